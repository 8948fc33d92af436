"""The ``excite`` stage's journals: every SCP iteration of the offline design, or every control step of the RATTLE
closed loop, written to the MCAP as it is produced.

Offline design (:class:`ExciteJournal`):

:func:`oacli.excitation.design.design_excitation` hands each iteration to :meth:`ExciteJournal.on_iteration`
(its ``on_iteration`` callback), which writes one ``oacli.ScpProgress`` record on ``/excitation/scp`` -- the
start it belongs to, the iteration's criterion, merit, violation, trust regions, acceptance and solver status
(the fields of ``oacli.ScpIteration``), and the start's current design (positions (N+1, 3) [m] and inputs
(N, 6) [N, N·m]) when it changed (first iteration of a start, or an accepted step) -- and finishes a chunk on disk
(an SCP iteration takes 0.1-1 s, so every record is on disk at once). A run killed during the design leaves a
``.excite.mcap.<random>.partial`` readable up to its last chunk (see :mod:`oacli.stages.stage_journal`).

The run folder is created by the first record (so a problem refused before the first iteration, e.g. an
unreachable goal, leaves no folder). The complete ``excite.mcap`` replaces the journal at the end.

RATTLE closed loop (:class:`RattleJournal`): :func:`oacli.excitation.rattle_loop.run_rattle` hands every control
step to :meth:`RattleJournal.on_step` (the simulator's ``on_step``), which writes, on the mission time axis as
``track``'s journal does (:mod:`oacli.stages.track_journal`), ``/state/true`` (the plant samples), ``/reference``
(the plan followed, at the control instants), ``/state/measured``, ``/control/command``, ``/control/applied``,
``/disturbance`` and ``/solver/stats`` (a replan's solve time at the steps that replanned), merged by time, and
finishes a chunk every :data:`FLUSH_STEPS` control steps or :data:`FLUSH_WALL_S` seconds of wall time.

Both are kept as ``excite.mcap`` (valid, with the summary section) when the stage is interrupted by Ctrl-C or a
termination signal, next to an ``interrupted`` ``summary.json`` (:mod:`oacli.stages.stage_journal`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from oacli.excitation.design_types import ScpIterate
from oacli.io.mcap_write import StageMcapWriter
from oacli.signals import atomic
from oacli.stages.stage_journal import StageJournal
from oacli.types import SolveInfo

#: Control steps between two flushes of the RATTLE journal (a finished chunk each).
FLUSH_STEPS = 25
#: Longest wall time between two flushes of the RATTLE journal [s].
FLUSH_WALL_S = 1.0

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
        with atomic():  # an interruption waits until the record is on disk
            self._on_iteration(start, iterate, x, u)

    def _on_iteration(self, start: int, iterate: ScpIterate, x: np.ndarray, u: np.ndarray) -> None:
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


class RattleJournal(StageJournal):
    """Write the RATTLE closed loop's control steps while it runs (module docstring).

    Parameters
    ----------
    open_writer : callable
        Returns the stage's time-ordered writer, not yet entered.
    """

    def __init__(self, open_writer: Callable[[], StageMcapWriter]) -> None:
        super().__init__(open_writer, flush_wall_s=FLUSH_WALL_S)
        self.steps = 0
        self._ctrl: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, SolveInfo]] = []
        self._true: list[tuple[np.ndarray, np.ndarray]] = []
        self._t_last = 0.0  # latest mission time taken [s]

    def on_step(self, j: int, *, t_true: np.ndarray, x_true: np.ndarray, t_ctrl: float, x_measured: np.ndarray,
                x_reference: np.ndarray, u_command: np.ndarray, u_applied: np.ndarray, disturbance: np.ndarray,
                info: SolveInfo) -> None:
        """Take control step ``j`` (the keyword arguments of :func:`oacli.sim.simulator.simulate`'s ``on_step``)."""
        if self._closed:
            return
        with atomic():  # an interruption waits until the step is buffered (and a due flush is on disk)
            self._take(t_true, x_true, t_ctrl, x_measured, x_reference, u_command, u_applied, disturbance, info)

    def _take(self, t_true: np.ndarray, x_true: np.ndarray, t_ctrl: float, x_measured: np.ndarray,
              x_reference: np.ndarray, u_command: np.ndarray, u_applied: np.ndarray, disturbance: np.ndarray,
              info: SolveInfo) -> None:
        self._ctrl.append((float(t_ctrl), x_measured, x_reference, u_command, u_applied, disturbance, info))
        t = np.asarray(t_true, dtype=float)
        if t.size:
            self._true.append((t, np.asarray(x_true, dtype=float).reshape(-1, 13)))
            self._t_last = max(self._t_last, float(t[-1]))
        self._t_last = max(self._t_last, float(t_ctrl))
        self.steps += 1
        if len(self._ctrl) >= FLUSH_STEPS or self.due():
            self.flush()

    def flush(self) -> None:
        """Write the buffered steps merged by time and finish a chunk on disk."""
        if self._ctrl or self._true:
            writer = self.writer()
            if writer is not None:
                self._write(writer)
        super().flush()

    def _write(self, w: StageMcapWriter) -> None:
        ctrl, true = self._ctrl, self._true
        self._ctrl, self._true = [], []
        with w.time_ordered():
            if ctrl:
                t = np.array([c[0] for c in ctrl])
                x_meas, x_ref, u_cmd, u_app, dist = (np.array([c[i] for c in ctrl]) for i in range(1, 6))
                w.write_states("/reference", t, x_ref)
                w.write_states("/state/measured", t, x_meas, u_cmd)
                w.write_wrenches("/control/command", t, u_cmd)
                w.write_wrenches("/control/applied", t, u_app)
                w.write_wrenches("/disturbance", t, dist)
                w.write_solver_stats(t, [c[6] for c in ctrl])
            if true:
                w.write_states("/state/true", np.concatenate([a for a, _ in true]), np.vstack([b for _, b in true]))

    def on_interrupt(self, writer: StageMcapWriter) -> None:
        """Write the steps still buffered."""
        if self._ctrl or self._true:
            self._write(writer)
            writer.flush()

    def log_time_s(self) -> float:
        """The mission time of the latest step taken [s] (the journal's time axis)."""
        return self._t_last
