//! Sweeps step members of one system together (`simulate::lanes`): every member's figures
//! must be those of its run alone, from its scene loaded from the text with its values, bit
//! for bit, on systems where the lanes run to the end (the parabola, the double pendulum's
//! parametric form, the helix in 3D), where members leave them (a stop condition that fires
//! for some; a cusp that stops every run at its singular point; a rod system the lanes do
//! not take) and over several blocks of lanes with a partial last one.

use std::path::Path;
use std::sync::Arc;

mod common;

use bead::formulation::{Feedback, Method};
use bead::integrate::IntegratorKind;
use bead::plan::{Plan, PlanRequest};
use bead::scene::Scene;
use bead::simulate::{run, Event, NullSink, RunStats, Simulation};
use bead::sweep::{Axis, Combine, Member, Sweep};

/// Member i's run alone: its scene parsed from the text with its values (the equations
/// compiled afresh), planned, set up and run as `bead run --set` runs it.
fn alone(
    scene: &Scene,
    sweep: &Sweep,
    request: &PlanRequest,
    stop_when: Option<&str>,
    i: usize,
) -> (Option<RunStats>, Option<String>) {
    let overrides: Vec<(String, f64)> = sweep
        .axes()
        .iter()
        .map(|a| a.name.clone())
        .zip(sweep.params_of(i))
        .collect();
    let member = Scene::parse(scene.text(), &scene.file, &overrides).unwrap();
    let plan = Plan::resolve(&member, request).unwrap();
    let mut simulation = match Simulation::new(Arc::clone(&member.system), plan.config(plan.method))
    {
        Ok(s) => s,
        Err(e) => return (None, Some(e.to_string())),
    };
    let event = match stop_when {
        Some(source) => Some(Event::parse(&member.system, source).unwrap()),
        None => member.run.stop_when.clone(),
    };
    simulation.set_stop_when(event).unwrap();
    match run(&mut simulation, plan.options(), &mut NullSink) {
        Ok(stats) => (Some(stats), None),
        Err(failure) => (Some(*failure.stats), Some(failure.error.to_string())),
    }
}

fn without_wall_time(stats: &RunStats) -> RunStats {
    RunStats {
        wall_seconds: 0.0,
        ..stats.clone()
    }
}

/// Sweep `scene` over `axes` and compare every member with its run alone; returns the
/// members.
fn check(
    scene: &Scene,
    axes: Vec<Axis>,
    request: PlanRequest,
    stop_when: Option<&str>,
) -> Vec<Member> {
    let sweep = Sweep::new(
        scene,
        axes,
        Combine::Grid,
        request.clone(),
        stop_when.map(str::to_string),
    )
    .unwrap();
    let members = sweep.run(2).unwrap();
    assert_eq!(members.len(), sweep.len());
    for (i, member) in members.iter().enumerate() {
        let (stats, error) = alone(scene, &sweep, &request, stop_when, i);
        assert_eq!(member.error, error, "member {i} {:?}", member.params);
        assert_eq!(
            format!("{:?}", member.stats.as_ref().map(without_wall_time)),
            format!("{:?}", stats.as_ref().map(without_wall_time)),
            "member {i} {:?}",
            member.params
        );
    }
    members
}

fn shipped(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name);
    Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"))
}

/// The swept parabola with a spring of stiffness `k` (a parameter, 2 by default) from the
/// bead to an anchor, then the TOML `more`.
fn parabola_with_spring(file: &str, more: &str) -> Scene {
    let text = format!(
        "{}\n[[force]]\nkind = \"spring\"\nparticle = \"bead\"\nanchor = [0.0, -300.0]\nstiffness = \"k\"\nrest_length = 50.0\n{more}",
        common::PARABOLA_SWEPT.replace("mass = 1.0\n", "mass = 1.0\nk = 2.0\n")
    );
    Scene::parse(&text, file, &[]).unwrap()
}

fn rk4(method: Method, dt: f64, steps: u64) -> PlanRequest {
    PlanRequest {
        method: Some(method),
        integrator: Some(IntegratorKind::Rk4),
        dt: Some(dt),
        steps: Some(steps),
        ..Default::default()
    }
}

#[test]
fn the_parabola_in_lanes_is_the_parabola_alone() {
    let scene = Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap();
    for method in [Method::Implicit, Method::Parametric] {
        // 37 members: two full blocks of 16 and a partial one.
        let members = check(
            &scene,
            vec![Axis::linspace("x0", 10.0, 200.0, 37).unwrap()],
            rk4(method, 1.0 / 60.0, 300),
            None,
        );
        assert!(members.iter().all(|m| m.status() == "ok"));
    }
}

/// The parabola of mass 3 under g = 981, swept over x0 (so the members share one system and
/// run in lanes, 37 of them: two full blocks and a partial one): the lanes' step and each
/// member's run alone have the system's constants folded into their machine code (the
/// products by 1/3, 981 * 3), the one over 16 lanes and the other over one, with the same
/// bits; with feedback off (no term) and on.
#[test]
fn a_heavier_parabola_in_lanes_is_the_parabola_alone_with_and_without_feedback() {
    let text = common::PARABOLA_SWEPT
        .replace("g = 500.0\n", "g = 981.0\n")
        .replace("mass = 1.0\n", "mass = 3.0\n");
    assert_ne!(text, common::PARABOLA_SWEPT);
    let scene = Scene::parse(&text, "parabola.toml", &[]).unwrap();
    assert_eq!(scene.system.particles()[0].mass, 3.0);
    let feedback = Some(Feedback { ks: 25.0, kd: 10.0 });
    // Feedback applies to the implicit form only.
    for (stabilize, method) in [
        (None, Method::Implicit),
        (None, Method::Parametric),
        (feedback, Method::Implicit),
    ] {
        let request = PlanRequest {
            stabilize,
            ..rk4(method, 1.0 / 60.0, 300)
        };
        let axes = vec![Axis::linspace("x0", 10.0, 200.0, 37).unwrap()];
        let members = check(&scene, axes, request, None);
        assert!(members.iter().all(|m| m.status() == "ok"));
        // Moving members (RK4's energy error is 0 only at rest): no comparison of beads
        // that stay put.
        let drift = |m: &Member| m.stats.as_ref().map_or(0.0, |s| s.energy_rel_error_max);
        assert!(members.iter().all(|m| drift(m) > 0.0));
    }
}

#[test]
fn a_stop_condition_takes_its_members_out_of_the_lanes() {
    // The bead passes x = 0 going right a quarter period after its release at x0 < 0:
    // early for small swings, later for large ones (the period grows with the amplitude);
    // some not within the run.
    let scene = Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap();
    for method in [Method::Implicit, Method::Parametric] {
        let members = check(
            &scene,
            vec![Axis::linspace("x0", -200.0, -10.0, 20).unwrap()],
            rk4(method, 1.0 / 60.0, 35),
            Some("bead.x"),
        );
        let fired = members.iter().filter(|m| m.status() == "event").count();
        assert!(fired > 0 && fired < members.len(), "{fired} fired");
    }
}

#[test]
fn the_double_pendulum_over_a_grid_of_angles() {
    let scene = shipped("double-pendulum.toml");
    let axes = || {
        vec![
            Axis::linspace("th1", -3.0, 3.0, 5).unwrap(),
            Axis::linspace("th2", -3.0, 3.0, 4).unwrap(),
        ]
    };
    // The parametric form runs in lanes; the implicit form's rods are native rows, which
    // the lanes leave to the members alone.
    check(&scene, axes(), rk4(Method::Parametric, 1e-3, 1500), None);
    check(&scene, axes(), rk4(Method::Implicit, 1e-3, 300), None);
    // The lower bob falling below 1.5 L under the pivot stops the run.
    let members = check(
        &scene,
        axes(),
        rk4(Method::Parametric, 1e-3, 1500),
        Some("b.y - 1.5"),
    );
    let fired = members.iter().filter(|m| m.status() == "event").count();
    assert!(fired > 0 && fired < members.len(), "{fired} fired");
}

#[test]
fn members_that_reach_a_singular_point_leave_with_its_message() {
    let scene = shipped("cusp.toml");
    for method in [Method::Implicit, Method::Parametric] {
        let members = check(
            &scene,
            vec![Axis::linspace("s0", 0.5, 1.5, 18).unwrap()],
            rk4(method, 1e-3, 1500),
            None,
        );
        assert!(
            members.iter().any(|m| m.status() == "failed"),
            "{method:?}: some member reaches the cusp"
        );
    }
}

#[test]
fn the_helix_in_three_dimensions() {
    // w0 sets the initial rate only: the members share the helix's equations.
    let scene = shipped("helix.toml");
    for method in [Method::Implicit, Method::Parametric] {
        check(
            &scene,
            vec![Axis::linspace("w0", -3.0, 6.0, 17).unwrap()],
            rk4(method, 1e-3, 500),
            None,
        );
    }
}

#[test]
fn a_duration_off_the_grid_ends_every_member_exactly_there() {
    // Regression (issue 15): duration 1 at dt 0.3 ran to 1.2. The lanes take the shortened
    // last step as the members alone do, bit for bit.
    let scene = Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap();
    for method in [Method::Implicit, Method::Parametric] {
        let request = PlanRequest {
            steps: None,
            duration: Some(1.0),
            ..rk4(method, 0.3, 0)
        };
        let members = check(
            &scene,
            vec![Axis::linspace("x0", 10.0, 200.0, 18).unwrap()],
            request,
            None,
        );
        for member in &members {
            assert_eq!(member.stats.as_ref().unwrap().t_final, 1.0);
            assert_eq!(member.stats.as_ref().unwrap().steps, 4);
        }
    }
}

/// The lanes screen a stop condition inside every step as the member's own simulation does
/// (the same samples on the same interpolant): a member whose condition comes back above
/// zero between two step ends (the bead returning to 0.9999 x0 near its turning point, a
/// window shorter than the step of 0.05 s for most members) or is NaN (the square root of
/// a negative: members that swing beyond x = -50) leaves the lanes, and every member's
/// figures are its run's alone, bit for bit, for every sample count.
#[test]
fn stop_conditions_sampled_inside_the_steps_leave_the_lanes_as_alone() {
    let scene = Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap();
    for method in [Method::Implicit, Method::Parametric] {
        let mut fired = Vec::new();
        for samples in [0, 4, 16] {
            let request = PlanRequest {
                event_samples: Some(samples),
                ..rk4(method, 0.05, 60)
            };
            let axes = || vec![Axis::linspace("x0", 10.0, 200.0, 20).unwrap()];
            let members = check(&scene, axes(), request.clone(), Some("bead.x - 0.9999*x0"));
            fired.push(members.iter().filter(|m| m.status() == "event").count());
            let members = check(&scene, axes(), request, Some("sqrt(bead.x + 50)"));
            let failed = members.iter().filter(|m| m.status() == "failed").count();
            assert!(failed > 0 && failed < members.len(), "{failed} failed");
            for m in members.iter().filter(|m| m.status() == "failed") {
                let error = m.error.as_deref().unwrap();
                assert!(
                    error.starts_with("stop_when `sqrt(bead.x + 50)` is not a number at t = "),
                    "{error}"
                );
            }
        }
        // The samples find returns that the step ends miss.
        assert!(
            fired[0] < fired[1] && fired[1] <= fired[2],
            "{method:?}: {fired:?}"
        );
    }
}

/// Forces besides gravity (a spring to an anchor and a constant push, both with a potential):
/// the lanes finish each member's acceleration and energy by its own code, and every figure
/// is still the member's alone, bit for bit, in both forms.
#[test]
fn members_with_springs_and_constant_forces_are_their_runs_alone() {
    let push = "\n[[force]]\nkind = \"constant\"\nparticle = \"bead\"\nvector = [40.0, 0.0]\n";
    let scene = parabola_with_spring("parabola-spring.toml", push);
    for method in [Method::Implicit, Method::Parametric] {
        let members = check(
            &scene,
            vec![
                Axis::linspace("x0", 10.0, 200.0, 9).unwrap(),
                Axis::linspace("k", 0.5, 8.0, 3).unwrap(),
            ],
            rk4(method, 1.0 / 240.0, 900),
            None,
        );
        assert!(members.iter().all(|m| m.error.is_none()));
    }
}

/// Members whose steps blow up (a spring too stiff for rk4 at this dt) leave the lanes with
/// the divergence their runs alone report, at the same step: the lanes' divergence test
/// (every coordinate within the floor, else within the member's reach at t) is the run's.
#[test]
fn members_that_blow_up_leave_with_their_divergence() {
    let scene = parabola_with_spring("parabola-stiff.toml", "");
    for method in [Method::Implicit, Method::Parametric] {
        let members = check(
            &scene,
            vec![
                Axis::linspace("x0", 10.0, 200.0, 5).unwrap(),
                Axis::linspace("k", 1.0, 9.0e4, 5).unwrap(),
            ],
            rk4(method, 1.0 / 60.0, 600),
            None,
        );
        let diverged = members
            .iter()
            .filter(|m| m.error.as_ref().is_some_and(|e| e.contains("diverged")))
            .count();
        let errors: Vec<_> = members.iter().filter_map(|m| m.error.clone()).collect();
        assert!(
            diverged >= 5 && members.iter().any(|m| m.error.is_none()),
            "{method:?}: {diverged} diverged of {}: {errors:?}",
            members.len()
        );
    }
}

/// Members whose energy grows slowly past 10^6 times its scale (rk4 just past its stability
/// limit, small releases of the article's bead: omega dt = 2.85, the implicit form drifting
/// off its curve) end as their runs alone do, with the energy's divergence, after leaving
/// the lanes on the drift's regularity candidates (tests/divergence.rs has a sweep whose
/// members stay in the lanes to the energy's limit).
#[test]
fn members_whose_energy_blows_up_slowly_leave_where_they_would_alone() {
    let scene = Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap();
    let members = check(
        &scene,
        vec![Axis::linspace("x0", 0.5, 1.2, 5).unwrap()],
        rk4(Method::Implicit, 0.9, 30_000),
        None,
    );
    let diverged = members
        .iter()
        .filter(|m| {
            m.error
                .as_ref()
                .is_some_and(|e| e.contains("the energy's change |E - E0| / E_scale"))
        })
        .count();
    assert!(
        diverged >= 3,
        "{:?}",
        members.iter().map(|m| &m.error).collect::<Vec<_>>()
    );
}
