//! `bead plot`: columns of a trace CSV against t, as PNG or SVG, read row by row and
//! min/max-decimated so that a trace of any length gives a small file.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use bead_report::plot::{
    write_figure, Figure, Format, MinMaxDecimator, Panel, Series, DEFAULT_BUCKETS,
};

use crate::outputs::Files;
use crate::report_args::PlotArgs;

/// `bead plot`.
pub fn plot(args: &PlotArgs) -> Result<()> {
    let output = args
        .output
        .clone()
        .unwrap_or_else(|| args.trace.with_extension("png"));
    // Check the format before reading a possibly long trace.
    Format::from_path(&output)?;
    let mut files = Files::new();
    files.input("the trace", &args.trace).output(
        if args.output.is_some() {
            "-o"
        } else {
            "the plot"
        },
        &output,
    );
    files.check()?;
    let name = args.trace.display().to_string();
    let file = File::open(&args.trace).with_context(|| format!("cannot open `{name}`"))?;
    let mut lines = BufReader::new(file).lines();
    let header = match lines.next() {
        Some(line) => line.with_context(|| format!("cannot read `{name}`"))?,
        None => bail!("{name}: the file is empty; expected a header row starting with `t`"),
    };
    let columns: Vec<String> = header.split(',').map(|c| c.trim().to_string()).collect();
    if columns.first().map(String::as_str) != Some("t") {
        bail!(
            "{name}:1: the first column must be `t`, got `{}` (is this a bead trace?)",
            columns.first().map(String::as_str).unwrap_or("")
        );
    }
    if columns.len() < 2 {
        bail!("{name}: nothing to plot: the trace has only the column `t`");
    }
    let chosen = choose_columns(&columns, args.columns.as_deref())?;
    let mut decimators: Vec<MinMaxDecimator> = chosen
        .iter()
        .map(|_| MinMaxDecimator::new(DEFAULT_BUCKETS))
        .collect();
    let mut rows = 0u64;
    // Whether each chosen column has a finite value (NaN and infinities are not drawn).
    let mut finite = vec![false; chosen.len()];
    let mut t_finite = false;
    for (index, line) in lines.enumerate() {
        let number = index + 2;
        let line = line.with_context(|| format!("{name}:{number}: cannot read the line"))?;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != columns.len() {
            bail!(
                "{name}:{number}: expected {} fields like the header, got {}",
                columns.len(),
                fields.len()
            );
        }
        let value = |k: usize| -> Result<f64> {
            let field = fields[k].trim();
            field.parse::<f64>().map_err(|_| {
                anyhow::anyhow!(
                    "{name}:{number}: column `{}` is not a number: `{field}`",
                    columns[k]
                )
            })
        };
        let t = value(0)?;
        t_finite |= t.is_finite();
        for ((decimator, &k), finite) in decimators.iter_mut().zip(&chosen).zip(&mut finite) {
            let y = value(k)?;
            *finite |= y.is_finite() && t.is_finite();
            decimator.push(t, y);
        }
        rows += 1;
    }
    if rows == 0 {
        bail!("{name}: no data rows after the header");
    }
    let in_rows = if rows == 1 {
        "in 1 row".to_string()
    } else {
        format!("in {rows} rows")
    };
    if !t_finite {
        bail!("{name}: nothing to plot: column `t` has no finite value {in_rows}");
    }
    let empty: Vec<&str> = chosen
        .iter()
        .zip(&finite)
        .filter(|(_, &f)| !f)
        .map(|(&k, _)| columns[k].as_str())
        .collect();
    if empty.len() == chosen.len() {
        bail!(
            "{name}: nothing to plot: {} no finite value {in_rows}",
            match empty.as_slice() {
                [one] => format!("column `{one}` has"),
                many => format!("columns {} have", quoted(many)),
            }
        );
    }
    if !empty.is_empty() {
        super::warn(&format!(
            "{name}: {} no finite value; {} empty",
            match empty.as_slice() {
                [one] => format!("column `{one}` has"),
                many => format!("columns {} have", quoted(many)),
            },
            if empty.len() == 1 {
                "its panel is"
            } else {
                "their panels are"
            }
        ));
    }
    let panels: Vec<Panel> = chosen
        .iter()
        .zip(&decimators)
        .map(|(&k, d)| Panel {
            title: columns[k].clone(),
            x_label: "t (s)".into(),
            y_label: unit_label(&columns[k]),
            x_log: false,
            y_log: args.log,
            series: vec![Series::line(columns[k].clone(), d.points())],
        })
        .collect();
    let n = panels.len() as u32;
    let figure = Figure {
        title: format!("{} ({rows} rows)", file_name(&args.trace)),
        panels,
        columns: 1,
        size: (960, (60 + 280 * n).min(4000)),
    };
    write_figure(&figure, &output)?;
    super::print(&format!("wrote {}\n", output.display()))
}

/// Column indices to plot: the requested ones, else energy and constraint_error when
/// present, else every column but t.
fn choose_columns(columns: &[String], requested: Option<&[String]>) -> Result<Vec<usize>> {
    match requested {
        Some(names) => names
            .iter()
            .map(|name| {
                let name = name.trim();
                if name == columns[0] {
                    bail!(
                        "`{name}` is the horizontal axis of every panel; choose among {}",
                        columns[1..].join(", ")
                    );
                }
                columns
                    .iter()
                    .position(|c| c == name)
                    .filter(|&k| k > 0)
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "unknown column `{name}`; the trace has {}",
                            columns[1..].join(", ")
                        )
                    })
            })
            .collect(),
        None => {
            let preferred: Vec<usize> = ["energy", "constraint_error"]
                .iter()
                .filter_map(|n| columns.iter().position(|c| c == n))
                .collect();
            if preferred.is_empty() {
                Ok((1..columns.len()).collect())
            } else {
                Ok(preferred)
            }
        }
    }
}

/// The y-axis label of a trace column, with its unit where bead knows it.
fn unit_label(column: &str) -> String {
    match column {
        "energy" => "energy T + V (scene energy units)".into(),
        "constraint_error" => "max |C_i| (constraint units)".into(),
        c if c.starts_with("qdot.") => format!("{c} (per s)"),
        c if c.contains(".v") => format!("{c} (length/s)"),
        c => format!("{c} (scene units)"),
    }
}

/// `a`, `b` and `c` with backquotes: "`a`, `b`".
fn quoted(names: &[&str]) -> String {
    names
        .iter()
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| PathBuf::from(path).display().to_string())
}
