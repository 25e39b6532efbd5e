//! Classic fourth-order Runge-Kutta on the first-order form y = (q, qdot), y' = (qdot, f):
//!
//! ```text
//! k1 = F(t, y)            k2 = F(t + dt/2, y + dt/2 k1)
//! k3 = F(t + dt/2, y + dt/2 k2)    k4 = F(t + dt, y + dt k3)
//! y' = y + dt/6 (k1 + 2 k2 + 2 k3 + k4)
//! ```
//! Order 4, four evaluations per step; not symplectic: on the article's parametric form the
//! energy slowly decays.

use super::{axpy_into, Integrator};
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Classic RK4.
pub struct Rk4 {
    /// Stage velocities (the q-slopes) k_i^q = qdot_i, 4 x n
    velocity: [Vec<f64>; 4],
    /// Stage accelerations k_i^qdot, 4 x n
    acceleration: [Vec<f64>; 4],
    q_stage: Vec<f64>,
}

impl Rk4 {
    pub fn new(n: usize) -> Self {
        let buffers = || [vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        Rk4 {
            velocity: buffers(),
            acceleration: buffers(),
            q_stage: vec![0.0; n],
        }
    }
}

impl Integrator for Rk4 {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let [v1, v2, v3, v4] = &mut self.velocity;
        let [a1, a2, a3, a4] = &mut self.acceleration;
        let q = &mut self.q_stage;
        v1.copy_from_slice(&s.qdot);
        system.acceleration(s.t, &s.q, v1, a1)?;
        axpy_into(q, &s.q, 0.5 * dt, v1);
        axpy_into(v2, &s.qdot, 0.5 * dt, a1);
        system.acceleration(s.t + 0.5 * dt, q, v2, a2)?;
        axpy_into(q, &s.q, 0.5 * dt, v2);
        axpy_into(v3, &s.qdot, 0.5 * dt, a2);
        system.acceleration(s.t + 0.5 * dt, q, v3, a3)?;
        axpy_into(q, &s.q, dt, v3);
        axpy_into(v4, &s.qdot, dt, a3);
        system.acceleration(s.t + dt, q, v4, a4)?;
        let h = dt / 6.0;
        for i in 0..s.q.len() {
            s.q[i] += h * (v1[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]);
            s.qdot[i] += h * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]);
        }
        s.t += dt;
        Ok(())
    }
}
