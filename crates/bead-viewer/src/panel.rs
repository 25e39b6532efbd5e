//! One panel: a scene text, a formulation, an integrator and their state, advanced a batch of
//! steps at a time. Nothing here panics on user input; every failure becomes the panel's
//! error and stops that panel only.

use std::sync::Arc;
use std::time::{Duration, Instant};

use bead::formulation::{formulate, Feedback, Formulation, Method, State};
use bead::integrate::{Dopri5, Integrator, IntegratorKind, IntegratorSettings};
use bead::model::{ConstraintEval, System};
use bead::scene::Scene;
use bead::simulate::constraint_tolerance;

use crate::protocol::{DragInfo, PanelFrame, PanelInfo};

/// Values beyond this magnitude count as a blow-up (as in the run loop).
const BLOW_UP: f64 = 1e150;
/// Adaptive integrators: accepted steps allowed per output interval.
const MAX_ADAPTIVE_STEPS: u32 = 100_000;

/// What a panel runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PanelSettings {
    pub method: Method,
    pub integrator: IntegratorKind,
    pub dt: f64,
    pub ks: f64,
    pub kd: f64,
    pub project: bool,
}

impl PanelSettings {
    fn feedback(&self) -> Feedback {
        Feedback {
            ks: self.ks,
            kd: self.kd,
        }
    }
}

/// A drag in progress: a spring from `particle` to `target` plus critical damping.
#[derive(Clone, Debug, PartialEq)]
struct Drag {
    particle: usize,
    target: Vec<f64>,
    /// The target moved since the formulation was last rebuilt.
    dirty: bool,
}

enum Stepper {
    Fixed(Box<dyn Integrator>),
    Adaptive(Box<Dopri5>),
}

/// A live panel.
pub struct Panel {
    pub id: u32,
    pub settings: PanelSettings,
    /// The scene text this panel runs (the session's, with this panel's curve edits).
    pub text: Arc<str>,
    pub file: String,
    /// The expression of every `[[constraint]]` (None for non-expression kinds).
    pub exprs: Vec<Option<String>>,
    /// The system without the drag spring: energy and constraint error are measured on it.
    base: Arc<System>,
    formulation: Box<dyn Formulation + Send>,
    stepper: Stepper,
    state: State,
    x: Vec<f64>,
    xdot: Vec<f64>,
    constraints: ConstraintEval,
    projection_tolerance: f64,
    energy_initial: f64,
    energy_scale: f64,
    energy: f64,
    constraint_error: f64,
    pub steps: u64,
    pub running: bool,
    pub failed: Option<String>,
    /// Simulated time owed to real time (s).
    debt: f64,
    behind: bool,
    steps_per_second: f64,
    drag: Option<Drag>,
    /// Scene scale (largest side of the view box) for the drag spring.
    scale: f64,
    pub curves: Vec<Vec<f64>>,
    pub curve_source: String,
}

/// Why a panel cannot be built.
pub type BuildError = String;

impl Panel {
    /// Build a panel from a parsed scene (`scene` was parsed from `text`).
    pub fn new(
        id: u32,
        settings: PanelSettings,
        text: Arc<str>,
        scene: &Scene,
        exprs: Vec<Option<String>>,
        view: [f64; 4],
    ) -> Result<Panel, BuildError> {
        validate_combination(&settings, &scene.system)?;
        let base = Arc::clone(&scene.system);
        let formulation = formulate(Arc::clone(&base), settings.method, settings.feedback())
            .map_err(|e| e.to_string())?;
        let state = formulation.initial_state();
        let n = base.n_coords();
        let projection_tolerance = constraint_tolerance(&base, 1e-12);
        let stepper = make_stepper(&settings, state.q.len(), projection_tolerance);
        let (curves, curve_source) = crate::geometry::curves(&base, settings.method, view);
        let mut panel = Panel {
            id,
            settings,
            text,
            file: scene.file.clone(),
            exprs,
            constraints: base.constraints().workspace(),
            base,
            formulation,
            stepper,
            state,
            x: vec![0.0; n],
            xdot: vec![0.0; n],
            projection_tolerance,
            energy_initial: 0.0,
            energy_scale: 1.0,
            energy: 0.0,
            constraint_error: 0.0,
            steps: 0,
            running: false,
            failed: None,
            debt: 0.0,
            behind: false,
            steps_per_second: 0.0,
            drag: None,
            scale: (view[2] - view[0]).max(view[3] - view[1]),
            curves,
            curve_source,
        };
        panel.reset();
        Ok(panel)
    }

    /// Back to the scene's initial state (moved onto the constraints for implicit panels),
    /// clearing any failure and drag.
    pub fn reset(&mut self) {
        let was_dragging = self.drag.take().is_some();
        if was_dragging {
            if let Err(e) = self.rebuild(None) {
                self.failed = Some(e);
                return;
            }
        }
        self.state = self.formulation.initial_state();
        self.steps = 0;
        self.debt = 0.0;
        self.failed = None;
        self.behind = false;
        self.stepper = make_stepper(
            &self.settings,
            self.state.q.len(),
            self.projection_tolerance,
        );
        if self.settings.method == Method::Implicit {
            // A curve edit leaves the initial position off the new curve: move it on.
            if let Some(constrained) = self.formulation.as_constrained() {
                let tolerance = self.projection_tolerance;
                let ok = constrained
                    .project_positions(0.0, &mut self.state.q, tolerance, 50)
                    .and_then(|_| {
                        constrained.project_velocities(0.0, &self.state.q, &mut self.state.qdot)
                    });
                if let Err(e) = ok {
                    self.failed = Some(format!(
                        "cannot move the initial state onto the constraints: {e}"
                    ));
                }
            }
        }
        self.observe();
        self.rebaseline();
        if !self.energy.is_finite() || !self.constraint_error.is_finite() {
            self.failed = Some("the initial state is not finite".into());
        }
    }

    /// Restart the energy reference at the current state.
    fn rebaseline(&mut self) {
        let kinetic = self.base.kinetic_energy(&self.xdot);
        let potential = self.base.potential_energy(&self.x);
        self.energy_initial = kinetic + potential;
        let scale = self.energy_initial.abs().max(kinetic + potential.abs());
        self.energy_scale = if scale > 0.0 && scale.is_finite() {
            scale
        } else {
            1.0
        };
    }

    /// Particle state, energy and constraint error of the current state.
    fn observe(&mut self) {
        let s = &self.state;
        self.formulation
            .particle_state(s.t, &s.q, &s.qdot, &mut self.x, &mut self.xdot);
        self.energy = self.base.energy(&self.x, &self.xdot);
        self.constraint_error =
            self.base
                .constraints()
                .max_abs_residual(s.t, &self.x, &mut self.constraints);
    }

    /// Advance by the real time `elapsed` times `time_scale`, at most `max_steps` steps and
    /// roughly `budget` of compute time. Returns the steps taken.
    pub fn advance(
        &mut self,
        elapsed: f64,
        time_scale: f64,
        max_steps: u64,
        budget: Duration,
    ) -> u64 {
        if !self.running || self.failed.is_some() {
            self.behind = false;
            return 0;
        }
        self.debt += time_scale * elapsed;
        let wanted = (self.debt / self.settings.dt).round().max(0.0);
        let wanted = if wanted.is_finite() { wanted as u64 } else { 0 };
        let steps = wanted.min(max_steps);
        let taken = self.run_steps(steps, budget);
        self.behind = taken < wanted;
        if self.behind {
            // Do not try to catch up later: fall behind real time instead.
            self.debt = 0.0;
        } else {
            self.debt -= taken as f64 * self.settings.dt;
        }
        taken
    }

    /// Take exactly one step (for the `step` control).
    pub fn single_step(&mut self) {
        self.running = false;
        if self.failed.is_none() {
            self.run_steps(1, Duration::from_secs(5));
        }
    }

    /// Run up to `steps` steps within about `budget`; stops the panel on failure.
    fn run_steps(&mut self, steps: u64, budget: Duration) -> u64 {
        if steps == 0 {
            return 0;
        }
        if let Err(e) = self.apply_drag() {
            self.fail(e);
            return 0;
        }
        let start = Instant::now();
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut taken = 0;
            while taken < steps {
                self.step_once()?;
                taken += 1;
                if start.elapsed() > budget {
                    break;
                }
            }
            Ok::<u64, String>(taken)
        }));
        let taken = match result {
            Ok(Ok(taken)) => taken,
            Ok(Err(e)) => {
                self.fail(e);
                0
            }
            Err(_) => {
                self.fail("internal error: the simulation panicked".into());
                0
            }
        };
        let wall = start.elapsed().as_secs_f64();
        if taken > 0 && wall > 0.0 {
            let rate = taken as f64 / wall;
            self.steps_per_second = if self.steps_per_second > 0.0 {
                0.8 * self.steps_per_second + 0.2 * rate
            } else {
                rate
            };
        }
        if self.failed.is_none() {
            self.observe();
            if !self.energy.is_finite() {
                self.fail(format!(
                    "diverged at t = {}: the energy is {}",
                    self.state.t, self.energy
                ));
            } else if !self.constraint_error.is_finite() {
                self.fail(format!(
                    "diverged at t = {}: the constraint error is {}",
                    self.state.t, self.constraint_error
                ));
            }
        }
        taken
    }

    fn fail(&mut self, message: String) {
        self.failed = Some(message);
        self.running = false;
    }

    /// One step of dt (or, for adaptive integrators, one output interval).
    fn step_once(&mut self) -> Result<(), String> {
        let dt = self.settings.dt;
        let t_end = (self.steps + 1) as f64 * dt;
        match &mut self.stepper {
            Stepper::Fixed(integrator) => {
                integrator
                    .step(&mut *self.formulation, &mut self.state, dt)
                    .map_err(|e| e.to_string())?;
                self.state.t = t_end;
            }
            Stepper::Adaptive(dopri) => {
                let mut count = 0;
                while self.state.t < t_end {
                    dopri
                        .advance(&mut *self.formulation, &mut self.state, t_end)
                        .map_err(|e| e.to_string())?;
                    count += 1;
                    if count > MAX_ADAPTIVE_STEPS {
                        return Err(format!(
                            "at t = {}: more than {MAX_ADAPTIVE_STEPS} adaptive steps in one interval of dt",
                            self.state.t
                        ));
                    }
                }
            }
        }
        if self.settings.project {
            if let Some(constrained) = self.formulation.as_constrained() {
                let t = self.state.t;
                constrained
                    .project_positions(t, &mut self.state.q, self.projection_tolerance, 50)
                    .and_then(|_| {
                        constrained.project_velocities(t, &self.state.q, &mut self.state.qdot)
                    })
                    .map_err(|e| e.to_string())?;
            }
        }
        self.steps += 1;
        for (k, v) in self.state.q.iter().chain(&self.state.qdot).enumerate() {
            if !v.is_finite() || v.abs() > BLOW_UP {
                let n = self.state.q.len();
                let what = if k < n {
                    format!("coordinate {k}")
                } else {
                    format!("the velocity of coordinate {}", k - n)
                };
                return Err(format!(
                    "diverged at t = {} (step {}): {what} is {v:e}",
                    self.state.t, self.steps
                ));
            }
        }
        Ok(())
    }

    /// Start dragging particle `particle` towards `target`.
    pub fn drag_start(&mut self, particle: usize, target: Vec<f64>) -> Result<(), String> {
        if particle >= self.base.particles().len() {
            return Err(format!(
                "no particle {particle}: the scene has {}",
                self.base.particles().len()
            ));
        }
        let target = self.full_target(particle, target)?;
        self.drag = Some(Drag {
            particle,
            target,
            dirty: true,
        });
        Ok(())
    }

    /// Move the drag target.
    pub fn drag_move(&mut self, target: Vec<f64>) -> Result<(), String> {
        let Some(particle) = self.drag.as_ref().map(|d| d.particle) else {
            return Err("no drag in progress in this panel".into());
        };
        let target = self.full_target(particle, target)?;
        if let Some(drag) = &mut self.drag {
            drag.target = target;
            drag.dirty = true;
        }
        Ok(())
    }

    /// Release the drag: the spring goes, the energy reference restarts here.
    pub fn drag_end(&mut self) -> Result<(), String> {
        if self.drag.take().is_none() {
            return Ok(());
        }
        self.rebuild(None)?;
        self.observe();
        self.rebaseline();
        Ok(())
    }

    /// A target with one number per axis: a missing z is the particle's current z.
    fn full_target(&self, particle: usize, mut target: Vec<f64>) -> Result<Vec<f64>, String> {
        let dim = self.base.dim();
        if target.len() == 2 && dim == 3 {
            target.push(self.x[particle * dim + 2]);
        }
        if target.len() != dim {
            return Err(format!("target needs {dim} numbers, got {}", target.len()));
        }
        if target.iter().any(|v| !v.is_finite() || v.abs() > 1e12) {
            return Err("target must be finite numbers within 1e12".into());
        }
        Ok(target)
    }

    /// Rebuild the formulation for a moved drag target, keeping the state.
    fn apply_drag(&mut self) -> Result<(), String> {
        let Some(drag) = &self.drag else {
            return Ok(());
        };
        if !drag.dirty {
            return Ok(());
        }
        let spring = self.spring_text(drag.particle, &drag.target);
        if let Some(drag) = &mut self.drag {
            drag.dirty = false;
        }
        self.rebuild(Some(spring))
    }

    /// The scene text of the drag spring and its damping.
    fn spring_text(&self, particle: usize, target: &[f64]) -> String {
        let p = &self.base.particles()[particle];
        let gravity = self
            .base
            .gravity()
            .iter()
            .map(|g| g * g)
            .sum::<f64>()
            .sqrt();
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
        let stiffness = p.mass * omega2;
        let damping = 2.0 * p.mass * omega2.sqrt();
        let name = serde_json::to_string(&p.name).unwrap_or_else(|_| "\"\"".into());
        let anchor: Vec<String> = target.iter().map(|v| format!("{v:?}")).collect();
        format!(
            "\n[[force]]\nkind = \"spring\"\nparticle = {name}\nanchor = [{}]\nstiffness = {stiffness:?}\n\n[[force]]\nkind = \"drag\"\nparticle = {name}\ncoefficient = {damping:?}\n",
            anchor.join(", ")
        )
    }

    /// Rebuild formulation and integrator from the panel's text plus `extra` (the drag
    /// spring), keeping the current state.
    fn rebuild(&mut self, extra: Option<String>) -> Result<(), String> {
        let system = match extra {
            None => Arc::clone(&self.base),
            Some(extra) => {
                let text = format!("{}\n{extra}", self.text);
                let scene = crate::session::parse_scene(&text, &self.file)
                    .map_err(|e| format!("cannot add the drag spring: {}", e.message))?;
                scene.system
            }
        };
        let formulation = formulate(system, self.settings.method, self.settings.feedback())
            .map_err(|e| e.to_string())?;
        self.formulation = formulation;
        self.stepper = make_stepper(
            &self.settings,
            self.state.q.len(),
            self.projection_tolerance,
        );
        Ok(())
    }

    /// Settings and drawing data.
    pub fn info(&self) -> PanelInfo {
        PanelInfo {
            id: self.id,
            method: self.settings.method.name().into(),
            integrator: self.settings.integrator.name().into(),
            dt: self.settings.dt,
            ks: self.settings.ks,
            kd: self.settings.kd,
            project: self.settings.project,
            exprs: self.exprs.clone(),
            curves: self.curves.clone(),
            curve_source: self.curve_source.clone(),
        }
    }

    /// The current state for a frame.
    pub fn frame(&self) -> PanelFrame {
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        PanelFrame {
            id: self.id,
            t: finite(self.state.t),
            steps: self.steps,
            x: self.x.iter().map(|&v| finite(v)).collect(),
            energy: finite(self.energy),
            energy_rel_error: finite((self.energy - self.energy_initial).abs() / self.energy_scale),
            constraint_error: finite(self.constraint_error),
            steps_per_second: finite(self.steps_per_second),
            status: if self.failed.is_some() {
                "failed"
            } else if self.running {
                "running"
            } else {
                "paused"
            }
            .into(),
            error: self.failed.clone(),
            behind: self.behind,
            drag: self.drag.as_ref().map(|d| DragInfo {
                particle: d.particle,
                target: d.target.clone(),
            }),
        }
    }
}

/// Whether `settings` can run on `system`.
pub fn validate_combination(settings: &PanelSettings, system: &System) -> Result<(), String> {
    let implicit = settings.method == Method::Implicit;
    if settings.method == Method::Parametric && system.parametric().is_none() {
        return Err("the scene has no [parametric] section".into());
    }
    if settings.integrator.needs_constraints() && !implicit {
        return Err(format!(
            "{} needs the implicit form (it works on the constraints directly)",
            settings.integrator.name()
        ));
    }
    if settings.project && !implicit {
        return Err("projection applies to the implicit form only".into());
    }
    if settings.project && settings.integrator.is_adaptive() {
        return Err(format!(
            "projection is not available with {}: it would invalidate its step control",
            settings.integrator.name()
        ));
    }
    if !implicit && (settings.ks != 0.0 || settings.kd != 0.0) {
        return Err(
            "feedback ks, kd applies to the implicit form only; set both to 0 for parametric"
                .into(),
        );
    }
    Ok(())
}

fn make_stepper(settings: &PanelSettings, n: usize, tolerance: f64) -> Stepper {
    let integrator_settings = IntegratorSettings {
        constraint_tolerance: tolerance,
        ..IntegratorSettings::default()
    };
    if settings.integrator.is_adaptive() {
        Stepper::Adaptive(Box::new(Dopri5::new(n, &integrator_settings)))
    } else {
        Stepper::Fixed(settings.integrator.build_with(n, &integrator_settings))
    }
}
