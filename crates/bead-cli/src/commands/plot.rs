//! `bead plot`: columns of a trace CSV against t (or against another column: a phase plot),
//! one panel each or overlaid in one, as PNG or SVG, read row by row and decimated so that a
//! trace of any length gives a small file (min/max buckets against t, every k-th row for a
//! phase plot, whose points must stay in time order).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use bead_report::plot::{
    write_figure, Dash, Figure, Format, Look, MinMaxDecimator, Panel, Series, StrideDecimator,
    DEFAULT_BUCKETS,
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
    if let Some(scene) = &args.scene {
        files.input("--scene", scene);
    }
    files.check()?;
    let scene = match &args.scene {
        Some(path) => Some(super::load_scene(path, &[])?),
        None => None,
    };
    let units = Units::of(scene.as_ref());
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
    let x_column = match &args.x {
        None => 0,
        Some(name) => {
            let name = name.trim();
            columns.iter().position(|c| c == name).ok_or_else(|| {
                anyhow::anyhow!(
                    "--x: unknown column `{name}`; the trace has {}",
                    columns.join(", ")
                )
            })?
        }
    };
    let chosen = choose_columns(&columns, args.columns.as_deref(), x_column)?;
    let mut decimators: Vec<MinMaxDecimator> = chosen
        .iter()
        .map(|_| MinMaxDecimator::new(DEFAULT_BUCKETS))
        .collect();
    // A phase plot keeps whole rows (x and every chosen column) in time order.
    let mut phase = (x_column != 0).then(|| StrideDecimator::new(1 + chosen.len(), 4000));
    let mut row = vec![0.0; 1 + chosen.len()];
    let mut rows = 0u64;
    // Whether each chosen column has a finite value (NaN and infinities are not drawn).
    let mut finite = vec![false; chosen.len()];
    // Whether each chosen column has a value above zero (what a log axis can draw).
    let mut positive = vec![false; chosen.len()];
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
        let t = value(x_column)?;
        t_finite |= t.is_finite();
        row[0] = t;
        for ((((decimator, &k), finite), positive), cell) in decimators
            .iter_mut()
            .zip(&chosen)
            .zip(&mut finite)
            .zip(&mut positive)
            .zip(&mut row[1..])
        {
            let y = value(k)?;
            *finite |= y.is_finite() && t.is_finite();
            *positive |= y.is_finite() && y > 0.0 && t.is_finite();
            *cell = y;
            if phase.is_none() {
                decimator.push(t, y);
            }
        }
        if let Some(phase) = &mut phase {
            phase.push(&row);
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
        bail!(
            "{name}: nothing to plot: column `{}` has no finite value {in_rows}",
            columns[x_column]
        );
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
    if args.log {
        // A log axis shows values above zero only: a column without any has nothing to
        // draw, which is said, never drawn as an invented frame.
        let none: Vec<&str> = chosen
            .iter()
            .zip(finite.iter().zip(&positive))
            .filter(|(_, (&f, &p))| f && !p)
            .map(|(&k, _)| columns[k].as_str())
            .collect();
        let drawable = chosen.iter().zip(&positive).filter(|(_, &p)| p).count();
        let which = match none.as_slice() {
            [one] => format!("column `{one}` has"),
            many => format!("columns {} have", quoted(many)),
        };
        if drawable == 0 && !none.is_empty() {
            bail!(
                "{name}: --log: {which} no value above zero {in_rows}, and a log axis shows only those; plot without --log"
            );
        }
        if !none.is_empty() {
            super::warn(&format!(
                "{name}: --log: {which} no value above zero; {} says so",
                if none.len() == 1 {
                    "its panel"
                } else {
                    "each of their panels"
                }
            ));
        }
    }
    let x_label = if x_column == 0 {
        "t (s)".to_string()
    } else {
        units.label(&columns[x_column])
    };
    // A particle's x against its y: a path in the plane, at equal scales, with the scene's
    // gravity pointing down the page when it points along +y.
    let path_of = |column: &str| -> Option<(String, char)> {
        let (particle, axis) = column.rsplit_once('.')?;
        let axis = match axis {
            "x" => 'x',
            "y" => 'y',
            _ => return None,
        };
        Some((particle.to_string(), axis))
    };
    let path_plot = x_column != 0
        && chosen.len() == 1
        && match (path_of(&columns[x_column]), path_of(&columns[chosen[0]])) {
            (Some((a, 'x')), Some((b, 'y'))) => a == b,
            _ => false,
        };
    let y_down = path_plot
        && scene
            .as_ref()
            .is_some_and(|s| s.system.gravity().get(1).is_some_and(|&g| g > 0.0));
    // The points of chosen column j.
    let phase_rows = phase.as_ref().map(StrideDecimator::rows);
    let points = |j: usize| -> Vec<(f64, f64)> {
        match &phase_rows {
            Some(rows) => rows.iter().map(|r| (r[0], r[1 + j])).collect(),
            None => decimators[j].points(),
        }
    };
    let panels: Vec<Panel> = if args.overlay {
        let series = chosen
            .iter()
            .enumerate()
            .map(|(j, &k)| {
                Series::line(columns[k].clone(), points(j)).with_look(Look {
                    color: Some(j),
                    light: false,
                    dash: Dash::ALL[j % Dash::ALL.len()],
                    marker: None,
                })
            })
            .collect();
        vec![Panel {
            title: chosen
                .iter()
                .map(|&k| columns[k].as_str())
                .collect::<Vec<_>>()
                .join(", "),
            x_label: x_label.clone(),
            y_label: if chosen.len() == 1 {
                units.label(&columns[chosen[0]])
            } else {
                "value".into()
            },
            y_log: args.log,
            equal_aspect: path_plot,
            y_down,
            series,
            ..Panel::default()
        }]
    } else {
        chosen
            .iter()
            .enumerate()
            .map(|(j, &k)| Panel {
                title: if x_column == 0 {
                    columns[k].clone()
                } else {
                    format!("{} against {}", columns[k], columns[x_column])
                },
                x_label: x_label.clone(),
                y_label: if y_down {
                    format!("{}, pointing down", units.label(&columns[k]))
                } else {
                    units.label(&columns[k])
                },
                y_log: args.log,
                equal_aspect: path_plot,
                y_down,
                series: vec![Series::line(columns[k].clone(), points(j))],
                ..Panel::default()
            })
            .collect()
    };
    let n = panels.len() as u32;
    let figure = Figure {
        title: format!("{} ({rows} rows)", file_name(&args.trace)),
        panels,
        columns: 1,
        size: (1100, (60 + 300 * n).min(4000)),
    };
    write_figure(&figure, &output)?;
    super::print(&format!("wrote {}\n", output.display()))
}

/// Column indices to plot: the requested ones, else energy and constraint_error when
/// present, else every column but t and the horizontal axis `x`.
fn choose_columns(
    columns: &[String],
    requested: Option<&[String]>,
    x: usize,
) -> Result<Vec<usize>> {
    let others = || {
        columns
            .iter()
            .enumerate()
            .filter(|&(k, _)| k != x)
            .map(|(_, c)| c.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    match requested {
        Some(names) => names
            .iter()
            .map(|name| {
                let name = name.trim();
                if name == columns[x] {
                    bail!(
                        "`{name}` is the horizontal axis of every panel; choose among {}",
                        others()
                    );
                }
                columns.iter().position(|c| c == name).ok_or_else(|| {
                    anyhow::anyhow!("unknown column `{name}`; the trace has {}", others())
                })
            })
            .collect(),
        None => {
            let preferred: Vec<usize> = ["energy", "constraint_error"]
                .iter()
                .filter_map(|n| columns.iter().position(|c| c == n))
                .filter(|&k| k != x)
                .collect();
            if preferred.is_empty() {
                Ok((1..columns.len()).filter(|&k| k != x).collect())
            } else {
                Ok(preferred)
            }
        }
    }
}

/// The units of a trace's columns, from the scene when `--scene` gives it.
struct Units {
    /// The length unit (`px`, `m`), if the scene says.
    length: Option<String>,
    /// The energy unit (`J`, `kg px^2/s^2`), if the scene says.
    energy: Option<String>,
}

impl Units {
    fn of(scene: Option<&bead::scene::Scene>) -> Units {
        match scene.and_then(|s| s.units.as_deref()) {
            Some("SI") => Units {
                length: Some("m".into()),
                energy: Some("J".into()),
            },
            Some(unit) => Units {
                length: Some(unit.to_string()),
                energy: Some(format!("kg {unit}^2/s^2")),
            },
            None => Units {
                length: None,
                energy: None,
            },
        }
    }

    /// The axis label of a trace column, with its unit where it is known: a particle
    /// coordinate in the scene's length unit, its velocity per second, the energy in the
    /// scene's energy unit. A parametric coordinate (`q.NAME`) may be an angle or a length,
    /// so it gets no unit rather than a wrong one.
    fn label(&self, column: &str) -> String {
        let with = |unit: &Option<String>, per_second: bool| match unit {
            Some(u) if per_second => format!("{column} ({u}/s)"),
            Some(u) => format!("{column} ({u})"),
            None => column.to_string(),
        };
        match column {
            "energy" => match &self.energy {
                Some(u) => format!("energy T + V ({u})"),
                None => "energy T + V".into(),
            },
            "constraint_error" => "max |C_i| (constraint units)".into(),
            c if c.starts_with("qdot.") => format!("{c} (per s)"),
            c if c.starts_with("q.") => c.to_string(),
            c if c.contains(".v") => with(&self.length, true),
            c if c
                .rsplit_once('.')
                .is_some_and(|(_, a)| matches!(a, "x" | "y" | "z")) =>
            {
                with(&self.length, false)
            }
            c => c.to_string(),
        }
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
