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

/// The point of the parabola y = -x^2/100 closest to (a, b), computed apart from bead: the
/// distance's derivative vanishes where x^3 + (100 b + 5000) x - 5000 a = 0 (Cardano, the
/// trigonometric form for three real roots), and the closest of the real roots wins.
fn closest_on_parabola(a: f64, b: f64) -> [f64; 2] {
    let (p, q) = (100.0 * b + 5000.0, -5000.0 * a);
    let roots: Vec<f64> = if 4.0 * p * p * p + 27.0 * q * q < 0.0 {
        let r = 2.0 * (-p / 3.0).sqrt();
        let phi = ((3.0 * q / (2.0 * p)) * (-3.0 / p).sqrt()).acos() / 3.0;
        (0..3)
            .map(|k| r * (phi - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos())
            .collect()
    } else {
        let d = (q * q / 4.0 + p * p * p / 27.0).sqrt();
        vec![(-q / 2.0 + d).cbrt() + (-q / 2.0 - d).cbrt()]
    };
    let distance = |x: f64| (x - a).powi(2) + (-x * x / 100.0 - b).powi(2);
    let x = roots
        .into_iter()
        .min_by(|u, v| distance(*u).total_cmp(&distance(*v)))
        .unwrap();
    [x, -x * x / 100.0]
}

/// A drop off the curve: both forms restart at the point of the curve closest to it, the
/// same point to 1e-9, whatever the bead's state when paused. Issue 15: the drop
/// (-100, -200) restarted the implicit form at (-135, -183), where the mass-weighted
/// projection of the drop lands, and the parametric one at (100, -100), the local minimum
/// of the distance on the far side of the bowl that the fit from the current q fell into;
/// the closest point is (-136.6, -186.6).
#[test]
fn drag_start_puts_both_forms_at_the_closest_point() {
    let scene = parabola();
    for drop in [
        [-100.0, -200.0],
        [-70.0, -45.0],
        [150.0, 20.0],
        [30.0, -150.0],
        [-5.0, -0.5],
    ] {
        let exact = closest_on_parabola(drop[0], drop[1]);
        for paused in [0.0, 0.5, 1.0, 1.7] {
            let mut placed = Vec::new();
            for method in [Method::Implicit, Method::Parametric] {
                let mut sim = simulation(&scene, method);
                sim.advance_to(paused).unwrap();
                let start = sim.closest_start(&drop).unwrap();
                sim.restart_at_rest(&drop).unwrap();
                let x = sim.positions().to_vec();
                let label = format!("{method:?} drop {drop:?} paused at {paused}");
                assert!(
                    (x[0] - exact[0]).abs() < 1e-9 && (x[1] - exact[1]).abs() < 1e-9,
                    "{label}: {x:?} vs {exact:?}"
                );
                assert!((start[0] - x[0]).abs() < 1e-9, "{label}: {start:?} {x:?}");
                assert!(sim.velocities().iter().all(|v| *v == 0.0), "{label}");
                placed.push(x);
            }
            assert!(
                (placed[0][0] - placed[1][0]).abs() < 1e-9
                    && (placed[0][1] - placed[1][1]).abs() < 1e-9,
                "{placed:?}"
            );
        }
    }
}

/// Several particles: the closest configuration is in the kinetic metric sum m |y - x|^2,
/// the same for both forms. The double pendulum (two rods) with its lower bob dragged off
/// its circle: both forms put both bobs at the same place (both move a little), on the rods.
#[test]
fn both_forms_of_several_particles_restart_at_the_same_place() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/double-pendulum.toml"
    );
    let scene = Scene::load(std::path::Path::new(path), &[]).unwrap();
    let mut x = scene.system.initial_particle_state().0;
    x[2] += 0.3;
    x[3] -= 0.2;
    let mut placed = Vec::new();
    for method in [Method::Implicit, Method::Parametric] {
        let mut sim = simulation(&scene, method);
        sim.advance_to(0.3).unwrap();
        sim.restart_at_rest(&x).unwrap();
        assert!(sim.constraint_error() < 1e-9, "{method:?}");
        placed.push(sim.positions().to_vec());
    }
    for (a, b) in placed[0].iter().zip(&placed[1]) {
        assert!((a - b).abs() < 1e-9, "{placed:?}");
    }
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
