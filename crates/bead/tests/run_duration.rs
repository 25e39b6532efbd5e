//! Runs end exactly at the requested duration (issue 15: `duration = 1` at `dt = 0.3` ran to
//! t = 1.2, and `dt = 100` to t = 100). The last step is shortened to land on the duration,
//! as `Simulation::advance_to` does, for every integrator and both forms; the trace's last
//! row, the summary and a simulation advanced to the same time agree bit for bit.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::plan::{Plan, PlanRequest};
use bead::scene::Scene;
use bead::simulate::{run, Sample, Simulation, Sink};

const PENDULUM: &str = r#"
[params]
L = 1.0
[world]
gravity = [0.0, 9.81]
[[particle]]
name = "bead"
mass = 1.0
position = ["L*sin(1)", "L*cos(1)"]
velocity = [0.0, 0.0]
[[constraint]]
name = "circle"
expr = "bead.x^2 + bead.y^2 - L^2"
[parametric]
coordinates = ["theta"]
initial = [1.0]
rates = [0.0]
[parametric.positions]
bead = ["L*sin(theta)", "L*cos(theta)"]
"#;

#[derive(Default)]
struct Times(Vec<(f64, Vec<f64>)>);

impl Sink for Times {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.0.push((sample.t, sample.x.to_vec()));
        Ok(())
    }
}

fn accepts(method: Method, integrator: IntegratorKind) -> bool {
    !(method == Method::Parametric && integrator.needs_constraints())
}

#[test]
fn a_run_ends_exactly_at_a_duration_that_is_not_a_whole_number_of_steps() {
    let scene = Scene::parse(PENDULUM, "pendulum.toml", &[]).unwrap();
    for method in [Method::Implicit, Method::Parametric] {
        for integrator in IntegratorKind::ALL {
            if !accepts(method, integrator) {
                continue;
            }
            // (dt, duration, steps): a shorter last step, and a duration shorter than dt.
            for (dt, duration, steps) in [(0.3, 1.0, 4), (0.01, 0.125, 13), (100.0, 0.01, 1)] {
                let request = PlanRequest {
                    method: Some(method),
                    integrator: Some(integrator),
                    dt: Some(dt),
                    duration: Some(duration),
                    ..Default::default()
                };
                let plan = Plan::resolve(&scene, &request).unwrap();
                assert_eq!((plan.steps, plan.t_end()), (steps, duration));
                let context = format!("{method:?} {integrator:?} dt {dt} duration {duration}");
                let config = plan.config(method);
                let mut simulation = Simulation::new(Arc::clone(&scene.system), config).unwrap();
                let mut times = Times::default();
                let stats = run(&mut simulation, plan.options(), &mut times)
                    .unwrap_or_else(|e| panic!("{context}: {e}"));
                assert_eq!(stats.t_final, duration, "{context}");
                let (t_last, x_last) = times.0.last().unwrap();
                assert_eq!(*t_last, duration, "{context}: the last row");
                assert_eq!(
                    x_last, &stats.x,
                    "{context}: the last row is the summary's state"
                );
                // Every earlier row on the grid of dt.
                for (k, (t, _)) in times.0.iter().enumerate().take(times.0.len() - 1) {
                    assert_eq!(*t, k as f64 * dt, "{context}: row {k}");
                }
                // The same state as a simulation advanced to the duration.
                let mut alone = Simulation::new(Arc::clone(&scene.system), config).unwrap();
                alone.set_stop_time(Some(duration));
                alone.advance_to(duration).unwrap();
                assert_eq!(alone.t(), duration, "{context}");
                assert_eq!(alone.positions(), &stats.x[..], "{context}");
                if !integrator.is_adaptive() {
                    assert_eq!(stats.steps, steps, "{context}");
                }
            }
        }
    }
}

#[test]
fn a_shortened_last_step_keeps_the_integrators_order() {
    // rk4 with a last step of dt/3 at every dt: the end-point error still falls by ~2^4
    // per halving of dt (a last step of dt rounded up to the grid would end at the wrong
    // time, an O(1) error in t). Reference: the exact pendulum equation by RK4 at a tiny
    // step, written here.
    let scene = Scene::parse(PENDULUM, "pendulum.toml", &[]).unwrap();
    let duration = 1.0;
    let theta = |t_end: f64| {
        let n = 100_000;
        let h = t_end / n as f64;
        let f = |th: f64| -9.81 * th.sin();
        let (mut th, mut w) = (1.0_f64, 0.0_f64);
        for _ in 0..n {
            let (k1q, k1v) = (w, f(th));
            let (k2q, k2v) = (w + 0.5 * h * k1v, f(th + 0.5 * h * k1q));
            let (k3q, k3v) = (w + 0.5 * h * k2v, f(th + 0.5 * h * k2q));
            let (k4q, k4v) = (w + h * k3v, f(th + h * k3q));
            th += h / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q);
            w += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        }
        th
    };
    let exact = theta(duration);
    let exact_x = [exact.sin(), exact.cos()];
    let mut errors = Vec::new();
    for steps in [24u64, 48, 96, 192] {
        // steps - 1 whole steps and a last one of a third of dt.
        let dt = duration / (steps as f64 - 2.0 / 3.0);
        let request = PlanRequest {
            method: Some(Method::Parametric),
            integrator: Some(IntegratorKind::Rk4),
            dt: Some(dt),
            duration: Some(duration),
            ..Default::default()
        };
        let plan = Plan::resolve(&scene, &request).unwrap();
        assert_eq!(plan.steps, steps);
        let mut simulation =
            Simulation::new(Arc::clone(&scene.system), plan.config(Method::Parametric)).unwrap();
        let stats = run(&mut simulation, plan.options(), &mut Times::default()).unwrap();
        assert_eq!(stats.t_final, duration);
        let error = ((stats.x[0] - exact_x[0]).powi(2) + (stats.x[1] - exact_x[1]).powi(2)).sqrt();
        errors.push(error);
    }
    for pair in errors.windows(2) {
        let order = (pair[0] / pair[1]).log2();
        assert!(
            (3.5..=4.5).contains(&order),
            "order {order} from {errors:?}"
        );
    }
}
