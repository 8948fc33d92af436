"""Stages a mission runs beside the flight on a second core: the calibrations, the sequential estimate, the
segment-3 baselines and ``mission.mcap``.

A mission is a chain (plan → smooth → track → … → estimate → plan …), but some of its stages feed nothing the chain
needs next: the actuator calibrations feed only segment 2's estimates, the sequential estimate and the three
segment-3 baselines feed only the mission's outputs, and ``mission.mcap`` is written beside ``mission.rrd`` and the
plots. On a machine with a free core they run in one background process while the chain goes on; every stage runs
exactly as it would in line (same config, same hand-off, same seed: a stage's seed comes from its place in
:data:`oacli.mission.layout.ALL_STAGES`, never from the order stages run in), into its own folder, so the mission's
files and numbers are the same (``tests/test_mission_background.py``). Only the wall time changes.

:data:`BACKGROUND` lists the stages that may run there, with the stages of the chain that do not read their output
(those run while it works; any other stage waits for it first). :data:`LAUNCH_BEFORE` starts the baselines before
``segment-3/track``: they fly the same reference from the same start with the prior model, so they only need what
``segment-3/track`` itself needs.

The worker is one child process, started with the mission (before any stage runs): forked when that is safe (no
thread but BLAS pools; rerun's import starts a runtime's threads, so the mission imports it after the fork), so it
shares what is already imported; spawned otherwise. It imports the stages' modules while the chain's first stages
run, takes jobs (lists of stage keys) in order and answers each with the stages' outcomes; the stages' results are their
folders, read back like kept stages. It ignores SIGINT: an interrupted mission stops it
(:meth:`BackgroundStages.stop`) and leaves an unfinished stage's folder incomplete, so ``--resume`` reruns it; it
dies with the mission's process (Linux). Campaigns run one mission per core and keep every stage in line.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from oacli.config import OacliConfig
from oacli.errors import OacliError
from oacli.mission.calibration import CALIBRATE_KEY, MANOEUVRE_KEY, ON_MANOEUVRE_KEY
from oacli.mission.layout import BASELINES, UNCONSTRAINED_BASELINE

_CHAIN_AFTER_SEGMENT_2 = frozenset({"segment-2/estimate", "segment-3/plan", "segment-3/smooth", "segment-3/track"})
_BASELINE_KEYS = (*(k for k in BASELINES if k != "segment-3/track"), UNCONSTRAINED_BASELINE)

BACKGROUND: dict[str, frozenset[str]] = {
    CALIBRATE_KEY: frozenset({MANOEUVRE_KEY, "segment-2/excite", "segment-2/track"}),
    ON_MANOEUVRE_KEY: frozenset({"segment-2/excite", "segment-2/track"}),
    "segment-2/estimate-sequential": _CHAIN_AFTER_SEGMENT_2,
    **{key: frozenset({"segment-3/track"}) for key in _BASELINE_KEYS},
}
"""Stages that may run in the background, each with the stages of the chain that may run before it has finished
(they do not read its output): the calibrations feed only segment 2's estimates
(:func:`oacli.mission.calibration.actuator_calibration`), the sequential estimate and the baselines only the
mission's outputs (segment 3 flies the batch estimate: :func:`oacli.mission.run.learned_model`)."""

LAUNCH_BEFORE: dict[str, str] = {CALIBRATE_KEY: MANOEUVRE_KEY, **{key: "segment-3/track" for key in _BASELINE_KEYS}}
"""Background stages started before a stage of the chain that comes earlier in the mission's order: segment 1's
calibration beside the calibration manoeuvre's flight (it reads segment 1's track only), the baselines beside
``segment-3/track`` (the same reference and start, the prior model)."""

MISSION_MCAP_JOB = "mission.mcap"
"""The job name of writing ``mission.mcap`` (:func:`oacli.mission.foxglove.write_mission_mcap`)."""

STAGE_MODULES = ("oacli.stages.track", "oacli.stages.estimate", "oacli.mission.foxglove")
"""Modules the worker imports as soon as it starts, before its first job (the background stages' commands)."""


@dataclass
class Outcome:
    """What the worker says about one stage of a job.

    Attributes
    ----------
    key : str
        The stage key (or :data:`MISSION_MCAP_JOB`).
    kind : str
        ``done`` (its folder is complete: read its summary), ``handled`` (a failure the mission records, in
        ``failure``), ``error`` (a failure that stops the mission: ``message``) or ``crash`` (an unexpected
        exception: ``message`` holds its traceback).
    failure : dict, optional
        The stage's entry for a handled failure.
    message : str
        The error's text.
    """

    key: str
    kind: str
    failure: dict[str, Any] | None = None
    message: str = ""


@dataclass
class _Job:
    keys: tuple[str, ...]
    outcomes: list[Outcome] | None = None


StageRunner = Callable[[OacliConfig, str, Path], tuple[dict[str, Any], OacliConfig | None]]
"""Runs one stage as the chain does: :func:`oacli.mission.run.run_one_stage`."""


def _worker(conn: Connection, cfg: OacliConfig, mission_dir: Path, run_one: StageRunner) -> None:
    """The background process: run each job received on ``conn`` and send its outcomes back (None ends it)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the mission's process decides what an interruption stops
    signal.signal(signal.SIGTERM, _exit_on_sigterm)  # BackgroundStages.stop: files being written are cleaned up
    _die_with_parent()
    import importlib

    for name in STAGE_MODULES:  # while the chain's first stages run: the first job starts at once
        importlib.import_module(name)
    while True:
        try:
            job = conn.recv()
        except EOFError:  # the mission's process is gone
            return
        if job is None:
            return
        keys, summary = job
        conn.send(_run_job(cfg, mission_dir, keys, summary, run_one))


def _run_job(cfg: OacliConfig, mission_dir: Path, keys: Sequence[str], summary: dict[str, Any] | None,
             run_one: StageRunner) -> list[Outcome]:
    """Run the stages ``keys`` in order as the chain would (``run_one``), or write ``mission.mcap`` from the
    mission's ``summary``."""
    from oacli.mission.foxglove import write_mission_mcap

    outcomes: list[Outcome] = []
    for key in keys:
        try:
            if key == MISSION_MCAP_JOB:
                assert summary is not None
                write_mission_mcap(mission_dir, summary)
                outcomes.append(Outcome(key, "done"))
                continue
            entry, stage_cfg = run_one(cfg, key, mission_dir)
            outcomes.append(Outcome(key, "done") if stage_cfg is not None else Outcome(key, "handled", failure=entry))
        except OacliError as exc:
            outcomes.append(Outcome(key, "error", message="; ".join(exc.problems)))
            break
        except (KeyboardInterrupt, SystemExit):  # stopped by the mission's process: nothing to report
            raise
        except BaseException:
            outcomes.append(Outcome(key, "crash", message=traceback.format_exc()))
            break
    return outcomes


def _exit_on_sigterm(signum: int, _frame: object) -> None:
    """SIGTERM in the worker: unwind (temporary files removed, the stage's folder left incomplete), then exit."""
    raise SystemExit(128 + signum)


def _die_with_parent() -> None:
    """Ask Linux to kill this process when the mission's process dies (``prctl(PR_SET_PDEATHSIG, SIGKILL)``): a
    mission killed with SIGKILL leaves no worker writing into its folder. Elsewhere the worker ends at its next job
    (the pipe's end of file)."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent died before the request took effect
        os._exit(1)


def _fork_safe() -> bool:
    """Whether forking this process is safe: no Python thread but the main one, and no named native thread (rerun's
    runtime workers, its allocator's); unnamed native threads (BLAS pools) re-initialise after a fork. Linux only
    (``/proc/self/task``); False where that cannot be told."""
    import threading

    if threading.active_count() != 1:
        return False
    try:
        tasks = os.listdir("/proc/self/task")
        names = {Path(f"/proc/self/task/{t}/comm").read_text().strip() for t in tasks}
        main_name = Path("/proc/self/comm").read_text().strip()
    except OSError:
        return False
    return names == {main_name}


@dataclass
class BackgroundStages:
    """One background process for a mission's stages (module docstring).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    mission_dir : Path
        The mission folder.
    run_one : callable
        Runs one stage as the chain does (:func:`oacli.mission.run.run_one_stage`; a module-level function, so a
        spawned worker can import it).
    """

    cfg: OacliConfig
    mission_dir: Path
    run_one: StageRunner
    start_method: str = ""
    _jobs: list[_Job] = field(default_factory=list)
    _process: Any = None
    _conn: Connection | None = None

    def start(self) -> None:
        """Fork the worker while this process has one thread (before rerun's import starts its runtime's threads:
        :mod:`oacli.mission.run` imports the recording lazily), spawn it otherwise; either way it then imports the
        stages' modules while the chain's first stages run."""
        self.start_method = "fork" if _fork_safe() else "spawn"
        ctx: Any = mp.get_context(self.start_method)
        parent, child = ctx.Pipe()
        self._process = ctx.Process(target=_worker, args=(child, self.cfg, Path(self.mission_dir), self.run_one),
                                    name="oacli-mission-background", daemon=True)
        self._process.start()
        child.close()
        self._conn = parent

    def submit(self, keys: Sequence[str], summary: dict[str, Any] | None = None) -> None:
        """Queue a job: the stages ``keys``, run in order after the jobs before it (``summary``: the mission's,
        for :data:`MISSION_MCAP_JOB`)."""
        if self._conn is None:
            self.start()
        assert self._conn is not None
        self._jobs.append(_Job(tuple(keys)))
        self._conn.send((tuple(keys), summary))

    def pending(self) -> set[str]:
        """The stage keys of the jobs not yet answered."""
        return {k for job in self._jobs if job.outcomes is None for k in job.keys}

    def wait_for(self, keys: set[str], on_outcome: Callable[[Outcome], None]) -> None:
        """Wait until no job holding one of ``keys`` is unanswered; ``on_outcome`` is called for each stage of
        every job answered meanwhile, in order."""
        while any(job.outcomes is None and set(job.keys) & keys for job in self._jobs):
            self._receive(on_outcome)

    def wait_all(self, on_outcome: Callable[[Outcome], None]) -> None:
        """Wait for every job (see :meth:`wait_for`)."""
        self.wait_for({k for job in self._jobs for k in job.keys}, on_outcome)

    def _receive(self, on_outcome: Callable[[Outcome], None]) -> None:
        assert self._conn is not None
        try:
            outcomes: list[Outcome] = self._conn.recv()
        except EOFError:
            code = None if self._process is None else self._process.exitcode
            raise OacliError(f"the mission's background process ended unexpectedly (exit code {code})") from None
        job = next(j for j in self._jobs if j.outcomes is None)
        job.outcomes = outcomes
        for outcome in outcomes:
            on_outcome(outcome)

    def stop(self) -> None:
        """End the worker: politely when it is idle, at once otherwise (an interrupted or failed mission)."""
        if self._process is None:
            return
        idle = not self.pending()
        if idle and self._conn is not None:
            try:
                self._conn.send(None)
            except OSError:
                pass
            self._process.join(timeout=5.0)
        if self._process.is_alive():
            self._process.terminate()  # SIGTERM: the worker unwinds (_exit_on_sigterm)
            self._process.join(timeout=10.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(timeout=5.0)
        if self._conn is not None:
            self._conn.close()
        self._process = self._conn = None


def background_workers_default() -> int:
    """How many background processes ``oacli mission`` uses unless told: 1 with two or more usable cores, else 0."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return 1 if cores >= 2 else 0


__all__ = ["BACKGROUND", "LAUNCH_BEFORE", "MISSION_MCAP_JOB", "BackgroundStages", "Outcome",
           "background_workers_default"]
