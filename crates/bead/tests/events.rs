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
    run, Direction, Event, EventError, EventSpec, NullSink, RunOptions, RunStats, Sample,
    Simulation, SimulationConfig, Sink,
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
        // is >= 0 and below |dg/dt| 1e-10 dt (|dx/dt| is the speed at the bottom,
        // sqrt(2 g L (1 - cos 60°)) = sqrt(9.81) < 3.2).
        let x = sim.positions()[0];
        assert!(
            -x >= 0.0 && -x <= 3.2 * 1e-10 * dt + 1e-15,
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
        // The speed at the bottom is sqrt(9.81) < 3.2 (see above), the bracket 1e-10 dt.
        let x = sim.positions()[0];
        assert!(
            -x >= 0.0 && -x <= 3.2 * 1e-12,
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

/// Carlson's symmetric elliptic integral R_F(x, y, z), by duplication to |1 - x/mu| < 1e-4
/// and the fifth-order series (truncation ~1e-24).
fn carlson_rf(mut x: f64, mut y: f64, mut z: f64) -> f64 {
    loop {
        let mu = (x + y + z) / 3.0;
        let (dx, dy, dz) = (1.0 - x / mu, 1.0 - y / mu, 1.0 - z / mu);
        if dx.abs().max(dy.abs()).max(dz.abs()) < 1e-4 {
            let e2 = dx * dy - dz * dz;
            let e3 = dx * dy * dz;
            return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0)
                / mu.sqrt();
        }
        let l = (x * y).sqrt() + (y * z).sqrt() + (z * x).sqrt();
        (x, y, z) = ((x + l) / 4.0, (y + l) / 4.0, (z + l) / 4.0);
    }
}

/// The incomplete elliptic integral of the first kind F(phi, k).
fn elliptic_f(phi: f64, k: f64) -> f64 {
    let (s, c) = phi.sin_cos();
    s * carlson_rf(c * c, 1.0 - k * k * s * s, 1.0)
}

/// The pendulum of scenes/circle.toml (L = 1, g = 9.81, released at rest at theta0 = 60°):
/// the time of the first upward crossing of x = L sin(theta_c), theta_c < theta0, which
/// happens as the bead comes back up to theta0 after a whole period T: T - t(theta_c), with
/// t(theta) = sqrt(L/g) (K(k) - F(phi, k)) the time from the release down to theta, k =
/// sin(theta0/2), sin(phi) = sin(theta/2)/k. The bead stays beyond x_c for 2 t(theta_c)
/// around T.
fn pendulum_return(theta_c: f64) -> (f64, f64) {
    let theta0 = PI / 3.0;
    let k = (theta0 / 2.0).sin();
    let scale = (1.0f64 / 9.81).sqrt();
    let big_k = elliptic_f(PI / 2.0, k);
    let phi = ((theta_c / 2.0).sin() / k).asin();
    let t_c = scale * (big_k - elliptic_f(phi, k));
    (4.0 * scale * big_k - t_c, t_c)
}

fn with_samples(mut config: SimulationConfig, samples: u32) -> SimulationConfig {
    config.event_samples = samples;
    config
}

/// g = sin(100 t) starts at 0, goes up, down through zero at pi/100 and up again at
/// 2 pi/100 = 0.0628: within the first step of 0.1. Its end samples alone compare g(0) = 0
/// and g(0.1) < 0 and fire at the next step with g >= 0 at its end (0.1257); the samples
/// inside the step find the first upward crossing, and it is located to 1e-10 dt, for every
/// integrator and both forms (the expression reads t alone, so the path does not matter).
/// Going on, every later upward crossing 2 pi k / 100 fires in turn, about 1.6 per step of
/// 0.1, dopri5's long steps included (free fall is exact for it, so its steps grow to the
/// end; its dense output is sampled at least every dt / 5 too).
#[test]
fn event_crossing_within_one_step_is_found() {
    use IntegratorKind::*;
    let scene = drop_scene();
    let dt = 0.1;
    let cases = [
        (Method::Implicit, Euler),
        (Method::Implicit, SymplecticEuler),
        (Method::Implicit, Midpoint),
        (Method::Implicit, Rk4),
        (Method::Implicit, Verlet),
        (Method::Implicit, Rattle),
        (Method::Implicit, GaussLegendre),
        (Method::Implicit, Dopri5),
        (Method::Parametric, Rk4),
        (Method::Parametric, GaussLegendre),
        (Method::Parametric, Dopri5),
    ];
    for (method, integrator) in cases {
        let label = format!("{} {}", method.name(), integrator.name());
        let mut config = config(method, integrator, dt);
        config.settings.rtol = 1e-6;
        let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        sim.set_stop_when(Some(Event::parse(&scene.system, "sin(100*t)").unwrap()))
            .unwrap();
        sim.set_stop_time(Some(1.0));
        for k in 1..=15 {
            sim.advance_to(1.0).unwrap();
            let exact = 2.0 * PI * k as f64 / 100.0;
            assert!(sim.stopped_at_event(), "{label}: crossing {k} not found");
            assert!(
                (sim.t() - exact).abs() <= 1e-10 * dt + 4.0 * f64::EPSILON,
                "{label}: crossing {k} at {} instead of {exact}: {:e}",
                sim.t(),
                sim.t() - exact
            );
        }
    }
    // The command-line case of the issue: `bead run scenes/parabola.toml --stop-when
    // "sin(100*t)" --dt 0.1` reported 0.1257.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/parabola.toml");
    let parabola = Scene::load(std::path::Path::new(path), &[]).unwrap();
    let (stats, _, _) = run_until(
        &parabola,
        "sin(100*t)",
        SimulationConfig {
            dt,
            ..Default::default()
        },
        100,
    );
    let t = stats.stop_time.unwrap();
    assert!((t - 0.02 * PI).abs() <= 1e-10 * dt, "{t}");
    // Without interior samples only the step ends are compared: the crossing is missed.
    let (stats, _, _) = run_until(
        &parabola,
        "sin(100*t)",
        with_samples(
            SimulationConfig {
                dt,
                ..Default::default()
            },
            0,
        ),
        100,
    );
    assert!(stats.stop_time.unwrap() > 0.1);
}

/// A physical double crossing: the pendulum comes back up to its release angle after a
/// period T = 2.1529 s and stays beyond x_c = sin(theta_c), theta_c just below theta0, for
/// 2 t_c around T (elliptic integrals, independent of bead). rk4 at dt = 0.02 with
/// theta_c = theta0 - 1.5e-4 (a window of 0.012 s inside its step from 2.14 to 2.16; rk4
/// loses about 40 h^4 rad of amplitude a period, 6e-6 here, which moves the return by
/// 1e-4 s), gauss-legendre at dt = 0.1 with theta0 - 4e-3 (0.061 s inside the step from 2.1
/// to 2.2): compared at the step ends alone (`event_samples` 0) the return is missed and
/// the run goes on to its end; with the default samples it is found, to the integrator's
/// own error, and located on its path to 1e-10 dt. dopri5 at dt = 0.1 with theta0 - 4e-5:
/// a window of 0.006 s, narrower than the default spacing of dt / 5 = 0.02 s, falls between
/// two samples of its dense output and is missed; 32 samples per dt (spacing 0.003 s) find
/// it.
#[test]
fn event_double_crossing_of_a_pendulum_within_one_step_is_found() {
    let scene = circle();
    let theta0 = PI / 3.0;
    let default = SimulationConfig::default().event_samples;
    for (integrator, dt, drop, tolerance, missed, found) in [
        (IntegratorKind::Rk4, 0.02, 1.5e-4, 3e-4, 0, default),
        (IntegratorKind::GaussLegendre, 0.1, 4e-3, 1e-4, 0, default),
        (IntegratorKind::Dopri5, 0.1, 4e-5, 2e-5, default, 32),
    ] {
        let label = integrator.name();
        let theta_c = theta0 - drop;
        let (exact, t_c) = pendulum_return(theta_c);
        let event = format!("bead.x - {}", theta_c.sin());
        let mut config = config(Method::Implicit, integrator, dt);
        config.settings.rtol = 1e-7;
        config.settings.atol = 1e-9;
        let steps = (3.0 / dt) as u64;
        let (stats, sim, _) = run_until(&scene, &event, with_samples(config, found), steps);
        let t = stats
            .stop_time
            .unwrap_or_else(|| panic!("{label}: the return at {exact} was missed"));
        assert!(
            (t - exact).abs() <= tolerance,
            "{label}: {t} vs {exact} (window {t_c}): {:e}",
            t - exact
        );
        let g = sim.positions()[0] - theta_c.sin();
        assert!(g >= 0.0 && g <= 1e-10 * dt, "{label}: g = {g:e}");
        let (stats, _, _) = run_until(&scene, &event, with_samples(config, missed), steps);
        assert_eq!(
            stats.stop_time, None,
            "{label}: found with {missed} samples"
        );
    }
}

/// A sample on the interpolant that the integrator's path does not confirm is no event, and
/// the step stands as it was. Euler's first step from rest keeps y = 0 (y1 = y0 + h v0), and
/// the path of a part of it too, while the cubic through the step's ends dips to
/// -g h^2 s^2 (1 - s) < 0 inside it: `-1e-9 - bead.y` is negative on the path throughout (it
/// never crosses) and positive on the interpolant. The run ends where the run without the
/// event ends, bit for bit.
#[test]
fn a_sample_the_integrators_path_does_not_confirm_does_not_fire() {
    let scene = drop_scene();
    let config = config(Method::Implicit, IntegratorKind::Euler, 0.1);
    let (stats, _, _) = run_until(&scene, "-1e-9 - bead.y", config, 20);
    assert_eq!(stats.stop_time, None);
    let mut plain = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    let want = run(&mut plain, RunOptions::steps(20), &mut NullSink).unwrap();
    assert_eq!(stats.x, want.x);
    assert_eq!(stats.xdot, want.xdot);
    assert_eq!(stats.energy_rel_error_max, want.energy_rel_error_max);
    assert_eq!(stats.constraint_error_max, want.constraint_error_max);
    assert_eq!(stats.steps, want.steps);
}

/// A stop condition that becomes NaN is an error naming it, the time and the values it
/// read, and the run stands at the start of the step, where it was a number; once NaN at
/// the start, at t = 0. It used to never fire, silently.
#[test]
fn event_condition_nan_is_an_error() {
    let scene = circle();
    let quarter = quarter_period();
    use IntegratorKind::*;
    for (method, integrator, samples) in [
        (Method::Implicit, Rk4, 4),
        (Method::Implicit, Rk4, 0),
        (Method::Implicit, Rattle, 4),
        (Method::Implicit, Dopri5, 4),
        (Method::Implicit, Dopri5, 0),
        (Method::Parametric, GaussLegendre, 4),
        (Method::Parametric, Rk4, 4),
    ] {
        let label = format!("{} {} {samples}", method.name(), integrator.name());
        let dt = 0.01;
        // x crosses zero downward at a quarter period: sqrt(x) is NaN from there.
        let config = with_samples(config(method, integrator, dt), samples);
        let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        sim.set_stop_when(Some(Event::parse(&scene.system, "sqrt(bead.x)").unwrap()))
            .unwrap();
        let failure = run(&mut sim, RunOptions::steps(100), &mut NullSink).expect_err(&label);
        let bead::simulate::RunError::EventNotANumber {
            t, values, stopped, ..
        } = &failure.error
        else {
            panic!("{label}: {}", failure.error);
        };
        let message = failure.error.to_string();
        assert!(
            message.starts_with(&format!(
                "stop_when `sqrt(bead.x)` is not a number at t = {}",
                bead::readable(*t)
            )),
            "{label}: {message}"
        );
        assert!(message.contains("(with bead.x = -"), "{label}: {message}");
        assert_eq!(values.len(), 1);
        assert!(values[0].1 < 0.0);
        // At the first sample past the quarter period, or the first step end.
        let spacing = if samples > 0 && integrator != Dopri5 {
            dt / (samples + 1) as f64
        } else {
            dt
        };
        assert!(
            *t > quarter && *t <= quarter + spacing + 1e-9,
            "{label}: {t}"
        );
        // The run stands at the start of the step, a good state (x > 0), before t.
        assert_eq!(failure.stats.t_final, *stopped, "{label}");
        assert_eq!(sim.t(), *stopped, "{label}");
        assert!(*stopped < quarter && *stopped < *t, "{label}: {stopped}");
        assert!(sim.positions()[0] > 0.0, "{label}");
        if integrator != Dopri5 {
            assert!(quarter - stopped <= dt, "{label}: {stopped}");
        }
    }
    // NaN from the start: the error is at t = 0, and the run does not move.
    let mut sim = Simulation::new(
        Arc::clone(&scene.system),
        config(Method::Implicit, Rk4, 0.01),
    )
    .unwrap();
    sim.set_stop_when(Some(Event::parse(&scene.system, "sqrt(-bead.x)").unwrap()))
        .unwrap();
    let failure = run(&mut sim, RunOptions::steps(10), &mut NullSink).unwrap_err();
    assert!(
        failure
            .error
            .to_string()
            .starts_with("stop_when `sqrt(-bead.x)` is not a number at t = 0 (with bead.x = 0.866"),
        "{}",
        failure.error
    );
    assert_eq!(failure.stats.t_final, 0.0);
    assert_eq!(failure.stats.steps, 0);
}

/// An event that is not the stop condition is named as an event in the same error.
#[test]
fn an_event_that_is_not_a_number_is_named_as_an_event() {
    let scene = circle();
    let config = config(Method::Implicit, IntegratorKind::Rk4, 0.01);
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    let event = Event::parse(&scene.system, "sqrt(bead.x)").unwrap();
    sim.set_events(vec![EventSpec {
        event,
        direction: Direction::Down,
        terminal: false,
        stop_when: false,
    }])
    .unwrap();
    let failure = run(&mut sim, RunOptions::steps(100), &mut NullSink).unwrap_err();
    let message = failure.error.to_string();
    assert!(
        message.starts_with("the event `sqrt(bead.x)` is not a number at t = 0.5"),
        "{message}"
    );
}

/// The first thing on the path decides: g = 0.2 - sqrt(0.07 - t) crosses zero upward at
/// t = 0.03 and is NaN from 0.07, both inside the first step of 0.1. The samples find the
/// crossing first, and the run stops there; compared at the step's ends alone, g is NaN at
/// the end, an error at t = 0.1.
#[test]
fn a_crossing_before_a_nan_in_the_same_step_fires_first() {
    let scene = drop_scene();
    let source = "0.2 - sqrt(0.07 - t)";
    let config = config(Method::Implicit, IntegratorKind::Rk4, 0.1);
    let (stats, _, _) = run_until(&scene, source, config, 10);
    let t = stats.stop_time.unwrap();
    assert!((t - 0.03).abs() <= 1e-11, "{t}");
    let mut sim = Simulation::new(Arc::clone(&scene.system), with_samples(config, 0)).unwrap();
    sim.set_stop_when(Some(Event::parse(&scene.system, source).unwrap()))
        .unwrap();
    let failure = run(&mut sim, RunOptions::steps(10), &mut NullSink).unwrap_err();
    assert_eq!(
        failure.error.to_string(),
        "stop_when `0.2 - sqrt(0.07 - t)` is not a number at t = 0.1; the run stopped at the last good state, t = 0"
    );
    assert_eq!(failure.stats.t_final, 0.0);
}

/// `[run] event_samples` reaches the plan (a request overrides it), and a bad count is
/// refused where it is written; a request beyond the limit names the option.
#[test]
fn event_samples_come_from_the_scene_or_the_request_and_are_checked() {
    use bead::plan::{Plan, PlanRequest};
    let text = format!("{DROP}[run]\nevent_samples = 9\n");
    let scene = Scene::parse(&text, "drop.toml", &[]).unwrap();
    assert_eq!(scene.run.event_samples, Some(9));
    let plan = Plan::resolve(&scene, &PlanRequest::default()).unwrap();
    assert_eq!(plan.config(Method::Implicit).event_samples, 9);
    let asked = PlanRequest {
        event_samples: Some(0),
        ..Default::default()
    };
    assert_eq!(
        Plan::resolve(&scene, &asked)
            .unwrap()
            .config(Method::Implicit)
            .event_samples,
        0
    );
    let default = Plan::resolve(&drop_scene(), &PlanRequest::default()).unwrap();
    assert_eq!(default.config(Method::Implicit).event_samples, 4);
    let too_many = PlanRequest {
        event_samples: Some(5000),
        ..Default::default()
    };
    assert_eq!(
        Plan::resolve(&scene, &too_many).unwrap_err().to_string(),
        "event_samples=5000: must be at most 1024"
    );
    for (value, shown) in [("2000", "2000"), ("1.5", "1.5"), ("-1", "-1")] {
        let text = format!("{DROP}[run]\nevent_samples = {value}\n");
        let error = Scene::parse(&text, "drop.toml", &[]).unwrap_err().render();
        assert!(
            error.starts_with(&format!(
                "drop.toml:19:17: run: `event_samples` must be a whole number from 0 to 1024, got {shown}"
            )),
            "{error}"
        );
    }
    // The simulation refuses a count beyond the limit as well.
    let config = SimulationConfig {
        event_samples: 1025,
        ..Default::default()
    };
    let error = Simulation::new(Arc::clone(&scene.system), config).unwrap_err();
    assert_eq!(
        error.to_string(),
        "event_samples must be at most 1024, got 1025"
    );
}

/// Locating an event integrates parts of a step again from its start; the integrators that
/// carry their multipliers from step to step (rattle, rattle4 and fast-projection: the warm
/// start of their Newton iterations) set them aside meanwhile, so that a run that records
/// crossings takes every step as the same run without them, bit for bit. The control: the
/// crossings are there, and a partial step from the step's start leaves the multipliers of
/// a step the run did not take (without the set-aside the next step differs).
#[test]
fn recording_events_changes_no_bit_of_a_warm_started_run() {
    let scene = circle();
    for integrator in [
        IntegratorKind::Rattle,
        IntegratorKind::Rattle4,
        IntegratorKind::FastProjection,
    ] {
        let config = config(Method::Implicit, integrator, 0.01);
        let mut plain = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        let mut watched = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        let crossing = |direction| EventSpec {
            event: Event::parse(&scene.system, "bead.x").unwrap(),
            direction,
            terminal: false,
            stop_when: false,
        };
        watched
            .set_events(vec![crossing(Direction::Down), crossing(Direction::Up)])
            .unwrap();
        for step in 0..300 {
            plain.step().unwrap();
            watched.step().unwrap();
            assert_eq!(
                plain.positions(),
                watched.positions(),
                "{integrator:?}, step {step}"
            );
            assert_eq!(
                plain.velocities(),
                watched.velocities(),
                "{integrator:?}, step {step}"
            );
        }
        let crossings = watched.stats(0.0).events;
        assert!(
            crossings.iter().map(|e| e.times.len()).sum::<usize>() >= 2,
            "{integrator:?}: {crossings:?}"
        );
    }
}

/// g = -1/bead.x changes sign where the pendulum passes the bottom (x = 0, a quarter
/// period), by a pole, not by crossing zero: the run stops at the step's start with an
/// error that says so, at the pole's time, on a fixed-step path and on a dense output,
/// terminal or not; a bounded jump there (-sign(bead.x), or times 2 - x^2) still fires at
/// the same time, as -bead.x does; and a g that is infinite (1/0) is an error as a NaN is.
#[test]
fn a_pole_is_not_a_crossing_and_an_infinite_value_is_an_error() {
    use bead::simulate::RunError;
    use IntegratorKind::*;
    let scene = circle();
    let exact = quarter_period();
    for (integrator, dt, tolerance) in [(Rk4, 1e-3, 1e-11), (Dopri5, 1e-2, 1e-10)] {
        for terminal in [true, false] {
            let label = format!("{} terminal {terminal}", integrator.name());
            let config = config(Method::Implicit, integrator, dt);
            let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
            let event = Event::parse(&scene.system, "-1/bead.x").unwrap();
            sim.set_events(vec![EventSpec {
                event,
                direction: Direction::Up,
                terminal,
                stop_when: terminal,
            }])
            .unwrap();
            let failure = run(&mut sim, RunOptions::steps(2000), &mut NullSink).expect_err(&label);
            let RunError::EventJump {
                t,
                before,
                after,
                stopped,
                ..
            } = failure.error
            else {
                panic!("{label}: {}", failure.error);
            };
            assert!((t - exact).abs() <= tolerance, "{label}: {t} vs {exact}");
            assert!(before < -1e6 && after > 1e6, "{label}: {before} {after}");
            assert!(stopped < t && t - stopped <= dt, "{label}: {stopped}");
            assert_eq!(failure.stats.t_final, stopped, "{label}");
            let name = if terminal { "stop_when" } else { "the event" };
            let message = failure.error.to_string();
            let start = format!("{name} `-1/bead.x` jumps over zero at t = ");
            assert!(message.starts_with(&start), "{message}");
            assert!(
                message.contains(": a pole, not a crossing of zero)"),
                "{message}"
            );
            // Bounded jumps fire where -bead.x crosses, even one whose size at the crossing
            // exceeds its size at the samples around it (2 against ~1.2).
            let at = |g: &str| run_until(&scene, g, config, 2000).0.stop_time.unwrap();
            let crossing = at("-bead.x");
            for jump in ["-sign(bead.x)", "-sign(bead.x)*(2 - bead.x^2)"] {
                let t = at(jump);
                assert!(
                    (t - crossing).abs() <= tolerance,
                    "{label} {jump}: {t} vs {crossing}"
                );
            }
        }
        let mut sim = Simulation::new(
            Arc::clone(&scene.system),
            config(Method::Implicit, integrator, dt),
        )
        .unwrap();
        sim.set_stop_when(Some(Event::parse(&scene.system, "1/0 - bead.x").unwrap()))
            .unwrap();
        let failure = run(&mut sim, RunOptions::steps(10), &mut NullSink).unwrap_err();
        assert!(
            failure
                .error
                .to_string()
                .starts_with("stop_when `1/0 - bead.x` is infinite at t = 0 (with bead.x = 0.866"),
            "{}",
            failure.error
        );
    }
}
