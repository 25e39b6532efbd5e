//! The Newton matrix of a closest-point projection onto constraints.
//!
//! The projection of q* onto C(q) = 0 in the mass metric,
//!
//! ```text
//! minimize 1/2 (q - q*)^T M (q - q*)   subject to C(q) = 0,
//! ```
//!
//! has the optimality conditions M (q - q*) + J(q)^T lambda = 0, C(q) = 0, and Newton's
//! method on them solves at every iterate
//!
//! ```text
//! [ M + sum_i lambda_i H_i   J^T ] [ dq      ]     [ M (q - q*) + J^T lambda ]
//! [ J                         0  ] [ dlambda ] = - [ C(q)                    ]
//! ```
//!
//! with H_i = d2C_i/dq2. This matrix is assembled here for rows whose Hessian is a constant
//! multiple of a graph Laplacian ([`RowCurvature`]: bead's distance rows, H = (1/L) [I, -I;
//! -I, I]); the other rows' Hessians are left out (Gauss-Newton in those rows). While the
//! top-left block is positive definite the matrix is quasi-definite
//! ([`SparseLdlt::quasi_definite`]); compressed rods (lambda_i < 0) can make it indefinite,
//! which the factorization reports ([`NewtonMatrixError::NotPositive`]), and
//! [`Curvature::TensionOnly`] then keeps it definite. The pattern and its symbolic analysis
//! are fixed once; every factorization reuses them.

use super::{
    Ordering, RowStructure, Singular, SparseLdlt, SparseOptions, SymmetricPattern, SymmetricSolver,
};

/// The multipliers' block of the matrix is -delta diag(J_i W J_i^T) with this delta rather
/// than 0: the matrix is then quasi-definite and factors in any order (AMD's, which would
/// otherwise eliminate a multiplier before its unknowns and meet a zero pivot), at the
/// price of a Newton step that is exact only to about delta relative, which the iteration
/// (its residual exact) corrects.
pub const MULTIPLIER_REGULARIZATION: f64 = 1e-8;

/// Which multipliers' curvature the matrix takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Curvature {
    /// Every row's, lambda_i H_i as it is: Newton's method itself, while
    /// M + sum_i lambda_i H_i stays positive definite (compressed rods, lambda_i < 0,
    /// subtract from it).
    Signed,
    /// Only rows pulling (lambda_i > 0): positive definite always.
    TensionOnly,
}

/// Why the projection's Newton matrix did not factor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NewtonMatrixError {
    /// Constraint row `row` reads no coordinate that moves (J_i W J_i^T = 0). A row that
    /// depends on others is not caught here: the regularization keeps its pivot at least
    /// delta J_i W J_i^T; the velocity projection's J W J^T (`project_velocities`) names it.
    Dependent { row: usize },
    /// M + sum_i lambda_i H_i is not positive definite: a coordinate's pivot vanished or
    /// turned negative (relative to its mass and curvature), as compressed rods can make it.
    NotPositive,
    /// A value was not finite.
    NonFinite,
}

/// A constraint row whose Hessian is `scale` [I, -I; -I, I] over the `dim` coordinates
/// starting at `a` and those starting at `b` (`scale` I over a's alone when `b` is `None`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RowCurvature {
    pub row: usize,
    pub a: usize,
    pub b: Option<usize>,
    pub dim: usize,
    pub scale: f64,
}

/// Where one axis of a [`RowCurvature`] adds its terms: (a, a), (b, b), (a, b); `None`
/// where a coordinate does not move. `a` and `b` are the axis's coordinates.
#[derive(Clone, Copy, Debug)]
struct CurvatureSlots {
    a: usize,
    b: Option<usize>,
    aa: Option<usize>,
    bb: Option<usize>,
    ab: Option<usize>,
}

/// The projection's Newton matrix (see the module): n coordinates, then m multipliers.
pub struct ProjectionNewtonMatrix {
    n: usize,
    /// M_kk = 1 / W_kk (n)
    mass: Vec<f64>,
    inverse_mass: Vec<f64>,
    /// The matrix's values in the pattern's order
    values: Vec<f64>,
    /// The diagonal's slots (n + m)
    diagonal_slots: Vec<usize>,
    /// The slot of J's entry s, at (column, n + row), if its column moves (nnz(J))
    jacobian_slots: Vec<Option<usize>>,
    /// (row, column) of J's entry s (nnz(J))
    entries: Vec<(usize, usize)>,
    curvature: Vec<RowCurvature>,
    /// `dim` entries per curvature row, in order
    curvature_slots: Vec<CurvatureSlots>,
    /// What each pivot is measured against (n + m)
    pivot_scales: Vec<f64>,
    solver: SparseLdlt,
    /// The right-hand side and solution (n + m)
    rhs: Vec<f64>,
}

impl ProjectionNewtonMatrix {
    /// The pattern of the matrix for J's `rows`, the inverse masses (0 for a coordinate
    /// that does not move) and the rows with curvature, and its symbolic analysis.
    pub fn new(rows: RowStructure<'_>, inverse_mass: &[f64], curvature: Vec<RowCurvature>) -> Self {
        let (n, m) = (inverse_mass.len(), rows.n_rows());
        // A coordinate of infinite mass (W_kk = 0: an integrated quantity such as the
        // ledger's work) does not move: its row is 1 dq_k = 0, no entry couples it.
        let movable = |k: usize| inverse_mass[k] > 0.0;
        let mut pairs: Vec<(usize, usize)> = Vec::with_capacity(rows.n_nonzeros());
        let mut entries = Vec::with_capacity(rows.n_nonzeros());
        for i in 0..m {
            for &column in rows.row_columns(i) {
                if movable(column) {
                    pairs.push((column, n + i));
                }
                entries.push((i, column));
            }
        }
        for c in &curvature {
            if let Some(b) = c.b {
                pairs.extend(
                    (0..c.dim)
                        .map(|axis| (c.a + axis, b + axis))
                        .filter(|&(a, b)| movable(a) && movable(b)),
                );
            }
        }
        let pattern = SymmetricPattern::new(n + m, pairs);
        let slot = |i: usize, j: usize| pattern.slot(i, j).expect("an entry of the pattern");
        let jacobian_slots = entries
            .iter()
            .map(|&(row, column)| movable(column).then(|| slot(column, n + row)))
            .collect();
        let curvature_slots = curvature
            .iter()
            .flat_map(|c| {
                (0..c.dim).map(move |axis| {
                    let (a, b) = (c.a + axis, c.b.map(|b| b + axis));
                    CurvatureSlots {
                        a,
                        b,
                        aa: movable(a).then(|| slot(a, a)),
                        bb: b.filter(|&b| movable(b)).map(|b| slot(b, b)),
                        ab: b.filter(|&b| movable(a) && movable(b)).map(|b| slot(a, b)),
                    }
                })
            })
            .collect();
        let signs = (0..n + m).map(|k| if k < n { 1 } else { -1 }).collect();
        let options = SparseOptions {
            ordering: Ordering::Amd,
            supernodal: None,
        };
        let solver = SparseLdlt::quasi_definite(&pattern, options, signs);
        ProjectionNewtonMatrix {
            n,
            mass: inverse_mass
                .iter()
                .map(|&w| if w > 0.0 { 1.0 / w } else { 1.0 })
                .collect(),
            inverse_mass: inverse_mass.to_vec(),
            values: vec![0.0; pattern.nnz()],
            diagonal_slots: (0..n + m).map(|k| pattern.diagonal_slot(k)).collect(),
            jacobian_slots,
            entries,
            curvature,
            curvature_slots,
            pivot_scales: vec![0.0; n + m],
            solver,
            rhs: vec![0.0; n + m],
        }
    }

    /// The factorization's description (size, ordering, layout, values in L).
    pub fn describe(&self) -> String {
        self.solver.describe()
    }

    /// Assemble the matrix at J's entries `jacobian` (in the row structure's order) and the
    /// multipliers `lambda` (m), with `curvature`, and factor it.
    pub fn factor(
        &mut self,
        jacobian: &[f64],
        lambda: &[f64],
        curvature: Curvature,
    ) -> Result<(), NewtonMatrixError> {
        let n = self.n;
        self.values.fill(0.0);
        for (k, &slot) in self.diagonal_slots[..n].iter().enumerate() {
            self.values[slot] = self.mass[k];
            self.pivot_scales[k] = self.mass[k];
        }
        // A multiplier's pivot is measured against J_i W J_i^T: its pivot if H were M and
        // only its own unknowns were eliminated before it.
        self.pivot_scales[n..].fill(0.0);
        for (s, (&slot, &(row, column))) in
            self.jacobian_slots.iter().zip(&self.entries).enumerate()
        {
            if let Some(slot) = slot {
                let value = jacobian[s];
                self.values[slot] = value;
                self.pivot_scales[n + row] += value * value * self.inverse_mass[column];
            }
        }
        let mut slots = self.curvature_slots.iter();
        for c in &self.curvature {
            let weight = match curvature {
                Curvature::Signed => lambda[c.row],
                Curvature::TensionOnly => lambda[c.row].max(0.0),
            } * c.scale;
            for slots in slots.by_ref().take(c.dim) {
                for (slot, sign) in [(slots.aa, 1.0), (slots.bb, 1.0), (slots.ab, -1.0)] {
                    if let Some(slot) = slot {
                        self.values[slot] += sign * weight;
                    }
                }
                // A coordinate's pivot is measured against its mass and the size of the
                // curvature on it.
                if slots.aa.is_some() {
                    self.pivot_scales[slots.a] += weight.abs();
                }
                if let (Some(b), Some(_)) = (slots.b, slots.bb) {
                    self.pivot_scales[b] += weight.abs();
                }
            }
        }
        for (&slot, scale) in self.diagonal_slots[n..].iter().zip(&self.pivot_scales[n..]) {
            self.values[slot] = -MULTIPLIER_REGULARIZATION * scale;
        }
        self.solver
            .factor_signed(&self.values, &self.pivot_scales)
            .map_err(|singular| match singular {
                Singular { finite: false, .. } => NewtonMatrixError::NonFinite,
                Singular { row, .. } if row < n => NewtonMatrixError::NotPositive,
                Singular { row, .. } => NewtonMatrixError::Dependent { row: row - n },
            })
    }

    /// Solve with the last factorization: `residual_q` (n) = M (q - q*) + J^T lambda and
    /// `residual_c` (m) = C in, the Newton step (dq, dlambda) = -K^-1 (residual_q,
    /// residual_c) out.
    pub fn solve(
        &mut self,
        residual_q: &[f64],
        residual_c: &[f64],
        dq: &mut [f64],
        dlambda: &mut [f64],
    ) {
        let n = self.n;
        for (r, value) in self.rhs.iter_mut().zip(residual_q.iter().chain(residual_c)) {
            *r = -value;
        }
        for (r, w) in self.rhs.iter_mut().zip(&self.inverse_mass) {
            if *w == 0.0 {
                *r = 0.0;
            }
        }
        self.solver.solve_in_place(&mut self.rhs);
        dq.copy_from_slice(&self.rhs[..n]);
        dlambda.copy_from_slice(&self.rhs[n..]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// In 2D: particle 0 (mass 2) on a circle of radius 1 about the origin, particle 1
    /// (mass 3) at distance 1.5 from it, and particle 1's x held by a row without curvature.
    /// The Newton step agrees with Gaussian elimination on the matrix written out by hand
    /// (the Hessians of C = (|d|^2 - L^2) / (2L) taken by hand), with the compressed rod's
    /// curvature and without it.
    #[test]
    fn the_newton_step_agrees_with_the_matrix_written_out() {
        let (x0, x1) = ([0.6, 0.9], [1.7, 1.6]);
        let (l0, l1) = (1.0, 1.5);
        let w = [0.5, 0.5, 1.0 / 3.0, 1.0 / 3.0];
        let row_start = [0, 2, 6, 7];
        let columns = [0, 1, 0, 1, 2, 3, 2];
        let d = [x0[0] - x1[0], x0[1] - x1[1]];
        let jacobian = [
            x0[0] / l0,
            x0[1] / l0,
            d[0] / l1,
            d[1] / l1,
            -d[0] / l1,
            -d[1] / l1,
            1.0,
        ];
        let lambda = [0.3, -0.2, 0.7];
        let curvature = vec![
            RowCurvature {
                row: 0,
                a: 0,
                b: None,
                dim: 2,
                scale: 1.0 / l0,
            },
            RowCurvature {
                row: 1,
                a: 0,
                b: Some(2),
                dim: 2,
                scale: 1.0 / l1,
            },
        ];
        let rows = RowStructure::new(&row_start, &columns);
        let mut matrix = ProjectionNewtonMatrix::new(rows, &w, curvature);
        let residual_q = [0.1, -0.2, 0.05, 0.3];
        let residual_c = [0.01, -0.02, 0.03];
        let j_rows: [[f64; 4]; 3] = [
            [x0[0] / l0, x0[1] / l0, 0.0, 0.0],
            [d[0] / l1, d[1] / l1, -d[0] / l1, -d[1] / l1],
            [0.0, 0.0, 1.0, 0.0],
        ];
        for mode in [Curvature::Signed, Curvature::TensionOnly] {
            matrix.factor(&jacobian, &lambda, mode).unwrap();
            let (mut dq, mut dlambda) = ([0.0; 4], [0.0; 3]);
            matrix.solve(&residual_q, &residual_c, &mut dq, &mut dlambda);

            // By hand: M, lambda_0 (1/l0) I on particle 0, lambda_1 (1/l1) [I, -I; -I, I]
            // on both (Signed only: lambda_1 < 0), J^T, J, and the regularization
            // -delta J_i W J_i^T.
            let k = 7;
            let mut dense = vec![0.0; k * k];
            for c in 0..4 {
                dense[c * k + c] = 1.0 / w[c];
            }
            for c in 0..2 {
                dense[c * k + c] += lambda[0] / l0;
                if mode == Curvature::Signed {
                    let h = lambda[1] / l1;
                    dense[c * k + c] += h;
                    dense[(c + 2) * k + c + 2] += h;
                    dense[c * k + c + 2] -= h;
                    dense[(c + 2) * k + c] -= h;
                }
            }
            for (i, row) in j_rows.iter().enumerate() {
                for c in 0..4 {
                    dense[(4 + i) * k + c] = row[c];
                    dense[c * k + 4 + i] = row[c];
                }
                let jwj: f64 = (0..4).map(|c| row[c] * row[c] * w[c]).sum();
                dense[(4 + i) * k + 4 + i] = -MULTIPLIER_REGULARIZATION * jwj;
            }
            let mut expected: Vec<f64> = residual_q.iter().chain(&residual_c).map(|r| -r).collect();
            super::super::solve_general(k, &mut dense, &mut expected, &mut [0.0; 7]).unwrap();
            // To about delta relative: AMD eliminates the pin's multiplier first, whose
            // pivot is -delta J W J^T, and its unknown's pivot then carries 1/delta beside
            // its mass (the iteration's exact residual corrects what the step misses).
            let got: Vec<f64> = dq.iter().chain(&dlambda).copied().collect();
            for (g, e) in got.iter().zip(&expected) {
                assert!(
                    (g - e).abs() < 10.0 * MULTIPLIER_REGULARIZATION * (1.0 + e.abs()),
                    "{mode:?}: {got:?} vs {expected:?}"
                );
            }
        }
        // A rod compressed hard enough makes M + lambda H indefinite: said, and the tension
        // alone still factors.
        let crushed = [0.3, -40.0, 0.7];
        assert_eq!(
            matrix.factor(&jacobian, &crushed, Curvature::Signed),
            Err(NewtonMatrixError::NotPositive)
        );
        matrix
            .factor(&jacobian, &crushed, Curvature::TensionOnly)
            .unwrap();
    }
}
