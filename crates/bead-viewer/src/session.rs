//! One connection's state: the current scene, its panels and the time scale; handles client
//! messages and advances the panels frame by frame. Independent of the network, so that it
//! can be tested directly.

use std::sync::Arc;
use std::time::Duration;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::{DeclaredConstraint, EditError, Endpoint};
use bead::scene::{Scene, SceneError};
use bead::simulate::{ConfigError, RunError, SetupError, StateRequest};

use crate::geometry;
use crate::panel::{DragError, Panel, PanelFailure, PanelSettings};
use crate::protocol::{
    default_param_range, message_type, parse_client_message, AtEnd, ClientMessage, Clock,
    ConstraintInfo, Encoded, ErrorCode, IntegratorInfo, Limits, PanelFrame, PanelSettingsPatch,
    ParamInfo, ParticleInfo, Pin, Rod, SceneInfo, ServerMessage, Welcome, PROTOCOL_VERSION,
};
use crate::scenes::Catalog;

/// Compute time allowed for stepping per frame, over all panels.
const FRAME_BUDGET: Duration = Duration::from_millis(25);

/// The loaded scene; panels share it, or a copy with their own curve edits.
struct CurrentScene {
    scene: Arc<Scene>,
    info: SceneInfo,
    /// The `[params]` as first loaded, with their ranges: a parameter change keeps them, so
    /// that a slider's range does not move under it.
    params: Vec<ParamInfo>,
    /// Where the scene's run ends (`[run]` duration), resolved once at load.
    end: Option<f64>,
}

impl CurrentScene {
    fn new(scene: Arc<Scene>, info: SceneInfo, params: Vec<ParamInfo>) -> CurrentScene {
        let end = bead::plan::Plan::resolve(&scene, &bead::plan::PlanRequest::default())
            .ok()
            .map(|plan| plan.t_end());
        CurrentScene {
            scene,
            info,
            params,
            end,
        }
    }
}

/// Why a request was rejected. Each has an [`ErrorCode`] for the reply.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("no scene loaded")]
    NoScene,
    #[error("no panel {0}")]
    NoPanel(u32),
    #[error("no panel to start: add one first")]
    NoPanels,
    #[error("too many panels (limit {0})")]
    TooManyPanels(usize),
    /// A number outside its range.
    #[error("{name} must be a number in [{}, {}]", bead::readable(*min), bead::readable(*max))]
    OutOfRange {
        name: &'static str,
        min: f64,
        max: f64,
    },
    /// A method or integrator name that is not one (the library's message).
    #[error("{0}")]
    UnknownName(String),
    /// The library's legality check: the same words as the CLI's.
    #[error(transparent)]
    Illegal(ConfigError),
    /// The simulation cannot start (over-constrained, initial state).
    #[error(transparent)]
    Setup(SetupError),
    #[error("unknown scene `{name}`; use one of {}", known.join(", "))]
    UnknownScene { name: String, known: Vec<String> },
    #[error("load_scene needs exactly one of `name` and `toml`")]
    SceneSource,
    #[error(transparent)]
    Drag(#[from] DragError),
    /// A `step` request made the panel fail.
    #[error("{message}")]
    StepFailed { message: String },
    #[error("unknown parameter `{name}`; the scene's parameters: {}", if known.is_empty() { "none".to_string() } else { known.join(", ") })]
    UnknownParam { name: String, known: Vec<String> },
    #[error("parameter `{name}` must be a number in [{}, {}]", bead::readable(*min), bead::readable(*max))]
    ParamRange { name: String, min: f64, max: f64 },
    /// The scene does not load or start with the new value (the library's message).
    #[error("cannot use this value: {0}")]
    ParamFailed(String),
    #[error("set_param needs exactly one of `value` and `expr`")]
    ParamSource,
    /// A typed expression that is not a constant.
    #[error("parameter `{name}`: {message}")]
    ParamExpr { name: String, message: String },
    #[error("parameter `{name}` is derived ({name} = {expr}): change {} instead", if from.is_empty() { "the scene".to_string() } else { from.join(", ") })]
    DerivedParam {
        name: String,
        expr: String,
        from: Vec<String>,
    },
    #[error("parameter `{name}` is a whole number, got {}", bead::readable(*value))]
    ParamWhole { name: String, value: f64 },
    /// `set_start_state` values of the wrong length.
    #[error("{what} need {expected} numbers (the particles' coordinates), got {got}")]
    StateValues {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A `set_view` region that is not one.
    #[error("view must be [x_min, y_min, x_max, y_max], finite within 1e12 with x_min < x_max and y_min < y_max; got {view:?}")]
    Region { view: [f64; 4] },
    /// A panel cannot start from the dragged state.
    #[error("cannot start from this state: panel {panel} ({method}): {message}")]
    StartFailed {
        panel: u32,
        method: &'static str,
        message: String,
    },
}

impl SessionError {
    pub fn code(&self) -> ErrorCode {
        match self {
            SessionError::NoScene => ErrorCode::NoScene,
            SessionError::NoPanel(_) | SessionError::NoPanels => ErrorCode::NoPanel,
            SessionError::TooManyPanels(_) => ErrorCode::TooManyPanels,
            SessionError::OutOfRange { .. } | SessionError::UnknownName(_) => ErrorCode::BadValue,
            SessionError::Illegal(_) => ErrorCode::IllegalCombination,
            SessionError::Setup(_) => ErrorCode::SetupFailed,
            SessionError::UnknownScene { .. } => ErrorCode::UnknownScene,
            SessionError::SceneSource => ErrorCode::BadRequest,
            SessionError::Drag(DragError::NoDrag) => ErrorCode::NoDrag,
            SessionError::Drag(_) => ErrorCode::BadValue,
            SessionError::StepFailed { .. } => ErrorCode::StepFailed,
            SessionError::UnknownParam { .. } => ErrorCode::UnknownParam,
            SessionError::ParamRange { .. }
            | SessionError::Region { .. }
            | SessionError::ParamExpr { .. }
            | SessionError::DerivedParam { .. }
            | SessionError::ParamWhole { .. }
            | SessionError::StateValues { .. } => ErrorCode::BadValue,
            SessionError::ParamSource => ErrorCode::BadRequest,
            SessionError::ParamFailed(_) => ErrorCode::SetupFailed,
            SessionError::StartFailed { .. } => ErrorCode::StartFailed,
        }
    }
}

impl From<SetupError> for SessionError {
    fn from(e: SetupError) -> Self {
        match e {
            SetupError::Config(e) => SessionError::Illegal(e),
            other => SessionError::Setup(other),
        }
    }
}

/// Why a curve edit was refused (a [`ServerMessage::CurveError`]).
#[derive(Debug, thiserror::Error)]
enum CurveFailure {
    #[error("expression too long: {chars} characters (limit {limit})")]
    TooLong { chars: usize, limit: usize },
    #[error(transparent)]
    Edit(EditError),
    #[error("a parametric panel's curve is its map x(q): edit [parametric.positions] in the scene file instead")]
    ParametricPanel,
    #[error("no implicit panel to apply the curve to: add one (the parametric form's curve is its map x(q))")]
    NoImplicitPanel,
    #[error(transparent)]
    Setup(SessionError),
    #[error("cannot move the initial state onto the new curve: {0}")]
    Start(String),
}

impl CurveFailure {
    fn code(&self) -> ErrorCode {
        match self {
            CurveFailure::TooLong { .. } => ErrorCode::TooLong,
            CurveFailure::Edit(EditError::Expression { .. }) => ErrorCode::Expression,
            CurveFailure::Edit(EditError::NoCoordinate { .. }) => ErrorCode::NoCoordinate,
            CurveFailure::Edit(EditError::UnknownConstraint { .. }) => ErrorCode::UnknownConstraint,
            CurveFailure::Edit(EditError::NotAnExpression { .. }) => ErrorCode::NotAnExpression,
            CurveFailure::Edit(_) => ErrorCode::BadValue,
            CurveFailure::ParametricPanel => ErrorCode::ParametricPanel,
            CurveFailure::NoImplicitPanel => ErrorCode::NoImplicitPanel,
            CurveFailure::Setup(e) => e.code(),
            CurveFailure::Start(_) => ErrorCode::SetupFailed,
        }
    }

    /// The message shown under the input: an expression error's own message (the columns
    /// point into the input), else the whole error.
    fn message(&self) -> String {
        match self {
            CurveFailure::Edit(EditError::Expression { message, .. }) => message.clone(),
            other => other.to_string(),
        }
    }

    /// The character range of an expression error inside `expr`.
    fn columns(&self, expr: &str) -> Option<[usize; 2]> {
        let CurveFailure::Edit(EditError::Expression { span, .. }) = self else {
            return None;
        };
        Some(char_columns(expr, span.start, span.end))
    }
}

/// A byte range of `text` as a character range, at least one character wide (an error at
/// the end of the input underlines the place just after it).
pub fn char_columns(text: &str, start: usize, end: usize) -> [usize; 2] {
    let chars_before = |i: usize| {
        let mut i = i.min(text.len());
        while !text.is_char_boundary(i) {
            i -= 1;
        }
        text[..i].chars().count()
    };
    let begin = chars_before(start);
    [begin, chars_before(end).max(begin + 1)]
}

/// A connection's session.
pub struct Session {
    catalog: Arc<Catalog>,
    limits: Limits,
    scene: Option<CurrentScene>,
    panels: Vec<Panel>,
    next_id: u32,
    next_epoch: u64,
    time_scale: f64,
    /// The shared clock: the simulated time every running panel advances to.
    clock: f64,
    /// Counts restarts of the panels ([`Clock::generation`]).
    generation: u64,
    /// Simulated seconds per wall second (recent average).
    sim_rate: f64,
    /// The panel that held the others back in the last frame.
    limited_by: Option<u32>,
    /// What the clock does at the scene's end, and whether it stopped there.
    at_end: AtEnd,
    ended: bool,
}

/// Parse a scene as a session would: refusing more particles than a session allows
/// ([`Limits::max_particles`]) and never panicking. `bead serve` checks its scene with it.
pub fn parse_scene(text: &str, file: &str) -> Result<Scene, SceneError> {
    let error = |message: String| SceneError {
        file: file.to_string(),
        line: 0,
        column: 0,
        message,
        snippet: None,
    };
    let scene = std::panic::catch_unwind(|| Scene::parse(text, file, &[]))
        .map_err(|_| error("internal error: the scene parser panicked".into()))??;
    let limit = Limits::default().max_particles;
    if scene.system.particles().len() > limit {
        return Err(error(format!(
            "too many particles: {} (limit {limit})",
            scene.system.particles().len()
        )));
    }
    Ok(scene)
}

type Rejection = (SessionError, Option<u32>);

impl Session {
    /// A session with the catalog's first scene loaded and its default panels.
    pub fn new(catalog: Arc<Catalog>, limits: Limits) -> Session {
        let mut session = Session {
            catalog,
            limits,
            scene: None,
            panels: Vec::new(),
            next_id: 1,
            next_epoch: 1,
            time_scale: 1.0,
            clock: 0.0,
            generation: 0,
            sim_rate: 0.0,
            limited_by: None,
            at_end: AtEnd::Stop,
            ended: false,
        };
        if let Some(first) = session.catalog.first().cloned() {
            // A bad command-line scene was reported by the CLI already; leave it empty.
            let _ = session.load(&first.name, &first.text);
        }
        session
    }

    /// The messages a new connection starts with: welcome, scene, panels.
    pub fn greeting(&self) -> Vec<ServerMessage> {
        let mut out = vec![ServerMessage::Welcome(Welcome {
            protocol: PROTOCOL_VERSION,
            scenes: self.catalog.names(),
            integrators: IntegratorKind::ALL
                .iter()
                .map(|k| IntegratorInfo {
                    name: k.name().into(),
                    order: k.order(),
                    symplectic: k.symplectic(),
                    adaptive: k.is_adaptive(),
                    needs_constraints: k.needs_constraints(),
                    description: k.describe(),
                })
                .collect(),
            methods: vec!["implicit".into(), "parametric".into()],
            limits: self.limits,
        })];
        out.extend(self.scene_messages());
        out
    }

    fn scene_messages(&self) -> Vec<ServerMessage> {
        let mut out = Vec::new();
        if let Some(scene) = &self.scene {
            out.push(ServerMessage::Scene(scene.info.clone()));
        }
        out.push(self.panels_message());
        out
    }

    fn panels_message(&self) -> ServerMessage {
        ServerMessage::Panels {
            panels: self.panels.iter().map(Panel::info).collect(),
        }
    }

    /// The current state of every panel, with each panel's distance to the first panel when
    /// both are at the same t.
    pub fn frame(&mut self) -> ServerMessage {
        let mut panels: Vec<PanelFrame> = self.panels.iter_mut().map(Panel::frame).collect();
        if let Some((first, others)) = self.panels.split_first() {
            for (frame, other) in panels.iter_mut().skip(1).zip(others) {
                frame.distance = distance(first, other);
            }
        }
        ServerMessage::Frame {
            time_scale: self.time_scale,
            clock: Clock {
                generation: self.generation,
                sim_rate: self.sim_rate,
                limited_by: self.limited_by,
                end: self.end(),
                at_end: self.at_end,
                ended: self.ended,
            },
            panels,
        }
    }

    /// The restart count ([`Clock::generation`]).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Every panel restarted (or a new set of panels): the clock starts again at 0.
    fn restarted(&mut self) {
        self.generation += 1;
        self.clock = 0.0;
        self.limited_by = None;
        self.ended = false;
    }

    /// The scene's end ([`Clock::end`]): the time at which `bead run` ends its run.
    pub fn end(&self) -> Option<f64> {
        self.scene.as_ref()?.end
    }

    /// Restart every panel but those at `except` (rebuilt already) from the scene's initial
    /// state, in new epochs: the panels share one clock.
    fn restart_others(&mut self, except: &[usize]) {
        for index in 0..self.panels.len() {
            if !except.contains(&index) {
                let epoch = self.epoch();
                self.panels[index].reset(epoch);
            }
        }
        self.restarted();
    }

    /// Number of panels.
    pub fn panel_count(&self) -> usize {
        self.panels.len()
    }

    /// A fresh epoch (unique within the session).
    fn epoch(&mut self) -> u64 {
        let epoch = self.next_epoch;
        self.next_epoch += 1;
        epoch
    }

    /// Advance the running panels by `elapsed` wall seconds (times the time scale), within the
    /// per-frame step limit and compute budget, on one clock: every running panel advances
    /// to the same simulated time. When one cannot get there, the clock stops at the
    /// earliest time a running panel reached (all panels slow together; the others wait
    /// there) and the frame names that panel ([`Clock::limited_by`]).
    ///
    /// A frame advances the clock by at most 0.1 s of wall time (a server that was held up
    /// does not make up for it); the simulation rate is measured against the whole
    /// `elapsed`, so that it tells how the simulation kept up with real time, however
    /// loaded the machine.
    pub fn advance(&mut self, elapsed: f64) {
        let wall = elapsed.max(0.0);
        let elapsed = elapsed.clamp(0.0, 0.1);
        let active = |p: &&Panel| p.running && !p.failed();
        let running = self.panels.iter().filter(active).count() as u64;
        if running == 0 {
            self.sim_rate = 0.0;
            self.limited_by = None;
            return;
        }
        let earliest = |panels: &[Panel]| {
            panels
                .iter()
                .filter(active)
                .map(Panel::t)
                .fold(f64::INFINITY, f64::min)
        };
        // A panel resumed or stepped on its own is caught up with, not overtaken.
        self.clock = self.clock.max(earliest(&self.panels));
        let start = self.clock;
        let mut target = start + self.time_scale * elapsed;
        // The scene's end holds the clock there (unless it goes on past it).
        let end = self.end().filter(|_| self.at_end != AtEnd::Continue);
        let at_end = end.is_some_and(|end| target >= end);
        if let Some(end) = end {
            target = target.min(end);
        }
        let max_steps = (self.limits.max_steps_per_frame / running).max(1);
        let budget = FRAME_BUDGET / running as u32;
        // The first panel that could not get there, and the earliest time such a panel
        // reached (a panel of a coarser dt short of the target by less than its dt is not
        // behind: it waits for its next whole step).
        let mut limited = None;
        let mut reached = f64::INFINITY;
        for panel in &mut self.panels {
            if !panel.advance_until(target, max_steps, budget) {
                limited.get_or_insert(panel.id);
                reached = reached.min(panel.t());
            }
        }
        self.limited_by = limited;
        // Do not try to catch up later: fall behind real time instead, all together.
        self.clock = if reached.is_finite() { reached } else { target };
        // Every running panel has taken its last whole step within the end.
        if at_end && limited.is_none() {
            match self.at_end {
                AtEnd::Stop => {
                    for panel in &mut self.panels {
                        panel.running = false;
                    }
                    self.ended = true;
                }
                AtEnd::Loop => {
                    self.restart_others(&[]);
                    for panel in &mut self.panels {
                        panel.running = !panel.failed();
                    }
                }
                AtEnd::Continue => {}
            }
        }
        if wall > 0.0 {
            let rate = ((self.clock - start) / wall).max(0.0);
            self.sim_rate = if self.sim_rate > 0.0 {
                0.9 * self.sim_rate + 0.1 * rate
            } else {
                rate
            };
        }
    }

    /// Handle one client message; returns the replies (besides frames).
    pub fn handle(&mut self, message: ClientMessage) -> Vec<ServerMessage> {
        let kind = message.kind();
        match self.apply(message) {
            Ok(replies) => replies,
            Err((error, panel)) => vec![ServerMessage::Error {
                code: error.code(),
                message: error.to_string(),
                request: Some(kind.into()),
                panel,
            }],
        }
    }

    /// Handle one message as the page sends it (JSON text): parsed within the session's
    /// limits, then [`Session::handle`]; a message that does not parse gets its error reply.
    /// Every transport (the server's WebSocket, the page's own engine) goes through here.
    pub fn handle_text(&mut self, text: &str) -> Vec<ServerMessage> {
        match parse_client_message(text, &self.limits) {
            Ok(message) => self.handle(message),
            Err(e) => vec![ServerMessage::Error {
                code: e.code(),
                message: e.to_string(),
                request: message_type(text),
                panel: None,
            }],
        }
    }

    /// One tick of the page's clock: [`Session::advance`] by `elapsed` wall seconds, then
    /// the frame, encoded (`None` if it could not be encoded).
    pub fn tick(&mut self, elapsed: f64) -> Option<Encoded> {
        self.advance(elapsed);
        self.frame().encode().ok()
    }

    fn scene(&self) -> Result<&CurrentScene, Rejection> {
        self.scene.as_ref().ok_or((SessionError::NoScene, None))
    }

    fn apply(&mut self, message: ClientMessage) -> Result<Vec<ServerMessage>, Rejection> {
        match message {
            ClientMessage::AddPanel(patch) => {
                if self.panels.len() >= self.limits.max_panels {
                    return Err((SessionError::TooManyPanels(self.limits.max_panels), None));
                }
                let current = self.scene()?;
                let (scene, view) = (Arc::clone(&current.scene), current.info.view);
                let defaults = default_settings(&scene, None);
                let settings =
                    patch_settings(defaults, &patch, &self.limits).map_err(|e| (e, None))?;
                let epoch = self.epoch();
                let mut panel = Panel::new(self.next_id, epoch, settings, scene, view)
                    .map_err(|e| (e.into(), None))?;
                panel.running = self.panels.iter().any(|p| p.running);
                self.next_id += 1;
                self.panels.push(panel);
                // One clock: the others start again with the new panel.
                let new = self.panels.len() - 1;
                self.restart_others(&[new]);
                Ok(vec![self.panels_message()])
            }
            ClientMessage::RemovePanel { panel } => {
                let index = self.index(panel)?;
                self.panels.remove(index);
                Ok(vec![self.panels_message()])
            }
            ClientMessage::ConfigurePanel { panel, settings } => {
                let index = self.index(panel)?;
                let old = &self.panels[index];
                let view = old.info().view;
                let new_settings = patch_settings(old.settings(), &settings, &self.limits)
                    .map_err(|e| (e, Some(panel)))?;
                // The panel keeps its own scene, with its curve edits.
                let scene = Arc::clone(old.scene());
                let running = old.running;
                let note = old.curve_note.clone();
                let epoch = self.epoch();
                let mut rebuilt = Panel::new(panel, epoch, new_settings, scene, view)
                    .map_err(|e| (e.into(), Some(panel)))?;
                rebuilt.running = running && !rebuilt.failed();
                rebuilt.curve_note = note;
                self.panels[index] = rebuilt;
                self.restart_others(&[index]);
                Ok(vec![self.panels_message()])
            }
            ClientMessage::Play { panel } => {
                // Stopped at the end: Play starts again from the start.
                if self.ended {
                    self.restart_others(&[]);
                }
                for p in self.targets(panel)? {
                    p.running = !p.failed();
                }
                Ok(Vec::new())
            }
            ClientMessage::Pause { panel } => {
                for p in self.targets(panel)? {
                    p.running = false;
                }
                Ok(Vec::new())
            }
            ClientMessage::Step { panel } => {
                let mut failed = None;
                for p in self.targets(panel)? {
                    if p.failed() {
                        p.running = false;
                        continue;
                    }
                    let id = p.id;
                    if let Err(failure) = p.single_step() {
                        failed.get_or_insert((id, failure.to_string()));
                    }
                }
                match failed {
                    None => Ok(Vec::new()),
                    Some((id, message)) => Err((SessionError::StepFailed { message }, Some(id))),
                }
            }
            ClientMessage::Reset { panel } => {
                // One clock: a reset restarts every panel (a `panel` must still exist).
                if let Some(id) = panel {
                    self.index(id)?;
                }
                self.restart_others(&[]);
                Ok(vec![self.panels_message()])
            }
            ClientMessage::SetTimeScale { scale } => {
                let max = self.limits.max_time_scale;
                if !(scale.is_finite() && (0.0..=max).contains(&scale)) {
                    return Err((
                        SessionError::OutOfRange {
                            name: "time scale",
                            min: 0.0,
                            max,
                        },
                        None,
                    ));
                }
                self.time_scale = scale;
                Ok(Vec::new())
            }
            ClientMessage::SetAtEnd { at_end } => {
                self.at_end = at_end;
                // Going on past the end: Play resumes from where the panels stopped.
                if at_end == AtEnd::Continue {
                    self.ended = false;
                }
                Ok(Vec::new())
            }
            ClientMessage::LoadScene {
                name,
                toml,
                file_name,
            } => {
                let (name, text) = match (name, toml) {
                    (Some(name), None) => {
                        let scene = self.catalog.get(&name).ok_or_else(|| {
                            (
                                SessionError::UnknownScene {
                                    name: truncate(&name, 80),
                                    known: self.catalog.names(),
                                },
                                None,
                            )
                        })?;
                        (scene.name.clone(), scene.text.clone())
                    }
                    (None, Some(text)) => {
                        let name = file_name
                            .map(|f| truncate(&f, 120))
                            .filter(|f| !f.is_empty())
                            .unwrap_or_else(|| "scene.toml".into());
                        (name, text)
                    }
                    _ => return Err((SessionError::SceneSource, None)),
                };
                match self.load(&name, &text) {
                    Ok(()) => Ok(self.scene_messages()),
                    Err(e) => Ok(vec![ServerMessage::SceneError {
                        message: e.render(),
                        line: e.line,
                        column: e.column,
                    }]),
                }
            }
            ClientMessage::SetCurve {
                panel,
                constraint,
                expr,
            } => self.set_curve(panel, constraint, expr),
            ClientMessage::DragStart {
                panel,
                particle,
                target,
            } => {
                let index = self.index(panel)?;
                self.panels[index]
                    .drag_start(particle, target)
                    .map_err(|e| (e.into(), Some(panel)))?;
                Ok(Vec::new())
            }
            ClientMessage::DragMove { panel, target } => {
                let index = self.index(panel)?;
                self.panels[index]
                    .drag_move(target)
                    .map_err(|e| (e.into(), Some(panel)))?;
                Ok(Vec::new())
            }
            ClientMessage::DragEnd { panel } => {
                let index = self.index(panel)?;
                self.panels[index].drag_end();
                Ok(Vec::new())
            }
            ClientMessage::SetParam { name, value, expr } => {
                let value = match (value, expr) {
                    (Some(value), None) => value,
                    (None, Some(expr)) => constant_value(&name, &expr).map_err(|e| (e, None))?,
                    _ => return Err((SessionError::ParamSource, None)),
                };
                self.set_param(&name, value)
            }
            ClientMessage::SetStart {
                panel,
                particle,
                target,
            } => self.set_start(panel, particle, target),
            ClientMessage::SetStartState {
                panel,
                positions,
                velocities,
            } => {
                let panel = match panel {
                    Some(id) => id,
                    None => self
                        .panels
                        .first()
                        .map(|p| p.id)
                        .ok_or((SessionError::NoPanels, None))?,
                };
                self.set_start_state(panel, positions, velocities)
            }
            ClientMessage::SetView { panel, view } => {
                // A hint about what a page shows: one for a panel replaced meanwhile (a scene
                // load crossed it) is dropped without an error.
                let Ok(index) = self.index(panel) else {
                    return Ok(Vec::new());
                };
                let [x0, y0, x1, y1] = view;
                let sane = |v: f64| v.is_finite() && v.abs() <= 1e12;
                if !(view.iter().all(|&v| sane(v)) && x1 > x0 && y1 > y0) {
                    return Err((SessionError::Region { view }, Some(panel)));
                }
                self.panels[index].set_region(view);
                Ok(Vec::new())
            }
            ClientMessage::Equations { panel } => {
                let index = self.index(panel)?;
                let p = &self.panels[index];
                Ok(vec![ServerMessage::Equations {
                    panel,
                    method: p.method().name().into(),
                    text: bead::describe::equations(&p.scene().system, p.method(), 200),
                    mathml: bead::describe::equations_mathml(&p.scene().system, p.method(), 12),
                }])
            }
        }
    }

    /// Reload the scene with one parameter changed and restart every panel with its
    /// settings; nothing changes when the value is out of range or a panel cannot start.
    fn set_param(&mut self, name: &str, value: f64) -> Result<Vec<ServerMessage>, Rejection> {
        let current = self.scene()?;
        let Some(range) = current.params.iter().find(|p| p.name == name) else {
            return Err((
                SessionError::UnknownParam {
                    name: truncate(name, 80),
                    known: current.params.iter().map(|p| p.name.clone()).collect(),
                },
                None,
            ));
        };
        if let Some(expr) = &range.derived {
            return Err((
                SessionError::DerivedParam {
                    name: range.name.clone(),
                    expr: expr.clone(),
                    from: range.depends_on.clone(),
                },
                None,
            ));
        }
        let within = !range.bounded || (value >= range.min && value <= range.max);
        if !(value.is_finite() && value.abs() <= 1e12 && within) {
            let (min, max) = if range.bounded {
                (range.min, range.max)
            } else {
                (-1e12, 1e12)
            };
            return Err((
                SessionError::ParamRange {
                    name: range.name.clone(),
                    min,
                    max,
                },
                None,
            ));
        }
        if range.integer && value.fract() != 0.0 {
            return Err((
                SessionError::ParamWhole {
                    name: range.name.clone(),
                    value,
                },
                None,
            ));
        }
        let params = current.params.clone();
        let scene = current
            .scene
            .with_param(name, value)
            .map_err(|e| (SessionError::ParamFailed(e.to_string()), None))?;
        let scene = Arc::new(scene);
        let mut info = scene_info(&current.info.name, &scene);
        info.params = params_with_ranges(&scene, &params);
        let view = info.view;
        // Every panel again, with its settings, on the new scene (curve edits of single
        // panels are dropped: the scene's own expressions follow the parameter).
        let mut rebuilt = Vec::new();
        for old in &self.panels {
            let epoch = self.next_epoch + rebuilt.len() as u64;
            let mut panel = Panel::new(old.id, epoch, old.settings(), Arc::clone(&scene), view)
                .map_err(|e| (SessionError::from(e), Some(old.id)))?;
            if let Some(failure) = panel.failure() {
                return Err((
                    SessionError::ParamFailed(format!("panel {}: {failure}", old.id)),
                    Some(old.id),
                ));
            }
            panel.running = old.running;
            rebuilt.push(panel);
        }
        self.next_epoch += rebuilt.len() as u64;
        self.panels = rebuilt;
        // Widened ranges stay widened.
        let params = info.params.clone();
        self.scene = Some(CurrentScene::new(scene, info, params));
        self.restarted();
        Ok(self.scene_messages())
    }

    /// A new start state: particle `particle` of panel `panel` at `target`, the others where
    /// that panel has them, at rest, moved onto the point of the constraints closest to that
    /// ([`Panel::closest_start`]); every panel restarts from that point, or none does.
    fn set_start(
        &mut self,
        panel: u32,
        particle: usize,
        target: Vec<f64>,
    ) -> Result<Vec<ServerMessage>, Rejection> {
        let index = self.index(panel)?;
        let source = &self.panels[index];
        let dim = source.scene().system.dim();
        let mut x = source.positions().to_vec();
        let count = x.len() / dim.max(1);
        if particle >= count {
            return Err((
                SessionError::Drag(DragError::NoParticle { particle, count }),
                Some(panel),
            ));
        }
        let mut target = target;
        if target.len() == 2 && dim == 3 {
            target.push(x[particle * dim + 2]);
        }
        if target.len() != dim {
            return Err((
                SessionError::Drag(DragError::TargetDimension {
                    dim,
                    got: target.len(),
                }),
                Some(panel),
            ));
        }
        if target.iter().any(|v| !v.is_finite() || v.abs() > 1e12) {
            return Err((SessionError::Drag(DragError::TargetRange), Some(panel)));
        }
        x[particle * dim..(particle + 1) * dim].copy_from_slice(&target);
        // The start, computed once and given to every panel: the point of the constraints
        // closest to the drop (each form would find the same from the drop; handing them
        // this point makes it so by construction).
        let start = source.closest_start(&x).map_err(|message| {
            (
                SessionError::StartFailed {
                    panel,
                    method: source.method().name(),
                    message,
                },
                Some(panel),
            )
        })?;
        let placed = start[particle * dim..(particle + 1) * dim].to_vec();
        let moved = placed
            .iter()
            .zip(&target)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        let mut rebuilt = Vec::new();
        for (k, old) in self.panels.iter().enumerate() {
            let epoch = self.next_epoch + k as u64;
            match old.restarted_at_rest(epoch, &start) {
                Ok(panel) => rebuilt.push(panel),
                Err(message) => {
                    return Err((
                        SessionError::StartFailed {
                            panel: old.id,
                            method: old.method().name(),
                            message,
                        },
                        Some(old.id),
                    ))
                }
            }
        }
        self.next_epoch += rebuilt.len() as u64;
        self.panels = rebuilt;
        self.restarted();
        Ok(vec![
            ServerMessage::StartPlaced {
                panel,
                particle,
                dropped: target,
                placed,
                moved,
                positions: start,
            },
            self.panels_message(),
        ])
    }

    /// A new start state from typed or dragged positions and velocities: panel `panel`
    /// places them on its constraints, every panel restarts from the placed state (the same
    /// for both forms), or none does.
    fn set_start_state(
        &mut self,
        panel: u32,
        positions: Option<Vec<f64>>,
        velocities: Option<Vec<f64>>,
    ) -> Result<Vec<ServerMessage>, Rejection> {
        let index = self.index(panel)?;
        let source = &self.panels[index];
        let n = source.positions().len();
        for (what, values) in [("positions", &positions), ("velocities", &velocities)] {
            if let Some(values) = values {
                if values.len() != n {
                    return Err((
                        SessionError::StateValues {
                            what,
                            expected: n,
                            got: values.len(),
                        },
                        Some(panel),
                    ));
                }
                if values.iter().any(|v| !v.is_finite() || v.abs() > 1e12) {
                    return Err((SessionError::Drag(DragError::TargetRange), Some(panel)));
                }
            }
        }
        let request = StateRequest {
            positions: Some(positions.unwrap_or_else(|| source.positions().to_vec())),
            velocities: Some(velocities.unwrap_or_else(|| source.velocities().to_vec())),
            ..StateRequest::default()
        };
        let failed = |p: &Panel, message: String| {
            (
                SessionError::StartFailed {
                    panel: p.id,
                    method: p.method().name(),
                    message,
                },
                Some(p.id),
            )
        };
        let (first, placed) = source
            .restarted_from(self.next_epoch + index as u64, &request)
            .map_err(|m| failed(source, m))?;
        // The others start from the placed state, on the constraints already.
        let start = StateRequest {
            positions: Some(placed.positions.clone()),
            velocities: Some(placed.velocities.clone()),
            ..StateRequest::default()
        };
        let mut rebuilt = Vec::new();
        let mut first = Some(first);
        for (k, old) in self.panels.iter().enumerate() {
            if k == index {
                rebuilt.push(first.take().expect("once"));
                continue;
            }
            let (panel, _) = old
                .restarted_from(self.next_epoch + k as u64, &start)
                .map_err(|m| failed(old, m))?;
            rebuilt.push(panel);
        }
        self.next_epoch += rebuilt.len() as u64;
        self.panels = rebuilt;
        self.restarted();
        Ok(vec![
            ServerMessage::StateSet {
                panel,
                positions: placed.positions,
                velocities: placed.velocities,
                position_moved: placed.position_moved,
                velocity_moved: placed.velocity_moved,
            },
            self.panels_message(),
        ])
    }

    fn index(&self, panel: u32) -> Result<usize, Rejection> {
        self.panels
            .iter()
            .position(|p| p.id == panel)
            .ok_or((SessionError::NoPanel(panel), Some(panel)))
    }

    fn targets(&mut self, panel: Option<u32>) -> Result<Vec<&mut Panel>, Rejection> {
        match panel {
            None => Ok(self.panels.iter_mut().collect()),
            Some(id) => {
                let index = self.index(id)?;
                Ok(vec![&mut self.panels[index]])
            }
        }
    }

    /// Load a scene text and replace the panels by its default panels.
    fn load(&mut self, name: &str, text: &str) -> Result<(), SceneError> {
        let scene = Arc::new(parse_scene(text, name)?);
        let info = scene_info(name, &scene);
        let view = info.view;
        let mut methods = Vec::new();
        if info.has_implicit || !info.has_parametric {
            methods.push(Method::Implicit);
        }
        if info.has_parametric {
            methods.push(Method::Parametric);
        }
        let mut panels = Vec::new();
        for (k, method) in methods.into_iter().enumerate() {
            let settings = default_settings(&scene, Some(method));
            let epoch = self.next_epoch + k as u64;
            let mut panel = Panel::new(
                self.next_id + k as u32,
                epoch,
                settings,
                Arc::clone(&scene),
                view,
            )
            .map_err(|e| SceneError {
                file: name.to_string(),
                line: 0,
                column: 0,
                message: e.to_string(),
                snippet: None,
            })?;
            // A scene starts playing, as in the article.
            panel.running = !panel.failed();
            panels.push(panel);
        }
        self.next_id += panels.len() as u32;
        self.next_epoch += panels.len() as u64;
        self.panels = panels;
        let params = info.params.clone();
        self.scene = Some(CurrentScene::new(scene, info, params));
        self.restarted();
        Ok(())
    }

    fn set_curve(
        &mut self,
        panel: Option<u32>,
        constraint: usize,
        expr: String,
    ) -> Result<Vec<ServerMessage>, Rejection> {
        let reply = |failure: CurveFailure| {
            Ok(vec![ServerMessage::CurveError {
                constraint,
                code: failure.code(),
                message: failure.message(),
                columns: failure.columns(&expr),
            }])
        };
        let chars = expr.chars().count();
        if chars > self.limits.max_expr_chars {
            return reply(CurveFailure::TooLong {
                chars,
                limit: self.limits.max_expr_chars,
            });
        }
        let indices: Vec<usize> = match panel {
            Some(id) => {
                let index = self.index(id)?;
                if self.panels[index].method() != Method::Implicit {
                    return reply(CurveFailure::ParametricPanel);
                }
                vec![index]
            }
            None => (0..self.panels.len())
                .filter(|&i| self.panels[i].method() == Method::Implicit)
                .collect(),
        };
        if indices.is_empty() {
            // The expression's own errors come first: they are what the user can fix here.
            if let Err(e) = self.scene()?.scene.with_constraint_expr(constraint, &expr) {
                return reply(CurveFailure::Edit(e));
            }
            return reply(CurveFailure::NoImplicitPanel);
        }
        // Build every new panel first; replace them only when all succeeded. Panels that
        // share a scene share its edited copy.
        // The view box is made again for the new curve, so that the page refits to it.
        let mut edited: Vec<(Arc<Scene>, Arc<Scene>, [f64; 4])> = Vec::new();
        let mut rebuilt = Vec::new();
        for &index in &indices {
            let old = &self.panels[index];
            let (scene, view) = match edited
                .iter()
                .find(|(from, _, _)| Arc::ptr_eq(from, old.scene()))
            {
                Some((_, to, view)) => (Arc::clone(to), *view),
                None => match old.scene().with_constraint_expr(constraint, &expr) {
                    Ok(scene) => {
                        let scene = Arc::new(scene);
                        let view = scene_view(&scene);
                        edited.push((Arc::clone(old.scene()), Arc::clone(&scene), view));
                        (scene, view)
                    }
                    Err(e) => return reply(CurveFailure::Edit(e)),
                },
            };
            let (id, settings, running) = (old.id, old.settings(), old.running);
            let epoch = self.epoch();
            let mut panel = match Panel::new(id, epoch, settings, scene, view) {
                Ok(panel) => panel,
                Err(e) => return reply(CurveFailure::Setup(e.into())),
            };
            if let Some(failure) = panel.failure() {
                let message = match failure {
                    PanelFailure::Start(RunError::Step(e)) => e.to_string(),
                    other => other.to_string(),
                };
                return reply(CurveFailure::Start(message));
            }
            panel.running = running;
            rebuilt.push((index, panel));
        }
        for (index, panel) in rebuilt {
            self.panels[index] = panel;
        }
        self.restart_others(&indices);
        // Panels left as they were say so: a parametric panel's curve is its map x(q).
        if panel.is_none() {
            for (index, other) in self.panels.iter_mut().enumerate() {
                if !indices.contains(&index) {
                    other.curve_note = Some(format!(
                        "curve edit not applied here: this panel's curve is its map x(q) ([parametric.positions] of the scene file), which still runs `{}` unchanged",
                        other
                            .scene()
                            .system
                            .declared_constraints()
                            .get(constraint)
                            .and_then(|c| c.source())
                            .unwrap_or("the original constraint")
                    ));
                }
            }
        }
        Ok(vec![self.panels_message()])
    }
}

/// What the page draws of a scene that does not move: the [`ServerMessage::Scene`] a session
/// sends for `scene` loaded as `name`. Needs no simulation (the view box of a large scene is
/// bounded work, see [`geometry::view_box`]), so a test can show the page a scene without
/// running it.
pub fn scene_info(name: &str, scene: &Scene) -> SceneInfo {
    let system = &scene.system;
    let declared = system.declared_constraints();
    let constraints = declared
        .iter()
        .enumerate()
        .map(|(index, c)| ConstraintInfo {
            name: c.name().to_string(),
            description: system.constraint_description(index),
            expr: c.source().map(str::to_string),
        })
        .collect();
    let rods: Vec<Rod> = declared
        .iter()
        .filter_map(|c| match c {
            DeclaredConstraint::Distance { a, b, .. } => Some(match b {
                Endpoint::Particle(b) => Rod {
                    a: a.0,
                    b: Some(b.0),
                    anchor: None,
                },
                Endpoint::Fixed(point) => Rod {
                    a: a.0,
                    b: None,
                    anchor: Some(point.to_vec()),
                },
            }),
            _ => None,
        })
        .collect();
    let pins: Vec<Pin> = declared
        .iter()
        .filter_map(|c| match c {
            DeclaredConstraint::Pin {
                particle, anchor, ..
            } if anchor.len() >= 2 => Some(Pin {
                particle: particle.0,
                anchor: anchor.to_vec(),
            }),
            _ => None,
        })
        .collect();
    SceneInfo {
        name: name.to_string(),
        title: scene.title.clone(),
        about: scene.about.clone(),
        energy_unit: scene.units.as_deref().map(|u| {
            if u.eq_ignore_ascii_case("SI") {
                "J".to_string()
            } else {
                format!("kg {u}^2/s^2")
            }
        }),
        length_unit: scene.units.as_deref().map(|u| {
            if u.eq_ignore_ascii_case("SI") {
                "m".to_string()
            } else {
                u.to_string()
            }
        }),
        dim: system.dim(),
        gravity: system.gravity().to_vec(),
        particles: system
            .particles()
            .iter()
            .map(|p| ParticleInfo {
                name: p.name.clone(),
                mass: p.mass,
            })
            .collect(),
        constraints,
        view: scene_view(scene),
        rods,
        pins,
        has_implicit: system.constraints().n_rows() > 0,
        has_parametric: system.parametric().is_some(),
        warnings: scene.warnings(),
        params: scene
            .params
            .iter()
            .map(|(name, value)| {
                let spec = scene.param_specs.iter().find(|s| s.name == *name);
                let integer = spec.is_some_and(|s| s.integer);
                let range = spec.and_then(|s| s.range);
                let (min, max) = match range {
                    Some([lo, hi]) => (lo, hi),
                    None => default_param_range(*value, integer),
                };
                let derived = spec
                    .filter(|s| !s.depends_on.is_empty())
                    .and_then(|s| s.expr.clone());
                ParamInfo {
                    name: name.clone(),
                    value: *value,
                    min,
                    max,
                    bounded: range.is_some(),
                    integer,
                    unit: spec.and_then(|s| s.unit.clone()),
                    description: spec.and_then(|s| s.description.clone()),
                    depends_on: if derived.is_some() {
                        spec.map(|s| s.depends_on.clone()).unwrap_or_default()
                    } else {
                        Vec::new()
                    },
                    derived,
                }
            })
            .collect(),
    }
}

/// The value of `expr`, an expression of numbers, pi and e typed for parameter `name`.
fn constant_value(name: &str, expr: &str) -> Result<f64, SessionError> {
    let failed = |message: String| SessionError::ParamExpr {
        name: truncate(name, 80),
        message,
    };
    if expr.chars().count() > 200 {
        return Err(failed(
            "the expression is longer than 200 characters".into(),
        ));
    }
    // The parser knows pi and e itself; any other name is not a constant.
    let resolve = |word: &str| -> Result<bead::expr::Resolved, String> {
        Err(format!(
            "unknown name `{}`; a typed value may use numbers, pi and e",
            truncate(word, 40)
        ))
    };
    let parsed = bead::expr::parse(expr, &resolve).map_err(|e| failed(e.to_string()))?;
    let value = parsed.eval(&[]);
    if value.is_finite() {
        Ok(value)
    } else {
        Err(failed(format!(
            "`{}` is not a finite number",
            truncate(expr, 80)
        )))
    }
}

/// The scene's current parameter values with the ranges of `first` (as first loaded); an
/// unbounded range widened to hold a value typed beyond it.
fn params_with_ranges(scene: &Scene, first: &[ParamInfo]) -> Vec<ParamInfo> {
    first
        .iter()
        .map(|p| {
            let value = scene
                .params
                .iter()
                .find(|(n, _)| *n == p.name)
                .map(|(_, v)| *v)
                .unwrap_or(p.value);
            let (min, max) = if p.bounded {
                (p.min, p.max)
            } else {
                (p.min.min(value), p.max.max(value))
            };
            ParamInfo {
                value,
                min,
                max,
                ..p.clone()
            }
        })
        .collect()
}

/// max over particles of |x_a - x_b| between two panels at the same t, when they are.
fn distance(a: &Panel, b: &Panel) -> Option<f64> {
    let (ta, tb) = (a.t(), b.t());
    if (ta - tb).abs() > 1e-9 * ta.abs().max(1.0) {
        return None;
    }
    let (xa, xb) = (a.positions(), b.positions());
    let dim = a.scene().system.dim();
    if xa.len() != xb.len() || dim == 0 {
        return None;
    }
    let d = crate::panel::largest_distance(xa, xb, dim);
    d.is_finite().then_some(d)
}

/// The view box of `scene` ([`geometry::view_box`]): its initial state, its fixed points
/// (rods' anchors and pins, so that a pendulum's pivot is always in view), its closed
/// curves and the motion of a short trial run at the scene's dt.
pub fn scene_view(scene: &Scene) -> [f64; 4] {
    let anchors: Vec<[f64; 2]> = scene
        .system
        .declared_constraints()
        .iter()
        .filter_map(|c| match c {
            DeclaredConstraint::Distance {
                b: Endpoint::Fixed(point),
                ..
            } if point.len() >= 2 => Some([point[0], point[1]]),
            DeclaredConstraint::Pin { anchor, .. } if anchor.len() >= 2 => {
                Some([anchor[0], anchor[1]])
            }
            _ => None,
        })
        .collect();
    let dt = scene.run.dt.unwrap_or(1.0 / 60.0);
    let duration = scene
        .run
        .duration
        .or(scene.run.steps.map(|s| s as f64 * dt))
        .unwrap_or(10.0);
    geometry::view_box(&scene.system, dt, duration, &anchors)
}

/// The scene's defaults for a panel of `method` (default: the scene's run method, else the
/// first formulation it has).
fn default_settings(scene: &Scene, method: Option<Method>) -> PanelSettings {
    let system = &scene.system;
    let method = method.or(scene.run.method).unwrap_or(
        if system.constraints().n_rows() > 0 || system.parametric().is_none() {
            Method::Implicit
        } else {
            Method::Parametric
        },
    );
    let mut integrator = scene.run.integrator.unwrap_or(IntegratorKind::Rk4);
    if integrator.needs_constraints() && method != Method::Implicit {
        integrator = IntegratorKind::Rk4;
    }
    let feedback = match method {
        Method::Implicit => scene.run.stabilize.unwrap_or_default(),
        Method::Parametric => Default::default(),
    };
    PanelSettings {
        method,
        integrator,
        dt: scene.run.dt.unwrap_or(1.0 / 60.0),
        ks: feedback.ks,
        kd: feedback.kd,
        project: false,
        reference: false,
    }
}

/// `base` with the fields of `patch`, each in its range. Whether the combination can run is
/// the library's [`bead::simulate::SimulationConfig::check`], when the panel is built.
fn patch_settings(
    base: PanelSettings,
    patch: &PanelSettingsPatch,
    limits: &Limits,
) -> Result<PanelSettings, SessionError> {
    let mut s = base;
    if let Some(method) = &patch.method {
        s.method = method
            .parse()
            .map_err(|e: String| SessionError::UnknownName(truncate(&e, 200)))?;
        // Switching to the parametric form drops what only the implicit one has, unless the
        // request asks for it (then the library refuses the combination).
        if s.method == Method::Parametric && patch.ks.is_none() && patch.kd.is_none() {
            s.ks = 0.0;
            s.kd = 0.0;
        }
        if s.method == Method::Parametric && patch.project.is_none() {
            s.project = false;
        }
    }
    if let Some(integrator) = &patch.integrator {
        s.integrator = integrator
            .parse()
            .map_err(|e: String| SessionError::UnknownName(truncate(&e, 300)))?;
    }
    if let Some(dt) = patch.dt {
        if !(dt.is_finite() && dt >= limits.min_dt && dt <= limits.max_dt) {
            return Err(SessionError::OutOfRange {
                name: "dt",
                min: limits.min_dt,
                max: limits.max_dt,
            });
        }
        s.dt = dt;
    }
    for (name, value, slot) in [("ks", patch.ks, &mut s.ks), ("kd", patch.kd, &mut s.kd)] {
        if let Some(v) = value {
            if !(v.is_finite() && (0.0..=limits.max_feedback).contains(&v)) {
                return Err(SessionError::OutOfRange {
                    name,
                    min: 0.0,
                    max: limits.max_feedback,
                });
            }
            *slot = v;
        }
    }
    if let Some(project) = patch.project {
        s.project = project;
    }
    if let Some(reference) = patch.reference {
        s.reference = reference;
    }
    Ok(s)
}

fn truncate(s: &str, max: usize) -> String {
    if s.chars().count() <= max {
        s.to_string()
    } else {
        s.chars().take(max).collect::<String>() + "…"
    }
}
