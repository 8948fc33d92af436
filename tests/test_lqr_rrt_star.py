"""LQR-RRT*: exact LQR connections ([Doerr2021] Eqs. 5-10), real rewiring, and a pass-rate test on a scene with a known
optimum (S1, shortest path 2.0907 m)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.integrate import quad

from oacli.control.lqr import tv_riccati
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.geometry.collision import CollisionChecker
from oacli.model.double_integrator import double_integrator
from oacli.planning.lqr_rrt_star import LqrRrtStarSettings, plan_lqr_rrt_star
from oacli.planning.problem import PlanningProblem
from oacli.planning.result import edge_trajectory
from oacli.planning.shortcut import lqr_shortcut
from oacli.planning.steering import LqrConnector, axis_maps
from oacli.planning.translational import CostWeights, TranslationalTrajectory, interval_cost_matrix
from oacli.planning.tree import EDGE_LQR, Tree
from tests.model_helpers import mass_model
from tests.plan_checks import S1_SHORTEST_M, assert_valid_plan, scene_problem

WEIGHTS = CostWeights([0.3, 0.5, 0.7], [1.1, 1.3, 0.2], [2.0, 3.0, 4.0], 0.5)
MASS, DT = 9.6, 0.5
MODEL = mass_model(MASS)


@pytest.fixture(scope="module")
def connector() -> LqrConnector:
    return LqrConnector(MODEL, DT, WEIGHTS, 40)


def _end_points(seed: int):
    rng = np.random.default_rng(seed)
    goal = np.concatenate([rng.normal(size=3), np.zeros(3)])
    return rng.normal(size=6) * [1, 1, 1, 0.2, 0.2, 0.2], rng.normal(size=6) * [1, 1, 1, 0.2, 0.2, 0.2], goal


# ------------------------------------------------------------------------------------------------------------
# The exact LQR connection
# ------------------------------------------------------------------------------------------------------------


def test_cost_integral_is_exact(connector):
    """The interval cost matrices integrate ∫ w_t + ½ fᵀRf + ½ (x - x_g)ᵀ Q (x - x_g) dt exactly (vs quadrature)."""
    x_a, x_b, goal = _end_points(1)
    traj = connector.trajectory(x_a, x_b, goal, 7)

    def integrand(t):
        k = min(int(t / DT), 6)
        x = traj.states_at([t])[0]
        e = x - goal
        f = traj.u[k]
        return WEIGHTS.time + 0.5 * (WEIGHTS.force @ f**2 + WEIGHTS.position @ e[:3] ** 2
                                     + WEIGHTS.velocity @ e[3:] ** 2)

    numeric = sum(quad(integrand, k * DT, (k + 1) * DT, epsabs=1e-12, epsrel=1e-12)[0] for k in range(7))
    assert traj.cost(WEIGHTS, goal) == pytest.approx(numeric, rel=1e-10)
    assert connector.costs(x_a, x_b, goal)[0, 7] == pytest.approx(numeric, rel=1e-10)


@pytest.mark.parametrize("steps", [2, 3, 9, 40])
def test_connection_lands_exactly_and_follows_the_exact_double_integrator(connector, steps):
    x_a, x_b, goal = _end_points(steps)
    traj = connector.trajectory(x_a, x_b, goal, steps)
    np.testing.assert_array_equal(traj.x[-1], x_b)
    # Propagate the forces with the exact ZOH model of oacli.model.double_integrator, independently.
    a, b = double_integrator(DT, 1.0 / MASS)
    x = x_a.copy()
    for f in traj.u:
        for i in range(3):
            x[[i, 3 + i]] = a @ x[[i, 3 + i]] + b[:, 0] * f[i]
    np.testing.assert_allclose(x, x_b, atol=1e-10)


def test_riccati_maps_equal_the_kkt_solution():
    """The O(N) multiplier-Riccati construction equals the dense KKT solution of the same quadratic programme."""
    n, dt, m, q_r, q_v, r_f = 13, 0.5, 9.6, 0.3, 1.1, 2.0
    g_all, _, cost_all = axis_maps(n, dt, mass_model(m), q_r, q_v, r_f)
    a, b = double_integrator(dt, 1.0 / m)
    w = interval_cost_matrix(dt, mass_model(m), q_r, q_v, r_f)
    # y = [r_a, v_a, r_b, v_b, r_g, v_g]; z_k = [r_k - r_g, v_k, v_k - v_g, u_k] = zy_k y + zu_k U
    xa = np.zeros((n + 1, 2, 6))
    xu = np.zeros((n + 1, 2, n))
    xa[0, :, 0:2] = np.eye(2)
    for k in range(n):
        xa[k + 1] = a @ xa[k]
        xu[k + 1] = a @ xu[k]
        xu[k + 1, :, k] += b[:, 0]
    h, f, e = np.zeros((n, n)), np.zeros((n, 6)), np.zeros((6, 6))
    for k in range(n):
        zy, zu = np.zeros((4, 6)), np.zeros((4, n))
        zy[0], zy[1], zy[2] = xa[k, 0], xa[k, 1], xa[k, 1]
        zy[0, 4] -= 1.0
        zy[2, 5] -= 1.0
        zu[0], zu[1], zu[2], zu[3, k] = xu[k, 0], xu[k, 1], xu[k, 1], 1.0
        h += zu.T @ w @ zu
        f += zu.T @ w @ zy
        e += zy.T @ w @ zy
    kkt = np.block([[h, xu[n].T], [xu[n], np.zeros((2, 2))]])
    sel_b = np.zeros((2, 6))
    sel_b[:, 2:4] = np.eye(2)
    g = np.linalg.solve(kkt, np.vstack([-f, sel_b - xa[n]]))[:n]
    cost = 0.5 * (g.T @ h @ g + g.T @ f + f.T @ g + e)
    np.testing.assert_allclose(g_all[n, :n], g, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(cost_all[n], 0.5 * (cost + cost.T), rtol=1e-9, atol=1e-12)


def test_connection_is_the_limit_of_doerrs_affine_riccati_with_a_growing_terminal_weight(connector):
    """[Doerr2021] Eqs. 8-9 (oacli.control.lqr.tv_riccati) in δx = x - x_b with Q_N → ∞ converge to the connection."""
    x_a, x_b, goal = _end_points(4)
    n = 12
    exact = connector.forces(x_a, x_b, goal, n)
    a1, b1 = double_integrator(DT, 1.0 / MASS)
    w = [interval_cost_matrix(DT, MODEL, WEIGHTS.position[i], WEIGHTS.velocity[i], WEIGHTS.force[i]) for i in range(3)]
    errors = []
    for q_final in (1e4, 1e6, 1e8):
        forces = np.empty((n, 3))
        for i in range(3):
            # stage cost ½ [x - g; u]ᵀ W̃ [x - g; u] with x = [r, v]; W over z = [r - r_g, v, v - v_g, u]
            t = np.array([[1, 0, 0], [0, 1, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
            wt = t.T @ w[i] @ t  # in [r - r_g, v, u] (goal velocity zero)
            off = np.array([x_b[i] - goal[i], x_b[3 + i]])  # x - g = δx + off
            sol = tv_riccati(
                np.tile(a1, (n, 1, 1)), np.tile(b1, (n, 1, 1)), np.tile(wt[:2, :2], (n, 1, 1)),
                np.tile(wt[2:, 2:], (n, 1, 1)), q_final * np.eye(2),
                g=np.tile((a1 - np.eye(2)) @ np.array([x_b[i], x_b[3 + i]]), (n, 1)),
                p=np.tile(wt[:2, 2:], (n, 1, 1)), q_lin=np.tile(wt[:2, :2] @ off, (n, 1)),
                r_lin=np.tile(wt[2:, :2] @ off, (n, 1)),
            )
            dx0 = np.array([x_a[i] - x_b[i], x_a[3 + i] - x_b[3 + i]])
            _, us = sol.rollout(np.tile(a1, (n, 1, 1)), np.tile(b1, (n, 1, 1)),
                                np.tile((a1 - np.eye(2)) @ np.array([x_b[i], x_b[3 + i]]), (n, 1)), dx0)
            forces[:, i] = us[:, 0]
        errors.append(np.abs(forces - exact).max())
    # The penalty solution approaches the constrained one as 1/Q_N.
    assert errors[1] < 2e-2 * errors[0] and errors[2] < 2e-2 * errors[1]
    assert errors[2] < 1e-4 * np.abs(exact).max()


def test_value_function_and_transformed_metric_give_the_connection_cost(connector):
    """Eq. 8 (½ xᵀSx + xᵀs + c) and the Euclidean form of the metric (Eq. 10) equal the optimal cost."""
    rng = np.random.default_rng(9)
    metric = connector.metric(10)
    for _ in range(20):
        x_a, x_b, goal = rng.normal(size=6), rng.normal(size=6), np.concatenate([rng.normal(size=3), np.zeros(3)])
        cost = connector.costs(x_a, x_b, goal)[0, 10]
        assert connector.value_function(10, x_b, goal)(x_a) == pytest.approx(cost, rel=1e-9)
        time_cost = WEIGHTS.time * 10 * DT
        z, c = metric.query_to(x_b, goal)
        assert np.sum((metric.source_coords(x_a) - z) ** 2) + c + time_cost == pytest.approx(cost, rel=1e-9)
        z, c = metric.query_from(x_a, goal)
        assert np.sum((metric.target_coords(x_b) - z) ** 2) + c + time_cost == pytest.approx(cost, rel=1e-9)


def test_connection_is_optimal_among_trajectories_with_the_same_end_points(connector):
    x_a, x_b, goal = _end_points(5)
    n = 8
    best = connector.trajectory(x_a, x_b, goal, n)
    best_cost = best.cost(WEIGHTS, goal)
    rng = np.random.default_rng(0)
    # Perturbations that keep both end points: forces in the null space of the end-state map.
    a1, b1 = double_integrator(DT, 1.0 / MASS)
    reach = np.stack([np.linalg.matrix_power(a1, n - 1 - k) @ b1[:, 0] for k in range(n)], axis=1)  # (2, n)
    null = np.linalg.svd(reach)[2][2:].T  # (n, n - 2)
    for _ in range(20):
        du = null @ rng.normal(size=(n - 2, 3)) * 0.05
        other = TranslationalTrajectory.from_forces(x_a, best.u + du, DT, MODEL)
        np.testing.assert_allclose(other.x[-1], x_b, atol=1e-9)
        assert other.cost(WEIGHTS, goal) > best_cost


def test_saturated_rollout_respects_the_limits_and_reaches_a_feasible_target(connector):
    f_lim, v_lim = np.full(3, 0.5), np.full(3, 0.2)
    far = connector.saturated_rollout(np.zeros(6), np.array([5.0, -3.0, 1.0, 0.2, 0.0, -0.2]), np.zeros(6), 10,
                                      f_lim, v_lim)
    assert np.all(far.max_abs_force_N() <= f_lim + 1e-12)
    assert np.all(far.max_abs_velocity_mps() <= v_lim + 1e-12)
    assert far.zoh_residual() < 1e-12
    near_target = np.array([0.1, 0.05, 0.0, 0.0, 0.0, 0.0])
    near = connector.saturated_rollout(np.zeros(6), near_target, np.zeros(6), 10, f_lim, v_lim)
    np.testing.assert_allclose(near.x[-1], near_target, atol=1e-9)  # no limit active: lands exactly


# ------------------------------------------------------------------------------------------------------------
# The tree: a rewire that really rewires
# ------------------------------------------------------------------------------------------------------------


def test_rewire_moves_the_subtree_and_propagates_the_cost_change():
    tree = Tree(np.zeros(6))
    a = tree.add(np.ones(6), 0, 5.0, EDGE_LQR, steps=4, iteration=1, wall_time_s=0.0)
    b = tree.add(2 * np.ones(6), a, 7.0, EDGE_LQR, steps=4, iteration=2, wall_time_s=0.0)
    c = tree.add(3 * np.ones(6), b, 10.0, EDGE_LQR, steps=4, iteration=3, wall_time_s=0.0)
    d = tree.add(4 * np.ones(6), 0, 1.0, EDGE_LQR, steps=4, iteration=4, wall_time_s=0.0)
    event = tree.rewire(a, d, 3.0, steps=6, iteration=5)
    assert tree.parent[a] == d and a in tree.children(d) and a not in tree.children(0)
    np.testing.assert_allclose(tree.cost[[a, b, c]], [3.0, 5.0, 8.0])
    assert event.descendants_updated == 2 and event.old_parent == 0 and event.new_steps == 6
    assert tree.path_to(c) == [0, d, a, b, c]
    with pytest.raises(ValueError, match="cycle"):
        tree.rewire(a, c, 0.5, steps=4, iteration=6)


# ------------------------------------------------------------------------------------------------------------
# The planner
# ------------------------------------------------------------------------------------------------------------


def _tree_is_consistent(result, problem):
    """Every node's cost is its parent's cost plus its own edge's exact cost, recomputed from scratch."""
    conn = LqrConnector(problem.model, 0.5, problem.weights, 30)
    tree = result.tree
    for node in range(1, len(tree)):
        edge = edge_trajectory(tree, node, conn, problem.goal)
        assert tree.cost[node] == pytest.approx(tree.cost[tree.parent[node]] + edge.cost(problem.weights,
                                                                                        problem.goal), rel=1e-9)


def test_s1_pass_rate_over_20_seeds_with_a_known_optimum():
    """S1: 20/20 seeds solve within 400 iterations; every plan and smoothed plan is dense-checked, never shorter
    than the optimum 2.0907 m (a shorter one would have cut through the sphere) and, smoothed, within 3 % of it."""
    problem = scene_problem()
    conn = LqrConnector(problem.model, 0.5, problem.weights, 60)
    settings = LqrRrtStarSettings(max_iterations=400, time_budget_s=60.0)
    lengths, solved = [], 0
    for seed in range(20):
        result = plan_lqr_rrt_star(problem, settings, np.random.default_rng(seed))
        if not result.solved:
            continue
        solved += 1
        assert_valid_plan(result.trajectory, problem)
        assert result.trajectory.path_length_m() >= S1_SHORTEST_M - 1e-9
        assert result.cost == pytest.approx(result.tree.cost[result.tree.goal_node], rel=1e-9)
        smooth = lqr_shortcut(result.trajectory, conn, problem.checker, problem.goal, problem.force_limit_N,
                              problem.velocity_limit_mps, np.random.default_rng(seed), tries=250)
        assert_valid_plan(smooth.trajectory, problem)
        assert smooth.cost_after <= smooth.cost_before
        lengths.append(smooth.trajectory.path_length_m())
    assert solved == 20
    assert min(lengths) >= S1_SHORTEST_M - 1e-9
    assert np.median(lengths) <= 1.03 * S1_SHORTEST_M


def test_anytime_mode_rewires_and_only_improves():
    problem = scene_problem()
    settings = LqrRrtStarSettings(max_iterations=250, time_budget_s=60.0, anytime=True)
    result = plan_lqr_rrt_star(problem, settings, np.random.default_rng(3))
    assert result.solved and result.stop_reason == "iterations" and result.iterations == 250
    costs = [s.cost for s in result.solutions]
    assert all(b < a for a, b in itertools.pairwise(costs))
    assert result.cost == pytest.approx(costs[-1], rel=1e-9)
    assert len(result.rewires) > 0 and all(ev.new_cost < ev.old_cost for ev in result.rewires)
    assert result.tree.parent[result.tree.goal_node] == result.path[-2]
    _tree_is_consistent(result, problem)
    assert_valid_plan(result.trajectory, problem)


def test_same_seed_same_plan():
    problem = scene_problem()
    settings = LqrRrtStarSettings(max_iterations=300, time_budget_s=60.0)
    a = plan_lqr_rrt_star(problem, settings, np.random.default_rng(42))
    b = plan_lqr_rrt_star(problem, settings, np.random.default_rng(42))
    np.testing.assert_array_equal(a.trajectory.x, b.trajectory.x)
    np.testing.assert_array_equal(a.tree.parent, b.tree.parent)


def test_unreachable_goal_returns_the_partial_tree():
    # A wall spanning the whole keep-in box separates start and goal.
    scene = Scene(keep_in=(Box([-1, -1, -1], [3, 1, 1]),),
                  keep_out=(Ellipsoid.from_semi_axes([1.0, 0.0, 0.0], [0.1, 5.0, 5.0]),))
    problem = PlanningProblem(np.zeros(6), np.array([2.0, 0, 0, 0, 0, 0]), MODEL, np.full(3, 0.5), np.full(3, 0.2),
                              CollisionChecker(scene), [[-1, -1, -1]], [[3, 1, 1]], scene_problem().weights)
    result = plan_lqr_rrt_star(problem, LqrRrtStarSettings(max_iterations=60), np.random.default_rng(0))
    assert result.status == "no_solution" and result.trajectory is None and result.path == ()
    assert len(result.tree) > 5 and result.tree.goal_node == -1
    assert np.all(result.tree.states[:, 0] < 1.0)  # nothing beyond the wall
    assert result.stop_reason == "iterations"
