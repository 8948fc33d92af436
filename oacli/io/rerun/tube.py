"""Rerun layers and layout of a ``track`` run with the robust tube MPC (``controller: tube``).

Entities (added to the track recording of :func:`oacli.io.rerun.track.write_track_recording`):

* ``world/nominal`` — the nominal path (static polyline of the tube centres ``z``), and
  ``world/nominal/centre`` the nominal position moving over ``mission_time``;
* ``world/tube`` — the tube ``z ⊕ Z`` along the nominal path: one box per control step, centred on the nominal
  position, spanning the projection of Z on position (exact: Z is a product over the world axes);
* ``metrics/tube/force_nominal_N`` and ``metrics/tube/force_ancillary_N`` — nominal ``v`` and ancillary
  ``K (x̃ − z)`` force per axis ([ReSWARM2023] Fig. 24), each with ± the tightened bound ``Ū`` (nominal) or
  ``max |K Z|`` (ancillary) as limits;
* ``metrics/tube/nominal_velocity_mps`` — nominal velocity against the tightened velocity bound ``X̄``;
* ``metrics/tube/tube_margin`` — ``min_i (h_i − H_i (x̃ − ẑ))`` (≥ 0: inside the promised tube);
* ``metrics/tube/disturbance_position_m`` and ``metrics/tube/disturbance_velocity_mps`` — the realised one-step
  disturbance ``w`` per axis (:mod:`oacli.control.tube_monitor`) against ± W's half-widths in use at each step
  (children ``limit_upper`` / ``limit_lower``, changing when the tube is redesigned), and
  ``metrics/tube/w_violation`` (1 where w left W).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.io.rerun.layout import collapsed_side_panels, world_title, world_view
from oacli.io.rerun.track import ATTITUDE_ERROR, FORCE, POSITION_ERROR, SOLVE_TIME, TORQUE
from oacli.io.rerun.writer import AXIS_NAMES, LOG, TIMELINE, WORLD, StageRecording, time_series_view

if TYPE_CHECKING:
    from oacli.control.tube_design import TubeDesign
    from oacli.control.tube_monitor import DisturbanceRecord
    from oacli.control.tube_mpc import TubeHistory

NOMINAL = "world/nominal"
TUBE = "world/tube"
TUBE_METRICS = "metrics/tube"
FORCE_NOMINAL = "metrics/tube/force_nominal_N"
FORCE_ANCILLARY = "metrics/tube/force_ancillary_N"
NOMINAL_VELOCITY = "metrics/tube/nominal_velocity_mps"
TUBE_MARGIN = "metrics/tube/tube_margin"
DISTURBANCE_POSITION = "metrics/tube/disturbance_position_m"
DISTURBANCE_VELOCITY = "metrics/tube/disturbance_velocity_mps"
W_VIOLATION = "metrics/tube/w_violation"

NOMINAL_COLOR = (60, 200, 200, 255)
TUBE_COLOR = (60, 200, 200, 70)


def log_tube_layers(
    rec: StageRecording, history: TubeHistory, designs: Sequence[TubeDesign], design_index: np.ndarray
) -> None:
    """Log the tube layers (see the module docstring).

    Parameters
    ----------
    rec : StageRecording
        The track recording.
    history : oacli.control.tube_mpc.TubeHistory
        What the tube controller did at each step: nominal state ``[r (world) m, v m/s]``, nominal and ancillary
        force [N] and the tube margin (NaN where undefined).
    designs : sequence of oacli.control.tube_design.TubeDesign
        The designs in use during the run (0: the initial one; the ± limits are the initial design's).
    design_index : ndarray of int, shape (K,)
        Which design drove each step (the tube's extent changes after a redesign).
    """
    first = designs[0]
    z = np.asarray(history.nominal_state, dtype=float)
    t_ctrl = history.t
    ext = np.array([d.position_extent() for d in designs])[design_index]  # (K, 3, 2): [−min, max] per axis [m]
    rec.log_path(NOMINAL, z[:, 0:3], color=NOMINAL_COLOR)
    rec.log_positions_over_time(f"{NOMINAL}/centre", t_ctrl, z[:, 0:3], color=NOMINAL_COLOR, radius_m=0.01)
    lower, upper = z[:, 0:3] - ext[:, :, 0], z[:, 0:3] + ext[:, :, 1]
    rec.stream.log(
        TUBE,
        rr.Boxes3D(
            centers=0.5 * (lower + upper),
            half_sizes=0.5 * (upper - lower),
            colors=[TUBE_COLOR],
            fill_mode=rr.components.FillMode.MajorWireframe,
        ),
        static=True,
        strict=True,
    )
    rec.log_series(FORCE_NOMINAL, t_ctrl, history.nominal_force, AXIS_NAMES,
                   limits=np.array([ax.force_bounds_N[1] for ax in first.axes]))
    rec.log_series(FORCE_ANCILLARY, t_ctrl, history.ancillary_force, AXIS_NAMES,
                   limits=np.array([ax.ancillary_force_N for ax in first.axes]))
    rec.log_series(NOMINAL_VELOCITY, t_ctrl, z[:, 3:6], AXIS_NAMES,
                   limits=np.array([ax.velocity_bounds_mps[1] for ax in first.axes]))
    rec.log_series(TUBE_MARGIN, t_ctrl, history.tube_margin, ["tube margin"])


def log_disturbance_layers(rec: StageRecording, record: DisturbanceRecord) -> None:
    """Log the realised disturbance against W (see the module docstring).

    Parameters
    ----------
    rec : StageRecording
        The track recording.
    record : oacli.control.tube_monitor.DisturbanceRecord
        Per controller step: the measured one-step disturbance per axis ``[position m, velocity m/s]`` (NaN where
        not measured), W's half-widths in use, and whether w left W.
    """
    t_ctrl, w, w_half_widths = record.t, record.w, record.w_half_widths
    for entity, j in ((DISTURBANCE_POSITION, 0), (DISTURBANCE_VELOCITY, 1)):
        rec.log_series(entity, t_ctrl, w[:, :, j], AXIS_NAMES)
        rec.log_series(f"{entity}/limit_upper", t_ctrl, w_half_widths[:, :, j], AXIS_NAMES, width=0.75)
        rec.log_series(f"{entity}/limit_lower", t_ctrl, -w_half_widths[:, :, j], AXIS_NAMES, width=0.75)
    rec.log_series(W_VIOLATION, t_ctrl, np.asarray(record.violated, dtype=float), ["w outside W"])


def tube_track_blueprint(*, frame: str = "world", focus: np.ndarray | None = None) -> rrb.Blueprint:
    """Layout: the track layout's scene and log, its metrics, and a column of tube metrics.

    Parameters
    ----------
    frame : str
        Name of the world frame (the 3-D view's title).
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view frames (reference and flown path).

    Returns
    -------
    rerun.blueprint.Blueprint
        Pass it to :func:`oacli.io.rerun.track.write_track_recording` as ``blueprint``.
    """
    world = world_view(WORLD, world_title(frame, "reference, flown path, nominal tube"), focus)
    log = rrb.TextLogView(origin=LOG, name="Log")
    # View names use glyphs of the viewer's font only (it panics on e.g. U+2295 ⊕ or combining macrons).
    note = " x/y/z"
    metrics = rrb.Vertical(
        time_series_view(POSITION_ERROR, "Position error [m]"),
        time_series_view(ATTITUDE_ERROR, "Attitude error [rad]"),
        time_series_view(FORCE, "Force applied [N]" + note + ", ± limits", legend=False),
        time_series_view(TORQUE, "Torque applied [N·m]" + note + ", ± limits", legend=False),
        time_series_view(SOLVE_TIME, "Solve time [ms]"),
        name="Metrics",
    )
    tube = rrb.Vertical(
        time_series_view(FORCE_NOMINAL, "Nominal force v [N]" + note + ", tightened U", legend=False),
        time_series_view(FORCE_ANCILLARY, "Ancillary K(x - z) [N]" + note + ", max over Z", legend=False),
        time_series_view(NOMINAL_VELOCITY, "Nominal velocity [m/s]" + note + ", tightened X", legend=False),
        time_series_view(TUBE_MARGIN, "Tube margin (>= 0: inside z + Z)"),
        time_series_view(DISTURBANCE_POSITION, "Disturbance w, position [m]" + note + ", W", legend=False),
        time_series_view(DISTURBANCE_VELOCITY, "Disturbance w, velocity [m/s]" + note + ", W",
                         legend=False),
        time_series_view(W_VIOLATION, "w outside W (1 = yes)"),
        name="Tube",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, log, row_shares=[3.0, 1.0], name="Scene"),
            metrics,
            tube,
            column_shares=[1.2, 1.0, 1.0],
        ),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
        *collapsed_side_panels(),
    )
