"""The offline ``excite`` stage's journal: every SCP iteration written to the MCAP as it is produced.

:func:`oacli.excitation.design.design_excitation` hands each iteration to :meth:`ExciteJournal.on_iteration`
(its ``on_iteration`` callback), which writes one ``oacli.ScpProgress`` record on ``/excitation/scp`` -- the
start it belongs to, the iteration's criterion, merit, violation, trust regions, acceptance and solver status
(the fields of ``oacli.ScpIteration``), and the start's current design (positions (N+1, 3) [m] and inputs
(N, 6) [N, N·m]) when it changed (first iteration of a start, or an accepted step) -- and finishes a chunk on disk
(an SCP iteration takes 0.1-1 s, so every record is on disk at once). A run killed during the design leaves a
``.excite.mcap.<random>.partial`` readable up to its last chunk (see :mod:`oacli.stages.stage_journal`).

The run folder is created by the first record (so a problem refused before the first iteration, e.g. an
unreachable goal, leaves no folder). The complete ``excite.mcap`` replaces the journal at the end.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from oacli.excitation.design_types import ScpIterate
from oacli.io.mcap_write import StageMcapWriter
from oacli.stages.stage_journal import StageJournal

TOPIC_SCP = "/excitation/scp"
SCP_PROGRESS = "oacli.ScpProgress"
SCP_PROGRESS_SCHEMA: dict[str, Any] = {
    "description": "One SCP iteration of the offline excitation design as it was produced (the stage's journal; "
                   "t is the wall time since the design began).",
    "properties": {
        "t": {"type": "number", "description": "wall time since the design began [s]"},
        "start": {"type": "integer", "description": "index of the SCP start (multi-start screening), from 0"},
        "iteration": {"type": "integer", "description": "iteration number within the start, from 1"},
        "criterion": {"type": ["number", "null"], "description": "criterion of the design after the iteration"},
        "merit": {"type": ["number", "null"], "description": "merit J/J_ref + μ V after the iteration"},
        "violation": {"type": ["number", "null"], "description": "normalised constraint violation after it"},
        "candidate_criterion": {"type": ["number", "null"], "description": "criterion at the trial point"},
        "ratio": {"type": ["number", "null"], "description": "actual / predicted merit decrease"},
        "trust_region_force": {"type": "number", "description": "trust region, fraction of the force limit"},
        "trust_region_torque": {"type": "number", "description": "trust region, fraction of the torque limit"},
        "accepted": {"type": "boolean", "description": "the trial point became the design"},
        "status": {"type": "string", "description": "solver status of the subproblem"},
        "solve_time_ms": {"type": "number", "description": "subproblem solve time [ms]"},
        "position": {"type": ["array", "null"], "description": "design positions (N+1, 3) [m], null if unchanged"},
        "input": {"type": ["array", "null"], "description": "design inputs (N, 6) [N, N·m], null if unchanged"},
    },
}


class ExciteJournal(StageJournal):
    """Write the SCP iterations while the design runs (module docstring).

    Parameters
    ----------
    open_writer : callable
        Returns the stage's time-ordered writer, not yet entered (creating the run folder if needed).
    """

    def __init__(self, open_writer: Callable[[], StageMcapWriter]) -> None:
        super().__init__(open_writer, flush_wall_s=0.0)
        self.iterations = 0
        self._started: set[int] = set()

    def on_iteration(self, *, start: int, iterate: ScpIterate, x: np.ndarray, u: np.ndarray) -> None:
        """Take one SCP iteration (the keyword arguments of ``design_excitation``'s ``on_iteration``)."""
        writer = self.writer()
        if writer is None:
            return
        changed = bool(iterate.accepted) or start not in self._started
        self._started.add(start)
        writer.write_json(TOPIC_SCP, SCP_PROGRESS, SCP_PROGRESS_SCHEMA, self.elapsed_s(), {
            "start": int(start), "iteration": int(iterate.iteration), "criterion": iterate.criterion,
            "merit": iterate.merit, "violation": iterate.violation,
            "candidate_criterion": iterate.candidate_criterion, "ratio": iterate.ratio,
            "trust_region_force": iterate.trust_region_force, "trust_region_torque": iterate.trust_region_torque,
            "accepted": bool(iterate.accepted), "status": str(iterate.status),
            "solve_time_ms": 1e3 * iterate.solve_time_s,
            "position": np.asarray(x)[:, 0:3] if changed else None,
            "input": np.asarray(u) if changed else None,
        })
        self.iterations += 1
        self.flush()
