//! `bead.Simulation`: a simulation stepped by hand from Python, whose state, forces and
//! parameters Python sets ([`Simulation::set_state`], [`Simulation::add_force`], a scene
//! with other parameters), and whose constraint forces it reads.

use std::sync::{Arc, Mutex};

use bead::model::{Force, ParticleId};
use bead::scene::Scene;
use bead::simulate::{Event, EventSpec, ForceId, PlacedState, RunError, Simulation, StateRequest};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1};
use pyo3::exceptions::{PyIndexError, PyTypeError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::{
    args, detached, event_error, particle_names, poisoned, run_error, scene_edit_error,
    setup_error, step_error, EventCrossings, Interrupt,
};

/// What a `bead.Simulation` holds behind its lock: the simulation, the scene it simulates
/// (with the parameters set since), and the forces applied from Python by particle.
pub(crate) struct Held {
    pub(crate) simulation: Simulation,
    pub(crate) scene: Arc<Scene>,
    applied: Vec<Applied>,
}

/// A force held on a particle by `apply_force`.
struct Applied {
    particle: usize,
    id: ForceId,
    vector: Vec<f64>,
}

impl Held {
    pub(crate) fn new(simulation: Simulation, scene: Arc<Scene>) -> Held {
        Held {
            simulation,
            scene,
            applied: Vec::new(),
        }
    }
}

/// A simulation to step by hand: `step()`, `advance_to(t)`, and the current state. Made by
/// `Scene.simulation()`. After an error it holds the last good state. The GIL is released
/// while it steps; calls from several threads take turns.
#[pyclass(frozen, module = "bead", name = "Simulation")]
pub struct PySimulation {
    inner: Mutex<Held>,
    particles: Vec<String>,
    dim: usize,
}

impl PySimulation {
    pub(crate) fn new(held: Held) -> PySimulation {
        PySimulation {
            particles: particle_names(&held.scene),
            dim: held.scene.system.dim(),
            inner: Mutex::new(held),
        }
    }

    /// Read the simulation (with the GIL held: nothing steps it meanwhile for long, since
    /// stepping happens with the lock taken only while detached).
    fn read<T>(&self, py: Python<'_>, f: impl FnOnce(&Simulation) -> T + Send) -> PyResult<T>
    where
        T: Send,
    {
        self.with_held(py, |held| f(&held.simulation))
    }

    /// Run `f` on what the lock holds, waiting for the lock with the GIL released (so that a
    /// thread stepping this simulation can re-attach), without stepping.
    fn with_held<T>(&self, py: Python<'_>, f: impl FnOnce(&mut Held) -> T + Send) -> PyResult<T>
    where
        T: Send,
    {
        let inner = &self.inner;
        let out = py.detach(|| inner.lock().map(|mut held| f(&mut held)).map_err(|_| ()));
        out.map_err(|_| poisoned())
    }

    /// Step the simulation with the GIL released.
    fn advance(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut Simulation) -> Result<(), RunError> + Send,
    ) -> PyResult<()> {
        let inner = &self.inner;
        let result = detached(py, move || match inner.lock() {
            Ok(mut held) => Ok(f(&mut held.simulation)),
            Err(_) => Err(()),
        })?;
        match result {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(run_error(py, &e, None)),
            Err(()) => Err(poisoned()),
        }
    }

    /// A (P, D) array of `values` (n_coords).
    fn matrix<'py>(&self, py: Python<'py>, values: Vec<f64>) -> PyResult<Bound<'py, PyAny>> {
        let shape = (values.len() / self.dim, self.dim);
        Ok(Array2::from_shape_vec(shape, values)
            .map_err(|e| PyValueError::new_err(e.to_string()))?
            .into_pyarray(py)
            .into_any())
    }

    /// The index of particle `particle` (its name, or its index in `particles`).
    fn event_arrays<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyList>, Bound<'py, PyList>)> {
        let crossings = self.read(py, |s| EventCrossings::of(s, s.event_count()))?;
        crossings.arrays(py)
    }

    fn particle_index(&self, particle: &Bound<'_, PyAny>) -> PyResult<usize> {
        if let Ok(name) = particle.extract::<String>() {
            return self
                .particles
                .iter()
                .position(|p| *p == name)
                .ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "no particle named '{name}'; the particles are {}",
                        self.particles.join(", ")
                    ))
                });
        }
        let count = self.particles.len() as u64;
        let index = args::integer_value(
            "particle",
            particle,
            0,
            count.saturating_sub(1),
            "a particle name or index",
        )
        .map_err(|_| {
            PyIndexError::new_err(format!(
                "particle={}: must be a particle name ({}) or an index 0..{}",
                args::shown(particle),
                self.particles.join(", "),
                count
            ))
        })?;
        Ok(index as usize)
    }
}

/// The numbers of `value` (a number, a sequence or an array of any shape, flattened) for
/// the argument `name`; `shape` says the shapes it accepts, in messages.
pub(crate) fn numbers(name: &str, value: &Bound<'_, PyAny>, shapes: &str) -> PyResult<Vec<f64>> {
    let py = value.py();
    let array = py
        .import("numpy")?
        .call_method1("asarray", (value, "float64"))
        .map_err(|_| {
            PyTypeError::new_err(format!(
                "{name}={}: must be numbers ({shapes})",
                args::shown(value)
            ))
        })?;
    let flat = array.call_method0("ravel")?;
    flat.call_method0("tolist")?.extract::<Vec<f64>>()
}

/// A state asked for from Python: arrays of any shape with the right count of numbers.
pub(crate) fn state_request(
    dim: usize,
    particles: usize,
    positions: Option<&Bound<'_, PyAny>>,
    velocities: Option<&Bound<'_, PyAny>>,
    q: Option<&Bound<'_, PyAny>>,
    qdot: Option<&Bound<'_, PyAny>>,
    t: Option<&Bound<'_, PyAny>>,
) -> PyResult<StateRequest> {
    let shape = format!(
        "a ({particles}, {dim}) array or {} numbers",
        particles * dim
    );
    let get = |name: &str, value: Option<&Bound<'_, PyAny>>, shapes: &str| {
        value
            .filter(|v| !v.is_none())
            .map(|v| numbers(name, v, shapes))
            .transpose()
    };
    Ok(StateRequest {
        t: t.filter(|v| !v.is_none())
            .map(|v| args::real_value("t", v, "a finite time (s)"))
            .transpose()?,
        positions: get("positions", positions, &shape)?,
        velocities: get("velocities", velocities, &shape)?,
        q: get("q", q, "one number per coordinate")?,
        qdot: get("qdot", qdot, "one number per coordinate")?,
    })
}

/// A `UserWarning` when the state placed is further from the one asked for than rounding
/// (1e-9 of the larger of 1 and the largest number asked for): what moved, and how far.
pub(crate) fn warn_placed(
    py: Python<'_>,
    what: &str,
    request: &StateRequest,
    placed: &PlacedState,
) -> PyResult<()> {
    let scale = |v: &Option<Vec<f64>>| {
        v.as_deref()
            .unwrap_or(&[])
            .iter()
            .fold(1.0_f64, |m, x| m.max(x.abs()))
    };
    let mut moved = Vec::new();
    if placed.position_moved > 1e-9 * scale(&request.positions) {
        moved.push(format!(
            "the positions by {} (onto the constraints, the closest point)",
            bead::significant(placed.position_moved, 6)
        ));
    }
    if placed.velocity_moved > 1e-9 * scale(&request.velocities) {
        moved.push(format!(
            "the velocities by {} (onto the constraints' tangent)",
            bead::significant(placed.velocity_moved, 6)
        ));
    }
    if moved.is_empty() {
        return Ok(());
    }
    let message = std::ffi::CString::new(format!("{what} moved {}", moved.join(" and ")))
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    PyErr::warn(py, &py.get_type::<PyUserWarning>(), &message, 1)
}

#[pymethods]
impl PySimulation {
    /// Take `count` steps (default 1): dt each for fixed-step integrators, one accepted step
    /// of its own size each for dopri5. Raises `bead.RunError` when a step fails.
    #[pyo3(signature = (count = None), text_signature = "($self, count=1)")]
    fn step(&self, py: Python<'_>, count: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let count = args::integer("count", count, 0, u64::MAX, "")?.unwrap_or(1);
        // Ctrl-C stops a long call between two steps, at a good state.
        let mut watch = Interrupt::new(py)?;
        let checking = &mut watch;
        self.advance(py, move |simulation| {
            for _ in 0..count {
                simulation.step()?;
                if checking.check() {
                    break;
                }
            }
            Ok(())
        })?;
        watch.error.map_or(Ok(()), Err)
    }

    /// Advance to exactly time `t` (not before the current time): steps of dt and, when `t`
    /// is not on the grid of steps, one shorter step to land on it. Ctrl-C stops it within a
    /// fraction of a second at the end of a step (KeyboardInterrupt); the simulation holds
    /// that state and can go on.
    fn advance_to(&self, py: Python<'_>, t: &Bound<'_, PyAny>) -> PyResult<()> {
        let t = args::real_value("t", t, "a finite time (s) >= the current time")?;
        let mut watch = Interrupt::new(py)?;
        let checking = &mut watch;
        let stepped = self.advance(py, move |simulation| {
            match simulation.advance_to_with(t, &mut || checking.check()) {
                Err(RunError::Interrupted { .. }) => Ok(()),
                other => other,
            }
        });
        match watch.error {
            Some(interrupt) => Err(interrupt),
            None => stepped,
        }
    }

    /// Back to the scene's initial state.
    fn reset(&self, py: Python<'_>) -> PyResult<()> {
        self.advance(py, |simulation| {
            simulation.reset();
            Ok(())
        })
    }

    /// Time of the current state (s).
    #[getter]
    fn t(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, Simulation::t)
    }

    /// Particle positions now, a (P, D) array (a copy).
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let values = self.read(py, |s| s.positions().to_vec())?;
        self.matrix(py, values)
    }

    /// Particle velocities now, a (P, D) array (a copy).
    #[getter]
    fn velocities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let values = self.read(py, |s| s.velocities().to_vec())?;
        self.matrix(py, values)
    }

    /// The formulation's coordinates now, a (K,) array: the particle coordinates for the
    /// implicit form, the generalized coordinates for the parametric one.
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let values = self.read(py, |s| s.q().to_vec())?;
        Ok(values.into_pyarray(py))
    }

    /// Their rates, a (K,) array.
    #[getter]
    fn qdot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let values = self.read(py, |s| s.qdot().to_vec())?;
        Ok(values.into_pyarray(py))
    }

    /// The switches of unilateral constraints so far (`side` in the scene), in time order:
    /// a list of dicts with `t`, `constraint` (its name), `kind` (`detach`, `land` or
    /// `bounce`), `normal_velocity` (s Cdot before and after: < 0 approaching), `dissipated`
    /// (the kinetic energy the impact took) and `positions` ((P, D) array).
    #[getter]
    fn contact_switches<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let switches = self.read(py, |s| s.contact_switches().to_vec())?;
        let list = PyList::empty(py);
        for switch in switches {
            let item = pyo3::types::PyDict::new(py);
            item.set_item("t", switch.t)?;
            item.set_item("constraint", switch.constraint)?;
            item.set_item("kind", switch.kind.name())?;
            item.set_item("normal_velocity", switch.normal_velocity)?;
            item.set_item("dissipated", switch.dissipated)?;
            item.set_item("positions", self.matrix(py, switch.x)?)?;
            list.append(item)?;
        }
        Ok(list)
    }

    /// Per unilateral constraint (in the scene's order), whether the particle is off it now
    /// (in flight); empty without unilateral constraints.
    #[getter]
    fn detached(&self, py: Python<'_>) -> PyResult<Vec<bool>> {
        self.read(py, Simulation::detached)
    }

    /// Total mechanical energy T + V now.
    #[getter]
    fn energy(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, Simulation::energy)
    }

    /// max_i |C_i| now, over the scene's implicit constraints (for both forms).
    #[getter]
    fn constraint_error(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, Simulation::constraint_error)
    }

    /// Integrator steps taken (accepted steps for dopri5).
    #[getter]
    fn steps(&self, py: Python<'_>) -> PyResult<u64> {
        self.read(py, Simulation::steps)
    }

    /// Newton iterations of every step so far (since the start or the last set_state, as
    /// `steps`) that solved onto the constraints: the integrator's own (rattle, rattle4,
    /// fast-projection) and `project=True`'s after every substep; None for the other
    /// integrators (with project=True: until the first projection). Divided by `steps`, the solver's work per step:
    /// substeps, retries and events' partial steps included. A run's summary and a sweep's
    /// `newton_iterations` give the same count.
    #[getter]
    fn newton_iterations(&self, py: Python<'_>) -> PyResult<Option<u64>> {
        self.read(py, Simulation::newton_iterations_total)
    }

    /// "implicit" or "parametric".
    #[getter]
    fn method(&self, py: Python<'_>) -> PyResult<&'static str> {
        self.read(py, |s| s.method().name())
    }

    /// The integrator's name.
    #[getter]
    fn integrator(&self, py: Python<'_>) -> PyResult<&'static str> {
        self.read(py, |s| s.integrator().name())
    }

    /// The step size (s).
    #[getter]
    fn dt(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, |s| s.config().dt)
    }

    /// Particle names, in the order of the rows of `positions`.
    #[getter]
    fn particles(&self) -> Vec<String> {
        self.particles.clone()
    }

    /// Names of the formulation's coordinates (the entries of `q`).
    #[getter]
    fn coordinates(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        self.read(py, |s| s.formulation().coordinate_names().to_vec())
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        self.read(py, |s| {
            format!(
                "<bead.Simulation {} {} dt={} at t={} after {} steps>",
                s.method().name(),
                s.integrator().name(),
                bead::readable(s.config().dt),
                bead::readable(s.t()),
                s.steps()
            )
        })
    }

    /// Set the state and start from it (MuJoCo's `qpos`/`qvel`, scipy's `y0`): `positions`
    /// and `velocities` ((P, D) arrays), or `q` and `qdot` (the formulation's coordinates:
    /// the parametric form's generalized coordinates, the implicit form's particle
    /// coordinates), and `t`; what is not given keeps its value. The state is put on the
    /// constraints (positions at the closest point, velocities along them), the same way for
    /// both forms; a `UserWarning` says how far when that moved it by more than rounding.
    /// The energy reference, the work and the step count restart there; forces applied stay.
    /// Raises ValueError (nothing changes) for a state that cannot be placed or started from.
    #[pyo3(signature = (*, positions = None, velocities = None, q = None, qdot = None, t = None))]
    fn set_state(
        &self,
        py: Python<'_>,
        positions: Option<&Bound<'_, PyAny>>,
        velocities: Option<&Bound<'_, PyAny>>,
        q: Option<&Bound<'_, PyAny>>,
        qdot: Option<&Bound<'_, PyAny>>,
        t: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let request = state_request(
            self.dim,
            self.particles.len(),
            positions,
            velocities,
            q,
            qdot,
            t,
        )?;
        let asked = request.clone();
        let placed = self
            .with_held(py, move |held| held.simulation.set_state(&asked))?
            .map_err(|e| PyValueError::new_err(format!("set_state: {e}")))?;
        warn_placed(py, "set_state", &request, &placed)
    }

    /// Apply the constant force `force` (D numbers, in the scene's units) to `particle` (a
    /// name or an index) from now on, held until changed (MuJoCo's `xfrc_applied`); `None`
    /// removes it. The energy ledger counts its work (`work`, `summary`), as for a drag in
    /// the viewer; while any force is applied, T + V is not conserved.
    fn apply_force(
        &self,
        py: Python<'_>,
        particle: &Bound<'_, PyAny>,
        force: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let p = self.particle_index(particle)?;
        let vector = if force.is_none() {
            None
        } else {
            let v = numbers("force", force, &format!("{} numbers", self.dim))?;
            if v.len() != self.dim {
                return Err(PyValueError::new_err(format!(
                    "force: needs {} numbers (the scene is {}D), got {}",
                    self.dim,
                    self.dim,
                    v.len()
                )));
            }
            if let Some(bad) = v.iter().find(|x| !x.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "force: must be finite numbers, got {bad}"
                )));
            }
            Some(v)
        };
        let result = self.with_held(py, move |held| -> Result<(), String> {
            let existing = held.applied.iter().position(|a| a.particle == p);
            match (vector, existing) {
                (None, Some(i)) => {
                    let applied = held.applied.remove(i);
                    held.simulation.remove_force(applied.id);
                }
                (None, None) => {}
                (Some(vector), Some(i)) => {
                    let force = Force::Constant {
                        particle: ParticleId(p),
                        vector: vector.clone(),
                    };
                    let id = held.applied[i].id;
                    held.simulation
                        .set_force(id, force)
                        .map_err(|e| e.to_string())?;
                    held.applied[i].vector = vector;
                }
                (Some(vector), None) => {
                    let force = Force::Constant {
                        particle: ParticleId(p),
                        vector: vector.clone(),
                    };
                    let id = held
                        .simulation
                        .add_force(force)
                        .map_err(|e| e.to_string())?;
                    held.applied.push(Applied {
                        particle: p,
                        id,
                        vector,
                    });
                }
            }
            Ok(())
        })?;
        result.map_err(|e| PyValueError::new_err(format!("apply_force: {e}")))
    }

    /// The forces applied with `apply_force`, by particle name.
    #[getter]
    fn applied_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let applied: Vec<(usize, Vec<f64>)> = self.with_held(py, |held| {
            held.applied
                .iter()
                .map(|a| (a.particle, a.vector.clone()))
                .collect()
        })?;
        let out = PyDict::new(py);
        for (p, vector) in applied {
            out.set_item(&self.particles[p], vector.into_pyarray(py))?;
        }
        Ok(out)
    }

    /// Set parameter `name` of the scene to `value` and go on from the current state: the
    /// scene's expressions follow it (as `Scene.with_params`), the simulation keeps its
    /// settings, time, state (placed on the constraints when they changed: a `UserWarning`
    /// says how far it moved), stop condition and applied forces. The energy reference
    /// restarts at the change (a new g changes the potential energy; that is not work), as
    /// do the step count and the work. Raises ValueError (nothing changes) for an unknown
    /// name or a value the scene cannot take.
    fn set_param(&self, py: Python<'_>, name: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let value = args::real_value(name, value, "a finite number")?;
        let name = name.to_string();
        let outcome = self.with_held(
            py,
            move |held| -> Result<(StateRequest, PlacedState), ChangeError> {
                let scene = held
                    .scene
                    .with_params(&[(name, value)])
                    .map_err(ChangeError::Edit)?;
                let old = &held.simulation;
                let config = *old.config();
                let mut simulation = Simulation::new(Arc::clone(&scene.system), config)
                    .map_err(ChangeError::Setup)?;
                let mut events = Vec::new();
                for spec in old.events() {
                    let source = spec.event.source();
                    let event = Event::parse(&scene.system, source)
                        .map_err(|e| ChangeError::Other(format!("the event `{source}`: {e}")))?;
                    events.push(EventSpec { event, ..spec });
                }
                simulation.set_events(events).map_err(ChangeError::Event)?;
                let request = match old.method() {
                    bead::formulation::Method::Parametric => StateRequest {
                        t: Some(old.t()),
                        q: Some(old.q().to_vec()),
                        qdot: Some(old.qdot().to_vec()),
                        ..Default::default()
                    },
                    bead::formulation::Method::Implicit => StateRequest {
                        t: Some(old.t()),
                        positions: Some(old.positions().to_vec()),
                        velocities: Some(old.velocities().to_vec()),
                        ..Default::default()
                    },
                };
                let mut applied = Vec::new();
                for a in &held.applied {
                    let force = Force::Constant {
                        particle: ParticleId(a.particle),
                        vector: a.vector.clone(),
                    };
                    let id = simulation
                        .add_force(force)
                        .map_err(|e| ChangeError::Other(e.to_string()))?;
                    applied.push(Applied {
                        particle: a.particle,
                        id,
                        vector: a.vector.clone(),
                    });
                }
                let placed = simulation
                    .set_state(&request)
                    .map_err(|e| ChangeError::Other(e.to_string()))?;
                simulation.prepend_crossings(old.crossings());
                held.simulation = simulation;
                held.scene = Arc::new(scene);
                held.applied = applied;
                Ok((request, placed))
            },
        )?;
        match outcome {
            Ok((request, placed)) => warn_placed(py, "set_param", &request, &placed),
            Err(ChangeError::Edit(e)) => Err(scene_edit_error(py, &e)),
            Err(ChangeError::Setup(e)) => Err(setup_error(py, &e)),
            Err(ChangeError::Event(e)) => Err(event_error(e)),
            Err(ChangeError::Other(e)) => Err(PyValueError::new_err(format!("set_param: {e}"))),
        }
    }

    /// Whether the last `step()` or `advance_to()` stopped early at a terminal event (then
    /// `t` is its crossing time, and `fired_event` says which).
    #[getter]
    fn event_fired(&self, py: Python<'_>) -> PyResult<bool> {
        self.read(py, |s| s.stopped_at_event())
    }

    /// The index (in the simulation's events: those given to `simulation(events=...)`, or the
    /// scene's `[[event]]` tables, then `stop_when`) of the terminal event that stopped the
    /// last `step()` or `advance_to()`, or None.
    #[getter]
    fn fired_event(&self, py: Python<'_>) -> PyResult<Option<usize>> {
        self.read(py, |s| s.fired_event())
    }

    /// The crossing times of each event since the start (or the last `set_state` or
    /// `reset`), up to now: a list with an array (k,) per event, as scipy's `t_events`.
    #[getter]
    fn t_events<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        self.event_arrays(py).map(|(t, _)| t)
    }

    /// The particle states at those crossings: a list with an array (k, 2 P D) per event,
    /// each row the positions then the velocities of every particle, flattened (scipy's
    /// `y_events`).
    #[getter]
    fn y_events<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        self.event_arrays(py).map(|(_, y)| y)
    }

    /// The scene's parameters now (after `set_param`).
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let params = self.with_held(py, |held| held.scene.params.clone())?;
        let out = PyDict::new(py);
        for (name, value) in params {
            out.set_item(name, value)?;
        }
        Ok(out)
    }

    /// The multiplier lambda of each implicit constraint row at the current state, an (m,)
    /// array (the force of row i on the particles is lambda_i grad C_i). The parametric form
    /// has no rows (its map holds the particles on the constraints): ValueError there; use
    /// `constraint_force_vectors`, defined for both forms.
    #[getter]
    fn constraint_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        if self.read(py, |s| s.method())? == bead::formulation::Method::Parametric {
            return Err(PyValueError::new_err(NO_MULTIPLIERS));
        }
        let forces = self
            .with_held(py, |held| held.simulation.constraint_forces())?
            .map_err(|e| step_error(py, &e))?;
        Ok(forces.multipliers.into_pyarray(py))
    }

    /// The total constraint force on each particle at the current state, a (P, D) array:
    /// J^T lambda for the implicit form, the map's reaction m a - F for the parametric one
    /// (the same force for the same state). External forces applied now are included in F.
    #[getter]
    fn constraint_force_vectors<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let forces = self
            .with_held(py, |held| held.simulation.constraint_forces())?
            .map_err(|e| step_error(py, &e))?;
        self.matrix(py, forces.force)
    }

    /// The work W done on T + V since the start by what does work (drag, driven
    /// constraints, applied forces): `energy - work` is conserved. 0 when nothing does.
    #[getter]
    fn work(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, Simulation::work)
    }

    /// T + V at the start (or at the last set_state, set_param or reset).
    #[getter]
    fn energy_initial(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, Simulation::energy_initial)
    }
}

/// Why `set_param` could not go on.
enum ChangeError {
    Edit(bead::scene::SceneEditError),
    Setup(bead::simulate::SetupError),
    Event(bead::simulate::EventError),
    Other(String),
}

/// What the parametric form says when asked for multipliers.
pub(crate) const NO_MULTIPLIERS: &str = "the parametric form has no constraint rows, so no multipliers: its map x(q) holds the particles on the constraints (its generalized constraint forces J^T F_c vanish: the constraint force does no virtual work); constraint_force_vectors gives the force the map exerts on each particle (m a - F)";
