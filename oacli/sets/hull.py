"""Convex hulls of point sets, returned as facet normals and hull vertices.

Used to turn a vertex (V-) description into an inequality (H-) description. The offsets of the inequalities are
NOT taken from the hull: callers compute them as support values over *all* points (or from exact support
functions), so the H-polytope always contains every point given, whatever rounding happened in the hull.

* 1-D: the interval ``[min, max]``.
* 2-D: Andrew's monotone chain with exact orientation tests; a point is dropped only when it makes no strict
  left turn (it lies inside or on an edge). Degenerate sets (a segment, a point) get the normals of their
  bounding rectangle along and across the segment, which describe them exactly. Minkowski sums of convex
  polygons by merging their edges in angular order.
* n-D: Qhull (``scipy.spatial.ConvexHull``); the set must be full-dimensional.
"""

from __future__ import annotations

from typing import cast

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull of 2-D ``points (k, 2)``, counter-clockwise, without collinear points.

    Returns an array of shape (h, 2): h ≥ 3 for a full-dimensional hull, 2 for a segment, 1 for a point.

    Parameters
    ----------
    points : ndarray, shape (k, 2)
        The points (any order, duplicates allowed).

    Returns
    -------
    ndarray, shape (h, 2)
        The hull's vertices, counter-clockwise.
    """
    pts = np.unique(np.asarray(points, dtype=float).reshape(-1, 2), axis=0)  # sorted by x, then y
    if pts.shape[0] <= 2:
        return pts
    lower: list[np.ndarray] = []
    for p in pts:
        while len(lower) >= 2 and _cross(lower[-2], lower[-1], p) <= 0.0:
            lower.pop()
        lower.append(p)
    upper: list[np.ndarray] = []
    for p in pts[::-1]:
        while len(upper) >= 2 and _cross(upper[-2], upper[-1], p) <= 0.0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])  # two points when all are collinear


def minkowski_sum_polygons(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Vertices of ``conv(p) ⊕ conv(q)`` for convex polygons given counter-clockwise (as from
    :func:`convex_hull_2d`), by merging their edges in angular order (linear time; no point is dropped by a
    tolerance: vertices are sums of input vertices up to rounding, collinear vertices may remain).

    Parameters
    ----------
    p, q : ndarray, shape (k, 2)
        Vertices of the two convex polygons, counter-clockwise; with fewer than 3 vertices either one is treated
        as a point set (the hull of all pairwise sums is returned).

    Returns
    -------
    ndarray, shape (h, 2)
        Vertices of the sum, counter-clockwise.
    """
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    if p.shape[0] < 3 or q.shape[0] < 3:
        return convex_hull_2d((p[:, None, :] + q[None, :, :]).reshape(-1, 2))

    def from_lowest(v: np.ndarray) -> np.ndarray:
        return np.roll(v, -int(np.lexsort((v[:, 0], v[:, 1]))[0]), axis=0)

    p, q = from_lowest(p), from_lowest(q)
    edges = np.vstack([np.roll(p, -1, axis=0) - p, np.roll(q, -1, axis=0) - q])
    angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), 2 * np.pi)
    steps = edges[np.argsort(angles, kind="stable")]
    return cast(np.ndarray, p[0] + q[0] + np.vstack([np.zeros(2), np.cumsum(steps[:-1], axis=0)]))


def minkowski_sum_linear_images(polygon: np.ndarray, maps: np.ndarray) -> np.ndarray:
    """Vertices of ``⊕_i M_i conv(polygon)`` for 2×2 matrices ``M_i``, by one merge of all edges in angular order.

    The sum of convex polygons is the polygon whose edges are all their edges sorted by angle, starting from the
    sum of their lowest vertices (the same edge merge as :func:`minkowski_sum_polygons`, done once for all terms
    instead of term by term). A map with a negative determinant reverses the orientation of the image, which is
    undone; a singular map falls back to the hull of its image (a segment or a point, as pairwise sums).

    Parameters
    ----------
    polygon : ndarray, shape (k, 2)
        Vertices of a convex polygon, counter-clockwise (as from :func:`convex_hull_2d`), k ≥ 3.
    maps : ndarray, shape (s, 2, 2)
        The linear maps.

    Returns
    -------
    ndarray, shape (h, 2)
        Points whose convex hull is the sum (every vertex of the sum is among them; collinear points may
        remain).
    """
    poly = np.asarray(polygon, dtype=float)
    mats = np.asarray(maps, dtype=float)
    det = mats[:, 0, 0] * mats[:, 1, 1] - mats[:, 0, 1] * mats[:, 1, 0]
    if poly.shape[0] < 3 or np.any(det == 0.0):  # degenerate: term-by-term sums
        points = convex_hull_2d(poly @ mats[0].T)
        for m in mats[1:]:
            points = minkowski_sum_polygons(points, convex_hull_2d(poly @ m.T))
        return points
    images = np.einsum("kj,sij->ski", poly, mats)  # (s, k, 2): rows poly @ M_iᵀ
    images[det < 0] = images[det < 0, ::-1]  # counter-clockwise again
    edges = (np.roll(images, -1, axis=1) - images).reshape(-1, 2)
    lowest = np.lexsort((images[..., 0], images[..., 1]), axis=-1)[:, 0]  # lowest y, then lowest x, per image
    start = images[np.arange(images.shape[0]), lowest].sum(axis=0)
    angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), 2 * np.pi)
    steps = edges[np.argsort(angles, kind="stable")]
    return cast(np.ndarray, start + np.vstack([np.zeros(2), np.cumsum(steps[:-1], axis=0)]))


def _unit_rows(a: np.ndarray) -> np.ndarray:
    return cast(np.ndarray, a / np.linalg.norm(a, axis=1, keepdims=True))


def _dedupe_normals(normals: np.ndarray) -> np.ndarray:
    """Drop repeated unit normals (equal to 12 decimals); dropping a repeat removes a duplicate inequality only."""
    _, idx = np.unique(np.round(normals, 12), axis=0, return_index=True)
    return normals[np.sort(idx)]


def hull_normals(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit outward facet normals and the hull vertices of a point set.

    Parameters
    ----------
    points : ndarray, shape (k, n)

    Returns
    -------
    normals : ndarray, shape (f, n)
        Unit outward normals; together with offsets ``max_i normals @ points[i]`` they describe the hull exactly
        (2-D normals are ordered counter-clockwise by angle).
    vertices : ndarray, shape (h, n)
        The points that are hull vertices.

    Raises
    ------
    ValueError
        For n ≥ 3 when the points do not span a full-dimensional set.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] == 0:
        raise ValueError(f"points: expected a non-empty (k, n) array, got shape {pts.shape}")
    n = pts.shape[1]
    if n == 1:
        lo, hi = pts.min(), pts.max()
        return np.array([[1.0], [-1.0]]), np.unique(np.array([[lo], [hi]]), axis=0)
    if n == 2:
        hull = convex_hull_2d(pts)
        if hull.shape[0] >= 3:
            edges = np.roll(hull, -1, axis=0) - hull
            normals = _unit_rows(np.column_stack([edges[:, 1], -edges[:, 0]]))
            return _dedupe_normals(normals), hull
        if hull.shape[0] == 2:
            d = hull[1] - hull[0]
            d = d / np.linalg.norm(d)
            perp = np.array([d[1], -d[0]])
            return np.vstack([perp, d, -perp, -d]), hull
        return np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]), hull
    try:
        qh = ConvexHull(pts)
    except QhullError as exc:
        raise ValueError(f"the points do not span a full-dimensional {n}-D set ({str(exc).splitlines()[0]})") from None
    normals = _dedupe_normals(_unit_rows(qh.equations[:, :n]))
    return normals, pts[qh.vertices]
