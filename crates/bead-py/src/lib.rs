//! `bead._bead`: the native half of the Python package `bead`. It drives the library's own
//! objects ([`bead::plan::Plan`], [`bead::simulate::Simulation`], [`bead::simulate::run`],
//! [`bead::output::Summary`]) and writes no physics of its own: it converts arguments into a
//! [`bead::plan::PlanRequest`], runs with the GIL released, and hands numpy arrays back to the
//! Python half (`python/bead`), which holds them in a `Run` and defines the exceptions.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bead::formulation::{Feedback, Method, StepError};
use bead::integrate::IntegratorKind;
use bead::output::{trace_header, Summary, Trajectory};
use bead::plan::{self, Plan, PlanError, PlanRequest};
use bead::scene::{Scene, SceneEditError, SceneError};
use bead::simulate::{
    self, ConstraintForceProbe, ConstraintForces, Direction, Event, EventError, EventSpec,
    RunError, RunFailure, RunStats, SetupError, Simulation, StateRequest,
};
use bead::sweep::{Axis, Combine, Member, Recording, Sweep, SweepError};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::{PyIndexError, PyTypeError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyString};

mod args;
mod simulation;
mod toml_text;

use simulation::PySimulation;

/// mimalloc for the extension's own (Rust) allocations, as the CLI: a sweep sets up and
/// drops thousands of simulations, which glibc's malloc frees and coalesces at ~16% of a
/// sweep's instructions. numpy's arrays keep Python's allocator; a Rust buffer handed to
/// numpy is freed by the allocator that made it.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Most bytes of arrays a run may record before it is refused: 8 GiB.
const MAX_RECORDED_BYTES: u64 = 8 << 30;

/// The native module `bead._bead`; the package `bead` re-exports what users need.
#[pymodule]
fn _bead(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(load, m)?)?;
    m.add_function(wrap_pyfunction!(loads, m)?)?;
    m.add_function(wrap_pyfunction!(_unpickle, m)?)?;
    m.add_function(wrap_pyfunction!(toml_text::_toml_value, m)?)?;
    m.add_class::<PyScene>()?;
    m.add_class::<PySimulation>()?;
    m.add_class::<PySweepPlan>()?;
    m.add_class::<ConstraintForceSource>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add(
        "INTEGRATORS",
        IntegratorKind::ALL
            .iter()
            .map(|k| k.name())
            .collect::<Vec<_>>(),
    )?;
    m.add("METHODS", ["implicit", "parametric"])?;
    // What a parametric run or simulation says when asked for multipliers (`Run` reads it).
    m.add("_NO_MULTIPLIERS", simulation::NO_MULTIPLIERS)?;
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Loading scenes

/// Load a scene file (TOML) and return a `Scene`.
///
/// `params` overrides values of the scene's `[params]` table, e.g. `{"g": 9.81}`; an unknown
/// name or a value that is not a finite number is an error. Raises `bead.SceneError` (a
/// `ValueError`) with `.path`, `.line`, `.column` and `.message` when the file cannot be read or
/// is not a valid scene; `str(error)` is the located message with the offending line and a
/// caret under it.
#[pyfunction]
#[pyo3(signature = (path, params = None))]
fn load(py: Python<'_>, path: PathBuf, params: Option<&Bound<'_, PyAny>>) -> PyResult<PyScene> {
    let overrides = overrides(params)?;
    let scene = py
        .detach(|| Scene::load(&path, &overrides))
        .map_err(|e| scene_error(py, &e))?;
    warn_scene(py, &scene)?;
    Ok(PyScene::new(scene))
}

/// Load a scene from TOML text and return a `Scene`.
///
/// `name` stands for the file in messages and in the summary's `scene` key. `params` and the
/// errors are as for `bead.load`.
#[pyfunction]
#[pyo3(signature = (text, params = None, name = "<string>"))]
fn loads(
    py: Python<'_>,
    text: &str,
    params: Option<&Bound<'_, PyAny>>,
    name: &str,
) -> PyResult<PyScene> {
    let overrides = overrides(params)?;
    let scene = Scene::parse(text, name, &overrides).map_err(|e| scene_error(py, &e))?;
    warn_scene(py, &scene)?;
    Ok(PyScene::new(scene))
}

/// A pickled `Scene` loaded again (`Scene.__reduce__`): as `loads`, without raising the
/// scene's warnings again, which were raised where it was first loaded.
#[pyfunction]
#[pyo3(signature = (text, params, name, start = None))]
fn _unpickle(
    py: Python<'_>,
    text: &str,
    params: &Bound<'_, PyAny>,
    name: &str,
    start: Option<&Bound<'_, PyAny>>,
) -> PyResult<PyScene> {
    let overrides = overrides(Some(params))?;
    let scene = Scene::parse(text, name, &overrides).map_err(|e| scene_error(py, &e))?;
    let scene = PyScene::new(scene);
    match start {
        Some(start) if !start.is_none() => {
            let started = scene.started(py, Some(start))?;
            Ok(PyScene { inner: started })
        }
        _ => Ok(scene),
    }
}

/// A start as asked for ([`Scene::with_state`]), as a dict of the parts given.
fn start_dict<'py>(py: Python<'py>, request: &StateRequest) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    for (key, part) in [
        ("positions", &request.positions),
        ("velocities", &request.velocities),
        ("q", &request.q),
        ("qdot", &request.qdot),
    ] {
        if let Some(values) = part {
            out.set_item(key, values.clone().into_pyarray(py))?;
        }
    }
    Ok(out)
}

/// Raise each of the scene's warnings (a start off a constraint, a parametric form that
/// starts elsewhere) as a `UserWarning` located at the scene file and line it is about, as
/// Python shows a warning of its own code. The warnings registry is the calling module's,
/// as for `warnings.warn`: under the default filter a warning is shown once per caller.
fn warn_scene(py: Python<'_>, scene: &Scene) -> PyResult<()> {
    let warnings = scene.located_warnings();
    if warnings.is_empty() {
        return Ok(());
    }
    let module = py.import("warnings")?;
    let category = py.get_type::<PyUserWarning>();
    // The frame that called this native function (a native call adds no frame); none when
    // called from outside any Python code.
    let registry = py
        .import("sys")?
        .call_method1("_getframe", (0,))
        .and_then(|frame| frame.getattr("f_globals"))
        .and_then(|globals| {
            globals.call_method1("setdefault", ("__warningregistry__", PyDict::new(py)))
        })
        .ok();
    for warning in warnings {
        let kwargs = PyDict::new(py);
        kwargs.set_item("registry", &registry)?;
        module.call_method(
            "warn_explicit",
            (
                warning.message,
                &category,
                &scene.file,
                warning.line.unwrap_or(1),
            ),
            Some(&kwargs),
        )?;
    }
    Ok(())
}

/// `params` as (name, value) pairs: any mapping of names to real numbers.
fn overrides(params: Option<&Bound<'_, PyAny>>) -> PyResult<Vec<(String, f64)>> {
    let Some(params) = params else {
        return Ok(Vec::new());
    };
    let items = params.call_method0("items").map_err(|_| {
        PyTypeError::new_err("params must be a mapping of parameter names to numbers")
    })?;
    let mut pairs = Vec::new();
    for item in items.try_iter()? {
        let (name, value): (Bound<'_, PyAny>, Bound<'_, PyAny>) = item?.extract()?;
        let name: String = name.extract().map_err(|_| {
            PyTypeError::new_err(format!("params: the name {name} is not a string"))
        })?;
        let number = args::real_value(&format!("params[{name:?}]"), &value, "a finite number")?;
        if !number.is_finite() {
            return Err(PyValueError::new_err(format!(
                "params[{name:?}]: {} is not a finite number",
                bead::readable(number)
            )));
        }
        pairs.push((name, number));
    }
    Ok(pairs)
}

// ---------------------------------------------------------------------------------------
// Scenes

/// A loaded scene: particles, constraints, forces, an optional parametric form and the `[run]`
/// defaults. Immutable; `run()` and `simulation()` may be called any number of times, from any
/// thread.
#[pyclass(frozen, module = "bead", name = "Scene")]
pub struct PyScene {
    inner: Arc<Scene>,
}

impl PyScene {
    /// This scene started from `initial` (a mapping with keys positions, velocities, q,
    /// qdot), or this scene itself.
    fn started(&self, py: Python<'_>, initial: Option<&Bound<'_, PyAny>>) -> PyResult<Arc<Scene>> {
        let Some(initial) = initial.filter(|i| !i.is_none()) else {
            return Ok(Arc::clone(&self.inner));
        };
        let mut parts: [Option<Bound<'_, PyAny>>; 4] = Default::default();
        let keys = ["positions", "velocities", "q", "qdot"];
        let items = initial.call_method0("items").map_err(|_| {
            PyTypeError::new_err(format!(
                "initial={}: must be a dict with keys among {}",
                args::shown(initial),
                keys.join(", ")
            ))
        })?;
        for item in items.try_iter()? {
            let (key, value): (String, Bound<'_, PyAny>) = item?.extract()?;
            let Some(k) = keys.iter().position(|k| *k == key) else {
                return Err(PyValueError::new_err(format!(
                    "initial: unknown key '{key}'; the keys are {}",
                    keys.join(", ")
                )));
            };
            parts[k] = Some(value);
        }
        let system = &self.inner.system;
        let [positions, velocities, q, qdot] = &parts;
        let request = simulation::state_request(
            system.dim(),
            system.particles().len(),
            positions.as_ref(),
            velocities.as_ref(),
            q.as_ref(),
            qdot.as_ref(),
            None,
        )?;
        Ok(Arc::new(self.placed(py, &request)?))
    }

    /// [`Scene::with_state`] with its warning and its error for Python.
    fn placed(&self, py: Python<'_>, request: &StateRequest) -> PyResult<Scene> {
        let (scene, placed) = self
            .inner
            .with_state(request)
            .map_err(|e| PyValueError::new_err(format!("with_state: {e}")))?;
        simulation::warn_placed(py, "with_state", request, &placed)?;
        Ok(scene)
    }

    fn new(scene: Scene) -> PyScene {
        PyScene {
            inner: Arc::new(scene),
        }
    }
}

/// The run options of `Scene.run`, `Scene.simulation` (without the run's length) and
/// `bead.sweep` (without `every`), as Python passed them: one conversion for all three.
#[derive(Default)]
struct Asked<'a, 'py> {
    method: Option<&'a str>,
    integrator: Option<&'a str>,
    dt: Option<&'a Bound<'py, PyAny>>,
    duration: Option<&'a Bound<'py, PyAny>>,
    steps: Option<&'a Bound<'py, PyAny>>,
    every: Option<&'a Bound<'py, PyAny>>,
    stabilize: Option<&'a Bound<'py, PyAny>>,
    rtol: Option<&'a Bound<'py, PyAny>>,
    atol: Option<&'a Bound<'py, PyAny>>,
    project: bool,
    substeps: Option<&'a Bound<'py, PyAny>>,
    max_substeps: Option<&'a Bound<'py, PyAny>>,
    event_samples: Option<&'a Bound<'py, PyAny>>,
}

impl Asked<'_, '_> {
    /// The plan request, every value converted with errors that name the argument and its
    /// range ([`args`]); the plan checks the ranges of the real numbers ([`Plan::resolve`]),
    /// in the same words.
    fn request(&self) -> PyResult<PlanRequest> {
        let method = self
            .method
            .map(|m| m.parse::<Method>().map_err(PyValueError::new_err))
            .transpose()?;
        let integrator = self
            .integrator
            .map(|i| i.parse::<IntegratorKind>().map_err(PyValueError::new_err))
            .transpose()?;
        let positive = "a finite number > 0";
        let substeps = |name, value| {
            args::integer(name, value, 1, u32::MAX.into(), "").map(|n| n.map(|n| n as u32))
        };
        Ok(PlanRequest {
            method,
            integrator,
            dt: args::real("dt", self.dt, positive)?,
            duration: args::real("duration", self.duration, positive)?,
            steps: args::integer("steps", self.steps, 1, args::MAX_STEPS, "")?,
            every: args::integer("every", self.every, 1, args::MAX_STEPS, "")?,
            stabilize: stabilize(self.stabilize)?,
            rtol: args::real("rtol", self.rtol, positive)?,
            atol: args::real("atol", self.atol, "a finite number >= 0")?,
            project: self.project,
            substeps: substeps("substeps", self.substeps)?,
            max_substeps: substeps("max_substeps", self.max_substeps)?,
            event_samples: args::integer(
                "event_samples",
                self.event_samples,
                0,
                bead::simulate::MAX_EVENT_SAMPLES as u64,
                "",
            )?
            .map(|k| k as u32),
        })
    }
}

/// `stabilize=(ks, kd)`: two real numbers (their range is checked by the plan).
fn stabilize(value: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Feedback>> {
    let Some(value) = value.filter(|v| !v.is_none()) else {
        return Ok(None);
    };
    let accepts = "two finite numbers >= 0, (ks, kd)";
    let pair: Option<(Bound<'_, PyAny>, Bound<'_, PyAny>)> = if value.is_instance_of::<PyString>() {
        None
    } else {
        value.extract().ok()
    };
    let Some((ks, kd)) = pair else {
        return Err(PyTypeError::new_err(format!(
            "stabilize={}: must be {accepts}",
            args::shown(value)
        )));
    };
    Ok(Some(Feedback {
        ks: args::real_value("stabilize[0] (ks)", &ks, "a finite number >= 0")?,
        kd: args::real_value("stabilize[1] (kd)", &kd, "a finite number >= 0")?,
    }))
}

/// The plan for `request`, warning when the scene's feedback is dropped for a parametric run
/// (the CLI's warning, as a Python `UserWarning`).
fn resolve(py: Python<'_>, scene: &Scene, request: &PlanRequest) -> PyResult<Plan> {
    let plan = Plan::resolve(scene, request).map_err(plan_error)?;
    if plan.ignores_scene_feedback(plan.method) {
        PyErr::warn(
            py,
            &py.get_type::<pyo3::exceptions::PyUserWarning>(),
            c"the scene's [run] stabilize applies only to the implicit form; not used for this parametric run",
            1,
        )?;
    }
    Ok(plan)
}

#[pymethods]
impl PyScene {
    /// The title, or the file stem when the scene has none.
    #[getter]
    fn title(&self) -> &str {
        &self.inner.title
    }

    /// The file name as given (or the `name` given to `bead.loads`).
    #[getter]
    fn file(&self) -> &str {
        &self.inner.file
    }

    /// Particle names, in scene order (the order of the P axis of positions and velocities).
    #[getter]
    fn particles(&self) -> Vec<String> {
        self.inner
            .system
            .particles()
            .iter()
            .map(|p| p.name.clone())
            .collect()
    }

    /// The dimension D: 2 or 3.
    #[getter]
    fn dimension(&self) -> usize {
        self.inner.system.dim()
    }

    /// The `[params]` values after overrides, in file order, as a new dict.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let dict = PyDict::new(py);
        for (name, value) in &self.inner.params {
            dict.set_item(name, value)?;
        }
        Ok(dict)
    }

    /// What the scene says about each parameter besides its value, in file order: a dict
    /// name -> {"value", "unit", "range" ((lo, hi) or None), "description", "integer",
    /// "derived" (the expression of a parameter computed from others, else None),
    /// "depends_on"} -- what a slider or a table of parameters shows.
    #[getter]
    fn param_info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for (name, value) in &self.inner.params {
            let spec = self.inner.param_specs.iter().find(|s| s.name == *name);
            let entry = PyDict::new(py);
            entry.set_item("value", value)?;
            entry.set_item("unit", spec.and_then(|s| s.unit.clone()))?;
            entry.set_item("range", spec.and_then(|s| s.range).map(|[lo, hi]| (lo, hi)))?;
            entry.set_item("description", spec.and_then(|s| s.description.clone()))?;
            entry.set_item("integer", spec.is_some_and(|s| s.integer))?;
            let derived = spec.filter(|s| !s.depends_on.is_empty());
            entry.set_item("derived", derived.and_then(|s| s.expr.clone()))?;
            entry.set_item(
                "depends_on",
                derived.map(|s| s.depends_on.clone()).unwrap_or_default(),
            )?;
            out.set_item(name, entry)?;
        }
        Ok(out)
    }

    /// The formulations the scene defines: "implicit" when it has a constraint or no
    /// parametric form, "parametric" when it has a parametric form.
    #[getter]
    fn methods(&self) -> Vec<&'static str> {
        plan::methods(&self.inner)
            .into_iter()
            .map(Method::name)
            .collect()
    }

    /// The method `run()` uses without `method=`: the scene's `[run]` method, else implicit
    /// when the scene has constraints or no parametric form, else parametric.
    #[getter]
    fn default_method(&self) -> &'static str {
        plan::run_method(&self.inner, None).name()
    }

    /// Names of the parametric form's generalized coordinates (the K axis of q and qdot);
    /// empty when the scene has no parametric form.
    #[getter]
    fn coordinates(&self) -> Vec<String> {
        match self.inner.system.parametric() {
            Some(map) => map.coordinates().to_vec(),
            None => Vec::new(),
        }
    }

    /// The number of implicit constraints.
    #[getter]
    fn constraint_count(&self) -> usize {
        self.inner.system.constraints().n_declared()
    }

    /// What the scene's `[run]` table sets (only the keys it sets).
    #[getter]
    fn run_defaults<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let run = &self.inner.run;
        let dict = PyDict::new(py);
        if let Some(m) = run.method {
            dict.set_item("method", m.name())?;
        }
        if let Some(i) = run.integrator {
            dict.set_item("integrator", i.name())?;
        }
        if let Some(dt) = run.dt {
            dict.set_item("dt", dt)?;
        }
        if let Some(d) = run.duration {
            dict.set_item("duration", d)?;
        }
        if let Some(s) = run.steps {
            dict.set_item("steps", s)?;
        }
        if let Some(f) = run.stabilize {
            dict.set_item("stabilize", (f.ks, f.kd))?;
        }
        Ok(dict)
    }

    /// Warnings about the scene (e.g. a parametric form that does not start where the
    /// particles do), as `bead check` prints them. Loading the scene raised each as a
    /// `UserWarning` at the scene file and line it is about; `repr(scene)` shows them.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner.warnings()
    }

    /// The scene text it was loaded from.
    #[getter]
    fn text(&self) -> &str {
        self.inner.text()
    }

    /// A copy of this scene with parameters replaced, e.g. `scene.with_params({"g": 1.62})`:
    /// the scene is loaded again from its text with these overrides on top of its own.
    fn with_params(&self, py: Python<'_>, params: &Bound<'_, PyAny>) -> PyResult<PyScene> {
        let values = overrides(Some(params))?;
        let scene = self
            .inner
            .with_params(&values)
            .map_err(|e| scene_edit_error(py, &e))?;
        warn_scene(py, &scene)?;
        Ok(PyScene::new(scene))
    }

    /// A copy of this scene started elsewhere, e.g. `scene.with_state(positions=[[100, -100]])`:
    /// `positions` and `velocities` ((P, D) arrays) or the parametric form's `q` and `qdot`;
    /// what is not given keeps the scene's value. The start is put on the constraints
    /// (positions at the closest point, velocities along them) and is the same for both
    /// forms: the particles' positions and velocities and `[parametric] initial` and
    /// `rates` all change (`scene.text` stays the file's). A `UserWarning` says how far
    /// the start moved when that is more than rounding. The start is kept by
    /// `with_params` (placed again) and by pickling. Raises ValueError when it cannot be
    /// placed.
    #[pyo3(signature = (*, positions = None, velocities = None, q = None, qdot = None))]
    fn with_state(
        &self,
        py: Python<'_>,
        positions: Option<&Bound<'_, PyAny>>,
        velocities: Option<&Bound<'_, PyAny>>,
        q: Option<&Bound<'_, PyAny>>,
        qdot: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyScene> {
        let system = &self.inner.system;
        let request = simulation::state_request(
            system.dim(),
            system.particles().len(),
            positions,
            velocities,
            q,
            qdot,
            None,
        )?;
        let scene = self.placed(py, &request)?;
        Ok(PyScene::new(scene))
    }

    /// A copy of this scene with a force added, as a `[[force]]` table of the scene file
    /// (see docs/scene-format.md): `with_force("drag", coefficient=0.5)` (on every particle,
    /// or `particle="bead"`), `with_force("constant", particle="bead", vector=[0, -2])`,
    /// `with_force("spring", between=["a", "b"], stiffness=10, rest_length=1)` or with
    /// `particle` and `anchor`. Numbers may be expressions of the parameters ("k/2"). The
    /// energy ledger counts the work of forces without a potential (drag). Raises
    /// bead.SceneError, located in the scene text with the table added after it.
    #[pyo3(signature = (kind, **keys))]
    fn with_force(
        &self,
        py: Python<'_>,
        kind: &Bound<'_, PyAny>,
        keys: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<PyScene> {
        let mut entries = vec![("kind".to_string(), kind.clone())];
        if let Some(keys) = keys {
            for (k, v) in keys.iter() {
                entries.push((k.extract::<String>()?, v));
            }
        }
        let table = toml_text::array_table("force", &entries)?;
        let scene = self
            .inner
            .with_tables(&table)
            .map_err(|e| scene_edit_error(py, &e))?;
        warn_scene(py, &scene)?;
        Ok(PyScene::new(scene))
    }

    /// A copy of this scene with an event added, as an `[[event]]` table of the scene file
    /// (see docs/scene-format.md and `bead.Event`): `expr` crossing zero in `direction` (1
    /// up, -1 down, 0 either), recorded (`t_events`) or, when `terminal`, ending the run.
    /// Runs, simulations and sweeps of the copy watch it. Raises bead.SceneError, located in
    /// the scene text with the table added after it.
    #[pyo3(signature = (expr, direction = None, terminal = None), text_signature = "($self, expr, direction=0, terminal=False)")]
    fn with_event(
        &self,
        py: Python<'_>,
        expr: &Bound<'_, PyAny>,
        direction: Option<&Bound<'_, PyAny>>,
        terminal: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyScene> {
        let mut entries = vec![("expr".to_string(), expr.clone())];
        if let Some(direction) = direction {
            entries.push(("direction".to_string(), direction.clone()));
        }
        if let Some(terminal) = terminal {
            entries.push(("terminal".to_string(), terminal.clone()));
        }
        let table = toml_text::array_table("event", &entries)?;
        let scene = self
            .inner
            .with_tables(&table)
            .map_err(|e| scene_edit_error(py, &e))?;
        Ok(PyScene::new(scene))
    }

    /// The start set with `with_state` (or `initial=`), as asked for: a dict of arrays, or
    /// None.
    #[getter]
    fn start<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner.start().map(|r| start_dict(py, r)).transpose()
    }

    /// Run the scene and return a `bead.Run` with its recorded states as numpy arrays.
    ///
    /// Every argument is optional and overrides the scene's `[run]` table, which overrides the
    /// defaults (as the `bead run` flags do): method ("implicit" or "parametric"), integrator
    /// (see `bead.INTEGRATORS`), dt (s, > 0), duration (s, > 0) or steps (>= 1), every (record
    /// every K-th step; the first and last states are always recorded), stabilize ((ks, kd),
    /// implicit form), rtol and atol (dopri5), project (implicit form), substeps and
    /// max_substeps, and stop_when (an expression of the particles' coordinates and
    /// velocities, t and params, e.g. "-bead.x": the run ends where it crosses zero upward,
    /// located to 1e-10 of dt; default: the scene's `[run] stop_when`), and event_samples
    /// (times inside each step at which stop_when is also sampled, 0 to 1024; default: the
    /// scene's `[run] event_samples`, else 4). A stop_when that is not a number (NaN), is infinite,
    /// or changes sign by a pole (-1/bead.x at x = 0) raises `bead.RunError`.
    ///
    /// Raises ValueError for a bad argument, `bead.SetupError` when the simulation cannot
    /// start (e.g. rattle on the parametric form), and `bead.RunError` (`bead.DivergenceError`
    /// when the state blew up) when a step fails, with the run up to the last good state as
    /// `.run`. The GIL is released while the run steps.
    #[pyo3(signature = (*, method = None, integrator = None, dt = None, duration = None, steps = None, every = None, stabilize = None, rtol = None, atol = None, project = false, substeps = None, max_substeps = None, stop_when = None, event_samples = None, initial = None, t_eval = None, events = None))]
    #[allow(clippy::too_many_arguments)]
    fn run(
        &self,
        py: Python<'_>,
        method: Option<&str>,
        integrator: Option<&str>,
        dt: Option<&Bound<'_, PyAny>>,
        duration: Option<&Bound<'_, PyAny>>,
        steps: Option<&Bound<'_, PyAny>>,
        every: Option<&Bound<'_, PyAny>>,
        stabilize: Option<&Bound<'_, PyAny>>,
        rtol: Option<&Bound<'_, PyAny>>,
        atol: Option<&Bound<'_, PyAny>>,
        project: bool,
        substeps: Option<&Bound<'_, PyAny>>,
        max_substeps: Option<&Bound<'_, PyAny>>,
        stop_when: Option<&str>,
        event_samples: Option<&Bound<'_, PyAny>>,
        initial: Option<&Bound<'_, PyAny>>,
        t_eval: Option<&Bound<'_, PyAny>>,
        events: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Py<PyAny>> {
        let scene = self.started(py, initial)?;
        let times = output_times(
            t_eval,
            [("duration", duration), ("steps", steps), ("every", every)],
        )?;
        let asked = Asked {
            method,
            integrator,
            dt,
            duration,
            steps,
            every,
            stabilize,
            rtol,
            atol,
            project,
            substeps,
            max_substeps,
            event_samples,
        };
        let mut request = asked.request()?;
        if times.is_some() {
            // t_eval sets where the run ends: one step keeps the scene's duration from being
            // checked against the step.
            request.steps = Some(1);
            request.duration = None;
        }
        let plan = resolve(py, &scene, &request)?;
        let events = watched_events(&scene, events, stop_when)?;
        run_plan(py, &scene, &plan, events, times)
    }

    /// A convergence study, as `bead order` runs it: each integrator (`integrators`, default
    /// every fixed-step one) with every form of the scene that accepts it, at dt, dt/2, ...,
    /// dt/2^halvings (dt, duration or steps: the scene's unless given), against dopri5 at
    /// `reference_rtol` (on the parametric form when the scene has one). Returns a dict of
    /// equal-length lists, one entry per run (`pandas.DataFrame(study["runs"])`): method,
    /// integrator, dt, steps, evaluations (of the acceleration), wall_seconds,
    /// position_error (max |x - x_ref| at the times of dt), energy_error (max |E - E0| /
    /// E_scale, of E - W when work is done), constraint_error (max |C_i| / |grad C_i|; NaN for
    /// the parametric form), and position_order, energy_order, constraint_order (log2 of the
    /// previous step's error over this one's; NaN at the first step, where an error is at
    /// its floor and after a failed step); with `floors` (the floors, a dict), `reference`
    /// (its form and steps) and `failures` ("method integrator" to a dict of each dt whose
    /// run failed to why: the series goes on at the finer steps).
    ///
    /// Raises ValueError for a bad argument (an adaptive integrator, a duration that is not a
    /// whole number of steps) and `bead.SetupError` when the reference cannot run. The GIL is
    /// released while the runs step.
    #[pyo3(signature = (*, integrators = None, dt = None, duration = None, steps = None, halvings = 4, reference_rtol = 1e-13))]
    #[allow(clippy::too_many_arguments)]
    fn order<'py>(
        &self,
        py: Python<'py>,
        integrators: Option<Vec<String>>,
        dt: Option<&Bound<'py, PyAny>>,
        duration: Option<&Bound<'py, PyAny>>,
        steps: Option<&Bound<'py, PyAny>>,
        halvings: u32,
        reference_rtol: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let scene = self.started(py, None)?;
        if !(1..=12).contains(&halvings) {
            return Err(PyValueError::new_err(format!(
                "halvings={halvings}: must be 1 to 12"
            )));
        }
        if !(reference_rtol.is_finite() && reference_rtol > 0.0) {
            return Err(PyValueError::new_err(format!(
                "reference_rtol={reference_rtol}: must be a finite number > 0"
            )));
        }
        let positive = "a finite number > 0";
        let request = PlanRequest {
            dt: args::real("dt", dt, positive)?,
            duration: args::real("duration", duration, positive)?,
            steps: args::integer("steps", steps, 1, args::MAX_STEPS, "")?,
            ..PlanRequest::default()
        };
        let plan = resolve(py, &scene, &request)?;
        if plan.last_step_shortened {
            return Err(PyValueError::new_err(format!(
                "the duration is not a whole number of steps of dt = {}: a convergence study compares the runs at the output times of dt; give steps, or a duration that is",
                bead::readable(plan.dt)
            )));
        }
        let kinds: Vec<IntegratorKind> = match integrators {
            None => IntegratorKind::ALL
                .into_iter()
                .filter(|k| !k.is_adaptive())
                .collect(),
            Some(names) => names
                .iter()
                .map(|name| {
                    name.parse::<IntegratorKind>()
                        .map_err(PyValueError::new_err)
                })
                .collect::<PyResult<_>>()?,
        };
        let mut cases = Vec::new();
        for method in bead::plan::methods(&scene) {
            for &kind in &kinds {
                if !(method == Method::Parametric && kind.needs_constraints()) {
                    cases.push((method, kind));
                }
            }
        }
        if cases.is_empty() {
            return Err(PyValueError::new_err(
                "integrators: none of them runs on this scene's forms (they need the implicit form)",
            ));
        }
        let settings = bead::convergence::StudySettings {
            dt: plan.dt,
            halvings,
            steps: plan.steps,
            reference_rtol,
        };
        let base = plan.config(Method::Implicit);
        let system = Arc::clone(&scene.system);
        let study = detached(py, move || {
            bead::convergence::study(&system, &cases, &settings, &base)
        })?
        .map_err(|e| match e {
            bead::convergence::StudyError::Reference { .. } => {
                python_error(py, "SetupError", (e.to_string(),))
            }
            other => PyValueError::new_err(other.to_string()),
        })?;
        study_dict(py, &study)
    }

    /// A `bead.Simulation` to step by hand (`step()`, `advance_to(t)`), at the scene's
    /// initial state. The arguments are those of `run()` without the run's length.
    #[pyo3(signature = (*, method = None, integrator = None, dt = None, stabilize = None, rtol = None, atol = None, project = false, substeps = None, max_substeps = None, stop_when = None, event_samples = None, initial = None, events = None))]
    #[allow(clippy::too_many_arguments)]
    fn simulation(
        &self,
        py: Python<'_>,
        method: Option<&str>,
        integrator: Option<&str>,
        dt: Option<&Bound<'_, PyAny>>,
        stabilize: Option<&Bound<'_, PyAny>>,
        rtol: Option<&Bound<'_, PyAny>>,
        atol: Option<&Bound<'_, PyAny>>,
        project: bool,
        substeps: Option<&Bound<'_, PyAny>>,
        max_substeps: Option<&Bound<'_, PyAny>>,
        stop_when: Option<&str>,
        event_samples: Option<&Bound<'_, PyAny>>,
        initial: Option<&Bound<'_, PyAny>>,
        events: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PySimulation> {
        let scene = self.started(py, initial)?;
        let asked = Asked {
            method,
            integrator,
            dt,
            stabilize,
            rtol,
            atol,
            project,
            substeps,
            max_substeps,
            event_samples,
            ..Asked::default()
        };
        // Only the step matters here: the scene's run length is not used, and a request for
        // one step keeps the scene's duration from being checked against the new dt.
        let mut request = asked.request()?;
        request.steps = Some(1);
        let plan = resolve(py, &scene, &request)?;
        let config = plan.config(plan.method);
        let system = Arc::clone(&scene.system);
        let events = watched_events(&scene, events, stop_when)?;
        let mut simulation = detached(py, move || Simulation::new(system, config))?
            .map_err(|e| setup_error(py, &e))?;
        simulation.set_events(events).map_err(event_error)?;
        Ok(PySimulation::new(simulation::Held::new(simulation, scene)))
    }

    /// Pickled as its text, file name and parameter overrides (loaded again as
    /// `bead.loads` does, without raising its warnings again), so that a scene can be sent to
    /// another process or machine.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let loads = py.import("bead._bead")?.getattr("_unpickle")?;
        let params = PyDict::new(py);
        for (name, value) in self.inner.overrides() {
            params.set_item(name, value)?;
        }
        let start = self.inner.start().map(|r| start_dict(py, r)).transpose()?;
        (loads, (self.inner.text(), params, &self.inner.file, start))
            .into_pyobject(py)
            .map(|t| t.into_any())
    }

    /// The title, the file, the counts, the methods and the warnings (the first three, with
    /// their lines).
    fn __repr__(&self) -> String {
        let scene = &self.inner;
        let warnings = scene.located_warnings();
        let mut shown: Vec<String> = warnings
            .iter()
            .take(3)
            .map(|w| match w.line {
                Some(line) => format!("line {line}: {}", w.message),
                None => w.message.clone(),
            })
            .collect();
        if warnings.len() > 3 {
            shown.push(format!("{} more in .warnings", warnings.len() - 3));
        }
        let warned = if warnings.is_empty() {
            String::new()
        } else {
            format!(
                "; {}: {}",
                counted(warnings.len(), "warning"),
                shown.join("; ")
            )
        };
        format!(
            "<bead.Scene {:?} from {:?}: {} in {}D, {}, methods {}{warned}>",
            scene.title,
            scene.file,
            counted(scene.system.particles().len(), "particle"),
            scene.system.dim(),
            counted(scene.system.constraints().n_declared(), "constraint"),
            self.methods().join(", ")
        )
    }
}

/// `n thing` or `n things`.
fn counted(n: usize, thing: &str) -> String {
    if n == 1 {
        format!("1 {thing}")
    } else {
        format!("{n} {thing}s")
    }
}

// ---------------------------------------------------------------------------------------
// Runs

/// The numbers in one recorded row: t, energy, constraint_error and work, the particles'
/// positions and velocities (`coordinates` each), q and qdot (`k` each).
#[derive(Clone, Copy)]
struct RowWidth {
    coordinates: usize,
    k: usize,
}

impl RowWidth {
    fn values(self) -> u64 {
        4 + 2 * self.coordinates as u64 + 2 * self.k as u64
    }
}

/// `t_eval` as times: numbers, finite, >= 0 and not decreasing; none of `excluded` (the
/// arguments that set a run's length or grid) given with it.
fn output_times<const N: usize>(
    t_eval: Option<&Bound<'_, PyAny>>,
    excluded: [(&str, Option<&Bound<'_, PyAny>>); N],
) -> PyResult<Option<Vec<f64>>> {
    let Some(t_eval) = t_eval.filter(|t| !t.is_none()) else {
        return Ok(None);
    };
    if let Some((name, _)) = excluded
        .iter()
        .find(|(_, v)| v.is_some_and(|v| !v.is_none()))
    {
        return Err(PyValueError::new_err(format!(
            "t_eval and {name}: give one; t_eval sets the times recorded and the run ends at the last"
        )));
    }
    let times = simulation::numbers("t_eval", t_eval, "a 1-D array of times")?;
    if times.is_empty() {
        return Err(PyValueError::new_err("t_eval: give at least one time"));
    }
    for (k, &t) in times.iter().enumerate() {
        if !(t.is_finite() && t >= 0.0) {
            return Err(PyValueError::new_err(format!(
                "t_eval[{k}] = {t}: times must be finite and >= 0 (a run starts at t = 0)"
            )));
        }
        if k > 0 && t < times[k - 1] {
            return Err(PyValueError::new_err(format!(
                "t_eval[{k}] = {t} is before t_eval[{}] = {}: the times must not decrease",
                k - 1,
                times[k - 1]
            )));
        }
    }
    Ok(Some(times))
}

/// The most rows `plan` can record: the first state, every `every`-th, the last (or the
/// last good one); refused with what it would take and how to take less when their arrays
/// would pass [`MAX_RECORDED_BYTES`]. The arrays are the whole of the memory a run's
/// recording takes at its peak: the recorder's vectors become the numpy arrays without a
/// copy ([`build_run`]).
fn record_guard(plan: &Plan, width: RowWidth) -> PyResult<u64> {
    let rows = plan.steps / plan.every + 2;
    let per_row = width.values();
    let bytes = (rows as f64) * (per_row as f64) * 8.0;
    if bytes <= MAX_RECORDED_BYTES as f64 {
        return Ok(rows);
    }
    // The smallest every=K whose rows fit, when one does: steps / K + 2 rows fit when
    // steps / K <= n, i.e. K > steps / (n + 1).
    let fitting_rows = MAX_RECORDED_BYTES / 8 / per_row;
    let every = match fitting_rows.checked_sub(2) {
        None => String::new(),
        Some(n) => format!(" (every={} or more fits)", plan.steps / (n + 1) + 1),
    };
    Err(PyValueError::new_err(format!(
        "this run would record {rows} states of {per_row} numbers, {} bytes ({} GB) of arrays, \
         more than the {MAX_RECORDED_BYTES} bytes (8 GiB) a run may record; record every K-th \
         state with every=K{every}, or run a shorter duration (fewer steps)",
        bead::readable(bytes),
        bead::significant(bytes * 1e-9, 3)
    )))
}

/// What a run left: the recorded rows, the outcome and its summary.
struct Finished {
    recorder: Trajectory,
    result: Result<RunStats, RunFailure>,
    summary: Summary,
    crossings: EventCrossings,
    coordinates: Vec<String>,
    tracks_work: bool,
}

/// The crossings of a run's (or a simulation's) events, by event: scipy's `t_events` and
/// `y_events`.
pub(crate) struct EventCrossings {
    /// Per event: the times, and the particle states there (positions, then velocities).
    times: Vec<Vec<f64>>,
    states: Vec<Vec<f64>>,
    width: usize,
}

impl EventCrossings {
    pub(crate) fn of(simulation: &Simulation, n_events: usize) -> EventCrossings {
        let width = 2 * simulation.system().n_coords();
        let mut times = vec![Vec::new(); n_events];
        let mut states = vec![Vec::new(); n_events];
        for c in simulation.crossings() {
            if c.event < n_events {
                times[c.event].push(c.t);
                states[c.event].extend_from_slice(&c.x);
                states[c.event].extend_from_slice(&c.xdot);
            }
        }
        EventCrossings {
            times,
            states,
            width,
        }
    }

    /// Lists of numpy arrays: the times (k,) and the states (k, 2 P D) of each event.
    pub(crate) fn arrays<'py>(
        self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyList>, Bound<'py, PyList>)> {
        let t_events = PyList::empty(py);
        let y_events = PyList::empty(py);
        for (times, states) in self.times.into_iter().zip(self.states) {
            let k = times.len();
            t_events.append(times.into_pyarray(py))?;
            let states = Array2::from_shape_vec((k, self.width), states)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            y_events.append(states.into_pyarray(py))?;
        }
        Ok((t_events, y_events))
    }
}

/// The stop condition of a run: `stop_when`, parsed against the scene's system (a bad one is
/// a ValueError showing where in the expression), else the scene's `[run] stop_when`, else
/// none: as `bead run --stop-when` resolves it.
fn stop_event(scene: &Scene, stop_when: Option<&str>) -> PyResult<Option<Event>> {
    match stop_when {
        None => Ok(scene.run.stop_when.clone()),
        Some(source) => parse_event(scene, source, "stop_when").map(Some),
    }
}

/// `source` parsed as an event of `scene`'s system; a ValueError starting with `label` shows
/// where in the expression it fails.
fn parse_event(scene: &Scene, source: &str, label: &str) -> PyResult<Event> {
    Event::parse(&scene.system, source).map_err(|e| {
        let start = source[..e.span.start.min(source.len())].chars().count();
        let width = source
            .get(e.span.start..e.span.end.max(e.span.start))
            .map_or(1, |s| s.chars().count().max(1));
        PyValueError::new_err(format!(
            "{label}: {}\n  {source}\n  {}{}",
            e.message,
            " ".repeat(start),
            "^".repeat(width)
        ))
    })
}

/// The events a run watches: `events` (each a `bead.Event`, or an expression string: a
/// non-terminal event of either direction), else the scene's `[[event]]` tables; then the
/// stop condition (`stop_when`, else the scene's), a terminal upward event.
pub(crate) fn watched_events(
    scene: &Scene,
    events: Option<&Bound<'_, PyAny>>,
    stop_when: Option<&str>,
) -> PyResult<Vec<EventSpec>> {
    let stop = stop_event(scene, stop_when)?;
    let Some(events) = events.filter(|e| !e.is_none()) else {
        return Ok(scene.run.events_with(stop));
    };
    if events.is_instance_of::<PyString>() {
        return Err(PyTypeError::new_err(
            "events: expected a list of bead.Event (or expression strings), got a string; \
             write events=[...]",
        ));
    }
    let mut specs = Vec::new();
    for (i, item) in events.try_iter()?.enumerate() {
        let item = item?;
        let label = format!("events[{i}]");
        let spec = if let Ok(source) = item.extract::<String>() {
            EventSpec {
                event: parse_event(scene, &source, &label)?,
                direction: Direction::Either,
                terminal: false,
                stop_when: false,
            }
        } else {
            let attribute = |name: &str| {
                item.getattr(name).map_err(|_| {
                    PyTypeError::new_err(format!(
                        "{label}: expected a bead.Event or an expression string, got {}",
                        item.get_type()
                            .name()
                            .map_or("an object".to_string(), |n| n.to_string())
                    ))
                })
            };
            let source: String = attribute("expr")?.extract()?;
            let sign: f64 = attribute("direction")?.extract()?;
            let terminal: bool = attribute("terminal")?.extract()?;
            let direction = Direction::from_sign(sign).ok_or_else(|| {
                PyValueError::new_err(format!("{label}: direction must be 1, -1 or 0"))
            })?;
            EventSpec {
                event: parse_event(scene, &source, &label)?,
                direction,
                terminal,
                stop_when: false,
            }
        };
        specs.push(spec);
    }
    specs.extend(stop.map(EventSpec::stop));
    Ok(specs)
}

/// A stop condition that does not fit the run (generalized coordinates on the implicit form).
pub(crate) fn event_error(e: EventError) -> PyErr {
    PyValueError::new_err(format!("events: {e}"))
}

/// Why a run could not start.
enum StartError {
    Setup(SetupError),
    Event(EventError),
    /// Not a start error: Ctrl-C (or another signal whose handler raised) during the run.
    Interrupted(PyErr),
}

/// Ctrl-C while a run goes on with the GIL released: every few steps, at most every 20 ms of
/// wall time, the run's thread takes the GIL back for a moment and lets Python run its
/// signal handlers (`PyErr_CheckSignals`); when one raises (KeyboardInterrupt), the run
/// stops there ([`simulate::Progress::interrupted`]) and the exception is raised once the
/// run has let go. Only on the main thread, the only one where Python runs signal handlers.
pub(crate) struct Interrupt {
    watch: bool,
    countdown: u32,
    last: Instant,
    error: Option<PyErr>,
}

impl Interrupt {
    /// Steps between two looks at the clock.
    const EVERY: u32 = 16;

    fn new(py: Python<'_>) -> PyResult<Interrupt> {
        let threading = py.import("threading")?;
        let main = threading
            .call_method0("current_thread")?
            .is(&threading.call_method0("main_thread")?);
        Ok(Interrupt {
            watch: main,
            countdown: Self::EVERY,
            last: Instant::now(),
            error: None,
        })
    }

    /// Whether a signal handler raised (then `error` holds its exception).
    fn check(&mut self) -> bool {
        if self.error.is_some() {
            return true;
        }
        if !self.watch {
            return false;
        }
        self.countdown -= 1;
        if self.countdown > 0 {
            return false;
        }
        self.countdown = Self::EVERY;
        if self.last.elapsed() < Duration::from_millis(20) {
            return false;
        }
        self.last = Instant::now();
        if let Err(e) = Python::attach(|py| py.check_signals()) {
            self.error = Some(e);
        }
        self.error.is_some()
    }
}

impl simulate::Progress for Interrupt {
    fn advance(&mut self, _: u64, _: u64) {}

    fn interrupted(&mut self) -> bool {
        self.check()
    }
}

/// Run `plan` on `scene` with the GIL released, and build the Python `Run` (or raise the
/// `RunError` that carries it).
fn run_plan(
    py: Python<'_>,
    scene: &Arc<Scene>,
    plan: &Plan,
    events: Vec<EventSpec>,
    times: Option<Vec<f64>>,
) -> PyResult<Py<PyAny>> {
    let system = &scene.system;
    let coordinates = system.n_coords();
    let k = match plan.method {
        Method::Parametric => system.parametric().map_or(0, |m| m.n_q()),
        Method::Implicit => coordinates,
    };
    let width = RowWidth { coordinates, k };
    let rows = match &times {
        Some(times) => times.len() as u64,
        None => record_guard(plan, width)?,
    };
    let config = plan.config(plan.method);
    let options = plan.options();
    let shared = Arc::clone(scene);
    let mut watch = Interrupt::new(py)?;
    let finished = detached(py, move || -> Result<Finished, StartError> {
        let mut simulation =
            Simulation::new(Arc::clone(&shared.system), config).map_err(StartError::Setup)?;
        let n_events = events.len();
        simulation.set_events(events).map_err(StartError::Event)?;
        let coordinates = simulation.formulation().coordinate_names().to_vec();
        let tracks_work = simulation.tracks_work();
        let mut recorder = Trajectory::with_room(rows, width.coordinates, width.k, tracks_work);
        let result = match &times {
            Some(times) => {
                simulate::run_at_times(&mut simulation, times, &mut recorder, &mut watch)
            }
            None => {
                simulate::run_with_progress(&mut simulation, options, &mut recorder, &mut watch)
            }
        };
        if let Some(interrupt) = watch.error {
            return Err(StartError::Interrupted(interrupt));
        }
        let summary = Summary::from_result(&shared.file, &shared.system, &coordinates, &result);
        Ok(Finished {
            recorder,
            result,
            summary,
            crossings: EventCrossings::of(&simulation, n_events),
            coordinates,
            // The ledger may have started during the run (external forces); the rows say.
            tracks_work: tracks_work || simulation.tracks_work(),
        })
    })?
    .map_err(|e| match e {
        StartError::Setup(e) => setup_error(py, &e),
        StartError::Event(e) => event_error(e),
        StartError::Interrupted(e) => e,
    })?;
    let Finished {
        recorder,
        result,
        summary,
        crossings,
        coordinates,
        tracks_work,
    } = finished;
    let source = ConstraintForceSource {
        system: Arc::clone(&scene.system),
        method: plan.method,
        feedback: config.feedback,
    };
    let run = build_run(
        py,
        scene,
        recorder,
        &summary,
        &coordinates,
        tracks_work,
        source,
    )?;
    let (t_events, y_events) = crossings.arrays(py)?;
    run.bind(py).setattr("t_events", t_events)?;
    run.bind(py).setattr("y_events", y_events)?;
    match result {
        Ok(_) => Ok(run),
        Err(failure) => Err(run_error(py, &failure.error, Some(run))),
    }
}

/// The Python `bead.Run` holding the recorded rows as numpy arrays, each made from the
/// recorder's vector without a copy (numpy's array owns the Rust buffer).
fn build_run(
    py: Python<'_>,
    scene: &Scene,
    recorder: Trajectory,
    summary: &Summary,
    coordinates: &[String],
    tracks_work: bool,
    source: ConstraintForceSource,
) -> PyResult<Py<PyAny>> {
    let system = &scene.system;
    let (p, d) = (system.particles().len(), system.dim());
    let rows = recorder.t.len();
    let k = recorder.q.len().checked_div(rows).unwrap_or(0);
    let shape_error = |e: numpy::ndarray::ShapeError| PyValueError::new_err(e.to_string());
    let Trajectory {
        t,
        x,
        xdot,
        energy,
        constraint_error,
        q,
        qdot,
        work,
        ..
    } = recorder;
    // A run that stopped early leaves room it did not use: give it back (in place for the
    // large buffers, which the allocator maps on their own) before numpy owns them.
    let exact = |mut v: Vec<f64>| {
        v.shrink_to_fit();
        v
    };
    let has_work = tracks_work && work.len() == rows;
    let kwargs = PyDict::new(py);
    kwargs.set_item("t", exact(t).into_pyarray(py))?;
    for (key, values) in [("positions", x), ("velocities", xdot)] {
        let array = Array3::from_shape_vec((rows, p, d), exact(values)).map_err(shape_error)?;
        kwargs.set_item(key, array.into_pyarray(py))?;
    }
    kwargs.set_item("energy", exact(energy).into_pyarray(py))?;
    kwargs.set_item("constraint_error", exact(constraint_error).into_pyarray(py))?;
    for (key, values) in [("q", q), ("qdot", qdot)] {
        let array = Array2::from_shape_vec((rows, k), exact(values)).map_err(shape_error)?;
        kwargs.set_item(key, array.into_pyarray(py))?;
    }
    kwargs.set_item("work", has_work.then(|| exact(work).into_pyarray(py)))?;
    let json = summary
        .to_json_pretty()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let summary_dict = py.import("json")?.call_method1("loads", (json,))?;
    kwargs.set_item("summary", summary_dict)?;
    kwargs.set_item("particles", particle_names(scene))?;
    kwargs.set_item("coordinates", coordinates.to_vec())?;
    kwargs.set_item("columns", trace_header(system, coordinates, has_work))?;
    kwargs.set_item("constraint_force_source", source)?;
    let run_class = py.import("bead._run")?.getattr("Run")?;
    Ok(run_class.call((), Some(&kwargs))?.unbind())
}

/// The constraint forces of a run's recorded states, evaluated when `Run` first asks
/// ([`ConstraintForceProbe`]: the same evaluation as the run's own at each state).
#[pyclass(frozen, module = "bead._bead", name = "ConstraintForceSource")]
pub struct ConstraintForceSource {
    system: Arc<bead::model::System>,
    method: Method,
    feedback: Feedback,
}

#[pymethods]
impl ConstraintForceSource {
    /// "implicit" or "parametric".
    #[getter]
    fn method(&self) -> &'static str {
        self.method.name()
    }

    /// (multipliers (T, m), forces (T, P, D)) at the states (t (T,), q (T, K), qdot (T, K)).
    fn __call__<'py>(
        &self,
        py: Python<'py>,
        t: PyReadonlyArray1<'py, f64>,
        q: numpy::PyReadonlyArray2<'py, f64>,
        qdot: numpy::PyReadonlyArray2<'py, f64>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let t = t.as_slice()?.to_vec();
        let q = q.as_array().to_owned();
        let qdot = qdot.as_array().to_owned();
        let rows = t.len();
        let (system, method, feedback) = (Arc::clone(&self.system), self.method, self.feedback);
        let (p, d) = (system.particles().len(), system.dim());
        let m = match method {
            Method::Implicit => system.constraints().n_rows(),
            Method::Parametric => 0,
        };
        let computed = detached(py, move || -> Result<(Vec<f64>, Vec<f64>), String> {
            let mut probe =
                ConstraintForceProbe::new(system, method, feedback).map_err(|e| e.to_string())?;
            let mut out = ConstraintForces::default();
            let (mut multipliers, mut forces) = (
                Vec::with_capacity(rows * m),
                Vec::with_capacity(rows * p * d),
            );
            for (k, &t) in t.iter().enumerate() {
                let (q, qdot) = (q.row(k).to_vec(), qdot.row(k).to_vec());
                probe.evaluate(t, &q, &qdot, &mut out).map_err(|e| {
                    format!("the constraint forces at t = {}: {e}", bead::readable(t))
                })?;
                multipliers.extend_from_slice(&out.multipliers);
                forces.extend_from_slice(&out.force);
            }
            Ok((multipliers, forces))
        })?
        .map_err(|e| step_error_text(py, &e))?;
        let (multipliers, forces) = computed;
        let shape_error = |e: numpy::ndarray::ShapeError| PyValueError::new_err(e.to_string());
        let multipliers = Array2::from_shape_vec((rows, m), multipliers).map_err(shape_error)?;
        let forces = Array3::from_shape_vec((rows, p, d), forces).map_err(shape_error)?;
        Ok((
            multipliers.into_pyarray(py).into_any(),
            forces.into_pyarray(py).into_any(),
        ))
    }
}

pub(crate) fn particle_names(scene: &Scene) -> Vec<String> {
    scene
        .system
        .particles()
        .iter()
        .map(|p| p.name.clone())
        .collect()
}

// ---------------------------------------------------------------------------------------
// Sweeps

/// The native half of `bead.Sweep` (python/bead/_sweep.py): a [`Sweep`] of a scene over
/// axes of parameter values, each member run as `Scene.run` would run it with those values.
/// `run_range` runs a chunk of the members on threads with the GIL released, in segments
/// between which Ctrl-C is honoured, and returns flat arrays.
#[pyclass(frozen, module = "bead._bead", name = "SweepPlan")]
pub struct PySweepPlan {
    inner: Arc<Sweep>,
    method: Method,
}

/// A sweep that cannot be set up, in Python's terms (`params[...]`, `zip=True`).
fn sweep_error(e: SweepError, particles: &[String]) -> PyErr {
    match e {
        SweepError::UnknownParam { name, known } => {
            let known = if known.is_empty() {
                "the scene has no [params] table".to_string()
            } else {
                format!("the scene's parameters are {}", known.join(", "))
            };
            if name.contains('.') {
                return PyValueError::new_err(format!(
                    "initial[{name:?}]: not a number of the scene's start; sweep a particle's \
                     position or velocity as NAME.x, NAME.y, NAME.vx, ... (particles: {}) or \
                     the parametric form's q.NAME, qdot.NAME",
                    particles.join(", ")
                ));
            }
            PyValueError::new_err(format!(
                "params[{name:?}]: not a parameter of the scene; {known}. A swept name must be \
                 in the scene's [params] table: add it there (e.g. `{name} = 1.0`) and write \
                 the numbers it should change as expressions of it (or sweep the start with \
                 initial={{\"bead.x\": values}})"
            ))
        }
        SweepError::NoValues { name } => {
            PyValueError::new_err(format!("params[{name:?}]: no values to sweep"))
        }
        SweepError::ZipLengths { .. } => PyValueError::new_err(format!("zip=True: {e}")),
        SweepError::OutOfRange { .. } => PyIndexError::new_err(e.to_string()),
        SweepError::OtherLayout { ref expected, .. } => PyValueError::new_err(format!(
            "{e}: a sweep's arrays have the scene's particles and coordinates (positions shaped \
             grid + (P, D) with P = {}, D = {}; q grid + ({},)); sweep each particle count \
             on its own, or write one row per member and coordinate with `bead sweep \
             --format long`",
            expected.particles.len(),
            expected.dim,
            expected.coordinates.len()
        )),
        SweepError::Plan(e) => plan_error(e),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// `threads=`: 0 or None (one per core) to [`args::MAX_THREADS`].
fn threads_arg(threads: Option<&Bound<'_, PyAny>>) -> PyResult<usize> {
    let n = args::integer(
        "threads",
        threads,
        0,
        args::MAX_THREADS,
        " (0: one per core)",
    )?;
    Ok(n.unwrap_or(0) as usize)
}

/// Threads to use: `threads`, or one per core for 0.
fn thread_count(threads: usize) -> usize {
    match threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    }
}

#[pymethods]
impl PySweepPlan {
    /// A sweep of `scene` over `names` (parameters of its `[params]` table) taking `values`
    /// (one 1-D float64 array per name): every combination (first name outermost), or with
    /// `zip=True` value i of each. The keyword arguments are those of `Scene.run`; with
    /// `every` or `t_eval` each member records its states (a trajectory), as that run would.
    #[new]
    #[pyo3(signature = (scene, names, values, zip = false, *, method = None, integrator = None, dt = None, duration = None, steps = None, every = None, stabilize = None, rtol = None, atol = None, project = false, substeps = None, max_substeps = None, stop_when = None, event_samples = None, t_eval = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        scene: &Bound<'_, PyScene>,
        names: Vec<String>,
        values: Vec<PyReadonlyArray1<'_, f64>>,
        zip: bool,
        method: Option<&str>,
        integrator: Option<&str>,
        dt: Option<&Bound<'_, PyAny>>,
        duration: Option<&Bound<'_, PyAny>>,
        steps: Option<&Bound<'_, PyAny>>,
        every: Option<&Bound<'_, PyAny>>,
        stabilize: Option<&Bound<'_, PyAny>>,
        rtol: Option<&Bound<'_, PyAny>>,
        atol: Option<&Bound<'_, PyAny>>,
        project: bool,
        substeps: Option<&Bound<'_, PyAny>>,
        max_substeps: Option<&Bound<'_, PyAny>>,
        stop_when: Option<&str>,
        event_samples: Option<&Bound<'_, PyAny>>,
        t_eval: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PySweepPlan> {
        let scene = &scene.get().inner;
        if names.len() != values.len() {
            return Err(PyValueError::new_err(format!(
                "{} names and {} arrays of values",
                names.len(),
                values.len()
            )));
        }
        let mut axes = Vec::with_capacity(names.len());
        for (name, values) in names.into_iter().zip(values) {
            // Read in place, which needs aligned data (bead.Sweep passes aligned copies).
            if !(values.data() as usize).is_multiple_of(std::mem::align_of::<f64>()) {
                return Err(PyValueError::new_err(format!(
                    "params[{name:?}]: the values must be an aligned float64 array \
                     (numpy.require(values, numpy.float64, ['C', 'A']))"
                )));
            }
            let values = values.as_array().to_vec();
            if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "params[{name:?}]: {} is not a finite number",
                    bead::readable(*bad)
                )));
            }
            axes.push(Axis::new(&name, values));
        }
        let times = output_times(
            t_eval,
            [("duration", duration), ("steps", steps), ("every", every)],
        )?;
        let asked = Asked {
            method,
            integrator,
            dt,
            duration,
            steps,
            every,
            stabilize,
            rtol,
            atol,
            project,
            substeps,
            max_substeps,
            event_samples,
        };
        let mut request = asked.request()?;
        if times.is_some() {
            // As in `Scene.run`: t_eval sets where each member ends.
            request.steps = Some(1);
            request.duration = None;
        }
        let recording = match (times, every) {
            (Some(times), _) => Recording::Times(times.into()),
            (None, Some(every)) if !every.is_none() => Recording::Steps,
            (None, _) => Recording::Nothing,
        };
        let plan = resolve(py, scene, &request)?;
        // A run option the formulation cannot take (rattle on the parametric form) is refused
        // here in `Scene.run`'s words, rather than failing every member.
        plan.config(plan.method)
            .check(&scene.system)
            .map_err(|e| setup_error(py, &SetupError::Config(e)))?;
        // A stop condition that does not parse, or does not fit the formulation, is refused
        // here with its place marked, rather than failing every member.
        let event = stop_event(scene, stop_when)?;
        if event.is_some() && stop_when.is_some() {
            let config = plan.config(plan.method);
            let system = Arc::clone(&scene.system);
            let mut simulation = detached(py, move || Simulation::new(system, config))?
                .map_err(|e| setup_error(py, &e))?;
            simulation.set_stop_when(event).map_err(event_error)?;
        }
        let combine = if zip { Combine::Zip } else { Combine::Grid };
        let sweep = Sweep::new(scene, axes, combine, request, stop_when.map(str::to_string))
            .and_then(|sweep| sweep.recording(recording))
            .map_err(|e| sweep_error(e, &particle_names(scene)))?;
        Ok(PySweepPlan {
            inner: Arc::new(sweep),
            method: plan.method,
        })
    }

    /// The number of members.
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// The shape of the results: the axes' lengths (grid) or (n,) (zip).
    #[getter]
    fn shape(&self) -> Vec<usize> {
        self.inner.shape().to_vec()
    }

    /// The swept parameters' names, in order.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.inner.axes().iter().map(|a| a.name.clone()).collect()
    }

    /// The formulation every member runs: "implicit" or "parametric".
    #[getter]
    fn method(&self) -> &'static str {
        self.method.name()
    }

    /// About how many bytes one member's result takes at its peak (what `run_range` counts
    /// against the 8 GiB a sweep returns at once).
    #[getter]
    fn bytes_per_member(&self) -> u64 {
        Columns::bytes_per_member(&self.inner)
    }

    /// The columns of `bead sweep`'s CSV, as its header line.
    #[getter]
    fn csv_header(&self) -> String {
        self.inner.csv_header()
    }

    /// Particle names (the P axis of positions).
    #[getter]
    fn particles(&self) -> Vec<String> {
        particle_names(self.inner.scene())
    }

    /// The dimension D.
    #[getter]
    fn dimension(&self) -> usize {
        self.inner.scene().system.dim()
    }

    /// The generalized coordinates of a parametric sweep (the K axis of q); empty for the
    /// implicit form.
    #[getter]
    fn coordinates(&self) -> Vec<String> {
        match (self.method, self.inner.scene().system.parametric()) {
            (Method::Parametric, Some(map)) => map.coordinates().to_vec(),
            _ => Vec::new(),
        }
    }

    /// Run members `start` to `stop` (exclusive) on `threads` threads (0: one per core) with
    /// the GIL released, and return their figures as a dict of flat arrays (one row per
    /// member, in index order), streamed into the arrays as members finish. Refuses (before
    /// running) a range whose arrays would pass [`MAX_SWEEP_BYTES`], and (as it arrives) a
    /// member whose particles or coordinates are not the scene's. Raises KeyboardInterrupt
    /// on Ctrl-C, between two segments of members (each about a quarter of a second of work).
    #[pyo3(signature = (start, stop, threads = None), text_signature = "($self, start, stop, threads=0)")]
    fn run_range<'py>(
        &self,
        py: Python<'py>,
        start: &Bound<'py, PyAny>,
        stop: &Bound<'py, PyAny>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let sweep = &*self.inner;
        let len = sweep.len() as u64;
        let start = args::integer_value("start", start, 0, len, "")? as usize;
        let stop = args::integer_value("stop", stop, 0, len, "")? as usize;
        let threads = threads_arg(threads)?;
        if start > stop || stop > sweep.len() {
            return Err(sweep_error(
                SweepError::OutOfRange {
                    start,
                    end: stop,
                    len: sweep.len(),
                },
                &[],
            ));
        }
        let count = stop - start;
        let per_member = Columns::bytes_per_member(sweep);
        let bytes = (count as u64).saturating_mul(per_member);
        if bytes > MAX_SWEEP_BYTES {
            let layout = sweep.layout();
            return Err(PyValueError::new_err(format!(
                "{count} members need about {} for their result arrays ({per_member} bytes each: \
                 {} parameter(s), {} particle(s) in {}D, {} generalized coordinate(s)), more than \
                 the 8 GiB a sweep returns at once; run it in chunks that fit and keep what you \
                 need of each: sweep = bead.Sweep(scene, params, ...), then \
                 sweep.run_range(start, stop) for each (start, stop) in sweep.chunks({})",
                bead::byte_size(bytes),
                sweep.axes().len(),
                layout.particles.len(),
                layout.dim,
                layout.coordinates.len(),
                bytes.div_ceil(MAX_SWEEP_BYTES / 2).max(2)
            )));
        }
        let threads = thread_count(threads).min(count.max(1));
        let clock = Instant::now();
        let mut columns = Columns::new(sweep, count);
        // Segments grow while they take under a quarter of a second and shrink past one, so
        // that Ctrl-C is noticed quickly while threads seldom wait for each other at the end
        // of a segment. A member's numbers depend on its index alone, so segments change none.
        let mut size = threads;
        let mut next = start;
        while next < stop {
            let end = (next + size).min(stop);
            let segment = Instant::now();
            let columns = &mut columns;
            detached(py, move || {
                sweep.run_each(next..end, threads, |member| columns.push(sweep, member))
            })?
            .map_err(|e| sweep_error(e, &[]))?;
            py.check_signals()?;
            let seconds = segment.elapsed().as_secs_f64();
            if seconds < 0.25 {
                size = size.saturating_mul(2).min(1 << 20);
            } else if seconds > 1.0 {
                size = (size / 2).max(threads);
            }
            next = end;
        }
        columns.into_dict(py, threads, clock)
    }

    fn __repr__(&self) -> String {
        format!(
            "<bead._bead.SweepPlan of {:?}: {} members, {} {}>",
            self.inner.scene().title,
            self.inner.len(),
            self.names().join(" x "),
            self.method.name()
        )
    }
}

/// The most bytes a sweep's result may take in Python (8 GiB; see
/// [`Columns::bytes_per_member`]): above, `run_range` refuses and suggests chunks.
const MAX_SWEEP_BYTES: u64 = 8 << 30;

/// A sweep's figures as flat columns, one row per member (NaN and 0 where a member has none),
/// filled as members arrive and moved into numpy arrays without a copy.
struct Columns {
    /// Parameters swept.
    k: usize,
    /// Particle coordinates and generalized coordinates of the scene swept.
    n_coords: usize,
    n_q: usize,
    particles: usize,
    dim: usize,
    params: Vec<f64>,
    /// 0 ok, 1 event, 2 failed (Python turns them into strings).
    status: Vec<u8>,
    errors: Vec<Option<String>>,
    t_final: Vec<f64>,
    stop_time: Vec<f64>,
    energy_rel: Vec<f64>,
    energy_balance: Vec<f64>,
    constraint: Vec<f64>,
    /// Newton iterations of all steps (NaN where none solved onto the constraints)
    newton: Vec<f64>,
    steps: Vec<i64>,
    x: Vec<f64>,
    xdot: Vec<f64>,
    q: Vec<f64>,
    qdot: Vec<f64>,
    /// Per member, per event: the crossing times.
    event_times: Vec<Vec<Vec<f64>>>,
    /// Per member, the states it recorded (when the sweep records any).
    trajectories: Option<Vec<Option<Box<Trajectory>>>>,
}

impl Columns {
    /// Bytes one member takes at the peak of a sweep in Python: 8 per float64 (the K
    /// parameters, t_final, stop_time, steps, the three error maxima, the Newton
    /// iterations, the run index, 2 x P x D of positions and velocities, 2 x Q of q and
    /// qdot), its status (1 byte here, 24 as
    /// numpy's `<U6`) and its error slot (24 here while it is converted, 8 in the list, 8 in
    /// the object array). An error message itself is not counted. A recorded trajectory
    /// counts twice its rows (t, energy, constraint_error, work, positions, velocities, q,
    /// qdot): as recorded, then padded into the arrays.
    fn bytes_per_member(sweep: &Sweep) -> u64 {
        let layout = sweep.layout();
        let state = layout.n_coords() + layout.coordinates.len();
        let floats = sweep.axes().len() + 8 + 2 * state;
        let recorded = sweep
            .rows_per_member()
            .saturating_mul(2 * 8 * (4 + 2 * state as u64));
        (8 * floats as u64 + 1 + 24 + 24 + 8 + 8).saturating_add(recorded)
    }

    /// Empty columns for `count` members of `sweep`, reserved in full.
    fn new(sweep: &Sweep, count: usize) -> Columns {
        let layout = sweep.layout();
        let (k, nc, nq) = (
            sweep.axes().len(),
            layout.n_coords(),
            layout.coordinates.len(),
        );
        let floats = || Vec::with_capacity(count);
        Columns {
            k,
            n_coords: nc,
            n_q: nq,
            particles: layout.particles.len(),
            dim: layout.dim,
            params: Vec::with_capacity(count * k),
            status: Vec::with_capacity(count),
            errors: Vec::with_capacity(count),
            t_final: floats(),
            stop_time: floats(),
            energy_rel: floats(),
            energy_balance: floats(),
            constraint: floats(),
            newton: floats(),
            steps: Vec::with_capacity(count),
            x: Vec::with_capacity(count * nc),
            xdot: Vec::with_capacity(count * nc),
            q: Vec::with_capacity(count * nq),
            qdot: Vec::with_capacity(count * nq),
            event_times: Vec::with_capacity(count),
            trajectories: (*sweep.recorded() != Recording::Nothing)
                .then(|| Vec::with_capacity(count)),
        }
    }

    /// Append `member`'s row; a member whose particles or coordinates are not the scene's
    /// does not fit the arrays (grid + (P, D)) and is refused.
    fn push(&mut self, sweep: &Sweep, member: Member) -> Result<(), SweepError> {
        sweep.check_layout(&member)?;
        let (nc, nq) = (self.n_coords, self.n_q);
        self.params.extend_from_slice(&member.params);
        self.status.push(match member.status() {
            "ok" => 0,
            "event" => 1,
            _ => 2,
        });
        match &member.stats {
            Some(stats) => {
                self.t_final.push(stats.t_final);
                self.stop_time.push(stats.stop_time.unwrap_or(f64::NAN));
                self.energy_rel.push(stats.energy_rel_error_max);
                self.energy_balance
                    .push(stats.energy_balance_error_max.unwrap_or(f64::NAN));
                self.constraint.push(stats.constraint_error_max);
                self.newton
                    .push(stats.newton_iterations.map_or(f64::NAN, |n| n as f64));
                self.steps
                    .push(i64::try_from(stats.steps).unwrap_or(i64::MAX));
                self.x.extend_from_slice(&stats.x);
                self.xdot.extend_from_slice(&stats.xdot);
                if nq > 0 {
                    self.q.extend_from_slice(&stats.q);
                    self.qdot.extend_from_slice(&stats.qdot);
                }
                self.event_times
                    .push(stats.events.iter().map(|e| e.times.clone()).collect());
            }
            None => {
                for column in [
                    &mut self.t_final,
                    &mut self.stop_time,
                    &mut self.energy_rel,
                    &mut self.energy_balance,
                    &mut self.constraint,
                    &mut self.newton,
                ] {
                    column.push(f64::NAN);
                }
                self.steps.push(0);
                self.x.resize(self.x.len() + nc, f64::NAN);
                self.xdot.resize(self.xdot.len() + nc, f64::NAN);
                self.q.resize(self.q.len() + nq, f64::NAN);
                self.qdot.resize(self.qdot.len() + nq, f64::NAN);
                self.event_times.push(Vec::new());
            }
        }
        self.errors.push(member.error);
        if let Some(trajectories) = &mut self.trajectories {
            trajectories.push(member.trajectory);
        }
        Ok(())
    }

    /// The columns as a dict of numpy arrays (`status` as codes 0 ok, 1 event, 2 failed).
    fn into_dict<'py>(
        self,
        py: Python<'py>,
        threads: usize,
        clock: Instant,
    ) -> PyResult<Bound<'py, PyDict>> {
        let n = self.status.len();
        let (k, p, d, nq) = (self.k, self.particles, self.dim, self.n_q);
        let shape_error = |e: numpy::ndarray::ShapeError| PyValueError::new_err(e.to_string());
        let dict = PyDict::new(py);
        dict.set_item(
            "params",
            Array2::from_shape_vec((n, k), self.params)
                .map_err(shape_error)?
                .into_pyarray(py),
        )?;
        dict.set_item("status", self.status.into_pyarray(py))?;
        dict.set_item("errors", self.errors)?;
        dict.set_item("t_final", self.t_final.into_pyarray(py))?;
        dict.set_item("stop_time", self.stop_time.into_pyarray(py))?;
        dict.set_item("steps", self.steps.into_pyarray(py))?;
        dict.set_item("energy_rel_error_max", self.energy_rel.into_pyarray(py))?;
        dict.set_item(
            "energy_balance_error_max",
            self.energy_balance.into_pyarray(py),
        )?;
        dict.set_item("constraint_error_max", self.constraint.into_pyarray(py))?;
        dict.set_item("newton_iterations", self.newton.into_pyarray(py))?;
        for (key, values) in [("positions", self.x), ("velocities", self.xdot)] {
            let array = Array3::from_shape_vec((n, p, d), values).map_err(shape_error)?;
            dict.set_item(key, array.into_pyarray(py))?;
        }
        if nq > 0 {
            for (key, values) in [("q", self.q), ("qdot", self.qdot)] {
                let array = Array2::from_shape_vec((n, nq), values).map_err(shape_error)?;
                dict.set_item(key, array.into_pyarray(py))?;
            }
        } else {
            dict.set_item("q", py.None())?;
            dict.set_item("qdot", py.None())?;
        }
        let t_events = PyList::empty(py);
        for member in self.event_times {
            let times = PyList::empty(py);
            for event in member {
                times.append(event.into_pyarray(py))?;
            }
            t_events.append(times)?;
        }
        dict.set_item("t_events", t_events)?;
        match self.trajectories {
            Some(trajectories) => {
                let recorded = trajectories_dict(py, trajectories, (p, d, nq))?;
                dict.set_item("trajectory", recorded)?
            }
            None => dict.set_item("trajectory", py.None())?,
        }
        dict.set_item("threads", threads)?;
        dict.set_item("wall_seconds", clock.elapsed().as_secs_f64())?;
        Ok(dict)
    }
}

/// Members' recorded states as arrays padded with NaN to the most rows any recorded:
/// `t`, `energy`, `constraint_error` (n, T), `positions`, `velocities` (n, T, P, D), `q`,
/// `qdot` (n, T, K) or None (implicit form), `work` (n, T) or None (no member ran the
/// ledger), `rows` (n,) int64: how many rows each recorded. Each member's rows are freed as
/// they are copied.
fn trajectories_dict<'py>(
    py: Python<'py>,
    trajectories: Vec<Option<Box<Trajectory>>>,
    (p, d, k): (usize, usize, usize),
) -> PyResult<Bound<'py, PyDict>> {
    let n = trajectories.len();
    let longest = trajectories
        .iter()
        .flatten()
        .map(|r| r.rows())
        .max()
        .unwrap_or(0);
    let any_work = trajectories.iter().flatten().any(|r| !r.work.is_empty());
    let nc = p * d;
    let padded = |per_row: usize| vec![f64::NAN; n * longest * per_row];
    let (mut t, mut energy, mut error, mut work) = (padded(1), padded(1), padded(1), padded(1));
    let (mut x, mut xdot) = (padded(nc), padded(nc));
    let (mut q, mut qdot) = (padded(k), padded(k));
    let mut rows = Vec::with_capacity(n);
    for (i, recorded) in trajectories.into_iter().enumerate() {
        let Some(recorded) = recorded else {
            rows.push(0i64);
            continue;
        };
        let m = recorded.rows();
        rows.push(m as i64);
        let place = |to: &mut [f64], from: &[f64], per_row: usize| {
            let at = i * longest * per_row;
            let len = from.len().min(m * per_row);
            to[at..at + len].copy_from_slice(&from[..len]);
        };
        place(&mut t, &recorded.t, 1);
        place(&mut energy, &recorded.energy, 1);
        place(&mut error, &recorded.constraint_error, 1);
        place(&mut x, &recorded.x, nc);
        place(&mut xdot, &recorded.xdot, nc);
        if k > 0 {
            place(&mut q, &recorded.q, k);
            place(&mut qdot, &recorded.qdot, k);
        }
        if recorded.work.len() == m {
            place(&mut work, &recorded.work, 1);
        }
    }
    let shape_error = |e: numpy::ndarray::ShapeError| PyValueError::new_err(e.to_string());
    let dict = PyDict::new(py);
    for (key, values) in [("t", t), ("energy", energy), ("constraint_error", error)] {
        let array = Array2::from_shape_vec((n, longest), values).map_err(shape_error)?;
        dict.set_item(key, array.into_pyarray(py))?;
    }
    for (key, values) in [("positions", x), ("velocities", xdot)] {
        let array = numpy::ndarray::Array4::from_shape_vec((n, longest, p, d), values)
            .map_err(shape_error)?;
        dict.set_item(key, array.into_pyarray(py))?;
    }
    for (key, values) in [("q", q), ("qdot", qdot)] {
        if k > 0 {
            let array = Array3::from_shape_vec((n, longest, k), values).map_err(shape_error)?;
            dict.set_item(key, array.into_pyarray(py))?;
        } else {
            dict.set_item(key, py.None())?;
        }
    }
    if any_work {
        let array = Array2::from_shape_vec((n, longest), work).map_err(shape_error)?;
        dict.set_item("work", array.into_pyarray(py))?;
    } else {
        dict.set_item("work", py.None())?;
    }
    dict.set_item("rows", rows.into_pyarray(py))?;
    Ok(dict)
}

// ---------------------------------------------------------------------------------------
// Simulations

// ---------------------------------------------------------------------------------------
// Releasing the GIL, and errors

/// Run `f` with the GIL released. A panic in `f` (a bug in bead) becomes a `bead.BeadError`
/// instead of unwinding into Python.
pub(crate) fn detached<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    py.detach(|| catch_unwind(AssertUnwindSafe(f)))
        .map_err(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            bead_error(
                py,
                &format!("internal error (a bug in bead; please report it): {what}"),
            )
        })
}

/// A simulation whose lock was poisoned by a panic while it stepped.
pub(crate) fn poisoned() -> PyErr {
    Python::attach(|py| {
        bead_error(
            py,
            "this simulation failed with an internal error earlier and cannot be used",
        )
    })
}

/// An instance of `bead._errors.NAME` made with `args`, as a `PyErr` (or the error of making
/// it).
fn python_error<'py>(py: Python<'py>, name: &str, args: impl pyo3::call::PyCallArgs<'py>) -> PyErr {
    let made = py
        .import("bead._errors")
        .and_then(|m| m.getattr(name))
        .and_then(|class| class.call1(args));
    match made {
        Ok(instance) => PyErr::from_value(instance),
        Err(e) => e,
    }
}

fn bead_error(py: Python<'_>, message: &str) -> PyErr {
    python_error(py, "BeadError", (message,))
}

/// `bead.SceneError(text, path, line, column, message, snippet)`.
/// The message says what to change in Python: an override the loader refuses names the
/// command line's `--set NAME=VALUE`, which Python users did not write; it becomes
/// `params["NAME"]: ...`.
fn scene_error(py: Python<'_>, e: &SceneError) -> PyErr {
    let message = python_wording(&e.message);
    let text = e.render().replacen(&e.message, &message, 1);
    python_error(
        py,
        "SceneError",
        (
            text,
            e.file.clone(),
            e.line,
            e.column,
            message,
            e.snippet.clone(),
        ),
    )
}

/// `--set NAME=VALUE: unknown parameter ...` as `params["NAME"]: unknown parameter ...`, with
/// what a Python user can do about it; any other message unchanged.
fn python_wording(message: &str) -> String {
    let Some((assignment, rest)) = message
        .strip_prefix("--set ")
        .and_then(|m| m.split_once(": "))
    else {
        return message.to_string();
    };
    let name = assignment.split('=').next().unwrap_or(assignment);
    let hint = if rest.starts_with("unknown parameter") {
        " (the keys of params= must be names of the scene's [params] table; to vary another \
         number, add it there and write the number as its name)"
    } else {
        ""
    };
    format!("params[{name:?}]: {rest}{hint}")
}

/// `bead.SetupError`: the simulation cannot start with these settings or this state.
/// A scene that cannot take new parameters: the load's located error, or why the start set
/// on it cannot be placed on the changed scene.
pub(crate) fn scene_edit_error(py: Python<'_>, e: &SceneEditError) -> PyErr {
    match e {
        SceneEditError::Load(e) => scene_error(py, e),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// An evaluation that failed at the current state (a singular point): `bead.RunError`.
pub(crate) fn step_error(py: Python<'_>, e: &StepError) -> PyErr {
    step_error_text(py, &e.to_string())
}

/// `bead.RunError` with `message` and no run.
fn step_error_text(py: Python<'_>, message: &str) -> PyErr {
    python_error(py, "RunError", (message.to_string(), None::<Py<PyAny>>))
}

pub(crate) fn setup_error(py: Python<'_>, e: &SetupError) -> PyErr {
    python_error(py, "SetupError", (e.to_string(),))
}

/// A plan that cannot be made: a bad argument (ValueError naming it as a keyword) or a bad
/// `[run]` value of the scene.
fn plan_error(e: PlanError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `bead.RunError` (`bead.DivergenceError` when the state blew up) with the partial run.
pub(crate) fn run_error(py: Python<'_>, e: &RunError, run: Option<Py<PyAny>>) -> PyErr {
    let class = match e {
        RunError::Diverged { .. } => "DivergenceError",
        // advance_to(t) before the current time: a bad argument, nothing ran.
        RunError::TimeBehind { .. } => return PyValueError::new_err(e.to_string()),
        _ => "RunError",
    };
    python_error(py, class, (e.to_string(), run))
}

/// A convergence study as Python data (see `Scene.order`).
fn study_dict<'py>(
    py: Python<'py>,
    study: &bead::convergence::Study,
) -> PyResult<Bound<'py, PyDict>> {
    let floors = &study.floors;
    let mut columns: Vec<(&str, Vec<Py<PyAny>>)> = [
        "method",
        "integrator",
        "dt",
        "steps",
        "evaluations",
        "wall_seconds",
        "position_error",
        "energy_error",
        "constraint_error",
        "position_order",
        "energy_order",
        "constraint_order",
    ]
    .into_iter()
    .map(|name| (name, Vec::new()))
    .collect();
    let failures = PyDict::new(py);
    for series in &study.series {
        let orders = [
            series.position_orders(floors),
            series.energy_orders(floors),
            series.constraint_orders(floors),
        ];
        for (k, level) in series.levels.iter().enumerate() {
            let order =
                |o: &Vec<Option<f64>>| k.checked_sub(1).and_then(|i| o[i]).unwrap_or(f64::NAN);
            let constraint_order = match level.constraint_error {
                Some(_) => order(&orders[2]),
                None => f64::NAN,
            };
            let row: [Py<PyAny>; 12] = [
                series.method.name().into_pyobject(py)?.into_any().unbind(),
                series
                    .integrator
                    .name()
                    .into_pyobject(py)?
                    .into_any()
                    .unbind(),
                level.dt.into_pyobject(py)?.into_any().unbind(),
                level.steps.into_pyobject(py)?.into_any().unbind(),
                level.evaluations.into_pyobject(py)?.into_any().unbind(),
                level.wall_seconds.into_pyobject(py)?.into_any().unbind(),
                level.position_error.into_pyobject(py)?.into_any().unbind(),
                level.energy_error.into_pyobject(py)?.into_any().unbind(),
                level
                    .constraint_error
                    .unwrap_or(f64::NAN)
                    .into_pyobject(py)?
                    .into_any()
                    .unbind(),
                order(&orders[0]).into_pyobject(py)?.into_any().unbind(),
                order(&orders[1]).into_pyobject(py)?.into_any().unbind(),
                constraint_order.into_pyobject(py)?.into_any().unbind(),
            ];
            for ((_, column), value) in columns.iter_mut().zip(row) {
                column.push(value);
            }
        }
        if !series.failures.is_empty() {
            let why = PyDict::new(py);
            for failure in &series.failures {
                why.set_item(failure.dt, &failure.error)?;
            }
            failures.set_item(
                format!("{} {}", series.method.name(), series.integrator.name()),
                why,
            )?;
        }
    }
    let runs = PyDict::new(py);
    for (name, column) in columns {
        runs.set_item(name, column)?;
    }
    let floor_dict = PyDict::new(py);
    floor_dict.set_item("position", floors.position)?;
    floor_dict.set_item("energy", floors.energy)?;
    floor_dict.set_item("constraint", floors.constraint)?;
    let reference = PyDict::new(py);
    reference.set_item("method", study.reference_method.name())?;
    reference.set_item("rtol", study.settings.reference_rtol)?;
    reference.set_item("steps", study.reference_steps)?;
    let out = PyDict::new(py);
    out.set_item("runs", runs)?;
    out.set_item("floors", floor_dict)?;
    out.set_item("reference", reference)?;
    out.set_item("failures", failures)?;
    out.set_item("length_scale", study.length_scale)?;
    Ok(out)
}
