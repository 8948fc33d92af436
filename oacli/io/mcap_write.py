"""Write a stage's MCAP file (the record of truth of every oacli stage); read it with :mod:`oacli.io.mcap_read`.

The contract (topics, schemas, units, metadata, attachments) is documented in ``docs/mcap.md`` and its names
and JSON schemas live in :mod:`oacli.io.mcap_schema`.

Writing uses the Foxglove SDK's MCAP writer (``foxglove.open_mcap``) with one ``foxglove.Context`` per file, so
channels of one file never leak into another. It writes zstd-compressed chunks (level :data:`ZSTD_LEVEL`) of at most
:data:`DEFAULT_CHUNK_SIZE` bytes (uncompressed), chunk CRCs, the data-section CRC, the summary CRC and attachment
CRCs. The file is written under a temporary name and renamed into place only when the ``with`` block ends
without an exception (:func:`oacli.io.atomic.atomic_file`: an exclusive temporary file, never a
predictable name); a failed write names its cause (:class:`oacli.io.atomic.WriteError`).

Messages go to the file in time order (``log_time`` non-decreasing over the whole file, ties in call order) when
the writer is opened with ``time_ordered=True`` or inside a :meth:`StageMcapWriter.time_ordered` block: each
``write_*`` call is validated at once and queued as a lazy per-topic stream, and the streams are merged by time
(:func:`heapq.merge`) when the block ends or on :meth:`StageMcapWriter.flush`. Chunks are written as they fill,
so a file cut by a crash holds every complete chunk (all topics up to about the same time), which the ``mcap``
package's stream reader reads up to the cut.
"""

from __future__ import annotations

import contextlib
import functools
import heapq
import itertools
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from datetime import UTC, datetime
from operator import itemgetter
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, cast

import foxglove
import numpy as np
from foxglove.channels import LogChannel, PoseInFrameChannel, SceneUpdateChannel
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from foxglove.messages import (
    Color,
    CubePrimitive,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

import oacli
from oacli.geometry.shapes import Scene
from oacli.io import mcap_memo
from oacli.io import mcap_schema as ms
from oacli.io.atomic import WriteError, atomic_file, describe_os_error
from oacli.io.jsonsafe import to_json_safe
from oacli.model.quaternion import from_rotation_matrix
from oacli.signals import PENDING, held, interruption_point
from oacli.types import INPUT_DIM, STATE_DIM, SolveInfo, Trajectory

#: Target uncompressed chunk size [bytes]; a hard crash loses at most the chunk being filled.
DEFAULT_CHUNK_SIZE = 256 * 1024

_NS_PER_S = 1_000_000_000

#: The JSON encoder of :meth:`StageMcapWriter.write_json` (``json.dumps(..., allow_nan=False)`` builds one per call).
_JSON = json.JSONEncoder(allow_nan=False)

#: zstd level of the chunks: 1, the fastest standard level. On a mission's JSON records (10 MB) the writer's default
#: level cost about 0.13 s of CPU, level 1 about 0.08 s, and its files were no larger (issue 9).
ZSTD_LEVEL = 1

#: One queued message: ``(log_time [ns], emit, payload)``; ``emit(payload, log_time)`` writes it.
_Pending = tuple[int, Callable[[Any, int], None], Any]

_LOG_LEVELS = {
    "debug": LogLevel.Debug,
    "info": LogLevel.Info,
    "warning": LogLevel.Warning,
    "warn": LogLevel.Warning,
    "error": LogLevel.Error,
    "fatal": LogLevel.Fatal,
    "critical": LogLevel.Fatal,
}

_KEEP_IN_COLOR = (0.2, 0.8, 0.3, 0.08)
_KEEP_OUT_COLOR = (0.9, 0.15, 0.15, 0.35)
_BODY_COLOR = (0.55, 0.6, 0.68, 0.9)
_COLLISION_COLOR = (0.55, 0.6, 0.68, 0.12)

#: Edge of the drawn robot body [m]: Astrobee is a cube about 30 cm wide ([ReSWARM2023] §5.1.3), the same cube as
#: the Rerun recordings draw.
ROBOT_BODY_EDGE_M = 0.30
#: Highest rate of the robot body's ``/scene`` updates [Hz] (a 3D panel needs no more; keeps files small).
ROBOT_BODY_RATE_HZ = 10.0
#: Path colours in order (reference blue, actual orange, then green, purple, brown, pink, grey, olive).
_PATH_PALETTE = (
    (0.12, 0.47, 0.71, 1.0),
    (1.0, 0.5, 0.05, 1.0),
    (0.17, 0.63, 0.17, 1.0),
    (0.58, 0.4, 0.74, 1.0),
    (0.55, 0.34, 0.29, 1.0),
    (0.89, 0.47, 0.76, 1.0),
    (0.5, 0.5, 0.5, 1.0),
    (0.74, 0.74, 0.13, 1.0),
)


def _times_ns(what: str, t: Any) -> tuple[np.ndarray, list[int]]:
    """Check times ``t`` [s] (1-D, finite, >= 0) and return them with ``round(t * 1e9)`` [ns]."""
    arr = np.array(t, dtype=float, ndmin=1)
    if arr.ndim != 1:
        raise ValueError(f"{what}: times must be a 1-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: times contain NaN or infinite values")
    if arr.size and arr.min() < 0.0:
        raise ValueError(f"{what}: times must be >= 0 s (mission time), got {arr.min()!r}")
    return arr, np.rint(arr * 1e9).astype(np.int64).tolist()


def _time_ns(what: str, t: Any) -> tuple[float, int]:
    """One time ``t`` [s] (finite, >= 0) and ``round(t * 1e9)`` [ns], as :func:`_times_ns` gives them."""
    if type(t) is float or type(t) is int:  # the common case without numpy (same rounding: half to even)
        t_s = float(t)
        if not math.isfinite(t_s):
            raise ValueError(f"{what}: times contain NaN or infinite values")
        if t_s < 0.0:
            raise ValueError(f"{what}: times must be >= 0 s (mission time), got {t_s!r}")
        return t_s, round(t_s * 1e9)
    times, ns = _times_ns(what, t)
    if times.shape != (1,):
        raise ValueError(f"{what}: write_json takes one time, got shape {times.shape}")
    return float(times[0]), ns[0]


def _finite_array(what: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: contains NaN or infinite values")
    return arr


def _timestamp(ns: int) -> Timestamp:
    return Timestamp(ns // _NS_PER_S, ns % _NS_PER_S)


def _pose(position: Sequence[float] | np.ndarray, quat_xyzw: Sequence[float] | np.ndarray) -> Pose:
    x, y, z = (float(v) for v in position)
    qx, qy, qz, qw = (float(v) for v in quat_xyzw)
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))


def _color(rgba: Sequence[float]) -> Color:
    r, g, b, a = rgba
    return Color(r=r, g=g, b=b, a=a)


def _vec3(v: Sequence[float] | np.ndarray) -> Vector3:
    x, y, z = (float(c) for c in v)
    return Vector3(x=x, y=y, z=z)


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(repr(float(c)) for c in v) + "]"


def _ms_or_none(seconds: float) -> float | None:
    seconds = float(seconds)
    return seconds * 1e3 if math.isfinite(seconds) else None


class _SpoolFile:
    """The file object ``foxglove.open_mcap`` writes to: new bytes collect in memory and :meth:`spill` writes
    them to the real file from oacli's code.

    So a failed write (disk full) raises a plain ``OSError`` here, named in one line, instead of inside the
    foxglove writer (which prints the Python traceback and then refuses every later message). The MCAP writer
    seeks back to patch a chunk's header once the chunk is complete: a patch of bytes already spilled is
    written in place (it needs no new disk space).
    """

    def __init__(self, handle: Any) -> None:
        self._fd = handle.fileno()
        self._base = 0  # file offset of the buffer's first byte
        self._buffer = bytearray()
        self._position = 0
        self.error: OSError | None = None

    def write(self, data: bytes) -> int:
        data = bytes(data)
        pos, n = self._position, len(data)
        if pos < self._base:  # patch of spilled bytes
            head = data[: self._base - pos]
            os.pwrite(self._fd, head, pos)
            data, pos = data[len(head):], pos + len(head)
        if data:
            offset = pos - self._base
            if offset > len(self._buffer):
                self._buffer += bytes(offset - len(self._buffer))
            self._buffer[offset : offset + len(data)] = data
        self._position += n
        return n

    def seek(self, offset: int, whence: int = 0) -> int:
        end = self._base + len(self._buffer)
        self._position = {0: offset, 1: self._position + offset, 2: end + offset}[whence]
        return self._position

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        """Called by the MCAP writer; the bytes reach the file at the next :meth:`spill`."""

    @property
    def pending(self) -> int:
        """Bytes not yet written to the file."""
        return len(self._buffer)

    @property
    def buffer(self) -> bytearray:
        """The bytes not yet written to the file (one object for the spool's life: empty once spilled)."""
        return self._buffer

    def spill(self) -> None:
        """Write the collected bytes to the file (an ``OSError`` is kept in ``error`` and raised)."""
        if not self._buffer:
            return
        try:
            with memoryview(self._buffer) as view:
                done = 0
                while done < len(view):
                    done += os.pwrite(self._fd, view[done:], self._base + done)
        except OSError as exc:
            if self.error is None:
                self.error = exc
            raise
        self._base += len(self._buffer)
        self._buffer.clear()


class EncodedRows:
    """The JSON payloads of a writer's sample records (``write_states``, ``write_wrenches``) kept with their rows,
    by topic, so that a second file writing the same rows on the same topic takes them instead of encoding again
    (:meth:`StageMcapWriter.keep_encoded`, :meth:`StageMcapWriter.reuse_encoded`: the ``track`` stage's journal and
    its complete file, :mod:`oacli.stages.track_journal`).

    A topic's payloads are reused only when the rows written equal, value for value and in order, every row kept
    for that topic and record template, and every one of them was encoded (a queue dropped by an exception leaves
    rows without payloads): the bytes written are then exactly those encoding would give.
    """

    def __init__(self) -> None:
        # (topic, template) -> (row blocks as written, payloads in the same order)
        self._parts: dict[tuple[str, str], tuple[list[np.ndarray], list[bytes]]] = {}

    def keep(self, topic: str, template: str, rows: np.ndarray) -> list[bytes]:
        """Record ``rows`` of ``topic``; returns the list their payloads are to be appended to, in order."""
        blocks, payloads = self._parts.setdefault((topic, template), ([], []))
        blocks.append(rows)
        return payloads

    def payloads(self, topic: str, template: str, rows: np.ndarray) -> list[bytes] | None:
        """The payloads of ``rows`` on ``topic`` when they are exactly the rows kept (else None).

        Parameters
        ----------
        topic : str
            Topic name.
        template : str
            The record template (:data:`oacli.io.mcap_schema.TRAJECTORY_SAMPLE_TEMPLATE`, ...).
        rows : ndarray, shape (N, k)
            The rows about to be written.

        Returns
        -------
        list of bytes or None
        """
        parts = self._parts.get((topic, template))
        if parts is None:
            return None
        blocks, payloads = parts
        if len(payloads) != rows.shape[0] or sum(b.shape[0] for b in blocks) != rows.shape[0]:
            return None
        kept = blocks[0] if len(blocks) == 1 else np.vstack(blocks)
        return payloads if np.array_equal(kept, rows) else None


def _remember(written: dict[str, list[tuple[int, bytes]]], emit: Any, payload: Any, log_time: int) -> None:
    """Keep a message just written for :mod:`oacli.io.mcap_memo`: a JSON payload as is, a ``foxglove.Log`` as its
    protobuf encoding (what the file holds); other Foxglove messages are not decoded by the reader, not kept."""
    if type(payload) is bytes:
        written.setdefault(emit.topic, []).append((log_time, payload))
    elif isinstance(payload, Log):
        written.setdefault(emit.topic, []).append((log_time, payload.encode()))


_time_of = itemgetter(0)


def _in_time_order(messages: list[_Pending]) -> bool:
    """Whether the log times of ``messages`` never decrease."""
    if len(messages) < 2:
        return True
    times = list(map(_time_of, messages))
    return times == sorted(times)


class StageMcapWriter:
    """Context manager writing one stage's MCAP file atomically.

    On entering, the file is opened under an exclusive temporary name (``.<name>.<random>.partial`` beside
    ``path``), and the
    metadata record ``oacli`` and the attachment ``config.yaml`` are written first (so that even a file cut by a
    crash carries them). On leaving without an exception the file is finished (summary, CRCs), fsynced and
    renamed to ``path``; if an exception escapes the ``with`` block the temporary file is deleted and no file
    named ``path`` is created.

    All times are mission time ``t`` [s] since the start of the stage, ``t >= 0``; each message's MCAP
    ``log_time`` and ``publish_time`` are ``round(t * 1e9)`` [ns] and oacli's JSON records also hold the exact
    float ``t``. Sample topics (trajectories, wrenches, solver statistics, poses) must be written with strictly
    increasing times; a topic may be written in several calls (each continuing after the last time written).

    Parameters
    ----------
    path : Path
        Final file name (``*.mcap``). Its folder must exist.
    stage : str
        Stage name (``plan``, ``smooth``, ``track``, ...), stored in the ``oacli`` metadata.
    config_yaml : str
        The resolved configuration as YAML text, stored as the attachment ``config.yaml``.
    metadata : Mapping[str, object], optional
        Further entries of the ``oacli`` metadata record (``seed``, ``git_commit``, ...); values are converted
        with ``str``. They override the defaults ``version``, ``created_utc``, ``frame``, ``contract_version``;
        ``seed`` and ``git_commit`` default to ``"unknown"``.
    frame : str
        Name of the world frame (``frame_id`` of poses; channel metadata of sample topics).
    chunk_size : int
        Target uncompressed chunk size [bytes].
    overwrite : bool
        Replace an existing ``path`` (default: refuse with ``FileExistsError``).
    time_ordered : bool
        Queue every message and write them merged by time (see the module docstring) when the ``with`` block
        ends or on :meth:`flush`; otherwise each ``write_*`` call writes its messages at once.

    Examples
    --------
    ::

        with StageMcapWriter(run / "plan.mcap", stage="plan", config_yaml=text, metadata={"seed": 1}) as w:
            w.write_trajectory("/trajectory", plan)
            w.write_poses(plan.t, plan.x)
            w.write_scene(scene, {"plan": plan.x[:, :3]})
            w.write_log(0.0, "info", "plan found")
    """

    def __init__(
        self,
        path: Path,
        *,
        stage: str,
        config_yaml: str,
        metadata: Mapping[str, object] | None = None,
        frame: str = "world",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        overwrite: bool = False,
        time_ordered: bool = False,
    ) -> None:
        self.path = Path(path)
        self.stage = str(stage)
        self.frame = str(frame)
        self._config_yaml = str(config_yaml)
        self._extra_metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._chunk_size = int(chunk_size)
        self._overwrite = bool(overwrite)
        self._atomic: Any = None
        self._file: _SpoolFile | None = None
        self._writer: Any = None
        self._context: Any = None
        self._state = "new"
        # topic -> (channel, schema name, channel metadata)
        self._channels: dict[str, tuple[Any, str, dict[str, str]]] = {}
        self._last_t: dict[str, float] = {}
        self._ordered = bool(time_ordered)
        self._queue: list[Iterator[_Pending] | list[_Pending]] | None = [] if self._ordered else None
        self._kept: EncodedRows | None = None  # payloads of sample records are kept here (keep_encoded)
        self._reuse: EncodedRows | None = None  # payloads taken from here when the rows match (reuse_encoded)
        self._written: mcap_memo.Written | None = None  # what is written, while oacli.io.mcap_memo is active
        self._raw_emitters: dict[int, Any] = {}  # id(channel) -> its emit (_raw_emitter); channels live as long

    # -- context management ------------------------------------------------------------------------------

    def __enter__(self) -> StageMcapWriter:
        if self._state != "new":
            raise RuntimeError("a StageMcapWriter can be entered only once")
        if self.path.exists() and not self._overwrite:
            raise FileExistsError(f"{self.path} exists; refusing to overwrite it")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"folder {self.path.parent} does not exist")
        self._atomic = atomic_file(self.path)
        self._file = _SpoolFile(self._atomic.__enter__())
        self._written = mcap_memo.Written() if mcap_memo.active() else None
        try:
            self._context = foxglove.Context()
            options = MCAPWriteOptions(
                compression=MCAPCompression.Zstd,
                compression_level=ZSTD_LEVEL,
                compression_threads=0,  # compressed in this thread (no pool of one thread per CPU)
                chunk_size=self._chunk_size,
                calculate_chunk_crcs=True,
                calculate_data_section_crc=True,
                calculate_summary_section_crc=True,
                calculate_attachment_crcs=True,
            )
            sink = cast(BinaryIO, self._file)  # our spool: write/flush/seek/tell as open_mcap needs
            with held():  # Ctrl-C inside the native writer's callbacks is raised after them (oacli.signals)
                self._writer = foxglove.open_mcap(sink, context=self._context, writer_options=options)
            self._state = "open"
            created = datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")
            info = {
                "version": oacli.__version__,
                "stage": self.stage,
                "seed": "unknown",
                "git_commit": "unknown",
                "created_utc": created,
                "frame": self.frame,
                "contract_version": ms.CONTRACT_VERSION,
                **self._extra_metadata,
            }
            self.write_metadata(ms.METADATA_NAME, info)
            self.attach(ms.CONFIG_ATTACHMENT, self._config_yaml.encode("utf-8"), ms.CONFIG_MEDIA_TYPE)
            with held():
                self._writer.flush()
            self._spill()  # the metadata and the config are on disk before any message
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._state == "closed":
            return
        with held():  # an interruption while closing is raised once the file is committed or removed
            self._close(exc)

    def _close(self, exc: BaseException | None) -> None:
        error = exc
        try:
            if error is None and self._writer is not None:
                self._drain()
        except BaseException as err:
            error = err
        self._state = "closed"
        self._queue = None
        try:
            if self._writer is not None:
                self._writer.close()
                if error is None:
                    self._spill()
        except BaseException as err:
            if error is None:
                error = err
            else:
                error.add_note(f"(closing the MCAP writer also failed: {err})")
        finally:
            self._writer = None
            for channel, _, _ in self._channels.values():
                channel.close()
            self._channels.clear()
            self._context = None
        if not isinstance(error, KeyboardInterrupt) and self._file is not None and self._file.error is not None:
            # The foxglove writer reports a failed write vaguely; name the cause (e.g. ENOSPC) and the path.
            if not isinstance(error, WriteError):
                cause = error
                error = WriteError(describe_os_error(self._file.error, self.path))
                error.__cause__ = cause
        if error is None:
            self._atomic.__exit__(None, None, None)
            if self._written is not None:
                mcap_memo.store(self.path, self._written)
            self._written = None
            return
        self._written = None
        self._atomic.__exit__(type(error), error, error.__traceback__)  # removes the temporary file
        if error is not exc:
            raise error

    # -- time order --------------------------------------------------------------------------------------------

    @contextlib.contextmanager
    def time_ordered(self) -> Iterator[StageMcapWriter]:
        """Within the block, queue every message; at its end write them all merged by time.

        Messages with equal times keep the order of the calls. Nothing queued is written if the block raises.
        """
        self._require_open()
        if self._queue is not None:
            yield self  # already queueing (nested block or a time-ordered writer)
            return
        self._queue = []
        try:
            yield self
        except BaseException:
            self._queue = None
            raise
        try:
            self._drain()
        finally:
            self._queue = None

    def _emit(self, messages: Iterable[_Pending]) -> None:
        """Write ``messages`` now, or queue them (a list as is, other iterables lazily) while time-ordered."""
        if self._queue is not None:
            self._queue.append(messages if type(messages) is list else iter(messages))
            return
        self._write(messages)

    def _write(self, messages: Iterable[_Pending]) -> None:
        spool = self._file
        written = None if self._written is None else self._written.messages
        pending = spool.buffer if spool is not None else bytearray()  # bytes a completed chunk left in the spool
        with held():  # Ctrl-C inside the native writer is held, then raised between two messages (oacli.signals)
            if written is None:
                for log_time, emit, payload in messages:
                    emit(payload, log_time)
                    if pending:  # a chunk was completed: to the file now
                        self._spill()
                    if PENDING:
                        interruption_point()
                return
            for log_time, emit, payload in messages:
                emit(payload, log_time)
                if type(payload) is bytes:  # a JSON record, kept for oacli.io.mcap_memo (_remember)
                    written.setdefault(emit.topic, []).append((log_time, payload))  # type: ignore[attr-defined]
                else:
                    _remember(written, emit, payload, log_time)
                if pending:
                    self._spill()
                if PENDING:
                    interruption_point()

    def _spill(self) -> None:
        try:
            self._file.spill()  # type: ignore[union-attr]
        except OSError as exc:
            raise WriteError(describe_os_error(exc, self.path)) from None

    def _drain(self) -> None:
        """Write every queued message, merged by time (stable for equal times: in the order of the calls).

        The queued streams are encoded into one list first; when each stream is in time order (as every ``write_*``
        call checks its times), a stable sort of their concatenation is their merge, done in C (Timsort merges the
        sorted runs); otherwise :func:`heapq.merge` of the streams (the same order as before).
        """
        if not self._queue:
            return
        queued, self._queue = self._queue, []
        if len(queued) == 1:
            self._write(queued[0])
            return
        parts = [stream if type(stream) is list else list(stream) for stream in queued]
        if all(_in_time_order(part) for part in parts):
            merged = list(itertools.chain.from_iterable(parts))
            merged.sort(key=_time_of)
            self._write(merged)
        else:
            self._write(heapq.merge(*parts, key=_time_of))

    def _require_open(self) -> None:
        if self._state != "open":
            raise RuntimeError("StageMcapWriter is not open; use it as a context manager (with ... as w:)")

    # -- channels --------------------------------------------------------------------------------------------

    def _json_channel(self, topic: str, schema_name: str, schema: Mapping[str, Any], metadata: dict[str, str]) -> Any:
        self._require_open()
        entry = self._channels.get(topic)
        if entry is not None:
            channel, existing, existing_meta = entry
            if existing != schema_name:
                raise ValueError(f"topic {topic} carries {existing} records; cannot write {schema_name} on it")
            if metadata.get("frame", existing_meta.get("frame")) != existing_meta.get("frame"):
                raise ValueError(f"topic {topic} is in frame {existing_meta.get('frame')!r}, not {metadata['frame']!r}")
            return channel
        full_schema = {**schema, "title": schema_name}
        full_schema.setdefault("type", "object")
        with held():
            channel = foxglove.Channel(topic, schema=full_schema, context=self._context, metadata=metadata or None)
        self._channels[topic] = (channel, schema_name, metadata)
        return channel

    def _typed_channel(self, topic: str, channel_cls: Any, schema_name: str) -> Any:
        self._require_open()
        entry = self._channels.get(topic)
        if entry is not None:
            if entry[1] != schema_name:
                raise ValueError(f"topic {topic} carries {entry[1]} messages; cannot write {schema_name} on it")
            return entry[0]
        with held():
            channel = channel_cls(topic, context=self._context)
        self._channels[topic] = (channel, schema_name, {})
        return channel

    def _sample_times(self, topic: str, t: Any) -> tuple[np.ndarray, list[int]]:
        """Times of a sample topic: valid, strictly increasing and after the last time written on ``topic``."""
        arr, ns = _times_ns(topic, t)
        if np.any(np.diff(arr) <= 0.0):
            raise ValueError(f"{topic}: times must be strictly increasing")
        last = self._last_t.get(topic)
        if last is not None and arr.size and arr[0] <= last:
            raise ValueError(f"{topic}: times must continue after the last written time {last!r} s")
        return arr, ns

    def _raw_emitter(self, channel: Any) -> Callable[[Any, int], None]:
        """``emit(payload, log_time)`` of a JSON channel: the native ``log`` of its already encoded text (skips
        ``foxglove.Channel.log``'s checks; a C-level partial, no Python frame per message), one per channel."""
        emit = self._raw_emitters.get(id(channel))
        if emit is None:
            emit = functools.partial(channel.base.log)
            emit.topic = channel.topic()  # type: ignore[attr-defined]  # for oacli.io.mcap_memo (_remember)
            self._raw_emitters[id(channel)] = emit
        return emit

    @staticmethod
    def _typed_emitter(channel: Any) -> Callable[[Any, int], None]:
        def emit(message: Any, log_time: int) -> None:
            channel.log(message, log_time=log_time)

        emit.topic = channel.topic()  # type: ignore[attr-defined]
        return emit

    def keep_encoded(self) -> EncodedRows:
        """Keep the payloads of the sample records written from now on (for :meth:`reuse_encoded` by another
        writer).

        Returns
        -------
        EncodedRows
            Filled as the records are encoded.
        """
        if self._kept is None:
            self._kept = EncodedRows()
        return self._kept

    def reuse_encoded(self, encoded: EncodedRows | None) -> None:
        """Take the payloads of sample records from ``encoded`` when a topic's rows are exactly those it kept
        (:class:`EncodedRows`); other records are encoded as usual. None: encode everything.

        Parameters
        ----------
        encoded : EncodedRows or None
            Another writer's kept payloads (:meth:`keep_encoded`).
        """
        self._reuse = encoded

    def _log_rows(self, topic: str, channel: Any, template: str, rows: np.ndarray, ns: list[int]) -> None:
        emit = self._raw_emitter(channel)
        reused = None if self._reuse is None else self._reuse.payloads(topic, template, rows)
        if reused is not None:
            self._emit(list(zip(ns, itertools.repeat(emit, len(ns)), reused, strict=True)))
            return
        kept = None if self._kept is None else self._kept.keep(topic, template, rows)
        payloads = [(template % row).encode() for row in map(tuple, rows.tolist())]
        if kept is not None:
            kept.extend(payloads)
        self._emit(list(zip(ns, itertools.repeat(emit, len(ns)), payloads, strict=True)))

    # -- oacli records ---------------------------------------------------------------------------------------

    def write_states(
        self,
        topic: str,
        t: np.ndarray,
        x: np.ndarray,
        u: np.ndarray | None = None,
        *,
        name: str | None = None,
        frame: str | None = None,
    ) -> None:
        """Write state (and input) samples as ``oacli.TrajectorySample`` records on ``topic``.

        Parameters
        ----------
        topic : str
            Any topic name (``/state/true``, ``/reference``, ``/control/command``, ...).
        t : ndarray, shape (N,)
            Mission times [s], ``>= 0``, strictly increasing (and after the last time written on ``topic``).
        x : ndarray, shape (N, 13)
            States ``[r (m), v (m/s), q (x, y, z, w), omega (rad/s)]``.
        u : ndarray, shape (N, 6), optional
            Inputs ``[f (N, world), tau (N·m, body)]``; zeros when omitted.
        name : str, optional
            Trajectory name stored in the channel metadata (default: the topic without its leading ``/``).
        frame : str, optional
            World frame of the samples (default: the writer's frame); fixed per topic.
        """
        times, ns = self._sample_times(topic, t)
        n = times.shape[0]
        xs = _finite_array(f"{topic}: x", x, (n, STATE_DIM))
        us = np.zeros((n, INPUT_DIM)) if u is None else _finite_array(f"{topic}: u", u, (n, INPUT_DIM))
        meta = {"frame": self.frame if frame is None else str(frame), "name": name or topic.strip("/")}
        channel = self._json_channel(topic, ms.TRAJECTORY_SAMPLE, ms.TRAJECTORY_SAMPLE_SCHEMA, meta)
        if n:
            self._log_rows(topic, channel, ms.TRAJECTORY_SAMPLE_TEMPLATE, np.column_stack([times, xs, us]), ns)
            self._last_t[topic] = float(times[-1])

    def write_trajectory(self, topic: str, traj: Trajectory) -> None:
        """Write a :class:`~oacli.types.Trajectory` (its name and frame go to the channel metadata).

        Parameters
        ----------
        topic : str
            Topic name, ``/trajectory`` for a stage's output trajectory.
        traj : Trajectory
            Times [s] must be ``>= 0``.
        """
        self.write_states(topic, traj.t, traj.x, traj.u, name=traj.name, frame=traj.frame)

    def write_wrenches(self, topic: str, t: np.ndarray, wrench: np.ndarray) -> None:
        """Write force/torque samples as ``oacli.Wrench`` records (e.g. ``/disturbance``).

        Parameters
        ----------
        topic : str
            Topic name.
        t : ndarray, shape (N,)
            Mission times [s], strictly increasing.
        wrench : ndarray, shape (N, 6)
            ``[f (N, world), tau (N·m, body)]`` held from ``t[k]`` to ``t[k+1]``.
        """
        times, ns = self._sample_times(topic, t)
        w = _finite_array(f"{topic}: wrench", wrench, (times.shape[0], INPUT_DIM))
        channel = self._json_channel(topic, ms.WRENCH, ms.WRENCH_SCHEMA, {"frame": self.frame})
        if times.size:
            self._log_rows(topic, channel, ms.WRENCH_TEMPLATE, np.column_stack([times, w]), ns)
            self._last_t[topic] = float(times[-1])

    def write_solver_stats(self, t: np.ndarray, infos: Sequence[SolveInfo], topic: str = ms.TOPIC_SOLVER_STATS) -> None:
        """Write one ``oacli.SolverStats`` record per controller step.

        Parameters
        ----------
        t : ndarray, shape (K,)
            Controller step times [s], strictly increasing.
        infos : sequence of SolveInfo, length K
            Per-step outcome; NaN objective or times become JSON ``null``; times are written in ms.
        topic : str
            Topic name.
        """
        times, ns = self._sample_times(topic, t)
        if len(infos) != times.shape[0]:
            raise ValueError(f"{topic}: {times.shape[0]} times but {len(infos)} SolveInfo records")
        channel = self._json_channel(topic, ms.SOLVER_STATS, ms.SOLVER_STATS_SCHEMA, {})
        emit = self._raw_emitter(channel)
        infos = list(infos)

        def messages() -> Iterator[_Pending]:
            for ti, info, log_time in zip(times.tolist(), infos, ns, strict=True):
                objective = float(info.objective)
                record = {
                    "t": ti,
                    "status": str(info.status),
                    "success": bool(info.success),
                    "objective": objective if math.isfinite(objective) else None,
                    "iterations": int(info.iterations),
                    "solve_time_ms": _ms_or_none(info.solve_time_s),
                    "step_time_ms": _ms_or_none(info.step_time_s),
                }
                yield log_time, emit, json.dumps(record, allow_nan=False).encode()

        self._emit(messages())
        if times.size:
            self._last_t[topic] = float(times[-1])

    def write_json(
        self, topic: str, schema_name: str, schema: Mapping[str, Any], t: float, record: Mapping[str, Any]
    ) -> None:
        """Write one record of a stage-specific JSON schema (parameter estimates, events, ...).

        Parameters
        ----------
        topic : str
            Topic name; a topic carries one schema.
        schema_name : str
            Schema name, ``oacli.<Something>`` by convention (stored as the JSON schema's ``title``).
        schema : Mapping
            JSON Schema of an object (``{"type": "object", "properties": {...}}``); used on the first write.
        t : float
            Mission time [s], ``>= 0``; stored as the record's ``t`` field (inserted first).
        record : Mapping
            The record; numpy arrays and scalars are converted, NaN and infinities become ``null``.
        """
        t_s, log_time = _time_ns(topic, t)
        if "t" in record and float(record["t"]) != t_s:
            raise ValueError(f"{topic}: record t={record['t']!r} differs from t={t_s!r}")
        channel = self._json_channel(topic, schema_name, schema, {})
        body = to_json_safe({"t": t_s, **{k: v for k, v in record.items() if k != "t"}})
        self._emit([(log_time, self._raw_emitter(channel), _JSON.encode(body).encode())])

    # -- Foxglove messages -----------------------------------------------------------------------------------

    def write_poses(self, t: np.ndarray, x: np.ndarray, topic: str = ms.TOPIC_ROBOT_POSE) -> None:
        """Write the robot pose as ``foxglove.PoseInFrame`` messages (one per sample, ``frame_id`` = frame).

        Parameters
        ----------
        t : ndarray, shape (N,)
            Times [s], strictly increasing.
        x : ndarray, shape (N, 13)
            States; position ``x[:, 0:3]`` [m] and quaternion ``x[:, 6:10]`` ``[x, y, z, w]`` are used.
        topic : str
            Topic name.
        """
        times, ns = self._sample_times(topic, t)
        xs = _finite_array(f"{topic}: x", x, (times.shape[0], STATE_DIM))
        channel = self._typed_channel(topic, PoseInFrameChannel, "foxglove.PoseInFrame")
        frame, emit, rows = self.frame, self._typed_emitter(channel), xs[:, [0, 1, 2, 6, 7, 8, 9]].tolist()

        def messages() -> Iterator[_Pending]:
            for (px, py, pz, qx, qy, qz, qw), log_time in zip(rows, ns, strict=True):
                pose = Pose(position=Vector3(x=px, y=py, z=pz), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))
                yield log_time, emit, PoseInFrame(timestamp=_timestamp(log_time), frame_id=frame, pose=pose)

        self._emit(messages())
        if times.size:
            self._last_t[topic] = float(times[-1])

    def write_scene(
        self,
        scene: Scene,
        paths: Mapping[str, np.ndarray] | None = None,
        t: float = 0.0,
        topic: str = ms.TOPIC_SCENE,
    ) -> None:
        """Write the workspace and named paths as one ``foxglove.SceneUpdate``.

        Entities (all in ``scene.frame``, lifetime unlimited): ``keep_in/<i>`` a translucent green cube per
        keep-in box (centre, edge lengths [m]); ``keep_out/<i>`` a translucent red ellipsoid
        (``SpherePrimitive``) per keep-out zone, with ``size`` = 2 × semi-axes [m] along the principal axes and
        the orientation of the principal-axes rotation; ``path/<name>`` a ``LINE_STRIP`` per path, coloured
        in order (blue, orange, green, purple, ...). Entity metadata give the numbers in text.

        Parameters
        ----------
        scene : Scene
            Keep-in boxes and keep-out ellipsoids.
        paths : Mapping[str, ndarray of shape (N, 3)], optional
            Named polylines [m] (e.g. ``{"reference": ..., "actual": ...}``).
        t : float
            Time of the update [s].
        topic : str
            Topic name.
        """
        _, ns = _times_ns(topic, t)
        stamp = _timestamp(ns[0])
        identity = (0.0, 0.0, 0.0, 1.0)
        entities = []
        for i, box in enumerate(scene.keep_in):
            cube = CubePrimitive(pose=_pose(box.center, identity), size=_vec3(box.size), color=_color(_KEEP_IN_COLOR))
            meta = [
                KeyValuePair(key="kind", value="keep-in box"),
                KeyValuePair(key="lower_m", value=_fmt(box.lower)),
                KeyValuePair(key="upper_m", value=_fmt(box.upper)),
            ]
            entities.append(
                SceneEntity(timestamp=stamp, frame_id=scene.frame, id=f"keep_in/{i}", metadata=meta, cubes=[cube])
            )
        for i, ellipsoid in enumerate(scene.keep_out):
            semi_axes, rotation = ellipsoid.principal_axes()
            quat = from_rotation_matrix(rotation)
            sphere = SpherePrimitive(
                pose=_pose(ellipsoid.center, quat), size=_vec3(2.0 * semi_axes), color=_color(_KEEP_OUT_COLOR)
            )
            meta = [
                KeyValuePair(key="kind", value="keep-out ellipsoid"),
                KeyValuePair(key="center_m", value=_fmt(ellipsoid.center)),
                KeyValuePair(key="semi_axes_m", value=_fmt(semi_axes)),
                KeyValuePair(key="orientation_xyzw", value=_fmt(quat)),
            ]
            entities.append(
                SceneEntity(timestamp=stamp, frame_id=scene.frame, id=f"keep_out/{i}", metadata=meta, spheres=[sphere])
            )
        for k, (name, points) in enumerate((paths or {}).items()):
            pts = np.asarray(points, dtype=float)
            if pts.ndim != 2 or pts.shape[1] != 3:
                raise ValueError(f"path {name!r}: expected shape (N, 3), got {pts.shape}")
            if not np.all(np.isfinite(pts)):
                raise ValueError(f"path {name!r}: contains NaN or infinite values")
            line = LinePrimitive(
                type=LinePrimitiveLineType.LineStrip,
                pose=_pose((0.0, 0.0, 0.0), identity),
                thickness=2.0,
                scale_invariant=True,
                points=[Point3(x=px, y=py, z=pz) for px, py, pz in pts.tolist()],
                color=_color(_PATH_PALETTE[k % len(_PATH_PALETTE)]),
            )
            meta = [KeyValuePair(key="kind", value="path"), KeyValuePair(key="points", value=str(len(pts)))]
            entities.append(
                SceneEntity(timestamp=stamp, frame_id=scene.frame, id=f"path/{name}", metadata=meta, lines=[line])
            )
        channel = self._typed_channel(topic, SceneUpdateChannel, "foxglove.SceneUpdate")
        self._emit([(ns[0], self._typed_emitter(channel), SceneUpdate(entities=entities))])

    def write_robot_body(
        self,
        t: np.ndarray,
        x: np.ndarray,
        *,
        edge_m: float = ROBOT_BODY_EDGE_M,
        radius_m: float | None = None,
        rate_hz: float = ROBOT_BODY_RATE_HZ,
        topic: str = ms.TOPIC_SCENE,
    ) -> None:
        """Write the robot's body on ``/scene``: entity ``robot`` posed at the robot's pose over time.

        One ``foxglove.SceneUpdate`` per kept sample, holding only the entity ``robot`` (so it replaces the previous
        one and leaves the workspace entities alone): a ``CubePrimitive`` of edge ``edge_m`` [m] at the pose
        (position ``x[:, 0:3]``, quaternion ``x[:, 6:10]``) and, with ``radius_m``, a translucent
        ``SpherePrimitive`` of diameter ``2 radius_m`` (the collision sphere the planners use). Samples are
        thinned to at most ``rate_hz`` (the first sample of each ``1 / rate_hz`` interval after ``t[0]``; the
        last sample is always kept). Write the workspace (:meth:`write_scene`) first.

        Parameters
        ----------
        t : ndarray, shape (N,)
            Times [s], strictly increasing.
        x : ndarray, shape (N, 13)
            States.
        edge_m : float
            Edge of the body cube [m], > 0 (Astrobee: :data:`ROBOT_BODY_EDGE_M`).
        radius_m : float, optional
            Collision radius [m] (``robot.radius_m``); drawn when > 0.
        rate_hz : float
            Highest update rate [Hz], > 0.
        topic : str
            Topic name.
        """
        times, ns = _times_ns(topic, t)
        if np.any(np.diff(times) <= 0.0):
            raise ValueError(f"{topic}: robot body times must be strictly increasing")
        xs = _finite_array(f"{topic}: x", x, (times.shape[0], STATE_DIM))
        if not (math.isfinite(edge_m) and edge_m > 0.0) or not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"{topic}: edge_m and rate_hz must be finite and > 0")
        if times.size == 0:
            return
        _, keep = np.unique(np.floor((times - times[0]) * rate_hz), return_index=True)
        keep = np.union1d(keep, [times.size - 1])
        channel = self._typed_channel(topic, SceneUpdateChannel, "foxglove.SceneUpdate")
        size = _vec3((edge_m, edge_m, edge_m))
        meta = [KeyValuePair(key="kind", value="robot body"), KeyValuePair(key="edge_m", value=repr(float(edge_m)))]
        radius = 0.0 if radius_m is None else float(radius_m)
        draw_sphere = radius > 0.0
        if draw_sphere:
            meta.append(KeyValuePair(key="collision_radius_m", value=repr(radius)))
            diameter = _vec3((2.0 * radius, 2.0 * radius, 2.0 * radius))
        emit, frame = self._typed_emitter(channel), self.frame

        def messages() -> Iterator[_Pending]:  # queued like every other topic (time order over the file)
            for i in keep.tolist():
                pose = _pose(xs[i, 0:3], xs[i, 6:10])
                cube = CubePrimitive(pose=pose, size=size, color=_color(_BODY_COLOR))
                spheres = ([SpherePrimitive(pose=pose, size=diameter, color=_color(_COLLISION_COLOR))]
                           if draw_sphere else [])
                entity = SceneEntity(timestamp=_timestamp(ns[i]), frame_id=frame, id="robot", metadata=meta,
                                     cubes=[cube], spheres=spheres)
                yield ns[i], emit, SceneUpdate(entities=[entity])

        self._emit(messages())

    def write_log(self, t: float, level: str, message: str, *, topic: str = ms.TOPIC_LOG) -> None:
        """Write a text message as ``foxglove.Log`` (``name`` = the stage).

        Parameters
        ----------
        t : float
            Mission time [s].
        level : str
            ``debug``, ``info``, ``warning`` (``warn``), ``error`` or ``fatal`` (``critical``), any case.
        message : str
            The text.
        topic : str
            Topic name.
        """
        try:
            log_level = _LOG_LEVELS[level.lower()]
        except KeyError:
            raise ValueError(f"unknown log level {level!r}; use one of {sorted(_LOG_LEVELS)}") from None
        _, ns = _times_ns(topic, t)
        channel = self._typed_channel(topic, LogChannel, "foxglove.Log")
        msg = Log(timestamp=_timestamp(ns[0]), level=log_level, message=str(message), name=self.stage)
        self._emit([(ns[0], self._typed_emitter(channel), msg)])

    # -- attachments and metadata ----------------------------------------------------------------------------

    def attach(self, name: str, data: bytes, media_type: str, *, t: float = 0.0) -> None:
        """Store a file as an MCAP attachment (create time = now, log time = ``t`` [s] mission time).

        Parameters
        ----------
        name : str
            Attachment name (e.g. ``config.yaml``).
        data : bytes
            Content.
        media_type : str
            MIME type (e.g. ``application/yaml``).
        t : float
            Mission time [s] of the attachment.
        """
        self._require_open()
        _, ns = _times_ns(f"attachment {name}", t)
        with held():
            self._writer.attach(
                log_time=ns[0], create_time=time.time_ns(), name=str(name), media_type=str(media_type),
                data=bytes(data),
            )
        if self._written is not None:
            self._written.attachments[str(name)] = bytes(data)

    def write_metadata(self, name: str, data: Mapping[str, object]) -> None:
        """Write a metadata record (string keys and values; values converted with ``str``).

        Parameters
        ----------
        name : str
            Record name.
        data : Mapping[str, object]
            Entries; must not be empty.
        """
        self._require_open()
        if not data:
            raise ValueError(f"metadata record {name!r} is empty (MCAP writers drop empty records)")
        entries = {str(k): str(v) for k, v in data.items()}
        with held():
            self._writer.write_metadata(str(name), entries)
        if self._written is not None:
            self._written.metadata[str(name)] = dict(entries)

    def flush(self) -> None:
        """Write the queued messages (merged by time), finish the current chunk and flush it to disk.

        A time-ordered writer keeps queueing afterwards; later calls should continue after the times written.
        """
        self._require_open()
        if self._queue:
            self._drain()
        with held():
            self._writer.flush()
        self._spill()
