"""Sweeps: one scene run over a grid of parameter values, on every core, as numpy arrays.

The members run in the Rust library (`bead::sweep::Sweep::run_range`) with the GIL released;
this module only shapes what comes back and cuts a sweep into chunks for other processes or
machines (a `Sweep` pickles as the scene's text, its file name, its parameters, the values
swept and the run options).
"""

from __future__ import annotations

import csv
import itertools
import json
import operator
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _bead
from ._errors import RunError
from ._events import Event

# The run options of `Scene.run` that a sweep takes, with their defaults.
_OPTIONS: Dict[str, Any] = {
    "method": None,
    "integrator": None,
    "dt": None,
    "duration": None,
    "steps": None,
    "every": None,
    "t_eval": None,
    "stabilize": None,
    "rtol": None,
    "atol": None,
    "project": False,
    "substeps": None,
    "max_substeps": None,
    "stop_when": None,
    "event_samples": None,
}

# The most bytes a sweep's result may take at once (as the native side counts them).
_MAX_BYTES = 8 << 30

# The run options that may take a list of values, each value a member of the grid: their
# axes come first (outermost), in this order.
_RUN_AXES = ("integrator", "dt")

# The arrays of a member's recorded states, with their trailing dimensions besides (T,).
_TRAJECTORY = ("t", "energy", "constraint_error", "work", "positions", "velocities", "q", "qdot")

# The per-member arrays a result holds, with their trailing dimensions besides the grid's.
_FIELDS = (
    "t_final",
    "stop_time",
    "steps",
    "energy_rel_error_max",
    "energy_balance_error_max",
    "constraint_error_max",
    "newton_iterations",
    "positions",
    "velocities",
    "q",
    "qdot",
)


# A member's status by the code the native side gives it.
_STATUS = np.array(["ok", "event", "failed"], dtype="<U6")

# The columns of `bead sweep`'s CSV before the final state: member, the parameters, then these.
_FIGURES = ("status", "t_final", "stop_time", "steps", "energy_rel_error_max",
            "energy_balance_error_max", "constraint_error_max", "newton_iterations")


def _run_axis(key: str, value: Any) -> Optional[np.ndarray]:
    """The values of run option `key` when a list of them was given (a grid axis), else
    None (one value, or none: every member takes it)."""
    if value is None or isinstance(value, (str, bytes)) or np.ndim(value) == 0:
        return None
    if key == "integrator":
        names = list(value)
        for i, name in enumerate(names):
            if not isinstance(name, str):
                raise TypeError(
                    f"integrator[{i}] = {name!r}: each integrator is a name (bead.INTEGRATORS)"
                )
        if len(set(names)) != len(names):
            raise ValueError(f"integrator={names!r}: an integrator is listed twice")
        array = np.array(names)
    else:
        array = _float_values(key, value)
        if array.ndim != 1:
            raise ValueError(f"{key}: a number or a 1-D array of values, got shape {array.shape}")
    if len(array) == 0:
        raise ValueError(f"{key}: no values to sweep (an empty list)")
    return array


def _float_values(label: str, value: Any) -> np.ndarray:
    """`value` as a float64 array, or an error starting with `label`: ValueError for a value
    beyond a float's range, TypeError for what is not numbers."""
    try:
        return np.asarray(value, dtype=np.float64)
    except OverflowError:
        raise ValueError(
            f"{label}: a value is beyond the range of a float (about 1.8e308); the values "
            "must be finite numbers"
        ) from None
    except (TypeError, ValueError) as e:
        raise TypeError(f"{label}: not an array of numbers ({e})") from None


def _value(x: Any) -> str:
    """A swept value as messages write it: a float's repr, a name quoted."""
    return repr(x) if isinstance(x, str) else repr(float(x))


def _pad(arrays: List[np.ndarray], rows: int) -> List[np.ndarray]:
    """Each array (n, T_i, ...) padded with NaN along its second axis to `rows`."""
    padded = []
    for a in arrays:
        if a.shape[1] < rows:
            wider = np.full((a.shape[0], rows) + a.shape[2:], np.nan)
            wider[:, : a.shape[1]] = a
            a = wider
        padded.append(a)
    return padded


def _merge(flats: List[Dict[str, Any]]) -> Dict[str, Any]:
    """Consecutive members' flat results (native dicts, each with its "run" indices) as one."""
    if len(flats) == 1:
        return flats[0]
    flat: Dict[str, Any] = {}
    for key in ("params", "status", "run") + _FIELDS:
        arrays = [f[key] for f in flats]
        flat[key] = None if arrays[0] is None else np.concatenate(arrays)
    flat["errors"] = [e for f in flats for e in f["errors"]]
    flat["t_events"] = [e for f in flats for e in f["t_events"]]
    recorded = [f["trajectory"] for f in flats]
    if recorded[0] is None:
        flat["trajectory"] = None
    else:
        rows = max(r["t"].shape[1] for r in recorded)
        merged: Dict[str, Any] = {"rows": np.concatenate([r["rows"] for r in recorded])}
        for key in _TRAJECTORY:
            parts = [r[key] for r in recorded]
            if all(p is None for p in parts):
                merged[key] = None
                continue
            like = next(p for p in parts if p is not None)
            parts = [
                p if p is not None else np.full((len(r["rows"]),) + like.shape[1:], np.nan)
                for p, r in zip(parts, recorded)
            ]
            merged[key] = np.concatenate(_pad(parts, rows))
        flat["trajectory"] = merged
    flat["threads"] = max(int(f["threads"]) for f in flats)
    flat["wall_seconds"] = sum(float(f["wall_seconds"]) for f in flats)
    return flat


class SweepTrajectory:
    """The states each member of a sweep recorded (``every=K`` or ``t_eval=``), as numpy
    arrays shaped like the grid, then the rows: with T the most rows any member recorded,

    - ``t``, ``energy``, ``constraint_error``: ``shape + (T,)``
    - ``positions``, ``velocities``: ``shape + (T, P, D)``
    - ``q``, ``qdot``: ``shape + (T, K)`` for the parametric form, else None
    - ``work``: ``shape + (T,)``, the energy ledger's W (the work of drag, applied forces and
      moving constraints on T + V) where it runs, else None
    - ``rows``: ``shape`` (int64), how many rows each member recorded.

    A member's rows are exactly those of its run alone (``scene.with_params(...).run(...)``
    with the same ``every`` or ``t_eval``, bit for bit); the rows past them are NaN (a
    member that stopped at its terminal event or failed records fewer; one that could not
    start none). With ``t_eval`` every member's ``t`` is ``t_eval`` up to its end.
    """

    t: np.ndarray
    energy: np.ndarray
    constraint_error: np.ndarray
    work: Optional[np.ndarray]
    positions: np.ndarray
    velocities: np.ndarray
    q: Optional[np.ndarray]
    qdot: Optional[np.ndarray]
    rows: np.ndarray

    def __init__(self, recorded: Dict[str, Any], shape: Tuple[int, ...]) -> None:
        self.rows = recorded["rows"].reshape(shape)
        for key in _TRAJECTORY:
            value = recorded[key]
            setattr(self, key, None if value is None else value.reshape(shape + value.shape[1:]))

    def __repr__(self) -> str:
        return (
            f"<bead.SweepTrajectory: t {self.t.shape}, positions {self.positions.shape}, "
            f"{int(self.rows.sum())} rows recorded>"
        )


def _quoted(name: str) -> str:
    """`name` in double quotes, as the native side's messages write it: params["g"]."""
    return json.dumps(name, ensure_ascii=False)


def _integer(name: str, value: Any, low: int) -> int:
    """`value` as an int >= `low` (any integer type, not a bool or a float), or an error
    naming `name` and the range."""
    if isinstance(value, bool):
        raise TypeError(f"{name}={value!r}: must be an integer >= {low}, not a bool")
    try:
        n = operator.index(value)
    except TypeError:
        raise TypeError(
            f"{name}={value!r}: must be an integer >= {low}, not a {type(value).__name__}"
        ) from None
    if n < low:
        raise ValueError(f"{name}={n}: must be an integer >= {low}")
    return n


def _axes(params: Mapping[str, Any], what: str = "params") -> Tuple[List[str], List[np.ndarray]]:
    """Names and float64 value arrays (1-D, C-contiguous) of `params` (the argument `what`)."""
    if not hasattr(params, "items"):
        kind = "parameter names" if what == "params" else "initial-state names (bead.x, q.theta)"
        raise TypeError(f"{what} must be a mapping of {kind} to arrays of values")
    names, values = [], []
    for name, value in params.items():
        if not isinstance(name, str):
            raise TypeError(f"{what}: the name {name!r} is not a string")
        array = _float_values(f"{what}[{_quoted(name)}]", value)
        if array.ndim > 1:
            raise ValueError(
                f"{what}[{_quoted(name)}]: a 1-D array of values is needed, got shape {array.shape} "
                "(several parameters make the grid themselves: give each its own values)"
            )
        names.append(name)
        values.append(np.ascontiguousarray(np.atleast_1d(array)))
    return names, values


class SweepResult:
    """What the members of a sweep did, as numpy arrays shaped like the parameter grid.

    ``shape`` is the grid's: the lengths of the swept arrays in the order given (the first
    outermost), or ``(n,)`` for ``zip=True``, or ``(stop - start,)`` for a chunk (``members``
    says which); a list of integrators, then of dt, adds its axis in front (outermost).
    ``names`` lists the axes in that order. With P particles in D dimensions and K
    generalized coordinates:

    - ``params``: dict name -> array ``shape``, each member's value of each swept parameter
      (and of ``integrator`` (str) and ``dt`` when they are swept)
    - ``status`` ``shape`` (str): "ok" (ran to the end), "event" (stopped at its stop_when),
      "failed" (``errors`` says why)
    - ``t_final``, ``stop_time`` (NaN where the event did not fire), ``steps`` (int64),
      ``energy_rel_error_max`` (max of |E - E0| / E_scale, as ``run.summary``),
      ``energy_balance_error_max`` (max of |E - W - E0| / E_scale where something does
      work on the system, else NaN), ``constraint_error_max``, ``newton_iterations``
      (float64: the Newton iterations of all steps of rattle, rattle4, fast-projection and
      ``project=True``, as ``Simulation.newton_iterations``; NaN for the other
      integrators): ``shape``
    - ``positions``, ``velocities`` ``shape + (P, D)``: the final state
    - ``q``, ``qdot`` ``shape + (K,)`` for the parametric form, else None
    - ``errors`` ``shape`` (object): each member's error message, or None
    - ``t_events`` ``shape`` (object): each member's crossing times, a list with an array
      per event (the scene's ``[[event]]`` tables, ``events=``, then ``stop_when``), as a
      run's ``t_events``
    - ``trajectory``: the states each member recorded (a `bead.SweepTrajectory`, arrays
      ``shape + (T, ...)``) when the sweep was given ``every=`` or ``t_eval=``, else None

    A member that failed keeps the figures up to its last good state; one that could not
    start has NaN (and 0 steps). ``to_pandas()`` gives one row per member with the columns of
    ``bead sweep``'s CSV. Every member has the scene's particles and coordinates: a sweep
    whose parameter changes them (a chain's ``N``) raises ValueError naming the first member
    that differs.
    """

    names: List[str]
    axes: Dict[str, np.ndarray]
    shape: Tuple[int, ...]
    members: range
    params: Dict[str, np.ndarray]
    status: np.ndarray
    t_final: np.ndarray
    stop_time: np.ndarray
    steps: np.ndarray
    energy_rel_error_max: np.ndarray
    energy_balance_error_max: np.ndarray
    constraint_error_max: np.ndarray
    newton_iterations: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    q: Optional[np.ndarray]
    qdot: Optional[np.ndarray]
    errors: np.ndarray
    t_events: np.ndarray
    trajectory: Optional[SweepTrajectory]
    particles: List[str]
    coordinates: List[str]
    columns: List[str]
    method: str
    title: str
    threads: int
    wall_seconds: float

    def __init__(
        self,
        flat: Dict[str, Any],
        *,
        names: List[str],
        axes: Dict[str, np.ndarray],
        run_axes: Dict[str, np.ndarray],
        shape: Tuple[int, ...],
        members: range,
        particles: List[str],
        coordinates: List[str],
        columns: List[str],
        method: str,
        title: str,
        total: int,
    ) -> None:
        self._flat = flat
        self._total = total
        self._param_names = list(names)
        self._run_axes = run_axes
        self.names = list(run_axes) + list(names)
        self.axes = {**run_axes, **axes}
        self.shape = tuple(shape)
        self.members = members
        self.particles = particles
        self.coordinates = coordinates
        self.columns = columns
        self.method = method
        self.title = title
        self.threads = int(flat["threads"])
        self.wall_seconds = float(flat["wall_seconds"])
        self.params = {}
        if run_axes:
            run_shape = tuple(len(v) for v in run_axes.values())
            for name, at in zip(run_axes, np.unravel_index(flat["run"], run_shape)):
                self.params[name] = run_axes[name][at].reshape(self.shape)
        for i, name in enumerate(self._param_names):
            self.params[name] = flat["params"][:, i].reshape(self.shape)
        self.status = _STATUS[flat["status"]].reshape(self.shape)
        errors = np.empty(len(flat["errors"]), dtype=object)
        errors[:] = flat["errors"]
        self.errors = errors.reshape(self.shape)
        t_events = np.empty(len(flat["t_events"]), dtype=object)
        for i, times in enumerate(flat["t_events"]):
            t_events[i] = times
        self.t_events = t_events.reshape(self.shape)
        recorded = flat.get("trajectory")
        self.trajectory = None if recorded is None else SweepTrajectory(recorded, self.shape)
        for field in _FIELDS:
            value = flat[field]
            setattr(
                self,
                field,
                None if value is None else value.reshape(self.shape + value.shape[1:]),
            )

    def __len__(self) -> int:
        return len(self.members)

    @property
    def members_per_second(self) -> float:
        """Members run per second of wall time."""
        return len(self) / self.wall_seconds if self.wall_seconds > 0 else float("inf")

    def counts(self) -> Dict[str, int]:
        """How many members ended "ok", "event" and "failed"."""
        return {s: int(np.count_nonzero(self.status == s)) for s in ("ok", "event", "failed")}

    def table(self) -> Dict[str, np.ndarray]:
        """One flat array per column of ``bead sweep``'s CSV (``columns``), in that order."""
        flat = self._flat
        n = len(self)
        data: Dict[str, np.ndarray] = {"member": np.arange(self.members.start, self.members.stop)}
        for name in self._run_axes:
            data[name] = self.params[name].ravel()
        # The CSV's names: an axis of the start is start.bead.x (bead.x is the final state's).
        first_param = 1 + len(self._run_axes)
        for i, column in enumerate(self.columns[first_param:first_param + len(self._param_names)]):
            data[column] = flat["params"][:, i]
        data["status"] = _STATUS[flat["status"]]
        for key in _FIGURES[1:]:
            data[key] = flat[key]
        parts = [flat["positions"].reshape(n, -1), flat["velocities"].reshape(n, -1)]
        if flat["q"] is not None:
            parts += [flat["q"], flat["qdot"]]
        state = np.hstack(parts) if parts else np.empty((n, 0))
        first = 1 + len(self.names) + len(_FIGURES)
        for j, column in enumerate(self.columns[first:-1]):
            data[column] = state[:, j]
        errors = np.empty(n, dtype=object)
        errors[:] = flat["errors"]
        data["error"] = errors
        return data

    def to_pandas(self) -> Any:
        """One row per member, with the columns of ``bead sweep``'s CSV: member, the swept
        parameters (``integrator`` and ``dt`` first when they are swept), status, t_final, stop_time, steps, energy_rel_error_max,
        energy_balance_error_max, constraint_error_max, newton_iterations, each particle's final position and
        velocity (P.x, P.vx, ...), q.NAME and qdot.NAME for the parametric form, error. Needs
        pandas."""
        try:
            import pandas
        except ImportError as e:
            raise ImportError(
                "SweepResult.to_pandas() needs pandas: pip install pandas "
                "(or use the numpy arrays: result.t_final, result.positions, ...)"
            ) from e
        return pandas.DataFrame(self.table(), columns=self.columns)

    def __repr__(self) -> str:
        counts = self.counts()
        grid = " x ".join(f"{name}[{len(self.axes[name])}]" for name in self.names)
        chunk = ""
        if len(self.members) != self._total:
            chunk = f", members {self.members.start}..{self.members.stop} of {self._total}"
        return (
            f"<bead.SweepResult {self.title!r} {self.method}: {grid}, shape {self.shape}"
            f"{chunk}; {counts['ok']} ok, {counts['event']} stopped at the event, "
            f"{counts['failed']} failed; {self.wall_seconds:.3g} s on {self.threads} "
            f"thread(s)>"
        )


class Sweep:
    """A scene swept over parameter values: ``Sweep(scene, params, zip=False, **options)``.

    ``params`` maps names of the scene's ``[params]`` table to 1-D arrays of values; with
    several names the members are every combination (the first name outermost, like a C
    array of shape ``tuple(len(v) for v in params.values())``), or with ``zip=True`` value i
    of each (all of one length). ``options`` are ``Scene.run``'s keyword arguments: each
    member is exactly ``scene.with_params({...}).run(**options)``, bit for bit. A list of
    ``integrator`` names and a list of ``dt`` values are axes too, in front of the others
    (integrator outermost): each member runs one of each. ``every=K`` or ``t_eval=times``
    makes each member record its states (the result's ``trajectory``).

    ``run(threads=0)`` runs every member; ``run_range(start, stop)`` runs a chunk of them
    (members are numbered row-major over the grid) and ``assemble(chunks)`` joins chunks into
    the whole result, equal bit for bit to ``run()`` whatever the chunking or the number of
    threads. A ``Sweep`` pickles as plain data (the scene's text, its file name and
    parameters, the values and the options), so chunks can run in other processes or on
    other machines (``examples/dask_sweep.py``). ``chunks(count)`` proposes the ranges.
    """

    def __init__(
        self,
        scene: _bead.Scene,
        params: Optional[Mapping[str, Any]] = None,
        *,
        initial: Optional[Mapping[str, Any]] = None,
        zip: bool = False,
        events: Optional[Sequence[Any]] = None,
        **options: Any,
    ) -> None:
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise TypeError(
                f"Sweep: unexpected keyword argument(s) {', '.join(unknown)}; the run "
                f"options are {', '.join(_OPTIONS)}"
            )
        if not isinstance(scene, _bead.Scene):
            raise TypeError(f"Sweep: scene must be a bead.Scene, got {type(scene).__name__}")
        names, values = _axes(params if params is not None else {})
        more, more_values = _axes(initial if initial is not None else {}, "initial")
        names, values = names + more, values + more_values
        run_axes: Dict[str, np.ndarray] = {}
        for key in _RUN_AXES:
            axis = _run_axis(key, options.get(key))
            if axis is not None:
                run_axes[key] = axis
        if not names and not run_axes:
            raise ValueError(
                "a sweep needs values to sweep: params={name: values} and/or "
                "initial={'bead.x': values} (a particle's NAME.x, NAME.vx, or q.NAME, qdot.NAME), "
                "or a list of integrators or of dt values"
            )
        # Events watched by every member: `[[event]]` tables added to the scene, so that a
        # member is exactly that scene's run (and the tables travel with a pickled sweep).
        if isinstance(events, str):
            raise TypeError(
                "Sweep: events must be a list of bead.Event (or expression strings), got a "
                "string; write events=[...]"
            )
        for i, event in enumerate(events or []):
            if isinstance(event, str):
                event = Event(event)
            if not isinstance(event, Event):
                raise TypeError(
                    f"Sweep: events[{i}]: expected a bead.Event or an expression string, got "
                    f"{type(event).__name__}"
                )
            scene = scene.with_event(event.expr, event.direction, event.terminal)
        self._scene = scene
        self._names = names
        self._values = values
        self._run_axes = run_axes
        self._zip = bool(zip)
        # Only what was given, so that the pickled form is short and says what was asked.
        self._options = {
            k: v for k, v in options.items() if v is not _OPTIONS[k]
        }
        self._plans = self._make_plans()

    def _make_plans(self) -> List[_bead.SweepPlan]:
        """One native plan per combination of the run options swept (integrator outermost),
        each over the parameters."""
        # The native side reads the values in place: C-contiguous and aligned (an array from
        # a buffer, or unpickled by Dask from a frame, may be neither).
        values = [np.require(v, np.float64, ["C", "A"]) for v in self._values]
        fixed = {k: v for k, v in self._options.items() if k not in self._run_axes}
        plans = []
        for combination in itertools.product(*self._run_axes.values()):
            run = {
                k: str(v) if k == "integrator" else float(v)
                for k, v in zip(self._run_axes, combination)
            }
            try:
                plans.append(
                    _bead.SweepPlan(self._scene, self._names, values, self._zip, **fixed, **run)
                )
            except ValueError as e:
                # A bad option, or one the formulation cannot take (bead.SetupError).
                if not run:
                    raise
                which = ", ".join(f"{k}={_value(v)}" for k, v in run.items())
                raise type(e)(f"the members with {which}: {e}") from None
        return plans

    def __getstate__(self) -> Dict[str, Any]:
        state = dict(self.__dict__)
        del state["_plans"]
        return state

    def __setstate__(self, state: Dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._plans = self._make_plans()

    @property
    def scene(self) -> _bead.Scene:
        """The scene swept."""
        return self._scene

    @property
    def names(self) -> List[str]:
        """The axes, in order: the run options swept (integrator, dt), then the parameters."""
        return list(self._run_axes) + list(self._names)

    @property
    def axes(self) -> Dict[str, np.ndarray]:
        """Each axis's values (copies)."""
        axes = {n: v.copy() for n, v in self._run_axes.items()}
        axes.update({n: v.copy() for n, v in zip(self._names, self._values)})
        return axes

    @property
    def zip(self) -> bool:
        """Whether the axes are zipped (else the full grid)."""
        return self._zip

    @property
    def options(self) -> Dict[str, Any]:
        """The run options given (those that differ from the defaults)."""
        return dict(self._options)

    @property
    def shape(self) -> Tuple[int, ...]:
        """The shape of the results: the run options' and parameters' axes' lengths (the
        parameters' (n,) when zipped)."""
        return tuple(len(v) for v in self._run_axes.values()) + tuple(self._plans[0].shape)

    @property
    def method(self) -> str:
        """The formulation the members run: "implicit" or "parametric"."""
        return self._plans[0].method

    def __len__(self) -> int:
        return len(self._plans) * len(self._plans[0])

    def chunks(self, count: int) -> List[Tuple[int, int]]:
        """`count` ranges (start, stop) of about equal size covering the members in order."""
        count = _integer("count", count, 1)
        n = len(self)
        count = min(count, n)
        bounds = [n * i // count for i in range(count + 1)]
        return [(a, b) for a, b in zip(bounds, bounds[1:])]

    def _result(self, flat: Dict[str, Any], members: range, shape: Tuple[int, ...]) -> SweepResult:
        plan = self._plans[0]
        columns = next(csv.reader([plan.csv_header]))
        columns[1:1] = list(self._run_axes)
        return SweepResult(
            flat,
            names=list(self._names),
            axes={n: v.copy() for n, v in zip(self._names, self._values)},
            run_axes={n: v.copy() for n, v in self._run_axes.items()},
            shape=shape,
            members=members,
            particles=plan.particles,
            coordinates=plan.coordinates,
            columns=columns,
            method=plan.method,
            title=self._scene.title,
            total=len(self),
        )

    def _run(self, start: int, stop: int, threads: int) -> Dict[str, Any]:
        """Members `start` .. `stop` - 1 as one flat result: each plan runs its share."""
        per_plan = len(self._plans[0])
        if len(self._plans) == 1:
            flat = self._plans[0].run_range(start, stop, threads)
            flat["run"] = np.zeros(len(flat["status"]), dtype=np.int64)
            return flat
        n = len(self)
        start = _integer("start", start, 0)
        stop = _integer("stop", stop, 0)
        if not start <= stop <= n:
            raise IndexError(
                f"members {start}..{stop}: not a range of the sweep's {n} members (0..{n})"
            )
        # Each plan refuses a share past 8 GiB; the shares together must fit too.
        need = sum(
            (min(stop, (v + 1) * per_plan) - max(start, v * per_plan)) * plan.bytes_per_member
            for v, plan in enumerate(self._plans)
            if min(stop, (v + 1) * per_plan) > max(start, v * per_plan)
        )
        if need > _MAX_BYTES:
            raise ValueError(
                f"{stop - start} members need about {need / 2**30:.3g} GiB for their result "
                "arrays, more than the 8 GiB a sweep returns at once; run it in chunks that "
                "fit and keep what you need of each: sweep = bead.Sweep(scene, params, ...), "
                f"then sweep.run_range(start, stop) for each (start, stop) in "
                f"sweep.chunks({max(2, -(-need // (_MAX_BYTES // 2)))})"
            )
        flats = []
        for v, plan in enumerate(self._plans):
            a, b = max(start, v * per_plan), min(stop, (v + 1) * per_plan)
            if a < b:
                flat = plan.run_range(a - v * per_plan, b - v * per_plan, threads)
                flat["run"] = np.full(b - a, v, dtype=np.int64)
                flats.append(flat)
        if not flats:
            flat = self._plans[0].run_range(0, 0, threads)
            flat["run"] = np.zeros(0, dtype=np.int64)
            flats.append(flat)
        return _merge(flats)

    def run_range(self, start: int, stop: int, threads: int = 0) -> SweepResult:
        """Run members `start` .. `stop` - 1 on `threads` threads (0: one per core) with the
        GIL released; a result of shape (stop - start,), to `assemble` with the others.
        Members that all fail are returned, not raised (a chunk is judged when assembled).
        Ctrl-C raises KeyboardInterrupt within about a second.

        Raises ValueError for a range that is not inside ``0 .. len(self)`` (the message
        names the argument), when the result would take more than 8 GiB (the message says
        how much; run smaller chunks) or when a member's particles are not the scene's (see
        `SweepResult`)."""
        flat = self._run(start, stop, threads)
        # Accepted as integers in range.
        start, stop = operator.index(start), operator.index(stop)
        return self._result(flat, range(start, stop), (stop - start,))

    def run(self, threads: int = 0) -> SweepResult:
        """Run every member on `threads` threads (0: one per core); arrays shaped like the
        grid. Raises `bead.RunError` when every member failed (its ``result`` holds the
        `SweepResult`, its message the first member's error)."""
        flat = self._run(0, len(self), threads)
        return _unless_all_failed(self._result(flat, range(len(self)), self.shape))

    def assemble(self, chunks: Iterable[SweepResult]) -> SweepResult:
        """The whole sweep's result from chunks (`run_range` results, in any order) that
        cover every member once; arrays shaped like the grid. ``wall_seconds`` is the sum of
        the chunks' and ``threads`` the most any chunk used. Raises `bead.RunError`, as
        `run` does, when every member failed."""
        parts = sorted(chunks, key=lambda c: c.members.start)
        at = 0
        for part in parts:
            if part.members.start != at:
                what = "overlap" if part.members.start < at else "leave a gap"
                raise ValueError(
                    f"assemble: the chunks {what} at member {min(at, part.members.start)} "
                    f"(a chunk starts at {part.members.start}, the members before end at {at})"
                )
            if part.names != self.names:
                raise ValueError("assemble: a chunk of another sweep (other parameters)")
            at = part.members.stop
        if at != len(self):
            raise ValueError(f"assemble: the chunks end at member {at} of {len(self)}")
        flat = _merge([p._flat for p in parts])
        return _unless_all_failed(self._result(flat, range(len(self)), self.shape))

    def __repr__(self) -> str:
        joined = " zip " if self._zip else " x "
        grid = joined.join(f"{n}[{len(v)}]" for n, v in zip(self._names, self._values))
        grid = " x ".join([f"{n}[{len(v)}]" for n, v in self._run_axes.items()] + [grid] * bool(grid))
        options = ", ".join(
            f"{k}={v!r}" for k, v in self._options.items() if k != "method" and k not in self._run_axes
        )
        return (
            f"<bead.Sweep {self._scene.title!r}: {grid} = {len(self)} members, "
            f"{self.method}{', ' + options if options else ''}>"
        )


def _unless_all_failed(result: SweepResult) -> SweepResult:
    """`result`, or `bead.RunError` (with ``result`` attached) when every member failed."""
    failed = result.status == "failed"
    if len(result) == 0 or not failed.all():
        return result
    first = int(np.flatnonzero(failed.ravel())[0])
    values = ", ".join(f"{n} = {_value(result.params[n].ravel()[first])}" for n in result.names)
    message = result.errors.ravel()[first] or "it could not start"
    error = RunError(
        f"every member of the sweep failed ({len(result)} of {len(result)}); the first, "
        f"member {result.members.start + first} ({values}): {message}")
    error.result = result  # type: ignore[attr-defined]
    raise error


def sweep(
    scene: _bead.Scene,
    params: Optional[Mapping[str, Any]] = None,
    *,
    initial: Optional[Mapping[str, Any]] = None,
    zip: bool = False,
    members: Optional[Union[range, Sequence[int]]] = None,
    threads: int = 0,
    method: Optional[str] = None,
    integrator: Optional[Union[str, Sequence[str]]] = None,
    dt: Optional[Union[float, Sequence[float]]] = None,
    duration: Optional[float] = None,
    steps: Optional[int] = None,
    every: Optional[int] = None,
    t_eval: Optional[Sequence[float]] = None,
    stabilize: Optional[Tuple[float, float]] = None,
    rtol: Optional[float] = None,
    atol: Optional[float] = None,
    project: bool = False,
    substeps: Optional[int] = None,
    max_substeps: Optional[int] = None,
    stop_when: Optional[str] = None,
    event_samples: Optional[int] = None,
    events: Optional[Sequence[Any]] = None,
) -> SweepResult:
    """Run `scene` once per combination of parameter values, on every core, and return a
    `bead.SweepResult` of numpy arrays shaped like the parameter grid.

    ``params`` maps names of the scene's ``[params]`` table to 1-D arrays of values, e.g.
    ``{"x0": np.linspace(10, 200, 10_000)}``; ``initial`` maps numbers of the scene's start
    to values, named as the trace's columns: ``{"bead.x": xs}`` (a particle's position,
    ``bead.vx`` its velocity) or ``{"q.theta": thetas}`` (the parametric form's coordinate,
    ``qdot.theta`` its rate); each member's start is the scene's with those numbers set,
    placed on the constraints as `Scene.with_state` places it. Several names make the full grid (the first
    outermost; the result's shape is the arrays' lengths), or with ``zip=True`` one member
    per position (all arrays of one length n; shape (n,)). Each member is exactly
    ``scene.with_params({...}).run(...)`` with the same options, bit for bit: method,
    integrator, dt, duration or steps, every, t_eval, stabilize, rtol, atol, project, substeps,
    max_substeps, stop_when and event_samples are those of `Scene.run` (the scene's ``[run]`` table
    supplies what is not given), and ``events`` (a list of `bead.Event`) are watched by
    every member as ``[[event]]`` tables of the scene (`Scene.with_event`): their crossing
    times are the result's ``t_events``.

    A list of integrators (``integrator=["rk4", "rattle"]``) or of step sizes
    (``dt=[1e-2, 5e-3]``) sweeps them too: their axes come first (integrator outermost, then
    dt, then the parameters), and ``params`` may then be omitted. ``every=K`` (every K-th
    step, as `Scene.run` records) or ``t_eval=times`` (the states at those times, exactly)
    makes each member record its states: the result's ``trajectory`` holds them as arrays
    shaped ``shape + (T, ...)`` (MuJoCo's ``rollout``); without them a member records only
    its figures and final state, and members that share their equations step together. A member that fails is reported (status "failed", its
    message in ``errors``), not raised; but when every member fails (the whole sweep, not a
    chunk given by ``members=``) `bead.RunError` is raised, with the first member's error as
    its message and the `SweepResult` as its ``result``.

    The members run on ``threads`` threads (0: one per core; at most 1024) with the GIL
    released; the numbers do not depend on the thread count. Ctrl-C raises KeyboardInterrupt
    within about a second. ``members=range(a, b)`` runs only those members (row-major numbering over the
    grid) and returns a result of shape (b - a,): see `bead.Sweep` to cut a sweep into
    chunks for other processes or machines and join them.

    Raises ValueError for an unknown parameter name, values that are not finite, a bad
    option, more than 2^32 members, a result that would take more than 8 GiB (the message
    says how much; run it in chunks with `bead.Sweep.run_range`), or a member whose particles
    are not the scene's (a swept ``N`` that sets their number: the arrays are shaped grid +
    (P, D) with the scene's P; the message names the member).
    """
    options = {
        "method": method,
        "integrator": integrator,
        "dt": dt,
        "duration": duration,
        "steps": steps,
        "every": every,
        "t_eval": t_eval,
        "stabilize": stabilize,
        "rtol": rtol,
        "atol": atol,
        "project": project,
        "substeps": substeps,
        "max_substeps": max_substeps,
        "stop_when": stop_when,
        "event_samples": event_samples,
    }
    plan = Sweep(scene, params, initial=initial, zip=zip, events=events, **options)
    if members is None:
        return plan.run(threads)
    try:
        picked = members if isinstance(members, range) else range(*members)
    except TypeError:
        raise TypeError(
            f"members={members!r}: must be a range of member indices (or (start, stop))"
        ) from None
    n = len(plan)
    if picked.step != 1 or not 0 <= picked.start <= picked.stop <= n:
        raise ValueError(
            f"members={members!r}: must be a range of consecutive members (step 1) within "
            f"range(0, {n})"
        )
    return plan.run_range(picked.start, picked.stop, threads)
