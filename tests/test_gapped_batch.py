"""Gaps in the input record (whole controller records lost) in the batch estimator.

The clean experiment behind the design (:func:`oacli.estimation.lost_inputs.segment_link_weights`): on noise-free data a
split run gives exactly the unsplit estimate, whether the gap links are cut or bridged with the unknown force
profiled out; the closed-form pieces (force directions, the prediction of a lost input and its error variance) are
checked against hand computations; with noise, a closed loop whose input feeds back the noisy measurement keeps the
gapped estimate within 2σ of the clean one.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from estimation_helpers import (
    CONTROL_PERIOD_S,
    PLANT_PERIOD_S,
    THETA_TRUE,
    closed_loop_pd,
    records,
    settings,
    simulate_open_loop,
)
from scipy.stats import chi2

from oacli.estimation import lost_inputs
from oacli.estimation.alignment import align_records
from oacli.estimation.batch import estimate_batch
from oacli.estimation.bounds import cramer_rao_bound
from oacli.estimation.imu import ImuStream, attach_accelerations
from oacli.estimation.lost_inputs import (
    bridge_accelerations,
    lost_input_model,
    lost_input_prior,
    noise_corrected_prediction,
    segment_link_weights,
    unknown_force_directions,
    unknown_torque_directions,
)
from oacli.estimation.manifold import boxminus
from oacli.estimation.models import ProcessNoise
from oacli.estimation.sequential import SequentialEstimator
from oacli.sim.delivered import DeliveredInput
from oacli.sim.imu import ImuModel, simulate_imu
from oacli.sim.sensors import SensorNoise
from oacli.types import ParameterEstimate
from tests.model_helpers import mass_model

CUTS = (9, 17, 26, 34, 47)
WIDE_PRIOR = ParameterEstimate(0.0, [15.0, 0.1, 0.1, 0.1], np.diag([15.0, 0.005, 0.005, 0.005]) * 1e8, "prior")


def _split(recs, cuts=CUTS):
    return [replace(r, starts_segment=i in cuts) for i, r in enumerate(recs)]


@pytest.mark.parametrize("mode", ["cut", "profiled"])
def test_a_noise_free_split_run_gives_the_unsplit_estimate(monkeypatch, mode):
    """Noise-free open loop: the unsplit and the split run both recover θ exactly (to the solver's tolerance),
    with every gap link cut (segments independent) or bridged with the unknown force profiled out."""
    tel = simulate_open_loop(60, sensors=SensorNoise(0.0, 0.0, 0.0, 0.0), seed=0)
    recs = records(tel)
    start = THETA_TRUE * np.array([1.1, 0.9, 1.1, 0.9])
    whole = estimate_batch(recs, settings(), WIDE_PRIOR, initial_theta=start)
    if mode == "cut":
        monkeypatch.setattr(lost_inputs, "BRIDGE_FACTOR", 0.0)
    else:
        monkeypatch.setattr(lost_inputs, "_MIN_PREDICTION_SAMPLES", 10**6)
    split = estimate_batch(_split(recs), settings(), WIDE_PRIOR, initial_theta=start)
    assert split.segments == len(CUTS) + 1 and whole.converged and split.converged
    np.testing.assert_allclose(whole.estimate.theta, THETA_TRUE, rtol=1e-7)
    np.testing.assert_allclose(split.estimate.theta, whole.estimate.theta, rtol=1e-7)
    # The bridge keeps information the cut loses; both lose some against the unsplit run.
    sd_whole = np.sqrt(np.diag(whole.estimate.covariance))
    sd_split = np.sqrt(np.diag(split.estimate.covariance))
    assert np.all(sd_split >= sd_whole * (1 - 1e-9))


def test_the_profiled_bridge_keeps_more_mass_information_than_the_cut(monkeypatch):
    tel = simulate_open_loop(60, sensors=SensorNoise(0.0, 0.0, 0.0, 0.0), seed=0)
    recs = _split(records(tel))
    monkeypatch.setattr(lost_inputs, "_MIN_PREDICTION_SAMPLES", 10**6)
    bridged = estimate_batch(recs, settings(), WIDE_PRIOR)
    monkeypatch.setattr(lost_inputs, "BRIDGE_FACTOR", 0.0)
    cut = estimate_batch(recs, settings(), WIDE_PRIOR)
    sd = [np.sqrt(np.diag(r.estimate.covariance)) for r in (bridged, cut)]
    assert sd[0][0] < sd[1][0]
    np.testing.assert_allclose(sd[0][1:], sd[1][1:], rtol=1e-6)  # rotation is cut in both
    assert bridged.chi2_dof == cut.chi2_dof + 3 * len(CUTS)  # three translational residuals per bridged gap


def test_segment_link_weights_in_closed_form():
    rng = np.random.default_rng(3)
    dt = np.array([0.2, 0.2, 0.2, 0.6])
    theta = np.array([12.0, 0.15, 0.14, 0.16])
    noise = ProcessNoise(1e-3, 1e-4)
    w, q = noise.sqrt_information(dt, theta), noise.covariance(dt, theta)
    links = np.array([True, False, False, False])
    predicted = np.array([False, True, False, True])  # the last one is too long to bridge at all
    var = rng.uniform(1e-4, 1e-3, 6)
    out, rows = segment_link_weights(w, q, dt, links, predicted, var, theta)
    np.testing.assert_array_equal(rows, [12, 12, 3, 0])
    np.testing.assert_array_equal(out[0], w[0])
    np.testing.assert_array_equal(out[3], 0.0)
    np.testing.assert_array_equal(out[2, 6:, :], 0.0)  # profiled: no rotational residual
    d = unknown_force_directions(dt)
    np.testing.assert_allclose(d[0, 0:6, 0], [0.02, 0, 0, 0.2, 0, 0])  # ½T², T per unit of Δf/m
    dr = unknown_torque_directions(dt, theta[1:])
    np.testing.assert_allclose(dr[0, 6:12, 1], [0, 0.02 / 0.14, 0, 0, 0.2 / 0.14, 0])
    # Predicted: whitened by Q + D Σ_u Dᵀ (the prediction's error as a random effect).
    dd = np.concatenate([d[1] / theta[0], dr[1]], axis=1)
    cov = q[1] + dd @ np.diag(var) @ dd.T
    np.testing.assert_allclose(out[1].T @ out[1], np.linalg.inv(cov), rtol=1e-8)
    # Profiled: the force directions are annihilated, the rest of the whitened residual kept (rank 3).
    np.testing.assert_allclose(out[2, :6, :6] @ d[2, :6], 0.0, atol=1e-9 * np.abs(w[2]).max())
    assert np.linalg.matrix_rank(out[2], tol=1e-9 * np.abs(w[2]).max()) == 3
    e = rng.standard_normal(6)
    force = rng.standard_normal(3)
    r1 = out[2, :6, :6] @ e
    r2 = out[2, :6, :6] @ (e + d[2, :6] @ force)
    np.testing.assert_allclose(r1, r2, atol=1e-9 * np.abs(r1).max())
    # ‖P W e‖² is the cost minimised over the force in closed form.
    wt = w[2, :6, :6]
    best = np.linalg.lstsq(wt @ d[2, :6], wt @ e, rcond=None)[0]
    np.testing.assert_allclose(r1 @ r1, np.sum((wt @ (e - d[2, :6] @ best)) ** 2), rtol=1e-9)


def test_the_lost_input_is_predicted_from_its_neighbours_with_the_measured_error():
    rng = np.random.default_rng(0)
    t = np.arange(40) * 0.2
    u = rng.standard_normal((40, 6))
    links = np.ones(39, dtype=bool)
    links[20] = False  # the input of record 20 is unknown (a placeholder)
    links[30] = False
    links[31] = False  # two in a row: record 31's neighbour 32 is known but 30's is not
    u_prior, predicted, var = lost_input_prior(t, u, links)
    assert np.flatnonzero(predicted).tolist() == [20]
    np.testing.assert_allclose(u_prior[20], 0.5 * (u[19] + u[21]))
    np.testing.assert_array_equal(u_prior[30], u[30])
    known = np.r_[links, False]
    mid = [i for i in range(1, 39) if known[i - 1] and known[i] and known[i + 1]]
    d = u[mid] - 0.5 * (u[np.array(mid) - 1] + u[np.array(mid) + 1])
    np.testing.assert_allclose(var, np.mean(d**2, axis=0), rtol=1e-12)
    _, none, var_none = lost_input_prior(t[:8], u[:8], np.r_[links[:6], False])
    assert not none.any() and np.all(np.isinf(var_none))  # too few triples: no prediction


def test_a_lost_control_record_keeps_the_last_input_for_one_period_only():
    t = np.arange(12) * 0.2
    x = np.tile(np.r_[np.zeros(6), 0, 0, 0, 1, np.zeros(3)], (12, 1))
    u = np.arange(72, dtype=float).reshape(12, 6)
    keep = np.setdiff1d(np.arange(12), [4, 8, 9])
    recs, rep = align_records(t[keep], x[keep], t[keep], u[keep], reorder_window=0)
    by_t = {round(r.t, 6): r for r in recs}
    # The first lost instant of each gap becomes an input-only record with an unknown input (zero placeholder).
    for lost in (0.8, 1.6):
        assert not by_t[lost].state_measured and not by_t[lost].starts_segment
        np.testing.assert_array_equal(by_t[lost].u_applied, 0.0)
    assert 1.8 not in by_t  # only the first lost instant of a longer gap
    assert by_t[1.0].starts_segment and by_t[2.0].starts_segment
    assert rep.gaps == 2 and rep.segments == 3 and rep.lost_instants == 2 and rep.input_only == 0
    assert rep.as_dict()["lost_instants"] == 2
    # The sequential filter predicts through the lost instant with the last known input and re-initialises after.
    est = SequentialEstimator(settings(), WIDE_PRIOR, bootstrap_relative_std=None)
    for r in recs:
        est.update(r)
    est.flush()
    status = {round(s.t, 6): s.status for s in est.history}
    assert status[0.8] == "predicted" and status[1.0] == "segment" and status[2.0] == "segment"
    assert est.segments == 2


@pytest.mark.parametrize("seed", [0, 1])
def test_a_gapped_closed_loop_run_stays_within_two_sigma_of_the_clean_one(seed):
    tel = closed_loop_pd(seed, 150)
    clean = estimate_batch(records(tel), settings(), WIDE_PRIOR)
    keep = np.ones(len(tel.t_ctrl), dtype=bool)
    keep[np.random.default_rng(100 + seed).choice(np.arange(1, len(keep) - 1), 15, replace=False)] = False
    recs, rep = align_records(tel.t_ctrl[keep], tel.x_measured[keep], tel.t_ctrl[keep], tel.u_applied[keep],
                              reorder_window=0)
    assert rep.gaps > 0 and rep.lost_instants == rep.gaps  # the first lost instant of every gap
    gapped = estimate_batch(recs, settings(), WIDE_PRIOR)
    assert gapped.converged and 0.8 < gapped.chi2 / gapped.chi2_dof < 1.2
    # The mass (translation: the lost force predicted, position continuity kept) within 2σ; all four together
    # within the 99 % χ² bound of the gapped fit's covariance.
    diff = gapped.estimate.theta - clean.estimate.theta
    assert abs(diff[0]) <= 2.0 * np.sqrt(gapped.estimate.covariance[0, 0])
    assert diff @ np.linalg.solve(gapped.estimate.covariance, diff) <= chi2.ppf(0.99, 4)


def _gapped(tel, lost):
    keep = np.setdiff1d(np.arange(len(tel.t_ctrl)), lost)
    recs, rep = align_records(tel.t_ctrl[keep], tel.x_measured[keep], tel.t_ctrl[keep], tel.u_applied[keep],
                              reorder_window=0)
    assert rep.lost_instants == len(lost)
    return recs


def test_the_prediction_corrected_for_the_feedback_on_the_neighbours_noise():
    """The closed loop's PD law reacts to the measurement noise: the regression on the neighbours' mean and their
    measurement residuals predicts the lost inputs to the reaction to the lost record's own noise (which no
    predictor can know), better than the neighbours' mean, and its error variance says so."""
    tel = closed_loop_pd(0, 300)
    t, u = tel.t_ctrl, tel.u_applied
    x_true = tel.x_true[np.searchsorted(tel.t_true, t - 1e-9)]
    noise = boxminus(tel.x_measured, x_true)  # the true measurement noise ỹ ⊟ x
    lost = np.arange(10, 295, 5)
    links = np.ones(len(t) - 1, dtype=bool)
    links[lost] = False
    correction, var, ok = noise_corrected_prediction(t, u, links, noise)
    assert np.flatnonzero(ok).tolist() == lost.tolist()
    mean = 0.5 * (u[lost - 1] + u[lost + 1])
    err_new = u[lost] - (mean + correction[lost])
    err_mid = u[lost] - mean
    # u = ff − K n: force K = [2 I on r, 4 I on v], torque 0.2 I on ω; the lost record's own part K n_k remains.
    own = np.concatenate([2.0 * noise[:, 0:3] + 4.0 * noise[:, 3:6], 0.2 * noise[:, 9:12]], axis=1)
    rms_own = np.sqrt(np.mean(own[lost] ** 2, axis=0))
    rms_new = np.sqrt(np.mean(err_new**2, axis=0))
    assert np.all(rms_new < np.sqrt(np.mean(err_mid**2, axis=0)))
    np.testing.assert_allclose(rms_new, rms_own, rtol=0.25)
    np.testing.assert_allclose(np.sqrt(var), np.sqrt(np.mean(own**2, axis=0)), rtol=0.25)
    _, _, plain = lost_input_prior(t, u, links)
    assert np.all(var < plain)
    # The model takes it only where asked, and only on bridged intervals.
    u_plain, bridged, v_plain, _ = lost_input_model(t, u, links, np.array([15.0, 0.2, 0.2, 0.2]))
    u_corr, _, v_corr, _ = lost_input_model(t, u, links, np.array([15.0, 0.2, 0.2, 0.2]), noise=noise)
    assert np.flatnonzero(bridged).tolist() == lost.tolist()
    np.testing.assert_allclose(u_corr[lost] - u_plain[lost], correction[lost])
    np.testing.assert_array_equal(u_corr[~np.r_[~links, False]], u_plain[~np.r_[~links, False]])
    np.testing.assert_allclose(v_corr[lost, 3:], np.broadcast_to(var[3:], (lost.size, 3)))
    np.testing.assert_allclose(v_plain[lost, 0:3] * 15.0**2, np.broadcast_to(plain[0:3], (lost.size, 3)))
    assert np.all(np.isnan(v_corr[~bridged]))


def test_the_bound_with_the_estimators_prior_on_the_lost_wrench_matches_its_covariance():
    """Closed loop with lost control records: the batch's covariance and the Cramér-Rao bound with the lost
    wrench's prior (the estimator's model, the noise-corrected prediction included) agree along the estimate
    to a few percent (the bound assumes exact dynamics; the process noise is small); the bound that cuts every
    gap (what the benchmark's column used to show) is far wider in mass."""
    tel = closed_loop_pd(1, 150)
    recs = _gapped(tel, [20, 41, 60, 77, 95, 118, 130])
    fit = estimate_batch(recs, settings(), WIDE_PRIOR)
    assert fit.converged
    starts = np.array([r.starts_segment for r in recs])
    u = np.array([r.u_applied for r in recs])
    y = np.array([r.x_measured for r in recs])
    args = (fit.t, fit.states, u, fit.estimate.theta, settings().measurement, PLANT_PERIOD_S)
    kw = {"used": fit.inliers, "segment_starts": starts, "measured": y}
    prior = cramer_rao_bound(*args, **kw)
    cut = cramer_rao_bound(*args, **kw, lost_inputs="cut")
    sd = np.sqrt(np.diag(fit.estimate.covariance))
    np.testing.assert_allclose(prior.std, sd, rtol=0.05)
    assert cut.std[0] > 1.5 * prior.std[0]


def test_the_accelerometer_bridges_a_lost_force():
    """Lost control records with the IMU kept (closed loop, RATTLE-level accelerometer): the input-only record of
    each lost instant carries the mean of the readings over its control period, which measures the lost force as
    ``f/m`` to ``σ_a / √n``; bridged with it, the mass is better determined than with the force predicted from
    the neighbouring inputs, and the estimate stays within 2σ of the clean one."""
    tel = closed_loop_pd(0, 150)
    sigma_a = math.sqrt(5e-6)
    delivered = DeliveredInput.from_telemetry(tel)
    model = ImuModel(accelerometer_noise_std_mps2=sigma_a, accelerometer_bias_std_mps2=0.0)
    imu = simulate_imu(tel.t_true, tel.x_true, delivered.force_world(tel.t_true), mass_model(THETA_TRUE[0]).params,
                       model, np.random.default_rng(0))
    stream = ImuStream(imu.t, imu.specific_force_mps2, imu.angular_rate_radps)
    lost = [12, 30, 47, 63, 80, 97, 115, 131]
    recs = _gapped(tel, lost)
    t_inputs = np.array([r.t for r in recs if r.state_measured])
    bridged, missing = attach_accelerations(recs, stream, np.zeros(3), t_inputs, CONTROL_PERIOD_S)
    assert missing == 0
    lost_recs = [r for r in bridged if not r.state_measured]
    assert len(lost_recs) == len(lost)
    for r in lost_recs:
        inside = (imu.t >= r.t - 1e-9) & (imu.t < r.t + CONTROL_PERIOD_S - 1e-9)
        assert r.acceleration_readings == inside.sum() >= 12
        k = round(r.t / CONTROL_PERIOD_S)
        err = r.linear_acceleration_mps2 - tel.u_applied[k, 0:3] / THETA_TRUE[0]
        assert np.all(np.abs(err) < 4.0 * sigma_a / math.sqrt(r.acceleration_readings)), err
    imu_settings = settings(measurement=replace(settings().measurement, linear_acceleration_std_mps2=sigma_a))
    acc, var = bridge_accelerations(bridged, imu_settings.measurement)
    assert np.isfinite(var).sum() == len(lost) and np.isfinite(acc).all(axis=1).sum() == len(lost)
    with_imu = estimate_batch(bridged, imu_settings, WIDE_PRIOR)
    without = estimate_batch(recs, settings(), WIDE_PRIOR)
    clean = estimate_batch(records(tel), settings(), WIDE_PRIOR)
    assert with_imu.converged and without.converged
    assert with_imu.estimate.covariance[0, 0] < 0.95**2 * without.estimate.covariance[0, 0]  # 0.86 here
    assert abs(with_imu.estimate.theta[0] - clean.estimate.theta[0]) <= 2.0 * math.sqrt(
        with_imu.estimate.covariance[0, 0])
