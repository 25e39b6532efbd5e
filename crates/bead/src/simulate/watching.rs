//! A simulation's events: screened after every step, their crossings located on the
//! integrator's own path, the run stopped at a terminal one and the others recorded (see
//! [`super::Event`] for the rules).

use super::event::{sample_time, Bracket, Crossing, EventError, EventSpec, Watch};
use super::{
    dense_samples, more_substeps, retryable, split, tried_in, RunError, Simulation, Stepper,
    EVENT_TOLERANCE,
};
use crate::formulation::{Method, StepError};
use crate::simulate::Event;

/// Screen one step for every watch (see [`Watch::screen`]); g at the step's end goes into
/// `g_end`. When no watch needs a closer look, every watch remembers this end as the start
/// of the next step; otherwise none does (the caller goes back to the step's start).
pub(super) fn screen_all(
    watches: &mut [Watch],
    g_end: &mut [f64],
    t: f64,
    state: (&[f64], &[f64], &[f64], &[f64]),
) -> bool {
    let (x, xdot, q, qdot) = state;
    let mut look = false;
    for (watch, g) in watches.iter_mut().zip(g_end.iter_mut()) {
        *g = watch.eval(t, x, xdot, q, qdot);
        look = look || watch.screen(t, x, xdot, q, qdot, *g);
    }
    if !look {
        for (watch, &g) in watches.iter_mut().zip(g_end.iter()) {
            watch.remember(t, x, xdot, q, qdot, g);
        }
    }
    look
}

impl Simulation {
    /// Watch `events` from now on, in place of any watched before (an empty list stops
    /// watching): after every step each event's expression g is tested for a crossing of
    /// zero in its [`super::Direction`] inside the step, located to 1e-10 of dt on the
    /// integrator's own path (see [`Event`]). A terminal event makes [`Simulation::step`] and
    /// [`Simulation::advance_to`] stop at its crossing ([`Simulation::stopped_at_event`],
    /// [`Simulation::fired_event`]), the earliest when several cross in one step; a
    /// non-terminal one is recorded ([`Simulation::crossings`]) and changes nothing else. An
    /// event that is at or beyond zero now does not fire until it has crossed; the
    /// simulation can go on after a terminal event (its next crossing fires again). A g that
    /// is not a number makes the step fail with [`RunError::EventNotANumber`], the simulation
    /// standing at the step's start. The crossings recorded so far are kept.
    ///
    /// Fails when an event was parsed for another system, or reads generalized coordinates
    /// and the simulation runs the implicit form; then nothing changes.
    pub fn set_events(&mut self, events: Vec<EventSpec>) -> Result<(), EventError> {
        let parametric = self.method() == Method::Parametric;
        for spec in &events {
            spec.event.check(self.system(), parametric)?;
        }
        self.pending_event = None;
        self.resume_event = None;
        self.stopped_at_event = false;
        self.fired_event = None;
        let samples = self.config.event_samples;
        self.watches = events
            .into_iter()
            .map(|spec| Watch::new(spec, samples))
            .collect();
        let m = self.watches.len();
        self.g_before = vec![0.0; m];
        self.g_now = vec![0.0; m];
        // Sized now, so that a step that locates a crossing allocates only its record.
        self.event_state.clone_from(&self.state);
        self.step_end.clone_from(&self.state);
        self.sample_state.clone_from(&self.state);
        self.stop_state.clone_from(&self.state);
        self.rearm_events();
        Ok(())
    }

    /// Watch `event` as the one stop condition (a terminal upward event; `None`: watch
    /// nothing), in place of any event watched before: [`Simulation::set_events`] with that
    /// event alone.
    pub fn set_stop_when(&mut self, event: Option<Event>) -> Result<(), EventError> {
        self.set_events(event.into_iter().map(EventSpec::stop).collect())
    }

    /// The events being watched, in the order given.
    pub fn events(&self) -> Vec<EventSpec> {
        self.watches
            .iter()
            .map(|w| EventSpec {
                event: w.event.clone(),
                direction: w.direction,
                terminal: w.terminal,
                stop_when: w.stop_when,
            })
            .collect()
    }

    /// How many events are watched.
    pub fn event_count(&self) -> usize {
        self.watches.len()
    }

    /// The first terminal event being watched (the stop condition).
    pub fn stop_when(&self) -> Option<&Event> {
        self.watches.iter().find(|w| w.terminal).map(|w| &w.event)
    }

    /// The time a terminal event last stopped the simulation, if one has since the start (or
    /// the last reset).
    pub fn event_time(&self) -> Option<f64> {
        self.event_time
    }

    /// Which event (its index in [`Simulation::set_events`]'s list) stopped the last
    /// [`Simulation::step`] or [`Simulation::advance_to`], if one did.
    pub fn fired_event(&self) -> Option<usize> {
        self.fired_event.filter(|_| self.stopped_at_event)
    }

    /// Whether the last [`Simulation::step`] or [`Simulation::advance_to`] stopped early, at a
    /// terminal event's crossing (then [`Simulation::t`] is [`Simulation::event_time`]).
    pub fn stopped_at_event(&self) -> bool {
        self.stopped_at_event
    }

    /// The crossings of the watched events from the start (or the last reset or restart) up
    /// to the current time, in time order (terminal ones included).
    pub fn crossings(&self) -> &[Crossing] {
        let t = self.t();
        let end = self.crossings.partition_point(|c| c.t <= t);
        &self.crossings[..end]
    }

    /// Put `earlier` crossings (of the same events, e.g. recorded by the simulation this one
    /// replaces after a parameter changed) before those recorded so far.
    pub fn prepend_crossings(&mut self, earlier: &[Crossing]) {
        self.crossings.splice(0..0, earlier.iter().cloned());
    }

    /// g of every event at the observed state, as the start of the next crossing test.
    pub(super) fn rearm_events(&mut self) {
        let n = self.n;
        let observed = if self.output_behind {
            &self.output
        } else {
            &self.state
        };
        let x = &self.monitor.observation.x;
        let xdot = &self.monitor.observation.xdot;
        let (q, qdot) = (&observed.q[..n], &observed.qdot[..n]);
        for watch in &mut self.watches {
            let g = watch.eval(observed.t, x, xdot, q, qdot);
            watch.remember(observed.t, x, xdot, q, qdot, g);
        }
        if self.output_behind && !self.watches.is_empty() {
            // The events start inside the last adaptive step: search its rest.
            self.resume_event = Some(observed.t);
        }
    }

    /// With events, after a step was accepted (its end observed): look for crossings inside
    /// it. Fixed-step integrators screen the step on an interpolant ([`Watch::screen`]) and,
    /// when it asks, evaluate g on their own path at the sample times
    /// ([`Simulation::scan_fixed`]); dopri5 samples its dense output, its own path between
    /// steps ([`Simulation::scan_dense`]). A failure undoes the step and the crossings
    /// recorded in it.
    pub(super) fn watch_step(&mut self) -> Result<(), RunError> {
        let n = self.n;
        let recorded = self.crossings.len();
        let result = match self.stepper {
            Stepper::Fixed(_) => {
                let (state, observation) = (&self.state, &self.monitor.observation);
                let end = (
                    &observation.x[..],
                    &observation.xdot[..],
                    &state.q[..n],
                    &state.qdot[..n],
                );
                if screen_all(&mut self.watches, &mut self.g_now, state.t, end) {
                    self.scan_fixed()
                } else {
                    self.monitor.accumulate();
                    Ok(())
                }
            }
            Stepper::Adaptive(_) => {
                for k in 0..self.watches.len() {
                    let g_end = self.event_value(k, false);
                    self.g_before[k] = self.watches[k].g_last;
                    self.watches[k].g_last = g_end;
                }
                let start = self.previous.t;
                let result = self.scan_dense(start, start);
                if result.is_err() {
                    self.steps -= 1;
                    self.restore();
                    self.rearm_events();
                } else if self.pending_event.is_none() {
                    self.monitor.accumulate();
                }
                result
            }
        };
        if result.is_err() {
            self.crossings.truncate(recorded);
        }
        result
    }

    /// The error for a g of event `k` that is not a number at time t (its watch holds the
    /// state it was evaluated at): the step is undone, the run stands at its start.
    fn event_not_a_number(&mut self, k: usize, t: f64, g: f64) -> RunError {
        let error = self.watches[k].not_a_number(t, g, self.previous.t);
        self.steps -= 1;
        self.restore();
        error
    }

    /// The screen flagged the step from `previous` to `state`: evaluate every g on the
    /// integrator's own path (the step integrated again from its start, as when locating)
    /// at the sample times in order, and locate the crossings between two of them
    /// ([`Simulation::locate_crossings`]), up to the first terminal one, where the step ends;
    /// a g that is not a number there is an error. Without a terminal crossing the step
    /// stands as it was taken.
    fn scan_fixed(&mut self) -> Result<(), RunError> {
        // The samples' and the location's partial steps must not change the run's next step.
        if let Stepper::Fixed(integrator) = &mut self.stepper {
            integrator.set_aside_carry();
        }
        let scanned = self.scan_fixed_samples();
        if let Stepper::Fixed(integrator) = &mut self.stepper {
            integrator.take_back_carry();
        }
        scanned
    }

    /// [`Simulation::scan_fixed`], between setting aside what the integrator carries from
    /// step to step ([`crate::integrate::Integrator::set_aside_carry`]) and taking it back.
    fn scan_fixed_samples(&mut self) -> Result<(), RunError> {
        let n = self.n;
        let samples = self.config.event_samples;
        let (t0, t1) = (self.previous.t, self.state.t);
        for (g, watch) in self.g_before.iter_mut().zip(&self.watches) {
            *g = watch.g_last;
        }
        if let Some(k) = self.g_before.iter().position(|g| !g.is_finite()) {
            self.restore();
            let g = self.event_value(k, false);
            self.steps -= 1;
            return Err(self.watches[k].not_a_number(t0, g, t0));
        }
        self.step_end.clone_from(&self.state);
        let mut t_before = t0;
        for i in 1..=samples + 1 {
            let ti = sample_time(t0, t1, i, samples);
            if i <= samples {
                self.restore_state_only();
                if let Err(e) = self.partial_step(ti) {
                    return Err(self.fail(e));
                }
            } else {
                self.state.clone_from(&self.step_end);
            }
            self.observe_state(ti);
            for k in 0..self.watches.len() {
                self.g_now[k] = self.event_value(k, false);
                if !self.g_now[k].is_finite() {
                    return Err(self.event_not_a_number(k, ti, self.g_now[k]));
                }
            }
            if self.any_crossing() && self.locate_crossings(t_before, ti)? {
                return Ok(());
            }
            self.g_before.copy_from_slice(&self.g_now);
            t_before = ti;
        }
        // No terminal crossing on the integrator's path: the step stands, observed at its end.
        self.state.clone_from(&self.step_end);
        self.observe_state(t1);
        let (state, observation) = (&self.state, &self.monitor.observation);
        for (watch, &g) in self.watches.iter_mut().zip(&self.g_before) {
            watch.remember(
                t1,
                &observation.x,
                &observation.xdot,
                &state.q[..n],
                &state.qdot[..n],
                g,
            );
        }
        self.monitor.accumulate();
        Ok(())
    }

    /// Whether some event crosses zero in its direction from `g_before` to `g_now`.
    fn any_crossing(&self) -> bool {
        self.watches
            .iter()
            .zip(self.g_before.iter().zip(&self.g_now))
            .any(|(w, (&a, &b))| w.direction.crossing(a, b).is_some())
    }

    /// Fixed-step integrators: the state at sample time `b` is `state` (observed), g is
    /// `g_before` at the sample time `a` before it and `g_now` at b. Locate every crossing
    /// between the two ([`Simulation::locate_fixed`]) and record the non-terminal ones; at a
    /// terminal one (the earliest, when several) end the step there, drop the crossings
    /// after it, and return true. Otherwise `state` is back at b.
    fn locate_crossings(&mut self, a: f64, b: f64) -> Result<bool, RunError> {
        let n = self.n;
        let recorded = self.crossings.len();
        self.sample_state.clone_from(&self.state);
        let mut stop: Option<(f64, usize, f64)> = None;
        for k in 0..self.watches.len() {
            let (before, now) = (self.g_before[k], self.g_now[k]);
            let Some(sign) = self.watches[k].direction.crossing(before, now) else {
                continue;
            };
            self.state.clone_from(&self.sample_state);
            let te = self.locate_fixed(k, sign, Bracket::new(a, sign * before, b, sign * now))?;
            if !self.watches[k].terminal {
                self.record_crossing(k, sign);
            } else if stop.is_none_or(|(t, _, _)| te < t) {
                stop = Some((te, k, sign));
                self.stop_state.clone_from(&self.state);
            }
        }
        self.crossings[recorded..]
            .sort_unstable_by(|p, q| p.t.total_cmp(&q.t).then(p.event.cmp(&q.event)));
        let Some((te, k, sign)) = stop else {
            self.state.clone_from(&self.sample_state);
            return Ok(false);
        };
        let keep = recorded + self.crossings[recorded..].partition_point(|c| c.t <= te);
        self.crossings.truncate(keep);
        self.state.clone_from(&self.stop_state);
        self.observe_state(te);
        self.record_crossing(k, sign);
        self.monitor.accumulate();
        for j in 0..self.watches.len() {
            let g = self.event_value(j, false);
            let (state, observation) = (&self.state, &self.monitor.observation);
            self.watches[j].remember(
                te,
                &observation.x,
                &observation.xdot,
                &state.q[..n],
                &state.qdot[..n],
                g,
            );
        }
        self.grid_origin = te;
        self.grid_steps = 0;
        self.event_time = Some(te);
        self.fired_event = Some(k);
        self.stopped_at_event = true;
        Ok(true)
    }

    /// Record a crossing of event `k` (sign +1 up, -1 down) at the observed `state`.
    fn record_crossing(&mut self, k: usize, sign: f64) {
        let n = self.n;
        let observation = &self.monitor.observation;
        self.crossings.push(Crossing {
            event: k,
            t: self.state.t,
            sign: sign as i8,
            x: observation.x.clone(),
            xdot: observation.xdot.clone(),
            q: self.state.q[..n].to_vec(),
            qdot: self.state.qdot[..n].to_vec(),
        });
    }

    /// Observe `state`, at time t.
    fn observe_state(&mut self, t: f64) {
        let (q, qdot, work) = split(&self.state, self.n);
        self.monitor
            .observe(&mut *self.formulation, t, q, qdot, work);
    }

    /// The tolerance of an event's time: 1e-10 of dt, or a few ulps of t when that is less.
    pub(super) fn event_tolerance(&self, t: f64) -> f64 {
        (EVENT_TOLERANCE * self.config.dt).max(4.0 * f64::EPSILON * t.abs())
    }

    /// g of event `k` at the state last observed by the monitor, at time t with the
    /// formulation's coordinates `state` (or `output`).
    fn event_value(&mut self, k: usize, at_output: bool) -> f64 {
        let n = self.n;
        let state = if at_output { &self.output } else { &self.state };
        let observation = &self.monitor.observation;
        self.watches[k].eval(
            state.t,
            &observation.x,
            &observation.xdot,
            &state.q[..n],
            &state.qdot[..n],
        )
    }

    /// Fixed-step integrators: re-integrate the step from its start over a part of its
    /// length until the crossing of event `k` (sign s: the root of s g) is bracketed to the
    /// tolerance; `state` is the bracket's upper end on entry, and on return the state at
    /// the located time (observed), which is returned.
    fn locate_fixed(&mut self, k: usize, sign: f64, mut bracket: Bracket) -> Result<f64, RunError> {
        self.event_state.clone_from(&self.state);
        let tolerance = self.event_tolerance(bracket.hi);
        while !bracket.done(tolerance) {
            let t = bracket.next();
            self.restore_state_only();
            if let Err(e) = self.partial_step(t) {
                return Err(self.fail(e));
            }
            self.observe_state(t);
            let g = self.event_value(k, false);
            if !g.is_finite() {
                return Err(self.event_not_a_number(k, t, g));
            }
            if sign * g >= 0.0 {
                self.event_state.clone_from(&self.state);
            }
            bracket.update(t, sign * g);
        }
        if let Some((lo, hi)) = bracket.jump() {
            let error = self.watches[k].jump(bracket.hi, (sign * lo, sign * hi), self.previous.t);
            self.steps -= 1;
            self.restore();
            return Err(error);
        }
        self.state.clone_from(&self.event_state);
        let t = self.state.t;
        self.observe_state(t);
        Ok(t)
    }

    /// The current step from its start (`previous`, already restored) to `t_end`, with the
    /// substeps the whole step took, retried with more when an iteration does not converge.
    pub(super) fn partial_step(&mut self, t_end: f64) -> Result<(), StepError> {
        let mut substeps = self.last_substeps.max(1);
        loop {
            match self.substeps(t_end, substeps) {
                Ok(()) => return Ok(()),
                Err(e) if retryable(&e) && substeps < self.config.max_substeps => {
                    self.restore_state_only();
                    substeps = more_substeps(substeps, self.config.max_substeps);
                }
                Err(e) => return Err(tried_in(e, substeps)),
            }
        }
    }

    /// Adaptive integrators: every g on the last step's dense output from time `from`
    /// (where it is `g_before`) to the step's end (where it is each watch's `g_last`), at the
    /// step's sample times after `from`. The crossings between two of them are located on
    /// the dense output and recorded; the first terminal one is left pending for the output
    /// to reach ([`Simulation::fire_adaptive`]), and those after it are dropped (the scan
    /// resumes there). A g that is not a number is an error (the caller moves the run to
    /// `stopped`, its last good state).
    fn scan_dense(&mut self, from: f64, stopped: f64) -> Result<(), RunError> {
        let Stepper::Adaptive(dopri) = &self.stepper else {
            unreachable!("scan_dense is called for adaptive integrators only");
        };
        let (t_old, t_new) = dopri.last_step();
        let samples = dense_samples(t_new - t_old, self.config.dt, self.config.event_samples);
        if let Some(k) = self.g_before.iter().position(|g| !g.is_finite()) {
            let g = self.dense_value(k, from);
            return Err(self.watches[k].not_a_number(from, g, stopped));
        }
        let mut t_before = from;
        for i in 1..=samples + 1 {
            let ti = sample_time(t_old, t_new, i, samples);
            if ti <= from {
                continue;
            }
            for k in 0..self.watches.len() {
                let g = if i <= samples {
                    self.dense_value(k, ti)
                } else {
                    self.watches[k].g_last
                };
                if !g.is_finite() {
                    self.dense_value(k, ti);
                    return Err(self.watches[k].not_a_number(ti, g, stopped));
                }
                self.g_now[k] = g;
            }
            if self.any_crossing() && self.locate_dense_crossings(t_before, ti, stopped)? {
                return Ok(());
            }
            self.g_before.copy_from_slice(&self.g_now);
            t_before = ti;
        }
        Ok(())
    }

    /// Adaptive integrators: locate and record the crossings between the sample times `a`
    /// and `b` (g there `g_before` and `g_now`) on the dense output; at a terminal one (the
    /// earliest) drop those after it, leave it pending and return true.
    fn locate_dense_crossings(&mut self, a: f64, b: f64, stopped: f64) -> Result<bool, RunError> {
        let recorded = self.crossings.len();
        let mut stop: Option<(f64, usize)> = None;
        for k in 0..self.watches.len() {
            let (before, now) = (self.g_before[k], self.g_now[k]);
            let Some(sign) = self.watches[k].direction.crossing(before, now) else {
                continue;
            };
            let bracket = Bracket::new(a, sign * before, b, sign * now);
            let te = self.locate_dense(k, sign, bracket, stopped)?;
            self.record_dense_crossing(k, te, sign);
            if self.watches[k].terminal && stop.is_none_or(|(t, _)| te < t) {
                stop = Some((te, k));
            }
        }
        self.crossings[recorded..]
            .sort_unstable_by(|p, q| p.t.total_cmp(&q.t).then(p.event.cmp(&q.event)));
        let Some((te, k)) = stop else {
            return Ok(false);
        };
        // The crossings after the stop are found again when the scan resumes there.
        let keep = recorded + self.crossings[recorded..].partition_point(|c| c.t <= te);
        self.crossings.truncate(keep);
        self.pending_event = Some((te, k));
        Ok(true)
    }

    /// Adaptive integrators: g of event `k` at time t of the last step's dense output (put
    /// into `output`, not observed: the watch maps it to particle space itself).
    fn dense_value(&mut self, k: usize, t: f64) -> f64 {
        if let Stepper::Adaptive(dopri) = &self.stepper {
            dopri.interpolate(t, &mut self.output.q, &mut self.output.qdot);
        }
        self.output.t = t;
        let n = self.n;
        self.watches[k].eval_state(
            &mut *self.formulation,
            t,
            &self.output.q[..n],
            &self.output.qdot[..n],
        )
    }

    /// Adaptive integrators: record a crossing of event `k` at time t of the dense output.
    fn record_dense_crossing(&mut self, k: usize, t: f64, sign: f64) {
        let n = self.n;
        if let Stepper::Adaptive(dopri) = &self.stepper {
            dopri.interpolate(t, &mut self.output.q, &mut self.output.qdot);
        }
        self.output.t = t;
        let coordinates = self.formulation.system().n_coords();
        let (mut x, mut xdot) = (vec![0.0; coordinates], vec![0.0; coordinates]);
        let (q, qdot) = (&self.output.q[..n], &self.output.qdot[..n]);
        self.formulation
            .particle_state(t, q, qdot, &mut x, &mut xdot);
        self.crossings.push(Crossing {
            event: k,
            t,
            sign: sign as i8,
            x,
            xdot,
            q: q.to_vec(),
            qdot: qdot.to_vec(),
        });
    }

    /// Adaptive integrators: the dense output at time t of the last step into `output`,
    /// observed.
    pub(super) fn observe_state_at(&mut self, t: f64) {
        if let Stepper::Adaptive(dopri) = &self.stepper {
            dopri.interpolate(t, &mut self.output.q, &mut self.output.qdot);
        }
        self.output.t = t;
        let (q, qdot, work) = split(&self.output, self.n);
        self.monitor
            .observe(&mut *self.formulation, t, q, qdot, work);
    }

    /// Adaptive integrators: find the crossing of event `k` (the root of s g, s = `sign`) on
    /// the last step's dense output; the output reaches it later.
    fn locate_dense(
        &mut self,
        k: usize,
        sign: f64,
        mut bracket: Bracket,
        stopped: f64,
    ) -> Result<f64, RunError> {
        let tolerance = self.event_tolerance(bracket.hi);
        while !bracket.done(tolerance) {
            let t = bracket.next();
            let g = self.dense_value(k, t);
            if !g.is_finite() {
                return Err(self.watches[k].not_a_number(t, g, stopped));
            }
            bracket.update(t, sign * g);
        }
        if let Some((lo, hi)) = bracket.jump() {
            return Err(self.watches[k].jump(bracket.hi, (sign * lo, sign * hi), stopped));
        }
        Ok(bracket.hi)
    }

    /// Adaptive integrators, after an event fired inside the last step (or the events were
    /// set with the output inside it): search the rest of that step before going on. On
    /// error the run stands at the output's time, which becomes the integrator's state.
    pub(super) fn resume_dense_scan(&mut self) -> Result<(), RunError> {
        let Some(from) = self.resume_event.take() else {
            return Ok(());
        };
        if self.watches.is_empty() || self.pending_event.is_some() || from >= self.state.t {
            return Ok(());
        }
        let n = self.n;
        for k in 0..self.watches.len() {
            self.g_before[k] = self.dense_value(k, from);
            let (q, qdot) = (&self.state.q[..n], &self.state.qdot[..n]);
            let g_end = self.watches[k].eval_state(&mut *self.formulation, self.state.t, q, qdot);
            self.watches[k].g_last = g_end;
        }
        let recorded = self.crossings.len();
        let result = self.scan_dense(from, from);
        if result.is_err() {
            self.crossings.truncate(recorded);
            // The last good state is the output at `from`: the integrator starts again there.
            self.observe_state_at(from);
            self.state.clone_from(&self.output);
            self.previous.clone_from(&self.output);
            self.output_behind = false;
            self.rearm_events();
        }
        result
    }

    /// Adaptive integrators: the output reached the crossing of event `k` located at `te`: it
    /// becomes the observable state and the step or advance stops there; the rest of the
    /// step is searched for the next crossings when the simulation goes on.
    pub(super) fn fire_adaptive(&mut self, te: f64, k: usize) {
        if te == self.state.t {
            self.output_behind = false;
            self.observe_state(te);
        } else {
            self.observe_state_at(te);
            self.output_behind = true;
            self.resume_event = Some(te);
        }
        self.monitor.accumulate();
        self.event_time = Some(te);
        self.fired_event = Some(k);
        self.stopped_at_event = true;
    }
}
