//! `bead run`: one formulation, a summary, optionally a trace and a JSON summary.

use anyhow::{bail, Result};

use super::{json, load_scene, print, run_method, stop_when, warn, write_file, Trace};
use crate::args::RunArgs;
use crate::outputs::Files;
use crate::plan;
use crate::report;

/// `bead run`: resolve the method and plan, run, write the trace and summary, report.
pub fn run(args: &RunArgs) -> Result<()> {
    let mut files = Files::new();
    files.input("the scene file", &args.scene);
    if let Some(trace) = &args.trace {
        files.output("--trace", trace);
    }
    if let Some(summary) = &args.output.summary {
        files.output("--summary", summary);
    }
    files.check()?;
    let scene = load_scene(&args.scene, &args.sim.set)?;
    let plan = plan::resolve(&scene, &args.sim, args.method.map(|m| m.0))?;
    let method = plan.method;
    let stop_when = stop_when(&scene, &args.sim)?;
    if plan.ignores_scene_feedback(method) {
        warn("the scene's [run] stabilize applies only to the implicit form; not used for this parametric run");
    }
    let outcome = run_method(
        &scene,
        &plan,
        plan.config(method),
        stop_when.as_ref(),
        Trace::at(args.trace.as_deref(), args.constraint_forces),
    )?;
    let summary_json = json(&outcome.summary)?;
    if let Some(path) = &args.output.summary {
        write_file(path, &summary_json)?;
    }
    let printed = if args.output.json {
        print(&summary_json)
    } else {
        print(&report::run_text(&scene, &plan, &outcome.summary))
    };
    // A failed run is the error to report, even when stdout is gone.
    match outcome.result {
        Ok(_) => printed,
        Err(failure) => bail!("{}", failure.error),
    }
}
