//! Singular points of a curve: a run never crosses a point where the constraint's gradient
//! (or the parametric map's dx/dq) vanishes silently; it stops before, with an error naming
//! the constraint, the time and the place.
//!
//! Scenes (shipped in `scenes/`): `node.toml`, a bead sliding into the self-crossing of the
//! nodal cubic y^2 = x^2 (x + 1), and `cusp.toml`, a bead sliding into the cusp of
//! y^2 = x^3. Arrival times come from energy conservation along the parametrizations, by
//! quadrature, independently of the engine:
//!
//! - node: x = s^2 - 1, y = s (s^2 - 1), gravity g along +x, from rest at s0 = -1/2:
//!   s'^2 = 2 g (s^2 - s0^2) / (4 s^2 + (3 s^2 - 1)^2); the crossing is s = -1;
//! - cusp: x = s^2, y = s^3, gravity g along -x, from rest at s0 = 1:
//!   s'^2 = 2 g (1 - s^2) / (4 s^2 + 9 s^4); the tip is s = 0.

use std::path::Path;
use std::sync::Arc;

use bead::formulation::{Method, StepError, Subject};
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{run, RunError, RunOptions, Sample, Simulation, SimulationConfig, Sink};

const G: f64 = 9.81;

fn scene(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name);
    Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"))
}

/// Simpson's rule on [a, b] with n (even) intervals.
fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
    let h = (b - a) / n as f64;
    let inner: f64 = (1..n)
        .map(|i| f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 })
        .sum();
    h / 3.0 * (f(a) + f(b) + inner)
}

/// Time from rest at s0 = -1/2 to the crossing s = -1, with s = -1/2 - u^2 to remove the
/// inverse square root at the start: dt = 2 sqrt(M(s) / (2 g (1 + u^2))) du, M = 4 s^2 + (3 s^2 - 1)^2.
fn node_arrival() -> f64 {
    simpson(
        |u| {
            let s = -0.5 - u * u;
            let m = 4.0 * s * s + (3.0 * s * s - 1.0).powi(2);
            2.0 * (m / (2.0 * G * (1.0 + u * u))).sqrt()
        },
        0.0,
        0.5f64.sqrt(),
        2000,
    )
}

/// Time from rest at s = 1 to the tip s = 0, with s = sin(phi):
/// dt = sin(phi) sqrt(4 + 9 sin^2 phi) / sqrt(2 g) dphi.
fn cusp_arrival() -> f64 {
    simpson(
        |phi: f64| phi.sin() * (4.0 + 9.0 * phi.sin().powi(2)).sqrt() / (2.0 * G).sqrt(),
        0.0,
        std::f64::consts::FRAC_PI_2,
        2000,
    )
}

/// Every recorded particle position, with its time.
#[derive(Default)]
struct Positions(Vec<(f64, f64, f64)>);
impl Sink for Positions {
    fn record(&mut self, s: &Sample) -> std::io::Result<()> {
        self.0.push((s.t, s.x[0], s.x[1]));
        Ok(())
    }
}

fn run_scene(
    scene: &Scene,
    method: Method,
    integrator: IntegratorKind,
    dt: f64,
    duration: f64,
) -> (
    Result<bead::simulate::RunStats, bead::simulate::RunFailure>,
    Positions,
) {
    run_scene_with(scene, method, integrator, dt, duration, 64)
}

/// [`run_scene`] with at most `max_substeps` substeps per retried step (1: no retries).
fn run_scene_with(
    scene: &Scene,
    method: Method,
    integrator: IntegratorKind,
    dt: f64,
    duration: f64,
    max_substeps: u32,
) -> (
    Result<bead::simulate::RunStats, bead::simulate::RunFailure>,
    Positions,
) {
    let config = SimulationConfig {
        method,
        integrator,
        dt,
        max_substeps,
        ..Default::default()
    };
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    let mut positions = Positions::default();
    let steps = (duration / dt).round() as u64;
    let result = run(&mut sim, RunOptions::steps(steps), &mut positions);
    (result, positions)
}

/// The singular point error of a failed run, checked to name the constraint.
fn singular_point(
    result: &Result<bead::simulate::RunStats, bead::simulate::RunFailure>,
    what: &str,
) -> f64 {
    match result {
        Err(failure) => match &failure.error {
            RunError::Step(StepError::SingularPoint { t, subject, .. }) => {
                match subject {
                    Subject::Constraint { name, .. } => assert_eq!(name, what),
                    Subject::Coordinate { name } => assert_eq!(name, what),
                }
                let message = failure.error.to_string();
                assert!(message.contains("is singular"), "{message}");
                *t
            }
            other => panic!("{what}: expected a singular point, got {other}"),
        },
        Ok(stats) => panic!("{what}: the run went through, to t = {}", stats.t_final),
    }
}

/// Law: the implicit form cannot pass a self-crossing (its constraint force is undefined
/// there, and a drifted state follows the level set onto another branch). For every
/// integrator and step size the run stops before the crossing, never later than the true
/// arrival time, and every recorded state is still on the branch it came along (the loop's
/// upper half, x < 0 < y).
#[test]
fn implicit_runs_stop_before_the_self_crossing_for_every_integrator() {
    let node = scene("node.toml");
    let arrival = node_arrival();
    assert!((arrival - 0.4308).abs() < 1e-3, "{arrival}");
    for integrator in IntegratorKind::ALL {
        for dt in [1e-2, 1e-3, 1e-4] {
            let (result, positions) = run_scene(&node, Method::Implicit, integrator, dt, 1.0);
            let t = singular_point(&result, "nodal cubic");
            assert!(
                t <= arrival + 1e-9,
                "{integrator:?} dt = {dt}: stopped at {t}, after the arrival {arrival}"
            );
            for &(t, x, y) in &positions.0 {
                assert!(
                    x < 0.0 && y > 0.0,
                    "{integrator:?} dt = {dt}: recorded ({x}, {y}) at t = {t}, off the branch"
                );
            }
        }
    }
}

/// Law: the same through the parametric form x = s^2 - 1, y = s (s^2 - 1), which is smooth
/// there: the bead goes straight through the crossing onto the lower right branch
/// (x > 0 > y), arriving at the time energy conservation gives.
#[test]
fn the_parametric_form_goes_straight_through_the_crossing() {
    let node = scene("node.toml");
    let arrival = node_arrival();
    let (result, positions) = run_scene(&node, Method::Parametric, IntegratorKind::Rk4, 1e-4, 1.0);
    result.unwrap();
    let crossing = positions
        .0
        .windows(2)
        .find(|w| w[0].1 < 0.0 && w[1].1 >= 0.0)
        .expect("the bead crosses x = 0");
    // Straight through: from the upper left to the lower right quadrant.
    assert!(crossing[0].2 > 0.0 && crossing[1].2 < 0.0, "{crossing:?}");
    // x crosses 0 at the crossing time (linear interpolation within a step of 1e-4 s).
    let (t0, x0, _) = crossing[0];
    let (t1, x1, _) = crossing[1];
    let t_cross = t0 + (t1 - t0) * (-x0) / (x1 - x0);
    assert!((t_cross - arrival).abs() < 1e-6, "{t_cross} vs {arrival}");
    let (_, x, y) = *positions.0.last().unwrap();
    assert!(x > 1.0 && y < -1.0, "({x}, {y})");
}

/// Law: at a cusp both forms are singular (the gradient of y^2 - x^3 and the column
/// dx/ds = (2s, 3s^2) vanish at the tip). For every integrator and step size each run stops
/// before the tip (when the run is accurate enough to time it, before the arrival time), and
/// no run records a state off the upper branch (x >= 0 and y >= 0: states with x < 0 are not
/// on the curve at all, and y < 0 is the other branch).
#[test]
fn runs_stop_before_the_cusp_for_every_integrator_and_both_forms() {
    let cusp = scene("cusp.toml");
    let arrival = cusp_arrival();
    assert!((arrival - 0.7065).abs() < 1e-3, "{arrival}");
    for method in [Method::Implicit, Method::Parametric] {
        for integrator in IntegratorKind::ALL {
            if method == Method::Parametric && integrator.needs_constraints() {
                continue;
            }
            for dt in [1e-2, 1e-3, 1e-4] {
                let (result, positions) = run_scene(&cusp, method, integrator, dt, 1.0);
                let what = match method {
                    Method::Implicit => "cusp",
                    Method::Parametric => "s",
                };
                let t = singular_point(&result, what);
                // A run accurate enough to time the arrival stops before it (Euler's timing
                // error at a coarse step is larger than the last step).
                let accurate = result
                    .as_ref()
                    .map_err(|f| f.stats.energy_rel_error_max < 1e-3)
                    .unwrap_err();
                assert!(
                    !accurate || t <= arrival + 1e-9,
                    "{method:?} {integrator:?} dt = {dt}: stopped at {t}, after {arrival}"
                );
                for &(t, x, y) in &positions.0 {
                    assert!(
                        x >= 0.0 && y >= 0.0,
                        "{method:?} {integrator:?} dt = {dt}: recorded ({x}, {y}) at t = {t}"
                    );
                }
            }
        }
    }
}

/// Law: when an implicit iteration fails next to a singular point (here Gauss-Legendre's
/// stages on the cusp's parametrization at a coarse step, retries off), the error names the
/// singular point, not "reduce dt", and keeps the iteration's failure as its cause. With
/// retries the shorter substeps carry the run closer, and the monitor stops it there, before
/// the cusp.
#[test]
fn an_iteration_that_fails_next_to_a_singular_point_names_it() {
    let cusp = scene("cusp.toml");
    let (result, _) = run_scene_with(
        &cusp,
        Method::Parametric,
        IntegratorKind::GaussLegendre,
        0.05,
        1.0,
        1,
    );
    let stopped_without_retries = singular_point(&result, "s");
    match &result.unwrap_err().error {
        RunError::Step(StepError::SingularPoint {
            cause: Some(cause), ..
        }) => {
            assert!(cause.contains("gauss-legendre"), "{cause}");
        }
        other => panic!("expected a singular point with its cause, got {other}"),
    }
    let (result, _) = run_scene(
        &cusp,
        Method::Parametric,
        IntegratorKind::GaussLegendre,
        0.05,
        1.0,
    );
    let stopped_with_retries = singular_point(&result, "s");
    assert!(stopped_with_retries >= stopped_without_retries);
}

/// Regular curves stop nothing, whatever the step: the parabola (whose gradient (2x, 100)
/// never vanishes, though its x part does at the vertex and an unstable Euler run makes it
/// reverse), the circle, the helix, the double pendulum: every shipped regular scene runs
/// with every integrator at a coarse and a fine step without a singular-point error.
#[test]
fn regular_curves_never_stop_for_a_singular_point() {
    for name in [
        "parabola.toml",
        "circle.toml",
        "helix.toml",
        "double-pendulum.toml",
    ] {
        let s = scene(name);
        let dt0 = s.run.dt.unwrap();
        for integrator in IntegratorKind::ALL {
            for dt in [dt0, 10.0 * dt0] {
                let (result, _) = run_scene(&s, Method::Implicit, integrator, dt, 200.0 * dt);
                if let Err(failure) = &result {
                    assert!(
                        !matches!(
                            failure.error,
                            RunError::Step(StepError::SingularPoint { .. })
                        ),
                        "{name} {integrator:?} dt = {dt}: {}",
                        failure.error
                    );
                }
            }
        }
    }
}

/// A thin ellipse (x / 1)^2 + (y / 0.05)^2 = 1 has tips with a radius of curvature of
/// 0.0025 and a gradient 20 times shorter there than at the flanks, but no singular point (the
/// gradient vanishes only at the centre, which is not on the curve): laps around it stop
/// nothing.
#[test]
fn the_tips_of_a_thin_ellipse_are_not_singular() {
    let mut b = bead::model::SystemBuilder::new(&[0.0, 0.0]);
    b.particle("bead", 1.0, &[0.0, 0.05], &[1.0, 0.0]).unwrap();
    b.constraint_expr("bead.x^2 + (bead.y/0.05)^2 - 1").unwrap();
    let system = Arc::new(b.build().unwrap());
    // One lap is about 4 length units at speed 1.
    for (integrator, dt) in [
        (IntegratorKind::Rk4, 1e-4),
        (IntegratorKind::Rattle, 1e-4),
        (IntegratorKind::GaussLegendre, 2e-4),
        (IntegratorKind::Dopri5, 1e-2),
    ] {
        let config = SimulationConfig {
            method: Method::Implicit,
            integrator,
            dt,
            ..Default::default()
        };
        let mut sim = Simulation::new(Arc::clone(&system), config).unwrap();
        let steps = (10.0 / dt) as u64;
        let stats = run(
            &mut sim,
            RunOptions {
                every: 100,
                ..RunOptions::steps(steps)
            },
            &mut bead::simulate::NullSink,
        )
        .unwrap_or_else(|e| panic!("{integrator:?}: {e}"));
        assert!(
            stats.energy_rel_error_max < 1e-3,
            "{integrator:?}: {}",
            stats.energy_rel_error_max
        );
    }
}
