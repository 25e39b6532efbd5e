//! Convergence studies (`bead order`): each integrator at dt, dt/2, ..., dt/2^K against a
//! reference, with the observed order of each error per halving.
//!
//! A method of order p has global error e(h) ~ C h^p once h is in its asymptotic range, so
//! log2(e(h) / e(h/2)) tends to p. Three errors are measured per run, at the output times of
//! the coarsest step (t0 + j dt, which every level hits exactly: dt / 2^k is exact):
//!
//! - **position**: max over those times and every coordinate of |x - x_ref| (length units),
//!   against a reference computed by dopri5 at a tight tolerance (the parametric form when
//!   the scene has one, which cannot leave its curve; else the implicit form);
//! - **energy**: max |E - E0| / E_scale over the run, of E - W when the energy ledger runs
//!   (the run's own monitor; its exact value is E0, no reference needed);
//! - **off the constraints**: max |C_i| / |grad C_i| (length units; the implicit form only).
//!
//! An order is reported only where both errors of a halving lie above a floor below which
//! they are not the method's (the reference's own error, round-off, a solver's tolerance):
//! `Floors`. The work of a run is counted in evaluations of the acceleration
//! ([`Simulation::evaluations`]) and in wall time.

use std::sync::Arc;
use std::time::Instant;

use crate::formulation::Method;
use crate::integrate::IntegratorKind;
use crate::model::System;
use crate::simulate::{self, RunOptions, Sample, Simulation, SimulationConfig, Sink};

/// What a study runs.
#[derive(Clone, Debug)]
pub struct StudySettings {
    /// The coarsest step (s): the output interval of every level.
    pub dt: f64,
    /// How many times dt is halved (K: K + 1 levels).
    pub halvings: u32,
    /// Output intervals of dt to run (the duration is steps dt).
    pub steps: u64,
    /// The reference's relative tolerance (dopri5); its absolute tolerance is this times
    /// the scene's length scale.
    pub reference_rtol: f64,
}

/// The floors below which an error is not the method's (see the module).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floors {
    /// The reference's own error: its largest distance from a reference at 10x its
    /// tolerance, and at least 100 reference_rtol L (L the length scale)
    pub position: f64,
    /// 1e-10 (relative): round-off in E over 10^5 steps and the constraint solves'
    /// tolerances (RATTLE's 1e-12 of each row's scale)
    pub energy: f64,
    /// 1e-10 L: the constraint solvers' tolerances (RATTLE's is 1e-12 of each row's scale)
    pub constraint: f64,
}

/// One run of a series: one step size.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    pub dt: f64,
    pub steps: u64,
    /// Evaluations of the acceleration
    pub evaluations: u64,
    pub wall_seconds: f64,
    /// max |x - x_ref| at the coarse output times (length units)
    pub position_error: f64,
    /// max |E - (W) - E0| / E_scale
    pub energy_error: f64,
    /// max |C_i| / |grad C_i| (length units; `None` for the parametric form)
    pub constraint_error: Option<f64>,
}

/// A step size whose run failed.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelFailure {
    pub dt: f64,
    /// Why (divergence, a failed solve, a step too long for a constraint)
    pub error: String,
}

/// One integrator on one form at every step size: the runs that finished, and the ones that
/// failed. A failed step size does not end the series: an unstable coarse step is common
/// (explicit Euler at dt = 0.2 on the article's parabola), and the finer ones still measure
/// the order.
#[derive(Clone, Debug)]
pub struct Series {
    pub method: Method,
    pub integrator: IntegratorKind,
    /// The runs that finished, coarsest first
    pub levels: Vec<Level>,
    /// The step sizes whose run failed, coarsest first
    pub failures: Vec<LevelFailure>,
}

/// The observed orders log2(e_k / e_k+1) per halving, `None` where either error is at or
/// below `floor` (or not finite).
pub fn observed_orders(errors: &[f64], floor: f64) -> Vec<Option<f64>> {
    errors
        .windows(2)
        .map(|e| {
            let usable = |e: f64| e.is_finite() && e > floor;
            (usable(e[0]) && usable(e[1])).then(|| (e[0] / e[1]).log2())
        })
        .collect()
}

impl Series {
    /// The observed orders of the position error between consecutive levels (one fewer
    /// than the levels; see [`observed_orders`]), `None` also across a failed step size
    /// (two halvings are not one).
    pub fn position_orders(&self, floors: &Floors) -> Vec<Option<f64>> {
        self.orders(|l| l.position_error, floors.position)
    }
    /// As [`Self::position_orders`], of the energy error.
    pub fn energy_orders(&self, floors: &Floors) -> Vec<Option<f64>> {
        self.orders(|l| l.energy_error, floors.energy)
    }
    /// As [`Self::position_orders`], of the distance off the constraints.
    pub fn constraint_orders(&self, floors: &Floors) -> Vec<Option<f64>> {
        self.orders(|l| l.constraint_error.unwrap_or(0.0), floors.constraint)
    }

    fn orders(&self, error: impl Fn(&Level) -> f64, floor: f64) -> Vec<Option<f64>> {
        let errors: Vec<f64> = self.levels.iter().map(error).collect();
        observed_orders(&errors, floor)
            .into_iter()
            .zip(self.levels.windows(2))
            // dt / 2^k is exact: the next level is one halving on exactly when its dt is half.
            .map(|(order, pair)| order.filter(|_| pair[1].dt * 2.0 == pair[0].dt))
            .collect()
    }
}

/// A finished study.
#[derive(Clone, Debug)]
pub struct Study {
    pub settings: StudySettings,
    /// The form the reference ran on, and its accepted steps
    pub reference_method: Method,
    pub reference_steps: u64,
    /// The scene's length scale L (the largest initial coordinate magnitude, 1 when all 0)
    pub length_scale: f64,
    pub floors: Floors,
    pub series: Vec<Series>,
}

/// Why a study could not run.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StudyError {
    #[error("the convergence study needs dt > 0, at least one step and one halving at most 12 (got dt = {dt}, {steps} steps, {halvings} halvings)")]
    Settings { dt: f64, steps: u64, halvings: u32 },
    #[error("{integrator} chooses its own steps: a convergence study halves a fixed step (study dopri5 by its tolerance with `bead compare --rtols`)")]
    Adaptive { integrator: &'static str },
    #[error("the reference run (dopri5 at rtol {rtol:e}, {method} form) failed: {error}")]
    Reference {
        rtol: f64,
        method: &'static str,
        error: String,
    },
}

/// Runs shorter than this (s) are timed twice, the faster counting.
const REPEAT_BELOW: f64 = 0.5;

/// Particle positions at every recorded sample.
struct Positions(Vec<(u64, Vec<f64>)>);

impl Sink for Positions {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.0.push((sample.step, sample.x.to_vec()));
        Ok(())
    }
}

/// max over the samples of `run` (recorded every `every` steps) and their coordinates of
/// |x - x_ref|, x_ref the `reference` sample (recorded every step of the coarse dt) at the
/// same time; NaN if any is.
fn largest_difference(run: &Positions, reference: &Positions, every: u64) -> f64 {
    let mut largest = 0.0_f64;
    for (step, x) in &run.0 {
        let (_, x_ref) = &reference.0[(step / every) as usize];
        for (a, b) in x.iter().zip(x_ref) {
            largest = crate::linalg::max_nan(largest, (a - b).abs());
        }
    }
    largest
}

/// Run `system` with `config` for `steps` intervals of `config.dt`, recording every
/// `every`-th: the positions, the stats and the evaluations.
fn positions_of(
    system: &Arc<System>,
    config: SimulationConfig,
    steps: u64,
    every: u64,
) -> Result<(Positions, simulate::RunStats, u64, f64), String> {
    let mut simulation = Simulation::new(system.clone(), config).map_err(|e| e.to_string())?;
    let mut positions = Positions(Vec::new());
    let options = RunOptions {
        steps,
        every,
        duration: None,
    };
    let start = Instant::now();
    let stats = simulate::run(&mut simulation, options, &mut positions)
        .map_err(|failure| failure.error.to_string())?;
    let mut wall = start.elapsed().as_secs_f64();
    let evaluations = simulation.evaluations();
    if wall < REPEAT_BELOW {
        // A short run's time is mostly its cold start (caches, first evaluations): the
        // faster of two runs.
        let mut again = Simulation::new(system.clone(), config).map_err(|e| e.to_string())?;
        let start = Instant::now();
        simulate::run(&mut again, options, &mut simulate::NullSink)
            .map_err(|failure| failure.error.to_string())?;
        wall = wall.min(start.elapsed().as_secs_f64());
    }
    Ok((positions, stats, evaluations, wall))
}

/// The study of `cases` (form, integrator) on `system`, each built from `base` (tolerances,
/// feedback, projection) with its own form, integrator and step.
pub fn study(
    system: &Arc<System>,
    cases: &[(Method, IntegratorKind)],
    settings: &StudySettings,
    base: &SimulationConfig,
) -> Result<Study, StudyError> {
    let StudySettings {
        dt,
        halvings,
        steps,
        reference_rtol,
    } = settings.clone();
    if !(dt > 0.0 && dt.is_finite()) || steps == 0 || halvings > 12 {
        return Err(StudyError::Settings {
            dt,
            steps,
            halvings,
        });
    }
    if let Some(&(_, kind)) = cases.iter().find(|(_, k)| k.is_adaptive()) {
        return Err(StudyError::Adaptive {
            integrator: kind.name(),
        });
    }
    let length_scale = system.length_scale();
    // The reference: dopri5 at the tight tolerance, on the form that cannot drift.
    let reference_method = if system.parametric().is_some() {
        Method::Parametric
    } else {
        Method::Implicit
    };
    let mut reference_config = SimulationConfig {
        method: reference_method,
        integrator: IntegratorKind::Dopri5,
        dt,
        project: false,
        substeps: 1,
        max_substeps: 1,
        ..*base
    };
    if reference_method == Method::Parametric {
        reference_config.feedback = Default::default();
    }
    reference_config.settings.rtol = reference_rtol;
    reference_config.settings.atol = reference_rtol * length_scale;
    let reference_error = |error: String| StudyError::Reference {
        rtol: reference_rtol,
        method: reference_method.name(),
        error,
    };
    let (reference, reference_stats, _, _) =
        positions_of(system, reference_config, steps, 1).map_err(reference_error)?;
    // The reference's own error, bounded by the distance to a reference at 10x the
    // tolerance (about 10x its error): no smaller position error is the method's.
    let mut looser_config = reference_config;
    looser_config.settings.rtol *= 10.0;
    looser_config.settings.atol *= 10.0;
    let (looser, _, _, _) =
        positions_of(system, looser_config, steps, 1).map_err(reference_error)?;
    let reference_spread = largest_difference(&reference, &looser, 1);
    let floors = Floors {
        position: reference_spread.max(100.0 * reference_rtol * length_scale),
        energy: 1e-10,
        constraint: 1e-10 * length_scale,
    };
    let mut series = Vec::new();
    for &(method, integrator) in cases {
        let mut levels = Vec::new();
        let mut failures = Vec::new();
        for k in 0..=halvings {
            let every = 1u64 << k;
            let mut config = SimulationConfig {
                method,
                integrator,
                dt: dt / every as f64,
                ..*base
            };
            if method == Method::Parametric {
                config.feedback = Default::default();
                config.project = false;
            }
            let (positions, stats, evaluations, wall_seconds) =
                match positions_of(system, config, steps * every, every) {
                    Ok(run) => run,
                    Err(error) => {
                        failures.push(LevelFailure {
                            dt: dt / every as f64,
                            error,
                        });
                        continue;
                    }
                };
            let position_error = largest_difference(&positions, &reference, every);
            levels.push(Level {
                dt: dt / every as f64,
                steps: stats.steps,
                evaluations,
                wall_seconds,
                position_error,
                energy_error: stats.conserved_energy_error_max(),
                constraint_error: stats.constraint_distance_max,
            });
        }
        series.push(Series {
            method,
            integrator,
            levels,
            failures,
        });
    }
    Ok(Study {
        settings: settings.clone(),
        reference_method,
        reference_steps: reference_stats.steps,
        length_scale,
        floors,
        series,
    })
}
