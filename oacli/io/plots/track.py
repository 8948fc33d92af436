"""The ``track`` stage's PNG plots.

* ``tracking_error.png`` -- position error ‖r − r_ref‖ [m] and attitude error [deg] over time, computed exactly as
  ``summary.json``'s ``rms_/max_position_error_m`` (:func:`oacli.metrics.tracking_errors` at the plant samples), with
  the control instants (true state at exactly those times, :func:`oacli.metrics.true_states_at`) as dots;
* ``inputs.png`` -- the applied force and torque per axis against the robot's limits;
* ``views.png`` -- top, side and front views of the reference and the flown path, zoomed on the flown region, with
  the keep-in boxes and the keep-out zones projected into each (grown by the robot radius, dashed), and a view that
  shows the clearance where the axis views cannot (:mod:`oacli.io.plots.track_views`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oacli.geometry import Scene
from oacli.io.plots.common import (
    RunFiles,
    decimate,
    guarded_plots,
    legend_outside,
    log_scale,
    plot_inputs,
    save_png,
    spans_decades,
    subplots,
)
from oacli.io.plots.track_views import plot_views
from oacli.metrics import tracking_errors
from oacli.model.limits import MotionLimits
from oacli.types import Telemetry, Trajectory


@dataclass(frozen=True)
class ErrorSeries:
    """The series drawn in ``tracking_error.png``.

    Attributes
    ----------
    t_s, position_m, attitude_rad : ndarray, shape (M,)
        At the plant samples (the summary's series).
    t_ctrl_s, position_ctrl_m : ndarray, shape (K,)
        At the control instants.
    """

    t_s: np.ndarray
    position_m: np.ndarray
    attitude_rad: np.ndarray
    t_ctrl_s: np.ndarray
    position_ctrl_m: np.ndarray


def plot_tracking_error(path: Path, telemetry: Telemetry, reference: Trajectory) -> ErrorSeries:
    """Draw ``tracking_error.png`` (module docstring) and return the series drawn.

    Parameters
    ----------
    path : Path
        Output PNG.
    telemetry : Telemetry
        The simulated run.
    reference : Trajectory
        The reference followed.

    Returns
    -------
    ErrorSeries
    """
    dense = tracking_errors(telemetry, reference)
    ctrl = tracking_errors(telemetry, reference, telemetry.t_ctrl)
    series = ErrorSeries(dense.t, dense.position_m, dense.attitude_rad, ctrl.t, ctrl.position_m)
    rms = float(np.sqrt(np.mean(dense.position_m**2)))
    fig, (ax, ax_att) = subplots(2, 1, figsize=(11, 6.5), sharex=True)
    ax.plot(*decimate(dense.t, dense.position_m), color="tab:blue", lw=1.2,
            label=f"plant samples (RMS {1e3 * rms:.3g} mm, max {1e3 * dense.position_m.max():.3g} mm)")
    ax.plot(*decimate(ctrl.t, ctrl.position_m), ".", color="tab:orange", ms=3, label="control instants")
    log = spans_decades(dense.position_m, 3.0)  # both panels on the same kind of axis
    ax.set_ylabel("position error [m]" + (", log" if log else ""))
    if log:
        log_scale(ax)
    ax.set_title("‖r − r_ref‖, true state against the reference at equal times", loc="left", fontsize="medium")
    ax_att.plot(*decimate(dense.t, np.degrees(dense.attitude_rad)), color="tab:purple", lw=1.2, label="attitude error")
    att = np.degrees(dense.attitude_rad)
    log_att = log and bool(np.any(np.isfinite(att) & (att > 0)))  # a log axis needs a positive value to show
    ax_att.set_ylabel("attitude error [deg]" + (", log" if log_att else ""))
    if log_att:
        log_scale(ax_att)
    ax_att.set_xlabel("time [s]")
    for a in (ax, ax_att):
        a.grid(True, alpha=0.3, which="both")
        legend_outside(a)
    save_png(fig, path)
    return series


def track_figures(*, telemetry: Telemetry, reference: Trajectory, limits: MotionLimits, scene: Scene | None,
                  robot_radius_m: float) -> dict[str, Callable[[Path], object]]:
    """The ``track`` stage's figures, name -> function drawing it to a path (shared by the stage and by
    ``oacli plots``, :mod:`oacli.stages.replot`).

    Parameters
    ----------
    telemetry : Telemetry
    reference : Trajectory
    limits : MotionLimits
        The robot's limits (inputs panel).
    scene : Scene, optional
    robot_radius_m : float

    Returns
    -------
    dict of str to callable
    """
    return {
        "tracking_error": lambda p: plot_tracking_error(p, telemetry, reference),
        "inputs": lambda p: plot_inputs(p, telemetry.t_ctrl, telemetry.u_applied, limits.force_N, limits.torque_Nm,
                                        "Applied inputs against the robot's limits"),
        "views": lambda p: plot_views(p, scene, robot_radius_m, reference, telemetry),
    }


def write_track_plots(run: RunFiles, summary: dict[str, Any], *, telemetry: Telemetry, reference: Trajectory,
                      limits: MotionLimits, scene: Scene | None, robot_radius_m: float) -> None:
    """Write the ``track`` stage's PNGs into its run folder and register them (failures: a summary warning).

    Parameters
    ----------
    run : RunFolder
        The open run folder.
    summary : dict
        The stage's summary.
    telemetry : Telemetry
    reference : Trajectory
    limits : MotionLimits
        The robot's limits (inputs panel).
    scene : Scene, optional
    robot_radius_m : float
    """
    guarded_plots(run, summary, track_figures(telemetry=telemetry, reference=reference, limits=limits, scene=scene,
                                              robot_radius_m=robot_radius_m))
