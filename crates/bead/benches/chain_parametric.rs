//! The parametric form at scale: a chain of N links in angle coordinates.
//!
//! Unit masses on rods of length 1, pinned at the origin, +y down, g = 9.81, horizontal at
//! rest (every angle pi/2). Particle i sits at x_i = sum_{k <= i} (sin th_k, cos th_k), so
//! dx_i/dth_j = 0 for j > i: half of the dense J is structural zeros.
//!
//! Measured for N = 10, 100, 300 (`cargo bench -p bead --bench chain`):
//!
//! - load: building the system (symbolic J, xdot and h, tape compilation) from positions built
//!   in code as running sums (x_i = x_(i-1) + (sin th_i, cos th_i), a shared DAG), and from
//!   scene text (`sin(th1) + sin(th2) + ...` per particle, as a scene file writes it); then
//!   `Parametric::new`;
//! - steps/s: rk4 at dt = 1/120 through `Integrator::step` alone, and through
//!   `Simulation::step` (monitors included).
//!
//! Without `--bench` (`cargo test --benches`) it runs N = 10 and 30 only, briefly, as a
//! smoke test.

use std::sync::Arc;
use std::time::Instant;

use bead::expr::Expr;
use bead::formulation::{Formulation, Method, Parametric};
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, System, SystemBuilder};
use bead::simulate::{Simulation, SimulationConfig};

const G: f64 = 9.81;
const DT: f64 = 1.0 / 120.0;

fn names(n: usize) -> Vec<String> {
    (1..=n).map(|i| format!("th{i}")).collect()
}

/// The chain's particles, rods and coordinates, without parametric positions.
fn chain_builder(n: usize) -> SystemBuilder {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let mut previous = None;
    for i in 1..=n {
        let p = b
            .particle(&format!("p{i}"), 1.0, &[i as f64, 0.0], &[0.0, 0.0])
            .unwrap();
        let end = previous.map_or(Endpoint::Fixed(vec![0.0, 0.0]), Endpoint::Particle);
        b.distance(&format!("rod{i}"), p, end, 1.0).unwrap();
        previous = Some(p);
    }
    let names = names(n);
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let half_pi = std::f64::consts::FRAC_PI_2;
    b.parametric(&names, &vec![half_pi; n], &vec![0.0; n])
        .unwrap();
    b
}

/// Positions built in code: running sums, so particle i shares particle i-1's expression.
fn chain_in_code(n: usize) -> System {
    let mut b = chain_builder(n);
    let (mut x, mut y) = (Expr::constant(0.0), Expr::constant(0.0));
    for i in 1..=n {
        let th = Expr::var(i - 1);
        x = x + th.sin();
        y = y + th.cos();
        b.parametric_position(&format!("p{i}"), vec![x.clone(), y.clone()])
            .unwrap();
    }
    b.build().unwrap()
}

/// Positions as a scene file writes them: one sum of i terms per particle, parsed.
fn chain_from_text(n: usize) -> System {
    let mut b = chain_builder(n);
    let names = names(n);
    for i in 1..=n {
        let sum = |f: &str| {
            names[..i]
                .iter()
                .map(|th| format!("{f}({th})"))
                .collect::<Vec<_>>()
                .join(" + ")
        };
        let (x, y) = (sum("sin"), sum("cos"));
        b.parametric_position_exprs(&format!("p{i}"), &[&x, &y])
            .unwrap();
    }
    b.build().unwrap()
}

fn seconds<R>(f: impl FnOnce() -> R) -> (f64, R) {
    let start = Instant::now();
    let r = f();
    (start.elapsed().as_secs_f64(), r)
}

/// Steps per second of `step`: the best of rounds of at least `budget / 5` seconds and 3
/// steps each, over about `budget` seconds (the best round filters out other processes on a
/// shared machine).
fn steps_per_second(budget: f64, mut step: impl FnMut()) -> f64 {
    step(); // warm-up
    let start = Instant::now();
    let mut best: f64 = 0.0;
    while best == 0.0 || start.elapsed().as_secs_f64() < budget {
        let round = Instant::now();
        let mut steps = 0u64;
        while steps < 3 || round.elapsed().as_secs_f64() < budget / 5.0 {
            step();
            steps += 1;
        }
        best = best.max(steps as f64 / round.elapsed().as_secs_f64());
    }
    best
}

struct Row {
    n: usize,
    load_code: f64,
    load_text: f64,
    formulation: f64,
    instructions: usize,
    integrator: f64,
    simulation: f64,
}

fn measure(n: usize, budget: f64) -> Row {
    let (load_code, system) = seconds(|| Arc::new(chain_in_code(n)));
    let (load_text, text_system) = seconds(|| chain_from_text(n));
    let instructions = system.parametric().unwrap().n_instructions();
    let (formulation, mut parametric) = seconds(|| Parametric::new(system.clone()).unwrap());

    // The two ways of writing the chain describe the same motion.
    let mut other = Parametric::new(Arc::new(text_system)).unwrap();
    let start = parametric.initial_state();
    let mut integrator = IntegratorKind::Rk4.build(n);
    let mut state = start.clone();
    integrator.step(&mut parametric, &mut state, DT).unwrap();
    let mut other_state = start.clone();
    integrator.step(&mut other, &mut other_state, DT).unwrap();
    for (a, b) in state.q.iter().zip(&other_state.q) {
        assert!((a - b).abs() <= 1e-12, "code {a} vs text {b}");
    }

    let mut state = start.clone();
    let integrator_rate = steps_per_second(budget, || {
        integrator.step(&mut parametric, &mut state, DT).unwrap();
    });
    let config = SimulationConfig {
        method: Method::Parametric,
        integrator: IntegratorKind::Rk4,
        dt: DT,
        ..Default::default()
    };
    let mut simulation = Simulation::new(system, config).unwrap();
    let simulation_rate = steps_per_second(budget, || simulation.step().unwrap());
    Row {
        n,
        load_code,
        load_text,
        formulation,
        instructions,
        integrator: integrator_rate,
        simulation: simulation_rate,
    }
}

fn main() {
    let benchmarking = std::env::args().any(|a| a == "--bench");
    // BEAD_CHAIN_N=100 measures one size only, BEAD_CHAIN_SECONDS=0.1 shortens the stepping
    // (for a profiler).
    let chosen: Option<usize> = std::env::var("BEAD_CHAIN_N")
        .ok()
        .and_then(|n| n.parse().ok());
    let seconds: Option<f64> = std::env::var("BEAD_CHAIN_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok());
    let (sizes, budget): (Vec<usize>, f64) = match chosen {
        Some(n) => (vec![n], 5.0),
        None if benchmarking => (vec![10, 100, 300], 5.0),
        None => (vec![10, 30], 0.05),
    };
    let budget = seconds.unwrap_or(budget);
    println!();
    println!("Chain of N links in angle coordinates, parametric form, rk4 at dt = 1/120:");
    println!(
        "  {:>4} {:>12} {:>12} {:>14} {:>12} {:>16} {:>16}",
        "N",
        "load code s",
        "load text s",
        "Parametric s",
        "tape instr",
        "integrator st/s",
        "simulation st/s"
    );
    for n in sizes {
        let r = measure(n, budget);
        println!(
            "  {:>4} {:>12.4} {:>12.4} {:>14.4} {:>12} {:>16.1} {:>16.1}",
            r.n,
            r.load_code,
            r.load_text,
            r.formulation,
            r.instructions,
            r.integrator,
            r.simulation
        );
    }
}
