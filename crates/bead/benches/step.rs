//! One RK4 step of the article's bead on the parabola x^2 + 100 y = 0 (+y down, g = 500),
//! through the engine and by hand:
//!
//! - engine, scene loaded from TOML text (`Scene::parse`): implicit form (the constraint as an
//!   expression, compiled to a tape) and parametric form (x = (q, -q^2/100));
//! - engine, system built in Rust with the constraint as a `Holonomic` type: traced into an
//!   expression when the system is built (`SystemBuilder::holonomic`, then the TOML path), and
//!   by dual numbers at every evaluation (`SystemBuilder::holonomic_by_dual_numbers`);
//! - hand-written closed forms, the floor: RK4 on (x, y, vx, vy) with the article's constraint
//!   force Fc.y = (-50 m vx^2 - 2500 Fy) / (x^2 + 2500), Fc.x = Fc.y x / 50 (gravity only, so
//!   Fx = 0), and RK4 on (q, qdot) with qddot = (-q qdot^2 - 50 g q) / (2500 + q^2).
//!
//! In the criterion groups and the first table every step starts from the same state (a copy
//! of the state, done on both sides), so that the implicit form's drift cannot change what is
//! measured, and the processor may overlap one step with the next: how much work a step is.
//! The second table takes steps along trajectories, each from the last one's end, as a run
//! does: how long a step takes when it waits for the one before. Both tables of
//! engine/hand-written ratios are measured with plain `Instant` loops.

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bead::formulation::{Feedback, Formulation, Implicit, Parametric, State};
use bead::integrate::{Integrator, IntegratorKind};
use bead::model::{Holonomic, ParticleId, System, SystemBuilder};
use bead::scene::Scene;
use bead::Scalar;
use criterion::Criterion;

const M: f64 = 1.0;
const G: f64 = 500.0;
const DT: f64 = 1.0 / 60.0;
/// A state on the parabola, moving: x = 120, y = -144, v = vx (1, -2x/100).
const X0: f64 = 120.0;
const VX0: f64 = -250.0;

const SCENE: &str = r#"
title = "The article's bead on a parabola"

[params]
g = 500.0

[world]
gravity = [0.0, "g"]

[[particle]]
name = "bead"
mass = 1.0
position = [120.0, -144.0]
velocity = [-250.0, 600.0]

[[constraint]]
expr = "bead.x^2 + 100*bead.y"

[parametric]
coordinates = ["q"]
initial = [120.0]
rates = [-250.0]

[parametric.positions]
bead = ["q", "-q^2/100"]
"#;

/// The article's parabola as a Rust type.
struct Parabola(ParticleId);

impl Holonomic for Parabola {
    fn particles(&self) -> Vec<ParticleId> {
        vec![self.0]
    }
    fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
        x[0] * x[0] + x[1] * 100.0
    }
}

fn scene_system() -> Arc<System> {
    Scene::parse(SCENE, "parabola.toml", &[])
        .unwrap_or_else(|e| panic!("{e}"))
        .system
}

fn holonomic_system(traced: bool) -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let bead = b
        .particle(
            "bead",
            M,
            &[X0, -X0 * X0 / 100.0],
            &[VX0, -2.0 * X0 * VX0 / 100.0],
        )
        .unwrap();
    if traced {
        b.holonomic("parabola", Parabola(bead));
    } else {
        b.holonomic_by_dual_numbers("parabola", Parabola(bead));
    }
    Arc::new(b.build().unwrap())
}

/// An engine formulation with its RK4 and a fixed start state.
struct EngineStep<F: Formulation> {
    formulation: F,
    integrator: Box<dyn Integrator>,
    start: State,
    state: State,
}

impl<F: Formulation> EngineStep<F> {
    fn new(formulation: F) -> Self {
        Self::with(formulation, IntegratorKind::Rk4)
    }
    fn with(formulation: F, kind: IntegratorKind) -> Self {
        let start = formulation.initial_state();
        let integrator = kind.build(start.q.len());
        EngineStep {
            formulation,
            integrator,
            state: start.clone(),
            start,
        }
    }
    fn step(&mut self) -> f64 {
        self.restart();
        self.advance()
    }
    /// Back to the start state.
    fn restart(&mut self) {
        self.state.t = self.start.t;
        self.state.q.copy_from_slice(&self.start.q);
        self.state.qdot.copy_from_slice(&self.start.qdot);
    }
    /// One step from where the last one ended.
    fn advance(&mut self) -> f64 {
        self.integrator
            .step(&mut self.formulation, &mut self.state, black_box(DT))
            .unwrap();
        self.state.q[0]
    }
}

/// The article's implicit equations by hand: a = (F + Fc)/m with F = (0, m g).
#[inline(always)]
fn article_implicit_acceleration(s: [f64; 4]) -> [f64; 2] {
    let [x, _y, vx, _vy] = s;
    let fy = M * G;
    let fcy = (-50.0 * M * vx * vx - 2500.0 * fy) / (x * x + 2500.0);
    let fcx = fcy * x / 50.0;
    [fcx / M, (fy + fcy) / M]
}

/// Classic RK4 on (x, y, vx, vy).
#[inline(never)]
fn hand_implicit_rk4(s: [f64; 4], dt: f64) -> [f64; 4] {
    let f = |s: [f64; 4]| {
        let a = article_implicit_acceleration(s);
        [s[2], s[3], a[0], a[1]]
    };
    let add = |s: [f64; 4], h: f64, k: [f64; 4]| {
        [
            s[0] + h * k[0],
            s[1] + h * k[1],
            s[2] + h * k[2],
            s[3] + h * k[3],
        ]
    };
    let k1 = f(s);
    let k2 = f(add(s, 0.5 * dt, k1));
    let k3 = f(add(s, 0.5 * dt, k2));
    let k4 = f(add(s, dt, k3));
    let h = dt / 6.0;
    std::array::from_fn(|i| s[i] + h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
}

/// Classic RK4 on (q, qdot) with the article's qddot.
#[inline(never)]
fn hand_parametric_rk4(s: [f64; 2], dt: f64) -> [f64; 2] {
    let f = |[q, qd]: [f64; 2]| [qd, (-q * qd * qd - 50.0 * G * q) / (2500.0 + q * q)];
    let add = |s: [f64; 2], h: f64, k: [f64; 2]| [s[0] + h * k[0], s[1] + h * k[1]];
    let k1 = f(s);
    let k2 = f(add(s, 0.5 * dt, k1));
    let k3 = f(add(s, 0.5 * dt, k2));
    let k4 = f(add(s, dt, k3));
    let h = dt / 6.0;
    [
        s[0] + h * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
        s[1] + h * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
    ]
}

const IMPLICIT_START: [f64; 4] = [X0, -X0 * X0 / 100.0, VX0, -2.0 * X0 * VX0 / 100.0];
const PARAMETRIC_START: [f64; 2] = [X0, VX0];

/// The benchmarked variants, each a closure doing one step from the fixed start state.
struct Variants {
    implicit_toml: EngineStep<Implicit>,
    parametric_toml: EngineStep<Parametric>,
    implicit_holonomic: EngineStep<Implicit>,
    implicit_holonomic_duals: EngineStep<Implicit>,
}

impl Variants {
    fn new() -> Self {
        let system = scene_system();
        let mut v = Variants {
            implicit_toml: EngineStep::new(Implicit::new(system.clone(), Feedback::default())),
            parametric_toml: EngineStep::new(Parametric::new(system).unwrap()),
            implicit_holonomic: EngineStep::new(Implicit::new(
                holonomic_system(true),
                Feedback::default(),
            )),
            implicit_holonomic_duals: EngineStep::new(Implicit::new(
                holonomic_system(false),
                Feedback::default(),
            )),
        };
        v.check_same_work();
        v
    }

    /// The engine and the hand-written steps compute the same thing (else the ratio would be
    /// meaningless): same start state, same result to rounding.
    fn check_same_work(&mut self) {
        let close = |got: &[f64], want: &[f64]| {
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (g - w).abs() <= 1e-9 * w.abs().max(1.0),
                    "engine {got:?} vs hand-written {want:?}"
                );
            }
        };
        let hand = hand_implicit_rk4(IMPLICIT_START, DT);
        for engine in [
            &mut self.implicit_toml,
            &mut self.implicit_holonomic,
            &mut self.implicit_holonomic_duals,
        ] {
            assert_eq!(
                [engine.start.q.as_slice(), &engine.start.qdot].concat(),
                IMPLICIT_START
            );
            engine.step();
            close(
                &[engine.state.q.as_slice(), &engine.state.qdot].concat(),
                &hand,
            );
        }
        let engine = &mut self.parametric_toml;
        assert_eq!([engine.start.q[0], engine.start.qdot[0]], PARAMETRIC_START);
        engine.step();
        close(
            &[engine.state.q[0], engine.state.qdot[0]],
            &hand_parametric_rk4(PARAMETRIC_START, DT),
        );
    }
}

fn bench_steps(c: &mut Criterion) {
    let mut v = Variants::new();
    let mut group = c.benchmark_group("rk4 step, article parabola");
    group.bench_function("implicit, engine from TOML", |b| {
        b.iter(|| black_box(v.implicit_toml.step()))
    });
    group.bench_function("implicit, engine with Holonomic type", |b| {
        b.iter(|| black_box(v.implicit_holonomic.step()))
    });
    group.bench_function("implicit, Holonomic type by dual numbers", |b| {
        b.iter(|| black_box(v.implicit_holonomic_duals.step()))
    });
    group.bench_function("implicit, hand-written", |b| {
        b.iter(|| black_box(hand_implicit_rk4(black_box(IMPLICIT_START), black_box(DT))))
    });
    group.bench_function("parametric, engine from TOML", |b| {
        b.iter(|| black_box(v.parametric_toml.step()))
    });
    group.bench_function("parametric, hand-written", |b| {
        b.iter(|| {
            black_box(hand_parametric_rk4(
                black_box(PARAMETRIC_START),
                black_box(DT),
            ))
        })
    });
    group.finish();
}

/// Mean time per call of `f` in ns, from plain `Instant` loops: the best of several rounds of
/// `n` calls (the minimum filters out interruptions).
fn mean_ns(n: u32, mut f: impl FnMut()) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..7 {
        let start = Instant::now();
        for _ in 0..n {
            f();
        }
        best = best.min(start.elapsed().as_secs_f64() * 1e9 / n as f64);
    }
    best
}

/// Steps along a trajectory run at a time: each step from the last one's end, as a run takes
/// them, so that a step waits for the one before; from the start state again every 60 steps
/// (one second), so that the implicit form's drift stays as small as in a run. The best of 7
/// rounds of n steps (restarts included: a copy of the start state on both sides), ns per
/// step. The hand-written steps' results pass from step to step through a `Cell`, and the
/// last is given to `black_box`.
fn trajectory_ns(n: u32, mut restart: impl FnMut(), mut advance: impl FnMut()) -> f64 {
    mean_ns((n / 60).max(1), || {
        restart();
        for _ in 0..60 {
            advance();
        }
    }) / 60.0
}

/// [`trajectory_ns`] of an engine's steps.
fn engine_trajectory_ns<F: Formulation>(engine: &mut EngineStep<F>, n: u32) -> f64 {
    let engine = std::cell::RefCell::new(engine);
    trajectory_ns(
        n,
        || engine.borrow_mut().restart(),
        || {
            black_box(engine.borrow_mut().advance());
        },
    )
}

/// A table of variants and their ns per step.
fn print_times(rows: &[(&str, f64)]) {
    println!("  {:<40} {:>10}", "variant", "ns/step");
    for (name, ns) in rows {
        println!("  {name:<40} {ns:>10.1}");
    }
}

/// Ratios engine / hand-written along trajectories (see [`trajectory_ns`]), printed as a
/// table: what a run's steps cost, where each waits for the last one's result, beside the
/// table of independent steps (which a processor overlaps, and which measures how much work
/// a step is).
fn print_trajectory_ratios(v: &mut Variants, n: u32) {
    let implicit_toml = engine_trajectory_ns(&mut v.implicit_toml, n);
    let implicit_holonomic = engine_trajectory_ns(&mut v.implicit_holonomic, n);
    let parametric_toml = engine_trajectory_ns(&mut v.parametric_toml, n);
    let implicit = std::cell::Cell::new(IMPLICIT_START);
    let hand_implicit = trajectory_ns(
        n,
        || implicit.set(black_box(IMPLICIT_START)),
        || implicit.set(hand_implicit_rk4(implicit.get(), black_box(DT))),
    );
    black_box(implicit.get());
    let parametric = std::cell::Cell::new(PARAMETRIC_START);
    let hand_parametric = trajectory_ns(
        n,
        || parametric.set(black_box(PARAMETRIC_START)),
        || parametric.set(hand_parametric_rk4(parametric.get(), black_box(DT))),
    );
    black_box(parametric.get());
    println!();
    println!("Along a trajectory (each step from the last one's end, 60 at a time):");
    print_times(&[
        ("implicit, engine from TOML", implicit_toml),
        ("implicit, engine with Holonomic type", implicit_holonomic),
        ("implicit, hand-written", hand_implicit),
        ("parametric, engine from TOML", parametric_toml),
        ("parametric, hand-written", hand_parametric),
    ]);
    println!();
    println!(
        "  implicit TOML / hand-written      = {:.2}x",
        implicit_toml / hand_implicit
    );
    println!(
        "  implicit Holonomic / hand-written = {:.2}x (traced)",
        implicit_holonomic / hand_implicit
    );
    println!(
        "  parametric TOML / hand-written    = {:.2}x",
        parametric_toml / hand_parametric
    );
}

/// Ratios engine / hand-written, printed as a table.
fn print_ratios(quick: bool) {
    let mut v = Variants::new();
    let n = if quick { 10 } else { 200_000 };
    let implicit_toml = mean_ns(n, || {
        black_box(v.implicit_toml.step());
    });
    let implicit_holonomic = mean_ns(n, || {
        black_box(v.implicit_holonomic.step());
    });
    let implicit_holonomic_duals = mean_ns(n, || {
        black_box(v.implicit_holonomic_duals.step());
    });
    let parametric_toml = mean_ns(n, || {
        black_box(v.parametric_toml.step());
    });
    let hand_implicit = mean_ns(n, || {
        black_box(hand_implicit_rk4(black_box(IMPLICIT_START), black_box(DT)));
    });
    let hand_parametric = mean_ns(n, || {
        black_box(hand_parametric_rk4(
            black_box(PARAMETRIC_START),
            black_box(DT),
        ));
    });
    println!();
    println!("One RK4 step of the article's parabola (best of 7 rounds of {n} steps):");
    print_times(&[
        ("implicit, engine from TOML", implicit_toml),
        ("implicit, engine with Holonomic type", implicit_holonomic),
        (
            "implicit, Holonomic type by dual numbers",
            implicit_holonomic_duals,
        ),
        ("implicit, hand-written", hand_implicit),
        ("parametric, engine from TOML", parametric_toml),
        ("parametric, hand-written", hand_parametric),
    ]);
    println!();
    println!(
        "  implicit TOML / hand-written      = {:.1}x",
        implicit_toml / hand_implicit
    );
    println!(
        "  implicit Holonomic / hand-written = {:.1}x (traced; {:.1}x by dual numbers)",
        implicit_holonomic / hand_implicit,
        implicit_holonomic_duals / hand_implicit
    );
    println!(
        "  parametric TOML / hand-written    = {:.1}x",
        parametric_toml / hand_parametric
    );
    print_trajectory_ratios(&mut v, n);
    // The constrained-symplectic methods on the same step of the implicit form (no
    // hand-written floor: their position solves iterate): RATTLE, and rattle4 (five RATTLE
    // steps per step, order 4), beside rk4.
    let system = scene_system();
    let mut rattle = EngineStep::with(
        Implicit::new(system.clone(), Feedback::default()),
        IntegratorKind::Rattle,
    );
    let mut rattle4 = EngineStep::with(
        Implicit::new(system, Feedback::default()),
        IntegratorKind::Rattle4,
    );
    let rattle_ns = mean_ns(n, || {
        black_box(rattle.step());
    });
    let rattle4_ns = mean_ns(n, || {
        black_box(rattle4.step());
    });
    println!();
    println!("  implicit, engine from TOML, rattle   {rattle_ns:>10.1} ns/step");
    println!("  implicit, engine from TOML, rattle4  {rattle4_ns:>10.1} ns/step");
    println!(
        "  rattle4 / rattle = {:.1}x (5 stages), rattle4 / rk4 = {:.1}x",
        rattle4_ns / rattle_ns,
        rattle4_ns / implicit_toml
    );
    println!(
        "  machine code: {}",
        if bead::expr::jit_enabled() {
            "on"
        } else {
            "off (BEAD_JIT=0)"
        }
    );
}

/// The machine code of every shipped scene as `bead check` reports it: tapes (the fused
/// accelerations' included), instructions and compile time, and the whole load's time, first
/// thing in the process (a scene whose tapes have the shape of an earlier one's reuses their
/// code and says so).
fn print_compile_times() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("scenes/")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    println!();
    println!("Machine code per shipped scene (as `bead check` prints it):");
    for path in files {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("?");
        let start = Instant::now();
        match Scene::load(&path, &[]) {
            Ok(scene) => {
                // The fused accelerations' tapes too (built on first use by a run).
                bead::formulation::prepare_fused_accelerations(&scene.system);
                let load = start.elapsed().as_secs_f64() * 1e3;
                println!(
                    "  {name:<24} {} (load in all {load:.1} ms)",
                    scene.system.machine_code()
                )
            }
            Err(e) => println!("  {name:<24} does not load: {e}"),
        }
    }
}

/// `BEAD_STEP_RATIOS=1`: the ratio table alone. `BEAD_STEP_ONLY=VARIANT BEAD_STEP_COUNT=N`: N steps of one variant and nothing else, for
/// instruction counts (`scripts/step-instructions` runs it under callgrind at two N and
/// divides the difference: instructions per step, free of setup and of the machine's load).
fn only(variant: &str, count: u64) {
    let mut v = Variants::new();
    let mut step: Box<dyn FnMut() -> f64> = match variant {
        "implicit_toml" => Box::new(|| v.implicit_toml.step()),
        "implicit_holonomic" => Box::new(|| v.implicit_holonomic.step()),
        "implicit_holonomic_duals" => Box::new(|| v.implicit_holonomic_duals.step()),
        "parametric_toml" => Box::new(|| v.parametric_toml.step()),
        "implicit_hand" => {
            Box::new(|| hand_implicit_rk4(black_box(IMPLICIT_START), black_box(DT))[0])
        }
        "parametric_hand" => {
            Box::new(|| hand_parametric_rk4(black_box(PARAMETRIC_START), black_box(DT))[0])
        }
        other => panic!("BEAD_STEP_ONLY={other}: not a variant"),
    };
    for _ in 0..count {
        black_box(step());
    }
}

fn main() {
    if let Ok(variant) = std::env::var("BEAD_STEP_ONLY") {
        let count = std::env::var("BEAD_STEP_COUNT").map_or(1000, |c| c.parse().unwrap());
        only(&variant, count);
        return;
    }
    if std::env::var_os("BEAD_STEP_RATIOS").is_some() {
        // The ratio table alone (the README's figures), without criterion's groups.
        print_ratios(false);
        return;
    }
    print_compile_times();
    // `cargo bench` passes --bench; without it (cargo test --benches) criterion runs each
    // benchmark once as a smoke test, and so does the ratio table.
    let benchmarking = std::env::args().any(|a| a == "--bench");
    let mut criterion = Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .sample_size(20)
        .configure_from_args();
    bench_steps(&mut criterion);
    criterion.final_summary();
    print_ratios(!benchmarking);
}
