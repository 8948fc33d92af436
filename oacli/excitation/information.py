"""Parameter sensitivities and Fisher information of a trajectory ([Doerr2021] Eqs. 29-30).

The inertial parameters ``θ = [m, Ixx, Iyy, Izz]`` enter the discretised dynamics ``x_{k+1} = F(x_k, u_k, θ)``
(RK4 with zero-order hold, :mod:`oacli.model.rigid_body`). Their effect on the state follows the forward
sensitivity recursion, obtained by differentiating the discrete map *exactly*::

    S_0 = 0,    S_{k+1} = A_k S_k + C_k,    A_k = ∂F/∂x,  C_k = ∂F/∂θ   (at x_k, u_k, θ)

so ``S_k = ∂x_k/∂θ``. A measurement ``y_k = h(x_k, u_k, θ) + v_k`` with ``v_k ~ N(0, R)`` then carries the
Fisher information (Eq. 29 for Gaussian noise)::

    F = Σ_k G_kᵀ R⁻¹ G_k,    G_k = dy_k/dθ = H_k S_k + ∂h/∂θ

The Cramér-Rao bound of any unbiased estimator is ``cov(θ̂) ⪰ F⁻¹``; the A-optimal design of Eq. 30 minimises
``tr(F⁻¹)``.

Measured quantities (each optional, see :class:`MeasurementModel`): position, velocity, attitude (as the
body-frame rotation-vector error about the true attitude), angular velocity, linear acceleration ``f/m`` and
angular acceleration ``ω̇`` (RATTLE's estimator uses velocities and accelerations, [ReSWARM2023] §4.4.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model import rigid_body as rb

N_PARAMS = rb.N_PARAMS
PARAM_NAMES = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")


@dataclass(frozen=True)
class MeasurementModel:
    """Which quantities are measured, with their per-axis noise standard deviations (``None`` = not measured).

    Attributes
    ----------
    position_std_m, velocity_std_mps, attitude_std_rad, angular_velocity_std_radps : float or None
        State measurements at every step k = 1..N.
    linear_acceleration_std_mps2, angular_acceleration_std_radps2 : float or None
        Acceleration measurements at every step k = 0..N-1 (they depend on the input u_k).
    """

    position_std_m: float | None = None
    velocity_std_mps: float | None = None
    attitude_std_rad: float | None = None
    angular_velocity_std_radps: float | None = None
    linear_acceleration_std_mps2: float | None = None
    angular_acceleration_std_radps2: float | None = None

    def __post_init__(self) -> None:
        stds = [s for s in self._state_stds() + self._accel_stds() if s is not None]
        if not stds:
            raise ValueError("a measurement model needs at least one measured quantity")
        if any(not s > 0 for s in stds):
            raise ValueError("measurement standard deviations must be > 0")

    def _state_stds(self) -> list[float | None]:
        return [self.position_std_m, self.velocity_std_mps, self.attitude_std_rad, self.angular_velocity_std_radps]

    def _accel_stds(self) -> list[float | None]:
        return [self.linear_acceleration_std_mps2, self.angular_acceleration_std_radps2]

    @property
    def state_weights(self) -> np.ndarray:
        """R⁻¹ diagonal for the state measurements, (12,) over [r, v, φ, ω]; 0 where not measured."""
        return np.concatenate([np.full(3, 0.0 if s is None else 1.0 / s**2) for s in self._state_stds()])

    @property
    def acceleration_weights(self) -> np.ndarray:
        """R⁻¹ diagonal for [linear (3), angular (3)] acceleration measurements; 0 where not measured."""
        return np.concatenate([np.full(3, 0.0 if s is None else 1.0 / s**2) for s in self._accel_stds()])


def attitude_error_jacobian(q_bar: np.ndarray) -> np.ndarray:
    """∂φ/∂q (3, 4) of the body-frame error ``φ = 2 vec(q̄⁻¹ ⊗ q)`` at ``q = q̄`` (first order).

    Parameters
    ----------
    q_bar : ndarray, shape (4,)
        Linearisation attitude.

    Returns
    -------
    ndarray, shape (3, 4)
    """
    v = q_bar[0:3]
    w = q_bar[3]
    skew = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return 2.0 * np.hstack([w * np.eye(3) - skew, -v[:, None]])


def state_output_matrix(x: np.ndarray) -> np.ndarray:
    """H (12, 13) mapping a state perturbation to [δr, δv, δφ, δω].

    Parameters
    ----------
    x : ndarray, shape (13,)
        State (its attitude is used).

    Returns
    -------
    ndarray, shape (12, 13)
    """
    h = np.zeros((12, 13))
    h[0:6, 0:6] = np.eye(6)
    h[6:9, 6:10] = attitude_error_jacobian(x[6:10])
    h[9:12, 10:13] = np.eye(3)
    return h


def propagate_with_sensitivities(
    x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Propagate the model and the parameter sensitivities along an input sequence.

    Parameters
    ----------
    x0 : ndarray, shape (13,)
        Initial state (known, so ``S_0 = 0``).
    u : ndarray, shape (N, 6)
        Inputs held over each step [N, N·m].
    theta : ndarray, shape (4,)
        [m kg, Ixx, Iyy, Izz kg·m²] at which to linearise.
    dt : float
        Step [s].

    Returns
    -------
    x : ndarray, shape (N+1, 13)
        States (quaternion rescaled to unit norm each step, on a continuous hemisphere).
    s : ndarray, shape (N+1, 13, 4)
        Sensitivities ``∂x_k/∂θ``.
    """
    u = np.asarray(u, dtype=float)
    n = u.shape[0]
    xs = np.empty((n + 1, 13))
    ss = np.zeros((n + 1, 13, N_PARAMS))
    xs[0] = x0
    for k in range(n):
        x_next, a, _, c = rb.rk4_step_jacobians(xs[k], u[k], theta, dt)
        # Rescale only: flipping q to w >= 0 here would have to flip the quaternion rows of S too (q and −q are
        # the same attitude, and the attitude measurement is sign-free, so the hemisphere is simply kept).
        x_next[6:10] /= np.linalg.norm(x_next[6:10])
        xs[k + 1] = x_next
        ss[k + 1] = a @ ss[k] + c
    return xs, ss


def output_sensitivities(
    x: np.ndarray, u: np.ndarray, s: np.ndarray, theta: np.ndarray, model: MeasurementModel
) -> tuple[np.ndarray, np.ndarray]:
    """Sensitivities of the measurements to θ, weighted by R^-½.

    Parameters
    ----------
    x : ndarray, shape (N+1, 13)
        States along the rollout.
    u : ndarray, shape (N, 6)
        Inputs.
    s : ndarray, shape (N+1, 13, 4)
        Parameter sensitivities ``∂x_k/∂θ``.
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    model : MeasurementModel

    Returns
    -------
    g_state : ndarray, shape (N, 12, 4)
        ``R^-½ dy_k/dθ`` of the state measurements at k = 1..N.
    g_accel : ndarray, shape (N, 6, 4)
        ``R^-½ dy_k/dθ`` of the acceleration measurements at k = 0..N-1.
    """
    n = u.shape[0]
    w_state = np.sqrt(model.state_weights)
    w_acc = np.sqrt(model.acceleration_weights)
    g_state = np.empty((n, 12, N_PARAMS))
    g_accel = np.zeros((n, 6, N_PARAMS))
    for k in range(1, n + 1):
        g_state[k - 1] = w_state[:, None] * (state_output_matrix(x[k]) @ s[k])
    if np.any(w_acc):
        for k in range(n):
            fx, _, ft = rb.dynamics_jacobians(x[k], u[k], theta)
            # Accelerations are rows 3:6 (v̇ = f/m) and 10:13 (ω̇) of the continuous dynamics.
            rows = np.r_[3:6, 10:13]
            g_accel[k] = w_acc[:, None] * (fx[rows] @ s[k] + ft[rows])
    return g_state, g_accel


def fisher_information(
    x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel
) -> np.ndarray:
    """Fisher information F (4, 4) of θ from measuring the response to ``u (N, 6)`` from ``x0`` (Eq. 29).

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

    Returns
    -------
    ndarray, shape (4, 4)
    """
    x, s = propagate_with_sensitivities(x0, u, theta, dt)
    g_state, g_accel = output_sensitivities(x, u, s, theta, model)
    return np.einsum("kmi,kmj->ij", g_state, g_state) + np.einsum("kmi,kmj->ij", g_accel, g_accel)


def information_per_step(
    x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel
) -> np.ndarray:
    """Fisher information of each step's measurements, shape (N, 4, 4); their sum is :func:`fisher_information`.

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

    Returns
    -------
    ndarray, shape (N, 4, 4)
    """
    x, s = propagate_with_sensitivities(x0, u, theta, dt)
    g_state, g_accel = output_sensitivities(x, u, s, theta, model)
    return np.einsum("kmi,kmj->kij", g_state, g_state) + np.einsum("kmi,kmj->kij", g_accel, g_accel)


def a_optimality(fim: np.ndarray) -> float:
    """A-criterion tr(F⁻¹) ([Doerr2021] Eq. 30); ``inf`` when F is singular.

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.

    Returns
    -------
    float
    """
    try:
        return float(np.trace(np.linalg.inv(fim))) if np.linalg.matrix_rank(fim) == fim.shape[0] else np.inf
    except np.linalg.LinAlgError:
        return float("inf")


def d_optimality(fim: np.ndarray) -> float:
    """D-criterion −log det F (smaller is better); ``inf`` when F is singular.

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.

    Returns
    -------
    float
    """
    sign, logdet = np.linalg.slogdet(fim)
    return float(-logdet) if sign > 0 else float("inf")


def e_optimality(fim: np.ndarray) -> float:
    """E-criterion −λ_min(F) (smaller is better).

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.

    Returns
    -------
    float
    """
    return float(-np.linalg.eigvalsh(0.5 * (fim + fim.T)).min())


def unidentifiable_parameters(
    fim: np.ndarray, theta_scale: np.ndarray | None = None, rel_tol: float = 1e-9
) -> list[str]:
    """Names of the parameters that load on the near-null space of F.

    The check is made on the information of the *relative* parameters ``θ_i / scale_i`` (``D F D`` with
    ``D = diag(scale)``), so that mass [kg] and inertias [kg·m²] are compared fairly.

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.
    theta_scale : ndarray, shape (4,), optional
        Scale of each parameter (typically θ itself); 1 by default.
    rel_tol : float, optional
        Eigenvalues below ``rel_tol`` times the largest count as zero.

    Returns
    -------
    list of str
        Names from ``PARAM_NAMES``; empty when every parameter is identifiable.
    """
    d = np.ones(fim.shape[0]) if theta_scale is None else np.abs(np.asarray(theta_scale, dtype=float))
    scaled = d[:, None] * (0.5 * (fim + fim.T)) * d[None, :]
    eigval, eigvec = np.linalg.eigh(scaled)
    limit = rel_tol * max(float(eigval.max(initial=0.0)), 1e-300)
    null = eigvec[:, eigval <= limit]
    if null.size == 0:
        return []
    loads = np.max(np.abs(null), axis=1)
    return [PARAM_NAMES[i] for i in np.flatnonzero(loads > 1e-3)]


def cramer_rao_std(fim: np.ndarray, theta_scale: np.ndarray | None = None) -> np.ndarray:
    """Cramér-Rao lower bound on the standard deviations, ``sqrt(diag F⁻¹)`` (4,); ``inf`` where unidentifiable.

    Parameters
    ----------
    fim : ndarray, shape (4, 4)
        Fisher information F.
    theta_scale : ndarray, shape (4,), optional
        As in :func:`unidentifiable_parameters`.

    Returns
    -------
    ndarray, shape (4,)
    """
    bad = unidentifiable_parameters(fim, theta_scale)
    if not bad:
        return np.sqrt(np.diag(np.linalg.inv(0.5 * (fim + fim.T))))
    out = np.sqrt(np.abs(np.diag(np.linalg.pinv(0.5 * (fim + fim.T)))))
    out[[PARAM_NAMES.index(name) for name in bad]] = np.inf
    return out
