"""`Run._repr_html_`: what a notebook shows for a run."""

import bead
from conftest import ROOT


def test_a_run_shows_its_figures_and_a_light_sketch_of_the_paths():
    run = bead.load(ROOT / "scenes" / "circle.toml").run(duration=2.0)
    page = run._repr_html_()
    assert "<table>" in page and "completed" in page and "rk4" in page
    assert page.count("<polyline") == 1
    points = page.split("points='")[1].split("'")[0].split()
    assert 2 <= len(points) <= 401
    # Every point inside the 240 px box.
    assert all(0 <= float(c) <= 240 for p in points for c in p.split(","))
    stopped = bead.load(ROOT / "scenes" / "circle.toml").run(stop_when="-bead.x")
    assert "stop_when fired at t" in stopped._repr_html_()


def test_a_run_that_solves_onto_the_constraints_shows_its_newton_iterations():
    scene = bead.load(ROOT / "scenes" / "circle.toml")
    run = scene.run(integrator="rattle", dt=0.01, duration=1.5)
    total, steps = run.summary["newton_iterations"], run.summary["steps"]
    # The same count as a Simulation stepped by hand over the same steps.
    sim = scene.simulation(integrator="rattle", dt=0.01)
    sim.advance_to(1.5)
    assert (sim.newton_iterations, sim.steps) == (total, steps) == (total, 150)
    page = run._repr_html_()
    most = run.summary["newton_iterations_max"]
    shown = f"{total} ({total / steps:.3g} per step, at most {most} per solve)"
    assert "Newton iterations" in page and shown in page, page
    # rk4 solves nothing: no such row.
    assert "Newton" not in scene.run(duration=0.5)._repr_html_()
