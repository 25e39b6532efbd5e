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
//! let results = sweep.run(2);
//! // Falling from rest at g = 10: y = h at t = sqrt(h / 5).
//! for (member, h) in results.iter().zip([1.0f64, 2.0, 3.0, 4.0]) {
//!     let t = member.stats.as_ref().unwrap().stop_time.unwrap();
//!     assert!((t - (h / 5.0).sqrt()).abs() < 1e-11);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

use crate::formulation::Method;
use crate::model::System;
use crate::plan::{Plan, PlanError, PlanRequest};
use crate::scene::Scene;
use crate::simulate::lanes::{lanes_can_run, run_lanes, LaneOutcome, LANES};
use crate::simulate::{
    run, run_rest, Event, NullSink, RunFailure, RunOptions, RunStats, Simulation,
};

/// One swept parameter and its values.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// A parameter of the scene (`[params]`).
    pub name: String,
    /// Its values, in order.
    pub values: Vec<f64>,
}

impl Axis {
    /// `count` values from `start` to `stop`, both included, evenly spaced, as numpy's
    /// `linspace(start, stop, count)` computes them: value i = start + i (stop - start) /
    /// (count - 1), the last exactly `stop` (one value: `start`).
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
        let values = if count == 1 {
            vec![start]
        } else {
            let step = (stop - start) / (count - 1) as f64;
            let mut values: Vec<f64> = (0..count).map(|i| i as f64 * step + start).collect();
            values[count - 1] = stop;
            values
        };
        Ok(Axis {
            name: name.to_string(),
            values,
        })
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

/// A sweep that cannot be set up.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SweepError {
    #[error("a sweep needs at least one parameter to vary")]
    NoAxes,
    #[error("`{name}` has no values (a count of 0)")]
    NoValues { name: String },
    #[error("`{name}`: the start and stop must be finite numbers")]
    NotFinite { name: String },
    #[error("`{name}` is swept twice")]
    Repeated { name: String },
    #[error("unknown parameter `{name}`; {}", known_params(.known))]
    UnknownParam { name: String, known: Vec<String> },
    #[error("zipped parameters must have the same number of values: {}", .lengths.iter().map(|(n, l)| format!("`{n}` has {l}")).collect::<Vec<_>>().join(", "))]
    ZipLengths { lengths: Vec<(String, usize)> },
    #[error("the grid has more members than this machine can count ({})", .shape.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(" x "))]
    TooLarge { shape: Vec<usize> },
    #[error("members {start}..{end} are not in the sweep of {len} members")]
    OutOfRange {
        start: usize,
        end: usize,
        len: usize,
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

/// What one member did.
#[derive(Clone, Debug, PartialEq)]
pub struct Member {
    /// Its index in the sweep (see [`Combine`]).
    pub index: usize,
    /// Its parameter values, in the order of the axes.
    pub params: Vec<f64>,
    /// The figures of its run, complete or up to where it stopped: final state (`x`, `xdot`,
    /// and `q`, `qdot` for the parametric form), `energy_rel_error_max` and
    /// [`RunStats::conserved_energy_error_max`], `constraint_error_max`, `stop_time`,
    /// `steps`. `None` when the member could not start (its scene or initial state is
    /// invalid). `wall_seconds` is the only figure that differs between two runs.
    pub stats: Option<RunStats>,
    /// Why it failed, when it did, on one line: the scene with its values cannot be loaded
    /// (`file:line:column: message`), the simulation cannot start, or the run stopped early
    /// (then `stats` holds the figures up to the last good state).
    pub error: Option<String>,
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

/// A scene, the axes it is swept over, and how each member runs.
#[derive(Clone, Debug)]
pub struct Sweep {
    scene: Scene,
    axes: Vec<Axis>,
    combine: Combine,
    request: PlanRequest,
    /// The formulation of the base scene's plan (the CSV's columns follow it)
    method: Method,
    stop_when: Option<String>,
    /// Members per axis (grid) or the common length (zip, one entry)
    shape: Vec<usize>,
    len: usize,
}

impl Sweep {
    /// A sweep of `scene` (with the overrides it was loaded with) over `axes`, each member
    /// run as `request` asks over its own scene's `[run]` table (recording nothing), until
    /// the end or until `stop_when` ([`Event`]; `None`: the scene's `[run] stop_when`, if
    /// any) fires. Checks the axes (at least one, each a parameter of the scene, once, with
    /// values; zipped axes of one length) and the request against the scene itself.
    pub fn new(
        scene: &Scene,
        axes: Vec<Axis>,
        combine: Combine,
        request: PlanRequest,
        stop_when: Option<String>,
    ) -> Result<Sweep, SweepError> {
        let method = Plan::resolve(scene, &request)?.method;
        if axes.is_empty() {
            return Err(SweepError::NoAxes);
        }
        for (i, axis) in axes.iter().enumerate() {
            if !scene.params.iter().any(|(n, _)| *n == axis.name) {
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
            if axis.values.is_empty() {
                return Err(SweepError::NoValues {
                    name: axis.name.clone(),
                });
            }
        }
        let shape: Vec<usize> = match combine {
            Combine::Grid => axes.iter().map(|a| a.values.len()).collect(),
            Combine::Zip => {
                let n = axes[0].values.len();
                if axes.iter().any(|a| a.values.len() != n) {
                    return Err(SweepError::ZipLengths {
                        lengths: axes
                            .iter()
                            .map(|a| (a.name.clone(), a.values.len()))
                            .collect(),
                    });
                }
                vec![n]
            }
        };
        let len = shape
            .iter()
            .try_fold(1usize, |acc, &n| acc.checked_mul(n))
            .ok_or_else(|| SweepError::TooLarge {
                shape: shape.clone(),
            })?;
        Ok(Sweep {
            scene: scene.clone(),
            axes,
            combine,
            request,
            method,
            stop_when,
            shape,
            len,
        })
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

    /// Member `index`'s parameter values, in the order of the axes.
    pub fn params_of(&self, index: usize) -> Vec<f64> {
        match self.combine {
            Combine::Zip => self.axes.iter().map(|a| a.values[index]).collect(),
            Combine::Grid => {
                let mut rest = index;
                let mut values = vec![0.0; self.axes.len()];
                for (k, axis) in self.axes.iter().enumerate().rev() {
                    let n = axis.values.len();
                    values[k] = axis.values[rest % n];
                    rest /= n;
                }
                values
            }
        }
    }

    /// Run member `index` alone (on the calling thread). A panic inside the library (a bug)
    /// fails this member only, with the panic's message.
    pub fn run_member(&self, index: usize) -> Member {
        self.guarded(index, || self.member(index))
    }

    /// Member `index` failed with a panic inside the library (a bug), with its message.
    fn panicked(&self, index: usize, panic: Box<dyn std::any::Any + Send>) -> Member {
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
        }
    }

    fn member(&self, index: usize) -> Member {
        match self.prepare(index) {
            Prepared::Finished(member) => *member,
            Prepared::Ready(ready) => ready.run_alone(),
        }
    }

    /// Member `index` set up to run (its scene with its values, its plan, its simulation and
    /// stop condition), or its result when it cannot start.
    fn prepare(&self, index: usize) -> Prepared {
        let params = self.params_of(index);
        let fail = |error: String| {
            Prepared::Finished(Box::new(Member {
                index,
                params: params.clone(),
                stats: None,
                error: Some(error),
            }))
        };
        let overrides: Vec<(String, f64)> = self
            .axes
            .iter()
            .zip(&params)
            .map(|(a, &v)| (a.name.clone(), v))
            .collect();
        let scene = match self.scene.with_params(&overrides) {
            Ok(scene) => scene,
            // `file:line:column: message`, without the snippet under it: one line per member.
            Err(e) => return fail(e.to_string().lines().next().unwrap_or_default().to_string()),
        };
        let plan = match Plan::resolve(&scene, &self.request) {
            Ok(plan) => plan,
            Err(e) => return fail(e.to_string()),
        };
        let config = plan.config(plan.method);
        let mut simulation = match Simulation::new(Arc::clone(&scene.system), config) {
            Ok(simulation) => simulation,
            Err(e) => return fail(e.to_string()),
        };
        let event = match &self.stop_when {
            Some(source) => match Event::parse(&scene.system, source) {
                Ok(event) => Some(event),
                Err(e) => return fail(format!("the stop condition `{source}`: {e}")),
            },
            None => scene.run.stop_when.clone(),
        };
        if let Err(e) = simulation.set_stop_when(event) {
            return fail(e.to_string());
        }
        Prepared::Ready(Box::new(Ready {
            index,
            params,
            system: Arc::clone(&scene.system),
            simulation: Some(simulation),
            options: plan.options(),
        }))
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
                    let joins = lanes_can_run(ready.sim())
                        && together.first().is_none_or(|first| first.runs_like(&ready));
                    if joins {
                        together.push(*ready);
                    } else {
                        done.push(self.guarded(index, || ready.run_alone()));
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
                            },
                            LaneOutcome::Handover { intervals } => {
                                let index = ready.index;
                                let mut simulation = simulation;
                                self.guarded(index, || {
                                    let options = ready.options;
                                    ready.finish(run_rest(&mut simulation, 0.0, intervals, options))
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

    /// `f`'s member, or member `index` failed with the message of a panic inside it.
    fn guarded(&self, index: usize, f: impl FnOnce() -> Member) -> Member {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
            .unwrap_or_else(|panic| self.panicked(index, panic))
    }

    /// Every member, on `threads` threads (0: one per core).
    pub fn run(&self, threads: usize) -> Vec<Member> {
        self.run_range(0..self.len, threads)
            .expect("the whole sweep is in range")
    }

    /// Members `range` (a chunk of the sweep, to split it across processes or machines), on
    /// `threads` threads (0: one per core), in index order. A member's result depends on its
    /// index alone: chunks and thread counts do not change a number.
    pub fn run_range(
        &self,
        range: Range<usize>,
        threads: usize,
    ) -> Result<Vec<Member>, SweepError> {
        if range.start > range.end || range.end > self.len {
            return Err(SweepError::OutOfRange {
                start: range.start,
                end: range.end,
                len: self.len,
            });
        }
        let count = range.len();
        let threads = match threads {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n,
        }
        .min(count.div_ceil(LANES).max(1));
        let block = |start: usize| start..(start + LANES).min(range.end);
        if threads <= 1 {
            return Ok((range.start..range.end)
                .step_by(LANES)
                .flat_map(|start| self.run_block(block(start)))
                .collect());
        }
        // Each thread takes the next block of members from a shared counter (members differ
        // in cost: an event or a failure ends one early), and keeps its results; they are put
        // in order at the end.
        let next = AtomicUsize::new(range.start);
        let mut members: Vec<Member> = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..threads)
                .map(|_| {
                    scope.spawn(|| {
                        let mut done = Vec::new();
                        loop {
                            let i = next.fetch_add(LANES, Ordering::Relaxed);
                            if i >= range.end {
                                break done;
                            }
                            done.extend(self.run_block(block(i)));
                        }
                    })
                })
                .collect();
            workers
                .into_iter()
                .flat_map(|w| w.join().expect("members catch their panics"))
                .collect()
        });
        members.sort_by_key(|m| m.index);
        Ok(members)
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
            && self.system.same_dynamics_as(&other.system)
    }

    fn sim(&self) -> &Simulation {
        self.simulation.as_ref().expect("not taken yet")
    }

    /// Run it on its own.
    fn run_alone(mut self: Box<Self>) -> Member {
        let mut simulation = self.take_simulation();
        let result = run(&mut simulation, self.options, &mut NullSink);
        self.finish(result)
    }

    /// Its member, from the result of its run.
    fn finish(self, result: Result<RunStats, RunFailure>) -> Member {
        match result {
            Ok(stats) => Member {
                index: self.index,
                params: self.params,
                stats: Some(stats),
                error: None,
            },
            Err(failure) => Member {
                index: self.index,
                params: self.params,
                stats: Some(*failure.stats),
                error: Some(failure.error.to_string()),
            },
        }
    }
}

impl Sweep {
    /// The CSV header: `member`, the parameters, `status,t_final,stop_time,steps,
    /// energy_error_max,constraint_error_max`, every particle's final position and velocity
    /// (`P.x`, ..., `P.vx`, ...), the final generalized coordinates and rates of a parametric
    /// run (`q.NAME`, `qdot.NAME`), then `error`.
    pub fn csv_header(&self) -> String {
        let system = &self.scene.system;
        let mut columns: Vec<String> = vec!["member".into()];
        columns.extend(self.axes.iter().map(|a| a.name.clone()));
        for c in [
            "status",
            "t_final",
            "stop_time",
            "steps",
            "energy_error_max",
            "constraint_error_max",
        ] {
            columns.push(c.into());
        }
        columns.extend((0..system.n_coords()).map(|k| system.coordinate_name(k)));
        columns.extend((0..system.n_coords()).map(|k| system.velocity_name(k)));
        if self.method == Method::Parametric {
            if let Some(map) = system.parametric() {
                columns.extend(map.coordinates().iter().map(|c| format!("q.{c}")));
                columns.extend(map.coordinates().iter().map(|c| format!("qdot.{c}")));
            }
        }
        columns.push("error".into());
        columns
            .iter()
            .map(|c| csv_field(c))
            .collect::<Vec<_>>()
            .join(",")
    }

    /// One CSV row of `member` (see [`Sweep::csv_header`]): numbers exact (shortest
    /// round-trip), empty where the member has no value.
    pub fn csv_row(&self, member: &Member) -> String {
        use std::fmt::Write;
        let mut row = String::new();
        let _ = write!(row, "{}", member.index);
        for value in &member.params {
            let _ = write!(row, ",{value}");
        }
        let _ = write!(row, ",{}", member.status());
        let system = &self.scene.system;
        let n_q = match (self.method, system.parametric()) {
            (Method::Parametric, Some(map)) => map.coordinates().len(),
            _ => 0,
        };
        match &member.stats {
            Some(stats) => {
                let _ = write!(row, ",{}", stats.t_final);
                match stats.stop_time {
                    Some(t) => {
                        let _ = write!(row, ",{t}");
                    }
                    None => row.push(','),
                }
                let _ = write!(
                    row,
                    ",{},{},{}",
                    stats.steps,
                    stats.conserved_energy_error_max(),
                    stats.constraint_error_max
                );
                for value in stats.x.iter().chain(&stats.xdot) {
                    let _ = write!(row, ",{value}");
                }
                if n_q > 0 {
                    for value in stats.q.iter().chain(&stats.qdot) {
                        let _ = write!(row, ",{value}");
                    }
                }
            }
            None => {
                let empty = 5 + 2 * system.n_coords() + 2 * n_q;
                row.push_str(&",".repeat(empty));
            }
        }
        row.push(',');
        if let Some(error) = &member.error {
            row.push_str(&csv_field(error));
        }
        row
    }

    /// The header and one row per member, each line ending in a newline.
    pub fn write_csv(
        &self,
        members: &[Member],
        out: &mut dyn std::io::Write,
    ) -> std::io::Result<()> {
        writeln!(out, "{}", self.csv_header())?;
        for member in members {
            writeln!(out, "{}", self.csv_row(member))?;
        }
        Ok(())
    }
}

/// A CSV field, quoted (with quotes doubled) when it holds a comma, a quote or a line break.
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}
