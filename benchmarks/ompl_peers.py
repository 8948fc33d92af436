"""OMPL peers of the planner benchmark (PyPI ``ompl`` 2.x, the ``bench`` extra; never an oacli dependency).

* :func:`ompl_control_rrt`: OMPL's control-based RRT (``ompl.control.RRT``) on the same double integrator
  (6-D state with the same position and velocity bounds, 3-D force control within the same limits, the exact
  double-integrator propagator as a Python callback), the same point validity function (oacli's
  ``CollisionChecker.points_free``), checked by OMPL at its propagation steps only.
* :func:`ompl_rrt_star_length`: OMPL's geometric RRT* in the 3-D position space with the same validity function
  and OMPL's default motion validator, followed by ``PathSimplifier.simplifyMax`` (the geometric baseline for the
  path length).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import control as oc
from ompl import geometric as og
from ompl import util as ou

ou.setLogLevel(ou.LogLevel.LOG_NONE)


def seed_ompl(seed: int) -> None:
    """Seed OMPL's global RNG (effective only before OMPL first draws a random number in this process)."""
    ou.RNG.setSeed(int(seed))


@dataclass(frozen=True)
class ControlPath:
    """A solution of OMPL's control RRT as zero-order-hold samples: times, states and held forces."""

    t: np.ndarray  # (n+1,)
    x: np.ndarray  # (n+1, 6)
    u: np.ndarray  # (n, 3)


def _bounds(lower, upper) -> ob.RealVectorBounds:
    b = ob.RealVectorBounds(len(lower))
    for i, (lo, hi) in enumerate(zip(lower, upper, strict=True)):
        b.setLow(i, float(lo))
        b.setHigh(i, float(hi))
    return b


def ompl_control_rrt(
    start: np.ndarray, goal: np.ndarray, box_lower: np.ndarray, box_upper: np.ndarray, mass_kg: float,
    force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray, valid_position: Callable[[np.ndarray], bool],
    *, time_budget_s: float, step_s: float = 0.5, max_steps: int = 10, goal_threshold: float = 0.1,
) -> tuple[bool, float, ControlPath | None]:
    """Plan with ``ompl.control.RRT``; returns ``(exact solution found, wall time [s], path)``."""
    space = ob.RealVectorStateSpace(6)
    space.setBounds(_bounds(np.r_[box_lower, -velocity_limit_mps], np.r_[box_upper, velocity_limit_mps]))
    cspace = oc.RealVectorControlSpace(space, 3)
    cspace.setBounds(_bounds(-force_limit_N, force_limit_N))
    ss = oc.SimpleSetup(cspace)
    si = ss.getSpaceInformation()

    def is_valid(state) -> bool:
        return bool(si.satisfiesBounds(state) and valid_position(np.array([state[0], state[1], state[2]])))

    def propagate(state, control, duration, result) -> None:
        for i in range(3):
            a = control[i] / mass_kg
            result[i] = state[i] + state[3 + i] * duration + 0.5 * a * duration * duration
            result[3 + i] = state[3 + i] + a * duration

    ss.setStateValidityChecker(is_valid)
    ss.setStatePropagator(propagate)
    si.setPropagationStepSize(step_s)
    si.setMinMaxControlDuration(1, max_steps)
    s, g = space.allocState(), space.allocState()
    for i in range(6):
        s[i], g[i] = float(start[i]), float(goal[i])
    ss.setStartAndGoalStates(s, g, goal_threshold)
    ss.setPlanner(oc.RRT(si))
    t0 = time.perf_counter()
    status = ss.solve(time_budget_s)
    wall = time.perf_counter() - t0
    if not (bool(status) and ss.haveExactSolutionPath()):
        return False, wall, None
    path = ss.getSolutionPath()
    states = path.getStates()
    controls = path.getControls()
    durations = path.getControlDurations()
    x = np.array([[st[i] for i in range(6)] for st in states])
    u = np.array([[c[i] for i in range(3)] for c in controls]).reshape(-1, 3)
    t = np.concatenate([[0.0], np.cumsum(durations)])
    return True, wall, ControlPath(t, x, u)


def ompl_rrt_star_length(
    start: np.ndarray, goal: np.ndarray, box_lower: np.ndarray, box_upper: np.ndarray,
    valid_position: Callable[[np.ndarray], bool], *, time_budget_s: float, resolution: float = 0.001,
) -> tuple[bool, float, np.ndarray | None]:
    """``og.RRTstar`` for ``time_budget_s`` then ``simplifyMax``; returns ``(solved, length [m], waypoints)``.

    ``resolution`` is OMPL's motion-validation step as a fraction of the space's extent (OMPL's default 0.01
    lets simplified segments cut into the ellipsoids by centimetres; 0.001 checks every ~5 mm here).
    """
    space = ob.RealVectorStateSpace(3)
    space.setBounds(_bounds(box_lower, box_upper))
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(lambda st: bool(valid_position(np.array([st[0], st[1], st[2]]))))
    s, g = space.allocState(), space.allocState()
    for i in range(3):
        s[i], g[i] = float(start[i]), float(goal[i])
    ss.setStartAndGoalStates(s, g)
    ss.getSpaceInformation().setStateValidityCheckingResolution(resolution)
    ss.setPlanner(og.RRTstar(ss.getSpaceInformation()))
    status = ss.solve(time_budget_s)
    if not (bool(status) and ss.haveExactSolutionPath()):
        return False, float("nan"), None
    path = ss.getSolutionPath()
    ss.getPathSimplifier().simplifyMax(path)
    pts = np.array([[st[i] for i in range(3)] for st in path.getStates()])
    return True, float(path.length()), pts
