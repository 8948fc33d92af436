"""Standard MPC ([Doerr2021] Eq. 26): DPP, equality with LQR when unconstrained, limits, fallback."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from oacli.control.lqr import dlqr
from oacli.control.mpc import LinearMPC
from oacli.control.tracking import TrackingMPC, TrackingWeights
from oacli.model.double_integrator import hover_error_model
from oacli.model.limits import MotionLimits
from oacli.reference import waypoint_reference
from oacli.types import InertialParams, SolveInfo

PARAMS = InertialParams(9.583788668, [0.153427995, 0.14271405, 0.162302759])  # Astrobee on ISS, [AstrobeeFSW]
Q = np.array([10.0] * 3 + [1.0] * 3 + [10.0] * 3 + [1.0] * 3)
R = np.array([1.0] * 3 + [100.0] * 3)
U_MAX = np.array([0.452, 0.216, 0.257, 0.0452, 0.0216, 0.0257])  # [ReSWARM2023] Table 2 (2000 RPM), torque ≈ 1/10
X_MAX = np.r_[[np.inf] * 3, [0.2] * 3, [np.inf] * 3, [0.1745] * 3]


def make_mpc(horizon=10, dt=0.2):
    a, b = hover_error_model(PARAMS, dt)
    return LinearMPC(a, b, Q, R, horizon, U_MAX, x_max=X_MAX), a, b


def test_compiled_path_equals_problem_solve(rng):
    """The direct-Clarabel path solves the same cvxpy problem as problem.solve()."""
    a, b = hover_error_model(PARAMS, 0.2)
    fast = LinearMPC(a, b, Q, R, 10, U_MAX, x_max=X_MAX)
    slow = LinearMPC(a, b, Q, R, 10, U_MAX, x_max=X_MAX, fast=False)
    for _ in range(5):
        x0 = np.r_[rng.uniform(-1, 1, 3), rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.5, 0.5, 3), np.zeros(3)]
        x_ref = np.tile(rng.uniform(-0.1, 0.1, 12), (11, 1))
        f, s = fast.solve(x0, x_ref, np.zeros((10, 6))), slow.solve(x0, x_ref, np.zeros((10, 6)))
        assert f.info.success and s.info.success
        np.testing.assert_allclose(f.u, s.u, atol=1e-6)
        assert f.info.objective == pytest.approx(s.info.objective, rel=1e-6, abs=1e-9)
        assert f.max_slack == pytest.approx(s.max_slack, abs=1e-7)


def test_problem_is_dpp_and_resolving_raises_no_warning():
    mpc, _, _ = make_mpc()
    assert mpc.problem.is_dpp()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for scale in (0.01, 0.02):
            sol = mpc.solve(scale * np.ones(12), np.zeros((11, 12)), np.zeros((10, 6)))
            assert sol.info.success


@pytest.mark.parametrize("horizon", [1, 5, 20])
def test_unconstrained_mpc_equals_the_lqr_law(horizon, rng):
    """With the DARE terminal weight and no active constraint, MPC's first input is the LQR law u = K x."""
    mpc, a, b = make_mpc(horizon)
    k, _ = dlqr(a, b, np.diag(Q), np.diag(R))
    for _ in range(5):
        x0 = rng.uniform(-1, 1, 12) * np.r_[[0.01] * 3, [0.001] * 3, [0.01] * 3, [0.001] * 3]
        sol = mpc.solve(x0, np.zeros((horizon + 1, 12)), np.zeros((horizon, 6)))
        assert sol.info.status == "optimal"
        assert np.all(np.abs(sol.u) < 0.9 * U_MAX)  # really unconstrained
        np.testing.assert_allclose(sol.u[0], k @ x0, rtol=1e-5, atol=1e-8)
        # The predicted trajectory obeys the model.
        np.testing.assert_allclose(sol.x[1:], sol.x[:-1] @ a.T + sol.u @ b.T, atol=1e-8)


def test_inputs_never_exceed_the_limits_and_saturate_on_large_errors(rng):
    mpc, _a, _b = make_mpc(10)
    for _ in range(10):
        x0 = np.r_[rng.uniform(-3, 3, 3), rng.uniform(-0.1, 0.1, 3), rng.uniform(-1, 1, 3), np.zeros(3)]
        sol = mpc.solve(x0, np.zeros((11, 12)), np.zeros((10, 6)))
        assert sol.info.success
        assert np.all(np.abs(sol.u) <= U_MAX * (1 + 1e-6) + 1e-9)
        assert np.any(np.isclose(np.abs(sol.u[0]), U_MAX, rtol=1e-4))  # some axis at its limit
        # Velocity limits hold over the prediction (they are feasible from rest-like states).
        assert np.all(np.abs(sol.x[1:, 3:6]) <= 0.2 + 1e-6)
        assert sol.max_slack < 1e-6


def test_state_limits_are_soft_when_the_measured_state_already_violates_them():
    mpc, _, _ = make_mpc(10)
    x0 = np.zeros(12)
    x0[3] = 0.35  # 0.35 m/s measured against a 0.2 m/s limit: a hard constraint would be infeasible
    sol = mpc.solve(x0, np.zeros((11, 12)), np.zeros((10, 6)))
    assert sol.info.success
    assert sol.max_slack > 0.0
    assert sol.x[1, 3] < 0.35  # it brakes as hard as it can
    assert sol.u[0, 0] == pytest.approx(-U_MAX[0], rel=1e-4)


def _tracking(reference):
    limits = MotionLimits(U_MAX[:3], U_MAX[3:], np.full(3, 0.2), np.full(3, 0.1745))
    weights = TrackingWeights(*[np.full(3, v) for v in (10.0, 1.0, 10.0, 1.0, 1.0, 100.0)])
    return TrackingMPC(reference, PARAMS, dt_s=0.2, horizon=10, weights=weights, limits=limits)


def _reference():
    return waypoint_reference(
        [[10.8, -9.6, 4.8], [10.8, -7.75, 5.2]], [[0, 0, -0.7071068, 0.7071068], [0, 0, 0, 1]], PARAMS,
        speed_mps=0.1, accel_mps2=0.01, rate_radps=0.1, ang_accel_radps2=0.05, hold_s=1.0,
    )


def test_failed_solves_fall_back_to_the_shifted_plan_then_lqr(monkeypatch):
    ref = _reference()
    ctrl = _tracking(ref)
    x = ref.x[0].copy()
    first = ctrl.step(5.0, x)
    assert first.info.success
    plan = ctrl._plan.copy()

    def broken_solve(*args, **kwargs):
        return SolveInfo("solver_error: injected failure", False, float("nan"), -1, 0.0)

    monkeypatch.setattr(ctrl.mpc.compiled, "solve", broken_solve)
    steps = [ctrl.step(5.0 + 0.2 * i, x) for i in range(1, 13)]
    assert not any(s.info.success for s in steps)
    for i, s in enumerate(steps[:9], start=1):
        assert s.info.status.startswith("fallback (")
        np.testing.assert_allclose(s.u, np.clip(plan[i], -U_MAX, U_MAX))
    assert all(s.info.status.startswith("lqr (") for s in steps[9:])
    assert all(np.all(np.abs(s.u) <= U_MAX + 1e-12) for s in steps)
    assert "injected failure" in steps[0].info.status
