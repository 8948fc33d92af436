"""Naming the phase of a long computation on a progress callback (no UI import: the algorithm core may use it).

A progress callback is any ``Callable[[float], None]`` taking the completed fraction; the CLI's
:class:`oacli.commands.progress.Progress` also has a ``phase(name)`` method, shown in its bar. :func:`set_phase`
calls it when present and does nothing otherwise, so plain callables (tests, the mission) keep working.
"""

from __future__ import annotations

from collections.abc import Callable


def set_phase(progress: Callable[[float], None] | None, name: str) -> None:
    """Name the current phase on ``progress`` when it has a ``phase`` method.

    Parameters
    ----------
    progress : callable or None
        The progress callback.
    name : str
        Phase name, e.g. ``"SCP iteration 3/40"``.
    """
    phase = getattr(progress, "phase", None)
    if callable(phase):
        phase(name)
