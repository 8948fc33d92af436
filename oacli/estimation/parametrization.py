"""A parametrisation of θ = [m, Ixx, Iyy, Izz] that is physical by construction.

Principal moments of inertia of a real body are ``Ixx = B + C``, ``Iyy = A + C``, ``Izz = A + B`` with the
second moments of its mass distribution ``A = ∫x² dm``, ``B = ∫y² dm``, ``C = ∫z² dm`` >= 0 (Wensing, Kim &
Slotine 2017, "Linear matrix inequalities for physically consistent inertial parameter identification"; seed
001 §2 cites it for physical feasibility). The estimators therefore work with

    φ = [log m, log A, log B, log C],     A = (Iyy + Izz − Ixx)/2,  B = (Ixx + Izz − Iyy)/2,  C = (Ixx + Iyy − Izz)/2

Every real φ maps to a mass > 0 and inertias that satisfy the triangle inequalities, so no estimate
is ever reset or clipped (RATTLE's ``param_est`` reset its filter to the prior when an estimate became
non-physical). The Gaussian prior and the reported covariance stay in θ (linearised through ``dθ/dφ``).
"""

from __future__ import annotations

import numpy as np

N_PARAMS = 4

# θ_inertia = M @ [A, B, C]
_SUMS = np.array([[0.0, 1.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 0.0]])
_SUMS_INV = 0.5 * np.array([[-1.0, 1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, -1.0]])


TRIANGLE_RTOL = 1e-12
"""Relative rounding tolerance of the triangle inequalities (as the config's ``INERTIA_TRIANGLE_RTOL``)."""


def is_physical(theta: np.ndarray) -> bool:
    """True when ``m > 0``, every principal inertia > 0 and each sum of two >= the third (within rounding).

    Equality is a planar body (a lamina); φ reaches it only in the limit ``log A → −∞``, where the computed
    inertias satisfy the inequality to rounding.

    Parameters
    ----------
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    bool
    """
    theta = np.asarray(theta, dtype=float)
    second_moments = _SUMS_INV @ theta[1:4]
    return bool(theta[0] > 0 and np.all(theta[1:4] > 0)
                and np.all(second_moments >= -TRIANGLE_RTOL * np.max(theta[1:4])))


def phi_from_theta(theta: np.ndarray) -> np.ndarray:
    """φ of a physical θ (raises ``ValueError`` otherwise).

    Parameters
    ----------
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    ndarray, shape (4,)
        φ.
    """
    theta = np.asarray(theta, dtype=float)
    if not (theta[0] > 0 and np.all(_SUMS_INV @ theta[1:4] > 0)):
        raise ValueError(f"θ = {theta} is not physical: φ needs mass > 0 and strict inertia triangle inequalities")
    return np.log(np.concatenate([[theta[0]], _SUMS_INV @ theta[1:4]]))


def theta_from_phi(phi: np.ndarray) -> np.ndarray:
    """θ = [m, Ixx, Iyy, Izz] of φ (always physical).

    Parameters
    ----------
    phi : ndarray, shape (4,)
        φ = [log m, log A, log B, log C].

    Returns
    -------
    ndarray, shape (4,)
        θ.
    """
    e = np.exp(np.asarray(phi, dtype=float))
    return np.concatenate([[e[0]], _SUMS @ e[1:4]])


def theta_jacobian(phi: np.ndarray) -> np.ndarray:
    """``dθ/dφ`` (4, 4) at φ.

    Parameters
    ----------
    phi : ndarray, shape (4,)
        φ = [log m, log A, log B, log C].

    Returns
    -------
    ndarray, shape (4, 4)
    """
    e = np.exp(np.asarray(phi, dtype=float))
    jac = np.zeros((N_PARAMS, N_PARAMS))
    jac[0, 0] = e[0]
    jac[1:4, 1:4] = _SUMS * e[1:4][None, :]
    return jac
