"""Trajectory polish, part 2: the geometry of the convexification, keep-out half-spaces and keep-in bounds of
each piece (see :mod:`oacli.planning.polish`)."""

from __future__ import annotations

import numpy as np

from oacli.geometry.collision import CollisionChecker
from oacli.geometry.halfspaces import KeepOutZone, supporting_halfspaces
from oacli.geometry.vectors import cross_rows

#: Stand-in for an unbounded keep-in coordinate [m] (a scene without keep-in boxes).
_FAR_M = 1e6


def _closest_on_segments(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Point of least norm on each segment ``a[i] → b[i]``, shape (K, 3)."""
    d = b - a
    dd = np.einsum("ki,ki->k", d, d)
    t = np.zeros(dd.shape)
    np.divide(-np.einsum("ki,ki->k", a, d), dd, out=t, where=dd > 1e-300)
    np.clip(t, 0.0, 1.0, out=t)  # also maps an overflow to ±inf onto the segment's ends
    return a + t[:, None] * d


def min_norm_on_triangles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Point of least Euclidean norm in each triangle ``conv{a, b, c}`` (degenerate triangles allowed), (K, 3).

    Exact: the minimum lies on an edge or, if the origin projects inside the triangle's plane region, at that
    projection; every candidate is in the triangle, and the least-norm one is returned.

    Parameters
    ----------
    a, b, c : ndarray, shape (K, 3)
        Corners.

    Returns
    -------
    ndarray, shape (K, 3)
    """
    cands = [_closest_on_segments(a, b), _closest_on_segments(b, c), _closest_on_segments(a, c)]
    nrm = cross_rows(b - a, c - a)
    n2 = np.einsum("ki,ki->k", nrm, nrm)
    scale = np.maximum.reduce([np.einsum("ki,ki->k", e, e) for e in (b - a, c - a, c - b)]) + 1e-300
    face = n2 > 1e-12 * scale * scale
    if np.any(face):
        af, bf, cf, nf = a[face], b[face], c[face], nrm[face]
        p = nf * (np.einsum("ki,ki->k", af, nf) / n2[face])[:, None]
        # Barycentric signs: p inside iff it is on the inner side of the three edges.
        s1 = np.einsum("ki,ki->k", cross_rows(bf - af, p - af), nf)
        s2 = np.einsum("ki,ki->k", cross_rows(cf - bf, p - bf), nf)
        s3 = np.einsum("ki,ki->k", cross_rows(af - cf, p - cf), nf)
        inside = (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
        proj = np.full_like(a, np.inf)
        idx = np.flatnonzero(face)[inside]
        proj[idx] = p[inside]
        cands.append(proj)
    stack = np.stack(cands, axis=1)  # (K, C, 3)
    norms = np.sqrt((stack * stack).sum(axis=2))  # np.linalg.norm's arithmetic
    return stack[np.arange(a.shape[0]), np.argmin(norms, axis=1)]


def keep_out_halfspaces(
    zone: KeepOutZone, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, clearance_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Half-spaces ``nᵀ p >= b`` (unit n) that keep pieces with control points ``p0, p1, p2`` (K, 3) out of a zone.

    Parameters
    ----------
    zone : KeepOutZone
    p0, p1, p2 : ndarray, shape (K, 3)
        Control points [m] of the K pieces (start, mid-piece control point, end).
    clearance_m : float
        Extra clearance [m].

    Returns
    -------
    normal : ndarray, shape (K, 3)
    offset : ndarray, shape (K,)
        ``b``: the support of the zone (robot included) in direction n plus the clearance (module docstring).
    margin : ndarray, shape (K,)
        ``min_P nᵀ P − b`` over the three control points [m]: >= 0 where these pieces satisfy their half-space.
    """
    return keep_out_halfspaces_of_zones([zone], p0, p1, p2, clearance_m)[0]


def keep_out_halfspaces_of_zones(
    zones: list[KeepOutZone], p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, clearance_m: float
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`keep_out_halfspaces` for every zone, the least-norm points of all zones in one vectorised call.

    Parameters
    ----------
    zones : list of KeepOutZone
    p0, p1, p2 : ndarray, shape (K, 3)
        Control points [m] of the K pieces.
    clearance_m : float
        Extra clearance [m].

    Returns
    -------
    list of (normal, offset, margin)
        Per zone, as :func:`keep_out_halfspaces` returns them.
    """
    if not zones:
        return []
    k = p0.shape[0]
    w = [np.concatenate([(p - z.center) @ z.metric.T for z in zones]) for p in (p0, p1, p2)]  # (J K, 3) each
    w_star = min_norm_on_triangles(*w)
    norm = np.sqrt((w_star * w_star).sum(axis=1))  # np.linalg.norm's arithmetic
    # The hull contains the centre (no direction): point from the centre to the hull's mean instead.
    m = np.where(norm[:, None] > 1e-12, w_star, (w[0] + w[1] + w[2]) / 3.0)
    m = np.where(np.sqrt((m * m).sum(axis=1))[:, None] > 1e-12, m, np.array([1.0, 0.0, 0.0]))
    out = []
    for j, zone in enumerate(zones):
        n, offset = supporting_halfspaces(zone, m[j * k:(j + 1) * k], clearance_m)
        current = np.minimum.reduce([np.einsum("ki,ki->k", n, p) for p in (p0, p1, p2)])
        out.append((n, offset, current - offset))
    return out


def keep_in_bounds(checker: CollisionChecker, p0: np.ndarray, p1: np.ndarray,
                   p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per piece, the keep-in box its control points must stay in.

    The first box holding all three of them, else the box holding most of them (the buffer then absorbs the
    difference); without keep-in boxes, bounds far outside any scene.

    Parameters
    ----------
    checker : CollisionChecker
    p0, p1, p2 : ndarray, shape (K, 3)
        Control points [m] of the K pieces (start, mid-piece control point, end).

    Returns
    -------
    lower, upper : ndarray, shape (K, 3)
    """
    boxes = checker.scene.keep_in
    k = p0.shape[0]
    if not boxes:
        return np.full((k, 3), -_FAR_M), np.full((k, 3), _FAR_M)
    lo = np.array([b.lower for b in boxes])
    hi = np.array([b.upper for b in boxes])
    count = sum(np.all((p[:, None, :] >= lo) & (p[:, None, :] <= hi), axis=2).astype(int) for p in (p0, p1, p2))
    chosen = np.argmax(count, axis=1)  # first box with the most control points inside
    return lo[chosen], hi[chosen]
