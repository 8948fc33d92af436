"""LQR-RRT* in the translational state space ([Doerr2021] §"LQR-RRT*", Eqs. 5-11; Perez et al. 2012).

One iteration, as in Doerr's list of seven components:

1. **Random sampling** of a state (position in the keep-in boxes, velocity within its limits); with probability
   ``goal_bias`` the goal is chosen instead, and then the goal is connected from its near set directly.
2. **Nearest node** by the LQR cost-to-go (Eq. 10), a Euclidean nearest-neighbour query in transformed
   coordinates (:class:`~oacli.planning.steering.LqrMetric`).
3. **LQR steer** (:meth:`~oacli.planning.steering.LqrConnector.saturated_rollout`): a shrinking-horizon LQR
   rollout from the nearest node towards the sample, with the force clipped to its limits and to the range that
   keeps the velocity within its limits; the new state is where it ends (reachable within the limits).
4. **Near nodes** with cost-to-go at most ``γ (log n / n)^(1/n_x)``, ``n_x = 6`` (Eq. 11), at most ``max_near``.
5. **Choose parent**: the near node and horizon of least cost-to-come plus connection cost whose connection is
   within the limits and **collision-free in continuous time** (checked lazily in cost order: the candidates'
   forces and samples come a chunk at a time from one batched product, a candidate with a sample that certainly
   collides is rejected at once (:class:`~oacli.planning.sample_filter.SampleFilter`), the others get the exact
   continuous check).
6. **Collision checking** of every edge that enters the tree (:mod:`oacli.geometry.collision`).
7. **Rewire**: every near node that becomes cheaper through the new node gets it as its parent (over an exact,
   checked LQR connection), and the cost change propagates to all its descendants (:meth:`Tree.rewire`).

The goal is connected exactly (a collision-checked LQR connection ending at rest on the goal); once in the tree it
is rewired like any node, so improvements anywhere above it lower the solution's cost. ``anytime=False`` stops at
the first solution (as Doerr and ReSWARM fly it); ``anytime=True`` keeps improving until the iteration or time
budget is spent.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

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
from oacli.planning.sample_filter import SampleFilter
from oacli.planning.steering import LIMIT_RTOL, MIN_STEPS, LqrConnector
from oacli.planning.translational import TranslationalTrajectory
from oacli.planning.tree import EDGE_LQR, RewireEvent, Tree

#: State-space dimension n_x of Eq. 11.
STATE_DIM = 6
#: Relative margin a rewire must improve a cost by.
_IMPROVE_RTOL = 1e-9
#: Candidate connections batched together in choose-parent and goal links (in cost order).
_CHUNK = 16
#: Most improving rewire connections whose limits are checked by one batched product (else all at once).
_REWIRE_BATCH = 64


@dataclass(frozen=True)
class LqrRrtStarSettings:
    """Settings of :func:`plan_lqr_rrt_star`.

    Attributes
    ----------
    dt_s : float
        Step of the held force in every connection [s].
    metric_steps : int
        Horizon [steps] of the cost-to-go metric (nearest, near set) and the longest steering connection.
    max_steps : int
        Longest connection [steps] in choose-parent, rewiring and goal connections.
    max_iterations : int
        Iteration budget.
    time_budget_s : float
        Wall-time budget [s].
    anytime : bool
        Keep improving after the first solution until a budget is spent.
    goal_bias : float
        Probability of sampling the goal, in [0, 1).
    gamma : float
        γ of the near radius ``γ (log n / n)^(1/6)`` (Eq. 11), in cost units.
    max_near : int
        Largest near set.
    max_edge_checks : int
        Collision checks per choose-parent or goal connection before giving up.
    snapshots : int
        Approximate number of tree snapshots kept for replay.
    """

    dt_s: float = 0.5
    metric_steps: int = 10
    max_steps: int = 30
    max_iterations: int = 2000
    time_budget_s: float = 30.0
    anytime: bool = False
    goal_bias: float = 0.05
    gamma: float = 20.0
    max_near: int = 30
    max_edge_checks: int = 8
    snapshots: int = 40

    def __post_init__(self) -> None:
        if not self.dt_s > 0:
            raise ValueError("dt_s must be > 0")
        if not MIN_STEPS <= self.metric_steps <= self.max_steps:
            raise ValueError(f"need {MIN_STEPS} <= metric_steps <= max_steps")
        if not 0.0 <= self.goal_bias < 1.0:
            raise ValueError("goal_bias must be in [0, 1)")
        if self.max_iterations < 0 or self.time_budget_s <= 0 or self.gamma <= 0 or self.max_near < 1:
            raise ValueError("budgets, gamma and max_near must be positive")


class _Planner:
    """State of one LQR-RRT* run (see :func:`plan_lqr_rrt_star`)."""

    def __init__(self, problem: PlanningProblem, settings: LqrRrtStarSettings, rng: np.random.Generator,
                 clock: Callable[[], float]) -> None:
        self.problem = problem
        self.settings = settings
        self.rng = rng
        self.clock = clock
        self.t0 = clock()
        self.conn = LqrConnector(problem.model, settings.dt_s, problem.weights, settings.max_steps)
        self.metric = self.conn.metric(settings.metric_steps)
        self.filter = SampleFilter(problem.checker)
        self._f_lim = problem.force_limit_N * (1.0 + LIMIT_RTOL)
        self._v_lim = problem.velocity_limit_mps * (1.0 + LIMIT_RTOL)
        self.goal = problem.goal
        self.tree = Tree(problem.start)
        self.sources = PointIndex(STATE_DIM)
        self.targets = PointIndex(STATE_DIM)
        self.sources.add(self.metric.source_coords(problem.start), 0)
        self.targets.add(self.metric.target_coords(problem.start), 0)
        self.goal_node = -1
        self.best_cost = math.inf
        self.rewires: list[RewireEvent] = []
        self.solutions: list[SolutionEvent] = []
        self.snapshots: list[TreeSnapshot] = []
        self.iteration = 0
        self.stats = {
            "samples": 0,
            "goal_samples": 0,
            "sample_rejected": 0,
            "steer_failed": 0,
            "no_parent": 0,
            "edge_checks": 0,
            "edge_collisions": 0,
            "rewire_checks": 0,
            "rewires": 0,
            "rewire_descendants_updated": 0,
            "goal_attempts": 0,
        }

    # -- helpers ---------------------------------------------------------------------------------------------

    def elapsed(self) -> float:
        return self.clock() - self.t0

    def near_radius(self) -> float:
        n = self.tree.n
        if n < 2:
            return 0.0
        return self.settings.gamma * (math.log(n) / n) ** (1.0 / STATE_DIM)

    def limits_ok(self, x_a: np.ndarray, x_b: np.ndarray, steps: np.ndarray | None = None) -> np.ndarray:
        f_ok, v_ok = self.conn.within_limits(
            x_a, x_b, self.goal, self.problem.force_limit_N, self.problem.velocity_limit_mps, steps
        )
        return f_ok & v_ok

    def edge(self, x_a: np.ndarray, x_b: np.ndarray, steps: int,
             traj: TranslationalTrajectory | None = None) -> tuple[bool, TranslationalTrajectory]:
        if traj is None:
            traj = self.conn.trajectory(x_a, x_b, self.goal, steps)
        self.stats["edge_checks"] += 1
        free = self.problem.checker.is_free(traj.pieces())
        if not free:
            self.stats["edge_collisions"] += 1
        return free, traj

    def near_sources(self, x: np.ndarray, extra: int | None = None) -> np.ndarray:
        z, c = self.metric.query_to(x, self.goal)
        near = self.sources.within(z, self.near_radius() - c, self.settings.max_near)
        if extra is not None and extra not in near:
            near = np.append(near, extra)
        if near.size == 0:
            near = np.array([self.sources.nearest(z)[0]])
        return near

    def best_connection(self, parents: np.ndarray, x: np.ndarray, bound: float = math.inf) -> tuple[int, int, float]:
        """Least total cost (cost-to-come + connection) parent and horizon with a free connection to ``x``.

        Only connections cheaper than ``bound`` and within the limits are considered; up to ``max_edge_checks`` of
        them are collision-checked in cost order. The candidates are taken in cost order a chunk at a time: their
        forces and samples come from one batched product (:meth:`LqrConnector.batch`), which gives the limit
        check of the whole chunk and the early rejection of every candidate with a colliding sample
        (:class:`~oacli.planning.sample_filter.SampleFilter`); only the others get the continuous check.
        """
        tree = self.tree
        xs = tree.states[parents]
        total = tree.cost[parents][:, None] + self.conn.costs(xs, x, self.goal)
        total[total >= bound] = np.inf
        flat = np.argsort(total, axis=None, kind="stable")
        n_finite = int(np.count_nonzero(total < math.inf))
        width = total.shape[1]
        max_checks = self.settings.max_edge_checks
        checks = start = 0
        while start < n_finite and checks < max_checks:
            chunk = flat[start:min(start + _CHUNK, n_finite)]
            start += chunk.shape[0]
            rows, horizons = np.divmod(chunk, width)
            u, states = self.conn.batch(xs[rows], x, self.goal, horizons)
            within = np.all(np.abs(u) <= self._f_lim, axis=(1, 2))
            within &= np.all(np.abs(states[:, :, 3:6]) <= self._v_lim, axis=(1, 2))
            cand = np.flatnonzero(within)[: max_checks - checks]
            if cand.size == 0:
                continue
            rejected = self.filter.connections_colliding(states[cand], horizons[cand]).tolist()
            for c, reject in zip(cand.tolist(), rejected, strict=True):
                checks += 1
                k, n = int(rows[c]), int(horizons[c])
                if reject:
                    self.stats["edge_checks"] += 1
                    self.stats["edge_collisions"] += 1
                    continue
                free, _ = self.edge(xs[k], x, n)
                if free:
                    return int(parents[k]), n, float(total[k, n])
        return -1, 0, math.inf

    # -- steps -----------------------------------------------------------------------------------------------

    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> np.ndarray | None:
        """LQR steering within the limits towards ``x_to`` (Doerr: 'LQR steer'; Perez et al. 2012).

        The horizon is the cheapest one up to the steering horizon; the new state is where the saturated
        shrinking-horizon LQR rollout ends (:meth:`LqrConnector.saturated_rollout`), so it is reachable from
        ``x_from`` within the force and velocity limits. None when that state is not collision-free.
        """
        costs = self.conn.costs(x_from, x_to, self.goal)[0, : self.settings.metric_steps + 1]
        steps = int(np.argmin(costs))
        x_new = self.conn.saturated_end(
            x_from, x_to, self.goal, steps, self.problem.force_limit_N, self.problem.velocity_limit_mps
        )
        if float(np.max(np.abs(x_new - x_from))) <= 1e-9:
            return None
        if not self.problem.checker.points_free(x_new[0:3]):
            return None
        return x_new

    def add_node(self, x: np.ndarray, parent: int, steps: int, cost: float, *, index_as_source: bool) -> int:
        node = self.tree.add(x, parent, cost, EDGE_LQR, steps=steps, iteration=self.iteration,
                             wall_time_s=self.elapsed())
        if index_as_source:
            self.sources.add(self.metric.source_coords(x), node)
        self.targets.add(self.metric.target_coords(x), node)
        return node

    def rewire_from(self, new: int) -> None:
        """Make ``new`` the parent of every near node it makes cheaper (Doerr's 'rewire near nodes')."""
        tree = self.tree
        x_new = tree.states[new]
        z, c = self.metric.query_from(x_new, self.goal)
        cands = self.targets.within(z, self.near_radius() - c, self.settings.max_near)
        cands = cands[(cands != new) & (cands != 0)]
        if self.goal_node >= 0 and self.goal_node not in cands:
            cands = np.append(cands, self.goal_node)
        if cands.size == 0:
            return
        xs = tree.states[cands]
        via = tree.cost[new] + self.conn.costs(x_new, xs, self.goal)
        # Only connections that would lower a node's cost now can rewire it (costs only fall during the loop
        # below), so only their limits are checked: usually few, from one batched product.
        current = tree.cost[cands]
        improving = via < (current - _IMPROVE_RTOL * np.maximum(1.0, np.abs(current)))[:, None]
        rows, cols = np.nonzero(improving)
        if rows.size == 0:
            return
        if rows.size <= _REWIRE_BATCH:
            u, states = self.conn.batch(x_new, xs[rows], self.goal, cols)
            within = np.all(np.abs(u) <= self._f_lim, axis=(1, 2))
            within &= np.all(np.abs(states[:, :, 3:6]) <= self._v_lim, axis=(1, 2))
            improving[rows[~within], cols[~within]] = False
        else:
            improving &= self.limits_ok(x_new, xs)
        via[~improving] = np.inf
        for k in np.argsort(via.min(axis=1), kind="stable"):
            node = int(cands[k])
            order = np.argsort(via[k], kind="stable")[:2]
            for n in order:
                current = tree.cost[node]
                if not via[k, n] < current - _IMPROVE_RTOL * max(1.0, abs(current)):
                    break
                if tree.is_ancestor(node, new):
                    break
                self.stats["rewire_checks"] += 1
                free, _ = self.edge(x_new, xs[k], int(n))
                if free:
                    event = tree.rewire(node, new, float(via[k, n]), steps=int(n), iteration=self.iteration)
                    self.rewires.append(event)
                    self.stats["rewires"] += 1
                    self.stats["rewire_descendants_updated"] += event.descendants_updated
                    break

    def connect_goal(self, parents: np.ndarray) -> None:
        """Connect the goal from ``parents`` (add it, or give it a cheaper parent)."""
        self.stats["goal_attempts"] += 1
        bound = math.inf
        if self.goal_node >= 0:
            current = self.tree.cost[self.goal_node]
            bound = current - _IMPROVE_RTOL * max(1.0, abs(current))
        parent, n, total = self.best_connection(parents, self.goal, bound)
        if parent < 0:
            return
        if self.goal_node < 0:
            self.goal_node = self.add_node(self.goal, parent, n, total, index_as_source=False)
        elif not self.tree.is_ancestor(self.goal_node, parent):
            event = self.tree.rewire(self.goal_node, parent, total, steps=n, iteration=self.iteration)
            self.rewires.append(event)
            self.stats["rewires"] += 1

    def record_solution(self) -> None:
        if self.goal_node < 0:
            return
        cost = float(self.tree.cost[self.goal_node])
        if cost < self.best_cost - _IMPROVE_RTOL * max(1.0, abs(cost)):
            self.best_cost = cost
            self.solutions.append(SolutionEvent(self.iteration, self.elapsed(), cost, self.tree.n))

    def snapshot(self) -> None:
        path = tuple(self.tree.path_to(self.goal_node)) if self.goal_node >= 0 else ()
        self.snapshots.append(TreeSnapshot(self.iteration, self.tree.parent.copy(), path))

    def iterate(self) -> None:
        problem, tree = self.problem, self.tree
        if self.rng.random() < self.settings.goal_bias:
            self.stats["goal_samples"] += 1
            self.connect_goal(self.near_sources(self.goal))
            return
        self.stats["samples"] += 1
        x_rand = problem.sample_free_state(self.rng, attempts=1)
        if x_rand is None:
            self.stats["sample_rejected"] += 1
            return
        z, _ = self.metric.query_to(x_rand, self.goal)
        nearest, _ = self.sources.nearest(z)
        x_new = self.steer(tree.states[nearest], x_rand)
        if x_new is None:
            self.stats["steer_failed"] += 1
            return
        parent, n, total = self.best_connection(self.near_sources(x_new, extra=nearest), x_new)
        if parent < 0:
            self.stats["no_parent"] += 1
            return
        new = self.add_node(x_new, parent, n, total, index_as_source=True)
        self.rewire_from(new)
        self.connect_goal(np.array([new]))  # first link to the goal, or one that beats its current parent

    def run(self, progress: Callable[[float], None] | None,
            on_iteration: Callable[[int, Tree, float], None] | None = None) -> PlanResult:
        s = self.settings
        snapshot_every = max(1, s.max_iterations // max(s.snapshots, 1))
        self.connect_goal(np.array([0]))
        self.record_solution()
        stop = "iterations"
        while True:
            if self.goal_node >= 0 and not s.anytime:
                stop = "first_solution"
                break
            if self.iteration >= s.max_iterations:
                stop = "iterations"
                break
            elapsed = self.elapsed()
            if elapsed >= s.time_budget_s:
                stop = "time_budget"
                break
            self.iteration += 1
            self.iterate()
            self.record_solution()
            if on_iteration is not None:
                on_iteration(self.iteration, self.tree, self.best_cost)
            if self.iteration % snapshot_every == 0:
                self.snapshot()
            if progress is not None and self.iteration % 25 == 0:
                progress(min(1.0, max(self.iteration / max(s.max_iterations, 1), elapsed / s.time_budget_s)))
        if not self.snapshots or self.snapshots[-1].iteration != self.iteration:
            self.snapshot()
        if progress is not None:
            progress(1.0)
        return self.result(stop)

    def result(self, stop: str) -> PlanResult:
        tree, problem = self.tree, self.problem
        record = tree_record(tree, self.goal_node, self.conn, self.goal)
        common = dict(
            tree=record, rewires=tuple(self.rewires), solutions=tuple(self.solutions),
            snapshots=tuple(self.snapshots), iterations=self.iteration, planning_time_s=self.elapsed(),
            stop_reason=stop, stats=dict(self.stats),
        )
        if self.goal_node < 0:
            return PlanResult(NO_SOLUTION, "lqr-rrt-star", None, (), math.nan, **common)  # type: ignore[arg-type]
        path = tree.path_to(self.goal_node)
        traj = path_trajectory(tree, path, self.conn, self.goal)
        return PlanResult(SOLVED, "lqr-rrt-star", traj, tuple(path), traj.cost(problem.weights, self.goal), **common)  # type: ignore[arg-type]


def plan_lqr_rrt_star(
    problem: PlanningProblem,
    settings: LqrRrtStarSettings,
    rng: np.random.Generator,
    *,
    progress: Callable[[float], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
    on_iteration: Callable[[int, Tree, float], None] | None = None,
) -> PlanResult:
    """Plan from ``problem.start`` to ``problem.goal`` with LQR-RRT* (module docstring).

    Parameters
    ----------
    problem : PlanningProblem
    settings : LqrRrtStarSettings
    rng : numpy.random.Generator
        Every random choice comes from it (same generator state, same settings: same plan, unless the time budget
        cuts the run).
    progress : callable, optional
        Called with the used fraction of the budget (iterations or time, whichever is larger).
    clock : callable
        Wall clock [s] (injected for tests).
    on_iteration : callable, optional
        Called after each iteration as ``on_iteration(iteration, tree, best_cost)`` (the tree so far, read only;
        ``best_cost`` is ``inf`` before the first solution), e.g. to record the search as it grows.

    Returns
    -------
    PlanResult
    """
    return _Planner(problem, settings, rng, clock).run(progress, on_iteration)
