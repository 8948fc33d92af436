"""The ``plan`` stage's Rerun recording and its layout (the motion layers are shared with ``smooth``).

Entities of ``plan.rrd`` (a fixed contract; tests read them back): ``world/keep_in``, ``world/keep_out`` (static
scene); ``world/plan/start``, ``world/plan/goal`` (points); ``world/plan/tree`` (the final tree, every edge as its
exact curve, static); ``world/plan/growth`` (the tree as straight parent-child segments after each snapshot, on the
``iteration`` sequence timeline, with the best path at that moment under ``world/plan/growth/path``);
``world/plan/path`` (the final trajectory's path, static); ``world/robot`` (the robot's pose on ``mission_time``);
``metrics/force_N`` and ``metrics/velocity_mps`` per axis against their ± limits (``mission_time``);
``metrics/solution_cost`` (the best solution's cost on the ``iteration`` timeline) and ``charts/solution_cost`` (the
same figures as a static line chart, x the iteration, y framed on the costs' range: :mod:`oacli.io.rerun.chart`,
so the panel shows them on ``mission_time``, the timeline the layout opens on); ``log``. Application id
``oacli-plan``. The 3-D view opens framed on the start, goal and plan (not on the whole workspace).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.geometry import Scene
from oacli.io.rerun.chart import line_chart_view, log_line_chart
from oacli.io.rerun.layout import collapsed_side_panels, world_title, world_view
from oacli.io.rerun.writer import (
    AXIS_NAMES,
    LOG,
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

if TYPE_CHECKING:
    from oacli.planning.result import PlanResult

ITERATION = "iteration"

PLAN_START = "world/plan/start"
PLAN_GOAL = "world/plan/goal"
PLAN_TREE = "world/plan/tree"
PLAN_GROWTH = "world/plan/growth"
PLAN_GROWTH_PATH = "world/plan/growth/path"
PLAN_PATH = "world/plan/path"
FORCE = "metrics/force_N"
VELOCITY = "metrics/velocity_mps"
SOLUTION_COST = "metrics/solution_cost"
SOLUTION_COST_CHART = "charts/solution_cost"

TREE_COLOR = (150, 150, 150, 110)
GROWTH_COLOR = (120, 160, 220, 140)
PATH_COLOR = (255, 170, 40, 255)
START_COLOR = (60, 200, 90, 255)
GOAL_COLOR = (230, 60, 60, 255)


def set_sequence(rec: StageRecording, timeline: str, value: int) -> None:
    """Set a sequence timeline (``iteration``, ``shortcut`` ...) for the next ``rec.stream.log`` calls.

    Parameters
    ----------
    rec : StageRecording
        The recording.
    timeline : str
        Timeline name.
    value : int
        Sequence number; call ``rec.stream.reset_time()`` after logging.
    """
    rec.stream.set_time(timeline, sequence=int(value))


def log_motion(rec: StageRecording, trajectory: Trajectory, limits: AxisLimits, *, start_on_iteration: bool) -> None:
    """Log the robot's pose, force and velocity over ``mission_time`` (``plan`` and ``smooth``).

    Parameters
    ----------
    rec : StageRecording
        The recording.
    trajectory : Trajectory
        The output trajectory.
    limits : AxisLimits
        Force [N] and velocity [m/s] bounds plotted as ±.
    start_on_iteration : bool
        Also show the robot at the start on the ``iteration`` timeline (the plan's growth).
    """
    t, x, u = trajectory.t, trajectory.x, trajectory.u
    rec.log_trajectory_over_time(ROBOT, t, x)
    if start_on_iteration:  # show the robot at the start on the iteration timeline too
        set_sequence(rec, ITERATION, 0)
        rec.stream.log(ROBOT, rr.Transform3D(translation=x[0, 0:3], quaternion=x[0, 6:10]))  # type: ignore[arg-type]
        rec.stream.reset_time()
    rec.log_series(FORCE, t, u[:, 0:3], AXIS_NAMES, limits=np.asarray(limits.force_N, dtype=float))
    rec.log_series(VELOCITY, t, x[:, 3:6], AXIS_NAMES, limits=np.asarray(limits.velocity_mps, dtype=float))


def motion_blueprint(world_name: str, extra_plots: Sequence[Any], timeline: str, *,
                     limits: AxisLimits | None = None, motion: bool = True,
                     focus: np.ndarray | None = None) -> rrb.Blueprint:
    """3D scene and log on the left; force, velocity and ``extra_plots`` on the right (plan and smooth layouts).

    Parameters
    ----------
    world_name : str
        Title of the 3D view.
    extra_plots : sequence of rerun.blueprint views
        Views below the force and velocity plots.
    timeline : str
        Timeline the time panel shows first.
    limits : AxisLimits, optional
        Force and velocity bounds: the value axes span 1.15 × them (ticks beyond ``0`` however flat the data).
    motion : bool
        Include the force and velocity plots (False when there is no trajectory to plot).
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view's camera frames (:func:`oacli.io.rerun.layout.framed_eye`).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    world = world_view(WORLD, world_name, focus)
    force_range = None if limits is None else limit_range(limits.force_N)
    velocity_range = None if limits is None else limit_range(limits.velocity_mps)
    motion_plots = (
        time_series_view(FORCE, "Force [N] x/y/z, ± limits", legend=False, y_range=force_range),
        time_series_view(VELOCITY, "Velocity [m/s] x/y/z, ± limits", legend=False, y_range=velocity_range),
    ) if motion else ()
    plots = rrb.Vertical(*motion_plots, *extra_plots, name="Metrics")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, rrb.TextLogView(origin=LOG, name="Log"), row_shares=[3.0, 1.0]),
            plots,
            column_shares=[1.4, 1.0],
        ),
        rrb.TimePanel(timeline=timeline, state="collapsed"),
        *collapsed_side_panels(),
    )


def plan_blueprint(limits: AxisLimits | None = None, *, solved: bool = True, frame: str = "world",
                   focus: np.ndarray | None = None) -> rrb.Blueprint:
    """Layout of ``plan.rrd``: 3D scene and log on the left, force, velocity and solution cost on the right.

    It opens on ``mission_time`` (the plan flown); the tree's growth is on the ``iteration`` timeline.

    Parameters
    ----------
    limits : AxisLimits, optional
        Force and velocity bounds (fixes the value axes).
    solved : bool
        A solution was found (else the force, velocity and cost panels, which would be empty, are left out).
    frame : str
        Name of the world frame (the 3-D view's title).
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view frames (start, goal, plan).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    cost = [line_chart_view(SOLUTION_COST_CHART, "Best cost at each improvement (x: iteration)")]
    return motion_blueprint(world_title(frame, "tree, plan, obstacles"), cost if solved else [], TIMELINE,
                            limits=limits, motion=solved, focus=focus)


def write_plan_recording(
    path: Path,
    *,
    scene: Scene,
    start: np.ndarray,
    goal: np.ndarray,
    result: PlanResult,
    trajectory: Trajectory | None,
    limits: AxisLimits,
    log: Sequence[LogEntry] = (),
    recording_name: str = "plan",
) -> None:
    """Write ``plan.rrd`` (entities in the module docstring) with :func:`plan_blueprint`.

    Parameters
    ----------
    path : Path
        Output file (written atomically).
    scene : Scene
        Keep-in boxes and keep-out ellipsoids.
    start, goal : ndarray, shape (3,)
        Positions [m].
    result : oacli.planning.result.PlanResult
        The planner's output: its final tree (node states and each node's incoming edge as a polyline), the tree
        snapshots (growth) and the improvements of the best solution.
    trajectory : Trajectory or None
        The plan (None when no solution was found).
    limits : AxisLimits
        Force [N] and velocity [m/s] bounds plotted as ±.
    log : sequence of (t, level, message)
        The stage's text log.
    recording_name : str
        Recording name shown in the viewer.
    """
    rec = StageRecording(application_id("plan"), recording_name)
    rec.log_scene(scene)
    rec.log_points(PLAN_START, np.asarray(start, dtype=float).reshape(1, 3), color=START_COLOR, radius_m=0.03,
                   labels=["start"])
    rec.log_points(PLAN_GOAL, np.asarray(goal, dtype=float).reshape(1, 3), color=GOAL_COLOR, radius_m=0.03,
                   labels=["goal"])
    tree = result.tree
    strips = [np.asarray(p, dtype=float) for p in tree.edges if len(p) >= 2]
    rec.stream.log(PLAN_TREE, rr.LineStrips3D(strips, colors=[TREE_COLOR], radii=[0.002]), static=True)
    pos = np.asarray(tree.states, dtype=float)[:, 0:3]
    for snapshot in result.snapshots:
        parent = np.asarray(snapshot.parent)
        best = snapshot.path
        child = np.flatnonzero(parent >= 0)
        segs = np.stack([pos[parent[child]], pos[child]], axis=1) if child.size else np.zeros((0, 2, 3))
        set_sequence(rec, ITERATION, snapshot.iteration)
        rec.stream.log(PLAN_GROWTH, rr.LineStrips3D(segs, colors=[GROWTH_COLOR], radii=[0.002]))  # type: ignore[arg-type]
        path_pts = pos[np.asarray(best, dtype=int)] if len(best) >= 2 else np.zeros((0, 3))
        rec.stream.log(PLAN_GROWTH_PATH, rr.LineStrips3D([path_pts] if len(path_pts) else [],
                                                         colors=[PATH_COLOR], radii=[0.006]))
        rec.stream.reset_time()
    if result.solutions:
        its = np.array([s.iteration for s in result.solutions], dtype=np.int64)
        costs = np.array([s.cost for s in result.solutions], dtype=float)
        rec.stream.log(SOLUTION_COST, rr.SeriesLines(names=["best cost"]), static=True)
        rec.stream.send_columns(SOLUTION_COST, indexes=[rr.TimeColumn(ITERATION, sequence=its)],
                                columns=rr.Scalars.columns(scalars=costs))
        log_line_chart(rec.stream, SOLUTION_COST_CHART, its, costs, color=PATH_COLOR, x_name="iteration",
                       y_name="cost")
    if trajectory is not None:
        rec.log_path(PLAN_PATH, trajectory.x[:, 0:3], color=PATH_COLOR, radius_m=0.008)
        log_motion(rec, trajectory, limits, start_on_iteration=True)
    rec.log_entries(log)
    focus = [np.asarray(start, dtype=float).reshape(1, 3), np.asarray(goal, dtype=float).reshape(1, 3)]
    if trajectory is not None:
        focus.append(trajectory.x[:, 0:3])
    rec.save(Path(path), plan_blueprint(limits, solved=trajectory is not None and bool(result.solutions),
                                        frame=scene.frame, focus=np.concatenate(focus)))
