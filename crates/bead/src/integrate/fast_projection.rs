//! Step and project, after the fast projection of Goldenthal, Harmon, Fattal, Bercovier &
//! Grinspun ("Efficient Simulation of Inextensible Cloth", SIGGRAPH 2007): an unconstrained
//! symplectic Euler step, the positions projected onto the constraints (the closest point
//! in the mass metric), and the velocity taken from the positions' change:
//!
//! ```text
//! v*      = v_n + h W F(q_n, v_n)                        (applied forces only)
//! q*      = q_n + h v*
//! q_{n+1} = argmin 1/2 (q - q*)^T M (q - q*)  subject to C(q, t_{n+1}) = 0
//!         = q* - W J(q_{n+1})^T lambda                    (constraint forces at the end)
//! v_{n+1} = (q_{n+1} - q_n) / h,  then projected onto J(q_{n+1}) v + C_t = 0
//! ```
//!
//! Order 1, implicit form only. Every constraint force comes from the projection at the
//! step's end (the constraint direction is implicit), so the step is stable however stiff
//! the constraints make the motion: a cloth's taut threads oscillate across themselves at
//! up to 2 sqrt(T / (m L)) (2,190 rad/s for the shipped 50 x 50 cloth), and RATTLE, explicit
//! in those directions like every Verlet method, needs h omega < 2 (h = 1/2,300 s) where
//! this step takes a frame (1/60 s) and holds every rod to the tolerance
//! (`tests/fast_projection.rs`: a 12 x 12 cloth at dt F = 4.2, where RATTLE fails within a
//! second). The price is damping: modes the step cannot resolve (h omega >> 1) lose their
//! energy, as in every game engine's cloth (on that cloth the energy never rose above its
//! start in 1,200 steps). For accuracy and energy on systems RATTLE can step, RATTLE stays
//! the method.
//!
//! The paper iterates Gauss-Newton steps q <- q - W J^T (J W J^T)^-1 C, which end on the
//! constraints but not at the closest point, and which converge slowly where the
//! constraints curve: on the shipped 50 x 50 cloth at dt = 1/60 they overshoot on the taut,
//! nearly collinear threads and take up to ~170 iterations (8.8 steps/s). Here the
//! projection is solved by Newton's method on its optimality conditions
//! M (q - q*) + J^T lambda = 0, C = 0 ([`ProjectionNewtonMatrix`]):
//!
//! ```text
//! [ M + sum_i lambda_i+ H_i   J^T ] [ dq      ]     [ M (q - q*) + J^T lambda ]
//! [ J                          0  ] [ dlambda ] = - [ C(q, t_{n+1})           ]
//! ```
//!
//! with the exact Hessians H_i of distance rows ((1/L) [I, -I; -I, I]: the tension's
//! transverse stiffness) and the multipliers warm-started from the last step's (scaled by
//! (h / h_last)^2: lambda is an impulse times h) when the step starts at bitwise the state
//! the last one ended at, or at it as its driver retimed it ([`Integrator::continued`]);
//! any other start, from lambda = 0, has a fresh integrator's bits.
//! Each step factors this matrix at its first iterate; later iterations reuse the
//! factorization (chord steps, one solve each) while the residual keeps shrinking at least
//! 4x per iteration, and factor again when it does not. On the 50 x 50 cloth at dt = 1/60 that is about one factorization and four
//! solves per step (the chain bench; `tests/fast_projection.rs`). Rows without a known
//! Hessian (expressions, pins, Rust rows) are taken in Gauss-Newton form: where their
//! multipliers' curvature matters (a taut expression row at dt omega >> 1) the iteration
//! converges slowly or not at all, and the step fails with `ProjectionFailed` (which a
//! simulation retries in substeps) rather than stop anywhere but at C within the tolerance
//! and the closest point. The velocity projection is
//! [`ConstrainedSystem::project_velocities`]. A projection that does not converge within
//! the iteration limit is [`StepError::ProjectionFailed`], never a silent continuation.

use super::{constraints_of, Integrator, IntegratorKind, IntegratorSettings, StepEnd};
use crate::formulation::{ConstrainedSystem, SecondOrderSystem, State, StepError};
use crate::linalg::{
    max_abs, max_nan, Curvature, NewtonMatrixError, ProjectionNewtonMatrix, RowCurvature,
};

/// A later iteration of a step reuses the factorization while the last one shrank the
/// residual at least this much (else it factors the Newton matrix at its own iterate).
const REUSE_CONTRACTION: f64 = 0.25;

/// The projection stops when q is this close to the closest point, relative to the
/// correction: max |W (M (q - q*) + J^T lambda)| <= this * max |q - q*| (with C within the
/// constraint tolerance). The step is first order; 1e-10 of its correction is far below
/// its error, and 1e-12 would cost the 50 x 50 cloth 25% more solves.
const STATIONARITY_TOLERANCE: f64 = 1e-10;

/// Step and project (see the module).
pub struct FastProjection {
    tolerance: f64,
    max_iterations: usize,
    /// Most projection iterations any step has needed so far
    iterations_max: usize,
    /// Projection iterations of all steps so far
    iterations_total: u64,
    /// Factorizations of the projection's Newton matrix in all steps so far
    factorizations_total: u64,
    /// The work of the last step's constraint impulses (see `constraint_work`)
    constraint_work: f64,
    /// a, then v* (n)
    acceleration: Vec<f64>,
    /// q_n (n)
    q_start: Vec<f64>,
    /// The projection's Newton iteration, built for the system's rows on the first step
    newton: Option<ProjectionNewton>,
    /// The state the last constrained step ended at: the multipliers are a start only for a
    /// step from it
    end: StepEnd,
    /// Its multipliers, their step and its end, set aside while an event is located
    /// ([`Integrator::set_aside_carry`])
    aside_lambda: Vec<f64>,
    aside_lambda_dt: f64,
    aside_end: StepEnd,
}

/// The projection's Newton matrix and the buffers sized for one row structure.
struct ProjectionNewton {
    /// The row structure the matrix was built for: row starts, columns
    row_start: Vec<usize>,
    columns: Vec<usize>,
    curvature: Vec<RowCurvature>,
    inverse_mass: Vec<f64>,
    matrix: ProjectionNewtonMatrix,
    /// The multipliers (m), kept from step to step, and the step they belong to
    lambda: Vec<f64>,
    lambda_dt: f64,
    dlambda: Vec<f64>,
    c: Vec<f64>,
    jacobian: Vec<f64>,
    residual_q: Vec<f64>,
    dq: Vec<f64>,
    /// q* = q_n + h v*, where the projection starts (n)
    q_free: Vec<f64>,
    /// Per coordinate, the sizes of the terms W r_q sums (n)
    term_sizes: Vec<f64>,
}

impl ProjectionNewton {
    fn curvature_of(cs: &dyn ConstrainedSystem) -> impl Iterator<Item = RowCurvature> + '_ {
        (0..cs.n_constraints()).filter_map(|row| {
            cs.distance_row(row).map(|d| RowCurvature {
                row,
                a: d.a,
                b: d.b,
                dim: d.dim,
                scale: 1.0 / d.length,
            })
        })
    }

    fn new(cs: &dyn ConstrainedSystem) -> Self {
        let rows = cs.constraint_structure();
        let m = rows.n_rows();
        let n = cs.inverse_mass().len();
        let curvature: Vec<RowCurvature> = Self::curvature_of(cs).collect();
        ProjectionNewton {
            row_start: (0..m).map(|i| rows.row_entries(i).start).collect(),
            columns: rows.columns().to_vec(),
            matrix: ProjectionNewtonMatrix::new(rows, cs.inverse_mass(), curvature.clone()),
            curvature,
            inverse_mass: cs.inverse_mass().to_vec(),
            lambda: vec![0.0; m],
            lambda_dt: 0.0,
            dlambda: vec![0.0; m],
            c: vec![0.0; m],
            jacobian: vec![0.0; rows.n_nonzeros()],
            residual_q: vec![0.0; n],
            dq: vec![0.0; n],
            q_free: vec![0.0; n],
            term_sizes: vec![0.0; n],
        }
    }

    /// Whether this was built for `cs` as it is now: rows, masses, distances (compared
    /// without allocating).
    fn fits(&self, cs: &dyn ConstrainedSystem) -> bool {
        let rows = cs.constraint_structure();
        let m = rows.n_rows();
        m == self.row_start.len()
            && (0..m).all(|i| rows.row_entries(i).start == self.row_start[i])
            && rows.columns() == self.columns
            && cs.inverse_mass() == self.inverse_mass
            && Self::curvature_of(cs).eq(self.curvature.iter().copied())
    }

    /// Project `q` (q* on entry, kept as `q_free`) onto C(q, t) = 0 by Newton's method
    /// (see the module) to `limits` (the constraint tolerance, the iteration limit),
    /// counting factorizations into `factorizations`; the number of iterations taken.
    fn project(
        &mut self,
        cs: &mut dyn ConstrainedSystem,
        t: f64,
        q: &mut [f64],
        dt: f64,
        limits: (f64, usize),
        factorizations: &mut u64,
    ) -> Result<usize, StepError> {
        let (tolerance, max_iterations) = limits;
        self.q_free.copy_from_slice(q);
        // lambda is h^2 times a force: carried over to another step size as such.
        let ratio = if self.lambda_dt > 0.0 {
            dt / self.lambda_dt
        } else {
            0.0
        };
        for lambda in &mut self.lambda {
            *lambda *= ratio * ratio;
        }
        self.lambda_dt = dt;
        let mut iterations = 0;
        let mut previous = f64::INFINITY;
        let outcome = loop {
            cs.constraint_values_and_jacobian(t, q, &mut self.c, &mut self.jacobian);
            let residual = cs.constraint_residual(q, &self.c);
            // r_q = M (q - q*) + J^T lambda, and the stationarity |W r_q| / |q - q*| (max
            // norms): how far q is from the closest point, relative to the correction.
            let mut displacement = 0.0_f64;
            for ((r, (q, q_free)), w) in self
                .residual_q
                .iter_mut()
                .zip(q.iter().zip(&self.q_free))
                .zip(&self.inverse_mass)
            {
                *r = if *w > 0.0 { (q - q_free) / w } else { 0.0 };
                displacement = max_nan(displacement, (q - q_free).abs());
            }
            let rows = cs.constraint_structure();
            rows.add_transpose(&self.jacobian, &self.lambda, &mut self.residual_q);
            // What rounding leaves of W r_q: a few eps times the terms it sums, q and q*
            // (whose difference is far smaller than each on a short step) and
            // W J_ik lambda_i (the forces of taut threads cancel to a net far smaller than
            // each).
            let mut off = 0.0_f64;
            let mut terms = 0.0_f64;
            for (k, ((r, q), q_free)) in self
                .residual_q
                .iter()
                .zip(q.iter())
                .zip(&self.q_free)
                .enumerate()
            {
                let w = self.inverse_mass[k];
                off = max_nan(off, (w * r).abs());
                // A coordinate that does not move (the ledger's work) sums nothing.
                self.term_sizes[k] = if w > 0.0 {
                    q.abs().max(q_free.abs())
                } else {
                    0.0
                };
            }
            for i in 0..rows.n_rows() {
                for (s, &k) in rows.row_entries(i).zip(rows.row_columns(i)) {
                    self.term_sizes[k] +=
                        (self.inverse_mass[k] * self.jacobian[s] * self.lambda[i]).abs();
                }
            }
            for size in &self.term_sizes {
                terms = max_nan(terms, *size);
            }
            let stationarity = if off == 0.0 { 0.0 } else { off / displacement };
            let rounding = if terms == 0.0 {
                0.0
            } else {
                64.0 * f64::EPSILON * terms / displacement
            };
            // Done when C is within the tolerance and q is at the closest point: to
            // STATIONARITY_TOLERANCE, or to what rounding allows.
            if residual <= tolerance && stationarity <= STATIONARITY_TOLERANCE.max(rounding) {
                break Ok(iterations);
            }
            if iterations >= max_iterations || residual.is_nan() || stationarity.is_nan() {
                break Err(StepError::ProjectionFailed {
                    t,
                    iterations,
                    residual: max_abs(&self.c),
                    solve: "the fast projection onto the constraints",
                    substeps: 0,
                });
            }
            // Each step's first iterate is factored; later ones reuse it while it still
            // shrinks the residuals fast (a chord step: one solve instead of a
            // factorization).
            let progress = (residual / tolerance).max(stationarity / STATIONARITY_TOLERANCE);
            let reuse = iterations > 0 && progress <= REUSE_CONTRACTION * previous;
            previous = progress;
            if !reuse {
                // Newton's own matrix; with only the pulling rows' curvature where
                // compressed rods make it indefinite.
                let factored = self
                    .matrix
                    .factor(&self.jacobian, &self.lambda, Curvature::Signed)
                    .or_else(|error| match error {
                        NewtonMatrixError::NotPositive => {
                            *factorizations += 1;
                            self.matrix
                                .factor(&self.jacobian, &self.lambda, Curvature::TensionOnly)
                        }
                        other => Err(other),
                    });
                if let Err(error) = factored {
                    break Err(match error {
                        NewtonMatrixError::Dependent { row } => cs.singular_constraint(t, row),
                        _ => StepError::ProjectionFailed {
                            t,
                            iterations,
                            residual: f64::NAN,
                            solve: "the fast projection onto the constraints",
                            substeps: 0,
                        },
                    });
                }
                *factorizations += 1;
            }
            self.matrix
                .solve(&self.residual_q, &self.c, &mut self.dq, &mut self.dlambda);
            for (q, dq) in q.iter_mut().zip(&self.dq) {
                *q += dq;
            }
            for (lambda, dlambda) in self.lambda.iter_mut().zip(&self.dlambda) {
                *lambda += dlambda;
            }
            iterations += 1;
        };
        if outcome.is_err() {
            // A failed step's multipliers are no start for the next one.
            self.lambda.fill(0.0);
            self.lambda_dt = 0.0;
        }
        outcome
    }
}

impl FastProjection {
    /// Step and project for n coordinates with the constraint tolerance and iteration limit
    /// of `settings` (those of RATTLE's position solve and `--project`).
    pub fn with_settings(n: usize, settings: &IntegratorSettings) -> Self {
        FastProjection {
            tolerance: settings.constraint_tolerance,
            max_iterations: settings.constraint_max_iterations,
            iterations_max: 0,
            iterations_total: 0,
            factorizations_total: 0,
            constraint_work: 0.0,
            acceleration: vec![0.0; n],
            q_start: vec![0.0; n],
            newton: None,
            end: StepEnd::default(),
            aside_lambda: Vec::new(),
            aside_lambda_dt: 0.0,
            aside_end: StepEnd::default(),
        }
    }

    /// Projection iterations summed over every step so far.
    pub fn projection_iterations_total(&self) -> u64 {
        self.iterations_total
    }

    /// Factorizations of the projection's Newton matrix summed over every step so far (one
    /// for each iteration that does not reuse the last, two where the signed curvature made
    /// it indefinite; see the module).
    pub fn factorizations_total(&self) -> u64 {
        self.factorizations_total
    }
}

impl Integrator for FastProjection {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let cs = constraints_of(system, IntegratorKind::FastProjection)?;
        // The last multipliers start the projection only from bitwise the state the last
        // step ended at: a state set from outside, an impact or a retry after a failure
        // starts from lambda = 0, a fresh integrator's bits (stale multipliers may lead
        // Newton's method to another stationary point of the projection).
        let from_own_end = self.end.take_continued_by(s);
        let (t0, t1) = (s.t, s.t + dt);
        cs.unconstrained_acceleration(t0, &s.q, &s.qdot, &mut self.acceleration)?;
        self.q_start.copy_from_slice(&s.q);
        // v* = v + h a (kept in `acceleration`), q* = q + h v*.
        for ((q, v), a) in s.q.iter_mut().zip(&s.qdot).zip(&mut self.acceleration) {
            *a = v + dt * *a;
            *q += dt * *a;
        }
        let constrained = cs.n_constraints() > 0;
        let iterations = if constrained {
            if !self.newton.as_ref().is_some_and(|newton| newton.fits(cs)) {
                self.newton = Some(ProjectionNewton::new(cs));
            }
            let newton = self.newton.as_mut().expect("built above");
            if !from_own_end {
                newton.lambda.fill(0.0);
                newton.lambda_dt = 0.0;
            }
            newton.project(
                cs,
                t1,
                &mut s.q,
                dt,
                (self.tolerance, self.max_iterations),
                &mut self.factorizations_total,
            )?
        } else {
            0
        };
        self.iterations_max = self.iterations_max.max(iterations);
        self.iterations_total += iterations as u64;
        for ((v, q), q0) in s.qdot.iter_mut().zip(&s.q).zip(&self.q_start) {
            *v = (q - q0) / dt;
        }
        if constrained {
            cs.project_velocities(t1, &s.q, &mut s.qdot)?;
        }
        // The constraint impulses M (v_{n+1} - v*) do the work sum Delta p . v_{n+1} (the
        // step's own first-order rule: the velocity projection's share is mu . C_t exactly,
        // zero for fixed constraints; the position projection's is of the step's order).
        let w = cs.inverse_mass();
        self.constraint_work = 0.0;
        if cs.n_constraints() > 0 {
            for ((v, v_free), w) in s.qdot.iter().zip(&self.acceleration).zip(w) {
                if *w > 0.0 {
                    self.constraint_work += (v - v_free) / w * v;
                }
            }
        }
        s.t = t1;
        if constrained {
            self.end.record(s);
        }
        Ok(())
    }

    fn newton_iterations_max(&self) -> Option<usize> {
        Some(self.iterations_max)
    }

    fn constraint_work(&self) -> f64 {
        self.constraint_work
    }

    fn set_aside_carry(&mut self) {
        if let Some(newton) = &self.newton {
            self.aside_lambda.clone_from(&newton.lambda);
            self.aside_lambda_dt = newton.lambda_dt;
        }
        self.aside_end.clone_from(&self.end);
    }

    fn continued(&mut self, stepped: f64, state: &State, amended: bool) {
        self.end.continued(stepped, state, amended);
    }

    fn iterations_total(&self) -> Option<u64> {
        Some(self.iterations_total)
    }

    /// The multipliers set aside, unless the rows changed since (then they start at 0).
    fn take_back_carry(&mut self) {
        if let Some(newton) = &mut self.newton {
            if newton.lambda.len() == self.aside_lambda.len() {
                newton.lambda.clone_from(&self.aside_lambda);
                newton.lambda_dt = self.aside_lambda_dt;
                self.end.clone_from(&self.aside_end);
            } else {
                newton.lambda_dt = 0.0;
                self.end.forget();
            }
        }
    }
}
