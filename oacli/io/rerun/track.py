"""The ``track`` stage's Rerun recording and its default layout.

Entities (a fixed contract: tests and other stages read them back): ``world/keep_in``, ``world/keep_out`` (static
scene), ``world/reference`` (static path, plus a moving target point ``world/reference/target``), ``world/actual``
(static path flown), ``world/robot`` (pose over time and body), ``metrics/position_error_m``,
``metrics/attitude_error_rad``, ``metrics/force_N`` and ``metrics/torque_Nm`` (applied, series ``x, y, z``, with
``limit_upper``/``limit_lower`` children and the commanded value under ``.../command``), ``metrics/solve_time_ms``
and ``log``. The tube controller's layers are in :mod:`oacli.io.rerun.tube`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun.blueprint as rrb

from oacli.geometry import Scene
from oacli.io.rerun.layout import collapsed_side_panels, world_title, world_view
from oacli.io.rerun.writer import (
    ACTUAL_COLOR,
    AXIS_COLORS,
    AXIS_NAMES,
    LOG,
    REFERENCE_COLOR,
    ROBOT,
    TIMELINE,
    WORLD,
    AxisLimits,
    LogEntry,
    StageRecording,
    application_id,
    limit_range,
    time_series_view,
)
from oacli.types import Telemetry, Trajectory

if TYPE_CHECKING:
    from oacli.metrics import TrackingErrors

REFERENCE = "world/reference"
ACTUAL = "world/actual"
POSITION_ERROR = "metrics/position_error_m"
ATTITUDE_ERROR = "metrics/attitude_error_rad"
FORCE = "metrics/force_N"
TORQUE = "metrics/torque_Nm"
SOLVE_TIME = "metrics/solve_time_ms"

_AXES_NOTE = " x/y/z, ± limits, faded = commanded"


def track_application_id(controller: str) -> str:
    """The application id of a track recording flown with ``controller`` (``oacli-track-mpc``, ``oacli-track-tube``).

    Parameters
    ----------
    controller : str
        ``controller.type`` of the run.

    Returns
    -------
    str
    """
    return application_id(f"track-{controller}")


def track_blueprint(limits: AxisLimits | None = None, *, frame: str = "world",
                    focus: np.ndarray | None = None) -> rrb.Blueprint:
    """Default layout of the ``track`` recording.

    Left: a 3D view of ``world/`` (keep-in box, keep-out ellipsoids, reference and actual path, the robot body
    moving along ``mission_time``) above the text log. Right: stacked time series of position error [m],
    attitude error [rad], force [N] and torque [N·m] per axis against their ± limits (and the commanded value),
    and the solver time [ms].

    Parameters
    ----------
    limits : AxisLimits, optional
        Force and torque bounds: the value axes span 1.15 × them (ticks beyond ``0`` however flat the data).
    frame : str
        Name of the world frame (``environment.frame``), in the 3-D view's title.
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view's camera frames (reference and flown path), not the whole workspace.

    Returns
    -------
    rerun.blueprint.Blueprint
        The blueprint; pass it to :meth:`oacli.io.rerun.writer.StageRecording.save`.
    """
    world = world_view(WORLD, world_title(frame, "reference (blue), flown (orange)"), focus)
    log = rrb.TextLogView(origin=LOG, name="Log")
    plots = rrb.Vertical(
        time_series_view(POSITION_ERROR, "Position error [m]"),
        time_series_view(ATTITUDE_ERROR, "Attitude error [rad]"),
        time_series_view(FORCE, f"Force [N]{_AXES_NOTE}", legend=False,
                         y_range=None if limits is None else limit_range(limits.force_N)),
        time_series_view(TORQUE, f"Torque [N·m]{_AXES_NOTE}", legend=False,
                         y_range=None if limits is None else limit_range(limits.torque_Nm)),
        time_series_view(SOLVE_TIME, "Solve time [ms]"),
        name="Metrics",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, log, row_shares=[3.0, 1.0], name="Scene"),
            plots,
            column_shares=[1.2, 1.0],
        ),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
        *collapsed_side_panels(),
    )


def write_track_recording(
    path: Path,
    *,
    scene: Scene,
    reference: Trajectory,
    telemetry: Telemetry,
    errors: TrackingErrors,
    limits: AxisLimits,
    log: Sequence[LogEntry] = (),
    recording_name: str = "track",
    extra: Callable[[StageRecording], None] | None = None,
    blueprint: rrb.Blueprint | Callable[..., rrb.Blueprint] | None = None,
    controller: str = "mpc",
) -> None:
    """Write the ``track`` stage's recording (entities in the module docstring) with :func:`track_blueprint`.

    Parameters
    ----------
    path : Path
        Output ``.rrd``, written atomically.
    scene : oacli.geometry.Scene
        Keep-in boxes and keep-out ellipsoids.
    reference : Trajectory
        The reference (positions [m] drawn).
    telemetry : Telemetry
        The run: true states (position [m] and attitude drawn), commanded and applied inputs at the controller
        times, and the solver time of each step (NaN where unknown, or when ``solve_info`` is empty).
    errors : oacli.metrics.TrackingErrors
        Position [m] and attitude [rad] errors at the controller times ``telemetry.t_ctrl``.
    limits : AxisLimits
        Force [N] and torque [N·m] bounds per axis (plotted as ±).
    log : sequence of (float, str, str)
        ``(t [s], level, message)`` lines for the text log.
    recording_name : str
        Recording name shown in the viewer.
    extra : callable, optional
        Called with the :class:`~oacli.io.rerun.writer.StageRecording` before it is saved, to log
        controller-specific layers.
    blueprint : rerun.blueprint.Blueprint or callable, optional
        Layout to store instead of :func:`track_blueprint`, or a function that makes it, called with the keywords
        ``frame`` (the world frame's name) and ``focus`` (the reference and flown positions [m] the 3-D view
        frames), e.g. :func:`oacli.io.rerun.tube.tube_track_blueprint`.
    controller : str
        The controller kind (``controller.type``: ``"mpc"`` or ``"tube"``): the application id is
        ``oacli-track-<controller>`` (:func:`track_application_id`), so a standard-MPC and a tube-MPC flight open
        side by side in one viewer, each in its own layout (the viewer keeps one blueprint per application id).

    Raises
    ------
    ValueError
        Errors or limits of the wrong shape, or a state the recording cannot draw (nothing is written).
    """
    tel = telemetry
    t_ctrl = tel.t_ctrl
    k = t_ctrl.shape[0]
    solve_time_ms = (1e3 * np.array([i.solve_time_s for i in tel.solve_info]) if tel.solve_info
                     else np.full(k, np.nan))
    for name, arr, shape in (
        ("position_error_m", errors.position_m, (k,)),
        ("attitude_error_rad", errors.attitude_rad, (k,)),
        ("force_limit_N", limits.force_N, (3,)),
        ("torque_limit_Nm", limits.torque_Nm, (3,)),
    ):
        if np.shape(arr) != shape:
            raise ValueError(f"{name}: expected shape {shape}, got {np.shape(arr)}")
    u_command, u_applied = tel.u_command, tel.u_applied

    rec = StageRecording(track_application_id(controller), recording_name)
    rec.log_scene(scene)
    rec.log_path(REFERENCE, reference.x[:, 0:3], color=REFERENCE_COLOR)
    rec.log_positions_over_time(f"{REFERENCE}/target", reference.t, reference.x[:, 0:3], color=REFERENCE_COLOR,
                                radius_m=0.03)
    rec.log_trajectory_over_time(ROBOT, tel.t_true, tel.x_true, path_entity=ACTUAL, path_color=ACTUAL_COLOR)

    rec.log_series(POSITION_ERROR, t_ctrl, errors.position_m, ["position error"])
    rec.log_series(ATTITUDE_ERROR, t_ctrl, errors.attitude_rad, ["attitude error"])
    rec.log_series(FORCE, t_ctrl, u_applied[:, 0:3], AXIS_NAMES, limits=limits.force_N)
    rec.log_series(TORQUE, t_ctrl, u_applied[:, 3:6], AXIS_NAMES, limits=limits.torque_Nm)
    faded = [(*c[:3], 110) for c in AXIS_COLORS]
    rec.log_series(f"{FORCE}/command", t_ctrl, u_command[:, 0:3], [f"{a} cmd" for a in AXIS_NAMES], colors=faded)
    rec.log_series(f"{TORQUE}/command", t_ctrl, u_command[:, 3:6], [f"{a} cmd" for a in AXIS_NAMES], colors=faded)
    rec.log_series(SOLVE_TIME, t_ctrl, solve_time_ms, ["solve time"])

    rec.log_entries(log)
    if extra is not None:
        extra(rec)
    focus = np.concatenate([reference.x[:, 0:3], tel.x_true[:, 0:3]])
    if blueprint is None:
        blueprint = track_blueprint(limits, frame=scene.frame, focus=focus)
    elif callable(blueprint):
        blueprint = blueprint(frame=scene.frame, focus=focus)
    rec.save(Path(path), blueprint)
