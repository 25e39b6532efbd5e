"""Shapes, dtypes and values of the recorded arrays, against the summary and the scene."""

import numpy as np
import pytest

import bead
from conftest import scene_path


def test_shapes_and_dtypes_implicit_2d():
    scene = bead.load(scene_path("parabola.toml"))
    run = scene.run(method="implicit", dt=0.01, steps=100)
    T, P, D = 101, 1, 2
    assert run.t.shape == (T,) and run.t.dtype == np.float64
    assert run.positions.shape == (T, P, D) and run.positions.dtype == np.float64
    assert run.velocities.shape == (T, P, D)
    assert run.energy.shape == (T,) and run.constraint_error.shape == (T,)
    # The implicit form's coordinates are the particle coordinates.
    assert run.q.shape == (T, P * D)
    np.testing.assert_array_equal(run.q, run.positions.reshape(T, -1))
    assert run.work is None
    assert run.coordinates == [] and run.particles == ["bead"]


def test_shapes_parametric_and_3d():
    scene = bead.load(scene_path("helix.toml"))
    assert scene.dimension == 3
    run = scene.run(method="parametric", steps=10)
    K = len(scene.coordinates)
    assert K >= 1
    assert run.positions.shape == (11, len(scene.particles), 3)
    assert run.q.shape == (11, K) and run.qdot.shape == (11, K)
    assert run.q.dtype == np.float64


def test_values_agree_with_the_summary_and_the_scene():
    scene = bead.load(scene_path("double-pendulum.toml"))
    run = scene.run(method="implicit", integrator="rk4", dt=0.002, steps=500)
    s = run.summary
    assert run.t[-1] == s["t_final"] and len(run.t) == s["steps"] + 1
    assert run.energy[0] == s["energy_initial"] and run.energy[-1] == s["energy_final"]
    assert run.constraint_error.max() == s["constraint_error_max"]
    for i, name in enumerate(run.particles):
        assert list(run.positions[-1, i]) == s["particles"][name]["position"]
        assert list(run.velocities[-1, i]) == s["particles"][name]["velocity"]


def test_every_records_every_kth_state_and_the_last():
    scene = bead.load(scene_path("circle.toml"))
    dt = 0.01
    run = scene.run(dt=dt, steps=10, every=4)
    # States 0, 4, 8 and the last (10); t = k dt exactly.
    np.testing.assert_array_equal(run.t, [0.0, 4 * dt, 8 * dt, 10 * dt])


def test_params_override_changes_the_physics():
    # The bead starts at rest at x = 150 on y = -x^2/100, +y down: E0 = V0 = m g x^2 / 100.
    for g in (1.0, 9.81, 500.0):
        scene = bead.load(scene_path("parabola.toml"), params={"g": g})
        assert scene.params == {"g": g}
        run = scene.run(steps=1)
        assert run.summary["energy_initial"] == pytest.approx(g * 150.0**2 / 100.0, rel=1e-15)
    moon = bead.load(scene_path("parabola.toml")).with_params({"g": 1.62})
    assert moon.params == {"g": 1.62}


def test_scene_introspection():
    scene = bead.load(scene_path("double-pendulum.toml"))
    assert scene.particles == ["a", "b"]
    assert scene.methods == ["implicit", "parametric"]
    assert scene.default_method == "implicit"
    assert scene.constraint_count == 2 and scene.dimension == 2
    assert scene.title in repr(scene) and "2 particles in 2D, 2 constraints" in repr(scene)
    assert scene.run_defaults == {"method": "implicit", "integrator": "rk4", "dt": 0.001,
                                  "duration": 10.0}
    assert set(bead.INTEGRATORS) >= {"rk4", "rattle", "dopri5", "gauss-legendre"}


def test_to_pandas_without_pandas_says_what_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pandas", None)  # makes `import pandas` fail
    run = bead.load(scene_path("circle.toml")).run(steps=2)
    with pytest.raises(ImportError, match="pip install pandas"):
        run.to_pandas()


def test_docstrings_explain():
    assert "Load a scene file" in bead.load.__doc__
    assert "Run the scene" in bead.Scene.run.__doc__
    assert "``t`` (T,)" in bead.Run.__doc__
