//! Step and project with fast projection (Goldenthal, Harmon, Fattal, Bercovier & Grinspun,
//! "Efficient Simulation of Inextensible Cloth", SIGGRAPH 2007): an unconstrained symplectic
//! Euler step, then the positions projected onto the constraints along J(q^k)^T at every
//! iterate, and the velocity taken from the positions' change:
//!
//! ```text
//! v*      = v_n + h W F(q_n, v_n)                        (applied forces only)
//! q^0     = q_n + h v*
//! q^{k+1} = q^k - W J(q^k)^T (J(q^k) W J(q^k)^T)^-1 C(q^k, t_{n+1})   until C = 0
//! v_{n+1} = (q_{n+1} - q_n) / h,  then projected onto J(q_{n+1}) v + C_t = 0
//! ```
//!
//! Order 1, implicit form only. Every constraint force comes from the projection at the
//! step's end (the constraint direction is implicit), so the step is stable however stiff
//! the constraints make the motion: a cloth's taut threads oscillate across themselves at
//! up to 2 sqrt(T / (m L)) (2,300 rad/s for the shipped 50 x 50 cloth), and RATTLE, explicit
//! in those directions like every Verlet method, needs h omega < 2 (h = 1/2,300 s) where
//! this step takes a frame (1/60 s) and holds every rod to the tolerance
//! (`tests/fast_projection.rs`: a 12 x 12 cloth at dt F = 4.2, where RATTLE fails within a
//! second). The price is damping: modes the step cannot resolve (h omega >> 1) lose their
//! energy, as in every game engine's cloth (on that cloth the energy never rose above its
//! start in 1,200 steps). For accuracy and energy on systems RATTLE can step, RATTLE stays
//! the method.
//!
//! On the shipped 50 x 50 cloth at dt = 1/60 the projection converges, but slowly: its
//! Gauss-Newton steps ignore the curvature of the taut, nearly collinear threads (the
//! tension's transverse stiffness), overshoot, and take up to ~170 iterations (quadratic
//! only at the end) where a 12 x 12 cloth takes 3 to 7. A Newton iteration on the
//! projection's optimality conditions (M + sum_i lambda_i d2C_i, J^T; J, 0) would add that
//! curvature; it is not built yet.
//!
//! The position projection is [`ConstrainedSystem::project_positions`] (each iteration
//! assembles and factors J(q^k) W J(q^k)^T by the formulation's solver: sparse LDL^T with
//! its symbolic analysis reused, or the path elimination on chains), the velocity
//! projection [`ConstrainedSystem::project_velocities`]. A projection that does not
//! converge within the iteration limit is [`StepError::ProjectionFailed`], never a silent
//! continuation.

use super::{constraints_of, Integrator, IntegratorKind, IntegratorSettings};
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Step and project (see the module).
pub struct FastProjection {
    tolerance: f64,
    max_iterations: usize,
    /// Most projection iterations any step has needed so far
    iterations_max: usize,
    /// Projection iterations of all steps so far
    iterations_total: u64,
    /// The work of the last step's constraint impulses (see `constraint_work`)
    constraint_work: f64,
    /// a, then v* (n)
    acceleration: Vec<f64>,
    /// q_n (n)
    q_start: Vec<f64>,
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
            constraint_work: 0.0,
            acceleration: vec![0.0; n],
            q_start: vec![0.0; n],
        }
    }

    /// Projection iterations summed over every step so far.
    pub fn projection_iterations_total(&self) -> u64 {
        self.iterations_total
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
        let (t0, t1) = (s.t, s.t + dt);
        cs.unconstrained_acceleration(t0, &s.q, &s.qdot, &mut self.acceleration)?;
        self.q_start.copy_from_slice(&s.q);
        // v* = v + h a (kept in `acceleration`), q^0 = q + h v*.
        for ((q, v), a) in s.q.iter_mut().zip(&s.qdot).zip(&mut self.acceleration) {
            *a = v + dt * *a;
            *q += dt * *a;
        }
        let iterations = if cs.n_constraints() > 0 {
            cs.project_positions(t1, &mut s.q, self.tolerance, self.max_iterations)?
        } else {
            0
        };
        self.iterations_max = self.iterations_max.max(iterations);
        self.iterations_total += iterations as u64;
        for ((v, q), q0) in s.qdot.iter_mut().zip(&s.q).zip(&self.q_start) {
            *v = (q - q0) / dt;
        }
        if cs.n_constraints() > 0 {
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
        Ok(())
    }

    fn newton_iterations_max(&self) -> Option<usize> {
        Some(self.iterations_max)
    }

    fn constraint_work(&self) -> f64 {
        self.constraint_work
    }
}
