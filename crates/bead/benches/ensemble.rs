//! The article's scene as an ensemble (issue 10, item 4): 10^4 beads on the parabola
//! x^2 + 100 y = 0, released at rest at x0 spread evenly over [10, 200), 1000 RK4 steps of
//! dt = 1/60 each, both formulations, through `bead::sweep` on every core, beside a
//! hand-written, vectorized RK4 of the same equations measured in the same run.
//!
//! The floor keeps the members in structure-of-arrays blocks of 512 (a block's state fits in
//! L1), steps each block 1000 times with its equations written out by hand, and splits the
//! blocks over the same number of threads as the sweep:
//!
//! ```text
//! implicit    lambda = (-2 vx^2 - 100 g) / (4 x^2 + 10^4),  a = (2 x lambda, g + 100 lambda)
//! parametric  qddot = -(g q / 50 + q qdot^2 / 2500) / (1 + q^2 / 2500)
//! ```
//!
//! (m = 1; C = x^2 + 100 y, J = (2x, 100), bias = 2 vx^2; x(q) = (q, -q^2/100),
//! M = 1 + (q/50)^2, Q = -g q / 50, h = (0, -qdot^2/50)). Before timing, both are checked to
//! agree on every member's final state (to 1e-7 of the swing: the same equations, rounded
//! differently), so that the two measure the same work. Prints particle-steps per second
//! through the sweep (members stepped in lanes), through the same sweep with each member
//! stepped alone (what the lanes gain; both give the same numbers, checked), and by hand,
//! with the floor's lead; the target is >= 1e8 particle-steps/s on 2 cores (within 4x of the
//! floor). All three run in the same process, so that the ratios hold on a loaded machine.
//!
//! Then the same ensemble through the Python package's `bead.sweep` beside a vectorized
//! numpy RK4 of the same equations, by CPU time (see [`beside_numpy`]).
//!
//! Then the cost of setting a member up, restarted from the scene's compiled equations (the
//! sweep's path for a release point) and loaded again from the scene's text.
//!
//! `cargo bench -p bead --bench ensemble` (`-- --members N` for another ensemble size,
//! `-- --setup-only` for the setup alone, `-- --restarted-only` for the restarted setup alone,
//! `-- --lanes-only` for the sweep through the lanes alone: what to profile; with
//! `-- --rounds N`, the best of N sweeps, which repeats within ~2% on a noisy machine where
//! single sweeps spread over 20%: what to compare builds with).

use std::hint::black_box;
use std::time::Instant;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::plan::PlanRequest;
use bead::scene::Scene;
use bead::sweep::{Axis, Combine, Member, Sweep};

/// The allocator of bead's front ends (`bead sweep`, `bead.sweep`), whose path this measures.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

const G: f64 = 500.0;
const DT: f64 = 1.0 / 60.0;
const STEPS: u64 = 1000;
const BLOCK: usize = 512;

/// The article's scene with the release point as a parameter.
const SCENE: &str = r#"
title = "Bead on a parabola, released at x0"
[params]
g = 500.0
x0 = 150.0
[world]
gravity = [0.0, "g"]
[[particle]]
name = "bead"
mass = 1.0
position = ["x0", "-x0^2/100"]
velocity = [0.0, 0.0]
[[constraint]]
expr = "bead.x^2 + 100*bead.y"
[parametric]
coordinates = ["q"]
initial = ["x0"]
rates = [0.0]
[parametric.positions]
bead = ["q", "-q^2/100"]
"#;

/// x0 for member i of n: evenly over [10, 200).
fn release_points(n: usize) -> Vec<f64> {
    (0..n).map(|i| 10.0 + 190.0 * i as f64 / n as f64).collect()
}

/// The sweep through the library: every member's scene loaded with its x0, its run planned
/// and stepped in lanes of members (`bead::simulate` lanes), on `threads` threads; with
/// `alone`, each member stepped by its own `Simulation` instead (`Sweep::run_member`, the
/// path of a single `bead run`), for the lanes' gain in the same run.
fn through_bead(method: Method, x0: &[f64], threads: usize, alone: bool) -> (f64, Vec<Member>) {
    let scene = Scene::parse(SCENE, "parabola-x0.toml", &[]).expect("the scene loads");
    let sweep = Sweep::new(
        &scene,
        vec![Axis::new("x0", x0.to_vec())],
        Combine::Zip,
        PlanRequest {
            method: Some(method),
            integrator: Some(IntegratorKind::Rk4),
            dt: Some(DT),
            steps: Some(STEPS),
            ..Default::default()
        },
        None,
    )
    .expect("the sweep is valid");
    let start = Instant::now();
    let members = if alone {
        let next = std::sync::atomic::AtomicUsize::new(0);
        let mut members: Vec<Member> = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..threads)
                .map(|_| {
                    scope.spawn(|| {
                        let mut done = Vec::new();
                        loop {
                            let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                            if i >= sweep.len() {
                                break done;
                            }
                            done.push(sweep.run_member(i));
                        }
                    })
                })
                .collect();
            workers
                .into_iter()
                .flat_map(|w| w.join().unwrap())
                .collect()
        });
        members.sort_by_key(|m| m.index);
        members
    } else {
        sweep.run(threads).expect("the members fit in memory")
    };
    (start.elapsed().as_secs_f64(), members)
}

/// Microseconds per member to set up (scene, plan, simulation, stop condition; nothing run),
/// on one thread, best of 5 rounds over every member: restarted from the scene's compiled
/// equations (the sweep's own path here) and, with `reload`, loading each member's scene
/// again (the path of parameters that change the equations).
fn setup_micros(method: Method, x0: &[f64], reload: bool) -> f64 {
    let scene = Scene::parse(SCENE, "parabola-x0.toml", &[]).expect("the scene loads");
    let mut sweep = Sweep::new(
        &scene,
        vec![Axis::new("x0", x0.to_vec())],
        Combine::Zip,
        PlanRequest {
            method: Some(method),
            integrator: Some(IntegratorKind::Rk4),
            dt: Some(DT),
            steps: Some(STEPS),
            ..Default::default()
        },
        None,
    )
    .expect("the sweep is valid");
    if reload {
        sweep = sweep.reloading_every_member();
    }
    assert_eq!(sweep.reload_reasons().is_empty(), !reload);
    (0..5)
        .map(|_| {
            let start = Instant::now();
            for i in 0..sweep.len() {
                assert!(black_box(sweep.set_up_member(i)));
            }
            start.elapsed().as_secs_f64() * 1e6 / sweep.len() as f64
        })
        .fold(f64::INFINITY, f64::min)
}

/// One block of the hand-written implicit form: state (x, y, vx, vy) per member.
fn implicit_block(x: &mut [f64], y: &mut [f64], vx: &mut [f64], vy: &mut [f64]) {
    let accel = |x: f64, vx: f64| {
        let lambda = (-2.0 * vx * vx - 100.0 * G) / (4.0 * x * x + 1e4);
        (2.0 * x * lambda, G + 100.0 * lambda)
    };
    let h = DT / 6.0;
    for _ in 0..STEPS {
        for i in 0..x.len() {
            let (x0, y0, u0, w0) = (x[i], y[i], vx[i], vy[i]);
            let (a1, b1) = accel(x0, u0);
            let (x2, u2, w2) = (x0 + 0.5 * DT * u0, u0 + 0.5 * DT * a1, w0 + 0.5 * DT * b1);
            let (a2, b2) = accel(x2, u2);
            let (x3, u3, w3) = (x0 + 0.5 * DT * u2, u0 + 0.5 * DT * a2, w0 + 0.5 * DT * b2);
            let (a3, b3) = accel(x3, u3);
            let (x4, u4, w4) = (x0 + DT * u3, u0 + DT * a3, w0 + DT * b3);
            let (a4, b4) = accel(x4, u4);
            x[i] = x0 + h * (u0 + 2.0 * u2 + 2.0 * u3 + u4);
            y[i] = y0 + h * (w0 + 2.0 * w2 + 2.0 * w3 + w4);
            vx[i] = u0 + h * (a1 + 2.0 * a2 + 2.0 * a3 + a4);
            vy[i] = w0 + h * (b1 + 2.0 * b2 + 2.0 * b3 + b4);
        }
    }
}

/// One block of the hand-written parametric form: state (q, qdot) per member.
fn parametric_block(q: &mut [f64], qdot: &mut [f64]) {
    let accel = |q: f64, v: f64| -(G * q / 50.0 + q * v * v / 2500.0) / (1.0 + q * q / 2500.0);
    let h = DT / 6.0;
    for _ in 0..STEPS {
        for i in 0..q.len() {
            let (q0, v0) = (q[i], qdot[i]);
            let a1 = accel(q0, v0);
            let (q2, v2) = (q0 + 0.5 * DT * v0, v0 + 0.5 * DT * a1);
            let a2 = accel(q2, v2);
            let (q3, v3) = (q0 + 0.5 * DT * v2, v0 + 0.5 * DT * a2);
            let a3 = accel(q3, v3);
            let (q4, v4) = (q0 + DT * v3, v0 + DT * a3);
            let a4 = accel(q4, v4);
            q[i] = q0 + h * (v0 + 2.0 * v2 + 2.0 * v3 + v4);
            qdot[i] = v0 + h * (a1 + 2.0 * a2 + 2.0 * a3 + a4);
        }
    }
}

/// The floor: every member's final (x, y), blocks of `BLOCK` split over `threads` threads.
fn by_hand(method: Method, x0: &[f64], threads: usize) -> (f64, Vec<[f64; 2]>) {
    let n = x0.len();
    let mut finals = vec![[0.0; 2]; n];
    let start = Instant::now();
    let chunk = n.div_ceil(threads).div_ceil(BLOCK) * BLOCK;
    std::thread::scope(|scope| {
        for (x0, finals) in x0.chunks(chunk).zip(finals.chunks_mut(chunk)) {
            scope.spawn(move || {
                for (x0, finals) in x0.chunks(BLOCK).zip(finals.chunks_mut(BLOCK)) {
                    let m = x0.len();
                    let mut x = x0.to_vec();
                    match method {
                        Method::Implicit => {
                            let mut y: Vec<f64> = x0.iter().map(|x| -x * x / 100.0).collect();
                            let (mut vx, mut vy) = (vec![0.0; m], vec![0.0; m]);
                            implicit_block(&mut x, &mut y, &mut vx, &mut vy);
                            for (f, (x, y)) in finals.iter_mut().zip(x.iter().zip(&y)) {
                                *f = [*x, *y];
                            }
                        }
                        Method::Parametric => {
                            let mut qdot = vec![0.0; m];
                            parametric_block(&mut x, &mut qdot);
                            for (f, q) in finals.iter_mut().zip(&x) {
                                *f = [*q, -q * q / 100.0];
                            }
                        }
                    }
                }
            });
        }
    });
    (start.elapsed().as_secs_f64(), black_box(finals))
}

fn main() {
    let mut members = 10_000;
    let (mut setup_only, mut restarted_only, mut lanes_only) = (false, false, false);
    let mut rounds = 1;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        if arg == "--setup-only" {
            setup_only = true;
        } else if arg == "--restarted-only" {
            (setup_only, restarted_only) = (true, true);
        } else if arg == "--lanes-only" {
            lanes_only = true;
        } else if arg == "--rounds" {
            rounds = args
                .next()
                .and_then(|n| n.parse().ok())
                .filter(|&n| n > 0)
                .expect("--rounds N");
        } else if arg == "--members" {
            members = args
                .next()
                .and_then(|n| n.parse().ok())
                .expect("--members N");
        }
    }
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let x0 = release_points(members);
    let work = members as f64 * STEPS as f64; // one particle per member
    println!(
        "ensemble: {members} beads on the article's parabola, x0 over [10, 200), {STEPS} rk4 steps of 1/60 s, {threads} thread(s)"
    );
    println!(
        "{:<11} {:>16} {:>16} {:>16} {:>11} {:>11}",
        "form", "bead (lanes)", "bead (alone)", "floor", "floor/bead", "lanes gain"
    );
    for method in [Method::Implicit, Method::Parametric] {
        if setup_only {
            break;
        }
        if lanes_only {
            let seconds = (0..rounds)
                .map(|_| through_bead(method, &x0, threads, false).0)
                .fold(f64::INFINITY, f64::min);
            println!("{:<11} {:>16.3e}", method.name(), work / seconds);
            continue;
        }
        let (alone_seconds, alone) = through_bead(method, &x0, threads, true);
        let (bead_seconds, results) = through_bead(method, &x0, threads, false);
        let (floor_seconds, finals) = by_hand(method, &x0, threads);
        // The lanes change no number.
        for (a, b) in alone.iter().zip(&results) {
            let (a, b) = (a.stats.as_ref().unwrap(), b.stats.as_ref().unwrap());
            assert_eq!(
                (&a.x, &a.xdot, a.energy_rel_error_max),
                (&b.x, &b.xdot, b.energy_rel_error_max)
            );
        }
        // The same work: every member's final position agrees (rounding differs).
        for (member, hand) in results.iter().zip(&finals) {
            let stats = member.stats.as_ref().expect("every member runs");
            assert!(member.error.is_none(), "{:?}", member.error);
            for k in 0..2 {
                assert!(
                    (stats.x[k] - hand[k]).abs() <= 1e-7 * 400.0,
                    "member {}: bead {:?}, by hand {:?}",
                    member.index,
                    stats.x,
                    hand
                );
            }
        }
        let bead_rate = work / bead_seconds;
        let alone_rate = work / alone_seconds;
        let floor_rate = work / floor_seconds;
        println!(
            "{:<11} {:>16.3e} {:>16.3e} {:>16.3e} {:>10.1}x {:>10.2}x",
            method.name(),
            bead_rate,
            alone_rate,
            floor_rate,
            floor_rate / bead_rate,
            bead_rate / alone_rate
        );
    }
    if lanes_only {
        return;
    }
    println!("target: >= 1e8 particle-steps/s on 2 cores (within 4x of the floor)");
    println!("member setup, us per member (1 thread, best of 5 rounds of {members}):");
    println!("{:<11} {:>16} {:>16}", "form", "restarted", "reloaded");
    for method in [Method::Implicit, Method::Parametric] {
        let restarted = setup_micros(method, &x0, false);
        let reloaded = if restarted_only {
            f64::NAN
        } else {
            setup_micros(method, &x0, true)
        };
        println!(
            "{:<11} {:>16.2} {:>16.2}",
            method.name(),
            restarted,
            reloaded
        );
    }
    beside_numpy(members);
}

/// The same ensemble through the Python package's `bead.sweep` beside a vectorized numpy RK4
/// of the same equations, by CPU time, in a Python process started from here
/// (`examples/numpy_ensemble.py`, which checks first that both end every member at the same
/// place). The interpreter is `$BEAD_PYTHON`, else the repository's `.venv` (made by
/// `scripts/test`, with the package as last built there); without one that imports bead
/// and numpy, says how to get it.
fn beside_numpy(members: usize) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let python = std::env::var_os("BEAD_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| root.join(".venv/bin/python"));
    let usable = std::process::Command::new(&python)
        .args(["-c", "import bead, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    println!();
    if !usable {
        println!(
            "beside numpy: skipped ({} cannot import bead and numpy; run scripts/test once, \
             or set BEAD_PYTHON to a Python with both)",
            python.display()
        );
        return;
    }
    if let Some(warning) = stale_package(&python, &root) {
        println!("beside numpy: {warning}");
    }
    let status = std::process::Command::new(&python)
        .arg(root.join("examples/numpy_ensemble.py"))
        .args(["--members", &members.to_string(), "--rounds", "1"])
        .status();
    if !status.is_ok_and(|s| s.success()) {
        println!("beside numpy: examples/numpy_ensemble.py failed");
    }
}

/// Why the figures of `python`'s bead may not be this tree's: its compiled extension is
/// older than the newest source of the library or the package (a `.venv` left from an
/// earlier build measures that build, silently). `None` when it is as new, or when either
/// cannot be found.
fn stale_package(python: &std::path::Path, root: &std::path::Path) -> Option<String> {
    let out = std::process::Command::new(python)
        .args(["-c", "import bead._bead as m; print(m.__file__)"])
        .output()
        .ok()?;
    let extension = std::path::PathBuf::from(String::from_utf8(out.stdout).ok()?.trim());
    let built = std::fs::metadata(&extension).ok()?.modified().ok()?;
    fn newest_in(dir: &std::path::Path) -> Option<std::time::SystemTime> {
        let mut newest = None;
        for entry in std::fs::read_dir(dir).ok()?.flatten() {
            let path = entry.path();
            let time = if path.is_dir() {
                newest_in(&path)
            } else {
                entry.metadata().ok()?.modified().ok()
            };
            newest = newest.max(time);
        }
        newest
    }
    let source = ["crates/bead/src", "crates/bead-py/src"]
        .iter()
        .filter_map(|dir| newest_in(&root.join(dir)))
        .max()?;
    (built < source).then(|| {
        format!(
            "WARNING: {} was built before the latest change to the sources, so the \
             bead.sweep figures below are an older build's (rebuild: `maturin develop \
             --release` in crates/bead-py with that Python's environment)",
            extension.display()
        )
    })
}
