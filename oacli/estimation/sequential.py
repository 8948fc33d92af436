"""Sequential estimation of the inertial parameters: an error-state EKF with the parameters as states.

[ReSWARM2023] §4.4.1 ran recursive least squares on the Newton-Euler regressor, fed with linear accelerations and with
angular accelerations obtained by differentiating the angular rate -- which amplified the noise and made the
localisation jumps of Fig. 21 dominate. RATTLE's code (``param_est``) is in fact an EKF whose state is θ and whose
measurement is the one-step prediction of the velocities from the previous *measured* state, so every measurement
noise enters two consecutive innovations. Here the filter's state is the robot state **and** the parameters,
``[x (13, on the manifold), φ (4)]`` with the 16-entry error state ``[δr, δv, δφ_att, δω, δφ]``:

* **predict** from ``t_{k-1}`` to ``t_k`` with the input held, through the exact multi-rate process model
  (:mod:`oacli.estimation.propagation`) and its Jacobians ``A_k``, ``C_k``, plus the process noise ``Q_k`` of
  :class:`oacli.estimation.models.ProcessNoise`; θ is constant;
* **gate** the innovation ``ν = ỹ_k ⊟ h(x̂⁻)`` with ``S = H P Hᵀ + R``: the record is rejected when
  ``νᵀ S⁻¹ ν`` exceeds the χ² quantile at 0.99 ([ReSWARM2023] §6.2.1, Eqs. 40-42);
* **update** by Gauss-Newton on the last step (an iterated EKF: ``[x_{k-1}, φ, x_k]`` given their prior, the
  process model and the record), which re-linearises the process model about each iterate.

**Bootstrap.** With RATTLE's broad prior (inertia standard deviation 0.07 kg·m², half the value) and gyro noise of
0.016 rad/s, the first seconds of data carry information that is strongly non-linear in θ (the inertias enter as
I⁻¹), and a Gaussian filter started from the prior linearises about estimates that are still far off and can become
overconfident (and then gate good records). So the filter starts as a batch solver
(:func:`oacli.estimation.batch.estimate_batch` over the records so far, at geometrically spaced record counts)
and hands over -- last state, φ and their joint covariance -- once every parameter is known to
``bootstrap_relative_std`` (5 %). Until then :meth:`SequentialEstimator.update` returns the batch estimate.

The flight's own estimator, recursive least squares on accelerations, is :mod:`oacli.estimation.rls`; this filter
uses the pose, velocity and angular rate directly (they carry most of the information, integrated over the whole
run) and accelerations when a record has them; for a linear-Gaussian model its final estimate equals the batch
posterior, so the two estimators cross-check each other. The parameters are filtered as ``φ``
(:mod:`oacli.estimation.parametrization`), so every estimate is physical by construction: nothing is ever clipped or
reset. Out-of-order records go through a :class:`~oacli.estimation.preprocessing.ReorderBuffer`; a lost state
(``reinitialise_after`` consecutive rejections) re-initialises the robot state, never θ; lost records and gaps in
the input record are bridged as the batch links them (:mod:`oacli.estimation.lost_inputs`, with the IMU where it
survived) or, after a longer gap, start a new segment. docs/estimation.md ("The sequential filter") has the details
and the counters each case increments.

Usage (what an online planner does)::

    est = SequentialEstimator(settings, prior)
    for record in stream:                      # Measurement(t, x_measured, u_applied, ...)
        estimate = est.update(record)          # ParameterEstimate: θ, covariance, samples used/rejected
    estimate = est.flush()                     # process what the reorder buffer still holds
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from oacli.estimation.batch import BatchResult
from oacli.estimation.batch_model import FullModel, LegacyModel
from oacli.estimation.bootstrap import handover_in_reach, solve_bootstrap
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.lost_inputs import (
    gyro_bridge_offset,
)
from oacli.estimation.manifold import (
    TANGENT_DIM,
    boxminus,
    boxplus,
    lift_matrix,
    project_matrix,
    so3_right_jacobian_inverse,
)
from oacli.estimation.manifold_one import (
    boxminus_one,
    boxplus_one,
    lift_one,
    project_one,
    right_jacobian_inverse_one,
)
from oacli.estimation.models import EstimatorSettings, Measurement, SequentialStep, measured_rows
from oacli.estimation.preprocessing import ReorderBuffer
from oacli.estimation.propagation import propagate_intervals, propagate_one, substep_schedule
from oacli.estimation.sequential_gaps import bridge_gap
from oacli.types import ParameterEstimate

__all__ = ["SequentialEstimator", "SequentialStep"]

_ATT = np.arange(6, 9)  # attitude rows/columns of the 12-entry error state
_UNMEASURED_VARIANCE = 1.0  # initial variance of state components no sensor measures (gauge, see batch.py)
_MAX_UPDATE_ITERATIONS = 5
_STEP_TOL_PHI = 1e-6
"""The iterated update has converged when a step moves φ by less than this and (``_STEP_TOL_X``) the states by
less than that (radians, metres, ...): the next step would be ~1e-10 (quadratic convergence)."""
_STEP_TOL_X = 1e-6


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
    bootstrap_relative_std : float or None
        Hand over from the batch bootstrap once every standard deviation is below this fraction of its estimate
        (``None``: start the filter from the first record and the prior).
    bootstrap_check_every : int
        Fewest records between two bootstrap solves (>= 1); the spacing grows by 25 % each time.
    bootstrap_max_records : int
        Hand over after this many records even if θ is not yet that well known (the batch covariance is used as
        it is; if it is singular -- unexciting data -- the filter starts from the last record and the prior).
    reference : bool
        Use the original implementation (the general batched RK4 :func:`~oacli.estimation.propagation.
        propagate_intervals` for every propagation, no reuse of the prediction's linearisation, the batch bootstrap
        on its reference path); the same filter, kept to check the default path against (tests, benchmark).
    intermediate_estimates : bool
        During the bootstrap, solve the batch at every check so that :attr:`estimate` improves as records arrive
        (an online planner reads it). False (an offline caller that keeps only the final estimate, e.g. the
        ``estimate`` stage): a check that the covariance at the previous solution shows to be far from the
        hand-over (:meth:`_near_handover`) is not solved, and the estimate stays at the prior until the hand-over;
        the hand-over and everything after it are the same.
    """

    def __init__(
        self, settings: EstimatorSettings, prior: ParameterEstimate, *, reinitialise_after: int = 5,
        bootstrap_relative_std: float | None = 0.05, bootstrap_check_every: int = 5,
        bootstrap_max_records: int = 200, reference: bool = False, intermediate_estimates: bool = True,
        model: FullModel | None = None,
    ) -> None:
        if reinitialise_after < 1:
            raise ValueError("reinitialise_after must be >= 1")
        if bootstrap_check_every < 1 or (bootstrap_relative_std is not None and not bootstrap_relative_std > 0):
            raise ValueError("bootstrap_check_every must be >= 1 and bootstrap_relative_std > 0 or None")
        self.settings = settings
        self.prior = prior
        self.reference = bool(reference)
        self._predicted: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if self.reference:
            self._bm, self._bp, self._jr, self._lift, self._proj = (
                boxminus, boxplus, so3_right_jacobian_inverse, lift_matrix, project_matrix)
        else:
            self._bm, self._bp, self._jr, self._lift, self._proj = (
                boxminus_one, boxplus_one, right_jacobian_inverse_one, lift_one, project_one)
        self.reinitialise_after = int(reinitialise_after)
        self.bootstrap_relative_std = bootstrap_relative_std
        self.bootstrap_check_every = int(bootstrap_check_every)
        self.bootstrap_max_records = max(int(bootstrap_max_records), 2)
        self._next_check = self.bootstrap_check_every
        self._boot: list[Measurement] | None = [] if bootstrap_relative_std is not None else None
        self._boot_estimate: ParameterEstimate | None = None
        self._boot_last: BatchResult | None = None  # the last full bootstrap solve
        self.intermediate_estimates = bool(intermediate_estimates)
        self.bootstrap_records = 0
        self.bootstrap_unidentified = False
        """The bootstrap's hand-over solve had no usable covariance (θ not identified by its records, e.g. no record
        passed its χ² gate): the filter went on from the prior instead (the estimate stage reports it)."""
        self._full = model
        self._model: LegacyModel | FullModel = LegacyModel() if model is None else model
        n = self._n = TANGENT_DIM + self._model.n  # the error state [δx, δφ]
        self._eye_n, self._eye_step = np.eye(n), np.eye(n + TANGENT_DIM)  # the last step's [δx_{k-1}, δφ, δx_k]
        self._posterior_order = np.ix_(*(2 * [np.r_[n:n + TANGENT_DIM, TANGENT_DIM:n]]))  # [x_k, φ] in it
        idx = self._model.prior_index
        p_theta0 = prior.covariance if model is None else model.prior_cov[np.ix_(idx, idx)]
        self._phi = self._model.phi(prior.theta if model is None else model.prior_mean)
        jac_inv = np.linalg.inv(self._model.jacobian(self._phi)[idx])
        self._p_phi0 = jac_inv @ p_theta0 @ jac_inv.T
        self._state_rows, self._accel_rows = measured_rows(settings.measurement)
        self._r_state = 1.0 / settings.measurement.state_weights[self._state_rows]
        self._r_accel = 1.0 / settings.measurement.acceleration_weights[self._accel_rows]
        self._w_state = 1.0 / np.sqrt(self._r_state)
        self._att_in_rows = np.flatnonzero((self._state_rows >= 6) & (self._state_rows < 9))
        att = self._att_in_rows  # the measured attitude rows: their J_r⁻¹ blocks (rows of it, all 3 columns)
        self._att_sel = self._state_rows[att] - 6
        self._w_att = self._w_state[att, None]
        self._ix_innovation_att = np.ix_(att, _ATT)
        self._ix_step_att = np.ix_(n + TANGENT_DIM + att, n + _ATT)
        self._q_cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._buffer = ReorderBuffer(settings.reorder_window)
        self._x: np.ndarray | None = None
        self._p = np.zeros((n, n))
        self._p[TANGENT_DIM:, TANGENT_DIM:] = self._p_phi0
        self._t_last: float | None = None
        self._u_last: np.ndarray | None = None
        self._rejected_in_a_row = 0
        self.samples_used = 0
        self.samples_rejected = 0
        self.reinitialisations = 0
        self.segments = 0
        self.history: list[SequentialStep] = []
        self._estimate_cache: ParameterEstimate | None = None
        self.gaps_bridged = 0
        self.gaps_bridged_imu = 0
        self.gaps_bridged_gyro = 0
        self._gap_q: np.ndarray | None = None
        # Across an accelerometer-bridged gap: the measured mean specific force [m/s²] (world) and the interval [s];
        # _propagate adds its exact effect on position and velocity (the held force is 0 there).
        self._gap_acc: tuple[np.ndarray, float] | None = None
        # The previous record when it is a lost instant with the accelerometer's mean: (f/m [m/s²], readings).
        self._lost_acc: tuple[np.ndarray, int] | None = None
        # Likewise with the gyro's mean ω̇ over the lost interval: (ω̇ [rad/s²], its variance, the rate at t [rad/s]);
        # across a gyro-bridged gap, the ω̇ the lost torque added (J⁻¹τ), that rate and the interval [s] (_propagate).
        self._lost_gyro: tuple[np.ndarray, float, np.ndarray] | None = None
        self._gap_gyro: tuple[np.ndarray, np.ndarray, float] | None = None
        self._inputs_t: list[float] = []  # every processed record's time, input and segment flag (_bridge_gap)
        self._inputs_u: list[np.ndarray] = []
        self._inputs_start: list[bool] = []

    # -- public API ------------------------------------------------------------------------------------------------

    @property
    def estimate(self) -> ParameterEstimate:
        """The current estimate (the prior before the first record is processed)."""
        if self._boot is not None:
            return self._boot_estimate if self._boot_estimate is not None else self.prior
        if self._estimate_cache is not None:  # unchanged since the last record
            return self._estimate_cache
        theta, cov = self.full_estimate()
        self._estimate_cache = ParameterEstimate(
            t=float(self._t_last) if self._t_last is not None else float(self.prior.t),
            theta=theta[:4],
            covariance=cov[:4, :4],
            method="sequential" if self._t_last is not None else "prior",
            samples_used=self.samples_used,
            samples_rejected=self.samples_rejected,
        )
        return self._estimate_cache

    def full_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """θ and its covariance of the model filtered: the full rigid body's (16, 16×16; entries not estimated
        held, zero variance) or [m, Ixx, Iyy, Izz] (4, 4×4) (the current filter state; call after :meth:`flush`).

        Returns
        -------
        theta : ndarray, shape (16,) or (4,)
        covariance : ndarray, shape (16, 16) or (4, 4)
        """
        jac = self._model.jacobian(self._phi)
        cov = jac @ self._p[TANGENT_DIM:, TANGENT_DIM:] @ jac.T
        return self._model.theta(self._phi), 0.5 * (cov + cov.T)

    @property
    def state(self) -> np.ndarray | None:
        """Filtered robot state at the last processed record (None before the first)."""
        return None if self._x is None else self._x.copy()

    def update(self, record: Measurement) -> ParameterEstimate:
        """Take one record (possibly out of order) and return the current estimate.

        The record may be held in the reorder buffer; the estimate reflects every record released so far.

        Parameters
        ----------
        record : Measurement

        Returns
        -------
        ParameterEstimate
        """
        released, late = self._buffer.push(record)
        for rec in late:
            self._late(rec)
        for rec in released:
            self._process(rec)
        return self.estimate

    def flush(self) -> ParameterEstimate:
        """Process every record still in the reorder buffer and return the estimate.

        Returns
        -------
        ParameterEstimate
        """
        released, late = self._buffer.flush()
        for rec in late:
            self._late(rec)
        for rec in released:
            self._process(rec)
        if self._boot:
            self._bootstrap(force=True)
        return self.estimate

    # -- filter ----------------------------------------------------------------------------------------------------

    def _late(self, rec: Measurement) -> None:
        self._estimate_cache = None
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
        theta = self._model.theta(self._phi)
        durations = substep_schedule(np.array([self._t_last]), np.array([t]), self.settings.substep_s)
        self._before = (self._x.copy(), self._phi.copy(), self._p.copy(), durations)
        x_new, a, c = self._propagate(self._x, theta, durations)
        self._predicted = (x_new, a, c)  # the first iterate of the update linearises at this very point
        proj = self._proj(x_new)
        phi_mat = self._eye_n.copy()
        phi_mat[:TANGENT_DIM, :TANGENT_DIM] = proj @ a @ self._lift(self._x)
        phi_mat[:TANGENT_DIM, TANGENT_DIM:] = proj @ c @ self._model.jacobian(self._phi)
        self._q, self._w_proc = self._process_noise(t - self._t_last)
        if self._gap_q is not None:  # across a bridged gap: the predicted input's error (_bridge_gap)
            self._q = self._q + self._gap_q
            self._w_proc = np.linalg.inv(np.linalg.cholesky(self._q))
            self._gap_q = None
        p = phi_mat @ self._p @ phi_mat.T
        p[:TANGENT_DIM, :TANGENT_DIM] += self._q
        self._x = x_new
        self._p = 0.5 * (p + p.T)

    def _process_noise(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``Q`` (12, 12) over an interval of ``dt_s`` and its whitening ``W`` (``WᵀW = Q⁻¹``); the intervals
        repeat (the control period), so both are kept per interval length."""
        hit = self._q_cache.get(dt_s)
        if hit is None:
            q = self.settings.process.covariance(np.array([dt_s]), self.prior.theta)[0]
            hit = (q, np.linalg.inv(np.linalg.cholesky(q)))
            if len(self._q_cache) >= 64:
                self._q_cache.clear()
            self._q_cache[dt_s] = hit
        return hit

    def _propagate(self, x: np.ndarray, theta: np.ndarray, durations: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The process model over the current interval from ``x`` with the held input: ``x⁺``, ``∂x⁺/∂x``,
        ``∂x⁺/∂θ``."""
        assert self._u_last is not None
        if self._full is not None:  # the full rigid body (rigid_dynamics.propagate_full)
            x1, a1, c1 = self._full.propagate(x[None], self._u_last[None], theta, durations)
            assert a1 is not None and c1 is not None
            x_new, a, c = x1[0], a1[0], c1[0]
        elif self.reference:
            x_new, a, c = propagate_intervals(x[None], self._u_last[None], theta, durations)
            x_new, a, c = x_new[0], a[0], c[0]
        else:
            x_new, a, c = propagate_one(x, self._u_last, theta, durations)
        if self._gap_acc is not None:  # the measured f/m over a bridged gap (constant, world frame): exact
            acc, dt_s = self._gap_acc
            x_new = x_new.copy()
            x_new[0:3] += (0.5 * dt_s**2) * acc
            x_new[3:6] += dt_s * acc
        if self._gap_gyro is not None:  # the ω̇ the lost torque added (gyro, [Doerr2021] Eq. 35b): body frame
            added, rate, dt_s = self._gap_gyro
            offset = np.zeros(TANGENT_DIM)
            offset[6:12] = gyro_bridge_offset(added, rate, dt_s)
            x_new = self._bp(x_new, offset)
        return x_new, a, c

    def _accel_selection(self, rec: Measurement) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The record's measured accelerations (6,), the rows of them it has (indices into ``[linear, angular]``)
        and their noise variances."""
        acc = rec.accelerations()
        keep = np.isfinite(acc[self._accel_rows])
        return acc, self._accel_rows[keep], self._r_accel[keep]

    def _accel_model(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, dtheta: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted accelerations (6,) at ``x`` and their Jacobians w.r.t. ``δx`` (6, 12) and ``δφ`` (6, 4)."""
        pred, jx, jth = self._model.accelerations(x[None], u[None], theta)
        assert jx is not None and jth is not None
        return pred[0], jx[0] @ self._lift(x), jth[0] @ dtheta

    def _innovation(self, rec: Measurement) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``ν``, ``H`` (m, 16) and ``R`` diagonal (m,) for the measured components of ``rec``."""
        assert self._x is not None
        e = self._bm(rec.x_measured, self._x)
        rows = self._state_rows
        acc, acc_rows, r_acc = self._accel_selection(rec)
        m = rows.size
        h = np.zeros((m + acc_rows.size, self._n))
        h[np.arange(m), rows] = 1.0
        att = self._att_in_rows  # positions of the measured attitude rows 6:9 among ``rows``
        if att.size:
            h[self._ix_innovation_att] = self._jr(-e[6:9])[self._att_sel]
        nu, r = e[rows], self._r_state
        if acc_rows.size:
            pred, jx, jphi = self._accel_model(self._x, rec.u_applied, self._model.theta(self._phi),
                                               self._model.jacobian(self._phi))
            h[m:, :TANGENT_DIM] = jx[acc_rows]
            h[m:, TANGENT_DIM:] = jphi[acc_rows]
            nu = np.concatenate([nu, (acc - pred)[acc_rows]])
            r = np.concatenate([r, r_acc])
        return nu, h, r

    def _step_residuals(
        self, rec: Measurement, xa: np.ndarray, ph: np.ndarray, xb: np.ndarray, first: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals and Jacobian of the last step's problem at ``(x_{k-1}, φ, x_k)`` (see below);
        ``first``: ``(x_{k-1}, φ)`` is the prediction's point, whose propagation is reused.

        Rows: the prior on ``[x_{k-1}, φ]`` (the previous posterior), the process ``x_k ⊟ f(x_{k-1}, u, θ)``, the
        measurement ``x_k ⊟ ỹ_k`` and the measured accelerations; columns ``[δx_{k-1}, δφ, δx_k]``. Each block is
        written into one preallocated matrix (the identity blocks directly, the attitude corrections ``J_r⁻¹`` on
        their three columns or rows only).
        """
        assert self._u_last is not None
        x_prev, phi_prev, _, durations = self._before
        w_prior, w_proc = self._w_prior, self._w_proc
        nt = TANGENT_DIM
        kb = self._n  # [δx_{k-1}, δφ, δx_k]
        theta = self._model.theta(ph)
        dtheta = self._model.jacobian(ph)
        if first and not self.reference and self._predicted is not None:
            fx, a, c = self._predicted
        else:
            fx, a, c = self._propagate(xa, theta, durations)
        acc, acc_rows, r_acc = self._acc
        rows = self._state_rows
        m = rows.size
        n_rows = kb + nt + m + acc_rows.size
        res = np.empty(n_rows)
        jac = np.zeros((n_rows, kb + nt))
        # Prior on [x_{k-1}, φ]: J = I except J_r⁻¹ on the attitude block.
        e_xa = self._bm(xa, x_prev)
        res[:nt] = e_xa
        res[nt:kb] = ph - phi_prev
        res[:kb] = w_prior @ res[:kb]
        jac[:kb, :kb] = w_prior
        jac[:kb, _ATT] = w_prior[:, _ATT] @ self._jr(e_xa[6:9])
        # Process: x_k ⊟ f(x_{k-1}, u, θ).
        e_proc = self._bm(xb, fx)
        proj = self._proj(fx)
        proj[_ATT] = self._jr(-e_proc[6:9]) @ proj[_ATT]
        blk = np.empty((nt, kb))
        blk[:, :nt] = -(proj @ (a @ self._lift(xa)))
        blk[:, nt:] = -(proj @ (c @ dtheta))
        jac[kb:kb + nt, :kb] = w_proc @ blk
        jac[kb:kb + nt, kb:] = w_proc
        jac[kb:kb + nt, kb + 6:kb + 9] = w_proc[:, _ATT] @ self._jr(e_proc[6:9])
        res[kb:kb + nt] = w_proc @ e_proc
        # Measurement: x_k ⊟ ỹ_k (whitened).
        e_meas = self._bm(xb, rec.x_measured)
        o = kb + nt
        res[o:o + m] = self._w_state * e_meas[rows]
        jac[o + np.arange(m), kb + rows] = self._w_state
        att = self._att_in_rows
        if att.size:
            jac[self._ix_step_att] = self._w_att * self._jr(e_meas[6:9])[self._att_sel]
        if acc_rows.size:
            w_acc = 1.0 / np.sqrt(r_acc)
            pred, jx, jphi = self._accel_model(xb, rec.u_applied, theta, dtheta)
            o += m
            res[o:] = w_acc * (pred - acc)[acc_rows]
            jac[o:, nt:kb] = w_acc[:, None] * jphi[acc_rows]
            jac[o:, kb:] = w_acc[:, None] * jx[acc_rows]
        return res, jac

    def _iterated_update(self, rec: Measurement) -> None:
        """Gauss-Newton on the last step: ``[x_{k-1}, φ, x_k]`` given their prior, the process model and ``ỹ_k``.

        The iterated EKF (Bell & Cathey 1993) of the augmented step: the process model is re-linearised about each
        iterate instead of about the previous estimate only, which keeps the filter consistent while θ is still far
        from its value (the inertias enter through I⁻¹). Full Gauss-Newton steps are taken (with the nearly rigid
        process model the first step may raise the cost -- the Maratos effect of stiff constraints -- and the next
        one removes it); the iterate with the lowest cost is kept, so a wild record can never drive the filter to
        non-finite values. The result is the Gaussian posterior of ``[x_k, φ]``.
        """
        assert self._x is not None
        x_prev, phi_prev, p_prev, _ = self._before
        self._w_prior = np.linalg.inv(np.linalg.cholesky(p_prev))
        self._acc = self._accel_selection(rec)
        nt, kb = TANGENT_DIM, self._n
        xa, ph, xb = x_prev, phi_prev, self._x  # never modified in place (each step makes new arrays)
        r, j = self._step_residuals(rec, xa, ph, xb, first=True)
        best_cost, best, best_j = float(r @ r), (xa, ph, xb), j
        for it in range(_MAX_UPDATE_ITERATIONS):
            jt = j.T
            step = -np.linalg.solve(jt @ j, jt @ r)
            size = np.abs(step)
            size_x = max(float(size[:nt].max()), float(size[kb:].max()))
            size_phi = float(size[nt:kb].max())
            if it > 0 and not self.reference and size_phi < _STEP_TOL_PHI and size_x < _STEP_TOL_X:
                # Converged (Gauss-Newton's steps shrink quadratically: ~1e-3, 1e-7, 1e-10): take the last step
                # without another linearisation; its Jacobian differs from the one here by that step's size.
                xa, ph, xb = best
                best = (self._bp(xa, step[:nt]), ph + step[nt:kb], self._bp(xb, step[kb:]))
                break
            xa, ph, xb = self._bp(xa, step[:nt]), ph + step[nt:kb], self._bp(xb, step[kb:])
            with np.errstate(all="ignore"):
                r, j = self._step_residuals(rec, xa, ph, xb)
                cost = float(r @ r)
                finite = math.isfinite(cost) and math.isfinite(float(np.sum(j)))  # a sum is finite iff every entry is
            if not finite:
                break
            if cost < best_cost:
                best_cost, best, best_j = cost, (xa, ph, xb), j
            if size_phi < 1e-8 and float(size[kb:].max()) < 1e-10:
                break
        _, ph, xb = best
        # (JᵀJ)⁻¹ from the triangular factor of J (R⁻¹R⁻ᵀ): JᵀJ of a nearly rigid step has a condition number of
        # ~1e9, so its inverse would be good to ~1e-7 only; the factor of J keeps cond(J)·ε (~1e-11).
        r_inv = sla.solve_triangular(np.linalg.qr(best_j, mode="r"), self._eye_step, check_finite=False)
        cov = r_inv @ r_inv.T
        p = cov[self._posterior_order]  # [x_k, φ]
        self._x, self._phi, self._p = xb, ph, 0.5 * (p + p.T)

    def _bootstrap(self, force: bool) -> None:
        """Batch-solve the records so far; hand over to the filter once θ is known to ``bootstrap_relative_std``."""
        assert self._boot is not None
        if len(self._boot) < 2:
            if force:  # a single record: start the filter from it
                recs, self._boot = self._boot, None
                for history in (self._inputs_t, self._inputs_u, self._inputs_start):
                    del history[len(history) - len(recs):]  # processed again below
                for rec in recs:
                    self._process(rec)
            return
        n = len(self._boot)
        if not (force or self.intermediate_estimates or n >= self.bootstrap_max_records or self._near_handover()):
            return
        result = solve_bootstrap(self._boot, self._boot_last, self.settings, self.prior, self.reference, self._full)
        self._boot_last = result
        est = result.estimate
        self._boot_estimate = ParameterEstimate(est.t, est.theta, est.covariance, "sequential", est.samples_used,
                                                est.samples_rejected)
        converged = bool(np.all(est.std <= self.bootstrap_relative_std * np.abs(est.theta)))
        if not (force or converged or len(self._boot) >= self.bootstrap_max_records):
            return
        gate = self.settings.gate_probability
        usable = bool(np.all(np.isfinite(result.last_covariance))) and bool(
            np.all(np.linalg.eigvalsh(result.last_covariance) > 0))
        for i, rec in enumerate(self._boot):
            status = "accepted" if result.inliers[i] else "rejected" if rec.state_measured else "predicted"
            self.history.append(SequentialStep(rec.t, status, float(result.d2[i]), result.dof, self._boot_estimate,
                                               result.states[i].copy()))
        self.samples_used += est.samples_used
        self.samples_rejected += est.samples_rejected
        self.bootstrap_records = len(self._boot)
        if not usable:  # θ not identified so far: continue as a plain filter from the prior
            self.bootstrap_unidentified = True
            self._x = result.states[-1].copy()
            self._initialise(self._boot[-1])
            self._t_last = self._boot[-1].t
            self._u_last = np.array(self._boot[-1].u_applied, dtype=float)
            self._boot = None
            return
        self._x = result.states[-1].copy()
        self._phi = result.phi.copy()
        self._p = result.last_covariance.copy()
        self._t_last = self._boot[-1].t
        self._u_last = np.array(self._boot[-1].u_applied, dtype=float)
        self._rejected_in_a_row = 0 if gate is None or result.inliers[-1] else 1
        self._boot = None

    def _near_handover(self) -> bool:
        """Whether the records so far may be within reach of the hand-over (:func:`handover_in_reach`)."""
        assert self._boot is not None and self.bootstrap_relative_std is not None
        return handover_in_reach(self._boot, self._boot_last, self.settings, self.prior, self.bootstrap_relative_std,
                                 self._full)

    def _predict_and_update(self, rec: Measurement) -> tuple[str, float, int]:
        """Predict to ``rec.t``, gate the innovation (χ², Mahalanobis d²) and update; returns (status, d², dof)."""
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
            if self._rejected_in_a_row >= self.reinitialise_after:
                self._initialise(rec)
                self.reinitialisations += 1
                return "reinitialised", d2, dof
            return "rejected", d2, dof
        self._iterated_update(rec)
        self._rejected_in_a_row = 0
        self.samples_used += 1
        return "accepted", d2, dof

    def _bridge_gap(self, rec: Measurement) -> bool:
        """Prepare the prediction across a gap ending at ``rec`` (:func:`~oacli.estimation.sequential_gaps.bridge_gap`);
        False when it cannot be bridged."""
        return bridge_gap(self, rec)

    def _process(self, rec: Measurement) -> None:
        self._estimate_cache = None
        self._inputs_t.append(rec.t)
        self._inputs_u.append(np.asarray(rec.u_applied, dtype=float))
        self._inputs_start.append(bool(rec.starts_segment))
        if self._boot is not None:
            self._boot.append(rec)
            n = len(self._boot)
            if n >= 2 and (n >= self._next_check or n >= self.bootstrap_max_records):
                # Checks at 5, 10, 15, 20, 25, 31, 38, ... records: the bootstrap costs O(n) batch records.
                self._next_check = max(n + self.bootstrap_check_every, int(np.ceil(1.25 * n)))
                self._bootstrap(force=False)
            return
        status = "accepted"
        d2 = float("nan")
        dof = 0
        if not rec.state_measured:
            if self._x is not None and (not rec.starts_segment or self._bridge_gap(rec)):
                self._predict(rec.t)
            else:
                self._x = None  # no state to propagate across the gap: wait for the next measurement
            status = "predicted"
        elif self._x is not None and rec.starts_segment and not self._bridge_gap(rec):
            self._initialise(rec)
            self.segments += 1
            status = "segment"
            self.samples_used += 1
        elif self._x is None:
            self._initialise(rec)
            status = "initialised"
            self.samples_used += 1
        else:
            phi_before, p_before = self._phi.copy(), self._p.copy()
            counts = (self.samples_used, self.samples_rejected, self.reinitialisations)
            try:
                with np.errstate(all="ignore"):
                    status, d2, dof = self._predict_and_update(rec)
                lost = not (np.all(np.isfinite(self._x)) and np.all(np.isfinite(self._phi))
                            and np.all(np.isfinite(self._p)))
            except (ZeroDivisionError, OverflowError, ValueError, np.linalg.LinAlgError):
                lost = True
            if lost:
                # The state estimate diverged numerically (e.g. an attitude pushed through zero norm on very noisy
                # data): restart the state from this measurement, keep θ and its covariance from before the
                # step, and count it as a reinitialisation (never hidden).
                self._phi, self._p = phi_before, p_before
                self._initialise(rec)
                self.samples_used, self.samples_rejected, self.reinitialisations = counts
                self.reinitialisations += 1
                self.samples_rejected += 1
                status = "reinitialised"
        self._t_last = rec.t
        self._u_last = np.array(rec.u_applied, dtype=float)
        self._gap_acc = None
        self._gap_gyro = None
        acc_lost = rec.linear_acceleration_mps2
        self._lost_acc = (None if rec.state_measured or acc_lost is None or not np.all(np.isfinite(acc_lost))
                          else (np.asarray(acc_lost, dtype=float), int(rec.acceleration_readings)))
        alpha, alpha_var = rec.angular_acceleration_radps2, rec.angular_acceleration_var_rad2ps4
        self._lost_gyro = (None if rec.state_measured or alpha is None or alpha_var is None
                           or not (np.all(np.isfinite(alpha)) and np.isfinite(alpha_var) and alpha_var > 0)
                           else (np.asarray(alpha, dtype=float), float(alpha_var),
                                 np.asarray(rec.x_measured[10:13], dtype=float)))
        state = self._x.copy() if self._x is not None else np.full(13, np.nan)
        self.history.append(SequentialStep(rec.t, status, d2, dof, self.estimate, state))
