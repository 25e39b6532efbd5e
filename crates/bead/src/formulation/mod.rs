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
mod contact;
mod fused;
mod gradients;
mod implicit;
mod parametric;
mod parametric_contact;

use std::fmt;
use std::sync::Arc;

pub use constrained::{ConstrainedSystem, ConstraintScales};
pub use contact::{Contact, Unilateral};
pub use fused::prepare as prepare_fused_accelerations;
pub use gradients::{Gradients, Observation, SingularSearch};
pub use implicit::{Feedback, Implicit};
pub(crate) use parametric::LaneScratch;
pub use parametric::Parametric;
pub use parametric_contact::ParametricContact;

use crate::model::{Force, System};

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

    /// A whole classic RK4 step with this system's acceleration compiled into it
    /// ([`crate::integrate::Rk4`]'s arithmetic as one tape), where the system has its
    /// acceleration as one tape (a small system under constant forces, see
    /// `formulation/fused.rs`): advance `state`'s q and qdot (not t) by dt. True when done,
    /// with the same bits as the integrator's own step; false, `state` untouched, when the
    /// system has no compiled step or a stage's matrix fails its pivot test: then the
    /// integrator steps as usual (and reports what the general path reports). The compiled
    /// step is built on first use (once per system and formulation; allocating then, never
    /// after). It evaluates none of the system's own accelerations: after it, what "the last
    /// evaluation" holds (multipliers, the power) is not at the step.
    fn compiled_rk4_step(&mut self, _state: &mut State, _dt: f64) -> bool {
        false
    }

    /// Whether [`Self::compiled_rk4_step`] applies (it may still decline a step whose pivot
    /// test fails).
    fn compiles_rk4_step(&self) -> bool {
        false
    }

    /// The monitors' observation at the end of the last [`Self::compiled_rk4_step`], when
    /// that step evaluated it and ended at exactly (t, q, qdot), bit for bit: the outputs of
    /// the form's observation tape there (the implicit form's C and J entries, the
    /// parametric form's x, xdot and map Jacobian entries). For a single run's express
    /// steps (`simulate::express`); the layout is internal.
    #[doc(hidden)]
    fn compiled_step_observation(&self, _t: f64, _q: &[f64], _qdot: &[f64]) -> Option<&[f64]> {
        None
    }

    /// [`Self::compiled_step_observation`] right after a [`Self::compiled_rk4_step`] that
    /// returned true, the state untouched since but for its time, set to t: only t is
    /// compared with the step's end (a single run's express steps).
    #[doc(hidden)]
    fn compiled_step_observation_after(&self, _t: f64) -> Option<&[f64]> {
        None
    }

    /// Take `steps` compiled RK4 steps back out of the evaluation count: steps a single
    /// run's express batch took past one that failed its checks, which the run never takes
    /// there (`simulate::express`).
    #[doc(hidden)]
    fn discount_compiled_steps(&mut self, _steps: u64) {}
}

/// What a [`StepError::ProjectionFailed`] suggests, given the substeps its step was last
/// tried in.
fn gave_up_hint(substeps: u32) -> String {
    match substeps {
        0 => " (reduce dt, or start nearer the constraints)".into(),
        1 => " in a step without substeps (allow substeps with max_substeps, `--max-substeps`, or reduce dt)".into(),
        n => format!(" in {n} substeps of the step, the most allowed (raise max_substeps, `--max-substeps`, or reduce dt)"),
    }
}

/// Why an acceleration could not be computed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    #[error("at t = {}: the constraints are singular at {constraint} (`{description}`): its gradient vanishes there or it duplicates other constraints", crate::readable(*t))]
    SingularConstraints {
        t: f64,
        constraint: String,
        description: String,
    },
    #[error("at t = {}: the mass matrix M(q) is singular in coordinate `{coordinate}`: the parametric map x(q) does not depend on it there", crate::readable(*t))]
    SingularMassMatrix { t: f64, coordinate: String },
    #[error("at t = {}: {quantity} is not finite", crate::readable(*t))]
    NonFinite { t: f64, quantity: String },
    #[error("at t = {}: {message}", crate::readable(*t))]
    Contact { t: f64, message: String },
    /// An iteration onto the constraints (`solve`: RATTLE's solve for its constraint
    /// forces, the fast projection's, `--project`'s) did not converge; `substeps` is how
    /// many the step was last tried in, as many as the simulation allowed (0: not from a
    /// simulation's step).
    #[error("at t = {}: {solve} did not converge: max |C| = {residual:e} after {iterations} iterations{}", crate::readable(*t), gave_up_hint(*substeps))]
    ProjectionFailed {
        t: f64,
        iterations: usize,
        residual: f64,
        solve: &'static str,
        substeps: u32,
    },
    #[error("{what} needs the implicit form; the parametric form has no constraints to project onto — use gauss-legendre or rk4")]
    NeedsConstraints { what: String },
    /// The fixed-point iteration of an integrator's implicit equations did not converge:
    /// gauss-legendre's stages, or the velocity half kick of verlet and rattle when the
    /// acceleration depends on the velocity.
    #[error("at t = {}: {method}: the implicit {equations} did not converge in {iterations} fixed-point iterations (last increment {residual:.3e} relative to the accelerations); reduce dt: the iteration converges when dt is small against the system's time scales", crate::readable(*t))]
    ImplicitStageFailed {
        /// The integrator, e.g. `gauss-legendre`.
        method: &'static str,
        /// Which equations, e.g. `stage equations`.
        equations: &'static str,
        t: f64,
        iterations: u32,
        residual: f64,
    },
    #[error("step size underflow at t = {}: the adaptive step fell to {h:.3e} s, below 1e-14 of the time scale (the system is too stiff or singular there, or the tolerances are too tight)", crate::readable(*t))]
    StepSizeUnderflow { t: f64, h: f64 },
    /// The motion reached, or is about to cross, a point where a constraint's gradient (or a
    /// column dx/dq of the parametric map) vanishes: a cusp or a self-crossing of the curve.
    #[error("{}", describe_singular_point(*t, subject, position, *kind, cause.as_deref()))]
    SingularPoint {
        t: f64,
        /// The constraint or coordinate that becomes singular.
        subject: Subject,
        /// Where: the coordinates it reads, by name, at the last good state.
        position: Vec<(String, f64)>,
        kind: SingularKind,
        /// What failed first, when the singular point was found as the cause of another
        /// failure (e.g. an implicit stage iteration that did not converge next to it).
        cause: Option<String>,
    },
    /// A constraint's gradient (or a column dx/dq) reversed direction within one step where
    /// the curve is regular: the step is too long for the curve's turn.
    #[error("{}", describe_step_too_long(*t, subject, position, *offset))]
    StepTooLong {
        t: f64,
        subject: Subject,
        /// The coordinates the row reads, by name, at the end of the rejected step.
        position: Vec<(String, f64)>,
        /// How far that state is off the constraint, |C| / |grad C|.
        offset: f64,
    },
}

fn describe_step_too_long(
    t: f64,
    subject: &Subject,
    position: &[(String, f64)],
    offset: f64,
) -> String {
    let what = match subject {
        Subject::Constraint { .. } => "its gradient",
        Subject::Coordinate { .. } => "dx/dq along it",
    };
    format!(
        "at t = {}: the step is too long for {subject}: {what} turned by more than 90 degrees within the step that ended at {}, {} off the constraint, with no point nearby where it vanishes (the curve is regular there; the step jumped across a turn it did not follow); reduce dt",
        crate::readable(t),
        describe_position(position),
        crate::readable(offset)
    )
}

/// `name = value`, or `(names) = (values)` for several coordinates.
fn describe_position(position: &[(String, f64)]) -> String {
    let names: Vec<&str> = position.iter().map(|(n, _)| n.as_str()).collect();
    let values: Vec<String> = position.iter().map(|(_, v)| crate::readable(*v)).collect();
    if position.len() == 1 {
        format!("{} = {}", names[0], values[0])
    } else {
        format!("({}) = ({})", names.join(", "), values.join(", "))
    }
}

/// What becomes singular: a constraint row of the implicit form or a generalized coordinate of
/// the parametric form.
#[derive(Clone, Debug, PartialEq)]
pub enum Subject {
    Constraint { name: String, description: String },
    Coordinate { name: String },
}

impl fmt::Display for Subject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Subject::Constraint { name, description } => write!(f, "{name} (`{description}`)"),
            Subject::Coordinate { name } => write!(f, "coordinate `{name}`"),
        }
    }
}

/// How a singular point showed itself (see `simulate`'s regularity monitor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SingularKind {
    /// The gradient has all but vanished: below 1e-2 of its largest length in this run, with a
    /// point where it vanishes confirmed on the curve nearby.
    Vanishes,
    /// The gradient reversed its direction within one step: the step crossed a point where
    /// it vanishes.
    Reverses,
    /// Extrapolated along the motion, the gradient vanishes within the next few steps (two
    /// for a step that was accepted, ten to explain one that failed).
    Ahead,
    /// The state is off the constraint by more than 1/100 of the distance to a point ahead
    /// where the gradient vanishes: near a crossing the level set through the state belongs
    /// to another branch of the curve.
    OffBranch,
    /// The gradient is exactly zero (or not finite) at the initial state.
    AtStart,
}

fn describe_singular_point(
    t: f64,
    subject: &Subject,
    position: &[(String, f64)],
    kind: SingularKind,
    cause: Option<&str>,
) -> String {
    let at = describe_position(position);
    let (what, how) = match subject {
        Subject::Constraint { .. } => ("its gradient", "a cusp or a crossing of the curve; the motion cannot be continued on this curve by the implicit form"),
        Subject::Coordinate { .. } => ("dx/dq along it", "a cusp of the parametrization, where the map stops depending on this coordinate; the motion cannot be continued through it"),
    };
    let happened = match kind {
        SingularKind::Vanishes => format!("{what} vanishes near {at}"),
        SingularKind::Reverses => format!("{what} reversed direction within the step that ended at {at}, so the step crossed a point where it vanishes"),
        SingularKind::Ahead => format!("{what} vanishes a few steps ahead of {at}"),
        SingularKind::OffBranch => format!("the state {at} is off the constraint by more than 1/100 of its distance to a point ahead where {what} vanishes, so it may follow another branch of the curve"),
        SingularKind::AtStart => format!("{what} is zero or not finite at the initial state {at}"),
    };
    let cause = cause
        .map(|c| format!(" (which is why the step failed: {c})"))
        .unwrap_or_default();
    format!(
        "at t = {}: {subject} is singular: {happened}: {how}{cause}",
        crate::readable(t)
    )
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
#[derive(Clone, Debug, Default, PartialEq)]
pub struct State {
    pub t: f64,
    /// q (n)
    pub q: Vec<f64>,
    /// qdot (n)
    pub qdot: Vec<f64>,
}

/// Why a formulation cannot be built.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FormulationError {
    #[error("the scene defines no parametric form (add a [parametric] table)")]
    NoParametricForm,
    #[error("constraint feedback (ks, kd) applies to the implicit form only: the parametric form stays on its constraints by construction")]
    FeedbackOnParametric,
    #[error("the parametric form simulates one unilateral constraint (`side`), and the scene has more: its map holds them all at once, and with some left it has no coordinates for the rest; use the implicit method")]
    UnilateralParametric,
}

/// Why the mechanical energy T + V of a formulation is not conserved: something does work on
/// it, which the energy ledger counts (see `simulate`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Nonconservation {
    /// A force without a potential, e.g. `drag on \`bead\``.
    Force(String),
    /// A constraint that depends on time (a driven or moving constraint), by name.
    DrivenConstraint(String),
    /// The parametric map x(q, t) depends on time.
    MovingMap,
    /// Forces applied from outside the system while it runs (e.g. dragging in the viewer).
    External,
    /// Impacts on a unilateral constraint, by name: a landing with restitution e < 1 (or a
    /// soft one that stays attached) takes kinetic energy away.
    Impacts(String),
}

impl fmt::Display for Nonconservation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Nonconservation::Force(force) => write!(f, "{force}"),
            Nonconservation::DrivenConstraint(name) => {
                write!(f, "driven constraint: {name} depends on t")
            }
            Nonconservation::MovingMap => {
                write!(f, "moving map: the parametric positions depend on t")
            }
            Nonconservation::External => write!(f, "external forces"),
            Nonconservation::Impacts(name) => write!(f, "impacts on {name} (unilateral)"),
        }
    }
}

/// What the run loop needs beyond the ODE.
pub trait Formulation: SecondOrderSystem {
    fn method(&self) -> Method;
    fn system(&self) -> &System;
    /// The system, shared: to build another formulation of it.
    fn shared_system(&self) -> Arc<System>;
    /// The state at t = 0.
    fn initial_state(&self) -> State;
    /// Names of the generalized coordinates, for parametric forms; empty for implicit.
    fn coordinate_names(&self) -> &[String];
    /// Particle positions x and velocities xdot (n_coords each) of state (t, q, qdot).
    fn particle_state(&mut self, t: f64, q: &[f64], qdot: &[f64], x: &mut [f64], xdot: &mut [f64]);

    /// Give back the scratch space of the full acceleration's evaluation (the constraint
    /// values, rates and gradients it keeps), sized again by the next evaluation that needs
    /// it: a run's setup evaluates the acceleration once to check its start, and an
    /// integrator that never does again (RATTLE) then keeps none. No result changes.
    fn release_evaluation_scratch(&mut self) {}

    /// Evaluations of the acceleration so far (full, or the applied forces alone for RATTLE's
    /// kicks; a compiled RK4 step counts its four): the work measure of convergence studies.
    fn evaluations(&self) -> u64 {
        0
    }

    /// Measure position tolerances (RATTLE, projections) row by row against `scales`, or
    /// absolutely with `None` (the default). Formulations without constraints ignore it.
    fn set_constraint_scales(&mut self, scales: Option<ConstraintScales>) {
        let _ = scales;
    }

    /// Forces applied from outside the system (e.g. a spring dragged with the mouse): added to
    /// the system's own forces in every evaluation and counted as non-conservative by the
    /// energy ledger. Changing them takes effect at the next evaluation; nothing is rebuilt.
    fn external_forces_mut(&mut self) -> &mut Vec<Force>;
    /// The forces applied from outside, see [`Formulation::external_forces_mut`].
    fn external_forces(&self) -> &[Force];

    /// P = dW/dt, the power of every force that does work on T + V, at the state of the last
    /// [`SecondOrderSystem::acceleration`] call, given that call's `q`, `qdot` and result
    /// `qddot`:
    ///
    /// ```text
    /// P = sum_k v_k (m_k a_k - F_cons,k) = F_nc . v + F_c . v
    /// ```
    /// with v, a the particle velocities and accelerations, F_nc the forces without a potential
    /// (drag, external forces) and F_c the constraint force (implicit: J^T lambda, including
    /// feedback; parametric: m a - F, which works only when the map moves). d(T + V)/dt = P
    /// holds exactly for the equations the integrator advances.
    fn power(&self, q: &[f64], qdot: &[f64], qddot: &[f64]) -> f64;
    /// The constraint forces at (t, q, qdot), from one evaluation of the acceleration there
    /// (into `qddot`, n): into `force` (n_coords) the total force the constraints put on each
    /// particle coordinate, into `multipliers` the multiplier of each implicit row.
    ///
    /// ```text
    /// implicit:    M a = F + J^T lambda,  F_c = J^T lambda   (feedback included)
    /// parametric:  a = J_map qddot + h,   F_c = M a - F      (the map's reaction)
    /// ```
    /// The parametric form has no rows (its map holds the particles on the constraints), so
    /// `multipliers` is left empty there; F_c is defined for both forms and agrees between
    /// them on the same state.
    fn constraint_forces(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        qddot: &mut [f64],
        multipliers: &mut Vec<f64>,
        force: &mut [f64],
    ) -> Result<(), StepError>;
    /// P of the applied forces only (no constraint force) at (q, qdot): what RATTLE's
    /// unconstrained kicks need beside the constraint impulses it handles itself.
    fn applied_power(&self, q: &[f64], qdot: &[f64]) -> f64;

    /// Why T + V is not conserved by this formulation; empty when it is.
    fn nonconservation(&self) -> Vec<Nonconservation>;

    /// A buffer for [`Formulation::observe`], sized for this formulation.
    fn new_observation(&self) -> Observation;
    /// What the monitors need about (t, q, qdot), from one evaluation: particle positions and
    /// velocities, the implicit constraints' values, and the vectors whose collapse makes this
    /// formulation singular (the gradient rows J_i of the implicit constraints with how far
    /// the state is off each, or the columns dx/dq_j of the parametric map). Allocation-free.
    fn observe(&mut self, t: f64, q: &[f64], qdot: &[f64], out: &mut Observation);

    /// [`Formulation::observe`] from the evaluation the last
    /// [`SecondOrderSystem::acceleration`] made, which the caller guarantees was at (t, q,
    /// qdot) (a simulation primes its integrator's first stage at a step's end, see
    /// [`crate::integrate::Integrator::prime`]): the same numbers, bit for bit, without a
    /// second evaluation. False when the formulation cannot (`out` untouched): call
    /// [`Formulation::observe`].
    fn observe_accelerated(
        &mut self,
        _t: f64,
        _q: &[f64],
        _qdot: &[f64],
        _out: &mut Observation,
    ) -> bool {
        false
    }
    /// What row `row` of [`Observation::gradients`] belongs to.
    fn gradient_subject(&self, row: usize) -> Subject;
    /// The coordinates row `row` reads, by name, with their values at q: the particle
    /// coordinates of a constraint row, or the generalized coordinate of a column.
    fn gradient_position(&self, row: usize, q: &[f64]) -> Vec<(String, f64)>;
    /// The variables a search for row `row`'s singular point moves, at q: the particle
    /// coordinates the constraint row reads (implicit), or all of q (parametric).
    fn row_variables(&self, row: usize, q: &[f64]) -> Vec<f64>;
    /// Look near q for a point where gradient row `row` vanishes (Gauss-Newton with exact
    /// second derivatives over [`Formulation::row_variables`]). A diagnostic, used before a
    /// run is stopped for a singular point; it allocates.
    fn locate_singular_point(&self, row: usize, t: f64, q: &[f64]) -> SingularSearch;
    /// The distance from `before` to `q` in row `row`'s variables ([`Formulation::row_variables`]),
    /// without allocating: how far a step moved what the row reads.
    fn row_step_length(&self, row: usize, q: &[f64], before: &[f64]) -> f64;
    /// Whether gradient row `row` can vanish nowhere on its constraint, so that it has no
    /// singular point to watch for: a rod of length L > 0 (|grad C| = sqrt(2) on C = 0; it
    /// vanishes only where the rod's ends meet, a distance L off the constraint) or a pin.
    fn row_never_singular(&self, row: usize) -> bool {
        let _ = row;
        false
    }
    /// A form with unilateral rows, whose rows switch between attached and detached
    /// ([`Contact`], [`ParametricContact`]; `None`, the default, for every other
    /// formulation).
    fn contact_mut(&mut self) -> Option<&mut dyn Unilateral> {
        None
    }
    /// [`Formulation::contact_mut`], to read.
    fn contact(&self) -> Option<&dyn Unilateral> {
        None
    }
    /// The system whose constraint rows the equations hold now: [`Formulation::system`],
    /// but for the implicit form with unilateral rows detached ([`Contact`]), the system
    /// without them.
    fn active_system(&self) -> &System {
        self.system()
    }
}

/// Build the formulation `method` of `system`.
pub fn formulate(
    system: Arc<System>,
    method: Method,
    feedback: Feedback,
) -> Result<Box<dyn Formulation + Send>, FormulationError> {
    match method {
        Method::Implicit if !system.unilateral().is_empty() => {
            Ok(Box::new(Contact::new(system, feedback)))
        }
        Method::Implicit => Ok(Box::new(Implicit::new(system, feedback))),
        Method::Parametric if !system.unilateral().is_empty() => {
            ParametricContact::new(system).map(|p| Box::new(p) as Box<dyn Formulation + Send>)
        }
        Method::Parametric => {
            if feedback != Feedback::default() {
                return Err(FormulationError::FeedbackOnParametric);
            }
            Parametric::new(system).map(|p| Box::new(p) as Box<dyn Formulation + Send>)
        }
    }
}
