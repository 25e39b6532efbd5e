//! `bead sweep`: a scene run over a grid of parameter values by the library's
//! [`bead::sweep::Sweep`], on every core, its CSV rows written as members finish
//! ([`Sweep::run_each`]: in member order, memory bounded whatever the count).

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use bead::sweep::{Axis, Combine, CsvFormat, Member, Sweep, SweepError};

use super::{load_scene, stop_when, warn, Usage};
use crate::args::{SweepArgs, SweepFormat};
use crate::outputs::Files;
use crate::plan;

/// `bead sweep`: resolve the plan as `run` does, run every member, write the CSV and a line
/// of figures on stderr.
pub fn sweep(args: &SweepArgs) -> Result<()> {
    let mut files = Files::new();
    files.input("the scene file", &args.scene);
    if let Some(out) = &args.out {
        files.output("--out", out);
    }
    files.check()?;
    // A parameter both set and swept: the sweep's values would win, silently.
    if let Some((name, _)) =
        (args.sim.set.iter()).find(|(n, _)| args.params.iter().any(|p| &p.name == n))
    {
        return Err(Usage(format!(
            "--set {name} and --param {name} both give `{name}`; set it or sweep it"
        ))
        .into());
    }
    let scene = load_scene(&args.scene, &args.sim.set)?;
    let plan = plan::resolve(&scene, &args.sim, args.method.map(|m| m.0))?;
    let method = plan.method;
    if plan.ignores_scene_feedback(method) {
        warn("the scene's [run] stabilize applies only to the implicit form; not used for this parametric run");
    }
    // Parsed here against the scene, for a located error before anything runs; each member
    // parses it (or, without the flag, its scene's [run] stop_when) against its own values.
    stop_when(&scene, &args.sim)?;
    let axes = args
        .params
        .iter()
        .map(|p| ("--param", p))
        .chain(args.initial.iter().map(|p| ("--initial", p)))
        .map(|(flag, p)| {
            Axis::linspace(&p.name, p.start, p.stop, p.count)
                .map_err(|e| Usage(format!("{flag}: {e}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let combine = if args.zip {
        Combine::Zip
    } else {
        Combine::Grid
    };
    let sweep = Sweep::new(
        &scene,
        axes,
        combine,
        plan::request(&args.sim, args.method.map(|m| m.0)),
        args.sim.stop_when.clone(),
    )
    .map_err(|e| {
        let flag = match &e {
            bead::sweep::SweepError::UnknownParam { name, .. } if name.contains('.') => "--initial",
            _ => "--param",
        };
        Usage(format!("{flag}: {e}"))
    })?;
    // The output file is created before the members run, so that a missing directory is
    // reported at once.
    let mut out: Box<dyn Write> = match &args.out {
        Some(path) => Box::new(BufWriter::new(File::create(path).with_context(|| {
            format!("cannot create the --out file `{}`", path.display())
        })?)),
        None => Box::new(BufWriter::new(io::stdout().lock())),
    };
    let threads = match args.threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    };
    let format = match args.format {
        SweepFormat::Wide => CsvFormat::Wide,
        SweepFormat::Long => CsvFormat::Long,
    };
    let start = Instant::now();
    // Ctrl-C (SIGINT, SIGTERM, SIGHUP) stops the sweep at the next member handed over in
    // order, its rows written and flushed at once (a second Ctrl-C ends the process without
    // waiting for the members still running on other threads, which are dropped unwritten).
    super::progress::catch_interrupts();
    writeln!(out, "{}", sweep.header(format))?;
    let mut tally = Tally::default();
    let mut flushed_at = Instant::now();
    let written = sweep.run_each(0..sweep.len(), threads, |member| -> Result<(), Stop> {
        let rows = sweep.rows(format, &member).map_err(Stop::Member)?;
        out.write_all(rows.as_bytes()).map_err(Stop::Io)?;
        // Rows reach the file (or a pipe) at least every second, not only when the buffer
        // fills, so that a long sweep can be watched.
        if flushed_at.elapsed().as_secs_f64() >= 1.0 {
            out.flush().map_err(Stop::Io)?;
            flushed_at = Instant::now();
        }
        tally.add(member);
        if super::progress::interrupted() {
            out.flush().map_err(Stop::Io)?;
            return Err(Stop::Interrupted);
        }
        Ok(())
    });
    // The rows written so far stay valid whatever stopped the sweep.
    let flushed = out.flush();
    let seconds = start.elapsed().as_secs_f64();
    match written {
        Ok(()) => flushed?,
        Err(Stop::Io(e)) => return Err(e.into()),
        Err(Stop::Member(e @ SweepError::OtherLayout { .. })) => {
            flushed?;
            let written = match tally.members {
                0 => "so it holds the header alone".to_string(),
                n => format!("so it ends before this member, after the rows of the {n} before it"),
            };
            return Err(anyhow!(
                "{e}: the wide CSV has a column per coordinate of the scene swept, {written}; \
                 --format long writes one row per member and coordinate, for members that differ \
                 in particles"
            ));
        }
        Err(Stop::Member(e)) => return Err(e.into()),
        Err(Stop::Interrupted) => {
            flushed?;
            return Err(anyhow!(
                "interrupted: the sweep stopped after {} of its {} members ({} stopped at the event, {} failed) in {} s; the CSV holds their rows, in member order",
                tally.members,
                sweep.len(),
                tally.events,
                tally.failed,
                bead::significant(seconds, 4),
            ));
        }
    }
    let _ = writeln!(
        io::stderr(),
        "sweep: {} members ({} stopped at the event, {} failed) in {} s on {threads} thread(s): {} members/s",
        tally.members,
        tally.events,
        tally.failed,
        bead::significant(seconds, 4),
        bead::significant(tally.members as f64 / seconds.max(1e-12), 4)
    );
    if let Some(first) = tally
        .first_failure
        .filter(|_| tally.failed == tally.members)
    {
        return Err(anyhow!(
            "every member of the sweep failed ({} of {}); the first, {}: {}",
            tally.failed,
            tally.members,
            sweep.describe_member(&first),
            first.error.as_deref().unwrap_or("it could not start")
        ));
    }
    Ok(())
}

/// What stopped the writing of the rows.
enum Stop {
    Member(SweepError),
    Io(io::Error),
    /// Ctrl-C (see [`super::progress`])
    Interrupted,
}

impl From<SweepError> for Stop {
    fn from(e: SweepError) -> Stop {
        Stop::Member(e)
    }
}

/// Members written so far, by status, with the first that failed.
#[derive(Default)]
struct Tally {
    members: usize,
    events: usize,
    failed: usize,
    first_failure: Option<Member>,
}

impl Tally {
    fn add(&mut self, member: Member) {
        self.members += 1;
        match member.status() {
            "event" => self.events += 1,
            "failed" => {
                self.failed += 1;
                if self.first_failure.is_none() {
                    self.first_failure = Some(member);
                }
            }
            _ => {}
        }
    }
}
