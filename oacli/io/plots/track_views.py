"""The ``track`` stage's ``views.png``: the flown path in top, side and front views, zoomed on the flown region,
each with the keep-out zones projected into it (issue 33 item 2), and a fourth panel: the view along the direction
that shows the clearance when every axis view shows the path crossing a keep-out it clears in 3-D
(:func:`oacli.io.plots.views.choose_views`), otherwise the clearance to each nearby keep-out over time.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Ellipse, Polygon
from scipy.spatial import ConvexHull, QhullError

from oacli.geometry import Scene
from oacli.geometry.shapes import Ellipsoid
from oacli.geometry.verify import point_ellipsoid_distance
from oacli.io.plots.common import decimate, legend_outside, save_png, subplots
from oacli.io.plots.views import View, choose_views
from oacli.types import Telemetry, Trajectory

#: Room around the flown region in each view [m], at least (plus 5 % of the view's span).
VIEW_MARGIN_M = 0.1


@dataclass(frozen=True)
class DrawnViews:
    """What ``views.png`` shows.

    Attributes
    ----------
    views : list of View
        The projected panels, in order.
    zones : list of Ellipsoid
        The keep-out zones drawn (those near the path).
    clearance_m : ndarray, shape (N, Z) or None
        Signed distance [m] of the true position to each zone's surface minus the robot radius, when the fourth
        panel shows it over time.
    """

    views: list[View]
    zones: list[Ellipsoid]
    clearance_m: np.ndarray | None


def _hull(points_2d: np.ndarray) -> np.ndarray:
    try:
        return points_2d[ConvexHull(points_2d).vertices]
    except QhullError:  # a box seen edge-on (flat): its extreme points
        return points_2d[[int(np.argmin(points_2d[:, 0])), int(np.argmax(points_2d[:, 0]))]]


def _limits(view: View, region_m: np.ndarray, zones: list[Ellipsoid], grow_m: float) -> np.ndarray:
    """``[[x_lo, y_lo], [x_hi, y_hi]]`` of the view: the flown region and the nearby zones' shadows (grown)."""
    pts = view.project(region_m)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    for zone in zones:
        c = view.basis @ zone.center
        half = np.sqrt(np.einsum("ij,jk,ik->i", view.basis, np.linalg.inv(zone.shape), view.basis)) + grow_m
        lo, hi = np.minimum(lo, c - half), np.maximum(hi, c + half)
    pad = VIEW_MARGIN_M + 0.05 * float(np.max(hi - lo))
    return np.array([lo - pad, hi + pad])


def _draw_view(ax: Axes, view: View, scene: Scene | None, zones: list[Ellipsoid], robot_radius_m: float,
               reference: Trajectory, flown_m: np.ndarray, region_m: np.ndarray) -> None:
    from oacli.io.plots.views import shadow_ellipse

    if scene is not None:
        for k, box in enumerate(scene.keep_in):
            lo, hi = np.asarray(box.lower, dtype=float), np.asarray(box.upper, dtype=float)
            corners = np.array([[(lo, hi)[a][0], (lo, hi)[b][1], (lo, hi)[c][2]]
                                for a in (0, 1) for b in (0, 1) for c in (0, 1)])
            ax.add_patch(Polygon(_hull(view.project(corners)), closed=True, fc=(0.3, 0.8, 0.45, 0.08),
                                 ec="tab:green", lw=1.2, label="keep-in" if k == 0 else None))
    for k, zone in enumerate(zones):
        x, y, w, h, a = shadow_ellipse(zone, view.basis)
        ax.add_patch(Ellipse((x, y), w, h, angle=a, fc=(0.9, 0.25, 0.25, 0.35), ec="tab:red", lw=1.0,
                             label="keep-out (safety factor incl.)" if k == 0 else None))
        if robot_radius_m > 0:
            x, y, w, h, a = shadow_ellipse(zone, view.basis, robot_radius_m)
            ax.add_patch(Ellipse((x, y), w, h, angle=a, fill=False, ec="tab:red", ls="--", lw=0.8,
                                 label=f"keep-out + robot radius {robot_radius_m:g} m" if k == 0 else None))
    ref = view.project(reference.x[:, 0:3])
    flown = view.project(flown_m)
    ax.plot(*decimate(ref[:, 0], ref[:, 1]), "--", color="0.3", lw=1.2, label="reference")
    ax.plot(*decimate(flown[:, 0], flown[:, 1]), color="tab:blue", lw=1.6, label="flown (true)")
    ax.plot(*flown[0], "ko", ms=6, label="start")
    ax.plot(*ref[-1], "k^", ms=8, label="reference end")
    # the view: the flown region and the nearby zones (the keep-in boxes reach far beyond), widened to equal scales
    ax.dataLim.set_points(_limits(view, region_m, zones, robot_radius_m))
    ax.margins(0.0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(view.labels[0])
    ax.set_ylabel(view.labels[1])
    ax.grid(True, alpha=0.3)
    title = {"top": "top view (x-y)", "side": "side view (x-z)", "front": "front view (y-z)",
             "clearance": "view along the line of sight that shows the clearance"}[view.name]
    ax.set_title(title, loc="left", fontsize="medium")


def plot_views(path: Path, scene: Scene | None, robot_radius_m: float, reference: Trajectory,
               telemetry: Telemetry) -> DrawnViews:
    """Draw ``views.png`` (module docstring) and return what it shows.

    Parameters
    ----------
    path : Path
        Output PNG.
    scene : Scene, optional
    robot_radius_m : float
        Robot radius [m] (dashed: the keep-outs grown by it).
    reference : Trajectory
    telemetry : Telemetry

    Returns
    -------
    DrawnViews
    """
    flown = np.asarray(telemetry.x_true[:, 0:3], dtype=float)
    finite = np.all(np.isfinite(flown), axis=1)
    flown, t_flown = flown[finite], np.asarray(telemetry.t_true, dtype=float)[finite]
    region = np.vstack([flown, reference.x[:, 0:3]])
    views, zones = choose_views(flown, scene, robot_radius_m)
    fig, axes = subplots(2, 2, figsize=(13, 10.5))
    panels = list(axes.flat)
    for ax, view in zip(panels, views, strict=False):
        _draw_view(ax, view, scene, zones, robot_radius_m, reference, flown, region)
    clearance = None
    if len(views) == 3:
        ax = panels[3]
        t = t_flown
        columns = []
        for k, zone in enumerate(zones):
            semi, rot = zone.principal_axes()
            d = point_ellipsoid_distance(flown, zone.center, semi, rot) - robot_radius_m
            columns.append(d)
            ax.plot(*decimate(t, d), lw=1.4, label=f"keep-out {k}: min {1e3 * float(d.min()):.0f} mm")
        clearance = np.column_stack(columns) if columns else np.zeros((len(flown), 0))
        ax.axhline(0.0, color="tab:red", ls="--", lw=1.0, label="touching (robot radius incl.)")
        if not zones:  # nothing to scale to: fixed limits (the flight's time span), so every draw is the same
            ax.text(0.5, 0.5, "no keep-out near the path", transform=ax.transAxes, ha="center", va="center")
            span = (float(t[0]), float(t[-1])) if len(t) > 1 and t[-1] > t[0] else (0.0, 1.0)
            ax.set_xlim(*span)
            ax.set_ylim(-0.1, 1.0)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("clearance to keep-out [m]")
        ax.grid(True, alpha=0.3)
        ax.set_title("distance of the robot's surface to each nearby keep-out", loc="left", fontsize="medium")
        legend_outside(ax)
    legend_outside(panels[1])
    fig.suptitle("Flown path and keep-out zones in three projections, zoomed on the flown region")
    save_png(fig, path)
    return DrawnViews(views, zones, clearance)
