//! Time integrators for second-order systems qddot = f(t, q, qdot). An integrator sees only
//! [`SecondOrderSystem`]; it never knows which formulation it advances.
//!
//! | method | order | symplectic | evaluations per step |
//! |---|---|---|---|
//! | `euler` | 1 | no | 1 |
//! | `symplectic-euler` | 1 | yes (for separable Hamiltonians) | 1 |
//! | `midpoint` | 2 | no | 2 |
//! | `rk4` | 4 | no | 4 |

mod euler;
mod midpoint;
mod rk4;
mod symplectic_euler;

pub use euler::Euler;
pub use midpoint::Midpoint;
pub use rk4::Rk4;
pub use symplectic_euler::SymplecticEuler;

use crate::formulation::{SecondOrderSystem, State, StepError};

/// Advances a [`State`] by one step. Implementations allocate their buffers at construction
/// and nothing in [`Integrator::step`].
pub trait Integrator: Send {
    /// Advance `state` from t to t + dt.
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        state: &mut State,
        dt: f64,
    ) -> Result<(), StepError>;
}

/// The integrators by name, as used in scenes and on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IntegratorKind {
    Euler,
    SymplecticEuler,
    Midpoint,
    Rk4,
}

impl IntegratorKind {
    pub const ALL: [IntegratorKind; 4] = [
        IntegratorKind::Euler,
        IntegratorKind::SymplecticEuler,
        IntegratorKind::Midpoint,
        IntegratorKind::Rk4,
    ];

    /// Name in scene files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            IntegratorKind::Euler => "euler",
            IntegratorKind::SymplecticEuler => "symplectic-euler",
            IntegratorKind::Midpoint => "midpoint",
            IntegratorKind::Rk4 => "rk4",
        }
    }
    /// Global order of accuracy.
    pub fn order(self) -> u32 {
        match self {
            IntegratorKind::Euler | IntegratorKind::SymplecticEuler => 1,
            IntegratorKind::Midpoint => 2,
            IntegratorKind::Rk4 => 4,
        }
    }
    /// Whether the method is symplectic (for separable Hamiltonians; on the implicit form's
    /// velocity-dependent constraint forces no explicit method is).
    pub fn symplectic(self) -> bool {
        matches!(self, IntegratorKind::SymplecticEuler)
    }
    /// One-line description for help texts.
    pub fn describe(self) -> String {
        format!(
            "{}: order {}, {}",
            self.name(),
            self.order(),
            if self.symplectic() {
                "symplectic"
            } else {
                "not symplectic"
            }
        )
    }
    /// A ready integrator for n coordinates.
    pub fn build(self, n: usize) -> Box<dyn Integrator> {
        match self {
            IntegratorKind::Euler => Box::new(Euler::new(n)),
            IntegratorKind::SymplecticEuler => Box::new(SymplecticEuler::new(n)),
            IntegratorKind::Midpoint => Box::new(Midpoint::new(n)),
            IntegratorKind::Rk4 => Box::new(Rk4::new(n)),
        }
    }
}

impl std::str::FromStr for IntegratorKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        IntegratorKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = IntegratorKind::ALL.iter().map(|k| k.name()).collect();
                format!("unknown integrator `{s}`; use one of {}", names.join(", "))
            })
    }
}

/// y = x + h z, elementwise.
fn axpy_into(y: &mut [f64], x: &[f64], h: f64, z: &[f64]) {
    for ((y, x), z) in y.iter_mut().zip(x).zip(z) {
        *y = x + h * z;
    }
}
