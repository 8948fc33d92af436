"""The ``excite`` stage's Rerun recording and its default layout.

Entities (a fixed contract: tests read them back):

* ``world/keep_in``, ``world/keep_out``: the workspace (static);
* ``world/excitation``: the path of the output trajectory (static), ``world/initial_guess``: the SCP's start;
  ``world/plans``: each RATTLE plan, logged at its replan time;
* ``world/robot``: the robot body moving along ``mission_time``;
* ``metrics/criterion``: the design criterion of the current design after each SCP iteration, and
  ``metrics/criterion/candidate`` that of each trial point, on the ``scp_iteration`` sequence timeline (the
  design's also as a static line chart ``charts/criterion``, y framed on its range, shown on ``mission_time``:
  :mod:`oacli.io.rerun.chart`);
* ``metrics/information``: cumulative Fisher information per parameter, relative (``F_ii θ_i²``, series
  ``m, Ixx, Iyy, Izz``), and ``metrics/crb_std_log10_pct``: log10 of the Cramér-Rao standard deviation in % of
  θ_i, over time (it falls by decades; Rerun's plots have no log axis);
* ``metrics/gamma``: RATTLE's information weights over time;
* ``metrics/force_N``, ``metrics/torque_Nm`` (with ± limits), ``metrics/velocity_mps``,
  ``metrics/angular_velocity_radps`` (with ± limits);
* ``log``: the text log.

Application id ``oacli-excite-offline`` (the offline design) or ``oacli-excite-rattle`` (RATTLE): the two
kinds have different layouts and open side by side in one viewer (:func:`excite_application_id`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.geometry import Scene
from oacli.io.rerun.chart import line_chart_view, log_line_chart
from oacli.io.rerun.layout import collapsed_side_panels, world_title, world_view
from oacli.io.rerun.writer import (
    ACTUAL_COLOR,
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
from oacli.types import Trajectory

EXCITATION = "world/excitation"
INITIAL_GUESS = "world/initial_guess"
PLANS = "world/plans"
CRITERION = "metrics/criterion"
CRITERION_CANDIDATE = "metrics/criterion/candidate"
CRITERION_CHART = "charts/criterion"
INFORMATION = "metrics/information"
CRB_STD_LOG10_PCT = "metrics/crb_std_log10_pct"
GAMMA = "metrics/gamma"
FORCE = "metrics/force_N"
TORQUE = "metrics/torque_Nm"
VELOCITY = "metrics/velocity_mps"
ANGULAR_VELOCITY = "metrics/angular_velocity_radps"
ITERATION_TIMELINE = "scp_iteration"
PARAMETER_SERIES = ("m", "Ixx", "Iyy", "Izz")
_PARAM_COLORS = ((230, 60, 60, 255), (60, 180, 75, 255), (60, 110, 230, 255), (200, 120, 20, 255))
_PLAN_COLOR = (150, 150, 150, 200)


@dataclass(frozen=True)
class InformationSeries:
    """The Fisher information along a trajectory, for the recording.

    Attributes
    ----------
    theta : ndarray, shape (4,)
        Parameters the information is relative to [kg, kg·m²].
    information : ndarray, shape (N, 4, 4)
        Cumulative Fisher information at each sample.
    crb_std : ndarray, shape (N, 4)
        Cramér-Rao standard deviation at each sample (``inf`` where unidentifiable: not drawn).
    """

    theta: np.ndarray
    information: np.ndarray
    crb_std: np.ndarray


@dataclass(frozen=True)
class ScpSteps:
    """What the offline design's sequential convex programming did, for the recording.

    Attributes
    ----------
    criterion, candidate_criterion : ndarray, shape (I,)
        Criterion of the design and of the trial point after each iteration (``nan`` where the subproblem failed).
    initial_positions : ndarray, shape (M, 3)
        Path of the initial guess [m].
    """

    criterion: np.ndarray
    candidate_criterion: np.ndarray
    initial_positions: np.ndarray


@dataclass(frozen=True)
class RattleSteps:
    """What RATTLE's replanning did, for the recording.

    Attributes
    ----------
    plans : sequence of (float, ndarray (K, 3))
        Each replan's time [s] and planned positions [m].
    replan_t : ndarray, shape (R,)
        Replan times [s].
    gamma : ndarray, shape (R, 4)
        Information weights at each replan.
    """

    plans: Sequence[tuple[float, np.ndarray]]
    replan_t: np.ndarray
    gamma: np.ndarray


def excite_application_id(rattle: bool) -> str:
    """The application id of an ``excite`` recording: ``oacli-excite-rattle`` or ``oacli-excite-offline``.

    Parameters
    ----------
    rattle : bool
        The excitation was replanned online by RATTLE (else designed offline).

    Returns
    -------
    str
    """
    return application_id("excite-rattle" if rattle else "excite-offline")


def excite_blueprint(limits: AxisLimits | None = None, *, scp: bool = True, rattle: bool = False,
                     frame: str = "world", focus: np.ndarray | None = None) -> rrb.Blueprint:
    """Default layout: 3D world and log on the left; information, bounds, inputs and rates over mission time on
    the right, with the criterion per SCP iteration (offline design) or RATTLE's information weights.

    Parameters
    ----------
    limits : AxisLimits, optional
        Force, torque, velocity and angular-rate bounds (fix the value axes).
    scp : bool
        Show the criterion per SCP iteration (the offline design).
    rattle : bool
        Show RATTLE's information weights.
    frame : str
        Name of the world frame (the 3-D view's title).
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view frames (the excitation path).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    world = world_view(WORLD, world_title(frame, "RATTLE plans (grey), flown (orange)" if rattle else
                                          "initial guess (blue), design (orange)"), focus)
    log = rrb.TextLogView(origin=LOG, name="Log")
    def rng(name: str):
        return None if limits is None else limit_range(getattr(limits, name))

    extra: list[rrb.View] = []
    if scp:
        extra.append(line_chart_view(CRITERION_CHART, "Design criterion per SCP iteration (x: iteration)"))
    if rattle:
        extra.append(time_series_view(GAMMA, "RATTLE information weights γ"))
    plots = rrb.Grid(
        time_series_view(INFORMATION, "Information F_ii θ_i² [-]"),
        time_series_view(CRB_STD_LOG10_PCT, "Cramér-Rao std, log10(% of θ)"),
        time_series_view(FORCE, "Force [N] x/y/z, ± limits", legend=False, y_range=rng("force_N")),
        time_series_view(TORQUE, "Torque [N·m] x/y/z, ± limits", legend=False, y_range=rng("torque_Nm")),
        time_series_view(VELOCITY, "Velocity [m/s] x/y/z", legend=False),
        time_series_view(ANGULAR_VELOCITY, "Rate [rad/s] x/y/z, ± limits", legend=False,
                         y_range=rng("angular_velocity_radps")),
        *extra,
        grid_columns=2,
        name="Metrics",
    )
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(world, log, row_shares=[3.0, 1.0], name="Scene"), plots, column_shares=[1.0, 1.3]),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
        *collapsed_side_panels(),
    )


def write_excite_recording(
    path: Path,
    *,
    scene: Scene,
    trajectory: Trajectory,
    information: InformationSeries,
    limits: AxisLimits,
    scp: ScpSteps | None = None,
    rattle: RattleSteps | None = None,
    log: Sequence[LogEntry] = (),
    recording_name: str = "excite",
) -> None:
    """Write the ``excite`` recording (entities in the module docstring) with :func:`excite_blueprint`.

    Parameters
    ----------
    path : Path
        Output ``.rrd`` (written atomically).
    scene : Scene
        Keep-in boxes and keep-out ellipsoids.
    trajectory : Trajectory
        The output trajectory (inputs [N, N·m] held from each sample).
    information : InformationSeries
        Fisher information and Cramér-Rao bound at each sample of ``trajectory``.
    limits : AxisLimits
        Force [N], torque [N·m] and angular-rate [rad/s] bounds plotted as ±.
    scp : ScpSteps, optional
        The offline design's iterations and initial guess.
    rattle : RattleSteps, optional
        RATTLE's plans and information weights.
    log : sequence of (float, str, str)
        The stage's text log.
    recording_name : str
        Recording name shown in the viewer.
    """
    t, x, u = trajectory.t, trajectory.x, trajectory.u
    theta = information.theta
    rec = StageRecording(excite_application_id(rattle is not None), recording_name)
    rec.log_scene(scene)
    rec.log_trajectory_over_time(ROBOT, t, x, path_entity=EXCITATION, path_color=ACTUAL_COLOR)
    if scp is not None:
        rec.log_path(INITIAL_GUESS, scp.initial_positions, color=REFERENCE_COLOR, radius_m=0.003)
    for t_plan, positions in rattle.plans if rattle is not None else ():
        rec.log_path(PLANS, positions, color=_PLAN_COLOR, radius_m=0.004, static=False, t=float(t_plan))

    diag = np.einsum("kii->ki", np.asarray(information.information, dtype=float)) * np.asarray(theta, dtype=float) ** 2
    rec.log_series(INFORMATION, t, diag, PARAMETER_SERIES, colors=_PARAM_COLORS)
    pct = 100.0 * np.asarray(information.crb_std, dtype=float) / np.abs(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_pct = np.log10(pct)
    log_pct = np.where(np.isfinite(log_pct), log_pct, np.nan)
    rec.log_series(CRB_STD_LOG10_PCT, t, log_pct, PARAMETER_SERIES, colors=_PARAM_COLORS)
    rec.log_series(FORCE, t, u[:, 0:3], AXIS_NAMES, limits=limits.force_N)
    rec.log_series(TORQUE, t, u[:, 3:6], AXIS_NAMES, limits=limits.torque_Nm)
    rec.log_series(VELOCITY, t, x[:, 3:6], AXIS_NAMES)
    rec.log_series(ANGULAR_VELOCITY, t, x[:, 10:13], AXIS_NAMES, limits=limits.angular_velocity_radps)
    if rattle is not None:
        rec.log_series(GAMMA, rattle.replan_t, rattle.gamma, PARAMETER_SERIES, colors=_PARAM_COLORS)

    if scp is not None and len(scp.criterion):
        iterations = np.arange(1, len(scp.criterion) + 1)
        for entity, values, name in ((CRITERION, scp.criterion, "design"),
                                     (CRITERION_CANDIDATE, scp.candidate_criterion, "candidate")):
            rec.stream.log(entity, rr.SeriesLines(names=[name]), static=True)
            rec.stream.send_columns(
                entity,
                indexes=[rr.TimeColumn(ITERATION_TIMELINE, sequence=iterations)],
                columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)),
            )
        log_line_chart(rec.stream, CRITERION_CHART, iterations, np.asarray(scp.criterion, dtype=float),
                       color=ACTUAL_COLOR, x_name="iteration", y_name="criterion")
    rec.log_entries(log)
    has_scp = scp is not None and len(scp.criterion) > 0
    rec.save(Path(path), excite_blueprint(limits, scp=has_scp, rattle=rattle is not None, frame=scene.frame,
                                          focus=x[:, 0:3]))
