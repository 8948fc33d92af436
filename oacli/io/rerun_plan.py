"""Rerun recordings of the ``plan`` and ``smooth`` stages (layouts and writers).

Entity paths (a fixed contract; tests read them back):

``plan.rrd``
    ``world/keep_in``, ``world/keep_out`` (static scene); ``world/plan/start``, ``world/plan/goal`` (points);
    ``world/plan/tree`` (the final tree, every edge as its exact curve, static); ``world/plan/growth`` (the tree
    as straight parent-child segments after each snapshot, on the ``iteration`` sequence timeline, with the best
    path at that moment under ``world/plan/growth/path``); ``world/plan/path`` (the final trajectory's path,
    static); ``world/robot`` (the robot's pose on ``mission_time``); ``metrics/force_N`` and
    ``metrics/velocity_mps`` per axis against their ± limits (``mission_time``); ``metrics/solution_cost`` (the
    best solution's cost on the ``iteration`` timeline); ``log``.
``smooth.rrd``
    the scene; ``world/smooth/before`` and ``world/smooth/after`` (paths, static; ``after`` is the output, polished
    when the polish ran); ``world/smooth/shortcut`` (the path after the shortcutting, before the polish, static;
    only when the polish ran); ``world/smooth/shortcuts`` (each accepted shortcut's section, on the ``shortcut``
    sequence timeline); ``world/smooth/polish`` (each accepted polish candidate's path, on the ``polish``
    sequence timeline); ``world/robot`` (output trajectory); ``metrics/force_N``, ``metrics/velocity_mps``
    (output, ``mission_time``); ``metrics/cost`` (trajectory cost after each try, ``shortcut`` timeline);
    ``metrics/polish_length_m`` (exact path length of each polish candidate, ``polish`` timeline); ``log``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.geometry import Scene
from oacli.io.rerun_blueprints import LOG, TIMELINE, WORLD, time_series_view
from oacli.io.rerun_io import ACTUAL_COLOR, AXIS_NAMES, REFERENCE_COLOR, ROBOT, StageRecording

ITERATION = "iteration"
SHORTCUT = "shortcut"
POLISH = "polish"

PLAN_START = "world/plan/start"
PLAN_GOAL = "world/plan/goal"
PLAN_TREE = "world/plan/tree"
PLAN_GROWTH = "world/plan/growth"
PLAN_GROWTH_PATH = "world/plan/growth/path"
PLAN_PATH = "world/plan/path"
SMOOTH_BEFORE = "world/smooth/before"
SMOOTH_AFTER = "world/smooth/after"
SMOOTH_SHORTCUTS = "world/smooth/shortcuts"
SMOOTH_SHORTCUT_PATH = "world/smooth/shortcut"
SMOOTH_POLISH = "world/smooth/polish"
POLISH_LENGTH = "metrics/polish_length_m"
FORCE = "metrics/force_N"
VELOCITY = "metrics/velocity_mps"
SOLUTION_COST = "metrics/solution_cost"
COST = "metrics/cost"

TREE_COLOR = (150, 150, 150, 110)
GROWTH_COLOR = (120, 160, 220, 140)
PATH_COLOR = (255, 170, 40, 255)
START_COLOR = (60, 200, 90, 255)
GOAL_COLOR = (230, 60, 60, 255)
SHORTCUT_COLOR = (120, 120, 120, 255)
POLISH_COLOR = (60, 200, 90, 255)


def _sequence(rec: StageRecording, timeline: str, value: int) -> None:
    rec.stream.set_time(timeline, sequence=int(value))


def _strips(polylines: Sequence[np.ndarray]) -> list[np.ndarray]:
    return [np.asarray(p, dtype=float) for p in polylines if len(p) >= 2]


def _log_motion(rec: StageRecording, t: np.ndarray, x: np.ndarray, u: np.ndarray, force_limit_N: np.ndarray,
                velocity_limit_mps: np.ndarray, start_on_iteration: bool) -> None:
    """Robot pose, force and velocity over ``mission_time``."""
    rec.log_trajectory_over_time(ROBOT, t, x)
    if start_on_iteration:  # show the robot at the start on the iteration timeline too
        _sequence(rec, ITERATION, 0)
        rec.stream.log(ROBOT, rr.Transform3D(translation=x[0, 0:3], quaternion=x[0, 6:10]))  # type: ignore[arg-type]
        rec.stream.reset_time()
    rec.log_series(FORCE, t, u[:, 0:3], AXIS_NAMES, limits=np.asarray(force_limit_N, dtype=float))
    rec.log_series(VELOCITY, t, x[:, 3:6], AXIS_NAMES, limits=np.asarray(velocity_limit_mps, dtype=float))


def _log_texts(rec: StageRecording, log: Sequence[tuple[float, str, str]]) -> None:
    if log:
        t_log, levels, messages = zip(*log, strict=True)
        rec.log_texts(np.array(t_log, dtype=float), list(levels), list(messages))


def _motion_blueprint(world_name: str, extra_plots: list, timeline: str) -> rrb.Blueprint:
    """3D scene and log on the left; force, velocity and ``extra_plots`` on the right (plan and smooth layouts)."""
    world = rrb.Spatial3DView(origin=WORLD, name=world_name)
    plots = rrb.Vertical(
        time_series_view(FORCE, "Force [N], world frame (mission_time)", legend=False),
        time_series_view(VELOCITY, "Velocity [m/s], world frame (mission_time)", legend=False),
        *extra_plots,
        name="Metrics",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, rrb.TextLogView(origin=LOG, name="Log"), row_shares=[3.0, 1.0]),
            plots,
            column_shares=[1.4, 1.0],
        ),
        rrb.TimePanel(timeline=timeline),
    )


def plan_blueprint() -> rrb.Blueprint:
    """Layout of ``plan.rrd``: 3D scene and log on the left, force, velocity and solution cost on the right."""
    return _motion_blueprint(
        "World: tree, plan, obstacles", [time_series_view(SOLUTION_COST, "Best solution cost (iteration)")], ITERATION
    )


def write_plan_recording(
    path: Path,
    *,
    scene: Scene,
    start: np.ndarray,
    goal: np.ndarray,
    tree_states: np.ndarray,
    tree_edges: Sequence[np.ndarray],
    snapshots: Sequence[tuple[int, np.ndarray, Sequence[int]]],
    solutions: Sequence[tuple[int, float]],
    trajectory: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    force_limit_N: np.ndarray,
    velocity_limit_mps: np.ndarray,
    log: Sequence[tuple[float, str, str]] = (),
    recording_name: str = "plan",
) -> None:
    """Write ``plan.rrd`` (entities in the module docstring).

    Parameters
    ----------
    path : Path
        Output file (written atomically).
    scene : Scene
    start, goal : ndarray, shape (3,)
        Positions [m].
    tree_states : ndarray, shape (n, 6)
        Final tree node states.
    tree_edges : sequence of ndarray (k_i, 3)
        Each node's incoming edge as a polyline (empty for the root).
    snapshots : sequence of (iteration, parent (m,), best path node ids)
        Tree growth.
    solutions : sequence of (iteration, cost)
        Improvements of the best solution.
    trajectory : (t (N,), x (N, 13), u (N, 6)) or None
        The plan (None when no solution was found).
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
    log : sequence of (t, level, message)
    recording_name : str
    """
    rec = StageRecording(recording_name=recording_name)
    rec.log_scene(scene)
    rec.log_points(PLAN_START, np.asarray(start, dtype=float).reshape(1, 3), color=START_COLOR, radius_m=0.03,
                   labels=["start"])
    rec.log_points(PLAN_GOAL, np.asarray(goal, dtype=float).reshape(1, 3), color=GOAL_COLOR, radius_m=0.03,
                   labels=["goal"])
    strips = _strips(tree_edges)
    rec.stream.log(PLAN_TREE, rr.LineStrips3D(strips, colors=[TREE_COLOR], radii=[0.002]), static=True)
    pos = np.asarray(tree_states, dtype=float)[:, 0:3]
    for iteration, parent, best in snapshots:
        parent = np.asarray(parent)
        child = np.flatnonzero(parent >= 0)
        segs = np.stack([pos[parent[child]], pos[child]], axis=1) if child.size else np.zeros((0, 2, 3))
        _sequence(rec, ITERATION, iteration)
        rec.stream.log(PLAN_GROWTH, rr.LineStrips3D(segs, colors=[GROWTH_COLOR], radii=[0.002]))  # type: ignore[arg-type]
        path_pts = pos[np.asarray(best, dtype=int)] if len(best) >= 2 else np.zeros((0, 3))
        rec.stream.log(PLAN_GROWTH_PATH, rr.LineStrips3D([path_pts] if len(path_pts) else [],
                                                         colors=[PATH_COLOR], radii=[0.006]))
        rec.stream.reset_time()
    if solutions:
        its = np.array([s[0] for s in solutions], dtype=np.int64)
        costs = np.array([s[1] for s in solutions], dtype=float)
        rec.stream.log(SOLUTION_COST, rr.SeriesLines(names=["best cost"]), static=True)
        rec.stream.send_columns(SOLUTION_COST, indexes=[rr.TimeColumn(ITERATION, sequence=its)],
                                columns=rr.Scalars.columns(scalars=costs))
    if trajectory is not None:
        t, x, u = trajectory
        rec.log_path(PLAN_PATH, x[:, 0:3], color=PATH_COLOR, radius_m=0.008)
        _log_motion(rec, t, x, u, force_limit_N, velocity_limit_mps, start_on_iteration=True)
    _log_texts(rec, log)
    rec.save(Path(path), plan_blueprint())


def smooth_blueprint() -> rrb.Blueprint:
    """Layout of ``smooth.rrd``: 3D scene and log, force, velocity, cost per shortcut try, length per polish step."""
    return _motion_blueprint(
        "World: before (blue), shortcut (grey), after (orange)",
        [
            time_series_view(COST, "Trajectory cost after each shortcut try (shortcut)"),
            time_series_view(POLISH_LENGTH, "Path length of each polish candidate [m] (polish)"),
        ],
        TIMELINE,
    )


def write_smooth_recording(
    path: Path,
    *,
    scene: Scene,
    before: np.ndarray,
    trajectory: tuple[np.ndarray, np.ndarray, np.ndarray],
    shortcuts: Sequence[tuple[int, np.ndarray]],
    cost_per_try: np.ndarray,
    force_limit_N: np.ndarray,
    velocity_limit_mps: np.ndarray,
    log: Sequence[tuple[float, str, str]] = (),
    recording_name: str = "smooth",
    shortcut_path: np.ndarray | None = None,
    polish_steps: Sequence[tuple[int, np.ndarray]] = (),
    polish_lengths: np.ndarray | None = None,
) -> None:
    """Write ``smooth.rrd`` (entities in the module docstring).

    Parameters
    ----------
    path : Path
    scene : Scene
    before : ndarray, shape (M, 3)
        Path of the input trajectory [m].
    trajectory : (t (N,), x (N, 13), u (N, 6))
        The smoothed trajectory.
    shortcuts : sequence of (try index, positions (k, 3))
        Accepted shortcut sections.
    cost_per_try : ndarray, shape (tries + 1,)
        Cost before the first try and after each try.
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
    log : sequence of (t, level, message)
    recording_name : str
    shortcut_path : ndarray, shape (K, 3), optional
        Path after the shortcutting, before the polish [m] (None when the polish did not run).
    polish_steps : sequence of (iteration, positions (k, 3))
        Accepted polish candidates.
    polish_lengths : ndarray, shape (iterations,), optional
        Exact path length of each polish candidate [m] (NaN where the subproblem failed).
    """
    rec = StageRecording(recording_name=recording_name)
    rec.log_scene(scene)
    rec.log_path(SMOOTH_BEFORE, before, color=REFERENCE_COLOR, radius_m=0.006)
    if shortcut_path is not None:
        rec.log_path(SMOOTH_SHORTCUT_PATH, shortcut_path, color=SHORTCUT_COLOR, radius_m=0.005)
    for index, pts in polish_steps:
        _sequence(rec, POLISH, index)
        rec.stream.log(SMOOTH_POLISH, rr.LineStrips3D([np.asarray(pts, dtype=float)], colors=[POLISH_COLOR],
                                                      radii=[0.006]))
        rec.stream.reset_time()
    lengths = np.asarray(polish_lengths if polish_lengths is not None else [], dtype=float)
    solved = np.flatnonzero(np.isfinite(lengths))
    if solved.size:
        rec.stream.log(POLISH_LENGTH, rr.SeriesLines(names=["path length"]), static=True)
        rec.stream.send_columns(POLISH_LENGTH, indexes=[rr.TimeColumn(POLISH, sequence=solved)],
                                columns=rr.Scalars.columns(scalars=lengths[solved]))
    t, x, u = trajectory
    rec.log_path(SMOOTH_AFTER, x[:, 0:3], color=ACTUAL_COLOR, radius_m=0.008)
    for index, pts in shortcuts:
        _sequence(rec, SHORTCUT, index)
        rec.stream.log(SMOOTH_SHORTCUTS, rr.LineStrips3D([np.asarray(pts, dtype=float)], colors=[PATH_COLOR],
                                                         radii=[0.006]))
        rec.stream.reset_time()
    costs = np.asarray(cost_per_try, dtype=float)
    rec.stream.log(COST, rr.SeriesLines(names=["cost"]), static=True)
    rec.stream.send_columns(COST, indexes=[rr.TimeColumn(SHORTCUT, sequence=np.arange(costs.size))],
                            columns=rr.Scalars.columns(scalars=costs))
    _log_motion(rec, t, x, u, force_limit_N, velocity_limit_mps, start_on_iteration=False)
    _log_texts(rec, log)
    rec.save(Path(path), smooth_blueprint())
