"""`Run`: the recorded states of one run, as numpy arrays."""

from __future__ import annotations

import html
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from ._bead import _NO_MULTIPLIERS


class Run:
    """The recorded states of a run, from `Scene.run()`.

    Arrays (float64), T the number of recorded states, P the particles, D the dimension,
    K the formulation's coordinates:

    - ``t`` (T,): time of each state (s)
    - ``positions``, ``velocities`` (T, P, D): particles in scene order (``particles``)
    - ``energy`` (T,): total mechanical energy T + V
    - ``constraint_error`` (T,): max_i |C_i| over the scene's implicit constraints
    - ``q``, ``qdot`` (T, K): the formulation's coordinates (``coordinates``): the
      generalized coordinates for the parametric form, the particle coordinates for the
      implicit one
    - ``work`` (T,) or None: the work done on T + V so far, when something does work
    - ``constraint_force_vectors`` (T, P, D): the total constraint force on each particle
      (J^T lambda in the implicit form, the map's reaction m a - F in the parametric one)
    - ``constraint_forces`` (T, m): the multiplier lambda of each implicit constraint row
      (implicit form only: the parametric form has no rows)

    - ``t_events``, ``y_events``: the crossings of the run's events (``run(events=...)``,
      else the scene's ``[[event]]`` tables, then ``stop_when``), as scipy's: a list with
      one array per event, of the times (k,) and of the particle states there (k, 2 P D:
      the positions then the velocities of every particle, flattened)

    The constraint forces are evaluated at the recorded states when first read (one
    evaluation of the equations of motion per state, the run's own).

    ``summary`` is a dict with the keys and values of ``bead run --json``.
    """

    t: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    energy: np.ndarray
    constraint_error: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    work: Optional[np.ndarray]
    t_events: List[np.ndarray]
    y_events: List[np.ndarray]
    particles: List[str]
    coordinates: List[str]
    columns: List[str]

    def __init__(
        self,
        *,
        t: np.ndarray,
        positions: np.ndarray,
        velocities: np.ndarray,
        energy: np.ndarray,
        constraint_error: np.ndarray,
        q: np.ndarray,
        qdot: np.ndarray,
        work: Optional[np.ndarray],
        summary: Dict[str, Any],
        particles: List[str],
        coordinates: List[str],
        columns: List[str],
        constraint_force_source: Optional[Callable[..., Tuple[np.ndarray, np.ndarray]]] = None,
    ) -> None:
        self.t = t
        self.positions = positions
        self.velocities = velocities
        self.energy = energy
        self.constraint_error = constraint_error
        self.q = q
        self.qdot = qdot
        self.work = work
        self._summary = summary
        self.particles = particles
        self.coordinates = coordinates
        self.columns = columns
        self._force_source = constraint_force_source
        self.t_events = []
        self.y_events = []
        self._forces: Optional[Tuple[np.ndarray, np.ndarray]] = None

    def _constraint_force_arrays(self) -> Tuple[np.ndarray, np.ndarray]:
        if self._forces is None:
            if self._force_source is None:
                raise ValueError("this Run was built without its scene: no constraint forces")
            self._forces = self._force_source(self.t, self.q, self.qdot)
        return self._forces

    @property
    def constraint_forces(self) -> np.ndarray:
        """(T, m): the multiplier lambda of each implicit constraint row at each recorded
        state (row i pushes particle coordinates with lambda_i dC_i/dx). Implicit form only:
        ValueError for the parametric form, whose map holds the particles on the
        constraints without rows (see ``constraint_force_vectors``)."""
        if self.method == "parametric":
            raise ValueError(_NO_MULTIPLIERS)
        return self._constraint_force_arrays()[0]

    @property
    def constraint_force_vectors(self) -> np.ndarray:
        """(T, P, D): the total constraint force on each particle at each recorded state:
        J^T lambda (implicit form) or m a - F, the map's reaction (parametric form); the
        same force for the same state."""
        return self._constraint_force_arrays()[1]

    @property
    def summary(self) -> Dict[str, Any]:
        """The run's figures, with the keys and values of ``bead run --json`` (a new dict)."""
        return dict(self._summary)

    @property
    def method(self) -> str:
        """"implicit" or "parametric"."""
        return str(self._summary["method"])

    @property
    def integrator(self) -> str:
        """The integrator's name."""
        return str(self._summary["integrator"])

    @property
    def completed(self) -> bool:
        """Whether every requested step ran."""
        return bool(self._summary["completed"])

    @property
    def error(self) -> Optional[str]:
        """Why the run stopped early, or None."""
        return self._summary.get("error")

    def __len__(self) -> int:
        return len(self.t)

    def table(self) -> np.ndarray:
        """The states as one (T, len(columns)) array, in the columns of ``bead run --trace``:
        t, then per particle its position and velocity, energy, constraint_error, work when
        tracked, then per coordinate q and qdot."""
        n = len(self.t)
        parts = [self.t[:, None]]
        for i in range(len(self.particles)):
            parts += [self.positions[:, i, :], self.velocities[:, i, :]]
        parts += [self.energy[:, None], self.constraint_error[:, None]]
        if self.work is not None:
            parts.append(self.work[:, None])
        for k in range(len(self.coordinates)):
            parts += [self.q[:, k : k + 1], self.qdot[:, k : k + 1]]
        return np.hstack(parts).reshape(n, len(self.columns))

    def to_pandas(self) -> Any:
        """The states as a pandas DataFrame with the columns of ``bead run --trace`` (t, each
        particle's position and velocity, energy, constraint_error, work when tracked, and
        q.NAME, qdot.NAME for the parametric form). Needs pandas."""
        try:
            import pandas
        except ImportError as e:
            raise ImportError(
                "Run.to_pandas() needs pandas: pip install pandas "
                "(or use the numpy arrays: run.t, run.positions, ...)"
            ) from e
        return pandas.DataFrame(self.table(), columns=self.columns)

    def _repr_html_(self) -> str:
        """A notebook's view of the run: its figures in a small table and, in 2D or 3D (the
        first two axes), each particle's path as a light SVG sketch (at most 400 points)."""
        summary = self._summary
        rows = [
            ("method", f"{self.method}, {self.integrator}, dt = {summary['dt']}"),
            ("states", f"{len(self)}, t = {self.t[0] if len(self) else 0:g} .. "
                       f"{self.t[-1] if len(self) else 0:g}"),
            ("outcome", "completed" if self.completed else f"stopped early: {self.error}"),
            ("|E - E0| / E_scale, max", f"{summary.get('energy_rel_error_max', float('nan')):.3g}"),
            ("max |C|", f"{summary.get('constraint_error_max', float('nan')):.3g}"),
        ]
        if summary.get("newton_iterations") is not None and summary.get("steps"):
            rows.append(("Newton iterations", f"{summary['newton_iterations']} "
                         f"({summary['newton_iterations'] / summary['steps']:.3g} per step, "
                         f"at most {summary['newton_iterations_max']} per solve)"))
        if summary.get("stop_time") is not None:
            rows.append(("stop_when fired at t", f"{summary['stop_time']}"))
        table = "".join(
            f"<tr><th style='text-align:left'>{html.escape(k)}</th>"
            f"<td style='text-align:left'>{html.escape(v)}</td></tr>" for k, v in rows)
        return f"<div><b>bead.Run</b><table>{table}</table>{self._sketch()}</div>"

    def _sketch(self) -> str:
        if len(self) < 2:
            return ""
        xy = self.positions[:, :, :2]
        finite = np.isfinite(xy).all(axis=(1, 2))
        xy = xy[finite]
        if len(xy) < 2:
            return ""
        step = max(1, len(xy) // 400)
        xy = xy[::step]
        lo, hi = xy.reshape(-1, 2).min(axis=0), xy.reshape(-1, 2).max(axis=0)
        span = max(float((hi - lo).max()), 1e-300)
        size, pad = 240.0, 8.0
        scale = (size - 2 * pad) / span
        paths = []
        for p in range(xy.shape[1]):
            points = " ".join(
                f"{pad + (x - lo[0]) * scale:.1f},{pad + (y - lo[1]) * scale:.1f}"
                for x, y in xy[:, p, :])
            paths.append(f"<polyline points='{points}' fill='none' stroke='#1f77b4' "
                         f"stroke-width='1'/>")
        # Screen y points down, as the scenes' +y does in the viewer.
        return (f"<svg width='{size:.0f}' height='{size:.0f}' viewBox='0 0 {size:.0f} "
                f"{size:.0f}' style='border:1px solid #ddd'>{''.join(paths)}</svg>")

    def __repr__(self) -> str:
        state = "completed" if self.completed else f"stopped early: {self.error}"
        return (
            f"<bead.Run {self.method} {self.integrator} dt={self._summary['dt']}: "
            f"{len(self)} states, t = {self.t[0] if len(self) else 0} .. "
            f"{self.t[-1] if len(self) else 0}, {state}>"
        )
