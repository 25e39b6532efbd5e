//! Linear solves behind one interface, so that a sparse or linear-time solver can replace the
//! dense one without touching the formulations.

/// max_i |v_i|, NaN when any entry is NaN (a non-finite value must not hide behind max);
/// 0 for an empty slice.
pub(crate) fn max_abs(values: &[f64]) -> f64 {
    values.iter().fold(0.0, |m: f64, &v| max_nan(m, v.abs()))
}

/// max(a, b), NaN when either is NaN.
pub(crate) fn max_nan(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// A symmetric positive-definite system A z = b that could not be solved because pivot `row`
/// vanished (relative to A's own diagonal): the row is linearly dependent on earlier ones, or
/// its own gradient vanishes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Singular {
    pub row: usize,
    /// Whether the failing row's numbers were finite: `false` means overflow or a non-finite
    /// input (an inf or NaN diagonal or pivot), not a dependent or vanishing row.
    pub finite: bool,
}

/// Solves A z = b for a symmetric positive-definite A.
pub trait SpdSolver: Send {
    /// `a` is n x n, row-major, both triangles filled; it may be overwritten. `b` (n) is
    /// overwritten with z. Must not allocate.
    fn solve(&mut self, n: usize, a: &mut [f64], b: &mut [f64]) -> Result<(), Singular>;
}

/// Dense Cholesky A = L L^T in place (left-looking, row-major lower triangle), then forward
/// and back substitution: n^3/6 multiply-adds plus n square roots.
///
/// Pivot test: row j is singular when its pivot d_j = A_jj - sum_k L_jk^2 is not above
/// `relative_pivot_tolerance * A_jj` (or A_jj <= 0, or d_j is NaN). d_j / A_jj is the squared
/// sine of the angle between row j of J W^(1/2) and the span of the earlier rows, so the test
/// is scale-free and names the first dependent row.
///
/// ```
/// use bead::linalg::{DenseCholesky, SpdSolver};
/// let mut a = [4.0, 1.0, 1.0, 3.0];
/// let mut b = [1.0, 2.0];
/// DenseCholesky::default().solve(2, &mut a, &mut b).unwrap();
/// assert!((b[0] - 1.0 / 11.0).abs() < 1e-15 && (b[1] - 7.0 / 11.0).abs() < 1e-15);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct DenseCholesky {
    /// Pivots below this fraction of the original diagonal count as zero.
    pub relative_pivot_tolerance: f64,
}

impl Default for DenseCholesky {
    fn default() -> Self {
        DenseCholesky {
            relative_pivot_tolerance: 1e-10,
        }
    }
}

impl SpdSolver for DenseCholesky {
    fn solve(&mut self, n: usize, a: &mut [f64], b: &mut [f64]) -> Result<(), Singular> {
        let a = &mut a[..n * n];
        let b = &mut b[..n];
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
            if !(diagonal > 0.0 && pivot > self.relative_pivot_tolerance * diagonal) {
                return Err(Singular {
                    row: j,
                    finite: diagonal.is_finite() && pivot.is_finite(),
                });
            }
            a[j * n + j] = pivot.sqrt();
        }
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
        Ok(())
    }
}

/// A pivot below this fraction of its column's largest original entry counts as zero in
/// [`solve_general`].
const GENERAL_RELATIVE_PIVOT_TOLERANCE: f64 = 1e-10;

/// Solve A z = b (A m x m, row-major, general) by Gaussian elimination with partial pivoting,
/// in place; `b` becomes z. Err(column) when that column has no usable pivot (relative to the
/// column's largest original entry): its constraint is dependent on earlier ones or its
/// gradient vanishes.
pub fn solve_general(
    m: usize,
    a: &mut [f64],
    b: &mut [f64],
    column_scale: &mut [f64],
) -> Result<(), usize> {
    for j in 0..m {
        column_scale[j] = (0..m).fold(0.0, |s: f64, i| s.max(a[i * m + j].abs()));
    }
    for j in 0..m {
        let (mut pivot_row, mut pivot) = (j, 0.0);
        for i in j..m {
            let value = a[i * m + j].abs();
            if value > pivot {
                (pivot_row, pivot) = (i, value);
            }
        }
        // Written so that NaN counts as singular.
        let usable = pivot > GENERAL_RELATIVE_PIVOT_TOLERANCE * column_scale[j];
        if !usable {
            return Err(j);
        }
        if pivot_row != j {
            for k in 0..m {
                a.swap(j * m + k, pivot_row * m + k);
            }
            b.swap(j, pivot_row);
        }
        let diagonal = a[j * m + j];
        for i in j + 1..m {
            let factor = a[i * m + j] / diagonal;
            if factor != 0.0 {
                for k in j..m {
                    a[i * m + k] -= factor * a[j * m + k];
                }
                b[i] -= factor * b[j];
            }
        }
    }
    for i in (0..m).rev() {
        let mut sum = b[i];
        for k in i + 1..m {
            sum -= a[i * m + k] * b[k];
        }
        b[i] = sum / a[i * m + i];
    }
    Ok(())
}

/// Look for a zero of g: R^k -> R^m near `y` by Gauss-Newton with Levenberg damping:
/// `y <- y - (D^T D + mu I)^-1 D^T g`, D = dg/dy (m x k, row-major), mu = 1e-12 trace(D^T D).
/// `eval(y, g, d)` writes g(y) (m) and D(y). Stops after `max_iterations`, when |g| falls
/// below `1e-12` of its start, or when an iteration no longer reduces it by a tenth.
/// Returns |g(y_end)| / |g(y_start)| (0 when g(y_start) = 0; NaN when not finite). For a
/// regular zero the reduction is quadratic; for a double one (a cusp) it is a constant
/// factor per iteration. Where g has no zero (the gradient of a parabola, whose component
/// along the axis is constant) the reduction stalls above it.
///
/// Off the hot path: it allocates its buffers. Used to confirm singular points of
/// constraints before a run is stopped for one.
pub fn gauss_newton_zero(
    y: &mut [f64],
    m: usize,
    max_iterations: usize,
    mut eval: impl FnMut(&[f64], &mut [f64], &mut [f64]),
) -> f64 {
    let k = y.len();
    let mut g = vec![0.0; m];
    let mut d = vec![0.0; m * k];
    let mut normal = vec![0.0; k * k];
    let mut rhs = vec![0.0; k];
    let norm = |g: &[f64]| g.iter().map(|c| c * c).sum::<f64>().sqrt();
    eval(y, &mut g, &mut d);
    let start = norm(&g);
    if !start.is_finite() {
        return f64::NAN;
    }
    if start == 0.0 {
        return 0.0;
    }
    let mut current = start;
    let mut trial = y.to_vec();
    for _ in 0..max_iterations {
        // Normal equations (D^T D + mu I) step = D^T g.
        for a in 0..k {
            for b in 0..k {
                normal[a * k + b] = (0..m).map(|i| d[i * k + a] * d[i * k + b]).sum();
            }
            rhs[a] = (0..m).map(|i| d[i * k + a] * g[i]).sum();
        }
        let trace: f64 = (0..k).map(|a| normal[a * k + a]).sum();
        if !(trace > 0.0 && trace.is_finite()) {
            break;
        }
        for a in 0..k {
            normal[a * k + a] += 1e-12 * trace;
        }
        let mut solver = DenseCholesky {
            relative_pivot_tolerance: 0.0,
        };
        if solver.solve(k, &mut normal, &mut rhs).is_err() {
            break;
        }
        for ((t, y), step) in trial.iter_mut().zip(y.iter()).zip(&rhs) {
            *t = y - step;
        }
        eval(&trial, &mut g, &mut d);
        let next = norm(&g);
        if next.is_nan() || next >= 0.9 * current {
            // No longer converging: keep the best point found.
            break;
        }
        y.copy_from_slice(&trial);
        current = next;
        if current <= 1e-12 * start {
            break;
        }
    }
    current / start
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gradient of the node curve y^2 - x^2 (x + 1) vanishes at the origin; Gauss-Newton
    /// from nearby finds it. The parabola's gradient (2x, 100) never vanishes: the search
    /// stalls at the vertex.
    #[test]
    fn gauss_newton_finds_the_node_and_not_the_parabola_vertex() {
        let node = |y: &[f64], g: &mut [f64], d: &mut [f64]| {
            let (x, yy) = (y[0], y[1]);
            g[0] = -3.0 * x * x - 2.0 * x;
            g[1] = 2.0 * yy;
            d.copy_from_slice(&[-6.0 * x - 2.0, 0.0, 0.0, 2.0]);
        };
        let mut y = [0.05, -0.04];
        let reduction = gauss_newton_zero(&mut y, 2, 40, node);
        assert!(reduction < 1e-10, "{reduction}");
        assert!(y[0].abs() < 1e-12 && y[1].abs() < 1e-12, "{y:?}");

        let parabola = |y: &[f64], g: &mut [f64], d: &mut [f64]| {
            g[0] = 2.0 * y[0];
            g[1] = 100.0;
            d.copy_from_slice(&[2.0, 0.0, 0.0, 0.0]);
        };
        let mut y = [300.0, -900.0];
        let reduction = gauss_newton_zero(&mut y, 2, 40, parabola);
        assert!(reduction > 0.1, "{reduction}");

        // The cusp y^2 - x^3: a double zero in x, found at a constant rate.
        let cusp = |y: &[f64], g: &mut [f64], d: &mut [f64]| {
            g[0] = -3.0 * y[0] * y[0];
            g[1] = 2.0 * y[1];
            d.copy_from_slice(&[-6.0 * y[0], 0.0, 0.0, 2.0]);
        };
        let mut y = [0.01, 0.001];
        let reduction = gauss_newton_zero(&mut y, 2, 40, cusp);
        assert!(reduction < 1e-8, "{reduction}");
    }

    /// A z = b with a random SPD A = B B^T + I: the residual is at round-off.
    #[test]
    fn solves_random_spd_systems() {
        let mut seed = 0x9e3779b97f4a7c15_u64;
        let mut random = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for n in 1..8 {
            let b_matrix: Vec<f64> = (0..n * n).map(|_| random()).collect();
            let mut a = vec![0.0; n * n];
            for i in 0..n {
                for j in 0..n {
                    a[i * n + j] = (0..n)
                        .map(|k| b_matrix[i * n + k] * b_matrix[j * n + k])
                        .sum::<f64>()
                        + if i == j { 1.0 } else { 0.0 };
                }
            }
            let rhs: Vec<f64> = (0..n).map(|_| random()).collect();
            let (mut factor, mut z) = (a.clone(), rhs.clone());
            DenseCholesky::default()
                .solve(n, &mut factor, &mut z)
                .unwrap();
            for i in 0..n {
                let az: f64 = (0..n).map(|j| a[i * n + j] * z[j]).sum();
                assert!(
                    (az - rhs[i]).abs() < 1e-13,
                    "n = {n}, row {i}: {az} vs {}",
                    rhs[i]
                );
            }
        }
    }

    #[test]
    fn names_the_dependent_row() {
        let mut a = [2.0, 0.0, 2.0, 0.0, 1.0, 0.0, 2.0, 0.0, 2.0];
        let mut b = [1.0, 1.0, 1.0];
        assert_eq!(
            DenseCholesky::default().solve(3, &mut a, &mut b),
            Err(Singular {
                row: 2,
                finite: true
            })
        );
    }

    #[test]
    fn zero_row_is_singular() {
        let mut a = [1.0, 0.0, 0.0, 0.0];
        let mut b = [1.0, 1.0];
        assert_eq!(
            DenseCholesky::default().solve(2, &mut a, &mut b),
            Err(Singular {
                row: 1,
                finite: true
            })
        );
    }

    #[test]
    fn nan_is_singular_not_propagated() {
        let mut a = [f64::NAN];
        let mut b = [1.0];
        assert_eq!(
            DenseCholesky::default().solve(1, &mut a, &mut b),
            Err(Singular {
                row: 0,
                finite: false
            })
        );
    }
}
