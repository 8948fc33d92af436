"""The ``track`` stage's journal: its MCAP written while the simulation runs, so a killed run leaves a readable file.

During the closed-loop simulation the simulator hands every control step to :meth:`TrackJournal.on_step`
(:func:`oacli.sim.simulator.simulate`'s ``on_step``), which writes ``/state/true`` (the plant samples), ``/reference``,
``/state/measured``, ``/control/command``, ``/control/applied``, ``/disturbance`` and ``/solver/stats`` to the
stage's MCAP under its exclusive temporary name (``.track.mcap.<random>.partial``), merged by time, and flushes a
chunk every :data:`FLUSH_STEPS` control steps or :data:`FLUSH_WALL_S` seconds of wall time. A process killed during
the simulation (SIGKILL, power loss) thus leaves a ``.partial`` MCAP that the ``mcap`` package reads up to its last
complete chunk (``oacli logs recover`` turns it into a valid file).

The complete ``track.mcap`` is still written at the end from the whole run (topics that need it: the scene's flown
path, the summary-derived log, tube topics, flown sensors), merged by time over the whole file, beside the journal
(:meth:`TrackJournal.replaced_by`): the journal stays the record until the complete file is in place, and is
deleted right after its rename (the rename and the deletion are one :class:`oacli.signals.atomic` step). So a
signal at any moment leaves either the complete file or the journal (kept as ``track.mcap``, or, should closing it
fail, its ``.partial`` that ``oacli logs recover`` reads), and the ``interrupted`` summary says which
(``"records": {"mcap": "complete" | "journal" | "journal-partial"}``). The topics both files hold are encoded
once: the complete file takes the journal's JSON payloads where its rows are exactly the journal's
(:attr:`TrackJournal.encoded`, :class:`oacli.io.mcap_write.EncodedRows`). While the complete file is written the
disk holds both (about twice the MCAP's size).

Ctrl-C or a termination signal (a :class:`KeyboardInterrupt`, :mod:`oacli.signals`) during the simulation keeps the
journal as ``track.mcap``: the steps still buffered are written, then a ``/log`` warning naming the interruption, and
the file is closed valid (summary section, CRCs) next to the ``interrupted`` ``summary.json``, as ``plan`` and
``excite`` do (:mod:`oacli.stages.stage_journal`). So does a complete file that cannot be written (a full disk: the
journal then stays the record, next to the ``failed`` summary). Each step is taken whole
(:class:`oacli.signals.atomic`), so an interruption never finds the buffers half updated.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from oacli.io.atomic import WriteError
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.mcap_write import EncodedRows
from oacli.io.runfolder import StageRun
from oacli.signals import atomic
from oacli.stages.stage_journal import journal_partial, keep_interrupted, replace_journal
from oacli.trajectory import sample_inputs
from oacli.types import SolveInfo, Trajectory

#: Control steps between two flushes of the journal (a finished chunk each).
FLUSH_STEPS = 25
#: Longest wall time between two flushes [s] (slow controllers still leave a recent file).
FLUSH_WALL_S = 1.0


class _Discarded(Exception):
    """Passed to the writer's ``__exit__`` so it deletes its temporary file instead of committing it."""


class TrackJournal:
    """Write a tracking run's per-step topics while it runs (see the module docstring).

    Parameters
    ----------
    writer : StageMcapWriter
        A time-ordered writer, not yet entered, on the stage's MCAP path; never committed (see :meth:`discard`).
    reference : Trajectory
        The reference followed (its inputs are written on ``/reference``, as the final file does).
    run : StageRun, optional
        The stage's run: told what its MCAP holds when the stage is stopped (:attr:`StageRun.records`).
    """

    def __init__(self, writer: StageMcapWriter, reference: Trajectory, *, run: StageRun | None = None) -> None:
        self._writer = writer
        self._run = run
        self._final_failed = False  # the complete file could not be written: the journal stays the record
        self._reference = reference
        #: JSON payloads of the sample records written, for the complete file (``StageMcapWriter.reuse_encoded``).
        self.encoded: EncodedRows = writer.keep_encoded()
        self._open = False
        self._ctrl: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, SolveInfo]] = []
        self._true: list[np.ndarray] = []  # rows [t, x (13), u (6)] ready to write
        self._pending: tuple[np.ndarray, np.ndarray] | None = None  # plant samples of the latest step
        self._u_last: np.ndarray | None = None  # applied input of the latest step
        self._steps = 0
        self._t_last = 0.0  # control time of the latest step [s] (the kept journal's closing /log record)
        self._last_flush = time.monotonic()

    def __enter__(self) -> TrackJournal:
        self._writer.__enter__()
        self._open = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        if isinstance(exc, KeyboardInterrupt) or (isinstance(exc, WriteError) and self._final_failed):
            self.keep(exc)  # interrupted, or the complete file could not be written (a full disk): the record
        else:
            self.discard()

    def keep(self, interruption: BaseException) -> None:
        """Keep an interrupted run's journal as its MCAP (:func:`oacli.stages.stage_journal.keep_interrupted`: the
        buffered steps, a ``/log`` warning naming the interruption, the writer closed under its final name). Never
        raises."""
        if not self._open:
            return
        left = keep_interrupted(self._writer, interruption, write_last=self._close_buffers,
                                log_time_s=lambda: self._t_last, what="the simulation")
        if self._run is not None:
            self._run.records["mcap"] = "journal" if left is None else "journal-partial"
            if left is not None:
                self._run.files["journal"] = left

    def replaced_by(self, writer: StageMcapWriter) -> contextlib.AbstractContextManager[StageMcapWriter]:
        """Write the complete MCAP with ``writer`` (not yet entered, on the same final name) while the journal stays
        the record; when the block ends, the complete file is renamed into place and the journal deleted as one
        :class:`oacli.signals.atomic` step (:func:`oacli.stages.stage_journal.replace_journal`)."""

        def discard() -> None:
            if self._run is not None:
                self._run.records["mcap"] = "complete"
            self.discard()

        return self._guard_final(replace_journal(writer, discard))

    @contextlib.contextmanager
    def _guard_final(self, inner: contextlib.AbstractContextManager[StageMcapWriter]) -> Iterator[StageMcapWriter]:
        """Note a :class:`WriteError` of the complete file (e.g. no space left): the journal is then kept."""
        try:
            with inner as writer:
                yield writer
        except WriteError:
            self._final_failed = True
            raise

    def _close_buffers(self) -> None:
        """Write every buffered step (the last one's plant samples too), then mark the journal closed."""
        try:
            self.flush(final=True)
        finally:
            self._open = False

    def _resolve(self, t_now: float | None, u_now: np.ndarray | None) -> None:
        """Give the pending plant samples their applied input: the latest step's, or from ``t_now`` on the new
        step's ``u_now`` (a sample carries the input of the last control step at or before it, as the final
        file's ``searchsorted(t_ctrl, t_true, side="right") - 1``)."""
        if self._pending is None or self._u_last is None:
            return
        t, x = self._pending
        u = np.tile(self._u_last, (t.size, 1))
        if t_now is not None and u_now is not None:
            u[t >= t_now] = u_now
        self._true.append(np.column_stack([t, x, u]))
        self._pending = None

    def on_step(self, j: int, *, t_true: np.ndarray, x_true: np.ndarray, t_ctrl: float, x_measured: np.ndarray,
                x_reference: np.ndarray, u_command: np.ndarray, u_applied: np.ndarray, disturbance: np.ndarray,
                info: SolveInfo) -> None:
        """Take control step ``j`` (the keyword arguments of :func:`oacli.sim.simulator.simulate`'s ``on_step``)."""
        if not self._open:
            return
        with atomic():  # an interruption waits until the step is buffered (and a due flush is on disk)
            self._resolve(t_ctrl, u_applied)
            self._ctrl.append((t_ctrl, x_measured, x_reference, u_command, u_applied, disturbance, info))
            self._pending = (np.asarray(t_true, dtype=float), np.asarray(x_true, dtype=float).reshape(-1, 13))
            self._u_last = u_applied
            self._t_last = float(t_ctrl)
            self._steps += 1
            if self._steps >= FLUSH_STEPS or time.monotonic() - self._last_flush >= FLUSH_WALL_S:
                self.flush()

    def flush(self, *, final: bool = False) -> None:
        """Write the buffered steps (merged by time) and finish a chunk on disk; ``final`` also writes the plant
        samples of the last step."""
        if not self._open:
            return
        if final:
            self._resolve(None, None)
        w = self._writer
        with w.time_ordered():
            if self._ctrl:
                t = np.array([c[0] for c in self._ctrl])
                x_meas, x_ref, u_cmd, u_app, dist = (np.array([c[i] for c in self._ctrl]) for i in range(1, 6))
                w.write_states("/reference", t, x_ref, sample_inputs(self._reference, t))
                w.write_states("/state/measured", t, x_meas, u_cmd)
                w.write_wrenches("/control/command", t, u_cmd)
                w.write_wrenches("/control/applied", t, u_app)
                w.write_wrenches("/disturbance", t, dist)
                w.write_solver_stats(t, [c[6] for c in self._ctrl])
            if self._true:
                rows = np.vstack(self._true)
                w.write_states("/state/true", rows[:, 0], rows[:, 1:14], rows[:, 14:20])
        self._ctrl, self._true = [], []
        w.flush()
        self._steps = 0
        self._last_flush = time.monotonic()

    def discard(self) -> None:
        """Close the journal and delete its file (the complete MCAP replaced it, or the stage failed)."""
        if self._open:
            self._open = False
            self._writer.__exit__(_Discarded, _Discarded("journal discarded"), None)

    @property
    def partial(self) -> Any:
        """The journal's temporary file while it is open (``.track.mcap.<random>.partial``), else None."""
        return journal_partial(self._writer) if self._open else None

    @property
    def writer(self) -> Any:
        """The underlying writer."""
        return self._writer
