"""Batch maximum-likelihood estimation of states and inertial parameters (Doerr et al. 2021, Eqs. 31-32).

Given records ``ỹ_k`` (measured state, applied input, optional accelerations) at times ``t_1 .. t_K``, the
estimator maximises Eq. 31, ``Π p(ỹ_k | x_k) Π p(x_k | x_{k-1}, u_{k-1}, θ)``, over every state and the parameters,
``ϑ = [x_1 .. x_K, θ]``. With Gaussian noise this is the nonlinear least-squares problem

    min_ϑ  Σ_k ‖ R^-½ (h(x_k) ⊟ ỹ_k) ‖²  +  Σ_k ‖ Q_k^-½ (x_{k+1} ⊟ f(x_k, u_k, θ)) ‖²  (+ ‖ P₀^-½ (θ − θ₀) ‖²)

solved by Gauss-Newton with Levenberg-Marquardt damping: each iteration linearises about ``ϑ̄`` and solves Eq. 32,
``min ‖b(ϑ̄) + A δϑ‖²``, then updates ``x̄ ⊞ δx`` (quaternion-aware, :mod:`oacli.estimation.manifold`) and θ.

Choices the paper leaves open, and what is done here:

* **Residuals on the manifold.** The attitude residuals are body-frame rotation vectors ``log(q̃⁻¹ ⊗ q)`` and
  ``log(f_q⁻¹ ⊗ q_{k+1})``; their Jacobians use the exact inverse SO(3) Jacobians, so the linearisation is exact to
  first order even far from the solution (checked against finite differences in the tests).
* **Process model.** ``f`` is the simulator's multi-rate RK4 integration with the input held over each control
  period (:mod:`oacli.estimation.propagation`), with its exact Jacobians ``A_k = ∂f/∂x``, ``C_k = ∂f/∂θ``.
* **Physical parameters.** θ is estimated through φ (:mod:`oacli.estimation.parametrization`), so every iterate has
  mass > 0 and inertias satisfying the triangle inequalities; the maximum-likelihood point is the same.
* **Sparsity.** Every residual touches one state, or two consecutive states, and φ, so ``AᵀA`` is block
  tridiagonal in the states (12×12 blocks) with a dense 4-column border in φ. It is accumulated directly in blocks
  (``A`` is never formed) and ``(AᵀA + λD) δϑ = −Aᵀb`` is solved by eliminating the states: a banded Cholesky
  factorisation of the state block and a 4×4 Schur complement on φ; the cost grows linearly with the telemetry.
  ``estimate_batch(..., reference=True)`` keeps the original path (``A`` assembled as a ``scipy.sparse`` matrix,
  ``AᵀA`` factorised by sparse LU, the general 13×17 RK4 Jacobians): the same iterations, to check against.
  Its covariance comes from the augmented system ``[[I, A], [Aᵀ, 0]]`` (sparse LU), not from ``AᵀA``: see below.
* **Covariance.** ``cov(θ̂) = [(AᵀA)⁻¹]_θθ`` at the solution (Doerr: "extracted from (AᵀA)⁻¹"), mapped from φ
  to θ through ``dθ/dφ``. It is computed from a block QR factorisation of ``A`` (a square-root information
  smoother, :meth:`_Problem.last_covariance_qr`), not from ``AᵀA``: with a nearly rigid process model
  ``cond(AᵀA)`` reaches 10¹³, so any solve of the normal equations is good to ~10⁻⁵ relative only (the
  original path's LU of ``AᵀA`` differed from a dense QR of ``A`` by 8.6e-6 on the 60 s ISS run), while the QR is
  good to ``cond(A)·ε`` (3.6e-10 there). The reference path therefore solves the augmented system
  ``[[I, A], [Aᵀ, 0]] [r; z] = [0; −e]`` (Björck 1996, §2.5.3) by sparse LU, which never forms ``AᵀA`` and is
  accurate to ``cond(A)·ε`` as well: the two covariances agree to 3.4e-10 on that run.
* **Outliers.** After convergence every record's normalised residual ``d²_k = ‖R^-½ (h(x̂_k) ⊟ ỹ_k)‖²`` is tested
  against the χ² gate ([ReSWARM2023] §6.2.1); records outside it are dropped and the problem is re-solved, until the
  inlier set no longer changes. The dynamics still tie the state of a dropped record to its neighbours.
* **Continuation.** With a nearly rigid model (small process noise) the process residuals have tiny standard
  deviations, and the second-order terms a large parameter step leaves in them (``u Δt/m`` is not linear in m)
  make full Gauss-Newton steps overshoot, so Levenberg-Marquardt would crawl. The problem is therefore solved
  first with the process noise inflated 1000×, 100× and 10× (each solution warm-starts the next, with a loose
  tolerance) and then with the configured noise; only the last stage's costs are in ``cost_history``. The
  continuation runs in the first gating round only: a later round starts at the previous round's solution, which
  dropping a few outliers moves by little, and converges in a few full steps from there (on the 60 s ISS run, with
  or without 5 % localisation jumps, it reaches the same θ̂ to 2e-12 relative as restarting the continuation every
  round, with 40 % fewer iterations).
* **Gauge.** State components that are not measured at all (e.g. position when only velocities are used) have
  unobservable offsets that do not affect θ; the first state's unmeasured components get a unit-weight tie to the
  first record so that ``AᵀA`` stays invertible.
* **Imperfect telemetry** (:mod:`oacli.estimation.alignment`). An input-only record (``state_measured=False``: the
  localisation message was lost) keeps its state variable and process residuals but has no measurement residual
  and is never an inlier. A record that ``starts_segment`` (the input over the interval before it is unknown) is
  never reached by holding an input over the gap (:func:`segment_link_weights`): the unknown wrench is predicted
  from its neighbours with the prediction's error (measured on the run, :func:`lost_input_prior`) as extra process
  noise over that interval; after the first solve the prediction is redone by regression on the neighbours' mean
  and their measurement residuals (:func:`noise_corrected_prediction`: the controller's reaction to measurement
  noise is most of the miss, and a prediction whose error correlates with it biased Ixx) and solved again, the
  directions weighted at that solve's θ̂. Where the records carry the accelerometer's mean over a lost period
  (:func:`oacli.estimation.imu.attach_accelerations`), the force is not predicted: the specific force *is*
  ``f/m``, so the translation across the gap takes the measured acceleration (:func:`lost_input_model`); where
  they carry the gyro's slope over it, the rotation takes the measured ``ω̇`` likewise ([Doerr2021] Eq. 35b). Without
  a prediction the force is profiled out (position continuity kept) and the rotational state after the gap is
  estimated afresh; a longer gap is cut (the segment's first state free, with its own gauge tie). Cutting every
  gap biases θ in closed loop (see :func:`segment_link_weights`).
* **Goodness of fit.** At the solution the cost ``‖b‖²`` of a correct model is χ²-distributed with
  ``m − n`` degrees of freedom (residuals minus unknowns); :attr:`BatchResult.chi2` and ``chi2_dof`` report both,
  so a fit far outside its expected range (a wrong input record, an unmodelled effect) is visible.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from oacli.estimation import parametrization as par
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.manifold import (
    TANGENT_DIM,
    boxminus,
    boxplus,
    lift_matrix,
    project_matrix,
    so3_left_jacobian_inverse,
    so3_right_jacobian_inverse,
    xi_stack,
)
from oacli.estimation.models import EstimatorSettings, Measurement, MeasurementModel, measured_rows
from oacli.estimation.preprocessing import order_by_time
from oacli.estimation.propagation import (
    TIME_TOL_S,
    dynamics_batch,
    dynamics_jacobians_batch,
    propagate_intervals,
    propagate_intervals_structured,
    propagate_state_one,
    substep_schedule,
)
from oacli.types import ParameterEstimate

__all__ = ["BRIDGE_FACTOR", "UNIDENTIFIED_VARIANCE", "BatchResult", "GyroBridge", "bridge_accelerations",
           "bridge_angular_accelerations", "covariance_at", "estimate_batch", "estimate_batch_windows",
           "gyro_bridge_offset", "lost_input_model"]

_ACCEL_ROWS = np.r_[3:6, 10:13]  # v̇ and ω̇ rows of the continuous dynamics
_LAMBDA_INIT = 1e-6
_LAMBDA_WARM = 1e-12
"""Initial damping of every Levenberg-Marquardt solve of :func:`estimate_batch` warm-started at the solution of fewer
records (a longer window of :func:`estimate_batch_windows`): Gauss-Newton steps are nearly exact there, and a
damping of 1e-6 · diag(AᵀA) slows the weakly determined directions of an ill-conditioned ``AᵀA`` (cond ~10¹³) by
one decade per iteration; LM raises it again after a rejected step. A cold start keeps :data:`_LAMBDA_INIT` in
every round: on flight-like telemetry (large residuals) undamped Gauss-Newton converges only linearly after the
gating round, and the cost tolerance then stops it up to 7e-7 (relative, 3e-5 standard deviations) short of the
minimum in θ on the default mission's first 10 s window (windows warm-started from a converged solution: 7e-8 on
the second, 7e-10 at the last)."""
_LAMBDA_MAX = 1e12
_CONTINUATION = (1000.0, 100.0, 10.0)
"""Process-noise inflation factors solved first, each warm-starting the next (see the module docstring)."""
_CONTINUATION_WARM = (10.0,)
"""The continuation of a warm-started solve (:func:`estimate_batch_windows`): the last stage only. Without it the
new records' open-loop states can lead the first gating round elsewhere (a window with localisation jumps and a
gap converged to a different inlier set than a cold solve); with the full continuation the warm start saves little
(16 instead of 21 iterations per window on the default mission, 10 with this one stage)."""
_CONTINUATION_TOLERANCE = 1e-6

UNIDENTIFIED_VARIANCE = 1e300
"""The variance reported for every parameter when ``AᵀA`` is singular at the solution (θ not identified by the
records that passed the gate): finite, so the estimate stays a valid Gaussian, but no σ (the estimate stage reports
none and ends ``degraded``)."""

BRIDGE_FACTOR = 1.5
"""A gap link is bridged (translational residual kept) when it spans at most this many typical record spacings."""
_MIN_PREDICTION_SAMPLES = 10
"""Triples of known inputs needed to measure the error of a lost input's prediction (else it is profiled out)."""


def gyro_bridge_offset(added_radps2: np.ndarray, rate_radps: np.ndarray, dt_s: np.ndarray | float) -> np.ndarray:
    """The attitude and angular-velocity change ``(..., 6)`` a lost torque adds over its interval, in the end
    state's body frame, from the gyro's measure of it (:func:`lost_input_model`; [Doerr2021] Eq. 35b).

    ``[½T² a − (T³/6) ω × a,  T a]`` with ``a = J⁻¹τ`` held over ``T``: the ``T³`` term is the body frame's turn at
    ``ω`` meanwhile (``∫ (I − (T − t)[ω]×) t a dt``). The batch (:func:`lost_input_model`) and the sequential filter
    both add it across a gyro-bridged gap.

    Parameters
    ----------
    added_radps2 : ndarray, shape (..., 3)
        ``J⁻¹τ`` [rad/s²], the angular acceleration the lost torque added.
    rate_radps : ndarray, shape (..., 3)
        The body rate at the interval's start [rad/s].
    dt_s : ndarray, shape (..., 1), or float
        Interval length(s) [s].

    Returns
    -------
    ndarray, shape (..., 6)
        Attitude [rad] then angular velocity [rad/s] offsets.
    """
    out = np.empty((*np.broadcast_shapes(np.shape(added_radps2), np.shape(rate_radps))[:-1], 6))
    out[..., 0:3] = 0.5 * dt_s**2 * added_radps2 - dt_s**3 / 6.0 * np.cross(rate_radps, added_radps2)
    out[..., 3:6] = dt_s * added_radps2
    return out


def unknown_torque_directions(dt_s: np.ndarray, inertia_kgm2: np.ndarray) -> np.ndarray:
    """Directions ``(K, 12, 3)`` along which a wrong body torque ``Δτ`` held over ``dt_s`` moves the end state, per
    unit of ``Δτ``, to first order and without the gyroscopic coupling: ``½T² J⁻¹ Δτ`` on the attitude and
    ``T J⁻¹ Δτ`` on the angular velocity (Doerr Eq. 35 linearised at rest). Used only to weight a predicted
    torque's error (:func:`segment_link_weights`), never to move the state.

    Parameters
    ----------
    dt_s : ndarray, shape (K,)
        Interval lengths [s].
    inertia_kgm2 : ndarray, shape (3,)
        Principal inertias [kg·m²] (the weighting point).

    Returns
    -------
    ndarray, shape (K, 12, 3)
    """
    dt = np.atleast_1d(np.asarray(dt_s, dtype=float))
    j_inv = np.diag(1.0 / np.asarray(inertia_kgm2, dtype=float))
    out = np.zeros((dt.size, TANGENT_DIM, 3))
    out[:, 6:9, :] = 0.5 * dt[:, None, None] ** 2 * j_inv
    out[:, 9:12, :] = dt[:, None, None] * j_inv
    return out


def unknown_force_directions(dt_s: np.ndarray) -> np.ndarray:
    """Directions ``D_k`` (K, 12, 3) of ``x_{k+1} ⊟ f(x_k, u_k, θ)`` along which a wrong force held over an interval
    of ``dt_s`` moves the end state, per unit of ``Δf / m``.

    The translational dynamics are linear with the force in the world frame (Doerr Eq. 34): a force error ``Δf``
    held over ``T`` moves ``r⁺`` by ``½T² Δf/m`` and ``v⁺`` by ``T Δf/m``, whatever the state, the attitude or the
    inertia, so the directions are exact and ``m`` only scales them.

    Parameters
    ----------
    dt_s : ndarray, shape (K,)
        Interval lengths [s].

    Returns
    -------
    ndarray, shape (K, 12, 3)
    """
    dt = np.atleast_1d(np.asarray(dt_s, dtype=float))
    out = np.zeros((dt.size, TANGENT_DIM, 3))
    eye = np.eye(3)
    out[:, 0:3, :] = 0.5 * dt[:, None, None] ** 2 * eye
    out[:, 3:6, :] = dt[:, None, None] * eye
    return out


def lost_input_prior(t: np.ndarray, u: np.ndarray, links: np.ndarray, min_samples: int | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A data-driven prior for the unknown input over each gap interval: the mean of its neighbours.

    A record whose outgoing interval has an unknown input (``links[k]`` False) lies between two known inputs when
    ``links[k-1]`` and ``links[k+1]`` hold (one lost control instant). Its input is then predicted as
    ``(u_{k-1} + u_{k+1}) / 2``; the prediction's error variance is measured on the same run, from every triple of
    consecutive known inputs on an even grid: ``mean((u_i − (u_{i-1} + u_{i+1}) / 2)²)`` per axis. Controller
    records lost at random are like the others, so this is the error the interpolation makes on average (the
    controller's feedback on the measurement noise included); it is a stated assumption, not a held input.

    Parameters
    ----------
    t : ndarray, shape (K,)
        Record times [s].
    u : ndarray, shape (K, 6)
        Inputs [N, N·m] (placeholders where unknown).
    links : ndarray of bool, shape (K - 1,)
        The input over interval k is known.
    min_samples : int, optional
        Fewer triples than this: no prediction (the force is profiled out); default ``_MIN_PREDICTION_SAMPLES``.

    Returns
    -------
    u_prior : ndarray, shape (K, 6)
        ``u`` with the predicted inputs in place of the placeholders that can be predicted.
    predicted : ndarray of bool, shape (K - 1,)
        Intervals whose unknown input has a prediction.
    variance : ndarray, shape (6,)
        Its error variance per axis [N², (N·m)²] (``inf`` without enough triples).
    """
    k = t.size
    min_samples = _MIN_PREDICTION_SAMPLES if min_samples is None else min_samples
    links = np.asarray(links, dtype=bool)
    u_prior = np.array(u, dtype=float)
    known = np.zeros(k, dtype=bool)
    known[:-1] = links
    dt = np.diff(t)
    mid = np.arange(1, k - 1)
    even = np.abs(dt[1:] - dt[:-1]) <= TIME_TOL_S + 1e-6 * np.abs(dt[1:]) if k > 2 else np.zeros(0, dtype=bool)
    triples = mid[known[mid - 1] & known[mid] & known[mid + 1] & even]
    variance = np.full(6, np.inf)
    if triples.size >= min_samples:
        d = u_prior[triples] - 0.5 * (u_prior[triples - 1] + u_prior[triples + 1])
        variance = np.mean(d * d, axis=0)
    predicted = np.zeros(max(k - 1, 0), dtype=bool)
    if np.all(np.isfinite(variance)):
        cand = mid[~known[mid] & known[mid - 1] & known[mid + 1] & even]
        predicted[cand] = True
        u_prior[cand] = 0.5 * (u_prior[cand - 1] + u_prior[cand + 1])
    return u_prior, predicted, variance


def noise_corrected_prediction(
    t: np.ndarray, u: np.ndarray, links: np.ndarray, noise: np.ndarray, min_samples: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lost input predicted by regression on its neighbours' mean and their measurement residuals.

    The controller acts on the measured state, so ``u_j = g_j − K n_j`` (``n_j`` the measurement noise, ``g_j`` a
    function of the true state and the reference). The neighbours' mean ``p_k = (u_{k−1} + u_{k+1}) / 2``
    (:func:`lost_input_prior`) misses ``u_k`` by ``−K (n_k − (n_{k−1} + n_{k+1}) / 2)`` plus the curvature of
    ``g``: on the benchmark's runs the measurement noise at k−1, k, k+1 explains over 98 % of the variance of
    that miss, two thirds of it from ``n_{k±1}``, which the data keep (the residuals ``ỹ ⊟ x̂`` of a first solve,
    ``noise``). The midpoint's error is also correlated with the midpoint itself (an axis the controller moves
    fast is under-predicted at its peaks: slope +0.25 on the ISS run's x torque; an axis dominated by the noise
    reaction is over-predicted), and the estimator, which uses the prediction as the input, reads that
    correlation as a change of θ (Ixx bias on the benchmark's ``gapped`` row: −0.62σ with the midpoint, −0.36σ
    with this regression, 20 seeds, standard error 0.22). So each
    axis is regressed, by least squares over every triple of known inputs with measured neighbours, on
    ``[1, p_k, (n_{k−1} + n_{k+1}) / 2]`` (the force on the position and velocity residuals, the torque on the
    attitude and angular-velocity ones; ``n_k`` is lost with the record: its part stays an error): the
    prediction's error is then orthogonal to what it is built from, and its variance over the same triples
    (degrees of freedom counted) is the prior's.

    Parameters
    ----------
    t : ndarray, shape (K,)
    u : ndarray, shape (K, 6)
        Inputs (placeholders where unknown).
    links : ndarray of bool, shape (K - 1,)
    noise : ndarray, shape (K, 12)
        Measurement residuals ``ỹ ⊟ x̂`` (NaN where a record has none).
    min_samples : int, optional
        Triples needed (default: 4 × the regressors, 32).

    Returns
    -------
    correction : ndarray, shape (K - 1, 6)
        To add to the neighbours' mean on each interval (0 where not ``ok``).
    variance : ndarray, shape (6,)
        The regression's error variance per axis [N², (N·m)²] (``inf`` without enough triples).
    ok : ndarray of bool, shape (K - 1,)
        Intervals with an unknown input between known ones whose neighbours have a residual (and enough triples).
    """
    t = np.asarray(t, dtype=float)
    k = t.size
    noise = np.asarray(noise, dtype=float)
    correction = np.zeros((max(k - 1, 0), 6))
    ok = np.zeros(max(k - 1, 0), dtype=bool)
    variance = np.full(6, np.inf)
    if k < 3:
        return correction, variance, ok
    known = np.zeros(k, dtype=bool)
    known[:-1] = np.asarray(links, dtype=bool)
    dt = np.diff(t)
    mid = np.arange(1, k - 1)
    even = np.abs(dt[1:] - dt[:-1]) <= TIME_TOL_S + 1e-6 * np.abs(dt[1:])
    seen = np.all(np.isfinite(noise), axis=1)
    sides = seen[mid - 1] & seen[mid + 1]
    triples = mid[known[mid - 1] & known[mid] & known[mid + 1] & even & sides]
    regressors = 8  # 1, p, six residual components
    min_samples = 4 * regressors if min_samples is None else min_samples
    if triples.size < max(min_samples, regressors + 1):
        return correction, variance, ok
    u = np.asarray(u, dtype=float)
    cand = mid[~known[mid] & known[mid - 1] & known[mid + 1] & even & sides]
    p_fit = 0.5 * (u[triples - 1] + u[triples + 1])
    p_new = 0.5 * (u[cand - 1] + u[cand + 1])
    side_fit = 0.5 * (noise[triples - 1] + noise[triples + 1])
    side_new = 0.5 * (noise[cand - 1] + noise[cand + 1])
    for axis in range(6):
        comps = slice(0, 6) if axis < 3 else slice(6, 12)  # force: r, v; torque: attitude, ω
        x_fit = np.column_stack([np.ones(triples.size), p_fit[:, axis], side_fit[:, comps]])
        coef, *_ = np.linalg.lstsq(x_fit, u[triples, axis], rcond=None)
        err = u[triples, axis] - x_fit @ coef
        variance[axis] = float(err @ err) / (triples.size - regressors)
        x_new = np.column_stack([np.ones(cand.size), p_new[:, axis], side_new[:, comps]])
        correction[cand, axis] = x_new @ coef - p_new[:, axis]
    ok[cand] = True
    return correction, variance, ok


def lost_input_model(
    t: np.ndarray, u: np.ndarray, links: np.ndarray, mass_kg: float, *,
    bridge_acceleration: np.ndarray | None = None, bridge_acceleration_variance: np.ndarray | None = None,
    noise: np.ndarray | None = None, gyro: GyroBridge | None = None, inertia_kgm2: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the estimator assumes over each interval with an unknown input (one model for :class:`_Problem` and
    :func:`oacli.estimation.bounds.cramer_rao_bound`).

    A bridged interval (one lost control instant between known inputs, :func:`lost_input_prior`, at most
    ``BRIDGE_FACTOR`` typical spacings) has an unknown constant wrench ``[f, τ]``, written as a nuisance
    ``w = [f/m, τ]`` with a Gaussian prior:

    * ``τ`` -- predicted from its neighbours, with their measured error variance;
    * ``f/m`` -- measured by the accelerometer when the record carries the mean of the readings over its interval
      (``bridge_acceleration``, variance ``σ_a² / n``; the specific force *is* ``f/m``, so the interval's
      translation needs neither the force nor the mass: its force is set to 0 in ``u`` and the measured
      ``f/m`` enters the residual as an offset ``D_f ā``, :func:`unknown_force_directions`); otherwise predicted
      from its neighbours like ``τ`` (variance ``σ_f² / m²``).
    * ``τ`` -- measured by the gyro instead when the record carries the slope of its readings over the interval
      (``gyro``, :func:`oacli.estimation.imu.attach_accelerations`): by [Doerr2021] Eq. 35b,
      ``ω̇ = J⁻¹ (τ − ω × J ω)``, and the torque is held, so the slope ``ᾱ`` is the interval's ``ω̇``, gyroscopic
      term included. The torque is set to 0 in ``u``, and the model then still applies the gyroscopic term
      ``−J⁻¹ (ω × J ω)``, so what the lost torque added is ``J⁻¹ τ = ᾱ + J⁻¹ (ω × J ω)`` (``ω`` the gyro's rate,
      ``J`` at ``inertia_kgm2``, the weighting point; its error there moves the offset by ``T ω² ΔJ/J``, µrad/s).
      It enters the residual as an offset ``[½T², T] J⁻¹ τ`` on the attitude and the angular velocity (the
      directions of :func:`unknown_torque_directions`; the attitude's also ``− (T³/6) ω × J⁻¹τ``, the turn of the
      body frame meanwhile, ~1e-5 rad on the ISS runs: left out, it was 100 times the process noise's tolerance in
      the direction the lost torque cannot move), the prior variance of ``τ`` is ``J² σ_ᾱ²``: the interval's
      rotation needs neither the torque nor ``J``, as the translation needs neither ``f`` nor ``m``.

    Parameters
    ----------
    t : ndarray, shape (K,)
    u : ndarray, shape (K, 6)
        Inputs (placeholders where unknown).
    links : ndarray of bool, shape (K - 1,)
        The input over interval k is known.
    mass_kg : float
        Mass at which a predicted force's variance is expressed as ``f/m``.
    bridge_acceleration : ndarray, shape (K, 3), optional
        Mean measured ``f/m`` (world frame) over each record's outgoing interval (NaN where none).
    bridge_acceleration_variance : ndarray, shape (K,), optional
        Its variance per axis [m²/s⁴].
    noise : ndarray, shape (K, 12), optional
        Measurement residuals ``ỹ_k ⊟ x̂_k`` of a first solve (NaN where a record has none): the prediction is
        corrected for the controller's reaction to the neighbours' measurement noise
        (:func:`noise_corrected_prediction`).
    gyro : GyroBridge, optional
        The gyro's ``ω̇`` over each record's outgoing interval (:func:`bridge_angular_accelerations`); used with
        ``inertia_kgm2``.
    inertia_kgm2 : ndarray, shape (3,), optional
        Principal inertias where the gyro-bridged torque's variance and gyroscopic term are evaluated (the
        weighting point of :func:`segment_link_weights`).

    Returns
    -------
    u_model : ndarray, shape (K, 6)
        Inputs with the predictions in place (force 0 where the accelerometer bridges, torque 0 where the gyro
        does).
    bridged : ndarray of bool, shape (K - 1,)
        Intervals with an unknown input linked through the nuisance ``w``.
    variance : ndarray, shape (K - 1, 6)
        Prior variance of ``w = [f/m, τ]`` on the bridged intervals (NaN elsewhere).
    offset : ndarray, shape (K - 1, 12)
        ``D_f ā`` on the accelerometer-bridged intervals, ``[½T², T] J⁻¹ τ`` on the gyro-bridged ones (0
        elsewhere): subtracted from the process residual.
    """
    t = np.asarray(t, dtype=float)
    k = t.size
    links = np.asarray(links, dtype=bool)
    u_model, predicted, input_var = lost_input_prior(t, u, links)
    dt = np.diff(t)
    bridged = np.zeros(max(k - 1, 0), dtype=bool)
    variance = np.full((max(k - 1, 0), 6), np.nan)
    offset = np.zeros((max(k - 1, 0), TANGENT_DIM))
    if k < 2 or np.all(links):
        return u_model, bridged, variance, offset
    typical = float(np.median(dt[links])) if np.any(links) else float(np.median(dt))
    bridged = ~links & predicted & (dt <= BRIDGE_FACTOR * typical + TIME_TOL_S)
    variance[bridged, 0:3] = input_var[0:3] / mass_kg**2
    variance[bridged, 3:6] = input_var[3:6]
    if noise is not None:
        correction, corrected_var, ok = noise_corrected_prediction(t, u_model, links, noise)
        fix = bridged & ok
        u_model[:-1][fix] += correction[fix]
        variance[fix, 0:3] = corrected_var[0:3] / mass_kg**2
        variance[fix, 3:6] = corrected_var[3:6]
    if bridge_acceleration is not None and bridge_acceleration_variance is not None:
        acc = np.asarray(bridge_acceleration, dtype=float)[:-1]
        acc_var = np.asarray(bridge_acceleration_variance, dtype=float)[:-1]
        imu = bridged & np.all(np.isfinite(acc), axis=1) & np.isfinite(acc_var) & (acc_var > 0)
        variance[imu, 0:3] = acc_var[imu, None]
        u_model[:-1][imu, 0:3] = 0.0
        offset[imu] = np.einsum("kij,kj->ki", unknown_force_directions(dt[imu]), acc[imu])
    if gyro is not None and inertia_kgm2 is not None:
        inertia = np.asarray(inertia_kgm2, dtype=float)
        alpha, alpha_var, rate = gyro.angular_acceleration[:-1], gyro.variance[:-1], gyro.rate[:-1]
        turn = (bridged & np.all(np.isfinite(alpha), axis=1) & np.isfinite(alpha_var) & (alpha_var > 0)
                & np.all(np.isfinite(rate), axis=1))
        variance[turn, 3:6] = alpha_var[turn, None] * inertia**2
        u_model[:-1][turn, 3:6] = 0.0
        added = alpha[turn] + np.cross(rate[turn], rate[turn] * inertia) / inertia  # J⁻¹τ
        offset[turn, 6:12] = gyro_bridge_offset(added, rate[turn], dt[turn, None])
    return u_model, bridged, variance, offset


def segment_link_weights(
    w_proc: np.ndarray, q_proc: np.ndarray, dt_s: np.ndarray, links: np.ndarray, predicted: np.ndarray,
    input_variance: np.ndarray, theta: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Process-residual whitening across the gaps of the input record (``links[k]`` False: the input over
    ``[t_k, t_{k+1})`` is unknown, :mod:`oacli.estimation.alignment`).

    The input over such an interval is a constant (the controller's zero-order hold) but unknown wrench.

    * Where :func:`lost_input_prior` predicts it (``predicted``), the process residual is computed with the
      prediction and whitened with ``Q_k + D Σ_u Dᵀ``: the prediction's error is process noise over that interval
      (a random effect), ``D`` its force (:func:`unknown_force_directions`, exact, ``/m``) and torque
      (:func:`unknown_torque_directions`, first order) directions. All twelve residuals remain.
    * Elsewhere the force is *profiled out*: the whitened translational residual is projected onto the orthogonal
      complement of ``W_t D`` (the cost minimised over the force in closed form; exact, the directions depend on
      neither the state nor θ), which leaves position continuity (three residuals); the rotational residuals are
      dropped (the attitude and angular velocity after the gap are estimated afresh).
    * A gap longer than ``BRIDGE_FACTOR`` typical record spacings (several unknown inputs) is cut.

    Cutting every gap link (each segment's initial state free) is consistent but, in closed loop, biased: the
    controller's input depends on the noisy measurement that also fixes the segment's initial state, and a short
    segment's free initial state absorbs part of that noise -- least squares with fixed effects and predetermined
    regressors (Nickell 1981), a bias of order 1/segment length per segment that does not average out over
    segments (``benchmarks/bench_estimation.py``, row ``clean split``; open loop it is absent).

    Parameters
    ----------
    w_proc, q_proc : ndarray, shape (K, 12, 12)
        Whitening matrices ``Q_k^-½`` and covariances ``Q_k`` of every interval.
    dt_s : ndarray, shape (K,)
        Interval lengths [s].
    links : ndarray of bool, shape (K,)
        The input over interval k is known.
    predicted : ndarray of bool, shape (K,)
        The unknown input over interval k has a prediction (:func:`lost_input_prior`).
    input_variance : ndarray, shape (6,) or (K, 6)
        The prediction's error variance per axis [N², (N·m)²], for every interval or per interval (an
        accelerometer-bridged interval: its measured ``f/m``'s variance times ``m²``, :func:`lost_input_model`).
    theta : ndarray, shape (4,)
        θ at which the directions are evaluated (the weighting point, like ``Q_k``).

    Returns
    -------
    weights : ndarray, shape (K, 12, 12)
        ``w_proc`` on the linked intervals, the bridged weights on the gaps, zeros on the cut ones.
    rows : ndarray of int, shape (K,)
        Residual rows that carry information per interval (12 linked or predicted, 3 profiled, 0 cut).
    """
    links = np.asarray(links, dtype=bool)
    dt = np.asarray(dt_s, dtype=float)
    theta = np.asarray(theta, dtype=float)
    out = w_proc * links[:, None, None]
    rows = np.where(links, TANGENT_DIM, 0)
    gaps = np.flatnonzero(~links)
    if gaps.size == 0:
        return out, rows
    typical = float(np.median(dt[links])) if np.any(links) else float(np.median(dt))
    gaps = gaps[dt[gaps] <= BRIDGE_FACTOR * typical + TIME_TOL_S]
    with_prior = gaps[np.asarray(predicted, dtype=bool)[gaps]]
    profiled = np.setdiff1d(gaps, with_prior)
    if with_prior.size:
        d = np.concatenate([unknown_force_directions(dt[with_prior]),
                            unknown_torque_directions(dt[with_prior], theta[1:4])], axis=2)
        var = np.broadcast_to(np.asarray(input_variance, dtype=float), (dt.size, 6))[with_prior].copy()
        var[:, 0:3] /= theta[0] ** 2  # the force's error as f/m
        cov = q_proc[with_prior] + d @ (var[:, :, None] * d.transpose(0, 2, 1))
        out[with_prior] = np.linalg.inv(np.linalg.cholesky(cov))
        rows[with_prior] = TANGENT_DIM
    if profiled.size:
        wt = w_proc[profiled, 0:6, 0:6]
        q, _ = np.linalg.qr(wt @ unknown_force_directions(dt[profiled])[:, 0:6, :])  # whitened force directions
        out[profiled, 0:6, 0:6] = (np.eye(6) - q @ q.transpose(0, 2, 1)) @ wt
        rows[profiled] = 3
    return out, rows

Propagated = tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray | None, np.ndarray | None]]
"""A cached process-model propagation: (states, φ, (x_next, a, c))."""


@dataclass(frozen=True)
class BatchResult:
    """Outcome of :func:`estimate_batch`.

    Attributes
    ----------
    estimate : ParameterEstimate
        θ̂ and ``[(AᵀA)⁻¹]_θθ``; ``samples_used`` = inlier records, ``samples_rejected`` = gated records plus
        duplicated time stamps.
    t : ndarray, shape (K,)
        Record times [s] in time order (duplicates removed).
    states : ndarray, shape (K, 13)
        Estimated states ``x̂_k``.
    inliers : ndarray of bool, shape (K,)
        Records used in the final solve.
    d2 : ndarray, shape (K,)
        Normalised residual squared of every record against the final fit.
    gate_threshold : float
        χ² threshold used (``inf`` without gating); ``dof`` degrees of freedom per record.
    dof : int
    iterations : int
        Gauss-Newton iterations over all gating rounds.
    gating_rounds : int
    cost_history : tuple of float
        Cost ``‖b‖²`` after every accepted iteration (first entry: the initial guess), across rounds.
    converged : bool
        The last round met the tolerance within ``max_iterations``.
    duplicates : int
        Records dropped for a repeated time stamp.
    solve_time_s : float
        Wall time [s].
    phi : ndarray, shape (4,)
        The solution in the physical parametrisation (:mod:`oacli.estimation.parametrization`).
    last_covariance : ndarray, shape (16, 16)
        Covariance of ``[δx_K (12, tangent of the last state), δφ (4)]`` -- what a filter continuing from here
        needs (:class:`oacli.estimation.sequential.SequentialEstimator` bootstraps from it).
    chi2 : float
        Final cost ``‖b‖²`` (whitened residuals squared, configured process noise).
    chi2_dof : int
        Its expected value for a correct model: residuals minus unknowns (``m − n``).
    gate_emptied : bool
        No record passed the χ² gate in some round (the previous inlier set was kept).
    segments : int
        Records linked by the process model form this many segments (1 without gaps).
    """

    estimate: ParameterEstimate
    t: np.ndarray
    states: np.ndarray
    inliers: np.ndarray
    d2: np.ndarray
    gate_threshold: float
    dof: int
    iterations: int
    gating_rounds: int
    cost_history: tuple[float, ...]
    converged: bool
    duplicates: int
    solve_time_s: float
    phi: np.ndarray
    last_covariance: np.ndarray
    chi2: float = float("nan")
    chi2_dof: int = 0
    gate_emptied: bool = False
    segments: int = 1


def _block_coo(blocks: np.ndarray, row0: np.ndarray, col0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COO triplets of a stack of dense blocks (n, r, c) placed at row/column offsets (n,)."""
    n, r, c = blocks.shape
    rows = np.broadcast_to(row0[:, None, None] + np.arange(r)[None, :, None], (n, r, c))
    cols = np.broadcast_to(col0[:, None, None] + np.arange(c)[None, None, :], (n, r, c))
    return rows.ravel(), cols.ravel(), blocks.ravel()


@dataclass
class _Group:
    """Residual rows of one kind, one block per record: ``res (n, r)``; ``state (n, r, 12)`` on the states
    ``index (n,)``; ``next_state`` on ``index + 1`` (process rows); ``phi (n, r, 4)`` on φ (None: no such column)."""

    res: np.ndarray
    index: np.ndarray
    state: np.ndarray | None
    next_state: np.ndarray | None = None
    phi: np.ndarray | None = None


@dataclass
class _Normal:
    """``AᵀA`` and ``Aᵀb`` of the batch problem in blocks: block tridiagonal in the K states, dense border in φ.

    ``hd[k]`` = the k-th 12×12 diagonal block, ``ho[k]`` = the block coupling states k and k+1, ``hxp[k]`` = state
    k against φ (12×4), ``hpp`` = φ against φ; ``gx``, ``gp`` the matching parts of ``Aᵀb``. Damped systems
    ``(AᵀA + λ diag(d)) δ = −Aᵀb`` are solved by eliminating the states first (a Schur complement on φ): one
    banded Cholesky factorisation of the state block (bandwidth 23) and a 4×4 solve, so the cost is linear in K.
    """

    hd: np.ndarray
    ho: np.ndarray
    hxp: np.ndarray
    hpp: np.ndarray
    gx: np.ndarray
    gp: np.ndarray

    def diagonal(self) -> np.ndarray:
        """Diagonal of ``AᵀA`` in the variable order ``[δx_1 .. δx_K, δφ]``."""
        return np.concatenate([np.einsum("kii->ki", self.hd).ravel(), np.diag(self.hpp)])

    def _factor(self, damping: np.ndarray | None) -> np.ndarray | None:
        """Banded Cholesky factor (lower form) of the state block, plus ``damping`` on its diagonal."""
        k, nt = self.hd.shape[0], TANGENT_DIM
        n = k * nt
        ab = np.zeros((2 * nt, n))
        rr, cc = _TRIL
        cols0 = nt * np.arange(k)[:, None]
        ab[(rr - cc)[None, :], cols0 + cc[None, :]] = self.hd[:, rr, cc]
        if k > 1:
            r2, c2 = _FULL
            ab[(nt + r2 - c2)[None, :], cols0[:-1] + c2[None, :]] = self.ho[:, c2, r2]
        if damping is not None:
            ab[0] += damping
        try:
            return sla.cholesky_banded(ab, lower=True, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None

    def solve(self, damping: np.ndarray) -> np.ndarray | None:
        """``δ = −(AᵀA + diag(damping))⁻¹ Aᵀb``, or None when the damped system is not positive definite."""
        n = self.gx.size
        chol = self._factor(damping[:n])
        if chol is None:
            return None
        border = self.hxp.reshape(n, par.N_PARAMS)
        sol = sla.cho_solve_banded((chol, True), np.column_stack([self.gx.ravel(), border]), check_finite=False)
        schur = self.hpp + np.diag(damping[n:]) - border.T @ sol[:, 1:]
        try:
            dphi = np.linalg.solve(schur, -self.gp + border.T @ sol[:, 0])
        except np.linalg.LinAlgError:
            return None
        out = np.concatenate([-sol[:, 0] - sol[:, 1:] @ dphi, dphi])
        return out if np.all(np.isfinite(out)) else None


_TRIL = np.tril_indices(TANGENT_DIM)
_FULL = tuple(np.indices((TANGENT_DIM, TANGENT_DIM)).reshape(2, -1))


def _process_jacobians(
    w_proc: np.ndarray, e: np.ndarray, fx: np.ndarray, a: np.ndarray, c: np.ndarray, x_prev: np.ndarray,
    dtheta: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened Jacobians of the process residuals ``W_k (x_{k+1} ⊟ f(x_k, u_k, θ))`` with respect to ``δx_k``,
    ``δx_{k+1}`` and ``δφ`` (each (K, 12, ·)), from the propagation's ``a = ∂f/∂x`` and ``c = ∂f/∂θ``.

    ``−W Π(f) A Λ(x_k)`` with ``Π = diag(I₆, J_l⁻¹(e_att) 2Ξ(f_q)ᵀ, I₃)`` (:func:`~oacli.estimation.manifold.
    project_matrix` with the residual's inverse left Jacobian) and ``Λ = diag(I₆, ½Ξ(q_k), I₃)``
    (:func:`~oacli.estimation.manifold.lift_matrix`), in blocks: ``A`` of the structured propagation has a
    translational 6×6 block and a rotational 7×7 block only, so the product is formed on those (the same entries as
    the dense 12×13 · 13×13 · 13×12 product, without its zero blocks); ``W J_r⁻¹`` on the attitude columns for
    ``δx_{k+1}``.
    """
    n, nt = e.shape[0], TANGENT_DIM
    jr_inv = so3_right_jacobian_inverse(e[:, 6:9])
    jl_inv = so3_left_jacobian_inverse(e[:, 6:9])
    proj_rot = np.zeros((n, 6, 7))  # rows [δφ_att, δω] of Π on the columns [q, ω]
    proj_rot[:, 0:3, 0:4] = jl_inv @ (2.0 * np.swapaxes(xi_stack(fx[:, 6:10]), -1, -2))
    proj_rot[:, 3:6, 4:7] = np.eye(3)
    lift_rot = np.zeros((n, 7, 6))  # rows [q, ω] of Λ on the columns [δφ_att, δω]
    lift_rot[:, 0:4, 0:3] = 0.5 * xi_stack(x_prev[:, 6:10])
    lift_rot[:, 4:7, 3:6] = np.eye(3)
    core = np.zeros((n, nt, nt))
    core[:, 0:6, 0:6] = a[:, 0:6, 0:6]
    core[:, 6:12, 6:12] = proj_rot @ (a[:, 6:13, 6:13] @ lift_rot)
    cphi = c @ dtheta
    core_phi = np.empty((n, nt, dtheta.shape[1]))
    core_phi[:, 0:6] = cphi[:, 0:6]
    core_phi[:, 6:12] = proj_rot @ cphi[:, 6:13]
    j_prev = w_proc @ core
    np.negative(j_prev, out=j_prev)
    j_next = w_proc.copy()
    j_next[:, :, 6:9] = w_proc[:, :, 6:9] @ jr_inv
    j_phi = w_proc @ core_phi
    np.negative(j_phi, out=j_phi)
    return j_prev, j_next, j_phi


def bridge_accelerations(records: Sequence[Measurement], model: MeasurementModel
                          ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The accelerometer's mean ``f/m`` over each input-only record's interval and its variance ``σ_a² / n``
    (:func:`oacli.estimation.imu.attach_accelerations`; None when the model has no accelerometer noise or no
    input-only record carries a reading).

    Parameters
    ----------
    records : sequence of Measurement
        In time order.
    model : MeasurementModel

    Returns
    -------
    acceleration : ndarray, shape (K, 3), or None
        World-frame ``f/m`` [m/s²], NaN where none.
    variance : ndarray, shape (K,), or None
        Per axis [m²/s⁴].
    """
    std = model.linear_acceleration_std_mps2
    if std is None:
        return None, None
    acc = np.full((len(records), 3), np.nan)
    var = np.full(len(records), np.nan)
    for i, r in enumerate(records):
        if not r.state_measured and r.linear_acceleration_mps2 is not None:
            acc[i] = r.linear_acceleration_mps2
            var[i] = float(std) ** 2 / max(int(r.acceleration_readings), 1)
    return (acc, var) if np.any(np.isfinite(var)) else (None, None)


@dataclass(frozen=True)
class GyroBridge:
    """The gyro's measurements over the lost intervals (:func:`bridge_angular_accelerations`).

    Attributes
    ----------
    angular_acceleration : ndarray, shape (K, 3)
        Mean ``ω̇`` over each record's outgoing interval, body frame [rad/s²] (NaN where none).
    variance : ndarray, shape (K,)
        Its variance per axis [rad²/s⁴].
    rate : ndarray, shape (K, 3)
        The gyro's rate at the record's stamp [rad/s] (for the gyroscopic term).
    """

    angular_acceleration: np.ndarray
    variance: np.ndarray
    rate: np.ndarray


def bridge_angular_accelerations(records: Sequence[Measurement]) -> GyroBridge | None:
    """The gyro's mean ``ω̇`` over each input-only record's interval, its variance and rate
    (:func:`oacli.estimation.imu.attach_accelerations`; None when no record carries one).

    Parameters
    ----------
    records : sequence of Measurement
        In time order.

    Returns
    -------
    GyroBridge or None
    """
    k = len(records)
    alpha = np.full((k, 3), np.nan)
    var = np.full(k, np.nan)
    rate = np.full((k, 3), np.nan)
    for i, r in enumerate(records):
        v = r.angular_acceleration_var_rad2ps4
        if not r.state_measured and r.angular_acceleration_radps2 is not None and v is not None:
            alpha[i] = r.angular_acceleration_radps2
            var[i] = float(v)
            rate[i] = r.x_measured[10:13]
    return GyroBridge(alpha, var, rate) if np.any(np.isfinite(var)) else None


class _Problem:
    """Residuals ``b(ϑ)`` and the sparse Jacobian ``A`` of the batch problem for fixed data."""

    def __init__(
        self, records: Sequence[Measurement], settings: EstimatorSettings, prior: ParameterEstimate | None,
        weights_theta: np.ndarray,
    ) -> None:
        self.t = np.array([r.t for r in records])
        self.y = np.array([r.x_measured for r in records])
        self.u = np.array([r.u_applied for r in records])
        self.acc = np.array([r.accelerations() for r in records])
        self.k = len(records)
        self.n_var = TANGENT_DIM * self.k + par.N_PARAMS
        self.has_state = np.array([r.state_measured for r in records], dtype=bool)
        starts = np.array([r.starts_segment for r in records], dtype=bool)
        starts[0] = True
        self.segment_starts = np.flatnonzero(starts)
        self.links = ~starts[1:]  # process residual k -> k+1 present
        model = settings.measurement
        self.state_rows, accel_rows = measured_rows(model)
        # Acceleration rows are used only where every record with a measurement carries them.
        measured_acc = self.acc[self.has_state]
        self.accel_rows = np.array([i for i in accel_rows if np.all(np.isfinite(measured_acc[:, i]))], dtype=int)
        self.w_state = np.sqrt(model.state_weights[self.state_rows])
        self.w_accel = np.sqrt(model.acceleration_weights[self.accel_rows])
        self.dof = len(self.state_rows) + len(self.accel_rows)
        self.gauge_rows = np.setdiff1d(np.arange(TANGENT_DIM), self.state_rows)
        self.durations = substep_schedule(self.t[:-1], self.t[1:], settings.substep_s)
        self._w_proc_nominal = settings.process.sqrt_information(np.diff(self.t), weights_theta)
        self.link_rows = TANGENT_DIM * self.links.astype(int)  # informative process residuals per interval
        self.gap_offset = np.zeros((max(self.k - 1, 0), TANGENT_DIM))
        self.has_gaps = self.k > 1 and not np.all(self.links)
        self._u_records = self.u.copy()
        self._w_proc_linked = self._w_proc_nominal
        self._q_proc = settings.process.covariance(np.diff(self.t), weights_theta) if self.has_gaps else None
        self._weights_theta = np.asarray(weights_theta, dtype=float)
        self._bridge = bridge_accelerations(records, model) if self.has_gaps else (None, None)
        self._gyro = bridge_angular_accelerations(records) if self.has_gaps else None
        self.w_proc = self._w_proc_nominal
        self.set_lost_inputs()
        self._propagation_cache: Propagated | None = None
        self.prior = prior
        if prior is not None:
            self.prior_sqrt_info = np.linalg.inv(np.linalg.cholesky(prior.covariance))

    def set_lost_inputs(self, noise: np.ndarray | None = None, theta: np.ndarray | None = None) -> None:
        """The model across the gaps of the input record: the unknown wrench predicted from its neighbours (the
        force measured by the accelerometer when the records carry it), or its force profiled out and the rotation
        cut (:func:`lost_input_model`, :func:`segment_link_weights`). ``noise`` (the measurement residuals of a
        first solve) corrects the prediction for the controller's reaction to the neighbours' measurement noise;
        ``theta`` (that solve's θ̂) replaces the prior as the point where the lost wrench's directions and the
        force's ``1/m`` are evaluated (a prior 30 % off in inertia mis-weights the torque's error by as much)."""
        if not self.has_gaps or self._q_proc is None:
            return
        weights_theta = self._weights_theta if theta is None else np.asarray(theta, dtype=float)
        m_w = float(weights_theta[0])
        acc, var = self._bridge
        self.u, bridged, variance, self.gap_offset = lost_input_model(
            self.t, self._u_records, self.links, m_w, bridge_acceleration=acc, bridge_acceleration_variance=var,
            noise=noise, gyro=self._gyro, inertia_kgm2=weights_theta[1:4])
        self._w_proc_nominal, self.link_rows = segment_link_weights(
            self._w_proc_linked, self._q_proc, np.diff(self.t), self.links, bridged,
            variance * np.r_[m_w**2, m_w**2, m_w**2, 1.0, 1.0, 1.0], weights_theta)
        self.w_proc = self._w_proc_nominal
        self._propagation_cache = None

    def measurement_noise(self, x: np.ndarray, inliers: np.ndarray) -> np.ndarray:
        """``ỹ_k ⊟ x_k`` (K, 12) on the inlier records, NaN elsewhere (the residuals of a solve)."""
        out = np.full((self.k, TANGENT_DIM), np.nan)
        out[inliers] = boxminus(self.y[inliers], x[inliers])
        return out

    def set_process_noise_scale(self, factor: float) -> None:
        """Use ``factor`` × the configured process noise standard deviations (continuation, see the module)."""
        self.w_proc = self._w_proc_nominal / float(factor)

    # -- residuals and Jacobian ------------------------------------------------------------------------------------

    def evaluate(
        self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, jacobian: bool
    ) -> tuple[np.ndarray, sp.csc_matrix | None]:
        """``b(ϑ)`` and, if asked, ``A = ∂b/∂δϑ`` (right perturbations of the states, φ additive)."""
        k = self.k
        theta = par.theta_from_phi(phi)
        dtheta = par.theta_jacobian(phi)
        parts: list[np.ndarray] = []
        triplets: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        row = 0
        phi_col = TANGENT_DIM * k

        # Measurement residuals h(x_k) ⊟ ỹ_k on the inlier records.
        idx = np.flatnonzero(inliers)
        if idx.size and self.state_rows.size:
            e = boxminus(x[idx], self.y[idx])
            res = (e[:, self.state_rows] * self.w_state).ravel()
            parts.append(res)
            if jacobian:
                blocks = np.zeros((idx.size, TANGENT_DIM, TANGENT_DIM))
                blocks[:, 0:6, 0:6] = np.eye(6)
                blocks[:, 6:9, 6:9] = so3_right_jacobian_inverse(e[:, 6:9])
                blocks[:, 9:12, 9:12] = np.eye(3)
                blocks = blocks[:, self.state_rows, :] * self.w_state[None, :, None]
                n_r = len(self.state_rows)
                triplets.append(_block_coo(blocks, row + n_r * np.arange(idx.size), TANGENT_DIM * idx))
            row += res.size

        # Acceleration residuals (rows of the continuous dynamics at x_k, u_k).
        if idx.size and self.accel_rows.size:
            f = dynamics_batch(x[idx], self.u[idx], theta)[:, _ACCEL_ROWS]
            res = ((f - self.acc[idx])[:, self.accel_rows] * self.w_accel).ravel()
            parts.append(res)
            if jacobian:
                jac = dynamics_jacobians_batch(x[idx], self.u[idx], theta)[:, _ACCEL_ROWS][:, self.accel_rows]
                jx = jac[:, :, 0:13] @ lift_matrix(x[idx]) * self.w_accel[None, :, None]
                jp = jac[:, :, 13:] @ dtheta * self.w_accel[None, :, None]
                n_a = len(self.accel_rows)
                r0 = row + n_a * np.arange(idx.size)
                triplets.append(_block_coo(jx, r0, TANGENT_DIM * idx))
                triplets.append(_block_coo(jp, r0, np.full(idx.size, phi_col)))
            row += res.size

        # Process residuals x_{k+1} ⊟ f(x_k, u_k, θ), whitened by Q_k^-½.
        if k > 1:
            fx, a, c = propagate_intervals(x[:-1], self.u[:-1], theta, self.durations)
            e_raw = boxminus(x[1:], fx)  # the Jacobians are those of ⊟, at its value (the gap offset is constant)
            e = e_raw - self.gap_offset
            res = np.einsum("kij,kj->ki", self.w_proc, e).ravel()
            parts.append(res)
            if jacobian:
                next_blk = np.zeros((k - 1, TANGENT_DIM, TANGENT_DIM))
                next_blk[:, 0:6, 0:6] = np.eye(6)
                next_blk[:, 6:9, 6:9] = so3_right_jacobian_inverse(e_raw[:, 6:9])
                next_blk[:, 9:12, 9:12] = np.eye(3)
                pred_blk = next_blk.copy()
                pred_blk[:, 6:9, 6:9] = so3_left_jacobian_inverse(e_raw[:, 6:9])
                proj = pred_blk @ project_matrix(fx)  # (K-1, 12, 13)
                j_prev = -(self.w_proc @ proj @ a @ lift_matrix(x[:-1]))
                j_next = self.w_proc @ next_blk
                j_phi = -(self.w_proc @ proj @ c @ dtheta)
                r0 = row + TANGENT_DIM * np.arange(k - 1)
                triplets.append(_block_coo(j_prev, r0, TANGENT_DIM * np.arange(k - 1)))
                triplets.append(_block_coo(j_next, r0, TANGENT_DIM * np.arange(1, k)))
                triplets.append(_block_coo(j_phi, r0, np.full(k - 1, phi_col)))
            row += res.size

        # Gauge: tie the unmeasured components of each segment's first state to its record (unit weight).
        for first in self.segment_starts if self.gauge_rows.size else ():
            e = boxminus(x[first], self.y[first])
            parts.append(e[self.gauge_rows])
            if jacobian:
                blk = np.eye(TANGENT_DIM)
                blk[6:9, 6:9] = so3_right_jacobian_inverse(e[6:9])
                triplets.append(_block_coo(blk[self.gauge_rows][None], np.array([row]),
                                           np.array([TANGENT_DIM * first])))
            row += self.gauge_rows.size

        # Gaussian prior on θ (in θ, not in φ).
        if self.prior is not None:
            parts.append(self.prior_sqrt_info @ (theta - self.prior.theta))
            if jacobian:
                blk = (self.prior_sqrt_info @ dtheta)[None]
                triplets.append(_block_coo(blk, np.array([row]), np.array([phi_col])))
            row += par.N_PARAMS

        b = np.concatenate(parts) if parts else np.zeros(0)
        if not jacobian:
            return b, None
        rows, cols, vals = (np.concatenate(z) for z in zip(*triplets, strict=True))
        a_mat = sp.csc_matrix((vals, (rows, cols)), shape=(row, self.n_var))
        return b, a_mat

    def _propagate(self, x: np.ndarray, phi: np.ndarray, theta: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Process model over every interval; the last result is reused while (x, φ) are unchanged (the next
        continuation stage and the covariance start where the previous solve stopped)."""
        cached = self._propagation_cache
        if cached is not None and np.array_equal(cached[0], x) and np.array_equal(cached[1], phi):
            return cached[2]
        out = propagate_intervals_structured(x[:-1], self.u[:-1], theta, self.durations)
        self._propagation_cache = (x.copy(), phi.copy(), out)
        return out

    def jacobian_groups(
        self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, *, jacobian: bool = True
    ) -> tuple[np.ndarray, list[_Group]]:
        """``b(ϑ)`` and its Jacobian as groups of per-record blocks (same residuals and Jacobians as
        :meth:`evaluate`, in the same row order); the process model is
        :func:`oacli.estimation.propagation.propagate_intervals_structured`."""
        k = self.k
        theta = par.theta_from_phi(phi)
        dtheta = par.theta_jacobian(phi)
        nt = TANGENT_DIM
        parts: list[np.ndarray] = []
        groups: list[_Group] = []

        idx = np.flatnonzero(inliers)
        if idx.size and self.state_rows.size:
            e = boxminus(x[idx], self.y[idx])
            res = e[:, self.state_rows] * self.w_state
            parts.append(res.ravel())
            if jacobian:
                blocks = np.zeros((idx.size, nt, nt))
                blocks[:, 0:6, 0:6] = np.eye(6)
                blocks[:, 6:9, 6:9] = so3_right_jacobian_inverse(e[:, 6:9])
                blocks[:, 9:12, 9:12] = np.eye(3)
                blocks = blocks[:, self.state_rows, :] * self.w_state[None, :, None]
                groups.append(_Group(res, idx, blocks))

        if idx.size and self.accel_rows.size:
            f = dynamics_batch(x[idx], self.u[idx], theta)[:, _ACCEL_ROWS]
            res = (f - self.acc[idx])[:, self.accel_rows] * self.w_accel
            parts.append(res.ravel())
            if jacobian:
                jac = dynamics_jacobians_batch(x[idx], self.u[idx], theta)[:, _ACCEL_ROWS][:, self.accel_rows]
                jx = jac[:, :, 0:13] @ lift_matrix(x[idx]) * self.w_accel[None, :, None]
                jp = jac[:, :, 13:] @ dtheta * self.w_accel[None, :, None]
                groups.append(_Group(res, idx, jx, phi=jp))

        if k > 1:
            if jacobian:
                fx, a, c = self._propagate(x, phi, theta)
            else:  # the end states only (a trial step's cost)
                fx = propagate_intervals_structured(x[:-1], self.u[:-1], theta, self.durations, jacobians=False)[0]
            e_raw = boxminus(x[1:], fx)  # the Jacobians are those of ⊟, at its value (the gap offset is constant)
            e = e_raw - self.gap_offset
            res = np.einsum("kij,kj->ki", self.w_proc, e)
            parts.append(res.ravel())
            if jacobian:
                assert a is not None and c is not None  # the Jacobian branch propagated with Jacobians
                j_prev, j_next, j_phi = _process_jacobians(self.w_proc, e_raw, fx, a, c, x[:-1], dtheta)
                groups.append(_Group(res, np.arange(k - 1), j_prev, j_next, j_phi))

        if self.gauge_rows.size:
            first = self.segment_starts
            e = boxminus(x[first], self.y[first])
            res = e[:, self.gauge_rows]
            parts.append(res.ravel())
            if jacobian:
                blk = np.broadcast_to(np.eye(nt), (first.size, nt, nt)).copy()
                blk[:, 6:9, 6:9] = so3_right_jacobian_inverse(e[:, 6:9])
                groups.append(_Group(res, first, blk[:, self.gauge_rows]))

        if self.prior is not None:
            res = self.prior_sqrt_info @ (theta - self.prior.theta)
            parts.append(res)
            if jacobian:
                groups.append(_Group(res[None], np.zeros(0, dtype=int), None,
                                     phi=(self.prior_sqrt_info @ dtheta)[None]))

        b = np.concatenate(parts) if parts else np.zeros(0)
        return b, groups

    def normal_equations(self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray) -> tuple[np.ndarray, _Normal]:
        """``b(ϑ)`` and the blocks of ``AᵀA`` and ``Aᵀb`` (:class:`_Normal`).

        ``A`` is never formed: every residual touches one or two consecutive states and φ, so ``AᵀA`` is block
        tridiagonal in the states (12×12 blocks) with a dense 4-column border in φ, accumulated directly from the
        per-record Jacobian blocks of :meth:`jacobian_groups`.
        """
        b, groups = self.jacobian_groups(x, phi, inliers)
        k, nt, npar = self.k, TANGENT_DIM, par.N_PARAMS
        hd = np.zeros((k, nt, nt))
        ho = np.zeros((max(k - 1, 0), nt, nt))
        hxp = np.zeros((k, nt, npar))
        hpp = np.zeros((npar, npar))
        gx = np.zeros((k, nt))
        gp = np.zeros(npar)
        for grp in groups:
            for offset, blk in ((0, grp.state), (1, grp.next_state)):
                if blk is None:
                    continue
                at = grp.index + offset
                bt = blk.transpose(0, 2, 1)
                hd[at] += bt @ blk
                gx[at] += np.einsum("kij,kj->ki", bt, grp.res)
                if grp.phi is not None:
                    hxp[at] += bt @ grp.phi
            if grp.next_state is not None:
                ho[grp.index] += grp.state.transpose(0, 2, 1) @ grp.next_state  # type: ignore[union-attr,index]
            if grp.phi is not None:
                hpp += np.einsum("kri,krj->ij", grp.phi, grp.phi)
                gp += np.einsum("kri,kr->i", grp.phi, grp.res)
        return b, _Normal(hd, ho, hxp, hpp, gx, gp)

    def last_covariance_qr(self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray) -> np.ndarray | None:
        """Covariance of ``[δx_K, δφ]`` (16×16) from a block QR factorisation of ``A`` (no ``AᵀA`` formed).

        With the variables ordered ``[x_1 .. x_K, φ]`` and ``A = QR``, the last 16×16 block of ``(AᵀA)⁻¹ =
        R⁻¹R⁻ᵀ`` is ``R_ll⁻¹ R_ll⁻ᵀ``. ``R`` is built state by state (a square-root information smoother): the
        rows left over on ``[x_k, φ]``, the rows of record k and the process rows k → k+1 are triangularised on
        ``[x_k, x_{k+1}, φ]``; what remains on ``[x_{k+1}, φ]`` is carried on. The normal equations square the
        condition number of ``A`` (10¹²-10¹³ for a nearly rigid process model, so their covariance is good to
        ~10⁻⁴ only); this is accurate to ``cond(A)·ε``. Returns None when ``A`` has not full column rank.
        """
        _, groups = self.jacobian_groups(x, phi, inliers)
        k, nt, npar = self.k, TANGENT_DIM, par.N_PARAMS
        single: list[list[np.ndarray]] = [[] for _ in range(k)]
        phi_only: list[np.ndarray] = []
        process = None
        for grp in groups:
            if grp.next_state is not None:
                process = grp
                continue
            if grp.state is None:
                for blk in grp.phi:  # type: ignore[union-attr,index]
                    rows = np.zeros((blk.shape[0], nt + npar))
                    rows[:, nt:] = blk
                    phi_only.append(rows)
                continue
            n, r = grp.res.shape
            rows = np.zeros((n, r, nt + npar))
            rows[:, :, :nt] = grp.state
            if grp.phi is not None:
                rows[:, :, nt:] = grp.phi
            for i, at in enumerate(grp.index):
                single[at].append(rows[i])
        carry = np.zeros((0, nt + npar))  # rows on [x_k, φ]
        for i in range(k):
            last = i == k - 1
            width = nt + npar if last else 2 * nt + npar
            own = [carry, *single[i], *(phi_only if last else ())]
            stacked = np.concatenate([r for r in own if r.size] or [np.zeros((0, nt + npar))])
            block = np.zeros((stacked.shape[0], width))
            block[:, :nt] = stacked[:, :nt]
            block[:, width - npar:] = stacked[:, nt:]
            if not last:
                link = np.zeros((nt, width))
                link[:, :nt] = process.state[i]  # type: ignore[union-attr,index]
                link[:, nt:2 * nt] = process.next_state[i]  # type: ignore[union-attr,index]
                link[:, 2 * nt:] = process.phi[i]  # type: ignore[union-attr,index]
                block = np.vstack([block, link])
            if block.shape[0] < (width if last else nt):
                return None
            r_mat: np.ndarray = np.asarray(np.linalg.qr(block, mode="r"))
            if last:
                r_ll = r_mat[:width, :width]
                if np.min(np.abs(np.diag(r_ll))) <= 1e-14 * np.max(np.abs(np.diag(r_ll))):
                    return None
                r_inv = sla.solve_triangular(r_ll, np.eye(width), check_finite=False)
                cov = r_inv @ r_inv.T
                return cov if np.all(np.isfinite(cov)) else None
            carry = r_mat[nt:, nt:]
        return None

    def d2(self, x: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Normalised residual squared ``d²_k`` of every record against the states ``x``."""
        e = boxminus(x, self.y)[:, self.state_rows] * self.w_state
        out = np.sum(e * e, axis=1)
        if self.accel_rows.size:
            f = dynamics_batch(x, self.u, par.theta_from_phi(phi))[:, _ACCEL_ROWS]
            ea = (f - self.acc)[:, self.accel_rows] * self.w_accel
            out += np.sum(ea * ea, axis=1)
        out[~self.has_state] = np.nan
        return out

    def residual_count(self, inliers: np.ndarray) -> int:
        """Rows of ``b`` that carry information (measurement, acceleration, linked process, gauge, prior)."""
        n = int(inliers.sum()) * self.dof + int(self.link_rows.sum())
        n += self.gauge_rows.size * self.segment_starts.size
        return n + (par.N_PARAMS if self.prior is not None else 0)


def _solve(h: sp.csc_matrix, g: np.ndarray) -> np.ndarray | None:
    try:
        out = spla.splu(h).solve(g)
    except RuntimeError:  # exactly singular
        return None
    return out if np.all(np.isfinite(out)) else None


class _ReferenceSystem:
    """The sparse normal equations of the original implementation (``A`` assembled, ``AᵀA`` factorised by LU)."""

    def __init__(self, b: np.ndarray, a_mat: sp.csc_matrix) -> None:
        self.h = (a_mat.T @ a_mat).tocsc()
        self.g = a_mat.T @ b

    def diagonal(self) -> np.ndarray:
        return self.h.diagonal()

    def solve(self, damping: np.ndarray) -> np.ndarray | None:
        return _solve((self.h + sp.diags(damping)).tocsc(), -self.g)


def _linearise(
    problem: _Problem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, reference: bool
) -> tuple[np.ndarray, _Normal | _ReferenceSystem]:
    """Residuals and the normal equations at (x, φ): block form (default) or the sparse reference path."""
    if reference:
        b, a_mat = problem.evaluate(x, phi, inliers, jacobian=True)
        return b, _ReferenceSystem(b, a_mat)  # type: ignore[arg-type]
    b, normal = problem.normal_equations(x, phi, inliers)
    return b, normal  # type: ignore[return-value]


def _levenberg_marquardt(
    problem: _Problem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, settings: EstimatorSettings,
    history: list[float], reference: bool = False, lambda_init: float = _LAMBDA_INIT,
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Minimise ‖b‖² from (x, φ) starting with damping ``lambda_init``; returns the solution, the iterations done
    and whether it converged."""
    b, system = _linearise(problem, x, phi, inliers, reference)
    cost = float(b @ b)
    history.append(cost)
    lam = lambda_init
    k = problem.k
    for it in range(1, settings.max_iterations + 1):
        h_diag = system.diagonal()
        diag = np.maximum(h_diag, 1e-12 * max(h_diag.max(), 1.0))
        retried = False
        while True:
            step = system.solve(lam * diag)
            if step is None:
                lam *= 10.0
                if lam > _LAMBDA_MAX:
                    return x, phi, it, False
                continue
            x_new = boxplus(x, step[: TANGENT_DIM * k].reshape(k, TANGENT_DIM))
            phi_new = phi + step[TANGENT_DIM * k:]
            # The first trial of an iteration is linearised at once (it is nearly always taken); after a rejection
            # the cost comes first, from the end states only, and the Jacobians only for a step that is taken.
            cheap = retried and not reference
            with np.errstate(all="ignore"):  # a wild trial step may overflow; it is then rejected below
                if cheap:
                    b_new = problem.jacobian_groups(x_new, phi_new, inliers, jacobian=False)[0]
                else:
                    b_new, system_new = _linearise(problem, x_new, phi_new, inliers, reference)
                cost_new = float(b_new @ b_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                if cheap:
                    b_new, system_new = _linearise(problem, x_new, phi_new, inliers, reference)
                    cost_new = float(b_new @ b_new)
                break
            retried = True
            lam *= 10.0
            if lam > _LAMBDA_MAX:
                return x, phi, it, True  # no descent left: at a minimum within rounding
        decrease = (cost - cost_new) / max(cost, 1e-300)
        step_size = float(np.max(np.abs(step)))
        x, phi, b, system, cost = x_new, phi_new, b_new, system_new, cost_new
        history.append(cost)
        lam = max(lam / 10.0, 1e-15)
        if decrease < settings.tolerance or step_size < settings.tolerance:
            return x, phi, it, True
    return x, phi, settings.max_iterations, False


def _marginal_covariances(
    problem: _Problem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, reference: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``[(AᵀA)⁻¹]_θθ`` mapped from φ to θ, and the covariance of ``[δx_K, δφ]`` (last state and φ, 16×16).

    Singular ``AᵀA`` gives ``inf`` diagonals.
    """
    m = TANGENT_DIM + par.N_PARAMS
    if reference:
        # The augmented system [[I, A], [Aᵀ, 0]] [r; z] = [0; −e]  ⇒  z = (AᵀA)⁻¹ e, by sparse LU: AᵀA is never
        # formed, so the covariance is good to cond(A)·ε like the QR (a solve of AᵀA squares the condition number:
        # 10¹²-10¹³ for a nearly rigid process model, ~1e-5 relative accuracy only).
        _, a_mat = problem.evaluate(x, phi, inliers, jacobian=True)
        rows, n = a_mat.shape  # type: ignore[union-attr]
        kkt = sp.bmat([[sp.identity(rows), a_mat], [a_mat.T, None]]).tocsc()  # type: ignore[union-attr]
        rhs = np.zeros((rows + n, m))
        rhs[rows + n - m:, :] = -np.eye(m)
        sol = _solve(kkt, rhs)
        cov_last = None if sol is None else sol[rows + n - m:, :]
    else:
        cov_last = problem.last_covariance_qr(x, phi, inliers)
    if cov_last is None:
        return np.diag(np.full(par.N_PARAMS, np.inf)), np.diag(np.full(m, np.inf))
    cov_last = 0.5 * (cov_last + cov_last.T)
    jac = par.theta_jacobian(phi)
    cov = jac @ cov_last[TANGENT_DIM:, TANGENT_DIM:] @ jac.T
    return 0.5 * (cov + cov.T), cov_last


def covariance_at(
    records: Sequence[Measurement], settings: EstimatorSettings, prior: ParameterEstimate | None,
    states: np.ndarray, phi: np.ndarray, weights_theta: np.ndarray,
) -> np.ndarray:
    """The batch problem's parameter covariance ``[(AᵀA)⁻¹]_θθ`` at a given point, without iterating.

    The covariance of the maximum-likelihood problem ([Doerr2021] Eqs. 31-32: ``cov(θ̂)`` "extracted from
    ``(AᵀA)⁻¹``", module docstring) evaluated at ``(states, φ)``: what a solve converged there would report.
    The sequential filter uses it to skip bootstrap checks that cannot hand over yet.

    Parameters
    ----------
    records : sequence of Measurement
        Time-ordered records.
    settings : EstimatorSettings
    prior : ParameterEstimate or None
        Prior on θ (its information is added when given).
    states : ndarray, shape (K, 13)
        States of the records at the point.
    phi : ndarray, shape (4,)
        Parameters at the point in the solver's parametrisation (:mod:`oacli.estimation.parametrization`).
    weights_theta : ndarray, shape (4,)
        θ ``[m kg, Ixx, Iyy, Izz kg·m²]`` at which the lost inputs' model is weighted.

    Returns
    -------
    ndarray, shape (4, 4)
        Covariance of ``θ`` (``inf`` diagonal when ``AᵀA`` is singular).
    """
    problem = _Problem(records, settings, prior, weights_theta)
    cov, _ = _marginal_covariances(problem, states, phi, problem.has_state.copy())
    return cov


def estimate_batch(
    records: Sequence[Measurement],
    settings: EstimatorSettings,
    prior: ParameterEstimate | None,
    *,
    initial_theta: np.ndarray | None = None,
    initial_states: np.ndarray | None = None,
    initial_phi: np.ndarray | None = None,
    continuation: bool = True,
    warm_start: bool = False,
    reference: bool = False,
) -> BatchResult:
    """Batch maximum-likelihood estimate of the states and θ from a set of records (Doerr Eqs. 31-32).

    Parameters
    ----------
    records : sequence of Measurement
        In any order (sorted by time stamp here; repeated time stamps are dropped and counted). At least 2.
    settings : EstimatorSettings
        Noise models, integration grid, gate, iteration limits.
    prior : ParameterEstimate or None
        Gaussian prior ``N(θ₀, P₀)`` on θ (``None``: pure maximum likelihood). ``P₀`` is a covariance
        (variances on its diagonal).
    initial_theta : ndarray, shape (4,), optional
        Starting point (default: the prior mean); must be physical.
    initial_states : ndarray, shape (K, 13), optional
        Starting states for the time-ordered records (default: the measured states).
    initial_phi : ndarray, shape (4,), optional
        Starting point in the physical parametrisation (overrides ``initial_theta``; a previous solution's ``phi``,
        which may lie arbitrarily close to the physical boundary).
    continuation : bool
        Solve with inflated process noise first (see the module docstring); a warm start close to the solution
        may skip it.
    warm_start : bool
        The starting point is a previous solution (of fewer records): the continuation's last stage only
        (:data:`_CONTINUATION_WARM`), every Levenberg-Marquardt solve started with little damping
        (:data:`_LAMBDA_WARM`).
    reference : bool
        Use the original implementation (sparse ``A`` assembled, ``AᵀA`` factorised by LU, the general
        :func:`~oacli.estimation.propagation.propagate_intervals`) instead of the block normal equations with a
        Schur complement on φ; the same iterations, kept to check the fast path against (tests, benchmark).

    Returns
    -------
    BatchResult
    """
    wall = time.perf_counter()
    ordered = order_by_time(records)
    recs = ordered.records
    if len(recs) < 2:
        raise ValueError(f"the batch estimator needs at least 2 records with distinct time stamps, got {len(recs)}")
    if initial_theta is None and initial_phi is None:
        if prior is None:
            raise ValueError("give a prior or an initial_theta")
        initial_theta = prior.theta
    phi = par.phi_from_theta(initial_theta) if initial_phi is None else np.array(initial_phi, dtype=float)  # type: ignore[arg-type]
    theta_w = prior.theta if prior is not None else par.theta_from_phi(phi)
    problem = _Problem(recs, settings, prior, theta_w)
    x = problem.y.copy() if initial_states is None else np.array(initial_states, dtype=float)
    threshold = chi2_threshold(problem.dof, settings.gate_probability) if settings.gate_probability else np.inf
    inliers = problem.has_state.copy()
    if not np.any(inliers):
        raise ValueError("the batch estimator needs at least one record with a measured state")
    gate_emptied = False
    history: list[float] = []
    iterations = 0
    loose = EstimatorSettings(**{**settings.__dict__, "tolerance": max(settings.tolerance, _CONTINUATION_TOLERANCE)})
    rounds = 0
    converged = False
    lam0 = _LAMBDA_WARM if warm_start else _LAMBDA_INIT
    for rounds in range(1, settings.max_gating_rounds + 1):
        # The continuation in the first round only: a later round starts from the previous round's solution, which
        # dropping a few outliers moves by little (the full Gauss-Newton steps do not overshoot from there).
        for factor in (_CONTINUATION_WARM if warm_start else _CONTINUATION) if continuation and rounds == 1 else ():
            problem.set_process_noise_scale(factor)
            x, phi, its, _ = _levenberg_marquardt(problem, x, phi, inliers, loose, [], reference, lam0)
            iterations += its
        problem.set_process_noise_scale(1.0)
        x, phi, its, converged = _levenberg_marquardt(problem, x, phi, inliers, settings, history, reference, lam0)
        iterations += its
        if rounds == 1 and problem.has_gaps:
            # The lost inputs' prediction corrected with this solve's measurement residuals (set_lost_inputs), and
            # solved again from here.
            problem.set_lost_inputs(problem.measurement_noise(x, inliers), par.theta_from_phi(phi))
            x, phi, its, converged = _levenberg_marquardt(problem, x, phi, inliers, settings, history, reference,
                                                          lam0)
            iterations += its
        d2 = problem.d2(x, phi)
        new_inliers = problem.has_state & (np.nan_to_num(d2, nan=np.inf) <= threshold)
        if not np.any(new_inliers):
            gate_emptied = True  # reported: the caller must not call this fit ok
            break  # nothing passes the gate: keep the last inlier set rather than an empty problem
        if np.array_equal(new_inliers, inliers):
            break
        inliers = new_inliers
    d2 = problem.d2(x, phi)
    cov, cov_last = _marginal_covariances(problem, x, phi, inliers, reference)
    estimate = ParameterEstimate(
        t=float(problem.t[-1]),
        theta=par.theta_from_phi(phi),
        covariance=cov if np.all(np.isfinite(cov)) else np.diag(np.full(4, UNIDENTIFIED_VARIANCE)),
        method="batch",
        samples_used=int(inliers.sum()),
        samples_rejected=int((~inliers & problem.has_state).sum()) + len(ordered.duplicates),
    )
    return BatchResult(
        estimate=estimate,
        t=problem.t,
        states=x,
        inliers=inliers,
        d2=d2,
        gate_threshold=float(threshold),
        dof=problem.dof,
        iterations=iterations,
        gating_rounds=rounds,
        cost_history=tuple(history),
        converged=converged,
        duplicates=len(ordered.duplicates),
        solve_time_s=time.perf_counter() - wall,
        phi=phi,
        last_covariance=cov_last,
        chi2=float(history[-1]) if history else float("nan"),
        chi2_dof=problem.residual_count(inliers) - problem.n_var,
        gate_emptied=gate_emptied,
        segments=int(problem.segment_starts.size),
    )


def extend_states(
    states: np.ndarray, records: Sequence[Measurement], theta: np.ndarray, substep_s: float
) -> np.ndarray:
    """Warm start for a longer window.

    The solved ``states`` for the first records, then the process model propagated from the last of them with the
    records' inputs (consistent with the dynamics: the stiff process residuals start at zero).

    Parameters
    ----------
    states : ndarray, shape (n, 13)
        Solved states of the first n records.
    records : sequence of Measurement
        The records of the longer window (at least n), in time order.
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz].
    substep_s : float
        Integration substep [s].

    Returns
    -------
    ndarray, shape (len(records), 13)
    """
    out = np.array([r.x_measured for r in records])
    n = states.shape[0]
    out[:n] = states
    if n >= len(records):
        return out
    t = np.array([r.t for r in records])
    sched = substep_schedule(t[n - 1:-1], t[n:], substep_s)
    for i in range(n, len(records)):
        if records[i].starts_segment:
            continue  # the input before it is unknown: start from its measurement
        out[i] = propagate_state_one(out[i - 1], records[i - 1].u_applied, theta, sched[i - n])
    return out


def estimate_batch_windows(
    records: Sequence[Measurement],
    settings: EstimatorSettings,
    prior: ParameterEstimate | None,
    window_ends_s: Sequence[float],
    *,
    progress: Callable[[float], None] | None = None,
    reference: bool = False,
) -> list[BatchResult]:
    """Batch estimates on growing windows ``[t_first, t_end]`` (to show convergence over mission time).

    Each window is warm-started from the previous solution (states and θ, the new records' states propagated by
    :func:`extend_states`) with one continuation stage (:data:`_CONTINUATION_WARM`) and little initial damping
    (:data:`_LAMBDA_WARM`): on the default mission 10 iterations per window instead of 21 (two gating rounds
    each), θ̂ equal to a cold solve's to 7e-10 relative on the last window and 7e-8 on the second (the cost
    tolerance's accuracy: 6e-6 standard deviations). A window whose warm solve does not converge is solved again
    from the prior. Windows with fewer
    than two records are skipped. The last entry of ``window_ends_s`` should be the last record time to include
    all data. ``progress`` is called with the fraction of windows done.

    Parameters
    ----------
    records : sequence of Measurement
    settings : EstimatorSettings
    prior : ParameterEstimate or None
    window_ends_s : sequence of float
        End time [s] of each window, increasing.
    progress : callable, optional
    reference : bool
        Solve every window with the original implementation (see :func:`estimate_batch`).

    Returns
    -------
    list of BatchResult
        One per window that was solved.
    """
    ordered = order_by_time(records).records
    t = np.array([r.t for r in ordered])
    results: list[BatchResult] = []
    theta = None if prior is None else prior.theta
    phi: np.ndarray | None = None
    states: np.ndarray | None = None
    for i, end in enumerate(window_ends_s):
        n = int(np.searchsorted(t, end + TIME_TOL_S, side="right"))
        if n >= 2:
            init = None if states is None else extend_states(states, ordered[:n], theta, settings.substep_s)  # type: ignore[arg-type]
            result = estimate_batch(ordered[:n], settings, prior, initial_theta=theta, initial_states=init,
                                    initial_phi=phi, warm_start=init is not None,
                                    reference=reference)
            if init is not None and not result.converged:  # the warm start did not pay off: solve from the prior
                result = estimate_batch(ordered[:n], settings, prior, reference=reference)
            results.append(result)
            theta, phi, states = result.estimate.theta, result.phi, result.states
        if progress is not None:
            progress((i + 1) / len(window_ends_s))
    return results
