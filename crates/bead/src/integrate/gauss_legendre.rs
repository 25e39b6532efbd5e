//! The two-stage Gauss-Legendre collocation method (Hairer, Lubich & Wanner, *Geometric
//! Numerical Integration*, II.1.3) on the first-order form y = (q, qdot), y' = (qdot, f):
//!
//! ```text
//! c = 1/2 -+ sqrt(3)/6     A = | 1/4              1/4 - sqrt(3)/6 |     b = (1/2, 1/2)
//!                              | 1/4 + sqrt(3)/6  1/4             |
//! ```
//! Order 4, A-stable, symmetric and symplectic: on the parametric form (a reversible
//! Lagrangian system) its energy error stays bounded instead of drifting, the energy-conserving
//! counterpart of RK4.
//!
//! The stage equations are implicit. Written for the second-order structure, the unknowns are
//! the two stage accelerations A_i (2 x n):
//!
//! ```text
//! V_i = qdot + h sum_j a_ij A_j,   Q_i = q + h sum_j a_ij V_j,   A_i = f(t + c_i h, Q_i, V_i)
//! q' = q + h sum_i b_i V_i,        qdot' = qdot + h sum_i b_i A_i
//! ```
//! and are solved by fixed-point iteration on A, started from the previous step's collocation
//! polynomial (or from A_i = f(t, q, qdot) on the first step). No Jacobian
//! of f is needed (the project takes no finite differences of the physics), each iteration
//! costs two evaluations of f, and the iteration contracts by a factor of about
//! h ||df/dqdot|| + h^2 ||df/dq|| per sweep: it converges when dt is small against the
//! system's time scales (omega dt well below 1, the same regime in which an order-4 method is
//! accurate). It stops when the increment's max norm is at most `implicit_tolerance` times the max norm
//! of A (default 1e-14, i.e. to round-off), or when the increments stop shrinking at a level
//! that is already round-off (below 1e-10 of A); it fails with
//! [`StepError::ImplicitStageFailed`] ("reduce dt") after `implicit_max_iterations` sweeps
//! otherwise (both in [`IntegratorSettings`]).

// Stage loops index the Butcher tableau as the formulas do (a_ij, c_i, b_i).
#![allow(clippy::needless_range_loop)]

use super::fixed_point::{increment_and_scale, FixedPoint};
use super::{Integrator, IntegratorSettings};
use crate::formulation::{SecondOrderSystem, State, StepError};

const SQRT3_6: f64 = 0.288_675_134_594_812_882_254_574_390_251; // sqrt(3)/6
const C: [f64; 2] = [0.5 - SQRT3_6, 0.5 + SQRT3_6];
const A: [[f64; 2]; 2] = [[0.25, 0.25 - SQRT3_6], [0.25 + SQRT3_6, 0.25]];
const B: [f64; 2] = [0.5, 0.5];

/// Two-stage Gauss-Legendre (order 4, symplectic) with fixed-point stage iteration.
pub struct GaussLegendre {
    /// Stage accelerations A_i, current iterate (2 x n)
    acceleration: [Vec<f64>; 2],
    /// Stage accelerations f(Q_i, V_i) of the current iterate (2 x n)
    next: [Vec<f64>; 2],
    /// Stage velocities V_i (2 x n)
    velocity: [Vec<f64>; 2],
    /// Stage positions Q_i (2 x n)
    position: [Vec<f64>; 2],
    /// Stopping rule of the stage iteration
    rule: FixedPoint,
    /// Most stage iterations any step so far has needed
    iterations_max: usize,
    /// The state this integrator last produced and the step that produced it, to start the
    /// next step's iteration from the last collocation polynomial when the run continues
    end_q: Vec<f64>,
    end_qdot: Vec<f64>,
    end_h: f64,
    warm: bool,
}

impl GaussLegendre {
    /// For n coordinates, with the implicit-solve tolerance and iteration limit of `settings`.
    pub fn new(n: usize, settings: &IntegratorSettings) -> Self {
        let pair = || [vec![0.0; n], vec![0.0; n]];
        GaussLegendre {
            acceleration: pair(),
            next: pair(),
            velocity: pair(),
            position: pair(),
            rule: FixedPoint {
                method: "gauss-legendre",
                equations: "stage equations",
                tolerance: settings.implicit_tolerance,
                max_iterations: settings.implicit_max_iterations.max(1),
            },
            iterations_max: 0,
            end_q: vec![0.0; n],
            end_qdot: vec![0.0; n],
            end_h: 0.0,
            warm: false,
        }
    }

    /// V_i and Q_i from the current stage accelerations.
    fn stages(&mut self, q: &[f64], qdot: &[f64], h: f64) {
        let [a1, a2] = &self.acceleration;
        for i in 0..2 {
            let v = &mut self.velocity[i];
            for k in 0..q.len() {
                v[k] = qdot[k] + h * (A[i][0] * a1[k] + A[i][1] * a2[k]);
            }
        }
        let [v1, v2] = &self.velocity;
        for i in 0..2 {
            let x = &mut self.position[i];
            for k in 0..q.len() {
                x[k] = q[k] + h * (A[i][0] * v1[k] + A[i][1] * v2[k]);
            }
        }
    }
}

impl GaussLegendre {
    /// The most fixed-point sweeps of the stage equations any step so far has needed.
    pub fn iterations_max(&self) -> usize {
        self.iterations_max
    }
}

impl Integrator for GaussLegendre {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let h = dt;
        // Starting values. When this step continues the last one (same h, the state it
        // produced), extrapolate the last step's stage accelerations linearly to this step's
        // nodes 1 + c_i: that is the derivative of the last collocation polynomial (degree 2
        // in q), HLW VIII.6.1, and saves a few sweeps. Otherwise A_i = f(t, q, qdot). The
        // start changes only how fast the iteration converges, not what it converges to.
        let continuing =
            self.warm && self.end_h == h && self.end_q == s.q && self.end_qdot == s.qdot;
        self.warm = false;
        {
            let [a1, a2] = &mut self.acceleration;
            if continuing {
                for k in 0..a1.len() {
                    let slope = (a2[k] - a1[k]) / (C[1] - C[0]);
                    let base = a1[k] - slope * C[0];
                    a1[k] = base + slope * (1.0 + C[0]);
                    a2[k] = base + slope * (1.0 + C[1]);
                }
            } else {
                system.acceleration(s.t, &s.q, &s.qdot, a1)?;
                a2.copy_from_slice(a1);
            }
        }
        let mut previous = f64::INFINITY;
        let mut iterations = 0;
        loop {
            iterations += 1;
            self.stages(&s.q, &s.qdot, h);
            for i in 0..2 {
                system.acceleration(
                    s.t + C[i] * h,
                    &self.position[i],
                    &self.velocity[i],
                    &mut self.next[i],
                )?;
            }
            let (mut increment, mut scale) = (0.0, 0.0);
            for i in 0..2 {
                (increment, scale) =
                    increment_and_scale(&self.next[i], &self.acceleration[i], (increment, scale));
            }
            std::mem::swap(&mut self.acceleration, &mut self.next);
            if self
                .rule
                .converged(s.t, iterations, increment, previous, scale)?
            {
                self.iterations_max = self.iterations_max.max(iterations as usize);
                break;
            }
            previous = increment;
        }
        // Stage velocities of the converged accelerations (the positions are not needed).
        let [a1, a2] = &self.acceleration;
        for k in 0..s.q.len() {
            let v1 = s.qdot[k] + h * (A[0][0] * a1[k] + A[0][1] * a2[k]);
            let v2 = s.qdot[k] + h * (A[1][0] * a1[k] + A[1][1] * a2[k]);
            s.q[k] += h * (B[0] * v1 + B[1] * v2);
            s.qdot[k] += h * (B[0] * a1[k] + B[1] * a2[k]);
        }
        s.t += dt;
        self.end_q.copy_from_slice(&s.q);
        self.end_qdot.copy_from_slice(&s.qdot);
        self.end_h = h;
        self.warm = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tableau_is_the_gauss_collocation_one() {
        assert!((SQRT3_6 - 3f64.sqrt() / 6.0).abs() <= f64::EPSILON * SQRT3_6);
        // Row sums are the nodes; simplifying assumptions B(4), C(2) hold.
        for i in 0..2 {
            assert!((A[i][0] + A[i][1] - C[i]).abs() < 1e-15);
            let c2: f64 = (0..2).map(|j| A[i][j] * C[j]).sum();
            assert!((c2 - C[i] * C[i] / 2.0).abs() < 1e-15);
        }
        for k in 1..=4 {
            let quad: f64 = (0..2).map(|i| B[i] * C[i].powi(k - 1)).sum();
            assert!((quad - 1.0 / k as f64).abs() < 1e-15, "B({k})");
        }
        // Symplecticity: b_i a_ij + b_j a_ji = b_i b_j.
        for i in 0..2 {
            for j in 0..2 {
                assert!((B[i] * A[i][j] + B[j] * A[j][i] - B[i] * B[j]).abs() < 1e-15);
            }
        }
    }
}
