//! Formulations turn a [`System`] into a second-order ODE qddot = f(t, q, qdot) that any
//! integrator can advance:
//!
//! - [`Implicit`]: q = all particle coordinates; constraint forces J^T lambda keep C(x, t) = 0
//!   at the acceleration level (Witkin).
//! - [`Parametric`]: q = generalized coordinates, x = x(q, t); Lagrange's equations
//!   M(q) qddot = Q - sum m J^T h.
//!
//! Both implement [`SecondOrderSystem`] (all an integrator sees) and [`Formulation`] (what the
//! run loop needs: the initial state and the map back to particles).

mod constrained;
mod implicit;
mod parametric;

use std::sync::Arc;

pub use constrained::ConstrainedSystem;
pub use implicit::{Feedback, Implicit};
pub use parametric::Parametric;

use crate::model::System;

/// A second-order ODE qddot = f(t, q, qdot) in n coordinates: the whole interface between
/// formulations and integrators.
pub trait SecondOrderSystem {
    /// Number of coordinates n.
    fn n_coords(&self) -> usize;
    /// Write qddot = f(t, q, qdot) into `a` (n). Must not allocate.
    fn acceleration(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        a: &mut [f64],
    ) -> Result<(), StepError>;

    /// Whether f may depend on qdot. Integrators whose velocity update is implicit in qdot
    /// (verlet's second half kick) solve it only when this is true, and take the explicit
    /// update, exact then, when it is false. Answering false for a system whose f does depend
    /// on qdot costs accuracy (verlet drops to first order), so the default is true.
    fn velocity_dependent(&self) -> bool {
        true
    }

    /// The holonomic constraints of this system, for integrators and projections that work
    /// on them directly (RATTLE, `--project`). `None` (the default) for systems without
    /// constraints to project onto, such as the parametric form.
    fn as_constrained(&mut self) -> Option<&mut dyn ConstrainedSystem> {
        None
    }
}

/// Why an acceleration could not be computed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    #[error("at t = {t}: the constraints are singular at {constraint} (`{description}`): its gradient vanishes there or it duplicates other constraints")]
    SingularConstraints {
        t: f64,
        constraint: String,
        description: String,
    },
    #[error("at t = {t}: the mass matrix M(q) is singular in coordinate `{coordinate}`: the parametric map x(q) does not depend on it there")]
    SingularMassMatrix { t: f64, coordinate: String },
    #[error("at t = {t}: {quantity} is not finite")]
    NonFinite { t: f64, quantity: String },
    #[error("at t = {t}: projection onto the constraints did not converge: max |C| = {residual:e} after {iterations} iterations (raise the tolerance or the iteration limit, or reduce dt)")]
    ProjectionFailed {
        t: f64,
        iterations: usize,
        residual: f64,
    },
    #[error("{what} needs the implicit form; the parametric form has no constraints to project onto — use gauss-legendre or rk4")]
    NeedsConstraints { what: String },
    /// The fixed-point iteration of an integrator's implicit equations did not converge:
    /// gauss-legendre's stages, or the velocity half kick of verlet and rattle when the
    /// acceleration depends on the velocity.
    #[error("at t = {t}: {method}: the implicit {equations} did not converge in {iterations} fixed-point iterations (last increment {residual:.3e} relative to the accelerations); reduce dt: the iteration converges when dt is small against the system's time scales")]
    ImplicitStageFailed {
        /// The integrator, e.g. `gauss-legendre`.
        method: &'static str,
        /// Which equations, e.g. `stage equations`.
        equations: &'static str,
        t: f64,
        iterations: u32,
        residual: f64,
    },
    #[error("step size underflow at t = {t}: the adaptive step fell to {h:.3e} s, below 1e-14 of the time scale (the system is too stiff or singular there, or the tolerances are too tight)")]
    StepSizeUnderflow { t: f64, h: f64 },
}

/// Which formulation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    Implicit,
    Parametric,
}

impl Method {
    /// Name as used in scene files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Implicit => "implicit",
            Method::Parametric => "parametric",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "implicit" => Ok(Method::Implicit),
            "parametric" => Ok(Method::Parametric),
            _ => Err(format!("unknown method `{s}`; use implicit or parametric")),
        }
    }
}

/// Time and the formulation's own coordinates and rates.
#[derive(Clone, Debug, PartialEq)]
pub struct State {
    pub t: f64,
    /// q (n)
    pub q: Vec<f64>,
    /// qdot (n)
    pub qdot: Vec<f64>,
}

/// What the run loop needs beyond the ODE.
pub trait Formulation: SecondOrderSystem {
    fn method(&self) -> Method;
    fn system(&self) -> &System;
    /// The state at t = 0.
    fn initial_state(&self) -> State;
    /// Names of the generalized coordinates, for parametric forms; empty for implicit.
    fn coordinate_names(&self) -> &[String];
    /// Particle positions x and velocities xdot (n_coords each) of state (t, q, qdot).
    fn particle_state(&mut self, t: f64, q: &[f64], qdot: &[f64], x: &mut [f64], xdot: &mut [f64]);
}

/// Build the formulation `method` of `system`.
pub fn formulate(
    system: Arc<System>,
    method: Method,
    feedback: Feedback,
) -> Result<Box<dyn Formulation + Send>, String> {
    match method {
        Method::Implicit => Ok(Box::new(Implicit::new(system, feedback))),
        Method::Parametric => {
            if feedback != Feedback::default() {
                return Err("feedback (--stabilize) applies to the implicit form only; the parametric form cannot drift off its constraints".into());
            }
            Parametric::new(system).map(|p| Box::new(p) as Box<dyn Formulation + Send>)
        }
    }
}
