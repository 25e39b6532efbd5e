//! What a panel draws besides the particles: the view box and the curves.
//!
//! Curves are made on the server and sent as polylines of points with the scene's `dim`
//! coordinates each:
//! - implicit 2D constraints on a single particle are contoured by marching squares over the
//!   view box, for systems of at most 16 constraint rows; pins are not (the page draws them);
//! - a parametric form with one coordinate is sampled along x(q) (clipped to the view box in
//!   2D; whole in 3D, where the page projects it).
//!
//! A curve that depends on t (a driven constraint C(x, t) = 0 or a moving map x(q, t)) is
//! [`Curves::moving`]: the panel makes it again for every frame at the frame's t, at
//! [`Resolution::Frame`] (coarser: it is paid 60 times a second), so that the bead is drawn on
//! the curve it is on now, never on the curve of t = 0.
//!
//! A parametric panel with one coordinate draws its map; otherwise contours are drawn when
//! there are any, else the map.
//!
//! Curves follow the motion: a map is sampled over an interval of q ([`Curves::q_range`])
//! that [`follow_range`] widens when the bead comes near its end (a bead sliding down a
//! helix), and contours and 2D maps are made again over the region the page shows when it
//! pans or zooms past the region they were made over (`set_view`).

use std::sync::Arc;
use std::time::Duration;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::{DeclaredConstraint, Endpoint, System};
use bead::simulate::{Simulation, SimulationConfig};

use crate::clock::Stopwatch;

/// Marching-squares resolution per side, for curves made once.
pub const GRID: usize = 160;
/// Marching-squares resolution per side, for moving curves made every frame.
pub const FRAME_GRID: usize = 72;
/// Systems with more constraint rows than this get no contours.
const MAX_CONTOUR_ROWS: usize = 16;
/// Samples along a parametric curve made once.
const PARAMETRIC_SAMPLES: usize = 1200;
/// Samples along a moving parametric curve made every frame.
pub const FRAME_PARAMETRIC_SAMPLES: usize = 120;

/// How finely to make curves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Resolution {
    /// Once per scene or curve edit: [`GRID`] cells a side, 1200 samples along a map.
    Scene,
    /// Every frame, for a moving curve: [`FRAME_GRID`] cells a side, [`FRAME_PARAMETRIC_SAMPLES`]
    /// samples along a map (frame bytes and compute are paid 60 times a second).
    Frame,
}

impl Resolution {
    fn grid(self) -> usize {
        match self {
            Resolution::Scene => GRID,
            Resolution::Frame => FRAME_GRID,
        }
    }
    fn samples(self) -> usize {
        match self {
            Resolution::Scene => PARAMETRIC_SAMPLES,
            Resolution::Frame => FRAME_PARAMETRIC_SAMPLES,
        }
    }
}

/// A panel's curves.
#[derive(Clone, Debug, PartialEq)]
pub struct Curves {
    /// Polylines, `dim` numbers a point (contours: 2D scenes only).
    pub lines: Vec<Vec<f64>>,
    /// How they were made: `"contour"`, `"parametric"` or `"none"`.
    pub source: &'static str,
    /// They depend on t: a driven constraint row was contoured, or the map x(q, t) moves.
    pub moving: bool,
    /// The interval of q a one-coordinate map was sampled over (`source == "parametric"`).
    pub q_range: Option<[f64; 2]>,
}

/// A map's sampled interval grows at most to this many times its first width
/// ([`default_q_range`]); beyond, it becomes a window of that width around the bead.
pub const MAX_Q_RANGE_FACTOR: f64 = 16.0;

/// The interval of q a one-coordinate map is first sampled over: q0 +- max(3 |q0|, 2 pi).
pub fn default_q_range(system: &System) -> Option<[f64; 2]> {
    let map = system.parametric().filter(|m| m.n_q() == 1)?;
    let q0 = map.initial()[0];
    let span = (3.0 * q0.abs()).max(2.0 * std::f64::consts::PI);
    Some([q0 - span, q0 + span])
}

/// The interval to sample a map over now that the bead is at `q`, when `range` no longer
/// does: `None` while q is inside `range` by more than a tenth of its width. Else the side q
/// is near moves to half a width beyond q; an interval wider than `max_width` becomes a
/// window of that width centered on q (a bead sliding on forever is drawn on its wire, and
/// the work per sample stays bounded).
pub fn follow_range(q: f64, range: [f64; 2], max_width: f64) -> Option<[f64; 2]> {
    let [lo, hi] = range;
    let width = hi - lo;
    if !(q.is_finite() && width > 0.0) {
        return None;
    }
    let margin = 0.1 * width;
    if q > lo + margin && q < hi - margin {
        return None;
    }
    let (mut lo, mut hi) = (lo.min(q - 0.5 * width), hi.max(q + 0.5 * width));
    if hi - lo > max_width {
        if q < 0.5 * (lo + hi) {
            hi = lo + max_width;
        } else {
            lo = hi - max_width;
        }
        if !(q > lo + 0.1 * max_width && q < hi - 0.1 * max_width) {
            (lo, hi) = (q - 0.5 * max_width, q + 0.5 * max_width);
        }
    }
    Some([lo, hi])
}

/// The q in `range` (to 1/512 of its width) whose map positions at `t` are nearest `x` (all
/// particles): where on a drawn map an implicit panel's bead is.
pub fn nearest_q(system: &System, range: [f64; 2], x: &[f64], t: f64) -> Option<f64> {
    const SAMPLES: usize = 512;
    let map = system.parametric().filter(|m| m.n_q() == 1)?;
    let mut ws = map.workspace();
    let mut best = (f64::INFINITY, None);
    for i in 0..=SAMPLES {
        let q = range[0] + (range[1] - range[0]) * i as f64 / SAMPLES as f64;
        map.state_at(t, &[q], &[0.0], &mut ws);
        let d: f64 = ws
            .position
            .iter()
            .zip(x)
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        if d < best.0 {
            best = (d, Some(q));
        }
    }
    best.1
}

/// Systems up to this many particles and constraint rows get a trial run for their view box:
/// a step of such a system costs microseconds (a dense solve of at most 64 rows), so the run's
/// time budget bounds its work. Larger systems get the reach bound instead.
pub const TRIAL_MAX_PARTICLES: usize = 64;
/// See [`TRIAL_MAX_PARTICLES`].
pub const TRIAL_MAX_ROWS: usize = 64;

/// The view box `[x_min, y_min, x_max, y_max]` of a scene: its initial positions, `extra`
/// points (anchors), and where the particles may go:
/// - small systems (at most [`TRIAL_MAX_PARTICLES`] particles and [`TRIAL_MAX_ROWS`]
///   constraint rows): the motion of a short trial run (parametric form when there is one
///   that satisfies the constraints, else implicit from the state moved onto them; rk4 at `dt`; at most `duration` simulated seconds, 20000 steps, 150 ms);
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
    fn grow(bounds: &mut [f64; 4], x: f64, y: f64) {
        if x.is_finite() && y.is_finite() && x.abs() < 1e12 && y.abs() < 1e12 {
            bounds[0] = bounds[0].min(x);
            bounds[1] = bounds[1].min(y);
            bounds[2] = bounds[2].max(x);
            bounds[3] = bounds[3].max(y);
        }
    }
    let mut include = |x: f64, y: f64| grow(&mut bounds, x, y);
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
    // A closed curve is shown whole (the circle of a pendulum with its center, the pivot),
    // when it closes within twice the box so far.
    if system.dim() == 2 {
        for [x, y] in closed_curve_points(system, bounds) {
            grow(&mut bounds, x, y);
        }
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

/// The points of the contours at t = 0 over `bounds` doubled about its center, when none of
/// them comes within two cells of that region's border (every contour closes inside it);
/// else none. Only for systems that get contours.
fn closed_curve_points(system: &System, bounds: [f64; 4]) -> Vec<[f64; 2]> {
    let (w, h) = (bounds[2] - bounds[0], bounds[3] - bounds[1]);
    let size = w.max(h).max(1e-9);
    let (cx, cy) = (0.5 * (bounds[0] + bounds[2]), 0.5 * (bounds[1] + bounds[3]));
    // A square around the box: a circle through a short arc has its center a radius away.
    let region = [cx - size, cy - size, cx + size, cy + size];
    let lines = contour_curves(system, region, 0.0, Resolution::Frame.grid());
    // contour_curves pads the region by 10% a side; a contour that reaches that border
    // runs on outside it.
    let (pad_w, pad_h) = (1.2 * (region[2] - region[0]), 1.2 * (region[3] - region[1]));
    let cell = 2.0 * pad_w.max(pad_h) / Resolution::Frame.grid() as f64;
    let (x_min, y_min) = (
        region[0] - 0.1 * (region[2] - region[0]),
        region[1] - 0.1 * (region[3] - region[1]),
    );
    let mut points = Vec::new();
    for line in &lines {
        for p in line.chunks(2) {
            let near_border = p[0] - x_min < cell
                || x_min + pad_w - p[0] < cell
                || p[1] - y_min < cell
                || y_min + pad_h - p[1] < cell;
            if near_border {
                return Vec::new();
            }
            points.push([p[0], p[1]]);
        }
    }
    points
}

/// Include every position of a short trial run (see [`view_box`]).
fn trial_run(system: &Arc<System>, dt: f64, duration: f64, include: &mut impl FnMut(f64, f64)) {
    let dim = system.dim();
    // The map, when it stands for the constraints (not after a curve edit).
    let method = match system.parametric() {
        Some(map)
            if system.constraints().n_rows() == 0
                || map_satisfies_constraints(system, map, 0.0) =>
        {
            Method::Parametric
        }
        _ => Method::Implicit,
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
    // From the state the panels start from: on the constraints (an edited curve may not pass
    // through the scene's initial state).
    if simulation.reset_onto_constraints().is_err() {
        return;
    }
    let steps = (duration / dt).ceil().clamp(1.0, 20_000.0) as u64;
    let start = Stopwatch::start();
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

/// The curves of a panel at time `t` (see the module doc): the map for a parametric panel
/// with one coordinate, else the contours when there are any, else the map when it has one
/// coordinate. Contours over `view` (padded by 10% a side); a map over `q_range` (default
/// [`default_q_range`]), clipped to `view` padded by 20% a side in 2D.
pub fn curves(
    system: &System,
    method: Method,
    view: [f64; 4],
    q_range: Option<[f64; 2]>,
    t: f64,
    resolution: Resolution,
) -> Curves {
    let map = system.parametric().filter(|m| m.n_q() == 1);
    let parametric = |map: &bead::model::ParametricMap| {
        let first = default_q_range(system).unwrap_or([-1.0, 1.0]);
        let range = q_range.unwrap_or(first);
        // As many samples per unit of q as over the first interval, up to the widest one.
        let widths = ((range[1] - range[0]) / (first[1] - first[0]))
            .ceil()
            .clamp(1.0, MAX_Q_RANGE_FACTOR);
        Curves {
            lines: parametric_curves(
                system,
                view,
                range,
                t,
                resolution.samples() * widths as usize,
            ),
            source: "parametric",
            moving: map.is_time_dependent(),
            q_range: Some(range),
        }
    };
    if let (Method::Parametric, Some(map)) = (method, map) {
        return parametric(map);
    }
    if system.dim() == 2 {
        let lines = contour_curves(system, view, t, resolution.grid());
        if !lines.is_empty() {
            let set = system.constraints();
            return Curves {
                lines,
                source: "contour",
                moving: contoured_rows(system).any(|row| set.is_time_dependent(row)),
                q_range: None,
            };
        }
    }
    match map {
        // The map stands for the implicit form only where it satisfies its constraints (a
        // curve edit changes the constraints, not the map).
        Some(map) if map_satisfies_constraints(system, map, t) => parametric(map),
        _ => Curves {
            lines: Vec::new(),
            source: "none",
            moving: false,
            q_range: None,
        },
    }
}

/// Whether the map's positions at its initial q and at q + 1 (every coordinate) satisfy the
/// implicit constraints at `t` (to 1e-6 relative to the positions' size squared).
fn map_satisfies_constraints(system: &System, map: &bead::model::ParametricMap, t: f64) -> bool {
    let set = system.constraints();
    let mut ws = set.workspace();
    let mut map_ws = map.workspace();
    let q0 = map.initial().to_vec();
    let q1: Vec<f64> = q0.iter().map(|q| q + 1.0).collect();
    let rates = vec![0.0; q0.len()];
    [q0, q1].iter().all(|q| {
        map.state_at(t, q, &rates, &mut map_ws);
        let size = map_ws.position.iter().fold(1.0f64, |m, v| m.max(v.abs()));
        set.max_abs_residual(t, &map_ws.position, &mut ws) <= 1e-6 * size * size
    })
}

/// Sample x(q) of a one-coordinate parametric map over `range`, one polyline per particle,
/// broken where it leaves the (padded) view box.
fn parametric_curves(
    system: &System,
    view: [f64; 4],
    range: [f64; 2],
    t: f64,
    samples: usize,
) -> Vec<Vec<f64>> {
    let Some(map) = system.parametric() else {
        return Vec::new();
    };
    let dim = system.dim();
    let (w, h) = (view[2] - view[0], view[3] - view[1]);
    // 3D curves are sent whole: the page projects them, and the view box is x-y only.
    let inside = |x: f64, y: f64| {
        dim == 3
            || x >= view[0] - 0.2 * w
                && x <= view[2] + 0.2 * w
                && y >= view[1] - 0.2 * h
                && y <= view[3] + 0.2 * h
    };
    let mut ws = map.workspace();
    let n_particles = system.particles().len();
    let mut lines: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new()]; n_particles];
    for i in 0..=samples {
        let q = range[0] + (range[1] - range[0]) * i as f64 / samples as f64;
        map.state_at(t, &[q], &[0.0], &mut ws);
        for (p, particle_lines) in lines.iter_mut().enumerate() {
            let point = &ws.position[p * dim..(p + 1) * dim];
            let finite = point.iter().all(|v| v.is_finite() && v.abs() < 1e12);
            let current = particle_lines.last_mut();
            match current {
                Some(line) if finite && inside(point[0], point[1]) => {
                    line.extend_from_slice(point);
                }
                Some(line) if !line.is_empty() => particle_lines.push(Vec::new()),
                _ => {}
            }
        }
    }
    lines
        .into_iter()
        .flatten()
        .filter(|l| l.len() >= 2 * dim)
        .collect()
}

/// The constraint rows that are contoured: rows on a single particle that are not a pin's
/// (a pin's rows are lines through its point: the page draws the pin itself instead). None
/// for systems of more than [`MAX_CONTOUR_ROWS`] rows: each grid point evaluates every row.
fn contoured_rows(system: &System) -> impl Iterator<Item = usize> + '_ {
    let dim = system.dim();
    let set = system.constraints();
    let pins: Vec<&str> = system
        .declared_constraints()
        .into_iter()
        .filter_map(|c| match c {
            DeclaredConstraint::Pin { name, .. } => Some(name),
            _ => None,
        })
        .collect();
    let rows = if set.n_rows() > MAX_CONTOUR_ROWS {
        0
    } else {
        set.n_rows()
    };
    (0..rows).filter(move |&row| {
        if pins.contains(&set.name_of_row(row)) {
            return false;
        }
        let columns = set.row_columns(row);
        match columns.first() {
            Some(&first) => columns.iter().all(|&c| c / dim == first / dim),
            None => false,
        }
    })
}

/// Marching squares at time `t` of every contoured row (see [`contoured_rows`]) on a `grid`
/// x `grid` grid over `view` padded by 10% a side. Segments come as 2-point polylines.
fn contour_curves(system: &System, view: [f64; 4], t: f64, grid: usize) -> Vec<Vec<f64>> {
    let dim = system.dim();
    let set = system.constraints();
    let (x0, _) = system.initial_particle_state();
    let mut ws = set.workspace();
    let mut out = Vec::new();
    let (w, h) = (view[2] - view[0], view[3] - view[1]);
    let (x_min, y_min) = (view[0] - 0.1 * w, view[1] - 0.1 * h);
    let (dx, dy) = (1.2 * w / grid as f64, 1.2 * h / grid as f64);
    let rows: Vec<usize> = contoured_rows(system).collect();
    for row in rows {
        let particle = set.row_columns(row)[0] / dim;
        let mut x = x0.clone();
        let mut values = vec![0.0; (grid + 1) * (grid + 1)];
        for j in 0..=grid {
            for i in 0..=grid {
                x[particle * dim] = x_min + i as f64 * dx;
                x[particle * dim + 1] = y_min + j as f64 * dy;
                values[j * (grid + 1) + i] = set.residuals(t, &x, &mut ws)[row];
            }
        }
        let value = |i: usize, j: usize| values[j * (grid + 1) + i];
        for j in 0..grid {
            for i in 0..grid {
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
