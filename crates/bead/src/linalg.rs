//! Linear solves behind one interface, so that a sparse or linear-time solver can replace the
//! dense one without touching the formulations.

use nalgebra::{Cholesky, DMatrix, DVector};

/// A symmetric positive-definite system A z = b that could not be solved because pivot `row`
/// vanished (relative to A's own diagonal): the row is linearly dependent on earlier ones, or
/// its own gradient vanishes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Singular {
    pub row: usize,
}

/// Solves A z = b for symmetric positive-definite A (n x n, both triangles filled).
pub trait SpdSolver: Send {
    /// Overwrites `b` with the solution; `a` may be overwritten. Allocation-free after the
    /// first call at a given size.
    fn solve(&mut self, a: &mut DMatrix<f64>, b: &mut DVector<f64>) -> Result<(), Singular>;
}

/// Dense Cholesky A = L L^T (nalgebra), about n^3/3 flops, with a relative pivot test:
/// row j is singular when its pivot L_jj^2 <= eps * A_jj (or A_jj = 0). nalgebra alone only
/// rejects exactly non-positive pivots and does not say which row, so the test is ours.
#[derive(Clone, Debug)]
pub struct DenseCholesky {
    /// Pivots below this fraction of the original diagonal count as zero.
    pub relative_pivot_tolerance: f64,
    diagonal: Vec<f64>,
}

impl Default for DenseCholesky {
    fn default() -> Self {
        DenseCholesky {
            relative_pivot_tolerance: 1e-10,
            diagonal: Vec::new(),
        }
    }
}

impl SpdSolver for DenseCholesky {
    fn solve(&mut self, a: &mut DMatrix<f64>, b: &mut DVector<f64>) -> Result<(), Singular> {
        let n = a.nrows();
        self.diagonal.clear();
        self.diagonal.extend((0..n).map(|i| a[(i, i)]));
        // Move the matrix through the factorization and back: no allocation.
        let matrix = std::mem::replace(a, DMatrix::zeros(0, 0));
        let factor = Cholesky::new_unchecked(matrix);
        let l = factor.unpack_dirty();
        let singular = (0..n).find(|&j| {
            let pivot = l[(j, j)];
            let d = self.diagonal[j];
            !(d > 0.0 && pivot.is_finite() && pivot * pivot > self.relative_pivot_tolerance * d)
        });
        let factor = Cholesky::pack_dirty(l);
        if singular.is_none() {
            factor.solve_mut(b);
        }
        *a = factor.unpack_dirty();
        match singular {
            Some(row) => Err(Singular { row }),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_spd_system() {
        let mut a = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let mut b = DVector::from_row_slice(&[1.0, 2.0]);
        DenseCholesky::default().solve(&mut a, &mut b).unwrap();
        // Hand solution: z = [1/11, 7/11].
        assert!((b[0] - 1.0 / 11.0).abs() < 1e-15 && (b[1] - 7.0 / 11.0).abs() < 1e-15);
    }

    #[test]
    fn names_the_dependent_row() {
        let mut a = DMatrix::from_row_slice(3, 3, &[2.0, 0.0, 2.0, 0.0, 1.0, 0.0, 2.0, 0.0, 2.0]);
        let mut b = DVector::from_row_slice(&[1.0, 1.0, 1.0]);
        assert_eq!(
            DenseCholesky::default().solve(&mut a, &mut b),
            Err(Singular { row: 2 })
        );
    }

    #[test]
    fn zero_row_is_singular() {
        let mut a = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 0.0]);
        let mut b = DVector::from_row_slice(&[1.0, 1.0]);
        assert_eq!(
            DenseCholesky::default().solve(&mut a, &mut b),
            Err(Singular { row: 1 })
        );
    }
}
