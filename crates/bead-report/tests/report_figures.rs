//! What the report's figures say about the runs: each run its own look (colour by
//! integrator, dash by dt, marker by method), the energy's sign (the article's parametric
//! form loses energy: its signed change is below zero), the parabola drawn as the valley it
//! is (+y down, equal scales) and work-precision against steps.

use std::path::Path;
use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{run, RunOptions, Simulation, SimulationConfig, Sink};
use bead_report::plot::{Dash, Marker, DEFAULT_BUCKETS};
use bead_report::report::{Recorder, Report, ReportRun};

fn parabola_report() -> Report {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
    let mut runs = Vec::new();
    for (integrator, dt, label) in [
        (IntegratorKind::Rk4, 1.0 / 60.0, "1/60"),
        (IntegratorKind::Rk4, 1.0 / 120.0, "1/120"),
        (IntegratorKind::Verlet, 1.0 / 60.0, "1/60"),
    ] {
        for method in [Method::Implicit, Method::Parametric] {
            let config = SimulationConfig {
                method,
                integrator,
                dt,
                ..Default::default()
            };
            let mut simulation = Simulation::new(Arc::clone(&scene.system), config).unwrap();
            let mut recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
            let steps = (10.0 / dt).round() as u64;
            let stats = run(&mut simulation, RunOptions::steps(steps), &mut recorder)
                .unwrap_or_else(|e| panic!("{e}"));
            runs.push(ReportRun {
                method,
                projected: false,
                integrator,
                dt,
                dt_label: label.into(),
                rtol: None,
                stats,
                error: None,
                recording: recorder.recording(),
            });
        }
    }
    Report {
        title: "parabola".into(),
        description: "test".into(),
        system: Arc::clone(&scene.system),
        runs,
        skipped: vec![],
        scene: None,
    }
}

#[test]
fn every_run_has_its_own_look_and_the_figures_tell_the_physics() {
    let report = parabola_report();
    let looks: Vec<_> = report.runs.iter().map(|r| report.look(r)).collect();
    for (i, a) in looks.iter().enumerate() {
        for b in &looks[i + 1..] {
            assert_ne!(a, b, "two runs look alike");
        }
    }
    // Colour by run (integrator and dt), shared by the formulations of that run, which the
    // line style tells apart: implicit solid, parametric dashed; marker by integrator.
    let look = |integrator, dt: f64, method| {
        let run = report
            .runs
            .iter()
            .find(|r| r.integrator == integrator && r.dt == dt && r.method == method)
            .unwrap();
        report.look(run)
    };
    let rk4 = look(IntegratorKind::Rk4, 1.0 / 60.0, Method::Implicit);
    let rk4_parametric = look(IntegratorKind::Rk4, 1.0 / 60.0, Method::Parametric);
    assert_eq!(rk4_parametric.color, rk4.color);
    assert_eq!((rk4.dash, rk4_parametric.dash), (Dash::Solid, Dash::Dashed));
    for other in [
        look(IntegratorKind::Rk4, 1.0 / 120.0, Method::Implicit),
        look(IntegratorKind::Verlet, 1.0 / 60.0, Method::Implicit),
    ] {
        assert_ne!(other.color, rk4.color);
    }
    assert_eq!(rk4.marker, rk4_parametric.marker);
    assert_ne!(
        look(IntegratorKind::Verlet, 1.0 / 60.0, Method::Implicit).marker,
        rk4.marker
    );
    // The legend says what colour and line stand for.
    let note = report.energy_figure().panels[0].legend_note.join("\n");
    assert!(note.contains("solid: implicit") && note.contains("dashed: parametric"), "{note}");

    // The energy figure: a signed panel, where the parametric rk4 run at 1/60 ends below
    // zero (it loses energy, the article's observation), then the log panel.
    let energy = report.energy_figure();
    assert_eq!(energy.panels.len(), 2);
    assert!(!energy.panels[0].y_log && energy.panels[1].y_log);
    let parametric = energy.panels[0]
        .series
        .iter()
        .find(|s| s.label == "parametric rk4 dt=1/60")
        .unwrap();
    let last = parametric.points.last().unwrap().1;
    assert!(last < -1e-6, "parametric rk4 loses energy: {last:e}");
    // The log panel holds the envelope of the sizes of the same changes: the running
    // maximum, never decreasing, ending at the largest size reached.
    let sizes = energy.panels[1]
        .series
        .iter()
        .find(|s| s.label == "parametric rk4 dt=1/60")
        .unwrap();
    assert!(sizes.points.windows(2).all(|w| w[1].1 >= w[0].1 && w[1].0 >= w[0].0));
    let largest = parametric.points.iter().map(|p| p.1.abs()).fold(0.0, f64::max);
    assert!((sizes.points.last().unwrap().1 - largest).abs() <= 1e-15);
    assert!(largest >= last.abs());

    // Trajectories: gravity along +y, so y points down, at equal scales.
    let trajectories = report.trajectory_figure();
    let panel = &trajectories.panels[0];
    assert!(panel.y_down && panel.equal_aspect, "{panel:?}");
    assert!(panel.y_label.contains("pointing down"));

    // Work-precision against steps: 600 and 1200 steps for rk4.
    let work = report.work_precision_figure();
    let rk4_points = &work.panels[0]
        .series
        .iter()
        .find(|s| s.label == "implicit rk4")
        .unwrap()
        .points;
    let steps: Vec<f64> = rk4_points.iter().map(|p| p.0).collect();
    assert_eq!(steps, vec![600.0, 1200.0]);
    assert_eq!(work.panels[0].x_label, "steps");

    // Every figure draws (SVG), legends and all.
    for figure in [report.constraint_figure(), energy, trajectories, work] {
        let svg = bead_report::plot::svg_string(&figure).unwrap();
        // (Work-precision names a method and integrator, its points are the dts.)
        assert!(svg.contains("parametric rk4"), "{}", figure.title);
    }
}

/// The HTML report has its sections, the bead version and the setup.
#[test]
fn the_report_names_its_sections_version_and_setup() {
    let report = parabola_report();
    let dir = std::env::temp_dir().join(format!("bead-report-sections-{}", std::process::id()));
    let files = bead_report::report::write_report(&report, &dir).unwrap();
    let html = std::fs::read_to_string(&files.html).unwrap();
    for heading in [
        "Setup",
        "Runs",
        "Constraint error",
        "Energy",
        "Trajectories",
        "Work-precision",
    ] {
        assert!(html.contains(&format!("<h2>{heading}</h2>")), "{heading}");
    }
    assert!(html.contains(&format!("bead {}", env!("CARGO_PKG_VERSION"))));
    assert!(
        html.contains("1 particle in 2D, 1 constraint row, gravity (0, 500)"),
        "setup line"
    );
    assert!(
        html.contains("with y pointing down as the scene"),
        "trajectory caption"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The deviation from the curve is a distance, whatever C's units: a point placed a known
/// distance d off the parabola along its normal reads d (to O(d / R), R >= 50 the radius of
/// curvature), for C = x^2 + 100 y and for 1000 times that, whose max |C| is 1000 times
/// larger.
#[test]
fn the_deviation_from_the_curve_is_the_distance_off_it() {
    let scene_with = |expr: &str| {
        let text = format!(
            "[world]\ngravity = [0.0, 500.0]\n[[particle]]\nname = \"bead\"\nmass = 1.0\nposition = [150.0, -225.0]\n[[constraint]]\nexpr = \"{expr}\"\n"
        );
        Scene::parse(&text, "parabola.toml", &[]).unwrap_or_else(|e| panic!("{e}"))
    };
    for (expr, c_scale) in [
        ("bead.x^2 + 100*bead.y", 1.0),
        ("1000*(bead.x^2 + 100*bead.y)", 1000.0),
    ] {
        let scene = scene_with(expr);
        let mut recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
        // The point (u, -u^2/100) of the curve, moved by d along the unit normal
        // (u/50, 1) / |(u/50, 1)|; C there is about d |grad C|.
        let (u, d) = (37.0_f64, 1e-3);
        let normal = [u / 50.0, 1.0];
        let length = (normal[0] * normal[0] + 1.0).sqrt();
        let x = [u + d * normal[0] / length, -u * u / 100.0 + d / length];
        let c = c_scale * (x[0] * x[0] + 100.0 * x[1]);
        for (t, point) in [(0.0, [u, -u * u / 100.0]), (1.0, x)] {
            let c_here = c_scale * (point[0] * point[0] + 100.0 * point[1]);
            recorder
                .record(&bead::simulate::Sample {
                    step: t as u64,
                    t,
                    x: &point,
                    xdot: &[0.0, 0.0],
                    energy: 0.0,
                    constraint_error: c_here.abs(),
                    q: &point,
                    qdot: &[0.0, 0.0],
                    work: None,
                    energy_initial: 0.0,
                    energy_scale: 1.0,
                })
                .unwrap();
        }
        let recording = recorder.recording();
        let at = |series: &[(f64, f64)], t: f64| {
            series
                .iter()
                .find(|p| p.0 == t)
                .map(|p| p.1)
                .unwrap_or_else(|| panic!("no point at t = {t} in {series:?}"))
        };
        assert_eq!(at(&recording.deviation, 0.0), 0.0, "{expr}: on the curve");
        let deviation = at(&recording.deviation, 1.0);
        assert!(
            (deviation - d).abs() < 1e-4 * d,
            "{expr}: deviation {deviation}, distance {d}"
        );
        // max |C| carries C's units: 1000 times larger for the scaled constraint.
        let error = at(&recording.constraint_error, 1.0);
        assert!((error - c.abs()).abs() <= 1e-9 * c.abs(), "{error} vs {c}");
    }
}

/// A chaotic motion has no period (its cycles differ by far more than 5%), while the
/// parabola's oscillation has one; the table then says `-`.
#[test]
fn a_motion_that_is_not_periodic_gets_no_period() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/double-pendulum.toml");
    let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
    let config = SimulationConfig {
        method: Method::Parametric,
        integrator: IntegratorKind::Rk4,
        dt: 1e-3,
        ..Default::default()
    };
    let mut simulation = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    let mut recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
    run(&mut simulation, RunOptions::steps(20_000), &mut recorder)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(recorder.recording().period, None);
    let report = parabola_report();
    assert!(report.runs.iter().all(|r| r.recording.period.is_some()));
}
