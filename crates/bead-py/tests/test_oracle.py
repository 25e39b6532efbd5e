"""The oracle suite through the Python package: `Scene.run()` arrays and summary,
`Simulation.advance_to` and `step`, and `bead.sweep`, for every system, method and
integrator of tests/oracle/cases.json (written by the Rust half, bead-oracle's listing),
against the references of tests/oracle/references/ (made without bead by
tests/oracle/make_references.py) and, bit for bit, against the `bead` binary.

The systems are read from the references' own statement of them (masses, gravity, the map
x(q, t) as text, evaluated here with numpy; velocities by complex-step differentiation), not
from the scenes through bead. Needs numpy only.
"""

import csv
import importlib.util
import json
import math

import numpy as np
import pytest

import bead
from conftest import ROOT

ORACLE = ROOT / "tests" / "oracle"
PLAN = json.loads((ORACLE / "cases.json").read_text())
SYSTEMS = PLAN["systems"]
ROUND_OFF = PLAN["round_off"]
DOPRI_BOUND = PLAN["dopri5_bound"]


class Reference:
    """One system's reference table, interpolated by quintic Hermite between grid points."""

    def __init__(self, name):
        self.name = name
        self.settings = json.loads((ORACLE / "references" / f"{name}.json").read_text())
        with open(ORACLE / "references" / f"{name}.csv", newline="") as f:
            header, *rows = list(csv.reader(f))
        self.table = np.array([[float(v) for v in r] for r in rows])
        self.k = (len(header) - 1) // 3
        self.step = self.settings["grid_step"]
        env = {"pi": math.pi}
        self.params = {n: float(eval(str(v), {}, env)) for n, v in self.settings["params"].items()}
        scope = {**self.params, "pi": math.pi}
        self.masses = [float(eval(m, {}, scope)) for _, m in self.settings["particles"]]
        self.gravity = np.array([float(eval(g, {}, scope)) for g in self.settings["gravity"]])
        self.dim = len(self.gravity)

    def at(self, t):
        """(q, qdot) at t (a number or an array of times: rows of q, qdot)."""
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        k, tab = self.k, self.table
        last = len(tab) - 1
        pos = np.clip(ts / self.step, 0.0, last)
        i = np.minimum(np.floor(pos).astype(int), last - 1)
        s = pos - i
        i = np.where(np.abs(s - 1) < 1e-9, i + 1, i)
        on = (np.abs(s) < 1e-9) | (np.abs(s - 1) < 1e-9)
        j = np.minimum(i, last - 1)
        a, b = tab[j], tab[j + 1]
        h = (b[:, 0] - a[:, 0])[:, None]
        s = ((ts - a[:, 0]) / h[:, 0])[:, None]
        s2, s3, s4 = s * s, s ** 3, s ** 4
        y0, d0, a0 = a[:, 1:1 + k], a[:, 1 + k:1 + 2 * k], a[:, 1 + 2 * k:1 + 3 * k]
        y1, d1, a1 = b[:, 1:1 + k], b[:, 1 + k:1 + 2 * k], b[:, 1 + 2 * k:1 + 3 * k]
        q = ((1 - 10 * s3 + 15 * s4 - 6 * s3 * s2) * y0
             + (s - 6 * s3 + 8 * s4 - 3 * s3 * s2) * h * d0
             + (s2 - 3 * s3 + 3 * s4 - s3 * s2) / 2 * h * h * a0
             + (10 * s3 - 15 * s4 + 6 * s3 * s2) * y1
             + (-4 * s3 + 7 * s4 - 3 * s3 * s2) * h * d1
             + (s3 - 2 * s4 + s3 * s2) / 2 * h * h * a1)
        qd = ((-30 * s2 + 60 * s3 - 30 * s4) * y0 / h
              + (1 - 18 * s2 + 32 * s3 - 15 * s4) * d0
              + (2 * s - 9 * s2 + 12 * s3 - 5 * s4) / 2 * h * a0
              + (30 * s2 - 60 * s3 + 30 * s4) * y1 / h
              + (-12 * s2 + 28 * s3 - 15 * s4) * d1
              + (3 * s2 - 8 * s3 + 5 * s4) / 2 * h * a1)
        q = np.where(on[:, None], tab[i, 1:1 + k], q)
        qd = np.where(on[:, None], tab[i, 1 + k:1 + 2 * k], qd)
        if np.ndim(t) == 0:
            return q[0], qd[0]
        return q, qd

    def x(self, q, t):
        """The map x(q, t), every particle's coordinates in order (q: (K,) or (N, K); t a
        number or (N,))."""
        q = np.asarray(q)
        scope = {"sin": np.sin, "cos": np.cos, "pi": math.pi, "t": t, **self.params}
        scope.update(zip(self.settings["coordinates"], q.T))
        return np.array([np.broadcast_to(eval(e, {}, scope), np.shape(q.T[0]))
                         for p, _ in self.settings["particles"]
                         for e in self.settings["map"][p]]).T

    def v(self, q, qdot, t):
        """dx/dt = J q' + dx/dt at fixed q, by complex steps."""
        eps = 1e-30
        q = np.asarray(q, dtype=complex)
        qdot = np.asarray(qdot)
        v = self.x(q, np.asarray(t) + 1j * eps).imag / eps
        for j in range(q.shape[-1]):
            dq = q.copy()
            dq[..., j] += 1j * eps
            v = v + self.x(dq, t).imag / eps * qdot[..., j:j + 1] if q.ndim == 2 else \
                v + self.x(dq, t).imag / eps * qdot[j]
        return v

    def energy(self, x, v):
        """T + V of particle states (x, v: (n,) or (N, n))."""
        x, v = np.asarray(x), np.asarray(v)
        d = self.dim
        e = 0.0
        for p, m in enumerate(self.masses):
            xs, vs = x[..., p * d:(p + 1) * d], v[..., p * d:(p + 1) * d]
            e = e + 0.5 * m * np.sum(vs * vs, axis=-1) - m * np.sum(xs * self.gravity, axis=-1)
        return e

    def exact(self, t):
        """(x, v) at t (a number, or an array of times: rows)."""
        q, qd = self.at(t)
        return self.x(q, t).real, self.v(q, qd, t)


REFERENCES = {name: Reference(name) for name in SYSTEMS}


def error_vectors(name, ts, xs, vs, works=None):
    """The signed errors of states (rows), positions over the length scale, velocities over
    the speed scale, and the work W over the energy scale for driven systems (as
    bead-oracle's rows.rs)."""
    ref, sys = REFERENCES[name], SYSTEMS[name]
    ts = np.asarray(ts, dtype=float)
    n = len(ts)
    ex, ev = ref.exact(ts)
    xs = np.asarray(xs).reshape(n, -1)
    vs = np.asarray(vs).reshape(n, -1)
    parts = [(xs - ex) / sys["length"], (vs - ev) / sys["speed"]]
    if sys["driven"] and works is not None:
        x0, v0 = ref.exact(0.0)
        exact_work = ref.energy(ex, ev) - ref.energy(x0, v0)
        parts.append(((np.asarray(works) - exact_work) / (sum(ref.masses) * sys["speed"] ** 2))[:, None])
    return np.hstack(parts)


def errors_of(name, run):
    return error_vectors(name, run.t, run.positions, run.velocities, run.work)


def convergence(name, order, coarse, fine, what):
    """(a) halving dt divides the error by 2^p within 20% (largest error and row by row), as
    bead-oracle's checks.rs."""
    floor = ROUND_OFF + SYSTEMS[name]["reference_floor"]
    factor = 2.0 ** order
    ec, ef = errors_of(name, coarse), errors_of(name, fine)
    assert len(fine.t) == 2 * len(coarse.t) - 1, what
    big_c, big_f = np.max(np.abs(ec)), np.max(np.abs(ef))
    if big_f > 4 * floor:
        assert abs(big_c / big_f / factor - 1) <= 0.2, \
            f"{what}: the error fell from {big_c:.3e} to {big_f:.3e}, not by {factor}"
    else:
        assert big_c <= 4 * factor * floor, f"{what}: {big_c:.3e} at dt, {big_f:.3e} at dt/2"
    assert np.array_equal(coarse.t, fine.t[::2]), what
    deviation = np.max(np.abs(ec - factor * ef[::2]), axis=1)
    allowed = 0.2 * factor * big_f + (1 + factor) * floor
    bad = np.nonzero(deviation > allowed)[0]
    assert len(bad) == 0, f"{what}: at t = {coarse.t[bad[0]]}: {ec[bad[0]]} and {ef[2 * bad[0]]}"
    return big_c


def within(name, ts, xs, vs, bound, what):
    floor = ROUND_OFF + SYSTEMS[name]["reference_floor"]
    e = np.max(np.abs(error_vectors(name, ts, xs, vs)), axis=1)
    bad = np.nonzero(e > bound + floor)[0]
    assert len(bad) == 0, \
        f"{what}: at t = {np.asarray(ts)[bad[0]]} the error is {e[bad[0]]:.3e} > {bound:.3e}"


def check_rows(name, run, what):
    """(b) each row one state: energy = T + V of its x and v; for the parametric form
    x = x(q, t) and v = J q' + dx/dt at its own t."""
    ref = REFERENCES[name]
    sys = SYSTEMS[name]
    scale = sum(ref.masses) * sys["speed"] ** 2
    n = len(run.t)
    x, v = run.positions.reshape(n, -1), run.velocities.reshape(n, -1)
    bad = np.nonzero(np.abs(ref.energy(x, v) - run.energy) > 4e-13 * scale)[0]
    assert len(bad) == 0, f"{what}: row {bad[0]}: energy is not T + V of its x and v"
    if run.method == "parametric":
        dx = np.max(np.abs(ref.x(run.q, run.t).real - x), axis=1)
        bad = np.nonzero(dx > 1e-13 * sys["length"])[0]
        assert len(bad) == 0, f"{what}: row {bad[0]} at t = {run.t[bad[0]]}: x is not x(q, t)"
        dv = np.max(np.abs(ref.v(run.q, run.qdot, run.t) - v), axis=1)
        bad = np.nonzero(dv > 1e-13 * sys["speed"])[0]
        assert len(bad) == 0, f"{what}: row {bad[0]} at t = {run.t[bad[0]]}: v is not J q' + dx/dt"
    assert (run.work is not None) == sys["driven"], what


def check_summary(case, run, end, what):
    """The summary is the last row, at the end asked for (or at the event)."""
    s = run.summary
    assert s["t_final"] == run.t[-1], what
    if s.get("stop_time") is None:
        assert abs(run.t[-1] - end) <= 4 * np.finfo(float).eps * end, \
            f"{what}: the run ended at t = {run.t[-1]}, asked for {end}"
    for p, name in enumerate(SYSTEMS[case["system"]]["particles"]):
        assert s["particles"][name]["position"] == list(run.positions[-1, p]), what
        assert s["particles"][name]["velocity"] == list(run.velocities[-1, p]), what
    assert s["energy_final"] == run.energy[-1], what
    if run.work is not None:
        assert s["work_final"] == run.work[-1], what


def options(case, **extra):
    o = dict(method=case["method"], integrator=case["integrator"], dt=case["dt"],
             duration=case["duration"])
    if case["rtol"] is not None:
        o["rtol"] = case["rtol"]
    o.update(extra)
    return o


def scene_of(case):
    return bead.load(str(ROOT / SYSTEMS[case["system"]]["scene"]))


def against_reference(case, run, scene, what, **extra):
    """(a) for a run of `case` (fixed step: with the run at dt / 2; dopri5: its bound)."""
    name = case["system"]
    if case["integrator"] == "dopri5":
        within(name, run.t, run.positions, run.velocities, DOPRI_BOUND * case["rtol"], what)
        return None
    fine = scene.run(**options(case, dt=case["dt"] / 2, **extra))
    return convergence(name, case["order"], run, fine, what)


def cli_trace(cli, tmp_path, case, extra=()):
    trace = tmp_path / "trace.csv"
    args = ["run", ROOT / SYSTEMS[case["system"]]["scene"], "--method", case["method"],
            "--integrator", case["integrator"], "--dt", repr(case["dt"]),
            "--duration", repr(case["duration"]), "--trace", trace, *extra]
    if case["rtol"] is not None:
        args += ["--rtol", repr(case["rtol"])]
    code, _, err = cli(*args)
    assert code == 0, err
    with open(trace, newline="") as f:
        header, *rows = list(csv.reader(f))
    return header, np.array([[float(v) for v in r] for r in rows])


def cases(front):
    return [pytest.param(c, id=f"{c['system']}-{c['method']}-{c['integrator']}")
            for c in PLAN["cases"] if front in c["fronts"]]


@pytest.mark.parametrize("case", cases("py-run"))
def test_run_meets_the_oracle(case, cli, tmp_path):
    what = f"Scene.run {case}"
    scene = scene_of(case)
    run = scene.run(**options(case))
    check_rows(case["system"], run, what)
    check_summary(case, run, case["duration"], what)
    against_reference(case, run, scene, what)
    # (c) the arrays are the CLI's trace, bit for bit.
    header, table = cli_trace(cli, tmp_path, case)
    assert run.columns == header
    assert np.array_equal(run.table(), table), f"{what}: not the CLI's trace"


@pytest.mark.parametrize("case", cases("py-run"))
def test_run_stops_at_the_reference_event(case):
    name = case["system"]
    ref = REFERENCES[name]
    event = ref.settings["events"][0]
    what = f"Scene.run stop_when {case}"
    scene = scene_of(case)
    run = scene.run(**options(case, duration=ref.table[-1, 0], stop_when=event[case["method"]]))
    s = run.summary
    assert s["stop_time"] == run.t[-1] == s["t_final"], what
    check_rows(name, run, what)
    check_summary(case, run, None, what)
    # The crossing is within (the run's largest error) x (length / speed) x 100 of the
    # exact time (bead-oracle's checks.rs says why), dopri5 within its bound.
    largest = np.max(np.abs(errors_of(name, run)))
    sys = SYSTEMS[name]
    bound = 100 * max(largest, ROUND_OFF) * sys["length"] / sys["speed"] + 1e-10 * case["dt"]
    assert abs(run.t[-1] - event["t"]) <= bound, f"{what}: {run.t[-1]} vs {event['t']}"


@pytest.mark.parametrize("case", cases("py-advance"))
def test_advance_to_and_step_give_the_run(case):
    what = f"Simulation {case}"
    scene = scene_of(case)
    run = scene.run(**options(case))
    o = options(case)
    del o["duration"]
    by_advance = scene.simulation(**o)
    by_step = scene.simulation(**o)
    ts, xs, vs = [], [], []
    for k in range(1, len(run.t)):
        by_advance.advance_to(k * case["dt"])
        if case["integrator"] == "dopri5":
            ts.append(by_advance.t)
            xs.append(by_advance.positions.copy())
            vs.append(by_advance.velocities.copy())
            continue
        assert by_advance.t == run.t[k], what
        assert np.array_equal(by_advance.positions, run.positions[k]), f"{what}: step {k}"
        assert np.array_equal(by_advance.velocities, run.velocities[k]), f"{what}: step {k}"
        assert by_advance.energy == run.energy[k], what
        by_step.step(1)
        assert np.array_equal(by_step.positions, run.positions[k]), f"{what}: step() {k}"
    if case["integrator"] == "dopri5":
        within(case["system"], ts, xs, vs, DOPRI_BOUND * case["rtol"], what)


@pytest.mark.parametrize("case", cases("py-sweep"))
def test_sweep_members_are_their_runs_and_meet_the_oracle(case):
    what = f"bead.sweep {case}"
    scene = scene_of(case)
    name, low, middle = SYSTEMS[case["system"]]["sweep"]
    values = np.linspace(low, 2 * middle - low, 3)
    result = bead.sweep(scene, params={name: values}, threads=2, **options(case))
    assert list(result.status) == ["ok"] * 3, f"{what}: {result.errors}"
    for i, value in enumerate(values):
        run = scene.with_params({name: float(value)}).run(**options(case))
        assert result.t_final[i] == run.t[-1] == case["duration"] or \
            abs(run.t[-1] - case["duration"]) <= 1e-15, f"{what}: t_final {run.t[-1]}"
        assert np.array_equal(result.positions[i], run.positions[-1]), f"{what}: member {i}"
        assert np.array_equal(result.velocities[i], run.velocities[-1]), f"{what}: member {i}"
        if value == middle:
            against_reference(case, run, scene, what)
            largest = np.max(np.abs(errors_of(case["system"], run)))
            within(case["system"], [run.t[-1]], [result.positions[i]], [result.velocities[i]],
                   largest, what)


@pytest.mark.parametrize("case", [
    pytest.param(c, id=f"{c['system']}-{c['method']}-{c['integrator']}-{c['dt']}")
    for c in PLAN["off_grid"]])
def test_durations_off_the_grid_end_at_the_duration(case):
    """The run, and a sweep member, end at the duration (the Rust half checks the last
    state's accuracy; these are the same runs, the CLI's bit for bit)."""
    scene = scene_of(case)
    run = scene.run(**options(case))
    check_summary(case, run, case["duration"], f"Scene.run {case}")
    name, low, middle = SYSTEMS[case["system"]]["sweep"]
    result = bead.sweep(scene, params={name: [middle]}, **options(case))
    assert result.t_final[0] == case["duration"], \
        f"bead.sweep {case}: t_final {result.t_final[0]}"


DOPRI = [(s, m, rtol, dt) for s in SYSTEMS for m in ("implicit", "parametric")
         for rtol, dt in ((1e-6, 1e-3), (1e-12, 0.25))]


@pytest.mark.parametrize("system,method,rtol,dt", DOPRI)
def test_dopri5_steps_longer_and_shorter_than_the_output_interval(system, method, rtol, dt):
    case = dict(system=system, method=method, integrator="dopri5", dt=dt, duration=1.0,
                rtol=rtol)
    what = f"Scene.run {case}"
    run = scene_of(case).run(**options(case))
    check_rows(system, run, what)
    check_summary(case, run, 1.0, what)
    within(system, run.t, run.positions, run.velocities, DOPRI_BOUND * rtol, what)


def test_the_references_are_what_the_script_makes():
    """Each NAME.json states the settings of make_references.py (importing it needs neither
    scipy nor sympy), and each table covers its duration on its grid."""
    spec = importlib.util.spec_from_file_location("make_references",
                                                  ORACLE / "make_references.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert sorted(script.SYSTEMS) == sorted(SYSTEMS)
    for name, ref in REFERENCES.items():
        stated = {k: v for k, v in ref.settings.items()
                  if k not in ("how", "reference_error", "interpolation_error")}
        for e in stated["events"]:
            assert isinstance(e.pop("t"), float)
        assert stated == script.settings_of(name), name
        t = ref.table[:, 0]
        assert t[0] == 0 and t[-1] == script.SYSTEMS[name]["duration"], name
        assert np.allclose(np.diff(t), script.GRID_STEP, rtol=0, atol=1e-12), name
        assert ref.settings["reference_error"] < 1e-8 * max(1.0, np.max(np.abs(ref.table)))
        assert list(ref.table.shape) == [len(t), 1 + 3 * ref.k]
