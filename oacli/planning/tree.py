"""The search tree of the sampling-based planners, with a rewire that really rewires.

Every node stores its state, its parent, its cost-to-come and the edge from its parent. An edge is either an exact
LQR connection of ``steps`` steps (LQR-RRT*, goal links) or one motion primitive: a force held for a duration
(kinodynamic RRT). Because LQR connections end *exactly* on their target state, giving a node a new parent leaves
the edges to its children valid; the children's costs then change by exactly the same amount as the node's cost,
and :meth:`Tree.rewire` propagates that change to every descendant. (The ReSWARM flight code and PythonRobotics'
LQR-RRT* compute a better parent and then keep the old one.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Edge kinds.
EDGE_ROOT = 0
EDGE_LQR = 1
EDGE_PRIMITIVE = 2


@dataclass(frozen=True)
class RewireEvent:
    """One rewiring: ``node`` moved from ``old_parent`` to ``new_parent``.

    Attributes
    ----------
    iteration : int
        Planner iteration of the rewire.
    node, old_parent, new_parent : int
        Node indices.
    old_steps, new_steps : int
        Horizons [steps] of the old and the new edge.
    old_cost, new_cost : float
        Cost-to-come of ``node`` before and after.
    descendants_updated : int
        Nodes below ``node`` whose cost changed by the same amount.
    """

    iteration: int
    node: int
    old_parent: int
    new_parent: int
    old_steps: int
    new_steps: int
    old_cost: float
    new_cost: float
    descendants_updated: int


class Tree:
    """Growable arrays of nodes with parent links and children lists.

    Parameters
    ----------
    root : ndarray, shape (6,)
        The start state.
    capacity : int
        Initial capacity (doubled when full).
    """

    def __init__(self, root: np.ndarray, capacity: int = 1024) -> None:
        cap = max(int(capacity), 2)
        self._states = np.empty((cap, 6))
        self._parent = np.full(cap, -1, dtype=np.int64)
        self._cost = np.empty(cap)
        self._kind = np.zeros(cap, dtype=np.int8)
        self._steps = np.zeros(cap, dtype=np.int64)
        self._force = np.zeros((cap, 3))
        self._duration = np.zeros(cap)
        self._iteration = np.zeros(cap, dtype=np.int64)
        self._time = np.zeros(cap)
        self._children: list[list[int]] = []
        self.n = 0
        self.add(root, -1, 0.0, EDGE_ROOT, iteration=0, wall_time_s=0.0)

    def _grow(self) -> None:
        for name in ("_states", "_parent", "_cost", "_kind", "_steps", "_force", "_duration", "_iteration", "_time"):
            arr = getattr(self, name)
            setattr(self, name, np.concatenate([arr, np.zeros_like(arr)]))

    def add(
        self,
        state: np.ndarray,
        parent: int,
        cost: float,
        kind: int,
        *,
        steps: int = 0,
        force: np.ndarray | None = None,
        duration_s: float = 0.0,
        iteration: int,
        wall_time_s: float,
    ) -> int:
        """Append a node; returns its index.

        Parameters
        ----------
        state : ndarray, shape (6,)
        parent : int
            Parent index (-1 for the root).
        cost : float
            Cost-to-come.
        kind : int
            Edge kind (:data:`EDGE_ROOT`, :data:`EDGE_LQR`, :data:`EDGE_PRIMITIVE`).
        steps : int, optional
            Horizon [steps] of an LQR edge.
        force : ndarray, shape (3,), optional
            Held force [N] of a motion-primitive edge.
        duration_s : float, optional
            Duration [s] of a motion-primitive edge.
        iteration : int
            Planner iteration that added the node.
        wall_time_s : float
            Planner time [s] at which it was added.

        Returns
        -------
        int
        """
        if self.n == self._states.shape[0]:
            self._grow()
        i = self.n
        self._states[i] = state
        self._parent[i] = parent
        self._cost[i] = cost
        self._kind[i] = kind
        self._steps[i] = steps
        self._force[i] = 0.0 if force is None else force
        self._duration[i] = duration_s
        self._iteration[i] = iteration
        self._time[i] = wall_time_s
        self._children.append([])
        if parent >= 0:
            self._children[parent].append(i)
        self.n += 1
        return i

    # -- views -----------------------------------------------------------------------------------------------

    @property
    def states(self) -> np.ndarray:
        """Node states (n, 6) (a view: do not modify)."""
        return self._states[: self.n]

    @property
    def parent(self) -> np.ndarray:
        """Parent indices (n,), -1 for the root."""
        return self._parent[: self.n]

    @property
    def cost(self) -> np.ndarray:
        """Cost-to-come (n,)."""
        return self._cost[: self.n]

    @property
    def kind(self) -> np.ndarray:
        """Edge kinds (n,) (:data:`EDGE_ROOT`, :data:`EDGE_LQR`, :data:`EDGE_PRIMITIVE`)."""
        return self._kind[: self.n]

    @property
    def steps(self) -> np.ndarray:
        """Horizon [steps] of each node's LQR edge (0 for other kinds)."""
        return self._steps[: self.n]

    @property
    def force(self) -> np.ndarray:
        """Held force [N] of each primitive edge (n, 3)."""
        return self._force[: self.n]

    @property
    def duration_s(self) -> np.ndarray:
        """Duration [s] of each primitive edge (n,)."""
        return self._duration[: self.n]

    @property
    def iteration(self) -> np.ndarray:
        """Iteration at which each node was added (n,)."""
        return self._iteration[: self.n]

    @property
    def wall_time_s(self) -> np.ndarray:
        """Planner wall time [s] at which each node was added (n,)."""
        return self._time[: self.n]

    def children(self, node: int) -> list[int]:
        """Children of ``node`` (a copy).

        Parameters
        ----------
        node : int

        Returns
        -------
        list of int
        """
        return list(self._children[node])

    # -- structure -------------------------------------------------------------------------------------------

    def path_to(self, node: int) -> list[int]:
        """Node indices from the root to ``node``.

        Parameters
        ----------
        node : int

        Returns
        -------
        list of int
        """
        out = []
        while node >= 0:
            out.append(int(node))
            node = int(self._parent[node])
        return out[::-1]

    def is_ancestor(self, ancestor: int, node: int) -> bool:
        """True when ``ancestor`` lies on the path from the root to ``node`` (a node is its own ancestor).

        Parameters
        ----------
        ancestor, node : int

        Returns
        -------
        bool
        """
        while node >= 0:
            if node == ancestor:
                return True
            node = int(self._parent[node])
        return False

    def descendants(self, node: int) -> list[int]:
        """Every node below ``node`` (not ``node`` itself), breadth first.

        Parameters
        ----------
        node : int

        Returns
        -------
        list of int
        """
        out: list[int] = []
        frontier = list(self._children[node])
        while frontier:
            out.extend(frontier)
            nxt: list[int] = []
            for c in frontier:
                nxt.extend(self._children[c])
            frontier = nxt
        return out

    def rewire(self, node: int, new_parent: int, new_cost: float, *, steps: int, iteration: int) -> RewireEvent:
        """Give ``node`` a new parent over an LQR edge of ``steps`` steps and cost-to-come ``new_cost``.

        The cost change is propagated to every descendant (their edges start at ``node``'s unchanged state).

        Parameters
        ----------
        node : int
        new_parent : int
        new_cost : float
            New cost-to-come of ``node``.
        steps : int
            Horizon [steps] of the new edge.
        iteration : int
            Planner iteration.

        Returns
        -------
        RewireEvent

        Raises
        ------
        ValueError
            If the new parent lies below ``node`` (that would make a cycle).
        """
        if self.is_ancestor(node, new_parent):
            raise ValueError(f"node {new_parent} lies below node {node}: rewiring would make a cycle")
        old_parent = int(self._parent[node])
        old_cost = float(self._cost[node])
        old_steps = int(self._steps[node])
        self._children[old_parent].remove(node)
        self._children[new_parent].append(node)
        self._parent[node] = new_parent
        self._kind[node] = EDGE_LQR
        self._steps[node] = steps
        self._force[node] = 0.0
        self._duration[node] = 0.0
        delta = new_cost - old_cost
        self._cost[node] = new_cost
        below = self.descendants(node)
        if below:
            self._cost[np.array(below)] += delta
        return RewireEvent(
            iteration, int(node), old_parent, int(new_parent), old_steps, int(steps), old_cost, float(new_cost),
            len(below),
        )
