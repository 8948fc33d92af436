"""Robust positively invariant (RPI) sets of ``e⁺ = A_K e + w``, ``w ∈ W``.

* :func:`minimal_rpi_outer`: Raković, Kerrigan, Kouramas & Mayne 2005 ("Invariant approximations of the
  minimal robust positively invariant set", IEEE TAC 50(3)), Algorithm 1: the RPI outer ε-approximation
  ``F(α, s) = (1 − α)⁻¹ F_s`` of the minimal RPI set ``F_∞``, with ``F_s = ⊕_{i<s} A_Kⁱ W`` (their Eq. 2),
  ``α°(s) = max_i h_W((A_Kˢ)ᵀ f_i) / g_i`` (Eq. 11), ``A_Kˢ W ⊆ α W`` (Eq. 4) and one of two stopping rules:

  - ``"absolute"`` (the paper's Eq. 14): ``α ≤ ε / (ε + M(s))`` with ``M(s)`` of Eq. 13, so that
    ``F_∞ ⊆ F(α, s) ⊆ F_∞ ⊕ B_∞ⁿ(ε)`` (ε in state units);
  - ``"relative"``: ``α ≤ ε / (1 + ε)``, so that ``F_∞ ⊆ F(α, s) ⊆ (1 + ε) F_∞`` (ε dimensionless). It follows
    from ``F_s ⊆ F_∞`` (0 ∈ W), hence ``F(α, s) ⊆ (1 − α)⁻¹ F_∞``, and ``(1 − α)⁻¹ ≤ 1 + ε`` ⇔ ``α ≤ ε/(1 + ε)``
    (the scaling argument of the paper's Theorem 1; Mayne, Seron & Raković 2005 use such a Z as the tube
    cross-section). Unlike the absolute rule it does not depend on the size of W, so it bounds the tube's
    conservatism for a small W (the absolute ε = 0.005 of the ReSWARM flight code almost doubles a tube of a
    few millimetres).
* :func:`minimal_rpi_support`: the support function of ``F_∞`` itself, ``Σ_{k≥0} h_W((A_Kᵏ)ᵀ d)``, summed to a
  rigorous tail bound (an independent reference for ``F(α, s)`` and for the tube's conservatism).
* :func:`rpi_margins`: the robust invariance test facet by facet, ``h_Z(A_Kᵀ a_i) + h_W(a_i) ≤ b_i``.
* :func:`reduce_facets`: fewer facets for a 2-D RPI set, each removal verified to keep the set RPI and within
  ``(1 + growth)`` times the original (an outer approximation of ``F_∞`` that stays RPI).

The computation never caps the number of terms ``s`` silently: when ``max_terms`` is not enough it refuses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, cast

import numpy as np

from oacli.errors import InfeasibleError
from oacli.sets.hull import convex_hull_2d, hull_normals, minkowski_sum_linear_images
from oacli.sets.polytope import Polytope

EpsilonMode = Literal["absolute", "relative"]
"""Meaning of ε in :func:`minimal_rpi_outer`: a ∞-norm ball radius [state units] or a relative scale [-]."""

#: How many times ``max_terms`` the α-only iteration goes on when refusing, to say how many terms are needed.
_NEEDED_SEARCH_FACTOR = 20


@dataclass(frozen=True)
class RPIApproximation:
    """Result of :func:`minimal_rpi_outer`.

    Attributes
    ----------
    z : Polytope
        The RPI outer ε-approximation ``F(α, s)`` of the minimal RPI set.
    s : int
        Number of Minkowski-sum terms.
    alpha : float
        ``α°(s)``: ``A_Kˢ W ⊆ α W``.
    m_s : float
        ``M(s)`` of RKKM05 Eq. 13 [state units].
    epsilon : float
        Requested accuracy ε: radius of the ∞-norm ball [state units] (``mode == "absolute"``) or relative
        scale [-] (``mode == "relative"``).
    spectral_radius : float
        Spectral radius of ``A_K`` (< 1).
    mode : {"absolute", "relative"}
        The stopping rule used (see :func:`minimal_rpi_outer`).
    """

    z: Polytope
    s: int
    alpha: float
    m_s: float
    epsilon: float
    spectral_radius: float
    mode: EpsilonMode = "absolute"

    @property
    def facets(self) -> int:
        """Number of inequalities of ``z``."""
        return self.z.n_facets

    @property
    def absolute_accuracy(self) -> float:
        """``α M(s) / (1 − α)`` [state units]: ``F(α, s) ⊆ F_∞ ⊕ B_∞(·)`` holds with this radius (any mode)."""
        return self.alpha * self.m_s / (1.0 - self.alpha)

    @property
    def relative_accuracy(self) -> float:
        """``α / (1 − α)`` [-]: ``F(α, s) ⊆ (1 + ·) F_∞`` holds with this value (any mode)."""
        return self.alpha / (1.0 - self.alpha)

    @property
    def epsilon_achieved(self) -> float:
        """The accuracy actually reached in the requested sense (≤ ε): absolute or relative, by ``mode``."""
        return self.relative_accuracy if self.mode == "relative" else self.absolute_accuracy


class RPITermsError(InfeasibleError):
    """:func:`minimal_rpi_outer` needs more terms than allowed (exit code 3, like every InfeasibleError).

    Attributes
    ----------
    needed : int or None
        Terms the stopping rule needs (None: more than ``max_terms`` × 20, not searched further).
    max_terms : int
    spectral_radius : float
        Of ``A_K``: the closer to 1, the more terms.
    """

    def __init__(self, message: str, *, needed: int | None, max_terms: int, spectral_radius: float):
        super().__init__(message)
        self.needed = needed
        self.max_terms = max_terms
        self.spectral_radius = spectral_radius


def spectral_radius(a: np.ndarray) -> float:
    """Largest absolute eigenvalue of a square matrix.

    Parameters
    ----------
    a : ndarray, shape (n, n)

    Returns
    -------
    float
    """
    return float(np.max(np.abs(np.linalg.eigvals(np.asarray(a, dtype=float)))))


def minimal_rpi_outer(
    a_closed: np.ndarray,
    w: Polytope,
    epsilon: float,
    *,
    mode: EpsilonMode = "absolute",
    max_terms: int = 1000,
) -> RPIApproximation:
    """RPI outer ε-approximation of the minimal RPI set (Raković et al. 2005, Algorithm 1).

    Parameters
    ----------
    a_closed : ndarray, shape (n, n)
        Closed-loop matrix ``A_K = A + B K``; must be Schur stable.
    w : Polytope
        Disturbance set W (bounded, with the origin in its interior: every offset ``g_i > 0``).
    epsilon : float
        Accuracy ε > 0: with ``mode="absolute"`` the radius of the ∞-norm ball of Eq. 14 [state units]; with
        ``mode="relative"`` the scale of ``F(α, s) ⊆ (1 + ε) F_∞`` [-].
    mode : {"absolute", "relative"}
        Stopping rule: the paper's ``α ≤ ε / (ε + M(s))`` (default, reproduces the published example) or
        ``α ≤ ε / (1 + ε)`` (see the module docstring).
    max_terms : int
        Largest number of terms s allowed. Needing more raises; the set is never cut short.

    Returns
    -------
    RPIApproximation

    Raises
    ------
    InfeasibleError
        When ``A_K`` is not Schur stable or W does not contain the origin in its interior.
    RPITermsError
        (an InfeasibleError) When more than ``max_terms`` terms are needed to reach ε; ``needed`` says how many
        when found within 20 × ``max_terms`` (a cheap search: no set is built).
    """
    a_k = np.asarray(a_closed, dtype=float)
    n = a_k.shape[0]
    if a_k.shape != (n, n) or w.dim != n:
        raise ValueError(f"A_K must be square and match W's dimension ({w.dim}), got {a_k.shape}")
    if not epsilon > 0 or not np.isfinite(epsilon):
        raise ValueError(f"epsilon must be finite and > 0, got {epsilon}")
    if mode not in ("absolute", "relative"):
        raise ValueError(f"mode must be 'absolute' or 'relative', got {mode!r}")
    if int(max_terms) < 1:
        raise ValueError(f"max_terms must be >= 1, got {max_terms}")
    rho = spectral_radius(a_k)
    if rho >= 1.0:
        raise InfeasibleError(
            f"the ancillary closed loop A + BK is not Schur stable (spectral radius {rho:.6g} >= 1): "
            "no bounded robust positively invariant set exists; choose another ancillary gain"
        )
    if np.any(w.b <= 0.0):
        raise InfeasibleError(
            "the disturbance set W does not contain the origin in its interior (an offset g_i <= 0): "
            "Raković et al. 2005 Algorithm 1 needs 0 ∈ int W"
        )
    s, alpha, m_s = _terms_needed(a_k, w, float(epsilon), mode, int(max_terms) * _NEEDED_SEARCH_FACTOR)
    if s is None or s > max_terms:
        needed = f"s = {s} terms" if s is not None else f"more than {int(max_terms) * _NEEDED_SEARCH_FACTOR} terms"
        unit = "" if mode == "relative" else " [state units]"
        raise RPITermsError(
            f"the minimal RPI approximation needs {needed} for the {mode} ε = {epsilon:g}{unit}, more than "
            f"max_terms = {max_terms} (spectral radius of A + BK {rho:.6g}; α = {alpha:.4g} at the last term "
            "tried); the set is not truncated: raise max_terms or ε, or use a faster ancillary gain",
            needed=s, max_terms=int(max_terms), spectral_radius=rho,
        )
    z = _scaled_minkowski_series(a_k, w, s, 1.0 / (1.0 - alpha))
    return RPIApproximation(z=z, s=s, alpha=alpha, m_s=m_s, epsilon=float(epsilon), spectral_radius=rho, mode=mode)


def _terms_needed(
    a_k: np.ndarray, w: Polytope, epsilon: float, mode: EpsilonMode, limit: int
) -> tuple[int | None, float, float]:
    """The smallest s ≤ ``limit`` meeting the stopping rule, with ``α°(s)`` (Eq. 11) and ``M(s)`` (Eq. 13).

    Only 2n + m support values per term (no set is built), so searching past ``max_terms`` to report the
    number of terms needed is cheap. Returns ``(None, α°(limit), M(limit))`` when ``limit`` is not enough.
    """
    n = a_k.shape[0]
    f, g = w.a, w.b
    eye = np.eye(n)
    directions = np.vstack([eye, -eye])
    power = eye.copy()  # A_K^(s-1) during iteration s
    m_sums = np.zeros(2 * n)  # Σ_{i<s} h_W(±(A_Kⁱ)ᵀ e_j)
    alpha, m_s = np.inf, 0.0
    relative_bound = epsilon / (1.0 + epsilon)
    for s in range(1, limit + 1):
        m_sums += w.support(directions @ power)  # rows ±e_jᵀ A^(s-1)  → directions (A^(s-1))ᵀ(±e_j)
        power = a_k @ power  # A_K^s
        alpha = float(np.max(w.support(f @ power) / g))  # α°(s), Eq. 11: h_W((A^s)ᵀ f_i) / g_i
        m_s = float(np.max(m_sums))  # M(s), Eq. 13
        bound = relative_bound if mode == "relative" else epsilon / (epsilon + m_s)  # Eq. 14 (absolute)
        if alpha <= bound:  # bound < 1, so α < 1 and F(α, s) is defined
            return s, alpha, m_s
    return None, alpha, m_s


def minimal_rpi_support(
    a_closed: np.ndarray, w: Polytope, directions: np.ndarray, *, rtol: float = 1e-13, max_terms: int = 100_000
) -> tuple[np.ndarray, np.ndarray]:
    """Support function of the minimal RPI set, ``h_{F_∞}(d) = Σ_{k≥0} h_W((A_Kᵏ)ᵀ d)`` (RKKM05 Eq. 2, s → ∞).

    Computed term by term, independently of :func:`minimal_rpi_outer` (no α, no Minkowski sum), until a rigorous
    bound on the remaining tail is below ``rtol`` times the partial sum in every direction. Tail bound: with
    ``q = ‖A_Kᴺ‖₂ < 1``, submultiplicativity gives ``Σ_{k≥N} ‖A_Kᵏ‖₂ ≤ q / (1 − q) · Σ_{k<N} ‖A_Kᵏ‖₂``, and
    ``h_W(c) ≤ r_W ‖c‖₂`` with ``r_W`` the largest vertex norm of W.

    Parameters
    ----------
    a_closed : ndarray, shape (n, n)
        Schur-stable ``A_K``.
    w : Polytope
        Bounded disturbance set containing the origin.
    directions : ndarray, shape (n,) or (k, n)
    rtol : float
        Relative accuracy of the sum (the tail bound); ≥ 1e-15.
    max_terms : int
        Refuse (ValueError) beyond this many terms.

    Returns
    -------
    support : ndarray, shape (k,)
        The partial sums (k = 1 for a single direction): lower bounds of ``h_{F_∞}`` (every term is ≥ 0 as
        0 ∈ W).
    tail : ndarray, shape (k,)
        Upper bounds of the neglected tails: ``support ≤ h_{F_∞}(d) ≤ support + tail``.
    """
    a_k = np.asarray(a_closed, dtype=float)
    d2 = np.atleast_2d(np.asarray(directions, dtype=float))
    if spectral_radius(a_k) >= 1.0:
        raise ValueError("A_K is not Schur stable: F_∞ is unbounded")
    r_w = float(np.max(np.linalg.norm(w.vertices, axis=1)))
    d_norm = np.linalg.norm(d2, axis=1)
    total = np.zeros(d2.shape[0])
    power = np.eye(a_k.shape[0])
    norm_sum = 0.0
    tail = np.full(d2.shape[0], np.inf)
    n_dir = d2.shape[0]
    block = 8  # terms per batch: one support evaluation and one batched 2-norm per block (same sums, term order)
    for k0 in range(0, max_terms, block):
        count = min(block, max_terms - k0)
        powers = np.empty((count + 1, *power.shape))
        powers[0] = power
        for j in range(count):
            powers[j + 1] = a_k @ powers[j]
        terms = np.asarray(w.support((d2 @ powers[:count]).reshape(count * n_dir, -1))).reshape(count, n_dir)
        norms = np.linalg.norm(powers, 2, axis=(1, 2))
        for j in range(count):
            total += terms[j]  # h_W((A_Kᵏ)ᵀ d), rows dᵀ A_Kᵏ
            norm_sum += float(norms[j])
        power = powers[count]
        if count == block:
            q = float(norms[count])
            if q < 1.0:
                tail = r_w * d_norm * q / (1.0 - q) * norm_sum
                if np.all(tail <= max(rtol, 1e-15) * total):
                    return total, tail
    raise ValueError(f"the sum of h_W over A_K's powers did not reach rtol = {rtol:g} within {max_terms} terms")


def _scaled_minkowski_series(a_k: np.ndarray, w: Polytope, s: int, scale: float) -> Polytope:
    """``scale · ⊕_{i<s} A_Kⁱ W`` with normals from the hull of the summed vertices and offsets from the exact
    support function ``scale · Σ_i h_W((A_Kⁱ)ᵀ a)`` (no vertex pruning affects the offsets)."""
    n = a_k.shape[0]
    powers = [np.eye(n)]
    for _ in range(1, s):
        powers.append(a_k @ powers[-1])
    if n == 2:  # exact polygon sum by merging the edges of all terms in angular order
        points = minkowski_sum_linear_images(convex_hull_2d(w.vertices), np.array(powers))
    else:
        points = w.vertices.copy()
        for p in powers[1:]:
            points = (points[:, None, :] + (w.vertices @ p.T)[None, :, :]).reshape(-1, n)
            _, points = hull_normals(points)  # keep the hull vertices only (a point dropped lies inside the hull)
    normals, hull_vertices = hull_normals(points)
    # Σ_i h_W((A_Kⁱ)ᵀ a) for every normal a: one support evaluation for all terms, summed term by term.
    offsets = np.sum(np.asarray(w.support((normals @ np.array(powers)).reshape(-1, n))).reshape(len(powers), -1),
                     axis=0)
    return Polytope(normals, cast(np.ndarray, scale * offsets), vertices=scale * hull_vertices)


def rpi_margins(a_closed: np.ndarray, z: Polytope, w: Polytope) -> np.ndarray:
    """Robust invariance margins ``b_i − h_Z(A_Kᵀ a_i) − h_W(a_i)`` per facet ``a_iᵀ e ≤ b_i`` of Z.

    All margins ``≥ 0`` ⇔ ``A_K Z ⊕ W ⊆ Z`` (Z is RPI; Kolmanovsky & Gilbert 1998).

    Parameters
    ----------
    a_closed : ndarray, shape (n, n)
        Closed-loop matrix ``A_K = A + B K``.
    z : Polytope
        Candidate invariant set Z, bounded.
    w : Polytope
        Disturbance set W, bounded.

    Returns
    -------
    ndarray, shape (n_facets,)
        One margin per inequality of Z.
    """
    a = z.a
    return z.b - z.support(a @ np.asarray(a_closed, dtype=float)) - w.support(a)


@dataclass(frozen=True)
class FacetReduction:
    """Result of :func:`reduce_facets`.

    Attributes
    ----------
    z : Polytope
        The reduced RPI set (contains the input set, is RPI, lies within ``(1 + growth)`` times the input).
    facets_before, facets_after : int
    growth : float
        Largest ``h_reduced(a) / h_original(a) − 1`` over the original normals and the coordinate axes (≤ growth).
    min_margin : float
        Smallest robust invariance margin of the reduced set (≥ 0).
    """

    z: Polytope
    facets_before: int
    facets_after: int
    growth: float
    min_margin: float


def _intersect(a1: np.ndarray, b1: float, a2: np.ndarray, b2: float) -> np.ndarray | None:
    """Intersection of the lines ``a1ᵀx = b1`` and ``a2ᵀx = b2`` (None when parallel)."""
    det = a1[0] * a2[1] - a1[1] * a2[0]
    if abs(det) < 1e-14:
        return None
    return np.array([(b1 * a2[1] - b2 * a1[1]) / det, (a1[0] * b2 - a2[0] * b1) / det])


def reduce_facets(a_closed: np.ndarray, z: Polytope, w: Polytope, growth: float) -> FacetReduction:
    """A 2-D RPI set with fewer facets, within ``(1 + growth) Z`` (a valid, cheaper lasso constraint).

    The search starts from ``(1 + growth/2) Z``, which is RPI with a positive margin on every facet (for an RPI
    set Z, ``h_Z(a) − h_Z(A_Kᵀa) ≥ h_W(a)``, so scaling by ``1 + δ`` adds ``δ h_W(a)`` of margin). Removing
    facet j replaces the polygon P by ``conv(P ∪ {v})``, v the intersection of j's neighbouring lines, so every
    support value becomes ``max(h_P(d), vᵀd)``: the removal is accepted only when (i) the neighbours still bound
    the set, (ii) every remaining robust invariance inequality ``h(A_Kᵀ a_k) + h_W(a_k) ≤ c_k`` holds with margin
    ``≥ 1e-12 max|c|`` and (iii) ``vᵀa ≤ (1 + growth) h_Z(a)`` along every original normal and axis. Short facets
    are tried first; passes repeat until nothing changes. The result contains Z (and ``F_∞``); it is checked once
    more on independently enumerated vertices, and should that check fail Z is returned unchanged.

    Parameters
    ----------
    a_closed : ndarray, shape (2, 2)
    z : Polytope
        A 2-D RPI set of ``(A_K, W)`` whose inequalities are all facets (as from :func:`minimal_rpi_outer`).
    w : Polytope
    growth : float
        Allowed relative growth ≥ 0; 0 returns ``z`` unchanged.

    Returns
    -------
    FacetReduction
        The reduced set, the facet counts, the growth used and the smallest margin.
    """
    a_k = np.asarray(a_closed, dtype=float)
    before = z.n_facets
    if z.dim != 2 or growth <= 0.0 or before <= 4:
        return FacetReduction(z, before, before, 0.0, float(rpi_margins(a_k, z, w).min()))
    angle = np.arctan2(z.a[:, 1], z.a[:, 0])
    order = np.argsort(angle)
    normals, angle = z.a[order], angle[order]
    offsets = (1.0 + 0.5 * growth) * z.b[order]
    f = len(offsets)
    probe = np.vstack([normals, np.eye(2), -np.eye(2)])
    limit = (1.0 + growth) * z.support(probe)
    tol = 1e-12 * float(np.max(np.abs(offsets)))
    budget = offsets - w.support(normals)  # c_k − h_W(a_k): the bound on h(A_Kᵀ a_k)
    image_dirs = normals @ a_k  # rows (A_Kᵀ a_k)ᵀ
    h_image = (1.0 + 0.5 * growth) * z.support(image_dirs)  # supports of the current polygon
    if np.any(h_image > budget - tol):  # no room (numerically tight): keep Z
        return FacetReduction(z, before, before, 0.0, float(rpi_margins(a_k, z, w).min()))
    prev = np.roll(np.arange(f), 1)
    nxt = np.roll(np.arange(f), -1)
    keep = np.ones(f, dtype=bool)
    vertex = np.array([_intersect(normals[k], offsets[k], normals[nxt[k]], offsets[nxt[k]]) for k in range(f)])
    changed = True
    while changed and keep.sum() > 3:
        changed = False
        kept = np.flatnonzero(keep)
        lengths = np.linalg.norm(vertex[kept] - vertex[prev[kept]], axis=1)  # edge of line k: v_prev(k) .. v_k
        for j in kept[np.argsort(lengths)]:
            if keep.sum() <= 3:
                break
            p, n = prev[j], nxt[j]
            gap = (angle[n] - angle[p]) % (2 * np.pi)
            if gap >= np.pi - 1e-9:  # (i) the neighbours would not bound the set
                continue
            v = _intersect(normals[p], offsets[p], normals[n], offsets[n])
            if v is None or np.any(probe @ v > limit + tol):  # (iii)
                continue
            new_h = np.maximum(h_image, image_dirs @ v)
            others = keep.copy()
            others[j] = False
            if np.any(new_h[others] > budget[others] - tol):  # (ii)
                continue
            keep[j] = False
            h_image = new_h
            nxt[p], prev[n] = n, p
            vertex[p] = v
            changed = True
    reduced = Polytope(normals[keep], offsets[keep])  # vertices re-enumerated independently of the search
    grown = float(np.max(reduced.support(probe) / z.support(probe)) - 1.0)
    margin = float(rpi_margins(a_k, reduced, w).min())
    if margin < 0.0 or grown > growth * (1.0 + 1e-9) or not reduced.contains(z):  # independent final check
        return FacetReduction(z, before, before, 0.0, float(rpi_margins(a_k, z, w).min()))
    return FacetReduction(reduced, before, reduced.n_facets, max(grown, 0.0), margin)
