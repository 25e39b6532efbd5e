//! The step loop allocates nothing.
//!
//! Property checked: after warm-up, `Integrator::step` of every integrator on both
//! formulations, and `simulate::run`'s loop with a `NullSink`, make no heap allocation, so
//! their cost per step is pure arithmetic (and a real-time caller may run them on a thread that
//! must not allocate). A counting global allocator wraps the system allocator.
//!
//! The counter is per thread: the test harness runs tests on several threads at once, and a
//! process-wide counter would see their allocations too. Each thread counts only while it has
//! switched counting on, and only its own calls.

// The workspace denies unsafe code and the library forbids it; this test alone needs
// `unsafe impl GlobalAlloc` to count allocations.
#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System as SystemAllocator};
use std::cell::Cell;
use std::sync::Arc;

use bead::formulation::{formulate, Feedback, Formulation, Implicit, Method, Parametric};
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, Force, Holonomic, ParticleId, System, SystemBuilder};
use bead::simulate::{NullSink, RunOptions};
use bead::Scalar;
use common::{run, Options};

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static CALLS: Cell<usize> = const { Cell::new(0) };
}

/// Counts allocator calls (alloc, alloc_zeroed, realloc, dealloc) of the threads that have
/// switched counting on. The thread-locals are const-initialized `Cell`s without destructors,
/// so touching them never allocates or registers anything.
struct CountingAllocator;

fn note_call() {
    let _ = COUNTING.try_with(|counting| {
        if counting.get() {
            let _ = CALLS.try_with(|calls| calls.set(calls.get() + 1));
        }
    });
}

// SAFETY: every method forwards to the system allocator with the caller's arguments unchanged;
// the counting touches only thread-local `Cell<usize>`/`Cell<bool>` values, which neither
// allocate nor unwind.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_call();
        // SAFETY: forwarded contract of GlobalAlloc::alloc.
        unsafe { SystemAllocator.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_call();
        // SAFETY: forwarded contract of GlobalAlloc::alloc_zeroed.
        unsafe { SystemAllocator.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_call();
        // SAFETY: forwarded contract of GlobalAlloc::realloc.
        unsafe { SystemAllocator.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note_call();
        // SAFETY: forwarded contract of GlobalAlloc::dealloc.
        unsafe { SystemAllocator.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// Allocator calls made by this thread while `f` runs.
fn allocator_calls<R>(f: impl FnOnce() -> R) -> (usize, R) {
    CALLS.with(|c| c.set(0));
    COUNTING.with(|c| c.set(true));
    let result = f();
    COUNTING.with(|c| c.set(false));
    (CALLS.with(|c| c.get()), result)
}

// The counter itself must see allocations, or every zero below would be vacuous.
#[test]
fn the_counter_sees_allocations() {
    let (calls, v) = allocator_calls(|| std::hint::black_box(vec![1.0f64; 16]));
    assert!(calls >= 1, "a Vec allocation was not counted");
    drop(v);
    let (calls, _) = allocator_calls(|| std::hint::black_box(3.0f64).sqrt());
    assert_eq!(calls, 0);
}

/// The article's parabola as a Rust type, for the dual-number path.
struct Parabola(ParticleId);

impl Holonomic for Parabola {
    fn particles(&self) -> Vec<ParticleId> {
        vec![self.0]
    }
    fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
        x[0] * x[0] + x[1] * 100.0
    }
}

/// The article's bead: expression constraint and parametric map, plus a spring and drag so
/// that every force kind is evaluated.
fn parabola() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 500.0]);
    let bead = b
        .particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0])
        .unwrap();
    b.force(Force::Constant {
        particle: bead,
        vector: vec![300.0, 0.0],
    })
    .unwrap();
    b.force(Force::Spring {
        a: bead,
        b: Endpoint::Fixed(vec![0.0, -50.0]),
        stiffness: 2.0,
        rest_length: 10.0,
    })
    .unwrap();
    b.force(Force::Drag {
        particle: None,
        coefficient: 0.01,
    })
    .unwrap();
    b.constraint_expr("bead.x^2 + 100*bead.y").unwrap();
    b.parametric(&["q"], &[150.0], &[0.0]).unwrap();
    b.parametric_position_exprs("bead", &["q", "-q^2/100"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// The same wire as a Rust `Holonomic` type (implicit form only), traced into an expression
/// or by dual numbers at every evaluation.
fn parabola_rust_type(traced: bool) -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 500.0]);
    let bead = b
        .particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0])
        .unwrap();
    if traced {
        b.holonomic("parabola", Parabola(bead));
    } else {
        b.holonomic_by_dual_numbers("parabola", Parabola(bead));
    }
    Arc::new(b.build().unwrap())
}

/// A double pendulum: two distance constraints (a 2 x 2 solve) and a two-angle map.
fn double_pendulum() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    let (s1, c1, s2, c2) = (0.9f64.sin(), 0.9f64.cos(), 0.3f64.sin(), 0.3f64.cos());
    let a = b.particle("a", 1.0, &[s1, c1], &[0.0, 0.0]).unwrap();
    let bob = b
        .particle("b", 2.0, &[s1 + s2, c1 + c2], &[0.0, 0.0])
        .unwrap();
    b.distance("upper", a, Endpoint::Fixed(vec![0.0, 0.0]), 1.0)
        .unwrap();
    b.distance("lower", bob, Endpoint::Particle(a), 1.0)
        .unwrap();
    b.parametric(&["u", "w"], &[0.9, 0.3], &[0.0, 0.0]).unwrap();
    b.parametric_position_exprs("a", &["sin(u)", "cos(u)"])
        .unwrap();
    b.parametric_position_exprs("b", &["sin(u) + sin(w)", "cos(u) + cos(w)"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// A chain of five links in angles on unit rods: rows of J with 1..5 nonzeros, columns with
/// 10..2.
fn chain() -> Arc<System> {
    let links = 5;
    let angles: [f64; 5] = [1.5, 1.2, 0.9, 0.6, 0.3];
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    let names: Vec<String> = (1..=links).map(|i| format!("th{i}")).collect();
    let (mut x, mut y, mut previous): (f64, f64, _) = (0.0, 0.0, None);
    for (i, th) in angles.iter().enumerate() {
        (x, y) = (x + th.sin(), y + th.cos());
        let p = b
            .particle(&format!("p{}", i + 1), 1.0, &[x, y], &[0.0, 0.0])
            .unwrap();
        let end = previous.map_or(Endpoint::Fixed(vec![0.0, 0.0]), Endpoint::Particle);
        b.distance(&format!("rod{}", i + 1), p, end, 1.0).unwrap();
        previous = Some(p);
    }
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    b.parametric(&refs, &angles, &[0.0; 5]).unwrap();
    for i in 1..=links {
        let sum = |f: &str| {
            names[..i]
                .iter()
                .map(|th| format!("{f}({th})"))
                .collect::<Vec<_>>()
                .join(" + ")
        };
        b.parametric_position_exprs(&format!("p{i}"), &[&sum("sin"), &sum("cos")])
            .unwrap();
    }
    Arc::new(b.build().unwrap())
}

const STEPS: usize = 1000;

/// Allocator calls during STEPS steps after one warm-up step.
fn calls_while_stepping<F: Formulation>(
    mut formulation: F,
    kind: IntegratorKind,
    dt: f64,
) -> usize {
    let mut state = formulation.initial_state();
    let mut integrator = kind.build(state.q.len());
    // What is built on first use is built by the first two steps: a small system's compiled
    // RK4 steps (the primed one on the first step, the unprimed one on the second).
    for _ in 0..2 {
        integrator.step(&mut formulation, &mut state, dt).unwrap();
    }
    let (calls, ()) = allocator_calls(|| {
        for _ in 0..STEPS {
            integrator.step(&mut formulation, &mut state, dt).unwrap();
        }
    });
    assert!(state.q.iter().all(|q| q.is_finite()));
    calls
}

#[test]
fn every_integrator_steps_the_implicit_form_without_allocating() {
    let systems = [
        ("parabola", parabola(), 1.0 / 600.0),
        ("Holonomic parabola", parabola_rust_type(true), 1.0 / 600.0),
        (
            "Holonomic parabola, duals",
            parabola_rust_type(false),
            1.0 / 600.0,
        ),
        ("double pendulum", double_pendulum(), 1e-3),
        // 40 rows: J W J^T by faer's sparse LDL^T (numeric factorization and solves in
        // buffers sized at construction).
        ("chain of 40", Arc::new(common::chain(40)), 1e-3),
    ];
    for (name, system, dt) in systems {
        for kind in IntegratorKind::ALL {
            let feedback = Feedback::from_frequency(2.0, 1.0);
            let calls = calls_while_stepping(Implicit::new(system.clone(), feedback), kind, dt);
            assert_eq!(
                calls,
                0,
                "implicit {name}, {}: {calls} allocator calls in {STEPS} steps",
                kind.name()
            );
        }
    }
}

#[test]
fn every_integrator_steps_the_parametric_form_without_allocating() {
    for (name, system, dt) in [
        ("parabola", parabola(), 1.0 / 600.0),
        ("double pendulum", double_pendulum(), 1e-3),
        ("chain", chain(), 1e-3),
    ] {
        // rattle needs the implicit form's constraints (an error on this form, tested in
        // physics_rattle.rs).
        for kind in IntegratorKind::ALL
            .into_iter()
            .filter(|k| !k.needs_constraints())
        {
            let calls = calls_while_stepping(Parametric::new(system.clone()).unwrap(), kind, dt);
            assert_eq!(
                calls,
                0,
                "parametric {name}, {}: {calls} allocator calls in {STEPS} steps",
                kind.name()
            );
        }
    }
}

/// Allocator calls a search for a singular point may make (a diagnostic, raised by the
/// monitor's first-order tests a few times per run at most: see `monitor.rs`).
const CALLS_PER_SEARCH: usize = 500;

/// (allocator calls, singular-point searches) of a 10-step and a 10000-step run: the same
/// calls, except that the singular-point monitor's searches, few (at most 10) and counted,
/// may allocate, far below one call per step.
fn assert_no_allocation_per_step(short: (usize, u64), long: (usize, u64), context: &str) {
    let ((short, short_searches), (long, long_searches)) = (short, long);
    let context = format!(
        "{context}: {short} allocator calls in 10 steps, {long} in 10000, with \
         {short_searches} and {long_searches} searches for singular points"
    );
    if long_searches == short_searches {
        assert_eq!(short, long, "{context}");
    } else {
        assert!(long_searches <= 10, "{context}");
        let allowed = (long_searches - short_searches) as usize * CALLS_PER_SEARCH;
        assert!(long - short <= allowed, "{context}");
    }
}

// run() allocates its buffers once (integrator, monitor, state copies, the final statistics);
// the loop itself must add nothing, so a 10-step and a 10000-step run make the same number of
// allocator calls, except for the singular-point monitor's searches: a drifting integrator
// (euler) may raise a few, each allocating; they are counted and bounded, far below one call
// per step.
#[test]
fn run_loop_allocation_count_does_not_depend_on_the_number_of_steps() {
    for (name, system, dt) in [
        ("parabola", parabola(), 1.0 / 600.0),
        ("double pendulum", double_pendulum(), 1e-4),
        ("chain", chain(), 1e-4),
    ] {
        for method in [Method::Implicit, Method::Parametric] {
            for kind in IntegratorKind::ALL {
                if method == Method::Parametric && kind.needs_constraints() {
                    continue;
                }
                let calls = |steps: u64| {
                    let formulation =
                        formulate(system.clone(), method, Feedback::default()).unwrap();
                    let options = Options {
                        integrator: kind,
                        dt,
                        steps,
                        every: 1,
                        ..Default::default()
                    };
                    let mut searches = 0;
                    let (calls, result) = allocator_calls(|| {
                        let mut simulation = common::simulation(formulation, &options);
                        let result = bead::simulate::run(
                            &mut simulation,
                            RunOptions::steps(steps),
                            &mut NullSink,
                        );
                        searches = simulation.singular_point_searches();
                        result
                    });
                    // Adaptive runs count their own steps; every run reaches the end.
                    assert_eq!(result.unwrap().t_final, steps as f64 * dt);
                    (calls, searches)
                };
                let context = format!("{name} {} {}", method.name(), kind.name());
                // A first run builds what the system keeps once built (its compiled RK4
                // step's tape); every run after it allocates the same.
                calls(10);
                assert_no_allocation_per_step(calls(10), calls(10_000), &context);
            }
        }
    }
}

// The projection after every step (--project) adds nothing per step either.
#[test]
fn run_loop_with_projection_allocates_nothing_per_step() {
    for (name, system, dt) in [
        ("parabola", parabola(), 1.0 / 600.0),
        ("double pendulum", double_pendulum(), 1e-4),
        ("chain of 40", Arc::new(common::chain(40)), 1e-4),
    ] {
        for kind in IntegratorKind::ALL.into_iter().filter(|k| !k.is_adaptive()) {
            let calls = |steps: u64| {
                let formulation =
                    formulate(system.clone(), Method::Implicit, Feedback::default()).unwrap();
                let options = Options {
                    integrator: kind,
                    dt,
                    steps,
                    every: 1,
                    project: true,
                    ..Default::default()
                };
                let (calls, result) = allocator_calls(|| run(formulation, &options, &mut NullSink));
                assert_eq!(result.unwrap().steps, steps);
                calls
            };
            let (short, long) = (calls(10), calls(10_000));
            assert_eq!(
                short,
                long,
                "{name} {} + project: {short} allocator calls in 10 steps, {long} in 10000",
                kind.name()
            );
        }
    }
}

// Watching a stop condition adds nothing per step either: its screen inside every step (the
// samples on the interpolant, dopri5's samples of its dense output) runs in buffers sized
// when it is set, so a run with one that never fires makes as many allocator calls in 10
// steps as in 10000.
#[test]
fn run_loop_with_a_stop_condition_allocates_nothing_per_step() {
    let system = parabola();
    for kind in IntegratorKind::ALL {
        for method in [Method::Implicit, Method::Parametric] {
            if method == Method::Parametric && kind.needs_constraints() {
                continue;
            }
            let calls = |steps: u64| {
                let formulation = formulate(system.clone(), method, Feedback::default()).unwrap();
                let options = Options {
                    integrator: kind,
                    dt: 1.0 / 600.0,
                    steps,
                    every: 1,
                    ..Default::default()
                };
                let mut simulation = common::simulation(formulation, &options);
                let event = bead::simulate::Event::parse(&system, "-1e9 - bead.x").unwrap();
                simulation.set_stop_when(Some(event)).unwrap();
                let run = bead::simulate::RunOptions::steps(steps);
                let (calls, result) =
                    allocator_calls(|| bead::simulate::run(&mut simulation, run, &mut NullSink));
                assert_eq!(result.unwrap().stop_time, None);
                (calls, simulation.singular_point_searches())
            };
            let context = format!("{} {} with a stop condition", method.name(), kind.name());
            assert_no_allocation_per_step(calls(10), calls(10_000), &context);
        }
    }
}
