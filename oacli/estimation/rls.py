"""The flight's sequential estimator: recursive least squares on accelerations ([ReSWARM2023] §4.4.1, §6.2.1).

The ReSWARM/RATTLE flights estimated θ = [m, Ixx, Iyy, Izz] from the measured linear acceleration ``a`` (body
frame) and the angular acceleration ``α`` (numerical derivative of the measured rate), given the applied force ``F``
and torque ``τ`` ([ReSWARM2023] Eqs. 31-32):

    z = [a, α] = h(θ; F, τ, ω) + ν,   h = [κ ⊙ F_b / m,  J⁻¹(τ − ω × Jω)],   J = diag(Ixx, Iyy, Izz),

with a recursive least-squares update that "resembles the update step of the Kalman filter without a process model"
([ReSWARM2023] Eq. 33 as cited there from Crassidis & Junkins 2004): ``K = P Hᵀ S⁻¹``, ``ψ ← ψ + K (z − h(ψ))``,
``P ← (I − K H) P``, ``S = H P Hᵀ + R``. The regression is written in the inverse parameters
``ψ = [1/m, 1/Ixx, 1/Iyy, 1/Izz]``, in which the force and torque are the regressors of the measured accelerations
(``a = κ ⊙ F ψ₀``, ``α_i = ψ_i (τ_i − (ω × Jω)_i)``): linear but for the small gyroscopic term, whose Jacobian is
taken at the current estimate. Written in θ instead, ``F/m`` is far from linear over a vague prior (15 kg² on a
10 kg robot: σ is 40 % of the mean), so a first-order update at the prior's mass would be a poor model of it. θ and
its covariance are reported through ``θ = 1/ψ`` and ``∂θ/∂ψ = −diag(θ²)`` (first order); the prior is mapped the
same way. The covariance update uses Joseph's form so that ``P`` stays symmetric positive definite. A step whose
normalised innovation ``d² = νᵀ S⁻¹ ν`` exceeds the χ² quantile with 6 degrees of freedom at the gate probability
(0.99 in flight) is not applied ([ReSWARM2023] Eqs. 40-42). An update that would leave the physical set (mass ≤ 0,
an inertia ≤ 0 or breaking a triangle inequality) is not applied either and is counted (RATTLE's code reset the
whole estimator to its prior there).

**Actuator calibration** ([ReSWARM2023] §6.2.1, Eqs. 38-39): on orbit the measured accelerations were larger than
``F/m`` with the known mass, by a different factor per body axis. The flight fitted a scale ``κ_i`` per axis by
linear least squares on data of the robot with known mass, ``a_i ≈ κ_i F_i / m_known``, and used ``κ ⊙ F`` as the
force afterwards: :func:`calibrate_force_scale`. Calibrating on the same run whose mass is then estimated is
circular (it returns the known mass by construction); calibrate on a run of the known robot.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from oacli.estimation.gating import chi2_threshold
from oacli.estimation.imu import ImuStream, gyro_slopes
from oacli.estimation.models import Measurement
from oacli.estimation.parametrization import is_physical
from oacli.model.quaternion import to_rotation_matrix
from oacli.types import InertialParams, ParameterEstimate

__all__ = [
    "RATTLE_TABLE_COV_REDUCTION_PCT",
    "RATTLE_TABLE_ERROR_PCT",
    "AccelerationSamples",
    "ForceScale",
    "RlsEstimator",
    "RlsStep",
    "acceleration_model",
    "acceleration_samples",
    "calibrate_force_scale",
]

_MEAS_DIM = 6

RATTLE_TABLE_ERROR_PCT: tuple[float, float, float, float] = (0.39, 0.91, 1.35, 6.92)
"""The flight's estimation errors [%] of m, Ixx, Iyy, Izz ([ReSWARM2023] §6.2, RATTLE table)."""
RATTLE_TABLE_COV_REDUCTION_PCT: tuple[float, float, float, float] = (99.0, 68.0, 49.0, 25.0)
"""The flight's covariance reductions from the prior [%] of m, Ixx, Iyy, Izz ([ReSWARM2023] §6.2, RATTLE table)."""


@dataclass(frozen=True)
class AccelerationSamples:
    """The regression data of the flight's estimator, one row per control interval, body frame.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Time of each sample [s] (the start of its control interval).
    accel_mps2 : ndarray, shape (K, 3)
        Measured linear acceleration in the body frame [m/s²].
    alpha_radps2 : ndarray, shape (K, 3)
        Measured angular acceleration in the body frame [rad/s²].
    force_N : ndarray, shape (K, 3)
        Applied force in the body frame [N].
    torque_Nm : ndarray, shape (K, 3)
        Applied torque in the body frame [N·m].
    rate_radps : ndarray, shape (K, 3)
        Measured angular rate at the sample [rad/s] (for the gyroscopic term).
    accel_std_mps2 : ndarray, shape (K,)
        Noise std of each linear-acceleration component [m/s²].
    alpha_std_radps2 : ndarray, shape (K,)
        Noise std of each angular-acceleration component [rad/s²].
    """

    t: np.ndarray
    accel_mps2: np.ndarray
    alpha_radps2: np.ndarray
    force_N: np.ndarray
    torque_Nm: np.ndarray
    rate_radps: np.ndarray
    accel_std_mps2: np.ndarray
    alpha_std_radps2: np.ndarray

    def __len__(self) -> int:
        return int(self.t.size)


def acceleration_samples(
    records: Sequence[Measurement], velocity_std_mps: float | None, angular_velocity_std_radps: float | None,
    linear_acceleration_std_mps2: float | None = None, imu: ImuStream | None = None,
    gyro_noise_variance_rad2ps2: float | None = None,
) -> AccelerationSamples:
    """The flight estimator's measurements from time-ordered records ([ReSWARM2023] §4.4.1).

    The angular acceleration is "obtained from differentiation of angular velocities": with an IMU, the slope of
    the gyro's readings over the control interval (:func:`oacli.estimation.imu.gyro_slopes`, noise std
    ``σ_g / √Σ(t − t̄)²``); without one, the finite difference of the measured rate ``(ω_{k+1} − ω_k) / Δt`` (noise
    std ``√2 σ_ω / Δt``). The linear acceleration is the accelerometer's reading where the records carry one
    (rotated into the body frame), else the finite difference of the measured velocity (``√2 σ_v / Δt``). The
    applied force (world frame in the records) and torque are those held over the interval; the force is rotated
    into the body frame with the measured attitude. Only intervals between two measured records of the same
    segment are used.

    **Closed loop.** A finite difference of *localisation* measurements is biased in closed loop: the controller's
    input ``u_k`` reacts to the measurement noise ``n_k``, which enters ``(y_{k+1} − y_k)`` with the opposite
    sign, so the regressor and the measurement error are correlated (errors-in-variables). On a 29 s tube-MPC track
    of a 15 kg payload at 5 Hz the velocity differences fit 9.6 kg while the true states' differences fit 15.07 kg.
    The IMU's readings are independent of the localisation noise and have no such bias: use them (the flight did:
    accelerations from the IMU-fed filter).

    Parameters
    ----------
    records : sequence of Measurement
        Time-ordered records.
    velocity_std_mps : float or None
        Velocity noise std [m/s] (for differenced linear accelerations).
    angular_velocity_std_radps : float
        Angular-rate noise std [rad/s].
    linear_acceleration_std_mps2 : float, optional
        Accelerometer noise std [m/s²] (for records that carry a reading).
    imu : ImuStream, optional
        The IMU's readings: the angular acceleration is then the gyro's slope over each control interval.
    gyro_noise_variance_rad2ps2 : float, optional
        The gyro's white-noise variance per axis [rad²/s²] (:func:`oacli.estimation.imu.gyro_noise_variance`);
        needed with ``imu``.

    Returns
    -------
    AccelerationSamples

    Raises
    ------
    ValueError
        When fewer than two usable intervals remain, or a needed noise std is missing.
    """
    slopes: dict[float, tuple[np.ndarray, float]] = {}
    if imu is not None and gyro_noise_variance_rad2ps2 is not None:
        t_rec = np.array([r.t for r in records])
        slope, s_ss, _ = gyro_slopes(t_rec, imu)
        for i in range(t_rec.size - 1):
            if np.isfinite(s_ss[i]) and s_ss[i] > 0:
                slopes[float(t_rec[i])] = (slope[i], float(np.sqrt(gyro_noise_variance_rad2ps2 / s_ss[i])))
    elif angular_velocity_std_radps is None:
        raise ValueError("acceleration samples: no gyro readings and no angular velocity noise std")
    rows = []
    for prev, nxt in itertools.pairwise(records):
        dt = nxt.t - prev.t
        if not (dt > 0 and prev.state_measured and nxt.state_measured and not nxt.starts_segment):
            continue
        rot = to_rotation_matrix(prev.x_measured[6:10])
        if prev.linear_acceleration_mps2 is not None and linear_acceleration_std_mps2 is not None:
            acc_world = prev.linear_acceleration_mps2  # the mean of its readings
            acc_std = linear_acceleration_std_mps2 / np.sqrt(max(prev.acceleration_readings, 1))
        else:
            if velocity_std_mps is None:
                raise ValueError("acceleration samples: no accelerometer reading and no velocity noise std")
            acc_world = (nxt.x_measured[3:6] - prev.x_measured[3:6]) / dt
            acc_std = np.sqrt(2.0) * velocity_std_mps / dt
        if slopes:
            if prev.t not in slopes:
                continue
            alpha, alpha_std = slopes[prev.t]
        else:
            assert angular_velocity_std_radps is not None
            alpha = (nxt.x_measured[10:13] - prev.x_measured[10:13]) / dt
            alpha_std = np.sqrt(2.0) * angular_velocity_std_radps / dt
        rows.append((prev.t, rot.T @ acc_world, alpha, rot.T @ prev.u_applied[0:3], prev.u_applied[3:6],
                     prev.x_measured[10:13], acc_std, alpha_std))
    if len(rows) < 2:
        raise ValueError(f"acceleration samples: {len(rows)} usable control intervals, need at least 2")
    cols = list(zip(*rows, strict=True))
    return AccelerationSamples(*(np.array(c, dtype=float) for c in cols))


def acceleration_model(
    theta: np.ndarray, force_N: np.ndarray, torque_Nm: np.ndarray, rate_radps: np.ndarray,
    force_scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``h(θ) = [κ ⊙ F / m, J⁻¹(τ − ω × Jω)]`` and its Jacobian ``∂h/∂θ`` ([Doerr2021] Eqs. 34b, 35b, body frame).

    Parameters
    ----------
    theta : ndarray, shape (4,)
        ``[m kg, Ixx, Iyy, Izz kg·m²]``.
    force_N, torque_Nm, rate_radps : ndarray, shape (3,)
        Body-frame force, torque and angular rate.
    force_scale : ndarray, shape (3,), optional
        Per-axis force scale κ (default 1).

    Returns
    -------
    h : ndarray, shape (6,)
    jac : ndarray, shape (6, 4)
    """
    m, inertia = float(theta[0]), np.asarray(theta[1:4], dtype=float)
    f = force_N if force_scale is None else force_scale * force_N
    w = rate_radps
    h = np.empty(6)
    jac = np.zeros((6, 4))
    h[0:3] = f / m
    jac[0:3, 0] = -f / (m * m)
    gyro = np.cross(w, inertia * w)
    h[3:6] = (torque_Nm - gyro) / inertia
    # ∂/∂I_j of (τ_i − (ω × Jω)_i) / I_i: the cross product's derivative (ω × e_j ω_j) and the 1/I_i factor.
    for j in range(3):
        e = np.zeros(3)
        e[j] = w[j]
        jac[3:6, 1 + j] = -np.cross(w, e) / inertia
    jac[3:6, 1:4] -= np.diag(h[3:6] / inertia)
    return h, jac


@dataclass(frozen=True)
class ForceScale:
    """Per-axis force scale ``κ`` fitted by least squares on a run of known mass ([ReSWARM2023] Eqs. 38-39).

    Attributes
    ----------
    scale : ndarray, shape (3,)
        κ per body axis [-].
    std : ndarray, shape (3,)
        Standard error of each κ from the residual scatter [-].
    samples : int
        Samples used.
    """

    scale: np.ndarray
    std: np.ndarray
    samples: int


def calibrate_force_scale(samples: AccelerationSamples, known: InertialParams) -> ForceScale:
    """``κ_i = argmin ‖a_i − κ_i F_i / m‖²`` per body axis ([ReSWARM2023] Eqs. 38-39).

    Parameters
    ----------
    samples : AccelerationSamples
        Data of the robot with known mass.
    known : InertialParams
        The robot whose mass [kg] is known (the flight: the bare robot, before the grasp); only its mass is used.

    Returns
    -------
    ForceScale

    Raises
    ------
    ValueError
        When an axis saw no force (κ not identified).
    """
    if not known.mass_kg > 0:
        raise ValueError("the known mass must be > 0")
    x = samples.force_N / known.mass_kg  # regressor per axis
    y = samples.accel_mps2
    sxx = np.einsum("ki,ki->i", x, x)
    if np.any(sxx <= 0):
        raise ValueError("force scale: an axis saw no force, its scale is not identified")
    scale = np.einsum("ki,ki->i", x, y) / sxx
    dof = max(len(samples) - 1, 1)
    resid = y - x * scale
    sigma2 = np.einsum("ki,ki->i", resid, resid) / dof
    return ForceScale(scale, np.sqrt(sigma2 / sxx), len(samples))


@dataclass(frozen=True)
class RlsStep:
    """What the estimator did with one sample.

    Attributes
    ----------
    t : float
        Sample time [s].
    status : str
        ``"accepted"``, ``"rejected"`` (χ² gate, [ReSWARM2023] Eq. 42) or ``"infeasible"`` (the update would
        leave the physical set: not applied).
    d2 : float
        Normalised innovation squared ``νᵀ S⁻¹ ν``.
    estimate : ParameterEstimate
        The estimate after this sample.
    """

    t: float
    status: str
    d2: float
    estimate: ParameterEstimate


@dataclass
class RlsEstimator:
    """Recursive least squares on accelerations with the χ² gate ([ReSWARM2023] §4.4.1, Eqs. 31-33, 40-42).

    Parameters
    ----------
    prior : ParameterEstimate
        ``θ₀`` and ``P₀`` (RATTLE's flight prior: 15 kg², 0.005 (kg·m²)² on the diagonal).
    force_scale : ndarray, shape (3,), optional
        Calibrated per-axis force scale κ (:func:`calibrate_force_scale`; default 1).
    gate_probability : float or None
        χ² gate probability (0.99 in flight; None: no gate).
    process_variance : ndarray, shape (4,), optional
        Random-walk variance of θ added per sample [kg², (kg·m²)² ×3] (RATTLE's ``Q``; default 0, a constant θ);
        mapped to ψ = 1/θ as ``var(θ) / θ⁴``.
    """

    prior: ParameterEstimate
    force_scale: np.ndarray | None = None
    gate_probability: float | None = 0.99
    process_variance: np.ndarray | None = None
    history: list[RlsStep] = field(default_factory=list)

    def __post_init__(self) -> None:
        theta0 = np.array(self.prior.theta, dtype=float)
        self._psi = 1.0 / theta0
        d_inv = np.diag(1.0 / theta0**2)  # ∂ψ/∂θ = −diag(1/θ²); the sign cancels in the covariance
        self._p = d_inv @ np.array(self.prior.covariance, dtype=float) @ d_inv
        self._gate = (chi2_threshold(_MEAS_DIM, self.gate_probability) if self.gate_probability is not None
                      else float("inf"))
        self.samples_used = 0
        self.samples_rejected = 0
        self.infeasible = 0

    @property
    def estimate(self) -> ParameterEstimate:
        """The current estimate (method ``"rls"``)."""
        theta = 1.0 / self._psi
        d = np.diag(theta**2)
        cov = d @ self._p @ d
        return ParameterEstimate(self.history[-1].t if self.history else self.prior.t, theta,
                                 0.5 * (cov + cov.T), "rls", self.samples_used, self.samples_rejected)

    def update(self, t: float, accel_mps2: np.ndarray, alpha_radps2: np.ndarray, force_N: np.ndarray,
               torque_Nm: np.ndarray, rate_radps: np.ndarray, accel_std_mps2: float,
               alpha_std_radps2: float) -> RlsStep:
        """One RLS update with the sample's measurement ``z = [a, α]`` (body frame).

        Parameters
        ----------
        t : float
            Sample time [s].
        accel_mps2, alpha_radps2, force_N, torque_Nm, rate_radps : ndarray, shape (3,)
            Measured accelerations, applied force and torque, and measured rate (body frame).
        accel_std_mps2, alpha_std_radps2 : float
            Noise std of each component [m/s², rad/s²].

        Returns
        -------
        RlsStep
        """
        if self.process_variance is not None:  # given in θ's units: ψ = 1/θ has var(ψ) = var(θ) / θ⁴ (first order)
            self._p = self._p + np.diag(np.asarray(self.process_variance, dtype=float) * self._psi**4)
        z = np.concatenate([accel_mps2, alpha_radps2])
        theta = 1.0 / self._psi
        h, jac_theta = acceleration_model(theta, force_N, torque_Nm, rate_radps, self.force_scale)
        jac = jac_theta * (-(theta**2))  # ∂h/∂ψ = ∂h/∂θ ∂θ/∂ψ, ∂θ/∂ψ = −diag(θ²)
        r = np.concatenate([np.full(3, accel_std_mps2 ** 2), np.full(3, alpha_std_radps2 ** 2)])
        nu = z - h
        s = jac @ self._p @ jac.T + np.diag(r)
        s = 0.5 * (s + s.T)
        chol = np.linalg.cholesky(s)
        w = np.linalg.solve(chol, nu)
        d2 = float(w @ w)
        if d2 > self._gate:
            self.samples_rejected += 1
            step = RlsStep(float(t), "rejected", d2, self.estimate)
            self.history.append(step)
            return step
        gain = np.linalg.solve(chol.T, np.linalg.solve(chol, jac @ self._p)).T  # P Hᵀ S⁻¹
        psi = self._psi + gain @ nu
        if not (np.all(psi > 0) and is_physical(1.0 / psi)):
            self.infeasible += 1
            step = RlsStep(float(t), "infeasible", d2, self.estimate)
            self.history.append(step)
            return step
        ikh = np.eye(4) - gain @ jac
        self._p = ikh @ self._p @ ikh.T + (gain * r) @ gain.T  # Joseph form
        self._psi = psi
        self.samples_used += 1
        step = RlsStep(float(t), "accepted", d2, self.estimate)
        self.history.append(step)
        return step

    def run(self, samples: AccelerationSamples) -> ParameterEstimate:
        """Update with every sample in order; returns the final estimate.

        Parameters
        ----------
        samples : AccelerationSamples

        Returns
        -------
        ParameterEstimate
        """
        for k in range(len(samples)):
            self.update(samples.t[k], samples.accel_mps2[k], samples.alpha_radps2[k], samples.force_N[k],
                        samples.torque_Nm[k], samples.rate_radps[k], samples.accel_std_mps2[k],
                        samples.alpha_std_radps2[k])
        return self.estimate
