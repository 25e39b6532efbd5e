//! Step and project (`fast-projection`) on the shipped cloth at frame-size steps, where
//! RATTLE cannot go: the cloth's taut threads oscillate across themselves at up to
//! F = 2 sqrt(T / (m L)) (the scene's parameter F), and RATTLE, explicit in those
//! directions, needs dt F < 2.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{Simulation, SimulationConfig};

/// The shipped cloth at W x H masses.
fn cloth(w: f64, h: f64) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cloth.toml");
    Scene::load(&path, &[("W".into(), w), ("H".into(), h)]).unwrap_or_else(|e| panic!("{e}"))
}

/// The largest rod stretch |d - L| / L at the simulation's state.
fn stretch(sim: &Simulation, ws: &mut bead::model::ConstraintEval) -> f64 {
    let set = sim.system().constraints();
    let c = set.residuals(sim.t(), sim.positions(), ws);
    let mut stretch = 0.0_f64;
    for info in set.infos() {
        if let Some(l) = info.length {
            // C = (|d|^2 - L^2) / (2 L), so |d| = sqrt(L^2 + 2 L C).
            let d = (l * l + 2.0 * l * c[info.rows.start]).sqrt();
            stretch = stretch.max((d - l).abs() / l);
        }
    }
    stretch
}

/// Law: at dt = 1/60 s on a 12 x 12 cloth (dt F = 4.2), fast projection holds every rod to
/// 1e-10 of its length after every one of 1,200 steps (20 s, ten times the scene's default
/// duration), its energy never rises above the start and ends below it (the modes it cannot
/// resolve are damped); RATTLE at the same step fails within the first second (with no
/// substeps to retry in), and runs at dt F = 1.5.
#[test]
fn fast_projection_steps_a_stiff_cloth_at_frame_size_steps_where_rattle_cannot() {
    let scene = cloth(12.0, 12.0);
    let f = scene.params.iter().find(|p| p.0 == "F").unwrap().1;
    let dt = 1.0 / 60.0;
    assert!(dt * f > 4.0, "dt F = {}", dt * f);
    let system = Arc::clone(&scene.system);
    let config = |integrator, dt| SimulationConfig {
        method: Method::Implicit,
        integrator,
        dt,
        max_substeps: 1,
        ..Default::default()
    };
    let mut sim = Simulation::new(
        Arc::clone(&system),
        config(IntegratorKind::FastProjection, dt),
    )
    .unwrap();
    let mut ws = system.constraints().workspace();
    let e0 = sim.energy();
    let mut worst = (0.0_f64, f64::NEG_INFINITY);
    for step in 0..1200 {
        sim.step()
            .unwrap_or_else(|e| panic!("fast-projection, step {step}: {e}"));
        worst.0 = worst.0.max(stretch(&sim, &mut ws));
        worst.1 = worst.1.max(sim.energy() - e0);
    }
    println!(
        "fast-projection at dt F = {:.2}: stretch {:.1e}, max E - E0 {:.1e} (E0 {e0:.4})",
        dt * f,
        worst.0,
        worst.1
    );
    assert!(worst.0 <= 1e-10, "stretch {:e}", worst.0);
    assert!(worst.1 <= 1e-12 * e0.abs(), "energy rose by {:e}", worst.1);
    // The energy goes: the stiff modes it cannot resolve are damped.
    assert!(sim.energy() < e0);

    let mut rattle =
        Simulation::new(Arc::clone(&system), config(IntegratorKind::Rattle, dt)).unwrap();
    let failed = (0..60).any(|_| rattle.step().is_err());
    assert!(failed, "rattle at dt F = {:.1} ran a second", dt * f);
    let mut rattle =
        Simulation::new(Arc::clone(&system), config(IntegratorKind::Rattle, 1.5 / f)).unwrap();
    for step in 0..200 {
        rattle
            .step()
            .unwrap_or_else(|e| panic!("rattle at dt F = 1.5, step {step}: {e}"));
    }
}
