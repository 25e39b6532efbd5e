//! Fixtures shared by the physics tests: the simple pendulum, built both ways, and its
//! reference solution computed without the engine.
//!
//! The pendulum: a bead of mass MASS on a rod of length L to the origin, +y down, gravity G
//! along +y, started at angle THETA0 from the downward vertical with rate OMEGA0. Exact
//! equation: theta'' = -(g/L) sin theta (T = m L^2 theta'^2 / 2, V = -m g L cos theta).
#![allow(dead_code)] // each test file uses its own subset

use std::sync::Arc;

use bead::model::{Endpoint, System, SystemBuilder};

pub const G: f64 = 9.81;
pub const L: f64 = 1.5;
pub const MASS: f64 = 2.0;
pub const THETA0: f64 = 1.0;
pub const OMEGA0: f64 = 0.5;

/// The pendulum as a distance constraint (implicit form) and as the angle map x = L (sin
/// theta, cos theta) (parametric form).
pub fn pendulum() -> Arc<System> {
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
    b.distance("rod", bead, Endpoint::Fixed(vec![0.0, 0.0]), L)
        .unwrap();
    b.parametric(&["theta"], &[THETA0], &[OMEGA0]).unwrap();
    b.parametric_position_exprs("bead", &["L*sin(theta)", "L*cos(theta)"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// theta'' = -(g/L) sin theta by classic RK4 with step `h`, from t = 0: the bead's position
/// at every multiple of `every` steps (index 0 is t = 0). Uses nothing of the engine.
pub fn pendulum_reference_positions(h: f64, steps: u64, every: u64) -> Vec<[f64; 2]> {
    let f = |theta: f64| -(G / L) * theta.sin();
    let (mut theta, mut omega) = (THETA0, OMEGA0);
    let mut out = vec![[L * theta.sin(), L * theta.cos()]];
    for k in 1..=steps {
        let (k1q, k1v) = (omega, f(theta));
        let (k2q, k2v) = (omega + 0.5 * h * k1v, f(theta + 0.5 * h * k1q));
        let (k3q, k3v) = (omega + 0.5 * h * k2v, f(theta + 0.5 * h * k2q));
        let (k4q, k4v) = (omega + h * k3v, f(theta + h * k3q));
        theta += h / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q);
        omega += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        if k % every == 0 {
            out.push([L * theta.sin(), L * theta.cos()]);
        }
    }
    out
}

/// The reference position at `t_end`, reached in `n` RK4 steps.
pub fn pendulum_reference(t_end: f64, n: u64) -> [f64; 2] {
    let positions = pendulum_reference_positions(t_end / n as f64, n, n);
    positions[positions.len() - 1]
}

/// What the tests run: the formulation's integrator settings plus the run's length, as one
/// record (the library splits them into `SimulationConfig` and `RunOptions`).
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    pub integrator: bead::integrate::IntegratorKind,
    pub dt: f64,
    pub steps: u64,
    pub every: u64,
    pub settings: bead::integrate::IntegratorSettings,
    pub project: bool,
    /// The most substeps a retried step may take (1: no retries)
    pub max_substeps: u32,
}

impl Default for Options {
    /// rk4, dt = 1/60 s, 600 steps, every step recorded, default settings, no projection,
    /// the default retries.
    fn default() -> Self {
        Options {
            integrator: bead::integrate::IntegratorKind::Rk4,
            dt: 1.0 / 60.0,
            steps: 600,
            every: 1,
            settings: bead::integrate::IntegratorSettings::default(),
            project: false,
            max_substeps: bead::simulate::SimulationConfig::default().max_substeps,
        }
    }
}

impl Options {
    /// The simulation configuration: the tests set tolerances themselves, unscaled.
    pub fn config(&self) -> bead::simulate::SimulationConfig {
        bead::simulate::SimulationConfig {
            integrator: self.integrator,
            dt: self.dt,
            project: self.project,
            settings: self.settings,
            scaled_constraint_tolerance: false,
            max_substeps: self.max_substeps,
            ..Default::default()
        }
    }
}

/// A simulation of `formulation` as `options` say; panics when it cannot start.
pub fn simulation(
    formulation: Box<dyn bead::formulation::Formulation + Send>,
    options: &Options,
) -> bead::simulate::Simulation {
    bead::simulate::Simulation::with_formulation(formulation, options.config())
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Run `formulation` from its initial state as `options` say.
pub fn run(
    formulation: Box<dyn bead::formulation::Formulation + Send>,
    options: &Options,
    sink: &mut dyn bead::simulate::Sink,
) -> Result<bead::simulate::RunStats, bead::simulate::RunFailure> {
    run_with_progress(formulation, options, sink, &mut bead::simulate::NoProgress)
}

/// [`run`] with a progress observer.
pub fn run_with_progress(
    formulation: Box<dyn bead::formulation::Formulation + Send>,
    options: &Options,
    sink: &mut dyn bead::simulate::Sink,
    progress: &mut dyn bead::simulate::Progress,
) -> Result<bead::simulate::RunStats, bead::simulate::RunFailure> {
    let mut simulation = simulation(formulation, options);
    let run = bead::simulate::RunOptions {
        steps: options.steps,
        every: options.every,
        duration: None,
    };
    bead::simulate::run_with_progress(&mut simulation, run, sink, progress)
}

// ---------------------------------------------------------------------------------------
// Structures of many rods, for the sparse linear algebra (issue 8)

/// A hanging chain: `links` particles of unit mass at (i + 1, 0), rods of length 1, the first
/// to the origin, at rest, g = 9.81 along +y (down). Rows in parent-first order.
pub fn chain(links: usize) -> System {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let mut previous = None;
    for i in 0..links {
        let p = b
            .particle(&format!("p{i}"), 1.0, &[(i + 1) as f64, 0.0], &[0.0, 0.0])
            .unwrap();
        let end = previous.map_or(Endpoint::Fixed(vec![0.0, 0.0]), Endpoint::Particle);
        b.distance(&format!("rod {i}"), p, end, 1.0).unwrap();
        previous = Some(p);
    }
    b.build().unwrap()
}

/// Rod between particles (or to a fixed point) of the length they are apart at the start.
fn rod(b: &mut SystemBuilder, name: &str, x: &[Vec<f64>], a: usize, end: Option<usize>) {
    let (target, endpoint) = match end {
        Some(j) => (x[j].clone(), Endpoint::Particle(bead::model::ParticleId(j))),
        None => (
            vec![0.0; x[a].len()],
            Endpoint::Fixed(vec![0.0; x[a].len()]),
        ),
    };
    let length = x[a]
        .iter()
        .zip(&target)
        .map(|(p, q)| (p - q) * (p - q))
        .sum::<f64>()
        .sqrt();
    b.distance(name, bead::model::ParticleId(a), endpoint, length)
        .unwrap();
}

/// A tree of rods: a trunk of 4 links from the origin, three branches of 5 links from its
/// tip, and a twig of 3 links from the middle of the first branch (2D, masses 1 to 2).
pub fn tree() -> System {
    let mut x: Vec<Vec<f64>> = Vec::new();
    let mut rods: Vec<(usize, Option<usize>)> = Vec::new();
    let mut grow = |x: &mut Vec<Vec<f64>>, from: Option<usize>, links: usize, dir: [f64; 2]| {
        let mut parent = from;
        let mut at = from.map_or([0.0, 0.0], |p| [x[p][0], x[p][1]]);
        let mut ids = Vec::new();
        for _ in 0..links {
            at = [at[0] + dir[0], at[1] + dir[1]];
            x.push(at.to_vec());
            let id = x.len() - 1;
            rods.push((id, parent));
            parent = Some(id);
            ids.push(id);
        }
        ids
    };
    let trunk = grow(&mut x, None, 4, [0.9, 0.4]);
    let tip = *trunk.last().unwrap();
    let first = grow(&mut x, Some(tip), 5, [0.8, -0.5]);
    grow(&mut x, Some(tip), 5, [1.0, 0.1]);
    grow(&mut x, Some(tip), 5, [0.3, 0.9]);
    grow(&mut x, Some(first[2]), 3, [-0.2, 0.95]);
    let mut b = SystemBuilder::new(&[0.0, G]);
    for (i, p) in x.iter().enumerate() {
        let mass = 1.0 + (i % 3) as f64 * 0.5;
        b.particle(&format!("n{i}"), mass, p, &[0.0, 0.0]).unwrap();
    }
    for (k, &(a, end)) in rods.iter().enumerate() {
        rod(&mut b, &format!("rod {k}"), &x, a, end);
    }
    b.build().unwrap()
}

/// A closed ring of `n` rods (a regular polygon of radius 2, slightly squashed), one of its
/// particles pinned (2D).
pub fn ring(n: usize) -> System {
    let x: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let angle = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
            vec![2.0 * angle.cos(), 1.5 * angle.sin() + 3.0]
        })
        .collect();
    let mut b = SystemBuilder::new(&[0.0, G]);
    for (i, p) in x.iter().enumerate() {
        b.particle(&format!("r{i}"), 1.0, p, &[0.0, 0.0]).unwrap();
    }
    for i in 0..n {
        rod(&mut b, &format!("rod {i}"), &x, i, Some((i + 1) % n));
    }
    b.pin("top", bead::model::ParticleId(0), &x[0]).unwrap();
    b.build().unwrap()
}

/// A cloth patch in 3D: `rows` x `cols` particles on a curved sheet (z = 0.1 (c - cols/2)^2, so
/// that no line of rods is straight), structural rods between grid neighbours, the two top
/// corners pinned.
pub fn cloth(rows: usize, cols: usize) -> System {
    let at = |r: usize, c: usize| {
        let u = c as f64 - cols as f64 / 2.0;
        vec![
            c as f64 * 0.5,
            r as f64 * 0.5,
            0.1 * u * u + 0.05 * r as f64,
        ]
    };
    let x: Vec<Vec<f64>> = (0..rows)
        .flat_map(|r| (0..cols).map(move |c| at(r, c)))
        .collect();
    let mut b = SystemBuilder::new(&[0.0, G, 0.0]);
    for (i, p) in x.iter().enumerate() {
        b.particle(&format!("c{i}"), 0.2, p, &[0.0, 0.0, 0.0])
            .unwrap();
    }
    let id = |r: usize, c: usize| r * cols + c;
    for r in 0..rows {
        for c in 0..cols {
            if c + 1 < cols {
                rod(
                    &mut b,
                    &format!("h{r}.{c}"),
                    &x,
                    id(r, c),
                    Some(id(r, c + 1)),
                );
            }
            if r + 1 < rows {
                rod(
                    &mut b,
                    &format!("v{r}.{c}"),
                    &x,
                    id(r, c),
                    Some(id(r + 1, c)),
                );
            }
        }
    }
    b.pin(
        "left corner",
        bead::model::ParticleId(id(0, 0)),
        &x[id(0, 0)],
    )
    .unwrap();
    b.pin(
        "right corner",
        bead::model::ParticleId(id(0, cols - 1)),
        &x[id(0, cols - 1)],
    )
    .unwrap();
    b.build().unwrap()
}

/// A deterministic generator of uniform numbers in [-1/2, 1/2).
pub struct Random(pub u64);

impl Random {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}

/// The article's parabola with its release point x0 and gravity g as parameters, and a
/// `mass` that a member can make invalid.
pub const PARABOLA_SWEPT: &str = r#"
[params]
g = 500.0
x0 = 150.0
mass = 1.0
[world]
gravity = [0.0, "g"]
[[particle]]
name = "bead"
mass = "mass"
position = ["x0", "-x0^2/100"]
[[constraint]]
expr = "bead.x^2 + 100*bead.y"
[parametric]
coordinates = ["q"]
initial = ["x0"]
[parametric.positions]
bead = ["q", "-q^2/100"]
"#;
