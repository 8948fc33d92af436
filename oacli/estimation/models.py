"""Measurement records, noise models and settings shared by the batch and the sequential estimator.

A :class:`Measurement` is what the robot's localisation and actuators report at one time stamp: the measured
state (pose, velocity, angular rate), the input applied from that time on (held until the next record, zero-order
hold) and, optionally, accelerations from an IMU. Which components are used, and their noise, is an
:class:`oacli.excitation.information.MeasurementModel` -- the same object the Fisher information uses, so the
estimators and their Cramér-Rao bound (:mod:`oacli.estimation.bounds`) share one noise model.

Process noise ([Doerr2021] Eq. 31, ``p(x_k | x_{k-1}, u_{k-1}, θ)``) is an unmodelled force (world frame) and torque
(body frame) acting as white noise. Over an interval Δt its intensity is ``σ²·Δt`` (so its effect on the velocity
after Δt has the standard deviation of a force σ held over Δt), which gives per axis the non-singular covariance of
the continuous white-noise-acceleration model (Bar-Shalom, Li & Kirubarajan 2001, §6.2.2)::

    cov[δr, δv] = (σ² Δt / m²) [[Δt³/3, Δt²/2], [Δt²/2, Δt]]      (and δφ, δω with the torque and I_ii)

evaluated with the prior θ, so the weights do not depend on the unknowns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.excitation.information import MeasurementModel
from oacli.types import ParameterEstimate

__all__ = [
    "EstimatorSettings",
    "Measurement",
    "MeasurementModel",
    "ProcessNoise",
    "SequentialStep",
    "measured_rows",
]


def _vector(name: str, value, n: int) -> np.ndarray:
    arr = np.array(value, dtype=float).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected {n} numbers, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Measurement:
    """One time-stamped record for the estimators.

    Attributes
    ----------
    t : float
        Time stamp [s] (mission time). Records may arrive out of order; see :mod:`oacli.estimation.preprocessing`.
    x_measured : ndarray, shape (13,)
        Measured state ``[r m, v m/s, q (x, y, z, w), ω rad/s]`` (localisation output, see :mod:`oacli.types`).
    u_applied : ndarray, shape (6,)
        Input applied from ``t`` until the next record ``[f N (world frame), τ N·m (body frame)]``.
    linear_acceleration_mps2 : ndarray, shape (3,), optional
        Measured linear acceleration ``f/m`` in the world frame [m/s²] at ``t`` (just after the input switched to
        ``u_applied``); an accelerometer's body-frame reading rotated by the measured attitude.
    angular_acceleration_radps2 : ndarray, shape (3,), optional
        Measured angular acceleration ``ω̇`` in the body frame [rad/s²] at ``t``.
    state_measured : bool
        False for an *input-only* record: the localisation message of this control step was lost but the input
        applied from ``t`` on is known, so the estimators propagate through it without a measurement update
        (``x_measured`` then only seeds the solver; :mod:`oacli.estimation.alignment`).
    starts_segment : bool
        True when the input between the previous record and this one is unknown (a gap in the input record): the
        estimators do not link this record's state to the previous one through the process model; the state of
        each segment's first record is estimated afresh.
    acceleration_readings : int
        Accelerometer readings averaged into ``linear_acceleration_mps2`` (1: a single reading). An input-only record
        whose input is unknown (the next record ``starts_segment``) may carry the mean of the readings over its
        interval: the IMU bridges the lost force there (:func:`oacli.estimation.imu.attach_accelerations`).
    angular_acceleration_var_rad2ps4 : float or None
        On such an input-only record only: the variance per axis of ``angular_acceleration_radps2`` [rad²/s⁴],
        which is then the gyro's mean ``ω̇`` over the lost interval (fitted to its readings; ``x_measured[10:13]``
        holds the fitted rate at ``t``): the gyro bridges the lost torque
        (:func:`oacli.estimation.imu.attach_accelerations`). None otherwise.
    """

    t: float
    x_measured: np.ndarray
    u_applied: np.ndarray
    linear_acceleration_mps2: np.ndarray | None = None
    angular_acceleration_radps2: np.ndarray | None = None
    state_measured: bool = True
    starts_segment: bool = False
    acceleration_readings: int = 1
    angular_acceleration_var_rad2ps4: float | None = None

    def __post_init__(self) -> None:
        t = float(self.t)
        if not np.isfinite(t):
            raise ValueError("t must be finite")
        object.__setattr__(self, "t", t)
        x = _vector("x_measured", self.x_measured, 13).copy()
        norm = np.linalg.norm(x[6:10])
        if not norm > 0.5:
            raise ValueError(f"x_measured: quaternion norm {norm:.3g} is not close to 1")
        x[6:10] /= norm
        x.setflags(write=False)
        object.__setattr__(self, "x_measured", x)
        object.__setattr__(self, "u_applied", _vector("u_applied", self.u_applied, 6))
        for name in ("linear_acceleration_mps2", "angular_acceleration_radps2"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _vector(name, value, 3))

    def accelerations(self) -> np.ndarray:
        """``[linear (3), angular (3)]`` accelerations, NaN where not measured, shape (6,).

        Returns
        -------
        ndarray, shape (6,)
        """
        out = np.full(6, np.nan)
        if self.linear_acceleration_mps2 is not None:
            out[0:3] = self.linear_acceleration_mps2
        if self.angular_acceleration_radps2 is not None:
            out[3:6] = self.angular_acceleration_radps2
        return out


def measured_rows(model: MeasurementModel) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the measured tangent components (of [r, v, φ, ω], 12) and of the accelerations (of 6).

    Parameters
    ----------
    model : MeasurementModel

    Returns
    -------
    state_rows : ndarray of int
        Rows of the 12-entry state residual with a finite noise (``state_weights > 0``).
    accel_rows : ndarray of int
        Rows of the 6-entry acceleration residual ``[linear (3), angular (3)]`` with a finite noise.
    """
    return np.flatnonzero(model.state_weights > 0), np.flatnonzero(model.acceleration_weights > 0)


@dataclass(frozen=True)
class ProcessNoise:
    """Unmodelled force and torque acting on the robot, as white noise (see the module docstring).

    Attributes
    ----------
    force_std_N : float
        Standard deviation of a force held over one interval [N], > 0, per world axis.
    torque_std_Nm : float
        Standard deviation of a torque held over one interval [N·m], > 0, per body axis.
    """

    force_std_N: float
    torque_std_Nm: float

    def __post_init__(self) -> None:
        if not (self.force_std_N > 0 and self.torque_std_Nm > 0):
            raise ValueError("process noise standard deviations must be > 0 (use a small value for a rigid model)")

    def covariance(self, dt_s: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Covariance (K, 12, 12) of ``x_{k+1} ⊟ f(x_k, u_k, θ)`` over intervals ``dt_s (K,)`` [s].

        Blocks couple ``(δr_i, δv_i)`` and ``(δφ_i, δω_i)`` per axis; ``theta`` gives m and I_ii.

        Parameters
        ----------
        dt_s : ndarray, shape (K,)
            Interval lengths [s].
        theta : ndarray, shape (4,)
            θ = [m, Ixx, Iyy, Izz].

        Returns
        -------
        ndarray, shape (K, 12, 12)
        """
        dt = np.atleast_1d(np.asarray(dt_s, dtype=float))
        theta = np.asarray(theta, dtype=float)
        out = np.zeros((dt.shape[0], 12, 12))
        shape = np.stack(
            [np.stack([dt**3 / 3.0, dt**2 / 2.0], -1), np.stack([dt**2 / 2.0, dt], -1)], -2
        ) * dt[:, None, None]
        force = self.force_std_N**2 / theta[0] ** 2
        for axis in range(3):
            torque = self.torque_std_Nm**2 / theta[1 + axis] ** 2
            for scale, (a, b) in ((force, (axis, 3 + axis)), (torque, (6 + axis, 9 + axis))):
                out[:, a, a] = scale * shape[:, 0, 0]
                out[:, a, b] = out[:, b, a] = scale * shape[:, 0, 1]
                out[:, b, b] = scale * shape[:, 1, 1]
        return out

    def sqrt_information(self, dt_s: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Whitening matrices ``W_k`` (K, 12, 12) with ``W_kᵀ W_k = Q_k⁻¹`` (inverse Cholesky factors).

        Parameters
        ----------
        dt_s : ndarray, shape (K,)
            Interval lengths [s].
        theta : ndarray, shape (4,)
            θ = [m, Ixx, Iyy, Izz].

        Returns
        -------
        ndarray, shape (K, 12, 12)
        """
        q = self.covariance(dt_s, theta)
        chol = np.linalg.cholesky(q)
        return np.linalg.inv(chol)


@dataclass(frozen=True)
class EstimatorSettings:
    """Everything both estimators need besides the data and the prior.

    Attributes
    ----------
    measurement : MeasurementModel
        Measured components and their noise standard deviations (``None`` = not used).
    process : ProcessNoise
        Unmodelled wrench.
    substep_s : float
        Integration grid of the process model [s] (the simulator's plant period; see
        :mod:`oacli.estimation.propagation`).
    gate_probability : float or None
        χ² gate level for outlier rejection ([ReSWARM2023] §6.2.1: 0.99); ``None`` disables gating.
    max_iterations : int
        Batch: Gauss-Newton/Levenberg-Marquardt iterations per gating round.
    tolerance : float
        Batch: stop when the relative cost decrease and the scaled step fall below this.
    max_gating_rounds : int
        Batch: re-solve with the current inlier set at most this many times.
    reorder_window : int
        Sequential: records held back to restore time-stamp order ([ReSWARM2023] §5.4.3); 0 processes at once.
    """

    measurement: MeasurementModel
    process: ProcessNoise
    substep_s: float = 1.0 / 62.5
    gate_probability: float | None = 0.99
    max_iterations: int = 30
    tolerance: float = 1e-10
    max_gating_rounds: int = 8
    reorder_window: int = 8

    def __post_init__(self) -> None:
        if not self.substep_s > 0:
            raise ValueError("substep_s must be > 0")
        if self.gate_probability is not None and not 0.0 < self.gate_probability < 1.0:
            raise ValueError("gate_probability must be in (0, 1) or None")
        if self.max_iterations < 1 or self.max_gating_rounds < 1 or self.reorder_window < 0:
            raise ValueError("max_iterations and max_gating_rounds must be >= 1, reorder_window >= 0")


@dataclass(frozen=True)
class SequentialStep:
    """What the filter did with one record.

    Attributes
    ----------
    t : float
        Record time [s].
    status : str
        ``"initialised"``, ``"accepted"``, ``"rejected"`` (χ² gate), ``"late"`` (time stamp before the last
        processed one), ``"reinitialised"`` (state re-initialised after repeated rejections), ``"predicted"``
        (input-only record: no measurement) or ``"segment"`` (state re-initialised after a gap in the inputs).
    d2 : float
        Normalised innovation squared ``νᵀ S⁻¹ ν`` (NaN when not computed).
    dof : int
        Innovation dimension.
    estimate : ParameterEstimate
        The parameter estimate after this record.
    state : ndarray, shape (13,)
        Filtered robot state after this record (NaN for a late record).
    """

    t: float
    status: str
    d2: float
    dof: int
    estimate: ParameterEstimate
    state: np.ndarray
