"""The IMU's bridges of a lost controller record: closed forms and properties.

A lost control record leaves the IMU's readings in the log. The accelerometer's mean over the lost period measures
the lost force as ``f/m`` (world frame); the slope of the gyro's readings measures the ``ω̇`` the lost torque produced
([Doerr2021] Eq. 35b), a constant gyro bias cancelling in it (:func:`oacli.estimation.imu.attach_accelerations`).
Checked here against the simulator's truth: each bridge is unbiased over the gaps and its reported variance is its
error's; the gyro's noise measured on the run is the simulated one; the estimators' offset over a gyro-bridged
interval reproduces the true end state to within that noise; and the estimators take the torque from the gyro.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from estimation_helpers import (
    CONTROL_PERIOD_S,
    RATTLE_PRIOR,
    THETA_TRUE,
    closed_loop_pd,
    dense_jacobian_matching_central_differences,
    records,
    settings,
    simulate_open_loop,
)

from oacli.estimation import parametrization as par
from oacli.estimation.alignment import align_records
from oacli.estimation.batch import estimate_batch
from oacli.estimation.batch_problem import BatchProblem
from oacli.estimation.imu import ImuStream, _gyro_window, attach_accelerations, gyro_noise_variance
from oacli.estimation.lost_inputs import bridge_accelerations, bridge_angular_accelerations, lost_input_model
from oacli.estimation.manifold import boxminus, boxplus
from oacli.estimation.models import ProcessNoise
from oacli.estimation.propagation import propagate_intervals, substep_schedule
from oacli.estimation.sequential import SequentialEstimator
from oacli.sim.delivered import DeliveredInput
from oacli.sim.imu import ImuModel, simulate_imu
from oacli.types import InertialParams

SIGMA_A = math.sqrt(5e-6)  # RATTLE's accelerometer variance
SIGMA_G = 1e-3  # configs/iss_reswarm.yaml sensors.imu
TRUTH = InertialParams(THETA_TRUE[0], THETA_TRUE[1:4])


def _flight(seed: int, n: int, lost_every: int = 6):
    """A closed-loop PD run with a biased, noisy IMU and one control record in ``lost_every`` lost (never two in a
    row), bridged by :func:`attach_accelerations`."""
    tel = closed_loop_pd(seed, n)
    delivered = DeliveredInput.from_telemetry(tel)
    model = ImuModel(accelerometer_noise_std_mps2=SIGMA_A, gyro_noise_std_radps=SIGMA_G,
                     accelerometer_bias_std_mps2=0.0, gyro_bias_std_radps=5e-3)
    imu = simulate_imu(tel.t_true, tel.x_true, delivered.force_world(tel.t_true), TRUTH, model,
                       np.random.default_rng(100 + seed))
    assert np.all(np.abs(imu.gyro_bias_radps[0]) > 0)
    rng = np.random.default_rng(200 + seed)
    starts = np.arange(3, n - lost_every, lost_every)
    lost = starts + rng.integers(0, lost_every - 2, size=starts.size)
    keep = np.setdiff1d(np.arange(n), lost)
    recs, rep = align_records(tel.t_ctrl[keep], tel.x_measured[keep], tel.t_ctrl[keep], tel.u_applied[keep],
                              reorder_window=0)
    assert rep.lost_instants == lost.size
    stream = ImuStream(imu.t, imu.specific_force_mps2, imu.angular_rate_radps)
    t_inputs = np.array([r.t for r in recs if r.state_measured])
    bridged, missing = attach_accelerations(recs, stream, np.zeros(3), t_inputs, CONTROL_PERIOD_S)
    assert missing == 0
    return tel, delivered, stream, recs, bridged


def _true_states(tel, delivered, t):
    return delivered.states_at(np.asarray(t, float), tel.t_true, tel.x_true, TRUTH)


def test_the_gyro_noise_is_measured_on_the_run():
    """The pooled residual variance of a line over every control period is the simulated gyro noise (to its
    sampling error, ~2 % with ~4000 degrees of freedom; the gyroscopic term's curvature adds µrad/s)."""
    _, _, stream, recs, _ = _flight(0, 150)
    var = gyro_noise_variance(recs, stream, CONTROL_PERIOD_S)
    assert var is not None
    assert abs(math.sqrt(var) / SIGMA_G - 1.0) < 0.05


def test_each_bridge_measures_its_lost_wrench_without_bias():
    """Over every lost period of three runs, the accelerometer's mean minus the true ``Δv/T`` and the gyro's slope
    minus the true ``Δω/T`` (from the simulator's states at the period's ends), in units of their reported
    standard deviations: mean within 3 standard errors of 0 (no bias: the gyro bias cancels in the slope), RMS
    within the χ² range of 1 (the variances are the errors')."""
    z_acc, z_gyro = [], []
    for seed in range(3):
        tel, delivered, _, _, bridged = _flight(seed, 150)
        for j, r in enumerate(bridged):
            if r.state_measured or not bridged[j + 1].starts_segment:
                continue
            assert r.angular_acceleration_var_rad2ps4 is not None and r.linear_acceleration_mps2 is not None
            x0, x1 = _true_states(tel, delivered, [r.t, bridged[j + 1].t])
            dt = bridged[j + 1].t - r.t
            z_acc.append((r.linear_acceleration_mps2 - (x1[3:6] - x0[3:6]) / dt)
                         / (SIGMA_A / math.sqrt(r.acceleration_readings)))
            z_gyro.append((r.angular_acceleration_radps2 - (x1[10:13] - x0[10:13]) / dt)
                          / math.sqrt(r.angular_acceleration_var_rad2ps4))
            assert np.all(np.abs(r.x_measured[10:13] - x0[10:13]) < 0.02)  # the gyro's rate, bias included
    for z in (np.array(z_acc).ravel(), np.array(z_gyro).ravel()):
        n = z.size
        assert n >= 200
        assert abs(z.mean()) < 3.0 / math.sqrt(n), z.mean()
        assert 0.8 < math.sqrt(np.mean(z**2)) < 1.2, math.sqrt(np.mean(z**2))


def test_the_gyro_bridge_borrows_the_neighbouring_periods_and_no_reading_twice():
    """The continuous piecewise-linear fit (:func:`oacli.estimation.imu._gyro_bridge`): every lost period's window
    holds it and at most one neighbouring period per side, no control period lies in two windows (so no reading
    enters two bridges: their errors are independent, as the estimators take them), and the variance of the mean
    ``ω̇`` is never above the single-period line's ``σ_g² / Σ(t_i − t̄)²`` and, with both neighbours, 0.35-0.55 times
    it (0.45 for evenly spread readings, the hat-function fit's closed form)."""
    _, _, stream, recs, bridged = _flight(2, 150)
    lost = {j for j, r in enumerate(recs) if not r.state_measured and recs[j + 1].starts_segment}
    var_g = gyro_noise_variance(recs, stream, CONTROL_PERIOD_S)
    assert var_g is not None and len(lost) >= 20
    used: set[int] = set()
    both = 0
    for j in sorted(lost):
        knots = _gyro_window(recs, j, lost, CONTROL_PERIOD_S)
        assert knots == list(range(knots[0], knots[-1] + 1)) and knots[0] >= j - 1 and knots[-1] <= j + 2
        periods = set(knots[:-1])
        assert j in periods and not periods & used
        used |= periods
        t = stream.t[(stream.t >= recs[j].t - 1e-9) & (stream.t <= recs[j + 1].t + 1e-9)]
        single = var_g / float(np.sum((t - t.mean()) ** 2))
        ratio = bridged[j].angular_acceleration_var_rad2ps4 / single
        assert ratio <= 1.0 + 1e-9
        if len(knots) == 4:
            both += 1
            assert 0.35 < ratio < 0.55, ratio
        if len(knots) == 2:
            assert abs(ratio - 1.0) < 1e-9  # no neighbour: the single line
    assert both >= 10


def test_the_gyro_bridge_offset_reproduces_the_true_end_state():
    """Closed form of :func:`lost_input_model` over a gyro-bridged interval: the model with the torque (and force)
    set to 0, plus the offset ``[½T², T] (ᾱ + J⁻¹(ω × Jω))`` (and ``[½T², T] ā``), propagated from the true state
    at the lost instant, lands on the true state after it to within the bridges' noise: the residual's angular
    velocity part is ``T`` times the slope's error, its attitude part ``½T²`` times it (to third order in ``T``)."""
    tel, delivered, _, _, bridged = _flight(1, 120)
    t = np.array([r.t for r in bridged])
    u = np.array([r.u_applied for r in bridged])
    links = ~np.array([r.starts_segment for r in bridged])[1:]
    acc, var = bridge_accelerations(bridged, replace(settings().measurement, linear_acceleration_std_mps2=SIGMA_A))
    gyro = bridge_angular_accelerations(bridged)
    assert gyro is not None
    u_model, bridged_mask, variance, offset = lost_input_model(
        t, u, links, np.r_[TRUTH.mass_kg, THETA_TRUE[1:4]], bridge_acceleration=acc, bridge_acceleration_variance=var,
        gyro=gyro)
    gaps = np.flatnonzero(bridged_mask)
    assert gaps.size >= 15 and np.all(u_model[gaps] == 0.0)
    np.testing.assert_allclose(variance[gaps, 3:6], gyro.variance[gaps, None] * THETA_TRUE[1:4] ** 2)
    xs = _true_states(tel, delivered, t)
    fx = propagate_intervals(xs[:-1], u_model[:-1], THETA_TRUE, substep_schedule(t[:-1], t[1:], 1.0 / 62.5))[0]
    e = boxminus(xs[1:], fx) - offset
    dt = np.diff(t)[gaps, None]
    sd_alpha = np.sqrt(gyro.variance[gaps])[:, None]
    z_w = e[gaps, 9:12] / (dt * sd_alpha)
    assert np.all(np.abs(z_w) < 4.5) and 0.7 < math.sqrt(np.mean(z_w**2)) < 1.3
    # The attitude's error is the same slope error times ½T² (with the body frame's turn ``(T³/6) ω × ᾱ`` in the
    # offset, the neglected terms -- the gyroscopic term's change, the rate's error in that turn -- stay below a
    # twentieth of its standard deviation ½T² σ_ᾱ; without the turn, up to 5e-6 rad: a sixth).
    assert np.all(np.abs(e[gaps, 6:9] - 0.5 * dt * e[gaps, 9:12]) < 0.05 * 0.5 * dt**2 * sd_alpha)
    z_v = e[gaps, 3:6] / (dt * np.sqrt(variance[gaps, 0:3]))
    assert np.all(np.abs(z_v) < 4.5)
    assert np.max(np.abs(e[np.flatnonzero(links)])) < 1e-9  # known inputs: the model is exact


def test_both_estimators_take_the_lost_torque_from_the_gyro():
    """Batch and filter on a gapped run with the IMU: with the gyro's bridge the inertias are better determined
    than with the torque predicted from the neighbours (accelerometer bridge only), and the estimates stay
    within 2σ of the clean run's; the filter bridges every gap after its bootstrap with the gyro, counted once in
    ``gaps_bridged_imu``."""
    tel, _, _, _, bridged = _flight(0, 150)
    no_gyro = [replace(r, angular_acceleration_radps2=None, angular_acceleration_var_rad2ps4=None) for r in bridged]
    imu_settings = settings(measurement=replace(settings().measurement, linear_acceleration_std_mps2=SIGMA_A))
    wide = replace(RATTLE_PRIOR, covariance=RATTLE_PRIOR.covariance * 1e8)
    clean = estimate_batch(records(tel), settings(), wide)
    with_gyro = estimate_batch(bridged, imu_settings, wide)
    without = estimate_batch(no_gyro, imu_settings, wide)
    assert with_gyro.converged  # (the fit without the gyro bridge stops short of converging on this run)
    sd_with, sd_without = with_gyro.estimate.std, without.estimate.std
    assert np.all(sd_with[1:4] < 0.9 * sd_without[1:4]), (sd_with, sd_without)
    assert np.all(np.abs(with_gyro.estimate.theta - clean.estimate.theta) <= 2.0 * sd_with)

    filt = SequentialEstimator(imu_settings, RATTLE_PRIOR, bootstrap_max_records=40)
    for rec in bridged:
        filt.update(rec)
    filt.flush()
    after_bootstrap = sum(r.starts_segment for r in bridged[filt.bootstrap_records:])
    assert after_bootstrap >= 10
    assert filt.gaps_bridged == filt.gaps_bridged_imu == filt.gaps_bridged_gyro == after_bootstrap
    assert filt.segments == 0 and filt.reinitialisations == 0
    assert np.all(filt.estimate.std[1:4] < 0.9 * sd_without[1:4])  # the filter's posterior is the batch's
    assert np.all(np.abs(filt.estimate.theta - clean.estimate.theta) <= 2.0 * filt.estimate.std)


def test_the_process_jacobian_with_a_gap_offset_matches_finite_differences():
    """With a gyro bridge the gap offset reaches the attitude rows (``½T² J⁻¹τ``, ~1e-3 rad); the residual is
    ``(x_{k+1} ⊟ f) − offset`` with a constant offset, so its Jacobian is that of ``⊟`` at ``⊟``'s own value.
    Checked against central differences (reference path, :meth:`BatchProblem.evaluate`) and the blocks of the fast
    path's ``AᵀA`` and ``Aᵀb`` against the reference's (an offset of 0.02 rad makes the difference visible)."""
    tel = simulate_open_loop(6, seed=3)
    problem = BatchProblem(records(tel), settings(process=ProcessNoise(0.01, 0.001)), RATTLE_PRIOR, THETA_TRUE)
    rng = np.random.default_rng(5)
    problem.gap_offset = np.zeros_like(problem.gap_offset)  # (set on a linked interval: every row is whitened)
    problem.gap_offset[2] = rng.normal(0.0, 0.02, 12)
    x = boxplus(problem.y, rng.normal(0, 0.05, (6, 12)))
    phi = par.phi_from_theta(np.array([12.0, 0.12, 0.15, 0.17]))
    inliers = np.ones(6, dtype=bool)
    b, a_dense = dense_jacobian_matching_central_differences(problem, x, phi, inliers)
    _, normal = problem.normal_equations(x, phi, inliers)
    ata, atb = a_dense.T @ a_dense, a_dense.T @ b
    for i in range(6):
        blk = slice(12 * i, 12 * i + 12)
        np.testing.assert_allclose(normal.hd[i], ata[blk, blk], rtol=1e-8, atol=1e-8 * np.abs(ata).max())
        np.testing.assert_allclose(normal.gx[i], atb[blk], rtol=1e-8, atol=1e-8 * np.abs(atb).max())
