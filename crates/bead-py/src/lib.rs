//! `bead._bead`: the native half of the Python package `bead`. It drives the library's own
//! objects ([`bead::plan::Plan`], [`bead::simulate::Simulation`], [`bead::simulate::run`],
//! [`bead::output::Summary`]) and writes no physics of its own: it converts arguments into a
//! [`bead::plan::PlanRequest`], runs with the GIL released, and hands numpy arrays back to the
//! Python half (`python/bead`), which holds them in a `Run` and defines the exceptions.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bead::formulation::{Feedback, Method};
use bead::integrate::IntegratorKind;
use bead::output::{trace_header, Summary};
use bead::plan::{self, Plan, PlanError, PlanRequest};
use bead::scene::{Scene, SceneError};
use bead::simulate::{
    self, Event, EventError, RunError, RunFailure, RunStats, Sample, SetupError, Simulation, Sink,
};
use bead::sweep::{Axis, Combine, Member, Sweep, SweepError};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::{PyIndexError, PyTypeError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

mod args;

/// Most bytes of arrays a run may record before it is refused: 8 GiB.
const MAX_RECORDED_BYTES: u64 = 8 << 30;

/// The native module `bead._bead`; the package `bead` re-exports what users need.
#[pymodule]
fn _bead(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(load, m)?)?;
    m.add_function(wrap_pyfunction!(loads, m)?)?;
    m.add_function(wrap_pyfunction!(_unpickle, m)?)?;
    m.add_class::<PyScene>()?;
    m.add_class::<PySimulation>()?;
    m.add_class::<PySweepPlan>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add(
        "INTEGRATORS",
        IntegratorKind::ALL
            .iter()
            .map(|k| k.name())
            .collect::<Vec<_>>(),
    )?;
    m.add("METHODS", ["implicit", "parametric"])?;
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
fn _unpickle(
    py: Python<'_>,
    text: &str,
    params: &Bound<'_, PyAny>,
    name: &str,
) -> PyResult<PyScene> {
    let overrides = overrides(Some(params))?;
    let scene = Scene::parse(text, name, &overrides).map_err(|e| scene_error(py, &e))?;
    Ok(PyScene::new(scene))
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
        self.inner.system.constraints().infos().len()
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
        let mut all = self.inner.overrides().to_vec();
        for (name, value) in overrides(Some(params))? {
            all.retain(|(n, _)| *n != name);
            all.push((name, value));
        }
        let scene = Scene::parse(self.inner.text(), &self.inner.file, &all)
            .map_err(|e| scene_error(py, &e))?;
        warn_scene(py, &scene)?;
        Ok(PyScene::new(scene))
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
    /// located to 1e-10 of dt; default: the scene's `[run] stop_when`).
    ///
    /// Raises ValueError for a bad argument, `bead.SetupError` when the simulation cannot
    /// start (e.g. rattle on the parametric form), and `bead.RunError` (`bead.DivergenceError`
    /// when the state blew up) when a step fails, with the run up to the last good state as
    /// `.run`. The GIL is released while the run steps.
    #[pyo3(signature = (*, method = None, integrator = None, dt = None, duration = None, steps = None, every = None, stabilize = None, rtol = None, atol = None, project = false, substeps = None, max_substeps = None, stop_when = None))]
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
    ) -> PyResult<Py<PyAny>> {
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
        };
        let request = asked.request()?;
        let plan = resolve(py, &self.inner, &request)?;
        let event = stop_event(&self.inner, stop_when)?;
        run_plan(py, &self.inner, &plan, event)
    }

    /// A `bead.Simulation` to step by hand (`step()`, `advance_to(t)`), at the scene's
    /// initial state. The arguments are those of `run()` without the run's length.
    #[pyo3(signature = (*, method = None, integrator = None, dt = None, stabilize = None, rtol = None, atol = None, project = false, substeps = None, max_substeps = None, stop_when = None))]
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
    ) -> PyResult<PySimulation> {
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
            ..Asked::default()
        };
        // Only the step matters here: the scene's run length is not used, and a request for
        // one step keeps the scene's duration from being checked against the new dt.
        let mut request = asked.request()?;
        request.steps = Some(1);
        let plan = resolve(py, &self.inner, &request)?;
        let config = plan.config(plan.method);
        let system = Arc::clone(&self.inner.system);
        let event = stop_event(&self.inner, stop_when)?;
        let mut simulation = detached(py, move || Simulation::new(system, config))?
            .map_err(|e| setup_error(py, &e))?;
        simulation.set_stop_when(event).map_err(event_error)?;
        Ok(PySimulation {
            inner: Mutex::new(simulation),
            scene: Arc::clone(&self.inner),
        })
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
        (loads, (self.inner.text(), params, &self.inner.file))
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
            counted(scene.system.constraints().infos().len(), "constraint"),
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

/// Every recorded sample of a run, row after row (a [`Sink`]).
#[derive(Default)]
struct Recorder {
    t: Vec<f64>,
    x: Vec<f64>,
    xdot: Vec<f64>,
    energy: Vec<f64>,
    constraint_error: Vec<f64>,
    q: Vec<f64>,
    qdot: Vec<f64>,
    work: Vec<f64>,
}

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

impl Recorder {
    /// A recorder with room for `rows` rows reserved up front, so that no vector is moved
    /// while it grows: the peak is then the arrays themselves. When the system will not
    /// reserve that much at once (a run may stop long before its end), they grow as needed.
    fn with_room(rows: u64, width: RowWidth, work: bool) -> Recorder {
        let rows = usize::try_from(rows).unwrap_or(usize::MAX);
        let room = |per_row: usize| {
            let mut v = Vec::new();
            let wanted = rows.saturating_mul(per_row);
            if v.try_reserve_exact(wanted).is_err() {
                v.reserve(wanted.min(1 << 16));
            }
            v
        };
        Recorder {
            t: room(1),
            x: room(width.coordinates),
            xdot: room(width.coordinates),
            energy: room(1),
            constraint_error: room(1),
            q: room(width.k),
            qdot: room(width.k),
            work: if work { room(1) } else { Vec::new() },
        }
    }
}

impl Sink for Recorder {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.t.push(sample.t);
        self.x.extend_from_slice(sample.x);
        self.xdot.extend_from_slice(sample.xdot);
        self.energy.push(sample.energy);
        self.constraint_error.push(sample.constraint_error);
        self.q.extend_from_slice(sample.q);
        self.qdot.extend_from_slice(sample.qdot);
        if let Some(w) = sample.work {
            self.work.push(w);
        }
        Ok(())
    }
}

/// What a run left: the recorded rows, the outcome and its summary.
struct Finished {
    recorder: Recorder,
    result: Result<RunStats, RunFailure>,
    summary: Summary,
    coordinates: Vec<String>,
    tracks_work: bool,
}

/// Run `plan` on `scene` with the GIL released, and build the Python `Run` (or raise the
/// `RunError` that carries it).
/// The stop condition of a run: `stop_when`, parsed against the scene's system (a bad one is
/// a ValueError showing where in the expression), else the scene's `[run] stop_when`, else
/// none: as `bead run --stop-when` resolves it.
fn stop_event(scene: &Scene, stop_when: Option<&str>) -> PyResult<Option<Event>> {
    match stop_when {
        None => Ok(scene.run.stop_when.clone()),
        Some(source) => Event::parse(&scene.system, source).map(Some).map_err(|e| {
            let start = source[..e.span.start.min(source.len())].chars().count();
            let width = source
                .get(e.span.start..e.span.end.max(e.span.start))
                .map_or(1, |s| s.chars().count().max(1));
            PyValueError::new_err(format!(
                "stop_when: {}\n  {source}\n  {}{}",
                e.message,
                " ".repeat(start),
                "^".repeat(width)
            ))
        }),
    }
}

/// A stop condition that does not fit the run (generalized coordinates on the implicit form).
fn event_error(e: EventError) -> PyErr {
    PyValueError::new_err(format!("stop_when: {e}"))
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
struct Interrupt {
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

fn run_plan(
    py: Python<'_>,
    scene: &Arc<Scene>,
    plan: &Plan,
    event: Option<Event>,
) -> PyResult<Py<PyAny>> {
    let system = &scene.system;
    let coordinates = system.n_coords();
    let k = match plan.method {
        Method::Parametric => system.parametric().map_or(0, |m| m.n_q()),
        Method::Implicit => coordinates,
    };
    let width = RowWidth { coordinates, k };
    let rows = record_guard(plan, width)?;
    let config = plan.config(plan.method);
    let options = plan.options();
    let shared = Arc::clone(scene);
    let mut watch = Interrupt::new(py)?;
    let finished = detached(py, move || -> Result<Finished, StartError> {
        let mut simulation =
            Simulation::new(Arc::clone(&shared.system), config).map_err(StartError::Setup)?;
        simulation.set_stop_when(event).map_err(StartError::Event)?;
        let coordinates = simulation.formulation().coordinate_names().to_vec();
        let tracks_work = simulation.tracks_work();
        let mut recorder = Recorder::with_room(rows, width, tracks_work);
        let result =
            simulate::run_with_progress(&mut simulation, options, &mut recorder, &mut watch);
        if let Some(interrupt) = watch.error {
            return Err(StartError::Interrupted(interrupt));
        }
        let summary = Summary::from_result(&shared.file, &shared.system, &coordinates, &result);
        Ok(Finished {
            recorder,
            result,
            summary,
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
        coordinates,
        tracks_work,
    } = finished;
    let run = build_run(py, scene, recorder, &summary, &coordinates, tracks_work)?;
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
    recorder: Recorder,
    summary: &Summary,
    coordinates: &[String],
    tracks_work: bool,
) -> PyResult<Py<PyAny>> {
    let system = &scene.system;
    let (p, d) = (system.particles().len(), system.dim());
    let rows = recorder.t.len();
    let k = recorder.q.len().checked_div(rows).unwrap_or(0);
    let shape_error = |e: numpy::ndarray::ShapeError| PyValueError::new_err(e.to_string());
    let Recorder {
        t,
        x,
        xdot,
        energy,
        constraint_error,
        q,
        qdot,
        work,
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
    let run_class = py.import("bead._run")?.getattr("Run")?;
    Ok(run_class.call((), Some(&kwargs))?.unbind())
}

fn particle_names(scene: &Scene) -> Vec<String> {
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
fn sweep_error(e: SweepError) -> PyErr {
    match e {
        SweepError::UnknownParam { name, known } => {
            let known = if known.is_empty() {
                "the scene has no [params] table".to_string()
            } else {
                format!("the scene's parameters are {}", known.join(", "))
            };
            PyValueError::new_err(format!(
                "params[{name:?}]: not a parameter of the scene; {known}. A swept name must be \
                 in the scene's [params] table: add it there (e.g. `{name} = 1.0`) and write \
                 the numbers it should change as expressions of it"
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
    /// `zip=True` value i of each. The keyword arguments are those of `Scene.run` without
    /// `every` (each member records nothing but its figures).
    #[new]
    #[pyo3(signature = (scene, names, values, zip = false, *, method = None, integrator = None, dt = None, duration = None, steps = None, stabilize = None, rtol = None, atol = None, project = false, substeps = None, max_substeps = None, stop_when = None))]
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
        stabilize: Option<&Bound<'_, PyAny>>,
        rtol: Option<&Bound<'_, PyAny>>,
        atol: Option<&Bound<'_, PyAny>>,
        project: bool,
        substeps: Option<&Bound<'_, PyAny>>,
        max_substeps: Option<&Bound<'_, PyAny>>,
        stop_when: Option<&str>,
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
        let asked = Asked {
            method,
            integrator,
            dt,
            duration,
            steps,
            stabilize,
            rtol,
            atol,
            project,
            substeps,
            max_substeps,
            ..Asked::default()
        };
        let request = asked.request()?;
        let plan = resolve(py, scene, &request)?;
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
            .map_err(sweep_error)?;
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
            return Err(sweep_error(SweepError::OutOfRange {
                start,
                end: stop,
                len: sweep.len(),
            }));
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
            .map_err(sweep_error)?;
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
    steps: Vec<i64>,
    x: Vec<f64>,
    xdot: Vec<f64>,
    q: Vec<f64>,
    qdot: Vec<f64>,
}

impl Columns {
    /// Bytes one member takes at the peak of a sweep in Python: 8 per float64 (the K
    /// parameters, t_final, stop_time, steps, the three error maxima, 2 x P x D of
    /// positions and velocities, 2 x Q of q and qdot), its status (1 byte here, 24 as
    /// numpy's `<U6`) and its error slot (24 here while it is converted, 8 in the list, 8 in
    /// the object array). An error message itself is not counted.
    fn bytes_per_member(sweep: &Sweep) -> u64 {
        let layout = sweep.layout();
        let floats = sweep.axes().len() + 7 + 2 * (layout.n_coords() + layout.coordinates.len());
        8 * floats as u64 + 1 + 24 + 24 + 8 + 8
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
            steps: Vec::with_capacity(count),
            x: Vec::with_capacity(count * nc),
            xdot: Vec::with_capacity(count * nc),
            q: Vec::with_capacity(count * nq),
            qdot: Vec::with_capacity(count * nq),
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
                self.steps
                    .push(i64::try_from(stats.steps).unwrap_or(i64::MAX));
                self.x.extend_from_slice(&stats.x);
                self.xdot.extend_from_slice(&stats.xdot);
                if nq > 0 {
                    self.q.extend_from_slice(&stats.q);
                    self.qdot.extend_from_slice(&stats.qdot);
                }
            }
            None => {
                for column in [
                    &mut self.t_final,
                    &mut self.stop_time,
                    &mut self.energy_rel,
                    &mut self.energy_balance,
                    &mut self.constraint,
                ] {
                    column.push(f64::NAN);
                }
                self.steps.push(0);
                self.x.resize(self.x.len() + nc, f64::NAN);
                self.xdot.resize(self.xdot.len() + nc, f64::NAN);
                self.q.resize(self.q.len() + nq, f64::NAN);
                self.qdot.resize(self.qdot.len() + nq, f64::NAN);
            }
        }
        self.errors.push(member.error);
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
        dict.set_item("threads", threads)?;
        dict.set_item("wall_seconds", clock.elapsed().as_secs_f64())?;
        Ok(dict)
    }
}

// ---------------------------------------------------------------------------------------
// Simulations

/// A simulation to step by hand: `step()`, `advance_to(t)`, and the current state. Made by
/// `Scene.simulation()`. After an error it holds the last good state. The GIL is released
/// while it steps; calls from several threads take turns.
#[pyclass(frozen, module = "bead", name = "Simulation")]
pub struct PySimulation {
    inner: Mutex<Simulation>,
    scene: Arc<Scene>,
}

impl PySimulation {
    /// Read the simulation (with the GIL held: nothing steps it meanwhile for long, since
    /// stepping happens with the lock taken only while detached).
    fn read<T>(&self, py: Python<'_>, f: impl FnOnce(&Simulation) -> T + Send) -> PyResult<T>
    where
        T: Send,
    {
        // Wait for the lock detached, so that a thread stepping this simulation can re-attach.
        let inner = &self.inner;
        let out = py.detach(|| inner.lock().map(|s| f(&s)).map_err(|_| ()));
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
            Ok(mut simulation) => Ok(f(&mut simulation)),
            Err(_) => Err(()),
        })?;
        match result {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(run_error(py, &e, None)),
            Err(()) => Err(poisoned()),
        }
    }

    /// An (n / dim, dim) array of `values`.
    fn matrix<'py>(&self, py: Python<'py>, values: Vec<f64>) -> PyResult<Bound<'py, PyAny>> {
        let d = self.scene.system.dim();
        let shape = (values.len() / d, d);
        Ok(Array2::from_shape_vec(shape, values)
            .map_err(|e| PyValueError::new_err(e.to_string()))?
            .into_pyarray(py)
            .into_any())
    }
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
        particle_names(&self.scene)
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
}

// ---------------------------------------------------------------------------------------
// Releasing the GIL, and errors

/// Run `f` with the GIL released. A panic in `f` (a bug in bead) becomes a `bead.BeadError`
/// instead of unwinding into Python.
fn detached<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
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
fn poisoned() -> PyErr {
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
fn setup_error(py: Python<'_>, e: &SetupError) -> PyErr {
    python_error(py, "SetupError", (e.to_string(),))
}

/// A plan that cannot be made: a bad argument (ValueError naming it as a keyword) or a bad
/// `[run]` value of the scene.
fn plan_error(e: PlanError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `bead.RunError` (`bead.DivergenceError` when the state blew up) with the partial run.
fn run_error(py: Python<'_>, e: &RunError, run: Option<Py<PyAny>>) -> PyErr {
    let class = match e {
        RunError::Diverged { .. } => "DivergenceError",
        // advance_to(t) before the current time: a bad argument, nothing ran.
        RunError::TimeBehind { .. } => return PyValueError::new_err(e.to_string()),
        _ => "RunError",
    };
    python_error(py, class, (e.to_string(), run))
}
