//! `bead compare`: every formulation of a scene with the same integrator and dt.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use bead::formulation::{Feedback, Method};

use super::{
    json, load_scene, print, report_error, run_method, stop_when, warn_implicit_only, write_file,
    Trace,
};
use crate::args::CompareArgs;
use crate::outputs::Files;
use crate::plan::{self, compare_methods};
use crate::report;

/// `bead compare`: run every formulation of the scene and print them side by side.
pub fn compare(args: &CompareArgs) -> Result<()> {
    if args.grid.integrators.is_some() || args.grid.dts.is_some() || args.grid.report.is_some() {
        return super::grid::compare_grid(args);
    }
    let scene = load_scene(&args.scene, &args.sim.set)?;
    let plan = plan::resolve(&scene, &args.sim, None)?;
    let stop_when = stop_when(&scene, &args.sim)?;
    let methods = compare_methods(&scene);
    warn_implicit_only(&plan, &methods);
    let mut files = Files::new();
    files.input("the scene file", &args.scene);
    if let Some(trace) = &args.trace {
        for &method in &methods {
            files.derived("--trace", trace, &trace_path(trace, method), None);
        }
    }
    if let Some(summary) = &args.output.summary {
        files.output("--summary", summary);
    }
    files.check()?;
    let mut summaries = Vec::new();
    let mut failures = Vec::new();
    for &method in &methods {
        let trace = args.trace.as_deref().map(|path| trace_path(path, method));
        // --stabilize, the scene's stabilize and --project apply to the implicit run only.
        let mut config = plan.config(method);
        if method == Method::Parametric {
            config.feedback = Feedback::default();
            config.project = false;
        }
        let trace = Trace::at(trace.as_deref(), args.constraint_forces);
        let outcome = run_method(&scene, &plan, config, stop_when.as_ref(), trace)?;
        if let Err(failure) = &outcome.result {
            failures.push(format!("{}: {}", method.name(), failure.error));
        }
        summaries.push(outcome.summary);
    }
    let summary_json = json(&summaries)?;
    if let Some(path) = &args.output.summary {
        write_file(path, &summary_json)?;
    }
    let printed = if args.output.json {
        print(&summary_json)
    } else {
        print(&report::compare_text(&scene, &plan, &summaries))
    };
    // Failed runs are the errors to report, even when stdout is gone.
    match failures.split_last() {
        None => printed,
        Some((last, others)) => {
            for failure in others {
                report_error(failure);
            }
            bail!("{last}")
        }
    }
}

/// `trace.csv` -> `trace.implicit.csv`; `trace` -> `trace.implicit`.
fn trace_path(path: &Path, method: Method) -> PathBuf {
    let mut name = OsString::new();
    match (path.file_stem(), path.extension()) {
        (Some(stem), Some(extension)) => {
            name.push(stem);
            name.push(".");
            name.push(method.name());
            name.push(".");
            name.push(extension);
        }
        (Some(stem), None) => {
            name.push(stem);
            name.push(".");
            name.push(method.name());
        }
        (None, _) => name.push(format!("trace.{}.csv", method.name())),
    }
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trace_names_insert_the_method_before_the_extension() {
        assert_eq!(
            trace_path(Path::new("out/t.csv"), Method::Implicit),
            PathBuf::from("out/t.implicit.csv")
        );
        assert_eq!(
            trace_path(Path::new("t"), Method::Parametric),
            PathBuf::from("t.parametric")
        );
        assert_eq!(
            trace_path(Path::new("a.b.csv"), Method::Parametric),
            PathBuf::from("a.b.parametric.csv")
        );
    }
}
