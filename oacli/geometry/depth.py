"""How deep a position violates the workspace: Euclidean depth outside the keep-in union and inside a keep-out zone.

Used to report a run's safety (:func:`oacli.metrics.safety_report`): a count of violating samples says *that* the
robot left the free space, the depth says *how far*.

* **Keep-in** (the robot's centre must lie in the union ``U`` of the closed boxes, as in
  :mod:`oacli.geometry.collision`; with a margin ``r`` it must lie in the erosion ``{p : B(p, r) ⊆ U}``): the
  depth is ``max(0, r − d(p, ∁U))`` for ``p`` in ``U`` and ``r + d(p, U)`` outside, i.e. how far the ball of
  radius ``r`` around ``p`` sticks out of ``U``. ``d(p, U)`` is the smallest distance to a box. ``d(p, ∁U)`` is
  exact too: the box faces cut space into a grid of cells, each wholly inside or outside ``U``, and the complement
  is the union of the outside cells (unbounded ones included), so the distance is the smallest distance to an
  outside cell. Eroding each box separately instead would open false gaps where boxes meet.
* **Keep-out** (the robot, a ball of radius ``r`` about its centre, must not overlap an ellipsoid ``E``): the depth
  is ``max(0, r − sd(p, E))`` with ``sd`` the signed Euclidean distance to the surface of ``E``
  (:func:`oacli.geometry.verify.point_ellipsoid_distance`), i.e. the penetration into ``E ⊕ B(0, r)``.
"""

from __future__ import annotations

import numpy as np

from oacli.geometry.shapes import Scene
from oacli.geometry.verify import point_ellipsoid_distance

#: Points per block when distances to many cells are evaluated at once (bounds the memory use).
_BLOCK = 256


def _box_distance(points: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Euclidean distance from points (M, 3) to closed boxes (n, 3) (infinite bounds allowed), shape (M, n)."""
    below = np.maximum(lower[None] - points[:, None], 0.0)
    above = np.maximum(points[:, None] - upper[None], 0.0)
    gap = np.maximum(below, above)
    return np.sqrt(np.sum(gap * gap, axis=-1))


def _as_boxes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    lower = np.array([b.lower for b in scene.keep_in], dtype=float).reshape(-1, 3)
    upper = np.array([b.upper for b in scene.keep_in], dtype=float).reshape(-1, 3)
    return lower, upper


def distance_outside_boxes(points: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``d(p, U)`` [m] for the union U of closed boxes ``lower <= p <= upper`` (0 inside).

    Parameters
    ----------
    points : ndarray, shape (..., 3)
        Positions [m].
    lower, upper : ndarray, shape (b, 3)
        Opposite corners of the boxes [m].

    Returns
    -------
    ndarray, shape (...,)
        Euclidean distance to the union [m].
    """
    p = np.asarray(points, dtype=float)
    flat = p.reshape(-1, 3)
    out = np.empty(flat.shape[0])
    for i in range(0, flat.shape[0], _BLOCK):
        out[i : i + _BLOCK] = _box_distance(flat[i : i + _BLOCK], lower, upper).min(axis=1)
    return out.reshape(p.shape[:-1])


def outside_cells(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cells of the face grid that lie outside the union of the boxes, as ``(lower, upper)`` arrays (c, 3).

    Per axis the box faces ``c_0 < ... < c_m`` give the intervals ``(−∞, c_0], [c_0, c_1], ..., [c_m, ∞)``; a
    bounded cell is inside the union exactly when its centre is (box faces are grid lines); unbounded cells are
    outside.

    Parameters
    ----------
    lower, upper : ndarray, shape (b, 3)
        Opposite corners of the boxes [m].

    Returns
    -------
    tuple of ndarray, each shape (c, 3)
        Lower and upper corners of the outside cells (infinite where unbounded).
    """
    edges = [np.concatenate([[-np.inf], np.unique(np.r_[lower[:, k], upper[:, k]]), [np.inf]]) for k in range(3)]
    lo = np.stack(np.meshgrid(*(e[:-1] for e in edges), indexing="ij"), axis=-1).reshape(-1, 3)
    hi = np.stack(np.meshgrid(*(e[1:] for e in edges), indexing="ij"), axis=-1).reshape(-1, 3)
    bounded = np.all(np.isfinite(lo) & np.isfinite(hi), axis=1)
    centre = np.where(bounded[:, None], 0.5 * (np.nan_to_num(lo) + np.nan_to_num(hi)), 0.0)
    inside = bounded & np.any(np.all((centre[:, None] >= lower[None]) & (centre[:, None] <= upper[None]), axis=-1),
                              axis=1)
    return lo[~inside], hi[~inside]


def distance_to_complement(points: np.ndarray, lower: np.ndarray, upper: np.ndarray, cap_m: float) -> np.ndarray:
    """``min(d(p, ∁U), cap_m)`` [m] for the union U of the boxes (0 outside U), shape (...,).

    Only cells within ``cap_m`` of a block of points are examined, so a small cap keeps it cheap.

    Parameters
    ----------
    points : ndarray, shape (..., 3)
        Positions [m].
    lower, upper : ndarray, shape (b, 3)
        Opposite corners of the boxes [m].
    cap_m : float
        Largest distance of interest [m].

    Returns
    -------
    ndarray, shape (...,)
        Distance to the complement of the union, capped [m].
    """
    p = np.asarray(points, dtype=float)
    flat = p.reshape(-1, 3)
    cell_lo, cell_hi = outside_cells(lower, upper)
    out = np.full(flat.shape[0], float(cap_m))
    for i in range(0, flat.shape[0], _BLOCK):
        block = flat[i : i + _BLOCK]
        near = np.all((cell_lo <= block.max(axis=0) + cap_m) & (cell_hi >= block.min(axis=0) - cap_m), axis=1)
        if np.any(near):
            d = _box_distance(block, cell_lo[near], cell_hi[near]).min(axis=1)
            out[i : i + _BLOCK] = np.minimum(d, cap_m)
    return out.reshape(p.shape[:-1])


def keep_in_depth(points: np.ndarray, scene: Scene, margin_m: float = 0.0) -> np.ndarray:
    """How far the ball of radius ``margin_m`` about each point sticks out of the keep-in union [m], shape (...,).

    0 where the ball lies inside the union (and everywhere when the scene has no keep-in box); ``d(p, U)`` for a
    centre outside with ``margin_m = 0`` (module docstring). Non-finite points get ``inf``.

    Parameters
    ----------
    points : ndarray, shape (..., 3)
        Positions [m].
    scene : Scene
        Its keep-in boxes.
    margin_m : float
        Radius of the ball that must stay inside [m].

    Returns
    -------
    ndarray, shape (...,)
        Depth outside the keep-in [m].
    """
    p = np.asarray(points, dtype=float)
    if not scene.keep_in:
        return np.zeros(p.shape[:-1])
    lower, upper = _as_boxes(scene)
    finite = np.all(np.isfinite(p), axis=-1)
    q = np.where(finite[..., None], p, 0.0)
    depth = distance_outside_boxes(q, lower, upper)
    outside = depth > 0.0
    depth = np.where(outside, depth + margin_m, 0.0)
    if margin_m > 0:
        inner = distance_to_complement(q, lower, upper, margin_m)
        depth = np.where(outside, depth, np.maximum(margin_m - inner, 0.0))
    return np.where(finite, depth, np.inf)


def keep_out_depth(points: np.ndarray, scene: Scene, robot_radius_m: float = 0.0) -> np.ndarray:
    """Deepest penetration of a ball of radius ``robot_radius_m`` about each point into a keep-out zone [m].

    ``max_j max(0, r − sd(p, E_j))`` (module docstring), shape (...,); 0 without keep-out zones; ``inf`` for
    non-finite points.

    Parameters
    ----------
    points : ndarray, shape (..., 3)
        Positions [m].
    scene : Scene
        Its keep-out ellipsoids.
    robot_radius_m : float
        Radius of the robot's ball [m].

    Returns
    -------
    ndarray, shape (...,)
        Penetration depth [m].
    """
    p = np.asarray(points, dtype=float)
    depth = np.zeros(p.shape[:-1])
    finite = np.all(np.isfinite(p), axis=-1)
    q = np.where(finite[..., None], p, 0.0)
    for e in scene.keep_out:
        semi, rot = e.principal_axes()
        depth = np.maximum(depth, robot_radius_m - point_ellipsoid_distance(q, e.center, semi, rot))
    return np.where(finite, depth, np.inf)
