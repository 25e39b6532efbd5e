//! Flags meet the scene: the command-line flags become a [`PlanRequest`], which the library
//! resolves against the scene's `[run]` table and the defaults ([`bead::plan`]). Only the
//! spelling of the flags is the CLI's own.

use anyhow::{anyhow, Result};
use bead::formulation::Method;
use bead::plan::{PlanError, PlanRequest};
use bead::scene::Scene;

pub use bead::plan::{methods as compare_methods, steps_for, Plan};

use crate::args::SimArgs;

/// The request the flags make; `method` is `bead run`'s `--method` (None for the commands
/// that run every method).
pub fn request(sim: &SimArgs, method: Option<Method>) -> PlanRequest {
    PlanRequest {
        method,
        integrator: sim.integrator.map(|i| i.0),
        dt: sim.dt,
        duration: sim.duration,
        steps: sim.steps,
        every: Some(sim.every),
        stabilize: sim.stabilize,
        rtol: sim.rtol,
        atol: sim.atol,
        project: sim.project,
        substeps: Some(sim.substeps),
        max_substeps: Some(sim.max_substeps),
        event_samples: sim.event_samples,
    }
}

/// Resolve the flags against `scene`; an out-of-range value is named by its flag.
pub fn resolve(scene: &Scene, sim: &SimArgs, method: Option<Method>) -> Result<Plan> {
    Plan::resolve(scene, &request(sim, method)).map_err(|e| match e {
        PlanError::Request {
            option,
            value,
            problem,
        } => anyhow!("--{} {value}: {problem}", option.replace('_', "-")),
        other => other.into(),
    })
}
