"""The flight's RLS for the full rigid body (oacli.estimation.rls_full): the model against the estimators' dynamics,
the reduced case against today's RLS, recovery of a known CoM and products within 3σ with σ at the Cramér-Rao bound,
and physical consistency under hostile data."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.estimation.rigid_dynamics import accelerations_full
from oacli.estimation.rigid_parameters import is_physical_full
from oacli.estimation.rls import AccelerationSamples, RlsEstimator
from oacli.estimation.rls_full import RlsFullEstimator, _theta_jacobian, full_acceleration_model
from oacli.types import ParameterEstimate

# Astrobee with a payload, products and the ISS config's measured CoM offset (astrobee iss.config).
TRUTH = np.r_[15.0, 0.1464, 0.1376, 0.1604, 0.0031, -0.0018, 0.0024, 0.0037, -0.0003, -0.0025, 1.03, 0.97, 1.02,
              0.98, 1.02, 1.0]
PRIOR_MEAN = np.r_[9.583788668, 0.153427995, 0.14271405, 0.162302759, np.zeros(6), TRUTH[10:16]]
PRIOR_COV = np.diag(np.r_[15.0, 0.005, 0.005, 0.005, np.full(3, 0.005**2), np.full(3, 0.01**2), np.full(6, 1e-6)])


def _psi(theta: np.ndarray) -> np.ndarray:
    j = np.array([[theta[1], theta[4], theta[5]], [theta[4], theta[2], theta[6]], [theta[5], theta[6], theta[3]]])
    k = np.linalg.inv(j)
    return np.r_[1 / theta[0], k[0, 0], k[1, 1], k[2, 2], k[0, 1], k[0, 2], k[1, 2], theta[7:10]]


def synthetic(rng: np.random.Generator, n: int, theta: np.ndarray = TRUTH, acc_std: float = 2e-3,
              alpha_std: float = 5e-3) -> AccelerationSamples:
    """Samples of the estimators' own dynamics (oacli.estimation.rigid_dynamics, body frame: attitude identity)."""
    force = rng.uniform(-0.25, 0.25, (n, 3))
    torque = rng.uniform(-0.025, 0.025, (n, 3))
    rate = rng.uniform(-0.15, 0.15, (n, 3))
    x = np.zeros((n, 13))
    x[:, 9] = 1.0
    x[:, 10:13] = rate
    acc = accelerations_full(x, np.c_[force, torque], theta)[0]
    acc = acc + rng.normal(size=acc.shape) * np.r_[[acc_std] * 3, [alpha_std] * 3]
    return AccelerationSamples(np.arange(n) * 0.2, acc[:, 0:3], acc[:, 3:6], force, torque, rate,
                               np.full(n, acc_std), np.full(n, alpha_std))


def test_model_is_the_estimators_dynamics_and_its_jacobian_exact() -> None:
    rng = np.random.default_rng(1)
    force, torque, rate = rng.normal(size=3) * 0.2, rng.normal(size=3) * 0.02, rng.normal(size=3) * 0.3
    x = np.r_[np.zeros(9), 1.0, rate][None]
    ref = accelerations_full(x, np.r_[force, torque][None], TRUTH)[0][0]
    psi = _psi(TRUTH)
    f_cal, t_cal = TRUTH[10:13] * force, TRUTH[13:16] * torque
    h, jac = full_acceleration_model(psi, f_cal, t_cal, rate)
    np.testing.assert_allclose(h, ref, rtol=1e-12, atol=1e-15)
    for i in range(10):
        step = np.zeros(10)
        step[i] = 1e-6 * max(abs(psi[i]), 1e-3)
        up = full_acceleration_model(psi + step, f_cal, t_cal, rate)[0]
        down = full_acceleration_model(psi - step, f_cal, t_cal, rate)[0]
        np.testing.assert_allclose(jac[:, i], (up - down) / (2 * step[i]), rtol=1e-6, atol=1e-7)


def test_reduced_case_equals_todays_rls() -> None:
    rng = np.random.default_rng(2)
    theta4 = TRUTH[:4]
    samples = synthetic(rng, 300, np.r_[theta4, np.zeros(6), np.ones(6)])
    prior4 = ParameterEstimate(0.0, PRIOR_MEAN[:4], PRIOR_COV[:4, :4], "prior")
    old = RlsEstimator(prior4, gate_probability=0.99).run(samples)
    mean = np.r_[PRIOR_MEAN[:4], np.zeros(6), np.ones(6)]
    new = RlsFullEstimator(mean, PRIOR_COV, ("mass", "inertia"), gate_probability=0.99).run(samples)
    np.testing.assert_allclose(new.theta[:4], old.theta, rtol=1e-12)
    np.testing.assert_allclose(new.covariance, old.covariance, rtol=1e-9, atol=1e-20)
    assert (new.samples_used, new.samples_rejected) == (old.samples_used, old.samples_rejected)
    assert new.parameter_estimate().method == "rls"


def test_recovers_com_and_products_within_3_sigma_at_the_bound() -> None:
    rng = np.random.default_rng(3)
    samples = synthetic(rng, 3000)
    est = RlsFullEstimator(PRIOR_MEAN, PRIOR_COV, gate_probability=0.99).run(samples)
    assert est.physical and est.triangle_margin > 0 and est.infeasible == 0
    assert est.names[7:10] == ("com_x_m", "com_y_m", "com_z_m")
    z = (est.theta[est.index] - TRUTH[est.index]) / est.std
    assert np.all(np.abs(z) <= 3.0), dict(zip(est.names, np.round(z, 2), strict=True))
    assert np.all(np.abs(est.theta[7:10] - TRUTH[7:10]) < 5e-4)  # CoM to half a millimetre
    # The Cramér-Rao bound of this regression at the truth: (Σ Hᵀ R⁻¹ H + P₀⁻¹)⁻¹ in ψ, mapped to θ.
    psi = _psi(TRUTH)
    info = np.zeros((10, 10))
    for k in range(len(samples)):
        _, h = full_acceleration_model(psi, TRUTH[10:13] * samples.force_N[k], TRUTH[13:16] * samples.torque_Nm[k],
                                       samples.rate_radps[k])
        w = 1.0 / np.r_[np.full(3, samples.accel_std_mps2[k]), np.full(3, samples.alpha_std_radps2[k])]
        info += (h * w[:, None]).T @ (h * w[:, None])
    t_jac = _theta_jacobian(psi)
    crb = np.sqrt(np.diag(t_jac @ np.linalg.inv(info) @ t_jac.T))  # data alone: the prior adds little here
    ratio = est.std / crb
    assert np.all((ratio > 0.8) & (ratio < 1.05)), np.round(ratio, 3)


def test_hostile_data_keeps_the_estimate_physical_and_says_so() -> None:
    rng = np.random.default_rng(4)
    samples = synthetic(rng, 400)
    # Angular accelerations of an 'inertia' that breaks the triangle inequality (Izz > Ixx + Iyy), no gate.
    bad = TRUTH.copy()
    bad[1:7] = [0.02, 0.02, 0.2, 0.0, 0.0, 0.0]
    assert not is_physical_full(bad)
    x = np.zeros((len(samples), 13))
    x[:, 9] = 1.0
    x[:, 10:13] = samples.rate_radps
    alpha = accelerations_full(x, np.c_[samples.force_N, samples.torque_Nm], bad)[0][:, 3:6]
    hostile = AccelerationSamples(samples.t, samples.accel_mps2, -3.0 * alpha, samples.force_N, samples.torque_Nm,
                                  samples.rate_radps, samples.accel_std_mps2, samples.alpha_std_radps2)
    est = RlsFullEstimator(PRIOR_MEAN, PRIOR_COV, gate_probability=None).run(hostile)
    assert est.infeasible > 0
    assert est.physical and est.triangle_margin > 0 and is_physical_full(est.theta)
    assert np.all(np.linalg.eigvalsh(est.covariance) > 0)
    with pytest.raises(ValueError, match="not physical"):
        RlsFullEstimator(bad, PRIOR_COV)
    with pytest.raises(ValueError, match="calibrate"):
        RlsFullEstimator(PRIOR_MEAN, PRIOR_COV, ("mass", "inertia", "force_scale"))


@pytest.mark.slow
def test_cli_rls_full_body_recovers_the_com(tmp_path) -> None:
    """`oacli estimate` with rls.full_body on a track of a payload with a CoM offset, flown with the flight's IMU."""
    import json

    import yaml
    from typer.testing import CliRunner

    from oacli.cli import app
    from tests.test_rls_estimator import _flight_sensors_config

    cfg = _flight_sensors_config(tmp_path / "imu.yaml", linear_acceleration=True)
    data = yaml.safe_load(cfg.read_text())
    data["truth"]["com_offset_m"] = [0.0037, -0.0003, -0.0025]
    data["estimation"]["parameters"] = ["mass", "inertia", "com"]
    data["estimation"]["rls"] = {"full_body": True}
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    runner = CliRunner()
    result = runner.invoke(app, ["track", str(cfg), "--out", str(tmp_path / "track"), "--quiet"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["estimate", str(cfg), "--telemetry", str(tmp_path / "track" / "track.mcap"),
                                 "--out", str(tmp_path / "rls"), "--quiet"])
    assert result.exit_code == 0, result.output
    s = json.loads((tmp_path / "rls" / "summary.json").read_text())
    assert s["method"] == "rls"
    full = s["rls_full"]
    assert full["groups"] == ["mass", "inertia", "com"] and full["physical"] and full["triangle_margin_kgm2"] > 0
    for i, axis in enumerate("xyz"):
        name = f"com_{axis}_m"
        err = full["theta"][name] - data["truth"]["com_offset_m"][i]
        assert abs(err) < 3 * full["std"][name] + 1e-4, (name, err, full["std"][name])
    rb = s["rigid_body"]  # the run's full estimate feeds the rigid-body section like the batch's
    assert rb["parameters"] == ["mass", "inertia", "com"]
    assert rb["estimate"]["com_x_m"] == pytest.approx(full["theta"]["com_x_m"], rel=1e-12)
    # With the scales in the groups the method refuses by name.
    data["estimation"]["parameters"] = ["mass", "inertia", "force_scale"]
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    result = runner.invoke(app, ["estimate", str(cfg), "--telemetry", str(tmp_path / "track" / "track.mcap"),
                                 "--out", str(tmp_path / "rls2"), "--quiet"])
    assert result.exit_code == 2 and "estimation.parameters" in result.output
