"""The state manifold of the free flyer: ``⊞``/``⊟`` and their exact Jacobians ([Doerr2021] Eqs. 31-32).

The 13-entry state ``x = [r, v, q, ω]`` (see :mod:`oacli.types`) lives on ℝ⁶ × S³ × ℝ³. Estimators work with
12-entry perturbations ``δx = [δr, δv, δφ, δω]`` where the attitude part is a **body-frame** rotation vector:

    x ⊞ δx = [r + δr, v + δv, q ⊗ exp(δφ), ω + δω]                       ("⊞" of [Doerr2021] Eq. 31)
    y ⊟ x  = [r_y − r, v_y − v, log(q⁻¹ ⊗ q_y), ω_y − ω]                 so that x ⊞ (y ⊟ x) = y

The Jacobians of ``log`` that make Gauss-Newton exact are the inverse right and left Jacobians of SO(3):
perturbing ``q_y`` on the right by ``exp(δ)`` changes ``e = log(q⁻¹ ⊗ q_y)`` by ``J_r⁻¹(e) δ``, perturbing ``q`` on
the right changes it by ``−J_l⁻¹(e) δ`` (Sola, Deray & Atchuthan 2018, "A micro Lie theory", Eqs. 143-146).
All functions take one state (13,) or a stack (K, 13).
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat

TANGENT_DIM = 12


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices ``[v]×`` of vectors (..., 3) -> (..., 3, 3).

    Parameters
    ----------
    v : ndarray, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def so3_right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_r⁻¹(φ)`` (..., 3, 3) of SO(3): ``I + ½[φ]× + (1/θ² − (1 + cos θ)/(2θ sin θ)) [φ]×²``, θ = ‖φ‖.

    Parameters
    ----------
    phi : ndarray, shape (..., 3)
        Rotation vectors [rad].

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < 1e-5
    t = np.where(small, 1.0, theta)
    # Series 1/12 + θ²/720 near zero.
    coef = np.where(small, 1.0 / 12.0 + theta**2 / 720.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    s = skew(phi)
    return np.eye(3) + 0.5 * s + coef[..., None, None] * (s @ s)


def so3_left_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_l⁻¹(φ) = J_r⁻¹(−φ)`` (..., 3, 3).

    Parameters
    ----------
    phi : ndarray, shape (..., 3)
        Rotation vectors [rad].

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    return so3_right_jacobian_inverse(-np.asarray(phi, dtype=float))


def boxplus(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """``x ⊞ δx``: states (..., 13) perturbed by tangent vectors (..., 12); the quaternion is renormalised.

    Parameters
    ----------
    x : ndarray, shape (..., 13)
        States.
    dx : ndarray, shape (..., 12)
        Tangent vectors ``[δr, δv, δφ, δω]``.

    Returns
    -------
    ndarray, shape (..., 13)
    """
    x = np.asarray(x, dtype=float)
    dx = np.asarray(dx, dtype=float)
    out = np.array(x, copy=True)
    out[..., 0:6] += dx[..., 0:6]
    out[..., 6:10] = quat.normalize(quat.multiply(x[..., 6:10], quat.exp(dx[..., 6:9])))
    out[..., 10:13] += dx[..., 9:12]
    return out


def boxminus(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``y ⊟ x`` (..., 12): the tangent vector with ``x ⊞ (y ⊟ x) = y`` (attitude: body frame of ``x``).

    Parameters
    ----------
    y, x : ndarray, shape (..., 13)
        States (broadcast).

    Returns
    -------
    ndarray, shape (..., 12)
    """
    y = np.asarray(y, dtype=float)
    x = np.asarray(x, dtype=float)
    out = np.empty((*np.broadcast_shapes(y.shape, x.shape)[:-1], TANGENT_DIM))
    out[..., 0:6] = y[..., 0:6] - x[..., 0:6]
    out[..., 6:9] = quat.log(quat.multiply(quat.conjugate(x[..., 6:10]), y[..., 6:10]))
    out[..., 9:12] = y[..., 10:13] - x[..., 10:13]
    return out


def xi_stack(q: np.ndarray) -> np.ndarray:
    """Ξ(q) of [Doerr2021] Eq. 36 for a stack of quaternions (..., 4) -> (..., 4, 3).

    Parameters
    ----------
    q : ndarray, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4, 3)
    """
    q = np.asarray(q, dtype=float)
    x, y, z, w = (q[..., i] for i in range(4))
    out = np.empty((*q.shape[:-1], 4, 3))
    out[..., 0, :] = np.stack([w, -z, y], axis=-1)
    out[..., 1, :] = np.stack([z, w, -x], axis=-1)
    out[..., 2, :] = np.stack([-y, x, w], axis=-1)
    out[..., 3, :] = np.stack([-x, -y, -z], axis=-1)
    return out


def lift_matrix(x: np.ndarray) -> np.ndarray:
    """``∂(x ⊞ δx)/∂δx`` at ``δx = 0``, (..., 13, 12): identity blocks and ``½ Ξ(q)`` for the attitude.

    Parameters
    ----------
    x : ndarray, shape (..., 13)

    Returns
    -------
    ndarray, shape (..., 13, 12)
    """
    x = np.asarray(x, dtype=float)
    out = np.zeros((*x.shape[:-1], 13, TANGENT_DIM))
    out[..., 0:6, 0:6] = np.eye(6)
    out[..., 6:10, 6:9] = 0.5 * xi_stack(x[..., 6:10])
    out[..., 10:13, 9:12] = np.eye(3)
    return out


def project_matrix(x: np.ndarray) -> np.ndarray:
    """Left inverse of :func:`lift_matrix` on the tangent space, (..., 12, 13): ``2 Ξ(q)ᵀ`` for the attitude.

    For a unit ``q`` and a tangent change ``dq`` (``qᵀ dq = 0``), ``2 Ξ(q)ᵀ dq`` is the body-frame rotation
    vector ``δφ`` with ``q ⊗ exp(δφ) ≈ q + dq``; a radial component of ``dq`` is ignored.

    Parameters
    ----------
    x : ndarray, shape (..., 13)

    Returns
    -------
    ndarray, shape (..., 12, 13)
    """
    x = np.asarray(x, dtype=float)
    out = np.zeros((*x.shape[:-1], TANGENT_DIM, 13))
    out[..., 0:6, 0:6] = np.eye(6)
    out[..., 6:9, 6:10] = 2.0 * np.swapaxes(xi_stack(x[..., 6:10]), -1, -2)
    out[..., 9:12, 10:13] = np.eye(3)
    return out
