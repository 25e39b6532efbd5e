"""One name, one quantity: where a `Run`, a `Simulation` and a sweep's result name a figure
alike, it is the same number for the same run. Checked on a system that conserves T + V
(the double pendulum) and on one that does not (the spinning hoop, driven: its T + V error
and its energy balance error differ by eleven orders of magnitude, so a figure that means
one under the other's name shows)."""

import pytest

import bead
from conftest import scene_path

SCENES = ["double-pendulum.toml", "spinning-hoop.toml"]


@pytest.mark.parametrize("name", SCENES)
def test_a_sweep_figure_is_the_run_summary_figure_of_the_same_name(name):
    scene = bead.load(scene_path(name))
    param, value = next(iter(scene.params.items()))
    result = bead.sweep(scene, {param: [value]}, steps=200)
    summary = scene.with_params({param: value}).run(steps=200, every=10**6).summary
    shared = [f for f in result.columns if f in summary and f not in ("steps",)]
    assert {"t_final", "stop_time", "constraint_error_max"} <= set(shared)
    for figure in shared + ["steps"]:
        ours = getattr(result, figure)[0]
        theirs = summary[figure]
        assert (ours == theirs) or (theirs is None and ours != ours), (figure, ours, theirs)


@pytest.mark.parametrize("name", SCENES)
def test_a_simulation_names_the_figures_of_a_run_alike(name):
    scene = bead.load(scene_path(name))
    run = scene.run(steps=50)
    sim = scene.simulation()
    sim.step(50)
    assert sim.t == run.t[-1] == run.summary["t_final"]
    assert sim.steps == run.summary["steps"]
    assert sim.energy == run.energy[-1] == run.summary["energy_final"]
    assert sim.constraint_error == run.constraint_error[-1] == run.summary["constraint_error_final"]
    assert (sim.positions == run.positions[-1]).all() and (sim.q == run.q[-1]).all()
    assert sim.particles == run.particles and sim.coordinates == run.coordinates
