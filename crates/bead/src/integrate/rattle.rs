//! RATTLE (Andersen 1983; Leimkuhler & Reich, *Simulating Hamiltonian Dynamics*, ch. 7):
//! velocity Verlet with the holonomic constraints C(q, t) = 0 enforced at the position and at
//! the velocity level by Lagrange multipliers. With the applied acceleration a = W F(q, v):
//!
//! ```text
//! v_half  = v_n + h/2 (a(q_n, v_n) + W J(q_n)^T lambda)
//! q_{n+1} = q_n + h v_half,            C(q_{n+1}, t_{n+1}) = 0        (solve for lambda)
//! v_{n+1} = v_half + h/2 (a(q_{n+1}, v_{n+1}) + W J(q_{n+1})^T mu),
//!           J(q_{n+1}) v_{n+1} + C_t(q_{n+1}, t_{n+1}) = 0           (solve for mu)
//! ```
//! Order 2 for any applied forces, drag included. For forces a = a(q) it is RATTLE exactly:
//! symmetric and symplectic on the constraint manifold, so the energy error stays bounded, and
//! the constraint holds after every step to the solver tolerance, without drift and without
//! feedback. With velocity-dependent forces (drag) the last line is implicit in v_{n+1} and
//! the method dissipative, as the system is.
//!
//! **Position solve (SHAKE).** Write q(nu) = q_pred - W J(q_n)^T nu with the unconstrained
//! predictor q_pred = q_n + h v_n + h^2/2 a_n (nu = -h^2/2 lambda). The correction direction
//! stays W J(q_n)^T, as the method requires; nu solves C(q(nu), t_{n+1}) = 0 by a Newton
//! iteration whose matrix is one of ([`NewtonMatrix`]):
//!
//! - **exact**: the Jacobian of that map, the non-symmetric m x m matrix J(q^k) W J(q_n)^T,
//!   re-evaluated at each iterate q^k (a gradient evaluation and an assembly per iteration)
//!   and solved by Gaussian elimination with partial pivoting, or, when the rows couple in
//!   paths (chains: the system's solver is [`crate::linalg::PathLdlt`]), by tridiagonal
//!   elimination in the path order, O(m). Quadratic convergence.
//! - **simplified**: the symmetric J(q_n) W J(q_n)^T, assembled from J(q_n)'s sparse rows
//!   and factored once per step by the system's solver (faer's sparse LDL^T above
//!   [`DENSE_MAX_ROWS`] rows), every iteration then one evaluation of C and two triangular
//!   solves. Linear convergence at a rate of order h |v_rel| |d2C| / |J| (h times the rods'
//!   angular velocities for a chain), so it needs more iterations for fast motion and fails
//!   to converge once that rate nears 1.
//!
//! The default ([`NewtonMatrix::Auto`]) is the exact matrix fused along the rods when every
//! row is a rod and the rods couple in paths or trees (the system's own
//! [`RodPath`](crate::linalg::RodPath), [`ConstrainedSystem::rods_mut`], any size), otherwise
//! the exact matrix for systems of at most [`DENSE_MAX_ROWS`] rows and the simplified one
//! above.
//! Measured before the fused path (hanging chain of unit
//! masses and unit rods released horizontally, dt = 1/120, tolerance 1e-12 L max|J|, RATTLE
//! stepped directly, 2-core machine shared with other work; iterations per step mean / max):
//!
//! ```text
//! links   exact                       simplified
//!     1   726k steps/s  1.98 / 2      1.21M steps/s  2.66 / 3
//!     8   183k          2.09 / 3       209k          4.59 / 6
//!    32    37k          1.98 / 2        50k          4.07 / 5
//!   100   4.6k          1.97 / 2        19k          3.43 / 4
//!  1000     48 (dense)  1.76 / 2       1.7k          2.90 / 4
//! ```
//!
//! The simplified matrix is faster on chains of every size; the exact one is kept for small
//! systems because it is robust to fast motion: on the article's parabola at dt = 1/60
//! (speeds of hundreds) the simplified iteration needs up to 8 iterations where the exact
//! one needs 3, and it diverges where h |v| |d2C| / |J| reaches 1. On chains the exact
//! matrix is tridiagonal in path order and costs O(m) per iteration; measured with the
//! tridiagonal solver at 1000 links (`cargo run --release -p bead --example chain -- 1000
//! --newton simplified --newton exact`, at `Simulation`'s per-rod tolerance): simplified 10.9k
//! steps/s at 4.05 iterations per step, exact 9.9k at 2.03 (a gradient evaluation and an
//! assembly of J(q^k) W J(q_n)^T per iteration cost more than the two iterations saved), so
//! the simplified matrix stayed the default there until the fused path: the same exact
//! iteration with no Jacobian and no assembly, 2.8 iterations and about 15.3k steps/s at 1000
//! links (`cargo bench -p bead --bench chain`, `step alone`). A tridiagonal elimination that meets
//! a vanishing pivot (a rod turned by about a right angle in one step) hands the rest of the
//! step to the simplified matrix. On other sparse structures an exact Newton would need a
//! sparse LU of J(q^k) W J(q_n)^T at each iteration; on the 1000-link chain one LDL^T
//! factorization by faer cost about as much as two pairs of triangular solves plus the W J^T
//! update, so an LU (at least an LDL^T's cost, plus a gradient evaluation and an assembly per
//! iteration) at 1.76 iterations per step cannot beat 2.9 simplified iterations that reuse
//! one factorization; faer's sparse LU also grows its buffers during the numeric
//! factorization (partial pivoting changes the fill), which the step loop must not do. It is
//! not implemented. The loop stops when max_i |C_i| <= `tolerance` (absolute, units of C);
//! needing more than `max_iterations` Newton steps, or a NaN residual, or (on the fused
//! path) more than 5 iterations without halving the best residual (`EXACT_STALL`), is
//! [`StepError::ProjectionFailed`], never a silent continuation.
//!
//! **Warm start.** A step that starts at bitwise the state the last step ended at starts its
//! Newton iteration from that step's multipliers scaled to its own step, nu_0 = (h /
//! h_prev)^2 nu_prev (nu = -h^2/2 lambda, and lambda moves by O(h) per step), if that start's
//! residual is below the cold start's (q_pred, nu = 0): a start farther from the constraints
//! can lead Newton's method to another root of C(q(nu)) = 0, a motion that satisfies the
//! constraints and is not the step's. A warm start that stalls (`EXACT_STALL`) gives way to
//! the cold step; any other step starts cold ([`Rattle::with_warm_start`]), apart from the
//! driver's own changes that leave the motion alone ([`Integrator::continued`]). Measured on the
//! hanging chain at 1000 links (dt = 1/120, `cargo bench -p bead --bench chain`, `step
//! alone`): 1.41 Newton iterations per step instead of 2.77, 10.2k-10.4k frames of 1/60 s per
//! second instead of 8.6k-8.9k; the hand-written floor gains the same (2.77 -> 1.42). The
//! tests cost an evaluation of C and two copies and comparisons of the state per step.
//!
//! **Stable step.** Across the rods RATTLE is the Stormer-Verlet method, explicit in the
//! oscillations the rods' tensions give the particles, and stable only for h omega < 2
//! (omega the fastest of them). On systems of rods and pins it bounds omega^2 from its last
//! multipliers ([`crate::linalg::RodPath::stiffness_bound`] along paths and trees,
//! [`crate::linalg::stiffness_bound_of_rows`] elsewhere), and `Simulation` takes
//! as many substeps as keep h omega <= 2 ([`Integrator::stable_step`]) before any Newton solve
//! fails: beyond the bound the fastest oscillation grows from step to step, and when the
//! solve fails at last the retried step leaves it in the motion for good (a symplectic
//! method does not damp it), at two or three Newton iterations a substep instead of one.
//!
//! **Velocity solve.** For a given a_{n+1}, linear in mu: the mass-weighted projection of
//! v_half + h/2 a_{n+1} onto J v = -C_t, done by [`ConstrainedSystem::project_velocities`] (the
//! symmetric J W J^T at q_{n+1}, the formulation's own sparse or dense factorization,
//! singular rows named), with
//! a_{n+1} = a(q_{n+1}, v_half) first. When the applied forces ignore the velocity
//! ([`ConstrainedSystem::applied_forces_velocity_dependent`] false) that is all: one force
//! evaluation and one projection. Otherwise a_{n+1} = a(q_{n+1}, v_{n+1}) is solved by
//! fixed-point iteration, each sweep re-evaluating a at the last projected v_{n+1} and
//! projecting again (one force evaluation and one projection per sweep; the evaluation at
//! v_half alone would be an O(h^2) error per step, first order). It contracts by about
//! h/2 ||da/dv|| (c/(2m) h for drag c) and stops or fails as gauss-legendre's stages do
//! (`implicit_tolerance`, `implicit_max_iterations` in [`IntegratorSettings`]; failure is
//! [`StepError::ImplicitStageFailed`] naming rattle: reduce dt).
//!
//! RATTLE works on the constraints themselves, so it needs the implicit form: on a system
//! without [`SecondOrderSystem::as_constrained`] (the parametric form) each step fails with
//! [`StepError::NeedsConstraints`]. Buffers that depend on the constraints' row structure
//! (and J W J^T's pattern and symbolic factorization) are built on the first step; later
//! steps allocate nothing. On the sparse path nothing is of size m x n or m x m.

use std::sync::Arc;

use super::fixed_point::{increment_and_scale, FixedPoint};
use super::{constraints_of, Integrator, IntegratorKind, IntegratorSettings, StepEnd};
use crate::formulation::{ConstrainedSystem, SecondOrderSystem, State, StepError};
use crate::linalg::{
    max_abs, solve_general, stiffness_bound_of_rows, ConstraintMatrix, LinearSolver, DENSE_MAX_ROWS,
};

/// Iterations the fused exact Newton iteration may go without halving its best residual
/// before the step is given up as failed (and retried in substeps by `Simulation`): Newton's
/// method converges quadratically once it converges at all, and on long chains whose tip
/// whips (10^4 links at dt = 1/120) a step it cannot solve otherwise wanders for all of
/// `max_iterations` at a residual of 1e-7..1e-5 (25 steps' work) before the retry.
const EXACT_STALL: usize = 5;

/// Buffers of the exact Newton iteration: J(q^k) (nnz), J(q^k) W J(q_n)^T's upper and lower
/// triangles on the pattern of J W J^T, and how it is solved.
struct ExactNewton {
    jacobian: Vec<f64>,
    upper: Vec<f64>,
    lower: Vec<f64>,
    solve: ExactSolve,
}

/// How the exact Newton matrix is solved.
enum ExactSolve {
    /// Gaussian elimination with partial pivoting of the dense matrix (m x m) with column
    /// scales (m): small systems, or any system when asked for.
    Dense {
        dense: Vec<f64>,
        column_scale: Vec<f64>,
    },
    /// Tridiagonal elimination in the path order of J W J^T's solver (chains), scratch (2m):
    /// O(m) per iteration.
    Path { scratch: Vec<f64> },
}

/// A step's warm start (see [`Rattle::with_warm_start`]) and its way back to the cold one.
struct WarmStart<'a> {
    /// The residual at the cold start q_pred
    cold_residual: f64,
    /// v_half (n), with h: q_pred = q_n + h v_half
    velocity_half: &'a [f64],
    dt: f64,
}

impl WarmStart<'_> {
    /// q = q_n + h v_half: the unconstrained predictor, the same bits as the step's drift.
    fn predictor(q_start: &[f64], velocity_half: &[f64], h: f64, q: &mut [f64]) {
        for ((q, q0), v) in q.iter_mut().zip(q_start).zip(velocity_half) {
            *q = q0 + h * v;
        }
    }
}

/// How RATTLE's position step solves C(q(nu), t_{n+1}) = 0 for nu (see the module
/// documentation for the measurements behind the default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NewtonMatrix {
    /// The exact matrix fused along the rods ([`RodPath`](crate::linalg::RodPath)) when
    /// every row is a rod and the rods couple in paths or trees; otherwise [`NewtonMatrix::Exact`]
    /// for systems of at most [`DENSE_MAX_ROWS`] rows (solved densely),
    /// [`NewtonMatrix::Simplified`] above.
    #[default]
    Auto,
    /// Newton's method: J(q^k) W J(q_n)^T, re-evaluated at every iterate and solved by dense
    /// Gaussian elimination with partial pivoting (O(m^2) memory, O(m^3) per iteration).
    /// Quadratic convergence.
    Exact,
    /// The symmetric J(q_n) W J(q_n)^T, assembled and factored once per step by the system's
    /// solver (sparse for large systems) and reused by every iteration. Linear convergence.
    Simplified,
}

/// RATTLE with a Newton solve for the position multipliers.
pub struct Rattle {
    /// The method its errors name: rattle, or the composition it is a stage of
    kind: IntegratorKind,
    /// Which Newton matrix the position step uses
    newton: NewtonMatrix,
    tolerance: f64,
    max_iterations: usize,
    /// Most Newton iterations any step has needed so far.
    iterations_max: usize,
    /// Newton iterations of all steps so far.
    iterations_total: u64,
    /// Stopping rule of the implicit velocity kick (velocity-dependent forces)
    rule: FixedPoint,
    /// Most sweeps of the implicit velocity kick any step has needed so far.
    velocity_iterations_max: usize,
    /// a, then the current iterate of a_{n+1} (n); between steps, the scratch of
    /// `stable_step`
    acceleration: Vec<f64>,
    /// a at the velocity the current a_{n+1} implies (n; sized on the first step whose
    /// applied forces depend on the velocity, empty otherwise)
    next: Vec<f64>,
    /// v_half (n)
    velocity_half: Vec<f64>,
    /// v_n (n)
    velocity_start: Vec<f64>,
    /// The work of the last step's constraint impulses (see `constraint_work`)
    constraint_work: f64,
    /// q_n (n)
    q_start: Vec<f64>,
    /// W (n), the system's own ([`ConstrainedSystem::shared_inverse_mass`])
    inverse_mass: Arc<[f64]>,
    /// Whether `reserve` has sized the buffers, for the system's `solver`, `m` and
    /// `row_fingerprint` ([`ConstrainedSystem::row_fingerprint`]) or, when it has none, its
    /// row `structure`
    reserved: bool,
    solver: LinearSolver,
    m: usize,
    row_fingerprint: Option<u64>,
    /// Row starts and columns (empty with a fingerprint)
    structure: (Vec<usize>, Vec<usize>),
    /// J(q_n): J's nonzero entries (nnz; empty while fused rods need none)
    jacobian_start: Vec<f64>,
    /// J(q_n) W J(q_n)^T and its factorization, built on the first step, or with fused rods
    /// on the first hand-over to the simplified matrix
    matrix: Option<ConstraintMatrix>,
    /// Exact Newton: J(q^k) (nnz), J(q^k) W J(q_n)^T's upper and lower triangles on the
    /// pattern of J W J^T (nnz of it each), the dense matrix (m x m) and column scales (m)
    exact: Option<ExactNewton>,
    /// Whether the position step runs as exact Newton fused along the system's own rods
    /// ([`ConstrainedSystem::rods_mut`]: every row a rod, the rods coupled in paths;
    /// [`NewtonMatrix::Auto`] only): O(m)
    fused: bool,
    /// C(q^k), then the Newton increment (m)
    residual: Vec<f64>,
    /// Accumulated nu (m); after a step, that step's
    nu: Vec<f64>,
    /// Whether a step that starts at bitwise the state the last one ended at starts its
    /// Newton iteration from the last step's nu (see [`Rattle::with_warm_start`])
    warm_start: bool,
    /// The step h the nu held was solved for; 0 when it predicts nothing (no step yet, the
    /// last one failed, or the rows changed, or warm starts are off)
    nu_step: f64,
    /// The state the last step ended at (none without warm start)
    end: StepEnd,
    /// The same, set aside while an event is located ([`Integrator::set_aside_carry`])
    aside_nu: Vec<f64>,
    aside_nu_step: f64,
    aside_end: StepEnd,
    /// J(q_n) v_n (m)
    jv: Vec<f64>,
}

impl Rattle {
    /// RATTLE for n coordinates: the position solve stops at max_i |C_i| <= `tolerance`
    /// (absolute) and fails after `max_iterations` Newton iterations. The implicit velocity
    /// kick uses the defaults of [`IntegratorSettings`].
    pub fn new(n: usize, tolerance: f64, max_iterations: usize) -> Self {
        Self::with_settings(
            n,
            &IntegratorSettings {
                constraint_tolerance: tolerance,
                constraint_max_iterations: max_iterations,
                ..IntegratorSettings::default()
            },
        )
    }

    /// RATTLE for n coordinates with the constraint and implicit-solve tolerances and
    /// iteration limits of `settings`.
    pub fn with_settings(n: usize, settings: &IntegratorSettings) -> Self {
        Rattle {
            kind: IntegratorKind::Rattle,
            newton: NewtonMatrix::Auto,
            tolerance: settings.constraint_tolerance,
            max_iterations: settings.constraint_max_iterations,
            iterations_max: 0,
            iterations_total: 0,
            rule: FixedPoint {
                method: "rattle",
                equations: "velocity half kick v' = v_half + h/2 (a(q', v') + W J^T mu)",
                tolerance: settings.implicit_tolerance,
                max_iterations: settings.implicit_max_iterations.max(1),
            },
            velocity_iterations_max: 0,
            acceleration: vec![0.0; n],
            next: Vec::new(),
            velocity_half: vec![0.0; n],
            velocity_start: vec![0.0; n],
            constraint_work: 0.0,
            q_start: vec![0.0; n],
            inverse_mass: Arc::from([]),
            reserved: false,
            solver: LinearSolver::Auto,
            m: 0,
            row_fingerprint: None,
            structure: (Vec::new(), Vec::new()),
            jacobian_start: Vec::new(),
            matrix: None,
            exact: None,
            fused: false,
            residual: Vec::new(),
            nu: Vec::new(),
            warm_start: true,
            nu_step: 0.0,
            end: StepEnd::default(),
            aside_nu: Vec::new(),
            aside_nu_step: 0.0,
            aside_end: StepEnd::default(),
            jv: Vec::new(),
        }
    }

    /// The same with the position step's Newton iteration started cold (nu = 0) at every
    /// step (`false`), or warm (`true`, the default): a step that starts at bitwise the state
    /// the last step ended at starts from that step's multipliers, scaled to its own step,
    ///
    /// ```text
    /// nu_0 = (h / h_prev)^2 nu_prev,   q^0 = q_pred - W J(q_n)^T nu_0
    /// ```
    ///
    /// (nu = -h^2/2 lambda, and lambda changes by O(h) from one step to the next), when that
    /// start's residual is below the cold start's; otherwise, and from any other state (the
    /// first step, a state set from outside, a step after a failed one, changed rows), it
    /// starts cold, with a cold step's bits. The state the last step ended at is also that
    /// state as its driver put it on a time grid or amended its ledger entry
    /// ([`Integrator::continued`]). Either way the step ends at the same tolerance.
    pub fn with_warm_start(mut self, warm_start: bool) -> Self {
        self.warm_start = warm_start;
        self.nu_step = 0.0;
        self
    }

    /// This RATTLE as the stages of `kind` (rattle4): its errors name that method.
    pub(super) fn staged_in(mut self, kind: IntegratorKind) -> Self {
        self.kind = kind;
        self.rule.method = kind.name();
        self
    }

    /// Newton iterations of the position step summed over every step so far.
    pub fn newton_iterations_total(&self) -> u64 {
        self.iterations_total
    }

    /// Whether the position step runs fused along the rods ([`crate::linalg::RodPath`]:
    /// every row a distance, the rows coupled in paths or trees, the system solving along
    /// them, as [`crate::formulation::Implicit`] does with [`LinearSolver::Auto`];
    /// [`NewtonMatrix::Auto`]); known after the first step.
    pub fn fused_rods(&self) -> bool {
        self.fused
    }

    /// The same with another Newton matrix for the position step.
    pub fn with_newton(mut self, newton: NewtonMatrix) -> Self {
        self.newton = newton;
        self.reserved = false;
        self
    }

    /// The most fixed-point sweeps of the implicit velocity kick any step so far has needed
    /// (0 while the applied forces did not depend on the velocity).
    pub fn velocity_iterations_max(&self) -> usize {
        self.velocity_iterations_max
    }

    /// Size the m-dependent buffers and analyse J W J^T for the system's row structure
    /// (allocates only when the rows change, i.e. on the first step).
    fn reserve(&mut self, cs: &mut dyn ConstrainedSystem) {
        let has_rods = cs.rods_mut().is_some();
        let rows = cs.constraint_structure();
        let m = rows.n_rows();
        let solver = cs.linear_solver();
        let starts = (0..=m).map(|i| {
            if i < m {
                rows.row_entries(i).start
            } else {
                rows.n_nonzeros()
            }
        });
        let fingerprint = cs.row_fingerprint();
        // O(1) with the system's fingerprint; O(nnz) comparing the structure without one.
        let same = self.reserved
            && self.solver == solver
            && self.m == m
            && match fingerprint {
                Some(fingerprint) => self.row_fingerprint == Some(fingerprint),
                None => {
                    self.row_fingerprint.is_none()
                        && self.structure.0.iter().copied().eq(starts.clone())
                        && self.structure.1 == rows.columns()
                }
            };
        if !same {
            (self.reserved, self.solver, self.m) = (true, solver, m);
            self.row_fingerprint = fingerprint;
            self.structure = match fingerprint {
                Some(_) => (Vec::new(), Vec::new()),
                None => (starts.collect(), rows.columns().to_vec()),
            };
            // The system's own rods (their geometry is its own, never stale).
            self.fused = self.newton == NewtonMatrix::Auto && m > 0 && has_rods;
            self.matrix = None;
            self.exact = None;
            self.jacobian_start = Vec::new();
            // Fused rods need neither J W J^T nor J(q_n) unless a step hands over to the
            // simplified matrix (`general_matrix`).
            if !self.fused {
                let exact = match self.newton {
                    NewtonMatrix::Exact => true,
                    NewtonMatrix::Simplified => false,
                    NewtonMatrix::Auto => m <= DENSE_MAX_ROWS,
                };
                let matrix = ConstraintMatrix::new(rows, solver);
                self.exact = exact.then(|| ExactNewton {
                    jacobian: vec![0.0; rows.n_nonzeros()],
                    upper: vec![0.0; matrix.pattern().nnz()],
                    lower: vec![0.0; matrix.pattern().nnz()],
                    solve: if matrix.path().is_some() {
                        ExactSolve::Path {
                            scratch: vec![0.0; 2 * m],
                        }
                    } else {
                        ExactSolve::Dense {
                            dense: vec![0.0; m * m],
                            column_scale: vec![0.0; m],
                        }
                    },
                });
                self.matrix = Some(matrix);
                self.jacobian_start = vec![0.0; rows.n_nonzeros()];
            }
            self.residual = vec![0.0; m];
            self.nu = vec![0.0; m];
            self.nu_step = 0.0;
            self.jv = vec![0.0; m];
        }
    }

    /// J W J^T for the simplified iteration, and room for J(q_n), built when a step first
    /// needs them (on the first step unless the rods are fused).
    fn general_matrix(&mut self, cs: &dyn ConstrainedSystem) -> &mut ConstraintMatrix {
        let rows = cs.constraint_structure();
        if self.jacobian_start.len() != rows.n_nonzeros() {
            self.jacobian_start = vec![0.0; rows.n_nonzeros()];
        }
        self.matrix
            .get_or_insert_with(|| ConstraintMatrix::new(rows, cs.linear_solver()))
    }

    /// The residual of C(q, t) (`constraint_residual`), C left in `residual`; fused rods in
    /// their own pass when the system says how it scales.
    fn residual_at(&mut self, cs: &mut dyn ConstrainedSystem, t: f64, q: &[f64]) -> f64 {
        match cs.rods_mut().filter(|_| self.fused) {
            Some((rods, Some(scales))) => {
                rods.values_and_residual(q, &mut self.residual, &scales.scale, &scales.rounding)
            }
            Some((rods, None)) => {
                rods.values(q, &mut self.residual);
                cs.constraint_residual(q, &self.residual)
            }
            None => {
                cs.constraint_values(t, q, &mut self.residual);
                cs.constraint_residual(q, &self.residual)
            }
        }
    }

    /// Whether a warm start whose first residual is no smaller than the cold start's went
    /// back to the cold start (q = q_pred, bit for bit, and nu = 0): a start farther from
    /// the constraints may lead Newton's method to another root, another solution of
    /// C(q(nu)) = 0 far from the step's.
    fn cold_again(
        q_start: &[f64],
        nu: &mut [f64],
        warm: &mut Option<WarmStart>,
        residual: f64,
        q: &mut [f64],
    ) -> bool {
        match warm {
            // Not `residual < cold`, NaN included.
            Some(start)
                if residual.partial_cmp(&start.cold_residual) != Some(std::cmp::Ordering::Less) =>
            {
                WarmStart::predictor(q_start, start.velocity_half, start.dt, q);
                nu.fill(0.0);
                *warm = None;
                true
            }
            _ => false,
        }
    }

    /// Newton iterations for nu: q <- q - W J(q_n)^T dnu with M dnu = C(q, t) until
    /// max|C(q, t)| <= tolerance. Simplified: M = J(q_n) W J(q_n)^T, factored once (on the
    /// first iteration that needs it) and reused; exact: M = J(q^k) W J(q_n)^T. An exact
    /// matrix whose tridiagonal elimination meets a vanishing pivot (the step turned a rod
    /// by about a right angle) hands the rest of the step to the simplified matrix. Returns
    /// the number of iterations. `jacobian_start` holds J(q_n), or, with the fused rods,
    /// their vectors hold q_n's and `jacobian_start` is evaluated at `t0` if the rods hand
    /// over.
    ///
    /// Fused rods: the exact Newton iteration along the path ([`RodPath::newton_step`]);
    /// a pivot that fails there hands the rest of the step to the simplified matrix, as the
    /// general exact matrix does.
    ///
    /// `warm`: q is already q_pred - W J(q_n)^T nu for the nu held (the warm start), kept
    /// only if it starts nearer the constraints than q_pred (else q goes back to q_pred and
    /// `warm` becomes `None`, so that a failure after it is known to be a cold start's);
    /// without it q is q_pred and nu starts at 0.
    fn solve_positions(
        &mut self,
        cs: &mut dyn ConstrainedSystem,
        t0: f64,
        t: f64,
        warm: &mut Option<WarmStart>,
        q: &mut [f64],
    ) -> Result<usize, StepError> {
        if warm.is_none() {
            self.nu.fill(0.0);
        }
        let mut iterations = 0;
        // Whether the first residual has been set against the warm start's.
        let mut started = false;
        if self.fused {
            // The best residual so far and the iterations since it last halved.
            let (mut best, mut stalled) = (f64::INFINITY, 0);
            loop {
                let residual = self.residual_at(cs, t, q);
                if !std::mem::replace(&mut started, true)
                    && Self::cold_again(&self.q_start, &mut self.nu, warm, residual, q)
                {
                    continue;
                }
                if residual <= self.tolerance {
                    return Ok(iterations);
                }
                if residual < 0.5 * best {
                    (best, stalled) = (residual, 0);
                } else {
                    stalled += 1;
                }
                if iterations >= self.max_iterations || residual.is_nan() || stalled > EXACT_STALL {
                    return Err(StepError::ProjectionFailed {
                        t,
                        iterations,
                        residual: max_abs(&self.residual),
                        solve: "rattle's solve for the constraint forces",
                        substeps: 0,
                    });
                }
                let (rods, _) = cs.rods_mut().expect("fused rods");
                if rods
                    .newton_step(&self.inverse_mass, &mut self.residual, q)
                    .is_err()
                {
                    self.general_matrix(cs);
                    cs.constraint_jacobian(t0, &self.q_start, &mut self.jacobian_start);
                    break;
                }
                for (nu, d) in self.nu.iter_mut().zip(&self.residual) {
                    *nu += d;
                }
                iterations += 1;
            }
        }
        let matrix = self
            .matrix
            .as_mut()
            .expect("built in reserve or on the hand-over");
        let mut exact = self.exact.as_mut();
        let mut factored = false;
        // A warm start gives up as the fused iteration does (`EXACT_STALL`), for a cold one.
        let (mut best, mut stalled) = (f64::INFINITY, 0);
        loop {
            // The exact matrix needs J(q^k): evaluated with C(q^k) in one pass.
            match &mut exact {
                Some(newton) => cs.constraint_values_and_jacobian(
                    t,
                    q,
                    &mut self.residual,
                    &mut newton.jacobian,
                ),
                None => cs.constraint_values(t, q, &mut self.residual),
            }
            let residual = cs.constraint_residual(q, &self.residual);
            if !std::mem::replace(&mut started, true)
                && Self::cold_again(&self.q_start, &mut self.nu, warm, residual, q)
            {
                continue;
            }
            if residual <= self.tolerance {
                return Ok(iterations);
            }
            if residual < 0.5 * best {
                (best, stalled) = (residual, 0);
            } else {
                stalled += 1;
            }
            if iterations >= self.max_iterations
                || residual.is_nan()
                || (warm.is_some() && stalled > EXACT_STALL)
            {
                return Err(StepError::ProjectionFailed {
                    t,
                    iterations,
                    residual: max_abs(&self.residual),
                    solve: "rattle's solve for the constraint forces",
                    substeps: 0,
                });
            }
            let mut solved = false;
            if let Some(newton) = &mut exact {
                // J(q^k) W J(q_n)^T.
                matrix.assemble_product(
                    &newton.jacobian,
                    &self.jacobian_start,
                    &self.inverse_mass,
                    &mut newton.upper,
                    &mut newton.lower,
                );
                match &mut newton.solve {
                    ExactSolve::Dense {
                        dense,
                        column_scale,
                    } => {
                        let m = self.residual.len();
                        dense.fill(0.0);
                        let pattern = matrix.pattern();
                        for j in 0..m {
                            for (s, &i) in pattern.column(j) {
                                dense[i * m + j] = newton.upper[s];
                                dense[j * m + i] = newton.lower[s];
                            }
                        }
                        if let Err(column) =
                            solve_general(m, dense, &mut self.residual, column_scale)
                        {
                            return Err(cs.singular_constraint(t, column));
                        }
                        solved = true;
                    }
                    ExactSolve::Path { scratch } => {
                        let path = matrix.path().expect("a path solver");
                        let result = path.solve_general(
                            &newton.upper,
                            &newton.lower,
                            &mut self.residual,
                            scratch,
                        );
                        if result.is_ok() {
                            solved = true;
                        } else {
                            // Simplified from here on: J(q_n) W J(q_n)^T is the one that
                            // tells a dependent row from a large turn.
                            exact = None;
                            cs.constraint_values(t, q, &mut self.residual);
                        }
                    }
                }
            }
            if !solved {
                if !factored {
                    matrix.assemble(&self.jacobian_start, &self.inverse_mass);
                    if let Err(singular) = matrix.factor() {
                        return Err(if singular.finite {
                            cs.singular_constraint(t, singular.row)
                        } else {
                            StepError::NonFinite {
                                t,
                                quantity: "the matrix J W J^T (overflow)".into(),
                            }
                        });
                    }
                    factored = true;
                }
                matrix.solve_in_place(&mut self.residual);
            }
            for (nu, d) in self.nu.iter_mut().zip(&self.residual) {
                *nu += d;
            }
            cs.constraint_structure().subtract_weighted_transpose(
                &self.jacobian_start,
                &self.inverse_mass,
                &self.residual,
                q,
            );
            iterations += 1;
        }
    }
}

/// v = v_half + h/2 a, then the mass-weighted projection onto J(q) v + C_t(q, t) = 0 (which
/// adds the W J^T mu term).
fn kick_and_project(
    cs: &mut dyn ConstrainedSystem,
    t: f64,
    q: &[f64],
    v: &mut [f64],
    velocity_half: &[f64],
    half: f64,
    acceleration: &[f64],
) -> Result<(), StepError> {
    for ((v, vh), a) in v.iter_mut().zip(velocity_half).zip(acceleration) {
        *v = vh + half * a;
    }
    if cs.n_constraints() > 0 {
        cs.project_velocities(t, q, v)?;
    }
    Ok(())
}

impl Integrator for Rattle {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let cs = constraints_of(system, self.kind)?;
        let n = s.q.len();
        let m = cs.n_constraints();
        self.reserve(cs);
        // Warm only from bitwise the state the last step ended at; cold until this one ends.
        let previous_step = std::mem::replace(&mut self.nu_step, 0.0);
        let warm = self.end.take_continued_by(s) && previous_step != 0.0;
        // The system's W, shared: taken again only when the system is another one.
        if !std::ptr::eq(cs.inverse_mass(), &*self.inverse_mass) {
            self.inverse_mass = cs.shared_inverse_mass();
        }
        let (t0, t1, half) = (s.t, s.t + dt, 0.5 * dt);

        // Unconstrained half kick and drift: v_half = v + h/2 a_n, q_pred = q + h v_half.
        cs.unconstrained_acceleration(t0, &s.q, &s.qdot, &mut self.acceleration)?;
        self.q_start.copy_from_slice(&s.q);
        self.velocity_start.copy_from_slice(&s.qdot);
        self.constraint_work = 0.0;
        // Constraints fixed in time do no work: exactly 0, not the rounding of J v = 0.
        let work_done = m > 0 && cs.constraints_time_dependent();
        for ((q, v), a) in
            s.q.iter_mut()
                .zip(s.qdot.iter_mut())
                .zip(&self.acceleration)
        {
            *v += half * a;
            *q += dt * *v;
        }
        if m > 0 {
            match cs.rods_mut().filter(|_| self.fused) {
                Some((rods, _)) => rods.set_start(&self.q_start),
                None => cs.constraint_jacobian(t0, &self.q_start, &mut self.jacobian_start),
            }
            let mut start = warm.then(|| WarmStart {
                cold_residual: self.residual_at(cs, t1, &s.q),
                velocity_half: &s.qdot,
                dt,
            });
            if warm {
                // nu = -h^2/2 lambda: the last step's lambda at this step's h.
                let scale = (dt / previous_step).powi(2);
                self.nu.iter_mut().for_each(|nu| *nu *= scale);
                match cs.rods_mut().filter(|_| self.fused) {
                    Some((rods, _)) => {
                        rods.subtract_start_transpose(&self.inverse_mass, &self.nu, &mut s.q)
                    }
                    None => cs.constraint_structure().subtract_weighted_transpose(
                        &self.jacobian_start,
                        &self.inverse_mass,
                        &self.nu,
                        &mut s.q,
                    ),
                }
            }
            let iterations = match self.solve_positions(cs, t0, t1, &mut start, &mut s.q) {
                // Multipliers that moved too far for the last step's to be a start (fast
                // turns): the step again from q_pred and nu = 0, a cold step's bits (unless
                // the start went cold at its first residual: that failure is the cold one's).
                Err(error) if start.is_some() => {
                    let spent = match error {
                        StepError::ProjectionFailed { iterations, .. } => iterations,
                        _ => 0,
                    };
                    WarmStart::predictor(&self.q_start, &s.qdot, dt, &mut s.q);
                    spent + self.solve_positions(cs, t0, t1, &mut None, &mut s.q)?
                }
                solved => solved?,
            };
            self.iterations_max = self.iterations_max.max(iterations);
            self.iterations_total += iterations as u64;
            // v_half += h/2 W J(q_n)^T lambda = -(1/h) W J(q_n)^T nu. The impulse
            // -J(q_n)^T nu / h does the work (h/2) lambda . J(q_n) v_n on the velocity it
            // acts at: the first half of the trapezoidal rule for the constraint force's
            // power (zero for fixed constraints, where J v_n = 0).
            for (d, nu) in self.residual.iter_mut().zip(&self.nu) {
                *d = nu / dt;
            }
            match cs.rods_mut().filter(|_| self.fused) {
                Some((rods, _)) => {
                    rods.subtract_start_transpose(&self.inverse_mass, &self.residual, &mut s.qdot);
                    if work_done {
                        rods.start_multiply(&self.velocity_start, &mut self.jv);
                    }
                }
                None => {
                    let rows = cs.constraint_structure();
                    rows.subtract_weighted_transpose(
                        &self.jacobian_start,
                        &self.inverse_mass,
                        &self.residual,
                        &mut s.qdot,
                    );
                    if work_done {
                        rows.multiply(&self.jacobian_start, &self.velocity_start, &mut self.jv);
                    }
                }
            }
            if work_done {
                self.constraint_work -= self
                    .residual
                    .iter()
                    .zip(&self.jv)
                    .map(|(d, jv)| d * jv)
                    .sum::<f64>();
            }
        }
        // Second half kick, then the velocity constraint J v + C_t = 0 (the mu solve), with
        // a_{n+1} first at v_half.
        self.velocity_half.copy_from_slice(&s.qdot);
        cs.unconstrained_acceleration(t1, &s.q, &s.qdot, &mut self.acceleration)?;
        kick_and_project(
            cs,
            t1,
            &s.q,
            &mut s.qdot,
            &self.velocity_half,
            half,
            &self.acceleration,
        )?;
        if cs.applied_forces_velocity_dependent() {
            // Fixed point a_{n+1} = a(q_{n+1}, v_{n+1}(a_{n+1})).
            let mut previous = f64::INFINITY;
            let mut iterations = 0;
            self.next.resize(n, 0.0);
            loop {
                iterations += 1;
                cs.unconstrained_acceleration(t1, &s.q, &s.qdot, &mut self.next)?;
                let (increment, scale) =
                    increment_and_scale(&self.next, &self.acceleration, (0.0, 0.0));
                std::mem::swap(&mut self.acceleration, &mut self.next);
                kick_and_project(
                    cs,
                    t1,
                    &s.q,
                    &mut s.qdot,
                    &self.velocity_half,
                    half,
                    &self.acceleration,
                )?;
                if self
                    .rule
                    .converged(t0, iterations, increment, previous, scale)?
                {
                    break;
                }
                previous = increment;
            }
            self.velocity_iterations_max = self.velocity_iterations_max.max(iterations as usize);
        }
        // The velocity projection's impulse M (v_{n+1} - (v_half + h/2 a_{n+1})) does the work
        // (h/2) mu . J(q_{n+1}) v_{n+1}: the trapezoidal rule's second half.
        if work_done {
            for k in 0..n {
                let w = self.inverse_mass[k];
                if w > 0.0 {
                    let kicked = self.velocity_half[k] + half * self.acceleration[k];
                    self.constraint_work += (s.qdot[k] - kicked) / w * s.qdot[k];
                }
            }
        }
        s.t = t1;
        if self.warm_start && m > 0 {
            self.nu_step = dt;
            self.end.record(s);
        }
        Ok(())
    }

    /// The work of the last step's constraint impulses, sum of Delta p . v: the trapezoidal
    /// rule for the constraint force's power lambda . J v = -lambda . C_t, so nonzero only for
    /// constraints that depend on t (a driven constraint does work; a fixed one does none).
    fn constraint_work(&self) -> f64 {
        self.constraint_work
    }

    fn newton_iterations_max(&self) -> Option<usize> {
        Some(self.iterations_max)
    }

    /// 2 / omega, omega^2 bounded by [`RodPath::stiffness_bound`] (rods in paths and
    /// trees) or [`stiffness_bound_of_rows`] (rods and pins in any graph) from the last
    /// step's multipliers lambda = -2 nu / h^2 (the rods' tensions over that step): the
    /// Stormer-Verlet step RATTLE takes across the rods is stable for h omega < 2 and
    /// excites their fastest oscillation beyond it. Measured on the hanging chain of 10^4
    /// links at h = 1/120: h omega (the bound) passes 2 at 2.0 s; a run that goes to two
    /// substeps by then takes one Newton iteration per substep for the rest of 10 s, one that
    /// goes on in single steps until the Newton solve fails at h omega = 2.09 leaves that
    /// oscillation in the chain for good, at 2-3 iterations per substep. Rods and pins only
    /// (their Hessians are constant and their forces are the multipliers; `None` with a row
    /// written as an expression); after a warm-start step only (`nu_step`, else `None`).
    ///
    /// [`RodPath::stiffness_bound`]: crate::linalg::RodPath::stiffness_bound
    fn stable_step(&mut self, system: &mut dyn SecondOrderSystem) -> Option<f64> {
        let h = self.nu_step;
        let cs = system.as_constrained()?;
        // Multipliers of this system's rows (W shared with it), and room for the bound.
        let same = std::ptr::eq(cs.inverse_mass(), &*self.inverse_mass)
            && cs.n_constraints() == self.nu.len()
            && self.acceleration.len() == self.inverse_mass.len();
        if h == 0.0 || !same {
            return None;
        }
        let scale = 2.0 / (h * h);
        let nu = &self.nu;
        let lambda = |row: usize| scale * nu[row];
        let (w, scratch) = (&self.inverse_mass, &mut self.acceleration);
        let omega_squared = match cs.rods_mut() {
            Some((rods, _)) => rods.stiffness_bound(w, lambda, scratch),
            // Rods in rings (a cloth, a net) and pins, one row at a time.
            None => {
                let row = |r| match cs.distance_row(r) {
                    Some(rod) => Some(Some(rod)),
                    None => cs.linear_row(r).then_some(None),
                };
                stiffness_bound_of_rows(nu.len(), row, w, lambda, scratch)?
            }
        };
        (omega_squared >= 0.0).then(|| 2.0 / omega_squared.sqrt())
    }

    fn set_aside_carry(&mut self) {
        self.aside_nu.clone_from(&self.nu);
        self.aside_end.clone_from(&self.end);
        self.aside_nu_step = self.nu_step;
    }

    fn continued(&mut self, stepped: f64, state: &State, amended: bool) {
        self.end.continued(stepped, state, amended);
    }

    fn iterations_total(&self) -> Option<u64> {
        Some(self.iterations_total)
    }

    /// The multipliers set aside, unless the rows changed since (then the next step is cold).
    fn take_back_carry(&mut self) {
        if self.aside_nu.len() == self.nu.len() {
            self.nu.clone_from(&self.aside_nu);
            self.end.clone_from(&self.aside_end);
            self.nu_step = self.aside_nu_step;
        } else {
            self.nu_step = 0.0;
        }
    }
}
