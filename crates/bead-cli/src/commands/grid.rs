//! `bead compare` over a grid: every formulation x integrator x dt, with the table and the
//! optional HTML report (`--integrators`, `--dts`, `--report`).

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Result};
use bead::formulation::{Feedback, Method};
use bead::integrate::IntegratorKind;
use bead::simulate::{Sample, Sink};
use bead_report::report::{
    report_files, shell_command, write_report, Recorder, Report, ReportRun, SceneStatement,
};

use super::{
    json, load_scene, print, report_error, run_method_with, stop_when, warn_implicit_only,
    write_file, Trace,
};
use crate::args::CompareArgs;
use crate::outputs::Files;
use crate::plan::{self, compare_methods, steps_for};
use crate::report::{energy_note, exact, integrator_text, table, title, ADAPTIVE_NOTE};

/// Two sinks fed the same samples.
pub struct Tee<'a>(pub &'a mut dyn Sink, pub &'a mut dyn Sink);

impl Sink for Tee<'_> {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.0.record(sample)?;
        self.1.record(sample)
    }
    fn finish(&mut self) -> std::io::Result<()> {
        let first = self.0.finish();
        let second = self.1.finish();
        first.and(second)
    }
    fn discards(&self) -> bool {
        self.0.discards() && self.1.discards()
    }
}

/// `bead compare` with `--integrators`, `--dts` or `--report`.
pub fn compare_grid(args: &CompareArgs) -> Result<()> {
    let scene = load_scene(&args.scene, &args.sim.set)?;
    let plan = plan::resolve(&scene, &args.sim, None)?;
    let stop_when = stop_when(&scene, &args.sim)?;
    let integrators = match &args.grid.integrators {
        Some(list) => list.0.clone(),
        None => vec![plan.integrator],
    };
    let dts = match &args.grid.dts {
        Some(list) => list.0.clone(),
        None => vec![(exact(plan.dt), plan.dt)],
    };
    // The adaptive integrator runs once per tolerance (it chooses its own steps); a list of
    // tolerances without it would do nothing, which is refused.
    let rtols: Option<Vec<(String, f64)>> = args.grid.rtols.as_ref().map(|l| l.0.clone());
    if rtols.is_some() && !integrators.iter().any(|k| k.is_adaptive()) {
        bail!(
            "--rtols sets the tolerances of the adaptive integrator (dopri5), which is not among the integrators compared; add it with --integrators"
        );
    }
    // Every dt covers the same time: the requested duration, else the planned run's.
    let duration = plan.duration.unwrap_or_else(|| plan.t_end());
    let methods = compare_methods(&scene);
    warn_implicit_only(&plan, &methods);
    let mut runs = Vec::new();
    let mut summaries = Vec::new();
    let mut skipped = Vec::new();
    let mut failures = Vec::new();
    // --project applies to the implicit form only; on a grid the implicit form then runs
    // both without and with the projection, so that the table shows what it changes.
    let mut variants = Vec::new();
    for &method in &methods {
        variants.push((method, false));
        if plan.project && method == Method::Implicit {
            variants.push((method, true));
        }
    }
    // Which combinations run (the others are skipped, with the reason).
    let mut combinations = Vec::new();
    for &(method, project) in &variants {
        for &integrator in &integrators {
            let mut combination = plan.clone();
            combination.integrator = integrator;
            combination.project = project;
            let mut config = combination.config(method);
            if method == Method::Parametric {
                // --stabilize and the scene's stabilize apply to the implicit runs only.
                config.feedback = Feedback::default();
            }
            if let Err(reason) = config.check(&scene.system) {
                let name = if project {
                    format!("{}+project", method.name())
                } else {
                    method.name().to_string()
                };
                skipped.push(format!("{name} x {}: {reason}", integrator.name()));
                continue;
            }
            combinations.push((method, project, integrator, combination, config));
        }
    }
    let trace_of = |method: Method, project: bool, integrator: IntegratorKind, label: &str| {
        args.trace.as_deref().map(|path| {
            trace_path(
                path,
                &format!(
                    "{}{}.{}.{}",
                    method.name(),
                    if project { "-project" } else { "" },
                    integrator.name(),
                    file_label(label)
                ),
            )
        })
    };
    // No output may overwrite another, or the scene, before anything runs.
    let mut files = Files::new();
    files.input("the scene file", &args.scene);
    for &(method, project, integrator, _, _) in &combinations {
        for (label, _, rtol) in runs_of(integrator, &dts, &rtols, plan.settings.rtol) {
            let tag = run_tag(&label, rtol.as_ref());
            if let (Some(given), Some(path)) =
                (&args.trace, trace_of(method, project, integrator, &tag))
            {
                let run = format!(
                    "{}{} {} {}",
                    method.name(),
                    if project { "+project" } else { "" },
                    integrator.name(),
                    tag.replacen("dt", "dt ", 1).replacen("rtol", "rtol ", 1)
                );
                files.derived("--trace", given, &path, Some(&run));
            }
        }
    }
    if let Some(summary) = &args.output.summary {
        files.output("--summary", summary);
    }
    if let Some(dir) = &args.grid.report {
        files.output("--report", dir);
        for file in report_files(dir) {
            files.derived("--report", dir, &file, None);
        }
    }
    files.check()?;
    for (method, project, integrator, combination, config) in combinations {
        for (dt_label, dt, rtol) in runs_of(integrator, &dts, &rtols, plan.settings.rtol) {
            let mut planned = combination.clone();
            if args.grid.dts.is_some() {
                let (steps, _, shortened) = steps_for(duration, dt)?;
                planned.dt = dt;
                planned.steps = steps;
                planned.last_step_shortened = shortened;
            }
            let trace = trace_of(
                method,
                project,
                integrator,
                &run_tag(&dt_label, rtol.as_ref()),
            );
            let mut recorder =
                Recorder::new(Arc::clone(&scene.system), (args.grid.points / 2) as usize);
            let mut config = config;
            config.dt = planned.dt;
            if let Some((_, rtol)) = &rtol {
                config.settings.rtol = *rtol;
                planned.settings.rtol = *rtol;
            }
            let outcome = run_method_with(
                &scene,
                &planned,
                config,
                stop_when.as_ref(),
                Trace::at(trace.as_deref(), args.constraint_forces),
                Some(&mut recorder),
            )?;
            let (stats, error) = match &outcome.result {
                Ok(stats) => (stats.clone(), None),
                Err(failure) => (*failure.stats.clone(), Some(failure.error.to_string())),
            };
            let run = ReportRun {
                method,
                projected: planned.project,
                integrator,
                dt,
                dt_label: dt_label.clone(),
                rtol: rtol.map(|(_, rtol)| rtol),
                stats,
                error,
                recording: recorder.recording(),
            };
            if let Some(error) = &run.error {
                failures.push(format!("{}: {error}", run.label()));
            }
            runs.push(run);
            summaries.push(outcome.summary);
        }
    }
    let mut description = format!("scene {}; t = 0 to {} s", scene.file, exact(duration));
    if args.grid.integrators.is_none() {
        description.push_str(&format!(
            "; integrator {}",
            integrator_text(plan.integrator)
        ));
    }
    let implicit = methods.contains(&Method::Implicit);
    if implicit && plan.feedback != Feedback::default() {
        description.push_str(&format!(
            "; implicit form stabilized with ks = {}, kd = {}",
            exact(plan.feedback.ks),
            exact(plan.feedback.kd)
        ));
    }
    if implicit && plan.project {
        description.push_str(
            "; implicit+project: the implicit form projected onto its constraints after every step (--project)",
        );
    }
    let report = Report {
        title: title(&scene).to_string(),
        description,
        system: Arc::clone(&scene.system),
        runs,
        skipped,
        // The command as typed (the program as `bead`), so that the report reproduces itself.
        scene: Some(SceneStatement::of(
            &scene,
            shell_command(std::iter::once("bead".to_string()).chain(std::env::args().skip(1))),
        )),
    };
    let summary_json = json(&summaries)?;
    if let Some(path) = &args.output.summary {
        write_file(path, &summary_json)?;
    }
    let written = match &args.grid.report {
        Some(dir) => Some(write_report(&report, dir)?),
        None => None,
    };
    let printed = if args.output.json {
        for s in &report.skipped {
            report_error(&format!("skipped: {s}"));
        }
        print(&summary_json)
    } else {
        let mut text = format!("{}\n  {}\n\n", report.title, report.description);
        text.push_str(&table(&report.rows()));
        text.push_str(&energy_note(&summaries));
        if report.runs.iter().any(|r| r.stats.accepted_steps.is_some()) {
            text.push_str(ADAPTIVE_NOTE);
            text.push('\n');
        }
        for s in &report.skipped {
            text.push_str(&format!("skipped: {s}\n"));
        }
        if let Some(files) = &written {
            text.push_str(&format!("report: {}\n", files.html.display()));
        }
        print(&text)
    };
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

/// One run of an integrator on the grid: dt as written, dt, and for the adaptive integrator
/// its relative tolerance (as written, value).
type GridRun = (String, f64, Option<(String, f64)>);

/// The runs of one integrator on the grid: (dt label, dt, tolerance). A fixed-step integrator
/// runs once per dt; the adaptive one once per tolerance (`rtols`, else once at `plan_rtol`),
/// with the smallest dt as its output interval, so that its recording is as fine as the
/// finest fixed-step run's.
fn runs_of(
    integrator: IntegratorKind,
    dts: &[(String, f64)],
    rtols: &Option<Vec<(String, f64)>>,
    plan_rtol: f64,
) -> Vec<GridRun> {
    if !integrator.is_adaptive() {
        return dts.iter().map(|(l, dt)| (l.clone(), *dt, None)).collect();
    }
    let finest = dts
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .cloned()
        .expect("at least one dt");
    match rtols {
        None => vec![(finest.0, finest.1, Some((exact(plan_rtol), plan_rtol)))],
        Some(list) => list
            .iter()
            .map(|r| (finest.0.clone(), finest.1, Some(r.clone())))
            .collect(),
    }
}

/// A run's part of a trace file name: `dt1/60`, or `rtol1e-9` for a tolerance.
fn run_tag(dt_label: &str, rtol: Option<&(String, f64)>) -> String {
    match rtol {
        Some((label, _)) => format!("rtol{label}"),
        None => format!("dt{dt_label}"),
    }
}

/// A dt as given (`1/60`, `2*pi/100`) as part of a file name: `1_60`, `2_pi_100`.
fn file_label(label: &str) -> String {
    label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '+') {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// `trace.csv` -> `trace.TAG.csv`.
fn trace_path(path: &Path, tag: &str) -> PathBuf {
    let mut name = OsString::new();
    match (path.file_stem(), path.extension()) {
        (Some(stem), Some(extension)) => {
            name.push(stem);
            name.push(format!(".{tag}."));
            name.push(extension);
        }
        (Some(stem), None) => {
            name.push(stem);
            name.push(format!(".{tag}"));
        }
        (None, _) => name.push(format!("trace.{tag}.csv")),
    }
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dt_labels_become_file_name_parts() {
        assert_eq!(file_label("1/60"), "1_60");
        assert_eq!(file_label("2*pi/100"), "2_pi_100");
        assert_eq!(file_label("1e-3"), "1e-3");
        assert_eq!(file_label("atan2(1, 2)"), "atan2_1__2_");
    }
}
