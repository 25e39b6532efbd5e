//! Command-line flags as parsed by clap, before they meet a scene. Every value is checked
//! here (a bad value is a usage error, exit code 2); combining flags with the scene's `[run]`
//! defaults happens in [`crate::plan`].

use std::path::PathBuf;

use bead::formulation::{Feedback, Method};
use bead::integrate::IntegratorKind;
use clap::builder::PossibleValue;
use clap::{Args, Parser, Subcommand, ValueEnum};

use crate::numbers::{self, Bound, Context, NumberError};

/// Constrained particle dynamics from scene files: the same constrained system simulated by
/// constraint forces (implicit form) or in generalized coordinates (parametric form).
#[derive(Debug, Parser)]
#[command(name = "bead", version, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,

    /// Evaluate the equations with the interpreter instead of machine code (same numbers, bit
    /// for bit; slower). The environment variable BEAD_JIT=0 does the same.
    #[arg(long, global = true)]
    pub no_jit: bool,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a scene with one formulation; report energy and constraint error.
    #[command(after_long_help = AFTER_RUN)]
    Run(RunArgs),
    /// Run every formulation the scene defines with the same integrator and dt, side by side.
    ///
    /// The implicit form runs when the scene has at least one [[constraint]] or no
    /// [parametric] section; the parametric form runs when it has a [parametric] section.
    #[command(after_long_help = AFTER_RUN)]
    Compare(CompareArgs),
    /// Run a scene many times over a grid of parameter values, in parallel; one CSV row per
    /// member (or per member and coordinate), written as members finish.
    #[command(after_long_help = AFTER_SWEEP)]
    Sweep(SweepArgs),
    /// Validate a scene and describe it, with the derivatives the engine will use.
    Check(CheckArgs),
    /// A convergence study: each integrator at dt, dt/2, ... against a reference (dopri5 at a
    /// tight tolerance), with the observed order of the position, energy and constraint
    /// errors per halving, and a work-precision plot.
    #[command(after_long_help = AFTER_ORDER)]
    Order(OrderArgs),
    /// Plot columns of a trace CSV against t, as PNG or SVG.
    Plot(crate::report_args::PlotArgs),
    /// Start the live browser viewer: a local web server that runs the simulation and streams
    /// it to a page (panels per formulation, live charts, drag a particle, edit the curve).
    Serve(ServeArgs),
    /// Write the viewer as a static folder that needs no server: the engine runs in the page
    /// (WebAssembly). Open its index.html, publish it on any static host, or embed a scene in
    /// a post with the printed <iframe> snippet.
    #[command(after_long_help = AFTER_EXPORT_PAGE)]
    ExportPage(ExportPageArgs),
}

const AFTER_EXPORT_PAGE: &str = "\
The folder holds index.html, viewer.js, viewer.css, engine.js, bead.wasm (the engine), bead-wasm.js
(the same bytes in base64, for pages opened from file://), scenes.js (the picker's scenes) and
embed.html (an <iframe> snippet). The page is the one `bead serve` serves, and share URLs
(?scene=NAME&param.g=...&panel=...) work on it too. Files of other names in DIR are left alone.

Example: bead export-page scenes/parabola.toml --out site/bead --only";

/// `bead export-page`.
#[derive(Debug, Args)]
pub struct ExportPageArgs {
    /// Scene files (TOML) for the page's picker, named by their file names without .toml; the
    /// first is shown when the page opens. The shipped scenes follow them unless --only.
    pub scenes: Vec<PathBuf>,

    /// The folder to write (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Only the given scenes in the picker (without the shipped ones).
    #[arg(long)]
    pub only: bool,

    /// An HTML fragment shown above the scene (an introduction, a lesson).
    #[arg(long, value_name = "FILE")]
    pub intro: Option<PathBuf>,

    /// The page's title (the browser's tab).
    #[arg(long, value_name = "TEXT", default_value = "bead")]
    pub title: String,

    /// Write into DIR even when it holds an index.html that `bead export-page` did not write
    /// (a site's own page would be replaced).
    #[arg(long)]
    pub force: bool,
}

const AFTER_ORDER: &str = "\
Each run records the particles at the output times of the coarsest step (t0 + j dt, which every
halving hits exactly); its position error is the largest distance of a coordinate from the
reference's at those times, its energy error the largest |E - E0| / E_scale (of E - W when the
energy ledger runs), its error off the constraints the largest |C_i| / |grad C_i| (implicit form).
An order log2(e(h) / e(h/2)) is printed only where both errors lie above the floor where they stop
being the method's (the reference's error, round-off, a solver's tolerance): `-` otherwise. The
work of a run is its evaluations of the acceleration and its wall time.

Example: bead order scenes/parabola.toml --integrators rk4,rattle,rattle4,gauss-legendre \\
             --plot order.png";

/// `bead order`.
#[derive(Debug, Args)]
pub struct OrderArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,

    /// The integrators to study (comma-separated names, or `all`) [default: every
    /// fixed-step integrator]; each runs with every formulation that accepts it.
    #[arg(long, value_name = "LIST", value_parser = crate::report_args::parse_integrators)]
    pub integrators: Option<crate::report_args::IntegratorList>,

    /// The coarsest step (s) [default: the scene's dt]
    #[arg(long, value_name = "SECONDS", value_parser = parse_positive)]
    pub dt: Option<f64>,

    /// Simulated time (s) [default: the scene's duration]
    #[arg(long, value_name = "SECONDS", value_parser = parse_positive, conflicts_with = "steps")]
    pub duration: Option<f64>,

    /// Steps of the coarsest dt
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub steps: Option<u64>,

    /// How many times dt is halved (1 to 12)
    #[arg(long, value_name = "K", default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=12))]
    pub halvings: u32,

    /// The reference's relative tolerance (dopri5)
    #[arg(long, value_name = "RTOL", default_value_t = 1e-13, value_parser = parse_positive)]
    pub reference_rtol: f64,

    /// Override a scene parameter: NAME=VALUE (repeatable)
    #[arg(long = "set", value_name = "NAME=VALUE", value_parser = parse_set)]
    pub set: Vec<(String, f64)>,

    /// Write the work-precision plot (errors against evaluations and against wall time) to
    /// FILE (.png or .svg)
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
}

/// `bead serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// A scene file (TOML) to show first, named by its file name without .toml; the shipped
    /// scenes are always available.
    pub scene: Option<PathBuf>,

    /// Port to listen on (0: any free port).
    #[arg(long, default_value_t = 8000)]
    pub port: u16,

    /// Address to listen on. Other than loopback only when given explicitly: the viewer has
    /// no authentication.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: std::net::IpAddr,

    /// Open the page in a browser (xdg-open or open; failure is only a warning).
    #[arg(long)]
    pub open: bool,
}

const AFTER_RUN: &str = "\
Options given here override the scene's [run] table. Without either: the implicit method when the
scene has constraints or no parametric form (else parametric), rk4, dt = 1/60 s, duration 10 s.
The number of steps is duration/dt when that is within 1e-9 of an integer, else rounded up (the
run then ends slightly after the duration, and the summary says so).

Every number given to a flag (--dt, --duration, --stabilize, --set, --rtol, --atol, --dts) may be
an expression of numbers, pi, e and functions, like 1/60 or 2*pi/100.

Exit status: 0 on success, 1 when the scene is invalid or the run fails (the trace keeps every
finished row and --summary is still written, with completed: false), 2 on a usage error (a bad
flag value, or two outputs naming the same file), 130 when Ctrl-C (SIGINT, SIGTERM, SIGHUP)
ended the run of `run` or `compare`: at its last good state, with its trace and --summary
written as for a failed run, or stopped `sweep` at the next member handed over in order,
its CSV holding the rows up to that member (a second Ctrl-C ends the process at once).";

/// `bead run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,

    /// Formulation [default: the scene's [run] method, else implicit when the scene has
    /// constraints or no parametric form, else parametric]
    #[arg(long, value_name = "METHOD")]
    pub method: Option<MethodArg>,

    #[command(flatten)]
    pub sim: SimArgs,

    /// Write a CSV trace: t, each particle's position and velocity, energy, constraint_error
    /// and, for the parametric form, q.NAME and qdot.NAME per coordinate.
    #[arg(long, value_name = "FILE.csv")]
    pub trace: Option<PathBuf>,

    /// Add the constraint forces to the trace: lambda.1 .. lambda.m, the implicit form's
    /// multipliers (one per constraint row), and NAME.Fcx NAME.Fcy [NAME.Fcz], the total
    /// constraint force on each particle (for the parametric form the map's reaction m a - F)
    #[arg(long, requires = "trace")]
    pub constraint_forces: bool,

    #[command(flatten)]
    pub output: OutputArgs,
}

/// `bead compare`.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,

    #[command(flatten)]
    pub sim: SimArgs,

    #[command(flatten)]
    pub grid: crate::report_args::GridArgs,

    /// Write one CSV trace per method, named by inserting the method before the extension:
    /// --trace out.csv writes out.implicit.csv and out.parametric.csv.
    #[arg(long, value_name = "FILE.csv")]
    pub trace: Option<PathBuf>,

    /// Add the constraint forces to the trace: lambda.1 .. lambda.m, the implicit form's
    /// multipliers (one per constraint row), and NAME.Fcx NAME.Fcy [NAME.Fcz], the total
    /// constraint force on each particle (for the parametric form the map's reaction m a - F)
    #[arg(long, requires = "trace")]
    pub constraint_forces: bool,

    #[command(flatten)]
    pub output: OutputArgs,
}

const AFTER_SWEEP: &str = "\
Each --param NAME=START:STOP:COUNT takes COUNT values from START to STOP, both included, evenly
spaced (numpy's linspace); START and STOP may be expressions like 2*pi. Several --param make the
full grid of their combinations, the first outermost (member index = row-major order), or with
--zip one member per position (all COUNTs equal). Each member is the scene with those [params]
overridden, run exactly as `bead run --set NAME=VALUE ...` runs it (same method, integrator, dt,
duration and stop condition), without a trace.

CSV columns (--format wide, the default), one row per member in index order:
  member                     the member's index
  NAME...                    its parameter values, one column per --param
  status                     ok (ran to the end), event (stopped at --stop-when) or failed
  t_final                    time of the last good state
  stop_time                  the stop condition's crossing time (empty when it did not fire)
  steps                      integrator steps taken
  energy_rel_error_max       max over the run of |E - E0| / E_scale (as `bead run --json`)
  energy_balance_error_max   max of |E - W - E0| / E_scale when something does work on the
                             system (the error of the conserved E - W); empty otherwise
  constraint_error_max       max over the run of max_i |C_i|
  newton_iterations          Newton iterations of all steps (rattle, rattle4,
                             fast-projection, --project); empty for the other integrators
  P.x P.y [P.z] P.vx ...     every particle's final position and velocity
  q.NAME qdot.NAME           final generalized coordinates (parametric runs)
  error                      why the member failed (empty otherwise)
The wide columns are the scene's: a member whose particles or generalized coordinates differ
(a swept N that sets their number) is refused with an error naming it; the rows before it stay
written. --format long writes one row per member and coordinate instead, with the columns
member, NAME..., status ... newton_iterations as above, then
  coordinate                 P.x, P.y, ... (the member's own particles), then q.NAME
  position, velocity         its final value and rate (q and qdot for q.NAME)
  error
(a member that could not start is one row with empty coordinate, position and velocity).
Rows are written as members finish, in index order, with memory bounded whatever the count.
Numbers are written exactly (shortest round-trip); a member that could not start has empty
result columns. A sweep has at most 4294967296 (2^32) members.
Exit status: 0 when the sweep ran, even if some members failed (their rows say why); 1 when
every member failed (the error names the first), when a member does not fit the wide format,
or when the scene is invalid; 2 on a usage error (a COUNT or grid beyond the limit included).";

/// `bead sweep`.
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,
    /// A parameter to sweep: NAME=START:STOP:COUNT, COUNT values from START to STOP
    /// inclusive (repeatable: a grid, the first outermost)
    #[arg(long = "param", value_name = "NAME=START:STOP:COUNT", value_parser = parse_param, required_unless_present = "initial")]
    pub params: Vec<ParamRange>,
    /// A number of the start to sweep, after the parameters: a particle's position or
    /// velocity (bead.x, bead.vy) or the parametric form's coordinate or rate (q.theta,
    /// qdot.theta), COUNT values from START to STOP inclusive (repeatable). Each member
    /// starts with it set and the rest placed on the constraints around it (bead.x on a
    /// curve: the bead on the curve at that x); its column is start.NAME
    #[arg(long = "initial", value_name = "NAME.COORD=START:STOP:COUNT", value_parser = parse_initial)]
    pub initial: Vec<ParamRange>,
    /// Combine the parameters position by position instead of as a grid (equal COUNTs)
    #[arg(long)]
    pub zip: bool,
    /// Formulation [default: as for run]
    #[arg(long, value_name = "METHOD")]
    pub method: Option<MethodArg>,
    #[command(flatten)]
    pub sim: SimArgs,
    /// Write the CSV here instead of stdout
    #[arg(long, value_name = "FILE.csv")]
    pub out: Option<PathBuf>,
    /// wide: one row per member, a column per coordinate of the scene; long: one row per
    /// member and coordinate (members may differ in particles)
    #[arg(long, value_name = "FORMAT", value_enum, default_value_t = SweepFormat::Wide)]
    pub format: SweepFormat,
    /// Threads to run members on [default: 0, one per core]
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub threads: usize,
}

/// `bead sweep --format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SweepFormat {
    /// One row per member
    Wide,
    /// One row per member and coordinate
    Long,
}

/// `--param NAME=START:STOP:COUNT` as written.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamRange {
    pub name: String,
    pub start: f64,
    pub stop: f64,
    pub count: usize,
}

/// `bead check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,

    /// Override a scene parameter from [params] with a number or an expression of numbers,
    /// pi, e and functions, like 2*pi (not of other parameters) (repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE", value_parser = parse_set)]
    pub set: Vec<(String, f64)>,
}

/// How to simulate: shared by `run` and `compare`.
#[derive(Debug, Args)]
pub struct SimArgs {
    /// Time integrator [default: the scene's, else rk4]
    #[arg(long, value_name = "INTEGRATOR")]
    pub integrator: Option<IntegratorArg>,

    /// Step size in seconds, > 0, e.g. 1/60 [default: the scene's, else 1/60]
    #[arg(long, value_name = "SECONDS", value_parser = parse_positive)]
    pub dt: Option<f64>,

    /// Simulated time in seconds, > 0 [default: the scene's, else 10]
    #[arg(long, value_name = "SECONDS", value_parser = parse_positive, conflicts_with = "steps")]
    pub duration: Option<f64>,

    /// Number of steps, >= 1 (instead of --duration)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub steps: Option<u64>,

    /// Constraint stabilization for the implicit form: Cddot = -KS C - KD Cdot, two finite
    /// numbers >= 0 (units 1/s^2 and 1/s); compare applies it to the implicit run only
    /// [default: the scene's, else 0,0]
    #[arg(long, value_name = "KS,KD", value_parser = parse_stabilize)]
    pub stabilize: Option<Feedback>,

    /// Override a scene parameter from [params] with a number or an expression of numbers,
    /// pi, e and functions, like 2*pi (not of other parameters) (repeatable)
    #[arg(long = "set", value_name = "NAME=VALUE", value_parser = parse_set)]
    pub set: Vec<(String, f64)>,

    /// Record every K-th step in the trace (the first and last states are always recorded)
    #[arg(long, value_name = "K", default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub every: u64,

    /// Relative tolerance of the adaptive integrator (dopri5), a finite number > 0; other
    /// integrators ignore it [default: 1e-8]
    #[arg(long, value_name = "RTOL", value_parser = parse_positive)]
    pub rtol: Option<f64>,

    /// Absolute tolerance of the adaptive integrator (dopri5), a finite number >= 0, in the
    /// units of q and qdot; other integrators ignore it [default: 1e-10]
    #[arg(long, value_name = "ATOL", value_parser = parse_non_negative)]
    pub atol: Option<f64>,

    /// After every step, project positions onto the constraints C = 0 and velocities onto
    /// J v = -C_t (mass-weighted, to 1e-12 of the constraints' scale); implicit form only,
    /// not with dopri5; compare applies it to the implicit run only
    #[arg(long)]
    pub project: bool,

    /// Take each step of dt as K steps of dt/K (fixed-step integrators; not dopri5)
    #[arg(long, value_name = "K", default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub substeps: u32,

    /// When a step's iteration does not converge (rattle's Newton solve, --project, an
    /// implicit kick or stage), retry it with about 1.5 times as many substeps (2, 3, 5, 8,
    /// ...), up to M, before failing; rattle on systems of rods and pins (chains, cloth) also
    /// takes, up to M, as many as it needs to stay stable (h omega <= 2, omega the rods'
    /// fastest oscillation under their last tensions)
    #[arg(long, value_name = "M", default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_substeps: u32,
    /// Stop where EXPR crosses zero upward (from < 0 to >= 0), located to 1e-10 of dt: an
    /// expression of particle coordinates and velocities (bead.y, bead.vx), generalized
    /// coordinates (NAME or q.NAME, rates qdot.NAME; parametric form), t and parameters,
    /// e.g. "5 - bead.y" [default: the scene's [run] stop_when, else none]
    #[arg(long, value_name = "EXPR", allow_hyphen_values = true)]
    pub stop_when: Option<String>,

    /// Also sample the stop condition at K evenly spaced times inside each step (for dopri5:
    /// at least every dt/(K+1) of its dense output), so that a crossing and its return within
    /// one step are found when a sample falls between them; 0 compares step ends only, at
    /// most 1024 [default: the scene's [run] event_samples, else 4]
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(0..=bead::simulate::MAX_EVENT_SAMPLES as i64))]
    pub event_samples: Option<u32>,
}

impl SimArgs {
    /// No flags at all, as if none were given: everything comes from the scene's `[run]` table
    /// or the defaults (for `bead check`, which starts the scene as `bead run SCENE` would).
    pub fn none() -> SimArgs {
        SimArgs {
            integrator: None,
            dt: None,
            duration: None,
            steps: None,
            stabilize: None,
            set: Vec::new(),
            every: 1,
            rtol: None,
            atol: None,
            project: false,
            substeps: 1,
            max_substeps: 64,
            stop_when: None,
            event_samples: None,
        }
    }
}

/// Where the report goes: shared by `run` and `compare`.
#[derive(Debug, Args)]
pub struct OutputArgs {
    /// Also write the summary as JSON to FILE (for compare: an array, one per method)
    #[arg(long, value_name = "FILE.json")]
    pub summary: Option<PathBuf>,

    /// Print the summary as JSON on stdout instead of text (for compare: an array)
    #[arg(long)]
    pub json: bool,
}

/// `--integrator`: an [`IntegratorKind`] whose help lists each method's order and whether it
/// is symplectic.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntegratorArg(pub IntegratorKind);

impl ValueEnum for IntegratorArg {
    fn value_variants<'a>() -> &'a [Self] {
        // Every kind of IntegratorKind::ALL, in its order, whatever its length.
        const ALL: [IntegratorArg; IntegratorKind::ALL.len()] = {
            let mut all = [IntegratorArg(IntegratorKind::ALL[0]); IntegratorKind::ALL.len()];
            let mut i = 1;
            while i < all.len() {
                all[i] = IntegratorArg(IntegratorKind::ALL[i]);
                i += 1;
            }
            all
        };
        &ALL
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let name = self.0.name();
        let described = self.0.describe();
        // `describe` reads "NAME: order k, ..."; clap prints the name itself.
        let help = described
            .strip_prefix(&format!("{name}: "))
            .unwrap_or(&described)
            .to_string();
        Some(PossibleValue::new(name).help(help))
    }
}

/// `--method`: a [`Method`] with a one-line description.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MethodArg(pub Method);

impl ValueEnum for MethodArg {
    fn value_variants<'a>() -> &'a [Self] {
        &[MethodArg(Method::Implicit), MethodArg(Method::Parametric)]
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let help = match self.0 {
            Method::Implicit => "particle coordinates kept on the constraints by constraint forces",
            Method::Parametric => "generalized coordinates of the scene's [parametric] map",
        };
        Some(PossibleValue::new(self.0.name()).help(help))
    }
}

/// A finite number > 0: an expression of numbers, `pi`, `e` and functions (`1/60`).
fn parse_positive(s: &str) -> Result<f64, String> {
    numbers::whole(s, Bound::Positive)
}

/// A finite number >= 0 (an expression, like [`parse_positive`]).
fn parse_non_negative(s: &str) -> Result<f64, String> {
    numbers::whole(s, Bound::NonNegative)
}

/// `KS,KD`: two finite numbers >= 0, each an expression.
fn parse_stabilize(s: &str) -> Result<Feedback, String> {
    const USAGE: &str = "expected KS,KD (two finite numbers >= 0, e.g. 100,20)";
    let parts = numbers::split_list(s);
    if parts.len() != 2 {
        let count = parts.len();
        let (start, end) = match parts.get(2) {
            // Point at the third number.
            Some(&(start, _)) => (start, s.len()),
            None => (0, s.len()),
        };
        let got = if count == 1 {
            "one number".to_string()
        } else {
            format!("{count} numbers")
        };
        return Err(NumberError::new(format!("{USAGE}, got {got}"), start, end).render(s));
    }
    let number = |(start, end): (usize, usize), which: &str| {
        numbers::number(s, start, end, Bound::NonNegative, Context::Flag).map_err(|e| {
            NumberError::new(
                format!("{which} {}; {USAGE}", e.message),
                e.span.start,
                e.span.end,
            )
            .render(s)
        })
    };
    Ok(Feedback {
        ks: number(parts[0], "KS:")?,
        kd: number(parts[1], "KD:")?,
    })
}

/// `NAME=START:STOP:COUNT`: a name, two finite numbers (expressions) and a count >= 1; errors
/// point at the offending part.
fn parse_param(s: &str) -> Result<ParamRange, String> {
    parse_range(
        s,
        "expected NAME=START:STOP:COUNT (e.g. x0=10:200:100)",
        "a parameter name",
        bead::expr::is_identifier,
    )
}

/// `--initial NAME.COORD=START:STOP:COUNT`: a number of the start (`bead.x`, `q.theta`).
fn parse_initial(s: &str) -> Result<ParamRange, String> {
    parse_range(
        s,
        "expected NAME.COORD=START:STOP:COUNT (e.g. bead.x=10:200:100, q.theta=0.1:1.5:30)",
        "a particle's NAME.x, NAME.vx, ... or q.NAME, qdot.NAME",
        |name| {
            name.split_once('.')
                .is_some_and(|(a, b)| bead::expr::is_identifier(a) && bead::expr::is_identifier(b))
        },
    )
}

/// NAME=START:STOP:COUNT with a NAME that `valid` accepts (`what` it must be, in messages).
fn parse_range(
    s: &str,
    usage: &str,
    what: &str,
    valid: fn(&str) -> bool,
) -> Result<ParamRange, String> {
    let Some(equals) = s.find('=') else {
        return Err(NumberError::new(format!("{usage}: no `=`"), 0, s.len()).render(s));
    };
    let name = s[..equals].trim();
    if !valid(name) {
        let why = if name.is_empty() {
            "the name is empty".to_string()
        } else {
            format!("`{name}` is not {what}")
        };
        return Err(NumberError::new(format!("{usage}: {why}"), 0, equals).render(s));
    }
    let mut parts = Vec::new();
    let mut start = equals + 1;
    for (i, c) in s[equals + 1..].char_indices() {
        if c == ':' {
            parts.push((start, equals + 1 + i));
            start = equals + 2 + i;
        }
    }
    parts.push((start, s.len()));
    if parts.len() != 3 {
        return Err(NumberError::new(
            format!(
                "{usage}: got {} part{} after `=`",
                parts.len(),
                if parts.len() == 1 { "" } else { "s" }
            ),
            equals + 1,
            s.len(),
        )
        .render(s));
    }
    let number = |(a, b): (usize, usize), which: &str| {
        numbers::number(s, a, b, Bound::Finite, Context::Set).map_err(|e| {
            NumberError::new(format!("{which}: {}", e.message), e.span.start, e.span.end).render(s)
        })
    };
    let first = number(parts[0], "START")?;
    let last = number(parts[1], "STOP")?;
    let (a, b) = parts[2];
    let text = s[a..b].trim();
    let too_many = || {
        NumberError::new(
            format!(
                "COUNT must be at most {} (2^32, the most members a sweep may have), got `{text}`",
                bead::sweep::MAX_MEMBERS
            ),
            a,
            b,
        )
        .render(s)
    };
    let count: usize = match text.parse::<u128>() {
        Ok(0) => {
            return Err(
                NumberError::new("COUNT must be at least 1, got 0".to_string(), a, b).render(s),
            )
        }
        Ok(n) if n > u128::from(bead::sweep::MAX_MEMBERS) => return Err(too_many()),
        Ok(n) => match usize::try_from(n) {
            Ok(n) => n,
            Err(_) => return Err(too_many()),
        },
        Err(_) if !text.is_empty() && text.bytes().all(|c| c.is_ascii_digit()) => {
            return Err(too_many())
        }
        Err(_) => {
            return Err(NumberError::new(
                format!("COUNT must be a whole number >= 1, got `{text}`"),
                a,
                b.max(a + 1).min(s.len().max(a)),
            )
            .render(s))
        }
    };
    Ok(ParamRange {
        name: name.to_string(),
        start: first,
        stop: last,
        count,
    })
}

/// `NAME=VALUE` with a finite number, an expression of numbers, `pi`, `e` and functions (not
/// of the scene's parameters: see [`Context::Set`]).
fn parse_set(s: &str) -> Result<(String, f64), String> {
    let Some(equals) = s.find('=') else {
        return Err(format!("expected NAME=VALUE, got `{s}`"));
    };
    let name = s[..equals].trim();
    if name.is_empty() {
        return Err(format!(
            "expected NAME=VALUE, got `{s}` (the name is empty)"
        ));
    }
    let x = numbers::number(s, equals + 1, s.len(), Bound::Finite, Context::Set).map_err(|e| {
        NumberError::new(
            format!("the value of `{name}`: {}", e.message),
            e.span.start,
            e.span.end,
        )
        .render(s)
    })?;
    Ok((name.to_string(), x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn clap_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn stabilize_takes_two_non_negative_numbers() {
        assert_eq!(
            parse_stabilize("100, 20"),
            Ok(Feedback {
                ks: 100.0,
                kd: 20.0
            })
        );
        for bad in ["100", "1,2,3", "-1,0", "0,nan", "inf,0", "a,b", ""] {
            assert!(parse_stabilize(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn set_takes_a_name_and_a_finite_number() {
        assert_eq!(parse_set("k=2.5"), Ok(("k".to_string(), 2.5)));
        for bad in ["k", "=1", "k=", "k=x", "k=NaN", "k=inf"] {
            assert!(parse_set(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn positive_rejects_zero_negative_and_non_finite() {
        assert_eq!(parse_positive("0.01"), Ok(0.01));
        for bad in ["0", "-1", "nan", "inf", "x", ""] {
            assert!(parse_positive(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn non_negative_accepts_zero_and_rejects_negative_and_non_finite() {
        assert_eq!(parse_non_negative("0"), Ok(0.0));
        assert_eq!(parse_non_negative("1e-10"), Ok(1e-10));
        for bad in ["-1e-10", "nan", "inf", "x", ""] {
            assert!(parse_non_negative(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn no_flags_are_what_clap_parses_from_no_flags() {
        let cli = Cli::try_parse_from(["bead", "run", "s.toml"]).expect("parses");
        let Command::Run(run) = cli.command else {
            panic!("not run")
        };
        assert_eq!(format!("{:?}", run.sim), format!("{:?}", SimArgs::none()));
    }

    #[test]
    fn integrator_help_comes_from_the_library() {
        let rk4 = IntegratorArg(IntegratorKind::Rk4)
            .to_possible_value()
            .unwrap();
        assert_eq!(rk4.get_name(), "rk4");
        assert_eq!(
            rk4.get_help().map(|h| h.to_string()).as_deref(),
            Some("order 4, not symplectic")
        );
    }
}
