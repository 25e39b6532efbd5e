//! A run that blows up stops and says so; one that is merely large does not.
//!
//! Law checked: explicit Euler on a mass on a spring at omega dt = 2 is unstable, so its
//! energy grows geometrically (by 1 + (omega dt)^2 = 5 per step, exactly); the run must stop
//! with a divergence error naming the quantity long before f64 overflows, instead of
//! finishing with numbers like 1e292 and exit code 0: at the first step whose energy has
//! changed by more than 10^6 times its scale. Free fall under gravity, by contrast, grows
//! only as y = g t^2 / 2 and must never be flagged over a long run.

mod common;

use std::sync::Arc;

use bead::formulation::{formulate, Feedback, Method};
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, Force, SystemBuilder};
use bead::simulate::{NullSink, RunError};
use common::{run, Options};

#[test]
fn unstable_euler_is_reported_as_divergence_not_finished() {
    // A mass on a spring to the origin (k = 4, m = 1: omega = 2) and no constraint, so that
    // nothing but the divergence test can stop it: explicit Euler multiplies the amplitude by
    // sqrt(1 + (omega dt)^2) = sqrt(5) per step at dt = 1. (On a constrained system such a
    // step also turns the constraint's gradient by more than 90 degrees, which stops the run
    // earlier as a step too long for the curve: tests/singular_points.rs.)
    let mut b = SystemBuilder::new(&[0.0, 0.0]);
    let bead = b.particle("bead", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
    b.force(Force::Spring {
        a: bead,
        b: Endpoint::Fixed(vec![0.0, 0.0]),
        stiffness: 4.0,
        rest_length: 0.0,
    })
    .unwrap();
    let system = Arc::new(b.build().unwrap());
    let free = formulate(system, Method::Implicit, Feedback::default()).unwrap();
    let options = Options {
        integrator: IntegratorKind::Euler,
        dt: 1.0,
        steps: 100,
        ..Options::default()
    };
    let failure = run(free, &options, &mut NullSink).expect_err("must diverge");
    // E_n = 5^n E_0 with E_0 = k x0^2 / 2 = 2, the energy scale: |E_n - E_0| / E_scale is
    // 5^n - 1, beyond 10^6 first at n = 9 (5^8 - 1 = 390,624; 5^9 - 1 = 1,953,124).
    match &failure.error {
        RunError::Diverged {
            step,
            quantity,
            value,
            limit,
            ..
        } => {
            assert_eq!(*step, 9, "caught at step {step}");
            assert_eq!(*quantity, bead::simulate::Quantity::EnergyChange);
            assert_eq!(*limit, Some(1e6));
            assert!((value - 1_953_124.0).abs() <= 1e-9 * 1_953_124.0, "{value}");
        }
        other => panic!("expected divergence, got {other}"),
    }
    let message = failure.to_string();
    assert!(
        message.starts_with(
            "diverged at t = 9 (step 9): the energy's change |E - E0| / E_scale is 1953124"
        ),
        "{message}"
    );
    assert!(message.contains(
        ", beyond 1000000 (T + V is conserved, and has changed by more than 10^6 times its scale"
    ));
    // The last good state is step 8's: its energy changed by 5^8 - 1 times the scale.
    assert!((failure.stats.energy_rel_error_max - 390_624.0).abs() <= 1e-9 * 390_624.0);
    // The figures kept are those of the last good state, all finite.
    assert!(failure.stats.energy_final.is_finite());
}

#[test]
fn long_free_fall_is_not_divergence() {
    // 10^5 s of free fall from rest at the origin, g = 500: y reaches 2.5e12, far beyond the
    // initial positions (all 0); the run's length scale g T^2 / 2 = 2.5e12 accounts for it.
    let mut b = SystemBuilder::new(&[0.0, 500.0]);
    b.particle("stone", 1.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
    let system = Arc::new(b.build().unwrap());
    let free = formulate(system, Method::Implicit, Feedback::default()).unwrap();
    let options = Options {
        integrator: IntegratorKind::Rk4,
        dt: 10.0,
        steps: 10_000,
        ..Options::default()
    };
    let stats = run(free, &options, &mut NullSink).expect("free fall is not divergence");
    // RK4 integrates y'' = g exactly: y = g t^2 / 2.
    let t: f64 = 1e5;
    assert!((stats.x[1] - 250.0 * t * t).abs() <= 1e-9 * 250.0 * t * t);
}

/// Stops the run once `after` intervals have gone by.
struct StopAfter {
    calls: u64,
    after: u64,
}

impl bead::simulate::Progress for StopAfter {
    fn advance(&mut self, _: u64, _: u64) {}
    fn interrupted(&mut self) -> bool {
        self.calls += 1;
        self.calls >= self.after
    }
}

#[test]
fn an_interrupted_run_stops_at_a_good_state_and_says_so() {
    let mut b = SystemBuilder::new(&[0.0, 500.0]);
    b.particle("stone", 1.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
    let system = Arc::new(b.build().unwrap());
    let free = formulate(system, Method::Implicit, Feedback::default()).unwrap();
    let options = Options {
        dt: 0.5,
        steps: 1000,
        every: 100,
        ..Options::default()
    };
    let mut progress = StopAfter { calls: 0, after: 7 };
    let failure = common::run_with_progress(free, &options, &mut NullSink, &mut progress)
        .expect_err("interrupted");
    match failure.error {
        RunError::Interrupted { t, step } => assert_eq!((t, step), (3.5, 7)),
        other => panic!("expected an interruption, got {other}"),
    }
    assert_eq!(failure.stats.steps, 7);
    assert_eq!(failure.stats.t_final, 3.5);
}

/// A slow blow-up: rk4 on the article's bead released at x0 = 1 (small oscillations, omega
/// = sqrt(2 g / 100) = sqrt(10)) at dt = 0.9, just past rk4's stability limit (omega dt =
/// 2.85 > 2.785): the energy grows by a fraction of a percent per step, the implicit form
/// drifting off its curve, and passes 10^6 times its scale after some 24,000 steps, with
/// the bead still far within the reach. `run` into a sink that keeps nothing (express steps
/// checked in batches by the lane monitor) stops at the step where `Simulation::step`, one
/// step at a time through the simulation's own monitor, stops: the same error and state.
#[test]
fn a_slow_blow_up_stops_where_the_energy_passes_a_million_times_its_scale() {
    use bead::plan::{Plan, PlanRequest};
    use bead::scene::Scene;
    use bead::simulate::{run as run_simulation, Simulation};
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/parabola-x0.toml");
    let scene = Scene::load(std::path::Path::new(path), &[("x0".into(), 1.0)]).unwrap();
    let request = PlanRequest {
        method: Some(Method::Implicit),
        integrator: Some(IntegratorKind::Rk4),
        dt: Some(0.9),
        steps: Some(40_000),
        ..Default::default()
    };
    let plan = Plan::resolve(&scene, &request).unwrap();
    let new = || Simulation::new(Arc::clone(&scene.system), plan.config(plan.method)).unwrap();
    let mut batched = new();
    let failure =
        run_simulation(&mut batched, plan.options(), &mut NullSink).expect_err("must diverge");
    let RunError::Diverged {
        step,
        quantity,
        value,
        ..
    } = &failure.error
    else {
        panic!("expected divergence, got {}", failure.error);
    };
    assert_eq!(*quantity, bead::simulate::Quantity::EnergyChange);
    assert!(*step > 20_000 && *step < 30_000, "{step}");
    assert!(*value > 1e6 && *value < 1.01e6, "{value}");
    assert!(failure.stats.energy_rel_error_max <= 1e6);
    // Far within the reach (10^12 times the scene's scales): the bead has drifted up off its
    // curve to y ~ -10^6 (V = -m g y = 5 10^8 = 10^6 times E0 = 500), no further.
    assert!(
        failure.stats.x.iter().all(|x| x.abs() < 2e6),
        "{:?}",
        failure.stats.x
    );
    let mut own = new();
    let error = loop {
        if let Err(error) = own.step() {
            break error;
        }
        assert!(own.steps() < 40_000, "the own steps ran on");
    };
    assert_eq!(error.to_string(), failure.error.to_string());
    let end = |s: &Simulation| {
        let bits: Vec<u64> = (s.q().iter().chain(s.qdot()))
            .map(|v| v.to_bits())
            .collect();
        (s.t().to_bits(), s.steps(), bits)
    };
    assert_eq!(end(&batched), end(&own));
}

/// The sweep lanes watch the energy too: a mass on a spring (k = m = 1, omega = 1) and no
/// constraint, so that no regularity candidate takes a member out of the lanes, stepped by
/// rk4 at dt = 2.83, just past its stability limit 2 sqrt(2): |R(2.83 i)|^2 = 1.0079, the
/// energy grows by 0.8% a step and passes 10^6 times its scale near step 1750, far within
/// the reach. Every member of a sweep over its release point leaves the lanes at that step
/// with the divergence its run alone reports one `Simulation::step` at a time (the
/// simulation's own monitor), at the same step and state.
#[test]
fn sweep_members_stop_where_their_energy_passes_a_million_times_its_scale() {
    use bead::plan::{Plan, PlanRequest};
    use bead::scene::Scene;
    use bead::simulate::Simulation;
    use bead::sweep::{Axis, Combine, Sweep};
    let text = "[params]\nx0 = 1.0\n[world]\ngravity = [0.0, 0.0]\n[[particle]]\nname = \"p\"\nmass = 1.0\nposition = [\"x0\", 0.0]\nvelocity = [0.0, 0.0]\n[[force]]\nkind = \"spring\"\nparticle = \"p\"\nanchor = [0.0, 0.0]\nstiffness = 1.0\nrest_length = 0.0\n";
    let scene = Scene::parse(text, "spring.toml", &[]).unwrap();
    let request = PlanRequest {
        integrator: Some(IntegratorKind::Rk4),
        dt: Some(2.83),
        steps: Some(5000),
        ..Default::default()
    };
    let axis = Axis::linspace("x0", 0.5, 3.0, 20).unwrap();
    let sweep = Sweep::new(&scene, vec![axis], Combine::Grid, request.clone(), None).unwrap();
    let members = sweep.run(2).unwrap();
    for (i, member) in members.iter().enumerate() {
        // Alone, one `Simulation::step` at a time: the simulation's own monitor.
        let alone = Scene::parse(text, "spring.toml", &[("x0".into(), member.params[0])]).unwrap();
        let plan = Plan::resolve(&alone, &request).unwrap();
        let mut simulation =
            Simulation::new(Arc::clone(&alone.system), plan.config(plan.method)).unwrap();
        let error = loop {
            if let Err(error) = simulation.step() {
                break error;
            }
            assert!(simulation.steps() < 5000, "member {i} ran on");
        };
        let RunError::Diverged { step, quantity, .. } = &error else {
            panic!("member {i}: {error}");
        };
        assert_eq!(
            *quantity,
            bead::simulate::Quantity::EnergyChange,
            "member {i}"
        );
        assert!(*step > 1500 && *step < 2000, "member {i}: step {step}");
        assert_eq!(member.error, Some(error.to_string()), "member {i}");
        let stats = member.stats.as_ref().unwrap();
        assert_eq!(stats.steps, simulation.steps(), "member {i}");
        assert_eq!(stats.x, simulation.positions(), "member {i}");
    }
}
