//! Convergence order of the integrators on both formulations.
//!
//! Law checked: a method of order p has global error e(dt) ~ C dt^p at a fixed end time in the
//! asymptotic range, so halving dt divides the error by 2^p and the observed order
//! log2(e(dt) / e(dt/2)) tends to p: euler and symplectic-euler 1, midpoint 2, rk4 4.
//!
//! System: a simple pendulum (bead on a circle of radius L about the origin, +y down, gravity
//! g along +y), written as a distance constraint (implicit form) and as the angle map
//! x = (L sin theta, L cos theta) (parametric form). Both describe the same motion, whose
//! exact equation is theta'' = -(g/L) sin theta (Lagrange: T = m L^2 theta'^2 / 2,
//! V = -m g L cos theta). The reference is that scalar equation integrated by a hand-written
//! RK4 at a step 100 times below the finest step tested (its error, ~1e-17, is far below every
//! error measured here); the error is the distance between the engine's final particle position
//! and the reference's.

use std::sync::Arc;

use bead::formulation::{formulate, Feedback, Method};
use bead::integrate::IntegratorKind;
use bead::model::System;
use bead::simulate::NullSink;
use common::{run, Options};

mod common;
use common::{pendulum, pendulum_reference};

/// End time at which errors are measured.
const T_END: f64 = 1.0;

/// The reference position at T_END after `n` RK4 steps of the exact equation.
fn reference_position(n: u64) -> [f64; 2] {
    pendulum_reference(T_END, n)
}

/// The engine's particle position at T_END with `n` steps.
fn engine_position(system: &Arc<System>, method: Method, kind: IntegratorKind, n: u64) -> [f64; 2] {
    let formulation = formulate(system.clone(), method, Feedback::default()).unwrap();
    let options = Options {
        integrator: kind,
        dt: T_END / n as f64,
        steps: n,
        every: n,
        ..Default::default()
    };
    let stats = run(formulation, &options, &mut NullSink).unwrap();
    assert_eq!(stats.steps, n);
    [stats.x[0], stats.x[1]]
}

/// Errors at step counts `ns` (each twice the previous), the observed orders between
/// consecutive ones, and the assertion that every observed order lies in `band`.
fn assert_order(method: Method, kind: IntegratorKind, ns: &[u64], band: (f64, f64)) {
    let system = pendulum();
    let finest = *ns.last().unwrap();
    let reference = reference_position(100 * finest);
    let errors: Vec<f64> = ns
        .iter()
        .map(|&n| {
            let x = engine_position(&system, method, kind, n);
            (x[0] - reference[0]).hypot(x[1] - reference[1])
        })
        .collect();
    let orders: Vec<f64> = errors.windows(2).map(|e| (e[0] / e[1]).log2()).collect();
    let errors_text: Vec<String> = errors.iter().map(|e| format!("{e:.3e}")).collect();
    let report = format!(
        "{} {}: steps {ns:?}, errors [{}], observed orders {orders:.3?}",
        method.name(),
        kind.name(),
        errors_text.join(", ")
    );
    println!("{report}");
    // Far above round-off (1e-15 relative to L) at the finest step, so the order is real.
    assert!(
        errors.iter().all(|&e| e > 1e-12),
        "error at round-off level, order meaningless: {report}"
    );
    for order in &orders {
        assert!(
            (band.0..=band.1).contains(order),
            "observed order {order:.3} outside {band:?}: {report}"
        );
    }
}

const FIRST: (f64, f64) = (0.8, 1.2);
const SECOND: (f64, f64) = (1.8, 2.2);
const FOURTH: (f64, f64) = (3.7, 4.3);

// Step counts: each list starts where the error is already in its asymptotic regime (the
// leading term dominates: omega dt <= 0.03 for first order, <= 0.1 for midpoint, <= 0.3 for
// rk4, omega = sqrt(g/L) ~ 2.6/s) and stops well above round-off.
const FIRST_ORDER_STEPS: [u64; 5] = [200, 400, 800, 1600, 3200];
const SECOND_ORDER_STEPS: [u64; 5] = [50, 100, 200, 400, 800];
const FOURTH_ORDER_STEPS: [u64; 5] = [10, 20, 40, 80, 160];

#[test]
fn implicit_euler_converges_at_first_order() {
    assert_order(
        Method::Implicit,
        IntegratorKind::Euler,
        &FIRST_ORDER_STEPS,
        FIRST,
    );
}

#[test]
fn parametric_euler_converges_at_first_order() {
    assert_order(
        Method::Parametric,
        IntegratorKind::Euler,
        &FIRST_ORDER_STEPS,
        FIRST,
    );
}

#[test]
fn implicit_symplectic_euler_converges_at_first_order() {
    assert_order(
        Method::Implicit,
        IntegratorKind::SymplecticEuler,
        &FIRST_ORDER_STEPS,
        FIRST,
    );
}

#[test]
fn parametric_symplectic_euler_converges_at_first_order() {
    assert_order(
        Method::Parametric,
        IntegratorKind::SymplecticEuler,
        &FIRST_ORDER_STEPS,
        FIRST,
    );
}

#[test]
fn implicit_midpoint_converges_at_second_order() {
    assert_order(
        Method::Implicit,
        IntegratorKind::Midpoint,
        &SECOND_ORDER_STEPS,
        SECOND,
    );
}

#[test]
fn parametric_midpoint_converges_at_second_order() {
    assert_order(
        Method::Parametric,
        IntegratorKind::Midpoint,
        &SECOND_ORDER_STEPS,
        SECOND,
    );
}

#[test]
fn implicit_rk4_converges_at_fourth_order() {
    assert_order(
        Method::Implicit,
        IntegratorKind::Rk4,
        &FOURTH_ORDER_STEPS,
        FOURTH,
    );
}

#[test]
fn parametric_rk4_converges_at_fourth_order() {
    assert_order(
        Method::Parametric,
        IntegratorKind::Rk4,
        &FOURTH_ORDER_STEPS,
        FOURTH,
    );
}

// The declared orders agree with what is measured above.
#[test]
fn declared_orders_match_the_measured_ones() {
    assert_eq!(IntegratorKind::Euler.order(), 1);
    assert_eq!(IntegratorKind::SymplecticEuler.order(), 1);
    assert_eq!(IntegratorKind::Midpoint.order(), 2);
    assert_eq!(IntegratorKind::Rk4.order(), 4);
}
