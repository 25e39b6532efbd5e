"""`Event`: a zero crossing to record or stop at, as scipy's `solve_ivp` events."""

from __future__ import annotations

import math
from typing import Any


class Event:
    """An event for ``Scene.run(events=[...])`` and ``Scene.simulation(events=[...])``.

    ``expr`` is an expression g of the state, written as a scene's ``stop_when``: the
    particles' coordinates and velocities (``bead.x``, ``bead.vy``), the generalized
    coordinates of the parametric form (``theta``, ``qdot.theta``), ``t`` and the scene's
    parameters. A crossing of zero is reported according to ``direction``: 1 for upward
    crossings (g < 0 before, g >= 0 after), -1 for downward ones (g > 0, then g <= 0), 0
    (the default) for either, as in scipy. A ``terminal`` event ends the run at its first
    crossing; a non-terminal one (the default) is only recorded and changes no number of the
    run. Crossings are located to 1e-10 of dt on the integrator's own path (fixed-step
    integrators re-integrate part of the step, dopri5 uses its dense output); the run's
    ``t_events`` and ``y_events`` list them per event.

    >>> import bead
    >>> bead.Event("-bead.x", direction=1, terminal=True)
    Event('-bead.x', direction=1, terminal=True)
    """

    __slots__ = ("expr", "direction", "terminal")

    expr: str
    direction: int
    terminal: bool

    def __init__(self, expr: str, direction: Any = 0, terminal: bool = False) -> None:
        if not isinstance(expr, str):
            raise TypeError(f"Event: expr must be an expression string, got {type(expr).__name__}")
        try:
            value = float(direction)
        except (TypeError, ValueError):
            raise TypeError(
                f"Event: direction must be 1, -1 or 0, got {direction!r}"
            ) from None
        if math.isnan(value):
            raise ValueError("Event: direction must be 1, -1 or 0, got nan")
        if not isinstance(terminal, (bool, int)):
            raise TypeError(f"Event: terminal must be True or False, got {terminal!r}")
        self.expr = expr
        self.direction = (value > 0) - (value < 0)
        self.terminal = bool(terminal)

    def __repr__(self) -> str:
        return f"Event({self.expr!r}, direction={self.direction}, terminal={self.terminal})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Event):
            return NotImplemented
        return (self.expr, self.direction, self.terminal) == (
            other.expr,
            other.direction,
            other.terminal,
        )

    def __hash__(self) -> int:
        return hash((self.expr, self.direction, self.terminal))
