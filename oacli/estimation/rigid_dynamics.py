"""The process model of the full rigid body (:mod:`oacli.estimation.rigid_parameters`) with exact Jacobians.

The dynamics of [Doerr2021] Eqs. 34-35 about the centre of mass, with the wrench Astrobee's body-fixed actuators
deliver ([ReSWARM2023] §3, Eqs. 38-39; :mod:`oacli.sim.actuators`):

    F_b = κ_F ⊙ (Rᵀ F),   v̇ = R F_b / m,   ω̇ = J⁻¹ (κ_τ ⊙ τ − c × F_b − ω × J ω),   q̇ = ½ Ξ(q) ω

with the full inertia tensor ``J``. As in the simulator (and :mod:`oacli.estimation.propagation`), each interval
between records is integrated on the plant's grid, the input held; the wrench is evaluated at the attitude at the
start of every sub-step and held over its four RK4 stages (what :func:`oacli.sim.simulator.simulate` does), so
noise-free data of the simulator are fitted exactly. Within a sub-step the acceleration is then constant, so the
translation is closed form: ``v⁺ = v + Σ h_i a_i``, ``r⁺ = r + T v + Σ (½ h_i² + h_i (T − s_i − h_i)) a_i`` (``s_i``
the sub-step's start within the interval of length ``T``). The rotation ``z = [q, ω]`` is integrated sub-step by
sub-step with its Jacobian with respect to ``[z_0, θ]`` carried through every RK4 stage, the held wrench's
dependence on the sub-step's initial attitude, and every quaternion normalisation (chain rule, as
:func:`oacli.estimation.propagation.propagate_intervals` does for θ = [m, Ixx, Iyy, Izz]).
"""

from __future__ import annotations

import numpy as np

from oacli.estimation.rigid_parameters import N_FULL, inertia_tensor
from oacli.sim.actuators import delivered_wrench_floats

STATE_DIM = 13
_NZ = 7

__all__ = ["accelerations_full", "propagate_full", "propagate_full_one", "rotation_matrices", "wrench_full"]


def rotation_matrices(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R(q)`` (K, 3, 3) for unit quaternions ``q = [x, y, z, w]`` and ``∂R/∂q`` (K, 4, 3, 3) projected on the
    tangent of the unit sphere (``R(q/|q|)``'s derivative at ``|q| = 1``: no radial part).

    Parameters
    ----------
    q : ndarray, shape (K, 4)

    Returns
    -------
    rot : ndarray, shape (K, 3, 3)
    d_rot : ndarray, shape (K, 4, 3, 3)
    """
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    k = q.shape[0]
    rot = np.empty((k, 3, 3))
    rot[:, 0, 0] = 1 - 2 * (y * y + z * z)
    rot[:, 0, 1] = 2 * (x * y - z * w)
    rot[:, 0, 2] = 2 * (x * z + y * w)
    rot[:, 1, 0] = 2 * (x * y + z * w)
    rot[:, 1, 1] = 1 - 2 * (x * x + z * z)
    rot[:, 1, 2] = 2 * (y * z - x * w)
    rot[:, 2, 0] = 2 * (x * z - y * w)
    rot[:, 2, 1] = 2 * (y * z + x * w)
    rot[:, 2, 2] = 1 - 2 * (x * x + y * y)
    d = np.zeros((k, 4, 3, 3))
    x2, y2, z2, w2 = 2 * x, 2 * y, 2 * z, 2 * w
    d[:, 0, 0, 1] = d[:, 0, 1, 0] = y2
    d[:, 0, 0, 2] = d[:, 0, 2, 0] = z2
    d[:, 0, 1, 1] = d[:, 0, 2, 2] = -4 * x
    d[:, 0, 1, 2], d[:, 0, 2, 1] = -w2, w2
    d[:, 1, 0, 0] = d[:, 1, 2, 2] = -4 * y
    d[:, 1, 0, 1] = d[:, 1, 1, 0] = x2
    d[:, 1, 0, 2], d[:, 1, 2, 0] = w2, -w2
    d[:, 1, 1, 2] = d[:, 1, 2, 1] = z2
    d[:, 2, 0, 0] = d[:, 2, 1, 1] = -4 * z
    d[:, 2, 0, 1], d[:, 2, 1, 0] = -w2, w2
    d[:, 2, 0, 2] = d[:, 2, 2, 0] = x2
    d[:, 2, 1, 2] = d[:, 2, 2, 1] = y2
    d[:, 3, 0, 1], d[:, 3, 1, 0] = -z2, z2
    d[:, 3, 0, 2], d[:, 3, 2, 0] = y2, -y2
    d[:, 3, 1, 2], d[:, 3, 2, 1] = -x2, x2
    # Projection on the tangent: ∂R(q/|q|)/∂q = Σ_j ∂R/∂q_j (δ_ji − q_j q_i) at |q| = 1.
    radial = np.einsum("kj,kjab->kab", q, d)
    d = d - q[:, :, None, None] * radial[:, None]
    return rot, d


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` along the last axis (written out: ``np.cross`` costs 10× more on small stacks)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    k = v.shape[0]
    out = np.zeros((k, 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


def wrench_full(q: np.ndarray, u: np.ndarray, theta: np.ndarray, derivatives: bool = True
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The delivered wrench ``[R F_b, κ_τ ⊙ τ − c × F_b]`` (module docstring) and its derivatives.

    Parameters
    ----------
    q : ndarray, shape (K, 4)
        Unit attitudes.
    u : ndarray, shape (K, 6)
        Commanded force (world) [N] and torque (body) [N·m].
    theta : ndarray, shape (16,)
    derivatives : bool
        Also return the derivatives.

    Returns
    -------
    w : ndarray, shape (K, 6)
        World force [N], torque about the centre of mass (body) [N·m].
    d_q : ndarray, shape (K, 6, 4) or None
        ``∂w/∂q`` (tangent-projected).
    d_theta : ndarray, shape (K, 6, 16) or None
        ``∂w/∂θ``.
    """
    kf, kt, c = theta[10:13], theta[13:16], theta[7:10]
    rot, d_rot = rotation_matrices(q)
    f = u[:, 0:3]
    fb0 = np.einsum("kji,kj->ki", rot, f)  # Rᵀ F
    fb = kf * fb0
    w = np.empty((q.shape[0], 6))
    w[:, 0:3] = np.einsum("kij,kj->ki", rot, fb)
    w[:, 3:6] = kt * u[:, 3:6] - _cross(c, fb)
    if not derivatives:
        return w, None, None
    k = q.shape[0]
    d_fb0 = np.einsum("knji,kj->kin", d_rot, f)  # (K, 3, 4)
    d_fb = kf[None, :, None] * d_fb0
    d_q = np.empty((k, 6, 4))
    d_q[:, 0:3] = np.einsum("knij,kj->kin", d_rot, fb) + rot @ d_fb
    d_q[:, 3:6] = -np.einsum("ab,kbn->kan", _skew(c[None])[0], d_fb)
    d_th = np.zeros((k, 6, N_FULL))
    d_th[:, 0:3, 10:13] = rot * fb0[:, None, :]
    # ∂(−c × F_b)/∂κ_F,j = −c × e_j (Rᵀ F)_j ;  ∂(−c × F_b)/∂c = [F_b]×
    d_th[:, 3:6, 10:13] = -_skew(c[None])[0] * fb0[:, None, :]
    d_th[:, 3:6, 7:10] = _skew(fb)
    d_th[:, 3, 13], d_th[:, 4, 14], d_th[:, 5, 15] = u[:, 3], u[:, 4], u[:, 5]
    return w, d_q, d_th


def _rotation_rate(z: np.ndarray, tau: np.ndarray, j: np.ndarray, j_inv: np.ndarray, jacobians: bool
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``ż = [½ Ξ(q) ω, J⁻¹(τ − ω × Jω)]`` (K, 7), ``∂ż/∂z`` (K, 7, 7) and ``∂ω̇/∂J`` (K, 3, 6) with τ held."""
    qx, qy, qz, qw = z[:, 0], z[:, 1], z[:, 2], z[:, 3]
    w = z[:, 4:7]
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    jw = w @ j.T
    wdot = (tau - _cross(w, jw)) @ j_inv.T
    out = np.empty((z.shape[0], _NZ))
    out[:, 0] = 0.5 * (qw * wx - qz * wy + qy * wz)
    out[:, 1] = 0.5 * (qz * wx + qw * wy - qx * wz)
    out[:, 2] = 0.5 * (-qy * wx + qx * wy + qw * wz)
    out[:, 3] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    out[:, 4:7] = wdot
    if not jacobians:
        return out, None, None
    k = z.shape[0]
    jz = np.zeros((k, _NZ, _NZ))
    h = 0.5
    jz[:, 0, 1], jz[:, 0, 2], jz[:, 0, 3] = h * wz, -h * wy, h * wx
    jz[:, 1, 0], jz[:, 1, 2], jz[:, 1, 3] = -h * wz, h * wx, h * wy
    jz[:, 2, 0], jz[:, 2, 1], jz[:, 2, 3] = h * wy, -h * wx, h * wz
    jz[:, 3, 0], jz[:, 3, 1], jz[:, 3, 2] = -h * wx, -h * wy, -h * wz
    jz[:, 0, 4], jz[:, 0, 5], jz[:, 0, 6] = h * qw, -h * qz, h * qy
    jz[:, 1, 4], jz[:, 1, 5], jz[:, 1, 6] = h * qz, h * qw, -h * qx
    jz[:, 2, 4], jz[:, 2, 5], jz[:, 2, 6] = -h * qy, h * qx, h * qw
    jz[:, 3, 4], jz[:, 3, 5], jz[:, 3, 6] = -h * qx, -h * qy, -h * qz
    # ∂ω̇/∂ω = −J⁻¹ ([ω]× J − [Jω]×)
    jz[:, 4:7, 4:7] = -j_inv @ (_skew(w) @ j - _skew(jw))
    # ∂ω̇/∂J_e = −J⁻¹ (ω × E_e ω + E_e ω̇)
    ew = _basis_products(w)
    terms = _cross(w[:, None, :], ew)
    terms += _basis_products(wdot)
    jj = -(terms @ j_inv.T).transpose(0, 2, 1)
    return out, jz, jj


def _basis_products(v: np.ndarray) -> np.ndarray:
    """``E_e v`` (K, 6, 3) for the symmetric basis matrices of J's entries [xx, yy, zz, xy, xz, yz]."""
    out = np.zeros((v.shape[0], 6, 3))
    out[:, 0, 0] = out[:, 3, 1] = out[:, 4, 2] = v[:, 0]
    out[:, 1, 1] = out[:, 3, 0] = out[:, 5, 2] = v[:, 1]
    out[:, 2, 2] = out[:, 4, 0] = out[:, 5, 1] = v[:, 2]
    return out


def accelerations_full(x: np.ndarray, u: np.ndarray, theta: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``[v̇, ω̇]`` of the continuous dynamics at ``x`` (module docstring) and its Jacobians (the accelerometer and
    gyro-slope rows of the batch problem).

    Parameters
    ----------
    x : ndarray, shape (K, 13)
    u : ndarray, shape (K, 6)
    theta : ndarray, shape (16,)

    Returns
    -------
    acc : ndarray, shape (K, 6)
        [m/s², rad/s²].
    d_x : ndarray, shape (K, 6, 13)
    d_theta : ndarray, shape (K, 6, 16)
    """
    j = inertia_tensor(theta)
    j_inv = np.linalg.inv(j)
    m = float(theta[0])
    wr, wq, wth = wrench_full(x[:, 6:10], u, theta)
    assert wq is not None and wth is not None
    rate, jz, jj = _rotation_rate(x[:, 6:13], wr[:, 3:6], j, j_inv, True)
    assert jz is not None and jj is not None
    k = x.shape[0]
    acc = np.empty((k, 6))
    acc[:, 0:3] = wr[:, 0:3] / m
    acc[:, 3:6] = rate[:, 4:7]
    d_x = np.zeros((k, 6, STATE_DIM))
    d_x[:, 0:3, 6:10] = wq[:, 0:3] / m
    d_x[:, 3:6, 6:10] = j_inv @ wq[:, 3:6]
    d_x[:, 3:6, 10:13] = jz[:, 4:7, 4:7]
    d_th = np.zeros((k, 6, N_FULL))
    d_th[:, 0:3] = wth[:, 0:3] / m
    d_th[:, 0:3, 0] -= wr[:, 0:3] / m**2
    d_th[:, 3:6] = j_inv @ wth[:, 3:6]
    d_th[:, 3:6, 1:7] += jj
    return acc, d_x, d_th


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as a slice when it is a contiguous run (basic indexing: views, in-place sums), else itself."""
    if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
        return slice(int(index[0]), int(index[0]) + index.size)
    return index


def propagate_full(x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray, *,
                   jacobians: bool = True, columns: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Integrate K intervals of the full model, each from its own state with its own held input.

    Parameters
    ----------
    x : ndarray, shape (K, 13)
        Start states (unit quaternions).
    u : ndarray, shape (K, 6)
        Commanded inputs held over each interval [N world frame, N·m body frame].
    theta : ndarray, shape (16,)
        θ (:mod:`oacli.estimation.rigid_parameters`).
    durations : ndarray, shape (K, M)
        Sub-step durations from :func:`oacli.estimation.propagation.substep_schedule` (zeros skipped exactly).
    jacobians : bool
        False: the end states only.
    columns : ndarray of int, optional
        The θ entries to differentiate by (increasing; the estimated ones, :attr:`ParameterSet.index`): the
        sensitivities carried through the sub-steps have ``7 + len(columns)`` columns instead of 23, and ``c`` is
        zero in the others. Default: all 16.

    Returns
    -------
    x_next : ndarray, shape (K, 13)
    a : ndarray, shape (K, 13, 13) or None
        ``∂x_next/∂x``.
    c : ndarray, shape (K, 13, 16) or None
        ``∂x_next/∂θ``.
    """
    x = np.array(x, dtype=float, ndmin=2)
    u = np.array(u, dtype=float, ndmin=2)
    durations = np.array(durations, dtype=float, ndmin=2)
    theta = np.asarray(theta, dtype=float)
    k = x.shape[0]
    m = float(theta[0])
    j = inertia_tensor(theta)
    j_inv = np.linalg.inv(j)
    cols = np.arange(N_FULL) if columns is None else np.asarray(columns, dtype=int)
    all_cols = cols.size == N_FULL
    th_cols = slice(None) if all_cols else _as_slice(cols)
    # Where the inertia entries (θ 1..6: ∂ω̇/∂J, module docstring) and the mass (θ 0) sit among the carried columns.
    j_local = np.flatnonzero((cols >= 1) & (cols <= 6))
    j_sel = _as_slice(cols[j_local] - 1)
    j_dst = _as_slice(_NZ + j_local)
    mass_local = int(np.flatnonzero(cols == 0)[0]) if np.any(cols == 0) else None
    nc = _NZ + cols.size
    total_s = durations.sum(axis=1)
    z = x[:, 6:13].copy()
    v_sum = np.zeros((k, 3))
    r_sum = np.zeros((k, 3))
    d_z = d_v = d_r = None
    if jacobians:
        d_z = np.zeros((k, _NZ, nc))
        d_z[:, :, 0:_NZ] = np.eye(_NZ)
        d_v = np.zeros((k, 3, nc))
        d_r = np.zeros((k, 3, nc))
    elapsed = np.zeros(k)
    all_active = bool(np.all(durations > 0.0))
    for col in range(durations.shape[1]):
        h = durations[:, col]
        active = h > 0.0
        if not all_active and not np.any(active):
            continue
        wr, wq, wth = wrench_full(z[:, 0:4], u, theta, jacobians)
        tau = wr[:, 3:6]
        acc = wr[:, 0:3] / m
        weight = 0.5 * h * h + h * (total_s - elapsed - h)
        v_sum += h[:, None] * acc
        r_sum += weight[:, None] * acc
        hv = h[:, None]
        g_tau = None
        if jacobians:
            assert d_z is not None and d_v is not None and d_r is not None and wq is not None and wth is not None
            dq0 = d_z[:, 0:4, :]
            g_acc = wq[:, 0:3] @ dq0
            g_acc[:, :, _NZ:] += wth[:, 0:3, th_cols]
            g_acc /= m
            if mass_local is not None:
                g_acc[:, :, _NZ + mass_local] -= acc / m
            d_v += h[:, None, None] * g_acc
            d_r += weight[:, None, None] * g_acc
            g_tau = wq[:, 3:6] @ dq0
            g_tau[:, :, _NZ:] += wth[:, 3:6, th_cols]
            g_tau = j_inv @ g_tau  # ∂ω̇/∂(held τ) · ∂τ/∂[z0, θ]
        ks: list[np.ndarray] = []
        d_sum = None  # Σ_s w_s dk_s (RK4 weights 1, 2, 2, 1)
        dk = None
        for coef, weight in ((0.0, 1.0), (0.5, 2.0), (0.5, 2.0), (1.0, 1.0)):
            zs = z if not ks else z + coef * hv * ks[-1]
            f, jz, jj = _rotation_rate(zs, tau, j, j_inv, jacobians)
            ks.append(f)
            if jacobians:
                assert d_z is not None and jz is not None and jj is not None and g_tau is not None
                ds = d_z if dk is None else d_z + (coef * h)[:, None, None] * dk
                # ż's Jacobian: the q rows on [q, ω], the ω rows on ω only (the torque is held)
                dk = np.empty_like(ds)
                np.matmul(jz[:, 0:4, 0:4], ds[:, 0:4], out=dk[:, 0:4])
                dk[:, 0:4] += jz[:, 0:4, 4:7] @ ds[:, 4:7]
                np.matmul(jz[:, 4:7, 4:7], ds[:, 4:7], out=dk[:, 4:7])
                dk[:, 4:7] += g_tau
                dk[:, 4:7, j_dst] += jj[:, :, j_sel]
                if d_sum is None:
                    d_sum = dk.copy()
                else:
                    d_sum += weight * dk
        z_new = z + (hv / 6.0) * (ks[0] + 2.0 * ks[1] + 2.0 * ks[2] + ks[3])
        q = z_new[:, 0:4]
        norm = np.sqrt(np.einsum("ki,ki->k", q, q))
        sign = np.where(q[:, 3] < 0.0, -1.0, 1.0)
        q_hat = q / norm[:, None]
        z_new[:, 0:4] = sign[:, None] * q_hat
        if jacobians:
            assert d_z is not None and d_sum is not None
            d_sum *= (h / 6.0)[:, None, None]
            d_sum += d_z
            proj = (np.eye(4) - q_hat[:, :, None] * q_hat[:, None, :]) * (sign / norm)[:, None, None]
            d_sum[:, 0:4, :] = proj @ d_sum[:, 0:4, :]
            d_z = d_sum if all_active else np.where(active[:, None, None], d_sum, d_z)
        z = z_new if all_active else np.where(active[:, None], z_new, z)
        elapsed += h
    x_next = np.empty_like(x)
    x_next[:, 0:3] = x[:, 0:3] + total_s[:, None] * x[:, 3:6] + r_sum
    x_next[:, 3:6] = x[:, 3:6] + v_sum
    x_next[:, 6:13] = z
    if not jacobians:
        return x_next, None, None
    assert d_z is not None and d_v is not None and d_r is not None
    a = np.zeros((k, STATE_DIM, STATE_DIM))
    a[:, 0:6, 0:6] = np.eye(6)
    a[:, 0, 3] = a[:, 1, 4] = a[:, 2, 5] = total_s
    a[:, 0:3, 6:13] = d_r[:, :, 0:_NZ]
    a[:, 3:6, 6:13] = d_v[:, :, 0:_NZ]
    a[:, 6:13, 6:13] = d_z[:, :, 0:_NZ]
    c = np.empty((k, STATE_DIM, N_FULL)) if all_cols else np.zeros((k, STATE_DIM, N_FULL))
    c[:, 0:3, th_cols] = d_r[:, :, _NZ:]
    c[:, 3:6, th_cols] = d_v[:, :, _NZ:]
    c[:, 6:13, th_cols] = d_z[:, :, _NZ:]
    return x_next, a, c


def propagate_full_one(x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray, *,
                       jacobians: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`propagate_full` for a single interval (a filter step): the same outputs, the states integrated in
    Python floats and the stage Jacobians of all sub-steps evaluated at once.

    As :func:`oacli.estimation.propagation.propagate_one` does for θ = [m, Ixx, Iyy, Izz]: the sub-steps are
    integrated first (the wrench of :func:`oacli.sim.actuators.delivered_wrench_floats` at each sub-step's start,
    RK4 of ``ω̇ = J⁻¹(τ − ω × Jω)``), their stage points kept; the wrench and rate Jacobians are then formed in one
    vectorised call each and chained sub-step by sub-step.

    Parameters
    ----------
    x : ndarray, shape (13,) or (1, 13)
    u : ndarray, shape (6,) or (1, 6)
    theta : ndarray, shape (16,)
    durations : ndarray, shape (M,) or (1, M)
        Sub-step durations [s] (zeros skipped).
    jacobians : bool
        False: the end state only (a warm start's record, :func:`oacli.estimation.batch.extend_states`).

    Returns
    -------
    x_next : ndarray, shape (13,)
    a : ndarray, shape (13, 13) or None
        ``∂x_next/∂x``.
    c : ndarray, shape (13, 16) or None
        ``∂x_next/∂θ``.
    """
    x = np.asarray(x, dtype=float).reshape(STATE_DIM)
    u = np.asarray(u, dtype=float).reshape(6)
    theta = np.asarray(theta, dtype=float)
    dts = [float(d) for d in np.asarray(durations, dtype=float).reshape(-1) if d > 0.0]
    n = len(dts)
    m = float(theta[0])
    j = inertia_tensor(theta)
    j_inv = np.linalg.inv(j)
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = j.tolist()
    (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = j_inv.tolist()
    kf = (float(theta[10]), float(theta[11]), float(theta[12]))
    r = (float(theta[7]), float(theta[8]), float(theta[9]))
    f0, f1, f2 = (float(v) for v in u[0:3])
    t0, t1, t2 = (float(v) for v in theta[13:16] * u[3:6])
    total_s = float(sum(dts))
    qx, qy, qz, qw, wx, wy, wz = (float(v) for v in x[6:13])
    starts: list[tuple[float, ...]] = []
    stages: list[tuple[float, ...]] = []
    taus: list[tuple[float, float, float]] = []
    accs: list[tuple[float, float, float]] = []
    raw: list[tuple[float, ...]] = []
    vx, vy, vz = (float(v) for v in x[3:6])
    rx, ry, rz = 0.0, 0.0, 0.0
    elapsed = 0.0
    for h in dts:
        g0, g1, g2, tx, ty, tz = delivered_wrench_floats(f0, f1, f2, t0, t1, t2, qx, qy, qz, qw, kf, r)
        starts.append((qx, qy, qz, qw))
        taus.append((tx, ty, tz))
        ax, ay, az = g0 / m, g1 / m, g2 / m
        accs.append((ax, ay, az))
        weight = 0.5 * h * h + h * (total_s - elapsed - h)
        rx, ry, rz = rx + weight * ax, ry + weight * ay, rz + weight * az
        vx, vy, vz = vx + h * ax, vy + h * ay, vz + h * az
        elapsed += h

        def rate(px: float, py: float, pz: float, pw: float, ox: float, oy: float, oz: float,
                 tx: float = tx, ty: float = ty, tz: float = tz) -> tuple[float, ...]:
            hx, hy, hz = j00 * ox + j01 * oy + j02 * oz, j10 * ox + j11 * oy + j12 * oz, j20 * ox + j21 * oy + j22 * oz
            bx, by, bz = tx - (oy * hz - oz * hy), ty - (oz * hx - ox * hz), tz - (ox * hy - oy * hx)
            return (0.5 * (pw * ox - pz * oy + py * oz), 0.5 * (pz * ox + pw * oy - px * oz),
                    0.5 * (-py * ox + px * oy + pw * oz), 0.5 * (-px * ox - py * oy - pz * oz),
                    i00 * bx + i01 * by + i02 * bz, i10 * bx + i11 * by + i12 * bz, i20 * bx + i21 * by + i22 * bz)

        z = (qx, qy, qz, qw, wx, wy, wz)
        k1 = rate(*z)
        s2 = tuple(a + 0.5 * h * b for a, b in zip(z, k1, strict=True))
        k2 = rate(*s2)
        s3 = tuple(a + 0.5 * h * b for a, b in zip(z, k2, strict=True))
        k3 = rate(*s3)
        s4 = tuple(a + h * b for a, b in zip(z, k3, strict=True))
        k4 = rate(*s4)
        stages += (z, s2, s3, s4)
        qx, qy, qz, qw, wx, wy, wz = (a + (h / 6.0) * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
                                      for a, b1, b2, b3, b4 in zip(z, k1, k2, k3, k4, strict=True))
        raw.append((qx, qy, qz, qw))
        norm = float(np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw))
        sgn = (-1.0 if qw < 0.0 else 1.0) / norm
        qx, qy, qz, qw = sgn * qx, sgn * qy, sgn * qz, sgn * qw
    x_next = np.empty(STATE_DIM)
    x_next[0:3] = x[0:3] + total_s * x[3:6] + np.array([rx, ry, rz])
    x_next[3:6] = [vx, vy, vz]
    x_next[6:13] = [qx, qy, qz, qw, wx, wy, wz]
    if not jacobians:
        return x_next, None, None
    a = np.eye(STATE_DIM)
    a[0, 3] = a[1, 4] = a[2, 5] = total_s
    c = np.zeros((STATE_DIM, N_FULL))
    if n == 0:
        return x_next, a, c
    nc = _NZ + N_FULL
    _, wq, wth = wrench_full(np.array(starts), np.broadcast_to(u, (n, 6)), theta)
    assert wq is not None and wth is not None
    tau_rep = np.repeat(np.array(taus), 4, axis=0)
    _, jz_all, jj_all = _rotation_rate(np.array(stages), tau_rep, j, j_inv, True)
    assert jz_all is not None and jj_all is not None
    jz_all = jz_all.reshape(n, 4, _NZ, _NZ)
    jj_all = jj_all.reshape(n, 4, 3, 6)
    acc_arr = np.array(accs)
    q_raw = np.array(raw)
    d_z = np.zeros((_NZ, nc))
    d_z[:, 0:_NZ] = np.eye(_NZ)
    d_v = np.zeros((3, nc))
    d_r = np.zeros((3, nc))
    elapsed = 0.0
    for i, h in enumerate(dts):
        dq0 = d_z[0:4]
        g_acc = wq[i, 0:3] @ dq0
        g_acc[:, _NZ:] += wth[i, 0:3]
        g_acc /= m
        g_acc[:, _NZ] -= acc_arr[i] / m
        weight = 0.5 * h * h + h * (total_s - elapsed - h)
        elapsed += h
        d_v += h * g_acc
        d_r += weight * g_acc
        g_tau = wq[i, 3:6] @ dq0
        g_tau[:, _NZ:] += wth[i, 3:6]
        g_tau = j_inv @ g_tau
        dks: list[np.ndarray] = []
        for s, coef in enumerate((0.0, 0.5, 0.5, 1.0)):
            ds = d_z if not dks else d_z + (coef * h) * dks[-1]
            dk = jz_all[i, s] @ ds
            dk[4:7] += g_tau
            dk[4:7, _NZ + 1:_NZ + 7] += jj_all[i, s]
            dks.append(dk)
        d_new = d_z + (h / 6.0) * (dks[0] + 2.0 * dks[1] + 2.0 * dks[2] + dks[3])
        q = q_raw[i]
        norm = float(np.sqrt(q @ q))
        q_hat = q / norm
        sign = -1.0 if q[3] < 0.0 else 1.0
        d_new[0:4] = ((np.eye(4) - np.outer(q_hat, q_hat)) * (sign / norm)) @ d_new[0:4]
        d_z = d_new
    a[0:3, 6:13] = d_r[:, 0:_NZ]
    a[3:6, 6:13] = d_v[:, 0:_NZ]
    a[6:13, 6:13] = d_z[:, 0:_NZ]
    c[0:3] = d_r[:, _NZ:]
    c[3:6] = d_v[:, _NZ:]
    c[6:13] = d_z[:, _NZ:]
    return x_next, a, c
