//! From the deserialized file to a [`Scene`]: evaluate numbers, check everything, feed the
//! [`SystemBuilder`], and turn every failure into a located [`SceneError`].

use std::cell::Cell;
use std::collections::HashMap;
use std::ops::Range;
use std::sync::Arc;

use toml::Spanned;

use super::file::{
    span_of, ConstraintDef, Entries, EventDef, ForceDef, Names, Num, NumVec, ParamDef, ParamTable,
    ParametricDef, ParticleDef, RangeText, RunDef, SceneFile, Stabilize, StringBytes,
};
use super::location::Source;
use super::template::{self, Expanded, Scope, StringError};
use super::{
    Generated, Lines, ParamSpec, RunDefaults, Scene, SceneError, TableKind, MAX_EXPANDED_BYTES,
    MAX_LOOP_VARIABLES, MAX_REPETITIONS,
};
use crate::expr::{parse, Expr, ExprError, Func, Resolved};
use crate::formulation::{Feedback, Method};
use crate::integrate::IntegratorKind;
use crate::model::System;
use crate::model::{Endpoint, Force, ModelError, ParticleId, SystemBuilder};
use crate::simulate::{Direction, Event, EventSpec};

/// Names a parameter may not take (the model's reserved names).
const RESERVED: [&str; 6] = ["t", "pi", "e", "x", "y", "z"];

/// The largest integer a range bound may be: every integer up to it is exact in an f64.
const LARGEST_INTEGER: f64 = 9_007_199_254_740_992.0;

type Result<T> = std::result::Result<T, SceneError>;

/// Load a scene; with `previous` (the same scene's system at other parameter values), its
/// compiled equations are reused when the dynamics did not change
/// ([`crate::model::compile_reusing`]), which leaves every number as it would be.
pub(super) fn load(
    text: &str,
    file: &str,
    overrides: &[(String, f64)],
    previous: Option<&crate::model::System>,
) -> Result<Scene> {
    load_limited(text, file, overrides, previous, MAX_EXPANDED_BYTES)
}

/// [`load`] with `limit` bytes of generated text instead of [`MAX_EXPANDED_BYTES`].
fn load_limited(
    text: &str,
    file: &str,
    overrides: &[(String, f64)],
    previous: Option<&crate::model::System>,
    limit: usize,
) -> Result<Scene> {
    let src = Source { text, file };
    let doc: SceneFile = toml::from_str(text).map_err(|e| src.toml_error(&e))?;
    let mut loader = Loader {
        src,
        params: Vec::new(),
        scope: None,
        expanded: Cell::new(0),
        limit,
    };

    let params = loader.params(doc.params.as_ref(), overrides)?;
    let param_specs = param_specs(&doc, &src)?;
    let title = match &doc.title {
        Some(t) => {
            no_control_characters(&src, t, "`title`")?;
            t.get_ref().clone()
        }
        None => std::path::Path::new(file)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };

    let about = match &doc.about {
        Some(a) => {
            no_control_characters(&src, a, "`about`")?;
            Some(a.get_ref().trim().to_string()).filter(|a| !a.is_empty())
        }
        None => None,
    };

    // [world]
    let world = doc.world.as_ref().ok_or_else(|| {
        src.error_at_start(
            "missing table `[world]` with `gravity` (its length, 2 or 3, sets the dimension)",
        )
    })?;
    let gravity_def = world.get_ref().gravity.as_ref().ok_or_else(|| {
        src.error(
            world.span(),
            "world: missing `gravity` (its length, 2 or 3, sets the dimension)",
        )
    })?;
    let gravity = loader.vector(gravity_def, "world", &"`gravity`")?;
    let units = match &world.get_ref().units {
        Some(u) => {
            no_control_characters(&src, u, "world: `units`")?;
            let text = u.get_ref().trim();
            if text.is_empty() || text.chars().count() > 20 {
                return Err(src.error(
                    u.span(),
                    "world: `units` must be \"SI\" or the length unit the scene's numbers are in (e.g. \"px\"), at most 20 characters",
                ));
            }
            Some(text.to_string())
        }
        None => None,
    };
    if !(2..=3).contains(&gravity.len()) {
        return Err(src.error(
            gravity_def.span(),
            format!(
                "world: `gravity` must have 2 or 3 components (it sets the dimension), got {}",
                gravity.len()
            ),
        ));
    }
    let dim = gravity.len();
    let mut b = SystemBuilder::new(&gravity);
    for ((name, value), (key, _)) in params
        .iter()
        .zip(doc.params.iter().flat_map(|p| p.get_ref().0.iter()))
    {
        b.param(name, *value)
            .map_err(|e| loader.model(key.span(), &format!("parameter `{name}`"), e))?;
    }
    let mut l = Builder {
        loader,
        b,
        dim,
        particles: Vec::new(),
        particle_origins: Vec::new(),
        constraint_names: HashMap::new(),
        generated: Vec::new(),
        forces: 0,
        repeated: 0,
        lines: Lines::default(),
    };

    // [[particle]]
    if doc.particle.0.is_empty() {
        return Err(
            src.error_at_start("the scene has no particles; add at least one `[[particle]]` table")
        );
    }
    for (i, p) in doc.particle.0.iter().enumerate() {
        l.repeat(TableKind::Particle, i, p, &p.get_ref().repeat, |l, i, p| {
            l.particle(i, p)
        })?;
    }
    if l.particles.is_empty() {
        // Every particle table has a `for` with an empty range.
        let first = doc.particle.0[0]
            .get_ref()
            .repeat
            .as_ref()
            .map(|f| f.span());
        return Err(src.error(
            first.unwrap_or(0..0),
            "the scene has no particles: its `[[particle]]` tables repeat over empty ranges",
        ));
    }
    for (i, f) in doc.force.0.iter().enumerate() {
        l.repeat(TableKind::Force, i, f, &f.get_ref().repeat, |l, i, f| {
            l.force(i, f)
        })?;
    }
    for (i, c) in doc.constraint.0.iter().enumerate() {
        l.repeat(
            TableKind::Constraint,
            i,
            c,
            &c.get_ref().repeat,
            |l, i, c| l.constraint(i, c),
        )?;
    }
    if let Some(p) = &doc.parametric {
        l.parametric(p)?;
    }
    let mut run = l.loader.run(doc.run.as_ref(), doc.parametric.is_some())?;
    let system = match previous {
        Some(previous) => crate::model::compile_reusing(Arc::new(l.b), previous),
        None => l.b.build(),
    }
    .map_err(|e| src.error_at_start(e.to_string()))?;
    if let Some(stop_when) = doc
        .run
        .as_ref()
        .and_then(|r| r.get_ref().stop_when.as_ref())
    {
        let source = stop_when.get_ref();
        let event = Event::parse(&system, source).map_err(|err| {
            src.expr_error(
                stop_when.span(),
                source,
                &err,
                format!("run: `stop_when`: {}", err.message),
            )
        })?;
        run.stop_when = Some(event);
    }
    for (i, table) in doc.event.0.iter().enumerate() {
        run.events.push(event_table(&src, &system, i, table)?);
    }
    Ok(Scene {
        title,
        about,
        units,
        file: file.to_string(),
        system: Arc::new(system),
        params,
        param_specs,
        run,
        generated: l.generated,
        text: Arc::from(text),
        overrides: overrides.to_vec(),
        edits: Vec::new(),
        start: None,
        lines: l.lines,
    })
}

/// An `[[event]]` table (`i` 0-based): its expression parsed against the system,
/// `direction` 1, -1 or 0 (default 0), `terminal` (default false).
fn event_table(
    src: &Source,
    system: &System,
    i: usize,
    table: &Spanned<EventDef>,
) -> Result<EventSpec> {
    let ctx = format!("event {}", i + 1);
    let def = table.get_ref();
    let Some(expr) = &def.expr else {
        return Err(src.error(table.span(), format!("{ctx}: missing `expr`")));
    };
    let source = expr.get_ref();
    let event = Event::parse(system, source).map_err(|err| {
        src.expr_error(
            expr.span(),
            source,
            &err,
            format!("{ctx}: `expr`: {}", err.message),
        )
    })?;
    let direction = match &def.direction {
        None => Direction::Either,
        Some(d) => match d.get_ref() {
            Num::Value(v) if *v == 1.0 || *v == -1.0 || *v == 0.0 => {
                Direction::from_sign(*v).expect("a sign")
            }
            _ => {
                return Err(src.error(
                    d.span(),
                    format!(
                    "{ctx}: `direction` must be 1 (upward crossings), -1 (downward) or 0 (either)"
                ),
                ))
            }
        },
    };
    let terminal = def.terminal.as_ref().is_some_and(|t| *t.get_ref());
    Ok(EventSpec {
        event,
        direction,
        terminal,
        stop_when: false,
    })
}

/// A scene's initial values at other parameter values, read from its file as [`load`] reads
/// them, without the rest of the scene (see `rebind.rs`).
pub(super) struct InitialValues {
    /// Every parameter, in file order.
    pub params: Vec<(String, f64)>,
    /// Position and velocity of each particle table asked for.
    pub particles: Vec<(Vec<f64>, Vec<f64>)>,
    /// The parametric form's initial values and rates, when asked for.
    pub parametric: Option<(Vec<f64>, Vec<f64>)>,
}

/// The parameters of `doc` (the scene file `src`, deserialized once) with `overrides`, the
/// position and velocity of the `[[particle]]` tables `particles` (0-based, tables without
/// `for`) and, with `parametric`, the `[parametric]` initial values and rates, each evaluated
/// by the code [`load`] evaluates it with, so that every number has the same bits. Fails
/// where `load` would fail reading these values (e.g. a position that is not finite).
pub(super) fn initial_values(
    doc: &SceneFile,
    src: Source<'_>,
    overrides: &[(String, f64)],
    particles: &[usize],
    parametric: bool,
    dim: usize,
) -> Result<InitialValues> {
    let mut loader = Loader {
        src,
        params: Vec::new(),
        scope: None,
        expanded: Cell::new(0),
        limit: MAX_EXPANDED_BYTES,
    };
    let params = loader.params(doc.params.as_ref(), overrides)?;
    // Particle tables are read with an empty scope (their `{...}` expanded), as
    // `Builder::repeat` reads a table without `for`.
    loader.scope = Some(Scope::default());
    let mut values = Vec::with_capacity(particles.len());
    for &i in particles {
        let table = &doc.particle.0[i];
        let def = table.get_ref();
        let ctx = format!("particle {}", i + 1);
        let position = loader.required(&def.position, table.span(), &ctx, "position")?;
        let position = loader.dim_vector(position, &ctx, "position", dim)?;
        let velocity = match &def.velocity {
            Some(v) => loader.dim_vector(v, &ctx, "velocity", dim)?,
            None => vec![0.0; dim],
        };
        values.push((position, velocity));
    }
    loader.scope = None;
    let parametric = match (parametric, &doc.parametric) {
        (true, Some(p)) => {
            let d = p.get_ref();
            let ctx = "parametric";
            let n_q = d.coordinates.as_ref().map_or(0, |c| c.get_ref().0.len());
            let counted = |what: &str, v: &Spanned<NumVec>| -> Result<Vec<f64>> {
                let values = loader.vector(v, ctx, &format_args!("`{what}`"))?;
                if values.len() != n_q {
                    return Err(src.error(
                        v.span(),
                        format!(
                            "{ctx}: `{what}` has {} values for {n_q} coordinates",
                            values.len()
                        ),
                    ));
                }
                Ok(values)
            };
            let initial = counted(
                "initial",
                loader.required(&d.initial, p.span(), ctx, "initial")?,
            )?;
            let rates = match &d.rates {
                Some(r) => counted("rates", r)?,
                None => vec![0.0; n_q],
            };
            Some((initial, rates))
        }
        _ => None,
    };
    Ok(InitialValues {
        params,
        particles: values,
        parametric,
    })
}

/// A `[params]` entry's value (`None`: a table without `value`) and its table, if any.
fn param_value(def: &Spanned<ParamDef>) -> (Option<Spanned<Num>>, Option<&ParamTable>) {
    match def.get_ref() {
        ParamDef::Value(n) => (Some(Spanned::new(def.span(), n.clone())), None),
        ParamDef::Table(t) => (t.value.clone(), Some(t)),
    }
}

/// The identifiers in `text` (letters, digits, `_`, not starting with a digit).
fn identifiers(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| {
            w.chars()
                .next()
                .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        })
}

/// What the scene says about each parameter besides its value (see [`ParamSpec`]): its
/// expression and the parameters it names, the table's `range`, `unit`, `description` (else
/// the comment after it on its line) and whether it is whole (`integer = true`, or named by a
/// `for` range, directly or through the parameters derived from it).
fn param_specs(doc: &SceneFile, src: &Source<'_>) -> Result<Vec<ParamSpec>> {
    let Some(table) = doc.params.as_ref() else {
        return Ok(Vec::new());
    };
    let entries = &table.get_ref().0;
    let names: Vec<&str> = entries.iter().map(|(k, _)| k.get_ref().as_str()).collect();
    // Constants only in a range: pi, e and numbers.
    let constants = Loader {
        src: *src,
        params: Vec::new(),
        scope: None,
        expanded: Cell::new(0),
        limit: MAX_EXPANDED_BYTES,
    };
    let mut specs = Vec::with_capacity(entries.len());
    for (key, def) in entries {
        let name = key.get_ref().clone();
        let ctx = format!("parameter `{name}`");
        let (value, table) = param_value(def);
        let expr = match value.as_ref().map(|v| v.get_ref()) {
            Some(Num::Expr(text)) => Some(text.clone()),
            _ => None,
        };
        let mut depends_on: Vec<String> = Vec::new();
        for word in expr.iter().flat_map(|e| identifiers(e)) {
            if names.contains(&word) && word != name && !depends_on.iter().any(|d| d == word) {
                depends_on.push(word.to_string());
            }
        }
        let range = match table.and_then(|t| t.range.as_ref()) {
            Some(range) => {
                let values = constants.vector(range, &ctx, &"`range`").map_err(|e| {
                    if names.iter().any(|n| e.to_string().contains(&format!("`{n}`"))) {
                        src.error(range.span(), format!("{ctx}: `range` may use numbers, pi and e only (it does not change with the other parameters)"))
                    } else {
                        e
                    }
                })?;
                match values[..] {
                    [lo, hi] if lo < hi => Some([lo, hi]),
                    _ => {
                        return Err(src.error(
                            range.span(),
                            format!(
                                "{ctx}: `range` must be [lo, hi] with lo < hi, got {}",
                                values
                                    .iter()
                                    .map(|v| crate::readable(*v))
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            ),
                        ))
                    }
                }
            }
            None => None,
        };
        let text_of = |s: &Option<Spanned<String>>| {
            s.as_ref()
                .map(|s| s.get_ref().trim().to_string())
                .filter(|s| !s.is_empty())
        };
        let unit = table.and_then(|t| text_of(&t.unit));
        let description = table
            .and_then(|t| text_of(&t.description))
            .or_else(|| line_comment(src.text, def.span().end))
            .or_else(|| comment_above(src.text, key.span().start));
        let integer = table
            .and_then(|t| t.integer.as_ref())
            .is_some_and(|b| *b.get_ref());
        specs.push(ParamSpec {
            name,
            expr,
            depends_on,
            range,
            unit,
            description,
            integer,
        });
    }
    // Whole numbers: what a `for` range names, and what those are derived from.
    let mut counted: Vec<String> = Vec::new();
    let ranges = doc
        .particle
        .0
        .iter()
        .map(|t| &t.get_ref().repeat)
        .chain(doc.force.0.iter().map(|t| &t.get_ref().repeat))
        .chain(doc.constraint.0.iter().map(|t| &t.get_ref().repeat));
    for repeat in ranges.flatten() {
        for (_, range) in &repeat.get_ref().0 {
            for word in identifiers(&range.get_ref().0) {
                if names.contains(&word) && !counted.iter().any(|c| c == word) {
                    counted.push(word.to_string());
                }
            }
        }
    }
    while let Some(name) = counted.pop() {
        if let Some(spec) = specs.iter_mut().find(|s| s.name == name) {
            if !spec.integer {
                spec.integer = true;
                counted.extend(spec.depends_on.iter().cloned());
            }
        }
    }
    Ok(specs)
}

/// The comment lines right above the line of byte `start` (`# ...` each, no blank line
/// between), joined by spaces; `None` when there are none.
fn comment_above(text: &str, start: usize) -> Option<String> {
    let before = text.get(..start)?;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let mut lines: Vec<&str> = Vec::new();
    for line in text[..line_start].lines().rev() {
        match line.trim_start().strip_prefix('#') {
            Some(comment) => lines.push(comment.trim()),
            None => break,
        }
    }
    lines.reverse();
    let joined = lines.join(" ");
    (!joined.trim().is_empty()).then(|| joined.trim().to_string())
}

/// The comment after byte `end` on its line (`# ...`), trimmed; `None` when there is none.
fn line_comment(text: &str, end: usize) -> Option<String> {
    let rest = text.get(end..)?;
    let line = rest.split('\n').next()?;
    let comment = line.trim_start().strip_prefix('#')?.trim();
    (!comment.is_empty()).then(|| comment.to_string())
}

struct Loader<'a> {
    src: Source<'a>,
    /// Parameters evaluated so far, in file order.
    params: Vec<(String, f64)>,
    /// While a `[[particle]]`, `[[constraint]]` or `[[force]]` table is read: its loop
    /// variables (empty without `for`), and `{...}` in its strings is expanded. None elsewhere.
    scope: Option<Scope>,
    /// Bytes of text the strings of tables with `for` have expanded to so far, and the most
    /// they may ([`MAX_EXPANDED_BYTES`]).
    expanded: Cell<usize>,
    limit: usize,
}

impl Loader<'_> {
    /// Evaluate `[params]` in file order, applying `overrides`.
    fn params(
        &mut self,
        table: Option<&Spanned<Entries<ParamDef>>>,
        overrides: &[(String, f64)],
    ) -> Result<Vec<(String, f64)>> {
        let entries: &[(Spanned<String>, Spanned<ParamDef>)] =
            table.map(|t| t.get_ref().0.as_slice()).unwrap_or(&[]);
        let known: Vec<&str> = entries.iter().map(|(k, _)| k.get_ref().as_str()).collect();
        for (name, value) in overrides {
            if !known.contains(&name.as_str()) {
                let list = if known.is_empty() {
                    "the scene has no parameters".to_string()
                } else {
                    format!("the scene's parameters are {}", known.join(", "))
                };
                return Err(self.src.error_unplaced(format!(
                    "--set {name}={}: unknown parameter `{name}`; {list}",
                    crate::readable(*value)
                )));
            }
            if !value.is_finite() {
                return Err(self.src.error_unplaced(format!(
                    "--set {name}={}: the value must be finite",
                    crate::readable(*value)
                )));
            }
        }
        for (i, (key, value)) in entries.iter().enumerate() {
            let name = key.get_ref();
            let ctx = format!("parameter `{name}`");
            if !is_identifier(name) {
                return Err(self.src.error(
                    key.span(),
                    format!("{ctx}: a parameter name must be a letter or `_` followed by letters, digits or `_`"),
                ));
            }
            if RESERVED.contains(&name.as_str()) {
                return Err(self.src.error(
                    key.span(),
                    format!("{ctx}: `{name}` is reserved (t, pi, e, x, y, z)"),
                ));
            }
            if Func::from_name(name).is_some() {
                return Err(self.src.error(
                    key.span(),
                    format!("{ctx}: `{name}` is a built-in function"),
                ));
            }
            let overridden = overrides
                .iter()
                .rev()
                .find(|(n, _)| n == name)
                .map(|(_, v)| *v);
            let later: Vec<&str> = known[i + 1..].to_vec();
            let (value, table) = param_value(value);
            let value = value.ok_or_else(|| {
                self.src.error(
                    key.span(),
                    format!("{ctx}: a parameter table needs `value`, e.g. `{name} = {{ value = 1.0, unit = \"m\" }}`"),
                )
            })?;
            let v = match overridden {
                Some(v) => v,
                None => self.number_with(&value, &ctx, &"the value", &later)?,
            };
            let integer = table
                .and_then(|t| t.integer.as_ref())
                .is_some_and(|b| *b.get_ref());
            if integer && v.fract() != 0.0 {
                let place = if overridden.is_some() {
                    format!("--set {name}={}: ", crate::readable(v))
                } else {
                    String::new()
                };
                return Err(self.src.error(
                    value.span(),
                    format!(
                        "{place}{ctx} is a whole number (`integer = true`), got {}",
                        crate::readable(v)
                    ),
                ));
            }
            self.params.push((name.clone(), v));
        }
        Ok(self.params.clone())
    }

    /// A number: a TOML number, or an expression of parameters, pi and e. Must be finite.
    fn number(&self, value: &Spanned<Num>, ctx: &str, what: &str) -> Result<f64> {
        self.number_with(value, ctx, &what, &[])
    }

    fn number_with(
        &self,
        value: &Spanned<Num>,
        ctx: &str,
        what: &dyn std::fmt::Display,
        later: &[&str],
    ) -> Result<f64> {
        let v = match value.get_ref() {
            Num::Value(v) => *v,
            Num::Expr(source) => {
                let expanded = self.expand(value.span(), source, ctx)?;
                self.evaluate(&expanded.text, later)
                    .map_err(|e| self.string_error(value.span(), source, ctx, expanded.error(&e)))?
            }
        };
        if !v.is_finite() {
            return Err(self.src.error(
                value.span(),
                format!("{ctx}: {what} must be finite, got {}", crate::readable(v)),
            ));
        }
        Ok(v)
    }

    /// The value of expression `source`: pi, e, the parameters and the loop variables of the
    /// table being read. `later` are the parameters after the one being evaluated.
    fn evaluate(&self, source: &str, later: &[&str]) -> std::result::Result<f64, ExprError> {
        let resolve = |name: &str| {
            if let Some(v) = self.scope.as_ref().and_then(|s| s.value(name)) {
                return Ok(Resolved::Value(v));
            }
            if let Some((_, v)) = self.params.iter().find(|(n, _)| n == name) {
                return Ok(Resolved::Value(*v));
            }
            if later.contains(&name) {
                return Err(format!(
                    "parameter `{name}` is defined after this one; a parameter may use only the ones before it"
                ));
            }
            let list = if self.params.is_empty() {
                "none".to_string()
            } else {
                crate::name_list(self.params.iter().map(|(n, _)| n.as_str()))
            };
            match self.scope.as_ref().filter(|s| !s.vars.is_empty()) {
                Some(scope) => Err(format!(
                    "unknown name `{name}`; numbers here may use pi, e, parameters ({list}) and the loop variables ({})",
                    crate::name_list(scope.vars.iter().map(|(n, _)| n.as_str()))
                )),
                None => Err(format!(
                    "unknown name `{name}`; numbers in a scene may use pi, e and parameters ({list})"
                )),
            }
        };
        parse(source, &resolve).map(|e| constant_value(&e))
    }

    /// `source`, the string at `span`, with its `{...}` replaced when a
    /// `[[particle]]`, `[[constraint]]` or `[[force]]` table is being read; as it is elsewhere.
    fn expand<'s>(&self, span: Range<usize>, source: &'s str, ctx: &str) -> Result<Expanded<'s>> {
        let Some(scope) = &self.scope else {
            return Ok(Expanded::verbatim(source));
        };
        let expanded = template::expand(source, &|inner| self.evaluate(inner, &[]))
            .map_err(|e| self.string_error(span, source, ctx, e))?;
        if !scope.vars.is_empty() {
            self.expanded.set(self.expanded.get() + expanded.text.len());
        }
        Ok(expanded)
    }

    /// An error in the string `source` written at `span`, located inside it.
    fn string_error(
        &self,
        span: Range<usize>,
        source: &str,
        ctx: &str,
        error: StringError,
    ) -> SceneError {
        self.src.within_string(
            span,
            source,
            error.span,
            format!("{ctx}: {}", error.message),
        )
    }

    /// The repetitions of a table with `for = { i = "START..STOP", ... }`: one scope per
    /// combination of the loop variables' values, the first variable outermost. A bound is
    /// an integer expression of the parameters and of the loop variables before its own.
    /// `budget` is how many repetitions the scene may still make ([`MAX_REPETITIONS`] in
    /// all); `is_particle` tells the names a loop variable must not take.
    fn repetitions(
        &self,
        repeat: &Spanned<Entries<RangeText>>,
        ctx: &str,
        budget: usize,
        is_particle: &dyn Fn(&str) -> bool,
    ) -> Result<Vec<Scope>> {
        let ranges = &repeat.get_ref().0;
        if ranges.is_empty() {
            return Err(self.src.error(
                repeat.span(),
                format!(
                    "{ctx}: `for` names no loop variable; write e.g. `for = {{ i = \"0..N\" }}`"
                ),
            ));
        }
        if let Some((key, _)) = ranges.get(MAX_LOOP_VARIABLES) {
            return Err(self.src.error(
                key.span(),
                format!("{ctx}: `for` has more than {MAX_LOOP_VARIABLES} loop variables"),
            ));
        }
        for (k, (key, _)) in ranges.iter().enumerate() {
            let name = key.get_ref();
            let refuse = |why: String| Err(self.src.error(key.span(), format!("{ctx}: {why}")));
            if !is_identifier(name) {
                return refuse(format!(
                    "loop variable `{}` must be a letter or `_` followed by letters, digits or `_`",
                    crate::printable(name)
                ));
            }
            if RESERVED.contains(&name.as_str()) {
                return refuse(format!(
                    "`{name}` is reserved (t, pi, e, x, y, z) and cannot name a loop variable"
                ));
            }
            if Func::from_name(name).is_some() {
                return refuse(format!(
                    "`{name}` is a built-in function and cannot name a loop variable"
                ));
            }
            if self.params.iter().any(|(n, _)| n == name) {
                return refuse(format!(
                    "loop variable `{name}` has the name of a parameter; rename one of them"
                ));
            }
            if is_particle(name) {
                return refuse(format!(
                    "loop variable `{name}` has the name of a particle; rename one of them"
                ));
            }
            // TOML refuses a key given twice, so this cannot happen; kept for safety.
            if ranges[..k].iter().any(|(n, _)| n.get_ref() == name) {
                return refuse(format!("loop variable `{name}` is given twice"));
            }
        }
        let mut walk = Walk {
            ranges,
            span: repeat.span(),
            table: ctx,
            budget,
            taken: vec![0; ranges.len()],
            out: Vec::new(),
        };
        self.nest(&mut walk, &mut Scope::default())?;
        Ok(walk.out)
    }

    /// Push every repetition of the loop variables `walk.ranges[scope.vars.len()..]` within
    /// the outer values in `scope`.
    fn nest(&self, walk: &mut Walk<'_>, scope: &mut Scope) -> Result<()> {
        let k = scope.vars.len();
        let Some((key, range)) = walk.ranges.get(k) else {
            walk.out.push(scope.clone());
            return Ok(());
        };
        let name = key.get_ref();
        let table = walk.table;
        let ctx = if scope.vars.is_empty() {
            table.to_string()
        } else {
            format!("{table} ({})", scope.describe())
        };
        let text = &range.get_ref().0;
        let Some(dots) = text.find("..") else {
            return Err(self.src.error(
                range.span(),
                format!("{ctx}: the range of `{name}` must be `START..STOP` (START, START + 1, ..., STOP - 1), got `{}`", crate::printable(text)),
            ));
        };
        let later: Vec<&str> = walk.ranges[k..]
            .iter()
            .map(|(n, _)| n.get_ref().as_str())
            .collect();
        let bound = |part: Range<usize>, which: &str| -> Result<i64> {
            let source = &text[part.clone()];
            // The caret goes under the bound itself, not the spaces around it.
            let trimmed = {
                let start = part.start + (source.len() - source.trim_start().len());
                start..(start + source.trim().len()).max(start)
            };
            let shift = |e: ExprError| StringError {
                span: part.start + e.span.start..part.start + e.span.end,
                message: format!("the range of `{name}`: {}", e.message),
            };
            let resolve = |n: &str| {
                if let Some(v) = scope.value(n) {
                    return Ok(Resolved::Value(v));
                }
                if let Some((_, v)) = self.params.iter().find(|(p, _)| p == n) {
                    return Ok(Resolved::Value(*v));
                }
                if n == name.as_str() {
                    return Err(format!("a range cannot use its own variable `{n}`"));
                }
                if later.contains(&n) {
                    return Err(format!("loop variable `{n}` comes after `{name}`; a range may use the loop variables before its own"));
                }
                Err(format!(
                    "unknown name `{n}`; a range may use pi, e, parameters ({}) and the loop variables before its own",
                    if self.params.is_empty() { "none".to_string() } else { crate::name_list(self.params.iter().map(|(p, _)| p.as_str())) }
                ))
            };
            let v = parse(source, &resolve)
                .map(|e| constant_value(&e))
                .map_err(|e| self.string_error(range.span(), text, &ctx, shift(e)))?;
            let problem = if !(v.is_finite() && v.fract() == 0.0) {
                "not an integer"
            } else if v.abs() > LARGEST_INTEGER {
                "too large (at most 2^53 in size)"
            } else {
                return Ok(v as i64);
            };
            Err(self.string_error(
                range.span(),
                text,
                &ctx,
                StringError {
                    span: trimmed,
                    message: format!(
                        "the range of `{name}`: its {which} `{}` is {}, {problem}",
                        source.trim(),
                        crate::readable(v)
                    ),
                },
            ))
        };
        let start = bound(0..dots, "start")?;
        let stop = bound(dots + 2..text.len(), "stop")?;
        if stop < start {
            return Err(self.src.error(
                range.span(),
                format!("{ctx}: the range of `{name}` is {start}..{stop}: its stop is below its start (an empty range is START..START)"),
            ));
        }
        for value in start..stop {
            // Counting the combinations taken at every level, not only the repetitions, also
            // stops `i = "0..1e15", j = "0..0"` at once.
            walk.taken[k] += 1;
            if walk.taken[k] > walk.budget {
                return Err(self.src.error(walk.span.clone(), walk.too_many(k)));
            }
            scope.vars.push((name.clone(), value));
            self.nest(walk, scope)?;
            scope.vars.pop();
        }
        Ok(())
    }

    /// A number that must be > 0.
    fn positive(&self, value: &Spanned<Num>, ctx: &str, what: &str) -> Result<f64> {
        let v = self.number(value, ctx, what)?;
        if v <= 0.0 {
            return Err(self.src.error(
                value.span(),
                format!("{ctx}: {what} must be positive, got {}", crate::readable(v)),
            ));
        }
        Ok(v)
    }

    /// A number that must be >= 0.
    fn non_negative(&self, value: &Spanned<Num>, ctx: &str, what: &str) -> Result<f64> {
        let v = self.number(value, ctx, what)?;
        if v < 0.0 {
            return Err(self.src.error(
                value.span(),
                format!(
                    "{ctx}: {what} must not be negative, got {}",
                    crate::readable(v)
                ),
            ));
        }
        Ok(v)
    }

    /// An array of numbers, any length.
    /// (`what` is formatted only for an error: members of a sweep read vectors by the
    /// thousand.)
    fn vector(
        &self,
        value: &Spanned<NumVec>,
        ctx: &str,
        what: &dyn std::fmt::Display,
    ) -> Result<Vec<f64>> {
        value
            .get_ref()
            .0
            .iter()
            .enumerate()
            .map(|(i, c)| {
                self.number_with(c, ctx, &format_args!("component {} of {what}", i + 1), &[])
            })
            .collect()
    }

    /// A vector of `dim` components.
    fn dim_vector(
        &self,
        value: &Spanned<NumVec>,
        ctx: &str,
        key: &str,
        dim: usize,
    ) -> Result<Vec<f64>> {
        let v = self.vector(value, ctx, &format_args!("`{key}`"))?;
        if v.len() != dim {
            return Err(self.src.error(
                value.span(),
                format!(
                    "{ctx}: `{key}` has {} components but the scene is {dim}D (set by the length of `gravity`)",
                    v.len(),
                ),
            ));
        }
        Ok(v)
    }

    /// A located model error.
    fn model(&self, span: Range<usize>, ctx: &str, e: ModelError) -> SceneError {
        self.src.error(span, format!("{ctx}: {e}"))
    }

    fn required<'v, T>(
        &self,
        value: &'v Option<Spanned<T>>,
        table: Range<usize>,
        ctx: &str,
        key: &str,
    ) -> Result<&'v Spanned<T>> {
        value
            .as_ref()
            .ok_or_else(|| self.src.error(table, format!("{ctx}: missing `{key}`")))
    }

    /// `[run]`.
    fn run(&self, run: Option<&Spanned<RunDef>>, has_parametric: bool) -> Result<RunDefaults> {
        let Some(run) = run else {
            return Ok(RunDefaults::default());
        };
        let r = run.get_ref();
        let ctx = "run";
        let mut out = RunDefaults::default();
        if let Some(m) = &r.method {
            let method: Method = m
                .get_ref()
                .parse()
                .map_err(|e| self.src.error(m.span(), format!("{ctx}: {e}")))?;
            if method == Method::Parametric && !has_parametric {
                return Err(self.src.error(
                    m.span(),
                    format!("{ctx}: method `parametric` needs a `[parametric]` table, and the scene has none"),
                ));
            }
            out.method = Some(method);
        }
        if let Some(i) = &r.integrator {
            let kind: IntegratorKind = i
                .get_ref()
                .parse()
                .map_err(|e| self.src.error(i.span(), format!("{ctx}: {e}")))?;
            out.integrator = Some(kind);
        }
        if let Some(dt) = &r.dt {
            out.dt = Some(self.positive(dt, ctx, "`dt`")?);
        }
        if let Some(d) = &r.duration {
            out.duration = Some(self.positive(d, ctx, "`duration`")?);
        }
        if let Some(s) = &r.steps {
            let v = self.number(s, ctx, "`steps`")?;
            if !(v >= 1.0 && v.fract() == 0.0 && v <= LARGEST_INTEGER) {
                return Err(self.src.error(
                    s.span(),
                    format!(
                        "{ctx}: `steps` must be a positive integer, got {}",
                        crate::readable(v)
                    ),
                ));
            }
            out.steps = Some(v as u64);
        }
        if let Some(k) = &r.event_samples {
            let v = self.number(k, ctx, "`event_samples`")?;
            let max = crate::simulate::MAX_EVENT_SAMPLES;
            if !(v >= 0.0 && v.fract() == 0.0 && v <= max as f64) {
                return Err(self.src.error(
                    k.span(),
                    format!(
                        "{ctx}: `event_samples` must be a whole number from 0 to {max}, got {}",
                        crate::readable(v)
                    ),
                ));
            }
            out.event_samples = Some(v as u32);
        }
        if let (Some(_), Some(s)) = (&r.duration, &r.steps) {
            return Err(self.src.error(
                s.span(),
                format!("{ctx}: give `duration` or `steps`, not both"),
            ));
        }
        if let Some(s) = &r.stabilize {
            let feedback = match s.get_ref() {
                Stabilize::Gains(gains) => {
                    if gains.len() != 2 {
                        return Err(self.src.error(
                            s.span(),
                            format!(
                                "{ctx}: `stabilize` must be `[ks, kd]` or `{{ frequency = f, damping = zeta }}`, got {} number{}",
                                gains.len(),
                                if gains.len() == 1 { "" } else { "s" }
                            ),
                        ));
                    }
                    Feedback {
                        ks: self.non_negative(&gains[0], ctx, "`stabilize` ks")?,
                        kd: self.non_negative(&gains[1], ctx, "`stabilize` kd")?,
                    }
                }
                Stabilize::Frequency(t) => {
                    let f = t.frequency.as_ref().ok_or_else(|| {
                        self.src.error(
                            s.span(),
                            format!("{ctx}: `stabilize` table: missing `frequency`"),
                        )
                    })?;
                    let frequency = self.positive(f, ctx, "`stabilize` frequency")?;
                    let damping = match &t.damping {
                        Some(d) => self.non_negative(d, ctx, "`stabilize` damping")?,
                        None => 1.0,
                    };
                    Feedback::from_frequency(frequency, damping)
                }
            };
            if out.method == Some(Method::Parametric) && feedback != Feedback::default() {
                return Err(self.src.error(
                    s.span(),
                    format!("{ctx}: `stabilize` applies to the implicit method only, and `method` is parametric"),
                ));
            }
            out.stabilize = Some(feedback);
        }
        Ok(out)
    }
}

/// The state of [`Loader::repetitions`] while it goes through the ranges of one `for`.
struct Walk<'r> {
    ranges: &'r [(Spanned<String>, Spanned<RangeText>)],
    /// The `for` value, where a count error points.
    span: Range<usize>,
    /// `particle 2`: the table, for messages.
    table: &'r str,
    /// How many repetitions the scene may still make.
    budget: usize,
    /// Per loop variable, how many values it has taken so far (over all outer values).
    taken: Vec<usize>,
    out: Vec<Scope>,
}

impl Walk<'_> {
    /// The message for more than `budget` combinations of the first `level + 1` variables
    /// (at the last level, more than `budget` repetitions).
    fn too_many(&self, level: usize) -> String {
        let what = if level + 1 == self.ranges.len() {
            format!("repeats the table more than {} times", self.budget)
        } else {
            let names: Vec<String> = self.ranges[..=level]
                .iter()
                .map(|(n, _)| format!("`{}`", n.get_ref()))
                .collect();
            format!(
                "goes through more than {} combinations of values of {}",
                self.budget,
                names.join(", ")
            )
        };
        let made = MAX_REPETITIONS - self.budget;
        let limit = if made == 0 {
            format!("a scene may make at most {MAX_REPETITIONS} repetitions in all")
        } else {
            format!("the tables before it made {made} of the {MAX_REPETITIONS} repetitions a scene may make in all")
        };
        format!("{}: `for` {what}; {limit}", self.table)
    }
}

/// The limit on generated text, and what the tables before used of it, for a message.
fn expansion_limit(limit: usize, before: usize) -> String {
    let limit = if limit == MAX_EXPANDED_BYTES {
        format!(
            "{} MiB ({MAX_EXPANDED_BYTES} bytes)",
            MAX_EXPANDED_BYTES >> 20
        )
    } else {
        format!("{limit} bytes")
    };
    let limit = format!("a scene's generated tables may expand to at most {limit} of text in all");
    if before == 0 {
        limit
    } else {
        format!(
            "{limit}, and the tables before it expanded to {}",
            crate::byte_size(before as u64)
        )
    }
}

/// The value of an expression without variables.
fn constant_value(expr: &Expr) -> f64 {
    match expr.as_constant() {
        Some(v) => v,
        None if expr.vars().is_empty() => expr.eval(&[]),
        None => f64::NAN,
    }
}

/// Titles and names are labels, shown on terminals, in reports, plots and the viewer: a
/// control character in one (an escape sequence, a newline) is refused where it is written,
/// rather than escaped in every place that shows it.
fn no_control_characters(src: &Source, value: &Spanned<String>, what: &str) -> Result<()> {
    match value.get_ref().chars().find(|c| c.is_control()) {
        Some(c) => Err(src.error(
            value.span(),
            format!(
                "{what} must not contain control characters, found `{}`",
                crate::printable(c.encode_utf8(&mut [0; 4]))
            ),
        )),
        None => Ok(()),
    }
}

/// The names a scene gives (parameters, coordinates; particles through the builder) are the
/// expression parser's identifiers, so every accepted name can be used in an expression.
fn is_identifier(name: &str) -> bool {
    crate::expr::is_identifier(name)
}

/// The system being built, with the particles' names and initial positions.
struct Builder<'a> {
    loader: Loader<'a>,
    b: SystemBuilder,
    dim: usize,
    particles: Vec<(String, Vec<f64>)>,
    /// Per particle, the table (and repetition) that made it, for messages about duplicates.
    particle_origins: Vec<String>,
    /// Constraint names taken so far, with the table (and repetition) that took each.
    constraint_names: HashMap<String, String>,
    /// The tables with a `for` key, and what they made.
    generated: Vec<Generated>,
    /// Forces added so far.
    forces: usize,
    /// Repetitions made so far by the tables with `for` (at most [`MAX_REPETITIONS`]).
    repeated: usize,
    /// Where each particle and constraint is given, for the scene's warnings.
    lines: Lines,
}

impl Builder<'_> {
    fn src(&self) -> &Source<'_> {
        &self.loader.src
    }

    /// Read table `i` of `kind` with `read`: once, or, with `for`, once per repetition with
    /// its loop variables in scope.
    fn repeat<T: StringBytes>(
        &mut self,
        kind: TableKind,
        i: usize,
        table: &Spanned<T>,
        repeat: &Option<Spanned<Entries<RangeText>>>,
        read: impl Fn(&mut Self, usize, &Spanned<T>) -> Result<()>,
    ) -> Result<()> {
        let Some(repeat) = repeat else {
            self.loader.scope = Some(Scope::default());
            read(self, i, table)?;
            self.loader.scope = None;
            return Ok(());
        };
        let b = &self.b;
        let table_name = format!("{} {}", kind.name(), i + 1);
        let scopes = self.loader.repetitions(
            repeat,
            &table_name,
            MAX_REPETITIONS - self.repeated,
            &|name| b.particle_id(name).is_ok(),
        )?;
        self.repeated += scopes.len();
        // The text this table will expand to, refused before any of it is made: its strings
        // as written, once per repetition.
        let before = self.loader.expanded.get();
        let written = table.get_ref().string_bytes();
        let estimate = written.saturating_mul(scopes.len());
        let limit = self.loader.limit;
        if before.saturating_add(estimate) > limit {
            return Err(self.src().error(
                repeat.span(),
                format!(
                    "{table_name}: `for` would expand the table's {} of strings {} times, to \
                     about {} of text; {}",
                    crate::byte_size(written as u64),
                    scopes.len(),
                    crate::byte_size(estimate as u64),
                    expansion_limit(limit, before)
                ),
            ));
        }
        let first = self.made(kind);
        let count = scopes.len();
        for (k, scope) in scopes.into_iter().enumerate() {
            let vars = scope.describe();
            self.loader.scope = Some(scope);
            read(self, i, table)?;
            // `{...}` can make a string longer than written: checked as it grows.
            if self.loader.expanded.get() > limit {
                return Err(self.src().error(
                    repeat.span(),
                    format!(
                        "{table_name}: `for` has expanded the table's strings to {} of text by \
                         its repetition {} of {count} ({vars}); {}",
                        crate::byte_size((self.loader.expanded.get() - before) as u64),
                        k + 1,
                        expansion_limit(limit, before)
                    ),
                ));
            }
        }
        self.loader.scope = None;
        let ranges = repeat
            .get_ref()
            .0
            .iter()
            .map(|(name, range)| format!("{} = {}", name.get_ref(), range.get_ref().0))
            .collect::<Vec<_>>()
            .join(", ");
        self.generated.push(Generated {
            kind,
            table: i + 1,
            line: self.src().line_of(table.span().start),
            ranges,
            items: first..self.made(kind),
        });
        Ok(())
    }

    /// How many items of `kind` the scene has so far.
    fn made(&self, kind: TableKind) -> usize {
        match kind {
            TableKind::Particle => self.particles.len(),
            TableKind::Constraint => self.constraint_names.len(),
            TableKind::Force => self.forces,
        }
    }

    /// `particle 2`, or in a repetition of a generated table `particle 2 (i = 3, j = 0)`.
    fn ctx(&self, kind: TableKind, i: usize) -> String {
        match self.loader.scope.as_ref().filter(|s| !s.vars.is_empty()) {
            Some(scope) => format!("{} {} ({})", kind.name(), i + 1, scope.describe()),
            None => format!("{} {}", kind.name(), i + 1),
        }
    }

    /// Whether the table being read has a `for` key.
    fn generated_table(&self) -> bool {
        self.loader
            .scope
            .as_ref()
            .is_some_and(|s| !s.vars.is_empty())
    }

    /// A name as written, with its `{...}` replaced (particle and constraint names,
    /// references to particles).
    fn name(&self, value: &Spanned<String>, ctx: &str) -> Result<String> {
        let expanded = self.loader.expand(value.span(), value.get_ref(), ctx)?;
        Ok(expanded.text.into_owned())
    }

    /// A vector of this scene's dimension.
    fn vector(&self, value: &Spanned<NumVec>, ctx: &str, key: &str) -> Result<Vec<f64>> {
        self.loader.dim_vector(value, ctx, key, self.dim)
    }

    fn particle_list(&self) -> String {
        crate::name_list(self.particles.iter().map(|(n, _)| n.as_str()))
    }

    /// Look up a particle named by a string value (with its `{...}` replaced).
    fn lookup(&self, name: &Spanned<String>, ctx: &str) -> Result<ParticleId> {
        let expanded = self.name(name, ctx)?;
        self.b.particle_id(&expanded).map_err(|_| {
            self.src().error(
                name.span(),
                format!(
                    "{ctx}: unknown particle `{}`; particles: {}",
                    crate::printable(&expanded),
                    self.particle_list()
                ),
            )
        })
    }

    /// The message for a name given twice: where it was given first when either is in a
    /// generated table, and, when a generated table gives the same name in every repetition,
    /// how to vary it.
    fn duplicate(&self, ctx: &str, what: &str, name: &str, written: &str, earlier: &str) -> String {
        let mut message = format!("{ctx}: duplicate {what} name `{name}`");
        if self.generated_table() || earlier.contains('(') {
            message.push_str(&format!(", made before by {earlier}"));
        }
        if self.generated_table() && !written.contains('{') {
            message.push_str(&format!(
                "; every repetition gives the same name: put a loop variable in it, e.g. `{written}{{{}}}`",
                self.loader.scope.as_ref().map_or("i", |s| s.vars[0].0.as_str())
            ));
        }
        message
    }

    fn particle(&mut self, i: usize, p: &Spanned<ParticleDef>) -> Result<()> {
        let ctx = self.ctx(TableKind::Particle, i);
        let def = p.get_ref();
        let l = &self.loader;
        let name_def = l.required(&def.name, p.span(), &ctx, "name")?;
        let mass_def = l.required(&def.mass, p.span(), &ctx, "mass")?;
        let position_def = l.required(&def.position, p.span(), &ctx, "position")?;
        let name = self.name(name_def, &ctx)?;
        if let Ok(earlier) = self.b.particle_id(&name) {
            return Err(self.src().error(
                name_def.span(),
                self.duplicate(
                    &ctx,
                    "particle",
                    &name,
                    name_def.get_ref(),
                    &self.particle_origins[earlier.0],
                ),
            ));
        }
        let mass = self.loader.positive(mass_def, &ctx, "`mass`")?;
        let (lightest, heaviest) = crate::model::MASS_RANGE;
        if !(lightest..=heaviest).contains(&mass) {
            // The builder refuses it too, but located at the name; point at the mass.
            return Err(self.src().error(
                mass_def.span(),
                format!(
                    "{ctx}: `mass` must be between {} and {}, got {}: masses, their inverses and momenta must stay far from overflow and underflow",
                    crate::readable(lightest),
                    crate::readable(heaviest),
                    crate::readable(mass)
                ),
            ));
        }
        let position = self.vector(position_def, &ctx, "position")?;
        let velocity = match &def.velocity {
            Some(v) => self.vector(v, &ctx, "velocity")?,
            None => vec![0.0; self.dim],
        };
        self.b
            .particle(&name, mass, &position, &velocity)
            .map_err(|e| l.model(name_def.span(), &ctx, e))?;
        self.particles.push((name, position));
        self.particle_origins.push(ctx);
        let line = |span: Range<usize>| self.loader.src.line_of(span.start);
        let position_line = line(position_def.span());
        let velocity_line = def
            .velocity
            .as_ref()
            .map_or(position_line, |v| line(v.span()));
        self.lines.position.push(position_line);
        self.lines.velocity.push(velocity_line);
        Ok(())
    }

    /// Reject keys that do not belong to `kind`.
    fn reject(&self, ctx: &str, kind: &str, keys: &[(&str, Option<Range<usize>>)]) -> Result<()> {
        for (key, span) in keys {
            if let Some(span) = span {
                return Err(self.src().error(
                    span.clone(),
                    format!("{ctx}: `{key}` does not apply to {kind}"),
                ));
            }
        }
        Ok(())
    }

    /// `between = ["a", "b"]` or `particle = "a", anchor = [..]`: the first particle and the
    /// other end. `anchor_default` supplies a missing anchor (None: the anchor is required).
    fn endpoints(
        &self,
        ctx: &str,
        table: Range<usize>,
        between: &Option<Spanned<Names>>,
        particle: &Option<Spanned<String>>,
        anchor: &Option<Spanned<NumVec>>,
        what: &str,
    ) -> Result<(ParticleId, Endpoint)> {
        match (between, particle) {
            (Some(between), None) => {
                if let Some(a) = anchor {
                    return Err(self.src().error(
                        a.span(),
                        format!("{ctx}: `anchor` goes with `particle`, not with `between`"),
                    ));
                }
                let names = &between.get_ref().0;
                if names.len() != 2 {
                    return Err(self.src().error(
                        between.span(),
                        format!("{ctx}: `between` must name 2 particles, got {}", names.len()),
                    ));
                }
                let a = self.lookup(&names[0], ctx)?;
                let b = self.lookup(&names[1], ctx)?;
                if a == b {
                    return Err(self.src().error(between.span(), format!("{ctx}: `between` names the same particle twice")));
                }
                Ok((a, Endpoint::Particle(b)))
            }
            (None, Some(p)) => {
                let a = self.lookup(p, ctx)?;
                let anchor = anchor.as_ref().ok_or_else(|| {
                    self.src().error(table.clone(), format!("{ctx}: missing `anchor` (the fixed end of the {what})"))
                })?;
                Ok((a, Endpoint::Fixed(self.vector(anchor, ctx, "anchor")?)))
            }
            (Some(between), Some(_)) => Err(self.src().error(
                between.span(),
                format!("{ctx}: give either `between` or `particle` and `anchor`, not both"),
            )),
            (None, None) => Err(self.src().error(
                table,
                format!("{ctx}: missing `between` (two particles) or `particle` and `anchor` (a fixed end)"),
            )),
        }
    }

    fn force(&mut self, i: usize, f: &Spanned<ForceDef>) -> Result<()> {
        let ctx = self.ctx(TableKind::Force, i);
        let d = f.get_ref();
        let l = &self.loader;
        let kind = l.required(&d.kind, f.span(), &ctx, "kind")?;
        let force = match kind.get_ref().as_str() {
            "constant" => {
                self.reject(
                    &ctx,
                    "a constant force",
                    &[
                        ("between", span_of(&d.between)),
                        ("anchor", span_of(&d.anchor)),
                        ("stiffness", span_of(&d.stiffness)),
                        ("rest_length", span_of(&d.rest_length)),
                        ("coefficient", span_of(&d.coefficient)),
                    ],
                )?;
                let particle =
                    self.lookup(l.required(&d.particle, f.span(), &ctx, "particle")?, &ctx)?;
                let vector = self.vector(
                    l.required(&d.vector, f.span(), &ctx, "vector")?,
                    &ctx,
                    "vector",
                )?;
                Force::Constant { particle, vector }
            }
            "spring" => {
                self.reject(
                    &ctx,
                    "a spring",
                    &[
                        ("vector", span_of(&d.vector)),
                        ("coefficient", span_of(&d.coefficient)),
                    ],
                )?;
                let (a, b) =
                    self.endpoints(&ctx, f.span(), &d.between, &d.particle, &d.anchor, "spring")?;
                let stiffness = l.non_negative(
                    l.required(&d.stiffness, f.span(), &ctx, "stiffness")?,
                    &ctx,
                    "`stiffness`",
                )?;
                let rest_length = match &d.rest_length {
                    Some(r) => l.non_negative(r, &ctx, "`rest_length`")?,
                    None => 0.0,
                };
                Force::Spring {
                    a,
                    b,
                    stiffness,
                    rest_length,
                }
            }
            "drag" => {
                self.reject(
                    &ctx,
                    "drag",
                    &[
                        ("between", span_of(&d.between)),
                        ("anchor", span_of(&d.anchor)),
                        ("vector", span_of(&d.vector)),
                        ("stiffness", span_of(&d.stiffness)),
                        ("rest_length", span_of(&d.rest_length)),
                    ],
                )?;
                let particle = d
                    .particle
                    .as_ref()
                    .map(|p| self.lookup(p, &ctx))
                    .transpose()?;
                let coefficient = l.non_negative(
                    l.required(&d.coefficient, f.span(), &ctx, "coefficient")?,
                    &ctx,
                    "`coefficient`",
                )?;
                Force::Drag {
                    particle,
                    coefficient,
                }
            }
            other => {
                return Err(self.src().error(
                    kind.span(),
                    format!("{ctx}: unknown kind `{other}`; use constant, spring or drag"),
                ))
            }
        };
        self.b
            .force(force)
            .map_err(|e| l.model(f.span(), &ctx, e))?;
        self.forces += 1;
        Ok(())
    }

    fn constraint(&mut self, i: usize, c: &Spanned<ConstraintDef>) -> Result<()> {
        let ctx = self.ctx(TableKind::Constraint, i);
        let d = c.get_ref();
        let at = d.expr.as_ref().map_or(c.span(), |e| e.span());
        self.lines
            .constraint
            .push(self.loader.src.line_of(at.start));
        let l = &self.loader;
        let name = match &d.name {
            Some(n) => {
                if n.get_ref().trim().is_empty() {
                    return Err(self
                        .src()
                        .error(n.span(), format!("{ctx}: `name` must not be empty")));
                }
                no_control_characters(self.src(), n, &format!("{ctx}: `name`"))?;
                let name = self.name(n, &ctx)?;
                if let Some(earlier) = self.constraint_names.get(&name) {
                    return Err(self.src().error(
                        n.span(),
                        self.duplicate(&ctx, "constraint", &name, n.get_ref(), earlier),
                    ));
                }
                name
            }
            None => {
                // `constraint 2`, or in a generated table `constraint 2 (i = 3)`.
                let default = ctx.clone();
                if self.constraint_names.contains_key(&default) {
                    return Err(self.src().error(
                        c.span(),
                        format!("{ctx}: its default name `{default}` is taken by an earlier constraint; give it a `name`"),
                    ));
                }
                default
            }
        };
        self.constraint_names.insert(name.clone(), ctx.clone());
        let kind = d
            .kind
            .as_ref()
            .map(|k| k.get_ref().as_str())
            .unwrap_or("expression");
        match kind {
            "expression" => {
                self.reject(
                    &ctx,
                    "an expression constraint",
                    &[
                        ("particle", span_of(&d.particle)),
                        ("between", span_of(&d.between)),
                        ("anchor", span_of(&d.anchor)),
                        ("length", span_of(&d.length)),
                    ],
                )?;
                let e = l.required(&d.expr, c.span(), &ctx, "expr")?;
                let source = e.get_ref();
                // `{...}` first (particle names like `p{i-1}.x`), then the loop variables as
                // numbers, then the builder's names; errors point into the text as written.
                let expanded = l.expand(e.span(), source, &ctx)?;
                let scope = l.scope.as_ref();
                let resolve = |name: &str| match scope.and_then(|s| s.value(name)) {
                    Some(v) => Ok(Resolved::Value(v)),
                    None => self.b.resolve_constraint_name(name).map_err(|message| {
                        match scope.filter(|s| !s.vars.is_empty()) {
                            Some(s) => format!(
                                "{message}; here also the loop variables ({})",
                                crate::name_list(s.vars.iter().map(|(n, _)| n.as_str()))
                            ),
                            None => message,
                        }
                    }),
                };
                let expr = parse(&expanded.text, &resolve)
                    .map_err(|err| l.string_error(e.span(), source, &ctx, expanded.error(&err)))?;
                let n = self.particles.len() * self.dim;
                if !expr.vars().iter().any(|&k| k < n) {
                    return Err(self.src().error(
                        e.span(),
                        format!("{ctx}: the expression does not depend on any particle coordinate"),
                    ));
                }
                // The system keeps a text that stands alone: no `{...}`, no loop variables.
                let standalone = match scope {
                    Some(scope) => scope.substitute(&expanded.text),
                    None => expanded.text.into_owned(),
                };
                self.b.add_constraint_expr(&name, expr, &standalone);
            }
            "distance" => {
                self.reject(&ctx, "a distance constraint", &[("expr", span_of(&d.expr))])?;
                let (a, b) =
                    self.endpoints(&ctx, c.span(), &d.between, &d.particle, &d.anchor, "rod")?;
                let length = match &d.length {
                    Some(len) => l.positive(len, &ctx, "`length`")?,
                    None => {
                        // The initial distance.
                        let pa = &self.position(a);
                        let pb = match &b {
                            Endpoint::Particle(p) => self.position(*p),
                            Endpoint::Fixed(point) => point.clone(),
                        };
                        let len = pa
                            .iter()
                            .zip(&pb)
                            .map(|(x, y)| (x - y) * (x - y))
                            .sum::<f64>()
                            .sqrt();
                        if len <= 0.0 {
                            return Err(self.src().error(
                                c.span(),
                                format!("{ctx}: missing `length`, and the initial distance is 0"),
                            ));
                        }
                        len
                    }
                };
                self.b
                    .distance(&name, a, b, length)
                    .map_err(|e| l.model(c.span(), &ctx, e))?;
            }
            "pin" => {
                self.reject(
                    &ctx,
                    "a pin",
                    &[
                        ("expr", span_of(&d.expr)),
                        ("between", span_of(&d.between)),
                        ("length", span_of(&d.length)),
                    ],
                )?;
                let p = self.lookup(l.required(&d.particle, c.span(), &ctx, "particle")?, &ctx)?;
                let anchor = match &d.anchor {
                    Some(a) => self.vector(a, &ctx, "anchor")?,
                    None => self.position(p),
                };
                self.reject(
                    &ctx,
                    "a pin (only a scalar constraint, an expression or a distance, can be unilateral)",
                    &[
                        ("side", span_of(&d.side)),
                        ("restitution", span_of(&d.restitution)),
                    ],
                )?;
                self.b
                    .pin(&name, p, &anchor)
                    .map_err(|e| l.model(c.span(), &ctx, e))?;
            }
            other => {
                let span = d.kind.as_ref().map(|k| k.span()).unwrap_or(c.span());
                return Err(self.src().error(
                    span,
                    format!("{ctx}: unknown kind `{other}`; use expression (the default), distance or pin"),
                ));
            }
        }
        self.unilateral(&ctx, c)
    }

    /// `side` and `restitution` of the constraint table just read: a unilateral constraint.
    fn unilateral(&mut self, ctx: &str, c: &Spanned<ConstraintDef>) -> Result<()> {
        let d = c.get_ref();
        let l = &self.loader;
        let Some(side) = &d.side else {
            if let Some(e) = &d.restitution {
                return Err(self.src().error(
                    e.span(),
                    format!("{ctx}: `restitution` applies to a unilateral constraint only; add `side = \"above\"` (C >= 0) or `side = \"below\"` (C <= 0)"),
                ));
            }
            return Ok(());
        };
        let parsed: crate::model::Side = side.get_ref().parse().map_err(|message: String| {
            self.src().error(side.span(), format!("{ctx}: {message}"))
        })?;
        let restitution = match &d.restitution {
            Some(e) => {
                let value = l.number(e, ctx, "`restitution`")?;
                if !(0.0..=1.0).contains(&value) {
                    return Err(self.src().error(
                        e.span(),
                        format!(
                            "{ctx}: `restitution` must be between 0 (a plastic landing) and 1 (an elastic bounce), got {}",
                            crate::readable(value)
                        ),
                    ));
                }
                value
            }
            None => 0.0,
        };
        self.b
            .unilateral(parsed, restitution)
            .map_err(|e| l.model(side.span(), ctx, e))?;
        Ok(())
    }

    /// A particle's initial position as given.
    fn position(&self, p: ParticleId) -> Vec<f64> {
        self.particles[p.0].1.clone()
    }

    fn parametric(&mut self, p: &Spanned<ParametricDef>) -> Result<()> {
        let ctx = "parametric";
        let d = p.get_ref();
        let l = &self.loader;
        let coords_def = l.required(&d.coordinates, p.span(), ctx, "coordinates")?;
        let coords = &coords_def.get_ref().0;
        if coords.is_empty() {
            return Err(self.src().error(
                coords_def.span(),
                format!("{ctx}: `coordinates` must name at least one coordinate"),
            ));
        }
        for (i, c) in coords.iter().enumerate() {
            let name = c.get_ref();
            if !is_identifier(name) {
                return Err(self.src().error(
                    c.span(),
                    format!("{ctx}: coordinate name `{name}` must be a letter or `_` followed by letters, digits or `_`"),
                ));
            }
            if RESERVED.contains(&name.as_str()) || Func::from_name(name).is_some() {
                return Err(self.src().error(
                    c.span(),
                    format!("{ctx}: `{name}` is reserved and cannot name a coordinate"),
                ));
            }
            if self.b.param_value(name).is_some() {
                return Err(self.src().error(
                    c.span(),
                    format!("{ctx}: coordinate `{name}` has the name of a parameter; rename one of them"),
                ));
            }
            if coords[..i].iter().any(|o| o.get_ref() == name) {
                return Err(self
                    .src()
                    .error(c.span(), format!("{ctx}: duplicate coordinate `{name}`")));
            }
        }
        let n_q = coords.len();
        let counted = |what: &str, v: &Spanned<NumVec>| -> Result<Vec<f64>> {
            let values = l.vector(v, ctx, &format!("`{what}`"))?;
            if values.len() != n_q {
                return Err(self.src().error(
                    v.span(),
                    format!(
                        "{ctx}: `{what}` has {} values for {n_q} coordinate{} ({})",
                        values.len(),
                        if n_q == 1 { "" } else { "s" },
                        coords
                            .iter()
                            .map(|c| c.get_ref().as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ));
            }
            Ok(values)
        };
        let initial = counted("initial", l.required(&d.initial, p.span(), ctx, "initial")?)?;
        let rates = match &d.rates {
            Some(r) => counted("rates", r)?,
            None => vec![0.0; n_q],
        };
        let names: Vec<&str> = coords.iter().map(|c| c.get_ref().as_str()).collect();
        self.b
            .parametric(&names, &initial, &rates)
            .map_err(|e| l.model(p.span(), ctx, e))?;

        let positions = d.positions.as_ref().ok_or_else(|| {
            self.src().error(
                p.span(),
                format!("{ctx}: missing `positions` (a table giving each particle's position as expressions of the coordinates)"),
            )
        })?;
        let mut given = vec![false; self.particles.len()];
        for (key, value) in &positions.get_ref().0 {
            let pctx = format!("{ctx}: position of `{}`", key.get_ref());
            let id = self.lookup(key, ctx)?;
            let components = &value.get_ref().0;
            if components.len() != self.dim {
                return Err(self.src().error(
                    value.span(),
                    format!(
                        "{pctx} has {} components but the scene is {}D (set by the length of `gravity`)",
                        components.len(),
                        self.dim
                    ),
                ));
            }
            let mut exprs = Vec::with_capacity(self.dim);
            let mut sources = Vec::with_capacity(self.dim);
            for c in components {
                let expr = match c.get_ref() {
                    Num::Value(v) => {
                        if !v.is_finite() {
                            return Err(self.src().error(
                                c.span(),
                                format!(
                                    "{pctx}: components must be finite, got {}",
                                    crate::readable(*v)
                                ),
                            ));
                        }
                        sources.push(None);
                        Expr::constant(*v)
                    }
                    Num::Expr(source) => {
                        sources.push(Some(source.clone()));
                        self.b.parse_parametric_expr(source).map_err(|err| {
                            self.src().expr_error(
                                c.span(),
                                source,
                                &err,
                                format!("{pctx}: {}", err.message),
                            )
                        })?
                    }
                };
                exprs.push(expr);
            }
            self.b
                .parametric_position_with_sources(key.get_ref(), exprs, sources)
                .map_err(|e| l.model(key.span(), ctx, e))?;
            given[id.0] = true;
        }
        if let Some(missing) = given.iter().position(|g| !g) {
            return Err(self.src().error(
                positions.span(),
                format!(
                    "{ctx}: no position for particle `{}`; every particle needs one",
                    self.particles[missing].0
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `{...}` that expand to more than they are written pass the estimate (written bytes x
    /// repetitions) and are refused as they grow, at the repetition that passes the limit.
    #[test]
    fn expansions_that_grow_past_the_limit_are_refused_as_they_grow() {
        let scene = |count: usize| {
            format!(
                "[params]\nB = 1e15\n[world]\ngravity = [0.0, 1.0]\n[[particle]]\nfor = {{ i = \"0..{count}\" }}\nname = \"p{{i}}_{}\"\nmass = 1.0\nposition = [\"i\", 0.0]\n",
                "{B}".repeat(10)
            )
        };
        // Written: 36 bytes a repetition; expanded: 163 to 167 (B has 16 digits).
        let limit = 100 * 36;
        assert!(load_limited(&scene(20), "s.toml", &[], None, limit).is_ok());
        let error = load_limited(&scene(50), "s.toml", &[], None, limit)
            .unwrap_err()
            .to_string();
        assert!(
            error.starts_with(
                "s.toml:6:7: particle 1: `for` has expanded the table's strings to 3.62 kB of text by its repetition 22 of 50 (i = 21); a scene's generated tables may expand to at most 3600 bytes of text in all\n"
            ),
            "{error}"
        );
        // The tables before count: a second table that would pass what the first left.
        let two = format!(
            "{}[[particle]]\nfor = {{ j = \"0..10\" }}\nname = \"q{{j}}\"\nmass = 1.0\nposition = [\"j\", 1.0]\n",
            scene(20)
        );
        let error = load_limited(&two, "s.toml", &[], None, 3300)
            .unwrap_err()
            .to_string();
        assert!(
            error.starts_with(
                "s.toml:11:7: particle 2: `for` would expand the table's 5 bytes of strings 10 times, to about 50 bytes of text; a scene's generated tables may expand to at most 3300 bytes of text in all, and the tables before it expanded to 3.29 kB\n"
            ),
            "{error}"
        );
        // Written bytes times repetitions past the limit: refused before any is read.
        let error = load_limited(&scene(101), "s.toml", &[], None, limit)
            .unwrap_err()
            .to_string();
        assert!(
            error.starts_with(
                "s.toml:6:7: particle 1: `for` would expand the table's 36 bytes of strings 101 times, to about 3.64 kB of text; a scene's generated tables may expand"
            ),
            "{error}"
        );
    }
}
