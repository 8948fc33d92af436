"""Kinodynamic RRT with motion primitives ([ReSWARM2023] §4.1.2-4.1.3, Eqs. 26-27)."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.geometry import Box, Scene
from oacli.geometry.collision import CollisionChecker, RobotBody
from oacli.planning.kino_rrt import KinoRrtSettings, motion_primitives, plan_kino_rrt
from oacli.planning.problem import PlanningProblem
from oacli.planning.translational import TranslationalTrajectory
from oacli.planning.tree import EDGE_LQR, EDGE_PRIMITIVE
from tests.model_helpers import mass_model
from tests.plan_checks import S1_SHORTEST_M, assert_valid_plan, scene_problem


def test_primitive_sets_of_eq_27():
    limits = np.array([0.4, 0.2, 0.3])
    axes = motion_primitives(limits, 0.5, "axes")
    assert axes.shape == (7, 3)  # 2 n_u + 1 with the zero action
    np.testing.assert_array_equal(axes[0], 0.0)
    np.testing.assert_allclose(np.sort(np.abs(axes[1:]).sum(axis=1)), np.sort(np.repeat(0.5 * limits, 2)))
    assert np.all(np.count_nonzero(axes[1:], axis=1) == 1)
    combos = motion_primitives(limits, 0.5, "combinations")
    assert combos.shape == (27, 3)
    assert len({tuple(r) for r in combos}) == 27
    assert np.all(np.isin(np.abs(combos), [0.0, 0.2, 0.1, 0.15]))


@pytest.mark.parametrize("primitive_set", ["axes", "combinations"])
def test_kino_rrt_solves_s1_with_primitives_and_an_exact_goal_link(primitive_set):
    problem = scene_problem()
    settings = KinoRrtSettings(primitive_set=primitive_set, max_iterations=4000, time_budget_s=60.0)
    solved = 0
    for seed in range(4):
        result = plan_kino_rrt(problem, settings, np.random.default_rng(seed))
        if not result.solved:
            continue
        solved += 1
        traj = result.trajectory
        assert_valid_plan(traj, problem)
        assert traj.path_length_m() >= S1_SHORTEST_M - 1e-9
        tree = result.tree
        kinds = tree.kind[list(result.path[1:])]
        assert np.all(kinds[:-1] == EDGE_PRIMITIVE) and kinds[-1] == EDGE_LQR  # primitives, then the goal link
        prims = motion_primitives(problem.force_limit_N, settings.primitive_fraction, primitive_set)
        for node in result.path[1:-1]:
            assert np.any(np.all(np.isclose(prims, tree.force[node]), axis=1))
            assert tree.duration_s[node] == settings.primitive_dt_s
        before_link = tree.states[result.path[-2]]
        assert np.linalg.norm(before_link[0:3] - problem.goal[0:3]) <= settings.goal_tolerance_m
        assert result.cost == pytest.approx(tree.cost[tree.goal_node], rel=1e-9)
    assert solved >= 3


def test_long_primitives_never_tunnel_through_a_thin_wall():
    """A 2 cm wall (the gap between two keep-in boxes) with a door at y >= 0.6: Δt = 4 s primitives jump far over
    the wall, so a check of the primitives' end points alone would cross it anywhere; the continuous check keeps
    every plan to the door (and the dense 5 mm re-check agrees)."""
    boxes = (Box([-1, -1, -1], [0.99, 1, 1]), Box([1.01, -1, -1], [3, 1, 1]), Box([0.9, 0.6, -1], [1.1, 1, 1]))
    scene = Scene(keep_in=boxes)
    checker = CollisionChecker(scene)
    base = scene_problem()
    lower = np.array([b.lower for b in boxes])
    upper = np.array([b.upper for b in boxes])
    problem = PlanningProblem(base.start, base.goal, base.model, base.force_limit_N, base.velocity_limit_mps,
                              checker, lower, upper, base.weights)
    # A primitive straight through the wall: both ends inside the keep-in union, the middle is not.
    jump = TranslationalTrajectory.from_forces([0.6, 0.0, 0.0, 0.2, 0.0, 0.0], [[0.25, 0.0, 0.0]], 4.0, mass_model(9.6))
    assert checker.points_free(jump.x[:, 0:3]).all()
    assert not checker.check(jump.pieces()).free
    settings = KinoRrtSettings(primitive_dt_s=4.0, max_iterations=6000, time_budget_s=60.0)
    solved = 0
    for seed in range(3):
        result = plan_kino_rrt(problem, settings, np.random.default_rng(seed))
        if result.solved:
            solved += 1
            assert_valid_plan(result.trajectory, problem)
            pts = result.trajectory.states_at(np.linspace(0, result.trajectory.duration_s, 40001))
            in_wall = np.abs(pts[:, 0] - 1.0) < 0.01
            assert np.any(in_wall) and np.all(pts[in_wall, 1] >= 0.6 - 1e-9)  # through the door only
    assert solved >= 2


def test_robot_ellipsoid_against_obstacles_uses_ellipsoid_on_ellipsoid_checks():
    problem = scene_problem()
    body = RobotBody.ellipsoid([0.15, 0.05, 0.05])
    checker = CollisionChecker(problem.checker.scene, body)
    ell_problem = PlanningProblem(problem.start, problem.goal, problem.model, problem.force_limit_N,
                                  problem.velocity_limit_mps, checker, problem.sample_lower, problem.sample_upper,
                                  problem.weights)
    result = plan_kino_rrt(ell_problem, KinoRrtSettings(max_iterations=4000, time_budget_s=60.0),
                           np.random.default_rng(1))
    assert result.solved
    traj = result.trajectory
    t = np.linspace(0.0, traj.duration_s, 20001)
    g = checker.clearance_sq(traj.states_at(t)[:, 0:3])
    assert g.min() >= 1.0  # the robot ellipsoid never overlaps the sphere (Gilitschenski-Hanebeck test)
    assert checker.check(traj.pieces()).free
