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
    /// The state at which `acceleration[0]` was evaluated by [`Integrator::prime`], if it
    /// was and no step has used it since: t, then q and qdot (2n)
    primed: Option<f64>,
    primed_state: Vec<f64>,
}

impl Rk4 {
    pub fn new(n: usize) -> Self {
        let buffers = || [vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        Rk4 {
            velocity: buffers(),
            acceleration: buffers(),
            q_stage: vec![0.0; n],
            primed: None,
            primed_state: vec![0.0; 2 * n],
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
        // The first stage evaluated by `prime` at bitwise this state is this one.
        let primed = self.primed.take().is_some_and(|t| {
            let n = s.q.len();
            let (q, qdot) = self.primed_state.split_at(n);
            t.to_bits() == s.t.to_bits() && same_bits(q, &s.q) && same_bits(qdot, &s.qdot)
        });
        if !primed {
            system.acceleration(s.t, &s.q, v1, a1)?;
        }
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

    fn prime(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &State,
    ) -> Option<Result<(), StepError>> {
        self.primed = None;
        let result = system.acceleration(s.t, &s.q, &s.qdot, &mut self.acceleration[0]);
        if result.is_ok() {
            let n = s.q.len();
            self.primed_state[..n].copy_from_slice(&s.q);
            self.primed_state[n..].copy_from_slice(&s.qdot);
            self.primed = Some(s.t);
        }
        Some(result)
    }

    fn unprime(&mut self) {
        self.primed = None;
    }
}

/// Whether two slices hold the same bits.
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}
