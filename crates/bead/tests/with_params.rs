//! `Scene::with_params` compiles the equations again only when the new values change them;
//! otherwise it reuses the compiled ones with the new initial state. Either way the scene it
//! gives runs exactly as the scene loaded from its text with the same values does: checked
//! here for every parameter of every shipped scene, both formulations, bit for bit.

use std::path::Path;
use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{run, NullSink, RunOptions, RunStats, Simulation, SimulationConfig};

fn run_of(scene: &Scene, method: Method) -> Option<RunStats> {
    let config = SimulationConfig {
        method,
        integrator: IntegratorKind::Rk4,
        dt: scene.run.dt.unwrap_or(1e-3).min(1e-3),
        ..Default::default()
    };
    let mut simulation = Simulation::new(Arc::clone(&scene.system), config).ok()?;
    let stats = match run(&mut simulation, RunOptions::steps(20), &mut NullSink) {
        Ok(stats) => stats,
        Err(failure) => *failure.stats,
    };
    Some(RunStats {
        wall_seconds: 0.0,
        ..stats
    })
}

#[test]
fn with_params_runs_as_the_scene_loaded_with_those_values() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut checked = 0;
    let mut entries: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().collect();
    entries.sort_by_key(|e| e.path());
    for entry in entries {
        let path = entry.path();
        let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
        // The large generated scenes (cloth, chain) take the same code path at a hundred
        // times the cost.
        if scene.system.particles().len() > 100 {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        for (name, value) in scene.params.clone() {
            // A nearby value: a position parameter moves the start, a physical one the
            // equations (then they are compiled again).
            // (A whole number stays whole: it may count repetitions.)
            let changed = match value {
                0.0 => 0.25,
                v if v.fract() == 0.0 => v + 1.0,
                v => v * 1.05,
            };
            let overrides = vec![(name.clone(), changed)];
            let edited = scene.with_params(&overrides);
            let loaded = Scene::parse(&text, &scene.file, &overrides);
            let (edited, loaded) = match (edited, loaded) {
                (Ok(edited), Ok(loaded)) => (edited, loaded),
                (edited, loaded) => {
                    assert_eq!(
                        edited.err().map(|e| e.to_string()),
                        loaded.err().map(|e| e.to_string())
                    );
                    continue;
                }
            };
            for method in [Method::Implicit, Method::Parametric] {
                let a = run_of(&edited, method);
                let b = run_of(&loaded, method);
                assert_eq!(
                    format!("{a:?}"),
                    format!("{b:?}"),
                    "{}: {name} = {changed}, {method:?}",
                    path.display()
                );
                checked += a.is_some() as usize;
            }
        }
    }
    assert!(checked >= 10, "only {checked} runs compared");
}
