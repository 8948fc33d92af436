"""A stage's journal: its MCAP written while a long computation runs, so a killed run leaves a readable file.

The base of :mod:`oacli.stages.excite_journal` and :mod:`oacli.stages.plan_journal` (``track`` has its own,
:mod:`oacli.stages.track_journal`). A journal holds a time-ordered :class:`~oacli.io.mcap_write.StageMcapWriter` on
the stage's MCAP path, opened lazily (the first record creates the run folder when the stage has not yet), writing
under the writer's exclusive temporary name (``.<stage>.mcap.<random>.partial``). :meth:`StageJournal.flush` writes
what was queued merged by time and finishes a chunk on disk, so a process killed by SIGKILL or a power loss leaves a
``.partial`` MCAP that the ``mcap`` package reads up to its last complete chunk (``oacli logs recover`` turns it
into a valid file). When the stage ends normally the complete MCAP is written beside the journal and the journal
is deleted right after the complete file's rename (:meth:`StageJournal.replaced_by`, :func:`replace_journal`): the
journal stays the record until the complete file is in place, so a signal at any moment leaves one or the other.

A stage stopped by Ctrl-C or a termination signal (a :class:`KeyboardInterrupt`, :mod:`oacli.signals`) keeps what it
computed: leaving the ``with`` block, the journal writes its last records (:meth:`StageJournal.on_interrupt`), one
``/log`` warning naming the signal, and closes as a valid MCAP under the stage's final name (:meth:`commit`, summary
section and CRCs); the run folder's ``summary.json`` then says ``"status": "interrupted"`` and lists it, so the folder
never looks complete (:func:`oacli.io.runfolder.is_complete`). Should that close fail (e.g. the interruption came in
the middle of a write and broke the writer), the temporary file is removed and the interruption goes on, with a note.
Any other error deletes the journal (a stage may :meth:`commit` it itself, as ``excite`` does for a design that
fails its final check).

Journal records carry ``t`` = wall time since the journal was created [s] when the computation has no mission time
(``plan``, the offline ``excite``), or the mission time (the RATTLE closed loop), monotone, so the file is in time
order.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Self

from oacli.io.mcap_write import StageMcapWriter
from oacli.signals import atomic, describe_interruption


class _Discarded(Exception):
    """Passed to the writer's ``__exit__`` so it deletes its temporary file instead of committing it."""


class StageJournal:
    """Lazily opened, periodically flushed journal writer (module docstring).

    Parameters
    ----------
    open_writer : callable
        Returns a time-ordered :class:`StageMcapWriter` on the stage's MCAP path, not yet entered (called once, at
        the first record).
    flush_wall_s : float
        Longest wall time between two flushes [s].
    """

    def __init__(self, open_writer: Callable[[], StageMcapWriter], flush_wall_s: float) -> None:
        self._open_writer = open_writer
        self._writer: StageMcapWriter | None = None
        self._closed = False
        self._flush_wall_s = float(flush_wall_s)
        self._t0 = time.monotonic()
        self._last_flush = self._t0

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        if isinstance(exc, KeyboardInterrupt):
            self.keep(exc)
        else:
            self.discard()

    def on_interrupt(self, writer: StageMcapWriter) -> None:
        """Write what is still buffered before an interrupted journal is kept (nothing here; subclasses)."""

    def keep(self, interruption: BaseException) -> None:
        """Keep an interrupted stage's journal as its MCAP (:func:`keep_interrupted`: the last records, a ``/log``
        warning naming the interruption, the writer closed under its final name). Never raises."""
        writer = self._writer
        if self._closed or writer is None:
            self._closed = True
            return

        def write_last() -> None:
            try:
                self.on_interrupt(writer)
            finally:
                self._closed = True

        keep_interrupted(writer, interruption, write_last=write_last, log_time_s=self.log_time_s,
                         what="the computation")

    def log_time_s(self) -> float:
        """The ``t`` of the journal's closing ``/log`` record (default: the wall time since it was created)."""
        return self.elapsed_s()

    def elapsed_s(self) -> float:
        """Wall time since the journal was created [s] (the ``t`` of its records)."""
        return time.monotonic() - self._t0

    def due(self) -> bool:
        """True when the last flush is older than the flush period."""
        return time.monotonic() - self._last_flush >= self._flush_wall_s

    def writer(self) -> StageMcapWriter | None:
        """The open writer (opened now if needed), or None once the journal is closed."""
        if self._closed:
            return None
        if self._writer is None:
            writer = self._open_writer()
            self._writer = writer  # before entering: an interruption while it opens still finds (and closes) it
            writer.__enter__()
        return self._writer

    def flush(self) -> None:
        """Write the queued records merged by time and finish a chunk on disk."""
        if self._writer is not None and not self._closed:
            self._writer.flush()
        self._last_flush = time.monotonic()

    def discard(self) -> None:
        """Close the journal and delete its file (the stage's complete MCAP replaces it)."""
        if self._closed:
            return
        self._closed = True
        if self._writer is not None:
            self._writer.__exit__(_Discarded, _Discarded("journal discarded"), None)

    def replaced_by(self, writer: StageMcapWriter) -> contextlib.AbstractContextManager[StageMcapWriter]:
        """Write the complete MCAP with ``writer`` beside the journal, which is deleted once the complete file is in
        place (:func:`replace_journal`)."""
        return replace_journal(writer, self.discard)

    def commit(self) -> None:
        """Close the journal as the stage's MCAP (its final name), e.g. when the stage fails after the journal
        began and the journal is the only record of what ran."""
        if self._closed:
            return
        self._closed = True
        if self._writer is not None:
            self._writer.__exit__(None, None, None)


@contextlib.contextmanager
def replace_journal(writer: StageMcapWriter, discard: Callable[[], None]) -> Iterator[StageMcapWriter]:
    """Write a stage's complete MCAP with ``writer`` (not yet entered, on the journal's final name) while its journal
    stays the record; when the block ends, finish the complete file, rename it into place and ``discard()`` the
    journal as one :class:`oacli.signals.atomic` step (a signal in it is raised after both).

    An exception in the block (a signal too) removes the complete file's temporary and leaves the journal open:
    leaving the journal's ``with`` block then keeps it (an interruption) or deletes it (any other error). While the
    complete file is written the disk holds both (about twice the MCAP's size).
    """
    writer.__enter__()
    try:
        yield writer
        writer.flush()  # the bulk of the file (interruptible between two messages)
    except BaseException as exc:
        writer.__exit__(type(exc), exc, exc.__traceback__)
        raise
    with atomic():
        writer.__exit__(None, None, None)  # summary section, fsync, rename (never a symlink)
        discard()


def keep_interrupted(writer: StageMcapWriter, interruption: BaseException, *, write_last: Callable[[], None],
                     log_time_s: Callable[[], float], what: str) -> Path | None:
    """Close an interrupted stage's journal writer as the stage's MCAP: ``write_last()`` (what is still buffered),
    one ``/log`` warning at ``log_time_s()`` naming the interruption, then the writer's normal close (final name,
    summary section, CRCs). Never raises: should the close fail, the journal's temporary file is left in place (every
    chunk flushed so far; ``oacli logs recover`` makes a valid file of it) and the failure is added to
    ``interruption``'s notes (the journals of :mod:`oacli.stages.stage_journal` and
    :mod:`oacli.stages.track_journal`).

    Parameters
    ----------
    writer : StageMcapWriter
        The journal's open writer.
    interruption : BaseException
        The :class:`KeyboardInterrupt` (or :class:`oacli.signals.Terminated`) that stopped the stage, or the error
        that kept the complete file from being written.
    write_last : callable
        Writes the records still buffered.
    log_time_s : callable
        The ``t`` of the closing ``/log`` record [s] (read after ``write_last``).
    what : str
        What the journal holds, for the warning (``"the computation"``, ``"the simulation"``).

    Returns
    -------
    Path or None
        None when the journal was kept under the stage's final name; else the temporary file left in place.
    """
    partial = journal_partial(writer)
    try:
        write_last()
        how = describe_interruption(interruption) if isinstance(interruption, KeyboardInterrupt) else \
            f"failed ({interruption})"
        writer.write_log(log_time_s(), "warning", f"stage {how}: the journal of {what} so far is kept as the "
                         "stage's MCAP")
        writer.__exit__(None, None, None)
        return None
    except BaseException as err:
        target = getattr(writer, "_atomic", None)
        if target is not None and hasattr(target, "keep_on_error"):
            target.keep_on_error = True  # the chunks flushed so far stay readable (oacli logs recover)
        with contextlib.suppress(BaseException):
            writer.__exit__(type(err), err, err.__traceback__)
        left = partial if partial is not None and partial.exists() else None
        where = f"; its chunks so far are in {left} (oacli logs recover)" if left else ""
        interruption.add_note(f"(the journal could not be closed: {type(err).__name__}: {err}{where})")
        return left


def journal_partial(writer: StageMcapWriter) -> Path | None:
    """The temporary file an open journal writer writes (``.<stage>.mcap.<random>.partial``), or None."""
    target = getattr(writer, "_atomic", None)
    path = getattr(target, "temporary", None)
    return Path(path) if path is not None else None
