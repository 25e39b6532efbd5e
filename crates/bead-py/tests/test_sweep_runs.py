"""Sweeps over the run itself: lists of integrators and step sizes as axes of the grid, and
members that record their states (`every=K`, `t_eval=`) as arrays shaped grid + (T, ...),
MuJoCo's `rollout`. Each member equals its run alone bit for bit; the trajectories are
checked against the helix's closed form and the observed orders against the integrators'."""

import csv
import pickle

import numpy as np
import pytest

import bead
from conftest import ROOT

CIRCLE = ROOT / "scenes" / "circle.toml"
HELIX = ROOT / "scenes" / "helix.toml"
PARABOLA = ROOT / "scenes" / "parabola-x0.toml"
TIMES = np.array([0.0, 0.0123, 0.1, 1 / 3, 0.5, 1.0, np.e / 2, 2.0])


def same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def phi(t, w0, R=1.0, b=0.2, g=9.81):
    """The helix's angle under gravity along its axis: uniformly decelerated."""
    return w0 * t - 0.5 * g * b / (R * R + b * b) * t * t


@pytest.mark.parametrize("method,integrators", [
    ("implicit", ["rk4", "rattle", "midpoint", "dopri5"]),
    ("parametric", ["rk4", "gauss-legendre", "verlet"]),
])
def test_an_integrator_and_dt_grid_is_the_runs_alone_bit_for_bit(method, integrators):
    scene = bead.load(CIRCLE)
    dts = [1e-2, 5e-3]
    thetas = [0.5, 1.0]
    r = bead.sweep(scene, {"theta0": thetas}, integrator=integrators, dt=dts, method=method,
                   duration=1.5)
    assert r.shape == (len(integrators), 2, 2)
    assert r.names == ["integrator", "dt", "theta0"]
    assert list(r.axes["integrator"]) == integrators
    for i, integrator in enumerate(integrators):
        for j, dt in enumerate(dts):
            for k, theta0 in enumerate(thetas):
                assert r.params["integrator"][i, j, k] == integrator
                assert r.params["dt"][i, j, k] == dt and r.params["theta0"][i, j, k] == theta0
                alone = scene.with_params({"theta0": theta0}).run(
                    integrator=integrator, dt=dt, method=method, duration=1.5)
                s = alone.summary
                for field in ("energy_rel_error_max", "constraint_error_max", "t_final",
                              "steps"):
                    assert r.__dict__[field][i, j, k] == s[field], (integrator, dt, field)
                newton = s.get("newton_iterations")
                got = r.newton_iterations[i, j, k]
                assert np.isnan(got) if newton is None else got == newton, (integrator, dt)
                assert same_bits(r.positions[i, j, k], alone.positions[-1])
                assert same_bits(r.velocities[i, j, k], alone.velocities[-1])
    table = r.to_pandas()
    assert list(table.columns[:4]) == ["member", "integrator", "dt", "theta0"]
    assert table["integrator"].tolist() == list(r.params["integrator"].ravel())
    assert np.array_equal(table["t_final"], r.t_final.ravel())


@pytest.mark.parametrize("integrator,project", [
    ("rattle", False), ("rattle4", False), ("rk4", True), ("rk4", False)])
def test_newton_iterations_agree_in_the_csv_the_arrays_and_a_simulation(
        cli, tmp_path, integrator, project):
    """The Newton iterations a member's steps took: `bead sweep`'s column, the sweep's
    array and a `Simulation` stepped by hand to the same time count the same solves; an
    integrator that solves nothing has an empty column and NaN."""
    thetas = np.linspace(0.5, 2.5, 3)
    out = tmp_path / "sweep.csv"
    flags = ["--project"] if project else []
    code, _, err = cli("sweep", CIRCLE, "--param", "theta0=0.5:2.5:3", "--integrator",
                       integrator, "--dt", "0.01", "--duration", "1.5", *flags, "--out", out)
    assert code == 0, err
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    r = bead.sweep(bead.load(CIRCLE), {"theta0": thetas},
                   integrator=integrator, dt=0.01, duration=1.5, project=project)
    scene = bead.load(CIRCLE)
    for k, theta0 in enumerate(thetas):
        sim = scene.with_params({"theta0": theta0}).simulation(
            integrator=integrator, dt=0.01, project=project)
        sim.advance_to(1.5)
        assert sim.steps == r.steps[k] == 150
        if sim.newton_iterations is None:
            assert integrator == "rk4" and not project
            assert np.isnan(r.newton_iterations[k]) and rows[k]["newton_iterations"] == ""
        else:
            # RATTLE: at least one iteration a step (rattle4: a stage); a projection may
            # find a step already on the circle.
            assert sim.newton_iterations >= (1 if project else 150)
            assert r.newton_iterations[k] == sim.newton_iterations
            assert int(rows[k]["newton_iterations"]) == sim.newton_iterations


def test_observed_orders_from_one_sweep_over_dt():
    """rk4's energy error falls as dt^4, rattle's (bounded) as dt^2: the pendulum at 60
    degrees, halving dt three times, read from one sweep."""
    scene = bead.load(CIRCLE)
    dts = 0.02 / 2.0 ** np.arange(4)
    r = bead.sweep(scene, integrator=["rk4", "rattle"], dt=dts, duration=4.0)
    assert r.shape == (2, 4) and r.names == ["integrator", "dt"]
    orders = np.log2(r.energy_rel_error_max[:, :-1] / r.energy_rel_error_max[:, 1:])
    assert np.all(np.abs(orders[0] - 4.0) < 0.1), orders
    assert np.all(np.abs(orders[1] - 2.0) < 0.1), orders


@pytest.mark.parametrize("method,integrator,bound", [
    ("parametric", "rk4", 1e-9), ("parametric", "dopri5", 1e-9),
    ("parametric", "gauss-legendre", 1e-9), ("implicit", "rattle", 1e-3),
    ("implicit", "dopri5", 1e-5),
])
def test_t_eval_trajectories_follow_the_closed_form_at_every_time(method, integrator, bound):
    """Uniformly decelerated motion along a helix: every member's states at the times asked
    for, against phi(t), for several initial rates (exact to rounding where the method
    integrates the quadratic phi(t) exactly: the parametric form; to the method's accuracy
    in the implicit form); each the run alone's rows bit for bit."""
    scene = bead.load(HELIX)
    w0 = np.array([1.0, 3.0, 5.0])
    r = bead.sweep(scene, {"w0": w0}, method=method, integrator=integrator, dt=0.01,
                   t_eval=TIMES)
    traj = r.trajectory
    assert traj.t.shape == (3, len(TIMES)) and traj.positions.shape == (3, len(TIMES), 1, 3)
    assert np.array_equal(traj.t, np.broadcast_to(TIMES, (3, len(TIMES))))
    assert traj.rows.tolist() == [len(TIMES)] * 3
    exact = phi(TIMES[None, :], w0[:, None])
    assert np.max(np.abs(traj.positions[:, :, 0, 2] - 0.2 * exact)) < bound
    if method == "parametric":
        assert traj.q.shape == (3, len(TIMES), 1)
        assert np.max(np.abs(traj.q[..., 0] - exact)) < 1e-9
    else:
        assert traj.q is None and traj.qdot is None
    for k, value in enumerate(w0):
        alone = scene.with_params({"w0": value}).run(
            method=method, integrator=integrator, dt=0.01, t_eval=TIMES)
        for name in ("t", "positions", "velocities", "energy", "constraint_error"):
            assert same_bits(getattr(traj, name)[k], getattr(alone, name)), name
        if method == "parametric":
            assert same_bits(traj.q[k], alone.q) and same_bits(traj.qdot[k], alone.qdot)
        assert r.t_final[k] == alone.summary["t_final"] == TIMES[-1]


def test_every_k_trajectories_are_the_runs_rows_and_stopped_members_pad_with_nan():
    """The parabola released from several x0 with a terminal event at the bottom: members
    that stop earlier record fewer rows, NaN after them; each member's rows are run(every=K)'s."""
    scene = bead.load(PARABOLA)
    x0 = np.array([20.0, 100.0, 200.0])
    options = dict(integrator="rk4", dt=1 / 60, duration=5.0, every=10, stop_when="-bead.x")
    r = bead.sweep(scene, {"x0": x0}, **options)
    traj = r.trajectory
    assert (r.status == "event").all()
    rows = []
    for k, value in enumerate(x0):
        alone = scene.with_params({"x0": value}).run(**options)
        n = len(alone.t)
        rows.append(n)
        assert traj.rows[k] == n
        assert same_bits(traj.t[k, :n], alone.t)
        assert same_bits(traj.positions[k, :n], alone.positions)
        assert np.isnan(traj.t[k, n:]).all() and np.isnan(traj.positions[k, n:]).all()
        # The last row is the state where the event fired.
        assert traj.t[k, n - 1] == r.stop_time[k] and abs(traj.positions[k, n - 1, 0, 0]) < 1e-9
    assert traj.t.shape[-1] == max(rows) and len(set(rows)) > 1
    # Recording every K-th step changes no figure of a member.
    quiet = bead.sweep(scene, {"x0": x0}, **{k: v for k, v in options.items() if k != "every"})
    for field in ("stop_time", "energy_rel_error_max", "steps", "positions"):
        assert same_bits(getattr(quiet, field), getattr(r, field)), field
    assert quiet.trajectory is None


def test_dt_swept_with_every_gives_each_member_its_own_grid():
    scene = bead.load(CIRCLE)
    r = bead.sweep(scene, dt=[0.01, 0.005], every=25, duration=1.0)
    traj = r.trajectory
    assert traj.rows.tolist() == [5, 9] and traj.t.shape == (2, 9)
    assert np.allclose(traj.t[0, :5], [0, 0.25, 0.5, 0.75, 1.0], rtol=0, atol=1e-15)
    assert np.isnan(traj.t[0, 5:]).all()
    assert np.allclose(traj.t[1], np.arange(9) * 0.125, rtol=0, atol=1e-15)


def test_chunks_threads_and_pickles_change_nothing_with_run_axes_and_trajectories():
    scene = bead.load(CIRCLE)
    plan = bead.Sweep(scene, {"theta0": [0.3, 0.6, 0.9]}, integrator=["rk4", "rattle"],
                      dt=[0.01, 0.02], t_eval=[0.0, 0.5, 1.0])
    assert len(plan) == 12 and plan.shape == (2, 2, 3)
    assert plan.names == ["integrator", "dt", "theta0"]
    whole = plan.run(threads=1)
    again = pickle.loads(pickle.dumps(plan))
    parts = [again.run_range(a, b, threads=2) for a, b in [(0, 5), (5, 7), (7, 12)]]
    joined = plan.assemble(reversed(parts))
    for name in ("t", "positions", "velocities", "energy", "rows"):
        assert same_bits(getattr(whole.trajectory, name), getattr(joined.trajectory, name))
    for field in ("energy_rel_error_max", "positions", "t_final"):
        assert same_bits(getattr(whole, field), getattr(joined, field))
    assert whole.params["integrator"].tolist() == joined.params["integrator"].tolist()
    # A chunk across two integrators: each member's own integrator.
    chunk = plan.run_range(4, 8)
    assert chunk.params["integrator"].tolist() == ["rk4", "rk4", "rattle", "rattle"]
    assert same_bits(chunk.positions, whole.positions.reshape(12, 1, 2)[4:8])
    assert "integrator[2] x dt[2] x theta0[3]" in repr(plan)


def test_bad_run_axes_say_what_and_where():
    scene = bead.load(CIRCLE)
    with pytest.raises(ValueError, match="the members with integrator='leapfrog'"):
        bead.sweep(scene, integrator=["rk4", "leapfrog"])
    with pytest.raises(ValueError, match="the members with dt=-0.1: dt=-0.1: must be"):
        bead.sweep(scene, dt=[0.1, -0.1])
    with pytest.raises(ValueError, match="dt: no values to sweep"):
        bead.sweep(scene, dt=[])
    with pytest.raises(ValueError, match="integrator=.*listed twice"):
        bead.sweep(scene, integrator=["rk4", "rk4"])
    with pytest.raises(TypeError, match=r"integrator\[1\] = 3"):
        bead.sweep(scene, integrator=["rk4", 3])
    with pytest.raises(ValueError, match="a sweep needs values to sweep"):
        bead.sweep(scene)
    with pytest.raises(ValueError, match=r"t_eval\[1\] = 0.5 is before"):
        bead.sweep(scene, dt=[0.1], t_eval=[1.0, 0.5])
    # rattle runs only the implicit form: refused before any member runs.
    with pytest.raises(bead.SetupError, match="the members with integrator='rattle': rattle needs"):
        bead.sweep(scene, integrator=["gauss-legendre", "rattle"], method="parametric")


def test_run_axes_together_are_held_to_the_8_gib_of_one_sweep():
    """Each integrator's share fits, all of them together do not: refused before running."""
    scene = bead.load(CIRCLE)
    plan = bead.Sweep(scene, {"theta0": np.linspace(0.1, 1.0, 30)},
                      integrator=["rk4", "rattle", "midpoint"], t_eval=np.linspace(0.0, 1.0, 10**6))
    share = 30 * plan._plans[0].bytes_per_member
    assert 3 << 30 < share < 8 << 30
    with pytest.raises(ValueError, match=r"90 members need about .* GiB .* sweep.chunks\("):
        plan.run()
