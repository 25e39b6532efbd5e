//! Dense Cholesky: the solver of small systems (the article's one-row scenes, the parametric
//! mass matrix) and the test oracle of the sparse one.

use super::{Singular, SymmetricPattern, SymmetricSolver, RELATIVE_PIVOT_TOLERANCE};

/// Factor A = L L^T in place: `a` is n x n, row-major, its lower triangle read and replaced
/// by L (left-looking, n^3/6 multiply-adds plus n square roots; the upper triangle is not
/// read).
///
/// Pivot test: row j is singular when its pivot d_j = A_jj - sum_k L_jk^2 is not above
/// `relative_pivot_tolerance * A_jj` (or A_jj <= 0, or d_j is NaN). d_j / A_jj is the squared
/// sine of the angle between row j of J W^(1/2) and the span of the earlier rows, so the test
/// is scale-free and names the first dependent row.
pub fn cholesky_in_place(
    n: usize,
    a: &mut [f64],
    relative_pivot_tolerance: f64,
) -> Result<(), Singular> {
    let mut failed = [None];
    cholesky_lanes::<1>(n, &mut a[..n * n], relative_pivot_tolerance, &mut failed);
    match failed[0] {
        None => Ok(()),
        Some(singular) => Err(singular),
    }
}

/// [`cholesky_in_place`] of L matrices at once (structure of arrays: entry e of matrix l at
/// `a[e * L + l]`), the same arithmetic per matrix (the scalar function is this one for one
/// lane). `failed[l]` gets matrix l's first singular row; its factor is then garbage, the
/// others' are not affected.
pub(crate) fn cholesky_lanes<const L: usize>(
    n: usize,
    a: &mut [f64],
    relative_pivot_tolerance: f64,
    failed: &mut [Option<Singular>; L],
) {
    let at = |r: usize, c: usize, l: usize| (r * n + c) * L + l;
    for j in 0..n {
        // Row j of L: entries k < j from the rows above, then the pivot.
        for i in 0..j {
            for l in 0..L {
                let mut sum = a[at(j, i, l)];
                for k in 0..i {
                    sum -= a[at(j, k, l)] * a[at(i, k, l)];
                }
                a[at(j, i, l)] = sum / a[at(i, i, l)];
            }
        }
        for l in 0..L {
            let diagonal = a[at(j, j, l)];
            // sum() of f64 starts from -0.0.
            let mut squares = -0.0;
            for k in 0..j {
                squares += a[at(j, k, l)] * a[at(j, k, l)];
            }
            let pivot = diagonal - squares;
            if !(diagonal > 0.0 && pivot > relative_pivot_tolerance * diagonal)
                && failed[l].is_none()
            {
                failed[l] = Some(Singular {
                    row: j,
                    finite: diagonal.is_finite() && pivot.is_finite(),
                });
            }
            a[at(j, j, l)] = pivot.sqrt();
        }
    }
}

/// Solve L L^T z = b with the factor of [`cholesky_in_place`]; `b` (n) becomes z.
pub fn cholesky_substitute(n: usize, a: &[f64], b: &mut [f64]) {
    cholesky_substitute_lanes::<1>(n, a, &mut b[..n]);
}

/// [`cholesky_substitute`] for L systems at once (the layout of [`cholesky_lanes`]; element i
/// of right-hand side l at `b[i * L + l]`).
pub(crate) fn cholesky_substitute_lanes<const L: usize>(n: usize, a: &[f64], b: &mut [f64]) {
    let at = |r: usize, c: usize, l: usize| (r * n + c) * L + l;
    // L y = b, then L^T z = y.
    for i in 0..n {
        for l in 0..L {
            let mut sum = b[i * L + l];
            for k in 0..i {
                sum -= a[at(i, k, l)] * b[k * L + l];
            }
            b[i * L + l] = sum / a[at(i, i, l)];
        }
    }
    for i in (0..n).rev() {
        for l in 0..L {
            let mut sum = b[i * L + l];
            for k in i + 1..n {
                sum -= a[at(k, i, l)] * b[k * L + l];
            }
            b[i * L + l] = sum / a[at(i, i, l)];
        }
    }
}

/// Solve A z = b for a symmetric positive-definite A (n x n, row-major, lower triangle read
/// and overwritten) in place with the relative pivot test of [`cholesky_in_place`].
///
/// ```
/// let mut a = [4.0, 1.0, 1.0, 3.0];
/// let mut b = [1.0, 2.0];
/// bead::linalg::dense_solve(2, &mut a, &mut b).unwrap();
/// assert!((b[0] - 1.0 / 11.0).abs() < 1e-15 && (b[1] - 7.0 / 11.0).abs() < 1e-15);
/// ```
pub fn dense_solve(n: usize, a: &mut [f64], b: &mut [f64]) -> Result<(), Singular> {
    cholesky_in_place(n, a, RELATIVE_PIVOT_TOLERANCE)?;
    cholesky_substitute(n, a, b);
    Ok(())
}

/// The dense Cholesky factorization behind [`SymmetricSolver`]: the pattern's values are
/// scattered into an m x m matrix (zero outside the pattern) and factored in place. O(m^2)
/// memory and O(m^3) time: for small m (see [`super::DENSE_MAX_ROWS`]), where it is faster than
/// the sparse factorization, and as the sparse one's oracle in tests.
#[derive(Clone, Debug)]
pub struct DenseCholesky {
    /// Pivots below this fraction of the original diagonal count as zero.
    pub relative_pivot_tolerance: f64,
    pattern: SymmetricPattern,
    /// L, row-major lower triangle (m x m)
    factor: Vec<f64>,
}

impl DenseCholesky {
    /// A dense factorization of matrices with `pattern`.
    pub fn new(pattern: &SymmetricPattern) -> Self {
        let m = pattern.dim();
        DenseCholesky {
            relative_pivot_tolerance: RELATIVE_PIVOT_TOLERANCE,
            pattern: pattern.clone(),
            factor: vec![0.0; m * m],
        }
    }
}

impl DenseCholesky {
    /// What [`SymmetricSolver::factor`] factors, for L matrices at once: the pattern's values
    /// (`values[slot * L + l]`) scattered into dense m x m matrices (`dense[(i * m + j) * L +
    /// l]`, lower triangle, zero elsewhere), to factor with [`cholesky_lanes`].
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

impl SymmetricSolver for DenseCholesky {
    fn factor(&mut self, values: &[f64]) -> Result<(), Singular> {
        let m = self.pattern.dim();
        // The lower triangle of row-major A = the upper triangle by columns.
        self.factor.fill(0.0);
        for j in 0..m {
            for (slot, &i) in self.pattern.column(j) {
                self.factor[j * m + i] = values[slot];
            }
        }
        cholesky_in_place(m, &mut self.factor, self.relative_pivot_tolerance)
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) {
        cholesky_substitute(self.pattern.dim(), &self.factor, rhs);
    }

    fn describe(&self) -> String {
        format!("dense Cholesky ({0} x {0})", self.pattern.dim())
    }

    fn dense_pivot_tolerance(&self) -> Option<f64> {
        Some(self.relative_pivot_tolerance)
    }
}
