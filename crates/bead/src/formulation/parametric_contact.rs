//! The parametric form of a system with one unilateral constraint: in generalized
//! coordinates q on the track, in Cartesian coordinates x in flight.
//!
//! The state is [q (n_q); x (n_x)] with rates [qdot; v]: on the track q moves by Lagrange's
//! equations (the [`Parametric`] form) and x stands still; in flight x moves by the implicit
//! form of the rest of the system (the other constraints hold; without any, a = W F) and q
//! stands still. The simulation moves the state between the two at a switch
//! (`simulate/contact.rs`): at a detach x, v = x(q), J qdot + x_t; at a landing q is fitted
//! to x (the closest point of the map, x(q) = x at the landing) and qdot to v (the
//! mass-weighted projection onto the map's velocities). What is read from outside (particle
//! positions, the observation, the constraint forces) is the motion's, whichever half holds
//! it. The switching functions, the impact and the flight are those of the implicit form
//! ([`Contact`]) at the particles' state:
//!
//! ```text
//! on the track:  g = s lambda, the implicit form's multiplier at x(q), J qdot + x_t
//! in flight:     g = s C(x)
//! ```

use std::sync::Arc;

use super::contact::Unilateral;
use super::{
    Contact, Feedback, FormulationError, Nonconservation, Observation, Parametric,
    SecondOrderSystem, SingularSearch, State, StepError, Subject,
};
use super::{Formulation, Method};
use crate::model::{ConstraintEval, Force, System, UnilateralRow};

/// The parametric form with one unilateral constraint (see the module documentation).
pub struct ParametricContact {
    parametric: Parametric,
    /// The implicit form, its unilateral row attached on the track and detached in flight.
    implicit: Contact,
    system: Arc<System>,
    n_q: usize,
    names: Vec<String>,
    /// The external forces changed since the implicit form last copied them.
    external_stale: bool,
    eval: ConstraintEval,
    x: Vec<f64>,
    v: Vec<f64>,
    zeros: Vec<f64>,
}

impl ParametricContact {
    /// The parametric form of `system`, which has exactly one unilateral constraint.
    pub fn new(system: Arc<System>) -> Result<ParametricContact, FormulationError> {
        let parametric = Parametric::new(Arc::clone(&system))?;
        if system.unilateral().len() != 1 {
            return Err(FormulationError::UnilateralParametric);
        }
        let n_q = parametric.coordinate_names().len();
        let n_x = system.n_coords();
        let mut names = parametric.coordinate_names().to_vec();
        names.extend((0..n_x).map(|k| system.coordinate_name(k)));
        Ok(ParametricContact {
            eval: system.constraints().workspace(),
            implicit: Contact::new(Arc::clone(&system), Feedback::default()),
            n_q,
            names,
            external_stale: false,
            x: vec![0.0; n_x],
            v: vec![0.0; n_x],
            zeros: vec![0.0; n_q],
            parametric,
            system,
        })
    }

    /// The number of generalized coordinates (the state's first part).
    pub fn n_q(&self) -> usize {
        self.n_q
    }

    fn flying(&self) -> bool {
        self.implicit.detached()[0]
    }

    /// Particle positions and velocities of state (t, q, qdot) into `self.x`, `self.v`.
    fn particles(&mut self, t: f64, q: &[f64], qdot: &[f64]) {
        let n_q = self.n_q;
        if self.flying() {
            self.x.copy_from_slice(&q[n_q..]);
            self.v.copy_from_slice(&qdot[n_q..]);
        } else {
            let (mut x, mut v) = (std::mem::take(&mut self.x), std::mem::take(&mut self.v));
            self.parametric
                .particle_state(t, &q[..n_q], &qdot[..n_q], &mut x, &mut v);
            (self.x, self.v) = (x, v);
        }
    }

    /// On the track the map must hold the unilateral constraint (it traces what the
    /// particle lands on): an error when x(q) at `x` is off it by more than 1e-6 of the
    /// scene's size, rather than a motion through it.
    fn on_the_map(&mut self, t: f64, x: &[f64]) -> Result<(), StepError> {
        let size = x.iter().fold(1.0_f64, |m, c| m.max(c.abs()));
        let (_, offset) = self.implicit.separations(t, x)[0];
        if offset > 1e-6 * size {
            return Err(StepError::Contact {
                t,
                message: format!(
                    "the parametric map does not hold the unilateral {} (x(q) is {} off it): on the track the map must trace the constraint the particle lands on; use the implicit method",
                    self.implicit.row_name(0),
                    crate::readable(offset)
                ),
            });
        }
        Ok(())
    }

    /// The implicit form, with the external forces of the parametric one.
    fn implicit(&mut self) -> &mut Contact {
        if self.external_stale {
            let external = self.implicit.external_forces_mut();
            external.clear();
            external.extend_from_slice(self.parametric.external_forces());
            self.external_stale = false;
        }
        &mut self.implicit
    }
}

impl Unilateral for ParametricContact {
    fn unilateral(&self) -> &[UnilateralRow] {
        self.implicit.unilateral()
    }

    fn detached(&self) -> &[bool] {
        self.implicit.detached()
    }

    fn set_detached(&mut self, k: usize, detached: bool) -> Result<(), StepError> {
        self.implicit.set_detached(k, detached)
    }

    fn switching_values(
        &mut self,
        t: f64,
        q: &[f64],
        v: &[f64],
        g: &mut [f64],
    ) -> Result<(), StepError> {
        self.particles(t, q, v);
        let (x, xdot) = (std::mem::take(&mut self.x), std::mem::take(&mut self.v));
        let result = if self.flying() {
            self.implicit().switching_values(t, &x, &xdot, g)
        } else {
            self.on_the_map(t, &x)
                .and_then(|()| self.implicit().switching_values(t, &x, &xdot, g))
        };
        (self.x, self.v) = (x, xdot);
        result
    }

    fn normal_motion(
        &mut self,
        k: usize,
        t: f64,
        q: &[f64],
        v: &[f64],
    ) -> Result<(f64, f64), StepError> {
        self.particles(t, q, v);
        let (x, xdot) = (std::mem::take(&mut self.x), std::mem::take(&mut self.v));
        let result = self.implicit().normal_motion(k, t, &x, &xdot);
        (self.x, self.v) = (x, xdot);
        result
    }

    /// In flight only (an impact is a landing): on the state's x half.
    fn impact(
        &mut self,
        k: usize,
        e: f64,
        t: f64,
        q: &[f64],
        qdot: &mut [f64],
    ) -> Result<f64, StepError> {
        let n_q = self.n_q;
        self.implicit().impact(k, e, t, &q[n_q..], &mut qdot[n_q..])
    }

    fn separations(&mut self, t: f64, q: &[f64]) -> Vec<(f64, f64)> {
        let zeros = vec![0.0; q.len()];
        self.particles(t, q, &zeros);
        let x = std::mem::take(&mut self.x);
        let result = self.implicit.separations(t, &x);
        self.x = x;
        result
    }

    fn row_name(&self, k: usize) -> String {
        self.implicit.row_name(k)
    }

    fn parametric_layout(&self) -> Option<usize> {
        Some(self.n_q)
    }
}

impl SecondOrderSystem for ParametricContact {
    fn n_coords(&self) -> usize {
        self.n_q + self.system.n_coords()
    }

    fn acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        let n_q = self.n_q;
        if self.flying() {
            a[..n_q].fill(0.0);
            self.implicit()
                .acceleration(t, &q[n_q..], &qdot[n_q..], &mut a[n_q..])
        } else {
            a[n_q..].fill(0.0);
            self.parametric
                .acceleration(t, &q[..n_q], &qdot[..n_q], &mut a[..n_q])
        }
    }
}

impl Formulation for ParametricContact {
    fn method(&self) -> Method {
        Method::Parametric
    }

    fn system(&self) -> &System {
        &self.system
    }

    fn shared_system(&self) -> Arc<System> {
        Arc::clone(&self.system)
    }

    /// [q0; x0] and [qdot0; v0]: the map's start and the particles' (the same motion when
    /// the start is on the track; the particles' when it is in flight).
    fn initial_state(&self) -> State {
        let mut state = self.parametric.initial_state();
        let (x, v) = self.system.initial_particle_state();
        state.q.extend(x);
        state.qdot.extend(v);
        state
    }

    fn coordinate_names(&self) -> &[String] {
        &self.names
    }

    fn particle_state(&mut self, t: f64, q: &[f64], qdot: &[f64], x: &mut [f64], xdot: &mut [f64]) {
        self.particles(t, q, qdot);
        x.copy_from_slice(&self.x);
        xdot.copy_from_slice(&self.v);
    }

    fn evaluations(&self) -> u64 {
        self.parametric.evaluations() + self.implicit.evaluations()
    }

    fn external_forces_mut(&mut self) -> &mut Vec<Force> {
        self.external_stale = true;
        self.parametric.external_forces_mut()
    }

    fn external_forces(&self) -> &[Force] {
        self.parametric.external_forces()
    }

    fn power(&self, q: &[f64], qdot: &[f64], qddot: &[f64]) -> f64 {
        let n_q = self.n_q;
        if self.flying() {
            self.implicit.power(&q[n_q..], &qdot[n_q..], &qddot[n_q..])
        } else {
            self.parametric
                .power(&q[..n_q], &qdot[..n_q], &qddot[..n_q])
        }
    }

    fn constraint_forces(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        qddot: &mut [f64],
        multipliers: &mut Vec<f64>,
        force: &mut [f64],
    ) -> Result<(), StepError> {
        let n_q = self.n_q;
        if self.flying() {
            qddot[..n_q].fill(0.0);
            self.implicit().constraint_forces(
                t,
                &q[n_q..],
                &qdot[n_q..],
                &mut qddot[n_q..],
                multipliers,
                force,
            )?;
            // The parametric form reports no multipliers (it has no rows of its own).
            multipliers.clear();
            return Ok(());
        }
        qddot[n_q..].fill(0.0);
        self.parametric.constraint_forces(
            t,
            &q[..n_q],
            &qdot[..n_q],
            &mut qddot[..n_q],
            multipliers,
            force,
        )
    }

    fn applied_power(&self, q: &[f64], qdot: &[f64]) -> f64 {
        // Called with the particles' x and v (see Parametric::applied_power).
        self.parametric.applied_power(q, qdot)
    }

    fn nonconservation(&self) -> Vec<Nonconservation> {
        let mut out = self.parametric.nonconservation();
        out.push(Nonconservation::Impacts(self.row_name(0)));
        out
    }

    fn new_observation(&self) -> Observation {
        self.parametric.new_observation()
    }

    fn observe(&mut self, t: f64, q: &[f64], qdot: &[f64], out: &mut Observation) {
        let n_q = self.n_q;
        if !self.flying() {
            self.parametric.observe(t, &q[..n_q], &qdot[..n_q], out);
            return;
        }
        // The map's columns at the q it stands at (they stop nothing), the particles' own
        // state, and C there counted only where it penetrates.
        let zeros = std::mem::take(&mut self.zeros);
        self.parametric.observe(t, &q[..n_q], &zeros, out);
        self.zeros = zeros;
        out.x.copy_from_slice(&q[n_q..]);
        out.xdot.copy_from_slice(&qdot[n_q..]);
        let set = self.system.constraints();
        let values = set.residuals(t, &q[n_q..], &mut self.eval);
        out.constraints.copy_from_slice(values);
        let u = self.implicit.unilateral()[0];
        if u.side.sign() * out.constraints[u.row] >= 0.0 {
            out.constraints[u.row] = 0.0;
        }
    }

    fn gradient_subject(&self, row: usize) -> Subject {
        self.parametric.gradient_subject(row)
    }

    fn gradient_position(&self, row: usize, q: &[f64]) -> Vec<(String, f64)> {
        self.parametric.gradient_position(row, &q[..self.n_q])
    }

    fn row_variables(&self, row: usize, q: &[f64]) -> Vec<f64> {
        self.parametric.row_variables(row, &q[..self.n_q])
    }

    fn locate_singular_point(&self, row: usize, t: f64, q: &[f64]) -> SingularSearch {
        self.parametric
            .locate_singular_point(row, t, &q[..self.n_q])
    }

    fn row_step_length(&self, row: usize, q: &[f64], before: &[f64]) -> f64 {
        self.parametric
            .row_step_length(row, &q[..self.n_q], &before[..self.n_q])
    }

    fn row_never_singular(&self, row: usize) -> bool {
        self.parametric.row_never_singular(row)
    }

    fn contact_mut(&mut self) -> Option<&mut dyn Unilateral> {
        Some(self)
    }

    fn contact(&self) -> Option<&dyn Unilateral> {
        Some(self)
    }
}
