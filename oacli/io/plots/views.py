"""Projected views of a flown path and the keep-out zones that cannot mislead (issue 33 item 2).

A path that clears a keep-out ellipsoid in 3-D may cross its shadow in a projection (segment 3 of the ISS mission
passes *below* the keep-out: crossing in x-y, clear in x-z). :func:`choose_views` therefore gives the three axis
views (top x-y, side x-z, front y-z) and, when the path clears an ellipsoid in 3-D but crosses its shadow in every
axis view, a fourth view along the direction that shows the clearance best (:func:`clearing_direction`).

Geometry: the orthographic shadow of ``(p − c)ᵀ P (p − c) <= 1`` on the plane with orthonormal in-plane axes
``u, v`` (rows of ``basis``) and view direction ``d = u × v`` is the ellipse of the 2×2 matrix ``B P⁻¹ Bᵀ``
(:func:`shadow_ellipse`); a point ``p`` projects into the shadow iff the line ``p + s d`` meets the ellipsoid, i.e.
``min_s f(p + s d) = eᵀPe − (dᵀPe)² / (dᵀPd) < 1`` with ``e = p − c`` (:func:`shadow_depth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry import Scene
from oacli.geometry.shapes import Ellipsoid
from oacli.geometry.verify import point_ellipsoid_distance

#: Axis views: name -> world axes (x, y, z = 0, 1, 2) of the horizontal and vertical plot axes.
AXIS_VIEWS: dict[str, tuple[int, int]] = {"top": (0, 1), "side": (0, 2), "front": (1, 2)}
#: Keep-outs whose surface comes nearer the path than this [m] (plus the robot radius) are drawn and counted.
NEAR_M = 0.5
#: Directions tried by :func:`clearing_direction` (a Fibonacci half sphere).
SEARCH_DIRECTIONS = 1500
#: Path points used by the direction search (the path is thinned evenly; the closest points are always kept).
SEARCH_POINTS = 600


@dataclass(frozen=True)
class View:
    """One orthographic view.

    Attributes
    ----------
    name : str
        ``top``, ``side``, ``front`` or ``clearance``.
    basis : ndarray, shape (2, 3)
        Orthonormal rows: the world directions of the plot's horizontal and vertical axes.
    labels : tuple of str
        Axis labels with units.
    """

    name: str
    basis: np.ndarray
    labels: tuple[str, str]

    @property
    def direction(self) -> np.ndarray:
        """The viewing direction ``u × v`` (unit)."""
        return np.cross(self.basis[0], self.basis[1])

    def project(self, points_m: np.ndarray) -> np.ndarray:
        """Plane coordinates [m] of points ``(N, 3)`` -> ``(N, 2)``."""
        return np.asarray(points_m, dtype=float).reshape(-1, 3) @ self.basis.T


def axis_view(name: str) -> View:
    """The axis view ``name`` of :data:`AXIS_VIEWS`."""
    i, j = AXIS_VIEWS[name]
    basis = np.eye(3)[[i, j]]
    axes = "xyz"
    return View(name, basis, (f"{axes[i]} [m]", f"{axes[j]} [m]"))


def shadow_depth(points_m: np.ndarray, ellipsoid: Ellipsoid, direction: np.ndarray) -> np.ndarray:
    """``min_s f(p + s d)`` per point, ``f(x) = (x − c)ᵀ P (x − c)``: below 1 where the point's projection along
    ``direction`` lies inside the ellipsoid's shadow (module docstring).

    Parameters
    ----------
    points_m : ndarray, shape (N, 3)
    ellipsoid : Ellipsoid
    direction : ndarray, shape (3,) or (3, D)
        Viewing direction(s), unit.

    Returns
    -------
    ndarray, shape (N,) or (N, D)
    """
    e = np.asarray(points_m, dtype=float).reshape(-1, 3) - ellipsoid.center
    pe = e @ ellipsoid.shape
    f0 = np.einsum("ij,ij->i", e, pe)
    d = np.asarray(direction, dtype=float)
    dpd = np.einsum("i...,ij,j...->...", d, ellipsoid.shape, d)
    dpe = pe @ d
    return (f0[:, None] - dpe.reshape(len(e), -1) ** 2 / np.reshape(dpd, (1, -1))).reshape(dpe.shape)


def depth_3d(points_m: np.ndarray, ellipsoid: Ellipsoid) -> np.ndarray:
    """``f(p)`` per point: below 1 inside the ellipsoid."""
    e = np.asarray(points_m, dtype=float).reshape(-1, 3) - ellipsoid.center
    return np.einsum("ij,jk,ik->i", e, ellipsoid.shape, e)


def shadow_ellipse(ellipsoid: Ellipsoid, basis: np.ndarray,
                   grow_m: float = 0.0) -> tuple[float, float, float, float, float]:
    """The shadow of ``ellipsoid`` on the plane of ``basis`` (rows u, v): centre (2), width, height [m] and angle
    [deg] of :class:`matplotlib.patches.Ellipse`; semi-axes grown by ``grow_m`` (the robot radius: an ellipse that
    holds the shadow grown by a disc of that radius).

    Parameters
    ----------
    ellipsoid : Ellipsoid
    basis : ndarray, shape (2, 3)
    grow_m : float

    Returns
    -------
    tuple of float
    """
    b = np.asarray(basis, dtype=float).reshape(2, 3)
    cov = b @ np.linalg.inv(ellipsoid.shape) @ b.T  # the shadow is the ellipse of B P⁻¹ Bᵀ
    eig, vec = np.linalg.eigh(cov)
    semi = np.sqrt(np.maximum(eig, 0.0)) + grow_m
    angle = float(np.degrees(np.arctan2(vec[1, 1], vec[0, 1])))
    cx, cy = b @ ellipsoid.center
    return float(cx), float(cy), 2.0 * float(semi[1]), 2.0 * float(semi[0]), angle


def near_keep_outs(scene: Scene | None, path_m: np.ndarray, robot_radius_m: float = 0.0) -> list[Ellipsoid]:
    """The keep-out zones whose surface the path comes within :data:`NEAR_M` plus the robot radius of [m]."""
    if scene is None or not len(path_m):
        return []
    near = []
    for zone in scene.keep_out:
        semi, rot = zone.principal_axes()
        if float(point_ellipsoid_distance(path_m, zone.center, semi, rot).min()) < NEAR_M + robot_radius_m:
            near.append(zone)
    return near


def _half_sphere(n: int) -> np.ndarray:
    """``n`` unit directions spread evenly over the half sphere ``z >= 0`` (Fibonacci lattice), shape (3, n)."""
    k = np.arange(n) + 0.5
    z = k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    r = np.sqrt(1.0 - z**2)
    return np.vstack([r * np.cos(phi), r * np.sin(phi), z])


def _thin(path_m: np.ndarray, zones: list[Ellipsoid], limit: int) -> np.ndarray:
    pts = np.asarray(path_m, dtype=float).reshape(-1, 3)
    if len(pts) <= limit:
        return pts
    keep = set(np.linspace(0, len(pts) - 1, limit).astype(int).tolist())
    for zone in zones:
        depth = depth_3d(pts, zone)
        keep.update(np.argsort(depth)[:50].tolist())
    return pts[sorted(keep)]


def clearing_direction(path_m: np.ndarray, zones: list[Ellipsoid]) -> tuple[np.ndarray, float]:
    """The viewing direction along which the path's projection keeps farthest outside the shadows of ``zones``.

    Parameters
    ----------
    path_m : ndarray, shape (N, 3)
    zones : list of Ellipsoid

    Returns
    -------
    direction : ndarray, shape (3,)
    depth : float
        The smallest :func:`shadow_depth` along it (> 1: the view shows the path clear of every zone).
    """
    pts = _thin(path_m, zones, SEARCH_POINTS)
    dirs = _half_sphere(SEARCH_DIRECTIONS)
    score = np.full(dirs.shape[1], np.inf)
    for zone in zones:
        score = np.minimum(score, shadow_depth(pts, zone, dirs).min(axis=0))
    best = int(np.argmax(score))
    return dirs[:, best], float(score[best])


def oblique_view(direction: np.ndarray) -> View:
    """The view along ``direction``: horizontal axis ``u`` horizontal in the world (⊥ z) when possible, ``v``
    completing ``(u, v, d)`` to a right-handed frame."""
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    u = np.cross(np.array([0.0, 0.0, 1.0]), d)
    if np.linalg.norm(u) < 1e-6:
        u = np.array([1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    if v[2] < 0:  # world up drawn upwards (u and v both flipped: d = u × v is kept)
        u, v = -u, -v
    fmt = lambda w: "(" + ", ".join(f"{c:+.3f}" for c in w) + ")"  # noqa: E731
    return View("clearance", np.vstack([u, v]), (f"along {fmt(u)} [m]", f"along {fmt(v)} [m]"))


def choose_views(path_m: np.ndarray, scene: Scene | None,
                 robot_radius_m: float = 0.0) -> tuple[list[View], list[Ellipsoid]]:
    """The views of a flown path: top, side, front, and a clearance view when needed (module docstring).

    Parameters
    ----------
    path_m : ndarray, shape (N, 3)
        The flown positions [m].
    scene : Scene, optional
    robot_radius_m : float
        Widens the reach of :func:`near_keep_outs` [m].

    Returns
    -------
    views : list of View
    zones : list of Ellipsoid
        The keep-outs near the path.
    """
    views = [axis_view(name) for name in AXIS_VIEWS]
    pts = np.asarray(path_m, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    zones = near_keep_outs(scene, pts, robot_radius_m)
    hidden = [z for z in zones if float(depth_3d(pts, z).min()) >= 1.0
              and all(float(shadow_depth(pts, z, v.direction).min()) < 1.0 for v in views)]
    if hidden:
        direction, depth = clearing_direction(pts, hidden)
        if depth >= 1.0:
            views.append(oblique_view(direction))
    return views, zones
