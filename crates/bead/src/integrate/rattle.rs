//! RATTLE (Andersen 1983; Leimkuhler & Reich, *Simulating Hamiltonian Dynamics*, ch. 7):
//! velocity Verlet with the holonomic constraints C(q, t) = 0 enforced at the position and at
//! the velocity level by Lagrange multipliers. With the applied acceleration a = W F(q):
//!
//! ```text
//! v_half  = v_n + h/2 (a_n + W J(q_n)^T lambda)
//! q_{n+1} = q_n + h v_half,            C(q_{n+1}, t_{n+1}) = 0        (solve for lambda)
//! v_{n+1} = v_half + h/2 (a_{n+1} + W J(q_{n+1})^T mu),
//!           J(q_{n+1}) v_{n+1} + C_t(q_{n+1}, t_{n+1}) = 0           (solve for mu)
//! ```
//! Order 2, symmetric and symplectic on the constraint manifold (for forces a = a(q)): the
//! energy error stays bounded, and the constraint holds after every step to the solver
//! tolerance, without drift and without feedback.
//!
//! **Position solve (SHAKE).** Write q(nu) = q_pred - W J(q_n)^T nu with the unconstrained
//! predictor q_pred = q_n + h v_n + h^2/2 a_n (nu = -h^2/2 lambda). The correction direction
//! stays W J(q_n)^T, as the method requires; nu solves C(q(nu), t_{n+1}) = 0 by Newton's method
//! with the exact Jacobian of that map, the non-symmetric m x m matrix
//! J(q^k) W J(q_n)^T (re-evaluated at each iterate q^k, solved by Gaussian elimination with
//! partial pivoting). Convergence is quadratic: from the predictor, whose residual is O(h^2),
//! two or three iterations reach round-off at ordinary step sizes. (The simplified
//! quasi-Newton matrix J(q_n) W J(q_n)^T would converge only linearly, with a rate of order
//! h |v| |d2C| / |J|.) The loop stops when max_i |C_i| <= `tolerance` (absolute, units of C);
//! needing more than `max_iterations` Newton steps, or a NaN residual, is
//! [`StepError::ProjectionFailed`], never a silent continuation.
//!
//! **Velocity solve.** Linear in mu: the mass-weighted projection of
//! v_half + h/2 a_{n+1} onto J v = -C_t, done by [`ConstrainedSystem::project_velocities`] (the
//! symmetric J W J^T at q_{n+1}, the formulation's SPD solver, singular rows named).
//!
//! **Forces.** a_{n+1} is evaluated at (q_{n+1}, v_half), a_n at (q_n, v_n). For forces that
//! depend only on q this is RATTLE exactly; with velocity-dependent forces (drag) it is the
//! explicit variant and not symplectic, which is expected for a dissipative system.
//!
//! RATTLE works on the constraints themselves, so it needs the implicit form: on a system
//! without [`SecondOrderSystem::as_constrained`] (the parametric form) each step fails with
//! [`StepError::NeedsConstraints`]. Buffers that depend on the number of constraints m are
//! sized on the first step; later steps allocate nothing.

use super::Integrator;
use crate::formulation::{ConstrainedSystem, SecondOrderSystem, State, StepError};
use crate::linalg::solve_general;

/// RATTLE with a Newton solve for the position multipliers.
pub struct Rattle {
    tolerance: f64,
    max_iterations: usize,
    /// Most Newton iterations any step has needed so far.
    iterations_max: usize,
    /// a (n)
    acceleration: Vec<f64>,
    /// q_n (n)
    q_start: Vec<f64>,
    /// W (n)
    inverse_mass: Vec<f64>,
    /// J(q_n), dense row-major (m x n)
    jacobian_start: Vec<f64>,
    /// J(q^k), dense row-major (m x n)
    jacobian: Vec<f64>,
    /// J(q^k) W J(q_n)^T (m x m)
    matrix: Vec<f64>,
    /// C(q^k), then the Newton increment (m)
    residual: Vec<f64>,
    /// Accumulated nu (m)
    nu: Vec<f64>,
    /// Largest entry of each column of the matrix (m)
    column_scale: Vec<f64>,
}

impl Rattle {
    /// RATTLE for n coordinates: the position solve stops at max_i |C_i| <= `tolerance`
    /// (absolute) and fails after `max_iterations` Newton iterations.
    pub fn new(n: usize, tolerance: f64, max_iterations: usize) -> Self {
        Rattle {
            tolerance,
            max_iterations,
            iterations_max: 0,
            acceleration: vec![0.0; n],
            q_start: vec![0.0; n],
            inverse_mass: vec![0.0; n],
            jacobian_start: Vec::new(),
            jacobian: Vec::new(),
            matrix: Vec::new(),
            residual: Vec::new(),
            nu: Vec::new(),
            column_scale: Vec::new(),
        }
    }

    /// Size the m-dependent buffers (allocates only when m changes, i.e. on the first step).
    fn reserve(&mut self, n: usize, m: usize) {
        if self.residual.len() != m {
            self.jacobian_start = vec![0.0; m * n];
            self.jacobian = vec![0.0; m * n];
            self.matrix = vec![0.0; m * m];
            self.residual = vec![0.0; m];
            self.nu = vec![0.0; m];
            self.column_scale = vec![0.0; m];
        }
    }

    /// Newton iterations for nu: q <- q - W J(q_n)^T dnu until max|C(q, t)| <= tolerance.
    /// Returns the number of iterations.
    fn solve_positions(
        &mut self,
        cs: &mut dyn ConstrainedSystem,
        t: f64,
        q: &mut [f64],
    ) -> Result<usize, StepError> {
        let n = q.len();
        let m = self.residual.len();
        self.nu.fill(0.0);
        let mut iterations = 0;
        loop {
            cs.constraint_values(t, q, &mut self.residual);
            let residual = max_abs(&self.residual);
            if residual <= self.tolerance {
                return Ok(iterations);
            }
            if iterations >= self.max_iterations || residual.is_nan() {
                return Err(StepError::ProjectionFailed {
                    t,
                    iterations,
                    residual,
                });
            }
            cs.constraint_jacobian(t, q, &mut self.jacobian);
            // A = J(q^k) W J(q_n)^T
            for i in 0..m {
                let row_i = &self.jacobian[i * n..(i + 1) * n];
                for j in 0..m {
                    let row_j = &self.jacobian_start[j * n..(j + 1) * n];
                    let mut sum = 0.0;
                    for k in 0..n {
                        sum += row_i[k] * self.inverse_mass[k] * row_j[k];
                    }
                    self.matrix[i * m + j] = sum;
                }
            }
            if let Err(column) = solve_general(
                m,
                &mut self.matrix,
                &mut self.residual,
                &mut self.column_scale,
            ) {
                return Err(cs.singular_constraint(t, column));
            }
            for j in 0..m {
                let d = self.residual[j];
                self.nu[j] += d;
                let row_j = &self.jacobian_start[j * n..(j + 1) * n];
                for k in 0..n {
                    q[k] -= self.inverse_mass[k] * row_j[k] * d;
                }
            }
            iterations += 1;
        }
    }
}

/// max |c_i|, NaN if any is NaN.
fn max_abs(c: &[f64]) -> f64 {
    c.iter().fold(0.0, |m: f64, c| {
        if m.is_nan() || c.is_nan() {
            f64::NAN
        } else {
            m.max(c.abs())
        }
    })
}

impl Integrator for Rattle {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let cs = system
            .as_constrained()
            .ok_or_else(|| StepError::NeedsConstraints {
                what: "rattle".into(),
            })?;
        let n = s.q.len();
        let m = cs.n_constraints();
        self.reserve(n, m);
        self.inverse_mass.copy_from_slice(cs.inverse_mass());
        let (t0, t1, half) = (s.t, s.t + dt, 0.5 * dt);

        // Unconstrained half kick and drift: v_half = v + h/2 a_n, q_pred = q + h v_half.
        cs.unconstrained_acceleration(t0, &s.q, &s.qdot, &mut self.acceleration)?;
        self.q_start.copy_from_slice(&s.q);
        for ((q, v), a) in
            s.q.iter_mut()
                .zip(s.qdot.iter_mut())
                .zip(&self.acceleration)
        {
            *v += half * a;
            *q += dt * *v;
        }
        if m > 0 {
            cs.constraint_jacobian(t0, &self.q_start, &mut self.jacobian_start);
            let iterations = self.solve_positions(cs, t1, &mut s.q)?;
            self.iterations_max = self.iterations_max.max(iterations);
            // v_half += h/2 W J(q_n)^T lambda = -(1/h) W J(q_n)^T nu.
            for (row_j, nu) in self.jacobian_start.chunks_exact(n).zip(&self.nu) {
                let d = nu / dt;
                for ((v, w), jk) in s.qdot.iter_mut().zip(&self.inverse_mass).zip(row_j) {
                    *v -= w * jk * d;
                }
            }
        }
        // Second half kick, then the velocity constraint J v + C_t = 0 (the mu solve).
        cs.unconstrained_acceleration(t1, &s.q, &s.qdot, &mut self.acceleration)?;
        for (v, a) in s.qdot.iter_mut().zip(&self.acceleration) {
            *v += half * a;
        }
        if m > 0 {
            cs.project_velocities(t1, &s.q, &mut s.qdot)?;
        }
        s.t = t1;
        Ok(())
    }

    fn newton_iterations_max(&self) -> Option<usize> {
        Some(self.iterations_max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn general_solve_with_pivoting() {
        // [[0, 2], [3, 1]] z = [4, 5] -> z = [1, 2]
        let mut a = [0.0, 2.0, 3.0, 1.0];
        let mut b = [4.0, 5.0];
        let mut scale = [0.0; 2];
        solve_general(2, &mut a, &mut b, &mut scale).unwrap();
        assert!(
            (b[0] - 1.0).abs() < 1e-15 && (b[1] - 2.0).abs() < 1e-15,
            "{b:?}"
        );
    }

    #[test]
    fn general_solve_names_the_dependent_column() {
        let mut a = [1.0, 2.0, 2.0, 4.0];
        let mut b = [1.0, 1.0];
        let mut scale = [0.0; 2];
        assert_eq!(solve_general(2, &mut a, &mut b, &mut scale), Err(1));
        let mut a = [1.0, 0.0, 0.0, 0.0];
        assert_eq!(solve_general(2, &mut a, &mut b, &mut scale), Err(1));
    }
}
