"""The OMPL peers of benchmarks/bench_planners.py check exactly oacli's geometry: the scalar validity check of
benchmarks/ompl_peers.py against oacli's vectorised ``CollisionChecker.points_free`` on random points (all keep-in
boxes, keep-out ellipsoids grown by the robot), and the stop-and-go time parametrisation of OMPL's RRT* paths."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.ompl_peers import OMPL_IMPORT_ERROR, ScalarValidity, keep_in_bounds, stop_and_go
from oacli.config import load_config
from oacli.geometry import Scene
from oacli.geometry.collision import CollisionChecker, RobotBody
from oacli.geometry.shapes import Box, Ellipsoid
from oacli.planning.translational import TranslationalTrajectory
from oacli.stages.plan import build_problem, resolve_segment
from tests.conftest import REPO
from tests.model_helpers import mass_model
from tests.plan_checks import S1, S2


def _checker(path, segment=None) -> CollisionChecker:
    cfg = load_config(path)
    problem, _ = build_problem(cfg, resolve_segment(cfg, segment))
    return problem.checker


def _agree(checker: CollisionChecker, rng: np.random.Generator, n: int, near: bool) -> tuple[int, int]:
    lo, hi = keep_in_bounds(checker)
    pad = 0.2 * (hi - lo)
    pts = rng.uniform(lo - pad, hi + pad, size=(n, 3))
    if near:  # also points close to the grown ellipsoids' surfaces, where the Newton search decides
        for e in checker.scene.keep_out:
            axes, rot = e.principal_axes()
            d = rng.standard_normal((n, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            grow = checker.robot.bounding_radius_m
            scale = rng.uniform(0.8, 1.2, (n, 1))
            pts = np.vstack([pts, e.center + (d * (axes + grow) * scale) @ rot.T])
    vec = checker.points_free(pts)
    sca = ScalarValidity(checker).points(pts)
    return int(np.sum(vec != sca)), int(np.sum(~vec))


@pytest.mark.parametrize("config,segment,robot", [
    (S1, None, None), (S2, None, None),
    (REPO / "configs" / "mission_iss.yaml", "A-B", None),
    (REPO / "configs" / "mission_iss.yaml", "C-A", None),
    (REPO / "configs" / "mission_iss.yaml", "A-B", RobotBody.ellipsoid(np.array([0.35, 0.2, 0.15]))),
])
def test_scalar_check_agrees_with_points_free(config, segment, robot) -> None:
    checker = _checker(config, segment)
    if robot is not None:  # an ellipsoidal robot: the Gilitschenski-Hanebeck search is not trivial
        checker = CollisionChecker(checker.scene, robot)
    rng = np.random.default_rng(7)
    mismatches, blocked = _agree(checker, rng, 4000, near=True)
    assert mismatches == 0
    assert blocked > 500  # the sample really exercises the obstacles and the keep-in union


def test_all_keep_in_boxes_are_used() -> None:
    """Three ISS boxes: a point in the second or third box is valid, a point in their bounding box but in none
    of them is not (ompl_peers gave OMPL only the first box before)."""
    checker = _checker(REPO / "configs" / "mission_iss.yaml", "A-B")
    check = ScalarValidity(checker)
    boxes = checker.scene.keep_in
    assert len(boxes) == 3
    for b in boxes[1:]:
        assert check(*map(float, b.center)) and checker.points_free(b.center)
    lo, _ = keep_in_bounds(checker)
    np.testing.assert_allclose(lo, np.min([b.lower for b in boxes], axis=0))
    corner = np.array([lo[0] + 1e-3, -2.0, 5.0])  # x only in box 1's range, y only in box 2's
    assert not checker.points_free(corner)
    assert not check(*map(float, corner))


def test_sphere_robot_grows_the_ellipsoid_by_its_radius() -> None:
    """Closed form: a sphere keep-out of radius a against a sphere robot of radius r is free iff |p - c| >= a + r."""
    scene = Scene(keep_in=(Box(np.full(3, -5.0), np.full(3, 5.0)),),
                  keep_out=(Ellipsoid.from_semi_axes(np.zeros(3), np.full(3, 0.5)),))
    check = ScalarValidity(CollisionChecker(scene, RobotBody.sphere(0.25)))
    assert check(0.75 + 1e-9, 0.0, 0.0)
    assert not check(0.75 - 1e-9, 0.0, 0.0)
    assert not check(0.0, 0.0, -0.7)
    assert not check(5.1, 0.0, 0.0)


def test_stop_and_go_is_flyable() -> None:
    """Rest at every vertex, within the per-axis limits, on the polyline, minimum time per segment."""
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [1.0, 0.5, 0.01], [2.0, -0.5, 0.3]])
    f_lim, v_lim, m = np.array([0.452, 0.216, 0.257]), np.full(3, 0.2), 9.58
    t, x, u = stop_and_go(pts, m, f_lim, v_lim)
    traj = TranslationalTrajectory(t, x, u, mass_model(m))
    assert traj.zoh_residual() <= 1e-12
    assert np.all(traj.max_abs_force_N() <= f_lim * (1 + 1e-12))
    assert np.all(traj.max_abs_velocity_mps() <= v_lim * (1 + 1e-12))
    np.testing.assert_allclose(traj.path_length_m(), np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)),
                               rtol=1e-9)
    # The short vertical segment: triangular profile at a = F_z/m, t = 2 sqrt(L/a).
    a_z = 0.257 / m
    i = np.flatnonzero(np.isclose(x[:, 2], 0.01) & np.isclose(x[:, 0], 1.0))[0]
    j = np.flatnonzero(np.isclose(x[:, 0], 1.0) & np.isclose(x[:, 2], 0.0))[-1]
    np.testing.assert_allclose(t[i] - t[j], 2.0 * np.sqrt(0.01 / a_z), rtol=1e-12)
    vertices = [k for k in range(len(t)) if np.any(np.all(np.isclose(x[k, 0:3], pts, atol=1e-12), axis=1))]
    assert np.all(x[vertices, 3:6] == 0.0)


@pytest.mark.skipif(OMPL_IMPORT_ERROR is not None, reason=f"OMPL not installed ({OMPL_IMPORT_ERROR})")
def test_ompl_sees_the_same_validity() -> None:
    """OMPL's own state validity (bounds + the scalar check) agrees with points_free inside the sampling box."""
    from ompl import base as ob
    from ompl import geometric as og

    checker = _checker(REPO / "configs" / "mission_iss.yaml", "C-A")
    check = ScalarValidity(checker)
    lo, hi = keep_in_bounds(checker)
    space = ob.RealVectorStateSpace(3)
    bounds = ob.RealVectorBounds(3)
    for i in range(3):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(lambda st: bool(check(st[0], st[1], st[2])))
    si = ss.getSpaceInformation()  # (no ss.setup(): OMPL 2.0.1 segfaults without start and goal)
    rng = np.random.default_rng(3)
    pts = rng.uniform(lo, hi, (2000, 3))
    state = space.allocState()
    got = []
    for p in pts:
        for i in range(3):
            state[i] = float(p[i])
        got.append(bool(si.isValid(state)))
    np.testing.assert_array_equal(np.array(got), checker.points_free(pts))
