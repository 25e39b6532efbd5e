"""The Python package and `bead run --json` give the same summary: same keys, same values
(bit for bit: the same library code runs), on every shipped scene and formulation."""

import csv

import numpy as np
import pytest

import bead
from conftest import ROOT, SCENES, scene_path

# Wall time differs from run to run; everything else must match exactly.
TIMING = {"wall_seconds", "steps_per_second"}


def comparable(summary):
    return {k: v for k, v in summary.items() if k not in TIMING}


def cases():
    for path in SCENES:
        scene = bead.load(str(path))
        for method in scene.methods:
            yield pytest.param(path.name, method, id=f"{path.stem}-{method}")


@pytest.mark.parametrize("name,method", list(cases()))
def test_summary_matches_the_cli_on_every_scene(cli_json, name, method):
    path = f"scenes/{name}"
    # A few steps of each scene with its own [run] settings (the chain and cloth are long).
    code, expected, err = cli_json(path, "--method", method, "--steps", "40")
    scene = bead.load(str(ROOT / path))
    if code != 0 and expected is None:
        # The CLI refused to start; Python refuses too, with the library's words.
        with pytest.raises((bead.SetupError, ValueError)) as refused:
            scene.run(method=method, steps=40)
        assert str(refused.value) in err
        return
    try:
        run = scene.run(method=method, steps=40)
        summary = run.summary
    except bead.RunError as failure:
        assert code == 1
        summary = failure.run.summary
    expected["scene"] = summary["scene"]  # the path as each was given
    assert comparable(summary) == comparable(expected)
    assert list(summary) == list(expected), "same keys in the same order"


@pytest.mark.parametrize("integrator", ["rk4", "rattle", "rattle4", "dopri5", "gauss-legendre", "verlet"])
def test_full_default_run_matches_the_cli(cli_json, integrator):
    path = scene_path("parabola.toml")
    code, expected, _ = cli_json(path, "--integrator", integrator, "--set", "g=9.81")
    assert code == 0
    run = bead.load(path, params={"g": 9.81}).run(integrator=integrator)
    assert comparable(run.summary) == comparable(expected)


def test_parametric_run_with_every_and_duration_matches_the_cli(cli_json):
    path = scene_path("double-pendulum.toml")
    args = ["--method", "parametric", "--integrator", "gauss-legendre", "--dt", "0.001",
            "--duration", "1.5", "--every", "7"]
    code, expected, _ = cli_json(path, *args)
    assert code == 0
    run = bead.load(path).run(method="parametric", integrator="gauss-legendre", dt=0.001,
                              duration=1.5, every=7)
    assert comparable(run.summary) == comparable(expected)


def test_table_and_to_pandas_equal_the_cli_trace(cli, tmp_path):
    path = scene_path("double-pendulum.toml")
    trace = tmp_path / "trace.csv"
    code, _, _ = cli("run", path, "--method", "parametric", "--steps", "50", "--every", "3",
                     "--trace", trace)
    assert code == 0
    with open(trace, newline="") as f:
        header, *rows = list(csv.reader(f))
    expected = np.array([[float(x) for x in row] for row in rows])  # float() reads exactly
    run = bead.load(path).run(method="parametric", steps=50, every=3)
    assert run.columns == header
    np.testing.assert_array_equal(run.table(), expected)
    pandas = pytest.importorskip("pandas")
    frame = run.to_pandas()
    assert list(frame.columns) == header
    np.testing.assert_array_equal(frame.to_numpy(), expected)


def test_failed_run_summary_matches_the_cli(cli_json):
    path = scene_path("parabola.toml")
    code, expected, _ = cli_json(path, "--method", "parametric", "--integrator", "euler", "--dt",
                                 "5", "--duration", "100000")
    assert code == 1 and expected["completed"] is False
    with pytest.raises(bead.DivergenceError) as failure:
        bead.load(path).run(method="parametric", integrator="euler", dt=5, duration=100000)
    assert comparable(failure.value.run.summary) == comparable(expected)
    assert str(failure.value) == expected["error"]
