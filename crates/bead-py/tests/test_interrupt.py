"""Ctrl-C interrupts a long sweep, a long run and a long step(n): a child process starts one
that would take minutes, the test waits until the child is computing inside it (its CPU time
grows past the moment it said so), sends SIGINT and waits for the child to exit with
KeyboardInterrupt caught."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import scene_path

CHILD = r"""
import signal
import sys
import numpy as np
import bead

# Python installs its KeyboardInterrupt handler only when SIGINT is not ignored at startup; a
# child of a background job (nohup, CI runners) inherits SIGINT ignored. Install it, as an
# interactive session has it.
signal.signal(signal.SIGINT, signal.default_int_handler)

scene = bead.load(sys.argv[2])
kind = sys.argv[1]
print("ready", flush=True)
try:
    # The parametric form: it stays on the rods, so no divergence can end the run first.
    if kind == "run":
        # hours: records only the first and last states
        scene.run(method="parametric", steps=10**9, every=10**9)
    elif kind == "run-dopri5":
        # one output interval of 10^9 s: every step is inside it
        scene.run(method="parametric", integrator="dopri5", dt=1e9, steps=1)
    elif kind == "step":
        scene.simulation(method="parametric").step(10**9)
    elif kind.startswith("advance_to"):
        sim = scene.simulation(method="parametric", integrator=kind.split("-")[1])
        sim.advance_to(1e9)
    else:
        bead.sweep(scene, {"th1": np.linspace(0.0, 1.0, 10**5)}, steps=10**5)
except KeyboardInterrupt:
    if kind.startswith("advance_to"):
        # Stopped at a good state, from which the simulation goes on.
        t = sim.t
        assert 0 < t < 1e9, t
        assert np.isfinite(sim.positions).all() and np.isfinite(sim.energy), sim
        sim.advance_to(t + 0.5)
        assert sim.t == t + 0.5, (sim.t, t)
        assert np.isfinite(sim.positions).all() and np.isfinite(sim.energy), sim
    print("interrupted", flush=True)
    sys.exit(3)
print("finished", flush=True)
"""


def cpu_seconds(pid):
    """User + system CPU time of process `pid` so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")


@needs_proc
@pytest.mark.parametrize("kind", ["run", "step", "sweep"])
def test_ctrl_c_interrupts_promptly(kind):
    interrupt_child(kind)


@needs_proc
@pytest.mark.parametrize("integrator", ["rk4", "dopri5"])
def test_advance_to_stops_on_ctrl_c(integrator):
    """advance_to(t) far ahead stops at a good state on Ctrl-C, and the simulation goes on
    from there (it ignored the signal and ran to t)."""
    interrupt_child(f"advance_to-{integrator}")


@needs_proc
def test_dopri5_run_with_one_output_interval_stops_on_ctrl_c():
    """A run's Ctrl-C check inside an output interval: dopri5 takes all its steps inside the
    one interval of this run (the check came only after each interval)."""
    interrupt_child("run-dopri5")


def interrupt_child(kind):
    """Start CHILD doing `kind`, wait until it is busy inside the call, send SIGINT, and
    require that it caught KeyboardInterrupt (and passed its own checks) within 5 s."""
    child = subprocess.Popen([sys.executable, "-c", CHILD, kind,
                              scene_path("double-pendulum.toml")],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        # Wait until the child has burnt half a second of CPU past "ready": it is inside the
        # call, not before it (a SIGINT before the call would be raised by Python anyway).
        base = cpu_seconds(child.pid)
        deadline = time.monotonic() + 60
        while cpu_seconds(child.pid) < base + 0.5:
            assert child.poll() is None, child.stderr.read()
            assert time.monotonic() < deadline, "the child never got busy"
            time.sleep(0.02)
        sent = time.monotonic()
        child.send_signal(signal.SIGINT)
        code = child.wait(timeout=30)
        took = time.monotonic() - sent
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    out, err = child.communicate()
    assert code == 3, (code, out, err)
    assert out.strip() == "interrupted"
    assert took < 5.0, f"KeyboardInterrupt came {took:.1f} s after SIGINT"
