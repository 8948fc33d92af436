"""Shared helpers of the planning tests: the benchmark scenes and an independent check of every produced path."""

from __future__ import annotations

import numpy as np

from oacli.config import load_config
from oacli.geometry.verify import dense_check
from oacli.planning.problem import PlanningProblem
from oacli.planning.translational import TranslationalTrajectory
from oacli.stages.plan import build_problem, resolve_segment
from tests.conftest import REPO

SCENES = REPO / "benchmarks" / "scenes"
S1 = SCENES / "s1_sphere.yaml"
S2 = SCENES / "s2_slalom.yaml"
#: S1's shortest collision-free path: 2 sqrt(1 - 0.3²) + 0.3 (π - 2 acos 0.3) (two tangents and an arc).
S1_SHORTEST_M = 2.0 * np.sqrt(1.0 - 0.09) + 0.3 * (np.pi - 2.0 * np.arccos(0.3))


def scene_problem(path=S1) -> PlanningProblem:
    """The planning problem of a benchmark scene config (point robot, m = 9.6 kg, 0.5 N, 0.2 m/s)."""
    cfg = load_config(path)
    problem, _ = build_problem(cfg, resolve_segment(cfg, None))
    return problem


def assert_valid_plan(traj: TranslationalTrajectory, problem: PlanningProblem, robot_radius_m: float = 0.0) -> None:
    """Independent checks of a start-to-goal trajectory.

    Dense re-check every 5 mm of the whole trajectory (goal link and splices included) by point-to-ellipsoid
    distance; the samples follow the held forces exactly; force and velocity limits hold; it starts at the start
    and ends exactly at the goal. The trajectory carries the problem's robot model itself (planner, shortcut and
    polish hand the one object on; issue 28).
    """
    assert traj.model is problem.model
    dense = dense_check(traj.t, traj.x, traj.u, traj.model, problem.checker.scene, robot_radius_m)
    assert dense.ok, dense
    assert dense.max_spacing_m <= 0.005 + 1e-9
    assert traj.zoh_residual() <= 1e-9
    assert np.all(traj.max_abs_force_N() <= problem.force_limit_N * (1 + 1e-9))
    assert np.all(traj.max_abs_velocity_mps() <= problem.velocity_limit_mps * (1 + 1e-9))
    np.testing.assert_allclose(traj.x[0], problem.start, atol=1e-12)
    np.testing.assert_array_equal(traj.x[-1], problem.goal)
