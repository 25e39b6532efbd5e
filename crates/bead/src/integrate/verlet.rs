//! Velocity Verlet (Störmer-Verlet, leapfrog in velocity form):
//!
//! ```text
//! v_half = v + dt/2 f(t, q, v)
//! q'     = q + dt v_half
//! v'     = v_half + dt/2 f(t + dt, q', v_half)
//! ```
//! Order 2, symmetric, and symplectic for separable Hamiltonians (forces a = a(q)), so that
//! the energy error stays bounded instead of drifting. Two evaluations of f per step (the
//! first could be reused from the previous step when f does not depend on qdot, but the run
//! loop may change the state between steps, e.g. by projection, so it is recomputed).
//!
//! Meant for unconstrained and pinned systems and as the base of RATTLE ([`super::Rattle`]).
//! On the implicit form with constraints it is just Verlet on the constraint-force ODE, whose
//! acceleration depends on qdot through the constraint bias: no longer symplectic and the
//! constraint drifts (use `rattle`, or `--project`). With velocity-dependent forces the second
//! evaluation uses v_half, which keeps the method explicit.

use super::Integrator;
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Velocity Verlet.
pub struct Verlet {
    /// f at the start, then at the end of the step (n)
    acceleration: Vec<f64>,
}

impl Verlet {
    pub fn new(n: usize) -> Self {
        Verlet {
            acceleration: vec![0.0; n],
        }
    }
}

impl Integrator for Verlet {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let half = 0.5 * dt;
        system.acceleration(s.t, &s.q, &s.qdot, &mut self.acceleration)?;
        for ((q, v), a) in
            s.q.iter_mut()
                .zip(s.qdot.iter_mut())
                .zip(&self.acceleration)
        {
            *v += half * a;
            *q += dt * *v;
        }
        system.acceleration(s.t + dt, &s.q, &s.qdot, &mut self.acceleration)?;
        for (v, a) in s.qdot.iter_mut().zip(&self.acceleration) {
            *v += half * a;
        }
        s.t += dt;
        Ok(())
    }
}
