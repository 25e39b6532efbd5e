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
//! evaluation: the compiled constraint tape, then J W J^T assembled from J's sparse rows into
//! a pattern fixed at construction ([`ConstraintMatrix`]: one product per pair of entries of
//! two rows that share a coordinate) and factored: densely (O(m^3)) for at most
//! [`crate::linalg::DENSE_MAX_ROWS`] rows, by faer's sparse LDL^T above (O(m) for a chain or
//! a tree, O(nnz(L)) memory). Nothing of size m x n or, on the sparse path, m x m exists.

use std::sync::Arc;

use super::fused::{compiled_rk4_step, FusedImplicit, ImplicitBuffers};
use super::{
    Formulation, Gradients, Method, Nonconservation, Observation, SecondOrderSystem,
    SingularSearch, State, StepError, Subject,
};
use crate::linalg::{ConstraintMatrix, LazyConstraintMatrix, LinearSolver};
use crate::model::{ConstraintEval, Force, System};

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

    /// Whether both gains are zero: the feedback is then no term at all, not `- 0 C -
    /// 0 Cdot` (which would turn a -0 right-hand side into +0, an infinite C into NaN).
    pub fn is_off(&self) -> bool {
        self.ks == 0.0 && self.kd == 0.0
    }

    /// `rhs - ks C - kd Cdot`, or `rhs` itself when the feedback is off: no term, rather
    /// than a zero one (`rhs - 0 C` would turn a -0 into +0, and an infinite C into NaN).
    /// Every path (general, fused, lanes) computes it so.
    #[inline]
    pub(crate) fn subtract(&self, rhs: f64, c: f64, cdot: f64) -> f64 {
        if self.is_off() {
            rhs
        } else {
            rhs - self.ks * c - self.kd * cdot
        }
    }
}

/// The implicit (constraint-force) formulation; q = particle coordinates.
pub struct Implicit {
    pub(crate) system: Arc<System>,
    /// Evaluations of the acceleration (full or applied forces only) so far
    pub(super) evaluations: u64,
    feedback: Feedback,
    /// Which factorization solves J W J^T
    pub(crate) solver: LinearSolver,
    /// F (n)
    pub(super) force: Vec<f64>,
    /// The full evaluation's C, Cdot, bias and J: sized on the first acceleration (an
    /// integrator that never asks for one, RATTLE, keeps none: 56 bytes a rod in 2D)
    pub(super) constraints: ConstraintEval,
    constraints_sized: bool,
    /// J W J^T and its factorization (shared by the acceleration and the projections),
    /// built when first needed
    pub(crate) matrix: LazyConstraintMatrix,
    /// rhs, then lambda (m)
    pub(super) lambda: Vec<f64>,
    /// Scratch space of the [`super::ConstrainedSystem`] methods (projections).
    pub(crate) projection: super::constrained::ProjectionWorkspace,
    /// Forces applied from outside the system (see [`Formulation::external_forces_mut`]).
    pub(crate) external: Vec<Force>,
    /// Per-row tolerance scales (see [`Formulation::set_constraint_scales`]); `None`:
    /// tolerances are absolute.
    pub(crate) scales: Option<super::ConstraintScales>,
    /// The whole acceleration in one tape, for small systems (see `formulation/fused.rs`).
    pub(crate) fused: Option<FusedImplicit>,
    /// Whether the last evaluation was the fused tape's, whose C, J, lambda and F are still
    /// in its outputs (see [`Implicit::unpack`]) rather than in `constraints`, `lambda` and
    /// `force`
    fused_pending: bool,
}

impl Implicit {
    /// The implicit form of `system` with optional feedback; J W J^T is solved densely or
    /// sparsely by its size ([`LinearSolver::Auto`]).
    pub fn new(system: Arc<System>, feedback: Feedback) -> Self {
        Self::with_solver(system, feedback, LinearSolver::Auto)
    }

    /// As [`Implicit::new`] with the factorization of J W J^T chosen. The pattern of J W J^T
    /// and the solver's symbolic analysis are computed here, once.
    pub fn with_solver(system: Arc<System>, feedback: Feedback, solver: LinearSolver) -> Self {
        let n = system.n_coords();
        let m = system.constraints().n_rows();
        let matrix = LazyConstraintMatrix::new(solver);
        let dense_pivot_tolerance = matrix.dense_pivot_tolerance(system.constraints().structure());
        let fused = FusedImplicit::new(&system, dense_pivot_tolerance, feedback);
        let projection = super::constrained::ProjectionWorkspace::new(&system, solver);
        Implicit {
            evaluations: 0,
            fused,
            fused_pending: false,
            feedback,
            solver,
            force: vec![0.0; n],
            constraints: ConstraintEval::default(),
            constraints_sized: false,
            matrix,
            lambda: vec![0.0; m],
            projection,
            external: Vec::new(),
            scales: None,
            system,
        }
    }

    /// The multipliers lambda (m) of the last evaluation; the constraint force is J^T lambda.
    pub fn multipliers(&self) -> &[f64] {
        match &self.fused {
            Some(fused) if self.fused_pending => fused.multipliers(),
            _ => &self.lambda,
        }
    }

    /// J's entries of the last evaluation.
    pub(super) fn jacobian(&self) -> &[f64] {
        match &self.fused {
            Some(fused) if self.fused_pending => fused.jacobian(),
            _ => &self.constraints.jacobian,
        }
    }

    /// The last evaluation's C, Cdot, bias, J, lambda and F + J^T lambda into `constraints`,
    /// `lambda` and `force`, where the fused tape left them in its outputs.
    pub(super) fn unpack(&mut self) {
        if self.fused_pending {
            self.size_constraints();
        }
        if let Some(fused) = self.fused.as_ref().filter(|_| self.fused_pending) {
            fused.unpack(ImplicitBuffers {
                constraints: &mut self.constraints,
                lambda: &mut self.lambda,
                force: &mut self.force,
            });
            self.fused_pending = false;
        }
    }

    /// The factorization of J W J^T asked for (see [`Implicit::with_solver`]).
    pub fn linear_solver(&self) -> LinearSolver {
        self.solver
    }

    /// The observation of (q, qdot) from C and J at (t, q) already in the projection's
    /// evaluation: what [`Formulation::observe`] does after evaluating them.
    pub(crate) fn observe_evaluated(&mut self, q: &[f64], qdot: &[f64], out: &mut Observation) {
        observe_from(
            self.system.constraints(),
            &self.projection.eval,
            q,
            qdot,
            out,
        );
    }

    /// The constraint stabilization it applies.
    pub(crate) fn feedback(&self) -> Feedback {
        self.feedback
    }

    /// The constraint evaluation [`Implicit::accelerate_evaluated`] reads.
    pub(crate) fn evaluation_mut(&mut self) -> &mut ConstraintEval {
        self.unpack();
        self.size_constraints();
        &mut self.constraints
    }

    /// `constraints` sized for the system's rows (once: allocates the first time only).
    fn size_constraints(&mut self) {
        if !self.constraints_sized {
            self.constraints = self.system.constraints().workspace();
            self.constraints_sized = true;
        }
    }

    /// The acceleration at (t, x, v) from the constraint evaluation already in
    /// [`Implicit::evaluation_mut`] (C, Cdot, bias, J at (t, x, v)): what
    /// [`SecondOrderSystem::acceleration`] does after evaluating the constraints, so that an
    /// ensemble that evaluates them for many members at once ([`crate::expr::Tape::eval_lanes`])
    /// finishes each member with this same code.
    pub(crate) fn accelerate_evaluated(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        self.fused_pending = false;
        let system = &*self.system;
        let set = system.constraints();
        let w = &system.inverse_mass;
        accumulate_all_forces(system, &self.external, x, v, &mut self.force);
        let m = set.n_rows();
        if m > 0 {
            let ce = &self.constraints;
            // rhs = -bias - J W F [- ks C - kd Cdot].
            for i in 0..m {
                let columns = set.row_columns(i);
                let row = &ce.jacobian[set.row_entries(i)];
                let jwf: f64 = columns
                    .iter()
                    .zip(row)
                    .map(|(&k, &jik)| jik * w[k] * self.force[k])
                    .sum();
                self.lambda[i] =
                    self.feedback
                        .subtract(-ce.bias[i] - jwf, ce.value[i], ce.velocity[i]);
            }
            // (J W J^T) lambda = rhs: along the rods when they are in paths or trees (no
            // matrix), else by the assembled matrix's factorization.
            let solved = match &mut self.projection.rods {
                Some(rods) => rods.solve_normal(x, w, &mut self.lambda),
                None => {
                    let matrix = self.matrix.get_mut(set.structure());
                    matrix.assemble(&ce.jacobian, w);
                    matrix
                        .factor()
                        .map(|()| matrix.solve_in_place(&mut self.lambda))
                }
            };
            if let Err(singular) = solved {
                // Overflow or a non-finite input is not a singular constraint: say which.
                if let Some(error) = non_finite_input(system, t, x, v, &self.force, ce) {
                    return Err(error);
                }
                return Err(super::constrained::singular_error(set, t, singular));
            }
            // F += J^T lambda.
            set.structure()
                .add_transpose(&ce.jacobian, &self.lambda, &mut self.force);
        }
        for ((a, f), w) in a.iter_mut().zip(&self.force).zip(w.iter()) {
            *a = w * f;
        }
        Ok(())
    }

    /// Whether J W J^T is solved along the rods (every row a rod, the rods in paths or
    /// trees with the solver [`LinearSolver::Auto`], in paths with
    /// [`LinearSolver::Tridiagonal`]): the acceleration's multipliers and both projections,
    /// with no matrix assembled ([`crate::linalg::RodPath`]).
    pub fn fused_rods(&self) -> bool {
        self.projection.rods.is_some()
    }

    /// J W J^T's pattern and factorization, e.g. for diagnostics
    /// ([`ConstraintMatrix::describe`]).
    pub fn constraint_matrix(&self) -> &ConstraintMatrix {
        self.matrix.get(self.system.constraints().structure())
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
        self.evaluations += 1;
        if let Some(fused) = &mut self.fused {
            let force_given = !(fused.has_constant_force() && self.external.is_empty());
            if force_given {
                accumulate_all_forces(&self.system, &self.external, x, v, &mut self.force);
            }
            let force = force_given.then_some(self.force.as_slice());
            if fused.accelerate(t, x, v, a, force) {
                self.fused_pending = true;
                return Ok(());
            }
        }
        self.size_constraints();
        let set = self.system.constraints();
        if set.n_rows() > 0 {
            set.evaluate(t, x, v, &mut self.constraints);
        }
        self.accelerate_evaluated(t, x, v, a)
    }

    /// True with any constraint row (the bias v^T H v + 2 C_xt v and the feedback kd Cdot
    /// depend on v; a linear constraint's bias vanishes, but Rust-typed rows cannot be
    /// inspected, so every row counts) or a velocity-dependent force (drag).
    fn velocity_dependent(&self) -> bool {
        self.system.constraints().n_rows() > 0
            || self.system.has_velocity_dependent_forces()
            || self.external.iter().any(|f| f.depends_on_velocity())
    }

    fn as_constrained(&mut self) -> Option<&mut dyn super::ConstrainedSystem> {
        Some(self)
    }

    /// The fused acceleration's RK4 step (see `formulation/fused.rs`), under constant forces and
    /// no external force.
    fn compiled_rk4_step(&mut self, state: &mut State, dt: f64) -> bool {
        if !self.compiles_rk4_step() {
            return false;
        }
        let set = self.system.constraints();
        let fused = self.fused.as_mut().expect("checked above");
        // With C and J at the step's end, which the monitors read there (`observe`).
        let stepped = compiled_rk4_step(fused, set.fused(), Some(set.gradient_tape()), state, dt);
        self.evaluations += if stepped { 4 } else { 0 };
        stepped
    }

    fn discount_compiled_steps(&mut self, steps: u64) {
        self.evaluations -= 4 * steps;
    }

    fn compiled_step_observation(&self, t: f64, q: &[f64], qdot: &[f64]) -> Option<&[f64]> {
        self.fused.as_ref()?.observation_at(t, q, qdot)
    }

    fn compiled_step_observation_after(&self, t: f64) -> Option<&[f64]> {
        self.fused.as_ref()?.observation_after_step(t)
    }

    fn compiles_rk4_step(&self) -> bool {
        self.external.is_empty()
            && self
                .fused
                .as_ref()
                .is_some_and(FusedImplicit::has_constant_force)
    }
}

impl Formulation for Implicit {
    fn evaluations(&self) -> u64 {
        self.evaluations
    }

    fn release_evaluation_scratch(&mut self) {
        // What the fused tape left in its outputs stays there (`unpack` sizes this again).
        if self.constraints_sized {
            self.constraints = ConstraintEval::default();
            self.constraints_sized = false;
        }
    }

    fn method(&self) -> Method {
        Method::Implicit
    }
    fn system(&self) -> &System {
        &self.system
    }
    fn shared_system(&self) -> Arc<System> {
        Arc::clone(&self.system)
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

    fn set_constraint_scales(&mut self, scales: Option<super::ConstraintScales>) {
        self.scales = scales;
    }

    fn external_forces_mut(&mut self) -> &mut Vec<Force> {
        &mut self.external
    }

    fn external_forces(&self) -> &[Force] {
        &self.external
    }

    /// P = lambda . (J v) + F_nc . v: the constraint force J^T lambda (feedback included) and
    /// the forces without a potential, at the last evaluation.
    fn power(&self, x: &[f64], v: &[f64], _a: &[f64]) -> f64 {
        let set = self.system.constraints();
        let (jacobian, lambda) = (self.jacobian(), self.multipliers());
        // Before any evaluation there is no constraint force (and no J kept).
        if !self.fused_pending && !self.constraints_sized {
            return self.applied_power(x, v);
        }
        let constraint: f64 = (0..set.n_rows())
            .map(|i| {
                let jv: f64 = set
                    .row_columns(i)
                    .iter()
                    .zip(&jacobian[set.row_entries(i)])
                    .map(|(&k, &jik)| jik * v[k])
                    .sum();
                lambda[i] * jv
            })
            .sum();
        constraint + self.applied_power(x, v)
    }

    fn applied_power(&self, x: &[f64], v: &[f64]) -> f64 {
        let system = &*self.system;
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
        let set = self.system.constraints();
        let (jacobian, lambda) = (self.jacobian(), self.multipliers());
        multipliers.clear();
        multipliers.extend_from_slice(lambda);
        force.fill(0.0);
        for (i, &l) in lambda.iter().enumerate() {
            for (&k, &jik) in set.row_columns(i).iter().zip(&jacobian[set.row_entries(i)]) {
                force[k] += jik * l;
            }
        }
        Ok(())
    }

    fn nonconservation(&self) -> Vec<Nonconservation> {
        let set = self.system.constraints();
        let mut out: Vec<Nonconservation> = self
            .system
            .nonconservative_forces()
            .into_iter()
            .map(Nonconservation::Force)
            .collect();
        for (k, (mut rows, _)) in set.declared_rows().enumerate() {
            if rows.any(|r| set.is_time_dependent(r)) {
                out.push(Nonconservation::DrivenConstraint(set.info(k).name));
            }
        }
        if !self.external.is_empty() {
            out.push(Nonconservation::External);
        }
        out
    }

    fn new_observation(&self) -> Observation {
        let set = self.system.constraints();
        let n = self.system.n_coords();
        Observation {
            x: vec![0.0; n],
            xdot: vec![0.0; n],
            constraints: vec![0.0; set.n_rows()],
            gradients: Gradients::with_rows((0..set.n_rows()).map(|i| set.row_columns(i).len())),
        }
    }

    fn observe(&mut self, t: f64, q: &[f64], qdot: &[f64], out: &mut Observation) {
        let set = self.system.constraints();
        // At the end of a compiled step, C and J were evaluated inside it.
        if let Some((value, jacobian)) = self
            .fused
            .as_ref()
            .and_then(|f| f.step_observation(t, q, qdot))
        {
            #[cfg(debug_assertions)]
            {
                // The same bits as the gradient tape's (allocation-free).
                set.gradient(t, q, &mut self.projection.eval);
                let eval = &self.projection.eval;
                assert!(
                    crate::same_bits(value, &eval.value)
                        && crate::same_bits(jacobian, &eval.jacobian),
                    "the step's observation differs from the gradient tape's"
                );
            }
            observe_from_parts(set, value, jacobian, q, qdot, out);
            return;
        }
        // With J's entries not kept (no row watched), rods and pins give C and |J_i|^2
        // without writing J.
        let g = &mut out.gradients;
        if !g.values_kept
            && set.n_rows() > 0
            && set.native_values_and_squared_gradients(q, &mut out.constraints, &mut g.offset)
        {
            out.x.copy_from_slice(q);
            out.xdot.copy_from_slice(qdot);
            offsets_from_squared_norms(&out.constraints, &mut out.gradients.offset);
            #[cfg(debug_assertions)]
            {
                // The general path's bits (allocation-free).
                set.gradient(t, q, &mut self.projection.eval);
                let eval = &self.projection.eval;
                for (i, (&c, &offset)) in out
                    .constraints
                    .iter()
                    .zip(&out.gradients.offset)
                    .enumerate()
                {
                    let squared: f64 = eval.jacobian[set.row_entries(i)]
                        .iter()
                        .map(|g| g * g)
                        .sum();
                    let want = eval.value[i].abs() / squared.sqrt();
                    assert!(
                        c.to_bits() == eval.value[i].to_bits()
                            && offset.to_bits() == want.to_bits(),
                        "row {i}: the native observation differs: {c} {offset} against {} {want}",
                        eval.value[i]
                    );
                }
            }
            return;
        }
        if set.n_rows() > 0 {
            set.gradient(t, q, &mut self.projection.eval);
        }
        self.observe_evaluated(q, qdot, out);
    }

    /// C and J from the full evaluation of the last acceleration (the same tape outputs as
    /// the gradient tape's, checked in debug builds by the monitor).
    fn observe_accelerated(
        &mut self,
        _t: f64,
        q: &[f64],
        qdot: &[f64],
        out: &mut Observation,
    ) -> bool {
        let set = self.system.constraints();
        match &self.fused {
            // Read in place: the other outputs stay where they are.
            Some(fused) if self.fused_pending => {
                observe_from_parts(set, fused.values(), fused.jacobian(), q, qdot, out)
            }
            _ => observe_from(set, &self.constraints, q, qdot, out),
        }
        true
    }

    fn gradient_subject(&self, row: usize) -> Subject {
        let info = self.system.constraints().info_of_row(row);
        Subject::Constraint {
            name: info.name,
            description: info.description,
        }
    }

    fn gradient_position(&self, row: usize, q: &[f64]) -> Vec<(String, f64)> {
        self.system
            .constraints()
            .row_columns(row)
            .iter()
            .map(|&k| (self.system.coordinate_name(k), q[k]))
            .collect()
    }

    fn row_variables(&self, row: usize, q: &[f64]) -> Vec<f64> {
        let set = self.system.constraints();
        set.row_columns(row).iter().map(|&k| q[k]).collect()
    }

    fn locate_singular_point(&self, row: usize, t: f64, q: &[f64]) -> SingularSearch {
        self.system.constraints().locate_singular_point(row, t, q)
    }

    fn row_step_length(&self, row: usize, q: &[f64], before: &[f64]) -> f64 {
        let columns = self.system.constraints().row_columns(row);
        columns
            .iter()
            .map(|&k| (q[k] - before[k]) * (q[k] - before[k]))
            .sum::<f64>()
            .sqrt()
    }

    fn row_never_singular(&self, row: usize) -> bool {
        self.system.constraints().is_native_row(row)
    }
}

/// F = every force on the particles: the system's own (gravity included) and the external
/// ones, at positions `x` and velocities `v`.
pub(crate) fn accumulate_all_forces(
    system: &System,
    external: &[Force],
    x: &[f64],
    v: &[f64],
    force: &mut [f64],
) {
    system.accumulate_forces(x, v, force);
    for f in external {
        f.accumulate(system.dim(), x, v, force);
    }
}

/// The power F . v of the external forces (all counted as non-conservative).
pub(crate) fn external_power(system: &System, external: &[Force], x: &[f64], v: &[f64]) -> f64 {
    external.iter().map(|f| f.power(system.dim(), x, v)).sum()
}

/// The first non-finite input of an evaluation, as the error to report instead of a singular
/// matrix: a position or velocity, an applied force, a constraint value, gradient or bias.
fn non_finite_input(
    system: &System,
    t: f64,
    x: &[f64],
    v: &[f64],
    force: &[f64],
    ce: &ConstraintEval,
) -> Option<StepError> {
    let error = |quantity: String| Some(StepError::NonFinite { t, quantity });
    if let Some(k) = x.iter().position(|c| !c.is_finite()) {
        return error(format!(
            "the position {} ({})",
            system.coordinate_name(k),
            x[k]
        ));
    }
    if let Some(k) = v.iter().position(|c| !c.is_finite()) {
        return error(format!(
            "the velocity {} ({})",
            system.velocity_name(k),
            v[k]
        ));
    }
    if let Some(k) = force.iter().position(|c| !c.is_finite()) {
        return error(format!(
            "the applied force on {} ({})",
            system.coordinate_name(k),
            force[k]
        ));
    }
    let set = system.constraints();
    for i in 0..set.n_rows() {
        let name = || set.name_of_row(i);
        if !ce.value[i].is_finite() {
            return error(format!("the value of {} ({})", name(), ce.value[i]));
        }
        if ce.jacobian[set.row_entries(i)]
            .iter()
            .any(|g| !g.is_finite())
        {
            return error(format!("the gradient of {}", name()));
        }
        if !ce.bias[i].is_finite() {
            return error(format!(
                "the acceleration bias of {} ({})",
                name(),
                ce.bias[i]
            ));
        }
    }
    None
}

/// The observation of (q, qdot) from C and J at (t, q) in `ws`.
fn observe_from(
    set: &crate::model::ConstraintSet,
    ws: &ConstraintEval,
    q: &[f64],
    qdot: &[f64],
    out: &mut Observation,
) {
    observe_from_parts(set, &ws.value, &ws.jacobian, q, qdot, out);
}

/// The observation of (q, qdot) from C (`value`) and J's entries (`jacobian`) at (t, q):
/// offset_i = |C_i| / |J_i|.
fn observe_from_parts(
    set: &crate::model::ConstraintSet,
    value: &[f64],
    jacobian: &[f64],
    q: &[f64],
    qdot: &[f64],
    out: &mut Observation,
) {
    out.x.copy_from_slice(q);
    out.xdot.copy_from_slice(qdot);
    if set.n_rows() == 0 {
        return;
    }
    out.constraints.copy_from_slice(value);
    let g = &mut out.gradients;
    if g.values_kept {
        g.values.copy_from_slice(jacobian);
    }
    for (i, squared) in g.offset.iter_mut().enumerate() {
        *squared = jacobian[set.row_entries(i)]
            .iter()
            .map(|g| g * g)
            .sum::<f64>();
    }
    offsets_from_squared_norms(value, &mut g.offset);
}

/// offset_i = |C_i| / sqrt(offset_i), `offset` holding |J_i|^2 on entry: over all rows in
/// one loop, which runs in vector registers (correctly rounded there as in scalar ones: the
/// same bits).
fn offsets_from_squared_norms(value: &[f64], offset: &mut [f64]) {
    for (offset, c) in offset.iter_mut().zip(value) {
        *offset = c.abs() / offset.sqrt();
    }
}
