//! States from outside and the constraint forces of a state.
//!
//! A state asked for ([`StateRequest`]: particle positions and velocities, or the parametric
//! form's q and qdot, and a time) is put on the constraints by [`place`], the same way for
//! both forms, so that an implicit and a parametric simulation started from one request start
//! from one state:
//!
//! ```text
//! positions asked:  x = the point of C(x, t) = 0 closest to them in the kinetic metric
//!                   (see `restart.rs`); q = the coordinates whose x(q, t) is closest to x
//! q asked:          q as given; x = x(q, t)
//! velocities asked: v = the mass-weighted projection onto J v + C_t = 0;
//!                   qdot = argmin |J_map qdot + dx/dt - v|_M (the same projection)
//! qdot asked:       qdot as given; v = J_map qdot + dx/dt
//! ```
//!
//! Parts not asked for keep their current value (velocities keep their particle values when
//! positions are asked for, and are placed again at the new positions). How far the placed
//! state lies from the one asked for is reported ([`PlacedState::position_moved`]): a
//! front end warns when that is more than rounding.
//!
//! The constraint forces of a state ([`Formulation::constraint_forces`]) come from one
//! evaluation of the acceleration there: J^T lambda in the implicit form, the map's reaction
//! M a - F in the parametric form.

use std::sync::Arc;

use super::restart::{self, closest_with, fit_coordinates, fit_rates, implicit_projector};
use super::{check_start, Monitor, RestartError, Simulation, SimulationConfig};
use crate::formulation::StepError;
use crate::formulation::{formulate, Feedback, Formulation, FormulationError, Method, State};
use crate::model::System;

/// A state asked for by [`Simulation::set_state`] or [`crate::scene::Scene::with_state`]:
/// each part that is `None` keeps its current value. `positions` and `velocities` are the
/// particles' (n_coords each: particle p, axis a at p * dim + a); `q` and `qdot` the
/// parametric form's coordinates and rates (for a simulation of the implicit form, its
/// coordinates: the particles'). A part may be given in one of the two ways, not both.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StateRequest {
    pub t: Option<f64>,
    pub positions: Option<Vec<f64>>,
    pub velocities: Option<Vec<f64>>,
    pub q: Option<Vec<f64>>,
    pub qdot: Option<Vec<f64>>,
}

impl StateRequest {
    /// Whether it asks for nothing.
    pub fn is_empty(&self) -> bool {
        *self == StateRequest::default()
    }
}

/// Where a requested state was put ([`Simulation::set_state`], `Scene::with_state`).
#[derive(Clone, Debug, PartialEq)]
pub struct PlacedState {
    pub t: f64,
    /// Particle positions and velocities (n_coords each), on the implicit constraints.
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    /// The parametric form's q and qdot, when the system has one.
    pub parametric: Option<(Vec<f64>, Vec<f64>)>,
    /// |x - x_asked| (Euclidean, over all coordinates): how far the positions asked for were
    /// moved onto the constraints (for a parametric start, x(q) against them); 0 when none
    /// were asked for.
    pub position_moved: f64,
    /// |v - v_asked| likewise for the velocities asked for.
    pub velocity_moved: f64,
}

/// Why a state cannot be set.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SetStateError {
    #[error("{what} need {expected} numbers, got {got}")]
    Length {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{what} must be finite numbers ({what}[{index}] is {value})")]
    NotFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("give {0}")]
    Conflict(&'static str),
    #[error("q and qdot are the parametric form's coordinates, and this scene has no [parametric] table; give positions and velocities")]
    NoParametricForm,
    #[error("{0}")]
    Placement(RestartError),
    #[error("the simulation cannot start from this state: {0}")]
    Start(StepError),
    #[error("a scene starts at t = 0; t = {0} can be set on a simulation (Simulation::set_state)")]
    StartTime(f64),
}

/// The state of a system that a request starts from: time, particle positions and velocities,
/// and the parametric form's q and qdot when there is one.
pub(crate) struct Current<'a> {
    pub t: f64,
    pub x: &'a [f64],
    pub v: &'a [f64],
    pub parametric: Option<(&'a [f64], &'a [f64])>,
}

/// Put `request` on the constraints of `system`, starting from `current` (see the module
/// documentation). `implicit` is the implicit form to project with when the caller has one
/// (else one is built when the system has constraint rows).
pub(crate) fn place(
    system: &Arc<System>,
    config: &SimulationConfig,
    implicit: Option<&mut dyn Formulation>,
    current: Current<'_>,
    request: &StateRequest,
) -> Result<PlacedState, SetStateError> {
    let n = system.n_coords();
    let map = system.parametric();
    let n_q = map.map_or(0, |m| m.n_q());
    check_part("t", request.t.as_slice(), 1)?;
    check_part("positions", request.positions.as_deref().unwrap_or(&[]), n)?;
    check_part(
        "velocities",
        request.velocities.as_deref().unwrap_or(&[]),
        n,
    )?;
    if request.q.is_some() || request.qdot.is_some() {
        if map.is_none() {
            return Err(SetStateError::NoParametricForm);
        }
        check_part("q", request.q.as_deref().unwrap_or(&[]), n_q)?;
        check_part("qdot", request.qdot.as_deref().unwrap_or(&[]), n_q)?;
    }
    if request.positions.is_some() && request.q.is_some() {
        return Err(SetStateError::Conflict(
            "either positions or q, not both: each says where the particles are",
        ));
    }
    if request.velocities.is_some() && request.qdot.is_some() {
        return Err(SetStateError::Conflict(
            "either velocities or qdot, not both: each says how the particles move",
        ));
    }
    let t = request.t.unwrap_or(current.t);
    let masses: Vec<f64> = system.inverse_mass().iter().map(|w| 1.0 / w).collect();
    let mut built;
    let mut projector: Option<&mut dyn Formulation> = match implicit {
        Some(f) => Some(f),
        None if system.constraints().n_rows() > 0 => {
            built =
                implicit_projector(Arc::clone(system), config).map_err(SetStateError::Placement)?;
            Some(&mut *built)
        }
        None => None,
    };
    let cartesian_positions = request.positions.is_some();
    // Positions: x on the constraints, q the map's coordinates there.
    let (x, q) = match (&request.q, map) {
        (Some(q), Some(map)) => (restart::map_positions(map, t, q), Some(q.clone())),
        _ => {
            let asked = request.positions.as_deref().unwrap_or(current.x);
            let x = match projector.as_deref_mut() {
                Some(f) => closest_with(f, t, asked, config).map_err(SetStateError::Placement)?,
                None => asked.to_vec(),
            };
            let q = match (map, current.parametric) {
                (Some(_), Some((q0, _))) if !cartesian_positions => Some(q0.to_vec()),
                (Some(map), current_q) => {
                    let mut seeds: Vec<&[f64]> = current_q.map(|(q, _)| q).into_iter().collect();
                    seeds.push(map.initial());
                    Some(
                        fit_coordinates(map, t, &seeds, &x, &masses)
                            .map_err(SetStateError::Placement)?,
                    )
                }
                (None, _) => None,
            };
            (x, q)
        }
    };
    // Velocities: v tangent to the constraints, qdot the map's rates.
    let (mut v, qdot) = match (&request.qdot, map, &q) {
        (Some(qdot), Some(map), Some(q)) => {
            let mut ws = map.workspace();
            map.observe(t, q, qdot, &mut ws);
            (ws.velocity, Some(qdot.clone()))
        }
        _ => {
            let asked = request.velocities.as_deref().unwrap_or(current.v).to_vec();
            let keep_rates = request.velocities.is_none() && !cartesian_positions;
            let qdot = match (map, &q, current.parametric) {
                (Some(_), Some(_), Some((_, r0))) if keep_rates => Some(r0.to_vec()),
                (Some(map), Some(q), _) => {
                    Some(fit_rates(map, t, q, &asked, &masses).map_err(SetStateError::Placement)?)
                }
                _ => None,
            };
            (asked, qdot)
        }
    };
    let mut x = x;
    match (projector, map, &q, &qdot) {
        (Some(f), _, _, _) => {
            if let Some(constrained) = f.as_constrained() {
                constrained
                    .project_velocities(t, &x, &mut v)
                    .map_err(|e| SetStateError::Placement(RestartError::Projection(e)))?;
            }
        }
        // Without constraint rows the map alone holds the particles: x = x(q), v = xdot.
        (None, Some(map), Some(q), Some(qdot)) => {
            let mut ws = map.workspace();
            map.observe(t, q, qdot, &mut ws);
            x = ws.position;
            v = ws.velocity;
        }
        _ => {}
    }
    let distance = |a: &[f64], b: &[f64]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt()
    };
    let position_moved = match &request.positions {
        Some(asked) => distance(&x, asked),
        None => 0.0,
    };
    let velocity_moved = match &request.velocities {
        Some(asked) => distance(&v, asked),
        None => 0.0,
    };
    Ok(PlacedState {
        t,
        positions: x,
        velocities: v,
        parametric: q.zip(qdot),
        position_moved,
        velocity_moved,
    })
}

/// [`place`] for a scene's start (t = 0), with the constraint tolerance a run uses by
/// default (relative, [`super::RELATIVE_CONSTRAINT_TOLERANCE`]).
pub(crate) fn place_start(
    system: &Arc<System>,
    current: Current<'_>,
    request: &StateRequest,
) -> Result<PlacedState, SetStateError> {
    let mut config = SimulationConfig::default();
    config.settings.constraint_tolerance = super::RELATIVE_CONSTRAINT_TOLERANCE;
    place(system, &config, None, current, request)
}

/// The most constraint rows times coordinates [`solve_holding`] takes (its matrices are
/// dense): a few thousand coordinates of a single-constraint system, or a chain of tens of
/// links.
const HOLDING_MAX_ENTRIES: usize = 1 << 16;

/// Put positions `x` and velocities `v` (n_coords each) on the constraints at time `t` with
/// the coordinates marked in `held_x` (and the velocity components in `held_v`) kept as
/// they are and the others moved least in the kinetic metric (what a sweep over `bead.x`
/// means on a curve: the bead at that x, on the curve). Gauss-Newton on the free
/// coordinates f, with W_f the inverse masses there:
///
/// ```text
/// x_f <- x_f - W_f J_f^T (J_f W_f J_f^T)^-1 C(x)          (to C = 0)
/// v_f <- v_f - W_f J_f^T (J_f W_f J_f^T)^-1 (J v + C_t)   (one step: it is linear)
/// ```
///
/// When J_f W_f J_f^T is singular (every coordinate a constraint reads is held) nothing is
/// solved: the placement that follows ([`place`]) puts such a start at the closest point.
/// An error when the iteration does not reach the constraints or the system is too large
/// for the dense matrices.
pub(crate) fn solve_holding(
    system: &System,
    t: f64,
    x: &mut [f64],
    v: &mut [f64],
    held_x: &[bool],
    held_v: &[bool],
) -> Result<(), String> {
    let set = system.constraints();
    let (m, n) = (set.n_rows(), system.n_coords());
    if m == 0 {
        return Ok(());
    }
    if m * n > HOLDING_MAX_ENTRIES {
        return Err(format!(
            "{m} constraint rows over {n} coordinates are too many to hold some coordinates \
             while placing the others; give every coordinate"
        ));
    }
    let w = system.inverse_mass();
    let mut ws = set.workspace();
    // A = J_f W_f J_f^T from J (dense, m x n); the correction -W_f J_f^T A^-1 r.
    let correct = |ws: &crate::model::ConstraintEval,
                   residual: &[f64],
                   held: &[bool],
                   values: &mut [f64]|
     -> Result<Option<f64>, String> {
        let mut jacobian = vec![0.0; m * n];
        for i in 0..m {
            for (&k, &jik) in set
                .row_columns(i)
                .iter()
                .zip(&ws.jacobian[set.row_entries(i)])
            {
                jacobian[i * n + k] = jik;
            }
        }
        let mut a = vec![0.0; m * m];
        for i in 0..m {
            for j in 0..m {
                a[i * m + j] = (0..n)
                    .filter(|&k| !held[k])
                    .map(|k| w[k] * jacobian[i * n + k] * jacobian[j * n + k])
                    .sum();
            }
        }
        let Some(lambda) = restart::solve_dense(a, residual.to_vec(), m) else {
            return Ok(None);
        };
        let mut moved: f64 = 0.0;
        for k in (0..n).filter(|&k| !held[k]) {
            let dk = w[k] * (0..m).map(|i| jacobian[i * n + k] * lambda[i]).sum::<f64>();
            values[k] -= dk;
            moved = moved.max(dk.abs());
        }
        Ok(Some(moved))
    };
    let scale = x.iter().fold(1.0_f64, |s, c| s.max(c.abs()));
    // Newton converges quadratically: a correction at rounding (1e-15 of the scale) ends it;
    // one that stalls a little above rounding after 50 iterations (an ill-conditioned
    // J_f W_f J_f^T) is accepted up to 1e-12 of the scale.
    let mut moved = f64::INFINITY;
    for _ in 0..50 {
        set.gradient(t, x, &mut ws);
        let residual = ws.value.clone();
        if residual.iter().any(|c| !c.is_finite()) {
            return Err("a constraint is not finite there".into());
        }
        match correct(&ws, &residual, held_x, x)? {
            Some(step) => moved = step,
            // Every coordinate a constraint reads is given: nothing to solve for here (the
            // placement after it moves the start to the closest point, if it is off).
            None => {
                moved = 0.0;
                break;
            }
        }
        if moved <= 1e-15 * scale {
            break;
        }
    }
    if moved.is_nan() || moved > 1e-12 * scale {
        return Err("the positions did not settle on the constraints in 50 iterations".into());
    }
    set.evaluate(t, x, v, &mut ws);
    let cdot = ws.velocity.clone();
    correct(&ws, &cdot, held_v, v)?;
    Ok(())
}

/// `values` has `expected` finite numbers (or none: the part was not asked for).
fn check_part(what: &'static str, values: &[f64], expected: usize) -> Result<(), SetStateError> {
    if values.is_empty() {
        return Ok(());
    }
    if values.len() != expected {
        return Err(SetStateError::Length {
            what,
            expected,
            got: values.len(),
        });
    }
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(SetStateError::NotFinite {
            what,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

/// The constraint forces of one state (see [`Formulation::constraint_forces`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ConstraintForces {
    /// lambda of each implicit row (empty for the parametric form, which has no rows).
    pub multipliers: Vec<f64>,
    /// The total constraint force on each particle coordinate (n_coords).
    pub force: Vec<f64>,
}

/// Evaluates the constraint forces of states of one system and form, e.g. of a recorded run.
pub struct ConstraintForceProbe {
    formulation: Box<dyn Formulation + Send>,
    qddot: Vec<f64>,
}

impl ConstraintForceProbe {
    /// A probe of `system` in form `method` with constraint feedback `feedback` (which the
    /// implicit form's J^T lambda includes).
    pub fn new(
        system: Arc<System>,
        method: Method,
        feedback: Feedback,
    ) -> Result<ConstraintForceProbe, FormulationError> {
        let formulation = formulate(system, method, feedback)?;
        let qddot = vec![0.0; formulation.n_coords()];
        Ok(ConstraintForceProbe { formulation, qddot })
    }

    /// The constraint forces at (t, q, qdot), the form's coordinates, into `out`.
    pub fn evaluate(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        out: &mut ConstraintForces,
    ) -> Result<(), StepError> {
        out.force.resize(self.formulation.system().n_coords(), 0.0);
        self.formulation.constraint_forces(
            t,
            q,
            qdot,
            &mut self.qddot,
            &mut out.multipliers,
            &mut out.force,
        )
    }
}

impl Simulation {
    /// Set the state (see [`StateRequest`]; for the implicit form `q` and `qdot` are the
    /// particle positions and velocities), placed on the constraints and their velocity
    /// constraint as the module documentation says, and start from it: the energy reference,
    /// the work, the step count and the statistics restart there; external forces stay. On
    /// error nothing changes. Returns where the state was put and how far that is from what
    /// was asked for.
    pub fn set_state(&mut self, request: &StateRequest) -> Result<PlacedState, SetStateError> {
        if self
            .formulation
            .contact()
            .is_some_and(|c| c.parametric_layout().is_some())
        {
            return Err(SetStateError::Conflict(
                "the state of the implicit form: the parametric form of a scene with a unilateral constraint cannot be set to a state yet",
            ));
        }
        let mut request = request.clone();
        let method = self.method();
        if method == Method::Implicit {
            if request.q.is_some() && request.positions.is_some() {
                return Err(SetStateError::Conflict(
                    "either positions or q (the implicit form's q are the positions), not both",
                ));
            }
            if request.qdot.is_some() && request.velocities.is_some() {
                return Err(SetStateError::Conflict(
                    "either velocities or qdot (the implicit form's qdot are the velocities), not both",
                ));
            }
            request.positions = request.positions.or(request.q.take());
            request.velocities = request.velocities.or(request.qdot.take());
        }
        let n = self.n;
        let t = self.t();
        let (x, v) = (self.positions().to_vec(), self.velocities().to_vec());
        let observed = self.observed().clone();
        let parametric =
            (method == Method::Parametric).then(|| (&observed.q[..n], &observed.qdot[..n]));
        let current = Current {
            t,
            x: &x,
            v: &v,
            parametric,
        };
        let system = self.formulation.shared_system();
        let config = self.config;
        // Unilateral rows the asked positions are off are not projected onto.
        let modes_before = match &request.positions {
            Some(asked) if asked.len() == x.len() => {
                let at = request.t.unwrap_or(t);
                super::contact::mode_for_positions(&mut *self.formulation, at, asked)
                    .map_err(SetStateError::Start)?
            }
            _ => Vec::new(),
        };
        let implicit = match method {
            Method::Implicit => Some(&mut *self.formulation as &mut dyn Formulation),
            Method::Parametric => None,
        };
        let restore_modes = |formulation: &mut dyn Formulation| {
            if let Some(contact) = formulation.contact_mut() {
                for (k, &d) in modes_before.iter().enumerate() {
                    // Back to modes it had (each built before): cannot fail.
                    let _ = contact.set_detached(k, d);
                }
            }
        };
        let placed = match place(&system, &config, implicit, current, &request) {
            Ok(placed) => placed,
            Err(e) => {
                restore_modes(&mut *self.formulation);
                return Err(e);
            }
        };
        let (q, qdot) = match (&placed.parametric, method) {
            (Some((q, qdot)), Method::Parametric) => (q.clone(), qdot.clone()),
            _ => (placed.positions.clone(), placed.velocities.clone()),
        };
        let mut state = State {
            t: placed.t,
            q,
            qdot,
        };
        if self.ledger.is_some() {
            state.q.push(0.0);
            state.qdot.push(0.0);
        }
        let monitor = Monitor::new(
            &mut *self.formulation,
            state.t,
            &state.q[..n],
            &state.qdot[..n],
        );
        if let Err(e) = check_start(&mut self.formulation, &mut self.ledger, n, &state, &monitor) {
            restore_modes(&mut *self.formulation);
            return Err(SetStateError::Start(e));
        }
        self.had_external = !self.external_ids.is_empty();
        self.refresh_nonconservation();
        self.start_from(state);
        Ok(placed)
    }

    /// The constraint forces at the current state (one evaluation of the acceleration
    /// there, with the external forces applied now): see [`Formulation::constraint_forces`].
    pub fn constraint_forces(&mut self) -> Result<ConstraintForces, StepError> {
        let n = self.n;
        let observed = self.observed().clone();
        let mut out = ConstraintForces {
            multipliers: Vec::new(),
            force: vec![0.0; self.system().n_coords()],
        };
        let mut qddot = vec![0.0; n];
        self.formulation.constraint_forces(
            observed.t,
            &observed.q[..n],
            &observed.qdot[..n],
            &mut qddot,
            &mut out.multipliers,
            &mut out.force,
        )?;
        Ok(out)
    }
}
