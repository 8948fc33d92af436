"""LQR shortcutting: never raises the cost, never splices in a colliding or infeasible section."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from oacli.geometry import Box, Ellipsoid, Scene
from oacli.geometry.collision import CollisionChecker
from oacli.planning.lqr_rrt_star import LqrRrtStarSettings, plan_lqr_rrt_star
from oacli.planning.shortcut import ACCEPTED, COLLISION, INPUT_LIMIT, REJECTIONS, lqr_shortcut, splice
from oacli.planning.steering import LqrConnector
from oacli.planning.translational import TranslationalTrajectory
from tests.plan_checks import S1, S2, assert_valid_plan, scene_problem

_PLANS: dict = {}


def plan_for(scene: str, seed: int):
    """A first-solution LQR-RRT* plan of a benchmark scene (cached: hypothesis reuses them)."""
    key = (scene, seed)
    if key not in _PLANS:
        problem = scene_problem(S1 if scene == "S1" else S2)
        result = plan_lqr_rrt_star(problem, LqrRrtStarSettings(max_iterations=1500, time_budget_s=60.0),
                                   np.random.default_rng(seed))
        assert result.solved
        conn = LqrConnector(problem.model, 0.5, problem.weights, 60)
        _PLANS[key] = (problem, conn, result.trajectory)
    return _PLANS[key]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=st.sampled_from(["S1", "S2"]), plan_seed=st.integers(0, 2), seed=st.integers(0, 2**32 - 1),
       tries=st.integers(1, 80), refine=st.booleans())
def test_smoothing_never_raises_the_cost_and_stays_collision_free(scene, plan_seed, seed, tries, refine):
    problem, conn, traj = plan_for(scene, plan_seed)
    if refine:
        traj = traj.refined(0.1)
    result = lqr_shortcut(traj, conn, problem.checker, problem.goal, problem.force_limit_N,
                          problem.velocity_limit_mps, np.random.default_rng(seed), tries=tries,
                          sample_dt_s=0.1 if refine else None)
    out = result.trajectory
    # The cost never rises, try after try, and the reported costs are the trajectories' exact costs.
    assert result.cost_before == pytest.approx(traj.cost(problem.weights, problem.goal), rel=1e-12)
    assert result.cost_after == pytest.approx(out.cost(problem.weights, problem.goal), rel=1e-12)
    assert result.cost_after <= result.cost_before * (1 + 1e-12)
    for attempt in result.attempts:
        assert attempt.outcome == ACCEPTED or attempt.outcome in REJECTIONS
        if attempt.outcome == ACCEPTED:
            assert attempt.new_cost < attempt.old_cost
    assert result.tried == tries and result.accepted + sum(result.rejected.values()) == tries
    assert len(result.sections) == result.accepted
    # Independent checks of the whole smoothed trajectory (every splice included).
    assert_valid_plan(out, problem)
    assert problem.checker.check(out.pieces()).free


def test_splicing_changes_the_cost_by_exactly_the_difference_of_the_sections():
    problem, conn, traj = plan_for("S1", 0)
    traj = traj.refined(0.1)
    a, b = 5, len(traj) - 7
    section = conn.trajectory(traj.x[a], traj.x[b], problem.goal, 20)
    costs = traj.interval_costs(problem.weights, problem.goal)
    new = splice(traj, a, b, section)
    expected = costs.sum() - costs[a:b].sum() + section.cost(problem.weights, problem.goal)
    assert new.cost(problem.weights, problem.goal) == pytest.approx(expected, rel=1e-12)
    assert new.zoh_residual() < 1e-12
    assert new.duration_s == pytest.approx(traj.duration_s - (traj.t[b] - traj.t[a]) + section.duration_s)


def _detour_around(obstacle_y: float) -> tuple[TranslationalTrajectory, LqrConnector, CollisionChecker]:
    """A slow rest-to-rest detour from (0,0,0) over (1, 0.5, 0) to (2,0,0), i.e. around a sphere at (1, 0, 0)."""
    scene = Scene(keep_in=(Box([-1, -1, -1], [3, 1, 1]),),
                  keep_out=(Ellipsoid.from_semi_axes([1.0, obstacle_y, 0.0], [0.3, 0.3, 0.3]),))
    problem = scene_problem()
    conn = LqrConnector(problem.model, 0.5, problem.weights, 80)
    via = np.array([1.0, 0.5, 0.0, 0.1, 0.0, 0.0])
    first = conn.trajectory(np.zeros(6), via, problem.goal, 30)
    second = conn.trajectory(via, problem.goal, problem.goal, 30)
    return TranslationalTrajectory.concatenate([first, second]), conn, CollisionChecker(scene)


def test_a_cheaper_but_colliding_shortcut_is_rejected():
    traj, conn, checker = _detour_around(0.0)
    problem = scene_problem()
    assert checker.check(traj.pieces()).free
    # Always the whole trajectory: its direct connection is cheaper and goes through the sphere.
    direct = conn.trajectory(traj.x[0], traj.x[-1], problem.goal, 40)
    assert not checker.check(direct.pieces()).free
    rng = np.random.default_rng(0)
    result = lqr_shortcut(traj, conn, checker, problem.goal, problem.force_limit_N, problem.velocity_limit_mps,
                          rng, tries=200)
    assert result.rejected[COLLISION] > 0
    assert checker.check(result.trajectory.pieces()).free
    assert result.trajectory.path_length_m() > 2.0 * np.sqrt(1.0 - 0.09)  # still goes around the sphere
    # Without the obstacle in the way the same shortcutting straightens the path.
    free_traj, conn, far = _detour_around(5.0)
    straight = lqr_shortcut(free_traj, conn, far, problem.goal, problem.force_limit_N,
                            problem.velocity_limit_mps, np.random.default_rng(0), tries=200)
    assert straight.trajectory.path_length_m() < 2.02


def test_a_cheaper_shortcut_beyond_the_force_limit_is_rejected():
    traj, conn, checker = _detour_around(5.0)
    problem = scene_problem()
    tiny_force = np.full(3, 1e-4)  # every new connection needs more than this
    result = lqr_shortcut(traj, conn, checker, problem.goal, tiny_force, problem.velocity_limit_mps,
                          np.random.default_rng(1), tries=50)
    assert result.accepted == 0 and result.rejected[INPUT_LIMIT] > 0
    np.testing.assert_array_equal(result.trajectory.x, traj.x)
