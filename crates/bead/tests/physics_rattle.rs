//! Structure-preserving constrained integration: velocity Verlet, RATTLE and the projection
//! onto the constraints (`--project`).
//!
//! Laws checked (each test states its own):
//! - a method of order p has global error ~ C dt^p, so halving dt divides it by 2^p;
//! - RATTLE satisfies the holonomic constraint C(q, t) = 0 after every step to its solver
//!   tolerance, and the velocity constraint J v + C_t = 0 to round-off;
//! - a symplectic method's energy error stays bounded (oscillates) instead of drifting;
//! - the mass-weighted projections land on C = 0 and on J v = -C_t;
//! - impossible requests (RATTLE without constraints) and solver failures are errors.
//!
//! References are independent of the engine: closed-form solutions, or the pendulum's scalar
//! equation theta'' = -(g/L) sin theta integrated by a hand-written RK4.

use std::sync::Arc;

use bead::formulation::{
    formulate, ConstrainedSystem, Feedback, Implicit, Method, Parametric, SecondOrderSystem, State,
    StepError,
};
use bead::integrate::{Integrator, IntegratorKind, IntegratorSettings, Rattle};
use bead::model::{Endpoint, Force, System, SystemBuilder};
use bead::simulate::{
    ConfigError, NullSink, Requirement, RunError, RunStats, Sample, SetupError, Simulation,
    SimulationConfig, Sink,
};
use common::{run, Options};

// ---------------------------------------------------------------------------------------
// systems

/// Spring oscillator: unconstrained particle of mass 2 on a zero-length spring (k = 8) to the
/// origin, no gravity: x'' = -(k/m) x, omega = 2, exact x(t) = x0 cos wt + v0/w sin wt.
const SPRING_K: f64 = 8.0;
const SPRING_MASS: f64 = 2.0;
const SPRING_X0: [f64; 2] = [1.0, 0.5];
const SPRING_V0: [f64; 2] = [0.3, -0.2];

fn spring_oscillator() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 0.0]);
    let p = b
        .particle("p", SPRING_MASS, &SPRING_X0, &SPRING_V0)
        .unwrap();
    b.force(Force::Spring {
        a: p,
        b: Endpoint::Fixed(vec![0.0, 0.0]),
        stiffness: SPRING_K,
        rest_length: 0.0,
    })
    .unwrap();
    Arc::new(b.build().unwrap())
}

fn spring_exact(t: f64) -> [f64; 2] {
    let w = (SPRING_K / SPRING_MASS).sqrt();
    let (s, c) = (w * t).sin_cos();
    [
        SPRING_X0[0] * c + SPRING_V0[0] / w * s,
        SPRING_X0[1] * c + SPRING_V0[1] / w * s,
    ]
}

mod common;
use common::{pendulum, pendulum_reference, G};

/// The article's bead on the parabola x^2 + 100 y = 0, g = 500, released at rest at x = 150.
/// Length scale 150; C has units of length^2.
const PARABOLA_LENGTH: f64 = 150.0;

fn parabola() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 500.0]);
    b.particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0])
        .unwrap();
    b.constraint_expr("bead.x^2 + 100*bead.y").unwrap();
    b.parametric(&["q"], &[150.0], &[0.0]).unwrap();
    b.parametric_position_exprs("bead", &["q", "-q^2/100"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// The shipped double pendulum: rods of length 1 at pi/2 and 3 pi/4, masses 1 (chaotic).
fn double_pendulum() -> Arc<System> {
    let (th1, th2) = (std::f64::consts::FRAC_PI_2, 0.75 * std::f64::consts::PI);
    let mut b = SystemBuilder::new(&[0.0, G]);
    let a = b
        .particle("a", 1.0, &[th1.sin(), th1.cos()], &[0.0, 0.0])
        .unwrap();
    let bob = b
        .particle(
            "b",
            1.0,
            &[th1.sin() + th2.sin(), th1.cos() + th2.cos()],
            &[0.0, 0.0],
        )
        .unwrap();
    b.distance("upper rod", a, Endpoint::Fixed(vec![0.0, 0.0]), 1.0)
        .unwrap();
    b.distance("lower rod", bob, Endpoint::Particle(a), 1.0)
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// A bead on a circle of radius 1 whose centre moves as (0.3 sin 2t, 0): a time-dependent
/// (rheonomic) constraint with C_t != 0.
fn moving_circle() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    b.particle("bead", 1.5, &[1.0, 0.0], &[0.0, 0.6]).unwrap();
    b.constraint_expr("(bead.x - 0.3*sin(2*t))^2 + bead.y^2 - 1")
        .unwrap();
    Arc::new(b.build().unwrap())
}

// ---------------------------------------------------------------------------------------
// helpers

/// The moving circle, its implicit form and its initial state, the velocity projected onto
/// the velocity constraint J v + C_t = 0 too.
fn moving_circle_started() -> (Arc<System>, Implicit, State) {
    let system = moving_circle();
    let mut formulation = Implicit::new(system.clone(), Feedback::default());
    let (q, qdot) = system.initial_particle_state();
    let mut state = State { t: 0.0, q, qdot };
    formulation
        .project_velocities(0.0, &state.q.clone(), &mut state.qdot)
        .unwrap();
    (system, formulation, state)
}

fn options(kind: IntegratorKind, dt: f64, steps: u64) -> Options {
    Options {
        integrator: kind,
        dt,
        steps,
        every: 1,
        ..Options::default()
    }
}

fn with_tolerance(mut options: Options, tolerance: f64) -> Options {
    options.settings = IntegratorSettings {
        constraint_tolerance: tolerance,
        ..IntegratorSettings::default()
    };
    options
}

fn run_implicit(system: &Arc<System>, options: &Options, sink: &mut dyn Sink) -> RunStats {
    let formulation = formulate(system.clone(), Method::Implicit, Feedback::default()).unwrap();
    match run(formulation, options, sink) {
        Ok(stats) => stats,
        Err(failure) => panic!("run failed: {}", failure.error),
    }
}

/// Numbers as `[1.234e-5, ...]`.
fn sci(values: &[f64]) -> String {
    let parts: Vec<String> = values.iter().map(|v| format!("{v:.3e}")).collect();
    format!("[{}]", parts.join(", "))
}

/// Observed orders log2(e_i / e_{i+1}) for errors at successive halvings of dt.
fn orders(errors: &[f64]) -> Vec<f64> {
    errors.windows(2).map(|e| (e[0] / e[1]).log2()).collect()
}

/// Relative energy errors |E - E0| / |E0| and constraint errors of every step.
struct Trace {
    energy0: Option<f64>,
    energy_errors: Vec<f64>,
    constraint_errors: Vec<f64>,
}

impl Trace {
    fn new() -> Self {
        Trace {
            energy0: None,
            energy_errors: Vec::new(),
            constraint_errors: Vec::new(),
        }
    }
    /// (max relative energy error over the first tenth of the steps, over the last tenth).
    fn energy_tenths(&self) -> (f64, f64) {
        let tenth = self.energy_errors.len() / 10;
        let max = |s: &[f64]| s.iter().fold(0.0, |m: f64, e| m.max(*e));
        (
            max(&self.energy_errors[1..=tenth]),
            max(&self.energy_errors[self.energy_errors.len() - tenth..]),
        )
    }
}

impl Sink for Trace {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        let e0 = *self.energy0.get_or_insert(sample.energy);
        self.energy_errors
            .push((sample.energy - e0).abs() / e0.abs());
        self.constraint_errors.push(sample.constraint_error);
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// convergence

/// Law: velocity Verlet is of order 2. On the linear spring oscillator x'' = -(k/m) x the
/// global error at t = 2 against the exact x0 cos wt + v0/w sin wt falls by 4 per halving of
/// dt (observed order in [1.9, 2.1]).
#[test]
fn verlet_converges_at_second_order_on_a_spring_oscillator() {
    let system = spring_oscillator();
    let t_end = 2.0;
    let exact = spring_exact(t_end);
    let errors: Vec<f64> = [50u64, 100, 200, 400, 800]
        .iter()
        .map(|&n| {
            let stats = run_implicit(
                &system,
                &options(IntegratorKind::Verlet, t_end / n as f64, n),
                &mut NullSink,
            );
            (stats.x[0] - exact[0]).hypot(stats.x[1] - exact[1])
        })
        .collect();
    let observed = orders(&errors);
    println!(
        "verlet spring: errors {}, orders {observed:.3?}",
        sci(&errors)
    );
    for order in &observed {
        assert!(
            (1.9..=2.1).contains(order),
            "{observed:?}, errors {errors:?}"
        );
    }
}

/// Law: RATTLE is of order 2. On the pendulum held by its rod (distance constraint, implicit
/// form) the particle position at t = 1 converges to the solution of
/// theta'' = -(g/L) sin theta (hand-written RK4 at 100x the finest step) with observed order
/// in [1.9, 2.1]. The constraint solve runs to 1e-14 so that it does not pollute the error.
#[test]
fn rattle_converges_at_second_order_on_the_pendulum() {
    let system = pendulum();
    let t_end = 1.0;
    let ns = [50u64, 100, 200, 400, 800];
    let reference = pendulum_reference(t_end, 100 * 800);
    let errors: Vec<f64> = ns
        .iter()
        .map(|&n| {
            let o = with_tolerance(options(IntegratorKind::Rattle, t_end / n as f64, n), 1e-14);
            let stats = run_implicit(&system, &o, &mut NullSink);
            (stats.x[0] - reference[0]).hypot(stats.x[1] - reference[1])
        })
        .collect();
    let observed = orders(&errors);
    println!(
        "rattle pendulum: errors {}, orders {observed:.3?}",
        sci(&errors)
    );
    assert!(errors.iter().all(|&e| e > 1e-10), "{errors:?}");
    for order in &observed {
        assert!(
            (1.9..=2.1).contains(order),
            "{observed:?}, errors {errors:?}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// constraint residuals

/// Law: RATTLE enforces C(q_{n+1}) = 0 at every step by construction. On the article's
/// parabola (dt = 1/60) and on the double pendulum (two rods, dt = 1e-3) max |C| over every
/// one of 10^4 steps is at most the solver tolerance, 1e-12 times the constraint's scale
/// (L^2 = 150^2 for the parabola's C = x^2 + 100 y, 1 for the rods' C in length units).
#[test]
fn rattle_keeps_every_step_on_the_constraints() {
    for (name, system, dt, tolerance) in [
        (
            "parabola",
            parabola(),
            1.0 / 60.0,
            1e-12 * PARABOLA_LENGTH * PARABOLA_LENGTH,
        ),
        ("double pendulum", double_pendulum(), 1e-3, 1e-12),
    ] {
        let o = with_tolerance(options(IntegratorKind::Rattle, dt, 10_000), tolerance);
        let mut trace = Trace::new();
        let stats = run_implicit(&system, &o, &mut trace);
        let worst = trace
            .constraint_errors
            .iter()
            .fold(0.0, |m: f64, c| m.max(*c));
        println!(
            "rattle {name}: max |C| over {} steps = {worst:.3e} (tolerance {tolerance:.3e}), \
             at most {:?} Newton iterations per step",
            stats.steps, stats.newton_iterations_max
        );
        assert_eq!(trace.constraint_errors.len(), 10_001);
        assert!(worst <= tolerance, "{name}: {worst:e} > {tolerance:e}");
        assert!(stats.constraint_error_max <= tolerance);
        assert!(stats.newton_iterations_max.unwrap() <= 5);
    }
}

/// Law: for a moving constraint RATTLE solves C(q_{n+1}, t_{n+1}) = 0 and
/// J v_{n+1} + C_t = 0 (the velocity target includes C_t). The position residual stays within
/// tolerance and the velocity residual Cdot = J v + C_t at round-off after every step.
#[test]
fn rattle_follows_a_moving_constraint() {
    let (system, mut formulation, mut state) = moving_circle_started();
    let mut rattle = Rattle::new(2, 1e-13, 20);
    let set = system.constraints();
    let mut ws = set.workspace();
    let (mut worst_c, mut worst_cdot) = (0.0f64, 0.0f64);
    for _ in 0..2000 {
        rattle.step(&mut formulation, &mut state, 1e-3).unwrap();
        set.evaluate(state.t, &state.q, &state.qdot, &mut ws);
        worst_c = worst_c.max(ws.value[0].abs());
        worst_cdot = worst_cdot.max(ws.velocity[0].abs());
    }
    println!("moving circle: max |C| {worst_c:.3e}, max |J v + C_t| {worst_cdot:.3e}");
    assert!(worst_c <= 1e-13, "{worst_c:e}");
    assert!(worst_cdot <= 1e-12, "{worst_cdot:e}");
}

/// Law: the constraint forces do work -lambda . C_t, none for a fixed constraint. RATTLE's
/// constraint work is exactly 0 on a pendulum (a fixed rod, also with drag, whose applied
/// forces make the second half kick implicit) and not 0 on the moving circle, where it is the
/// trapezoidal rule for -lambda . C_t: summed over the run it matches the kinetic and
/// potential energy's change, which only the moving constraint causes.
#[test]
fn rattle_constraint_work_is_exactly_zero_for_fixed_constraints_only() {
    for drag in [0.0, 0.3] {
        let mut b = SystemBuilder::new(&[0.0, G]);
        let p = b.particle("bob", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
        b.distance("rod", p, Endpoint::Fixed(vec![0.0, 0.0]), 1.0)
            .unwrap();
        if drag > 0.0 {
            b.force(Force::Drag {
                particle: Some(p),
                coefficient: drag,
            })
            .unwrap();
        }
        let mut formulation = Implicit::new(Arc::new(b.build().unwrap()), Feedback::default());
        let mut state = bead::formulation::Formulation::initial_state(&formulation);
        let mut rattle = Rattle::new(2, 1e-13, 20);
        for step in 0..200 {
            rattle.step(&mut formulation, &mut state, 1e-2).unwrap();
            assert_eq!(rattle.constraint_work(), 0.0, "drag {drag}, step {step}");
        }
    }
    let (system, mut formulation, mut state) = moving_circle_started();
    let e0 = system.energy(&state.q, &state.qdot);
    let mut rattle = Rattle::new(2, 1e-13, 20);
    let (mut work, mut largest) = (0.0, 0.0_f64);
    for _ in 0..2000 {
        rattle.step(&mut formulation, &mut state, 1e-3).unwrap();
        work += rattle.constraint_work();
        largest = largest.max(rattle.constraint_work().abs());
    }
    let change = system.energy(&state.q, &state.qdot) - e0;
    println!("moving circle: constraint work {work:.6e}, energy change {change:.6e}");
    assert!(largest > 1e-6, "{largest:e}");
    assert!(
        (work - change).abs() < 1e-4 * change.abs(),
        "{work} vs {change}"
    );
}

// ---------------------------------------------------------------------------------------
// energy

/// Steps of the energy runs in debug builds (the acceptance test below does 10^6 in release).
const ENERGY_STEPS: u64 = 100_000;

/// Law: RATTLE is symplectic, so on the article's parabola (conservative, dt = 1/60) the
/// energy error oscillates without drift: over 10^5 steps the max relative energy error over
/// the last tenth is within 2x of that over the first tenth. rk4 with --project keeps
/// max |C| <= 1e-9 L^2 over the same run.
#[test]
fn rattle_energy_is_bounded_and_projection_keeps_rk4_on_the_parabola() {
    let system = parabola();
    let scale = PARABOLA_LENGTH * PARABOLA_LENGTH;
    let o = with_tolerance(
        options(IntegratorKind::Rattle, 1.0 / 60.0, ENERGY_STEPS),
        1e-12 * scale,
    );
    let mut trace = Trace::new();
    let stats = run_implicit(&system, &o, &mut trace);
    let (first, last) = trace.energy_tenths();
    println!(
        "rattle parabola {ENERGY_STEPS} steps: energy error first tenth {first:.4e}, last tenth \
         {last:.4e}, max |C| {:.3e}",
        stats.constraint_error_max
    );
    assert!(
        last <= 2.0 * first,
        "energy drifts: {first:e} then {last:e}"
    );
    assert!(stats.constraint_error_max <= 1e-9 * scale);

    let mut o = with_tolerance(
        options(IntegratorKind::Rk4, 1.0 / 60.0, ENERGY_STEPS),
        1e-12 * scale,
    );
    o.project = true;
    let stats = run_implicit(&system, &o, &mut NullSink);
    println!(
        "rk4 + project parabola {ENERGY_STEPS} steps: max |C| {:.3e}, energy error {:.3e}",
        stats.constraint_error_max, stats.energy_rel_error_max
    );
    assert!(stats.projected);
    assert!(stats.constraint_error_max <= 1e-9 * scale);
}

/// Law: RATTLE composed in Suzuki's five stages (rattle4, order 4) on the article's parabola
/// at dt = 1/60 over 10^5 steps: |C| within the solve's tolerance at every step, the energy
/// error at most 1e-5 of E_scale (RATTLE's is 2.6e-3 there), bounded (the last tenth's
/// maximum within 2x the first tenth's), and at equal work (RATTLE at dt/5, five times the
/// steps) at least 10x smaller than RATTLE's.
#[test]
fn rattle4_holds_the_parabolas_energy_to_1e_5_where_rattle_reaches_2_6e_3() {
    let system = parabola();
    let tolerance = 1e-12 * PARABOLA_LENGTH * PARABOLA_LENGTH;
    let dt = 1.0 / 60.0;
    let o = with_tolerance(
        options(IntegratorKind::Rattle4, dt, ENERGY_STEPS),
        tolerance,
    );
    let mut trace = Trace::new();
    let stats = run_implicit(&system, &o, &mut trace);
    let (first, last) = trace.energy_tenths();
    let worst_c = trace
        .constraint_errors
        .iter()
        .fold(0.0, |m: f64, c| m.max(*c));
    let energy = |kind: IntegratorKind, dt: f64, steps: u64| {
        let mut o = with_tolerance(options(kind, dt, steps), tolerance);
        o.every = steps;
        run_implicit(&system, &o, &mut NullSink).energy_rel_error_max
    };
    let rattle = energy(IntegratorKind::Rattle, dt, ENERGY_STEPS);
    let rattle_equal_work = energy(IntegratorKind::Rattle, dt / 5.0, 5 * ENERGY_STEPS);
    println!(
        "parabola, {ENERGY_STEPS} steps of 1/60 s: rattle4 energy error {:.3e} of E_scale \
         (first tenth {first:.3e}, last {last:.3e}), max |C| {worst_c:.3e}; rattle {rattle:.3e}; \
         rattle at dt/5 {rattle_equal_work:.3e}",
        stats.energy_rel_error_max
    );
    assert_eq!(stats.steps, ENERGY_STEPS);
    assert!(worst_c <= tolerance, "{worst_c:e}");
    assert!(stats.constraint_error_max <= tolerance);
    assert!(stats.energy_rel_error_max <= 1e-5);
    assert!(
        last <= 2.0 * first,
        "energy drifts: {first:e} then {last:e}"
    );
    assert!(rattle > 1e-3, "{rattle:e}");
    assert!(
        stats.energy_rel_error_max * 10.0 <= rattle_equal_work,
        "{:e} vs {rattle_equal_work:e}",
        stats.energy_rel_error_max
    );
}

/// Law: the construction matters (why rattle4 is Suzuki's five stages): Yoshida's triple
/// jump (g, 1 - 2g, g with g = 1 / (2 - 2^(1/3)), a middle stage of -1.70 dt) is of order 4
/// too, but its error constant is larger: on the parabola at dt = 1/60 over 10^5 steps its
/// energy error is 8.4e-5 of E0 against Suzuki's 3.6e-6, both composed from the same
/// RATTLE and stepped the same way.
#[test]
fn the_triple_jump_is_24x_less_accurate_than_suzukis_five_stages() {
    use bead::integrate::{suzuki_weights, triple_jump_weights, Composition};
    let system = parabola();
    let energy_error = |weights: &[f64]| {
        let mut formulation = Implicit::new(system.clone(), Feedback::default());
        let (q, qdot) = system.initial_particle_state();
        let mut state = State { t: 0.0, q, qdot };
        let e0 = system.energy(&state.q, &state.qdot);
        let rattle = Rattle::new(2, 1e-12 * PARABOLA_LENGTH * PARABOLA_LENGTH, 50);
        let mut composed = Composition::with_weights(rattle, weights);
        let mut worst = 0.0_f64;
        for _ in 0..ENERGY_STEPS {
            composed
                .step(&mut formulation, &mut state, 1.0 / 60.0)
                .unwrap();
            worst = worst.max((system.energy(&state.q, &state.qdot) - e0).abs() / e0.abs());
        }
        worst
    };
    let (suzuki, triple) = (
        energy_error(&suzuki_weights()),
        energy_error(&triple_jump_weights()),
    );
    println!(
        "parabola, {ENERGY_STEPS} steps of 1/60 s: suzuki {suzuki:.3e}, triple jump {triple:.3e}"
    );
    assert!((3.0e-6..4.0e-6).contains(&suzuki), "{suzuki:e}");
    assert!((7.0e-5..1.0e-4).contains(&triple), "{triple:e}");
    assert!(triple > 20.0 * suzuki);
}

// ---------------------------------------------------------------------------------------
// projections

/// Law: the position projection (mass-weighted Gauss-Newton) lands on C = 0 within its
/// tolerance, and the velocity projection makes J v + C_t = 0 while changing v only along
/// W J^T (the kinetic-energy-orthogonal complement of the allowed velocities): the change
/// dv satisfies dv = W J^T z for a scalar z, i.e. M dv is parallel to J.
#[test]
fn projections_land_on_the_constraints() {
    let system = moving_circle();
    let mut formulation = Implicit::new(system.clone(), Feedback::default());
    let t = 0.4;
    let mut q = vec![1.7, -0.4];
    let iterations = formulation.project_positions(t, &mut q, 1e-13, 20).unwrap();
    let mut c = [0.0];
    formulation.constraint_values(t, &q, &mut c);
    assert!(c[0].abs() <= 1e-13, "{c:?} after {iterations} iterations");
    assert!((1..=8).contains(&iterations), "{iterations}");

    let v0 = [0.8, 1.1];
    let mut v = v0.to_vec();
    formulation.project_velocities(t, &q, &mut v).unwrap();
    let set = system.constraints();
    let mut ws = set.workspace();
    set.evaluate(t, &q, &v, &mut ws);
    assert!(
        ws.velocity[0].abs() < 1e-13,
        "J v + C_t = {}",
        ws.velocity[0]
    );
    // M dv parallel to J: cross product vanishes.
    let mut jacobian = [0.0; 2];
    formulation.constraint_jacobian(t, &q, &mut jacobian);
    let mass = 1.5;
    let (dv0, dv1) = (mass * (v[0] - v0[0]), mass * (v[1] - v0[1]));
    let cross = dv0 * jacobian[1] - dv1 * jacobian[0];
    assert!(cross.abs() < 1e-12, "{cross}");
    assert!(formulation.n_constraints() == 1 && formulation.inverse_mass() == [1.0 / mass; 2]);
}

// ---------------------------------------------------------------------------------------
// errors

/// Law: RATTLE needs constraints to project onto; on the parametric form (none) the
/// simulation refuses to start with a message naming the fix, and a bare step reports the
/// same need.
#[test]
fn rattle_on_the_parametric_form_is_a_clear_error() {
    let system = parabola();
    let config = SimulationConfig {
        method: Method::Parametric,
        integrator: IntegratorKind::Rattle,
        dt: 0.01,
        ..Default::default()
    };
    let error = Simulation::new(system.clone(), config).unwrap_err();
    assert_eq!(
        error,
        SetupError::Config(ConfigError::NeedsConstraints(Requirement::Integrator(
            IntegratorKind::Rattle
        )))
    );
    assert_eq!(
        error.to_string(),
        "rattle needs the implicit form: the parametric form has no constraints to project onto (it stays on them by construction); use gauss-legendre or rk4 with the parametric form"
    );

    let mut parametric = Parametric::new(system.clone()).unwrap();
    assert!(parametric.as_constrained().is_none());
    let mut state = bead::formulation::Formulation::initial_state(&parametric);
    let err = Rattle::new(1, 1e-10, 10)
        .step(&mut parametric, &mut state, 0.01)
        .unwrap_err();
    assert!(matches!(err, StepError::NeedsConstraints { .. }), "{err}");

    let config = SimulationConfig {
        method: Method::Parametric,
        integrator: IntegratorKind::Rk4,
        dt: 0.01,
        project: true,
        ..Default::default()
    };
    let error = Simulation::new(system, config).unwrap_err();
    assert_eq!(
        error,
        SetupError::Config(ConfigError::NeedsConstraints(Requirement::Projection))
    );
    assert!(
        error.to_string().contains("needs the implicit form"),
        "{error}"
    );
}

/// Law: a constraint solve that does not reach its tolerance is an error naming the time,
/// the iterations and the residual, never a silent continuation: RATTLE and --project with
/// max_iterations = 0 off the constraint, and a projection onto an empty set
/// (x^2 + y^2 + 1 = 0 has no real point).
#[test]
fn projection_failure_is_reported() {
    // The pendulum starts on its rod, but one step's predictor leaves it.
    let system = pendulum();
    let mut o = options(IntegratorKind::Rattle, 0.01, 10);
    o.settings.constraint_max_iterations = 0;
    o.settings.constraint_tolerance = 1e-14;
    // With retries, the step is tried in 2, 3, 5, ..., 64 substeps first; the failure is the
    // first substep's of the last try.
    let formulation = formulate(system.clone(), Method::Implicit, Feedback::default()).unwrap();
    let failure = run(formulation, &o, &mut NullSink).unwrap_err();
    match &failure.error {
        RunError::Step(StepError::ProjectionFailed { t, substeps, .. }) => {
            assert_eq!((*t, *substeps), (0.01 / 64.0, 64))
        }
        other => panic!("expected ProjectionFailed, got {other}"),
    }
    assert!(failure
        .error
        .to_string()
        .contains("rattle's solve for the constraint forces did not converge: max |C| = "));
    assert!(failure.error.to_string().ends_with(
        " in 64 substeps of the step, the most allowed (raise max_substeps, `--max-substeps`, or reduce dt)"
    ), "{}", failure.error);
    assert_eq!(failure.stats.steps, 0);
    o.max_substeps = 1;
    let formulation = formulate(system.clone(), Method::Implicit, Feedback::default()).unwrap();
    let failure = run(formulation, &o, &mut NullSink).unwrap_err();
    match &failure.error {
        RunError::Step(StepError::ProjectionFailed {
            t,
            iterations,
            residual,
            substeps,
            ..
        }) => {
            assert_eq!((*t, *iterations, *substeps), (0.01, 0, 1));
            assert!(*residual > 1e-14);
        }
        other => panic!("expected ProjectionFailed, got {other}"),
    }
    assert!(failure
        .error
        .to_string()
        .contains("rattle's solve for the constraint forces did not converge: max |C| = "));
    assert!(failure.error.to_string().ends_with(
        " in a step without substeps (allow substeps with max_substeps, `--max-substeps`, or reduce dt)"
    ), "{}", failure.error);
    assert_eq!(failure.stats.steps, 0);

    // Retries off: shorter substeps leave the rod by less and may need no iteration at all.
    let mut o = options(IntegratorKind::Rk4, 0.01, 10);
    o.project = true;
    o.max_substeps = 1;
    o.settings.constraint_max_iterations = 0;
    o.settings.constraint_tolerance = 1e-14;
    let formulation = formulate(system.clone(), Method::Implicit, Feedback::default()).unwrap();
    let failure = run(formulation, &o, &mut NullSink).unwrap_err();
    assert!(
        matches!(
            failure.error,
            RunError::Step(StepError::ProjectionFailed { iterations: 0, .. })
        ),
        "{}",
        failure.error
    );
    assert!(failure
        .error
        .to_string()
        .contains(": the projection onto the constraints did not converge: max |C| = "));

    let mut b = SystemBuilder::new(&[0.0, 0.0]);
    b.particle("bead", 1.0, &[0.5, 0.5], &[0.0, 0.0]).unwrap();
    b.constraint_expr("bead.x^2 + bead.y^2 + 1").unwrap();
    let mut impossible = Implicit::new(Arc::new(b.build().unwrap()), Feedback::default());
    let mut q = vec![0.5, 0.5];
    let err = impossible
        .project_positions(0.0, &mut q, 1e-12, 30)
        .unwrap_err();
    println!("projection onto an empty set: {err}");
    assert!(
        matches!(
            err,
            StepError::ProjectionFailed { .. } | StepError::SingularConstraints { .. }
        ),
        "{err}"
    );
}

/// A unit mass at (1, 0) moving at `velocity` on a unit rod from the origin, no gravity, its
/// initial state, and RATTLE to 1e-12 in at most 50 iterations.
fn bob_on_a_rod(velocity: [f64; 2]) -> (Implicit, State, Rattle) {
    let mut b = SystemBuilder::new(&[0.0, 0.0]);
    let p = b.particle("bob", 1.0, &[1.0, 0.0], &velocity).unwrap();
    b.distance("rod", p, Endpoint::Fixed(vec![0.0, 0.0]), 1.0)
        .unwrap();
    let formulation = Implicit::new(Arc::new(b.build().unwrap()), Feedback::default());
    let state = bead::formulation::Formulation::initial_state(&formulation);
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        constraint_max_iterations: 50,
        ..IntegratorSettings::default()
    };
    (formulation, state, Rattle::with_settings(2, &settings))
}

/// A step whose SHAKE equation has no solution is given up in a few iterations, not after
/// all of them: a unit rod from the origin to a unit mass at (1, 0) moving at (0, 1000),
/// dt = 0.01. The predictor is (1, 10) and the correction runs along the rod's old direction
/// (1, 0): q(nu) = (1 - nu, 10) is never at distance 1 from the origin (C(nu) >= 49.5), so
/// the fused exact Newton iteration cannot halve its residual and stops after 6 iterations
/// without progress.
#[test]
fn a_step_without_a_solution_is_given_up_early() {
    let (mut formulation, mut state, mut rattle) = bob_on_a_rod([0.0, 1000.0]);
    let error = rattle.step(&mut formulation, &mut state, 0.01).unwrap_err();
    assert!(
        rattle.fused_rods(),
        "a rod to a fixed point is a path of rods"
    );
    match error {
        StepError::ProjectionFailed {
            iterations,
            residual,
            ..
        } => {
            assert!(iterations <= 8, "{iterations} iterations");
            assert!(residual >= 49.5 * (1.0 - 1e-12), "residual {residual}");
        }
        other => panic!("expected ProjectionFailed, got {other}"),
    }
}

/// One `Rattle` handed two chains with the same rows but rods of other lengths keeps each
/// chain's own: the fused path steps along each system's own rods, with buffers sized again
/// when the rows change (`row_fingerprint`).
#[test]
fn one_rattle_on_two_chains_keeps_each_ones_lengths() {
    let chain = |length: f64| {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        let mut previous = None;
        for k in 0..5 {
            let position = [(k + 1) as f64 * length, 0.0];
            let p = b
                .particle(&format!("p{k}"), 1.0, &position, &[0.0, 0.0])
                .unwrap();
            let end = previous.map_or(Endpoint::Fixed(vec![0.0, 0.0]), Endpoint::Particle);
            b.distance(&format!("rod {k}"), p, end, length).unwrap();
            previous = Some(p);
        }
        Arc::new(b.build().unwrap())
    };
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-13,
        ..IntegratorSettings::default()
    };
    let mut rattle = Rattle::with_settings(10, &settings);
    for length in [1.0, 1.5] {
        let mut formulation = Implicit::new(chain(length), Feedback::default());
        let mut state = bead::formulation::Formulation::initial_state(&formulation);
        for _ in 0..20 {
            rattle
                .step(&mut formulation, &mut state, 1.0 / 120.0)
                .unwrap();
        }
        assert!(rattle.fused_rods());
        let mut before = [0.0, 0.0];
        for p in state.q.chunks_exact(2) {
            let d = ((p[0] - before[0]).powi(2) + (p[1] - before[1]).powi(2)).sqrt();
            assert!((d - length).abs() < 1e-12, "a rod of {length} at {d}");
            before = [p[0], p[1]];
        }
    }
}

// ---------------------------------------------------------------------------------------
// acceptance (release, `cargo test --release -- --ignored`)

/// The acceptance figures, 10^6 steps of the article's parabola at dt = 1/60:
/// RATTLE keeps max |C| <= 1e-9 L^2 (L = 150) and its energy bounded (last tenth's max
/// relative error within 2x of the first tenth's); rattle4 keeps |C| at its tolerance and
/// its energy bounded and within 1e-5 of E_scale; rk4 + --project keeps max |C| <= 1e-9 L^2.
#[test]
#[ignore = "10^6 steps: run in release with --ignored"]
fn acceptance_rattle_and_projection_1e6_steps() {
    const STEPS: u64 = 1_000_000;
    let started = std::time::Instant::now();
    let system = parabola();
    let scale = PARABOLA_LENGTH * PARABOLA_LENGTH;
    let o = with_tolerance(
        options(IntegratorKind::Rattle, 1.0 / 60.0, STEPS),
        1e-12 * scale,
    );
    let mut trace = Trace::new();
    let stats = run_implicit(&system, &o, &mut trace);
    let (first, last) = trace.energy_tenths();
    println!(
        "acceptance rattle: {STEPS} steps, max |C| = {:.3e} (bound {:.3e}), energy error max \
         first tenth {first:.4e}, last tenth {last:.4e}, overall {:.4e}, Newton iterations <= \
         {:?}, {:.3} s",
        stats.constraint_error_max,
        1e-9 * scale,
        stats.energy_rel_error_max,
        stats.newton_iterations_max,
        stats.wall_seconds
    );
    assert_eq!(stats.steps, STEPS);
    assert!(stats.constraint_error_max <= 1e-9 * scale);
    assert!(
        last <= 2.0 * first,
        "energy drifts: {first:e} then {last:e}"
    );

    // rattle4 (issue 20): bounded too, at 1e-5 of E_scale.
    let o = with_tolerance(
        options(IntegratorKind::Rattle4, 1.0 / 60.0, STEPS),
        1e-12 * scale,
    );
    let mut trace = Trace::new();
    let stats = run_implicit(&system, &o, &mut trace);
    let (first, last) = trace.energy_tenths();
    println!(
        "acceptance rattle4: {STEPS} steps, max |C| = {:.3e}, energy error max first tenth \
         {first:.4e}, last tenth {last:.4e}, of E_scale {:.4e}, {:.3} s",
        stats.constraint_error_max, stats.energy_rel_error_max, stats.wall_seconds
    );
    assert_eq!(stats.steps, STEPS);
    assert!(stats.constraint_error_max <= 1e-12 * scale);
    assert!(stats.energy_rel_error_max <= 1e-5);
    assert!(
        last <= 2.0 * first,
        "energy drifts: {first:e} then {last:e}"
    );

    let mut o = with_tolerance(
        options(IntegratorKind::Rk4, 1.0 / 60.0, STEPS),
        1e-12 * scale,
    );
    o.project = true;
    let stats = run_implicit(&system, &o, &mut NullSink);
    println!(
        "acceptance rk4 + project: {STEPS} steps, max |C| = {:.3e} (bound {:.3e}), energy error \
         max {:.4e}, final energy {:.6} (initial {}), projection iterations <= {:?}, {:.3} s",
        stats.constraint_error_max,
        1e-9 * scale,
        stats.energy_rel_error_max,
        stats.energy_final,
        stats.energy_initial,
        stats.newton_iterations_max,
        stats.wall_seconds
    );
    assert_eq!(stats.steps, STEPS);
    assert!(stats.constraint_error_max <= 1e-9 * scale);
    println!(
        "acceptance test total: {:.3} s",
        started.elapsed().as_secs_f64()
    );
}

/// A fused step whose rod turns by a right angle hands over to the simplified matrix, which
/// RATTLE builds then (not on the first step): a unit rod from the origin to a unit mass at
/// (1, 0) moving at (-100, 150), dt = 0.01, no gravity, so the predictor is (0, 1.5), where
/// the fused Newton matrix e(q^k).e(q_n) = 0 fails the pivot test. The simplified iteration
/// runs and fails (it moves along e(q_n) = (1, 0), and (-z, 1.5) is never on the rod: C
/// grows until it overflows): a projection failure, no panic; the same `Rattle` then steps a
/// state it can.
#[test]
fn a_fused_step_that_turns_a_rod_over_hands_over_to_the_simplified_matrix() {
    let (mut formulation, mut state, mut rattle) = bob_on_a_rod([-100.0, 150.0]);
    let error = rattle.step(&mut formulation, &mut state, 0.01).unwrap_err();
    assert!(rattle.fused_rods());
    match error {
        // The simplified iteration's (the fused one took none): not the pivot's
        // `SingularConstraints`.
        StepError::ProjectionFailed { iterations, .. } => assert!(iterations > 0),
        other => panic!("expected ProjectionFailed, got {other}"),
    }
    // A slow turn: the fused path again, to the tolerance.
    let mut state = State {
        t: 0.0,
        q: vec![1.0, 0.0],
        qdot: vec![0.0, 1.0],
    };
    rattle.step(&mut formulation, &mut state, 0.01).unwrap();
    let stretch = (state.q[0].hypot(state.q[1]) - 1.0).abs();
    assert!(stretch < 1e-12, "stretch {stretch}");
}

// ---------------------------------------------------------------------------------------
// warm start

/// A chain of `n` unit masses on rods of length 1 hanging from the origin, released
/// horizontally at rest (its tip whips: the multipliers grow and turn fast).
fn hanging_chain(n: usize) -> Arc<System> {
    Arc::new(common::chain(n))
}

/// `system`'s implicit form with the per-row tolerance scales `Simulation` gives it, and its
/// initial state.
fn scaled_implicit(system: &Arc<System>) -> (Implicit, State) {
    let mut formulation = Implicit::new(system.clone(), Feedback::default());
    bead::formulation::Formulation::set_constraint_scales(
        &mut formulation,
        Some(bead::formulation::ConstraintScales::of(system)),
    );
    let (q, qdot) = system.initial_particle_state();
    (formulation, State { t: 0.0, q, qdot })
}

/// The warm start (the last step's multipliers scaled by (h / h_prev)^2 as the Newton
/// iteration's start) is a better first guess, not another method: warm and cold RATTLE end
/// on the same trajectory to the solver's tolerance, on every path of the position solve
/// (the rods fused along a chain, the dense exact matrix, the simplified matrix, and the
/// stages of rattle4, whose steps alternate in length and sign), and warm needs fewer
/// Newton iterations where a cold start needs more than two.
#[test]
fn warm_started_rattle_ends_where_cold_does_in_fewer_newton_iterations() {
    use bead::integrate::{Composition, NewtonMatrix};
    // Simulation's stopping rule: every row to 1e-12 of its scale, plus rounding.
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..IntegratorSettings::default()
    };
    let chain = hanging_chain(30);
    let pendulum = double_pendulum();
    type Build = fn(usize, &IntegratorSettings, bool) -> Box<dyn Integrator>;
    let rattle: Build = |n, s, warm| Box::new(Rattle::with_settings(n, s).with_warm_start(warm));
    let simplified: Build = |n, s, warm| {
        Box::new(
            Rattle::with_settings(n, s)
                .with_newton(NewtonMatrix::Simplified)
                .with_warm_start(warm),
        )
    };
    let rattle4: Build = |n, s, warm| {
        Box::new(Composition::suzuki(
            Rattle::with_settings(n, s).with_warm_start(warm),
        ))
    };
    let cases: [(&str, &Arc<System>, Build, f64); 5] = [
        ("chain, fused", &chain, rattle, 1.0 / 120.0),
        ("chain, simplified", &chain, simplified, 1.0 / 120.0),
        (
            "double pendulum, dense exact",
            &pendulum,
            rattle,
            1.0 / 240.0,
        ),
        (
            "double pendulum, simplified",
            &pendulum,
            simplified,
            1.0 / 240.0,
        ),
        ("chain, rattle4", &chain, rattle4, 1.0 / 120.0),
    ];
    for (name, system, build, dt) in cases {
        let n = system.n_coords();
        let steps = (1.0 / dt) as usize;
        let run = |warm| {
            let mut integrator = build(n, &settings, warm);
            let (mut formulation, mut state) = scaled_implicit(system);
            for _ in 0..steps {
                integrator.step(&mut formulation, &mut state, dt).unwrap();
            }
            state
        };
        let (warm, cold) = (run(true), run(false));
        let apart = warm
            .q
            .iter()
            .zip(&cold.q)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!("{name}: warm and cold {apart:.1e} apart after 1 s");
        assert!(apart > 0.0, "{name}: the warm start changed nothing");
        assert!(apart < 1e-10, "{name}: warm and cold {apart:e} apart");
    }
    // Fewer iterations over 3 s (RATTLE counts every step's), where a cold start needs more
    // than two: a long chain whose rods turn fast, the simplified matrix's linear
    // convergence, the double pendulum at dt = 1/60.
    let (long_chain, chain_100) = (hanging_chain(1000), hanging_chain(100));
    for (name, system, newton, dt) in [
        (
            "chain of 1000, fused",
            &long_chain,
            NewtonMatrix::Auto,
            1.0 / 120.0,
        ),
        (
            "chain of 100, simplified",
            &chain_100,
            NewtonMatrix::Simplified,
            1.0 / 120.0,
        ),
        (
            "double pendulum, dense exact",
            &pendulum,
            NewtonMatrix::Auto,
            1.0 / 60.0,
        ),
    ] {
        let n = system.n_coords();
        let total = |warm| {
            let mut rattle = Rattle::with_settings(n, &settings)
                .with_newton(newton)
                .with_warm_start(warm);
            let (mut formulation, mut state) = scaled_implicit(system);
            let steps = (3.0 / dt) as usize;
            for _ in 0..steps {
                rattle.step(&mut formulation, &mut state, dt).unwrap();
            }
            rattle.newton_iterations_total() as f64 / steps as f64
        };
        let (warm, cold) = (total(true), total(false));
        println!("{name}: {warm:.2} Newton iterations per step warm, {cold:.2} cold");
        assert!(warm < 0.85 * cold, "{name}: {warm} warm, {cold} cold");
    }
}

/// The warm start holds only for a step from bitwise the state the last step ended at (or
/// that state as its driver retimed it, `Integrator::continued`): a step from any other
/// state (set from outside, an impulse applied, another time, retimed from another step's
/// end) has a fresh integrator's bits; a step of another length scales the last multipliers by (h / h_prev)^2
/// and ends on the constraints as a cold one does.
#[test]
fn a_warm_start_needs_the_state_the_last_step_ended_at() {
    // Simulation's stopping rule: every row to 1e-12 of its scale, plus rounding.
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..IntegratorSettings::default()
    };
    let system = hanging_chain(20);
    let n = system.n_coords();
    let dt = 1.0 / 120.0;
    let (mut formulation, mut state) = scaled_implicit(&system);
    let mut warm = Rattle::with_settings(n, &settings);
    for _ in 0..60 {
        warm.step(&mut formulation, &mut state, dt).unwrap();
    }
    // From a state of its own ending, warm differs from a fresh (cold) first step.
    let fresh_step = |from: &State, h: f64| {
        let mut fresh = Rattle::with_settings(n, &settings);
        let (mut formulation, _) = scaled_implicit(&system);
        let mut s = from.clone();
        fresh.step(&mut formulation, &mut s, h).unwrap();
        s
    };
    let mut continued = state.clone();
    warm.step(&mut formulation, &mut continued, dt).unwrap();
    assert_ne!(continued.q, fresh_step(&state, dt).q, "no warm start");
    // The other starts: cold, a fresh integrator's bits. Each integrator first ends a step
    // of its own at `ended`, then steps from a state beside it.
    type Perturbation = fn(&mut State);
    let perturbations: [(&str, Perturbation); 4] = [
        ("kicked", |s| s.qdot[7] += 1e-3),
        ("moved", |s| s.q[4] = f64::from_bits(s.q[4].to_bits() + 1)),
        ("later", |s| s.t += 1e-9),
        // Retimed by a driver that names another step's end: not this one's continuation.
        ("retimed from elsewhere", |s| s.t += 1e-9),
    ];
    for (what, perturb) in perturbations {
        let mut other = Rattle::with_settings(n, &settings);
        let mut ended = state.clone();
        other.step(&mut formulation, &mut ended, dt).unwrap();
        if what == "retimed from elsewhere" {
            let mut retimed = ended.clone();
            perturb(&mut retimed);
            other.continued(ended.t + 1e-6, &retimed, false);
        }
        // The control: from `ended` itself the step is warm, not a fresh one.
        let mut control = Rattle::with_settings(n, &settings);
        let mut own = state.clone();
        control.step(&mut formulation, &mut own, dt).unwrap();
        control.step(&mut formulation, &mut own, dt).unwrap();
        assert_ne!(own.q, fresh_step(&ended, dt).q, "{what}: no warm start");
        let mut from = ended.clone();
        perturb(&mut from);
        let mut s = from.clone();
        other.step(&mut formulation, &mut s, dt).unwrap();
        let fresh = fresh_step(&from, dt);
        assert_eq!(s.q, fresh.q, "{what}: positions are not a cold start's");
        assert_eq!(
            s.qdot, fresh.qdot,
            "{what}: velocities are not a cold start's"
        );
    }
    // A driver's own retiming of the state (`continued` with this step's end) keeps it warm.
    let mut retimed_by_driver = Rattle::with_settings(n, &settings);
    let mut ended = state.clone();
    retimed_by_driver
        .step(&mut formulation, &mut ended, dt)
        .unwrap();
    let stepped = ended.t;
    ended.t += 1e-9;
    retimed_by_driver.continued(stepped, &ended, false);
    let mut s = ended.clone();
    retimed_by_driver
        .step(&mut formulation, &mut s, dt)
        .unwrap();
    assert_ne!(s.q, fresh_step(&ended, dt).q, "retimed: no warm start");
    // Half the step from the continued state: scaled warm start, on the constraints, fewer
    // iterations than cold.
    let mut half = continued.clone();
    let before = warm.newton_iterations_total();
    warm.step(&mut formulation, &mut half, 0.5 * dt).unwrap();
    let warm_iterations = warm.newton_iterations_total() - before;
    let mut cold = Rattle::with_settings(n, &settings);
    let mut half_cold = continued.clone();
    cold.step(&mut formulation, &mut half_cold, 0.5 * dt)
        .unwrap();
    let cold_iterations = cold.newton_iterations_total();
    assert!(
        warm_iterations < cold_iterations,
        "half step: {warm_iterations} warm, {cold_iterations} cold"
    );
    let apart = half
        .q
        .iter()
        .zip(&half_cold.q)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(apart < 1e-11, "half step: warm and cold {apart:e} apart");
}

/// The README's claim for the article's parabola at dt = 1/60 over its 10 minutes (and
/// twice that): RATTLE needs at most 2 Newton iterations a step when it starts from the last
/// step's multipliers, and 3 from zero, with `Simulation`'s stopping rule.
#[test]
fn the_parabola_takes_at_most_2_newton_iterations_a_step_warm_and_3_cold() {
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..IntegratorSettings::default()
    };
    let system = parabola();
    let dt = 1.0 / 60.0;
    let most = |warm: bool| {
        let mut rattle = Rattle::with_settings(system.n_coords(), &settings).with_warm_start(warm);
        let (mut formulation, mut state) = scaled_implicit(&system);
        let mut most_in_600_s = 0;
        for step in 1..=72_000 {
            rattle.step(&mut formulation, &mut state, dt).unwrap();
            if step == 36_000 {
                most_in_600_s = rattle.newton_iterations_max().unwrap();
            }
        }
        (most_in_600_s, rattle.newton_iterations_max().unwrap())
    };
    assert_eq!(most(true), (2, 2), "warm");
    assert_eq!(most(false), (3, 3), "cold");
}

/// A simulation's substeps and rattle4's stages start on a grid (t0 + k h, t0 + c_i dt),
/// which differs from the last step's own t + h in the last bit for about one step in
/// eight; the integrator's warm start goes along ([`Integrator::continued`]). The chain's
/// equations do not read t, so every step is the same as RATTLE's stages stepped alone with
/// the time they leave (every one warm): the same Newton iterations and the same bits, at 2
/// substeps of a frame in `Simulation` and for rattle4's five stages. Without a warm start
/// it takes 1.4x the iterations; without the retiming 1.8% more in `Simulation` and 8% more
/// in rattle4.
#[test]
fn steps_on_a_grid_keep_the_warm_start() {
    use bead::integrate::suzuki_weights;
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..IntegratorSettings::default()
    };
    let system = hanging_chain(1000);
    let n = system.n_coords();
    for (kind, frame) in [
        (IntegratorKind::Rattle, 1.0 / 60.0),
        (IntegratorKind::Rattle4, 1.0 / 30.0),
    ] {
        let frames = (3.0 / frame) as usize;
        let config = SimulationConfig {
            method: Method::Implicit,
            integrator: kind,
            dt: frame,
            substeps: 2,
            max_substeps: 2,
            ..SimulationConfig::default()
        };
        let mut sim = Simulation::new(system.clone(), config).unwrap();
        for _ in 0..frames {
            sim.step().unwrap();
        }
        let simulated = sim.newton_iterations_total().unwrap();
        // The stages alone, at the times they leave.
        let stages: &[f64] = match kind {
            IntegratorKind::Rattle => &[1.0],
            _ => &suzuki_weights(),
        };
        let alone = |warm: bool| {
            let mut rattle = Rattle::with_settings(n, &settings).with_warm_start(warm);
            let (mut formulation, mut state) = scaled_implicit(&system);
            for k in 0..frames {
                // Simulation's substeps: the frame on its grid, in halves.
                let h = ((k + 1) as f64 * frame - k as f64 * frame) / 2.0;
                for _ in 0..2 {
                    for weight in stages {
                        rattle
                            .step(&mut formulation, &mut state, weight * h)
                            .unwrap();
                    }
                }
            }
            (rattle.newton_iterations_total(), state)
        };
        let ((warm, stepped), (cold, _)) = (alone(true), alone(false));
        println!(
            "{}: {simulated} Newton iterations in Simulation, {warm} stepped alone warm, \
             {cold} cold",
            kind.name()
        );
        assert!(
            cold as f64 > 1.25 * warm as f64,
            "{}: {cold} cold, {warm} warm",
            kind.name()
        );
        assert_eq!(simulated, warm, "{}: Newton iterations", kind.name());
        assert_eq!(
            sim.positions(),
            &stepped.q[..],
            "{}: positions",
            kind.name()
        );
    }
}
