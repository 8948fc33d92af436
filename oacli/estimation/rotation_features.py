"""The rotational dynamics ([Doerr2021] Eqs. 35a-35b) as linear maps of a few features, for fast propagation.

The rotational state ``z = [q, ω]`` evolves as ``q̇ = ½ q ⊗ [ω, 0]`` and ``ω̇ = J⁻¹(τ − ω × Jω)``; both rates and
their Jacobians ``[∂ż/∂z | ∂ż/∂J]`` are linear in the features ``[ω, q, (ωy ωz, ωz ωx, ωx ωy), ω̇, q ⊗ ω]`` with
coefficients that depend on the principal inertias only. :func:`rotation_rates` and :func:`rotation_substeps` are the
RK4 sub-steps of :func:`oacli.estimation.propagation.propagate_intervals_structured` built on these maps; they are
pinned to the general dynamics (:func:`oacli.estimation.propagation.dynamics_batch`) by the tests.
"""

from __future__ import annotations

import functools

import numpy as np

# Non-zero entries of [∂ż/∂z | ∂ż/∂I] (7×10) and of q̇ as linear maps of the features
# [ω (3), q (4), (ωy ωz, ωz ωx, ωx ωy) (3), ω̇ (3), q ⊗ ω products (12: q_i ω_j at 13 + 3 i + j)]:
# (row, column, feature, coefficient); ``inertia`` entries are filled in by :func:`_rate_map`.
_WX, _WY, _WZ, _QX, _QY, _QZ, _QW, _P1, _P2, _P3, _F4, _F5, _F6 = range(13)
_N_FEATURES = 25
_Q_ROWS = (
    (0, 1, _WZ, 0.5), (0, 2, _WY, -0.5), (0, 3, _WX, 0.5),
    (1, 0, _WZ, -0.5), (1, 2, _WX, 0.5), (1, 3, _WY, 0.5),
    (2, 0, _WY, 0.5), (2, 1, _WX, -0.5), (2, 3, _WZ, 0.5),
    (3, 0, _WX, -0.5), (3, 1, _WY, -0.5), (3, 2, _WZ, -0.5),
    (0, 4, _QW, 0.5), (0, 5, _QZ, -0.5), (0, 6, _QY, 0.5),
    (1, 4, _QZ, 0.5), (1, 5, _QW, 0.5), (1, 6, _QX, -0.5),
    (2, 4, _QY, -0.5), (2, 5, _QX, 0.5), (2, 6, _QW, 0.5),
    (3, 4, _QX, -0.5), (3, 5, _QY, -0.5), (3, 6, _QZ, -0.5),
)


@functools.lru_cache(maxsize=64)
def _rate_map(inertia: tuple[float, float, float]) -> np.ndarray:
    """Matrix (25, 74) mapping the features of :func:`rotational_rate` to ``[jacobian (70), q̇ (4)]``
    (cached per inertia: a filter asks for the same one many times; read-only). Its two non-zero blocks are used
    apart (:func:`rate_map_blocks`)."""
    ix, iy, iz = inertia
    out = np.zeros((_N_FEATURES, 74))
    entries = [
        *_Q_ROWS,
        (4, 5, _WZ, -(iz - iy) / ix), (4, 6, _WY, -(iz - iy) / ix),
        (5, 4, _WZ, -(ix - iz) / iy), (5, 6, _WX, -(ix - iz) / iy),
        (6, 4, _WY, -(iy - ix) / iz), (6, 5, _WX, -(iy - ix) / iz),
        (4, 7, _F4, -1.0 / ix), (4, 8, _P1, 1.0 / ix), (4, 9, _P1, -1.0 / ix),
        (5, 7, _P2, -1.0 / iy), (5, 8, _F5, -1.0 / iy), (5, 9, _P2, 1.0 / iy),
        (6, 7, _P3, 1.0 / iz), (6, 8, _P3, -1.0 / iz), (6, 9, _F6, -1.0 / iz),
    ]
    for row, col, feature, coef in entries:
        out[feature, 10 * row + col] = coef
    # q̇ = ½ Ξ(q) ω: the coefficients of ∂q̇/∂ω (rows 0-3, columns 4-6) on the products q_i ω_j.
    for row, col, feature, coef in _Q_ROWS[12:]:
        out[13 + 3 * (feature - _QX) + (col - 4), 70 + row] = coef
    out.setflags(write=False)
    return out


def _constant_rate_blocks() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parts of :func:`_rate_map` that do not depend on the inertia: its Jacobian block with the q̇ rows'
    entries (13, 70), its q̇ block (12, 4), and the flat positions in the Jacobian block of the 15 entries that do."""
    full = _rate_map((1.0, 2.0, 3.0))  # any inertia: its own entries are overwritten
    jac_map = np.array(full[0:13, 0:70])
    qdot_map = np.ascontiguousarray(full[13:_N_FEATURES, 70:74])
    qdot_map.setflags(write=False)
    positions = np.array([70 * feature + 10 * row + col for row, col, feature in _INERTIA_ENTRIES])
    jac_map.ravel()[positions] = 0.0
    jac_map.setflags(write=False)
    return jac_map, qdot_map, positions


_INERTIA_ENTRIES = (  # (row, column, feature) of the entries of _rate_map with inertia-dependent coefficients
    (4, 5, _WZ), (4, 6, _WY), (5, 4, _WZ), (5, 6, _WX), (6, 4, _WY), (6, 5, _WX),
    (4, 7, _F4), (4, 8, _P1), (4, 9, _P1), (5, 7, _P2), (5, 8, _F5), (5, 9, _P2), (6, 7, _P3), (6, 8, _P3),
    (6, 9, _F6),
)


@functools.lru_cache(maxsize=64)
def rate_map_blocks(inertia: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The non-zero blocks of :func:`_rate_map`: the first 13 features to the Jacobian (13, 70) and the 12 products
    ``q_i ω_j`` to ``q̇`` (12, 4) (the other two blocks are zero; two small products instead of one 25×74). Built
    from the constant parts and the 15 inertia-dependent coefficients (the filter's θ changes at every record, so
    this cache rarely hits there); read-only.

    Parameters
    ----------
    inertia : tuple of 3 float
        Principal moments of inertia ``(Ixx, Iyy, Izz)`` [kg·m²] (hashable: the result is cached).

    Returns
    -------
    jac_map : ndarray, shape (13, 70), read-only
        Maps the features ``[ω (3), q (4), (ωy ωz, ωz ωx, ωx ωy) (3), ω̇ (3)]`` to ``[∂ż/∂z | ∂ż/∂I]`` (7×10,
        row-major) of [Doerr2021] Eqs. 35a-35b.
    qdot_map : ndarray, shape (12, 4), read-only
        Maps the products ``q_i ω_j`` (at ``3 i + j``) to ``q̇ = ½ Ξ(q) ω`` ([Doerr2021] Eq. 36).
    """
    ix, iy, iz = inertia
    jac_map = _CONSTANT_RATE_BLOCKS[0].copy()
    jac_map.ravel()[_CONSTANT_RATE_BLOCKS[2]] = (
        -(iz - iy) / ix, -(iz - iy) / ix, -(ix - iz) / iy, -(ix - iz) / iy, -(iy - ix) / iz, -(iy - ix) / iz,
        -1.0 / ix, 1.0 / ix, -1.0 / ix, -1.0 / iy, -1.0 / iy, 1.0 / iy, 1.0 / iz, -1.0 / iz, -1.0 / iz)
    jac_map.setflags(write=False)
    return jac_map, _CONSTANT_RATE_BLOCKS[1]

_CONSTANT_RATE_BLOCKS = _constant_rate_blocks()


def rotational_rate(
    z: np.ndarray, tau: np.ndarray, inertia: np.ndarray, rate_map: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """ż (K, 7) of ``z = [q, ω]`` ([Doerr2021] Eqs. 35a-35b) and ``[∂ż/∂z | ∂ż/∂I]`` (K, 7, 10).

    Every entry is linear in a few features of z (ω, q, products of two rates, ω̇, products q_i ω_j), so all of them
    come from products with the blocks of ``rate_map`` (:func:`rate_map_blocks`). ``q̇ = ½ Ξ(q) ω`` with Ξ of
    [Doerr2021] Eq. 36, ``ω̇ = J⁻¹(τ − ω × Jω)`` with ``J = diag(Ixx, Iyy, Izz)``.

    Parameters
    ----------
    z : ndarray, shape (K, 7)
        Rotational states ``[q (x, y, z, w), ω rad/s]``.
    tau : ndarray, shape (K, 3) or (3,)
        Body-frame torques [N·m].
    inertia : ndarray, shape (3,)
        Principal moments of inertia ``[Ixx, Iyy, Izz]`` [kg·m²].
    rate_map : tuple of ndarray
        ``rate_map_blocks(tuple(inertia))``: the (13, 70) and (12, 4) feature maps at the same inertia.

    Returns
    -------
    zdot : ndarray, shape (K, 7)
        ``[q̇ 1/s, ω̇ rad/s²]``.
    jacobian : ndarray, shape (K, 7, 10)
        ``∂ż/∂z`` (columns 0-6, on ``[q, ω]``) and ``∂ż/∂[Ixx, Iyy, Izz]`` (columns 7-9, per kg·m²).
    """
    k = z.shape[0]
    w = z[:, 4:7]
    feats = np.empty((k, _N_FEATURES))
    feats[:, 0:3] = w
    feats[:, 3:7] = z[:, 0:4]
    prod = w[:, [1, 2, 0]] * w[:, [2, 0, 1]]
    feats[:, 7:10] = prod
    feats[:, 10:13] = (tau - (inertia[[2, 0, 1]] - inertia[[1, 2, 0]]) * prod) / inertia
    feats[:, 13:25] = (z[:, 0:4, None] * w[:, None, :]).reshape(k, 12)
    jac_map, qdot_map = rate_map
    f = np.empty((k, 7))
    f[:, 0:4] = feats[:, 13:25] @ qdot_map
    f[:, 4:7] = feats[:, 10:13]
    return f, (feats[:, 0:13] @ jac_map).reshape(k, 7, 10)


def rotation_rates(z: np.ndarray, tau: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """ż (K, 7) of the rotational state ``z = [q, ω]`` ([Doerr2021] Eqs. 35a-35b; the operations of
    :func:`dynamics_batch`).

    ``q̇ = ½ Ξ(q) ω`` (Ξ of [Doerr2021] Eq. 36) and ``ω̇ = J⁻¹(τ − ω × Jω)``, ``J = diag(Ixx, Iyy, Izz)``; no
    Jacobians (the end-state-only propagation).

    Parameters
    ----------
    z : ndarray, shape (K, 7)
        Rotational states ``[q (x, y, z, w), ω rad/s]``.
    tau : ndarray, shape (K, 3)
        Body-frame torques [N·m].
    inertia : ndarray, shape (3,)
        Principal moments of inertia ``[Ixx, Iyy, Izz]`` [kg·m²].

    Returns
    -------
    ndarray, shape (K, 7)
        ``[q̇ 1/s, ω̇ rad/s²]``.
    """
    qx, qy, qz, qw = z[:, 0], z[:, 1], z[:, 2], z[:, 3]
    wx, wy, wz = z[:, 4], z[:, 5], z[:, 6]
    ix, iy, iz = inertia
    f = np.empty_like(z)
    f[:, 0] = 0.5 * (qw * wx - qz * wy + qy * wz)
    f[:, 1] = 0.5 * (qz * wx + qw * wy - qx * wz)
    f[:, 2] = 0.5 * (-qy * wx + qx * wy + qw * wz)
    f[:, 3] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    f[:, 4] = (tau[:, 0] - (iz - iy) * wy * wz) / ix
    f[:, 5] = (tau[:, 1] - (ix - iz) * wz * wx) / iy
    f[:, 6] = (tau[:, 2] - (iy - ix) * wx * wy) / iz
    return f


def rotation_substeps(z: np.ndarray, tau: np.ndarray, inertia: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """End states (K, 7) of the RK4 sub-steps of the rotational state of K intervals (the simulator's stages and
    quaternion normalisation; the translation is in closed form, see :func:`propagate_intervals_structured`).

    Integrates [Doerr2021] Eqs. 35a-35b (:func:`rotation_rates`) with the torque held over each interval.

    Parameters
    ----------
    z : ndarray, shape (K, 7)
        Rotational states ``[q (x, y, z, w), ω rad/s]`` at the intervals' starts.
    tau : ndarray, shape (K, 3)
        Body-frame torques [N·m], constant over each interval.
    inertia : ndarray, shape (3,)
        Principal moments of inertia ``[Ixx, Iyy, Izz]`` [kg·m²].
    durations : ndarray, shape (K, M)
        Sub-step durations [s] (:func:`oacli.estimation.propagation.substep_schedule`); zeros are skipped.

    Returns
    -------
    ndarray, shape (K, 7)
        Rotational states at the intervals' ends, each quaternion of unit norm with ``w >= 0``.
    """
    for col in range(durations.shape[1]):
        dt = durations[:, col]
        active = dt > 0.0
        h = dt[:, None]
        z2 = z + 0.5 * h * (f1 := rotation_rates(z, tau, inertia))
        z3 = z + 0.5 * h * (f2 := rotation_rates(z2, tau, inertia))
        z4 = z + h * (f3 := rotation_rates(z3, tau, inertia))
        f4 = rotation_rates(z4, tau, inertia)
        z_new = z + (h / 6.0) * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
        q = z_new[:, 0:4]
        norm = np.sqrt(np.einsum("ki,ki->k", q, q))
        sign = np.where(q[:, 3] < 0.0, -1.0, 1.0)
        z_new[:, 0:4] = sign[:, None] * (q / norm[:, None])
        z = z_new if np.all(active) else np.where(active[:, None], z_new, z)
    return z
