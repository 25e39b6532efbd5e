//! The sparse LDL^T factorization of large systems (faer).

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::reborrow::Reborrow;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LdltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};

use super::{Singular, SymmetricPattern, SymmetricSolver, RELATIVE_PIVOT_TOLERANCE};

/// The elimination order of a sparse factorization.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Ordering {
    /// The identity when it fills L no more than AMD does (a chain or tree whose rows are
    /// declared parent first has no fill in its own order, and the identity saves the
    /// permutation of A and of every right-hand side), else AMD.
    #[default]
    Auto,
    /// Approximate minimum degree (faer's AMD).
    Amd,
    /// The rows' own order.
    Identity,
}

/// How [`SparseLdlt`] factors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SparseOptions {
    pub ordering: Ordering,
    /// `Some(true)`: supernodal (dense blocks), `Some(false)`: simplicial (one column at a
    /// time), `None`: faer decides from the flop count of the symbolic analysis.
    pub supernodal: Option<bool>,
}

/// A symmetric positive-definite matrix factored as P A P^T = L D L^T by faer's sparse
/// factorization: the symbolic analysis (ordering, elimination tree, pattern of L) is done
/// once in [`SparseLdlt::new`]; [`SymmetricSolver::factor`] computes L and D into buffers
/// sized then and [`SymmetricSolver::solve_in_place`] solves with them, neither allocating.
/// O(nnz(L)) memory and, for a chain or a tree in parent-first order, O(m) time.
///
/// Pivot test as [`super::DenseLdlt`]'s: pivot k of the elimination, d_k = D_kk, fails when
/// it is not above [`RELATIVE_PIVOT_TOLERANCE`] times A's diagonal entry of the same row; the
/// first failing pivot in elimination order names its row of A through the permutation. (faer
/// does not stop at a small or negative pivot; it stops only at an exactly zero or non-finite one. Exact zeros are turned
/// into the smallest positive number by faer's regularization, so that they fail the relative
/// test here and count as a dependent row; a non-finite pivot is reported as not finite.)
pub struct SparseLdlt {
    relative_pivot_tolerance: f64,
    pattern: SymbolicSparseColMat<usize>,
    symbolic: SymbolicCholesky<usize>,
    /// L and D (faer's layout)
    l_values: Vec<f64>,
    /// The row of A eliminated at step k (m)
    order: Vec<usize>,
    /// Where D_kk sits in `l_values` (m)
    pivot_at: Vec<usize>,
    /// The slot of A's diagonal entry of row i (m)
    diagonal_slot: Vec<usize>,
    ordering_used: Ordering,
    supernodal: bool,
    /// +1 / -1 per row of A for a quasi-definite matrix (see [`SparseLdlt::quasi_definite`]),
    /// empty for a positive-definite one
    signs: Vec<i8>,
    mem: MemBuffer,
}

impl SparseLdlt {
    /// The symbolic analysis of `pattern` (allocates; everything after does not).
    pub fn new(pattern: &SymmetricPattern, options: SparseOptions) -> Self {
        let m = pattern.dim();
        let symbolic_pattern = SymbolicSparseColMat::new_checked(
            m,
            m,
            pattern.col_ptr().to_vec(),
            None,
            pattern.row_idx().to_vec(),
        );
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: match options.supernodal {
                None => SupernodalThreshold::AUTO,
                Some(true) => SupernodalThreshold::FORCE_SUPERNODAL,
                Some(false) => SupernodalThreshold::FORCE_SIMPLICIAL,
            },
            ..Default::default()
        };
        let analyse = |ordering: SymmetricOrdering<'_, usize>| {
            factorize_symbolic_cholesky(symbolic_pattern.rb(), Side::Upper, ordering, params)
                .expect("symbolic analysis of the constraint matrix (out of memory)")
        };
        let (symbolic, ordering_used) = match options.ordering {
            Ordering::Amd => (analyse(SymmetricOrdering::Amd), Ordering::Amd),
            Ordering::Identity => (analyse(SymmetricOrdering::Identity), Ordering::Identity),
            Ordering::Auto => {
                let identity = analyse(SymmetricOrdering::Identity);
                let amd = analyse(SymmetricOrdering::Amd);
                if identity.len_val() <= amd.len_val() {
                    (identity, Ordering::Identity)
                } else {
                    (amd, Ordering::Amd)
                }
            }
        };
        let order = match symbolic.perm() {
            Some(perm) => perm.arrays().0.to_vec(),
            None => (0..m).collect(),
        };
        let (pivot_at, supernodal) = match symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => (s.col_ptr()[..m].to_vec(), false),
            SymbolicCholeskyRaw::Supernodal(s) => {
                let mut at = Vec::with_capacity(m);
                for k in 0..s.n_supernodes() {
                    let (begin, end) = (s.supernode_begin()[k], s.supernode_end()[k]);
                    let ncols = end - begin;
                    let nrows = ncols + s.supernode(k).pattern().len();
                    let offset = s.col_ptr_for_val()[k];
                    at.extend((0..ncols).map(|c| offset + c * nrows + c));
                }
                (at, true)
            }
        };
        let par = Par::Seq;
        let scratch = StackReq::any_of(&[
            symbolic.factorize_numeric_ldlt_scratch::<f64>(par, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, par),
        ]);
        SparseLdlt {
            relative_pivot_tolerance: RELATIVE_PIVOT_TOLERANCE,
            l_values: vec![0.0; symbolic.len_val()],
            diagonal_slot: (0..m).map(|i| pattern.diagonal_slot(i)).collect(),
            pattern: symbolic_pattern,
            symbolic,
            order,
            pivot_at,
            ordering_used,
            supernodal,
            signs: Vec::new(),
            mem: MemBuffer::new(scratch),
        }
    }

    /// The symbolic analysis of a symmetric quasi-definite matrix [A, B^T; B, -C] with A and
    /// C positive definite (`signs[i] > 0` for A's rows, `< 0` for C's): e.g. the Newton
    /// matrix of a constrained minimization with its multipliers' block regularized. Such a
    /// matrix has an LDL^T factorization in every symmetric order, D_ii of the sign of row
    /// i (Vanderbei 1995), so `options.ordering` is free to minimize fill. Factor with
    /// [`SparseLdlt::factor_signed`].
    pub fn quasi_definite(
        pattern: &SymmetricPattern,
        options: SparseOptions,
        signs: Vec<i8>,
    ) -> Self {
        assert_eq!(signs.len(), pattern.dim(), "one sign per row");
        SparseLdlt {
            signs,
            ..SparseLdlt::new(pattern, options)
        }
    }

    /// The ordering the analysis chose (never [`Ordering::Auto`]).
    pub fn ordering(&self) -> Ordering {
        self.ordering_used
    }
    /// Whether the factorization is supernodal.
    pub fn is_supernodal(&self) -> bool {
        self.supernodal
    }
    /// Stored values of L and D: the memory of the factor, O(nnz(L)).
    pub fn factor_len(&self) -> usize {
        self.l_values.len()
    }

    /// The first pivot among elimination steps `0..end` that fails the relative test:
    /// sign * D_kk must be above the tolerance times the row's scale, itself positive.
    fn first_failing_pivot(
        &self,
        end: usize,
        sign_and_scale: &impl Fn(&Self, usize) -> (f64, f64),
    ) -> Option<Singular> {
        (0..end).find_map(|k| {
            let row = self.order[k];
            let (sign, scale) = sign_and_scale(self, row);
            let pivot = sign * self.l_values[self.pivot_at[k]];
            (!(scale > 0.0 && pivot > self.relative_pivot_tolerance * scale)).then_some(Singular {
                row,
                finite: scale.is_finite() && pivot.is_finite(),
            })
        })
    }
}

impl SparseLdlt {
    /// Factor a quasi-definite matrix (built by [`SparseLdlt::quasi_definite`]): `values` as
    /// for [`SymmetricSolver::factor`], `pivot_scales` (m, positive) the size each pivot is
    /// measured against. Pivot k of row i fails when sign_i D_kk is not above
    /// [`RELATIVE_PIVOT_TOLERANCE`] times `pivot_scales[i]` (a positive row's diagonal
    /// entry; for a multiplier's row, e.g. J_i W J_i^T, the pivot it would have with H
    /// diagonal): a dependent row, reported as for a positive-definite matrix.
    pub fn factor_signed(&mut self, values: &[f64], pivot_scales: &[f64]) -> Result<(), Singular> {
        assert!(
            !self.signs.is_empty(),
            "factor_signed needs SparseLdlt::quasi_definite"
        );
        self.factor_with(values, |this, row| {
            (f64::from(this.signs[row]), pivot_scales[row])
        })
    }

    /// The numeric factorization, then the pivot test: `sign_and_scale(row)` gives the sign
    /// the row's pivot must have and the scale it must exceed (see [`Self::factor_signed`]).
    fn factor_with(
        &mut self,
        values: &[f64],
        sign_and_scale: impl Fn(&Self, usize) -> (f64, f64),
    ) -> Result<(), Singular> {
        let m = self.order.len();
        let a = SparseColMatRef::new(self.pattern.rb(), values);
        // Pivots of the wrong sign or exactly zero become the smallest normal number of the
        // right sign, so that they fail the relative test below rather than stop faer.
        let regularization = LdltRegularization {
            dynamic_regularization_signs: (!self.signs.is_empty()).then_some(&self.signs[..]),
            dynamic_regularization_delta: f64::MIN_POSITIVE,
            dynamic_regularization_epsilon: f64::MIN_POSITIVE,
        };
        let result = self.symbolic.factorize_numeric_ldlt(
            &mut self.l_values,
            a,
            Side::Upper,
            regularization,
            Par::Seq,
            MemStack::new(&mut self.mem),
            Default::default(),
        );
        match result {
            Ok(_) => match self.first_failing_pivot(m, &sign_and_scale) {
                Some(singular) => Err(singular),
                None => Ok(()),
            },
            Err(faer::linalg::cholesky::ldlt::factor::LdltError::ZeroPivot { index }) => {
                // A non-finite pivot (zeros were regularized). The simplicial factorization
                // numbers it from 1, the supernodal one from 0.
                let k = if self.supernodal {
                    index
                } else {
                    index.saturating_sub(1)
                }
                .min(m.saturating_sub(1));
                Err(self
                    .first_failing_pivot(k, &sign_and_scale)
                    .unwrap_or(Singular {
                        row: self.order[k],
                        finite: false,
                    }))
            }
        }
    }
}

impl SymmetricSolver for SparseLdlt {
    fn factor(&mut self, values: &[f64]) -> Result<(), Singular> {
        assert!(
            self.signs.is_empty(),
            "a quasi-definite matrix needs factor_signed"
        );
        self.factor_with(values, |this, row| (1.0, values[this.diagonal_slot[row]]))
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) {
        let m = self.order.len();
        LdltRef::new(&self.symbolic, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut rhs[..m], m, 1),
            Par::Seq,
            MemStack::new(&mut self.mem),
        );
    }

    fn describe(&self) -> String {
        format!(
            "sparse LDL^T ({} x {}, {} ordering, {}, {} values in L)",
            self.order.len(),
            self.order.len(),
            match self.ordering_used {
                Ordering::Amd => "AMD",
                _ => "identity",
            },
            if self.supernodal {
                "supernodal"
            } else {
                "simplicial"
            },
            self.l_values.len()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::super::{DenseLdlt, SymmetricPattern, SymmetricSolver};
    use super::*;

    /// Every ordering and layout the options allow.
    fn all_options() -> Vec<SparseOptions> {
        let mut out = Vec::new();
        for ordering in [Ordering::Auto, Ordering::Amd, Ordering::Identity] {
            for supernodal in [None, Some(false), Some(true)] {
                out.push(SparseOptions {
                    ordering,
                    supernodal,
                });
            }
        }
        out
    }

    /// A = B B^T + I with B sparse (each row couples to the next and to row i + 7): SPD, with
    /// fill under the identity ordering. Values in the pattern's order.
    fn random_spd(m: usize, seed: u64) -> (SymmetricPattern, Vec<f64>) {
        let mut state = seed;
        let mut random = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut b = vec![0.0; m * m];
        for i in 0..m {
            b[i * m + i] = 1.0 + random();
            for j in [i + 1, i + 7] {
                if j < m {
                    b[i * m + j] = random();
                }
            }
        }
        let dense: Vec<f64> = (0..m * m)
            .map(|ij| {
                let (i, j) = (ij / m, ij % m);
                (0..m).map(|k| b[i * m + k] * b[j * m + k]).sum::<f64>()
                    + if i == j { 1.0 } else { 0.0 }
            })
            .collect();
        let pairs = (0..m)
            .flat_map(|i| (0..m).map(move |j| (i, j)))
            .filter(|&(i, j)| dense[i * m + j] != 0.0);
        let pattern = SymmetricPattern::new(m, pairs);
        let mut values = vec![0.0; pattern.nnz()];
        for j in 0..m {
            for (s, &i) in pattern.column(j) {
                values[s] = dense[i * m + j];
            }
        }
        (pattern, values)
    }

    #[test]
    fn agrees_with_the_dense_ldlt_in_every_ordering_and_layout() {
        let m = 40;
        let (pattern, values) = random_spd(m, 7);
        let rhs: Vec<f64> = (0..m).map(|i| (i as f64).sin()).collect();
        let mut dense = DenseLdlt::new(&pattern);
        dense.factor(&values).unwrap();
        let mut expected = rhs.clone();
        dense.solve_in_place(&mut expected);
        for options in all_options() {
            let mut sparse = SparseLdlt::new(&pattern, options);
            sparse.factor(&values).unwrap();
            let mut z = rhs.clone();
            sparse.solve_in_place(&mut z);
            let error = z
                .iter()
                .zip(&expected)
                .fold(0.0f64, |e, (a, b)| e.max((a - b).abs()));
            assert!(error < 1e-12, "{options:?}: {error:e}");
        }
    }

    /// K = [A, B^T; B, -C]: A the 30 x 30 SPD matrix of `random_spd`, B 12 x 30 (row r
    /// reads columns 2r and 2r + 5), C = `c` I. Values in the pattern's order, and K dense.
    fn random_quasi_definite(c: f64) -> (SymmetricPattern, Vec<f64>, Vec<f64>) {
        let (na, nb) = (30, 12);
        let m = na + nb;
        let (a_pattern, a_values) = random_spd(na, 11);
        let mut dense = vec![0.0; m * m];
        for j in 0..na {
            for (s, &i) in a_pattern.column(j) {
                dense[i * m + j] = a_values[s];
                dense[j * m + i] = a_values[s];
            }
        }
        for r in 0..nb {
            for (k, column) in [2 * r, 2 * r + 5].into_iter().enumerate() {
                let value = 0.5 + 0.1 * (r + k) as f64;
                dense[(na + r) * m + column] = value;
                dense[column * m + na + r] = value;
            }
            dense[(na + r) * m + na + r] = -c;
        }
        let pairs = (0..m)
            .flat_map(|i| (0..m).map(move |j| (i, j)))
            .filter(|&(i, j)| dense[i * m + j] != 0.0);
        let pattern = SymmetricPattern::new(m, pairs);
        let mut values = vec![0.0; pattern.nnz()];
        for j in 0..m {
            for (s, &i) in pattern.column(j) {
                values[s] = dense[i * m + j];
            }
        }
        (pattern, values, dense)
    }

    /// A quasi-definite matrix solves as Gaussian elimination with partial pivoting does,
    /// in every ordering and layout; with C = 0 it is not quasi-definite, and AMD's order,
    /// which eliminates a multiplier before its unknowns, meets a zero pivot and names its
    /// row.
    #[test]
    fn a_quasi_definite_matrix_factors_in_every_ordering_with_its_signs() {
        let (pattern, values, dense) = random_quasi_definite(1e-3);
        let m = pattern.dim();
        let signs: Vec<i8> = (0..m).map(|i| if i < 30 { 1 } else { -1 }).collect();
        let rhs: Vec<f64> = (0..m).map(|i| (0.7 * i as f64).cos()).collect();
        let mut expected = rhs.clone();
        let mut a = dense.clone();
        super::super::solve_general(m, &mut a, &mut expected, &mut vec![0.0; m]).unwrap();
        let mut scales = vec![1.0; m];
        for (i, scale) in scales.iter_mut().enumerate().take(30) {
            *scale = dense[i * m + i];
        }
        for options in all_options() {
            let mut sparse = SparseLdlt::quasi_definite(&pattern, options, signs.clone());
            sparse.factor_signed(&values, &scales).unwrap();
            let mut z = rhs.clone();
            sparse.solve_in_place(&mut z);
            let error = z
                .iter()
                .zip(&expected)
                .fold(0.0f64, |e, (a, b)| e.max((a - b).abs()));
            assert!(error < 1e-10, "{options:?}: {error:e}");
        }
        // C = 0: a multiplier whose row AMD eliminates before its unknowns has a zero pivot.
        let (_, values, _) = random_quasi_definite(0.0);
        let mut amd = SparseLdlt::quasi_definite(
            &pattern,
            SparseOptions {
                ordering: Ordering::Amd,
                supernodal: None,
            },
            signs,
        );
        let singular = amd.factor_signed(&values, &scales).unwrap_err();
        assert!(singular.row >= 30 && singular.finite, "{singular:?}");
    }

    /// Row 5 repeats row 2 (a duplicated constraint): whichever the elimination meets second
    /// is named, finite. A NaN on the diagonal is not finite.
    #[test]
    fn names_a_dependent_row_through_the_permutation_and_tells_nan() {
        let m = 20;
        let (pattern, mut values) = random_spd(m, 3);
        // Make rows/columns 2 and 5 equal: A = C C^T with C's rows 2 and 5 equal has them
        // dependent; simplest: copy column 2 into 5 and row 2 into 5 on a Gram matrix.
        let dense_of = |values: &[f64]| {
            let mut d = vec![0.0; m * m];
            for j in 0..m {
                for (s, &i) in pattern.column(j) {
                    d[i * m + j] = values[s];
                    d[j * m + i] = values[s];
                }
            }
            d
        };
        let mut d = dense_of(&values);
        let (p, q) = (2, 5);
        for k in 0..m {
            d[q * m + k] = d[p * m + k];
            d[k * m + q] = d[k * m + p];
        }
        d[q * m + q] = d[p * m + p];
        d[p * m + q] = d[p * m + p];
        d[q * m + p] = d[p * m + p];
        let pattern = SymmetricPattern::new(
            m,
            (0..m)
                .flat_map(|i| (0..m).map(move |j| (i, j)))
                .filter(|&(i, j)| d[i * m + j] != 0.0),
        );
        values.resize(pattern.nnz(), 0.0);
        for j in 0..m {
            for (s, &i) in pattern.column(j) {
                values[s] = d[i * m + j];
            }
        }
        for options in all_options() {
            let mut sparse = SparseLdlt::new(&pattern, options);
            let singular = sparse.factor(&values).unwrap_err();
            assert!(
                singular.finite && (singular.row == p || singular.row == q),
                "{options:?}: {singular:?}"
            );
        }
        let (pattern, mut nan) = random_spd(m, 3);
        nan[pattern.diagonal_slot(9)] = f64::NAN;
        for options in all_options() {
            let mut sparse = SparseLdlt::new(&pattern, options);
            let singular = sparse.factor(&nan).unwrap_err();
            assert!(!singular.finite, "{options:?}: {singular:?}");
        }
    }
}
