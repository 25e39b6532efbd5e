"""Unilateral constraints from Python: a scene built with `side`, its switches on
`Simulation.contact_switches`, and the run's arrays through the flight, against the analytic
answers (the Rust tests check the same physics more finely)."""

import numpy as np
import pytest

import bead
from conftest import ROOT


def sphere():
    return (
        bead.Builder(dim=3, gravity=[0.0, 0.0, -9.81])
        .particle("p", mass=1.0, position=[0.0, 0.0, 1.0], velocity=[1e-7, 0.0, 0.0])
        .constraint("p.x^2 + p.y^2 + p.z^2 - 1", name="sphere", side="above")
        .run(method="implicit", integrator="rk4", dt=0.001, duration=8.0)
        .build()
    )


def test_a_particle_leaves_a_sphere_at_cos_theta_two_thirds():
    sim = sphere().simulation()
    assert sim.detached == [False]
    sim.advance_to(8.0)
    switches = sim.contact_switches
    assert switches[0]["kind"] == "detach" and switches[0]["constraint"] == "sphere"
    x = switches[0]["positions"][0]
    assert abs(x[2] / np.linalg.norm(x) - 2.0 / 3.0) < 1e-9
    assert sim.detached == [True]
    # The run's rows follow the same path: after the detach a free fall (a parabola).
    run = sphere().run(duration=8.0)
    t0 = switches[0]["t"]
    after = run.t > t0 + 0.01
    z = run.positions[after, 0, 2]
    t = run.t[after]
    # z'' = -g in flight: the second differences of z over equal steps.
    dt = t[1] - t[0]
    assert np.allclose(np.diff(z, 2) / dt**2, -9.81, rtol=1e-6)


def test_bounces_lose_one_minus_e_squared_of_the_normal_energy():
    scene = bead.load(ROOT / "scenes" / "bounce.toml", params={"restitution": 0.5})
    sim = scene.simulation(integrator="rk4", dt=1e-4)
    sim.advance_to(3.0)
    bounces = [s for s in sim.contact_switches if s["kind"] == "bounce"]
    assert len(bounces) >= 3
    for b in bounces:
        before, after = b["normal_velocity"]
        assert after == pytest.approx(-0.5 * before, rel=1e-9)
        x = b["positions"][0]
        vn = before / np.hypot(2 * x[0], 100.0)
        assert b["dissipated"] == pytest.approx(0.75 * 0.5 * vn * vn, rel=1e-9)


def test_both_forms_of_the_bowl_bounce_alike():
    scene = bead.load(ROOT / "scenes" / "bounce.toml")
    implicit = scene.simulation(method="implicit")
    parametric = scene.simulation(method="parametric")
    implicit.advance_to(3.0)
    parametric.advance_to(3.0)
    a, b = implicit.contact_switches, parametric.contact_switches
    assert len(a) == len(b) > 5
    for s, r in zip(a, b):
        assert s["kind"] == r["kind"]
        assert s["t"] == pytest.approx(r["t"], abs=1e-9)
    np.testing.assert_allclose(implicit.positions, parametric.positions, atol=1e-4)
    # The parametric form's state is [q; x]: its coordinates say so.
    assert parametric.coordinates == ["q", "ball.x", "ball.y"]
