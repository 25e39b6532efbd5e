"""Type stubs of the native module `bead._bead` (kept in sync by tests/test_stubs.py)."""

import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike

from ._events import Event
from ._run import Run

__version__: str
INTEGRATORS: List[str]
METHODS: List[str]

def load(
    path: Union[str, os.PathLike[str]], params: Optional[Mapping[str, float]] = None
) -> Scene:
    """Load a scene file (TOML); `params` overrides `[params]` values. Raises bead.SceneError."""

def loads(
    text: str, params: Optional[Mapping[str, float]] = None, name: str = "<string>"
) -> Scene:
    """Load a scene from TOML text; `name` stands for the file in messages."""

class Scene:
    """A loaded scene (immutable)."""

    @property
    def title(self) -> str: ...
    @property
    def file(self) -> str: ...
    @property
    def particles(self) -> List[str]: ...
    @property
    def dimension(self) -> int: ...
    @property
    def params(self) -> Dict[str, float]: ...
    @property
    def param_info(self) -> Dict[str, Dict[str, Any]]: ...
    @property
    def methods(self) -> List[str]: ...
    @property
    def default_method(self) -> str: ...
    @property
    def coordinates(self) -> List[str]: ...
    @property
    def constraint_count(self) -> int: ...
    @property
    def run_defaults(self) -> Dict[str, Any]: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def text(self) -> str: ...
    def with_params(self, params: Mapping[str, float]) -> Scene: ...
    def with_state(
        self,
        *,
        positions: Optional[ArrayLike] = None,
        velocities: Optional[ArrayLike] = None,
        q: Optional[ArrayLike] = None,
        qdot: Optional[ArrayLike] = None,
    ) -> Scene:
        """A copy started elsewhere, placed on the constraints (the same start for both
        forms); a UserWarning says how far the start moved when more than rounding."""
    @property
    def start(self) -> Optional[Dict[str, np.ndarray]]: ...
    def with_event(self, expr: str, direction: int = 0, terminal: bool = False) -> Scene:
        """A copy with an [[event]] table added (see bead.Event)."""
    def with_force(self, kind: str, **keys: Any) -> Scene:
        """A copy with a [[force]] table added (constant, spring or drag)."""
    def run(
        self,
        *,
        method: Optional[str] = None,
        integrator: Optional[str] = None,
        dt: Optional[float] = None,
        duration: Optional[float] = None,
        steps: Optional[int] = None,
        every: Optional[int] = None,
        stabilize: Optional[Tuple[float, float]] = None,
        rtol: Optional[float] = None,
        atol: Optional[float] = None,
        project: bool = False,
        substeps: Optional[int] = None,
        max_substeps: Optional[int] = None,
        stop_when: Optional[str] = None,
        event_samples: Optional[int] = None,
        initial: Optional[Mapping[str, ArrayLike]] = None,
        t_eval: Optional[ArrayLike] = None,
        events: Optional[Sequence[Union[Event, str]]] = None,
    ) -> Run:
        """Run the scene; arguments override its [run] table. stop_when ends the run where
        the expression (e.g. "bead.y - 100") crosses zero upward (summary["stop_time"]);
        events (bead.Event, scipy's) are recorded in run.t_events and run.y_events.
        Raises ValueError, bead.SetupError, bead.RunError (with .run, the partial run)."""
    def order(
        self,
        *,
        integrators: Optional[Sequence[str]] = None,
        dt: Optional[float] = None,
        duration: Optional[float] = None,
        steps: Optional[int] = None,
        halvings: int = 4,
        reference_rtol: float = 1e-13,
    ) -> Dict[str, Any]:
        """A convergence study (as `bead order`): each integrator with every form at dt,
        dt/2, ..., against dopri5 at reference_rtol. study["runs"] is a dict of columns
        (method, integrator, dt, steps, evaluations, wall_seconds, position_error,
        energy_error, constraint_error and their orders per halving) for pandas.DataFrame;
        study["floors"], study["reference"], study["failures"] ("method integrator" to
        {dt: why} for each step whose run failed; the finer steps still run)."""
    def simulation(
        self,
        *,
        method: Optional[str] = None,
        integrator: Optional[str] = None,
        dt: Optional[float] = None,
        stabilize: Optional[Tuple[float, float]] = None,
        rtol: Optional[float] = None,
        atol: Optional[float] = None,
        project: bool = False,
        substeps: Optional[int] = None,
        max_substeps: Optional[int] = None,
        stop_when: Optional[str] = None,
        event_samples: Optional[int] = None,
        initial: Optional[Mapping[str, ArrayLike]] = None,
        events: Optional[Sequence[Union[Event, str]]] = None,
    ) -> Simulation:
        """A simulation to step by hand, at the scene's initial state."""

class Simulation:
    """A simulation stepped by hand (from Scene.simulation())."""

    def step(self, count: int = 1) -> None: ...
    def advance_to(self, t: float) -> None: ...
    def reset(self) -> None: ...
    @property
    def t(self) -> float: ...
    @property
    def positions(self) -> np.ndarray: ...
    @property
    def velocities(self) -> np.ndarray: ...
    @property
    def q(self) -> np.ndarray: ...
    @property
    def qdot(self) -> np.ndarray: ...
    @property
    def contact_switches(self) -> List[Dict[str, Any]]: ...
    @property
    def detached(self) -> List[bool]: ...
    @property
    def energy(self) -> float: ...
    @property
    def constraint_error(self) -> float: ...
    @property
    def steps(self) -> int: ...
    @property
    def newton_iterations(self) -> Optional[int]: ...
    @property
    def method(self) -> str: ...
    @property
    def integrator(self) -> str: ...
    @property
    def dt(self) -> float: ...
    @property
    def particles(self) -> List[str]: ...
    @property
    def coordinates(self) -> List[str]: ...
    def set_state(
        self,
        *,
        positions: Optional[ArrayLike] = None,
        velocities: Optional[ArrayLike] = None,
        q: Optional[ArrayLike] = None,
        qdot: Optional[ArrayLike] = None,
        t: Optional[float] = None,
    ) -> None:
        """Set the state (placed on the constraints) and start from it."""
    def apply_force(self, particle: Union[str, int], force: Optional[ArrayLike]) -> None:
        """Hold a constant force on a particle from now on (None removes it)."""
    @property
    def applied_forces(self) -> Dict[str, np.ndarray]: ...
    def set_param(self, name: str, value: float) -> None:
        """Change a parameter of the scene and go on from the current state."""
    @property
    def params(self) -> Dict[str, float]: ...
    @property
    def constraint_forces(self) -> np.ndarray: ...
    @property
    def constraint_force_vectors(self) -> np.ndarray: ...
    @property
    def work(self) -> float: ...
    @property
    def energy_initial(self) -> float: ...
    @property
    def event_fired(self) -> bool: ...
    @property
    def fired_event(self) -> Optional[int]: ...
    @property
    def t_events(self) -> List[np.ndarray]: ...
    @property
    def y_events(self) -> List[np.ndarray]: ...

class ConstraintForceSource:
    """The constraint forces of a run's recorded states (used by bead.Run)."""

    @property
    def method(self) -> str: ...
    def __call__(
        self, t: np.ndarray, q: np.ndarray, qdot: np.ndarray
    ) -> Tuple[np.ndarray, np.ndarray]: ...

class SweepPlan:
    """The native half of bead.Sweep (use bead.sweep or bead.Sweep instead)."""

    def __init__(
        self,
        scene: Scene,
        names: List[str],
        values: List[np.ndarray],
        zip: bool = False,
        *,
        method: Optional[str] = None,
        integrator: Optional[str] = None,
        dt: Optional[float] = None,
        duration: Optional[float] = None,
        steps: Optional[int] = None,
        every: Optional[int] = None,
        stabilize: Optional[Tuple[float, float]] = None,
        rtol: Optional[float] = None,
        atol: Optional[float] = None,
        project: bool = False,
        substeps: Optional[int] = None,
        max_substeps: Optional[int] = None,
        stop_when: Optional[str] = None,
        event_samples: Optional[int] = None,
        t_eval: Optional[Any] = None,
    ) -> None: ...
    def __len__(self) -> int: ...
    @property
    def shape(self) -> List[int]: ...
    @property
    def names(self) -> List[str]: ...
    @property
    def method(self) -> str: ...
    @property
    def bytes_per_member(self) -> int: ...
    @property
    def csv_header(self) -> str: ...
    @property
    def particles(self) -> List[str]: ...
    @property
    def dimension(self) -> int: ...
    @property
    def coordinates(self) -> List[str]: ...
    def run_range(self, start: int, stop: int, threads: int = 0) -> Dict[str, Any]:
        """Run members start..stop-1 with the GIL released; flat arrays, one row per member."""
