"""`Scene.param_info`: what a scene says about its parameters besides their values (unit,
range, description, whole numbers, derived ones), for a notebook's sliders or a table."""

import math

import bead
from conftest import scene_path


def test_units_ranges_descriptions_of_a_shipped_scene():
    info = bead.load(scene_path("circle.toml")).param_info
    assert list(info) == ["L", "g", "theta0"]
    theta0 = info["theta0"]
    assert theta0["value"] == math.pi / 3
    assert theta0["unit"] == "rad"
    # The range's ends are exactly -pi and pi.
    assert theta0["range"] == (-math.pi, math.pi)
    assert "initial angle" in theta0["description"]
    assert theta0["integer"] is False
    assert theta0["derived"] is None and theta0["depends_on"] == []
    assert info["g"]["unit"] == "m/s^2" and info["g"]["range"] == (0.0, 30.0)


def test_whole_and_derived_parameters():
    with open(scene_path("cloth.toml")) as f:
        text = f.read()
    text = text.replace("W = { value = 50,", "W = { value = 4,").replace(
        "H = { value = 50,", "H = { value = 4,"
    )
    info = bead.loads(text, name="cloth.toml").param_info
    assert info["W"]["integer"] and info["H"]["integer"]
    assert info["L"]["derived"] == "S/(W-1)"
    assert info["L"]["depends_on"] == ["S", "W"]
    assert info["L"]["value"] == 1.0 / 3.0
    assert info["A"]["derived"] is None
    # A plain parameter: its comment is its description, no unit, no range.
    plain = bead.loads(
        '[params]\nk = 3.0  # spring constant\n[world]\ngravity = [0.0, 1.0]\n'
        '[[particle]]\nname = "a"\nmass = 1.0\nposition = ["k", 0.0]\n'
    ).param_info["k"]
    assert plain == {
        "value": 3.0,
        "unit": None,
        "range": None,
        "description": "spring constant",
        "integer": False,
        "derived": None,
        "depends_on": [],
    }
