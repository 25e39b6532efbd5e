"""A scene's warnings (a start off its constraint, a parametric form that starts elsewhere)
reach Python's `warnings` machinery: each is a `UserWarning` raised where the scene is
loaded, located at the scene file and line it is about, and the scene's repr shows them.
They were only in `scene.warnings`, which nobody reads before a run that silently starts the
parametric form 8 px away from the particle's position."""

import pickle
import warnings
from pathlib import Path

import pytest

import bead
from conftest import SCENES

# The article's parabola with the bead 8 px below the wire.
OFF = """title = "Bead off the parabola"

[params]
g = 500.0

[world]
gravity = [0.0, "g"]

[[particle]]
name = "bead"
mass = 1.0
position = [150.0, -217.0]
velocity = [0.0, 0.0]

[[constraint]]
expr = "bead.x^2 + 100*bead.y"

[parametric]
coordinates = ["q"]
initial = [150.0]
rates = [0.0]

[parametric.positions]
bead = ["q", "-q^2/100"]
"""

POSITION = ("particle `bead`: the parametric form's initial position x(q0) = [150, -225] "
            "differs from the scene's position [150, -217] by 8")
CONSTRAINT = ("constraint 1 (`bead.x^2 + 100*bead.y = 0`): the initial positions violate "
              "it: C = 800 (about 2.52982 off the constraint)")


@pytest.fixture
def off(tmp_path):
    path = tmp_path / "off.toml"
    path.write_text(OFF)
    return path


def loaded(how, path):
    """Load the off scene `how`, returning it and the warnings raised meanwhile."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if how == "load":
            scene = bead.load(path)
        elif how == "loads":
            scene = bead.loads(OFF, name="off.toml")
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                base = bead.load(path)
            scene = base.with_params({"g": 400.0})
    return scene, caught


@pytest.mark.parametrize("how", ["load", "loads", "with_params"])
def test_scene_warning_is_a_user_warning(off, how):
    scene, caught = loaded(how, off)
    file = str(off) if how != "loads" else "off.toml"
    got = [(w.category, w.filename, w.lineno, str(w.message)) for w in caught]
    # Once per warning, at the line it is about: the particle's position, the constraint.
    assert got == [
        (UserWarning, file, 12, POSITION),
        (UserWarning, file, 16, CONSTRAINT),
    ]
    assert scene.warnings == [POSITION, CONSTRAINT]


def test_scene_warnings_show_in_the_repr(off):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = bead.load(off)
    assert repr(scene) == (
        f'<bead.Scene "Bead off the parabola" from "{off}": 1 particle in 2D, 1 constraint, '
        f"methods implicit, parametric; 2 warnings: line 12: {POSITION}; line 16: {CONSTRAINT}>"
    )


def test_a_warning_is_shown_once_per_caller_under_the_default_filter(off):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        for _ in range(3):
            bead.load(off)
    assert [str(w.message) for w in caught] == [POSITION, CONSTRAINT]


def test_warnings_as_errors_refuse_the_scene(off):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(UserWarning, match="differs from the scene's position"):
            bead.load(off)


def test_an_unpickled_scene_does_not_warn_again(off):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = bead.load(off)
    data = pickle.dumps(scene)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = pickle.loads(data)
    assert caught == [] and again.warnings == scene.warnings


@pytest.mark.parametrize("path", SCENES, ids=[p.name for p in SCENES])
def test_shipped_scenes_load_without_warnings(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = bead.load(Path(path))
    assert scene.warnings == [] and "warning" not in repr(scene)
