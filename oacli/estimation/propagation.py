"""The estimators' process model: the simulator's multi-rate RK4 integration with exact Jacobians, vectorised.

Telemetry comes at the control rate (5 Hz on ReSWARM, [ReSWARM2023] §5.4.3) while the plant is integrated at 62.5 Hz:
within each control period the input is held and :func:`oacli.sim.simulator.simulate` takes RK4 steps on the
fixed grid ``n · h`` (``h`` = plant period), splitting a step where a control instant falls between two grid
points, and renormalises the quaternion after every step. One RK4 step of 0.2 s would only approximate those 12.5
plant steps, so the estimators use the *same* sub-stepping (:func:`substep_schedule`): with the simulator's ``h``
their model of the discrete dynamics ``x_{k+1} = f(x_k, u_k, θ)`` ([Doerr2021] Eq. 31) is exact, and noise-free data are
fitted exactly. On hardware any ``h`` of a few hundredths of a second gives the continuous dynamics to within
RK4's error.

:func:`propagate_intervals` integrates many intervals at once (a stack of K start states, one input each) and
returns ``A = ∂x_{k+1}/∂x_k`` and ``C = ∂x_{k+1}/∂θ`` by differentiating every RK4 stage and every normalisation
exactly (the chain rule of :func:`oacli.model.rigid_body.rk4_step_jacobians`, batched).
"""

from __future__ import annotations

import math

import numpy as np

from oacli.estimation.rotation_features import rate_map_blocks, rotation_substeps, rotational_rate

STATE_DIM = 13
N_PARAMS = 4
TIME_TOL_S = 1e-9
"""Time stamps closer than this are the same instant (the simulator's tolerance)."""


def substep_schedule(t0: np.ndarray, t1: np.ndarray, step_s: float) -> np.ndarray:
    """Durations of the integration sub-steps of each interval ``[t0_k, t1_k]`` on the grid ``n · step_s``.

    Parameters
    ----------
    t0, t1 : ndarray, shape (K,)
        Interval starts and ends [s], ``t1 > t0``.
    step_s : float
        Grid spacing [s] (the simulator's plant period).

    Returns
    -------
    ndarray, shape (K, M)
        Sub-step durations [s], zero-padded to the longest interval's count ``M``; each row sums to ``t1 − t0``.
        Grid points within :data:`TIME_TOL_S` of ``t0`` or ``t1`` do not split the interval.
    """
    t0 = np.atleast_1d(np.asarray(t0, dtype=float))
    t1 = np.atleast_1d(np.asarray(t1, dtype=float))
    if step_s <= 0:
        raise ValueError("step_s must be > 0")
    rows = []
    for a, b in zip(t0, t1, strict=True):
        n = math.floor((a + TIME_TOL_S) / step_s) + 1
        cuts = [a]
        while n * step_s < b - TIME_TOL_S:
            cuts.append(n * step_s)
            n += 1
        cuts.append(b)
        rows.append(np.diff(cuts))
    width = max((len(r) for r in rows), default=0)
    out = np.zeros((len(rows), width))
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


def dynamics_batch(x: np.ndarray, u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """ẋ = f(x, u, θ) ([Doerr2021] Eqs. 34-35) for stacks ``x (K, 13)``, ``u (K, 6)``; same as ``rigid_body.dynamics``.

    Parameters
    ----------
    x : ndarray, shape (K, 13)
    u : ndarray, shape (K, 6)
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    ndarray, shape (K, 13)
    """
    if x.shape[0] == 1:  # one state: Python floats are 10× faster than 1-element arrays
        m, ix, iy, iz = (float(v) for v in theta)
        vx, vy, vz, qx, qy, qz, qw, wx, wy, wz = (float(v) for v in x[0, 3:13])
        fx, fy, fz, tx, ty, tz = (float(v) for v in u[0])
        return np.array([[
            vx, vy, vz, fx / m, fy / m, fz / m,
            0.5 * (qw * wx - qz * wy + qy * wz), 0.5 * (qz * wx + qw * wy - qx * wz),
            0.5 * (-qy * wx + qx * wy + qw * wz), 0.5 * (-qx * wx - qy * wy - qz * wz),
            (tx - (iz - iy) * wy * wz) / ix, (ty - (ix - iz) * wz * wx) / iy, (tz - (iy - ix) * wx * wy) / iz,
        ]])
    m = theta[0]
    ix, iy, iz = theta[1], theta[2], theta[3]
    qx, qy, qz, qw = x[:, 6], x[:, 7], x[:, 8], x[:, 9]  # type: ignore[assignment]
    wx, wy, wz = x[:, 10], x[:, 11], x[:, 12]  # type: ignore[assignment]
    dx = np.empty_like(x)
    dx[:, 0:3] = x[:, 3:6]
    dx[:, 3:6] = u[:, 0:3] / m
    dx[:, 6] = 0.5 * (qw * wx - qz * wy + qy * wz)
    dx[:, 7] = 0.5 * (qz * wx + qw * wy - qx * wz)
    dx[:, 8] = 0.5 * (-qy * wx + qx * wy + qw * wz)
    dx[:, 9] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    dx[:, 10] = (u[:, 3] - (iz - iy) * wy * wz) / ix
    dx[:, 11] = (u[:, 4] - (ix - iz) * wz * wx) / iy
    dx[:, 12] = (u[:, 5] - (iy - ix) * wx * wy) / iz
    return dx


def _jacobian_single(x: np.ndarray, u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """:func:`dynamics_jacobians_batch` for one state, with Python floats (a filter step is 10× faster)."""
    m, ix, iy, iz = (float(v) for v in theta)
    qx, qy, qz, qw, wx, wy, wz = (float(v) for v in x[6:13])
    fx, fy, fz, tx, ty, tz = (float(v) for v in u)
    jac = np.zeros((1, STATE_DIM, STATE_DIM + N_PARAMS))
    j = jac[0]
    j[0, 3] = j[1, 4] = j[2, 5] = 1.0
    m2 = m * m
    j[3, 13], j[4, 13], j[5, 13] = -fx / m2, -fy / m2, -fz / m2
    hx, hy, hz, hqx, hqy, hqz, hqw = 0.5 * wx, 0.5 * wy, 0.5 * wz, 0.5 * qx, 0.5 * qy, 0.5 * qz, 0.5 * qw
    j[6, 7], j[6, 8], j[6, 9], j[6, 10], j[6, 11], j[6, 12] = hz, -hy, hx, hqw, -hqz, hqy
    j[7, 6], j[7, 8], j[7, 9], j[7, 10], j[7, 11], j[7, 12] = -hz, hx, hy, hqz, hqw, -hqx
    j[8, 6], j[8, 7], j[8, 9], j[8, 10], j[8, 11], j[8, 12] = hy, -hx, hz, -hqy, hqx, hqw
    j[9, 6], j[9, 7], j[9, 8], j[9, 10], j[9, 11], j[9, 12] = -hx, -hy, -hz, -hqx, -hqy, -hqz
    j[10, 11], j[10, 12] = -(iz - iy) * wz / ix, -(iz - iy) * wy / ix
    j[11, 10], j[11, 12] = -(ix - iz) * wz / iy, -(ix - iz) * wx / iy
    j[12, 10], j[12, 11] = -(iy - ix) * wy / iz, -(iy - ix) * wx / iz
    wdx = (tx - (iz - iy) * wy * wz) / ix
    wdy = (ty - (ix - iz) * wz * wx) / iy
    wdz = (tz - (iy - ix) * wx * wy) / iz
    j[10, 14], j[10, 15], j[10, 16] = -wdx / ix, wy * wz / ix, -wy * wz / ix
    j[11, 14], j[11, 15], j[11, 16] = -wz * wx / iy, -wdy / iy, wz * wx / iy
    j[12, 14], j[12, 15], j[12, 16] = wx * wy / iz, -wx * wy / iz, -wdz / iz
    return jac


def dynamics_jacobians_batch(x: np.ndarray, u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``[∂f/∂x | ∂f/∂θ]`` (K, 13, 17) of :func:`dynamics_batch` (same as ``rigid_body.dynamics_jacobians``).

    Parameters
    ----------
    x : ndarray, shape (K, 13)
    u : ndarray, shape (K, 6)
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    ndarray, shape (K, 13, 17)
    """
    k = x.shape[0]
    if k == 1:
        return _jacobian_single(x[0], u[0], theta)
    m = theta[0]
    ix, iy, iz = theta[1], theta[2], theta[3]
    q = x[:, 6:10]
    qx, qy, qz, qw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    wx, wy, wz = x[:, 10], x[:, 11], x[:, 12]
    jac = np.zeros((k, STATE_DIM, STATE_DIM + N_PARAMS))
    jac[:, 0, 3] = jac[:, 1, 4] = jac[:, 2, 5] = 1.0
    jac[:, 3:6, 13] = -u[:, 0:3] / m**2
    # q̇ = ½ Ω(ω) q = ½ Ξ(q) ω
    half = 0.5
    jac[:, 6, 7], jac[:, 6, 8], jac[:, 6, 9] = half * wz, -half * wy, half * wx
    jac[:, 7, 6], jac[:, 7, 8], jac[:, 7, 9] = -half * wz, half * wx, half * wy
    jac[:, 8, 6], jac[:, 8, 7], jac[:, 8, 9] = half * wy, -half * wx, half * wz
    jac[:, 9, 6], jac[:, 9, 7], jac[:, 9, 8] = -half * wx, -half * wy, -half * wz
    jac[:, 6, 10], jac[:, 6, 11], jac[:, 6, 12] = half * qw, -half * qz, half * qy
    jac[:, 7, 10], jac[:, 7, 11], jac[:, 7, 12] = half * qz, half * qw, -half * qx
    jac[:, 8, 10], jac[:, 8, 11], jac[:, 8, 12] = -half * qy, half * qx, half * qw
    jac[:, 9, 10], jac[:, 9, 11], jac[:, 9, 12] = -half * qx, -half * qy, -half * qz
    jac[:, 10, 11], jac[:, 10, 12] = -(iz - iy) * wz / ix, -(iz - iy) * wy / ix
    jac[:, 11, 10], jac[:, 11, 12] = -(ix - iz) * wz / iy, -(ix - iz) * wx / iy
    jac[:, 12, 10], jac[:, 12, 11] = -(iy - ix) * wy / iz, -(iy - ix) * wx / iz
    wdx = (u[:, 3] - (iz - iy) * wy * wz) / ix
    wdy = (u[:, 4] - (ix - iz) * wz * wx) / iy
    wdz = (u[:, 5] - (iy - ix) * wx * wy) / iz
    jac[:, 10, 14], jac[:, 10, 15], jac[:, 10, 16] = -wdx / ix, wy * wz / ix, -wy * wz / ix
    jac[:, 11, 14], jac[:, 11, 15], jac[:, 11, 16] = -wz * wx / iy, -wdy / iy, wz * wx / iy
    jac[:, 12, 14], jac[:, 12, 15], jac[:, 12, 16] = wx * wy / iz, -wx * wy / iz, -wdz / iz
    return jac


def _rk4_substep(x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One RK4 step per row with durations ``dt (K,)``; returns ``x⁺`` and ``[∂x⁺/∂x | ∂x⁺/∂θ]`` (K, 13, 17)."""
    k = x.shape[0]
    eye = np.zeros((k, STATE_DIM, STATE_DIM + N_PARAMS))
    eye[:, :, 0:STATE_DIM] = np.eye(STATE_DIM)
    h = dt[:, None]
    hj = dt[:, None, None]
    ks: list[np.ndarray] = []
    dks: list[np.ndarray] = []
    xs, dxs = x, eye
    for coef in (0.0, 0.5, 0.5, 1.0):
        if ks:
            xs = x + coef * h * ks[-1]
            dxs = eye + coef * hj * dks[-1]
        f = dynamics_batch(xs, u, theta)
        jac = dynamics_jacobians_batch(xs, u, theta)
        dk = jac[:, :, 0:STATE_DIM] @ dxs
        dk[:, :, STATE_DIM:] += jac[:, :, STATE_DIM:]
        ks.append(f)
        dks.append(dk)
    x_next = x + (h / 6.0) * (ks[0] + 2.0 * ks[1] + 2.0 * ks[2] + ks[3])
    d_next = eye + (hj / 6.0) * (dks[0] + 2.0 * dks[1] + 2.0 * dks[2] + dks[3])
    return x_next, d_next


def _normalise(x: np.ndarray, d: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Renormalise the quaternions of the rows in ``mask`` (sign chosen so that w >= 0, as the simulator does)."""
    q = x[:, 6:10]
    norm = np.linalg.norm(q, axis=1)
    sign = np.where(q[:, 3] < 0.0, -1.0, 1.0)
    q_hat = q / norm[:, None]
    jac = sign[:, None, None] * (np.eye(4) - q_hat[:, :, None] * q_hat[:, None, :]) / norm[:, None, None]
    x = x.copy()
    d = d.copy()
    x[mask, 6:10] = (sign[:, None] * q_hat)[mask]
    d[mask, 6:10, :] = (jac @ d[:, 6:10, :])[mask]
    return x, d


def propagate_intervals(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray, *, normalise: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integrate K intervals in one go, each from its own start state with its own held input.

    Parameters
    ----------
    x : ndarray, shape (K, 13)
        Start states.
    u : ndarray, shape (K, 6)
        Inputs held over each interval [N world frame, N·m body frame].
    theta : ndarray, shape (4,)
        [m kg, Ixx, Iyy, Izz kg·m²].
    durations : ndarray, shape (K, M)
        Sub-step durations from :func:`substep_schedule` (zeros are skipped exactly).
    normalise : bool
        Renormalise the quaternion after every non-empty sub-step (the simulator does).

    Returns
    -------
    x_next : ndarray, shape (K, 13)
        End states.
    a : ndarray, shape (K, 13, 13)
        ``∂x_next/∂x``.
    c : ndarray, shape (K, 13, 4)
        ``∂x_next/∂θ``.
    """
    x = np.array(x, dtype=float, ndmin=2)
    u = np.array(u, dtype=float, ndmin=2)
    durations = np.array(durations, dtype=float, ndmin=2)
    theta = np.asarray(theta, dtype=float)
    k = x.shape[0]
    total = np.zeros((k, STATE_DIM, STATE_DIM + N_PARAMS))
    total[:, :, 0:STATE_DIM] = np.eye(STATE_DIM)
    for m in range(durations.shape[1]):
        dt = durations[:, m]
        active = dt > 0.0
        if not np.any(active):
            continue
        x_new, d = _rk4_substep(x, u, theta, dt)
        if normalise:
            x_new, d = _normalise(x_new, d, active)
        chained = d[:, :, 0:STATE_DIM] @ total
        chained[:, :, STATE_DIM:] += d[:, :, STATE_DIM:]
        x = np.where(active[:, None], x_new, x)
        total = np.where(active[:, None, None], chained, total)
    return x, total[:, :, 0:STATE_DIM], total[:, :, STATE_DIM:]


_ROT = slice(6, 13)  # [q (4), ω (3)] within the 13-entry state
_EYE13 = np.eye(STATE_DIM)
_E7 = np.hstack([np.eye(7), np.zeros((7, 3))])  # ∂z/∂[z, I] of the rotational state z = [q, ω]


def propagate_intervals_structured(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray, *, jacobians: bool = True
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`propagate_intervals` (with normalisation) exploiting the structure of the dynamics; same outputs.

    The translational and rotational dynamics ([Doerr2021] Eqs. 34-35) are decoupled: ``[r, v]`` sees only the
    world-frame force and the mass, ``[q, ω]`` only the body torque and the inertias. With the force held over an
    interval, the translational RK4 sub-steps are exact (constant acceleration: RK4 integrates the quadratic
    exactly), so ``r⁺ = r + T v + ½T² f/m``, ``v⁺ = v + T f/m`` over the whole interval ``T`` in closed form. Only
    the 7-entry rotational state is integrated sub-step by sub-step, with its 7×10 Jacobian
    ``∂[q, ω]⁺/∂[q, ω, I]`` carried through every RK4 stage and quaternion normalisation (the chain rule of
    :func:`propagate_intervals` restricted to its non-zero blocks), so each sub-step costs a few (K, 7, 10) products
    instead of (K, 13, 17).

    Parameters
    ----------
    x : ndarray, shape (K, 13)
        Start states.
    u : ndarray, shape (K, 6)
        Inputs held over each interval [N world frame, N·m body frame].
    theta : ndarray, shape (4,)
        [m kg, Ixx, Iyy, Izz kg·m²].
    durations : ndarray, shape (K, M)
        Sub-step durations from :func:`substep_schedule` (zeros are skipped exactly).
    jacobians : bool
        False: the end states only (``a`` and ``c`` are None).

    Returns
    -------
    x_next : ndarray, shape (K, 13)
    a : ndarray, shape (K, 13, 13)
        ``∂x_next/∂x``.
    c : ndarray, shape (K, 13, 4)
        ``∂x_next/∂θ``.
    """
    if not jacobians:
        return _propagate_states(x, u, theta, durations), None, None
    x = np.array(x, dtype=float, ndmin=2)
    u = np.array(u, dtype=float, ndmin=2)
    durations = np.array(durations, dtype=float, ndmin=2)
    theta = np.asarray(theta, dtype=float)
    k = x.shape[0]
    m = float(theta[0])
    inertia = np.array(theta[1:4], dtype=float)
    rate_map = rate_map_blocks((float(inertia[0]), float(inertia[1]), float(inertia[2])))
    tau = u[:, 3:6]
    # Translation: closed form over the interval (RK4 is exact for a constant acceleration).
    total_s = durations.sum(axis=1)
    acc = u[:, 0:3] / m
    x_next = np.empty_like(x)
    x_next[:, 0:3] = x[:, 0:3] + total_s[:, None] * x[:, 3:6] + (0.5 * total_s**2)[:, None] * acc
    x_next[:, 3:6] = x[:, 3:6] + total_s[:, None] * acc
    # Rotation: RK4 sub-steps with the Jacobian w.r.t. [z_0, I].
    z = x[:, _ROT].copy()
    total = None  # ∂z/∂[z_0, I] after the sub-steps so far (None: the identity _E7)
    all_active = bool(np.all(durations > 0.0))
    for col in range(durations.shape[1]):
        dt = durations[:, col]
        active = None if all_active else dt > 0.0
        if active is not None and not np.any(active):
            continue
        h = dt[:, None]
        hj = dt[:, None, None]
        f1, g1 = rotational_rate(z, tau, inertia, rate_map)
        f2, j2 = rotational_rate(z + 0.5 * h * f1, tau, inertia, rate_map)
        g2 = j2[:, :, 0:7] @ g1
        g2 *= 0.5 * hj
        g2 += j2
        f3, j3 = rotational_rate(z + 0.5 * h * f2, tau, inertia, rate_map)
        g3 = j3[:, :, 0:7] @ g2
        g3 *= 0.5 * hj
        g3 += j3
        f4, j4 = rotational_rate(z + h * f3, tau, inertia, rate_map)
        g4 = j4[:, :, 0:7] @ g3
        g4 *= hj
        g4 += j4
        z_new = z + (h / 6.0) * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
        step = g2
        step += g3
        step *= 2.0
        step += g1
        step += g4
        step *= hj / 6.0
        step += _E7
        # Quaternion renormalisation (sign w >= 0, as the simulator does). Its Jacobian s (I − q̂ q̂ᵀ) / |q| is
        # applied as its scale s / |q| here and its projection once after the last sub-step: q̇ is linear in q and
        # ω̇ does not depend on q, so a sub-step maps the radial direction [q, 0] onto the radial direction of the
        # next quaternion, and every radial part the projections would remove on the way is removed by the last one.
        q = z_new[:, 0:4]
        norm = np.sqrt(np.einsum("ki,ki->k", q, q))
        sign = np.where(q[:, 3] < 0.0, -1.0, 1.0)
        step[:, 0:4, :] *= (sign / norm)[:, None, None]
        z_new[:, 0:4] = sign[:, None] * (q / norm[:, None])
        if total is None:
            chained = step
        else:
            chained = step[:, :, 0:7] @ total
            chained[:, :, 7:] += step[:, :, 7:]
        if active is None:
            z, total = z_new, chained
        else:
            z = np.where(active[:, None], z_new, z)
            total = np.where(active[:, None, None], chained, _E7 if total is None else total)
    if total is None:
        total = np.broadcast_to(_E7, (k, 7, 10))
    else:  # the renormalisations' projection I − q̂ q̂ᵀ at the end quaternion (rows with a sub-step)
        q_hat = z[:, 0:4] if all_active else np.where(np.any(durations > 0.0, axis=1)[:, None], z[:, 0:4], 0.0)
        total[:, 0:4, :] -= q_hat[:, :, None] * (q_hat[:, None, :] @ total[:, 0:4, :])
    x_next[:, _ROT] = z
    a = np.zeros((k, STATE_DIM, STATE_DIM))
    a[:, 0:6, 0:6] = np.eye(6)
    a[:, 0, 3] = a[:, 1, 4] = a[:, 2, 5] = total_s
    a[:, _ROT, _ROT] = total[:, :, 0:7]
    c = np.zeros((k, STATE_DIM, N_PARAMS))
    c[:, 0:3, 0] = -(0.5 * total_s**2)[:, None] * acc / m
    c[:, 3:6, 0] = -total_s[:, None] * acc / m
    c[:, _ROT, 1:4] = total[:, :, 7:]
    return x_next, a, c


def _propagate_states(x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """End states of :func:`propagate_intervals_structured` without Jacobians (a trial step's cost, warm starts)."""
    x = np.array(x, dtype=float, ndmin=2)
    u = np.array(u, dtype=float, ndmin=2)
    durations = np.array(durations, dtype=float, ndmin=2)
    m = float(theta[0])
    total_s = durations.sum(axis=1)
    acc = u[:, 0:3] / m
    x_next = np.empty_like(x)
    x_next[:, 0:3] = x[:, 0:3] + total_s[:, None] * x[:, 3:6] + (0.5 * total_s**2)[:, None] * acc
    x_next[:, 3:6] = x[:, 3:6] + total_s[:, None] * acc
    inertia = np.array(theta[1:4], dtype=float)
    x_next[:, _ROT] = rotation_substeps(x[:, _ROT], u[:, 3:6], inertia, durations)
    return x_next


def propagate_state_one(x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """End state of :func:`propagate_one` without Jacobians, in Python floats (a warm start propagates records one
    after the other, where numpy's per-call cost on one row would dominate).

    Parameters
    ----------
    x : ndarray, shape (13,)
    u : ndarray, shape (6,)
    theta : ndarray, shape (4,)
    durations : ndarray, shape (M,) or (1, M)
        Sub-step durations from :func:`substep_schedule` (zeros are skipped).

    Returns
    -------
    ndarray, shape (13,)
    """
    x = np.asarray(x, dtype=float).reshape(STATE_DIM)
    u = np.asarray(u, dtype=float).reshape(6)
    dts = [float(d) for d in np.asarray(durations, dtype=float).reshape(-1) if d > 0.0]
    m = float(theta[0])
    ix, iy, iz = float(theta[1]), float(theta[2]), float(theta[3])
    t0, t1, t2 = float(u[3]), float(u[4]), float(u[5])
    total_s = float(sum(dts))
    acc = u[0:3] / m
    out = np.empty(STATE_DIM)
    out[0:3] = x[0:3] + total_s * x[3:6] + (0.5 * total_s**2) * acc
    out[3:6] = x[3:6] + total_s * acc
    kx, ky, kz = iz - iy, ix - iz, iy - ix

    def rate(qx: float, qy: float, qz: float, qw: float, wx: float, wy: float, wz: float) -> tuple[float, ...]:
        return (0.5 * (qw * wx - qz * wy + qy * wz), 0.5 * (qz * wx + qw * wy - qx * wz),
                0.5 * (-qy * wx + qx * wy + qw * wz), 0.5 * (-qx * wx - qy * wy - qz * wz),
                (t0 - kx * wy * wz) / ix, (t1 - ky * wz * wx) / iy, (t2 - kz * wx * wy) / iz)

    z = tuple(float(v) for v in x[_ROT])
    for h in dts:
        f1 = rate(*z)
        f2 = rate(*(a + 0.5 * h * b for a, b in zip(z, f1, strict=True)))
        f3 = rate(*(a + 0.5 * h * b for a, b in zip(z, f2, strict=True)))
        f4 = rate(*(a + h * b for a, b in zip(z, f3, strict=True)))
        qx, qy, qz, qw, wx, wy, wz = (a + (h / 6.0) * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
                                      for a, b1, b2, b3, b4 in zip(z, f1, f2, f3, f4, strict=True))
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        sgn = -1.0 if qw < 0.0 else 1.0
        z = (sgn * (qx / norm), sgn * (qy / norm), sgn * (qz / norm), sgn * (qw / norm), wx, wy, wz)
    out[_ROT] = z
    return out


def propagate_one(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`propagate_intervals_structured` for a single interval (what a filter step needs); same outputs.

    A filter propagates one interval at a time, where the stacked arrays of the batched functions are mostly
    per-call overhead. Here the rotational state is integrated sub-step by sub-step in Python floats (the same RK4
    stages and normalisation), its stage points are kept, and the Jacobians of all sub-steps are then formed at
    once: the stage Jacobians of every sub-step in one vectorised evaluation, the RK4 chain of each sub-step as
    batched (n, 7, 7) products over the sub-steps, and finally the product over the sub-steps.

    Parameters
    ----------
    x : ndarray, shape (13,)
        Start state.
    u : ndarray, shape (6,)
        Input held over the interval [N world frame, N·m body frame].
    theta : ndarray, shape (4,)
        [m kg, Ixx, Iyy, Izz kg·m²].
    durations : ndarray, shape (M,) or (1, M)
        Sub-step durations from :func:`substep_schedule` (zeros are skipped).

    Returns
    -------
    x_next : ndarray, shape (13,)
    a : ndarray, shape (13, 13)
        ``∂x_next/∂x``.
    c : ndarray, shape (13, 4)
        ``∂x_next/∂θ``.
    """
    x = np.asarray(x, dtype=float).reshape(STATE_DIM)
    u = np.asarray(u, dtype=float).reshape(6)
    dts = [float(d) for d in np.asarray(durations, dtype=float).reshape(-1) if d > 0.0]
    m = float(theta[0])
    inertia = (float(theta[1]), float(theta[2]), float(theta[3]))
    tau = (float(u[3]), float(u[4]), float(u[5]))
    total_s = float(sum(dts))
    acc = u[0:3] / m
    x_next = np.empty(STATE_DIM)
    x_next[0:3] = x[0:3] + total_s * x[3:6] + (0.5 * total_s**2) * acc
    x_next[3:6] = x[3:6] + total_s * acc
    n = len(dts)
    ix, iy, iz = inertia
    t0, t1, t2 = tau
    kx, ky, kz = (iz - iy) / ix, (ix - iz) / iy, (iy - ix) / iz
    bx, by, bz = t0 / ix, t1 / iy, t2 / iz

    stage_rows: list[tuple[float, ...]] = []
    raw_rows: list[tuple[float, ...]] = []
    qx, qy, qz, qw, wx, wy, wz = (float(v) for v in x[_ROT])
    for h in dts:
        hh, h6 = 0.5 * h, h / 6.0
        # Stage 1 (the rates of [Doerr2021] Eqs. 34-35 written out: this loop is the cost of a filter step).
        z1 = (qx, qy, qz, qw, wx, wy, wz)
        a0, a1, a2, a3 = (0.5 * (qw * wx - qz * wy + qy * wz), 0.5 * (qz * wx + qw * wy - qx * wz),
                          0.5 * (-qy * wx + qx * wy + qw * wz), 0.5 * (-qx * wx - qy * wy - qz * wz))
        a4, a5, a6 = bx - kx * wy * wz, by - ky * wz * wx, bz - kz * wx * wy
        # Stage 2
        px, py, pz, pw = qx + hh * a0, qy + hh * a1, qz + hh * a2, qw + hh * a3
        vx, vy, vz = wx + hh * a4, wy + hh * a5, wz + hh * a6
        z2 = (px, py, pz, pw, vx, vy, vz)
        b0, b1, b2, b3 = (0.5 * (pw * vx - pz * vy + py * vz), 0.5 * (pz * vx + pw * vy - px * vz),
                          0.5 * (-py * vx + px * vy + pw * vz), 0.5 * (-px * vx - py * vy - pz * vz))
        b4, b5, b6 = bx - kx * vy * vz, by - ky * vz * vx, bz - kz * vx * vy
        # Stage 3
        px, py, pz, pw = qx + hh * b0, qy + hh * b1, qz + hh * b2, qw + hh * b3
        vx, vy, vz = wx + hh * b4, wy + hh * b5, wz + hh * b6
        z3 = (px, py, pz, pw, vx, vy, vz)
        c0, c1, c2, c3 = (0.5 * (pw * vx - pz * vy + py * vz), 0.5 * (pz * vx + pw * vy - px * vz),
                          0.5 * (-py * vx + px * vy + pw * vz), 0.5 * (-px * vx - py * vy - pz * vz))
        c4, c5, c6 = bx - kx * vy * vz, by - ky * vz * vx, bz - kz * vx * vy
        # Stage 4
        px, py, pz, pw = qx + h * c0, qy + h * c1, qz + h * c2, qw + h * c3
        vx, vy, vz = wx + h * c4, wy + h * c5, wz + h * c6
        z4 = (px, py, pz, pw, vx, vy, vz)
        d0, d1, d2, d3 = (0.5 * (pw * vx - pz * vy + py * vz), 0.5 * (pz * vx + pw * vy - px * vz),
                          0.5 * (-py * vx + px * vy + pw * vz), 0.5 * (-px * vx - py * vy - pz * vz))
        d4, d5, d6 = bx - kx * vy * vz, by - ky * vz * vx, bz - kz * vx * vy
        stage_rows += (z1, z2, z3, z4)
        qx = qx + h6 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
        qy = qy + h6 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
        qz = qz + h6 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
        qw = qw + h6 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
        wx = wx + h6 * (a4 + 2.0 * b4 + 2.0 * c4 + d4)
        wy = wy + h6 * (a5 + 2.0 * b5 + 2.0 * c5 + d5)
        wz = wz + h6 * (a6 + 2.0 * b6 + 2.0 * c6 + d6)
        raw_rows.append((qx, qy, qz, qw))
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        sgn = (-1.0 if qw < 0.0 else 1.0) / norm
        qx, qy, qz, qw = sgn * qx, sgn * qy, sgn * qz, sgn * qw
    z = (qx, qy, qz, qw, wx, wy, wz)
    stages = np.array(stage_rows).reshape(n, 4, 7)
    q_raw = np.array(raw_rows).reshape(n, 4)
    x_next[_ROT] = z
    a = _EYE13.copy()
    a[0, 3] = a[1, 4] = a[2, 5] = total_s
    c = np.zeros((STATE_DIM, N_PARAMS))
    c[0:3, 0] = -(0.5 * total_s**2) * acc / m
    c[3:6, 0] = -total_s * acc / m
    if n == 0:
        return x_next, a, c
    rate_map = rate_map_blocks(inertia)
    _, jac = rotational_rate(stages.reshape(4 * n, 7), u[3:6], np.array(inertia), rate_map)
    jac = jac.reshape(n, 4, 7, 10)
    hj = np.array(dts)[:, None, None]
    g1 = jac[:, 0]
    g2 = jac[:, 1] + 0.5 * hj * (jac[:, 1, :, 0:7] @ g1)
    g3 = jac[:, 2] + 0.5 * hj * (jac[:, 2, :, 0:7] @ g2)
    g4 = jac[:, 3] + hj * (jac[:, 3, :, 0:7] @ g3)
    step = _E7 + (hj / 6.0) * (g1 + 2.0 * g2 + 2.0 * g3 + g4)
    # The renormalisations' Jacobians s (I − q̂ q̂ᵀ) / |q|: their scales here, the projection once at the end (see
    # propagate_intervals_structured).
    norm = np.sqrt(np.einsum("ki,ki->k", q_raw, q_raw))
    sign = np.where(q_raw[:, 3] < 0.0, -1.0, 1.0)
    step[:, 0:4, :] *= (sign / norm)[:, None, None]
    # The product of the sub-steps' Jacobians, later ones on the left, by pairs (a few batched products instead
    # of one per sub-step); the columns on I add the later sub-step's own.
    while step.shape[0] > 1:
        pairs = step.shape[0] // 2
        later = step[1:2 * pairs:2]
        chained = later[:, :, 0:7] @ step[0:2 * pairs:2]
        chained[:, :, 7:] += later[:, :, 7:]
        step = chained if step.shape[0] == 2 * pairs else np.concatenate([chained, step[-1:]])
    total = step[0]
    q_hat = np.array(z[0:4])
    total[0:4, :] -= np.outer(q_hat, q_hat @ total[0:4, :])
    a[_ROT, _ROT] = total[:, 0:7]
    c[_ROT, 1:4] = total[:, 7:]
    return x_next, a, c
