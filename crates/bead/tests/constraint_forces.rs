//! Constraint forces against the pendulum's tension from Newton's law along the rod, in
//! both forms, at states along a run; the probe of recorded states against the simulation.

use std::sync::Arc;

use bead::formulation::{Feedback, Method};
use bead::integrate::IntegratorKind;
use bead::model::Force;
use bead::scene::Scene;
use bead::simulate::{
    ConstraintForceProbe, ConstraintForces, Simulation, SimulationConfig, StateRequest,
};

fn circle() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/circle.toml");
    Scene::parse(&std::fs::read_to_string(path).unwrap(), "circle.toml", &[]).unwrap()
}

/// The force of the rod on a bead of mass m at x (any distance r from the pivot), moving
/// with v, under gravity g down (+y): the implicit form holds d^2/dt^2 |x|^2 = 0, so
/// x . a = -|v|^2 with m a = m g e_y + F, F = -T x / r along the rod:
/// T = m (g y / r + |v|^2 / r), which on the circle is m (g cos th + L thdot^2).
fn rod_force(m: f64, g: f64, x: [f64; 2], v: [f64; 2]) -> [f64; 2] {
    let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
    let tension = m * (g * x[1] / r + (v[0] * v[0] + v[1] * v[1]) / r);
    [-tension * x[0] / r, -tension * x[1] / r]
}

fn relative_error(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().map(|v| v.abs()).fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
        / scale
}

#[test]
fn the_rod_tension_is_newtons_along_the_rod_in_both_forms_and_every_integrator() {
    let scene = circle();
    let (m, g) = (1.0, 9.81);
    for method in [Method::Implicit, Method::Parametric] {
        for integrator in [
            IntegratorKind::Rk4,
            IntegratorKind::Dopri5,
            IntegratorKind::Verlet,
        ] {
            let config = SimulationConfig {
                method,
                integrator,
                dt: 1e-3,
                ..SimulationConfig::default()
            };
            let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
            let mut worst: f64 = 0.0;
            for k in 1..=40 {
                sim.advance_to(0.05 * k as f64).unwrap();
                let forces = sim.constraint_forces().unwrap();
                let (x, v) = (sim.positions(), sim.velocities());
                let expected = rod_force(m, g, [x[0], x[1]], [v[0], v[1]]);
                worst = worst.max(relative_error(&forces.force, &expected));
                match method {
                    // F = J^T lambda = lambda (2x, 2y): lambda = -T / (2 r).
                    Method::Implicit => {
                        assert_eq!(forces.multipliers.len(), 1);
                        let from_lambda = [
                            2.0 * forces.multipliers[0] * x[0],
                            2.0 * forces.multipliers[0] * x[1],
                        ];
                        assert!(relative_error(&from_lambda, &expected) < 1e-12);
                    }
                    Method::Parametric => assert!(forces.multipliers.is_empty()),
                }
            }
            assert!(worst < 1e-9, "{method:?} {integrator:?}: {worst:e}");
        }
    }
}

#[test]
fn both_forms_at_one_state_agree_and_a_held_force_counts() {
    let scene = circle();
    let request = StateRequest {
        positions: Some(vec![0.6, 0.8]),
        velocities: Some(vec![-2.4, 1.8]),
        ..Default::default()
    };
    let mut forces: Vec<ConstraintForces> = Vec::new();
    for method in [Method::Implicit, Method::Parametric] {
        let config = SimulationConfig {
            method,
            ..SimulationConfig::default()
        };
        let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        sim.set_state(&request).unwrap();
        // A push along +x of 3 N: the rod takes its component along the rod as well.
        sim.add_force(Force::Constant {
            particle: bead::model::ParticleId(0),
            vector: vec![3.0, 0.0],
        })
        .unwrap();
        forces.push(sim.constraint_forces().unwrap());
    }
    // T from m a . e_r = -|v|^2 / r: F_c . e_r = -m |v|^2 / r - (m g e_y + P) . e_r.
    let (x, v) = ([0.6, 0.8], [-2.4, 1.8]);
    let along = -(v[0] * v[0] + v[1] * v[1]) - (9.81 * x[1] + 3.0 * x[0]);
    let expected = [along * x[0], along * x[1]];
    for f in &forces {
        assert!(
            relative_error(&f.force, &expected) < 1e-12,
            "{f:?} {expected:?}"
        );
    }
}

#[test]
fn the_probe_of_recorded_states_gives_the_simulations_numbers() {
    let scene = circle();
    for method in [Method::Implicit, Method::Parametric] {
        let config = SimulationConfig {
            method,
            dt: 1e-2,
            ..SimulationConfig::default()
        };
        let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        let mut probe =
            ConstraintForceProbe::new(Arc::clone(&scene.system), method, Feedback::default())
                .unwrap();
        let mut out = ConstraintForces::default();
        for _ in 0..25 {
            sim.step().unwrap();
            let (t, q, qdot) = (sim.t(), sim.q().to_vec(), sim.qdot().to_vec());
            probe.evaluate(t, &q, &qdot, &mut out).unwrap();
            assert_eq!(out, sim.constraint_forces().unwrap());
        }
    }
}
