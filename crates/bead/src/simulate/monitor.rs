//! What a simulation watches after every step: the energy ledger, the constraint error,
//! divergence, and singular points of the constraints (the regularity monitor).

use std::fmt;

use crate::formulation::{Formulation, Observation, SingularKind, StepError};
use crate::linalg::{max_abs, max_nan};
use crate::model::System;

/// A particle farther than this many times the run's length scale, or faster than this many
/// times its speed scale, has diverged (see [`Reach`]).
pub(super) const BLOW_UP_FACTOR: f64 = 1e12;

/// A run whose energy T + V is conserved and has changed by more than this many times its
/// energy scale (|E - E0| / E_scale) has diverged: no integrator that follows the physics
/// gets near it, while an unstable one (explicit Euler on an oscillator) grows the energy
/// geometrically, slowly enough to stay within [`BLOW_UP_FACTOR`] times the reach for a
/// long time.
pub(super) const ENERGY_BLOW_UP: f64 = 1e6;

/// A gradient row shorter than this fraction of its longest length in the run has all but
/// vanished (a candidate, confirmed by a search).
pub(super) const VANISHED: f64 = 1e-2;
/// The lookahead: extrapolated along the motion, a gradient row that shrinks below this
/// fraction of its length ...
pub(super) const AHEAD_FRACTION: f64 = 0.5;
/// ... within this many steps, meets a singular point.
pub(super) const AHEAD_STEPS: f64 = 2.0;
/// A state off its constraint by more than this fraction of the distance to a singular point
/// ahead may follow another branch of the curve.
pub(super) const OFF_BRANCH: f64 = 0.01;
/// A step whose gradient reversed with no singular point near is too long for the curve when
/// it also left the curve by more than this fraction of its own length.
const TOO_LONG_OFFSET: f64 = 0.1;
/// A point where a gradient row vanishes is on the curve when |C| there is below this
/// fraction of the row's scale (its gradient's length at the start times the scene's
/// length): C vanishes quadratically at a singular point of the curve (C = 0 there exactly),
/// while a critical point off the curve (a circle's centre, a rod's ends meeting) has |C| of
/// the order of the scale.
const ON_CURVE: f64 = 1e-6;

/// A quantity that diverged.
#[derive(Clone, Debug, PartialEq)]
pub enum Quantity {
    /// A particle coordinate, e.g. `bead.x`.
    Position(String),
    /// A particle velocity component, e.g. `bead.vx`.
    Velocity(String),
    /// A generalized coordinate of the parametric form, by name.
    Coordinate(String),
    /// The rate of a generalized coordinate, by name.
    Rate(String),
    /// The energy T + V.
    Energy,
    /// The largest constraint residual max |C_i|.
    ConstraintError,
    /// The work W of the energy ledger.
    Work,
    /// The energy's change |E - E0| over the energy scale.
    EnergyChange,
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Quantity::Position(name) | Quantity::Velocity(name) => write!(f, "{name}"),
            Quantity::Coordinate(name) => write!(f, "q.{name}"),
            Quantity::Rate(name) => write!(f, "qdot.{name}"),
            Quantity::Energy => write!(f, "the energy"),
            Quantity::ConstraintError => write!(f, "the constraint error"),
            Quantity::Work => write!(f, "the work W"),
            Quantity::EnergyChange => write!(f, "the energy's change |E - E0| / E_scale"),
        }
    }
}

/// Why a state is not acceptable: not finite, beyond the run's reach, or at a singular point.
pub(super) enum Rejection {
    Diverged {
        quantity: Quantity,
        value: f64,
        /// The limit it passed, when it is finite but too large.
        limit: Option<f64>,
    },
    Singular(StepError),
    /// A gradient row reversed direction within the step (turned by more than 90 degrees)
    /// with no singular point of the curve on the step: the step is too long for the curve.
    TooLong(StepError),
}

/// The length and speed a run can legitimately reach by time t: the reach of the initial state,
/// of gravity and of the initial energy,
///
/// ```text
/// L(t) = max(1, max|x0|, max|v0| t, |g| t^2 / 2, V t)
/// V(t) = max(1, max|v0|, |g| t, sqrt(|g| L), sqrt(2 E_scale / m_min))
/// ```
/// Legitimate motion stays within a small multiple of these, while an unstable integration
/// grows geometrically and passes [`BLOW_UP_FACTOR`] times them within a few steps, long
/// before f64 overflows.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Reach {
    position: f64,
    speed: f64,
    gravity: f64,
    energy_speed: f64,
}

impl Reach {
    fn at(&self, t: f64) -> (f64, f64) {
        let t = t.abs();
        let speed0 = self.speed.max(self.energy_speed);
        let length = [1.0, self.position, speed0 * t, 0.5 * self.gravity * t * t]
            .into_iter()
            .fold(0.0, f64::max);
        let speed = [
            1.0,
            speed0,
            self.gravity * t,
            (self.gravity * length).sqrt(),
        ]
        .into_iter()
        .fold(0.0, f64::max);
        (BLOW_UP_FACTOR * length, BLOW_UP_FACTOR * speed)
    }
}

/// The energy's blow-up watch: |E - E0| beyond `limit`, [`ENERGY_BLOW_UP`] times the
/// energy scale, has diverged. Watched where T + V is conserved
/// (`Simulation::watch_energy`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct EnergyWatch {
    pub(super) limit: f64,
}

/// The monitors of one simulation: energy ledger, constraint error and regularity, with their
/// maxima. Buffers are sized once. (`Default`: an empty placeholder, observing nothing.)
#[derive(Default)]
pub(super) struct Monitor {
    /// The last observed state (particle state, constraint values, gradient rows).
    pub(super) observation: Observation,
    /// The last accepted step's end (regularity: what a new state is compared with), at
    /// `ends[newest]`, and the step end before it (to explain a failure at the last accepted
    /// state) at `ends[1 - newest]`: a step's shift flips the index instead of moving them
    ends: [StepEnd; 2],
    newest: usize,
    /// The longest each gradient row has been in this run (rows)
    longest: Vec<f64>,
    /// Each gradient row's length at the last observed step end, as the regularity monitor
    /// computed it (rows, none when no row is watched; scratch, so that the step's shift does
    /// not take the norms again)
    lengths: Vec<f64>,
    /// Each gradient row's length at the start (rows, none when no row is watched): its
    /// scale, which a blow-up cannot inflate as it inflates `longest`
    initial: Vec<f64>,
    /// The formulation's q at the start (a divergence within the first steps is explained
    /// from there, before the blow-up, by the watched rows: none kept when no row is)
    pub(super) initial_q: Vec<f64>,
    /// Per row, the gradient's length when a search for a singular point last found none
    /// (infinite when none failed): the search is repeated only once the gradient has
    /// shrunk by half since, so that a curve with a sharp but regular turn (the tip of a thin
    /// ellipse) costs a few searches, not one per step.
    searched: Vec<f64>,
    /// Per row, whether it can have no singular point on its constraint (rods and pins):
    /// those rows are not watched
    never_singular: Vec<bool>,
    /// Whether any row is watched (some row can be singular)
    watched: bool,
    /// The scene's length scale: the largest initial coordinate magnitude (1 when all are 0)
    length_scale: f64,
    /// Searches for a singular point made after a step (each allocates)
    pub(super) searches: u64,
    pub(super) energy_initial: f64,
    /// E_scale: the denominator of relative energy errors
    pub(super) energy_scale: f64,
    pub(super) energy: f64,
    pub(super) work: f64,
    /// Whether the energy is watched for a blow-up, and how (see [`EnergyWatch`])
    pub(super) energy_watch: Option<EnergyWatch>,
    pub(super) energy_rel_error_max: f64,
    pub(super) balance_error_max: f64,
    pub(super) constraint_error: f64,
    pub(super) constraint_error_max: f64,
    /// max_i |C_i| / |grad C_i| now and over the run (see [`Observation::constraint_distance`])
    pub(super) constraint_distance: f64,
    pub(super) constraint_distance_max: f64,
    reach: Reach,
    /// T + V as the system computes it, with its terms gathered once
    energy_terms: EnergyTerms,
    /// Debug builds: the observation made apart, to check [`Monitor::observe_accelerated`]
    #[cfg(debug_assertions)]
    check: Observation,
    /// The divergence limits at t = 0, [`Reach::at`]'s least over every t: a state within
    /// them is within the limits at any time, so that the limits of its own time need not be
    /// computed (see [`Monitor::check_divergence`]).
    floor: (f64, f64),
}

impl Monitor {
    /// A monitor at the initial state (t0, q, qdot); the energy scale is fixed here:
    ///
    /// ```text
    /// E_scale = max(|E0|, T0 + |V0|, T0 + M |g| L)
    /// ```
    /// with M the total mass and L the scene's length scale, the largest initial coordinate
    /// magnitude: the energy the motion can exchange, which does not vanish when the scene
    /// starts at the potential's zero. 1 (an absolute error) when all of these vanish.
    pub(super) fn new(
        formulation: &mut (dyn Formulation + Send),
        t0: f64,
        q: &[f64],
        qdot: &[f64],
    ) -> Self {
        let mut observation = formulation.new_observation();
        formulation.observe(t0, q, qdot, &mut observation);
        let system = formulation.system();
        let kinetic = system.kinetic_energy(&observation.xdot);
        let potential = system.potential_energy(&observation.x);
        let energy = kinetic + potential;
        // The largest coordinate magnitude at the run's start: the energy scale's lever arm
        // (0 for a system at the origin), and the run's length scale (1 then).
        let length = observation.x.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
        let length_scale = crate::model::length_scale(&observation.x);
        let gravity = norm(system.gravity());
        let mass: f64 = system.particles().iter().map(|p| p.mass).sum();
        let scale = [
            energy.abs(),
            kinetic + potential.abs(),
            kinetic + mass * gravity * length,
        ]
        .into_iter()
        .fold(0.0, f64::max);
        let energy_scale = if scale > 0.0 && scale.is_finite() {
            scale
        } else {
            1.0
        };
        let largest = |v: &[f64]| v.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
        let lightest = system
            .particles()
            .iter()
            .map(|p| p.mass)
            .fold(f64::INFINITY, f64::min);
        let reach = Reach {
            position: largest(&observation.x),
            speed: largest(&observation.xdot),
            gravity,
            energy_speed: (2.0 * energy_scale / lightest).sqrt(),
        };
        let constraint_error = observation.constraint_error();
        let constraint_distance = observation.constraint_distance();
        let longest: Vec<f64> = (0..observation.gradients.n_rows())
            .map(|r| norm(observation.gradients.row(r)))
            .collect();
        let searched = vec![f64::INFINITY; longest.len()];
        let never_singular: Vec<bool> = (0..longest.len())
            .map(|r| formulation.row_never_singular(r))
            .collect();
        let watched = never_singular.contains(&false);
        // Read for watched rows only: none kept when no row is.
        let initial = if watched { longest.clone() } else { Vec::new() };
        let lengths = vec![0.0; if watched { longest.len() } else { 0 }];
        // With no row watched (a chain, a cloth) a step end's gradient values are never
        // read: none are kept (48 bytes a rod, twice).
        let last = StepEnd {
            gradients: if watched {
                observation.gradients.clone()
            } else {
                Default::default()
            },
            q: q.to_vec(),
            valid: true,
        };
        let before = StepEnd {
            valid: false,
            ..last.clone()
        };
        #[cfg(debug_assertions)]
        let mut check = formulation.new_observation();
        if !watched {
            // Nor are the observation's: only the offsets are read from here on (a copy of
            // J's entries saved at every step, 32 bytes a rod in 2D).
            observation.gradients.drop_values();
            #[cfg(debug_assertions)]
            check.gradients.drop_values();
        }
        Monitor {
            observation,
            ends: [last, before],
            newest: 0,
            lengths,
            longest,
            initial,
            // Read for watched rows only (`Simulation::explain_divergence`).
            initial_q: if watched { q.to_vec() } else { Vec::new() },
            searched,
            never_singular,
            watched,
            length_scale,
            searches: 0,
            energy_initial: energy,
            energy_scale,
            energy,
            work: 0.0,
            energy_watch: None,
            energy_rel_error_max: 0.0,
            balance_error_max: 0.0,
            constraint_error,
            constraint_error_max: constraint_error,
            constraint_distance,
            constraint_distance_max: constraint_distance,
            floor: reach.at(0.0),
            energy_terms: EnergyTerms::of(system),
            #[cfg(debug_assertions)]
            check,
            reach,
        }
    }

    /// Observe (t, q, qdot) with work W: particle state, energy, constraint error.
    pub(super) fn observe(
        &mut self,
        formulation: &mut (dyn Formulation + Send),
        t: f64,
        q: &[f64],
        qdot: &[f64],
        work: f64,
    ) {
        formulation.observe(t, q, qdot, &mut self.observation);
        self.measure(formulation.system(), work);
    }

    /// Energy, work and constraint error of the observation.
    fn measure(&mut self, system: &System, work: f64) {
        self.energy = self
            .energy_terms
            .energy(system, &self.observation.x, &self.observation.xdot);
        self.work = work;
        self.constraint_error = self.observation.constraint_error();
        self.constraint_distance = self.observation.constraint_distance();
    }

    /// [`Monitor::observe`] from the evaluation of the formulation's last acceleration, which
    /// was at (t, q, qdot) (see [`Formulation::observe_accelerated`]); false when the
    /// formulation cannot (nothing observed). Debug builds check it against
    /// [`Monitor::observe`], bit for bit.
    pub(super) fn observe_accelerated(
        &mut self,
        formulation: &mut (dyn Formulation + Send),
        t: f64,
        q: &[f64],
        qdot: &[f64],
        work: f64,
    ) -> bool {
        if !formulation.observe_accelerated(t, q, qdot, &mut self.observation) {
            return false;
        }
        #[cfg(debug_assertions)]
        {
            // Without allocating (the step loop allocates nothing, tests/alloc_free.rs).
            let check = &mut self.check;
            formulation.observe(t, q, qdot, check);
            let o = &self.observation;
            for (got, want) in [
                (&o.x, &check.x),
                (&o.xdot, &check.xdot),
                (&o.constraints, &check.constraints),
                (&o.gradients.values, &check.gradients.values),
                (&o.gradients.offset, &check.gradients.offset),
            ] {
                assert!(
                    crate::same_bits(got, want),
                    "observation from the acceleration differs: {got:?} {want:?}"
                );
            }
        }
        self.measure(formulation.system(), work);
        true
    }

    /// The monitor as it stands after a run accepted step ends up to one at state `last_q`
    /// with gradient values `last_gradients` (the ensemble lanes or a run's express steps
    /// took those steps, see `lanes` and `express`): `before` is the step end before it
    /// (none if `last` is the initial state), `longest` each row's longest length so far,
    /// `searched` each row's length at the last fruitless search, `maxima` the energy,
    /// balance and constraint error maxima. The observation is [`Monitor::observe`]d again by
    /// the caller. The gradient values are those [`Monitor::step_end`] gives (none when no
    /// row is watched).
    pub(super) fn adopt(
        &mut self,
        last_q: &[f64],
        last_gradients: &[f64],
        before: Option<(&[f64], &[f64])>,
        longest: &[f64],
        searched: &[f64],
        maxima: [f64; 4],
    ) {
        let newest = self.newest;
        let last = &mut self.ends[newest];
        last.q.copy_from_slice(last_q);
        last.gradients.values.copy_from_slice(last_gradients);
        last.valid = true;
        if let Some((q, gradients)) = before {
            let before = &mut self.ends[1 - newest];
            before.q.copy_from_slice(q);
            before.gradients.values.copy_from_slice(gradients);
            before.valid = true;
        }
        self.longest.copy_from_slice(longest);
        self.searched.copy_from_slice(searched);
        [
            self.energy_rel_error_max,
            self.balance_error_max,
            self.constraint_error_max,
            self.constraint_distance_max,
        ] = maxima;
    }

    /// The position and speed limits of the divergence test at time t (see [`Reach`]).
    pub(super) fn limits(&self, t: f64) -> (f64, f64) {
        self.reach.at(t)
    }

    /// The divergence limits at t = 0, the least at any time (position, speed): a state
    /// within them is within [`Monitor::limits`] at every t.
    pub(super) fn floor(&self) -> (f64, f64) {
        self.floor
    }

    /// Per row, whether it can have no singular point (not watched).
    pub(super) fn never_singular(&self) -> &[bool] {
        &self.never_singular
    }

    /// The longest each gradient row has been in the run so far.
    pub(super) fn longest(&self) -> &[f64] {
        &self.longest
    }

    /// The last accepted step end (`newest`) or the one before it: its q and gradient
    /// values (none kept when no row is watched), if it holds a step end yet.
    pub(super) fn step_end(&self, newest: bool) -> Option<(&[f64], &[f64])> {
        let end = &self.ends[if newest { self.newest } else { 1 - self.newest }];
        end.valid
            .then_some((end.q.as_slice(), end.gradients.values.as_slice()))
    }

    /// Per row, the gradient's length when a search for a singular point last found none
    /// (infinite when none failed).
    pub(super) fn searched(&self) -> &[f64] {
        &self.searched
    }

    /// Fold the last observation into the maxima.
    pub(super) fn accumulate(&mut self) {
        let error = (self.energy - self.energy_initial).abs() / self.energy_scale;
        let balance = (self.energy - self.work - self.energy_initial).abs() / self.energy_scale;
        self.energy_rel_error_max = max_nan(self.energy_rel_error_max, error);
        self.balance_error_max = max_nan(self.balance_error_max, balance);
        self.constraint_error_max = max_nan(self.constraint_error_max, self.constraint_error);
        self.constraint_distance_max =
            max_nan(self.constraint_distance_max, self.constraint_distance);
    }

    /// The scene's length scale (the largest initial coordinate magnitude, 1 when all are 0).
    pub(super) fn length_scale(&self) -> f64 {
        self.length_scale
    }

    /// Whether the state last observed at the end of a step (at time t) can be accepted: finite,
    /// within the run's reach, and away from singular points of the constraints. Call after
    /// [`Monitor::observe`] of a step's end (not of an interpolated sample); on success the
    /// gradient rows become the reference of the next step's regularity check.
    pub(super) fn check_step(
        &mut self,
        formulation: &dyn Formulation,
        t: f64,
        q: &[f64],
    ) -> Result<(), Rejection> {
        self.check_divergence(formulation.system(), t)?;
        let measured = self.ends[self.newest].valid;
        match self.regularity(formulation, t, q) {
            Some(Finding::Singular(row, kind)) => {
                return Err(Rejection::Singular(StepError::SingularPoint {
                    t,
                    subject: formulation.gradient_subject(row),
                    position: formulation.gradient_position(row, q),
                    kind,
                    cause: None,
                }))
            }
            Some(Finding::TooLong(row, offset)) => {
                return Err(Rejection::TooLong(StepError::StepTooLong {
                    t,
                    subject: formulation.gradient_subject(row),
                    position: formulation.gradient_position(row, q),
                    offset,
                }))
            }
            None => {}
        }
        // Shift: the last step end becomes the one before, the new state the last (its
        // gradient values and q: a step end's offsets are never read). With no row watched
        // (a chain, a cloth) the gradient values are never read, nor are unwatched rows'
        // lengths: not kept (nor do the lane monitors read them).
        self.newest = 1 - self.newest;
        let last = &mut self.ends[self.newest];
        if self.watched {
            last.gradients
                .values
                .copy_from_slice(&self.observation.gradients.values);
        }
        last.q.copy_from_slice(q);
        last.valid = true;
        for (r, (longest, searched)) in self.longest.iter_mut().zip(&mut self.searched).enumerate()
        {
            if self.never_singular[r] {
                continue;
            }
            // The regularity monitor took the watched rows' lengths already (the same sum in
            // the same order, so the same bits as `norm`).
            let length = if measured {
                self.lengths[r]
            } else {
                norm(self.observation.gradients.row(r))
            };
            *longest = longest.max(length);
            if length > 2.0 * *searched {
                // Away from where the last search found nothing: search again next time.
                *searched = f64::INFINITY;
            }
        }
        Ok(())
    }

    /// Whether the last observed state (the last good one) is next to a singular point, to
    /// explain a failed step (an implicit stage iteration or a projection that did not
    /// converge): a confirmed singular point (see [`Monitor::regularity`]) within ten step
    /// lengths, or where the gradient has fallen below 1% of its longest.
    pub(super) fn near_singular(
        &self,
        formulation: &dyn Formulation,
        t: f64,
        q: &[f64],
    ) -> Option<(usize, SingularKind)> {
        let g = &self.observation.gradients;
        for r in 0..g.n_rows() {
            if self.never_singular[r] {
                continue;
            }
            let row = g.row(r);
            let length = norm(row);
            let before = &self.ends[1 - self.newest];
            let ahead = if before.valid {
                steps_to_vanish(row, before.gradients.row(r), AHEAD_FRACTION)
            } else {
                None
            };
            let (kind, probe, reach) = match ahead {
                Some(steps) if steps <= 10.0 => (SingularKind::Ahead, steps, 11.0),
                _ if length < VANISHED * self.longest[r] => {
                    (SingularKind::Vanishes, 0.0, f64::INFINITY)
                }
                _ => continue,
            };
            if self.confirm(formulation, before, r, t, q, probe, reach) {
                return Some((r, kind));
            }
        }
        None
    }

    /// Whether a point where a watched gradient row vanishes lies on the curve within ten
    /// times what one step moves the row's variables from the last observed state q: the
    /// last step's length, or `displacement` (dt qdot + dt^2 a / 2 at q, for a failure at
    /// the first step or from rest). Explains a divergence that [`Monitor::near_singular`]
    /// saw no candidate for (a start next to a cusp blows up within a step or two). Searches
    /// every watched row, so it is for failures only.
    pub(super) fn singular_within_reach(
        &self,
        formulation: &dyn Formulation,
        t: f64,
        q: &[f64],
        displacement: &[f64],
    ) -> Option<usize> {
        let ahead: Vec<f64> = q.iter().zip(displacement).map(|(a, b)| a + b).collect();
        (0..self.observation.gradients.n_rows()).find(|&r| {
            if self.never_singular[r] {
                return false;
            }
            let mut step = formulation.row_step_length(r, &ahead, q);
            let before = &self.ends[1 - self.newest];
            if before.valid {
                step = step.max(formulation.row_step_length(r, q, &before.q));
            }
            self.search(formulation, &self.ends[self.newest], r, t, q, 0.0)
                .is_some_and(|(found, now, _)| distance(&found, &now) <= 10.0 * step)
        })
    }

    /// A row whose gradient is zero or not finite at the initial state: call on a new
    /// monitor, whose longest lengths are the initial state's.
    pub(super) fn singular_at_start(&self) -> Option<usize> {
        self.longest
            .iter()
            .position(|&length| !(length > 0.0 && length.is_finite()))
    }

    fn check_divergence(&self, system: &System, t: f64) -> Result<(), Rejection> {
        let diverged = |quantity: Quantity, value: f64, limit: Option<f64>| {
            Err(Rejection::Diverged {
                quantity,
                value,
                limit,
            })
        };
        if !self.energy.is_finite() {
            return diverged(Quantity::Energy, self.energy, None);
        }
        if !self.constraint_error.is_finite() {
            return diverged(Quantity::ConstraintError, self.constraint_error, None);
        }
        if !self.work.is_finite() {
            return diverged(Quantity::Work, self.work, None);
        }
        let x = &self.observation.x;
        let v = &self.observation.xdot;
        // Within the limits at t = 0, the least at any time: nothing diverged, whatever t (a
        // NaN fails the comparison and takes the full test; the largest sizes are taken
        // without a branch per entry).
        let (position_floor, speed_floor) = self.floor;
        if !(max_abs(x) <= position_floor && max_abs(v) <= speed_floor) {
            let (position_limit, speed_limit) = self.reach.at(t);
            if let Some(k) = x
                .iter()
                .position(|c| c.is_nan() || c.abs() > position_limit)
            {
                let limit = x[k].is_finite().then_some(position_limit);
                return diverged(Quantity::Position(system.coordinate_name(k)), x[k], limit);
            }
            if let Some(k) = v.iter().position(|c| c.is_nan() || c.abs() > speed_limit) {
                let limit = v[k].is_finite().then_some(speed_limit);
                return diverged(Quantity::Velocity(system.velocity_name(k)), v[k], limit);
            }
        }
        // A blow-up slow enough to stay within the reach (checked after it, so that a fast
        // one is still named by the coordinate that left).
        if let Some(EnergyWatch { limit }) = self.energy_watch {
            // As the lane monitors compare it (the same operations, so the same verdict).
            let change = (self.energy - self.energy_initial).abs();
            if change > limit {
                let relative = change / self.energy_scale;
                return diverged(Quantity::EnergyChange, relative, Some(ENERGY_BLOW_UP));
            }
        }
        Ok(())
    }

    /// The regularity monitor: the first gradient row that vanished, reversed, or is seen to
    /// vanish ahead, at a point of the curve. Rows that cannot vanish on their constraint
    /// (rods, pins: [`Formulation::row_never_singular`]) are not watched. Per row r, with g
    /// its gradient now, p at the previous step's end, d = g - p, G its longest length in the
    /// run and l the step's length in the row's variables, a cheap first-order test raises a
    /// candidate:
    ///
    /// - g . p < 0: the gradient reversed within the step (on a smooth curve it turns by far
    ///   less than 90 degrees per step), so the step may have crossed a point where it
    ///   vanishes;
    /// - |g| < 1e-2 G: it has all but vanished;
    /// - extrapolated linearly along the motion, g + s d shrinks below 0.5 |g| within
    ///   s <= 2 steps: a singular point may be about to be reached;
    /// - the same extrapolation shrinks below 0.5 |g| at any distance while the state is off
    ///   the constraint by more than 1/100 of |g| l / |d|, the distance to where the gradient
    ///   would vanish at the rate it changed over the step: near a crossing, the level set
    ///   through a drifted state may belong to another branch (a pair of hyperbolas near a
    ///   node, which never comes near the node itself).
    ///
    /// A candidate stops the run only when a search with exact second derivatives
    /// ([`Formulation::locate_singular_point`]) confirms a point x* where the gradient
    /// vanishes (reduced by 1e-6 to below 1e-6 of its length at the start, G0, or by 1e-10),
    /// on the curve (|C(x*)| below 1e-6 of G0 times the scene's length), and within reach:
    /// on the step's chord (reversal), within three steps (ahead), anywhere (a gradient that
    /// has collapsed is close to its zero in its own scale, whatever the step), or closer
    /// than 100 times the state's distance off the constraint (another branch). A reversal that no singular point explains is a coarse
    /// step across a bend of a regular curve, accepted, unless the step also left the curve
    /// by more than a tenth of its length: then it is a step too long for the curve
    /// ([`Finding::TooLong`]), never "a cusp or a crossing". A wildly unstable integration
    /// on a regular curve is otherwise left to the divergence test, and the centre of an
    /// ellipse (a critical point of C off the curve) stops nothing.
    fn regularity(&mut self, formulation: &dyn Formulation, t: f64, q: &[f64]) -> Option<Finding> {
        let g = &self.observation.gradients;
        let reference = &self.ends[self.newest];
        if !reference.valid {
            return None;
        }
        for r in 0..g.n_rows() {
            if self.never_singular[r] {
                continue;
            }
            let row = g.row(r);
            let previous = reference.gradients.row(r);
            // One pass: |g|^2, g . p, |p|^2 give the length, the reversal and the lookahead.
            let (mut gg, mut gp, mut pp) = (0.0, 0.0, 0.0);
            for (g, p) in row.iter().zip(previous) {
                gg += g * g;
                gp += g * p;
                pp += p * p;
            }
            let length = gg.sqrt();
            self.lengths[r] = length;
            let reversed = gp < 0.0;
            let (s, shortest) = lookahead(gg, gp, pp);
            let shrinking = s > 0.0 && shortest < AHEAD_FRACTION * AHEAD_FRACTION * gg;
            let ahead = shrinking.then_some(s);
            let vanished = length < VANISHED * self.longest[r];
            let offset = g.offset(r);
            let drifted = shrinking && offset > 0.0 && {
                let change = (gg - 2.0 * gp + pp).max(0.0).sqrt();
                let step = formulation.row_step_length(r, q, &reference.q);
                off_branch_candidate(offset, length, change, step)
            };
            let candidate = if reversed {
                // The chord's point where the interpolated gradient is shortest, as a step
                // fraction s in [-1, 0] from the current state.
                Some((
                    SingularKind::Reverses,
                    chord_minimum(previous, row) - 1.0,
                    1.0,
                ))
            } else if let Some(steps) = ahead.filter(|&s| s <= AHEAD_STEPS) {
                Some((SingularKind::Ahead, steps, AHEAD_STEPS + 1.0))
            } else if vanished {
                // Collapsed below 1% of its longest: close to the singular point in the row's
                // own scale whatever the step (an adaptive integrator approaching it shrinks
                // its steps without end), so any confirmed point of the curve counts.
                Some((SingularKind::Vanishes, 0.0, f64::INFINITY))
            } else if drifted {
                let probe = if s > 0.0 { s } else { 0.0 };
                Some((SingularKind::OffBranch, probe, f64::INFINITY))
            } else {
                None
            };
            let Some((kind, probe, reach)) = candidate else {
                continue;
            };
            // A reversal is rare and decisive: always searched. Other candidates only once
            // the gradient has halved since a search found nothing.
            if kind != SingularKind::Reverses && length > 0.5 * self.searched[r] {
                continue;
            }
            self.searches += 1;
            let confirmed = if kind == SingularKind::OffBranch {
                self.off_branch(formulation, reference, r, t, q, probe)
            } else {
                self.confirm(formulation, reference, r, t, q, probe, reach)
            };
            if confirmed {
                return Some(Finding::Singular(r, kind));
            }
            if kind == SingularKind::Reverses {
                // No singular point explains the turn: a coarse step across a bend of a
                // regular curve (legitimate, if inaccurate), unless the step also left the
                // curve by more than a tenth of its own length: then it did not follow the
                // curve at all.
                let step = formulation.row_step_length(r, q, &reference.q);
                if offset > TOO_LONG_OFFSET * step {
                    return Some(Finding::TooLong(r, offset));
                }
                continue;
            }
            self.searched[r] = length;
        }
        None
    }

    /// Whether a search from q + probe (q - q_ref) finds a point of the curve where row r's
    /// gradient vanishes within `reach` step lengths of the state q (of the chord from the
    /// reference state, one step earlier, to q, for a reversal).
    #[allow(clippy::too_many_arguments)]
    fn confirm(
        &self,
        formulation: &dyn Formulation,
        reference: &StepEnd,
        r: usize,
        t: f64,
        q: &[f64],
        probe: f64,
        reach: f64,
    ) -> bool {
        let Some((found, now, step)) = self.search(formulation, reference, r, t, q, probe) else {
            return false;
        };
        let distance = if probe < 0.0 {
            // Reversal: the distance to the chord from the previous to the current state.
            let before = formulation.row_variables(r, &reference.q);
            distance_to_segment(&found, &before, &now)
        } else {
            distance(&found, &now)
        };
        reach.is_infinite() || distance <= reach * step
    }

    /// Whether the state is off row r's constraint by more than [`OFF_BRANCH`] times its
    /// distance to a confirmed singular point of the curve ahead.
    fn off_branch(
        &self,
        formulation: &dyn Formulation,
        reference: &StepEnd,
        r: usize,
        t: f64,
        q: &[f64],
        probe: f64,
    ) -> bool {
        let Some((found, now, _)) = self.search(formulation, reference, r, t, q, probe) else {
            return false;
        };
        self.observation.gradients.offset(r) > OFF_BRANCH * distance(&found, &now)
    }

    /// The search for row r's singular point from q + probe (q - q_prev): the point found,
    /// the row's variables now and the length of the last step in them, when the search
    /// converged (|g| reduced below 1e-6 of its start) at a point of the curve.
    fn search(
        &self,
        formulation: &dyn Formulation,
        reference: &StepEnd,
        r: usize,
        t: f64,
        q: &[f64],
        probe: f64,
    ) -> Option<(Vec<f64>, Vec<f64>, f64)> {
        let start: Vec<f64> = q
            .iter()
            .zip(&reference.q)
            .map(|(now, before)| now + probe * (now - before))
            .collect();
        let search = formulation.locate_singular_point(r, t, &start);
        // Reduced by 1e-6, and either small against the row's own scale or reduced by far
        // more: a search from a state far out, after a blow-up, reduces a gradient that has
        // no zero by 1e-6 too, down to the gradient's nonzero minimum, where it stalls; at a
        // zero it goes on (quadratically, or by a constant factor at a cusp) to 1e-12 of its
        // start, even when the scene starts so close to a cusp that its own scale is tiny.
        let row_scale = self.row_scale(r);
        let vanishes = search.reduction <= 1e-6
            && (search.residual <= 1e-6 * row_scale || search.reduction <= 1e-10);
        if !vanishes {
            return None;
        }
        // On the curve: C there vanishes against the row's own scale (see ON_CURVE).
        let scale = row_scale * self.length_scale;
        if search.value.is_nan() || search.value.abs() > ON_CURVE * scale {
            return None;
        }
        let now = formulation.row_variables(r, q);
        let before = formulation.row_variables(r, &reference.q);
        let step = distance(&now, &before);
        Some((search.point, now, step))
    }
}

/// [`System::energy`] bit for bit, without its iterator chains: the particle masses gathered
/// once, the same products and sums in the same order, each sum from the value `Sum` starts
/// from. A system with applied forces (their potentials) takes the system's own path.
#[derive(Default)]
struct EnergyTerms {
    /// 0.5 m and -m per particle
    half_mass: Vec<f64>,
    negative_mass: Vec<f64>,
    gravity: Vec<f64>,
    dim: usize,
    /// What an empty `Sum` of f64 is (-0.0 in current Rust)
    zero: f64,
    /// Whether the system has applied forces
    general: bool,
}

impl EnergyTerms {
    fn of(system: &System) -> Self {
        let masses = system.particles().iter().map(|p| p.mass);
        EnergyTerms {
            half_mass: masses.clone().map(|m| 0.5 * m).collect(),
            negative_mass: masses.map(|m| -m).collect(),
            gravity: system.gravity().to_vec(),
            dim: system.dim(),
            zero: std::iter::empty::<f64>().sum(),
            general: !system.forces().is_empty(),
        }
    }

    fn energy(&self, system: &System, x: &[f64], v: &[f64]) -> f64 {
        if self.general {
            return system.energy(x, v);
        }
        // Systems are 2D or 3D (`ModelError::BadDimension`).
        let energy = match self.dim {
            2 => self.gravity_energy::<2>(x, v),
            _ => self.gravity_energy::<3>(x, v),
        };
        debug_assert_eq!(energy.to_bits(), system.energy(x, v).to_bits());
        energy
    }

    /// T + V under gravity alone, D coordinates a particle: the sums of `System::energy` in
    /// its order (kinetic sum_p m_p/2 |v_p|^2 and gravity sum_p -m_p g . x_p, each term's
    /// own sum from -0.0), the two running sums in one pass so that their additions overlap.
    fn gravity_energy<const D: usize>(&self, x: &[f64], v: &[f64]) -> f64 {
        let gravity_vector: &[f64; D] = self.gravity.as_slice().try_into().expect("D entries");
        let mut kinetic = self.zero;
        let mut gravity = self.zero;
        let particles = x.as_chunks::<D>().0.iter().zip(v.as_chunks::<D>().0);
        let masses = self.half_mass.iter().zip(&self.negative_mass);
        for ((xp, vp), (&half_mass, &negative_mass)) in particles.zip(masses) {
            let mut s = self.zero;
            let mut gx = self.zero;
            for k in 0..D {
                s += vp[k] * vp[k];
                gx += gravity_vector[k] * xp[k];
            }
            kinetic += half_mass * s;
            gravity += negative_mass * gx;
        }
        // The applied forces' potentials: an empty sum.
        kinetic + (gravity + self.zero)
    }
}

/// What the regularity monitor found at a step's end.
enum Finding {
    /// Row r is singular there (a confirmed point of the curve where it vanishes).
    Singular(usize, SingularKind),
    /// Row r reversed direction within the step with no singular point to explain it, and
    /// the step ended this far off its constraint.
    TooLong(usize, f64),
}

/// Whether a state `offset` off a row's constraint may follow another branch near a point
/// where the gradient vanishes: offset > 1/100 of |g| l / |d|, the distance over which the
/// gradient (length |g|, changed by |d| over a step of length l) would vanish. Shared with
/// the ensemble lanes, which hand a member over on the same test.
pub(super) fn off_branch_candidate(offset: f64, length: f64, change: f64, step: f64) -> bool {
    offset * change > OFF_BRANCH * length * step
}

impl Monitor {
    /// Row r's gradient length scale: its length at the start, or its longest in the run
    /// when it started at zero (a run that starts at a singular point is refused anyway).
    fn row_scale(&self, r: usize) -> f64 {
        if self.initial[r] > 0.0 {
            self.initial[r]
        } else {
            self.longest[r]
        }
    }
}

/// What the regularity monitor keeps of an accepted step's end.
#[derive(Clone, Debug, Default)]
struct StepEnd {
    gradients: crate::formulation::Gradients,
    /// The formulation's q (n)
    q: Vec<f64>,
    /// Whether it holds a step end yet
    valid: bool,
}

/// The fraction u in [0, 1] at which p + u (g - p) is shortest.
fn chord_minimum(p: &[f64], g: &[f64]) -> f64 {
    let (mut pd, mut dd) = (0.0, 0.0);
    for (p, g) in p.iter().zip(g) {
        pd += p * (g - p);
        dd += (g - p) * (g - p);
    }
    if dd > 0.0 {
        (-pd / dd).clamp(0.0, 1.0)
    } else {
        0.5
    }
}

/// With `row` = g now and `previous` = p one step earlier: the number of steps s > 0 after
/// which the linear extrapolation g + s (g - p) is shortest, when it is then shorter than
/// `fraction` |g|; None when the extrapolation never comes that close to zero.
fn steps_to_vanish(row: &[f64], previous: &[f64], fraction: f64) -> Option<f64> {
    let (mut gg, mut gp, mut pp) = (0.0, 0.0, 0.0);
    for (g, p) in row.iter().zip(previous) {
        gg += g * g;
        gp += g * p;
        pp += p * p;
    }
    let (s, shortest) = lookahead(gg, gp, pp);
    (s > 0.0 && shortest < fraction * fraction * gg).then_some(s)
}

/// From |g|^2, g . p and |p|^2: the step count s at which g + s (g - p) is shortest and its
/// squared length there, |g|^2 - (g.d)^2 / |d|^2 with d = g - p; (NaN, NaN) when g = p.
pub(super) fn lookahead(gg: f64, gp: f64, pp: f64) -> (f64, f64) {
    lookahead_along(gg, gg - gp, gg - 2.0 * gp + pp)
}

/// [`lookahead`] from |g|^2, g . d and |d|^2.
pub(super) fn lookahead_along(gg: f64, gd: f64, dd: f64) -> (f64, f64) {
    if dd.is_nan() || dd <= 0.0 {
        return (f64::NAN, f64::NAN);
    }
    (-gd / dd, (gg - gd * gd / dd).max(0.0))
}

pub(super) fn norm(v: &[f64]) -> f64 {
    v.iter().map(|c| c * c).sum::<f64>().sqrt()
}

/// The distance from `p` to the segment from `a` to `b`.
fn distance_to_segment(p: &[f64], a: &[f64], b: &[f64]) -> f64 {
    let (mut ap_ab, mut ab_ab) = (0.0, 0.0);
    for ((p, a), b) in p.iter().zip(a).zip(b) {
        ap_ab += (p - a) * (b - a);
        ab_ab += (b - a) * (b - a);
    }
    let u = if ab_ab > 0.0 {
        (ap_ab / ab_ab).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.iter()
        .zip(a)
        .zip(b)
        .map(|((p, a), b)| {
            let c = a + u * (b - a);
            (p - c) * (p - c)
        })
        .sum::<f64>()
        .sqrt()
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt()
}
