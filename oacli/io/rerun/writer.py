"""The Rerun recording writer: :class:`StageRecording`, the entity names every stage shares, and view helpers.

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
from typing import Protocol

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation

from oacli.geometry import Scene
from oacli.io.atomic import atomic_path

#: Timeline every oacli recording uses: simulated mission time since the start of the stage [s].
TIMELINE = "mission_time"

# Entity paths shared by the stage recordings (a fixed contract: tests and other stages read them).
WORLD = "world"
KEEP_IN = "world/keep_in"
KEEP_OUT = "world/keep_out"
ROBOT = "world/robot"
LOG = "log"

#: Child entities that :meth:`StageRecording.log_series` adds for ± limits.
LIMIT_UPPER = "limit_upper"
LIMIT_LOWER = "limit_lower"

def application_id(stage: str) -> str:
    """The Rerun application id of a stage's recording, ``oacli-<stage>`` (``oacli-plan``, ``oacli-track`` ...).

    The viewer keeps one blueprint per application id: distinct ids let several stages' recordings be open at
    once, each in its own layout.

    Parameters
    ----------
    stage : str
        Stage name.

    Returns
    -------
    str
    """
    return f"oacli-{stage}"


LogEntry = tuple[float, str, str]
"""A text log line: ``(t [s], level, message)``."""


class AxisLimits(Protocol):
    """Per-axis bounds a recording plots as ± limits (:class:`oacli.reference_limits.LimitSet`,
    :class:`oacli.model.limits.MotionLimits`)."""

    @property
    def force_N(self) -> np.ndarray:
        """Force bound per world axis [N], shape (3,)."""
        ...

    @property
    def torque_Nm(self) -> np.ndarray:
        """Torque bound per body axis [N·m], shape (3,)."""
        ...

    @property
    def velocity_mps(self) -> np.ndarray:
        """Velocity bound per world axis [m/s], shape (3,)."""
        ...

    @property
    def angular_velocity_radps(self) -> np.ndarray:
        """Angular-rate bound per body axis [rad/s], shape (3,)."""
        ...


#: Astrobee is a 30 cm cube.
ASTROBEE_SIZE_M = 0.30

# RGBA colours (0-255).
KEEP_IN_COLOR = (80, 200, 120, 60)
KEEP_OUT_COLOR = (230, 60, 60, 110)
REFERENCE_COLOR = (90, 150, 255, 255)
ACTUAL_COLOR = (255, 170, 40, 255)
ROBOT_COLOR = (240, 220, 90, 140)
#: Per-axis series colours (x red, y green, z blue).
AXIS_COLORS = ((230, 60, 60, 255), (60, 180, 75, 255), (60, 110, 230, 255))
AXIS_NAMES = ("x", "y", "z")

_TEXT_LEVELS = {"WARNING": "WARN", "FATAL": "CRITICAL", "ERR": "ERROR"}


# ----------------------------------------------------------------------------------------------------------------
# Small helpers
# ----------------------------------------------------------------------------------------------------------------


def time_column(t_s: np.ndarray) -> rr.TimeColumn:
    """The ``mission_time`` column of ``send_columns`` from times [s], rounded to the nearest nanosecond.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Mission times [s] (Rerun would truncate floats).

    Returns
    -------
    rerun.TimeColumn
    """
    ns = np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    return rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))


def _times(name: str, t: np.ndarray) -> np.ndarray:
    """Check a 1-D array of finite times [s] and return it as float64."""
    arr = np.asarray(t, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array of times, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: times must be finite")
    return arr


def _points(name: str, p: np.ndarray) -> np.ndarray:
    """Check an (N, 3) array of finite positions [m]."""
    arr = np.asarray(p, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: positions must be finite")
    return arr


def _rgba(color: Sequence[int] | np.ndarray) -> np.ndarray:
    """An RGB or RGBA colour (0-255) as a uint8 RGBA array of shape (4,)."""
    c = np.asarray(color, dtype=np.uint8).reshape(-1)
    if c.shape == (3,):
        c = np.append(c, np.uint8(255))
    if c.shape != (4,):
        raise ValueError(f"a colour needs 3 or 4 channels, got {c.shape}")
    return c


def _level(level: str) -> str:
    up = str(level).strip().upper()
    return _TEXT_LEVELS.get(up, up)


# ----------------------------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------------------------


class StageRecording:
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
        return self._rec.get_recording_id()

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

    def log_scene(
        self,
        scene: Scene,
        *,
        keep_in_color: Sequence[int] = KEEP_IN_COLOR,
        keep_out_color: Sequence[int] = KEEP_OUT_COLOR,
        view_coordinates: rr.components.ViewCoordinates | None = rr.ViewCoordinates.RIGHT_HAND_Z_DOWN,
    ) -> None:
        """Log the workspace statically: keep-in boxes under ``world/keep_in``, keep-out zones under ``world/keep_out``.

        Parameters
        ----------
        scene : oacli.geometry.Scene
            Keep-in boxes [m] and keep-out ellipsoids.
        keep_in_color, keep_out_color : sequence of int
            RGBA (0-255); both are drawn as a translucent fill with a wireframe.
        view_coordinates : rerun.components.ViewCoordinates or None
            Axis convention logged on ``world``. The default, right-handed with +z down, is the ISS analysis
            frame Astrobee uses (+x forward, +y starboard, +z deck). ``None`` logs none.

        Notes
        -----
        Both entities are logged even when empty, so a reader always finds them. Ellipsoids are drawn with
        ``half_sizes`` = semi-axes [m] and the rotation of :meth:`oacli.geometry.Ellipsoid.principal_axes`
        (a quaternion, x, y, z, w).
        """
        if view_coordinates is not None:
            self._log(WORLD, view_coordinates, static=True, t=None)
        boxes = scene.keep_in
        self._log(
            KEEP_IN,
            rr.Boxes3D(
                centers=np.array([b.center for b in boxes], dtype=float).reshape(-1, 3),
                half_sizes=np.array([0.5 * b.size for b in boxes], dtype=float).reshape(-1, 3),
                colors=np.tile(_rgba(keep_in_color), (len(boxes), 1)),
                fill_mode=rr.components.FillMode.TransparentFillMajorWireframe,
                labels=[f"keep-in {i}" for i in range(len(boxes))],
                show_labels=False,
            ),
            static=True,
            t=None,
        )
        axes = [e.principal_axes() for e in scene.keep_out]
        self._log(
            KEEP_OUT,
            rr.Ellipsoids3D(
                centers=np.array([e.center for e in scene.keep_out], dtype=float).reshape(-1, 3),
                half_sizes=np.array([a for a, _ in axes], dtype=float).reshape(-1, 3),
                quaternions=np.array([Rotation.from_matrix(r).as_quat() for _, r in axes]).reshape(-1, 4),
                colors=np.tile(_rgba(keep_out_color), (len(axes), 1)),
                fill_mode=rr.components.FillMode.TransparentFillMajorWireframe,
                labels=[f"keep-out {i}" for i in range(len(axes))],
                show_labels=False,
            ),
            static=True,
            t=None,
        )

    def log_path(
        self,
        entity: str,
        positions: np.ndarray,
        *,
        color: Sequence[int] = REFERENCE_COLOR,
        radius_m: float = 0.006,
        static: bool = True,
        t: float | None = None,
    ) -> None:
        """Log a polyline through ``positions`` as ``LineStrips3D`` (e.g. ``world/reference``, ``world/plan/path``).

        Parameters
        ----------
        entity : str
            Entity path.
        positions : ndarray, shape (N, 3)
            Vertices [m] in the world frame.
        color : sequence of int
            RGB(A) 0-255.
        radius_m : float
            Line radius [m] (drawn in scene units).
        static : bool
            Log for all times (default); otherwise at mission time ``t``.
        t : float, optional
            Mission time [s] of a non-static path (e.g. the plan an MPC made at ``t``).
        """
        p = _points(entity, positions)
        self._log(entity, rr.LineStrips3D([p], colors=[_rgba(color)], radii=[float(radius_m)]), static=static, t=t)

    def log_segments(
        self,
        entity: str,
        starts: np.ndarray,
        ends: np.ndarray,
        *,
        color: Sequence[int] = (160, 160, 160, 160),
        radius_m: float = 0.002,
        static: bool = True,
        t: float | None = None,
    ) -> None:
        """Log many straight segments ``starts[i] -> ends[i]`` as one ``LineStrips3D`` (e.g. a planner's tree).

        Parameters
        ----------
        entity : str
            Entity path, e.g. ``world/plan/tree``.
        starts, ends : ndarray, shape (M, 3)
            Segment end points [m].
        color : sequence of int
            RGB(A) 0-255, shared by all segments.
        radius_m : float
            Line radius [m].
        static : bool
            Log for all times (default); otherwise at mission time ``t`` [s].
        t : float, optional
            Mission time [s] for a non-static log.
        """
        a = _points(f"{entity} starts", starts)
        b = _points(f"{entity} ends", ends)
        if a.shape != b.shape:
            raise ValueError(f"{entity}: starts {a.shape} and ends {b.shape} differ")
        strips = np.stack([a, b], axis=1)
        self._log(
            entity,
            rr.LineStrips3D(strips, colors=[_rgba(color)], radii=[float(radius_m)]),
            static=static,
            t=t,
        )

    def log_points(
        self,
        entity: str,
        positions: np.ndarray,
        *,
        color: Sequence[int] = (200, 200, 200, 255),
        radius_m: float = 0.02,
        labels: Sequence[str] | None = None,
        static: bool = True,
        t: float | None = None,
    ) -> None:
        """Log a set of points (``Points3D``), e.g. waypoints or rejected samples.

        Parameters
        ----------
        entity : str
            Entity path.
        positions : ndarray, shape (N, 3)
            Points [m].
        color : sequence of int
            RGB(A) 0-255.
        radius_m : float
            Point radius [m].
        labels : sequence of str, optional
            One label per point.
        static : bool
            Log for all times (default); otherwise at mission time ``t`` [s].
        t : float, optional
            Mission time [s] for a non-static log.
        """
        p = _points(entity, positions)
        self._log(
            entity,
            rr.Points3D(p, colors=[_rgba(color)], radii=[float(radius_m)], labels=labels),
            static=static,
            t=t,
        )

    def log_positions_over_time(
        self,
        entity: str,
        t: np.ndarray,
        positions: np.ndarray,
        *,
        color: Sequence[int] = REFERENCE_COLOR,
        radius_m: float = 0.03,
    ) -> None:
        """Log one moving point: ``positions[i]`` at mission time ``t[i]`` (one ``send_columns`` call).

        Parameters
        ----------
        entity : str
            Entity path, e.g. ``world/reference/target``.
        t : ndarray, shape (N,)
            Mission times [s].
        positions : ndarray, shape (N, 3)
            Positions [m].
        color : sequence of int
            RGB(A) 0-255 (static).
        radius_m : float
            Point radius [m] (static).
        """
        tt = _times(f"{entity} t", t)
        p = _points(entity, positions)
        if p.shape[0] != tt.shape[0]:
            raise ValueError(f"{entity}: {tt.shape[0]} times but {p.shape[0]} positions")
        self._log(entity, rr.Points3D.from_fields(colors=[_rgba(color)], radii=[float(radius_m)]), static=True, t=None)
        self._send(entity, tt, rr.Points3D.columns(positions=p))

    def log_trajectory_over_time(
        self,
        entity: str,
        t: np.ndarray,
        x: np.ndarray,
        *,
        body_size_m: float = ASTROBEE_SIZE_M,
        body_color: Sequence[int] = ROBOT_COLOR,
        axes_length_m: float = 0.25,
        path_entity: str | None = None,
        path_color: Sequence[int] = ACTUAL_COLOR,
    ) -> None:
        """Log a rigid body's pose over time and, optionally, the path it flew.

        ``entity`` gets a ``Transform3D`` (translation ``x[:, 0:3]``, quaternion ``x[:, 6:10]``) per time stamp via
        one ``send_columns`` call, plus a static ``Boxes3D`` body (a cube of edge ``body_size_m``) and body axes,
        both drawn in the body frame so they move with the transform.

        Parameters
        ----------
        entity : str
            Entity path of the body, e.g. ``world/robot``.
        t : ndarray, shape (N,)
            Mission times [s].
        x : ndarray, shape (N, 13)
            States ``[r (3) m, v (3) m/s, q (4) x, y, z, w, omega (3) rad/s]`` (see :mod:`oacli.types`).
        body_size_m : float
            Edge length of the drawn cube [m] (Astrobee: 0.30 m).
        body_color : sequence of int
            RGBA 0-255 of the body.
        axes_length_m : float
            Length of the drawn body axes [m]; 0 draws none.
        path_entity : str, optional
            When given, the positions are also logged there as a static polyline (e.g. ``world/actual``).
        path_color : sequence of int
            RGB(A) 0-255 of that polyline.
        """
        tt = _times(f"{entity} t", t)
        xx = np.asarray(x, dtype=float)
        if xx.shape != (tt.shape[0], 13):
            raise ValueError(f"{entity}: expected x of shape ({tt.shape[0]}, 13), got {xx.shape}")
        if not np.all(np.isfinite(xx[:, :10])):
            raise ValueError(f"{entity}: positions and quaternions must be finite")
        q = xx[:, 6:10]
        norm = np.linalg.norm(q, axis=1)
        if np.any(norm < 1e-9):
            raise ValueError(f"{entity}: zero quaternion in x[:, 6:10]")
        self._send(
            entity,
            tt,
            rr.Transform3D.columns(translation=xx[:, 0:3], quaternion=q / norm[:, None]),
        )
        half = 0.5 * float(body_size_m)
        self._log(
            entity,
            rr.Boxes3D(
                half_sizes=[[half, half, half]],
                colors=[_rgba(body_color)],
                fill_mode=rr.components.FillMode.TransparentFillMajorWireframe,
            ),
            static=True,
            t=None,
        )
        if axes_length_m > 0:
            self._log(entity, rr.TransformAxes3D(float(axes_length_m)), static=True, t=None)
        if path_entity is not None:
            self.log_path(path_entity, xx[:, 0:3], color=path_color)

    # -- time series ---------------------------------------------------------------------------------------------

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

    def log_bar_chart(
        self, entity: str, x: np.ndarray, values: np.ndarray, *, color: Sequence[int] = (90, 150, 255, 255)
    ) -> None:
        """Log a static bar chart (one bar per ``x``), shown on every timeline: per-iteration figures that live on
        a sequence timeline of their own, so their panel is never empty on the ``mission_time`` timeline.

        Parameters
        ----------
        entity : str
            Entity path (may also hold the same figures as ``Scalars`` on a sequence timeline).
        x : ndarray, shape (N,)
            Abscissa (iteration, try ...).
        values : ndarray, shape (N,)
            Bar heights; NaN is drawn as 0.
        color : sequence of int
            RGB(A) 0-255.
        """
        xx = np.asarray(x, dtype=float).reshape(-1)
        vv = np.nan_to_num(np.asarray(values, dtype=float).reshape(-1))
        if xx.shape != vv.shape:
            raise ValueError(f"{entity}: {xx.shape[0]} abscissae but {vv.shape[0]} values")
        self._log(entity, rr.BarChart(vv, abscissa=xx, color=_rgba(color)), static=True, t=None)

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
                rr.send_blueprint(blueprint, make_active=False, make_default=True, recording=self._rec)
            self._rec.flush()
            data = stream.read(flush=True) or b""
        finally:
            # Disconnecting finishes the stream (the footer); the recording is closed either way.
            self._rec.disconnect()
            self._saved = True
        data += stream.read(flush=True) or b""
        with atomic_path(path) as tmp:
            fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0))
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
            _check_complete(tmp, self.recording_id)


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


# ----------------------------------------------------------------------------------------------------------------
# Layout helpers (each stage's blueprint is in its own module)
# ----------------------------------------------------------------------------------------------------------------


def time_series_view(origin: str, name: str, *, legend: bool = True,
                     y_range: tuple[float, float] | None = None) -> rrb.TimeSeriesView:
    """A time series view of ``origin`` and its children whose time axis spans the whole run.

    Parameters
    ----------
    origin : str
        Entity path; every ``Scalars`` series at or below it is plotted.
    name : str
        Panel title, short (give the unit, e.g. ``"Position error [m]"``); the series names go in the legend.
    legend : bool
        Show the legend (in the top-right corner, where it covers the least of a plot that starts at rest).
    y_range : (float, float), optional
        Fixed value axis (e.g. 1.15 × the ± limits, so the axis carries ticks beyond ``0`` however flat the data).

    Returns
    -------
    rerun.blueprint.TimeSeriesView
        The view (Rerun's default would show only a window around the time cursor).
    """
    whole_run = rr.TimeRange(start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.infinite())
    return rrb.TimeSeriesView(
        origin=origin,
        name=name,
        axis_x=rrb.TimeAxis(view_range=whole_run),
        axis_y=None if y_range is None else rrb.ScalarAxis(range=(float(y_range[0]), float(y_range[1]))),
        plot_legend=rrb.PlotLegend(visible=False) if not legend else rrb.PlotLegend("RightTop", visible=True),
    )


def limit_range(limits: Sequence[float] | np.ndarray, margin: float = 1.15) -> tuple[float, float]:
    """A symmetric value range ``± margin · max(limits)`` for a plot of series against their ± limits.

    Parameters
    ----------
    limits : array_like
        The ± limits [unit of the plot].
    margin : float
        Headroom beyond the largest limit.

    Returns
    -------
    (float, float)
    """
    top = margin * float(np.max(np.abs(np.asarray(limits, dtype=float))))
    return (-top, top)
