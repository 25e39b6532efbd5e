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
    let a = &mut a[..n * n];
    for j in 0..n {
        // Row j of L: entries k < j from the rows above, then the pivot.
        for i in 0..j {
            let mut sum = a[j * n + i];
            for k in 0..i {
                sum -= a[j * n + k] * a[i * n + k];
            }
            a[j * n + i] = sum / a[i * n + i];
        }
        let diagonal = a[j * n + j];
        let pivot = diagonal - (0..j).map(|k| a[j * n + k] * a[j * n + k]).sum::<f64>();
        if !(diagonal > 0.0 && pivot > relative_pivot_tolerance * diagonal) {
            return Err(Singular {
                row: j,
                finite: diagonal.is_finite() && pivot.is_finite(),
            });
        }
        a[j * n + j] = pivot.sqrt();
    }
    Ok(())
}

/// Solve L L^T z = b with the factor of [`cholesky_in_place`]; `b` (n) becomes z.
pub fn cholesky_substitute(n: usize, a: &[f64], b: &mut [f64]) {
    let b = &mut b[..n];
    // L y = b, then L^T z = y.
    for i in 0..n {
        let mut sum = b[i];
        for k in 0..i {
            sum -= a[i * n + k] * b[k];
        }
        b[i] = sum / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut sum = b[i];
        for k in i + 1..n {
            sum -= a[k * n + i] * b[k];
        }
        b[i] = sum / a[i * n + i];
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
}
