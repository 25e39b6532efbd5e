//! Time integrators for second-order systems qddot = f(t, q, qdot). An integrator sees only
//! [`SecondOrderSystem`]; it never knows which formulation it advances.
//!
//! | method | order | symplectic | evaluations per step |
//! |---|---|---|---|
//! | `euler` | 1 | no | 1 |
//! | `symplectic-euler` | 1 | yes (for separable Hamiltonians) | 1 |
//! | `midpoint` | 2 | no | 2 |
//! | `rk4` | 4 | no | 4 |
//! | `verlet` | 2 | yes (for separable Hamiltonians) | 2; when f depends on qdot 2 + 1 per sweep of the implicit velocity kick |
//! | `rattle` | 2 | yes (constrained; implicit form only) | 2 + 1 per Newton iteration; with drag + 1 force evaluation and velocity projection per kick sweep |
//! | `gauss-legendre` | 4 | yes (implicit; fixed-point stage iteration) | 1 + 2 per iteration |
//! | `dopri5` | 5 (adaptive, error estimate of order 4) | no | 6 per step (FSAL) |
//! | `fast-projection` | 1 | no (damps what the step cannot resolve; implicit form only) | 1 + a factorization per projection iteration + a velocity projection |
//!
//! The orders hold whether or not f depends on qdot; `tests/physics_orders.rs` measures every
//! fixed-step method on systems where it does (the implicit form's constraint bias, a
//! parametric map nonlinear in q, drag). The implicit kicks iterate to round-off, each sweep
//! contracting by about dt/2 ||df/dqdot||: 3 to 9 sweeps per step on those systems at dt = 1/100
//! to 1/400 s. Systems whose f ignores qdot ([`SecondOrderSystem::velocity_dependent`]) skip
//! them.

mod composition;
mod dopri5;
mod euler;
mod fast_projection;
mod fixed_point;
mod gauss_legendre;
mod midpoint;
mod rattle;
pub(crate) mod rk4;
mod symplectic_euler;
mod verlet;

pub use composition::{suzuki_weights, triple_jump_weights, Composition};
pub use dopri5::Dopri5;
pub use euler::Euler;
pub use fast_projection::FastProjection;
pub use gauss_legendre::GaussLegendre;
pub use midpoint::Midpoint;
pub use rattle::{NewtonMatrix, Rattle};
pub use rk4::Rk4;
pub use symplectic_euler::SymplecticEuler;
pub use verlet::Verlet;

use crate::formulation::{SecondOrderSystem, State, StepError};

/// Advances a [`State`] by one step. Implementations allocate their buffers at construction
/// and nothing in [`Integrator::step`] (a system may build its compiled step on first use:
/// see [`SecondOrderSystem::compiled_rk4_step`]).
pub trait Integrator: Send {
    /// Advance `state` from t to t + dt.
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        state: &mut State,
        dt: f64,
    ) -> Result<(), StepError>;

    /// For iterative methods: the most iterations (e.g. Newton steps) any step so far has
    /// needed; `None` for explicit methods.
    fn newton_iterations_max(&self) -> Option<usize> {
        None
    }

    /// The work done on the particles by constraint impulses the last step applied outside
    /// of f (RATTLE's multipliers), sum of Delta p . v; 0 for methods that take every force
    /// from f. The energy ledger adds it to the work W (see `simulate`).
    fn constraint_work(&self) -> f64 {
        0.0
    }

    /// For methods whose first stage is the acceleration at the step's start (rk4): evaluate
    /// it now at `state`, so that the next [`Integrator::step`] from bitwise the same state
    /// uses it instead of evaluating it again. A simulation primes the integrator at every
    /// accepted step's end, where its monitors read the same evaluation
    /// ([`crate::formulation::Formulation::observe_accelerated`]); a step from any other
    /// state evaluates as usual. `None`: this method does not take it (nothing evaluated).
    /// The system must not change before that step (else [`Integrator::unprime`]).
    fn prime(
        &mut self,
        _system: &mut dyn SecondOrderSystem,
        _state: &State,
    ) -> Option<Result<(), StepError>> {
        None
    }

    /// Forget a primed first stage (the system changed, e.g. its external forces).
    fn unprime(&mut self) {}

    /// Set aside what the next step takes over from the last one (RATTLE's and fast
    /// projection's multipliers, their warm start) before steps that are not the run's own:
    /// an event's location integrates parts of a step again from its start. With
    /// [`Integrator::take_back_carry`] after them, the run's next step is the one it would
    /// have taken without them, bit for bit.
    fn set_aside_carry(&mut self) {}

    /// Take back what [`Integrator::set_aside_carry`] set aside.
    fn take_back_carry(&mut self) {}

    /// The driver changed the state the last step ended at without changing the motion, and
    /// a step from `state` continues the last one (RATTLE's and fast projection's warm
    /// start, which otherwise needs bitwise the state the last step ended at): it moved the
    /// time from `stepped` (the step's own t + dt) to `state.t` (substeps and composition
    /// stages land on t0 + k h, which differs from the sum of rounded steps in the last bit
    /// for about one step in eight), and, where `amended`, changed entries on which no force,
    /// constraint or multiplier depends (the energy ledger adds the constraint impulses'
    /// work to its own entry). A driver that changes anything else calls nothing: the next
    /// step starts cold.
    fn continued(&mut self, _stepped: f64, _state: &State, _amended: bool) {}

    /// For iterative methods: the iterations (e.g. Newton steps) of all steps so far, whose
    /// most in one step is [`Integrator::newton_iterations_max`]; `None` for explicit methods.
    fn iterations_total(&self) -> Option<u64> {
        None
    }

    /// The longest step at which the method stays stable after its last step, as far as it
    /// can tell from that step: RATTLE's 2 / omega on systems of rods and pins,
    /// omega bounded from its multipliers ([`Rattle`]'s stable step); `None` when it cannot
    /// tell (the default: every other method, other constraints, no step yet).
    fn stable_step(&mut self, _system: &mut dyn SecondOrderSystem) -> Option<f64> {
        None
    }
}

/// Settings of the iterative integrators and of the constraint projection, with defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntegratorSettings {
    /// RATTLE's position solve and `--project`: tolerance on
    /// [`crate::formulation::ConstrainedSystem::constraint_residual`]: absolute on max_i |C_i|
    /// (units of C), or relative to each row's scale when the formulation has
    /// [`crate::formulation::ConstraintScales`] (a [`crate::simulate::Simulation`] sets them
    /// with 1e-12 unless told not to). Default 1e-10.
    pub constraint_tolerance: f64,
    /// RATTLE's position solve and `--project`: Newton iterations allowed per step before
    /// [`StepError::ProjectionFailed`]. Default 50.
    pub constraint_max_iterations: usize,
    /// dopri5: relative tolerance of the local error, > 0. Default 1e-8.
    pub rtol: f64,
    /// dopri5: absolute tolerance of the local error (units of q and qdot), >= 0. Default
    /// 1e-10: below the rtol share for any state of magnitude >= 0.01, so that rtol governs
    /// and atol only guards components passing through zero.
    pub atol: f64,
    /// gauss-legendre's stage iteration, and the implicit velocity kick of verlet and rattle
    /// on velocity-dependent systems: the fixed-point iteration stops when its increment's
    /// max norm is at most this times the accelerations' max norm. Default 1e-14 (round-off).
    pub implicit_tolerance: f64,
    /// gauss-legendre, verlet, rattle: fixed-point iterations allowed per step before
    /// [`StepError::ImplicitStageFailed`]. Default 50.
    pub implicit_max_iterations: u32,
}

impl Default for IntegratorSettings {
    fn default() -> Self {
        IntegratorSettings {
            constraint_tolerance: 1e-10,
            constraint_max_iterations: 50,
            rtol: 1e-8,
            atol: 1e-10,
            implicit_tolerance: 1e-14,
            implicit_max_iterations: 50,
        }
    }
}

/// The integrators by name, as used in scenes and on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IntegratorKind {
    Euler,
    SymplecticEuler,
    Midpoint,
    Rk4,
    Verlet,
    Rattle,
    /// RATTLE composed in Suzuki's five stages ([`Composition`]): order 4, symplectic
    Rattle4,
    GaussLegendre,
    Dopri5,
    FastProjection,
}

impl IntegratorKind {
    pub const ALL: [IntegratorKind; 10] = [
        IntegratorKind::Euler,
        IntegratorKind::SymplecticEuler,
        IntegratorKind::Midpoint,
        IntegratorKind::Rk4,
        IntegratorKind::Verlet,
        IntegratorKind::Rattle,
        IntegratorKind::Rattle4,
        IntegratorKind::GaussLegendre,
        IntegratorKind::Dopri5,
        IntegratorKind::FastProjection,
    ];

    /// Name in scene files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            IntegratorKind::Euler => "euler",
            IntegratorKind::SymplecticEuler => "symplectic-euler",
            IntegratorKind::Midpoint => "midpoint",
            IntegratorKind::Rk4 => "rk4",
            IntegratorKind::Verlet => "verlet",
            IntegratorKind::Rattle => "rattle",
            IntegratorKind::Rattle4 => "rattle4",
            IntegratorKind::GaussLegendre => "gauss-legendre",
            IntegratorKind::Dopri5 => "dopri5",
            IntegratorKind::FastProjection => "fast-projection",
        }
    }
    /// Global order of accuracy.
    pub fn order(self) -> u32 {
        match self {
            IntegratorKind::Euler
            | IntegratorKind::SymplecticEuler
            | IntegratorKind::FastProjection => 1,
            IntegratorKind::Midpoint | IntegratorKind::Verlet | IntegratorKind::Rattle => 2,
            IntegratorKind::Rk4 | IntegratorKind::Rattle4 | IntegratorKind::GaussLegendre => 4,
            IntegratorKind::Dopri5 => 5,
        }
    }
    /// Whether the method is symplectic (for separable Hamiltonians; on the implicit form's
    /// velocity-dependent constraint forces no explicit method is).
    pub fn symplectic(self) -> bool {
        matches!(
            self,
            IntegratorKind::SymplecticEuler
                | IntegratorKind::Verlet
                | IntegratorKind::Rattle
                | IntegratorKind::Rattle4
                | IntegratorKind::GaussLegendre
        )
    }
    /// Whether the method works on the constraints directly (through
    /// [`SecondOrderSystem::as_constrained`]) and so needs the implicit form.
    pub fn needs_constraints(self) -> bool {
        matches!(
            self,
            IntegratorKind::Rattle | IntegratorKind::Rattle4 | IntegratorKind::FastProjection
        )
    }
    /// Whether the method chooses its own steps (dopri5): the run loop then treats dt as the
    /// output interval and drives it through [`Dopri5::advance`] and its dense output.
    pub fn is_adaptive(self) -> bool {
        matches!(self, IntegratorKind::Dopri5)
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
        ) + match self {
            IntegratorKind::GaussLegendre => ", implicit stages",
            IntegratorKind::Rattle => ", implicit form only: constraints solved each step",
            IntegratorKind::Rattle4 => {
                ", implicit form only: rattle composed in Suzuki's 5 stages (5 rattle steps \
                 per step), constraints solved at each"
            }
            IntegratorKind::Dopri5 => ", adaptive: dt is the output interval, see --rtol, --atol",
            IntegratorKind::FastProjection => {
                ", implicit form only: step, then project onto the constraints; damps what dt \
                 cannot resolve (stiff cloth at frame-size steps)"
            }
            _ => "",
        }
    }
    /// A ready integrator for n coordinates with default [`IntegratorSettings`].
    pub fn build(self, n: usize) -> Box<dyn Integrator> {
        self.build_with(n, &IntegratorSettings::default())
    }
    /// A ready integrator for n coordinates.
    pub fn build_with(self, n: usize, settings: &IntegratorSettings) -> Box<dyn Integrator> {
        match self {
            IntegratorKind::Euler => Box::new(Euler::new(n)),
            IntegratorKind::SymplecticEuler => Box::new(SymplecticEuler::new(n)),
            IntegratorKind::Midpoint => Box::new(Midpoint::new(n)),
            IntegratorKind::Rk4 => Box::new(Rk4::new(n)),
            IntegratorKind::Verlet => Box::new(Verlet::with_settings(n, settings)),
            IntegratorKind::Rattle => Box::new(Rattle::with_settings(n, settings)),
            IntegratorKind::Rattle4 => Box::new(Composition::suzuki(
                Rattle::with_settings(n, settings).staged_in(IntegratorKind::Rattle4),
            )),
            IntegratorKind::GaussLegendre => Box::new(GaussLegendre::new(n, settings)),
            IntegratorKind::Dopri5 => Box::new(Dopri5::new(n, settings)),
            IntegratorKind::FastProjection => Box::new(FastProjection::with_settings(n, settings)),
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

/// The constraints of `system` for a method that works on them (`kind`, which
/// [`IntegratorKind::needs_constraints`]); [`StepError::NeedsConstraints`] naming the method
/// where the system has none to offer (the parametric form).
fn constraints_of(
    system: &mut dyn SecondOrderSystem,
    kind: IntegratorKind,
) -> Result<&mut dyn crate::formulation::ConstrainedSystem, StepError> {
    system
        .as_constrained()
        .ok_or_else(|| StepError::NeedsConstraints {
            what: kind.name().into(),
        })
}

/// y = x + h z, elementwise.
fn axpy_into(y: &mut [f64], x: &[f64], h: f64, z: &[f64]) {
    for ((y, x), z) in y.iter_mut().zip(x).zip(z) {
        *y = x + h * z;
    }
}

/// The state a step ended at, bit for bit (t, then q and qdot), as its driver retimed or
/// amended it ([`Integrator::continued`]): what a warm start (RATTLE's, fast projection's)
/// needs the next step to start from.
#[derive(Clone, Debug, Default)]
pub(crate) struct StepEnd {
    /// `None` until a step records its end, and from the check of the next step's start
    /// until that step records its own
    t: Option<f64>,
    /// q, then qdot (2n)
    state: Vec<f64>,
}

impl StepEnd {
    /// Whether `s` is bitwise the recorded end; forgets it either way, so that a step that
    /// fails leaves none.
    pub(crate) fn take_continued_by(&mut self, s: &State) -> bool {
        let n = s.q.len();
        self.t.take().is_some_and(|t| t.to_bits() == s.t.to_bits())
            && self.state.len() == 2 * n
            && crate::same_bits(&self.state[..n], &s.q)
            && crate::same_bits(&self.state[n..], &s.qdot)
    }

    /// The step ended at `s`.
    pub(crate) fn record(&mut self, s: &State) {
        let n = s.q.len();
        self.t = Some(s.t);
        self.state.resize(2 * n, 0.0);
        self.state[..n].copy_from_slice(&s.q);
        self.state[n..].copy_from_slice(&s.qdot);
    }

    /// [`Integrator::continued`]: the end recorded at `stepped` is now `state` (its time,
    /// and where `amended`, its other entries).
    pub(crate) fn continued(&mut self, stepped: f64, state: &State, amended: bool) {
        if self.t.is_some_and(|t| t.to_bits() == stepped.to_bits()) {
            if amended {
                self.record(state);
            } else {
                self.t = Some(state.t);
            }
        }
    }

    /// No end: the next step starts cold.
    pub(crate) fn forget(&mut self) {
        self.t = None;
    }
}
