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
//! construction. Cost per evaluation: the compiled map tape, O(n n_q^2) to form M and O(n_q^3)
//! for the dense Cholesky solve.

use std::sync::Arc;

use super::implicit::{accumulate_all_forces, external_power};
use super::{
    Formulation, FormulationError, Gradients, Method, Nonconservation, Observation,
    SecondOrderSystem, SingularSearch, State, StepError, Subject,
};
use crate::linalg::{DenseCholesky, SpdSolver};
use crate::model::{ConstraintEval, Force, ParametricEval, ParametricMap, System};

/// The parametric (generalized-coordinate) formulation.
pub struct Parametric {
    system: Arc<System>,
    solver: Box<dyn SpdSolver>,
    map: ParametricEval,
    /// F (n_coords)
    force: Vec<f64>,
    /// The mass of each particle coordinate (n_coords), so the hot loops multiply
    coordinate_mass: Vec<f64>,
    /// M, row-major (n_q x n_q)
    matrix: Vec<f64>,
    /// rhs, then qddot (n_q)
    rhs: Vec<f64>,
    /// Forces applied from outside the system (see [`Formulation::external_forces_mut`]).
    external: Vec<Force>,
    /// The system's implicit constraints, evaluated at the mapped positions for the monitors.
    constraints: ConstraintEval,
    /// Whether qddot depends on qdot, decided once from the model (see `velocity_dependent`).
    velocity_dependent: bool,
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
        Ok(Parametric {
            velocity_dependent,
            solver: Box::new(DenseCholesky::default()),
            map: map.workspace(),
            force: vec![0.0; system.n_coords()],
            coordinate_mass: system
                .particles()
                .iter()
                .flat_map(|p| std::iter::repeat_n(p.mass, system.dim()))
                .collect(),
            matrix: vec![0.0; n_q * n_q],
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
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        let n_q = map.n_q();
        let ws = &mut self.map;
        map.evaluate(t, q, qdot, ws);
        accumulate_all_forces(
            system,
            &self.external,
            &ws.position,
            &ws.velocity,
            &mut self.force,
        );
        let mass_of = &self.coordinate_mass;
        // Q - sum m J^T h: with per-coordinate mass m_k, rhs_j = sum_k J_kj (F_k - m_k h_k).
        for j in 0..n_q {
            let mut rhs = 0.0;
            for (k, m) in mass_of.iter().enumerate() {
                rhs += ws.jacobian[k * n_q + j] * (self.force[k] - m * ws.bias[k]);
            }
            self.rhs[j] = rhs;
            for l in 0..=j {
                let mut mass = 0.0;
                for (k, m) in mass_of.iter().enumerate() {
                    mass += m * ws.jacobian[k * n_q + j] * ws.jacobian[k * n_q + l];
                }
                self.matrix[j * n_q + l] = mass;
                self.matrix[l * n_q + j] = mass;
            }
        }
        if let Err(singular) = self.solver.solve(n_q, &mut self.matrix, &mut self.rhs) {
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

    /// True with a velocity-dependent force (drag) or when h = xddot - J qddot depends on
    /// qdot (the map is nonlinear in q or its J depends on t); decided at construction.
    fn velocity_dependent(&self) -> bool {
        self.velocity_dependent || self.external.iter().any(|f| f.depends_on_velocity())
    }
}

impl Formulation for Parametric {
    fn method(&self) -> Method {
        Method::Parametric
    }
    fn system(&self) -> &System {
        &self.system
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
        let ws = &self.map;
        let n_q = qddot.len();
        let reaction: f64 = (0..ws.position.len())
            .map(|k| {
                let jq: f64 = (0..n_q).map(|j| ws.jacobian[k * n_q + j] * qddot[j]).sum();
                let a = jq + ws.bias[k];
                ws.velocity[k] * (self.coordinate_mass[k] * a - self.force[k])
            })
            .sum();
        reaction + self.applied_power(&ws.position, &ws.velocity)
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
        let n_q = self.parametric_map().n_q();
        Observation {
            x: vec![0.0; n],
            xdot: vec![0.0; n],
            constraints: vec![0.0; self.system.constraints().n_rows()],
            gradients: Gradients::with_rows((0..n_q).map(|_| n)),
        }
    }

    /// Gradient row j: the column dx/dq_j of the map.
    fn observe(&mut self, t: f64, q: &[f64], qdot: &[f64], out: &mut Observation) {
        let system = &*self.system;
        let map = system.parametric().expect("checked in Parametric::new");
        let n_q = map.n_q();
        map.observe(t, q, qdot, &mut self.map);
        let ws = &self.map;
        out.x.copy_from_slice(&ws.position);
        out.xdot.copy_from_slice(&ws.velocity);
        let n = ws.position.len();
        for j in 0..n_q {
            for k in 0..n {
                out.gradients.values[j * n + k] = ws.jacobian[k * n_q + j];
            }
        }
        let set = system.constraints();
        if set.n_rows() > 0 {
            let values = set.residuals(t, &out.x, &mut self.constraints);
            out.constraints.copy_from_slice(values);
        }
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
        let (point, reduction) = self.parametric_map().locate_singular_point(row, t, q);
        SingularSearch {
            point,
            reduction,
            value: 0.0,
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
