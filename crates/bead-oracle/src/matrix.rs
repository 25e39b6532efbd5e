//! Which runs the checks make: every system with every method and integrator that accepts
//! it, at a step where the error is in its asymptotic range (calibrated: halving it divides
//! the error by 2^p within 20%) and above round-off.

use bead::formulation::Method;
use bead::integrate::IntegratorKind;

use crate::run::Spec;
use crate::systems::System;

/// The methods of every oracle system (each has both forms).
pub const METHODS: [Method; 2] = [Method::Implicit, Method::Parametric];

/// Whether bead accepts the combination (`SimulationConfig::check`: rattle needs the
/// implicit form's constraints).
pub fn accepts(method: Method, integrator: IntegratorKind) -> bool {
    !(method == Method::Parametric && integrator.needs_constraints())
}

/// The simulated time of a system's runs (s).
pub fn duration(system: &System) -> f64 {
    match system.name {
        "parabola" => 1.5,
        _ => 1.0,
    }
}

/// dopri5's tolerance in the oracle runs, and the bound of its error relative to it: its
/// step control holds each step's local error to rtol, and the global error is their sum
/// carried along (measured: up to 140 rtol at rtol 1e-12 over 1 s on the rotating rod, a
/// few rtol elsewhere); a stale or mislabelled state is |v| dt, 1e-3 and more.
pub const DOPRI_RTOL: f64 = 1e-9;
pub const DOPRI_BOUND: f64 = 1000.0;

/// The step of a fixed-step integrator's coarse run (its fine run halves it); dopri5's
/// output interval.
pub fn dt(system: &System, method: Method, integrator: IntegratorKind) -> f64 {
    let _ = method;
    let base = match system.name {
        "parabola" => 0.5,
        "spinning-hoop" => 0.5,
        "double-pendulum" => 0.5,
        _ => 1.0,
    };
    base * match integrator {
        IntegratorKind::Euler
        | IntegratorKind::SymplecticEuler
        | IntegratorKind::FastProjection => 1e-3,
        IntegratorKind::Midpoint | IntegratorKind::Verlet | IntegratorKind::Rattle => 1e-2,
        // The double pendulum's error is asymptotic (within 20% of 2^4 at every row) from
        // about here.
        IntegratorKind::Rk4 | IntegratorKind::Rattle4 | IntegratorKind::GaussLegendre
            if system.name == "double-pendulum" =>
        {
            1.25e-2
        }
        IntegratorKind::Rk4 | IntegratorKind::Rattle4 | IntegratorKind::GaussLegendre => 2.5e-2,
        IntegratorKind::Dopri5 => 5e-2,
    }
}

/// Every accepted (system, method, integrator) as a run of the system's duration at its
/// calibrated step (dopri5 at [`DOPRI_RTOL`]).
pub fn cases() -> Vec<Spec> {
    let mut cases = Vec::new();
    for system in System::all() {
        for method in METHODS {
            for integrator in IntegratorKind::ALL {
                if !accepts(method, integrator) {
                    continue;
                }
                let mut spec = Spec::new(
                    system,
                    method,
                    integrator,
                    dt(system, method, integrator),
                    duration(system),
                );
                if integrator.is_adaptive() {
                    spec.rtol = Some(DOPRI_RTOL);
                }
                cases.push(spec);
            }
        }
    }
    cases
}

/// Runs whose duration is not a whole number of steps: the issue's (1 s at dt 0.3 s, rk4
/// and dopri5: the run ended at 1.2), and rk4 and gauss-legendre at 0.7 times their
/// calibrated step, where the error is asymptotic.
pub fn off_grid_cases() -> (Vec<Spec>, Vec<Spec>) {
    let mut issue = Vec::new();
    let mut asymptotic = Vec::new();
    for system in System::all() {
        for method in METHODS {
            // (The double pendulum's arms turn by more than 90 degrees in 0.3 s: the parametric
            // form refuses such a step with "the step is too long", and at that step no
            // answer would be near the reference anyway.)
            for integrator in [IntegratorKind::Rk4, IntegratorKind::Dopri5] {
                if system.name == "double-pendulum" && !integrator.is_adaptive() {
                    continue;
                }
                let mut spec = Spec::new(system, method, integrator, 0.3, 1.0);
                spec.rtol = integrator.is_adaptive().then_some(DOPRI_RTOL);
                issue.push(spec);
            }
            for integrator in [IntegratorKind::Rk4, IntegratorKind::GaussLegendre] {
                let dt = 0.7 * dt(system, method, integrator);
                asymptotic.push(Spec::new(system, method, integrator, dt, duration(system)));
            }
        }
    }
    (issue, asymptotic)
}
