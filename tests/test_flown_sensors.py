"""Measurements as flown: the simulated IMU against closed form, localisation faults at their
configured rates, held inputs between control instants, and IMU-fed estimates against the Cramér-Rao bound."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from oacli.estimation.alignment import align_records
from oacli.estimation.imu import ImuStream, attach_accelerations, fit_accelerometer_bias
from oacli.sim.delivered import DeliveredInput
from oacli.sim.imu import ImuModel, simulate_imu
from oacli.sim.localisation import LocalisationModel, localisation_stamps, simulate_localisation
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.sim.substreams import sensor_rng
from oacli.stages.estimate import run_estimation
from oacli.types import InertialParams
from tests.estimation_helpers import (
    CONTROL_PERIOD_S,
    PLANT_PERIOD_S,
    RATTLE_PRIOR,
    THETA_TRUE,
    Playback,
    settings,
    simulate_open_loop,
)
from tests.estimation_helpers import MODEL as STATE_MODEL
from tests.model_helpers import mass_model

ACC_STD = math.sqrt(5e-6)  # rattle param_est R, linear acceleration (a variance)
YAW_90 = np.array([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])  # body x -> world y


def _open_loop(u: np.ndarray, x0: np.ndarray, n: int):
    return simulate(Playback(np.tile(u, (n, 1))), x0, InertialParams(THETA_TRUE[0], THETA_TRUE[1:4]),
                    duration_s=n * CONTROL_PERIOD_S, control_period_s=CONTROL_PERIOD_S,
                    plant_period_s=PLANT_PERIOD_S, input_limits=np.full(6, 10.0), sensors=SensorNoise(),
                    disturbance=Disturbance.none(), rng=np.random.default_rng(0))


def test_constant_force_gives_the_specific_force_f_over_m_in_the_body_frame():
    x0 = np.zeros(13)
    x0[6:10] = YAW_90
    tel = _open_loop(np.array([0.1, 0.0, 0.05, 0.0, 0.0, 0.0]), x0, 20)
    force = DeliveredInput.from_telemetry(tel).force_world(tel.t_true)
    imu = simulate_imu(tel.t_true, tel.x_true, force, mass_model(THETA_TRUE[0]).params, ImuModel(),
                       np.random.default_rng(1))
    # Yaw +90°: world x is body -y, world z is body z.
    expected = np.array([0.0, -0.1, 0.05]) / THETA_TRUE[0]
    np.testing.assert_allclose(imu.specific_force_mps2, np.tile(expected, (len(tel.t_true), 1)), atol=1e-12)
    assert len(imu.t) == len(tel.t_true) and np.allclose(np.diff(imu.t), PLANT_PERIOD_S)  # 62.5 Hz


def test_constant_spin_gives_the_rate_plus_a_constant_bias():
    x0 = np.zeros(13)
    x0[6:10] = [0.0, 0.0, 0.0, 1.0]
    x0[10:13] = [0.0, 0.0, 0.1]  # about a principal axis, no torque: ω stays constant
    tel = _open_loop(np.zeros(6), x0, 20)
    model = ImuModel(gyro_bias_std_radps=0.01, accelerometer_bias_std_mps2=0.002)
    imu = simulate_imu(tel.t_true, tel.x_true, np.zeros((len(tel.t_true), 3)), mass_model(THETA_TRUE[0]).params, model,
                       np.random.default_rng(2))
    bias = imu.gyro_bias_radps[0]
    assert np.all(np.abs(bias) > 1e-5)
    np.testing.assert_allclose(imu.angular_rate_radps, np.tile(np.array([0.0, 0.0, 0.1]) + bias, (len(tel.t_true), 1)),
                               atol=1e-12)
    np.testing.assert_allclose(imu.specific_force_mps2, np.tile(imu.accelerometer_bias_mps2[0],
                                                                (len(tel.t_true), 1)), atol=1e-15)


def test_imu_noise_and_random_walk_have_their_configured_spread():
    n = 20000
    t = np.arange(n) * PLANT_PERIOD_S
    x = np.zeros((n, 13))
    x[:, 9] = 1.0
    model = ImuModel(accelerometer_noise_std_mps2=ACC_STD, gyro_noise_std_radps=0.01,
                     accelerometer_bias_random_walk=1e-4)
    imu = simulate_imu(t, x, np.zeros((n, 3)), mass_model(10.0).params, model, np.random.default_rng(3))
    tol = 4.0 / math.sqrt(2 * 3 * n)  # relative std of a sample std over 3n values, 4 σ
    assert abs(np.std(imu.angular_rate_radps) / 0.01 - 1.0) < tol
    noise = imu.specific_force_mps2 - imu.accelerometer_bias_mps2
    assert abs(np.std(noise) / ACC_STD - 1.0) < tol
    steps = np.diff(imu.accelerometer_bias_mps2, axis=0)
    assert abs(np.std(steps) / (1e-4 * math.sqrt(PLANT_PERIOD_S)) - 1.0) < tol


def test_localisation_jumps_drops_and_delays_at_their_configured_rates():
    k = 6000
    stamps = localisation_stamps((k - 1) / 10.0, 10.0)
    assert stamps.size == k
    x = np.zeros((k, 13))
    x[:, 0] = stamps  # a position that identifies the stamp
    x[:, 9] = 1.0
    p_jump, p_drop, p_delay = 0.05, 0.1, 0.2
    model = LocalisationModel(rate_hz=10.0, noise=SensorNoise(), jump_probability=p_jump, drop_probability=p_drop,
                              delay_probability=p_delay, jump_position_m=(0.1, 0.3), delay_mean_s=0.5)
    msgs = simulate_localisation(stamps, x, model, np.random.default_rng(4))

    def within_binomial(count: int, n: int, p: float) -> bool:
        return abs(count - n * p) <= 4.0 * math.sqrt(n * p * (1 - p))

    eligible = k - 1  # the first message is always clean and on time
    assert within_binomial(msgs.jumped_s.size, eligible, p_jump)
    assert within_binomial(msgs.dropped_s.size, eligible, p_drop)
    assert within_binomial(msgs.delayed_s.size, eligible, p_delay * (1 - p_drop))
    # Delivered = generated − dropped, each stamp once; arrival times non-decreasing; delayed ones out of order.
    assert np.array_equal(np.sort(msgs.stamp_s), np.setdiff1d(stamps, msgs.dropped_s))
    assert np.all(np.diff(msgs.arrival_s) >= 0)
    delayed = np.isin(msgs.stamp_s, msgs.delayed_s)
    assert np.all(msgs.arrival_s[~delayed] == msgs.stamp_s[~delayed])
    delay = msgs.arrival_s[delayed] - msgs.stamp_s[delayed]
    assert abs(delay.mean() / 0.5 - 1.0) < 4.0 / math.sqrt(delay.size)  # exponential: std = mean
    assert msgs.counts()["out_of_order"] > 0
    # Jumps: position moved by a magnitude in the configured range; the others untouched (no noise configured).
    jumped = np.isin(msgs.stamp_s, msgs.jumped_s)
    dp = np.linalg.norm(msgs.x[:, 0:3] - np.column_stack([msgs.stamp_s, np.zeros((msgs.stamp_s.size, 2))]), axis=1)
    assert np.all((dp[jumped] >= 0.1 - 1e-12) & (dp[jumped] <= 0.3 + 1e-12)) and np.all(dp[~jumped] < 1e-12)


def test_sensor_substreams_are_independent_of_the_closed_loop_and_of_each_other():
    a = sensor_rng(5, "imu").standard_normal(4)
    assert np.array_equal(a, sensor_rng(5, "imu").standard_normal(4))
    assert not np.array_equal(a, sensor_rng(5, "localisation").standard_normal(4))
    assert not np.array_equal(a, np.random.default_rng(5).standard_normal(4))


def test_measurements_between_control_instants_get_the_held_input():
    t_in = np.arange(6) * 0.2
    u = np.arange(36, dtype=float).reshape(6, 6)
    x = np.tile(np.r_[np.zeros(6), 0, 0, 0, 1, np.zeros(3)], (11, 1))
    t_meas = np.arange(11) * 0.1  # twice the control rate
    keep = np.ones(6, dtype=bool)
    keep[3] = False  # the input of 0.6 s is lost: 0.6 and 0.7 s cannot be held from 0.4 s
    records, report = align_records(t_meas, x, t_in[keep], u[keep], reorder_window=0)
    by_t = {round(r.t, 6): r for r in records}
    np.testing.assert_array_equal(by_t[0.1].u_applied, u[0])
    np.testing.assert_array_equal(by_t[0.5].u_applied, u[2])
    assert by_t[0.8].starts_segment  # after the unknown input of 0.6-0.8 s
    # held: 0.1, 0.3, 0.5 and 0.9; 0.6 and 0.7 have no known input, so 0.7 and 0.8 each start a segment
    assert report.held == 4 and report.gaps == 2 and by_t[0.7].starts_segment


def _imu_fed_errors(seed: int, n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    tel = simulate_open_loop(n, seed=seed)
    force = DeliveredInput.from_telemetry(tel).force_world(tel.t_true)
    model = ImuModel(accelerometer_noise_std_mps2=ACC_STD, accelerometer_bias_std_mps2=1e-3)
    imu = simulate_imu(tel.t_true, tel.x_true, force, mass_model(THETA_TRUE[0]).params, model, sensor_rng(seed, "imu"))
    records, _ = align_records(tel.t_ctrl, tel.x_measured, tel.t_ctrl, tel.u_applied, reorder_window=0)
    stream = ImuStream(imu.t, imu.specific_force_mps2, imu.angular_rate_radps)
    fit = fit_accelerometer_bias(records, stream, tel.t_ctrl, CONTROL_PERIOD_S)
    assert fit is not None
    records, missing = attach_accelerations(records, stream, fit.bias_mps2, tel.t_ctrl, CONTROL_PERIOD_S)
    assert missing == 0
    measurement = type(STATE_MODEL)(**{**STATE_MODEL.__dict__, "linear_acceleration_std_mps2": ACC_STD})
    run = run_estimation(records, settings(measurement=measurement), RATTLE_PRIOR, "batch", window_s=1e6)
    return run.final.theta - THETA_TRUE, run.bound.std


def _check_spread(seeds: range) -> None:
    z = np.array([err / crb for err, crb in (_imu_fed_errors(s) for s in seeds)])  # (seeds, 4)
    n = z.shape[0]
    # Spread ≤ 1.2 × CRB within sampling tolerance: Σ z² / (1.2²) is χ²(n) under the target; refuse above 99.9 %.
    limit = 1.2**2 * stats.chi2.ppf(0.999, n) / n
    assert np.all(np.mean(z**2, axis=0) <= limit), np.sqrt(np.mean(z**2, axis=0))


def test_imu_fed_estimates_against_the_cramer_rao_bound_fast():
    _check_spread(range(6))


@pytest.mark.slow
def test_imu_fed_estimates_against_the_cramer_rao_bound_over_many_seeds():
    _check_spread(range(40))
