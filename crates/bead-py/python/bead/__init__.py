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

The physics is the Rust library's (the same as the `bead` command line): the run's
`summary` has the keys and values of `bead run --json`.
"""

from ._errors import BeadError, DivergenceError, RunError, SceneError, SetupError
from ._run import Run
from ._sweep import Sweep, SweepResult, sweep
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
    "DivergenceError",
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
    "__version__",
    "load",
    "loads",
    "sweep",
]
