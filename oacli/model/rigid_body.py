"""Free-flyer rigid-body dynamics ([Doerr2021] Eqs. 33-36) and their discretisation (Eq. 2).

State ``x = [r, v, q, ω]`` (13), input ``u = [f, τ]`` (6): the force ``f`` [N] acts in the world frame, the
torque ``τ`` [N·m] in the body frame (see :mod:`oacli.types`). Inertial parameters
``θ = [m, Ixx, Iyy, Izz]`` [kg, kg·m²] with a principal-axis body frame.

Continuous dynamics::

    ṙ = v                                   (34a)
    v̇ = f / m                               (34b)
    q̇ = ½ Ξ(q) ω                            (35a, 36)
    ω̇ = I⁻¹ (τ − ω × I ω)                   (35b)

Discretisation is classical fourth-order Runge-Kutta with a zero-order hold on ``u`` over the step ``dt``.
:func:`rk4_step_jacobians` differentiates that discrete map *exactly* (chain rule through the four stages), which
gives the LTV matrices ``A_k = ∂x_{k+1}/∂x_k``, ``B_k = ∂x_{k+1}/∂u_k`` of Eq. 2 and the parameter sensitivity
``C_k = ∂x_{k+1}/∂θ`` used by the information and estimation code.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from oacli.model import quaternion as quat
from oacli.types import INPUT_DIM, STATE_DIM, InertialParams

N_PARAMS = 4  # θ = [m, Ixx, Iyy, Izz]


def theta_of(params: InertialParams) -> np.ndarray:
    """θ = [m, Ixx, Iyy, Izz] as an array.

    Parameters
    ----------
    params : InertialParams

    Returns
    -------
    ndarray, shape (4,)
    """
    return np.concatenate([[params.mass_kg], params.inertia_kgm2])


def dynamics(x: np.ndarray, u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Continuous-time state derivative ẋ = f(x, u, θ) ([Doerr2021] Eqs. 34-35).

    Parameters
    ----------
    x : ndarray, shape (13,)
        State [r m, v m/s, q (x, y, z, w), ω rad/s].
    u : ndarray, shape (6,)
        Input [f N (world frame), τ N·m (body frame)].
    theta : ndarray, shape (4,)
        [m kg, Ixx, Iyy, Izz kg·m²].

    Returns
    -------
    ndarray, shape (13,)
    """
    m = theta[0]
    inertia = theta[1:4]
    q = x[6:10]
    w = x[10:13]
    dx = np.empty(STATE_DIM)
    dx[0:3] = x[3:6]
    dx[3:6] = u[0:3] / m
    qx, qy, qz, qw = q
    wx, wy, wz = w
    dx[6] = 0.5 * (qw * wx - qz * wy + qy * wz)
    dx[7] = 0.5 * (qz * wx + qw * wy - qx * wz)
    dx[8] = 0.5 * (-qy * wx + qx * wy + qw * wz)
    dx[9] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    ix, iy, iz = inertia
    dx[10] = (u[3] - (iz - iy) * wy * wz) / ix
    dx[11] = (u[4] - (ix - iz) * wz * wx) / iy
    dx[12] = (u[5] - (iy - ix) * wx * wy) / iz
    return dx


def dynamics_jacobians(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic Jacobians of :func:`dynamics`.

    Parameters
    ----------
    x : ndarray, shape (13,)
        State ``[r, v, q, ω]``.
    u : ndarray, shape (6,)
        Input ``[f (world frame) [N], τ (body frame) [N·m]]``.
    theta : ndarray, shape (4,)
        θ = [m [kg], Ixx, Iyy, Izz [kg·m²]].

    Returns
    -------
    fx : ndarray, shape (13, 13)
        ``∂f/∂x``.
    fu : ndarray, shape (13, 6)
        ``∂f/∂u``.
    ft : ndarray, shape (13, 4)
        ``∂f/∂θ``.
    """
    m = theta[0]
    ix, iy, iz = theta[1:4]
    q = x[6:10]
    wx, wy, wz = x[10:13]
    fx = np.zeros((STATE_DIM, STATE_DIM))
    fu = np.zeros((STATE_DIM, INPUT_DIM))
    ft = np.zeros((STATE_DIM, N_PARAMS))
    fx[0:3, 3:6] = np.eye(3)
    fu[3:6, 0:3] = np.eye(3) / m
    ft[3:6, 0] = -u[0:3] / m**2
    fx[6:10, 6:10] = 0.5 * quat.omega_matrix(x[10:13])
    fx[6:10, 10:13] = 0.5 * quat.xi_matrix(q)
    # ω̇x = (τx − (Iz − Iy) ωy ωz)/Ix, cyclic.
    fx[10, 11] = -(iz - iy) * wz / ix
    fx[10, 12] = -(iz - iy) * wy / ix
    fx[11, 10] = -(ix - iz) * wz / iy
    fx[11, 12] = -(ix - iz) * wx / iy
    fx[12, 10] = -(iy - ix) * wy / iz
    fx[12, 11] = -(iy - ix) * wx / iz
    fu[10:13, 3:6] = np.diag([1.0 / ix, 1.0 / iy, 1.0 / iz])
    wdot_x = (u[3] - (iz - iy) * wy * wz) / ix
    wdot_y = (u[4] - (ix - iz) * wz * wx) / iy
    wdot_z = (u[5] - (iy - ix) * wx * wy) / iz
    ft[10, 1:4] = [-wdot_x / ix, wy * wz / ix, -wy * wz / ix]
    ft[11, 1:4] = [-wz * wx / iy, -wdot_y / iy, wz * wx / iy]
    ft[12, 1:4] = [wx * wy / iz, -wx * wy / iz, -wdot_z / iz]
    return fx, fu, ft


def rk4_step(x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float) -> np.ndarray:
    """One RK4 step of length ``dt`` [s] with ``u`` held (zero-order hold); the quaternion is not renormalised.

    Parameters
    ----------
    x : ndarray, shape (13,)
        State ``[r, v, q, ω]``.
    u : ndarray, shape (6,)
        Input ``[f (world frame) [N], τ (body frame) [N·m]]``.
    theta : ndarray, shape (4,)
        θ = [m [kg], Ixx, Iyy, Izz [kg·m²]].
    dt : float
        Step [s].

    Returns
    -------
    ndarray, shape (13,)
        The state after ``dt``.
    """
    k1 = dynamics(x, u, theta)
    k2 = dynamics(x + 0.5 * dt * k1, u, theta)
    k3 = dynamics(x + 0.5 * dt * k2, u, theta)
    k4 = dynamics(x + dt * k3, u, theta)
    return cast(np.ndarray, x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4))


def propagate(x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float) -> np.ndarray:
    """One RK4 step followed by quaternion renormalisation (the truth plant's integrator step).

    Parameters
    ----------
    x : ndarray, shape (13,)
        State ``[r, v, q, ω]``.
    u : ndarray, shape (6,)
        Input ``[f (world frame) [N], τ (body frame) [N·m]]``.
    theta : ndarray, shape (4,)
        θ = [m [kg], Ixx, Iyy, Izz [kg·m²]].
    dt : float
        Step [s].

    Returns
    -------
    ndarray, shape (13,)
        The state after ``dt``, unit quaternion with ``w >= 0``.
    """
    out = rk4_step(x, u, theta, dt)
    out[6:10] = quat.normalize(out[6:10])
    return out


def rk4_step_jacobians(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """RK4 step and its exact Jacobians ([Doerr2021] Eq. 2 discretisation).

    Parameters
    ----------
    x : ndarray, shape (13,)
        State ``[r, v, q, ω]``.
    u : ndarray, shape (6,)
        Input ``[f (world frame) [N], τ (body frame) [N·m]]``.
    theta : ndarray, shape (4,)
        θ = [m [kg], Ixx, Iyy, Izz [kg·m²]].
    dt : float
        Step [s].

    Returns
    -------
    x_next : ndarray, shape (13,)
        ``rk4_step(x, u, theta, dt)``.
    a : ndarray, shape (13, 13)
        ``∂x_next/∂x``.
    b : ndarray, shape (13, 6)
        ``∂x_next/∂u``.
    c : ndarray, shape (13, 4)
        ``∂x_next/∂θ``.
    """
    eye = np.eye(STATE_DIM)
    stages = []
    d_x = (eye, np.zeros((STATE_DIM, INPUT_DIM)), np.zeros((STATE_DIM, N_PARAMS)))
    xs = x
    ks: list[np.ndarray] = []
    dks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for coef in (0.0, 0.5, 0.5, 1.0):
        if ks:
            xs = x + coef * dt * ks[-1]
            dkx, dku, dkt = dks[-1]
            d_x = (eye + coef * dt * dkx, coef * dt * dku, coef * dt * dkt)
        k = dynamics(xs, u, theta)
        fx, fu, ft = dynamics_jacobians(xs, u, theta)
        dks.append((fx @ d_x[0], fx @ d_x[1] + fu, fx @ d_x[2] + ft))
        ks.append(k)
        stages.append(xs)
    w = (1.0, 2.0, 2.0, 1.0)
    x_next = x + (dt / 6.0) * sum(wi * ki for wi, ki in zip(w, ks, strict=True))
    a = eye + (dt / 6.0) * sum(wi * d[0] for wi, d in zip(w, dks, strict=True))
    b = (dt / 6.0) * sum(wi * d[1] for wi, d in zip(w, dks, strict=True))
    c = (dt / 6.0) * sum(wi * d[2] for wi, d in zip(w, dks, strict=True))
    return x_next, a, cast(np.ndarray, b), cast(np.ndarray, c)


def linearize_discrete(
    x_bar: np.ndarray, u_bar: np.ndarray, params: InertialParams, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LTV matrices of [Doerr2021] Eq. 2 about ``(x_bar, u_bar)``: ``δx_{k+1} = A δx_k + B δu_k + g``.

    Parameters
    ----------
    x_bar : ndarray, shape (13,)
        Operating state.
    u_bar : ndarray, shape (6,)
        Operating input.
    params : InertialParams
    dt : float
        Step [s].

    Returns
    -------
    a : ndarray, shape (13, 13)
    b : ndarray, shape (13, 6)
    g : ndarray, shape (13,)
        ``f_d(x_bar, u_bar) − x_bar``, the affine drift of the discrete map at the operating point (zero at an
        equilibrium).
    """
    x_next, a, b, _ = rk4_step_jacobians(x_bar, u_bar, theta_of(params), dt)
    return a, b, x_next - x_bar


def angular_momentum_world(x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Angular momentum ``R(q) I ω`` in the world frame [kg·m²/s]; conserved when τ = 0.

    Parameters
    ----------
    x : ndarray, shape (13,)
        State ``[r, v, q, ω]``.
    theta : ndarray, shape (4,)
        θ = [m [kg], Ixx, Iyy, Izz [kg·m²]].

    Returns
    -------
    ndarray, shape (3,)
    """
    return cast(np.ndarray, quat.to_rotation_matrix(x[6:10]) @ (theta[1:4] * x[10:13]))


def rotational_energy(x: np.ndarray, theta: np.ndarray) -> float:
    """Rotational kinetic energy ½ ωᵀ I ω [J]; conserved when τ = 0.

    Parameters
    ----------
    x : ndarray, shape (13,)
        State ``[r, v, q, ω]``.
    theta : ndarray, shape (4,)
        θ = [m [kg], Ixx, Iyy, Izz [kg·m²]].

    Returns
    -------
    float
    """
    w = x[10:13]
    return 0.5 * float(np.sum(theta[1:4] * w * w))
