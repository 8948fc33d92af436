"""Convex pieces of the workspace for convex programs: keep-in boxes and supporting half-spaces of keep-out zones.

The free space ([Doerr2021] Eqs. 12-14) is a union of keep-in boxes minus keep-out ellipsoids: not convex.
Every convex program of the project (the trajectory polish, the excitation design, the MPC controllers) replaces
it, per step, by a convex inner piece: one keep-in box and one half-space per keep-out zone. This module holds
the one implementation they share.

Keep-out zone grown by the robot
--------------------------------
Zone j's set of forbidden centre positions is ``O_j = E_j ⊕ R``: the keep-out ellipsoid (safety factor applied)
grown by the robot's bounding ellipsoid R ([ReSWARM2023] §4.2.2; a sphere of the robot's radius, or a point). An
ellipsoid containing ``O_j`` is ``{p : ‖L (p − c_j)‖ ≤ 1}`` (``E_j`` itself for a point robot; for a body, the
trace-minimal outer ellipsoid of the Minkowski sum, ``Σ = Σ_j/(1 − s) + Σ_R/s``, Kurzhanski & Vályi 1997). Its
normalised coordinates ``w = L (p − c_j)`` give the *metric direction* of a point, ``m = w/‖w‖``. The half-space

    nᵀ p ≥ β,   n = Lᵀ m / ‖Lᵀ m‖,   β = nᵀ c_j + sqrt(nᵀ Σ_j n) + sqrt(nᵀ Σ_R n) + μ

is bounded by the supporting plane of ``O_j`` (its support function ``h_{E_j}(n) + h_R(n)``) moved out by a
clearance μ: ``O_j`` lies entirely on the other side, so any centre position in it keeps the body out of the
zone. For a point robot and a point p outside ``E_j`` this is the tangent plane of ``E_j`` at the point of its
surface along ``p − c_j`` in its own metric (the gradient direction of ``(p − c)ᵀP(p − c)`` at p); a point
satisfies its own half-space exactly when it is outside ``E_j``: ``nᵀp − β = (‖w‖ − 1)/‖Lᵀ m‖ − μ``.

Keep-in box of a point
----------------------
:func:`best_box`: the box holding all the given points with the largest worst margin, or, when none holds them,
the nearest one (least worst excess, an L∞ distance).

Boxes of a union are not enough once they are shrunk (by the robot's radius, a tube): two boxes that touch along
a face leave a gap between their shrunk copies, though the shrunk *union* is connected there.
:func:`keep_in_pieces` adds, for every pair of boxes whose intervals along one axis overlap or touch and whose
cross-sections across it intersect, the *bridge* box: that intersection of cross-sections times the union of the
two intervals. Every point of a bridge is in one of the two boxes, so the bridges are convex pieces of the union,
and a motion from one box to the other stays in the bridge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import RobotBody
from oacli.geometry.shapes import Ellipsoid, Scene

#: Below this norm [-] a metric direction is undefined (the point is the zone's centre).
_DEGENERATE = 1e-12


@dataclass(frozen=True)
class KeepOutZone:
    """A keep-out zone grown by the robot's body, as the convex programs see it.

    Attributes
    ----------
    center : ndarray, shape (3,)
        Zone centre c [m].
    sigma_zone : ndarray, shape (3, 3)
        ``Σ_j = P_j⁻¹`` [m²] of the keep-out ellipsoid (safety factor applied).
    sigma_robot : ndarray, shape (3, 3)
        Shape Σ_R [m²] of the robot's bounding ellipsoid (zero for a point).
    metric : ndarray, shape (3, 3)
        L [1/m] with ``‖L (p − c)‖ <= 1`` on an ellipsoid containing the zone grown by the robot.
    """

    center: np.ndarray
    sigma_zone: np.ndarray
    sigma_robot: np.ndarray
    metric: np.ndarray

    def support_m(self, normals: np.ndarray) -> np.ndarray:
        """Support function of the grown zone, ``max_{p ∈ E ⊕ R} nᵀp`` [m].

        Parameters
        ----------
        normals : ndarray, shape (K, 3)
            Unit normals.

        Returns
        -------
        ndarray, shape (K,)
        """
        n = np.atleast_2d(normals)
        zone = np.sum((n @ self.sigma_zone) * n, axis=1)
        robot = np.sum((n @ self.sigma_robot) * n, axis=1)
        return n @ self.center + np.sqrt(zone) + np.sqrt(np.maximum(robot, 0.0))


def keep_out_zone(ellipsoid: Ellipsoid, robot: RobotBody | None = None) -> KeepOutZone:
    """A keep-out ellipsoid grown by the robot's body, with its metric (module docstring).

    Parameters
    ----------
    ellipsoid : Ellipsoid
        The keep-out zone (safety factor applied).
    robot : RobotBody, optional
        The robot's bounding ellipsoid (a point when omitted).

    Returns
    -------
    KeepOutZone
    """
    sigma_r = np.zeros((3, 3)) if robot is None else np.asarray(robot.sigma, dtype=float)
    sigma_o = np.linalg.inv(ellipsoid.shape)
    sigma_o = 0.5 * (sigma_o + sigma_o.T)
    if not np.any(sigma_r):
        outer = sigma_o
    else:  # trace-minimal outer ellipsoid of the Minkowski sum: Σ_o/(1−s) + Σ_r/s
        ro, rr = np.sqrt(np.trace(sigma_o)), np.sqrt(np.trace(sigma_r))
        s = rr / (ro + rr)
        outer = sigma_o / (1.0 - s) + sigma_r / s
    chol = np.linalg.cholesky(0.5 * (outer + outer.T))
    return KeepOutZone(np.asarray(ellipsoid.center, dtype=float), sigma_o, sigma_r, np.linalg.inv(chol))


def keep_out_zones(scene: Scene, robot: RobotBody | None = None) -> list[KeepOutZone]:
    """Every keep-out zone of a scene grown by the robot's body.

    Parameters
    ----------
    scene : Scene
    robot : RobotBody, optional
        The robot's bounding ellipsoid (a point when omitted).

    Returns
    -------
    list of KeepOutZone
    """
    return [keep_out_zone(e, robot) for e in scene.keep_out]


def supporting_halfspaces(
    zone: KeepOutZone, directions: np.ndarray, clearance_m: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Half-spaces ``nᵀp ≥ β`` bounded by the supporting planes of the grown zone along metric directions.

    Parameters
    ----------
    zone : KeepOutZone
    directions : ndarray, shape (K, 3)
        Directions m in the zone's normalised coordinates ``w = L (p − c)`` (non-zero; need not be unit).
    clearance_m : float
        μ: the plane is moved this far [m] away from the zone.

    Returns
    -------
    normal : ndarray, shape (K, 3)
        Unit world normals ``Lᵀm/‖Lᵀm‖``.
    offset : ndarray, shape (K,)
        β: support of the grown zone along the normal plus μ.
    """
    n = np.atleast_2d(directions) @ zone.metric  # rows: Lᵀ m
    n = n / np.sqrt(np.sum(n * n, axis=1))[:, None]
    return n, zone.support_m(n) + clearance_m


def metric_directions(zone: KeepOutZone, points: np.ndarray) -> np.ndarray:
    """Metric directions ``w = L (p − c)`` of points; +x of the normalised coordinates for a point on the centre.

    Parameters
    ----------
    zone : KeepOutZone
    points : ndarray, shape (K, 3)
        Points [m].

    Returns
    -------
    ndarray, shape (K, 3)
        Non-zero directions in the zone's normalised coordinates (not unit).
    """
    w = (np.atleast_2d(points) - zone.center) @ zone.metric.T
    degenerate = np.sum(w * w, axis=1) <= _DEGENERATE**2
    if degenerate.any():
        w[degenerate] = np.array([1.0, 0.0, 0.0])
    return w


def point_halfspaces(
    zone: KeepOutZone, points: np.ndarray, clearance_m: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Supporting half-spaces of the grown zone along the metric direction of each point.

    Parameters
    ----------
    zone : KeepOutZone
    points : ndarray, shape (K, 3)
        Linearisation points [m].
    clearance_m : float
        μ [m] (see :func:`supporting_halfspaces`).

    Returns
    -------
    normal : ndarray, shape (K, 3)
        Unit normals.
    offset : ndarray, shape (K,)
        β [m].
    margin : ndarray, shape (K,)
        ``nᵀp − β`` [m]: >= 0 exactly when the point satisfies its own half-space (it is at least μ outside the
        zone's outer ellipsoid along n).
    """
    p = np.atleast_2d(np.asarray(points, dtype=float))
    n, beta = supporting_halfspaces(zone, metric_directions(zone, p), clearance_m)
    return n, beta, np.sum(n * p, axis=1) - beta


def keep_in_pieces(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Convex box pieces of the keep-in union: the boxes and their pairwise bridges (module docstring).

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    lower, upper : ndarray, shape (B, 3)
        Corners [m]: the scene's boxes first, then the bridges that are not contained in one of their two boxes.
    """
    lower = [np.asarray(b.lower, dtype=float) for b in scene.keep_in]
    upper = [np.asarray(b.upper, dtype=float) for b in scene.keep_in]
    n_boxes = len(lower)
    for i in range(n_boxes):
        for j in range(i + 1, n_boxes):
            lo_x, hi_x = np.maximum(lower[i], lower[j]), np.minimum(upper[i], upper[j])
            for axis in range(3):
                across = [a for a in range(3) if a != axis]
                if lo_x[axis] > hi_x[axis] or np.any(lo_x[across] >= hi_x[across]):
                    continue  # apart along the axis, or no common cross-section
                lo, hi = lo_x.copy(), hi_x.copy()
                lo[axis] = min(lower[i][axis], lower[j][axis])
                hi[axis] = max(upper[i][axis], upper[j][axis])
                inside = [np.all(lo >= lower[b]) and np.all(hi <= upper[b]) for b in (i, j)]
                if not any(inside):
                    lower.append(lo)
                    upper.append(hi)
    return np.array(lower).reshape(-1, 3), np.array(upper).reshape(-1, 3)


def best_piece(lower: np.ndarray, upper: np.ndarray, *point_sets: np.ndarray,
               margin: np.ndarray | float = 0.0) -> np.ndarray:
    """Index of the box ``[lower[b], upper[b]]`` best holding the points ``point_sets[·][k]`` together, for each k.

    The score of a box for index k is the worst margin of the k-th points of every set inside the box shrunk by
    ``margin`` (per axis) — the box with the largest score wins (it holds them all, with the largest margin; or,
    when none does, it is the nearest in the L∞ sense).

    Parameters
    ----------
    lower, upper : ndarray, shape (B, 3)
        Box corners [m].
    *point_sets : ndarray, shape (K, 3)
        Points [m]; the k-th points of all sets are scored together.
    margin : ndarray of shape (3,) or float
        Inward margin of the boxes [m].

    Returns
    -------
    ndarray of int, shape (K,)
    """
    lo = np.asarray(lower, dtype=float)[:, None, :] + margin  # (B, 1, 3)
    hi = np.asarray(upper, dtype=float)[:, None, :] - margin
    slack = np.minimum.reduce([np.minimum(np.asarray(p)[None] - lo, hi - np.asarray(p)[None]) for p in point_sets])
    return np.argmax(slack.min(axis=2), axis=0)


def best_box(scene: Scene, *point_sets: np.ndarray, margin: np.ndarray | float = 0.0) -> np.ndarray:
    """:func:`best_piece` over the scene's keep-in boxes.

    Parameters
    ----------
    scene : Scene
        Has at least one keep-in box.
    *point_sets : ndarray, shape (K, 3)
        Points [m]; the k-th points of all sets are scored together.
    margin : ndarray of shape (3,) or float
        Inward margin of the boxes [m].

    Returns
    -------
    ndarray of int, shape (K,)

    Raises
    ------
    ValueError
        When the scene has no keep-in box.
    """
    if not scene.keep_in:
        raise ValueError("the scene has no keep-in box")
    return best_piece(np.array([b.lower for b in scene.keep_in]), np.array([b.upper for b in scene.keep_in]),
                      *point_sets, margin=margin)
