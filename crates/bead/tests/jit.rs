//! Machine code and interpreter give the same numbers, bit for bit: every shipped scene and
//! the oracle's own scene, loaded with the JIT and without it (`expr::with_jit`, one process),
//! stepped with both methods and several integrators, state by state; a sweep (the lanes'
//! machine code) with the switch on and off; and the summary `bead check` prints.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bead::expr::{set_jit_enabled, with_jit};
use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::plan::PlanRequest;
use bead::scene::Scene;
use bead::simulate::{Simulation, SimulationConfig};
use bead::sweep::{Axis, Combine, Sweep};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn scene_files() -> Vec<PathBuf> {
    let mut files = Vec::new();
    for dir in ["scenes", "tests/oracle/scenes"] {
        for entry in std::fs::read_dir(root().join(dir)).expect("scene directory") {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                files.push(path);
            }
        }
    }
    files.sort();
    assert!(files.len() >= 10, "{files:?}");
    files
}

/// The generated scenes at a size a debug build steps quickly (as tests/scenes.rs).
fn small(path: &Path) -> Vec<(String, f64)> {
    let set = |pairs: &[(&str, f64)]| pairs.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    match path.file_name().and_then(|n| n.to_str()).unwrap_or("") {
        "chain.toml" | "rope.toml" => set(&[("N", 5.0)]),
        "cloth.toml" => set(&[("W", 4.0), ("H", 4.0)]),
        "net.toml" => set(&[("W", 4.0), ("R", 2.0)]),
        "tassel.toml" => set(&[("T", 3.0), ("B", 3.0), ("K", 3.0)]),
        _ => Vec::new(),
    }
}

fn methods(scene: &Scene) -> Vec<Method> {
    let mut methods = Vec::new();
    if scene.system.constraints().n_rows() > 0 || scene.system.parametric().is_none() {
        methods.push(Method::Implicit);
    }
    if scene.system.parametric().is_some() {
        methods.push(Method::Parametric);
    }
    methods
}

/// Every state of `steps` steps, as bits (t, q, qdot, positions, velocities), and the error
/// that ended the run early, if any. `None` if the simulation does not start.
fn trace(
    scene: &Scene,
    method: Method,
    integrator: IntegratorKind,
    steps: usize,
) -> Option<(Vec<u64>, Option<String>)> {
    let dt = scene.run.dt.unwrap_or(1.0 / 60.0);
    let config = SimulationConfig {
        method,
        integrator,
        dt,
        ..Default::default()
    };
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).ok()?;
    let mut bits = Vec::new();
    let mut record = |sim: &Simulation| {
        bits.push(sim.t().to_bits());
        for v in [sim.q(), sim.qdot(), sim.positions(), sim.velocities()] {
            bits.extend(v.iter().map(|x| x.to_bits()));
        }
    };
    record(&sim);
    for _ in 0..steps {
        if let Err(e) = sim.step() {
            return Some((bits, Some(e.to_string())));
        }
        record(&sim);
    }
    Some((bits, None))
}

#[test]
fn every_scene_steps_to_the_same_bits_with_and_without_machine_code() {
    use IntegratorKind::*;
    let mut compiled_scenes = 0;
    let files = scene_files();
    for path in &files {
        let load = |jit: bool| {
            with_jit(jit, || {
                Scene::load(path, &small(path)).unwrap_or_else(|e| panic!("{e}"))
            })
        };
        let (native, interpreted) = (load(true), load(false));
        let (on, off) = (
            native.system.machine_code(),
            interpreted.system.machine_code(),
        );
        // Scenes of distances and pins only (chain, cloth, net, rope, tassel) have no tapes:
        // direct code.
        compiled_scenes += usize::from(on.compiled > 0);
        assert!(on.fallbacks.is_empty(), "{}: {on}", path.display());
        assert_eq!(off.compiled, 0, "{}: {off}", path.display());
        assert_eq!(off.disabled, on.compiled, "{}: {off}", path.display());
        for method in methods(&native) {
            let mut ran = 0;
            for integrator in [Rk4, Midpoint, Dopri5, Verlet, Rattle, GaussLegendre] {
                let a = trace(&native, method, integrator, 60);
                let b = trace(&interpreted, method, integrator, 60);
                assert_eq!(
                    a.is_some(),
                    b.is_some(),
                    "{} {method:?} {integrator:?}",
                    path.display()
                );
                if let (Some((a, ea)), Some((b, eb))) = (a, b) {
                    assert_eq!(ea, eb, "{} {method:?} {integrator:?}", path.display());
                    assert!(
                        a == b,
                        "{} {method:?} {integrator:?}: traces differ",
                        path.display()
                    );
                    ran += 1;
                }
            }
            assert!(ran >= 2, "{} {method:?}: {ran} integrators", path.display());
        }
    }
    assert!(compiled_scenes + 5 >= files.len(), "{compiled_scenes}");
}

/// A sweep loads its members on worker threads: the process-wide switch decides there.
/// (The other tests of this file use the per-thread override, which takes precedence.)
#[test]
fn a_sweep_gives_the_same_members_with_and_without_machine_code() {
    let scene = Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap();
    let request = PlanRequest {
        method: Some(Method::Implicit),
        integrator: Some(IntegratorKind::Rk4),
        dt: Some(1.0 / 120.0),
        steps: Some(200),
        ..Default::default()
    };
    let sweep = |jit: bool| {
        set_jit_enabled(jit);
        let sweep = Sweep::new(
            &scene,
            vec![Axis::linspace("x0", 10.0, 200.0, 37).unwrap()],
            Combine::Grid,
            request.clone(),
            None,
        )
        .unwrap();
        let members = sweep.run(2).unwrap();
        members
            .iter()
            .map(|m| {
                let stats = m.stats.as_ref().map(|s| {
                    let mut s = s.clone();
                    s.wall_seconds = 0.0;
                    s
                });
                format!("{:?} {:?}", stats, m.error)
            })
            .collect::<Vec<_>>()
    };
    let on = sweep(true);
    let off = sweep(false);
    set_jit_enabled(true);
    assert_eq!(on.len(), 37);
    assert_eq!(on, off);
}
