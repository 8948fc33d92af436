"""Kinodynamic RRT with motion primitives ([ReSWARM2023] §4.1.2-4.1.3, Eqs. 26-27; LaValle 2001).

* **Metric** (Eq. 26): weighted Euclidean distance ``|W (x - x_rand)|`` with ``W = diag(w_r, w_r, w_r, w_v, w_v,
  w_v)``; nearest-neighbour search is a vectorised scan of the weighted nodes.
* **Motion primitives** (Eq. 27): per input axis ``±α F_i`` with ``0 < α <= 1`` (``α`` the primitive fraction),
  plus the zero action: ``2 n_u + 1 = 7`` actions (``primitive_set="axes"``, the paper's set), or every
  combination of ``{-α F_i, 0, +α F_i}`` over the axes, 27 actions (``"combinations"``). Each is held for the
  propagation time Δt and propagated with the exact double integrator.
* **Steer**: from the nearest node, every primitive is propagated; those that keep the velocity limits (velocity
  is linear in time, so the end points decide) and are collision-free in continuous time (the robot's bounding
  ellipsoid against the keep-out ellipsoids: [ReSWARM2023] §4.2.2 ellipsoid-on-ellipsoid, swept over the whole
  primitive, :mod:`oacli.geometry.collision`) compete; the one ending closest to the sample is added.
* **Goal**: a node within the goal tolerance (position and speed) is linked to the exact goal at rest by a
  collision-checked LQR connection (:class:`~oacli.planning.steering.LqrConnector`), so the plan ends exactly on
  the goal. The planner stops at the first solution (kinodynamic RRT does not optimise).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import Pieces
from oacli.planning.nearest import PointIndex
from oacli.planning.problem import PlanningProblem
from oacli.planning.result import (
    NO_SOLUTION,
    SOLVED,
    PlanResult,
    SolutionEvent,
    TreeSnapshot,
    path_trajectory,
    tree_record,
)
from oacli.planning.steering import MIN_STEPS, LqrConnector
from oacli.planning.translational import interval_costs
from oacli.planning.tree import EDGE_LQR, EDGE_PRIMITIVE, Tree


@dataclass(frozen=True)
class KinoRrtSettings:
    """Settings of :func:`plan_kino_rrt`.

    Attributes
    ----------
    primitive_fraction : float
        α of Eq. 27: primitives apply ``±α F_i``, ``0 < α <= 1``.
    primitive_dt_s : float
        Propagation time Δt of each primitive [s].
    primitive_set : str
        ``"axes"`` (2 n_u + 1 actions, Eq. 27) or ``"combinations"`` (3^n_u actions).
    position_weight, velocity_weight : float
        ``w_r`` [1/m] and ``w_v`` [s/m] of the metric (Eq. 26).
    goal_tolerance_m, goal_tolerance_mps : float
        A node this close to the goal position and this slow tries the LQR goal link.
    dt_s : float
        Step of the LQR goal link's held force [s].
    max_link_steps : int
        Longest goal link [steps].
    max_iterations : int
    time_budget_s : float
    goal_bias : float
        Probability of sampling the goal.
    snapshots : int
        Approximate number of tree snapshots kept for replay.
    """

    primitive_fraction: float = 0.5
    primitive_dt_s: float = 2.0
    primitive_set: str = "axes"
    position_weight: float = 1.0
    velocity_weight: float = 5.0
    goal_tolerance_m: float = 0.5
    goal_tolerance_mps: float = 0.1
    dt_s: float = 0.5
    max_link_steps: int = 30
    max_iterations: int = 20000
    time_budget_s: float = 30.0
    goal_bias: float = 0.1
    snapshots: int = 40

    def __post_init__(self) -> None:
        if not 0.0 < self.primitive_fraction <= 1.0:
            raise ValueError("primitive_fraction must be in (0, 1]")
        if self.primitive_set not in ("axes", "combinations"):
            raise ValueError("primitive_set must be 'axes' or 'combinations'")
        if self.primitive_dt_s <= 0 or self.dt_s <= 0 or self.max_link_steps < MIN_STEPS:
            raise ValueError("time steps must be > 0 and max_link_steps >= 2")


def motion_primitives(force_limit_N: np.ndarray, fraction: float, kind: str = "axes") -> np.ndarray:
    """The action set of [ReSWARM2023] Eq. 27, shape (P, 3) [N]: zero first, then the ± actions.

    Parameters
    ----------
    force_limit_N : ndarray, shape (3,)
        Force limits [N].
    fraction : float
        Fraction of the limit each action uses.
    kind : {"axes", "combinations"}, optional
        One axis at a time (7 actions) or every combination of 0, +, − per axis (27).

    Returns
    -------
    ndarray, shape (P, 3)
        Forces [N].
    """
    f = fraction * np.asarray(force_limit_N, dtype=float)
    if kind == "axes":
        out = [np.zeros(3)]
        for i in range(3):
            for sign in (1.0, -1.0):
                u = np.zeros(3)
                u[i] = sign * f[i]
                out.append(u)
        return np.array(out)
    if kind == "combinations":
        combos = sorted(itertools.product((0.0, 1.0, -1.0), repeat=3), key=lambda c: sum(map(abs, c)))
        return np.array(combos) * f
    raise ValueError(f"unknown primitive set {kind!r}")


def plan_kino_rrt(
    problem: PlanningProblem,
    settings: KinoRrtSettings,
    rng: np.random.Generator,
    *,
    progress: Callable[[float], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
    on_iteration: Callable[[int, Tree, float], None] | None = None,
) -> PlanResult:
    """Plan from ``problem.start`` to ``problem.goal`` with kinodynamic RRT and motion primitives.

    Parameters
    ----------
    problem : PlanningProblem
    settings : KinoRrtSettings
    rng : numpy.random.Generator
    progress : callable, optional
        Called with the used fraction of the budget.
    clock : callable
        Wall clock [s].
    on_iteration : callable, optional
        Called before each iteration as ``on_iteration(iterations_done, tree, inf)`` (the tree so far, read only;
        the search stops at its first solution), e.g. to record the search as it grows.

    Returns
    -------
    PlanResult
        Status ``solved`` with the trajectory through the primitives and the goal link, or ``no_solution`` with
        the tree grown so far.
    """
    s = settings
    t0 = clock()
    goal = problem.goal
    conn = LqrConnector(problem.model, s.dt_s, problem.weights, s.max_link_steps)
    prims = motion_primitives(problem.force_limit_N, s.primitive_fraction, s.primitive_set)
    acc = prims / problem.model.mass_kg
    dt = s.primitive_dt_s
    weight = np.array([s.position_weight] * 3 + [s.velocity_weight] * 3)
    tree = Tree(problem.start)
    index = PointIndex(6)
    index.add(weight * problem.start, 0)
    checker = problem.checker
    v_lim = problem.velocity_limit_mps * (1.0 + 1e-12)
    goal_node = -1
    solutions: list[SolutionEvent] = []
    snapshots: list[TreeSnapshot] = []
    stats = {"samples": 0, "goal_samples": 0, "sample_rejected": 0, "expansions_blocked": 0,
             "primitives_velocity_limit": 0, "primitives_colliding": 0, "goal_attempts": 0,
             "goal_link_collisions": 0}
    snapshot_every = max(1, s.max_iterations // max(s.snapshots, 1))

    def try_goal_link(node: int, iteration: int) -> int:
        x = tree.states[node]
        stats["goal_attempts"] += 1
        total = conn.costs(x, goal, goal)[0]
        f_ok, v_ok = conn.within_limits(x, goal, goal, problem.force_limit_N, problem.velocity_limit_mps)
        total[~(f_ok[0] & v_ok[0])] = np.inf
        for n in np.argsort(total, kind="stable")[:3]:
            if not np.isfinite(total[n]):
                break
            link = conn.trajectory(x, goal, goal, int(n))
            if checker.is_free(link.pieces()):
                return tree.add(goal, node, tree.cost[node] + total[n], EDGE_LQR, steps=int(n),
                                iteration=iteration, wall_time_s=clock() - t0)
            stats["goal_link_collisions"] += 1
        return -1

    def near_goal(x: np.ndarray) -> bool:
        return bool(np.linalg.norm(x[0:3] - goal[0:3]) <= s.goal_tolerance_m
                    and np.linalg.norm(x[3:6] - goal[3:6]) <= s.goal_tolerance_mps)

    if near_goal(problem.start):
        goal_node = try_goal_link(0, 0)
    iteration = 0
    stop = "iterations"
    while goal_node < 0:
        if iteration >= s.max_iterations:
            stop = "iterations"
            break
        elapsed = clock() - t0
        if elapsed >= s.time_budget_s:
            stop = "time_budget"
            break
        if on_iteration is not None:
            on_iteration(iteration, tree, math.inf)
        iteration += 1
        if rng.random() < s.goal_bias:
            stats["goal_samples"] += 1
            x_rand: np.ndarray | None = goal
        else:
            stats["samples"] += 1
            x_rand = problem.sample_free_state(rng, attempts=1)
            if x_rand is None:
                stats["sample_rejected"] += 1
                continue
        near, _ = index.nearest(weight * x_rand)
        x0 = tree.states[near]
        p1 = x0[0:3] + x0[3:6] * dt + 0.5 * acc * dt * dt
        v1 = x0[3:6] + acc * dt
        ok = np.all(np.abs(v1) <= v_lim, axis=1)
        stats["primitives_velocity_limit"] += int((~ok).sum())
        if np.any(ok):
            cand = np.flatnonzero(ok)
            pieces = Pieces(np.tile(x0[0:3], (cand.size, 1)), np.tile(x0[3:6], (cand.size, 1)), acc[cand],
                            np.full(cand.size, dt))
            free = checker.check(pieces).piece_free
            stats["primitives_colliding"] += int((~free).sum())
            cand = cand[free]
        else:
            cand = np.zeros(0, dtype=int)
        if cand.size == 0:
            stats["expansions_blocked"] += 1
        else:
            x1 = np.concatenate([p1[cand], v1[cand]], axis=1)
            best = int(cand[np.argmin(np.sum((weight * (x1 - x_rand)) ** 2, axis=1))])
            x_new = np.concatenate([p1[best], v1[best]])
            edge_cost = float(interval_costs(x0[None, :], prims[best][None, :], np.array([dt]), problem.model,
                                             problem.weights, goal)[0])
            node = tree.add(x_new, near, tree.cost[near] + edge_cost, EDGE_PRIMITIVE, force=prims[best],
                            duration_s=dt, iteration=iteration, wall_time_s=clock() - t0)
            index.add(weight * x_new, node)
            if near_goal(x_new):
                goal_node = try_goal_link(node, iteration)
                if goal_node >= 0:
                    stop = "first_solution"
        if iteration % snapshot_every == 0:
            snapshots.append(TreeSnapshot(iteration, tree.parent.copy(), ()))
        if progress is not None and iteration % 100 == 0:
            progress(min(1.0, max(iteration / max(s.max_iterations, 1), elapsed / s.time_budget_s)))
    if goal_node >= 0:
        solutions.append(SolutionEvent(iteration, clock() - t0, float(tree.cost[goal_node]), tree.n))
        stop = "first_solution"
    path = tuple(tree.path_to(goal_node)) if goal_node >= 0 else ()
    snapshots.append(TreeSnapshot(iteration, tree.parent.copy(), path))
    if progress is not None:
        progress(1.0)
    record = tree_record(tree, goal_node, conn, goal)
    common = dict(tree=record, rewires=(), solutions=tuple(solutions), snapshots=tuple(snapshots),
                  iterations=iteration, planning_time_s=clock() - t0, stop_reason=stop, stats=stats)
    if goal_node < 0:
        return PlanResult(NO_SOLUTION, "kino-rrt", None, (), math.nan, **common)  # type: ignore[arg-type]
    traj = path_trajectory(tree, list(path), conn, goal)
    return PlanResult(SOLVED, "kino-rrt", traj, path, traj.cost(problem.weights, goal), **common)  # type: ignore[arg-type]
