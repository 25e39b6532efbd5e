//! One connection's state: the current scene, its panels and the time scale; handles client
//! messages and advances the panels frame by frame. Independent of the network, so that it
//! can be tested directly.

use std::sync::Arc;
use std::time::Duration;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::{Scene, SceneError};

use crate::geometry;
use crate::panel::{validate_combination, Panel, PanelSettings};
use crate::protocol::{
    ClientMessage, ConstraintInfo, IntegratorInfo, Limits, PanelSettingsPatch, ParticleInfo, Rod,
    SceneInfo, ServerMessage, Welcome, PROTOCOL_VERSION,
};
use crate::scenes::Catalog;

/// Compute time allowed for stepping per frame, over all panels.
const FRAME_BUDGET: Duration = Duration::from_millis(25);

/// The loaded scene, shared by the panels (each may have its own curve edits).
struct CurrentScene {
    name: String,
    text: Arc<str>,
    scene: Scene,
    info: SceneInfo,
    /// `[[constraint]]` expressions as in the file.
    exprs: Vec<Option<String>>,
}

/// A connection's session.
pub struct Session {
    catalog: Arc<Catalog>,
    limits: Limits,
    scene: Option<CurrentScene>,
    panels: Vec<Panel>,
    next_id: u32,
    time_scale: f64,
}

/// Parse a scene, refusing more particles than any session allows and never panicking.
pub(crate) fn parse_scene(text: &str, file: &str) -> Result<Scene, SceneError> {
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

impl Session {
    /// A session with the catalog's first scene loaded and its default panels.
    pub fn new(catalog: Arc<Catalog>, limits: Limits) -> Session {
        let mut session = Session {
            catalog,
            limits,
            scene: None,
            panels: Vec::new(),
            next_id: 1,
            time_scale: 1.0,
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

    /// The current state of every panel.
    pub fn frame(&self) -> ServerMessage {
        ServerMessage::Frame {
            time_scale: self.time_scale,
            panels: self.panels.iter().map(Panel::frame).collect(),
        }
    }

    /// Number of panels.
    pub fn panel_count(&self) -> usize {
        self.panels.len()
    }

    /// Advance the running panels by `elapsed` wall seconds (times the time scale), within the
    /// per-frame step limit and compute budget.
    pub fn advance(&mut self, elapsed: f64) {
        let elapsed = elapsed.clamp(0.0, 0.1);
        let running = self
            .panels
            .iter()
            .filter(|p| p.running && p.failed.is_none())
            .count() as u64;
        if running == 0 {
            return;
        }
        let max_steps = (self.limits.max_steps_per_frame / running).max(1);
        let budget = FRAME_BUDGET / running as u32;
        for panel in &mut self.panels {
            panel.advance(elapsed, self.time_scale, max_steps, budget);
        }
    }

    /// Handle one client message; returns the replies (besides frames).
    pub fn handle(&mut self, message: ClientMessage) -> Vec<ServerMessage> {
        let kind = message.kind();
        match self.apply(message) {
            Ok(replies) => replies,
            Err((message, panel)) => vec![ServerMessage::Error {
                message,
                request: Some(kind.into()),
                panel,
            }],
        }
    }

    fn apply(
        &mut self,
        message: ClientMessage,
    ) -> Result<Vec<ServerMessage>, (String, Option<u32>)> {
        let plain = |m: String| (m, None);
        match message {
            ClientMessage::AddPanel(patch) => {
                if self.panels.len() >= self.limits.max_panels {
                    return Err(plain(format!(
                        "too many panels (limit {})",
                        self.limits.max_panels
                    )));
                }
                let scene = self
                    .scene
                    .as_ref()
                    .ok_or_else(|| plain("no scene loaded".into()))?;
                let defaults = default_settings(&scene.scene, None);
                let settings = patch_settings(defaults, &patch, &self.limits).map_err(plain)?;
                let panel = Panel::new(
                    self.next_id,
                    settings,
                    Arc::clone(&scene.text),
                    &scene.scene,
                    scene.exprs.clone(),
                    scene.info.view,
                )
                .map_err(plain)?;
                let mut panel = panel;
                panel.running = self.panels.iter().any(|p| p.running);
                self.next_id += 1;
                self.panels.push(panel);
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
                let new_settings = patch_settings(old.settings, &settings, &self.limits)
                    .map_err(|m| (m, Some(panel)))?;
                let scene = self
                    .scene
                    .as_ref()
                    .ok_or_else(|| plain("no scene loaded".into()))?;
                // Rebuild from the panel's own text (it keeps its curve edits).
                let parsed =
                    parse_scene(&old.text, &scene.name).map_err(|e| (e.render(), Some(panel)))?;
                let mut rebuilt = Panel::new(
                    panel,
                    new_settings,
                    Arc::clone(&old.text),
                    &parsed,
                    old.exprs.clone(),
                    scene.info.view,
                )
                .map_err(|m| (m, Some(panel)))?;
                rebuilt.running = old.running;
                self.panels[index] = rebuilt;
                Ok(vec![self.panels_message()])
            }
            ClientMessage::Play { panel } => {
                for p in self.targets(panel)? {
                    p.running = p.failed.is_none();
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
                for p in self.targets(panel)? {
                    p.single_step();
                }
                Ok(Vec::new())
            }
            ClientMessage::Reset { panel } => {
                for p in self.targets(panel)? {
                    p.reset();
                }
                Ok(Vec::new())
            }
            ClientMessage::SetTimeScale { scale } => {
                if !(scale.is_finite() && (0.0..=self.limits.max_time_scale).contains(&scale)) {
                    return Err(plain(format!(
                        "time scale must be a number in [0, {}]",
                        self.limits.max_time_scale
                    )));
                }
                self.time_scale = scale;
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
                            plain(format!(
                                "unknown scene `{}`; use one of {}",
                                truncate(&name, 80),
                                self.catalog.names().join(", ")
                            ))
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
                    _ => {
                        return Err(plain(
                            "load_scene needs exactly one of `name` and `toml`".into(),
                        ))
                    }
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
                    .map_err(|m| (m, Some(panel)))?;
                Ok(Vec::new())
            }
            ClientMessage::DragMove { panel, target } => {
                let index = self.index(panel)?;
                self.panels[index]
                    .drag_move(target)
                    .map_err(|m| (m, Some(panel)))?;
                Ok(Vec::new())
            }
            ClientMessage::DragEnd { panel } => {
                let index = self.index(panel)?;
                if let Err(m) = self.panels[index].drag_end() {
                    self.panels[index].failed = Some(m);
                }
                Ok(Vec::new())
            }
        }
    }

    fn index(&self, panel: u32) -> Result<usize, (String, Option<u32>)> {
        self.panels
            .iter()
            .position(|p| p.id == panel)
            .ok_or_else(|| (format!("no panel {panel}"), Some(panel)))
    }

    fn targets(&mut self, panel: Option<u32>) -> Result<Vec<&mut Panel>, (String, Option<u32>)> {
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
        let scene = parse_scene(text, name)?;
        let table: Option<toml::Table> = toml::from_str(text).ok();
        let constraint_tables = constraint_tables(table.as_ref());
        let system = &scene.system;
        let constraints: Vec<ConstraintInfo> = system
            .constraints()
            .infos()
            .iter()
            .enumerate()
            .map(|(i, info)| ConstraintInfo {
                name: info.name.clone(),
                description: info.description.clone(),
                expr: expression_of(constraint_tables.get(i).copied()),
            })
            .collect();
        let exprs: Vec<Option<String>> = constraints.iter().map(|c| c.expr.clone()).collect();
        let rods = rods(&scene, &constraint_tables);
        let anchors: Vec<[f64; 2]> = rods.iter().filter_map(|r| r.anchor).collect();
        let dt = scene.run.dt.unwrap_or(1.0 / 60.0);
        let duration = scene
            .run
            .duration
            .or(scene.run.steps.map(|s| s as f64 * dt))
            .unwrap_or(10.0);
        let view = geometry::view_box(system, dt, duration, &anchors);
        let info = SceneInfo {
            name: name.to_string(),
            title: scene.title.clone(),
            dim: system.dim(),
            particles: system
                .particles()
                .iter()
                .map(|p| ParticleInfo {
                    name: p.name.clone(),
                    mass: p.mass,
                })
                .collect(),
            constraints,
            view,
            rods,
            has_implicit: system.constraints().n_rows() > 0,
            has_parametric: system.parametric().is_some(),
            warnings: scene.warnings(),
        };
        let text: Arc<str> = Arc::from(text);
        let mut panels = Vec::new();
        let mut methods = Vec::new();
        if info.has_implicit || !info.has_parametric {
            methods.push(Method::Implicit);
        }
        if info.has_parametric {
            methods.push(Method::Parametric);
        }
        for method in methods {
            let settings = default_settings(&scene, Some(method));
            let mut panel = Panel::new(
                self.next_id,
                settings,
                Arc::clone(&text),
                &scene,
                exprs.clone(),
                view,
            )
            .map_err(|message| SceneError {
                file: name.to_string(),
                line: 0,
                column: 0,
                message,
                snippet: None,
            })?;
            self.next_id += 1;
            // A scene starts playing, as in the article.
            panel.running = true;
            panels.push(panel);
        }
        self.panels = panels;
        self.scene = Some(CurrentScene {
            name: name.to_string(),
            text,
            scene,
            info,
            exprs,
        });
        Ok(())
    }

    fn set_curve(
        &mut self,
        panel: Option<u32>,
        constraint: usize,
        expr: String,
    ) -> Result<Vec<ServerMessage>, (String, Option<u32>)> {
        let curve_error = |message: String, columns: Option<[usize; 2]>| {
            Ok(vec![ServerMessage::CurveError {
                constraint,
                message,
                columns,
            }])
        };
        let chars = expr.chars().count();
        if chars > self.limits.max_expr_chars {
            return curve_error(
                format!(
                    "expression too long: {chars} characters (limit {})",
                    self.limits.max_expr_chars
                ),
                None,
            );
        }
        if let Some((column, c)) = expr
            .chars()
            .enumerate()
            .find(|(_, c)| *c == '"' || *c == '\\' || c.is_control())
        {
            return curve_error(
                format!("unexpected character {c:?} in the expression"),
                Some([column, column + 1]),
            );
        }
        if expr.trim().is_empty() {
            return curve_error("the expression is empty".into(), None);
        }
        let Some(scene) = &self.scene else {
            return Err(("no scene loaded".into(), None));
        };
        if scene.exprs.get(constraint).is_none_or(|e| e.is_none()) {
            return curve_error(
                format!(
                    "constraint {constraint} is not an expression constraint of this scene (it has {} constraints)",
                    scene.exprs.len()
                ),
                None,
            );
        }
        let indices: Vec<usize> = match panel {
            Some(id) => {
                let index = self.index(id)?;
                if self.panels[index].settings.method != Method::Implicit {
                    return curve_error(
                        "a parametric panel's curve is its map x(q): edit [parametric.positions] in the scene file instead".into(),
                        None,
                    );
                }
                vec![index]
            }
            None => (0..self.panels.len())
                .filter(|&i| self.panels[i].settings.method == Method::Implicit)
                .collect(),
        };
        if indices.is_empty() {
            return curve_error(
                "no implicit panel to apply the curve to: add one (the parametric form's curve is its map x(q))".into(),
                None,
            );
        }
        // Build every new panel first; replace them only when all succeeded.
        let mut rebuilt = Vec::new();
        for &index in &indices {
            let old = &self.panels[index];
            let (text, expr_line) = match replace_expression(&old.text, constraint, &expr) {
                Ok(v) => v,
                Err(m) => return curve_error(m, None),
            };
            let parsed = match parse_scene(&text, &scene.name) {
                Ok(parsed) => parsed,
                Err(e) => {
                    let columns = expression_columns(&e, expr_line, &text, &expr);
                    return curve_error(e.message.clone(), columns);
                }
            };
            let mut exprs = old.exprs.clone();
            exprs[constraint] = Some(expr.clone());
            let mut panel = match Panel::new(
                old.id,
                old.settings,
                Arc::from(text.as_str()),
                &parsed,
                exprs,
                scene.info.view,
            ) {
                Ok(panel) => panel,
                Err(m) => return curve_error(m, None),
            };
            if let Some(failure) = &panel.failed {
                return curve_error(failure.clone(), None);
            }
            panel.running = old.running;
            rebuilt.push((index, panel));
        }
        for (index, panel) in rebuilt {
            self.panels[index] = panel;
        }
        Ok(vec![self.panels_message()])
    }
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
    }
}

/// `base` with the fields of `patch`, validated.
fn patch_settings(
    base: PanelSettings,
    patch: &PanelSettingsPatch,
    limits: &Limits,
) -> Result<PanelSettings, String> {
    let mut s = base;
    if let Some(method) = &patch.method {
        s.method = method.parse().map_err(|e: String| truncate(&e, 200))?;
        if s.method == Method::Parametric && patch.ks.is_none() && patch.kd.is_none() {
            s.ks = 0.0;
            s.kd = 0.0;
        }
        if s.method == Method::Parametric && patch.project.is_none() {
            s.project = false;
        }
    }
    if let Some(integrator) = &patch.integrator {
        s.integrator = integrator.parse().map_err(|e: String| truncate(&e, 300))?;
    }
    if let Some(dt) = patch.dt {
        if !(dt.is_finite() && dt >= limits.min_dt && dt <= limits.max_dt) {
            return Err(format!(
                "dt must be a number in [{:e}, {}]",
                limits.min_dt, limits.max_dt
            ));
        }
        s.dt = dt;
    }
    for (name, value, slot) in [("ks", patch.ks, &mut s.ks), ("kd", patch.kd, &mut s.kd)] {
        if let Some(v) = value {
            if !(v.is_finite() && (0.0..=limits.max_feedback).contains(&v)) {
                return Err(format!(
                    "{name} must be a number in [0, {:e}]",
                    limits.max_feedback
                ));
            }
            *slot = v;
        }
    }
    if let Some(project) = patch.project {
        s.project = project;
    }
    if !(s.dt.is_finite() && s.dt > 0.0) {
        s.dt = 1.0 / 60.0;
    }
    Ok(s)
}

/// Check settings against a system without building a panel (for tests).
pub fn check_settings(settings: &PanelSettings, scene: &Scene) -> Result<(), String> {
    validate_combination(settings, &scene.system)
}

/// The `[[constraint]]` tables of a parsed scene file, in order.
fn constraint_tables(table: Option<&toml::Table>) -> Vec<&toml::Table> {
    table
        .and_then(|t| t.get("constraint"))
        .and_then(|c| c.as_array())
        .map(|a| a.iter().filter_map(|v| v.as_table()).collect())
        .unwrap_or_default()
}

/// The expression of an expression constraint table.
fn expression_of(table: Option<&toml::Table>) -> Option<String> {
    let table = table?;
    let kind = table
        .get("kind")
        .and_then(|k| k.as_str())
        .unwrap_or("expression");
    if kind != "expression" {
        return None;
    }
    table.get("expr")?.as_str().map(str::to_string)
}

/// Distance constraints as rods.
fn rods(scene: &Scene, tables: &[&toml::Table]) -> Vec<Rod> {
    let system = &scene.system;
    let id = |v: Option<&toml::Value>| {
        v.and_then(|v| v.as_str())
            .and_then(|name| system.particle_id(name))
            .map(|p| p.0)
    };
    let mut out = Vec::new();
    for table in tables {
        if table.get("kind").and_then(|k| k.as_str()) != Some("distance") {
            continue;
        }
        if let Some(between) = table.get("between").and_then(|b| b.as_array()) {
            if let (Some(a), Some(b)) = (id(between.first()), id(between.get(1))) {
                out.push(Rod {
                    a,
                    b: Some(b),
                    anchor: None,
                });
            }
        } else if let Some(a) = id(table.get("particle")) {
            let anchor = table
                .get("anchor")
                .and_then(|v| v.as_array())
                .and_then(|v| {
                    let number = |i: usize| {
                        v.get(i)
                            .and_then(|c| c.as_float().or_else(|| c.as_integer().map(|i| i as f64)))
                    };
                    Some([number(0)?, number(1)?])
                });
            if anchor.is_some() {
                out.push(Rod { a, b: None, anchor });
            }
        }
    }
    out
}

/// The scene text with constraint `index`'s `expr` replaced, and the 1-based line on which
/// the new expression stands.
fn replace_expression(text: &str, index: usize, expr: &str) -> Result<(String, usize), String> {
    let mut table: toml::Table =
        toml::from_str(text).map_err(|e| format!("cannot edit the scene: {e}"))?;
    let constraint = table
        .get_mut("constraint")
        .and_then(|c| c.as_array_mut())
        .and_then(|a| a.get_mut(index))
        .and_then(|c| c.as_table_mut())
        .ok_or_else(|| format!("the scene has no constraint {index}"))?;
    constraint.insert("expr".into(), toml::Value::String(expr.to_string()));
    // A marker value, to find the line of the expression after serialization.
    let text = toml::to_string(&table).map_err(|e| format!("cannot edit the scene: {e}"))?;
    let needle = format!("expr = {}", toml::Value::String(expr.to_string()));
    // The n-th occurrence of an expr line belongs to constraint n only if every earlier
    // constraint has one; search by content instead: the first line equal to the needle.
    let line = text
        .lines()
        .position(|l| l.trim() == needle)
        .map(|l| l + 1)
        .unwrap_or(0);
    Ok((text, line))
}

/// The 0-based character range within `expr` of a scene error on the expression's line.
fn expression_columns(
    error: &SceneError,
    expr_line: usize,
    text: &str,
    expr: &str,
) -> Option<[usize; 2]> {
    if error.line == 0 || error.line != expr_line {
        return None;
    }
    let line = text.lines().nth(expr_line - 1)?;
    // The expression starts after `expr = "`.
    let quote = line.find('"')?;
    let start = line[..quote].chars().count() + 1;
    let column = error.column.checked_sub(1)?.checked_sub(start)?;
    let width = error
        .snippet
        .as_deref()
        .and_then(|s| s.lines().find(|l| l.trim_start().starts_with('^')))
        .map(|l| l.trim().chars().filter(|c| *c == '^').count())
        .unwrap_or(1)
        .max(1);
    let len = expr.chars().count();
    let begin = column.min(len);
    Some([begin, (column + width).min(len.max(begin + 1))])
}

fn truncate(s: &str, max: usize) -> String {
    if s.chars().count() <= max {
        s.to_string()
    } else {
        s.chars().take(max).collect::<String>() + "…"
    }
}
