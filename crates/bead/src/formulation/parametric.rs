//! The parametric form: Lagrange's equations in generalized coordinates q.
//!
//! With x = x(q, t), J = dx/dq, xddot = J qddot + h and applied forces F, projecting Newton's
//! law onto the tangent directions (d'Alembert) gives
//!
//! ```text
//! M(q) qddot = Q - sum_i m_i J_i^T h_i,    M = sum_i m_i J_i^T J_i,   Q = sum_i J_i^T F_i
//! ```
//!
//! which for conservative F is d/dt dT/dqdot - dT/dq = Q. The constraints hold exactly by
//! construction.
//!
//! J is sparse (see [`ParametricMap`]): row k lists the q's that particle coordinate k depends
//! on, and M and Q are assembled over those lists only, M_jl += m_k J_kj J_kl for the pairs of
//! row k. Cost per evaluation: the compiled map tape (the nonzeros of J, x, xdot and h), the
//! sum over rows of (row length)^2 / 2 for M (n n_q^2 / 2 when every x_k depends on every q,
//! about N^3 / 3 for a chain of N links in angles, against n n_q^2 / 2 = N^3 dense), and
//! n_q^3 / 6 for the dense LDL^T solve.

use std::sync::Arc;

use super::fused::{compiled_rk4_step, FusedParametric, ParametricBuffers};
use super::implicit::{accumulate_all_forces, external_power};
use super::{
    Formulation, FormulationError, Gradients, Method, Nonconservation, Observation,
    SecondOrderSystem, SingularSearch, State, StepError, Subject,
};
use crate::linalg::{DenseLdlt, SymmetricPattern, SymmetricSolver};
use crate::model::{ConstraintEval, Force, ParametricEval, ParametricMap, System};

/// Buffers of [`Parametric::accelerate_across_lanes`], sized on first use.
#[derive(Debug, Default)]
pub(crate) struct LaneScratch {
    pub(super) force: Vec<f64>,
    matrix: Vec<f64>,
    dense: Vec<f64>,
}

/// The parametric (generalized-coordinate) formulation.
pub struct Parametric {
    pub(crate) system: Arc<System>,
    /// Evaluations of the acceleration so far
    evaluations: u64,
    /// Dense LDL^T of M (n_q x n_q)
    solver: DenseLdlt,
    pub(super) map: ParametricEval,
    /// F (n_coords)
    pub(super) force: Vec<f64>,
    /// The mass of each particle coordinate (n_coords), so the hot loops multiply
    coordinate_mass: Vec<f64>,
    /// The nonzeros of J as runs of consecutive columns, for the assembly of M
    runs: Runs,
    /// M's lower triangle by rows (= its upper triangle by columns): (j, l), l <= j, at
    /// j (j + 1) / 2 + l
    matrix: Vec<f64>,
    /// rhs, then qddot (n_q)
    rhs: Vec<f64>,
    /// Forces applied from outside the system (see [`Formulation::external_forces_mut`]).
    external: Vec<Force>,
    /// The system's implicit constraints, evaluated at the mapped positions for the monitors.
    constraints: ConstraintEval,
    /// Whether qddot depends on qdot, decided once from the model (see `velocity_dependent`).
    velocity_dependent: bool,
    /// The whole acceleration in one tape, for small maps under constant forces (see
    /// [`super::fused`]); used while no external force is applied.
    pub(crate) fused: Option<FusedParametric>,
    /// Whether the last evaluation was the fused tape's, whose x, xdot, h, J and F are still
    /// in its outputs (see [`Parametric::unpack`]) rather than in `map` and `force`
    fused_pending: bool,
}

impl Parametric {
    /// The parametric form of `system`; an error when the system has none.
    pub fn new(system: Arc<System>) -> Result<Self, FormulationError> {
        let map = system
            .parametric()
            .ok_or(FormulationError::NoParametricForm)?;
        let n_q = map.n_q();
        // qddot depends on qdot through drag, or through h = x_qq(qdot, qdot) + 2 x_qt qdot
        // + x_tt when the compiled h reads a rate slot (n_q..2 n_q): a map nonlinear in q (so
        // also any non-constant M(q)) or one whose J moves with t. Symbolic dependence is a
        // superset of the true one, so this errs on the safe side.
        let velocity_dependent =
            system.has_velocity_dependent_forces() || map.bias_depends_on_rates();
        let solver = DenseLdlt::new(&SymmetricPattern::dense(n_q));
        let coordinate_mass = system.coordinate_masses();
        // The applied forces, constant where the fused path applies (x, v are not read).
        let mut force = vec![0.0; system.n_coords()];
        let zeros = vec![0.0; system.n_coords()];
        accumulate_all_forces(&system, &[], &zeros, &zeros, &mut force);
        let fused = FusedParametric::new(
            &system,
            &force,
            &coordinate_mass,
            solver.relative_pivot_tolerance,
        );
        Ok(Parametric {
            evaluations: 0,
            fused,
            fused_pending: false,
            velocity_dependent,
            solver,
            map: map.workspace(),
            force: vec![0.0; system.n_coords()],
            coordinate_mass,
            runs: Runs::new(map),
            matrix: vec![0.0; n_q * (n_q + 1) / 2],
            rhs: vec![0.0; n_q],
            external: Vec::new(),
            constraints: system.constraints().workspace(),
            system,
        })
    }

    fn parametric_map(&self) -> &ParametricMap {
        self.system
            .parametric()
            .expect("checked in Parametric::new")
    }

    /// Evaluate the map and the forces at (t, q, qdot) and assemble M into `matrix` and
    /// Q - sum m J^T h into `rhs`. Allocation-free.
    #[cfg(test)]
    fn assemble_at(&mut self, t: f64, q: &[f64], qdot: &[f64]) {
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        map.evaluate(t, q, qdot, &mut self.map);
        self.assemble_evaluated();
    }

    /// M and the right-hand side from the map's evaluation already in
    /// [`Parametric::evaluation_mut`].
    fn assemble_evaluated(&mut self) {
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        let ws = &mut self.map;
        accumulate_all_forces(
            system,
            &self.external,
            &ws.position,
            &ws.velocity,
            &mut self.force,
        );
        assemble(
            map,
            &self.runs,
            ws,
            &self.coordinate_mass,
            &self.force,
            &mut self.matrix,
            &mut self.rhs,
        );
    }
}

impl SecondOrderSystem for Parametric {
    fn n_coords(&self) -> usize {
        self.parametric_map().n_q()
    }

    fn acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        qddot: &mut [f64],
    ) -> Result<(), StepError> {
        self.evaluations += 1;
        let map = self
            .system
            .parametric()
            .expect("checked in Parametric::new");
        if let Some(fused) = self.fused.as_mut().filter(|_| self.external.is_empty()) {
            if fused.accelerate(t, q, qdot, qddot) {
                self.fused_pending = true;
                return Ok(());
            }
        }
        map.evaluate(t, q, qdot, &mut self.map);
        self.accelerate_evaluated(t, q, qdot, qddot)
    }

    /// True with a velocity-dependent force (drag) or when h = xddot - J qddot depends on
    /// qdot (the map is nonlinear in q or its J depends on t); decided at construction.
    fn velocity_dependent(&self) -> bool {
        self.velocity_dependent || self.external.iter().any(|f| f.depends_on_velocity())
    }

    /// The fused acceleration's RK4 step (see `formulation/fused.rs`), with no external force.
    fn compiled_rk4_step(&mut self, state: &mut State, dt: f64) -> bool {
        if !self.compiles_rk4_step() {
            return false;
        }
        let map = self
            .system
            .parametric()
            .expect("checked in Parametric::new");
        let fused = self.fused.as_mut().expect("checked above");
        // With x, xdot and J at the step's end, which the monitors read there (`observe`;
        // the sweep lanes' step for these constants, so one tape for both).
        let observe = Some(map.observation_tape());
        let stepped = compiled_rk4_step(fused, map.fused(), observe, state, dt);
        self.evaluations += if stepped { 4 } else { 0 };
        stepped
    }

    fn discount_compiled_steps(&mut self, steps: u64) {
        self.evaluations -= 4 * steps;
    }

    fn compiles_rk4_step(&self) -> bool {
        self.external.is_empty() && self.fused.is_some()
    }

    fn compiled_step_observation(&self, t: f64, q: &[f64], qdot: &[f64]) -> Option<&[f64]> {
        self.fused.as_ref()?.observation_at(t, q, qdot)
    }

    fn compiled_step_observation_after(&self, t: f64) -> Option<&[f64]> {
        self.fused.as_ref()?.observation_after_step(t)
    }
}

impl Parametric {
    /// The last evaluation's x, xdot, h, J and F into `map` and `force`, where the fused tape
    /// left them in its outputs.
    pub(super) fn unpack(&mut self) {
        if let Some(fused) = self.fused.as_ref().filter(|_| self.fused_pending) {
            let ws = &mut self.map;
            fused.unpack(ParametricBuffers {
                position: &mut ws.position,
                velocity: &mut ws.velocity,
                bias: &mut ws.bias,
                jacobian: &mut ws.jacobian,
                force: &mut self.force,
            });
            self.fused_pending = false;
        }
    }

    /// The map's reaction on particle coordinate k at the last evaluation (`evaluated`, from
    /// [`Parametric::evaluated`]), whose result was `qddot`: m_k a_k - F_k with
    /// a = J qddot + h (the constraint force the map exerts).
    fn reaction(&self, evaluated: &[&[f64]; 5], k: usize, qddot: &[f64]) -> f64 {
        let [_, _, bias, jacobian, force] = *evaluated;
        let map = self.parametric_map();
        let entries = map.row_entries(k);
        let jq: f64 = jacobian[entries.clone()]
            .iter()
            .zip(&map.jacobian_columns()[entries])
            .map(|(v, &j)| v * qddot[j])
            .sum();
        self.coordinate_mass[k] * (jq + bias[k]) - force[k]
    }

    /// The last evaluation's x, xdot, h, J and F, wherever they are.
    pub(super) fn evaluated(&self) -> [&[f64]; 5] {
        match &self.fused {
            Some(fused) if self.fused_pending => fused.evaluation(),
            _ => {
                let ws = &self.map;
                [
                    &ws.position,
                    &ws.velocity,
                    &ws.bias,
                    &ws.jacobian,
                    &self.force,
                ]
            }
        }
    }

    /// The observation at time t from the map's x, xdot and J already in
    /// [`Parametric::evaluation_mut`] (by [`ParametricMap::observe`]): what
    /// [`Formulation::observe`] does after evaluating the map.
    pub(crate) fn observe_evaluated(&mut self, t: f64, out: &mut Observation) {
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        // The fused tape's outputs in place, or the map's evaluation.
        let [position, velocity, _, jacobian, _] = self.evaluated();
        out.x.copy_from_slice(position);
        out.xdot.copy_from_slice(velocity);
        let mut values = out.gradients.values.iter_mut();
        for j in 0..map.n_q() {
            for (&entry, value) in map.column_entries(j).iter().zip(&mut values) {
                *value = jacobian[entry];
            }
        }
        let set = system.constraints();
        if set.n_rows() > 0 {
            let values = set.residuals(t, &out.x, &mut self.constraints);
            out.constraints.copy_from_slice(values);
        }
    }

    /// Whether [`Parametric::accelerate_across_lanes`] applies: gravity is the only force.
    pub(crate) fn across_lanes(&self) -> bool {
        self.system.forces().is_empty() && self.external.is_empty()
    }

    /// [`Parametric::accelerate_evaluated`] for L members at once from the evaluation tape's
    /// outputs (structure of arrays: output o of member l at `out[o * L + l]`), gravity the
    /// only force: the same operations in the same order per member, members innermost, into
    /// `qddot` (n_q x L). `scratch` holds F, M (packed and dense) and the right-hand side.
    /// `failed[l]` is set when member l's mass matrix is singular (its qddot is then garbage).
    ///
    /// ```text
    /// F = M g;  M = sum_k m_k J_k^T J_k;  M qddot = sum_k J_k^T (F_k - m_k h_k)
    /// ```
    pub(crate) fn accelerate_across_lanes<const L: usize>(
        &self,
        out: &[f64],
        scratch: &mut LaneScratch,
        qddot: &mut [f64],
        failed: &mut [Option<crate::linalg::Singular>; L],
    ) {
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        let (n, n_q, dim) = (map.positions.len(), map.n_q(), system.dim());
        scratch.force.resize(n * L, 0.0);
        scratch.matrix.resize(n_q * (n_q + 1) / 2 * L, 0.0);
        scratch.dense.resize(n_q * n_q * L, 0.0);
        let force = &mut scratch.force;
        for (p, particle) in system.particles().iter().enumerate() {
            for (a, g) in system.gravity().iter().enumerate() {
                force[(p * dim + a) * L..(p * dim + a + 1) * L].fill(particle.mass * g);
            }
        }
        // assemble(): M and the right-hand side, lanes innermost.
        let (matrix, rhs) = (&mut scratch.matrix, &mut qddot[..n_q * L]);
        matrix.fill(0.0);
        rhs.fill(0.0);
        let (bias, jacobian) = (&out[2 * n * L..3 * n * L], &out[3 * n * L..]);
        let columns = map.jacobian_columns();
        for (k, &m) in self.coordinate_mass.iter().enumerate() {
            let entries = map.row_entries(k);
            let start = entries.start;
            let mut reduced = [0.0; L];
            for (l, r) in reduced.iter_mut().enumerate() {
                *r = force[k * L + l] - m * bias[k * L + l];
            }
            for (a, &j) in columns[entries].iter().enumerate() {
                let e = start + a;
                let mut weighted = [0.0; L];
                for l in 0..L {
                    rhs[j * L + l] += jacobian[e * L + l] * reduced[l];
                    weighted[l] = m * jacobian[e * L + l];
                }
                let row = j * (j + 1) / 2;
                for run in self.runs.of_row(k) {
                    if run.entry > a {
                        break;
                    }
                    let len = run.len.min(a + 1 - run.entry);
                    for c in 0..len {
                        let (target, other) = (row + run.column + c, start + run.entry + c);
                        for l in 0..L {
                            matrix[target * L + l] += weighted[l] * jacobian[other * L + l];
                        }
                    }
                }
            }
        }
        self.solver.scatter_lanes::<L>(matrix, &mut scratch.dense);
        crate::linalg::ldlt_lanes::<L>(
            n_q,
            &mut scratch.dense,
            self.solver.relative_pivot_tolerance,
            failed,
        );
        crate::linalg::ldlt_substitute_lanes::<L>(n_q, &scratch.dense, rhs);
    }

    /// The map's evaluation (x, xdot, h, J at (t, q, qdot)) that
    /// [`Parametric::accelerate_evaluated`] reads.
    pub(crate) fn evaluation_mut(&mut self) -> &mut ParametricEval {
        self.unpack();
        &mut self.map
    }

    /// qddot at (t, q, qdot) from the map's evaluation already in
    /// [`Parametric::evaluation_mut`]: what [`SecondOrderSystem::acceleration`] does after
    /// evaluating the map, so that an ensemble evaluating it for many members at once
    /// finishes each member with this same code.
    pub(crate) fn accelerate_evaluated(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        qddot: &mut [f64],
    ) -> Result<(), StepError> {
        self.fused_pending = false;
        self.assemble_evaluated();
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        let factored = self.solver.factor(&self.matrix);
        if factored.is_ok() {
            self.solver.solve_in_place(&mut self.rhs);
        }
        let ws = &self.map;
        if let Err(singular) = factored {
            let inputs = [q, qdot, &ws.position, &ws.velocity, &ws.jacobian, &ws.bias];
            if !singular.finite || inputs.iter().any(|v| v.iter().any(|c| !c.is_finite())) {
                return Err(non_finite_input(system, map, t, q, qdot, ws, &self.force));
            }
            return Err(StepError::SingularMassMatrix {
                t,
                coordinate: map.coordinates()[singular.row].clone(),
            });
        }
        qddot.copy_from_slice(&self.rhs);
        Ok(())
    }
}

impl Formulation for Parametric {
    fn evaluations(&self) -> u64 {
        self.evaluations
    }

    fn method(&self) -> Method {
        Method::Parametric
    }
    fn system(&self) -> &System {
        &self.system
    }
    fn shared_system(&self) -> Arc<System> {
        Arc::clone(&self.system)
    }
    fn initial_state(&self) -> State {
        let map = self.parametric_map();
        State {
            t: 0.0,
            q: map.initial().to_vec(),
            qdot: map.rates().to_vec(),
        }
    }
    fn coordinate_names(&self) -> &[String] {
        self.parametric_map().coordinates()
    }
    fn particle_state(&mut self, t: f64, q: &[f64], qdot: &[f64], x: &mut [f64], xdot: &mut [f64]) {
        // What the map's evaluation holds besides x and xdot stays the last acceleration's.
        self.unpack();
        let map = self
            .system
            .parametric()
            .expect("checked in Parametric::new");
        map.state_at(t, q, qdot, &mut self.map);
        x.copy_from_slice(&self.map.position);
        xdot.copy_from_slice(&self.map.velocity);
    }

    fn external_forces_mut(&mut self) -> &mut Vec<Force> {
        &mut self.external
    }

    fn external_forces(&self) -> &[Force] {
        &self.external
    }

    /// P = sum_k v_k (m_k a_k - F_k) + F_nc . v with a = J qddot + h: the map's reaction force
    /// m a - F (which works only when the map moves, since J^T (m a - F) = 0) plus the forces
    /// without a potential, at the last evaluation.
    fn power(&self, _q: &[f64], _qdot: &[f64], qddot: &[f64]) -> f64 {
        let evaluated = self.evaluated();
        let [position, velocity, _, _, _] = evaluated;
        let reaction: f64 = (0..position.len())
            .map(|k| velocity[k] * self.reaction(&evaluated, k, qddot))
            .sum();
        reaction + self.applied_power(position, velocity)
    }

    /// Here `x`, `v` are particle positions and velocities (the map's, from the last
    /// evaluation, when called by [`Formulation::power`]).
    fn applied_power(&self, x: &[f64], v: &[f64]) -> f64 {
        let system = &*self.system;
        if x.len() != system.n_coords() {
            return 0.0;
        }
        system.nonconservative_power(x, v) + external_power(system, &self.external, x, v)
    }

    fn constraint_forces(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        qddot: &mut [f64],
        multipliers: &mut Vec<f64>,
        force: &mut [f64],
    ) -> Result<(), StepError> {
        self.acceleration(t, q, qdot, qddot)?;
        multipliers.clear();
        let evaluated = self.evaluated();
        for (k, f) in force.iter_mut().enumerate() {
            *f = self.reaction(&evaluated, k, qddot);
        }
        Ok(())
    }

    fn nonconservation(&self) -> Vec<Nonconservation> {
        let mut out: Vec<Nonconservation> = self
            .system
            .nonconservative_forces()
            .into_iter()
            .map(Nonconservation::Force)
            .collect();
        if self.parametric_map().is_time_dependent() {
            out.push(Nonconservation::MovingMap);
        }
        if !self.external.is_empty() {
            out.push(Nonconservation::External);
        }
        out
    }

    fn new_observation(&self) -> Observation {
        let n = self.system.n_coords();
        let map = self.parametric_map();
        Observation {
            x: vec![0.0; n],
            xdot: vec![0.0; n],
            constraints: vec![0.0; self.system.constraints().n_rows()],
            gradients: Gradients::with_rows((0..map.n_q()).map(|j| map.column_entries(j).len())),
        }
    }

    /// Gradient row j: the column dx/dq_j of the map, over the particle coordinates that
    /// depend on q_j (its structural nonzeros; the others are 0 at every state).
    fn observe(&mut self, t: f64, q: &[f64], qdot: &[f64], out: &mut Observation) {
        self.unpack();
        let map = self
            .system
            .parametric()
            .expect("checked in Parametric::new");
        let ws = &mut self.map;
        // At the end of a compiled step, x, xdot and J were evaluated inside it: the
        // observation tape's outputs, taken as `ParametricMap::observe` takes its own.
        match self
            .fused
            .as_ref()
            .and_then(|f| f.observation_at(t, q, qdot))
        {
            Some(observed) => {
                #[cfg(debug_assertions)]
                {
                    map.observe(t, q, qdot, ws);
                    let n = ws.position.len();
                    let (x, rest) = observed.split_at(n);
                    let (xdot, jacobian) = rest.split_at(n);
                    assert!(
                        crate::same_bits(x, &ws.position)
                            && crate::same_bits(xdot, &ws.velocity)
                            && crate::same_bits(jacobian, &ws.jacobian),
                        "the step's observation differs from the observation tape's"
                    );
                    // What `take_observation` does not write would show as NaN.
                    for v in [&mut ws.position, &mut ws.velocity, &mut ws.jacobian] {
                        v.fill(f64::NAN);
                    }
                }
                map.take_observation(observed, ws);
            }
            None => map.observe(t, q, qdot, ws),
        }
        self.observe_evaluated(t, out);
    }

    /// x, xdot and J from the evaluation tape's outputs of the last acceleration (the same
    /// as the observation tape's, checked in debug builds by the monitor).
    fn observe_accelerated(
        &mut self,
        t: f64,
        _q: &[f64],
        _qdot: &[f64],
        out: &mut Observation,
    ) -> bool {
        self.observe_evaluated(t, out);
        true
    }

    fn gradient_subject(&self, row: usize) -> Subject {
        Subject::Coordinate {
            name: self.parametric_map().coordinates()[row].clone(),
        }
    }

    fn gradient_position(&self, row: usize, q: &[f64]) -> Vec<(String, f64)> {
        vec![(self.parametric_map().coordinates()[row].clone(), q[row])]
    }

    fn row_variables(&self, _row: usize, q: &[f64]) -> Vec<f64> {
        q.to_vec()
    }

    fn locate_singular_point(&self, row: usize, t: f64, q: &[f64]) -> SingularSearch {
        let (point, reduction, residual) = self.parametric_map().locate_singular_point(row, t, q);
        SingularSearch {
            point,
            reduction,
            residual,
            value: 0.0,
        }
    }

    fn row_step_length(&self, _row: usize, q: &[f64], before: &[f64]) -> f64 {
        q.iter()
            .zip(before)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt()
    }
}

/// The nonzeros of each row of J grouped into runs of consecutive columns: row k owns
/// `runs[row_runs[k]..row_runs[k + 1]]`. A chain's row is one run (th_1..th_i), so the
/// assembly's inner loop is a slice update the compiler vectorizes; scattered columns make
/// runs of one.
struct Runs {
    row_runs: Vec<usize>,
    runs: Vec<Run>,
}

/// `len` entries of a row, from its entry `entry` on (counted within the row), in the
/// consecutive columns `column..column + len`.
#[derive(Clone, Copy, Debug)]
struct Run {
    column: usize,
    entry: usize,
    len: usize,
}

impl Runs {
    fn new(map: &ParametricMap) -> Runs {
        let columns = map.jacobian_columns();
        let mut row_runs = vec![0];
        let mut runs: Vec<Run> = Vec::new();
        for k in 0..map.positions.len() {
            let first = runs.len();
            for (entry, &column) in columns[map.row_entries(k)].iter().enumerate() {
                match runs[first..].last_mut() {
                    Some(run) if run.column + run.len == column => run.len += 1,
                    _ => runs.push(Run {
                        column,
                        entry,
                        len: 1,
                    }),
                }
            }
            row_runs.push(runs.len());
        }
        Runs { row_runs, runs }
    }

    fn of_row(&self, k: usize) -> &[Run] {
        &self.runs[self.row_runs[k]..self.row_runs[k + 1]]
    }
}

/// M = sum_k m_k J_k^T J_k (its lower triangle by rows, packed: (j, l) at j (j + 1) / 2 + l)
/// and rhs = sum_k J_k^T (F_k - m_k h_k)
/// over the nonzeros of J: for each particle coordinate k, the pairs (j, l) of the q's it
/// depends on. Rows are visited in order, so each entry sums its terms in the order of the
/// dense formula, without its zero terms, and gets the same value. Allocation-free.
fn assemble(
    map: &ParametricMap,
    runs: &Runs,
    ws: &ParametricEval,
    mass: &[f64],
    force: &[f64],
    matrix: &mut [f64],
    rhs: &mut [f64],
) {
    matrix.fill(0.0);
    rhs.fill(0.0);
    let columns = map.jacobian_columns();
    for (k, &m) in mass.iter().enumerate() {
        let entries = map.row_entries(k);
        let values = &ws.jacobian[entries.clone()];
        let reduced = force[k] - m * ws.bias[k];
        for (a, (&j, &value)) in columns[entries].iter().zip(values).enumerate() {
            rhs[j] += value * reduced;
            // M_jl += m J_kj J_kl for the row's entries up to this one: columns ascend within
            // a row, so l <= j, the lower triangle.
            let weighted = m * value;
            let row = &mut matrix[j * (j + 1) / 2..(j + 1) * (j + 2) / 2];
            for run in runs.of_row(k) {
                if run.entry > a {
                    break;
                }
                let len = run.len.min(a + 1 - run.entry);
                let target = &mut row[run.column..run.column + len];
                for (t, &other) in target.iter_mut().zip(&values[run.entry..run.entry + len]) {
                    *t += weighted * other;
                }
            }
        }
    }
}

/// The first non-finite input of an evaluation, as the error to report instead of a singular
/// mass matrix.
fn non_finite_input(
    system: &System,
    map: &ParametricMap,
    t: f64,
    q: &[f64],
    qdot: &[f64],
    ws: &ParametricEval,
    force: &[f64],
) -> StepError {
    let names = map.coordinates();
    let quantity = if let Some(j) = q.iter().position(|c| !c.is_finite()) {
        format!("the coordinate {} ({})", names[j], q[j])
    } else if let Some(j) = qdot.iter().position(|c| !c.is_finite()) {
        format!("the rate of {} ({})", names[j], qdot[j])
    } else if let Some(k) = ws.position.iter().position(|c| !c.is_finite()) {
        format!(
            "the parametric position {} ({})",
            system.coordinate_name(k),
            ws.position[k]
        )
    } else if let Some(k) = ws.velocity.iter().position(|c| !c.is_finite()) {
        format!(
            "the parametric velocity {} ({})",
            system.velocity_name(k),
            ws.velocity[k]
        )
    } else if ws.jacobian.iter().any(|c| !c.is_finite()) {
        "the derivative dx/dq of the parametric map".into()
    } else if ws.bias.iter().any(|c| !c.is_finite()) {
        "the parametric map's acceleration term h".into()
    } else if let Some(k) = force.iter().position(|c| !c.is_finite()) {
        format!(
            "the applied force on {} ({})",
            system.coordinate_name(k),
            force[k]
        )
    } else {
        "the mass matrix or the generalized force (overflow)".into()
    };
    StepError::NonFinite { t, quantity }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::Rng;
    use crate::expr::Expr;
    use crate::model::{Endpoint, SystemBuilder};
    use crate::scene::Scene;

    /// The dense formula before J was sparse, as an oracle: J by one derivative per (k, j)
    /// (structural zeros included), xdot and h as the fold of per-slot derivatives over the
    /// slots each expression contains, all evaluated by `Expr::eval`, and M, rhs by loops over
    /// all n x n_q x n_q entries.
    struct Dense {
        jacobian: Vec<f64>,
        matrix: Vec<f64>,
        rhs: Vec<f64>,
        /// max_j sum_k |J_kj (F_k - m_k h_k)|: the size of rhs's terms
        rhs_scale: f64,
    }

    fn dense_oracle(system: &System, t: f64, q: &[f64], qdot: &[f64]) -> Dense {
        let map = system.parametric().unwrap();
        let n_q = map.n_q();
        let n = system.n_coords();
        let time = 2 * n_q;
        let total_derivative = |f: &Expr| {
            f.vars()
                .into_iter()
                .filter(|&j| j < n_q)
                .fold(f.derivative(time), |acc, j| {
                    acc + f.derivative(j) * Expr::var(n_q + j)
                })
        };
        let vars: Vec<f64> = [q, qdot, &[t]].concat();
        let positions = &map.positions;
        let velocities: Vec<Expr> = positions.iter().map(total_derivative).collect();
        let biases: Vec<Expr> = velocities.iter().map(total_derivative).collect();
        let x: Vec<f64> = positions.iter().map(|e| e.eval(&vars)).collect();
        let v: Vec<f64> = velocities.iter().map(|e| e.eval(&vars)).collect();
        let h: Vec<f64> = biases.iter().map(|e| e.eval(&vars)).collect();
        let jacobian: Vec<f64> = positions
            .iter()
            .flat_map(|x| (0..n_q).map(move |j| x.derivative(j)))
            .map(|e| e.eval(&vars))
            .collect();
        let mut force = vec![0.0; n];
        system.accumulate_forces(&x, &v, &mut force);
        let mass: Vec<f64> = system
            .particles()
            .iter()
            .flat_map(|p| std::iter::repeat_n(p.mass, system.dim()))
            .collect();
        let (mut matrix, mut rhs) = (vec![0.0; n_q * n_q], vec![0.0; n_q]);
        let mut rhs_scale: f64 = 0.0;
        for j in 0..n_q {
            let mut scale = 0.0;
            for (k, m) in mass.iter().enumerate() {
                let term = jacobian[k * n_q + j] * (force[k] - m * h[k]);
                rhs[j] += term;
                scale += term.abs();
            }
            rhs_scale = rhs_scale.max(scale);
            for l in 0..=j {
                let mut sum = 0.0;
                for (k, m) in mass.iter().enumerate() {
                    sum += m * jacobian[k * n_q + j] * jacobian[k * n_q + l];
                }
                matrix[j * n_q + l] = sum;
                matrix[l * n_q + j] = sum;
            }
        }
        Dense {
            jacobian,
            matrix,
            rhs,
            rhs_scale,
        }
    }

    /// A chain of `links` unit masses on rods of length 1 in angle coordinates, +y down,
    /// positions written as a scene file writes them (one sum per particle).
    fn chain(links: usize) -> Arc<System> {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        let names: Vec<String> = (1..=links).map(|i| format!("th{i}")).collect();
        let mut previous = None;
        for i in 1..=links {
            let p = b
                .particle(&format!("p{i}"), 1.0, &[i as f64, 0.0], &[0.0, 0.0])
                .unwrap();
            let end = previous.map_or(Endpoint::Fixed(vec![0.0, 0.0]), Endpoint::Particle);
            b.distance(&format!("rod{i}"), p, end, 1.0).unwrap();
            previous = Some(p);
        }
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let half_pi = std::f64::consts::FRAC_PI_2;
        b.parametric(&refs, &vec![half_pi; links], &vec![0.0; links])
            .unwrap();
        for i in 1..=links {
            let sum = |f: &str| {
                names[..i]
                    .iter()
                    .map(|th| format!("{f}({th})"))
                    .collect::<Vec<_>>()
                    .join(" + ")
            };
            b.parametric_position_exprs(&format!("p{i}"), &[&sum("sin"), &sum("cos")])
                .unwrap();
        }
        Arc::new(b.build().unwrap())
    }

    fn scene(name: &str) -> Arc<System> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenes")
            .join(name);
        Scene::load(&path, &[])
            .unwrap_or_else(|e| panic!("{e}"))
            .system
    }

    fn max_abs(v: &[f64]) -> f64 {
        v.iter().fold(0.0, |m: f64, x| m.max(x.abs()))
    }

    /// At random states: the sparse M and rhs against the dense oracle, entry by entry, and
    /// qddot against a solve of the oracle's M (backward error, so the conditioning of M
    /// does not enter).
    fn agrees_with_the_dense_formula(name: &str, system: Arc<System>, seed: u64) {
        let mut rng = Rng::new(seed);
        let mut p = Parametric::new(system.clone()).unwrap();
        let n_q = p.n_coords();
        for _ in 0..20 {
            let t = rng.uniform(0.0, 3.0);
            let q: Vec<f64> = (0..n_q).map(|_| rng.uniform(-3.0, 3.0)).collect();
            let qdot: Vec<f64> = (0..n_q).map(|_| rng.uniform(-4.0, 4.0)).collect();
            let dense = dense_oracle(&system, t, &q, &qdot);
            p.assemble_at(t, &q, &qdot);
            let m_scale = max_abs(&dense.matrix);
            for j in 0..n_q {
                for l in 0..=j {
                    let (new, old) = (p.matrix[j * (j + 1) / 2 + l], dense.matrix[j * n_q + l]);
                    assert!(
                        (new - old).abs() <= 1e-13 * m_scale,
                        "{name}: M[{j}][{l}] = {new} vs dense {old}"
                    );
                }
            }
            for (j, (new, old)) in p.rhs.iter().zip(&dense.rhs).enumerate() {
                assert!(
                    (new - old).abs() <= 1e-13 * dense.rhs_scale,
                    "{name}: rhs[{j}] = {new} vs dense {old}"
                );
            }
            let mut qddot = vec![0.0; n_q];
            p.acceleration(t, &q, &qdot, &mut qddot).unwrap();
            for j in 0..n_q {
                let row = &dense.matrix[j * n_q..(j + 1) * n_q];
                let product: f64 = row.iter().zip(&qddot).map(|(m, a)| m * a).sum();
                let size: f64 = row.iter().zip(&qddot).map(|(m, a)| (m * a).abs()).sum();
                let residual = (product - dense.rhs[j]).abs();
                assert!(
                    residual <= 1e-13 * (size + dense.rhs_scale),
                    "{name}: row {j} of M qddot = rhs off by {residual:e}"
                );
            }
            // The monitors' rows are J's columns over their nonzeros: every other entry of
            // the dense column is 0, so lengths and products are the dense ones.
            let mut observation = p.new_observation();
            p.observe(t, &q, &qdot, &mut observation);
            let n = system.n_coords();
            for j in 0..n_q {
                let column: Vec<f64> = (0..n).map(|k| dense.jacobian[k * n_q + j]).collect();
                let entries = p.parametric_map().column_entries(j);
                let rows: Vec<usize> = entries
                    .iter()
                    .map(|&e| {
                        (0..n)
                            .find(|&k| p.parametric_map().row_entries(k).contains(&e))
                            .unwrap()
                    })
                    .collect();
                let row = observation.gradients.row(j);
                assert_eq!(row.len(), rows.len());
                for (value, &k) in row.iter().zip(&rows) {
                    assert!(
                        (value - column[k]).abs() <= 1e-14 * max_abs(&column),
                        "{name}"
                    );
                }
                for (k, c) in column.iter().enumerate() {
                    if !rows.contains(&k) {
                        assert_eq!(*c, 0.0, "{name}: dx_{k}/dq_{j} is a structural zero");
                    }
                }
            }
        }
    }

    #[test]
    fn sparse_assembly_agrees_with_the_dense_formula() {
        agrees_with_the_dense_formula("chain of 5", chain(5), 1);
        agrees_with_the_dense_formula("chain of 20", chain(20), 2);
        for (seed, name) in [
            "double-pendulum.toml",
            "helix.toml",
            "cycloid.toml",
            "spinning-hoop.toml",
        ]
        .into_iter()
        .enumerate()
        {
            agrees_with_the_dense_formula(name, scene(name), 3 + seed as u64);
        }
    }

    #[test]
    fn the_chain_keeps_only_its_structural_nonzeros() {
        let links = 20;
        let system = chain(links);
        let map = system.parametric().unwrap();
        // x_i and y_i depend on th_1..th_i: rows of i entries, columns of 2 (links - j + 1).
        assert_eq!(map.jacobian_nonzeros(), links * (links + 1));
        for i in 1..=links {
            for axis in 0..2 {
                let k = 2 * (i - 1) + axis;
                let row = map.symbolic(k);
                assert_eq!(row.columns, (0..i).collect::<Vec<_>>().as_slice());
            }
        }
        for j in 0..links {
            assert_eq!(map.column_entries(j).len(), 2 * (links - j));
        }
        // One run of consecutive columns per row.
        let p = Parametric::new(system.clone()).unwrap();
        assert!((0..2 * links).all(|k| p.runs.of_row(k).len() == 1));
    }

    /// An entry whose derivative simplifies to the constant 0 is a structural zero too, and a
    /// row with gaps between its columns makes several runs.
    #[test]
    fn zero_derivatives_are_dropped_and_gaps_split_runs() {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        b.particle("a", 1.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        b.particle("b", 2.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        b.parametric(&["u", "v", "w"], &[0.3, -0.2, 0.5], &[0.1, 0.7, -0.4])
            .unwrap();
        // d(a.x)/dv = 1 - 1 = 0 after simplification; b.x skips v.
        b.parametric_position_exprs("a", &["u + v - v", "u*v"])
            .unwrap();
        b.parametric_position_exprs("b", &["sin(u) + w^2", "v + cos(w)"])
            .unwrap();
        let system = Arc::new(b.build().unwrap());
        let map = system.parametric().unwrap();
        assert_eq!(map.symbolic(0).columns, [0]);
        assert_eq!(map.symbolic(1).columns, [0, 1]);
        assert_eq!(map.symbolic(2).columns, [0, 2]);
        assert_eq!(map.symbolic(3).columns, [1, 2]);
        let p = Parametric::new(system.clone()).unwrap();
        assert_eq!(p.runs.of_row(2).len(), 2);
        agrees_with_the_dense_formula("gaps", system, 9);
    }

    /// A coordinate the map never reads has an empty column: M's row is zero and the
    /// pivot test names the coordinate; the monitors' row for it is empty and a simulation
    /// refuses to start.
    #[test]
    fn a_coordinate_without_entries_is_named() {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        b.particle("bead", 1.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        b.parametric(&["u", "v"], &[0.1, 0.2], &[0.0, 0.0]).unwrap();
        b.parametric_position_exprs("bead", &["u", "u^2"]).unwrap();
        let system = Arc::new(b.build().unwrap());
        let map = system.parametric().unwrap();
        assert!(map.column_entries(1).is_empty());
        let mut p = Parametric::new(system.clone()).unwrap();
        let mut qddot = [0.0; 2];
        let error = p.acceleration(0.5, &[0.1, 0.2], &[0.3, 0.0], &mut qddot);
        assert_eq!(
            error,
            Err(StepError::SingularMassMatrix {
                t: 0.5,
                coordinate: "v".into()
            })
        );
        assert_eq!(p.new_observation().gradients.row(1), &[] as &[f64]);
        let config = crate::simulate::SimulationConfig {
            method: Method::Parametric,
            ..Default::default()
        };
        let error = crate::simulate::Simulation::new(system, config)
            .err()
            .unwrap();
        assert!(error.to_string().contains("`v`"), "{error}");
    }

    /// The double pendulum by hand (+y down, unit rods): M = [[m1 + m2, m2 c], [m2 c, m2]]
    /// with c = cos(u - w), rhs_u = -(m1 + m2) g sin u + m2 w'^2 sin(w - u),
    /// rhs_w = -m2 g sin w + m2 u'^2 sin(u - w).
    #[test]
    fn double_pendulum_matches_the_hand_derivation() {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        let (m1, m2, g) = (1.5, 0.7, 9.81);
        b.particle("a", m1, &[0.0, 1.0], &[0.0, 0.0]).unwrap();
        b.particle("b", m2, &[0.0, 2.0], &[0.0, 0.0]).unwrap();
        b.parametric(&["u", "w"], &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        b.parametric_position_exprs("a", &["sin(u)", "cos(u)"])
            .unwrap();
        b.parametric_position_exprs("b", &["sin(u) + sin(w)", "cos(u) + cos(w)"])
            .unwrap();
        let mut p = Parametric::new(Arc::new(b.build().unwrap())).unwrap();
        let mut rng = Rng::new(11);
        for _ in 0..50 {
            let (u, w) = (rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0));
            let (ud, wd) = (rng.uniform(-4.0, 4.0), rng.uniform(-4.0, 4.0));
            p.assemble_at(0.0, &[u, w], &[ud, wd]);
            let c = (u - w).cos();
            // Packed lower triangle: M_00, M_10, M_11.
            let matrix = [m1 + m2, m2 * c, m2];
            let rhs = [
                -(m1 + m2) * g * u.sin() + m2 * wd * wd * (w - u).sin(),
                -m2 * g * w.sin() + m2 * ud * ud * (u - w).sin(),
            ];
            let rhs_scale = (m1 + m2) * g + m2 * (ud * ud + wd * wd);
            for (got, want) in p.matrix.iter().zip(matrix) {
                assert!((got - want).abs() <= 1e-14 * (m1 + m2), "{got} vs {want}");
            }
            for (got, want) in p.rhs.iter().zip(rhs) {
                assert!((got - want).abs() <= 1e-13 * rhs_scale, "{got} vs {want}");
            }
        }
    }

    /// Deriving J, xdot and h of a long chain written out in full costs about the number of
    /// nonzeros of J (it took 21 s for 300 links when every (k, j) was differentiated on its
    /// own): 200 links, far within the bound even in a debug build on a busy machine.
    #[test]
    fn a_long_chain_loads_in_about_quadratic_time() {
        let start = std::time::Instant::now();
        let system = chain(200);
        let elapsed = start.elapsed().as_secs_f64();
        assert_eq!(system.parametric().unwrap().jacobian_nonzeros(), 200 * 201);
        assert!(elapsed < 20.0, "{elapsed} s");
    }
}
