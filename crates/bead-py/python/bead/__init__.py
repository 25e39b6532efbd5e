"""bead: constrained particle dynamics from scene files, in Python.

    import bead
    scene = bead.load("scenes/parabola.toml", params={"g": 9.81})
    run = scene.run(method="implicit", integrator="rattle", dt=1/60, duration=10.0)
    run.t, run.positions, run.energy, run.constraint_error, run.summary

    sim = scene.simulation(method="parametric", integrator="gauss-legendre", dt=1e-3)
    sim.advance_to(2.5); sim.positions, sim.energy

    result = bead.sweep(scene, params={"x0": np.linspace(10, 200, 10_000)}, steps=1000)
    result.t_final, result.positions, result.status, result.to_pandas()

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
