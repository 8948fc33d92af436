"""The full rigid body in the batch estimator: exact Jacobians, physical φ, recovery, the 4-parameter case.

θ = mass, inertia tensor with products, centre-of-mass offset, force and torque scale per body axis
(oacli.estimation.rigid_parameters, rigid_dynamics, batch_model).
"""

from __future__ import annotations

import numpy as np
import pytest
from estimation_helpers import (
    CONTROL_PERIOD_S,
    PLANT_PERIOD_S,
    SENSORS,
    Playback,
    exciting_inputs,
    initial_state,
    records,
    settings,
    simulate_open_loop,
)

from oacli.config import config_from_dict
from oacli.errors import ConfigError
from oacli.estimation.batch import estimate_batch
from oacli.estimation.batch_model import FullModel, full_prior
from oacli.estimation.manifold import boxplus, lift_matrix
from oacli.estimation.propagation import propagate_intervals_structured, substep_schedule
from oacli.estimation.rigid_dynamics import accelerations_full, propagate_full, propagate_full_one
from oacli.estimation.rigid_parameters import (
    FULL_NAMES,
    ParameterSet,
    inertia_tensor,
    is_physical_full,
    phi_from_theta_full,
    theta_from_phi_full,
    theta_jacobian_full,
)
from oacli.sim.sensors import Disturbance
from oacli.sim.simulator import simulate
from oacli.types import InertialParams, ParameterEstimate

TRUTH = np.array([15.0, 0.1464, 0.1376, 0.1604, 0.004, -0.003, 0.002, 0.0037, -0.0003, -0.0025,
                  1.03, 0.97, 1.02, 0.98, 1.01, 1.0])
PRIOR = ParameterEstimate(0.0, [14.0, 0.15, 0.15, 0.15], np.diag([1.0, 4e-4, 4e-4, 4e-4]), "prior")
EXTRA_MEAN = np.r_[np.zeros(6), np.ones(6)]
EXTRA_STD = np.r_[np.full(3, 0.01), np.full(3, 0.01), np.full(6, 0.05)]
ALL = ("mass", "inertia", "products", "com", "force_scale", "torque_scale")


def _model(groups=ALL) -> FullModel:
    mean, cov = full_prior(PRIOR.theta, PRIOR.covariance, EXTRA_MEAN, EXTRA_STD)
    return FullModel(ParameterSet.build(groups, mean), mean, cov)


def _random_intervals(k: int = 4):
    rng = np.random.default_rng(0)
    x = np.c_[rng.normal(size=(k, 3)), 0.05 * rng.normal(size=(k, 3)), rng.normal(size=(k, 4)),
              0.1 * rng.normal(size=(k, 3))]
    x[:, 6:10] /= np.linalg.norm(x[:, 6:10], axis=1)[:, None]
    u = np.c_[0.2 * rng.normal(size=(k, 3)), 0.02 * rng.normal(size=(k, 3))]
    t0 = 0.2 * np.arange(k) + 0.003
    return x, u, substep_schedule(t0, t0 + 0.2, PLANT_PERIOD_S)


def test_process_model_jacobians_equal_central_differences():
    """∂f/∂x (on the state tangent) and ∂f/∂θ of the full model's RK4 sub-steps (held wrench at each sub-step's
    attitude, quaternion renormalisation), and of the continuous accelerations, against central differences."""
    x, u, dur = _random_intervals()
    _, a, c = propagate_full(x, u, TRUTH, dur)
    eps = 1e-6
    for i in range(16):
        tp, tm = TRUTH.copy(), TRUTH.copy()
        tp[i] += eps
        tm[i] -= eps
        fd = (propagate_full(x, u, tp, dur, jacobians=False)[0] - propagate_full(x, u, tm, dur, jacobians=False)[0])
        np.testing.assert_allclose(c[:, :, i], fd / (2 * eps), atol=2e-9)
        acc_fd = (accelerations_full(x, u, tp)[0] - accelerations_full(x, u, tm)[0]) / (2 * eps)
        np.testing.assert_allclose(accelerations_full(x, u, TRUTH)[2][:, :, i], acc_fd, atol=2e-9)
    lifted = a @ lift_matrix(x)
    acc_lifted = accelerations_full(x, u, TRUTH)[1] @ lift_matrix(x)
    for i in range(12):
        d = np.zeros((x.shape[0], 12))
        d[:, i] = eps
        fd = (propagate_full(boxplus(x, d), u, TRUTH, dur, jacobians=False)[0]
              - propagate_full(boxplus(x, -d), u, TRUTH, dur, jacobians=False)[0]) / (2 * eps)
        np.testing.assert_allclose(lifted[:, :, i], fd, atol=2e-9)
        acc_fd = (accelerations_full(boxplus(x, d), u, TRUTH)[0] - accelerations_full(boxplus(x, -d), u, TRUTH)[0])
        np.testing.assert_allclose(acc_lifted[:, :, i], acc_fd / (2 * eps), atol=2e-9)


def test_process_model_is_the_simulators_plant():
    """Noise-free: the full model over one control period reaches the simulator's state (body-axis force scale,
    CoM torque, full inertia tensor); its single-interval path equals the batched one; it reduces to the
    4-parameter structured propagation for the ideal body."""
    x, u, dur = _random_intervals(1)
    tel = simulate(Playback(np.tile(u, (2, 1))), x[0], InertialParams(TRUTH[0], TRUTH[1:4]), duration_s=0.2,
                   control_period_s=0.2, plant_period_s=PLANT_PERIOD_S, input_limits=np.full(6, 10.0),
                   sensors=type(SENSORS)(), disturbance=Disturbance.none(), rng=np.random.default_rng(0),
                   actuator_scale=TRUTH[10:16], com_offset_m=TRUTH[7:10], inertia_tensor_kgm2=inertia_tensor(TRUTH))
    dur0 = substep_schedule(np.array([0.0]), np.array([0.2]), PLANT_PERIOD_S)
    np.testing.assert_allclose(propagate_full(x, u, TRUTH, dur0, jacobians=False)[0][0], tel.x_true[-1],
                               atol=1e-13)
    for k in range(x.shape[0]):  # the single-interval path (a filter step) is the same map
        one = propagate_full_one(x[k], u[k], TRUTH, dur[k])
        batched = propagate_full(x[k:k + 1], u[k:k + 1], TRUTH, dur[k:k + 1])
        for got, want in zip(one, batched, strict=True):
            np.testing.assert_allclose(got, want[0], atol=1e-14)
    ideal = np.r_[TRUTH[:4], EXTRA_MEAN]
    full = propagate_full(x, u, ideal, dur)
    legacy = propagate_intervals_structured(x, u, TRUTH[:4], dur)
    np.testing.assert_allclose(full[0], legacy[0], atol=1e-15)
    np.testing.assert_allclose(full[2][:, :, 0:4], legacy[2], atol=1e-14)


def test_parametrisation_is_physical_and_its_jacobian_exact():
    """Every φ (also hostile: huge, tiny) maps to a mass > 0 and an inertia tensor whose Σ = tr(J)/2 − J is
    positive definite (Wensing 2017's pseudo-inertia ≻ 0: principal moments satisfy the triangle inequalities);
    θ → φ → θ round-trips; dθ/dφ equals central differences."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        phi = rng.normal(scale=6.0, size=16)
        theta = theta_from_phi_full(phi)
        assert is_physical_full(theta)
        moments = np.linalg.eigvalsh(inertia_tensor(theta))
        assert moments[0] > 0 and moments[0] + moments[1] >= moments[2] * (1 - 1e-9)
    phi = phi_from_theta_full(TRUTH)
    np.testing.assert_allclose(theta_from_phi_full(phi), TRUTH, rtol=1e-14, atol=1e-16)
    jac = theta_jacobian_full(phi)
    for i in range(16):
        d = np.zeros(16)
        d[i] = 1e-6
        np.testing.assert_allclose(jac[:, i], (theta_from_phi_full(phi + d) - theta_from_phi_full(phi - d)) / 2e-6,
                                   atol=1e-8)
    with pytest.raises(ValueError, match="not physical"):
        phi_from_theta_full(np.r_[15.0, 0.1, 0.1, 0.3, np.zeros(6), np.ones(6)])  # 0.1 + 0.1 < 0.3


def test_reduced_four_parameter_case_equals_todays_estimate():
    """``parameters: [mass, inertia]`` through the full model's code (the 16-entry process model, ParameterSet)
    gives today's 4-parameter estimate and covariance (the same φ: log m, log A, log B, log C)."""
    recs = records(simulate_open_loop(60))
    legacy = estimate_batch(recs, settings(), PRIOR)
    mean, cov = full_prior(PRIOR.theta, PRIOR.covariance, EXTRA_MEAN, EXTRA_STD)
    params = ParameterSet.build(("mass", "inertia"), mean)
    assert params.is_legacy
    full = estimate_batch(recs, settings(), PRIOR, model=FullModel(params, mean, cov))
    np.testing.assert_allclose(full.estimate.theta, legacy.estimate.theta, rtol=1e-9)
    np.testing.assert_allclose(full.estimate.covariance, legacy.estimate.covariance, rtol=1e-6, atol=1e-15)
    assert full.iterations == legacy.iterations


@pytest.mark.slow
def test_recovers_com_products_and_scales_within_their_bound():
    """60 s of exciting open-loop data from a plant with products of inertia, a CoM offset and per-axis scale
    errors: the full model fits (χ² ratio near 1) and every one of the 16 parameters lies within 3σ of the truth,
    σ from [(AᵀA)⁻¹]_θθ (the Cramér-Rao bound of the linearised problem at the solution)."""
    n = 300
    tel = simulate(Playback(exciting_inputs(n, 7)), initial_state(), InertialParams(TRUTH[0], TRUTH[1:4]),
                   duration_s=n * CONTROL_PERIOD_S, control_period_s=CONTROL_PERIOD_S,
                   plant_period_s=PLANT_PERIOD_S, input_limits=np.full(6, 10.0), sensors=SENSORS,
                   disturbance=Disturbance.none(), rng=np.random.default_rng(0), actuator_scale=TRUTH[10:16],
                   com_offset_m=TRUTH[7:10], inertia_tensor_kgm2=inertia_tensor(TRUTH))
    recs = records(tel)
    legacy = estimate_batch(recs, settings(), PRIOR)
    assert legacy.chi2 / legacy.chi2_dof > 5.0  # the 4 parameters cannot explain this plant
    result = estimate_batch(recs, settings(), PRIOR, model=_model())
    assert 0.9 < result.chi2 / result.chi2_dof < 1.1
    std = np.sqrt(np.diag(result.covariance_full))
    z = (result.theta_full - TRUTH) / std
    assert np.all(np.abs(z) < 3.0), dict(zip(FULL_NAMES, np.round(z, 2), strict=True))
    assert std[7:10].max() < 5e-4 and std[4:7].max() < 2e-4  # CoM to 0.5 mm, products to 2e-4 kg·m²
    # The reported σ is the Cramér-Rao bound of the full model (bounds_full: initial state unknown, the prior of the
    # entries beyond m and I included) up to the prior's information on m and I and the small process noise.
    from oacli.estimation.bounds_full import cramer_rao_bound_full

    model = _model()
    bound = cramer_rao_bound_full(result.t, result.states, np.array([r.u_applied for r in recs]),
                                  result.theta_full, model, settings().measurement, PLANT_PERIOD_S)
    ratio = std[model.params.index] / bound.std
    assert np.all((ratio > 0.85) & (ratio < 1.15)), dict(zip(model.params.names, np.round(ratio, 3), strict=True))


def test_sequential_filter_with_the_full_rigid_body():
    """The sequential filter over all 16 parameters on 30 s of the plant with products, CoM offset and scale errors:
    its innovations fit their model (NIS ratio within 10 % of 1), no re-initialisation, every parameter within 3σ
    of the truth (σ from its posterior covariance); the 4-parameter filter's innovations on the same data do not."""
    from oacli.estimation.sequential import SequentialEstimator

    n = 150
    tel = simulate(Playback(exciting_inputs(n, 7)), initial_state(), InertialParams(TRUTH[0], TRUTH[1:4]),
                   duration_s=n * CONTROL_PERIOD_S, control_period_s=CONTROL_PERIOD_S,
                   plant_period_s=PLANT_PERIOD_S, input_limits=np.full(6, 10.0), sensors=SENSORS,
                   disturbance=Disturbance.none(), rng=np.random.default_rng(0), actuator_scale=TRUTH[10:16],
                   com_offset_m=TRUTH[7:10], inertia_tensor_kgm2=inertia_tensor(TRUTH))
    recs = records(tel)

    def run(model):
        est = SequentialEstimator(settings(), PRIOR, model=model, intermediate_estimates=False)
        for r in recs:
            est.update(r)
        est.flush()
        own = [s for s in est.history[est.bootstrap_records:] if s.status in ("accepted", "rejected") and s.dof]
        return est, float(np.mean([s.d2 / s.dof for s in own]))

    est, nis = run(_model())
    assert abs(nis - 1.0) < 0.1 and est.reinitialisations == 0
    theta, cov = est.full_estimate()
    z = (theta - TRUTH) / np.sqrt(np.diag(cov))
    assert np.all(np.abs(z) < 3.0), dict(zip(FULL_NAMES, np.round(z, 2), strict=True))
    assert run(None)[1] > 1.5


def test_hostile_data_still_gives_a_physical_estimate():
    """Inputs recorded with wrong signs and 3× too large torques, a mass axis scaled by 0.2 (a plant nothing like the
    model), 5 s only: every iterate is physical, so the estimate is (mass > 0, positive-definite inertia
    satisfying the triangle inequalities), and the reported 4-parameter covariance is a valid Gaussian (finite,
    the unidentified marker where the records do not determine θ)."""
    recs = records(simulate_open_loop(25))
    for r in recs:
        object.__setattr__(r, "u_applied", r.u_applied * np.r_[-1.0, 0.2, 1.0, 3.0, -3.0, 3.0])
    result = estimate_batch(recs, settings(max_iterations=10), PRIOR, model=_model())
    assert is_physical_full(result.theta_full)
    assert np.all(np.isfinite(result.estimate.covariance))
    assert np.all(np.isfinite(result.covariance_full)) or np.all(np.isinf(np.diag(result.covariance_full)))


@pytest.mark.parametrize(("value", "reason"), [
    (["mass", "inertia", "spin"], "parameters"),
    (["mass", "com"], "must include mass and inertia"),
    (["mass", "inertia", "com", "com"], "listed twice"),
])
def test_parameters_config_is_validated(value, reason):
    with pytest.raises(ConfigError, match=reason) as err:
        config_from_dict({"name": "x", "estimation": {"parameters": value}})
    assert "estimation.parameters" in str(err.value)  # names the field, not the whole section
