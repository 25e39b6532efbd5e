"""States set from Python, forces applied and parameters changed during a run, constraint
forces read: each against physics computed here (the pendulum's tension from Newton's law
along the rod, the work of a constant force, the closest point of a parabola)."""

import pickle
import warnings

import numpy as np
import pytest

import bead
from conftest import ROOT

CIRCLE = ROOT / "scenes" / "circle.toml"
PARABOLA = ROOT / "scenes" / "parabola.toml"


def closest_on_parabola(a, b):
    """The point of y = -x^2/100 closest to (a, b) (Newton on the distance's derivative)."""
    x = a
    for _ in range(100):
        f = (x - a) + (x * x / 100 + b) * x / 50
        df = 1 + (3 * x * x / 100 + b) / 50
        x -= f / df
    return np.array([x, -x * x / 100])


def rod_force(x, v, m=1.0, g=9.81):
    """The rod's force on the bead at x moving with v (implicit form: d^2|x|^2/dt^2 = 0, so
    T = m (g y / r + |v|^2 / r) toward the pivot; on the circle m (g cos th + L thdot^2))."""
    r = np.linalg.norm(x, axis=-1, keepdims=True)
    tension = m * (g * x[..., 1:2] / r + np.sum(v * v, axis=-1, keepdims=True) / r)
    return -tension * x / r


@pytest.mark.parametrize("method", ["implicit", "parametric"])
def test_a_state_off_the_curve_is_placed_at_the_closest_point_with_a_warning(method):
    sim = bead.load(PARABOLA).simulation(method=method, dt=1e-3)
    sim.advance_to(0.25)
    with pytest.warns(UserWarning, match="set_state moved the positions by"):
        sim.set_state(positions=[[100.0, -90.0]], velocities=[[10.0, 5.0]])
    point = closest_on_parabola(100.0, -90.0)
    tangent = np.array([1.0, -point[0] / 50])
    v = tangent * (np.dot([10.0, 5.0], tangent) / np.dot(tangent, tangent))
    assert np.allclose(sim.positions[0], point, rtol=0, atol=1e-9)
    assert np.allclose(sim.velocities[0], v, rtol=0, atol=1e-9)
    assert sim.t == 0.25 and sim.steps == 0
    # A state on the constraints is taken as it is, without a warning.
    on = sim.positions.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim.set_state(positions=on, t=1.0)
    assert np.array_equal(sim.positions, on) and sim.t == 1.0


def test_both_forms_from_one_initial_state_start_and_stay_together():
    scene = bead.load(PARABOLA)
    initial = {"positions": [[-80.0, -64.0]], "velocities": [[30.0, 48.0]]}
    runs = [scene.run(method=m, dt=1e-3, duration=1.0, initial=initial)
            for m in ("implicit", "parametric")]
    assert np.allclose(runs[0].positions[0], runs[1].positions[0], rtol=0, atol=1e-12)
    assert np.array_equal(runs[0].positions[0, 0], [-80.0, -64.0])
    assert runs[1].q[0, 0] == pytest.approx(-80.0, abs=1e-12)
    assert np.allclose(runs[0].positions[-1], runs[1].positions[-1], rtol=0, atol=1e-6)
    started = scene.with_state(**initial)
    assert started.run(method="implicit", dt=1e-3, duration=1.0).positions.tobytes() == \
        runs[0].positions.tobytes()
    # The start travels with the scene: through pickling and new parameters.
    again = pickle.loads(pickle.dumps(started))
    assert np.array_equal(again.start["positions"], [-80.0, -64.0])
    run = again.with_params({"g": 100.0}).run(method="parametric", steps=1)
    assert run.q[0, 0] == pytest.approx(-80.0, abs=1e-12)


def test_the_rod_tension_is_newtons_in_both_forms_through_every_output():
    scene = bead.load(CIRCLE)
    for method in ("implicit", "parametric"):
        run = scene.run(method=method, integrator="rk4", dt=1e-3, duration=2.0, every=10)
        forces = run.constraint_force_vectors
        assert forces.shape == (len(run), 1, 2)
        expected = rod_force(run.positions, run.velocities)
        assert np.max(np.abs(forces - expected)) < 1e-9 * np.max(np.abs(expected))
        sim = scene.simulation(method=method, dt=1e-3)
        sim.advance_to(1.0)
        k = np.searchsorted(run.t, 1.0)
        assert np.array_equal(sim.constraint_force_vectors, forces[k])
        if method == "implicit":
            lam = run.constraint_forces
            assert lam.shape == (len(run), 1)
            # F = J^T lambda = lambda (2x, 2y).
            assert np.allclose(2 * lam[:, :, None] * run.positions, forces, rtol=1e-12, atol=0)
            assert np.array_equal(sim.constraint_forces, lam[k])
        else:
            with pytest.raises(ValueError, match="no constraint rows"):
                run.constraint_forces
            with pytest.raises(ValueError, match="no constraint rows"):
                sim.constraint_forces
    # At the bottom, moving at speed v: T = m (g + v^2 / L).
    sim = scene.simulation(dt=1e-3)
    sim.set_state(positions=[[0.0, 1.0]], velocities=[[2.0, 0.0]])
    assert sim.constraint_force_vectors[0] == pytest.approx([0.0, -(9.81 + 4.0)], abs=1e-12)


@pytest.mark.parametrize("method", ["implicit", "parametric"])
def test_a_held_force_acts_until_removed_and_the_ledger_counts_its_work(method):
    sim = bead.load(CIRCLE).simulation(method=method, dt=1e-3)
    x0 = sim.positions[0, 0]
    sim.apply_force("bead", [3.0, 0.0])
    assert list(sim.applied_forces) == ["bead"]
    sim.advance_to(1.5)
    # A constant force F does the work F . (x - x0).
    assert sim.work == pytest.approx(3.0 * (sim.positions[0, 0] - x0), rel=1e-9)
    assert sim.energy - sim.work == pytest.approx(sim.energy_initial, abs=1e-9)
    # The push shows in the constraint force (the rod takes its radial part).
    x, v = sim.positions[0], sim.velocities[0]
    radial = -(v @ v) - (9.81 * x[1] + 3.0 * x[0])
    assert sim.constraint_force_vectors[0] == pytest.approx(radial * x, abs=1e-9)
    sim.apply_force(0, None)
    assert sim.applied_forces == {}
    work = sim.work
    sim.advance_to(2.0)
    # Without it only the rounding of the constraint force's work is left.
    assert sim.work == pytest.approx(work, abs=1e-9)


def test_a_parameter_changed_mid_run_goes_on_from_the_state():
    scene = bead.load(CIRCLE)
    sim = scene.simulation(method="parametric", dt=1e-3)
    sim.advance_to(0.5)
    t, q, qdot = sim.t, sim.q.copy(), sim.qdot.copy()
    sim.set_param("g", 5.0)
    assert (sim.t, sim.params["g"]) == (0.5, 5.0)
    assert np.array_equal(sim.q, q) and np.array_equal(sim.qdot, qdot)
    sim.advance_to(1.0)
    # The same as a simulation of the scene with g = 5 set to that state.
    other = scene.with_params({"g": 5.0}).simulation(method="parametric", dt=1e-3)
    other.set_state(q=q, qdot=qdot, t=t)
    other.advance_to(1.0)
    assert np.array_equal(sim.q, other.q)
    # A longer rod: the bead is placed on it, with a warning saying how far.
    sim = scene.simulation(method="implicit", dt=1e-3)
    with pytest.warns(UserWarning, match=r"set_param moved the positions by 1(\.0*)? "):
        sim.set_param("L", 2.0)
    assert np.linalg.norm(sim.positions[0]) == pytest.approx(2.0, abs=1e-12)


def test_bad_arguments_say_what_and_change_nothing():
    sim = bead.load(PARABOLA).simulation()
    before = sim.positions.copy()
    with pytest.raises(ValueError, match="positions need 2 numbers, got 3"):
        sim.set_state(positions=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="either positions or q"):
        bead.load(PARABOLA).simulation(method="parametric").set_state(positions=[0, 0], q=[0])
    with pytest.raises(ValueError, match="no particle named 'ghost'; the particles are bead"):
        sim.apply_force("ghost", [1.0, 0.0])
    with pytest.raises(ValueError, match="needs 2 numbers"):
        sim.apply_force("bead", [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="unknown"):
        sim.set_param("zz", 1.0)
    with pytest.raises(ValueError, match="unknown key 'pos'"):
        bead.load(PARABOLA).run(steps=1, initial={"pos": [0, 0]})
    free = bead.loads('[world]\ngravity = [0, 9.81]\n[[particle]]\nname = "a"\nmass = 1\n'
                      'position = [0, 0]\n')
    with pytest.raises(ValueError, match=r"has no \[parametric\] table"):
        free.with_state(q=[1.0])
    assert np.array_equal(sim.positions, before) and sim.steps == 0
