"""The ``plan`` and ``smooth`` stages' PNG plots.

* ``top_view.png`` (x-y) and ``side_view.png`` (x-z) -- keep-in boxes, keep-out ellipsoids (projected; dashed:
  grown by the robot radius), the paths (plan: the solution; smooth: the input plan and the smoothed path), start
  and goal.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from oacli.geometry import Scene
from oacli.io.plots.common import RunFiles, decimate, draw_scene, finish_view, guarded_plots, save_png, subplots

#: Line style per path label (others: solid).
_STYLES = {"plan (input)": (":", 1.2, "0.35"), "plan": ("-", 1.8, "tab:blue"), "smoothed": ("-", 1.8, "tab:blue")}


def plot_view(path: Path, axes: tuple[int, int], title: str, scene: Scene | None, robot_radius_m: float,
              paths: Mapping[str, np.ndarray], start_m: np.ndarray, goal_m: np.ndarray) -> None:
    """One projected view of the scene and the paths.

    Parameters
    ----------
    path : Path
        Output PNG.
    axes : tuple of int
        World axes of the view: (0, 1) top, (0, 2) side.
    title : str
    scene : Scene, optional
    robot_radius_m : float
    paths : mapping of str to ndarray, shape (N, 3)
        Label -> positions [m].
    start_m, goal_m : ndarray, shape (3,)
    """
    i, j = axes
    fig, ax = subplots(figsize=(10, 7))
    draw_scene(ax, scene, robot_radius_m, axes)
    for label, pos in paths.items():
        ls, lw, color = _STYLES.get(label, ("-", 1.4, None))
        p = np.asarray(pos, dtype=float)
        ax.plot(*decimate(p[:, i], p[:, j]), ls=ls, lw=lw, color=color, label=label)
    ax.plot(start_m[i], start_m[j], "ko", ms=7, label="start")
    ax.plot(goal_m[i], goal_m[j], "k^", ms=9, label="goal")
    finish_view(ax, axes, title)
    save_png(fig, path)


def path_figures(*, stage: str, scene: Scene | None, robot_radius_m: float, paths: Mapping[str, np.ndarray],
                 start_m: np.ndarray, goal_m: np.ndarray) -> dict[str, Callable[[Path], object]]:
    """The ``plan`` / ``smooth`` stage's figures, name -> function drawing it to a path (shared by the stage and by
    ``oacli plots``, :mod:`oacli.stages.replot`).

    Parameters
    ----------
    stage : str
        ``plan`` or ``smooth`` (in the titles).
    scene : Scene, optional
    robot_radius_m : float
    paths : mapping of str to ndarray, shape (N, 3)
        Label -> positions [m] (``plan``, ``plan (input)``, ``smoothed`` are styled).
    start_m, goal_m : ndarray, shape (3,)

    Returns
    -------
    dict of str to callable
    """
    start, goal = np.asarray(start_m, dtype=float), np.asarray(goal_m, dtype=float)
    return {
        "top_view": lambda p: plot_view(p, (0, 1), f"{stage} top view (x-y)", scene, robot_radius_m, paths,
                                        start, goal),
        "side_view": lambda p: plot_view(p, (0, 2), f"{stage} side view (x-z)", scene, robot_radius_m, paths,
                                         start, goal),
    }


def write_path_plots(run: RunFiles, summary: dict[str, Any], *, scene: Scene | None, robot_radius_m: float,
                     paths: Mapping[str, np.ndarray], start_m: np.ndarray, goal_m: np.ndarray) -> None:
    """Write ``top_view.png`` and ``side_view.png`` into the run folder and register them (failures: a summary
    warning).

    Parameters
    ----------
    run : RunFolder
        The open run folder.
    summary : dict
        The stage's summary.
    scene : Scene, optional
    robot_radius_m : float
    paths : mapping of str to ndarray, shape (N, 3)
        Label -> positions [m] (``plan``, ``plan (input)``, ``smoothed`` are styled).
    start_m, goal_m : ndarray, shape (3,)
    """
    guarded_plots(run, summary, path_figures(stage=str(summary.get("stage", "")), scene=scene,
                                             robot_radius_m=robot_radius_m, paths=paths, start_m=start_m,
                                             goal_m=goal_m))
