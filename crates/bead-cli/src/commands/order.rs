//! `bead order`: a convergence study of a scene ([`bead::convergence`]): the table of errors
//! and observed orders per halving, the orders at the last halving beside the declared ones,
//! and the work-precision plot.

use std::fmt::Write as _;

use anyhow::{bail, Context, Result};
use bead::convergence::{self, Series, Study, StudySettings};
use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::plan::PlanRequest;
use bead::scene::Scene;
use bead_report::plot::{write_figure, Figure, Look, Marker, Panel, Series as PlotSeries, Style};

use super::{load_scene, print};
use crate::args::OrderArgs;
use crate::plan::{compare_methods, Plan};
use crate::report::exact;

/// `bead order`.
pub fn order(args: &OrderArgs) -> Result<()> {
    let scene = load_scene(&args.scene, &args.set)?;
    let plan = Plan::resolve(
        &scene,
        &PlanRequest {
            dt: args.dt,
            duration: args.duration,
            steps: args.steps,
            ..PlanRequest::default()
        },
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    if plan.last_step_shortened {
        bail!(
            "the duration {} s is not a whole number of steps of dt = {} s: a convergence study compares the runs at the output times of dt; give --steps or a duration that is",
            exact(plan.duration.unwrap_or(0.0)),
            exact(plan.dt)
        );
    }
    let integrators: Vec<IntegratorKind> = match &args.integrators {
        Some(list) => list.0.clone(),
        None => IntegratorKind::ALL
            .into_iter()
            .filter(|k| !k.is_adaptive())
            .collect(),
    };
    if let Some(adaptive) = integrators.iter().find(|k| k.is_adaptive()) {
        bail!(
            "--integrators: {} chooses its own steps, so halving dt says nothing of it; study it by its tolerance with `bead compare --integrators dopri5 --rtols ...`",
            adaptive.name()
        );
    }
    let mut cases = Vec::new();
    let mut skipped = Vec::new();
    for &method in &compare_methods(&scene) {
        for &integrator in &integrators {
            if method == Method::Parametric && integrator.needs_constraints() {
                skipped.push(format!("{} x {}", method.name(), integrator.name()));
            } else {
                cases.push((method, integrator));
            }
        }
    }
    if cases.is_empty() {
        bail!(
            "no integrator given runs on this scene's forms ({})",
            skipped.join(", ")
        );
    }
    let settings = StudySettings {
        dt: plan.dt,
        halvings: args.halvings,
        steps: plan.steps,
        reference_rtol: args.reference_rtol,
    };
    let base = plan.config(Method::Implicit);
    let study = convergence::study(&scene.system, &cases, &settings, &base)?;
    if let Some(path) = &args.plot {
        write_figure(&figure(&scene, &study), path)
            .with_context(|| format!("writing the plot {}", path.display()))?;
    }
    print(&text(
        &scene,
        &args.scene.display().to_string(),
        &study,
        &skipped,
    ))
}

/// A step as `1/N` when it is one (1/60, 1/960), else exactly.
fn step_text(dt: f64) -> String {
    let inverse = 1.0 / dt;
    let n = inverse.round();
    if n >= 2.0 && (inverse - n).abs() <= 1e-9 * n && 1.0 / n == dt {
        format!("1/{n}")
    } else {
        exact(dt)
    }
}

/// An order, or `-` where it is not measured.
fn order_cell(order: Option<f64>) -> String {
    order.map_or("-".into(), |o| format!("{o:.2}"))
}

/// The last measured order of `orders`, if any.
fn last(orders: &[Option<f64>]) -> Option<f64> {
    orders.iter().rev().find_map(|o| *o)
}

/// The study as text: a header, the table, and the orders at the last halving.
fn text(scene: &Scene, file: &str, study: &Study, skipped: &[String]) -> String {
    let s = &study.settings;
    let units = scene.units.as_deref().unwrap_or("length units");
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Convergence of {file}: {} s, dt = {} halved {} times; reference: dopri5 at rtol {:e} on the {} form ({} steps).",
        exact(s.dt * s.steps as f64),
        step_text(s.dt),
        s.halvings,
        s.reference_rtol,
        study.reference_method.name(),
        study.reference_steps
    );
    let _ = writeln!(
        out,
        "Errors: position max |x - x_ref| ({units}) at the times of dt; energy max |E - E0| / E_scale (of E - W with work); off max |C_i| / |grad C_i| ({units}).\nOrders log2(e(h) / e(h/2)); `-` where an error is at its floor (position {:.1e}, energy {:.0e}, off {:.1e}) or the step before failed.\n",
        study.floors.position, study.floors.energy, study.floors.constraint
    );
    let _ = writeln!(
        out,
        "{:<11} {:<17} {:>7} {:>12} {:>15} {:>6} {:>13} {:>6} {:>12} {:>6}",
        "method",
        "integrator",
        "dt",
        "evaluations",
        "position error",
        "order",
        "energy error",
        "order",
        "off",
        "order"
    );
    let _ = writeln!(out, "{}", "-".repeat(115));
    for series in &study.series {
        let position = series.position_orders(&study.floors);
        let energy = series.energy_orders(&study.floors);
        let constraint = series.constraint_orders(&study.floors);
        // The failed step sizes in their place among the others (coarsest first).
        let mut failures = series.failures.iter().peekable();
        for (k, level) in series.levels.iter().enumerate() {
            while let Some(failure) = failures.next_if(|f| f.dt > level.dt) {
                failure_row(&mut out, series, failure);
            }
            let before = |orders: &[Option<f64>]| {
                if k == 0 {
                    String::new()
                } else {
                    order_cell(orders[k - 1])
                }
            };
            let _ = writeln!(
                out,
                "{:<11} {:<17} {:>7} {:>12} {:>15.4e} {:>6} {:>13.4e} {:>6} {:>12} {:>6}",
                series.method.name(),
                series.integrator.name(),
                step_text(level.dt),
                level.evaluations,
                level.position_error,
                before(&position),
                level.energy_error,
                before(&energy),
                level
                    .constraint_error
                    .map_or("-".into(), |c| format!("{c:.4e}")),
                if level.constraint_error.is_some() {
                    before(&constraint)
                } else {
                    String::new()
                },
            );
        }
        for failure in failures {
            failure_row(&mut out, series, failure);
        }
    }
    let _ = writeln!(out, "\nObserved orders at the last measured halving:");
    for series in &study.series {
        let _ = writeln!(out, "  {}", orders_line(series, study));
    }
    for skip in skipped {
        let _ = writeln!(out, "skipped: {skip} (needs the implicit form)");
    }
    // The columns' padding leaves trailing blanks on rows with empty cells.
    out.lines()
        .map(|l| l.trim_end().to_string() + "\n")
        .collect()
}

/// A row of the table for a step size whose run failed, with why.
fn failure_row(out: &mut String, series: &Series, failure: &convergence::LevelFailure) {
    let _ = writeln!(
        out,
        "{:<11} {:<17} {:>7} failed: {}",
        series.method.name(),
        series.integrator.name(),
        step_text(failure.dt),
        failure.error
    );
}

/// `implicit rk4: position 4.00, energy 4.01, off 3.98 (declared 4)`.
fn orders_line(series: &Series, study: &Study) -> String {
    let floors = &study.floors;
    let cell = |orders: Vec<Option<f64>>| order_cell(last(&orders));
    let mut line = format!(
        "{} {}: position {}, energy {}",
        series.method.name(),
        series.integrator.name(),
        cell(series.position_orders(floors)),
        cell(series.energy_orders(floors))
    );
    if series.method == Method::Implicit {
        let _ = write!(line, ", off {}", cell(series.constraint_orders(floors)));
    }
    let _ = write!(line, " (declared {})", series.integrator.order());
    line
}

/// The work-precision plot: position error against evaluations and against wall time, and
/// the energy error against evaluations; one line per form x integrator across the steps.
fn figure(scene: &Scene, study: &Study) -> Figure {
    let units = scene.units.as_deref().unwrap_or("length units");
    let series = |y: fn(&convergence::Level) -> f64, x: fn(&convergence::Level) -> f64| {
        study
            .series
            .iter()
            .enumerate()
            .map(|(i, s)| PlotSeries {
                label: format!("{} {}", s.method.name(), s.integrator.name()),
                points: s
                    .levels
                    .iter()
                    .map(|l| (x(l), y(l)))
                    .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
                    .collect(),
                style: Style::LineAndMarkers,
                look: Look {
                    color: Some(i),
                    marker: Some(if s.method == Method::Implicit {
                        Marker::Circle
                    } else {
                        Marker::Square
                    }),
                    ..Look::default()
                },
            })
            .collect()
    };
    let panel = |title: &str, x_label: &str, y_label: String, series: Vec<PlotSeries>| Panel {
        title: title.into(),
        x_label: x_label.into(),
        y_label,
        x_log: true,
        y_log: true,
        series,
        ..Panel::default()
    };
    Figure {
        columns: 0,
        title: format!(
            "{}: work-precision (one point per dt, dt = {} halved {} times)",
            super::super::report::title(scene),
            step_text(study.settings.dt),
            study.settings.halvings
        ),
        panels: vec![
            panel(
                "position error vs evaluations",
                "evaluations of the acceleration",
                format!("max |x - x_ref| ({units})"),
                series(|l| l.position_error, |l| l.evaluations as f64),
            ),
            panel(
                "position error vs wall time",
                "wall time (s)",
                format!("max |x - x_ref| ({units})"),
                series(|l| l.position_error, |l| l.wall_seconds),
            ),
            panel(
                "energy error vs evaluations",
                "evaluations of the acceleration",
                "max |E - E0| / E_scale, or of E - W (1)".into(),
                series(|l| l.energy_error, |l| l.evaluations as f64),
            ),
        ],
        size: (1500, 560),
    }
}
