//! The implicit form: constraint forces from the acceleration constraint (Witkin).
//!
//! With W = M^-1 (diagonal), applied forces F and stacked constraints C(x, t) = 0:
//!
//! ```text
//! Cddot = J a + bias = -ks C - kd Cdot,   a = W (F + J^T lambda)
//! =>  (J W J^T) lambda = -bias - J W F - ks C - kd Cdot
//! ```
//!
//! J^T lambda does no work on any velocity with J v = 0 (the article's "no work" argument in
//! matrix form). ks, kd > 0 add the article's error term (Baumgarte feedback). Cost per
//! evaluation: the compiled constraint tape, O(m^2 k) to form J W J^T (k nonzeros per row) and
//! O(m^3) for the dense Cholesky solve.

use std::sync::Arc;

use super::{Formulation, Method, SecondOrderSystem, State, StepError};
use crate::linalg::{DenseCholesky, SpdSolver};
use crate::model::{ConstraintEval, ConstraintSet, System};

/// Constraint stabilization Cddot = -ks C - kd Cdot (units 1/s^2 and 1/s).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Feedback {
    pub ks: f64,
    pub kd: f64,
}

impl Feedback {
    /// From a natural frequency f (Hz) and damping ratio zeta: omega = 2 pi f, ks = omega^2,
    /// kd = 2 zeta omega. Stable with explicit integrators while omega dt stays well below 1.
    pub fn from_frequency(frequency: f64, damping_ratio: f64) -> Feedback {
        let omega = 2.0 * std::f64::consts::PI * frequency;
        Feedback {
            ks: omega * omega,
            kd: 2.0 * damping_ratio * omega,
        }
    }
}

/// The implicit (constraint-force) formulation; q = particle coordinates.
pub struct Implicit {
    pub(crate) system: Arc<System>,
    feedback: Feedback,
    pub(crate) solver: Box<dyn SpdSolver>,
    /// F (n)
    force: Vec<f64>,
    constraints: ConstraintEval,
    /// J dense, row-major (m x n); entries outside the sparse structure stay 0
    jacobian: Vec<f64>,
    /// J W J^T, row-major (m x m)
    matrix: Vec<f64>,
    /// rhs, then lambda (m)
    lambda: Vec<f64>,
    /// Scratch space of the [`super::ConstrainedSystem`] methods (projections).
    pub(crate) projection: super::constrained::ProjectionWorkspace,
}

impl Implicit {
    /// The implicit form of `system` with optional feedback, solved by dense Cholesky.
    pub fn new(system: Arc<System>, feedback: Feedback) -> Self {
        Self::with_solver(system, feedback, Box::new(DenseCholesky::default()))
    }

    /// As [`Implicit::new`] with another linear solver.
    pub fn with_solver(
        system: Arc<System>,
        feedback: Feedback,
        solver: Box<dyn SpdSolver>,
    ) -> Self {
        let n = system.n_coords();
        let m = system.constraints().n_rows();
        Implicit {
            feedback,
            solver,
            force: vec![0.0; n],
            constraints: system.constraints().workspace(),
            jacobian: vec![0.0; m * n],
            matrix: vec![0.0; m * m],
            lambda: vec![0.0; m],
            projection: super::constrained::ProjectionWorkspace::new(&system),
            system,
        }
    }

    /// The multipliers lambda (m) of the last evaluation; the constraint force is J^T lambda.
    pub fn multipliers(&self) -> &[f64] {
        &self.lambda
    }
}

impl SecondOrderSystem for Implicit {
    fn n_coords(&self) -> usize {
        self.system.n_coords()
    }

    fn acceleration(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        let system = &*self.system;
        let set = system.constraints();
        let w = &system.inverse_mass;
        system.accumulate_forces(x, v, &mut self.force);
        let m = set.n_rows();
        if m > 0 {
            set.evaluate(t, x, v, &mut self.constraints);
            let ce = &self.constraints;
            assemble_jwjt(set, &ce.jacobian, w, &mut self.jacobian, &mut self.matrix);
            // rhs = -bias - J W F - ks C - kd Cdot.
            for i in 0..m {
                let columns = set.row_columns(i);
                let row = &ce.jacobian[set.row_entries(i)];
                let jwf: f64 = columns
                    .iter()
                    .zip(row)
                    .map(|(&k, &jik)| jik * w[k] * self.force[k])
                    .sum();
                self.lambda[i] = -ce.bias[i]
                    - jwf
                    - self.feedback.ks * ce.value[i]
                    - self.feedback.kd * ce.velocity[i];
            }
            if let Err(singular) = self.solver.solve(m, &mut self.matrix, &mut self.lambda) {
                let info = set.info_of_row(singular.row);
                return Err(StepError::SingularConstraints {
                    t,
                    constraint: info.name.clone(),
                    description: info.description.clone(),
                });
            }
            // F += J^T lambda.
            for i in 0..m {
                for (&k, &jik) in set
                    .row_columns(i)
                    .iter()
                    .zip(&ce.jacobian[set.row_entries(i)])
                {
                    self.force[k] += jik * self.lambda[i];
                }
            }
        }
        for ((a, f), w) in a.iter_mut().zip(&self.force).zip(w) {
            *a = w * f;
        }
        Ok(())
    }

    /// True with any constraint row (the bias v^T H v + 2 C_xt v and the feedback kd Cdot
    /// depend on v; a linear constraint's bias vanishes, but Rust-typed rows cannot be
    /// inspected, so every row counts) or a velocity-dependent force (drag).
    fn velocity_dependent(&self) -> bool {
        self.system.constraints().n_rows() > 0
            || self.system.forces().iter().any(|f| f.depends_on_velocity())
    }

    fn as_constrained(&mut self) -> Option<&mut dyn super::ConstrainedSystem> {
        Some(self)
    }
}

impl Formulation for Implicit {
    fn method(&self) -> Method {
        Method::Implicit
    }
    fn system(&self) -> &System {
        &self.system
    }
    fn initial_state(&self) -> State {
        let (q, qdot) = self.system.initial_particle_state();
        State { t: 0.0, q, qdot }
    }
    fn coordinate_names(&self) -> &[String] {
        &[]
    }
    fn particle_state(
        &mut self,
        _t: f64,
        q: &[f64],
        qdot: &[f64],
        x: &mut [f64],
        xdot: &mut [f64],
    ) {
        x.copy_from_slice(q);
        xdot.copy_from_slice(qdot);
    }
}

/// A = J W J^T (m x m, row-major) from J's sparse rows (`entries` in the structure of
/// `set`), through a dense copy `dense_j` of J (m x n, row-major). J's structure is fixed, so
/// every structural entry is overwritten on each call and the others stay 0.
pub(crate) fn assemble_jwjt(
    set: &ConstraintSet,
    entries: &[f64],
    w: &[f64],
    dense_j: &mut [f64],
    matrix: &mut [f64],
) {
    let (m, n) = (set.n_rows(), w.len());
    for i in 0..m {
        for (&k, &value) in set.row_columns(i).iter().zip(&entries[set.row_entries(i)]) {
            dense_j[i * n + k] = value;
        }
    }
    for i in 0..m {
        let columns = set.row_columns(i);
        let row = &entries[set.row_entries(i)];
        for j in 0..=i {
            let mut sum = 0.0;
            for (&k, &jik) in columns.iter().zip(row) {
                sum += jik * w[k] * dense_j[j * n + k];
            }
            matrix[i * m + j] = sum;
            matrix[j * m + i] = sum;
        }
    }
}
