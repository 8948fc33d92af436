"""Batch maximum-likelihood estimation ([Doerr2021] Eqs. 31-32): model, Jacobians, exactness, outliers, the CRB."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from oacli.estimation import parametrization as par
from oacli.estimation.batch import estimate_batch, estimate_batch_windows
from oacli.estimation.batch_problem import BatchProblem
from oacli.estimation.bounds import cramer_rao_bound
from oacli.estimation.manifold import (
    boxminus,
    boxplus,
    lift_matrix,
    project_matrix,
    so3_left_jacobian_inverse,
    so3_right_jacobian_inverse,
)
from oacli.estimation.models import Measurement, MeasurementModel, ProcessNoise
from oacli.estimation.propagation import (
    dynamics_batch,
    dynamics_jacobians_batch,
    propagate_intervals,
    substep_schedule,
)
from oacli.excitation.information import MeasurementModel as InfoModel
from oacli.excitation.information import fisher_information
from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb
from oacli.sim.faults import inject_localisation_jumps
from oacli.sim.sensors import SensorNoise
from tests.conftest import random_state
from tests.estimation_helpers import (
    MODEL,
    PLANT_PERIOD_S,
    RATTLE_PRIOR,
    THETA_TRUE,
    dense_jacobian_matching_central_differences,
    exciting_inputs,
    records,
    settings,
    simulate_open_loop,
)

# ---------------------------------------------------------------------------------------------------------------
# Manifold and parametrisation
# ---------------------------------------------------------------------------------------------------------------


def test_boxplus_and_boxminus_are_inverse(rng):
    for _ in range(20):
        x = random_state(rng)
        dx = rng.normal(0, 0.3, 12)
        np.testing.assert_allclose(boxminus(boxplus(x, dx), x), dx, atol=1e-12)
        y = random_state(rng)
        np.testing.assert_allclose(quat.angle_between(boxplus(x, boxminus(y, x))[6:10], y[6:10]), 0, atol=1e-9)


def test_inverse_so3_jacobians_match_finite_differences(rng):
    """∂ log(exp(e) exp(δ))/∂δ = J_r⁻¹(e) and ∂ log(exp(−δ) exp(e))/∂δ = −J_l⁻¹(e) (Sola et al. 2018)."""
    for _ in range(10):
        e = rng.normal(0, 0.8, 3)
        q = quat.exp(e)
        jr, jl = np.zeros((3, 3)), np.zeros((3, 3))
        h = 1e-6
        for i in range(3):
            d = np.zeros(3)
            d[i] = h
            jr[:, i] = (quat.log(quat.multiply(q, quat.exp(d))) - quat.log(quat.multiply(q, quat.exp(-d)))) / (2 * h)
            jl[:, i] = -(quat.log(quat.multiply(quat.exp(-d), q)) - quat.log(quat.multiply(quat.exp(d), q))) / (2 * h)
        np.testing.assert_allclose(so3_right_jacobian_inverse(e), jr, atol=1e-8)
        np.testing.assert_allclose(so3_left_jacobian_inverse(e), jl, atol=1e-8)


def test_lift_and_project_are_the_tangent_maps(rng):
    x = random_state(rng)
    x[6:10] = quat.normalize(x[6:10])  # w >= 0, the sign boxplus keeps
    np.testing.assert_allclose(project_matrix(x) @ lift_matrix(x), np.eye(12), atol=1e-12)
    dx = 1e-7 * rng.standard_normal(12)
    np.testing.assert_allclose(boxplus(x, dx) - x, lift_matrix(x) @ dx, atol=1e-13)


@given(st.lists(st.floats(-8, 3), min_size=4, max_size=4))
def test_every_phi_is_physical_and_round_trips(phi):
    theta = par.theta_from_phi(np.array(phi))
    assert par.is_physical(theta)
    np.testing.assert_allclose(par.phi_from_theta(theta), phi, atol=1e-9)


def test_parametrisation_jacobian_and_rejection_of_non_physical_theta():
    phi = par.phi_from_theta(THETA_TRUE)
    h = 1e-7
    fd = np.column_stack([(par.theta_from_phi(phi + h * e) - par.theta_from_phi(phi - h * e)) / (2 * h)
                          for e in np.eye(4)])
    np.testing.assert_allclose(par.theta_jacobian(phi), fd, rtol=1e-7)
    with pytest.raises(ValueError, match="not physical"):
        par.phi_from_theta(np.array([15.0, 0.1, 0.1, 0.25]))  # 0.1 + 0.1 < 0.25
    with pytest.raises(ValueError, match="not physical"):
        par.phi_from_theta(np.array([-1.0, 0.1, 0.1, 0.1]))


# ---------------------------------------------------------------------------------------------------------------
# Process model
# ---------------------------------------------------------------------------------------------------------------


def test_batched_dynamics_and_one_rk4_step_equal_rigid_body(rng):
    xs = np.array([random_state(rng) for _ in range(5)])
    us = rng.normal(0, 0.2, (5, 6))
    jac = dynamics_jacobians_batch(xs, us, THETA_TRUE)
    for k in range(5):
        np.testing.assert_allclose(dynamics_batch(xs, us, THETA_TRUE)[k], rb.dynamics(xs[k], us[k], THETA_TRUE))
        fx, _, ft = rb.dynamics_jacobians(xs[k], us[k], THETA_TRUE)
        np.testing.assert_allclose(jac[k, :, 0:13], fx, atol=1e-15)
        np.testing.assert_allclose(jac[k, :, 13:], ft, atol=1e-15)
        x1, a, _, c = rb.rk4_step_jacobians(xs[k], us[k], THETA_TRUE, 0.016)
        xb, ab, cb = propagate_intervals(xs[k][None], us[k][None], THETA_TRUE, np.array([[0.016]]), normalise=False)
        np.testing.assert_allclose(xb[0], x1, atol=1e-15)
        np.testing.assert_allclose(ab[0], a, atol=1e-14)
        np.testing.assert_allclose(cb[0], c, atol=1e-14)


def test_substep_schedule_follows_the_plant_grid():
    # 0.2 s control periods on the 0.016 s grid: [0, 0.2] has 12 full steps and a 0.008 s remainder, [0.2, 0.4]
    # starts with the other 0.008 s, and 0.4 s = 25 plant periods is a grid point.
    sched = substep_schedule(np.array([0.0, 0.2]), np.array([0.2, 0.4]), 0.016)
    np.testing.assert_allclose(sched.sum(axis=1), 0.2)
    assert (sched[0] > 0).sum() == 13 and (sched[1] > 0).sum() == 13
    np.testing.assert_allclose(sched[0, 12], 0.008, atol=1e-12)
    np.testing.assert_allclose(sched[1, 0], 0.008, atol=1e-12)


def test_process_model_reproduces_the_simulator_exactly():
    """The estimators' model of one control period equals the simulator's 62.5 Hz integration to rounding."""
    tel = simulate_open_loop(40, sensors=SensorNoise())  # noise-free: x_measured = true state at t_ctrl
    t = tel.t_ctrl
    x_next, _, _ = propagate_intervals(tel.x_measured[:-1], tel.u_applied[:-1], THETA_TRUE,
                                       substep_schedule(t[:-1], t[1:], PLANT_PERIOD_S))
    assert np.max(np.abs(boxminus(tel.x_measured[1:], x_next))) < 1e-13
    # One RK4 step per control period is only an approximation of the 12.5 plant steps.
    x_one, _, _ = propagate_intervals(tel.x_measured[:-1], tel.u_applied[:-1], THETA_TRUE, np.diff(t)[:, None])
    assert np.max(np.abs(boxminus(tel.x_measured[1:], x_one))) > 1e3 * np.max(
        np.abs(boxminus(tel.x_measured[1:], x_next)))


def test_interval_jacobians_match_finite_differences(rng):
    x0 = random_state(rng)
    u = rng.normal(0, 0.2, 6)
    sched = substep_schedule(np.array([0.1]), np.array([0.3]), PLANT_PERIOD_S)
    _, a, c = propagate_intervals(x0[None], u[None], THETA_TRUE, sched)
    h = 1e-6
    for i in range(12):
        d = np.zeros(12)
        d[i] = h
        xp, _, _ = propagate_intervals(boxplus(x0, d)[None], u[None], THETA_TRUE, sched)
        xm, _, _ = propagate_intervals(boxplus(x0, -d)[None], u[None], THETA_TRUE, sched)
        np.testing.assert_allclose((xp[0] - xm[0]) / (2 * h), (a[0] @ lift_matrix(x0))[:, i], atol=1e-7)
    for i in range(4):
        d = np.zeros(4)
        d[i] = h * THETA_TRUE[i]
        xp, _, _ = propagate_intervals(x0[None], u[None], THETA_TRUE + d, sched)
        xm, _, _ = propagate_intervals(x0[None], u[None], THETA_TRUE - d, sched)
        np.testing.assert_allclose((xp[0] - xm[0]) / (2 * d[i]), c[0][:, i], rtol=1e-5, atol=1e-9)


# ---------------------------------------------------------------------------------------------------------------
# The least-squares problem
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "model",
    [
        InfoModel(0.01, 0.002, 0.005, 0.01, linear_acceleration_std_mps2=0.003, angular_acceleration_std_radps2=0.01),
        InfoModel(None, 0.002, None, 0.01),  # velocities only: unmeasured offsets are tied by the gauge rows
    ],
    ids=["pose+velocity+accelerations", "velocities-only"],
)
def test_residual_jacobian_matches_finite_differences(rng, model):
    """A = ∂b/∂δϑ of every residual block (measurement, acceleration, process, gauge, prior) vs central
    differences, at a point away from the solution (large attitude residuals included)."""
    tel = simulate_open_loop(6, sensors=SensorNoise(0.01, 0.002, 0.005, 0.01), seed=3)
    acc = rng.normal(0, 0.01, (6, 3))
    recs = records(tel, linear_acceleration_mps2=acc, angular_acceleration_radps2=acc[::-1])
    problem = BatchProblem(recs, settings(measurement=model, process=ProcessNoise(0.01, 0.001)), RATTLE_PRIOR,
                       THETA_TRUE)
    x = boxplus(problem.y, rng.normal(0, 0.05, (6, 12)))
    phi = par.phi_from_theta(np.array([12.0, 0.12, 0.15, 0.17]))
    inliers = np.array([True, True, False, True, True, True])
    dense_jacobian_matching_central_differences(problem, x, phi, inliers)


def test_noise_free_data_recover_theta_exactly():
    """Without noise and without a prior the maximum-likelihood point is the truth, to rounding."""
    tel = simulate_open_loop(100, sensors=SensorNoise())
    result = estimate_batch(records(tel), settings(), None, initial_theta=RATTLE_PRIOR.theta)
    np.testing.assert_allclose(result.estimate.theta, THETA_TRUE, rtol=1e-9)
    assert result.converged and result.cost_history[-1] < 1e-12
    assert result.estimate.samples_rejected == 0 and result.iterations > 3  # it started 32 % off in Ixx


def test_a_trial_step_that_makes_the_model_singular_is_rejected_not_raised(monkeypatch):
    """A Levenberg-Marquardt trial step whose model evaluation raises ``LinAlgError`` (the full rigid body's
    inertia tensor singular at a wild θ: 2 of 16 runs of the payload-envelope campaign crashed on it) is rejected
    like an overflow: more damping, and the same maximum-likelihood point in the end."""
    import oacli.estimation.levenberg_marquardt as lm

    real = lm.linearise
    calls = {"n": 0}

    def singular_on_the_first_trial(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:  # 1: the starting point, 2: the first trial step
            raise np.linalg.LinAlgError("Singular matrix")
        return real(*args, **kwargs)

    monkeypatch.setattr(lm, "linearise", singular_on_the_first_trial)
    tel = simulate_open_loop(100, sensors=SensorNoise())
    result = estimate_batch(records(tel), settings(), None, initial_theta=RATTLE_PRIOR.theta)
    assert calls["n"] > 2
    np.testing.assert_allclose(result.estimate.theta, THETA_TRUE, rtol=1e-9)
    assert result.converged


def test_covariance_is_the_cramer_rao_bound_and_below_it_lies_information_py_bound():
    """(AᵀA)⁻¹ of a nearly rigid model is the Cramér-Rao bound with the initial state unknown; information.py's
    bound (initial state known) is lower."""
    tel = simulate_open_loop(100, seed=1)
    result = estimate_batch(records(tel), settings(gate_probability=None), None, initial_theta=RATTLE_PRIOR.theta)
    bound = cramer_rao_bound(result.t, result.states, tel.u_applied, result.estimate.theta, MODEL, PLANT_PERIOD_S)
    np.testing.assert_allclose(result.estimate.std, bound.std, rtol=0.03)
    assert np.all(bound.std_known_initial_state < bound.std)


def test_known_initial_state_information_equals_information_py_on_its_own_discretisation():
    """With one RK4 step per control period (information.py's model) and x₀ known, both information matrices are
    the same sum Σ GᵀR⁻¹G. The 40 s run keeps the quaternion's w > 0 (information.py does not carry its
    sensitivities through the w >= 0 sign flip of the normalisation; ours does, see the next test)."""
    tel = simulate_open_loop(40, sensors=SensorNoise())
    assert tel.x_measured[:, 9].min() > 0.3
    t, u = tel.t_ctrl, tel.u_applied
    fim = fisher_information(tel.x_measured[0], u[:-1], THETA_TRUE, 0.2, MODEL)
    # Linearise along information.py's own one-step trajectory.
    x = [tel.x_measured[0]]
    for k in range(len(t) - 1):
        x.append(rb.propagate(x[-1], u[k], THETA_TRUE, 0.2))
    bound = cramer_rao_bound(t, np.array(x), u, THETA_TRUE, MODEL, 0.2)
    np.testing.assert_allclose(bound.information_known_initial_state, fim, rtol=1e-6)  # radial q parts differ


def test_bound_does_not_depend_on_the_quaternion_sign():
    tel = simulate_open_loop(100, sensors=SensorNoise())
    t, u, x = tel.t_ctrl, tel.u_applied, tel.x_measured
    flipped = x.copy()
    flipped[::3, 6:10] *= -1.0
    a = cramer_rao_bound(t, x, u, THETA_TRUE, MODEL, PLANT_PERIOD_S)
    b = cramer_rao_bound(t, flipped, u, THETA_TRUE, MODEL, PLANT_PERIOD_S)
    np.testing.assert_allclose(a.information, b.information, rtol=1e-9)
    np.testing.assert_allclose(a.information_known_initial_state, b.information_known_initial_state, rtol=1e-9)


# ---------------------------------------------------------------------------------------------------------------
# Outliers, ordering, physicality
# ---------------------------------------------------------------------------------------------------------------


def test_localisation_jumps_are_rejected_and_leave_the_estimate_within_two_sigma():
    tel = simulate_open_loop(150, seed=4)
    clean = estimate_batch(records(tel), settings(), RATTLE_PRIOR)
    jumped, idx = inject_localisation_jumps(tel.x_measured, 0.05, np.random.default_rng(5))
    recs = [Measurement(r.t, x, r.u_applied) for r, x in zip(records(tel), jumped, strict=True)]
    robust = estimate_batch(recs, settings(), RATTLE_PRIOR)
    rejected = np.flatnonzero(~robust.inliers)
    assert set(idx) <= set(rejected)
    assert len(rejected) <= len(idx) + 6  # plus the 1 % of clean records the 0.99 gate drops by design
    assert np.all(np.abs(robust.estimate.theta - clean.estimate.theta) <= 2 * clean.estimate.std)
    assert robust.estimate.samples_rejected == len(rejected)
    # Without the gate the same jumps pull the estimate far outside 2σ.
    naive = estimate_batch(recs, settings(gate_probability=None), RATTLE_PRIOR)
    assert np.any(np.abs(naive.estimate.theta - clean.estimate.theta) > 2 * clean.estimate.std)


def test_shuffled_time_stamps_give_the_same_estimate():
    tel = simulate_open_loop(60, seed=6)
    ordered = records(tel)
    shuffled = [ordered[i] for i in np.random.default_rng(1).permutation(len(ordered))]
    a = estimate_batch(ordered, settings(), RATTLE_PRIOR)
    b = estimate_batch(shuffled, settings(), RATTLE_PRIOR)
    np.testing.assert_array_equal(a.estimate.theta, b.estimate.theta)
    np.testing.assert_array_equal(a.estimate.covariance, b.estimate.covariance)
    np.testing.assert_array_equal(a.t, np.sort([r.t for r in shuffled]))
    # A repeated time stamp is dropped and counted as rejected.
    c = estimate_batch([*shuffled, ordered[10]], settings(), RATTLE_PRIOR)
    assert c.duplicates == 1 and c.estimate.samples_rejected == a.estimate.samples_rejected + 1


@hsettings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(noise_scale=st.floats(1.0, 300.0), n=st.integers(3, 12), seed=st.integers(0, 1000))
def test_estimates_stay_physical_on_short_and_very_noisy_data(noise_scale, n, seed):
    """Short runs with up to 300× the nominal noise: every iterate is physical by construction (φ)."""
    sensors = SensorNoise(0.01 * noise_scale, 0.002 * noise_scale, min(0.005 * noise_scale, 1.0), 0.016 * noise_scale)
    tel = simulate_open_loop(n, sensors=sensors, seed=seed)
    result = estimate_batch(records(tel), settings(gate_probability=None), RATTLE_PRIOR)
    assert par.is_physical(result.estimate.theta)
    assert np.all(np.isfinite(result.estimate.covariance))


def test_growing_windows_converge_to_the_full_batch():
    tel = simulate_open_loop(80, seed=8)
    recs = records(tel)
    windows = estimate_batch_windows(recs, settings(), RATTLE_PRIOR, [4.0, 8.0, 12.0, recs[-1].t])
    full = estimate_batch(recs, settings(), RATTLE_PRIOR)
    assert [w.t[-1] for w in windows] == pytest.approx([4.0, 8.0, 12.0, recs[-1].t])
    np.testing.assert_allclose(windows[-1].estimate.theta, full.estimate.theta, rtol=1e-6)
    stds = np.array([w.estimate.std for w in windows])
    assert np.all(np.diff(stds, axis=0) <= 1e-12)  # more data never widens the bound


# ---------------------------------------------------------------------------------------------------------------
# Spread over seeds against the Cramér-Rao bound
# ---------------------------------------------------------------------------------------------------------------


def _spread_over_seeds(n_seeds: int, n_records: int) -> tuple[np.ndarray, np.ndarray]:
    errors, bounds = [], []
    for seed in range(n_seeds):
        tel = simulate_open_loop(n_records, seed=1000 + seed)
        result = estimate_batch(records(tel), settings(), RATTLE_PRIOR)
        errors.append(result.estimate.theta - THETA_TRUE)
        bounds.append(cramer_rao_bound(result.t, result.states, tel.u_applied, result.estimate.theta, MODEL,
                                       PLANT_PERIOD_S, used=result.inliers).std)
    return np.array(errors), np.array(bounds)


def test_spread_over_seeds_is_consistent_with_the_cramer_rao_bound():
    """16 seeds of the same 12 s experiment: the root-mean-square error against sqrt(diag F⁻¹).

    Under the bound, 16 · ratio² is χ²₁₆; its 0.05 % and 99.95 % quantiles, 0.47 and 1.61, keep the chance of a
    false alarm over the four parameters below 0.4 % (the slow test below pins the ratio to ±15 %)."""
    errors, bounds = _spread_over_seeds(16, 60)
    ratio = np.sqrt(np.mean(errors**2, axis=0)) / np.mean(bounds, axis=0)
    assert np.all(ratio > 0.47) and np.all(ratio < 1.61), ratio


@pytest.mark.slow
def test_spread_over_many_seeds_matches_the_cramer_rao_bound():
    """120 seeds of a 20 s experiment: the spread is the bound within ±15 % (χ²₁₂₀: 0.85-1.15 at 99 %), and the
    mean error is zero within 3 standard errors."""
    errors, bounds = _spread_over_seeds(120, 100)
    ratio = np.sqrt(np.mean(errors**2, axis=0)) / np.mean(bounds, axis=0)
    assert np.all(ratio > 0.85) and np.all(ratio < 1.15), ratio
    assert np.all(np.abs(errors.mean(axis=0)) < 3 * bounds.mean(axis=0) / np.sqrt(120))


def test_at_least_two_records_and_a_starting_point_are_required():
    tel = simulate_open_loop(3, seed=0)
    with pytest.raises(ValueError, match="at least 2 records"):
        estimate_batch(records(tel)[:1], settings(), RATTLE_PRIOR)
    with pytest.raises(ValueError, match="prior or an initial_theta"):
        estimate_batch(records(tel), settings(), None)
    assert exciting_inputs(5).shape == (5, 6)
    assert MeasurementModel is InfoModel
