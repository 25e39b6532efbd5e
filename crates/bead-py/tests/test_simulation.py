"""A simulation stepped by hand lands on the same states as a run; the GIL is released while
anything steps."""

import sys
import threading
import time

import numpy as np
import pytest

import bead
from conftest import scene_path


@pytest.mark.parametrize("method,integrator", [("implicit", "rk4"), ("implicit", "rattle"),
                                               ("parametric", "gauss-legendre")])
def test_stepping_equals_the_run(method, integrator):
    scene = bead.load(scene_path("double-pendulum.toml"))
    dt, n = 0.002, 300
    run = scene.run(method=method, integrator=integrator, dt=dt, steps=n)
    sim = scene.simulation(method=method, integrator=integrator, dt=dt)
    assert (sim.t, sim.steps) == (0.0, 0)
    np.testing.assert_array_equal(sim.positions, run.positions[0])
    for k in range(1, n + 1):
        sim.step()
        if k % 50 == 0:
            assert sim.t == run.t[k]
            np.testing.assert_array_equal(sim.positions, run.positions[k])
            np.testing.assert_array_equal(sim.velocities, run.velocities[k])
            np.testing.assert_array_equal(sim.q, run.q[k])
            np.testing.assert_array_equal(sim.qdot, run.qdot[k])
            assert sim.energy == run.energy[k]
            assert sim.constraint_error == run.constraint_error[k]
    assert sim.steps == n


def test_advance_to_equals_the_run_and_lands_on_t():
    scene = bead.load(scene_path("parabola.toml"))
    run = scene.run(method="parametric", integrator="rk4", dt=0.01, steps=250)
    sim = scene.simulation(method="parametric", integrator="rk4", dt=0.01)
    sim.advance_to(1.0)
    np.testing.assert_array_equal(sim.positions, run.positions[100])
    sim.advance_to(2.5)
    np.testing.assert_array_equal(sim.q, run.q[250])
    sim.advance_to(2.505)  # off the grid: one shorter step lands on it
    assert sim.t == 2.505
    sim.reset()
    assert sim.t == 0.0 and sim.steps == 0
    assert sim.positions.shape == (1, 2) and sim.q.shape == (1,)
    assert "parametric rk4" in repr(sim)


def _progress_while(call):
    """How many times this thread ran while `call` ran in another thread (the worker reads
    the count the moment `call` returns).

    The switch interval is made so long that the interpreter never takes the GIL from a
    thread that holds it: if `call` kept the GIL, this thread could not run at all until it
    returned, and the count is 0; if `call` releases it, this thread counts meanwhile (and
    hands the GIL back at every `time.sleep(0)`)."""
    counter = [0]
    seen = []
    started = threading.Event()

    def worker():
        started.set()
        call()
        seen.append(counter[0])

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)
    try:
        thread = threading.Thread(target=worker)
        thread.start()
        started.wait()
        while thread.is_alive():
            counter[0] += 1
            time.sleep(0)
        thread.join()
    finally:
        sys.setswitchinterval(interval)
    return seen[0]


def test_the_gil_probe_sees_a_call_that_holds_the_gil():
    # sorted() of floats runs in C with the GIL held from start to end.
    data = [float((i * 7919) % 100_003) for i in range(300_000)]
    assert _progress_while(lambda: sorted(data)) == 0


def test_run_releases_the_gil():
    scene = bead.load(scene_path("double-pendulum.toml"))
    progress = _progress_while(lambda: scene.run(steps=200_000, every=200_000))
    assert progress > 0


def test_stepping_releases_the_gil():
    sim = bead.load(scene_path("double-pendulum.toml")).simulation()
    progress = _progress_while(lambda: sim.step(200_000))
    assert progress > 0


@pytest.mark.parametrize("integrator", ["rk4", "verlet", "dopri5"])
def test_a_run_ends_exactly_at_a_duration_off_the_grid_as_in_the_cli(integrator, cli_json):
    # Regression (issue 15): run(duration=1, dt=0.3) ended at t = 1.2, and dt=100 at 100.
    scene = bead.load(scene_path("circle.toml"))
    for dt, duration, rows in [(0.3, 1.0, 5), (100.0, 0.01, 2)]:
        run = scene.run(integrator=integrator, dt=dt, duration=duration)
        assert run.t[-1] == duration and run.summary["t_final"] == duration
        if integrator != "dopri5":
            assert len(run.t) == rows
            np.testing.assert_array_equal(run.t[:-1], np.arange(rows - 1) * dt)
        sim = scene.simulation(integrator=integrator, dt=dt)
        sim.advance_to(duration)
        np.testing.assert_array_equal(sim.positions, run.positions[-1])
        code, cli, err = cli_json(scene_path("circle.toml"), "--integrator", integrator,
                                  "--dt", repr(dt), "--duration", repr(duration))
        assert code == 0, err
        assert cli["t_final"] == duration
        assert cli["particles"]["bead"]["position"] == list(run.positions[-1, 0])


def test_newton_iterations_count_the_solver_work_of_every_step():
    scene = bead.load(scene_path("parabola.toml"))
    sim = scene.simulation(method="implicit", integrator="rattle", dt=1 / 60)
    assert sim.newton_iterations == 0
    sim.advance_to(60.0)
    # The README's figures for this scene: at most 2 iterations a step, warm-started.
    assert sim.steps == 3600
    assert sim.steps <= sim.newton_iterations <= 2 * sim.steps
    assert scene.simulation(method="implicit", integrator="rk4").newton_iterations is None
