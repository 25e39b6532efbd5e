"""Scenes built in Python (`bead.Builder`) and forces added to a scene (`Scene.with_force`):
the scene of the same TOML, bit for bit, with the loader's located errors."""

import numpy as np
import pytest

import bead
from conftest import ROOT

CIRCLE = ROOT / "scenes" / "circle.toml"


def pendulum():
    return (
        bead.Builder(dim=2, gravity=[0.0, "g"], title="Bead on a circle (pendulum)")
        .param("L", 1.0)
        .param("g", 9.81)
        .param("theta0", "pi/3")
        .particle("bead", mass=1.0, position=["L*sin(theta0)", "L*cos(theta0)"],
                  velocity=[0.0, 0.0])
        .constraint("bead.x^2 + bead.y^2 - L^2", name="circle")
        .parametric(["theta"], initial=["theta0"], rates=[0.0],
                    positions={"bead": ["L*sin(theta)", "L*cos(theta)"]})
        .run(method="implicit", integrator="rk4", dt=0.001, duration=10.0)
    )


def test_a_built_scene_runs_as_its_scene_file_bit_for_bit():
    built = pendulum().build()
    loaded = bead.load(CIRCLE)
    assert built.params == loaded.params
    assert built.run_defaults == loaded.run_defaults
    for method in ("implicit", "parametric"):
        a = built.run(method=method, duration=2.0)
        b = loaded.run(method=method, duration=2.0)
        assert a.positions.tobytes() == b.positions.tobytes(), method
        assert a.energy.tobytes() == b.energy.tobytes(), method
    # The text is a scene file: loaded again, the same scene.
    text = pendulum().to_toml()
    assert text.startswith('title = "Bead on a circle (pendulum)"\n[params]\nL = 1.0\n')
    again = bead.loads(text).run(duration=1.0)
    assert again.positions.tobytes() == built.run(duration=1.0).positions.tobytes()


def test_builder_errors_are_the_loaders_located_with_the_call():
    builder = bead.Builder(gravity=[0, 9.81]).particle("bob", 1.0, [1.0, 0.0])
    builder.constraint("bob.x^2 + bob.w^2 - 1")
    with pytest.raises(bead.SceneError) as e:
        builder.build()
    assert e.value.path == "<bead.Builder>"
    assert "`bob` has no coordinate `w`" in e.value.message
    assert (e.value.line, e.value.column) == (8, 19)
    assert "written by Builder.constraint('bob.x^2 + bob.w^2 - 1') (called at" in str(e.value)
    assert "test_builder.py" in str(e.value)
    with pytest.raises(ValueError, match="needs 3 numbers"):
        bead.Builder(dim=3, gravity=[0, 1])
    with pytest.raises(TypeError, match="cannot be written in a scene"):
        bead.Builder().param("a", object()).to_toml()


def test_names_that_are_not_identifiers_reach_the_loader_as_written():
    # Quoted as TOML keys, so the loader (not TOML's dotted keys) says what is wrong.
    with pytest.raises(bead.SceneError, match="parameter") as e:
        bead.Builder(gravity=[0, 9.81]).param("a.b", 1.0).particle("p", 1.0, [0, 0]).build()
    assert "written by Builder.param" in str(e.value)
    with pytest.raises(bead.SceneError, match="particle name `a b`") as e:
        bead.Builder(gravity=[0, 9.81]).particle("a b", 1.0, [0, 0]).build()
    assert "Builder.particle('a b')" in str(e.value)


@pytest.mark.parametrize("method", ["implicit", "parametric"])
def test_drag_added_to_a_scene_takes_energy_the_ledger_counts(method):
    scene = bead.load(CIRCLE).with_force("drag", coefficient=0.3)
    run = scene.run(method=method, dt=1e-3, duration=3.0)
    assert run.work is not None and run.work[-1] < 0
    assert run.energy[-1] < run.energy[0] - 0.1
    # E - W is conserved: what drag takes is what the ledger counts.
    assert np.max(np.abs(run.energy - run.work - run.energy[0])) < 1e-9
    # The scene's text holds the table; with_params keeps it.
    assert scene.text.rstrip().endswith('[[force]]\nkind = "drag"\ncoefficient = 0.3')
    assert scene.with_params({"g": 1.0}).run(steps=2).work is not None


def test_a_bad_force_is_a_located_scene_error():
    with pytest.raises(bead.SceneError, match="stiffness") as e:
        bead.load(CIRCLE).with_force("spring", particle="bead", anchor=[0, 0])
    assert e.value.line > 30


def test_built_events_are_the_scene_files_event_tables():
    built = pendulum().event("bead.x", direction=-1).event("bead.vx", direction=1, terminal=True)
    text = built.to_toml()
    assert text.endswith(
        '[[event]]\nexpr = "bead.x"\ndirection = -1\nterminal = false\n'
        '[[event]]\nexpr = "bead.vx"\ndirection = 1\nterminal = true\n'
    )
    a = built.build().run(duration=3.0)
    b = bead.loads(text).run(duration=3.0)
    assert a.positions.tobytes() == b.positions.tobytes()
    assert [t.tolist() for t in a.t_events] == [t.tolist() for t in b.t_events]
    assert len(a.t_events[0]) == 1 and a.summary["stop_time"] == a.t_events[1][0]
    with pytest.raises(bead.SceneError, match=r"event\('bead.q'\)"):
        pendulum().event("bead.q").build()
