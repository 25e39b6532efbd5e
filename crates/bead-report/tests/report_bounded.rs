//! A report over a long run keeps a bounded number of points per series, so its files stay
//! small whatever the number of steps; and the progress hook is called a bounded number of
//! times.

use std::path::Path;
use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{run_with_progress, Progress, RunOptions, Simulation, SimulationConfig};
use bead_report::plot::DEFAULT_BUCKETS;
use bead_report::report::{write_report, Recorder, Report, ReportRun};

struct Count(u64, u64);
impl Progress for Count {
    fn advance(&mut self, step: u64, total: u64) {
        assert!(step <= total);
        self.0 += 1;
        self.1 = step;
    }
}

#[test]
fn a_report_over_100_000_steps_keeps_at_most_the_bounded_points_per_series() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/circle.toml");
    let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
    let steps = 100_000;
    let mut runs = Vec::new();
    for method in [Method::Implicit, Method::Parametric] {
        let config = SimulationConfig {
            method,
            integrator: IntegratorKind::Rk4,
            dt: 1e-3,
            ..Default::default()
        };
        let mut simulation = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        let mut recorder = Recorder::new(Arc::clone(&scene.system), DEFAULT_BUCKETS);
        let mut progress = Count(0, 0);
        let options = RunOptions::steps(steps);
        let stats = run_with_progress(&mut simulation, options, &mut recorder, &mut progress)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(progress.0 <= 101, "progress called {} times", progress.0);
        assert_eq!(progress.1, steps, "the last call reports the end");
        let recording = recorder.recording();
        assert_eq!(recording.samples, steps + 1);
        let bound = 2 * DEFAULT_BUCKETS;
        assert!(recording.constraint_error.len() <= bound);
        assert!(recording.energy_error.len() <= bound);
        assert!(recording.trajectory.len() <= bound + 1);
        assert!(
            recording.constraint_error.len() > bound / 4,
            "not over-decimated"
        );
        // The period is measured from every sample: 100 s of a 2.153 s pendulum.
        let period = recording.period.clone().expect("periodic");
        assert!((period.seconds - 2.1529).abs() < 2e-3, "{period:?}");
        assert_eq!(period.signal, "bead.vx");
        runs.push(ReportRun {
            method,
            projected: false,
            integrator: IntegratorKind::Rk4,
            dt: 1e-3,
            dt_label: "1/1000".into(),
            rtol: None,
            stats,
            error: None,
            recording,
        });
    }
    let report = Report {
        title: "circle".into(),
        description: "100 000 steps".into(),
        system: Arc::clone(&scene.system),
        runs,
        skipped: vec![],
        scene: None,
    };
    let dir = std::env::temp_dir().join(format!("bead-report-bounded-{}", std::process::id()));
    let files = write_report(&report, &dir).unwrap();
    // report_files lists what write_report writes (the CLI checks other outputs against it).
    let mut written: Vec<_> = files.plots.iter().chain([&files.html]).cloned().collect();
    let mut listed = bead_report::report::report_files(&dir);
    written.sort();
    listed.sort();
    assert_eq!(written, listed);
    let total: u64 = files
        .plots
        .iter()
        .chain([&files.html])
        .map(|f| std::fs::metadata(f).unwrap().len())
        .sum();
    assert!(total < 1_500_000, "report files total {total} bytes");
    let _ = std::fs::remove_dir_all(&dir);
}
