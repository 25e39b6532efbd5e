//! The run loop: advance a formulation with an integrator, watch energy, constraint error and
//! divergence, and push samples into a [`Sink`].

use std::time::Instant;

use crate::formulation::{Formulation, Method, StepError};
use crate::integrate::IntegratorKind;
use crate::model::ConstraintEval;

/// How to run.
#[derive(Clone, Debug, PartialEq)]
pub struct RunOptions {
    pub integrator: IntegratorKind,
    /// Step size (s), > 0.
    pub dt: f64,
    /// Number of steps.
    pub steps: u64,
    /// Record every K-th step to the sink (the first and last state are always recorded).
    pub every: u64,
}

/// One recorded state, in particle space and in the formulation's own coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Sample<'a> {
    pub step: u64,
    pub t: f64,
    /// Particle positions (n_coords)
    pub x: &'a [f64],
    /// Particle velocities (n_coords)
    pub xdot: &'a [f64],
    /// Total mechanical energy T + V
    pub energy: f64,
    /// max_i |C_i| over the system's implicit constraints
    pub constraint_error: f64,
    /// The formulation's coordinates: particle coordinates (implicit) or q (parametric)
    pub q: &'a [f64],
    pub qdot: &'a [f64],
}

/// Receives samples as the run goes. Implementations flush as they write, so that a run that
/// fails keeps every finished record.
pub trait Sink {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()>;
    /// Called once at the end, whether the run succeeded or failed.
    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A sink that discards everything.
pub struct NullSink;
impl Sink for NullSink {
    fn record(&mut self, _: &Sample) -> std::io::Result<()> {
        Ok(())
    }
}

/// Figures of a run (complete or up to where it stopped).
#[derive(Clone, Debug, PartialEq)]
pub struct RunStats {
    pub method: Method,
    pub integrator: IntegratorKind,
    pub dt: f64,
    /// Steps completed.
    pub steps: u64,
    pub t_final: f64,
    pub wall_seconds: f64,
    pub energy_initial: f64,
    pub energy_final: f64,
    /// max over steps of |E - E0| / E_scale, E_scale = max(|E0|, T0 + |V0|), or 1 (absolute
    /// error) when both vanish.
    pub energy_rel_error_max: f64,
    pub constraint_error_max: f64,
    pub constraint_error_final: f64,
    /// Final particle positions and velocities (n_coords each).
    pub x: Vec<f64>,
    pub xdot: Vec<f64>,
    /// Final formulation coordinates and rates.
    pub q: Vec<f64>,
    pub qdot: Vec<f64>,
}

impl RunStats {
    /// Steps per second of wall time.
    pub fn steps_per_second(&self) -> f64 {
        if self.wall_seconds > 0.0 {
            self.steps as f64 / self.wall_seconds
        } else {
            0.0
        }
    }
}

/// Why a run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Step(StepError),
    #[error("diverged at t = {t} (step {step}): {quantity} is {}", readable(*value))]
    Diverged {
        t: f64,
        step: u64,
        quantity: String,
        value: f64,
    },
    #[error("writing output failed: {0}")]
    Io(#[from] std::io::Error),
}

/// A run that stopped early, with the figures up to the last good state.
#[derive(Debug, thiserror::Error)]
#[error("{error}")]
pub struct RunFailure {
    pub error: RunError,
    pub stats: Box<RunStats>,
}

/// `value` in plain notation, or in exponent notation when it is very large or very small.
pub fn readable(value: f64) -> String {
    let magnitude = value.abs();
    if magnitude != 0.0 && magnitude.is_finite() && !(1e-4..1e16).contains(&magnitude) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

/// Values beyond this magnitude count as a blow-up.
const BLOW_UP: f64 = 1e150;

struct Monitor {
    constraints: ConstraintEval,
    x: Vec<f64>,
    xdot: Vec<f64>,
    energy_initial: f64,
    energy_scale: f64,
    energy: f64,
    energy_rel_error_max: f64,
    constraint_error: f64,
    constraint_error_max: f64,
}

impl Monitor {
    /// Particle state, energy and constraint error at (t, q, qdot).
    fn observe(&mut self, formulation: &mut dyn Formulation, t: f64, q: &[f64], qdot: &[f64]) {
        formulation.particle_state(t, q, qdot, &mut self.x, &mut self.xdot);
        let system = formulation.system();
        self.energy = system.energy(&self.x, &self.xdot);
        self.constraint_error =
            system
                .constraints()
                .max_abs_residual(t, &self.x, &mut self.constraints);
        let rel = (self.energy - self.energy_initial).abs() / self.energy_scale;
        self.energy_rel_error_max = max_nan(self.energy_rel_error_max, rel);
        self.constraint_error_max = max_nan(self.constraint_error_max, self.constraint_error);
    }
}

/// max that propagates NaN.
fn max_nan(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// Run `formulation` from its initial state. The step loop allocates nothing.
pub fn run(
    formulation: &mut dyn Formulation,
    options: &RunOptions,
    sink: &mut dyn Sink,
) -> Result<RunStats, RunFailure> {
    let start = Instant::now();
    let mut state = formulation.initial_state();
    let mut integrator = options.integrator.build(state.q.len());
    let n = formulation.system().n_coords();
    let mut monitor = Monitor {
        constraints: formulation.system().constraints().workspace(),
        x: vec![0.0; n],
        xdot: vec![0.0; n],
        energy_initial: 0.0,
        energy_scale: 1.0,
        energy: 0.0,
        energy_rel_error_max: 0.0,
        constraint_error: 0.0,
        constraint_error_max: 0.0,
    };
    formulation.particle_state(
        state.t,
        &state.q,
        &state.qdot,
        &mut monitor.x,
        &mut monitor.xdot,
    );
    {
        let system = formulation.system();
        let (kinetic, potential) = (
            system.kinetic_energy(&monitor.xdot),
            system.potential_energy(&monitor.x),
        );
        monitor.energy_initial = kinetic + potential;
        let scale = monitor.energy_initial.abs().max(kinetic + potential.abs());
        monitor.energy_scale = if scale > 0.0 { scale } else { 1.0 };
    }
    monitor.observe(formulation, state.t, &state.q, &state.qdot);
    let every = options.every.max(1);
    let mut previous = state.clone();
    let mut recorded_step = 0;
    let mut failure = None;
    let mut step = 0;

    if let Err(e) = sink.record(&monitor.sample(0, &state)) {
        failure = Some(RunError::Io(e));
    }

    while failure.is_none() && step < options.steps {
        previous.t = state.t;
        previous.q.copy_from_slice(&state.q);
        previous.qdot.copy_from_slice(&state.qdot);
        if let Err(e) = integrator.step(&mut *formulation, &mut state, options.dt) {
            failure = Some(RunError::Step(e));
            break;
        }
        step += 1;
        // Time from the step count, so that it does not accumulate rounding.
        state.t = step as f64 * options.dt;
        if let Some((quantity, value)) = non_finite(formulation, &state.q, &state.qdot) {
            failure = Some(RunError::Diverged {
                t: state.t,
                step,
                quantity,
                value,
            });
            break;
        }
        monitor.observe(formulation, state.t, &state.q, &state.qdot);
        if !monitor.energy.is_finite() || !monitor.constraint_error.is_finite() {
            let (quantity, value) = if monitor.energy.is_finite() {
                ("the constraint error".to_string(), monitor.constraint_error)
            } else {
                ("the energy".to_string(), monitor.energy)
            };
            failure = Some(RunError::Diverged {
                t: state.t,
                step,
                quantity,
                value,
            });
            break;
        }
        if step % every == 0 || step == options.steps {
            recorded_step = step;
            if let Err(e) = sink.record(&monitor.sample(step, &state)) {
                failure = Some(RunError::Io(e));
            }
        }
    }

    let last_good = if failure.is_some() && !matches!(failure, Some(RunError::Io(_))) {
        // The state before the failing step is the last good one; make sure the sink has it.
        let good_step = if matches!(failure, Some(RunError::Step(_))) {
            step
        } else {
            step - 1
        };
        monitor.observe_quiet(formulation, &previous);
        if good_step != recorded_step {
            // Best effort: the run has already failed, and that error is the one to report.
            let _ = sink.record(&monitor.sample(good_step, &previous));
        }
        step = good_step;
        previous
    } else {
        state
    };
    let finish = sink.finish();
    let stats = RunStats {
        method: formulation.method(),
        integrator: options.integrator,
        dt: options.dt,
        steps: step,
        t_final: last_good.t,
        wall_seconds: start.elapsed().as_secs_f64(),
        energy_initial: monitor.energy_initial,
        energy_final: monitor.energy,
        energy_rel_error_max: monitor.energy_rel_error_max,
        constraint_error_max: monitor.constraint_error_max,
        constraint_error_final: monitor.constraint_error,
        x: monitor.x.clone(),
        xdot: monitor.xdot.clone(),
        q: last_good.q,
        qdot: last_good.qdot,
    };
    match (failure, finish) {
        (Some(error), _) => Err(RunFailure {
            error,
            stats: Box::new(stats),
        }),
        (None, Err(e)) => Err(RunFailure {
            error: RunError::Io(e),
            stats: Box::new(stats),
        }),
        (None, Ok(())) => Ok(stats),
    }
}

impl Monitor {
    /// The sample of `state` at `step`, with the particle state and diagnostics last observed.
    fn sample<'a>(&'a self, step: u64, state: &'a crate::formulation::State) -> Sample<'a> {
        Sample {
            step,
            t: state.t,
            x: &self.x,
            xdot: &self.xdot,
            energy: self.energy,
            constraint_error: self.constraint_error,
            q: &state.q,
            qdot: &state.qdot,
        }
    }

    /// Particle state, energy and constraint error of `state` without touching the maxima.
    fn observe_quiet(
        &mut self,
        formulation: &mut dyn Formulation,
        state: &crate::formulation::State,
    ) {
        formulation.particle_state(state.t, &state.q, &state.qdot, &mut self.x, &mut self.xdot);
        let system = formulation.system();
        self.energy = system.energy(&self.x, &self.xdot);
        self.constraint_error =
            system
                .constraints()
                .max_abs_residual(state.t, &self.x, &mut self.constraints);
    }
}

/// The first non-finite or blown-up coordinate, named.
fn non_finite(formulation: &dyn Formulation, q: &[f64], qdot: &[f64]) -> Option<(String, f64)> {
    let name = |k: usize, rate: bool| {
        let names = formulation.coordinate_names();
        let base = if names.is_empty() {
            formulation.system().coordinate_name(k)
        } else {
            format!("q.{}", names[k])
        };
        if rate {
            format!("the velocity of {base}")
        } else {
            base
        }
    };
    for (k, &value) in q.iter().enumerate() {
        if !value.is_finite() || value.abs() > BLOW_UP {
            return Some((name(k, false), value));
        }
    }
    for (k, &value) in qdot.iter().enumerate() {
        if !value.is_finite() || value.abs() > BLOW_UP {
            return Some((name(k, true), value));
        }
    }
    None
}
