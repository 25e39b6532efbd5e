//! The convergence study (`bead::convergence`, `bead order`): the orders it observes are the
//! methods' (measured independently in `physics_orders.rs` against hand-written references),
//! its work counts are the methods' evaluations per step derived by hand, and its floors keep
//! the reference's own error out of the orders.

use std::path::Path;
use std::sync::Arc;

use bead::convergence::{
    observed_orders, study, Floors, Level, LevelFailure, Series, Study, StudySettings,
};
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
        assert!(s.failures.is_empty(), "{:?}", s.failures);
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

/// Law: a step size whose run fails does not end its series: explicit Euler on the article's
/// parabola fails at dt = 0.2 (implicit form: a step too long for the curve's turn;
/// parametric: the energy blows up, as `bead order --dt 0.2` shows), and the study still runs
/// dt = 0.1, 0.05 and 0.025, whose errors shrink with dt and give orders per halving. Before,
/// the failure at 0.2 dropped the finer steps and the series reported nothing.
#[test]
fn a_failed_coarse_step_leaves_the_finer_steps_measured() {
    let settings = StudySettings {
        dt: 0.2,
        halvings: 3,
        steps: 50,
        reference_rtol: 1e-12,
    };
    let cases = [
        (Method::Implicit, IntegratorKind::Euler),
        (Method::Parametric, IntegratorKind::Euler),
    ];
    let study = study(&parabola(), &cases, &settings, &SimulationConfig::default()).unwrap();
    for s in &study.series {
        let what = format!("{} {}", s.method.name(), s.integrator.name());
        assert_eq!(s.failures.len(), 1, "{what}: {:?}", s.failures);
        assert_eq!(s.failures[0].dt, 0.2, "{what}");
        assert!(
            s.failures[0].error.contains("reduce dt"),
            "{what}: {}",
            s.failures[0].error
        );
        let dts: Vec<f64> = s.levels.iter().map(|l| l.dt).collect();
        assert_eq!(dts, [0.1, 0.05, 0.025], "{what}");
        let orders = s.position_orders(&study.floors);
        assert_eq!(orders.len(), 2, "{what}");
        assert!(orders.iter().all(Option::is_some), "{what}: {orders:?}");
    }
}

/// Law: an order is a ratio of one halving: across a failed step size (dt then dt/4) none is
/// reported, though both errors lie above the floor.
#[test]
fn no_order_is_reported_across_a_failed_step() {
    let level = |dt: f64, error: f64| Level {
        dt,
        steps: 0,
        evaluations: 0,
        wall_seconds: 0.0,
        position_error: error,
        energy_error: error,
        constraint_error: None,
    };
    let series = Series {
        method: Method::Implicit,
        integrator: IntegratorKind::Rk4,
        levels: vec![
            level(0.1, 1.6e-3),
            level(0.025, 1e-4),
            level(0.0125, 6.25e-6),
        ],
        failures: vec![LevelFailure {
            dt: 0.05,
            error: "diverged".into(),
        }],
    };
    let floors = Floors {
        position: 1e-9,
        energy: 1e-9,
        constraint: 1e-9,
    };
    let orders = series.position_orders(&floors);
    assert_eq!(orders[0], None);
    assert!((orders[1].unwrap() - 4.0).abs() < 1e-12, "{orders:?}");
    assert_eq!(series.energy_orders(&floors), orders);
}
