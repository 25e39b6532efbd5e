"""`Builder`: a scene built in Python, as the TOML text of a scene file.

The builder writes the tables of docs/scene-format.md in the order of the calls and loads
the text with `bead.loads`, so a built scene is exactly the scene of its TOML
(`Builder.to_toml()`), and an error is the loader's, located in that text, with the builder
call that wrote the offending line added to the message.
"""

from __future__ import annotations

import inspect
import re
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from . import _bead
from ._errors import SceneError

_NAME = "<bead.Builder>"


def _value(value: Any) -> str:
    return _bead._toml_value(value)


def _key(key: str) -> str:
    """A TOML key: bare when it can be, quoted otherwise (a particle named "a.b")."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _value(key)


class Builder:
    """A scene built in Python; each method returns the builder, so calls chain.

    >>> import bead
    >>> scene = (bead.Builder(dim=2, gravity=[0, 9.81], title="pendulum")
    ...          .param("L", 1.0)
    ...          .particle("bob", mass=1.0, position=["L*sin(pi/3)", "L*cos(pi/3)"])
    ...          .constraint("bob.x^2 + bob.y^2 - L^2", name="rod")
    ...          .parametric(["th"], initial=["pi/3"], positions={"bob": ["L*sin(th)", "L*cos(th)"]})
    ...          .build())
    >>> scene.particles, scene.coordinates, scene.constraint_count
    (['bob'], ['th'], 1)

    Numbers may be expressions of the parameters given before them ("2*L", "sqrt(g/L)");
    constraints and parametric positions are expressions of the particles' coordinates
    (``bob.x``), ``t``, the coordinates and the parameters. See docs/scene-format.md.
    """

    def __init__(
        self,
        dim: int = 2,
        gravity: Optional[Sequence[Any]] = None,
        title: Optional[str] = None,
    ) -> None:
        if gravity is None:
            if dim not in (2, 3):
                raise ValueError(f"dim={dim!r}: a scene is 2D or 3D")
            gravity = [0.0] * dim
        elif len(gravity) != dim:
            raise ValueError(
                f"gravity={list(gravity)!r}: needs {dim} numbers for dim={dim}"
            )
        self._title = title
        self._gravity = list(gravity)
        self._params: List[Tuple[str, Any]] = []
        # (table header, [(key, value)], the call that wrote it)
        self._tables: List[Tuple[str, List[Tuple[str, Any]], str]] = []
        self._parametric: Optional[Tuple[List[Tuple[str, Any]], Dict[str, Any], str]] = None
        self._run: Optional[Tuple[List[Tuple[str, Any]], str]] = None
        self._events: List[Tuple[List[Tuple[str, Any]], str]] = []

    @staticmethod
    def _caller(call: str) -> str:
        frame = inspect.stack()[2]
        return f"{call} (called at {frame.filename}:{frame.lineno})"

    def param(self, name: str, value: Any) -> "Builder":
        """A named number (or an expression of the parameters before it)."""
        self._params.append((name, value))
        return self

    def particle(
        self,
        name: str,
        mass: Any,
        position: Sequence[Any],
        velocity: Optional[Sequence[Any]] = None,
    ) -> "Builder":
        """A particle: its mass, its initial position and velocity (default at rest)."""
        keys = [("name", name), ("mass", mass), ("position", list(position))]
        if velocity is not None:
            keys.append(("velocity", list(velocity)))
        self._tables.append(("[[particle]]", keys, self._caller(f"particle({name!r})")))
        return self

    def force(self, kind: str, **keys: Any) -> "Builder":
        """A force: "constant" (particle, vector), "spring" (between=[a, b] or particle and
        anchor; stiffness; rest_length) or "drag" (coefficient; particle, default all)."""
        self._tables.append(
            ("[[force]]", [("kind", kind), *keys.items()], self._caller(f"force({kind!r})"))
        )
        return self

    def constraint(
        self, expr: Optional[str] = None, name: Optional[str] = None, **keys: Any
    ) -> "Builder":
        """A constraint of the implicit form: `expr` = 0 (an expression of the particles'
        coordinates, t and parameters), or kind="distance" (between, length) or kind="pin"
        (particle, anchor). side="above" (C >= 0) or "below" (C <= 0) makes a scalar
        constraint unilateral (it only pushes; the particle may leave it), with
        restitution=e in [0, 1] at its landings."""
        entries: List[Tuple[str, Any]] = []
        if name is not None:
            entries.append(("name", name))
        if expr is not None:
            entries.append(("expr", expr))
        entries += list(keys.items())
        shown = expr if expr is not None else keys.get("kind", "")
        self._tables.append(("[[constraint]]", entries, self._caller(f"constraint({shown!r})")))
        return self

    def parametric(
        self,
        coordinates: Sequence[str],
        initial: Sequence[Any],
        rates: Optional[Sequence[Any]] = None,
        positions: Optional[Mapping[str, Sequence[Any]]] = None,
    ) -> "Builder":
        """The parametric form: generalized coordinates, their initial values and rates
        (default 0), and every particle's position as expressions of them (and t)."""
        keys: List[Tuple[str, Any]] = [
            ("coordinates", list(coordinates)),
            ("initial", list(initial)),
        ]
        if rates is not None:
            keys.append(("rates", list(rates)))
        self._parametric = (
            keys,
            {k: list(v) for k, v in (positions or {}).items()},
            self._caller("parametric(...)"),
        )
        return self

    def run(self, **defaults: Any) -> "Builder":
        """The [run] defaults: method, integrator, dt, duration or steps, stabilize,
        stop_when, event_samples (scene.run() arguments override them)."""
        self._run = (list(defaults.items()), self._caller("run(...)"))
        return self

    def event(self, expr: str, direction: int = 0, terminal: bool = False) -> "Builder":
        """An [[event]] table, as `bead.Event`: `expr` crossing zero in `direction` (1 up,
        -1 down, 0 either), recorded in the run's `t_events`, or ending the run when
        `terminal`."""
        keys = [("expr", expr), ("direction", direction), ("terminal", terminal)]
        self._events.append((keys, self._caller(f"event({expr!r})")))
        return self

    def _lines(self) -> Tuple[List[str], List[Tuple[int, int, str]]]:
        lines: List[str] = []
        spans: List[Tuple[int, int, str]] = []

        def table(header: Optional[str], keys: Sequence[Tuple[str, Any]], call: str) -> None:
            start = len(lines) + 1
            if header is not None:
                lines.append(header)
            for key, value in keys:
                lines.append(f"{_key(key)} = {_value(value)}")
            spans.append((start, len(lines), call))

        if self._title is not None:
            table(None, [("title", self._title)], "Builder(title=...)")
        if self._params:
            table("[params]", self._params, "param(...)")
        table("[world]", [("gravity", self._gravity)], "Builder(gravity=...)")
        for header, keys, call in self._tables:
            table(header, keys, call)
        if self._parametric is not None:
            keys, positions, call = self._parametric
            table("[parametric]", keys, call)
            table("[parametric.positions]", list(positions.items()), call)
        if self._run is not None:
            table("[run]", *self._run)
        for keys, call in self._events:
            table("[[event]]", keys, call)
        return lines, spans

    def to_toml(self) -> str:
        """The scene file this builder writes (what `build()` loads)."""
        return "\n".join(self._lines()[0]) + "\n"

    def build(self, params: Optional[Mapping[str, float]] = None) -> "_bead.Scene":
        """The scene: `bead.loads(self.to_toml(), params)`. Raises bead.SceneError located
        in that text, with the builder call that wrote the line."""
        lines, spans = self._lines()
        try:
            return _bead.loads("\n".join(lines) + "\n", params, name=_NAME)
        except SceneError as e:
            call = next((c for a, b, c in spans if a <= e.line <= b), None)
            if call is None:
                raise
            text = f"{e.text}\n(written by Builder.{call})"
            raise SceneError(text, e.path, e.line, e.column, e.message, e.snippet) from None
