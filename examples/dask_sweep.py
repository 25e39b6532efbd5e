"""A bead sweep beyond one machine: cut it into chunks, run them on a Dask cluster, join
them, and check that the result equals the same sweep run locally, bit for bit.

    python examples/dask_sweep.py                              # a LocalCluster of 2 processes
    python examples/dask_sweep.py --scheduler tcp://host:8786  # any Dask cluster

The workers need the package too (`pip install ./crates/bead-py` in each worker's
environment); they need no scene file: a `bead.Sweep` travels as plain data (the scene's
text, its file name and parameters, the values swept and the run options), and each task
runs its members with `Sweep.run_range(start, stop)`, which depends on member indices alone.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import bead

ROOT = Path(__file__).resolve().parents[1]


def run_chunk(sweep: bead.Sweep, start: int, stop: int, threads: int) -> bead.SweepResult:
    """One task: members start..stop-1 of the sweep, on the worker."""
    return sweep.run_range(start, stop, threads)


def identical(a, b) -> bool:
    """Bit for bit: the same bytes (NaN where NaN, the sign of zero included)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype == object or a.dtype.kind == "U":
        return a.shape == b.shape and a.tolist() == b.tolist()
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


FIELDS = ("t_final", "stop_time", "steps", "energy_rel_error_max", "energy_balance_error_max",
          "constraint_error_max", "newton_iterations", "positions", "velocities", "q", "qdot",
          "status", "errors")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scheduler", help="address of a Dask scheduler (default: a "
                        "LocalCluster of 2 worker processes on this machine)")
    parser.add_argument("--n", type=int, default=60, help="N x N initial angles")
    parser.add_argument("--duration", type=float, default=5.0, help="run length (s)")
    parser.add_argument("--chunks", type=int, default=8, help="tasks to cut the sweep into")
    parser.add_argument("--threads", type=int, default=1,
                        help="threads per task (0: every core of the worker)")
    args = parser.parse_args(argv)

    from dask.distributed import Client, LocalCluster

    # The double pendulum over a grid of initial angles, stopped when an arm flips over
    # (examples/flip_time.py draws this at 400 x 400).
    scene = bead.load(ROOT / "scenes" / "double-pendulum.toml")
    angles = np.linspace(-3.0, 3.0, args.n)
    sweep = bead.Sweep(
        scene,
        {"th1": angles, "th2": angles},
        method="parametric",
        integrator="rk4",
        dt=0.01,
        duration=args.duration,
        stop_when="(abs(theta1) + abs(theta2) + abs(abs(theta1) - abs(theta2)))/2 - pi",
    )
    print(sweep)

    if args.scheduler:
        cluster = None
        client = Client(args.scheduler)
    else:
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        workers = len(client.scheduler_info()["workers"])
        if args.scheduler:
            print(f"dask: the scheduler at {args.scheduler}, {workers} workers")
        else:
            print(f"dask: a LocalCluster of {workers} worker processes")
        start = time.perf_counter()
        shared = client.scatter(sweep, broadcast=True)
        ranges = sweep.chunks(args.chunks)
        futures = [client.submit(run_chunk, shared, a, b, args.threads, pure=False)
                   for a, b in ranges]
        chunks = client.gather(futures)
        remote = sweep.assemble(chunks)
        remote_wall = time.perf_counter() - start
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    print(f"dask:  {len(ranges)} chunks of ~{len(sweep) // len(ranges)} members, "
          f"{remote_wall:.2f} s wall")

    start = time.perf_counter()
    local = sweep.run()
    local_wall = time.perf_counter() - start
    print(f"local: {len(local)} members on {local.threads} threads, {local_wall:.2f} s wall")
    print(local)

    same = {field: identical(getattr(remote, field), getattr(local, field)) for field in FIELDS}
    same["params"] = all(identical(remote.params[n], local.params[n]) for n in sweep.names)
    for field, equal in same.items():
        print(f"  {field:24s} {'identical' if equal else 'DIFFERENT'}")
    verdict = all(same.values())
    print("dask result equals the local sweep bit for bit:", "yes" if verdict else "NO")
    return 0 if verdict else 1


if __name__ == "__main__":
    raise SystemExit(main())
