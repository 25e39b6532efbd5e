"""Sweeps over the initial state: each member equals a run started there, bit for bit."""

import numpy as np
import pytest

import bead
from conftest import ROOT

PARABOLA = ROOT / "scenes" / "parabola.toml"
CIRCLE = ROOT / "scenes" / "circle.toml"


@pytest.mark.parametrize("method", ["implicit", "parametric"])
def test_a_sweep_over_bead_x_and_g_is_the_runs_started_at_each_x(method):
    scene = bead.load(PARABOLA)
    xs = np.array([30.0, -60.0, 90.0])
    gs = np.array([250.0, 500.0])
    result = bead.sweep(scene, params={"g": gs}, initial={"bead.x": xs}, method=method,
                        steps=120)
    assert result.shape == (2, 3)
    assert result.counts()["ok"] == 6
    for i, g in enumerate(gs):
        for j, x in enumerate(xs):
            run = scene.with_params({"g": g}).run(
                method=method, steps=120,
                initial={"positions": [[x, -x * x / 100]], "velocities": [[0.0, 0.0]]})
            assert np.array_equal(result.positions[i, j], run.positions[-1])
            assert result.params["bead.x"][i, j] == x


def test_a_sweep_over_the_parametric_coordinate_and_rate():
    scene = bead.load(CIRCLE)
    thetas = np.linspace(0.1, 1.5, 4)
    result = bead.sweep(scene, initial={"q.theta": thetas, "qdot.theta": [0.5] * 4}, zip=True,
                        method="parametric", duration=0.5)
    for k, th in enumerate(thetas):
        run = scene.run(method="parametric", duration=0.5,
                        initial={"q": [th], "qdot": [0.5]})
        assert np.array_equal(result.q[k], run.q[-1])


def test_unknown_state_names_say_what_can_be_swept():
    with pytest.raises(ValueError, match="NAME.x"):
        bead.sweep(bead.load(CIRCLE), initial={"bead.w": [1.0]}, steps=1)
    with pytest.raises(ValueError, match="needs values to sweep"):
        bead.sweep(bead.load(CIRCLE), steps=1)
