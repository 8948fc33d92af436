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


#: Direction from the framed centre to the eye in the world frame (behind, port side, above: the world frames are
#: right-handed with +z towards the deck, so "above" is −z), normalised in :func:`framed_eye`.
EYE_DIRECTION = (-1.0, -0.75, -0.85)
#: The eye's "up" in the world frame (+z points to the deck).
EYE_UP = (0.0, 0.0, -1.0)


def framed_eye(points: np.ndarray, *, min_half_extent_m: float = 0.35, margin: float = 1.25) -> rrb.EyeControls3D:
    """An orbital camera looking at the centre of ``points``' bounding box from far enough to fit them.

    The viewer frames a 3-D view on everything in it by default (in the ISS, the whole JEM, where the robot's
    path is a few dozen pixels); this eye frames the robot's path instead.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        What must be in view [m] (paths, start, goal, tube corners); non-finite rows are ignored.
    min_half_extent_m : float
        Smallest half-size of the framed region [m] (a short hop is still seen with the robot's body around it).
    margin : float
        Distance factor beyond the one that just fits the bounding sphere in a 60° field of view.

    Returns
    -------
    rerun.blueprint.EyeControls3D
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if p.size == 0:
        p = np.zeros((1, 3))
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), float(min_half_extent_m))
    direction = np.asarray(EYE_DIRECTION, dtype=float)
    direction /= np.linalg.norm(direction)
    distance = margin * radius / np.sin(np.radians(30.0))
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=centre + distance * direction,
                             look_target=centre, eye_up=EYE_UP)


def world_title(frame: str, what: str = "") -> str:
    """Title of a 3-D view of the world: ``"World (<frame> frame)"`` and what it shows.

    Parameters
    ----------
    frame : str
        Name of the world frame (``environment.frame``: ``iss``, ``assembly_bay`` ...).
    what : str
        What the view draws (``"reference, flown path"``).

    Returns
    -------
    str
    """
    return f"World ({frame} frame)" + (f": {what}" if what else "")


def world_view(origin: str, name: str, focus: np.ndarray | None = None, **kwargs) -> rrb.Spatial3DView:
    """A 3-D view of ``origin`` titled ``name``, its camera framed on ``focus`` (:func:`framed_eye`) when given.

    Parameters
    ----------
    origin : str
        Entity path of the view's space (``world``).
    name : str
        Title.
    focus : ndarray, shape (N, 3), optional
        The points [m] the camera frames; the viewer's default framing (everything) when None.
    **kwargs
        Passed to :class:`rerun.blueprint.Spatial3DView` (``contents`` ...).

    Returns
    -------
    rerun.blueprint.Spatial3DView
    """
    eye = None if focus is None else framed_eye(focus)
    return rrb.Spatial3DView(origin=origin, name=name, eye_controls=eye, **kwargs)


def collapsed_side_panels() -> list:
    """Blueprint parts that start the blueprint and selection panels collapsed (more room for the views)."""
    return [rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed")]
