//! The energy ledger's quadrature: the work W done on T + V, integrated by the integrator
//! itself as one extra coordinate, so that it converges at the integrator's own order.
//!
//! [`WithWork`] presents a formulation with n coordinates as a system with n + 1: the extra
//! coordinate's "velocity" is W and its "acceleration" is the power P = dW/dt
//! ([`Formulation::power`]); its "position" (the time integral of W) is never read. Every
//! integrator advances W with the same stages and weights as the velocities (RK4 by Simpson's
//! weights, Gauss-Legendre by Gauss quadrature, Verlet by the trapezoidal rule, dopri5 under
//! its error control), without knowing what the coordinate is. For integrators that work on
//! the constraints (RATTLE, the projection) the extra coordinate has zero inverse mass and
//! no constraint reads it (J's sparse rows never name it, so J is the formulation's own),
//! so constraint impulses never touch it; the applied forces' power drives it through
//! [`ConstrainedSystem::unconstrained_acceleration`].

use std::sync::Arc;

use crate::formulation::{ConstrainedSystem, Formulation, SecondOrderSystem, StepError};
use crate::linalg::{LinearSolver, RowStructure};

/// Scratch space of [`WithWork`], sized once.
pub(super) struct LedgerScratch {
    /// W = M^-1 with a trailing 0 for the work coordinate (n + 1)
    inverse_mass: Arc<[f64]>,
    /// The formulation's factorization of J W J^T
    solver: LinearSolver,
}

impl LedgerScratch {
    pub(super) fn new(formulation: &mut (dyn Formulation + Send)) -> Self {
        let n = formulation.n_coords();
        let (mut inverse_mass, solver) = match formulation.as_constrained() {
            Some(cs) => (cs.inverse_mass().to_vec(), cs.linear_solver()),
            None => (vec![0.0; n], LinearSolver::Auto),
        };
        inverse_mass.push(0.0);
        LedgerScratch {
            inverse_mass: inverse_mass.into(),
            solver,
        }
    }
}

/// A formulation plus the work coordinate (see the module documentation).
pub(super) struct WithWork<'a> {
    formulation: &'a mut (dyn Formulation + Send),
    scratch: &'a mut LedgerScratch,
    /// Whether the applied forces (so also their power) depend on the velocities
    applied_velocity_dependent: bool,
}

impl<'a> WithWork<'a> {
    pub(super) fn new(
        formulation: &'a mut (dyn Formulation + Send),
        scratch: &'a mut LedgerScratch,
    ) -> Self {
        // The work coordinate's "acceleration" is the applied power F_nc . v: it depends on v
        // whenever such forces exist, even when they depend on positions only (an external
        // spring), and the formulation's own answer covers drag.
        let applied_velocity_dependent = !formulation.external_forces().is_empty()
            || formulation
                .as_constrained()
                .is_none_or(|c| c.applied_forces_velocity_dependent());
        WithWork {
            formulation,
            scratch,
            applied_velocity_dependent,
        }
    }
}

impl WithWork<'_> {
    fn n(&self) -> usize {
        self.scratch.inverse_mass.len() - 1
    }

    fn constrained(&mut self) -> &mut dyn ConstrainedSystem {
        self.formulation
            .as_constrained()
            .expect("WithWork is offered as constrained only when the formulation is")
    }
}

impl SecondOrderSystem for WithWork<'_> {
    fn n_coords(&self) -> usize {
        self.n() + 1
    }

    /// qddot of the formulation, and P for the work coordinate.
    fn acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        let n = self.n();
        self.formulation
            .acceleration(t, &q[..n], &qdot[..n], &mut a[..n])?;
        a[n] = self.formulation.power(&q[..n], &qdot[..n], &a[..n]);
        Ok(())
    }

    fn as_constrained(&mut self) -> Option<&mut dyn ConstrainedSystem> {
        if self.formulation.as_constrained().is_some() {
            Some(self)
        } else {
            None
        }
    }
}

impl ConstrainedSystem for WithWork<'_> {
    fn n_constraints(&self) -> usize {
        self.formulation.active_system().constraints().n_rows()
    }

    /// The formulation's rows: none reads the work coordinate.
    fn constraint_structure(&self) -> RowStructure<'_> {
        self.formulation.active_system().constraints().structure()
    }

    fn linear_solver(&self) -> LinearSolver {
        self.scratch.solver
    }

    fn inverse_mass(&self) -> &[f64] {
        &self.scratch.inverse_mass
    }

    fn shared_inverse_mass(&self) -> Arc<[f64]> {
        Arc::clone(&self.scratch.inverse_mass)
    }

    /// The formulation's distance rows (their coordinates are the formulation's, which come
    /// first).
    fn distance_row(&self, row: usize) -> Option<crate::model::DistanceRow> {
        self.formulation
            .active_system()
            .constraints()
            .distance_row(row)
    }

    fn linear_row(&self, row: usize) -> bool {
        self.formulation
            .active_system()
            .constraints()
            .is_pin_row(row)
    }

    /// The formulation's rods (they read only its coordinates, which come first) and scales.
    fn rods_mut(
        &mut self,
    ) -> Option<(
        &mut crate::linalg::RodPath,
        Option<&crate::formulation::ConstraintScales>,
    )> {
        self.constrained().rods_mut()
    }

    fn row_fingerprint(&self) -> Option<u64> {
        Some(
            self.formulation
                .active_system()
                .constraints()
                .row_fingerprint(),
        )
    }

    fn constraints_time_dependent(&self) -> bool {
        self.formulation
            .active_system()
            .constraints()
            .any_time_dependent()
    }

    /// Whether the applied accelerations depend on v, the work coordinate's (the power
    /// F_nc . v) included: see [`WithWork::new`].
    fn applied_forces_velocity_dependent(&self) -> bool {
        self.applied_velocity_dependent
    }

    /// a = W F for the particles, and the applied forces' power for the work coordinate.
    fn unconstrained_acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        let n = self.n();
        self.constrained()
            .unconstrained_acceleration(t, &q[..n], &qdot[..n], &mut a[..n])?;
        a[n] = self.formulation.applied_power(&q[..n], &qdot[..n]);
        Ok(())
    }

    fn constraint_values(&mut self, t: f64, q: &[f64], c: &mut [f64]) {
        let n = self.n();
        self.constrained().constraint_values(t, &q[..n], c);
    }

    fn constraint_residual(&mut self, q: &[f64], c: &[f64]) -> f64 {
        let n = self.n();
        self.constrained().constraint_residual(&q[..n], c)
    }

    /// The formulation's J: its sparse rows never name the work coordinate, so widening J by
    /// that zero column changes nothing.
    fn constraint_jacobian(&mut self, t: f64, q: &[f64], jacobian: &mut [f64]) {
        let n = self.n();
        self.constrained().constraint_jacobian(t, &q[..n], jacobian);
    }

    fn constraint_values_and_jacobian(
        &mut self,
        t: f64,
        q: &[f64],
        c: &mut [f64],
        jacobian: &mut [f64],
    ) {
        let n = self.n();
        self.constrained()
            .constraint_values_and_jacobian(t, &q[..n], c, jacobian);
    }

    fn singular_constraint(&mut self, t: f64, row: usize) -> StepError {
        self.constrained().singular_constraint(t, row)
    }

    fn project_positions(
        &mut self,
        t: f64,
        q: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<usize, StepError> {
        let n = self.n();
        self.constrained()
            .project_positions(t, &mut q[..n], tolerance, max_iterations)
    }

    fn project_velocities(&mut self, t: f64, q: &[f64], qdot: &mut [f64]) -> Result<(), StepError> {
        let n = self.n();
        self.constrained()
            .project_velocities(t, &q[..n], &mut qdot[..n])
    }
}
