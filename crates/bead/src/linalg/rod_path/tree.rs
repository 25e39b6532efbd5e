//! Rods that couple in trees (a particle on three rods or more, no ring): the elimination of
//! A = J(x) W J(y)^T particle by particle.
//!
//! Root each tree of particles at one of them. Every rod p then hangs from its upper particle
//! s_p (towards the root) and has a lower end: a particle or a fixed point. Two rods couple
//! only through a particle they share, so the rods on particle s (the children C(s), hanging
//! from it, and the parent P(s), which s hangs from) form a dense block of A, and eliminating
//! C(s) touches that block alone. Taken in post-order (a particle after every particle below
//! it), each particle's block is
//!
//! ```text
//! B_ab = A_ab                     a != b, both on s: s_a s_b e_a(x) . W_s e_b(y) / (L_a L_b)
//! B_aa = A_aa + S_a               a in C(s), S_a what eliminating the block below a left
//! B_PP = 0                        P's own diagonal enters at its upper particle
//! ```
//!
//! (s_a = +1 when s is rod a's particle a, -1 when it is its particle b); Gaussian elimination
//! of the children (no pivoting, the pivot test of the path) leaves S_P = B_PP and the
//! eliminated right-hand side of P in the block's last row. The backward sweep runs the
//! particles in reverse: z_P is known when P's children are solved. On a path every block is
//! 2 x 2 and this is the Thomas algorithm; paths keep their own sweeps (`forward`,
//! `backward` in the parent module), which need no block storage. Cost O(sum over particles of
//! (rods on it)^3), O(m) for bounded degree.

use super::{pivot_test, weighted_dot, Rod, Singular};

/// No parent rod: the root of its tree.
const ROOT: u32 = u32::MAX;

/// The most rods on one particle the elimination takes: its block costs n^2 numbers and n^3
/// operations per solve, so a hub of more rods goes to the general (sparse) path.
pub(super) const MAX_RODS_ON_A_PARTICLE: usize = 64;

/// One particle with rods hanging from it, in post-order.
#[derive(Clone, Debug)]
struct Node {
    /// The first of its children in elimination order (they are consecutive)
    first: u32,
    /// How many rods hang from it
    children: u32,
    /// The rod it hangs from (elimination order), [`ROOT`] for a root
    parent: u32,
    /// Where its block (n x n, n = children + 1 with a parent) starts in `blocks`
    block: usize,
}

/// The elimination order and factors of rods that couple in a forest (see the module
/// documentation). The rods themselves are the parent module's, in the order this gives them
/// (`Rod::shared` holds each rod's upper particle).
#[derive(Clone, Debug)]
pub(super) struct TreeElimination {
    nodes: Vec<Node>,
    /// The blocks: L below the diagonal, U above it (the pivots are the parent module's
    /// `inverse_pivots`)
    blocks: Vec<f64>,
    /// S_p: what eliminating the block below rod p added to its diagonal (m)
    schur: Vec<f64>,
    /// One block's right-hand side and unmodified diagonal (the largest block's n)
    values: Vec<f64>,
    diagonal: Vec<f64>,
}

/// The rods with ends `ends` (by row: first coordinates of particles a and b, b `None` for
/// a fixed point; `dim` coordinates a particle) as a forest, or `None` when they close a
/// ring (two rods on the same pair of particles included) or some particle is on more than
/// [`MAX_RODS_ON_A_PARTICLE`] rods: each row in elimination order
/// with the first coordinate of the particle it hangs from, and the elimination. The rows on
/// particle i are `rows_on[starts[i]..starts[i + 1]]`.
pub(super) fn forest(
    ends: &[(usize, Option<usize>)],
    dim: usize,
    starts: &[usize],
    rows_on: &[usize],
) -> Option<(Vec<(usize, usize)>, TreeElimination)> {
    const NONE: usize = usize::MAX;
    let m = ends.len();
    let n_particles = starts.len() - 1;
    let on = |particle: usize| &rows_on[starts[particle]..starts[particle + 1]];
    if (0..n_particles).any(|i| on(i).len() > MAX_RODS_ON_A_PARTICLE) {
        return None;
    }
    let below = |r: usize, particle: usize| -> Option<usize> {
        let (a, b) = ends[r];
        let b = b?;
        Some(if a / dim == particle {
            b / dim
        } else {
            a / dim
        })
    };
    let mut visited = vec![false; n_particles];
    // The particle each rod hangs from, and the rod each particle hangs from.
    let mut upper = vec![NONE; m];
    let mut parent_of = vec![NONE; n_particles];
    // The rods in elimination order: each particle's, as it is left for the last time.
    let mut hanging: Vec<usize> = Vec::with_capacity(m);
    // Particles with rods hanging from them, in post-order, with their range in `hanging`.
    let mut post: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
    // Depth first, iteratively: (particle, the next of its rows to follow).
    let mut stack: Vec<(usize, usize)> = Vec::new();
    for root in 0..n_particles {
        if visited[root] || on(root).is_empty() {
            continue;
        }
        visited[root] = true;
        stack.push((root, 0));
        while let Some((particle, next)) = stack.last_mut() {
            let particle = *particle;
            if let Some(&r) = on(particle).get(*next) {
                *next += 1;
                if r == parent_of[particle] {
                    continue;
                }
                if upper[r] != NONE {
                    // Reached again through another rod: a ring.
                    return None;
                }
                upper[r] = particle;
                if let Some(lower) = below(r, particle) {
                    if visited[lower] {
                        return None;
                    }
                    visited[lower] = true;
                    parent_of[lower] = r;
                    stack.push((lower, 0));
                }
            } else {
                stack.pop();
                let start = hanging.len();
                hanging.extend(on(particle).iter().filter(|&&r| upper[r] == particle));
                if hanging.len() > start {
                    post.push((particle, start..hanging.len()));
                }
            }
        }
    }
    if hanging.len() != m {
        return None;
    }
    // Elimination order: `hanging` as it stands (a particle's rods after every rod below it).
    let mut position = vec![NONE; m];
    for (p, &r) in hanging.iter().enumerate() {
        position[r] = p;
    }
    let mut nodes = Vec::with_capacity(post.len());
    let mut block = 0;
    let mut widest = 0;
    for (particle, range) in &post {
        let parent = parent_of[*particle];
        let n = range.len() + usize::from(parent != NONE);
        nodes.push(Node {
            first: u32::try_from(range.start).ok()?,
            children: u32::try_from(range.len()).ok()?,
            parent: if parent == NONE {
                ROOT
            } else {
                u32::try_from(position[parent]).ok()?
            },
            block,
        });
        block += n * n;
        widest = widest.max(n);
    }
    let order = hanging
        .iter()
        .map(|&r| (r, upper[r] * dim))
        .collect::<Vec<_>>();
    Some((
        order,
        TreeElimination {
            nodes,
            blocks: vec![0.0; block],
            schur: vec![0.0; m],
            values: vec![0.0; widest],
            diagonal: vec![0.0; widest],
        },
    ))
}

impl TreeElimination {
    /// The forward elimination of A z = r, A = J(left) W J(right)^T, r_p = `source(p)` (p in
    /// elimination order); the eliminated right-hand side is left in `eliminated` and the
    /// inverse pivots in `inverse_pivots`. SYMMETRIC (left = right, A positive definite): a
    /// pivot must be positive and above the tolerance times its diagonal entry; otherwise
    /// its magnitude must.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn forward<const D: usize, const SYMMETRIC: bool>(
        &mut self,
        rods: &[Rod],
        left: &[[f64; D]],
        right: &[[f64; D]],
        w: &[f64],
        inverse_pivots: &mut [f64],
        eliminated: &mut [f64],
        source: impl Fn(usize) -> f64,
    ) -> Result<(), Singular> {
        // What the blocks below leave for each rod: nothing until they are eliminated.
        self.schur.fill(0.0);
        eliminated.fill(0.0);
        for node in &self.nodes {
            let (first, k) = (node.first as usize, node.children as usize);
            let parent = (node.parent != ROOT).then_some(node.parent as usize);
            let n = k + usize::from(parent.is_some());
            let member = |a: usize| {
                if a < k {
                    first + a
                } else {
                    node.parent as usize
                }
            };
            // The particle the block couples through, and each rod's sign on it.
            let s = rods[first].shared as usize;
            let sign = |p: usize| if rods[p].a() == s { 1.0 } else { -1.0 };
            let block = &mut self.blocks[node.block..node.block + n * n];
            let diagonal_of = |p: usize| {
                let rod = &rods[p];
                let mut diagonal = weighted_dot::<D>(&left[p], w, rod.a(), &right[p]);
                if let Some(b) = rod.b() {
                    diagonal += weighted_dot::<D>(&left[p], w, b, &right[p]);
                }
                diagonal * (rod.inverse_length * rod.inverse_length)
            };
            let coupling = |p: usize, q: usize| {
                sign(p)
                    * sign(q)
                    * weighted_dot::<D>(&left[p], w, s, &right[q])
                    * (rods[p].inverse_length * rods[q].inverse_length)
            };
            if let (1, Some(parent)) = (k, parent) {
                // A particle on two rods (a stretch of path inside the tree): the general
                // block's arithmetic below without its loops.
                let p = first;
                let diagonal = diagonal_of(p);
                let pivot = diagonal + self.schur[p];
                pivot_test::<SYMMETRIC>(pivot, diagonal, rods[p].row())?;
                let (upper, lower) = (coupling(p, parent), coupling(parent, p));
                let inverse = 1.0 / pivot;
                let l = lower * inverse;
                let value = source(p) + eliminated[p];
                block.copy_from_slice(&[pivot, upper, l, 0.0 - l * upper]);
                inverse_pivots[p] = inverse;
                eliminated[p] = value;
                self.schur[parent] = block[3];
                eliminated[parent] = 0.0 - l * value;
                continue;
            }
            for a in 0..n {
                let p = member(a);
                for b in 0..n {
                    let q = member(b);
                    block[a * n + b] = if a != b {
                        coupling(p, q)
                    } else if a < k {
                        let diagonal = diagonal_of(p);
                        self.diagonal[a] = diagonal;
                        diagonal + self.schur[p]
                    } else {
                        0.0
                    };
                }
                self.values[a] = if a < k {
                    source(p) + eliminated[p]
                } else {
                    0.0
                };
            }
            for a in 0..k {
                let (pivot, diagonal) = (block[a * n + a], self.diagonal[a]);
                pivot_test::<SYMMETRIC>(pivot, diagonal, rods[first + a].row())?;
                let inverse = 1.0 / pivot;
                inverse_pivots[first + a] = inverse;
                for r in a + 1..n {
                    let l = block[r * n + a] * inverse;
                    block[r * n + a] = l;
                    for c in a + 1..n {
                        block[r * n + c] -= l * block[a * n + c];
                    }
                    self.values[r] -= l * self.values[a];
                }
            }
            eliminated[first..first + k].copy_from_slice(&self.values[..k]);
            if let Some(parent) = parent {
                self.schur[parent] = block[k * n + k];
                eliminated[parent] = self.values[k];
            }
        }
        Ok(())
    }

    /// The backward substitution after [`TreeElimination::forward`]: z_p left in
    /// `eliminated` and handed to `sink(rod_p, e_p(right), z_p)` as each is found (the
    /// root's rods first).
    pub(super) fn backward<const D: usize>(
        &self,
        rods: &[Rod],
        right: &[[f64; D]],
        inverse_pivots: &[f64],
        eliminated: &mut [f64],
        mut sink: impl FnMut(&Rod, &[f64; D], f64),
    ) {
        for node in self.nodes.iter().rev() {
            let (first, k) = (node.first as usize, node.children as usize);
            let parent = (node.parent != ROOT).then_some(node.parent as usize);
            let n = k + usize::from(parent.is_some());
            let block = &self.blocks[node.block..node.block + n * n];
            let z_parent = parent.map_or(0.0, |p| eliminated[p]);
            for a in (0..k).rev() {
                let mut value = eliminated[first + a];
                for c in a + 1..k {
                    value -= block[a * n + c] * eliminated[first + c];
                }
                if parent.is_some() {
                    value -= block[a * n + k] * z_parent;
                }
                let z = value * inverse_pivots[first + a];
                eliminated[first + a] = z;
                sink(&rods[first + a], &right[first + a], z);
            }
        }
    }
}
