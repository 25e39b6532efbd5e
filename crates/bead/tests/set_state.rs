//! `Simulation::set_state` and `Scene::with_state`: a state asked for from outside is put on
//! the constraints (the closest point, the tangent velocity), the same for both forms,
//! checked against the geometry computed here; bad requests change nothing.

use std::sync::Arc;

use bead::formulation::Method;
use bead::scene::Scene;
use bead::simulate::{SetStateError, Simulation, SimulationConfig, StateRequest};

fn scene(name: &str) -> Scene {
    let path = format!("{}/../../scenes/{name}", env!("CARGO_MANIFEST_DIR"));
    Scene::parse(&std::fs::read_to_string(path).unwrap(), name, &[]).unwrap()
}

fn simulation(scene: &Scene, method: Method) -> Simulation {
    let config = SimulationConfig {
        method,
        dt: 1e-3,
        ..SimulationConfig::default()
    };
    Simulation::new(Arc::clone(&scene.system), config).unwrap()
}

/// The point of the parabola y = -x^2/100 closest to (a, b), by Newton's method on
/// d/dx [(x - a)^2 + (-x^2/100 - b)^2] / 2 = (x - a) + (x^2/100 + b) x / 50 = 0.
fn closest_on_parabola(a: f64, b: f64) -> [f64; 2] {
    let mut x = a;
    for _ in 0..100 {
        let f = (x - a) + (x * x / 100.0 + b) * x / 50.0;
        let df = 1.0 + (3.0 * x * x / 100.0 + b) / 50.0;
        x -= f / df;
    }
    [x, -x * x / 100.0]
}

/// The velocity `v` projected onto the parabola's tangent at x (unit mass).
fn tangent_part(x: f64, v: [f64; 2]) -> [f64; 2] {
    let tangent = [1.0, -x / 50.0];
    let length2 = tangent[0] * tangent[0] + tangent[1] * tangent[1];
    let along = (v[0] * tangent[0] + v[1] * tangent[1]) / length2;
    [along * tangent[0], along * tangent[1]]
}

fn close(a: &[f64], b: &[f64], tolerance: f64) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(a, b)| (a - b).abs() <= tolerance)
}

#[test]
fn positions_off_the_curve_land_on_the_closest_point_with_the_tangent_velocity_in_both_forms() {
    let scene = scene("parabola.toml");
    let asked = [100.0, -90.0];
    let velocity = [10.0, 5.0];
    let point = closest_on_parabola(asked[0], asked[1]);
    let expected_v = tangent_part(point[0], velocity);
    let distance = ((point[0] - asked[0]).powi(2) + (point[1] - asked[1]).powi(2)).sqrt();
    for method in [Method::Implicit, Method::Parametric] {
        let mut sim = simulation(&scene, method);
        sim.advance_to(0.3).unwrap();
        let placed = sim
            .set_state(&StateRequest {
                positions: Some(asked.to_vec()),
                velocities: Some(velocity.to_vec()),
                ..Default::default()
            })
            .unwrap();
        assert!(
            close(sim.positions(), &point, 1e-9),
            "{method:?}: {:?}",
            sim.positions()
        );
        assert!(
            close(sim.velocities(), &expected_v, 1e-9),
            "{method:?}: {:?}",
            sim.velocities()
        );
        assert!(
            (placed.position_moved - distance).abs() < 1e-9,
            "{}",
            placed.position_moved
        );
        assert_eq!(sim.t(), 0.3, "t stays when not asked for");
        assert_eq!(sim.steps(), 0);
        assert_eq!(sim.energy_error(), 0.0, "the energy reference restarts");
        if method == Method::Parametric {
            let (q, qdot) = placed.parametric.clone().unwrap();
            assert_eq!(sim.q(), q.as_slice());
            assert_eq!(sim.qdot(), qdot.as_slice());
            assert!((q[0] - point[0]).abs() < 1e-9);
        }
    }
}

#[test]
fn both_forms_started_from_one_state_follow_one_motion() {
    let scene = scene("parabola.toml");
    let request = StateRequest {
        t: Some(1.0),
        positions: Some(vec![-80.0, -64.0]),
        velocities: Some(vec![30.0, 0.0]),
        ..Default::default()
    };
    let mut finals = Vec::new();
    for method in [Method::Implicit, Method::Parametric] {
        let mut sim = simulation(&scene, method);
        sim.set_state(&request).unwrap();
        assert_eq!(sim.t(), 1.0);
        sim.advance_to(2.0).unwrap();
        finals.push(sim.positions().to_vec());
    }
    // rk4 at dt = 1e-3 over 1 s: both within 1e-6 px of the motion, so of each other.
    assert!(close(&finals[0], &finals[1], 1e-6), "{finals:?}");
}

#[test]
fn coordinates_set_the_parametric_form_and_positions_the_implicit_one() {
    let scene = scene("parabola.toml");
    let mut parametric = simulation(&scene, Method::Parametric);
    parametric
        .set_state(&StateRequest {
            q: Some(vec![50.0]),
            qdot: Some(vec![3.0]),
            ..Default::default()
        })
        .unwrap();
    assert_eq!(parametric.q(), &[50.0]);
    assert_eq!(parametric.qdot(), &[3.0]);
    assert!(close(parametric.positions(), &[50.0, -25.0], 1e-12));
    assert!(close(parametric.velocities(), &[3.0, -3.0], 1e-12));
    // The implicit form's q are the positions. rk4 leaves the curve by a little (the
    // article's observation): set again, the state comes back onto it by about as much,
    // and a state on it read back sets the same state, bit for bit.
    let mut implicit = simulation(&scene, Method::Implicit);
    implicit.advance_to(0.7).unwrap();
    let read = |sim: &Simulation| StateRequest {
        t: Some(sim.t()),
        q: Some(sim.q().to_vec()),
        qdot: Some(sim.qdot().to_vec()),
        ..Default::default()
    };
    let drifted = read(&implicit);
    let [x, y] = [implicit.q()[0], implicit.q()[1]];
    let off = (x * x + 100.0 * y).abs() / (4.0 * x * x + 1e4).sqrt();
    let mut again = simulation(&scene, Method::Implicit);
    let placed = again.set_state(&drifted).unwrap();
    assert!(
        off > 0.0 && placed.position_moved < 2.0 * off,
        "{off} {placed:?}"
    );
    let on = read(&again);
    let placed = again.set_state(&on).unwrap();
    assert_eq!(read(&again), on);
    assert_eq!(placed.position_moved, 0.0);
}

#[test]
fn positions_alone_keep_the_particle_velocities_and_place_them_again() {
    let scene = scene("parabola.toml");
    for method in [Method::Implicit, Method::Parametric] {
        let mut sim = simulation(&scene, method);
        sim.advance_to(0.5).unwrap();
        let before = sim.velocities().to_vec();
        sim.set_state(&StateRequest {
            positions: Some(vec![0.0, 0.0]),
            ..Default::default()
        })
        .unwrap();
        let expected = tangent_part(0.0, [before[0], before[1]]);
        assert!(close(sim.velocities(), &expected, 1e-9), "{method:?}");
    }
}

#[test]
fn bad_requests_say_what_and_change_nothing() {
    let scene = scene("parabola.toml");
    let mut sim = simulation(&scene, Method::Parametric);
    sim.advance_to(0.2).unwrap();
    let (t, q, qdot, steps) = (sim.t(), sim.q().to_vec(), sim.qdot().to_vec(), sim.steps());
    let cases = [
        (
            StateRequest {
                positions: Some(vec![1.0]),
                ..Default::default()
            },
            "positions need 2 numbers, got 1",
        ),
        (
            StateRequest {
                velocities: Some(vec![1.0, f64::NAN]),
                ..Default::default()
            },
            "velocities must be finite numbers (velocities[1] is NaN)",
        ),
        (
            StateRequest {
                positions: Some(vec![1.0, 2.0]),
                q: Some(vec![1.0]),
                ..Default::default()
            },
            "either positions or q",
        ),
        (
            StateRequest {
                t: Some(f64::INFINITY),
                ..Default::default()
            },
            "t must be finite",
        ),
    ];
    for (request, words) in cases {
        let error = sim.set_state(&request).unwrap_err();
        assert!(error.to_string().contains(words), "{error}");
        assert_eq!(
            (sim.t(), sim.q(), sim.qdot(), sim.steps()),
            (t, &q[..], &qdot[..], steps)
        );
    }
    // A start the simulation cannot take (the implicit circle's centre, where the gradient
    // vanishes) is refused with the reason.
    let circle = self::scene("circle.toml");
    let mut sim = simulation(&circle, Method::Implicit);
    let error = sim
        .set_state(&StateRequest {
            q: Some(vec![0.0, 0.0]),
            ..Default::default()
        })
        .unwrap_err();
    assert!(matches!(error, SetStateError::Placement(_)), "{error}");
    assert_eq!(sim.t(), 0.0);
    // q on a scene without a parametric form.
    let free = Scene::parse(
        "[world]\ngravity = [0.0, 9.81]\n[[particle]]\nname = \"a\"\nmass = 1.0\nposition = [0.0, 0.0]\n",
        "free.toml",
        &[],
    )
    .unwrap();
    let error = free
        .with_state(&StateRequest {
            q: Some(vec![1.0]),
            ..Default::default()
        })
        .unwrap_err();
    assert_eq!(error, SetStateError::NoParametricForm);
}

#[test]
fn a_scene_started_elsewhere_starts_both_forms_there_and_keeps_it_through_parameters() {
    let scene = scene("circle.toml");
    let request = StateRequest {
        positions: Some(vec![0.0, 2.0]),
        velocities: Some(vec![1.5, 0.0]),
        ..Default::default()
    };
    let (moved, placed) = scene.with_state(&request).unwrap();
    // The closest point of the unit circle to (0, 2) is (0, 1).
    assert!(close(&placed.positions, &[0.0, 1.0], 1e-12), "{placed:?}");
    assert!((placed.position_moved - 1.0).abs() < 1e-12);
    let (q, qdot) = placed.parametric.clone().unwrap();
    assert!(
        q[0].abs() < 1e-12 && (qdot[0] - 1.5).abs() < 1e-12,
        "{q:?} {qdot:?}"
    );
    let implicit = simulation(&moved, Method::Implicit);
    let parametric = simulation(&moved, Method::Parametric);
    assert!(close(implicit.positions(), parametric.positions(), 1e-12));
    assert!(close(implicit.velocities(), parametric.velocities(), 1e-12));
    assert!(moved.warnings().is_empty(), "{:?}", moved.warnings());
    // The same start as a simulation's set_state at t = 0, bit for bit.
    let mut set = simulation(&scene, Method::Implicit);
    set.set_state(&request).unwrap();
    assert_eq!(set.positions(), implicit.positions());
    assert_eq!(set.velocities(), implicit.velocities());
    // Through a parameter change: placed again on the circle of the new radius.
    let longer = moved.with_params(&[("L".to_string(), 2.0)]).unwrap();
    let (x, v) = longer.system.initial_particle_state();
    assert!(close(&x, &[0.0, 2.0], 1e-12), "{x:?}");
    assert!(close(&v, &[1.5, 0.0], 1e-12), "{v:?}");
    assert_eq!(longer.start(), Some(&request));
    // A scene starts at t = 0.
    let error = scene
        .with_state(&StateRequest {
            t: Some(1.0),
            ..Default::default()
        })
        .unwrap_err();
    assert!(error.to_string().contains("starts at t = 0"), "{error}");
}
