//! Symplectic (semi-implicit) Euler: qdot' = qdot + dt f(t, q, qdot), q' = q + dt qdot'.
//! Order 1; symplectic for separable Hamiltonians, so energy errors stay bounded there.

use super::Integrator;
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Symplectic Euler (velocity first, then position with the new velocity).
pub struct SymplecticEuler {
    /// f(t, q, qdot) (n)
    acceleration: Vec<f64>,
}

impl SymplecticEuler {
    pub fn new(n: usize) -> Self {
        SymplecticEuler {
            acceleration: vec![0.0; n],
        }
    }
}

impl Integrator for SymplecticEuler {
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
            *v += dt * a;
            *q += dt * *v;
        }
        s.t += dt;
        Ok(())
    }
}
