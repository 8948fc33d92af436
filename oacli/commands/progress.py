"""Progress on stderr for the ``oacli`` commands: a rich bar with the phase, elapsed time and ETA.

``Progress(label, enabled)`` is called with the completed fraction in [0, 1]; ``Progress.phase(name)`` names the
current phase (shown in the bar). On a terminal the bar redraws in place; otherwise (pipes, CI logs) one line is
written every 25 %, so logs stay short.
"""

from __future__ import annotations

import sys
import time

from rich.console import Console
from rich.progress import (
    BarColumn,
    TaskID,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.progress import Progress as RichProgress


class Progress:
    """A progress bar on stderr.

    Parameters
    ----------
    label : str
        What runs (the stage name).
    enabled : bool
        False draws nothing (``--quiet``).
    """

    def __init__(self, label: str, enabled: bool) -> None:
        self.label = label
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.start = time.perf_counter()
        self._phase = ""
        self._last_step = -1
        self._bar: RichProgress | None = None
        self._task: TaskID | None = None

    def phase(self, name: str) -> None:
        """Name the current phase (e.g. ``"simulate"``, ``"write"``).

        Parameters
        ----------
        name : str
            Phase name shown after the label.
        """
        self._phase = name
        if self._bar is not None and self._task is not None:
            self._bar.update(self._task, description=self._description())

    def _description(self) -> str:
        return f"{self.label}: {self._phase}" if self._phase else self.label

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        fraction = min(max(float(fraction), 0.0), 1.0)
        if self.tty:
            if self._bar is None:
                self._bar = RichProgress(
                    TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(), TimeElapsedColumn(),
                    TextColumn("ETA"), TimeRemainingColumn(), console=Console(stderr=True), transient=False,
                )
                self._bar.start()
                self._task = self._bar.add_task(self._description(), total=1.0)
            if self._task is not None:
                self._bar.update(self._task, completed=fraction)
            if fraction >= 1.0:
                self.close()
        else:
            step = int(fraction * 4)
            if step != self._last_step:
                self._last_step = step
                elapsed = time.perf_counter() - self.start
                eta = f", ETA {elapsed * (1 - fraction) / fraction:.0f} s" if 0 < fraction < 1 else ""
                sys.stderr.write(f"{self._description()}: {25 * step}% ({elapsed:.1f} s{eta})\n")
                sys.stderr.flush()

    def close(self) -> None:
        """Stop the bar (idempotent)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
