"""Ellipsoid-on-ellipsoid overlap ([ReSWARM2023] §4.2.2) in the form of Gilitschenski & Hanebeck.

Two ellipsoids ``E1 = {x : (x - c1)ᵀ Σ1⁻¹ (x - c1) <= 1}`` and ``E2 = {x : (x - c2)ᵀ Σ2⁻¹ (x - c2) <= 1}``
(Σ1 positive definite, Σ2 positive semidefinite; Σ2 = 0 is a point) have overlapping interiors if and only if
``δ = c2 - c1`` lies in the interior of the Minkowski sum ``E(Σ1) ⊕ E(Σ2)``. That sum is the intersection of the
one-parameter family of ellipsoids (Kurzhanski & Vályi 1997; Gilitschenski & Hanebeck 2014)

    E_s = {δ : δᵀ M(s) δ <= 1},   M(s) = [Σ1 / (1 - s) + Σ2 / s]⁻¹,   0 < s < 1,

each of which *contains* the sum. Hence the ellipsoids are separated (or at most touch) if and only if

    g*(δ) = max_{0 < s < 1} g(s; δ) >= 1,   g(s; δ) = δᵀ M(s) δ,

and the function ``g(·; δ)`` is concave on (0, 1) (Gilitschenski & Hanebeck, "A robust computational test for
overlap of two arbitrary-dimensional ellipsoids in fault-detection of Kalman filters", FUSION 2014), so its maximum
is found by a one-dimensional search. With ``Σ1 = L Lᵀ`` and the eigen-decomposition
``L⁻¹ Σ2 L⁻ᵀ = V diag(λ) Vᵀ`` (the generalised eigenvalues of the pair), ``w = Vᵀ L⁻¹ δ`` gives

    g(s; δ) = Σ_i w_i² s (1 - s) / (s + λ_i (1 - s)).

For a point robot (Σ2 = 0) ``g* = δᵀ Σ1⁻¹ δ``: the ellipsoid-on-point test of [Doerr2021] Eq. 12. For two spheres
(radii a, r) ``g* = |δ|² / (a + r)²``: the distance test. ``sqrt(g*)`` is the factor by which both ellipsoids must
be scaled about their centres to touch, a dimensionless clearance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Newton iterations at most (quadratic convergence: 5-8 are typical).
_MAX_NEWTON = 60
#: Generalised eigenvalues below this are raised to it (a robot flat along some axis is still a valid limit).
_LAMBDA_FLOOR = 1e-300


@dataclass(frozen=True)
class EllipsoidPair:
    """Precomputed geometry of a static ellipsoid (Σ1, centre c) against a robot ellipsoid Σ2 (same frame).

    Attributes
    ----------
    center : ndarray, shape (3,)
        Centre c of the static ellipsoid [m].
    transform : ndarray, shape (3, 3)
        ``T = Vᵀ L⁻¹`` with ``Σ1 = L Lᵀ``; ``w = T δ``.
    eigenvalues : ndarray, shape (3,)
        Generalised eigenvalues λ >= 0 of (Σ2, Σ1); all zero for a point robot.
    point_robot : bool
        True when Σ2 = 0 (then ``g* = |w|²`` exactly).
    """

    center: np.ndarray
    transform: np.ndarray
    eigenvalues: np.ndarray
    point_robot: bool

    @classmethod
    def build(cls, center: np.ndarray, sigma_static: np.ndarray, sigma_robot: np.ndarray) -> EllipsoidPair:
        """Pair of a static ellipsoid ``Σ1`` (= P⁻¹ of a keep-out zone) centred at ``center`` and a robot ``Σ2``.

        Parameters
        ----------
        center : ndarray, shape (3,)
            Centre of the static ellipsoid [m].
        sigma_static : ndarray, shape (3, 3)
            Σ1, positive definite.
        sigma_robot : ndarray, shape (3, 3)
            Σ2, positive semidefinite (0 for a point robot).

        Returns
        -------
        EllipsoidPair
        """
        chol = np.linalg.cholesky(np.asarray(sigma_static, dtype=float))
        l_inv = np.linalg.inv(chol)
        sigma_robot = np.asarray(sigma_robot, dtype=float)
        point = not np.any(sigma_robot)
        if point:
            lam, vec = np.zeros(3), np.eye(3)
        else:
            reduced = l_inv @ sigma_robot @ l_inv.T
            lam, vec = np.linalg.eigh(0.5 * (reduced + reduced.T))
            lam = np.clip(lam, 0.0, None)
        return cls(np.asarray(center, dtype=float).reshape(3), vec.T @ l_inv, lam, point)

    def weights(self, s: np.ndarray | float) -> np.ndarray:
        """``d_i(s) = s (1 - s) / (s + λ_i (1 - s))``, shape (..., 3); ``M(s) = Tᵀ diag(d(s)) T``.

        Parameters
        ----------
        s : float or ndarray, shape (...)
            Family parameter in (0, 1).

        Returns
        -------
        ndarray, shape (..., 3)
        """
        s = np.asarray(s, dtype=float)[..., None]
        if self.point_robot:
            return np.broadcast_to(np.ones(3), (*s.shape[:-1], 3)).copy()
        return s * (1.0 - s) / (s + self.eigenvalues * (1.0 - s))

    def shape_matrix(self, s: np.ndarray | float) -> np.ndarray:
        """``M(s)`` of the outer ellipsoid ``E_s`` of the Minkowski sum, shape (..., 3, 3).

        Parameters
        ----------
        s : float or ndarray, shape (...)
            Family parameter in (0, 1).

        Returns
        -------
        ndarray, shape (..., 3, 3)
        """
        d = self.weights(s)
        return np.einsum("ai,...a,aj->...ij", self.transform, d, self.transform)

    def clearance_sq(self, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``g*(δ)`` and its maximiser ``s*`` for offsets ``δ = p - c`` of shape (..., 3).

        ``g* >= 1``: separated or touching; ``g* < 1``: the interiors overlap. ``s*`` is 0 for a point robot.

        Parameters
        ----------
        delta : ndarray, shape (..., 3)
            Offsets ``p - c`` [m].

        Returns
        -------
        g : ndarray, shape (...)
            ``g*(δ)``.
        s : ndarray, shape (...)
            ``s*``.
        """
        w2 = np.einsum("ij,...j->...i", self.transform, np.asarray(delta, dtype=float)) ** 2
        if self.point_robot:
            return w2.sum(axis=-1), np.zeros(w2.shape[:-1])
        return max_clearance_sq(w2, self.eigenvalues)


def _g(s: np.ndarray, w2: np.ndarray, lam: np.ndarray) -> np.ndarray:
    s = s[..., None]
    return np.sum(w2 * s * (1.0 - s) / (s + lam * (1.0 - s)), axis=-1)


def max_clearance_sq(w2: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Maximise the concave ``g(s) = Σ w_i² s(1-s)/D_i``, ``D_i = λ_i + (1-λ_i) s``, over (0, 1).

    Safeguarded Newton on ``g'(s) = Σ w_i² (λ_i - 2λ_i s - (1-λ_i) s²)/D_i²`` with ``g''(s) = -2 Σ w_i² λ_i/D_i³``
    (< 0: strictly concave for λ > 0), keeping a bracket ``g'(lo) > 0 > g'(hi)`` and bisecting whenever a Newton
    step would leave it. Vectorised over the leading axes of ``w2`` (λ broadcasts against ``w2``).

    Parameters
    ----------
    w2 : ndarray, shape (..., 3)
        ``w_i²``, the squared offset in the pair's reduced coordinates (:meth:`EllipsoidPair.clearance_sq`).
    lam : ndarray, shape (3,) or broadcastable to ``w2``
        Generalised eigenvalues ``λ_i`` of the pair (floored at a small positive value).

    Returns
    -------
    g : ndarray, shape (...)
        ``max_s g(s)``.
    s : ndarray, shape (...)
        The maximiser in (0, 1).
    """
    lam = np.broadcast_to(np.clip(lam, _LAMBDA_FLOOR, None), w2.shape)
    shape = w2.shape[:-1]
    lo = np.zeros(shape)
    hi = np.ones(shape)
    s = np.full(shape, 0.5)
    for _ in range(_MAX_NEWTON):
        sc = s[..., None]
        den = lam + (1.0 - lam) * sc
        slope = np.sum(w2 * (lam - 2.0 * lam * sc - (1.0 - lam) * sc * sc) / den**2, axis=-1)
        curv = -2.0 * np.sum(w2 * lam / den**3, axis=-1)
        lo = np.where(slope > 0.0, s, lo)
        hi = np.where(slope > 0.0, hi, s)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(curv < 0.0, slope / curv, 0.0)
        newton = s - step
        inside = (newton >= lo) & (newton <= hi) & np.isfinite(newton)
        s_new = np.where(inside, newton, 0.5 * (lo + hi))
        done = np.abs(s_new - s) <= 1e-15 + 1e-13 * s
        s = s_new
        if np.all(done):
            break
    return _g(s, w2, lam), s


def ellipsoids_overlap(
    center1: np.ndarray, sigma1: np.ndarray, center2: np.ndarray, sigma2: np.ndarray
) -> bool:
    """True when the interiors of two ellipsoids ``(x - c)ᵀ Σ⁻¹ (x - c) < 1`` overlap (Σ1 definite, Σ2 >= 0).

    Parameters
    ----------
    center1 : ndarray, shape (3,)
    sigma1 : ndarray, shape (3, 3)
        Σ1, positive definite.
    center2 : ndarray, shape (3,)
    sigma2 : ndarray, shape (3, 3)
        Σ2, positive semidefinite (0 for a point).

    Returns
    -------
    bool
    """
    pair = EllipsoidPair.build(center1, sigma1, sigma2)
    g, _ = pair.clearance_sq(np.asarray(center2, dtype=float) - pair.center)
    return bool(g < 1.0)
