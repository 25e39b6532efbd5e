//! What the per-step monitors cost: a scene (default the article's, `scenes/parabola.toml`)
//! stepped with its `[run]` integrator and dt, either bare (the formulation and the
//! integrator alone, as the step bench does, but along the trajectory) or through
//! [`bead::simulate::run`] with a sink that records nothing (what `bead run` does per step:
//! the observation, energy, ledger, divergence, singular-point and constraint-distance
//! monitors, the stop condition), for both forms.
//!
//! ```text
//! cargo run --release -p bead --example monitor_cost -- [--scene PATH] [--steps N]
//!     [--method implicit|parametric] [--mode bare|run] [--seconds S]
//! ```
//! With `--method` and `--mode`: runs that one case for N steps (default 10^5) and prints its
//! final state (what `scripts/monitor_cost` runs under callgrind, twice, to count the
//! instructions of a step without the setup). Without them: times every case for about S
//! seconds each (default 1) and prints ns per step and the monitors' overhead.

use std::hint::black_box;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use bead::formulation::{formulate, ConstraintScales, Method, State};
use bead::integrate::IntegratorKind;
use bead::plan::{Plan, PlanRequest};
use bead::scene::Scene;
use bead::simulate::{run, NullSink, RunOptions, Simulation};

#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Bare,
    Run,
}

struct Args {
    scene: PathBuf,
    steps: u64,
    method: Option<Method>,
    mode: Option<Mode>,
    seconds: f64,
}

fn args() -> Args {
    let mut args = Args {
        scene: PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/parabola.toml"
        )),
        steps: 100_000,
        method: None,
        mode: None,
        seconds: 1.0,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().unwrap_or_else(|| panic!("{flag} needs a value"));
        match flag.as_str() {
            "--scene" => args.scene = value.into(),
            "--steps" => args.steps = value.parse().expect("--steps N"),
            "--seconds" => args.seconds = value.parse().expect("--seconds S"),
            "--method" => {
                args.method = Some(match value.as_str() {
                    "implicit" => Method::Implicit,
                    "parametric" => Method::Parametric,
                    _ => panic!("--method implicit|parametric"),
                })
            }
            "--mode" => {
                args.mode = Some(match value.as_str() {
                    "bare" => Mode::Bare,
                    "run" => Mode::Run,
                    _ => panic!("--mode bare|run"),
                })
            }
            _ => panic!("unknown flag {flag}"),
        }
    }
    args
}

/// One case, ready to step.
struct Case {
    plan: Plan,
    scene: Scene,
    method: Method,
}

impl Case {
    /// N bare steps from the initial state; returns the final state.
    fn bare(&self, steps: u64) -> State {
        let config = self.plan.config(self.method);
        let system: Arc<_> = self.scene.system.clone();
        let mut formulation = formulate(system, self.method, config.feedback).expect("formulate");
        formulation.set_constraint_scales(Some(ConstraintScales::of(formulation.system())));
        let mut state = formulation.initial_state();
        let mut integrator = config
            .integrator
            .build_with(state.q.len(), &config.settings);
        let dt = black_box(config.dt);
        let t0 = state.t;
        for k in 1..=steps {
            // As `Simulation` steps: on the grid t0 + k dt, each step its own length.
            let t_end = t0 + k as f64 * dt;
            let h = t_end - state.t;
            integrator
                .step(&mut *formulation, &mut state, h)
                .expect("a bare step");
            state.t = t_end;
        }
        state
    }

    /// N steps through `run` (monitors included); returns the final state.
    fn run(&self, steps: u64) -> State {
        let config = self.plan.config(self.method);
        let mut simulation = Simulation::new(self.scene.system.clone(), config).expect("setup");
        let options = RunOptions {
            steps,
            every: steps,
            duration: None,
        };
        run(&mut simulation, options, &mut NullSink).expect("the run");
        State {
            t: simulation.t(),
            q: simulation.q().to_vec(),
            qdot: simulation.qdot().to_vec(),
        }
    }

    fn step(&self, mode: Mode, steps: u64) -> State {
        match mode {
            Mode::Bare => self.bare(steps),
            Mode::Run => self.run(steps),
        }
    }
}

fn main() {
    let args = args();
    let scene = Scene::load(&args.scene, &[]).unwrap_or_else(|e| panic!("{e}"));
    let plan = Plan::resolve(&scene, &PlanRequest::default()).expect("plan");
    assert!(
        plan.integrator != IntegratorKind::Dopri5,
        "fixed-step integrators only"
    );
    if let (Some(method), Some(mode)) = (args.method, args.mode) {
        let case = Case {
            plan,
            scene,
            method,
        };
        let state = case.step(mode, args.steps);
        println!("t = {} q = {:?} qdot = {:?}", state.t, state.q, state.qdot);
        return;
    }
    println!(
        "{}: {} dt = {}",
        args.scene.display(),
        plan.integrator.name(),
        plan.dt
    );
    println!(
        "{:<12}{:>12}{:>12}{:>10}",
        "method", "bare ns", "run ns", "overhead"
    );
    for method in [Method::Implicit, Method::Parametric] {
        let case = Case {
            plan: plan.clone(),
            scene: scene.clone(),
            method,
        };
        // Same final state both ways: the monitors change nothing.
        let (bare, run) = (case.bare(1000), case.run(1000));
        assert_eq!(
            (bare.q, bare.qdot),
            (run.q, run.qdot),
            "bare and run differ"
        );
        let time = |mode: Mode| {
            // Batches of 10^4 steps until the time is used; the best batch counts.
            let batch = 10_000;
            let start = Instant::now();
            let mut best = f64::INFINITY;
            while start.elapsed().as_secs_f64() < args.seconds {
                let t = Instant::now();
                black_box(case.step(mode, batch));
                best = best.min(t.elapsed().as_secs_f64() / batch as f64);
            }
            best * 1e9
        };
        let (bare, run) = (time(Mode::Bare), time(Mode::Run));
        println!(
            "{:<12}{:>12.1}{:>12.1}{:>9.0}%",
            method.name(),
            bare,
            run,
            100.0 * (run / bare - 1.0)
        );
    }
}
