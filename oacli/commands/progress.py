"""Progress on stderr for the ``oacli`` commands: a rich bar with the phase, elapsed time and ETA.

``Progress(label, enabled)`` is called with the completed fraction in [0, 1]; ``Progress.phase(name)`` names the
current phase (shown in the bar). On a terminal the bar redraws in place; otherwise (pipes, CI logs) one line is
written at 25, 50, 75 and 100 % (no 0 % line: at the first update the rate, hence the ETA, is not known yet), so
logs stay short.

:class:`CampaignProgress` is the campaign's: runs done / total, elapsed time and ETA, shown from the start (the bar
appears before the first run ends; the ETA once one has), and the per-run lines printed above the bar.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # rich is imported when a bar is drawn (a terminal), not with every command
    from rich.progress import Progress as RichProgress
    from rich.progress import TaskID


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
                from rich.console import Console
                from rich.progress import (
                    BarColumn,
                    TaskProgressColumn,
                    TextColumn,
                    TimeElapsedColumn,
                    TimeRemainingColumn,
                )
                from rich.progress import Progress as RichProgress

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
                if step == 0:  # no line at 0 %: nothing done yet, and an ETA from a tiny fraction is absurd
                    return
                elapsed = time.perf_counter() - self.start
                eta = f", ETA {elapsed * (1 - fraction) / fraction:.0f} s" if 0 < fraction < 1 else ""
                sys.stderr.write(f"{self._description()}: {25 * step}% ({elapsed:.1f} s{eta})\n")
                sys.stderr.flush()

    def close(self) -> None:
        """Stop the bar (idempotent)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None


def _clock(seconds: float) -> str:
    seconds = max(0, round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class CampaignProgress:
    """The campaign's progress on stderr: runs done / total, elapsed time and ETA.

    On a terminal: a rich bar from the moment the runs are known (``ETA estimating…`` until the first run ends,
    then ``(elapsed / done) × runs left``), the per-run lines printed above it. Otherwise one line per run that
    ends, with ``[done/total]``, the elapsed time and the ETA, after a first line announcing the runs.

    Parameters
    ----------
    enabled : bool
        False draws nothing (``--quiet``).
    workers : int
        Runs in flight at once (shown in the first line).
    """

    def __init__(self, enabled: bool, workers: int = 1) -> None:
        self.enabled = enabled
        self.workers = workers
        self.tty = sys.stderr.isatty()
        self.start = time.perf_counter()
        self.done = 0
        self.total = 0
        self._bar: RichProgress | None = None
        self._task: TaskID | None = None

    def eta_s(self) -> float | None:
        """Seconds left at the mean time per finished run so far (None before the first run ends)."""
        if self.done <= 0 or self.total <= 0:
            return None
        elapsed = time.perf_counter() - self.start
        return elapsed / self.done * (self.total - self.done)

    def _eta_text(self) -> str:
        eta = self.eta_s()
        return "estimating…" if eta is None else _clock(eta) if self.done < self.total else "0:00:00"

    def _refresh(self) -> None:
        if self._bar is not None and self._task is not None:
            self._bar.update(self._task, completed=self.done, runs=f"{self.done}/{self.total} runs",
                             eta=self._eta_text())

    def __call__(self, done: int, total: int) -> None:
        """Runs ``done`` of ``total`` have ended (``done = 0``: the campaign starts)."""
        if not self.enabled:
            return
        if int(done) == 0 and self.done == 0:  # the runs start now: the ETA's clock (preparing them is not a run)
            self.start = time.perf_counter()
        self.done, self.total = int(done), int(total)
        if self.tty:
            if self._bar is None:
                from rich.console import Console
                from rich.progress import BarColumn, TextColumn, TimeElapsedColumn
                from rich.progress import Progress as RichProgress

                self._bar = RichProgress(
                    TextColumn("campaign"), BarColumn(), TextColumn("{task.fields[runs]}"), TimeElapsedColumn(),
                    TextColumn("ETA {task.fields[eta]}"), console=Console(stderr=True), transient=False,
                    refresh_per_second=2,
                )
                self._task = self._bar.add_task("campaign", total=max(self.total, 1),
                                                runs=f"{self.done}/{self.total} runs", eta=self._eta_text())
                self._bar.start()
            self._refresh()
            if self.done >= self.total:
                self.close()
        elif self.done == 0:
            sys.stderr.write(f"campaign: {self.total} runs, {self.workers} at a time\n")
            sys.stderr.flush()

    def line(self, text: str) -> None:
        """Print a per-run line: above the bar on a terminal; with ``[done/total]``, elapsed and ETA otherwise."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.console.print(text, markup=False, highlight=False)
            self._refresh()
            return
        elapsed = time.perf_counter() - self.start
        eta = self.eta_s()
        timing = f" ({elapsed:.0f} s" + (f", ETA {eta:.0f} s)" if eta is not None and self.done < self.total else ")")
        sys.stderr.write(text + timing + "\n")
        sys.stderr.flush()

    def close(self) -> None:
        """Stop the bar (idempotent)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
