//! Scene files (TOML) to a compiled [`System`] plus run defaults, with every error located by
//! file, line and column (and, inside expressions, a caret under the offending text).
//!
//! # Format
//!
//! ```toml
//! title = "Bead on a parabola"
//! [params]                  # optional named numbers, usable in expressions (`--set g=9.81`)
//! g = 500.0
//! [world]
//! gravity = [0.0, "g"]      # an acceleration; its length (2 or 3) sets the dimension
//! [[particle]]
//! name = "bead"
//! mass = 1.0
//! position = [150.0, -225.0]
//! velocity = [0.0, 0.0]     # optional, default 0
//! [[force]]                 # optional: constant, spring or drag
//! kind = "constant"
//! particle = "bead"
//! vector = [300.0, 0.0]
//! [[constraint]]            # implicit form: expr == 0
//! expr = "bead.x^2 + 100*bead.y"
//! [parametric]              # optional parametric form of the same system
//! coordinates = ["q"]
//! initial = [150.0]
//! rates = [0.0]             # optional, default 0
//! [parametric.positions]
//! bead = ["q", "-q^2/100"]
//! [run]                     # optional defaults; command-line flags override them
//! method = "implicit"
//! integrator = "rk4"
//! dt = 0.016666666666666666
//! duration = 10.0
//! ```
//!
//! - Any number may be a TOML number or a string expression of parameters, `pi` and `e`
//!   (`"2*L"`, `"sqrt(g/L)"`). A parameter may use the parameters before it in the file.
//! - `[[force]]`: `kind = "constant"` (`particle`, `vector`); `"spring"` (`between = ["a", "b"]`
//!   or `particle` and `anchor`; `stiffness`; `rest_length`, default 0); `"drag"`
//!   (`coefficient`; `particle`, default all particles).
//! - `[[constraint]]`: optional `name` (default `constraint N`, `constraint N (i = 3)` in a
//!   generated table; unique). `kind = "expression"`
//!   (the default) has `expr`, an expression of particle coordinates `NAME.x|y|z`, `t` and
//!   parameters; `"distance"` has `between` or `particle` and `anchor`, and `length` (default the
//!   initial distance); `"pin"` has `particle` and `anchor` (default its initial position).
//! - `[parametric.positions]` gives every particle's position as expressions of the
//!   coordinates, `t` and parameters.
//! - `[run]`: `method` (implicit, parametric), `integrator` (any of
//!   [`crate::integrate::IntegratorKind::ALL`] by name: euler, symplectic-euler, midpoint, rk4,
//!   verlet, rattle, gauss-legendre, dopri5, fast-projection), `dt`, `duration` or `steps`,
//!   and `stabilize = [ks, kd]` or `stabilize = { frequency = f, damping = zeta }` (damping
//!   default 1), and
//!   `stop_when = "EXPR"`: end the run where EXPR, an expression of the particles'
//!   coordinates and velocities (`bead.y`, `bead.vx`), the generalized coordinates (`q` or
//!   `q.q`, rates `qdot.q`), `t` and parameters, crosses zero upward
//!   ([`crate::simulate::Event`]), and `event_samples = K`, the interior times per step at
//!   which it is sampled.
//! - `[[event]]`: `expr`, an expression as `stop_when`'s, `direction` (1: upward crossings,
//!   -1: downward, 0: either, the default) and `terminal` (true: the first crossing ends
//!   the run; false, the default: crossings are recorded, `bead run --json` lists their
//!   times). `stop_when` is one more terminal upward event, after them.
//! - `for = { i = "START..STOP", j = ... }` on a `[[particle]]`, `[[constraint]]` or
//!   `[[force]]` table repeats it for i = START, ..., STOP - 1 (the first variable outermost,
//!   as written; bounds are integer expressions of the parameters and the earlier loop
//!   variables). The loop variables may be used in every expression of the table, and
//!   `{EXPR}` in its strings (names, particle references, `expr`) is replaced by EXPR's value,
//!   a whole number >= 0: `name = "p{i}"`, `between = ["p{i-1}", "p{i}"]`. `{...}` works in
//!   tables without `for` too, with the parameters. The `for` keys of a scene make at most
//!   [`MAX_REPETITIONS`] repetitions in all, and expand to at most [`MAX_EXPANDED_BYTES`] of
//!   text; one `for` has at most [`MAX_LOOP_VARIABLES`]. Expansion is the loader's (`template.rs`), before
//!   the [`crate::model::SystemBuilder`]: the system has one particle or constraint per
//!   repetition and no loops; [`Scene::generated`] tells which table made what.
//! - Unknown keys, wrong types, missing keys, non-finite numbers (`nan`, `inf`) and values out of
//!   range are errors located in the file. So are control characters (escape sequences, line
//!   breaks, tabs) in `title` and constraint names: they are labels, shown on terminals and in
//!   reports. Error snippets show control characters escaped (`\x1b`).

mod file;
mod load;
mod location;
mod rebind;
mod template;

pub(crate) use rebind::Rebinder;

pub use crate::model::EditError;

use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use crate::formulation::{Feedback, Method};
use crate::integrate::IntegratorKind;
use crate::model::System;
use crate::simulate::{Event, EventSpec, PlacedState, SetStateError, StateRequest};

/// Relative tolerance of the consistency checks of [`Scene::warnings`].
const WARN_TOLERANCE: f64 = 1e-9;

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// `title`, or the file stem when the file has none.
    pub title: String,
    /// `about`: a sentence or two on what the scene shows (a front end shows it under the
    /// title).
    pub about: Option<String>,
    /// `[world] units`: `"SI"` (metres, kilograms, seconds: energies in J), or the length
    /// unit the scene's numbers are in (`"px"`: energies in kg px^2/s^2); `None` when the
    /// scene does not say (front ends then print no unit).
    pub units: Option<String>,
    /// The file name as given (for messages and summaries).
    pub file: String,
    /// The compiled system: particles, forces, implicit constraints, parametric form.
    pub system: Arc<System>,
    /// Parameter values after overrides, in file order.
    pub params: Vec<(String, f64)>,
    /// What the file says about each parameter besides its value, in file order (see
    /// [`ParamSpec`]).
    pub param_specs: Vec<ParamSpec>,
    /// The `[run]` table.
    pub run: RunDefaults,
    /// The tables with a `for` key, in file order within each kind.
    generated: Vec<Generated>,
    /// The text it was loaded from.
    text: Arc<str>,
    /// The parameter overrides it was loaded with.
    overrides: Vec<(String, f64)>,
    /// Constraint expressions replaced since (declared index, new expression), in order.
    edits: Vec<(usize, String)>,
    /// The start set since ([`Scene::with_state`]), placed again after every change.
    start: Option<StateRequest>,
    /// Where in the text each particle and constraint is given, for [`Scene::located_warnings`].
    lines: Lines,
}

/// What a scene file says about one of its `[params]` besides its value: what a slider, a
/// number box or a table of parameters shows. A parameter is written as a number, an
/// expression of pi, e and the parameters before it, or a table:
///
/// ```toml
/// [params]
/// g = { value = 9.81, unit = "m/s^2", range = [0, 30] }   # gravitational acceleration
/// N = { value = 20, integer = true }                       # links
/// L = "1/N"                                                # derived: rod length
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSpec {
    pub name: String,
    /// The expression it is written as (`"pi/3"`, `"S/(W-1)"`), if it is one.
    pub expr: Option<String>,
    /// The parameters its expression names: it is derived from them (a front end shows it,
    /// and changes them instead).
    pub depends_on: Vec<String>,
    /// `range = [lo, hi]` (numbers, pi and e): the values a front end offers. Not enforced
    /// by the library (`--set` may go beyond).
    pub range: Option<[f64; 2]>,
    /// `unit = "..."`.
    pub unit: Option<String>,
    /// `description = "..."`, else the comment after the parameter on its line.
    pub description: Option<String>,
    /// A whole number: `integer = true` (checked on load and on `--set`), or named by a
    /// `for` range (directly or through parameters derived from it).
    pub integer: bool,
}

/// The lines of the scene text that [`Scene::located_warnings`] points at (1-based).
#[derive(Clone, Debug, Default)]
struct Lines {
    /// Per particle, the line of its `position`.
    position: Vec<usize>,
    /// Per particle, the line of its `velocity` (of its `position` when it has none).
    velocity: Vec<usize>,
    /// Per declared constraint, the line of its `expr` (of its table's header for the other
    /// kinds).
    constraint: Vec<usize>,
}

/// A warning about a scene that does not stop a run (see [`Scene::warnings`]), with the line
/// of the scene text it is about.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneWarning {
    /// 1-based line of the key concerned (a particle's `position` or `velocity`, a
    /// constraint's `expr`), when known.
    pub line: Option<usize>,
    /// What is wrong, as [`Scene::warnings`] says it.
    pub message: String,
}

/// The most repetitions the `for` keys of one scene may make in all (particles, constraints
/// and forces together): ten times the largest scenes the solvers are meant for, few enough
/// that a typo (`0..1e9`, a grid of `0..N` by `0..N` meant as `0..N` by `0..3`) is an error
/// at once instead of minutes of loading and gigabytes of memory (a chain of 10^5 links takes
/// about 10 s and 1 GB to load).
pub const MAX_REPETITIONS: usize = 100_000;

/// The most text the generated tables of a scene may expand to, in bytes (16 MiB): the
/// strings of a table with `for` (names, references, expressions), summed over its
/// repetitions and over the tables. A table is refused before it is read when its strings as
/// written times its repetitions would pass the limit (with the tables before it), and while
/// it is read when its `{...}` expansions do. A scene holds its names and expressions several
/// times over, about 7 bytes per byte expanded: a scene at the limit loads in 0.3 s and
/// 115 MB (measured), where a 60 kB template repeated 4000 times took 79 s and 1.9 GB. The
/// shipped chain at its largest (N = 5 x 10^4, as many repetitions as a scene may make)
/// expands to 2.1 MB.
pub const MAX_EXPANDED_BYTES: usize = 16 << 20;

/// The most loop variables one `for` may have: a grid takes two or three, and the loader
/// nests one level per variable.
pub const MAX_LOOP_VARIABLES: usize = 8;

/// The kind of a table that a `for` key can repeat.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TableKind {
    /// `[[particle]]`
    Particle,
    /// `[[constraint]]`
    Constraint,
    /// `[[force]]`
    Force,
}

impl TableKind {
    /// `particle`, `constraint`, `force`: the table's name, as messages say it.
    pub fn name(self) -> &'static str {
        match self {
            TableKind::Particle => "particle",
            TableKind::Constraint => "constraint",
            TableKind::Force => "force",
        }
    }
}

/// A `[[particle]]`, `[[constraint]]` or `[[force]]` table with a `for` key, and what its
/// repetitions made (so that a description can summarize them instead of listing 10^4).
#[derive(Clone, Debug, PartialEq)]
pub struct Generated {
    /// What the table declares.
    pub kind: TableKind,
    /// Its number among the tables of its kind, 1-based, as messages count them
    /// (`constraint 2 (i = 3)` is a repetition of the second `[[constraint]]` table).
    pub table: usize,
    /// The line of its header in the file.
    pub line: usize,
    /// Its loop variables and ranges as written: `i = 0..N, j = 0..H`.
    pub ranges: String,
    /// What it made, in order: indices into [`System::particles`], into the declared
    /// constraints ([`crate::model::ConstraintSet::infos`]), or into [`System::forces`].
    /// Empty when its ranges are.
    pub items: Range<usize>,
}

/// Why [`Scene::with_param`] failed: the edit itself, or the scene's text with the new value
/// (e.g. a mass written as an expression of the parameter becomes negative).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SceneEditError {
    #[error(transparent)]
    Edit(#[from] EditError),
    #[error(transparent)]
    Load(#[from] SceneError),
    /// The start set with [`Scene::with_state`] cannot be placed on the changed scene.
    #[error("the start set on the scene: {0}")]
    Start(#[from] SetStateError),
}

/// `[run]` defaults; every field may be overridden on the command line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunDefaults {
    /// `method = "implicit" | "parametric"`.
    pub method: Option<Method>,
    /// `integrator = "euler" | "symplectic-euler" | "midpoint" | "rk4" | ...` (every
    /// [`IntegratorKind`] by name).
    pub integrator: Option<IntegratorKind>,
    /// `dt`: step size, > 0.
    pub dt: Option<f64>,
    /// `duration`: simulated time, > 0 (not together with `steps`).
    pub duration: Option<f64>,
    /// `steps`: number of steps, a positive integer (not together with `duration`).
    pub steps: Option<u64>,
    /// `stabilize = [ks, kd]` or `{ frequency = f, damping = zeta }` (implicit method only).
    pub stabilize: Option<Feedback>,
    /// `stop_when = "EXPR"`: stop the run where EXPR crosses zero upward (see
    /// [`crate::simulate::Event`]).
    pub stop_when: Option<Event>,
    /// The `[[event]]` tables, in file order: `expr = "EXPR"`, `direction = 1 | -1 | 0`
    /// (default 0: either crossing), `terminal = true | false` (default false: recorded
    /// only).
    pub events: Vec<EventSpec>,
    /// `event_samples = K`: interior times per step at which the stop condition is sampled
    /// (see [`crate::simulate::SimulationConfig::event_samples`]), 0 to
    /// [`crate::simulate::MAX_EVENT_SAMPLES`].
    pub event_samples: Option<u32>,
}

impl RunDefaults {
    /// The events a run of the scene watches: its `[[event]]` tables, then `stop_when` (the
    /// scene's, or one that overrides it) as a terminal upward event.
    pub fn events_with(&self, stop_when: Option<Event>) -> Vec<EventSpec> {
        let mut events = self.events.clone();
        events.extend(stop_when.map(EventSpec::stop));
        events
    }
}

/// A scene that cannot be loaded: what and where.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}", self.render())]
pub struct SceneError {
    /// The file name as given.
    pub file: String,
    /// 1-based; 0 when the error has no position (e.g. the file cannot be read).
    pub line: usize,
    /// 1-based, in characters.
    pub column: usize,
    /// What is wrong, on one line, prefixed by where in the scene (e.g. `particle 2: `).
    pub message: String,
    /// Source line(s) with a caret under the offending text, when known.
    pub snippet: Option<String>,
}

impl SceneError {
    /// `file:line:column: message` followed by the snippet, each of its lines indented by two
    /// spaces; `file: message` when the error has no position. No trailing newline.
    pub fn render(&self) -> String {
        let mut out = if self.line == 0 {
            format!("{}: {}", self.file, self.message)
        } else {
            format!(
                "{}:{}:{}: {}",
                self.file, self.line, self.column, self.message
            )
        };
        if let Some(snippet) = &self.snippet {
            for line in snippet.lines() {
                out.push('\n');
                out.push_str(format!("  {line}").trim_end());
            }
        }
        out
    }
}

/// The largest scene file [`Scene::load`] reads: 16 MiB (the shipped scenes are a few
/// kilobytes).
pub const MAX_SCENE_BYTES: u64 = 16 << 20;

impl Scene {
    /// Read and load a scene file; `overrides` replace `[params]` values (`--set NAME=VALUE`;
    /// an unknown name is an error).
    pub fn load(path: &Path, overrides: &[(String, f64)]) -> Result<Scene, SceneError> {
        use std::io::Read;
        let file = path.display().to_string();
        let error = |message: String| SceneError {
            file: file.clone(),
            line: 0,
            column: 0,
            message,
            snippet: None,
        };
        // Read at most one byte past the limit, so that a device or a pipe that never ends
        // (`/dev/zero`) is refused rather than read forever.
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_SCENE_BYTES + 1).read_to_end(&mut bytes))
            .map_err(|e| error(format!("cannot read the scene file: {e}")))?;
        if bytes.len() as u64 > MAX_SCENE_BYTES {
            return Err(error(format!(
                "the scene file is larger than {} MiB (a scene is a few kilobytes; tables with `for` make many items from one line)",
                MAX_SCENE_BYTES >> 20
            )));
        }
        let text = String::from_utf8(bytes).map_err(|_| {
            error("cannot read the scene file: stream did not contain valid UTF-8".into())
        })?;
        Scene::parse(&text, &file, overrides)
    }

    /// Load a scene from text; `file` names it in messages.
    pub fn parse(text: &str, file: &str, overrides: &[(String, f64)]) -> Result<Scene, SceneError> {
        load::load(text, file, overrides, None)
    }

    /// The tables with a `for` key and what each made, in file order within each kind
    /// (empty when no table has one).
    pub fn generated(&self) -> &[Generated] {
        &self.generated
    }

    /// The text the scene was loaded from (without later edits).
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The parameter overrides it was loaded with (`--set`, [`Scene::with_param`]).
    pub fn overrides(&self) -> &[(String, f64)] {
        &self.overrides
    }

    /// The constraint expressions replaced since loading ([`Scene::with_constraint_expr`]):
    /// (declared index, expression), latest edit of each constraint, in the order made.
    pub fn constraint_edits(&self) -> &[(usize, String)] {
        &self.edits
    }

    /// The scene with constraint `index` (0-based, the order of its `[[constraint]]` tables,
    /// each repetition of a table with `for` counted)
    /// replaced by `source = 0`: see [`System::with_constraint_expr`]. Errors in the new
    /// expression carry byte spans into `source`.
    ///
    /// ```
    /// use bead::model::EditError;
    /// use bead::scene::Scene;
    /// let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/parabola.toml"))?;
    /// let scene = Scene::parse(&text, "parabola.toml", &[])?;
    /// let flatter = scene.with_constraint_expr(0, "bead.x^2 + 200*bead.y")?;
    /// assert_eq!(flatter.system.declared_constraints()[0].source(), Some("bead.x^2 + 200*bead.y"));
    /// let error = scene.with_constraint_expr(0, "bead.x^2 + 200*bead.w").unwrap_err();
    /// assert!(matches!(error, EditError::Expression { span, .. } if span == (15..21)));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn with_constraint_expr(&self, index: usize, source: &str) -> Result<Scene, EditError> {
        let system = self.system.with_constraint_expr(index, source)?;
        let mut scene = self.clone();
        scene.system = Arc::new(system);
        scene.edits.retain(|(i, _)| *i != index);
        scene.edits.push((index, source.to_string()));
        Ok(scene)
    }

    /// The scene loaded again from its text with parameter `name` set to `value`, so that
    /// every number written as an expression of it (masses, positions, lengths, forces, the
    /// expressions of constraints and of the parametric form) follows; the constraint edits
    /// made before are applied again, parsed with the new value.
    pub fn with_param(&self, name: &str, value: f64) -> Result<Scene, SceneEditError> {
        self.with_params(&[(name.to_string(), value)])
    }

    /// [`Scene::with_param`] for several parameters at once (one load): each name must be a
    /// parameter of the scene and each value finite. The result is the scene as
    /// `Scene::parse(text, file, overrides)` loads it with these overrides after the ones it
    /// was loaded with, so a run of it equals `bead run --set NAME=VALUE ...` bit for bit.
    pub fn with_params(&self, values: &[(String, f64)]) -> Result<Scene, SceneEditError> {
        for (name, value) in values {
            self.check_param(name, *value)?;
        }
        let mut overrides = self.overrides.clone();
        overrides.retain(|(n, _)| !values.iter().any(|(name, _)| name == n));
        overrides.extend(values.iter().cloned());
        // The equations are compiled again only when the values change them.
        let mut scene = load::load(&self.text, &self.file, &overrides, Some(&self.system))?;
        for (index, source) in &self.edits {
            scene = scene.with_constraint_expr(*index, source)?;
        }
        if let Some(start) = &self.start {
            scene = scene.with_state(start)?.0;
        }
        Ok(scene)
    }

    /// The scene with the TOML tables `tables` added after its text (e.g. a `[[force]]`
    /// table: `bead.Scene.with_force` in Python), loaded again as
    /// [`Scene::with_params`] loads it, with its overrides, constraint edits and start. An
    /// error in the added text is located in the text with it (the lines after the file's).
    pub fn with_tables(&self, tables: &str) -> Result<Scene, SceneEditError> {
        let mut text = self.text.to_string();
        if !text.ends_with('\n') {
            text.push('\n');
        }
        text.push_str(tables);
        let mut scene = load::load(&text, &self.file, &self.overrides, Some(&self.system))?;
        for (index, source) in &self.edits {
            scene = scene.with_constraint_expr(*index, source)?;
        }
        if let Some(start) = &self.start {
            scene = scene.with_state(start)?.0;
        }
        Ok(scene)
    }

    /// The scene started from `request` (its `t` must be absent or 0: a scene starts at
    /// t = 0), placed on the constraints as [`crate::simulate::Simulation::set_state`]
    /// places it, the same start for both forms: the particles' positions and velocities
    /// and the parametric form's initial q and qdot are replaced (parts not asked for keep
    /// the scene's values; see `simulate/state.rs`). With where the start was put and how far
    /// that is from what was asked for. The start is kept through
    /// [`Scene::with_params`] (placed again on the changed scene); the text stays the
    /// file's.
    ///
    /// ```
    /// # use bead::scene::Scene;
    /// # use bead::simulate::StateRequest;
    /// let scene = Scene::load("../../scenes/parabola.toml".as_ref(), &[]).unwrap();
    /// let request = StateRequest { positions: Some(vec![100.0, -100.0]), ..Default::default() };
    /// let (moved, placed) = scene.with_state(&request).unwrap();
    /// assert_eq!(moved.system.initial_particle_state().0, vec![100.0, -100.0]);
    /// let (q, _) = placed.parametric.unwrap();
    /// assert!((q[0] - 100.0).abs() < 1e-9);
    /// ```
    pub fn with_state(
        &self,
        request: &StateRequest,
    ) -> Result<(Scene, PlacedState), SetStateError> {
        if let Some(t) = request.t.filter(|&t| t != 0.0) {
            return Err(SetStateError::StartTime(t));
        }
        let system = &self.system;
        let (x, v) = system.initial_particle_state();
        let parametric = system.parametric().map(|m| (m.initial(), m.rates()));
        let current = crate::simulate::Current {
            t: 0.0,
            x: &x,
            v: &v,
            parametric,
        };
        let placed = crate::simulate::place_start(system, current, request)?;
        let moved = system.with_initial_state(
            &placed.positions,
            &placed.velocities,
            placed.parametric.clone(),
        );
        let mut scene = self.clone();
        scene.system = Arc::new(moved);
        scene.start = Some(request.clone());
        Ok((scene, placed))
    }

    /// The start set with [`Scene::with_state`], if any (as asked for).
    pub fn start(&self) -> Option<&StateRequest> {
        self.start.as_ref()
    }

    /// Whether `name` is a parameter of the scene and `value` finite.
    fn check_param(&self, name: &str, value: f64) -> Result<(), SceneEditError> {
        if !value.is_finite() {
            return Err(EditError::Model(crate::model::ModelError::NotFinite {
                what: format!("parameter `{name}`"),
                value,
            })
            .into());
        }
        if !self.params.iter().any(|(n, _)| n == name) {
            return Err(EditError::UnknownParam {
                name: name.to_string(),
                known: self.params.iter().map(|(n, _)| n.clone()).collect(),
            }
            .into());
        }
        Ok(())
    }

    /// Warnings about the scene that do not stop a run:
    ///
    /// - the parametric form's x(q0) or xdot(q0, qdot0) differs from a particle's `position` or
    ///   `velocity` by more than 1e-9 of the scene's scale (max |position component|, or 1; for
    ///   velocities the larger of that and the largest speed component);
    /// - the initial positions are off an implicit constraint by more than 1e-9 of the length
    ///   scale, measured as |C| / |grad C| (the distance to the constraint surface to first
    ///   order), or the initial velocities are not tangent to it (|Cdot| / |grad C|);
    /// - a value, gradient or rate of either form is not finite at the initial state (said in
    ///   words: a run refuses to start from it).
    ///
    /// Positions are printed exactly ([`crate::readable`]); measured values (C, Cdot,
    /// distances) signed with 6 significant digits ([`crate::significant`]), as `bead check`
    /// prints them.
    pub fn warnings(&self) -> Vec<String> {
        self.located_warnings()
            .into_iter()
            .map(|w| w.message)
            .collect()
    }

    /// [`Scene::warnings`], each with the line of the scene text it is about: a particle's
    /// `position` (its `velocity` for a velocity), a constraint's `expr`.
    pub fn located_warnings(&self) -> Vec<SceneWarning> {
        let lines = &self.lines;
        let at = |lines: &[usize], i: usize, message: String| SceneWarning {
            line: lines.get(i).copied(),
            message,
        };
        let system = &self.system;
        let dim = system.dim();
        let (x0, v0) = system.initial_particle_state();
        let max_abs = |v: &[f64]| v.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
        let length_scale = max_abs(&x0).max(1.0);
        let mut warnings = Vec::new();

        // A start off a unilateral constraint (in flight): the parametric form starts from
        // the particles' own state, not from x(q0).
        let in_flight = !system.unilateral().is_empty() && {
            let set = system.constraints();
            let mut ws = set.workspace();
            set.gradient(0.0, &x0, &mut ws);
            system.unilateral().iter().any(|u| {
                let norm = ws.jacobian[set.row_entries(u.row)]
                    .iter()
                    .map(|g| g * g)
                    .sum::<f64>()
                    .sqrt();
                let c = ws.value[u.row];
                u.side.sign() * c > 0.0 && c.abs() > WARN_TOLERANCE * length_scale * norm
            })
        };
        if let Some(map) = system.parametric().filter(|_| !in_flight) {
            let mut ws = map.workspace();
            map.evaluate(0.0, map.initial(), map.rates(), &mut ws);
            let speed_scale = length_scale.max(max_abs(&v0)).max(max_abs(&ws.velocity));
            for (p, particle) in system.particles().iter().enumerate() {
                let range = p * dim..(p + 1) * dim;
                for (what, given, computed, key, scale, line) in [
                    (
                        "position",
                        &x0[range.clone()],
                        &ws.position[range.clone()],
                        "x(q0)",
                        length_scale,
                        &lines.position,
                    ),
                    (
                        "velocity",
                        &v0[range.clone()],
                        &ws.velocity[range.clone()],
                        "xdot(q0, qdot0)",
                        speed_scale,
                        &lines.velocity,
                    ),
                ] {
                    let name = &particle.name;
                    if computed.iter().any(|c| !c.is_finite()) {
                        warnings.push(at(line, p, format!(
                            "particle `{name}`: the parametric form's initial {what} {key} = {} is not finite",
                            fmt_vec(computed)
                        )));
                        continue;
                    }
                    let difference = distance(given, computed);
                    if exceeds(difference, WARN_TOLERANCE * scale) {
                        let by = if difference.is_finite() {
                            format!("by {}", crate::significant(difference, 6))
                        } else {
                            "by more than the largest representable number".to_string()
                        };
                        warnings.push(at(line, p, format!(
                            "particle `{name}`: the parametric form's initial {what} {key} = {} differs from the scene's {what} {} {by}",
                            fmt_vec(computed),
                            fmt_vec(given),
                        )));
                    }
                }
            }
        }

        let constraints = system.constraints();
        if constraints.n_rows() > 0 {
            let mut ws = constraints.workspace();
            constraints.evaluate(0.0, &x0, &v0, &mut ws);
            let speed_scale = length_scale.max(max_abs(&v0));
            for (i, info) in constraints.infos().enumerate() {
                let warn = |message| at(&lines.constraint, i, message);
                let rows = info.rows.clone();
                let name = format!("{} (`{}`)", info.name, info.description);
                // The row with the largest |value| (and |rate|), with its sign.
                let worst = |values: &[f64]| {
                    values[rows.clone()].iter().copied().fold(0.0_f64, |w, v| {
                        if w.is_nan() || v.abs() <= w.abs() {
                            w
                        } else {
                            v
                        }
                    })
                };
                let (c, cdot) = (worst(&ws.value), worst(&ws.velocity));
                // A unilateral constraint may start anywhere on its allowed side (in flight).
                let unilateral = system.unilateral().iter().find(|u| rows.contains(&u.row));
                if unilateral.is_some_and(|u| u.side.sign() * c > 0.0) {
                    continue;
                }
                if !c.is_finite() {
                    warnings.push(warn(format!(
                        "{name}: its value at the initial positions is not finite ({})",
                        crate::readable(c)
                    )));
                    continue;
                }
                let (mut off, mut drift) = (0.0_f64, 0.0_f64);
                let mut gradient_finite = true;
                for row in rows.clone() {
                    let gradient = ws.jacobian[constraints.row_entries(row)]
                        .iter()
                        .map(|g| g * g)
                        .sum::<f64>()
                        .sqrt();
                    gradient_finite &= gradient.is_finite();
                    let norm = if gradient > 0.0 { gradient } else { 1.0 };
                    off = crate::linalg::max_nan(off, ws.value[row].abs() / norm);
                    drift = crate::linalg::max_nan(drift, ws.velocity[row].abs() / norm);
                }
                if !gradient_finite {
                    warnings.push(warn(format!(
                        "{name}: its gradient at the initial positions is not finite"
                    )));
                } else if exceeds(off, WARN_TOLERANCE * length_scale) {
                    let how_far = if off.is_finite() {
                        format!("about {} off the constraint", crate::significant(off, 6))
                    } else {
                        "its gradient is too small there to tell how far".to_string()
                    };
                    warnings.push(warn(format!(
                        "{name}: the initial positions violate it: C = {} ({how_far})",
                        crate::significant(c, 6)
                    )));
                } else if !cdot.is_finite() {
                    warnings.push(warn(format!(
                        "{name}: its rate Cdot at the initial state is not finite ({})",
                        crate::readable(cdot)
                    )));
                } else if exceeds(drift, WARN_TOLERANCE * speed_scale) {
                    warnings.push(warn(format!(
                        "{name}: the initial velocities are not tangent to it: Cdot = {}",
                        crate::significant(cdot, 6)
                    )));
                }
            }
        }
        warnings
    }
}

/// `value > limit`, or NaN.
fn exceeds(value: f64, limit: f64) -> bool {
    value.is_nan() || value > limit
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// `[a, b]`, each exactly and never 300 digits long ([`crate::readable`]).
fn fmt_vec(v: &[f64]) -> String {
    format!(
        "[{}]",
        v.iter()
            .map(|c| crate::readable(*c))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::DeclaredConstraint;

    /// `with_params` reuses the compiled equations exactly when the values leave them
    /// unchanged: a release point does, gravity does not, and neither does a constant that
    /// differs only in its sign bit (0 and -0 round differently downstream).
    #[test]
    fn with_params_recompiles_only_when_the_equations_change() {
        let text = r#"
[params]
x0 = 150.0
g = 500.0
k = 0.0
c = 100.0
[world]
gravity = ["k", "g"]
[[particle]]
name = "bead"
mass = 1.0
position = ["x0", "-x0^2/100"]
[[constraint]]
expr = "bead.x^2 + c*bead.y"
[parametric]
coordinates = ["q"]
initial = ["x0"]
[parametric.positions]
bead = ["q", "-q^2/100"]
"#;
        let scene = Scene::parse(text, "p.toml", &[]).unwrap();
        let declared = |s: &Scene| Arc::clone(&s.system.declared);
        let same = |values: &[(&str, f64)]| {
            let values: Vec<(String, f64)> =
                values.iter().map(|(n, v)| (n.to_string(), *v)).collect();
            let other = scene.with_params(&values).unwrap();
            declared(&other).same_dynamics(&scene.system.declared)
        };
        assert!(same(&[("x0", 10.0)]));
        assert!(same(&[("x0", -3.5), ("k", 0.0)]));
        assert!(!same(&[("g", 9.81)]));
        assert!(!same(&[("k", 1e-300)]));
        assert!(!same(&[("k", -0.0)]));
        // A constant inside a constraint's expression.
        assert!(!same(&[("c", 101.0)]));
        // The reused system starts where the new values say, in both forms.
        let moved = scene.with_params(&[("x0".to_string(), 10.0)]).unwrap();
        assert_eq!(moved.system.particles()[0].position, vec![10.0, -1.0]);
        assert_eq!(
            moved.system.parametric.as_ref().unwrap().initial,
            vec![10.0]
        );
        assert_eq!(moved.params[0], ("x0".to_string(), 10.0));
    }

    /// Two pendulum bobs: the first on a circle of radius L (an expression), the second on a
    /// rod of length L from it; masses and positions are expressions of L too.
    const TWO_BOBS: &str = r#"
title = "two bobs"
[params]
L = 2.0
m = "L/2"
[world]
gravity = [0.0, 9.81]
[[particle]]
name = "a"
mass = "m"
position = ["L", 0.0]
[[particle]]
name = "b"
mass = 1.0
position = ["2*L", 0.0]
[[constraint]]
expr = "a.x^2 + a.y^2 - L^2"
[[constraint]]
kind = "distance"
between = ["a", "b"]
length = "L"
[parametric]
coordinates = ["p", "q"]
initial = [0.0, 0.0]
[parametric.positions]
a = ["L*cos(p)", "L*sin(p)"]
b = ["L*cos(p) + L*cos(q)", "L*sin(p) + L*sin(q)"]
"#;

    fn scene() -> Scene {
        Scene::parse(TWO_BOBS, "two.toml", &[]).unwrap()
    }

    fn circle_residual(scene: &Scene, x: &[f64]) -> f64 {
        let set = scene.system.constraints();
        let mut ws = set.workspace();
        set.residuals(0.0, x, &mut ws)[0]
    }

    #[test]
    fn a_constraint_edit_changes_that_expression_only() {
        let scene = scene();
        let edited = scene
            .with_constraint_expr(0, "a.x^2 + 4*a.y^2 - L^2")
            .unwrap();
        assert_eq!(
            edited.constraint_edits(),
            &[(0, "a.x^2 + 4*a.y^2 - L^2".to_string())]
        );
        assert_eq!(circle_residual(&edited, &[0.0, 1.0, 0.0, 0.0]), 0.0);
        assert_eq!(
            edited.system.declared_constraints()[1],
            scene.system.declared_constraints()[1]
        );
        assert!(scene.constraint_edits().is_empty());
        // The error points at the offending token of the new expression.
        let source = "a.x^2 + 4*a.w - L^2";
        let Err(EditError::Expression { span, message, .. }) =
            scene.with_constraint_expr(0, source)
        else {
            panic!("no expression error")
        };
        assert_eq!(&source[span], "a.w");
        assert_eq!(message, "`a` has no coordinate `w`; in 2D use x, y");
        assert!(matches!(
            scene.with_constraint_expr(1, "a.x"),
            Err(EditError::NotAnExpression {
                kind: "distance",
                ..
            })
        ));
    }

    #[test]
    fn a_parameter_change_reloads_the_numbers_and_keeps_the_edits() {
        let scene = scene()
            .with_constraint_expr(0, "a.x^2 + 4*a.y^2 - L^2")
            .unwrap();
        let bigger = scene.with_param("L", 3.0).unwrap();
        let system = &bigger.system;
        // Numbers written as expressions of L follow it.
        assert_eq!(system.particles()[0].mass, 1.5);
        assert_eq!(system.particles()[0].position, vec![3.0, 0.0]);
        assert_eq!(system.particles()[1].position, vec![6.0, 0.0]);
        assert!(matches!(
            system.declared_constraints()[1],
            DeclaredConstraint::Distance { length, .. } if length == 3.0
        ));
        assert!(bigger.params.contains(&("m".to_string(), 1.5)));
        assert_eq!(bigger.overrides(), &[("L".to_string(), 3.0)]);
        // The earlier edit is applied again with the new L.
        assert_eq!(circle_residual(&bigger, &[0.0, 1.5, 0.0, 0.0]), 0.0);
        let map = system.parametric().unwrap();
        let mut ws = map.workspace();
        map.state_at(0.0, &[0.0, 0.0], &[0.0, 0.0], &mut ws);
        assert_eq!(ws.position, vec![3.0, 0.0, 6.0, 0.0]);
        // Back again: the same as the original.
        let back = bigger.with_param("L", 2.0).unwrap();
        assert_eq!(back.system.particles(), scene.system.particles());

        assert!(matches!(
            scene.with_param("R", 1.0),
            Err(SceneEditError::Edit(EditError::UnknownParam { .. }))
        ));
        // A value that makes the scene invalid is the scene's located error.
        let Err(SceneEditError::Load(error)) = scene.with_param("L", -2.0) else {
            panic!("a negative mass was accepted")
        };
        assert!(error.message.contains("mass"), "{}", error.render());
        assert!(error.line > 0);
    }
}
