"""Foxglove messages of :class:`oacli.io.mcap_write.StageMcapWriter`: ``/robot/pose`` (``foxglove.PoseInFrame``),
``/scene`` (``foxglove.SceneUpdate``: workspace, paths, robot body) and ``/log`` (``foxglove.Log``); see
``docs/mcap.md``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence

import numpy as np
from foxglove.channels import LogChannel, PoseInFrameChannel, SceneUpdateChannel
from foxglove.messages import (
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
    Vector3,
)

from oacli.geometry.shapes import Scene
from oacli.io import mcap_schema as ms
from oacli.io.mcap_write_core import (
    WriterCore,
    _color,
    _finite_array,
    _fmt,
    _Pending,
    _pose,
    _times_ns,
    _timestamp,
    _vec3,
)
from oacli.model.quaternion import from_rotation_matrix
from oacli.types import STATE_DIM

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
#: Planner tree edges (grey), tube cross-sections (purple wireframe) and the current cross-section (translucent).
_TREE_COLOR = (0.45, 0.45, 0.45, 0.6)
_TUBE_COLOR = (0.58, 0.4, 0.74, 0.5)
_TUBE_NOW_COLOR = (0.58, 0.4, 0.74, 0.25)
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
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


class SceneWrites(WriterCore):
    """The Foxglove message writers of :class:`oacli.io.mcap_write.StageMcapWriter`."""

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


    def write_plan_tree(self, edges: Sequence[np.ndarray], in_path: Sequence[bool] | np.ndarray, *, t: float = 0.0,
                        max_points_per_edge: int = 12, topic: str = ms.TOPIC_SCENE) -> None:
        """Write a planner's final tree on ``/scene`` as entity ``plan/tree``: one ``LINE_LIST`` of every edge's
        polyline (each node's incoming edge, thinned evenly to at most ``max_points_per_edge`` points), grey, and
        the edges on the solution path as a second, thicker ``LINE_LIST`` in the path colour.

        Parameters
        ----------
        edges : sequence of ndarray, shape (M_i, 3)
            Each node's incoming edge as positions [m] (the root's is empty or one point).
        in_path : sequence of bool
            Per node: its edge is on the solution path.
        t : float
            Time of the update [s].
        max_points_per_edge : int
            Points kept per edge (>= 2).
        topic : str
            Topic name.
        """
        _, ns = _times_ns(topic, t)
        lines = []
        for on_path, color, thickness in ((False, _TREE_COLOR, 1.0), (True, _PATH_PALETTE[1], 3.0)):
            points: list[Point3] = []
            for edge, flag in zip(edges, in_path, strict=True):
                pts = np.asarray(edge, dtype=float).reshape(-1, 3)
                if len(pts) < 2 or bool(flag) != on_path or not np.all(np.isfinite(pts)):
                    continue
                keep = np.unique(np.linspace(0, len(pts) - 1, max(2, int(max_points_per_edge))).round().astype(int))
                seg = pts[keep]
                for a, b in zip(seg[:-1].tolist(), seg[1:].tolist(), strict=True):
                    points += [Point3(x=a[0], y=a[1], z=a[2]), Point3(x=b[0], y=b[1], z=b[2])]
            if points:
                lines.append(LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose((0.0, 0.0, 0.0), _IDENTITY),
                                           thickness=thickness, scale_invariant=True, points=points,
                                           color=_color(color)))
        meta = [KeyValuePair(key="kind", value="planner tree (each node's incoming edge)"),
                KeyValuePair(key="nodes", value=str(len(edges))),
                KeyValuePair(key="edges_in_path", value=str(int(np.count_nonzero(np.asarray(in_path, dtype=bool)))))]
        entity = SceneEntity(timestamp=_timestamp(ns[0]), frame_id=self.frame, id="plan/tree", metadata=meta,
                             lines=lines)
        channel = self._typed_channel(topic, SceneUpdateChannel, "foxglove.SceneUpdate")
        self._emit([(ns[0], self._typed_emitter(channel), SceneUpdate(entities=[entity]))])

    def write_tube_sections(self, t: np.ndarray, center_m: np.ndarray, extent_m: np.ndarray, *,
                            topic: str = ms.TOPIC_SCENE) -> None:
        """Write the tube MPC's position tube on ``/scene``: entity ``tube/sections`` at ``t[0]``, a ``LINE_LIST``
        of the 12 edges of every step's cross-section box (the nominal position ``z`` plus Z's position extent), and
        entity ``tube/now``, the current cross-section as a translucent ``CubePrimitive``, one update per step.

        Parameters
        ----------
        t : ndarray, shape (K,)
            Controller step times [s], strictly increasing.
        center_m : ndarray, shape (K, 3)
            Nominal positions ``z`` [m].
        extent_m : ndarray, shape (K, 3, 2)
            Z's position extent per axis ``[−min, max]`` [m] in use at each step.
        topic : str
            Topic name.
        """
        times, ns = _times_ns(topic, t)
        k = times.shape[0]
        centre = _finite_array(f"{topic}: tube centre", center_m, (k, 3))
        ext = np.asarray(extent_m, dtype=float).reshape(k, 3, 2)
        if k == 0:
            return
        lower, upper = centre - ext[:, :, 0], centre + ext[:, :, 1]
        corners = np.stack([np.where(np.array(bits, dtype=bool), upper, lower)
                            for bits in np.ndindex(2, 2, 2)], axis=1)  # (K, 8, 3), corner index = 4 bx + 2 by + bz
        pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]  # the 12 edges
        segs = corners[:, [p for pair in pairs for p in pair], :].reshape(-1, 3).tolist()
        section_lines = LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose((0.0, 0.0, 0.0), _IDENTITY),
                                      thickness=1.0, scale_invariant=True, color=_color(_TUBE_COLOR),
                                      points=[Point3(x=x, y=y, z=z) for x, y, z in segs])
        meta = [KeyValuePair(key="kind", value="tube cross-sections (z + Z's position extent per step)"),
                KeyValuePair(key="steps", value=str(k))]
        stamp = _timestamp(ns[0])
        sections = SceneEntity(timestamp=stamp, frame_id=self.frame, id="tube/sections", metadata=meta,
                               lines=[section_lines])
        channel = self._typed_channel(topic, SceneUpdateChannel, "foxglove.SceneUpdate")
        emit, frame = self._typed_emitter(channel), self.frame
        centres, sizes = (0.5 * (lower + upper)).tolist(), (upper - lower).tolist()
        now_meta = [KeyValuePair(key="kind", value="tube cross-section at this step")]

        def messages() -> Iterator[_Pending]:
            yield ns[0], emit, SceneUpdate(entities=[sections])
            for i, log_time in enumerate(ns):
                cube = CubePrimitive(pose=_pose(centres[i], _IDENTITY), size=_vec3(sizes[i]),
                                     color=_color(_TUBE_NOW_COLOR))
                yield log_time, emit, SceneUpdate(entities=[SceneEntity(
                    timestamp=_timestamp(log_time), frame_id=frame, id="tube/now", metadata=now_meta, cubes=[cube])])

        self._emit(messages())
