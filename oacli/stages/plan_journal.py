"""The ``plan`` stage's journal: the search tree's growth and the best cost written to the MCAP while it runs.

The planners (:func:`oacli.planning.lqr_rrt_star.plan_lqr_rrt_star`, :func:`oacli.planning.kino_rrt.plan_kino_rrt`)
hand the tree to :meth:`PlanJournal.on_iteration` after every iteration (their ``on_iteration`` callback). Every
:data:`FLUSH_WALL_S` seconds of wall time or :data:`FLUSH_ITERATIONS` iterations the journal writes one
``oacli.PlanGrowth`` record on ``/plan/growth`` -- the iteration, the node count, the best cost so far, the nodes
added since the last record (index, parent, position, velocity, cost-to-come, iteration) and the nodes whose parent
changed since (rewires: index and new parent) -- and finishes a chunk on disk. A record holds at most
:data:`MAX_NODES_PER_RECORD` new nodes (more are split over several records), so every chunk stays bounded. A run
killed during the search leaves a ``.plan.mcap.<random>.partial`` that the ``mcap`` package reads up to its last
chunk (see :mod:`oacli.stages.stage_journal`); the complete ``plan.mcap`` replaces it at the end.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from oacli.io.mcap_write import StageMcapWriter
from oacli.planning.tree import Tree
from oacli.signals import atomic
from oacli.stages.stage_journal import StageJournal

#: Longest wall time between two records [s].
FLUSH_WALL_S = 0.5
#: Most iterations between two records.
FLUSH_ITERATIONS = 500
#: Most new nodes in one record (about 160 kB of JSON: within a 256 KiB chunk).
MAX_NODES_PER_RECORD = 1000

TOPIC_PLAN_GROWTH = "/plan/growth"
PLAN_GROWTH = "oacli.PlanGrowth"
PLAN_GROWTH_SCHEMA: dict[str, Any] = {
    "description": "The planner's tree growth since the previous record (the plan stage's journal; t is the wall "
                   "time since the search began).",
    "properties": {
        "t": {"type": "number", "description": "wall time since the search began [s]"},
        "iteration": {"type": "integer", "description": "planner iterations done"},
        "nodes": {"type": "integer", "description": "nodes in the tree"},
        "best_cost": {"type": ["number", "null"], "description": "cost of the best solution so far, null if none"},
        "node": {"type": "array", "description": "indices of the nodes added since the previous record"},
        "parent": {"type": "array", "description": "their parents (-1 for the root)"},
        "position": {"type": "array", "description": "their positions [m]"},
        "velocity": {"type": "array", "description": "their velocities [m/s]"},
        "cost": {"type": "array", "description": "their costs-to-come"},
        "node_iteration": {"type": "array", "description": "the iteration that added each"},
        "rewired": {"type": "array", "description": "earlier nodes whose parent changed since the previous record"},
        "new_parent": {"type": "array", "description": "their new parents"},
    },
}


class PlanJournal(StageJournal):
    """Write the tree's growth while the planner runs (module docstring).

    Parameters
    ----------
    open_writer : callable
        Returns the stage's time-ordered writer, not yet entered.
    """

    def __init__(self, open_writer: Callable[[], StageMcapWriter]) -> None:
        super().__init__(open_writer, flush_wall_s=FLUSH_WALL_S)
        self.records = 0
        self._written = 0  # nodes written so far
        self._parents = np.zeros(0, dtype=np.int64)  # their parents as last written
        self._last_iteration = 0
        self._latest: tuple[int, Tree, float, int] | None = None  # the last callback's iteration, tree, cost, nodes

    def on_iteration(self, iteration: int, tree: Tree, best_cost: float) -> None:
        """Take the tree after ``iteration`` iterations (a planner's ``on_iteration`` callback)."""
        self._latest = (iteration, tree, best_cost, tree.n)
        if iteration - self._last_iteration >= FLUSH_ITERATIONS or self.due():
            self.record(iteration, tree, best_cost)

    def on_interrupt(self, writer: StageMcapWriter) -> None:
        """Record the growth since the last record up to the last iteration the planner finished (the nodes it
        had then; an iteration cut short adds nothing)."""
        if self._latest is not None and self._latest[0] > self._last_iteration:
            iteration, tree, best_cost, nodes = self._latest
            self.record(iteration, tree, best_cost, nodes=nodes)

    def record(self, iteration: int, tree: Tree, best_cost: float, *, nodes: int | None = None) -> None:
        """Write the growth since the last record (the tree's first ``nodes`` nodes, default all) and finish a
        chunk on disk."""
        with atomic():  # an interruption waits until the record is on disk and its bookkeeping done
            writer = self.writer()
            if writer is None:
                return
            n = tree.n if nodes is None else min(int(nodes), tree.n)
            parent = tree.parent[:n]
            old = parent[: self._written]
            rewired = np.flatnonzero(old != self._parents)
            first = True
            while first or self._written < n:
                first = False
                lo, hi = self._written, min(n, self._written + MAX_NODES_PER_RECORD)
                cost = float(best_cost)
                writer.write_json(TOPIC_PLAN_GROWTH, PLAN_GROWTH, PLAN_GROWTH_SCHEMA, self.elapsed_s(), {
                    "iteration": int(iteration), "nodes": int(n),
                    "best_cost": cost if math.isfinite(cost) else None,
                    "node": np.arange(lo, hi), "parent": parent[lo:hi], "position": tree.states[lo:hi, 0:3],
                    "velocity": tree.states[lo:hi, 3:6], "cost": tree.cost[lo:hi],
                    "node_iteration": tree.iteration[lo:hi], "rewired": rewired, "new_parent": old[rewired],
                })
                rewired = rewired[:0]
                self._written = hi
                self._parents = parent[:hi].copy()  # the parents as written (the next record's rewires)
                self.records += 1
                self.flush()
            self._last_iteration = iteration
