"""Nearest-neighbour search in a transformed space where the planner's metric is Euclidean.

The LQR cost-to-go at a fixed horizon (:class:`oacli.planning.steering.LqrMetric`) and the weighted Euclidean
metric of kinodynamic RRT ([ReSWARM2023] Eq. 26) are both squared Euclidean distances after a linear change of
coordinates, so nearest and near-set queries are a vectorised scan of a growable (n, d) array: one
subtraction, one row-sum and an argmin or a partial sort. Up to a few ten thousand nodes that is faster than
rebuilding and querying a k-d tree in Python.
"""

from __future__ import annotations

import numpy as np


class PointIndex:
    """A growable set of points in R^d with exact nearest and radius queries (squared Euclidean distance).

    Parameters
    ----------
    dim : int
        Dimension d.
    capacity : int
        Initial capacity (doubled when full).
    """

    def __init__(self, dim: int, capacity: int = 1024) -> None:
        self._points = np.empty((max(int(capacity), 1), int(dim)))
        self._ids = np.empty(max(int(capacity), 1), dtype=np.int64)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def add(self, point: np.ndarray, ident: int) -> None:
        """Insert a point with an identifier (e.g. a tree node index).

        Parameters
        ----------
        point : ndarray, shape (d,)
        ident : int
            Identifier returned by the queries.
        """
        if self._n == self._points.shape[0]:
            self._points = np.concatenate([self._points, np.empty_like(self._points)])
            self._ids = np.concatenate([self._ids, np.empty_like(self._ids)])
        self._points[self._n] = point
        self._ids[self._n] = ident
        self._n += 1

    def distances_sq(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Identifiers and squared distances to ``query`` of every stored point.

        Parameters
        ----------
        query : ndarray, shape (d,)

        Returns
        -------
        ids : ndarray of int, shape (n,)
        d2 : ndarray, shape (n,)
            ``|p - query|²``.
        """
        diff = self._points[: self._n] - query
        return self._ids[: self._n], np.einsum("ij,ij->i", diff, diff)

    def nearest(self, query: np.ndarray) -> tuple[int, float]:
        """Identifier and squared distance of the nearest point (ties: the first inserted).

        Parameters
        ----------
        query : ndarray, shape (d,)

        Returns
        -------
        ident : int
        d2 : float
        """
        if self._n == 0:
            raise ValueError("the index is empty")
        ids, d2 = self.distances_sq(query)
        k = int(np.argmin(d2))
        return int(ids[k]), float(d2[k])

    def within(self, query: np.ndarray, radius_sq: float, max_count: int | None = None) -> np.ndarray:
        """Identifiers of the points with ``|p - query|² <= radius_sq``, nearest first (at most ``max_count``).

        Parameters
        ----------
        query : ndarray, shape (d,)
        radius_sq : float
            Squared radius.
        max_count : int, optional
            Keep only the nearest ``max_count``.

        Returns
        -------
        ndarray of int
            Identifiers, nearest first.
        """
        ids, d2 = self.distances_sq(query)
        hit = np.flatnonzero(d2 <= radius_sq)
        if hit.size == 0:
            return hit.astype(np.int64)
        if max_count is not None and hit.size > max_count:
            part = np.argpartition(d2[hit], max_count - 1)[:max_count]
            hit = hit[part]
        return ids[hit[np.argsort(d2[hit], kind="stable")]]
