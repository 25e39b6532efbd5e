//! A scene at other parameter values without loading it again, when the values change only
//! where it starts: the members of a sweep over a release point, an initial angle or speed.
//!
//! [`Scene::rebinder`] reads the scene's text once and finds where the parameters swept reach,
//! following the parameters defined from them (`m = "L/2"`): every string of the file is
//! searched for their names (a superset of the names its expressions read), and every place
//! counts as part of the equations of motion except the particles' `position` and `velocity`
//! (in tables without `for`), the `[parametric]` `initial` and `rates`, and the `[run]`
//! table's `stop_when` (which a sweep parses itself). When they reach nothing else, a
//! [`Rebinder`] gives the scene's system at other values ([`Rebinder::system`]): the
//! parameters and those initial values evaluated by the loader's own code, over the scene's
//! compiled equations, shared. It is the system [`Scene::with_params`] makes, bit for bit
//! (tested on every shipped scene), in microseconds instead of a load.

use std::sync::Arc;

use super::file::SceneFile;
use super::load;
use super::location::Source;
use super::{Scene, TableKind};
use crate::model::System;

/// The scene's text read once, and where the parameters swept reach: see the module
/// documentation.
#[derive(Debug)]
pub(crate) struct Rebinder {
    doc: SceneFile,
    text: Arc<str>,
    file: String,
    /// The overrides the scene was loaded with.
    overrides: Vec<(String, f64)>,
    base: Arc<System>,
    /// The parameters swept and every parameter defined from them.
    reached: Vec<String>,
    /// The `[[particle]]` tables whose position or velocity they reach, and their particles.
    tables: Vec<usize>,
    particles: Vec<usize>,
    /// Whether they reach the parametric form's initial values or rates.
    parametric: bool,
}

/// Where in a scene file a string is.
enum Place {
    /// A parameter's definition (its name).
    Param(String),
    /// A particle table's `position` or `velocity` (table index, 0-based).
    Start(usize),
    /// `[parametric]` `initial` or `rates`.
    ParametricStart,
    /// `[run] stop_when`: the sweep parses the stop condition itself.
    StopWhen,
    /// Anything else: the equations of motion, the run, the structure (described).
    Other(String),
}

impl Scene {
    /// A [`Rebinder`] for the parameters `names`, or where they (or a parameter defined from
    /// them) reach beyond the initial values, one place per entry (`` `g` reaches world
    /// `gravity` ``).
    pub(crate) fn rebinder(&self, names: &[String]) -> Result<Rebinder, Vec<String>> {
        if self.start.is_some() {
            return Err(vec![
                "the scene's start was set (with_state), which each member places again".into(),
            ]);
        }
        let unreadable = || vec!["the scene's text cannot be read again".to_string()];
        let raw: toml::Table = toml::from_str(&self.text).map_err(|_| unreadable())?;
        let doc: SceneFile = toml::from_str(&self.text).map_err(|_| unreadable())?;
        let places = places(&raw);
        // The parameters swept and, to a fixed point, those whose definitions name them.
        let mut reached: Vec<String> = names.to_vec();
        loop {
            let before = reached.len();
            for (place, found) in &places {
                if let Place::Param(name) = place {
                    if !reached.contains(name) && found.iter().any(|n| reached.contains(n)) {
                        reached.push(name.clone());
                    }
                }
            }
            if reached.len() == before {
                break;
            }
        }
        let reaching = |found: &[String]| found.iter().find(|n| reached.contains(n)).cloned();
        // A distance without `length` or a pin without `anchor` takes it from the initial
        // positions: then those are part of the equations.
        let defaults_from_positions = raw
            .get("constraint")
            .and_then(toml::Value::as_array)
            .into_iter()
            .flatten()
            .filter_map(toml::Value::as_table)
            .any(|c| match c.get("kind").and_then(toml::Value::as_str) {
                Some("distance") => !c.contains_key("length"),
                Some("pin") => !c.contains_key("anchor"),
                _ => false,
            });
        let mut why = Vec::new();
        let mut tables = Vec::new();
        let mut parametric = false;
        for (place, found) in &places {
            let Some(name) = reaching(found) else {
                continue;
            };
            match place {
                Place::Param(_) | Place::StopWhen => {}
                Place::Start(table) if defaults_from_positions => why.push(format!(
                    "`{name}` reaches particle {}'s initial state, from which a constraint \
                     without `length` or `anchor` takes it",
                    table + 1
                )),
                Place::Start(table) => {
                    if !tables.contains(table) {
                        tables.push(*table);
                    }
                }
                Place::ParametricStart => parametric = true,
                Place::Other(place) => why.push(format!("`{name}` reaches {place}")),
            }
        }
        for (index, source) in &self.edits {
            let mut found = Vec::new();
            names_in(source, &mut found);
            if let Some(name) = reaching(&found) {
                why.push(format!(
                    "`{name}` reaches the edited constraint {}",
                    index + 1
                ));
            }
        }
        if !why.is_empty() {
            return Err(why);
        }
        tables.sort_unstable();
        // Each table's particle: tables with `for` make as many as the scene says they made.
        let mut particles = Vec::with_capacity(tables.len());
        let mut next = 0;
        for (i, table) in doc.particle.0.iter().enumerate() {
            if table.get_ref().repeat.is_some() {
                next += self
                    .generated
                    .iter()
                    .find(|g| g.kind == TableKind::Particle && g.table == i + 1)
                    .map_or(0, |g| g.items.len());
            } else {
                if tables.contains(&i) {
                    particles.push(next);
                }
                next += 1;
            }
        }
        if next != self.system.particles().len() || particles.len() != tables.len() {
            return Err(vec![
                "the scene's particles cannot be matched to its tables".into(),
            ]);
        }
        Ok(Rebinder {
            doc,
            text: Arc::clone(&self.text),
            file: self.file.clone(),
            overrides: self.overrides.clone(),
            base: Arc::clone(&self.system),
            reached,
            tables,
            particles,
            parametric,
        })
    }
}

impl Rebinder {
    /// The system of [`Scene::with_params`]`(values)` (values of parameters swept), from the
    /// scene's compiled equations and the initial values evaluated again; `None` when the
    /// values make the scene invalid (a position that is not finite, a value that is not):
    /// then `with_params` says why.
    pub(crate) fn system(&self, values: &[(String, f64)]) -> Option<System> {
        let mut overrides = self.overrides.clone();
        overrides.retain(|(n, _)| !values.iter().any(|(name, _)| name == n));
        overrides.extend(values.iter().cloned());
        let src = Source {
            text: &self.text,
            file: &self.file,
        };
        let dim = self.base.dim();
        let read = load::initial_values(
            &self.doc,
            src,
            &overrides,
            &self.tables,
            self.parametric,
            dim,
        )
        .ok()?;
        let particles = self
            .particles
            .iter()
            .zip(read.particles)
            .map(|(&p, (x, v))| (p, x, v))
            .collect();
        let declared = self
            .base
            .declared
            .restarted(read.params, particles, read.parametric);
        Some(self.base.restarted(Arc::new(declared)))
    }

    /// Whether expression text `source` names a parameter swept or one defined from them.
    pub(crate) fn reaches(&self, source: &str) -> bool {
        let mut found = Vec::new();
        names_in(source, &mut found);
        found.iter().any(|n| self.reached.contains(n))
    }
}

/// Every string of the file (keys of free tables included) with the place it is in.
fn places(raw: &toml::Table) -> Vec<(Place, Vec<String>)> {
    let mut out = Vec::new();
    let collect = |value: &toml::Value| {
        let mut found = Vec::new();
        strings(value, &mut found);
        found
    };
    for (key, value) in raw {
        match (key.as_str(), value) {
            // Labels, never evaluated.
            ("title" | "about", _) => {}
            ("params", toml::Value::Table(params)) => {
                for (name, value) in params {
                    // A table's unit and description are labels, never evaluated.
                    let evaluated = match value.as_table() {
                        Some(table) => ["value", "range"]
                            .iter()
                            .filter_map(|k| table.get(*k))
                            .flat_map(collect)
                            .collect(),
                        None => collect(value),
                    };
                    out.push((Place::Param(name.clone()), evaluated));
                }
            }
            ("particle", toml::Value::Array(tables)) => {
                for (i, table) in tables.iter().enumerate() {
                    let Some(table) = table.as_table() else {
                        out.push((Place::Other(format!("particle {}", i + 1)), collect(table)));
                        continue;
                    };
                    let repeated = table.contains_key("for");
                    for (k, v) in table {
                        let place = if !repeated && (k == "position" || k == "velocity") {
                            Place::Start(i)
                        } else {
                            Place::Other(format!("particle {} `{k}`", i + 1))
                        };
                        out.push((place, collect(v)));
                    }
                }
            }
            ("parametric", toml::Value::Table(table)) => {
                for (k, v) in table {
                    let place = if k == "initial" || k == "rates" {
                        Place::ParametricStart
                    } else {
                        Place::Other(format!("parametric `{k}`"))
                    };
                    out.push((place, collect(v)));
                }
            }
            ("run", toml::Value::Table(table)) => {
                for (k, v) in table {
                    let place = if k == "stop_when" {
                        Place::StopWhen
                    } else {
                        Place::Other(format!("run `{k}`"))
                    };
                    out.push((place, collect(v)));
                }
            }
            (key, toml::Value::Array(tables)) => {
                for (i, table) in tables.iter().enumerate() {
                    match table.as_table() {
                        Some(table) => {
                            for (k, v) in table {
                                let place = Place::Other(format!("{key} {} `{k}`", i + 1));
                                out.push((place, collect(v)));
                            }
                        }
                        None => {
                            out.push((Place::Other(format!("{key} {}", i + 1)), collect(table)))
                        }
                    }
                }
            }
            (key, toml::Value::Table(table)) => {
                for (k, v) in table {
                    out.push((Place::Other(format!("{key} `{k}`")), collect(v)));
                }
            }
            (key, value) => out.push((Place::Other(format!("`{key}`")), collect(value))),
        }
    }
    out
}

/// The names in every string of `value` (and in the keys of its tables).
fn strings(value: &toml::Value, out: &mut Vec<String>) {
    match value {
        toml::Value::String(s) => names_in(s, out),
        toml::Value::Array(values) => values.iter().for_each(|v| strings(v, out)),
        toml::Value::Table(table) => {
            for (k, v) in table {
                names_in(k, out);
                strings(v, out);
            }
        }
        _ => {}
    }
}

/// Every name an expression in `text` may read, and more: each run of identifier characters
/// and each of its tails after a digit (so that `2L` and `1e5L` count `L`, whatever the
/// parser makes of them). Parameters are read by whole names without dots, each such a run
/// or a tail after a number.
fn names_in(text: &str, out: &mut Vec<String>) {
    for run in text.split(|c: char| !unicode_ident::is_xid_continue(c)) {
        if run.is_empty() {
            continue;
        }
        out.push(run.to_string());
        for (i, c) in run.char_indices() {
            if c.is_ascii_digit() && i + 1 < run.len() {
                out.push(run[i + 1..].to_string());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_found_in_expressions_and_after_numbers() {
        let mut found = Vec::new();
        names_in("-x0^2/100 + 2L*sin(th_1) + bead.x + {i}", &mut found);
        for name in ["x0", "L", "sin", "th_1", "bead", "x", "i"] {
            assert!(found.iter().any(|n| n == name), "{name} in {found:?}");
        }
    }
}
