"""`Run`: the recorded states of one run, as numpy arrays."""

from __future__ import annotations

from typing import Any, Dict, List, Optional

import numpy as np


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

    def __repr__(self) -> str:
        state = "completed" if self.completed else f"stopped early: {self.error}"
        return (
            f"<bead.Run {self.method} {self.integrator} dt={self._summary['dt']}: "
            f"{len(self)} states, t = {self.t[0] if len(self) else 0} .. "
            f"{self.t[-1] if len(self) else 0}, {state}>"
        )
