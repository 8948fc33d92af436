"""Small vector arithmetic shared by the hot paths of control and planning."""

from __future__ import annotations

import numpy as np

#: Component orders of the cross product: ``(a × b)_i = a_{P_i} b_{R_i} − a_{R_i} b_{P_i}``.
_P = np.array([1, 2, 0])
_R = np.array([2, 0, 1])


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of (..., 3) rows (broadcast), without its overhead.

    Per component the same products and difference as ``np.cross`` (``a_1 b_2 − a_2 b_1``, ``a_2 b_0 − a_0 b_2``,
    ``a_0 b_1 − a_1 b_0``), so the same values bit for bit; all three components in one call.

    Parameters
    ----------
    a, b : ndarray, shape (..., 3)
        Vectors (any unit); their leading shapes broadcast.

    Returns
    -------
    ndarray, shape (..., 3)
        ``a × b`` row by row.
    """
    return np.asarray(a[..., _P] * b[..., _R] - a[..., _R] * b[..., _P])
