//! The simulation core: [`Simulation`] owns a formulation, an integrator (fixed-step or
//! adaptive, behind one interface), the state, the monitors and the run statistics. Every
//! front end drives it: the CLI's `run` and `compare` through [`run`], the viewer's panels,
//! and anything that steps a system.
//!
//! ```
//! use std::sync::Arc;
//! use bead::formulation::Method;
//! use bead::integrate::IntegratorKind;
//! use bead::model::SystemBuilder;
//! use bead::simulate::{Simulation, SimulationConfig};
//!
//! // A pendulum: a bead on a circle of radius 1, released at 90 degrees.
//! let mut b = SystemBuilder::new(&[0.0, 9.81]);
//! b.particle("bead", 1.0, &[1.0, 0.0], &[0.0, 0.0])?;
//! b.constraint_expr("bead.x^2 + bead.y^2 - 1")?;
//! let system = Arc::new(b.build()?);
//! let config = SimulationConfig {
//!     method: Method::Implicit,
//!     integrator: IntegratorKind::Rattle,
//!     dt: 1e-3,
//!     ..Default::default()
//! };
//! let mut sim = Simulation::new(system, config)?;
//! sim.advance_to(0.5)?;
//! assert_eq!(sim.t(), 0.5);
//! assert!(sim.constraint_error() < 1e-9);
//! assert!(sim.energy_error() < 1e-4); // relative to the energy scale, see `energy_scale`
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # What it watches
//!
//! After every step a simulation observes the new state and rejects it (restoring the last
//! good state and returning the error) when
//!
//! - a value is not finite, or a particle is beyond 10^12 times the run's reach (the length
//!   and speed the initial state, gravity and the initial energy can reach by then):
//!   [`RunError::Diverged`], naming the quantity;
//! - a constraint's gradient (implicit form) or a column dx/dq of the map (parametric form)
//!   vanishes, reverses within the step, or is about to vanish: a cusp or a self-crossing of
//!   the curve, where the motion cannot be continued on it
//!   ([`crate::formulation::StepError::SingularPoint`]; see `monitor.rs` for the tests).
//!
//! # The energy ledger
//!
//! T + V is conserved only when nothing does work on the system. Drag, forces applied from
//! outside (the viewer's drag spring), driven constraints (C depends on t) and moving maps
//! (x depends on t) do work W, with dW/dt = P (see [`Formulation::power`]). A simulation of
//! such a system integrates W as one more coordinate with the integrator's own method, so
//! that it converges at the same order as the state, and E - W is then the conserved
//! quantity: [`Simulation::energy_balance_error`] measures the integrator's error where the
//! plain energy error would measure the driver's work. Relative errors divide by
//! [`Simulation::energy_scale`], E_scale = max(|E0|, T0 + |V0|, T0 + M |g| L), which does not
//! vanish when a scene starts at the potential's zero.

mod config;
mod contact;
mod event;
mod express;
mod lane_monitor;
pub(crate) mod lanes;
mod ledger;
mod monitor;
mod restart;
mod run;
mod state;
mod vector;
mod watching;

use std::sync::Arc;

pub use crate::readable;
pub use config::{ConfigError, Requirement, SetupError, SimulationConfig};
pub use contact::{ContactCounts, ContactSwitch, SwitchKind, MAX_SWITCHES_PER_STEP};
pub use event::{Crossing, Direction, Event, EventError, EventSpec};
pub use monitor::Quantity;
pub(crate) use run::run_rest;
pub use run::{
    run, run_at_times, run_with_progress, EventRecord, NoProgress, NullSink, Progress, RunError,
    RunFailure, RunOptions, RunStats, Sample, Sink,
};
pub(crate) use state::{place_start, solve_holding, Current};
pub use state::{ConstraintForceProbe, ConstraintForces, PlacedState, SetStateError, StateRequest};

use crate::formulation::{
    formulate, ConstraintScales, Formulation, Method, Nonconservation, SecondOrderSystem,
    SingularKind, State, StepError,
};
use crate::integrate::{Dopri5, Integrator, IntegratorKind};
use crate::model::{Force, ModelError, System};
use event::Watch;
use ledger::{LedgerScratch, WithWork};
use monitor::{Monitor, Rejection};

/// The relative position tolerance of RATTLE and the projections when a simulation scales
/// its tolerances ([`SimulationConfig::scaled_constraint_tolerance`]): each constraint row
/// is held to 1e-12 of its own scale, a rod to a stretch of 1e-12, plus the rounding
/// allowance of [`ConstraintScales`].
pub const RELATIVE_CONSTRAINT_TOLERANCE: f64 = 1e-12;

/// An external force's handle (see [`Simulation::add_force`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ForceId(u64);

enum Stepper {
    Fixed(Box<dyn Integrator>),
    Adaptive(Box<Dopri5>),
}

impl Stepper {
    fn new(config: &SimulationConfig, n: usize) -> Stepper {
        if config.integrator.is_adaptive() {
            Stepper::Adaptive(Box::new(Dopri5::new(n, &config.settings)))
        } else {
            Stepper::Fixed(config.integrator.build_with(n, &config.settings))
        }
    }
}

/// One simulated system: a formulation advanced by an integrator, with its monitors.
///
/// Cheap to create from a shared `Arc<System>`, `Send`, and without global state, so that many
/// can run side by side. After any error the simulation holds the last good state, and it can
/// go on (e.g. with a smaller step after [`Simulation::reset`]).
pub struct Simulation {
    config: SimulationConfig,
    formulation: Box<dyn Formulation + Send>,
    stepper: Stepper,
    /// The integrator's state: q, qdot (n each), then the work coordinate when the ledger
    /// runs (its "velocity" is W)
    state: State,
    /// The state before the step in progress, restored when the step fails
    previous: State,
    /// Adaptive integrators: the state at the last requested time, behind `state` (no
    /// coordinates with a fixed-step integrator, which never falls behind: see
    /// [`Simulation::output_buffer`])
    output: State,
    output_behind: bool,
    /// The formulation's coordinate count n
    n: usize,
    ledger: Option<LedgerScratch>,
    monitor: Monitor,
    /// Whether forces from outside have acted since the start (they make T + V not conserved)
    had_external: bool,
    /// Why T + V is not conserved (kept up to date as external forces come and go)
    nonconservation: Vec<Nonconservation>,
    external_ids: Vec<ForceId>,
    next_force_id: u64,
    stop_time: Option<f64>,
    /// Fixed-step integrators step on the grid grid_origin + k dt
    grid_origin: f64,
    grid_steps: u64,
    /// Integrator steps taken (accepted ones for adaptive integrators)
    steps: u64,
    projection_iterations_max: Option<usize>,
    /// `--project`'s Newton iterations of every step so far
    projection_iterations_total: u64,
    /// The most substeps any step of dt took (configured ones, those stability asked for,
    /// retries)
    substeps_max: u32,
    /// Steps retried with more substeps because an iteration did not converge
    retried_steps: u64,
    /// Newton iterations of integrators this run replaced (the ledger's start builds one)
    iterations_replaced: u64,
    /// The substeps the next fixed steps start from after retries
    sticky: StickySubsteps,
    /// The substeps the last fixed step took (an event re-integrates part of it with them)
    last_substeps: u32,
    /// The events being watched (see `watching.rs`)
    watches: Vec<Watch>,
    /// g of each event at the previous and the current sample time while a step is scanned
    g_before: Vec<f64>,
    g_now: Vec<f64>,
    /// The state at the upper end of an event's bracket while it is located, the step's end
    /// and the current sample while a fixed step is scanned, and the earliest terminal
    /// crossing of a sample interval (sized when the events are set, so that locating
    /// allocates only the crossing's record)
    event_state: State,
    step_end: State,
    sample_state: State,
    stop_state: State,
    /// The crossings located so far, in time order
    crossings: Vec<event::Crossing>,
    /// Adaptive integrators: the time and the index of a terminal event located in the last
    /// step, not yet reached by the output
    pending_event: Option<(f64, usize)>,
    /// Adaptive integrators: the time inside the last step at which a terminal event fired,
    /// from which the rest of that step is still to be searched
    resume_event: Option<f64>,
    /// The time a terminal event last fired, and which
    event_time: Option<f64>,
    fired_event: Option<usize>,
    /// Whether the last `step` or `advance_to` ended at an event
    stopped_at_event: bool,
    /// Whether a step's end primes the integrator's first stage for the next step and the
    /// monitors read that evaluation (see [`Simulation::observe_step_end`]); off only in the
    /// test that shows it changes no number
    prime_first_stage: bool,
    /// Whether `run` may take plain steps as express steps (see `express.rs`), and check
    /// them in batches; off only to compare the paths
    express: bool,
    express_batches: bool,
    /// The switching of unilateral constraints, when the system has any (`contact.rs`).
    contact: Option<contact::ContactState>,
    /// The switches of unilateral constraints so far, in time order.
    contact_switches: Vec<ContactSwitch>,
    /// The same, counted (what frames and summaries read, in O(1)).
    contact_counts: ContactCounts,
}

/// Steps without a retry after which a step tries fewer substeps than its predecessors
/// needed (a probe).
const CALM_STEPS: u32 = 16;

/// The most calm steps between probes (about 2 s at dt = 1/120).
const CALM_STEPS_MAX: u32 = 256;

/// What recent retries needed, for the steps after them: a whipping chain needs more
/// substeps for many steps in a row, and each attempt that fails costs several Newton
/// iterations of the whole system.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct StickySubsteps {
    /// The substeps the next step starts from (at least the configured ones): what the
    /// last retried step needed, one place back in the retries' sequence after
    /// `calm_needed` steps without a retry (a probe). 0: none.
    substeps: u32,
    /// Steps without a retry since the last retry or probe
    calm_steps: u32,
    /// Calm steps before the next probe: `CALM_STEPS`, doubled (up to `CALM_STEPS_MAX`)
    /// each time a probe fails at once, as they do all through a long hard stretch (each
    /// such failure is an attempt wasted), and back to `CALM_STEPS` when one holds
    calm_needed: u32,
    /// Whether the step under way is a probe
    probing: bool,
}

impl Default for StickySubsteps {
    fn default() -> Self {
        StickySubsteps {
            substeps: 0,
            calm_steps: 0,
            calm_needed: CALM_STEPS,
            probing: false,
        }
    }
}

impl StickySubsteps {
    /// After a step that took `substeps` (`retried`: after failed attempts with fewer),
    /// `configured` the run's own.
    fn after_step(&mut self, substeps: u32, retried: bool, configured: u32) {
        let probed = std::mem::take(&mut self.probing);
        if retried {
            self.substeps = substeps;
            self.calm_steps = 0;
            if probed {
                self.calm_needed = (2 * self.calm_needed).min(CALM_STEPS_MAX);
            }
            return;
        }
        if probed {
            self.calm_needed = CALM_STEPS;
        }
        if self.substeps > configured {
            self.calm_steps += 1;
            if self.calm_steps >= self.calm_needed {
                self.substeps = fewer_substeps(self.substeps);
                self.calm_steps = 0;
                self.probing = true;
            }
        }
    }
}

/// An event's time is located to this fraction of dt (see [`Event`]).
pub const EVENT_TOLERANCE: f64 = 1e-10;

/// Interior times per step at which a stop condition is sampled by default
/// ([`SimulationConfig::event_samples`]): spaced dt / 5, so a crossing and its return
/// further apart than that are found within one step.
pub const DEFAULT_EVENT_SAMPLES: u32 = 4;

/// The most interior samples per step a stop condition may ask for.
pub const MAX_EVENT_SAMPLES: u32 = 1024;

impl Simulation {
    /// A simulation of `system` as `config` says, at the system's initial state. Fails when
    /// the combination is illegal ([`SimulationConfig::check`]), the system is
    /// over-constrained, or the initial state cannot be simulated (a constraint or its
    /// gradient not finite or zero there, dependent constraints, a singular mass matrix).
    pub fn new(system: Arc<System>, config: SimulationConfig) -> Result<Simulation, SetupError> {
        config.check(&system)?;
        check_rows(&system, config.method)?;
        let formulation =
            formulate(system, config.method, config.feedback).map_err(ConfigError::from)?;
        Simulation::start(formulation, config)
    }

    /// A simulation of an already built formulation, whose method replaces `config`'s;
    /// `config.feedback` should be the formulation's own (it is what [`Simulation::config`]
    /// reports). The legality check and the checks of the initial state of
    /// [`Simulation::new`] apply; external forces the formulation already has are kept, with
    /// ids in their order.
    pub fn with_formulation(
        formulation: Box<dyn Formulation + Send>,
        config: SimulationConfig,
    ) -> Result<Simulation, SetupError> {
        let config = SimulationConfig {
            method: formulation.method(),
            ..config
        };
        config.check(formulation.system())?;
        check_rows(formulation.system(), config.method)?;
        Simulation::start(formulation, config)
    }

    /// The simulation of a checked configuration.
    fn start(
        mut formulation: Box<dyn Formulation + Send>,
        config: SimulationConfig,
    ) -> Result<Simulation, SetupError> {
        let mut config = config;
        if config.scaled_constraint_tolerance {
            config.settings.constraint_tolerance = RELATIVE_CONSTRAINT_TOLERANCE;
            let scales = ConstraintScales::of(formulation.system());
            formulation.set_constraint_scales(Some(scales));
        }
        if !formulation.system().unilateral().is_empty() && formulation.contact().is_none() {
            return Err(ConfigError::UnilateralWithoutContact.into());
        }
        let state = formulation.initial_state();
        let n = state.q.len();
        contact::initial_mode(&mut *formulation, &state, n).map_err(SetupError::Initial)?;
        let contact = formulation
            .contact_mut()
            .map(|c| contact::ContactState::new(c.unilateral().len()));
        let monitor = Monitor::new(&mut *formulation, state.t, &state.q, &state.qdot);
        let mut simulation = Simulation {
            // Built once the start is checked (below): the check's scratch and the
            // integrator's are not held at once.
            stepper: Stepper::new(&config, 0),
            previous: state.clone(),
            output: Self::output_buffer(&config, &state),
            output_behind: false,
            grid_origin: state.t,
            state,
            n,
            ledger: None,
            monitor,
            had_external: false,
            nonconservation: Vec::new(),
            external_ids: Vec::new(),
            next_force_id: 0,
            stop_time: None,
            grid_steps: 0,
            steps: 0,
            projection_iterations_max: None,
            projection_iterations_total: 0,
            substeps_max: 0,
            retried_steps: 0,
            iterations_replaced: 0,
            sticky: StickySubsteps::default(),
            last_substeps: 1,
            watches: Vec::new(),
            g_before: Vec::new(),
            g_now: Vec::new(),
            event_state: State::default(),
            step_end: State::default(),
            sample_state: State::default(),
            stop_state: State::default(),
            crossings: Vec::new(),
            pending_event: None,
            resume_event: None,
            event_time: None,
            fired_event: None,
            stopped_at_event: false,
            prime_first_stage: true,
            express: true,
            express_batches: true,
            contact,
            contact_switches: Vec::new(),
            contact_counts: ContactCounts::default(),
            config,
            formulation,
        };
        let existing = simulation.formulation.external_forces().len() as u64;
        simulation.external_ids = (0..existing).map(ForceId).collect();
        simulation.next_force_id = existing;
        simulation.had_external = existing > 0;
        simulation.refresh_nonconservation();
        let track = config
            .track_work
            .unwrap_or(!simulation.nonconservation.is_empty());
        if track {
            // The integrator (for n + 1 coordinates) is built below, after the check.
            simulation.add_work_coordinate();
        }
        simulation.check_initial_state()?;
        // The check's evaluation kept C, Cdot, J and the bias for every row: the integrator
        // sizes them again if it evaluates the full acceleration.
        simulation.formulation.release_evaluation_scratch();
        simulation.stepper = Stepper::new(&simulation.config, simulation.state.q.len());
        Ok(simulation)
    }

    /// The checks of the initial state (see [`Simulation::new`]).
    fn check_initial_state(&mut self) -> Result<(), SetupError> {
        let Simulation {
            formulation,
            ledger,
            state,
            monitor,
            n,
            ..
        } = self;
        check_start(formulation, ledger, *n, state, monitor).map_err(SetupError::Initial)
    }

    /// The configuration (with the constraint tolerance it resolved).
    pub fn config(&self) -> &SimulationConfig {
        &self.config
    }
    /// The formulation it advances.
    pub fn formulation(&self) -> &dyn Formulation {
        &*self.formulation
    }
    /// The system it simulates.
    pub fn system(&self) -> &System {
        self.formulation.system()
    }
    /// Which formulation.
    pub fn method(&self) -> Method {
        self.formulation.method()
    }
    /// Which integrator.
    pub fn integrator(&self) -> IntegratorKind {
        self.config.integrator
    }

    /// The Newton iterations that solved onto the constraints in every step since the run
    /// started (or its state was set; as [`Simulation::steps`]): those of the integrators
    /// that do (rattle, rattle4, fast-projection; see [`Integrator::iterations_total`]) and
    /// of `--project` after every substep, the same solves whose most in one solve is
    /// [`RunStats::newton_iterations_max`]. Every substep's, and the iterations spent where
    /// the step was taken again (a retried attempt's converged substeps, an abandoned warm
    /// start, an event's or an impact's partial steps). `None` when no step has solved onto
    /// the constraints with `--project` and the integrator is not one that solves.
    pub fn newton_iterations_total(&self) -> Option<u64> {
        let integrator = match &self.stepper {
            Stepper::Fixed(integrator) => integrator
                .iterations_total()
                .map(|total| total + self.iterations_replaced),
            Stepper::Adaptive(_) => None,
        };
        // As `projection_iterations_max`: none before the first projection.
        let projection = self
            .projection_iterations_max
            .map(|_| self.projection_iterations_total);
        match (integrator, projection) {
            (Some(a), Some(b)) => Some(a + b),
            (a, b) => a.or(b),
        }
    }

    /// Evaluations of the acceleration since the formulation was built (see
    /// [`Formulation::evaluations`]): the work of a run, in the unit of convergence studies.
    pub fn evaluations(&self) -> u64 {
        self.formulation.evaluations()
    }

    /// The buffer of `output` for a run starting at `state`: a copy for an adaptive
    /// integrator (its dense output lands there); for a fixed-step one, which never falls
    /// behind, no coordinates (a large system's state is not kept three times).
    fn output_buffer(config: &SimulationConfig, state: &State) -> State {
        if config.integrator.is_adaptive() {
            state.clone()
        } else {
            State {
                t: state.t,
                q: Vec::new(),
                qdot: Vec::new(),
            }
        }
    }

    /// The observable state: the integrator's, or for adaptive integrators the dense output at
    /// the last requested time.
    fn observed(&self) -> &State {
        if self.output_behind {
            &self.output
        } else {
            &self.state
        }
    }
    /// Time of the current state.
    pub fn t(&self) -> f64 {
        self.observed().t
    }
    /// The formulation's coordinates q (particle coordinates for the implicit form).
    pub fn q(&self) -> &[f64] {
        &self.observed().q[..self.n]
    }
    /// Their rates qdot.
    pub fn qdot(&self) -> &[f64] {
        &self.observed().qdot[..self.n]
    }
    /// Particle positions (n_coords: particle p, axis a at p * dim + a).
    pub fn positions(&self) -> &[f64] {
        &self.monitor.observation.x
    }
    /// Particle velocities (n_coords).
    pub fn velocities(&self) -> &[f64] {
        &self.monitor.observation.xdot
    }
    /// The energy T + V of the current state.
    pub fn energy(&self) -> f64 {
        self.monitor.energy
    }
    /// T + V at the start.
    pub fn energy_initial(&self) -> f64 {
        self.monitor.energy_initial
    }
    /// E_scale = max(|E0|, T0 + |V0|, T0 + M |g| L): the denominator of the relative energy
    /// errors (M the total mass, L the largest initial coordinate magnitude; 1 when all of these
    /// vanish).
    pub fn energy_scale(&self) -> f64 {
        self.monitor.energy_scale
    }
    /// |E - E0| / E_scale now.
    pub fn energy_error(&self) -> f64 {
        (self.monitor.energy - self.monitor.energy_initial).abs() / self.monitor.energy_scale
    }
    /// The work W done on T + V since the start (0 when the ledger does not run).
    pub fn work(&self) -> f64 {
        self.monitor.work
    }
    /// |E - W - E0| / E_scale now: the error of the conserved quantity E - W.
    pub fn energy_balance_error(&self) -> f64 {
        (self.monitor.energy - self.monitor.work - self.monitor.energy_initial).abs()
            / self.monitor.energy_scale
    }
    /// Whether T + V is conserved: nothing does work on the system (no drag, no driven
    /// constraint or moving map, no external forces since the start).
    pub fn energy_conserved(&self) -> bool {
        self.nonconservation.is_empty()
    }
    /// What does work on the system, when T + V is not conserved.
    pub fn nonconservation(&self) -> &[Nonconservation] {
        &self.nonconservation
    }
    /// Recompute why T + V is not conserved (after external forces came or went).
    fn refresh_nonconservation(&mut self) {
        let mut reasons = self.formulation.nonconservation();
        if self.had_external && !reasons.contains(&Nonconservation::External) {
            reasons.push(Nonconservation::External);
        }
        self.nonconservation = reasons;
        self.watch_energy();
    }
    /// Watch the energy for a blow-up where T + V is conserved: |E - E0| beyond 10^6 times
    /// the energy scale ([`monitor::ENERGY_BLOW_UP`]). Not where something does work: a
    /// driven constraint or a force can add far more than the start's scale legitimately,
    /// and the ledger's balance |E - W - E0| errs in proportion to |E| and |W|, not to it.
    fn watch_energy(&mut self) {
        let limit = monitor::ENERGY_BLOW_UP * self.monitor.energy_scale;
        self.monitor.energy_watch = self
            .nonconservation
            .is_empty()
            .then_some(monitor::EnergyWatch { limit });
    }
    /// Whether the work W is being tracked.
    pub fn tracks_work(&self) -> bool {
        self.ledger.is_some()
    }
    /// max_i |C_i| now, over the system's implicit constraints (for both forms).
    pub fn constraint_error(&self) -> f64 {
        self.monitor.constraint_error
    }
    /// Integrator steps taken (accepted steps for adaptive integrators).
    pub fn steps(&self) -> u64 {
        self.steps
    }
    /// The most substeps any step has taken so far: the configured count, or more where
    /// RATTLE's stability asked for them or a step was retried in smaller ones (as
    /// [`RunStats::substeps_max`], without building the
    /// statistics and their copy of the state).
    pub fn substeps_max(&self) -> u32 {
        self.substeps_max.max(self.config.substeps.max(1))
    }
    /// How many times the singular-point monitor searched for a point where a gradient
    /// vanishes after a step (a candidate raised by its first-order tests; see the module
    /// doc). Each search allocates; the step loop allocates nothing else.
    pub fn singular_point_searches(&self) -> u64 {
        self.monitor.searches
    }

    /// Adaptive integrators never step past `t` (the end of a run), so that the last step
    /// lands on it; output before it comes from the dense output. `None`: every
    /// [`Simulation::advance_to`] lands exactly on its target.
    pub fn set_stop_time(&mut self, t: Option<f64>) {
        self.stop_time = t;
    }

    /// One step: dt for fixed-step integrators; for adaptive ones one accepted step of their
    /// own size, never past the stop time (or t + dt when none is set).
    pub fn step(&mut self) -> Result<(), RunError> {
        let dt = self.config.dt;
        self.stopped_at_event = false;
        match self.stepper {
            Stepper::Fixed(_) => {
                let t_end = self.grid_origin + (self.grid_steps + 1) as f64 * dt;
                self.fixed_step(t_end)?;
                if !self.stopped_at_event {
                    self.grid_steps += 1;
                }
            }
            Stepper::Adaptive(_) => {
                let t = self.state.t;
                let horizon = match self.stop_time {
                    Some(stop) if stop > t => stop,
                    _ => t + dt,
                };
                self.resume_dense_scan()?;
                if self.pending_event.is_none() {
                    self.adaptive_step(horizon)?;
                }
                if let Some((te, k)) = self.pending_event.take() {
                    self.fire_adaptive(te, k);
                    return Ok(());
                }
            }
        }
        self.output_behind = false;
        Ok(())
    }

    /// Advance to exactly time `t` (not before the current time): fixed-step integrators take
    /// steps of dt on their grid and, when `t` is not on it, one shorter step to land on `t`
    /// (the grid then restarts there); adaptive integrators take their own steps (not past
    /// the stop time, or `t` when none is set) and, when the last one passed `t`, the state
    /// is the dense output at `t`.
    pub fn advance_to(&mut self, t: f64) -> Result<(), RunError> {
        self.advance_to_with(t, &mut || false)
    }

    /// [`Simulation::advance_to`], asking `interrupted` after every step short of `t`: when it
    /// returns true the simulation stops at that step's end, a good state from which it can go
    /// on, with [`RunError::Interrupted`] (what a front end does on Ctrl-C). Called after every
    /// step, so it should look at a clock or a flag only every so many calls.
    pub fn advance_to_with(
        &mut self,
        t: f64,
        interrupted: &mut dyn FnMut() -> bool,
    ) -> Result<(), RunError> {
        let now = self.t();
        if !t.is_finite() || t < now {
            return Err(RunError::TimeBehind { requested: t, now });
        }
        let dt = self.config.dt;
        self.stopped_at_event = false;
        match self.stepper {
            Stepper::Fixed(_) => {
                self.output_behind = false;
                let tolerance = 1e-9 * dt;
                loop {
                    let next = self.grid_origin + (self.grid_steps + 1) as f64 * dt;
                    if next > t + tolerance {
                        break;
                    }
                    let on_target = (next - t).abs() <= tolerance;
                    self.fixed_step(if on_target { t } else { next })?;
                    if self.stopped_at_event {
                        return Ok(());
                    }
                    self.grid_steps += 1;
                    if on_target {
                        return Ok(());
                    }
                    if interrupted() {
                        return Err(self.interrupted_error());
                    }
                }
                if self.state.t < t {
                    self.fixed_step(t)?;
                    if self.stopped_at_event {
                        return Ok(());
                    }
                    self.grid_origin = t;
                    self.grid_steps = 0;
                }
                Ok(())
            }
            Stepper::Adaptive(_) => {
                let horizon = match self.stop_time {
                    Some(stop) if stop >= t => stop,
                    _ => t,
                };
                self.resume_dense_scan()?;
                while self.state.t < t && self.pending_event.is_none() {
                    self.adaptive_step(horizon)?;
                    if self.state.t < t && self.pending_event.is_none() && interrupted() {
                        self.output_behind = false;
                        return Err(self.interrupted_error());
                    }
                }
                if let Some((te, k)) = self.pending_event {
                    if te <= t {
                        self.pending_event = None;
                        self.fire_adaptive(te, k);
                        return Ok(());
                    }
                }
                if self.state.t > t {
                    if let Stepper::Adaptive(dopri) = &self.stepper {
                        dopri.interpolate(t, &mut self.output.q, &mut self.output.qdot);
                    }
                    self.output.t = t;
                    self.output_behind = true;
                    let (q, qdot, work) = split(&self.output, self.n);
                    self.monitor
                        .observe(&mut *self.formulation, t, q, qdot, work);
                    self.monitor.accumulate();
                } else if self.output_behind {
                    // The last step already reached t (it landed on the stop time): the
                    // observation still describes the dense output of an earlier request
                    // and must describe the state at t again.
                    self.output_behind = false;
                    let (q, qdot, work) = split(&self.state, self.n);
                    self.monitor
                        .observe(&mut *self.formulation, self.state.t, q, qdot, work);
                }
                Ok(())
            }
        }
    }

    /// [`RunError::Interrupted`] at the current state.
    fn interrupted_error(&self) -> RunError {
        RunError::Interrupted {
            t: self.state.t,
            step: self.steps,
        }
    }

    /// One fixed step from the current state to `t_end`, then the projection and the checks
    /// (with unilateral constraints, the step ends at a switch and goes on from there:
    /// `contact.rs`).
    fn fixed_step(&mut self, t_end: f64) -> Result<(), RunError> {
        self.integrate_fixed(t_end)?;
        if self.contact.is_some() {
            return self.contact_step(t_end);
        }
        self.steps += 1;
        self.accept()
    }

    /// The integrator's step from the current state (saved as `previous`) to `t_end`, in
    /// substeps, retried with more when an iteration does not converge; not yet accepted.
    fn integrate_fixed(&mut self, t_end: f64) -> Result<(), RunError> {
        self.save();
        let configured = self.config.substeps.max(1);
        let span = t_end - self.state.t;
        // Start from what recent steps needed, so that a run of hard steps does not pay for
        // the same failed attempts again at every step, and from what stability needs.
        let stable = self.stable_substeps(span);
        let mut substeps = configured
            .max(self.sticky.substeps)
            .max(stable.unwrap_or(1));
        let mut retried = false;
        // Whether what stability needs was known for this step.
        let mut known = stable.is_some();
        loop {
            match self.substeps(t_end, substeps) {
                // A step taken before the integrator could tell what stability needs (the
                // first after a start or a reset: no tensions yet) is taken again if the
                // tensions it found ask for more substeps: a step at h omega > 2 would
                // excite an oscillation that a symplectic method never damps.
                Ok(()) if !known => {
                    known = true;
                    match self.stable_substeps(span) {
                        Some(needed) if needed > substeps => {
                            self.restore_state_only();
                            substeps = needed;
                        }
                        _ => break,
                    }
                }
                Ok(()) => break,
                // An iteration that did not converge (RATTLE's Newton solve, a projection, an
                // implicit kick or stage) may converge on shorter steps: retry this step in
                // more substeps, up to the limit.
                Err(e) if retryable(&e) && substeps < self.config.max_substeps => {
                    self.restore_state_only();
                    substeps = more_substeps(substeps, self.config.max_substeps);
                    retried = true;
                }
                Err(e) => return Err(self.fail(tried_in(e, substeps))),
            }
        }
        if retried {
            self.retried_steps += 1;
        }
        self.sticky.after_step(substeps, retried, configured);
        self.substeps_max = self.substeps_max.max(substeps);
        self.last_substeps = substeps;
        Ok(())
    }

    /// The fewest substeps of a step of length `span` at which the integrator stays
    /// stable, as far as it can tell from its last step ([`Integrator::stable_step`]:
    /// RATTLE on rods and pins), at most `max_substeps`; 1 when no more are allowed than
    /// configured, `None` when it cannot tell (no such bound, or no step yet).
    fn stable_substeps(&mut self, span: f64) -> Option<u32> {
        let Simulation {
            formulation,
            ledger,
            stepper,
            config,
            ..
        } = self;
        let Stepper::Fixed(integrator) = stepper else {
            return Some(1);
        };
        // No more substeps allowed than configured: nothing to ask.
        if config.max_substeps <= config.substeps {
            return Some(1);
        }
        let stable = with_system(formulation, ledger, |system| integrator.stable_step(system))?;
        // NaN (no stable step) compares false: one substep.
        let needed = (span / stable).ceil();
        Some(if needed > 1.0 {
            needed.min(config.max_substeps as f64) as u32
        } else {
            1
        })
    }

    /// The step from the current state to `t_end` as `count` steps of equal length, each
    /// followed by the projection when it is on; the last lands exactly on `t_end`.
    fn substeps(&mut self, t_end: f64, count: u32) -> Result<(), StepError> {
        let t0 = self.state.t;
        let h = (t_end - t0) / count as f64;
        let Simulation {
            formulation,
            ledger,
            state,
            stepper,
            config,
            projection_iterations_max,
            projection_iterations_total,
            n,
            ..
        } = self;
        let Stepper::Fixed(integrator) = stepper else {
            unreachable!("fixed_step is called for fixed-step integrators only");
        };
        let tracks_work = ledger.is_some();
        with_system(formulation, ledger, |system| {
            for k in 1..=count {
                integrator.step(system, state, h)?;
                // On the grid t0 + k h; the integrator's warm start goes along.
                let stepped = std::mem::replace(
                    &mut state.t,
                    if k == count { t_end } else { t0 + k as f64 * h },
                );
                if tracks_work {
                    // Impulses the integrator applied outside f (RATTLE's) did work too.
                    state.qdot[*n] += integrator.constraint_work();
                }
                integrator.continued(stepped, state, tracks_work);
                if config.project {
                    let iterations = project(system, state, config)?;
                    *projection_iterations_max =
                        Some(projection_iterations_max.unwrap_or(0).max(iterations));
                    *projection_iterations_total += iterations as u64;
                }
            }
            Ok(())
        })
    }

    /// One accepted adaptive step towards `horizon`, then the checks.
    fn adaptive_step(&mut self, horizon: f64) -> Result<(), RunError> {
        if self.contact.is_some() {
            // At most dt a step: a free flight is a polynomial dopri5 would cross in one
            // long step, bounces and all.
            self.adaptive_advance(horizon.min(self.state.t + self.config.dt))?;
            return self.adaptive_contact_step();
        }
        self.adaptive_advance(horizon)?;
        self.steps += 1;
        self.accept()
    }

    /// The adaptive integrator's next step from the current state (saved as `previous`)
    /// towards `horizon`; not yet accepted.
    fn adaptive_advance(&mut self, horizon: f64) -> Result<(), RunError> {
        self.save();
        let Simulation {
            formulation,
            ledger,
            state,
            stepper,
            ..
        } = self;
        let Stepper::Adaptive(dopri) = stepper else {
            unreachable!("adaptive_step is called for adaptive integrators only");
        };
        let result = with_system(formulation, ledger, |system| {
            dopri.advance(system, state, horizon)
        });
        if let Err(e) = result {
            return Err(self.fail(e));
        }
        Ok(())
    }

    /// Remember the state before a step.
    fn save(&mut self) {
        self.previous.t = self.state.t;
        self.previous.q.copy_from_slice(&self.state.q);
        self.previous.qdot.copy_from_slice(&self.state.qdot);
    }

    /// Back to the state before the step, without observing it (a retry follows).
    fn restore_state_only(&mut self) {
        self.state.t = self.previous.t;
        self.state.q.copy_from_slice(&self.previous.q);
        self.state.qdot.copy_from_slice(&self.previous.qdot);
    }

    /// Back to the state before the step, which becomes the observable one (also after an
    /// adaptive integrator's dense output was ahead of it) and is observed again, so that
    /// every accessor and the statistics describe the last good state.
    fn restore(&mut self) {
        self.state.t = self.previous.t;
        self.state.q.copy_from_slice(&self.previous.q);
        self.state.qdot.copy_from_slice(&self.previous.qdot);
        self.output_behind = false;
        let (q, qdot, work) = split(&self.state, self.n);
        self.monitor
            .observe(&mut *self.formulation, self.state.t, q, qdot, work);
    }

    /// A failed step: restore the last good state, and report the error, or the singular point
    /// next to which an iteration failed.
    fn fail(&mut self, error: StepError) -> RunError {
        self.restore();
        let iterative = matches!(
            error,
            StepError::ImplicitStageFailed { .. }
                | StepError::ProjectionFailed { .. }
                | StepError::StepSizeUnderflow { .. }
                | StepError::SingularConstraints { .. }
                | StepError::SingularMassMatrix { .. }
        );
        if iterative {
            let (q, _, _) = split(&self.state, self.n);
            let near = self
                .monitor
                .near_singular(&*self.formulation, self.state.t, q);
            if let Some((row, kind)) = near {
                return RunError::Step(StepError::SingularPoint {
                    t: self.state.t,
                    subject: self.formulation.gradient_subject(row),
                    position: self
                        .formulation
                        .gradient_position(row, &self.state.q[..self.n]),
                    kind,
                    cause: Some(error.to_string()),
                });
            }
        }
        RunError::Step(error)
    }

    /// The acceleration at the integrator's state (work coordinate included when the ledger
    /// runs). Allocates: for setup and failures only.
    fn current_acceleration(&mut self) -> Result<Vec<f64>, StepError> {
        let mut a = vec![0.0; self.state.q.len()];
        let Simulation {
            formulation,
            ledger,
            state,
            ..
        } = self;
        with_system(formulation, ledger, |system| {
            system.acceleration(state.t, &state.q, &state.qdot, &mut a)
        })?;
        Ok(a)
    }

    /// A divergence from the last good state (restored): when that state is next to a
    /// singular point (see [`Simulation::fail`]), the singular point with the divergence as
    /// its cause, so that the message says both; otherwise the divergence.
    fn explain_divergence(&mut self, divergence: RunError) -> RunError {
        let (q, _, _) = split(&self.state, self.n);
        let mut near = self
            .monitor
            .near_singular(&*self.formulation, self.state.t, q);
        if near.is_none() {
            // What one step moves from here: dt qdot + dt^2 a / 2.
            let n = self.n;
            let dt = self.config.dt;
            let a = self.current_acceleration().unwrap_or_default();
            let displacement: Vec<f64> = (0..n)
                .map(|k| {
                    let a = a.get(k).copied().filter(|a| a.is_finite()).unwrap_or(0.0);
                    dt * self.state.qdot[k] + 0.5 * dt * dt * a
                })
                .collect();
            let q = &self.state.q[..n];
            near = self
                .monitor
                .singular_within_reach(&*self.formulation, self.state.t, q, &displacement)
                .map(|row| (row, SingularKind::Ahead));
            if near.is_none() && self.steps <= 10 {
                // A start next to a singular point blows up within a few steps, and the
                // states it accepted on the way are already far out: look from the start,
                // as far as the run went.
                let start = &self.monitor.initial_q;
                let moved: Vec<f64> = q.iter().zip(start).map(|(a, b)| a - b).collect();
                near = self
                    .monitor
                    .singular_within_reach(&*self.formulation, self.state.t, start, &moved)
                    .map(|row| (row, SingularKind::Ahead));
            }
        }
        let q = &self.state.q[..self.n];
        match near {
            Some((row, kind)) => RunError::Step(StepError::SingularPoint {
                t: self.state.t,
                subject: self.formulation.gradient_subject(row),
                position: self.formulation.gradient_position(row, q),
                kind,
                cause: Some(divergence.to_string()),
            }),
            None => divergence,
        }
    }

    /// Observe the state a step produced and accept it, or restore the previous one and say
    /// why not.
    fn accept(&mut self) -> Result<(), RunError> {
        let n = self.n;
        let t = self.state.t;
        if let Some((quantity, value)) = non_finite_state(&*self.formulation, &self.state, n) {
            let step = self.steps;
            self.steps -= 1;
            self.restore();
            return Err(self.explain_divergence(RunError::Diverged {
                t,
                step,
                quantity,
                value,
                limit: None,
            }));
        }
        self.observe_step_end();
        let (q, _, _) = split(&self.state, n);
        match self.monitor.check_step(&*self.formulation, t, q) {
            Ok(()) => {
                if !self.watches.is_empty() {
                    return self.watch_step();
                }
                self.monitor.accumulate();
                Ok(())
            }
            Err(rejection) => {
                let step = self.steps;
                self.steps -= 1;
                self.restore();
                Err(match rejection {
                    Rejection::Diverged {
                        quantity,
                        value,
                        limit,
                    } => self.explain_divergence(RunError::Diverged {
                        t,
                        step,
                        quantity,
                        value,
                        limit,
                    }),
                    Rejection::Singular(e) | Rejection::TooLong(e) => RunError::Step(e),
                })
            }
        }
    }

    /// Observe the state a step ended at. An integrator whose first stage is the acceleration
    /// there (rk4) evaluates it now, for the next step from this state
    /// ([`Integrator::prime`]), and the monitors read the observation from that evaluation
    /// instead of evaluating the constraints or the map a second time.
    fn observe_step_end(&mut self) {
        let n = self.n;
        let Simulation {
            formulation,
            ledger,
            state,
            stepper,
            monitor,
            ..
        } = self;
        let (q, qdot, work) = split(state, n);
        if let (Stepper::Fixed(integrator), true) = (stepper, self.prime_first_stage) {
            let primed = with_system(formulation, ledger, |system| {
                integrator.prime(system, state)
            });
            match primed {
                Some(Ok(()))
                    if monitor.observe_accelerated(&mut **formulation, state.t, q, qdot, work) =>
                {
                    return;
                }
                // The next step fails there the same way; the monitors see the state first.
                Some(Err(_)) => integrator.unprime(),
                _ => {}
            }
        }
        monitor.observe(&mut **formulation, state.t, q, qdot, work);
    }

    /// Back to the initial state: monitors, statistics and the integrator's memory restart;
    /// external forces stay (and energy counts as not conserved only while there are any).
    pub fn reset(&mut self) {
        self.had_external = !self.external_ids.is_empty();
        self.refresh_nonconservation();
        let mut state = self.formulation.initial_state();
        if self.ledger.is_some() {
            state.q.push(0.0);
            state.qdot.push(0.0);
        }
        self.start_from(state);
    }

    /// Restart from `state` (the formulation's coordinates, plus the work coordinate when the
    /// ledger runs): as [`Simulation::reset`], with this as the initial state.
    fn start_from(&mut self, state: State) {
        let n = self.n;
        // The old monitor and integrator go first: two of each at once would raise a large
        // system's peak memory (an integrator for no coordinates holds nothing).
        self.monitor = Monitor::default();
        self.stepper = Stepper::new(&self.config, 0);
        // A start the contact modes cannot be found for (on the wrong side of a unilateral
        // constraint) leaves every row attached; the first step reports what fails there.
        let _ = contact::initial_mode(&mut *self.formulation, &state, n);
        self.contact_switches.clear();
        self.contact_counts = ContactCounts::default();
        if let Some(c) = self.formulation.contact_mut() {
            self.contact = Some(contact::ContactState::new(c.unilateral().len()));
        }
        self.monitor = Monitor::new(
            &mut *self.formulation,
            state.t,
            &state.q[..n],
            &state.qdot[..n],
        );
        self.watch_energy();
        self.previous = state.clone();
        self.output = Self::output_buffer(&self.config, &state);
        self.output_behind = false;
        self.grid_origin = state.t;
        self.grid_steps = 0;
        self.steps = 0;
        self.projection_iterations_max = None;
        self.projection_iterations_total = 0;
        self.substeps_max = 0;
        self.retried_steps = 0;
        self.iterations_replaced = 0;
        self.sticky = StickySubsteps::default();
        self.stepper = Stepper::new(&self.config, state.q.len());
        self.state = state;
        self.pending_event = None;
        self.resume_event = None;
        self.event_time = None;
        self.fired_event = None;
        self.stopped_at_event = false;
        self.crossings.clear();
        self.rearm_events();
    }

    /// Back to the initial state moved onto the constraints (implicit form): positions onto
    /// C = 0, velocities onto J qdot + C_t = 0, by the mass-weighted projections; the energy
    /// reference restarts there. For the parametric form the same as [`Simulation::reset`].
    /// Used after the constraints changed (a curve edit), which leaves the scene's initial
    /// state off them.
    pub fn reset_onto_constraints(&mut self) -> Result<(), RunError> {
        self.reset();
        let mut state = self.state.clone();
        let config = self.config;
        let Simulation {
            formulation,
            ledger,
            ..
        } = self;
        let result = with_system(formulation, ledger, |system| {
            if system.as_constrained().is_some() {
                project(system, &mut state, &config).map(|_| ())
            } else {
                Ok(())
            }
        });
        result.map_err(RunError::Step)?;
        self.start_from(state);
        Ok(())
    }

    /// Restart at t = 0 at rest from the particle positions `x` (n_coords numbers), e.g. a
    /// state a user dragged, moved onto the constraints at [`Simulation::closest_start`]:
    /// the point of C(y, 0) = 0 closest to `x` in the kinetic metric, the same for both
    /// forms. Implicit form: there, velocities zero (then onto J qdot + C_t = 0); parametric
    /// form: the coordinates q whose x(q, 0) is closest to it (Gauss-Newton from the current
    /// q and from the scene's initial q, the better fit), qdot = 0. The energy reference
    /// restarts there. On error nothing changes.
    pub fn restart_at_rest(&mut self, x: &[f64]) -> Result<(), RestartError> {
        // The parametric form with a unilateral row holds [q; x] (see ParametricContact):
        // q fitted to the target and x the target itself; the start decides which is in use.
        let layout = self
            .formulation
            .contact()
            .and_then(|c| c.parametric_layout());
        let target = self.closest_start(x)?;
        let current_q = self.state.q[..self.n].to_vec();
        let mut state = self.formulation.initial_state();
        if self.ledger.is_some() {
            state.q.push(0.0);
            state.qdot.push(0.0);
        }
        let n = self.n;
        state.t = 0.0;
        state.qdot[..n].iter_mut().for_each(|v| *v = 0.0);
        match (self.method(), self.system().parametric()) {
            (Method::Parametric, Some(map)) => {
                let n_q = layout.unwrap_or(n);
                let seeds = [&current_q[..n_q], map.initial()];
                let masses = self.masses();
                let q = restart::fit_coordinates(map, 0.0, &seeds, &target, &masses)?;
                state.q[..n_q].copy_from_slice(&q);
                if layout.is_some() {
                    state.q[n_q..n].copy_from_slice(&target);
                }
            }
            _ => {
                state.q[..n].copy_from_slice(&target);
                let config = self.config;
                let Simulation {
                    formulation,
                    ledger,
                    ..
                } = self;
                with_system(formulation, ledger, |system| {
                    project(system, &mut state, &config)
                })
                .map_err(RestartError::Projection)?;
            }
        }
        self.had_external = !self.external_ids.is_empty();
        self.refresh_nonconservation();
        self.start_from(state);
        Ok(())
    }

    /// Where [`Simulation::restart_at_rest`] puts the particles for positions `x`: the point
    /// y of the system's constraints C(y, 0) = 0 closest to `x` in the kinetic metric
    /// sum_k m_k (y_k - x_k)^2 (for one particle the Euclidean closest point; see
    /// `restart.rs` for the iteration), whichever form this simulation runs, so that every
    /// form restarts from the same place. Without constraint rows (a parametric form only):
    /// x(q*, 0) for the best fit q* of the map. `x` itself on a system without either.
    pub fn closest_start(&self, x: &[f64]) -> Result<Vec<f64>, RestartError> {
        let n_coords = self.system().n_coords();
        if x.len() != n_coords {
            return Err(RestartError::Length {
                expected: n_coords,
                got: x.len(),
            });
        }
        if x.iter().any(|v| !v.is_finite()) {
            return Err(RestartError::NotFinite);
        }
        let system = self.system();
        if system.constraints().n_rows() > 0 {
            return restart::closest_on_constraints(
                self.formulation.shared_system(),
                0.0,
                x,
                &self.config,
            );
        }
        match system.parametric() {
            Some(map) => {
                let current = &self.state.q[..self.n];
                let seeds: Vec<&[f64]> = if self.method() == Method::Parametric {
                    vec![current, map.initial()]
                } else {
                    vec![map.initial()]
                };
                let q = restart::fit_coordinates(map, 0.0, &seeds, x, &self.masses())?;
                Ok(restart::map_positions(map, 0.0, &q))
            }
            None => Ok(x.to_vec()),
        }
    }

    /// The mass of each particle coordinate.
    fn masses(&self) -> Vec<f64> {
        self.system()
            .inverse_mass()
            .iter()
            .map(|w| 1.0 / w)
            .collect()
    }

    /// Apply `force` from outside the system from now on (e.g. a spring dragged with the
    /// mouse), without rebuilding anything. Its work is counted by the energy ledger, which
    /// starts running if it was not.
    pub fn add_force(&mut self, force: Force) -> Result<ForceId, ModelError> {
        self.system().check_force(&force)?;
        self.enable_work_tracking();
        self.unprime();
        self.formulation.external_forces_mut().push(force);
        let id = ForceId(self.next_force_id);
        self.next_force_id += 1;
        self.external_ids.push(id);
        self.had_external = true;
        self.refresh_nonconservation();
        Ok(id)
    }

    /// Replace the external force `id` (e.g. move a drag spring's anchor); cheap.
    pub fn set_force(&mut self, id: ForceId, force: Force) -> Result<(), ModelError> {
        self.system().check_force(&force)?;
        let index = self
            .external_ids
            .iter()
            .position(|&i| i == id)
            .ok_or(ModelError::UnknownForce(id.0))?;
        self.unprime();
        self.formulation.external_forces_mut()[index] = force;
        Ok(())
    }

    /// Stop applying the external force `id`; returns it, or `None` for an unknown id.
    pub fn remove_force(&mut self, id: ForceId) -> Option<Force> {
        let index = self.external_ids.iter().position(|&i| i == id)?;
        self.external_ids.remove(index);
        self.unprime();
        let force = self.formulation.external_forces_mut().remove(index);
        self.refresh_nonconservation();
        Some(force)
    }

    /// The system changes (its external forces): a first stage primed for the next step is
    /// no longer its acceleration.
    fn unprime(&mut self) {
        match &mut self.stepper {
            Stepper::Fixed(integrator) => integrator.unprime(),
            Stepper::Adaptive(dopri) => dopri.forget_last_stage(),
        }
    }

    /// Start the energy ledger (allocates once; the integrator restarts).
    fn enable_work_tracking(&mut self) {
        if self.add_work_coordinate() {
            let replaced =
                std::mem::replace(&mut self.stepper, Stepper::new(&self.config, self.n + 1));
            if let Stepper::Fixed(integrator) = replaced {
                self.iterations_replaced += integrator.iterations_total().unwrap_or(0);
            }
        }
    }

    /// The ledger and the work coordinate of [`Simulation::enable_work_tracking`] without a
    /// new integrator (its caller builds one); false when they were there already.
    fn add_work_coordinate(&mut self) -> bool {
        if self.ledger.is_some() {
            return false;
        }
        self.ledger = Some(LedgerScratch::new(&mut *self.formulation));
        for state in [&mut self.state, &mut self.previous] {
            state.q.push(0.0);
            state.qdot.push(0.0);
        }
        if self.config.integrator.is_adaptive() {
            self.output.q.push(0.0);
            self.output.qdot.push(0.0);
        }
        self.watch_energy();
        true
    }

    /// The statistics so far (wall time and sampling are the caller's: see [`run`]).
    pub fn stats(&self, wall_seconds: f64) -> RunStats {
        let observed = self.observed();
        let (accepted, rejected) = match &self.stepper {
            Stepper::Adaptive(dopri) => {
                (Some(dopri.accepted_steps()), Some(dopri.rejected_steps()))
            }
            Stepper::Fixed(_) => (None, None),
        };
        let integrator_iterations = match &self.stepper {
            Stepper::Fixed(integrator) => integrator.newton_iterations_max(),
            Stepper::Adaptive(_) => None,
        };
        let newton_iterations_max = match (integrator_iterations, self.projection_iterations_max) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        let m = &self.monitor;
        RunStats {
            method: self.method(),
            integrator: self.config.integrator,
            dt: self.config.dt,
            steps: self.steps,
            t_final: observed.t,
            wall_seconds,
            energy_initial: m.energy_initial,
            energy_final: m.energy,
            energy_scale: m.energy_scale,
            energy_rel_error_max: m.energy_rel_error_max,
            energy_conserved: self.energy_conserved(),
            nonconservation: self.nonconservation.clone(),
            work_final: self.tracks_work().then_some(m.work),
            energy_balance_error_max: self.tracks_work().then_some(m.balance_error_max),
            constraint_error_max: m.constraint_error_max,
            constraint_error_final: m.constraint_error,
            constraint_distance_max: (self.method() == Method::Implicit)
                .then_some(m.constraint_distance_max),
            constraint_distance_final: (self.method() == Method::Implicit)
                .then_some(m.constraint_distance),
            length_scale: m.length_scale(),
            x: m.observation.x.clone(),
            xdot: m.observation.xdot.clone(),
            q: observed.q[..self.n].to_vec(),
            qdot: observed.qdot[..self.n].to_vec(),
            accepted_steps: accepted,
            rejected_steps: rejected,
            projected: self.config.project,
            newton_iterations_max,
            newton_iterations: self.newton_iterations_total(),
            substeps: self.config.substeps.max(1),
            substeps_max: self.substeps_max(),
            retried_steps: self.retried_steps,
            stop_when: self
                .fired_event
                .and_then(|k| self.watches.get(k))
                .map(|w| &w.event)
                .or(self.stop_when())
                .map(|e| e.source().to_string()),
            stop_time: self.event_time,
            contacts: self.contact.is_some().then(|| self.contact_counts.clone()),
            events: self
                .watches
                .iter()
                .enumerate()
                .map(|(k, w)| EventRecord {
                    when: w.event.source().to_string(),
                    direction: w.direction,
                    terminal: w.terminal,
                    times: self
                        .crossings()
                        .iter()
                        .filter(|c| c.event == k)
                        .map(|c| c.t)
                        .collect(),
                })
                .collect(),
        }
    }

    /// The current state as a [`Sample`] numbered `index`.
    pub fn sample(&self, index: u64) -> Sample<'_> {
        let observed = self.observed();
        Sample {
            step: index,
            t: observed.t,
            x: &self.monitor.observation.x,
            xdot: &self.monitor.observation.xdot,
            energy: self.monitor.energy,
            constraint_error: self.monitor.constraint_error,
            q: &observed.q[..self.n],
            qdot: &observed.qdot[..self.n],
            work: self.tracks_work().then_some(self.monitor.work),
            energy_initial: self.monitor.energy_initial,
            energy_scale: self.monitor.energy_scale,
        }
    }
}

/// The interior samples of an adaptive step of length `h` for `samples` per dt: spaced at
/// most dt / (samples + 1), as a fixed step of dt is, however long the step.
fn dense_samples(h: f64, dt: f64, samples: u32) -> u32 {
    let intervals = (h / dt * (samples as f64 + 1.0)).ceil();
    if intervals.is_nan() || intervals < 1.0 {
        0
    } else {
        (intervals.min(u32::MAX as f64) as u32 - 1).min(u32::MAX - 1)
    }
}

/// The substeps to retry a step in after `substeps` failed: about 1.5 times as many (1, 2, 3,
/// 5, 8, 12, 18, ...), at most `max`. Doubling overshoots: a chain whose Newton solve fails at
/// 2 substeps mostly converges at 3, and the steps after a retry start from what it needed
/// (measured on the hanging chain: 10^4 links 8-15% and 10^5 links 18-20% more frames/s
/// than with 2, 4, 8, ...).
fn more_substeps(substeps: u32, max: u32) -> u32 {
    (substeps + substeps.div_ceil(2)).min(max)
}

/// The retries' sequence one place back (12 -> 8 -> 5 -> 3 -> 2 -> 1): the largest s with
/// s + ceil(s / 2) <= `substeps`, i.e. floor(2 substeps / 3), at least 1.
fn fewer_substeps(substeps: u32) -> u32 {
    (2 * substeps / 3).max(1)
}

/// A step's error, told the substeps it was last tried in when it is an iteration that
/// did not converge (then as many as allowed).
pub(super) fn tried_in(error: StepError, substeps: u32) -> StepError {
    match error {
        StepError::ProjectionFailed {
            t,
            iterations,
            residual,
            solve,
            ..
        } => StepError::ProjectionFailed {
            t,
            iterations,
            residual,
            solve,
            substeps,
        },
        other => other,
    }
}

/// Whether a failed step may succeed on shorter substeps: an iteration that did not converge.
fn retryable(error: &StepError) -> bool {
    matches!(
        error,
        StepError::ProjectionFailed { .. } | StepError::ImplicitStageFailed { .. }
    )
}

/// An implicit system with more constraint rows than coordinates cannot be solved.
fn check_rows(system: &System, method: Method) -> Result<(), SetupError> {
    let rows = system.constraints().n_rows();
    if method == Method::Implicit && rows > system.n_coords() {
        return Err(SetupError::OverConstrained {
            rows,
            coords: system.n_coords(),
        });
    }
    Ok(())
}

/// Run `f` on the formulation as the integrators see it: with the work coordinate when the
/// ledger runs.
fn with_system<R>(
    formulation: &mut Box<dyn Formulation + Send>,
    ledger: &mut Option<LedgerScratch>,
    f: impl FnOnce(&mut dyn SecondOrderSystem) -> R,
) -> R {
    match ledger {
        Some(scratch) => f(&mut WithWork::new(&mut **formulation, scratch)),
        None => f(&mut **formulation),
    }
}

/// Why [`Simulation::restart_at_rest`] refused a state.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RestartError {
    #[error("positions need {expected} numbers, got {got}")]
    Length { expected: usize, got: usize },
    #[error("positions must be finite numbers")]
    NotFinite,
    /// The implicit form's projection failed (far from the constraints, a singular point).
    #[error("cannot move the positions onto the constraints: {0}")]
    Projection(StepError),
    /// The parametric form's least-squares fit failed.
    #[error("no coordinates of the parametric form put the particles near these positions: {0}")]
    NoCoordinates(&'static str),
}

/// Project `state` onto C = 0 and J qdot + C_t = 0; returns the position iterations.
fn project(
    system: &mut dyn SecondOrderSystem,
    state: &mut State,
    config: &SimulationConfig,
) -> Result<usize, StepError> {
    let Some(constrained) = system.as_constrained() else {
        return Ok(0);
    };
    let settings = &config.settings;
    let iterations = constrained.project_positions(
        state.t,
        &mut state.q,
        settings.constraint_tolerance,
        settings.constraint_max_iterations,
    )?;
    constrained.project_velocities(state.t, &state.q, &mut state.qdot)?;
    Ok(iterations)
}

/// Whether a simulation can start from `state` (n formulation coordinates, then the work
/// coordinate when the ledger runs), whose observation `monitor` made: positions and
/// constraint values finite, no gradient vanishing there, a finite acceleration.
fn check_start(
    formulation: &mut Box<dyn Formulation + Send>,
    ledger: &mut Option<LedgerScratch>,
    n: usize,
    state: &State,
    monitor: &Monitor,
) -> Result<(), StepError> {
    let t = state.t;
    let observation = &monitor.observation;
    let system = formulation.system();
    if let Some(k) = observation.x.iter().position(|c| !c.is_finite()) {
        return Err(StepError::NonFinite {
            t,
            quantity: format!("the position {}", system.coordinate_name(k)),
        });
    }
    if let Some(i) = observation.constraints.iter().position(|c| !c.is_finite()) {
        let name = system.constraints().name_of_row(i);
        return Err(StepError::NonFinite {
            t,
            quantity: format!("the value of {name} ({})", observation.constraints[i]),
        });
    }
    if let Some(row) = monitor.singular_at_start() {
        return Err(StepError::SingularPoint {
            t,
            subject: formulation.gradient_subject(row),
            position: formulation.gradient_position(row, &state.q[..n]),
            kind: crate::formulation::SingularKind::AtStart,
            cause: None,
        });
    }
    let mut a = vec![0.0; state.q.len()];
    with_system(formulation, ledger, |system| {
        system.acceleration(t, &state.q, &state.qdot, &mut a)
    })?;
    if let Some(k) = a.iter().position(|c| !c.is_finite()) {
        let names = formulation.coordinate_names();
        let quantity = if k >= n {
            "the initial rate of work of the energy ledger".to_string()
        } else if names.is_empty() {
            let name = formulation.system().coordinate_name(k);
            format!("the initial acceleration of {name}")
        } else {
            format!("the initial acceleration of q.{}", names[k])
        };
        return Err(StepError::NonFinite { t, quantity });
    }
    Ok(())
}

/// (q, qdot, W) of a state with n formulation coordinates (W = 0 without the ledger).
fn split(state: &State, n: usize) -> (&[f64], &[f64], f64) {
    let work = state.qdot.get(n).copied().unwrap_or(0.0);
    (&state.q[..n], &state.qdot[..n], work)
}

/// The first non-finite coordinate or rate of a state, named.
fn non_finite_state(
    formulation: &dyn Formulation,
    state: &State,
    n: usize,
) -> Option<(Quantity, f64)> {
    if crate::linalg::all_finite(&state.q) && crate::linalg::all_finite(&state.qdot) {
        // The common case, without asking the formulation for names.
        return None;
    }
    let names = formulation.coordinate_names();
    let system = formulation.system();
    if let Some(k) = state.q[..n].iter().position(|c| !c.is_finite()) {
        let quantity = if names.is_empty() {
            Quantity::Position(system.coordinate_name(k))
        } else {
            Quantity::Coordinate(names[k].clone())
        };
        return Some((quantity, state.q[k]));
    }
    if let Some(k) = state.qdot[..n].iter().position(|c| !c.is_finite()) {
        let quantity = if names.is_empty() {
            Quantity::Velocity(system.velocity_name(k))
        } else {
            Quantity::Rate(names[k].clone())
        };
        return Some((quantity, state.qdot[k]));
    }
    if let Some(&w) = state.qdot.get(n) {
        if !w.is_finite() {
            return Some((Quantity::Work, w));
        }
    }
    None
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("method", &self.method())
            .field("config", &self.config)
            .field("t", &self.t())
            .field("steps", &self.steps)
            .field("tracks_work", &self.tracks_work())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send<T: Send>() {}

    #[test]
    fn a_simulation_can_move_to_another_thread() {
        assert_send::<Simulation>();
    }

    /// The retries' sequence backwards, and the probes: after a retry at 3 substeps the
    /// steps start from 3, and after 16 calm steps one probes 2; a probe that fails at once
    /// (retried at 3 again) makes the next probe wait twice as long, up to 256 steps; one
    /// that holds brings the wait back to 16 and the next probe goes on down to 1.
    #[test]
    fn sticky_substeps_probe_less_often_while_probes_fail() {
        for (s, fewer) in [(1, 1), (2, 1), (3, 2), (5, 3), (8, 5), (12, 8), (18, 12)] {
            assert_eq!(fewer_substeps(s), fewer, "{s}");
            assert!(s == 1 || more_substeps(fewer, u32::MAX) <= s);
        }
        let mut sticky = StickySubsteps::default();
        sticky.after_step(3, true, 1);
        // Steps until the next probe, each probe failing at once.
        let mut waits = Vec::new();
        for _ in 0..7 {
            let mut wait = 0;
            while sticky.substeps == 3 {
                sticky.after_step(3, false, 1);
                wait += 1;
            }
            assert_eq!(sticky.substeps, 2);
            waits.push(wait);
            sticky.after_step(3, true, 1);
        }
        assert_eq!(waits, [16, 32, 64, 128, 256, 256, 256]);
        // A probe that holds: 2 from then on, the next probe after 16 steps, down to 1.
        for _ in 0..256 {
            sticky.after_step(3, false, 1);
        }
        assert_eq!((sticky.substeps, sticky.probing), (2, true));
        sticky.after_step(2, false, 1);
        assert_eq!(sticky.calm_needed, CALM_STEPS);
        for _ in 0..15 {
            sticky.after_step(2, false, 1);
        }
        assert_eq!((sticky.substeps, sticky.probing), (1, true));
        sticky.after_step(1, false, 1);
        assert_eq!(sticky.substeps, 1);
    }

    /// The regularity monitor keeps a step end's gradient values only when it watches a
    /// row: none for a chain (rods cannot be singular; 48 bytes a rod, twice, at 10^5 links),
    /// all of them for a curve, whose singular points it looks for. The step ends' positions
    /// are kept in both.
    #[test]
    fn step_ends_keep_gradients_only_where_a_row_is_watched() {
        use crate::scene::Scene;
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        let chain = Scene::load(&root.join("chain.toml"), &[("N".into(), 5.0)]).unwrap();
        let circle = Scene::load(&root.join("circle.toml"), &[]).unwrap();
        let config = SimulationConfig {
            integrator: crate::integrate::IntegratorKind::Rattle,
            dt: 0.01,
            ..Default::default()
        };
        // The chain's 5 rods are never watched; the circle's one row (2 entries) is.
        for (scene, kept) in [(chain, 0), (circle, 2)] {
            let n = scene.system.n_coords();
            let mut sim = Simulation::new(scene.system, config).unwrap();
            for _ in 0..3 {
                sim.step().unwrap();
            }
            for newest in [true, false] {
                let (q, gradients) = sim.monitor.step_end(newest).expect("two step ends");
                assert_eq!((q.len(), gradients.len()), (n, kept), "newest: {newest}");
            }
        }
    }

    /// Why [`Integrator::continued`] exists: the substeps land on the grid t0 + k h, and for
    /// about one substep in eight (as README and DESIGN.md say) that differs in the last bit
    /// from the time the step itself reached, t + h. Counted here through `Simulation` on
    /// the circle at dt = 1/120: 2 and 4 substeps, 1200 steps.
    #[test]
    fn about_one_substep_in_eight_lands_off_its_own_time() {
        use crate::scene::Scene;
        use std::sync::atomic::{AtomicU32, Ordering};
        /// RATTLE, counting the driver's `continued` calls and those that moved the time.
        struct Counting {
            inner: Box<dyn Integrator>,
            calls: Arc<AtomicU32>,
            moved: Arc<AtomicU32>,
        }
        impl Integrator for Counting {
            fn step(
                &mut self,
                system: &mut dyn SecondOrderSystem,
                state: &mut State,
                dt: f64,
            ) -> Result<(), StepError> {
                self.inner.step(system, state, dt)
            }
            fn continued(&mut self, stepped: f64, state: &State, amended: bool) {
                self.calls.fetch_add(1, Ordering::Relaxed);
                if stepped.to_bits() != state.t.to_bits() {
                    self.moved.fetch_add(1, Ordering::Relaxed);
                }
                self.inner.continued(stepped, state, amended);
            }
        }
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        let circle = Scene::load(&root.join("circle.toml"), &[]).unwrap();
        for substeps in [2, 4] {
            let config = SimulationConfig {
                integrator: IntegratorKind::Rattle,
                dt: 1.0 / 120.0,
                substeps,
                ..Default::default()
            };
            let mut sim = Simulation::new(circle.system.clone(), config).unwrap();
            let (calls, moved) = (Arc::new(AtomicU32::new(0)), Arc::new(AtomicU32::new(0)));
            sim.stepper = Stepper::Fixed(Box::new(Counting {
                inner: IntegratorKind::Rattle.build(sim.n),
                calls: calls.clone(),
                moved: moved.clone(),
            }));
            for _ in 0..1200 {
                sim.step().unwrap();
            }
            let (calls, moved) = (calls.load(Ordering::Relaxed), moved.load(Ordering::Relaxed));
            assert_eq!(calls, 1200 * substeps, "every substep continues the last");
            let share = f64::from(moved) / f64::from(calls);
            assert!(
                (1.0 / 12.0..1.0 / 5.0).contains(&share),
                "{substeps} substeps: {moved} of {calls} moved ({share:.3})"
            );
        }
    }

    /// The bits of everything a trace row and the statistics show.
    fn figures(sim: &Simulation) -> Vec<u64> {
        let mut bits = vec![sim.t(), sim.energy(), sim.work(), sim.constraint_error()];
        for values in [sim.positions(), sim.velocities(), sim.q(), sim.qdot()] {
            bits.extend_from_slice(values);
        }
        bits.iter().map(|v| v.to_bits()).collect()
    }

    /// A step's end primes the integrator's first stage and the monitors read that
    /// evaluation: every shipped scene, both forms, its own integrator and rk4, gives the
    /// same numbers, errors and statistics, bit for bit, as with both evaluated apart.
    #[test]
    fn priming_the_first_stage_changes_no_number() {
        use crate::plan::{methods, Plan, PlanRequest};
        use crate::scene::Scene;
        let mut compared = 0;
        for path in crate::shipped_scene_paths() {
            let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
            let plan = Plan::resolve(&scene, &PlanRequest::default()).expect("a plan");
            for method in methods(&scene) {
                for integrator in [plan.integrator, IntegratorKind::Rk4] {
                    let config = SimulationConfig {
                        integrator,
                        ..plan.config(method)
                    };
                    let new = || Simulation::new(scene.system.clone(), config);
                    let (Ok(mut primed), Ok(mut apart)) = (new(), new()) else {
                        continue;
                    };
                    apart.prime_first_stage = false;
                    let what =
                        format!("{} {} {}", path.display(), method.name(), integrator.name());
                    for _ in 0..plan.steps.min(400) {
                        let (a, b) = (primed.step(), apart.step());
                        assert_eq!(format!("{a:?}"), format!("{b:?}"), "{what}");
                        assert_eq!(figures(&primed), figures(&apart), "{what}");
                        if a.is_err() {
                            break;
                        }
                    }
                    let stats = |s: &Simulation| format!("{:?}", s.stats(0.0));
                    assert_eq!(stats(&primed), stats(&apart), "{what}");
                    compared += 1;
                }
            }
        }
        assert!(compared >= 20, "only {compared} runs compared");
    }
}
