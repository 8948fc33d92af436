"""The Rerun recording writer: :class:`StageRecording` (its 3-D layers in :mod:`oacli.io.rerun.spatial`).

Every stage writes one ``.rrd`` next to its MCAP. A recording is derived data (the MCAP is the record of truth):
it exists for a human to look at in the Rerun viewer, and tests read its values back (:mod:`oacli.io.rerun.read`).
Each stage's entities and default layout live in their own module of :mod:`oacli.io.rerun`.

Conventions
-----------
- One :class:`rerun.RecordingStream` per :class:`StageRecording` (never the global one).
- One timeline, ``mission_time`` (a duration, seconds since the stage's start). The implicit ``log_time`` and
  ``log_tick`` timelines are switched off, so a recording holds no wall-clock times.
- Long series go through ``send_columns`` (one call per series, not one per sample).
- Times are rounded to the nearest nanosecond (Rerun's duration resolution); scalars are stored as float64,
  positions, sizes and quaternions as float32 (Rerun's component types).
- Recordings are not byte-reproducible (row ids, chunk batching): compare values, never bytes.

Writing model
-------------
A :class:`StageRecording` buffers everything in memory (the recording stream's initial buffered sink) until
:meth:`StageRecording.save`, which attaches a binary (in-memory) sink (Rerun forwards the buffered data to it),
disconnects (the stream finishes with its footer), writes the bytes itself to an exclusive temporary file
(Rerun's file sink is not used: it can hang on a full disk), checks that the file opens with its footer and only
then renames it into place (:func:`oacli.io.atomic.atomic_path`; a write error names its cause). ``save`` is final:
logging afterwards raises ``RuntimeError``.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from oacli.io.atomic import atomic_path
from oacli.io.rerun.common import (  # noqa: F401 -- re-exported: the names every stage module imports from here
    ACTUAL_COLOR,
    ASTROBEE_SIZE_M,
    AXIS_COLORS,
    AXIS_NAMES,
    KEEP_IN,
    KEEP_IN_COLOR,
    KEEP_OUT,
    KEEP_OUT_COLOR,
    LIMIT_LOWER,
    LIMIT_UPPER,
    LOG,
    REFERENCE_COLOR,
    ROBOT,
    ROBOT_COLOR,
    TIMELINE,
    WORLD,
    AxisLimits,
    LogEntry,
    _level,
    _rgba,
    _times,
    time_column,
)
from oacli.io.rerun.common import application_id as application_id  # re-exported
from oacli.io.rerun.layout import limit_range, time_series_view  # noqa: F401 -- re-exported
from oacli.io.rerun.spatial import SpatialLogging

# ----------------------------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------------------------


class StageRecording(SpatialLogging):
    """One stage's Rerun recording, buffered in memory until :meth:`save`.

    Parameters
    ----------
    application_id : str
        Rerun application id; the viewer groups recordings and blueprints by it.
    recording_name : str
        Human-readable name shown in the viewer (e.g. ``"track"``).
    recording_id : str, optional
        Rerun recording id; a fresh random UUID by default (two recordings never share one).

    Notes
    -----
    Everything logged before :meth:`save` ends up in the file; ``save`` is final. Temporal data lives on the
    ``mission_time`` duration timeline [s]. ``static=True`` data holds for all times.
    """

    def __init__(
        self, application_id: str = "oacli", recording_name: str = "oacli", *, recording_id: str | None = None
    ) -> None:
        self._rec = rr.RecordingStream(application_id, recording_id=recording_id or uuid.uuid4().hex)
        self._rec.set_log_time_enabled(False)
        self._rec.set_log_tick_enabled(False)
        self._rec.send_recording_name(recording_name)
        self._recording_id = str(self._rec.get_recording_id())
        self._saved = False
        self.application_id = application_id
        self.recording_name = recording_name

    # -- plumbing ------------------------------------------------------------------------------------------------

    @property
    def stream(self) -> rr.RecordingStream:
        """The underlying recording stream, for anything the helpers below do not cover.

        Its ``log_time`` and ``log_tick`` timelines are off: call ``stream.set_time(TIMELINE, duration=t)`` before
        a temporal ``stream.log`` (or use ``send_columns``), else the row carries no time at all.
        """
        self._check_open()
        return self._rec

    @property
    def recording_id(self) -> str:
        """The Rerun recording id."""
        return self._recording_id

    def _check_open(self) -> None:
        if self._saved:
            raise RuntimeError("this StageRecording was already saved; logging after save() is not possible")

    def _log(self, entity: str, archetype, *, static: bool, t: float | None) -> None:
        """Log one row: static, or at mission time ``t`` [s]."""
        self._check_open()
        if static:
            self._rec.log(entity, archetype, static=True, strict=True)
            return
        if t is None:
            raise ValueError(f"{entity}: a non-static row needs a time t [s]")
        self._rec.set_time(TIMELINE, duration=np.timedelta64(int(np.rint(float(t) * 1e9)), "ns"))
        try:
            self._rec.log(entity, archetype, strict=True)
        finally:
            self._rec.reset_time()

    def _send(self, entity: str, t_s: np.ndarray, columns) -> None:
        self._check_open()
        self._rec.send_columns(entity, indexes=[time_column(t_s)], columns=columns, strict=True)

    # -- 3D scene ------------------------------------------------------------------------------------------------

    def log_series(
        self,
        entity: str,
        t: np.ndarray,
        values: np.ndarray,
        names: Sequence[str] | None = None,
        *,
        limits: np.ndarray | None = None,
        colors: Sequence[Sequence[int]] | None = None,
        width: float = 1.5,
    ) -> None:
        """Log one or more scalar series sharing time stamps (one ``send_columns`` call).

        Parameters
        ----------
        entity : str
            Entity path, e.g. ``metrics/force_N``. All ``k`` series live on this one entity (one ``Scalars``
            row of length ``k`` per time), named by a static ``SeriesLines``.
        t : ndarray, shape (N,)
            Mission times [s].
        values : ndarray, shape (N,) or (N, k)
            Values in the entity's unit (put the unit in the entity name). NaN leaves a gap.
        names : sequence of str, optional
            Series names (length ``k``); ``x, y, z`` when ``k == 3``, else the last path element or ``s0, s1...``.
        limits : ndarray, shape (k,), optional
            Symmetric bounds: ``+limits`` is logged under ``<entity>/limit_upper`` and ``-limits`` under
            ``<entity>/limit_lower`` as constant series spanning ``t[0]..t[-1]`` (two samples each), in the same
            colours but thinner, so a time series view of ``<entity>`` shows each series against its limits.
        colors : sequence of RGB(A), optional
            One colour per series; red/green/blue for ``k == 3``, else Rerun's automatic colours.
        width : float
            Line width [ui points].
        """
        tt = _times(f"{entity} t", t)
        v = np.asarray(values, dtype=float)
        if v.ndim == 1:
            v = v[:, None]
        if v.ndim != 2 or v.shape[0] != tt.shape[0]:
            raise ValueError(
                f"{entity}: expected values of shape ({tt.shape[0]},) or ({tt.shape[0]}, k), got {v.shape}"
            )
        k = v.shape[1]
        if names is None:
            names = AXIS_NAMES if k == 3 else ((entity.rsplit("/", 1)[-1],) if k == 1 else [f"s{i}" for i in range(k)])
        names = [str(n) for n in names]
        if len(names) != k:
            raise ValueError(f"{entity}: {k} series but {len(names)} names")
        if colors is None and k == 3:
            colors = AXIS_COLORS
        rgba = None if colors is None else np.array([_rgba(c) for c in colors])
        if rgba is not None and rgba.shape[0] != k:
            raise ValueError(f"{entity}: {k} series but {rgba.shape[0]} colours")

        self._log(entity, rr.SeriesLines(names=names, colors=rgba, widths=[float(width)] * k), static=True, t=None)
        self._send(entity, tt, rr.Scalars.columns(scalars=v))

        if limits is None:
            return
        lim = np.asarray(limits, dtype=float).reshape(-1)
        if lim.shape != (k,):
            raise ValueError(f"{entity}: expected {k} limits, got shape {np.shape(limits)}")
        if tt.size == 0:
            return
        t_span = np.array([tt.min(), tt.max()])
        faded = None if rgba is None else np.concatenate([rgba[:, :3], np.full((k, 1), 150, np.uint8)], axis=1)
        for child, sign, label in ((LIMIT_UPPER, 1.0, "+"), (LIMIT_LOWER, -1.0, "−")):
            path = f"{entity}/{child}"
            self._log(
                path,
                rr.SeriesLines(names=[f"{label}{n} limit" for n in names], colors=faded, widths=[0.75] * k),
                static=True,
                t=None,
            )
            self._send(path, t_span, rr.Scalars.columns(scalars=np.tile(sign * lim, (2, 1))))

    # -- text ----------------------------------------------------------------------------------------------------

    def log_text(self, t: float, level: str, message: str) -> None:
        """Log one text line under ``log`` at mission time ``t`` [s].

        Parameters
        ----------
        t : float
            Mission time [s].
        level : str
            ``"DEBUG"``, ``"INFO"``, ``"WARN"`` (``"WARNING"`` is accepted), ``"ERROR"`` or ``"CRITICAL"``.
        message : str
            The text.
        """
        self._log(LOG, rr.TextLog(str(message), level=_level(level)), static=False, t=float(t))

    def log_texts(self, t: np.ndarray, levels: Sequence[str], messages: Sequence[str]) -> None:
        """Log many text lines under ``log`` at once (one ``send_columns`` call); see :meth:`log_text`."""
        tt = _times("log t", t)
        if not (len(levels) == len(messages) == tt.shape[0]):
            raise ValueError(f"log: {tt.shape[0]} times, {len(levels)} levels, {len(messages)} messages")
        if tt.size == 0:
            return
        self._send(LOG, tt, rr.TextLog.columns(text=[str(m) for m in messages], level=[_level(lv) for lv in levels]))

    def log_entries(self, log: Sequence[LogEntry]) -> None:
        """Log a stage's text log (``(t [s], level, message)`` lines) under ``log``; see :meth:`log_texts`.

        Parameters
        ----------
        log : sequence of (float, str, str)
            The lines; nothing is logged when empty.
        """
        if log:
            t_log, levels, messages = zip(*log, strict=True)
            self.log_texts(np.array(t_log, dtype=float), list(levels), list(messages))

    # -- output --------------------------------------------------------------------------------------------------

    def save(self, path: Path, blueprint: rrb.Blueprint | None = None) -> None:
        """Write everything logged so far to ``path`` atomically, with ``blueprint`` as the default layout.

        The file is written under a temporary name beside ``path``, completed (footer written, writer thread
        joined), checked to open, fsynced and then renamed onto ``path``. On any failure ``path`` is not
        created (an existing file is left untouched) and the temporary file is removed. The recording is closed
        afterwards, also on failure.

        Parameters
        ----------
        path : Path
            Final ``.rrd`` path; its folder must exist.
        blueprint : rerun.blueprint.Blueprint, optional
            Default viewer layout, stored in the file as a blueprint store of the same application id.

        Raises
        ------
        RuntimeError
            When called twice, or when the written file cannot be read back.
        """
        self._check_open()
        path = Path(path)
        try:
            # Memory, not Rerun's file sink: the file sink can block forever on a full disk (DESIGN.md §7).
            stream = rr.binary_stream(recording=self._rec)
            if blueprint is not None:
                send_default_blueprint(self._rec, self.application_id, blueprint)
            self._rec.flush()
            data = stream.read(flush=True) or b""
        finally:
            # Disconnecting finishes the stream (the footer); the recording is closed either way.
            self._rec.disconnect()
            self._saved = True
        data += stream.read(flush=True) or b""
        del stream
        self._release()
        with atomic_path(path) as tmp:
            fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0))
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
            _check_complete(tmp, self.recording_id)


    def _release(self) -> None:
        """Drop the closed stream and join its threads (and those of any other recording nobody holds).

        Rerun keeps a dropped :class:`rerun.RecordingStream`'s two threads (its chunk batcher and its sink
        forwarder) alive until ``rerun.bindings.flush_and_cleanup_orphaned_recordings`` runs, which only
        ``rr.init`` calls: a campaign worker flying one mission after another gathered ~1,800 idle threads
        (2 per recording) until the batchers' ticks alone loaded the machine. Called once the stream is
        disconnected (``save``); later use of the recording raises ``RuntimeError`` through ``_check_open``.
        """
        del self._rec
        release_orphaned_recordings()


def send_default_blueprint(recording: rr.RecordingStream, application_id: str, blueprint: rrb.Blueprint) -> None:
    """Send ``blueprint`` to ``recording`` as its application's default layout, leaving no thread behind.

    ``rr.send_blueprint`` logs the blueprint into a stream of its own with a memory sink and sends that sink's
    storage; the blueprint stream still holds the storage's messages when Python drops it, so Rerun never treats it
    as an orphan and its two threads (chunk batcher, sink forwarder) live until the process ends: one pair per saved
    recording with a blueprint (the track, plan and estimate stages'), 860 threads in a campaign worker after 50
    missions (the fix of :meth:`StageRecording._release` did not cover them). Here the same steps as
    ``rerun.blueprint.api.create_in_memory_blueprint`` and ``rr.send_blueprint`` (rerun-sdk 0.41), then the memory
    sink drained and the blueprint stream disconnected, so that :func:`release_orphaned_recordings` joins it.
    Falls back to ``rr.send_blueprint`` where those internals are missing (rerun-sdk is pinned to 0.41.*).

    Parameters
    ----------
    recording : rerun.RecordingStream
        The data recording the file is written from.
    application_id : str
        Its application id (the blueprint belongs to it).
    blueprint : rerun.blueprint.Blueprint
        The layout.
    """
    new_blueprint = getattr(rr.bindings, "new_blueprint", None)
    from_native = getattr(rr.RecordingStream, "_from_native", None)
    to_blueprint = getattr(blueprint, "to_blueprint", None)
    full: Any = to_blueprint() if to_blueprint is not None else None
    if new_blueprint is None or from_native is None or full is None or not hasattr(full, "_log_to_stream"):
        rr.send_blueprint(blueprint, make_active=False, make_default=True, recording=recording)
        return
    stream = from_native(new_blueprint(application_id=application_id, make_default=False, make_thread_default=False,
                                       default_enabled=True))
    try:
        stream.set_time("blueprint", sequence=0)
        full._log_to_stream(stream)
        memory = stream.memory_recording()
        rr.bindings.send_blueprint(memory.storage, False, True, recording=recording.to_native())
        memory.drain_as_bytes()
    finally:
        stream.disconnect()
    del stream


def release_orphaned_recordings() -> None:
    """Flush and join every Rerun recording stream no Python object refers to any more.

    The public function ``rr.init`` calls for the same purpose (``rerun.bindings``, rerun-sdk >= 0.20); a no-op
    where the bindings lack it.
    """
    cleanup = getattr(rr.bindings, "flush_and_cleanup_orphaned_recordings", None)
    if cleanup is not None:
        cleanup()


def _check_complete(path: Path, recording_id: str) -> None:
    """Raise ``RuntimeError`` unless ``path`` is an rrd with a footer holding ``recording_id``."""
    try:
        reader = RrdReader(path)
        ids = [s.recording_id for s in reader.recordings()]
        reader.store()  # reads the manifest from the footer: fails on a truncated file
    except Exception as exc:
        raise RuntimeError(f"the Rerun recording {path} was not written completely: {exc}") from exc
    if recording_id not in ids:
        raise RuntimeError(f"the Rerun recording {path} does not hold recording {recording_id} (Rerun disabled?)")
