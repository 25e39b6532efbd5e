//! `bead check`: validate a scene, describe it, and start each of its formulations as
//! `bead run` would, without stepping.

use std::sync::Arc;

use anyhow::{bail, Result};
use bead::scene::Scene;
use bead::simulate::Simulation;

use super::{load_scene, print, report_error};
use crate::args::{CheckArgs, SimArgs};
use crate::plan::{self, compare_methods};
use crate::report::{self, StartCheck};

/// `bead check`: load (which validates) and describe the scene, then report every reason
/// `bead run` would refuse it at t = 0 (exit code 1).
pub fn check(args: &CheckArgs) -> Result<()> {
    let scene = load_scene(&args.scene, &args.set)?;
    let start = start(&scene);
    print(&report::check_text(&scene, &start))?;
    match start.errors().split_last() {
        None => Ok(()),
        Some((last, others)) => {
            for error in others {
                report_error(error);
            }
            bail!("{last}")
        }
    }
}

/// Start every formulation the scene has (implicit when it has constraints or no parametric
/// form, parametric when it has one) with the scene's `[run]` settings resolved as `bead run`
/// resolves them. The library decides what can start ([`Simulation::new`]).
fn start(scene: &Scene) -> StartCheck {
    let plan = plan::resolve(scene, &SimArgs::none(), None).map_err(|e| format!("{e:#}"));
    let forms = match &plan {
        Ok(plan) => compare_methods(scene)
            .into_iter()
            .map(|method| {
                let started = Simulation::new(Arc::clone(&scene.system), plan.config(method));
                (method, started.map(drop))
            })
            .collect(),
        Err(_) => Vec::new(),
    };
    StartCheck {
        plan,
        forms,
        run_method: bead::plan::run_method(scene, None),
    }
}
