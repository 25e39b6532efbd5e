//! Holonomic constraints compiled for evaluation: values C, velocity Cdot, Jacobian J and the
//! acceleration bias, all exact.
//!
//! For a constraint C(x, t) = 0 on positions x (n_coords) with velocities v:
//!
//! ```text
//! Cdot  = J v + C_t                                   J = dC/dx
//! Cddot = J a + bias,   bias = v^T H v + 2 C_xt v + C_tt   (H = d2C/dx2)
//! ```
//!
//! Expression constraints get these symbolically at build time (bias as the total time
//! derivative of the Cdot expression with the accelerations left out) and run as one compiled
//! [`Tape`], as do Rust [`super::Holonomic`] constraints traced into expressions; those that
//! cannot be traced get them from dual numbers.

use std::ops::Range;
use std::sync::Arc;

use super::builder::SystemBuilder;
use super::holonomic::{DualScratch, SharedHolonomic};
use super::native::NativeRow;
use crate::expr::{Expr, Tape};

/// What a user named: one declared constraint, which may own several rows (a pin has one per
/// axis). Made on demand from the declaration ([`ConstraintSet::infos`]): a set keeps no
/// strings per constraint, so that a chain of 10^5 rods does not hold 2 x 10^5 of them.
#[derive(Clone, Debug, PartialEq)]
pub struct ConstraintInfo {
    /// Label used in messages, e.g. `constraint 1`.
    pub name: String,
    /// What it is, e.g. `bead.x^2 + 100*bead.y = 0` or `distance(a, b) = 1`.
    pub description: String,
    /// Its rows in the stacked constraint vector.
    pub rows: Range<usize>,
    /// Its own length when it has one (a distance's L): the scale of its tolerance, so that
    /// a rod's error is measured as its stretch |d - L| / L. `None` for expressions, pins
    /// and Rust constraints.
    pub length: Option<f64>,
}

/// A built-in distance row, C = (|x_a - x_b|^2 - L^2) / (2L) (x_b a fixed point when `b` is
/// `None`): its Hessian is constant, (1/L) [I, -I; -I, I] over (x_a, x_b) ((1/L) I over x_a
/// alone for a fixed point), which a Newton iteration on a projection can use exactly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DistanceRow {
    /// First coordinate of particle a (its `dim` coordinates follow)
    pub a: usize,
    /// First coordinate of particle b, `None` for a fixed point
    pub b: Option<usize>,
    /// The fixed point when `b` is `None` (its first `dim` entries; zeros otherwise)
    pub anchor: [f64; 3],
    /// Spatial dimension
    pub dim: usize,
    /// L
    pub length: f64,
}

/// One scalar constraint row written as an expression over slots [x (n), v (n), t], with
/// its exact derivatives.
#[derive(Clone, Debug)]
pub struct ExprRow {
    /// C(x, t)
    pub value: Expr,
    /// (coordinate k, dC/dx_k) for every coordinate C depends on.
    pub gradient: Vec<(usize, Expr)>,
    /// Cdot = J v + C_t
    pub velocity: Expr,
    /// Cddot - J a = v^T H v + 2 C_xt v + C_tt
    pub bias: Expr,
}

impl ExprRow {
    /// Differentiate `value` (slots: x = 0..n, v = n..2n, t = 2n) once, at build time.
    pub fn new(value: Expr, n_coords: usize) -> ExprRow {
        let time = 2 * n_coords;
        let velocity_of = |k: usize| Expr::var(n_coords + k);
        // The partial derivatives of f with respect to the coordinates it reads, in slot
        // order, taken together (one traversal of f), and df/dt (0 when f does not read t).
        let partials = |f: &Expr| {
            let vars = f.vars();
            let coordinates: Vec<usize> = vars.iter().copied().filter(|&k| k < n_coords).collect();
            let by_coordinate: Vec<(usize, Expr)> = coordinates
                .iter()
                .copied()
                .zip(f.derivatives(&coordinates))
                .collect();
            let by_time = if vars.contains(&time) {
                f.derivative(time)
            } else {
                Expr::constant(0.0)
            };
            (by_coordinate, by_time)
        };
        // Total time derivative along the motion, accelerations excluded:
        // d/dt f(x, v, t) = sum_k df/dx_k v_k + df/dt.
        let total_derivative = |(by_coordinate, by_time): (Vec<(usize, Expr)>, Expr)| {
            by_coordinate
                .into_iter()
                .fold(by_time, |acc, (k, d)| acc + d * velocity_of(k))
        };
        let (gradient, by_time) = partials(&value);
        let velocity = total_derivative((gradient.clone(), by_time));
        let bias = total_derivative(partials(&velocity));
        ExprRow {
            value,
            gradient,
            velocity,
            bias,
        }
    }
}

/// An expression row as the builder hands it to [`ConstraintSet`]: symbolic (compiled to the
/// tapes) or native (direct code; its symbolic form built only when asked for).
pub(crate) enum RowForm {
    Symbolic(ExprRow),
    Native(NativeRow),
}

/// A Rust constraint row and the coordinates it reads.
#[derive(Clone)]
pub(crate) struct CustomRow {
    pub(crate) constraint: SharedHolonomic,
    pub(crate) coords: Vec<usize>,
}

/// All implicit constraints of a system, compiled. Rows are stacked expression rows first,
/// then Rust rows.
#[derive(Clone)]
pub struct ConstraintSet {
    n_coords: usize,
    /// What the constraints were declared from (their names and descriptions)
    declared: Arc<SystemBuilder>,
    /// Each declared constraint's declaration and rows, in the order of
    /// [`ConstraintSet::infos`]: sorted by first row
    declarations: Vec<Declaration>,
    /// Number of expression rows (symbolic and native), which come before the Rust rows.
    n_expr_rows: usize,
    /// The symbolic rows, which the tapes evaluate, in row order (rows `tape_rows`).
    expr_rows: Vec<ExprRow>,
    custom_rows: Vec<CustomRow>,
    /// The rows of `expr_rows`: the expression rows without a native form.
    tape_rows: Vec<usize>,
    /// Expression rows evaluated by direct code (distances and pins), with their row index.
    native_rows: Vec<(usize, NativeRow)>,
    /// Outputs: C (tape rows).
    value_tape: Tape,
    /// Outputs: C | Cdot | bias (tape rows) | gradient entries in row order.
    full_tape: Tape,
    /// Outputs: C (tape rows) | gradient entries in row order.
    gradient_tape: Tape,
    /// The fused tapes (see [`super::FusedTapes`])
    fused: super::FusedTapes,
    /// Sparse row structure of J: row i owns entries row_start[i]..row_start[i+1] of `columns`.
    row_start: Vec<usize>,
    columns: Vec<usize>,
    /// Whether row i depends on t (m).
    time_dependent: Vec<bool>,
    /// Whether any row depends on t
    any_time_dependent: bool,
    /// A hash of the row structure and the distance rows' geometry (see
    /// [`ConstraintSet::row_fingerprint`])
    row_fingerprint: u64,
}

impl std::fmt::Debug for ConstraintSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConstraintSet")
            .field("n_declared", &self.declarations.len())
            .field("n_rows", &self.n_rows())
            .finish()
    }
}

/// One declared constraint of a [`ConstraintSet`]: its index in the declaration and its rows
/// (16 bytes; its name and description are the declaration's).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Declaration {
    /// Index in [`SystemBuilder`]'s constraint list
    pub(crate) index: u32,
    /// Number of rows
    pub(crate) n_rows: u32,
    /// First row
    pub(crate) first_row: usize,
}

impl Declaration {
    fn rows(&self) -> Range<usize> {
        self.first_row..self.first_row + self.n_rows as usize
    }
}

/// Results and scratch space of [`ConstraintSet::evaluate`], sized once
/// ([`ConstraintSet::workspace`]; the default is sized for no rows).
#[derive(Clone, Debug, Default)]
pub struct ConstraintEval {
    /// C (n_rows)
    pub value: Vec<f64>,
    /// Cdot = J v + C_t (n_rows)
    pub velocity: Vec<f64>,
    /// Cddot - J a (n_rows)
    pub bias: Vec<f64>,
    /// Nonzero entries of J in the row structure of [`ConstraintSet::row_columns`] (nnz)
    pub jacobian: Vec<f64>,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    tape_out: Vec<f64>,
    local_x: Vec<f64>,
    local_v: Vec<f64>,
    duals: DualScratch,
}

impl ConstraintEval {
    /// Where the tapes write their outputs before they are unpacked (see
    /// [`ConstraintSet::unpack_full`]).
    pub(crate) fn tape_out_mut(&mut self) -> &mut [f64] {
        &mut self.tape_out
    }
}

impl ConstraintSet {
    /// The set of expression `rows` (each symbolic or native) then `custom_rows`. Native rows
    /// are evaluated by direct code and keep no expression; the tapes are compiled from the
    /// symbolic rows only.
    pub(crate) fn new(
        n_coords: usize,
        declared: Arc<SystemBuilder>,
        mut declarations: Vec<Declaration>,
        rows: Vec<RowForm>,
        custom_rows: Vec<CustomRow>,
    ) -> Self {
        let n_expr_rows = rows.len();
        let mut tape_rows = Vec::new();
        let mut expr_rows = Vec::new();
        let mut native_rows = Vec::new();
        let mut row_start = vec![0];
        let mut columns = Vec::new();
        let mut time_dependent = Vec::with_capacity(n_expr_rows + custom_rows.len());
        let time = 2 * n_coords;
        for (r, row) in rows.into_iter().enumerate() {
            match row {
                RowForm::Symbolic(row) => {
                    columns.extend(row.gradient.iter().map(|(k, _)| *k));
                    time_dependent.push(row.value.depends_on(time));
                    tape_rows.push(r);
                    expr_rows.push(row);
                }
                RowForm::Native(row) => {
                    columns.extend(row.columns());
                    time_dependent.push(false);
                    native_rows.push((r, row));
                }
            }
            row_start.push(columns.len());
        }
        let values: Vec<Expr> = expr_rows.iter().map(|r| r.value.clone()).collect();
        let mut gradient_outputs = values.clone();
        gradient_outputs.extend(
            expr_rows
                .iter()
                .flat_map(|r| r.gradient.iter().map(|(_, d)| d.clone())),
        );
        let mut outputs = values.clone();
        outputs.extend(expr_rows.iter().map(|r| r.velocity.clone()));
        outputs.extend(expr_rows.iter().map(|r| r.bias.clone()));
        outputs.extend(
            expr_rows
                .iter()
                .flat_map(|r| r.gradient.iter().map(|(_, d)| d.clone())),
        );
        for row in &custom_rows {
            columns.extend(&row.coords);
            row_start.push(columns.len());
        }
        // Kept for the run: no slack from growing (a chain of 10^5 rods).
        for v in [&mut row_start, &mut columns, &mut tape_rows] {
            v.shrink_to_fit();
        }
        native_rows.shrink_to_fit();
        expr_rows.shrink_to_fit();
        declarations.shrink_to_fit();
        // `declaration_of_row` finds a row's owner by its first row: each owns at least one.
        debug_assert!(declarations.iter().all(|d| d.n_rows > 0));
        time_dependent.extend(custom_rows.iter().map(|r| r.constraint.time_dependent()));
        // FNV-1a over the row starts and columns, then each distance row's row, particles,
        // anchor and length bits.
        let mut row_fingerprint: u64 = 0xcbf2_9ce4_8422_2325;
        let mut hash = |word: u64| {
            for byte in word.to_le_bytes() {
                row_fingerprint = (row_fingerprint ^ byte as u64).wrapping_mul(0x100_0000_01b3);
            }
        };
        for &word in row_start.iter().chain(&columns) {
            hash(word as u64);
        }
        for (row, native) in &native_rows {
            if let NativeRow::Distance {
                a,
                b,
                anchor,
                length,
                ..
            } = native
            {
                let words = [*row as u64, *a as u64, b.map_or(u64::MAX, |b| b as u64)];
                let bits = anchor.iter().chain([length]).map(|x| x.to_bits());
                words.into_iter().chain(bits).for_each(&mut hash);
            }
        }
        ConstraintSet {
            row_fingerprint,
            fused: super::FusedTapes::default(),
            any_time_dependent: time_dependent.iter().any(|&d| d),
            time_dependent,
            n_coords,
            declared,
            declarations,
            value_tape: Tape::compile(&values),
            full_tape: Tape::compile(&outputs),
            gradient_tape: Tape::compile(&gradient_outputs),
            n_expr_rows,
            expr_rows,
            custom_rows,
            tape_rows,
            native_rows,
            row_start,
            columns,
        }
    }

    /// Whether every expression row is on the tape (no native rows): its outputs are then
    /// in row order and copied as blocks.
    fn all_taped(&self) -> bool {
        self.native_rows.is_empty()
    }

    /// Number of rows evaluated by direct code (distances and pins).
    pub fn n_native_rows(&self) -> usize {
        self.native_rows.len()
    }

    /// Number of scalar constraint rows m.
    pub fn n_rows(&self) -> usize {
        self.n_expr_rows + self.custom_rows.len()
    }
    /// Number of declared constraints (a pin owns several rows, a rod one).
    pub fn n_declared(&self) -> usize {
        self.declarations.len()
    }
    /// The declared constraints: expression constraints (traced Rust ones among them),
    /// distances and pins in the order they were declared, then Rust constraints by dual
    /// numbers (the order of their rows). Each is made from the
    /// declaration when asked for (two strings); [`ConstraintSet::declared_rows`] gives the
    /// rows and lengths alone.
    ///
    /// ```
    /// use bead::model::SystemBuilder;
    /// let mut b = SystemBuilder::new(&[0.0, 9.81]);
    /// let bob = b.particle("bob", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
    /// b.distance("rod", bob, bead::model::Endpoint::Fixed(vec![0.0, 0.0]), 1.0).unwrap();
    /// let system = b.build().unwrap();
    /// let rod = system.constraints().infos().next().unwrap();
    /// assert_eq!(rod.name, "rod");
    /// assert_eq!(rod.description, "distance(bob, [0.0, 0.0]) = 1");
    /// assert_eq!((rod.rows, rod.length), (0..1, Some(1.0)));
    /// ```
    pub fn infos(&self) -> impl ExactSizeIterator<Item = ConstraintInfo> + '_ {
        self.declarations.iter().map(|d| self.info_of(d))
    }
    /// Declared constraint k of [`ConstraintSet::infos`].
    pub fn info(&self, k: usize) -> ConstraintInfo {
        self.info_of(&self.declarations[k])
    }
    /// The rows and length ([`ConstraintInfo::rows`], [`ConstraintInfo::length`]) of each
    /// declared constraint, in the order of [`ConstraintSet::infos`], without their names.
    pub fn declared_rows(&self) -> impl ExactSizeIterator<Item = (Range<usize>, Option<f64>)> + '_ {
        self.declarations
            .iter()
            .map(|d| (d.rows(), self.declared.constraint_length(d.index as usize)))
    }
    /// The declared constraint that owns `row` (the first one when no constraint owns it).
    pub fn info_of_row(&self, row: usize) -> ConstraintInfo {
        self.info_of(self.declaration_of_row(row))
    }
    /// The name of the declared constraint that owns `row` (as [`ConstraintSet::info_of_row`]).
    pub fn name_of_row(&self, row: usize) -> &str {
        let index = self.declaration_of_row(row).index as usize;
        &self.declared.constraints[index].0
    }
    /// The declaration that owns `row`: the last whose first row is at most `row` (they are
    /// sorted by first row).
    fn declaration_of_row(&self, row: usize) -> &Declaration {
        let after = self.declarations.partition_point(|d| d.first_row <= row);
        let d = &self.declarations[after.saturating_sub(1)];
        if d.rows().contains(&row) {
            d
        } else {
            &self.declarations[0]
        }
    }
    fn info_of(&self, d: &Declaration) -> ConstraintInfo {
        let index = d.index as usize;
        ConstraintInfo {
            name: self.declared.constraints[index].0.clone(),
            description: self.declared.describe_constraint(index),
            rows: d.rows(),
            length: self.declared.constraint_length(index),
        }
    }
    /// Whether `row` depends on t (a moving or driven constraint, which does work).
    pub fn is_time_dependent(&self, row: usize) -> bool {
        self.time_dependent[row]
    }
    /// Whether any row depends on t (C_t != 0 somewhere): false when every constraint is
    /// fixed (scleronomic), whose forces then do no work.
    pub fn any_time_dependent(&self) -> bool {
        self.any_time_dependent
    }
    /// Whether `row` is a built-in distance (length > 0) or pin row, evaluated natively:
    /// rows whose gradient vanishes nowhere on their constraint.
    pub fn is_native_row(&self, row: usize) -> bool {
        // In row order (built by one pass over the rows).
        self.native_rows
            .binary_search_by_key(&row, |(r, _)| *r)
            .is_ok()
    }
    /// A hash of the row structure (each row's columns) and of every built-in distance
    /// row's geometry (row, particles, anchor, length): two sets that differ in either differ
    /// in it (up to hash collisions), so a solver that keeps per-row data between steps
    /// (RATTLE's matrices and fused rods) can tell in O(1) per step that it was handed
    /// another system.
    pub fn row_fingerprint(&self) -> u64 {
        self.row_fingerprint
    }
    /// Whether `row` is a built-in pin (x_k - anchor: linear, its Hessian zero).
    pub fn is_pin_row(&self, row: usize) -> bool {
        self.native_rows
            .binary_search_by_key(&row, |(r, _)| *r)
            .is_ok_and(|at| matches!(self.native_rows[at].1, NativeRow::Pin { .. }))
    }
    /// `row` as a built-in distance ([`DistanceRow`]), if it is one.
    pub fn distance_row(&self, row: usize) -> Option<DistanceRow> {
        let at = self
            .native_rows
            .binary_search_by_key(&row, |(r, _)| *r)
            .ok()?;
        match self.native_rows[at].1 {
            NativeRow::Distance {
                dim,
                a,
                b,
                anchor,
                length,
                ..
            } => Some(DistanceRow {
                a,
                b,
                anchor,
                dim: dim.into(),
                length,
            }),
            NativeRow::Pin { .. } => None,
        }
    }
    /// Coordinates of the nonzero entries of J in `row`.
    pub fn row_columns(&self, row: usize) -> &[usize] {
        &self.columns[self.row_start[row]..self.row_start[row + 1]]
    }
    /// Range of `row`'s entries in [`ConstraintEval::jacobian`].
    pub fn row_entries(&self, row: usize) -> Range<usize> {
        self.row_start[row]..self.row_start[row + 1]
    }
    /// The sparse row structure of J (rows, their coordinates, their entries in
    /// [`ConstraintEval::jacobian`]).
    pub fn structure(&self) -> crate::linalg::RowStructure<'_> {
        crate::linalg::RowStructure::new(&self.row_start, &self.columns)
    }
    /// Total number of nonzero Jacobian entries.
    pub fn n_nonzeros(&self) -> usize {
        self.columns.len()
    }
    /// Size of the compiled code (instructions in the full tape).
    pub fn n_instructions(&self) -> usize {
        self.full_tape.n_instructions()
    }
    /// The symbolic form of expression row `row` (None for Rust rows): borrowed for a row the
    /// tapes evaluate, built now for a native row (distances and pins keep no expressions).
    pub fn symbolic_row(&self, row: usize) -> Option<std::borrow::Cow<'_, ExprRow>> {
        if let Ok(j) = self.tape_rows.binary_search(&row) {
            return Some(std::borrow::Cow::Borrowed(&self.expr_rows[j]));
        }
        let j = self
            .native_rows
            .binary_search_by_key(&row, |(r, _)| *r)
            .ok()?;
        Some(std::borrow::Cow::Owned(
            self.native_rows[j].1.symbolic(self.n_coords),
        ))
    }

    /// A workspace sized for this set.
    pub fn workspace(&self) -> ConstraintEval {
        let m = self.n_rows();
        let widest = self
            .custom_rows
            .iter()
            .map(|r| r.coords.len())
            .max()
            .unwrap_or(0);
        ConstraintEval {
            value: vec![0.0; m],
            velocity: vec![0.0; m],
            bias: vec![0.0; m],
            jacobian: vec![0.0; self.columns.len()],
            // The tapes' inputs: none without tape rows (a chain's rods are all native).
            vars: vec![
                0.0;
                if self.tape_rows.is_empty() {
                    0
                } else {
                    2 * self.n_coords + 1
                }
            ],
            scratch: vec![
                0.0;
                self.full_tape
                    .n_slots()
                    .max(self.value_tape.n_slots())
                    .max(self.gradient_tape.n_slots())
            ],
            tape_out: vec![0.0; self.full_tape.n_outputs()],
            local_x: vec![0.0; widest],
            local_v: vec![0.0; widest],
            duals: DualScratch::with_capacity(widest),
        }
    }

    fn load_vars(&self, t: f64, x: &[f64], v: Option<&[f64]>, ws: &mut ConstraintEval) {
        let n = self.n_coords;
        ws.vars[..n].copy_from_slice(x);
        if let Some(v) = v {
            ws.vars[n..2 * n].copy_from_slice(v);
        }
        ws.vars[2 * n] = t;
    }

    /// Whether every row is evaluated by the tapes alone (no native distance or pin rows, no
    /// Rust rows): an ensemble can then evaluate them for many members at once.
    pub(crate) fn only_taped(&self) -> bool {
        self.native_rows.is_empty() && self.custom_rows.is_empty()
    }

    /// Every tape of the set (for the machine code summary), the fused acceleration's and
    /// its RK4 steps' once built.
    pub(crate) fn tapes(&self) -> Vec<Tape> {
        [&self.value_tape, &self.full_tape, &self.gradient_tape]
            .into_iter()
            .cloned()
            .chain(self.fused.built())
            .collect()
    }

    /// The fused tapes the formulation builds for this set (see [`super::FusedTapes`]).
    pub(crate) fn fused(&self) -> &super::FusedTapes {
        &self.fused
    }

    /// The tape of the expression rows' values C (outputs in row order), variables x, t (the
    /// slots of x, v, t).
    pub(crate) fn value_tape(&self) -> &Tape {
        &self.value_tape
    }

    /// The tape of C, Cdot, bias and J (outputs in that order), variables x, v, t.
    pub(crate) fn full_tape(&self) -> &Tape {
        &self.full_tape
    }

    /// The tape of C and J (outputs in that order), variables x, t (the slots of x, v, t).
    pub(crate) fn gradient_tape(&self) -> &Tape {
        &self.gradient_tape
    }

    /// The full tape's outputs in `ws.tape_out` into C, Cdot, bias and J (every row taped).
    pub(crate) fn unpack_full(&self, ws: &mut ConstraintEval) {
        let n_tape = self.tape_rows.len();
        let nnz = self.row_start[n_tape];
        let out = &ws.tape_out;
        ws.value[..n_tape].copy_from_slice(&out[..n_tape]);
        ws.velocity[..n_tape].copy_from_slice(&out[n_tape..2 * n_tape]);
        ws.bias[..n_tape].copy_from_slice(&out[2 * n_tape..3 * n_tape]);
        ws.jacobian[..nnz].copy_from_slice(&out[3 * n_tape..3 * n_tape + nnz]);
    }

    /// The gradient tape's outputs in `ws.tape_out` into C and J (every row taped).
    pub(crate) fn unpack_gradient(&self, ws: &mut ConstraintEval) {
        let n_tape = self.tape_rows.len();
        let nnz_tape = self.gradient_tape.n_outputs() - n_tape;
        let out = &ws.tape_out;
        ws.value[..n_tape].copy_from_slice(&out[..n_tape]);
        ws.jacobian[..nnz_tape].copy_from_slice(&out[n_tape..n_tape + nnz_tape]);
    }

    /// Evaluate C, Cdot, bias and J at (t, x, v) into `ws`. Allocation-free.
    pub fn evaluate(&self, t: f64, x: &[f64], v: &[f64], ws: &mut ConstraintEval) {
        let n_tape = self.tape_rows.len();
        if n_tape > 0 {
            self.load_vars(t, x, Some(v), ws);
            self.full_tape
                .eval(&ws.vars, &mut ws.scratch, &mut ws.tape_out);
            if self.all_taped() {
                self.unpack_full(ws);
            } else {
                let out = &ws.tape_out;
                let mut entry = 3 * n_tape;
                for (j, &r) in self.tape_rows.iter().enumerate() {
                    ws.value[r] = out[j];
                    ws.velocity[r] = out[n_tape + j];
                    ws.bias[r] = out[2 * n_tape + j];
                    let entries = self.row_entries(r);
                    let len = entries.len();
                    ws.jacobian[entries].copy_from_slice(&out[entry..entry + len]);
                    entry += len;
                }
            }
        }
        for (r, row) in &self.native_rows {
            let entries = self.row_start[*r]..self.row_start[r + 1];
            let (c, cdot, bias) = row.evaluate(x, v, &mut ws.jacobian[entries]);
            ws.value[*r] = c;
            ws.velocity[*r] = cdot;
            ws.bias[*r] = bias;
        }
        let n_expr = self.n_expr_rows;
        for (i, row) in self.custom_rows.iter().enumerate() {
            let r = n_expr + i;
            let len = row.coords.len();
            for (j, &k) in row.coords.iter().enumerate() {
                ws.local_x[j] = x[k];
                ws.local_v[j] = v[k];
            }
            let entries = self.row_entries(r);
            let (c, cdot, bias) = row.constraint.derivatives(
                &ws.local_x[..len],
                &ws.local_v[..len],
                t,
                &mut ws.duals,
                &mut ws.jacobian[entries],
            );
            ws.value[r] = c;
            ws.velocity[r] = cdot;
            ws.bias[r] = bias;
        }
    }

    /// C (`value`, m) and |J_i|^2 (`squared`, m) at x when every row is native (distances
    /// and pins, which do not depend on t), without writing J: the values
    /// [`ConstraintSet::gradient`] gives and the sums of squares of its rows' entries in
    /// their order, bit for bit. False, nothing written, when some row is not native.
    pub(crate) fn native_values_and_squared_gradients(
        &self,
        x: &[f64],
        value: &mut [f64],
        squared: &mut [f64],
    ) -> bool {
        if self.native_rows.len() != self.n_rows() {
            return false;
        }
        for (r, row) in &self.native_rows {
            (value[*r], squared[*r]) = row.value_and_squared_gradient(x);
        }
        true
    }

    /// C and J at (t, x) into `ws.value` and `ws.jacobian` (Cdot and bias untouched).
    /// Allocation-free.
    pub fn gradient(&self, t: f64, x: &[f64], ws: &mut ConstraintEval) {
        let n_tape = self.tape_rows.len();
        if n_tape > 0 {
            self.load_vars(t, x, None, ws);
            let nnz_tape = self.gradient_tape.n_outputs() - n_tape;
            self.gradient_tape.eval(
                &ws.vars,
                &mut ws.scratch,
                &mut ws.tape_out[..n_tape + nnz_tape],
            );
            if self.all_taped() {
                self.unpack_gradient(ws);
            } else {
                let out = &ws.tape_out;
                let mut entry = n_tape;
                for (j, &r) in self.tape_rows.iter().enumerate() {
                    ws.value[r] = out[j];
                    let entries = self.row_entries(r);
                    let len = entries.len();
                    ws.jacobian[entries].copy_from_slice(&out[entry..entry + len]);
                    entry += len;
                }
            }
        }
        for (r, row) in &self.native_rows {
            let entries = self.row_start[*r]..self.row_start[r + 1];
            ws.value[*r] = row.gradient(x, &mut ws.jacobian[entries]);
        }
        let n_expr = self.n_expr_rows;
        for (i, row) in self.custom_rows.iter().enumerate() {
            let r = n_expr + i;
            let len = row.coords.len();
            for (j, &k) in row.coords.iter().enumerate() {
                ws.local_x[j] = x[k];
                ws.local_v[j] = 0.0;
            }
            let entries = self.row_entries(r);
            let (c, _, _) = row.constraint.derivatives(
                &ws.local_x[..len],
                &ws.local_v[..len],
                t,
                &mut ws.duals,
                &mut ws.jacobian[entries],
            );
            ws.value[r] = c;
        }
    }

    /// C(x, t) into `ws.value`, nothing else. Allocation-free.
    pub fn residuals<'w>(&self, t: f64, x: &[f64], ws: &'w mut ConstraintEval) -> &'w [f64] {
        let n_tape = self.tape_rows.len();
        if n_tape > 0 {
            self.load_vars(t, x, None, ws);
            if self.all_taped() {
                self.value_tape
                    .eval(&ws.vars, &mut ws.scratch, &mut ws.value[..n_tape]);
            } else {
                self.value_tape
                    .eval(&ws.vars, &mut ws.scratch, &mut ws.tape_out[..n_tape]);
                for (j, &r) in self.tape_rows.iter().enumerate() {
                    ws.value[r] = ws.tape_out[j];
                }
            }
        }
        for (r, row) in &self.native_rows {
            ws.value[*r] = row.value(x);
        }
        let n_expr = self.n_expr_rows;
        for (i, row) in self.custom_rows.iter().enumerate() {
            let len = row.coords.len();
            for (j, &k) in row.coords.iter().enumerate() {
                ws.local_x[j] = x[k];
            }
            ws.value[n_expr + i] = row.constraint.value(&ws.local_x[..len], t);
        }
        &ws.value
    }

    /// Look near `x` for a point where row `row`'s gradient vanishes: Gauss-Newton over the
    /// coordinates the row reads (the others fixed), with the exact Hessian (symbolic for
    /// expression rows, dual numbers for Rust rows): those coordinates at the point found,
    /// |J(found)| / |J(x)| (see [`crate::linalg::gauss_newton_zero`]) and C there. Allocates:
    /// a diagnostic for the regularity monitor, not for the step loop.
    pub fn locate_singular_point(
        &self,
        row: usize,
        t: f64,
        x: &[f64],
    ) -> crate::formulation::SingularSearch {
        let columns = self.row_columns(row).to_vec();
        let k = columns.len();
        let mut y: Vec<f64> = columns.iter().map(|&c| x[c]).collect();
        let n = self.n_coords;
        match self.symbolic_row(row) {
            Some(expr_row) => {
                let gradient: Vec<&Expr> = expr_row.gradient.iter().map(|(_, e)| e).collect();
                let hessian: Vec<Expr> = gradient
                    .iter()
                    .flat_map(|g| columns.iter().map(move |&c| g.derivative(c)))
                    .collect();
                let mut vars = vec![0.0; 2 * n + 1];
                vars[..n].copy_from_slice(x);
                vars[2 * n] = t;
                let (reduction, residual) =
                    crate::linalg::gauss_newton_zero(&mut y, k, 40, |y, g, d| {
                        for (&c, &value) in columns.iter().zip(y) {
                            vars[c] = value;
                        }
                        for (slot, e) in g.iter_mut().zip(&gradient) {
                            *slot = e.eval(&vars);
                        }
                        for (slot, e) in d.iter_mut().zip(&hessian) {
                            *slot = e.eval(&vars);
                        }
                    });
                for (&c, &value) in columns.iter().zip(&y) {
                    vars[c] = value;
                }
                let value = expr_row.value.eval(&vars);
                crate::formulation::SingularSearch {
                    point: y,
                    reduction,
                    residual,
                    value,
                }
            }
            None => {
                let custom = &self.custom_rows[row - self.n_expr_rows];
                let (reduction, residual) =
                    crate::linalg::gauss_newton_zero(&mut y, k, 40, |y, g, d| {
                        custom.constraint.gradient_hessian(y, t, g, d);
                    });
                let value = custom.constraint.value(&y, t);
                crate::formulation::SingularSearch {
                    point: y,
                    reduction,
                    residual,
                    value,
                }
            }
        }
    }

    /// max_i |C_i(x, t)|, or 0 without constraints.
    pub fn max_abs_residual(&self, t: f64, x: &[f64], ws: &mut ConstraintEval) -> f64 {
        crate::linalg::max_abs(self.residuals(t, x, ws))
    }
}

#[cfg(test)]
mod tests {
    use crate::model::{ConstraintInfo, Endpoint, Holonomic, ParticleId, SystemBuilder};
    use crate::Scalar;

    /// x_p + y_p = 1, written in Rust.
    struct Diagonal(ParticleId);
    impl Holonomic for Diagonal {
        fn particles(&self) -> Vec<ParticleId> {
            vec![self.0]
        }
        fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
            x[0] + x[1] - 1.0
        }
    }

    /// The declared constraints as the set gives them on demand: names and descriptions
    /// written out by hand, rows in order with the Rust constraint by dual numbers (declared
    /// second) after the expression rows and the traced one (declared last) among them, the
    /// owner of every row by `info_of_row` and `name_of_row`, and the rows and lengths alone
    /// by `declared_rows`.
    #[test]
    fn declared_constraints_are_described_on_demand() {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        let p = b.particle("p", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
        let q = b.particle("q", 2.0, &[2.0, 0.0], &[0.0, 0.0]).unwrap();
        b.constraint_expr("p.x^2 + p.y^2 - 1").unwrap();
        b.holonomic_by_dual_numbers("diagonal", Diagonal(q));
        b.pin("pin", q, &[2.0, 0.0]).unwrap();
        b.distance("rod", q, Endpoint::Particle(p), 1.0).unwrap();
        b.distance("tether", p, Endpoint::Fixed(vec![0.0, 0.5]), 1.25)
            .unwrap();
        b.holonomic("traced", Diagonal(p));
        let system = b.build().unwrap();
        let set = system.constraints();
        let info = |name: &str, description: &str, rows, length| ConstraintInfo {
            name: name.into(),
            description: description.into(),
            rows,
            length,
        };
        let expected = [
            info("constraint 1", "p.x^2 + p.y^2 - 1 = 0", 0..1, None),
            info("pin", "pin(q) at [2.0, 0.0]", 1..3, None),
            info("rod", "distance(q, p) = 1", 3..4, Some(1.0)),
            info("tether", "distance(p, [0.0, 0.5]) = 1.25", 4..5, Some(1.25)),
            info(
                "traced",
                "Rust constraint (traced into an expression: symbolic derivatives)",
                5..6,
                None,
            ),
            info(
                "diagonal",
                "Rust constraint (derivatives by dual numbers: declared with \
                 holonomic_by_dual_numbers)",
                6..7,
                None,
            ),
        ];
        assert_eq!(set.n_declared(), 6);
        assert_eq!(set.infos().len(), 6);
        assert_eq!(set.infos().collect::<Vec<_>>(), expected);
        for (k, want) in expected.iter().enumerate() {
            assert_eq!(&set.info(k), want);
            for row in want.rows.clone() {
                assert_eq!(&set.info_of_row(row), want, "row {row}");
                assert_eq!(set.name_of_row(row), want.name, "row {row}");
            }
        }
        // In declaration order, the Rust constraint by dual numbers second.
        let declared: Vec<_> = (0..6).map(|k| system.constraint_description(k)).collect();
        let order = [0, 5, 1, 2, 3, 4];
        assert_eq!(declared, order.map(|k| expected[k].description.clone()));
        let rows: Vec<_> = set.declared_rows().collect();
        let want: Vec<_> = expected
            .iter()
            .map(|i| (i.rows.clone(), i.length))
            .collect();
        assert_eq!(rows, want);
    }

    fn set(expr: &str, at: [f64; 2]) -> crate::model::System {
        let mut b = SystemBuilder::new(&[0.0, 0.0]);
        b.particle("p", 1.0, &at, &[0.0, 0.0]).unwrap();
        b.constraint_expr(expr).unwrap();
        b.build().unwrap()
    }

    /// The search for a point where the gradient vanishes: it finds the crossing of the nodal
    /// cubic (on the curve, C = 0 there), finds the centre of an ellipse (a critical point of
    /// C, but off the curve: C = -1), and finds nothing on a parabola, whose gradient's
    /// component along the axis never vanishes.
    #[test]
    fn singular_point_search_tells_crossings_from_regular_points() {
        let node = set("p.y^2 - p.x^2*(p.x + 1)", [-0.05, 0.05]);
        let found = node
            .constraints()
            .locate_singular_point(0, 0.0, &[-0.05, 0.0475]);
        assert!(found.reduction < 1e-10, "{found:?}");
        assert!(found.point.iter().all(|c| c.abs() < 1e-10) && found.value.abs() < 1e-15);

        let ellipse = set("p.x^2 + (p.y/0.005)^2 - 1", [1.0, 0.0]);
        let found = ellipse
            .constraints()
            .locate_singular_point(0, 0.0, &[0.999, 0.0002]);
        assert!(found.reduction < 1e-10, "{found:?}");
        assert!((found.value + 1.0).abs() < 1e-12, "{found:?}");

        let parabola = set("p.x^2 + 100*p.y", [150.0, -225.0]);
        let found = parabola
            .constraints()
            .locate_singular_point(0, 0.0, &[150.0, -225.0]);
        assert!(found.reduction > 0.1, "{found:?}");
    }
}
