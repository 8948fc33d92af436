"""The flight's recursive least squares on accelerations ([ReSWARM2023] §4.4.1, §6.2.1): closed forms, a cross-check
against scipy's nonlinear least squares, honest σ, the χ² gate, the force-scale calibration, and ``oacli estimate
--method rls`` end to end with the flight's IMU."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from scipy.optimize import least_squares
from typer.testing import CliRunner

from oacli.cli import app
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.models import Measurement
from oacli.estimation.rls import (
    AccelerationSamples,
    RlsEstimator,
    acceleration_model,
    acceleration_samples,
    calibrate_force_scale,
)
from oacli.io.mcap_io import read_stage
from oacli.types import InertialParams, ParameterEstimate
from tests.conftest import REPO
from tests.test_cli_estimate import payload_config

THETA = np.array([15.0, 0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1: Astrobee with the printed object
PRIOR = ParameterEstimate(0.0, np.array([9.583788668, 0.153427995, 0.14271405, 0.162302759]),
                          np.diag([15.0, 0.005, 0.005, 0.005]), "prior")  # RATTLE's flight prior variances
NAMES = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")


def synthetic(rng: np.random.Generator, n: int, theta: np.ndarray = THETA, scale: np.ndarray | None = None,
              acc_std: float = 2e-3, alpha_std: float = 5e-3, noise: bool = True) -> AccelerationSamples:
    """Samples of the model itself with Astrobee-sized wrenches and rates (body frame)."""
    force = rng.uniform(-0.25, 0.25, (n, 3))
    torque = rng.uniform(-0.025, 0.025, (n, 3))
    rate = rng.uniform(-0.15, 0.15, (n, 3))
    h = np.array([acceleration_model(theta, force[k], torque[k], rate[k], scale)[0] for k in range(n)])
    if noise:
        h = h + rng.normal(size=h.shape) * np.r_[[acc_std] * 3, [alpha_std] * 3]
    return AccelerationSamples(np.arange(n) * 0.2, h[:, 0:3], h[:, 3:6], force, torque, rate,
                               np.full(n, acc_std), np.full(n, alpha_std))


def test_acceleration_model_jacobian_matches_central_differences(rng):
    force, torque, rate = rng.normal(size=3) * 0.2, rng.normal(size=3) * 0.02, rng.normal(size=3) * 0.3
    scale = np.array([1.1, 0.9, 1.05])
    _, jac = acceleration_model(THETA, force, torque, rate, scale)
    for j in range(4):
        step = np.zeros(4)
        step[j] = 1e-6 * THETA[j]
        up, _ = acceleration_model(THETA + step, force, torque, rate, scale)
        down, _ = acceleration_model(THETA - step, force, torque, rate, scale)
        np.testing.assert_allclose(jac[:, j], (up - down) / (2 * step[j]), rtol=1e-6, atol=1e-12)
    h, _ = acceleration_model(THETA, force, torque, rate, scale)
    inertia = np.diag(THETA[1:4])
    np.testing.assert_allclose(inertia @ h[3:6] + np.cross(rate, inertia @ rate), torque, atol=1e-15)  # Eq. 35b
    np.testing.assert_allclose(h[0:3] * THETA[0], scale * force, rtol=1e-15)  # Eq. 34b with κ


def test_noise_free_samples_recover_theta_from_the_flight_prior(rng):
    samples = synthetic(rng, 400, noise=False, acc_std=1e-6, alpha_std=1e-6)
    final = RlsEstimator(PRIOR).run(samples)
    np.testing.assert_allclose(final.theta, THETA, rtol=1e-6)


def test_rls_agrees_with_scipys_maximum_a_posteriori_estimate(rng):
    """On noisy samples the recursive estimate equals the batch MAP (scipy least_squares on the same residuals and
    the same prior, in ψ = 1/θ) to a small fraction of its σ, and its covariance equals the inverse Gauss-Newton
    information at the MAP."""
    samples = synthetic(rng, 1500)
    est = RlsEstimator(PRIOR, gate_probability=None)
    final = est.run(samples)
    psi0 = 1.0 / PRIOR.theta
    psi_std0 = np.sqrt(np.diag(PRIOR.covariance)) / PRIOR.theta**2
    sig = np.r_[samples.accel_std_mps2[0]] * np.ones(3), samples.alpha_std_radps2[0] * np.ones(3)
    weights = 1.0 / np.r_[sig[0], sig[1]]
    z = np.hstack([samples.accel_mps2, samples.alpha_radps2])

    def residuals(psi):
        theta = 1.0 / psi
        h = np.array([acceleration_model(theta, samples.force_N[k], samples.torque_Nm[k], samples.rate_radps[k])[0]
                      for k in range(len(samples))])
        return np.concatenate([((z - h) * weights).ravel(), (psi - psi0) / psi_std0])

    fit = least_squares(residuals, 1.0 / THETA, method="lm", xtol=1e-14, ftol=1e-14)
    theta_map = 1.0 / fit.x
    np.testing.assert_array_less(np.abs(final.theta - theta_map), 0.05 * final.std)
    cov_psi = np.linalg.inv(fit.jac.T @ fit.jac)
    d = np.diag(theta_map**2)
    std_map = np.sqrt(np.diag(d @ cov_psi @ d))
    np.testing.assert_allclose(final.std, std_map, rtol=0.02)
    assert est.samples_used == len(samples) and est.samples_rejected == 0


def test_reported_sigma_is_honest_over_seeds():
    """z = (θ̂ − θ)/σ over 80 independent runs: RMS near 1 for every parameter (an overconfident or a vague σ
    fails)."""
    z = []
    for seed in range(80):
        final = RlsEstimator(PRIOR, gate_probability=None).run(synthetic(np.random.default_rng(seed), 150))
        z.append((final.theta - THETA) / final.std)
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.8) & (rms < 1.25)), rms


def test_the_gate_rejects_a_jump_and_leaves_the_estimate_as_without_it(rng):
    samples = synthetic(rng, 300)
    clean = RlsEstimator(PRIOR)
    clean.run(samples)
    jumped = RlsEstimator(PRIOR)
    for k in range(len(samples)):
        alpha = samples.alpha_radps2[k] + (np.array([0.0, 0.0, 0.5]) if k == 200 else 0.0)  # 100σ jump
        jumped.update(samples.t[k], samples.accel_mps2[k], alpha, samples.force_N[k], samples.torque_Nm[k],
                      samples.rate_radps[k], samples.accel_std_mps2[k], samples.alpha_std_radps2[k])
    assert jumped.history[200].status == "rejected" and jumped.history[200].d2 > chi2_threshold(6, 0.99)
    clean_status = [s.status for s in clean.history]
    assert [s.status for s in jumped.history] == [*clean_status[:200], "rejected", *clean_status[201:]]
    if clean_status[200] == "accepted":  # then only that sample's update differs
        assert not np.allclose(jumped.estimate.theta, clean.estimate.theta, rtol=0, atol=0)
    d2 = np.array([s.d2 for s in clean.history[50:]])
    assert 5.3 < d2.mean() < 6.7  # χ² with 6 degrees of freedom: mean 6 ([ReSWARM2023] Eq. 41)


def test_an_update_that_leaves_the_physical_set_is_not_applied():
    vague = ParameterEstimate(0.0, PRIOR.theta, np.diag([1e6, 0.005, 0.005, 0.005]), "prior")
    est = RlsEstimator(vague, gate_probability=None)
    before = est.estimate.theta
    step = est.update(0.0, np.array([-1.0, 0.0, 0.0]), np.zeros(3), np.array([0.2, 0.0, 0.0]), np.zeros(3),
                      np.zeros(3), 1e-3, 1e-3)  # a = −5 F/m: a negative mass
    assert step.status == "infeasible" and est.infeasible == 1 and est.samples_used == 0
    np.testing.assert_array_equal(est.estimate.theta, before)


def test_force_scale_calibration_recovers_the_scale_within_its_standard_error():
    """[ReSWARM2023] Eqs. 38-39 on data of the known robot: κ̂ within 4 standard errors, and the standard errors
    honest over 150 seeds."""
    kappa = np.array([1.08, 0.95, 1.03])
    z = []
    for seed in range(150):
        samples = synthetic(np.random.default_rng(seed), 120, theta=PRIOR.theta, scale=kappa)
        fit = calibrate_force_scale(samples, InertialParams(PRIOR.theta[0], PRIOR.theta[1:4]))
        assert np.all(np.abs(fit.scale - kappa) < 4 * fit.std)
        z.append((fit.scale - kappa) / fit.std)
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.85) & (rms < 1.15)), rms
    with pytest.raises(ValueError, match="no force"):
        samples = synthetic(np.random.default_rng(0), 10)
        calibrate_force_scale(AccelerationSamples(*(
            getattr(samples, f) if f != "force_N" else np.zeros_like(samples.force_N)
            for f in samples.__dataclass_fields__)), InertialParams(9.6, PRIOR.theta[1:4]))


def test_samples_rotate_the_world_force_into_the_body_frame():
    """Records of a robot yawed by 90° under a constant world-frame force: the velocity difference gives exactly the
    body-frame acceleration ``Rᵀ F / m``; the rate difference gives ``α``."""
    m, dt = 10.0, 0.2
    q = np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])  # +90° about z: body x = world y
    force_world = np.array([0.1, 0.0, 0.0])
    recs = []
    for k in range(4):
        x = np.r_[np.zeros(3), force_world / m * dt * k, q, np.array([0.0, 0.0, 0.01 * k])]
        recs.append(Measurement(dt * k, x, np.r_[force_world, 0.0, 0.0, 0.001]))
    s = acceleration_samples(recs, 1e-3, 1e-3)
    assert len(s) == 3
    np.testing.assert_allclose(s.accel_mps2, np.tile([0.0, -0.01, 0.0], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(s.force_N, np.tile([0.0, -0.1, 0.0], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(s.alpha_radps2, np.tile([0.0, 0.0, 0.05], (3, 1)), atol=1e-12)
    np.testing.assert_allclose(s.accel_std_mps2, np.sqrt(2) * 1e-3 / dt)


def _flight_sensors_config(path, linear_acceleration: bool):
    """The test payload (15 kg, Table 1 inertias) flown with the flight's sensors: IMU on, localisation at 5 Hz
    without jumps (configs/iss_reswarm_flight_sensors.yaml)."""
    payload_config(path)
    data = yaml.safe_load(path.read_text())
    flight = yaml.safe_load((REPO / "configs" / "iss_reswarm_flight_sensors.yaml").read_text())
    data["sensors"] = flight["sensors"]
    data["sensors"]["localisation"]["jump_probability"] = 0.0
    noise = flight["estimation"]["measurement_noise"]
    if not linear_acceleration:
        noise["linear_acceleration_std_mps2"] = None
    data["estimation"]["measurement_noise"] = noise
    data["estimation"]["method"] = "rls"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_cli_rls_with_the_flight_imu_reports_the_rattle_table_columns(tmp_path):
    runner = CliRunner()
    cfg = _flight_sensors_config(tmp_path / "imu.yaml", linear_acceleration=True)
    result = runner.invoke(app, ["track", str(cfg), "--out", str(tmp_path / "track"), "--quiet"])
    assert result.exit_code == 0, result.output
    telemetry = tmp_path / "track" / "track.mcap"
    result = runner.invoke(app, ["estimate", str(cfg), "--telemetry", str(telemetry), "--out", str(tmp_path / "rls"),
                                 "--quiet"])
    assert result.exit_code == 0, result.output
    s = json.loads((tmp_path / "rls" / "summary.json").read_text())
    assert s["method"] == "rls" and s["status"] == "ok"
    assert s["rls_sources"] == {"linear_acceleration": "accelerometer", "angular_acceleration": "gyro slope"}
    estimate = [s["mass_kg"], *s["inertia_kgm2"]]
    for i, name in enumerate(NAMES):
        assert abs(estimate[i] - THETA[i]) < 4 * s["std"][name], name  # σ covers the error
        assert 90.0 < s["cov_reduction_pct"][name] < 100.0, name  # the flight table's column (99/68/49/25 %)
    assert 0.8 < s["nis_ratio"] < 1.25
    assert s["force_scale"] == [1.0, 1.0, 1.0] and s["infeasible_updates"] == 0
    assert s["flight_rattle_table"]["cov_reduction_pct"] == [99.0, 68.0, 49.0, 25.0]
    params = read_stage(tmp_path / "rls" / "estimate.mcap").json_records["/estimate/params"]
    assert params[-1]["method"] == "rls" and params[-1]["final"]
    assert abs(params[-1]["mass_kg"] - s["mass_kg"]) < 1e-12

    # Without the accelerometer the linear accelerations are localisation differences: biased in closed loop,
    # and the summary says so.
    cfg = _flight_sensors_config(tmp_path / "no_acc.yaml", linear_acceleration=False)
    result = runner.invoke(app, ["estimate", str(cfg), "--telemetry", str(telemetry), "--out",
                                 str(tmp_path / "rls-diff"), "--quiet"])
    assert result.exit_code == 0, result.output
    s = json.loads((tmp_path / "rls-diff" / "summary.json").read_text())
    assert s["rls_sources"]["linear_acceleration"] == "velocity finite difference"
    assert any("biased in closed loop" in w for w in s["warnings"])


def test_process_variance_is_added_in_theta_units():
    """A sample without any wrench or rate carries no information: θ stays and cov(θ) grows by exactly the
    configured random-walk variance (given in θ's units, mapped to ψ = 1/θ and back)."""
    q = np.array([0.5, 1e-4, 2e-4, 3e-4])
    est = RlsEstimator(PRIOR, gate_probability=None, process_variance=q)
    est.update(0.0, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), 1e-3, 1e-3)
    np.testing.assert_allclose(est.estimate.theta, PRIOR.theta, rtol=1e-15)
    np.testing.assert_allclose(np.diag(est.estimate.covariance), np.diag(PRIOR.covariance) + q, rtol=1e-12)
