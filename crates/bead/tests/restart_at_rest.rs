//! `Simulation::restart_at_rest`: a state a user dragged becomes the start state, on the
//! constraints, at rest, in both formulations; a bad state changes nothing.

use std::sync::Arc;

use bead::formulation::Method;
use bead::scene::Scene;
use bead::simulate::{RestartError, Simulation, SimulationConfig};

fn parabola() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/parabola.toml");
    Scene::parse(
        &std::fs::read_to_string(path).unwrap(),
        "parabola.toml",
        &[],
    )
    .unwrap()
}

fn simulation(scene: &Scene, method: Method) -> Simulation {
    let config = SimulationConfig {
        method,
        ..SimulationConfig::default()
    };
    Simulation::new(Arc::clone(&scene.system), config).unwrap()
}

/// The parabola is x^2 + 100 y = 0: a point dragged off it comes back onto it, at rest, and
/// both formulations put the bead at about the same place (the implicit form by the
/// mass-weighted projection, the parametric one by the closest q; for a point near the curve
/// they agree to first order).
#[test]
fn a_dragged_state_lands_on_the_curve_at_rest_in_both_forms() {
    let scene = parabola();
    let target = [-60.0, -36.5];
    let mut placed = Vec::new();
    for method in [Method::Implicit, Method::Parametric] {
        let mut sim = simulation(&scene, method);
        sim.advance_to(0.5).unwrap();
        sim.restart_at_rest(&target).unwrap();
        assert_eq!(sim.t(), 0.0);
        let x = sim.positions().to_vec();
        assert!(
            (x[0] * x[0] + 100.0 * x[1]).abs() < 1e-6,
            "{method:?}: {x:?}"
        );
        assert!(
            sim.velocities().iter().all(|v| v.abs() < 1e-12),
            "{method:?}"
        );
        assert!((x[0] - target[0]).abs() < 1.0, "{method:?}: {x:?}");
        assert_eq!(sim.energy_error(), 0.0);
        sim.advance_to(0.2).unwrap();
        assert!(
            sim.positions()[0] > x[0],
            "{method:?}: it slides down towards 0"
        );
        placed.push(x);
    }
    assert!((placed[0][0] - placed[1][0]).abs() < 0.1, "{placed:?}");
}

#[test]
fn a_bad_state_is_refused_and_changes_nothing() {
    let scene = parabola();
    let mut sim = simulation(&scene, Method::Implicit);
    sim.advance_to(0.25).unwrap();
    let before = sim.positions().to_vec();
    assert!(matches!(
        sim.restart_at_rest(&[1.0]),
        Err(RestartError::Length {
            expected: 2,
            got: 1
        })
    ));
    assert!(matches!(
        sim.restart_at_rest(&[f64::NAN, 0.0]),
        Err(RestartError::NotFinite)
    ));
    assert_eq!(sim.positions(), &before[..]);
    assert_eq!(sim.t(), 0.25);
}
