//! Events: where an expression of the state crosses zero, located on the integrator's path.
//!
//! An [`Event`] is an expression g over the particle positions and velocities (`a.x`,
//! `a.vy`, and with a single particle `x`, `vy`), the generalized coordinates of the
//! parametric form (`theta` or `q.theta`, rates `qdot.theta`), the time `t`, the scene's
//! parameters, `pi` and `e`. A simulation watches any number of them
//! ([`super::Simulation::set_events`]), each as an [`EventSpec`]: which crossings it reports
//! ([`Direction`]: upward, g < 0 before and g >= 0 after; downward, g > 0 before and g <= 0
//! after; or either) and whether it ends the run (`terminal`) or is only recorded
//! ([`super::Simulation::crossings`], scipy's `t_events` and `y_events`). The stop condition
//! `stop_when` is a terminal upward event. g is evaluated after every step at its end and at K
//! evenly spaced times inside it ([`super::SimulationConfig::event_samples`], default 4); a
//! crossing is a sign change between two consecutive of these times. An expression that
//! starts at or beyond zero does not fire there (there is no crossing); a crossing and its
//! return that both fall between two samples are missed; a g that is NaN is an error
//! ([`super::RunError::EventNotANumber`]).
//!
//! Fixed-step integrators screen the samples on a cubic Hermite interpolant of the step
//! ([`Watch::screen`]) and evaluate g on their own path only where it shows a crossing (or a
//! NaN); dopri5 samples its dense output. The crossing time t* is then located to 1e-10 of
//! the step dt: fixed-step integrators re-integrate the step from its saved start over a part
//! of its length, so that every state tried is the integrator's own (with its substeps,
//! retries and projection), and dopri5 evaluates its dense output, the continuous solution
//! its error control is about. The root of s g (s = +1 for an upward crossing, -1 for a
//! downward one) is bracketed by the two samples around it and found by the Illinois variant
//! of regula falsi, with a bisection whenever a secant point would not shrink the bracket by
//! half in two iterations. The state reported is the bracket's upper end, where s g >= 0. A
//! terminal event ends the run there (the earliest, when several cross in one step); the
//! non-terminal crossings before it are recorded, and a step with only non-terminal crossings
//! stands as the integrator took it: recording them changes no number of the run.

use crate::expr::{parse, Expr, ExprError, Resolved, Tape};
use crate::formulation::Formulation;
use crate::model::System;

/// A stop condition: the expression g whose upward zero crossing ends a run (see the module
/// documentation for the names it may use).
///
/// ```
/// use bead::model::SystemBuilder;
/// use bead::simulate::Event;
/// let mut b = SystemBuilder::new(&[0.0, -9.81]);
/// b.particle("ball", 1.0, &[0.0, 10.0], &[0.0, 0.0])?;
/// let system = b.build()?;
/// // The ball falls below y = 5.
/// let event = Event::parse(&system, "5 - ball.y")?;
/// assert_eq!(event.source(), "5 - ball.y");
/// assert!(Event::parse(&system, "ball.w").is_err());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct Event {
    source: String,
    tape: Tape,
    /// Particle coordinates n_c (positions and velocities each).
    n_coords: usize,
    /// Generalized coordinates the expression's slots leave room for.
    n_q: usize,
    /// Whether it reads a generalized coordinate or rate (parametric form only).
    uses_coordinates: bool,
    /// The (position slot, velocity slot) pairs of the coordinates it reads, through the
    /// position, the velocity or both: what the in-step interpolant fills.
    pairs: Vec<(usize, usize)>,
    /// The slots it reads with their names (`bead.x`, `qdot.theta`), for messages.
    names: Vec<(usize, String)>,
}

impl PartialEq for Event {
    /// Two events are the same when they were parsed from the same text for systems of the
    /// same shape.
    fn eq(&self, other: &Event) -> bool {
        self.source == other.source && self.n_coords == other.n_coords && self.n_q == other.n_q
    }
}

/// An event that cannot be used by a simulation.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EventError {
    #[error("the event `{source_text}` uses the generalized coordinates of the parametric form, and this run uses the implicit form; use particle coordinates (like a.x, a.vy) or the parametric method")]
    NeedsParametric { source_text: String },
    #[error("the event `{source_text}` was parsed for another system (with {n_coords} particle coordinates and {n_q} generalized ones)")]
    OtherSystem {
        source_text: String,
        n_coords: usize,
        n_q: usize,
    },
}

/// Which zero crossings of an event's expression g it reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Direction {
    /// From g < 0 to g >= 0 (scipy's `direction = 1`; the stop condition's).
    #[default]
    Up,
    /// From g > 0 to g <= 0 (`direction = -1`).
    Down,
    /// Either of the two (`direction = 0`).
    Either,
}

impl Direction {
    /// The direction of scipy's `direction` argument: its sign (+1 up, -1 down, 0 either).
    pub fn from_sign(sign: f64) -> Option<Direction> {
        if sign > 0.0 {
            Some(Direction::Up)
        } else if sign < 0.0 {
            Some(Direction::Down)
        } else if sign == 0.0 {
            Some(Direction::Either)
        } else {
            None
        }
    }

    /// +1, -1 or 0, as scipy writes it.
    pub fn sign(self) -> i8 {
        match self {
            Direction::Up => 1,
            Direction::Down => -1,
            Direction::Either => 0,
        }
    }

    /// `up`, `down` or `either`.
    pub fn name(self) -> &'static str {
        match self {
            Direction::Up => "up",
            Direction::Down => "down",
            Direction::Either => "either",
        }
    }

    /// The sign s of a crossing it reports between consecutive values `before` and `after`
    /// of g (s g goes from < 0 to >= 0): +1 upward, -1 downward; `None` when it reports none.
    pub fn crossing(self, before: f64, after: f64) -> Option<f64> {
        let up = before < 0.0 && after >= 0.0;
        let down = before > 0.0 && after <= 0.0;
        match self {
            Direction::Up if up => Some(1.0),
            Direction::Down if down => Some(-1.0),
            Direction::Either if up => Some(1.0),
            Direction::Either if down => Some(-1.0),
            _ => None,
        }
    }
}

/// An event a simulation watches: its expression, the crossings it reports, and whether the
/// first of them ends the run.
#[derive(Clone, Debug, PartialEq)]
pub struct EventSpec {
    pub event: Event,
    pub direction: Direction,
    /// Whether a crossing ends the run (else it is only recorded).
    pub terminal: bool,
    /// Whether it is the run's stop condition (`stop_when`, [`EventSpec::stop`]), which
    /// messages name so; else an event (`[[event]]`, Python's `bead.Event`).
    pub stop_when: bool,
}

impl EventSpec {
    /// The stop condition `stop_when`: terminal, upward.
    pub fn stop(event: Event) -> EventSpec {
        EventSpec {
            event,
            direction: Direction::Up,
            terminal: true,
            stop_when: true,
        }
    }
}

/// One crossing of a watched event, located on the integrator's path: its time and the state
/// there (particle positions and velocities; the formulation's coordinates).
#[derive(Clone, Debug, PartialEq)]
pub struct Crossing {
    /// The event's index in the list given to [`super::Simulation::set_events`].
    pub event: usize,
    pub t: f64,
    /// +1 for an upward crossing, -1 for a downward one.
    pub sign: i8,
    pub x: Vec<f64>,
    pub xdot: Vec<f64>,
    pub q: Vec<f64>,
    pub qdot: Vec<f64>,
}

const AXES: [&str; 3] = ["x", "y", "z"];
const VELOCITY_AXES: [&str; 3] = ["vx", "vy", "vz"];

impl Event {
    /// Parse `source` as a stop condition of `system`. The error's span points into `source`.
    ///
    /// Slots of the compiled expression: particle positions (n_c), velocities (n_c), t, then
    /// the generalized coordinates q and rates qdot of the system's parametric form.
    pub fn parse(system: &System, source: &str) -> Result<Event, ExprError> {
        let n_coords = system.n_coords();
        let coordinates: &[String] = system.parametric().map_or(&[], |p| p.coordinates());
        let n_q = coordinates.len();
        let resolve = |name: &str| resolve(system, coordinates, name);
        let expr: Expr = parse(source, &resolve)?;
        let first_q = 2 * n_coords + 1;
        let vars = expr.vars();
        let uses_coordinates = vars.iter().any(|&k| k >= first_q);
        // Slot k's coordinate pair and name.
        let pair_of = |k: usize| -> Option<((usize, usize), String)> {
            if k < n_coords {
                Some(((k, n_coords + k), system.coordinate_name(k)))
            } else if k < 2 * n_coords {
                let j = k - n_coords;
                Some(((j, k), system.velocity_name(j)))
            } else if k == 2 * n_coords {
                None
            } else if k < first_q + n_q {
                let j = k - first_q;
                Some(((k, k + n_q), coordinates[j].clone()))
            } else {
                let j = k - first_q - n_q;
                Some(((first_q + j, k), format!("qdot.{}", coordinates[j])))
            }
        };
        let mut pairs = Vec::new();
        let mut names = Vec::new();
        for &k in &vars {
            match pair_of(k) {
                Some((pair, name)) => {
                    if !pairs.contains(&pair) {
                        pairs.push(pair);
                    }
                    names.push((k, name));
                }
                None => names.push((k, "t".to_string())),
            }
        }
        Ok(Event {
            source: source.to_string(),
            tape: Tape::compile(&[expr]),
            n_coords,
            n_q,
            uses_coordinates,
            pairs,
            names,
        })
    }

    /// The expression as written.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// Whether it reads generalized coordinates (and so needs the parametric form).
    pub fn uses_coordinates(&self) -> bool {
        self.uses_coordinates
    }

    /// Whether a simulation of `system` by the parametric form (`parametric`) or the
    /// implicit one can evaluate it.
    pub(super) fn check(&self, system: &System, parametric: bool) -> Result<(), EventError> {
        let n_q = system.parametric().map_or(0, |p| p.coordinates().len());
        if self.n_coords != system.n_coords() || self.n_q != n_q {
            return Err(EventError::OtherSystem {
                source_text: self.source.clone(),
                n_coords: self.n_coords,
                n_q: self.n_q,
            });
        }
        if self.uses_coordinates && !parametric {
            return Err(EventError::NeedsParametric {
                source_text: self.source.clone(),
            });
        }
        Ok(())
    }
}

/// A name of a stop condition: `t`, a parameter, `NAME.x|y|z|vx|vy|vz` (plain with a single
/// particle), a generalized coordinate `NAME` or `q.NAME`, or its rate `qdot.NAME`.
fn resolve(system: &System, coordinates: &[String], name: &str) -> Result<Resolved, String> {
    let n_coords = system.n_coords();
    let dim = system.dim();
    if name == "t" {
        return Ok(Resolved::Var(2 * n_coords));
    }
    if let Some((_, value)) = system.params().iter().find(|(p, _)| p == name) {
        return Ok(Resolved::Value(*value));
    }
    let axis = |p: usize, axis: &str| {
        if let Some(a) = AXES[..dim].iter().position(|a| *a == axis) {
            return Some(Resolved::Var(p * dim + a));
        }
        VELOCITY_AXES[..dim]
            .iter()
            .position(|a| *a == axis)
            .map(|a| Resolved::Var(n_coords + p * dim + a))
    };
    let coordinate = |c: &str| coordinates.iter().position(|q| q == c);
    let first_q = 2 * n_coords + 1;
    if let Some((prefix, rest)) = name.split_once('.') {
        if let Some(p) = system.particle_id(prefix) {
            return axis(p.0, rest).ok_or_else(|| {
                format!(
                    "`{prefix}` has no coordinate `{rest}`; in {dim}D use {} and {}",
                    AXES[..dim].join(", "),
                    VELOCITY_AXES[..dim].join(", ")
                )
            });
        }
        if prefix == "q" || prefix == "qdot" {
            if let Some(j) = coordinate(rest) {
                let slot = first_q
                    + if prefix == "q" {
                        j
                    } else {
                        coordinates.len() + j
                    };
                return Ok(Resolved::Var(slot));
            }
            return Err(if coordinates.is_empty() {
                format!(
                    "`{name}`: the scene has no generalized coordinates (no [parametric] table)"
                )
            } else {
                format!(
                    "`{name}`: no generalized coordinate `{rest}`; coordinates: {}",
                    coordinates.join(", ")
                )
            });
        }
        return Err(format!(
            "unknown particle `{prefix}`; particles: {}",
            particle_list(system)
        ));
    }
    if let Some(j) = coordinate(name) {
        return Ok(Resolved::Var(first_q + j));
    }
    if system.particles().len() == 1 {
        if let Some(r) = axis(0, name) {
            return Ok(r);
        }
    }
    let example = system
        .particles()
        .first()
        .map(|p| format!("{0}.x, {0}.vx", p.name))
        .unwrap_or_default();
    let params: Vec<&str> = system.params().iter().map(|(p, _)| p.as_str()).collect();
    let mut message = format!(
        "unknown name `{name}`; a stop condition may use t, pi, e, parameters ({}) and particle coordinates and velocities like {example}",
        if params.is_empty() {
            "none".to_string()
        } else {
            params.join(", ")
        }
    );
    if !coordinates.is_empty() {
        message.push_str(&format!(
            ", and the generalized coordinates ({}) as NAME or q.NAME, their rates as qdot.NAME",
            coordinates.join(", ")
        ));
    }
    Err(message)
}

fn particle_list(system: &System) -> String {
    let names: Vec<&str> = system.particles().iter().map(|p| p.name.as_str()).collect();
    crate::name_list(names.iter().copied())
}

/// An event being watched by a simulation: its buffers (sized once, so that stepping with an
/// event allocates nothing), g at the last accepted step's end, and the values there of the
/// coordinates g reads, from which the next step's interpolant starts.
#[derive(Debug)]
pub(super) struct Watch {
    pub(super) event: Event,
    pub(super) direction: Direction,
    pub(super) terminal: bool,
    pub(super) stop_when: bool,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    /// Interior points per step at which g is sampled (see [`Watch::screen`]).
    pub(super) samples: u32,
    /// g at the end of the last accepted step (the start of the next one)
    pub(super) g_last: f64,
    /// The time of that state, and (position, velocity) of each of the event's coordinate
    /// pairs there
    t_last: f64,
    start: Vec<f64>,
    end: Vec<f64>,
    /// The interpolant's weights at each interior sample s = i / (samples + 1) (see
    /// [`Watch::screen`]): h00, h10, h01, h11, 6 s (s - 1), 3s^2 - 4s + 1, 3s^2 - 2s.
    weights: Vec<[f64; 7]>,
    /// Particle positions and velocities of a state given in the formulation's coordinates
    /// ([`Watch::eval_state`])
    x: Vec<f64>,
    xdot: Vec<f64>,
}

impl Watch {
    pub(super) fn new(spec: EventSpec, samples: u32) -> Watch {
        let EventSpec {
            event,
            direction,
            terminal,
            stop_when,
        } = spec;
        let tape_vars = event.tape.n_vars();
        let slots = 2 * event.n_coords + 1 + 2 * event.n_q;
        let pairs = event.pairs.len();
        let n_coords = event.n_coords;
        Watch {
            vars: vec![0.0; slots.max(tape_vars)],
            scratch: vec![0.0; event.tape.n_slots()],
            event,
            direction,
            terminal,
            stop_when,
            samples,
            g_last: f64::NAN,
            t_last: f64::NAN,
            start: vec![0.0; 2 * pairs],
            end: vec![0.0; 2 * pairs],
            weights: (1..=samples)
                .map(|i| {
                    let s = i as f64 / (samples as f64 + 1.0);
                    let (s2, s3) = (s * s, s * s * s);
                    [
                        2.0 * s3 - 3.0 * s2 + 1.0,
                        s3 - 2.0 * s2 + s,
                        3.0 * s2 - 2.0 * s3,
                        s3 - s2,
                        6.0 * (s2 - s),
                        3.0 * s2 - 4.0 * s + 1.0,
                        3.0 * s2 - 2.0 * s,
                    ]
                })
                .collect(),
            x: vec![0.0; n_coords],
            xdot: vec![0.0; n_coords],
        }
    }

    /// g at time t, particle state (x, xdot), generalized state (q, qdot) (empty for the
    /// implicit form).
    pub(super) fn eval(&mut self, t: f64, x: &[f64], xdot: &[f64], q: &[f64], qdot: &[f64]) -> f64 {
        self.load(t, x, xdot, q, qdot);
        self.eval_loaded()
    }

    /// g at time t of the formulation's state (q, qdot) (for the parametric form, positions
    /// and velocities from the map; for the implicit form they are q and qdot): dopri5's
    /// samples of its dense output, without observing them.
    pub(super) fn eval_state(
        &mut self,
        formulation: &mut dyn Formulation,
        t: f64,
        q: &[f64],
        qdot: &[f64],
    ) -> f64 {
        let (mut x, mut xdot) = (std::mem::take(&mut self.x), std::mem::take(&mut self.xdot));
        formulation.particle_state(t, q, qdot, &mut x, &mut xdot);
        let g = self.eval(t, &x, &xdot, q, qdot);
        (self.x, self.xdot) = (x, xdot);
        g
    }

    /// Put a state into the tape's variables.
    fn load(&mut self, t: f64, x: &[f64], xdot: &[f64], q: &[f64], qdot: &[f64]) {
        let n = self.event.n_coords;
        self.vars[..n].copy_from_slice(x);
        self.vars[n..2 * n].copy_from_slice(xdot);
        self.vars[2 * n] = t;
        if self.event.uses_coordinates {
            let k = self.event.n_q;
            self.vars[2 * n + 1..2 * n + 1 + k].copy_from_slice(q);
            self.vars[2 * n + 1 + k..2 * n + 1 + 2 * k].copy_from_slice(qdot);
        }
    }

    fn eval_loaded(&mut self) -> f64 {
        let mut out = [0.0];
        self.event
            .tape
            .eval(&self.vars, &mut self.scratch, &mut out);
        out[0]
    }

    /// Remember the state at time t, where g = `g`, as the start of the next step.
    pub(super) fn remember(
        &mut self,
        t: f64,
        x: &[f64],
        xdot: &[f64],
        q: &[f64],
        qdot: &[f64],
        g: f64,
    ) {
        self.load(t, x, xdot, q, qdot);
        for (i, &(p, v)) in self.event.pairs.iter().enumerate() {
            self.start[2 * i] = self.vars[p];
            self.start[2 * i + 1] = self.vars[v];
        }
        self.t_last = t;
        self.g_last = g;
    }

    /// Whether the step from the remembered state to this one (time t, g = `g_end`) needs a
    /// closer look: g sampled at the step's end and at `samples` interior times
    /// [`sample_time`] on the cubic Hermite interpolant of each coordinate it reads,
    ///
    /// ```text
    /// y(s) = (2s^3 - 3s^2 + 1) y0 + (s^3 - 2s^2 + s) h v0 + (3s^2 - 2s^3) y1 + (s^3 - s^2) h v1,
    /// v(s) = y'(s) / h = 6 s (s - 1) (y0 - y1) / h + (3s^2 - 4s + 1) v0 + (3s^2 - 2s) v1,
    /// ```
    ///
    /// s = (t - t0) / h, (y, v) a position and its velocity (or q and qdot), exact at both
    /// ends, O(h^4) between, from the step's end states alone (every integrator has them),
    /// crosses zero in the event's direction between two consecutive times, or is not a
    /// number somewhere (g at the start included). Those values only say where to look: the
    /// caller evaluates g on the integrator's own path there. When no event of the step needs
    /// a look, the caller remembers its end as the start of the next step
    /// ([`Watch::remember`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn screen(
        &mut self,
        t: f64,
        x: &[f64],
        xdot: &[f64],
        q: &[f64],
        qdot: &[f64],
        g_end: f64,
    ) -> bool {
        let t0 = self.t_last;
        let h = t - t0;
        let mut before = self.g_last;
        if !before.is_finite() || !g_end.is_finite() {
            return true;
        }
        if self.samples > 0 && h > 0.0 {
            self.load(t, x, xdot, q, qdot);
            for (i, &(p, v)) in self.event.pairs.iter().enumerate() {
                self.end[2 * i] = self.vars[p];
                self.end[2 * i + 1] = self.vars[v];
            }
            let t_slot = 2 * self.event.n_coords;
            for i in 1..=self.samples {
                let [h00, h10, h01, h11, d00, d10, d11] = self.weights[i as usize - 1];
                let (h10, h11, d00) = (h10 * h, h11 * h, d00 / h);
                for (k, &(pos, vel)) in self.event.pairs.iter().enumerate() {
                    let (y0, v0) = (self.start[2 * k], self.start[2 * k + 1]);
                    let (y1, v1) = (self.end[2 * k], self.end[2 * k + 1]);
                    self.vars[pos] = h00 * y0 + h10 * v0 + h01 * y1 + h11 * v1;
                    self.vars[vel] = d00 * (y0 - y1) + d10 * v0 + d11 * v1;
                }
                let ti = sample_time(t0, t, i, self.samples);
                self.vars[t_slot] = ti;
                let g = self.eval_loaded();
                if !g.is_finite() || self.direction.crossing(before, g).is_some() {
                    return true;
                }
                before = g;
            }
        }
        self.direction.crossing(before, g_end).is_some()
    }

    /// The error for g jumping over zero at time t, from `before` to `after` (see
    /// [`Bracket::jump`]); the run stands at `stopped`.
    pub(super) fn jump(
        &self,
        t: f64,
        (before, after): (f64, f64),
        stopped: f64,
    ) -> super::RunError {
        super::RunError::EventJump {
            source_text: self.event.source.clone(),
            stop_when: self.stop_when,
            t,
            before,
            after,
            stopped,
        }
    }

    /// The error for g = NaN at time t, at the state last given to [`Watch::eval`]; the run
    /// stands at `stopped`.
    pub(super) fn not_a_number(&self, t: f64, g: f64, stopped: f64) -> super::RunError {
        super::RunError::EventNotANumber {
            source_text: self.event.source.clone(),
            stop_when: self.stop_when,
            t,
            infinite: g.is_infinite(),
            values: self
                .event
                .names
                .iter()
                .filter(|(_, name)| name != "t")
                .map(|(k, name)| (name.clone(), self.vars[*k]))
                .collect(),
            stopped,
        }
    }
}

/// Interior sample i of `samples` (1 ..= samples; samples + 1 is the end) of the step from t0
/// to t1: evenly spaced, t0 + (t1 - t0) i / (samples + 1), the end exactly t1.
pub(super) fn sample_time(t0: f64, t1: f64, i: u32, samples: u32) -> f64 {
    if i > samples {
        t1
    } else {
        t0 + (t1 - t0) * (i as f64 / (samples as f64 + 1.0))
    }
}

/// How much larger than at a bracket's given ends g must be at its located ends to be a
/// pole rather than a bounded jump (see [`Bracket::jump`]).
const POLE_GROWTH: f64 = 1e3;

/// The root finder's bracket of an upward crossing: g(lo) < 0 <= g(hi).
#[derive(Clone, Copy, Debug)]
pub(super) struct Bracket {
    pub(super) lo: f64,
    pub(super) g_lo: f64,
    pub(super) hi: f64,
    pub(super) g_hi: f64,
    /// The largest |g| at the ends as given, and the last g found at each end (`g_lo` and
    /// `g_hi` are halved by Illinois' rule)
    g_given: f64,
    g_lo_found: f64,
    g_hi_found: f64,
    /// Which end the last two updates moved (Illinois: an end kept twice has its g halved)
    last_side: i8,
    /// Width before the last two iterations, to force a bisection when it did not halve
    width_before: f64,
    width_prev: f64,
}

impl Bracket {
    pub(super) fn new(lo: f64, g_lo: f64, hi: f64, g_hi: f64) -> Bracket {
        Bracket {
            lo,
            g_lo,
            hi,
            g_hi,
            g_given: g_lo.abs().max(g_hi.abs()),
            g_lo_found: g_lo,
            g_hi_found: g_hi,
            last_side: 0,
            width_before: f64::INFINITY,
            width_prev: f64::INFINITY,
        }
    }

    /// The next time to try, strictly inside (lo, hi): the Illinois secant point, or the
    /// midpoint when the bracket did not halve over the last two iterations or the secant
    /// point falls at an end.
    pub(super) fn next(&self) -> f64 {
        let width = self.hi - self.lo;
        let mid = self.lo + 0.5 * width;
        if width > 0.5 * self.width_before {
            return mid;
        }
        let secant = self.lo - self.g_lo * width / (self.g_hi - self.g_lo);
        if secant > self.lo && secant < self.hi && secant.is_finite() {
            secant
        } else {
            mid
        }
    }

    /// Fold in g(t) at a time t inside the bracket.
    pub(super) fn update(&mut self, t: f64, g: f64) {
        self.width_before = self.width_prev;
        self.width_prev = self.hi - self.lo;
        if g >= 0.0 {
            self.hi = t;
            self.g_hi = g;
            self.g_hi_found = g;
            if self.last_side == 1 {
                self.g_lo *= 0.5;
            }
            self.last_side = 1;
        } else {
            self.lo = t;
            self.g_lo = g;
            self.g_lo_found = g;
            if self.last_side == -1 {
                self.g_hi *= 0.5;
            }
            self.last_side = -1;
        }
    }

    /// Whether the bracket is narrower than `tolerance`, or no time fits strictly inside it.
    pub(super) fn done(&self, tolerance: f64) -> bool {
        let mid = self.lo + 0.5 * (self.hi - self.lo);
        self.hi - self.lo <= tolerance || mid <= self.lo || mid >= self.hi
    }

    /// Once [`Bracket::done`]: g's values at the ends `(lo, hi)` when they grew as the
    /// bracket closed in, each end beyond [`POLE_GROWTH`] times both given ends in size,
    /// where a continuous g would have shrunk towards its root: g jumps over zero there (a
    /// pole, like -1/x's at x = 0, grows by about the bracket's narrowing, ~10^9), it does
    /// not cross it. A bounded jump (a sign function, times anything finite) is a crossing.
    pub(super) fn jump(&self) -> Option<(f64, f64)> {
        let found = self.g_lo_found.abs().min(self.g_hi_found.abs());
        (found > POLE_GROWTH * self.g_given).then_some((self.g_lo_found, self.g_hi_found))
    }
}

#[cfg(test)]
mod tests {
    use super::Bracket;

    /// The root finder alone: the root of a smooth function (a triple root too) found to the
    /// tolerance, within the guarantee of a forced bisection at least every third iteration.
    #[test]
    fn the_bracket_closes_on_a_root() {
        for (f, root) in [
            (
                Box::new(|t: f64| t * t - 0.3) as Box<dyn Fn(f64) -> f64>,
                0.3f64.sqrt(),
            ),
            (Box::new(|t: f64| (t - 0.7).powi(3)), 0.7),
            (Box::new(|t: f64| (20.0 * (t - 0.123)).tanh()), 0.123),
        ] {
            let mut b = Bracket::new(0.0, f(0.0), 1.0, f(1.0));
            let mut evaluations = 0;
            while !b.done(1e-10) {
                let t = b.next();
                assert!(t > b.lo && t < b.hi);
                b.update(t, f(t));
                evaluations += 1;
                assert!(evaluations <= 3 * 34);
            }
            assert!(b.lo <= root && root <= b.hi, "{} {} {root}", b.lo, b.hi);
            assert!(b.hi - b.lo <= 1e-10);
            assert!(f(b.hi) >= 0.0);
        }
    }
}
