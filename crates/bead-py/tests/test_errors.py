"""Errors are Python exceptions with locations; bad arguments are ValueErrors; a failed run
carries the run up to its last good state."""

import pickle

import numpy as np
import pytest

import bead
from conftest import scene_path

BAD_MASS = """[world]
gravity = [0.0, 1.0]
[[particle]]
name = "a"
mass = -1.0
position = [0.0, 0.0]
velocity = [0.0, 0.0]
"""


def test_scene_error_has_its_location_and_the_caret_text():
    with pytest.raises(bead.SceneError) as caught:
        bead.loads(BAD_MASS, name="bad.toml")
    e = caught.value
    assert (e.path, e.line, e.column) == ("bad.toml", 5, 8)
    assert e.message == "particle 1: `mass` must be positive, got -1"
    assert str(e) == "bad.toml:5:8: particle 1: `mass` must be positive, got -1\n  mass = -1.0\n         ^^^^"
    assert isinstance(e, ValueError) and isinstance(e, bead.BeadError)
    again = pickle.loads(pickle.dumps(e))
    assert (again.line, again.column, str(again)) == (5, 8, str(e))


def test_scene_error_from_a_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(BAD_MASS)
    with pytest.raises(bead.SceneError) as caught:
        bead.load(path)
    assert (caught.value.path, caught.value.line, caught.value.column) == (str(path), 5, 8)


def test_missing_file_is_a_scene_error_without_a_position(tmp_path):
    with pytest.raises(bead.SceneError) as caught:
        bead.load(tmp_path / "none.toml")
    assert caught.value.line == 0 and "cannot read the scene file" in caught.value.message


def test_unknown_param_is_a_value_error():
    with pytest.raises(ValueError, match="unknown parameter `gg`"):
        bead.load(scene_path("parabola.toml"), params={"gg": 1.0})
    with pytest.raises(ValueError, match="not a finite number"):
        bead.load(scene_path("parabola.toml"), params={"g": float("nan")})
    with pytest.raises(TypeError, match="must be a finite number, not a str"):
        bead.load(scene_path("parabola.toml"), params={"g": "heavy"})
    with pytest.raises(TypeError, match="mapping"):
        bead.load(scene_path("parabola.toml"), params=[1, 2])


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"dt": 0.0}, "dt=0: must be a finite number > 0"),
        ({"dt": -1.0}, "dt=-1: must be a finite number > 0"),
        ({"dt": float("inf")}, "dt=inf: must be a finite number > 0"),
        ({"duration": -2.0}, "duration=-2: must be a finite number > 0"),
        ({"steps": 0}, "steps=0: must be an integer from 1 to 2^53"),
        ({"steps": -5}, "steps=-5: must be an integer from 1 to 2^53"),
        ({"every": 0}, "every=0: must be an integer from 1 to 2^53"),
        ({"steps": 3, "duration": 1.0}, "give steps or duration, not both"),
        ({"integrator": "rk5"}, "unknown integrator `rk5`; use one of"),
        ({"method": "explicit"}, "unknown method `explicit`; use implicit or parametric"),
        ({"stabilize": (-1.0, 0.0)}, "stabilize=-1,0: must be two finite numbers >= 0"),
        ({"rtol": 0.0}, "rtol=0: must be a finite number > 0"),
        ({"dt": 1e-300, "duration": 1e300}, "at most 2^53 are allowed"),
    ],
)
def test_bad_arguments_are_value_errors(kwargs, message):
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(ValueError) as caught:
        scene.run(**kwargs)
    assert message in str(caught.value)
    assert not isinstance(caught.value, bead.BeadError)


def test_illegal_combination_is_a_setup_error():
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(bead.SetupError, match="rattle"):
        scene.run(method="parametric", integrator="rattle")
    with pytest.raises(bead.SetupError):
        scene.simulation(method="parametric", integrator="rattle")


def test_divergence_raises_with_the_partial_run():
    # Explicit Euler on the parabola's parametric form at dt = 5 s blows up. (The implicit
    # form's first step already leaves the curve across a bend, which stops it earlier as a
    # step too long for the curve: crates/bead/tests/singular_watch.rs.)
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(bead.DivergenceError) as caught:
        scene.run(method="parametric", integrator="euler", dt=5.0, duration=1e5)
    e = caught.value
    assert isinstance(e, bead.RunError) and "diverged at t = " in str(e)
    run = e.run
    assert isinstance(run, bead.Run) and not run.completed and run.error == str(e)
    # Every recorded state is the last good one or before it: finite, on the step grid.
    assert 1 < len(run) < 1e5 / 5
    assert np.all(np.isfinite(run.positions))
    np.testing.assert_array_equal(run.t, 5.0 * np.arange(len(run)))
    assert run.summary["steps"] == len(run) - 1


def test_simulation_errors():
    # Explicit Euler at dt = 5 s: the first step is taken, the second's energy has changed by
    # more than 10^6 times its scale (a divergence).
    sim = bead.load(scene_path("parabola.toml")).simulation(
        method="parametric", integrator="euler", dt=5.0)
    sim.advance_to(5.0)
    with pytest.raises(ValueError, match="time only moves forward"):
        sim.advance_to(1.0)
    with pytest.raises(ValueError, match="count=-1: must be an integer from 0 to"):
        sim.step(-1)
    with pytest.raises(bead.DivergenceError) as caught:
        sim.step(100_000)
    assert caught.value.run is None
    # The simulation holds the last good state.
    assert np.all(np.isfinite(sim.positions)) and sim.t == 5.0
