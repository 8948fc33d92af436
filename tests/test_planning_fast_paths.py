"""The planners' fast paths agree with the general computations they replace.

Each fast path is checked against an independent evaluation: the single-pair limit check against the batched one,
the matmul connection against the einsum of the maps, the scalar steering end state against the rollout, the uniform
refinement against exact propagation, the broad phase of ``points_free`` against the overlap test on every point,
the box draw against ``Generator.choice``.
"""

from __future__ import annotations

import numpy as np
import pytest

from oacli.geometry import Box, Ellipsoid, Scene
from oacli.geometry.collision import CollisionChecker, Pieces, RobotBody
from oacli.planning.steering import LqrConnector
from oacli.planning.translational import CostWeights, TranslationalTrajectory
from tests.model_helpers import mass_model
from tests.plan_checks import scene_problem

WEIGHTS = CostWeights(np.array([0.1, 0.0, 0.2]), np.array([0.0, 0.3, 0.0]), np.array([1.0, 1.0, 2.0]), 0.1)


def _pair(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x_a, x_b, goal = rng.normal(size=6) * 0.3, rng.normal(size=6) * 0.3, rng.normal(size=6) * 0.1
    x_a[3:] *= 0.3
    x_b[3:] *= 0.3
    return x_a, x_b, goal


@pytest.mark.parametrize("max_steps", [30, 120])
def test_single_pair_limit_check_matches_the_batched_check(max_steps):
    conn = LqrConnector(mass_model(9.6), 0.5, WEIGHTS, max_steps)
    rng = np.random.default_rng(3)
    f_lim, v_lim = np.full(3, 0.5), np.full(3, 0.2)
    seen = set()
    for _ in range(25):
        x_a, x_b, goal = _pair(rng)
        steps = np.sort(rng.choice(max_steps + 1, 15, replace=False))
        for subset in (steps, None):
            f1, v1 = conn.within_limits(x_a, x_b, goal, f_lim, v_lim, subset)
            f2, v2 = conn.within_limits(np.stack([x_a, x_a]), np.stack([x_b, x_b]), goal, f_lim, v_lim, subset)
            np.testing.assert_array_equal(f1[0], f2[0])
            np.testing.assert_array_equal(v1[0], v2[0])
            seen.update(f1[0].tolist())
    assert seen == {True, False}  # both verdicts occurred: the comparison was not vacuous


def test_connection_trajectory_matches_the_einsum_of_its_maps_and_follows_the_dynamics():
    conn = LqrConnector(mass_model(9.6), 0.5, WEIGHTS, 40)
    rng = np.random.default_rng(4)
    for _ in range(30):
        x_a, x_b, goal = _pair(rng)
        n = int(rng.integers(2, 41))
        traj = conn.trajectory(x_a, x_b, goal, n)
        y = conn._y(x_a, x_b, goal)[0]
        u = np.einsum("ija,ia->ji", conn._g[:, n, :n], y)
        states = np.einsum("ikja,ia->kji", conn._x[:, n, : n + 1], y)
        np.testing.assert_allclose(traj.u, u, rtol=0, atol=1e-12)
        np.testing.assert_allclose(traj.x[1:-1, 0:3], states[1:-1, 0, :], rtol=0, atol=1e-12)
        np.testing.assert_allclose(traj.x[1:-1, 3:6], states[1:-1, 1, :], rtol=0, atol=1e-12)
        assert traj.zoh_residual() < 1e-9
        assert not traj.x.flags.writeable and not traj.u.flags.writeable


def test_steering_end_state_is_the_last_state_of_the_saturated_rollout():
    conn = LqrConnector(mass_model(9.6), 0.5, WEIGHTS, 10)
    rng = np.random.default_rng(5)
    f_lim, v_lim = np.full(3, 0.1), np.full(3, 0.05)  # tight: the clipping is active
    for _ in range(30):
        x_a, x_b, goal = _pair(rng)
        x_a[3:6] = np.clip(x_a[3:6], -v_lim, v_lim)  # a start within the limits (as a tree node is)
        steps = int(rng.integers(2, 11))
        roll = conn.saturated_rollout(x_a, x_b, goal, steps, f_lim, v_lim)
        np.testing.assert_array_equal(conn.saturated_end(x_a, x_b, goal, steps, f_lim, v_lim), roll.x[-1])
        assert np.all(np.abs(roll.u) <= f_lim * (1 + 1e-12))
        assert np.all(np.abs(roll.x[:, 3:6]) <= v_lim * (1 + 1e-12))
        assert roll.zoh_residual() < 1e-12


def test_uniform_refinement_matches_exact_propagation():
    rng = np.random.default_rng(6)
    forces = rng.normal(size=(12, 3)) * 0.2
    traj = TranslationalTrajectory.from_forces(rng.normal(size=6), forces, 0.5, mass_model(9.6), t0=2.0)
    fine = traj.refined(0.1)
    expected = TranslationalTrajectory.from_forces(traj.x[0], np.repeat(forces, 5, axis=0), 0.1, traj.model, t0=2.0)
    assert len(fine) == 61
    np.testing.assert_allclose(fine.t, expected.t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fine.x, expected.x, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fine.x[::5], traj.x)  # the original samples are kept bit-exact
    np.testing.assert_array_equal(fine.u, np.repeat(forces, 5, axis=0))


@pytest.mark.parametrize("radius", [0.0, 0.25])
def test_points_free_broad_phase_agrees_with_the_overlap_test_everywhere(radius):
    scene = Scene(keep_in=(Box([-1, -1, -1], [3, 1, 1]), Box([2.5, -0.5, -0.5], [4.0, 0.5, 0.5])),
                  keep_out=(Ellipsoid.from_semi_axes([1.0, 0.0, 0.0], [0.3, 0.5, 0.2]),
                            Ellipsoid.from_semi_axes([2.8, 0.2, 0.1], [0.1, 0.1, 0.4])))
    checker = CollisionChecker(scene, RobotBody.sphere(radius))
    rng = np.random.default_rng(7)
    points = rng.uniform([-1.2, -1.2, -1.2], [4.2, 1.2, 1.2], size=(4000, 3))
    expected = checker.in_keep_in(points) & np.all(checker.clearance_sq(points) >= 1.0, axis=-1)
    got = checker.points_free(points)
    np.testing.assert_array_equal(got, expected)
    assert 0 < got.sum() < got.size
    near = np.linalg.norm(points[:, None, :] - checker._centers, axis=-1) <= checker._broad_radius
    assert np.any(near.any(axis=1) & ~expected)  # the exact test decided some near points
    np.testing.assert_array_equal(checker.points_free(points[7]), expected[7])  # a single point, shape ()


def test_box_draw_is_the_draw_of_generator_choice():
    from oacli.planning.problem import PlanningProblem

    base = scene_problem()
    lower = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0]])
    upper = lower + np.array([[3.0, 1.0, 1.0], [1.0, 1.0, 1.0], [2.0, 2.0, 0.5]])
    problem = PlanningProblem(base.start, base.goal, base.model, base.force_limit_N, base.velocity_limit_mps,
                              base.checker, lower, upper, base.weights)
    volumes = np.prod(upper - lower, axis=1)
    ours, ref = np.random.default_rng(11), np.random.default_rng(11)
    for _ in range(300):
        x = problem.sample_state(ours)
        b = int(ref.choice(3, p=volumes / volumes.sum()))
        r = ref.uniform(lower[b], upper[b])
        v = ref.uniform(-base.velocity_limit_mps, base.velocity_limit_mps)
        np.testing.assert_array_equal(x, np.concatenate([r, v]))


def test_batched_connections_match_each_connection_and_are_zero_beyond_their_horizon():
    conn = LqrConnector(mass_model(9.6), 0.5, WEIGHTS, 40)
    rng = np.random.default_rng(12)
    for _ in range(10):
        x_a = np.stack([_pair(rng)[0] for _ in range(9)])
        x_b, goal = _pair(rng)[1:]
        steps = rng.integers(2, 41, size=9)
        for starts in (x_a, x_a[0]):  # one start per connection, or one for all
            u, states = conn.batch(starts, x_b, goal, steps)
            s = int(steps.max())
            assert u.shape == (9, s, 3) and states.shape == (9, s + 1, 6)
            for c, n in enumerate(steps.tolist()):
                traj = conn.trajectory(np.broadcast_to(starts, (9, 6))[c], x_b, goal, n)
                np.testing.assert_allclose(u[c, :n], traj.u, rtol=0, atol=1e-12)
                np.testing.assert_allclose(states[c, : n + 1], traj.x, rtol=0, atol=1e-12)
                np.testing.assert_array_equal(states[c, n], x_b)  # the end point exactly
                assert not np.any(u[c, n:]) and not np.any(states[c, n + 1 :])


def test_connection_costs_are_the_exact_costs_of_the_connections():
    conn = LqrConnector(mass_model(9.6), 0.5, WEIGHTS, 30)
    rng = np.random.default_rng(13)
    x_a = np.stack([_pair(rng)[0] for _ in range(5)])
    x_b, goal = _pair(rng)[1:]
    costs = conn.costs(x_a, x_b, goal)
    assert costs.shape == (5, 31) and np.all(np.isinf(costs[:, :2]))
    for k in range(5):
        for n in (2, 7, 30):
            exact = conn.trajectory(x_a[k], x_b, goal, n).cost(WEIGHTS, goal)  # the integral of Eq. 5, per interval
            np.testing.assert_allclose(costs[k, n], exact, rtol=1e-9)


@pytest.mark.parametrize("body", ["point", "sphere", "ellipsoid"])
def test_sample_filter_never_rejects_a_free_position_and_catches_deep_collisions(body):
    from oacli.planning.sample_filter import SampleFilter

    robot = {"point": RobotBody.point(), "sphere": RobotBody.sphere(0.25),
             "ellipsoid": RobotBody.ellipsoid([0.3, 0.15, 0.2], np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]))}[body]
    scene = Scene(keep_in=(Box([-1, -1, -1], [3, 1, 1]), Box([2.5, -0.5, -0.5], [4.0, 0.5, 0.5])),
                  keep_out=(Ellipsoid.from_semi_axes([1.0, 0.0, 0.0], [0.3, 0.5, 0.2]),
                            Ellipsoid.from_semi_axes([2.8, 0.2, 0.1], [0.1, 0.1, 0.4])))
    checker = CollisionChecker(scene, robot)
    filt = SampleFilter(checker)
    rng = np.random.default_rng(14)
    points = rng.uniform([-1.3, -1.3, -1.3], [4.3, 1.3, 1.3], size=(20000, 3))
    rejected = filt.colliding(points)
    free = checker.points_free(points)
    assert not np.any(rejected & free)  # sufficient for a collision: never a free position
    assert rejected.sum() > 0.5 * (~free).sum()  # and it rejects most colliding ones
    assert np.all(filt.colliding(checker._centers))  # every zone centre
    assert filt.colliding(np.array([0.0, 1.0 + 1e-6, 0.0])) and not filt.colliding(np.array([0.0, 1.0, 0.0]))
    states = np.zeros((2, 4, 6))
    states[:, :, 0:3] = [-0.5, 0.0, 0.0]  # free
    states[0, 3, 0:3] = checker._centers[0]  # a colliding sample at the horizon of connection 0 ...
    states[1, 3, 0:3] = checker._centers[0]  # ... and beyond the horizon of connection 1 (padding)
    np.testing.assert_array_equal(filt.connections_colliding(states, np.array([3, 2])), [True, False])


@pytest.mark.parametrize("radius_m", [0.0, 0.25])
def test_is_free_gives_the_verdict_of_check_on_random_pieces(radius_m):
    """is_free's outer-ellipsoid pre-pass and keep-in shortcut agree with the full check, both verdicts seen."""
    scene = Scene(keep_in=(Box(np.array([0.0, -1.0, -1.0]), np.array([6.0, 1.0, 1.0])),),
                  keep_out=(Ellipsoid(np.array([1.5, 0.35, 0.0]), np.diag(1.0 / np.array([0.35, 0.9, 1.2]) ** 2)),
                            Ellipsoid(np.array([3.0, -0.35, 0.0]), np.diag(1.0 / np.array([0.35, 0.9, 1.2]) ** 2))))
    checker = CollisionChecker(scene, RobotBody.sphere(radius_m))
    rng = np.random.default_rng(11)
    verdicts = []
    for _ in range(300):
        m = int(rng.integers(1, 12))
        p0 = rng.uniform([0.0, -1.0, -1.0], [6.0, 1.0, 1.0], size=(m, 3))
        pieces = Pieces(p0, rng.normal(size=(m, 3)) * 0.2, rng.normal(size=(m, 3)) * 0.05, np.full(m, 0.5))
        full = checker.check(pieces).free
        assert checker.is_free(pieces) == full
        verdicts.append(full)
    assert any(verdicts) and not all(verdicts)


def test_points_free_of_one_position_matches_the_vectorised_test():
    """The plain-float test of one position equals the vectorised one (point robot), for free and colliding points."""
    scene = Scene(keep_in=(Box(np.array([0.0, -1.0, -1.0]), np.array([6.0, 1.0, 1.0])),),
                  keep_out=(Ellipsoid(np.array([1.5, 0.35, 0.0]), np.diag(1.0 / np.array([0.35, 0.9, 1.2]) ** 2)),))
    checker = CollisionChecker(scene)
    pts = np.random.default_rng(5).uniform([-0.2, -1.2, -1.2], [6.2, 1.2, 1.2], size=(3000, 3))
    many = checker.points_free(pts)
    one = np.array([bool(checker.points_free(p)) for p in pts])
    np.testing.assert_array_equal(one, many)
    assert many.any() and not many.all()
