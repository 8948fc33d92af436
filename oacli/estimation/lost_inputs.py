"""Inputs lost from the telemetry, for the batch and sequential estimators ([Doerr2021] Eqs. 31-32, 35).

An input-only record or a gap in the telemetry leaves the wrench over an interval unknown. This module models it:
the prediction of a lost input from its neighbours and the prediction's measured error (:func:`lost_input_prior`,
:func:`noise_corrected_prediction`), the directions an unknown constant wrench moves the state
(:func:`unknown_force_directions`, :func:`unknown_torque_directions`), the IMU bridges over a lost period
(:func:`bridge_accelerations`, :func:`bridge_angular_accelerations`, [Doerr2021] Eq. 35b) and the weights of the
process residuals that cross a gap (:func:`lost_input_model`, :func:`segment_link_weights`). The design and its
measurements are in :mod:`oacli.estimation.batch`'s module docstring ("Imperfect telemetry").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from oacli.estimation.manifold import (
    TANGENT_DIM,
)
from oacli.estimation.models import Measurement, MeasurementModel
from oacli.estimation.propagation import (
    TIME_TOL_S,
)

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
    ``T J⁻¹ Δτ`` on the angular velocity ([Doerr2021] Eq. 35 linearised at rest). Used only to weight a predicted
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

    The translational dynamics are linear with the force in the world frame ([Doerr2021] Eq. 34): a force error ``Δf``
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
    t: np.ndarray, u: np.ndarray, links: np.ndarray, theta: np.ndarray, *,
    bridge_acceleration: np.ndarray | None = None, bridge_acceleration_variance: np.ndarray | None = None,
    noise: np.ndarray | None = None, gyro: GyroBridge | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the estimator assumes over each interval with an unknown input (one model for :class:`BatchProblem` and
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
    theta : ndarray, shape (4,)
        The weighting point ``[m kg, Ixx, Iyy, Izz kg·m²]`` (of :func:`segment_link_weights`): a predicted force's
        variance is expressed as ``f/m`` at its mass, the gyro-bridged torque's variance and gyroscopic term are
        evaluated at its inertias.
    bridge_acceleration : ndarray, shape (K, 3), optional
        Mean measured ``f/m`` (world frame) over each record's outgoing interval (NaN where none).
    bridge_acceleration_variance : ndarray, shape (K,), optional
        Its variance per axis [m²/s⁴].
    noise : ndarray, shape (K, 12), optional
        Measurement residuals ``ỹ_k ⊟ x̂_k`` of a first solve (NaN where a record has none): the prediction is
        corrected for the controller's reaction to the neighbours' measurement noise
        (:func:`noise_corrected_prediction`).
    gyro : GyroBridge, optional
        The gyro's ``ω̇`` over each record's outgoing interval (:func:`bridge_angular_accelerations`).

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
    weighting = np.asarray(theta, dtype=float)
    if weighting.shape != (4,):
        raise ValueError(f"theta: expected [m, Ixx, Iyy, Izz] (shape (4,)), got shape {weighting.shape}")
    mass_kg, inertia = float(weighting[0]), weighting[1:4]
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
    if gyro is not None:
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
