//! Explicit midpoint (RK2): evaluate at the half step, advance with the midpoint slopes.
//!
//! ```text
//! q_m = q + dt/2 qdot,   qdot_m = qdot + dt/2 f(t, q, qdot)
//! q' = q + dt qdot_m,    qdot' = qdot + dt f(t + dt/2, q_m, qdot_m)
//! ```
//! Order 2.

use super::{axpy_into, Integrator};
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Explicit midpoint method.
pub struct Midpoint {
    acceleration: Vec<f64>,
    q_mid: Vec<f64>,
    qdot_mid: Vec<f64>,
}

impl Midpoint {
    pub fn new(n: usize) -> Self {
        Midpoint {
            acceleration: vec![0.0; n],
            q_mid: vec![0.0; n],
            qdot_mid: vec![0.0; n],
        }
    }
}

impl Integrator for Midpoint {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        system.acceleration(s.t, &s.q, &s.qdot, &mut self.acceleration)?;
        axpy_into(&mut self.q_mid, &s.q, 0.5 * dt, &s.qdot);
        axpy_into(&mut self.qdot_mid, &s.qdot, 0.5 * dt, &self.acceleration);
        system.acceleration(
            s.t + 0.5 * dt,
            &self.q_mid,
            &self.qdot_mid,
            &mut self.acceleration,
        )?;
        for (q, v) in s.q.iter_mut().zip(&self.qdot_mid) {
            *q += dt * v;
        }
        for (v, a) in s.qdot.iter_mut().zip(&self.acceleration) {
            *v += dt * a;
        }
        s.t += dt;
        Ok(())
    }
}
