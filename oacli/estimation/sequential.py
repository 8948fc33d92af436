"""Sequential estimation of the inertial parameters: an error-state EKF with the parameters as states.

Seed 001 §4.4.1 ran recursive least squares on the Newton-Euler regressor, fed with linear accelerations and with
angular accelerations obtained by differentiating the angular rate -- which amplified the noise and made the
localisation jumps of Fig. 21 dominate. RATTLE's code (``param_est``) is in fact an EKF whose state is θ and whose
measurement is the one-step prediction of the velocities from the previous *measured* state, so every measurement
noise enters two consecutive innovations. Here the filter's state is the robot state **and** the parameters,
``[x (13, on the manifold), φ (4)]`` with the 16-entry error state ``[δr, δv, δφ_att, δω, δφ]``:

* **predict** from ``t_{k-1}`` to ``t_k`` with the input held, through the exact multi-rate process model
  (:mod:`oacli.estimation.propagation`) and its Jacobians ``A_k``, ``C_k``, plus the process noise ``Q_k`` of
  :class:`oacli.estimation.models.ProcessNoise`; θ is constant;
* **gate** the innovation ``ν = ỹ_k ⊟ h(x̂⁻)`` with ``S = H P Hᵀ + R``: the record is rejected when
  ``νᵀ S⁻¹ ν`` exceeds the χ² quantile at 0.99 (seed 001 §6.2.1, Eqs. 40-42);
* **update** with the Joseph form and the multiplicative attitude reset.

Why not RLS on the regressor: it needs accelerations, which the telemetry does not carry at all for the angular
part (numerical differentiation at 5 Hz is worse than in flight), and it discards the pose measurements that
carry most of the information (integrated over the whole run). The EKF uses pose, velocity and angular rate
directly, and accelerations when a record has them; for a linear-Gaussian model its final estimate equals the batch
posterior, so the two estimators cross-check each other.

The parameters are filtered as ``φ`` (:mod:`oacli.estimation.parametrization`), so every estimate is physical
(mass > 0, inertia triangle inequalities) by construction: nothing is ever clipped or reset. The prior ``N(θ₀, P₀)``
is mapped to φ by linearisation. Records go through a :class:`~oacli.estimation.preprocessing.ReorderBuffer`
(seed 001 §5.4.3): out-of-order time stamps within the window are processed in order, later ones are reported as
late. If the state itself is lost (``reinitialise_after`` consecutive rejections, e.g. after starting on a
localisation jump), the robot state -- never θ -- is re-initialised from the current record and the event is
recorded.

Usage (what an online planner does)::

    est = SequentialEstimator(settings, prior)
    for record in stream:                      # Measurement(t, x_measured, u_applied, ...)
        estimate = est.update(record)          # ParameterEstimate: θ, covariance, samples used/rejected
    estimate = est.flush()                     # process what the reorder buffer still holds
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.estimation import parametrization as par
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.manifold import (
    TANGENT_DIM,
    boxminus,
    boxplus,
    lift_matrix,
    project_matrix,
    skew,
    so3_left_jacobian_inverse,
)
from oacli.estimation.models import EstimatorSettings, Measurement, measured_rows
from oacli.estimation.preprocessing import ReorderBuffer
from oacli.estimation.propagation import (
    dynamics_batch,
    dynamics_jacobians_batch,
    propagate_intervals,
    substep_schedule,
)
from oacli.types import ParameterEstimate

__all__ = ["SequentialEstimator", "SequentialStep"]

_ACCEL_ROWS = np.r_[3:6, 10:13]
_N = TANGENT_DIM + par.N_PARAMS
_UNMEASURED_VARIANCE = 1.0  # initial variance of state components no sensor measures (gauge, see batch.py)


@dataclass(frozen=True)
class SequentialStep:
    """What the filter did with one record.

    Attributes
    ----------
    t : float
        Record time [s].
    status : str
        ``"initialised"``, ``"accepted"``, ``"rejected"`` (χ² gate), ``"late"`` (time stamp before the last
        processed one) or ``"reinitialised"`` (state re-initialised after repeated rejections).
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


class SequentialEstimator:
    """Error-state EKF over ``[x, φ]`` with χ² gating and time-stamp reordering (see the module docstring).

    Parameters
    ----------
    settings : EstimatorSettings
        Measurement and process noise, integration grid, gate probability, reorder window.
    prior : ParameterEstimate
        ``N(θ₀, P₀)``: a physical θ₀ and its covariance (variances on the diagonal).
    reinitialise_after : int
        Consecutive gated records after which the robot state is re-initialised from the next record (>= 1).
    """

    def __init__(self, settings: EstimatorSettings, prior: ParameterEstimate, *, reinitialise_after: int = 5) -> None:
        if reinitialise_after < 1:
            raise ValueError("reinitialise_after must be >= 1")
        self.settings = settings
        self.prior = prior
        self.reinitialise_after = int(reinitialise_after)
        self._phi = par.phi_from_theta(prior.theta)
        jac_inv = np.linalg.inv(par.theta_jacobian(self._phi))
        self._p_phi0 = jac_inv @ prior.covariance @ jac_inv.T
        self._state_rows, self._accel_rows = measured_rows(settings.measurement)
        self._r_state = 1.0 / settings.measurement.state_weights[self._state_rows]
        self._r_accel = 1.0 / settings.measurement.acceleration_weights[self._accel_rows]
        self._buffer = ReorderBuffer(settings.reorder_window)
        self._x: np.ndarray | None = None
        self._p = np.zeros((_N, _N))
        self._p[TANGENT_DIM:, TANGENT_DIM:] = self._p_phi0
        self._t_last: float | None = None
        self._u_last: np.ndarray | None = None
        self._rejected_in_a_row = 0
        self.samples_used = 0
        self.samples_rejected = 0
        self.reinitialisations = 0
        self.history: list[SequentialStep] = []

    # -- public API ------------------------------------------------------------------------------------------------

    @property
    def estimate(self) -> ParameterEstimate:
        """The current estimate (the prior before the first record is processed)."""
        jac = par.theta_jacobian(self._phi)
        cov = jac @ self._p[TANGENT_DIM:, TANGENT_DIM:] @ jac.T
        return ParameterEstimate(
            t=float(self._t_last) if self._t_last is not None else float(self.prior.t),
            theta=par.theta_from_phi(self._phi),
            covariance=0.5 * (cov + cov.T),
            method="sequential" if self._t_last is not None else "prior",
            samples_used=self.samples_used,
            samples_rejected=self.samples_rejected,
        )

    @property
    def state(self) -> np.ndarray | None:
        """Filtered robot state at the last processed record (None before the first)."""
        return None if self._x is None else self._x.copy()

    def update(self, record: Measurement) -> ParameterEstimate:
        """Take one record (possibly out of order) and return the current estimate.

        The record may be held in the reorder buffer; the estimate reflects every record released so far.
        """
        released, late = self._buffer.push(record)
        for rec in late:
            self._late(rec)
        for rec in released:
            self._process(rec)
        return self.estimate

    def flush(self) -> ParameterEstimate:
        """Process every record still in the reorder buffer and return the estimate."""
        released, late = self._buffer.flush()
        for rec in late:
            self._late(rec)
        for rec in released:
            self._process(rec)
        return self.estimate

    # -- filter ----------------------------------------------------------------------------------------------------

    def _late(self, rec: Measurement) -> None:
        self.samples_rejected += 1
        self.history.append(SequentialStep(rec.t, "late", float("nan"), 0, self.estimate, np.full(13, np.nan)))

    def _initialise(self, rec: Measurement) -> None:
        self._x = np.array(rec.x_measured, dtype=float)
        p_x = np.full(TANGENT_DIM, _UNMEASURED_VARIANCE)
        p_x[self._state_rows] = self._r_state
        self._p[:TANGENT_DIM, :] = 0.0
        self._p[:, :TANGENT_DIM] = 0.0
        self._p[:TANGENT_DIM, :TANGENT_DIM] = np.diag(p_x)
        self._rejected_in_a_row = 0

    def _predict(self, t: float) -> None:
        assert self._x is not None and self._t_last is not None and self._u_last is not None
        theta = par.theta_from_phi(self._phi)
        durations = substep_schedule(np.array([self._t_last]), np.array([t]), self.settings.substep_s)
        x_new, a, c = propagate_intervals(self._x[None], self._u_last[None], theta, durations)
        x_new = x_new[0]
        proj = project_matrix(x_new)
        phi_mat = np.eye(_N)
        phi_mat[:TANGENT_DIM, :TANGENT_DIM] = proj @ a[0] @ lift_matrix(self._x)
        phi_mat[:TANGENT_DIM, TANGENT_DIM:] = proj @ c[0] @ par.theta_jacobian(self._phi)
        q = self.settings.process.covariance(np.array([t - self._t_last]), self.prior.theta)[0]
        p = phi_mat @ self._p @ phi_mat.T
        p[:TANGENT_DIM, :TANGENT_DIM] += q
        self._x = x_new
        self._p = 0.5 * (p + p.T)

    def _innovation(self, rec: Measurement) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``ν``, ``H`` (m, 16) and ``R`` diagonal (m,) for the measured components of ``rec``."""
        assert self._x is not None
        e = boxminus(rec.x_measured, self._x)
        h_state = np.zeros((TANGENT_DIM, _N))
        h_state[:, :TANGENT_DIM] = np.eye(TANGENT_DIM)
        h_state[6:9, 6:9] = so3_left_jacobian_inverse(e[6:9])
        nu = [e[self._state_rows]]
        h = [h_state[self._state_rows]]
        r = [self._r_state]
        acc = rec.accelerations()
        rows = [i for i, j in enumerate(self._accel_rows) if np.isfinite(acc[j])]
        if rows:
            sel = self._accel_rows[rows]
            theta = par.theta_from_phi(self._phi)
            x1, u1 = self._x[None], rec.u_applied[None]
            pred = dynamics_batch(x1, u1, theta)[0, _ACCEL_ROWS]
            jac = dynamics_jacobians_batch(x1, u1, theta)[0][_ACCEL_ROWS]
            h_acc = np.zeros((6, _N))
            h_acc[:, :TANGENT_DIM] = jac[:, 0:13] @ lift_matrix(self._x)
            h_acc[:, TANGENT_DIM:] = jac[:, 13:] @ par.theta_jacobian(self._phi)
            nu.append((acc - pred)[sel])
            h.append(h_acc[sel])
            r.append(self._r_accel[rows])
        return np.concatenate(nu), np.vstack(h), np.concatenate(r)

    def _correct(self, nu: np.ndarray, h: np.ndarray, r: np.ndarray, s: np.ndarray) -> None:
        assert self._x is not None
        gain = np.linalg.solve(s, h @ self._p).T
        delta = gain @ nu
        ikh = np.eye(_N) - gain @ h
        p = ikh @ self._p @ ikh.T + (gain * r) @ gain.T
        # Multiplicative attitude reset: the error is re-expressed about the corrected attitude.
        reset = np.eye(_N)
        reset[6:9, 6:9] -= 0.5 * skew(delta[6:9])
        self._p = reset @ (0.5 * (p + p.T)) @ reset.T
        self._x = boxplus(self._x, delta[:TANGENT_DIM])
        self._phi = self._phi + delta[TANGENT_DIM:]

    def _process(self, rec: Measurement) -> None:
        status = "accepted"
        d2 = float("nan")
        dof = 0
        if self._x is None:
            self._initialise(rec)
            status = "initialised"
            self.samples_used += 1
        else:
            self._predict(rec.t)
            nu, h, r = self._innovation(rec)
            dof = nu.size
            s = h @ self._p @ h.T + np.diag(r)
            s = 0.5 * (s + s.T)
            chol = np.linalg.cholesky(s)
            z = np.linalg.solve(chol, nu)
            d2 = float(z @ z)
            gate = self.settings.gate_probability
            if gate is not None and d2 > chi2_threshold(dof, gate):
                self.samples_rejected += 1
                self._rejected_in_a_row += 1
                status = "rejected"
                if self._rejected_in_a_row >= self.reinitialise_after:
                    self._initialise(rec)
                    self.reinitialisations += 1
                    status = "reinitialised"
            else:
                self._correct(nu, h, r, s)
                self._rejected_in_a_row = 0
                self.samples_used += 1
        self._t_last = rec.t
        self._u_last = np.array(rec.u_applied, dtype=float)
        assert self._x is not None
        self.history.append(SequentialStep(rec.t, status, d2, dof, self.estimate, self._x.copy()))
