"""OMPL peers of the planner benchmark (PyPI ``ompl`` 2.x, the ``bench`` extra; never an oacli dependency).

* :class:`ScalarValidity`: the point validity check handed to OMPL, in plain Python floats (a few µs a call
  where oacli's vectorised :meth:`~oacli.geometry.collision.CollisionChecker.points_free` costs ~20 µs for one
  point). It is the *same geometry*: the centre must lie in the union of ALL keep-in boxes (closed, the checker's
  tolerance) and the robot must not overlap any keep-out ellipsoid (safety factor applied), i.e. the centre must
  stay outside the ellipsoid grown by the robot's bounding ellipsoid (a sphere of ``robot.radius_m``): the
  Gilitschenski-Hanebeck clearance ``g* >= 1`` of :mod:`oacli.geometry.overlap`, computed with the checker's own
  transform and eigenvalues, by a scalar copy of its safeguarded Newton search (only for points between the
  certain-collision and certain-free bounds). ``tests/test_planner_ompl_validity.py`` checks that both agree.
* :func:`ompl_control_rrt`: OMPL's control-based RRT (``ompl.control.RRT``) on the same double integrator
  (6-D state: positions within the bounding box of the keep-in boxes, velocities within the same limits; 3-D
  force control within the same limits; the exact double-integrator propagator as a Python callback), validity
  checked by OMPL at its propagation steps only (its design). Goal: within 0.1 of the goal state in the 6-D
  Euclidean state distance, not at rest.
* :func:`ompl_rrt_star_path`: OMPL's geometric RRT* in the 3-D position space with the same validity check and a
  fine motion validator, followed by ``PathSimplifier.simplifyMax``; :func:`stop_and_go` then gives the polyline
  a time parametrisation within the same force and velocity limits (rest at every vertex: a polyline's corners
  can only be flown exactly by stopping there).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import KEEP_IN_TOLERANCE_M, CollisionChecker

try:
    from ompl import base as ob
    from ompl import control as oc
    from ompl import geometric as og
    from ompl import util as ou
except ImportError as exc:  # the bench extra is not installed
    OMPL_IMPORT_ERROR: str | None = f"{type(exc).__name__}: {exc}"
else:
    OMPL_IMPORT_ERROR = None
    ou.setLogLevel(ou.LogLevel.LOG_NONE)

#: Newton iterations of the scalar clearance search (as oacli.geometry.overlap).
_MAX_NEWTON = 60
_LAMBDA_FLOOR = 1e-300


def _require_ompl() -> None:
    if OMPL_IMPORT_ERROR is not None:
        raise ImportError(f"OMPL is not available ({OMPL_IMPORT_ERROR}); pip install -e '.[bench]'")


def seed_ompl(seed: int) -> None:
    """Seed OMPL's global RNG (effective only before OMPL first draws a random number in this process)."""
    _require_ompl()
    ou.RNG.setSeed(int(seed))


class ScalarValidity:
    """Point validity of the robot centre in plain Python (module docstring): ``check(x, y, z) -> bool``.

    Parameters
    ----------
    checker : CollisionChecker
        oacli's checker; its scene (keep-in boxes, keep-out ellipsoids with the safety factor) and robot body
        define the geometry, and its precomputed transforms and generalised eigenvalues are used as they are.
    """

    def __init__(self, checker: CollisionChecker) -> None:
        tol = KEEP_IN_TOLERANCE_M
        self.boxes = [tuple(float(v) for v in (*(b.lower - tol), *(b.upper + tol))) for b in checker.scene.keep_in]
        self.point_robot = bool(checker.robot.is_point)
        zones = []
        centers = checker._centers  # the same numbers as the vectorised check
        for j in range(centers.shape[0]):
            t = checker._transform[j]
            lam = [max(float(v), _LAMBDA_FLOOR) for v in checker._lam[j]]
            # Certain collision when Σ w²/(1+√λ)² < 1 (g* is at most that: the sum of balls of radii 1 and √λ_i
            # per axis); certain freedom when g(s0) >= 1 at the s0 that is optimal for the mean eigenvalue.
            upper = [1.0 / (1.0 + math.sqrt(v)) ** 2 if not self.point_robot else 1.0 for v in lam]
            lam_mean = sum(lam) / 3.0
            s0 = 1.0 / (1.0 + math.sqrt(lam_mean))
            d0 = [s0 * (1.0 - s0) / (s0 + v * (1.0 - s0)) for v in lam]
            zones.append((tuple(float(v) for v in centers[j]), tuple(tuple(float(v) for v in row) for row in t),
                          tuple(lam), tuple(upper), tuple(d0)))
        self.zones = zones

    def __call__(self, x: float, y: float, z: float) -> bool:
        """True when the centre ``(x, y, z)`` is in a keep-in box and the robot touches no keep-out zone."""
        for lx, ly, lz, ux, uy, uz in self.boxes:
            if lx <= x <= ux and ly <= y <= uy and lz <= z <= uz:
                break
        else:
            if self.boxes:
                return False
        for (cx, cy, cz), (t0, t1, t2), lam, upper, d0 in self.zones:
            dx, dy, dz = x - cx, y - cy, z - cz
            w0 = t0[0] * dx + t0[1] * dy + t0[2] * dz
            w1 = t1[0] * dx + t1[1] * dy + t1[2] * dz
            w2 = t2[0] * dx + t2[1] * dy + t2[2] * dz
            a, b, c = w0 * w0, w1 * w1, w2 * w2
            if self.point_robot:
                if a + b + c < 1.0:
                    return False
                continue
            if a * upper[0] + b * upper[1] + c * upper[2] < 1.0:
                return False
            if a * d0[0] + b * d0[1] + c * d0[2] >= 1.0:
                continue
            if _max_clearance_sq(a, b, c, lam) < 1.0:
                return False
        return True

    def points(self, points: np.ndarray) -> np.ndarray:
        """The check on every row of ``points`` (N, 3) (for tests)."""
        return np.array([self(float(p[0]), float(p[1]), float(p[2])) for p in np.asarray(points, dtype=float)])


def _max_clearance_sq(a: float, b: float, c: float, lam: tuple[float, float, float]) -> float:
    """Scalar copy of :func:`oacli.geometry.overlap.max_clearance_sq` (same iteration, same stopping rule)."""
    w2 = (a, b, c)
    lo, hi, s = 0.0, 1.0, 0.5
    for _ in range(_MAX_NEWTON):
        slope = curv = 0.0
        for wi, li in zip(w2, lam, strict=True):
            den = li + (1.0 - li) * s
            slope += wi * (li - 2.0 * li * s - (1.0 - li) * s * s) / (den * den)
            curv -= 2.0 * wi * li / (den * den * den)
        if slope > 0.0:
            lo = s
        else:
            hi = s
        newton = s - slope / curv if curv < 0.0 else s
        s_new = newton if (lo <= newton <= hi and math.isfinite(newton)) else 0.5 * (lo + hi)
        done = abs(s_new - s) <= 1e-15 + 1e-13 * s
        s = s_new
        if done:
            break
    return sum(wi * s * (1.0 - s) / (s + li * (1.0 - s)) for wi, li in zip(w2, lam, strict=True))


def keep_in_bounds(checker: CollisionChecker) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of the union of ALL keep-in boxes (OMPL's sampling bounds; membership is the validity check)."""
    boxes = checker.scene.keep_in
    if not boxes:
        raise ValueError("the OMPL peers need keep-in boxes for their sampling bounds")
    return np.min([b.lower for b in boxes], axis=0), np.max([b.upper for b in boxes], axis=0)


@dataclass(frozen=True)
class ControlPath:
    """A solution of OMPL's control RRT as zero-order-hold samples: times, states and held forces."""

    t: np.ndarray  # (n+1,)
    x: np.ndarray  # (n+1, 6)
    u: np.ndarray  # (n, 3)


def _bounds(lower, upper):
    b = ob.RealVectorBounds(len(lower))
    for i, (lo, hi) in enumerate(zip(lower, upper, strict=True)):
        b.setLow(i, float(lo))
        b.setHigh(i, float(hi))
    return b


def ompl_control_rrt(
    start: np.ndarray, goal: np.ndarray, box_lower: np.ndarray, box_upper: np.ndarray, mass_kg: float,
    force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray, valid_position: Callable[[float, float, float], bool],
    *, time_budget_s: float, step_s: float = 0.5, max_steps: int = 10, goal_threshold: float = 0.1,
) -> tuple[bool, float, ControlPath | None]:
    """Plan with ``ompl.control.RRT``; returns ``(exact solution found, wall time [s], path)``.

    ``valid_position(x, y, z)`` is the scalar point check (:class:`ScalarValidity`); the wall time covers the
    whole ``solve`` (problem set-up excluded).
    """
    _require_ompl()
    space = ob.RealVectorStateSpace(6)
    space.setBounds(_bounds(np.r_[box_lower, -velocity_limit_mps], np.r_[box_upper, velocity_limit_mps]))
    cspace = oc.RealVectorControlSpace(space, 3)
    cspace.setBounds(_bounds(-force_limit_N, force_limit_N))
    ss = oc.SimpleSetup(cspace)
    si = ss.getSpaceInformation()
    inv_m = 1.0 / float(mass_kg)

    def is_valid(state) -> bool:
        return bool(si.satisfiesBounds(state) and valid_position(state[0], state[1], state[2]))

    def propagate(state, control, duration, result) -> None:
        for i in range(3):
            a = control[i] * inv_m
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
    ss.setup()
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


def ompl_rrt_star_path(
    start: np.ndarray, goal: np.ndarray, box_lower: np.ndarray, box_upper: np.ndarray,
    valid_position: Callable[[float, float, float], bool], *, time_budget_s: float, resolution: float = 0.001,
) -> tuple[bool, float, float, np.ndarray | None]:
    """``og.RRTstar`` for ``time_budget_s`` then ``simplifyMax``.

    ``resolution`` is OMPL's motion-validation step as a fraction of the space's extent (OMPL's default 0.01
    lets simplified segments cut into the ellipsoids by centimetres; 0.001 checks every few mm here).

    Returns
    -------
    solved : bool
    wall_s : float
        Wall time of the solve plus the simplification [s].
    length_m : float
    waypoints : ndarray, shape (n, 3) or None
    """
    _require_ompl()
    space = ob.RealVectorStateSpace(3)
    space.setBounds(_bounds(box_lower, box_upper))
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(lambda st: bool(valid_position(st[0], st[1], st[2])))
    s, g = space.allocState(), space.allocState()
    for i in range(3):
        s[i], g[i] = float(start[i]), float(goal[i])
    ss.setStartAndGoalStates(s, g)
    ss.getSpaceInformation().setStateValidityCheckingResolution(resolution)
    ss.setPlanner(og.RRTstar(ss.getSpaceInformation()))
    ss.setup()
    t0 = time.perf_counter()
    status = ss.solve(time_budget_s)
    if not (bool(status) and ss.haveExactSolutionPath()):
        return False, time.perf_counter() - t0, float("nan"), None
    path = ss.getSolutionPath()
    ss.getPathSimplifier().simplifyMax(path)
    wall = time.perf_counter() - t0
    pts = np.array([[st[i] for i in range(3)] for st in path.getStates()])
    return True, wall, float(path.length()), pts


def stop_and_go(points: np.ndarray, mass_kg: float, force_limit_N: np.ndarray,
                velocity_limit_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time parametrisation of a polyline within per-axis force and velocity limits, at rest at every vertex.

    Each segment (direction d, length L) is flown rest to rest in minimum time with the scalar limits
    ``a_max = min_i F_i / (m |d_i|)`` and ``v_max = min_i V_i / |d_i|`` (triangular or trapezoidal speed
    profile): a zero-order-hold force trajectory (at most three pieces per segment) that follows the polyline
    exactly.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Vertices [m].
    mass_kg : float
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)

    Returns
    -------
    t : ndarray, shape (k+1,)
    x : ndarray, shape (k+1, 6)
    u : ndarray, shape (k, 3)
    """
    points = np.asarray(points, dtype=float)
    t_list, x_list, u_list = [0.0], [np.r_[points[0], np.zeros(3)]], []
    for p, q in itertools.pairwise(points):
        seg = q - p
        length = float(np.linalg.norm(seg))
        if length <= 0.0:
            continue
        d = seg / length
        with np.errstate(divide="ignore"):
            a_max = float(np.min(np.where(np.abs(d) > 0, force_limit_N / (mass_kg * np.abs(d)), np.inf)))
            v_max = float(np.min(np.where(np.abs(d) > 0, velocity_limit_mps / np.abs(d), np.inf)))
        t_acc = v_max / a_max
        if a_max * t_acc * t_acc >= length:  # triangular: never reaches v_max
            t_acc = math.sqrt(length / a_max)
            phases = [(t_acc, a_max), (t_acc, -a_max)]
        else:
            t_coast = (length - a_max * t_acc * t_acc) / v_max
            phases = [(t_acc, a_max), (t_coast, 0.0), (t_acc, -a_max)]
        for dur, acc in phases:
            r0, v0 = x_list[-1][0:3], x_list[-1][3:6]
            a_vec = acc * d
            x_list.append(np.r_[r0 + v0 * dur + 0.5 * a_vec * dur * dur, v0 + a_vec * dur])
            u_list.append(mass_kg * a_vec)
            t_list.append(t_list[-1] + dur)
        x_list[-1] = np.r_[q, np.zeros(3)]  # exact vertex at rest (equal up to rounding)
    return np.array(t_list), np.array(x_list), np.array(u_list).reshape(-1, 3)
