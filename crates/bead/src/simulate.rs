//! The run loop: advance a formulation with an integrator, watch energy, constraint error and
//! divergence, and push samples into a [`Sink`].

use std::time::Instant;

use crate::formulation::{Formulation, Method, StepError};
use crate::integrate::{Dopri5, IntegratorKind, IntegratorSettings};
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
    /// Tolerances and iteration limits of the integrators that have them.
    pub settings: IntegratorSettings,
    /// After every step, project the positions onto C(q, t) = 0 (to
    /// `settings.constraint_tolerance`, at most `settings.constraint_max_iterations`
    /// Gauss-Newton iterations) and the velocities onto J qdot + C_t = 0, through
    /// [`crate::formulation::ConstrainedSystem`]. Implicit form only; not with dopri5.
    pub project: bool,
}

impl Default for RunOptions {
    /// rk4, dt = 1/60 s, 600 steps, every step recorded, default settings, no projection.
    fn default() -> Self {
        RunOptions {
            integrator: IntegratorKind::Rk4,
            dt: 1.0 / 60.0,
            steps: 600,
            every: 1,
            settings: IntegratorSettings::default(),
            project: false,
        }
    }
}

/// An absolute tolerance on max_i |C_i| for `system`, in the units of its constraints:
/// `relative` times max_i |J_i| L at the initial state, where |J_i| is the norm of row i's
/// gradient and L the largest initial coordinate magnitude (the scene's length scale; 1 when
/// every coordinate is 0). For the article's parabola C = x^2 + 100 y at (150, -225) this is
/// relative * 316 * 225 ~ relative * 7e4 (the scale of C, length^2). `relative` itself when
/// the system has no constraints.
pub fn constraint_tolerance(system: &crate::model::System, relative: f64) -> f64 {
    let set = system.constraints();
    let (x, v) = system.initial_particle_state();
    let length = x.iter().fold(0.0, |l: f64, c| l.max(c.abs()));
    let length = if length > 0.0 && length.is_finite() {
        length
    } else {
        1.0
    };
    let mut ws = set.workspace();
    set.evaluate(0.0, &x, &v, &mut ws);
    let gradient = (0..set.n_rows())
        .map(|i| {
            ws.jacobian[set.row_entries(i)]
                .iter()
                .map(|j| j * j)
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max);
    if gradient > 0.0 && gradient.is_finite() {
        relative * gradient * length
    } else {
        relative
    }
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
    /// Adaptive runs only (dopri5): integrator steps accepted and rejected. For these runs
    /// `dt` is the output interval and `steps` counts output intervals (t = steps * dt).
    pub accepted_steps: Option<u64>,
    pub rejected_steps: Option<u64>,
    /// Whether positions and velocities were projected onto the constraints after every step.
    pub projected: bool,
    /// The most Newton iterations any step needed, over the integrator's own solve (rattle)
    /// and the projection; `None` when neither ran.
    pub newton_iterations_max: Option<usize>,
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
    #[error("{0}")]
    Unsupported(String),
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
    /// Particle positions beyond this count as a blow-up (see [`BLOW_UP_FACTOR`]).
    position_limit: f64,
    /// Particle velocities beyond this count as a blow-up.
    velocity_limit: f64,
}

/// A particle farther than this many times the run's length scale, or faster than this many
/// times its speed scale, has diverged. Over a run of duration T:
/// L = max(1, max |x0|, max |v0| T, |g| T^2 / 2) and V = max(1, max |v0|, |g| T, sqrt(|g| L)),
/// the reach of the initial state and of gravity. Legitimate motion stays within a small
/// multiple of those, while an unstable integration grows geometrically and passes 10^12 of
/// them within a few steps, long before f64 overflows.
const BLOW_UP_FACTOR: f64 = 1e12;

impl Monitor {
    /// Observe `state` after a step, or say why it has diverged: a non-finite or blown-up
    /// coordinate of the formulation (checked first, so nothing is evaluated on NaN), else
    /// [`Monitor::divergence`] of the observed particle state.
    fn observe_checked(
        &mut self,
        formulation: &mut dyn Formulation,
        state: &crate::formulation::State,
    ) -> Option<(String, f64)> {
        if let Some(found) = non_finite(formulation, &state.q, &state.qdot) {
            return Some(found);
        }
        self.observe(formulation, state.t, &state.q, &state.qdot);
        self.divergence(formulation.system())
    }

    /// Why the last observed state has diverged, if it has: a non-finite energy or constraint
    /// error, or a particle beyond the position or velocity limit.
    fn divergence(&self, system: &crate::model::System) -> Option<(String, f64)> {
        if !self.energy.is_finite() {
            return Some(("the energy".into(), self.energy));
        }
        if !self.constraint_error.is_finite() {
            return Some(("the constraint error".into(), self.constraint_error));
        }
        if let Some(k) = self.x.iter().position(|x| x.abs() > self.position_limit) {
            let quantity = format!(
                "{} (limit {:e}, {BLOW_UP_FACTOR:e} times the scene's length scale)",
                system.coordinate_name(k),
                self.position_limit
            );
            return Some((quantity, self.x[k]));
        }
        if let Some(k) = self.xdot.iter().position(|v| v.abs() > self.velocity_limit) {
            let quantity = format!(
                "the velocity of {} (limit {:e}, {BLOW_UP_FACTOR:e} times the scene's speed scale)",
                system.coordinate_name(k),
                self.velocity_limit
            );
            return Some((quantity, self.xdot[k]));
        }
        None
    }

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

/// Told how far a run has got, for progress bars. Called at most about 100 times per run
/// (every `max(1, total / 100)` steps, or output intervals for adaptive runs), from the step
/// loop, which allocates nothing: implementations should not allocate either.
pub trait Progress {
    /// `step` of `total` steps done.
    fn advance(&mut self, step: u64, total: u64);
}

/// A [`Progress`] that ignores everything.
pub struct NoProgress;
impl Progress for NoProgress {
    fn advance(&mut self, _: u64, _: u64) {}
}

/// Run `formulation` from its initial state. The step loop allocates nothing.
pub fn run(
    formulation: &mut dyn Formulation,
    options: &RunOptions,
    sink: &mut dyn Sink,
) -> Result<RunStats, RunFailure> {
    run_with_progress(formulation, options, sink, &mut NoProgress)
}

/// [`run`], telling `progress` how far it has got (see [`Progress`]).
pub fn run_with_progress(
    formulation: &mut dyn Formulation,
    options: &RunOptions,
    sink: &mut dyn Sink,
    progress: &mut dyn Progress,
) -> Result<RunStats, RunFailure> {
    let start = Instant::now();
    let unsupported = unsupported(formulation, options);
    let progress_every = (options.steps / 100).max(1);
    if options.integrator.is_adaptive() && unsupported.is_none() {
        return run_adaptive(formulation, options, sink, start, progress);
    }
    let mut state = formulation.initial_state();
    let mut integrator = options
        .integrator
        .build_with(state.q.len(), &options.settings);
    let mut monitor = start_monitor(formulation, &state, options.steps as f64 * options.dt);
    let every = options.every.max(1);
    let mut previous = state.clone();
    let mut recorded_step = 0;
    let mut failure = unsupported;
    let mut step = 0;
    let mut projection_iterations_max = None;

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
        // Time from the step count, so that it does not accumulate rounding.
        state.t = (step + 1) as f64 * options.dt;
        if options.project {
            match project(formulation, &mut state, &options.settings) {
                Ok(iterations) => {
                    projection_iterations_max =
                        Some(projection_iterations_max.unwrap_or(0).max(iterations));
                }
                Err(e) => {
                    failure = Some(RunError::Step(e));
                    break;
                }
            }
        }
        step += 1;
        if step % progress_every == 0 {
            progress.advance(step, options.steps);
        }
        if let Some((quantity, value)) = monitor.observe_checked(formulation, &state) {
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
        let good_step = if matches!(failure, Some(RunError::Step(_) | RunError::Unsupported(_))) {
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
    let mut stats = monitor.stats(formulation, options, step, last_good, start);
    stats.newton_iterations_max = match (
        integrator.newton_iterations_max(),
        projection_iterations_max,
    ) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    };
    conclude(failure, sink.finish(), stats)
}

impl Monitor {
    /// The figures of a run that ends (or stopped) at `last_good` after `steps` steps or
    /// output intervals; the integrator-specific fields are left for the caller.
    fn stats(
        &self,
        formulation: &dyn Formulation,
        options: &RunOptions,
        steps: u64,
        last_good: crate::formulation::State,
        start: Instant,
    ) -> RunStats {
        RunStats {
            method: formulation.method(),
            integrator: options.integrator,
            dt: options.dt,
            steps,
            t_final: last_good.t,
            wall_seconds: start.elapsed().as_secs_f64(),
            energy_initial: self.energy_initial,
            energy_final: self.energy,
            energy_rel_error_max: self.energy_rel_error_max,
            constraint_error_max: self.constraint_error_max,
            constraint_error_final: self.constraint_error,
            x: self.x.clone(),
            xdot: self.xdot.clone(),
            q: last_good.q,
            qdot: last_good.qdot,
            accepted_steps: None,
            rejected_steps: None,
            projected: options.project,
            newton_iterations_max: None,
        }
    }

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

/// Why `options` cannot run on `formulation` at all: an integrator or a projection that needs
/// constraints on a form without them, or a projection with the adaptive integrator.
fn unsupported(formulation: &mut dyn Formulation, options: &RunOptions) -> Option<RunError> {
    let constrained = formulation.as_constrained().is_some();
    if options.integrator.needs_constraints() && !constrained {
        return Some(RunError::Step(StepError::NeedsConstraints {
            what: options.integrator.name().into(),
        }));
    }
    if options.project && !constrained {
        return Some(RunError::Step(StepError::NeedsConstraints {
            what: "projection (--project)".into(),
        }));
    }
    if options.project && options.integrator.is_adaptive() {
        return Some(RunError::Unsupported(format!(
            "projection (--project) is not available with {}: it would invalidate the adaptive integrator's step control and dense output; use a fixed-step integrator",
            options.integrator.name()
        )));
    }
    None
}

/// Project `state` onto C = 0 and J qdot + C_t = 0; returns the position iterations.
fn project(
    formulation: &mut dyn Formulation,
    state: &mut crate::formulation::State,
    settings: &IntegratorSettings,
) -> Result<usize, StepError> {
    let Some(constrained) = formulation.as_constrained() else {
        return Ok(0);
    };
    let iterations = constrained.project_positions(
        state.t,
        &mut state.q,
        settings.constraint_tolerance,
        settings.constraint_max_iterations,
    )?;
    constrained.project_velocities(state.t, &state.q, &mut state.qdot)?;
    Ok(iterations)
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

/// A monitor at the initial state, with the energy scale fixed there.
fn start_monitor(
    formulation: &mut dyn Formulation,
    state: &crate::formulation::State,
    duration: f64,
) -> Monitor {
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
        position_limit: f64::INFINITY,
        velocity_limit: f64::INFINITY,
    };
    formulation.particle_state(
        state.t,
        &state.q,
        &state.qdot,
        &mut monitor.x,
        &mut monitor.xdot,
    );
    let system = formulation.system();
    let largest = |v: &[f64]| v.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
    let gravity = system.gravity().iter().map(|g| g * g).sum::<f64>().sqrt();
    let (x0, v0) = (largest(&monitor.x), largest(&monitor.xdot));
    let length = [1.0, x0, v0 * duration, 0.5 * gravity * duration * duration]
        .into_iter()
        .fold(0.0, f64::max);
    let speed = [1.0, v0, gravity * duration, (gravity * length).sqrt()]
        .into_iter()
        .fold(0.0, f64::max);
    monitor.position_limit = BLOW_UP_FACTOR * length;
    monitor.velocity_limit = BLOW_UP_FACTOR * speed;
    let (kinetic, potential) = (
        system.kinetic_energy(&monitor.xdot),
        system.potential_energy(&monitor.x),
    );
    monitor.energy_initial = kinetic + potential;
    let scale = monitor.energy_initial.abs().max(kinetic + potential.abs());
    monitor.energy_scale = if scale > 0.0 { scale } else { 1.0 };
    monitor.observe(formulation, state.t, &state.q, &state.qdot);
    monitor
}

/// The adaptive path (dopri5): integrate to t_final = steps * dt with the integrator's own
/// steps; dt is the output interval. Samples at every `every * dt` (and t_final) come from the
/// dense output; the energy and constraint maxima are taken over those samples and over the
/// end of every accepted step. The last step is shortened to end exactly at t_final; no other
/// step is shortened for output. The loop allocates nothing.
fn run_adaptive(
    formulation: &mut dyn Formulation,
    options: &RunOptions,
    sink: &mut dyn Sink,
    start: Instant,
    progress: &mut dyn Progress,
) -> Result<RunStats, RunFailure> {
    let progress_every = (options.steps / 100).max(1);
    let mut state = formulation.initial_state();
    let mut integrator = Dopri5::new(state.q.len(), &options.settings);
    let mut monitor = start_monitor(formulation, &state, options.steps as f64 * options.dt);
    let every = options.every.max(1);
    let t_final = options.steps as f64 * options.dt;
    let mut sample = state.clone();
    let mut previous = state.clone();
    let mut failure = None;
    // Output intervals completed: samples lie at interval * dt.
    let mut interval = 0;
    let mut recorded = 0;

    if let Err(e) = sink.record(&monitor.sample(0, &state)) {
        failure = Some(RunError::Io(e));
    }

    'steps: while failure.is_none() && interval < options.steps {
        previous.t = state.t;
        previous.q.copy_from_slice(&state.q);
        previous.qdot.copy_from_slice(&state.qdot);
        if let Err(e) = integrator.advance(&mut *formulation, &mut state, t_final) {
            failure = Some(RunError::Step(e));
            break;
        }
        if let Some((quantity, value)) = monitor.observe_checked(formulation, &state) {
            failure = Some(RunError::Diverged {
                t: state.t,
                step: interval,
                quantity,
                value,
            });
            break;
        }
        // Every output time inside this step.
        loop {
            let next = interval + 1;
            let t_sample = if next == options.steps {
                t_final
            } else {
                next as f64 * options.dt
            };
            if next > options.steps || t_sample > state.t {
                break;
            }
            interval = next;
            if interval % progress_every == 0 {
                progress.advance(interval, options.steps);
            }
            if interval % every == 0 || interval == options.steps {
                integrator.interpolate(t_sample, &mut sample.q, &mut sample.qdot);
                sample.t = t_sample;
                monitor.observe(formulation, t_sample, &sample.q, &sample.qdot);
                recorded = interval;
                if let Err(e) = sink.record(&monitor.sample(interval, &sample)) {
                    failure = Some(RunError::Io(e));
                    break 'steps;
                }
            }
        }
    }

    let last_good = match &failure {
        Some(RunError::Io(_)) | None => state,
        Some(error) => {
            // A failed step leaves the state as it was; a diverged one is dropped.
            let good = if matches!(error, RunError::Step(_)) {
                state
            } else {
                previous
            };
            monitor.observe_quiet(formulation, &good);
            if good.t != recorded as f64 * options.dt {
                // Best effort: the run has already failed, and that error is the one to report.
                let _ = sink.record(&monitor.sample(interval, &good));
            }
            good
        }
    };
    let mut stats = monitor.stats(formulation, options, interval, last_good, start);
    stats.accepted_steps = Some(integrator.accepted_steps());
    stats.rejected_steps = Some(integrator.rejected_steps());
    conclude(failure, sink.finish(), stats)
}

/// The result of a run from its failure (if any), the sink's `finish` and its figures.
fn conclude(
    failure: Option<RunError>,
    finish: std::io::Result<()>,
    stats: RunStats,
) -> Result<RunStats, RunFailure> {
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
