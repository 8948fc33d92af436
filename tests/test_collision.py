"""Continuous collision checks: exact segment/curve-vs-ellipsoid tests, ellipsoid overlap, keep-in unions.

Analytic cases have closed-form answers; random cases are compared with dense sampling (which may only *miss*
collisions, never invent them, so the exact check must agree whenever the sampled margin is clear).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from oacli.geometry import Box, Ellipsoid, Scene
from oacli.geometry.collision import CollisionChecker, Pieces, RobotBody
from oacli.geometry.overlap import EllipsoidPair, ellipsoids_overlap
from oacli.geometry.quartic import quartic_minimum
from oacli.geometry.verify import dense_check, dense_positions, point_ellipsoid_distance
from tests.model_helpers import mass_model

SPHERE = Scene(keep_out=(Ellipsoid.from_semi_axes([1.0, 0.0, 0.0], [0.3, 0.3, 0.3]),))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# ------------------------------------------------------------------------------------------------------------
# Straight segments against a sphere and an ellipsoid: closed forms
# ------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("offset", "expect_free"),
    [
        (0.0, False),  # through the centre
        (0.299, False),  # 1 mm inside the sphere at the closest approach
        (0.3, True),  # tangent: touching is allowed (free space is (p-c)ᵀP(p-c) >= 1, [Doerr2021] Eq. 12)
        (0.301, True),
    ],
)
def test_segment_past_a_sphere_matches_the_distance_of_the_line(offset, expect_free):
    checker = CollisionChecker(SPHERE)
    seg = Pieces.segments([[0.0, offset, 0.0]], [[2.0, offset, 0.0]])
    assert bool(checker.check(seg).free) is expect_free


def test_tunnelling_through_a_thin_ellipsoid_is_caught_although_both_ends_are_free():
    # A wall 2 mm thick: both end points (and any 10 cm sampling) are outside, the segment crosses it.
    wall = Scene(keep_out=(Ellipsoid.from_semi_axes([1.0, 0.0, 0.0], [0.001, 0.5, 0.5]),))
    checker = CollisionChecker(wall)
    start, end = np.array([0.0, 0.1, 0.0]), np.array([2.0, 0.1, 0.0])
    samples = start + np.linspace(0, 1, 21)[:, None] * (end - start)  # every 10 cm, skips x = 1 ± 1 mm
    assert not np.any(wall.in_keep_out(samples[:, :])[np.abs(samples[:, 0] - 1.0) > 0.001])
    report = checker.check(Pieces.segments([start], [end]))
    assert not report.free
    assert report.kind == "keep_out" and report.zone == 0
    # The witness lies inside the wall (unit-duration segment: τ is the fraction of the way).
    witness = start + report.time_in_piece_s * (end - start)
    assert wall.in_keep_out(witness)


def test_segment_against_a_rotated_ellipsoid_matches_the_closed_form_in_its_own_frame():
    """A line hits an ellipsoid iff, mapped by diag(1/a) Rᵀ to the unit sphere, its distance to the origin is < 1."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        rot = random_rotation(rng)
        axes = rng.uniform(0.1, 1.0, 3)
        center = rng.normal(size=3)
        e = Ellipsoid.from_semi_axes(center, axes, rot)
        checker = CollisionChecker(Scene(keep_out=(e,)))
        a, b = center + rng.normal(size=3) * 2.0, center + rng.normal(size=3) * 2.0
        to_unit = np.diag(1.0 / axes) @ rot.T
        ua, ub = to_unit @ (a - center), to_unit @ (b - center)
        d = ub - ua
        s = np.clip(-(ua @ d) / (d @ d), 0.0, 1.0)
        dist = np.linalg.norm(ua + s * d)
        if abs(dist - 1.0) < 1e-9:
            continue
        assert bool(checker.check(Pieces.segments([a], [b])).free) == (dist > 1.0)


def test_curved_piece_is_judged_by_the_curve_not_by_its_chord():
    checker = CollisionChecker(SPHERE)
    # From (0, 0, 0) to (2, 0, 0) in 2 s, bulging to y = 0.5 at the midpoint: the chord crosses the sphere,
    # the parabola y(τ) = 0.5 τ (2 - τ)... passes above it (y(1) = 0.5 > 0.3).
    curve = Pieces(np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 0.0]]), np.array([[0.0, -1.0, 0.0]]),
                   np.array([2.0]))
    assert np.allclose(curve.position(np.array([2.0])), [[2.0, 0.0, 0.0]])
    assert checker.check(curve).free
    assert not checker.check(Pieces.segments([[0.0, 0.0, 0.0]], [[2.0, 0.0, 0.0]])).free
    # The same bulge, too small (y(1) = 0.25 < 0.3): caught between the samples at the ends.
    flat = Pieces(np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 0.5, 0.0]]), np.array([[0.0, -0.5, 0.0]]),
                  np.array([2.0]))
    report = checker.check(flat)
    assert not report.free and 0.0 < report.time_in_piece_s < 2.0


# ------------------------------------------------------------------------------------------------------------
# The exact quartic minimum
# ------------------------------------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(coeffs=st.lists(st.floats(-10.0, 10.0), min_size=5, max_size=5), lead=st.sampled_from([1.0, 1e-6, 0.0]))
def test_quartic_minimum_is_never_above_a_dense_sample_and_is_attained(coeffs, lead):
    c = np.array(coeffs)
    c[4] = abs(c[4]) * lead  # quartics, nearly-cubic and exactly-cubic/quadratic cases
    value, arg = quartic_minimum(c[None, :])
    s = np.linspace(0.0, 1.0, 20001)
    f = np.polyval(c[::-1], s)
    assert value[0] <= f.min() + 1e-9 * (1.0 + np.abs(c).sum())
    assert value[0] == pytest.approx(np.polyval(c[::-1], arg[0]), abs=1e-12 * (1 + np.abs(c).sum()))
    assert 0.0 <= arg[0] <= 1.0


# ------------------------------------------------------------------------------------------------------------
# Ellipsoid-on-ellipsoid ([ReSWARM2023] §4.2.2)
# ------------------------------------------------------------------------------------------------------------


def test_clearance_reduces_to_the_closed_forms_for_spheres_and_points():
    rng = np.random.default_rng(3)
    for _ in range(50):
        a, r = rng.uniform(0.1, 1.0, 2)
        delta = rng.normal(size=3)
        g, _ = EllipsoidPair.build(np.zeros(3), a * a * np.eye(3), r * r * np.eye(3)).clearance_sq(delta)
        assert g == pytest.approx(delta @ delta / (a + r) ** 2, rel=1e-10)
        axes, rot = rng.uniform(0.1, 1.0, 3), random_rotation(rng)
        p = rot @ np.diag(1.0 / axes**2) @ rot.T
        g_point, _ = EllipsoidPair.build(np.zeros(3), np.linalg.inv(p), np.zeros((3, 3))).clearance_sq(delta)
        assert g_point == pytest.approx(delta @ p @ delta, rel=1e-12)


def _brute_overlap(c1, sigma1, c2, sigma2, n=60000, seed=0):
    """Smallest obstacle-metric value over points sampled on and inside the second ellipsoid."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    radius = rng.uniform(0, 1, n) ** (1 / 3)
    radius[: n // 2] = 1.0  # half on the surface
    chol = np.linalg.cholesky(sigma2)
    pts = c2 + (d * radius[:, None]) @ chol.T
    p1 = np.linalg.inv(sigma1)
    diff = pts - c1
    return np.einsum("ij,jk,ik->i", diff, p1, diff).min()


def test_ellipsoid_overlap_agrees_with_sampling_the_robot_ellipsoid():
    rng = np.random.default_rng(11)
    decided = 0
    for _ in range(150):
        r1, r2 = random_rotation(rng), random_rotation(rng)
        s1 = r1 @ np.diag(rng.uniform(0.1, 0.8, 3) ** 2) @ r1.T
        s2 = r2 @ np.diag(rng.uniform(0.05, 0.5, 3) ** 2) @ r2.T
        c1, c2 = np.zeros(3), rng.normal(size=3) * 0.8
        g, _ = EllipsoidPair.build(c1, s1, s2).clearance_sq(c2 - c1)
        sampled_min = _brute_overlap(c1, s1, c2, s2)
        if sampled_min < 0.995:  # a sampled point of the robot lies well inside the obstacle
            assert ellipsoids_overlap(c1, s1, c2, s2)
            decided += 1
        elif g > 1.01:  # the test says clearly separated: sampling must not find overlap either
            assert sampled_min >= 1.0 - 1e-12
            decided += 1
    assert decided > 100


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000))
def test_continuous_check_of_an_ellipsoid_robot_never_passes_an_overlap(seed):
    """Soundness: a piece reported free has no sampled time at which the two ellipsoids overlap."""
    rng = np.random.default_rng(seed)
    obstacle = Ellipsoid.from_semi_axes(rng.normal(size=3) * 0.2, rng.uniform(0.1, 0.8, 3), random_rotation(rng))
    robot = RobotBody.ellipsoid(rng.uniform(0.02, 0.4, 3), random_rotation(rng))
    checker = CollisionChecker(Scene(keep_out=(obstacle,)), robot)
    m = 30
    pieces = Pieces(rng.normal(size=(m, 3)) * 1.2, rng.normal(size=(m, 3)), rng.normal(size=(m, 3)) * 2,
                    rng.uniform(0.1, 1.5, m))
    report = checker.check(pieces)
    tau = np.linspace(0.0, 1.0, 801)
    for i in range(m):
        t = tau * pieces.h[i]
        pts = pieces.p0[i] + np.outer(t, pieces.v0[i]) + 0.5 * np.outer(t * t, pieces.acc[i])
        g = checker.clearance_sq(pts)[:, 0]
        if report.piece_free[i]:
            assert g.min() >= 1.0 - 1e-9
        elif g.min() > 1.0 + 1e-3:
            # Reported colliding although every sample is clear: only allowed if it is within the sampling gap.
            tight = np.linspace(0.0, pieces.h[i], 40001)
            pts = pieces.p0[i] + np.outer(tight, pieces.v0[i]) + 0.5 * np.outer(tight**2, pieces.acc[i])
            assert checker.clearance_sq(pts)[:, 0].min() < 1.0 + 1e-6
    assert report.undecided == 0


def test_vectorised_check_equals_one_piece_at_a_time():
    rng = np.random.default_rng(5)
    scene = Scene(
        keep_in=(Box([-2, -2, -2], [2, 2, 2]),),
        keep_out=tuple(Ellipsoid.from_semi_axes(rng.normal(size=3), rng.uniform(0.1, 0.6, 3), random_rotation(rng))
                       for _ in range(4)),
    )
    checker = CollisionChecker(scene, RobotBody.sphere(0.1))
    pieces = Pieces(rng.normal(size=(60, 3)), rng.normal(size=(60, 3)) * 0.5, rng.normal(size=(60, 3)),
                    rng.uniform(0.2, 1.0, 60))
    together = checker.check(pieces).piece_free
    alone = [checker.check(Pieces(pieces.p0[i:i + 1], pieces.v0[i:i + 1], pieces.acc[i:i + 1], pieces.h[i:i + 1]))
             .free for i in range(60)]
    np.testing.assert_array_equal(together, alone)
    assert 0 < together.sum() < 60  # both outcomes occur


# ------------------------------------------------------------------------------------------------------------
# Keep-in boxes
# ------------------------------------------------------------------------------------------------------------


def test_a_piece_may_cross_from_one_keep_in_box_into_an_adjacent_one():
    scene = Scene(keep_in=(Box([0, 0, 0], [1, 1, 1]), Box([1, 0, 0], [3, 1, 1])))
    checker = CollisionChecker(scene)
    assert checker.check(Pieces.segments([[0.5, 0.5, 0.5]], [[2.5, 0.5, 0.5]])).free


def test_cutting_the_inner_corner_of_an_l_shaped_keep_in_is_caught_between_samples():
    scene = Scene(keep_in=(Box([0, 0, 0], [1, 3, 1]), Box([0, 0, 0], [3, 1, 1])))
    checker = CollisionChecker(scene)
    # Both ends inside, the straight line passes through (1.5, 1.5): outside the union.
    report = checker.check(Pieces.segments([[0.5, 2.5, 0.5]], [[2.5, 0.5, 0.5]]))
    assert not report.free and report.kind == "keep_in"
    # Going around the corner in two segments is fine.
    ok = Pieces.segments([[0.5, 2.5, 0.5], [0.5, 0.5, 0.5]], [[0.5, 0.5, 0.5], [2.5, 0.5, 0.5]])
    assert checker.check(ok).free


def test_a_curved_excursion_out_of_the_box_between_samples_is_caught():
    checker = CollisionChecker(Scene(keep_in=(Box([-1, -1, -1], [1, 1, 1]),)))
    # y(τ) = 1.9 τ - 0.95 τ², τ in [0, 2]: starts and ends at y = 0, peaks at y = 0.95 (inside) ...
    inside = Pieces(np.zeros((1, 3)), np.array([[0.0, 1.9, 0.0]]), np.array([[0.0, -1.9, 0.0]]), np.array([2.0]))
    assert checker.check(inside).free
    # ... and with a peak at y = 1.05 it leaves the box although both ends are at y = 0.
    outside = Pieces(np.zeros((1, 3)), np.array([[0.0, 2.1, 0.0]]), np.array([[0.0, -2.1, 0.0]]), np.array([2.0]))
    assert not checker.check(outside).free


# ------------------------------------------------------------------------------------------------------------
# The independent dense verifier
# ------------------------------------------------------------------------------------------------------------


def test_point_to_ellipsoid_distance_matches_sampling_its_surface():
    rng = np.random.default_rng(2)
    rot, axes, center = random_rotation(rng), np.array([0.3, 0.7, 1.1]), rng.normal(size=3)
    u, v = np.meshgrid(np.linspace(0, np.pi, 600), np.linspace(0, 2 * np.pi, 1200))
    surface = np.stack([axes[0] * np.sin(u) * np.cos(v), axes[1] * np.sin(u) * np.sin(v), axes[2] * np.cos(u)],
                       -1).reshape(-1, 3) @ rot.T + center
    pts = center + rng.normal(size=(15, 3)) * 1.5
    dist = point_ellipsoid_distance(pts, center, axes, rot)
    for p, d in zip(pts, dist, strict=True):
        if d > 0:
            assert d == pytest.approx(np.linalg.norm(surface - p, axis=1).min(), abs=2e-5)
        else:
            assert Ellipsoid.from_semi_axes(center, axes, rot).contains(p)


def test_dense_positions_fixed_substeps_follow_the_held_force_parabola():
    """With ``substeps`` every step gets that many points, the last on the next sample (exact under the held
    force: p_k + v_k τ + ½ (f_k/m) τ²)."""
    t = np.array([0.0, 0.5, 1.5])
    x = np.zeros((3, 6))
    x[0, 3:6] = [0.1, -0.2, 0.0]
    f = np.array([[2.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    mass = 4.0
    for k in range(2):
        h = t[k + 1] - t[k]
        x[k + 1, 0:3] = x[k, 0:3] + x[k, 3:6] * h + 0.5 * f[k] / mass * h**2
        x[k + 1, 3:6] = x[k, 3:6] + f[k] / mass * h
    times, pts = dense_positions(t, x, f / mass, substeps=4)
    np.testing.assert_allclose(times, [0.0, 0.125, 0.25, 0.375, 0.5, 0.75, 1.0, 1.25, 1.5])
    np.testing.assert_allclose(pts[[0, 4, 8]], x[:, 0:3], atol=1e-15)
    tau = times[5] - t[1]
    np.testing.assert_allclose(pts[5], x[1, 0:3] + x[1, 3:6] * tau + 0.5 * f[1] / mass * tau**2, atol=1e-15)


def test_dense_check_spacing_and_verdicts():
    t = np.array([0.0, 1.0, 2.0])
    x = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1.0, 0.0, 0.0], [2.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    f = np.zeros((2, 3))
    _, pts = dense_positions(t, x, f / 1.0)
    assert np.linalg.norm(np.diff(pts, axis=0), axis=1).max() <= 0.005 + 1e-12
    bad = dense_check(t, x, f, mass_model(1.0), SPHERE, robot_radius_m=0.0)
    assert not bad.ok and bad.keep_out_violations > 0
    x_ok = x.copy()
    x_ok[:, 1] = 0.4
    good = dense_check(t, x_ok, f, mass_model(1.0), SPHERE, robot_radius_m=0.05)
    assert good.ok and good.min_clearance_m == pytest.approx(0.4 - 0.3 - 0.05, abs=1e-6)
    assert not dense_check(t, x_ok, f, mass_model(1.0), SPHERE, robot_radius_m=0.15).ok
