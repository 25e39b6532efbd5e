//! Velocity Verlet (Störmer-Verlet, leapfrog in velocity form), with an implicit second half
//! kick when the acceleration depends on the velocity:
//!
//! ```text
//! v_half = v + dt/2 f(t, q, v)
//! q'     = q + dt v_half                    (= q + dt v + dt^2/2 f(t, q, v))
//! v'     = v_half + dt/2 f(t + dt, q', v')  (solved for v')
//! ```
//! The velocity update is the trapezoidal rule v' = v + dt/2 (f(t, q, v) + f(t + dt, q', v')),
//! so the method is of order 2 for every f(t, q, qdot), and symmetric (time-reversible): the
//! step with -dt from (q', v') returns to (q, v). When f does not depend on qdot
//! ([`SecondOrderSystem::velocity_dependent`] is false: unconstrained and pinned systems
//! without drag, parametric maps linear in q) the last line is explicit and this is classic
//! velocity Verlet, symplectic for separable Hamiltonians, so that the energy error stays
//! bounded instead of drifting.
//!
//! **The implicit kick.** v' is found by fixed-point iteration on the end acceleration
//! A = f(t + dt, q', v_half + dt/2 A), started from A_0 = f(t + dt, q', v_half) (the explicit
//! kick, which alone would make the method first order: its error dt/2 (f(q', v') - f(q',
//! v_half)) is O(dt^2) per step). Each sweep costs one evaluation of f and contracts by about
//! dt/2 ||df/dqdot||; it stops when the increment's max norm is at most `implicit_tolerance`
//! times max |A| (default 1e-14), or when the increments stop shrinking at round-off, and fails
//! with [`StepError::ImplicitStageFailed`] naming verlet after `implicit_max_iterations`
//! sweeps (both in [`super::IntegratorSettings`]): reduce dt. Cost per step: two evaluations
//! of f on velocity-independent systems, 2 + (sweeps) otherwise: 3 to 9 sweeps on the
//! systems of `tests/physics_orders.rs` at dt = 1/100 to 1/400 s, fewer as dt shrinks.
//!
//! Meant for unconstrained and pinned systems and as the base of RATTLE ([`super::Rattle`]).
//! On the implicit form with curved constraints it is Verlet on the constraint-force ODE,
//! whose acceleration depends on qdot through the constraint bias: order 2, but not symplectic,
//! and the constraint drifts (use `rattle`, or `--project`).

use super::fixed_point::{increment_and_scale, FixedPoint};
use super::{Integrator, IntegratorSettings};
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Velocity Verlet, with the implicit second half kick on velocity-dependent systems.
pub struct Verlet {
    /// f at the start of the step, then the current iterate of the end acceleration A (n)
    acceleration: Vec<f64>,
    /// f at the velocity the current A implies (n)
    next: Vec<f64>,
    /// v_half (n)
    velocity_half: Vec<f64>,
    /// Stopping rule of the implicit kick
    rule: FixedPoint,
    /// Most sweeps of the implicit kick any step so far has needed
    iterations_max: usize,
}

impl Verlet {
    /// For n coordinates with the default [`IntegratorSettings`].
    pub fn new(n: usize) -> Self {
        Self::with_settings(n, &IntegratorSettings::default())
    }

    /// For n coordinates; the implicit kick uses `implicit_tolerance` and
    /// `implicit_max_iterations` of `settings`.
    pub fn with_settings(n: usize, settings: &IntegratorSettings) -> Self {
        Verlet {
            acceleration: vec![0.0; n],
            next: vec![0.0; n],
            velocity_half: vec![0.0; n],
            rule: FixedPoint {
                method: "verlet",
                equations: "velocity half kick v' = v_half + dt/2 f(t + dt, q', v')",
                tolerance: settings.implicit_tolerance,
                max_iterations: settings.implicit_max_iterations.max(1),
            },
            iterations_max: 0,
        }
    }

    /// The most fixed-point sweeps of the implicit velocity kick any step so far has needed
    /// (0 while every step was on a velocity-independent system).
    pub fn iterations_max(&self) -> usize {
        self.iterations_max
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
        let t1 = s.t + dt;
        system.acceleration(s.t, &s.q, &s.qdot, &mut self.acceleration)?;
        for ((q, v), a) in
            s.q.iter_mut()
                .zip(s.qdot.iter_mut())
                .zip(&self.acceleration)
        {
            *v += half * a;
            *q += dt * *v;
        }
        // A_0 = f(t + dt, q', v_half); s.qdot holds v_half.
        system.acceleration(t1, &s.q, &s.qdot, &mut self.acceleration)?;
        if system.velocity_dependent() {
            self.velocity_half.copy_from_slice(&s.qdot);
            let mut previous = f64::INFINITY;
            let mut iterations = 0;
            loop {
                iterations += 1;
                for ((v, vh), a) in s
                    .qdot
                    .iter_mut()
                    .zip(&self.velocity_half)
                    .zip(&self.acceleration)
                {
                    *v = vh + half * a;
                }
                system.acceleration(t1, &s.q, &s.qdot, &mut self.next)?;
                let (increment, scale) =
                    increment_and_scale(&self.next, &self.acceleration, (0.0, 0.0));
                std::mem::swap(&mut self.acceleration, &mut self.next);
                if self
                    .rule
                    .converged(s.t, iterations, increment, previous, scale)?
                {
                    break;
                }
                previous = increment;
            }
            self.iterations_max = self.iterations_max.max(iterations as usize);
            s.qdot.copy_from_slice(&self.velocity_half);
        }
        for (v, a) in s.qdot.iter_mut().zip(&self.acceleration) {
            *v += half * a;
        }
        s.t = t1;
        Ok(())
    }
}
