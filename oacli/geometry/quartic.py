"""Exact minima of quartic polynomials over an interval, for the continuous collision checks.

Along a piece of constant acceleration ``p(τ) = p0 + v0 τ + ½ a τ²`` the ellipsoid function
``(p(τ) − c)ᵀ P (p(τ) − c) − 1`` ([Doerr2021] Eqs. 12-14) is a quartic in τ: :func:`quartic_minimum` finds its
minimum over [0, 1] exactly from the real roots of the cubic derivative, and :func:`quartic_minimum_at_least_zero`
decides its sign first from the Bernstein coefficients (a cheap certificate). Used by
:mod:`oacli.geometry.collision`.
"""

from __future__ import annotations

import numpy as np


def quartic_minimum(coeffs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact minimum over ``s ∈ [0, 1]`` of quartics ``Σ_k c_k s^k``, vectorised.

    Parameters
    ----------
    coeffs : ndarray, shape (K, 5)
        ``c_0 .. c_4`` per row.

    Returns
    -------
    value : ndarray, shape (K,)
        ``min_{0<=s<=1} f(s)``.
    argmin : ndarray, shape (K,)
        A minimiser ``s``.

    Notes
    -----
    The minimum is at an end point or at a real root of ``f'(s) = c1 + 2c2 s + 3c3 s² + 4c4 s³``. The roots are
    the eigenvalues of the companion matrix (a quadratic or linear formula when the leading coefficients vanish),
    polished by two Newton steps; ``f`` is then evaluated at ``{0, 1}`` and at the real parts of all roots clipped
    to [0, 1]. Every candidate lies in [0, 1], so the result is never below the true minimum, and a root error δ
    changes it only by O(δ²).
    """
    c = np.asarray(coeffs, dtype=float)
    k = c.shape[0]
    d = np.stack([c[:, 1], 2.0 * c[:, 2], 3.0 * c[:, 3], 4.0 * c[:, 4]], axis=1)  # f' coefficients d0..d3
    scale = np.max(np.abs(d), axis=1) + 1e-300
    roots = np.zeros((k, 3))
    cubic = np.abs(d[:, 3]) > 1e-9 * scale
    quad = ~cubic & (np.abs(d[:, 2]) > 1e-12 * scale)
    lin = ~cubic & ~quad & (np.abs(d[:, 1]) > 1e-14 * scale)
    if np.any(cubic):
        dc = d[cubic]
        comp = np.zeros((dc.shape[0], 3, 3))
        comp[:, 0, :] = -dc[:, [2, 1, 0]] / dc[:, 3:4]
        comp[:, 1, 0] = 1.0
        comp[:, 2, 1] = 1.0
        roots[cubic] = np.linalg.eigvals(comp).real
    if np.any(quad):
        a2, a1, a0 = d[quad, 2], d[quad, 1], d[quad, 0]
        disc = np.sqrt(np.clip(a1 * a1 - 4.0 * a2 * a0, 0.0, None))
        roots[quad, 0] = (-a1 + disc) / (2.0 * a2)
        roots[quad, 1] = (-a1 - disc) / (2.0 * a2)
    if np.any(lin):
        roots[lin, 0] = -d[lin, 0] / d[lin, 1]
    roots = np.clip(np.nan_to_num(roots, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    for _ in range(2):  # Newton polish on f'
        r = roots
        fp = d[:, :1] + r * (d[:, 1:2] + r * (d[:, 2:3] + r * d[:, 3:4]))
        fpp = d[:, 1:2] + r * (2.0 * d[:, 2:3] + 3.0 * r * d[:, 3:4])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            step = np.where(np.abs(fpp) > 1e-300, fp / fpp, 0.0)
        roots = np.clip(np.where(np.isfinite(step), r - step, r), 0.0, 1.0)
    cand = np.concatenate([np.zeros((k, 1)), np.ones((k, 1)), roots], axis=1)
    vals = c[:, :1] + cand * (c[:, 1:2] + cand * (c[:, 2:3] + cand * (c[:, 3:4] + cand * c[:, 4:5])))
    i = np.argmin(vals, axis=1)
    rows = np.arange(k)
    return vals[rows, i], cand[rows, i]


#: Power-to-Bernstein basis change of a quartic on [0, 1]: ``b = BERNSTEIN @ c``.
BERNSTEIN = np.array(
    [
        [1.0, 0.0, 0.0, 0.0, 0.0],
        [1.0, 0.25, 0.0, 0.0, 0.0],
        [1.0, 0.5, 1.0 / 6.0, 0.0, 0.0],
        [1.0, 0.75, 0.5, 0.25, 0.0],
        [1.0, 1.0, 1.0, 1.0, 1.0],
    ]
)


def quartic_minimum_at_least_zero(coeffs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decide ``min_{[0,1]} f >= 0`` for quartics, cheaply where possible, exactly everywhere.

    The Bernstein coefficients of ``f`` on [0, 1] bound it from below (``f`` is their convex combination), so
    ``min b >= 0`` certifies ``f >= 0`` without finding roots; ``f(0) < 0`` or ``f(1) < 0`` (the first and last
    coefficients) disproves it. Only the rows left open go to :func:`quartic_minimum`.

    Parameters
    ----------
    coeffs : ndarray, shape (K, 5)
        ``c_0 .. c_4`` per row, as in :func:`quartic_minimum`.

    Returns
    -------
    nonnegative : ndarray of bool, shape (K,)
    minimum : ndarray, shape (K,)
        The exact minimum where it was computed, else the smaller end value (a witness) or +inf (certified).
    argmin : ndarray, shape (K,)
        A minimiser (or witness) in [0, 1] (NaN where certified).
    """
    c = np.asarray(coeffs, dtype=float)
    b = c @ BERNSTEIN.T
    certified = b.min(axis=1) >= 0.0
    ends = np.minimum(b[:, 0], b[:, 4])
    witness = ends < 0.0
    value = np.where(certified, np.inf, ends)
    arg = np.where(certified, np.nan, np.where(b[:, 0] <= b[:, 4], 0.0, 1.0))
    open_ = ~certified & ~witness
    if np.any(open_):
        v, a = quartic_minimum(c[open_])
        value[open_] = v
        arg[open_] = a
    return value >= 0.0, value, arg


def quadratic_form_coeffs(
    alpha: np.ndarray, beta: np.ndarray, gamma: np.ndarray, m: np.ndarray
) -> np.ndarray:
    """Coefficients (K, 5) of ``(α + β s + γ s²)ᵀ M (α + β s + γ s²) - 1``.

    With ``α = p0 − c``, ``β = v0 h`` and ``γ = ½ a h²`` this is the ellipsoid function
    ``(p(τ) − c)ᵀ P (p(τ) − c) − 1`` of [Doerr2021] Eqs. 12-14 along a constant-acceleration piece of duration ``h``,
    in the normalised time ``s = τ / h ∈ [0, 1]``; it is >= 0 outside the keep-out ellipsoid.

    Parameters
    ----------
    alpha, beta, gamma : ndarray, shape (K, 3)
        The position offset from the centre and the velocity and acceleration terms of each piece [m].
    m : ndarray, shape (K, 3, 3)
        Symmetric shape matrices ``P`` [1/m²] (the cross terms assume ``M = Mᵀ``).

    Returns
    -------
    ndarray, shape (K, 5)
        ``c_0 .. c_4`` (dimensionless) of ``Σ_k c_k s^k``, as :func:`quartic_minimum` takes them.
    """
    ma = np.einsum("kij,kj->ki", m, alpha)
    mb = np.einsum("kij,kj->ki", m, beta)
    mg = np.einsum("kij,kj->ki", m, gamma)
    out = np.empty((alpha.shape[0], 5))
    out[:, 0] = np.einsum("ki,ki->k", alpha, ma) - 1.0
    out[:, 1] = 2.0 * np.einsum("ki,ki->k", alpha, mb)
    out[:, 2] = np.einsum("ki,ki->k", beta, mb) + 2.0 * np.einsum("ki,ki->k", alpha, mg)
    out[:, 3] = 2.0 * np.einsum("ki,ki->k", beta, mg)
    out[:, 4] = np.einsum("ki,ki->k", gamma, mg)
    return out
