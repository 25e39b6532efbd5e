//! Dense LDL^T: the solver of small systems (the article's one-row scenes, the parametric
//! mass matrix) and the test oracle of the sparse one.

use super::{Singular, SymmetricPattern, SymmetricSolver, RELATIVE_PIVOT_TOLERANCE};

/// Factor A = L D L^T in place (L unit lower triangular, D diagonal): `a` is n x n,
/// row-major; its lower triangle is read and replaced by L below the diagonal and D on it,
/// its upper triangle is scratch (neither read nor kept). Left-looking, row by row, with
/// w_k = L_jk D_k kept in the upper triangle:
///
/// ```text
/// w_i  = A_ji - sum_{k<i} w_k L_ik,   L_ji = w_i / D_i     (i < j)
/// D_j  = A_jj - sum_{k<j} w_k L_jk
/// ```
///
/// n^3/6 multiply-adds, n(n-1)/2 divisions and no square root: a one-row system's solve is
/// the single division b / A a hand derivation writes.
///
/// Pivot test: row j is singular when its pivot D_j is not above
/// `relative_pivot_tolerance * A_jj` (or A_jj <= 0, or D_j is NaN). D_j / A_jj is the squared
/// sine of the angle between row j of J W^(1/2) and the span of the earlier rows, so the test
/// is scale-free and names the first dependent row.
pub fn ldlt_in_place(
    n: usize,
    a: &mut [f64],
    relative_pivot_tolerance: f64,
) -> Result<(), Singular> {
    let mut failed = [None];
    ldlt_lanes::<1>(n, &mut a[..n * n], relative_pivot_tolerance, &mut failed);
    match failed[0] {
        None => Ok(()),
        Some(singular) => Err(singular),
    }
}

/// [`ldlt_in_place`] of L matrices at once (structure of arrays: entry e of matrix l at
/// `a[e * L + l]`), the same arithmetic per matrix (the scalar function is this one for one
/// lane). `failed[l]` gets matrix l's first singular row; its factor is then garbage, the
/// others' are not affected.
pub(crate) fn ldlt_lanes<const L: usize>(
    n: usize,
    a: &mut [f64],
    relative_pivot_tolerance: f64,
    failed: &mut [Option<Singular>; L],
) {
    let at = |r: usize, c: usize, l: usize| (r * n + c) * L + l;
    for j in 0..n {
        // Row j of L: w_i = L_ji D_i into the upper triangle (a[i][j]), L_ji below.
        for i in 0..j {
            for l in 0..L {
                let mut w = a[at(j, i, l)];
                for k in 0..i {
                    w -= a[at(k, j, l)] * a[at(i, k, l)];
                }
                a[at(i, j, l)] = w;
                a[at(j, i, l)] = w / a[at(i, i, l)];
            }
        }
        for l in 0..L {
            let diagonal = a[at(j, j, l)];
            let mut pivot = diagonal;
            for k in 0..j {
                pivot -= a[at(k, j, l)] * a[at(j, k, l)];
            }
            if !(diagonal > 0.0 && pivot > relative_pivot_tolerance * diagonal)
                && failed[l].is_none()
            {
                failed[l] = Some(Singular {
                    row: j,
                    finite: diagonal.is_finite() && pivot.is_finite(),
                });
            }
            a[at(j, j, l)] = pivot;
        }
    }
}

/// Solve L D L^T z = b with the factor of [`ldlt_in_place`]; `b` (n) becomes z.
pub fn ldlt_substitute(n: usize, a: &[f64], b: &mut [f64]) {
    ldlt_substitute_lanes::<1>(n, a, &mut b[..n]);
}

/// [`ldlt_substitute`] for L systems at once (the layout of [`ldlt_lanes`]; element i of
/// right-hand side l at `b[i * L + l]`).
pub(crate) fn ldlt_substitute_lanes<const L: usize>(n: usize, a: &[f64], b: &mut [f64]) {
    let at = |r: usize, c: usize, l: usize| (r * n + c) * L + l;
    // L y = b, then D u = y, then L^T z = u.
    for i in 0..n {
        for l in 0..L {
            let mut y = b[i * L + l];
            for k in 0..i {
                y -= a[at(i, k, l)] * b[k * L + l];
            }
            b[i * L + l] = y;
        }
    }
    for i in 0..n {
        for l in 0..L {
            b[i * L + l] /= a[at(i, i, l)];
        }
    }
    for i in (0..n).rev() {
        for l in 0..L {
            let mut z = b[i * L + l];
            for k in i + 1..n {
                z -= a[at(k, i, l)] * b[k * L + l];
            }
            b[i * L + l] = z;
        }
    }
}

/// Solve A z = b for a symmetric positive-definite A (n x n, row-major, lower triangle read
/// and overwritten, upper triangle scratch) in place with the relative pivot test of
/// [`ldlt_in_place`].
///
/// ```
/// let mut a = [4.0, 1.0, 1.0, 3.0];
/// let mut b = [1.0, 2.0];
/// bead::linalg::dense_solve(2, &mut a, &mut b).unwrap();
/// assert!((b[0] - 1.0 / 11.0).abs() < 1e-15 && (b[1] - 7.0 / 11.0).abs() < 1e-15);
/// ```
pub fn dense_solve(n: usize, a: &mut [f64], b: &mut [f64]) -> Result<(), Singular> {
    ldlt_in_place(n, a, RELATIVE_PIVOT_TOLERANCE)?;
    ldlt_substitute(n, a, b);
    Ok(())
}

/// The dense LDL^T factorization behind [`SymmetricSolver`]: the pattern's values are
/// scattered into an m x m matrix (zero outside the pattern) and factored in place. O(m^2)
/// memory and O(m^3) time: for small m (see [`super::DENSE_MAX_ROWS`]), where it is faster than
/// the sparse factorization, and as the sparse one's oracle in tests.
#[derive(Clone, Debug)]
pub struct DenseLdlt {
    /// Pivots below this fraction of the original diagonal count as zero.
    pub relative_pivot_tolerance: f64,
    pattern: SymmetricPattern,
    /// L and D, row-major lower triangle (m x m; see [`ldlt_in_place`])
    factor: Vec<f64>,
}

impl DenseLdlt {
    /// A dense factorization of matrices with `pattern`.
    pub fn new(pattern: &SymmetricPattern) -> Self {
        let m = pattern.dim();
        DenseLdlt {
            relative_pivot_tolerance: RELATIVE_PIVOT_TOLERANCE,
            pattern: pattern.clone(),
            factor: vec![0.0; m * m],
        }
    }
}

impl DenseLdlt {
    /// What [`SymmetricSolver::factor`] factors, for L matrices at once: the pattern's values
    /// (`values[slot * L + l]`) scattered into dense m x m matrices (`dense[(i * m + j) * L +
    /// l]`, lower triangle, zero elsewhere), to factor with [`ldlt_lanes`].
    pub(crate) fn scatter_lanes<const L: usize>(&self, values: &[f64], dense: &mut [f64]) {
        let m = self.pattern.dim();
        dense.fill(0.0);
        for j in 0..m {
            for (slot, &i) in self.pattern.column(j) {
                dense[(j * m + i) * L..(j * m + i + 1) * L]
                    .copy_from_slice(&values[slot * L..(slot + 1) * L]);
            }
        }
    }
}

impl SymmetricSolver for DenseLdlt {
    fn factor(&mut self, values: &[f64]) -> Result<(), Singular> {
        let m = self.pattern.dim();
        // The lower triangle of row-major A = the upper triangle by columns.
        self.factor.fill(0.0);
        for j in 0..m {
            for (slot, &i) in self.pattern.column(j) {
                self.factor[j * m + i] = values[slot];
            }
        }
        ldlt_in_place(m, &mut self.factor, self.relative_pivot_tolerance)
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) {
        ldlt_substitute(self.pattern.dim(), &self.factor, rhs);
    }

    fn describe(&self) -> String {
        format!("dense LDL^T ({0} x {0})", self.pattern.dim())
    }

    fn dense_pivot_tolerance(&self) -> Option<f64> {
        Some(self.relative_pivot_tolerance)
    }
}
