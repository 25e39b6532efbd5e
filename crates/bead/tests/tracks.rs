//! The teaching tracks (issue 18, item 9): each scene does what its `about` says, checked
//! against energy alone (a frictionless wire does no work), not against bead's own numbers:
//! the hump is crossed exactly when v0^2 / 2 > g h; the loop is gone round exactly when
//! v0^2 > 4 g b; the infinity track is crossed at the starting speed every lap and slower
//! every lap with damping; the spiral's two forms agree and its constraint force grows as
//! the about says. Every scene also runs past its duration.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{Simulation, SimulationConfig};

fn scene(name: &str, params: &[(&str, f64)]) -> Scene {
    let path = format!("{}/../../scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    let overrides: Vec<(String, f64)> = params.iter().map(|(n, v)| (n.to_string(), *v)).collect();
    Scene::load(path.as_ref(), &overrides).unwrap_or_else(|e| panic!("{e}"))
}

/// Step `scene` in `method` with rk4 at its dt for `seconds`, calling `observe(t, x, v)`
/// on the start and after every step.
fn run(
    scene: &Scene,
    method: Method,
    seconds: f64,
    mut observe: impl FnMut(f64, &[f64], &[f64]),
) -> Simulation {
    let dt = scene.run.dt.unwrap();
    let config = SimulationConfig {
        method,
        integrator: IntegratorKind::Rk4,
        dt,
        ..SimulationConfig::default()
    };
    let mut simulation = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    observe(0.0, simulation.positions(), simulation.velocities());
    for _ in 0..(seconds / dt).round() as usize {
        simulation.step().unwrap();
        observe(
            simulation.t(),
            simulation.positions(),
            simulation.velocities(),
        );
    }
    simulation
}

#[test]
fn the_hump_is_crossed_exactly_when_the_energy_suffices() {
    // Threshold sqrt(2 g h) = 4.4294 m/s (the start is h e^-9 = 1.2e-4 m up: 2.7e-4 m/s).
    for method in [Method::Implicit, Method::Parametric] {
        for (v0, crosses) in [(4.2, false), (4.40, false), (4.46, true), (4.5, true)] {
            let s = scene("hump", &[("v0", v0)]);
            let (mut max_y, mut last_x) = (f64::NEG_INFINITY, 0.0);
            run(&s, method, 8.0, |_, x, _| {
                max_y = max_y.max(x[1]);
                last_x = x[0];
            });
            assert_eq!(
                last_x > 2.0,
                crosses,
                "{method:?} v0 = {v0}: ends at x = {last_x}"
            );
            if !crosses {
                // It turns back where v0^2/2 = g (y - y0).
                let expected = (-9.0f64).exp() + v0 * v0 / (2.0 * 9.81);
                assert!(
                    (max_y - expected).abs() < 1e-4,
                    "{method:?} v0 = {v0}: top {max_y} vs {expected}"
                );
                assert!(last_x < -2.0, "{method:?} v0 = {v0}: slid back to {last_x}");
            }
        }
    }
    // Damping: E falls, E - W stays (the ledger counts the drag's work).
    let s = scene("hump", &[("v0", 4.5), ("c", 0.3)]);
    let simulation = run(&s, Method::Implicit, 6.0, |_, _, _| {});
    assert!(simulation.energy() < 0.7 * simulation.energy_initial());
    assert!(
        simulation.energy_balance_error() < 1e-6,
        "{}",
        simulation.energy_balance_error()
    );
}

#[test]
fn the_loop_is_gone_round_exactly_when_v0_squared_exceeds_4_g_b() {
    // Threshold sqrt(4 g b) = 7.6720 m/s for b = 1.5. Round: s passes the loop's top at
    // 2 pi and reaches the next valley at 3 pi. Short: s turns back below 2 pi.
    for (v0, round) in [(7.5, false), (7.64, false), (7.71, true), (8.5, true)] {
        let s = scene("loop", &[("v0", v0)]);
        let (mut max_q, mut last_q) = (f64::NEG_INFINITY, 0.0);
        let config = SimulationConfig {
            method: Method::Parametric,
            integrator: IntegratorKind::Rk4,
            dt: s.run.dt.unwrap(),
            ..SimulationConfig::default()
        };
        let mut sim = Simulation::new(Arc::clone(&s.system), config).unwrap();
        for _ in 0..4000 {
            sim.step().unwrap();
            max_q = max_q.max(sim.q()[0]);
            last_q = sim.q()[0];
        }
        let pi = std::f64::consts::PI;
        assert_eq!(max_q > 3.0 * pi, round, "v0 = {v0}: s up to {max_q}");
        if !round {
            assert!(
                max_q < 2.0 * pi && last_q < max_q - 1.0,
                "v0 = {v0}: falls back from {max_q} to {last_q}"
            );
        }
        assert!(
            sim.energy_error() < 1e-7,
            "v0 = {v0}: {}",
            sim.energy_error()
        );
    }
}

#[test]
fn the_infinity_track_is_crossed_at_the_starting_speed_every_lap() {
    for (c, slowing) in [(0.0, false), (0.05, true)] {
        let s = scene("infinity", &[("c", c)]);
        let mut speeds = Vec::new();
        let mut previous: Option<(f64, f64)> = None;
        // Crossings of the center: x changes sign with y near 0; the speed there is
        // interpolated linearly between the two samples.
        run(&s, Method::Parametric, 30.0, |_, x, v| {
            let speed = v[0].hypot(v[1]);
            if let Some((x0, s0)) = previous {
                if (x0 < 0.0) != (x[0] < 0.0) && x[1].abs() < 0.05 {
                    let f = x0 / (x0 - x[0]);
                    speeds.push(s0 + f * (speed - s0));
                }
            }
            previous = Some((x[0], speed));
        });
        assert!(speeds.len() >= 4, "c = {c}: {} crossings", speeds.len());
        for pair in speeds.windows(2) {
            if slowing {
                assert!(pair[1] < pair[0], "c = {c}: {speeds:?}");
            } else {
                assert!((pair[1] - 6.0).abs() < 1e-3, "c = {c}: {speeds:?}");
            }
        }
    }
}

#[test]
fn the_spiral_forms_agree_and_its_constraint_force_grows() {
    let s = scene("spiral", &[]);
    let mut implicit = run(&s, Method::Implicit, 5.0, |_, _, _| {});
    let parametric = run(&s, Method::Parametric, 5.0, |_, _, _| {});
    let d: f64 = implicit
        .positions()
        .iter()
        .zip(parametric.positions())
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt();
    assert!(d < 1e-6, "forms {d} m apart at 5 s");
    // The about: the force holding the bead grows from about 10 N (mostly its weight) to
    // about 30 N (m v^2 / r toward the axis) in five seconds.
    let end = implicit.constraint_forces().unwrap().force;
    let mut start = Simulation::new(
        Arc::clone(&s.system),
        SimulationConfig {
            dt: 0.001,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let begin = start.constraint_forces().unwrap().force;
    let norm = |f: &[f64]| f.iter().map(|c| c * c).sum::<f64>().sqrt();
    let (f0, f5) = (norm(&begin), norm(&end));
    assert!((9.0..11.0).contains(&f0), "start {f0} N");
    assert!((25.0..40.0).contains(&f5), "at 5 s {f5} N");
    // Far past its duration (the apex at 6.8 s, the mirror spiral after) it still runs.
    run(&s, Method::Implicit, 12.0, |_, _, _| {});
}
