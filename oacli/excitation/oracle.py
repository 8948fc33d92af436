"""The estimator interface of the online planner, and a Cramér-Rao "oracle" that implements it.

The information-aware planner (:mod:`oacli.excitation.rattle`) needs, at every replan, the latest estimate
``θ̂`` and its standard deviations. Any sequential estimator that can be fed one measurement at a time will do
(the :class:`OnlineEstimator` protocol below). ``oacli excite --method rattle`` uses the real one by default:
the error-state EKF with χ² outlier gating of :mod:`oacli.estimation.sequential` ([ReSWARM2023] §4.4.1, §6.2.1),
behind :class:`oacli.estimation.online.OnlineSequentialEstimator` (``excitation.rattle.estimator: sequential``);
``estimator: oracle`` selects the oracle below instead.

:class:`CramerRaoOracle` is **not** an estimator: it knows the true parameters and reports them, with the
Cramér-Rao covariance ``(F_prior + F)⁻¹`` of the information accumulated so far along the flown trajectory (the
forward sensitivities of :mod:`oacli.excitation.information`, updated one measurement at a time, treating the applied
inputs as known). It is the covariance an efficient estimator would reach, which makes it the right yardstick for
testing the planner's information-seeking behaviour independently of any estimator's quirks.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from oacli.excitation.information import N_PARAMS, MeasurementModel, state_output_matrix
from oacli.model import rigid_body as rb
from oacli.types import ParameterEstimate


@runtime_checkable
class OnlineEstimator(Protocol):
    """A parameter estimator updated with one measurement at a time.

    ``update(t, x_measured, u_applied)``: ``x_measured (13,)`` is the state measured at mission time ``t`` [s]
    (``[r, v, q, ω]``, see :mod:`oacli.types`) and ``u_applied (6,)`` the input held since the previous
    measurement ``[f N world frame, τ N·m body frame]``. Returns the estimate after the update.
    """

    def update(self, t: float, x_measured: np.ndarray, u_applied: np.ndarray) -> ParameterEstimate:
        """Fuse one measurement and return the current estimate.

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state.
        u_applied : ndarray, shape (6,)
            Input held since the previous measurement.

        Returns
        -------
        ParameterEstimate
        """
        ...

    @property
    def estimate(self) -> ParameterEstimate:
        """The current estimate (the prior before any update)."""
        ...


class CramerRaoOracle:
    """Cramér-Rao covariance of the information gathered so far, around the true parameters (see module docstring).

    Parameters
    ----------
    theta_true : ndarray, shape (4,)
        True parameters [m kg, Ixx, Iyy, Izz kg·m²] (reported as the estimate).
    prior_covariance : ndarray, shape (4, 4)
        Prior covariance P0; its inverse is the prior information.
    measurement : MeasurementModel
        What is measured at every update, with its noise.
    x0 : ndarray, shape (13,)
        State at ``t0`` (known: zero sensitivity).
    t0 : float
        Mission time of ``x0`` [s].
    """

    method = "oracle-crb"

    def __init__(
        self,
        theta_true: np.ndarray,
        prior_covariance: np.ndarray,
        measurement: MeasurementModel,
        x0: np.ndarray,
        t0: float = 0.0,
    ) -> None:
        self.theta = np.array(theta_true, dtype=float).reshape(N_PARAMS)
        self.prior_information = np.linalg.inv(np.asarray(prior_covariance, dtype=float))
        self.measurement = measurement
        self.information = np.zeros((N_PARAMS, N_PARAMS))
        self._x = np.array(x0, dtype=float).reshape(13)
        self._s = np.zeros((13, N_PARAMS))
        self._t = float(t0)
        self._w_state = np.sqrt(measurement.state_weights)
        self._w_acc = np.sqrt(measurement.acceleration_weights)
        self._count = 0
        self._estimate = self._make(self._t)

    def _make(self, t: float) -> ParameterEstimate:
        total = self.prior_information + self.information
        cov = np.linalg.inv(0.5 * (total + total.T))
        return ParameterEstimate(t, self.theta, 0.5 * (cov + cov.T), self.method, samples_used=self._count)

    @property
    def estimate(self) -> ParameterEstimate:
        """The current estimate (true θ, Cramér-Rao covariance)."""
        return self._estimate

    def update(self, t: float, x_measured: np.ndarray, u_applied: np.ndarray) -> ParameterEstimate:
        """Add the information of the measurement at ``t`` (after the input ``u_applied`` held since the last one).

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state.
        u_applied : ndarray, shape (6,)
            Input held since the previous measurement.

        Returns
        -------
        ParameterEstimate
            The truth with the Cramér-Rao covariance (unchanged when ``t`` is not later than the last time).
        """
        dt = float(t) - self._t
        if dt <= 0:
            return self._estimate
        u = np.asarray(u_applied, dtype=float)
        x = np.asarray(x_measured, dtype=float)
        theta = self.theta
        _, a, _, c = rb.rk4_step_jacobians(self._x, u, theta, dt)
        if np.any(self._w_acc):
            fx, _, ft = rb.dynamics_jacobians(self._x, u, theta)
            rows = np.r_[3:6, 10:13]
            g_acc = self._w_acc[:, None] * (fx[rows] @ self._s + ft[rows])
            self.information += g_acc.T @ g_acc
        self._s = a @ self._s + c
        g = self._w_state[:, None] * (state_output_matrix(x) @ self._s)
        self.information += g.T @ g
        self._x = x.copy()
        self._t = float(t)
        self._count += 1
        self._estimate = self._make(self._t)
        return self._estimate
