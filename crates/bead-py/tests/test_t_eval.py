"""`Scene.run(t_eval=...)`: the states at chosen times, exact to the integrator's accuracy,
against the closed form of uniformly accelerated motion along a helix."""

import numpy as np
import pytest

import bead
from conftest import ROOT

HELIX = ROOT / "scenes" / "helix.toml"
CIRCLE = ROOT / "scenes" / "circle.toml"
TIMES = np.array([0.0, 0.0123, 0.1, 1 / 3, 0.5, 1.0, np.e / 2, 2.0])


def phi(t, R=1.0, b=0.2, g=9.81, w0=3.0):
    return w0 * t - 0.5 * g * b / (R * R + b * b) * t * t


@pytest.mark.parametrize("integrator", ["rk4", "dopri5", "gauss-legendre", "verlet", "midpoint"])
def test_rows_are_at_the_times_asked_for_to_the_integrators_accuracy(integrator):
    run = bead.load(HELIX).run(method="parametric", integrator=integrator, dt=0.01, t_eval=TIMES)
    assert np.array_equal(run.t, TIMES)
    # Every method of order >= 2 integrates this quadratic motion exactly.
    assert np.max(np.abs(run.q[:, 0] - phi(TIMES))) < 1e-9
    assert np.max(np.abs(run.positions[:, 0, 2] - 0.2 * phi(TIMES))) < 1e-9
    assert run.completed and run.summary["t_final"] == TIMES[-1]


def test_rows_are_the_states_a_simulation_advanced_to_those_times_has():
    scene = bead.load(CIRCLE)
    run = scene.run(integrator="rk4", dt=0.01, t_eval=TIMES)
    sim = scene.simulation(integrator="rk4", dt=0.01)
    for k, t in enumerate(TIMES):
        sim.advance_to(t)
        assert np.array_equal(sim.positions, run.positions[k])
        assert np.array_equal(sim.constraint_force_vectors, run.constraint_force_vectors[k])


def test_a_stop_condition_ends_the_rows_before_it():
    run = bead.load(HELIX).run(method="parametric", t_eval=TIMES, stop_when="bead.z - 0.3")
    stop = run.summary["stop_time"]
    assert np.array_equal(run.t, TIMES[TIMES < stop])


@pytest.mark.parametrize("kwargs, words", [
    (dict(t_eval=[0.5, 0.2]), "must not decrease"),
    (dict(t_eval=[-1.0]), "finite and >= 0"),
    (dict(t_eval=[]), "at least one time"),
    (dict(t_eval=[1.0], duration=2.0), "t_eval and duration: give one"),
    (dict(t_eval=[1.0], every=2), "t_eval and every"),
])
def test_bad_times_are_refused(kwargs, words):
    with pytest.raises(ValueError, match=words):
        bead.load(CIRCLE).run(**kwargs)
