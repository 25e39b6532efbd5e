//! A run: a [`Simulation`] advanced over a number of output intervals, each recorded sample
//! pushed into a [`Sink`], with the figures of the run at the end.

use std::time::Instant;

use super::express::{Express, EXPRESS_CHUNK, EXPRESS_COOLDOWN};
use super::{Quantity, Simulation};
use crate::formulation::{Method, Nonconservation, StepError};
use crate::integrate::IntegratorKind;

/// How long to run and how often to record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunOptions {
    /// Output intervals of dt to run: steps for fixed-step integrators.
    pub steps: u64,
    /// Record every K-th interval (the first and the last state are always recorded).
    pub every: u64,
    /// When set, the run ends at exactly t0 + duration: the last output interval ends there
    /// instead of at t0 + steps dt, and is shorter than dt when the duration is not a whole
    /// number of dt (the fixed-step integrators take one shorter step, as
    /// [`Simulation::advance_to`] does). It should lie in ((steps - 1) dt, steps dt].
    pub duration: Option<f64>,
}

impl RunOptions {
    /// `steps` output intervals of dt, every one recorded, ending at t0 + steps dt.
    pub fn steps(steps: u64) -> RunOptions {
        RunOptions {
            steps,
            every: 1,
            duration: None,
        }
    }

    /// The end of output interval k of a run from t0: t0 + k dt, computed from k so that it
    /// does not accumulate rounding; the last one t0 + duration when a duration is set.
    pub fn output_time(&self, t0: f64, k: u64, dt: f64) -> f64 {
        match self.duration {
            Some(duration) if k >= self.steps => t0 + duration,
            _ => t0 + k as f64 * dt,
        }
    }
}

impl Default for RunOptions {
    /// 600 intervals (10 s at dt = 1/60), every one recorded.
    fn default() -> Self {
        RunOptions::steps(600)
    }
}

/// One recorded state, in particle space and in the formulation's own coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Sample<'a> {
    /// The output interval this sample ends (0 for the initial state).
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
    /// The work W done on T + V so far, when the energy ledger runs
    pub work: Option<f64>,
    /// T + V at the start of the run
    pub energy_initial: f64,
    /// E_scale, the denominator of relative energy errors (see
    /// [`Simulation::energy_scale`])
    pub energy_scale: f64,
}

impl Sample<'_> {
    /// The relative error of the conserved energy: |E - W - E0| / E_scale, with W = 0 when
    /// the energy ledger does not run (then T + V itself is conserved).
    pub fn conserved_energy_error(&self) -> f64 {
        (self.energy - self.work.unwrap_or(0.0) - self.energy_initial).abs() / self.energy_scale
    }
}

/// Receives samples as the run goes. Implementations flush as they write, so that a run that
/// fails keeps every finished record.
pub trait Sink {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()>;
    /// Called once at the end, whether the run succeeded or failed.
    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
    /// Whether the sink throws every sample away: then [`run`] records only the first and
    /// the last, and takes the steps between without stopping for rows (express runs).
    fn discards(&self) -> bool {
        false
    }
}

/// A sink that discards everything.
pub struct NullSink;
impl Sink for NullSink {
    fn record(&mut self, _: &Sample) -> std::io::Result<()> {
        Ok(())
    }
    fn discards(&self) -> bool {
        true
    }
}

/// Figures of a run (complete or up to where it stopped).
#[derive(Clone, Debug, PartialEq)]
pub struct RunStats {
    pub method: Method,
    pub integrator: IntegratorKind,
    /// Step size, or output interval of adaptive integrators (s).
    pub dt: f64,
    /// Integrator steps taken (for adaptive integrators: accepted steps).
    pub steps: u64,
    pub t_final: f64,
    pub wall_seconds: f64,
    pub energy_initial: f64,
    pub energy_final: f64,
    /// E_scale = max(|E0|, T0 + |V0|, T0 + M |g| L): the denominator of the relative energy
    /// errors (see [`Simulation::energy_scale`]).
    pub energy_scale: f64,
    /// max over the run of |E - E0| / E_scale.
    pub energy_rel_error_max: f64,
    /// Whether T + V is conserved (nothing does work on the system).
    pub energy_conserved: bool,
    /// What does work on the system when it is not.
    pub nonconservation: Vec<Nonconservation>,
    /// The work W done on T + V by the end, when the energy ledger ran.
    pub work_final: Option<f64>,
    /// max over the run of |E - W - E0| / E_scale, when the energy ledger ran: the error of
    /// the conserved quantity E - W.
    pub energy_balance_error_max: Option<f64>,
    pub constraint_error_max: f64,
    pub constraint_error_final: f64,
    /// The implicit form: max over the run and at the end of max_i |C_i| / |grad C_i|, how
    /// far the state is off the constraints in length units (what |C| alone cannot say when
    /// C is not a distance). `None` for the parametric form, which cannot leave its curve.
    pub constraint_distance_max: Option<f64>,
    pub constraint_distance_final: Option<f64>,
    /// The scene's length scale: the largest initial coordinate magnitude (1 when all are
    /// 0), to read the distance against.
    pub length_scale: f64,
    /// Final particle positions and velocities (n_coords each).
    pub x: Vec<f64>,
    pub xdot: Vec<f64>,
    /// Final formulation coordinates and rates.
    pub q: Vec<f64>,
    pub qdot: Vec<f64>,
    /// Adaptive runs only (dopri5): integrator steps accepted and rejected.
    pub accepted_steps: Option<u64>,
    pub rejected_steps: Option<u64>,
    /// Whether positions and velocities were projected onto the constraints after every step.
    pub projected: bool,
    /// The most Newton iterations any one solve needed: the integrator's own (a step, a
    /// substep or a rattle4 stage) and the projection's; `None` when neither ran.
    pub newton_iterations_max: Option<usize>,
    /// The same solves' iterations over every step
    /// ([`super::Simulation::newton_iterations_total`]); `None` when neither ran.
    pub newton_iterations: Option<u64>,
    /// Substeps per step of dt as configured (1: none).
    pub substeps: u32,
    /// The most substeps any step took, those RATTLE's stability asked for and retries
    /// included.
    pub substeps_max: u32,
    /// Steps retried with more substeps because an iteration did not converge.
    pub retried_steps: u64,
    /// The stop condition watched (see [`super::Event`]), as written: the terminal event
    /// that fired, else the first terminal event.
    pub stop_when: Option<String>,
    /// The time it fired, when it did: the run ended there (`t_final`).
    pub stop_time: Option<f64>,
    /// With unilateral constraints: how often they detached, landed and bounced, and the
    /// kinetic energy the impacts took (`None` without unilateral constraints).
    pub contacts: Option<super::ContactCounts>,
    /// Every watched event with the times it crossed, in the order they were set (empty when
    /// none).
    pub events: Vec<EventRecord>,
}

/// A watched event and the times it crossed zero in its direction during a run.
#[derive(Clone, Debug, PartialEq)]
pub struct EventRecord {
    /// The expression as written.
    pub when: String,
    pub direction: super::Direction,
    pub terminal: bool,
    /// The crossing times, in order.
    pub times: Vec<f64>,
}

impl RunStats {
    /// The largest relative error of what the system conserves: of E - W when something does
    /// work on it (the energy ledger ran), else of T + V.
    pub fn conserved_energy_error_max(&self) -> f64 {
        match (self.energy_conserved, self.energy_balance_error_max) {
            (false, Some(balance)) => balance,
            _ => self.energy_rel_error_max,
        }
    }

    /// Integrator steps per second of wall time (accepted steps for adaptive integrators).
    pub fn steps_per_second(&self) -> f64 {
        if self.wall_seconds > 0.0 {
            self.steps as f64 / self.wall_seconds
        } else {
            0.0
        }
    }
}

/// A diverged quantity's value: a coordinate exactly, a ratio of energies to 7 digits.
fn shown(quantity: &Quantity, value: f64) -> String {
    match quantity {
        Quantity::EnergyChange if value.is_finite() => crate::significant(value, 7),
        _ => crate::readable(value),
    }
}

/// The limit a diverged quantity passed, in words.
fn beyond(quantity: &Quantity, limit: Option<f64>) -> String {
    match (quantity, limit) {
        (_, None) => String::new(),
        (Quantity::EnergyChange, Some(l)) => format!(
            ", beyond {} (T + V is conserved, and has changed by more than 10^6 times its scale at the start: the integration is unstable at this dt; reduce dt)",
            crate::readable(l)
        ),
        (_, Some(l)) => format!(
            ", beyond {} (10^12 times the reach of the initial state, gravity and the initial energy by then)",
            crate::readable(l)
        ),
    }
}

/// Why a simulation or a run stopped.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Step(StepError),
    #[error("diverged at t = {} (step {step}): {quantity} is {}{}", crate::readable(*t), shown(quantity, *value), beyond(quantity, *limit))]
    Diverged {
        t: f64,
        step: u64,
        quantity: Quantity,
        value: f64,
        /// The limit a finite value passed.
        limit: Option<f64>,
    },
    #[error("cannot advance to t = {} from t = {}: time only moves forward, to a finite time", crate::readable(*requested), crate::readable(*now))]
    TimeBehind { requested: f64, now: f64 },
    /// The stop condition (`stop_when`) or an event is not a number (NaN), or is infinite
    /// (`infinite`), at time `t` of the integrator's path (a step end, a sample inside a
    /// step, or a time its crossing was looked for): it can neither cross zero nor stay
    /// below it. `values` are the quantities it reads there; the run stands at `stopped`,
    /// the start of that step, its last good state.
    #[error("{} `{source_text}` {} at t = {}{}; the run stopped at the last good state, t = {}", if *stop_when { "stop_when" } else { "the event" }, if *infinite { "is infinite" } else { "is not a number" }, crate::readable(*t), event_values(values), crate::readable(*stopped))]
    EventNotANumber {
        source_text: String,
        stop_when: bool,
        t: f64,
        infinite: bool,
        values: Vec<(String, f64)>,
        stopped: f64,
    },
    /// The stop condition or an event changes sign at time `t` by a jump that grows as it
    /// is looked at closer: from `before` to `after` across the located instant, each more
    /// than 1000 times larger in size than at the ends of the interval it was found in (a
    /// pole, like -1/x's at x = 0), where a crossing of zero would have shrunk towards it.
    /// The run stands at
    /// `stopped`, the start of that step, its last good state.
    #[error("{} `{source_text}` jumps over zero at t = {} (from {} to {}: a pole, not a crossing of zero); the run stopped at the last good state, t = {}", if *stop_when { "stop_when" } else { "the event" }, crate::readable(*t), crate::significant(*before, 4), crate::significant(*after, 4), crate::readable(*stopped))]
    EventJump {
        source_text: String,
        stop_when: bool,
        t: f64,
        before: f64,
        after: f64,
        stopped: f64,
    },
    /// The run's [`Progress::interrupted`] (or the callback of
    /// [`Simulation::advance_to_with`]) asked it to stop (e.g. Ctrl-C in Python); the state at
    /// `t` is good.
    #[error("interrupted at t = {} (step {step})", crate::readable(*t))]
    Interrupted { t: f64, step: u64 },
    /// The message includes the I/O error; it is not also the [`std::error::Error::source`],
    /// so that printing the chain shows it once.
    #[error("writing output failed: {0}")]
    Io(std::io::Error),
}

/// ` (with a.x = 1, a.vy = -2)`, or nothing for an expression of t alone.
fn event_values(values: &[(String, f64)]) -> String {
    if values.is_empty() {
        return String::new();
    }
    let list: Vec<String> = values
        .iter()
        .map(|(name, value)| format!("{name} = {}", crate::readable(*value)))
        .collect();
    format!(" (with {})", list.join(", "))
}

impl From<std::io::Error> for RunError {
    fn from(e: std::io::Error) -> Self {
        RunError::Io(e)
    }
}

/// A run that stopped early, with the figures up to the last good state.
#[derive(Debug, thiserror::Error)]
#[error("{error}")]
pub struct RunFailure {
    pub error: RunError,
    pub stats: Box<RunStats>,
}

/// Told how far a run has got, for progress bars. Called at most about 100 times per run
/// (at the first output interval past each hundredth of it, and at its end), from the step
/// loop, which allocates nothing: implementations should not allocate either.
pub trait Progress {
    /// `step` of `total` output intervals done.
    fn advance(&mut self, step: u64, total: u64);

    /// Asked after every output interval (after every run of at most 1024 intervals taken
    /// as express steps), and after every integrator step inside one (an adaptive
    /// integrator's output interval may take many): `true` ends the run there, at a
    /// good state, with [`RunError::Interrupted`] (what a front end does on Ctrl-C). It is
    /// called often, so an implementation should look at a clock or a flag only every so many
    /// calls.
    fn interrupted(&mut self) -> bool {
        false
    }
}

/// A [`Progress`] that ignores everything.
pub struct NoProgress;
impl Progress for NoProgress {
    fn advance(&mut self, _: u64, _: u64) {}
}

/// Run `simulation` from where it is over `options.steps` output intervals of dt, recording
/// into `sink`, or until its stop condition fires ([`Simulation::set_stop_when`]): then the
/// last sample recorded is the state at the crossing, and [`RunStats::stop_time`] its time.
/// The step loop allocates nothing.
pub fn run(
    simulation: &mut Simulation,
    options: RunOptions,
    sink: &mut dyn Sink,
) -> Result<RunStats, RunFailure> {
    run_with_progress(simulation, options, sink, &mut NoProgress)
}

/// The rest of a run that started at `t0` and has done `from` of `options.steps` output
/// intervals (another stepper took those: the ensemble lanes), recording nothing: the loop
/// of [`run`] from there, with the same output times t0 + k dt.
pub(crate) fn run_rest(
    simulation: &mut Simulation,
    t0: f64,
    from: u64,
    options: RunOptions,
) -> Result<RunStats, RunFailure> {
    let start = Instant::now();
    let dt = simulation.config().dt;
    simulation.set_stop_time(Some(options.output_time(t0, options.steps, dt)));
    let mut failure = None;
    let mut interval = from;
    while interval < options.steps {
        let next = interval + 1;
        if let Err(e) = simulation.advance_to(options.output_time(t0, next, dt)) {
            failure = Some(e);
            break;
        }
        interval = next;
        if simulation.stopped_at_event() {
            break;
        }
    }
    simulation.set_stop_time(None);
    let stats = simulation.stats(start.elapsed().as_secs_f64());
    match failure {
        Some(error) => Err(RunFailure {
            error,
            stats: Box::new(stats),
        }),
        None => Ok(stats),
    }
}

/// A run's result from its failure, if any, and the sink's `finish` (whose error fails a
/// run that went well).
fn outcome(
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

/// Run `simulation` from where it is to each of `times` in turn and record the state there,
/// exactly at that time (scipy's `t_eval`): a fixed-step integrator keeps its grid of steps
/// t0 + k dt and lands on a time between two of them by one shorter step, from which the
/// next step returns to the grid; an adaptive one takes its own steps and reads the state
/// from its dense output ([`Simulation::advance_to`]). `times` must not decrease and must not
/// lie before the current time ([`RunError::TimeBehind`] otherwise; nothing is recorded for
/// that time). The run ends after the last time, or where the stop condition fires: only
/// the times before it are recorded ([`RunStats::stop_time`] says when). On failure the
/// simulation holds the last good state, which is not recorded (the rows stay at `times`).
pub fn run_at_times(
    simulation: &mut Simulation,
    times: &[f64],
    sink: &mut dyn Sink,
    progress: &mut dyn Progress,
) -> Result<RunStats, RunFailure> {
    let start = Instant::now();
    let end = times.iter().copied().fold(simulation.t(), f64::max);
    simulation.set_stop_time(Some(end));
    let mut failure = None;
    let total = times.len() as u64;
    for (k, &t) in times.iter().enumerate() {
        if let Err(e) = simulation.advance_to_with(t, &mut || progress.interrupted()) {
            failure = Some(e);
            break;
        }
        if simulation.stopped_at_event() {
            break;
        }
        if let Err(e) = sink.record(&simulation.sample(k as u64)) {
            failure = Some(RunError::Io(e));
            break;
        }
        progress.advance(k as u64 + 1, total);
        if progress.interrupted() && k + 1 < times.len() {
            failure = Some(RunError::Interrupted {
                t: simulation.t(),
                step: k as u64,
            });
            break;
        }
    }
    simulation.set_stop_time(None);
    let stats = simulation.stats(start.elapsed().as_secs_f64());
    outcome(failure, sink.finish(), stats)
}

/// [`run`], telling `progress` how far it has got (see [`Progress`]).
///
/// Output time k is t0 + k dt, computed from k so that it does not accumulate rounding (the
/// last one t0 + duration when [`RunOptions::duration`] is set); a fixed-step integrator
/// takes one step per interval, an adaptive one its own steps with the samples from its dense
/// output, the last step landing on the end. On failure the
/// simulation holds the last good state, which the sink has received as well.
pub fn run_with_progress(
    simulation: &mut Simulation,
    options: RunOptions,
    sink: &mut dyn Sink,
    progress: &mut dyn Progress,
) -> Result<RunStats, RunFailure> {
    let start = Instant::now();
    let t0 = simulation.t();
    let dt = simulation.config().dt;
    // A sink that discards its samples needs no row between the first and the last.
    let every = if sink.discards() {
        options.steps.max(1)
    } else {
        options.every.max(1)
    };
    let progress_every = (options.steps / 100).max(1);
    let mut reported = 0;
    simulation.set_stop_time(Some(options.output_time(t0, options.steps, dt)));
    let mut failure = None;
    let mut recorded_t = t0;
    if let Err(e) = sink.record(&simulation.sample(0)) {
        failure = Some(RunError::Io(e));
    }
    let mut interval = 0;
    // Plain steps between the intervals that record, report or end, as express steps where
    // the run allows (the same bits and figures, see `express.rs`).
    let mut express = simulation
        .express
        .then(|| Express::new(simulation))
        .flatten();
    let mut cooldown = 0;
    while failure.is_none() && interval < options.steps {
        if let Some(express) = express.as_mut().filter(|_| cooldown == 0) {
            // Progress is reported where an express run ends, not by ending one.
            let boundary = ((interval / every + 1) * every)
                .min(options.steps)
                .min(interval + EXPRESS_CHUNK);
            let reached = simulation.express(express, t0, interval, boundary, &options);
            if reached < boundary {
                // The next interval needs the simulation's own path.
                cooldown = EXPRESS_COOLDOWN;
                if reached == interval {
                    continue;
                }
            }
            interval = reached;
        } else {
            let next = interval + 1;
            let target = options.output_time(t0, next, dt);
            if let Err(e) = simulation.advance_to_with(target, &mut || progress.interrupted()) {
                failure = Some(e);
                break;
            }
            interval = next;
            cooldown = cooldown.saturating_sub(1);
        }
        if interval / progress_every > reported / progress_every || interval == options.steps {
            progress.advance(interval, options.steps);
            reported = interval;
        }
        if simulation.stopped_at_event() {
            recorded_t = simulation.t();
            if let Err(e) = sink.record(&simulation.sample(interval)) {
                failure = Some(RunError::Io(e));
            }
            break;
        }
        if interval % every == 0 || interval == options.steps {
            recorded_t = simulation.t();
            if let Err(e) = sink.record(&simulation.sample(interval)) {
                failure = Some(RunError::Io(e));
            }
        }
        if failure.is_none() && interval < options.steps && progress.interrupted() {
            failure = Some(RunError::Interrupted {
                t: simulation.t(),
                step: interval,
            });
        }
    }
    if failure.is_some()
        && !matches!(failure, Some(RunError::Io(_)))
        && simulation.t() != recorded_t
    {
        // The last good state: make sure the sink has it. Best effort: the run has already
        // failed, and that error is the one to report.
        let _ = sink.record(&simulation.sample(interval));
    }
    simulation.set_stop_time(None);
    let stats = simulation.stats(start.elapsed().as_secs_f64());
    outcome(failure, sink.finish(), stats)
}
