"""The exceptions bead raises. Every one derives from `BeadError`."""

from __future__ import annotations

from typing import Any, Optional


class BeadError(Exception):
    """Base class of the errors bead raises (bad arguments raise ValueError)."""


class SceneError(BeadError, ValueError):
    """A scene that cannot be read or is not valid.

    Attributes: ``path`` (the file as given, or the name given to `bead.loads`), ``line`` and
    ``column`` (1-based; 0 when the error has no position, e.g. the file cannot be read),
    ``message`` (what is wrong, on one line) and ``snippet`` (the offending line with a caret
    under it, or None). ``str(error)`` is ``path:line:column: message`` followed by the
    snippet, as the command line prints it.
    """

    def __init__(
        self,
        text: str,
        path: str,
        line: int,
        column: int,
        message: str,
        snippet: Optional[str] = None,
    ) -> None:
        super().__init__(text, path, line, column, message, snippet)
        self.text = text
        self.path = path
        self.line = line
        self.column = column
        self.message = message
        self.snippet = snippet

    def __str__(self) -> str:
        return self.text


class SetupError(BeadError, ValueError):
    """A simulation that cannot start: an illegal combination (rattle on the parametric form,
    projection with dopri5), or an initial state that cannot be simulated."""


class RunError(BeadError, RuntimeError):
    """A run or a step that failed. ``run`` is the `bead.Run` up to the last good state
    (None when a `bead.Simulation` was stepping: it keeps the last good state itself)."""

    def __init__(self, message: str, run: Any = None) -> None:
        super().__init__(message, run)
        self.message = message
        self.run = run

    def __str__(self) -> str:
        return self.message


class DivergenceError(RunError):
    """A run whose state became non-finite or grew beyond any physical scale."""
