"""The manifold operations of :mod:`oacli.estimation.manifold` for one state, in Python floats.

A filter step of :class:`oacli.estimation.sequential.SequentialEstimator` handles one state; the stacked numpy
versions of :mod:`oacli.estimation.manifold` are mostly per-call overhead there. Quaternions are ``(x, y, z, w)``,
scalar last ([Doerr2021] Eq. 33); each function equals its stacked counterpart (checked by the tests).
"""

from __future__ import annotations

import math

import numpy as np

from oacli.estimation.manifold import TANGENT_DIM


def qmul(p: tuple[float, ...], q: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Hamilton product ``p ⊗ q`` of two quaternions (:func:`oacli.model.quaternion.multiply`).

    Parameters
    ----------
    p, q : tuple of 4 float
        Quaternions ``(x, y, z, w)`` ([Doerr2021] Eq. 33).

    Returns
    -------
    tuple of 4 float
        ``p ⊗ q`` as ``(x, y, z, w)``.
    """
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return (pw * qx + qw * px + (py * qz - pz * qy), pw * qy + qw * py + (pz * qx - px * qz),
            pw * qz + qw * pz + (px * qy - py * qx), pw * qw - (px * qx + py * qy + pz * qz))


def qnormalise(q: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Unit quaternion of ``q`` with ``w >= 0`` (:func:`oacli.model.quaternion.normalize`).

    Parameters
    ----------
    q : tuple of 4 float
        Non-zero quaternion ``(x, y, z, w)``.

    Returns
    -------
    tuple of 4 float
        ``±q / |q|``, the sign chosen so that ``w >= 0``.
    """
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    s = -1.0 / n if q[3] / n < 0.0 else 1.0 / n
    return (q[0] * s, q[1] * s, q[2] * s, q[3] * s)


def qlog(q: tuple[float, ...]) -> tuple[float, float, float]:
    """Rotation vector of a quaternion (:func:`oacli.model.quaternion.log`).

    Parameters
    ----------
    q : tuple of 4 float
        Quaternion ``(x, y, z, w)`` (normalised here, sign ``w >= 0``).

    Returns
    -------
    tuple of 3 float
        Rotation vector ``angle · axis`` [rad], angle in [0, π].
    """
    x, y, z, w = qnormalise(q)
    s = math.sqrt(x * x + y * y + z * z)
    k = 2.0 / w if s < 1e-9 else 2.0 * math.atan2(s, w) / s
    return (k * x, k * y, k * z)


def qexp(v: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion of a rotation vector (:func:`oacli.model.quaternion.exp`).

    Parameters
    ----------
    v : ndarray, shape (3,)
        Rotation vector [rad].

    Returns
    -------
    tuple of 4 float
        ``(sin(|v|/2) v/|v|, cos(|v|/2))`` as ``(x, y, z, w)``; all NaN when ``v`` is not finite.
    """
    vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
    angle = math.sqrt(vx * vx + vy * vy + vz * vz)
    if not math.isfinite(angle):  # a wild trial step: NaN as numpy gives (the step is then rejected)
        return (math.nan, math.nan, math.nan, math.nan)
    k = 0.5 - angle**2 / 48.0 if angle < 1e-6 else math.sin(0.5 * angle) / angle
    return (k * vx, k * vy, k * vz, math.cos(0.5 * angle))


def boxminus_one(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``y ⊟ x`` (12,) of one state (:func:`oacli.estimation.manifold.boxminus`).

    Parameters
    ----------
    y, x : ndarray, shape (13,)
        States [r m, v m/s, q (x, y, z, w), ω rad/s].

    Returns
    -------
    ndarray, shape (12,)
        Tangent vector ``[δr m, δv m/s, δφ rad, δω rad/s]`` with ``x ⊞ (y ⊟ x) = y`` (attitude in the body frame
        of ``x``).
    """
    out = np.empty(TANGENT_DIM)
    out[0:6] = y[0:6] - x[0:6]
    qx = (-float(x[6]), -float(x[7]), -float(x[8]), float(x[9]))
    out[6:9] = qlog(qmul(qx, (float(y[6]), float(y[7]), float(y[8]), float(y[9]))))
    out[9:12] = y[10:13] - x[10:13]
    return out


def boxplus_one(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """``x ⊞ δx`` (13,) of one state (:func:`oacli.estimation.manifold.boxplus`).

    Parameters
    ----------
    x : ndarray, shape (13,)
        State [r m, v m/s, q (x, y, z, w), ω rad/s].
    dx : ndarray, shape (12,)
        Tangent vector ``[δr m, δv m/s, δφ rad, δω rad/s]`` (attitude in the body frame of ``x``).

    Returns
    -------
    ndarray, shape (13,)
        The perturbed state, its quaternion renormalised (``w >= 0``).
    """
    out = np.array(x, dtype=float, copy=True)
    out[0:6] += dx[0:6]
    out[6:10] = qnormalise(qmul((float(x[6]), float(x[7]), float(x[8]), float(x[9])), qexp(dx[6:9])))
    out[10:13] += dx[9:12]
    return out


def right_jacobian_inverse_one(phi: np.ndarray) -> np.ndarray:
    """``J_r⁻¹(φ)`` (3, 3) of one rotation vector (:func:`oacli.estimation.manifold.so3_right_jacobian_inverse`):
    ``I + ½[φ]× + c [φ]×²`` with ``[φ]×² = φφᵀ − |φ|² I``, entry by entry.

    Parameters
    ----------
    phi : ndarray, shape (3,)
        Rotation vector [rad].

    Returns
    -------
    ndarray, shape (3, 3)
        ``J_r⁻¹(φ)`` (dimensionless); all NaN when ``phi`` is not finite.
    """
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    sq = x * x + y * y + z * z
    theta = math.sqrt(sq)
    if not math.isfinite(theta):
        return np.full((3, 3), math.nan)
    if theta < 1e-5:
        coef = 1.0 / 12.0 + sq / 720.0
    else:
        coef = 1.0 / sq - (1.0 + math.cos(theta)) / (2.0 * theta * math.sin(theta))
    d = 1.0 - coef * sq
    hx, hy, hz = 0.5 * x, 0.5 * y, 0.5 * z
    cxy, cxz, cyz = coef * x * y, coef * x * z, coef * y * z
    return np.array(((d + coef * x * x, cxy - hz, cxz + hy),
                     (cxy + hz, d + coef * y * y, cyz - hx),
                     (cxz - hy, cyz + hx, d + coef * z * z)))


_LIFT_TEMPLATE = np.zeros((13, TANGENT_DIM))
_LIFT_TEMPLATE[0:6, 0:6] = np.eye(6)
_LIFT_TEMPLATE[10:13, 9:12] = np.eye(3)
_PROJECT_TEMPLATE = np.zeros((TANGENT_DIM, 13))
_PROJECT_TEMPLATE[0:6, 0:6] = np.eye(6)
_PROJECT_TEMPLATE[9:12, 10:13] = np.eye(3)


def lift_one(x: np.ndarray) -> np.ndarray:
    """:func:`oacli.estimation.manifold.lift_matrix` of one state, (13, 12).

    ``∂(x ⊞ δx)/∂δx`` at ``δx = 0``: identity blocks and ``½ Ξ(q)`` ([Doerr2021] Eq. 36) for the attitude.

    Parameters
    ----------
    x : ndarray, shape (13,)
        State [r m, v m/s, q (x, y, z, w), ω rad/s].

    Returns
    -------
    ndarray, shape (13, 12)
    """
    qx, qy, qz, qw = (0.5 * float(v) for v in x[6:10])
    out = _LIFT_TEMPLATE.copy()
    out[6:10, 6:9] = ((qw, -qz, qy), (qz, qw, -qx), (-qy, qx, qw), (-qx, -qy, -qz))
    return out


def project_one(x: np.ndarray) -> np.ndarray:
    """:func:`oacli.estimation.manifold.project_matrix` of one state, (12, 13).

    Left inverse of :func:`lift_one` on the tangent space: identity blocks and ``2 Ξ(q)ᵀ`` ([Doerr2021] Eq. 36)
    for the attitude.

    Parameters
    ----------
    x : ndarray, shape (13,)
        State [r m, v m/s, q (x, y, z, w), ω rad/s].

    Returns
    -------
    ndarray, shape (12, 13)
    """
    qx, qy, qz, qw = (2.0 * float(v) for v in x[6:10])
    out = _PROJECT_TEMPLATE.copy()
    out[6:9, 6:10] = ((qw, qz, -qy, -qx), (-qz, qw, qx, -qy), (qy, -qx, qw, -qz))
    return out
