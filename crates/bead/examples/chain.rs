//! Steps per second of a hanging chain built in code: N particles of unit mass joined by
//! rods of length 1, the first rod pinned at the origin, horizontal at rest, g = 9.81, stepped
//! through `Simulation` (monitors included) with dt = 1/120. Each case runs from the
//! initial state for at most 2 simulated seconds (240 steps: rk4 without feedback drifts off
//! the rods over longer times), then restarts, until its wall time is used; only steps are
//! timed.
//!
//! ```text
//! cargo run --release -p bead --example chain -- [N ...] [--integrator rk4|rattle ...]
//!     [--seconds S] [--max-steps K] [--solver auto|dense|sparse|tridiagonal]
//!     [--newton auto|exact|simplified ...]
//! ```
//! Defaults: N = 10 100 1000 10000, both integrators, S = 2 (wall time per case, after one
//! warm-up step), at most K = 100000 steps per case, the solver chosen by size. `--newton`
//! steps RATTLE directly (no `Simulation`, no monitors) with that Newton matrix instead, and
//! reports the Newton iterations per step (mean and max) at the tolerance `Simulation` would
//! use.

use std::sync::Arc;
use std::time::Instant;

use bead::formulation::{ConstraintScales, Feedback, Formulation, Implicit, Method};
use bead::integrate::{Integrator, IntegratorKind, IntegratorSettings, NewtonMatrix, Rattle};
use bead::linalg::LinearSolver;
use bead::model::{Endpoint, System, SystemBuilder};
use bead::simulate::{Simulation, SimulationConfig};

/// The chain: particle i at (i + 1, 0); rod 0 from particle 0 to the origin, rod i from
/// particle i to particle i - 1.
fn chain(n: usize) -> System {
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    let mut previous = None;
    for i in 0..n {
        let p = b
            .particle(&format!("p{i}"), 1.0, &[(i + 1) as f64, 0.0], &[0.0, 0.0])
            .unwrap();
        let end = match previous {
            None => Endpoint::Fixed(vec![0.0, 0.0]),
            Some(q) => Endpoint::Particle(q),
        };
        b.distance(&format!("rod {i}"), p, end, 1.0).unwrap();
        previous = Some(p);
    }
    b.build().unwrap()
}

/// Steps from the initial state before a restart (2 s of simulated time).
const HORIZON: u64 = 240;

fn main() {
    let mut sizes = Vec::new();
    let mut integrators = Vec::new();
    let mut seconds = 2.0;
    let mut max_steps = 100_000u64;
    let mut solver = LinearSolver::Auto;
    let mut newtons = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--integrator" => integrators.push(match args.next().as_deref() {
                Some("rk4") => IntegratorKind::Rk4,
                Some("rattle") => IntegratorKind::Rattle,
                other => panic!("unknown integrator {other:?}"),
            }),
            "--seconds" => seconds = args.next().unwrap().parse().unwrap(),
            "--max-steps" => max_steps = args.next().unwrap().parse().unwrap(),
            "--solver" => {
                solver = match args.next().as_deref() {
                    Some("auto") => LinearSolver::Auto,
                    Some("dense") => LinearSolver::Dense,
                    Some("sparse") => LinearSolver::Sparse,
                    Some("tridiagonal") => LinearSolver::Tridiagonal,
                    other => panic!("unknown solver {other:?}"),
                }
            }
            "--newton" => newtons.push(match args.next().as_deref() {
                Some("exact") => NewtonMatrix::Exact,
                Some("simplified") => NewtonMatrix::Simplified,
                Some("auto") => NewtonMatrix::Auto,
                other => panic!("unknown Newton matrix {other:?}"),
            }),
            n => sizes.push(n.parse::<usize>().expect("N")),
        }
    }
    if sizes.is_empty() {
        sizes = vec![10, 100, 1000, 10_000];
    }
    if integrators.is_empty() {
        integrators = vec![IntegratorKind::Rk4, IntegratorKind::Rattle];
    }
    if !newtons.is_empty() {
        newton_table(&sizes, &newtons, solver, seconds, max_steps);
        return;
    }
    println!("| N | integrator | build s | setup s | steps | steps/s | max newton |");
    println!("|---|---|---|---|---|---|---|");
    for &n in &sizes {
        let start = Instant::now();
        let system = Arc::new(chain(n));
        let build = start.elapsed().as_secs_f64();
        for &integrator in &integrators {
            let config = SimulationConfig {
                method: Method::Implicit,
                integrator,
                dt: 1.0 / 120.0,
                ..Default::default()
            };
            let start = Instant::now();
            let formulation = Implicit::with_solver(system.clone(), Feedback::default(), solver);
            let mut sim = Simulation::with_formulation(Box::new(formulation), config).unwrap();
            sim.step().unwrap();
            let setup = start.elapsed().as_secs_f64();
            let (mut steps, mut elapsed, mut newton) = (0u64, 0.0, None);
            while steps < max_steps && elapsed < seconds {
                let start = Instant::now();
                while sim.steps() < HORIZON && steps < max_steps {
                    sim.step().unwrap();
                    steps += 1;
                    if start.elapsed().as_secs_f64() + elapsed >= seconds {
                        break;
                    }
                }
                elapsed += start.elapsed().as_secs_f64();
                newton = newton.max(sim.stats(elapsed).newton_iterations_max);
                sim.reset();
            }
            println!(
                "| {n} | {} | {build:.3} | {setup:.3} | {steps} | {:.1} | {} |",
                integrator.name(),
                steps as f64 / elapsed,
                newton.map_or("-".to_string(), |k| k.to_string()),
            );
        }
    }
}

/// RATTLE stepped directly with each Newton matrix: steps/s and Newton iterations per step.
fn newton_table(
    sizes: &[usize],
    newtons: &[NewtonMatrix],
    solver: LinearSolver,
    seconds: f64,
    max_steps: u64,
) {
    println!("| N | Newton matrix | steps | steps/s | iterations per step (mean) | max |");
    println!("|---|---|---|---|---|---|");
    for &n in sizes {
        let system = Arc::new(chain(n));
        for &newton in newtons {
            // The tolerance a `Simulation` uses: each rod to 1e-12 of its length.
            let mut formulation =
                Implicit::with_solver(system.clone(), Feedback::default(), solver);
            formulation.set_constraint_scales(Some(ConstraintScales::of(&system)));
            let settings = IntegratorSettings {
                constraint_tolerance: bead::simulate::RELATIVE_CONSTRAINT_TOLERANCE,
                ..IntegratorSettings::default()
            };
            let (mut steps, mut elapsed, mut iterations, mut max) = (0u64, 0.0, 0u64, 0usize);
            // Restarts: each begins with one untimed step, whose iterations count too.
            let mut chunks = 0u64;
            while steps < max_steps && elapsed < seconds {
                let mut state = formulation.initial_state();
                let mut rattle =
                    Rattle::with_settings(state.q.len(), &settings).with_newton(newton);
                rattle
                    .step(&mut formulation, &mut state, 1.0 / 120.0)
                    .unwrap();
                let start = Instant::now();
                chunks += 1;
                for _ in 1..HORIZON {
                    rattle
                        .step(&mut formulation, &mut state, 1.0 / 120.0)
                        .unwrap();
                    steps += 1;
                    if start.elapsed().as_secs_f64() + elapsed >= seconds || steps >= max_steps {
                        break;
                    }
                }
                elapsed += start.elapsed().as_secs_f64();
                max = max.max(rattle.newton_iterations_max().unwrap_or(0));
                iterations += rattle.newton_iterations_total();
            }
            println!(
                "| {n} | {newton:?} | {steps} | {:.1} | {:.2} | {max} |",
                steps as f64 / elapsed,
                iterations as f64 / (steps + chunks) as f64,
            );
        }
    }
}
