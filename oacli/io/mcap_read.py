"""Read a stage's MCAP file back into oacli's data types (see :mod:`oacli.io.mcap_write` for the writer).

Reading is one linear walk with the ``mcap`` package's stream reader (:class:`oacli.io.mcap_walk.McapWalk`): it
checks every chunk CRC, every attachment CRC and the data-section CRC (``mcap``'s seeking reader checks only the
chunks it reads, never the data-section CRC), bounds what chunks decompress to and how many messages and channels a
file holds. A file cut mid-write (a crash, a ``.partial`` leftover) has no footer; the walk then stops at the last
complete record and the result says ``truncated=True``.
"""

from __future__ import annotations

import itertools
import json
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Attachment, Channel, Message, Metadata, Schema

from oacli.errors import InputError
from oacli.io import mcap_memo
from oacli.io import mcap_schema as ms
from oacli.io.mcap_walk import (
    MAGIC,
    MAX_CHUNK_BYTES,
    MAX_DECOMPRESSED_BYTES,
    MAX_EXPANSION,
    MIN_DECOMPRESSED_BUDGET,
    McapWalk,
    decompressed_budget,
)

__all__ = [
    "MAX_CHUNK_BYTES",
    "MAX_DECOMPRESSED_BYTES",
    "MAX_EXPANSION",
    "MIN_DECOMPRESSED_BUDGET",
    "TELEMETRY_TOPICS",
    "StageRecord",
    "decompressed_budget",
    "read_stage",
    "read_telemetry",
    "read_trajectory",
    "telemetry_from_record",
]
from oacli.types import INPUT_DIM, STATE_DIM, SolveInfo, Telemetry, Trajectory

#: Read sample records written in the writer's template by one pattern over all of a topic's records
#: (:func:`_template_rows`) instead of one :func:`json.loads` each; ``benchmarks/bench_mission_overhead.py`` switches it
#: off for the old path.
FAST_SAMPLES = True

_LOG_LEVEL_NAMES = {0: "unknown", 1: "debug", 2: "info", 3: "warning", 4: "error", 5: "fatal"}


@dataclass(frozen=True)
class StageRecord:
    """What a stage's MCAP file holds, decoded.

    Attributes
    ----------
    path : Path
        The file read.
    trajectories : dict[str, Trajectory]
        Every topic whose schema is ``oacli.TrajectorySample`` and that has samples; name and frame from the
        channel metadata.
    wrenches : dict[str, tuple[ndarray, ndarray]]
        Every ``oacli.Wrench`` topic as ``(t (K,) [s], wrench (K, 6) [N, N·m])``.
    json_records : dict[str, tuple[dict, ...]]
        Every other JSON topic (``/solver/stats``, stage-specific records), records in file order.
    metadata : dict[str, dict[str, str]]
        Metadata records by name (``oacli`` holds version, stage, seed, git commit, creation time, ...).
    attachments : dict[str, bytes]
        Attachments by name (``config.yaml`` holds the resolved configuration).
    topics : dict[str, str]
        Every topic in the file and its schema name (``""`` for schemaless channels).
    message_counts : dict[str, int]
        Messages read per topic.
    log : tuple of (float, str, str)
        ``(t [s], level, message)`` of every ``foxglove.Log`` message, in file order.
    truncated : bool
        True when the file was not closed by its writer (no footer): everything up to the last complete
        record was read, later data is lost.
    bytes_read : int
        End of the last complete record read (for a truncated file: the intact part).
    bytes_total : int
        Size of the file.
    """

    path: Path
    trajectories: dict[str, Trajectory]
    wrenches: dict[str, tuple[np.ndarray, np.ndarray]]
    json_records: dict[str, tuple[dict, ...]]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, bytes]
    topics: dict[str, str]
    message_counts: dict[str, int]
    log: tuple[tuple[float, str, str], ...]
    truncated: bool
    bytes_read: int = 0
    bytes_total: int = 0

    @property
    def solver_stats(self) -> tuple[dict, ...]:
        """Records of ``/solver/stats`` (empty when absent)."""
        return self.json_records.get(ms.TOPIC_SOLVER_STATS, ())

    @property
    def config_yaml(self) -> str | None:
        """The resolved configuration (attachment ``config.yaml``) as text, or None."""
        data = self.attachments.get(ms.CONFIG_ATTACHMENT)
        return None if data is None else data.decode("utf-8")


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
        shift += 7


def _decode_log(buf: bytes) -> tuple[str, str]:
    """``(level, message)`` of a protobuf-encoded ``foxglove.Log`` (level = field 2, message = field 3)."""
    level, message, pos = 0, "", 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        field_number, wire_type = key >> 3, key & 7
        if wire_type == 0:
            value, pos = _varint(buf, pos)
            if field_number == 2:
                level = value
        elif wire_type == 2:
            length, pos = _varint(buf, pos)
            if field_number == 3:
                message = bytes(buf[pos : pos + length]).decode("utf-8", errors="replace")
            pos += length
        elif wire_type == 5:
            pos += 4
        elif wire_type == 1:
            pos += 8
        else:
            raise ValueError(f"unsupported protobuf wire type {wire_type}")
    return _LOG_LEVEL_NAMES.get(level, str(level)), message


class _Scan:
    """Collects what :class:`StageRecord` needs from one :class:`~oacli.io.mcap_walk.McapWalk` of a file."""

    def __init__(self, path: Path, validate_crcs: bool, topics: frozenset[str] | None) -> None:
        self.path = path
        self.validate = validate_crcs
        self.wanted = topics
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.topics: dict[str, str] = {}
        self.channel_meta: dict[str, dict[str, str]] = {}
        self.messages: dict[str, list[tuple[int, bytes]]] = {}
        self.counts: dict[str, int] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.truncated = False
        self.bytes_read = 0
        self.bytes_total = 0

    def fail(self, reason: str) -> InputError:
        return InputError(f"{self.path}: {reason}")

    def run(self) -> None:
        walk = McapWalk(self.path, self._record, validate_crcs=self.validate, topics=self.wanted)
        result = walk.run()
        for channel_id, count in walk.per_channel.items():  # every message, wanted or not
            topic = walk.channels[channel_id]
            self.counts[topic] = self.counts.get(topic, 0) + count
        data = walk.data
        ends_with_magic = len(data) >= 2 * len(MAGIC) and data[-len(MAGIC) :] == MAGIC
        for problem in result.problems:
            if problem.kind != "truncated":
                raise InputError(problem.message)
            if ends_with_magic:  # a closed file whose records run past its end: not a cut, a corrupt file
                raise InputError(f"{self.path}: corrupt MCAP: {problem.message.removeprefix(f'{self.path}: ')}")
        self.truncated = not result.complete
        self.bytes_read, self.bytes_total = result.bytes_read, result.size_bytes

    def _record(self, record: Any) -> None:
        if isinstance(record, Message):
            topic = self.channels[record.channel_id].topic  # the walk refuses unknown channels
            self.messages.setdefault(topic, []).append((record.log_time, record.data))  # the walk filters topics
        elif isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            schema = self.schemas.get(record.schema_id) if record.schema_id else None
            name = schema.name if schema is not None else ""
            if self.topics.get(record.topic, name) != name:
                raise self.fail(f"topic {record.topic} has two schemas ({self.topics[record.topic]}, {name})")
            self.channels[record.id] = record
            self.topics[record.topic] = name
            self.channel_meta[record.topic] = dict(record.metadata)
            self.counts.setdefault(record.topic, 0)
        elif isinstance(record, Attachment):
            self.attachments[record.name] = bytes(record.data)
        elif isinstance(record, Metadata):
            self.metadata[record.name] = dict(record.metadata)


class _WrittenScan(_Scan):
    """A :class:`_Scan` of a file this process wrote and remembers (:mod:`oacli.io.mcap_memo`): the messages' payloads
    as written, the topics, schemas, channel metadata and counts from the file's summary section."""

    def __init__(self, path: Path, topics: frozenset[str] | None, written: mcap_memo.Written) -> None:
        super().__init__(path, True, topics)
        self.written = written

    def run_from_memory(self) -> bool:
        """Fill the scan; False (nothing usable) when the file's summary and what was written disagree."""
        summary = mcap_memo.summary_of(self.path)
        if summary is None or summary.statistics is None:
            return False
        counts = summary.statistics.channel_message_counts
        written = self.written
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id) if channel.schema_id else None
            name = schema.name if schema is not None else ""
            if self.topics.get(channel.topic, name) != name:
                return False
            count = counts.get(channel_id, 0)
            kept = len(written.messages.get(channel.topic, ()))
            decoded = channel.message_encoding == "json" or name == "foxglove.Log"
            if decoded and kept != count:  # every message the reader decodes must have been kept
                return False
            self.channels[channel_id] = channel
            self.topics[channel.topic] = name
            self.channel_meta[channel.topic] = dict(channel.metadata)
            self.counts[channel.topic] = self.counts.get(channel.topic, 0) + count
        if set(written.messages) - set(self.topics):
            return False
        if ({m.name for m in summary.metadata_indexes} != set(written.metadata)
                or {a.name for a in summary.attachment_indexes} != set(written.attachments)):
            return False
        for topic, messages in written.messages.items():
            if self.wanted is None or topic in self.wanted:
                self.messages[topic] = messages
        self.metadata = {k: dict(v) for k, v in written.metadata.items()}
        self.attachments = dict(written.attachments)
        self.truncated = False
        self.bytes_read = self.bytes_total = self.path.stat().st_size
        return True


def _scan(path: Path, validate_crcs: bool, wanted: frozenset[str] | None) -> _Scan:
    """The messages of ``wanted`` topics of a file (all when None) and what else :class:`StageRecord` needs: from
    what this process wrote into it when it is remembered and unchanged (:mod:`oacli.io.mcap_memo`), else one walk
    of the file."""
    written = mcap_memo.recall(path) if validate_crcs else None
    if written is not None:
        from_memory = _WrittenScan(path, wanted, written)
        if from_memory.run_from_memory():
            return from_memory
    scan = _Scan(path, validate_crcs, wanted)
    scan.run()
    return scan


def _json_messages(scan: _Scan, topic: str) -> list[dict]:
    out = []
    for i, (_, data) in enumerate(scan.messages.get(topic, [])):
        try:
            out.append(json.loads(data))
        except ValueError as exc:
            raise scan.fail(f"message {i} on {topic} is not valid JSON ({exc})") from None
        except RecursionError:
            raise scan.fail(f"message {i} on {topic} is JSON nested too deeply") from None
    return out


#: A JSON number that :func:`json.loads` reads as a float (a fraction or an exponent: ``float(text)`` is then
#: exactly the value it gives; integers, ``-0`` among them, are left to the JSON path).
_FLOAT = rb"(-?(?:0|[1-9][0-9]*)(?:\.[0-9]+(?:[eE][-+]?[0-9]+)?|[eE][-+]?[0-9]+))"


def _template_pattern(template: str) -> re.Pattern[bytes]:
    """A whole-line pattern of a writer's record template (:mod:`oacli.io.mcap_schema`): each ``%r`` a float."""
    parts = [re.escape(part.encode()) for part in template.split("%r")]
    return re.compile(rb"^" + _FLOAT.join(parts) + rb"$", re.MULTILINE)


#: Sample records exactly as :class:`oacli.io.mcap_write.StageMcapWriter` encodes them (fields in template order).
_SAMPLE_PATTERNS: dict[str, tuple[re.Pattern[bytes], int]] = {
    ms.TRAJECTORY_SAMPLE: (_template_pattern(ms.TRAJECTORY_SAMPLE_TEMPLATE), 1 + STATE_DIM + INPUT_DIM),
    ms.WRENCH: (_template_pattern(ms.WRENCH_TEMPLATE), 1 + INPUT_DIM),
}


def _template_rows(payloads: list[bytes], schema_name: str) -> np.ndarray | None:
    """The rows ``[t, fields in template order]`` of sample records written in the writer's exact template, parsed
    in one pass over all of them; None when any record differs from the template in any way (whitespace, key order,
    integers, extra fields, ...): the caller then decodes every record as JSON. Where this succeeds, the values are
    exactly those :func:`json.loads` gives (each number is read by ``float``, as JSON reads a number with a fraction
    or an exponent), in the row layout :func:`_trajectory` and :func:`_wrenches` build."""
    pattern, width = _SAMPLE_PATTERNS[schema_name]
    if not payloads:
        return None
    joined = b"\n".join(payloads)
    if joined.count(b"\n") != len(payloads) - 1:  # a record holding a line break: not in template form
        return None
    fields = pattern.findall(joined)
    if len(fields) != len(payloads):  # each line matches at most once, so every record matched
        return None
    return np.array(list(map(float, itertools.chain.from_iterable(fields))), dtype=float).reshape(len(payloads), width)


def _trajectory_from_rows(scan: _Scan, topic: str, arr: np.ndarray) -> Trajectory:
    meta = scan.channel_meta.get(topic, {})
    try:
        return Trajectory(
            t=arr[:, 0],
            x=arr[:, 1 : 1 + STATE_DIM],
            u=arr[:, 1 + STATE_DIM :],
            name=meta.get("name", topic.strip("/")),
            frame=meta.get("frame", "world"),
        )
    except ValueError as exc:
        raise scan.fail(f"{topic}: not a valid trajectory ({exc})") from None


def _wrenches_from_rows(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t, w = arr[:, 0].copy(), arr[:, 1:].copy()
    t.setflags(write=False)
    w.setflags(write=False)
    return t, w


def _trajectory(scan: _Scan, topic: str, records: list[dict]) -> Trajectory:
    try:
        rows = [
            [
                r["t"],
                *r["position"],
                *r["velocity"],
                *r["quaternion"],
                *r["angular_velocity"],
                *r["force"],
                *r["torque"],
            ]
            for r in records
        ]
        arr = np.array(rows, dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise scan.fail(f"{topic}: malformed {ms.TRAJECTORY_SAMPLE} record ({exc!r})") from None
    if arr.shape[1:] != (1 + STATE_DIM + INPUT_DIM,):
        raise scan.fail(f"{topic}: {ms.TRAJECTORY_SAMPLE} records have the wrong vector lengths")
    return _trajectory_from_rows(scan, topic, arr)


def _wrenches(scan: _Scan, topic: str, records: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    try:
        arr = np.array([[r["t"], *r["force"], *r["torque"]] for r in records], dtype=float).reshape(-1, 7)
    except (KeyError, TypeError, ValueError) as exc:
        raise scan.fail(f"{topic}: malformed {ms.WRENCH} record ({exc!r})") from None
    return _wrenches_from_rows(arr)


def read_stage(path: Path, *, validate_crcs: bool = True, topics: Iterable[str] | None = None) -> StageRecord:
    """Read a stage's MCAP file.

    Parameters
    ----------
    path : Path
        The ``.mcap`` file (a ``.partial`` leftover of a crashed run is readable too: ``truncated=True``).
    validate_crcs : bool
        Check the chunk, attachment and data-section CRCs (default). Corruption raises :class:`InputError`.
    topics : iterable of str, optional
        Decode only these topics (all when omitted); ``topics`` and ``message_counts`` still list every topic.

    Returns
    -------
    StageRecord

    Raises
    ------
    InputError
        The file is missing, unreadable, not an MCAP file, corrupt (a CRC mismatch) or malformed.
    """
    scan = _scan(Path(path), validate_crcs, None if topics is None else frozenset(topics))
    trajectories: dict[str, Trajectory] = {}
    wrenches: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    json_records: dict[str, tuple[dict, ...]] = {}
    log: list[tuple[float, str, str]] = []
    for topic in scan.messages:
        schema_name = scan.topics[topic]
        channel_encoding = next(c.message_encoding for c in scan.channels.values() if c.topic == topic)
        if schema_name == "foxglove.Log":
            for log_time, data in scan.messages[topic]:
                try:
                    level, text = _decode_log(data)
                except (ValueError, IndexError) as exc:
                    raise scan.fail(f"undecodable foxglove.Log message on {topic} ({exc})") from None
                log.append((log_time / 1e9, level, text))
        elif channel_encoding == "json":
            rows = (_template_rows([data for _, data in scan.messages[topic]], schema_name) if FAST_SAMPLES
                    and schema_name in _SAMPLE_PATTERNS else None)
            if rows is not None:
                if schema_name == ms.TRAJECTORY_SAMPLE:
                    trajectories[topic] = _trajectory_from_rows(scan, topic, rows)
                else:
                    wrenches[topic] = _wrenches_from_rows(rows)
                continue
            records = _json_messages(scan, topic)
            if schema_name == ms.TRAJECTORY_SAMPLE:
                if records:
                    trajectories[topic] = _trajectory(scan, topic, records)
            elif schema_name == ms.WRENCH:
                wrenches[topic] = _wrenches(scan, topic, records)
            else:
                json_records[topic] = tuple(records)
    return StageRecord(
        path=Path(path),
        trajectories=trajectories,
        wrenches=wrenches,
        json_records=json_records,
        metadata=scan.metadata,
        attachments=scan.attachments,
        topics=dict(sorted(scan.topics.items())),
        message_counts=dict(sorted(scan.counts.items())),
        log=tuple(log),
        truncated=scan.truncated,
        bytes_read=scan.bytes_read,
        bytes_total=scan.bytes_total,
    )


def _refuse_truncated(record: StageRecord) -> None:
    raise InputError(
        f"{record.path}: the file is truncated (its writer did not finish, e.g. the run crashed); "
        "rerun the stage that produced it"
    )


def _missing_topic(record: StageRecord, topic: str, schema_name: str) -> InputError:
    if topic in record.topics:
        found = record.topics[topic] or "no schema"
        if found == schema_name:
            return InputError(f"{record.path}: topic {topic} has no messages")
        return InputError(f"{record.path}: topic {topic} carries {found}, not {schema_name}")
    listed = ", ".join(f"{t} ({s or 'no schema'})" for t, s in record.topics.items()) or "none"
    return InputError(f"{record.path}: no topic {topic}; topics in the file: {listed}")


def read_trajectory(path: Path, topic: str = ms.TOPIC_TRAJECTORY, *, allow_truncated: bool = False) -> Trajectory:
    """Read one ``oacli.TrajectorySample`` topic of an MCAP file as a :class:`~oacli.types.Trajectory`.

    Parameters
    ----------
    path : Path
        The ``.mcap`` file (CRCs are checked).
    topic : str
        Topic to read (``/trajectory`` by default).
    allow_truncated : bool
        Accept a file its writer did not finish and return the samples it holds (refused by default: a
        stage's input should not silently be half a trajectory).

    Returns
    -------
    Trajectory

    Raises
    ------
    InputError
        Missing or unreadable file, not an MCAP file, CRC mismatch, truncated file, or no such topic (the
        message lists the topics the file has).
    """
    record = read_stage(path, topics=[topic])
    if record.truncated and not allow_truncated:
        _refuse_truncated(record)
    if topic not in record.trajectories:
        raise _missing_topic(record, topic, ms.TRAJECTORY_SAMPLE)
    return record.trajectories[topic]


def _input_series(record: StageRecord, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """``(t, u)`` of an input topic stored either as ``oacli.TrajectorySample`` or as ``oacli.Wrench``."""
    if topic in record.trajectories:
        traj = record.trajectories[topic]
        return traj.t, traj.u
    if topic in record.wrenches:
        return record.wrenches[topic]
    raise _missing_topic(record, topic, ms.TRAJECTORY_SAMPLE)


def read_telemetry(path: Path, *, allow_truncated: bool = False) -> Telemetry:
    """Read a ``track`` stage's closed-loop record as :class:`~oacli.types.Telemetry`.

    Topics: ``/state/true`` (plant rate) gives ``t_true``, ``x_true``; ``/state/measured`` gives ``t_ctrl`` and
    ``x_measured``; ``/reference`` the reference state, ``/control/command`` and ``/control/applied`` the inputs
    (``oacli.TrajectorySample`` -- its ``force``/``torque`` -- or ``oacli.Wrench``), ``/disturbance`` (optional,
    ``oacli.Wrench``), ``/solver/stats`` (optional). All controller-rate topics must have exactly the times
    of ``/state/measured``.

    Parameters
    ----------
    path : Path
        The ``track.mcap`` file.
    allow_truncated : bool
        Accept a file cut by a crash; controller-rate topics are cut to their common length.

    Returns
    -------
    Telemetry

    Raises
    ------
    InputError
        Unreadable, corrupt or truncated file, a missing topic, or controller-rate topics whose times differ.
    """
    return telemetry_from_record(read_stage(path, topics=TELEMETRY_TOPICS), allow_truncated=allow_truncated)


#: The topics :func:`read_telemetry` reads.
TELEMETRY_TOPICS: tuple[str, ...] = (
    ms.TOPIC_STATE_TRUE,
    ms.TOPIC_STATE_MEASURED,
    ms.TOPIC_REFERENCE,
    ms.TOPIC_CONTROL_COMMAND,
    ms.TOPIC_CONTROL_APPLIED,
    ms.TOPIC_DISTURBANCE,
    ms.TOPIC_SOLVER_STATS,
)


def telemetry_from_record(record: StageRecord, *, allow_truncated: bool = False) -> Telemetry:
    """:func:`read_telemetry` of a file already read (its :data:`TELEMETRY_TOPICS` at least).

    Parameters
    ----------
    record : StageRecord
        A ``track.mcap`` read with :func:`read_stage` (all topics, or a set including :data:`TELEMETRY_TOPICS`).
    allow_truncated : bool
        As for :func:`read_telemetry`.

    Returns
    -------
    Telemetry

    Raises
    ------
    InputError
        As for :func:`read_telemetry`.
    """
    if record.truncated and not allow_truncated:
        _refuse_truncated(record)
    for topic in (ms.TOPIC_STATE_TRUE, ms.TOPIC_STATE_MEASURED, ms.TOPIC_REFERENCE):
        if topic not in record.trajectories:
            raise _missing_topic(record, topic, ms.TRAJECTORY_SAMPLE)
    true, measured = record.trajectories[ms.TOPIC_STATE_TRUE], record.trajectories[ms.TOPIC_STATE_MEASURED]
    reference = record.trajectories[ms.TOPIC_REFERENCE]
    series: dict[str, tuple[np.ndarray, np.ndarray]] = {
        ms.TOPIC_STATE_MEASURED: (measured.t, measured.x),
        ms.TOPIC_REFERENCE: (reference.t, reference.x),
        ms.TOPIC_CONTROL_COMMAND: _input_series(record, ms.TOPIC_CONTROL_COMMAND),
        ms.TOPIC_CONTROL_APPLIED: _input_series(record, ms.TOPIC_CONTROL_APPLIED),
    }
    if ms.TOPIC_DISTURBANCE in record.wrenches or ms.TOPIC_DISTURBANCE in record.trajectories:
        series[ms.TOPIC_DISTURBANCE] = _input_series(record, ms.TOPIC_DISTURBANCE)
    stats = record.solver_stats
    if stats:
        series[ms.TOPIC_SOLVER_STATS] = (np.array([float(s["t"]) for s in stats]), np.zeros((len(stats), 0)))
    k = len(measured.t)
    if allow_truncated:
        k = min(len(t) for t, _ in series.values())
    t_ctrl = measured.t[:k]
    for topic, (t, _) in series.items():
        if len(t) < k or (len(t) != k and not allow_truncated):
            raise InputError(f"{record.path}: {topic} has {len(t)} samples but {ms.TOPIC_STATE_MEASURED} has {k}")
        if not np.array_equal(t[:k], t_ctrl):
            raise InputError(f"{record.path}: the times of {topic} differ from those of {ms.TOPIC_STATE_MEASURED}")

    def nan_if_none(value: Any) -> float:
        return float("nan") if value is None else float(value)

    solve_info = tuple(
        SolveInfo(
            status=str(s["status"]),
            success=bool(s["success"]),
            objective=nan_if_none(s.get("objective")),
            iterations=int(s.get("iterations", -1)),
            solve_time_s=nan_if_none(s.get("solve_time_ms")) / 1e3,
            step_time_s=nan_if_none(s.get("step_time_ms")) / 1e3,
        )
        for s in stats[:k]
    )
    disturbance = series[ms.TOPIC_DISTURBANCE][1][:k] if ms.TOPIC_DISTURBANCE in series else None
    return Telemetry(
        t_true=true.t,
        x_true=true.x,
        t_ctrl=t_ctrl,
        x_measured=measured.x[:k],
        x_reference=series[ms.TOPIC_REFERENCE][1][:k],
        u_command=series[ms.TOPIC_CONTROL_COMMAND][1][:k],
        u_applied=series[ms.TOPIC_CONTROL_APPLIED][1][:k],
        solve_info=solve_info,
        disturbance=disturbance,
    )
