"""Rollout, Fisher information and its exact input gradients, fast: translation and rotation split, time batched.

The same quantities as :func:`oacli.excitation.information.propagate_with_sensitivities`,
:func:`oacli.excitation.information.fisher_information` and :func:`oacli.excitation.fim_gradient.fim_gradients`
([Doerr2021] Eqs. 29, 33-36), computed from the structure of the free-flyer model instead of a generic
13-state (65-state augmented) RK4 pass per step:

* **The dynamics split.** The force acts in the world frame, so ``[r, v]`` is an exact double integrator in ``f``
  that depends on θ only through ``m``, while ``[q, ω]`` depends only on ``τ`` and ``I = diag(Ixx, Iyy, Izz)``
  (Eqs. 34-35). Hence ``∂[r, v]/∂I = 0`` and ``∂[q, ω]/∂m = 0``, every measurement row (position, velocity,
  linear acceleration; attitude, rate, angular acceleration) loads on one block, and the Fisher information is
  block diagonal: ``F = diag(F_mm, F_II)`` with ``F_mI ≡ 0`` for every input.
* **Translation in closed form.** RK4 is exact on the double integrator: ``v_{k+1} = v_k + dt f_k/m``,
  ``r_{k+1} = r_k + dt v_k + dt² f_k/(2m)``, so ``∂v_k/∂m`` and ``∂r_k/∂m`` are cumulative sums of the forces and
  ``F_mm`` is a quadratic form in ``f`` whose gradient is two reverse cumulative sums.
* **Rotation: one scalar pass, then batches.** Only the 7-state ``[q, ω]`` RK4 recursion is sequential; it is run
  once in plain floats and keeps its four stage states per step. The stage Jacobians (and, for the gradients, the
  stage Jacobians of the 28-state augmented system ``[q, ω, vec ∂[q, ω]/∂I]``, the second derivatives of Eq. 35
  contracted with the sensitivities) are then formed for all steps at once and chained through the RK4 stages
  with batched matrix products; only the 7×3 sensitivity recursion and the adjoint's backward pass stay loops.

The quaternion is rescaled after every step and the Jacobians are those of the un-rescaled RK4 map, exactly as in
the reference functions, so the results agree with them to rounding (the tests compare both).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.excitation.fim_gradient import FimGradient
from oacli.excitation.information import N_PARAMS, MeasurementModel

N_ROT = 7  # [q (4), ω (3)]
N_ROT_AUG = N_ROT + N_ROT * 3  # 28: [q, ω, vec ∂[q, ω]/∂(Ixx, Iyy, Izz)] (row-major: 7 + 3 i + j)
_RK4_WEIGHTS = (1.0, 2.0, 2.0, 1.0)
_RK4_COEFS = (0.0, 0.5, 0.5, 1.0)


@dataclass(frozen=True)
class SplitRollout:
    """A rollout of the free-flyer model with its parameter sensitivities and rotational step Jacobians.

    Attributes
    ----------
    x : ndarray, shape (N+1, 13)
        States (quaternion rescaled to unit norm each step, on a continuous hemisphere).
    dv_dm, dr_dm : ndarray, shape (N+1, 3)
        ``∂v_k/∂m`` and ``∂r_k/∂m``.
    s_rot : ndarray, shape (N+1, 7, 3)
        ``∂[q, ω]_k/∂(Ixx, Iyy, Izz)``.
    stages : ndarray, shape (4, N, 7)
        The RK4 stage states ``[q, ω]`` of each step (the first is the state at the step's start).
    fx : ndarray, shape (4, N, 7, 7)
        ``∂[q̇, ω̇]/∂[q, ω]`` at each stage.
    ft : ndarray, shape (4, N, 7, 3)
        ``∂[q̇, ω̇]/∂I`` at each stage.
    a_rot, b_rot, c_rot : ndarray, shapes (N, 7, 7), (N, 7, 3), (N, 7, 3)
        Exact Jacobians of the RK4 step with respect to ``[q, ω]``, ``τ`` and ``I``.
    """

    x: np.ndarray
    dv_dm: np.ndarray
    dr_dm: np.ndarray
    s_rot: np.ndarray
    stages: np.ndarray
    fx: np.ndarray
    ft: np.ndarray
    a_rot: np.ndarray
    b_rot: np.ndarray
    c_rot: np.ndarray

    @property
    def s(self) -> np.ndarray:
        """Full sensitivities ``∂x_k/∂θ``, shape (N+1, 13, 4) (as :func:`propagate_with_sensitivities`)."""
        n1 = self.x.shape[0]
        out = np.zeros((n1, 13, N_PARAMS))
        out[:, 0:3, 0] = self.dr_dm
        out[:, 3:6, 0] = self.dv_dm
        out[:, 6:13, 1:4] = self.s_rot
        return out


def _rotation_pass(x0_rot: np.ndarray, tau: np.ndarray, inertia: np.ndarray,
                   dt: float) -> tuple[np.ndarray, np.ndarray]:
    """RK4 of ``[q, ω]`` in plain floats: states (N+1, 7) (quaternion rescaled) and stage states (4, N, 7)."""
    n = tau.shape[0]
    ix, iy, iz = (float(v) for v in inertia)
    cx, cy, cz = (iz - iy), (ix - iz), (iy - ix)
    out = np.empty((n + 1, N_ROT))
    stages = np.empty((4, n, N_ROT))
    out[0] = x0_rot
    qx, qy, qz, qw, wx, wy, wz = (float(v) for v in x0_rot)
    h = 0.5 * dt
    d6 = dt / 6.0
    taus = tau.tolist()
    for k in range(n):
        tx, ty, tz = taus[k]
        st = (qx, qy, qz, qw, wx, wy, wz)
        # stage 1
        a1 = 0.5 * (qw * wx - qz * wy + qy * wz)
        b1 = 0.5 * (qz * wx + qw * wy - qx * wz)
        c1 = 0.5 * (-qy * wx + qx * wy + qw * wz)
        d1 = 0.5 * (-qx * wx - qy * wy - qz * wz)
        e1 = (tx - cx * wy * wz) / ix
        f1 = (ty - cy * wz * wx) / iy
        g1 = (tz - cz * wx * wy) / iz
        # stage 2
        px, py, pz, pw = qx + h * a1, qy + h * b1, qz + h * c1, qw + h * d1
        ox, oy, oz = wx + h * e1, wy + h * f1, wz + h * g1
        s2 = (px, py, pz, pw, ox, oy, oz)
        a2 = 0.5 * (pw * ox - pz * oy + py * oz)
        b2 = 0.5 * (pz * ox + pw * oy - px * oz)
        c2 = 0.5 * (-py * ox + px * oy + pw * oz)
        d2 = 0.5 * (-px * ox - py * oy - pz * oz)
        e2 = (tx - cx * oy * oz) / ix
        f2 = (ty - cy * oz * ox) / iy
        g2 = (tz - cz * ox * oy) / iz
        # stage 3
        px, py, pz, pw = qx + h * a2, qy + h * b2, qz + h * c2, qw + h * d2
        ox, oy, oz = wx + h * e2, wy + h * f2, wz + h * g2
        s3 = (px, py, pz, pw, ox, oy, oz)
        a3 = 0.5 * (pw * ox - pz * oy + py * oz)
        b3 = 0.5 * (pz * ox + pw * oy - px * oz)
        c3 = 0.5 * (-py * ox + px * oy + pw * oz)
        d3 = 0.5 * (-px * ox - py * oy - pz * oz)
        e3 = (tx - cx * oy * oz) / ix
        f3 = (ty - cy * oz * ox) / iy
        g3 = (tz - cz * ox * oy) / iz
        # stage 4
        px, py, pz, pw = qx + dt * a3, qy + dt * b3, qz + dt * c3, qw + dt * d3
        ox, oy, oz = wx + dt * e3, wy + dt * f3, wz + dt * g3
        s4 = (px, py, pz, pw, ox, oy, oz)
        a4 = 0.5 * (pw * ox - pz * oy + py * oz)
        b4 = 0.5 * (pz * ox + pw * oy - px * oz)
        c4 = 0.5 * (-py * ox + px * oy + pw * oz)
        d4 = 0.5 * (-px * ox - py * oy - pz * oz)
        e4 = (tx - cx * oy * oz) / ix
        f4 = (ty - cy * oz * ox) / iy
        g4 = (tz - cz * ox * oy) / iz
        stages[0, k] = st
        stages[1, k] = s2
        stages[2, k] = s3
        stages[3, k] = s4
        qx = qx + d6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        qy = qy + d6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
        qz = qz + d6 * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
        qw = qw + d6 * (d1 + 2.0 * d2 + 2.0 * d3 + d4)
        wx = wx + d6 * (e1 + 2.0 * e2 + 2.0 * e3 + e4)
        wy = wy + d6 * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
        wz = wz + d6 * (g1 + 2.0 * g2 + 2.0 * g3 + g4)
        # Rescale only (no flip to w >= 0), as propagate_with_sensitivities.
        norm = (qx * qx + qy * qy + qz * qz + qw * qw) ** 0.5
        qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
        out[k + 1] = (qx, qy, qz, qw, wx, wy, wz)
    return out, stages


def _gyro(w: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """``∂ω̇/∂ω`` (..., 3, 3) of Euler's equation at rates ``w (..., 3)``; bilinear: ``J(w) s = J(s) w``."""
    ix, iy, iz = inertia
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    out = np.zeros((*w.shape[:-1], 3, 3))
    out[..., 0, 1] = -(iz - iy) * wz / ix
    out[..., 0, 2] = -(iz - iy) * wy / ix
    out[..., 1, 0] = -(ix - iz) * wz / iy
    out[..., 1, 2] = -(ix - iz) * wx / iy
    out[..., 2, 0] = -(iy - ix) * wy / iz
    out[..., 2, 1] = -(iy - ix) * wx / iz
    return out


def _omega(w: np.ndarray) -> np.ndarray:
    """Ω(ω) (..., 4, 4) with ``Ξ(q) ω = Ω(ω) q`` (:func:`oacli.model.quaternion.omega_matrix`), batched."""
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    z = np.zeros_like(wx)
    return np.stack([np.stack([z, wz, -wy, wx], -1), np.stack([-wz, z, wx, wy], -1),
                     np.stack([wy, -wx, z, wz], -1), np.stack([-wx, -wy, -wz, z], -1)], -2)


def _xi(q: np.ndarray) -> np.ndarray:
    """Ξ(q) (..., 4, 3) of [Doerr2021] Eq. 36 (:func:`oacli.model.quaternion.xi_matrix`), batched."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([np.stack([w, -z, y], -1), np.stack([z, w, -x], -1), np.stack([-y, x, w], -1),
                     np.stack([-x, -y, -z], -1)], -2)


def _wdot(xr: np.ndarray, tau: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """``ω̇`` (..., 3) of Euler's equation ([Doerr2021] Eq. 35b)."""
    ix, iy, iz = inertia
    wx, wy, wz = xr[..., 4], xr[..., 5], xr[..., 6]
    return np.stack([(tau[..., 0] - (iz - iy) * wy * wz) / ix, (tau[..., 1] - (ix - iz) * wz * wx) / iy,
                     (tau[..., 2] - (iy - ix) * wx * wy) / iz], -1)


def _rotation_jacobians(xr: np.ndarray, tau: np.ndarray, inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``∂[q̇, ω̇]/∂[q, ω]`` (..., 7, 7) and ``∂[q̇, ω̇]/∂I`` (..., 7, 3) at states ``xr (..., 7)``."""
    ix, iy, iz = inertia
    w = xr[..., 4:7]
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    fx = np.zeros((*xr.shape[:-1], N_ROT, N_ROT))
    fx[..., 0:4, 0:4] = 0.5 * _omega(w)
    fx[..., 0:4, 4:7] = 0.5 * _xi(xr[..., 0:4])
    fx[..., 4:7, 4:7] = _gyro(w, inertia)
    wd = _wdot(xr, tau, inertia)
    ft = np.zeros((*xr.shape[:-1], N_ROT, 3))
    ft[..., 4, 0], ft[..., 4, 1], ft[..., 4, 2] = -wd[..., 0] / ix, wy * wz / ix, -wy * wz / ix
    ft[..., 5, 0], ft[..., 5, 1], ft[..., 5, 2] = -wz * wx / iy, -wd[..., 1] / iy, wz * wx / iy
    ft[..., 6, 0], ft[..., 6, 1], ft[..., 6, 2] = wx * wy / iz, -wx * wy / iz, -wd[..., 2] / iz
    return fx, ft


def _rotation_fu(inertia: np.ndarray) -> np.ndarray:
    fu = np.zeros((N_ROT, 3))
    fu[4:7, 0:3] = np.diag(1.0 / np.asarray(inertia, dtype=float))
    return fu


def rollout(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float) -> SplitRollout:
    """Roll ``u`` out from ``x0`` with the parameter sensitivities and the rotational step Jacobians.

    Parameters
    ----------
    x0 : ndarray, shape (13,)
        Initial state (known: zero sensitivity).
    u : ndarray, shape (N, 6)
        Inputs [f N (world frame), τ N·m (body frame)], held over each step.
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] at which to linearise.
    dt : float
        Step [s].

    Returns
    -------
    SplitRollout
    """
    u = np.asarray(u, dtype=float)
    x0 = np.asarray(x0, dtype=float)
    n = u.shape[0]
    m = float(theta[0])
    inertia = np.asarray(theta[1:4], dtype=float)
    f = u[:, 0:3]
    x = np.empty((n + 1, 13))
    # Translation: exact double integrator (RK4 is exact on it).
    dv = np.vstack([np.zeros(3), np.cumsum(f * (dt / m), axis=0)])
    x[:, 3:6] = x0[3:6] + dv
    x[:, 0:3] = x0[0:3] + np.vstack([np.zeros(3), np.cumsum(dt * x[:-1, 3:6] + f * (dt * dt / (2.0 * m)), axis=0)])
    dv_dm = -dv / m
    dr_dm = np.vstack([np.zeros(3), np.cumsum(dt * dv_dm[:-1] - f * (dt * dt / (2.0 * m * m)), axis=0)])
    # Rotation: one scalar pass, then the stage Jacobians for all steps at once.
    xr, stages = _rotation_pass(x0[6:13], u[:, 3:6], inertia, dt)
    x[:, 6:13] = xr
    fx, ft = _rotation_jacobians(stages, u[None, :, 3:6], inertia)
    fu = _rotation_fu(inertia)
    eye = np.eye(N_ROT)
    dx, du_, dt_ = fx[0], np.broadcast_to(fu, (n, N_ROT, 3)), ft[0]
    sum_x, sum_u, sum_t = dx.copy(), du_.copy(), dt_.copy()
    for i in (1, 2, 3):
        c = _RK4_COEFS[i] * dt
        dx_new = fx[i] @ (eye + c * dx)
        du_new = c * (fx[i] @ du_) + fu
        dt_new = c * (fx[i] @ dt_) + ft[i]
        dx, du_, dt_ = dx_new, du_new, dt_new
        w = _RK4_WEIGHTS[i]
        sum_x += w * dx
        sum_u += w * du_
        sum_t += w * dt_
    a_rot = eye + (dt / 6.0) * sum_x
    b_rot = (dt / 6.0) * sum_u
    c_rot = (dt / 6.0) * sum_t
    s_rot = np.zeros((n + 1, N_ROT, 3))
    for k in range(n):
        s_rot[k + 1] = a_rot[k] @ s_rot[k] + c_rot[k]
    return SplitRollout(x, dv_dm, dr_dm, s_rot, stages, fx, ft, a_rot, b_rot, c_rot)


def _attitude_jacobian(q: np.ndarray) -> np.ndarray:
    """∂φ/∂q (..., 3, 4) of the body-frame attitude error at ``q`` (:func:`information.attitude_error_jacobian`)."""
    v = q[..., 0:3]
    w = q[..., 3]
    out = np.zeros((*q.shape[:-1], 3, 4))
    out[..., 0, 0] = out[..., 1, 1] = out[..., 2, 2] = 2.0 * w
    out[..., 0, 1], out[..., 0, 2] = 2.0 * v[..., 2], -2.0 * v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = -2.0 * v[..., 2], 2.0 * v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = 2.0 * v[..., 1], -2.0 * v[..., 0]
    out[..., :, 3] = -2.0 * v
    return out


def _weights(model: MeasurementModel) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(model.state_weights, dtype=float), np.asarray(model.acceleration_weights, dtype=float)


def _rotation_outputs(ro: SplitRollout, model: MeasurementModel) -> tuple[np.ndarray, np.ndarray | None,
                                                                           np.ndarray]:
    """Rotational output sensitivities: attitude (N, 3, 3) [k = 1..N], rate (N, 3, 3), angular acceleration
    (N, 3, 3) [k = 0..N-1] or None (not weighted)."""
    s = ro.s_rot
    att = np.einsum("kml,klj->kmj", _attitude_jacobian(ro.x[1:, 6:10]), s[1:, 0:4, :])
    acc = None
    if np.any(model.acceleration_weights[3:6]):
        acc = np.einsum("kml,klj->kmj", ro.fx[0][:, 4:7, :], s[:-1]) + ro.ft[0][:, 4:7, :]
    return att, acc, s[1:, 4:7, :]


def fisher_information(ro: SplitRollout, u: np.ndarray, theta: np.ndarray, model: MeasurementModel) -> np.ndarray:
    """Fisher information (4, 4) of the measurements along a rollout ([Doerr2021] Eq. 29), block diagonal.

    Parameters
    ----------
    ro : SplitRollout
        From :func:`rollout`.
    u : ndarray, shape (N, 6)
        Its inputs.
    theta : ndarray, shape (4,)
    model : MeasurementModel

    Returns
    -------
    ndarray, shape (4, 4)
    """
    return information_per_step(ro, u, theta, model).sum(axis=0)


def information_per_step(ro: SplitRollout, u: np.ndarray, theta: np.ndarray, model: MeasurementModel) -> np.ndarray:
    """Fisher information of each step's measurements (N, 4, 4): state at k+1 and accelerations at k.

    Parameters
    ----------
    ro : SplitRollout
    u : ndarray, shape (N, 6)
    theta : ndarray, shape (4,)
    model : MeasurementModel

    Returns
    -------
    ndarray, shape (N, 4, 4)
    """
    n = u.shape[0]
    m = float(theta[0])
    w_state, w_acc = _weights(model)
    out = np.zeros((n, N_PARAMS, N_PARAMS))
    out[:, 0, 0] = (ro.dr_dm[1:] ** 2 @ w_state[0:3] + ro.dv_dm[1:] ** 2 @ w_state[3:6]
                    + (np.asarray(u[:, 0:3], dtype=float) / m**2) ** 2 @ w_acc[0:3])
    att, acc, rate = _rotation_outputs(ro, model)
    f_ii = np.einsum("kmi,m,kmj->kij", att, w_state[6:9], att) + np.einsum("kmi,m,kmj->kij", rate, w_state[9:12], rate)
    if acc is not None:
        f_ii += np.einsum("kmi,m,kmj->kij", acc, w_acc[3:6], acc)
    out[:, 1:4, 1:4] = 0.5 * (f_ii + f_ii.transpose(0, 2, 1))
    return out


def fim_gradients(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
                  weights: np.ndarray, ro: SplitRollout | None = None) -> FimGradient:
    """:func:`oacli.excitation.fim_gradient.fim_gradients` from the split rollout (same result to rounding).

    Parameters
    ----------
    x0 : ndarray, shape (13,)
    u : ndarray, shape (N, 6)
    theta : ndarray, shape (4,)
    dt : float
    model : MeasurementModel
    weights : ndarray, shape (P, 4, 4)
        Symmetric weight matrices ``M_p`` of the functionals ``⟨M_p, F⟩``.
    ro : SplitRollout, optional
        The rollout of ``u`` from ``x0`` when already computed.

    Returns
    -------
    FimGradient
    """
    u = np.asarray(u, dtype=float)
    weights = np.asarray(weights, dtype=float)
    n = u.shape[0]
    n_fun = weights.shape[0]
    if ro is None:
        ro = rollout(x0, u, theta, dt)
    m = float(theta[0])
    inertia = np.asarray(theta[1:4], dtype=float)
    w_state, w_acc = _weights(model)
    grads = np.zeros((n_fun, n, 6))

    # Translation: ⟨M, F⟩ ∋ M_mm F_mm. With a_j = ∂v_j/∂m, b_j = ∂r_j/∂m (j = 1..N):
    # ∂F_mm/∂f_k = Σ_{j>k} 2 w_v a_j (−dt/m²) + Σ_{j>k} 2 w_r b_j (−dt²/m²)(j − k − ½) + 2 w_a f_k/m⁴.
    a = ro.dv_dm[1:] * w_state[3:6]  # (N, 3), index j−1
    b = ro.dr_dm[1:] * w_state[0:3]
    j = np.arange(1, n + 1)[:, None]
    tail_a = np.cumsum(a[::-1], axis=0)[::-1]  # Σ_{j ≥ k+1}: row k
    tail_b = np.cumsum(b[::-1], axis=0)[::-1]
    tail_jb = np.cumsum((j * b)[::-1], axis=0)[::-1]
    k = np.arange(n)[:, None]
    g_mm = (-2.0 * dt / m**2) * tail_a - (2.0 * dt * dt / m**2) * (tail_jb - (k + 0.5) * tail_b)
    g_mm += 2.0 * w_acc[0:3] * u[:, 0:3] / m**4
    grads[:, :, 0:3] = weights[:, 0, 0][:, None, None] * g_mm[None]

    # Rotation: adjoint of the 28-state augmented system z = [q, ω, vec S] (S = ∂[q, ω]/∂I), batched stages.
    m_ii = weights[:, 1:4, 1:4]  # (P, 3, 3)
    active = np.any(m_ii != 0, axis=(1, 2))  # functionals that see the inertia block (the others: zero gradient)
    if np.any(active):
        grads[active, :, 3:6] = _rotation_gradient(ro, u[:, 3:6], inertia, dt, w_state, w_acc, m_ii[active])

    fim = fisher_information(ro, u, theta, model)
    a_full = np.zeros((n, 13, 13))
    a_full[:, 0:6, 0:6] = np.eye(6)
    a_full[:, 0:3, 3:6] = dt * np.eye(3)
    a_full[:, 6:13, 6:13] = ro.a_rot
    b_full = np.zeros((n, 13, 6))
    b_full[:, 0:3, 0:3] = (dt * dt / (2.0 * m)) * np.eye(3)
    b_full[:, 3:6, 0:3] = (dt / m) * np.eye(3)
    b_full[:, 6:13, 3:6] = ro.b_rot
    return FimGradient(x=ro.x, s=ro.s, fim=fim, gradients=grads, a=a_full, b=b_full)


def _augmented_stage_jacobians(xs: np.ndarray, ss: np.ndarray, fx: np.ndarray, inertia: np.ndarray) -> tuple[
        np.ndarray, np.ndarray]:
    """``∂g/∂z`` (N, 28, 28) and ``∂g/∂τ`` (N, 28, 3) of ``g = [f_r; f_x S + f_I]`` at stage states (batched).

    The rotational restriction of :func:`oacli.excitation.fim_gradient.sensitivity_rate_jacobians`.
    """
    n = xs.shape[0]
    ix, iy, iz = inertia
    w = xs[:, 4:7]
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    gz = np.zeros((n, N_ROT_AUG, N_ROT_AUG))
    gz[:, 0:N_ROT, 0:N_ROT] = fx
    # kron(f_x, I_3) block: S[i, j] at 7 + 3 i + j; (f_x S)[i, j] = Σ_l f_x[i, l] S[l, j].
    blk = gz[:, N_ROT:, N_ROT:].reshape(n, N_ROT, 3, N_ROT, 3)
    for c in range(3):
        blk[:, :, c, :, c] = fx
    gz[:, N_ROT:, N_ROT:] = blk.reshape(n, N_ROT * 3, N_ROT * 3)
    k_x = np.zeros((n, N_ROT, 3, N_ROT))  # ∂K[i, j]/∂x
    k_u = np.zeros((n, N_ROT, 3, 3))
    sq = ss[:, 0:4, :]  # (N, 4, 3): column j = s_q of parameter j
    so = ss[:, 4:7, :]
    # q rows: ∂/∂q = ½ Ω(s_ω), ∂/∂ω = ½ Ξ(s_q) (per column j).
    k_x[:, 0:4, :, 0:4] = 0.5 * _omega(so.transpose(0, 2, 1)).transpose(0, 2, 1, 3)
    k_x[:, 0:4, :, 4:7] = 0.5 * _xi(sq.transpose(0, 2, 1)).transpose(0, 2, 1, 3)
    # ω rows: ∂(J(ω) s_ω)/∂ω = J(s_ω).
    k_x[:, 4:7, :, 4:7] = _gyro(so.transpose(0, 2, 1), inertia).transpose(0, 2, 1, 3)
    # f_I of the ω̇ rows and its derivatives (see _rotation_jacobians).
    jw = _gyro(w, inertia)  # (N, 3, 3)
    zero = np.zeros(n)
    d_yz = np.stack([zero, wz, wy], -1)
    d_zx = np.stack([wz, zero, wx], -1)
    d_xy = np.stack([wy, wx, zero], -1)
    k_x[:, 4, 0, 4:7] += -jw[:, 0] / ix
    k_x[:, 5, 0, 4:7] += -d_zx / iy
    k_x[:, 6, 0, 4:7] += d_xy / iz
    k_u[:, 4, 0, 0] = -1.0 / ix**2
    k_x[:, 4, 1, 4:7] += d_yz / ix
    k_x[:, 5, 1, 4:7] += -jw[:, 1] / iy
    k_x[:, 6, 1, 4:7] += -d_xy / iz
    k_u[:, 5, 1, 1] = -1.0 / iy**2
    k_x[:, 4, 2, 4:7] += -d_yz / ix
    k_x[:, 5, 2, 4:7] += d_zx / iy
    k_x[:, 6, 2, 4:7] += -jw[:, 2] / iz
    k_u[:, 6, 2, 2] = -1.0 / iz**2
    gz[:, N_ROT:, 0:N_ROT] = k_x.reshape(n, N_ROT * 3, N_ROT)
    gu = np.zeros((n, N_ROT_AUG, 3))
    gu[:, 0:N_ROT] = _rotation_fu(inertia)
    gu[:, N_ROT:] = k_u.reshape(n, N_ROT * 3, 3)
    return gz, gu


def _attitude_error_second(s_q: np.ndarray) -> np.ndarray:
    """``∂(E(q) s_q)/∂q`` (..., 3, 4), batched over leading axes (see fim_gradient._attitude_error_second)."""
    s_v, s_w = s_q[..., 0:3], s_q[..., 3]
    out = np.zeros((*s_q.shape[:-1], 3, 4))
    out[..., 0, 1], out[..., 0, 2] = -s_v[..., 2], s_v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = s_v[..., 2], -s_v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -s_v[..., 1], s_v[..., 0]
    for i in range(3):
        out[..., i, i] = -s_w
    out[..., :, 3] = s_v
    return 2.0 * out


def _rotation_gradient(ro: SplitRollout, tau: np.ndarray, inertia: np.ndarray, dt: float, w_state: np.ndarray,
                       w_acc: np.ndarray, m_ii: np.ndarray) -> np.ndarray:
    """``∂⟨M_II, F_II⟩/∂τ`` (P, N, 3) by the adjoint of the augmented rotational RK4 (batched stages)."""
    n = tau.shape[0]
    n_fun = m_ii.shape[0]
    s_k = ro.s_rot[:-1]  # (N, 7, 3)
    # Stage values of S and the stage Jacobians of the augmented system, for all steps at once.
    eye = np.eye(N_ROT_AUG)
    gz1, gu1 = _augmented_stage_jacobians(ro.stages[0], s_k, ro.fx[0], inertia)
    dz, du = gz1, gu1
    phi_z, phi_u = gz1.copy(), gu1.copy()
    k_prev = ro.fx[0] @ s_k + ro.ft[0]
    for i in (1, 2, 3):
        c = _RK4_COEFS[i] * dt
        s_stage = s_k + c * k_prev
        gz, gu = _augmented_stage_jacobians(ro.stages[i], s_stage, ro.fx[i], inertia)
        k_prev = ro.fx[i] @ s_stage + ro.ft[i]
        dz, du = gz @ (eye + c * dz), c * (gz @ du) + gu
        phi_z += _RK4_WEIGHTS[i] * dz
        phi_u += _RK4_WEIGHTS[i] * du
    phi_z = eye + (dt / 6.0) * phi_z
    phi_u = (dt / 6.0) * phi_u

    # Direct terms of ℓ_p = ⟨M_p, F_II⟩: state measurements at k = 1..N, angular accelerations at k = 0..N-1.
    a_dir = np.zeros((n + 1, n_fun, N_ROT_AUG))
    b_dir = np.zeros((n, n_fun, 3))
    s_all = ro.s_rot[1:]  # (N, 7, 3)
    q_all = ro.x[1:, 6:10]
    # rate rows: G = S_ω; ∂ℓ/∂S_ω = 2 W G M.
    lam_w = 2.0 * np.einsum("m,kmj,pjl->kpml", w_state[9:12], s_all[:, 4:7, :], m_ii)  # (N, P, 3, 3)
    a_s = np.zeros((n, n_fun, N_ROT, 3))
    a_s[:, :, 4:7, :] += lam_w
    if np.any(w_state[6:9]):
        e = _attitude_jacobian(q_all)  # (N, 3, 4)
        g_att = np.einsum("kml,klj->kmj", e, s_all[:, 0:4, :])
        lam_a = 2.0 * np.einsum("m,kmj,pjl->kpml", w_state[6:9], g_att, m_ii)  # (N, P, 3, 3)
        a_s[:, :, 0:4, :] += np.einsum("kml,kpmj->kplj", e, lam_a)
        d2 = _attitude_error_second(s_all[:, 0:4, :].transpose(0, 2, 1))  # (N, 3[j], 3, 4)
        a_dir[1:, :, 0:4] += np.einsum("kpmj,kjml->kpl", lam_a, d2)
    a_dir[1:, :, N_ROT:] += a_s.reshape(n, n_fun, N_ROT * 3)
    if np.any(w_acc[3:6]):
        g_acc = np.einsum("kml,klj->kmj", ro.fx[0][:, 4:7, :], s_k) + ro.ft[0][:, 4:7, :]  # (N, 3, 3)
        lam_c = 2.0 * np.einsum("m,kmj,pjl->kpml", w_acc[3:6], g_acc, m_ii)  # (N, P, 3, 3)
        flat = lam_c.reshape(n, n_fun, 9)
        rows = N_ROT + (3 * np.arange(4, 7)[:, None] + np.arange(3)[None, :]).ravel()  # K rows of ω̇
        a_dir[:-1] += np.einsum("kpr,krz->kpz", flat, gz1[:, rows, :])
        b_dir += np.einsum("kpr,kru->kpu", flat, gu1[:, rows, :])

    grads = np.empty((n_fun, n, 3))
    mu = a_dir[n].copy()
    for k in range(n - 1, -1, -1):
        grads[:, k, :] = b_dir[k] + mu @ phi_u[k]
        mu = a_dir[k] + mu @ phi_z[k]
    return grads


__all__ = ["N_ROT", "SplitRollout", "fim_gradients", "fisher_information", "information_per_step", "rollout"]
