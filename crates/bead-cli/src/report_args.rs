//! Flags of `bead compare`'s grid and report (`--integrators`, `--dts`, `--report`) and of
//! `bead plot`.

use std::path::PathBuf;

use bead::integrate::IntegratorKind;
use clap::Args;

use crate::numbers::{self, Bound, Context, NumberError};

/// `bead compare`: several integrators and step sizes, and the HTML report.
#[derive(Debug, Args)]
pub struct GridArgs {
    /// Compare these integrators (comma-separated names, or `all` for every one); each runs
    /// with every formulation, and combinations that cannot run are listed as skipped. With
    /// --integrators, --dts or --report and --project, the implicit form runs both without
    /// and with the projection (rows `implicit` and `implicit+project`)
    #[arg(long, value_name = "LIST", value_parser = parse_integrators, conflicts_with = "integrator")]
    pub integrators: Option<IntegratorList>,

    /// Compare these step sizes (comma-separated, each a number > 0 or an expression like
    /// 1/60) over the same duration
    #[arg(long, value_name = "LIST", value_parser = parse_dts, conflicts_with_all = ["dt", "steps"])]
    pub dts: Option<DtList>,

    /// Run the adaptive integrator (dopri5) once per relative tolerance in LIST
    /// (comma-separated, each > 0) instead of once at --rtol: it chooses its own steps, so it
    /// runs once per tolerance, never once per dt (its output interval is the smallest dt)
    #[arg(long, value_name = "LIST", value_parser = parse_rtols, conflicts_with = "rtol")]
    pub rtols: Option<DtList>,

    /// Write DIR/report.html with the table and plots (PNG and SVG beside it): constraint and
    /// energy error vs time, trajectories, work-precision
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,

    /// Most points per plotted series (min/max per bucket of consecutive samples, so spikes
    /// survive), >= 10
    #[arg(long, value_name = "N", default_value_t = 2000, value_parser = clap::value_parser!(u64).range(10..))]
    pub points: u64,
}

/// `bead plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// A trace CSV written by `bead run --trace` or `bead compare --trace` (header row, `t`
    /// first)
    pub trace: PathBuf,

    /// Columns to plot, comma-separated [default: energy and constraint_error when present,
    /// else every column but t and the --x column]
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    pub columns: Option<Vec<String>>,

    /// The horizontal axis: a column of the trace [default: t]. Another column gives a phase
    /// plot (e.g. `--x bead.x --columns bead.vx`), drawn in time order.
    #[arg(long, value_name = "COLUMN")]
    pub x: Option<String>,

    /// All columns in one panel, each its own colour and dash, instead of one panel each
    #[arg(long)]
    pub overlay: bool,

    /// Output file, .png or .svg [default: the trace with the extension .png]
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,

    /// Logarithmic y axis (values at or below zero, e.g. exact zeros, are left out and
    /// counted in a note under the plot; a column with no value above zero is an error, or
    /// an empty panel that says so when other columns have some)
    #[arg(long)]
    pub log: bool,

    /// The scene the trace was run from: axis labels in its units (`[world] units`), and a
    /// particle's x against its y (`--x bead.x --columns bead.y`) drawn with the scene's
    /// gravity pointing down the page (such a plot is always at equal scales)
    #[arg(long, value_name = "SCENE")]
    pub scene: Option<PathBuf>,
}

/// `--integrators`: the kinds, in the order given, without repeats.
#[derive(Clone, Debug, PartialEq)]
pub struct IntegratorList(pub Vec<IntegratorKind>);

/// `--dts`: each step size with its text as given (e.g. `1/60`).
#[derive(Clone, Debug, PartialEq)]
pub struct DtList(pub Vec<(String, f64)>);

pub fn parse_integrators(s: &str) -> Result<IntegratorList, String> {
    let mut kinds = Vec::new();
    for part in s.split(',') {
        let part = part.trim();
        if part == "all" {
            for k in IntegratorKind::ALL {
                if !kinds.contains(&k) {
                    kinds.push(k);
                }
            }
            continue;
        }
        if part.is_empty() {
            return Err(format!("empty integrator name in `{s}`"));
        }
        let kind: IntegratorKind = part.parse()?;
        if !kinds.contains(&kind) {
            kinds.push(kind);
        }
    }
    Ok(IntegratorList(kinds))
}

/// One step size: a finite number > 0, an expression of numbers, `pi`, `e` and functions
/// (`1/60`, `2*pi/100`).
#[cfg(test)]
fn parse_dt(s: &str) -> Result<f64, String> {
    numbers::whole(s, Bound::Positive)
}

/// Comma-separated step sizes (commas inside parentheses belong to a function call), each
/// with its text as given; the same text twice is an error (its runs would be the same).
fn parse_dts(s: &str) -> Result<DtList, String> {
    let mut dts: Vec<(String, f64)> = Vec::new();
    for (start, end) in numbers::split_list(s) {
        let dt = numbers::number(s, start, end, Bound::Positive, Context::Flag)
            .map_err(|e| e.render(s))?;
        let label = s[start..end].trim().to_string();
        if dts.iter().any(|(other, _)| *other == label) {
            let at = start + (s[start..end].len() - s[start..end].trim_start().len());
            return Err(NumberError::new(
                format!("`{label}` is given twice"),
                at,
                at + label.len(),
            )
            .render(s));
        }
        dts.push((label, dt));
    }
    Ok(DtList(dts))
}

/// `--rtols`: comma-separated relative tolerances, each a number > 0, without repeats.
fn parse_rtols(s: &str) -> Result<DtList, String> {
    parse_dts(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dts_take_fractions_and_decimals() {
        assert_eq!(parse_dt("1/60"), Ok(1.0 / 60.0));
        assert_eq!(parse_dt(" 0.01 "), Ok(0.01));
        assert_eq!(parse_dt("1e-3"), Ok(1e-3));
        // Any expression of numbers: 1/60/2 = 1/120.
        assert_eq!(parse_dt("1/60/2"), Ok(1.0 / 120.0));
        assert_eq!(parse_dt("pi/100"), Ok(std::f64::consts::PI / 100.0));
        for bad in ["1/0", "abc", "0", "-1/60", "1/", "/2", "inf", ""] {
            assert!(parse_dt(bad).is_err(), "{bad}");
        }
        let list = parse_dts("1/30, 0.01, atan2(1, 2)/100").unwrap();
        assert_eq!(list.0[0], ("1/30".to_string(), 1.0 / 30.0));
        assert_eq!(list.0[1], ("0.01".to_string(), 0.01));
        assert_eq!(list.0[2].0, "atan2(1, 2)/100");
        assert_eq!(
            parse_dts("1/60, 1/60").unwrap_err(),
            "`1/60` is given twice\n  1/60, 1/60\n        ^^^^"
        );
    }

    #[test]
    fn integrators_take_names_and_all() {
        assert_eq!(
            parse_integrators("rk4,euler,rk4").unwrap().0,
            vec![IntegratorKind::Rk4, IntegratorKind::Euler]
        );
        assert_eq!(
            parse_integrators("all").unwrap().0,
            IntegratorKind::ALL.to_vec()
        );
        assert!(parse_integrators("rk5").is_err());
        assert!(parse_integrators("rk4,").is_err());
    }
}
