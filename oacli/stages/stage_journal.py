"""A stage's journal: its MCAP written while a long computation runs, so a killed run leaves a readable file.

The base of :mod:`oacli.stages.excite_journal` and :mod:`oacli.stages.plan_journal` (``track`` has its own,
:mod:`oacli.stages.track_journal`). A journal holds a time-ordered :class:`~oacli.io.mcap_write.StageMcapWriter` on
the stage's MCAP path, opened lazily (the first record creates the run folder when the stage has not yet), writing
under the writer's exclusive temporary name (``.<stage>.mcap.<random>.partial``). :meth:`StageJournal.flush` writes
what was queued merged by time and finishes a chunk on disk, so a process killed by SIGKILL or a power loss leaves a
``.partial`` MCAP that the ``mcap`` package reads up to its last complete chunk (``oacli logs recover`` turns it
into a valid file). The journal is never renamed to the final name: the stage deletes it (:meth:`discard`) just
before it writes its complete MCAP, so a run folder never looks complete because of it.

Journal records carry ``t`` = wall time since the journal was created [s] (the computation has no mission time),
monotone, so the file is in time order.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Self

from oacli.io.mcap_write import StageMcapWriter


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

    def __exit__(self, *exc: object) -> None:
        self.discard()

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
            writer.__enter__()
            self._writer = writer
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

    def commit(self) -> None:
        """Close the journal as the stage's MCAP (its final name), e.g. when the stage fails after the journal
        began and the journal is the only record of what ran."""
        if self._closed:
            return
        self._closed = True
        if self._writer is not None:
            self._writer.__exit__(None, None, None)
