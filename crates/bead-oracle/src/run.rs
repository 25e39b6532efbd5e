//! A run of an oracle system as the front ends ask for one ([`Spec`]): through the library
//! here (the plan, `Simulation`, `simulate::run`, what the CLI and Python call), and as the
//! command-line flags and Python keyword arguments that ask for the same run.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::output::Summary;
use bead::plan::{Plan, PlanRequest};
use bead::scene::Scene;
use bead::simulate::{self, Event, RunFailure, RunStats, Sample, Simulation, Sink};

use crate::rows::Row;
use crate::systems::System;

/// What to run.
#[derive(Clone, Debug)]
pub struct Spec {
    pub system: &'static System,
    pub method: Method,
    pub integrator: IntegratorKind,
    pub dt: f64,
    pub duration: Option<f64>,
    pub steps: Option<u64>,
    pub rtol: Option<f64>,
    pub substeps: Option<u32>,
    pub max_substeps: Option<u32>,
    pub stop_when: Option<String>,
    pub overrides: Vec<(String, f64)>,
}

/// A run's rows and figures.
pub struct Outcome {
    pub rows: Vec<Row>,
    pub result: Result<RunStats, RunFailure>,
    pub summary: Summary,
}

impl Outcome {
    /// The figures, failed or not.
    pub fn stats(&self) -> &RunStats {
        match &self.result {
            Ok(stats) => stats,
            Err(failure) => &failure.stats,
        }
    }
}

struct Recorder {
    rows: Vec<Row>,
    parametric: bool,
}

impl Sink for Recorder {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.rows.push(Row::of_sample(sample, self.parametric));
        Ok(())
    }
}

impl Spec {
    pub fn new(
        system: &'static System,
        method: Method,
        integrator: IntegratorKind,
        dt: f64,
        duration: f64,
    ) -> Spec {
        Spec {
            system,
            method,
            integrator,
            dt,
            duration: Some(duration),
            steps: None,
            rtol: None,
            substeps: None,
            max_substeps: None,
            stop_when: None,
            overrides: Vec::new(),
        }
    }

    /// The same run at dt / 2.
    pub fn halved(&self) -> Spec {
        Spec {
            dt: self.dt / 2.0,
            steps: self.steps.map(|s| s * 2),
            ..self.clone()
        }
    }

    /// The scene's path, absolute.
    pub fn scene_path(&self) -> std::path::PathBuf {
        crate::root().join(self.system.scene)
    }

    /// The scene, loaded with the overrides.
    pub fn scene(&self) -> Scene {
        Scene::load(&self.scene_path(), &self.overrides).expect("the oracle's scene loads")
    }

    /// The request a front end makes.
    pub fn request(&self) -> PlanRequest {
        PlanRequest {
            method: Some(self.method),
            integrator: Some(self.integrator),
            dt: Some(self.dt),
            duration: self.duration,
            steps: self.steps,
            rtol: self.rtol,
            substeps: self.substeps,
            max_substeps: self.max_substeps,
            ..PlanRequest::default()
        }
    }

    /// The system's stop condition for this method (its reference event), with the
    /// reference's duration (after the event).
    pub fn with_event(mut self) -> Spec {
        self.duration = Some(self.system.reference().duration());
        let (implicit, parametric, _) = self.system.reference().events()[0].clone();
        self.stop_when = Some(match self.method {
            Method::Implicit => implicit,
            Method::Parametric => parametric,
        });
        self
    }

    /// The reference's event time.
    pub fn event_time(&self) -> f64 {
        self.system.reference().events()[0].2
    }

    /// The run through the library, as `bead run` makes it.
    pub fn run(&self) -> Outcome {
        let scene = self.scene();
        let plan = Plan::resolve(&scene, &self.request()).expect("the plan resolves");
        let mut simulation = Simulation::new(Arc::clone(&scene.system), plan.config(self.method))
            .expect("the simulation starts");
        let event = self
            .stop_when
            .as_ref()
            .map(|s| Event::parse(&scene.system, s).expect("the stop condition parses"));
        simulation
            .set_stop_when(event)
            .expect("the stop condition fits");
        let coordinates = simulation.formulation().coordinate_names().to_vec();
        let mut recorder = Recorder {
            rows: Vec::new(),
            parametric: self.method == Method::Parametric,
        };
        let result = simulate::run(&mut simulation, plan.options(), &mut recorder);
        let summary = Summary::from_result(&scene.file, &scene.system, &coordinates, &result);
        Outcome {
            rows: recorder.rows,
            result,
            summary,
        }
    }

    /// A simulation of this spec, not yet stepped (for `advance_to` and `step`).
    pub fn simulation(&self) -> Simulation {
        let scene = self.scene();
        let plan = Plan::resolve(&scene, &self.request()).expect("the plan resolves");
        Simulation::new(Arc::clone(&scene.system), plan.config(self.method))
            .expect("the simulation starts")
    }

    /// The flags of `bead run` (and `bead sweep`) for this run, after the scene.
    pub fn cli_flags(&self) -> Vec<String> {
        let mut args = vec![
            "--method".to_string(),
            self.method.name().to_string(),
            "--integrator".into(),
            self.integrator.name().into(),
            "--dt".into(),
            format!("{:e}", self.dt),
        ];
        if let Some(d) = self.duration {
            args.extend(["--duration".into(), format!("{d:e}")]);
        }
        if let Some(s) = self.steps {
            args.extend(["--steps".into(), s.to_string()]);
        }
        if let Some(r) = self.rtol {
            args.extend(["--rtol".into(), format!("{r:e}")]);
        }
        if let Some(s) = self.substeps {
            args.extend(["--substeps".into(), s.to_string()]);
        }
        if let Some(s) = self.max_substeps {
            args.extend(["--max-substeps".into(), s.to_string()]);
        }
        if let Some(s) = &self.stop_when {
            args.extend(["--stop-when".into(), s.clone()]);
        }
        for (name, value) in &self.overrides {
            args.extend(["--set".into(), format!("{name}={value:e}")]);
        }
        args
    }

    /// A label for messages: `pendulum implicit rk4 dt=0.01`.
    pub fn label(&self) -> String {
        let mut s = format!(
            "{} {} {} dt={}",
            self.system.name,
            self.method.name(),
            self.integrator.name(),
            self.dt
        );
        if let Some(r) = self.rtol {
            s += &format!(" rtol={r}");
        }
        if let Some(d) = self.duration {
            s += &format!(" duration={d}");
        }
        if let Some(w) = &self.stop_when {
            s += &format!(" stop_when={w}");
        }
        s
    }
}
