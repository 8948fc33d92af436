"""Static line charts in a 2-D view: convergence figures (cost per iteration, length per polish step) that a
reviewer sees whatever the active timeline.

A Rerun time series view plots only the timeline active in the time panel. A convergence figure lives on a
sequence timeline of its own (``iteration``, ``shortcut``, ``polish``): the stage recordings log it there as
``Scalars`` (read back by tests and shown when that timeline is picked) and open on ``mission_time``, where a time
series view of it would be empty. :func:`log_line_chart` also draws it as a static polyline in a 2-D view, x the
iteration and y the value, the y-range spanning the values' range (not from 0, so a 4.71 → 2.93 fall fills the
panel), the axis ends labelled with their values (y: the largest and smallest value, x: the first and last
iteration).

The chart lives in a normalised plane (x in [0, WIDTH], y in [−HEIGHT, 0], the 2-D view's y pointing down) with
fixed bounds (:func:`line_chart_view`), so every chart fills its panel the same way.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

WIDTH = 3.0
HEIGHT = 1.0
AXIS_COLOR = (150, 150, 150, 255)
# Radii below are negative: Rerun reads a negative radius as a size in UI points (the same on any zoom).


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def log_line_chart(stream: rr.RecordingStream, entity: str, x: np.ndarray, y: np.ndarray, *,
                   color: Sequence[int], x_name: str, y_name: str) -> None:
    """Log a static line chart of ``y`` against ``x`` under ``entity`` (``line``, ``points``, ``axes``, ``ticks``).

    Each sample is a dot on the line; the four axis ends carry the values they stand for.

    Parameters
    ----------
    stream : rerun.RecordingStream
        The recording.
    entity : str
        Root entity of the chart (e.g. ``charts/solution_cost``); show it with :func:`line_chart_view`.
    x : ndarray, shape (N,)
        Abscissae (iterations); NaN values of ``y`` are left out.
    y : ndarray, shape (N,)
        Values.
    color : sequence of int
        RGB(A) 0-255 of the line.
    x_name, y_name : str
        Axis names with units (``"iteration"``, ``"cost [-]"``), written at the axis ends.

    Raises
    ------
    ValueError
        ``x`` and ``y`` of different lengths.
    """
    xx = np.asarray(x, dtype=float).reshape(-1)
    yy = np.asarray(y, dtype=float).reshape(-1)
    if xx.shape != yy.shape:
        raise ValueError(f"{entity}: {xx.size} abscissae but {yy.size} values")
    keep = np.isfinite(xx) & np.isfinite(yy)
    xx, yy = xx[keep], yy[keep]
    if xx.size == 0:
        return
    x0, x1 = float(xx.min()), float(xx.max())
    lo, hi = float(yy.min()), float(yy.max())
    xs = WIDTH * ((xx - x0) / (x1 - x0) if x1 > x0 else np.full_like(xx, 0.5))
    ys = -HEIGHT * ((yy - lo) / (hi - lo) if hi > lo else np.full_like(yy, 0.5))
    pts = np.column_stack([xs, ys])
    rgba = list(color)
    stream.log(f"{entity}/line", rr.LineStrips2D([pts], colors=[rgba], radii=[-2.0]),
               static=True, strict=True)
    stream.log(f"{entity}/points", rr.Points2D(pts, colors=[rgba], radii=[-3.0]), static=True, strict=True)
    below, left = 0.12 * HEIGHT, -0.04 * WIDTH
    stream.log(f"{entity}/axes",
               rr.LineStrips2D([[[left, -1.08 * HEIGHT], [left, below], [1.02 * WIDTH, below]]], colors=[AXIS_COLOR],
                               radii=[-1.0]),
               static=True, strict=True)
    # y max and min left of the y axis, the x ends below the x axis (labels are drawn centred under their point);
    # a single value or abscissa gets one tick
    ticks = [((-0.16 * WIDTH, -HEIGHT), f"{y_name} {_fmt(hi)}")] if hi > lo else []
    ticks.append(((-0.16 * WIDTH, 0.0 if hi > lo else -0.5 * HEIGHT), f"{y_name} {_fmt(lo)}"))
    ticks += [((0.0, below), f"{x_name} {_fmt(x0)}")] if x1 > x0 else []
    ticks.append(((WIDTH if x1 > x0 else 0.5 * WIDTH, below), f"{x_name} {_fmt(x1)}"))
    stream.log(f"{entity}/ticks",
               rr.Points2D([t[0] for t in ticks], colors=[AXIS_COLOR], radii=[-1.0], labels=[t[1] for t in ticks],
                           show_labels=True),
               static=True, strict=True)

def line_chart_view(entity: str, name: str) -> rrb.Spatial2DView:
    """The 2-D view of a chart logged by :func:`log_line_chart`, bounded on the chart's plane and its labels.

    Parameters
    ----------
    entity : str
        The chart's root entity.
    name : str
        Panel title (what is plotted against what).

    Returns
    -------
    rerun.blueprint.Spatial2DView
    """
    bounds = rrb.VisualBounds2D(x_range=(-0.3 * WIDTH, 1.1 * WIDTH), y_range=(-1.15 * HEIGHT, 0.3 * HEIGHT))
    return rrb.Spatial2DView(origin=entity, name=name, visual_bounds=bounds)
