//! One panel: a [`Simulation`] of the panel's scene, advanced in real time.
//!
//! The simulation does the physics: stepping (fixed-step and adaptive), projection, the
//! divergence and singular-point checks, the energy ledger and the statistics; which
//! combinations are legal is its [`SimulationConfig::check`]. The panel keeps what is the
//! viewer's own: pacing against the wall clock (time scale, per-frame step and compute
//! budget, the `behind` flag, steps/s), the drag in progress, its epoch and the drawing data.
//! Nothing here panics on user input; a failure stops this panel only.

use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use bead::formulation::{Feedback, Method, StepError};
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, Force, ModelError, ParticleId};
use bead::scene::Scene;
use bead::simulate::{
    ForceId, PlacedState, RunError, SetupError, Simulation, SimulationConfig, StateRequest,
};

use crate::clock::Stopwatch;
use crate::geometry::{Curves, Resolution};
use crate::protocol::{
    Applies, Arrows, ContactFrame, DragInfo, PanelFrame, PanelInfo, ReferenceFrame, RowForce,
    ARROW_MAX_PARTICLES, ARROW_MAX_ROWS, GENERALIZED_MAX, PATH_MAX_NUMBERS, PATH_MAX_SAMPLES,
    REFERENCE_MAX_COORDS,
};

/// What a panel runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PanelSettings {
    pub method: Method,
    pub integrator: IntegratorKind,
    pub dt: f64,
    pub ks: f64,
    pub kd: f64,
    pub project: bool,
    /// Run the reference solution beside the panel: dopri5 at rtol [`REFERENCE_RTOL`] from the
    /// same start, drawn as a ghost (see [`PanelFrame::reference`]).
    pub reference: bool,
}

impl PanelSettings {
    /// The simulation these settings describe (the library's defaults otherwise).
    pub fn config(&self) -> SimulationConfig {
        SimulationConfig {
            method: self.method,
            integrator: self.integrator,
            dt: self.dt,
            feedback: Feedback {
                ks: self.ks,
                kd: self.kd,
            },
            project: self.project,
            ..SimulationConfig::default()
        }
    }
}

/// The reference solution beside a panel, drawn as a ghost: the panel's system and form
/// integrated by dopri5 at rtol 1e-12 (atol 1e-12 of the scene's length scale), without the
/// panel's feedback or projection (the true motion, not the stabilized one), from the panel's
/// own start and advanced to each of its output times; a drag acts on it as on the panel.
/// Its distance to the panel is the panel's error.
struct Reference {
    simulation: Simulation,
    /// The drag's spring and damping in the reference, while dragging
    drag: Option<(ForceId, ForceId)>,
}

/// max over particles p of |a_p - b_p| (`dim` coordinates each): how far apart two states of
/// the same particles are.
pub(crate) fn largest_distance(a: &[f64], b: &[f64], dim: usize) -> f64 {
    a.chunks(dim)
        .zip(b.chunks(dim))
        .map(|(p, q)| {
            p.iter()
                .zip(q)
                .map(|(u, v)| (u - v) * (u - v))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// rtol of the reference solution.
pub const REFERENCE_RTOL: f64 = 1e-12;

impl Reference {
    /// The reference of a panel running `settings` on `system`: `None` with the reason when
    /// the scene is too large for it.
    fn new(system: &Arc<bead::model::System>, settings: &PanelSettings) -> Result<Self, String> {
        let n = system.n_coords();
        if n > REFERENCE_MAX_COORDS {
            return Err(format!(
                "no reference: the scene has {n} coordinates, the reference runs for at most {REFERENCE_MAX_COORDS}"
            ));
        }
        let length = system.length_scale();
        let mut config = SimulationConfig {
            method: settings.method,
            integrator: IntegratorKind::Dopri5,
            dt: settings.dt,
            ..SimulationConfig::default()
        };
        config.settings.rtol = REFERENCE_RTOL;
        config.settings.atol = REFERENCE_RTOL * if length > 1e-300 { length } else { 1.0 };
        let simulation = Simulation::new(Arc::clone(system), config)
            .map_err(|e| format!("no reference: {e}"))?;
        Ok(Reference {
            simulation,
            drag: None,
        })
    }
}

/// A drag in progress: a spring from `particle` to `target` plus critical damping, both
/// external forces of the simulation.
#[derive(Clone, Debug, PartialEq)]
struct Drag {
    particle: usize,
    target: Vec<f64>,
    stiffness: f64,
    spring: ForceId,
    damping: ForceId,
    /// c / m of the damping (1/s).
    damping_rate: f64,
}

/// What was being dragged when a step failed (see [`PanelFailure`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DragContext {
    pub particle: usize,
    /// c / m of the drag's damping (1/s).
    pub damping_rate: f64,
    pub integrator: IntegratorKind,
    pub dt: f64,
}

/// Why a panel stopped. The simulation keeps the last good state; `reset` starts again.
#[derive(Debug)]
pub enum PanelFailure {
    /// A step failed or the motion diverged; `drag` when a particle was being dragged.
    Step {
        error: RunError,
        drag: Option<DragContext>,
    },
    /// The initial state could not be moved onto the constraints.
    Start(RunError),
    /// The simulation could not be built again on reset.
    Setup(SetupError),
    /// The simulation panicked: a bug.
    Panicked,
}

impl fmt::Display for PanelFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PanelFailure::Step { error, drag } => {
                write!(f, "{error}")?;
                let Some(drag) = drag else {
                    return Ok(());
                };
                let kick = matches!(error, RunError::Step(StepError::ImplicitStageFailed { .. }))
                    && matches!(
                        drag.integrator,
                        IntegratorKind::Verlet | IntegratorKind::Rattle | IntegratorKind::Rattle4
                    );
                if kick {
                    // The fixed-point iteration of the kick contracts by about dt c / (2 m)
                    // per iteration from the damping alone; it needs that well below 1.
                    write!(
                        f,
                        ". This happened while dragging particle {}: the drag's damping (c/m = {}/s) makes the force depend on the velocity, so {}'s second velocity kick is an implicit equation, solved by fixed-point iteration that contracts by about dt c/(2m) = {} per iteration here (dt = {} s), too slowly once that nears 1 (the constraint forces add to it). To drag with {}, use dt of at most about m/(2c) = {} s, or an explicit integrator",
                        drag.particle,
                        bead::readable(round3(drag.damping_rate)),
                        drag.integrator.name(),
                        bead::readable(round3(drag.dt * drag.damping_rate / 2.0)),
                        bead::readable(drag.dt),
                        drag.integrator.name(),
                        bead::readable(round3(0.5 / drag.damping_rate)),
                    )
                } else {
                    write!(
                        f,
                        " (while dragging particle {}: the drag's spring and damping, c/m = {}/s, stiffen the system; a smaller dt may help)",
                        drag.particle,
                        bead::readable(round3(drag.damping_rate))
                    )
                }
            }
            PanelFailure::Start(error) => write!(
                f,
                "cannot move the initial state onto the constraints: {error}"
            ),
            PanelFailure::Setup(error) => write!(f, "{error}"),
            PanelFailure::Panicked => write!(f, "internal error: the simulation panicked"),
        }
    }
}

/// Three significant digits, for messages.
fn round3(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(2 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

/// A drag request that cannot be carried out.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DragError {
    #[error("no particle {particle}: the scene has {count}")]
    NoParticle { particle: usize, count: usize },
    #[error("target needs {dim} numbers, got {got}")]
    TargetDimension { dim: usize, got: usize },
    #[error("target must be finite numbers within 1e12")]
    TargetRange,
    #[error("no drag in progress in this panel")]
    NoDrag,
    #[error("the drag force was refused: {0}")]
    Force(#[from] ModelError),
}

/// A live panel.
pub struct Panel {
    pub id: u32,
    epoch: u64,
    settings: PanelSettings,
    /// The scene this panel runs: the session's, with this panel's curve edits.
    scene: Arc<Scene>,
    simulation: Simulation,
    pub running: bool,
    failure: Option<PanelFailure>,
    /// Output intervals of dt taken since the epoch started: the next target time is
    /// (intervals + 1) dt.
    intervals: u64,
    behind: bool,
    steps_per_second: f64,
    drag: Option<Drag>,
    /// Scene scale (largest side of the view box), for the drag spring.
    scale: f64,
    /// The scene's view box (the page fits its view to it).
    view: [f64; 4],
    /// The x-y region the curves were made over: the view box, or the region the page
    /// showed when it asked for curves there ([`Panel::set_region`]).
    curve_region: [f64; 4],
    /// The curves (at t = 0 when they move).
    curves: Curves,
    /// The curves were made again (see [`Panel::follow_motion`], [`Panel::set_region`]) and
    /// no frame has carried them yet.
    curves_unsent: bool,
    /// The (epoch, steps) at which [`Panel::follow_motion`] last looked.
    followed_at: Option<(u64, u64)>,
    /// [`Arrows::speed_ref`] and [`Arrows::force_ref`] of this epoch.
    arrow_refs: (f64, f64),
    /// What the page should say about the curve (e.g. a curve edit that did not apply here).
    pub curve_note: Option<String>,
    /// The states of the last advance, `1 + n_coords` numbers each (t, positions); see
    /// [`PanelFrame::path`].
    path: Vec<f64>,
    /// Record every `path_stride`-th interval into `path`.
    path_stride: u64,
    /// The reference solution, when the settings ask for one and it runs
    reference: Option<Reference>,
    /// Why the settings ask for a reference and there is none
    reference_note: Option<String>,
}

impl Panel {
    /// A panel running `scene` with `settings`, from the scene's initial state moved onto
    /// the constraints (implicit form; see [`Simulation::reset_onto_constraints`]). Fails when
    /// the simulation cannot be built ([`SetupError`], whose `ConfigError` is the same for
    /// every front end); a state that cannot be moved onto the constraints leaves the panel
    /// failed (see [`Panel::failure`]).
    pub fn new(
        id: u32,
        epoch: u64,
        settings: PanelSettings,
        scene: Arc<Scene>,
        view: [f64; 4],
    ) -> Result<Panel, SetupError> {
        let simulation = Simulation::new(Arc::clone(&scene.system), settings.config())?;
        let curves = crate::geometry::curves(
            &scene.system,
            settings.method,
            view,
            None,
            0.0,
            Resolution::Scene,
        );
        let mut panel = Panel {
            id,
            epoch,
            settings,
            scene,
            simulation,
            running: false,
            failure: None,
            intervals: 0,
            behind: false,
            steps_per_second: 0.0,
            drag: None,
            scale: (view[2] - view[0]).max(view[3] - view[1]),
            view,
            curve_region: view,
            curves,
            curves_unsent: false,
            followed_at: None,
            arrow_refs: (1.0, 1.0),
            curve_note: None,
            path: Vec::new(),
            path_stride: 1,
            reference: None,
            reference_note: None,
        };
        panel.start();
        Ok(panel)
    }

    /// Move the simulation's initial state onto the constraints; a failure stops the panel.
    fn start(&mut self) {
        if let Err(e) = self.simulation.reset_onto_constraints() {
            self.failure = Some(PanelFailure::Start(e));
            self.running = false;
        }
        self.arrow_refs = self.arrow_references();
        self.start_reference(|r| r.reset_onto_constraints().map_err(|e| e.to_string()));
    }

    /// Build the reference when the settings ask for one, started by `start` as the panel
    /// was (so both begin at the same state).
    fn start_reference(&mut self, start: impl FnOnce(&mut Simulation) -> Result<(), String>) {
        self.reference = None;
        self.reference_note = None;
        if !self.settings.reference {
            return;
        }
        match Reference::new(&self.scene.system, &self.settings).and_then(|mut reference| {
            start(&mut reference.simulation)
                .map(|()| reference)
                .map_err(|e| format!("no reference: {e}"))
        }) {
            Ok(reference) => self.reference = Some(reference),
            Err(note) => self.reference_note = Some(note),
        }
    }

    /// The reference stopped (its step failed): say so, and run on without it.
    fn drop_reference(&mut self, error: &str) {
        if let Some(reference) = self.reference.take() {
            self.reference_note = Some(format!(
                "the reference stopped at t = {}: {error}",
                bead::readable(reference.simulation.t())
            ));
        }
    }

    /// The reference at the panel's t, with the distance between the two.
    fn reference_frame(&self) -> Option<ReferenceFrame> {
        let reference = &self.reference.as_ref()?.simulation;
        let dim = self.simulation.system().dim();
        let (x, x_ref) = (self.simulation.positions(), reference.positions());
        let distance = largest_distance(x, x_ref, dim);
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        Some(ReferenceFrame {
            t: finite(reference.t()),
            x: x_ref.iter().map(|&v| finite(v)).collect(),
            distance: finite(distance),
        })
    }

    pub fn epoch(&self) -> u64 {
        self.epoch
    }
    pub fn settings(&self) -> PanelSettings {
        self.settings
    }
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }
    pub fn method(&self) -> Method {
        self.settings.method
    }
    /// Why the panel stopped, when it did.
    pub fn failure(&self) -> Option<&PanelFailure> {
        self.failure.as_ref()
    }
    pub fn failed(&self) -> bool {
        self.failure.is_some()
    }

    /// Back to the scene's initial state (moved onto the constraints) in a new epoch,
    /// clearing any failure and drag. The simulation is built again, so that nothing of the
    /// last epoch (external forces, the work they did) carries over.
    pub fn reset(&mut self, epoch: u64) {
        self.epoch = epoch;
        self.intervals = 0;
        self.behind = false;
        self.drag = None;
        self.failure = None;
        self.path.clear();
        match Simulation::new(Arc::clone(&self.scene.system), self.settings.config()) {
            Ok(simulation) => {
                self.simulation = simulation;
                self.start();
            }
            Err(e) => {
                self.failure = Some(PanelFailure::Setup(e));
                self.running = false;
            }
        }
    }

    /// Advance to the session clock's `target` time: the whole intervals of dt that end at
    /// or before it, at most `max_steps` of them and roughly `budget` of compute time. False
    /// when the panel could not get there (it is then `behind`).
    pub fn advance_until(&mut self, target: f64, max_steps: u64, budget: Duration) -> bool {
        self.path.clear();
        if !self.running || self.failure.is_some() {
            self.behind = false;
            return true;
        }
        let dt = self.settings.dt;
        // The same rounding for every panel, so that panels of the same dt meet exactly.
        let end = (target / dt + 1e-9).floor().max(0.0);
        let end = if end.is_finite() { end as u64 } else { 0 };
        let wanted = end.saturating_sub(self.intervals);
        self.path_stride = wanted
            .min(max_steps)
            .div_ceil(PATH_MAX_SAMPLES as u64)
            .max(1);
        let taken = self.run_intervals(wanted.min(max_steps), budget);
        self.behind = taken < wanted && self.failure.is_none();
        !self.behind
    }

    /// The simulated time (s).
    pub fn t(&self) -> f64 {
        self.simulation.t()
    }

    /// The particle positions (`dim` numbers per particle).
    pub fn positions(&self) -> &[f64] {
        self.simulation.positions()
    }

    /// The panel's compute rate: integrator steps per second of compute (recent average).
    pub fn steps_per_second(&self) -> f64 {
        self.steps_per_second
    }

    /// The point of the constraints closest to positions `x`, where
    /// [`Panel::restarted_at_rest`] puts the particles (see
    /// [`Simulation::closest_start`]).
    pub fn closest_start(&self, x: &[f64]) -> Result<Vec<f64>, String> {
        self.simulation.closest_start(x).map_err(|e| e.to_string())
    }

    /// A new panel with this one's id, settings, scene and view, in epoch `epoch`.
    fn fresh(&self, epoch: u64) -> Result<Panel, String> {
        Panel::new(
            self.id,
            epoch,
            self.settings,
            Arc::clone(&self.scene),
            self.view,
        )
        .map_err(|e| e.to_string())
    }

    /// This panel restarted at t = 0 at rest from positions `x` (see
    /// [`Simulation::restart_at_rest`]), as a new panel in epoch `epoch`; `self` is left as
    /// it was, so that a session can replace its panels only when all of them can start.
    pub fn restarted_at_rest(&self, epoch: u64, x: &[f64]) -> Result<Panel, String> {
        let mut panel = self.fresh(epoch)?;
        panel
            .simulation
            .restart_at_rest(x)
            .map_err(|e| e.to_string())?;
        panel.start_reference(|r| r.restart_at_rest(x).map_err(|e| e.to_string()));
        panel.failure = None;
        panel.arrow_refs = panel.arrow_references();
        panel.running = self.running;
        panel.curve_note = self.curve_note.clone();
        Ok(panel)
    }

    /// Make the curves again over `region` (x-y, scene units): the page panned or zoomed
    /// past the region they were made over. The next frame carries them.
    pub fn set_region(&mut self, region: [f64; 4]) {
        self.curve_region = region;
        self.curves = crate::geometry::curves(
            self.simulation.system(),
            self.settings.method,
            region,
            self.curves.q_range,
            self.simulation.t(),
            Resolution::Scene,
        );
        self.curves_unsent = true;
    }

    /// Keep the drawn map under the bead: when the bead comes near the end of the interval
    /// of q the map was sampled over ([`crate::geometry::follow_range`]), sample it again over
    /// a wider one. The bead's q is its coordinate in a parametric panel, else the nearest
    /// point of the map ([`crate::geometry::nearest_q`]).
    fn follow_motion(&mut self) {
        let Some(range) = self.curves.q_range else {
            return;
        };
        let at = (self.epoch, self.simulation.steps());
        if self.followed_at == Some(at) {
            return;
        }
        self.followed_at = Some(at);
        let system = self.simulation.system();
        let q = match self.settings.method {
            Method::Parametric => self.simulation.q().first().copied(),
            Method::Implicit => crate::geometry::nearest_q(
                system,
                range,
                self.simulation.positions(),
                self.simulation.t(),
            ),
        };
        let Some(first) = crate::geometry::default_q_range(system) else {
            return;
        };
        let max_width = crate::geometry::MAX_Q_RANGE_FACTOR * (first[1] - first[0]);
        if let Some(wider) = q.and_then(|q| crate::geometry::follow_range(q, range, max_width)) {
            self.curves = crate::geometry::curves(
                system,
                self.settings.method,
                self.curve_region,
                Some(wider),
                self.simulation.t(),
                Resolution::Scene,
            );
            self.curves_unsent = true;
        }
    }

    /// The velocities and forces at the current state, for arrows (small scenes only, see
    /// [`Arrows`]): v, m g, the scene's other forces F - m g, and the constraint forces from
    /// one evaluation of the acceleration ([`Simulation::constraint_forces`]); in the
    /// implicit form each row's lambda_i grad C_i with J at the current state.
    fn arrows(&mut self) -> Option<Arrows> {
        let system = Arc::clone(&self.scene.system);
        let n_particles = system.particles().len();
        let n_rows = system.constraints().n_rows();
        if n_particles > ARROW_MAX_PARTICLES || n_rows > ARROW_MAX_ROWS {
            return None;
        }
        let dim = system.dim();
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        let s = &mut self.simulation;
        let (x, v) = (s.positions().to_vec(), s.velocities().to_vec());
        let mut gravity = vec![0.0; x.len()];
        for (p, particle) in system.particles().iter().enumerate() {
            for a in 0..dim {
                gravity[p * dim + a] = particle.mass * system.gravity()[a];
            }
        }
        let mut applied = vec![0.0; x.len()];
        system.accumulate_forces(&x, &v, &mut applied);
        for (f, w) in applied.iter_mut().zip(&gravity) {
            *f -= w;
        }
        let (constraint, multipliers) = match s.constraint_forces() {
            Ok(forces) => (forces.force, forces.multipliers),
            Err(_) => (Vec::new(), Vec::new()),
        };
        let mut rows = Vec::new();
        if self.settings.method == Method::Implicit && multipliers.len() == n_rows {
            let set = system.constraints();
            let mut ws = set.workspace();
            set.gradient(s.t(), &x, &mut ws);
            for (row, &lambda) in multipliers.iter().enumerate() {
                let mut force = vec![0.0; x.len()];
                let mut norm2 = 0.0;
                for (&column, &dc) in set
                    .row_columns(row)
                    .iter()
                    .zip(&ws.jacobian[set.row_entries(row)])
                {
                    force[column] += lambda * dc;
                    norm2 += dc * dc;
                }
                rows.push(RowForce {
                    row,
                    lambda: finite(lambda),
                    gradient_norm: finite(norm2.sqrt()),
                    force: force.into_iter().map(finite).collect(),
                });
            }
        }
        let clean = |v: Vec<f64>| v.into_iter().map(finite).collect::<Vec<_>>();
        Some(Arrows {
            velocity: clean(v),
            gravity: clean(gravity),
            applied: clean(applied),
            constraint: clean(constraint),
            rows,
            speed_ref: self.arrow_refs.0,
            force_ref: self.arrow_refs.1,
        })
    }

    /// The speed and force references of [`Arrows`] for the epoch starting now.
    fn arrow_references(&self) -> (f64, f64) {
        let system = &self.scene.system;
        let e_scale = self.simulation.energy_scale();
        let mass: f64 = system.particles().iter().map(|p| p.mass).sum();
        let extent = (self.view[2] - self.view[0]).max(self.view[3] - self.view[1]);
        let g = system.gravity().iter().map(|c| c * c).sum::<f64>().sqrt();
        let weight = system
            .particles()
            .iter()
            .map(|p| p.mass * g)
            .fold(0.0, f64::max);
        let speed = (2.0 * e_scale / mass).sqrt();
        let force = weight.max(e_scale / extent);
        let sane = |v: f64| if v.is_finite() && v > 0.0 { v } else { 1.0 };
        (sane(speed), sane(force))
    }

    /// This panel restarted at t = 0 from `request` placed on its constraints
    /// ([`Simulation::set_state`]), as a new panel in epoch `epoch`, with where the state
    /// was put; `self` is left as it was.
    pub fn restarted_from(
        &self,
        epoch: u64,
        request: &StateRequest,
    ) -> Result<(Panel, PlacedState), String> {
        let mut panel = self.fresh(epoch)?;
        let placed = panel
            .simulation
            .set_state(request)
            .map_err(|e| e.to_string())?;
        panel.start_reference(|r| r.set_state(request).map(|_| ()).map_err(|e| e.to_string()));
        panel.failure = None;
        panel.arrow_refs = panel.arrow_references();
        panel.running = self.running;
        panel.curve_note = self.curve_note.clone();
        Ok((panel, placed))
    }

    /// The velocities (`dim` numbers per particle).
    pub fn velocities(&self) -> &[f64] {
        self.simulation.velocities()
    }

    /// Which settings apply, by the library's legality check: feedback and projection are
    /// offered when a configuration with them passes [`SimulationConfig::check`].
    fn applies(&self) -> Applies {
        let system = &self.scene.system;
        let base = self.settings.config();
        let feedback = SimulationConfig {
            feedback: Feedback { ks: 1.0, kd: 1.0 },
            ..base
        };
        let project = SimulationConfig {
            project: true,
            ..base
        };
        Applies {
            feedback: feedback.check(system).is_ok(),
            project: project.check(system).is_ok(),
        }
    }

    /// Pause, then advance by exactly one interval of dt (one step of a fixed-step
    /// integrator). The failure, when the step fails.
    pub fn single_step(&mut self) -> Result<(), &PanelFailure> {
        self.running = false;
        self.path.clear();
        self.path_stride = 1;
        if self.failure.is_none() {
            self.run_intervals(1, Duration::from_secs(5));
        }
        match &self.failure {
            Some(failure) => Err(failure),
            None => Ok(()),
        }
    }

    /// Advance up to `count` intervals of dt within about `budget`; stops the panel on
    /// failure. Returns the intervals completed.
    fn run_intervals(&mut self, count: u64, budget: Duration) -> u64 {
        if count == 0 {
            return 0;
        }
        let start = Stopwatch::start();
        let steps_before = self.simulation.steps();
        let dt = self.settings.dt;
        let mut taken = 0;
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            while taken < count {
                let target = (self.intervals + 1) as f64 * dt;
                self.simulation.advance_to(target)?;
                if let Some(reference) = &mut self.reference {
                    if let Err(e) = reference.simulation.advance_to(target) {
                        self.drop_reference(&e.to_string());
                    }
                }
                self.intervals += 1;
                taken += 1;
                if self.intervals.is_multiple_of(self.path_stride) {
                    self.record_path();
                }
                if start.elapsed() > budget {
                    break;
                }
            }
            Ok::<(), RunError>(())
        }));
        match result {
            Ok(Ok(())) => {}
            Ok(Err(error)) => {
                let drag = self.drag.as_ref().map(|d| DragContext {
                    particle: d.particle,
                    damping_rate: d.damping_rate,
                    integrator: self.settings.integrator,
                    dt,
                });
                self.fail(PanelFailure::Step { error, drag });
            }
            Err(_) => self.fail(PanelFailure::Panicked),
        }
        let wall = start.elapsed().as_secs_f64();
        let steps = self.simulation.steps().saturating_sub(steps_before);
        if steps > 0 && wall > 0.0 {
            let rate = steps as f64 / wall;
            self.steps_per_second = if self.steps_per_second > 0.0 {
                0.8 * self.steps_per_second + 0.2 * rate
            } else {
                rate
            };
        }
        taken
    }

    /// Add the current state to the path, for scenes small enough to send one.
    fn record_path(&mut self) {
        let x = self.simulation.positions();
        if x.len() > PATH_MAX_NUMBERS || self.path.len() / (1 + x.len()) >= PATH_MAX_SAMPLES {
            return;
        }
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        self.path.push(finite(self.simulation.t()));
        self.path.extend(x.iter().map(|&v| finite(v)));
    }

    fn fail(&mut self, failure: PanelFailure) {
        self.failure = Some(failure);
        self.running = false;
    }

    /// Start dragging particle `particle` towards `target`: a spring to the target plus
    /// critical damping, added to the simulation as external forces (nothing is rebuilt). A
    /// drag already in progress is released first.
    pub fn drag_start(&mut self, particle: usize, target: Vec<f64>) -> Result<(), DragError> {
        let system = self.simulation.system();
        let count = system.particles().len();
        if particle >= count {
            return Err(DragError::NoParticle { particle, count });
        }
        let target = self.full_target(particle, target)?;
        let mass = system.particles()[particle].mass;
        let gravity = system.gravity().iter().map(|g| g * g).sum::<f64>().sqrt();
        let scale = if self.scale > 0.0 && self.scale.is_finite() {
            self.scale
        } else {
            1.0
        };
        // At least 2 Hz, and stiff enough that gravity stretches it by at most 1/20 of the
        // scene; critically damped.
        let omega2 = (2.0 * std::f64::consts::PI * 2.0)
            .powi(2)
            .max(20.0 * gravity / scale);
        let stiffness = mass * omega2;
        let coefficient = 2.0 * mass * omega2.sqrt();
        self.drag_end();
        let id = ParticleId(particle);
        let spring = self.simulation.add_force(Force::Spring {
            a: id,
            b: Endpoint::Fixed(target.clone()),
            stiffness,
            rest_length: 0.0,
        })?;
        let damping = match self.simulation.add_force(Force::Drag {
            particle: Some(id),
            coefficient,
        }) {
            Ok(damping) => damping,
            Err(e) => {
                self.simulation.remove_force(spring);
                return Err(e.into());
            }
        };
        // The reference is dragged as the panel is: the same spring and damping, on its own
        // particle (a reference that cannot take them is dropped, never the drag).
        let forces = (
            Force::Spring {
                a: id,
                b: Endpoint::Fixed(target.clone()),
                stiffness,
                rest_length: 0.0,
            },
            Force::Drag {
                particle: Some(id),
                coefficient,
            },
        );
        if let Some(reference) = &mut self.reference {
            let s = &mut reference.simulation;
            match s
                .add_force(forces.0)
                .and_then(|spring| Ok((spring, s.add_force(forces.1)?)))
            {
                Ok(ids) => reference.drag = Some(ids),
                Err(e) => self.drop_reference(&e.to_string()),
            }
        }
        self.drag = Some(Drag {
            particle,
            target,
            stiffness,
            spring,
            damping,
            damping_rate: coefficient / mass,
        });
        Ok(())
    }

    /// Move the drag target: the spring's fixed end moves, nothing is rebuilt.
    pub fn drag_move(&mut self, target: Vec<f64>) -> Result<(), DragError> {
        let Some(particle) = self.drag.as_ref().map(|d| d.particle) else {
            return Err(DragError::NoDrag);
        };
        let target = self.full_target(particle, target)?;
        let Some(drag) = &mut self.drag else {
            return Err(DragError::NoDrag);
        };
        let spring = Force::Spring {
            a: ParticleId(particle),
            b: Endpoint::Fixed(target.clone()),
            stiffness: drag.stiffness,
            rest_length: 0.0,
        };
        self.simulation.set_force(drag.spring, spring.clone())?;
        drag.target = target;
        if let Some(reference) = &mut self.reference {
            if let Some((id, _)) = reference.drag {
                if let Err(e) = reference.simulation.set_force(id, spring) {
                    self.drop_reference(&e.to_string());
                }
            }
        }
        Ok(())
    }

    /// Release the drag: spring and damping go. The work they did stays in the ledger, so
    /// the energy error goes on measuring E - W.
    pub fn drag_end(&mut self) {
        if let Some(drag) = self.drag.take() {
            self.simulation.remove_force(drag.spring);
            self.simulation.remove_force(drag.damping);
        }
        if let Some(reference) = &mut self.reference {
            if let Some((spring, damping)) = reference.drag.take() {
                reference.simulation.remove_force(spring);
                reference.simulation.remove_force(damping);
            }
        }
    }

    /// A target with one number per axis: a missing z is the particle's current z.
    fn full_target(&self, particle: usize, mut target: Vec<f64>) -> Result<Vec<f64>, DragError> {
        let dim = self.simulation.system().dim();
        if target.len() == 2 && dim == 3 {
            target.push(self.simulation.positions()[particle * dim + 2]);
        }
        if target.len() != dim {
            return Err(DragError::TargetDimension {
                dim,
                got: target.len(),
            });
        }
        if target.iter().any(|v| !v.is_finite() || v.abs() > 1e12) {
            return Err(DragError::TargetRange);
        }
        Ok(target)
    }

    /// Settings and drawing data.
    pub fn info(&self) -> PanelInfo {
        PanelInfo {
            id: self.id,
            epoch: self.epoch,
            method: self.settings.method.name().into(),
            integrator: self.settings.integrator.name().into(),
            dt: self.settings.dt,
            ks: self.settings.ks,
            kd: self.settings.kd,
            project: self.settings.project,
            reference: self.settings.reference,
            exprs: self
                .scene
                .system
                .declared_constraints()
                .iter()
                .map(|c| c.source().map(str::to_string))
                .collect(),
            curves: self.curves.lines.clone(),
            curve_source: self.curves.source.into(),
            curves_move: self.curves.moving,
            view: self.view,
            curve_region: self.curve_region,
            curve_note: self.curve_note.clone(),
            applies: self.applies(),
            coordinates: self.coordinate_names(),
        }
    }

    /// The current state for a frame; with the curves at the current t when they move, and
    /// when they were made again since the last frame.
    pub fn frame(&mut self) -> PanelFrame {
        self.follow_motion();
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        let s = &self.simulation;
        let curves = if self.curves.moving {
            let lines = crate::geometry::curves(
                s.system(),
                self.settings.method,
                self.curve_region,
                self.curves.q_range,
                s.t(),
                Resolution::Frame,
            )
            .lines;
            Some(lines)
        } else {
            self.curves_unsent.then(|| self.curves.lines.clone())
        };
        self.curves_unsent = false;
        let arrows = self.arrows();
        let s = &self.simulation;
        let curves = curves.map(|lines| {
            lines
                .into_iter()
                .map(|line| line.into_iter().map(finite).collect())
                .collect()
        });
        PanelFrame {
            id: self.id,
            epoch: self.epoch,
            t: finite(s.t()),
            steps: s.steps(),
            x: s.positions().iter().map(|&v| finite(v)).collect(),
            energy: finite(s.energy()),
            kinetic: finite(s.system().kinetic_energy(s.velocities())),
            potential: finite(s.system().potential_energy(s.positions())),
            energy_initial: finite(s.energy_initial()),
            energy_scale: finite(s.energy_scale()),
            energy_error: finite(s.energy_balance_error()),
            energy_conserved: s.energy_conserved(),
            work: finite(s.work()),
            not_conserved_by: s.nonconservation().iter().map(|r| r.to_string()).collect(),
            constraint_error: finite(s.constraint_error()),
            steps_per_second: finite(self.steps_per_second),
            distance: None,
            reference: self.reference_frame(),
            reference_note: self.reference_note.clone(),
            contact: (!s.system().unilateral().is_empty()).then(|| {
                let counts = s.contact_counts();
                ContactFrame {
                    detached: s.detached(),
                    detaches: counts.detaches,
                    landings: counts.landings,
                    bounces: counts.bounces,
                }
            }),
            status: if self.failure.is_some() {
                "failed"
            } else if self.running {
                "running"
            } else {
                "paused"
            }
            .into(),
            error: self.failure.as_ref().map(|f| f.to_string()),
            behind: self.behind,
            drag: self.drag.as_ref().map(|d| DragInfo {
                particle: d.particle,
                target: d.target.clone(),
            }),
            path: self.path.clone(),
            curves,
            curve_region: self.curve_region,
            arrows,
            generalized: self.generalized(),
        }
    }

    /// The generalized coordinates' names of a parametric panel (none for an implicit one).
    fn coordinate_names(&self) -> Vec<String> {
        match (self.settings.method, self.scene.system.parametric()) {
            (Method::Parametric, Some(map)) => map.coordinates().to_vec(),
            _ => Vec::new(),
        }
    }

    /// A parametric panel's q then q' (see [`PanelFrame::generalized`]).
    fn generalized(&self) -> Option<Vec<f64>> {
        let s = &self.simulation;
        let n = s.q().len();
        if self.settings.method != Method::Parametric || n > GENERALIZED_MAX {
            return None;
        }
        let finite = |v: &f64| if v.is_finite() { *v } else { 0.0 };
        Some(s.q().iter().chain(s.qdot()).map(finite).collect())
    }
}
