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

use super::{Formulation, Method, SecondOrderSystem, State, StepError};
use crate::linalg::{DenseCholesky, SpdSolver};
use crate::model::{ParametricEval, ParametricMap, System};

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
    /// Whether qddot depends on qdot, decided once from the model (see `velocity_dependent`).
    velocity_dependent: bool,
}

impl Parametric {
    /// The parametric form of `system`; an error when the system has none.
    pub fn new(system: Arc<System>) -> Result<Self, String> {
        let map = system
            .parametric()
            .ok_or("the scene defines no parametric form ([parametric])")?;
        let n_q = map.n_q();
        // qddot depends on qdot through drag, or through h = x_qq(qdot, qdot) + 2 x_qt qdot
        // + x_tt when the compiled h reads a rate slot (n_q..2 n_q): a map nonlinear in q (so
        // also any non-constant M(q)) or one whose J moves with t. Symbolic dependence is a
        // superset of the true one, so this errs on the safe side.
        let velocity_dependent = system.forces().iter().any(|f| f.depends_on_velocity())
            || (0..system.n_coords())
                .any(|k| (n_q..2 * n_q).any(|slot| map.symbolic(k).2.depends_on(slot)));
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
        system.accumulate_forces(&ws.position, &ws.velocity, &mut self.force);
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
        self.velocity_dependent
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
}
