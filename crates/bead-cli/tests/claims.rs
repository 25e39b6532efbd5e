//! What the README and the summaries claim, computed again (issue 15): the article's
//! comparison table exactly as the README prints it, the distance the implicit rk4 bead ends
//! off the wire (the true distance to the parabola, found here by Newton's method on the
//! closest-point equation, not by bead), the summary's note that an energy error alone
//! does not measure accuracy, and every `bead run`, `bead sweep` and `bead order` example's
//! printed lines.

mod common;

use std::path::{Path, PathBuf};

use common::{bead_in, ok};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn bead(args: &[&str]) -> String {
    ok(bead_in(&root(), args))
}

fn readme() -> String {
    std::fs::read_to_string(root().join("README.md")).unwrap()
}

/// Every `bead compare` example in the README (`$ bead compare ...` or `$ cargo run
/// --release -- compare ...`): its arguments after `bead`, and the lines printed under it.
fn readme_compare_examples() -> Vec<(Vec<String>, Vec<String>)> {
    readme_examples()
        .into_iter()
        .filter(|(args, _, _)| args[0] == "compare")
        .map(|(args, _, printed)| (args, printed))
        .collect()
}

/// Every `$ bead ...` (or `$ cargo run --release -- ...`) command in the README's code
/// blocks, continued over `\` lines, with the lines printed under it (up to the next `$ `
/// line or the block's end): its arguments after `bead` (double quotes grouping, a trailing
/// `# comment` and a `| grep WORD` filter split off), the filter and its lines.
fn readme_examples() -> Vec<(Vec<String>, Option<String>, Vec<String>)> {
    let text = readme();
    let mut examples = Vec::new();
    let (mut in_block, mut continued) = (false, None::<String>);
    let mut current: Option<(Vec<String>, Option<String>, Vec<String>)> = None;
    for line in text.lines() {
        if line.starts_with("```") {
            in_block = !in_block;
            examples.extend(current.take());
            continue;
        }
        if !in_block {
            continue;
        }
        let command = match (continued.take(), line.strip_prefix("$ ")) {
            (Some(head), _) => Some(head + line.trim()),
            (None, Some(command)) => {
                examples.extend(current.take());
                Some(command.trim().to_string())
            }
            (None, None) => {
                if let Some((_, _, printed)) = &mut current {
                    printed.push(line.to_string());
                }
                None
            }
        };
        let Some(command) = command else { continue };
        if let Some(head) = command.strip_suffix('\\') {
            continued = Some(head.to_string());
            continue;
        }
        let (words, filter) = shell_words(&command);
        let args = match words
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>()
            .as_slice()
        {
            ["bead", ..] => Some(words[1..].to_vec()),
            ["cargo", "run", "--release", "--", ..] => Some(words[4..].to_vec()),
            _ => None,
        };
        current = args.map(|args| (args, filter, Vec::new()));
    }
    examples
}

/// Table rows by their first three cells (method, integrator, dt), the other cells kept.
fn rows(lines: &[String]) -> Vec<(String, Vec<String>)> {
    lines
        .iter()
        .filter(|l| l.starts_with("implicit") || l.starts_with("parametric"))
        .map(|l| {
            let cells: Vec<String> = l.split_whitespace().map(String::from).collect();
            (cells[..3].join(" "), cells[3..].to_vec())
        })
        .collect()
}

#[test]
fn the_readmes_comparison_tables_are_what_bead_compare_prints() {
    let examples = readme_compare_examples();
    assert!(examples.len() >= 3, "{} examples", examples.len());
    for (args, printed) in examples {
        // The same runs without writing the README's report directory.
        let mut run: Vec<&str> = Vec::new();
        let mut skip = false;
        for arg in &args {
            if std::mem::take(&mut skip) {
                continue;
            }
            if arg == "--report" {
                skip = true;
                continue;
            }
            run.push(arg);
        }
        let out = bead(&run);
        let got: Vec<String> = out.lines().map(String::from).collect();
        let header = |lines: &[String]| lines.iter().find(|l| l.starts_with("method")).cloned();
        assert_eq!(header(&printed), header(&got), "{args:?}: {out}");
        let (want, got) = (rows(&printed), rows(&got));
        assert_eq!(want.len(), got.len(), "{args:?}: {out}");
        for ((label, want), (got_label, got)) in want.iter().zip(&got) {
            assert_eq!(label, got_label, "{args:?}");
            // Every figure but the last column (steps/s, a wall-clock speed) as printed.
            let n = want.len() - 1;
            assert_eq!(
                want[..n],
                got[..n],
                "{args:?} {label}: README {want:?}, bead {got:?}"
            );
        }
    }
}

/// The closest point of the parabola y = -x^2/100 (the article's wire, x^2 + 100 y = 0) to
/// (px, py): u minimizing (u - px)^2 + (-u^2/100 - py)^2, by a scan over u in [-400, 400]
/// at 0.1 for the global minimum, then Newton's method on the derivative from there;
/// returns the distance.
fn distance_to_parabola(px: f64, py: f64) -> f64 {
    let d = |u: f64| ((u - px).powi(2) + (-u * u / 100.0 - py).powi(2)).sqrt();
    let f = |u: f64| (u - px) + (-u * u / 100.0 - py) * (-u / 50.0);
    let df = |u: f64| 1.0 + (u / 50.0).powi(2) + (-u * u / 100.0 - py) * (-1.0 / 50.0);
    let mut u = (-4000..=4000)
        .map(|k| k as f64 * 0.1)
        .min_by(|a, b| d(*a).total_cmp(&d(*b)))
        .unwrap();
    let scanned = d(u);
    for _ in 0..50 {
        u -= f(u) / df(u);
    }
    assert!(
        d(u) <= scanned && f(u).abs() < 1e-9,
        "Newton left the minimum"
    );
    d(u)
}

#[test]
fn the_readmes_distance_off_the_wire_is_the_implicit_rk4_runs() {
    let json = bead(&[
        "run",
        "scenes/parabola.toml",
        "--integrator",
        "rk4",
        "--dt",
        "1/60",
        "--duration",
        "600",
        "--json",
    ]);
    let summary: serde_json::Value = serde_json::from_str(&json).unwrap();
    let position = &summary["particles"]["bead"]["position"];
    let (x, y) = (position[0].as_f64().unwrap(), position[1].as_f64().unwrap());
    let distance = distance_to_parabola(x, y);
    // "the bead ends N px off the wire": N rounded as the README gives it.
    let text = readme();
    let claim = text
        .split("the bead ends ")
        .nth(1)
        .and_then(|rest| rest.split(" px off the wire").next())
        .expect("README: \"the bead ends N px off the wire\"");
    let claimed: f64 = claim.trim_start_matches('~').parse().unwrap();
    assert!(
        (claimed - distance).abs() <= 0.5,
        "README says {claim} px, the run ends {distance} px off the wire"
    );
    // The summary's first-order distance |C| / |grad C| at the end, computed here.
    let c = x * x + 100.0 * y;
    let first_order = c.abs() / (4.0 * x * x + 1e4).sqrt();
    let reported = summary["constraint_distance_final"].as_f64().unwrap();
    assert!(
        (reported - first_order).abs() <= 1e-9 * first_order,
        "{reported} vs {first_order}"
    );
}

#[test]
fn a_small_energy_error_beside_a_large_constraint_error_is_flagged() {
    // Implicit verlet on the spinning hoop: E - W conserved to ~1e-5 while the bead leaves
    // the hoop by half its radius. The summary says so; rk4 at the same step stays on it.
    let args = |integrator: &'static str| {
        [
            "run",
            "scenes/spinning-hoop.toml",
            "--method",
            "implicit",
            "--integrator",
            integrator,
            "--duration",
            "100",
        ]
    };
    let verlet = bead(&args("verlet"));
    assert!(
        verlet.contains("neither figure alone measures accuracy"),
        "{verlet}"
    );
    let rk4 = bead(&args("rk4"));
    assert!(!rk4.contains("neither figure"), "{rk4}");
    // The distance in the JSON is the larger of the two rows' |C| / |grad C| at the final
    // position: the sphere x^2 + y^2 + z^2 - R^2 and the plane -x sin(wt) + y cos(wt).
    let mut json_args = args("verlet").to_vec();
    json_args.push("--json");
    let summary: serde_json::Value = serde_json::from_str(&bead(&json_args)).unwrap();
    let p: Vec<f64> = summary["particles"]["bead"]["position"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let (r, w, t) = (0.8_f64, 5.0_f64, summary["t_final"].as_f64().unwrap());
    let sphere = p.iter().map(|c| c * c).sum::<f64>() - r * r;
    let sphere_distance = sphere.abs() / (2.0 * p.iter().map(|c| c * c).sum::<f64>().sqrt());
    let plane_distance = (-p[0] * (w * t).sin() + p[1] * (w * t).cos()).abs();
    let expected = sphere_distance.max(plane_distance);
    let reported = summary["constraint_distance_final"].as_f64().unwrap();
    assert!(
        (reported - expected).abs() <= 1e-9 * expected,
        "{reported} vs {expected}"
    );
    assert!(reported > 0.1 * r, "{reported}");
}

/// The README's `bead order` example: every line it shows under the command is a line bead
/// prints (the README abridges the table; errors and evaluations are deterministic), and the
/// plot it names is what the command writes.
#[test]
fn the_readmes_convergence_study_is_what_bead_order_prints() {
    let text = readme();
    let start = text
        .find("$ bead order ")
        .expect("README: a `$ bead order` example");
    let block = &text[start..];
    let block = &block[..block.find("```").unwrap()];
    let mut lines = block.lines();
    let command = lines.next().unwrap().trim_start_matches("$ bead ");
    let dir = std::env::temp_dir().join(format!("bead-claims-order-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plot = dir.join("order.png");
    let args: Vec<String> = command
        .split_whitespace()
        .map(|a| {
            if a == "docs/order.png" {
                plot.display().to_string()
            } else {
                a.to_string()
            }
        })
        .collect();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = bead(&args);
    let printed: Vec<&str> = out.lines().collect();
    for line in lines.filter(|l| !l.trim().is_empty()) {
        assert!(
            printed.contains(&line),
            "README line not printed: {line:?}\n{out}"
        );
    }
    assert!(std::fs::metadata(&plot).unwrap().len() > 10_000);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every `$ bead run` and `$ bead sweep` example in the README (see [`readme_examples`];
/// `bead compare` and `bead order` examples have tests of their own above).
fn readme_cli_examples() -> Vec<(Vec<String>, Option<String>, Vec<String>)> {
    readme_examples()
        .into_iter()
        .filter(|(args, _, _)| matches!(args[0].as_str(), "run" | "sweep"))
        .collect()
}

/// A README command line's words: double quotes group, `#` outside them starts a comment,
/// `| grep WORD` becomes the filter.
fn shell_words(command: &str) -> (Vec<String>, Option<String>) {
    let (mut words, mut word, mut quoted) = (Vec::new(), String::new(), false);
    for c in command.chars() {
        match c {
            '"' => quoted = !quoted,
            '#' if !quoted => break,
            c if c.is_whitespace() && !quoted => {
                if !word.is_empty() {
                    words.push(std::mem::take(&mut word));
                }
            }
            c => word.push(c),
        }
    }
    if !word.is_empty() {
        words.push(word);
    }
    match words.iter().position(|w| w == "|") {
        Some(pipe) => {
            assert_eq!(words[pipe + 1], "grep", "{command}");
            let filter = words[pipe + 2].clone();
            words.truncate(pipe);
            (words, Some(filter))
        }
        None => (words, None),
    }
}

/// Whether the README's `printed` line shows `actual`: equal, or where the README elides
/// part of a CSV line with `,...,`, the same start and end.
fn shows(printed: &str, actual: &str) -> bool {
    match printed.split_once(",...,") {
        Some((start, end)) => {
            actual.starts_with(&format!("{start},")) && actual.ends_with(&format!(",{end}"))
        }
        None => printed == actual,
    }
}

/// What the README prints under `bead run` and `bead sweep` examples is what they print
/// now, line for line and in order (stdout, then stderr): a `...` line stands for lines left
/// out, and wall-clock figures (the `speed` row, a sweep's time and rate) are not compared.
/// Two examples are shown and not run: `bad.toml` (not shipped) and `node.toml` (its error
/// wrapped by hand). The README's CSV rows and crossing times once went stale in their last
/// digits and nothing caught it.
#[test]
fn the_readmes_run_and_sweep_examples_print_what_bead_prints() {
    // The events example's scene: the pendulum with three [[event]] tables, as it says.
    let dir = common::TempDir::new("readme-events");
    let circle = std::fs::read_to_string(root().join("scenes/circle.toml")).unwrap();
    let events = dir.write(
        "circle-events.toml",
        &format!(
            "{circle}\n[[event]]\nexpr = \"bead.x\"\ndirection = -1\n\n[[event]]\nexpr = \"bead.x\"\ndirection = 1\n\n[[event]]\nexpr = \"bead.vx\"\n"
        ),
    );
    let wall_clock = |line: &str| line.starts_with("  speed");
    let (mut checked, mut shown, mut stale) = (0, Vec::new(), Vec::new());
    for (mut args, filter, printed) in readme_cli_examples() {
        if args[1] == "/tmp/circle-events.toml" {
            args[1] = events.to_str().unwrap().to_string();
        }
        if args[1] == "bad.toml" || args[1] == "scenes/node.toml" {
            shown.push(args[1].clone());
            continue;
        }
        let words: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = bead_in(&root(), &words);
        let mut actual: Vec<String> = String::from_utf8_lossy(&out.stdout)
            .lines()
            .chain(String::from_utf8_lossy(&out.stderr).lines())
            .filter(|l| !wall_clock(l))
            .map(String::from)
            .collect();
        if let Some(filter) = &filter {
            actual.retain(|l| l.contains(filter.as_str()));
        }
        let command = format!("bead {}", args.join(" "));
        // The next printed line to match, and whether the README left lines out before it.
        let (mut at, mut gap) = (0, false);
        for line in &printed {
            let line = line.trim_end();
            if line.trim() == "..." {
                gap = true;
                continue;
            }
            if wall_clock(line) {
                continue;
            }
            // A sweep's closing line: the counts, not the time.
            let matches = |a: &String| match line.strip_prefix("sweep: ") {
                Some(rest) => a
                    .strip_prefix("sweep: ")
                    .is_some_and(|r| r.starts_with(rest.split(" in ").next().unwrap())),
                None => shows(line, a),
            };
            let found = match gap {
                true => actual[at.min(actual.len())..].iter().position(matches),
                false => actual.get(at).filter(|a| matches(a)).map(|_| 0),
            };
            match found {
                Some(k) => (at, gap) = (at + k + 1, false),
                None => {
                    stale.push(format!(
                        "README under `{command}`:\n{line}\nis not what bead prints there; it printed:\n{}",
                        actual.join("\n")
                    ));
                    // Go on from the next line that matches, if any, without a cascade.
                    gap = true;
                }
            }
        }
        if !gap && at < actual.len() {
            stale.push(format!(
                "README under `{command}` leaves out what bead prints after its last line (add `...`):\n{}",
                actual[at..].join("\n")
            ));
        }
        checked += 1;
    }
    assert!(stale.is_empty(), "{}", stale.join("\n\n"));
    assert_eq!(shown, ["scenes/node.toml", "bad.toml"]);
    // The sweeps (3), the stop conditions (5) and the events (1): a new example counts here.
    assert_eq!(checked, 9, "examples checked");
}
