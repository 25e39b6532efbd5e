//! `run_at_times` (scipy's `t_eval`): the state at arbitrary times, exact to the
//! integrator's accuracy, against the closed form of uniformly accelerated motion along a
//! helix (phi'' = -g b / (R^2 + b^2)), which every method of order >= 2 integrates exactly:
//! a row at a time the run missed by a little would be off by the speed times that.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{
    run_at_times, Event, NoProgress, RunError, Sample, Simulation, SimulationConfig, Sink,
};

fn helix() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/helix.toml");
    Scene::parse(&std::fs::read_to_string(path).unwrap(), "helix.toml", &[]).unwrap()
}

/// (R, b, g, w0) of the scene, and phi(t) in closed form.
fn phi(t: f64) -> f64 {
    let (r, b, g, w0) = (1.0, 0.2, 9.81, 3.0);
    let a = -g * b / (r * r + b * b);
    w0 * t + 0.5 * a * t * t
}

#[derive(Default)]
struct Rows(Vec<(f64, Vec<f64>, Vec<f64>)>);

impl Sink for Rows {
    fn record(&mut self, s: &Sample) -> std::io::Result<()> {
        self.0.push((s.t, s.q.to_vec(), s.x.to_vec()));
        Ok(())
    }
}

const TIMES: [f64; 6] = [
    0.0,
    0.123456789,
    1.0 / 3.0,
    0.5,
    1.0,
    std::f64::consts::E / 2.0,
];

#[test]
fn rows_land_on_the_times_asked_for_with_every_exact_method() {
    let scene = helix();
    for integrator in [
        IntegratorKind::Rk4,
        IntegratorKind::Dopri5,
        IntegratorKind::GaussLegendre,
        IntegratorKind::Verlet,
        IntegratorKind::Midpoint,
    ] {
        let config = SimulationConfig {
            method: Method::Parametric,
            integrator,
            dt: 0.01,
            ..SimulationConfig::default()
        };
        let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        let mut rows = Rows::default();
        run_at_times(&mut sim, &TIMES, &mut rows, &mut NoProgress).unwrap();
        assert_eq!(rows.0.len(), TIMES.len());
        for ((t, q, x), &asked) in rows.0.iter().zip(&TIMES) {
            assert_eq!(*t, asked, "{integrator:?}");
            let error = (q[0] - phi(asked)).abs();
            assert!(error < 1e-9, "{integrator:?} at t = {asked}: {error:e}");
            assert!((x[2] - 0.2 * phi(asked)).abs() < 1e-9);
        }
    }
}

#[test]
fn the_run_ends_at_its_stop_condition_and_refuses_times_behind() {
    let scene = helix();
    let config = SimulationConfig {
        method: Method::Parametric,
        dt: 0.01,
        ..SimulationConfig::default()
    };
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    // z = b phi rises to its top, b w0^2 / (2 |a|) = 0.4682...; it passes 0.3 upward at the
    // first root of phi(t) = 1.5.
    sim.set_stop_when(Some(Event::parse(&scene.system, "bead.z - 0.3").unwrap()))
        .unwrap();
    let mut rows = Rows::default();
    let stats = run_at_times(&mut sim, &TIMES, &mut rows, &mut NoProgress).unwrap();
    let a = -9.81 * 0.2 / 1.04;
    let crossing = (-3.0 + (9.0 + 2.0 * a * 1.5_f64).sqrt()) / a;
    assert!((stats.stop_time.unwrap() - crossing).abs() < 1e-9);
    let recorded: Vec<f64> = rows.0.iter().map(|r| r.0).collect();
    let before: Vec<f64> = TIMES.iter().copied().filter(|&t| t < crossing).collect();
    assert_eq!(recorded, before);
    // A time before the current one.
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    let failure = run_at_times(
        &mut sim,
        &[0.5, 0.25],
        &mut Rows::default(),
        &mut NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(failure.error, RunError::TimeBehind { .. }),
        "{}",
        failure.error
    );
}
