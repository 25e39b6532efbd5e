//! Chains and trees of rods solved in one pass: the rows' values, the Newton matrix's
//! entries, the elimination and the correction W J^T z, fused along the rods. Paths below;
//! trees (a particle on three rods or more) in `tree.rs`, with the same per-rod arithmetic.
//!
//! When every row is a rod, C_p = (|e_p|^2 - L_p^2) / (2 L_p) with e_p = x_a - x_b (x_b a
//! fixed point or a particle), and the rows couple in paths ([`PathOrder`]), the matrices of
//! a constrained step are tridiagonal in path order and their entries are dot products of
//! rod vectors. With J_p(x) = +-e_p(x)^T / L_p on a's and b's coordinates and x, y two
//! configurations:
//!
//! ```text
//! A_pp     = J_p(x) W J_p(y)^T     = sum_k e_p,k(x) e_p,k(y) (w_a,k + w_b,k) / L_p^2
//! A_p,p-1  = J_p(x) W J_p-1(y)^T   = s_p sum_k e_p,k(x) w_s,k e_p-1,k(y) / (L_p L_p-1)
//! A_p-1,p  = J_p-1(x) W J_p(y)^T   = s_p sum_k e_p-1,k(x) w_s,k e_p,k(y) / (L_p L_p-1)
//! ```
//!
//! where s is the particle rods p - 1 and p share and s_p = +1 when it has the same role (a
//! or b) in both, -1 otherwise. RATTLE's exact Newton matrix is x = q^k, y = q_n (the
//! unsymmetric J(q^k) W J(q_n)^T); the velocity projection's is x = y = q_{n+1} (symmetric
//! positive definite). One forward sweep computes the entries and eliminates
//! (u_p = A_pp - m_p A_p-1,p, m_p = A_p,p-1 / u_p-1); one backward sweep substitutes and
//! applies z_p's correction -W J_p(y)^T z_p to the two particles of rod p. No Jacobian, no
//! assembled matrix, no permutation array is written: the work of the hand-written chain.

mod tree;

use super::{max_nan, PathOrder, Singular, RELATIVE_PIVOT_TOLERANCE};
use crate::model::DistanceRow;
use tree::TreeElimination;

/// `Rod::shared` at the start of a path; with [`ANCHORED`], `Rod::b` of a rod to a fixed
/// point.
const FIXED: u32 = u32::MAX;
/// The flag of `Rod::b` that marks a rod to a fixed point; the other bits index
/// `RodPath::anchors`.
const ANCHORED: u32 = 1 << 31;

/// One rod at its place in the path (32 bytes: the sweeps stream through these; indices
/// are 32-bit, so a system with 2^31 coordinates or more takes the general path).
#[derive(Clone, Debug, PartialEq)]
struct Rod {
    /// Its row of C
    row: u32,
    /// First coordinate of particle a
    a: u32,
    /// First coordinate of particle b or, with [`ANCHORED`], the index of the rod's fixed
    /// point in `RodPath::anchors`
    b: u32,
    /// The first coordinate of the particle it shares with the rod before it in the path,
    /// [`FIXED`] at the start of a path
    shared: u32,
    inverse_length: f64,
    /// s_p / (L_p L_p-1) (module documentation); 0 at the start of a path
    link: f64,
}

impl Rod {
    #[inline(always)]
    fn row(&self) -> usize {
        self.row as usize
    }

    #[inline(always)]
    fn a(&self) -> usize {
        self.a as usize
    }

    /// Particle b's first coordinate, `None` for a fixed point.
    #[inline(always)]
    fn b(&self) -> Option<usize> {
        (self.b & ANCHORED == 0).then_some(self.b as usize)
    }

    /// The shared particle's first coordinate, `None` at the start of a path.
    #[inline(always)]
    fn shared(&self) -> Option<usize> {
        (self.shared != FIXED).then_some(self.shared as usize)
    }

    /// The point b: particle b's coordinates in `x`, or the rod's fixed point.
    #[inline(always)]
    fn b_coordinate(&self, anchors: &[[f64; 3]], x: &[f64], k: usize) -> f64 {
        match self.b() {
            Some(b) => x[b + k],
            None => anchors[(self.b & !ANCHORED) as usize][k],
        }
    }
}

/// The rods of a constraint set whose rows are all distances coupled in paths or trees (no
/// ring), with the scratch space of their fused solves (O(m) for paths and for trees of
/// bounded degree, allocated once). See the module documentation.
///
/// ```
/// use bead::linalg::{RodPath, PathOrder, SymmetricPattern};
/// use bead::model::DistanceRow;
/// // Two unit rods in 2D: the origin to particle 0 (x[0..2]), particle 0 to 1 (x[2..4]).
/// let rows = [
///     DistanceRow { a: 0, b: None, anchor: [0.0; 3], dim: 2, length: 1.0 },
///     DistanceRow { a: 2, b: Some(0), anchor: [0.0; 3], dim: 2, length: 1.0 },
/// ];
/// let order = PathOrder::of(&SymmetricPattern::new(2, [(0, 1)])).unwrap();
/// let mut rods = RodPath::new(&order, |r| Some(rows[r])).unwrap();
/// // Project a velocity onto J v = 0 at x = ((1, 0), (2, 0)): only the y components stay.
/// let (x, w) = ([1.0, 0.0, 2.0, 0.0], [1.0; 4]);
/// let mut v = [1.0, 1.0, 3.0, 2.0];
/// rods.project_velocities(&x, &w, &mut v).unwrap();
/// for (v, expected) in v.iter().zip([0.0, 1.0, 0.0, 2.0]) {
///     assert!((v - expected).abs() < 1e-15);
/// }
/// ```
#[derive(Clone, Debug)]
pub struct RodPath {
    dim: usize,
    /// In path order (m)
    rods: Vec<Rod>,
    /// The fixed points of the anchored rods, in path order (one per anchored rod)
    anchors: Vec<[f64; 3]>,
    /// L_p (m)
    lengths: Vec<f64>,
    /// e_p at the configuration the Newton matrix is linearized at (q_n): `set_start` (m x
    /// dim, read `dim` at a time: `as_chunks`)
    start: Vec<f64>,
    /// e_p at the last configuration `values` or `project_velocities` saw (m x dim)
    current: Vec<f64>,
    /// The elimination's inverse pivots 1 / u_p (m)
    inverse_pivots: Vec<f64>,
    /// A_p-1,p / u_p-1: the scaled super-diagonal the backward sweep needs (m)
    upper: Vec<f64>,
    /// The eliminated right-hand side, then z (m)
    eliminated: Vec<f64>,
    /// Rods that couple in trees: their elimination particle by particle (`tree.rs`), in
    /// place of the path's sweeps; `Rod::shared` is then each rod's upper particle
    tree: Option<TreeElimination>,
}

/// How a rod couples to the rods before it in elimination order.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Link {
    /// The start of a path
    Start,
    /// The next rod of a path, sharing a particle with the rod before it
    Previous,
    /// A rod of a tree, hanging from the particle with this first coordinate
    Upper(usize),
}

/// The rod vectors the right factor J(y)^T of a solve is taken at.
#[derive(Clone, Copy, Debug)]
enum Sides {
    /// y = q_n ([`RodPath::set_start`]): RATTLE's unsymmetric Newton matrix
    Start,
    /// y = x, the current vectors: J W J^T, symmetric
    Current,
}

impl RodPath {
    /// The rods of the rows in `order` (`row(r)`: row r as a distance, `None` when it is
    /// not one), or `None` when some row is not a distance, the rows differ in dimension, or
    /// two rods linked in the path do not share exactly one particle (two rods between the
    /// same pair of particles, say).
    pub fn new(order: &PathOrder, row: impl Fn(usize) -> Option<DistanceRow>) -> Option<RodPath> {
        let m = order.len();
        let link = |p| match order.linked(p) {
            true => Link::Previous,
            false => Link::Start,
        };
        Self::in_order((0..m).map(|p| (order.row(p), link(p))), m, &row, None)
    }

    /// The rods of rows 0..m when every row is a distance (`row(r)`) and the rods couple in
    /// paths or trees (rows are coupled when they share a particle; no ring of rods), found
    /// from the rods themselves. In paths (no particle on more than two rods) the same as
    /// [`RodPath::new`] on the [`PathOrder`] of J W J^T's pattern, without building the
    /// pattern: each path runs from its end with the smallest row, paths in the order of
    /// those rows. In trees (some particle on three rods or more) the rods are eliminated
    /// particle by particle (`tree.rs`), each tree rooted at its particle of least index.
    pub fn of_rows(m: usize, row: impl Fn(usize) -> Option<DistanceRow>) -> Option<RodPath> {
        const NONE: usize = usize::MAX;
        // The rows on each particle (by the particle's first coordinate / dim), as CSR.
        let mut ends = Vec::with_capacity(m);
        let mut dim = 0;
        let mut starts: Vec<usize> = Vec::new();
        for r in 0..m {
            let distance = row(r)?;
            // Rows of different dimensions are no set of rods (and would index the
            // particles differently below).
            if r > 0 && distance.dim != dim {
                return None;
            }
            dim = distance.dim;
            for particle in [Some(distance.a), distance.b].into_iter().flatten() {
                if dim == 0 || particle % dim != 0 {
                    return None;
                }
                let i = particle / dim;
                if i + 2 > starts.len() {
                    starts.resize(i + 2, 0);
                }
                starts[i + 1] += 1;
            }
            ends.push((distance.a, distance.b));
        }
        for i in 1..starts.len() {
            starts[i] += starts[i - 1];
        }
        let mut filled = starts.clone();
        let mut rows_on = vec![0; starts.last().copied().unwrap_or(0)];
        for (r, &(a, b)) in ends.iter().enumerate() {
            for particle in [Some(a), b].into_iter().flatten() {
                let slot = &mut filled[particle / dim];
                rows_on[*slot] = r;
                *slot += 1;
            }
        }
        drop(filled);
        let on = |i: usize| &rows_on[starts[i]..starts[i + 1]];
        let n_particles = starts.len().saturating_sub(1);
        if (0..n_particles).any(|i| on(i).len() > 2) {
            let (order, tree) = tree::forest(&ends, dim, &starts, &rows_on)?;
            drop((ends, starts, rows_on));
            let order = order.into_iter().map(|(r, s)| (r, Link::Upper(s)));
            return Self::in_order(order, m, &row, Some(tree));
        }
        // Each row's neighbours: the other row on each of its particles.
        let mut neighbours = vec![[NONE; 2]; m];
        for i in 0..n_particles {
            let &[i, j] = on(i) else { continue };
            for (r, other) in [(i, j), (j, i)] {
                let slot = &mut neighbours[r];
                match slot {
                    // Two rods on the same pair of particles: a ring of two.
                    _ if slot.contains(&other) => return None,
                    [NONE, _] => slot[0] = other,
                    _ => slot[1] = other,
                }
            }
        }
        drop((ends, starts, rows_on));
        let mut order = Vec::with_capacity(m);
        let mut visited = vec![false; m];
        for start in 0..m {
            if visited[start] || neighbours[start][1] != NONE {
                continue;
            }
            // A path's end: walk to its other end.
            let (mut previous, mut current) = (NONE, start);
            loop {
                visited[current] = true;
                let link = if previous == NONE {
                    Link::Start
                } else {
                    Link::Previous
                };
                order.push((current, link));
                let next = neighbours[current]
                    .into_iter()
                    .find(|&r| r != NONE && r != previous);
                match next {
                    Some(next) => (previous, current) = (current, next),
                    None => break,
                }
            }
        }
        // Rows left are on rings.
        if order.len() != m {
            return None;
        }
        Self::in_order(order.into_iter(), m, &row, None)
    }

    /// The rods of (row, how it couples to the rods before it) in elimination order, with the
    /// tree's elimination when they couple in trees.
    fn in_order(
        order: impl Iterator<Item = (usize, Link)>,
        m: usize,
        row: &impl Fn(usize) -> Option<DistanceRow>,
        tree: Option<TreeElimination>,
    ) -> Option<RodPath> {
        let mut rods: Vec<Rod> = Vec::with_capacity(m);
        let (mut anchors, mut lengths) = (Vec::new(), Vec::with_capacity(m));
        // 32-bit indices: a row or coordinate beyond them takes the general path.
        let index = |i: usize| u32::try_from(i).ok().filter(|&i| i & ANCHORED == 0);
        let mut dim = None;
        for (p, (r, link)) in order.enumerate() {
            let distance = row(r)?;
            if *dim.get_or_insert(distance.dim) != distance.dim
                || !(1..=3).contains(&distance.dim)
                || !(distance.length > 0.0 && distance.length.is_finite())
                || distance.b == Some(distance.a)
            {
                return None;
            }
            let b = match distance.b {
                Some(b) => index(b + distance.dim)? - distance.dim as u32,
                None => {
                    anchors.push(distance.anchor);
                    ANCHORED | index(anchors.len() - 1)?
                }
            };
            let particles = |rod: &Rod| [Some(rod.a()), rod.b()];
            let mut rod = Rod {
                row: index(r)?,
                a: index(distance.a + distance.dim)? - distance.dim as u32,
                b,
                shared: FIXED,
                inverse_length: 1.0 / distance.length,
                link: 0.0,
            };
            match link {
                Link::Upper(s) if particles(&rod).contains(&Some(s)) => rod.shared = s as u32,
                Link::Upper(_) => return None,
                _ if p == 0 => {}
                Link::Start | Link::Previous => {
                    let before = &rods[p - 1];
                    let shared: Vec<usize> = particles(&rod)
                        .into_iter()
                        .flatten()
                        .filter(|&s| particles(before).contains(&Some(s)))
                        .collect();
                    match (link, shared.as_slice()) {
                        (Link::Previous, &[s]) => {
                            let role = |rod: &Rod| if rod.a() == s { 1.0 } else { -1.0 };
                            let sign = role(&rod) * role(before);
                            rod.shared = s as u32;
                            rod.link = sign * rod.inverse_length * before.inverse_length;
                        }
                        (Link::Start, []) => {}
                        _ => return None,
                    }
                }
            }
            rods.push(rod);
            lengths.push(distance.length);
        }
        let dim = dim.unwrap_or(2);
        Some(RodPath {
            dim,
            rods,
            anchors,
            lengths,
            start: vec![0.0; m * dim],
            current: vec![0.0; m * dim],
            inverse_pivots: vec![0.0; m],
            // The path's super-diagonal: a tree keeps its blocks instead.
            upper: vec![0.0; if tree.is_some() { 0 } else { m }],
            eliminated: vec![0.0; m],
            tree,
        })
    }

    /// Whether the rods couple in trees (eliminated particle by particle) rather than in
    /// paths (the Thomas sweeps).
    pub fn is_tree(&self) -> bool {
        self.tree.is_some()
    }

    /// m
    pub fn len(&self) -> usize {
        self.rods.len()
    }

    /// Whether there are no rods.
    pub fn is_empty(&self) -> bool {
        self.rods.is_empty()
    }

    /// e = x_a - x_b (x_b the anchor for a fixed point) in `D` dimensions.
    #[inline(always)]
    fn rod_vector<const D: usize>(rod: &Rod, anchors: &[[f64; 3]], x: &[f64]) -> [f64; D] {
        let mut e = [0.0; D];
        for k in 0..D {
            e[k] = x[rod.a() + k] - rod.b_coordinate(anchors, x, k);
        }
        e
    }

    /// e . (v_a - v_b) / L (v_b = 0 for a fixed point): J_p v at the rod vector e.
    #[inline(always)]
    fn rate<const D: usize>(rod: &Rod, e: &[f64; D], v: &[f64]) -> f64 {
        let mut dot = 0.0;
        for k in 0..D {
            let relative = match rod.b() {
                Some(b) => v[rod.a() + k] - v[b + k],
                None => v[rod.a() + k],
            };
            dot += e[k] * relative;
        }
        dot * rod.inverse_length
    }

    /// Remember the rod vectors at `q` (q_n): the configuration J(y) is taken at by
    /// [`RodPath::newton_step`], [`RodPath::subtract_start_transpose`] and
    /// [`RodPath::start_multiply`].
    pub fn set_start(&mut self, q: &[f64]) {
        match self.dim {
            1 => self.set_start_in::<1>(q),
            2 => self.set_start_in::<2>(q),
            _ => self.set_start_in::<3>(q),
        }
    }

    fn set_start_in<const D: usize>(&mut self, q: &[f64]) {
        let anchors = &self.anchors;
        for (e, rod) in self.start.as_chunks_mut::<D>().0.iter_mut().zip(&self.rods) {
            *e = Self::rod_vector::<D>(rod, anchors, q);
        }
    }

    /// C(q) into `c` (by row: c\[row\] = (|e|^2 - L^2) / (2L), the native rows' own
    /// arithmetic), remembering the rod vectors at q for the next [`RodPath::newton_step`].
    pub fn values(&mut self, q: &[f64], c: &mut [f64]) {
        match self.dim {
            1 => self.values_in::<1>(q, c),
            2 => self.values_in::<2>(q, c),
            _ => self.values_in::<3>(q, c),
        }
    }

    fn values_in<const D: usize>(&mut self, q: &[f64], c: &mut [f64]) {
        let (anchors, rods) = (&self.anchors, self.rods.iter().zip(&self.lengths));
        for (e, (rod, length)) in self.current.as_chunks_mut::<D>().0.iter_mut().zip(rods) {
            *e = Self::rod_vector::<D>(rod, anchors, q);
            let squared: f64 = (0..D).map(|k| e[k] * e[k]).sum();
            c[rod.row()] = (squared - length * length) * (0.5 * rod.inverse_length);
        }
    }

    /// [`RodPath::values`] and, in the same pass, the scaled residual of
    /// `crate::formulation::ConstraintScales::residual` (by row: `scale` s_i, `rounding`
    /// rho_i): max_i max(0, |C_i| - rho_i max_{k in rod i} |q_k|) / s_i, NaN when any C_i is
    /// NaN. The same per-rod quantities and their maximum, so the same bits.
    pub fn values_and_residual(
        &mut self,
        q: &[f64],
        c: &mut [f64],
        scale: &[f64],
        rounding: &[f64],
    ) -> f64 {
        match self.dim {
            1 => self.values_and_residual_in::<1>(q, c, scale, rounding),
            2 => self.values_and_residual_in::<2>(q, c, scale, rounding),
            _ => self.values_and_residual_in::<3>(q, c, scale, rounding),
        }
    }

    fn values_and_residual_in<const D: usize>(
        &mut self,
        q: &[f64],
        c: &mut [f64],
        scale: &[f64],
        rounding: &[f64],
    ) -> f64 {
        let mut worst: f64 = 0.0;
        let mut nan = false;
        let (anchors, rods) = (&self.anchors, self.rods.iter().zip(&self.lengths));
        for (e, (rod, length)) in self.current.as_chunks_mut::<D>().0.iter_mut().zip(rods) {
            *e = Self::rod_vector::<D>(rod, anchors, q);
            let squared: f64 = (0..D).map(|k| e[k] * e[k]).sum();
            let value = (squared - length * length) * (0.5 * rod.inverse_length);
            c[rod.row()] = value;
            let (size, s) = (value.abs(), scale[rod.row()]);
            // Not `size <= worst * s`, NaN included.
            if matches!(
                size.partial_cmp(&(worst * s)),
                None | Some(std::cmp::Ordering::Greater)
            ) {
                nan |= value.is_nan();
                let mut coordinates: f64 = 0.0;
                for k in 0..D {
                    coordinates = coordinates.max(q[rod.a() + k].abs());
                    if let Some(b) = rod.b() {
                        coordinates = coordinates.max(q[b + k].abs());
                    }
                }
                let excess = size - rounding[rod.row()] * coordinates;
                if excess > 0.0 {
                    worst = worst.max(excess / s);
                }
            }
        }
        if nan {
            f64::NAN
        } else {
            worst
        }
    }

    /// One Newton step of RATTLE's position solve: with `c` = C(q^k) from the last
    /// [`RodPath::values`] (by row), solve J(q^k) W J(q_n)^T z = c, leave z in `c` and
    /// subtract W J(q_n)^T z from `q`. A pivot of the elimination not above
    /// [`RELATIVE_PIVOT_TOLERANCE`] times its diagonal entry (or not finite) is [`Singular`]
    /// (a rod turned by about a right angle in one step, or a dependent rod), with `c` and
    /// `q` untouched.
    pub fn newton_step(&mut self, w: &[f64], c: &mut [f64], q: &mut [f64]) -> Result<(), Singular> {
        match self.dim {
            1 => self.solve::<1>(w, c, q),
            2 => self.solve::<2>(w, c, q),
            _ => self.solve::<3>(w, c, q),
        }
    }

    /// The mass-weighted projection of `v` onto J(q) v = 0 (the rods' lengths are constant,
    /// so C_t = 0): v -= W J^T z with J W J^T z = J v, J W J^T factored as it is eliminated. A
    /// pivot not above [`RELATIVE_PIVOT_TOLERANCE`] times its diagonal entry (or not positive,
    /// or not finite: a dependent or vanishing rod) is [`Singular`], with `v` untouched.
    pub fn project_velocities(
        &mut self,
        q: &[f64],
        w: &[f64],
        v: &mut [f64],
    ) -> Result<(), Singular> {
        match self.dim {
            1 => self.project_in::<1>(q, w, v),
            2 => self.project_in::<2>(q, w, v),
            _ => self.project_in::<3>(q, w, v),
        }
    }

    fn project_in<const D: usize>(
        &mut self,
        q: &[f64],
        w: &[f64],
        v: &mut [f64],
    ) -> Result<(), Singular> {
        // r_p = J_p v = e_p . (v_a - v_b) / L_p; then v -= W J^T z.
        self.solve_symmetric::<D>(q, w, v, Self::rate::<D>, |rod, e, z, v| {
            correct::<D>(rod, e, w, z, v)
        })
    }

    /// Solve J(q) W J(q)^T z = `rhs` (by row) in place, J W J^T factored as it is eliminated
    /// (the implicit form's multipliers: no matrix is assembled). A pivot not above
    /// [`RELATIVE_PIVOT_TOLERANCE`] times its diagonal entry (or not positive, or not finite)
    /// is [`Singular`], with `rhs` untouched.
    pub fn solve_normal(&mut self, q: &[f64], w: &[f64], rhs: &mut [f64]) -> Result<(), Singular> {
        match self.dim {
            1 => self.solve_normal_in::<1>(q, w, rhs),
            2 => self.solve_normal_in::<2>(q, w, rhs),
            _ => self.solve_normal_in::<3>(q, w, rhs),
        }
    }

    fn solve_normal_in<const D: usize>(
        &mut self,
        q: &[f64],
        w: &[f64],
        rhs: &mut [f64],
    ) -> Result<(), Singular> {
        self.solve_symmetric::<D>(
            q,
            w,
            rhs,
            |rod, _, rhs| rhs[rod.row()],
            |rod, _, z, rhs| rhs[rod.row()] = z,
        )
    }

    /// J(q) W J(q)^T z = r with e_p taken at `q`, r_p = `source(rod_p, e_p, data)` read
    /// during the forward sweep and z_p handed to `sink(rod_p, e_p, z_p, data)` during the
    /// backward one (`data` untouched when a pivot is [`Singular`]).
    fn solve_symmetric<const D: usize>(
        &mut self,
        q: &[f64],
        w: &[f64],
        data: &mut [f64],
        source: impl Fn(&Rod, &[f64; D], &[f64]) -> f64,
        mut sink: impl FnMut(&Rod, &[f64; D], f64, &mut [f64]),
    ) -> Result<(), Singular> {
        for (e, rod) in self
            .current
            .as_chunks_mut::<D>()
            .0
            .iter_mut()
            .zip(&self.rods)
        {
            *e = Self::rod_vector::<D>(rod, &self.anchors, q);
        }
        let readable: &[f64] = data;
        self.eliminate::<D, true>(Sides::Current, w, |rod, e| source(rod, e, readable))?;
        self.substitute::<D>(Sides::Current, |rod, e, z| sink(rod, e, z, data));
        Ok(())
    }

    /// The forward sweep of A z = r, A = J(x) W J(y)^T with x the current rod vectors and y
    /// those of `right`, r_p = `source(rod_p, e_p(x))`: along the path or the tree.
    fn eliminate<const D: usize, const SYMMETRIC: bool>(
        &mut self,
        right: Sides,
        w: &[f64],
        source: impl Fn(&Rod, &[f64; D]) -> f64,
    ) -> Result<(), Singular> {
        let (rods, left) = (&self.rods, self.current.as_chunks::<D>().0);
        let right = match right {
            Sides::Start => self.start.as_chunks::<D>().0,
            Sides::Current => left,
        };
        let source = |p: usize| source(&rods[p], &left[p]);
        let (pivots, eliminated) = (&mut self.inverse_pivots, &mut self.eliminated);
        match &mut self.tree {
            Some(tree) => {
                tree.forward::<D, SYMMETRIC>(rods, left, right, w, pivots, eliminated, source)
            }
            None => forward::<D, SYMMETRIC>(
                rods,
                left,
                right,
                w,
                pivots,
                &mut self.upper,
                eliminated,
                source,
            ),
        }
    }

    /// The backward sweep after [`RodPath::eliminate`] with the same `right`: z_p handed to
    /// `sink(rod_p, e_p(y), z_p)`.
    fn substitute<const D: usize>(&mut self, right: Sides, sink: impl FnMut(&Rod, &[f64; D], f64)) {
        let right = match right {
            Sides::Start => self.start.as_chunks::<D>().0,
            Sides::Current => self.current.as_chunks::<D>().0,
        };
        let (rods, eliminated) = (&self.rods, &mut self.eliminated);
        match &self.tree {
            Some(tree) => tree.backward(rods, right, &self.inverse_pivots, eliminated, sink),
            None => backward(rods, right, &self.upper, eliminated, sink),
        }
    }

    fn solve<const D: usize>(
        &mut self,
        w: &[f64],
        c: &mut [f64],
        q: &mut [f64],
    ) -> Result<(), Singular> {
        self.eliminate::<D, false>(Sides::Start, w, |rod, _| c[rod.row()])?;
        self.substitute::<D>(Sides::Start, |rod, e, z| {
            c[rod.row()] = z;
            correct::<D>(rod, e, w, z, q);
        });
        Ok(())
    }

    /// y -= W J(q_n)^T z for z by row (q_n the configuration of [`RodPath::set_start`]).
    pub fn subtract_start_transpose(&self, w: &[f64], z: &[f64], y: &mut [f64]) {
        match self.dim {
            1 => self.subtract_in::<1>(w, z, y),
            2 => self.subtract_in::<2>(w, z, y),
            _ => self.subtract_in::<3>(w, z, y),
        }
    }

    fn subtract_in<const D: usize>(&self, w: &[f64], z: &[f64], y: &mut [f64]) {
        for (rod, e) in self.rods.iter().zip(self.start.as_chunks::<D>().0) {
            correct::<D>(rod, e, w, z[rod.row()], y);
        }
    }

    /// y -= W J(q)^T z for z by row, q the configuration of the last
    /// [`RodPath::solve_normal`] (a position projection's Newton step).
    pub fn subtract_current_transpose(&self, w: &[f64], z: &[f64], y: &mut [f64]) {
        match self.dim {
            1 => self.subtract_current_in::<1>(w, z, y),
            2 => self.subtract_current_in::<2>(w, z, y),
            _ => self.subtract_current_in::<3>(w, z, y),
        }
    }

    fn subtract_current_in<const D: usize>(&self, w: &[f64], z: &[f64], y: &mut [f64]) {
        for (rod, e) in self.rods.iter().zip(self.current.as_chunks::<D>().0) {
            correct::<D>(rod, e, w, z[rod.row()], y);
        }
    }

    /// An upper bound of omega^2, the square of the fastest oscillation the rods' forces
    /// `lambda(row)` (a rod's tension or thrust) give the particles across the rods: the
    /// forces' stiffness K = sum_r lambda_r Hess C_r, with Hess C_r = (1/L_r) [I, -I; -I, I]
    /// over the rod's two particles, in the mass metric W^(1/2) K W^(1/2), whose largest
    /// eigenvalue is at most its largest absolute row sum (Gershgorin):
    ///
    /// ```text
    /// omega^2 <= max_i sum_{rods r on i} |lambda_r| / L_r (w_i + sqrt(w_i w_j))
    /// ```
    ///
    /// (j the rod's other particle, w_j = 0 at a fixed point). On a chain of equal masses
    /// m under tension T it is 4 T / (m L), the limit of the chain's highest frequency
    /// squared as it grows long (a hanging chain's is 0.90 of it at 20 links, 0.99 at
    /// 1000): a Verlet step h is stable for h omega < 2. NaN when a `lambda` is. One pass along
    /// paths (a particle is on the rod before or after it in the path, or on no other);
    /// trees sum each particle's rods in `scratch`, an entry per coordinate (`w.len()`),
    /// whose entries at the rods' particles are overwritten.
    ///
    /// ```
    /// use bead::linalg::RodPath;
    /// use bead::model::DistanceRow;
    /// // A particle of mass 2 hanging from the origin on a rod of length 0.5 with tension 9.
    /// let row = DistanceRow { a: 0, b: None, anchor: [0.0; 3], dim: 2, length: 0.5 };
    /// let rods = RodPath::of_rows(1, |_| Some(row)).unwrap();
    /// let bound = rods.stiffness_bound(&[0.5, 0.5], |_| 9.0, &mut [0.0; 2]);
    /// // The pendulum's T / (m L) = 9.
    /// assert_eq!(bound, 9.0);
    /// ```
    pub fn stiffness_bound(
        &self,
        w: &[f64],
        lambda: impl Fn(usize) -> f64,
        scratch: &mut [f64],
    ) -> f64 {
        // Rod r's part of its particles' row sums: |lambda_r| / L_r (w + sqrt(w_a w_b)).
        let parts = |rod: &Rod| {
            let k = lambda(rod.row()).abs() * rod.inverse_length;
            let wa = w[rod.a()];
            let (wb, cross) = rod.b().map_or((0.0, 0.0), |b| (w[b], (wa * w[b]).sqrt()));
            (k, wa, wb, cross)
        };
        if self.tree.is_none() {
            // Each end alone, and the particle a rod shares with the one before it in the
            // path with both rods' parts.
            // (A NaN force makes the sum of the k NaN; the maxima, one comparison each, may
            // skip it.)
            let larger = |a: f64, b: f64| if a > b { a } else { b };
            let (mut most, mut sum) = (0.0, 0.0);
            let (mut k_before, mut cross_before) = (0.0, 0.0);
            for rod in &self.rods {
                let (k, wa, wb, cross) = parts(rod);
                sum += k;
                let mut row = k * (larger(wa, wb) + cross);
                if let Some(shared) = rod.shared() {
                    let ws = w[shared];
                    row = larger(k_before * (ws + cross_before) + k * (ws + cross), row);
                }
                most = larger(row, most);
                (k_before, cross_before) = (k, cross);
            }
            return if sum.is_nan() { sum } else { most };
        }
        for rod in &self.rods {
            scratch[rod.a()] = 0.0;
            if let Some(b) = rod.b() {
                scratch[b] = 0.0;
            }
        }
        for rod in &self.rods {
            let k = lambda(rod.row()).abs() * rod.inverse_length;
            add_rod_stiffness(scratch, w, rod.a(), rod.b(), k);
        }
        self.rods.iter().fold(0.0, |most, rod| {
            let most = max_nan(scratch[rod.a()], most);
            rod.b().map_or(most, |b| max_nan(scratch[b], most))
        })
    }

    /// out\[row\] = J_row(q_n) v (q_n the configuration of [`RodPath::set_start`]).
    pub fn start_multiply(&self, v: &[f64], out: &mut [f64]) {
        match self.dim {
            1 => self.start_multiply_in::<1>(v, out),
            2 => self.start_multiply_in::<2>(v, out),
            _ => self.start_multiply_in::<3>(v, out),
        }
    }

    fn start_multiply_in<const D: usize>(&self, v: &[f64], out: &mut [f64]) {
        for (rod, e) in self.rods.iter().zip(self.start.as_chunks::<D>().0) {
            out[rod.row()] = Self::rate::<D>(rod, e, v);
        }
    }
}

/// y -= W J_p(e)^T z for one rod: J_p = e^T / L on a's coordinates, -e^T / L on b's.
#[inline(always)]
fn correct<const D: usize>(rod: &Rod, e: &[f64; D], w: &[f64], z: f64, y: &mut [f64]) {
    let scaled = z * rod.inverse_length;
    for k in 0..D {
        let g = e[k] * scaled;
        let a = rod.a() + k;
        y[a] -= w[a] * g;
        if let Some(b) = rod.b() {
            y[b + k] += w[b + k] * g;
        }
    }
}

/// The pivot test of the sweeps: SYMMETRIC (A positive definite), the diagonal entry must be
/// positive and the pivot above [`RELATIVE_PIVOT_TOLERANCE`] times it; otherwise the pivot's
/// magnitude must be above the tolerance times the diagonal's. Row `row` is [`Singular`]
/// otherwise (NaN included).
#[inline(always)]
fn pivot_test<const SYMMETRIC: bool>(
    pivot: f64,
    diagonal: f64,
    row: usize,
) -> Result<(), Singular> {
    // Written so that NaN counts as singular.
    let usable = if SYMMETRIC {
        diagonal > 0.0 && pivot > RELATIVE_PIVOT_TOLERANCE * diagonal
    } else {
        pivot.abs() > RELATIVE_PIVOT_TOLERANCE * diagonal.abs()
    };
    if usable {
        Ok(())
    } else {
        Err(Singular {
            row,
            finite: diagonal.is_finite() && pivot.is_finite(),
        })
    }
}

/// sum_k x_k w_{s+k} y_k over D coordinates starting at s.
#[inline(always)]
fn weighted_dot<const D: usize>(x: &[f64; D], w: &[f64], s: usize, y: &[f64; D]) -> f64 {
    let mut sum = 0.0;
    for k in 0..D {
        sum += x[k] * w[s + k] * y[k];
    }
    sum
}

/// The forward sweep of A z = r with A = J(left) W J(right)^T (module documentation), in
/// the Thomas algorithm's form: the inverse pivots 1 / u_p, the scaled super-diagonal
/// A_p-1,p / u_p-1 (at p) and the eliminated right-hand side y'_p = (r_p - A_p,p-1 y'_p-1) /
/// u_p, r_p = `source(p)` in path order. The pivots are a serial chain (one division each);
/// the backward sweep then needs none. SYMMETRIC (left = right, A positive definite): a
/// pivot must be positive and above the tolerance times its diagonal entry; otherwise its
/// magnitude must.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forward<const D: usize, const SYMMETRIC: bool>(
    rods: &[Rod],
    left: &[[f64; D]],
    right: &[[f64; D]],
    w: &[f64],
    inverse_pivots: &mut [f64],
    upper: &mut [f64],
    eliminated: &mut [f64],
    source: impl Fn(usize) -> f64,
) -> Result<(), Singular> {
    // The previous rod's vectors, inverse pivot and eliminated value, carried in registers.
    let zero = [0.0; D];
    let (mut left_before, mut right_before) = (&zero, &zero);
    let (mut inverse_before, mut eliminated_before) = (0.0, 0.0);
    let rows = rods.iter().zip(left.iter().zip(right)).zip(
        inverse_pivots
            .iter_mut()
            .zip(upper)
            .zip(eliminated.iter_mut()),
    );
    for (p, ((rod, (x, y)), ((inverse_pivot, upper), eliminated))) in rows.enumerate() {
        let mut diagonal = weighted_dot::<D>(x, w, rod.a(), y);
        if let Some(b) = rod.b() {
            diagonal += weighted_dot::<D>(x, w, b, y);
        }
        diagonal *= rod.inverse_length * rod.inverse_length;
        let mut pivot = diagonal;
        let mut value = source(p);
        if let Some(shared) = rod.shared() {
            let below = rod.link * weighted_dot::<D>(x, w, shared, right_before);
            let above = rod.link * weighted_dot::<D>(left_before, w, shared, y);
            let scaled_above = above * inverse_before;
            pivot -= below * scaled_above;
            value -= below * eliminated_before;
            *upper = scaled_above;
        } else {
            *upper = 0.0;
        }
        pivot_test::<SYMMETRIC>(pivot, diagonal, rod.row())?;
        inverse_before = 1.0 / pivot;
        eliminated_before = value * inverse_before;
        *inverse_pivot = inverse_before;
        *eliminated = eliminated_before;
        (left_before, right_before) = (x, y);
    }
    Ok(())
}

/// The backward sweep after [`forward`]: z_p = y'_p - (A_p,p+1 / u_p) z_p+1, left in
/// `eliminated` and handed to `sink(rod_p, e_p(right), z_p)` as each is found (last rod
/// first).
#[inline(always)]
fn backward<const D: usize>(
    rods: &[Rod],
    right: &[[f64; D]],
    upper: &[f64],
    eliminated: &mut [f64],
    mut sink: impl FnMut(&Rod, &[f64; D], f64),
) {
    // (A_p,p+1 / u_p, z_p+1), zero past the end.
    let (mut coupling, mut next) = (0.0, 0.0);
    let rows = rods
        .iter()
        .zip(right)
        .zip(upper.iter().zip(eliminated.iter_mut()));
    for ((rod, e), (upper, eliminated)) in rows.rev() {
        let z = *eliminated - coupling * next;
        *eliminated = z;
        (coupling, next) = (*upper, z);
        sink(rod, e, z);
    }
}

/// A rod's part of its particles' row sums in [`RodPath::stiffness_bound`]: k (w + sqrt(w_a
/// w_b)) added to each end's first coordinate in `sums` (k = |lambda| / L; w_b = 0 at a
/// fixed point).
fn add_rod_stiffness(sums: &mut [f64], w: &[f64], a: usize, b: Option<usize>, k: f64) {
    let wa = w[a];
    match b {
        Some(b) => {
            let cross = (wa * w[b]).sqrt();
            sums[a] += k * (wa + cross);
            sums[b] += k * (w[b] + cross);
        }
        None => sums[a] += k * wa,
    }
}

/// [`RodPath::stiffness_bound`] for rows that are rods or pins in any graph (rings too: a
/// cloth, a net), rows 0..m: `row(r)` is `Some(Some(rod))` for a rod, `Some(None)` for a row
/// whose Hessian is zero (a pin, which stiffens nothing), `None` for any other row, and then
/// the bound is `None` (its curvature is not known). `scratch` has an entry per coordinate
/// (`w.len()`), all overwritten.
///
/// ```
/// use bead::linalg::stiffness_bound_of_rows;
/// use bead::model::DistanceRow;
/// // A pin (row 0) and a rod of length 2 with tension 8 between particles of mass 1 and 4.
/// let rod = DistanceRow { a: 0, b: Some(2), anchor: [0.0; 3], dim: 2, length: 2.0 };
/// let rows = |r| if r == 0 { Some(None) } else { Some(Some(rod)) };
/// let w = [1.0, 1.0, 0.25, 0.25];
/// let bound = stiffness_bound_of_rows(2, rows, &w, |_| 8.0, &mut [0.0; 4]);
/// // (8 / 2) (1 + sqrt(1 / 4)) at the lighter particle.
/// assert_eq!(bound, Some(6.0));
/// ```
pub fn stiffness_bound_of_rows(
    m: usize,
    row: impl Fn(usize) -> Option<Option<DistanceRow>>,
    w: &[f64],
    lambda: impl Fn(usize) -> f64,
    scratch: &mut [f64],
) -> Option<f64> {
    scratch.fill(0.0);
    // The particles' first coordinates are multiples of the rods' dimension.
    let mut dim = 1;
    for r in 0..m {
        if let Some(rod) = row(r)? {
            let k = lambda(r).abs() / rod.length;
            add_rod_stiffness(scratch, w, rod.a, rod.b, k);
            dim = rod.dim;
        }
    }
    Some(
        scratch
            .iter()
            .step_by(dim)
            .fold(0.0, |most, &sum| max_nan(sum, most)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::Rng;
    use crate::linalg::{solve_general, SymmetricPattern};

    /// Uniform in [-0.5, 0.5).
    fn random(rng: &mut Rng) -> f64 {
        rng.uniform(-0.5, 0.5)
    }

    /// A rod in `dim` dimensions between particles a and b (by index), or from a to the fixed
    /// point (0.3, -0.2, 0.1) when b is `None`.
    fn rod_between(dim: usize) -> impl Fn(usize, Option<usize>, f64) -> DistanceRow {
        move |a, b, length| DistanceRow {
            a: a * dim,
            b: b.map(|b| b * dim),
            anchor: [0.3, -0.2, 0.1],
            dim,
            length,
        }
    }

    /// Rods in scrambled row order, with a and b in both roles, two anchored rods at
    /// different points, two separate paths, unequal masses and lengths: particles 0..6 in
    /// `dim` dimensions. Path 1: anchor - p0 - p1 - p2 - p3 (rows 3, 0, 4, 1); path 2:
    /// p4 - p5 - p6 - another anchor (rows 2, 5, 6).
    fn rods(dim: usize) -> Vec<DistanceRow> {
        let rod = rod_between(dim);
        vec![
            rod(0, Some(1), 1.3),
            rod(3, Some(2), 0.7),
            rod(5, Some(4), 1.1),
            rod(0, None, 0.9),
            rod(1, Some(2), 1.6),
            rod(5, Some(6), 0.8),
            DistanceRow {
                anchor: [-0.4, 0.5, 0.2],
                ..rod(6, None, 1.2)
            },
        ]
    }

    /// The dense rows of J at x (m x n) for `rods`.
    fn jacobian(rods: &[DistanceRow], x: &[f64]) -> Vec<Vec<f64>> {
        rods.iter()
            .map(|r| {
                let mut row = vec![0.0; x.len()];
                for k in 0..r.dim {
                    let b = r.b.map_or(r.anchor[k], |b| x[b + k]);
                    let g = (x[r.a + k] - b) / r.length;
                    row[r.a + k] += g;
                    if let Some(b) = r.b {
                        row[b + k] -= g;
                    }
                }
                row
            })
            .collect()
    }

    /// A = J(x) W J(y)^T, dense, row-major.
    fn product(jx: &[Vec<f64>], w: &[f64], jy: &[Vec<f64>]) -> Vec<f64> {
        let m = jx.len();
        let mut a = vec![0.0; m * m];
        for i in 0..m {
            for j in 0..m {
                a[i * m + j] = (0..w.len()).map(|k| jx[i][k] * w[k] * jy[j][k]).sum();
            }
        }
        a
    }

    fn path_of(rows: &[DistanceRow]) -> RodPath {
        let couplings = [(3, 0), (0, 4), (4, 1), (2, 5), (5, 6)];
        let order = PathOrder::of(&SymmetricPattern::new(rows.len(), couplings)).unwrap();
        RodPath::new(&order, |r| Some(rows[r])).expect("rods in paths")
    }

    /// The same rods, their paths found from the rods (no pattern).
    fn found_path(rows: &[DistanceRow]) -> RodPath {
        RodPath::of_rows(rows.len(), |r| Some(rows[r])).expect("rods in paths")
    }

    /// Both ways of finding the paths.
    const BUILDERS: [fn(&[DistanceRow]) -> RodPath; 2] = [path_of, found_path];

    /// The fused Newton step and velocity projection against dense linear algebra on the
    /// same J(x) W J(y)^T, in 1, 2 and 3 dimensions, with the paths from the pattern and
    /// from the rods.
    #[test]
    fn fused_solves_match_dense_ones() {
        for (dim, build) in (1..=3).flat_map(|dim| BUILDERS.map(|build| (dim, build))) {
            let rows = rods(dim);
            let path = build(&rows);
            assert!(path.tree.is_none());
            match_dense(&rows, path, 7, dim);
        }
    }

    /// Rods in trees, scrambled rows: particle 0 on four rods (one to a fixed point, p0 as
    /// a and as b), particle 1 on three; in 2D and 3D a second fixed point on the same tree
    /// and a third on particle 1 (a rod to a fixed point among a particle's children, with
    /// a parent); a free star (particle 10 on three rods, no fixed point), a path p8 - p7 -
    /// p9, and a tree whose root p14 is on one rod only (p14 - p15, p15 on three) as other
    /// trees. Particles 0..18.
    fn tree_rods(dim: usize) -> Vec<DistanceRow> {
        let rod = rod_between(dim);
        let mut rows = vec![
            rod(1, Some(4), 0.9),
            rod(0, Some(1), 1.3),
            rod(12, Some(10), 0.8),
            rod(2, Some(0), 0.7),
            rod(0, None, 1.1),
            rod(5, Some(1), 1.2),
            rod(0, Some(3), 0.6),
            rod(8, Some(7), 1.0),
            rod(10, Some(11), 1.4),
            rod(7, Some(9), 0.5),
            rod(5, Some(6), 0.8),
            rod(13, Some(10), 1.05),
            rod(15, Some(14), 0.75),
            rod(15, Some(16), 1.15),
            rod(17, Some(15), 0.95),
        ];
        // In 1D more fixed points would over-constrain the first tree.
        if dim > 1 {
            rows.push(DistanceRow {
                anchor: [-0.4, 0.5, 0.2],
                ..rod(6, None, 1.2)
            });
            rows.insert(
                2,
                DistanceRow {
                    anchor: [0.2, 0.9, -0.3],
                    ..rod(1, None, 1.25)
                },
            );
        }
        rows
    }

    /// The same checks on rods in trees (eliminated particle by particle).
    #[test]
    fn fused_tree_solves_match_dense_ones() {
        for dim in 1..=3 {
            let rows = tree_rods(dim);
            let path = found_path(&rows);
            assert!(path.tree.is_some(), "dim {dim}: not taken as a tree");
            match_dense(&rows, path, 18, dim);
        }
    }

    /// The fused Newton step, velocity projection, multipliers and transposes of `path`
    /// (rods `rows` on `particles` particles in `dim` dimensions) against dense linear
    /// algebra on the same J(x) W J(y)^T at random states and unequal masses.
    fn match_dense(rows: &[DistanceRow], mut path: RodPath, particles: usize, dim: usize) {
        {
            let rows = rows.to_vec();
            let n = particles * dim;
            let mut seed = Rng::new(11 + dim as u64);
            let w: Vec<f64> = (0..particles)
                .flat_map(|_| {
                    let w = 0.5 + random(&mut seed).abs();
                    std::iter::repeat_n(w, dim)
                })
                .collect();
            let y: Vec<f64> = (0..n)
                .map(|k| k as f64 * 0.37 + random(&mut seed))
                .collect();
            let x: Vec<f64> = y.iter().map(|y| y + 0.05 * random(&mut seed)).collect();
            let (jx, jy) = (jacobian(&rows, &x), jacobian(&rows, &y));

            // C(x) by row, as the native rows compute it.
            path.set_start(&y);
            let mut c = vec![0.0; rows.len()];
            path.values(&x, &mut c);
            for (r, row) in rows.iter().enumerate() {
                let d2: f64 = (0..dim)
                    .map(|k| (x[row.a + k] - row.b.map_or(row.anchor[k], |b| x[b + k])).powi(2))
                    .sum();
                let expected = (d2 - row.length * row.length) * (0.5 / row.length);
                assert!((c[r] - expected).abs() < 1e-15, "C of row {r}");
            }
            // Newton step: z = (J(x) W J(y)^T)^-1 C, q -= W J(y)^T z.
            let m = rows.len();
            let mut expected = c.clone();
            let mut a = product(&jx, &w, &jy);
            solve_general(m, &mut a, &mut expected, &mut vec![0.0; m]).unwrap();
            let mut q = x.clone();
            path.newton_step(&w, &mut c, &mut q).unwrap();
            for (z, e) in c.iter().zip(&expected) {
                assert!(
                    (z - e).abs() < 1e-12 * (1.0 + e.abs()),
                    "dim {dim}: {z} vs {e}"
                );
            }
            for k in 0..n {
                let correction: f64 = (0..m).map(|i| w[k] * jy[i][k] * expected[i]).sum();
                assert!((q[k] - (x[k] - correction)).abs() < 1e-12, "q[{k}]");
            }

            // Velocity projection: v -= W J^T (J W J^T)^-1 J v at x, then J v = 0.
            let v0: Vec<f64> = (0..n).map(|_| random(&mut seed)).collect();
            let mut v = v0.clone();
            path.project_velocities(&x, &w, &mut v).unwrap();
            let mut jv: Vec<f64> = jx
                .iter()
                .map(|r| (0..n).map(|k| r[k] * v0[k]).sum())
                .collect();
            let mut a = product(&jx, &w, &jx);
            crate::linalg::dense_solve(m, &mut a, &mut jv).unwrap();
            for k in 0..n {
                let expected = v0[k] - (0..m).map(|i| w[k] * jx[i][k] * jv[i]).sum::<f64>();
                assert!(
                    (v[k] - expected).abs() < 1e-12,
                    "v[{k}]: {} vs {expected}",
                    v[k]
                );
            }
            let mut out = vec![0.0; m];
            path.set_start(&x);
            path.start_multiply(&v, &mut out);
            assert!(out.iter().all(|r| r.abs() < 1e-12), "J v = {out:?}");

            // Multipliers: (J W J^T) z = r at x, against the dense solve.
            let r: Vec<f64> = (0..m).map(|_| random(&mut seed)).collect();
            let mut z = r.clone();
            path.solve_normal(&x, &w, &mut z).unwrap();
            let mut expected = r.clone();
            crate::linalg::dense_solve(m, &mut product(&jx, &w, &jx), &mut expected).unwrap();
            for (z, e) in z.iter().zip(&expected) {
                assert!((z - e).abs() < 1e-12 * (1.0 + e.abs()), "{z} vs {e}");
            }
            // ... and y -= W J(x)^T z with J at the point of that solve.
            let mut y = vec![0.0; n];
            path.subtract_current_transpose(&w, &z, &mut y);
            for k in 0..n {
                let expected = -(0..m).map(|i| w[k] * jx[i][k] * z[i]).sum::<f64>();
                assert!((y[k] - expected).abs() < 1e-12, "y[{k}]");
            }
        }
    }

    /// y -= W J(y0)^T z and J(y0) v by row, against the dense J.
    #[test]
    fn transpose_and_product_match_dense() {
        let rows = rods(2);
        for build in BUILDERS {
            transpose_and_product_of(&rows, build(&rows));
        }
    }

    fn transpose_and_product_of(rows: &[DistanceRow], mut path: RodPath) {
        let mut seed = Rng::new(5);
        let x: Vec<f64> = (0..14).map(|k| k as f64 + random(&mut seed)).collect();
        let w: Vec<f64> = (0..14).map(|k| 1.0 + (k / 2) as f64).collect();
        let j = jacobian(rows, &x);
        path.set_start(&x);
        let m = rows.len();
        let z: Vec<f64> = (0..m).map(|_| random(&mut seed)).collect();
        let mut y = vec![0.0; 14];
        path.subtract_start_transpose(&w, &z, &mut y);
        for k in 0..14 {
            let expected = -(0..m).map(|i| w[k] * j[i][k] * z[i]).sum::<f64>();
            assert!((y[k] - expected).abs() < 1e-14);
        }
        let mut out = vec![0.0; m];
        path.start_multiply(&x, &mut out);
        for i in 0..m {
            let expected: f64 = (0..14).map(|k| j[i][k] * x[k]).sum();
            assert!((out[i] - expected).abs() < 1e-12);
        }
    }

    /// The stiffness bound is the largest absolute row sum of the dense W^(1/2) K W^(1/2),
    /// K = sum_r |lambda_r| Hess C_r assembled from each rod's Hessian (1/L) [I, -I; -I, I],
    /// and bounds the spectral radius of that matrix for the signed forces too (power
    /// iteration, from below): rods in paths, in trees and in rings (the general rows'
    /// bound, which also takes pins and refuses other rows), 1-3 dimensions, unequal
    /// masses, a massless (fixed) particle, forces of both signs; NaN when a force is.
    #[test]
    fn the_stiffness_bound_is_the_dense_gershgorin_bound() {
        // The paths' rods with one more closing a ring p0 - p1 - p2 - p3 - p0 (no longer
        // paths or trees).
        let ring = |dim: usize| {
            let mut rows = rods(dim);
            rows.push(rod_between(dim)(3, Some(0), 2.1));
            rows
        };
        let cases = (1..=3).flat_map(|dim| {
            [
                (rods(dim), 7, dim, false),
                (tree_rods(dim), 18, dim, false),
                (ring(dim), 7, dim, true),
            ]
        });
        for (rows, particles, dim, ringed) in cases {
            let found = RodPath::of_rows(rows.len(), |r| Some(rows[r]));
            assert_eq!(
                found.is_none(),
                ringed,
                "dim {dim}: a ring is not a path or tree"
            );
            let n = particles * dim;
            let mut seed = Rng::new(3 + dim as u64);
            let mut w: Vec<f64> = (0..particles)
                .flat_map(|_| std::iter::repeat_n(0.3 + random(&mut seed).abs(), dim))
                .collect();
            w[dim..2 * dim].fill(0.0);
            let lambda: Vec<f64> = rows.iter().map(|_| 10.0 * random(&mut seed)).collect();
            // sqrt(W) K sqrt(W), dense, for the forces `force(r)`.
            let dense = |force: &dyn Fn(usize) -> f64| {
                let mut k = vec![0.0; n * n];
                for (r, row) in rows.iter().enumerate() {
                    let stiffness = force(r) / row.length;
                    for c in 0..dim {
                        let a = row.a + c;
                        k[a * n + a] += stiffness * w[a];
                        if let Some(b) = row.b.map(|b| b + c) {
                            k[b * n + b] += stiffness * w[b];
                            let cross = -stiffness * (w[a] * w[b]).sqrt();
                            k[a * n + b] += cross;
                            k[b * n + a] += cross;
                        }
                    }
                }
                k
            };
            let mut scratch = vec![f64::NAN; n];
            // Rows: a pin first (its force stiffens nothing), then the rods.
            let general = |force: &dyn Fn(usize) -> f64, scratch: &mut [f64]| {
                let row = |r: usize| {
                    if r == 0 {
                        Some(None)
                    } else {
                        Some(Some(rows[r - 1]))
                    }
                };
                let force = |r: usize| if r == 0 { 1e6 } else { force(r - 1) };
                stiffness_bound_of_rows(rows.len() + 1, row, &w, force, scratch).unwrap()
            };
            let bound = general(&|r| lambda[r], &mut scratch);
            if !ringed {
                let path = found_path(&rows);
                let along = path.stiffness_bound(&w, |r| lambda[r], &mut scratch);
                assert!(
                    (along - bound).abs() <= 1e-14 * bound,
                    "{along} against {bound}"
                );
                let nan = path.stiffness_bound(&w, |r| [1.0, f64::NAN][r % 2], &mut scratch);
                assert!(nan.is_nan());
            }
            let other =
                stiffness_bound_of_rows(2, |r| (r == 0).then_some(None), &w, |_| 1.0, &mut scratch);
            assert_eq!(other, None, "a row that is neither a rod nor a pin");
            let pulling = dense(&|r| lambda[r].abs());
            let gershgorin = (0..n)
                .map(|i| (0..n).map(|j| pulling[i * n + j].abs()).sum::<f64>())
                .fold(0.0, f64::max);
            assert!(
                (bound - gershgorin).abs() <= 1e-14 * gershgorin,
                "dim {dim}: {bound} against {gershgorin}"
            );
            // The spectral radius for the signed forces, by power iteration.
            let k = dense(&|r| lambda[r]);
            let mut v: Vec<f64> = (0..n).map(|_| random(&mut seed)).collect();
            let mut radius = 0.0;
            for _ in 0..500 {
                let kv: Vec<f64> = (0..n)
                    .map(|i| (0..n).map(|j| k[i * n + j] * v[j]).sum())
                    .collect();
                radius = kv.iter().map(|x| x * x).sum::<f64>().sqrt();
                v = kv.iter().map(|x| x / radius).collect();
            }
            assert!(
                radius > 0.1 * bound && radius <= bound,
                "{radius} against {bound}"
            );
            assert!(general(&|r| [1.0, f64::NAN][r % 2], &mut scratch).is_nan());
        }
    }

    /// Not a set of rods in paths: a row that is not a rod, two rods on the same pair of
    /// particles, rows of different dimensions.
    #[test]
    fn refuses_what_is_not_a_rod_path() {
        let rows = rods(2);
        let couplings = [(3, 0), (0, 4), (4, 1), (2, 5), (5, 6)];
        let order = PathOrder::of(&SymmetricPattern::new(7, couplings)).unwrap();
        assert!(RodPath::new(&order, |r| (r != 4).then_some(rows[r])).is_none());
        let mut twice = rows.clone();
        twice[4] = DistanceRow {
            a: 2,
            b: Some(0),
            ..rows[0]
        };
        assert!(RodPath::new(&order, |r| Some(twice[r])).is_none());
        let mut mixed = rows.clone();
        mixed[5].dim = 3;
        assert!(RodPath::new(&order, |r| Some(mixed[r])).is_none());
        // Mixed dimensions whose coordinates are multiples of both (found from the rods:
        // the particles would be counted in one dimension and placed in another).
        let (a, b) = (
            DistanceRow {
                a: 30,
                b: None,
                dim: 3,
                ..rows[0]
            },
            rows[0],
        );
        assert!(RodPath::of_rows(2, |r| Some([a, DistanceRow { a: 1, dim: 1, ..b }][r])).is_none());
        // The same refusals when the paths are looked for from the rods.
        let found = |rows: &[DistanceRow]| RodPath::of_rows(rows.len(), |r| Some(rows[r]));
        assert!(RodPath::of_rows(7, |r| (r != 4).then_some(rows[r])).is_none());
        assert!(found(&twice).is_none());
        assert!(found(&mixed).is_none());
        assert!(found(&rows).is_some());
        let rod = |a: usize, b: Option<usize>| DistanceRow {
            a: 2 * a,
            b: b.map(|b| 2 * b),
            ..rows[0]
        };
        // A ring of three rods, the same ring with a branch (a particle on three rods: taken
        // as a tree, and refused there), two rods on one pair of particles beside a branch, a
        // rod from a particle to itself.
        assert!(found(&[rod(0, Some(1)), rod(1, Some(2)), rod(2, Some(0))]).is_none());
        let branch = rod(0, Some(3));
        assert!(found(&[rod(0, Some(1)), rod(1, Some(2)), rod(2, Some(0)), branch]).is_none());
        assert!(found(&[rod(0, Some(1)), rod(1, Some(0)), rod(0, Some(2)), branch]).is_none());
        assert!(found(&[rod(0, Some(0))]).is_none());
        assert!(found(&[rod(0, Some(0)), rod(0, Some(1)), branch, rod(0, None)]).is_none());
        // Three rods on one particle: a tree (one node, no path); a hub of more rods than
        // the elimination's blocks take goes to the general path.
        let star = found(&[rod(0, Some(1)), rod(0, Some(2)), rod(0, None)]).unwrap();
        assert!(star.tree.is_some());
        let hub = |n: usize| (1..=n).map(|k| rod(0, Some(k))).collect::<Vec<_>>();
        assert!(found(&hub(tree::MAX_RODS_ON_A_PARTICLE)).is_some_and(|h| h.is_tree()));
        assert!(found(&hub(tree::MAX_RODS_ON_A_PARTICLE + 1)).is_none());
        // A chain hung from both ends is a path.
        assert!(found(&[rod(0, None), rod(0, Some(1)), rod(1, None)]).is_some());
        // Rods' indices are 32-bit: a coordinate at or past 2^31 takes the general path.
        let one = PathOrder::of(&SymmetricPattern::new(1, std::iter::empty())).unwrap();
        let anchored = rows[3];
        let at = |a: usize| move |_| Some(DistanceRow { a, ..anchored });
        assert!(RodPath::new(&one, at((1 << 31) - 4)).is_some());
        assert!(RodPath::new(&one, at((1 << 31) - 2)).is_none());
    }

    /// A rod turned by a right angle between y and x: its diagonal entry e(x).e(y) vanishes
    /// and the Newton step reports that row, leaving q and c untouched; a rod of zero
    /// length at x is singular for the velocity projection and the multipliers' solve.
    #[test]
    fn names_the_singular_rod() {
        let rows = [DistanceRow {
            a: 0,
            b: None,
            anchor: [0.0; 3],
            dim: 2,
            length: 1.0,
        }];
        let order = PathOrder::of(&SymmetricPattern::new(1, [])).unwrap();
        let mut path = RodPath::new(&order, |r| Some(rows[r])).unwrap();
        path.set_start(&[1.0, 0.0]);
        let mut c = [0.0];
        let x = [0.0, 1.5];
        path.values(&x, &mut c);
        let (mut q, before) = (x, c);
        let singular = path.newton_step(&[1.0, 1.0], &mut c, &mut q).unwrap_err();
        assert_eq!(
            singular,
            Singular {
                row: 0,
                finite: true
            }
        );
        assert_eq!((q, c), (x, before));
        let mut v = [1.0, 2.0];
        let singular = path
            .project_velocities(&[0.0, 0.0], &[1.0, 1.0], &mut v)
            .unwrap_err();
        assert_eq!(singular.row, 0);
        assert_eq!(v, [1.0, 2.0]);
        let mut r = [3.0];
        let singular = path
            .solve_normal(&[0.0, 0.0], &[1.0, 1.0], &mut r)
            .unwrap_err();
        assert_eq!((singular.row, r), (0, [3.0]));
    }

    /// The same in a tree: particle 0 on three rods (to a fixed point, to p1, to p2), the
    /// rod to p2 turned by a right angle between y and x, then of zero length: that row is
    /// named and nothing is written.
    #[test]
    fn names_the_singular_rod_in_a_tree() {
        let rod = |a: usize, b: Option<usize>| DistanceRow {
            a: 2 * a,
            b: b.map(|b| 2 * b),
            anchor: [0.0; 3],
            dim: 2,
            length: 1.0,
        };
        let rows = [rod(0, None), rod(1, Some(0)), rod(0, Some(2))];
        let mut path = RodPath::of_rows(3, |r| Some(rows[r])).unwrap();
        assert!(path.is_tree());
        let w = [1.0; 6];
        // At y the rod p0 - p2 points along x, at x along y.
        path.set_start(&[1.0, 0.0, 1.0, 1.0, 2.0, 0.0]);
        let x = [1.0, 0.0, 1.0, 1.0, 1.0, 1.0];
        let mut c = [0.0; 3];
        path.values(&x, &mut c);
        let (mut q, before) = (x, c);
        let singular = path.newton_step(&w, &mut c, &mut q).unwrap_err();
        assert_eq!(singular.row, 2);
        assert_eq!((q, c), (x, before));
        let collapsed = [1.0, 0.0, 1.0, 1.0, 1.0, 0.0];
        let mut v = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let singular = path.project_velocities(&collapsed, &w, &mut v).unwrap_err();
        assert_eq!(singular.row, 2);
        assert_eq!(v, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let mut r = [1.0, 2.0, 3.0];
        let singular = path.solve_normal(&collapsed, &w, &mut r).unwrap_err();
        assert_eq!((singular.row, r), (2, [1.0, 2.0, 3.0]));
    }
}
