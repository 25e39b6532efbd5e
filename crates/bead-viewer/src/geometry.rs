//! What a panel draws that does not move: the view box and the curves.
//!
//! Curves are made on the server, once per scene or curve change, and sent as polylines:
//! - implicit 2D constraints on a single particle are contoured by marching squares on a
//!   [`GRID`] x [`GRID`] grid over the view box (other particles at their initial positions,
//!   t = 0), for systems of at most 16 constraint rows; pins are not (the page draws them);
//! - a parametric form with one coordinate is sampled along x(q) and clipped to the view box.
//!
//! A parametric panel with one coordinate draws its map; otherwise contours are drawn when
//! there are any, else the map (3D scenes, projected onto x-y).

use std::sync::Arc;
use std::time::{Duration, Instant};

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::{DeclaredConstraint, Endpoint, System};
use bead::simulate::{Simulation, SimulationConfig};

/// Marching-squares resolution per side.
pub const GRID: usize = 160;
/// Systems with more constraint rows than this get no contours.
const MAX_CONTOUR_ROWS: usize = 16;
/// Samples along a parametric curve.
const PARAMETRIC_SAMPLES: usize = 1200;

/// Systems up to this many particles and constraint rows get a trial run for their view box:
/// a step of such a system costs microseconds (a dense solve of at most 64 rows), so the run's
/// time budget bounds its work. Larger systems get the reach bound instead.
pub const TRIAL_MAX_PARTICLES: usize = 64;
/// See [`TRIAL_MAX_PARTICLES`].
pub const TRIAL_MAX_ROWS: usize = 64;

/// The view box `[x_min, y_min, x_max, y_max]` of a scene: its initial positions, `extra`
/// points (anchors), and where the particles may go:
/// - small systems (at most [`TRIAL_MAX_PARTICLES`] particles and [`TRIAL_MAX_ROWS`]
///   constraint rows): the motion of a short trial run (parametric form when there is one,
///   else implicit; rk4 at `dt`; at most `duration` simulated seconds, 20000 steps, 150 ms);
/// - larger ones, with no trial run (work linear in the particles and constraints): every
///   place that rods and pins let a particle reach, see [`reach`]. Particles not held to a
///   fixed point by rods and pins count at their initial positions only.
pub fn view_box(system: &Arc<System>, dt: f64, duration: f64, extra: &[[f64; 2]]) -> [f64; 4] {
    let dim = system.dim();
    let mut bounds = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let mut include = |x: f64, y: f64| {
        if x.is_finite() && y.is_finite() && x.abs() < 1e12 && y.abs() < 1e12 {
            bounds[0] = bounds[0].min(x);
            bounds[1] = bounds[1].min(y);
            bounds[2] = bounds[2].max(x);
            bounds[3] = bounds[3].max(y);
        }
    };
    let (x0, _) = system.initial_particle_state();
    for p in x0.chunks(dim) {
        include(p[0], p[1]);
    }
    for a in extra {
        include(a[0], a[1]);
    }
    let small = system.particles().len() <= TRIAL_MAX_PARTICLES
        && system.constraints().n_rows() <= TRIAL_MAX_ROWS;
    if small {
        trial_run(system, dt, duration, &mut include);
    } else {
        for (center, radius) in reach(system).into_iter().flatten() {
            include(center[0] - radius, center[1] - radius);
            include(center[0] + radius, center[1] + radius);
        }
    }
    if !bounds[0].is_finite() {
        return [-1.0, -1.0, 1.0, 1.0];
    }
    let (w, h) = (bounds[2] - bounds[0], bounds[3] - bounds[1]);
    let size = w.max(h);
    let size = if size > 1e-9 {
        size
    } else {
        bounds[0].abs().max(bounds[1].abs()).max(1.0)
    };
    // Pad by 15% of the larger side, and make the smaller side at least 40% of it so that a
    // flat motion still shows its curve around it.
    let pad = 0.15 * size;
    let (cx, cy) = (0.5 * (bounds[0] + bounds[2]), 0.5 * (bounds[1] + bounds[3]));
    let half_w = 0.5 * w.max(0.4 * size) + pad;
    let half_h = 0.5 * h.max(0.4 * size) + pad;
    [cx - half_w, cy - half_h, cx + half_w, cy + half_h]
}

/// Include every position of a short trial run (see [`view_box`]).
fn trial_run(system: &Arc<System>, dt: f64, duration: f64, include: &mut impl FnMut(f64, f64)) {
    let dim = system.dim();
    let method = if system.parametric().is_some() {
        Method::Parametric
    } else {
        Method::Implicit
    };
    let config = SimulationConfig {
        method,
        integrator: IntegratorKind::Rk4,
        dt,
        ..SimulationConfig::default()
    };
    let Ok(mut simulation) = Simulation::new(Arc::clone(system), config) else {
        return;
    };
    let steps = (duration / dt).ceil().clamp(1.0, 20_000.0) as u64;
    let start = Instant::now();
    for _ in 0..steps {
        if simulation.step().is_err() {
            break;
        }
        for p in simulation.positions().chunks(dim) {
            include(p[0], p[1]);
        }
        if start.elapsed() > Duration::from_millis(150) {
            break;
        }
    }
}

/// For each particle held to a fixed point by a path of rods (distance constraints) and pins,
/// a disc `(center, radius)` in x-y that it cannot leave: a fixed point it is held to and
/// the shortest length of rods between them (a pinned particle: its pin and 0; a rod to an
/// anchor: the anchor and the rod's length). Shortest paths from every fixed point at once
/// (Dijkstra), so the work is O((n + m) log n) for n particles and m constraints. `None`
/// for particles held by nothing fixed (free, or only by expression constraints).
pub fn reach(system: &System) -> Vec<Option<([f64; 2], f64)>> {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;

    let n = system.particles().len();
    let mut best: Vec<Option<([f64; 2], f64)>> = vec![None; n];
    let mut edges: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
    let seed = |best: &mut Vec<Option<([f64; 2], f64)>>, p: usize, at: &[f64], d: f64| {
        if p < n && at.len() >= 2 && d.is_finite() && best[p].is_none_or(|(_, r)| d < r) {
            best[p] = Some(([at[0], at[1]], d));
        }
    };
    for c in system.declared_constraints() {
        match c {
            DeclaredConstraint::Pin {
                particle, anchor, ..
            } => seed(&mut best, particle.0, anchor, 0.0),
            DeclaredConstraint::Distance { a, b, length, .. } => match b {
                Endpoint::Fixed(point) => seed(&mut best, a.0, point, length.abs()),
                Endpoint::Particle(b) => {
                    if a.0 < n && b.0 < n && length.is_finite() {
                        edges[a.0].push((b.0, length.abs()));
                        edges[b.0].push((a.0, length.abs()));
                    }
                }
            },
            _ => {}
        }
    }
    // Non-negative f64 order as their bits.
    let key = |d: f64| Reverse(d.to_bits());
    let mut queue: BinaryHeap<(Reverse<u64>, usize)> = best
        .iter()
        .enumerate()
        .filter_map(|(p, b)| b.map(|(_, d)| (key(d), p)))
        .collect();
    while let Some((Reverse(bits), p)) = queue.pop() {
        let Some((center, d)) = best[p] else {
            continue;
        };
        if d.to_bits() != bits {
            continue; // an outdated entry
        }
        for &(q, length) in &edges[p] {
            let through = d + length;
            if best[q].is_none_or(|(_, r)| through < r) {
                best[q] = Some((center, through));
                queue.push((key(through), q));
            }
        }
    }
    best
}

/// The curves of a panel and how they were made (`"contour"`, `"parametric"`, `"none"`).
pub fn curves(system: &System, method: Method, view: [f64; 4]) -> (Vec<Vec<f64>>, String) {
    let one_coordinate = system.parametric().is_some_and(|m| m.n_q() == 1);
    if method == Method::Parametric && one_coordinate {
        return (parametric_curves(system, view), "parametric".into());
    }
    let contours = if system.dim() == 2 {
        contour_curves(system, view)
    } else {
        Vec::new()
    };
    if !contours.is_empty() {
        return (contours, "contour".into());
    }
    if one_coordinate {
        return (parametric_curves(system, view), "parametric".into());
    }
    (Vec::new(), "none".into())
}

/// Sample x(q) of a one-coordinate parametric map, one polyline per particle, broken where
/// it leaves the (padded) view box.
fn parametric_curves(system: &System, view: [f64; 4]) -> Vec<Vec<f64>> {
    let Some(map) = system.parametric() else {
        return Vec::new();
    };
    let dim = system.dim();
    let q0 = map.initial()[0];
    let span = (3.0 * q0.abs()).max(2.0 * std::f64::consts::PI);
    let (w, h) = (view[2] - view[0], view[3] - view[1]);
    let inside = |x: f64, y: f64| {
        x >= view[0] - 0.2 * w
            && x <= view[2] + 0.2 * w
            && y >= view[1] - 0.2 * h
            && y <= view[3] + 0.2 * h
    };
    let mut ws = map.workspace();
    let n_particles = system.particles().len();
    let mut lines: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new()]; n_particles];
    for i in 0..=PARAMETRIC_SAMPLES {
        let q = q0 - span + 2.0 * span * i as f64 / PARAMETRIC_SAMPLES as f64;
        map.state_at(0.0, &[q], &[0.0], &mut ws);
        for (p, particle_lines) in lines.iter_mut().enumerate() {
            let (x, y) = (ws.position[p * dim], ws.position[p * dim + 1]);
            let current = particle_lines.last_mut();
            match current {
                Some(line) if x.is_finite() && y.is_finite() && inside(x, y) => {
                    line.push(x);
                    line.push(y);
                }
                Some(line) if !line.is_empty() => particle_lines.push(Vec::new()),
                _ => {}
            }
        }
    }
    lines
        .into_iter()
        .flatten()
        .filter(|l| l.len() >= 4)
        .collect()
}

/// Marching squares of every 2D constraint row that involves a single particle. Segments
/// come as 2-point polylines.
fn contour_curves(system: &System, view: [f64; 4]) -> Vec<Vec<f64>> {
    let dim = system.dim();
    let set = system.constraints();
    let (x0, _) = system.initial_particle_state();
    let mut ws = set.workspace();
    let mut out = Vec::new();
    let (w, h) = (view[2] - view[0], view[3] - view[1]);
    let (x_min, y_min) = (view[0] - 0.1 * w, view[1] - 0.1 * h);
    let (dx, dy) = (1.2 * w / GRID as f64, 1.2 * h / GRID as f64);
    if set.n_rows() > MAX_CONTOUR_ROWS {
        // Each grid point evaluates every row: too costly for large systems.
        return out;
    }
    // A pin's rows are lines through its point: the page draws the pin itself instead.
    let pins: Vec<&str> = system
        .declared_constraints()
        .into_iter()
        .filter_map(|c| match c {
            DeclaredConstraint::Pin { name, .. } => Some(name),
            _ => None,
        })
        .collect();
    for row in 0..set.n_rows() {
        if pins.contains(&set.info_of_row(row).name.as_str()) {
            continue;
        }
        let columns = set.row_columns(row);
        let Some(&first) = columns.first() else {
            continue;
        };
        let particle = first / dim;
        if columns.iter().any(|&c| c / dim != particle) {
            continue;
        }
        let mut x = x0.clone();
        let mut values = vec![0.0; (GRID + 1) * (GRID + 1)];
        for j in 0..=GRID {
            for i in 0..=GRID {
                x[particle * dim] = x_min + i as f64 * dx;
                x[particle * dim + 1] = y_min + j as f64 * dy;
                values[j * (GRID + 1) + i] = set.residuals(0.0, &x, &mut ws)[row];
            }
        }
        let value = |i: usize, j: usize| values[j * (GRID + 1) + i];
        for j in 0..GRID {
            for i in 0..GRID {
                // Corners counter-clockwise from (i, j).
                let corners = [
                    (i, j, value(i, j)),
                    (i + 1, j, value(i + 1, j)),
                    (i + 1, j + 1, value(i + 1, j + 1)),
                    (i, j + 1, value(i, j + 1)),
                ];
                if corners.iter().any(|c| !c.2.is_finite()) {
                    continue;
                }
                let mut points = Vec::with_capacity(4);
                for e in 0..4 {
                    let (a, b) = (corners[e], corners[(e + 1) % 4]);
                    if (a.2 < 0.0) != (b.2 < 0.0) {
                        let s = a.2 / (a.2 - b.2);
                        let px = x_min + (a.0 as f64 + s * (b.0 as f64 - a.0 as f64)) * dx;
                        let py = y_min + (a.1 as f64 + s * (b.1 as f64 - a.1 as f64)) * dy;
                        points.push((px, py));
                    }
                }
                if points.len() == 2 {
                    out.push(vec![points[0].0, points[0].1, points[1].0, points[1].1]);
                } else if points.len() == 4 {
                    out.push(vec![points[0].0, points[0].1, points[1].0, points[1].1]);
                    out.push(vec![points[2].0, points[2].1, points[3].0, points[3].1]);
                }
            }
        }
    }
    out
}
