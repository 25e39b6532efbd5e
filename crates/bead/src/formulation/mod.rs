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

mod implicit;
mod parametric;

use std::sync::Arc;

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
