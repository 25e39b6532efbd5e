//! Holonomic constraints as seen by structure-preserving integrators (RATTLE) and by the
//! run loop's projection (`--project`).
//!
//! [`ConstrainedSystem`] extends [`SecondOrderSystem`] with what those need beyond qddot:
//! the applied acceleration a = W F without the constraint force, the constraint values C,
//! the Jacobian J as sparse rows (its [`RowStructure`] and values), the factorization to use
//! for J W J^T ([`LinearSolver`], so that an integrator that assembles its own matrices with
//! [`crate::linalg::ConstraintMatrix`] solves them the same way), and two mass-weighted
//! projections:
//!
//! ```text
//! positions:  repeat  q <- q - W J(q)^T (J W J^T)^-1 C(q, t)   until |C| <= tolerance
//! velocities: qdot <- qdot - W J^T (J W J^T)^-1 (J qdot + C_t)  so that J qdot + C_t = 0
//! ```
//!
//! The position projection is a Gauss-Newton iteration for the point of the constraint
//! manifold nearest to q in the mass metric (quadratic convergence near the manifold). The
//! velocity projection is exact (one linear solve): the mass-weighted orthogonal projection
//! onto the velocities the (possibly moving) constraints allow; for time-dependent
//! constraints the target is J qdot = -C_t.
//!
//! Only [`Implicit`] implements it: integrators reach it through
//! [`SecondOrderSystem::as_constrained`], which is `None` for the parametric form.
//! Everything is allocation-free after construction, and O(n + nnz) in memory on the sparse
//! path: the projections assemble and factor the formulation's own [`ConstraintMatrix`].

use std::cmp::Ordering;
use std::sync::Arc;

use super::{Implicit, SecondOrderSystem, StepError};
use crate::linalg::{max_abs, ConstraintMatrix, LinearSolver, RodPath, RowStructure, Singular};
use crate::model::{ConstraintEval, ConstraintSet, DistanceRow, System};

/// A second-order system with holonomic constraints C(q, t) = 0 (m rows) on its coordinates.
pub trait ConstrainedSystem: SecondOrderSystem {
    /// Number of constraint rows m.
    fn n_constraints(&self) -> usize;
    /// The sparse row structure of J: which coordinates each row reads, and where its values
    /// are in [`ConstrainedSystem::constraint_jacobian`]'s output.
    fn constraint_structure(&self) -> RowStructure<'_>;
    /// The factorization this system uses for J W J^T; integrators that factor matrices of
    /// their own on [`ConstrainedSystem::constraint_structure`] use the same.
    fn linear_solver(&self) -> LinearSolver {
        LinearSolver::Auto
    }
    /// The diagonal inverse mass matrix W (n).
    fn inverse_mass(&self) -> &[f64];
    /// W as a shared allocation, for integrators that keep it between calls: the same
    /// values as [`ConstrainedSystem::inverse_mass`] at the same address, so that an
    /// integrator can tell from the pointer whether its copy is still this system's. The
    /// default copies W (a system that holds its W in an `Arc<[f64]>` returns that instead:
    /// with a copy, RATTLE takes W again at every step).
    fn shared_inverse_mass(&self) -> Arc<[f64]> {
        Arc::from(self.inverse_mass())
    }
    /// Constraint row `row` as a built-in distance, whose constant Hessian a projection's
    /// Newton iteration uses ([`DistanceRow`]); `None` for every other row (the default).
    fn distance_row(&self, row: usize) -> Option<DistanceRow> {
        let _ = row;
        None
    }
    /// Whether constraint row `row` is linear in q (a built-in pin: its Hessian is zero, and
    /// its force stiffens nothing); `false` when the system does not know (the default).
    fn linear_row(&self, row: usize) -> bool {
        let _ = row;
        false
    }
    /// The rods the system solves J W J^T along ([`RodPath`]: every row a rod, the rods
    /// coupled in paths), with the scales its residual is measured with (see
    /// [`ConstrainedSystem::constraint_scales`]): an integrator may take its own exact Newton
    /// steps along them (RATTLE's position step), their geometry always the system's. `None`
    /// (the default) when it does not.
    fn rods_mut(&mut self) -> Option<(&mut RodPath, Option<&ConstraintScales>)> {
        None
    }
    /// a = W F(t, q, qdot): the applied forces only, without any constraint force.
    fn unconstrained_acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError>;
    /// Whether a = W F depends on qdot (drag). RATTLE solves its second half kick
    /// implicitly only then. The default, true, is the safe answer.
    fn applied_forces_velocity_dependent(&self) -> bool {
        true
    }
    /// Whether C depends on t (some row has C_t != 0: a moving or driven constraint). When
    /// it does not, the constraint forces do no work (their power lambda . J v = -lambda .
    /// C_t is zero), and an integrator's `constraint_work` is exactly 0 without being summed
    /// from impulses whose J v is zero only to rounding. The default, true, is the safe
    /// answer.
    fn constraints_time_dependent(&self) -> bool {
        true
    }
    /// C(q, t) into `c` (m).
    fn constraint_values(&mut self, t: f64, q: &[f64], c: &mut [f64]);
    /// The size of the constraint error `c` = C(q, t) that position tolerances are compared
    /// with: max_i |C_i| (absolute, units of C) unless the system has
    /// [`ConstraintScales`], then max_i max(0, |C_i| - rho_i max_{k in row i} |q_k|) / s_i.
    /// NaN when any C_i is NaN.
    fn constraint_residual(&mut self, q: &[f64], c: &[f64]) -> f64 {
        let _ = q;
        max_abs(c)
    }
    /// A hash of the row structure and of the geometry of the rows
    /// [`ConstrainedSystem::distance_row`] describes (see [`ConstraintSet::row_fingerprint`]):
    /// an integrator that keeps per-row data between steps rebuilds it when this changes.
    /// `None` (the default): not known, and such an integrator compares the row structure
    /// itself (O(nnz) per step).
    fn row_fingerprint(&self) -> Option<u64> {
        None
    }
    /// The per-row scales [`ConstrainedSystem::constraint_residual`] measures with, when it
    /// has them (then it is [`ConstraintScales::residual`]); `None` otherwise (the default).
    fn constraint_scales(&self) -> Option<&ConstraintScales> {
        None
    }
    /// J = dC/dq at (q, t): its nonzero entries (nnz), in the order of
    /// [`ConstrainedSystem::constraint_structure`], every one overwritten.
    fn constraint_jacobian(&mut self, t: f64, q: &[f64], jacobian: &mut [f64]);
    /// C(q, t) into `c` (m) and J's nonzero entries into `jacobian` (nnz) in one evaluation.
    fn constraint_values_and_jacobian(
        &mut self,
        t: f64,
        q: &[f64],
        c: &mut [f64],
        jacobian: &mut [f64],
    ) {
        self.constraint_values(t, q, c);
        self.constraint_jacobian(t, q, jacobian);
    }
    /// The error to report when constraint row `row` is singular (vanishing gradient or
    /// dependent on earlier rows) at time t: names the declared constraint.
    fn singular_constraint(&mut self, t: f64, row: usize) -> StepError;
    /// Move q onto C(q, t) = 0 by mass-weighted Gauss-Newton steps
    /// dq = -W J^T (J W J^T)^-1 C until [`ConstrainedSystem::constraint_residual`] <=
    /// `tolerance` (absolute in the units of C, or relative to each row's scale).
    /// Returns the number of iterations (linear solves) used; 0 when q was already within
    /// tolerance. More than `max_iterations` needed: [`StepError::ProjectionFailed`].
    fn project_positions(
        &mut self,
        t: f64,
        q: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<usize, StepError>;
    /// qdot <- qdot - W J^T (J W J^T)^-1 (J qdot + C_t): afterwards J qdot + C_t = 0 (to
    /// round-off). The smallest change of qdot in the kinetic-energy metric.
    fn project_velocities(&mut self, t: f64, q: &[f64], qdot: &mut [f64]) -> Result<(), StepError>;
}

/// Per-row scales of the position tolerance: row i is within `tolerance` when
///
/// ```text
/// |C_i| <= tolerance s_i + rho_i max_{k in row i} |q_k|
/// ```
///
/// s_i is the row's own scale in the units of C_i: a distance constraint's length L (its
/// C = (|d|^2 - L^2) / (2L) is |d| - L to first order, so |C_i| / s_i is the rod's stretch),
/// otherwise |J_i(x_0)| times the scene's length scale (the largest initial coordinate, 1 when
/// all are 0). The second term allows for rounding: C_i is computed from coordinates of size
/// |q_k| and cannot be resolved below about eps |J_i| |q_k| (a chain of 10^4 unit rods spans
/// 10^4 lengths); rho_i = 16 eps |J_i(x_0)|.
#[derive(Clone, Debug, PartialEq)]
pub struct ConstraintScales {
    /// s_i > 0 (m)
    pub scale: Vec<f64>,
    /// rho_i >= 0 (m)
    pub rounding: Vec<f64>,
}

impl ConstraintScales {
    /// The scales of `system`'s constraint rows at its initial state (see the type).
    pub fn of(system: &System) -> ConstraintScales {
        let set = system.constraints();
        let (x, v) = system.initial_particle_state();
        let length = crate::model::length_scale(&x);
        let mut ws = set.workspace();
        set.evaluate(0.0, &x, &v, &mut ws);
        let norms: Vec<f64> = (0..set.n_rows())
            .map(|i| {
                let norm = ws.jacobian[set.row_entries(i)]
                    .iter()
                    .map(|j| j * j)
                    .sum::<f64>()
                    .sqrt();
                if norm > 0.0 && norm.is_finite() {
                    norm
                } else {
                    0.0
                }
            })
            .collect();
        // A row whose gradient vanishes or overflows at x_0 borrows the largest finite one.
        let largest = norms.iter().copied().fold(0.0, f64::max);
        let fallback = if largest > 0.0 { largest } else { 1.0 };
        let mut scale = vec![0.0; set.n_rows()];
        let mut rounding = vec![0.0; set.n_rows()];
        for (rows, own_length) in set.declared_rows() {
            for i in rows {
                let norm = if norms[i] > 0.0 { norms[i] } else { fallback };
                scale[i] = match own_length {
                    Some(l) if l > 0.0 && l.is_finite() => l,
                    _ => norm * length,
                };
                rounding[i] = 16.0 * f64::EPSILON * norm;
            }
        }
        ConstraintScales { scale, rounding }
    }

    /// max_i max(0, |C_i| - rho_i max_{k in row i} |q_k|) / s_i for `set`'s rows; NaN when
    /// any C_i is NaN. The rounding allowance (a pass over the row's coordinates) is worked
    /// out only for rows whose |C_i| / s_i exceeds the largest so far: in a solve's last
    /// iterations, a few rows.
    pub fn residual(&self, set: &ConstraintSet, q: &[f64], c: &[f64]) -> f64 {
        let mut worst: f64 = 0.0;
        for (i, (&value, &scale)) in c.iter().zip(&self.scale).enumerate() {
            let size = value.abs();
            // Not `size <= worst * scale`, NaN included.
            if matches!(
                size.partial_cmp(&(worst * scale)),
                None | Some(Ordering::Greater)
            ) {
                if value.is_nan() {
                    return f64::NAN;
                }
                let coordinates = set
                    .row_columns(i)
                    .iter()
                    .fold(0.0, |s: f64, &k| s.max(q[k].abs()));
                let excess = size - self.rounding[i] * coordinates;
                if excess > 0.0 {
                    worst = worst.max(excess / scale);
                }
            }
        }
        worst
    }
}

/// Scratch space of the projections, sized once for one system: O(n + nnz).
pub(crate) struct ProjectionWorkspace {
    pub(crate) eval: ConstraintEval,
    /// rhs, then the multipliers (m)
    rhs: Vec<f64>,
    /// The projections and the implicit acceleration's multipliers fused along the rods,
    /// when every row is a rod and the rods couple in paths or trees and the solver is not
    /// forced ([`LinearSolver::Auto`]; [`LinearSolver::Tridiagonal`] takes paths only)
    pub(super) rods: Option<RodPath>,
}

impl ProjectionWorkspace {
    pub(crate) fn new(system: &System, solver: LinearSolver) -> Self {
        let set = system.constraints();
        let m = set.n_rows();
        let rods = match solver {
            LinearSolver::Auto if m > 0 => RodPath::of_rows(m, |row| set.distance_row(row)),
            // Forced tridiagonal: paths only (trees take faer, as the matrix would).
            LinearSolver::Tridiagonal if m > 0 => {
                RodPath::of_rows(m, |row| set.distance_row(row)).filter(|rods| !rods.is_tree())
            }
            _ => None,
        };
        ProjectionWorkspace {
            eval: set.workspace(),
            rhs: vec![0.0; m],
            rods,
        }
    }

    /// After `set.evaluate` and with `rhs` set: A = J W J^T, solve A z = rhs in place and
    /// subtract W J^T z from `y`.
    fn correct(
        &mut self,
        set: &ConstraintSet,
        w: &[f64],
        matrix: &mut ConstraintMatrix,
        t: f64,
        y: &mut [f64],
    ) -> Result<(), StepError> {
        matrix.assemble(&self.eval.jacobian, w);
        if let Err(singular) = matrix.factor() {
            return Err(singular_error(set, t, singular));
        }
        matrix.solve_in_place(&mut self.rhs);
        set.structure()
            .subtract_weighted_transpose(&self.eval.jacobian, w, &self.rhs, y);
        Ok(())
    }
}

/// The error of a singular J W J^T: the dependent (or vanishing) constraint by name, or
/// overflow when the failing pivot was not finite.
pub(crate) fn singular_error(set: &ConstraintSet, t: f64, singular: Singular) -> StepError {
    if !singular.finite {
        return StepError::NonFinite {
            t,
            quantity: "the matrix J W J^T (overflow)".into(),
        };
    }
    let info = set.info_of_row(singular.row);
    StepError::SingularConstraints {
        t,
        constraint: info.name,
        description: info.description,
    }
}

impl ConstrainedSystem for Implicit {
    fn n_constraints(&self) -> usize {
        self.system.constraints().n_rows()
    }

    fn constraint_structure(&self) -> RowStructure<'_> {
        self.system.constraints().structure()
    }

    fn linear_solver(&self) -> LinearSolver {
        self.solver
    }

    fn inverse_mass(&self) -> &[f64] {
        &self.system.inverse_mass
    }

    fn shared_inverse_mass(&self) -> Arc<[f64]> {
        Arc::clone(&self.system.inverse_mass)
    }

    fn distance_row(&self, row: usize) -> Option<DistanceRow> {
        self.system.constraints().distance_row(row)
    }

    fn linear_row(&self, row: usize) -> bool {
        self.system.constraints().is_pin_row(row)
    }

    fn rods_mut(&mut self) -> Option<(&mut RodPath, Option<&ConstraintScales>)> {
        let scales = self.scales.as_ref();
        self.projection.rods.as_mut().map(|rods| (rods, scales))
    }

    fn unconstrained_acceleration(
        &mut self,
        _t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        self.evaluations += 1;
        let system = &*self.system;
        // a = W F, F accumulated in place.
        super::implicit::accumulate_all_forces(system, &self.external, q, qdot, a);
        for (a, w) in a.iter_mut().zip(system.inverse_mass.iter()) {
            *a *= w;
        }
        Ok(())
    }

    fn applied_forces_velocity_dependent(&self) -> bool {
        self.system.has_velocity_dependent_forces()
            || self.external.iter().any(|f| f.depends_on_velocity())
    }

    fn constraints_time_dependent(&self) -> bool {
        self.system.constraints().any_time_dependent()
    }

    fn constraint_values(&mut self, t: f64, q: &[f64], c: &mut [f64]) {
        let values = self
            .system
            .constraints()
            .residuals(t, q, &mut self.projection.eval);
        c.copy_from_slice(values);
    }

    fn constraint_residual(&mut self, q: &[f64], c: &[f64]) -> f64 {
        match &self.scales {
            Some(scales) => scales.residual(self.system.constraints(), q, c),
            None => max_abs(c),
        }
    }

    fn constraint_scales(&self) -> Option<&ConstraintScales> {
        self.scales.as_ref()
    }

    fn row_fingerprint(&self) -> Option<u64> {
        Some(self.system.constraints().row_fingerprint())
    }

    fn constraint_jacobian(&mut self, t: f64, q: &[f64], jacobian: &mut [f64]) {
        let ws = &mut self.projection;
        self.system.constraints().gradient(t, q, &mut ws.eval);
        jacobian.copy_from_slice(&ws.eval.jacobian);
    }

    fn constraint_values_and_jacobian(
        &mut self,
        t: f64,
        q: &[f64],
        c: &mut [f64],
        jacobian: &mut [f64],
    ) {
        let ws = &mut self.projection;
        self.system.constraints().gradient(t, q, &mut ws.eval);
        c.copy_from_slice(&ws.eval.value);
        jacobian.copy_from_slice(&ws.eval.jacobian);
    }

    fn singular_constraint(&mut self, t: f64, row: usize) -> StepError {
        singular_error(self.system.constraints(), t, Singular { row, finite: true })
    }

    fn project_positions(
        &mut self,
        t: f64,
        q: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<usize, StepError> {
        let system = &*self.system;
        let set = system.constraints();
        let w = &system.inverse_mass;
        let ws = &mut self.projection;
        if set.n_rows() == 0 {
            return Ok(0);
        }
        let mut iterations = 0;
        loop {
            set.gradient(t, q, &mut ws.eval);
            let residual = match &self.scales {
                Some(scales) => scales.residual(set, q, &ws.eval.value),
                None => max_abs(&ws.eval.value),
            };
            if residual <= tolerance {
                return Ok(iterations);
            }
            if iterations >= max_iterations || residual.is_nan() {
                return Err(StepError::ProjectionFailed {
                    t,
                    iterations,
                    residual: max_abs(&ws.eval.value),
                    solve: "the projection onto the constraints",
                    substeps: 0,
                });
            }
            ws.rhs.copy_from_slice(&ws.eval.value);
            match &mut ws.rods {
                // q -= W J(q)^T z, (J W J^T)(q) z = C along the rods: no matrix.
                Some(rods) => {
                    rods.solve_normal(q, w, &mut ws.rhs)
                        .map_err(|singular| singular_error(set, t, singular))?;
                    rods.subtract_current_transpose(w, &ws.rhs, q);
                }
                None => ws.correct(set, w, self.matrix.get_mut(set.structure()), t, q)?,
            }
            iterations += 1;
        }
    }

    fn project_velocities(&mut self, t: f64, q: &[f64], qdot: &mut [f64]) -> Result<(), StepError> {
        let system = &*self.system;
        let set = system.constraints();
        let w = &system.inverse_mass;
        let ws = &mut self.projection;
        if set.n_rows() == 0 {
            return Ok(());
        }
        if let Some(rods) = &mut ws.rods {
            return rods
                .project_velocities(q, w, qdot)
                .map_err(|singular| singular_error(set, t, singular));
        }
        // Cdot = J qdot + C_t: the residual of the velocity constraint J qdot = -C_t.
        set.evaluate(t, q, qdot, &mut ws.eval);
        ws.rhs.copy_from_slice(&ws.eval.velocity);
        ws.correct(set, w, self.matrix.get_mut(set.structure()), t, qdot)
    }
}
