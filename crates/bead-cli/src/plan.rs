//! Flags meet the scene: the command line overrides the scene's `[run]` table, which
//! overrides the built-in defaults. The result is a [`Plan`] with every value checked.

use anyhow::{bail, Result};
use bead::formulation::{Feedback, Method};
use bead::integrate::{IntegratorKind, IntegratorSettings};
use bead::scene::Scene;
use bead::simulate::{RunOptions, SimulationConfig};

use crate::args::SimArgs;
use crate::report::exact;

/// Step size when neither the flags nor the scene give one (s).
pub const DEFAULT_DT: f64 = 1.0 / 60.0;
/// Simulated time when neither the flags nor the scene give a duration or step count (s).
pub const DEFAULT_DURATION: f64 = 10.0;
/// Integrator when neither the flags nor the scene name one.
pub const DEFAULT_INTEGRATOR: IntegratorKind = IntegratorKind::Rk4;
/// More steps than this cannot be timed exactly (t = step * dt) and would not finish anyway.
const MAX_STEPS: f64 = 9_007_199_254_740_992.0; // 2^53

/// What to run, shared by every method of a `compare`.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub integrator: IntegratorKind,
    pub dt: f64,
    pub steps: u64,
    /// The requested duration when `steps` was derived from one.
    pub duration: Option<f64>,
    /// Whether duration/dt was not an integer, so that the run ends after the duration.
    pub overshoot: bool,
    /// Feedback for the implicit form.
    pub feedback: Feedback,
    /// Whether the feedback was asked for on the command line (not just by the scene).
    pub feedback_from_flags: bool,
    /// Record every K-th step.
    pub every: u64,
    /// Integrator tolerances (--rtol, --atol over the library defaults).
    pub settings: IntegratorSettings,
    /// Project onto the constraints after every step (--project; implicit form only).
    pub project: bool,
    /// Substeps per step of dt (--substeps) and the most a retried step may take
    /// (--max-substeps).
    pub substeps: u32,
    pub max_substeps: u32,
}

impl Plan {
    /// Resolve the flags against `scene`.
    pub fn resolve(scene: &Scene, sim: &SimArgs) -> Result<Plan> {
        let run = &scene.run;
        let integrator = sim
            .integrator
            .map(|i| i.0)
            .or(run.integrator)
            .unwrap_or(DEFAULT_INTEGRATOR);
        let dt = match sim.dt {
            Some(dt) => dt,
            None => scene_positive("dt", run.dt)?.unwrap_or(DEFAULT_DT),
        };
        let (steps, duration, overshoot) = match (sim.steps, sim.duration) {
            (Some(steps), _) if steps as f64 > MAX_STEPS => {
                bail!("--steps {steps}: at most 2^53 steps are allowed (beyond, t = step * dt is no longer exact)")
            }
            (Some(steps), _) => (steps, None, false),
            (None, Some(duration)) => steps_for(duration, dt)?,
            (None, None) => match (run.steps, scene_positive("duration", run.duration)?) {
                (Some(0), _) => bail!("the scene's [run] steps must be at least 1, got 0"),
                (Some(steps), _) => (steps, None, false),
                (None, Some(duration)) => steps_for(duration, dt)?,
                (None, None) => steps_for(DEFAULT_DURATION, dt)?,
            },
        };
        let (feedback, feedback_from_flags) = match (sim.stabilize, run.stabilize) {
            (Some(f), _) => (f, true),
            (None, Some(f)) => {
                if !(f.ks.is_finite() && f.kd.is_finite() && f.ks >= 0.0 && f.kd >= 0.0) {
                    bail!(
                        "the scene's [run] stabilize must be two finite numbers >= 0, got {}, {}",
                        exact(f.ks),
                        exact(f.kd)
                    );
                }
                (f, false)
            }
            (None, None) => (Feedback::default(), false),
        };
        Ok(Plan {
            integrator,
            dt,
            steps,
            duration,
            overshoot,
            feedback,
            feedback_from_flags,
            every: sim.every,
            settings: {
                let mut settings = IntegratorSettings::default();
                if let Some(rtol) = sim.rtol {
                    settings.rtol = rtol;
                }
                if let Some(atol) = sim.atol {
                    settings.atol = atol;
                }
                // rattle and --project: 1e-12 of each constraint's own scale, set by the
                // simulation (`scaled_constraint_tolerance`).
                settings.constraint_tolerance = bead::simulate::RELATIVE_CONSTRAINT_TOLERANCE;
                settings
            },
            project: sim.project,
            substeps: sim.substeps,
            max_substeps: sim.max_substeps.max(sim.substeps),
        })
    }

    /// How long the run goes and how often it is recorded.
    pub fn options(&self) -> RunOptions {
        RunOptions {
            steps: self.steps,
            every: self.every,
        }
    }

    /// The simulation of `method` as planned. Feedback from the scene's `[run]` table applies
    /// to the implicit form only and is dropped for the parametric one (the caller warns);
    /// feedback or a projection asked for on the command line is kept, so that the library's
    /// one legality check ([`SimulationConfig::check`]) refuses it with its own words.
    pub fn config(&self, method: Method) -> SimulationConfig {
        let feedback = match method {
            Method::Implicit => self.feedback,
            Method::Parametric if self.feedback_from_flags => self.feedback,
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
        }
    }

    /// Time at the end of a complete run (the run loop computes t = step * dt).
    pub fn t_end(&self) -> f64 {
        self.steps as f64 * self.dt
    }

    /// Whether the scene asks for feedback that a parametric run will not use.
    pub fn ignores_scene_feedback(&self, method: Method) -> bool {
        method == Method::Parametric
            && !self.feedback_from_flags
            && self.feedback != Feedback::default()
    }
}

/// The method of `bead run`: the flag, else the scene's `[run]` method, else implicit when the
/// scene has constraints or no parametric form, else parametric. Whether the scene has that
/// form is the library's to say (`Simulation::new`), in the words every front end uses.
pub fn run_method(scene: &Scene, flag: Option<Method>) -> Result<Method> {
    Ok(match (flag, scene.run.method) {
        (Some(m), _) | (None, Some(m)) => m,
        (None, None) => default_method(scene),
    })
}

/// The built-in default method of a scene.
pub fn default_method(scene: &Scene) -> Method {
    let system = &scene.system;
    if system.constraints().infos().is_empty() && system.parametric().is_some() {
        Method::Parametric
    } else {
        Method::Implicit
    }
}

/// Every formulation the scene defines, for `bead compare`: implicit when it has a constraint
/// or no parametric form; parametric when it has a parametric form.
pub fn compare_methods(scene: &Scene) -> Vec<Method> {
    let system = &scene.system;
    let mut methods = Vec::new();
    if !system.constraints().infos().is_empty() || system.parametric().is_none() {
        methods.push(Method::Implicit);
    }
    if system.parametric().is_some() {
        methods.push(Method::Parametric);
    }
    methods
}

/// A `[run]` value that must be positive and finite when present.
fn scene_positive(what: &str, value: Option<f64>) -> Result<Option<f64>> {
    match value {
        Some(x) if !(x.is_finite() && x > 0.0) => {
            bail!(
                "the scene's [run] {what} must be positive and finite, got {}",
                exact(x)
            )
        }
        other => Ok(other),
    }
}

/// Steps covering `duration`: duration/dt when it is within 1e-9 (relative, for large counts)
/// of an integer, else rounded up; at least one. Returns (steps, Some(duration), overshoot).
pub fn steps_for(duration: f64, dt: f64) -> Result<(u64, Option<f64>, bool)> {
    let ratio = duration / dt;
    if !ratio.is_finite() || ratio > MAX_STEPS {
        bail!(
            "duration {} with dt {} would take {} steps; at most 2^53 are allowed",
            exact(duration),
            exact(dt),
            exact(ratio)
        );
    }
    let nearest = ratio.round();
    let (steps, overshoot) = if (ratio - nearest).abs() <= 1e-9 * ratio.max(1.0) {
        (nearest, false)
    } else {
        (ratio.ceil(), true)
    };
    if steps < 1.0 {
        return Ok((1, Some(duration), true));
    }
    Ok((steps as u64, Some(duration), overshoot))
}

#[cfg(test)]
mod tests {
    use super::steps_for;

    #[test]
    fn steps_round_when_duration_is_a_whole_number_of_steps() {
        assert_eq!(
            steps_for(10.0, 1.0 / 60.0).unwrap(),
            (600, Some(10.0), false)
        );
        assert_eq!(steps_for(1.0, 0.1).unwrap(), (10, Some(1.0), false));
    }

    #[test]
    fn steps_round_up_otherwise() {
        assert_eq!(steps_for(1.0, 0.3).unwrap(), (4, Some(1.0), true));
        assert_eq!(steps_for(1e-12, 0.01).unwrap(), (1, Some(1e-12), true));
    }

    #[test]
    fn absurd_step_counts_are_errors() {
        assert!(steps_for(1e300, 1e-300).is_err());
    }
}
