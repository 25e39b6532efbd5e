"""stop_when in Python: the same event as `bead run --stop-when`, the scene's own
`[run] stop_when` honoured, a bad expression refused with its place marked, a crossing
inside one step found, and a condition that becomes NaN raised."""

import math

import numpy as np
import pytest

import bead
from conftest import scene_path


def test_stop_when_matches_the_cli(cli_json):
    path = scene_path("parabola.toml")
    # Released at x = 150, the bead first moves left: -x crosses zero upward at the bottom.
    code, expected, _ = cli_json(path, "--stop-when", "-bead.x")
    assert code == 0
    run = bead.load(path).run(stop_when="-bead.x")
    summary = run.summary
    assert summary["stop_when"] == "-bead.x"
    assert summary["stop_time"] == expected["stop_time"]
    assert summary["stop_time"] is not None and 0.5 < summary["stop_time"] < 2.0
    # The run ends at the crossing: its last recorded state is at the bottom.
    assert run.t[-1] == summary["stop_time"]
    assert abs(run.positions[-1, 0, 0]) < 1e-6


def test_the_scene_stop_when_is_used_unless_overridden():
    with open(scene_path("parabola.toml")) as f:
        text = f.read()
    assert text.count("[run]\n") == 1 and "stop_when" not in text
    scene = bead.loads(text.replace("[run]\n", '[run]\nstop_when = "-bead.x"\n'))
    stopped = scene.run().summary
    assert stopped["stop_when"] == "-bead.x"
    assert stopped["stop_time"] is not None
    # An explicit expression replaces the scene's.
    other = scene.run(stop_when="bead.y + 100").summary
    assert other["stop_when"] == "bead.y + 100"
    # Stepping by hand stops there too.
    sim = scene.simulation()
    sim.advance_to(10.0)
    assert sim.t == pytest.approx(stopped["stop_time"], abs=0.0)


def test_a_bad_stop_when_is_refused_with_its_place():
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(ValueError) as error:
        scene.run(stop_when="bead.q + 1")
    text = str(error.value)
    assert text.startswith("stop_when: ")
    assert "bead.q + 1" in text and "^" in text


def test_a_crossing_inside_one_step_is_found():
    # sin(100 t) goes up, down and up again within the first step of 0.1: its first upward
    # crossing is 2 pi / 100, found by the samples inside the step (event_samples, default
    # 4); compared at the step ends alone (event_samples=0) it fires a step later.
    scene = bead.load(scene_path("parabola.toml"))
    run = scene.run(stop_when="sin(100*t)", dt=0.1)
    assert abs(run.summary["stop_time"] - 0.02 * math.pi) < 1e-11
    late = scene.run(stop_when="sin(100*t)", dt=0.1, event_samples=0)
    assert late.summary["stop_time"] > 0.1
    swept = bead.sweep(scene, {"g": np.array([400.0, 500.0])}, stop_when="sin(100*t)",
                       dt=0.1, duration=1.0, event_samples=0)
    assert (swept.stop_time > 0.1).all()
    for bad in (-1, 5000):
        with pytest.raises(ValueError, match="event_samples"):
            scene.run(event_samples=bad)


def test_a_stop_condition_that_is_not_a_number_raises():
    # sqrt(x) of the pendulum is NaN once x < 0, a quarter period (0.538 s) after its
    # release: a RunError naming it, with the run up to the last good state.
    scene = bead.load(scene_path("circle.toml"))
    with pytest.raises(bead.RunError) as error:
        scene.run(stop_when="sqrt(bead.x)")
    assert not isinstance(error.value, bead.DivergenceError)
    assert str(error.value).startswith("stop_when `sqrt(bead.x)` is not a number at t = 0.538")
    assert 0.5 < error.value.run.t[-1] < 0.5383
    assert error.value.run.positions[-1, 0, 0] > 0.0
    sim = scene.simulation(stop_when="sqrt(bead.x)")
    with pytest.raises(bead.RunError):
        sim.advance_to(1.0)
    assert 0.5 < sim.t < 0.5383
