"""RATTLE's information-aware planner ([ReSWARM2023] §4.4, §4.6): decay rule, planner, closed loop with the oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oacli.excitation.information import MeasurementModel, fisher_information
from oacli.excitation.oracle import CramerRaoOracle, OnlineEstimator
from oacli.excitation.rattle import InformationAwarePlanner, InformationWeighting, information_weights
from oacli.excitation.rattle_loop import run_rattle
from oacli.geometry import Box, Scene
from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb
from oacli.model.limits import MotionLimits
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.types import InertialParams

TRUTH = np.array([15.0, 0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1, Astrobee with object
P0 = np.diag([15.0, 0.005, 0.005, 0.005])  # rattle param_est P0
RATTLE_MODEL = MeasurementModel(velocity_std_mps=5e-6**0.5, angular_velocity_std_radps=2.5e-4**0.5,
                                linear_acceleration_std_mps2=5e-6**0.5)
PLANNER_LIMITS = MotionLimits([0.15] * 3, [0.015] * 3, [0.15] * 3, [0.175] * 3)  # rattle planner |F|, |τ|
Q_ISS = quat.normalize(np.array([0.0, 0.0, -0.7071068, 0.7071068]))
B = np.array([10.8, -7.75, 5.2])  # rattle primary_coord_params: storage
C = np.array([10.8, -7.75, 4.3])  # safe area
JEM = Scene(keep_in=(Box((9.8595, -9.2365, 3.7831), (11.9950, -2.7532, 5.9180)),))


def state(position) -> np.ndarray:
    x = np.zeros(13)
    x[0:3] = position
    x[6:10] = Q_ISS
    return x


# ----------------------------------------------------------------------------------------------------------------
# Decay rule
# ----------------------------------------------------------------------------------------------------------------


def test_decay_rule_published_constants():
    """γ_i = γ0_i exp(−β floor_i/σ_i), 0 once σ_i ≤ α floor_i ([RATTLE2022]; [RattleCode] α 2.2, β 5)."""
    w = InformationWeighting()
    np.testing.assert_array_equal(w.gamma0, [50, 20, 20, 20])
    np.testing.assert_array_equal(w.floor, [0.03, 1e-4, 1e-4, 1e-4])
    sigma = np.array([0.3, 1e-3, 2.3e-4, 2.2e-4])
    expected = np.array([50 * np.exp(-5 * 0.03 / 0.3), 20 * np.exp(-5 * 1e-4 / 1e-3), 20 * np.exp(-5 / 2.3), 0.0])
    np.testing.assert_allclose(w.weights(sigma), expected, rtol=1e-14)
    # Just above and at the shut-off: a jump from γ0 exp(−β/α) to 0.
    assert w.weights(np.array([0.066 + 1e-12, 1, 1, 1]))[0] == pytest.approx(50 * np.exp(-5 / 2.2))
    assert w.weights(np.array([0.066, 1, 1, 1]))[0] == 0.0


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(1e-6, 10.0), min_size=4, max_size=4), st.lists(st.floats(1e-6, 10.0), min_size=4,
                                                                            max_size=4))
def test_weights_never_grow_as_the_uncertainty_falls(a, b):
    w = InformationWeighting()
    hi, lo = np.maximum(a, b), np.minimum(a, b)
    g_hi, g_lo = information_weights(hi, w), information_weights(lo, w)
    assert np.all(g_lo <= g_hi)
    assert np.all((g_hi >= 0) & (g_hi <= w.gamma0))


# ----------------------------------------------------------------------------------------------------------------
# Planner
# ----------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def planner() -> InformationAwarePlanner:
    return InformationAwarePlanner(state(C), horizon=40, dt_s=0.3, limits=PLANNER_LIMITS, measurement=RATTLE_MODEL,
                                   scene=JEM, iterations=3)


def test_planner_problem_is_dpp(planner):
    planner.plan(state(B), TRUTH, np.sqrt(np.diag(P0)), np.zeros(4))
    assert planner.problem.is_dpp()


def test_information_weight_makes_the_plan_excite_the_inertias(planner):
    sigma = np.sqrt(np.diag(P0))
    gamma = InformationWeighting().weights(sigma)
    info_plan = planner.plan(state(B), TRUTH, sigma, gamma)
    goal_plan = planner.plan(state(B), TRUTH, sigma, np.zeros(4))
    for plan in (info_plan, goal_plan):
        traj = plan.trajectory
        assert np.all(np.abs(traj.u) <= PLANNER_LIMITS.input * (1 + 1e-9))
        # Rates are soft constraints (exact penalty) on a linearised rotation: they hold to within 0.5 %.
        assert np.max(np.abs(traj.x[:, 10:13]) / PLANNER_LIMITS.angular_velocity_radps) <= 1.005
        assert np.all(JEM.in_keep_in(traj.x[:, 0:3]))
        assert traj.t[1] - traj.t[0] == pytest.approx(0.3) and len(traj) == 41
        # Both head for C (0.9 m below B).
        assert traj.x[-1, 2] < B[2] - 0.2
    # Goal only: no reason to turn, so nothing is learned about the inertias; with γ > 0 the plan spins up.
    assert np.all(np.diag(goal_plan.information)[1:] < 1e-6 * np.diag(info_plan.information)[1:])
    assert np.all(np.diag(info_plan.information)[1:] > 1e4)
    assert info_plan.information_reward > goal_plan.information_reward
    # The reported information is the Fisher information of the plan's own rollout.
    u = info_plan.trajectory.u[:-1]
    np.testing.assert_allclose(info_plan.information, fisher_information(state(B), u, TRUTH, 0.3, RATTLE_MODEL),
                               rtol=1e-10)


# ----------------------------------------------------------------------------------------------------------------
# Oracle and closed loop
# ----------------------------------------------------------------------------------------------------------------


def test_oracle_accumulates_the_fisher_information_of_the_flown_trajectory(rng):
    """Fed the noise-free states of an open-loop run, the oracle's information is F of that run (Eq. 29)."""
    n, dt = 30, 0.3
    u = np.zeros((n, 6))
    u[:, 0:3] = rng.uniform(-0.1, 0.1, (n, 3))
    u[:, 3:6] = rng.uniform(-0.01, 0.01, (n, 3))
    x = [state(B)]
    for k in range(n):
        x.append(rb.propagate(x[-1], u[k], TRUTH, dt))
    oracle = CramerRaoOracle(TRUTH, P0, RATTLE_MODEL, x[0])
    assert isinstance(oracle, OnlineEstimator)
    np.testing.assert_allclose(oracle.estimate.covariance, P0)
    for k in range(n):
        est = oracle.update((k + 1) * dt, x[k + 1], u[k])
    expected = fisher_information(x[0], u, TRUTH, dt, RATTLE_MODEL)
    np.testing.assert_allclose(oracle.information, expected, rtol=1e-9)
    np.testing.assert_allclose(est.covariance, np.linalg.inv(np.linalg.inv(P0) + expected), rtol=1e-9)
    np.testing.assert_array_equal(est.theta, TRUTH)
    assert est.method == "oracle-crb" and est.samples_used == n


def closed_loop(gamma0, duration_s=48.0):
    planner = InformationAwarePlanner(state(C), horizon=40, dt_s=0.3, limits=PLANNER_LIMITS,
                                      measurement=RATTLE_MODEL, scene=JEM, iterations=3)
    oracle = CramerRaoOracle(TRUTH, P0, RATTLE_MODEL, state(B))
    return run_rattle(
        planner, oracle, InformationWeighting(gamma0=np.asarray(gamma0, dtype=float)), state(B),
        InertialParams(TRUTH[0], TRUTH[1:]), duration_s=duration_s, replan_period_s=12.0, control_period_s=0.2,
        plant_period_s=1 / 62.5, input_limits=PLANNER_LIMITS.input,
        feedback_q=np.r_[[10.0] * 3, [1.0] * 3, [10.0] * 3, [1.0] * 3], feedback_r=np.r_[[1.0] * 3, [100.0] * 3],
        sensors=SensorNoise(), disturbance=Disturbance.none(), rng=np.random.default_rng(0),
    )


@pytest.fixture(scope="module")
def rattle_runs():
    return closed_loop([50.0, 20.0, 20.0, 20.0]), closed_loop([0.0, 0.0, 0.0, 0.0])


def test_replanning_happens_every_period_with_the_latest_estimate(rattle_runs):
    run, _ = rattle_runs
    np.testing.assert_allclose([r.t for r in run.replans], [0.0, 12.0, 24.0, 36.0], atol=1e-9)
    for r in run.replans[1:]:
        # The estimate used at a replan is the oracle's after the measurement at that time.
        est = next(e for e in run.estimates if abs(e.t - r.t) < 1e-9)
        np.testing.assert_allclose(r.std, est.std, rtol=1e-12)
        # Each plan starts where the robot was measured (noise-free sensors here) and spans 40 × 0.3 s.
        k = int(np.argmin(np.abs(run.telemetry.t_ctrl - r.t)))
        np.testing.assert_allclose(r.plan.trajectory.x[0], run.telemetry.x_measured[k], atol=1e-12)
        assert r.plan.trajectory.t[-1] - r.plan.trajectory.t[0] == pytest.approx(12.0)


def test_weights_decay_by_the_rule_as_the_uncertainty_falls(rattle_runs):
    run, _ = rattle_runs
    rule = InformationWeighting()
    stds = np.array([r.std for r in run.replans])
    gammas = np.array([r.gamma for r in run.replans])
    np.testing.assert_allclose(gammas, [rule.weights(s) for s in stds], rtol=1e-14)
    assert np.all(np.diff(stds, axis=0) <= 0)  # information only accumulates
    assert np.all(np.diff(gammas, axis=0) <= 0)
    # The mass is learned below α·floor = 0.066 kg: from then on its weight is switched off.
    off = stds[:, 0] <= 2.2 * 0.03
    assert off[-1] and np.all(gammas[off, 0] == 0.0) and np.all(gammas[~off, 0] > 0.0)
    assert np.all(gammas[-1, 1:] < gammas[0, 1:])


def test_robot_reaches_the_goal_and_stays_in_the_workspace(rattle_runs):
    for run in rattle_runs:
        tel = run.telemetry
        assert np.linalg.norm(tel.x_true[-1, 0:3] - C) < 0.05
        assert np.all(JEM.in_keep_in(tel.x_true[:, 0:3]))
        assert np.all(np.abs(tel.u_applied) <= PLANNER_LIMITS.input * (1 + 1e-12))


def test_information_gathered_beats_a_goal_only_plan_of_the_same_duration(rattle_runs):
    rattle, goal_only = rattle_runs
    assert rattle.telemetry.t_true[-1] == goal_only.telemetry.t_true[-1]
    cov_r, cov_g = rattle.final_estimate.covariance, goal_only.final_estimate.covariance
    # Every parameter ends better known, the inertias by far (goal-only never turns: prior std 0.0707).
    assert np.all(np.diag(cov_r) < np.diag(cov_g))
    assert np.all(np.sqrt(np.diag(cov_r))[1:] < 0.05 * np.sqrt(np.diag(cov_g))[1:])
    # A-criterion on relative parameters.
    d = np.diag(TRUTH)
    assert np.trace(np.linalg.inv(d) @ cov_r @ np.linalg.inv(d)) < 0.1 * np.trace(
        np.linalg.inv(d) @ cov_g @ np.linalg.inv(d))
