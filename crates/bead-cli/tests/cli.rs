//! The `bead` binary, run for real in temporary directories: output formats, traces, and
//! every error a user can cause, with its message and exit code.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{bead_in, fails, ok, stderr, stdout, TempDir};

fn parabola() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml")
}

fn bead(args: &[&str]) -> Output {
    bead_in(&std::env::temp_dir(), args)
}

fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 path")
}

const SUMMARY_KEYS: [&str; 16] = [
    "scene",
    "method",
    "integrator",
    "dt",
    "steps",
    "t_final",
    "wall_seconds",
    "steps_per_second",
    "energy_initial",
    "energy_final",
    "energy_rel_error_max",
    "constraint_error_max",
    "constraint_error_final",
    "particles",
    "coordinates",
    "completed",
];

/// A one-particle 2D scene with `extra` appended.
fn bead_scene(extra: &str) -> String {
    format!(
        r#"title = "test bead"
[world]
gravity = [0.0, 9.81]

[[particle]]
name = "bead"
mass = 1.0
position = [1.0, 0.0]
velocity = [0.0, 0.0]
{extra}"#
    )
}

// ---------------------------------------------------------------------------------------
// run

#[test]
fn run_prints_a_human_summary_with_method_and_speed() {
    let out = ok(bead(&["run", p(&parabola()), "--steps", "100"]));
    assert!(out.contains("Bead on a parabola"), "{out}");
    assert!(out.contains("method       implicit"), "{out}");
    assert!(
        out.contains("integrator   rk4 (order 4, not symplectic)"),
        "{out}"
    );
    assert!(out.contains("steps        100\n"), "{out}");
    assert!(out.contains("steps/s"), "{out}");
    assert!(out.contains("max relative error"), "{out}");
}

#[test]
fn run_json_prints_only_the_summary_with_every_key() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--steps",
        "100",
        "--method",
        "parametric",
        "--json",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("stdout is JSON only");
    for key in SUMMARY_KEYS {
        assert!(value.get(key).is_some(), "missing {key} in {out}");
    }
    assert!(value.get("error").is_none());
    assert_eq!(value["method"], "parametric");
    assert_eq!(value["integrator"], "rk4");
    assert_eq!(value["steps"], 100);
    assert_eq!(value["completed"], true);
    assert_eq!(
        value["particles"]["bead"]["position"]
            .as_array()
            .map(Vec::len),
        Some(2)
    );
    assert_eq!(value["coordinates"]["q"].as_array().map(Vec::len), Some(2));
}

#[test]
fn implicit_json_has_no_coordinates() {
    let out = ok(bead(&["run", p(&parabola()), "--steps", "10", "--json"]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value["method"], "implicit");
    assert!(value.get("coordinates").is_none());
}

#[test]
fn trace_has_the_header_and_one_row_per_step() {
    let dir = TempDir::new("trace");
    ok(bead_in(
        &dir.0,
        &["run", p(&parabola()), "--steps", "100", "--trace", "t.csv"],
    ));
    let text = std::fs::read_to_string(dir.path("t.csv")).expect("trace");
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines[0],
        "t,bead.x,bead.y,bead.vx,bead.vy,energy,constraint_error"
    );
    assert_eq!(lines.len(), 1 + 101);
    assert!(lines[1].starts_with("0,150,-225,0,0,"), "{}", lines[1]);
    for line in &lines[1..] {
        assert_eq!(line.split(',').count(), 7, "{line}");
    }
}

#[test]
fn parametric_trace_adds_q_and_qdot() {
    let dir = TempDir::new("ptrace");
    ok(bead_in(
        &dir.0,
        &[
            "run",
            p(&parabola()),
            "--steps",
            "5",
            "--method",
            "parametric",
            "--trace",
            "t.csv",
        ],
    ));
    let text = std::fs::read_to_string(dir.path("t.csv")).expect("trace");
    assert_eq!(
        text.lines().next(),
        Some("t,bead.x,bead.y,bead.vx,bead.vy,energy,constraint_error,q.q,qdot.q")
    );
    assert_eq!(text.lines().count(), 1 + 6);
}

/// `--constraint-forces`: the rod's force on the pendulum's bead in every row of both traces
/// is Newton's along the rod, T = m (g y / r + |v|^2 / r) toward the pivot, from the
/// row's own state; the implicit trace's lambda gives it as lambda grad C = 2 lambda x.
#[test]
fn constraint_force_columns_hold_the_rod_tension_in_both_traces() {
    let dir = TempDir::new("forces");
    let circle = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/circle.toml");
    ok(bead_in(
        &dir.0,
        &[
            "compare",
            p(&circle),
            "--duration",
            "2",
            "--every",
            "50",
            "--trace",
            "t.csv",
            "--constraint-forces",
        ],
    ));
    for (file, lambda) in [("t.implicit.csv", true), ("t.parametric.csv", false)] {
        let text = std::fs::read_to_string(dir.path(file)).expect(file);
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let column = |name: &str| header.iter().position(|h| *h == name).expect(name);
        assert_eq!(header.contains(&"lambda.1"), lambda, "{file}");
        let (fx, fy) = (column("bead.Fcx"), column("bead.Fcy"));
        let mut rows = 0;
        for line in lines {
            let row: Vec<f64> = line.split(',').map(|v| v.parse().unwrap()).collect();
            let (x, y) = (row[column("bead.x")], row[column("bead.y")]);
            let (vx, vy) = (row[column("bead.vx")], row[column("bead.vy")]);
            let r = (x * x + y * y).sqrt();
            let tension = 9.81 * y / r + (vx * vx + vy * vy) / r;
            let expected = [-tension * x / r, -tension * y / r];
            assert!((row[fx] - expected[0]).abs() < 1e-9, "{file}: {line}");
            assert!((row[fy] - expected[1]).abs() < 1e-9, "{file}: {line}");
            if lambda {
                let l = row[column("lambda.1")];
                assert!((2.0 * l * x - row[fx]).abs() < 1e-12, "{line}");
            }
            rows += 1;
        }
        assert_eq!(rows, 1 + 2000 / 50, "{file}");
    }
    // Only with a trace to put them in.
    let error = fails(bead(&["run", p(&circle), "--constraint-forces"]), 2);
    assert!(error.contains("--trace"), "{error}");
}

#[test]
fn every_10_records_11_rows_of_100_steps() {
    let dir = TempDir::new("every");
    ok(bead_in(
        &dir.0,
        &[
            "run",
            p(&parabola()),
            "--steps",
            "100",
            "--every",
            "10",
            "--trace",
            "t.csv",
        ],
    ));
    let text = std::fs::read_to_string(dir.path("t.csv")).expect("trace");
    assert_eq!(text.lines().count(), 1 + 11);
    let times: Vec<f64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times[0], 0.0);
    assert_eq!(times[10], 100.0 * 0.016666666666666666);
}

#[test]
fn no_jit_gives_byte_identical_traces_and_check_says_which() {
    let dir = TempDir::new("no-jit");
    let scene = parabola();
    for (name, extra) in [("jit.csv", None), ("interp.csv", Some("--no-jit"))] {
        for method in ["implicit", "parametric"] {
            let trace = format!("{method}.{name}");
            let mut args = vec![
                "run",
                p(&scene),
                "--method",
                method,
                "--steps",
                "300",
                "--trace",
                &trace,
            ];
            args.extend(extra);
            ok(bead_in(&dir.0, &args));
        }
    }
    for method in ["implicit", "parametric"] {
        let a = std::fs::read(dir.path(&format!("{method}.jit.csv"))).expect("a");
        let b = std::fs::read(dir.path(&format!("{method}.interp.csv"))).expect("b");
        assert!(!a.is_empty());
        assert!(a == b, "{method}: --no-jit changed the trace");
    }
    let on = ok(bead(&["check", p(&parabola())]));
    assert!(on.contains("\nmachine code: "), "{on}");
    assert!(on.contains(" instructions, compiled in "), "{on}");
    let off = ok(bead(&["check", p(&parabola()), "--no-jit"]));
    assert!(off.contains("\nmachine code: off ("), "{off}");
}

#[test]
fn two_runs_give_byte_identical_traces() {
    let dir = TempDir::new("determinism");
    for name in ["a.csv", "b.csv"] {
        ok(bead_in(
            &dir.0,
            &[
                "run",
                p(&parabola()),
                "--steps",
                "200",
                "--integrator",
                "midpoint",
                "--trace",
                name,
            ],
        ));
    }
    let a = std::fs::read(dir.path("a.csv")).expect("a");
    let b = std::fs::read(dir.path("b.csv")).expect("b");
    assert!(!a.is_empty());
    assert_eq!(a, b);
}

#[test]
fn summary_file_is_the_json_summary() {
    let dir = TempDir::new("summary");
    let out = ok(bead_in(
        &dir.0,
        &[
            "run",
            p(&parabola()),
            "--steps",
            "20",
            "--summary",
            "s.json",
        ],
    ));
    assert!(out.contains("method"), "human text still on stdout");
    let text = std::fs::read_to_string(dir.path("s.json")).expect("summary");
    let value: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(value["steps"], 20);
    assert_eq!(value["completed"], true);
}

#[test]
fn duration_not_a_whole_number_of_steps_ends_exactly_there_and_says_so() {
    // Regression (issue 15): the run went on to t = 1.2.
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--dt",
        "0.3",
        "--duration",
        "1",
    ]));
    assert!(out.contains("steps        4\n"), "{out}");
    assert!(out.contains("t_final      1 s\n"), "{out}");
    assert!(
        out.contains(
            "duration 1 s is not a whole number of steps of dt = 0.3 s; the last step is 0.1"
        ),
        "{out}"
    );
    let dir = TempDir::new("duration");
    let json = ok(bead(&[
        "run",
        p(&parabola()),
        "--dt",
        "0.3",
        "--duration",
        "1",
        "--json",
        "--trace",
        dir.path("t.csv").to_str().unwrap(),
    ]));
    let value: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(value["t_final"], 1.0);
    let trace = std::fs::read_to_string(dir.path("t.csv")).unwrap();
    let times: Vec<&str> = trace
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    assert_eq!(times.last(), Some(&"1"), "{trace}");
    assert_eq!(times.len(), 5, "{trace}");
}

#[test]
fn set_overrides_a_parameter() {
    let a = ok(bead(&["run", p(&parabola()), "--steps", "10", "--json"]));
    let b = ok(bead(&[
        "run",
        p(&parabola()),
        "--steps",
        "10",
        "--json",
        "--set",
        "g=100",
    ]));
    let a: serde_json::Value = serde_json::from_str(&a).unwrap();
    let b: serde_json::Value = serde_json::from_str(&b).unwrap();
    assert_ne!(a["energy_initial"], b["energy_initial"]);
}

#[test]
fn stabilize_is_reported() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--steps",
        "10",
        "--stabilize",
        "100,20",
    ]));
    assert!(out.contains("stabilize    ks = 100, kd = 20"), "{out}");
}

// ---------------------------------------------------------------------------------------
// compare and check

#[test]
fn compare_prints_both_methods_in_a_table() {
    let out = ok(bead(&["compare", p(&parabola()), "--steps", "100"]));
    assert!(out.contains("final constraint error"), "{out}");
    assert!(out.contains("steps/s"), "{out}");
    let implicit = out
        .lines()
        .find(|l| l.starts_with("implicit"))
        .expect("implicit row");
    let parametric = out
        .lines()
        .find(|l| l.starts_with("parametric"))
        .expect("parametric row");
    // method, final and max constraint error, max |C|/|grad C| (`-` for the parametric
    // form), max rel energy error, final energy, steps/s.
    assert_eq!(implicit.split_whitespace().count(), 7, "{implicit}");
    assert_eq!(parametric.split_whitespace().count(), 7, "{parametric}");
    assert_eq!(
        parametric.split_whitespace().nth(3),
        Some("-"),
        "{parametric}"
    );
}

#[test]
fn compare_json_is_an_array_of_summaries() {
    let out = ok(bead(&[
        "compare",
        p(&parabola()),
        "--steps",
        "50",
        "--json",
        "--integrator",
        "symplectic-euler",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON only");
    let runs = value.as_array().expect("array");
    assert_eq!(runs.len(), 2);
    assert_eq!(runs[0]["method"], "implicit");
    assert_eq!(runs[1]["method"], "parametric");
    for run in runs {
        assert_eq!(run["integrator"], "symplectic-euler");
        assert_eq!(run["steps"], 50);
    }
}

#[test]
fn compare_writes_one_trace_per_method() {
    let dir = TempDir::new("compare-trace");
    ok(bead_in(
        &dir.0,
        &[
            "compare",
            p(&parabola()),
            "--steps",
            "10",
            "--trace",
            "t.csv",
        ],
    ));
    for (file, columns) in [("t.implicit.csv", 7), ("t.parametric.csv", 9)] {
        let text = std::fs::read_to_string(dir.path(file)).unwrap_or_else(|_| panic!("{file}"));
        assert_eq!(text.lines().count(), 1 + 11, "{file}");
        assert_eq!(
            text.lines().next().map(|h| h.split(',').count()),
            Some(columns),
            "{file}"
        );
    }
    assert!(!dir.path("t.csv").exists());
}

#[test]
fn check_prints_the_derivatives() {
    let out = ok(bead(&["check", p(&parabola())]));
    assert!(out.contains("dimension    2D"), "{out}");
    assert!(
        out.contains("bead  mass 1, position [150, -225], velocity [0, 0]"),
        "{out}"
    );
    assert!(out.contains("gravity"), "{out}");
    assert!(
        out.contains("constraint 1: bead.x^2 + 100*bead.y = 0"),
        "{out}"
    );
    assert!(out.contains("dC/d(bead.x) = 2*bead.x"), "{out}");
    assert!(out.contains("dC/d(bead.y) = 100"), "{out}");
    assert!(out.contains("Cdot = "), "{out}");
    assert!(out.contains("bias = "), "{out}");
    assert!(out.contains("degrees of freedom: 1"), "{out}");
    assert!(out.contains("d(bead.y)/dq = "), "{out}");
    assert!(out.contains("tape instructions"), "{out}");
}

#[test]
fn check_prints_derivatives_with_constant_factors_folded() {
    let double = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/double-pendulum.toml");
    let out = ok(bead(&["check", p(&double)]));
    // C = (|a - b|^2 - L^2)/2: its gradient was printed 2*(a.x - b.x)/2.
    assert!(out.contains("dC/d(a.x) = a.x - b.x\n"), "{out}");
    assert!(out.contains("dC/d(b.x) = -(a.x - b.x)\n"), "{out}");
    assert!(
        out.contains("Cdot = (a.x - b.x)*a.vx + (a.y - b.y)*a.vy - (a.x - b.x)*b.vx"),
        "{out}"
    );
    let out = ok(bead(&["check", p(&parabola())]));
    assert!(out.contains("d(bead.y)/dq = -0.02*q\n"), "{out}");
    assert!(out.contains("bias = 2*bead.vx^2 "), "{out}");
}

/// A bead on y = prod_k (1 + x/k), k = 1..n: a 13.7 KB scene for n = 800.
fn product_scene(n: usize) -> String {
    let product: Vec<String> = (1..=n).map(|k| format!("(1 + bead.x/{k})")).collect();
    bead_scene(&format!(
        "[[constraint]]\nname = \"product\"\nexpr = \"bead.y - {}\"\n",
        product.join("*")
    ))
    .replace("position = [1.0, 0.0]", "position = [0.0, 1.0]")
}

#[test]
fn check_output_stays_small_for_a_product_of_800_factors() {
    // The derivatives of a product of n factors are DAGs of O(n) nodes but trees of O(n^2)
    // (gradient) and O(n^3) (bias) characters: printed in full, this scene took 4.4 GB of
    // output and as much memory. Each expression is now cut at about 400 characters.
    let dir = TempDir::new("product-800");
    let scene = product_scene(800);
    assert!(scene.len() > 13_000);
    dir.write("s.toml", &scene);
    let out = bead_in(&dir.0, &["check", "s.toml"]);
    let text = ok(out);
    // The description repeats the scene's constraint (13.7 KB); everything else is small.
    assert!(text.len() < scene.len() + 10_000, "{} bytes", text.len());
    for line in text.lines().filter(|l| l.contains(" = ")) {
        let printed = line.split(" ... (").next().unwrap_or(line);
        assert!(
            printed.len() < 600 || line.trim_start().starts_with("product:"),
            "{} characters: {}",
            printed.len(),
            line.chars().take(200).collect::<String>()
        );
    }
    let bias = text
        .lines()
        .find(|l| l.trim_start().starts_with("bias = "))
        .expect("bias line");
    assert!(bias.contains(" more characters)"), "{bias}");
    // `bead run` of the same scene starts (and check agrees).
    ok(bead_in(&dir.0, &["run", "s.toml", "--steps", "10"]));
}

#[test]
fn help_describes_every_integrator_and_flag() {
    let out = ok(bead(&["run", "--help"]));
    for line in [
        "euler:            order 1, not symplectic",
        "symplectic-euler: order 1, symplectic",
        "midpoint:         order 2, not symplectic",
        "rk4:              order 4, not symplectic",
        "gauss-legendre:   order 4, symplectic, implicit stages",
        "dopri5:           order 5, not symplectic, adaptive",
        "verlet:           order 2, symplectic",
        "fast-projection:  order 1, not symplectic, implicit form only",
        "rattle:           order 2, symplectic, implicit form only",
    ] {
        assert!(out.contains(line), "{line} in\n{out}");
    }
    for flag in [
        "--method",
        "--integrator",
        "--dt",
        "--duration",
        "--steps",
        "--stabilize",
        "--set",
        "--trace",
        "--every",
        "--summary",
        "--json",
        "--rtol",
        "--atol",
        "--project",
    ] {
        assert!(out.contains(flag), "{flag}");
    }
    let compare = ok(bead(&["compare", "--help"]));
    assert!(compare.contains("out.implicit.csv"), "{compare}");
    assert!(compare.contains("order 4, not symplectic"), "{compare}");
}

#[test]
fn version_is_printed() {
    let out = ok(bead(&["--version"]));
    assert_eq!(out.trim(), format!("bead {}", env!("CARGO_PKG_VERSION")));
}

// ---------------------------------------------------------------------------------------
// errors in scene files (exit code 1, located)

#[test]
fn missing_file() {
    let err = fails(bead(&["run", "no-such-scene.toml"]), 1);
    assert!(
        err.starts_with("error: no-such-scene.toml: cannot read the scene file"),
        "{err}"
    );
}

/// OS errors were printed twice: `(os error 2): No such file or directory (os error 2)`
/// (issue 7). Every cause is printed once, after what could not be done.
#[test]
fn os_errors_are_printed_once() {
    let dir = TempDir::new("os-errors");
    let os = std::fs::read_to_string(dir.path("no-such-scene.toml"))
        .unwrap_err()
        .to_string();
    let err = fails(bead_in(&dir.0, &["run", "no-such-scene.toml"]), 1);
    assert_eq!(
        err,
        format!("error: no-such-scene.toml: cannot read the scene file: {os}\n")
    );
    // Outputs under a regular file: "Not a directory", once.
    let file = dir.write("file", "");
    let under = |name: &str| file.join(name);
    let not_a_directory = std::fs::write(under("x"), "").unwrap_err().to_string();
    let trace = run_trace(&dir);
    let err = fails(
        bead_in(&dir.0, &["plot", p(&trace), "-o", p(&under("x.png"))]),
        1,
    );
    assert_eq!(
        err,
        format!(
            "error: cannot write `{}`: {not_a_directory}\n",
            p(&under("x.png"))
        )
    );
    let err = fails(
        bead_in(
            &dir.0,
            &[
                "compare",
                p(&parabola()),
                "--steps",
                "10",
                "--report",
                p(&under("report")),
            ],
        ),
        1,
    );
    assert_eq!(
        err,
        format!(
            "error: cannot write `{}`: {not_a_directory}\n",
            p(&under("report"))
        )
    );
    for (flag, what) in [
        ("--trace", "cannot create trace file"),
        ("--summary", "cannot write"),
    ] {
        let err = fails(
            bead_in(
                &dir.0,
                &[
                    "run",
                    p(&parabola()),
                    "--steps",
                    "10",
                    flag,
                    p(&under("out")),
                ],
            ),
            1,
        );
        assert_eq!(
            err,
            format!("error: {what} `{}`: {not_a_directory}\n", p(&under("out"))),
            "{flag}"
        );
    }
}

/// `--trace X --summary X` silently overwrote the trace with the summary (issue 7). Two
/// outputs naming one file, or an output naming an input, are a usage error naming both
/// flags, found before anything is written.
#[test]
fn outputs_that_name_the_same_file_are_refused() {
    let dir = TempDir::new("clash");
    let scene = dir.write(
        "s.toml",
        &std::fs::read_to_string(parabola()).expect("parabola"),
    );
    let refused = |args: &[&str], expected: &str| {
        let err = fails(bead_in(&dir.0, args), 2);
        assert_eq!(err, format!("error: {expected}\n"), "{args:?}");
    };
    refused(
        &["run", "s.toml", "--trace", "out", "--summary", "./out"],
        "--trace out and --summary ./out are the same file; give each output its own path",
    );
    refused(
        &["run", "s.toml", "--summary", p(&scene)],
        &format!(
            "--summary {} would overwrite the scene file s.toml",
            p(&scene)
        ),
    );
    refused(
        &[
            "compare",
            "s.toml",
            "--trace",
            "t.csv",
            "--summary",
            "t.parametric.csv",
        ],
        "--trace t.csv (writing t.parametric.csv) and --summary t.parametric.csv are the same \
         file; give each output its own path",
    );
    refused(
        &[
            "compare",
            "s.toml",
            "--dts",
            "1/60",
            "--report",
            "r",
            "--summary",
            "r/report.html",
        ],
        "--summary r/report.html and --report r (writing r/report.html) are the same file; give \
         each output its own path",
    );
    refused(
        &[
            "compare",
            "s.toml",
            "--dts",
            "1/60,1*60",
            "--trace",
            "t.csv",
        ],
        "--trace t.csv (writing t.implicit.rk4.dt1_60.csv for implicit rk4 dt 1/60) and --trace \
         t.csv (writing t.implicit.rk4.dt1_60.csv for implicit rk4 dt 1*60) are the same file; \
         give each output its own path",
    );
    // Nothing was written, and the scene is intact.
    let mut left: Vec<String> = std::fs::read_dir(&dir.0)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["s.toml"]);
    // A symbolic link is the file it points to.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(dir.path("s.toml"), dir.path("link.toml")).expect("symlink");
        refused(
            &["run", "link.toml", "--summary", "s.toml"],
            "--summary s.toml would overwrite the scene file link.toml",
        );
    }
    // Distinct files are fine.
    ok(bead_in(
        &dir.0,
        &[
            "run",
            "s.toml",
            "--steps",
            "5",
            "--trace",
            "a.csv",
            "--summary",
            "a.json",
        ],
    ));
}

/// Control characters in scene strings and file names reached the terminal raw (issue 7).
#[test]
fn control_characters_never_reach_the_terminal() {
    let dir = TempDir::new("control");
    let raw = |o: &Output| {
        let all = format!("{}{}", stdout(o), stderr(o));
        assert!(!all.contains('\u{1b}'), "{all:?}");
        all
    };
    // A title with an escape sequence is refused where it is written.
    dir.write(
        "s.toml",
        &bead_scene("").replace("title = \"test bead\"", "title = \"\\u001b[2J\""),
    );
    let out = bead_in(&dir.0, &["run", "s.toml"]);
    raw(&out);
    assert_eq!(
        fails(out, 1),
        "error: s.toml:1:9: `title` must not contain control characters, found `\\x1b`\n  \
         title = \"\\u001b[2J\"\n          ^^^^^^^^^^^\n"
    );
    // A file name cannot be refused: it is escaped (a scene without a title shows its name).
    let name = "e\u{1b}[2Jx.toml";
    dir.write(name, &bead_scene("").replace("title = \"test bead\"\n", ""));
    let out = bead_in(&dir.0, &["run", name, "--steps", "2"]);
    let text = raw(&out);
    assert!(
        text.starts_with("e\\x1b[2Jx\n  scene        e\\x1b[2Jx.toml\n"),
        "{text}"
    );
    let out = bead_in(&dir.0, &["check", "no\u{1b}such.toml"]);
    raw(&out);
    assert!(fails(out, 1).starts_with("error: no\\x1bsuch.toml: cannot read the scene file: "),);
    // JSON keeps the name, escaped the JSON way.
    let out = ok(bead_in(&dir.0, &["run", name, "--steps", "2", "--json"]));
    assert!(out.contains("\"scene\": \"e\\u001b[2Jx.toml\""), "{out}");
}

/// Unicode particle names were accepted but unusable in expressions (issue 7): `α.x` works
/// in a constraint, and check, run, compare, trace headers and plot all show the names.
#[test]
fn unicode_names_work_in_check_run_and_traces() {
    let dir = TempDir::new("unicode");
    dir.write(
        "s.toml",
        r#"title = "α on a circle"
[params]
"ℓ" = 1.0
[world]
gravity = [0.0, -9.81]
[[particle]]
name = "α"
mass = 1.0
position = ["ℓ", 0.0]
[[constraint]]
name = "rod"
expr = "α.x^2 + α.y^2 - ℓ^2"
[parametric]
coordinates = ["θ"]
initial = ["pi/2"]
[parametric.positions]
"α" = ["ℓ*sin(θ)", "-ℓ*cos(θ)"]
"#,
    );
    let check = ok(bead_in(&dir.0, &["check", "s.toml"]));
    assert!(check.starts_with("α on a circle\n"), "{check}");
    assert!(check.contains("dC/d(α.x) = 2*α.x"), "{check}");
    assert!(check.contains("α.x = sin(θ)"), "{check}");
    let run = ok(bead_in(
        &dir.0,
        &[
            "run", "s.toml", "--steps", "10", "--trace", "i.csv", "--set", "ℓ=1",
        ],
    ));
    assert!(run.starts_with("α on a circle\n"), "{run}");
    let header = |file: &str| {
        let text = std::fs::read_to_string(dir.path(file)).expect("trace");
        text.lines().next().expect("header").to_string()
    };
    assert_eq!(
        header("i.csv"),
        "t,α.x,α.y,α.vx,α.vy,energy,constraint_error"
    );
    ok(bead_in(
        &dir.0,
        &[
            "run",
            "s.toml",
            "--steps",
            "10",
            "--method",
            "parametric",
            "--trace",
            "p.csv",
        ],
    ));
    assert_eq!(
        header("p.csv"),
        "t,α.x,α.y,α.vx,α.vy,energy,constraint_error,q.θ,qdot.θ"
    );
    let value: serde_json::Value = serde_json::from_str(&ok(bead_in(
        &dir.0,
        &["compare", "s.toml", "--steps", "10", "--json"],
    )))
    .expect("JSON");
    assert_eq!(
        value[1]["coordinates"]["θ"].as_array().map(Vec::len),
        Some(2)
    );
    assert!(value[0]["particles"]["α"]["position"].is_array(), "{value}");
    let plotted = ok(bead_in(
        &dir.0,
        &["plot", "p.csv", "--columns", "α.x,q.θ", "-o", "p.svg"],
    ));
    assert_eq!(plotted, "wrote p.svg\n");
    let svg = std::fs::read_to_string(dir.path("p.svg")).expect("svg");
    assert!(svg.contains("α.x") && svg.contains("q.θ"), "labels");
}

#[test]
fn bad_toml_names_line_and_column() {
    let dir = TempDir::new("bad-toml");
    let scene = dir.write("bad.toml", "title = \"x\"\n[world\ngravity = [0.0, 1.0]\n");
    let err = fails(bead_in(&dir.0, &["run", p(&scene)]), 1);
    assert!(
        err.starts_with(&format!("error: {}:2:7: ", p(&scene))),
        "{err}"
    );
    assert!(err.contains("[world\n"), "{err}");
    assert!(err.contains('^'), "{err}");
}

#[test]
fn bad_expression_shows_a_caret() {
    let dir = TempDir::new("bad-expr");
    let scene = dir.write(
        "s.toml",
        &bead_scene("[[constraint]]\nexpr = \"bead.x^2 + * bead.y\"\n"),
    );
    let err = fails(bead_in(&dir.0, &["check", "s.toml"]), 1);
    assert_eq!(
        err,
        "error: s.toml:11:20: constraint 1: expected a number, name or `(`, found `*`\n  \
         expr = \"bead.x^2 + * bead.y\"\n                     ^\n"
    );
    let _ = scene;
}

#[test]
fn unknown_particle() {
    let dir = TempDir::new("unknown-particle");
    dir.write(
        "s.toml",
        &bead_scene("[[constraint]]\nexpr = \"ghost.x - 1\"\n"),
    );
    let err = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert!(err.starts_with("error: s.toml:11:9: "), "{err}");
    assert!(err.contains("unknown particle `ghost`"), "{err}");
    assert!(err.contains("^^^^^^^"), "{err}");
}

#[test]
fn duplicate_particle_names() {
    let dir = TempDir::new("duplicate");
    let second =
        "[[particle]]\nname = \"bead\"\nmass = 1.0\nposition = [0.0, 0.0]\nvelocity = [0.0, 0.0]\n";
    dir.write("s.toml", &bead_scene(second));
    let err = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert!(err.starts_with("error: s.toml:11:8: "), "{err}");
    assert!(err.contains("duplicate particle name `bead`"), "{err}");
}

#[test]
fn dimension_mismatch() {
    let dir = TempDir::new("dimension");
    dir.write(
        "s.toml",
        &bead_scene("").replace("position = [1.0, 0.0]", "position = [1.0, 0.0, 2.0]"),
    );
    let err = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert!(err.starts_with("error: s.toml:8:12: "), "{err}");
    assert!(err.contains("3 components but the scene is 2D"), "{err}");
}

#[test]
fn mass_must_be_positive() {
    let dir = TempDir::new("mass");
    dir.write(
        "s.toml",
        &bead_scene("").replace("mass = 1.0", "mass = -2.0"),
    );
    let err = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert!(err.starts_with("error: s.toml:7:8: "), "{err}");
    assert!(err.contains("`mass` must be positive, got -2"), "{err}");
}

#[test]
fn nan_in_the_file() {
    let dir = TempDir::new("nan");
    dir.write(
        "s.toml",
        &bead_scene("").replace("velocity = [0.0, 0.0]", "velocity = [nan, 0.0]"),
    );
    let err = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert!(err.starts_with("error: s.toml:9:13: "), "{err}");
    assert!(err.contains("must be finite, got NaN"), "{err}");
}

#[test]
fn scene_dt_must_be_positive() {
    let dir = TempDir::new("scene-dt");
    dir.write("s.toml", &bead_scene("[run]\ndt = 0.0\n"));
    let err = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert!(err.starts_with("error: s.toml:11:6: "), "{err}");
    assert!(err.contains("`dt` must be positive, got 0"), "{err}");
}

#[test]
fn unknown_set_parameter() {
    let err = fails(bead(&["run", p(&parabola()), "--set", "nope=1"]), 1);
    assert!(err.contains("unknown parameter `nope`"), "{err}");
}

// ---------------------------------------------------------------------------------------
// usage errors (exit code 2, clap's message)

#[test]
fn dt_flag_must_be_positive() {
    for dt in ["0", "-0.1", "nan", "inf"] {
        let err = fails(bead(&["run", p(&parabola()), &format!("--dt={dt}")]), 2);
        assert!(
            err.contains(&format!("invalid value '{dt}' for '--dt <SECONDS>'")),
            "{err}"
        );
    }
}

#[test]
fn duration_steps_and_every_must_be_positive() {
    let err = fails(bead(&["run", p(&parabola()), "--duration", "0"]), 2);
    assert!(err.contains("must be positive, got 0"), "{err}");
    let err = fails(bead(&["run", p(&parabola()), "--steps", "0"]), 2);
    assert!(err.contains("invalid value '0' for '--steps <N>'"), "{err}");
    let err = fails(bead(&["run", p(&parabola()), "--every", "0"]), 2);
    assert!(err.contains("invalid value '0' for '--every <K>'"), "{err}");
}

#[test]
fn unknown_integrator() {
    let err = fails(
        bead(&["run", p(&parabola()), "--integrator", "leapfrog"]),
        2,
    );
    assert!(
        err.contains("invalid value 'leapfrog' for '--integrator <INTEGRATOR>'"),
        "{err}"
    );
    assert!(
        err.contains("euler, symplectic-euler, midpoint, rk4"),
        "{err}"
    );
}

#[test]
fn unknown_method() {
    let err = fails(bead(&["run", p(&parabola()), "--method", "lagrange"]), 2);
    assert!(
        err.contains("invalid value 'lagrange' for '--method <METHOD>'"),
        "{err}"
    );
}

#[test]
fn steps_conflict_with_duration() {
    let err = fails(
        bead(&["run", p(&parabola()), "--steps", "10", "--duration", "1"]),
        2,
    );
    assert!(
        err.contains("'--steps <N>' cannot be used with '--duration <SECONDS>'"),
        "{err}"
    );
}

#[test]
fn bad_set() {
    for (set, message) in [
        ("g", "expected NAME=VALUE, got `g`"),
        // Values are expressions of numbers (see numeric_flags_take_expressions), so a
        // word is a name that is not a number, and `inf` is refused by name.
        ("g=abc", "the value of `g`: `abc` is not a number"),
        (
            "g=inf",
            "the value of `g`: `inf` is not allowed here: numbers must be finite",
        ),
        ("g=1e308*10", "the value of `g`: must be finite, got inf"),
        ("=1", "the name is empty"),
    ] {
        let err = fails(bead(&["run", p(&parabola()), "--set", set]), 2);
        assert!(err.contains(message), "{set}: {err}");
    }
}

/// `--dt 1/60` used to be refused while `--dts 1/60` was accepted (issue 7).
#[test]
fn numeric_flags_take_expressions() {
    let scene = parabola();
    let json = |args: &[&str]| -> serde_json::Value {
        let mut all = vec!["run", p(&scene), "--json"];
        all.extend_from_slice(args);
        serde_json::from_str(&ok(bead(&all))).expect("JSON")
    };
    let plain = json(&["--dt", "0.016666666666666666", "--duration", "1"]);
    let typed = json(&["--dt", "1/60", "--duration", "2*5/10"]);
    assert_eq!(typed["dt"], plain["dt"]);
    assert_eq!(typed["steps"], 60);
    assert_eq!(typed["particles"], plain["particles"]);
    // --set g=2*250 is the scene's own g = 500.
    let set = json(&["--steps", "10", "--set", "g=2*250"]);
    let own = json(&["--steps", "10"]);
    assert_eq!(set["particles"], own["particles"]);
    let moved = json(&["--steps", "10", "--set", "g=sqrt(4)*pi"]);
    assert_ne!(moved["particles"], own["particles"]);
    // --stabilize, --rtol and --atol.
    let text = ok(bead(&[
        "run",
        p(&parabola()),
        "--steps",
        "10",
        "--stabilize",
        "2*79, atan2(0, 1) + 25",
    ]));
    assert!(text.contains("ks = 158, kd = 25"), "{text}");
    let text = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "dopri5",
        "--rtol",
        "1/1e9",
        "--atol",
        "10^-12",
    ]));
    assert!(text.contains("rtol 1e-9, atol 1e-12"), "{text}");
}

#[test]
fn numeric_flag_errors_point_into_the_value() {
    for (args, expected) in [
        (
            vec!["--dt", "1/"],
            "error: invalid value '1/' for '--dt <SECONDS>': unexpected end of expression, \
             expected a number, name or `(`\n  1/\n    ^\n",
        ),
        (
            vec!["--duration", "10 - 2*5"],
            "error: invalid value '10 - 2*5' for '--duration <SECONDS>': must be positive, got 0\n  \
             10 - 2*5\n  ^^^^^^^^\n",
        ),
        (
            vec!["--set", "g=2*g"],
            "error: invalid value 'g=2*g' for '--set <NAME=VALUE>': the value of `g`: `g` is not \
             a number; a --set value may use pi, e and functions like sqrt(2), not the scene's \
             parameters\n  g=2*g\n      ^\n",
        ),
        (
            vec!["--stabilize", "100,-20"],
            "error: invalid value '100,-20' for '--stabilize <KS,KD>': KD: must not be negative, \
             got -20; expected KS,KD (two finite numbers >= 0, e.g. 100,20)\n  100,-20\n      ^^^\n",
        ),
        (
            vec!["--rtol", "1e-9 x"],
            "error: invalid value '1e-9 x' for '--rtol <RTOL>': unexpected `x`, expected an operator \
             (implicit multiplication is not supported; write `*`)\n  1e-9 x\n       ^\n",
        ),
    ] {
        let scene = parabola();
        let mut all = vec!["run", p(&scene)];
        all.extend_from_slice(&args);
        let err = fails(bead(&all), 2);
        assert!(
            err.starts_with(expected),
            "{args:?}:\n{err}\nexpected:\n{expected}"
        );
    }
    let err = fails(
        bead(&["compare", p(&parabola()), "--dts", "1/30, 1/60, 1/60"]),
        2,
    );
    assert!(
        err.contains("`1/60` is given twice\n  1/30, 1/60, 1/60\n              ^^^^\n"),
        "{err}"
    );
}

#[test]
fn bad_stabilize() {
    for value in ["1", "-1,0", "1,nan", "a,b"] {
        let err = fails(
            bead(&["run", p(&parabola()), &format!("--stabilize={value}")]),
            2,
        );
        assert!(
            err.contains("expected KS,KD (two finite numbers >= 0"),
            "{value}: {err}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// errors that depend on the scene or happen during the run (exit code 1)

#[test]
fn parametric_without_a_parametric_form() {
    let dir = TempDir::new("no-parametric");
    dir.write(
        "s.toml",
        &bead_scene("[[constraint]]\nexpr = \"bead.x - 1\"\n"),
    );
    let err = fails(
        bead_in(&dir.0, &["run", "s.toml", "--method", "parametric"]),
        1,
    );
    assert_eq!(
        err,
        "error: the scene defines no parametric form (add a [parametric] table)\n"
    );
}

#[test]
fn stabilize_with_parametric() {
    let err = fails(
        bead(&[
            "run",
            p(&parabola()),
            "--method",
            "parametric",
            "--stabilize",
            "10,1",
        ]),
        1,
    );
    assert_eq!(
        err,
        "error: constraint feedback (ks, kd) applies to the implicit form only: the parametric form stays on its constraints by construction\n"
    );
}

#[test]
fn two_identical_constraints_are_singular() {
    let dir = TempDir::new("singular-duplicate");
    let twice = "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n".repeat(2);
    dir.write("s.toml", &bead_scene(&twice));
    let err = fails(bead_in(&dir.0, &["run", "s.toml", "--steps", "10"]), 1);
    assert_eq!(
        err,
        "error: the initial state cannot be simulated: at t = 0: the constraints are singular at \
         constraint 2 (`bead.x^2 + bead.y^2 - 1 = 0`): its gradient vanishes there or it \
         duplicates other constraints\n"
    );
}

#[test]
fn a_vanishing_gradient_is_singular() {
    let dir = TempDir::new("singular-origin");
    let scene = bead_scene("[[constraint]]\nname = \"ring\"\nexpr = \"bead.x^2 + bead.y^2\"\n")
        .replace("position = [1.0, 0.0]", "position = [0.0, 0.0]");
    dir.write("s.toml", &scene);
    let err = fails(bead_in(&dir.0, &["run", "s.toml", "--steps", "10"]), 1);
    assert_eq!(
        err,
        "error: the initial state cannot be simulated: at t = 0: ring (`bead.x^2 + bead.y^2 = 0`) \
         is singular: its gradient is zero or not finite at the initial state (bead.x, bead.y) = \
         (0, 0): a cusp or a crossing of the curve; the motion cannot be continued on this curve \
         by the implicit form\n"
    );
}

// ---------------------------------------------------------------------------------------
// check refuses what run refuses at t = 0 (exit code 1, after the description)

/// The `error: ` lines of `text`.
fn error_lines(text: &str) -> Vec<String> {
    text.lines()
        .filter(|l| l.starts_with("error: "))
        .map(String::from)
        .collect()
}

/// Write `scene`, and assert that `bead check` prints its description, then exits 1 with the
/// error `bead run` gives for it (with `run_flags`), naming the formulation (`form`) when it
/// is about one. Returns check's stdout.
fn check_refuses_as_run_does(
    name: &str,
    scene: &str,
    form: Option<&str>,
    run_flags: &[&str],
) -> String {
    let dir = TempDir::new(name);
    dir.write("s.toml", scene);
    let check = bead_in(&dir.0, &["check", "s.toml"]);
    let out = stdout(&check);
    let err = fails(check, 1);
    assert!(out.starts_with("test bead\n"), "{out}");
    assert!(out.contains("\ndegrees of freedom: "), "{out}");
    assert!(out.contains("\nstart at t = 0"), "{out}");
    let mut args = vec!["run", "s.toml", "--steps", "1"];
    args.extend(run_flags);
    let run = error_lines(&fails(bead_in(&dir.0, &args), 1));
    assert_eq!(run.len(), 1, "{run:?}");
    let expected = match form {
        Some(form) => run[0].replacen("error: ", &format!("error: {form} form: "), 1),
        None => run[0].clone(),
    };
    assert_eq!(error_lines(&err), vec![expected], "{err}");
    out
}

#[test]
fn check_refuses_an_over_constrained_scene() {
    let three = "[[constraint]]\nexpr = \"bead.x - 1\"\n[[constraint]]\nexpr = \"bead.y\"\n\
                 [[constraint]]\nexpr = \"bead.x + bead.y - 1\"\n";
    let out = check_refuses_as_run_does("check-over", &bead_scene(three), Some("implicit"), &[]);
    assert!(!out.contains("degrees of freedom: -1"), "{out}");
    assert!(
        out.contains(
            "degrees of freedom: none: the system is over-constrained: 3 constraint rows on 2 \
             coordinates (more rows than coordinates, so the constraint forces are not \
             determined)\n"
        ),
        "{out}"
    );
    assert!(
        out.contains("  implicit     refused: the system is over-constrained"),
        "{out}"
    );
}

#[test]
fn check_refuses_a_duplicated_constraint() {
    let twice = "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n".repeat(2);
    let out = check_refuses_as_run_does("check-twice", &bead_scene(&twice), Some("implicit"), &[]);
    assert!(out.contains("duplicates other constraints"), "{out}");
}

#[test]
fn check_refuses_a_constraint_that_is_identically_zero() {
    let zero = "[[constraint]]\nexpr = \"bead.x - bead.x\"\n";
    check_refuses_as_run_does("check-zero", &bead_scene(zero), Some("implicit"), &[]);
}

#[test]
fn check_refuses_a_gradient_that_vanishes_at_the_start() {
    let cusp = bead_scene("[[constraint]]\nexpr = \"bead.y^2 - bead.x^3\"\n")
        .replace("position = [1.0, 0.0]", "position = [0.0, 0.0]");
    let out = check_refuses_as_run_does("check-cusp", &cusp, Some("implicit"), &[]);
    assert!(out.contains("is singular: its gradient is zero"), "{out}");
}

#[test]
fn check_refuses_a_parametric_map_singular_at_the_start() {
    let map = "[parametric]\ncoordinates = [\"s\"]\ninitial = [0.0]\nrates = [0.0]\n\
               [parametric.positions]\nbead = [\"s^2\", \"s^3\"]\n";
    let scene = bead_scene(map).replace("position = [1.0, 0.0]", "position = [0.0, 0.0]");
    let out = check_refuses_as_run_does("check-map", &scene, Some("parametric"), &[]);
    assert!(out.contains("coordinate `s` is singular"), "{out}");
}

#[test]
fn check_refuses_a_constraint_that_is_not_finite_at_the_start() {
    let infinite = "[[constraint]]\nexpr = \"bead.x - 1/0\"\n";
    let out = check_refuses_as_run_does("check-inf", &bead_scene(infinite), Some("implicit"), &[]);
    assert!(out.contains("is not finite"), "{out}");
}

#[test]
fn check_refuses_a_run_table_the_library_refuses() {
    // Both forms; the scene asks for the parametric form with rattle, which it cannot use.
    // (Asking for rattle with the implicit form as the run's form passes: see
    // check_passes_a_rattle_scene_that_also_has_a_parametric_form.)
    let both = "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n\
                [parametric]\ncoordinates = [\"th\"]\ninitial = [1.5707963267948966]\n\
                rates = [0.0]\n[parametric.positions]\nbead = [\"sin(th)\", \"cos(th)\"]\n\
                [run]\nmethod = \"parametric\"\nintegrator = \"rattle\"\n";
    let out = check_refuses_as_run_does(
        "check-rattle",
        &bead_scene(both),
        Some("parametric"),
        &["--method", "parametric"],
    );
    assert!(out.contains("start at t = 0 (rattle, "), "{out}");
    assert!(out.contains("  implicit     ok\n"), "{out}");
    assert!(
        out.contains("  parametric   refused: rattle needs the implicit form"),
        "{out}"
    );
}

#[test]
fn check_refuses_run_settings_that_run_refuses() {
    // The scene loader accepts each number; resolving them as `bead run` does fails.
    let scene = bead_scene(
        "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n[run]\ndt = 1e-10\nduration = 1e10\n",
    );
    let dir = TempDir::new("check-steps");
    dir.write("s.toml", &scene);
    let check = bead_in(&dir.0, &["check", "s.toml"]);
    let out = stdout(&check);
    let err = fails(check, 1);
    assert!(
        out.contains("\nstart at t = 0: not tried: duration"),
        "{out}"
    );
    // `bead run` without --steps (which would override the scene's duration).
    let run = fails(bead_in(&dir.0, &["run", "s.toml"]), 1);
    assert_eq!(error_lines(&err), error_lines(&run));
    assert_eq!(
        error_lines(&err),
        vec!["error: duration 10000000000 with dt 1e-10 would take 1e20 steps; at most 2^53 are allowed"]
    );
}

#[test]
fn check_accepts_every_shipped_scene() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("scenes/")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    scenes.sort();
    assert!(scenes.len() >= 5, "{scenes:?}");
    for scene in &scenes {
        let out = bead(&["check", p(scene)]);
        assert_eq!(stderr(&out), "", "{}", scene.display());
        let text = ok(out);
        assert!(text.contains("\ndegrees of freedom: "), "{text}");
        let integrator = ["rattle", "fast-projection"]
            .into_iter()
            .find(|name| text.contains(&format!("integrator {name}")))
            .unwrap_or("rk4");
        assert!(
            text.contains(&format!("\nstart at t = 0 ({integrator}, dt ")),
            "{text}"
        );
        assert!(!text.contains("refused"), "{text}");
        assert!(text.contains(" ok\n"), "{text}");
    }
}

/// A generated scene (issue 8): `bead check` names the tables with `for` and what they made,
/// counts the particles, forces and constraints after expansion, and lists a generated table
/// of 1000 items in a few lines, cut like `bead::name_list` cuts names.
#[test]
fn check_summarizes_a_generated_scene() {
    let chain = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/chain.toml");
    let out = bead(&["check", p(&chain)]);
    assert_eq!(stderr(&out), "");
    let text = ok(out);
    for expected in [
        "\n  generated    particle 1 (line 28): i = 0..N, 1000 particles\n               \
         constraint 2 (line 43): i = 1..N, 999 constraints\n\nparticles (1000)\n  p0    mass 1, \
         position [1, 0], velocity [0, 0]\n",
        "\n  p7    mass 1, position [8, 0], velocity [0, 0]\n  \
         ... 991 more made by particle 1 (line 28: for i = 0..N)\n  \
         p999  mass 1, position [1000, 0], velocity [0, 0]\n\nforces (gravity only)\n",
        "\nconstraints (1000, 1000 rows)\n  pivot rod: distance(p0, [0.0, 0.0]) = 1 (row 0)\n",
        "\n  ... 990 more made by constraint 2 (line 43: for i = 1..N)\n  \
         rod 999: distance(p998, p999) = 1 (row 999)\n",
        "\ndegrees of freedom: 1000\n",
        "\n  implicit     ok\n",
    ] {
        assert!(text.contains(expected), "{expected}\nnot in\n{text}");
    }
    // 9 particles and 10 constraints of a few lines each, not 10^4 lines.
    assert!(text.lines().count() < 150, "{} lines", text.lines().count());

    // A chain of 10 lists every link (no table made more than bead::LISTED_NAMES).
    let out = bead(&["check", p(&chain), "--set", "N=10"]);
    let text = ok(out);
    assert!(!text.contains("..."), "{text}");
    assert!(
        text.contains("\n  p9  mass 1,") && text.contains("\n  rod 9: "),
        "{text}"
    );
}

/// Whether `text` has a run of more than 20 digits (a number printed in full, like 1e300 as
/// 1000...0).
fn has_long_number(text: &str) -> bool {
    text.split(|c: char| !c.is_ascii_digit())
        .any(|run| run.len() > 20)
}

/// Overflow must never be reported as singular constraints, nor printed as 300 digits
/// (issue 7): a huge dt, a huge mass and a constraint that divides by zero are each named.
#[test]
fn overflow_is_named_never_called_singular() {
    let dir = TempDir::new("overflow");
    let circle = "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n";
    dir.write("circle.toml", &bead_scene(circle));
    // One step of 1e300 s (a duration would end the run at its 10 s).
    let out = bead_in(
        &dir.0,
        &["run", "circle.toml", "--dt", "1e300", "--steps", "1"],
    );
    let text = stdout(&out);
    let err = fails(out, 1);
    assert_eq!(
        err,
        "error: at t = 5e299: the position bead.y (inf) is not finite\n"
    );
    assert!(
        text.contains("dt           1e300 s") && !has_long_number(&text),
        "{text}"
    );

    dir.write(
        "heavy.toml",
        &bead_scene(circle).replace("mass = 1.0", "mass = 1e308"),
    );
    let err = fails(bead_in(&dir.0, &["run", "heavy.toml"]), 1);
    assert_eq!(
        err,
        "error: heavy.toml:7:8: particle 1: `mass` must be between 1e-100 and 1e100, got 1e308: \
         masses, their inverses and momenta must stay far from overflow and underflow\n  \
         mass = 1e308\n         ^^^^^\n"
    );

    dir.write(
        "divide.toml",
        &bead_scene("[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1 + 1/0\"\n"),
    );
    let err = fails(bead_in(&dir.0, &["run", "divide.toml"]), 1);
    assert_eq!(
        err,
        "warning: constraint 1 (`bead.x^2 + bead.y^2 - 1 + 1/0 = 0`): its value at the initial \
         positions is not finite (inf)\n\
         error: the initial state cannot be simulated: at t = 0: the value of constraint 1 (inf) \
         is not finite\n"
    );
}

/// Scene warnings printed 300-digit decimals and `by inf`, and `Cdot = 5e1` where `check`
/// printed `-50` (issue 7): numbers are exact and short, measured values signed and printed
/// like `check` prints them, and what is not finite is said in words.
#[test]
fn warnings_print_numbers_like_check() {
    let dir = TempDir::new("warnings");
    let circle = "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n";
    dir.write(
        "moving.toml",
        &bead_scene(circle).replace("velocity = [0.0, 0.0]", "velocity = [-25.0, 0.0]"),
    );
    let out = bead_in(&dir.0, &["run", "moving.toml", "--steps", "1"]);
    assert_eq!(
        stderr(&out),
        "warning: constraint 1 (`bead.x^2 + bead.y^2 - 1 = 0`): the initial velocities are not \
         tangent to it: Cdot = -50\n"
    );
    let check = ok(bead_in(&dir.0, &["check", "moving.toml"]));
    assert!(check.contains("at t = 0: C = 0, Cdot = -50\n"), "{check}");

    let off = bead_scene(circle).replace("position = [1.0, 0.0]", "position = [1.5, 0.0]");
    dir.write("off.toml", &off);
    let out = bead_in(&dir.0, &["run", "off.toml", "--steps", "1"]);
    assert_eq!(
        stderr(&out),
        "warning: constraint 1 (`bead.x^2 + bead.y^2 - 1 = 0`): the initial positions violate \
         it: C = 1.25 (about 0.416667 off the constraint)\n"
    );
    let check = ok(bead_in(&dir.0, &["check", "off.toml"]));
    assert!(check.contains("at t = 0: C = 1.25, Cdot = 0\n"), "{check}");

    // A parametric form 1e300 away: exact short numbers, and no `by inf`.
    let huge = bead_scene(
        "[parametric]\ncoordinates = [\"q\"]\ninitial = [1e300]\n\
         [parametric.positions]\nbead = [\"q\", \"0\"]\n",
    )
    .replace("position = [1.0, 0.0]", "position = [-1e300, 0.0]");
    dir.write("huge.toml", &huge);
    let out = bead_in(&dir.0, &["check", "huge.toml"]);
    let err = stderr(&out);
    assert_eq!(
        err,
        "warning: particle `bead`: the parametric form's initial position x(q0) = [1e300, 0] \
         differs from the scene's position [-1e300, 0] by more than the largest representable \
         number\n"
    );
    assert!(
        !has_long_number(&ok(out)),
        "check prints no 300-digit number"
    );
}

#[test]
fn divergence_names_the_time_and_keeps_the_trace_and_summary() {
    let dir = TempDir::new("diverge");
    let spring = "[[force]]\nkind = \"spring\"\nparticle = \"bead\"\nanchor = [0.0, 0.0]\nstiffness = 1e6\nrest_length = 0.0\n";
    dir.write("s.toml", &bead_scene(spring));
    let out = bead_in(
        &dir.0,
        &[
            "run",
            "s.toml",
            "--integrator",
            "euler",
            "--dt",
            "0.1",
            "--steps",
            "1000",
            "--trace",
            "t.csv",
            "--summary",
            "s.json",
        ],
    );
    let err = fails(out, 1);
    assert!(err.starts_with("error: diverged at t = "), "{err}");
    let step: u64 = err
        .split("(step ")
        .nth(1)
        .and_then(|rest| rest.split(')').next())
        .and_then(|n| n.parse().ok())
        .expect("step in message");
    let trace = std::fs::read_to_string(dir.path("t.csv")).expect("trace kept");
    // The header, then steps 0 ..= step - 1 (the last good state).
    assert_eq!(trace.lines().count() as u64, 1 + step);
    assert!(trace.lines().skip(1).all(|l| l.split(',').count() == 7));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path("s.json")).expect("summary kept"))
            .expect("JSON");
    assert_eq!(summary["completed"], false);
    assert_eq!(summary["steps"], step - 1);
    assert!(
        summary["error"]
            .as_str()
            .is_some_and(|e| e.starts_with("diverged at t = ")),
        "{summary}"
    );
}

#[test]
fn a_failed_run_still_prints_json() {
    let dir = TempDir::new("fail-json");
    let spring = "[[force]]\nkind = \"spring\"\nparticle = \"bead\"\nanchor = [0.0, 0.0]\nstiffness = 1e6\nrest_length = 0.0\n";
    dir.write("s.toml", &bead_scene(spring));
    let out = bead_in(
        &dir.0,
        &[
            "run",
            "s.toml",
            "--integrator",
            "euler",
            "--dt",
            "0.1",
            "--json",
        ],
    );
    let value: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("JSON on stdout");
    assert_eq!(value["completed"], false);
    assert!(value["error"]
        .as_str()
        .is_some_and(|e| e.contains("diverged")));
    fails(out, 1);
}

#[test]
fn a_run_that_cannot_start_says_why_and_prints_no_summary() {
    let dir = TempDir::new("fail-start");
    dir.write(
        "s.toml",
        &bead_scene(&"[[constraint]]\nexpr = \"bead.x - 1\"\n".repeat(2)),
    );
    let out = bead_in(&dir.0, &["run", "s.toml", "--json"]);
    assert_eq!(stdout(&out), "");
    let err = fails(out, 1);
    assert!(
        err.starts_with("error: the initial state cannot be simulated: at t = 0: the constraints are singular at constraint 2"),
        "{err}"
    );
}

#[test]
fn compare_applies_stabilize_to_the_implicit_run_only() {
    let plain = ok(bead(&[
        "compare",
        p(&parabola()),
        "--steps",
        "300",
        "--json",
    ]));
    let stable = ok(bead(&[
        "compare",
        p(&parabola()),
        "--steps",
        "300",
        "--json",
        "--stabilize",
        "100,20",
    ]));
    let plain: serde_json::Value = serde_json::from_str(&plain).expect("JSON");
    let stable: serde_json::Value = serde_json::from_str(&stable).expect("JSON");
    let drift = |v: &serde_json::Value| v[0]["constraint_error_final"].as_f64().expect("number");
    assert!(
        drift(&stable) < drift(&plain),
        "feedback reduces the implicit drift"
    );
    assert_eq!(
        plain[1]["particles"], stable[1]["particles"],
        "the parametric run is unchanged"
    );
}

/// A stiff spring on a bead, with a parametric form and (optionally) a constraint.
fn stiff_spring_scene(constraint: bool) -> String {
    let mut extra = String::from(
        "[[force]]\nkind = \"spring\"\nparticle = \"bead\"\nanchor = [0.0, 0.0]\nstiffness = 1e6\nrest_length = 0.0\n",
    );
    if constraint {
        extra.push_str("[[constraint]]\nexpr = \"bead.y\"\n");
    }
    extra.push_str("[parametric]\ncoordinates = [\"s\"]\ninitial = [1.0]\nrates = [0.0]\n");
    extra.push_str("[parametric.positions]\nbead = [\"s\", \"0\"]\n");
    bead_scene(&extra).replace("gravity = [0.0, 9.81]", "gravity = [0.0, 0.0]")
}

#[test]
fn compare_reports_every_failed_method_and_keeps_the_table() {
    let dir = TempDir::new("compare-fail");
    dir.write("s.toml", &stiff_spring_scene(true));
    let out = bead_in(
        &dir.0,
        &[
            "compare",
            "s.toml",
            "--integrator",
            "euler",
            "--dt",
            "0.1",
            "--steps",
            "1000",
        ],
    );
    let text = stdout(&out);
    assert!(text.contains("status"), "{text}");
    assert!(
        text.lines()
            .any(|l| l.starts_with("implicit") && l.contains("stopped at t = ")),
        "{text}"
    );
    let err = fails(out, 1);
    assert!(err.contains("error: implicit: diverged at t = "), "{err}");
    assert!(err.contains("error: parametric: diverged at t = "), "{err}");
}

#[test]
fn without_constraints_the_default_is_parametric_and_compare_runs_only_it() {
    let dir = TempDir::new("parametric-only");
    dir.write(
        "s.toml",
        &stiff_spring_scene(false).replace("stiffness = 1e6", "stiffness = 1.0"),
    );
    let out = ok(bead_in(
        &dir.0,
        &["run", "s.toml", "--steps", "10", "--json"],
    ));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value["method"], "parametric");
    let out = ok(bead_in(
        &dir.0,
        &["compare", "s.toml", "--steps", "10", "--json"],
    ));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value.as_array().map(Vec::len), Some(1));
}

/// `bead run scenes/cycloid.toml --method implicit` simulated free fall silently: the scene
/// has a parametric form and no constraints (issue 7). The library refuses it now.
#[test]
fn cycloid_refuses_the_implicit_method_and_compares_only_its_parametric_form() {
    let cycloid = scene("cycloid.toml");
    for integrator in ["rk4", "rattle", "dopri5"] {
        let err = fails(
            bead(&[
                "run",
                p(&cycloid),
                "--method",
                "implicit",
                "--integrator",
                integrator,
            ]),
            1,
        );
        assert_eq!(
            err,
            "error: the scene has no constraints, only a parametric form: its implicit form \
             would simulate free particles, not the system of its [parametric] table; use the \
             parametric method, or add [[constraint]] tables\n",
            "{integrator}"
        );
    }
    let out = ok(bead(&["compare", p(&cycloid), "--steps", "10"]));
    let methods: Vec<&str> = out
        .lines()
        .skip_while(|l| !l.starts_with("---"))
        .skip(1)
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert_eq!(methods, ["parametric"], "{out}");
    // Flags for the implicit form only are not silently dropped, nor claimed in the header.
    let out = bead(&["compare", p(&cycloid), "--steps", "10", "--project"]);
    assert_eq!(
        stderr(&out),
        "warning: --project applies to the implicit form only, and the scene has no \
         constraints: compare runs its parametric form alone; not used\n"
    );
    let text = ok(out);
    assert!(!text.contains("implicit"), "{text}");
    let out = ok(bead(&[
        "compare",
        p(&cycloid),
        "--steps",
        "10",
        "--integrators",
        "rk4,rattle",
    ]));
    assert!(out.contains("\nparametric          rk4 "), "{out}");
    assert!(out.contains("skipped: parametric x rattle: "), "{out}");
}

#[test]
fn without_a_parametric_form_compare_runs_only_implicit() {
    let dir = TempDir::new("implicit-only");
    dir.write(
        "s.toml",
        &bead_scene("[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n"),
    );
    let out = ok(bead_in(&dir.0, &["compare", "s.toml", "--steps", "10"]));
    assert!(out.lines().any(|l| l.starts_with("implicit")), "{out}");
    assert!(!out.lines().any(|l| l.starts_with("parametric")), "{out}");
}

#[test]
fn scene_warnings_go_to_stderr_and_json_stays_clean() {
    let dir = TempDir::new("warning");
    let text = std::fs::read_to_string(parabola()).expect("parabola");
    dir.write(
        "s.toml",
        &text.replace("initial = [150.0]", "initial = [100.0]"),
    );
    let out = bead_in(&dir.0, &["run", "s.toml", "--steps", "5", "--json"]);
    let err = stderr(&out);
    assert!(err.starts_with("warning: particle `bead`: "), "{err}");
    let value: serde_json::Value = serde_json::from_str(&ok(out)).expect("stdout is JSON only");
    assert_eq!(value["completed"], true);
}

#[test]
fn gauss_legendre_runs_the_parametric_form() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--method",
        "parametric",
        "--integrator",
        "gauss-legendre",
        "--steps",
        "1000",
        "--json",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value["integrator"], "gauss-legendre");
    assert_eq!(value["completed"], true);
    assert_eq!(value["steps"], 1000);
    // Bounded energy error: ~1e-6 of E0 at dt = 1/60 (rk4 loses 3e-5 over the same run).
    assert!(
        value["energy_rel_error_max"].as_f64().unwrap() < 1e-5,
        "{out}"
    );
    assert!(value.get("accepted_steps").is_none(), "{out}");
    assert!(value.get("rejected_steps").is_none(), "{out}");
}

#[test]
fn dopri5_reports_accepted_and_rejected_steps() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "dopri5",
        "--rtol",
        "1e-9",
        "--json",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value["integrator"], "dopri5");
    assert_eq!(value["completed"], true);
    assert_eq!(value["t_final"], 10.0);
    assert!(value["accepted_steps"].as_u64().unwrap() > 0, "{out}");
    assert!(value["rejected_steps"].as_u64().is_some(), "{out}");
    let text = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "dopri5",
        "--rtol",
        "1e-9",
        "--atol",
        "0",
    ]));
    assert!(text.contains("accepted steps"), "{text}");
    assert!(text.contains("rtol 1e-9, atol 0"), "{text}");
    for bad in [
        "--rtol=0",
        "--rtol=-1",
        "--rtol=nan",
        "--atol=-1e-3",
        "--atol=inf",
    ] {
        let err = fails(bead(&["run", p(&parabola()), bad]), 2);
        let flag = bad.split('=').next().unwrap();
        assert!(err.contains(flag), "{bad}: {err}");
    }
}

/// dopri5's steps/s used to count output intervals; the core counts its accepted steps now
/// (issue 7). The summary, `run`'s text and compare's table say which is which.
#[test]
fn dopri5_steps_per_second_counts_accepted_steps() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "dopri5",
        "--duration",
        "1",
        "--json",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    let accepted = value["accepted_steps"].as_u64().expect("accepted_steps");
    let wall = value["wall_seconds"].as_f64().expect("wall_seconds");
    let speed = value["steps_per_second"]
        .as_f64()
        .expect("steps_per_second");
    assert_eq!(value["steps"].as_u64(), Some(accepted), "{out}");
    assert_ne!(
        accepted, 60,
        "dopri5 takes its own steps, not the 60 output intervals"
    );
    assert!(wall > 0.0, "{out}");
    assert!(
        (speed - accepted as f64 / wall).abs() <= 1e-12 * speed,
        "{speed} != {accepted} / {wall}"
    );

    let text = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "dopri5",
        "--duration",
        "1",
    ]));
    assert!(
        text.contains("  dt           0.016666666666666666 s, the output interval\n"),
        "{text}"
    );
    assert!(
        text.contains("  output       60 intervals of dt\n"),
        "{text}"
    );
    assert!(text.contains(" accepted steps/s (wall time "), "{text}");
    let steps = text
        .lines()
        .find(|l| l.starts_with("  steps "))
        .expect("steps row");
    assert!(
        steps.contains(" accepted steps, ") && steps.contains("chosen by dopri5"),
        "{steps}"
    );

    let table = ok(bead(&[
        "compare",
        p(&parabola()),
        "--integrator",
        "dopri5",
        "--duration",
        "1",
    ]));
    assert!(
        table.contains("; 60 output intervals to t = 1 s\n"),
        "{table}"
    );
    assert!(
        table.ends_with(
            "steps/s counts integrator steps; an adaptive integrator's are its accepted \
             steps, and its dt is the output interval\n"
        ),
        "{table}"
    );
    let fixed = ok(bead(&["compare", p(&parabola()), "--duration", "1"]));
    assert!(fixed.contains("; 60 steps to t = 1 s\n"), "{fixed}");
    assert!(!fixed.contains("accepted"), "{fixed}");
}

#[test]
fn rattle_keeps_the_parabola_on_its_constraint() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "rattle",
        "--steps",
        "1000",
        "--json",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value["integrator"], "rattle");
    assert_eq!(value["completed"], true);
    // Tolerance 1e-12 of the constraint's scale (~7e4 for C = x^2 + 100 y at x = 150).
    let c_max = value["constraint_error_max"].as_f64().unwrap();
    assert!(c_max <= 1e-7, "{out}");
    let newton = value["newton_iterations_max"].as_u64().unwrap();
    assert!((1..=5).contains(&newton), "{out}");
    // All steps' iterations: at least one a step, at most 2 a step warm and 3 for the
    // first, cold (physics_rattle.rs holds that bound on RATTLE alone).
    let total = value["newton_iterations"].as_u64().unwrap();
    assert!((1000..=2001).contains(&total), "{out}");
    assert!(value.get("projected").is_none(), "{out}");
    let text = ok(bead(&[
        "run",
        p(&parabola()),
        "--integrator",
        "rattle",
        "--steps",
        "1000",
    ]));
    assert!(
        text.contains("integrator   rattle (order 2, symplectic"),
        "{text}"
    );
    // The text summary reads the same run's figures.
    let per_step = bead_report::report::sig(total as f64 / 1000.0, 3);
    assert!(
        text.contains(&format!(
            "newton       at most {newton} Newton iteration(s) per solve, {total} in all ({per_step} per step)"
        )),
        "{text}"
    );
}

/// `--project`'s Newton iterations count as the integrator's own do; an explicit integrator
/// without it solves nothing and reports nothing.
#[test]
fn projection_iterations_are_counted_over_the_run() {
    let scene = parabola();
    let run = |project: bool| {
        let mut args = vec!["run", p(&scene), "--integrator", "rk4", "--steps", "200"];
        if project {
            args.push("--project");
        }
        args.push("--json");
        let out = ok(bead(&args));
        serde_json::from_str::<serde_json::Value>(&out).expect("JSON")
    };
    let projected = run(true);
    let (max, total) = (
        projected["newton_iterations_max"].as_u64().unwrap(),
        projected["newton_iterations"].as_u64().unwrap(),
    );
    assert!(
        max >= 1 && total >= max && total <= 200 * max,
        "{projected}"
    );
    let plain = run(false);
    assert!(plain.get("newton_iterations").is_none(), "{plain}");
    assert!(plain.get("newton_iterations_max").is_none(), "{plain}");
}

#[test]
fn rattle_on_the_parametric_form_is_an_error() {
    let err = fails(
        bead(&[
            "run",
            p(&parabola()),
            "--method",
            "parametric",
            "--integrator",
            "rattle",
        ]),
        1,
    );
    assert_eq!(
        err,
        "error: rattle needs the implicit form: the parametric form has no constraints to project onto (it stays on them by construction); use gauss-legendre or rk4 with the parametric form\n"
    );
}

#[test]
fn projection_with_dopri5_is_an_error_in_the_librarys_words() {
    // The viewer replies with the same words (crates/bead-viewer/tests/session.rs).
    let err = fails(
        bead(&["run", p(&parabola()), "--integrator", "dopri5", "--project"]),
        1,
    );
    let expected = bead::simulate::ConfigError::ProjectionWithAdaptive(
        bead::integrate::IntegratorKind::Dopri5,
    );
    assert_eq!(err, format!("error: {expected}\n"));
}

#[test]
fn project_keeps_rk4_on_the_constraint_and_says_so() {
    let out = ok(bead(&[
        "run",
        p(&parabola()),
        "--project",
        "--steps",
        "1000",
        "--json",
    ]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(value["projected"], true);
    assert_eq!(value["completed"], true);
    assert!(
        value["constraint_error_max"].as_f64().unwrap() <= 1e-7,
        "{out}"
    );
    let text = ok(bead(&[
        "run",
        p(&parabola()),
        "--project",
        "--steps",
        "100",
    ]));
    assert!(text.contains("projection   on:"), "{text}");
    let compare = ok(bead(&[
        "compare",
        p(&parabola()),
        "--project",
        "--steps",
        "100",
    ]));
    assert!(compare.contains("--project"), "{compare}");
    let err = fails(
        bead(&["run", p(&parabola()), "--method", "parametric", "--project"]),
        1,
    );
    assert_eq!(
        err,
        "error: projection onto the constraints needs the implicit form: the parametric form stays on its constraints by construction, so there is nothing to project\n"
    );
}

// ---- compare over integrators x dts, --report, bead plot ----

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name)
}

/// Every `src="..."` and `href="..."` value of an HTML text.
fn html_references(html: &str) -> Vec<String> {
    let mut refs = Vec::new();
    for attribute in ["src=\"", "href=\""] {
        let mut rest = html;
        while let Some(i) = rest.find(attribute) {
            rest = &rest[i + attribute.len()..];
            let end = rest.find('"').expect("closing quote");
            refs.push(rest[..end].to_string());
            rest = &rest[end..];
        }
    }
    refs
}

/// Decode a PNG; returns (width, height, number of non-white pixels).
fn decode_png(path: &Path) -> (u32, u32, usize) {
    let decoder = png::Decoder::new(std::fs::File::open(path).expect("open png"));
    let mut reader = decoder.read_info().expect("png header");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("png data");
    let channels = info.color_type.samples();
    let inked = buf[..info.buffer_size()]
        .chunks(channels)
        .filter(|p| p.iter().take(3).any(|&c| c < 200))
        .count();
    (info.width, info.height, inked)
}

/// The rows of the grid table below its rule, split on whitespace.
fn grid_rows(text: &str) -> Vec<Vec<String>> {
    text.lines()
        .skip_while(|l| !l.starts_with("---"))
        .skip(1)
        .take_while(|l| !l.starts_with("skipped:") && !l.starts_with("report:") && !l.is_empty())
        .map(|l| l.split_whitespace().map(str::to_string).collect())
        .collect()
}

#[test]
fn compare_grid_writes_a_self_contained_report_with_png_and_svg_plots() {
    let dir = TempDir::new("report");
    let report = dir.path("report");
    let out = ok(bead_in(
        &dir.0,
        &[
            "compare",
            p(&parabola()),
            "--integrators",
            "rk4,euler",
            "--dts",
            "1/30,1/60",
            "--duration",
            "2",
            "--report",
            p(&report),
        ],
    ));
    let rows = grid_rows(&out);
    assert_eq!(rows.len(), 8, "2 methods x 2 integrators x 2 dts:\n{out}");
    for method in ["implicit", "parametric"] {
        for integrator in ["rk4", "euler"] {
            for dt in ["1/30", "1/60"] {
                assert!(
                    rows.iter()
                        .any(|r| r[0] == method && r[1] == integrator && r[2] == dt),
                    "missing {method} {integrator} {dt}:\n{out}"
                );
            }
        }
    }
    let html = std::fs::read_to_string(report.join("report.html")).expect("report.html");
    let runs_table = html
        .split("<h2>Runs</h2>")
        .nth(1)
        .and_then(|rest| rest.split("</table>").next())
        .expect("the runs table");
    assert_eq!(runs_table.matches("<tr>").count(), 9, "header + 8 rows");
    let refs = html_references(&html);
    assert!(!refs.is_empty());
    for r in &refs {
        assert!(
            !r.contains("://") && !r.starts_with('/'),
            "external reference {r}"
        );
        assert!(report.join(r).is_file(), "{r} does not exist");
    }
    assert!(html.contains("<svg"), "SVGs are inline");
    assert!(!html.contains("<script"));
    for name in [
        "constraint_error",
        "energy_error",
        "trajectories",
        "work_precision",
    ] {
        let svg = std::fs::read_to_string(report.join(format!("{name}.svg"))).expect("svg");
        let doc = roxmltree::Document::parse(&svg).unwrap_or_else(|e| panic!("{name}.svg: {e}"));
        assert_eq!(doc.root_element().tag_name().name(), "svg");
        let (w, h, inked) = decode_png(&report.join(format!("{name}.png")));
        assert!(w >= 600 && h >= 400, "{name}.png is {w}x{h}");
        assert!(
            inked > 1000,
            "{name}.png looks blank ({inked} inked pixels)"
        );
        assert!(
            refs.contains(&format!("{name}.png")),
            "{name}.png not linked"
        );
    }
}

/// The points of every series line of an SVG the report wrote, by panel and series: the
/// `data-panel` and `data-series` attributes of its polylines, pieces of one series
/// concatenated.
/// (panel, series label, pixel points) of one drawn series.
type DrawnSeries = (String, String, Vec<(i32, i32)>);

fn svg_series(svg: &str) -> Vec<DrawnSeries> {
    let doc = roxmltree::Document::parse(svg).expect("SVG parses");
    let mut series: Vec<DrawnSeries> = Vec::new();
    for node in doc.descendants().filter(|n| n.has_tag_name("polyline")) {
        let (Some(panel), Some(label)) =
            (node.attribute("data-panel"), node.attribute("data-series"))
        else {
            continue;
        };
        let points: Vec<(i32, i32)> = node
            .attribute("points")
            .unwrap_or("")
            .split_whitespace()
            .map(|p| {
                let (x, y) = p.split_once(',').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect();
        match series.iter_mut().find(|s| s.0 == panel && s.1 == label) {
            Some(s) => s.2.extend(points),
            None => series.push((panel.to_string(), label.to_string(), points)),
        }
    }
    series
}

/// A reviewer's grid: 3 integrators x 3 dts, the implicit form with and without projection
/// and the parametric form (17 runs), 10 s each. The whole report directory stays under
/// 2 MB; the log panels draw envelopes (running maxima: each line only rises on the page);
/// no drawn series has more than 1000 points; the HTML states the scene (its file text,
/// escaped, the parameter set by --set) and the command that reproduces it.
#[test]
fn a_three_by_three_grid_report_is_small_draws_envelopes_and_states_its_scene() {
    let dir = TempDir::new("grid-report");
    let report = dir.path("r");
    let scene = parabola();
    let args = [
        "compare",
        p(&scene),
        "--integrators",
        "rk4,rattle,verlet",
        "--dts",
        "1/60,1/120,1/240",
        "--project",
        "--set",
        "g=400",
        "--report",
        p(&report),
    ];
    let out = ok(bead_in(&dir.0, &args));
    assert!(grid_rows(&out).len() >= 15, "{out}");
    let total: u64 = std::fs::read_dir(&report)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    assert!(
        total < 2_000_000,
        "the report directory holds {total} bytes"
    );
    for name in ["constraint_error", "energy_error", "trajectories"] {
        let svg = std::fs::read_to_string(report.join(format!("{name}.svg"))).unwrap();
        let series = svg_series(&svg);
        assert!(series.len() >= 15, "{name}: {} series", series.len());
        for (panel, label, points) in &series {
            assert!(
                points.len() <= 1000,
                "{name} panel {panel} {label}: {} points",
                points.len()
            );
            // The log panels (the lower panel of the two time-series figures): envelopes,
            // drawn left to right and never down the page (image y grows downwards).
            if name != "trajectories" && panel == "1" {
                assert!(
                    points
                        .windows(2)
                        .all(|w| w[1].0 >= w[0].0 && w[1].1 <= w[0].1),
                    "{name} {label} is not a running max: {points:?}"
                );
            }
        }
    }
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    assert!(
        html.contains("expr = &quot;bead.x^2 + 100*bead.y&quot;"),
        "the scene's constraint line, escaped"
    );
    assert!(html.contains("<pre class=\"scene\">"));
    let command = html
        .split("<pre class=\"command\">")
        .nth(1)
        .and_then(|rest| rest.split("</pre>").next())
        .expect("the command line");
    assert_eq!(command, format!("bead {}", args.join(" ")));
    assert!(
        html.contains("<td>g</td><td>400 (--set)</td><td>px/s^2</td>"),
        "the parameter as set"
    );
    assert!(html.contains("bead: mass 1, position (150, -225), velocity (0, 0)"));
    assert!(html.contains("distance to the constraint set (closest point)"));
}

#[test]
fn compare_grid_skips_combinations_that_cannot_run_and_says_why() {
    let out = ok(bead(&[
        "compare",
        p(&parabola()),
        "--integrators",
        "rk4,rattle",
        "--dts",
        "0.01",
        "--duration",
        "0.5",
    ]));
    assert_eq!(grid_rows(&out).len(), 3, "{out}");
    assert!(
        out.contains("skipped: parametric x rattle: "),
        "the reason is printed:\n{out}"
    );
}

#[test]
fn compare_period_of_the_circle_matches_the_large_amplitude_pendulum() {
    // T = 4 sqrt(L/g) K(k), k = sin(theta0/2), theta0 = 60 degrees; K by the AGM.
    let (mut a, mut b) = (1.0f64, (1.0f64 - 0.25).sqrt());
    for _ in 0..20 {
        (a, b) = ((a + b) / 2.0, (a * b).sqrt());
    }
    let k = std::f64::consts::PI / (2.0 * a);
    let expected = 4.0 * (1.0f64 / 9.81).sqrt() * k;
    assert!((expected - 2.153).abs() < 1e-3, "{expected}");
    let out = ok(bead(&[
        "compare",
        p(&scene("circle.toml")),
        "--integrators",
        "rk4",
        "--dts",
        "1/1000",
        "--duration",
        "10",
    ]));
    let rows = grid_rows(&out);
    assert_eq!(rows.len(), 2, "{out}");
    for row in rows {
        // method, integrator, dt, final and max constraint error, max |C|/|grad C|, max rel
        // energy error, period, steps/s.
        let period: f64 = row[7]
            .parse()
            .unwrap_or_else(|_| panic!("no period in {row:?}"));
        assert!(
            ((period - expected) / expected).abs() < 1e-3,
            "{}: period {period}, expected {expected}",
            row[0]
        );
    }
}

#[test]
fn dts_entries_must_be_positive_numbers_or_fractions() {
    for (bad, message) in [("1/0", "must be finite, got inf"), ("abc", "not a number")] {
        let err = fails(
            bead(&["compare", p(&parabola()), "--dts", &format!("1/60,{bad}")]),
            2,
        );
        assert!(err.contains(message), "{bad}: {err}");
        assert!(err.contains("--dts"), "{bad}: {err}");
    }
}

/// A trace written by `bead run --trace` in `dir`.
fn run_trace(dir: &TempDir) -> PathBuf {
    let trace = dir.path("t.csv");
    ok(bead_in(
        &dir.0,
        &[
            "run",
            p(&parabola()),
            "--steps",
            "300",
            "--trace",
            p(&trace),
        ],
    ));
    trace
}

#[test]
fn plot_writes_png_by_default_and_svg_by_extension() {
    let dir = TempDir::new("plot");
    let trace = run_trace(&dir);
    ok(bead_in(&dir.0, &["plot", p(&trace)]));
    let (w, h, inked) = decode_png(&dir.path("t.png"));
    assert!(w > 0 && h > 0 && inked > 1000, "{w}x{h}, {inked}");
    let svg = dir.path("cols.svg");
    ok(bead_in(
        &dir.0,
        &[
            "plot",
            p(&trace),
            "--columns",
            "bead.x,constraint_error",
            "--log",
            "-o",
            p(&svg),
        ],
    ));
    let text = std::fs::read_to_string(&svg).expect("svg");
    roxmltree::Document::parse(&text).expect("the SVG parses");
    assert!(text.contains("bead.x") && text.contains("constraint_error"));
}

/// The texts of an SVG's `<text>` elements with their x.
fn svg_texts(svg: &str) -> Vec<(String, f64)> {
    let doc = roxmltree::Document::parse(svg).expect("SVG parses");
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .map(|n| {
            (
                n.text().unwrap_or("").trim().to_string(),
                n.attribute("x")
                    .and_then(|x| x.parse().ok())
                    .unwrap_or(f64::NAN),
            )
        })
        .collect()
}

/// `bead plot` as a reviewer found it: a near-constant column garbled its tick labels
/// (-4.9050000000x); --log on data without a value above zero drew an invented frame;
/// stacked panels' time axes did not line up. Now: labels offset by a round number that the
/// axis label states, a clear error (or, beside other columns, a panel that says "no
/// data"), and one x range and plotting width for stacked panels.
#[test]
fn plot_offsets_near_constant_ticks_says_no_data_and_aligns_time_axes() {
    let dir = TempDir::new("plot-honest");
    let mut csv = String::from("t,e,a,b\n");
    for k in 0..200 {
        let t = k as f64 * 0.05;
        let b = if t < 5.0 {
            "nan".to_string()
        } else {
            format!("{}", 0.3 + t)
        };
        csv.push_str(&format!(
            "{t},{:?},{},{b}\n",
            -4.905 + k as f64 * 1e-12,
            -1.0 - t * 0.1
        ));
    }
    std::fs::write(dir.path("c.csv"), csv).unwrap();
    ok(bead_in(
        &dir.0,
        &["plot", "c.csv", "--columns", "e", "-o", "e.svg"],
    ));
    let texts = svg_texts(&std::fs::read_to_string(dir.path("e.svg")).unwrap());
    assert!(
        texts
            .iter()
            .any(|(t, _)| t.ends_with("[value = tick - 4.905]")),
        "the offset in the axis label: {texts:?}"
    );
    for (text, _) in &texts {
        assert!(
            text.len() <= 40 && !text.contains("4.9050000"),
            "garbled label {text:?}"
        );
    }
    // --log on a column without a value above zero: an error naming it, no file.
    let err = fails(
        bead_in(
            &dir.0,
            &["plot", "c.csv", "--columns", "a", "--log", "-o", "a.svg"],
        ),
        1,
    );
    assert!(
        err.contains("--log: column `a` has no value above zero") && err.contains("without --log"),
        "{err}"
    );
    assert!(!dir.path("a.svg").exists());
    // Beside a column that has some: a warning and an honest empty panel.
    let out = bead_in(
        &dir.0,
        &["plot", "c.csv", "--columns", "a,b", "--log", "-o", "ab.svg"],
    );
    assert!(stderr(&out).contains("column `a` has no value above zero; its panel says so"));
    ok(out);
    let ab = std::fs::read_to_string(dir.path("ab.svg")).unwrap();
    assert!(ab.contains("no data: no value above zero for the log y axis"));
    // Stacked panels: `e` spans t = 0..10, `b` only 5..10; both axes the same, so every
    // time tick sits at the same x in both panels.
    ok(bead_in(
        &dir.0,
        &["plot", "c.csv", "--columns", "a,b", "-o", "stack.svg"],
    ));
    let texts = svg_texts(&std::fs::read_to_string(dir.path("stack.svg")).unwrap());
    for tick in ["0", "2", "4"] {
        let at: Vec<f64> = texts
            .iter()
            .filter(|(t, _)| t == tick)
            .map(|p| p.1)
            .collect();
        assert_eq!(at.len(), 2, "tick {tick} once per panel: {texts:?}");
        assert_eq!(at[0], at[1], "tick {tick} at different x");
    }
}

/// A +y-down scene's path (a particle's x against its y, with --scene): equal scales on
/// both axes, gravity pointing down the page, units from the scene.
#[test]
fn plot_draws_a_y_down_path_at_equal_scales_with_the_scenes_units() {
    let dir = TempDir::new("plot-path");
    let scene = parabola();
    ok(bead_in(
        &dir.0,
        &["run", p(&scene), "--duration", "3", "--trace", "p.csv"],
    ));
    let path_of = |extra: &[&str], out: &str| {
        let mut args = vec![
            "plot",
            "p.csv",
            "--x",
            "bead.x",
            "--columns",
            "bead.y",
            "-o",
            out,
        ];
        args.extend_from_slice(extra);
        ok(bead_in(&dir.0, &args));
        let svg = std::fs::read_to_string(dir.path(out)).unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let line = doc
            .descendants()
            .find(|n| n.attribute("data-series") == Some("bead.y"))
            .expect("the path");
        let points: Vec<(f64, f64)> = line
            .attribute("points")
            .unwrap()
            .split_whitespace()
            .map(|p| {
                let (x, y) = p.split_once(',').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect();
        (svg, points)
    };
    let (svg, points) = path_of(&["--scene", p(&scene)], "down.svg");
    assert!(svg.contains("bead.y (px), pointing down") && svg.contains("bead.x (px)"));
    let x = |p: &(f64, f64)| p.0;
    let y = |p: &(f64, f64)| p.1;
    let (x0, x1) = (
        points.iter().map(x).fold(f64::MAX, f64::min),
        points.iter().map(x).fold(f64::MIN, f64::max),
    );
    let (y0, y1) = (
        points.iter().map(y).fold(f64::MAX, f64::min),
        points.iter().map(y).fold(f64::MIN, f64::max),
    );
    // The bead swings over x in [-150, 150] and y in [-225, 0]: 300 by 225 at equal scales.
    let ratio = (x1 - x0) / (y1 - y0);
    assert!((ratio - 300.0 / 225.0).abs() < 0.05, "aspect {ratio}");
    // The bottom of the valley (lowest on the page: largest image y) is in the middle, and
    // the start (150, -225) at the top.
    let bottom = points.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    assert!(
        (bottom.0 - 0.5 * (x0 + x1)).abs() < 0.05 * (x1 - x0),
        "{bottom:?}"
    );
    assert!(
        (points[0].1 - y0).abs() <= 2.0,
        "the start is at the top: {:?}",
        points[0]
    );
    // Without the scene: equal scales still, y up, no invented unit.
    let (svg, points) = path_of(&[], "up.svg");
    assert!(!svg.contains("scene units") && !svg.contains("pointing down"));
    let top = points.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    assert!(
        (top.0 - 0.5 * (x0 + x1)).abs() < 0.05 * (x1 - x0),
        "y up: the valley's bottom at the top {top:?}"
    );
}

/// A CSV with nothing to plot (only `t`, or no finite value besides it) made `bead plot`
/// write a blank PNG and exit 0 (issue 7). It is an error, and no file is written.
#[test]
fn plot_refuses_a_trace_with_nothing_to_plot() {
    let dir = TempDir::new("plot-nothing");
    for (file, text, message) in [
        (
            "only_t.csv",
            "t\n0\n0.1\n",
            "nothing to plot: the trace has only the column `t`",
        ),
        (
            "nan.csv",
            "t,energy\n0,nan\n0.1,inf\n",
            "nothing to plot: column `energy` has no finite value in 2 rows",
        ),
        (
            "no_t.csv",
            "t,energy,bead.x\nnan,1,2\n",
            "nothing to plot: column `t` has no finite value in 1 row",
        ),
        (
            "empty.csv",
            "",
            "the file is empty; expected a header row starting with `t`",
        ),
        ("header.csv", "t,energy\n", "no data rows after the header"),
        (
            "blank_rows.csv",
            "t,energy\n\n\n",
            "no data rows after the header",
        ),
    ] {
        dir.write(file, text);
        let err = fails(bead_in(&dir.0, &["plot", file]), 1);
        assert_eq!(err, format!("error: {file}: {message}\n"));
    }
    let err = fails(
        bead_in(
            &dir.0,
            &["plot", "nan.csv", "--columns", "energy", "-o", "x.svg"],
        ),
        1,
    );
    assert!(err.contains("column `energy` has no finite value"), "{err}");
    let err = fails(bead_in(&dir.0, &["plot", "nan.csv", "--columns", "t"]), 1);
    assert_eq!(
        err,
        "error: `t` is the horizontal axis of every panel; choose among energy\n"
    );
    let written: Vec<String> = std::fs::read_dir(&dir.0)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".png") || n.ends_with(".svg"))
        .collect();
    assert!(written.is_empty(), "{written:?}");
    // One empty column among others is plotted, with a warning.
    dir.write("half.csv", "t,energy,bead.x\n0,nan,1\n0.1,nan,2\n");
    let out = bead_in(&dir.0, &["plot", "half.csv", "--columns", "energy,bead.x"]);
    assert_eq!(
        stderr(&out),
        "warning: half.csv: column `energy` has no finite value; its panel is empty\n"
    );
    assert_eq!(ok(out), "wrote half.png\n");
}

#[test]
fn plot_errors_name_the_problem() {
    let dir = TempDir::new("plot-errors");
    let trace = run_trace(&dir);
    let err = fails(
        bead_in(&dir.0, &["plot", p(&trace), "--columns", "energy,bogus"]),
        1,
    );
    assert!(err.contains("unknown column `bogus`"), "{err}");
    assert!(err.contains("bead.x, bead.y"), "lists the columns: {err}");

    let err = fails(
        bead_in(&dir.0, &["plot", p(&trace), "-o", p(&dir.path("x.jpg"))]),
        1,
    );
    assert!(err.contains("use a .png or .svg"), "{err}");

    let bad = dir.write("bad.csv", "t,energy\n0,1\n0.1,x\n");
    let err = fails(bead_in(&dir.0, &["plot", p(&bad)]), 1);
    assert!(err.contains("bad.csv:3:"), "line number: {err}");
    assert!(err.contains("`x`"), "{err}");

    let short = dir.write("short.csv", "t,energy\n0,1\n0.1\n");
    let err = fails(bead_in(&dir.0, &["plot", p(&short)]), 1);
    assert!(
        err.contains("short.csv:3:") && err.contains("expected 2 fields"),
        "{err}"
    );

    let no_t = dir.write("no_t.csv", "x,energy\n0,1\n");
    let err = fails(bead_in(&dir.0, &["plot", p(&no_t)]), 1);
    assert!(err.contains("no_t.csv:1:") && err.contains("`t`"), "{err}");
}

/// `bead plot --x` draws one column against another (a phase plot, points in time order) and
/// `--overlay` puts every column in one panel; an unknown `--x` is named with the columns.
#[test]
fn plot_draws_phase_plots_and_overlays() {
    let dir = TempDir::new("plot-phase");
    let trace = run_trace(&dir);
    let svg = dir.path("phase.svg");
    ok(bead_in(
        &dir.0,
        &[
            "plot",
            p(&trace),
            "--x",
            "bead.x",
            "--columns",
            "bead.vx",
            "-o",
            p(&svg),
        ],
    ));
    let text = std::fs::read_to_string(&svg).expect("svg");
    roxmltree::Document::parse(&text).expect("the SVG parses");
    assert!(text.contains("bead.vx against bead.x"), "panel title");
    // Named by its column, without a unit the trace does not know (--scene gives one).
    assert!(
        svg_texts(&text).iter().any(|(t, _)| t == "bead.x"),
        "x axis named by its column"
    );

    let overlay = dir.path("overlay.svg");
    ok(bead_in(
        &dir.0,
        &[
            "plot",
            p(&trace),
            "--columns",
            "bead.x,bead.y",
            "--overlay",
            "-o",
            p(&overlay),
        ],
    ));
    let text = std::fs::read_to_string(&overlay).expect("svg");
    assert!(
        text.contains("bead.x, bead.y"),
        "one panel titled by both columns"
    );
    // Two series, the second dashed: one polyline with a dash pattern (not one per dash).
    let series = svg_series(&text);
    assert_eq!(series.len(), 2, "{series:?}");
    assert_eq!(text.matches("stroke-dasharray").count(), 1);

    let err = fails(bead_in(&dir.0, &["plot", p(&trace), "--x", "bogus"]), 1);
    assert!(
        err.contains("--x: unknown column `bogus`") && err.contains("bead.x"),
        "{err}"
    );
    let err = fails(
        bead_in(
            &dir.0,
            &["plot", p(&trace), "--x", "bead.x", "--columns", "bead.x"],
        ),
        1,
    );
    assert!(err.contains("`bead.x` is the horizontal axis"), "{err}");
}

/// A scene whose `[run]` asks for rattle and that also has a parametric form: `bead run` uses
/// the implicit form and works, so `bead check` passes, noting that the parametric form is not
/// for rattle (as `bead compare` skips it), instead of failing the scene.
#[test]
fn check_passes_a_rattle_scene_that_also_has_a_parametric_form() {
    let dir = TempDir::new("check-rattle-both");
    let scene = bead_scene(
        "[[constraint]]\nexpr = \"bead.x^2 + bead.y^2 - 1\"\n\
         [parametric]\ncoordinates = [\"th\"]\ninitial = [1.5707963267948966]\n\
         [parametric.positions]\nbead = [\"sin(th)\", \"cos(th)\"]\n\
         [run]\nintegrator = \"rattle\"\n",
    );
    dir.write("s.toml", &scene);
    let text = ok(bead_in(&dir.0, &["check", "s.toml"]));
    assert!(text.contains("implicit     ok"), "{text}");
    assert!(
        text.contains("parametric   not with these settings (bead run uses the other form): rattle needs the implicit form"),
        "{text}"
    );
    ok(bead_in(&dir.0, &["run", "s.toml", "--steps", "10"]));
}

/// dopri5 chooses its own steps: on a grid it runs once per tolerance (`--rtols`), never once
/// per dt (issue 9), and a tolerance list without it is refused rather than ignored.
#[test]
fn compare_runs_the_adaptive_integrator_once_per_tolerance() {
    let scene = parabola();
    let grid = |extra: &[&str]| -> Vec<serde_json::Value> {
        let mut args = vec![
            "compare",
            p(&scene),
            "--integrators",
            "rk4,dopri5",
            "--dts",
            "1/60,1/120",
            "--duration",
            "2",
        ];
        args.extend_from_slice(extra);
        args.push("--json");
        let out = ok(bead(&args));
        serde_json::from_str::<Vec<serde_json::Value>>(&out).expect("JSON array")
    };
    let of = |runs: &[serde_json::Value], method: &str, integrator: &str| -> Vec<u64> {
        runs.iter()
            .filter(|r| r["method"] == method && r["integrator"] == integrator)
            .map(|r| r["steps"].as_u64().unwrap())
            .collect()
    };
    let once = grid(&[]);
    for method in ["implicit", "parametric"] {
        assert_eq!(of(&once, method, "rk4"), vec![120, 240], "{once:?}");
        assert_eq!(of(&once, method, "dopri5").len(), 1, "{once:?}");
    }
    let tolerances = grid(&["--rtols", "1e-5,1e-10"]);
    for method in ["implicit", "parametric"] {
        let steps = of(&tolerances, method, "dopri5");
        assert_eq!(steps.len(), 2, "{tolerances:?}");
        assert!(
            steps[1] > 2 * steps[0],
            "tighter takes more steps: {steps:?}"
        );
    }
    let text = ok(bead(&[
        "compare",
        p(&parabola()),
        "--integrators",
        "rk4,dopri5",
        "--dts",
        "1/60,1/120",
        "--duration",
        "2",
        "--rtols",
        "1e-5,1e-10",
    ]));
    assert!(
        text.contains("adaptive, rtol 1e-10 (output every 1/120)"),
        "{text}"
    );
    let err = fails(
        bead(&[
            "compare",
            p(&parabola()),
            "--integrators",
            "rk4",
            "--rtols",
            "1e-6",
        ]),
        1,
    );
    assert!(err.contains("--rtols") && err.contains("dopri5"), "{err}");
    let err = fails(
        bead(&[
            "compare",
            p(&parabola()),
            "--integrators",
            "dopri5",
            "--rtols",
            "1e-6,0",
        ]),
        2,
    );
    assert!(err.contains("--rtols"), "{err}");
}

/// `bead sweep --initial`: the start's column is `start.bead.x`, apart from the final
/// `bead.x`; every column name once; the bead starts on the curve at that x.
#[test]
fn sweep_over_the_start_names_its_column_apart_from_the_final_state() {
    let out = ok(bead(&[
        "sweep",
        p(&parabola()),
        "--initial",
        "bead.x=30:90:3",
        "--steps",
        "1",
        "--dt",
        "1e-9",
    ]));
    let mut lines = out.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let mut unique = header.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), header.len(), "{header:?}");
    let (start, x, y) = (
        header.iter().position(|h| *h == "start.bead.x").unwrap(),
        header.iter().position(|h| *h == "bead.x").unwrap(),
        header.iter().position(|h| *h == "bead.y").unwrap(),
    );
    for (line, expected) in lines.zip([30.0, 60.0, 90.0]) {
        let row: Vec<&str> = line.split(',').collect();
        let value = |k: usize| row[k].parse::<f64>().unwrap();
        assert_eq!(value(start), expected);
        assert!((value(x) - expected).abs() < 1e-6, "{line}");
        assert!(
            (value(y) + expected * expected / 100.0).abs() < 1e-6,
            "{line}"
        );
    }
    let error = fails(
        bead(&["sweep", p(&parabola()), "--initial", "bead.w=1:2:2"]),
        2,
    );
    assert!(
        error.contains("--initial: unknown") && error.contains("NAME.x"),
        "{error}"
    );
}

/// `[[event]]` tables in the scene: `bead run` prints each event's crossing times, the JSON
/// summary lists them, and the run's trace and end are those without the non-terminal
/// events; a terminal event stops the run. The times against the pendulum's T/4 + kT from
/// 60 degrees (T by the arithmetic-geometric mean).
#[test]
fn scene_event_tables_are_reported_in_the_summary_and_the_text() {
    let dir = TempDir::new("events");
    let circle = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/circle.toml");
    let base = std::fs::read_to_string(&circle).unwrap();
    let tables = "\n[[event]]\nexpr = \"bead.x\"\ndirection = -1\n\n[[event]]\nexpr = \"bead.vx - 1\"\ndirection = 1\nterminal = true\n";
    std::fs::write(dir.path("events.toml"), format!("{base}{tables}")).unwrap();
    let (mut a, mut b) = (1.0f64, (1.0f64 - 0.25).sqrt());
    for _ in 0..40 {
        (a, b) = ((a + b) / 2.0, (a * b).sqrt());
    }
    let period = 4.0 / 9.81f64.sqrt() * std::f64::consts::PI / (2.0 * a);
    let json = ok(bead_in(&dir.0, &["run", "events.toml", "--json"]));
    let summary: serde_json::Value = serde_json::from_str(&json).unwrap();
    let events = summary["events"].as_array().unwrap();
    assert_eq!(events.len(), 2);
    assert_eq!(events[0]["when"], "bead.x");
    assert_eq!(events[0]["direction"], -1);
    assert_eq!(events[1]["terminal"], true);
    // vx - 1 crosses upward on the way back: after 3T/4 ... the run stops there, before
    // 5T/4, and bead.x crossed downward once, at T/4.
    let stop = summary["stop_time"].as_f64().unwrap();
    assert_eq!(summary["stop_when"], "bead.vx - 1");
    assert_eq!(events[1]["times"][0].as_f64().unwrap(), stop);
    let down = events[0]["times"].as_array().unwrap();
    assert_eq!(down.len(), 1, "{json}");
    assert!((down[0].as_f64().unwrap() - period / 4.0).abs() < 1e-9);
    assert!(stop > period / 2.0 && stop < period, "{stop} {period}");
    let text = ok(bead_in(&dir.0, &["run", "events.toml"]));
    assert!(
        text.contains("  event 1      bead.x (downward): crossed at t = "),
        "{text}"
    );
    assert!(
        text.contains("  event 2      bead.vx - 1 (upward, terminal): crossed at t = "),
        "{text}"
    );
    // A table with a bad direction is refused where it is.
    std::fs::write(
        dir.path("bad.toml"),
        format!("{base}\n[[event]]\nexpr = \"bead.x\"\ndirection = 3\n"),
    )
    .unwrap();
    let error = fails(bead_in(&dir.0, &["run", "bad.toml"]), 1);
    assert!(
        error.contains("bad.toml:") && error.contains("event 1: `direction` must be 1"),
        "{error}"
    );
}

/// `bead order` on the article's scene prints the orders each method reaches (rk4 4 on the
/// implicit form, rattle 2, rattle4 4, gauss-legendre 4 in q) at the last halving it can
/// measure, writes the work-precision plot, and refuses what halving dt cannot study.
#[test]
fn order_prints_each_methods_order_and_writes_the_plot() {
    let dir = TempDir::new("order");
    let plot = dir.path("order.png");
    let out = ok(bead(&[
        "order",
        p(&parabola()),
        "--integrators",
        "rk4,rattle,rattle4,gauss-legendre",
        "--plot",
        p(&plot),
    ]));
    let position_order = |label: &str| -> f64 {
        let line = out
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{label}: position ")))
            .unwrap_or_else(|| panic!("no orders of {label}:\n{out}"));
        let value = line.split("position ").nth(1).unwrap();
        value.split(',').next().unwrap().parse().unwrap()
    };
    for (label, order) in [
        ("implicit rk4", 4.0),
        ("implicit rattle", 2.0),
        ("implicit rattle4", 4.0),
        ("parametric gauss-legendre", 4.0),
    ] {
        let observed = position_order(label);
        assert!((observed - order).abs() < 0.1, "{label}: {observed}\n{out}");
    }
    assert!(out.contains("skipped: parametric x rattle4"), "{out}");
    assert!(out.contains("   1/960 "), "{out}");
    let png = std::fs::read(&plot).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );

    let error = fails(
        bead(&["order", p(&parabola()), "--integrators", "dopri5"]),
        1,
    );
    assert!(error.contains("chooses its own steps"), "{error}");
    let error = fails(bead(&["order", p(&parabola()), "--duration", "0.1001"]), 1);
    assert!(error.contains("not a whole number of steps"), "{error}");
    let error = fails(bead(&["order", p(&parabola()), "--halvings", "13"]), 2);
    assert!(error.contains("--halvings"), "{error}");
}

/// `bead order` goes on past a step size whose run fails: explicit Euler on the article's
/// scene fails at dt = 0.2 in both forms, and the table says why in that step's row, then
/// measures dt = 1/10 and 1/20 and their order (before, the series ended at the failure and
/// reported no order).
#[test]
fn order_goes_on_past_a_failed_coarse_step() {
    let out = ok(bead(&[
        "order",
        p(&parabola()),
        "--integrators",
        "euler",
        "--dt",
        "0.2",
        "--duration",
        "10",
        "--halvings",
        "2",
    ]));
    for method in ["implicit", "parametric"] {
        let rows: Vec<&str> = out
            .lines()
            .filter(|l| l.starts_with(method) && l.contains(" euler "))
            .collect();
        assert_eq!(rows.len(), 3, "{method}:\n{out}");
        assert!(
            rows[0].contains(" 1/5 failed: ") && rows[0].contains("reduce dt"),
            "{method}:\n{out}"
        );
        assert!(
            rows[1].contains(" 1/10 ") && rows[2].contains(" 1/20 "),
            "{out}"
        );
        let orders = out
            .lines()
            .find(|l| {
                l.trim_start()
                    .starts_with(&format!("{method} euler: position "))
            })
            .unwrap_or_else(|| panic!("no orders of {method} euler:\n{out}"));
        assert!(!orders.contains("position -,"), "{orders}\n{out}");
    }
}

/// `bead run scenes/bounce.toml` (the README's figures): the switches counted in the text and
/// the JSON, and the impacts' energy equal to the ledger's work, -W (nothing else does work).
#[test]
fn run_counts_the_bounces_of_a_unilateral_scene() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/bounce.toml");
    let out = ok(bead(&["run", scene]));
    assert!(
        out.contains(
            "contacts     0 detaches, 1 landing, 17 bounces on the unilateral constraints; the impacts took 42863.3 of kinetic energy"
        ),
        "{out}"
    );
    let out = ok(bead(&["run", scene, "--json"]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    let contacts = &value["contacts"];
    assert_eq!(contacts["bounces"], 17);
    let dissipated = contacts["dissipated"].as_f64().unwrap();
    let work = value["work_final"].as_f64().unwrap();
    assert!(
        (dissipated + work).abs() < 1e-9 * dissipated,
        "{dissipated} vs W {work}"
    );
    // Both forms: the same switches, the same energy taken.
    let out = ok(bead(&["compare", scene, "--json"]));
    let value: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    let forms = value.as_array().expect("one summary per form");
    assert_eq!(forms.len(), 2);
    for key in ["detaches", "landings", "bounces"] {
        assert_eq!(
            forms[0]["contacts"][key], forms[1]["contacts"][key],
            "{key}"
        );
    }
    let (a, b) = (
        forms[0]["contacts"]["dissipated"].as_f64().unwrap(),
        forms[1]["contacts"]["dissipated"].as_f64().unwrap(),
    );
    assert!((a - b).abs() < 1e-6 * a, "{a} vs {b}");
}

/// `bead args` run in `dir` and sent SIGINT once file `watched` there holds 3 lines (the
/// command under way, its handler set before it writes), to its end.
#[cfg(unix)]
fn interrupted_once_written(dir: &TempDir, args: &[&str], watched: &str) -> Output {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_bead"))
        .args(args)
        .current_dir(&dir.0)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run bead");
    let lines = || {
        std::fs::read_to_string(dir.path(watched))
            .map(|t| t.lines().count())
            .unwrap_or(0)
    };
    while lines() < 3 {
        assert!(
            child.try_wait().unwrap().is_none(),
            "bead {args:?} ended by itself"
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(kill.success());
    child.wait_with_output().expect("bead ends")
}

/// Ctrl-C (SIGINT) in a long `bead run` ends the run at its last good state: the summary
/// file is written with the error and the state reached, the trace ends with that state's
/// row, stderr says where, and the exit code is 130. The signal is sent once the trace
/// shows the run under way (its handler is set before the run's first step).
#[cfg(unix)]
#[test]
fn ctrl_c_ends_a_run_at_its_last_good_state_with_its_files_written() {
    let dir = TempDir::new("ctrl-c");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    let scene = scene.to_str().unwrap();
    let run = ["run", scene, "--duration", "1e9", "--every", "1000"];
    let files = ["--trace", "trace.csv", "--summary", "summary.json"];
    let output = interrupted_once_written(&dir, &[&run[..], &files].concat(), "trace.csv");
    let err = stderr(&output);
    assert_eq!(output.status.code(), Some(130), "{err}");
    assert!(err.contains("error: interrupted at t = "), "{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path("summary.json")).unwrap()).unwrap();
    let error = summary["error"].as_str().unwrap();
    assert!(error.starts_with("interrupted at t = "), "{error}");
    let t_final = summary["t_final"].as_f64().unwrap();
    assert!(t_final > 0.0 && t_final < 1e9, "{t_final}");
    let trace = std::fs::read_to_string(dir.path("trace.csv")).unwrap();
    let last = trace.lines().last().unwrap();
    let t_last: f64 = last.split(',').next().unwrap().parse().unwrap();
    assert_eq!(t_last, t_final, "the trace's last row is the state reached");
    assert!(stdout(&output).contains("(stopped early)"));
}

/// Ctrl-C during `bead sweep` stops it at the next member handed over in order: the CSV
/// holds the header and the rows up to that member, in member order, each whole, and the
/// message says how many (exit code 130). The signal is sent once rows have reached the
/// file.
#[cfg(unix)]
#[test]
fn ctrl_c_stops_a_sweep_with_the_rows_written_so_far() {
    let dir = TempDir::new("ctrl-c-sweep");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    let members = 1_000_000;
    let values = format!("g=100:1000:{members}");
    let args = ["sweep", scene.to_str().unwrap(), "--threads", "2"];
    let out = ["--param", &values, "--out", "sweep.csv"];
    let output = interrupted_once_written(&dir, &[&args[..], &out].concat(), "sweep.csv");
    let err = stderr(&output);
    assert_eq!(output.status.code(), Some(130), "{err}");
    let csv = std::fs::read_to_string(dir.path("sweep.csv")).unwrap();
    assert!(csv.ends_with('\n'), "the last row is whole");
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    let written = rows.len();
    assert!(written >= 2 && written < members, "{written} rows");
    for (i, row) in rows.iter().enumerate() {
        assert!(row.starts_with(&format!("{i},")), "row {i}: {row}");
        assert!(row.contains(",ok,"), "row {i}: {row}");
    }
    let said =
        format!("error: interrupted: the sweep stopped after {written} of its {members} members");
    assert!(err.contains(&said), "{err}");
}

/// A "scene" that never ends (`/dev/zero`) or is too large is refused after 16 MiB, not
/// read forever.
#[cfg(unix)]
#[test]
fn a_scene_file_that_never_ends_is_refused() {
    let dir = TempDir::new("endless");
    let err = fails(bead_in(&dir.0, &["check", "/dev/zero"]), 1);
    assert!(
        err.contains("error: /dev/zero: the scene file is larger than 16 MiB"),
        "{err}"
    );
}

/// A parameter set twice, or both set and swept, is a usage error naming both, where the
/// last (or the sweep) won silently.
#[test]
fn a_parameter_set_twice_or_set_and_swept_is_refused() {
    let dir = TempDir::new("set-twice");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    let scene = scene.to_str().unwrap();
    let err = fails(
        bead_in(&dir.0, &["run", scene, "--set", "g=5", "--set", "g=6"]),
        2,
    );
    assert!(
        err.contains("error: --set g is given twice (g=5 and g=6); give each parameter once"),
        "{err}"
    );
    let err = fails(
        bead_in(
            &dir.0,
            &["sweep", scene, "--param", "g=1:2:2", "--set", "g=5"],
        ),
        2,
    );
    assert!(
        err.contains("error: --set g and --param g both give `g`; set it or sweep it"),
        "{err}"
    );
    // Different parameters, or one each, are fine.
    ok(bead_in(
        &dir.0,
        &["run", scene, "--set", "g=5", "--duration", "0.1"],
    ));
}

/// The README's slow blow-up: explicit Euler on the pendulum at dt = 0.01 stops where its
/// energy has changed by more than 10^6 times its scale, t = 72.36, exit code 1 (it ran on
/// to 100 s with an energy error of 5.7e9 and exit code 0).
#[test]
fn the_readmes_euler_pendulum_stops_as_diverged() {
    let dir = TempDir::new("euler-blow-up");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/circle.toml");
    let args = [
        "run",
        scene.to_str().unwrap(),
        "--integrator",
        "euler",
        "--dt",
        "0.01",
    ];
    let err = fails(
        bead_in(&dir.0, &[&args[..], &["--duration", "100"]].concat()),
        1,
    );
    assert!(
        err.contains("error: diverged at t = 72.36 (step 7236): the energy's change |E - E0| / E_scale is 1002973, beyond 1000000"),
        "{err}"
    );
}
