//! J W J^T assembled straight from the sparse rows of J, with a pattern fixed once.

use std::ops::Range;

use super::{symmetric_solver, LinearSolver, Singular, SymmetricPattern, SymmetricSolver};

/// The sparse row structure of a constraint Jacobian J (m x n): row i has nonzeros in
/// coordinates `row_columns(i)`, whose values are entries `row_entries(i)` of a flat array
/// (nnz). The structure of [`crate::model::ConstraintSet`] (see
/// [`crate::model::ConstraintSet::structure`]); J's values come from
/// [`crate::model::ConstraintEval::jacobian`] in this order.
#[derive(Clone, Copy, Debug)]
pub struct RowStructure<'a> {
    row_start: &'a [usize],
    columns: &'a [usize],
}

impl<'a> RowStructure<'a> {
    /// Row i owns entries `row_start[i]..row_start[i + 1]` of `columns` (m + 1 starts, the
    /// first 0, non-decreasing, the last `columns.len()`).
    pub fn new(row_start: &'a [usize], columns: &'a [usize]) -> Self {
        assert!(
            row_start.first() == Some(&0) && row_start.last() == Some(&columns.len()),
            "row starts must run from 0 to the number of entries"
        );
        debug_assert!(row_start.windows(2).all(|w| w[0] <= w[1]));
        RowStructure { row_start, columns }
    }
    /// m
    pub fn n_rows(&self) -> usize {
        self.row_start.len() - 1
    }
    /// nnz of J.
    pub fn n_nonzeros(&self) -> usize {
        self.columns.len()
    }
    /// The coordinates of row i's nonzeros.
    pub fn row_columns(&self, row: usize) -> &'a [usize] {
        &self.columns[self.row_start[row]..self.row_start[row + 1]]
    }
    /// Row i's entries in the flat array of J's values.
    pub fn row_entries(&self, row: usize) -> Range<usize> {
        self.row_start[row]..self.row_start[row + 1]
    }
    /// The columns of all entries, row after row (nnz).
    pub fn columns(&self) -> &'a [usize] {
        self.columns
    }

    /// out_i = J_i . v (out: m).
    pub fn multiply(&self, jacobian: &[f64], v: &[f64], out: &mut [f64]) {
        for (i, out) in out.iter_mut().enumerate().take(self.n_rows()) {
            let entries = self.row_entries(i);
            *out = self.columns[entries.clone()]
                .iter()
                .zip(&jacobian[entries])
                .map(|(&k, &j)| j * v[k])
                .sum();
        }
    }

    /// y -= W J^T z (y: n, z: m).
    pub fn subtract_weighted_transpose(
        &self,
        jacobian: &[f64],
        w: &[f64],
        z: &[f64],
        y: &mut [f64],
    ) {
        for (i, &zi) in z.iter().enumerate().take(self.n_rows()) {
            let entries = self.row_entries(i);
            for (&k, &j) in self.columns[entries.clone()].iter().zip(&jacobian[entries]) {
                y[k] -= w[k] * j * zi;
            }
        }
    }

    /// y += J^T z (y: n, z: m).
    pub fn add_transpose(&self, jacobian: &[f64], z: &[f64], y: &mut [f64]) {
        for (i, &zi) in z.iter().enumerate().take(self.n_rows()) {
            let entries = self.row_entries(i);
            for (&k, &j) in self.columns[entries.clone()].iter().zip(&jacobian[entries]) {
                y[k] += j * zi;
            }
        }
    }
}

/// One product J_i(a) w_k J_j(b) of an entry of J W J^T: entries a and b of J's flat values
/// (rows i <= j) that share coordinate k.
#[derive(Clone, Copy, Debug)]
struct Term {
    a: u32,
    b: u32,
    k: u32,
}

/// A = J W J^T (m x m, W diagonal) for a fixed [`RowStructure`], with its factorization.
///
/// Two rows are coupled when they share a coordinate. At construction the coupled pairs are
/// enumerated from the row structure, giving A's [`SymmetricPattern`] (upper triangle), and
/// for every entry of A the products J_i(a) w_k J_j(b) that make it, each as the two entries
/// of J and the coordinate; the solver ([`LinearSolver`]) does its symbolic work on the
/// pattern then. [`ConstraintMatrix::assemble`] writes each entry of A once from J's sparse
/// values (no dense copy of J, nothing of size m x n), [`ConstraintMatrix::factor`] factors it
/// and [`ConstraintMatrix::solve_in_place`] solves with the factor as often as needed. Memory
/// O(m + nnz(J) + products + the factor); nothing allocates after construction.
///
/// ```
/// use bead::linalg::{ConstraintMatrix, LinearSolver, RowStructure};
/// // Two rods of a chain in 1D: C0(x0), C1(x0, x1).
/// let (starts, columns) = ([0, 1, 3], [0, 0, 1]);
/// let mut a = ConstraintMatrix::new(RowStructure::new(&starts, &columns), LinearSolver::Sparse);
/// a.assemble(&[1.0, -1.0, 1.0], &[1.0, 0.5]); // J = [[1, 0], [-1, 1]], W = diag(1, 1/2)
/// assert_eq!(a.values(), &[1.0, -1.0, 1.5]);   // upper triangle by columns
/// a.factor().unwrap();
/// let mut z = [1.0, 0.0];
/// a.solve_in_place(&mut z);
/// assert!((z[0] - 3.0).abs() < 1e-14 && (z[1] - 2.0).abs() < 1e-14);
/// ```
pub struct ConstraintMatrix {
    pattern: SymmetricPattern,
    /// Products of slot s: `terms[term_start[s]..term_start[s + 1]]`
    term_start: Vec<usize>,
    terms: Vec<Term>,
    /// A's values in the pattern's order
    values: Vec<f64>,
    solver: Box<dyn SymmetricSolver>,
}

impl ConstraintMatrix {
    /// The pattern and products of J W J^T for `rows`, and the solver `kind` analysed on it.
    /// Allocates; O(nnz(J) + products) time, plus the solver's symbolic analysis.
    pub fn new(rows: RowStructure<'_>, kind: LinearSolver) -> Self {
        let m = rows.n_rows();
        let columns = rows.columns();
        let index = |i: usize| u32::try_from(i).expect("more than 2^32 constraint entries");
        let n = columns.iter().max().map_or(0, |k| k + 1);
        // The entries of each coordinate (J by columns), rows ascending.
        let mut coordinate_start = vec![0; n + 1];
        for &k in columns {
            coordinate_start[k + 1] += 1;
        }
        for k in 0..n {
            coordinate_start[k + 1] += coordinate_start[k];
        }
        let mut next = coordinate_start.clone();
        let mut by_coordinate = vec![(0, 0); columns.len()];
        for i in 0..m {
            for e in rows.row_entries(i) {
                let k = columns[e];
                by_coordinate[next[k]] = (i, e);
                next[k] += 1;
            }
        }
        // Every product, with the pair of rows it belongs to.
        let mut products = Vec::new();
        for k in 0..n {
            let touching = &by_coordinate[coordinate_start[k]..coordinate_start[k + 1]];
            for (p, &(i, a)) in touching.iter().enumerate() {
                for &(j, b) in &touching[p..] {
                    let term = Term {
                        a: index(a),
                        b: index(b),
                        k: index(k),
                    };
                    products.push((i, j, term));
                    if i == j && a != b {
                        // A row that lists a coordinate twice: the cross product counts twice.
                        products.push((i, j, term));
                    }
                }
            }
        }
        let pattern = SymmetricPattern::new(m, products.iter().map(|&(i, j, _)| (i, j)));
        let slots: Vec<usize> = products
            .iter()
            .map(|&(i, j, _)| pattern.slot(i, j).expect("in the pattern"))
            .collect();
        let mut term_start = vec![0; pattern.nnz() + 1];
        for &s in &slots {
            term_start[s + 1] += 1;
        }
        for s in 0..pattern.nnz() {
            term_start[s + 1] += term_start[s];
        }
        let mut next = term_start.clone();
        let mut terms = vec![Term { a: 0, b: 0, k: 0 }; products.len()];
        for (&s, &(_, _, term)) in slots.iter().zip(&products) {
            terms[next[s]] = term;
            next[s] += 1;
        }
        let solver = symmetric_solver(&pattern, kind);
        ConstraintMatrix {
            values: vec![0.0; pattern.nnz()],
            pattern,
            term_start,
            terms,
            solver,
        }
    }

    /// m
    pub fn n_rows(&self) -> usize {
        self.pattern.dim()
    }
    /// A's pattern.
    pub fn pattern(&self) -> &SymmetricPattern {
        &self.pattern
    }
    /// A's values (upper triangle, the pattern's order) of the last assembly.
    pub fn values(&self) -> &[f64] {
        &self.values
    }
    /// Products J_i(a) w_k J_j(b) summed per assembly.
    pub fn n_products(&self) -> usize {
        self.terms.len()
    }
    /// The solver, e.g. `sparse LDL^T (...)`.
    pub fn describe(&self) -> String {
        self.solver.describe()
    }
    /// The order that makes A tridiagonal, when its solver works in one (chains; see
    /// [`super::PathLdlt`]).
    pub fn path(&self) -> Option<&super::PathOrder> {
        self.solver.path()
    }

    /// A = J W J^T from J's values `jacobian` (nnz, in the row structure's order) and the
    /// diagonal W (n). Allocation-free.
    pub fn assemble(&mut self, jacobian: &[f64], w: &[f64]) {
        for (s, value) in self.values.iter_mut().enumerate() {
            *value = self.terms[self.term_start[s]..self.term_start[s + 1]]
                .iter()
                .map(|t| jacobian[t.a as usize] * w[t.k as usize] * jacobian[t.b as usize])
                .sum();
        }
    }

    /// [`ConstraintMatrix::assemble`] for L members at once (structure of arrays: entry e of
    /// member l at `jacobian[e * L + l]`), then A scattered into dense m x m matrices
    /// (`dense[(i * m + j) * L + l]`, lower triangle, zero elsewhere) as
    /// [`super::DenseLdlt`] does before factoring: the same arithmetic per member.
    pub(crate) fn assemble_dense_lanes<const L: usize>(
        &self,
        jacobian: &[f64],
        w: &[f64],
        dense: &mut [f64],
    ) {
        let m = self.pattern.dim();
        dense.fill(0.0);
        for j in 0..m {
            for (s, &i) in self.pattern.column(j) {
                let target = &mut dense[(j * m + i) * L..(j * m + i + 1) * L];
                // sum() of f64 starts from -0.0.
                target.fill(-0.0);
                for t in &self.terms[self.term_start[s]..self.term_start[s + 1]] {
                    let (a, b, w) = (t.a as usize, t.b as usize, w[t.k as usize]);
                    for (l, value) in target.iter_mut().enumerate() {
                        *value += jacobian[a * L + l] * w * jacobian[b * L + l];
                    }
                }
            }
        }
    }

    /// The dense factorization's pivot tolerance, when A is factored densely.
    pub(crate) fn dense_pivot_tolerance(&self) -> Option<f64> {
        self.solver.dense_pivot_tolerance()
    }

    /// The unsymmetric B = L W R^T of two Jacobians with this structure (RATTLE's exact Newton
    /// matrix J(q^k) W J(q_n)^T), on A's pattern mirrored: `upper[s]` = B_ij and `lower[s]` =
    /// B_ji for the slot s of (i, j), i <= j (both nnz). Allocation-free.
    pub fn assemble_product(
        &self,
        left: &[f64],
        right: &[f64],
        w: &[f64],
        upper: &mut [f64],
        lower: &mut [f64],
    ) {
        for j in 0..self.n_rows() {
            let diagonal = self.pattern.diagonal_slot(j);
            for (s, _) in self.pattern.column(j) {
                let (mut u, mut l) = (0.0, 0.0);
                for t in &self.terms[self.term_start[s]..self.term_start[s + 1]] {
                    let (a, b, w) = (t.a as usize, t.b as usize, w[t.k as usize]);
                    u += left[a] * w * right[b];
                    l += left[b] * w * right[a];
                }
                if s == diagonal {
                    // Its products are (a, b) pairs within one row, each listed once.
                    u = 0.5 * (u + l);
                    l = u;
                }
                upper[s] = u;
                lower[s] = l;
            }
        }
    }

    /// The products J_i(a) w_k J_j(b) summed into slot `s` of A, as (a, b, k), in the order
    /// [`Self::assemble`] sums them.
    pub(crate) fn slot_products(
        &self,
        s: usize,
    ) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
        self.terms[self.term_start[s]..self.term_start[s + 1]]
            .iter()
            .map(|t| (t.a as usize, t.b as usize, t.k as usize))
    }

    /// Factor the last assembled A (see [`SymmetricSolver::factor`]).
    pub fn factor(&mut self) -> Result<(), Singular> {
        self.solver.factor(&self.values)
    }

    /// rhs <- A^-1 rhs with the last factorization.
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) {
        self.solver.solve_in_place(rhs);
    }
}

/// A [`ConstraintMatrix`] built on first use: a system whose steps never solve with J W J^T
/// (RATTLE fused along rods, [`super::RodPath`]) never pays for its pattern and analysis
/// (about 400 bytes per rod of a chain).
pub(crate) struct LazyConstraintMatrix {
    matrix: std::sync::OnceLock<ConstraintMatrix>,
    kind: LinearSolver,
}

impl LazyConstraintMatrix {
    /// The matrix for `kind`, not built yet.
    pub(crate) fn new(kind: LinearSolver) -> Self {
        LazyConstraintMatrix {
            matrix: std::sync::OnceLock::new(),
            kind,
        }
    }

    /// The matrix, built for `rows` if it was not: `rows` must be the same every call.
    pub(crate) fn get(&self, rows: RowStructure<'_>) -> &ConstraintMatrix {
        self.matrix
            .get_or_init(|| ConstraintMatrix::new(rows, self.kind))
    }

    /// [`ConstraintMatrix::dense_pivot_tolerance`], built only when the matrix is dense
    /// (`None` otherwise, as the built one says).
    pub(crate) fn dense_pivot_tolerance(&self, rows: RowStructure<'_>) -> Option<f64> {
        if !super::solves_densely(self.kind, rows.n_rows()) {
            return None;
        }
        self.get(rows).dense_pivot_tolerance()
    }

    /// [`LazyConstraintMatrix::get`] for assembly and factorization.
    pub(crate) fn get_mut(&mut self, rows: RowStructure<'_>) -> &mut ConstraintMatrix {
        self.get(rows);
        self.matrix.get_mut().expect("built just now")
    }
}

impl std::fmt::Debug for ConstraintMatrix {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConstraintMatrix")
            .field("rows", &self.n_rows())
            .field("nnz", &self.pattern.nnz())
            .field("products", &self.terms.len())
            .field("solver", &self.solver.describe())
            .finish()
    }
}
