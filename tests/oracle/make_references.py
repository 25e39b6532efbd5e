#!/usr/bin/env python3
"""Reference solutions of the oracle suite's systems, computed without bead.

Each system is written here again from its physics (particle masses, gravity and the
parametric map x(q, t), the same numbers as its scene file): sympy derives the Euler-Lagrange
equations M(q, t) q'' = f(q, q', t) from L = T - V, and scipy's DOP853 integrates them at
rtol 1e-13. Where a closed form exists (the pendulum's Jacobi elliptic functions, the helix's
quadratic, the rotating rod's cosh) the reference is that closed form evaluated with mpmath
at 30 digits, and the DOP853 route is run as well and compared with it, which measures the
route's own accuracy. Event times (the first upward zero crossing of an expression) come
from the closed form or from DOP853's event location refined by bisection on its dense
output.

Output, per system, in tests/oracle/references/:
  NAME.csv   t, q.NAME..., qdot.NAME..., qddot.NAME... on a uniform grid of step `grid_step`
             (shortest round-trip decimals); the tests interpolate between grid points with
             the quintic Hermite interpolant of (q, q', q'').
  NAME.json  the settings (scene, parameters, grid, solver, tolerances), the measured errors
             (`reference_error`: of q and q' against the closed form or the rtol 1e-12
             solution; `interpolation_error`: of the quintic Hermite interpolant at the grid's
             midpoints against the solver) and the events.

Run from the repository root:  python tests/oracle/make_references.py
(needs numpy, scipy, sympy, mpmath; `--check` recomputes everything and fails when the
committed data differ by more than the stated errors, without writing.)

The settings below are what the data were made with; tests/oracle's tests check that every
NAME.json states them (test_oracle.py) and that the scenes still have these parameters
(bead-oracle's `references_match_the_scenes`).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE / "references"

RTOL = 1e-13
GRID_STEP = 1e-3

# Each system: the scene it belongs to, its parameters (as in the scene), the particles
# (name, mass), gravity, the coordinates, the map x(q, t) per particle as sympy-parsable
# text in the coordinates, t and the parameters, the initial q and q', the duration, the
# closed form when there is one (a key of CLOSED_FORMS) and the events: the stop condition
# as each form writes it, with the same expression of (t, q, q') for the solver.
SYSTEMS = {
    "pendulum": {
        "scene": "scenes/circle.toml",
        "params": {"L": 1.0, "g": 9.81, "theta0": "pi/3"},
        "particles": [["bead", "1"]],
        "gravity": ["0", "g"],
        "coordinates": ["theta"],
        "map": {"bead": ["L*sin(theta)", "L*cos(theta)"]},
        "q0": ["theta0"],
        "qdot0": ["0"],
        "duration": 2.5,
        "closed_form": "pendulum",
        "events": [
            {"implicit": "-bead.x", "parametric": "-theta", "g": "-theta",
             "what": "the bottom, a quarter period K(k)/w after the release"},
        ],
    },
    "helix": {
        "scene": "scenes/helix.toml",
        "params": {"R": 1.0, "b": 0.2, "g": 9.81, "w0": 3.0},
        "particles": [["bead", "1"]],
        "gravity": ["0", "0", "-g"],
        "coordinates": ["phi"],
        "map": {"bead": ["R*cos(phi)", "R*sin(phi)", "b*phi"]},
        "q0": ["0"],
        "qdot0": ["w0"],
        "duration": 2.0,
        "closed_form": "helix",
        "events": [
            {"implicit": "-bead.vz", "parametric": "-qdot.phi", "g": "-phidot",
             "what": "the top of the climb, w0 (R^2 + b^2) / (g b)"},
        ],
    },
    "rotating-rod": {
        "scene": "tests/oracle/scenes/rotating-rod.toml",
        "params": {"r0": 0.5, "w": 2.0, "m": 1.5},
        "particles": [["bead", "m"]],
        "gravity": ["0", "0"],
        "coordinates": ["r"],
        "map": {"bead": ["r*cos(w*t)", "r*sin(w*t)"]},
        "q0": ["r0"],
        "qdot0": ["0"],
        "duration": 1.0,
        "closed_form": "rotating-rod",
        "events": [
            {"implicit": "bead.x^2 + bead.y^2 - 1", "parametric": "r - 1", "g": "r - 1",
             "what": "r = 1, at acosh(1/r0)/w"},
        ],
    },
    "spinning-hoop": {
        "scene": "scenes/spinning-hoop.toml",
        "params": {"R": 0.8, "w": 5.0, "g": 9.81, "th0": 0.3},
        "particles": [["bead", "1"]],
        "gravity": ["0", "0", "-g"],
        "coordinates": ["th"],
        "map": {"bead": ["R*sin(th)*cos(w*t)", "R*sin(th)*sin(w*t)", "-R*cos(th)"]},
        "q0": ["th0"],
        "qdot0": ["0"],
        "duration": 2.0,
        "closed_form": None,
        "events": [
            {"implicit": "bead.z + 0.8*cos(1)", "parametric": "th - 1", "g": "th - 1",
             "what": "theta = 1 rad on the way up"},
        ],
    },
    "parabola": {
        "scene": "scenes/parabola.toml",
        "params": {"g": 500.0},
        "particles": [["bead", "1"]],
        "gravity": ["0", "g"],
        "coordinates": ["q"],
        "map": {"bead": ["q", "-q**2/100"]},
        "q0": ["150"],
        "qdot0": ["0"],
        "duration": 3.0,
        "closed_form": None,
        "events": [
            {"implicit": "-bead.x", "parametric": "-q", "g": "-q",
             "what": "the bottom of the bowl"},
        ],
    },
    "double-pendulum": {
        "scene": "scenes/double-pendulum.toml",
        "params": {"L1": 1.0, "L2": 1.0, "m1": 1.0, "m2": 1.0, "g": 9.81,
                   "th1": "pi/2", "th2": "3*pi/4"},
        "particles": [["a", "m1"], ["b", "m2"]],
        "gravity": ["0", "g"],
        "coordinates": ["theta1", "theta2"],
        "map": {"a": ["L1*sin(theta1)", "L1*cos(theta1)"],
                "b": ["L1*sin(theta1) + L2*sin(theta2)", "L1*cos(theta1) + L2*cos(theta2)"]},
        "q0": ["th1", "th2"],
        "qdot0": ["0", "0"],
        "duration": 1.5,
        "closed_form": None,
        "events": [
            {"implicit": "-a.x", "parametric": "-theta1", "g": "-theta1",
             "what": "the upper rod through the vertical"},
        ],
    },
}


def settings_of(name: str) -> dict:
    """What NAME.json must state as its settings: the system as written above plus the
    solver's settings."""
    system = SYSTEMS[name]
    return {
        "system": name,
        **{k: system[k] for k in ("scene", "params", "particles", "gravity", "coordinates",
                                  "map", "q0", "qdot0", "duration", "closed_form")},
        "events": [{k: e[k] for k in ("implicit", "parametric", "what")}
                   for e in system["events"]],
        "grid_step": GRID_STEP,
        "solver": "sympy Euler-Lagrange equations, scipy.integrate.solve_ivp DOP853",
        "rtol": RTOL,
        "atol": RTOL,
    }


# ------------------------------------------------------------------------------------------
# The equations of motion, from the Lagrangian (sympy)


def equations(system: dict):
    """(f, params): f(t, y) = [q', q''] for the solver, and the parameter values, from
    L = T - V with T = sum m |dx/dt|^2 / 2, V = -sum m g.x."""
    import sympy as sp

    params = {k: sp.sympify(v) for k, v in system["params"].items()}
    t = sp.Symbol("t")
    qs = [sp.Function(n)(t) for n in system["coordinates"]]
    names = {n: q for n, q in zip(system["coordinates"], qs)}
    gravity = [sp.sympify(v).subs(params) for v in system["gravity"]]
    T = 0
    V = 0
    for pname, mass in system["particles"]:
        m = sp.sympify(mass).subs(params)
        x = [sp.sympify(e, locals={**names, "t": t}).subs(params)
             for e in system["map"][pname]]
        v = [sp.diff(xi, t) for xi in x]
        T += m * sum(vi**2 for vi in v) / 2
        V += -m * sum(gi * xi for gi, xi in zip(gravity, x))
    L = T - V
    qd = [sp.diff(q, t) for q in qs]
    # Euler-Lagrange: d/dt dL/dq' - dL/dq = 0, i.e. M q'' = rhs with M = d2L/dq'dq'.
    Q = sp.symbols(f"Q0:{len(qs)}")
    QD = sp.symbols(f"QD0:{len(qs)}")
    QDD = sp.symbols(f"QDD0:{len(qs)}")
    qdd = [sp.diff(q, t, 2) for q in qs]
    el = [sp.diff(sp.diff(L, qd[i]), t) - sp.diff(L, qs[i]) for i in range(len(qs))]
    subs = {**{qdd[i]: QDD[i] for i in range(len(qs))},
            **{qd[i]: QD[i] for i in range(len(qs))}}
    el = [e.subs(subs).subs({qs[i]: Q[i] for i in range(len(qs))}) for e in el]
    M = sp.Matrix([[sp.diff(e, a) for a in QDD] for e in el])
    rhs = -sp.Matrix([e.subs({a: 0 for a in QDD}) for e in el])
    M_f = sp.lambdify((t, Q, QD), sp.simplify(M), "numpy")
    rhs_f = sp.lambdify((t, Q, QD), sp.simplify(rhs), "numpy")
    return M_f, rhs_f


def solve_dop853(system: dict, rtol: float, times):
    """q, q', q'' at `times` and the events' times, by DOP853 at rtol (atol = rtol)."""
    import numpy as np
    import sympy as sp
    from scipy.integrate import solve_ivp

    M_f, rhs_f = equations(system)
    k = len(system["coordinates"])
    params = {n: float(sp.sympify(v).subs({p: sp.sympify(w) for p, w in system["params"].items()}))
              for n, v in system["params"].items()}

    def accel(t, q, qd):
        M = np.array(M_f(t, q, qd), dtype=float).reshape(k, k)
        r = np.array(rhs_f(t, q, qd), dtype=float).reshape(k)
        return np.linalg.solve(M, r)

    def f(t, y):
        return np.concatenate([y[k:], accel(t, y[:k], y[k:])])

    def value(text):
        return float(sp.sympify(text).subs({p: sp.sympify(w) for p, w in system["params"].items()}))

    y0 = [value(v) for v in system["q0"]] + [value(v) for v in system["qdot0"]]
    symbols = {n: i for i, n in enumerate(system["coordinates"])}

    def event_fn(text):
        expr = sp.sympify(text)
        args = [sp.Symbol(n) for n in system["coordinates"]] + \
               [sp.Symbol(n + "dot") for n in system["coordinates"]] + [sp.Symbol("t")]
        g = sp.lambdify(args, expr.subs({sp.Symbol(p): v for p, v in params.items()}), "math")
        return lambda t, y: g(*y[:k], *y[k:], t)

    events = [event_fn(e["g"]) for e in system["events"]]
    for e in events:
        e.direction = 1.0
    sol = solve_ivp(f, (0.0, float(times[-1])), y0, method="DOP853", t_eval=times,
                    rtol=rtol, atol=rtol, dense_output=True, events=events)
    assert sol.success, sol.message
    q = sol.y[:k].T
    qd = sol.y[k:].T
    qdd = np.array([accel(t, a, b) for t, a, b in zip(times, q, qd)])
    event_times = []
    for e, found in zip(events, sol.t_events):
        # The first upward crossing after t = 0 with g < 0 before it, refined by bisection
        # on the dense output.
        hits = [t for t in found if t > 0]
        assert hits, "the event does not fire within the duration"
        lo, hi = hits[0] - 1e-3, hits[0] + 1e-3
        glo = e(lo, sol.sol(lo))
        assert glo < 0
        for _ in range(200):
            mid = (lo + hi) / 2
            if e(mid, sol.sol(mid)) < 0:
                lo = mid
            else:
                hi = mid
        event_times.append(hi)
    return q, qd, qdd, event_times


# ------------------------------------------------------------------------------------------
# Closed forms (mpmath, 30 digits)


def closed_form(name: str, system: dict, times):
    """q, q', q'' at `times` and the events' times, from the closed form."""
    import mpmath as mp
    import numpy as np

    mp.mp.dps = 30
    p = {k: mp.mpf(1) * (mp.pi / 3 if v == "pi/3" else mp.mpf(v))
         for k, v in system["params"].items()}
    rows = []
    if name == "pendulum":
        w = mp.sqrt(p["g"] / p["L"])
        k = mp.sin(p["theta0"] / 2)
        m = k**2
        K = mp.ellipk(m)
        for t in times:
            u = K - w * mp.mpf(t)
            sn = mp.ellipfun("sn", u, m=m)
            cn = mp.ellipfun("cn", u, m=m)
            th = 2 * mp.asin(k * sn)
            thd = -2 * k * w * cn
            rows.append([th, thd, -(p["g"] / p["L"]) * mp.sin(th)])
        events = [K / w]
    elif name == "helix":
        a = p["g"] * p["b"] / (p["R"] ** 2 + p["b"] ** 2)
        for t in times:
            t = mp.mpf(t)
            rows.append([p["w0"] * t - a * t**2 / 2, p["w0"] - a * t, -a])
        events = [p["w0"] / a]
    elif name == "rotating-rod":
        w = p["w"]
        for t in times:
            t = mp.mpf(t)
            rows.append([p["r0"] * mp.cosh(w * t), p["r0"] * w * mp.sinh(w * t),
                         p["r0"] * w**2 * mp.cosh(w * t)])
        events = [mp.acosh(1 / p["r0"]) / w]
    else:
        raise ValueError(name)
    a = np.array([[float(v) for v in r] for r in rows])
    return a[:, :1], a[:, 1:2], a[:, 2:3], [float(e) for e in events]


# ------------------------------------------------------------------------------------------


def hermite(h, y0, d0, a0, y1, d1, a1, s):
    """The quintic Hermite interpolant at s h (0 <= s <= 1) of value, slope and curvature at
    both ends of an interval of length h (the formula of bead-oracle's reference.rs)."""
    s2 = s * s
    s3 = s2 * s
    h00 = 1 - 10 * s3 + 15 * s3 * s - 6 * s3 * s2
    h10 = s - 6 * s3 + 8 * s3 * s - 3 * s3 * s2
    h20 = (s2 - 3 * s3 + 3 * s3 * s - s3 * s2) / 2
    h01 = 10 * s3 - 15 * s3 * s + 6 * s3 * s2
    h11 = -4 * s3 + 7 * s3 * s - 3 * s3 * s2
    h21 = (s3 - 2 * s3 * s + s3 * s2) / 2
    return h00 * y0 + h10 * h * d0 + h20 * h * h * a0 + h01 * y1 + h11 * h * d1 + h21 * h * h * a1


def hermite_slope(h, y0, d0, a0, y1, d1, a1, s):
    """The derivative in t of `hermite`."""
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    h00 = -30 * s2 + 60 * s3 - 30 * s4
    h10 = 1 - 18 * s2 + 32 * s3 - 15 * s4
    h20 = (2 * s - 9 * s2 + 12 * s3 - 5 * s4) / 2
    h01 = 30 * s2 - 60 * s3 + 30 * s4
    h11 = -12 * s2 + 28 * s3 - 15 * s4
    h21 = (3 * s2 - 8 * s3 + 5 * s4) / 2
    return (h00 * y0 + h01 * y1) / h + h10 * d0 + h20 * h * a0 + h11 * d1 + h21 * h * a1


def make(name: str):
    """(settings with measured errors and events, rows) of one system."""
    import numpy as np

    system = SYSTEMS[name]
    n = int(round(system["duration"] / GRID_STEP))
    fine = np.arange(2 * n + 1) * (GRID_STEP / 2)  # the grid and its midpoints
    fine[-1] = system["duration"]
    q, qd, qdd, events = solve_dop853(system, RTOL, fine)
    if system["closed_form"]:
        eq, eqd, eqdd, eevents = closed_form(system["closed_form"], system, fine)
        route_error = max(float(np.max(np.abs(q - eq))), float(np.max(np.abs(qd - eqd))))
        route_event_error = max(abs(a - b) for a, b in zip(events, eevents))
        q, qd, qdd, events = eq, eqd, eqdd, eevents
        reference_error = 1e-15  # the closed form at 30 digits, rounded to doubles
        how = ("closed form (mpmath, 30 digits); the DOP853 route on the same system "
               f"differs from it by {route_error:.2e} in q and q' and {route_event_error:.2e} "
               "in the event times")
    else:
        q2, qd2, _, events2 = solve_dop853(system, RTOL * 10, fine)
        reference_error = max(float(np.max(np.abs(q - q2))), float(np.max(np.abs(qd - qd2))))
        route_event_error = max(abs(a - b) for a, b in zip(events, events2))
        how = ("DOP853 at rtol 1e-13; reference_error is its largest difference from the "
               "solution at rtol 1e-12 in q and q' (an overestimate of its own error), "
               f"{route_event_error:.2e} in the event times")
    # The quintic Hermite interpolant at the midpoints, against the solver there: of q, and
    # its derivative of q'.
    interp = 0.0
    for i in range(n):
        a, b, mid = 2 * i, 2 * i + 2, 2 * i + 1
        h = fine[b] - fine[a]
        ends = (q[a], qd[a], qdd[a], q[b], qd[b], qdd[b])
        interp = max(interp, float(np.max(np.abs(hermite(h, *ends, 0.5) - q[mid]))),
                     float(np.max(np.abs(hermite_slope(h, *ends, 0.5) - qd[mid]))))
    settings = settings_of(name)
    settings["how"] = how
    settings["reference_error"] = reference_error
    settings["interpolation_error"] = interp
    for e, te in zip(settings["events"], events):
        e["t"] = te
    grid = slice(0, 2 * n + 1, 2)
    rows = np.hstack([fine[grid, None], q[grid], qd[grid], qdd[grid]])
    return settings, rows


def header(name: str):
    k = SYSTEMS[name]["coordinates"]
    return ["t"] + [f"q.{c}" for c in k] + [f"qdot.{c}" for c in k] + [f"qddot.{c}" for c in k]


def write(name: str, settings, rows):
    OUT.mkdir(exist_ok=True)
    (OUT / f"{name}.json").write_text(json.dumps(settings, indent=2) + "\n")
    with open(OUT / f"{name}.csv", "w") as f:
        f.write(",".join(header(name)) + "\n")
        for r in rows:
            f.write(",".join(repr(float(v)) for v in r) + "\n")


def read_rows(name: str):
    import numpy as np
    return np.loadtxt(OUT / f"{name}.csv", delimiter=",", skiprows=1, ndmin=2)


def main(argv):
    check = "--check" in argv
    names = [a for a in argv if not a.startswith("--")] or list(SYSTEMS)
    failed = False
    for name in names:
        settings, rows = make(name)
        print(f"{name}: {len(rows)} rows, reference error {settings['reference_error']:.2e}, "
              f"interpolation error {settings['interpolation_error']:.2e}; {settings['how']}")
        if check:
            import numpy as np
            old = read_rows(name)
            tol = 10 * max(settings["reference_error"], 1e-14)
            diff = float(np.max(np.abs(old[:, 1:] - rows[:, 1:]))) if old.shape == rows.shape \
                else math.inf
            print(f"  committed data differ by {diff:.2e} (allowed {tol:.2e})")
            failed |= not diff <= max(tol, 1e-12 * float(np.max(np.abs(rows))))
        else:
            write(name, settings, rows)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
