"""Default Rerun viewer layouts (blueprints) of the stage recordings.

A blueprint only names entity paths; it holds no data. The entity paths of the ``track`` recording are the
constants below (a fixed contract: tests and other stages read them).
"""

from __future__ import annotations

import rerun as rr
import rerun.blueprint as rrb

#: Timeline every oacli recording uses: simulated mission time since the start of the stage [s].
TIMELINE = "mission_time"

# Entity paths of the track recording.
WORLD = "world"
KEEP_IN = "world/keep_in"
KEEP_OUT = "world/keep_out"
REFERENCE = "world/reference"
ACTUAL = "world/actual"
ROBOT = "world/robot"
POSITION_ERROR = "metrics/position_error_m"
ATTITUDE_ERROR = "metrics/attitude_error_rad"
FORCE = "metrics/force_N"
TORQUE = "metrics/torque_Nm"
SOLVE_TIME = "metrics/solve_time_ms"
LOG = "log"

#: Child entities that :meth:`oacli.io.rerun_io.StageRecording.log_series` adds for ± limits.
LIMIT_UPPER = "limit_upper"
LIMIT_LOWER = "limit_lower"

_AXES_NOTE = ": x red, y green, z blue; thin = ± limit, faded = commanded"


def time_series_view(origin: str, name: str, *, legend: bool = True) -> rrb.TimeSeriesView:
    """A time series view of ``origin`` and its children whose time axis spans the whole run.

    Parameters
    ----------
    origin : str
        Entity path; every ``Scalars`` series at or below it is plotted.
    name : str
        Panel title (give the unit, e.g. ``"Position error [m]"``).
    legend : bool
        Show the legend (hide it when the many series would not fit and the title explains the colours).

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
        plot_legend=None if legend else rrb.PlotLegend(visible=False),
    )


def track_blueprint() -> rrb.Blueprint:
    """Default layout of the ``track`` recording.

    Left: a 3D view of ``world/`` (keep-in box, keep-out ellipsoids, reference and actual path, the robot body
    moving along ``mission_time``) above the text log. Right: stacked time series of position error [m],
    attitude error [rad], force [N] and torque [N·m] per axis against their ± limits (and the commanded value),
    and the solver time [ms].

    Returns
    -------
    rerun.blueprint.Blueprint
        The blueprint; pass it to :meth:`oacli.io.rerun_io.StageRecording.save`.
    """
    world = rrb.Spatial3DView(origin=WORLD, name="World (ISS frame)")
    log = rrb.TextLogView(origin=LOG, name="Log")
    plots = rrb.Vertical(
        time_series_view(POSITION_ERROR, "Position error [m]"),
        time_series_view(ATTITUDE_ERROR, "Attitude error [rad]"),
        time_series_view(FORCE, f"Force [N], world frame{_AXES_NOTE}", legend=False),
        time_series_view(TORQUE, f"Torque [N·m], body frame{_AXES_NOTE}", legend=False),
        time_series_view(SOLVE_TIME, "Solve time [ms]"),
        name="Metrics",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, log, row_shares=[3.0, 1.0], name="Scene"),
            plots,
            column_shares=[1.2, 1.0],
        ),
        rrb.TimePanel(timeline=TIMELINE),
    )
