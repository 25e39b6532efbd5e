//! A run that blows up stops and says so; one that is merely large does not.
//!
//! Law checked: explicit Euler on a mass on a spring at omega dt = 2 is unstable, so its
//! energy grows geometrically; the run must stop with a divergence error naming the quantity
//! long before f64 overflows, instead of finishing with numbers like 1e292 and exit code 0. Free fall under gravity, by contrast, grows only
//! as y = g t^2 / 2 and must never be flagged over a long run.

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
    match &failure.error {
        RunError::Diverged {
            step, value, limit, ..
        } => {
            assert!(*step < 100, "caught at step {step}");
            assert!(limit.is_some(), "{:?}", failure.error);
            assert!(value.is_finite() && value.abs() > 1e12, "{value}");
        }
        other => panic!("expected divergence, got {other}"),
    }
    let message = failure.to_string();
    assert!(message.starts_with("diverged at t = "), "{message}");
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
