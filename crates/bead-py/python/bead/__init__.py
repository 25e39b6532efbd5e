"""bead: constrained particle dynamics from scene files, in Python.

A run records every state as numpy arrays (paths are relative to the repository's root):

>>> import bead
>>> scene = bead.load("scenes/parabola.toml", params={"g": 9.81})
>>> run = scene.run(method="implicit", integrator="rattle", dt=1/60, duration=10.0)
>>> run.positions.shape, run.summary["t_final"], run.summary["completed"]
((601, 1, 2), 10.0, True)

A simulation steps by hand:

>>> sim = scene.simulation(method="parametric", integrator="gauss-legendre", dt=1e-3)
>>> sim.advance_to(2.5)
>>> sim.t, sim.positions.shape
(2.5, (1, 2))

A sweep runs a scene once per value of its parameters, on every core:

>>> import numpy as np
>>> scene = bead.load("scenes/parabola-x0.toml")
>>> result = bead.sweep(scene, params={"x0": np.linspace(10, 200, 1000)}, steps=1000)
>>> result.t_final.shape, result.counts()
((1000,), {'ok': 1000, 'event': 0, 'failed': 0})
>>> result.to_pandas().shape[0]
1000

Integrators and step sizes can be axes too, and members can record their states:

>>> grid = bead.sweep(scene, integrator=["rk4", "rattle"], dt=[1/60, 1/120], steps=60,
...                   every=30)
>>> grid.shape, grid.trajectory.positions.shape   # (integrator, dt) + (rows, P, D)
((2, 2), (2, 2, 3, 1, 2))

A state can be set, a force held, a parameter changed, and the constraint forces read:

>>> sim = bead.load("scenes/circle.toml").simulation(dt=1e-3)
>>> sim.set_state(positions=[[0.0, 1.0]], velocities=[[2.0, 0.0]])
>>> sim.constraint_force_vectors.round(12).tolist()   # the rod pulls with m (g + v^2 / L)
[[0.0, -13.81]]
>>> sim.apply_force("bead", [3.0, 0.0])
>>> sim.set_param("g", 1.62)
>>> run = bead.load("scenes/circle.toml").run(t_eval=[0.0, 0.5, 1.0])
>>> run.t.tolist(), run.constraint_force_vectors.shape
([0.0, 0.5, 1.0], (3, 1, 2))

Events are scipy's: each with a direction (1 up, -1 down, 0 either) and terminal or not,
their crossings located on the integrator's path:

>>> run = bead.load("scenes/circle.toml").run(duration=3.5, events=[
...     bead.Event("bead.x", direction=-1), bead.Event("bead.vx", direction=1)])
>>> [t.round(9).tolist() for t in run.t_events]   # T/4, 5T/4 and T/2, 3T/2 (T = 2.1529 s)
[[0.538218667, 2.691093334], [1.076437333, 3.229312]]

A scene can be built in Python (`bead.Builder`, which writes the scene file's TOML) or
started elsewhere (`scene.with_state`, `run(initial=...)`, `bead.sweep(initial=...)`). The
scene file format: docs/scene-format.md in the repository.

The physics is the Rust library's (the same as the `bead` command line): the run's
`summary` has the keys and values of `bead run --json`.
"""

from ._builder import Builder
from ._events import Event
from ._errors import BeadError, DivergenceError, RunError, SceneError, SetupError
from ._run import Run
from ._sweep import Sweep, SweepResult, SweepTrajectory, sweep
from ._bead import (
    INTEGRATORS,
    METHODS,
    Scene,
    Simulation,
    __version__,
    load,
    loads,
)

__all__ = [
    "BeadError",
    "Builder",
    "DivergenceError",
    "Event",
    "INTEGRATORS",
    "METHODS",
    "Run",
    "RunError",
    "Scene",
    "SceneError",
    "SetupError",
    "Simulation",
    "Sweep",
    "SweepResult",
    "SweepTrajectory",
    "__version__",
    "load",
    "loads",
    "sweep",
]
