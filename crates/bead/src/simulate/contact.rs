//! Unilateral constraints in a run: where a row detaches, where it lands, and the impact.
//!
//! After every fixed step the switching function of each unilateral row is evaluated at the
//! step's end ([`crate::formulation::Unilateral::switching_values`]: s lambda while attached, s
//! C while detached). Where one turned negative, the switch is located on the integrator's
//! own path (the step integrated again from its start over a part of its length, as events
//! are) to 1e-10 of dt by the same root finder; the earliest switch ends that part of the
//! step, which is accepted (monitors, events), then:
//!
//! - a detach leaves the row out of the equations from there (the state is the bracket's
//!   end where s lambda <= 0);
//! - a landing (the bracket's end where s C >= 0, just before contact) applies the impact
//!   impulse, which turns the row's normal velocity s Cdot into -e s Cdot; the bead then
//!   stays attached when it lands softly: when its free normal acceleration s Cddot pushes it
//!   back (< 0) and the rebound would land again within one step, 2 e |s Cdot| / |s Cddot| <
//!   dt (a second, plastic impulse takes the rest of the normal velocity). Otherwise it
//!   bounces. The kinetic energy an impact takes is work in the energy ledger.
//!
//! A switch is looked for where a switching function is below zero at the end of a step (or
//! of its part after a switch): a sign change that comes back within one step (a graze past
//! a bump narrower than the step) is not seen.
//!
//! The step then goes on from the switch to its planned end, in the new mode (the time grid
//! is kept). A step switches at most [`MAX_SWITCHES_PER_STEP`] times (a contact chattering
//! faster is an error that says so). Events are screened on each part of a step; a jump of
//! the velocities at an impact is not a crossing (the events are re-armed after it).

use super::event::Bracket;
use super::{split, RunError, Simulation, State, Stepper};
use crate::formulation::{Formulation, StepError, Unilateral};

/// The most switches of unilateral constraints one step may take.
pub const MAX_SWITCHES_PER_STEP: u32 = 64;

/// What happened to a unilateral constraint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SwitchKind {
    /// Its force would have pulled: the particle left it.
    Detach,
    /// It reached the constraint and stays on it (a soft landing).
    Land,
    /// It reached the constraint and bounced off.
    Bounce,
}

impl SwitchKind {
    /// `detach`, `land` or `bounce`.
    pub fn name(self) -> &'static str {
        match self {
            SwitchKind::Detach => "detach",
            SwitchKind::Land => "land",
            SwitchKind::Bounce => "bounce",
        }
    }
}

/// A switch of a unilateral constraint ([`Simulation::contact_switches`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ContactSwitch {
    pub t: f64,
    /// The constraint's name.
    pub constraint: String,
    pub kind: SwitchKind,
    /// s Cdot (the normal velocity, > 0 leaving) before and after the switch.
    pub normal_velocity: (f64, f64),
    /// The kinetic energy the switch took: 0 for a detach, >= 0 for an impact on a fixed
    /// constraint (negative when a moving one, C(x, t), gives the particle energy).
    pub dissipated: f64,
    /// Particle positions at the switch (n_coords).
    pub x: Vec<f64>,
}

/// The switches of a run's unilateral constraints, counted ([`super::RunStats::contacts`]).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct ContactCounts {
    pub detaches: u64,
    pub landings: u64,
    pub bounces: u64,
    /// The kinetic energy the impacts took, in all (see [`ContactSwitch::dissipated`]).
    pub dissipated: f64,
}

impl ContactCounts {
    /// The counts of `switches`.
    pub fn of(switches: &[ContactSwitch]) -> ContactCounts {
        let mut counts = ContactCounts::default();
        for s in switches {
            counts.add(s.kind, s.dissipated);
        }
        counts
    }

    /// Count one more switch.
    pub fn add(&mut self, kind: SwitchKind, dissipated: f64) {
        match kind {
            SwitchKind::Detach => self.detaches += 1,
            SwitchKind::Land => self.landings += 1,
            SwitchKind::Bounce => self.bounces += 1,
        }
        self.dissipated += dissipated;
    }
}

/// A simulation's working space for its unilateral rows.
pub(super) struct ContactState {
    g_start: Vec<f64>,
    g_end: Vec<f64>,
    /// Per row, s C where it last detached or bounced when that was below 0 (within the
    /// root's tolerance past it), else 0: a detached row's switching function is s C minus
    /// this, so that it starts a flight at >= 0 and its landing is a crossing.
    offset: Vec<f64>,
    /// The step's end while a switch in it is looked for.
    hi: State,
}

impl ContactState {
    pub(super) fn new(rows: usize) -> ContactState {
        ContactState {
            g_start: vec![0.0; rows],
            g_end: vec![0.0; rows],
            offset: vec![0.0; rows],
            hi: State::default(),
        }
    }
}

/// The mode of the unilateral rows at a start (t, x, v): a row off its constraint on the
/// allowed side (s C > 0 and more than 1e-12 of the scene's size off it, as an offset
/// |C| / |J|) starts detached, one on it attached unless its force would pull there
/// (s lambda < 0). A start on the wrong side of one by more than 1e-6 of the scene's size is
/// an error (then every row is left attached); closer, it is on the constraint (a placed
/// state's residual).
pub(super) fn initial_mode(
    formulation: &mut dyn Formulation,
    state: &State,
    n: usize,
) -> Result<(), StepError> {
    let Some(contact) = formulation.contact_mut() else {
        return Ok(());
    };
    let rows = contact.unilateral().len();
    let (t, x, v) = (state.t, &state.q[..n], &state.qdot[..n]);
    // Detached, the parametric form reads the particles' own start (its state's x part).
    for k in 0..rows {
        contact.set_detached(k, true)?;
    }
    let size = x.iter().fold(1.0_f64, |m, c| m.max(c.abs()));
    let separations = contact.separations(t, x);
    if let Some(k) = separations
        .iter()
        .position(|&(separation, offset)| separation < 0.0 && offset > 1e-6 * size)
    {
        for j in 0..rows {
            contact.set_detached(j, false)?;
        }
        let u = contact.unilateral()[k];
        return Err(StepError::Contact {
            t,
            message: format!(
                "the start is on the wrong side of the unilateral {}: C = {}, and its side is {} (C {} 0)",
                contact.row_name(k),
                crate::readable(separations[k].0 * u.side.sign()),
                u.side.name(),
                if u.side.sign() > 0.0 { ">=" } else { "<=" }
            ),
        });
    }
    for (k, (separation, offset)) in separations.into_iter().enumerate() {
        contact.set_detached(k, separation > 0.0 && offset > 1e-12 * size)?;
    }
    // On it: attached while its force pushes.
    let mut g = vec![0.0; rows];
    contact.switching_values(t, x, v, &mut g)?;
    for (k, g) in g.into_iter().enumerate() {
        if !contact.detached()[k] && g < 0.0 {
            contact.set_detached(k, true)?;
        }
    }
    Ok(())
}

/// Before a state is placed at positions `x` (time t): detach the unilateral rows `x` is off
/// (on their allowed side, as [`initial_mode`] tells), attach the others, so that the
/// placement projects onto the attached rows only. Returns the modes before, to restore
/// when the placement fails.
pub(super) fn mode_for_positions(
    formulation: &mut dyn Formulation,
    t: f64,
    x: &[f64],
) -> Result<Vec<bool>, StepError> {
    let Some(contact) = formulation.contact_mut() else {
        return Ok(Vec::new());
    };
    let before = contact.detached().to_vec();
    let size = x.iter().fold(1.0_f64, |m, c| m.max(c.abs()));
    for (k, (separation, offset)) in contact.separations(t, x).into_iter().enumerate() {
        contact.set_detached(k, separation > 0.0 && offset > 1e-12 * size)?;
    }
    Ok(before)
}

/// Detach unilateral row `k` (`detached` false) or apply its impact and attach it when it
/// lands softly (see the module documentation), at (t, q) with velocities `qdot` (changed
/// by an impact): the switch and (s Cdot before, after).
fn switch_row(
    contact: &mut dyn Unilateral,
    k: usize,
    detached: bool,
    dt: f64,
    (t, q, qdot): (f64, &[f64], &mut [f64]),
) -> Result<(SwitchKind, (f64, f64)), StepError> {
    if !detached {
        let (u, _) = contact.normal_motion(k, t, q, qdot)?;
        contact.set_detached(k, true)?;
        return Ok((SwitchKind::Detach, (u, u)));
    }
    let e = contact.unilateral()[k].restitution;
    let u_before = contact.impact(k, e, t, q, qdot)?;
    let (u_after, normal_acceleration) = contact.normal_motion(k, t, q, qdot)?;
    // Soft: pushed back, and the rebound would land again within one step.
    let soft =
        normal_acceleration < 0.0 && (u_after <= 0.0 || 2.0 * u_after < -normal_acceleration * dt);
    if soft {
        contact.impact(k, 0.0, t, q, qdot)?;
        contact.set_detached(k, false)?;
        return Ok((SwitchKind::Land, (u_before, 0.0)));
    }
    Ok((SwitchKind::Bounce, (u_before, u_after)))
}

impl Simulation {
    /// The switches of unilateral constraints from the start (or the last reset) up to the
    /// current time, in time order (every one is kept, as event crossings are).
    pub fn contact_switches(&self) -> &[ContactSwitch] {
        &self.contact_switches
    }

    /// [`Simulation::contact_switches`] counted, kept as they happen.
    pub fn contact_counts(&self) -> &ContactCounts {
        &self.contact_counts
    }

    /// Per unilateral row ([`crate::model::System::unilateral`]), whether it is detached now
    /// (empty without unilateral rows).
    pub fn detached(&self) -> Vec<bool> {
        self.formulation
            .contact()
            .map(|c| c.detached().to_vec())
            .unwrap_or_default()
    }

    /// A switch that failed: the modes back as they were, the run at the accepted state of
    /// the switch (saved as `previous`), and the error.
    fn fail_switch(&mut self, modes: &[bool], error: StepError) -> RunError {
        if let Some(contact) = self.formulation.contact_mut() {
            for (k, &d) in modes.iter().enumerate() {
                // Modes it had (each built before): cannot fail.
                let _ = contact.set_detached(k, d);
            }
        }
        self.unprime();
        self.fail(error)
    }

    /// The particles' positions and velocities at the integrator's state.
    fn particles(&mut self) -> (Vec<f64>, Vec<f64>) {
        let n = self.n;
        let coordinates = self.formulation.system().n_coords();
        let (mut x, mut v) = (vec![0.0; coordinates], vec![0.0; coordinates]);
        let (q, qdot) = (&self.state.q[..n], &self.state.qdot[..n]);
        self.formulation
            .particle_state(self.state.t, q, qdot, &mut x, &mut v);
        (x, v)
    }

    /// The parametric form landed (its state's x part holds the particles): q fitted to x
    /// (the map's point closest in the kinetic metric, seeded where q stood), qdot to v (the
    /// mass-weighted projection onto the map's velocities), the x part at rest.
    fn fit_parametric(&mut self, n_q: usize) -> Result<(), StepError> {
        let n = self.n;
        let t = self.state.t;
        let system = self.formulation.shared_system();
        let map = system.parametric().expect("a parametric form");
        let masses: Vec<f64> = system.inverse_mass().iter().map(|w| 1.0 / w).collect();
        let x = self.state.q[n_q..n].to_vec();
        let v = self.state.qdot[n_q..n].to_vec();
        let seed = self.state.q[..n_q].to_vec();
        let fitted = super::restart::fit_coordinates(map, t, &[&seed, map.initial()], &x, &masses)
            .and_then(|q| super::restart::fit_rates(map, t, &q, &v, &masses).map(|qdot| (q, qdot)));
        let (q, qdot) = fitted.map_err(|e| StepError::Contact {
            t,
            message: format!("the landing point has no coordinates on the parametric map: {e}"),
        })?;
        // The map must pass through the landing point (it traces the constraint landed on).
        let mapped = super::restart::map_positions(map, t, &q);
        let size = x.iter().fold(1.0_f64, |m, c| m.max(c.abs()));
        let off = mapped
            .iter()
            .zip(&x)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        if off > 1e-6 * size {
            let contact = self.formulation.contact().expect("a contact formulation");
            return Err(StepError::Contact {
                t,
                message: format!(
                    "the parametric map does not hold the unilateral {}: its closest point to where the particle lands is {} away; the map must trace the constraint the particle lands on; use the implicit method",
                    contact.row_name(0),
                    crate::readable(off)
                ),
            });
        }
        self.state.q[..n_q].copy_from_slice(&q);
        self.state.qdot[..n_q].copy_from_slice(&qdot);
        self.state.qdot[n_q..n].fill(0.0);
        Ok(())
    }

    /// The switching functions at the integrator's state into `g_end` (or `g_start`).
    fn switching(&mut self, at_start: bool) -> Result<(), StepError> {
        let n = self.n;
        let contact_state = self.contact.as_mut().expect("a contact simulation");
        let g = if at_start {
            &mut contact_state.g_start
        } else {
            &mut contact_state.g_end
        };
        let contact = self
            .formulation
            .contact_mut()
            .expect("a contact formulation");
        let (t, q, qdot) = (self.state.t, &self.state.q[..n], &self.state.qdot[..n]);
        contact.switching_values(t, q, qdot, g)?;
        for ((g, &detached), offset) in g
            .iter_mut()
            .zip(contact.detached())
            .zip(&contact_state.offset)
        {
            if detached {
                *g -= offset;
            }
        }
        Ok(())
    }

    /// A fixed step integrated to `t_end` with unilateral rows: accept it up to the first
    /// switch in it, switch, and go on to `t_end` (see the module documentation).
    pub(super) fn contact_step(&mut self, t_end: f64) -> Result<(), RunError> {
        let mut switches = 0;
        loop {
            let found = self.find_switch()?;
            self.steps += 1;
            self.accept()?;
            let Some(k) = found else {
                return Ok(());
            };
            if self.stopped_at_event {
                // A terminal event before the switch: the next step finds it again.
                return Ok(());
            }
            self.apply_switch(k)?;
            switches += 1;
            if self.state.t >= t_end {
                return Ok(());
            }
            if switches >= MAX_SWITCHES_PER_STEP {
                return Err(RunError::Step(StepError::Contact {
                    t: self.state.t,
                    message: format!(
                        "the unilateral constraints switched {switches} times within one step (a contact chattering faster than the step): reduce dt"
                    ),
                }));
            }
            self.integrate_fixed(t_end)?;
        }
    }

    /// After a step to `state` from `previous`: the earliest unilateral row whose switching
    /// function turned negative in it, with the state moved to its switch (located on the
    /// integrator's path); `None` when none did (the state is the step's end).
    fn find_switch(&mut self) -> Result<Option<usize>, RunError> {
        if let Err(e) = self.switching(false) {
            return Err(self.fail(e));
        }
        let contact = self.contact.as_ref().expect("a contact simulation");
        if contact.g_end.iter().all(|&g| g >= 0.0) {
            return Ok(None);
        }
        let (t0, t1) = (self.previous.t, self.state.t);
        let mut end = std::mem::take(&mut self.contact.as_mut().expect("contact").hi);
        end.clone_from(&self.state);
        self.restore_state_only();
        if let Err(e) = self.switching(true) {
            return Err(self.fail(e));
        }
        let detached = self.detached();
        let contact = self.contact.as_mut().expect("a contact simulation");
        contact.hi = end;
        // (row, g at the start, g at the end), read before locating overwrites g_end.
        let candidates: Vec<(usize, f64, f64)> = (0..detached.len())
            .filter(|&k| contact.g_end[k] < 0.0)
            .map(|k| (k, contact.g_start[k], contact.g_end[k]))
            .collect();
        let mut best: Option<(f64, usize, State)> = None;
        for (k, g0, g1) in candidates {
            let located = if g0 > 0.0 {
                self.locate_switch(k, Bracket::new(t0, -g0, t1, -g1))?
            } else if detached[k] {
                // Already on the wrong side at the start (a hop shorter than a step, or
                // drift): an impact at the step's end if it is closing in by then.
                let mut end = self.contact.as_ref().expect("contact").hi.clone();
                end.t = t1;
                let approaching = {
                    let n = self.n;
                    let contact = self.formulation.contact_mut().expect("contact");
                    match contact.normal_motion(k, t1, &end.q[..n], &end.qdot[..n]) {
                        Ok((u, _)) => u < 0.0,
                        Err(e) => return Err(self.fail(e)),
                    }
                };
                if !approaching {
                    continue;
                }
                end
            } else {
                // Attached and pulling at the start already: detach there.
                self.previous.clone()
            };
            if best.as_ref().is_none_or(|(t, _, _)| located.t < *t) {
                best = Some((located.t, k, located));
            }
        }
        let contact = self.contact.as_ref().expect("a contact simulation");
        match best {
            None => {
                self.state.clone_from(&contact.hi);
                Ok(None)
            }
            Some((_, k, state)) => {
                self.state = state;
                Ok(Some(k))
            }
        }
    }

    /// Re-integrate the step from its start to the root of unilateral row `k`'s switching
    /// function (bracketed as h = -g: h < 0 before, h >= 0 after) to the event tolerance;
    /// the state at the located time: after the root for a detach (s lambda <= 0), before
    /// it for a landing (s C >= 0). `state` is at the step's start on return.
    fn locate_switch(&mut self, k: usize, mut bracket: Bracket) -> Result<State, RunError> {
        let detached = self.detached()[k];
        let mut lo = self.previous.clone();
        let mut hi = self.contact.as_ref().expect("contact").hi.clone();
        let tolerance = self.event_tolerance(bracket.hi);
        while !bracket.done(tolerance) {
            let t = bracket.next();
            self.restore_state_only();
            if let Err(e) = self.partial_step(t) {
                return Err(self.fail(e));
            }
            if let Err(e) = self.switching(false) {
                return Err(self.fail(e));
            }
            let h = -contact_g(self, k, false);
            if h >= 0.0 {
                hi.clone_from(&self.state);
            } else {
                lo.clone_from(&self.state);
            }
            bracket.update(t, h);
        }
        self.restore_state_only();
        Ok(if detached { lo } else { hi })
    }

    /// Switch unilateral row `k` at the current state (accepted): detach it, or apply the
    /// impact and attach it when it lands softly; for the parametric form move the state
    /// between q and x; record the switch and observe the state.
    fn apply_switch(&mut self, k: usize) -> Result<(), RunError> {
        let n = self.n;
        let dt = self.config.dt;
        let t = self.state.t;
        let tracks_work = self.ledger.is_some();
        let modes_before = self.detached();
        let detached = modes_before[k];
        // The accepted state at the switch: where a failed switch leaves the run, its modes
        // as they were.
        self.save();
        self.output_behind = false;
        let (x_before, v_before) = self.particles();
        let system = self.formulation.shared_system();
        let before = system.kinetic_energy(&v_before);
        let contact = self
            .formulation
            .contact_mut()
            .expect("a contact formulation");
        let layout = contact.parametric_layout();
        let (q, qdot) = (&self.state.q[..n], &mut self.state.qdot[..n]);
        let (kind, normal_velocity) = match switch_row(contact, k, detached, dt, (t, q, qdot)) {
            Ok(r) => r,
            Err(e) => return Err(self.fail_switch(&modes_before, e)),
        };
        if let Some(n_q) = layout {
            // The parametric form: x, v from the map at a detach; q, qdot fitted at a landing.
            match kind {
                SwitchKind::Detach => {
                    self.state.q[n_q..n].copy_from_slice(&x_before);
                    self.state.qdot[n_q..n].copy_from_slice(&v_before);
                    self.state.qdot[..n_q].fill(0.0);
                }
                SwitchKind::Land => {
                    if let Err(e) = self.fit_parametric(n_q) {
                        return Err(self.fail_switch(&modes_before, e));
                    }
                }
                SwitchKind::Bounce => {}
            }
        }
        let (x_after, v_after) = self.particles();
        let dissipated = before - system.kinetic_energy(&v_after);
        if tracks_work {
            // The work the impact did: the kinetic energy it changed.
            self.state.qdot[n] -= dissipated;
        }
        let contact = self
            .formulation
            .contact_mut()
            .expect("a contact formulation");
        let separation = contact.separations(t, &self.state.q[..n])[k].0;
        let now_detached = contact.detached()[k];
        self.contact.as_mut().expect("contact").offset[k] = if now_detached {
            separation.min(0.0)
        } else {
            0.0
        };
        let name = contact.row_name(k);
        self.contact_counts.add(kind, dissipated);
        self.contact_switches.push(ContactSwitch {
            t,
            constraint: name,
            kind,
            normal_velocity,
            dissipated,
            x: x_after,
        });
        self.unprime();
        let (q, qdot, work) = split(&self.state, n);
        self.monitor
            .observe(&mut *self.formulation, t, q, qdot, work);
        self.rearm_events();
        Ok(())
    }
}

impl Simulation {
    /// dopri5's step from `previous` to `state` was taken with unilateral rows: when a
    /// switching function turned negative in it, locate the earliest switch on the step's
    /// dense output, take the step back, integrate again to exactly that time (accepted
    /// steps), and switch there; otherwise accept the step.
    pub(super) fn adaptive_contact_step(&mut self) -> Result<(), RunError> {
        if let Err(e) = self.switching(false) {
            return Err(self.fail(e));
        }
        if self
            .contact
            .as_ref()
            .expect("contact")
            .g_end
            .iter()
            .all(|&g| g >= 0.0)
        {
            self.steps += 1;
            return self.accept();
        }
        let n = self.n;
        let (t0, t1) = (self.previous.t, self.state.t);
        let end = self.state.clone();
        self.restore_state_only();
        if let Err(e) = self.switching(true) {
            return Err(self.fail(e));
        }
        let detached = self.detached();
        let contact = self.contact.as_ref().expect("contact");
        let candidates: Vec<(usize, f64, f64)> = (0..detached.len())
            .filter(|&k| contact.g_end[k] < 0.0)
            .map(|k| (k, contact.g_start[k], contact.g_end[k]))
            .collect();
        let mut best: Option<(f64, usize)> = None;
        for (k, g0, g1) in candidates {
            let te = if g0 > 0.0 {
                let mut bracket = Bracket::new(t0, -g0, t1, -g1);
                let tolerance = self.event_tolerance(t1);
                while !bracket.done(tolerance) {
                    let t = bracket.next();
                    if let Stepper::Adaptive(dopri) = &self.stepper {
                        dopri.interpolate(t, &mut self.state.q, &mut self.state.qdot);
                    }
                    self.state.t = t;
                    if let Err(e) = self.switching(false) {
                        return Err(self.fail(e));
                    }
                    bracket.update(t, -contact_g(self, k, false));
                }
                if detached[k] {
                    bracket.lo
                } else {
                    bracket.hi
                }
            } else if detached[k] {
                let contact = self.formulation.contact_mut().expect("contact");
                match contact.normal_motion(k, t1, &end.q[..n], &end.qdot[..n]) {
                    Ok((u, _)) if u < 0.0 => t1,
                    Ok(_) => continue,
                    Err(e) => return Err(self.fail(e)),
                }
            } else {
                t0
            };
            if best.is_none_or(|(t, _)| te < t) {
                best = Some((te, k));
            }
        }
        self.restore_state_only();
        let Some((te, k)) = best else {
            self.state.clone_from(&end);
            self.steps += 1;
            return self.accept();
        };
        // Integrate again to the switch: the integrator's own steps, accepted.
        self.unprime();
        while self.state.t < te {
            self.adaptive_advance(te)?;
            self.steps += 1;
            self.accept()?;
            if self.pending_event.is_some() {
                // A terminal event before the switch: the switch is found again later.
                return Ok(());
            }
        }
        self.apply_switch(k)
    }
}

/// g of unilateral row `k` at the step's start or end (as last evaluated).
fn contact_g(simulation: &Simulation, k: usize, at_start: bool) -> f64 {
    let contact = simulation.contact.as_ref().expect("a contact simulation");
    if at_start {
        contact.g_start[k]
    } else {
        contact.g_end[k]
    }
}
