"""The memory a run's recording takes: the recorded vectors become the numpy arrays without
a copy, so the peak is the arrays themselves (it was twice: a Rust vector, then numpy's
copy of it, while the guard counted the arrays once); the guard refuses a run whose arrays
would pass 8 GiB, saying how many bytes it needs and how to record less."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

import bead
from conftest import scene_path

LIMIT = 8 << 30

# 2000 free stones: each recorded state is 16,003 numbers (t, energy, constraint_error,
# positions and velocities, q and qdot), and an Euler step costs little.
STONES = """
[params]
N = 2000
[world]
gravity = [0.0, 9.81]
[[particle]]
for = { i = "0..N" }
name = "p{i}"
mass = 1.0
position = ["i", 0.0]
velocity = [1.0, 0.0]
"""

# The peak resident memory of the process, from /proc (VmHWM, of this process's own memory;
# ru_maxrss would start at the parent's, which execve keeps).
PEAK = r"""
import sys
import bead

def peak():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024

scene = bead.loads(sys.argv[1])
scene.run(steps=1)  # the allocator and the imports settle first
before = peak()
run = scene.run(integrator="euler", steps=int(sys.argv[2]))
after = peak()
arrays = sum(a.nbytes for a in (run.t, run.positions, run.velocities, run.energy,
                                run.constraint_error, run.q, run.qdot))
print(after - before, arrays)
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_recording_peak_is_the_arrays_not_twice():
    # 1000 steps: 1001 states of 64 KB, 128 MB of arrays.
    out = subprocess.run([sys.executable, "-c", PEAK, STONES, "1000"], capture_output=True,
                         text=True, check=True).stdout
    grew, arrays = map(int, out.split())
    assert arrays == 1001 * (3 + 4 * 4000) * 8
    assert grew < 1.25 * arrays, f"peak grew by {grew / arrays:.2f} times the arrays"


def test_record_guard_says_bytes_and_how_to_record_less():
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(ValueError) as caught:
        scene.run(steps=10**9)
    text = str(caught.value)
    # 10^9 + 2 rows of 12 numbers (t, energy, constraint_error, work, x, y, vx, vy, q and
    # qdot of the implicit form's 2 coordinates).
    assert text == (
        "this run would record 1000000002 states of 12 numbers, 96000000192 bytes (96 GB) of "
        "arrays, more than the 8589934592 bytes (8 GiB) a run may record; record every K-th "
        "state with every=K (every=12 or more fits), or run a shorter duration (fewer steps)"
    )


@pytest.mark.parametrize("steps", [10**9, 2**53, 123_456_789_012])
def test_the_every_the_guard_proposes_is_the_least_that_fits(steps):
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(ValueError) as caught:
        scene.run(steps=steps)
    every = int(re.search(r"every=(\d+) or more fits", str(caught.value)).group(1))

    def nbytes(k):
        return (steps // k + 2) * 12 * 8

    assert nbytes(every) <= LIMIT < nbytes(every - 1)
