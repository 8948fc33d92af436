"""Unit quaternions, scalar last ``[x, y, z, w]`` ([Doerr2021] Eq. 33), Hamilton product.

A quaternion ``q`` rotates body-frame vectors into the world frame: ``v_world = R(q) v_body``. The kinematics
``q̇ = ½ Ξ(q) ω`` ([Doerr2021] Eqs. 35a, 36) use the body angular rate ``ω``, i.e. ``q̇ = ½ q ⊗ [ω, 0]``.
All functions accept a single quaternion (4,) or a stack (..., 4).
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def normalize(q: np.ndarray) -> np.ndarray:
    """Return ``q / ‖q‖`` with the sign chosen so that ``w >= 0`` (the same rotation).

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        Quaternion(s) ``[x, y, z, w]``.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion(s) with ``w >= 0``.
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate (inverse for unit quaternions).

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        Quaternion(s) ``[x, y, z, w]``.

    Returns
    -------
    ndarray, shape (..., 4)
    """
    q = np.asarray(q, dtype=float)
    return np.concatenate([-q[..., :3], q[..., 3:4]], axis=-1)


def multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (rotation q first, then p).

    Parameters
    ----------
    p, q : ndarray, shape (..., 4)
        Quaternions ``[x, y, z, w]`` (broadcast).

    Returns
    -------
    ndarray, shape (..., 4)
    """
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pv, pw = p[..., :3], p[..., 3:4]
    qv, qw = q[..., :3], q[..., 3:4]
    vec = pw * qv + qw * pv + np.cross(pv, qv)
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    return np.concatenate([vec, w], axis=-1)


def xi_matrix(q: np.ndarray) -> np.ndarray:
    """Ξ(q) of [Doerr2021] Eq. 36, shape (4, 3): ``q̇ = ½ Ξ(q) ω``.

    Parameters
    ----------
    q : ndarray, shape (4,)
        Quaternion ``[x, y, z, w]``.

    Returns
    -------
    ndarray, shape (4, 3)
    """
    x, y, z, w = np.asarray(q, dtype=float)
    return np.array([[w, -z, y], [z, w, -x], [-y, x, w], [-x, -y, -z]])


def omega_matrix(omega: np.ndarray) -> np.ndarray:
    """Ω(ω), shape (4, 4), with ``Ξ(q) ω = Ω(ω) q`` (so ``∂q̇/∂q = ½ Ω(ω)``).

    Parameters
    ----------
    omega : ndarray, shape (3,)
        Angular velocity ω [rad/s] (body frame).

    Returns
    -------
    ndarray, shape (4, 4)
    """
    wx, wy, wz = np.asarray(omega, dtype=float)
    return np.array(
        [[0.0, wz, -wy, wx], [-wz, 0.0, wx, wy], [wy, -wx, 0.0, wz], [-wx, -wy, -wz, 0.0]]
    )


def to_rotation_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix R(q) (body to world), shape (..., 3, 3).

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        Quaternion(s) ``[x, y, z, w]``. Normalised first.

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    q = normalize(q)
    x, y, z, w = (q[..., i] for i in range(4))
    r = np.empty((*q.shape[:-1], 3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def rotation_floats(qx: float, qy: float, qz: float, qw: float) -> tuple[float, float, float, float, float, float,
                                                                         float, float, float]:
    """:func:`to_rotation_matrix` of one quaternion on Python floats, row by row (the per-step paths: the
    simulator's actuators, the controllers' centre-of-mass feed-forward).

    Parameters
    ----------
    qx, qy, qz, qw : float
        Quaternion ``[x, y, z, w]``; normalised first.

    Returns
    -------
    tuple of 9 float
        ``r00, r01, r02, r10, r11, r12, r20, r21, r22`` of R(q) (body to world).
    """
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    x, y, z, w = qx / norm, qy / norm, qz / norm, qw / norm
    return (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y))


def from_rotation_matrix(r: np.ndarray) -> np.ndarray:
    """Quaternion of a proper rotation matrix (Shepperd's method), shape (3, 3) -> (4,).

    Parameters
    ----------
    r : ndarray, shape (3, 3)
        Proper rotation matrix.

    Returns
    -------
    ndarray, shape (4,)
        Unit quaternion ``[x, y, z, w]`` with ``w >= 0``.
    """
    r = np.asarray(r, dtype=float)
    tr = np.trace(r)
    cands = np.array([r[0, 0], r[1, 1], r[2, 2], tr])
    i = int(np.argmax(cands))
    q: list[float] | np.ndarray
    if i == 3:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = [(r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w), w]
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = np.zeros(4)
        q[i] = 0.25 * s
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
        q[3] = (r[k, j] - r[j, k]) / s
    return normalize(np.asarray(q, dtype=float))


def exp(rotvec: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation vector φ [rad] (axis·angle).

    Parameters
    ----------
    rotvec : ndarray, shape (..., 3)
        Rotation vector φ [rad].

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion ``[x, y, z, w]``.
    """
    phi = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a with its Taylor series near 0 for accuracy.
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([k * phi, np.cos(half)], axis=-1)


def log(q: np.ndarray) -> np.ndarray:
    """Rotation vector φ [rad] of a quaternion, angle in [0, π] (shortest rotation).

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        Quaternion(s) ``[x, y, z, w]``. Normalised first.

    Returns
    -------
    ndarray, shape (..., 3)
        Rotation vector φ [rad].
    """
    q = normalize(q)
    v, w = q[..., :3], q[..., 3:4]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-9
    k = np.where(small, 2.0 / np.where(small, w, 1.0), angle / np.where(small, 1.0, s))
    return cast(np.ndarray, k * v)


def error_vector(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Body-frame attitude error φ [rad] with ``q = q_ref ⊗ exp(φ)``.

    Parameters
    ----------
    q_ref, q : ndarray, shape (..., 4)
        Reference and actual attitude.

    Returns
    -------
    ndarray, shape (..., 3)
        φ [rad], with norm in [0, π].
    """
    return log(multiply(conjugate(q_ref), q))


def angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] between two attitudes, in [0, π].

    Parameters
    ----------
    q1, q2 : ndarray, shape (..., 4)
        The two attitudes.

    Returns
    -------
    ndarray, shape (...)
        Angle [rad].
    """
    return cast(np.ndarray, np.linalg.norm(error_vector(q1, q2), axis=-1))


def slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation from q0 (s = 0) to q1 (s = 1) along the shortest arc.

    Parameters
    ----------
    q0, q1 : ndarray, shape (4,)
        End attitudes.
    s : float or ndarray, shape (k,)
        Interpolation parameter(s) in [0, 1].

    Returns
    -------
    ndarray, shape (4,) or (k, 4)
        Unit quaternion(s).
    """
    s = np.asarray(s, dtype=float)[..., None]
    delta = log(multiply(conjugate(q0), q1))
    return normalize(multiply(q0, exp(s * delta)))
