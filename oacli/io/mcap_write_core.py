"""The machinery of :class:`oacli.io.mcap_write.StageMcapWriter`: time checks, the spool file the Foxglove SDK's
MCAP writer writes to, channels, and the queue that writes messages merged by time (:class:`WriterCore`).

The record families are written by its subclasses: oacli's JSON records in :mod:`oacli.io.mcap_write_records`,
Foxglove messages (poses, ``/scene``, ``/log``) in :mod:`oacli.io.mcap_write_scene`; the file's life (open,
finish, attachments, metadata) in :mod:`oacli.io.mcap_write`.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from operator import itemgetter
from pathlib import Path
from typing import Any

import foxglove
import numpy as np
from foxglove.messages import Color, Log, Pose, Quaternion, Timestamp, Vector3

from oacli.io import mcap_memo
from oacli.io.atomic import WriteError, describe_os_error
from oacli.signals import PENDING, held, interruption_point

#: Target uncompressed chunk size [bytes]; a hard crash loses at most the chunk being filled.
DEFAULT_CHUNK_SIZE = 256 * 1024

_NS_PER_S = 1_000_000_000

#: zstd level of the chunks: 1, the fastest standard level. On a mission's JSON records (10 MB) the writer's default
#: level cost about 0.13 s of CPU, level 1 about 0.08 s, and its files were no larger (issue 9).
ZSTD_LEVEL = 1

#: One queued message: ``(log_time [ns], emit, payload)``; ``emit(payload, log_time)`` writes it.
_Pending = tuple[int, Callable[[Any, int], None], Any]

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


class WriterCore:
    """The state and the write path shared by the record families (see :class:`oacli.io.mcap_write.StageMcapWriter`
    for the parameters)."""

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

    # -- the write path ----------------------------------------------------------------------------------------

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

