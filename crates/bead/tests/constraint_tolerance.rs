//! The position tolerance of RATTLE and `--project` is per constraint row: each row to 1e-12
//! of its own scale (a rod's length), plus what rounding allows at its coordinates
//! (`ConstraintScales`). A scene-wide tolerance would let a short rod in a large scene stretch
//! by orders of magnitude more than its long neighbours, and would ask for the impossible of
//! a rod far from the origin.

use std::sync::Arc;

use bead::formulation::{ConstraintScales, Method};
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, System, SystemBuilder};
use bead::simulate::{Simulation, SimulationConfig};

const G: f64 = 9.81;

/// A double pendulum hanging from `anchor`: a rod of length `long`, then one of `short`,
/// both horizontal at rest to the right of the anchor.
fn double_pendulum(anchor: [f64; 2], long: f64, short: f64) -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let a = b
        .particle("a", 1.0, &[anchor[0] + long, anchor[1]], &[0.0, 0.0])
        .unwrap();
    let c = b
        .particle(
            "c",
            0.5,
            &[anchor[0] + long + short, anchor[1]],
            &[0.0, 0.0],
        )
        .unwrap();
    b.distance("long rod", a, Endpoint::Fixed(anchor.to_vec()), long)
        .unwrap();
    b.distance("short rod", c, Endpoint::Particle(a), short)
        .unwrap();
    Arc::new(b.build().unwrap())
}

/// max over the run of each rod's stretch |d - L| / L: (long rod, short rod).
fn stretches(
    system: Arc<System>,
    integrator: IntegratorKind,
    project: bool,
    anchor: [f64; 2],
    lengths: [f64; 2],
) -> [f64; 2] {
    let config = SimulationConfig {
        method: Method::Implicit,
        integrator,
        project,
        dt: 1e-3,
        ..Default::default()
    };
    let mut sim = Simulation::new(system, config).unwrap();
    let mut worst = [0.0_f64; 2];
    for _ in 0..2000 {
        sim.step().unwrap_or_else(|e| panic!("{e}"));
        let x = sim.positions();
        let d = |p: [f64; 2], q: [f64; 2]| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
        let (a, c) = ([x[0], x[1]], [x[2], x[3]]);
        worst[0] = worst[0].max((d(a, anchor) - lengths[0]).abs() / lengths[0]);
        worst[1] = worst[1].max((d(c, a) - lengths[1]).abs() / lengths[1]);
    }
    worst
}

/// Law: a rod 10^4 times shorter than its neighbour is held to the same relative stretch,
/// 1e-12 (plus rounding), under rattle and under rk4 with projection. (With the former
/// scene-wide tolerance, 1e-12 of the largest coordinate times the largest gradient, the
/// short rod was allowed a stretch of 1e-8.)
#[test]
fn a_short_rod_beside_a_long_one_keeps_its_own_relative_tolerance() {
    let (long, short) = (10.0, 1e-3);
    for (integrator, project) in [(IntegratorKind::Rattle, false), (IntegratorKind::Rk4, true)] {
        let system = double_pendulum([0.0, 0.0], long, short);
        let worst = stretches(system, integrator, project, [0.0, 0.0], [long, short]);
        // Rounding: the short rod's coordinates are up to ~10 in size, its C resolves to
        // about 16 eps * 10 * sqrt(2) absolute, 5e-11 of its length; the measured stretch
        // also carries the rounding of the check itself.
        let rounding = 16.0 * f64::EPSILON * 10.0 * 2f64.sqrt() / short;
        assert!(worst[0] <= 2e-12, "{integrator:?}: long rod {worst:?}");
        assert!(
            worst[1] <= 1e-12 + 2.0 * rounding,
            "{integrator:?}: short rod {worst:?}"
        );
    }
}

/// Law: far from the origin (coordinates 1e8) no computation resolves |C| below about
/// eps |x|: the solves stop at the rounding allowance instead of failing, and the rods are
/// as exact as the coordinates can say (stretch ~1e-7 of a unit rod at 1e8).
#[test]
fn rods_far_from_the_origin_converge_to_the_rounding_of_their_coordinates() {
    let anchor = [1e8, -1e8];
    for (integrator, project) in [(IntegratorKind::Rattle, false), (IntegratorKind::Rk4, true)] {
        let system = double_pendulum(anchor, 1.0, 1.0);
        let worst = stretches(system, integrator, project, anchor, [1.0, 1.0]);
        let rounding = 16.0 * f64::EPSILON * 1e8 * 2f64.sqrt();
        for w in worst {
            assert!(w <= 2.0 * rounding, "{integrator:?}: {worst:?}");
        }
    }
}

/// The scales themselves: a distance row's scale is its length, another row's is its
/// gradient's norm times the scene's length scale, and the rounding coefficient is
/// 16 eps |J_i|.
#[test]
fn scales_are_each_rows_own() {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let p = b.particle("p", 1.0, &[3.0, 4.0], &[0.0, 0.0]).unwrap();
    b.distance("rod", p, Endpoint::Fixed(vec![0.0, 0.0]), 5.0)
        .unwrap();
    b.constraint_expr("p.x^2 - 9 + 0*p.y").unwrap();
    let system = b.build().unwrap();
    let scales = ConstraintScales::of(&system);
    // Rows in declaration order. The rod's gradient at (3, 4) is (3, 4)/5, of norm 1; the
    // expression's is d/dx (x^2 - 9) = 6 at x = 3, and the scene's length scale is 4.
    assert_eq!(scales.scale, vec![5.0, 6.0 * 4.0]);
    let eps16 = 16.0 * f64::EPSILON;
    assert!((scales.rounding[0] - eps16).abs() <= 1e-30);
    assert_eq!(scales.rounding[1], eps16 * 6.0);
}
