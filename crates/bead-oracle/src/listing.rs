//! What the oracle suite checks: systems x methods x integrators x output paths, and the
//! hard cases, as data. Every front end's oracle test takes its cases from [`cases_for`],
//! so the listing and the tests have one source; `docs/oracle.md` is [`markdown`] and
//! `tests/oracle/cases.json` (which the Python tests read) is [`cases_json`], both checked
//! by [`check_files`] (run by `tests/library.rs`), so neither can go stale.

use serde_json::{json, Value};

use crate::matrix;
use crate::run::Spec;
use crate::systems::System;

/// An output path of bead, and the test that checks it.
pub struct Front {
    pub key: &'static str,
    /// What is read.
    pub path: &'static str,
    /// The test file.
    pub test: &'static str,
    /// The checks made on what is read: a (against the reference), b (one state per row),
    /// c (bit for bit the library's run).
    pub checks: &'static str,
}

/// Every output path the suite reads.
pub const FRONTS: [Front; 11] = [
    Front {
        key: "library-run",
        path: "`simulate::run` samples and `output::Summary` (what every front end calls)",
        test: "crates/bead-oracle/tests/library.rs",
        checks: "a b",
    },
    Front {
        key: "library-advance",
        path: "`Simulation::advance_to(k dt)` and `step()`",
        test: "crates/bead-oracle/tests/library.rs",
        checks: "a c",
    },
    Front {
        key: "library-sweep",
        path: "`bead::sweep::Sweep` members (final state)",
        test: "crates/bead-oracle/tests/library.rs",
        checks: "a c",
    },
    Front {
        key: "cli-trace",
        path: "`bead run --trace` rows (every recorded t)",
        test: "crates/bead-cli/tests/oracle.rs",
        checks: "a b c",
    },
    Front {
        key: "cli-json",
        path: "`bead run --json` summary (final particles, coordinates, energies, work, t_final)",
        test: "crates/bead-cli/tests/oracle.rs",
        checks: "a c",
    },
    Front {
        key: "cli-compare",
        path: "`bead compare --json` summaries and `--trace` rows (both forms)",
        test: "crates/bead-cli/tests/oracle.rs",
        checks: "a c",
    },
    Front {
        key: "cli-sweep",
        path: "`bead sweep` CSV rows (three members, the scene's value in the middle)",
        test: "crates/bead-cli/tests/oracle.rs",
        checks: "a c",
    },
    Front {
        key: "py-run",
        path: "Python `Scene.run()` arrays and `summary`",
        test: "crates/bead-py/tests/test_oracle.py",
        checks: "a b c",
    },
    Front {
        key: "py-advance",
        path: "Python `Simulation.advance_to` and `step`",
        test: "crates/bead-py/tests/test_oracle.py",
        checks: "a c",
    },
    Front {
        key: "py-sweep",
        path: "Python `bead.sweep` results",
        test: "crates/bead-py/tests/test_oracle.py",
        checks: "a c",
    },
    Front {
        key: "viewer",
        path: "the viewer's frames (`bead_viewer::session::Session`, binary frames decoded)",
        test: "crates/bead-viewer/tests/oracle.rs",
        checks: "a b c",
    },
];

/// A hard case and the output paths that check it.
pub struct Hard {
    pub case: &'static str,
    pub what: &'static str,
    pub fronts: &'static [&'static str],
}

pub const HARD: [Hard; 6] = [
    Hard {
        case: "stop_when",
        what: "each system's reference event (the pendulum's bottom at a quarter period K(k)/w, \
               the helix's top, r = 1 on the rod, ...) for every method and integrator: the \
               crossing's time and state converge at the method's order",
        fronts: &["library-run", "cli-trace", "cli-json", "py-run"],
    },
    Hard {
        case: "duration off the grid",
        what: "duration 1 s at dt 0.3 s (the issue's: rk4, dopri5), and rk4 and gauss-legendre \
               at 0.7 times their calibrated step: the run ends at the duration, its last \
               state converges at the method's order (dopri5: within its bound)",
        fronts: &["library-run", "cli-json", "cli-sweep", "py-run", "py-sweep"],
    },
    Hard {
        case: "dopri5 output intervals",
        what: "rtol 1e-6 at dt 1e-3 (several outputs per step) and rtol 1e-12 at dt 0.25 \
               (several steps per output): every row and the final state",
        fronts: &["library-run", "cli-trace", "cli-json", "py-run"],
    },
    Hard {
        case: "substeps",
        what: "`--substeps 2` for every fixed-step integrator: the rows of the run at dt/2",
        fronts: &["library-run", "cli-trace"],
    },
    Hard {
        case: "retries",
        what: "steps retried in halves at dt 0.2 s (rattle, gauss-legendre, verlet): every row \
               within 2^p times the error of the run with --substeps 2",
        fronts: &["library-run"],
    },
    Hard {
        case: "sweep lanes",
        what: "20 pendulums stepped 16 at a time in lanes (rk4): each against its own elliptic \
               solution",
        fronts: &["library-sweep"],
    },
];

/// The cases `front` checks: every accepted system, method and integrator, at the
/// calibrated step ([`matrix::cases`]); `bead compare` runs both forms with one integrator,
/// so it refuses rattle and fast-projection (the parametric form does) and has no case of
/// them.
pub fn cases_for(front: &str) -> Vec<Spec> {
    assert!(
        FRONTS.iter().any(|f| f.key == front),
        "no output path {front} in the listing"
    );
    matrix::cases()
        .into_iter()
        .filter(|s| !(front == "cli-compare" && s.integrator.needs_constraints()))
        .collect()
}

/// docs/oracle.md.
pub fn markdown() -> String {
    let mut out = String::from(
        "# The oracle suite\n\n\
         Generated by `bead_oracle::listing::markdown` and checked by \
         `crates/bead-oracle/tests/library.rs` (`the_listing_is_current`): this file is what \
         the suite runs.\n\n\
         Each system has an answer bead did not compute: a closed form (written in \
         `crates/bead-oracle/src/systems.rs`, evaluated there and by mpmath) or a reference \
         made by `tests/oracle/make_references.py` (the Euler-Lagrange equations derived by \
         sympy, integrated by scipy's DOP853 at rtol 1e-13), stored in \
         `tests/oracle/references/`. Checks: **a** the error at every recorded time against \
         the reference, bounded by the method's order (halving dt divides it by 2^p within \
         20%, row by row, unless at round-off; dopri5 within 1000 rtol); **b** each row's \
         numbers belong to one state (x = x(q, t) and v = J q' + dx/dt at the row's t, \
         energy = T + V of the row, constraint_error = max |C(x, t)|, work present exactly \
         when driven); **c** bit for bit the numbers of the library's run (or of the CLI's, \
         for Python).\n\n## Systems\n\n\
         | system | scene | reference | forms | duration (s) |\n|---|---|---|---|---|\n",
    );
    for system in System::all() {
        let how = if system.closed_form.is_some() {
            "closed form".to_string()
        } else {
            "sympy + DOP853 rtol 1e-13".to_string()
        };
        out += &format!(
            "| {} | `{}` | {} | implicit, parametric | {} |\n",
            system.name,
            system.scene,
            how,
            matrix::duration(system)
        );
    }
    let all = bead::integrate::IntegratorKind::ALL;
    let refused: Vec<&str> = all
        .iter()
        .filter(|k| k.needs_constraints())
        .map(|k| k.name())
        .collect();
    out += &format!(
        "\n## Systems x methods x integrators x output paths\n\n\
         Every accepted combination: the implicit form with all {} integrators, the \
         parametric form with {} (it refuses {}). Steps (dt of the coarse run; the fine run \
         halves it; dopri5's output interval at rtol 1e-9):\n\n\
         | system | euler, symplectic-euler, fast-projection | midpoint, verlet, rattle | rk4, rattle4, gauss-legendre | dopri5 |\n\
         |---|---|---|---|---|\n",
        all.len(),
        all.len() - refused.len(),
        refused.join(", ")
    );
    for system in System::all() {
        use bead::formulation::Method::Implicit;
        use bead::integrate::IntegratorKind as K;
        let dt = |k| matrix::dt(system, Implicit, k);
        out += &format!(
            "| {} | {} | {} | {} | {} |\n",
            system.name,
            dt(K::Euler),
            dt(K::Midpoint),
            dt(K::Rk4),
            dt(K::Dopri5)
        );
    }
    out += "\n| system | method |";
    let mut rule = String::from("|---|---|");
    for front in &FRONTS {
        out += &format!(" {} |", front.key);
        rule += "---|";
    }
    out += &format!("\n{rule}\n");
    for system in System::all() {
        for method in matrix::METHODS {
            out += &format!("| {} | {} |", system.name, method.name());
            for front in &FRONTS {
                let n = cases_for(front.key)
                    .iter()
                    .filter(|s| s.system.name == system.name && s.method == method)
                    .count();
                out += &format!(" {n} integrators: {} |", front.checks);
            }
            out += "\n";
        }
    }
    out += "\nOutput paths:\n\n";
    for front in &FRONTS {
        out += &format!(
            "- **{}**: {} (`{}`; checks {})\n",
            front.key, front.path, front.test, front.checks
        );
    }
    out += "\n## Hard cases\n\n| case | what | output paths |\n|---|---|---|\n";
    for hard in &HARD {
        out += &format!(
            "| {} | {} | {} |\n",
            hard.case,
            hard.what,
            hard.fronts.join(", ")
        );
    }
    let total: usize = FRONTS.iter().map(|f| cases_for(f.key).len()).sum();
    out += &format!(
        "\n{} systems, {} method x integrator combinations each, {} output paths: {total} \
         system x method x integrator x output path cases, plus the hard cases.\n",
        System::all().len(),
        matrix::cases().len() / System::all().len(),
        FRONTS.len()
    );
    out
}

/// tests/oracle/cases.json: the systems' scales and the cases, for the Python tests.
pub fn cases_json() -> String {
    let systems: serde_json::Map<String, Value> = System::all()
        .iter()
        .map(|s| {
            (
                s.name.to_string(),
                json!({
                    "scene": s.scene,
                    "length": s.length,
                    "speed": s.speed,
                    "driven": s.driven,
                    "particles": s.particles,
                    "sweep": [s.sweep.0, s.sweep.1, s.sweep.2],
                    "reference_floor": s.reference_floor(),
                }),
            )
        })
        .collect();
    let cases: Vec<Value> = matrix::cases()
        .iter()
        .map(|c| {
            let fronts: Vec<&str> = FRONTS
                .iter()
                .filter(|f| {
                    cases_for(f.key).iter().any(|o| {
                        o.system.name == c.system.name
                            && o.method == c.method
                            && o.integrator == c.integrator
                    })
                })
                .map(|f| f.key)
                .collect();
            json!({
                "system": c.system.name,
                "method": c.method.name(),
                "integrator": c.integrator.name(),
                "order": c.integrator.order(),
                "dt": c.dt,
                "duration": c.duration,
                "rtol": c.rtol,
                "fronts": fronts,
            })
        })
        .collect();
    let off_grid: Vec<Value> = {
        let (issue, asymptotic) = matrix::off_grid_cases();
        issue
            .iter()
            .chain(&asymptotic)
            .map(|c| {
                json!({
                    "system": c.system.name,
                    "method": c.method.name(),
                    "integrator": c.integrator.name(),
                    "dt": c.dt,
                    "duration": c.duration,
                    "rtol": c.rtol,
                })
            })
            .collect::<Vec<_>>()
    };
    let value = json!({
        "generated_by": "bead_oracle::listing::cases_json (checked by crates/bead-oracle/tests/library.rs)",
        "dopri5_bound": matrix::DOPRI_BOUND,
        "round_off": crate::checks::ROUND_OFF,
        "systems": systems,
        "cases": cases,
        "off_grid": off_grid,
        "hard": HARD.iter().map(|h| json!({"case": h.case, "fronts": h.fronts})).collect::<Vec<_>>(),
    });
    serde_json::to_string_pretty(&sorted(value)).expect("JSON") + "\n"
}

/// `value` with every object's keys in sorted order, whether or not serde_json preserves
/// insertion order (a feature another crate of the build may switch on).
fn sorted(value: Value) -> Value {
    match value {
        Value::Object(map) => {
            let mut entries: Vec<(String, Value)> = map.into_iter().collect();
            entries.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Object(entries.into_iter().map(|(k, v)| (k, sorted(v))).collect())
        }
        Value::Array(items) => Value::Array(items.into_iter().map(sorted).collect()),
        other => other,
    }
}

/// docs/oracle.md and tests/oracle/cases.json are what [`markdown`] and [`cases_json`]
/// make; `BEAD_ORACLE_WRITE=1` writes them instead.
pub fn check_files() {
    let root = crate::root();
    for (path, text) in [
        (root.join("docs/oracle.md"), markdown()),
        (root.join("tests/oracle/cases.json"), cases_json()),
    ] {
        if std::env::var_os("BEAD_ORACLE_WRITE").is_some() {
            std::fs::write(&path, &text).expect("write the listing");
            continue;
        }
        let old = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            old == text,
            "{} is not what the suite covers: run `BEAD_ORACLE_WRITE=1 cargo test -p \
             bead-oracle --test library the_listing_is_current` and commit it",
            path.display()
        );
    }
}
