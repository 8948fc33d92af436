"""The 3-D layers of a recording (scene, paths, segments, points, moving bodies): :class:`SpatialLogging`, the part of
:class:`oacli.io.rerun.writer.StageRecording` that draws in the world frame [m]."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from oacli.geometry import Scene
from oacli.io.rerun.common import (
    ACTUAL_COLOR,
    ASTROBEE_SIZE_M,
    KEEP_IN,
    KEEP_IN_COLOR,
    KEEP_OUT,
    KEEP_OUT_COLOR,
    REFERENCE_COLOR,
    ROBOT_COLOR,
    WORLD,
    _points,
    _rgba,
    _times,
)


class SpatialLogging:
    """3-D logging methods of :class:`~oacli.io.rerun.writer.StageRecording` (which provides ``_log`` and
    ``_send``); positions are in the world frame [m]."""

    def _log(self, entity: str, archetype, *, static: bool, t: float | None) -> None:  # pragma: no cover
        raise NotImplementedError

    def _send(self, entity: str, t_s: np.ndarray, columns) -> None:  # pragma: no cover
        raise NotImplementedError

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
