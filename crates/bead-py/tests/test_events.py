"""stop_when in Python: the same event as `bead run --stop-when`, the scene's own
`[run] stop_when` honoured, and a bad expression refused with its place marked."""

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
