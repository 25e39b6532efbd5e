//! A hanging chain of N rods with RATTLE, through the engine and by hand (the floor).
//!
//! The chain: N particles of unit mass, p_k at ((k + 1) L, 0), joined by rods of length L = 1,
//! the first to a fixed anchor at the origin; gravity g = 9.81 along +y; released at rest
//! (the setup of the peer figures in issue 8). Each variant simulates 10 s with RATTLE at
//! dt = 1/120 (two steps per frame of 1/60 s) and reports frames of 1/60 s per second of wall
//! time, the time per step per link, the stretch max |d - L| / L over the run, the energy
//! drift |E - E0| / (m g L N (N + 1) / 2) at the end and the substeps per step. A long
//! chain's tip whips faster than one Newton solve per 1/120 s can follow; the variants:
//!
//! - `engine`: `Simulation` (monitors included, what `bead run` does) with its own
//!   substeps: as many as RATTLE's stability needs under the rods' last tensions (h omega
//!   <= 2), and a step whose Newton solve fails anyway is taken again in 2, 3, 5, 8, ...
//!   substeps, the next steps starting from what it needed (the most any step took is
//!   printed);
//! - `engine, fixed`, `step alone` (the engine's RATTLE stepped directly, no monitors) and
//!   `hand-written` (the floor): the whole run with 1, 2, 4, ... substeps per step, the
//!   fewest at which every step converges.
//!
//! The floor is a hand-written RATTLE of this chain alone: the SHAKE step by exact Newton
//! with the tridiagonal matrix J(x^k) W J(x_n)^T solved by the Thomas algorithm, the velocity
//! step by the tridiagonal J W J^T, single-threaded, allocation-free; it stops its Newton
//! iteration by the engine's own per-rod test (each rod to 1e-12 of its length plus the
//! rounding its coordinates allow: `TOLERANCE`), so both do the same work. `hand, warm` is
//! the same floor warm-started as the engine's RATTLE is (each step's Newton iteration from
//! the last step's multipliers), the stronger floor. The peak memory
//! (the process's high-water mark) is printed after each size, the sizes in increasing
//! order; the last lines give the growth from each size to the next of the engine's time
//! per frame, the floor's, and the engine's time per Newton iteration (one sweep along the
//! chain, where linear in N is 10x per decade).

use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use bead::formulation::{Feedback, Implicit, Method};
use bead::integrate::IntegratorKind;
use bead::linalg::LinearSolver;
use bead::model::{Endpoint, System, SystemBuilder};
use bead::simulate::{Simulation, SimulationConfig};

const G: f64 = 9.81;
const L: f64 = 1.0;
const FRAME: f64 = 1.0 / 60.0;

/// The step: two per frame.
const DT: f64 = FRAME / 2.0;

/// The solves' stopping rule, the engine's own (`ConstraintScales`, `Simulation`'s
/// tolerance 1e-12): every rod i within
///
/// ```text
/// |C_i| <= 1e-12 L + rho_i max_k |x_k|,   rho_i = 16 eps |J_i(x_0)|
/// ```
///
/// in the units of C = (|d|^2 - L^2) / (2 L) (a length), the max over rod i's coordinates:
/// 1e-12 of a rod's length plus what rounding allows at its coordinates (|x| up to N L:
/// |C| cannot go below a few eps |x| L there). |J_i(x_0)| is sqrt(2) for a rod between two
/// particles (J_i = (d / L, -d / L)), 1 for the first, anchored one.
const TOLERANCE: f64 = 1e-12;
const ROUNDING_LINK: f64 = 16.0 * f64::EPSILON * std::f64::consts::SQRT_2;
const ROUNDING_FIRST: f64 = 16.0 * f64::EPSILON;

/// The chain's figures after a run.
#[derive(Clone, Copy, Debug)]
struct Figures {
    frames_per_second: f64,
    ns_per_step_per_link: f64,
    stretch: f64,
    drift: f64,
    steps: u64,
    /// Substeps per step: the most any step took (engine), or every step's (floor)
    substeps: u32,
}

/// The hand-written RATTLE of the chain. Particle k is at `x[k]`, its rod joins it to k - 1
/// (the anchor at the origin for k = 0).
struct HandChain {
    n: usize,
    x: Vec<[f64; 2]>,
    v: Vec<[f64; 2]>,
    /// x_n at the start of the step
    x0: Vec<[f64; 2]>,
    /// The predictor q_n + h (v_n + h/2 g)
    pred: Vec<[f64; 2]>,
    /// Rod vectors d_i = x_n[i] - x_n[i-1] (start) and e_i at the iterate
    d: Vec<[f64; 2]>,
    e: Vec<[f64; 2]>,
    /// Tridiagonal matrix (lower, diagonal, upper), right-hand side, multipliers, scratch
    lower: Vec<f64>,
    diag: Vec<f64>,
    upper: Vec<f64>,
    rhs: Vec<f64>,
    nu: Vec<f64>,
    scratch: Vec<f64>,
    /// Warm start: a step of the same h as the last one starts from its nu (0: cold)
    warm: bool,
    nu_h: f64,
}

impl HandChain {
    fn new(n: usize, warm: bool) -> Self {
        let x = (0..n).map(|k| [(k + 1) as f64 * L, 0.0]).collect();
        let zeros = vec![[0.0; 2]; n];
        HandChain {
            n,
            x,
            v: zeros.clone(),
            x0: zeros.clone(),
            pred: zeros.clone(),
            d: zeros.clone(),
            e: zeros,
            lower: vec![0.0; n],
            diag: vec![0.0; n],
            upper: vec![0.0; n],
            rhs: vec![0.0; n],
            nu: vec![0.0; n],
            scratch: vec![0.0; n],
            warm,
            nu_h: 0.0,
        }
    }

    /// x = pred - W J(x_n)^T nu.
    fn apply_multipliers(&mut self) {
        let n = self.n;
        for j in 0..n {
            let mut p = self.pred[j];
            let dj = self.d[j];
            p[0] -= dj[0] / L * self.nu[j];
            p[1] -= dj[1] / L * self.nu[j];
            if j + 1 < n {
                let dn = self.d[j + 1];
                p[0] += dn[0] / L * self.nu[j + 1];
                p[1] += dn[1] / L * self.nu[j + 1];
            }
            self.x[j] = p;
        }
    }

    fn rods(x: &[[f64; 2]], out: &mut [[f64; 2]]) {
        let mut before = [0.0, 0.0];
        for (o, p) in out.iter_mut().zip(x) {
            *o = [p[0] - before[0], p[1] - before[1]];
            before = *p;
        }
    }

    /// One RATTLE step of h; returns the Newton iterations it took, or `None` when the
    /// Newton iteration did not converge in 50 (the state is then spoilt).
    fn step(&mut self, h: f64) -> Option<usize> {
        let n = self.n;
        self.x0.copy_from_slice(&self.x);
        Self::rods(&self.x0, &mut self.d);
        for k in 0..n {
            let vy = self.v[k][1] + 0.5 * h * G;
            self.pred[k] = [self.x[k][0] + h * self.v[k][0], self.x[k][1] + h * vy];
        }
        // Warm: the last step's nu, from a step of the same h (the floor's substeps are all
        // alike); cold: nu = 0, x = pred.
        if self.warm && self.nu_h == h {
            self.apply_multipliers();
        } else {
            self.x.copy_from_slice(&self.pred);
            self.nu.fill(0.0);
        }
        self.nu_h = 0.0;
        let mut iterations = 0;
        let inv_l2 = 1.0 / (L * L);
        loop {
            Self::rods(&self.x, &mut self.e);
            let (mut worst, mut nan) = (0.0_f64, false);
            for i in 0..n {
                let e = self.e[i];
                let c = (e[0] * e[0] + e[1] * e[1] - L * L) / (2.0 * L);
                self.rhs[i] = c;
                // The engine's per-rod test (`ConstraintScales`): |C_i| beyond the rounding
                // allowance rho_i max |x_k| of the rod's coordinates, in units of L.
                let size = c.abs();
                // Not `size <= worst * L`, NaN included.
                if matches!(
                    size.partial_cmp(&(worst * L)),
                    None | Some(std::cmp::Ordering::Greater)
                ) {
                    let mut coordinates = self.x[i][0].abs().max(self.x[i][1].abs());
                    if i > 0 {
                        coordinates =
                            coordinates.max(self.x[i - 1][0].abs().max(self.x[i - 1][1].abs()));
                    }
                    let rounding = if i > 0 { ROUNDING_LINK } else { ROUNDING_FIRST };
                    worst = worst.max((size - rounding * coordinates) / L);
                    nan |= c.is_nan();
                }
            }
            if worst <= TOLERANCE && !nan {
                break;
            }
            if iterations >= 50 || nan {
                return None;
            }
            // A = J(x^k) W J(x_n)^T, tridiagonal.
            for i in 0..n {
                let (e, d) = (self.e[i], self.d[i]);
                let ed = (e[0] * d[0] + e[1] * d[1]) * inv_l2;
                self.diag[i] = if i > 0 { 2.0 * ed } else { ed };
                if i > 0 {
                    let dm = self.d[i - 1];
                    self.lower[i] = -(e[0] * dm[0] + e[1] * dm[1]) * inv_l2;
                }
                if i + 1 < n {
                    let dp = self.d[i + 1];
                    self.upper[i] = -(e[0] * dp[0] + e[1] * dp[1]) * inv_l2;
                }
            }
            thomas(
                &self.lower,
                &self.diag,
                &self.upper,
                &mut self.rhs,
                &mut self.scratch,
            );
            for (nu, delta) in self.nu.iter_mut().zip(&self.rhs) {
                *nu += delta;
            }
            self.apply_multipliers();
            iterations += 1;
        }
        // v_half = (x - x_n) / h, then the second half kick and the velocity projection onto
        // J v = 0 with the symmetric tridiagonal J W J^T at x_{n+1}.
        Self::rods(&self.x, &mut self.e);
        for k in 0..n {
            self.v[k] = [
                (self.x[k][0] - self.x0[k][0]) / h,
                (self.x[k][1] - self.x0[k][1]) / h + 0.5 * h * G,
            ];
        }
        let mut before = [0.0, 0.0];
        for i in 0..n {
            let e = self.e[i];
            let dv = [self.v[i][0] - before[0], self.v[i][1] - before[1]];
            before = self.v[i];
            self.rhs[i] = (e[0] * dv[0] + e[1] * dv[1]) / L;
            let ee = (e[0] * e[0] + e[1] * e[1]) * inv_l2;
            self.diag[i] = if i > 0 { 2.0 * ee } else { ee };
            if i > 0 {
                let em = self.e[i - 1];
                self.lower[i] = -(e[0] * em[0] + e[1] * em[1]) * inv_l2;
            }
            if i + 1 < n {
                let ep = self.e[i + 1];
                self.upper[i] = -(e[0] * ep[0] + e[1] * ep[1]) * inv_l2;
            }
        }
        thomas(
            &self.lower,
            &self.diag,
            &self.upper,
            &mut self.rhs,
            &mut self.scratch,
        );
        for j in 0..n {
            let ej = self.e[j];
            self.v[j][0] -= ej[0] / L * self.rhs[j];
            self.v[j][1] -= ej[1] / L * self.rhs[j];
            if j + 1 < n {
                let en = self.e[j + 1];
                self.v[j][0] += en[0] / L * self.rhs[j + 1];
                self.v[j][1] += en[1] / L * self.rhs[j + 1];
            }
        }
        self.nu_h = h;
        Some(iterations)
    }

    fn energy(&self) -> f64 {
        self.x
            .iter()
            .zip(&self.v)
            .map(|(x, v)| 0.5 * (v[0] * v[0] + v[1] * v[1]) - G * x[1])
            .sum()
    }

    fn stretch(&self) -> f64 {
        let mut before = [0.0, 0.0];
        let mut worst = 0.0_f64;
        for p in &self.x {
            let d = ((p[0] - before[0]).powi(2) + (p[1] - before[1]).powi(2)).sqrt();
            worst = worst.max((d - L).abs() / L);
            before = *p;
        }
        worst
    }
}

/// Solve the tridiagonal system (lower[i] at (i, i-1), diag[i], upper[i] at (i, i+1)) in
/// place: `rhs` becomes the solution. Thomas algorithm without pivoting: the chain's matrices
/// are diagonally dominant enough near the constraint manifold.
fn thomas(lower: &[f64], diag: &[f64], upper: &[f64], rhs: &mut [f64], c: &mut [f64]) {
    let n = rhs.len();
    let mut beta = diag[0];
    rhs[0] /= beta;
    for i in 1..n {
        c[i - 1] = upper[i - 1] / beta;
        beta = diag[i] - lower[i] * c[i - 1];
        rhs[i] = (rhs[i] - lower[i] * rhs[i - 1]) / beta;
    }
    for i in (0..n - 1).rev() {
        rhs[i] -= c[i] * rhs[i + 1];
    }
}

/// The chain as a bead system: distance rods, the first to a fixed anchor.
fn chain_system(n: usize) -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let mut previous = None;
    for k in 0..n {
        let p = b
            .particle(
                &format!("p{k}"),
                1.0,
                &[(k + 1) as f64 * L, 0.0],
                &[0.0, 0.0],
            )
            .unwrap();
        let other = match previous {
            None => Endpoint::Fixed(vec![0.0, 0.0]),
            Some(q) => Endpoint::Particle(q),
        };
        b.distance(&format!("rod {k}"), p, other, L).unwrap();
        previous = Some(p);
    }
    Arc::new(b.build().unwrap())
}

/// m g L N (N + 1) / 2: the potential energy the chain can exchange, the drift's scale.
fn energy_scale(n: usize) -> f64 {
    G * L * (n * (n + 1)) as f64 / 2.0
}

/// The floor with `substeps` per step (`None` when a step does not converge), and its Newton
/// iterations per step.
fn hand_run(n: usize, duration: f64, substeps: u32, warm: bool) -> Option<(Figures, f64)> {
    let steps = (duration / DT).round() as u64;
    let mut chain = HandChain::new(n, warm);
    let e0 = chain.energy();
    let h = DT / substeps as f64;
    let mut stretch = 0.0_f64;
    let mut iterations = 0;
    let start = Instant::now();
    for _ in 0..steps {
        for _ in 0..substeps {
            iterations += black_box(chain.step(h))?;
        }
        stretch = stretch.max(chain.stretch());
    }
    let wall = start.elapsed().as_secs_f64();
    let drift = (chain.energy() - e0).abs();
    Some((
        Figures {
            substeps,
            ..figures(n, steps, wall, stretch, drift)
        },
        iterations as f64 / steps as f64,
    ))
}

fn run_engine(n: usize, duration: f64) -> (Figures, f64) {
    engine_run(n, duration, None).expect("retries allowed")
}

/// The engine's run with `substeps` per step and no retry (`None` when a step fails), or,
/// without, `Simulation`'s own substeps (for stability, and retries in 2, 3, 5, ... where a
/// step fails anyway); and
/// its Newton iterations per step.
fn engine_run(n: usize, duration: f64, substeps: Option<u32>) -> Option<(Figures, f64)> {
    // The engine's own tolerance: each rod to 1e-12 of its length plus rounding at its
    // coordinates (`ConstraintScales`).
    let mut config = SimulationConfig {
        method: Method::Implicit,
        integrator: IntegratorKind::Rattle,
        dt: DT,
        ..Default::default()
    };
    if let Some(substeps) = substeps {
        (config.substeps, config.max_substeps) = (substeps, substeps);
    }
    let mut sim = Simulation::new(chain_system(n), config).unwrap();
    let e0 = sim.energy();
    let steps = (duration / DT).round() as u64;
    let mut stretch = 0.0_f64;
    let start = Instant::now();
    for _ in 0..steps {
        if let Err(e) = sim.step() {
            assert!(substeps.is_some(), "N = {n}: {e}");
            return None;
        }
        stretch = stretch.max(chain_stretch(sim.positions()));
    }
    let wall = start.elapsed().as_secs_f64();
    let drift = (sim.energy() - e0).abs();
    let iterations = sim.newton_iterations_total().expect("rattle counts") as f64;
    Some((
        Figures {
            substeps: sim.substeps_max(),
            ..figures(n, steps, wall, stretch, drift)
        },
        iterations / steps as f64,
    ))
}

/// `run(substeps)` with 1, 2, 4, ... substeps per step until a whole run converges (the
/// floor's rule).
fn fewest_substeps<T>(n: usize, mut run: impl FnMut(u32) -> Option<T>) -> T {
    let mut substeps = 1;
    loop {
        if let Some(result) = run(substeps) {
            return result;
        }
        substeps *= 2;
        assert!(substeps <= 64, "N = {n}: more than 64 substeps");
    }
}

/// The engine's RATTLE stepped directly (the implicit form with the per-rod tolerances
/// `Simulation` sets, no monitors) with `substeps` per step (`None` when a step fails), and
/// its Newton iterations per step.
fn step_alone_run(n: usize, duration: f64, substeps: u32) -> Option<(Figures, f64)> {
    use bead::integrate::{Integrator, Rattle};
    let system = chain_system(n);
    let (mut formulation, mut state, settings) = stepped_alone(&system);
    let mut rattle = Rattle::with_settings(state.q.len(), &settings);
    let e0 = system.energy(&state.q, &state.qdot);
    let steps = (duration / DT).round() as u64;
    let h = DT / substeps as f64;
    let mut stretch = 0.0_f64;
    let start = Instant::now();
    for _ in 0..steps {
        for _ in 0..substeps {
            rattle.step(&mut formulation, &mut state, h).ok()?;
        }
        stretch = stretch.max(chain_stretch(&state.q));
    }
    let wall = start.elapsed().as_secs_f64();
    let drift = (system.energy(&state.q, &state.qdot) - e0).abs();
    let iterations = rattle.newton_iterations_total() as f64 / steps as f64;
    Some((
        Figures {
            substeps,
            ..figures(n, steps, wall, stretch, drift)
        },
        iterations,
    ))
}

/// What an integrator stepped alone (no `Simulation`) needs to step `system` as `Simulation`
/// would: the implicit form with the per-rod tolerance scales, its initial state, and the
/// tolerance 1e-12 of each rod's length.
fn stepped_alone(
    system: &Arc<System>,
) -> (
    bead::formulation::Implicit,
    bead::formulation::State,
    bead::integrate::IntegratorSettings,
) {
    use bead::formulation::{ConstraintScales, Feedback, Formulation, Implicit};
    let mut formulation = Implicit::new(Arc::clone(system), Feedback::default());
    formulation.set_constraint_scales(Some(ConstraintScales::of(system)));
    let state = formulation.initial_state();
    let settings = bead::integrate::IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..Default::default()
    };
    (formulation, state, settings)
}

/// The process's peak resident memory so far (VmHWM, Linux), in MB.
fn peak_memory_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn chain_stretch(x: &[f64]) -> f64 {
    let mut before = [0.0, 0.0];
    let mut worst = 0.0_f64;
    for p in x.chunks_exact(2) {
        let d = ((p[0] - before[0]).powi(2) + (p[1] - before[1]).powi(2)).sqrt();
        worst = worst.max((d - L).abs() / L);
        before = [p[0], p[1]];
    }
    worst
}

fn figures(n: usize, steps: u64, wall: f64, stretch: f64, drift: f64) -> Figures {
    Figures {
        frames_per_second: steps as f64 * DT / FRAME / wall,
        ns_per_step_per_link: wall * 1e9 / steps as f64 / n as f64,
        stretch,
        drift: drift / energy_scale(n),
        steps,
        substeps: 1,
    }
}

fn main() {
    let benchmarking = std::env::args().any(|a| a == "--bench");
    // The chain's run simulates this much (s); shorter smoke runs under `cargo test --benches`.
    let duration = if benchmarking { 10.0 } else { 0.05 };
    // BEAD_CHAIN_SIZES=10,1000 picks the sizes; BEAD_CHAIN_VARIANTS=hand (or engine) one side.
    let sizes: Vec<usize> = match std::env::var("BEAD_CHAIN_SIZES") {
        Ok(list) => list
            .split(',')
            .map(|s| {
                s.trim()
                    .parse()
                    .expect("BEAD_CHAIN_SIZES: a comma-separated list of N")
            })
            .collect(),
        Err(_) if benchmarking => vec![10, 100, 1000, 10_000, 100_000],
        Err(_) => vec![10, 100],
    };
    // BEAD_CHAIN_VARIANTS picks among engine, fixed (the engine at fixed substeps), alone (the
    // step alone), hand (the floor), warm (the floor warm-started), tassel (the tree of rods)
    // and cloth (with the rope and the net).
    let variants = std::env::var("BEAD_CHAIN_VARIANTS")
        .unwrap_or_else(|_| "engine,fixed,alone,hand,warm".into());
    println!();
    println!("A chain of N rods, rattle at dt = 1/120, {duration} s simulated:");
    println!(
        "  {:>6}  {:<14} {:>12} {:>16} {:>10} {:>10} {:>9}",
        "N", "variant", "frames/s", "ns/step/link", "stretch", "drift", "substeps"
    );
    // (N, engine time per frame, the floor's, engine time per Newton iteration), in s
    let mut growth: Vec<(usize, f64, Option<f64>, f64)> = Vec::new();
    for &n in &sizes {
        let mut rows = Vec::new();
        let mut iterations = Vec::new();
        if variants.contains("engine") {
            let (figures, per_step) = run_engine(n, duration);
            let frame = 1.0 / figures.frames_per_second;
            // Two steps of 1/120 s per frame.
            growth.push((n, frame, None, frame / (2.0 * per_step)));
            iterations.push(("the engine", per_step));
            rows.push(("engine", figures));
        }
        if variants.contains("fixed") {
            let (figures, per_step) = fewest_substeps(n, |k| engine_run(n, duration, Some(k)));
            iterations.push(("the engine, fixed", per_step));
            rows.push(("engine, fixed", figures));
        }
        if variants.contains("alone") {
            let (figures, per_step) = fewest_substeps(n, |k| step_alone_run(n, duration, k));
            iterations.push(("the step alone", per_step));
            rows.push(("step alone", figures));
        }
        if variants.contains("hand") {
            let (figures, per_step) = fewest_substeps(n, |k| hand_run(n, duration, k, false));
            if let Some(last) = growth.last_mut().filter(|g| g.0 == n) {
                last.2 = Some(1.0 / figures.frames_per_second);
            }
            iterations.push(("the floor", per_step));
            rows.push(("hand-written", figures));
        }
        if variants.contains("warm") {
            let (figures, per_step) = fewest_substeps(n, |k| hand_run(n, duration, k, true));
            iterations.push(("the floor, warm", per_step));
            rows.push(("hand, warm", figures));
        }
        for (name, figures) in &rows {
            println!(
                "  {:>6}  {:<14} {:>12.1} {:>16.1} {:>10.1e} {:>10.1e} {:>9}",
                n,
                name,
                figures.frames_per_second,
                figures.ns_per_step_per_link,
                figures.stretch,
                figures.drift,
                figures.substeps,
            );
            black_box(figures.steps);
        }
        let find = |variant: &str| rows.iter().find(|(name, _)| *name == variant).map(|r| r.1);
        for floor in ["hand-written", "hand, warm"] {
            let Some(hand) = find(floor) else { continue };
            for variant in ["engine", "engine, fixed", "step alone"] {
                if let Some(figures) = find(variant) {
                    println!(
                        "  {:>6}  {variant} / {floor}: {:.2}x the floor's frames/s",
                        n,
                        figures.frames_per_second / hand.frames_per_second
                    );
                }
            }
        }
        for (variant, per_step) in iterations {
            println!("  {n:>6}  {variant}: {per_step:.2} Newton iterations per step of 1/120 s");
        }
        if let Some(peak) = peak_memory_mb() {
            println!("  {n:>6}  peak memory of the process so far: {peak:.0} MB");
        }
    }
    // Growth with N of the engine's time per frame, the floor's, and the engine's time per
    // Newton iteration (one sweep along the chain: linear would be x10 per x10 links). The
    // frame's grows faster than N on a hanging chain whatever the method: the tension at the
    // pivot grows as N, the fastest oscillation as sqrt(N), and with it the substeps a
    // stable step needs (issue 19's target, restated: time per iteration <= ~12x per decade,
    // time per frame no faster than the floor's).
    for pair in growth.windows(2) {
        let ((n0, frame0, floor0, iteration0), (n1, frame1, floor1, iteration1)) =
            (pair[0], pair[1]);
        let floor = match (floor0, floor1) {
            (Some(a), Some(b)) => format!(" (the floor's {:.1})", b / a),
            _ => String::new(),
        };
        println!(
            "  N = {n1} / N = {n0}: engine time per frame {:.1}{floor}, per Newton iteration {:.1}",
            frame1 / frame0,
            iteration1 / iteration0
        );
    }
    let everything = benchmarking && std::env::var("BEAD_CHAIN_VARIANTS").is_err();
    if variants.contains("tassel") || everything {
        // The tassel, a tree of rods: fused along the rods, and by faer's sparse LDL^T of
        // J W J^T (the general path, which trees took before).
        let duration = if benchmarking { 10.0 } else { 0.02 };
        let rattle = IntegratorKind::Rattle;
        run_scene("tassel.toml", rattle, None, duration);
        run_scene_solved("tassel.toml", rattle, None, duration, LinearSolver::Sparse);
    }
    if variants.contains("cloth") || everything {
        let duration = if benchmarking { 2.0 } else { 0.02 };
        // RATTLE at the step its stiffness needs (see cloth.toml), 1/(120 + F).
        let f = cloth_scene()
            .params
            .iter()
            .find(|p| p.0 == "F")
            .expect("cloth.toml has F")
            .1;
        run_cloth(IntegratorKind::Rattle, Some(1.0 / (120.0 + f)), duration);
        run_cloth(
            IntegratorKind::FastProjection,
            Some(FRAME),
            duration.max(FRAME),
        );
        run_cloth_projection_counts(duration.max(FRAME));
        run_xpbd_cloth(duration.max(FRAME), benchmarking);
        // The rope and the net with their own settings (RATTLE), and the net at a frame.
        let duration = if benchmarking { 10.0 } else { 0.02 };
        run_scene("rope.toml", IntegratorKind::Rattle, None, duration);
        run_scene("net.toml", IntegratorKind::Rattle, None, duration);
        run_scene(
            "net.toml",
            IntegratorKind::FastProjection,
            Some(FRAME),
            duration.max(FRAME),
        );
    }
}

/// The shipped cloth, loaded.
fn cloth_scene() -> bead::scene::Scene {
    shipped_scene("cloth.toml")
}

/// Shipped scene `name` (in `scenes/`), loaded.
fn shipped_scene(name: &str) -> bead::scene::Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name);
    bead::scene::Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"))
}

/// The fast projection's work on the cloth at dt = 1/60, by its integrator alone (no
/// monitors): Newton iterations and factorizations per step, time per step.
fn run_cloth_projection_counts(duration: f64) {
    use bead::integrate::{FastProjection, Integrator};
    let system = Arc::clone(&cloth_scene().system);
    let (mut formulation, mut state, settings) = stepped_alone(&system);
    let mut integrator = FastProjection::with_settings(state.q.len(), &settings);
    let steps = (duration / FRAME).round() as u64;
    let start = Instant::now();
    for _ in 0..steps {
        integrator
            .step(&mut formulation, &mut state, FRAME)
            .unwrap_or_else(|e| panic!("cloth: {e}"));
    }
    let wall = start.elapsed().as_secs_f64();
    println!(
        "  fast-projection's step alone: {:.2} ms per step, {:.2} Newton iterations and {:.2} \
         factorizations of the {} x {} Newton matrix per step (at most {} iterations)",
        wall * 1e3 / steps as f64,
        integrator.projection_iterations_total() as f64 / steps as f64,
        integrator.factorizations_total() as f64 / steps as f64,
        state.q.len() + system.constraints().n_rows(),
        state.q.len() + system.constraints().n_rows(),
        integrator.newton_iterations_max().unwrap_or(0),
    );
}

/// The game engines' answer on the same cloth (positions, gust, masses, rods and pins of
/// the scene): a hand-written XPBD (Macklin, Mueller & Chentanez 2016) with zero compliance, one
/// step per frame of 1/60 s: v += h g, p = x + h v, then `iterations` Gauss-Seidel sweeps
/// over the rods (p_a -= w_a / (w_a + w_b) C n, p_b += w_b / (w_a + w_b) C n with C = |d| - L,
/// n = d / |d|), v = (p - x) / h; or the frame in substeps of one sweep each. Each row its
/// frames/s and the largest stretch over the run; the game-engine target is 1e-3.
fn run_xpbd_cloth(duration: f64, benchmarking: bool) {
    let scene = cloth_scene();
    let system = Arc::clone(&scene.system);
    let set = system.constraints();
    let dim = system.dim();
    // The scene's start: its positions and the gust's velocities.
    let start = Simulation::new(Arc::clone(&system), SimulationConfig::default()).unwrap();
    let (x0, v0) = (start.positions().to_vec(), start.velocities().to_vec());
    let n = x0.len() / dim;
    let mut w: Vec<f64> = (0..n).map(|p| system.inverse_mass()[p * dim]).collect();
    let mut rods = Vec::new();
    for row in 0..set.n_rows() {
        match set.distance_row(row) {
            Some(rod) => rods.push((
                rod.a / dim,
                rod.b.expect("rods join particles") / dim,
                rod.length,
            )),
            // A pin holds its particle: infinite mass.
            None => w[set.row_columns(row)[0] / dim] = 0.0,
        }
    }
    let g = system.gravity().to_vec();
    let steps = (duration / FRAME).round() as u64;
    let cloth = XpbdCloth { dim, w, rods, g };
    println!();
    println!(
        "hand-written XPBD of the same cloth (zero compliance, Gauss-Seidel), frames of 1/60 s, \
         {duration:.3} s simulated:"
    );
    println!(
        "  {:>10} {:>10} {:>12} {:>10}",
        "substeps", "sweeps", "frames/s", "stretch"
    );
    // One step per frame with more and more sweeps, then more and more substeps of one
    // sweep each (Macklin et al. 2019, "Small steps in physics simulation"), until the
    // stretch is 1e-3 or the frame rate falls below 2 per second.
    for vary_substeps in [false, true] {
        let mut count = if vary_substeps { 20 } else { 10 };
        loop {
            let (substeps, sweeps) = if vary_substeps {
                (count, 1)
            } else {
                (1, count)
            };
            let start = Instant::now();
            let (x, stretch) = cloth.run(&x0, &v0, steps, substeps, sweeps);
            let wall = start.elapsed().as_secs_f64();
            black_box(&x);
            let frames_per_second = steps as f64 / wall;
            println!("  {substeps:>10} {sweeps:>10} {frames_per_second:>12.1} {stretch:>10.1e}");
            if stretch <= 1e-3 || frames_per_second < 2.0 || !benchmarking {
                break;
            }
            count *= 2;
        }
    }
}

/// The cloth for the hand-written XPBD: inverse masses per particle (0 where pinned), the
/// rods (a, b, L), gravity.
struct XpbdCloth {
    dim: usize,
    w: Vec<f64>,
    rods: Vec<(usize, usize, f64)>,
    g: Vec<f64>,
}

impl XpbdCloth {
    /// `frames` frames of 1/60 s from `x0` moving at `v0`, each `substeps` steps of
    /// `sweeps` sweeps: the final positions and the largest stretch |d - L| / L after any
    /// frame.
    fn run(
        &self,
        x0: &[f64],
        v0: &[f64],
        frames: u64,
        substeps: usize,
        sweeps: usize,
    ) -> (Vec<f64>, f64) {
        let (dim, w) = (self.dim, &self.w);
        let h = FRAME / substeps as f64;
        let (mut x, mut v, mut p) = (x0.to_vec(), v0.to_vec(), x0.to_vec());
        let mut stretch = 0.0_f64;
        for _ in 0..frames {
            for _ in 0..substeps {
                for k in 0..x.len() {
                    if w[k / dim] > 0.0 {
                        v[k] += h * self.g[k % dim];
                    }
                    p[k] = x[k] + h * v[k];
                }
                for _ in 0..sweeps {
                    for &(a, b, length) in &self.rods {
                        let (wa, wb) = (w[a], w[b]);
                        let mut d = [0.0; 3];
                        let mut norm = 0.0;
                        for axis in 0..dim {
                            d[axis] = p[a * dim + axis] - p[b * dim + axis];
                            norm += d[axis] * d[axis];
                        }
                        let norm = norm.sqrt();
                        let s = (norm - length) / ((wa + wb) * norm);
                        for axis in 0..dim {
                            p[a * dim + axis] -= wa * s * d[axis];
                            p[b * dim + axis] += wb * s * d[axis];
                        }
                    }
                }
                for k in 0..x.len() {
                    v[k] = (p[k] - x[k]) / h;
                    x[k] = p[k];
                }
            }
            for &(a, b, length) in &self.rods {
                let d: f64 = (0..dim)
                    .map(|axis| (x[a * dim + axis] - x[b * dim + axis]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                stretch = stretch.max((d - length).abs() / length);
            }
        }
        (x, stretch)
    }
}

/// `scenes/cloth.toml` (50 x 50 masses in 3D, 4900 rods, two pinned corners) with
/// `integrator` at `dt` (default: the scene's step, 1/60): frames of 1/60 s per
/// second, the largest rod stretch |d - L| / L after any step, the most Newton (projection)
/// iterations a step took and the energy's relative change over `duration` simulated seconds.
fn run_cloth(integrator: IntegratorKind, dt: Option<f64>, duration: f64) {
    run_scene("cloth.toml", integrator, dt, duration);
}

/// Shipped scene `name` as [`run_cloth`] runs the cloth.
fn run_scene(name: &str, integrator: IntegratorKind, dt: Option<f64>, duration: f64) {
    run_scene_solved(name, integrator, dt, duration, LinearSolver::Auto);
}

/// [`run_scene`] with the implicit form's `solver` (`Auto`: rods in paths and trees fused
/// along the rods; `Sparse`: faer's LDL^T of J W J^T, the general path).
fn run_scene_solved(
    name: &str,
    integrator: IntegratorKind,
    dt: Option<f64>,
    duration: f64,
    solver: LinearSolver,
) {
    let scene = shipped_scene(name);
    let dt = dt.or(scene.run.dt).unwrap_or(FRAME / 2.0);
    let config = SimulationConfig {
        method: Method::Implicit,
        integrator,
        dt,
        ..Default::default()
    };
    let system = Arc::clone(&scene.system);
    let formulation = Implicit::with_solver(Arc::clone(&system), Feedback::default(), solver);
    let mut sim = Simulation::with_formulation(Box::new(formulation), config).unwrap();
    let set = system.constraints();
    let mut ws = set.workspace();
    let steps = (duration / dt).round() as u64;
    let mut stretch = 0.0_f64;
    let energy_initial = sim.energy();
    let start = Instant::now();
    for _ in 0..steps {
        sim.step().unwrap_or_else(|e| panic!("{name}: {e}"));
        // C = (|d|^2 - L^2) / (2 L), so |d| = sqrt(L^2 + 2 L C).
        let c = set.residuals(sim.t(), sim.positions(), &mut ws);
        for (rows, length) in set.declared_rows() {
            if let Some(l) = length {
                let r = rows.start;
                let d = (l * l + 2.0 * l * c[r]).sqrt();
                stretch = stretch.max((d - l).abs() / l);
            }
        }
    }
    let wall = start.elapsed().as_secs_f64();
    println!();
    println!(
        "scenes/{name} ({} particles, {} rows), {} at dt = {dt:.5}, {duration:.3} s simulated{}:",
        system.particles().len(),
        set.n_rows(),
        integrator.name(),
        match solver {
            LinearSolver::Auto => String::new(),
            other => format!(", {other:?} solver"),
        }
    );
    let stats = sim.stats(wall);
    println!(
        "  frames/s {:.1}, ns/step/rod {:.1}, stretch {:.1e}, iterations per step <= {}, \
         steps retried {} (substeps <= {}), (E - E0) / |E0| {:+.1e}",
        steps as f64 * dt / FRAME / wall,
        wall * 1e9 / steps as f64 / set.n_rows() as f64,
        stretch,
        stats.newton_iterations_max.unwrap_or(0),
        stats.retried_steps,
        stats.substeps_max,
        (sim.energy() - energy_initial) / energy_initial.abs()
    );
}
