"""What a planner returns: the trajectory, the tree, its history and statistics (for the stage runner to log)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from oacli.planning.steering import LqrConnector
from oacli.planning.translational import TranslationalTrajectory
from oacli.planning.tree import EDGE_LQR, EDGE_PRIMITIVE, RewireEvent, Tree

SOLVED = "solved"
NO_SOLUTION = "no_solution"


@dataclass(frozen=True)
class SolutionEvent:
    """The best solution changed: its cost-to-come at the goal after ``iteration``.

    Attributes
    ----------
    iteration : int
    wall_time_s : float
        Planner wall time [s].
    cost : float
        Cost of the best solution.
    nodes : int
        Tree size at that moment.
    """

    iteration: int
    wall_time_s: float
    cost: float
    nodes: int


@dataclass(frozen=True)
class TreeSnapshot:
    """The tree's parent links after ``iteration`` (nodes ``0 .. len(parent) - 1``), for replaying its growth.

    Attributes
    ----------
    iteration : int
    parent : ndarray of int, shape (n,)
    path : tuple of int
        The best path at that moment (empty before the first solution).
    """

    iteration: int
    parent: np.ndarray
    path: tuple[int, ...]


@dataclass(frozen=True)
class TreeRecord:
    """The final tree (arrays indexed by node; node 0 is the start).

    Attributes
    ----------
    states : ndarray, shape (n, 6)
    parent : ndarray of int, shape (n,)
    cost : ndarray, shape (n,)
        Cost-to-come.
    kind : ndarray of int, shape (n,)
        Edge kind (:mod:`oacli.planning.tree`).
    steps : ndarray of int, shape (n,)
        LQR edge horizon [steps].
    force : ndarray, shape (n, 3)
        Primitive edge force [N].
    duration_s : ndarray, shape (n,)
        Edge duration [s].
    iteration : ndarray of int, shape (n,)
        Iteration each node was added in.
    wall_time_s : ndarray, shape (n,)
        Planner wall time [s] each node was added at.
    goal_node : int
        Index of the goal node, -1 when the goal was not reached.
    edges : tuple of ndarray
        Sampled positions (k_i, 3) [m] of each node's incoming edge (empty for the root).
    """

    states: np.ndarray
    parent: np.ndarray
    cost: np.ndarray
    kind: np.ndarray
    steps: np.ndarray
    force: np.ndarray
    duration_s: np.ndarray
    iteration: np.ndarray
    wall_time_s: np.ndarray
    goal_node: int
    edges: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return int(self.states.shape[0])


@dataclass(frozen=True)
class PlanResult:
    """Outcome of a planner run.

    Attributes
    ----------
    status : str
        ``"solved"`` or ``"no_solution"``.
    planner : str
        ``"lqr-rrt-star"`` or ``"kino-rrt"``.
    trajectory : TranslationalTrajectory or None
        Start-to-goal trajectory (sampled every planner step), None without a solution.
    path : tuple of int
        Node indices from the start to the goal (empty without a solution).
    cost : float
        Cost of ``trajectory`` (NaN without a solution).
    tree : TreeRecord
        The final tree.
    rewires : tuple of RewireEvent
    solutions : tuple of SolutionEvent
        Every improvement of the best solution (the first is the first solution).
    snapshots : tuple of TreeSnapshot
        Parent links at regular iterations (and at the end).
    iterations : int
        Iterations run.
    planning_time_s : float
        Wall time [s].
    stop_reason : str
        ``"first_solution"``, ``"iterations"`` or ``"time_budget"``.
    stats : dict
        Counters (samples, steering failures, edges rejected by reason, goal-link attempts, ...).
    """

    status: str
    planner: str
    trajectory: TranslationalTrajectory | None
    path: tuple[int, ...]
    cost: float
    tree: TreeRecord
    rewires: tuple[RewireEvent, ...]
    solutions: tuple[SolutionEvent, ...]
    snapshots: tuple[TreeSnapshot, ...]
    iterations: int
    planning_time_s: float
    stop_reason: str
    stats: dict[str, int] = field(default_factory=dict)

    @property
    def solved(self) -> bool:
        """True when a start-to-goal trajectory was found."""
        return self.status == SOLVED

    @property
    def time_to_first_solution_s(self) -> float:
        """Wall time [s] of the first solution (NaN without one)."""
        return self.solutions[0].wall_time_s if self.solutions else float("nan")

    @property
    def iterations_to_first_solution(self) -> int:
        """Iteration of the first solution (-1 without one)."""
        return self.solutions[0].iteration if self.solutions else -1


def edge_trajectory(
    tree: Tree | TreeRecord, node: int, connector: LqrConnector, goal: np.ndarray
) -> TranslationalTrajectory:
    """The trajectory of ``node``'s incoming edge (from its parent's state to its own, exact).

    Parameters
    ----------
    tree : Tree or TreeRecord
    node : int
        A node other than the root.
    connector : LqrConnector
        The steering function that made the LQR edges; its robot model propagates the motion-primitive edges.
    goal : ndarray, shape (6,)
        Goal state of the plan.

    Returns
    -------
    TranslationalTrajectory
    """
    parent = int(tree.parent[node])
    x_p = tree.states[parent]
    kind = int(tree.kind[node])
    if kind == EDGE_LQR:
        return connector.trajectory(x_p, tree.states[node], goal, int(tree.steps[node]))
    if kind == EDGE_PRIMITIVE:
        traj = TranslationalTrajectory.from_forces(x_p, tree.force[node][None, :], tree.duration_s[node],
                                                   connector.model)
        x = traj.x.copy()
        x[-1] = tree.states[node]  # identical up to rounding; keep the node's stored state exactly
        return TranslationalTrajectory(traj.t, x, traj.u, traj.model)
    raise ValueError(f"node {node} has no incoming edge")


def path_trajectory(
    tree: Tree, path: list[int], connector: LqrConnector, goal: np.ndarray
) -> TranslationalTrajectory:
    """Concatenate the edges along ``path`` (root first) into one trajectory starting at t = 0.

    Parameters
    ----------
    tree : Tree
    path : list of int
        Node indices, root first.
    connector : LqrConnector
        The steering function that made the LQR edges; its robot model propagates the motion-primitive edges.
    goal : ndarray, shape (6,)
        Goal state of the plan.

    Returns
    -------
    TranslationalTrajectory
    """
    if len(path) < 2:
        return TranslationalTrajectory(np.zeros(1), tree.states[path[0]][None, :], np.zeros((0, 3)), connector.model)
    parts = [edge_trajectory(tree, n, connector, goal) for n in path[1:]]
    return TranslationalTrajectory.concatenate(parts)


def edge_polylines(
    tree: Tree, connector: LqrConnector, goal: np.ndarray, samples_per_edge: int = 8
) -> tuple[np.ndarray, ...]:
    """Positions along every node's incoming edge (the root gets an empty array), for drawing the tree.

    Parameters
    ----------
    tree : Tree
    connector : LqrConnector
        The steering function that made the LQR edges; its robot model propagates the motion-primitive edges.
    goal : ndarray, shape (6,)
        Goal state of the plan.
    samples_per_edge : int, optional
        Segments per edge.

    Returns
    -------
    tuple of ndarray, shape (samples_per_edge + 1, 3)
        One per node, in node order.
    """
    out: list[np.ndarray] = [np.zeros((0, 3))]
    for node in range(1, tree.n):
        traj = edge_trajectory(tree, node, connector, goal)
        t = np.linspace(traj.t[0], traj.t[-1], samples_per_edge + 1)
        out.append(traj.states_at(t)[:, 0:3])
    return tuple(out)


def tree_record(
    tree: Tree, goal_node: int, connector: LqrConnector, goal: np.ndarray
) -> TreeRecord:
    """Freeze a :class:`~oacli.planning.tree.Tree` into a :class:`TreeRecord` (with edge polylines).

    Parameters
    ----------
    tree : Tree
    goal_node : int
        Node that reached the goal (-1: none).
    connector : LqrConnector
        The steering function that made the LQR edges; its robot model propagates the motion-primitive edges.
    goal : ndarray, shape (6,)
        Goal state of the plan.

    Returns
    -------
    TreeRecord
    """
    duration = np.where(tree.kind == EDGE_LQR, tree.steps * connector.dt_s, tree.duration_s)
    return TreeRecord(
        states=tree.states.copy(),
        parent=tree.parent.copy(),
        cost=tree.cost.copy(),
        kind=tree.kind.copy(),
        steps=tree.steps.copy(),
        force=tree.force.copy(),
        duration_s=duration,
        iteration=tree.iteration.copy(),
        wall_time_s=tree.wall_time_s.copy(),
        goal_node=int(goal_node),
        edges=edge_polylines(tree, connector, goal),
    )
