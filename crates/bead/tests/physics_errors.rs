//! Degenerate systems are reported, never integrated into NaN.
//!
//! Law checked: the equations of motion have a unique solution only when the constraint
//! forces are determined, i.e. when the constraint gradients are linearly independent
//! (J W J^T positive definite, implicit form) and when the parametric map is an immersion
//! (dx/dq of full rank, so the mass matrix M = sum m J^T J is positive definite, parametric
//! form). Where that fails, the engine must stop with an error that names the culprit (the
//! dependent constraint, or the coordinate the map does not depend on) and the time, instead of
//! returning accelerations made of divisions by zero.

mod common;

use std::sync::Arc;

use bead::formulation::{
    formulate, Feedback, Implicit, Method, Parametric, SecondOrderSystem, SingularKind, StepError,
    Subject,
};
use bead::integrate::IntegratorKind;
use bead::model::{System, SystemBuilder};
use bead::simulate::{NullSink, RunError, RunFailure, SetupError, Simulation, SimulationConfig};
use common::{run, Options};

/// The error of a simulation that cannot start from its initial state.
fn start_failure(system: Arc<System>, method: Method) -> StepError {
    let config = SimulationConfig {
        method,
        dt: 0.01,
        ..Default::default()
    };
    match Simulation::new(system, config) {
        Err(SetupError::Initial(e)) => e,
        Err(other) => panic!("expected a failure of the initial state, got {other}"),
        Ok(_) => panic!("the simulation must not start"),
    }
}

fn run_to_failure(system: Arc<System>, method: Method, dt: f64, steps: u64) -> RunFailure {
    let formulation = formulate(system, method, Feedback::default()).unwrap();
    let options = Options {
        integrator: IntegratorKind::Rk4,
        dt,
        steps,
        every: 1,
        ..Default::default()
    };
    let failure = run(formulation, &options, &mut NullSink).expect_err("the run must fail");
    // The figures up to the last good state are finite: nothing was integrated into NaN.
    let stats = &failure.stats;
    for value in stats
        .x
        .iter()
        .chain(&stats.xdot)
        .chain(&stats.q)
        .chain(&stats.qdot)
    {
        assert!(
            value.is_finite(),
            "non-finite state after the failure: {stats:?}"
        );
    }
    assert!(
        stats.energy_final.is_finite() && stats.constraint_error_final.is_finite(),
        "{stats:?}"
    );
    failure
}

fn singular_constraint(failure: &RunFailure) -> (f64, String) {
    match &failure.error {
        RunError::Step(StepError::SingularConstraints { t, constraint, .. }) => {
            (*t, constraint.clone())
        }
        other => panic!("expected singular constraints, got {other}"),
    }
}

// Two copies of the article's constraint x^2 + 100 y = 0: J has two equal rows, so
// J W J^T = [[a, a], [a, a]] is singular (the multipliers are not determined: only their sum
// is). The second copy is the dependent one.
#[test]
fn duplicate_constraints_are_singular_and_the_duplicate_is_named() {
    let mut b = SystemBuilder::new(&[0.0, 500.0]);
    b.particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0])
        .unwrap();
    b.constraint_expr("bead.x^2 + 100*bead.y").unwrap();
    b.constraint_expr("bead.x^2 + 100*bead.y").unwrap();
    let system = Arc::new(b.build().unwrap());

    let mut implicit = Implicit::new(system.clone(), Feedback::default());
    let mut a = [0.0; 2];
    let error = implicit
        .acceleration(1.25, &[150.0, -225.0], &[10.0, -30.0], &mut a)
        .unwrap_err();
    match &error {
        StepError::SingularConstraints {
            t,
            constraint,
            description,
        } => {
            assert_eq!(*t, 1.25);
            assert_eq!(constraint, "constraint 2");
            assert!(
                description.contains("bead.x^2 + 100*bead.y"),
                "{description}"
            );
        }
        other => panic!("expected singular constraints, got {other}"),
    }
    assert!(
        error.to_string().contains("t = 1.25") && error.to_string().contains("constraint 2"),
        "{error}"
    );
    assert!(
        a.iter().all(|v| v.is_finite()),
        "accelerations written on failure: {a:?}"
    );

    // A simulation refuses to start there.
    match start_failure(system, Method::Implicit) {
        StepError::SingularConstraints { t, constraint, .. } => {
            assert_eq!((t, constraint.as_str()), (0.0, "constraint 2"));
        }
        other => panic!("expected singular constraints, got {other}"),
    }
}

// C = x^2 + y^2 = 0 holds only at the origin, where grad C = (2x, 2y) = 0: J W J^T = [0].
#[test]
fn vanishing_gradient_at_the_origin_is_singular() {
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    b.particle("bead", 2.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
    b.constraint_expr("bead.x^2 + bead.y^2").unwrap();
    let system = Arc::new(b.build().unwrap());

    let mut implicit = Implicit::new(system.clone(), Feedback::default());
    let mut a = [0.0; 2];
    let error = implicit
        .acceleration(0.5, &[0.0, 0.0], &[0.0, 0.0], &mut a)
        .unwrap_err();
    assert!(
        matches!(&error, StepError::SingularConstraints { t, constraint, .. } if *t == 0.5 && constraint == "constraint 1"),
        "{error:?}"
    );
    assert!(a.iter().all(|v| v.is_finite()), "{a:?}");

    // A simulation refuses to start there, naming the singular point.
    let error = start_failure(system, Method::Implicit);
    match &error {
        StepError::SingularPoint {
            t,
            subject: Subject::Constraint { name, .. },
            position,
            kind: SingularKind::AtStart,
            ..
        } => {
            assert_eq!((*t, name.as_str()), (0.0, "constraint 1"));
            assert_eq!(
                position,
                &vec![("bead.x".to_string(), 0.0), ("bead.y".to_string(), 0.0)]
            );
        }
        other => panic!("expected a singular point at the start, got {other}"),
    }
    assert!(
        error
            .to_string()
            .contains("its gradient is zero or not finite"),
        "{error}"
    );
}

// A system that becomes singular in the middle of a run, so that the reported time matters.
// The bead rests at (1, 0) under C1 = y and C2 = cos(t) (x - 1) + sin(t) y; both hold at
// (1, 0) for all t and Cdot, Cddot vanish there, so the bead stays put. Their gradients
// (0, 1) and (cos t, sin t) are independent except at t = pi/2, where J W J^T =
// [[1, 1], [1, 1]] / m. With dt = (pi/2)/100, RK4's last stage of step 100 lands on pi/2.
#[test]
fn constraints_that_become_dependent_mid_run_are_reported_at_that_time() {
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    b.particle("bead", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
    b.constraint_expr("bead.y").unwrap();
    b.constraint_expr("cos(t)*(bead.x - 1) + sin(t)*bead.y")
        .unwrap();
    let system = Arc::new(b.build().unwrap());
    let half_pi = std::f64::consts::FRAC_PI_2;
    let failure = run_to_failure(system, Method::Implicit, half_pi / 100.0, 200);
    let (t, constraint) = singular_constraint(&failure);
    assert!(
        (t - half_pi).abs() < 1e-12,
        "singular at t = {t}, expected pi/2"
    );
    assert_eq!(constraint, "constraint 2");
    assert_eq!(
        failure.stats.steps, 99,
        "the last good state is the one before the failing step"
    );
    // Up to there the bead stayed at rest at (1, 0).
    assert!(
        (failure.stats.x[0] - 1.0).abs() < 1e-9 && failure.stats.x[1].abs() < 1e-9,
        "{:?}",
        failure.stats.x
    );
}

// x(q) = (q^3, 0): dx/dq = (3 q^2, 0) vanishes at q = 0, so M = m |dx/dq|^2 = 0 there and
// qddot = (Q - m J^T h) / M is undefined.
#[test]
fn degenerate_parametric_map_gives_a_singular_mass_matrix() {
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    b.particle("bead", 1.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
    b.parametric(&["q"], &[0.0], &[0.0]).unwrap();
    b.parametric_position_exprs("bead", &["q^3", "0"]).unwrap();
    let system = Arc::new(b.build().unwrap());

    let mut parametric = Parametric::new(system.clone()).unwrap();
    let mut qddot = [0.0];
    let error = parametric
        .acceleration(0.75, &[0.0], &[1.0], &mut qddot)
        .unwrap_err();
    assert_eq!(
        error,
        StepError::SingularMassMatrix {
            t: 0.75,
            coordinate: "q".into()
        }
    );
    assert!(
        error.to_string().contains("t = 0.75") && error.to_string().contains('q'),
        "{error}"
    );
    assert!(qddot[0].is_finite());

    // Away from q = 0 the map is fine.
    parametric
        .acceleration(0.0, &[0.5], &[0.0], &mut qddot)
        .unwrap();
    assert!(qddot[0].is_finite());

    // A simulation refuses to start there, naming the coordinate.
    match start_failure(system, Method::Parametric) {
        StepError::SingularPoint {
            t,
            subject: Subject::Coordinate { name },
            kind: SingularKind::AtStart,
            ..
        } => {
            assert_eq!((t, name.as_str()), (0.0, "q"));
        }
        other => panic!("expected a singular point at the start, got {other}"),
    }
}
