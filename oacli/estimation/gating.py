"""χ² innovation gating for outlier rejection ([ReSWARM2023] §6.2.1, Eqs. 40-42).

With Gaussian noise the normalised innovation squared ``d² = νᵀ S⁻¹ ν`` of a measurement with ``n`` independent
components follows a χ² distribution with ``n`` degrees of freedom (the squared Mahalanobis distance between the
predicted and the observed measurement, Mirzaei & Roumeliotis 2008). A measurement whose ``d²`` exceeds the χ²
quantile at the gate probability (0.99 in flight) is rejected: a genuine measurement is rejected with probability
``1 − p`` only, while a localisation jump of a few standard deviations is caught.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import gammaincinv


@lru_cache(maxsize=64)
def chi2_threshold(dof: int, probability: float = 0.99) -> float:
    """χ² quantile: ``P(d² <= threshold) = probability`` for ``dof`` degrees of freedom.

    Parameters
    ----------
    dof : int
        Degrees of freedom, >= 1.
    probability : float, optional
        In (0, 1).

    Returns
    -------
    float
    """
    if dof < 1:
        raise ValueError("dof must be >= 1")
    if not 0.0 < probability < 1.0:
        raise ValueError("probability must be in (0, 1)")
    return float(2.0 * gammaincinv(0.5 * dof, probability))  # χ²_n = Gamma(n/2, scale 2)


def normalised_innovation_squared(innovation: np.ndarray, covariance: np.ndarray) -> float:
    """``d² = νᵀ S⁻¹ ν`` ([ReSWARM2023] Eq. 42) via a Cholesky solve of the innovation covariance ``S``.

    Parameters
    ----------
    innovation : ndarray, shape (n,)
        ν.
    covariance : ndarray, shape (n, n)
        S, positive definite.

    Returns
    -------
    float
    """
    chol = np.linalg.cholesky(0.5 * (covariance + covariance.T))
    z = np.linalg.solve(chol, innovation)
    return float(z @ z)


def passes_gate(d2: float | np.ndarray, dof: int, probability: float | None) -> bool | np.ndarray:
    """True where ``d²`` is within the gate (always True when ``probability`` is None).

    Parameters
    ----------
    d2 : float or ndarray
        Normalised innovations squared.
    dof : int
    probability : float or None
        Gate level; None disables the gate.

    Returns
    -------
    bool or ndarray of bool
    """
    if probability is None:
        return np.ones_like(d2, dtype=bool) if np.ndim(d2) else True
    return np.asarray(d2) <= chi2_threshold(int(dof), float(probability))
