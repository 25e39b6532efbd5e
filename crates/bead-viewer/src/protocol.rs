//! The viewer's WebSocket protocol, version [`PROTOCOL_VERSION`].
//!
//! One WebSocket connection (`GET /ws`) is one session. Control messages are text frames,
//! each one JSON object with a `"type"` field naming the message; field names are
//! `snake_case`. The state of the panels, sent about 60 times a second, is one binary frame
//! per tick (see [Frames](#frames)). The client sends text only: binary frames, frames over
//! [`Limits::max_message_bytes`] and anything that is not a valid message get an
//! [`ServerMessage::Error`] reply; the connection stays open.
//!
//! Conversation:
//!
//! 1. On connect the server sends [`ServerMessage::Welcome`] (protocol version, shipped
//!    scenes, integrators, limits), then [`ServerMessage::Scene`] and
//!    [`ServerMessage::Panels`] for the initial scene with its default panels (one per
//!    formulation the scene defines: implicit first, then parametric). A loaded scene's
//!    panels start running; a panel added later runs when any other panel does.
//! 2. About 60 times a second the server sends a frame ([`ServerMessage::Frame`], binary)
//!    with the state of every panel (also while paused, so that a fresh page can draw at
//!    once).
//! 3. The client sends [`ClientMessage`]s; after any change of the panel set or of a panel's
//!    settings the server sends a new [`ServerMessage::Panels`]; after a scene change a new
//!    [`ServerMessage::Scene`] and [`ServerMessage::Panels`].
//!
//! Every panel has an `epoch` ([`PanelInfo::epoch`], [`PanelFrame::epoch`]) that changes
//! whenever the panel is rebuilt or restarted (`configure_panel`, `reset`, a curve edit, a
//! scene load). Frames already on their way still carry the old epoch: a client that waits
//! for the effect of a request waits for a frame of the new epoch, never for a value that a
//! frame from before the request could also show.
//!
//! Every rejected request gets an [`ServerMessage::Error`] with a stable, machine-readable
//! [`ErrorCode`] besides the human message; failed curve edits get
//! [`ServerMessage::CurveError`], also with a code.
//!
//! # Frames
//!
//! A frame is one binary WebSocket message: a small JSON header with everything but the
//! positions, then the positions of every panel packed as little-endian IEEE 754 doubles.
//!
//! | offset | size | contents |
//! |---|---|---|
//! | 0 | 4 | the magic bytes `b"bead"` ([`FRAME_MAGIC`]) |
//! | 4 | 4 | `h`: the header's length in bytes, u32 little-endian |
//! | 8 | `h` | the header: UTF-8 JSON, `{"type": "frame", "time_scale": .., "panels": [..]}` |
//! | 8 + `h` | 0-7 | zero bytes, so that the positions start at a multiple of 8 |
//! | `p` = 8 + `h` rounded up to a multiple of 8 | 8 `n` | `n` numbers, f64 little-endian |
//!
//! Each panel of the header is a [`PanelFrame`] without `x`, `path` and `curves`, plus where
//! they are in the block of numbers at `p` (counted in numbers, not bytes):
//! - `x_offset`, `x_count`: its positions (`dim` numbers per particle, particle by particle)
//!   are the numbers `x_offset .. x_offset + x_count`;
//! - `path_offset`, `path_count`: `path_count` samples of `1 + x_count` numbers each, `t`
//!   then the positions, of the states the simulation went through since the last frame
//!   (see [`PanelFrame::path`]);
//! - `curve_offset`, `curve_counts` (only when the panel's curves move, see
//!   [`PanelFrame::curves`]): the polylines one after the other, `curve_counts[i]` numbers
//!   for the i-th.
//!
//! `n` is the sum of all of these. In a browser: `JSON.parse` of the header, then
//! `new Float64Array(buffer, p, n)` (little-endian machines; the page reads through a
//! `DataView` elsewhere). [`decode_frame`] is the reference decoder. The frame is binary
//! because its size and cost grow with the particles: 16 bytes a particle in 2D against
//! about 37 for the same numbers in JSON (16 368 bytes against 36 997 for a frame of 1000
//! particles), and no number formatting or parsing (see DESIGN.md, Viewer, for the figures).
//!
//! # Versions
//!
//! Version 7 (this one) keeps the curves under the bead: a frame carries a panel's curves
//! also when they were made again (the bead neared the end of the drawn part of its map, or
//! the page asked with `set_view` for a region it shows), and the page keeps the last it
//! got; panels and frames say the region the curves cover (`curve_region`). Frames of small
//! scenes carry the velocities and forces for arrows ([`Arrows`]); parameters say their
//! unit, description, whether they are whole or derived, and `set_param` takes `expr`.
//! Within version 7 (a page that does not know them ignores them), a parametric panel names
//! its generalized coordinates ([`PanelInfo::coordinates`]) and its frames carry q and q'
//! ([`PanelFrame::generalized`]), for the live plot.
//!
//! Version 6 ends runs where the scene ends: the clock stops every panel at the
//! scene's `[run]` duration ([`Clock::end`]; `play` then starts again from the start), or
//! loops, or goes on, as `set_at_end` asks ([`AtEnd`]); frames' [`Clock`] carries `end`,
//! `at_end` and `ended`. Version 5 ran the panels until paused.
//!
//! Version 5 runs the panels on one clock: frames carry the session's
//! [`Clock`] (a `generation` that counts restarts, the simulation rate and the panel that
//! limits it) and each panel's `distance` to the first panel at the same t (overlay mode);
//! `add_panel`, `configure_panel` and `reset` restart every panel; new requests
//! `set_param`, `set_start` and `equations`; the scene lists its `params`, panels say which
//! settings apply to them (`applies`), and a new reply `equations`. Within version 5 (a
//! page that does not know it ignores it), `set_start` also replies `start_placed`: where
//! the drop was moved onto the curve.
//!
//! Version 4 adds to frames the path of the simulation's own steps
//! ([`PanelFrame::path`]), moving curves at the frame's t ([`PanelFrame::curves`]) and the
//! energy split (`kinetic`, `potential`, `energy_initial`, `energy_scale`); to panels their own
//! view box ([`PanelInfo::view`]), whether the curves move and a note on the curve; to the
//! scene its gravity. The points of 3D curves have three coordinates (version 3: x-y only).
//!
//! Version 3 sent frames as binary messages (above) instead of JSON text, and
//! adds the pins ([`SceneInfo::pins`]) to the scene. Version 2 added `epoch`, the error codes
//! and the energy ledger in frames (`energy_error`, which replaces version 1's
//! `energy_rel_error`, `energy_conserved`, `work`, `not_conserved_by`).
//!
//! Numbers must be finite JSON numbers. JSON has no NaN or infinity; a string such as
//! `"NaN"` is a wrong type, and an out-of-range literal like `1e999` is rejected. The server
//! sends non-finite values as 0 (positions included).
//!
//! Coordinates are the scene's own: `+y` points down in the shipped 2D scenes (gravity +y,
//! screen coordinates, as in the article); the page draws "up" against gravity
//! ([`SceneInfo::gravity`]). 3D scenes get a 3D view that the page projects.

use serde::{Deserialize, Serialize};

/// The protocol version; bumped on any incompatible change.
pub const PROTOCOL_VERSION: u32 = 7;

/// Which panels a message applies to: one panel by id, or all when absent / `null`.
pub type PanelTarget = Option<u32>;

/// Messages from the page to the server.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ClientMessage {
    /// Add a panel for the current scene. `method`: `"implicit"` or `"parametric"`;
    /// `integrator`: a name from [`Welcome::integrators`]; `dt` > 0 (s); `ks`, `kd` >= 0 the
    /// Baumgarte feedback (implicit only; must be 0 for parametric); `project`: project
    /// positions and velocities onto the constraints after every step (implicit only, not
    /// with adaptive integrators). Missing fields take the scene's defaults.
    AddPanel(PanelSettingsPatch),
    /// Remove panel `panel`.
    RemovePanel { panel: u32 },
    /// Change some settings of panel `panel` (the fields given); the panel restarts from
    /// the scene's initial state.
    ConfigurePanel {
        panel: u32,
        #[serde(flatten)]
        settings: PanelSettingsPatch,
    },
    /// Start advancing in real time (one panel, or all).
    Play {
        #[serde(default)]
        panel: PanelTarget,
    },
    /// Stop advancing (one panel, or all).
    Pause {
        #[serde(default)]
        panel: PanelTarget,
    },
    /// Pause, then advance by exactly one step of dt (one panel, or all).
    Step {
        #[serde(default)]
        panel: PanelTarget,
    },
    /// Restart from the scene's initial state (one panel, or all). A failed panel becomes
    /// usable again.
    Reset {
        #[serde(default)]
        panel: PanelTarget,
    },
    /// Simulated seconds per wall-clock second, in `[0, Limits::max_time_scale]`.
    SetTimeScale { scale: f64 },
    /// What the clock does at the scene's end ([`Clock::end`]): stop there, loop back to
    /// the start, or go on.
    SetAtEnd { at_end: AtEnd },
    /// Load a scene: exactly one of `name` (a name from [`Welcome::scenes`]) or `toml` (the
    /// text of a scene file the user picked; `file_name` names it in messages). On success
    /// all panels are replaced by the new scene's default panels; on failure the server
    /// replies [`ServerMessage::SceneError`] and nothing changes.
    LoadScene {
        #[serde(default)]
        name: Option<String>,
        #[serde(default)]
        toml: Option<String>,
        #[serde(default)]
        file_name: Option<String>,
    },
    /// Replace the expression of constraint `constraint` (0-based index into the scene's
    /// `[[constraint]]` tables; it must be an expression constraint) by `expr`, in one
    /// implicit panel or in all implicit panels. The panels restart from the scene's initial
    /// state moved onto the new curve. On error the server replies
    /// [`ServerMessage::CurveError`] and leaves every panel untouched.
    SetCurve {
        #[serde(default)]
        panel: PanelTarget,
        constraint: usize,
        expr: String,
    },
    /// Grab particle `particle` (index) of panel `panel`: from now on a spring from the
    /// particle to `target` (scene coordinates, 2 or 3 numbers; missing z = the particle's)
    /// plus critical damping act on it as forces from outside the system. Their work is
    /// counted in the frame's `work`, so the energy error stays the error of E - W.
    DragStart {
        panel: u32,
        particle: usize,
        target: Vec<f64>,
    },
    /// Move the spring's end of the drag in panel `panel`.
    DragMove { panel: u32, target: Vec<f64> },
    /// Release: the spring and the damping are removed (the work they did stays counted).
    DragEnd { panel: u32 },
    /// Reload the scene with parameter `name` (one of [`SceneInfo::params`], not a derived
    /// one) set to `value`, or to the value of `expr` (an expression of numbers, pi and e,
    /// e.g. `"pi/3"`: exactly the bits the scene file gets from it), and restart every panel
    /// with its settings. Exactly one of `value` and `expr`. A bounded parameter's value must
    /// be within its `min`..`max`, a whole parameter's whole. The reply is a new
    /// [`ServerMessage::Scene`] and [`ServerMessage::Panels`].
    SetParam {
        name: String,
        #[serde(default)]
        value: Option<f64>,
        #[serde(default)]
        expr: Option<String>,
    },
    /// Set the start state (while paused): particle `particle` of panel `panel` moved to
    /// `target` (2 or 3 numbers; a missing z is the particle's), the others where they are in
    /// that panel, all at rest. Every panel restarts from it at t = 0 (implicit: projected
    /// onto the point of the constraints closest to the drop, the same for every panel, see
    /// `bead::simulate::Simulation::restart_at_rest`); the reply is
    /// [`ServerMessage::StartPlaced`] and the new [`ServerMessage::Panels`]. If a panel
    /// cannot start, nothing changes and the reply is an error saying why.
    SetStart {
        panel: u32,
        particle: usize,
        target: Vec<f64>,
    },
    /// The page shows the x-y region `view` (`[x_min, y_min, x_max, y_max]`, scene units) of
    /// 2D panel `panel`, outside the region its curves were made over
    /// ([`PanelInfo::curve_region`]) or much smaller: the curves are made again over `view`
    /// and the next frame carries them ([`PanelFrame::curves`]). No other reply.
    SetView { panel: u32, view: [f64; 4] },
    /// Set the start state (while paused) to `positions` and `velocities` (`n_coords`
    /// numbers each; either may be absent: panel `panel`'s current ones), typed or from a
    /// dragged velocity arrow. Panel `panel` places them on its constraints (positions moved
    /// to the closest point, velocities projected onto the constraints' tangent, see
    /// `bead::simulate::Simulation::set_state`); every panel restarts at t = 0 from that
    /// placed state. The reply is [`ServerMessage::StateSet`] and the new
    /// [`ServerMessage::Panels`]; if a panel cannot start, nothing changes. Without `panel`
    /// (within version 7), the first panel places them (a share URL being restored does
    /// not know the ids its panels will get).
    SetStartState {
        #[serde(default)]
        panel: Option<u32>,
        #[serde(default)]
        positions: Option<Vec<f64>>,
        #[serde(default)]
        velocities: Option<Vec<f64>>,
    },
    /// Ask for the equations panel `panel`'s formulation derived (the text `bead check`
    /// prints for it); the reply is [`ServerMessage::Equations`].
    Equations { panel: u32 },
}

impl ClientMessage {
    /// The message's `type` name, for error replies.
    pub fn kind(&self) -> &'static str {
        match self {
            ClientMessage::AddPanel(_) => "add_panel",
            ClientMessage::RemovePanel { .. } => "remove_panel",
            ClientMessage::SetView { .. } => "set_view",
            ClientMessage::SetStartState { .. } => "set_start_state",
            ClientMessage::ConfigurePanel { .. } => "configure_panel",
            ClientMessage::Play { .. } => "play",
            ClientMessage::Pause { .. } => "pause",
            ClientMessage::Step { .. } => "step",
            ClientMessage::Reset { .. } => "reset",
            ClientMessage::SetTimeScale { .. } => "set_time_scale",
            ClientMessage::SetAtEnd { .. } => "set_at_end",
            ClientMessage::LoadScene { .. } => "load_scene",
            ClientMessage::SetCurve { .. } => "set_curve",
            ClientMessage::DragStart { .. } => "drag_start",
            ClientMessage::DragMove { .. } => "drag_move",
            ClientMessage::DragEnd { .. } => "drag_end",
            ClientMessage::SetParam { .. } => "set_param",
            ClientMessage::SetStart { .. } => "set_start",
            ClientMessage::Equations { .. } => "equations",
        }
    }
}

/// Panel settings as sent by the client; absent fields keep their current (or default)
/// value.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
pub struct PanelSettingsPatch {
    #[serde(default)]
    pub method: Option<String>,
    #[serde(default)]
    pub integrator: Option<String>,
    #[serde(default)]
    pub dt: Option<f64>,
    #[serde(default)]
    pub ks: Option<f64>,
    #[serde(default)]
    pub kd: Option<f64>,
    #[serde(default)]
    pub project: Option<bool>,
    /// Run the reference solution beside the panel and draw it as a ghost (see
    /// [`PanelFrame::reference`]).
    #[serde(default)]
    pub reference: Option<bool>,
}

/// Messages from the server to the page.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// First message of every connection.
    Welcome(Welcome),
    /// The current scene: what to draw that does not move.
    Scene(SceneInfo),
    /// The full list of panels with their settings and static drawing data (curves).
    Panels { panels: Vec<PanelInfo> },
    /// The state of every panel, ~60 times a second: a binary message (see
    /// [Frames](self#frames) and [`ServerMessage::encode`]), not JSON text.
    Frame {
        /// Simulated seconds per wall-clock second.
        time_scale: f64,
        /// The session's clock.
        clock: Clock,
        panels: Vec<PanelFrame>,
    },
    /// A request was rejected; nothing changed (except for `step_failed`: the step ran and
    /// failed, and the panel shows the failure). `code` says what went wrong for programs,
    /// `message` for people; `request` is the message type when it could be read, `panel`
    /// the panel concerned when there is one.
    Error {
        code: ErrorCode,
        message: String,
        #[serde(skip_serializing_if = "Option::is_none")]
        request: Option<String>,
        #[serde(skip_serializing_if = "Option::is_none")]
        panel: Option<u32>,
    },
    /// A `set_start` was done: the particles start (every panel alike) at `placed`, the
    /// point of the constraints closest to the drop (see
    /// `bead::simulate::Simulation::closest_start`); particle `particle` was dropped at
    /// `dropped` and moved by `moved` (scene units) onto the curve. Sent before the new
    /// [`ServerMessage::Panels`]; the page says how far it moved the drop.
    StartPlaced {
        panel: u32,
        particle: usize,
        dropped: Vec<f64>,
        placed: Vec<f64>,
        moved: f64,
        /// Every particle's start position (`n_coords`; at rest), for a share URL.
        positions: Vec<f64>,
    },
    /// A `set_start_state` was carried out: every panel starts from `positions` and
    /// `velocities` (on the constraints), which are `position_moved` and `velocity_moved`
    /// (Euclidean, scene units) from what was asked for. Sent before the new
    /// [`ServerMessage::Panels`].
    StateSet {
        panel: u32,
        positions: Vec<f64>,
        velocities: Vec<f64>,
        position_moved: f64,
        velocity_moved: f64,
    },
    /// The equations panel `panel`'s formulation derived: as `bead check` prints them
    /// (`text`), and the equations of motion typeset (`mathml`: HTML paragraphs with MathML
    /// blocks, [`bead::describe::equations_mathml`]; within version 7).
    Equations {
        panel: u32,
        method: String,
        text: String,
        mathml: String,
    },
    /// A `load_scene` failed: the rendered scene error (`file:line:column: message` and a
    /// caret snippet) and its position (0 when unknown).
    SceneError {
        message: String,
        line: usize,
        column: usize,
    },
    /// A `set_curve` failed. `columns` is the 0-based, end-exclusive character range (in
    /// characters, not bytes) of the offending text within `expr` when known, to underline it
    /// under the input; at the end of the input it is `[len, len + 1]`.
    CurveError {
        constraint: usize,
        code: ErrorCode,
        message: String,
        #[serde(skip_serializing_if = "Option::is_none")]
        columns: Option<[usize; 2]>,
    },
}

/// The session's clock, in every frame: the panels advance to the same simulated time
/// together.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Clock {
    /// Counts the restarts of the panels (scene load, parameter change, reset, add,
    /// configure, curve edit, new start state): a client waiting for the effect of such a
    /// request waits for a frame of a larger generation.
    pub generation: u64,
    /// Simulated seconds per wall-clock second over the last frames (recent average): the
    /// time scale when every panel keeps up, less when one cannot.
    pub sim_rate: f64,
    /// The panel that could not keep up in the last frame (all panels were held back to its
    /// time), when one could not.
    pub limited_by: Option<u32>,
    /// The scene's end: its `[run]` duration (or steps x dt; 10 s when it gives neither), as
    /// `bead run` runs it. `None` without a scene.
    pub end: Option<f64>,
    /// What happens there.
    pub at_end: AtEnd,
    /// Whether the panels stopped at the end ([`AtEnd::Stop`]): Play starts them again from
    /// the start.
    pub ended: bool,
}

/// What the clock does when it reaches the scene's end ([`Clock::end`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AtEnd {
    /// Every panel stops at the end (the default: a run as long as the scene says).
    #[default]
    Stop,
    /// Every panel starts again from the start.
    Loop,
    /// The panels go on past the end.
    Continue,
}

/// Why a request was rejected: stable names (`snake_case` in JSON) for programs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// Not JSON, not an object with a known `type`, or a field of the wrong type.
    InvalidMessage,
    /// A text frame over [`Limits::max_message_bytes`].
    TooLarge,
    /// A binary frame.
    BinaryMessage,
    /// The server failed while handling the message (a bug); the session is kept.
    InternalError,
    /// The request needs a scene and none is loaded.
    NoScene,
    /// No panel with that id.
    NoPanel,
    /// [`Limits::max_panels`] reached.
    TooManyPanels,
    /// A number out of its range (dt, ks, kd, time scale, drag target), or a name that
    /// is not a method, integrator or particle.
    BadValue,
    /// A combination of formulation, integrator, projection and feedback that cannot run
    /// (the message is the library's `ConfigError`, word for word what the CLI prints).
    IllegalCombination,
    /// The simulation cannot start: over-constrained, or an initial state that cannot be
    /// simulated or moved onto the constraints.
    SetupFailed,
    /// `load_scene` by a name that is not in [`Welcome::scenes`].
    UnknownScene,
    /// Fields that do not go together (e.g. `load_scene` with both `name` and `toml`).
    BadRequest,
    /// `drag_move` without a drag in progress in that panel.
    NoDrag,
    /// A `step` request ran and the panel failed (see its frame's `error`).
    StepFailed,
    /// `set_curve`: the expression does not parse or names something unknown (`columns`
    /// point at it).
    Expression,
    /// `set_curve`: the expression does not depend on any particle coordinate.
    NoCoordinate,
    /// `set_curve`: no constraint with that index.
    UnknownConstraint,
    /// `set_curve`: the constraint is a distance or pin constraint, which has no expression.
    NotAnExpression,
    /// `set_curve`: the expression is longer than [`Limits::max_expr_chars`].
    TooLong,
    /// `set_curve`: no implicit panel to apply the curve to.
    NoImplicitPanel,
    /// `set_curve` on a parametric panel, whose curve is its map x(q).
    ParametricPanel,
    /// `set_start`: a panel cannot start from that state (the message says which and why).
    StartFailed,
    /// `set_param` with a name that is not one of the scene's parameters.
    UnknownParam,
}

/// Contents of [`ServerMessage::Welcome`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Welcome {
    /// [`PROTOCOL_VERSION`].
    pub protocol: u32,
    /// Scene names `load_scene` accepts by name (the shipped scenes, plus the one given on
    /// the command line).
    pub scenes: Vec<String>,
    /// Every integrator a panel can use.
    pub integrators: Vec<IntegratorInfo>,
    /// `["implicit", "parametric"]`.
    pub methods: Vec<String>,
    pub limits: Limits,
}

/// An integrator as offered in the page.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IntegratorInfo {
    pub name: String,
    pub order: u32,
    pub symplectic: bool,
    /// Chooses its own steps; dt is then the output interval.
    pub adaptive: bool,
    /// Works on the constraints directly: implicit panels only.
    pub needs_constraints: bool,
    /// One-line description.
    pub description: String,
}

/// Per-connection limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Limits {
    pub max_panels: usize,
    /// Particles of a scene (a session refuses more). 10^4: what the viewer itself
    /// sustains at 60 frames/s, measured (DESIGN.md, Viewer, Scale): a 2D frame is 160 kB,
    /// encoded in 0.02 ms, 9.6 MB/s on the wire (most of a 100 Mbit/s link), decoded by the
    /// page in 0.14 ms and drawn in 6-11 ms of a 16.7 ms frame with 2 x 10^4 rods. Whether
    /// the simulation of so many particles keeps up is the core's affair: a panel that
    /// cannot says `behind`.
    pub max_particles: usize,
    /// Steps per frame, summed over the connection's panels.
    pub max_steps_per_frame: u64,
    pub max_message_bytes: usize,
    /// Characters of a `set_curve` expression.
    pub max_expr_chars: usize,
    pub min_dt: f64,
    pub max_dt: f64,
    pub max_feedback: f64,
    pub max_time_scale: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_panels: 8,
            max_particles: 10_000,
            max_steps_per_frame: 20_000,
            max_message_bytes: 64 * 1024,
            max_expr_chars: 2000,
            min_dt: 1e-6,
            max_dt: 1.0,
            max_feedback: 1e9,
            max_time_scale: 100.0,
        }
    }
}

/// Contents of [`ServerMessage::Scene`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneInfo {
    /// The name it was loaded by (a shipped scene's name or the file name).
    pub name: String,
    pub title: String,
    /// The scene's `about`: what to show with it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub about: Option<String>,
    /// The unit of energies, from `[world] units` (`"J"` for SI, `"kg px^2/s^2"` for px);
    /// absent when the scene does not say.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energy_unit: Option<String>,
    /// The unit of lengths, from `[world] units` (`"m"` for SI, else the scene's word, e.g.
    /// `"px"`); absent when the scene does not say.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub length_unit: Option<String>,
    /// 2 or 3.
    pub dim: usize,
    /// The scene's gravity, `dim` numbers (m/s^2): the page draws "up" against it.
    pub gravity: Vec<f64>,
    pub particles: Vec<ParticleInfo>,
    /// The scene's `[[constraint]]` tables, in order.
    pub constraints: Vec<ConstraintInfo>,
    /// The region to draw, in scene coordinates: `[x_min, y_min, x_max, y_max]`. Covers the
    /// initial state, the anchors and the motion of a short trial run.
    pub view: [f64; 4],
    /// Distance constraints, drawn as rods.
    pub rods: Vec<Rod>,
    /// Pin constraints: particles held at a fixed point (drawn as a square there).
    pub pins: Vec<Pin>,
    pub has_implicit: bool,
    pub has_parametric: bool,
    /// Scene warnings (initial state off the constraints, ...).
    pub warnings: Vec<String>,
    /// The scene's `[params]`, in file order, with what a slider and a number box need.
    pub params: Vec<ParamInfo>,
}

/// A `[params]` value of the scene and what its control shows (from the scene's parameter
/// table, `bead::scene::ParamSpec`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParamInfo {
    pub name: String,
    pub value: f64,
    /// The slider's ends: the scene's `range` (the exact values of its ends), else
    /// [`default_param_range`] of the value first loaded, widened to any value typed beyond.
    pub min: f64,
    pub max: f64,
    /// The ends are the scene's `range`: `set_param` refuses values beyond them. Without a
    /// range any finite value can be typed.
    pub bounded: bool,
    /// A whole number (`integer = true`, or a count in a `for` range): steps of 1.
    pub integer: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Derived from other parameters (the expression it is written as, e.g. `S/(W-1)`):
    /// shown, not set; `depends_on` are the parameters it follows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub derived: Option<String>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub depends_on: Vec<String>,
}

/// A slider's range for a parameter of value `value` whose scene gives none: through 0 and
/// twice the value (`[0, 2v]`, `[2v, 0]`, `[-1, 1]` at 0); whole numbers from 1 (or `v - 10`
/// when v < 1) to `max(2v, 10)`.
pub fn default_param_range(value: f64, integer: bool) -> (f64, f64) {
    if integer {
        if value >= 1.0 {
            (1.0, (2.0 * value).max(10.0))
        } else {
            (value - 10.0, value + 10.0)
        }
    } else if value == 0.0 || !value.is_finite() {
        (-1.0, 1.0)
    } else if value > 0.0 {
        (0.0, 2.0 * value)
    } else {
        (2.0 * value, 0.0)
    }
}

/// Which settings do something for a panel's method and integrator, decided by the
/// library's legality check (`SimulationConfig::check`): the page hides the others.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Applies {
    /// Baumgarte feedback ks, kd (implicit form only).
    pub feedback: bool,
    /// Projection after every step (implicit form, fixed-step integrators).
    pub project: bool,
}

/// A `kind = "distance"` constraint: a rod from particle `a` to particle `b` or to the fixed
/// point `anchor` (`dim` numbers; version 3 sent x-y only).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Rod {
    pub a: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub b: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anchor: Option<Vec<f64>>,
}

/// A `kind = "pin"` constraint: particle `particle` held at `anchor` (`dim` numbers).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Pin {
    pub particle: usize,
    pub anchor: Vec<f64>,
}

/// A particle of the scene.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParticleInfo {
    pub name: String,
    pub mass: f64,
}

/// A `[[constraint]]` of the scene.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ConstraintInfo {
    pub name: String,
    pub description: String,
    /// The expression text for `kind = "expression"` constraints (editable with
    /// `set_curve`); `None` for distance and pin constraints.
    pub expr: Option<String>,
}

/// A panel's settings and static drawing data.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PanelInfo {
    pub id: u32,
    /// Changes whenever the panel is rebuilt or restarted; frames carry it too.
    pub epoch: u64,
    pub method: String,
    pub integrator: String,
    pub dt: f64,
    pub ks: f64,
    pub kd: f64,
    pub project: bool,
    /// Whether the panel runs the reference solution beside it ([`PanelFrame::reference`]).
    pub reference: bool,
    /// The constraint expressions this panel runs with (index as in
    /// [`SceneInfo::constraints`]; `None` for non-expression constraints).
    pub exprs: Vec<Option<String>>,
    /// The curve(s) at t = 0, as polylines of points with `dim` coordinates each
    /// (`[x0, y0, x1, y1, ...]` in 2D) in scene coordinates. Implicit 2D constraints on one
    /// particle are contoured (marching squares over the view box); a parametric form with
    /// one coordinate is sampled along x(q). Empty when neither applies. When `curves_move`,
    /// frames carry the curves at their own t (see [`PanelFrame::curves`]).
    pub curves: Vec<Vec<f64>>,
    /// How the curves were made: `"contour"`, `"parametric"` or `"none"`.
    pub curve_source: String,
    /// The curves depend on t (a driven constraint, a moving map): each frame carries them.
    pub curves_move: bool,
    /// This panel's view box `[x_min, y_min, x_max, y_max]`: the scene's, or made again for
    /// the panel's edited curves (see [`SceneInfo::view`]).
    pub view: [f64; 4],
    /// The x-y region `[x_min, y_min, x_max, y_max]` the curves were made over: contours
    /// cover it padded by 10% a side, a 2D map it padded by 20%. The view box, or the region
    /// of the last `set_view`; a page that shows more (or far less) asks again.
    pub curve_region: [f64; 4],
    /// Something to say about the curve, e.g. that a curve edit did not change this
    /// (parametric) panel's map.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub curve_note: Option<String>,
    /// Which settings apply to this panel (the others do nothing or are refused).
    pub applies: Applies,
    /// The names of the generalized coordinates q of a parametric panel (the scene's
    /// `coordinates`); empty for an implicit panel, whose coordinates are the particles'.
    pub coordinates: Vec<String>,
}

/// The reference solution beside a panel (see [`PanelFrame::reference`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReferenceFrame {
    /// Its time: the panel's (both stand at the same output time of dt).
    pub t: f64,
    /// Particle positions, `dim` numbers per particle.
    pub x: Vec<f64>,
    /// max over particles of |x - x_ref|: how far the panel is from the reference.
    pub distance: f64,
}

/// A panel's unilateral constraints (see [`PanelFrame::contact`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ContactFrame {
    /// Per unilateral constraint, in the scene's order: whether the particle is off it now
    /// (in flight).
    pub detached: Vec<bool>,
    /// Since the panel's simulation started (a reset or a new start clears them): how often
    /// a particle left one, landed on one (and stayed), and bounced off one.
    pub detaches: u64,
    pub landings: u64,
    pub bounces: u64,
}

/// One panel's state in a [`ServerMessage::Frame`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PanelFrame {
    pub id: u32,
    /// The panel's epoch when this frame was made (see [`PanelInfo::epoch`]).
    pub epoch: u64,
    /// Simulated time (s).
    pub t: f64,
    /// Steps taken since the last reset (accepted steps for adaptive integrators).
    pub steps: u64,
    /// Particle positions, `dim` numbers per particle. Not in the frame's JSON header: they
    /// are packed after it (see [Frames](self#frames)).
    #[serde(skip)]
    pub x: Vec<f64>,
    /// Total mechanical energy E = T + V of the scene's system (the drag spring has no
    /// potential here: its work is in `work`).
    pub energy: f64,
    /// Kinetic energy T = 1/2 sum m |v|^2 (the core's).
    pub kinetic: f64,
    /// Potential energy V of the scene's conservative forces (the core's); T + V = `energy`.
    pub potential: f64,
    /// E0 = T + V when the epoch started.
    pub energy_initial: f64,
    /// E_scale, the denominator of `energy_error` (see there).
    pub energy_scale: f64,
    /// The relative error of what the panel conserves, |E - W - E0| / E_scale since the
    /// epoch started: |E - E0| / E_scale when nothing does work on the system. E_scale =
    /// max(|E0|, T0 + |V0|, T0 + M |g| L) does not vanish at the potential's zero.
    pub energy_error: f64,
    /// Whether T + V itself is conserved: nothing does work on the system (no drag force, no
    /// driven constraint or moving map, no drag with the mouse since the epoch started).
    pub energy_conserved: bool,
    /// The work W done on the system since the epoch started (0 when nothing does work).
    pub work: f64,
    /// What does work on the system when `energy_conserved` is false, e.g.
    /// `driven constraint: constraint 1 depends on t`, `external forces`.
    pub not_conserved_by: Vec<String>,
    /// max_i |C_i| over the scene's implicit constraints.
    pub constraint_error: f64,
    /// Steps per second of compute time (recent average): the compute rate.
    pub steps_per_second: f64,
    /// max over particles of |x - x_first|, the distance of this panel's particles to the
    /// first panel's at the same t (`None` for the first panel, and when the two are not
    /// at the same t or have different particles).
    pub distance: Option<f64>,
    /// The reference solution at the panel's t, when the panel runs one: the panel's system
    /// and form integrated by dopri5 at rtol 1e-12 from the panel's start, drawn as a ghost.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<ReferenceFrame>,
    /// Why a panel asked to run the reference has none (too many coordinates, or it failed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_note: Option<String>,
    /// With unilateral constraints (`side` in the scene): which are left now and the switches
    /// so far.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact: Option<ContactFrame>,
    /// `"running"`, `"paused"` or `"failed"`.
    pub status: String,
    /// Why the panel failed (divergence, singular constraints, ...), when it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The panel could not keep up with real time in the last frame (step or time budget).
    pub behind: bool,
    /// The particle being dragged and the spring's end, while dragging.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drag: Option<DragInfo>,
    /// The states the simulation went through since the last frame, for trails drawn along
    /// the motion rather than chords between frames: samples of `1 + x.len()` numbers, t
    /// then the positions, at most [`PATH_MAX_SAMPLES`] (evenly spaced in steps when more
    /// were taken). Empty for scenes of more than [`PATH_MAX_NUMBERS`] coordinates. Packed
    /// after the positions (see [Frames](self#frames)).
    #[serde(skip)]
    pub path: Vec<f64>,
    /// The panel's curves, when they move ([`PanelInfo::curves_move`]: at this frame's t,
    /// made coarser, [`crate::geometry::Resolution::Frame`]) or were made again since the
    /// last frame (the bead neared the end of the part of its map that was drawn, or a
    /// `set_view` asked for another region). They replace the curves the page has. Packed
    /// after the path (see [Frames](self#frames)).
    #[serde(skip)]
    pub curves: Option<Vec<Vec<f64>>>,
    /// The x-y region the panel's curves cover (see [`PanelInfo::curve_region`]).
    pub curve_region: [f64; 4],
    /// Velocities and forces at this frame's state, for arrows: scenes of at most
    /// [`ARROW_MAX_PARTICLES`] particles and [`ARROW_MAX_ROWS`] constraint rows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub arrows: Option<Arrows>,
    /// A parametric panel's generalized coordinates q then their rates q' (the names are
    /// [`PanelInfo::coordinates`]), for scenes of at most [`GENERALIZED_MAX`] coordinates.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub generalized: Option<Vec<f64>>,
}

/// Parametric panels of more generalized coordinates than this send no
/// [`PanelFrame::generalized`].
pub const GENERALIZED_MAX: usize = 32;

/// Panels of scenes with more coordinates than this run no reference solution
/// ([`PanelFrame::reference`]): dopri5 at rtol 1e-12 beside a large scene would hold the
/// panel back.
pub const REFERENCE_MAX_COORDS: usize = 64;

/// Scenes with more particles than this send no [`Arrows`].
pub const ARROW_MAX_PARTICLES: usize = 16;
/// Scenes with more constraint rows than this send no [`Arrows`].
pub const ARROW_MAX_ROWS: usize = 32;

/// What a panel's arrows show, at the frame's state: `dim` numbers per particle each
/// (`n_coords` in all), in the scene's units.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Arrows {
    /// The velocities v.
    pub velocity: Vec<f64>,
    /// The weights m g.
    pub gravity: Vec<f64>,
    /// The scene's other forces (springs, constant forces, drag), summed per particle; the
    /// drag spring of the mouse is not among them.
    pub applied: Vec<f64>,
    /// The total constraint force on each particle: J^T lambda in the implicit form
    /// (feedback included), M a - F in the parametric form (the map's reaction). Empty when
    /// it cannot be computed here (singular constraints).
    pub constraint: Vec<f64>,
    /// The implicit form's rows: lambda_i grad C_i each (their sum is `constraint`).
    pub rows: Vec<RowForce>,
    /// A speed and a force typical of the scene, constant within an epoch, that the page
    /// scales arrows by: sqrt(2 E_scale / M) and max(max m |g|, E_scale / L) with M the total
    /// mass and L the view box's larger side.
    pub speed_ref: f64,
    pub force_ref: f64,
}

/// One constraint row's force lambda_i grad C_i.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RowForce {
    /// The row (0-based, as in the scene's constraint rows).
    pub row: usize,
    /// Its multiplier lambda_i.
    pub lambda: f64,
    /// |grad C_i| over all coordinates.
    pub gradient_norm: f64,
    /// lambda_i dC_i/dx per coordinate (`n_coords` numbers).
    pub force: Vec<f64>,
}

/// Most path samples a frame carries per panel.
pub const PATH_MAX_SAMPLES: usize = 64;
/// Scenes with more coordinates than this send no path (trails are off for them by default).
pub const PATH_MAX_NUMBERS: usize = 60;

/// A drag in progress.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DragInfo {
    pub particle: usize,
    pub target: Vec<f64>,
}

/// A client text frame that is not a valid message.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    #[error("message too large: {bytes} bytes (limit {limit})")]
    TooLarge { bytes: usize, limit: usize },
    /// serde's message, which names the field and the position.
    #[error("invalid message: {0}")]
    Invalid(String),
}

impl ProtocolError {
    pub fn code(&self) -> ErrorCode {
        match self {
            ProtocolError::TooLarge { .. } => ErrorCode::TooLarge,
            ProtocolError::Invalid(_) => ErrorCode::InvalidMessage,
        }
    }
}

/// Parse one client text frame.
pub fn parse_client_message(text: &str, limits: &Limits) -> Result<ClientMessage, ProtocolError> {
    if text.len() > limits.max_message_bytes {
        return Err(ProtocolError::TooLarge {
            bytes: text.len(),
            limit: limits.max_message_bytes,
        });
    }
    serde_json::from_str(text).map_err(|e| ProtocolError::Invalid(e.to_string()))
}

/// The `type` of a JSON object, when it has a string one (for error replies to messages that
/// do not parse).
pub fn message_type(text: &str) -> Option<String> {
    let value: serde_json::Value = serde_json::from_str(text).ok()?;
    let kind = value.get("type")?.as_str()?;
    Some(kind.chars().take(40).collect())
}

/// The first four bytes of every binary frame.
pub const FRAME_MAGIC: [u8; 4] = *b"bead";

/// A server message as it goes on the wire.
#[derive(Clone, Debug, PartialEq)]
pub enum Encoded {
    /// A JSON text frame (every message but [`ServerMessage::Frame`]).
    Text(String),
    /// A binary frame ([`ServerMessage::Frame`], see [Frames](self#frames)).
    Binary(Vec<u8>),
}

/// One panel in a frame's JSON header: the frame without `x`, and where its positions are.
#[derive(Serialize)]
struct PanelHeader<'a> {
    #[serde(flatten)]
    frame: &'a PanelFrame,
    x_offset: usize,
    x_count: usize,
    path_offset: usize,
    path_count: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    curve_offset: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    curve_counts: Option<Vec<usize>>,
}

#[derive(Serialize)]
struct FrameHeader<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    time_scale: f64,
    clock: Clock,
    panels: Vec<PanelHeader<'a>>,
}

impl ServerMessage {
    /// The message as sent: a binary frame for [`ServerMessage::Frame`], JSON text otherwise.
    pub fn encode(&self) -> Result<Encoded, serde_json::Error> {
        match self {
            ServerMessage::Frame {
                time_scale,
                clock,
                panels,
            } => encode_frame_with(*time_scale, clock, panels).map(Encoded::Binary),
            other => serde_json::to_string(other).map(Encoded::Text),
        }
    }
}

/// A frame as a binary message (see [Frames](self#frames)), with a default [`Clock`].
pub fn encode_frame(time_scale: f64, panels: &[PanelFrame]) -> Result<Vec<u8>, serde_json::Error> {
    encode_frame_with(time_scale, &Clock::default(), panels)
}

/// A frame as a binary message (see [Frames](self#frames)).
pub fn encode_frame_with(
    time_scale: f64,
    clock: &Clock,
    panels: &[PanelFrame],
) -> Result<Vec<u8>, serde_json::Error> {
    let mut offset = 0;
    let headers = panels
        .iter()
        .map(|frame| {
            let x_offset = offset;
            offset += frame.x.len();
            let path_offset = offset;
            let sample = 1 + frame.x.len();
            let path_count = frame.path.len() / sample;
            offset += path_count * sample;
            let curve_offset = frame.curves.as_ref().map(|_| offset);
            let curve_counts = frame.curves.as_ref().map(|lines| {
                let counts: Vec<usize> = lines.iter().map(Vec::len).collect();
                offset += counts.iter().sum::<usize>();
                counts
            });
            PanelHeader {
                frame,
                x_offset,
                x_count: frame.x.len(),
                path_offset,
                path_count,
                curve_offset,
                curve_counts,
            }
        })
        .collect();
    let header = serde_json::to_vec(&FrameHeader {
        kind: "frame",
        time_scale,
        clock: *clock,
        panels: headers,
    })?;
    let header_len = u32::try_from(header.len()).map_err(serde::ser::Error::custom)?;
    let start = (8 + header.len()).next_multiple_of(8);
    let mut out = Vec::with_capacity(start + 8 * offset);
    out.extend_from_slice(&FRAME_MAGIC);
    out.extend_from_slice(&header_len.to_le_bytes());
    out.extend_from_slice(&header);
    out.resize(start, 0);
    for frame in panels {
        let sample = 1 + frame.x.len();
        let path = &frame.path[..frame.path.len() / sample * sample];
        let curves = frame.curves.iter().flatten().flatten();
        for v in frame.x.iter().chain(path).chain(curves) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    Ok(out)
}

/// A binary frame that does not follow the layout.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FrameError {
    #[error("not a frame: {0}")]
    Layout(&'static str),
    #[error("bad frame header: {0}")]
    Header(String),
}

/// The reference decoder of a binary frame: its JSON header with each panel's `x` filled in
/// as an array of numbers, `path` as an array of samples (each an array: t, then the
/// positions) and, when the curves move, `curves` as an array of polylines (the offsets and
/// counts kept). For tests and other clients.
pub fn decode_frame(bytes: &[u8]) -> Result<serde_json::Value, FrameError> {
    if bytes.len() < 8 || bytes[..4] != FRAME_MAGIC {
        return Err(FrameError::Layout("no magic bytes"));
    }
    let header_len = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]) as usize;
    let header = bytes
        .get(8..8 + header_len)
        .ok_or(FrameError::Layout("header past the end"))?;
    let mut value: serde_json::Value =
        serde_json::from_slice(header).map_err(|e| FrameError::Header(e.to_string()))?;
    let start = (8 + header_len).next_multiple_of(8);
    let block = bytes.get(start..).unwrap_or_default();
    if block.len() % 8 != 0 {
        return Err(FrameError::Layout("positions not a whole number of f64"));
    }
    let numbers: Vec<f64> = block
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect();
    let panels = value
        .get_mut("panels")
        .and_then(|p| p.as_array_mut())
        .ok_or_else(|| FrameError::Header("no panels".into()))?;
    for panel in panels {
        let field = |name: &str| {
            panel
                .get(name)
                .and_then(|v| v.as_u64())
                .map(|v| v as usize)
                .ok_or_else(|| FrameError::Header(format!("a panel without `{name}`")))
        };
        let (offset, count) = (field("x_offset")?, field("x_count")?);
        let (path_offset, path_count) = (field("path_offset")?, field("path_count")?);
        let take = |from: usize, len: usize| {
            numbers
                .get(from..from.saturating_add(len))
                .ok_or(FrameError::Layout("numbers past the end"))
        };
        let x = take(offset, count)?;
        let path = take(path_offset, path_count.saturating_mul(count + 1))?;
        let curves = match (panel.get("curve_offset"), panel.get("curve_counts")) {
            (Some(from), Some(counts)) => {
                let mut from = from
                    .as_u64()
                    .ok_or_else(|| FrameError::Header("bad `curve_offset`".into()))?
                    as usize;
                let counts = counts
                    .as_array()
                    .ok_or_else(|| FrameError::Header("bad `curve_counts`".into()))?;
                let mut lines = Vec::new();
                for c in counts {
                    let c = c
                        .as_u64()
                        .ok_or_else(|| FrameError::Header("bad `curve_counts`".into()))?
                        as usize;
                    lines.push(serde_json::json!(take(from, c)?));
                    from += c;
                }
                Some(serde_json::Value::Array(lines))
            }
            _ => None,
        };
        panel["x"] = x.iter().map(|&v| serde_json::json!(v)).collect();
        panel["path"] = path
            .chunks(count + 1)
            .map(|s| serde_json::json!(s))
            .collect();
        if let Some(curves) = curves {
            panel["curves"] = curves;
        }
    }
    Ok(value)
}
