//! The run's monitors for every lane at once (structure of arrays, lanes innermost): the
//! checks of `Simulation::accept` after each step, with the same operations in the same order
//! per lane as [`super::monitor::Monitor`] and the formulations' `observe`, so that every
//! figure is the member's own, bit for bit.
//!
//! Per step end, from the observation tape's outputs for all lanes:
//!
//! ```text
//! observation   x, xdot; C (m rows); gradient rows g_r; offset_r = |C_r| / |g_r| (implicit)
//! energy        E = sum_p m_p |v_p|^2 / 2 - sum_p m_p g . x_p (+ the forces' potentials)
//! divergence    E, max |C| finite; |E - E0| <= 10^6 E_scale where watched; |x_k| <= position
//!               limit(t); |xdot_k| <= speed limit(t)
//! regularity    a first-order candidate of `Monitor::regularity` for any row (see
//!               [`super::lanes`]): g.p < 0, the shortest |g| ahead within 2 steps, |g| below
//!               1e-2 of its longest, an off-branch drift, or |g| NaN (the lookahead and
//!               the drift by products, a superset: [`first_order_candidates`])
//! maxima        max |E - E0| (divided by E_scale when read: [`LaneMonitor::maxima_of`]),
//!               max |C|, max offset
//! ```
//!
//! A lane that fails a check is handed back to its own `Simulation` (see [`super::lanes`]).
//! What has no form across lanes is done per lane by the same code as alone: the energy of
//! forces other than gravity, the constraint values of native or Rust rows seen by the
//! parametric form, and the stop condition's screen.

// Loops run over the lanes innermost and index several arrays by lane.
#![allow(clippy::needless_range_loop)]

use super::monitor::Monitor;
use super::monitor::{AHEAD_FRACTION, AHEAD_STEPS, OFF_BRANCH, VANISHED};
use crate::expr::Tape;
use crate::formulation::Method;
use crate::linalg::max_nan;
use crate::model::{ConstraintEval, System};

/// One lane's last and before gradient values, longest lengths, lengths at the last
/// fruitless search and maxima (see [`LaneMonitor::lane`]).
pub(super) type LaneState = (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>, [f64; 4]);

/// One value per lane.
pub(super) type PerLane<const L: usize> = [f64; L];

/// Where a form's observation comes from in the observation tape's outputs.
enum Source {
    /// x = q, xdot = qdot; outputs C (m rows), then J's entries in gradient-row order.
    Implicit {
        /// Row r's coordinates (for the step's length in them)
        row_columns: Vec<Vec<usize>>,
    },
    /// Outputs x (n), xdot (n), then the map's Jacobian entries; gradient value i is entry
    /// `gather[i]` (column by column). C comes from the constraint value tape at x.
    Parametric {
        gather: Vec<usize>,
        /// The value tape when every constraint row is on it (else each lane's residuals)
        values: Option<Tape>,
    },
}

/// The monitors' state and scratch for L members (value k of lane l at `k * L + l`): the
/// sweep lanes' 16, or one for a single run's express steps (`super::express`).
pub(super) struct LaneMonitor<const L: usize> {
    source: Source,
    n: usize,
    m: usize,
    /// Gradient row r owns values start[r]..start[r + 1]
    start: Vec<usize>,
    /// Whether row r is watched for singular points (`Monitor` watches no rod or pin)
    watched: Vec<bool>,
    /// The last accepted step end's gradient values, the one before (both empty when no row
    /// is watched, as `Monitor` keeps none then), and the longest each row has been
    pub(super) last: Vec<f64>,
    pub(super) before: Vec<f64>,
    pub(super) longest: Vec<f64>,
    /// Each row's length when a search for a singular point last found none (infinite when
    /// none did: a lane member's start), as the regularity monitor keeps it
    pub(super) searched: Vec<f64>,
    /// max |E - E0| / E_scale, max |E - W - E0| / E_scale, max |C|, max offset, as loaded;
    /// the first two also take in `change_max` (see [`Self::maxima_of`])
    maxima: [PerLane<L>; 4],
    /// max |E - E0| over the steps accepted since the load: the energy maxima divided by
    /// E_scale once, when read, not at every step
    change_max: PerLane<L>,
    energy_initial: PerLane<L>,
    energy_scale: PerLane<L>,
    /// The limit of |E - E0| ([`Monitor`]'s energy watch; infinite where none)
    energy_limit: PerLane<L>,
    /// Each member's divergence limits at t = 0: position, speed (see [`Monitor::floor`])
    floor: [PerLane<L>; 2],
    /// This step end's gradient values, offsets, constraint values and energies (the
    /// gradient and constraint values of the parametric form only: the implicit form's stay
    /// in the observation tape's outputs, see [`observed`]; `values` is sized for them)
    values: Vec<f64>,
    offset: Vec<f64>,
    /// |g_r|^2 per row (summed from -0.0, as `sum()`) and |g_r|
    squared: Vec<f64>,
    lengths: Vec<f64>,
    constraints: Vec<f64>,
    energy: PerLane<L>,
    constraint_error: PerLane<L>,
    /// The value tape's variables (x, 0, t) and scratch (parametric form)
    vars: Vec<f64>,
    scratch: Vec<f64>,
    /// One lane's x and xdot, and a workspace for its constraint values
    x_one: Vec<f64>,
    xdot_one: Vec<f64>,
    residuals: ConstraintEval,
}

/// A structure-of-arrays buffer as its values' rows of L (fixed-size arrays, so that
/// the lane loops over them compile to vector instructions without bounds checks).
fn rows<const L: usize>(soa: &[f64]) -> &[PerLane<L>] {
    let (rows, rest) = soa.as_chunks::<L>();
    debug_assert!(rest.is_empty(), "a buffer of whole rows of lanes");
    rows
}

/// Whether any of the first `count` of `flags` is set: one pass without a branch per lane,
/// which the compiler makes a few vector instructions (a scan that stops at the first set
/// flag costs a compare and a branch per lane, and the lanes ask several times a step).
#[inline(always)]
pub(super) fn any_of<const L: usize>(flags: &[bool; L], count: usize) -> bool {
    (0..L).fold(false, |any, l| any | (flags[l] & (l < count)))
}

/// Below this, gg or offset^2 may have lost the relative precision that
/// [`first_order_candidates`]' margin counts on: a lane whose test depends on one is flagged.
/// (Far from the magnitudes of any scene: |g|^2 of 1e-280 is a gradient of length 1e-140.)
const TINY: f64 = 1e-280;

/// The margin of [`first_order_candidates`]' bounds: 1e-9, some 10^5 times what their
/// rounding (a few units of 2^-53 each) moves them.
const MARGIN: f64 = 1.0 - 1e-9;

/// A superset of two first-order candidates of `Monitor::regularity` for a watched row
/// (|g|^2 = gg at the step end, g . p = gp and |p|^2 = pp against the
/// last step end's p, the state `offset` off the row's constraint, the step's squared
/// length `step` in the row's variables), by products in place of the quotients and roots
/// of `lookahead` and `off_branch_candidate`, with no branch, so that the lanes run in
/// vector registers. With d = g - p (gd = g . d, dd = |d|^2 > 0) the monitor's tests are
///
/// ```text
/// shrinking   s = -gd/dd > 0  and  gg - gd^2/dd < gg/4     ahead    shrinking and s <= 2
/// drifted     shrinking, offset > 0 and offset |d| > 0.01 |g| sqrt(step)
/// ```
///
/// and these are taken, each implied by the monitor's in floating point (the lanes err
/// towards leaving, and a member that leaves meets the monitor's own tests):
///
/// ```text
/// shrinking'  gd < 0  and  gd^2 >= (1 - 1e-9) (3/4) gg dd
/// ahead'      shrinking' and -gd <= 2 dd        (exact: the quotient rounds above 2 otherwise)
/// drifted'    shrinking', offset > 0 and offset^2 dd >= (1 - 1e-9) (0.01)^2 gg step
/// ```
///
/// The monitor's tests, true, give the real inequalities with 3/4 and 1e-4 less a few
/// units of 2^-53 where gg and offset^2 are normal (where they are below [`TINY`] the tests
/// are taken as true); a product below the bound (the margin's 1e-9) then rounds to at most
/// the float it is below, as rounding is monotone, whatever the products' magnitudes.
#[inline(always)]
pub(super) fn first_order_candidates(
    gg: f64,
    gp: f64,
    pp: f64,
    offset: f64,
    step: f64,
) -> (bool, bool) {
    candidates_along(gg, gg - gp, gg - 2.0 * gp + pp, offset, step)
}

/// [`first_order_candidates`] from gg, gd and dd.
#[inline(always)]
fn candidates_along(gg: f64, gd: f64, dd: f64, offset: f64, step: f64) -> (bool, bool) {
    let unsure = (gg < TINY) | gg.is_nan();
    let shrinks = MARGIN * (1.0 - AHEAD_FRACTION * AHEAD_FRACTION) * gg * dd;
    let shrinking = (dd > 0.0) & (gd < 0.0) & ((gd * gd >= shrinks) | unsure);
    let ahead = shrinking & (-gd <= AHEAD_STEPS * dd);
    let squared = offset * offset;
    let bound = MARGIN * OFF_BRANCH * OFF_BRANCH * gg * step;
    let drifted =
        shrinking & (offset > 0.0) & ((squared * dd >= bound) | (squared < TINY) | unsure);
    (ahead, drifted)
}

/// Lane l's part of a structure-of-arrays buffer into `one`.
pub(super) fn gather<const L: usize>(soa: &[f64], l: usize, one: &mut [f64]) {
    for (k, value) in one.iter_mut().enumerate() {
        *value = soa[k * L + l];
    }
}

impl<const L: usize> LaneMonitor<L> {
    /// The monitors of `members` (at most L; lanes beyond them repeat the first), as each
    /// member's own monitor stands after its last accepted step end (or before its first
    /// step), its observation that step end's.
    pub(super) fn new(system: &System, method: Method, members: &[&Monitor]) -> LaneMonitor<L> {
        let template = &members[0].observation;
        let start = template.gradients.start.clone();
        let n_values = template.gradients.n_entries();
        let rows = start.len() - 1;
        let set = system.constraints();
        let source = match method {
            Method::Implicit => Source::Implicit {
                row_columns: (0..rows).map(|r| set.row_columns(r).to_vec()).collect(),
            },
            Method::Parametric => {
                let map = system.parametric().expect("checked by lanes_can_run");
                Source::Parametric {
                    gather: (0..map.n_q())
                        .flat_map(|j| map.column_entries(j).iter().copied())
                        .collect(),
                    values: set.only_taped().then(|| set.value_tape().clone()),
                }
            }
        };
        let n = system.n_coords();
        let m = set.n_rows();
        let watched: Vec<bool> = members[0]
            .never_singular()
            .iter()
            .map(|&never| !never)
            .collect();
        let n_kept = if watched.contains(&true) { n_values } else { 0 };
        let mut monitor = LaneMonitor::<L> {
            source,
            n,
            m,
            start,
            watched,
            before: vec![0.0; n_kept * L],
            last: vec![0.0; n_kept * L],
            longest: vec![0.0; rows * L],
            searched: vec![0.0; rows * L],
            maxima: [[0.0; L]; 4],
            change_max: [0.0; L],
            energy_initial: [0.0; L],
            floor: [[0.0; L]; 2],
            energy_scale: [0.0; L],
            energy_limit: [f64::INFINITY; L],
            values: vec![0.0; n_values * L],
            offset: vec![0.0; rows * L],
            squared: vec![0.0; rows * L],
            lengths: vec![0.0; rows * L],
            constraints: vec![0.0; m * L],
            energy: [0.0; L],
            constraint_error: [0.0; L],
            vars: vec![0.0; (2 * n + 1) * L],
            scratch: Vec::new(),
            x_one: vec![0.0; n],
            xdot_one: vec![0.0; n],
            residuals: set.workspace(),
        };
        monitor.load(members);
        monitor
    }

    /// Take the state of `members`' monitors (at most L, of this monitor's system and form;
    /// lanes beyond them repeat the first), as each stands after its last accepted step end
    /// (or before its first step): the regularity monitor's last two step ends, the longest
    /// gradient lengths, the maxima, the energy reference and the divergence limits.
    pub(super) fn load(&mut self, members: &[&Monitor]) {
        let monitor = |l: usize| members[l.min(members.len() - 1)];
        let soa = |buffer: &mut [f64], of: &dyn Fn(&Monitor) -> &[f64]| {
            for l in 0..L {
                let values = of(monitor(l));
                debug_assert_eq!(values.len() * L, buffer.len());
                for (k, v) in values.iter().enumerate() {
                    buffer[k * L + l] = *v;
                }
            }
        };
        let per_lane = |of: &dyn Fn(&Monitor) -> f64| std::array::from_fn(|l| of(monitor(l)));
        // The regularity monitor's reference: the last accepted step end (the initial state
        // before the first step), and the one before it (the reference itself if none).
        soa(&mut self.last, &|m| end_gradients(m, true));
        soa(&mut self.before, &|m| end_gradients(m, false));
        soa(&mut self.longest, &|m| m.longest());
        soa(&mut self.searched, &|m| m.searched());
        self.maxima = [
            per_lane(&|m| m.energy_rel_error_max),
            per_lane(&|m| m.balance_error_max),
            per_lane(&|m| m.constraint_error_max),
            per_lane(&|m| m.constraint_distance_max),
        ];
        self.change_max = [0.0; L];
        self.energy_initial = per_lane(&|m| m.energy_initial);
        self.energy_scale = per_lane(&|m| m.energy_scale);
        self.energy_limit = per_lane(&|m| m.energy_watch.map_or(f64::INFINITY, |w| w.limit));
        self.floor = [per_lane(&|m| m.floor().0), per_lane(&|m| m.floor().1)];
    }

    /// Lane l's last and before gradient values, longest lengths, lengths at the last
    /// fruitless search and maxima (for a handover).
    pub(super) fn lane(&self, l: usize) -> LaneState {
        let one = |soa: &[f64]| {
            let mut v = vec![0.0; soa.len() / L];
            gather::<L>(soa, l, &mut v);
            v
        };
        (
            one(&self.last),
            one(&self.before),
            one(&self.longest),
            one(&self.searched),
            self.maxima_of(l),
        )
    }

    /// Lane l's maxima as its own monitor holds them: max |E - E0| / E_scale, max |E - W -
    /// E0| / E_scale, max |C|, max offset. The energy's two are the loaded maxima and
    /// max |E - E0| over the steps since, divided by E_scale once: a division by the same
    /// positive E_scale is monotone, so fl(max a / s) = max fl(a / s), the maximum of the
    /// quotients the monitor takes at each step, and W = 0 in the lanes, so E - W - E0 has
    /// the bits of E - E0 (E - 0.0 is E, -0.0 included).
    pub(super) fn maxima_of(&self, l: usize) -> [f64; 4] {
        let [energy, balance, constraint, distance] = self.maxima.map(|m| m[l]);
        let change = self.change_max[l] / self.energy_scale[l];
        [
            max_nan(energy, change),
            max_nan(balance, change),
            constraint,
            distance,
        ]
    }

    /// The particle positions and velocities of the observation tape's outputs `out` (the
    /// parametric form) or the state (q, qdot) (the implicit form), all lanes.
    fn particle_state<'a>(
        &self,
        out: &'a [f64],
        q: &'a [f64],
        qdot: &'a [f64],
    ) -> (&'a [f64], &'a [f64]) {
        let n = self.n;
        match self.source {
            Source::Implicit { .. } => (q, qdot),
            Source::Parametric { .. } => (&out[..n * L], &out[n * L..2 * n * L]),
        }
    }

    /// Lane l's particle positions and velocities (see [`LaneMonitor::check`]'s arguments).
    pub(super) fn lane_state(
        &mut self,
        out: &[f64],
        q: &[f64],
        qdot: &[f64],
        l: usize,
    ) -> (&[f64], &[f64]) {
        let (x, xdot) = self.particle_state(out, q, qdot);
        gather::<L>(x, l, &mut self.x_one);
        gather::<L>(xdot, l, &mut self.xdot_one);
        (&self.x_one, &self.xdot_one)
    }

    /// The checks at the end of a step, for every lane: lane l's step ends at `t[l]`, `out`
    /// is the observation tape's outputs, (q, qdot) the state and `q_back` the step's start;
    /// the first `count` lanes are members (or a run's consecutive steps: see
    /// [`Self::chain_from`]), and `limits(l, t)` is member l's reach at t
    /// ([`Monitor::limits`]). Returns which lanes fail one and must leave; the others'
    /// observation stays for [`LaneMonitor::accept`].
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn check(
        &mut self,
        system: &System,
        count: usize,
        limits: impl Fn(usize, f64) -> (f64, f64),
        t: &PerLane<L>,
        out: &[f64],
        q: &[f64],
        qdot: &[f64],
        q_back: &[f64],
    ) -> [bool; L] {
        self.observe(system, count, t, out);
        self.check_observed(system, count, limits, t, out, q, qdot, q_back)
    }

    /// [`Self::check`] after [`Self::observe`] of the same step ends.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn check_observed(
        &mut self,
        system: &System,
        count: usize,
        limits: impl Fn(usize, f64) -> (f64, f64),
        t: &PerLane<L>,
        out: &[f64],
        q: &[f64],
        qdot: &[f64],
        q_back: &[f64],
    ) -> [bool; L] {
        let mut failed = [false; L];
        // The state is finite.
        for (q, qdot) in rows::<L>(q).iter().zip(rows::<L>(qdot)) {
            failed = std::array::from_fn(|l| failed[l] | !q[l].is_finite() | !qdot[l].is_finite());
        }
        let (x, xdot) = self.particle_state(out, q, qdot);
        // E = T + V, as `System::energy`.
        if system.forces().is_empty() {
            energy_across_lanes::<L>(system, x, xdot, &mut self.energy);
        } else {
            for l in 0..count {
                gather::<L>(x, l, &mut self.x_one);
                gather::<L>(xdot, l, &mut self.xdot_one);
                self.energy[l] = system.energy(&self.x_one, &self.xdot_one);
            }
        }
        // Divergence: E and max |C| finite, every coordinate within the member's reach.
        let own = (&self.constraints[..], &self.values[..]);
        let (constraints, values) = observed::<L>(&self.source, self.m, own, out);
        let mut constraint_error = [0.0; L];
        for c in rows::<L>(constraints) {
            for l in 0..L {
                constraint_error[l] = max_nan(constraint_error[l], c[l].abs());
            }
        }
        // Within the limits at t = 0, the least at any time (`Monitor::check_divergence`): a
        // lane whose every coordinate is within them needs no limits of its own time (a NaN
        // fails the comparison and takes the full test).
        let beyond_floor = beyond::<L>(x, xdot, &self.floor);
        if any_of(&beyond_floor, count) {
            let mut reach = [[f64::INFINITY; L]; 2];
            for l in 0..count {
                if beyond_floor[l] {
                    (reach[0][l], reach[1][l]) = limits(l, t[l]);
                }
            }
            for (failed, beyond) in failed.iter_mut().zip(beyond::<L>(x, xdot, &reach)) {
                *failed |= beyond;
            }
        }
        for l in 0..L {
            let change = (self.energy[l] - self.energy_initial[l]).abs();
            failed[l] |= !self.energy[l].is_finite()
                | !constraint_error[l].is_finite()
                | (change > self.energy_limit[l]);
        }
        self.constraint_error = constraint_error;
        // Regularity candidates, row by row: the first-order tests of `Monitor::regularity`,
        // without its memory of earlier fruitless searches (so erring towards leaving). They
        // only compare, so |g|^2 summed from -0.0 serves for `sum` from 0.0.
        let (values, last) = (rows::<L>(values), rows::<L>(&self.last));
        let (q, q_back) = (rows::<L>(q), rows::<L>(q_back));
        let (squared, lengths, offset, longest, searched) = (
            rows::<L>(&self.squared),
            rows::<L>(&self.lengths),
            rows::<L>(&self.offset),
            rows::<L>(&self.longest),
            rows::<L>(&self.searched),
        );
        for r in 0..self.start.len() - 1 {
            if !self.watched[r] {
                // A rod or a pin (`Monitor` does not watch it): only a NaN flags.
                for l in 0..L {
                    failed[l] |= lengths[r][l].is_nan();
                }
                continue;
            }
            // g . p and |p|^2 against the last step end's row p. (The lane loops build new
            // arrays from old ones rather than update them in place: values, not memory that
            // might alias the inputs, so that they compile to vector instructions.)
            let (mut gp, mut pp) = ([0.0; L], [0.0; L]);
            for e in self.start[r]..self.start[r + 1] {
                let (g, p) = (&values[e], &last[e]);
                gp = std::array::from_fn(|l| gp[l] + g[l] * p[l]);
                pp = std::array::from_fn(|l| pp[l] + p[l] * p[l]);
            }
            // The step's length in the row's variables (`row_step_length`; for a drift).
            let add_step = |step: PerLane<L>, k: usize| -> PerLane<L> {
                let (q, before) = (&q[k], &q_back[k]);
                std::array::from_fn(|l| {
                    let d = q[l] - before[l];
                    step[l] + d * d
                })
            };
            let step = match &self.source {
                Source::Implicit { row_columns } => row_columns[r]
                    .iter()
                    .fold([empty_sum(); L], |step, &k| add_step(step, k)),
                Source::Parametric { .. } => (0..q.len()).fold([empty_sum(); L], add_step),
            };
            let (gg, length, offset) = (&squared[r], &lengths[r], &offset[r]);
            let (longest, searched) = (&longest[r], &searched[r]);
            for l in 0..L {
                let (gg, gp, pp, length) = (gg[l], gp[l], pp[l], length[l]);
                let (ahead, drifted) = first_order_candidates(gg, gp, pp, offset[l], step[l]);
                // A candidate other than a reversal is searched only once the gradient has
                // halved since a search found nothing.
                let remembered = length > 0.5 * searched[l];
                failed[l] |= (gp < 0.0)
                    | (!remembered & (ahead | (length < VANISHED * longest[l]) | drifted))
                    | length.is_nan();
            }
        }
        failed
    }

    /// C, the gradient values and the offsets |C_r| / |g_r| (0 for the parametric form) of
    /// every lane from the observation tape's outputs, as the formulations' `observe`.
    #[inline(always)]
    pub(super) fn observe(&mut self, system: &System, count: usize, t: &PerLane<L>, out: &[f64]) {
        let (n, m) = (self.n, self.m);
        match &self.source {
            Source::Implicit { .. } => {
                if m == 0 {
                    return;
                }
                // C and the gradient values stay in `out`.
                let own = (&self.constraints[..], &self.values[..]);
                let (constraints, values) = observed::<L>(&self.source, m, own, out);
                // |C_r| / |g_r| (as `observe_from`).
                row_lengths::<L>(&self.start, values, &mut self.squared, &mut self.lengths);
                for ((offset, c), length) in
                    self.offset.iter_mut().zip(constraints).zip(&self.lengths)
                {
                    *offset = c.abs() / length;
                }
            }
            Source::Parametric {
                gather: entries,
                values,
            } => {
                let jacobian = &out[2 * n * L..];
                for (i, &e) in entries.iter().enumerate() {
                    self.values[i * L..(i + 1) * L].copy_from_slice(&jacobian[e * L..(e + 1) * L]);
                }
                row_lengths::<L>(
                    &self.start,
                    &self.values,
                    &mut self.squared,
                    &mut self.lengths,
                );
                if m == 0 {
                    return;
                }
                let x = &out[..n * L];
                match values {
                    Some(tape) => {
                        self.vars[..n * L].copy_from_slice(x);
                        self.vars[2 * n * L..].copy_from_slice(t);
                        self.scratch.resize(tape.n_slots() * L, 0.0);
                        tape.eval_lanes::<L>(&self.vars, &mut self.scratch, &mut self.constraints);
                    }
                    None => {
                        let set = system.constraints();
                        for l in 0..count {
                            gather::<L>(x, l, &mut self.x_one);
                            let c = set.residuals(t[l], &self.x_one, &mut self.residuals);
                            for (r, v) in c.iter().enumerate() {
                                self.constraints[r * L + l] = *v;
                            }
                        }
                    }
                }
            }
        }
    }

    /// Every lane's step end accepted (lanes that left no longer matter; `out` is the
    /// observation tape's outputs [`Self::check`] was given): the regularity monitor's
    /// reference and the maxima move on, as `Monitor::remember` and `Monitor::accumulate` do.
    #[inline(always)]
    pub(super) fn accept(&mut self, out: &[f64]) {
        std::mem::swap(&mut self.before, &mut self.last);
        if !self.last.is_empty() {
            let own = (&self.constraints[..], &self.values[..]);
            let (_, values) = observed::<L>(&self.source, self.m, own, out);
            self.last.copy_from_slice(values);
        }
        let mut distance = [0.0; L];
        for ((longest, length), offset) in (self.longest.as_chunks_mut::<L>().0.iter_mut())
            .zip(rows::<L>(&self.lengths))
            .zip(rows::<L>(&self.offset))
        {
            *longest = std::array::from_fn(|l| longest[l].max(length[l]));
            distance = std::array::from_fn(|l| max_nan(distance[l], offset[l].abs()));
        }
        // Away from where the last search found nothing: search again next time.
        for (searched, length) in
            (self.searched.as_chunks_mut::<L>().0.iter_mut()).zip(rows::<L>(&self.lengths))
        {
            *searched = std::array::from_fn(|l| {
                if length[l] > 2.0 * searched[l] {
                    f64::INFINITY
                } else {
                    searched[l]
                }
            });
        }
        let [_, _, constraint_max, distance_max] = &mut self.maxima;
        for l in 0..L {
            let change = (self.energy[l] - self.energy_initial[l]).abs();
            self.change_max[l] = max_nan(self.change_max[l], change);
            constraint_max[l] = max_nan(constraint_max[l], self.constraint_error[l]);
            distance_max[l] = max_nan(distance_max[l], distance[l]);
        }
    }
}

/// Lanes as consecutive steps of one run, for a run's steps checked in batches
/// (`super::express`): lane l is the step after lane l - 1.
impl<const L: usize> LaneMonitor<L> {
    /// After [`Self::observe`] of the batch's step ends `out`, give each lane the memory the
    /// run's monitor `one` (as it stood before the batch's first step) would hold after
    /// accepting the steps before it, as [`Self::accept`] moves it on: the last step end's
    /// gradient values, the longest lengths and the lengths at the last fruitless search;
    /// the maxima start from `one`'s in every lane (see [`Self::hand_prefix`]).
    #[inline(always)]
    pub(super) fn chain_from(&mut self, one: &LaneMonitor<1>, out: &[f64]) {
        if !self.last.is_empty() {
            let own = (&self.constraints[..], &self.values[..]);
            let (_, values) = observed::<L>(&self.source, self.m, own, out);
            for (k, row) in self.last.as_chunks_mut::<L>().0.iter_mut().enumerate() {
                row[0] = one.last[k];
                row[1..].copy_from_slice(&values[k * L..(k + 1) * L - 1]);
            }
        }
        let rows = self.longest.len() / L;
        for r in 0..rows {
            let (mut longest, mut searched) = (one.longest[r], one.searched[r]);
            for l in 0..L {
                self.longest[r * L + l] = longest;
                self.searched[r * L + l] = searched;
                let length = self.lengths[r * L + l];
                longest = longest.max(length);
                if length > 2.0 * searched {
                    searched = f64::INFINITY;
                }
            }
        }
        self.maxima = one.maxima.map(|[m]| [m; L]);
        self.change_max = [one.change_max[0]; L];
    }

    /// `one` (the run's monitor a batch was chained from, [`Self::chain_from`]) after
    /// accepting the batch's first `j` >= 1 steps, once [`Self::accept`] has accepted the
    /// batch: lane j - 1's memory, the one before it, and the running maxima over lanes 0 to
    /// j - 1 (each lane holds max(start, its own value); `max_nan` of magnitudes is
    /// associative, and equal ones have equal bits, so the sequential maxima's).
    #[inline(always)]
    pub(super) fn hand_prefix(&self, one: &mut LaneMonitor<1>, j: usize) {
        debug_assert!((1..=L).contains(&j));
        for k in 0..one.last.len() {
            one.before[k] = if j >= 2 {
                self.last[k * L + j - 2]
            } else {
                one.last[k]
            };
            one.last[k] = self.last[k * L + j - 1];
        }
        for r in 0..one.longest.len() {
            one.longest[r] = self.longest[r * L + j - 1];
            one.searched[r] = self.searched[r * L + j - 1];
        }
        let prefix = |lanes: &PerLane<L>| lanes[..j].iter().copied().reduce(max_nan);
        for (kept, lanes) in one.maxima.iter_mut().zip(&self.maxima) {
            kept[0] = prefix(lanes).expect("j >= 1");
        }
        one.change_max[0] = prefix(&self.change_max).expect("j >= 1");
    }
}

/// A step end's constraint values and gradient values, after [`LaneMonitor::observe`] of the
/// observation tape's outputs `out`: `out` itself for the implicit form (no copy: C for m
/// rows, then the gradient values, as many as `own`'s second holds), `own` (the monitor's
/// gathered and evaluated values) for the parametric form.
#[inline(always)]
fn observed<'a, const L: usize>(
    source: &Source,
    m: usize,
    own: (&'a [f64], &'a [f64]),
    out: &'a [f64],
) -> (&'a [f64], &'a [f64]) {
    match source {
        Source::Implicit { .. } if m == 0 => (&[], &[]),
        Source::Implicit { .. } => {
            let (rows, values) = (m * L, own.1.len());
            (&out[..rows], &out[rows..rows + values])
        }
        Source::Parametric { .. } => own,
    }
}

/// The gradient values of `monitor`'s last accepted step end (`newest`) or of the one
/// before it (the last one's when there is none yet).
fn end_gradients(monitor: &Monitor, newest: bool) -> &[f64] {
    let end = monitor.step_end(newest).or(monitor.step_end(true));
    end.expect("a monitor holds its last step end").1
}

/// What `Iterator::sum` of no f64 is (-0.0 in current Rust): every sum here starts from it,
/// as the scalar code's `sum()` does.
fn empty_sum() -> f64 {
    std::iter::empty::<f64>().sum()
}

/// Which lanes have a coordinate beyond their `limits` (position, speed) or NaN.
#[inline(always)]
fn beyond<const L: usize>(x: &[f64], xdot: &[f64], limits: &[PerLane<L>; 2]) -> [bool; L] {
    let [position, speed] = limits;
    let mut beyond = [false; L];
    for (x, xdot) in rows::<L>(x).iter().zip(rows::<L>(xdot)) {
        beyond = std::array::from_fn(|l| {
            beyond[l]
                | x[l].is_nan()
                | (x[l].abs() > position[l])
                | xdot[l].is_nan()
                | (xdot[l].abs() > speed[l])
        });
    }
    beyond
}

/// |g_r|^2 and |g_r| of every row r (entries start[r]..start[r + 1] of `values`) and lane,
/// summed from [`empty_sum`] as `sum()` (then the root: `norm`'s bits).
#[inline(always)]
fn row_lengths<const L: usize>(
    start: &[usize],
    values: &[f64],
    squared: &mut [f64],
    lengths: &mut [f64],
) {
    let values = rows::<L>(values);
    let squared = squared.as_chunks_mut::<L>().0;
    let lengths = lengths.as_chunks_mut::<L>().0;
    for (r, (gg, length)) in squared.iter_mut().zip(lengths).enumerate() {
        let mut sum = [empty_sum(); L];
        for g in &values[start[r]..start[r + 1]] {
            sum = std::array::from_fn(|l| sum[l] + g[l] * g[l]);
        }
        *gg = sum;
        *length = sum.map(f64::sqrt);
    }
}

/// E = T + V of every lane with gravity the only force, as `System::energy`: the same sums
/// in the same order (sum() from -0.0), lanes innermost.
///
/// ```text
/// T = sum_p m_p/2 sum_a v_pa^2,   V = sum_p -m_p sum_a g_a x_pa
/// ```
#[inline(always)]
fn energy_across_lanes<const L: usize>(
    system: &System,
    x: &[f64],
    xdot: &[f64],
    energy: &mut PerLane<L>,
) {
    let dim = system.dim();
    let gravity = system.gravity();
    let zero = empty_sum();
    let (x, xdot) = (rows::<L>(x), rows::<L>(xdot));
    let mut kinetic = [zero; L];
    let mut potential = [zero; L];
    for (p, particle) in system.particles().iter().enumerate() {
        let mut s = [zero; L];
        let mut gx = [zero; L];
        for a in 0..dim {
            let k = p * dim + a;
            let (x, v, g) = (&x[k], &xdot[k], gravity[a]);
            s = std::array::from_fn(|l| s[l] + v[l] * v[l]);
            gx = std::array::from_fn(|l| gx[l] + g * x[l]);
        }
        let half_mass = 0.5 * particle.mass;
        let weight = -particle.mass;
        kinetic = std::array::from_fn(|l| kinetic[l] + half_mass * s[l]);
        potential = std::array::from_fn(|l| potential[l] + weight * gx[l]);
    }
    for l in 0..L {
        // The forces' potentials: an empty sum.
        energy[l] = kinetic[l] + (potential[l] + zero);
    }
}

#[cfg(test)]
mod tests {
    use super::super::monitor::{lookahead_along, off_branch_candidate, AHEAD_FRACTION};
    use super::*;
    use crate::expr::testutil::Rng;

    /// `Monitor::regularity`'s shrinking, ahead and drifted tests, with its own functions.
    fn monitor_candidates(gg: f64, gp: f64, pp: f64, offset: f64, step: f64) -> (bool, bool, bool) {
        monitor_along(gg, gg - gp, gg - 2.0 * gp + pp, offset, step)
    }

    /// [`monitor_candidates`] from gg, gd and dd.
    fn monitor_along(gg: f64, gd: f64, dd: f64, offset: f64, step: f64) -> (bool, bool, bool) {
        let (s, shortest) = lookahead_along(gg, gd, dd);
        let shrinking = s > 0.0 && shortest < AHEAD_FRACTION * AHEAD_FRACTION * gg;
        let change = dd.max(0.0).sqrt();
        let drifted = shrinking
            && offset > 0.0
            && off_branch_candidate(offset, gg.sqrt(), change, step.sqrt());
        (shrinking, shrinking && s <= AHEAD_STEPS, drifted)
    }

    /// A value of random sign and magnitude 10^e, e uniform in `exponents`, or where they
    /// reach the ends of f64 a special one (0, subnormal, near the largest).
    fn value(rng: &mut Rng, exponents: (f64, f64)) -> f64 {
        let specials = exponents.0 < -300.0;
        match rng.below(40) {
            0 => 0.0,
            1 if specials => f64::MIN_POSITIVE * rng.uniform(0.0, 1.0),
            2 if specials => f64::MAX * rng.uniform(0.5, 1.0),
            _ => {
                let sign = if rng.below(2) == 0 { -1.0 } else { 1.0 };
                sign * rng.uniform(1.0, 10.0) * 10f64.powf(rng.uniform(exponents.0, exponents.1))
            }
        }
    }

    /// Gradient rows g and p (2-4 entries) summed as the lanes sum them, the offset and
    /// the squared step: (gg, gp, pp, offset, step).
    fn sample(rng: &mut Rng, exponents: (f64, f64)) -> (f64, f64, f64, f64, f64) {
        let n = 2 + rng.below(3);
        let g: Vec<f64> = (0..n).map(|_| value(rng, exponents)).collect();
        // p: g moved by a change of random size and direction (or an independent row).
        let scale = 10f64.powf(rng.uniform(-8.0, 1.0));
        let p: Vec<f64> = if rng.below(8) == 0 {
            (0..n).map(|_| value(rng, exponents)).collect()
        } else {
            g.iter()
                .map(|&g| g + scale * g.abs().max(1e-300) * rng.uniform(-1.0, 1.0))
                .collect()
        };
        let (mut gg, mut gp, mut pp) = (empty_sum(), empty_sum(), empty_sum());
        for (g, p) in g.iter().zip(&p) {
            gg += g * g;
            gp += g * p;
            pp += p * p;
        }
        let offset = value(rng, exponents).abs();
        let step = value(rng, exponents).abs();
        (gg, gp, pp, offset, step)
    }

    #[test]
    fn the_lanes_flag_every_candidate_the_monitor_would_test() {
        let mut rng = Rng::new(17);
        let (mut shrinking, mut ahead, mut drifted, mut extra) = (0, 0, 0, 0);
        let trials = 2_000_000;
        for trial in 0..trials {
            // Ordinary magnitudes, then the whole range of f64 with its specials.
            let exponents = if trial % 2 == 0 {
                (-6.0, 6.0)
            } else {
                (-330.0, 308.0)
            };
            let (gg, gp, pp, offset, step) = sample(&mut rng, exponents);
            let (is_shrinking, is_ahead, is_drifted) = monitor_candidates(gg, gp, pp, offset, step);
            let (lanes_ahead, lanes_drifted) = first_order_candidates(gg, gp, pp, offset, step);
            let inputs = format!("gg {gg:e} gp {gp:e} pp {pp:e} offset {offset:e} step {step:e}");
            assert!(!is_ahead || lanes_ahead, "ahead missed: {inputs}");
            assert!(!is_drifted || lanes_drifted, "drifted missed: {inputs}");
            shrinking += usize::from(is_shrinking);
            ahead += usize::from(is_ahead);
            drifted += usize::from(is_drifted);
            if trial % 2 == 0 {
                extra += usize::from((lanes_ahead && !is_ahead) || (lanes_drifted && !is_drifted));
            }
        }
        // The samples reach the tests (else this proves nothing), and the superset is tight
        // at ordinary magnitudes (else the lanes would hand members over for nothing): a
        // lane flagged where the monitor's tests are false is within 1e-9 of their bound.
        assert!(
            ahead > 10_000 && drifted > 10_000,
            "{ahead} ahead, {drifted} drifted"
        );
        assert!(shrinking > ahead, "{shrinking} shrinking");
        assert!(extra <= 10, "{extra} flagged beyond the monitor's tests");
    }

    #[test]
    fn the_lanes_flag_every_candidate_at_the_edges_of_the_monitors_tests() {
        // Rows at the edge of shrinking (gd^2 = 3/4 gg dd) and of drifting (offset^2 dd =
        // 1e-4 gg step), at every scale (products and gg down in the subnormals, offsets
        // whose squares are), each scanned over the floats around the edge: the lanes'
        // bounds must not cut into either.
        let mut checked = [0; 3];
        let scales = [1.0_f64, 1e-40, 1e40, 1e-150, 1e-152, 1e-154, 1e150];
        let mut rows: Vec<(f64, f64)> = scales
            .iter()
            .flat_map(|s| [1.0, 1e-8, 1e-16, 1e-20].map(|d| (s * s * 1.37, s * s * d * 0.61)))
            .collect();
        rows.extend([
            (1e-320, 1e10),
            (3e-318, 1e100),
            (1e-310, 1e12),
            (1e-300, 1e-5),
        ]);
        for (gg, dd) in rows {
            let edge = -(0.75 * gg * dd).sqrt();
            for step in [0.3, 1e-250, 1e200] {
                let offset = (1e-4 * gg * step / dd).sqrt();
                for k in -3000..=3000 {
                    let gd = edge * (1.0 + k as f64 * 1e-16);
                    for offset in [offset * (1.0 + k as f64 * 1e-16), 0.1 * offset] {
                        let monitor = monitor_along(gg, gd, dd, offset, step);
                        let lanes = candidates_along(gg, gd, dd, offset, step);
                        let inputs = format!(
                            "gg {gg:e} gd {gd:e} dd {dd:e} offset {offset:e} step {step:e}"
                        );
                        assert!(!monitor.1 || lanes.0, "ahead missed: {inputs}");
                        assert!(!monitor.2 || lanes.1, "drifted missed: {inputs}");
                        for (count, test) in
                            checked.iter_mut().zip([monitor.0, monitor.1, monitor.2])
                        {
                            *count += usize::from(test);
                        }
                    }
                }
            }
        }
        // Both sides of each edge were met.
        assert!(checked.iter().all(|&c| c > 1000), "{checked:?}");
    }

    #[test]
    fn the_lookahead_bound_is_the_monitors_at_its_edge() {
        // g = p / 1.5 in one variable, gg a power of 2: gd = -gg/2 and dd = gg/4 exactly, so
        // s = -gd/dd = 2, the edge of `ahead` (and well within shrinking); |p|^2 a float
        // less, and s is above 2. (Where gd^2 underflows the monitor's own test is off.)
        for gg in [1.0_f64, 0.5f64.powi(20), 2f64.powi(500), 0.5f64.powi(400)] {
            for (pp, expected) in [(2.25 * gg, true), ((2.25 * gg).next_down(), false)] {
                let gp = 1.5 * gg;
                let monitor = monitor_candidates(gg, gp, pp, 0.0, 1.0);
                let lanes = first_order_candidates(gg, gp, pp, 0.0, 1.0);
                assert_eq!(monitor.1, expected, "gg {gg:e} pp {pp:e}");
                assert_eq!(lanes.0, expected, "gg {gg:e} pp {pp:e}");
            }
        }
    }
}
