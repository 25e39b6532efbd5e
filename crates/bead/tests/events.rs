//! Events (`stop_when`): the run stops where an expression crosses zero upward, located to
//! 1e-10 of dt. Checked against analytic crossing times: free fall through a height
//! (t = sqrt(2h/g), which every integrator of order >= 2 integrates exactly, so that the
//! location alone is tested) and the pendulum reaching the bottom at a quarter of its exact
//! period (complete elliptic integral), for several integrators and both methods.

use std::f64::consts::PI;
use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::output::Summary;
use bead::scene::Scene;
use bead::simulate::{
    run, Event, EventError, NullSink, RunOptions, RunStats, Sample, Simulation, SimulationConfig,
    Sink,
};

/// A bead dropped from rest at the origin (+y down, g = 10) on the vertical line x = 0; its
/// parametric form is the height s = y.
const DROP: &str = r#"
[params]
g = 10.0
h = 2.5
[world]
gravity = [0.0, "g"]
[[particle]]
name = "bead"
mass = 1.0
position = [0.0, 0.0]
[[constraint]]
expr = "bead.x"
[parametric]
coordinates = ["s"]
initial = [0.0]
[parametric.positions]
bead = ["0*s", "s"]
"#;

/// The pendulum of scenes/circle.toml, released at rest at 60 degrees.
fn circle() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/circle.toml");
    Scene::load(std::path::Path::new(path), &[]).unwrap()
}

fn drop_scene() -> Scene {
    Scene::parse(DROP, "drop.toml", &[]).unwrap()
}

fn config(method: Method, integrator: IntegratorKind, dt: f64) -> SimulationConfig {
    let mut config = SimulationConfig {
        method,
        integrator,
        dt,
        ..Default::default()
    };
    config.settings.rtol = 1e-12;
    config.settings.atol = 1e-14;
    config
}

/// Records the times of the samples.
#[derive(Default)]
struct Times(Vec<f64>);
impl Sink for Times {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.0.push(sample.t);
        Ok(())
    }
}

fn run_until(
    scene: &Scene,
    event: &str,
    config: SimulationConfig,
    steps: u64,
) -> (RunStats, Simulation, Vec<f64>) {
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    sim.set_stop_when(Some(Event::parse(&scene.system, event).unwrap()))
        .unwrap();
    let mut times = Times::default();
    let stats = run(&mut sim, RunOptions::steps(steps), &mut times).unwrap();
    (stats, sim, times.0)
}

/// Integrators exact for a constant acceleration (order >= 2), each with a method it runs.
fn exact_for_free_fall() -> Vec<(Method, IntegratorKind)> {
    use IntegratorKind::*;
    vec![
        (Method::Implicit, Rk4),
        (Method::Implicit, Midpoint),
        (Method::Implicit, Verlet),
        (Method::Implicit, Rattle),
        (Method::Implicit, Dopri5),
        (Method::Parametric, Rk4),
        (Method::Parametric, GaussLegendre),
        (Method::Parametric, Dopri5),
        (Method::Parametric, Verlet),
    ]
}

#[test]
fn free_fall_stops_at_sqrt_2h_over_g_to_1e_10_of_dt() {
    let scene = drop_scene();
    let exact = (2.0f64 * 2.5 / 10.0).sqrt();
    let dt = 0.01;
    for (method, integrator) in exact_for_free_fall() {
        for event in ["bead.y - h", "s - h", "q.s - 2.5"] {
            if method == Method::Implicit && event != "bead.y - h" {
                continue;
            }
            let (stats, sim, times) = run_until(&scene, event, config(method, integrator, dt), 500);
            let label = format!("{} {} {event}", method.name(), integrator.name());
            let t = stats
                .stop_time
                .unwrap_or_else(|| panic!("{label}: no event"));
            assert!(
                (t - exact).abs() <= 1e-10 * dt + 1e-15,
                "{label}: {t} vs {exact}: {:e}",
                t - exact
            );
            assert_eq!(stats.t_final, t, "{label}");
            assert_eq!(sim.t(), t, "{label}");
            assert!(sim.stopped_at_event(), "{label}");
            assert_eq!(sim.event_time(), Some(t), "{label}");
            // The final state is the state at the crossing, just past it (g >= 0).
            let y = sim.positions()[1];
            assert!(
                y >= 2.5 && y - 2.5 <= 10.0 * exact * 2e-10 * dt,
                "{label}: y = {y}"
            );
            // The trace ends at the crossing.
            assert_eq!(*times.last().unwrap(), t, "{label}");
            assert!(times[times.len() - 2] < t, "{label}");
            assert_eq!(stats.stop_when.as_deref(), Some(event));
        }
    }
}

/// Euler is not exact for free fall: the crossing is that of its own trajectory,
/// y_k = g dt^2 k (k - 1) / 2 at the steps, and a partial step of length s from step k is
/// y_k + s v_k. The event finds the root of that path, not of the exact one.
#[test]
fn euler_stops_where_its_own_trajectory_crosses() {
    let scene = drop_scene();
    let dt = 0.01;
    let (stats, _, _) = run_until(
        &scene,
        "bead.y - h",
        config(Method::Implicit, IntegratorKind::Euler, dt),
        1000,
    );
    let g = 10.0;
    let y = |k: f64| g * dt * dt * k * (k - 1.0) / 2.0;
    let k = (1..1000).find(|&k| y(k as f64 + 1.0) >= 2.5).unwrap() as f64;
    let v = g * dt * k;
    let expected = k * dt + (2.5 - y(k)) / v;
    let t = stats.stop_time.unwrap();
    assert!((t - expected).abs() <= 1e-10 * dt + 1e-14, "{t} {expected}");
}

fn agm(mut a: f64, mut b: f64) -> f64 {
    while (a - b).abs() > 1e-16 * a {
        (a, b) = ((a + b) / 2.0, (a * b).sqrt());
    }
    a
}

/// The time the pendulum of scenes/circle.toml takes from rest at 60 degrees to the bottom:
/// a quarter period, sqrt(L/g) K(sin(theta0/2)).
fn quarter_period() -> f64 {
    let k = (PI / 6.0).sin();
    let elliptic_k = PI / (2.0 * agm(1.0, (1.0 - k * k).sqrt()));
    (1.0f64 / 9.81).sqrt() * elliptic_k
}

#[test]
fn the_pendulum_reaches_the_bottom_at_a_quarter_period() {
    let scene = circle();
    let exact = quarter_period();
    use IntegratorKind::*;
    // (method, integrator, dt, event, tolerance of the integrator's own error)
    let cases = [
        (Method::Implicit, Rk4, 1e-3, "-bead.x", 1e-11),
        (Method::Implicit, Rattle, 1e-3, "-bead.x", 1e-6),
        (Method::Implicit, Dopri5, 1e-2, "-bead.x", 1e-10),
        (Method::Implicit, GaussLegendre, 1e-3, "-bead.x", 1e-11),
        (Method::Parametric, Rk4, 1e-3, "-theta", 1e-11),
        (Method::Parametric, GaussLegendre, 1e-3, "-q.theta", 1e-11),
        (Method::Parametric, Dopri5, 1e-2, "-bead.x", 1e-10),
        (Method::Parametric, Verlet, 1e-3, "-theta", 1e-6),
    ];
    for (method, integrator, dt, event, tolerance) in cases {
        let label = format!("{} {} {event}", method.name(), integrator.name());
        let (stats, sim, _) = run_until(&scene, event, config(method, integrator, dt), 2000);
        let t = stats
            .stop_time
            .unwrap_or_else(|| panic!("{label}: no event"));
        assert!(
            (t - exact).abs() <= tolerance,
            "{label}: {t} vs {exact}: {:e}",
            t - exact
        );
        // Located on the integrator's own path to 1e-10 of dt: g = -x at the final state
        // is >= 0 and below |dg/dt| 1e-10 dt (|dx/dt| is the speed at the bottom, < 3).
        let x = sim.positions()[0];
        assert!(
            -x >= 0.0 && -x <= 3.0 * 1e-10 * dt + 1e-15,
            "{label}: x = {x:e}"
        );
    }
}

#[test]
fn substeps_and_the_projection_work_with_events() {
    let scene = circle();
    let exact = quarter_period();
    for (integrator, substeps, project) in [
        (IntegratorKind::Rattle, 4, false),
        (IntegratorKind::Rk4, 3, true),
        (IntegratorKind::Verlet, 2, true),
    ] {
        let mut config = config(Method::Implicit, integrator, 1e-2);
        config.substeps = substeps;
        config.project = project;
        let (stats, sim, _) = run_until(&scene, "-bead.x", config, 200);
        let t = stats.stop_time.unwrap();
        assert!(
            (t - exact).abs() < 1e-4,
            "{}: {t} {exact}",
            integrator.name()
        );
        let x = sim.positions()[0];
        assert!(
            -x >= 0.0 && -x <= 3.0 * 1e-12,
            "{}: {x:e}",
            integrator.name()
        );
        assert!(sim.constraint_error() < 1e-10, "{}", integrator.name());
    }
}

#[test]
fn an_event_on_the_first_step() {
    let scene = drop_scene();
    // y = 5 t^2 reaches 1e-4 at t = sqrt(2e-5), inside the first step of 0.01.
    let (stats, _, times) = run_until(
        &scene,
        "bead.y - 1e-4",
        config(Method::Implicit, IntegratorKind::Rk4, 0.01),
        100,
    );
    let t = stats.stop_time.unwrap();
    assert!((t - 2e-5f64.sqrt()).abs() <= 1e-12, "{t}");
    assert_eq!(stats.steps, 1);
    assert_eq!(times, vec![0.0, t]);
}

#[test]
fn an_expression_that_never_crosses_runs_to_the_end() {
    let scene = drop_scene();
    for integrator in [IntegratorKind::Rk4, IntegratorKind::Dopri5] {
        let (stats, sim, times) = run_until(
            &scene,
            "-1 - bead.y",
            config(Method::Implicit, integrator, 0.01),
            100,
        );
        assert_eq!(stats.stop_time, None);
        assert!((stats.t_final - 1.0).abs() < 1e-12);
        assert!(!sim.stopped_at_event());
        assert_eq!(times.len(), 101);
    }
}

/// g >= 0 at t = 0 is no crossing: only an upward crossing fires. x = L sin(theta) starts
/// positive, goes negative at a quarter period and positive again at three quarters: the
/// event `bead.x` fires there.
#[test]
fn an_expression_already_positive_at_the_start_fires_at_its_next_upward_crossing() {
    let scene = circle();
    let exact = 3.0 * quarter_period();
    for (method, event) in [(Method::Implicit, "bead.x"), (Method::Parametric, "theta")] {
        let (stats, _, _) = run_until(
            &scene,
            event,
            config(method, IntegratorKind::Rk4, 1e-3),
            10_000,
        );
        let t = stats.stop_time.unwrap();
        assert!((t - exact).abs() < 1e-10, "{t} {exact}");
    }
    // Exactly 0 at the start (the bead at the bottom, moving right): not a crossing either.
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/circle.toml"
    ))
    .unwrap();
    let scene = Scene::parse(&text, "circle.toml", &[("theta0".into(), 0.0)]).unwrap();
    let mut sim = Simulation::new(
        Arc::clone(&scene.system),
        config(Method::Implicit, IntegratorKind::Rk4, 1e-3),
    )
    .unwrap();
    sim.set_stop_when(Some(Event::parse(&scene.system, "bead.x").unwrap()))
        .unwrap();
    sim.advance_to(0.5).unwrap();
    assert!(!sim.stopped_at_event());
    assert_eq!(sim.event_time(), None);
}

/// After an event the simulation can go on, and the next upward crossing fires again; an
/// adaptive integrator's crossing beyond a requested time fires only once the output reaches
/// it.
#[test]
fn the_simulation_goes_on_after_an_event() {
    let scene = circle();
    let quarter = quarter_period();
    for integrator in [IntegratorKind::Rk4, IntegratorKind::Dopri5] {
        let mut sim = Simulation::new(
            Arc::clone(&scene.system),
            config(Method::Implicit, integrator, 1e-2),
        )
        .unwrap();
        sim.set_stop_when(Some(Event::parse(&scene.system, "-bead.x").unwrap()))
            .unwrap();
        sim.advance_to(quarter - 0.001).unwrap();
        assert!(!sim.stopped_at_event(), "{}", integrator.name());
        sim.advance_to(10.0).unwrap();
        assert!(sim.stopped_at_event());
        let first = sim.t();
        assert!((first - quarter).abs() < 1e-6, "{first} {quarter}");
        sim.advance_to(10.0).unwrap();
        assert!(sim.stopped_at_event());
        // -x crosses upward again after a whole period.
        assert!((sim.t() - 5.0 * quarter).abs() < 1e-5, "{}", sim.t());
        sim.reset();
        assert_eq!(sim.event_time(), None);
    }
}

#[test]
fn a_scene_stop_when_reaches_the_summary() {
    let text = format!("{DROP}[run]\nstop_when = \"bead.y - h\"\n");
    let scene = Scene::parse(&text, "drop.toml", &[("h".into(), 5.0)]).unwrap();
    let event = scene.run.stop_when.clone().unwrap();
    assert_eq!(event.source(), "bead.y - h");
    let mut sim = Simulation::new(
        Arc::clone(&scene.system),
        config(Method::Implicit, IntegratorKind::Rk4, 0.01),
    )
    .unwrap();
    sim.set_stop_when(Some(event)).unwrap();
    let result = run(&mut sim, RunOptions::default(), &mut NullSink);
    let summary = Summary::from_result("drop.toml", &scene.system, &[], &result);
    let json: serde_json::Value = serde_json::from_str(&summary.to_json_pretty().unwrap()).unwrap();
    // h = 5 by the override: t = 1.
    assert!((json["stop_time"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    assert_eq!(json["stop_when"], "bead.y - h");
    assert_eq!(json["completed"], true);
    // Without an event both are null.
    let mut sim = Simulation::new(
        Arc::clone(&scene.system),
        config(Method::Implicit, IntegratorKind::Rk4, 0.01),
    )
    .unwrap();
    let result = run(&mut sim, RunOptions::steps(3), &mut NullSink);
    let summary = Summary::from_result("drop.toml", &scene.system, &[], &result);
    let json: serde_json::Value = serde_json::from_str(&summary.to_json_pretty().unwrap()).unwrap();
    assert!(json["stop_time"].is_null());
    assert!(json["stop_when"].is_null());
}

#[test]
fn stop_when_errors_are_located() {
    let cases = [
        (
            "stop_when = \"bead.y - hh\"",
            "drop.toml:19:23: run: `stop_when`: unknown name `hh`",
            "                      ^^",
        ),
        (
            "stop_when = \"bead.y - \"",
            "drop.toml:19:23: run: `stop_when`: ",
            "                     ^",
        ),
        (
            "stop_when = \"bead.w\"",
            "drop.toml:19:14: run: `stop_when`: `bead` has no coordinate `w`; in 2D use x, y and vx, vy",
            "             ^^^^^^",
        ),
        (
            "stop_when = \"other.x\"",
            "drop.toml:19:14: run: `stop_when`: unknown particle `other`",
            "             ^^^^^^^",
        ),
        (
            "stop_when = \"qdot.r\"",
            "drop.toml:19:14: run: `stop_when`: `qdot.r`: no generalized coordinate `r`; coordinates: s",
            "             ^^^^^^",
        ),
    ];
    for (line, start, caret) in cases {
        let text = format!("{DROP}[run]\n{line}\n");
        let error = Scene::parse(&text, "drop.toml", &[]).unwrap_err().render();
        assert!(error.starts_with(start), "{error}");
        // The caret line: under the offending text, after the snippet's margin.
        assert!(
            error.lines().any(|l| l.ends_with(caret.trim_start())
                && l.len() >= caret.len()
                && l.trim_end().chars().filter(|&c| c == '^').count() == caret.trim().len()),
            "{error}"
        );
    }
}

#[test]
fn generalized_coordinates_need_the_parametric_form() {
    let scene = drop_scene();
    let mut sim = Simulation::new(
        Arc::clone(&scene.system),
        config(Method::Implicit, IntegratorKind::Rk4, 0.01),
    )
    .unwrap();
    let event = Event::parse(&scene.system, "qdot.s - 1").unwrap();
    assert!(event.uses_coordinates());
    let error = sim.set_stop_when(Some(event)).unwrap_err();
    assert!(matches!(error, EventError::NeedsParametric { .. }));
    assert!(error.to_string().contains("implicit form"), "{error}");
    // An event of another system is refused.
    let other = circle();
    let event = Event::parse(&other.system, "theta").unwrap();
    let mut sim = Simulation::new(
        Arc::clone(&scene.system),
        config(Method::Parametric, IntegratorKind::Rk4, 0.01),
    )
    .unwrap();
    // Same shape (one particle in 2D, one coordinate): accepted; a different shape is not.
    assert!(sim.set_stop_when(Some(event)).is_ok());
    let three_d = Scene::parse(
        "[world]\ngravity = [0.0, 0.0, 1.0]\n[[particle]]\nname = \"p\"\nmass = 1.0\nposition = [0.0, 0.0, 0.0]\n",
        "p.toml",
        &[],
    )
    .unwrap();
    let event = Event::parse(&three_d.system, "p.z - 1").unwrap();
    assert!(matches!(
        sim.set_stop_when(Some(event)),
        Err(EventError::OtherSystem { .. })
    ));
}

/// Velocities, t and single-particle plain names resolve.
#[test]
fn velocities_time_and_plain_names() {
    let scene = drop_scene();
    for (event, exact) in [
        // v = g t reaches 5 at t = 0.5
        ("bead.vy - 5", 0.5),
        ("vy - 5", 0.5),
        ("t - 0.25", 0.25),
        ("y - 0.2", (0.04f64).sqrt()),
    ] {
        let (stats, _, _) = run_until(
            &scene,
            event,
            config(Method::Implicit, IntegratorKind::Rk4, 0.01),
            200,
        );
        let t = stats.stop_time.unwrap();
        assert!((t - exact).abs() < 1e-12, "{event}: {t}");
    }
}
