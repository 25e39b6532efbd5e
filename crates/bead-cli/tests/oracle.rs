//! The oracle through the `bead` binary: `run --trace` rows, the `--json` summary, `compare`
//! and `sweep`, for every system, method and integrator of the oracle suite, against
//! answers bead did not compute and, bit for bit, against the library's run.

mod common;

use std::path::Path;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead_oracle::harness::each;
use bead_oracle::rows::{check_consistent, error};
use bead_oracle::summary::check_summary;
use bead_oracle::{checks, listing, matrix, Row, Spec, System};
use common::{bead_in, ok, TempDir};
use serde_json::Value;

fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 path")
}

/// The summary's numbers without the two that depend on the clock.
fn timeless(mut summary: Value) -> Value {
    if let Some(map) = summary.as_object_mut() {
        map.remove("wall_seconds");
        map.remove("steps_per_second");
        map.remove("scene");
    }
    summary
}

/// `bead run SCENE FLAGS --trace T --json`: (rows, summary).
fn run_cli(spec: &Spec, extra: &[&str]) -> (Vec<Row>, Value) {
    let dir = TempDir::new("oracle");
    let trace = dir.path("trace.csv");
    let scene = spec.scene_path();
    let mut args: Vec<String> = vec!["run".into(), p(&scene).into()];
    args.extend(spec.cli_flags());
    args.extend(["--trace".into(), p(&trace).into(), "--json".into()]);
    args.extend(extra.iter().map(|s| s.to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = ok(bead_in(&dir.0, &args));
    let summary: Value = serde_json::from_str(&out).expect("the summary is JSON");
    let text = std::fs::read_to_string(&trace).expect("the trace");
    (Row::parse_trace(&text, spec.system.dim), summary)
}

/// (a), (b), (c) of `bead run`'s trace and summary for `spec`.
fn check_run(spec: &Spec) {
    let what = format!("bead run {}", spec.label());
    let (rows, summary) = run_cli(spec, &[]);
    let library = spec.run();
    assert_eq!(rows.len(), library.rows.len(), "{what}: rows");
    for (i, (row, lib)) in rows.iter().zip(&library.rows).enumerate() {
        assert!(
            row.same_bits(lib),
            "{what}: trace row {i} is {row:?}, the library's {lib:?}"
        );
        check_consistent(
            spec.system,
            row,
            spec.method == Method::Parametric,
            &format!("{what}, trace row {i}"),
        );
    }
    let expected = serde_json::to_value(&library.summary).expect("summary");
    assert_eq!(
        timeless(summary.clone()),
        timeless(expected),
        "{what}: the --json summary differs from the library's"
    );
    check_summary(spec, &summary, &rows, spec.system.particles, &what);
    checks::against_reference(spec, &rows, &what);
}

#[test]
fn run_trace_and_json_meet_the_oracle() {
    let cases = listing::cases_for("cli-trace");
    assert_eq!(cases.len(), listing::cases_for("cli-json").len());
    each("bead run --trace --json", &cases, Spec::label, check_run);
}

#[test]
fn run_stops_at_the_reference_event() {
    let cases: Vec<Spec> = listing::cases_for("cli-trace")
        .into_iter()
        .map(Spec::with_event)
        .collect();
    each("bead run --stop-when", &cases, Spec::label, check_run);
}

#[test]
fn run_dopri5_with_steps_longer_and_shorter_than_the_output_interval() {
    let mut cases = Vec::new();
    for system in System::all() {
        for method in matrix::METHODS {
            for (rtol, dt) in [(1e-6, 1e-3), (1e-12, 0.25)] {
                let mut spec = Spec::new(system, method, IntegratorKind::Dopri5, dt, 1.0);
                spec.rtol = Some(rtol);
                cases.push(spec);
            }
        }
    }
    each("bead run dopri5 intervals", &cases, Spec::label, check_run);
}

#[test]
fn run_with_substeps_is_the_library_run() {
    let cases: Vec<Spec> = listing::cases_for("cli-trace")
        .into_iter()
        .filter(|s| !s.integrator.is_adaptive())
        .map(|mut s| {
            s.substeps = Some(2);
            s
        })
        .collect();
    each("bead run --substeps 2", &cases, Spec::label, |spec| {
        let what = format!("bead run {}", spec.label());
        let (rows, summary) = run_cli(spec, &[]);
        let library = spec.run();
        assert!(
            rows.len() == library.rows.len()
                && rows.iter().zip(&library.rows).all(|(a, b)| a.same_bits(b)),
            "{what}: the trace is not the library's run"
        );
        assert_eq!(summary["substeps"], 2, "{what}");
        check_summary(spec, &summary, &rows, spec.system.particles, &what);
    });
}

#[test]
fn run_durations_off_the_grid_end_at_the_duration() {
    // The library's runs are checked against the reference (library.rs); the CLI's are
    // those runs, bit for bit, and end where asked.
    let (issue, asymptotic) = matrix::off_grid_cases();
    let cases: Vec<Spec> = issue.into_iter().chain(asymptotic).collect();
    each(
        "bead run, duration off the grid",
        &cases,
        Spec::label,
        |spec| {
            let what = format!("bead run {}", spec.label());
            let (rows, summary) = run_cli(spec, &[]);
            let library = spec.run();
            assert!(
                rows.len() == library.rows.len()
                    && rows.iter().zip(&library.rows).all(|(a, b)| a.same_bits(b)),
                "{what}: the trace is not the library's run"
            );
            check_summary(spec, &summary, &rows, spec.system.particles, &what);
        },
    );
}

#[test]
fn compare_prints_the_runs_of_both_forms() {
    // `bead compare SCENE --integrator I --trace T --json`: one summary and one trace per
    // form, each the library's run of that form, bit for bit, and so meeting the oracle as
    // those runs do (library.rs); the trace rows are checked against the reference here too.
    // rattle: compare refuses it (the parametric form does), with the library's words.
    let mut cases: Vec<(&'static System, IntegratorKind)> = Vec::new();
    for system in System::all() {
        for integrator in IntegratorKind::ALL {
            cases.push((system, integrator));
        }
    }
    each(
        "bead compare",
        &cases,
        |(s, i)| format!("{} {}", s.name, i.name()),
        |&(system, integrator)| {
            let specs: Vec<Spec> = listing::cases_for("cli-compare")
                .into_iter()
                .filter(|s| s.system.name == system.name && s.integrator == integrator)
                .collect();
            if specs.is_empty() {
                // rattle, fast-projection: the parametric form refuses them, and compare says
                // so.
                let scene = bead_oracle::root().join(system.scene);
                let out = bead_in(
                    &std::env::temp_dir(),
                    &[
                        "compare",
                        p(&scene),
                        "--integrator",
                        integrator.name(),
                        "--steps",
                        "3",
                    ],
                );
                let err = String::from_utf8_lossy(&out.stderr);
                let refusal = format!("{} needs the implicit form", integrator.name());
                assert!(err.contains(&refusal), "{err}");
                return;
            }
            let spec = &specs[0];
            let what = format!("bead compare {} {}", system.name, integrator.name());
            let dir = TempDir::new("oracle-compare");
            let trace = dir.path("trace.csv");
            let scene = spec.scene_path();
            let mut args: Vec<String> = vec!["compare".into(), p(&scene).into()];
            // compare has no --method: both forms run.
            args.extend(spec.cli_flags().into_iter().skip(2));
            args.extend(["--trace".into(), p(&trace).into(), "--json".into()]);
            let args: Vec<&str> = args.iter().map(String::as_str).collect();
            let output = bead_in(&dir.0, &args);
            let summaries: Value = serde_json::from_str(&ok(output)).expect("JSON");
            let summaries = summaries.as_array().expect("an array of summaries");
            assert_eq!(summaries.len(), specs.len(), "{what}");
            for (spec, summary) in specs.iter().zip(summaries) {
                let library = spec.run();
                assert_eq!(
                    timeless(summary.clone()),
                    timeless(serde_json::to_value(&library.summary).unwrap()),
                    "{what}: the {} summary",
                    spec.method.name()
                );
                let path = dir.path(&format!("trace.{}.csv", spec.method.name()));
                let text = std::fs::read_to_string(&path).expect("a trace per form");
                let rows = Row::parse_trace(&text, system.dim);
                assert!(
                    rows.len() == library.rows.len()
                        && rows.iter().zip(&library.rows).all(|(a, b)| a.same_bits(b)),
                    "{what}: the {} trace is not the library's run",
                    spec.method.name()
                );
                check_summary(spec, summary, &rows, system.particles, &what);
                checks::against_reference(spec, &rows, &what);
            }
        },
    );
}

/// `bead sweep SCENE --param NAME=A:B:COUNT FLAGS` over the system's parameter (COUNT 3:
/// the scene's value in the middle; 1: the scene's value alone): the CSV's header and rows.
fn sweep_cli(spec: &Spec, count: usize) -> (Vec<String>, Vec<Vec<String>>) {
    let (name, low, middle) = spec.system.sweep;
    let (low, high) = if count == 1 {
        (middle, middle)
    } else {
        (low, 2.0 * middle - low)
    };
    let dir = TempDir::new("oracle-sweep");
    let scene = spec.scene_path();
    let mut args: Vec<String> = vec![
        "sweep".into(),
        p(&scene).into(),
        "--param".into(),
        format!("{name}={low:e}:{high:e}:{count}"),
        "--threads".into(),
        "2".into(),
    ];
    args.extend(spec.cli_flags());
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = ok(bead_in(&dir.0, &args));
    let mut lines = out.lines();
    let header = lines
        .next()
        .expect("header")
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

/// A member's row: its parameter value and final state.
fn member(spec: &Spec, header: &[String], fields: &[String]) -> (f64, Row, Value) {
    let column = |c: &str| {
        header
            .iter()
            .position(|h| h == c)
            .unwrap_or_else(|| panic!("no column {c}"))
    };
    let number = |c: &str| -> f64 { fields[column(c)].parse().expect("a number") };
    let system = spec.system;
    let mut x = Vec::new();
    let mut v = Vec::new();
    for particle in system.particles {
        for axis in ["x", "y", "z"].iter().take(system.dim) {
            x.push(number(&format!("{particle}.{axis}")));
        }
        for axis in ["vx", "vy", "vz"].iter().take(system.dim) {
            v.push(number(&format!("{particle}.{axis}")));
        }
    }
    let row = Row {
        t: number("t_final"),
        x,
        v,
        energy: f64::NAN,
        constraint_error: f64::NAN,
        work: None,
        q: Vec::new(),
        qdot: Vec::new(),
    };
    let status = Value::String(fields[column("status")].clone());
    (number(system.sweep.0), row, status)
}

#[test]
fn sweep_rows_are_their_runs_and_meet_the_oracle() {
    each(
        "bead sweep",
        &listing::cases_for("cli-sweep"),
        Spec::label,
        |spec| {
            let what = format!("bead sweep {}", spec.label());
            let (header, rows) = sweep_cli(spec, 3);
            assert_eq!(rows.len(), 3, "{what}");
            let (name, _, middle) = spec.system.sweep;
            for fields in &rows {
                let (value, row, status) = member(spec, &header, fields);
                assert_eq!(status, "ok", "{what}: {fields:?}");
                let mut alone = spec.clone();
                alone.overrides = vec![(name.to_string(), value)];
                let run = alone.run();
                let last = run.rows.last().unwrap();
                let bits =
                    |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
                assert!(
                    row.t.to_bits() == last.t.to_bits()
                        && bits(&row.x, &last.x)
                        && bits(&row.v, &last.v),
                    "{what}: member {name} = {value}: {row:?}, its run ends at {last:?}"
                );
                if value == middle {
                    // The member is its run, which meets the reference at every row, so its
                    // final state is within that run's largest error.
                    checks::against_reference(&alone, &run.rows, &what);
                    let largest = run
                        .rows
                        .iter()
                        .map(|r| error(spec.system, r))
                        .fold(0.0, f64::max);
                    checks::within(spec.system, &[row], largest, &what);
                    let end = bead_oracle::summary::end_time(spec);
                    assert!(
                        (last.t - end).abs() <= 4.0 * f64::EPSILON * end,
                        "{what}: t_final {}",
                        last.t
                    );
                }
            }
        },
    );
}

#[test]
fn sweep_durations_off_the_grid_end_at_the_duration() {
    let (issue, asymptotic) = matrix::off_grid_cases();
    let cases: Vec<Spec> = issue.into_iter().chain(asymptotic).collect();
    each(
        "bead sweep, duration off the grid",
        &cases,
        Spec::label,
        |spec| {
            // The scene's value: at dt 0.3 s a faster member's step can be refused as too
            // long (the helix at w0 = 4), which is not what this checks.
            let (header, rows) = sweep_cli(spec, 1);
            for fields in &rows {
                let (_, row, _) = member(spec, &header, fields);
                let end = bead_oracle::summary::end_time(spec);
                assert_eq!(row.t, end, "bead sweep {}: t_final {}", spec.label(), row.t);
            }
        },
    );
}
