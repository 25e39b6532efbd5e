//! The parametric form's map from generalized coordinates to particle positions,
//! x_i = x_i(q, t), compiled with its exact derivatives.
//!
//! ```text
//! xdot = J qdot + x_t                                        J = dx/dq   (n_coords x n_q)
//! xddot = J qddot + h,   h = sum_jk x_qj_qk qdot_j qdot_k + 2 x_qt qdot + x_tt
//! ```
//!
//! h is built as the total time derivative of the xdot expression with qddot left out. J is
//! kept sparse: only the entries that are not the constant 0 are compiled.

use std::sync::Arc;

use crate::expr::{gradients, reads_any, share, Expr, Tape};

/// Generalized coordinates and the compiled map x(q, t). Expression slots: q = 0..n_q,
/// qdot = n_q..2 n_q, t = 2 n_q.
///
/// J is sparse: entries dx_k/dq_j whose expression is the constant 0 (x_k does not contain
/// q_j, or its derivative simplifies to 0) are structural zeros, neither compiled nor
/// evaluated. A chain of N links in angles has x_i depending on th_1..th_i only, so half of
/// its dense J is such zeros. The nonzeros are stored by rows (row k: the q's that x_k
/// depends on, ascending) and indexed by columns too (column j: the coordinates that move
/// with q_j), see [`ParametricMap::row_entries`] and [`ParametricMap::column_entries`].
#[derive(Clone, Debug)]
pub struct ParametricMap {
    pub(crate) initial: Vec<f64>,
    pub(crate) rates: Vec<f64>,
    /// The map itself, shared by the maps that differ only in where they start (the members
    /// of a sweep over initial values).
    code: Arc<MapCode>,
}

impl std::ops::Deref for ParametricMap {
    type Target = MapCode;
    fn deref(&self) -> &MapCode {
        &self.code
    }
}

/// The compiled part of a [`ParametricMap`]: its coordinates, expressions and tapes.
#[derive(Debug)]
pub struct MapCode {
    pub(crate) coordinates: Vec<String>,
    /// x_k(q, t) for every particle coordinate k (n_coords).
    pub(crate) positions: Vec<Expr>,
    pub(crate) velocities: Vec<Expr>,
    pub(crate) accelerations: Vec<Expr>,
    /// The nonzeros of J in row order: row k owns entries row_start[k]..row_start[k + 1]
    /// (n_coords + 1).
    row_start: Vec<usize>,
    /// The column j of each entry (nnz), ascending within a row.
    columns: Vec<usize>,
    /// dx_k/dq_j of each entry (nnz).
    pub(crate) jacobian: Vec<Expr>,
    /// Column j's entries are column_entry[column_start[j]..column_start[j + 1]] (n_q + 1).
    column_start: Vec<usize>,
    /// Entry indices (into the row order), grouped by column, ascending row within a column.
    column_entry: Vec<usize>,
    /// Whether some h_k reads a rate qdot_j.
    bias_reads_rates: bool,
    /// Outputs: x (n) | xdot (n) | h (n) | J (nnz).
    tape: Tape,
    /// The fused tapes (see [`super::FusedTapes`])
    fused: super::FusedTapes,
    /// Outputs: x (n) | xdot (n), for mapping states back to particles.
    state_tape: Tape,
    /// Outputs: x (n) | xdot (n) | J (nnz), for the monitors (no h).
    observe_tape: Tape,
}

/// One row of the symbolic map, for `bead check`: see [`ParametricMap::symbolic`].
#[derive(Clone, Copy, Debug)]
pub struct SymbolicRow<'a> {
    /// x_k(q, t)
    pub position: &'a Expr,
    /// xdot_k = J_k qdot + dx_k/dt
    pub velocity: &'a Expr,
    /// h_k = xddot_k - J_k qddot
    pub bias: &'a Expr,
    /// The q's x_k depends on (ascending): the structural nonzeros of row k of J.
    pub columns: &'a [usize],
    /// dx_k/dq_j for each of `columns`; every other entry of the row is 0.
    pub jacobian: &'a [Expr],
}

/// Results and scratch of [`ParametricMap::evaluate`], sized once.
#[derive(Clone, Debug)]
pub struct ParametricEval {
    /// x(q, t) (n_coords)
    pub position: Vec<f64>,
    /// xdot (n_coords)
    pub velocity: Vec<f64>,
    /// h = xddot - J qddot (n_coords)
    pub bias: Vec<f64>,
    /// The nonzeros of J in row order (nnz; see [`ParametricMap::row_entries`]).
    pub jacobian: Vec<f64>,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
}

impl ParametricEval {
    /// Where the tapes write their outputs before they are unpacked (see
    /// [`ParametricMap::unpack_evaluation`]).
    pub(crate) fn out_mut(&mut self) -> &mut [f64] {
        &mut self.out
    }
}

impl ParametricMap {
    /// The same map with other initial values q0 and rates qdot0 (lengths as before).
    pub(crate) fn with_initial(&self, initial: &[f64], rates: &[f64]) -> ParametricMap {
        ParametricMap {
            initial: initial.to_vec(),
            rates: rates.to_vec(),
            ..self.clone()
        }
    }

    /// Derive J, xdot and h of `positions` (slots: q, qdot, t) and compile them.
    ///
    /// The positions are first merged structurally (a sum written out in full in every
    /// position of a chain becomes one shared running sum), then every partial derivative of
    /// every position comes from one forward pass over their DAG ([`gradients`]); xdot =
    /// dx_k/dt + sum_j J_kj qdot_j is formed from them, and h the same way from the partials
    /// of xdot. The expressions are those that one derivative per (k, j) would build, only
    /// shared, and the cost is about the size of the expressions plus the nonzeros of J,
    /// where one walk per (k, j) was O(N^3) for a chain of N links. Partials that are the
    /// constant 0 are structural zeros of J and are not compiled.
    pub(crate) fn new(
        coordinates: Vec<String>,
        initial: Vec<f64>,
        rates: Vec<f64>,
        positions: Vec<Expr>,
    ) -> Self {
        let n_q = coordinates.len();
        let n = positions.len();
        let time = 2 * n_q;
        let wanted = |j: usize| j < n_q || j == time;
        // d/dt f = df/dt + sum_j df/dq_j qdot_j over the q's f contains (ascending), from f's
        // partials; qddot is left out.
        let total_derivative = |partials: &[(usize, Expr)]| {
            let start = match partials.last() {
                Some((slot, d)) if *slot == time => d.clone(),
                _ => Expr::constant(0.0),
            };
            partials
                .iter()
                .filter(|(j, _)| *j < n_q)
                .fold(start, |acc, (j, d)| acc + d * Expr::var(n_q + j))
        };
        let positions = share(&positions);
        let position_partials = gradients(&positions, &wanted);
        let velocities = share(
            &position_partials
                .iter()
                .map(|p| total_derivative(p))
                .collect::<Vec<_>>(),
        );
        let accelerations: Vec<Expr> = gradients(&velocities, &wanted)
            .iter()
            .map(|p| total_derivative(p))
            .collect();

        let mut row_start = Vec::with_capacity(n + 1);
        let mut columns = Vec::new();
        let mut jacobian = Vec::new();
        row_start.push(0);
        for partials in &position_partials {
            for (j, d) in partials {
                if *j < n_q && d.as_constant() != Some(0.0) {
                    columns.push(*j);
                    jacobian.push(d.clone());
                }
            }
            row_start.push(columns.len());
        }
        let mut column_start = vec![0; n_q + 1];
        for &j in &columns {
            column_start[j + 1] += 1;
        }
        for j in 0..n_q {
            column_start[j + 1] += column_start[j];
        }
        let mut fill = column_start.clone();
        let mut column_entry = vec![0; columns.len()];
        for (entry, &j) in columns.iter().enumerate() {
            column_entry[fill[j]] = entry;
            fill[j] += 1;
        }
        let bias_reads_rates = reads_any(&accelerations, &|slot| (n_q..2 * n_q).contains(&slot));

        let mut outputs = positions.clone();
        outputs.extend(velocities.iter().cloned());
        outputs.extend(accelerations.iter().cloned());
        outputs.extend(jacobian.iter().cloned());
        let code = MapCode {
            fused: super::FusedTapes::default(),
            tape: Tape::compile(&outputs),
            state_tape: Tape::compile(&[positions.as_slice(), velocities.as_slice()].concat()),
            observe_tape: Tape::compile(
                &[
                    positions.as_slice(),
                    velocities.as_slice(),
                    jacobian.as_slice(),
                ]
                .concat(),
            ),
            coordinates,
            positions,
            velocities,
            accelerations,
            row_start,
            columns,
            jacobian,
            column_start,
            column_entry,
            bias_reads_rates,
        };
        ParametricMap {
            initial,
            rates,
            code: Arc::new(code),
        }
    }

    /// Names of the generalized coordinates.
    pub fn coordinates(&self) -> &[String] {
        &self.coordinates
    }
    /// Number of generalized coordinates n_q.
    pub fn n_q(&self) -> usize {
        self.coordinates.len()
    }
    /// Initial q.
    pub fn initial(&self) -> &[f64] {
        &self.initial
    }
    /// Initial qdot.
    pub fn rates(&self) -> &[f64] {
        &self.rates
    }
    /// The symbolic x_k(q, t), its xdot, h and the nonzeros of row k of J, for `bead check`.
    pub fn symbolic(&self, k: usize) -> SymbolicRow<'_> {
        let entries = self.row_entries(k);
        SymbolicRow {
            position: &self.positions[k],
            velocity: &self.velocities[k],
            bias: &self.accelerations[k],
            columns: &self.columns[entries.clone()],
            jacobian: &self.jacobian[entries],
        }
    }
    /// Row k of J: its entries' positions in [`ParametricEval::jacobian`]; their columns are
    /// `jacobian_columns()[row_entries(k)]`.
    pub fn row_entries(&self, k: usize) -> std::ops::Range<usize> {
        self.row_start[k]..self.row_start[k + 1]
    }
    /// The column j of every nonzero of J, in row order (nnz).
    pub fn jacobian_columns(&self) -> &[usize] {
        &self.columns
    }
    /// Column j of J: the positions in [`ParametricEval::jacobian`] of its nonzeros, by
    /// ascending particle coordinate.
    pub fn column_entries(&self, j: usize) -> &[usize] {
        &self.column_entry[self.column_start[j]..self.column_start[j + 1]]
    }
    /// Number of structural nonzeros of J.
    pub fn jacobian_nonzeros(&self) -> usize {
        self.columns.len()
    }
    /// Whether h = xddot - J qddot depends on qdot: the map is nonlinear in q, or its J moves
    /// with t (symbolic dependence, a superset of the true one).
    pub fn bias_depends_on_rates(&self) -> bool {
        self.bias_reads_rates
    }
    /// Whether the map x(q, t) depends on t (a moving map, which does work on the particles).
    pub fn is_time_dependent(&self) -> bool {
        let time = 2 * self.n_q();
        self.positions.iter().any(|x| x.depends_on(time))
    }
    /// Look near `q` for a point where the column dx/dq_j vanishes (a cusp of the
    /// parametrization): Gauss-Newton over q with the map's exact second derivatives. Returns
    /// q at the point found and |dx/dq_j(found)| / |dx/dq_j(q)| (see
    /// [`crate::linalg::gauss_newton_zero`]). Allocates: a diagnostic, not for the step loop.
    pub fn locate_singular_point(&self, j: usize, t: f64, q: &[f64]) -> (Vec<f64>, f64, f64) {
        let n_q = self.n_q();
        let column: Vec<Expr> = self
            .column_entries(j)
            .iter()
            .map(|&e| self.jacobian[e].clone())
            .collect();
        // d(column)/dq, dense (entries x n_q), from one pass over the column's expressions.
        let mut derivatives = vec![Expr::constant(0.0); column.len() * n_q];
        for (e, partials) in gradients(&column, &|l| l < n_q).into_iter().enumerate() {
            for (l, d) in partials {
                derivatives[e * n_q + l] = d;
            }
        }
        let mut vars = vec![0.0; 2 * n_q + 1];
        vars[2 * n_q] = t;
        let mut y = q.to_vec();
        let (reduction, residual) =
            crate::linalg::gauss_newton_zero(&mut y, column.len(), 40, |y, g, d| {
                vars[..n_q].copy_from_slice(y);
                for (slot, e) in g.iter_mut().zip(&column) {
                    *slot = e.eval(&vars);
                }
                for (slot, e) in d.iter_mut().zip(&derivatives) {
                    *slot = e.eval(&vars);
                }
            });
        (y, reduction, residual)
    }

    /// Size of the compiled code.
    pub fn n_instructions(&self) -> usize {
        self.tape.n_instructions()
    }

    /// A workspace sized for this map.
    pub fn workspace(&self) -> ParametricEval {
        let n = self.positions.len();
        ParametricEval {
            position: vec![0.0; n],
            velocity: vec![0.0; n],
            bias: vec![0.0; n],
            jacobian: vec![0.0; self.columns.len()],
            vars: vec![0.0; 2 * self.n_q() + 1],
            scratch: vec![
                0.0;
                self.tape
                    .n_slots()
                    .max(self.state_tape.n_slots())
                    .max(self.observe_tape.n_slots())
            ],
            out: vec![0.0; self.tape.n_outputs()],
        }
    }

    /// Evaluate x, xdot, h and J at (t, q, qdot). Allocation-free.
    pub fn evaluate(&self, t: f64, q: &[f64], qdot: &[f64], ws: &mut ParametricEval) {
        let n_q = self.n_q();
        ws.vars[..n_q].copy_from_slice(q);
        ws.vars[n_q..2 * n_q].copy_from_slice(qdot);
        ws.vars[2 * n_q] = t;
        self.tape.eval(&ws.vars, &mut ws.scratch, &mut ws.out);
        self.unpack_evaluation(ws);
    }

    /// Every tape of the map (for the machine code summary), the fused acceleration's and
    /// its RK4 steps' once built.
    pub(crate) fn tapes(&self) -> Vec<Tape> {
        [&self.tape, &self.state_tape, &self.observe_tape]
            .into_iter()
            .cloned()
            .chain(self.fused.built())
            .collect()
    }

    /// The fused tapes the formulation builds for this map (see [`super::FusedTapes`]).
    pub(crate) fn fused(&self) -> &super::FusedTapes {
        &self.fused
    }

    /// The tape of x, xdot, h and J (outputs in that order), variables q, qdot, t.
    pub(crate) fn evaluation_tape(&self) -> &Tape {
        &self.tape
    }

    /// The tape of x, xdot and J (outputs in that order), variables q, qdot, t.
    pub(crate) fn observation_tape(&self) -> &Tape {
        &self.observe_tape
    }

    /// [`ParametricMap::evaluate`]'s tape outputs, in `ws.out`, into x, xdot, h and J.
    pub(crate) fn unpack_evaluation(&self, ws: &mut ParametricEval) {
        let n = self.positions.len();
        ws.position.copy_from_slice(&ws.out[..n]);
        ws.velocity.copy_from_slice(&ws.out[n..2 * n]);
        ws.bias.copy_from_slice(&ws.out[2 * n..3 * n]);
        ws.jacobian.copy_from_slice(&ws.out[3 * n..]);
    }

    /// [`ParametricMap::observe`]'s tape outputs, in `ws.out`, into x, xdot and J.
    pub(crate) fn unpack_observation(&self, ws: &mut ParametricEval) {
        let n = self.positions.len();
        let outputs = 2 * n + self.columns.len();
        ws.position.copy_from_slice(&ws.out[..n]);
        ws.velocity.copy_from_slice(&ws.out[n..2 * n]);
        ws.jacobian.copy_from_slice(&ws.out[2 * n..outputs]);
    }

    /// [`ParametricMap::observe`]'s result from the observation tape's outputs `observed`
    /// (x, xdot, J), evaluated elsewhere (inside a compiled step, at its end): `ws` as
    /// `observe` leaves it. Allocation-free.
    ///
    /// # Panics
    /// If `observed` is not the observation tape's outputs.
    pub(crate) fn take_observation(&self, observed: &[f64], ws: &mut ParametricEval) {
        let outputs = 2 * self.positions.len() + self.columns.len();
        ws.out[..outputs].copy_from_slice(observed);
        self.unpack_observation(ws);
    }

    /// x, xdot and J at (t, q, qdot), without h: what the run's monitors read. Allocation-free.
    pub fn observe(&self, t: f64, q: &[f64], qdot: &[f64], ws: &mut ParametricEval) {
        let n_q = self.n_q();
        let n = self.positions.len();
        ws.vars[..n_q].copy_from_slice(q);
        ws.vars[n_q..2 * n_q].copy_from_slice(qdot);
        ws.vars[2 * n_q] = t;
        let outputs = 2 * n + self.columns.len();
        self.observe_tape
            .eval(&ws.vars, &mut ws.scratch, &mut ws.out[..outputs]);
        self.unpack_observation(ws);
    }

    /// Particle positions and velocities x(q, t), xdot(q, qdot, t) only, into `ws.position`
    /// and `ws.velocity`. Allocation-free.
    pub fn state_at(&self, t: f64, q: &[f64], qdot: &[f64], ws: &mut ParametricEval) {
        let n_q = self.n_q();
        let n = self.positions.len();
        ws.vars[..n_q].copy_from_slice(q);
        ws.vars[n_q..2 * n_q].copy_from_slice(qdot);
        ws.vars[2 * n_q] = t;
        self.state_tape
            .eval(&ws.vars, &mut ws.scratch, &mut ws.out[..2 * n]);
        ws.position.copy_from_slice(&ws.out[..n]);
        ws.velocity.copy_from_slice(&ws.out[n..2 * n]);
    }
}
