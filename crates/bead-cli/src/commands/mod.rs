//! The subcommands, and what they share: loading a scene, running one formulation, writing
//! files and stdout.

mod check;
mod compare;
mod export_page;
mod grid;
mod order;
mod plot;
pub mod progress;
mod run;
mod serve;
mod sweep;

use std::fs::File;
use std::io::{self, Write};
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result};
use bead::output::{CsvTrace, Summary};
use bead::scene::Scene;
use bead::simulate::{
    self, Event, NullSink, RunFailure, RunStats, Simulation, SimulationConfig, Sink,
};

use crate::args::{Command, SimArgs};
use crate::plan::Plan;

/// Run a parsed command line.
pub fn dispatch(command: Command) -> Result<()> {
    match command {
        Command::Run(args) => run::run(&args),
        Command::Compare(args) => compare::compare(&args),
        Command::Sweep(args) => sweep::sweep(&args),
        Command::Check(args) => check::check(&args),
        Command::Order(args) => order::order(&args),
        Command::Plot(args) => plot::plot(&args),
        Command::Serve(args) => serve::serve(&args),
        Command::ExportPage(args) => export_page::export_page(&args),
    }
}

/// A usage error found after the flags were parsed (e.g. two outputs naming the same file):
/// exit code 2, like clap's.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Load a scene and print its warnings to stderr. A parameter `--set` twice is a usage
/// error (the library lets the last win, which the command line should not do silently).
fn load_scene(path: &Path, overrides: &[(String, f64)]) -> Result<Scene> {
    for (i, (name, value)) in overrides.iter().enumerate() {
        if let Some((_, first)) = overrides[..i].iter().find(|(n, _)| n == name) {
            return Err(Usage(format!(
                "--set {name} is given twice ({name}={} and {name}={}); give each parameter once",
                bead::readable(*first),
                bead::readable(*value)
            ))
            .into());
        }
    }
    // The scene error renders as `file:line:column: message` and a caret snippet.
    let scene = Scene::load(path, overrides)?;
    for warning in scene.warnings() {
        warn(&warning);
    }
    Ok(scene)
}

/// The stop condition of a run: `--stop-when`, parsed against the scene's system, else the
/// scene's `[run] stop_when`, else none. A bad `--stop-when` is a usage error showing where
/// in the expression.
fn stop_when(scene: &Scene, sim: &SimArgs) -> Result<Option<Event>> {
    match &sim.stop_when {
        Some(source) => match Event::parse(&scene.system, source) {
            Ok(event) => Ok(Some(event)),
            Err(e) => Err(Usage(format!(
                "--stop-when: {}",
                crate::numbers::NumberError::new(e.message, e.span.start, e.span.end)
                    .render(source)
            ))
            .into()),
        },
        None => Ok(scene.run.stop_when.clone()),
    }
}

/// Print `warning: MESSAGE` to stderr (a closed stderr is not worth a panic).
fn warn(message: &str) {
    let _ = writeln!(io::stderr(), "warning: {}", terminal(message));
}

/// `compare` applies --stabilize and --project to the implicit run only: say so when the scene
/// has none (a scene with a parametric form and no constraints), instead of ignoring them.
fn warn_implicit_only(plan: &Plan, methods: &[bead::formulation::Method]) {
    if methods.contains(&bead::formulation::Method::Implicit) {
        return;
    }
    let mut flags = Vec::new();
    if plan.feedback_requested {
        flags.push("--stabilize");
    }
    if plan.project {
        flags.push("--project");
    }
    if !flags.is_empty() {
        warn(&format!(
            "{} {} to the implicit form only, and the scene has no constraints: compare runs its parametric form alone; not used",
            flags.join(" and "),
            if flags.len() == 1 { "applies" } else { "apply" }
        ));
    }
}

/// Print `error: MESSAGE` to stderr, for errors beyond the one `main` reports.
fn report_error(message: &str) {
    let _ = writeln!(io::stderr(), "error: {}", terminal(message));
}

/// `text` safe for a terminal: control characters escaped (`\x1b`, `\r`, `\u{9b}`) except
/// the newlines and tabs of the layout. Scene labels (titles, names) with control characters
/// are refused when the scene is loaded; this catches what cannot be refused there: file
/// names, and text quoted in messages.
pub fn terminal(text: &str) -> std::borrow::Cow<'_, str> {
    if !text
        .chars()
        .any(|c| c.is_control() && c != '\n' && c != '\t')
    {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for line in text.split_inclusive(['\n', '\t']) {
        let (body, end) = match line.char_indices().last() {
            Some((i, c @ ('\n' | '\t'))) => (&line[..i], Some(c)),
            _ => (line, None),
        };
        out.push_str(&bead::printable(body));
        out.extend(end);
    }
    std::borrow::Cow::Owned(out)
}

/// One finished (or failed) run of one formulation.
struct Outcome {
    result: Result<RunStats, RunFailure>,
    summary: Summary,
}

/// Where a run writes its CSV trace, and whether with the constraint forces.
#[derive(Clone, Copy)]
struct Trace<'a> {
    path: &'a Path,
    constraint_forces: bool,
}

impl<'a> Trace<'a> {
    fn at(path: Option<&'a Path>, constraint_forces: bool) -> Option<Trace<'a>> {
        path.map(|path| Trace {
            path,
            constraint_forces,
        })
    }
}

/// Run `scene` as `config` says (checked by the library: an illegal combination or an
/// initial state that cannot be simulated is the error), with an optional CSV trace.
fn run_method(
    scene: &Scene,
    plan: &Plan,
    config: SimulationConfig,
    stop_when: Option<&Event>,
    trace: Option<Trace<'_>>,
) -> Result<Outcome> {
    run_method_with(scene, plan, config, stop_when, trace, None)
}

/// [`run_method`], also recording into `recorder` (for `compare --report`), with a progress
/// bar on a terminal for long runs.
fn run_method_with(
    scene: &Scene,
    plan: &Plan,
    config: SimulationConfig,
    stop_when: Option<&Event>,
    trace: Option<Trace<'_>>,
    recorder: Option<&mut dyn Sink>,
) -> Result<Outcome> {
    let mut simulation = Simulation::new(Arc::clone(&scene.system), config)?;
    simulation.set_events(scene.run.events_with(stop_when.cloned()))?;
    let coordinates = simulation.formulation().coordinate_names().to_vec();
    let mut sink: Box<dyn Sink> = match trace {
        Some(Trace {
            path,
            constraint_forces,
        }) => {
            let file = File::create(path)
                .with_context(|| format!("cannot create trace file `{}`", path.display()))?;
            let trace = if constraint_forces {
                CsvTrace::with_constraint_forces(file, &simulation)
            } else {
                CsvTrace::for_simulation(file, &simulation)
            };
            let trace =
                trace.with_context(|| format!("cannot write trace file `{}`", path.display()))?;
            Box::new(trace)
        }
        None => Box::new(NullSink),
    };
    let mut bar = progress::Bar::new(format!(
        "{} {}",
        config.method.name(),
        config.integrator.name()
    ));
    let result = match recorder {
        Some(recorder) => simulate::run_with_progress(
            &mut simulation,
            plan.options(),
            &mut grid::Tee(&mut *sink, recorder),
            &mut bar,
        ),
        None => simulate::run_with_progress(&mut simulation, plan.options(), &mut *sink, &mut bar),
    };
    bar.finish();
    let summary = Summary::from_result(&scene.file, &scene.system, &coordinates, &result);
    Ok(Outcome { result, summary })
}

/// Write `text` to a file.
fn write_file(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write `{}`", path.display()))
}

/// Write `text` to stdout. A closed pipe (`bead run ... | head`) is reported as
/// [`io::ErrorKind::BrokenPipe`], which `main` treats as a quiet exit.
fn print(text: &str) -> Result<()> {
    let mut out = io::stdout().lock();
    out.write_all(terminal(text).as_bytes())?;
    out.flush()?;
    Ok(())
}

/// JSON of one or more summaries, pretty-printed, with a final newline.
/// serde_json escapes the ASCII control characters but writes DEL and the C1 controls
/// (U+0080 to U+009F, which some terminals obey) as they are; they can only occur inside
/// strings, where `\u00XX` is the same character.
fn json<T: serde::Serialize + ?Sized>(value: &T) -> Result<String> {
    let text = serde_json::to_string_pretty(value).context("cannot serialize the summary")?;
    let mut out = String::with_capacity(text.len() + 1);
    for c in text.chars() {
        if c.is_control() && c as u32 >= 0x7f {
            out.push_str(&format!("\\u{:04x}", c as u32));
        } else {
            out.push(c);
        }
    }
    out.push('\n');
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terminal_text_escapes_controls_but_keeps_the_layout() {
        assert_eq!(terminal("a\tb\nc"), "a\tb\nc");
        assert_eq!(
            terminal("\u{1b}[31mred\r\n\u{9b}x\t\u{7f}"),
            "\\x1b[31mred\\r\n\\u{9b}x\t\\x7f"
        );
    }

    #[test]
    fn json_escapes_del_and_c1_controls() {
        let text = json(&["a\u{1b}b\u{9b}c\u{7f}"]).unwrap();
        assert_eq!(text, "[\n  \"a\\u001bb\\u009bc\\u007f\"\n]\n");
        let back: Vec<String> = serde_json::from_str(&text).unwrap();
        assert_eq!(back, ["a\u{1b}b\u{9b}c\u{7f}"]);
    }
}
