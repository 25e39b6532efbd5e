"""The article's ensemble through `bead.sweep` beside a vectorized numpy RK4 of the same
equations, measured in one process by CPU time (issue 16, item 5).

10^4 beads on the parabola x^2 + 100 y = 0 (+y down, g = 500 px/s^2), released at rest at x0
spread evenly over [10, 200), 1000 RK4 steps of 1/60 s each; the implicit form (constraint
force) and the parametric form (x = q, y = -q^2/100). The numpy version is what a notebook
user writes: the equations solved by hand, every member a lane of one array,

    implicit    lambda = (-2 vx^2 - 100 g) / (4 x^2 + 10^4),  a = (2 x lambda, g + 100 lambda)
    parametric  qddot = -(g q / 50 + q qdot^2 / 2500) / (1 + q^2 / 2500)

(m = 1; C = x^2 + 100 y, J = (2x, 100), bias = 2 vx^2; M = 1 + (q/50)^2, Q = -g q / 50, h =
(0, -qdot^2/50)). Both are checked to end every member at the same place (to 1e-7 of the
swing: the same equations, rounded differently) before the figures are printed, so that the
two measure the same work. CPU time (`time.process_time`, every thread of the process) makes
the comparison fair on a shared machine and whatever the thread count: particle-steps per CPU
second, and bead's ratio to numpy.

    python examples/numpy_ensemble.py [--members N] [--steps K] [--threads T]
"""

import argparse
import time

import numpy as np

import bead

G = 500.0
DT = 1.0 / 60.0

SCENE = """
title = "Bead on a parabola, released at x0"
[params]
g = 500.0
x0 = 150.0
[world]
gravity = [0.0, "g"]
[[particle]]
name = "bead"
mass = 1.0
position = ["x0", "-x0^2/100"]
velocity = [0.0, 0.0]
[[constraint]]
expr = "bead.x^2 + 100*bead.y"
[parametric]
coordinates = ["q"]
initial = ["x0"]
rates = [0.0]
[parametric.positions]
bead = ["q", "-q^2/100"]
"""


def release_points(n):
    """x0 for n members: evenly over [10, 200)."""
    return 10.0 + 190.0 * np.arange(n) / n


def numpy_implicit(x0, steps, dt=DT, g=G):
    """Final (x, y) of every member: RK4 on (x, y, vx, vy) with the constraint force."""
    def accel(x, vx):
        lam = (-2.0 * vx * vx - 100.0 * g) / (4.0 * x * x + 1e4)
        return 2.0 * x * lam, g + 100.0 * lam

    x, y = x0.copy(), -x0 * x0 / 100.0
    vx, vy = np.zeros_like(x0), np.zeros_like(x0)
    for _ in range(steps):
        ax1, ay1 = accel(x, vx)
        ax2, ay2 = accel(x + 0.5 * dt * vx, vx + 0.5 * dt * ax1)
        vx2, vy2 = vx + 0.5 * dt * ax1, vy + 0.5 * dt * ay1
        ax3, ay3 = accel(x + 0.5 * dt * vx2, vx + 0.5 * dt * ax2)
        vx3, vy3 = vx + 0.5 * dt * ax2, vy + 0.5 * dt * ay2
        ax4, ay4 = accel(x + dt * vx3, vx + dt * ax3)
        vx4, vy4 = vx + dt * ax3, vy + dt * ay3
        x = x + dt / 6.0 * (vx + 2.0 * vx2 + 2.0 * vx3 + vx4)
        y = y + dt / 6.0 * (vy + 2.0 * vy2 + 2.0 * vy3 + vy4)
        vx = vx + dt / 6.0 * (ax1 + 2.0 * ax2 + 2.0 * ax3 + ax4)
        vy = vy + dt / 6.0 * (ay1 + 2.0 * ay2 + 2.0 * ay3 + ay4)
    return x, y


def numpy_parametric(x0, steps, dt=DT, g=G):
    """Final (x, y) of every member: RK4 on (q, qdot) with qddot solved by hand."""
    def accel(q, w):
        return -(g * q / 50.0 + q * w * w / 2500.0) / (1.0 + q * q / 2500.0)

    q, w = x0.copy(), np.zeros_like(x0)
    for _ in range(steps):
        a1 = accel(q, w)
        w2 = w + 0.5 * dt * a1
        a2 = accel(q + 0.5 * dt * w, w2)
        w3 = w + 0.5 * dt * a2
        a3 = accel(q + 0.5 * dt * w2, w3)
        w4 = w + dt * a3
        a4 = accel(q + dt * w3, w4)
        q = q + dt / 6.0 * (w + 2.0 * w2 + 2.0 * w3 + w4)
        w = w + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q, -q * q / 100.0


def through_bead(x0, steps, method, threads=0):
    """Final (x, y) of every member through `bead.sweep` (the path of `bead sweep`)."""
    scene = bead.loads(SCENE)
    result = bead.sweep(scene, params={"x0": x0}, method=method, integrator="rk4", dt=DT,
                        steps=steps, threads=threads)
    assert (result.status == "ok").all(), result
    return result.positions[:, 0, 0], result.positions[:, 0, 1]


def cpu_seconds(f, *args, **kwargs):
    """(CPU seconds of every thread of this process, f's result)."""
    start = time.process_time()
    out = f(*args, **kwargs)
    return time.process_time() - start, out


def compare(members=10_000, steps=1000, threads=0, rounds=3):
    """Rows (form, bead particle-steps per CPU second, numpy's, bead / numpy), best of
    `rounds`, after checking that both end every member within 1e-7 of the swing."""
    x0 = release_points(members)
    rows = []
    for method, by_hand in [("implicit", numpy_implicit), ("parametric", numpy_parametric)]:
        best_bead, best_numpy = float("inf"), float("inf")
        for _ in range(rounds):
            seconds, (bx, by) = cpu_seconds(through_bead, x0, steps, method, threads)
            best_bead = min(best_bead, seconds)
            seconds, (nx, ny) = cpu_seconds(by_hand, x0, steps)
            best_numpy = min(best_numpy, seconds)
            apart = max(np.abs(bx - nx).max(), np.abs(by - ny).max())
            assert apart <= 1e-7 * 200.0, f"{method}: bead and numpy differ by {apart}"
        work = members * steps
        rows.append((method, work / best_bead, work / best_numpy, best_numpy / best_bead))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--members", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--threads", type=int, default=0, help="bead.sweep threads (0: all)")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    print(f"ensemble: {args.members} beads on the article's parabola, {args.steps} rk4 steps "
          f"of 1/60 s; particle-steps per CPU second, best of {args.rounds}")
    print(f"{'form':<12}{'bead.sweep':>14}{'numpy':>14}{'bead/numpy':>12}")
    for method, ours, theirs, ratio in compare(args.members, args.steps, args.threads,
                                               args.rounds):
        print(f"{method:<12}{ours:>14.3e}{theirs:>14.3e}{ratio:>11.2f}x")
    print("target (issue 16): bead >= 2x numpy per CPU second, >= 1e8 particle-steps/s")


if __name__ == "__main__":
    main()
