//! Matrices whose coupling graph is a set of paths (chains and ropes): tridiagonal after a
//! permutation, factored and solved in O(m) by the Thomas algorithm.
//!
//! Rows i and j of J W J^T are coupled when they share a coordinate. For a chain of rods
//! every rod shares a particle with its neighbours only, so the graph of couplings is a path
//! and, in path order, A is tridiagonal:
//!
//! ```text
//! A = tridiag(e_p, a_p, e_{p+1})          (a_p diagonal, e_p = A_{p-1,p} = A_{p,p-1})
//! LDL^T:   d_0 = a_0,   l_p = e_p / d_{p-1},   d_p = a_p - l_p e_p
//! solve:   z_p -= l_p z_{p-1} (forward),  z_p /= d_p,  z_p -= l_{p+1} z_{p+1} (backward)
//! ```
//!
//! No fill, no symbolic structure beyond the order, and nothing for a general sparse
//! factorization to do but overhead: on the 1000-link chain faer's simplicial LDL^T and its
//! triangular solves took 29% of a RATTLE step, these loops a few percent.
//!
//! The same order gives the unsymmetric tridiagonal systems of RATTLE's exact Newton matrix
//! J(q^k) W J(q_n)^T, solved by elimination without pivoting ([`PathOrder::solve_general`]):
//! that matrix is J W J^T (symmetric positive definite) plus O(h) and the elimination is
//! stable for it; a pivot that fails the relative test is reported, never divided by.

use super::{Singular, SymmetricPattern, SymmetricSolver, RELATIVE_PIVOT_TOLERANCE};

/// The rows of a symmetric pattern in an order that makes it tridiagonal, when its coupling
/// graph is a set of paths (every row coupled to at most two others, no cycle). Built once.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PathOrder {
    /// The row of A at position p (m)
    order: Vec<usize>,
    /// The slot of A_{order[p], order[p]} (m)
    diagonal: Vec<usize>,
    /// The slot of the coupling of order[p - 1] and order[p], `None` at the start of a path
    /// (and at p = 0) (m)
    coupling: Vec<Option<usize>>,
    /// Whether order[p - 1] < order[p], i.e. the coupling slot's (i, j), i <= j, is
    /// (order[p - 1], order[p]) (m)
    ascending: Vec<bool>,
}

impl PathOrder {
    /// The path order of `pattern`, or `None` when some row is coupled to three or more
    /// others or the couplings close a loop.
    pub fn of(pattern: &SymmetricPattern) -> Option<PathOrder> {
        let m = pattern.dim();
        let mut neighbours = vec![[usize::MAX; 2]; m];
        let mut degree = vec![0usize; m];
        for j in 0..m {
            for (_, &i) in pattern.column(j) {
                if i == j {
                    continue;
                }
                for (a, b) in [(i, j), (j, i)] {
                    if degree[a] == 2 {
                        return None;
                    }
                    neighbours[a][degree[a]] = b;
                    degree[a] += 1;
                }
            }
        }
        // Walk every path from one of its ends; a row never reached is on a loop.
        let mut visited = vec![false; m];
        let mut order = Vec::with_capacity(m);
        for start in 0..m {
            if visited[start] || degree[start] == 2 {
                continue;
            }
            let (mut previous, mut current) = (usize::MAX, start);
            loop {
                visited[current] = true;
                order.push(current);
                let next = neighbours[current][..degree[current]]
                    .iter()
                    .copied()
                    .find(|&r| r != previous);
                match next {
                    Some(r) => (previous, current) = (current, r),
                    None => break,
                }
            }
        }
        if order.len() != m {
            return None;
        }
        let diagonal = order.iter().map(|&r| pattern.diagonal_slot(r)).collect();
        let mut coupling = vec![None; m];
        let mut ascending = vec![false; m];
        for p in 1..m {
            let (i, j) = (order[p - 1], order[p]);
            coupling[p] = pattern.slot(i, j);
            ascending[p] = i < j;
        }
        Some(PathOrder {
            order,
            diagonal,
            coupling,
            ascending,
        })
    }

    /// m
    pub fn len(&self) -> usize {
        self.order.len()
    }
    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }
    /// The row of A at position p.
    pub fn row(&self, p: usize) -> usize {
        self.order[p]
    }
    /// Whether the row at position p is coupled to the one before it (false where a path
    /// starts).
    pub fn linked(&self, p: usize) -> bool {
        self.coupling[p].is_some()
    }

    /// Solve B z = rhs in place for the unsymmetric B given on the mirrored pattern
    /// (`upper[s]` = B_ij, `lower[s]` = B_ji for the slot s of (i, j), i <= j; see
    /// [`super::ConstraintMatrix::assemble_product`]), tridiagonal in this order, by
    /// elimination without pivoting. `scratch` holds the eliminated super-diagonal and the
    /// permuted right-hand side (2m). A pivot not above [`RELATIVE_PIVOT_TOLERANCE`] times
    /// its original diagonal entry (or not finite) is [`Singular`] for its row, with `rhs`
    /// left unspecified.
    ///
    /// ```text
    /// B = tridiag(b_p, a_p, c_p)   (b_p = B_{p,p-1}, c_p = B_{p-1,p} in path order)
    /// u_0 = a_0;  m_p = b_p / u_{p-1};  u_p = a_p - m_p c_p;  y_p = r_p - m_p y_{p-1}
    /// z_p = (y_p - c_{p+1} z_{p+1}) / u_p
    /// ```
    pub fn solve_general(
        &self,
        upper: &[f64],
        lower: &[f64],
        rhs: &mut [f64],
        scratch: &mut [f64],
    ) -> Result<(), Singular> {
        let m = self.len();
        let (pivots, y) = scratch[..2 * m].split_at_mut(m);
        let off_diagonal = |p: usize| -> (f64, f64) {
            // (b_p, c_p) = (B_{order[p], order[p-1]}, B_{order[p-1], order[p]})
            match self.coupling[p] {
                Some(s) if self.ascending[p] => (lower[s], upper[s]),
                Some(s) => (upper[s], lower[s]),
                None => (0.0, 0.0),
            }
        };
        for p in 0..m {
            let diagonal = upper[self.diagonal[p]];
            let mut pivot = diagonal;
            let mut value = rhs[self.order[p]];
            if p > 0 {
                let (below, above) = off_diagonal(p);
                if below != 0.0 {
                    let multiplier = below / pivots[p - 1];
                    pivot -= multiplier * above;
                    value -= multiplier * y[p - 1];
                }
            }
            // Written so that NaN counts as singular.
            let usable = pivot.abs() > RELATIVE_PIVOT_TOLERANCE * diagonal.abs();
            if !usable {
                return Err(Singular {
                    row: self.order[p],
                    finite: diagonal.is_finite() && pivot.is_finite(),
                });
            }
            pivots[p] = pivot;
            y[p] = value;
        }
        for p in (0..m).rev() {
            let mut value = y[p];
            if p + 1 < m {
                value -= off_diagonal(p + 1).1 * rhs[self.order[p + 1]];
            }
            rhs[self.order[p]] = value / pivots[p];
        }
        Ok(())
    }
}

/// A symmetric positive-definite matrix whose coupling graph is a set of paths, factored as
/// P A P^T = L D L^T with L unit lower bidiagonal (see the module documentation). O(m)
/// memory and time; neither `factor` nor `solve_in_place` allocates.
///
/// Pivot test as [`super::DenseLdlt`]'s: d_p not above [`RELATIVE_PIVOT_TOLERANCE`] times
/// A's diagonal entry of the same row (or not finite) is [`Singular`] for that row.
///
/// ```
/// use bead::linalg::{PathLdlt, SymmetricPattern, SymmetricSolver};
/// // Rows 0-2 and 2-1 coupled: the path 0, 2, 1.
/// let pattern = SymmetricPattern::new(3, [(0, 2), (1, 2)]);
/// let mut solver = PathLdlt::new(&pattern).expect("a path");
/// // A = [[2, 0, -1], [0, 2, -1], [-1, -1, 2]], upper triangle by columns.
/// let slots = |i, j| pattern.slot(i, j).unwrap();
/// let mut values = vec![0.0; pattern.nnz()];
/// for (i, j, v) in [(0, 0, 2.0), (1, 1, 2.0), (2, 2, 2.0), (0, 2, -1.0), (1, 2, -1.0)] {
///     values[slots(i, j)] = v;
/// }
/// solver.factor(&values).unwrap();
/// let mut z = [1.0, 1.0, 0.0]; // A (1, 1, 1) = (1, 1, 0)
/// solver.solve_in_place(&mut z);
/// assert!(z.iter().all(|z| (z - 1.0).abs() < 1e-15));
/// ```
pub struct PathLdlt {
    path: PathOrder,
    /// Whether the path order is the rows' own (a chain declared link after link): the
    /// solve then needs no permutation.
    identity: bool,
    /// l_p (m; l_0 and the first entry of every path 0)
    multipliers: Vec<f64>,
    /// 1 / d_p (m)
    inverse_pivots: Vec<f64>,
    /// The right-hand side in path order (m)
    permuted: Vec<f64>,
}

impl PathLdlt {
    /// The solver for `pattern`, or `None` when its coupling graph is not a set of paths.
    pub fn new(pattern: &SymmetricPattern) -> Option<PathLdlt> {
        let path = PathOrder::of(pattern)?;
        let m = path.len();
        Some(PathLdlt {
            identity: (0..m).all(|p| path.row(p) == p),
            path,
            multipliers: vec![0.0; m],
            inverse_pivots: vec![0.0; m],
            permuted: vec![0.0; m],
        })
    }

    /// The order it eliminates in.
    pub fn path(&self) -> &PathOrder {
        &self.path
    }

    /// z <- L^-T D^-1 L^-1 z for z in path order.
    #[inline]
    fn substitute(multipliers: &[f64], inverse_pivots: &[f64], z: &mut [f64]) {
        let m = z.len();
        let mut previous = 0.0;
        for p in 0..m {
            let value = z[p] - multipliers[p] * previous;
            z[p] = value;
            previous = value;
        }
        let mut next = 0.0;
        for p in (0..m).rev() {
            let value = z[p] * inverse_pivots[p] - multipliers.get(p + 1).map_or(0.0, |l| l * next);
            z[p] = value;
            next = value;
        }
    }
}

impl SymmetricSolver for PathLdlt {
    fn factor(&mut self, values: &[f64]) -> Result<(), Singular> {
        let path = &self.path;
        for p in 0..path.len() {
            let diagonal = values[path.diagonal[p]];
            let mut pivot = diagonal;
            let mut multiplier = 0.0;
            if let Some(s) = path.coupling[p] {
                let coupling = values[s];
                multiplier = coupling * self.inverse_pivots[p - 1];
                pivot -= multiplier * coupling;
            }
            // Written so that NaN counts as singular.
            if !(diagonal > 0.0 && pivot > RELATIVE_PIVOT_TOLERANCE * diagonal) {
                return Err(Singular {
                    row: path.order[p],
                    finite: diagonal.is_finite() && pivot.is_finite(),
                });
            }
            self.multipliers[p] = multiplier;
            self.inverse_pivots[p] = 1.0 / pivot;
        }
        Ok(())
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) {
        if self.identity {
            Self::substitute(&self.multipliers, &self.inverse_pivots, rhs);
            return;
        }
        let order = &self.path.order;
        for (z, &row) in self.permuted.iter_mut().zip(order) {
            *z = rhs[row];
        }
        Self::substitute(&self.multipliers, &self.inverse_pivots, &mut self.permuted);
        for (z, &row) in self.permuted.iter().zip(order) {
            rhs[row] = *z;
        }
    }

    fn describe(&self) -> String {
        if self.identity {
            "tridiagonal LDL^T (rows in their own order)".into()
        } else {
            "tridiagonal LDL^T (rows in path order)".into()
        }
    }

    fn path(&self) -> Option<&PathOrder> {
        Some(&self.path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::dense_solve;

    fn random(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }

    /// A dense m x m matrix from values on a pattern (upper and lower given separately).
    fn dense(pattern: &SymmetricPattern, upper: &[f64], lower: &[f64]) -> Vec<f64> {
        let m = pattern.dim();
        let mut a = vec![0.0; m * m];
        for j in 0..m {
            for (s, &i) in pattern.column(j) {
                a[i * m + j] = upper[s];
                a[j * m + i] = lower[s];
            }
        }
        a
    }

    /// Paths in scrambled row order (two paths and a lone row): the permutation found makes
    /// A tridiagonal and the solve agrees with a dense one to round-off, for the symmetric
    /// factorization and the unsymmetric elimination.
    #[test]
    fn scrambled_paths_solve_like_dense() {
        // Path 3-0-5-1 and path 4-2, row 6 alone.
        let pairs = [(3, 0), (0, 5), (5, 1), (4, 2)];
        let pattern = SymmetricPattern::new(7, pairs);
        let path = PathOrder::of(&pattern).expect("paths");
        assert_eq!(path.len(), 7);
        let mut seen: Vec<usize> = (0..7).map(|p| path.row(p)).collect();
        seen.sort();
        assert_eq!(seen, (0..7).collect::<Vec<_>>());
        let mut seed = 7;
        let mut values = vec![0.0; pattern.nnz()];
        for j in 0..7 {
            for (s, &i) in pattern.column(j) {
                values[s] = if i == j {
                    3.0 + random(&mut seed)
                } else {
                    random(&mut seed)
                };
            }
        }
        let rhs: Vec<f64> = (0..7).map(|_| random(&mut seed)).collect();
        let mut expected = rhs.clone();
        dense_solve(7, &mut dense(&pattern, &values, &values), &mut expected).unwrap();
        let mut solver = PathLdlt::new(&pattern).unwrap();
        solver.factor(&values).unwrap();
        let mut z = rhs.clone();
        solver.solve_in_place(&mut z);
        for (z, e) in z.iter().zip(&expected) {
            assert!((z - e).abs() < 1e-14, "{z} vs {e}");
        }

        // Unsymmetric: perturb the lower triangle.
        let lower: Vec<f64> = values.iter().map(|v| v + 0.1 * random(&mut seed)).collect();
        let mut diagonal_equal = lower.clone();
        for j in 0..7 {
            let s = pattern.diagonal_slot(j);
            diagonal_equal[s] = values[s];
        }
        let mut expected = rhs.clone();
        let mut a = dense(&pattern, &values, &diagonal_equal);
        let mut scale = vec![0.0; 7];
        crate::linalg::solve_general(7, &mut a, &mut expected, &mut scale).unwrap();
        let mut z = rhs.clone();
        let mut scratch = vec![0.0; 14];
        path.solve_general(&values, &diagonal_equal, &mut z, &mut scratch)
            .unwrap();
        for (z, e) in z.iter().zip(&expected) {
            assert!((z - e).abs() < 1e-13, "{z} vs {e}");
        }
    }

    #[test]
    fn branches_and_loops_are_not_paths() {
        // Row 0 coupled to three rows: a branch.
        assert!(PathOrder::of(&SymmetricPattern::new(4, [(0, 1), (0, 2), (0, 3)])).is_none());
        // A triangle of couplings: a loop.
        assert!(PathOrder::of(&SymmetricPattern::new(4, [(0, 1), (1, 2), (2, 0)])).is_none());
        // A loop beside a path.
        assert!(
            PathOrder::of(&SymmetricPattern::new(6, [(0, 1), (2, 3), (3, 4), (4, 2)])).is_none()
        );
    }

    /// A dependent row (its pivot vanishes) is named; a NaN is reported as not finite.
    #[test]
    fn names_the_singular_row() {
        // A = [[1, 1], [1, 1]]: row 1 dependent on row 0.
        let pattern = SymmetricPattern::new(2, [(0, 1)]);
        let mut solver = PathLdlt::new(&pattern).unwrap();
        assert_eq!(
            solver.factor(&[1.0, 1.0, 1.0]),
            Err(Singular {
                row: 1,
                finite: true
            })
        );
        assert_eq!(
            solver.factor(&[1.0, f64::NAN, 1.0]),
            Err(Singular {
                row: 1,
                finite: false
            })
        );
        let path = solver.path().clone();
        let mut scratch = [0.0; 4];
        assert_eq!(
            path.solve_general(
                &[1.0, 1.0, 1.0],
                &[1.0, 1.0, 1.0],
                &mut [1.0, 1.0],
                &mut scratch
            ),
            Err(Singular {
                row: 1,
                finite: true
            })
        );
    }
}
