//! The convergence study (`bead::convergence`, `bead order`): the orders it observes are the
//! methods' (measured independently in `physics_orders.rs` against hand-written references),
//! its work counts are the methods' evaluations per step derived by hand, and its floors keep
//! the reference's own error out of the orders.

use std::path::Path;
use std::sync::Arc;

use bead::convergence::{observed_orders, study, Series, Study, StudySettings};
use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::System;
use bead::scene::Scene;
use bead::simulate::SimulationConfig;

fn parabola() -> Arc<System> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    Scene::load(&path, &[]).unwrap().system
}

/// The article's scene, 10 s at dt = 1/60 halved four times.
fn parabola_study(cases: &[(Method, IntegratorKind)]) -> Study {
    let settings = StudySettings {
        dt: 1.0 / 60.0,
        halvings: 4,
        steps: 600,
        reference_rtol: 1e-13,
    };
    study(&parabola(), cases, &settings, &SimulationConfig::default()).unwrap()
}

fn last(orders: &[Option<f64>]) -> f64 {
    orders
        .iter()
        .rev()
        .find_map(|o| *o)
        .expect("a measured order")
}

fn series(study: &Study, method: Method, integrator: IntegratorKind) -> &Series {
    study
        .series
        .iter()
        .find(|s| s.method == method && s.integrator == integrator)
        .unwrap()
}

/// Law: on the article's parabola the study observes each method's order at the last
/// halving it can measure: rk4 4 (implicit form), rattle 2, rattle4 4, gauss-legendre 4 (in
/// q: the parametric form), in position and energy error; every halving it reports is
/// within 0.2 of the declared order but the first (pre-asymptotic) ones.
#[test]
fn the_study_observes_the_declared_orders_on_the_parabola() {
    let cases = [
        (Method::Implicit, IntegratorKind::Rk4),
        (Method::Implicit, IntegratorKind::Rattle),
        (Method::Implicit, IntegratorKind::Rattle4),
        (Method::Parametric, IntegratorKind::GaussLegendre),
    ];
    let study = parabola_study(&cases);
    assert_eq!(study.reference_method, Method::Parametric);
    for (method, integrator) in cases {
        let s = series(&study, method, integrator);
        assert!(s.failure.is_none(), "{:?}", s.failure);
        assert_eq!(s.levels.len(), 5);
        let declared = integrator.order() as f64;
        let position = s.position_orders(&study.floors);
        let energy = s.energy_orders(&study.floors);
        println!(
            "{} {}: position {position:.3?}, energy {energy:.3?}",
            method.name(),
            integrator.name()
        );
        for orders in [&position, &energy] {
            assert!(
                (last(orders) - declared).abs() < 0.1,
                "{} {}: {orders:?}",
                method.name(),
                integrator.name()
            );
            for order in orders.iter().skip(1).flatten() {
                assert!((order - declared).abs() < 0.2, "{orders:?}");
            }
        }
    }
    // RATTLE holds the constraints at its tolerance: no order off them, the errors at the
    // floor; rk4 leaves the curve at its order.
    let rattle = series(&study, Method::Implicit, IntegratorKind::Rattle);
    assert!(rattle
        .constraint_orders(&study.floors)
        .iter()
        .all(Option::is_none));
    let rk4 = series(&study, Method::Implicit, IntegratorKind::Rk4);
    assert!((last(&rk4.constraint_orders(&study.floors)) - 4.0).abs() < 0.1);
    // Parametric runs have no distance off the constraints.
    let gl = series(&study, Method::Parametric, IntegratorKind::GaussLegendre);
    assert!(gl.levels.iter().all(|l| l.constraint_error.is_none()));
}

/// Law: the work counted is the evaluations of the acceleration each method makes, derived
/// by hand: rk4 four per step, RATTLE two (the kicks at the step's start and end: the forces
/// ignore the velocity), rattle4 five RATTLE steps; plus the monitors' one at the start. The
/// times of each level are those of dt / 2^k.
#[test]
fn the_work_is_the_evaluations_each_method_makes() {
    let study = parabola_study(&[
        (Method::Implicit, IntegratorKind::Rk4),
        (Method::Implicit, IntegratorKind::Rattle),
        (Method::Implicit, IntegratorKind::Rattle4),
    ]);
    for (integrator, per_step) in [
        (IntegratorKind::Rk4, 4),
        (IntegratorKind::Rattle, 2),
        (IntegratorKind::Rattle4, 10),
    ] {
        for (k, level) in series(&study, Method::Implicit, integrator)
            .levels
            .iter()
            .enumerate()
        {
            let steps = 600u64 << k;
            assert_eq!(level.steps, steps);
            assert_eq!(level.dt, 1.0 / 60.0 / (1u64 << k) as f64);
            assert_eq!(
                level.evaluations,
                per_step * steps + 1,
                "{} at level {k}",
                integrator.name()
            );
        }
    }
}

/// Law: an order is reported only where both errors lie above the floor; a ratio of 16 is
/// order 4.
#[test]
fn orders_are_reported_above_the_floor_only() {
    let orders = observed_orders(&[1.6e-3, 1e-4, 1e-9, 5e-10, f64::NAN], 1e-9);
    assert_eq!(orders[0], Some(4.0));
    assert_eq!(orders[1], None);
    assert_eq!(orders[2], None);
    assert_eq!(orders[3], None);
}

/// Law: the floor on the position error is at least 100 rtol L, and the reference's own
/// error (its distance from a reference at 10 rtol) lies under it: the finest
/// gauss-legendre run is closer to the reference than that, so its halving reports no order
/// rather than one made of the reference's error.
#[test]
fn the_position_floor_covers_the_references_error() {
    let study = parabola_study(&[(Method::Parametric, IntegratorKind::GaussLegendre)]);
    assert!(study.floors.position >= 100.0 * 1e-13 * study.length_scale);
    // The finest run's error is below the floor (the reference cannot resolve it), so its
    // halving reports none.
    let gl = series(&study, Method::Parametric, IntegratorKind::GaussLegendre);
    let finest = gl.levels.last().unwrap().position_error;
    println!(
        "floor {:.3e}, finest error {finest:.3e}",
        study.floors.position
    );
    assert!(finest < study.floors.position);
    assert_eq!(*gl.position_orders(&study.floors).last().unwrap(), None);
}

/// Law: an adaptive integrator or nonsense settings are refused with a message, not run.
#[test]
fn adaptive_integrators_and_bad_settings_are_refused() {
    let system = parabola();
    let settings = StudySettings {
        dt: 0.01,
        halvings: 2,
        steps: 10,
        reference_rtol: 1e-12,
    };
    let error = study(
        &system,
        &[(Method::Implicit, IntegratorKind::Dopri5)],
        &settings,
        &SimulationConfig::default(),
    )
    .unwrap_err();
    assert!(
        error.to_string().contains("chooses its own steps"),
        "{error}"
    );
    let bad = StudySettings {
        dt: -1.0,
        ..settings
    };
    let error = study(
        &system,
        &[(Method::Implicit, IntegratorKind::Rk4)],
        &bad,
        &SimulationConfig::default(),
    )
    .unwrap_err();
    assert!(error.to_string().contains("dt > 0"), "{error}");
}
