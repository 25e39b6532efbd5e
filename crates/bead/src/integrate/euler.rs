//! Explicit (forward) Euler: q' = q + dt qdot, qdot' = qdot + dt f(t, q, qdot).
//! Order 1; energy grows on oscillators. The article's "fails within a second".

use super::Integrator;
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Explicit Euler.
pub struct Euler {
    /// f(t, q, qdot) (n)
    acceleration: Vec<f64>,
}

impl Euler {
    pub fn new(n: usize) -> Self {
        Euler {
            acceleration: vec![0.0; n],
        }
    }
}

impl Integrator for Euler {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        system.acceleration(s.t, &s.q, &s.qdot, &mut self.acceleration)?;
        for ((q, v), a) in
            s.q.iter_mut()
                .zip(s.qdot.iter_mut())
                .zip(&self.acceleration)
        {
            *q += dt * *v;
            *v += dt * a;
        }
        s.t += dt;
        Ok(())
    }
}
