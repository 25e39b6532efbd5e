//! A front end can stop a long `advance_to` (Ctrl-C in Python) at a good state: the callback
//! of `Simulation::advance_to_with` is asked after every step short of the target, and a run
//! asks its `Progress::interrupted` inside an output interval too, so that an adaptive run
//! with one long output interval stops as promptly as a fixed-step one.
//!
//! Law checked: interrupted after k steps, the simulation is at the end of step k (a good
//! state), and going on from there reaches the target with the same bits as a simulation
//! that was never interrupted.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::{System, SystemBuilder};
use bead::simulate::{
    run_with_progress, NullSink, Progress, RunError, RunOptions, Simulation, SimulationConfig,
};

/// A bead on a circle of radius 1, released at 90 degrees.
fn pendulum() -> Arc<System> {
    let mut b = SystemBuilder::new(&[0.0, 9.81]);
    b.particle("bead", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
    b.constraint_expr("bead.x^2 + bead.y^2 - 1").unwrap();
    Arc::new(b.build().unwrap())
}

fn simulation(integrator: IntegratorKind, dt: f64) -> Simulation {
    let config = SimulationConfig {
        method: Method::Implicit,
        integrator,
        dt,
        ..Default::default()
    };
    Simulation::new(pendulum(), config).unwrap()
}

/// A callback that says "stop" on its `after`-th call, and counts the calls.
fn stop_after(after: u64, calls: &mut u64) -> impl FnMut() -> bool + '_ {
    move || {
        *calls += 1;
        *calls >= after
    }
}

#[test]
fn advance_to_with_stops_at_a_good_state_and_goes_on_with_the_same_bits() {
    for integrator in [IntegratorKind::Rk4, IntegratorKind::Dopri5] {
        let mut plain = simulation(integrator, 1e-3);
        plain.advance_to(0.5).unwrap();

        let mut stopped = simulation(integrator, 1e-3);
        let mut calls = 0;
        let error = stopped
            .advance_to_with(0.5, &mut stop_after(7, &mut calls))
            .expect_err("interrupted");
        assert_eq!(calls, 7, "{integrator:?}");
        match error {
            RunError::Interrupted { t, step } => {
                assert_eq!(step, 7, "{integrator:?}");
                assert_eq!(t, stopped.t(), "{integrator:?}");
                assert!(t > 0.0 && t < 0.5, "{integrator:?}: t = {t}");
            }
            other => panic!("{integrator:?}: {other}"),
        }
        assert_eq!(stopped.steps(), 7, "{integrator:?}");
        assert!(stopped.constraint_error() < 1e-6, "{integrator:?}");
        if integrator == IntegratorKind::Rk4 {
            assert_eq!(stopped.t(), 7e-3, "on the grid of steps");
        }

        stopped.advance_to(0.5).unwrap();
        assert_eq!(stopped.t(), plain.t(), "{integrator:?}");
        assert_eq!(stopped.steps(), plain.steps(), "{integrator:?}");
        assert_eq!(stopped.positions(), plain.positions(), "{integrator:?}");
        assert_eq!(stopped.velocities(), plain.velocities(), "{integrator:?}");
    }
}

#[test]
fn advance_to_with_does_not_ask_when_one_step_lands_on_the_target() {
    let mut sim = simulation(IntegratorKind::Rk4, 1e-3);
    let mut calls = 0;
    sim.advance_to_with(1e-3, &mut stop_after(1, &mut calls))
        .unwrap();
    assert_eq!((calls, sim.t()), (0, 1e-3));
}

/// Stops the run on the `after`-th question.
struct StopAfter {
    calls: u64,
    after: u64,
}

impl Progress for StopAfter {
    fn advance(&mut self, _: u64, _: u64) {}
    fn interrupted(&mut self) -> bool {
        self.calls += 1;
        self.calls >= self.after
    }
}

/// Law: dopri5 with one output interval of 100 s takes thousands of steps inside it; the
/// run stops on the first question that says so, not at the interval's end.
#[test]
fn an_adaptive_run_with_one_long_output_interval_is_interrupted_inside_it() {
    let mut sim = simulation(IntegratorKind::Dopri5, 100.0);
    let options = RunOptions::steps(1);
    let mut progress = StopAfter { calls: 0, after: 5 };
    let failure = run_with_progress(&mut sim, options, &mut NullSink, &mut progress)
        .expect_err("interrupted");
    match failure.error {
        RunError::Interrupted { t, step } => {
            assert_eq!(step, 5);
            assert!(t > 0.0 && t < 1.0, "t = {t}");
        }
        other => panic!("{other}"),
    }
    assert_eq!(failure.stats.steps, 5);
}
