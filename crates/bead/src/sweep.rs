//! Sweeps: one scene run many times over a grid of parameter values, the members in
//! parallel on every core, each result in its place whatever the number of threads.
//!
//! A member is the scene with its parameters overridden, loaded again from its text exactly as
//! `bead run --set NAME=VALUE` loads it ([`Scene::with_params`]), its run resolved from the
//! sweep's [`PlanRequest`] against that scene's `[run]` table ([`Plan::resolve`], as every
//! front end resolves a run), so that a member's run and that command's give the same numbers
//! bit for bit. Its stop condition (the sweep's, else the scene's `[run] stop_when`) is
//! parsed against the member's own system: the parameters in it take the member's values.
//!
//! When the parameters swept reach only where the scene starts (positions, velocities, the
//! parametric form's initial values and rates, the stop condition), the scene is not loaded
//! again: a member is the scene's compiled equations, shared, with those values evaluated
//! again by the loader's own code, the run planned once and the stop condition parsed once
//! unless it names a parameter swept: the same member, bit for bit, in microseconds
//! ([`Sweep::reload_reasons`] says why a sweep cannot, [`Sweep::restarted_members`] counts).
//!
//! ```
//! use bead::plan::PlanRequest;
//! use bead::scene::Scene;
//! use bead::sweep::{Axis, Combine, Sweep};
//! let scene = Scene::parse(
//!     "[params]\nh = 1.0\n[world]\ngravity = [0.0, 10.0]\n[[particle]]\nname = \"ball\"\nmass = 1.0\nposition = [0.0, 0.0]\n",
//!     "ball.toml",
//!     &[],
//! )?;
//! let sweep = Sweep::new(
//!     &scene,
//!     vec![Axis::linspace("h", 1.0, 4.0, 4)?],
//!     Combine::Grid,
//!     PlanRequest { dt: Some(0.01), steps: Some(200), ..Default::default() },
//!     Some("ball.y - h".to_string()),
//! )?;
//! let results = sweep.run(2)?;
//! // Falling from rest at g = 10: y = h at t = sqrt(h / 5).
//! for (member, h) in results.iter().zip([1.0f64, 2.0, 3.0, 4.0]) {
//!     let t = member.stats.as_ref().unwrap().stop_time.unwrap();
//!     assert!((t - (h / 5.0).sqrt()).abs() < 1e-11);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::collections::BTreeMap;
use std::io;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Condvar, Mutex, PoisonError};
use std::time::Instant;

use crate::formulation::Method;
use crate::model::System;
use crate::output::Trajectory;
use crate::plan::{Plan, PlanError, PlanRequest};
use crate::scene::{Rebinder, Scene};
use crate::simulate::lanes::{lanes_can_run, run_lanes, LaneOutcome, LANES};
use crate::simulate::{
    run, run_at_times, run_rest, run_with_progress, solve_holding, Event, EventSpec, NoProgress,
    NullSink, RunFailure, RunOptions, RunStats, Simulation, StateRequest,
};

/// The most members a sweep may have: 2^32. Members stream ([`Sweep::run_each`]), so memory
/// does not limit the count; a larger grid is far more work than any sweep this library runs
/// (2^32 members of 0.1 ms are five days on one core) and is almost always a typo.
pub const MAX_MEMBERS: u64 = 1 << 32;

/// One swept parameter and its values.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// A parameter of the scene (`[params]`).
    pub name: String,
    values: Values,
}

/// An axis's values: listed, or computed on demand (so that a long linspace costs nothing).
#[derive(Clone, Debug, PartialEq)]
enum Values {
    List(Vec<f64>),
    Linspace { start: f64, stop: f64, count: usize },
}

impl Axis {
    /// An axis taking `values`, in order.
    pub fn new(name: &str, values: Vec<f64>) -> Axis {
        Axis {
            name: name.to_string(),
            values: Values::List(values),
        }
    }

    /// `count` values from `start` to `stop`, both included, evenly spaced, as numpy's
    /// `linspace(start, stop, count)` computes them: value i = start + i (stop - start) /
    /// (count - 1), the last exactly `stop` (one value: `start`); where stop - start
    /// overflows, start (1 - f) + stop f with f = i / (count - 1). Computed when asked for,
    /// so any count costs no memory.
    pub fn linspace(name: &str, start: f64, stop: f64, count: usize) -> Result<Axis, SweepError> {
        if count == 0 {
            return Err(SweepError::NoValues {
                name: name.to_string(),
            });
        }
        if !(start.is_finite() && stop.is_finite()) {
            return Err(SweepError::NotFinite {
                name: name.to_string(),
            });
        }
        Ok(Axis {
            name: name.to_string(),
            values: Values::Linspace { start, stop, count },
        })
    }

    /// The number of values.
    pub fn len(&self) -> usize {
        match &self.values {
            Values::List(values) => values.len(),
            Values::Linspace { count, .. } => *count,
        }
    }

    /// Whether it has no values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i` (`i < len()`).
    pub fn value(&self, i: usize) -> f64 {
        match self.values {
            Values::List(ref values) => values[i],
            Values::Linspace { start, stop, count } => {
                if i + 1 == count {
                    // One value is `start`; the last of several is exactly `stop`.
                    if count == 1 {
                        start
                    } else {
                        stop
                    }
                } else if (stop - start).is_finite() {
                    i as f64 * ((stop - start) / (count - 1) as f64) + start
                } else {
                    // A span beyond f64::MAX (start and stop of opposite signs, both near
                    // it): weights of each end, whose terms stay finite.
                    let f = i as f64 / (count - 1) as f64;
                    start * (1.0 - f) + stop * f
                }
            }
        }
    }

    /// The values, in order.
    pub fn values(&self) -> impl ExactSizeIterator<Item = f64> + '_ {
        (0..self.len()).map(|i| self.value(i))
    }
}

/// How the axes combine into members.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Combine {
    /// Every combination (the Cartesian product), the first axis outermost: member
    /// (i_1, ..., i_k) has index ((i_1 n_2 + i_2) n_3 + ...) + i_k, row-major like a C or
    /// numpy array of shape (n_1, ..., n_k).
    Grid,
    /// The axes side by side (all the same length n): member i takes value i of each.
    Zip,
}

/// What each member of a sweep records besides its figures.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Recording {
    /// Nothing: the members may be stepped together, 16 at a time (the lanes).
    #[default]
    Nothing,
    /// The states its run records ([`run`]): the first, every `every`-th output interval of
    /// the request ([`PlanRequest::every`]), the last (or the state where its stop condition
    /// fired, or its last good state when it failed).
    Steps,
    /// The states at these times (not decreasing, none before the start), exactly there, as
    /// [`run_at_times`] records them: only those before a stop condition fires.
    Times(Arc<[f64]>),
}

/// A sweep that cannot be set up or run as asked.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SweepError {
    #[error("`{name}` has no values (a count of 0)")]
    NoValues { name: String },
    #[error("the times to record: {0}")]
    Times(String),
    #[error("`{name}`: the start and stop must be finite numbers")]
    NotFinite { name: String },
    #[error("`{name}` is swept twice")]
    Repeated { name: String },
    #[error("unknown parameter `{name}`; {}; or sweep the initial state: NAME.x, NAME.vx (a particle's position and velocity), q.NAME, qdot.NAME (the parametric form's)", known_params(.known))]
    UnknownParam { name: String, known: Vec<String> },
    #[error("zipped parameters must have the same number of values: {}", .lengths.iter().map(|(n, l)| format!("`{n}` has {l}")).collect::<Vec<_>>().join(", "))]
    ZipLengths { lengths: Vec<(String, usize)> },
    /// More members than [`MAX_MEMBERS`].
    #[error("{}", too_large(.shape))]
    TooLarge { shape: Vec<usize> },
    #[error("members {start}..{end} are not in the sweep of {len} members")]
    OutOfRange {
        start: usize,
        end: usize,
        len: usize,
    },
    /// [`Sweep::run_range`] cannot hold the results of that many members.
    #[error("cannot hold the results of {members} members in memory (about {}); run them in smaller ranges, or stream them with `Sweep::run_each`", crate::byte_size(*.bytes))]
    TooManyToHold { members: usize, bytes: u64 },
    /// A member whose particles or coordinates are not the scene's, where the output has the
    /// scene's columns (see [`Layout`]).
    #[error("{member} {}", .found.difference(.expected))]
    OtherLayout {
        /// Its index.
        index: usize,
        /// `member 3 (N = 5)`.
        member: String,
        found: Box<Layout>,
        expected: Box<Layout>,
    },
    #[error(transparent)]
    Plan(#[from] PlanError),
}

fn known_params(known: &[String]) -> String {
    if known.is_empty() {
        "the scene has no [params]".into()
    } else {
        format!("the scene's parameters are {}", known.join(", "))
    }
}

/// The message of [`SweepError::TooLarge`].
fn too_large(shape: &[usize]) -> String {
    let count = shape
        .iter()
        .try_fold(1u128, |acc, &n| acc.checked_mul(n as u128))
        .map_or_else(|| "more than 2^128".to_string(), |n| n.to_string());
    let grid = if shape.len() > 1 {
        let factors: Vec<String> = shape.iter().map(|n| n.to_string()).collect();
        format!(" ({})", factors.join(" x "))
    } else {
        String::new()
    };
    format!(
        "the sweep would have {count} members{grid}, more than the {MAX_MEMBERS} (2^32) a sweep \
         may have; sweep fewer values, or cut the values into several sweeps"
    )
}

/// The names of a member's state: its particles, their dimension, and the generalized
/// coordinates of a parametric run (empty for the implicit form). A sweep's wide output (the
/// CSV's columns, Python's arrays) follows its scene's layout; a parameter that changes the
/// particles (a chain's `N`) gives members another one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    /// The particles' names, in order.
    pub particles: Vec<String>,
    /// 2 or 3.
    pub dim: usize,
    /// The generalized coordinates of a parametric run, in order.
    pub coordinates: Vec<String>,
}

impl Layout {
    /// The layout of `system` run by `method`.
    pub fn of(system: &System, method: Method) -> Layout {
        Layout {
            particles: system.particles().iter().map(|p| p.name.clone()).collect(),
            dim: system.dim(),
            coordinates: Self::generalized(system, method).to_vec(),
        }
    }

    fn generalized(system: &System, method: Method) -> &[String] {
        match (method, system.parametric()) {
            (Method::Parametric, Some(map)) => map.coordinates(),
            _ => &[],
        }
    }

    /// Whether `system` run by `method` has this layout (compared without allocating).
    pub fn matches(&self, system: &System, method: Method) -> bool {
        system.dim() == self.dim
            && system.particles().len() == self.particles.len()
            && system
                .particles()
                .iter()
                .zip(&self.particles)
                .all(|(p, name)| p.name == *name)
            && Self::generalized(system, method) == self.coordinates.as_slice()
    }

    /// Particle coordinates: particles x dim.
    pub fn n_coords(&self) -> usize {
        self.particles.len() * self.dim
    }

    /// The name of particle coordinate k, e.g. `bead.y` (as [`System::coordinate_name`]).
    pub fn coordinate_name(&self, k: usize) -> String {
        const AXES: [&str; 3] = ["x", "y", "z"];
        format!("{}.{}", self.particles[k / self.dim], AXES[k % self.dim])
    }

    /// How `self` (a member's) differs from `expected` (the scene's), for a message.
    fn difference(&self, expected: &Layout) -> String {
        let count = |n: usize, what: &str| format!("{n} {what}{}", if n == 1 { "" } else { "s" });
        let list = |names: &[String]| crate::name_list(names);
        if self.particles.len() != expected.particles.len() {
            return format!(
                "has {} ({}), where the scene swept has {} ({})",
                count(self.particles.len(), "particle"),
                list(&self.particles),
                expected.particles.len(),
                list(&expected.particles)
            );
        }
        if self.dim != expected.dim {
            return format!(
                "is in {}D, where the scene swept is in {}D",
                self.dim, expected.dim
            );
        }
        if let Some(k) =
            (0..self.particles.len()).find(|&k| self.particles[k] != expected.particles[k])
        {
            return format!(
                "names particle {} `{}`, where the scene swept names it `{}`",
                k + 1,
                self.particles[k],
                expected.particles[k]
            );
        }
        if self.coordinates.len() != expected.coordinates.len() {
            return format!(
                "has {} ({}), where the scene swept has {} ({})",
                count(self.coordinates.len(), "generalized coordinate"),
                list(&self.coordinates),
                expected.coordinates.len(),
                list(&expected.coordinates)
            );
        }
        format!(
            "names its generalized coordinates {}, where the scene swept names them {}",
            list(&self.coordinates),
            list(&expected.coordinates)
        )
    }
}

/// What one member did.
#[derive(Clone, Debug, PartialEq)]
pub struct Member {
    /// Its index in the sweep (see [`Combine`]).
    pub index: usize,
    /// Its parameter values, in the order of the axes.
    pub params: Vec<f64>,
    /// The figures of its run, complete or up to where it stopped: final state (`x`, `xdot`,
    /// and `q`, `qdot` for the parametric form), `energy_rel_error_max`,
    /// `energy_balance_error_max`, `constraint_error_max`, `stop_time`, `steps`,
    /// `newton_iterations`. `None` when
    /// the member could not start (its scene or initial state is invalid). `wall_seconds` is
    /// the only figure that differs between two runs.
    pub stats: Option<RunStats>,
    /// Why it failed, when it did, on one line: the scene with its values cannot be loaded
    /// (`file:line:column: message`), the simulation cannot start, or the run stopped early
    /// (then `stats` holds the figures up to the last good state).
    pub error: Option<String>,
    /// Its particles and coordinates when they are not the scene's (a parameter changed
    /// them); `None` when they are, or when its scene could not be loaded.
    pub layout: Option<Arc<Layout>>,
    /// The states it recorded, as [`Sweep::recording`] asked (`None` when it asked for none,
    /// or when the member could not start): q and qdot only for the parametric form.
    pub trajectory: Option<Box<Trajectory>>,
}

impl Member {
    /// `ok` (ran to the end), `event` (stopped at its stop condition) or `failed`.
    pub fn status(&self) -> &'static str {
        match (&self.error, &self.stats) {
            (Some(_), _) | (None, None) => "failed",
            (None, Some(stats)) if stats.stop_time.is_some() => "event",
            (None, Some(_)) => "ok",
        }
    }
}

/// The layout of the CSV of a sweep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CsvFormat {
    /// One row per member, one column per coordinate of the scene swept
    /// ([`Sweep::csv_header`]): every member must have the scene's [`Layout`].
    #[default]
    Wide,
    /// One row per member and coordinate ([`Sweep::long_csv_header`]): members may differ in
    /// particles and coordinates.
    Long,
}

/// Why a sweep's CSV could not be written.
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    /// A member that does not fit the format ([`SweepError::OtherLayout`]).
    #[error(transparent)]
    Member(#[from] SweepError),
    #[error(transparent)]
    Io(#[from] io::Error),
}

/// A scene, the axes it is swept over, and how each member runs.
#[derive(Clone, Debug)]
pub struct Sweep {
    scene: Scene,
    axes: Vec<Axis>,
    combine: Combine,
    request: PlanRequest,
    /// The formulation of the base scene's plan (the CSV's columns follow it)
    method: Method,
    /// The base scene's particles and coordinates (the wide CSV's columns)
    layout: Layout,
    stop_when: Option<String>,
    /// Members per axis (grid) or the common length (zip, one entry)
    shape: Vec<usize>,
    len: usize,
    /// How members are set up
    setup: Arc<MemberSetup>,
    /// Members set up from the scene's compiled equations so far
    restarted: Arc<AtomicUsize>,
    /// What each member records
    recording: Recording,
    /// Rows a member records at most
    rows: u64,
}

/// How a sweep sets its members up.
#[derive(Debug)]
enum MemberSetup {
    /// The parameters swept reach only where the scene starts: a member is the scene's
    /// compiled equations with its initial values evaluated again ([`Rebinder`]), the
    /// scene's plan, and the stop condition parsed once when it names no parameter swept.
    Restart(Box<Restart>),
    /// Each member's scene is loaded again ([`Scene::with_params`]), for these reasons.
    Reload(Vec<String>),
}

#[derive(Debug)]
struct Restart {
    rebinder: Rebinder,
    plan: Plan,
    stop: Stop,
    /// The scene's `[[event]]` tables (the parameters swept do not reach them).
    events: Vec<EventSpec>,
}

/// A restarted member's stop condition.
#[derive(Debug)]
enum Stop {
    None,
    /// Parsed once (it names no parameter swept), or the error it gave.
    Once(Result<Event, ()>),
    /// Parsed for each member, against its system.
    Each(String),
}

/// A number of a scene's start that a sweep's axis may set instead of a parameter, named
/// as the trace's columns are: `NAME.x|y|z` and `NAME.vx|vy|vz` (particle NAME's position
/// and velocity), `q.NAME` and `qdot.NAME` (the parametric form's coordinate and rate).
/// A member's start is the scene's with these replaced, placed on the constraints
/// ([`Scene::with_state`]).
#[derive(Clone, Copy, Debug, PartialEq)]
enum StatePart {
    Position(usize),
    Velocity(usize),
    Q(usize),
    Qdot(usize),
}

impl StatePart {
    fn of(system: &System, name: &str) -> Option<StatePart> {
        let (head, tail) = name.rsplit_once('.')?;
        let coordinates = system.parametric().map_or(&[][..], |m| m.coordinates());
        match head {
            "q" => return coordinates.iter().position(|c| c == tail).map(StatePart::Q),
            "qdot" => {
                return coordinates
                    .iter()
                    .position(|c| c == tail)
                    .map(StatePart::Qdot)
            }
            _ => {}
        }
        let p = system.particle_id(head)?.0;
        let dim = system.dim();
        let axis = |a: &str| ["x", "y", "z"][..dim].iter().position(|&n| n == a);
        match tail.strip_prefix('v') {
            Some(a) => axis(a).map(|a| StatePart::Velocity(p * dim + a)),
            None => axis(tail).map(|a| StatePart::Position(p * dim + a)),
        }
    }

    /// The scene's start with `values` set. Particle coordinates set are held and the
    /// others placed on the constraints around them ([`solve_holding`]: `bead.x` swept on a
    /// curve puts the bead on the curve at that x); q and qdot set are taken as they are.
    /// Only the parts (positions and velocities, q, qdot) they touch are asked for.
    fn request(system: &System, values: &[(StatePart, f64)]) -> Result<StateRequest, String> {
        let (mut x, mut v) = system.initial_particle_state();
        let n = x.len();
        let (mut held_x, mut held_v) = (vec![false; n], vec![false; n]);
        for &(part, value) in values {
            match part {
                StatePart::Position(k) => (x[k], held_x[k]) = (value, true),
                StatePart::Velocity(k) => (v[k], held_v[k]) = (value, true),
                _ => {}
            }
        }
        let cartesian = held_x.iter().chain(&held_v).any(|&h| h);
        if cartesian {
            solve_holding(system, 0.0, &mut x, &mut v, &held_x, &held_v)?;
        }
        let (q, qdot) = system.parametric().map_or((Vec::new(), Vec::new()), |m| {
            (m.initial().to_vec(), m.rates().to_vec())
        });
        let mut request = StateRequest::default();
        if cartesian {
            request.positions = Some(x);
            request.velocities = Some(v);
        }
        for &(part, value) in values {
            match part {
                StatePart::Q(k) => request.q.get_or_insert_with(|| q.clone())[k] = value,
                StatePart::Qdot(k) => request.qdot.get_or_insert_with(|| qdot.clone())[k] = value,
                _ => {}
            }
        }
        Ok(request)
    }
}

impl Sweep {
    /// A sweep of `scene` (with the overrides it was loaded with) over `axes`, each member
    /// run as `request` asks over its own scene's `[run]` table (recording nothing unless
    /// [`Sweep::recording`] says), until the end or until `stop_when` ([`Event`]; `None`:
    /// the scene's `[run] stop_when`, if any) fires. Checks the axes (each a parameter of
    /// the scene or a number of its start, once, with values; zipped axes of one length; at
    /// most [`MAX_MEMBERS`] members) and the request against the scene itself. No axes make
    /// one member: the scene as it is.
    pub fn new(
        scene: &Scene,
        axes: Vec<Axis>,
        combine: Combine,
        request: PlanRequest,
        stop_when: Option<String>,
    ) -> Result<Sweep, SweepError> {
        let method = Plan::resolve(scene, &request)?.method;
        for (i, axis) in axes.iter().enumerate() {
            let is_param = scene.params.iter().any(|(n, _)| *n == axis.name);
            if !is_param && StatePart::of(&scene.system, &axis.name).is_none() {
                return Err(SweepError::UnknownParam {
                    name: axis.name.clone(),
                    known: scene.params.iter().map(|(n, _)| n.clone()).collect(),
                });
            }
            if axes[..i].iter().any(|a| a.name == axis.name) {
                return Err(SweepError::Repeated {
                    name: axis.name.clone(),
                });
            }
            if axis.is_empty() {
                return Err(SweepError::NoValues {
                    name: axis.name.clone(),
                });
            }
        }
        let shape: Vec<usize> = match combine {
            Combine::Grid => axes.iter().map(Axis::len).collect(),
            Combine::Zip => {
                let n = axes[0].len();
                if axes.iter().any(|a| a.len() != n) {
                    return Err(SweepError::ZipLengths {
                        lengths: axes.iter().map(|a| (a.name.clone(), a.len())).collect(),
                    });
                }
                vec![n]
            }
        };
        let len = shape
            .iter()
            .try_fold(1u64, |acc, &n| acc.checked_mul(n as u64))
            .filter(|&n| n <= MAX_MEMBERS)
            .and_then(|n| usize::try_from(n).ok())
            .ok_or_else(|| SweepError::TooLarge {
                shape: shape.clone(),
            })?;
        let setup = Self::member_setup(scene, &axes, &request, stop_when.as_deref());
        Ok(Sweep {
            scene: scene.clone(),
            axes,
            combine,
            request,
            method,
            layout: Layout::of(&scene.system, method),
            stop_when,
            shape,
            len,
            setup: Arc::new(setup),
            restarted: Arc::new(AtomicUsize::new(0)),
            recording: Recording::Nothing,
            rows: 0,
        })
    }

    /// This sweep with each member recording `recording` (see [`Member::trajectory`]).
    /// Members that record run one by one rather than stepped together; their figures are
    /// unchanged, bit for bit, and their rows are those of the same run alone. Refuses
    /// times that decrease, are not finite or lie before the start (t = 0), or none.
    pub fn recording(mut self, recording: Recording) -> Result<Sweep, SweepError> {
        if let Recording::Times(times) = &recording {
            if times.is_empty() {
                return Err(SweepError::Times("no times given".into()));
            }
            for (k, &t) in times.iter().enumerate() {
                if !t.is_finite() || t < 0.0 {
                    return Err(SweepError::Times(format!(
                        "time {k} is {}: times must be finite and >= 0 (a member starts at t = 0)",
                        crate::readable(t)
                    )));
                }
                if k > 0 && t < times[k - 1] {
                    return Err(SweepError::Times(format!(
                        "time {k} ({}) is before time {} ({}): the times must not decrease",
                        crate::readable(t),
                        k - 1,
                        crate::readable(times[k - 1])
                    )));
                }
            }
        }
        let plan = Plan::resolve(&self.scene, &self.request)?;
        self.rows = match &recording {
            Recording::Nothing => 0,
            Recording::Steps => plan.steps / plan.every.max(1) + 2,
            Recording::Times(times) => times.len() as u64,
        };
        self.recording = recording;
        Ok(self)
    }

    /// What each member records.
    pub fn recorded(&self) -> &Recording {
        &self.recording
    }

    /// The most rows a member records (0 when it records none): `times.len()`, or for
    /// [`Recording::Steps`] steps / every + 2 of the scene's plan (a member whose parameters
    /// change its duration or dt may record more, and its trajectory then has them all).
    pub fn rows_per_member(&self) -> u64 {
        self.rows
    }

    /// How the members of a sweep of `scene` over `axes` are set up: restarted from the
    /// scene's compiled equations when the parameters swept reach only its initial values,
    /// else loaded again.
    fn member_setup(
        scene: &Scene,
        axes: &[Axis],
        request: &PlanRequest,
        stop_when: Option<&str>,
    ) -> MemberSetup {
        if let Some(axis) = axes
            .iter()
            .find(|a| StatePart::of(&scene.system, &a.name).is_some())
        {
            return MemberSetup::Reload(vec![format!(
                "the initial state is swept (`{}`): each member's start is placed on the \
                 constraints",
                axis.name
            )]);
        }
        let names: Vec<String> = axes.iter().map(|a| a.name.clone()).collect();
        let rebinder = match scene.rebinder(&names) {
            Ok(rebinder) => rebinder,
            Err(why) => return MemberSetup::Reload(why),
        };
        let Ok(plan) = Plan::resolve(scene, request) else {
            return MemberSetup::Reload(vec!["the run cannot be planned".into()]);
        };
        let stop = match (stop_when, &scene.run.stop_when) {
            (Some(source), _) if rebinder.reaches(source) => Stop::Each(source.to_string()),
            (Some(source), _) => Stop::Once(Event::parse(&scene.system, source).map_err(|_| ())),
            (None, Some(event)) if rebinder.reaches(event.source()) => {
                Stop::Each(event.source().to_string())
            }
            (None, Some(event)) => Stop::Once(Ok(event.clone())),
            (None, None) => Stop::None,
        };
        MemberSetup::Restart(Box::new(Restart {
            rebinder,
            plan,
            stop,
            events: scene.run.events.clone(),
        }))
    }

    /// Why each member's scene is loaded again from its text, one reason per entry
    /// (`` `g` reaches world `gravity` ``: the parameters swept, or one defined from them,
    /// change the equations of motion, the run or the scene's structure); empty when the
    /// parameters swept reach only where the scene starts (particles' positions and
    /// velocities, the parametric form's initial values and rates, the stop condition), so
    /// that a member is set up from the scene's compiled equations with only those values
    /// evaluated again (a few microseconds instead of a load). Either way a member's numbers
    /// are those of [`Scene::with_params`], bit for bit.
    pub fn reload_reasons(&self) -> &[String] {
        match &*self.setup {
            MemberSetup::Restart(_) => &[],
            MemberSetup::Reload(why) => why,
        }
    }

    /// How many members were set up from the scene's compiled equations so far (see
    /// [`Sweep::reload_reasons`]); the others were loaded again, as every member is when the
    /// parameters swept change the equations, and a member whose values make the scene
    /// invalid is (its error is the load's).
    pub fn restarted_members(&self) -> usize {
        self.restarted.load(Ordering::Relaxed)
    }

    /// Set member `index` up to run, without running it: whether it could start. What a
    /// member's setup costs, for the benches.
    #[doc(hidden)]
    pub fn set_up_member(&self, index: usize) -> bool {
        matches!(self.prepare(index), Prepared::Ready(_))
    }

    /// This sweep with every member's scene loaded again from its text, as when the
    /// parameters swept change the equations: the reference the restarted members are
    /// compared with (tests, benches).
    #[doc(hidden)]
    pub fn reloading_every_member(mut self) -> Sweep {
        self.setup = Arc::new(MemberSetup::Reload(vec!["asked for".into()]));
        self.restarted = Arc::new(AtomicUsize::new(0));
        self
    }

    /// The number of members.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it has no members (never: every axis has a value).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The shape of the results: the axes' lengths for a grid, the common length for a zip.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The axes, in order.
    pub fn axes(&self) -> &[Axis] {
        &self.axes
    }

    /// The scene swept.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The formulation of the scene's plan, which the columns follow.
    pub fn method(&self) -> Method {
        self.method
    }

    /// The scene's particles and coordinates: the wide CSV's columns and a member's
    /// [`Member::layout`] when it is `None`.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Member `index`'s parameter values, in the order of the axes.
    pub fn params_of(&self, index: usize) -> Vec<f64> {
        match self.combine {
            Combine::Zip => self.axes.iter().map(|a| a.value(index)).collect(),
            Combine::Grid => {
                let mut rest = index;
                let mut values = vec![0.0; self.axes.len()];
                for (k, axis) in self.axes.iter().enumerate().rev() {
                    let n = axis.len();
                    values[k] = axis.value(rest % n);
                    rest /= n;
                }
                values
            }
        }
    }

    /// `member 3 (N = 5, L = 1)`: a member and its values, for messages.
    pub fn describe_member(&self, member: &Member) -> String {
        let values: Vec<String> = self
            .axes
            .iter()
            .zip(&member.params)
            .map(|(a, v)| format!("{} = {v}", a.name))
            .collect();
        format!("member {} ({})", member.index, values.join(", "))
    }

    /// [`SweepError::OtherLayout`] when `member`'s particles or coordinates are not the
    /// scene's, so that it does not fit the scene's columns.
    pub fn check_layout(&self, member: &Member) -> Result<(), SweepError> {
        match &member.layout {
            None => Ok(()),
            Some(found) => Err(SweepError::OtherLayout {
                index: member.index,
                member: self.describe_member(member),
                found: Box::new(Layout::clone(found)),
                expected: Box::new(self.layout.clone()),
            }),
        }
    }

    /// Run member `index` alone (on the calling thread). A panic inside the library (a bug)
    /// fails this member only, with the panic's message.
    pub fn run_member(&self, index: usize) -> Member {
        self.guarded(index, || self.member(index))
    }

    /// Member `index` failed with a panic inside the library (a bug), with its message.
    fn panicked(&self, index: usize, panic: &(dyn std::any::Any + Send)) -> Member {
        let message = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        Member {
            index,
            params: self.params_of(index),
            stats: None,
            error: Some(format!("internal error (a bug in bead): {message}")),
            layout: None,
            trajectory: None,
        }
    }

    fn member(&self, index: usize) -> Member {
        match self.prepare(index) {
            Prepared::Finished(member) => *member,
            Prepared::Ready(ready) => ready.run_alone(&self.recording),
        }
    }

    /// Member `index` set up to run (its scene with its values, its plan, its simulation and
    /// stop condition), or its result when it cannot start.
    fn prepare(&self, index: usize) -> Prepared {
        let params = self.params_of(index);
        if let MemberSetup::Restart(restart) = &*self.setup {
            if let Some(ready) = self.restart(restart, index, &params) {
                self.restarted.fetch_add(1, Ordering::Relaxed);
                return Prepared::Ready(Box::new(ready));
            }
        }
        let fail = |error: String, layout: Option<Arc<Layout>>| {
            Prepared::Finished(Box::new(Member {
                index,
                params: params.clone(),
                stats: None,
                error: Some(error),
                layout,
                trajectory: None,
            }))
        };
        let mut overrides: Vec<(String, f64)> = Vec::new();
        let mut state: Vec<(StatePart, f64)> = Vec::new();
        for (axis, &value) in self.axes.iter().zip(&params) {
            match StatePart::of(&self.scene.system, &axis.name) {
                Some(part) => state.push((part, value)),
                None => overrides.push((axis.name.clone(), value)),
            }
        }
        let scene = if overrides.is_empty() {
            Ok(self.scene.clone())
        } else {
            self.scene.with_params(&overrides)
        };
        let scene = match scene {
            Ok(scene) => scene,
            // `file:line:column: message`, without the snippet under it: one line per member.
            Err(e) => {
                let line = e.to_string().lines().next().unwrap_or_default().to_string();
                return fail(line, None);
            }
        };
        let scene = if state.is_empty() {
            scene
        } else {
            let placed = StatePart::request(&scene.system, &state)
                .and_then(|request| scene.with_state(&request).map_err(|e| e.to_string()));
            match placed {
                Ok((scene, _)) => scene,
                Err(e) => return fail(format!("the initial state: {e}"), None),
            }
        };
        let plan = match Plan::resolve(&scene, &self.request) {
            Ok(plan) => plan,
            Err(e) => return fail(e.to_string(), None),
        };
        let layout = (!self.layout.matches(&scene.system, self.method))
            .then(|| Arc::new(Layout::of(&scene.system, self.method)));
        let config = plan.config(plan.method);
        let mut simulation = match Simulation::new(Arc::clone(&scene.system), config) {
            Ok(simulation) => simulation,
            Err(e) => return fail(e.to_string(), layout),
        };
        let event = match &self.stop_when {
            Some(source) => match Event::parse(&scene.system, source) {
                Ok(event) => Some(event),
                Err(e) => return fail(format!("the stop condition `{source}`: {e}"), layout),
            },
            None => scene.run.stop_when.clone(),
        };
        if let Err(e) = simulation.set_events(scene.run.events_with(event)) {
            return fail(e.to_string(), layout);
        }
        Prepared::Ready(Box::new(Ready {
            index,
            params,
            system: Arc::clone(&scene.system),
            simulation: Some(simulation),
            options: plan.options(),
            layout,
            restarted: false,
        }))
    }

    /// Member `index` with values `params` set up from the scene's compiled equations
    /// ([`MemberSetup::Restart`]); `None` when anything fails, so that the member is loaded
    /// again and fails with the load's own words.
    fn restart(&self, restart: &Restart, index: usize, params: &[f64]) -> Option<Ready> {
        let values: Vec<(String, f64)> = self
            .axes
            .iter()
            .zip(params)
            .map(|(a, &v)| (a.name.clone(), v))
            .collect();
        let system = Arc::new(restart.rebinder.system(&values)?);
        let plan = &restart.plan;
        let mut simulation = Simulation::new(Arc::clone(&system), plan.config(plan.method)).ok()?;
        let event = match &restart.stop {
            Stop::None => None,
            Stop::Once(event) => Some(event.as_ref().ok()?.clone()),
            Stop::Each(source) => Some(Event::parse(&system, source).ok()?),
        };
        let mut events = restart.events.clone();
        events.extend(event.map(EventSpec::stop));
        simulation.set_events(events).ok()?;
        Some(Ready {
            index,
            params: params.to_vec(),
            system,
            simulation: Some(simulation),
            options: plan.options(),
            layout: None,
            restarted: true,
        })
    }

    /// Members `range` (at most [`LANES`]): those whose runs the lanes can take and that share
    /// the first such member's equations and run are stepped together
    /// ([`crate::simulate::lanes`]); the others, and any that leave the lanes, run alone.
    /// Either way a member's figures are those of its run alone, bit for bit.
    fn run_block(&self, range: Range<usize>) -> Vec<Member> {
        let mut done: Vec<Member> = Vec::with_capacity(range.len());
        let mut together: Vec<Ready> = Vec::new();
        for index in range {
            let prepared =
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.prepare(index)));
            match prepared {
                Ok(Prepared::Finished(member)) => done.push(*member),
                Ok(Prepared::Ready(ready)) => {
                    let joins = self.recording == Recording::Nothing
                        && lanes_can_run(ready.sim())
                        && together.first().is_none_or(|first| first.runs_like(&ready));
                    if joins {
                        together.push(*ready);
                    } else {
                        done.push(self.guarded(index, || ready.run_alone(&self.recording)));
                    }
                }
                Err(_) => done.push(self.run_member(index)),
            }
        }
        if let Some(first) = together.first() {
            let system = Arc::clone(&first.system);
            let options = first.options;
            let mut simulations: Vec<Simulation> =
                together.iter_mut().map(|r| r.take_simulation()).collect();
            let start = Instant::now();
            let outcomes = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                run_lanes(&system, &mut simulations, options)
            }));
            let wall = start.elapsed().as_secs_f64() / together.len() as f64;
            match outcomes {
                Ok(outcomes) => {
                    for ((ready, simulation), outcome) in
                        together.into_iter().zip(simulations).zip(outcomes)
                    {
                        done.push(match outcome {
                            LaneOutcome::Done => Member {
                                index: ready.index,
                                params: ready.params,
                                stats: Some(simulation.stats(wall)),
                                error: None,
                                layout: ready.layout,
                                trajectory: None,
                            },
                            LaneOutcome::Handover { intervals } => {
                                let index = ready.index;
                                let mut simulation = simulation;
                                self.guarded(index, || {
                                    let options = ready.options;
                                    ready.finish(
                                        run_rest(&mut simulation, 0.0, intervals, options),
                                        None,
                                    )
                                })
                            }
                            LaneOutcome::Leave => self.run_member(ready.index),
                        });
                    }
                }
                Err(_) => done.extend(together.iter().map(|r| self.run_member(r.index))),
            }
        }
        done.sort_by_key(|m| m.index);
        done
    }

    /// [`Self::run_block`], whose every member is reported failed should the block itself
    /// panic (a bug outside any member): a thread of [`Self::run_each`] never unwinds.
    fn run_block_guarded(&self, range: Range<usize>) -> Vec<Member> {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            self.run_block(range.clone())
        }))
        .unwrap_or_else(|panic| range.map(|i| self.panicked(i, &*panic)).collect())
    }

    /// `f`'s member, or member `index` failed with the message of a panic inside it.
    fn guarded(&self, index: usize, f: impl FnOnce() -> Member) -> Member {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
            .unwrap_or_else(|panic| self.panicked(index, &*panic))
    }

    /// Every member, on `threads` threads (0: one per core), held in memory: see
    /// [`Self::run_each`] to stream them.
    pub fn run(&self, threads: usize) -> Result<Vec<Member>, SweepError> {
        self.run_range(0..self.len, threads)
    }

    /// Members `range` (a chunk of the sweep, to split it across processes or machines), on
    /// `threads` threads (0: one per core), in index order, held in memory
    /// ([`SweepError::TooManyToHold`] when the allocation fails). A member's result depends
    /// on its index alone: chunks and thread counts do not change a number.
    pub fn run_range(
        &self,
        range: Range<usize>,
        threads: usize,
    ) -> Result<Vec<Member>, SweepError> {
        self.check_range(&range)?;
        let mut members: Vec<Member> = Vec::new();
        members
            .try_reserve_exact(range.len())
            .map_err(|_| SweepError::TooManyToHold {
                members: range.len(),
                bytes: (range.len() as u64).saturating_mul(self.member_bytes() as u64),
            })?;
        self.run_each(range, threads, |member| {
            members.push(member);
            Ok::<(), SweepError>(())
        })?;
        Ok(members)
    }

    /// Run members `range` on `threads` threads (0: one per core) and hand each to `each` on
    /// the calling thread, in index order, as soon as it and every member before it are done.
    /// Memory is bounded whatever the count: threads take blocks of 16 members (`LANES`) from a
    /// shared counter, but none starts a block more than a window of a few blocks per thread
    /// (fewer for large systems: about 16 MiB of results) ahead of the next member to hand
    /// over. When `each` returns an error, no further member starts and that error is
    /// returned once the running ones end. A member's result depends on its index alone:
    /// the thread count changes no number, only the order in which members finish.
    pub fn run_each<E: From<SweepError>>(
        &self,
        range: Range<usize>,
        threads: usize,
        mut each: impl FnMut(Member) -> Result<(), E>,
    ) -> Result<(), E> {
        self.check_range(&range)?;
        let threads = match threads {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n,
        }
        .min(range.len().div_ceil(LANES).max(1));
        let end = range.end;
        let block = |start: usize| start..(start + LANES).min(end);
        if threads <= 1 {
            for start in range.step_by(LANES) {
                for member in self.run_block_guarded(block(start)) {
                    each(member)?;
                }
            }
            return Ok(());
        }
        // Blocks a thread may run ahead of the next member to hand over: 2 to 32 per thread,
        // as many as fit in 16 MiB of results.
        let per_block = LANES.saturating_mul(self.member_bytes());
        let ahead = ((16usize << 20) / per_block).clamp(2, 32);
        let window = threads * ahead * LANES;
        let next = AtomicUsize::new(range.start);
        // The first member not yet handed over, and whether to stop.
        let handed = Mutex::new((range.start, false));
        let moved = Condvar::new();
        let lock = || handed.lock().unwrap_or_else(PoisonError::into_inner);
        let (sender, blocks) = mpsc::channel::<(usize, Vec<Member>)>();
        std::thread::scope(|scope| {
            for _ in 0..threads {
                let sender = sender.clone();
                let (next, moved, lock) = (&next, &moved, &lock);
                scope.spawn(move || loop {
                    let start = next.fetch_add(LANES, Ordering::Relaxed);
                    if start >= end {
                        break;
                    }
                    {
                        let mut state = lock();
                        // The block the consumer waits for is always inside the window, so
                        // some thread can always go on.
                        while !state.1 && start >= state.0 + window {
                            state = moved.wait(state).unwrap_or_else(PoisonError::into_inner);
                        }
                        if state.1 {
                            break;
                        }
                    }
                    if sender
                        .send((start, self.run_block_guarded(block(start))))
                        .is_err()
                    {
                        break;
                    }
                });
            }
            drop(sender);
            let mut pending: BTreeMap<usize, Vec<Member>> = BTreeMap::new();
            let mut at = range.start;
            let mut outcome = Ok(());
            'blocks: for (start, members) in blocks.iter() {
                pending.insert(start, members);
                while let Some(members) = pending.remove(&at) {
                    at = (at + LANES).min(end);
                    for member in members {
                        if let Err(e) = each(member) {
                            outcome = Err(e);
                            break 'blocks;
                        }
                    }
                    lock().0 = at;
                    moved.notify_all();
                }
            }
            // Stop the threads (after an error; at the end they have stopped already).
            lock().1 = true;
            moved.notify_all();
            drop(blocks);
            outcome
        })
    }

    /// [`SweepError::OutOfRange`] unless `range` is a range of members.
    fn check_range(&self, range: &Range<usize>) -> Result<(), SweepError> {
        if range.start > range.end || range.end > self.len {
            return Err(SweepError::OutOfRange {
                start: range.start,
                end: range.end,
                len: self.len,
            });
        }
        Ok(())
    }

    /// About how much memory one member's result takes (its struct, values and state).
    fn member_bytes(&self) -> usize {
        let state = 2 * self.layout.n_coords() + 2 * self.layout.coordinates.len();
        let rows = usize::try_from(self.rows).unwrap_or(usize::MAX);
        let recorded = rows.saturating_mul(8 * (state + 4));
        (std::mem::size_of::<Member>() + 8 * (self.axes.len() + 2 * state) + 256)
            .saturating_add(recorded)
    }
}

/// A member set up, or its result when it could not start.
enum Prepared {
    Ready(Box<Ready>),
    Finished(Box<Member>),
}

/// A member ready to run.
struct Ready {
    index: usize,
    params: Vec<f64>,
    /// Its scene's system (the member's initial state)
    system: Arc<System>,
    simulation: Option<Simulation>,
    options: RunOptions,
    layout: Option<Arc<Layout>>,
    /// Set up from the scene's compiled equations: its dynamics are the scene's.
    restarted: bool,
}

impl Ready {
    fn take_simulation(&mut self) -> Simulation {
        self.simulation.take().expect("taken once")
    }

    /// Whether `other` runs the same equations the same way (the lanes step them together).
    fn runs_like(&self, other: &Ready) -> bool {
        let (a, b) = (self.sim(), other.sim());
        self.options == other.options
            && a.config() == b.config()
            && ((self.restarted && other.restarted) || self.system.same_dynamics_as(&other.system))
    }

    fn sim(&self) -> &Simulation {
        self.simulation.as_ref().expect("not taken yet")
    }

    /// Run it on its own, recording what `recording` asks.
    fn run_alone(mut self: Box<Self>, recording: &Recording) -> Member {
        let mut simulation = self.take_simulation();
        let (coordinates, k) = (
            self.system.n_coords(),
            match simulation.config().method {
                Method::Parametric => simulation.formulation().coordinate_names().len(),
                Method::Implicit => 0,
            },
        );
        let work = simulation.tracks_work();
        let (result, trajectory) = match recording {
            Recording::Nothing => (run(&mut simulation, self.options, &mut NullSink), None),
            Recording::Steps => {
                let rows = self.options.steps / self.options.every.max(1) + 2;
                let mut rows = Trajectory::with_room(rows, coordinates, k, work);
                let result =
                    run_with_progress(&mut simulation, self.options, &mut rows, &mut NoProgress);
                (result, Some(rows))
            }
            Recording::Times(times) => {
                let mut rows = Trajectory::with_room(times.len() as u64, coordinates, k, work);
                let result = run_at_times(&mut simulation, times, &mut rows, &mut NoProgress);
                (result, Some(rows))
            }
        };
        self.finish(result, trajectory.map(Box::new))
    }

    /// Its member, from the result of its run and what it recorded.
    fn finish(
        self,
        result: Result<RunStats, RunFailure>,
        trajectory: Option<Box<Trajectory>>,
    ) -> Member {
        let (stats, error) = match result {
            Ok(stats) => (stats, None),
            Err(failure) => (*failure.stats, Some(failure.error.to_string())),
        };
        Member {
            index: self.index,
            params: self.params,
            stats: Some(stats),
            error,
            layout: self.layout,
            trajectory,
        }
    }
}

/// The columns every row of both CSV formats starts with, after `member` and the parameters.
const FIGURES: [&str; 8] = [
    "status",
    "t_final",
    "stop_time",
    "steps",
    "energy_rel_error_max",
    "energy_balance_error_max",
    "constraint_error_max",
    "newton_iterations",
];

impl Sweep {
    /// The wide CSV's header ([`CsvFormat::Wide`]): `member`, the parameters,
    /// `status,t_final,stop_time,steps,energy_rel_error_max,energy_balance_error_max,
    /// constraint_error_max,newton_iterations` (the keys of `bead run --json`), every particle's final
    /// position and velocity (`P.x`, ..., `P.vx`, ...), the final generalized coordinates
    /// and rates of a parametric run (`q.NAME`, `qdot.NAME`), then `error`.
    pub fn csv_header(&self) -> String {
        let system = &self.scene.system;
        let mut columns = self.leading_columns();
        columns.extend((0..system.n_coords()).map(|k| system.coordinate_name(k)));
        columns.extend((0..system.n_coords()).map(|k| system.velocity_name(k)));
        columns.extend(self.layout.coordinates.iter().map(|c| format!("q.{c}")));
        columns.extend(self.layout.coordinates.iter().map(|c| format!("qdot.{c}")));
        columns.push("error".into());
        join_fields(&columns)
    }

    /// The long CSV's header ([`CsvFormat::Long`]): the wide one's columns up to
    /// `newton_iterations`, then `coordinate,position,velocity,error`.
    pub fn long_csv_header(&self) -> String {
        let mut columns = self.leading_columns();
        columns.extend(["coordinate", "position", "velocity", "error"].map(String::from));
        join_fields(&columns)
    }

    /// The header of `format`.
    pub fn header(&self, format: CsvFormat) -> String {
        match format {
            CsvFormat::Wide => self.csv_header(),
            CsvFormat::Long => self.long_csv_header(),
        }
    }

    /// `member`, the parameters and [`FIGURES`].
    fn leading_columns(&self) -> Vec<String> {
        let mut columns: Vec<String> = vec!["member".into()];
        // An axis of the start is `start.bead.x`: `bead.x` is the final position's column.
        columns.extend(self.axes.iter().map(|a| {
            match StatePart::of(&self.scene.system, &a.name) {
                Some(_) => format!("start.{}", a.name),
                None => a.name.clone(),
            }
        }));
        columns.extend(FIGURES.map(String::from));
        columns
    }

    /// `member`'s values of the leading columns, each preceded by a comma but the first.
    fn leading_fields(&self, member: &Member) -> String {
        use std::fmt::Write;
        let mut row = String::new();
        let _ = write!(row, "{}", member.index);
        for value in &member.params {
            let _ = write!(row, ",{value}");
        }
        let _ = write!(row, ",{}", member.status());
        match &member.stats {
            Some(stats) => {
                let _ = write!(row, ",{},", stats.t_final);
                if let Some(t) = stats.stop_time {
                    let _ = write!(row, "{t}");
                }
                let _ = write!(row, ",{},{},", stats.steps, stats.energy_rel_error_max);
                if let Some(balance) = stats.energy_balance_error_max {
                    let _ = write!(row, "{balance}");
                }
                let _ = write!(row, ",{},", stats.constraint_error_max);
                if let Some(iterations) = stats.newton_iterations {
                    let _ = write!(row, "{iterations}");
                }
            }
            None => row.push_str(&",".repeat(FIGURES.len() - 1)),
        }
        row
    }

    /// One wide CSV row of `member` (see [`Sweep::csv_header`]), without a line break:
    /// numbers exact (shortest round-trip), empty where the member has no value. A member
    /// whose particles or coordinates are not the scene's does not fit the columns:
    /// [`SweepError::OtherLayout`].
    pub fn csv_row(&self, member: &Member) -> Result<String, SweepError> {
        use std::fmt::Write;
        self.check_layout(member)?;
        let mut row = self.leading_fields(member);
        let n_q = self.layout.coordinates.len();
        match &member.stats {
            Some(stats) => {
                for value in stats.x.iter().chain(&stats.xdot) {
                    let _ = write!(row, ",{value}");
                }
                if n_q > 0 {
                    for value in stats.q.iter().chain(&stats.qdot) {
                        let _ = write!(row, ",{value}");
                    }
                }
            }
            None => row.push_str(&",".repeat(2 * self.layout.n_coords() + 2 * n_q)),
        }
        row.push(',');
        if let Some(error) = &member.error {
            row.push_str(&csv_field(error));
        }
        Ok(row)
    }

    /// The long CSV rows of `member` (see [`Sweep::long_csv_header`]), each ending in a line
    /// break: one per particle coordinate (`P.x`, its final position and velocity), then
    /// one per generalized coordinate of a parametric run (`q.NAME`, q and qdot), named
    /// after the member's own particles; a member without a state (it could not start) is
    /// one row with empty coordinate, position and velocity.
    pub fn long_csv_rows(&self, member: &Member) -> String {
        use std::fmt::Write;
        let leading = self.leading_fields(member);
        let error = member.error.as_deref().map(csv_field).unwrap_or_default();
        let layout = member.layout.as_deref().unwrap_or(&self.layout);
        let mut rows = String::new();
        let Some(stats) = &member.stats else {
            let _ = writeln!(rows, "{leading},,,,{error}");
            return rows;
        };
        for (k, (x, v)) in stats.x.iter().zip(&stats.xdot).enumerate() {
            let name = csv_field(&layout.coordinate_name(k));
            let _ = writeln!(rows, "{leading},{name},{x},{v},{error}");
        }
        if !layout.coordinates.is_empty() {
            for (name, (q, v)) in layout
                .coordinates
                .iter()
                .zip(stats.q.iter().zip(&stats.qdot))
            {
                let name = csv_field(&format!("q.{name}"));
                let _ = writeln!(rows, "{leading},{name},{q},{v},{error}");
            }
        }
        rows
    }

    /// The rows of `member` in `format`, each ending in a line break.
    pub fn rows(&self, format: CsvFormat, member: &Member) -> Result<String, SweepError> {
        match format {
            CsvFormat::Wide => self.csv_row(member).map(|row| row + "\n"),
            CsvFormat::Long => Ok(self.long_csv_rows(member)),
        }
    }

    /// The header and the rows of `members` in `format`, each line ending in a line break.
    /// A member that does not fit the wide format stops the writing there, with the rows
    /// before it written.
    pub fn write_csv(
        &self,
        format: CsvFormat,
        members: &[Member],
        out: &mut dyn io::Write,
    ) -> Result<(), CsvError> {
        writeln!(out, "{}", self.header(format))?;
        for member in members {
            out.write_all(self.rows(format, member)?.as_bytes())?;
        }
        Ok(())
    }
}

/// Fields joined into a CSV line, each quoted where needed.
fn join_fields(fields: &[String]) -> String {
    fields
        .iter()
        .map(|c| csv_field(c))
        .collect::<Vec<_>>()
        .join(",")
}

/// A CSV field, quoted (with quotes doubled) when it holds a comma, a quote or a line break.
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formulation::Method;

    fn shipped_scenes() -> Vec<(String, Scene)> {
        crate::shipped_scene_paths()
            .into_iter()
            .map(|p| {
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                (name, Scene::load(&p, &[]).unwrap())
            })
            .collect()
    }

    /// An axis spanning more than f64::MAX (-1e308 to 1e308) has finite, evenly spaced
    /// values (its spacing overflowed to inf: the middle values were NaN and inf); within
    /// range the values are numpy's, bit for bit.
    #[test]
    fn linspace_values_stay_finite_across_a_span_beyond_the_largest_number() {
        let wide = Axis::linspace("g", -1e308, 1e308, 5).unwrap();
        let values: Vec<f64> = wide.values().collect();
        assert_eq!(values, [-1e308, -5e307, 0.0, 5e307, 1e308]);
        let max = Axis::linspace("g", f64::MIN, f64::MAX, 3).unwrap();
        assert_eq!(max.values().collect::<Vec<_>>(), [f64::MIN, 0.0, f64::MAX]);
        // numpy's `_nx.arange(0, num) * step + start`, step = (stop - start) / (num - 1)
        let step = (0.7 - 0.1) / 6.0;
        let numpy: Vec<f64> = (0..6).map(|i| i as f64 * step + 0.1).chain([0.7]).collect();
        let narrow = Axis::linspace("g", 0.1, 0.7, 7).unwrap();
        assert_eq!(narrow.values().collect::<Vec<_>>(), numpy);
    }

    /// Two values near `v` that keep a count a count.
    fn near(v: f64) -> Vec<f64> {
        if v.fract() == 0.0 && v.abs() >= 2.0 {
            vec![v - 1.0, v + 1.0]
        } else {
            vec![v * 1.0625 + 0.03125, v * 0.875 - 0.0625]
        }
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// A member's figures, exactly (every float as its shortest round trip, which tells
    /// every bit but a NaN's payload), without its wall time.
    fn figures(member: &Member) -> String {
        let stats = member.stats.clone().map(|mut s| {
            s.wall_seconds = 0.0;
            s
        });
        format!("{stats:?} {:?} {:?}", member.error, member.layout)
    }

    /// The parameters whose sweeps are expected to restart members: those that reach only
    /// initial values in the shipped scenes.
    const RESTARTED: [(&str, &str); 21] = [
        ("bounce.toml", "x0"),
        ("circle.toml", "theta0"),
        ("cloth.toml", "F"),
        ("cusp.toml", "s0"),
        ("cycloid.toml", "phi0"),
        ("double-pendulum.toml", "th1"),
        ("double-pendulum.toml", "th2"),
        ("helix.toml", "w0"),
        ("hump.toml", "v0"),
        ("hump.toml", "x0"),
        ("hump.toml", "s0"),
        ("infinity.toml", "v0"),
        ("lemniscate.toml", "v0"),
        ("loop.toml", "v0"),
        ("net.toml", "F"),
        ("node.toml", "s0"),
        ("parabola-x0.toml", "x0"),
        ("rope.toml", "F"),
        ("spinning-hoop.toml", "th0"),
        ("spiral.toml", "w0"),
        ("tassel.toml", "F"),
    ];

    /// Every parameter of every shipped scene, swept to two values: a restarted member is
    /// the member of `Scene::with_params` exactly (initial state, parameters, dynamics,
    /// plan, stop condition), and runs to the same figures bit for bit, in both forms; the
    /// parameters that reach only initial values restart every member.
    #[test]
    fn restarted_members_equal_the_members_loaded_again() {
        let mut restarted = Vec::new();
        for (file, scene) in shipped_scenes() {
            for (name, value) in scene.params.clone() {
                let methods: &[Method] = if scene.system.parametric().is_some() {
                    &[Method::Implicit, Method::Parametric]
                } else {
                    &[Method::Implicit]
                };
                for &method in methods {
                    let request = PlanRequest {
                        method: Some(method),
                        steps: Some(3),
                        ..Default::default()
                    };
                    let axis = Axis::new(&name, near(value));
                    let stop = Some("t - 0.02".to_string());
                    let sweep =
                        Sweep::new(&scene, vec![axis], Combine::Grid, request, stop).unwrap();
                    let reloaded = sweep.clone().reloading_every_member();
                    let mut ready = 0;
                    for index in 0..sweep.len() {
                        let values = vec![(name.clone(), sweep.params_of(index)[0])];
                        let (fast, slow) = (sweep.prepare(index), reloaded.prepare(index));
                        match (&fast, &slow) {
                            (Prepared::Ready(a), Prepared::Ready(b)) => {
                                ready += 1;
                                let (x, y) = (&a.system, &b.system);
                                let label = format!("{file} {values:?} {method:?}");
                                assert_eq!(x.particles().len(), y.particles().len(), "{label}");
                                for (p, q) in x.particles().iter().zip(y.particles()) {
                                    assert_eq!(bits(&p.position), bits(&q.position), "{label}");
                                    assert_eq!(bits(&p.velocity), bits(&q.velocity), "{label}");
                                    assert_eq!(p.mass.to_bits(), q.mass.to_bits(), "{label}");
                                }
                                let params = |s: &System| -> Vec<(String, u64)> {
                                    s.params
                                        .iter()
                                        .map(|(n, v)| (n.clone(), v.to_bits()))
                                        .collect()
                                };
                                assert_eq!(params(x), params(y), "{label}");
                                for (n, v) in &y.params {
                                    let declared = x.declared.param_value(n).map(f64::to_bits);
                                    assert_eq!(declared, Some(v.to_bits()), "{label}");
                                }
                                if let (Some(m), Some(n)) = (x.parametric(), y.parametric()) {
                                    assert_eq!(bits(&m.initial), bits(&n.initial), "{label}");
                                    assert_eq!(bits(&m.rates), bits(&n.rates), "{label}");
                                }
                                assert!(x.same_dynamics_as(y), "{label}");
                                assert_eq!(a.options, b.options, "{label}");
                                assert_eq!(a.sim().config(), b.sim().config(), "{label}");
                                assert_eq!(a.layout, b.layout, "{label}");
                            }
                            (Prepared::Finished(a), Prepared::Finished(b)) => {
                                assert_eq!(figures(a), figures(b));
                            }
                            _ => panic!("{file} {values:?}: one method failed, the other did not"),
                        }
                        let (a, b) = (sweep.run_member(index), reloaded.run_member(index));
                        assert_eq!(figures(&a), figures(&b), "{file} {values:?} {method:?}");
                    }
                    // The whole sweep, its members stepped together in lanes.
                    let (a, b) = (sweep.run(1).unwrap(), reloaded.run(1).unwrap());
                    for (a, b) in a.iter().zip(&b) {
                        assert_eq!(figures(a), figures(b), "{file} {name} {method:?}");
                    }
                    assert_eq!(reloaded.restarted_members(), 0);
                    if sweep.reload_reasons().is_empty() {
                        // prepare, run_member and run: every member that can start is
                        // restarted each time.
                        assert_eq!(sweep.restarted_members(), 3 * ready, "{file} {name}");
                        if ready > 0 {
                            restarted.push((file.clone(), name.clone()));
                        }
                    } else {
                        assert_eq!(sweep.restarted_members(), 0, "{file} {name}");
                    }
                }
            }
        }
        restarted.dedup();
        let expected: Vec<(String, String)> = RESTARTED
            .iter()
            .map(|(f, n)| (f.to_string(), n.to_string()))
            .collect();
        assert_eq!(restarted, expected, "{restarted:?}");
    }
}
