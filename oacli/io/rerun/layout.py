"""Layout helpers shared by the stage blueprints (each stage's blueprint is in its own module)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb


def time_series_view(origin: str, name: str, *, legend: bool = True,
                     y_range: tuple[float, float] | None = None) -> rrb.TimeSeriesView:
    """A time series view of ``origin`` and its children whose time axis spans the whole run.

    Parameters
    ----------
    origin : str
        Entity path; every ``Scalars`` series at or below it is plotted.
    name : str
        Panel title, short (give the unit, e.g. ``"Position error [m]"``); the series names go in the legend.
    legend : bool
        Show the legend (in the top-right corner, where it covers the least of a plot that starts at rest).
    y_range : (float, float), optional
        Fixed value axis (e.g. 1.15 × the ± limits, so the axis carries ticks beyond ``0`` however flat the data).

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
        axis_y=None if y_range is None else rrb.ScalarAxis(range=(float(y_range[0]), float(y_range[1]))),
        plot_legend=rrb.PlotLegend(visible=False) if not legend else rrb.PlotLegend("RightTop", visible=True),
    )


def limit_range(limits: Sequence[float] | np.ndarray, margin: float = 1.15) -> tuple[float, float]:
    """A symmetric value range ``± margin · max(limits)`` for a plot of series against their ± limits.

    Parameters
    ----------
    limits : array_like
        The ± limits [unit of the plot].
    margin : float
        Headroom beyond the largest limit.

    Returns
    -------
    (float, float)
    """
    top = margin * float(np.max(np.abs(np.asarray(limits, dtype=float))))
    return (-top, top)
