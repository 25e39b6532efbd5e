//! What to run, resolved the same way by every front end: a value asked for (a command-line
//! flag, a Python keyword argument) overrides the scene's `[run]` table, which overrides the
//! built-in defaults. [`Plan::resolve`] checks every value and returns a [`Plan`], from which
//! [`Plan::config`] and [`Plan::options`] build what [`crate::simulate`] runs.
//!
//! ```
//! use bead::plan::{Plan, PlanRequest};
//! use bead::scene::Scene;
//!
//! let text = "[world]\ngravity = [0.0, 0.0]\n[[particle]]\nname = \"p\"\nmass = 1.0\nposition = [0, 0]\nvelocity = [1, 0]\n\
//!             [run]\ndt = 0.01\nduration = 1\n";
//! let scene = Scene::parse(text, "free.toml", &[]).unwrap();
//! let plan = Plan::resolve(&scene, &PlanRequest::default()).unwrap();
//! assert_eq!((plan.dt, plan.steps), (0.01, 100));
//!
//! let asked = PlanRequest { steps: Some(5), ..PlanRequest::default() };
//! assert_eq!(Plan::resolve(&scene, &asked).unwrap().steps, 5);
//! ```

use crate::formulation::{Feedback, Method};
use crate::integrate::{IntegratorKind, IntegratorSettings};
use crate::readable;
use crate::scene::Scene;
use crate::simulate::{
    RunOptions, SimulationConfig, DEFAULT_EVENT_SAMPLES, MAX_EVENT_SAMPLES,
    RELATIVE_CONSTRAINT_TOLERANCE,
};

/// Step size when neither the request nor the scene give one (s).
pub const DEFAULT_DT: f64 = 1.0 / 60.0;
/// Simulated time when neither the request nor the scene give a duration or step count (s).
pub const DEFAULT_DURATION: f64 = 10.0;
/// Integrator when neither the request nor the scene name one.
pub const DEFAULT_INTEGRATOR: IntegratorKind = IntegratorKind::Rk4;
/// Most substeps a step may take (retried, or split for RATTLE's stability) when the request
/// does not say.
pub const DEFAULT_MAX_SUBSTEPS: u32 = 64;
/// More steps than 2^53 cannot be timed exactly (t = step * dt) and would not finish anyway.
const MAX_STEPS: f64 = 9_007_199_254_740_992.0;

/// What a front end asks for, each value optional: `None` leaves it to the scene's `[run]`
/// table, then to the defaults. Values are checked by [`Plan::resolve`], so a front end may
/// pass what its user typed unchecked.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlanRequest {
    /// Formulation; default: the scene's, else [`default_method`].
    pub method: Option<Method>,
    /// Integrator; default: the scene's, else [`DEFAULT_INTEGRATOR`].
    pub integrator: Option<IntegratorKind>,
    /// Step size (s), finite and > 0; default: the scene's, else [`DEFAULT_DT`].
    pub dt: Option<f64>,
    /// Simulated time (s), finite and > 0; not together with `steps`.
    pub duration: Option<f64>,
    /// Number of steps, 1 to 2^53; not together with `duration`.
    pub steps: Option<u64>,
    /// Record every K-th step, K >= 1; default 1.
    pub every: Option<u64>,
    /// Constraint feedback Cddot = -ks C - kd Cdot (implicit form), both finite and >= 0.
    pub stabilize: Option<Feedback>,
    /// Relative tolerance of the adaptive integrator, finite and > 0.
    pub rtol: Option<f64>,
    /// Absolute tolerance of the adaptive integrator, finite and >= 0.
    pub atol: Option<f64>,
    /// Project onto the constraints after every step (implicit form only).
    pub project: bool,
    /// Substeps per step of dt, >= 1; default 1.
    pub substeps: Option<u32>,
    /// Most substeps a step may take (retried, or split for RATTLE's stability), >= 1;
    /// default [`DEFAULT_MAX_SUBSTEPS`], and never fewer than `substeps`.
    pub max_substeps: Option<u32>,
    /// Interior times per step at which a stop condition is sampled, 0 to
    /// [`crate::simulate::MAX_EVENT_SAMPLES`]; default: the scene's, else
    /// [`crate::simulate::DEFAULT_EVENT_SAMPLES`].
    pub event_samples: Option<u32>,
}

/// Why a request and a scene do not make a plan.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// A requested value is out of range. `option` is the [`PlanRequest`] field's name; a front
    /// end words it as its users spell it (`--steps`, `steps=`).
    #[error("{option}={value}: {problem}")]
    Request {
        option: &'static str,
        /// The value as given, readable.
        value: String,
        /// What is wrong with it.
        problem: String,
    },
    /// duration / dt steps are more than 2^53 (or not a number).
    #[error(
        "duration {} with dt {} would take {} steps; at most 2^53 are allowed",
        readable(*duration),
        readable(*dt),
        readable(duration / dt)
    )]
    TooManySteps { duration: f64, dt: f64 },
    /// A `[run]` value of the scene that must be positive and finite is not.
    #[error(
        "the scene's [run] {key} must be positive and finite, got {}",
        readable(*value)
    )]
    SceneNotPositive { key: &'static str, value: f64 },
    /// The scene's `[run] steps = 0`.
    #[error("the scene's [run] steps must be at least 1, got 0")]
    SceneZeroSteps,
    /// The scene's `[run] stabilize` has a negative or non-finite gain.
    #[error(
        "the scene's [run] stabilize must be two finite numbers >= 0, got {}, {}",
        readable(feedback.ks),
        readable(feedback.kd)
    )]
    SceneStabilize { feedback: Feedback },
}

/// What to run, every value checked; shared by every method of a comparison.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// The formulation a single run uses (a comparison runs [`methods`] instead).
    pub method: Method,
    pub integrator: IntegratorKind,
    pub dt: f64,
    pub steps: u64,
    /// The requested duration when `steps` was derived from one.
    pub duration: Option<f64>,
    /// Whether duration/dt was not an integer, so that the last step is shorter than dt and
    /// the run ends exactly at the duration.
    pub last_step_shortened: bool,
    /// Feedback for the implicit form.
    pub feedback: Feedback,
    /// Whether the feedback was requested (not just set by the scene).
    pub feedback_requested: bool,
    /// Record every K-th step.
    pub every: u64,
    /// Integrator tolerances (the request's rtol and atol over the library defaults).
    pub settings: IntegratorSettings,
    /// Project onto the constraints after every step (implicit form only).
    pub project: bool,
    /// Substeps per step of dt.
    pub substeps: u32,
    /// The most substeps a step may take, retried or split for RATTLE's stability (at least
    /// `substeps`).
    pub max_substeps: u32,
    /// Interior times per step at which a stop condition is sampled.
    pub event_samples: u32,
}

impl Plan {
    /// Resolve `request` against `scene`'s `[run]` table and the defaults, checking every
    /// value. The number of steps is `steps` when given, else duration / dt when that is
    /// within 1e-9 (relative) of an integer, else rounded up with the last step shortened to
    /// end at the duration (see [`steps_for`]).
    pub fn resolve(scene: &Scene, request: &PlanRequest) -> Result<Plan, PlanError> {
        check_request(request)?;
        let run = &scene.run;
        let integrator = request
            .integrator
            .or(run.integrator)
            .unwrap_or(DEFAULT_INTEGRATOR);
        let dt = match request.dt {
            Some(dt) => dt,
            None => scene_positive("dt", run.dt)?.unwrap_or(DEFAULT_DT),
        };
        let (steps, duration, last_step_shortened) = match (request.steps, request.duration) {
            (Some(steps), _) => (steps, None, false),
            (None, Some(duration)) => steps_for(duration, dt)?,
            (None, None) => match (run.steps, scene_positive("duration", run.duration)?) {
                (Some(0), _) => return Err(PlanError::SceneZeroSteps),
                (Some(steps), _) => (steps, None, false),
                (None, Some(duration)) => steps_for(duration, dt)?,
                (None, None) => steps_for(DEFAULT_DURATION, dt)?,
            },
        };
        let (feedback, feedback_requested) = match (request.stabilize, run.stabilize) {
            (Some(f), _) => (f, true),
            (None, Some(f)) => {
                if !valid_feedback(f) {
                    return Err(PlanError::SceneStabilize { feedback: f });
                }
                (f, false)
            }
            (None, None) => (Feedback::default(), false),
        };
        let mut settings = IntegratorSettings::default();
        if let Some(rtol) = request.rtol {
            settings.rtol = rtol;
        }
        if let Some(atol) = request.atol {
            settings.atol = atol;
        }
        // rattle and projections: 1e-12 of each constraint's own scale, set by the
        // simulation (`scaled_constraint_tolerance`).
        settings.constraint_tolerance = RELATIVE_CONSTRAINT_TOLERANCE;
        let substeps = request.substeps.unwrap_or(1);
        Ok(Plan {
            method: run_method(scene, request.method),
            integrator,
            dt,
            steps,
            duration,
            last_step_shortened,
            feedback,
            feedback_requested,
            every: request.every.unwrap_or(1),
            settings,
            project: request.project,
            substeps,
            max_substeps: request
                .max_substeps
                .unwrap_or(DEFAULT_MAX_SUBSTEPS)
                .max(substeps),
            event_samples: request
                .event_samples
                .or(run.event_samples)
                .unwrap_or(DEFAULT_EVENT_SAMPLES),
        })
    }

    /// How long the run goes and how often it is recorded.
    pub fn options(&self) -> RunOptions {
        RunOptions {
            steps: self.steps,
            every: self.every,
            duration: self.duration.filter(|_| self.last_step_shortened),
        }
    }

    /// The simulation of `method` as planned. Feedback from the scene's `[run]` table applies
    /// to the implicit form only and is dropped for the parametric one (see
    /// [`Plan::ignores_scene_feedback`]); requested feedback or a projection is kept, so that
    /// the library's one legality check ([`SimulationConfig::check`]) refuses it with its own
    /// words.
    pub fn config(&self, method: Method) -> SimulationConfig {
        let feedback = match method {
            Method::Implicit => self.feedback,
            Method::Parametric if self.feedback_requested => self.feedback,
            Method::Parametric => Feedback::default(),
        };
        SimulationConfig {
            method,
            integrator: self.integrator,
            dt: self.dt,
            feedback,
            project: self.project,
            settings: self.settings,
            scaled_constraint_tolerance: true,
            substeps: self.substeps,
            max_substeps: self.max_substeps,
            track_work: None,
            event_samples: self.event_samples,
        }
    }

    /// Time at the end of a complete run from t = 0: steps * dt (the run loop computes t =
    /// step * dt), or the duration when the last step is shortened to end there.
    pub fn t_end(&self) -> f64 {
        self.options().output_time(0.0, self.steps, self.dt)
    }

    /// The length of the last step when it is shortened to end at the duration.
    pub fn last_step(&self) -> Option<f64> {
        let duration = self.duration.filter(|_| self.last_step_shortened)?;
        Some(duration - (self.steps - 1) as f64 * self.dt)
    }

    /// Whether the scene asks for feedback that a parametric run will not use (a front end
    /// says so).
    pub fn ignores_scene_feedback(&self, method: Method) -> bool {
        method == Method::Parametric
            && !self.feedback_requested
            && self.feedback != Feedback::default()
    }
}

/// The method of a single run: `requested`, else the scene's `[run]` method, else
/// [`default_method`]. Whether the scene has that form is the library's to say
/// ([`crate::simulate::Simulation::new`]), in the words every front end uses.
pub fn run_method(scene: &Scene, requested: Option<Method>) -> Method {
    requested
        .or(scene.run.method)
        .unwrap_or_else(|| default_method(scene))
}

/// The built-in default method of a scene: implicit when it has constraints or no parametric
/// form, else parametric.
pub fn default_method(scene: &Scene) -> Method {
    let system = &scene.system;
    if system.constraints().n_declared() == 0 && system.parametric().is_some() {
        Method::Parametric
    } else {
        Method::Implicit
    }
}

/// Every formulation the scene defines, in the order a comparison runs them: implicit when it
/// has a constraint or no parametric form; parametric when it has a parametric form.
pub fn methods(scene: &Scene) -> Vec<Method> {
    let system = &scene.system;
    let mut methods = Vec::new();
    if system.constraints().n_declared() > 0 || system.parametric().is_none() {
        methods.push(Method::Implicit);
    }
    if system.parametric().is_some() {
        methods.push(Method::Parametric);
    }
    methods
}

/// Steps covering `duration`: duration/dt when it is within 1e-9 (relative, for large counts)
/// of an integer, else rounded up, the last of them then shortened to end at the duration; at
/// least one. Returns (steps, Some(duration), whether the last step is shortened).
pub fn steps_for(duration: f64, dt: f64) -> Result<(u64, Option<f64>, bool), PlanError> {
    let ratio = duration / dt;
    if !ratio.is_finite() || ratio > MAX_STEPS {
        return Err(PlanError::TooManySteps { duration, dt });
    }
    let nearest = ratio.round();
    let (steps, shortened) = if (ratio - nearest).abs() <= 1e-9 * ratio.max(1.0) {
        (nearest, false)
    } else {
        (ratio.ceil(), true)
    };
    if steps < 1.0 {
        return Ok((1, Some(duration), true));
    }
    Ok((steps as u64, Some(duration), shortened))
}

/// Both gains finite and >= 0.
fn valid_feedback(f: Feedback) -> bool {
    f.ks.is_finite() && f.kd.is_finite() && f.ks >= 0.0 && f.kd >= 0.0
}

/// Every requested value in its range.
fn check_request(request: &PlanRequest) -> Result<(), PlanError> {
    let bad = |option: &'static str, value: String, problem: &str| PlanError::Request {
        option,
        value,
        problem: problem.to_string(),
    };
    let positive = |option: &'static str, value: Option<f64>| match value {
        Some(x) if !(x.is_finite() && x > 0.0) => {
            Err(bad(option, readable(x), "must be a finite number > 0"))
        }
        _ => Ok(()),
    };
    positive("dt", request.dt)?;
    positive("duration", request.duration)?;
    positive("rtol", request.rtol)?;
    if let Some(atol) = request.atol {
        if !(atol.is_finite() && atol >= 0.0) {
            return Err(bad("atol", readable(atol), "must be a finite number >= 0"));
        }
    }
    match (request.steps, request.duration) {
        (Some(_), Some(_)) => {
            return Err(bad(
                "steps",
                request.steps.unwrap_or_default().to_string(),
                "give steps or duration, not both",
            ))
        }
        (Some(0), None) => return Err(bad("steps", "0".into(), "must be at least 1")),
        (Some(steps), None) if steps > MAX_STEPS as u64 => {
            return Err(bad(
                "steps",
                steps.to_string(),
                "at most 2^53 steps are allowed (beyond, t = step * dt is no longer exact)",
            ))
        }
        _ => {}
    }
    if request.every == Some(0) {
        return Err(bad("every", "0".into(), "must be at least 1"));
    }
    if request.substeps == Some(0) {
        return Err(bad("substeps", "0".into(), "must be at least 1"));
    }
    if request.max_substeps == Some(0) {
        return Err(bad("max_substeps", "0".into(), "must be at least 1"));
    }
    if let Some(k) = request.event_samples {
        if k > MAX_EVENT_SAMPLES {
            return Err(PlanError::Request {
                option: "event_samples",
                value: k.to_string(),
                problem: format!("must be at most {MAX_EVENT_SAMPLES}"),
            });
        }
    }
    if let Some(f) = request.stabilize {
        if !valid_feedback(f) {
            return Err(bad(
                "stabilize",
                format!("{},{}", readable(f.ks), readable(f.kd)),
                "must be two finite numbers >= 0",
            ));
        }
    }
    Ok(())
}

/// A `[run]` value that must be positive and finite when present.
fn scene_positive(key: &'static str, value: Option<f64>) -> Result<Option<f64>, PlanError> {
    match value {
        Some(x) if !(x.is_finite() && x > 0.0) => {
            Err(PlanError::SceneNotPositive { key, value: x })
        }
        other => Ok(other),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FREE: &str = "[world]\ngravity = [0.0, 0.0]\n[[particle]]\nname = \"p\"\nmass = 1.0\nposition = [0, 0]\nvelocity = [1, 0]\n";

    fn scene(run: &str) -> Scene {
        Scene::parse(&format!("{FREE}{run}"), "free.toml", &[]).unwrap()
    }

    #[test]
    fn steps_round_when_duration_is_a_whole_number_of_steps() {
        assert_eq!(
            steps_for(10.0, 1.0 / 60.0).unwrap(),
            (600, Some(10.0), false)
        );
        assert_eq!(steps_for(1.0, 0.1).unwrap(), (10, Some(1.0), false));
    }

    /// 2^53 steps are allowed and 2^53 + 1 are not (which rounds to 2^53 as an f64).
    #[test]
    fn at_most_2_to_the_53_steps() {
        let with = |steps: u64| {
            let request = PlanRequest {
                steps: Some(steps),
                ..Default::default()
            };
            Plan::resolve(&scene(""), &request).map(|plan| plan.steps)
        };
        assert_eq!(with(1 << 53).unwrap(), 1 << 53);
        let error = with((1 << 53) + 1).unwrap_err().to_string();
        assert!(error.contains("at most 2^53 steps are allowed"), "{error}");
    }

    #[test]
    fn steps_round_up_otherwise() {
        assert_eq!(steps_for(1.0, 0.3).unwrap(), (4, Some(1.0), true));
        assert_eq!(steps_for(1e-12, 0.01).unwrap(), (1, Some(1e-12), true));
    }

    #[test]
    fn a_duration_off_the_grid_ends_exactly_there_with_a_shorter_last_step() {
        let plan = Plan::resolve(
            &scene("[run]\ndt = 0.3\nduration = 1.0\n"),
            &Default::default(),
        )
        .unwrap();
        assert_eq!((plan.steps, plan.t_end()), (4, 1.0));
        assert!((plan.last_step().unwrap() - 0.1).abs() < 1e-15);
        let options = plan.options();
        assert_eq!(options.output_time(0.0, 3, 0.3), 3.0 * 0.3);
        assert_eq!(options.output_time(0.0, 4, 0.3), 1.0);
        let whole = Plan::resolve(
            &scene("[run]\ndt = 0.25\nduration = 1.0\n"),
            &Default::default(),
        )
        .unwrap();
        assert_eq!(
            (whole.steps, whole.t_end(), whole.last_step()),
            (4, 1.0, None)
        );
        assert_eq!(whole.options().duration, None);
    }

    #[test]
    fn absurd_step_counts_are_errors() {
        assert!(matches!(
            steps_for(1e300, 1e-300),
            Err(PlanError::TooManySteps { .. })
        ));
    }

    #[test]
    fn request_overrides_scene_overrides_defaults() {
        let plain = Plan::resolve(&scene(""), &PlanRequest::default()).unwrap();
        assert_eq!(
            (plain.integrator, plain.dt, plain.steps, plain.every),
            (DEFAULT_INTEGRATOR, DEFAULT_DT, 600, 1)
        );
        assert_eq!((plain.substeps, plain.max_substeps), (1, 64));
        let with_run = scene("[run]\nintegrator = \"verlet\"\ndt = 0.5\nduration = 2\n");
        let from_scene = Plan::resolve(&with_run, &PlanRequest::default()).unwrap();
        assert_eq!(
            (from_scene.integrator, from_scene.dt, from_scene.steps),
            (IntegratorKind::Verlet, 0.5, 4)
        );
        let asked = PlanRequest {
            integrator: Some(IntegratorKind::Rk4),
            dt: Some(0.25),
            substeps: Some(100),
            ..PlanRequest::default()
        };
        let overridden = Plan::resolve(&with_run, &asked).unwrap();
        assert_eq!(
            (overridden.integrator, overridden.dt, overridden.steps),
            (IntegratorKind::Rk4, 0.25, 8)
        );
        assert_eq!((overridden.substeps, overridden.max_substeps), (100, 100));
    }

    #[test]
    fn bad_requested_values_are_named_errors() {
        let s = scene("");
        let cases = [
            (
                PlanRequest {
                    dt: Some(-1.0),
                    ..PlanRequest::default()
                },
                "dt=-1: must be a finite number > 0",
            ),
            (
                PlanRequest {
                    duration: Some(f64::NAN),
                    ..PlanRequest::default()
                },
                "duration=NaN: must be a finite number > 0",
            ),
            (
                PlanRequest {
                    steps: Some(0),
                    ..PlanRequest::default()
                },
                "steps=0: must be at least 1",
            ),
            (
                PlanRequest {
                    steps: Some(3),
                    duration: Some(1.0),
                    ..PlanRequest::default()
                },
                "steps=3: give steps or duration, not both",
            ),
            (
                PlanRequest {
                    every: Some(0),
                    ..PlanRequest::default()
                },
                "every=0: must be at least 1",
            ),
            (
                PlanRequest {
                    atol: Some(-1e-3),
                    ..PlanRequest::default()
                },
                "atol=-0.001: must be a finite number >= 0",
            ),
            (
                PlanRequest {
                    stabilize: Some(Feedback { ks: -1.0, kd: 0.0 }),
                    ..PlanRequest::default()
                },
                "stabilize=-1,0: must be two finite numbers >= 0",
            ),
        ];
        for (request, message) in cases {
            let error = Plan::resolve(&s, &request).unwrap_err();
            assert!(matches!(error, PlanError::Request { .. }), "{error:?}");
            assert_eq!(error.to_string(), message);
        }
    }

    #[test]
    fn bad_scene_values_are_errors() {
        // The loader refuses these; a scene built in code can still hold them.
        let mut zero = scene("");
        zero.run.steps = Some(0);
        let refused = Plan::resolve(&zero, &PlanRequest::default());
        assert_eq!(refused.unwrap_err(), PlanError::SceneZeroSteps);
        // A request that sets the value makes the scene's value irrelevant.
        let asked = PlanRequest {
            steps: Some(2),
            ..PlanRequest::default()
        };
        assert_eq!(Plan::resolve(&zero, &asked).unwrap().steps, 2);
        let mut negative = scene("");
        negative.run.dt = Some(-0.5);
        assert_eq!(
            Plan::resolve(&negative, &PlanRequest::default())
                .unwrap_err()
                .to_string(),
            "the scene's [run] dt must be positive and finite, got -0.5"
        );
    }
}
