"""The ``smooth`` stage's Rerun recording and its layout.

Entities of ``smooth.rrd`` (a fixed contract; tests read them back): the scene; ``world/smooth/before`` and
``world/smooth/after`` (paths, static; ``after`` is the output, polished when the polish ran);
``world/smooth/shortcut`` (the path after the shortcutting, before the polish, static; only when the polish ran);
``world/smooth/shortcuts`` (each accepted shortcut's section, on the ``shortcut`` sequence timeline);
``world/smooth/polish`` (each accepted polish candidate's path, on the ``polish`` sequence timeline);
``world/robot`` (output trajectory); ``metrics/force_N``, ``metrics/velocity_mps`` (output, ``mission_time``);
``metrics/cost`` (trajectory cost after each try, ``shortcut`` timeline); ``metrics/polish_length_m`` (exact path
length of each polish candidate, ``polish`` timeline); both also as static line charts ``charts/cost`` and
``charts/polish_length_m`` (x the try or candidate, y framed on the values' range: :mod:`oacli.io.rerun.chart`,
shown on ``mission_time``, the timeline the layout opens on); ``log``. Application id ``oacli-smooth``. The 3-D
view opens framed on the paths.
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
from oacli.io.rerun.layout import world_title
from oacli.io.rerun.plan import PATH_COLOR, log_motion, motion_blueprint, set_sequence
from oacli.io.rerun.writer import (
    ACTUAL_COLOR,
    REFERENCE_COLOR,
    TIMELINE,
    AxisLimits,
    LogEntry,
    StageRecording,
    application_id,
)
from oacli.types import Trajectory

SHORTCUT = "shortcut"
POLISH = "polish"

SMOOTH_BEFORE = "world/smooth/before"
SMOOTH_AFTER = "world/smooth/after"
SMOOTH_SHORTCUTS = "world/smooth/shortcuts"
SMOOTH_SHORTCUT_PATH = "world/smooth/shortcut"
SMOOTH_POLISH = "world/smooth/polish"
POLISH_LENGTH = "metrics/polish_length_m"
COST = "metrics/cost"
COST_CHART = "charts/cost"
POLISH_LENGTH_CHART = "charts/polish_length_m"

SHORTCUT_COLOR = (120, 120, 120, 255)
POLISH_COLOR = (60, 200, 90, 255)


@dataclass(frozen=True)
class ShortcutSteps:
    """What the shortcutting did, for the recording.

    Attributes
    ----------
    sections : sequence of (int, ndarray (k, 3))
        Each accepted shortcut: its try index and the positions [m] of the new section.
    cost_per_try : ndarray, shape (tries + 1,)
        Trajectory cost before the first try and after each try.
    """

    sections: Sequence[tuple[int, np.ndarray]]
    cost_per_try: np.ndarray


@dataclass(frozen=True)
class PolishSteps:
    """What the path-length polish did, for the recording.

    Attributes
    ----------
    before : ndarray, shape (K, 3)
        The path after the shortcutting, before the polish [m].
    accepted : sequence of (int, ndarray (k, 3))
        Each accepted polish candidate: its iteration and its positions [m].
    lengths_m : ndarray, shape (iterations,)
        Exact path length of each candidate [m] (NaN where the subproblem failed).
    """

    before: np.ndarray
    accepted: Sequence[tuple[int, np.ndarray]]
    lengths_m: np.ndarray


def smooth_blueprint(limits: AxisLimits | None = None, *, polished: bool = True, frame: str = "world",
                     focus: np.ndarray | None = None) -> rrb.Blueprint:
    """Layout of ``smooth.rrd``: 3D scene and log, force, velocity, cost per shortcut try, length per polish step.

    Parameters
    ----------
    limits : AxisLimits, optional
        Force and velocity bounds (fixes the value axes).
    polished : bool
        The polish ran and solved at least once (else its panel, which would be empty, is left out).
    frame : str
        Name of the world frame (the 3-D view's title).
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view frames (the paths).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    return motion_blueprint(
        world_title(frame, "before (blue), shortcut (grey), after (orange)"),
        [
            line_chart_view(COST_CHART, "Cost after each shortcut try (x: try)"),
            *([line_chart_view(POLISH_LENGTH_CHART, "Polish candidate path length [m] (x: candidate)")]
              if polished else []),
        ],
        TIMELINE,
        limits=limits,
        focus=focus,
    )


def write_smooth_recording(
    path: Path,
    *,
    scene: Scene,
    before: Trajectory,
    after: Trajectory,
    shortcuts: ShortcutSteps,
    polish: PolishSteps | None,
    limits: AxisLimits,
    log: Sequence[LogEntry] = (),
    recording_name: str = "smooth",
) -> None:
    """Write ``smooth.rrd`` (entities in the module docstring) with :func:`smooth_blueprint`.

    Parameters
    ----------
    path : Path
        Output file (written atomically).
    scene : Scene
        Keep-in boxes and keep-out ellipsoids.
    before : Trajectory
        The input trajectory (its path is drawn).
    after : Trajectory
        The smoothed trajectory.
    shortcuts : ShortcutSteps
        Accepted shortcut sections and the cost after each try.
    polish : PolishSteps or None
        The polish's steps (None when the polish did not run).
    limits : AxisLimits
        Force [N] and velocity [m/s] bounds plotted as ±.
    log : sequence of (t, level, message)
        The stage's text log.
    recording_name : str
        Recording name shown in the viewer.
    """
    rec = StageRecording(application_id("smooth"), recording_name)
    rec.log_scene(scene)
    rec.log_path(SMOOTH_BEFORE, before.x[:, 0:3], color=REFERENCE_COLOR, radius_m=0.006)
    if polish is not None:
        rec.log_path(SMOOTH_SHORTCUT_PATH, polish.before, color=SHORTCUT_COLOR, radius_m=0.005)
        for index, pts in polish.accepted:
            set_sequence(rec, POLISH, index)
            rec.stream.log(SMOOTH_POLISH, rr.LineStrips3D([np.asarray(pts, dtype=float)], colors=[POLISH_COLOR],
                                                          radii=[0.006]))
            rec.stream.reset_time()
        lengths = np.asarray(polish.lengths_m, dtype=float)
        solved = np.flatnonzero(np.isfinite(lengths))
        if solved.size:
            rec.stream.log(POLISH_LENGTH, rr.SeriesLines(names=["path length"]), static=True)
            rec.stream.send_columns(POLISH_LENGTH, indexes=[rr.TimeColumn(POLISH, sequence=solved)],
                                    columns=rr.Scalars.columns(scalars=lengths[solved]))
            log_line_chart(rec.stream, POLISH_LENGTH_CHART, solved, lengths[solved], color=POLISH_COLOR,
                           x_name="candidate", y_name="length [m]")
    rec.log_path(SMOOTH_AFTER, after.x[:, 0:3], color=ACTUAL_COLOR, radius_m=0.008)
    for index, pts in shortcuts.sections:
        set_sequence(rec, SHORTCUT, index)
        rec.stream.log(SMOOTH_SHORTCUTS, rr.LineStrips3D([np.asarray(pts, dtype=float)], colors=[PATH_COLOR],
                                                         radii=[0.006]))
        rec.stream.reset_time()
    costs = np.asarray(shortcuts.cost_per_try, dtype=float)
    rec.stream.log(COST, rr.SeriesLines(names=["cost"]), static=True)
    rec.stream.send_columns(COST, indexes=[rr.TimeColumn(SHORTCUT, sequence=np.arange(costs.size))],
                            columns=rr.Scalars.columns(scalars=costs))
    log_line_chart(rec.stream, COST_CHART, np.arange(costs.size), costs, color=PATH_COLOR, x_name="try",
                   y_name="cost")
    log_motion(rec, after, limits, start_on_iteration=False)
    rec.log_entries(log)
    polished = polish is not None and bool(np.any(np.isfinite(np.asarray(polish.lengths_m, dtype=float))))
    focus = np.concatenate([before.x[:, 0:3], after.x[:, 0:3]])
    rec.save(Path(path), smooth_blueprint(limits, polished=polished, frame=scene.frame, focus=focus))
