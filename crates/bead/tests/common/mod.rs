//! Fixtures shared by the physics tests: the simple pendulum, built both ways, and its
//! reference solution computed without the engine.
//!
//! The pendulum: a bead of mass MASS on a rod of length L to the origin, +y down, gravity G
//! along +y, started at angle THETA0 from the downward vertical with rate OMEGA0. Exact
//! equation: theta'' = -(g/L) sin theta (T = m L^2 theta'^2 / 2, V = -m g L cos theta).
#![allow(dead_code)] // each test file uses its own subset

use std::sync::Arc;

use bead::model::{Endpoint, System, SystemBuilder};

pub const G: f64 = 9.81;
pub const L: f64 = 1.5;
pub const MASS: f64 = 2.0;
pub const THETA0: f64 = 1.0;
pub const OMEGA0: f64 = 0.5;

/// The pendulum as a distance constraint (implicit form) and as the angle map x = L (sin
/// theta, cos theta) (parametric form).
pub fn pendulum() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    b.param("L", L).unwrap();
    let (s, c) = THETA0.sin_cos();
    let bead = b
        .particle(
            "bead",
            MASS,
            &[L * s, L * c],
            &[L * OMEGA0 * c, -L * OMEGA0 * s],
        )
        .unwrap();
    b.distance("rod", bead, Endpoint::Fixed(vec![0.0, 0.0]), L)
        .unwrap();
    b.parametric(&["theta"], &[THETA0], &[OMEGA0]).unwrap();
    b.parametric_position_exprs("bead", &["L*sin(theta)", "L*cos(theta)"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// theta'' = -(g/L) sin theta by classic RK4 with step `h`, from t = 0: the bead's position
/// at every multiple of `every` steps (index 0 is t = 0). Uses nothing of the engine.
pub fn pendulum_reference_positions(h: f64, steps: u64, every: u64) -> Vec<[f64; 2]> {
    let f = |theta: f64| -(G / L) * theta.sin();
    let (mut theta, mut omega) = (THETA0, OMEGA0);
    let mut out = vec![[L * theta.sin(), L * theta.cos()]];
    for k in 1..=steps {
        let (k1q, k1v) = (omega, f(theta));
        let (k2q, k2v) = (omega + 0.5 * h * k1v, f(theta + 0.5 * h * k1q));
        let (k3q, k3v) = (omega + 0.5 * h * k2v, f(theta + 0.5 * h * k2q));
        let (k4q, k4v) = (omega + h * k3v, f(theta + h * k3q));
        theta += h / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q);
        omega += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        if k % every == 0 {
            out.push([L * theta.sin(), L * theta.cos()]);
        }
    }
    out
}

/// The reference position at `t_end`, reached in `n` RK4 steps.
pub fn pendulum_reference(t_end: f64, n: u64) -> [f64; 2] {
    let positions = pendulum_reference_positions(t_end / n as f64, n, n);
    positions[positions.len() - 1]
}

/// What the tests run: the formulation's integrator settings plus the run's length, as one
/// record (the library splits them into `SimulationConfig` and `RunOptions`).
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    pub integrator: bead::integrate::IntegratorKind,
    pub dt: f64,
    pub steps: u64,
    pub every: u64,
    pub settings: bead::integrate::IntegratorSettings,
    pub project: bool,
    /// The most substeps a retried step may take (1: no retries)
    pub max_substeps: u32,
}

impl Default for Options {
    /// rk4, dt = 1/60 s, 600 steps, every step recorded, default settings, no projection,
    /// the default retries.
    fn default() -> Self {
        Options {
            integrator: bead::integrate::IntegratorKind::Rk4,
            dt: 1.0 / 60.0,
            steps: 600,
            every: 1,
            settings: bead::integrate::IntegratorSettings::default(),
            project: false,
            max_substeps: bead::simulate::SimulationConfig::default().max_substeps,
        }
    }
}

impl Options {
    /// The simulation configuration: the tests set tolerances themselves, unscaled.
    pub fn config(&self) -> bead::simulate::SimulationConfig {
        bead::simulate::SimulationConfig {
            integrator: self.integrator,
            dt: self.dt,
            project: self.project,
            settings: self.settings,
            scaled_constraint_tolerance: false,
            max_substeps: self.max_substeps,
            ..Default::default()
        }
    }
}

/// A simulation of `formulation` as `options` say; panics when it cannot start.
pub fn simulation(
    formulation: Box<dyn bead::formulation::Formulation + Send>,
    options: &Options,
) -> bead::simulate::Simulation {
    bead::simulate::Simulation::with_formulation(formulation, options.config())
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Run `formulation` from its initial state as `options` say.
pub fn run(
    formulation: Box<dyn bead::formulation::Formulation + Send>,
    options: &Options,
    sink: &mut dyn bead::simulate::Sink,
) -> Result<bead::simulate::RunStats, bead::simulate::RunFailure> {
    run_with_progress(formulation, options, sink, &mut bead::simulate::NoProgress)
}

/// [`run`] with a progress observer.
pub fn run_with_progress(
    formulation: Box<dyn bead::formulation::Formulation + Send>,
    options: &Options,
    sink: &mut dyn bead::simulate::Sink,
    progress: &mut dyn bead::simulate::Progress,
) -> Result<bead::simulate::RunStats, bead::simulate::RunFailure> {
    let mut simulation = simulation(formulation, options);
    let run = bead::simulate::RunOptions {
        steps: options.steps,
        every: options.every,
    };
    bead::simulate::run_with_progress(&mut simulation, run, sink, progress)
}
