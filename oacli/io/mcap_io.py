"""Write and read a stage's MCAP file (the record of truth of every oacli stage).

The contract (topics, schemas, units, metadata, attachments) is documented in ``docs/mcap.md`` and its names
and JSON schemas live in :mod:`oacli.io.mcap_schema`.

Writing uses the Foxglove SDK's MCAP writer (``foxglove.open_mcap``) with one ``foxglove.Context`` per file, so
channels of one file never leak into another. It writes zstd-compressed chunks of at most
:data:`DEFAULT_CHUNK_SIZE` bytes (uncompressed), chunk CRCs, the data-section CRC, the summary CRC and attachment
CRCs. The file is written under a temporary name and renamed into place only when the ``with`` block ends
without an exception (:func:`oacli.io.atomic.atomic_path`).

Reading walks the file record by record with the ``mcap`` package's record parsers: it checks every chunk CRC,
every attachment CRC and the data-section CRC (``mcap``'s seeking reader checks only the chunks it reads, never
the data-section CRC). A file cut mid-write (a crash, a ``.partial`` leftover) has no footer; the same walk then
stops at the last complete record and reports ``truncated=True``.
"""

from __future__ import annotations

import io
import json
import math
import sys
import time
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

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
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, DataEnd, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, breakup_chunk

import oacli
from oacli.errors import InputError
from oacli.geometry.shapes import Scene
from oacli.io import mcap_schema as ms
from oacli.io.atomic import atomic_path
from oacli.types import INPUT_DIM, STATE_DIM, SolveInfo, Telemetry, Trajectory

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "StageMcapWriter",
    "StageRecord",
    "quaternion_from_matrix",
    "read_stage",
    "read_telemetry",
    "read_trajectory",
]

#: Target uncompressed chunk size [bytes]; a hard crash loses at most the chunk being filled.
DEFAULT_CHUNK_SIZE = 256 * 1024

_MAGIC = b"\x89MCAP0\r\n"
_NS_PER_S = 1_000_000_000

_LOG_LEVELS = {
    "debug": LogLevel.Debug,
    "info": LogLevel.Info,
    "warning": LogLevel.Warning,
    "warn": LogLevel.Warning,
    "error": LogLevel.Error,
    "fatal": LogLevel.Fatal,
    "critical": LogLevel.Fatal,
}
_LOG_LEVEL_NAMES = {0: "unknown", 1: "debug", 2: "info", 3: "warning", 4: "error", 5: "fatal"}

_KEEP_IN_COLOR = (0.2, 0.8, 0.3, 0.08)
_KEEP_OUT_COLOR = (0.9, 0.15, 0.15, 0.35)
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


# ----------------------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------------------


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


def _finite_array(what: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: contains NaN or infinite values")
    return arr


def _timestamp(ns: int) -> Timestamp:
    return Timestamp(ns // _NS_PER_S, ns % _NS_PER_S)


def _pose(position: Sequence[float], quat_xyzw: Sequence[float]) -> Pose:
    x, y, z = (float(v) for v in position)
    qx, qy, qz, qw = (float(v) for v in quat_xyzw)
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))


def _color(rgba: Sequence[float]) -> Color:
    r, g, b, a = rgba
    return Color(r=r, g=g, b=b, a=a)


def _vec3(v: Sequence[float]) -> Vector3:
    x, y, z = (float(c) for c in v)
    return Vector3(x=x, y=y, z=z)


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(repr(float(c)) for c in v) + "]"


def quaternion_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[x, y, z, w]`` (scalar last, ``w >= 0``) of a rotation matrix (Shepperd's method).

    Parameters
    ----------
    rotation : ndarray, shape (3, 3)
        Proper rotation matrix (orthonormal, det = +1) mapping body to world coordinates.

    Returns
    -------
    ndarray, shape (4,)
        The quaternion q with ``R(q) = rotation``.
    """
    m = np.asarray(rotation, dtype=float).reshape(3, 3)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    k = int(np.argmax([trace, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        w = 0.5 * math.sqrt(max(1.0 + trace, 0.0))
        s = 0.25 / w
        q = [(m[2, 1] - m[1, 2]) * s, (m[0, 2] - m[2, 0]) * s, (m[1, 0] - m[0, 1]) * s, w]
    elif k == 1:
        x = 0.5 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        s = 0.25 / x
        q = [x, (m[0, 1] + m[1, 0]) * s, (m[0, 2] + m[2, 0]) * s, (m[2, 1] - m[1, 2]) * s]
    elif k == 2:
        y = 0.5 * math.sqrt(max(1.0 - m[0, 0] + m[1, 1] - m[2, 2], 0.0))
        s = 0.25 / y
        q = [(m[0, 1] + m[1, 0]) * s, y, (m[1, 2] + m[2, 1]) * s, (m[0, 2] - m[2, 0]) * s]
    else:
        z = 0.5 * math.sqrt(max(1.0 - m[0, 0] - m[1, 1] + m[2, 2], 0.0))
        s = 0.25 / z
        q = [(m[0, 2] + m[2, 0]) * s, (m[1, 2] + m[2, 1]) * s, z, (m[1, 0] - m[0, 1]) * s]
    quat = np.array(q) / np.linalg.norm(q)
    return -quat if quat[3] < 0.0 else quat


def _jsonable(value: Any) -> Any:
    """Convert numpy values, tuples and non-finite floats (to ``None``) into plain JSON values."""
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def _ms_or_none(seconds: float) -> float | None:
    seconds = float(seconds)
    return seconds * 1e3 if math.isfinite(seconds) else None


class StageMcapWriter:
    """Context manager writing one stage's MCAP file atomically.

    On entering, the file is opened under a temporary name (``.<name>.partial`` beside ``path``), and the
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
    ) -> None:
        self.path = Path(path)
        self.stage = str(stage)
        self.frame = str(frame)
        self._config_yaml = str(config_yaml)
        self._extra_metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._chunk_size = int(chunk_size)
        self._overwrite = bool(overwrite)
        self._atomic: Any = None
        self._writer: Any = None
        self._context: Any = None
        self._state = "new"
        # topic -> (channel, schema name, channel metadata)
        self._channels: dict[str, tuple[Any, str, dict[str, str]]] = {}
        self._last_t: dict[str, float] = {}

    # -- context management ------------------------------------------------------------------------------

    def __enter__(self) -> StageMcapWriter:
        if self._state != "new":
            raise RuntimeError("a StageMcapWriter can be entered only once")
        if self.path.exists() and not self._overwrite:
            raise FileExistsError(f"{self.path} exists; refusing to overwrite it")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"folder {self.path.parent} does not exist")
        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        try:
            self._context = foxglove.Context()
            options = MCAPWriteOptions(
                compression=MCAPCompression.Zstd,
                chunk_size=self._chunk_size,
                calculate_chunk_crcs=True,
                calculate_data_section_crc=True,
                calculate_summary_section_crc=True,
                calculate_attachment_crcs=True,
            )
            self._writer = foxglove.open_mcap(tmp, context=self._context, writer_options=options)
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
        self._state = "closed"
        try:
            if self._writer is not None:
                self._writer.close()
        except BaseException as err:
            if exc is None:
                self._atomic.__exit__(type(err), err, err.__traceback__)
                raise
            err.add_note("(while closing the MCAP writer after an earlier error)")
        finally:
            self._writer = None
            for channel, _, _ in self._channels.values():
                channel.close()
            self._channels.clear()
            self._context = None
        self._atomic.__exit__(exc_type, exc, tb)

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

    @staticmethod
    def _log_rows(channel: Any, template: str, rows: np.ndarray, ns: list[int]) -> None:
        base_log = channel.base.log  # the JSON text is already encoded: skip foxglove.Channel.log's checks
        for row, log_time in zip(rows.tolist(), ns, strict=True):
            base_log((template % tuple(row)).encode(), log_time, None)

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
            self._log_rows(channel, ms.TRAJECTORY_SAMPLE_TEMPLATE, np.column_stack([times, xs, us]), ns)
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
            self._log_rows(channel, ms.WRENCH_TEMPLATE, np.column_stack([times, w]), ns)
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
        base_log = channel.base.log
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
            base_log(json.dumps(record, allow_nan=False).encode(), log_time, None)
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
        times, ns = _times_ns(topic, t)
        if times.shape != (1,):
            raise ValueError(f"{topic}: write_json takes one time, got shape {times.shape}")
        t_s = float(times[0])
        if "t" in record and float(record["t"]) != t_s:
            raise ValueError(f"{topic}: record t={record['t']!r} differs from t={t_s!r}")
        channel = self._json_channel(topic, schema_name, schema, {})
        body = _jsonable({"t": t_s, **{k: v for k, v in record.items() if k != "t"}})
        channel.base.log(json.dumps(body, allow_nan=False).encode(), ns[0], None)

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
        frame = self.frame
        for (px, py, pz, qx, qy, qz, qw), log_time in zip(xs[:, [0, 1, 2, 6, 7, 8, 9]].tolist(), ns, strict=True):
            pose = Pose(position=Vector3(x=px, y=py, z=pz), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))
            channel.log(PoseInFrame(timestamp=_timestamp(log_time), frame_id=frame, pose=pose), log_time=log_time)
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
            quat = quaternion_from_matrix(rotation)
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
        channel.log(SceneUpdate(entities=entities), log_time=ns[0])

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
        channel.log(msg, log_time=ns[0])

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
        self._writer.attach(
            log_time=ns[0], create_time=time.time_ns(), name=str(name), media_type=str(media_type), data=bytes(data)
        )

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
        self._writer.write_metadata(str(name), {str(k): str(v) for k, v in data.items()})

    def flush(self) -> None:
        """Finish the current chunk and flush it to disk (bounds what a hard crash can lose)."""
        self._require_open()
        self._writer.flush()


# ----------------------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------------------


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


def _stream(body: bytes | memoryview) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


class _Scan:
    """Record-by-record walk of an MCAP file collecting what :class:`StageRecord` needs."""

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

    def fail(self, reason: str) -> InputError:
        return InputError(f"{self.path}: {reason}")

    def run(self) -> None:
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            raise self.fail("file not found") from None
        except OSError as exc:
            raise self.fail(f"cannot read the file ({exc.strerror or exc})") from None
        if len(data) < len(_MAGIC) or data[: len(_MAGIC)] != _MAGIC:
            raise self.fail("not an MCAP file (it does not start with the MCAP magic bytes)")
        complete = len(data) >= 2 * len(_MAGIC) and data[-len(_MAGIC) :] == _MAGIC
        view = memoryview(data)
        pos, end = len(_MAGIC), len(data)
        finished = False  # reached the DataEnd (or Footer) record
        while pos + 9 <= end:
            opcode = data[pos]
            length = int.from_bytes(data[pos + 1 : pos + 9], "little")
            if pos + 9 + length > end:
                break  # a record cut by the end of the file
            body = view[pos + 9 : pos + 9 + length]
            if opcode == Opcode.DATA_END:
                if self.validate:
                    expected = DataEnd.read(_stream(body)).data_section_crc
                    actual = zlib.crc32(view[:pos])
                    if expected != 0 and expected != actual:
                        raise self.fail(
                            f"data section CRC mismatch (stored {expected:#010x}, computed {actual:#010x}): "
                            "the file is corrupt"
                        )
                finished = True
                break  # the summary section after it repeats what was read
            if opcode == Opcode.FOOTER:
                finished = True
                break
            self._record(opcode, body, pos)
            pos += 9 + length
        if complete and not finished:
            raise self.fail(f"corrupt MCAP: the record at byte {pos} runs past the end of the data section")
        self.truncated = not complete

    def _record(self, opcode: int, body: memoryview, offset: int) -> None:
        try:
            if opcode == Opcode.CHUNK:
                chunk = Chunk.read(_stream(body))
                try:
                    records = breakup_chunk(chunk, validate_crc=self.validate)
                except CRCValidationError as exc:
                    raise self.fail(
                        f"chunk at byte {offset} failed its CRC check (stored {exc.expected:#010x}, computed "
                        f"{exc.actual:#010x}): the file is corrupt"
                    ) from None
                except InputError:
                    raise
                except Exception as exc:
                    raise self.fail(
                        f"chunk at byte {offset} is corrupt: its {chunk.compression} data do not decompress "
                        f"({exc}), so its CRC cannot match"
                    ) from None
                for record in records:
                    self._inner(record)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._inner(Schema.read(_stream(body)) if opcode == Opcode.SCHEMA else Channel.read(_stream(body)))
            elif opcode == Opcode.MESSAGE:
                self._inner(Message.read(_stream(body), len(body)))
            elif opcode == Opcode.ATTACHMENT:
                if self.validate:
                    stored = int.from_bytes(body[-4:], "little")
                    actual = zlib.crc32(body[:-4])
                    if stored != 0 and stored != actual:
                        raise self.fail(f"attachment at byte {offset} failed its CRC check: the file is corrupt")
                attachment = Attachment.read(_stream(body))
                self.attachments[attachment.name] = bytes(attachment.data)
            elif opcode == Opcode.METADATA:
                record = Metadata.read(_stream(body))
                self.metadata[record.name] = dict(record.metadata)
        except InputError:
            raise
        except Exception as exc:
            raise self.fail(f"corrupt MCAP record (opcode {opcode:#04x}) at byte {offset}: {exc}") from None

    def _inner(self, record: Any) -> None:
        if isinstance(record, Message):
            channel = self.channels.get(record.channel_id)
            if channel is None:
                raise self.fail(f"message on unknown channel id {record.channel_id}")
            topic = channel.topic
            self.counts[topic] = self.counts.get(topic, 0) + 1
            if self.wanted is None or topic in self.wanted:
                self.messages.setdefault(topic, []).append((record.log_time, record.data))
        elif isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            schema = self.schemas.get(record.schema_id) if record.schema_id else None
            if record.schema_id and schema is None:
                raise self.fail(f"channel {record.topic} refers to unknown schema id {record.schema_id}")
            name = schema.name if schema is not None else ""
            if self.topics.get(record.topic, name) != name:
                raise self.fail(f"topic {record.topic} has two schemas ({self.topics[record.topic]}, {name})")
            self.channels[record.id] = record
            self.topics[record.topic] = name
            self.channel_meta[record.topic] = dict(record.metadata)
            self.counts.setdefault(record.topic, 0)


def _json_messages(scan: _Scan, topic: str) -> list[dict]:
    out = []
    for i, (_, data) in enumerate(scan.messages.get(topic, [])):
        try:
            out.append(json.loads(data))
        except ValueError as exc:
            raise scan.fail(f"message {i} on {topic} is not valid JSON ({exc})") from None
    return out


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


def _wrenches(scan: _Scan, topic: str, records: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    try:
        arr = np.array([[r["t"], *r["force"], *r["torque"]] for r in records], dtype=float).reshape(-1, 7)
    except (KeyError, TypeError, ValueError) as exc:
        raise scan.fail(f"{topic}: malformed {ms.WRENCH} record ({exc!r})") from None
    t, w = arr[:, 0].copy(), arr[:, 1:].copy()
    t.setflags(write=False)
    w.setflags(write=False)
    return t, w


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
    scan = _Scan(Path(path), validate_crcs, None if topics is None else frozenset(topics))
    scan.run()
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
    wanted = [
        ms.TOPIC_STATE_TRUE,
        ms.TOPIC_STATE_MEASURED,
        ms.TOPIC_REFERENCE,
        ms.TOPIC_CONTROL_COMMAND,
        ms.TOPIC_CONTROL_APPLIED,
        ms.TOPIC_DISTURBANCE,
        ms.TOPIC_SOLVER_STATS,
    ]
    record = read_stage(path, topics=wanted)
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
