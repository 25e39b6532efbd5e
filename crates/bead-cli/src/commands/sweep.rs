//! `bead sweep`: a scene run over a grid of parameter values by the library's
//! [`bead::sweep::Sweep`], on every core, one CSV row per member.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::time::Instant;

use anyhow::{Context, Result};
use bead::sweep::{Axis, Combine, Sweep};

use super::{load_scene, stop_when, warn, Usage};
use crate::args::SweepArgs;
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
        .map(|p| Axis::linspace(&p.name, p.start, p.stop, p.count))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| Usage(format!("--param: {e}")))?;
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
    .map_err(|e| Usage(format!("--param: {e}")))?;
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
    let start = Instant::now();
    let members = sweep.run(threads);
    let seconds = start.elapsed().as_secs_f64();
    sweep.write_csv(&members, &mut out)?;
    out.flush()?;
    let failed = members.iter().filter(|m| m.status() == "failed").count();
    let events = members.iter().filter(|m| m.status() == "event").count();
    let _ = writeln!(
        io::stderr(),
        "sweep: {} members ({} stopped at the event, {failed} failed) in {} s on {threads} thread(s): {} members/s",
        members.len(),
        events,
        bead::significant(seconds, 4),
        bead::significant(members.len() as f64 / seconds.max(1e-12), 4)
    );
    Ok(())
}
