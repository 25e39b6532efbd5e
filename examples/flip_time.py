"""The double pendulum's flip-time picture: for an N x N grid of initial angles (theta1,
theta2) in [-pi, pi]^2, released from rest, the time until either arm flips over, drawn as
an image.

    python examples/flip_time.py                 # 400 x 400, flip_time.png here
    python examples/flip_time.py --n 100 --out /tmp/flip.png
    python examples/flip_time.py --out docs/flip_time.png   # the README's picture

Each pixel is one member of a `bead.sweep` of scenes/double-pendulum.toml over its
parameters th1 and th2 (the initial angles from the downward vertical, both arms measured
from the vertical), run in the parametric form (generalized coordinates theta1, theta2)
until the event `stop_when` fires: an arm flips when it passes over the top of its pivot,
that is when |theta1| or |theta2| reaches pi (the angles are continuous, not wrapped, and
start inside (-pi, pi): pixel centres). As an upward zero crossing:

    max(|theta1|, |theta2|) - pi,   written   (|t1| + |t2| + ||t1| - |t2||) / 2 - pi

(the expressions have no max). A member that never flips within the duration is drawn in a
neutral grey; released from rest with 2 cos(theta1) + cos(theta2) > 1 (m1 = m2, L1 = L2) it
cannot flip at all, not having the energy to lift either arm over the top.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Tuple

import numpy as np

import bead

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "double-pendulum.toml"

# max(|theta1|, |theta2|) - pi, as an expression of the generalized coordinates.
FLIP = "(abs(theta1) + abs(theta2) + abs(abs(theta1) - abs(theta2)))/2 - pi"

# The run of every member: the parametric form with rk4 (the event located to 1e-10 dt on the
# integrator's own path).
RUN = {"method": "parametric", "integrator": "rk4"}


def angles(n: int) -> np.ndarray:
    """The centres of n equal cells across [-pi, pi]."""
    return -np.pi + (2 * np.pi / n) * (np.arange(n) + 0.5)


def flip_times(
    n: int, duration: float, dt: float, threads: int = 0
) -> Tuple[np.ndarray, bead.SweepResult]:
    """The grid's angles and the sweep's result: ``result.stop_time[i, j]`` is the flip time
    of theta1 = angles[i], theta2 = angles[j] (NaN: no flip within `duration`)."""
    scene = bead.load(SCENE)
    values = angles(n)
    result = bead.sweep(
        scene,
        {"th1": values, "th2": values},
        dt=dt,
        duration=duration,
        stop_when=FLIP,
        threads=threads,
        **RUN,
    )
    return values, result


def draw(values: np.ndarray, result: bead.SweepResult, out: Path, title: str) -> None:
    """The picture: theta1 across, theta2 up, colour = log flip time, grey = no flip."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    times = np.ma.masked_invalid(result.stop_time.T)  # rows: theta2, columns: theta1
    cmap = plt.get_cmap("magma_r").with_extremes(bad="#c8c8c8")
    half = np.pi / len(values)
    extent = (values[0] - half, values[-1] + half, values[0] - half, values[-1] + half)
    low = max(float(np.nanmin(result.stop_time)), 1e-2) if times.count() else 1e-2
    high = float(result.t_final.max())
    fig, ax = plt.subplots(figsize=(7.2, 6), dpi=100)
    image = ax.imshow(
        times,
        origin="lower",
        extent=extent,
        cmap=cmap,
        norm=LogNorm(vmin=low, vmax=high),
        interpolation="nearest",
    )
    bar = fig.colorbar(image, ax=ax)
    bar.set_label("time until an arm flips over (s, log scale); grey: no flip")
    ticks = [-np.pi, -np.pi / 2, 0, np.pi / 2, np.pi]
    labels = ["-π", "-π/2", "0", "π/2", "π"]
    ax.set_xticks(ticks, labels)
    ax.set_yticks(ticks, labels)
    ax.set_xlabel("θ1 (upper arm, from the downward vertical)")
    ax.set_ylabel("θ2 (lower arm)")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=400, help="grid size N (N x N members)")
    parser.add_argument("--duration", type=float, default=10.0, help="run length (s)")
    parser.add_argument("--dt", type=float, default=0.01, help="rk4 step (s)")
    parser.add_argument("--threads", type=int, default=0, help="threads (0: one per core)")
    parser.add_argument("--out", type=Path, default=Path("flip_time.png"),
                        help="the picture (PNG); default flip_time.png in the current directory")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    values, result = flip_times(args.n, args.duration, args.dt, args.threads)
    wall = time.perf_counter() - start
    counts = result.counts()
    steps = int(result.steps.sum())
    print(result)
    print(
        f"{args.n} x {args.n} members, {args.duration} s at dt = {args.dt} (rk4, parametric): "
        f"{counts['event']} flipped, {counts['ok']} did not, {counts['failed']} failed"
    )
    print(
        f"wall time {wall:.1f} s on {result.threads} thread(s): "
        f"{len(result) / wall:.0f} members/s, {steps / wall:.3g} steps/s"
    )
    title = (
        f"Double pendulum released from rest: time until an arm flips over\n"
        f"{args.n}×{args.n} members, {args.duration:g} s, rk4 dt = {args.dt:g} s, "
        f"m1 = m2, L1 = L2 = 1 m; {wall:.0f} s wall on {result.threads} threads"
    )
    draw(values, result, args.out, title)
    print(f"wrote {os.path.relpath(args.out)}")
    return 1 if counts["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
