"""bead.sweep: arrays shaped like the parameter grid, each member equal to a single run with
its values bit for bit, the same numbers whatever the threads or chunks, the CLI's columns."""

import csv
import pickle

import numpy as np
import pytest

import bead
from conftest import scene_path
from test_simulation import _progress_while

PENDULUM = scene_path("double-pendulum.toml")
FLIP = "(abs(theta1) + abs(theta2) + abs(abs(theta1) - abs(theta2)))/2 - pi"
FIELDS = ("t_final", "stop_time", "steps", "energy_rel_error_max", "energy_balance_error_max",
          "constraint_error_max", "positions", "velocities", "q", "qdot")


def same_bits(a, b):
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def assert_identical(x, y):
    for field in FIELDS:
        assert same_bits(getattr(x, field), getattr(y, field)), field
    assert x.status.tolist() == y.status.tolist()
    assert x.errors.tolist() == y.errors.tolist()
    for name in x.names:
        assert same_bits(x.params[name], y.params[name])


def test_grid_shapes_and_dtypes():
    scene = bead.load(PENDULUM)
    th1, th2 = np.linspace(0.5, 1.5, 3), np.linspace(-1.0, 2.0, 4)
    r = bead.sweep(scene, {"th1": th1, "th2": th2}, method="parametric", steps=20)
    assert r.shape == (3, 4) and len(r) == 12 and r.names == ["th1", "th2"]
    P, D, K = 2, 2, 2
    assert r.positions.shape == (3, 4, P, D) and r.velocities.shape == (3, 4, P, D)
    assert r.q.shape == (3, 4, K) and r.qdot.shape == (3, 4, K)
    for field in ("t_final", "stop_time", "energy_rel_error_max", "energy_balance_error_max",
                  "constraint_error_max"):
        assert getattr(r, field).shape == (3, 4) and getattr(r, field).dtype == np.float64
    assert r.steps.dtype == np.int64 and (r.steps == 20).all()
    assert r.status.dtype.kind == "U" and (r.status == "ok").all()
    assert np.isnan(r.stop_time).all() and r.errors.shape == (3, 4)
    assert all(e is None for e in r.errors.flat)
    # First axis outermost: member (i, j) has th1[i], th2[j].
    np.testing.assert_array_equal(r.params["th1"], np.repeat(th1[:, None], 4, axis=1))
    np.testing.assert_array_equal(r.params["th2"], np.repeat(th2[None, :], 3, axis=0))
    # The final angles are the ones the positions say.
    np.testing.assert_allclose(np.sin(r.q[..., 0]), r.positions[..., 0, 0], atol=1e-12)
    assert "3 x 4" not in repr(r) and "th1[3] x th2[4]" in repr(r) and "12 ok" in repr(r)
    assert r.particles == ["a", "b"] and r.coordinates == ["theta1", "theta2"]


def test_zip_shape_and_the_implicit_form():
    scene = bead.load(PENDULUM)
    n = 5
    r = bead.sweep(scene, {"th1": np.linspace(0, 1, n), "th2": np.linspace(1, 2, n)}, zip=True,
                   steps=10)
    assert r.shape == (n,) and r.positions.shape == (n, 2, 2) and r.method == "implicit"
    assert r.q is None and r.qdot is None and r.coordinates == []
    with pytest.raises(ValueError, match="zip=True: zipped parameters must have the same"):
        bead.sweep(scene, {"th1": [0.0, 1.0], "th2": [1.0]}, zip=True, steps=10)


@pytest.mark.parametrize("method,integrator", [("parametric", "rk4"), ("implicit", "rattle"),
                                               ("parametric", "gauss-legendre")])
def test_a_member_is_the_single_run_bit_for_bit(method, integrator):
    scene = bead.load(PENDULUM)
    th1, th2 = np.linspace(-3.0, 3.0, 4), np.array([0.3, 2.9])
    options = dict(method=method, integrator=integrator, dt=0.01, duration=3.0)
    if method == "parametric":
        options["stop_when"] = FLIP
    r = bead.sweep(scene, {"th1": th1, "th2": th2}, **options)
    for i, a in enumerate(th1):
        for j, b in enumerate(th2):
            run = scene.with_params({"th1": a, "th2": b}).run(every=10**6, **options)
            s = run.summary
            assert r.t_final[i, j] == s["t_final"] and r.steps[i, j] == s["steps"]
            stop = s.get("stop_time")
            assert (np.isnan(r.stop_time[i, j]) and stop is None) or r.stop_time[i, j] == stop
            assert r.status[i, j] == ("event" if stop is not None else "ok")
            assert r.energy_rel_error_max[i, j] == s["energy_rel_error_max"]
            assert np.isnan(r.energy_balance_error_max[i, j])
            assert "energy_balance_error_max" not in s
            assert r.constraint_error_max[i, j] == s["constraint_error_max"]
            assert same_bits(r.positions[i, j], run.positions[-1])
            assert same_bits(r.velocities[i, j], run.velocities[-1])
            if method == "parametric":
                assert same_bits(r.q[i, j], run.q[-1]) and same_bits(r.qdot[i, j], run.qdot[-1])
    if method == "parametric":
        assert (r.status == "event").any(), "some members flip within 3 s"


def test_threads_and_chunks_change_nothing():
    scene = bead.load(PENDULUM)
    sweep = bead.Sweep(scene, {"th1": np.linspace(-3, 3, 7), "th2": np.linspace(-2, 2.5, 5)},
                       method="parametric", dt=0.01, duration=2.0, stop_when=FLIP)
    one = sweep.run(threads=1)
    two = sweep.run(threads=2)
    assert_identical(one, two)
    # Uneven chunks, run in another order, on other thread counts, one through pickle (as a
    # process or a machine elsewhere would receive it).
    parts = [sweep.run_range(20, 35, threads=2), sweep.run_range(0, 3, threads=1),
             pickle.loads(pickle.dumps(sweep)).run_range(3, 20, threads=3)]
    assert parts[0].shape == (15,) and parts[0].members == range(20, 35)
    assert "members 20..35 of 35" in repr(parts[0])
    assert_identical(sweep.assemble(parts), one)
    # bead.sweep(members=...) is run_range.
    chunk = bead.sweep(scene, {"th1": np.linspace(-3, 3, 7), "th2": np.linspace(-2, 2.5, 5)},
                       method="parametric", dt=0.01, duration=2.0, stop_when=FLIP,
                       members=range(3, 20))
    assert_identical(chunk, parts[2])
    assert sweep.chunks(3) == [(0, 11), (11, 23), (23, 35)]
    with pytest.raises(ValueError, match="leave a gap at member 0"):
        sweep.assemble(parts[:1] + parts[2:])
    with pytest.raises(ValueError, match="end at member 20 of 35"):
        sweep.assemble(parts[1:])


def test_a_sweep_and_a_scene_pickle_as_plain_data():
    scene = bead.load(PENDULUM, params={"g": 1.62})
    again = pickle.loads(pickle.dumps(scene))
    assert (again.text, again.file, again.params) == (scene.text, scene.file, scene.params)
    sweep = bead.Sweep(scene, {"m2": [1.0, 2.0]}, steps=5)
    blob = pickle.dumps(sweep)
    assert len(blob) < 4 * len(scene.text) + 2000
    copy = pickle.loads(blob)
    assert copy.options == {"steps": 5} and copy.scene.params["g"] == 1.62
    assert_identical(copy.run(), sweep.run())


def test_to_pandas_and_table_equal_the_cli_csv(cli, tmp_path):
    pytest.importorskip("pandas")
    out = tmp_path / "sweep.csv"
    code, _, err = cli("sweep", PENDULUM, "--param", "th1=-3:3:4", "--param", "th2=0.5:2.5:3",
                       "--method", "parametric", "--dt", "0.01", "--duration", "2",
                       "--stop-when", FLIP, "--out", out)
    assert code == 0, err
    with open(out, newline="") as f:
        header, *rows = list(csv.reader(f))
    r = bead.sweep(bead.load(PENDULUM), {"th1": np.linspace(-3, 3, 4),
                                         "th2": np.linspace(0.5, 2.5, 3)},
                   method="parametric", dt=0.01, duration=2.0, stop_when=FLIP)
    assert r.columns == header
    frame = r.to_pandas()
    assert list(frame.columns) == header and len(frame) == len(rows) == 12
    for row, (_, got) in zip(rows, frame.iterrows()):
        for name, text in zip(header, row):
            value = got[name]
            if name in ("status",):
                assert value == text
            elif name == "error":
                assert (value or "") == text
            elif text == "":
                assert np.isnan(value)
            else:
                assert float(value) == float(text), name


def test_failed_members_are_reported_not_raised():
    scene = bead.load(PENDULUM)
    r = bead.sweep(scene, {"m1": [1.0, -1.0, 2.0]}, steps=10)
    assert r.status.tolist() == ["ok", "failed", "ok"]
    assert "mass" in r.errors[1] and r.errors[0] is None
    assert np.isnan(r.t_final[1]) and r.steps[1] == 0 and np.isnan(r.positions[1]).all()
    assert r.counts() == {"ok": 2, "event": 0, "failed": 1}


def test_bad_sweeps_say_what_to_do_in_python():
    scene = bead.load(PENDULUM)
    with pytest.raises(ValueError) as caught:
        bead.sweep(scene, {"x0": [1.0, 2.0]})
    text = str(caught.value)
    assert text.startswith('params["x0"]: not a parameter of the scene; the scene\'s parameters '
                           "are L1, L2, m1, m2, g, th1, th2")
    assert "[params] table" in text and "--" not in text
    with pytest.raises(ValueError, match=r'params\["th1"\]: NaN is not a finite number'):
        bead.sweep(scene, {"th1": [0.0, np.nan]})
    with pytest.raises(ValueError, match="no values to sweep"):
        bead.sweep(scene, {"th1": []})
    with pytest.raises(ValueError, match="a 1-D array"):
        bead.sweep(scene, {"th1": np.zeros((2, 2))})
    with pytest.raises(ValueError, match="dt=0: must be a finite number > 0"):
        bead.sweep(scene, {"th1": [0.0]}, dt=0.0)
    with pytest.raises(ValueError, match="stop_when: "):
        bead.sweep(scene, {"th1": [0.0]}, stop_when="theta9")
    with pytest.raises(ValueError, match="t_eval and every: give one"):
        bead.Sweep(scene, {"th1": [0.0]}, every=3, t_eval=[0.0, 1.0])
    # Loading with an unknown parameter: Python words, not the command line's --set.
    with pytest.raises(bead.SceneError) as caught:
        bead.load(PENDULUM, params={"x0": 1.0})
    assert caught.value.message.startswith('params["x0"]: unknown parameter `x0`')
    assert "--set" not in str(caught.value) and "[params] table" in str(caught.value)


def test_a_sweep_releases_the_gil():
    scene = bead.load(PENDULUM)
    values = np.linspace(0.1, 1.0, 400)
    progress = _progress_while(lambda: bead.sweep(scene, {"th1": values}, steps=2000))
    assert progress > 0


def test_help_says_what_sweep_does():
    import pydoc

    text = pydoc.render_doc(bead.sweep, renderer=pydoc.plaintext)
    assert "once per combination of parameter values" in text and "stop_when" in text
    assert "bit for bit" in bead.Sweep.__doc__
    assert "``positions``, ``velocities`` ``shape + (P, D)``" in bead.SweepResult.__doc__


CHAIN = """title = "chain"
[params]
N = 2
[world]
gravity = [0.0, 9.81]
[[particle]]
for = { i = "0..N" }
name = "p{i}"
mass = 1.0
position = ["i+1", 0.0]
[[constraint]]
name = "pivot"
kind = "distance"
particle = "p0"
anchor = [0.0, 0.0]
length = 1.0
[[constraint]]
for = { i = "1..N" }
name = "rod {i}"
kind = "distance"
between = ["p{i-1}", "p{i}"]
length = 1.0
[run]
integrator = "rattle"
dt = 0.01
"""


def test_sweep_refuses_members_with_another_particle_count():
    """The arrays are shaped grid + (P, D) with the scene's P: a member with another number of
    particles is a ValueError naming it, never arrays of mixed members."""
    scene = bead.loads(CHAIN, name="chain.toml")
    with pytest.raises(ValueError) as caught:
        bead.sweep(scene, {"N": [2, 3, 4]}, steps=5)
    text = str(caught.value)
    assert text.startswith("member 1 (N = 3) has 3 particles (p0, p1, p2), where the scene "
                           "swept has 2 (p0, p1): a sweep's arrays have the scene's particles"), text
    assert "P = 2" in text and "--format long" in text
    # Members of the scene's count are fine, whatever the values.
    r = bead.sweep(scene, {"N": [2, 2.0]}, steps=5)
    assert r.positions.shape == (2, 2, 2)


def test_sweep_count_beyond_limit_is_an_error_not_an_abort():
    """10^8 members killed the interpreter (an allocation abort); past the memory limit of
    the result, or 2^32 members, a sweep is a ValueError that says what to do."""
    scene = bead.load(PENDULUM)
    grid = {"th1": np.linspace(1, 2, 10**4), "th2": np.linspace(1, 2, 10**4)}
    with pytest.raises(ValueError) as caught:
        bead.sweep(scene, grid, steps=1)
    text = str(caught.value)
    assert text.startswith("100000000 members need about 20.9 GB for their result arrays "
                           "(209 bytes each: 2 parameter(s), 2 particle(s) in 2D, 0 generalized "
                           "coordinate(s)), more than the 8 GiB a sweep returns at once"), text
    assert "sweep.run_range(start, stop)" in text and "sweep.chunks(" in text
    # A chunk that fits runs.
    plan = bead.Sweep(scene, grid, steps=1)
    assert len(plan) == 10**8 and len(plan.run_range(10**8 - 3, 10**8)) == 3
    with pytest.raises(ValueError, match="more than the 4294967296 \\(2\\^32\\) a sweep may have"):
        bead.Sweep(scene, {"th1": np.linspace(1, 2, 2**17), "th2": np.linspace(1, 2, 2**16)})
    with pytest.raises(ValueError, match="start=-1"):
        plan.run_range(-1, 3)
    with pytest.raises(IndexError, match="members 5..3 are not in the sweep"):
        plan.run_range(5, 3)
    with pytest.raises(ValueError, match="threads=-1"):
        plan.run_range(0, 3, threads=-1)


def test_sweep_where_every_member_fails_raises_run_error():
    scene = bead.load(PENDULUM)
    with pytest.raises(bead.RunError) as caught:
        bead.sweep(scene, {"m1": [-1.0, -2.0]}, steps=10)
    error = caught.value
    assert str(error).startswith("every member of the sweep failed (2 of 2); the first, "
                                 "member 0 (m1 = -1.0): "), str(error)
    assert "mass" in str(error)
    assert error.result.counts() == {"ok": 0, "event": 0, "failed": 2}
    # A chunk is returned (a chunk of failures may be part of a sweep that ran); the whole,
    # assembled, raises.
    plan = bead.Sweep(scene, {"m1": [-1.0, -2.0]}, steps=10)
    parts = [plan.run_range(0, 1), plan.run_range(1, 2)]
    assert parts[0].status.tolist() == ["failed"]
    with pytest.raises(bead.RunError, match="every member of the sweep failed"):
        plan.assemble(parts)
    assert bead.sweep(scene, {"m1": [-1.0, -2.0]}, steps=10, members=range(0, 2)).counts()[
        "failed"] == 2


def test_sweep_and_run_name_the_energy_errors_alike():
    """energy_rel_error_max is the run summary's |E - E0| / E_scale in every front end, and
    energy_balance_error_max its |E - W - E0| / E_scale where something does work."""
    with open(scene_path("double-pendulum.toml")) as f:
        text = f.read()
    scene = bead.loads(text + '\n[[force]]\nkind = "drag"\ncoefficient = 0.3\n',
                       name="drag.toml")
    r = bead.sweep(scene, {"th1": [0.5, 1.0]}, method="parametric", dt=0.01, steps=50)
    assert not hasattr(r, "energy_error_max")
    for i, th1 in enumerate([0.5, 1.0]):
        s = scene.with_params({"th1": th1}).run(method="parametric", dt=0.01, steps=50).summary
        assert r.energy_rel_error_max[i] == s["energy_rel_error_max"]
        assert r.energy_balance_error_max[i] == s["energy_balance_error_max"]
        assert r.constraint_error_max[i] == s["constraint_error_max"]
    frame = r.table()
    assert frame["energy_balance_error_max"].tolist() == r.energy_balance_error_max.tolist()
    assert r.columns[5:9] == ["steps", "energy_rel_error_max", "energy_balance_error_max",
                              "constraint_error_max"]
