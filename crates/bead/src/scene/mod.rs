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
//! - `[[constraint]]`: optional `name` (default `constraint N`, unique). `kind = "expression"`
//!   (the default) has `expr`, an expression of particle coordinates `NAME.x|y|z`, `t` and
//!   parameters; `"distance"` has `between` or `particle` and `anchor`, and `length` (default the
//!   initial distance); `"pin"` has `particle` and `anchor` (default its initial position).
//! - `[parametric.positions]` gives every particle's position as expressions of the
//!   coordinates, `t` and parameters.
//! - `[run]`: `method` (implicit, parametric), `integrator` (euler, symplectic-euler, midpoint,
//!   rk4), `dt`, `duration` or `steps`, and `stabilize = [ks, kd]` or
//!   `stabilize = { frequency = f, damping = zeta }` (damping default 1).
//! - Unknown keys, wrong types, missing keys, non-finite numbers (`nan`, `inf`) and values out of
//!   range are errors located in the file. So are control characters (escape sequences, line
//!   breaks, tabs) in `title` and constraint names: they are labels, shown on terminals and in
//!   reports. Error snippets show control characters escaped (`\x1b`).

mod file;
mod load;
mod location;

use std::path::Path;
use std::sync::Arc;

use crate::formulation::{Feedback, Method};
use crate::integrate::IntegratorKind;
use crate::model::System;

/// Relative tolerance of the consistency checks of [`Scene::warnings`].
const WARN_TOLERANCE: f64 = 1e-9;

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// `title`, or the file stem when the file has none.
    pub title: String,
    /// The file name as given (for messages and summaries).
    pub file: String,
    /// The compiled system: particles, forces, implicit constraints, parametric form.
    pub system: Arc<System>,
    /// Parameter values after overrides, in file order.
    pub params: Vec<(String, f64)>,
    /// The `[run]` table.
    pub run: RunDefaults,
}

/// `[run]` defaults; every field may be overridden on the command line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunDefaults {
    /// `method = "implicit" | "parametric"`.
    pub method: Option<Method>,
    /// `integrator = "euler" | "symplectic-euler" | "midpoint" | "rk4"`.
    pub integrator: Option<IntegratorKind>,
    /// `dt`: step size, > 0.
    pub dt: Option<f64>,
    /// `duration`: simulated time, > 0 (not together with `steps`).
    pub duration: Option<f64>,
    /// `steps`: number of steps, a positive integer (not together with `duration`).
    pub steps: Option<u64>,
    /// `stabilize = [ks, kd]` or `{ frequency = f, damping = zeta }` (implicit method only).
    pub stabilize: Option<Feedback>,
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

impl Scene {
    /// Read and load a scene file; `overrides` replace `[params]` values (`--set NAME=VALUE`;
    /// an unknown name is an error).
    pub fn load(path: &Path, overrides: &[(String, f64)]) -> Result<Scene, SceneError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| SceneError {
            file: file.clone(),
            line: 0,
            column: 0,
            message: format!("cannot read the scene file: {e}"),
            snippet: None,
        })?;
        Scene::parse(&text, &file, overrides)
    }

    /// Load a scene from text; `file` names it in messages.
    pub fn parse(text: &str, file: &str, overrides: &[(String, f64)]) -> Result<Scene, SceneError> {
        load::load(text, file, overrides)
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
        let system = &self.system;
        let dim = system.dim();
        let (x0, v0) = system.initial_particle_state();
        let max_abs = |v: &[f64]| v.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
        let length_scale = max_abs(&x0).max(1.0);
        let mut warnings = Vec::new();

        if let Some(map) = system.parametric() {
            let mut ws = map.workspace();
            map.evaluate(0.0, map.initial(), map.rates(), &mut ws);
            let speed_scale = length_scale.max(max_abs(&v0)).max(max_abs(&ws.velocity));
            for (p, particle) in system.particles().iter().enumerate() {
                let range = p * dim..(p + 1) * dim;
                for (what, given, computed, key, scale) in [
                    (
                        "position",
                        &x0[range.clone()],
                        &ws.position[range.clone()],
                        "x(q0)",
                        length_scale,
                    ),
                    (
                        "velocity",
                        &v0[range.clone()],
                        &ws.velocity[range.clone()],
                        "xdot(q0, qdot0)",
                        speed_scale,
                    ),
                ] {
                    let name = &particle.name;
                    if computed.iter().any(|c| !c.is_finite()) {
                        warnings.push(format!(
                            "particle `{name}`: the parametric form's initial {what} {key} = {} is not finite",
                            fmt_vec(computed)
                        ));
                        continue;
                    }
                    let difference = distance(given, computed);
                    if exceeds(difference, WARN_TOLERANCE * scale) {
                        let by = if difference.is_finite() {
                            format!("by {}", crate::significant(difference, 6))
                        } else {
                            "by more than the largest representable number".to_string()
                        };
                        warnings.push(format!(
                            "particle `{name}`: the parametric form's initial {what} {key} = {} differs from the scene's {what} {} {by}",
                            fmt_vec(computed),
                            fmt_vec(given),
                        ));
                    }
                }
            }
        }

        let constraints = system.constraints();
        if constraints.n_rows() > 0 {
            let mut ws = constraints.workspace();
            constraints.evaluate(0.0, &x0, &v0, &mut ws);
            let speed_scale = length_scale.max(max_abs(&v0));
            for info in constraints.infos() {
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
                if !c.is_finite() {
                    warnings.push(format!(
                        "{name}: its value at the initial positions is not finite ({})",
                        crate::readable(c)
                    ));
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
                    off = nan_max(off, ws.value[row].abs() / norm);
                    drift = nan_max(drift, ws.velocity[row].abs() / norm);
                }
                if !gradient_finite {
                    warnings.push(format!(
                        "{name}: its gradient at the initial positions is not finite"
                    ));
                } else if exceeds(off, WARN_TOLERANCE * length_scale) {
                    let how_far = if off.is_finite() {
                        format!("about {} off the constraint", crate::significant(off, 6))
                    } else {
                        "its gradient is too small there to tell how far".to_string()
                    };
                    warnings.push(format!(
                        "{name}: the initial positions violate it: C = {} ({how_far})",
                        crate::significant(c, 6)
                    ));
                } else if !cdot.is_finite() {
                    warnings.push(format!(
                        "{name}: its rate Cdot at the initial state is not finite ({})",
                        crate::readable(cdot)
                    ));
                } else if exceeds(drift, WARN_TOLERANCE * speed_scale) {
                    warnings.push(format!(
                        "{name}: the initial velocities are not tangent to it: Cdot = {}",
                        crate::significant(cdot, 6)
                    ));
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

fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
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
