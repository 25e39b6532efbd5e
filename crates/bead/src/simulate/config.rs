//! What a [`super::Simulation`] runs, and the one place that decides which combinations are
//! legal.

use crate::formulation::{Feedback, FormulationError, Method, StepError};
use crate::integrate::{IntegratorKind, IntegratorSettings};
use crate::model::System;

/// How to simulate: formulation, integrator, step, constraint feedback, projection and the
/// integrators' tolerances.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimulationConfig {
    pub method: Method,
    pub integrator: IntegratorKind,
    /// Step size of the fixed-step integrators; the output interval of the adaptive ones
    /// (dopri5 picks its own steps), s. Finite and > 0.
    pub dt: f64,
    /// Constraint feedback Cddot = -ks C - kd Cdot (implicit form only).
    pub feedback: Feedback,
    /// Project positions onto C = 0 and velocities onto J qdot + C_t = 0 after every step
    /// (implicit form, fixed-step integrators only).
    pub project: bool,
    /// Tolerances and iteration limits of the integrators that have them.
    pub settings: IntegratorSettings,
    /// Hold each constraint row to its own scale when the simulation is built: RATTLE and
    /// the projections stop at |C_i| <= 1e-12 s_i + rho_i |q| (a rod's stretch 1e-12, see
    /// [`crate::formulation::ConstraintScales`]), replacing `settings.constraint_tolerance` by
    /// [`super::RELATIVE_CONSTRAINT_TOLERANCE`]. Default true; false keeps
    /// `settings.constraint_tolerance` as an absolute bound on max_i |C_i|.
    pub scaled_constraint_tolerance: bool,
    /// Take each step of dt as this many steps of dt / substeps (fixed-step integrators; the
    /// convention of game-physics engines). Default 1.
    pub substeps: u32,
    /// When an iteration of a step does not converge (RATTLE's Newton solve, a projection, an
    /// implicit kick or stage), retry the step with about 1.5 times as many substeps (2, 3,
    /// 5, 8, ...), up to this many,
    /// before failing. The steps after a retried one start with the substeps it needed and
    /// try one place fewer in that sequence after 16 steps without a retry (after twice as
    /// many steps each time such a try fails at once, up to 256). RATTLE on rods also
    /// takes, before it fails, as many substeps as it needs to stay stable (h omega <= 2
    /// for the rods' fastest oscillation omega, bounded from the last step's tensions:
    /// [`crate::integrate::Integrator::stable_step`]), up to this many. Default 64; equal
    /// to `substeps` to never retry nor add any.
    pub max_substeps: u32,
    /// Track the work W done on T + V (the energy ledger, see [`super::Simulation::work`]):
    /// `None` (the default) tracks it when the formulation does not conserve T + V (drag,
    /// driven constraints, a moving map); external forces switch it on when they are added.
    pub track_work: Option<bool>,
    /// Interior times per step at which a stop condition is sampled, besides the step's end
    /// (see [`super::Event`]): a crossing and its return within one step are found when a
    /// sample falls between them. 0 to [`super::MAX_EVENT_SAMPLES`]; default
    /// [`super::DEFAULT_EVENT_SAMPLES`].
    pub event_samples: u32,
}

impl Default for SimulationConfig {
    /// Implicit form, rk4, dt = 1/60 s, no feedback, no projection, default settings.
    fn default() -> Self {
        SimulationConfig {
            method: Method::Implicit,
            integrator: IntegratorKind::Rk4,
            dt: 1.0 / 60.0,
            feedback: Feedback::default(),
            project: false,
            settings: IntegratorSettings::default(),
            scaled_constraint_tolerance: true,
            substeps: 1,
            max_substeps: 64,
            track_work: None,
            event_samples: super::DEFAULT_EVENT_SAMPLES,
        }
    }
}

/// What needs the implicit form's constraints.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Requirement {
    /// An integrator that works on the constraints (rattle).
    Integrator(IntegratorKind),
    /// The projection onto the constraints after every step.
    Projection,
}

impl std::fmt::Display for Requirement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Requirement::Integrator(kind) => write!(f, "{}", kind.name()),
            Requirement::Projection => write!(f, "projection onto the constraints"),
        }
    }
}

/// A combination of scene, formulation, integrator, projection and feedback that cannot run.
/// Every front end reports these with the same words.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("the scene defines no parametric form (add a [parametric] table)")]
    NoParametricForm,
    #[error("the scene has no constraints, only a parametric form: its implicit form would simulate free particles, not the system of its [parametric] table; use the parametric method, or add [[constraint]] tables")]
    NoConstraints,
    #[error("{}", needs_constraints(*.0))]
    NeedsConstraints(Requirement),
    #[error("projection onto the constraints is not available with {}: it would invalidate the adaptive integrator's step control and dense output; use a fixed-step integrator", .0.name())]
    ProjectionWithAdaptive(IntegratorKind),
    #[error("constraint feedback (ks, kd) applies to the implicit form only: the parametric form stays on its constraints by construction")]
    FeedbackOnParametric,
    #[error("the parametric form simulates one unilateral constraint (`side`), and the scene has more: its map holds them all at once, and with some left it has no coordinates for the rest; use the implicit method")]
    UnilateralParametric,
    #[error("the system has unilateral constraints (`side`), and this formulation would hold them on both sides: build it with `formulate` (a `Contact` or `ParametricContact`), not `Implicit::new` or `Parametric::new`")]
    UnilateralWithoutContact,
    #[error("the step dt must be positive and finite, got {}", crate::readable(*.0))]
    BadStep(f64),
    #[error(
        "substeps must be at least 1 and at most max_substeps (got {substeps} and {max_substeps})"
    )]
    BadSubsteps { substeps: u32, max_substeps: u32 },
    #[error("substeps do not apply to {}, which chooses its own steps", .0.name())]
    SubstepsWithAdaptive(IntegratorKind),
    #[error("constraint feedback ks and kd must be finite and not negative, got ks = {}, kd = {}", crate::readable(*ks), crate::readable(*kd))]
    BadFeedback { ks: f64, kd: f64 },
    #[error("event_samples must be at most {max}, got {0}", max = super::MAX_EVENT_SAMPLES)]
    BadEventSamples(u32),
    #[error("{name} must be {requirement}, got {}", crate::readable(*value))]
    BadSetting {
        name: &'static str,
        requirement: &'static str,
        value: f64,
    },
}

fn needs_constraints(requirement: Requirement) -> String {
    match requirement {
        Requirement::Integrator(kind) => format!(
            "{} needs the implicit form: the parametric form has no constraints to project onto (it stays on them by construction); use gauss-legendre or rk4 with the parametric form",
            kind.name()
        ),
        Requirement::Projection => "projection onto the constraints needs the implicit form: the parametric form stays on its constraints by construction, so there is nothing to project".into(),
    }
}

impl From<FormulationError> for ConfigError {
    fn from(e: FormulationError) -> Self {
        match e {
            FormulationError::NoParametricForm => ConfigError::NoParametricForm,
            FormulationError::FeedbackOnParametric => ConfigError::FeedbackOnParametric,
            FormulationError::UnilateralParametric => ConfigError::UnilateralParametric,
        }
    }
}

/// Why a simulation cannot start.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SetupError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("the system is over-constrained: {rows} constraint rows on {coords} coordinates (more rows than coordinates, so the constraint forces are not determined)")]
    OverConstrained { rows: usize, coords: usize },
    #[error("the initial state cannot be simulated: {0}")]
    Initial(StepError),
}

impl SimulationConfig {
    /// Whether this configuration can run on `system`: the one legality check of every front
    /// end. Looks at the system's structure only (see [`super::Simulation::new`] for the
    /// checks of the initial state).
    ///
    /// ```
    /// use bead::formulation::Method;
    /// use bead::integrate::IntegratorKind;
    /// use bead::model::SystemBuilder;
    /// use bead::simulate::{ConfigError, Requirement, SimulationConfig};
    /// let mut b = SystemBuilder::new(&[0.0, 9.81]);
    /// b.particle("bead", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
    /// b.constraint_expr("bead.x^2 + bead.y^2 - 1").unwrap();
    /// b.parametric(&["theta"], &[1.5707963267948966], &[0.0]).unwrap();
    /// b.parametric_position_exprs("bead", &["sin(theta)", "cos(theta)"]).unwrap();
    /// let system = b.build().unwrap();
    /// let config = SimulationConfig {
    ///     method: Method::Parametric,
    ///     integrator: IntegratorKind::Rattle,
    ///     ..Default::default()
    /// };
    /// assert_eq!(
    ///     config.check(&system),
    ///     Err(ConfigError::NeedsConstraints(Requirement::Integrator(IntegratorKind::Rattle)))
    /// );
    /// ```
    pub fn check(&self, system: &System) -> Result<(), ConfigError> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(ConfigError::BadStep(self.dt));
        }
        if self.substeps == 0 || self.max_substeps < self.substeps {
            return Err(ConfigError::BadSubsteps {
                substeps: self.substeps,
                max_substeps: self.max_substeps,
            });
        }
        if self.substeps > 1 && self.integrator.is_adaptive() {
            return Err(ConfigError::SubstepsWithAdaptive(self.integrator));
        }
        if self.event_samples > super::MAX_EVENT_SAMPLES {
            return Err(ConfigError::BadEventSamples(self.event_samples));
        }
        let Feedback { ks, kd } = self.feedback;
        if !(ks.is_finite() && kd.is_finite() && ks >= 0.0 && kd >= 0.0) {
            return Err(ConfigError::BadFeedback { ks, kd });
        }
        let s = &self.settings;
        for (name, value, ok, requirement) in [
            ("rtol", s.rtol, s.rtol > 0.0, "positive and finite"),
            ("atol", s.atol, s.atol >= 0.0, "finite and not negative"),
            (
                "the constraint tolerance",
                s.constraint_tolerance,
                s.constraint_tolerance > 0.0,
                "positive and finite",
            ),
            (
                "the implicit stage tolerance",
                s.implicit_tolerance,
                s.implicit_tolerance > 0.0,
                "positive and finite",
            ),
        ] {
            if !(ok && value.is_finite()) {
                return Err(ConfigError::BadSetting {
                    name,
                    requirement,
                    value,
                });
            }
        }
        match self.method {
            Method::Implicit => {
                if system.constraints().n_rows() == 0 && system.parametric().is_some() {
                    return Err(ConfigError::NoConstraints);
                }
            }
            Method::Parametric => {
                if system.unilateral().len() > 1 {
                    return Err(ConfigError::UnilateralParametric);
                }
                if system.parametric().is_none() {
                    return Err(ConfigError::NoParametricForm);
                }
                if self.integrator.needs_constraints() {
                    return Err(ConfigError::NeedsConstraints(Requirement::Integrator(
                        self.integrator,
                    )));
                }
                if self.project {
                    return Err(ConfigError::NeedsConstraints(Requirement::Projection));
                }
                if self.feedback != Feedback::default() {
                    return Err(ConfigError::FeedbackOnParametric);
                }
            }
        }
        if self.project && self.integrator.is_adaptive() {
            return Err(ConfigError::ProjectionWithAdaptive(self.integrator));
        }
        Ok(())
    }
}
