//! The oracle through the library: `simulate::run` (what `bead run`, `bead compare` and
//! Python's `Scene.run` call), `Simulation::advance_to` and `step`, and `bead::sweep`, for
//! every system, method and integrator, against answers bead did not compute.

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::sweep::{Axis, Combine, Sweep};
use bead_oracle::harness::each;
use bead_oracle::rows::{self, check_consistent, error};
use bead_oracle::summary::check_summary;
use bead_oracle::{checks, elliptic, listing, matrix, Row, Spec, System};

fn label(spec: &Spec) -> String {
    spec.label()
}

/// (a), (b), (c) of one run through `simulate::run`: every row against the reference, every
/// row one state, and the summary the last row at the time asked for.
fn check_run(spec: &Spec) {
    let what = spec.label();
    let outcome = spec.run();
    assert!(outcome.result.is_ok(), "{what}: {:?}", outcome.result.err());
    let parametric = spec.method == Method::Parametric;
    for (i, row) in outcome.rows.iter().enumerate() {
        check_consistent(spec.system, row, parametric, &format!("{what}, row {i}"));
    }
    let summary = serde_json::to_value(&outcome.summary).expect("the summary serializes");
    check_summary(spec, &summary, &outcome.rows, spec.system.particles, &what);
    checks::against_reference(spec, &outcome.rows, &what);
    // The spinning hoop's Jacobi integral E - w L_z is conserved: every row's is its
    // exact value within what the row's state error allows (|dJ| <= (|v| + g L / speed +
    // w L) speed |e| m: 3.2 E_scale |e| here; 5 is the bound).
    if let Some(j0) = rows::jacobi(spec.system, &outcome.rows[0]) {
        let (x0, v0) = spec.system.exact_state(0.0);
        let exact = Row {
            x: x0,
            v: v0,
            ..outcome.rows[0].clone()
        };
        let j_exact = rows::jacobi(spec.system, &exact).unwrap();
        assert!(
            (j0 - j_exact).abs() < 1e-12,
            "{what}: the start's Jacobi integral"
        );
        for row in &outcome.rows {
            let j = rows::jacobi(spec.system, row).unwrap();
            let bound = 5.0 * spec.system.energy_scale() * error(spec.system, row)
                + 1e-12 * spec.system.energy_scale();
            assert!(
                (j - j_exact).abs() <= bound,
                "{what}: at t = {} the Jacobi integral is {j}, exactly {j_exact}",
                row.t
            );
        }
    }
}

#[test]
fn every_method_and_integrator_converges_to_the_reference() {
    each(
        "simulate::run against the oracle",
        &matrix::cases(),
        label,
        check_run,
    );
}

#[test]
fn stop_conditions_fire_at_the_reference_event() {
    let cases: Vec<Spec> = matrix::cases().into_iter().map(Spec::with_event).collect();
    each("stop_when against the oracle", &cases, label, check_run);
}

#[test]
fn durations_that_are_not_multiples_of_dt_end_at_the_duration() {
    // The run ends at the duration (a shorter last step), its summary is that last row.
    // dopri5's last state is within its bound; a fixed-step run's last state converges at
    // the method's order: at dt / 2 (another short last step) its error is 2^p times less,
    // within 30% of the larger (the last step's own share is of higher order).
    let (issue, asymptotic) = matrix::off_grid_cases();
    let cases: Vec<Spec> = issue.into_iter().chain(asymptotic).collect();
    each("durations off the grid", &cases, label, |spec| {
        let what = spec.label();
        let outcome = spec.run();
        assert!(
            outcome.result.is_ok(),
            "{what}: {:?}",
            outcome.result.as_ref().err().map(|f| f.to_string())
        );
        let summary = serde_json::to_value(&outcome.summary).unwrap();
        check_summary(spec, &summary, &outcome.rows, spec.system.particles, &what);
        let last = outcome.rows.last().unwrap();
        check_consistent(spec.system, last, spec.method == Method::Parametric, &what);
        if spec.integrator.is_adaptive() {
            let bound = matrix::DOPRI_BOUND * matrix::DOPRI_RTOL;
            checks::within(spec.system, std::slice::from_ref(last), bound, &what);
        } else if spec.dt < 0.1 {
            let fine = spec.halved().run();
            let fine_last = fine.rows.last().unwrap();
            assert_eq!(fine_last.t, last.t, "{what}");
            let factor = 2f64.powi(spec.integrator.order() as i32);
            let (e_c, e_f) = (
                rows::error_vector(spec.system, last),
                rows::error_vector(spec.system, fine_last),
            );
            let deviation = e_c
                .iter()
                .zip(&e_f)
                .fold(0.0f64, |m, (a, b)| m.max((a - factor * b).abs()));
            let floor = checks::ROUND_OFF + spec.system.reference_floor();
            assert!(
                deviation <= 0.3 * rows::norm(&e_c) + (1.0 + factor) * floor,
                "{what}: the last state's error {e_c:?} at dt, {e_f:?} at dt/2: not {factor} \
                 times less"
            );
        }
    });
}

#[test]
fn dopri5_steps_longer_and_shorter_than_the_output_interval() {
    // Loose tolerance and a short output interval: several outputs per step, from the
    // dense output. Tight tolerance and a long one: several steps per output. Every row and
    // the summary's final state against the reference.
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
    each("dopri5 output intervals", &cases, label, |spec| {
        let what = spec.label();
        let outcome = spec.run();
        assert!(outcome.result.is_ok(), "{what}");
        for row in &outcome.rows {
            check_consistent(spec.system, row, spec.method == Method::Parametric, &what);
        }
        let summary = serde_json::to_value(&outcome.summary).unwrap();
        check_summary(spec, &summary, &outcome.rows, spec.system.particles, &what);
        checks::against_reference(spec, &outcome.rows, &what);
        let stats = outcome.stats();
        let outputs = outcome.rows.len() as u64 - 1;
        if spec.dt < 0.01 {
            assert!(
                stats.steps < outputs,
                "{what}: {} steps for {outputs} outputs",
                stats.steps
            );
        } else if !(spec.system.name == "helix" && spec.method == Method::Parametric) {
            // (The helix's parametric form is a quadratic in t, which dopri5 integrates
            // exactly: its steps grow to the output interval.)
            assert!(
                stats.steps > outputs,
                "{what}: {} steps for {outputs} outputs",
                stats.steps
            );
        }
    });
}

#[test]
fn advance_to_and_step_give_the_rows_of_the_run() {
    // A Simulation driven by advance_to(k dt) and by step() (fixed-step integrators) has the
    // run's states bit for bit; dopri5 driven by advance_to alone takes other steps (it
    // stops at every target) and is checked against the reference instead.
    each(
        "Simulation::advance_to and step",
        &matrix::cases(),
        label,
        |spec| {
            let what = spec.label();
            let run = spec.run();
            let parametric = spec.method == Method::Parametric;
            let mut by_advance = spec.simulation();
            let mut by_step = spec.simulation();
            let mut advanced = Vec::new();
            for (k, row) in run.rows.iter().enumerate().skip(1) {
                by_advance
                    .advance_to(k as f64 * spec.dt)
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                let got = row_of(&by_advance, parametric);
                if spec.integrator.is_adaptive() {
                    advanced.push(got);
                    continue;
                }
                assert!(
                    got.same_bits(row),
                    "{what}: advance_to({}) gave {got:?}, the run {row:?}",
                    row.t
                );
                by_step.step().unwrap_or_else(|e| panic!("{what}: {e}"));
                let stepped = row_of(&by_step, parametric);
                assert!(stepped.same_bits(row), "{what}: step {k} gave {stepped:?}");
            }
            if spec.integrator.is_adaptive() {
                let rtol = spec.rtol.unwrap();
                checks::within(spec.system, &advanced, matrix::DOPRI_BOUND * rtol, &what);
            }
        },
    );
}

/// A simulation's current state as a row.
fn row_of(s: &bead::simulate::Simulation, parametric: bool) -> Row {
    let sample = s.sample(0);
    Row::of_sample(&sample, parametric)
}

#[test]
fn sweep_members_are_their_runs_and_meet_the_reference() {
    // bead::sweep over the system's parameter (three values, the scene's in the middle):
    // each member's final state is its run's (with --set), bit for bit, and members with a
    // reference (the middle one; every one of a closed form) meet it.
    each("bead::sweep", &matrix::cases(), label, |spec| {
        let what = spec.label();
        let (name, low, middle) = spec.system.sweep;
        let axis = Axis::linspace(name, low, 2.0 * middle - low, 3).unwrap();
        let sweep = Sweep::new(
            &spec.scene(),
            vec![axis],
            Combine::Grid,
            spec.request(),
            None,
        )
        .unwrap_or_else(|e| panic!("{what}: {e}"));
        let members = sweep.run(2).expect("the sweep runs");
        for (i, member) in members.iter().enumerate() {
            let value = sweep.params_of(i)[0];
            let mut alone = spec.clone();
            alone.overrides = vec![(name.to_string(), value)];
            let run = alone.run();
            assert!(
                member.error.is_none(),
                "{what}: member {i} ({name} = {value}) failed: {:?}",
                member.error
            );
            let stats = member
                .stats
                .as_ref()
                .unwrap_or_else(|| panic!("{what}: member {i}"));
            let last = run.rows.last().unwrap();
            let bits =
                |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(
                bits(&stats.x, &last.x) && bits(&stats.xdot, &last.v) && stats.t_final == last.t,
                "{what}: member {i} ({name} = {value}) ended at {:?}, its run at {:?}",
                stats.x,
                last.x
            );
            let exact = if value == middle {
                Some(spec.system.exact_state(stats.t_final))
            } else {
                spec.system.closed_form_with.map(|f| {
                    let (q, qdot) = f(stats.t_final, value);
                    (
                        (spec.system.map)(&q, stats.t_final),
                        (spec.system.velocity)(&q, &qdot, stats.t_final),
                    )
                })
            };
            if let Some((x, _)) = exact {
                // The member's run, checked at every row, bounds its last row.
                let bound = if value == middle {
                    checks::against_reference(&alone, &run.rows, &what);
                    run.rows
                        .iter()
                        .map(|r| error(spec.system, r))
                        .fold(0.0, f64::max)
                } else {
                    f64::INFINITY
                };
                let e = stats.x.iter().zip(&x).fold(0.0f64, |m, (a, b)| {
                    m.max((a - b).abs() / spec.system.length)
                });
                let loose = if bound.is_finite() {
                    bound
                } else {
                    // Another parameter value: the error of the same method at this dt on
                    // the scene's value, with room for the other motion.
                    10.0 * run_error(spec) + 1e-9
                };
                assert!(
                    e <= loose + checks::ROUND_OFF,
                    "{what}: member {i} ({name} = {value}) is {e:.3e} off the closed form"
                );
            }
        }
    });
}

/// The largest error of a case's run (at the scene's parameters).
fn run_error(spec: &Spec) -> f64 {
    spec.run()
        .rows
        .iter()
        .map(|r| error(spec.system, r))
        .fold(0.0, f64::max)
}

#[test]
fn sweep_lanes_meet_the_closed_form() {
    // 20 pendulums (theta0 from 10 to 80 degrees) with rk4: the sweep steps them 16 at a time
    // in lanes; each member against its own elliptic-function solution.
    let system = System::named("pendulum");
    for method in matrix::METHODS {
        let spec = Spec::new(system, method, IntegratorKind::Rk4, 0.025, 1.0);
        let axis = Axis::linspace("theta0", 10f64.to_radians(), 80f64.to_radians(), 20).unwrap();
        let sweep = Sweep::new(
            &spec.scene(),
            vec![axis],
            Combine::Grid,
            spec.request(),
            None,
        )
        .unwrap();
        for (i, member) in sweep.run(2).expect("the sweep runs").iter().enumerate() {
            let theta0 = sweep.params_of(i)[0];
            assert!(member.error.is_none(), "{:?}", member.error);
            let stats = member.stats.as_ref().unwrap();
            let (q, _) = (system.closed_form_with.unwrap())(stats.t_final, theta0);
            let x = (system.map)(&q, stats.t_final);
            let e = (stats.x[0] - x[0]).abs().max((stats.x[1] - x[1]).abs());
            // rk4 at dt = 0.025 s for 1 s: the scene's 60 degrees are 7e-5 off at most
            // (every_method_and_integrator_converges_to_the_reference); smaller swings less.
            assert!(
                e < 1e-4,
                "{method:?} member {i}: theta0 {theta0}, {e:.3e} off"
            );
            assert_eq!(stats.t_final, 1.0);
        }
    }
}

#[test]
fn substeps_are_the_finer_step() {
    // --substeps 2 at dt takes two steps of dt/2: its rows at the steps of dt are those of
    // the run at dt/2 to round-off (its substeps' times are computed from the step's ends),
    // and meet the reference as that run does.
    let cases: Vec<Spec> = matrix::cases()
        .into_iter()
        .filter(|s| !s.integrator.is_adaptive())
        .map(|mut s| {
            s.substeps = Some(2);
            s
        })
        .collect();
    each("--substeps", &cases, label, |spec| {
        let what = spec.label();
        let run = spec.run();
        assert_eq!(run.stats().substeps, 2, "{what}");
        let mut plain = spec.clone();
        plain.substeps = None;
        let fine = plain.halved().run();
        for (k, row) in run.rows.iter().enumerate() {
            let partner = &fine.rows[2 * k];
            assert_eq!(row.t, partner.t, "{what}");
            let d = error(spec.system, row) - error(spec.system, partner);
            let scale = error(spec.system, partner).max(1e-12);
            assert!(
                d.abs() <= 1e-6 * scale + checks::ROUND_OFF,
                "{what}: at t = {} {row:?} against {partner:?}",
                row.t
            );
            check_consistent(spec.system, row, spec.method == Method::Parametric, &what);
        }
    });
}

#[test]
fn retried_steps_keep_the_method_order() {
    // Steps whose iteration does not converge at dt = 0.2 s are retried in halves (the
    // summary counts them); the run then holds states of a method of order p at dt, so
    // every row stays within 2^p times the error of the same run at --substeps 2 (which
    // retries nothing), and each row is one state.
    let cases = [
        ("double-pendulum", Method::Implicit, IntegratorKind::Rattle),
        (
            "double-pendulum",
            Method::Implicit,
            IntegratorKind::GaussLegendre,
        ),
        (
            "spinning-hoop",
            Method::Implicit,
            IntegratorKind::GaussLegendre,
        ),
        ("parabola", Method::Parametric, IntegratorKind::Verlet),
    ]
    .map(|(name, method, integrator)| Spec::new(System::named(name), method, integrator, 0.2, 1.0));
    each("retries", &cases, label, |spec| {
        let what = spec.label();
        let run = spec.run();
        assert!(run.result.is_ok(), "{what}");
        assert!(run.stats().retried_steps > 0, "{what}: nothing was retried");
        let mut halves = spec.clone();
        halves.substeps = Some(2);
        let reference_run = halves.run();
        assert_eq!(reference_run.stats().retried_steps, 0, "{what}");
        let bound = 2f64.powi(spec.integrator.order() as i32)
            * reference_run
                .rows
                .iter()
                .map(|r| error(spec.system, r))
                .fold(0.0, f64::max);
        checks::within(spec.system, &run.rows, bound, &what);
        for row in &run.rows {
            check_consistent(spec.system, row, spec.method == Method::Parametric, &what);
        }
    });
}

#[test]
fn references_match_the_scenes() {
    // The references were made for the scenes' parameters (tests/oracle/make_references.py
    // states them); a scene edited since would be compared with another system's answer.
    for system in System::all() {
        let reference = system.reference();
        let scene =
            bead::scene::Scene::load(&bead_oracle::root().join(system.scene), &[]).expect("scene");
        for (name, value) in &scene.params {
            let stated = reference.param(name);
            assert!(
                (value - stated).abs() <= 1e-15 * stated.abs(),
                "{}: {name} = {value} in the scene, {stated} in the reference",
                system.name
            );
        }
        assert_eq!(
            scene.params.len(),
            reference.settings["params"].as_object().unwrap().len(),
            "{}",
            system.name
        );
        assert_eq!(scene.system.gravity(), system.gravity, "{}", system.name);
        let masses: Vec<f64> = scene.system.particles().iter().map(|p| p.mass).collect();
        assert_eq!(masses, system.masses, "{}", system.name);
        let names: Vec<&str> = scene
            .system
            .particles()
            .iter()
            .map(|p| p.name.as_str())
            .collect();
        assert_eq!(names, system.particles, "{}", system.name);
        // The scene's initial state is the reference's at t = 0.
        let (x, v) = system.exact_state(0.0);
        let (x0, v0) = scene.system.initial_particle_state();
        for (a, b) in x0.iter().zip(&x) {
            assert!((a - b).abs() < 1e-14 * system.length, "{}: x0", system.name);
        }
        for (a, b) in v0.iter().zip(&v) {
            assert!((a - b).abs() < 1e-14 * system.speed, "{}: v0", system.name);
        }
    }
}

#[test]
fn closed_forms_agree_with_mpmath() {
    // The Rust closed forms (the pendulum's elliptic functions by the AGM) against the
    // script's mpmath evaluation at 30 digits, at every grid point.
    for system in System::all() {
        let Some(f) = system.closed_form else {
            continue;
        };
        let reference = system.reference();
        let mut t = 0.0;
        let mut k = 0;
        while t <= reference.duration() {
            let (q, qdot) = f(t);
            let (rq, rqdot) = reference.at(t);
            for (a, b) in q.iter().zip(&rq).chain(qdot.iter().zip(&rqdot)) {
                assert!(
                    (a - b).abs() <= 1e-13 * (1.0 + b.abs()),
                    "{} at t = {t}: {a} here, {b} by mpmath",
                    system.name
                );
            }
            k += 7;
            t = k as f64 * reference.step;
        }
    }
    // The quarter period K(k)/w of the pendulum is the reference's event time.
    let k = (std::f64::consts::PI / 6.0).sin();
    let quarter = elliptic::complete_k(k * k) / 9.81f64.sqrt();
    let event = System::named("pendulum").reference().events()[0].2;
    assert!((quarter - event).abs() < 1e-15, "{quarter} {event}");
}

#[test]
fn the_listing_is_current() {
    listing::check_files();
}
