//! The implicit form of a system with unilateral constraints ([`crate::model::Side`]): the
//! rows attached now are the equations, the detached ones are left out.
//!
//! [`Contact`] holds the implicit form of the whole system (every row attached) and, built
//! when first needed, one of the system without each set of detached rows
//! ([`crate::model::System::without_constraints`], compiled like any system: the
//! integrators see an ordinary [`Implicit`], RATTLE included). What the monitors and the
//! outputs read (the observation, the gradients, the names) is the whole system's, with a
//! detached row's value counted only where it is on the wrong side (s C < 0: a penetration
//! is an error, flight is not). When to switch is the simulation's (`simulate/contact.rs`);
//! this file gives it the switching functions and the impact.
//!
//! ```text
//! attached row r:   g_r = s lambda_r      (detach where it turns negative: the row would pull)
//! detached row r:   g_r = s C_r           (land where it reaches 0)
//! impact on row r:  v+ = v- - W J_A^T mu,  (J_A W J_A^T) mu = b,
//!                   b_r = (1 + e) Cdot_r,  b_k = 0 for the other attached rows k
//! ```
//!
//! so that Cdot_r+ = -e Cdot_r- and the other attached rows' Cdot are unchanged; the
//! velocity change is the smallest in the mass metric that does so (the tangential velocity
//! is kept).

use std::sync::Arc;

use super::{
    ConstrainedSystem, ConstraintScales, Feedback, Formulation, Implicit, Method, Nonconservation,
    Observation, SecondOrderSystem, SingularSearch, State, StepError, Subject,
};
use crate::linalg::dense_solve;
use crate::model::{ConstraintEval, Force, System, UnilateralRow};

/// A formulation with unilateral rows, as the simulation switches them
/// (`simulate/contact.rs`): the implicit form ([`Contact`]) and the parametric form with one
/// unilateral constraint ([`super::ParametricContact`]). `q` and `v` are the formulation's
/// state (for the parametric form [q; x], see there).
pub trait Unilateral {
    /// The unilateral rows, in the order of [`Unilateral::detached`].
    fn unilateral(&self) -> &[UnilateralRow];
    /// Per unilateral row, whether it is detached now.
    fn detached(&self) -> &[bool];
    /// Detach (`true`) or attach unilateral row `k`: the equations change; the state is the
    /// caller's to move (the parametric form's, see [`Unilateral::parametric_layout`]).
    fn set_detached(&mut self, k: usize, detached: bool) -> Result<(), StepError>;
    /// The switching function of every unilateral row at (t, q, v) into `g`: s lambda for an
    /// attached row, s C for a detached one.
    fn switching_values(
        &mut self,
        t: f64,
        q: &[f64],
        v: &[f64],
        g: &mut [f64],
    ) -> Result<(), StepError>;
    /// s Cdot of unilateral row `k` and s Cddot of it in the current mode at (t, q, v): how
    /// fast the row separates, and how fast that grows without its force.
    fn normal_motion(
        &mut self,
        k: usize,
        t: f64,
        q: &[f64],
        v: &[f64],
    ) -> Result<(f64, f64), StepError>;
    /// An impact on unilateral row `k` at (t, q) with restitution `e`: the velocities in `v`
    /// change so that the row's Cdot becomes -e times what it was, every other attached
    /// row's unchanged, the change the smallest in the kinetic metric. Returns the row's s
    /// Cdot before.
    fn impact(
        &mut self,
        k: usize,
        e: f64,
        t: f64,
        q: &[f64],
        v: &mut [f64],
    ) -> Result<f64, StepError>;
    /// Per unilateral row at (t, q): s C (> 0 on the allowed side) and the offset |C| / |J|.
    fn separations(&mut self, t: f64, q: &[f64]) -> Vec<(f64, f64)>;
    /// The name of unilateral row `k`'s constraint, e.g. `constraint 1`.
    fn row_name(&self, k: usize) -> String;
    /// For the parametric form, the number n_q of generalized coordinates in its state
    /// [q (n_q); x]; `None` for the implicit form (its state is x).
    fn parametric_layout(&self) -> Option<usize> {
        None
    }
}

/// The most sets of detached rows a [`Contact`] keeps compiled.
const MAX_MODES: usize = 32;

/// One set of detached rows: its system's implicit form, and where each of the whole
/// system's rows is in it.
struct Mode {
    detached: Vec<bool>,
    implicit: Implicit,
    /// Row of the whole system -> row of this mode's system (`None`: detached).
    rows: Vec<Option<usize>>,
}

/// The implicit form of a system with unilateral rows (see the module documentation).
pub struct Contact {
    full: Implicit,
    unilateral: Vec<UnilateralRow>,
    /// Per unilateral row, whether it is detached now.
    detached: Vec<bool>,
    /// The modes built so far (never the all-attached one: that is `full`).
    modes: Vec<Mode>,
    /// The mode in use (`None`: `full`).
    current: Option<usize>,
    feedback: Feedback,
    scaled: bool,
    /// The external forces changed since the current mode last copied them.
    external_stale: bool,
    /// C, Cdot, bias and J of the whole system, for the switching functions and impacts.
    eval: ConstraintEval,
    multipliers: Vec<f64>,
    acceleration: Vec<f64>,
}

impl Contact {
    /// The implicit form of `system` (which has unilateral rows), every row attached.
    pub fn new(system: Arc<System>, feedback: Feedback) -> Contact {
        let unilateral = system.unilateral().to_vec();
        let n = system.n_coords();
        Contact {
            eval: system.constraints().workspace(),
            detached: vec![false; unilateral.len()],
            unilateral,
            modes: Vec::new(),
            current: None,
            feedback,
            scaled: false,
            external_stale: false,
            multipliers: Vec::new(),
            acceleration: vec![0.0; n],
            full: Implicit::new(system, feedback),
        }
    }

    fn active(&mut self) -> &mut Implicit {
        match self.current {
            None => &mut self.full,
            Some(i) => {
                let mode = &mut self.modes[i];
                if self.external_stale {
                    mode.implicit.external.clone_from(&self.full.external);
                    self.external_stale = false;
                }
                &mut mode.implicit
            }
        }
    }

    /// A detached row counts in the observation only where it is on the wrong side.
    fn mask_observation(&self, out: &mut Observation) {
        for (u, &detached) in self.unilateral.iter().zip(&self.detached) {
            if detached && u.side.sign() * out.constraints[u.row] >= 0.0 {
                out.constraints[u.row] = 0.0;
                out.gradients.offset[u.row] = 0.0;
            }
        }
    }
}

impl Unilateral for Contact {
    /// The unilateral rows, in the order of [`Contact::detached`].
    fn unilateral(&self) -> &[UnilateralRow] {
        &self.unilateral
    }

    /// Per unilateral row, whether it is detached now.
    fn detached(&self) -> &[bool] {
        &self.detached
    }

    /// Detach (`true`) or attach unilateral row `k`: the equations switch to the system
    /// without the detached rows, compiled the first time this set of rows is detached.
    fn set_detached(&mut self, k: usize, detached: bool) -> Result<(), StepError> {
        if self.detached[k] == detached {
            return Ok(());
        }
        // The flag changes only once its mode exists (a failed compile changes nothing).
        let mut wanted = self.detached.clone();
        wanted[k] = detached;
        if !wanted.contains(&true) {
            self.detached = wanted;
            self.current = None;
            return Ok(());
        }
        if let Some(i) = self.modes.iter().position(|m| m.detached == wanted) {
            self.detached = wanted;
            self.current = Some(i);
            self.external_stale = true;
            return Ok(());
        }
        let full = self.full.system();
        let drop: Vec<usize> = self
            .unilateral
            .iter()
            .zip(&wanted)
            .filter(|(_, &d)| d)
            .map(|(u, _)| u.constraint)
            .collect();
        let reduced = full
            .without_constraints(&drop)
            .map_err(|e| StepError::Contact {
                t: f64::NAN,
                message: format!("the system without the detached constraints: {e}"),
            })?;
        let mut rows = Vec::with_capacity(full.constraints().n_rows());
        let mut next = 0;
        for r in 0..full.constraints().n_rows() {
            let gone = self
                .unilateral
                .iter()
                .zip(&wanted)
                .any(|(u, &d)| d && u.row == r);
            rows.push(if gone {
                None
            } else {
                next += 1;
                Some(next - 1)
            });
        }
        let reduced = Arc::new(reduced);
        let mut implicit = Implicit::with_solver(reduced.clone(), self.feedback, self.full.solver);
        if self.scaled {
            implicit.set_constraint_scales(Some(ConstraintScales::of(&reduced)));
        }
        implicit.external.clone_from(&self.full.external);
        // A bounded cache: a system of many unilateral rows (a rope of slack links) could
        // visit any of 2^m sets; the oldest mode goes first (it is compiled again if needed).
        if self.modes.len() >= MAX_MODES {
            self.modes.remove(0);
        }
        self.modes.push(Mode {
            detached: wanted.clone(),
            implicit,
            rows,
        });
        self.detached = wanted;
        self.current = Some(self.modes.len() - 1);
        self.external_stale = false;
        Ok(())
    }

    /// The switching function of every unilateral row at (t, x, v) into `g` (see the
    /// module documentation): s lambda for an attached row (from one evaluation of the
    /// acceleration in the current mode, skipped when every row is detached), s C for a
    /// detached one. Evaluates the whole system's constraints into the contact's own
    /// workspace.
    fn switching_values(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        g: &mut [f64],
    ) -> Result<(), StepError> {
        let set = self.full.system().constraints();
        set.evaluate(t, x, v, &mut self.eval);
        if self.detached.contains(&false) {
            let mut a = std::mem::take(&mut self.acceleration);
            let result = self.active().acceleration(t, x, v, &mut a);
            self.acceleration = a;
            result?;
        }
        let rows = self.current.map(|i| &self.modes[i].rows);
        let lambda = match self.current {
            None => self.full.multipliers(),
            Some(i) => self.modes[i].implicit.multipliers(),
        };
        for ((u, &detached), g) in self.unilateral.iter().zip(&self.detached).zip(g) {
            let s = u.side.sign();
            *g = if detached {
                s * self.eval.value[u.row]
            } else {
                let row = rows.map_or(Some(u.row), |rows| rows[u.row]);
                s * row.map_or(f64::NAN, |r| lambda[r])
            };
        }
        Ok(())
    }

    /// s Cdot of unilateral row `k` and s Cddot of it in the current mode at (t, x, v) (one
    /// evaluation of the acceleration): how fast the row separates, and how fast that
    /// grows without its force.
    fn normal_motion(
        &mut self,
        k: usize,
        t: f64,
        x: &[f64],
        v: &[f64],
    ) -> Result<(f64, f64), StepError> {
        let mut a = std::mem::take(&mut self.acceleration);
        let result = self.active().acceleration(t, x, v, &mut a);
        self.acceleration = a;
        result?;
        let set = self.full.system().constraints();
        set.evaluate(t, x, v, &mut self.eval);
        let u = self.unilateral[k];
        let s = u.side.sign();
        let jr: f64 = set
            .row_columns(u.row)
            .iter()
            .zip(&self.eval.jacobian[set.row_entries(u.row)])
            .map(|(&c, &j)| j * self.acceleration[c])
            .sum();
        Ok((
            s * self.eval.velocity[u.row],
            s * (jr + self.eval.bias[u.row]),
        ))
    }

    /// An impact on unilateral row `k` at (t, x) with restitution `e`: the velocities `v`
    /// change by -W J_A^T mu so that the row's Cdot becomes -e times what it was and every
    /// other attached row's Cdot is unchanged (see the module documentation). Returns the
    /// row's s Cdot before.
    fn impact(
        &mut self,
        k: usize,
        e: f64,
        t: f64,
        x: &[f64],
        v: &mut [f64],
    ) -> Result<f64, StepError> {
        let system = self.full.system();
        let set = system.constraints();
        let w = system.inverse_mass();
        set.evaluate(t, x, v, &mut self.eval);
        let landing = self.unilateral[k].row;
        let active: Vec<usize> = (0..set.n_rows())
            .filter(|&r| {
                r == landing
                    || !self
                        .unilateral
                        .iter()
                        .zip(&self.detached)
                        .any(|(u, &d)| d && u.row == r)
            })
            .collect();
        let m = active.len();
        // J_A W J_A^T (dense: impacts are rare and the active sets of contact scenes small).
        let mut matrix = vec![0.0; m * m];
        let mut dense_row = vec![0.0; v.len()];
        for (i, &ri) in active.iter().enumerate() {
            for (&c, &j) in set
                .row_columns(ri)
                .iter()
                .zip(&self.eval.jacobian[set.row_entries(ri)])
            {
                dense_row[c] = j * w[c];
            }
            for (jx, &rj) in active.iter().enumerate() {
                matrix[i * m + jx] = set
                    .row_columns(rj)
                    .iter()
                    .zip(&self.eval.jacobian[set.row_entries(rj)])
                    .map(|(&c, &j)| j * dense_row[c])
                    .sum();
            }
            for &c in set.row_columns(ri) {
                dense_row[c] = 0.0;
            }
        }
        let before = self.eval.velocity[landing];
        let mut mu: Vec<f64> = active
            .iter()
            .map(|&r| {
                if r == landing {
                    (1.0 + e) * before
                } else {
                    0.0
                }
            })
            .collect();
        if dense_solve(m, &mut matrix, &mut mu).is_err() {
            return Err(StepError::Contact {
                t,
                message: format!(
                    "the impact on {} cannot be resolved: its gradient vanishes there or depends on the attached constraints'",
                    set.name_of_row(landing)
                ),
            });
        }
        for (&r, &mu) in active.iter().zip(&mu) {
            for (&c, &j) in set
                .row_columns(r)
                .iter()
                .zip(&self.eval.jacobian[set.row_entries(r)])
            {
                v[c] -= w[c] * j * mu;
            }
        }
        Ok(self.unilateral[k].side.sign() * before)
    }

    /// Per unilateral row at (t, x): s C (> 0 on the allowed side) and the offset |C| / |J|.
    fn separations(&mut self, t: f64, x: &[f64]) -> Vec<(f64, f64)> {
        let set = self.full.system().constraints();
        set.gradient(t, x, &mut self.eval);
        self.unilateral
            .iter()
            .map(|u| {
                let c = self.eval.value[u.row];
                let norm = self.eval.jacobian[set.row_entries(u.row)]
                    .iter()
                    .map(|j| j * j)
                    .sum::<f64>()
                    .sqrt();
                (u.side.sign() * c, c.abs() / norm)
            })
            .collect()
    }

    /// The name of unilateral row `k`'s constraint, e.g. `constraint 1`.
    fn row_name(&self, k: usize) -> String {
        let set = self.full.system().constraints();
        set.name_of_row(self.unilateral[k].row).to_string()
    }
}

impl SecondOrderSystem for Contact {
    fn n_coords(&self) -> usize {
        self.full.n_coords()
    }

    fn acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError> {
        self.active().acceleration(t, q, qdot, a)
    }

    fn velocity_dependent(&self) -> bool {
        self.full.velocity_dependent()
    }

    fn as_constrained(&mut self) -> Option<&mut dyn ConstrainedSystem> {
        Some(self.active())
    }
}

impl Formulation for Contact {
    fn method(&self) -> Method {
        Method::Implicit
    }

    fn system(&self) -> &System {
        self.full.system()
    }

    fn shared_system(&self) -> Arc<System> {
        self.full.shared_system()
    }

    fn initial_state(&self) -> State {
        self.full.initial_state()
    }

    fn coordinate_names(&self) -> &[String] {
        &[]
    }

    fn particle_state(&mut self, t: f64, q: &[f64], qdot: &[f64], x: &mut [f64], xdot: &mut [f64]) {
        self.full.particle_state(t, q, qdot, x, xdot)
    }

    fn evaluations(&self) -> u64 {
        self.full.evaluations()
            + self
                .modes
                .iter()
                .map(|m| m.implicit.evaluations())
                .sum::<u64>()
    }

    fn set_constraint_scales(&mut self, scales: Option<ConstraintScales>) {
        self.scaled = scales.is_some();
        for mode in &mut self.modes {
            let scales = scales
                .as_ref()
                .map(|_| ConstraintScales::of(mode.implicit.system()));
            mode.implicit.set_constraint_scales(scales);
        }
        self.full.set_constraint_scales(scales);
    }

    fn external_forces_mut(&mut self) -> &mut Vec<Force> {
        self.external_stale = true;
        self.full.external_forces_mut()
    }

    fn external_forces(&self) -> &[Force] {
        self.full.external_forces()
    }

    fn power(&self, q: &[f64], qdot: &[f64], qddot: &[f64]) -> f64 {
        match self.current {
            None => self.full.power(q, qdot, qddot),
            Some(i) => self.modes[i].implicit.power(q, qdot, qddot),
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
        let Some(i) = self.current else {
            return self
                .full
                .constraint_forces(t, q, qdot, qddot, multipliers, force);
        };
        let mut reduced = std::mem::take(&mut self.multipliers);
        self.active()
            .constraint_forces(t, q, qdot, qddot, &mut reduced, force)?;
        multipliers.clear();
        multipliers.extend(
            self.modes[i]
                .rows
                .iter()
                .map(|r| r.map_or(0.0, |r| reduced[r])),
        );
        self.multipliers = reduced;
        Ok(())
    }

    fn applied_power(&self, q: &[f64], qdot: &[f64]) -> f64 {
        self.full.applied_power(q, qdot)
    }

    fn nonconservation(&self) -> Vec<Nonconservation> {
        let mut out = self.full.nonconservation();
        let set = self.full.system().constraints();
        out.extend(
            self.unilateral
                .iter()
                .map(|u| Nonconservation::Impacts(set.name_of_row(u.row).to_string())),
        );
        out
    }

    fn new_observation(&self) -> Observation {
        self.full.new_observation()
    }

    fn observe(&mut self, t: f64, q: &[f64], qdot: &[f64], out: &mut Observation) {
        self.full.observe(t, q, qdot, out);
        self.mask_observation(out);
    }

    fn observe_accelerated(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        out: &mut Observation,
    ) -> bool {
        // Only the whole system's own evaluation has every row's C and J.
        self.current.is_none() && self.full.observe_accelerated(t, q, qdot, out)
    }

    fn gradient_subject(&self, row: usize) -> Subject {
        self.full.gradient_subject(row)
    }

    fn gradient_position(&self, row: usize, q: &[f64]) -> Vec<(String, f64)> {
        self.full.gradient_position(row, q)
    }

    fn row_variables(&self, row: usize, q: &[f64]) -> Vec<f64> {
        self.full.row_variables(row, q)
    }

    fn locate_singular_point(&self, row: usize, t: f64, q: &[f64]) -> SingularSearch {
        self.full.locate_singular_point(row, t, q)
    }

    fn row_step_length(&self, row: usize, q: &[f64], before: &[f64]) -> f64 {
        self.full.row_step_length(row, q, before)
    }

    /// A unilateral row is not watched for singular points: in flight its gradient may
    /// vanish anywhere off the curve (a circle's at its centre).
    fn row_never_singular(&self, row: usize) -> bool {
        self.full.row_never_singular(row) || self.unilateral.iter().any(|u| u.row == row)
    }

    fn contact_mut(&mut self) -> Option<&mut dyn Unilateral> {
        Some(self)
    }

    fn contact(&self) -> Option<&dyn Unilateral> {
        Some(self)
    }

    fn active_system(&self) -> &System {
        match self.current {
            None => self.full.system(),
            Some(i) => self.modes[i].implicit.system(),
        }
    }
}
