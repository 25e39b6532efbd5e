"""Scene.order: the convergence study of `bead order`, as Python data. The orders are the
methods' (rk4 4 on the implicit form, rattle 2, rattle4 4, gauss-legendre 4 in q), the work
is their evaluations per step derived by hand, and every number is the one the CLI prints
(the same library code: compared digit for digit with its table)."""

import math

import pytest

import bead
from conftest import scene_path

INTEGRATORS = ["rk4", "rattle", "rattle4", "gauss-legendre"]


@pytest.fixture(scope="module")
def study():
    return bead.load(scene_path("parabola.toml")).order(integrators=INTEGRATORS)


def last_order(study, method, integrator, column="position_order"):
    runs = study["runs"]
    orders = [o for m, i, o in zip(runs["method"], runs["integrator"], runs[column])
              if m == method and i == integrator and not math.isnan(o)]
    return orders[-1]


def test_the_study_finds_each_methods_order(study):
    for method, integrator, order in [("implicit", "rk4", 4), ("implicit", "rattle", 2),
                                      ("implicit", "rattle4", 4),
                                      ("parametric", "gauss-legendre", 4)]:
        for column in ("position_order", "energy_order"):
            assert abs(last_order(study, method, integrator, column) - order) < 0.1
    assert study["reference"] == {"method": "parametric", "rtol": 1e-13, "steps": 2484}
    assert study["failures"] == {}


def test_columns_are_equal_length_and_load_into_pandas(study):
    pandas = pytest.importorskip("pandas")
    runs = pandas.DataFrame(study["runs"])
    # 4 implicit series and 2 parametric (rattle and rattle4 need the implicit form), 5 steps.
    assert len(runs) == 6 * 5
    implicit_rk4 = runs[(runs.method == "implicit") & (runs.integrator == "rk4")]
    assert list(implicit_rk4.dt) == [1 / 60 / 2 ** k for k in range(5)]
    # rk4 evaluates four times per step, RATTLE twice, rattle4 five RATTLE steps; plus the
    # monitors' one at the start.
    for integrator, per_step in [("rk4", 4), ("rattle", 2), ("rattle4", 10)]:
        rows = runs[(runs.method == "implicit") & (runs.integrator == integrator)]
        assert list(rows.evaluations) == [per_step * s + 1 for s in rows.steps]
    parametric = runs[runs.method == "parametric"]
    assert parametric.constraint_error.isna().all()
    assert runs.groupby(["method", "integrator"]).position_order.apply(
        lambda o: math.isnan(o.iloc[0])).all(), "no order at the first step"


def test_the_numbers_are_the_clis(study, cli):
    code, out, err = cli("order", scene_path("parabola.toml"), "--integrators",
                         ",".join(INTEGRATORS))
    assert code == 0, err
    printed = {}
    for line in out.splitlines():
        cells = line.split()
        if len(cells) >= 5 and cells[0] in ("implicit", "parametric") and cells[2].startswith("1/"):
            printed[(cells[0], cells[1], cells[2])] = (int(cells[3]), float(cells[4]))
    runs = study["runs"]
    assert len(printed) == len(runs["dt"])
    for method, integrator, dt, evaluations, error in zip(
            runs["method"], runs["integrator"], runs["dt"], runs["evaluations"],
            runs["position_error"]):
        key = (method, integrator, f"1/{round(1 / dt)}")
        assert printed[key] == (evaluations, float(f"{error:.4e}")), key


def test_bad_arguments_say_what_is_wrong():
    scene = bead.load(scene_path("parabola.toml"))
    with pytest.raises(ValueError, match="chooses its own steps"):
        scene.order(integrators=["dopri5"])
    with pytest.raises(ValueError, match="unknown integrator"):
        scene.order(integrators=["rk5"])
    with pytest.raises(ValueError, match="halvings=0"):
        scene.order(halvings=0)
    with pytest.raises(ValueError, match="not a whole number of steps"):
        scene.order(duration=0.1001)


def test_a_failed_coarse_step_is_reported_and_the_finer_steps_still_run():
    # Explicit Euler on the article's parabola fails at dt = 0.2 in both forms (a step too
    # long for the curve's turn; the energy blowing up); 0.1 and 0.05 still run.
    study = bead.load(scene_path("parabola.toml")).order(
        integrators=["euler"], dt=0.2, duration=10.0, halvings=2)
    assert set(study["failures"]) == {"implicit euler", "parametric euler"}
    for why in study["failures"].values():
        assert list(why) == [0.2]
        assert "reduce dt" in why[0.2]
    runs = study["runs"]
    assert runs["dt"] == [0.1, 0.05, 0.1, 0.05]
    # The first run after the failure has no order (nothing one halving coarser ran).
    orders = runs["position_order"]
    assert math.isnan(orders[0]) and math.isnan(orders[2])
    assert not math.isnan(orders[1]) and not math.isnan(orders[3])
