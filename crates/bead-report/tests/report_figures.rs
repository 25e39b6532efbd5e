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
use bead_report::plot::{Dash, DEFAULT_BUCKETS};
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
    // shade and the line style tell apart: implicit solid, parametric lighter and dashed;
    // marker by integrator.
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
    assert!(rk4_parametric.light && !rk4.light);
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
    assert!(
        note.contains("solid: implicit") && note.contains("dashed: parametric"),
        "{note}"
    );

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
    assert!(sizes
        .points
        .windows(2)
        .all(|w| w[1].1 >= w[0].1 && w[1].0 >= w[0].0));
    let largest = parametric
        .points
        .iter()
        .map(|p| p.1.abs())
        .fold(0.0, f64::max);
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

/// The distance from (px, py) to the parabola x^2 + 100 y = 0, found independently of bead:
/// the curve parameter u minimizing (u - px)^2 + (-u^2/100 - py)^2, by a scan over
/// [-2000, 2000] at 0.05 for the global minimum, golden-section search on the bracket around
/// it, then Newton's method on the derivative to round-off.
fn distance_to_parabola(px: f64, py: f64) -> f64 {
    let squared = |u: f64| (u - px).powi(2) + (-u * u / 100.0 - py).powi(2);
    let mut best = (-40_000..=40_000)
        .map(|k| k as f64 * 0.05)
        .min_by(|a, b| squared(*a).total_cmp(&squared(*b)))
        .unwrap();
    let (mut a, mut b) = (best - 0.05, best + 0.05);
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..200 {
        let (c, d) = (b - ratio * (b - a), a + ratio * (b - a));
        if squared(c) < squared(d) {
            b = d;
        } else {
            a = c;
        }
    }
    best = 0.5 * (a + b);
    // f = (1/2) d/du squared, f' its derivative.
    let f = |u: f64| (u - px) + (-u * u / 100.0 - py) * (-u / 50.0);
    let df = |u: f64| 1.0 + (u / 50.0).powi(2) + (-u * u / 100.0 - py) * (-1.0 / 50.0);
    for _ in 0..20 {
        let next = best - f(best) / df(best);
        if squared(next) <= squared(best) {
            best = next;
        }
    }
    squared(best).sqrt()
}

fn sample_at(recorder: &mut Recorder, t: f64, point: [f64; 2]) {
    recorder
        .record(&bead::simulate::Sample {
            step: t as u64,
            t,
            x: &point,
            xdot: &[0.0, 0.0],
            energy: 0.0,
            constraint_error: (point[0] * point[0] + 100.0 * point[1]).abs(),
            q: &point,
            qdot: &[0.0, 0.0],
            work: None,
            energy_initial: 0.0,
            energy_scale: 1.0,
        })
        .unwrap();
}

/// Where the report says "distance" it is the true distance to the parabola of
/// scenes/parabola.toml: equal to an independent closest-point search to 1e-6 px, at points
/// up to 150 px off the curve on either side (where the first-order |C|/|grad C| is off by
/// tens of per cent), and along a real run that leaves the curve (implicit verlet).
#[test]
fn the_distance_panel_is_the_distance_to_the_closest_point_of_the_parabola() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
    let mut recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
    // Points off the curve: below it (outside the bowl, +y down), above it (inside),
    // ~100 px off near the bottom and on the sides, and one on it.
    let points = [
        [150.0, -225.0],
        [0.0, 100.0],
        [0.0, -30.0],
        [120.0, -44.0],
        [-80.0, 36.0],
        [60.0, -136.0],
        [-150.0, -125.0],
        [30.0, -49.0],
        [200.0, -300.0],
    ];
    for (k, p) in points.iter().enumerate() {
        sample_at(&mut recorder, k as f64, *p);
    }
    let recording = recorder.recording();
    assert!(recording.deviation_is_distance);
    assert_eq!(recording.closest_failures, 0);
    let mut largest_gap: f64 = 0.0;
    for (k, p) in points.iter().enumerate() {
        let reported = recording
            .deviation
            .iter()
            .find(|d| d.0 == k as f64)
            .unwrap_or_else(|| panic!("no distance at {p:?}"))
            .1;
        let truth = distance_to_parabola(p[0], p[1]);
        assert!(
            (reported - truth).abs() <= 1e-6,
            "at {p:?}: the report says {reported}, the closest point is {truth} away"
        );
        let first_order = (p[0] * p[0] + 100.0 * p[1]).abs() / (4.0 * p[0] * p[0] + 1e4).sqrt();
        if truth > 50.0 {
            largest_gap = largest_gap.max((first_order - truth).abs() / truth);
        }
    }
    // What the panel showed before: the first-order estimate, tens of per cent off there.
    assert!(
        largest_gap > 0.2,
        "first-order within {largest_gap} of the distance"
    );

    // A real run that leaves the curve: every recorded distance against the search at the
    // recorded position at the same time (all 600 samples are kept).
    let config = SimulationConfig {
        method: Method::Implicit,
        integrator: IntegratorKind::Verlet,
        dt: 1.0 / 60.0,
        ..Default::default()
    };
    let mut simulation = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    let mut recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
    let stats = run(&mut simulation, RunOptions::steps(600), &mut recorder)
        .unwrap_or_else(|e| panic!("{e}"));
    let recording = recorder.recording();
    let mut checked = 0;
    let mut farthest: f64 = 0.0;
    for &(t, distance) in &recording.deviation {
        let row = recording
            .trajectory
            .iter()
            .find(|r| r[0] == t)
            .unwrap_or_else(|| panic!("no position at t = {t}"));
        let truth = distance_to_parabola(row[1], row[2]);
        assert!(
            (distance - truth).abs() <= 1e-6,
            "t = {t}: {distance} vs {truth}"
        );
        farthest = farthest.max(truth);
        checked += 1;
    }
    assert!(
        checked > 500 && farthest > 10.0,
        "{checked} points, {farthest} px"
    );
    // The figure's panel says "distance" and draws the running maximum of these.
    let report = Report {
        title: "parabola".into(),
        description: "test".into(),
        system: Arc::clone(&scene.system),
        runs: vec![ReportRun {
            method: Method::Implicit,
            projected: false,
            integrator: IntegratorKind::Verlet,
            dt: 1.0 / 60.0,
            dt_label: "1/60".into(),
            rtol: None,
            stats,
            error: None,
            recording: recording.clone(),
        }],
        skipped: vec![],
        scene: None,
    };
    let panel = &report.constraint_figure().panels[1];
    assert!(panel
        .title
        .starts_with("distance to the constraint set (closest point)"));
    let drawn = panel.series[0].points.last().unwrap().1;
    assert!((drawn - farthest).abs() <= 1e-6, "{drawn} vs {farthest}");
}

/// With several constraint rows the panel keeps the first-order estimate and says so.
#[test]
fn several_rows_keep_the_first_order_estimate_labelled_as_such() {
    let text = "[world]\ngravity = [0.0, -9.81, 0.0]\n[[particle]]\nname = \"b\"\nmass = 1.0\nposition = [1.0, 0.0, 0.0]\n[[constraint]]\nexpr = \"b.x^2 + b.y^2 - 1\"\n[[constraint]]\nexpr = \"b.z\"\n";
    let scene = Scene::parse(text, "ring.toml", &[]).unwrap_or_else(|e| panic!("{e}"));
    let recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
    assert!(!recorder.recording().deviation_is_distance);
    let report = Report {
        title: "ring".into(),
        description: "test".into(),
        system: Arc::clone(&scene.system),
        runs: vec![],
        skipped: vec![],
        scene: None,
    };
    let panel = &report.constraint_figure().panels[1];
    assert!(
        panel.title.starts_with("first-order estimate |C|/|grad C|"),
        "{}",
        panel.title
    );
    assert!(!panel.y_label.starts_with("distance"));
}
