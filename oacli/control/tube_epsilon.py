"""Relative accuracy of the tube: how a bound ``Z ⊆ (1 + ε) F_∞`` is shared between Raković et al. 2005's
``F(α, s)`` and the facet reduction of :func:`oacli.sets.reduce_facets` (used by :mod:`oacli.control.tube_design`)."""

from __future__ import annotations

import numpy as np


def split_relative_epsilon(epsilon: float, facet_growth: float) -> tuple[float, float]:
    """Split a relative bound ``Z ⊆ (1 + ε) F_∞`` between ``F(α, s)`` and the facet reduction.

    ``(1 + ε) = (1 + ε_F)(1 + g)``: the reduction gets ``g = min(facet_growth, √(1 + ε) − 1)`` (at most half of
    the bound, geometrically) and Raković et al.'s algorithm the rest, ``ε_F = (1 + ε)/(1 + g) − 1``. After
    ``F(α, s)`` is built, the reduction may use what it left (:func:`reduction_growth`).

    Parameters
    ----------
    epsilon : float
        Relative bound ε > 0 of the set in use.
    facet_growth : float
        Largest growth the facet reduction may take, ≥ 0.

    Returns
    -------
    epsilon_rpi : float
        Relative ε of ``F(α, s) ⊆ (1 + ε_F) F_∞``.
    growth : float
        Planned facet growth g.
    """
    if not (epsilon > 0 and np.isfinite(epsilon)) or not facet_growth >= 0:
        raise ValueError(f"need epsilon > 0 and facet_growth >= 0, got {epsilon}, {facet_growth}")
    growth = min(float(facet_growth), float(np.sqrt(1.0 + epsilon) - 1.0))
    return (1.0 + epsilon) / (1.0 + growth) - 1.0, growth


def reduction_growth(epsilon: float, facet_growth: float, alpha: float) -> float:
    """Facet growth left to the reduction by ``F(α, s) = (1 − α)⁻¹ F_s ⊆ (1 − α)⁻¹ F_∞`` under a relative bound.

    Parameters
    ----------
    epsilon : float
        Relative bound ε of the set in use.
    facet_growth : float
        Largest growth the reduction may take.
    alpha : float
        ``α`` of ``F(α, s)``, in [0, 1).

    Returns
    -------
    float
        ``min(facet_growth, (1 + ε)(1 − α) − 1)`` (≥ 0), so that ``(1 − α)⁻¹ (1 + g) ≤ 1 + ε``.
    """
    return max(0.0, min(float(facet_growth), (1.0 + epsilon) * (1.0 - alpha) - 1.0))
