//! The order of every fixed-step integrator, measured on systems whose acceleration depends on
//! the velocity.
//!
//! Law checked: a method of order p has global error e(dt) ~ C dt^p at a fixed end time once
//! dt is in the asymptotic range, so halving dt divides the error by 2^p and the observed
//! order log2(e(dt) / e(dt/2)) tends to p. Every integrator of the table in `integrate/mod.rs`
//! with a fixed step is measured here (dopri5 chooses its own steps; its accuracy against
//! tolerances is tested in `physics_gauss_dopri.rs`), each on systems where qddot = f(t, q,
//! qdot) depends on qdot, because a scheme that evaluates f at the wrong velocity can still
//! be of full order when f ignores qdot (a linear spring) and lose an order as soon as it
//! does not:
//!
//! - the implicit form with a curved constraint: its constraint bias v^T H v is quadratic in
//!   v (`scenes/circle.toml`, a bead on a circle started at rest at 60 degrees);
//! - a spherical pendulum in 3D, as a rod constraint |x| = L (implicit form: bias) and in the
//!   spherical angles theta, phi (parametric form: non-constant mass matrix
//!   m L^2 diag(1, sin^2 theta) and h = xddot - J qddot quadratic in the rates), started away
//!   from the poles with an azimuthal rate so that the motion is genuinely 3D;
//! - a pendulum with linear drag F = -c v, both forms (the applied force itself depends on v).
//!
//! References are independent of the engine: the exact equations of motion in the angles,
//! integrated by a hand-written RK4 with REFERENCE_STEPS steps (error ~1e-16, far below every
//! error measured); the error is the distance between the particle's position at T_END and the
//! reference's. Each measurement uses four step counts (three consecutive ratios, every one
//! asserted), chosen where the leading error term dominates and far above round-off.

use std::path::Path;
use std::sync::Arc;

use bead::formulation::{
    formulate, ConstrainedSystem, Feedback, Formulation, Implicit, Method, SecondOrderSystem,
    State, StepError,
};
use bead::integrate::{Integrator, IntegratorKind, IntegratorSettings, Rattle, Verlet};
use bead::model::{Endpoint, Force, System, SystemBuilder};
use bead::scene::Scene;

mod common;
use common::{G, L, MASS, OMEGA0, THETA0};

/// End time at which errors are measured.
const T_END: f64 = 1.0;
/// Steps of the reference RK4 over T_END: (omega h)^4 ~ 1e-17 for the systems below.
const REFERENCE_STEPS: u64 = 40_000;

// ---------------------------------------------------------------------------------------
// systems and their exact equations

/// The shipped bead on a circle (implicit form is what the issue measured).
fn circle_scene() -> Arc<System> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/circle.toml");
    Scene::load(&path, &[])
        .unwrap_or_else(|e| panic!("{e}"))
        .system
}

/// circle.toml's parameters: L = 1, g = 9.81, theta0 = pi/3, at rest.
const CIRCLE_L: f64 = 1.0;
const CIRCLE_THETA0: f64 = std::f64::consts::FRAC_PI_3;

/// Spherical pendulum: rod length SPHERE_L, +z down, gravity G along +z; theta from the
/// downward vertical, phi the azimuth about it.
const SPHERE_L: f64 = 1.2;
const SPHERE_MASS: f64 = 0.7;
/// (theta, phi, theta', phi') at t = 0.
const SPHERE_Y0: [f64; 4] = [1.0, 0.3, 0.4, 2.0];

/// x = L (sin theta cos phi, sin theta sin phi, cos theta) and its velocity.
fn sphere_position(y: &[f64; 4]) -> Vec<f64> {
    let (st, ct) = y[0].sin_cos();
    let (sp, cp) = y[1].sin_cos();
    vec![SPHERE_L * st * cp, SPHERE_L * st * sp, SPHERE_L * ct]
}

fn sphere_velocity(y: &[f64; 4]) -> Vec<f64> {
    let (st, ct) = y[0].sin_cos();
    let (sp, cp) = y[1].sin_cos();
    let (dt, dp) = (y[2], y[3]);
    vec![
        SPHERE_L * (ct * cp * dt - st * sp * dp),
        SPHERE_L * (ct * sp * dt + st * cp * dp),
        -SPHERE_L * st * dt,
    ]
}

/// The spherical pendulum as a rod to the origin (implicit) and in the angles (parametric).
fn spherical_pendulum() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 0.0, G]);
    b.param("L", SPHERE_L).unwrap();
    let bob = b
        .particle(
            "bob",
            SPHERE_MASS,
            &sphere_position(&SPHERE_Y0),
            &sphere_velocity(&SPHERE_Y0),
        )
        .unwrap();
    b.distance("rod", bob, Endpoint::Fixed(vec![0.0, 0.0, 0.0]), SPHERE_L)
        .unwrap();
    b.parametric(&["theta", "phi"], &SPHERE_Y0[..2], &SPHERE_Y0[2..])
        .unwrap();
    b.parametric_position_exprs(
        "bob",
        &[
            "L*sin(theta)*cos(phi)",
            "L*sin(theta)*sin(phi)",
            "L*cos(theta)",
        ],
    )
    .unwrap();
    Arc::new(b.build().unwrap())
}

/// Lagrange's equations of the spherical pendulum (T = m L^2 (theta'^2 + sin^2 theta phi'^2)
/// / 2, V = -m g L cos theta).
fn sphere_rates(y: &[f64; 4]) -> [f64; 4] {
    let (st, ct) = y[0].sin_cos();
    [
        y[2],
        y[3],
        st * ct * y[3] * y[3] - (G / SPHERE_L) * st,
        -2.0 * ct / st * y[2] * y[3],
    ]
}

/// Linear drag coefficient of the damped pendulum (c / m = 0.4 /s).
const DRAG: f64 = 0.8;

/// The tests' common pendulum (L = 1.5, m = 2, theta0 = 1, omega0 = 0.5, +y down) with drag
/// F = -c v: as a rod (implicit) and in the angle (parametric).
fn pendulum_with_drag() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    b.param("L", L).unwrap();
    let (s, c) = THETA0.sin_cos();
    let bead = b
        .particle(
            "bead",
            MASS,
            &[L * s, L * c],
            &[L * OMEGA0 * c, -L * OMEGA0 * s],
        )
        .unwrap();
    b.force(Force::Drag {
        particle: None,
        coefficient: DRAG,
    })
    .unwrap();
    b.distance("rod", bead, Endpoint::Fixed(vec![0.0, 0.0]), L)
        .unwrap();
    b.parametric(&["theta"], &[THETA0], &[OMEGA0]).unwrap();
    b.parametric_position_exprs("bead", &["L*sin(theta)", "L*cos(theta)"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// theta'' = -(g/L) sin theta - (c/m) theta' (the drag on a bead moving along the circle is
/// tangential: -c L theta').
fn drag_rates(y: &[f64; 4]) -> [f64; 4] {
    [y[2], 0.0, -(G / L) * y[0].sin() - DRAG / MASS * y[2], 0.0]
}

fn circle_rates(y: &[f64; 4]) -> [f64; 4] {
    [y[2], 0.0, -(G / CIRCLE_L) * y[0].sin(), 0.0]
}

/// Classic RK4 for y' = f(y), REFERENCE_STEPS steps from y0 to T_END.
fn reference(f: fn(&[f64; 4]) -> [f64; 4], y0: [f64; 4]) -> [f64; 4] {
    let h = T_END / REFERENCE_STEPS as f64;
    let shifted = |y: &[f64; 4], k: &[f64; 4], s: f64| std::array::from_fn(|i| y[i] + s * k[i]);
    let mut y = y0;
    for _ in 0..REFERENCE_STEPS {
        let k1 = f(&y);
        let k2 = f(&shifted(&y, &k1, 0.5 * h));
        let k3 = f(&shifted(&y, &k2, 0.5 * h));
        let k4 = f(&shifted(&y, &k3, h));
        for i in 0..4 {
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }
    y
}

/// A system to measure on: the model, the form, and the exact final particle position.
struct Case {
    name: &'static str,
    system: Arc<System>,
    method: Method,
    exact: Vec<f64>,
}

fn circle(method: Method) -> Case {
    let y = reference(circle_rates, [CIRCLE_THETA0, 0.0, 0.0, 0.0]);
    Case {
        name: "circle.toml",
        system: circle_scene(),
        method,
        exact: vec![CIRCLE_L * y[0].sin(), CIRCLE_L * y[0].cos()],
    }
}

fn sphere(method: Method) -> Case {
    Case {
        name: "spherical pendulum",
        system: spherical_pendulum(),
        method,
        exact: sphere_position(&reference(sphere_rates, SPHERE_Y0)),
    }
}

fn drag(method: Method) -> Case {
    let y = reference(drag_rates, [THETA0, 0.0, OMEGA0, 0.0]);
    Case {
        name: "pendulum with drag",
        system: pendulum_with_drag(),
        method,
        exact: vec![L * y[0].sin(), L * y[0].cos()],
    }
}

/// Every velocity-dependent case a method applies to (rattle: the implicit form only).
fn cases(kind: IntegratorKind) -> Vec<Case> {
    let mut cases = vec![circle(Method::Implicit)];
    for method in [Method::Implicit, Method::Parametric] {
        if method == Method::Parametric && kind.needs_constraints() {
            continue;
        }
        cases.push(sphere(method));
        cases.push(drag(method));
    }
    cases
}

// ---------------------------------------------------------------------------------------
// measurement

/// Settings of the measured runs: RATTLE's constraint solve to round-off (1e-14 in units of
/// C, lengths ~1), so that it does not pollute the error.
fn settings() -> IntegratorSettings {
    IntegratorSettings {
        constraint_tolerance: 1e-14,
        ..IntegratorSettings::default()
    }
}

/// The particle position at T_END after n steps of `kind`.
fn final_position(case: &Case, kind: IntegratorKind, n: u64) -> Vec<f64> {
    let mut formulation = formulate(case.system.clone(), case.method, Feedback::default()).unwrap();
    let mut state = formulation.initial_state();
    let mut integrator = kind.build_with(state.q.len(), &settings());
    let dt = T_END / n as f64;
    for _ in 0..n {
        integrator
            .step(&mut *formulation, &mut state, dt)
            .unwrap_or_else(|e| panic!("{} {}: {e}", case.name, kind.name()));
    }
    let dim = case.system.n_coords();
    let (mut x, mut xdot) = (vec![0.0; dim], vec![0.0; dim]);
    formulation.particle_state(state.t, &state.q, &state.qdot, &mut x, &mut xdot);
    x
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt()
}

/// Measure `kind` on every case at the step counts `ns` (each twice the previous) and assert
/// that every observed order lies within `tolerance` of `order` and every error is far above
/// round-off. Prints one line per case: the errors and the observed orders.
fn assert_order(kind: IntegratorKind, order: f64, tolerance: f64, ns: [u64; 4]) {
    let mut failures = Vec::new();
    for case in cases(kind) {
        let errors: Vec<f64> = ns
            .iter()
            .map(|&n| distance(&final_position(&case, kind, n), &case.exact))
            .collect();
        let observed: Vec<f64> = errors.windows(2).map(|e| (e[0] / e[1]).log2()).collect();
        let errors_text: Vec<String> = errors.iter().map(|e| format!("{e:.3e}")).collect();
        let report = format!(
            "{:<16} {:<10} {:<20} steps {ns:?} errors [{}] orders {observed:.3?}",
            kind.name(),
            case.method.name(),
            case.name,
            errors_text.join(", ")
        );
        println!("{report}");
        if errors.iter().any(|&e| e < 1e-12)
            || observed.iter().any(|o| (o - order).abs() > tolerance)
        {
            failures.push(report);
        }
    }
    assert!(
        failures.is_empty(),
        "observed orders outside {order} +- {tolerance} (or errors at round-off):\n{}",
        failures.join("\n")
    );
}

// ---------------------------------------------------------------------------------------
// orders

/// Law: explicit Euler is of order 1 (observed 1.0 +- 0.1) on velocity-dependent systems.
#[test]
fn euler_is_first_order_when_the_acceleration_depends_on_velocity() {
    assert_order(IntegratorKind::Euler, 1.0, 0.1, [800, 1600, 3200, 6400]);
}

/// Law: symplectic Euler is of order 1 (observed 1.0 +- 0.1) on velocity-dependent systems.
#[test]
fn symplectic_euler_is_first_order_when_the_acceleration_depends_on_velocity() {
    assert_order(
        IntegratorKind::SymplecticEuler,
        1.0,
        0.1,
        [800, 1600, 3200, 6400],
    );
}

/// Law: explicit midpoint is of order 2 (observed 2.0 +- 0.1) on velocity-dependent systems.
#[test]
fn midpoint_is_second_order_when_the_acceleration_depends_on_velocity() {
    assert_order(IntegratorKind::Midpoint, 2.0, 0.1, [400, 800, 1600, 3200]);
}

/// Law: velocity Verlet with the implicit velocity half kick v' = v_half + dt/2 f(q', v') is
/// of order 2 (observed 2.0 +- 0.1) when f depends on qdot: the implicit form's constraint
/// bias, the parametric spherical pendulum's M(q) and h, drag. (The explicit kick
/// f(q', v_half) of the old scheme made it first order on all of them.)
#[test]
fn verlet_is_second_order_when_the_acceleration_depends_on_velocity() {
    assert_order(IntegratorKind::Verlet, 2.0, 0.1, [100, 200, 400, 800]);
}

/// Law: RATTLE is of order 2 (observed 2.0 +- 0.1) with velocity-dependent applied forces
/// (drag) as well as on the curved constraints of the circle and the sphere: its second half
/// kick solves v' = v_half + h/2 (a(q', v') + W J^T mu), J v' + C_t = 0.
#[test]
fn rattle_is_second_order_when_the_applied_forces_depend_on_velocity() {
    assert_order(IntegratorKind::Rattle, 2.0, 0.1, [100, 200, 400, 800]);
}

/// Law: RATTLE composed in Suzuki's five stages is of order 4 (observed 4.0 +- 0.1) on the
/// same velocity-dependent systems as RATTLE: the composition of a symmetric second-order
/// method with weights summing to 1 and their cubes to 0 (its middle stage runs backwards).
#[test]
fn rattle4_is_fourth_order_when_the_applied_forces_depend_on_velocity() {
    assert_order(IntegratorKind::Rattle4, 4.0, 0.1, [10, 20, 40, 80]);
}

/// Law: step and project (fast projection) is of order 1 (observed 1.0 +- 0.1) on the curved
/// constraints of the circle and the sphere and with drag: its velocity is the positions'
/// change over the step, projected onto J v + C_t = 0.
#[test]
fn fast_projection_is_first_order_when_the_applied_forces_depend_on_velocity() {
    assert_order(
        IntegratorKind::FastProjection,
        1.0,
        0.1,
        [400, 800, 1600, 3200],
    );
}

/// Law: RK4 is of order 4 (observed 4.0 +- 0.1) on velocity-dependent systems.
#[test]
fn rk4_is_fourth_order_when_the_acceleration_depends_on_velocity() {
    assert_order(IntegratorKind::Rk4, 4.0, 0.1, [40, 80, 160, 320]);
}

/// Law: two-stage Gauss-Legendre is of order 4 (observed 4.0 +- 0.1) on velocity-dependent
/// systems.
#[test]
fn gauss_legendre_is_fourth_order_when_the_acceleration_depends_on_velocity() {
    assert_order(IntegratorKind::GaussLegendre, 4.0, 0.1, [10, 20, 40, 80]);
}

/// The declared orders (help texts, README) are the ones measured above.
#[test]
fn declared_orders_match_the_measured_ones() {
    for (kind, order) in [
        (IntegratorKind::Euler, 1),
        (IntegratorKind::SymplecticEuler, 1),
        (IntegratorKind::Midpoint, 2),
        (IntegratorKind::Verlet, 2),
        (IntegratorKind::Rattle, 2),
        (IntegratorKind::Rattle4, 4),
        (IntegratorKind::Rk4, 4),
        (IntegratorKind::GaussLegendre, 4),
        (IntegratorKind::FastProjection, 1),
    ] {
        assert_eq!(kind.order(), order, "{}", kind.name());
        assert!(kind.describe().contains(&format!("order {order}")));
    }
}

// ---------------------------------------------------------------------------------------
// verlet and rattle: what the implicit kick changes and what it does not

/// Counts the evaluations of f of the system it wraps.
struct Counting<'a> {
    inner: &'a mut dyn SecondOrderSystem,
    evaluations: u64,
}

impl SecondOrderSystem for Counting<'_> {
    fn n_coords(&self) -> usize {
        self.inner.n_coords()
    }
    fn acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        self.evaluations += 1;
        self.inner.acceleration(t, q, qdot, a)
    }
    fn velocity_dependent(&self) -> bool {
        self.inner.velocity_dependent()
    }
}

/// Unconstrained particle of mass 2 on a zero-length spring (k = 8) to the origin, no gravity:
/// x'' = -(k/m) x, omega = 2; f ignores qdot.
fn spring_oscillator() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 0.0]);
    let p = b.particle("p", 2.0, &[1.0, 0.5], &[0.3, -0.2]).unwrap();
    b.force(Force::Spring {
        a: p,
        b: Endpoint::Fixed(vec![0.0, 0.0]),
        stiffness: 8.0,
        rest_length: 0.0,
    })
    .unwrap();
    Arc::new(b.build().unwrap())
}

/// v += dt/2 a.
fn kick(v: &mut [f64], a: &[f64], dt: f64) {
    for (v, a) in v.iter_mut().zip(a) {
        *v += 0.5 * dt * a;
    }
}

/// v += dt/2 a, then q += dt v, component by component as velocity Verlet does.
fn drift_after_kick(s: &mut State, a: &[f64], dt: f64) {
    for ((v, q), a) in s.qdot.iter_mut().zip(s.q.iter_mut()).zip(a) {
        *v += 0.5 * dt * a;
        *q += dt * *v;
    }
}

/// Law: when f does not depend on qdot the implicit kick is not needed, and verlet is exactly
/// classic velocity Verlet (v += dt/2 a; q += dt v; a = f(q'); v += dt/2 a): on the spring
/// oscillator every position and velocity of 10^4 steps is bit-identical to a hand-written
/// velocity Verlet on the same f, with exactly two evaluations per step; being symplectic,
/// its energy error stays bounded (the largest relative error over the last tenth of the run,
/// 2000 periods' worth of phase, is within 1.5x of that over the first tenth, and below
/// (omega dt)^2 / 4).
#[test]
fn verlet_is_classic_velocity_verlet_when_the_acceleration_ignores_velocity() {
    const STEPS: usize = 10_000;
    let dt = 0.05;
    let system = spring_oscillator();
    let mut engine = Implicit::new(system.clone(), Feedback::default());
    assert!(!engine.velocity_dependent());
    let mut state = engine.initial_state();
    let mut by_hand = state.clone();
    let mut hand_system = Implicit::new(system.clone(), Feedback::default());
    let mut verlet = Verlet::new(2);
    let mut a = vec![0.0; 2];
    let e0 = system.energy(&state.q, &state.qdot);
    let mut energy_errors = Vec::with_capacity(STEPS);
    let mut counting = Counting {
        inner: &mut engine,
        evaluations: 0,
    };
    for step in 0..STEPS {
        verlet.step(&mut counting, &mut state, dt).unwrap();
        hand_system
            .acceleration(by_hand.t, &by_hand.q, &by_hand.qdot, &mut a)
            .unwrap();
        drift_after_kick(&mut by_hand, &a, dt);
        hand_system
            .acceleration(by_hand.t + dt, &by_hand.q, &by_hand.qdot, &mut a)
            .unwrap();
        kick(&mut by_hand.qdot, &a, dt);
        by_hand.t += dt;
        assert!(
            state.q == by_hand.q && state.qdot == by_hand.qdot,
            "step {step}: {state:?} vs {by_hand:?}"
        );
        energy_errors.push((system.energy(&state.q, &state.qdot) - e0).abs() / e0);
    }
    assert_eq!(counting.evaluations, 2 * STEPS as u64);
    assert_eq!(verlet.iterations_max(), 0);
    let tenth = STEPS / 10;
    let max = |s: &[f64]| s.iter().fold(0.0_f64, |m, e| m.max(*e));
    let (first, last) = (
        max(&energy_errors[..tenth]),
        max(&energy_errors[STEPS - tenth..]),
    );
    let omega_dt = 2.0 * dt;
    println!("verlet spring: energy error first tenth {first:.3e}, last tenth {last:.3e}");
    assert!(
        last <= 1.5 * first,
        "energy drifts: {first:e} then {last:e}"
    );
    assert!(first <= omega_dt * omega_dt / 4.0, "{first:e}");
}

/// The explicit second half kick v' = v_half + dt/2 f(t + dt, q', v_half) of the old verlet,
/// by hand: first order when f depends on qdot.
fn explicit_kick_verlet(system: &mut dyn SecondOrderSystem, s: &mut State, dt: f64, a: &mut [f64]) {
    system.acceleration(s.t, &s.q, &s.qdot, a).unwrap();
    drift_after_kick(s, a, dt);
    system.acceleration(s.t + dt, &s.q, &s.qdot, a).unwrap();
    kick(&mut s.qdot, a, dt);
    s.t += dt;
}

/// Law: solving the second half kick at v' instead of evaluating f at v_half removes the
/// O(dt) error term. On the implicit circle (circle.toml) at dt = 1/400 s the new verlet's
/// position error at t = 1 s is more than 20 times smaller than the explicit kick's (which
/// is first order), at 2 + (a few) evaluations per step instead of 2.
#[test]
fn verlet_error_on_the_implicit_circle_is_far_below_the_explicit_kicks() {
    let case = circle(Method::Implicit);
    let n = 400;
    let dt = T_END / n as f64;
    let mut formulation = Implicit::new(case.system.clone(), Feedback::default());
    assert!(formulation.velocity_dependent());
    let mut old = formulation.initial_state();
    let mut a = vec![0.0; 2];
    for _ in 0..n {
        explicit_kick_verlet(&mut formulation, &mut old, dt, &mut a);
    }
    let mut new = formulation.initial_state();
    let mut verlet = Verlet::new(2);
    let mut counting = Counting {
        inner: &mut formulation,
        evaluations: 0,
    };
    for _ in 0..n {
        verlet.step(&mut counting, &mut new, dt).unwrap();
    }
    let per_step = counting.evaluations as f64 / n as f64;
    let (old_error, new_error) = (distance(&old.q, &case.exact), distance(&new.q, &case.exact));
    println!(
        "circle.toml implicit, dt = 1/{n}: explicit kick error {old_error:.3e}, implicit kick \
         error {new_error:.3e} ({:.0}x smaller), {per_step:.2} evaluations per step, at most {} \
         sweeps",
        old_error / new_error,
        verlet.iterations_max()
    );
    assert!(
        new_error * 20.0 < old_error,
        "{new_error:e} vs {old_error:e}"
    );
    assert!(per_step <= 8.0, "{per_step}");
}

/// The cost of the implicit kick: each sweep contracts the error by about rho =
/// dt/2 ||df/dqdot||, so reaching round-off (1e-14 of the accelerations) takes about
/// 14 / log10(1/rho) sweeps, and fewer as dt shrinks. On every velocity-dependent case, at
/// dt = 1/100 s (the coarsest step of the order tests) and 1/400 s, verlet and rattle need at
/// most 16 sweeps per step (the limit is 50), and verlet at 1/400 s no more than at 1/100 s;
/// rattle iterates only with drag (its applied acceleration W F ignores the constraint bias).
/// Prints the mean evaluations of f per step of verlet and the most sweeps of each method.
#[test]
fn the_implicit_kick_converges_in_a_few_sweeps() {
    for case in cases(IntegratorKind::Verlet) {
        let mut line = format!("{:<10} {:<20}", case.method.name(), case.name);
        let mut sweeps = Vec::new();
        for n in [100, 400] {
            let dt = T_END / n as f64;
            let mut formulation =
                formulate(case.system.clone(), case.method, Feedback::default()).unwrap();
            assert!(formulation.velocity_dependent());
            let mut state = formulation.initial_state();
            let mut verlet = Verlet::with_settings(state.q.len(), &settings());
            let mut counting = Counting {
                inner: &mut *formulation,
                evaluations: 0,
            };
            for _ in 0..n {
                verlet.step(&mut counting, &mut state, dt).unwrap();
            }
            line += &format!(
                " | dt 1/{n}: verlet {:.2} evaluations per step, at most {} sweeps",
                counting.evaluations as f64 / n as f64,
                verlet.iterations_max()
            );
            sweeps.push(verlet.iterations_max());
            if case.method == Method::Implicit {
                let mut formulation = Implicit::new(case.system.clone(), Feedback::default());
                let mut state = formulation.initial_state();
                let mut rattle = Rattle::with_settings(state.q.len(), &settings());
                for _ in 0..n {
                    rattle.step(&mut formulation, &mut state, dt).unwrap();
                }
                let drag = formulation.applied_forces_velocity_dependent();
                line += &format!(
                    "; rattle at most {} sweeps",
                    rattle.velocity_iterations_max()
                );
                assert_eq!(rattle.velocity_iterations_max() > 0, drag, "{line}");
                assert!(rattle.velocity_iterations_max() <= 16, "{line}");
            }
        }
        println!("{line}");
        assert!(sweeps[0] <= 16 && sweeps[1] <= sweeps[0], "{line}");
    }
}

/// Law: the answer to "does f depend on qdot" follows the physics and errs only towards yes:
/// implicit form: any constraint row (the bias) or drag; parametric form: drag, or a map
/// whose h = xddot - J qddot reads the rates (nonlinear in q); a map linear in q, even one
/// moving with t, gives f independent of qdot.
#[test]
fn formulations_report_whether_the_acceleration_depends_on_velocity() {
    let line = |drag: bool, moving: bool| {
        let mut b = SystemBuilder::new(&[0.0, G]);
        b.particle("bead", 1.0, &[0.0, 0.0], &[1.0, 2.0]).unwrap();
        if drag {
            b.force(Force::Drag {
                particle: None,
                coefficient: 0.3,
            })
            .unwrap();
        }
        b.parametric(&["s"], &[0.0], &[1.0]).unwrap();
        let y = if moving { "2*s + sin(t)" } else { "2*s" };
        b.parametric_position_exprs("bead", &["s", y]).unwrap();
        Arc::new(b.build().unwrap())
    };
    let parametric = |system: Arc<System>| {
        formulate(system, Method::Parametric, Feedback::default())
            .unwrap()
            .velocity_dependent()
    };
    let implicit = |system: Arc<System>| Implicit::new(system, Feedback::default());

    assert!(!implicit(spring_oscillator()).velocity_dependent());
    assert!(!parametric(line(false, false)));
    assert!(!parametric(line(false, true)));
    assert!(parametric(line(true, false)));
    assert!(implicit(line(true, false)).velocity_dependent());
    assert!(!implicit(line(false, false)).velocity_dependent());
    assert!(implicit(circle_scene()).velocity_dependent());
    assert!(parametric(circle_scene()));
    assert!(parametric(spherical_pendulum()));
    assert!(!implicit(circle_scene()).applied_forces_velocity_dependent());
    assert!(implicit(pendulum_with_drag()).applied_forces_velocity_dependent());
}

/// A free particle under strong drag, c/m = 100 /s: the kick iteration contracts by
/// dt/2 c/m per sweep, so it diverges for dt > 0.02 s.
fn heavily_damped() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    b.particle("bead", 0.01, &[0.0, 0.0], &[1.0, 0.0]).unwrap();
    b.force(Force::Drag {
        particle: None,
        coefficient: 1.0,
    })
    .unwrap();
    Arc::new(b.build().unwrap())
}

/// Law: the implicit kick's fixed-point iteration converges only when dt is small against the
/// system's time scales; outside (dt = 0.1 s, five times the 0.02 s limit of c/m = 100 /s)
/// verlet and rattle fail with an error naming themselves, what did not converge and the fix
/// (reduce dt), instead of returning a wrong state; at dt = 1 ms both converge.
#[test]
fn the_implicit_kick_reports_an_iteration_that_does_not_converge() {
    for (kind, name) in [
        (IntegratorKind::Verlet, "verlet"),
        (IntegratorKind::Rattle, "rattle"),
    ] {
        for dt in [0.1, 1e-3] {
            let mut formulation = Implicit::new(heavily_damped(), Feedback::default());
            let mut state = formulation.initial_state();
            let mut integrator = kind.build(2);
            let result = integrator.step(&mut formulation, &mut state, dt);
            if dt < 0.02 {
                result.unwrap();
                continue;
            }
            let err = result.unwrap_err();
            let message = err.to_string();
            println!("{message}");
            assert!(
                matches!(err, StepError::ImplicitStageFailed { method, .. } if method == name),
                "{message}"
            );
            for part in [name, "velocity half kick", "did not converge", "reduce dt"] {
                assert!(message.contains(part), "{part} in {message}");
            }
        }
    }
}
