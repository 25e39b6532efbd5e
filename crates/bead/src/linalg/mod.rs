//! Linear solves behind one interface, so that the formulations and integrators do not know
//! whether a system is solved densely or sparsely.
//!
//! - [`SymmetricPattern`]: the nonzero pattern of a symmetric matrix (upper triangle by
//!   columns), fixed when a formulation is built; values live in a flat array in its order.
//! - [`SymmetricSolver`]: factor a matrix given by those values, then solve with the factor
//!   as many right-hand sides as needed. [`DenseLdlt`] for small systems, [`SparseLdlt`]
//!   (faer's sparse LDL^T, symbolic analysis once, numeric factorization allocation-free) for
//!   large ones, [`PathLdlt`] (the Thomas algorithm) for large ones whose rows couple in
//!   paths (chains, ropes); [`symmetric_solver`] picks one ([`LinearSolver`]).
//! - [`RowStructure`] and [`ConstraintMatrix`]: the sparse rows of a constraint Jacobian J and
//!   the matrix J W J^T assembled straight from them through slots computed once.

mod constraint_matrix;
mod dense;
mod kkt;
mod path;
mod pattern;
mod rod_path;
mod sparse;

pub(crate) use constraint_matrix::LazyConstraintMatrix;
pub use constraint_matrix::{ConstraintMatrix, RowStructure};
pub use dense::{dense_solve, ldlt_in_place, ldlt_substitute, DenseLdlt};
pub(crate) use dense::{ldlt_lanes, ldlt_substitute_lanes};
pub use kkt::{Curvature, NewtonMatrixError, ProjectionNewtonMatrix, RowCurvature};
pub use path::{PathLdlt, PathOrder};
pub use pattern::SymmetricPattern;
pub use rod_path::{stiffness_bound_of_rows, RodPath};
pub use sparse::{Ordering, SparseLdlt, SparseOptions};

/// max_i |v_i|, NaN when any entry is NaN (a non-finite value must not hide behind max);
/// 0 for an empty slice.
///
/// The largest |v_i| is the same whatever order the entries are visited in (a maximum
/// rounds nothing, and |v| has no signed zero), so four running maxima and a NaN flag give
/// the bits of the one-by-one fold, in vector registers.
pub(crate) fn max_abs(values: &[f64]) -> f64 {
    let (chunks, rest) = values.as_chunks::<4>();
    let mut lanes = [0.0_f64; 4];
    let mut nan = false;
    for chunk in chunks {
        for (lane, v) in lanes.iter_mut().zip(chunk) {
            let size = v.abs();
            // A select, no branch; NaN never replaces the running maximum.
            *lane = if size > *lane { size } else { *lane };
            nan |= v.is_nan();
        }
    }
    let mut largest = lanes.into_iter().fold(0.0, f64::max);
    for v in rest {
        largest = max_nan(largest, v.abs());
    }
    if nan {
        f64::NAN
    } else {
        largest
    }
}

/// Whether every entry is finite: every entry tested, no early exit, so that the test runs
/// in vector registers (the common case, all finite, reads them all anyway).
pub(crate) fn all_finite(values: &[f64]) -> bool {
    values.iter().fold(true, |finite, v| finite & v.is_finite())
}

/// max(a, b), NaN when either is NaN.
pub(crate) fn max_nan(a: f64, b: f64) -> f64 {
    // One compare-and-select, no branch, in lane loops: a NaN a is kept, and a NaN b wins
    // the comparison's failure. (Equal arguments give b: the callers' are magnitudes, never
    // -0.0, so which of two equal ones comes back changes no bit.)
    if (a > b) | a.is_nan() {
        a
    } else {
        b
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

/// Pivots of a symmetric positive-definite factorization below this fraction of the original
/// diagonal count as zero (see [`ldlt_in_place`]).
pub const RELATIVE_PIVOT_TOLERANCE: f64 = 1e-10;

/// Factor a symmetric positive-definite matrix A given by its values in the order of a
/// [`SymmetricPattern`] (the one the solver was built for), then solve A z = b with the factor
/// for as many right-hand sides as needed. Neither allocates.
pub trait SymmetricSolver: Send {
    /// Factor A (`values`: the pattern's upper triangle). A pivot at or below
    /// [`RELATIVE_PIVOT_TOLERANCE`] of its diagonal entry (or a non-positive or non-finite one)
    /// is [`Singular`], naming the row of A (in A's own order, whatever order the factorization
    /// eliminates in) whose pivot failed first.
    fn factor(&mut self, values: &[f64]) -> Result<(), Singular>;
    /// Overwrite `rhs` (m) with A^-1 rhs, A the last matrix factored without error.
    fn solve_in_place(&mut self, rhs: &mut [f64]);
    /// What it is, for diagnostics (e.g. `sparse LDL^T (identity ordering, simplicial)`).
    fn describe(&self) -> String;
    /// The order that makes A tridiagonal, when the solver works in one ([`PathLdlt`]).
    fn path(&self) -> Option<&PathOrder> {
        None
    }
    /// The pivot tolerance of a dense LDL^T factorization ([`DenseLdlt`]), which an
    /// ensemble can then run for many members at once with the same arithmetic; `None` for
    /// the other solvers.
    fn dense_pivot_tolerance(&self) -> Option<f64> {
        None
    }
}

/// Which factorization solves the symmetric systems of a formulation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LinearSolver {
    /// Dense for at most [`DENSE_MAX_ROWS`] rows; above, [`PathLdlt`] when the rows couple in
    /// paths, else [`SparseLdlt`].
    #[default]
    Auto,
    /// [`DenseLdlt`] whatever the size: O(m^2) memory, O(m^3) time.
    Dense,
    /// [`SparseLdlt`] with its automatic ordering, whatever the size.
    Sparse,
    /// [`PathLdlt`] whatever the size when the rows couple in paths, else [`SparseLdlt`].
    Tridiagonal,
}

/// The largest system [`LinearSolver::Auto`] solves densely. Measured on chains (one step of
/// rk4 and of rattle, see DESIGN.md): the dense factorization is faster up to about this size.
pub const DENSE_MAX_ROWS: usize = 8;

/// Whether [`symmetric_solver`] factors an m x m matrix with `kind` densely.
pub fn solves_densely(kind: LinearSolver, m: usize) -> bool {
    match kind {
        LinearSolver::Dense => true,
        LinearSolver::Auto => m <= DENSE_MAX_ROWS,
        LinearSolver::Tridiagonal | LinearSolver::Sparse => false,
    }
}

/// The solver `kind` for matrices with `pattern`.
pub fn symmetric_solver(
    pattern: &SymmetricPattern,
    kind: LinearSolver,
) -> Box<dyn SymmetricSolver> {
    if solves_densely(kind, pattern.dim()) {
        return Box::new(DenseLdlt::new(pattern));
    }
    match kind {
        LinearSolver::Auto | LinearSolver::Tridiagonal => {
            if let Some(path) = PathLdlt::new(pattern) {
                return Box::new(path);
            }
        }
        LinearSolver::Dense | LinearSolver::Sparse => {}
    }
    Box::new(SparseLdlt::new(pattern, SparseOptions::default()))
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
/// Returns |g(y_end)| / |g(y_start)| (0 when g(y_start) = 0; NaN when not finite) and
/// |g(y_end)| itself (a reduction from a far start can end at a g that is small only
/// against its start). For a
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
) -> (f64, f64) {
    let k = y.len();
    let mut g = vec![0.0; m];
    let mut d = vec![0.0; m * k];
    let mut normal = vec![0.0; k * k];
    let mut rhs = vec![0.0; k];
    let norm = |g: &[f64]| g.iter().map(|c| c * c).sum::<f64>().sqrt();
    eval(y, &mut g, &mut d);
    let start = norm(&g);
    if !start.is_finite() {
        return (f64::NAN, f64::NAN);
    }
    if start == 0.0 {
        return (0.0, 0.0);
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
        if ldlt_in_place(k, &mut normal, 0.0).is_err() {
            break;
        }
        ldlt_substitute(k, &normal, &mut rhs);
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
    (current / start, current)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// max(a, b), NaN when either is: each order, infinities, equal arguments.
    #[test]
    fn max_nan_is_the_maximum_or_nan() {
        let values = [0.0, 1.5, -2.0, 1e300, f64::INFINITY, f64::NEG_INFINITY];
        for a in values {
            for b in values {
                let want = if a >= b { a } else { b };
                assert_eq!(max_nan(a, b).to_bits(), want.to_bits(), "{a} {b}");
            }
            assert!(
                max_nan(a, f64::NAN).is_nan() && max_nan(f64::NAN, a).is_nan(),
                "{a}"
            );
        }
        assert!(max_nan(f64::NAN, f64::NAN).is_nan());
    }

    /// The four-lane maximum gives the bits of the one-by-one fold for every length and
    /// every position of a NaN, an infinity, a negative zero or the largest entry; the
    /// finiteness test sees a NaN or an infinity wherever it is.
    #[test]
    fn max_abs_and_all_finite_see_every_entry() {
        let fold = |v: &[f64]| v.iter().fold(0.0, |m: f64, &c| max_nan(m, c.abs()));
        for len in 0..11 {
            let base: Vec<f64> = (0..len).map(|i| ((i * 7 % 5) as f64 - 2.0) * 0.3).collect();
            assert_eq!(max_abs(&base).to_bits(), fold(&base).to_bits(), "{base:?}");
            for at in 0..len {
                for special in [
                    f64::NAN,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    -0.0,
                    -9.5,
                    1e300,
                ] {
                    let mut v = base.clone();
                    v[at] = special;
                    assert_eq!(all_finite(&v), special.is_finite(), "{v:?}");
                    let (got, want) = (max_abs(&v), fold(&v));
                    assert!(
                        got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                        "{v:?}: {got} against {want}"
                    );
                }
            }
        }
        assert_eq!(max_abs(&[]).to_bits(), 0.0_f64.to_bits());
        assert_eq!(max_abs(&[-0.0; 6]).to_bits(), 0.0_f64.to_bits());
    }

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
        let (reduction, _) = gauss_newton_zero(&mut y, 2, 40, node);
        assert!(reduction < 1e-10, "{reduction}");
        assert!(y[0].abs() < 1e-12 && y[1].abs() < 1e-12, "{y:?}");

        let parabola = |y: &[f64], g: &mut [f64], d: &mut [f64]| {
            g[0] = 2.0 * y[0];
            g[1] = 100.0;
            d.copy_from_slice(&[2.0, 0.0, 0.0, 0.0]);
        };
        let mut y = [300.0, -900.0];
        let (reduction, _) = gauss_newton_zero(&mut y, 2, 40, parabola);
        assert!(reduction > 0.1, "{reduction}");

        // The cusp y^2 - x^3: a double zero in x, found at a constant rate.
        let cusp = |y: &[f64], g: &mut [f64], d: &mut [f64]| {
            g[0] = -3.0 * y[0] * y[0];
            g[1] = 2.0 * y[1];
            d.copy_from_slice(&[-6.0 * y[0], 0.0, 0.0, 2.0]);
        };
        let mut y = [0.01, 0.001];
        let (reduction, _) = gauss_newton_zero(&mut y, 2, 40, cusp);
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
            dense_solve(n, &mut factor, &mut z).unwrap();
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
    fn general_solve_with_pivoting() {
        // [[0, 2], [3, 1]] z = [4, 5] -> z = [1, 2]
        let mut a = [0.0, 2.0, 3.0, 1.0];
        let mut b = [4.0, 5.0];
        let mut scale = [0.0; 2];
        solve_general(2, &mut a, &mut b, &mut scale).unwrap();
        assert!(
            (b[0] - 1.0).abs() < 1e-15 && (b[1] - 2.0).abs() < 1e-15,
            "{b:?}"
        );
    }

    #[test]
    fn general_solve_names_the_dependent_column() {
        let mut a = [1.0, 2.0, 2.0, 4.0];
        let mut b = [1.0, 1.0];
        let mut scale = [0.0; 2];
        assert_eq!(solve_general(2, &mut a, &mut b, &mut scale), Err(1));
        let mut a = [1.0, 0.0, 0.0, 0.0];
        assert_eq!(solve_general(2, &mut a, &mut b, &mut scale), Err(1));
    }

    #[test]
    fn names_the_dependent_row() {
        let mut a = [2.0, 0.0, 2.0, 0.0, 1.0, 0.0, 2.0, 0.0, 2.0];
        let mut b = [1.0, 1.0, 1.0];
        assert_eq!(
            dense_solve(3, &mut a, &mut b),
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
            dense_solve(2, &mut a, &mut b),
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
            dense_solve(1, &mut a, &mut b),
            Err(Singular {
                row: 0,
                finite: false
            })
        );
    }
}
