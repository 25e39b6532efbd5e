//! The parametric form's map from generalized coordinates to particle positions,
//! x_i = x_i(q, t), compiled with its exact derivatives.
//!
//! ```text
//! xdot = J qdot + x_t                                        J = dx/dq   (n_coords x n_q)
//! xddot = J qddot + h,   h = sum_jk x_qj_qk qdot_j qdot_k + 2 x_qt qdot + x_tt
//! ```
//!
//! h is built as the total time derivative of the xdot expression with qddot left out.

use crate::expr::{gradients, reads_any, share, Expr, Tape};

/// Generalized coordinates and the compiled map x(q, t). Expression slots: q = 0..n_q,
/// qdot = n_q..2 n_q, t = 2 n_q.
#[derive(Clone, Debug)]
pub struct ParametricMap {
    pub(crate) coordinates: Vec<String>,
    pub(crate) initial: Vec<f64>,
    pub(crate) rates: Vec<f64>,
    /// x_k(q, t) for every particle coordinate k (n_coords).
    pub(crate) positions: Vec<Expr>,
    pub(crate) velocities: Vec<Expr>,
    pub(crate) accelerations: Vec<Expr>,
    /// J row-major: dx_k/dq_j at k * n_q + j.
    pub(crate) jacobian: Vec<Expr>,
    /// Whether some h_k reads a rate qdot_j.
    bias_reads_rates: bool,
    /// Outputs: x (n) | xdot (n) | h (n) | J (n * n_q).
    tape: Tape,
    /// Outputs: x (n) | xdot (n), for mapping states back to particles.
    state_tape: Tape,
    /// Outputs: x (n) | xdot (n) | J (n * n_q), for the monitors (no h).
    observe_tape: Tape,
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
    /// J row-major (n_coords x n_q)
    pub jacobian: Vec<f64>,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
}

impl ParametricMap {
    /// Derive J, xdot and h of `positions` (slots: q, qdot, t) and compile them.
    ///
    /// The positions are first merged structurally (a sum written out in full in every
    /// position of a chain becomes one shared running sum), then every partial derivative of
    /// every position comes from one forward pass over their DAG ([`gradients`]); xdot =
    /// dx_k/dt + sum_j J_kj qdot_j is formed from them, and h the same way from the partials
    /// of xdot. The expressions are those that one derivative per (k, j) would build, only
    /// shared, and the cost is about the size of the expressions plus the nonzeros of J,
    /// where one walk per (k, j) was O(N^3) for a chain of N links.
    pub(crate) fn new(
        coordinates: Vec<String>,
        initial: Vec<f64>,
        rates: Vec<f64>,
        positions: Vec<Expr>,
    ) -> Self {
        let n_q = coordinates.len();
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
        let mut jacobian = vec![Expr::constant(0.0); positions.len() * n_q];
        for (k, partials) in position_partials.iter().enumerate() {
            for (j, d) in partials.iter().filter(|(j, _)| *j < n_q) {
                jacobian[k * n_q + j] = d.clone();
            }
        }
        let bias_reads_rates = reads_any(&accelerations, &|slot| (n_q..2 * n_q).contains(&slot));
        let mut outputs = positions.clone();
        outputs.extend(velocities.iter().cloned());
        outputs.extend(accelerations.iter().cloned());
        outputs.extend(jacobian.iter().cloned());
        ParametricMap {
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
            initial,
            rates,
            positions,
            velocities,
            accelerations,
            jacobian,
            bias_reads_rates,
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
    /// The symbolic x_k(q, t), its xdot, h and row k of J, for `bead check`.
    pub fn symbolic(&self, k: usize) -> (&Expr, &Expr, &Expr, &[Expr]) {
        let n_q = self.n_q();
        (
            &self.positions[k],
            &self.velocities[k],
            &self.accelerations[k],
            &self.jacobian[k * n_q..(k + 1) * n_q],
        )
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
    pub fn locate_singular_point(&self, j: usize, t: f64, q: &[f64]) -> (Vec<f64>, f64) {
        let n_q = self.n_q();
        let column: Vec<&Expr> = (0..self.positions.len())
            .map(|k| &self.jacobian[k * n_q + j])
            .collect();
        let derivatives: Vec<Expr> = column
            .iter()
            .flat_map(|e| (0..n_q).map(move |l| e.derivative(l)))
            .collect();
        let mut vars = vec![0.0; 2 * n_q + 1];
        vars[2 * n_q] = t;
        let mut y = q.to_vec();
        let reduction = crate::linalg::gauss_newton_zero(&mut y, column.len(), 40, |y, g, d| {
            vars[..n_q].copy_from_slice(y);
            for (slot, e) in g.iter_mut().zip(&column) {
                *slot = e.eval(&vars);
            }
            for (slot, e) in d.iter_mut().zip(&derivatives) {
                *slot = e.eval(&vars);
            }
        });
        (y, reduction)
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
            jacobian: vec![0.0; n * self.n_q()],
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
        let n = self.positions.len();
        ws.vars[..n_q].copy_from_slice(q);
        ws.vars[n_q..2 * n_q].copy_from_slice(qdot);
        ws.vars[2 * n_q] = t;
        self.tape.eval(&ws.vars, &mut ws.scratch, &mut ws.out);
        ws.position.copy_from_slice(&ws.out[..n]);
        ws.velocity.copy_from_slice(&ws.out[n..2 * n]);
        ws.bias.copy_from_slice(&ws.out[2 * n..3 * n]);
        ws.jacobian.copy_from_slice(&ws.out[3 * n..]);
    }

    /// x, xdot and J at (t, q, qdot), without h: what the run's monitors read. Allocation-free.
    pub fn observe(&self, t: f64, q: &[f64], qdot: &[f64], ws: &mut ParametricEval) {
        let n_q = self.n_q();
        let n = self.positions.len();
        ws.vars[..n_q].copy_from_slice(q);
        ws.vars[n_q..2 * n_q].copy_from_slice(qdot);
        ws.vars[2 * n_q] = t;
        let outputs = 2 * n + n * n_q;
        self.observe_tape
            .eval(&ws.vars, &mut ws.scratch, &mut ws.out[..outputs]);
        ws.position.copy_from_slice(&ws.out[..n]);
        ws.velocity.copy_from_slice(&ws.out[n..2 * n]);
        ws.jacobian.copy_from_slice(&ws.out[2 * n..outputs]);
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
