"""Exact gradients of the Fisher information (and of the design criteria) with respect to the inputs.

The optimal-design problem of Doerr et al. 2021 (Eq. 30) minimises a criterion of the Fisher information
``F(u) = Σ_k G_kᵀ G_k`` (Eq. 29, :mod:`oacli.excitation.information`), where the weighted measurement sensitivity
``G_k`` depends on the state ``x_k`` and the parameter sensitivity ``S_k = ∂x_k/∂θ``, and those follow the
discretised dynamics and the forward sensitivity recursion from the inputs ``u``. A sequential convex program
needs ``∂F/∂u``. This module computes it exactly by reverse-mode differentiation (an adjoint pass) of the
*augmented* discrete system ``z = [x, vec S]`` (13 + 13·4 = 65 states).

Augmented dynamics. The sensitivity obeys the variational equation ``Ṡ = f_x S + f_θ``; classical RK4 applied to
``ż = g(z, u) = [f(x, u, θ); f_x(x, u, θ) S + f_θ(x, u, θ)]`` gives exactly the ``S_{k+1} = A_k S_k + C_k`` of
:func:`oacli.excitation.information.propagate_with_sensitivities` (explicit Runge-Kutta schemes commute with
differentiation with respect to parameters: "internal differentiation"). The Jacobians ``∂g/∂z``, ``∂g/∂u`` need
the second derivatives of the rigid-body dynamics ([Doerr2021] Eqs. 34-35), given in closed form by
:func:`sensitivity_rate_jacobians`; the step Jacobians ``Φ_z = ∂z_{k+1}/∂z_k``, ``Φ_u = ∂z_{k+1}/∂u_k`` follow by
the chain rule through the four RK4 stages, as in :func:`oacli.model.rigid_body.rk4_step_jacobians`.

Adjoint. For a linear functional ``ℓ = ⟨M, F⟩ = tr(M F)`` (``M`` symmetric 4×4) the variation is
``dℓ = Σ_k 2⟨G_k M, dG_k⟩``; with ``a_k = ∂ℓ/∂z_k`` (direct) and ``b_k = ∂ℓ/∂u_k`` (direct, acceleration
measurements), the backward recursion ``μ_N = a_N``, ``∂ℓ/∂u_k = b_k + Φ_{u,k}ᵀ μ_{k+1}``,
``μ_k = a_k + Φ_{z,k}ᵀ μ_{k+1}`` gives the whole gradient in one pass. Several functionals are handled at once
(the ten entries of the symmetric F for the convexified design problem, or ``M = ∂J/∂F`` for a criterion J).

Criteria are evaluated on ``F_s = D F D`` with ``D = I`` (absolute parameters, Eq. 30 as printed) or
``D = diag(θ)`` (relative parameters); ``∂J/∂F = D (∂J/∂F_s) D``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from oacli.excitation.information import (
    N_PARAMS,
    MeasurementModel,
    a_optimality,
    d_optimality,
    e_optimality,
    fisher_information,
    state_output_matrix,
)
from oacli.model import rigid_body as rb

Criterion = Literal["A", "D", "E"]
Scaling = Literal["absolute", "relative"]

N_STATE = 13
N_AUG = N_STATE + N_STATE * N_PARAMS  # 65
_ACC_ROWS = np.array([3, 4, 5, 10, 11, 12])
# Rows of the augmented state holding K = f_x S + f_θ for the acceleration rows (row-major vec S: 13 + 4 i + j).
_ACC_AUG_ROWS = (N_STATE + N_PARAMS * _ACC_ROWS[:, None] + np.arange(N_PARAMS)[None, :]).ravel()
_EYE4 = np.eye(N_PARAMS)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _gyro_jacobian(w: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """``∂ω̇/∂ω`` (3, 3) of Euler's equation at rate ``w``; bilinear: ``J(w) s = J(s) w``."""
    ix, iy, iz = inertia
    wx, wy, wz = w
    return np.array(
        [
            [0.0, -(iz - iy) * wz / ix, -(iz - iy) * wy / ix],
            [-(ix - iz) * wz / iy, 0.0, -(ix - iz) * wx / iy],
            [-(iy - ix) * wy / iz, -(iy - ix) * wx / iz, 0.0],
        ]
    )


def sensitivity_rate_jacobians(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the sensitivity rate ``K = f_x(x, u, θ) S + f_θ(x, u, θ)`` with S held fixed.

    These are the second derivatives of the rigid-body dynamics ([Doerr2021] Eqs. 34-35) contracted with S.

    Parameters
    ----------
    x : ndarray, shape (13,)
    u : ndarray, shape (6,)
    theta : ndarray, shape (4,)
        [m kg, Ixx, Iyy, Izz kg·m²].
    s : ndarray, shape (13, 4)
        Sensitivity ``∂x/∂θ``.

    Returns
    -------
    k_x : ndarray, shape (13, 4, 13)
        ``∂K_{ij}/∂x``.
    k_u : ndarray, shape (13, 4, 6)
        ``∂K_{ij}/∂u``.
    """
    m = theta[0]
    inertia = theta[1:4]
    ix, iy, iz = inertia
    w = x[10:13]
    wx, wy, wz = w
    k_x = np.zeros((N_STATE, N_PARAMS, N_STATE))
    k_u = np.zeros((N_STATE, N_PARAMS, 6))
    # v̇ = f/m: only f_θ (column m) depends on u.
    k_u[3:6, 0, 0:3] = -np.eye(3) / m**2
    # q̇ = ½ Ω(ω) q = ½ Ξ(q) ω: (f_x S_j)_q = ½ Ω(ω) s_q + ½ Ξ(q) s_ω, so ∂/∂q = ½ Ω(s_ω), ∂/∂ω = ½ Ξ(s_q).
    qx, qy, qz, qw = s[6], s[7], s[8], s[9]  # each (4,): one entry per parameter column j
    ox, oy, oz = s[10], s[11], s[12]
    zero = np.zeros(N_PARAMS)
    omega = np.array([[zero, oz, -oy, ox], [-oz, zero, ox, oy], [oy, -ox, zero, oz], [-ox, -oy, -oz, zero]])
    xi = np.array([[qw, -qz, qy], [qz, qw, -qx], [-qy, qx, qw], [-qx, -qy, -qz]])
    k_x[6:10, :, 6:10] = 0.5 * omega.transpose(0, 2, 1)
    k_x[6:10, :, 10:13] = 0.5 * xi.transpose(0, 2, 1)
    # ω̇ rows: (f_x S_j)_ω = J(ω) s_ω, whose ω-derivative is J(s_ω) (bilinear and symmetric).
    cx, cy, cz = (iz - iy) / ix, (ix - iz) / iy, (iy - ix) / iz
    gyro = np.array([[zero, -cx * oz, -cx * oy], [-cy * oz, zero, -cy * ox], [-cz * oy, -cz * ox, zero]])
    k_x[10:13, :, 10:13] = gyro.transpose(0, 2, 1)
    # f_θ of the ω̇ rows (see rigid_body.dynamics_jacobians) and its derivatives.
    jw = _gyro_jacobian(w, inertia)
    d_yz = np.array([0.0, wz, wy])  # ∂(ωy ωz)/∂ω
    d_zx = np.array([wz, 0.0, wx])
    d_xy = np.array([wy, wx, 0.0])
    # column Ix: [−ω̇x/Ix, −ωzωx/Iy, ωxωy/Iz]
    k_x[10, 1, 10:13] += -jw[0] / ix
    k_x[11, 1, 10:13] += -d_zx / iy
    k_x[12, 1, 10:13] += d_xy / iz
    k_u[10, 1, 3] = -1.0 / ix**2
    # column Iy: [ωyωz/Ix, −ω̇y/Iy, −ωxωy/Iz]
    k_x[10, 2, 10:13] += d_yz / ix
    k_x[11, 2, 10:13] += -jw[1] / iy
    k_x[12, 2, 10:13] += -d_xy / iz
    k_u[11, 2, 4] = -1.0 / iy**2
    # column Iz: [−ωyωz/Ix, ωzωx/Iy, −ω̇z/Iz]
    k_x[10, 3, 10:13] += -d_yz / ix
    k_x[11, 3, 10:13] += d_zx / iy
    k_x[12, 3, 10:13] += -jw[2] / iz
    k_u[12, 3, 5] = -1.0 / iz**2
    return k_x, k_u


def augmented_dynamics(
    z: np.ndarray, u: np.ndarray, theta: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rate of the augmented state ``z = [x, vec S]`` and its Jacobians.

    ``vec S`` is row-major: entry ``S[i, j]`` sits at ``13 + 4 i + j``.

    Parameters
    ----------
    z : ndarray, shape (65,)
        Augmented state.
    u : ndarray, shape (6,)
        Input.
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.

    Returns
    -------
    g : ndarray, shape (65,)
        ``ż``.
    gz : ndarray, shape (65, 65)
        ``∂g/∂z``.
    gu : ndarray, shape (65, 6)
        ``∂g/∂u``.
    """
    x = z[:N_STATE]
    s = z[N_STATE:].reshape(N_STATE, N_PARAMS)
    fx, fu, ft = rb.dynamics_jacobians(x, u, theta)
    k_x, k_u = sensitivity_rate_jacobians(x, u, theta, s)
    g = np.empty(N_AUG)
    g[:N_STATE] = rb.dynamics(x, u, theta)
    g[N_STATE:] = (fx @ s + ft).ravel()
    gz = np.zeros((N_AUG, N_AUG))
    gz[:N_STATE, :N_STATE] = fx
    gz[N_STATE:, :N_STATE] = k_x.reshape(N_STATE * N_PARAMS, N_STATE)
    block = gz[N_STATE:, N_STATE:].reshape(N_STATE, N_PARAMS, N_STATE, N_PARAMS)  # a view: kron(f_x, I_4)
    for j in range(N_PARAMS):
        block[:, j, :, j] = fx
    gu = np.empty((N_AUG, 6))
    gu[:N_STATE] = fu
    gu[N_STATE:] = k_u.reshape(N_STATE * N_PARAMS, 6)
    return g, gz, gu


def augmented_rk4_step(
    z: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One RK4 step of the augmented system with its exact Jacobians.

    Parameters
    ----------
    z : ndarray, shape (65,)
        Augmented state.
    u : ndarray, shape (6,)
        Input held over the step.
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    dt : float
        Step [s].

    Returns
    -------
    z_next : ndarray, shape (65,)
        Next augmented state (the quaternion is *not* renormalised here).
    phi_z : ndarray, shape (65, 65)
        ``∂z_next/∂z``.
    phi_u : ndarray, shape (65, 6)
        ``∂z_next/∂u``.
    first_stage : tuple
        ``(g, ∂g/∂z, ∂g/∂u)`` at ``(z, u)`` (the acceleration measurement model reuses it).
    """
    eye = np.eye(N_AUG)
    dz_z, dz_u = eye, np.zeros((N_AUG, 6))
    ks, dks = [], []  # type: ignore[var-annotated]
    first = None
    for coef in (0.0, 0.5, 0.5, 1.0):
        zs = z
        if ks:
            zs = z + coef * dt * ks[-1]
            dkz, dku = dks[-1]
            dz_z = eye + coef * dt * dkz
            dz_u = coef * dt * dku
        g, gz, gu = augmented_dynamics(zs, u, theta)
        if first is None:
            first = (g, gz, gu)
        ks.append(g)
        dks.append((gz @ dz_z, gz @ dz_u + gu))
    w = (1.0, 2.0, 2.0, 1.0)
    z_next = z + (dt / 6.0) * sum(wi * ki for wi, ki in zip(w, ks, strict=True))
    phi_z = eye + (dt / 6.0) * sum(wi * d[0] for wi, d in zip(w, dks, strict=True))
    phi_u = (dt / 6.0) * sum(wi * d[1] for wi, d in zip(w, dks, strict=True))
    assert first is not None
    return z_next, phi_z, phi_u, first


def _attitude_error_second(s_q: np.ndarray) -> np.ndarray:
    """``∂(E(q) s_q)/∂q`` (3, 4) where ``E(q) = ∂φ/∂q`` is :func:`information.attitude_error_jacobian`."""
    s_v, s_w = s_q[0:3], s_q[3]
    return 2.0 * np.hstack([_skew(s_v) - s_w * np.eye(3), s_v[:, None]])


@dataclass(frozen=True)
class FimGradient:
    """Fisher information of an input sequence and gradients of linear functionals of it.

    Attributes
    ----------
    x : ndarray, shape (N+1, 13)
        States of the rollout (quaternion renormalised each step).
    s : ndarray, shape (N+1, 13, 4)
        Parameter sensitivities ``∂x_k/∂θ``.
    fim : ndarray, shape (4, 4)
        Fisher information ([Doerr2021] Eq. 29).
    gradients : ndarray, shape (P, N, 6)
        ``∂⟨M_p, F⟩/∂u`` for each weight matrix ``M_p`` requested.
    a : ndarray, shape (N, 13, 13)
        State step Jacobians ``∂x_{k+1}/∂x_k`` (the x-block of the augmented Jacobian; [Doerr2021] Eq. 2).
    b : ndarray, shape (N, 13, 6)
        Input step Jacobians ``∂x_{k+1}/∂u_k``.
    """

    x: np.ndarray
    s: np.ndarray
    fim: np.ndarray
    gradients: np.ndarray
    a: np.ndarray
    b: np.ndarray


def fim_gradients(
    x0: np.ndarray,
    u: np.ndarray,
    theta: np.ndarray,
    dt: float,
    model: MeasurementModel,
    weights: np.ndarray,
) -> FimGradient:
    """Fisher information along ``u`` and the input gradients of ``tr(M_p F)`` for every ``M_p`` in ``weights``.

    Parameters
    ----------
    x0 : ndarray, shape (13,)
        Initial state (known: ``S_0 = 0``).
    u : ndarray, shape (N, 6)
        Inputs [N, N·m], held over each step.
    theta : ndarray, shape (4,)
        Parameters at which the information is evaluated.
    dt : float
        Step [s]; one measurement per step (state at k = 1..N, accelerations at k = 0..N-1).
    model : MeasurementModel
    weights : ndarray, shape (P, 4, 4)
        Symmetric weight matrices M_p.

    Returns
    -------
    FimGradient
    """
    u = np.asarray(u, dtype=float)
    n = u.shape[0]
    weights = np.asarray(weights, dtype=float)
    n_fun = weights.shape[0]
    w_state = np.sqrt(model.state_weights)
    w_acc = np.sqrt(model.acceleration_weights)
    use_acc = bool(np.any(w_acc))
    use_att = bool(np.any(w_state[6:9]))

    zs = np.empty((n + 1, N_AUG))
    zs[0, :N_STATE] = x0
    zs[0, N_STATE:] = 0.0
    phi_z = np.empty((n, N_AUG, N_AUG))
    phi_u = np.empty((n, N_AUG, 6))
    fim = np.zeros((N_PARAMS, N_PARAMS))
    a_dir = np.zeros((n + 1, n_fun, N_AUG))  # direct ∂ℓ/∂z_k
    b_dir = np.zeros((n, n_fun, 6))  # direct ∂ℓ/∂u_k

    for k in range(n):
        z_next, pz, pu, (g, gz, gu) = augmented_rk4_step(zs[k], u[k], theta, dt)
        # Rescale only (no flip to w >= 0): a flip would have to flip the sensitivities' quaternion rows too.
        z_next[6:10] /= np.linalg.norm(z_next[6:10])
        zs[k + 1] = z_next
        phi_z[k] = pz
        phi_u[k] = pu
        if use_acc:
            ga = w_acc[:, None] * g[_ACC_AUG_ROWS].reshape(6, N_PARAMS)
            fim += ga.T @ ga
            lam = 2.0 * np.einsum("mj,pjl->pml", ga, weights) * w_acc[None, :, None]  # (P, 6, 4)
            flat = lam.reshape(n_fun, 6 * N_PARAMS)
            a_dir[k] += flat @ gz[_ACC_AUG_ROWS]
            b_dir[k] += flat @ gu[_ACC_AUG_ROWS]

    for k in range(1, n + 1):
        x = zs[k, :N_STATE]
        s = zs[k, N_STATE:].reshape(N_STATE, N_PARAMS)
        h = state_output_matrix(x)
        gs = w_state[:, None] * (h @ s)
        fim += gs.T @ gs
        lam = 2.0 * np.einsum("mj,pjl->pml", gs, weights) * w_state[None, :, None]  # (P, 12, 4) = W Λ
        a_dir[k, :, N_STATE:] += np.einsum("ml,pmj->plj", h, lam).reshape(n_fun, N_STATE * N_PARAMS)
        if use_att:
            for j in range(N_PARAMS):
                d2 = _attitude_error_second(s[6:10, j])  # (3, 4)
                a_dir[k, :, 6:10] += lam[:, 6:9, j] @ d2

    grads = np.empty((n_fun, n, 6))
    mu = a_dir[n].copy()
    for k in range(n - 1, -1, -1):
        grads[:, k, :] = b_dir[k] + mu @ phi_u[k]
        mu = a_dir[k] + mu @ phi_z[k]
    return FimGradient(
        x=zs[:, :N_STATE].copy(),
        s=zs[:, N_STATE:].reshape(n + 1, N_STATE, N_PARAMS).copy(),
        fim=0.5 * (fim + fim.T),
        gradients=grads,
        a=phi_z[:, :N_STATE, :N_STATE].copy(),
        b=phi_u[:, :N_STATE, :].copy(),
    )


SYMMETRIC_PAIRS = tuple((a, b) for a in range(N_PARAMS) for b in range(a, N_PARAMS))
"""Index pairs ``(a, b)``, ``a ≤ b``, of the 10 distinct entries of a symmetric 4×4 matrix, in the order of
:func:`symmetric_basis` (and of :func:`fim_gradients`)."""


def symmetric_basis() -> np.ndarray:
    """The 10 symmetric 4×4 matrices ``E_ab`` (a ≤ b) with ``⟨E_ab, F⟩ = F_ab``, shape (10, 4, 4).

    Returns
    -------
    ndarray, shape (10, 4, 4)
    """
    out = []
    for a in range(N_PARAMS):
        for b in range(a, N_PARAMS):
            e = np.zeros((N_PARAMS, N_PARAMS))
            if a == b:
                e[a, a] = 1.0
            else:
                e[a, b] = e[b, a] = 0.5
            out.append(e)
    return np.array(out)


def scaling_matrix(theta: np.ndarray, scaling: Scaling) -> np.ndarray:
    """``D`` of ``F_s = D F D``: identity (absolute) or ``diag(θ)`` (relative parameters).

    Parameters
    ----------
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    scaling : {"absolute", "relative"}

    Returns
    -------
    ndarray, shape (4, 4)
    """
    if scaling == "absolute":
        return np.eye(N_PARAMS)
    if scaling == "relative":
        return np.diag(np.abs(np.asarray(theta, dtype=float)))
    raise ValueError(f"unknown parameter scaling {scaling!r}")


def criterion_value(fim: np.ndarray, criterion: Criterion, d: np.ndarray) -> float:
    """Design criterion of ``F_s = D F D``: A = tr(F_s⁻¹), D = −log det F_s, E = −λ_min(F_s) (smaller is better).

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.
    criterion : {"A", "D", "E"}
    d : ndarray, shape (4, 4)
        Scaling ``D`` (:func:`scaling_matrix`).

    Returns
    -------
    float
        ``inf`` for a singular F (A and D).
    """
    fs = d @ fim @ d
    if criterion == "A":
        return a_optimality(fs)
    if criterion == "D":
        return d_optimality(fs)
    if criterion == "E":
        return e_optimality(fs)
    raise ValueError(f"unknown criterion {criterion!r}")


def criterion_weight(fim: np.ndarray, criterion: Criterion, d: np.ndarray) -> np.ndarray:
    """``∂J/∂F`` (4, 4, symmetric) of :func:`criterion_value` at a non-singular F.

    A: ``−D F_s⁻² D``; D: ``−D F_s⁻¹ D``; E: ``−D v vᵀ D`` with v the unit eigenvector of λ_min(F_s) (a
    subgradient when λ_min is repeated).

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.
    criterion : {"A", "D", "E"}
    d : ndarray, shape (4, 4)
        Scaling ``D`` (:func:`scaling_matrix`).

    Returns
    -------
    ndarray, shape (4, 4)
    """
    fs = d @ (0.5 * (fim + fim.T)) @ d
    if criterion == "A":
        inv = np.linalg.inv(fs)
        m = -inv @ inv
    elif criterion == "D":
        m = -np.linalg.inv(fs)
    elif criterion == "E":
        _, vecs = np.linalg.eigh(fs)
        v = vecs[:, 0]
        m = -np.outer(v, v)
    else:
        raise ValueError(f"unknown criterion {criterion!r}")
    m = d @ m @ d
    return 0.5 * (m + m.T)


def criterion_gradient(
    x0: np.ndarray,
    u: np.ndarray,
    theta: np.ndarray,
    dt: float,
    model: MeasurementModel,
    criterion: Criterion = "A",
    scaling: Scaling = "absolute",
) -> tuple[float, np.ndarray]:
    """Design criterion J(u) and its exact gradient ``∂J/∂u`` (N, 6) ([Doerr2021] Eq. 30 and its adjoint).

    Two passes: the first finds F (to form ``M = ∂J/∂F``), the second the adjoint of ``⟨M, F⟩``.

    Parameters
    ----------
    x0 : ndarray, shape (13,)
        Initial state.
    u : ndarray, shape (N, 6)
        Inputs, each held for ``dt``.
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    dt : float
        Step [s].
    model : MeasurementModel
        What is measured, with which noise.
    criterion : {"A", "D", "E"}, optional
    scaling : {"absolute", "relative"}, optional

    Returns
    -------
    value : float
        J(u).
    gradient : ndarray, shape (N, 6)
        ``∂J/∂u``.
    """
    d = scaling_matrix(theta, scaling)
    fim = fisher_information(x0, u, theta, dt, model)
    m = criterion_weight(fim, criterion, d)
    result = fim_gradients(x0, u, theta, dt, model, m[None])
    return criterion_value(fim, criterion, d), result.gradients[0]
