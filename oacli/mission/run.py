"""Run a mission: every stage of :data:`oacli.mission.layout.MISSION_STAGES` in order, each in its own folder.

Each stage runs through the same function its command uses (``run_plan``, ``run_smooth``, ``run_excite``,
``run_track``, ``run_estimate``) with the config :func:`oacli.mission.configs.stage_config` derives, and hands its
files to the next (:func:`handoff_for`). A stage whose folder is complete (:func:`oacli.io.runfolder.is_complete`) is
kept when resuming; an incomplete one is removed and rerun. Everything a stage needs comes from the earlier stages'
files, so a resumed mission equals an uninterrupted one with the same seed. The mission folder's ``summary.json`` is
written last; an interruption or failure leaves one saying so (never a complete-looking mission). While the mission
runs, the files its stages write are also kept in memory (:mod:`oacli.io.mcap_memo`), so reading one back (the next
stage's input, the summary, the recording, the plots) decodes what was written without walking the file again: the
same records as the file's.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig, dump_config
from oacli.errors import InfeasibleError, InputError, OacliError
from oacli.io import mcap_memo
from oacli.io import mcap_schema as ms
from oacli.io.atomic import write_text_atomic
from oacli.io.folder_lock import folder_lock
from oacli.io.runfolder import create_run_dir, is_complete, write_summary
from oacli.mission.background import BACKGROUND, LAUNCH_BEFORE, MISSION_MCAP_JOB, BackgroundStages, Outcome
from oacli.mission.calibration import (
    CALIBRATE_KEY,
    MANOEUVRE_KEY,
    ON_MANOEUVRE_KEY,
    actuator_calibration,
    calibration_stage_prior,
    estimate_failures,
)
from oacli.mission.compare import ARRIVAL_TOLERANCE_M, comparison_row
from oacli.mission.configs import Handoff, mission_section, prior_model, stage_config, with_rigid_estimate
from oacli.mission.foxglove import MISSION_MCAP, write_mission_mcap
from oacli.mission.layout import ALL_STAGES, SEGMENTS, UNCONSTRAINED_BASELINE, MissionStage, stage_by_key
from oacli.mission.plots import write_mission_plots
from oacli.mission.records import load_mission_records, read_telemetry_cached, remember_config, stage_record
from oacli.mission.stage_call import run_stage
from oacli.mission.verdict import MissionStageError, plan_above_nominal, stage_verdict, stop_reason
from oacli.model.robot_model import RobotModel
from oacli.signals import held
from oacli.status import COMPLETE_STATUSES, DEGRADED, FAILED, INTERRUPTED, NO_SOLUTION

ProgressFactory = Callable[[str], Callable[[float], None] | None]
"""Given a stage's key, the progress callback for that stage (or None)."""

BASELINE_STAGES = ("baseline-mpc-prior", "baseline-tube-prior", "baseline-mpc-unconstrained-prior")


@dataclass
class MissionResult:
    """What a mission produced.

    Attributes
    ----------
    run_dir : Path
        The mission folder.
    summary : dict
        The content of its ``summary.json``.
    stages : dict of str to dict
        Each stage's summary, by key (``segment-1/plan`` ...).
    """

    run_dir: Path
    summary: dict[str, Any]
    stages: dict[str, dict[str, Any]] = field(default_factory=dict)


def mission_stages(cfg: OacliConfig) -> tuple[MissionStage, ...]:
    """The stages this mission runs (the baselines only with ``mission.baselines``; the unconstrained standard MPC
    only with ``mission.unconstrained_baseline`` too; the actuator calibration only with ``mission.calibration``).

    Parameters
    ----------
    cfg : OacliConfig
        A mission config.

    Returns
    -------
    tuple of MissionStage
    """
    mission = mission_section(cfg)
    skip = set() if mission.baselines else set(BASELINE_STAGES)
    if not (mission.baselines and mission.unconstrained_baseline):
        skip.add(UNCONSTRAINED_BASELINE.split("/")[1])
    if not mission.calibration:
        skip.add(CALIBRATE_KEY.split("/")[1])
    if not (mission.calibration and mission.calibration_manoeuvre is not None):
        skip.update(k.split("/")[1] for k in (MANOEUVRE_KEY, ON_MANOEUVRE_KEY))
    stages = [s for s in ALL_STAGES if s.name not in skip]
    if mission.calibration and mission.calibration_manoeuvre is not None:  # at B, before the grasp
        extra = [stages.pop([s.key for s in stages].index(k)) for k in (MANOEUVRE_KEY, ON_MANOEUVRE_KEY)]
        at = [s.key for s in stages].index(CALIBRATE_KEY)
        stages[at:at + 1] = [extra[0], stages[at], extra[1]]
    return tuple(stages)


def _final_position(track_mcap: Path) -> np.ndarray:
    tel = read_telemetry_cached(track_mcap)
    return np.asarray(tel.x_true[-1, 0:3], dtype=float)


def _waypoint(cfg: OacliConfig, name: str) -> np.ndarray:
    return np.asarray(cfg.waypoints[name].position, dtype=float)


def estimate_model(cfg: OacliConfig, estimate_mcap: Path) -> RobotModel:
    """The learned model: the prior model with the batch estimate's θ and covariance (its final record).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    estimate_mcap : Path
        ``segment-2/estimate/estimate.mcap``.

    Returns
    -------
    RobotModel
    """
    record = stage_record(estimate_mcap, "estimate")  # the topics the mission records read too: one read
    params = [r for r in record.json_records.get(ms.TOPIC_ESTIMATE_PARAMS, ()) if r.get("final")]
    if not params:
        raise InputError(f"{estimate_mcap}: no final /estimate/params record")
    final = params[-1]
    theta = np.array([final["mass_kg"], *final["inertia_kgm2"]], dtype=float)
    model = prior_model(cfg).with_estimate(theta, np.asarray(final["covariance"], dtype=float))
    summary = estimate_mcap.parent / "summary.json"
    rigid = _read_summary(estimate_mcap.parent).get("rigid_body") if summary.is_file() else None
    return model if not rigid else with_rigid_estimate(model, rigid)


@dataclass(frozen=True)
class LearnedModel:
    """What segment 3 is handed: the learned model, or the prior when the estimate failed.

    Attributes
    ----------
    model : RobotModel
        θ and its covariance segment 3 plans, tubes and tracks with.
    source : str
        ``estimate`` (the batch estimate) or ``prior`` (the fallback).
    note : str or None
        Why the estimate was not handed on (None when it was).
    """

    model: RobotModel
    source: str
    note: str | None = None

    def summary(self) -> dict[str, Any]:
        """The ``learned_model`` entry of the mission's summary."""
        m = self.model
        return {"source": self.source, "mass_kg": m.mass_kg, "mass_std_kg": m.mass_std_kg,
                "inertia_kgm2": [float(v) for v in m.inertia_kgm2], "inertia_std_kgm2": [float(v) for v in m.std[1:]],
                "com_offset_m": [float(v) for v in m.com_offset_m], "com_std_m": [float(v) for v in m.com_std_m],
                "inertia_products_kgm2": [float(v) for v in m.inertia_products_kgm2],
                "products_std_kgm2": [float(v) for v in m.products_std_kgm2], "note": self.note}


def learned_model(cfg: OacliConfig, mission_dir: Path) -> LearnedModel:
    """The model segment 3 is handed: the batch estimate (θ and covariance), or the prior when it failed.

    A batch estimate that did not converge, identifies no covariance, or is not physical is not handed on:
    segment 3 then flies the conservative model, the prior (its mean and covariance, the range W and the design
    margins of segment 2 were sized for), and the mission says so (``learned_model.note``, status ``degraded``).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    mission_dir : Path
        The mission folder (``segment-2/estimate`` complete in it).

    Returns
    -------
    LearnedModel
    """
    folder = stage_by_key("segment-2/estimate").folder(Path(mission_dir))
    if is_complete(folder):
        problems = estimate_failures(_read_summary(folder))
    else:  # the stage refused (e.g. θ unobservable from the telemetry): no estimate at all
        problems = ["failed (no estimate from segment 2's telemetry)"]
    if not problems:
        try:
            return LearnedModel(estimate_model(cfg, stage_by_key("segment-2/estimate").mcap(Path(mission_dir))),
                                "estimate")
        except ValueError as exc:
            problems.append(f"is not physical ({exc})")
    prior = prior_model(cfg)
    note = (f"the batch estimate {' and '.join(problems)}: segment 3 flies the prior model instead (mass "
            f"{prior.mass_kg:.4g} ± {prior.mass_std_kg:.3g} kg, the range segment 2 was sized for)")
    return LearnedModel(prior, "prior", note)


def handoff_for(cfg: OacliConfig, stage: MissionStage, mission_dir: Path) -> Handoff:
    """What the earlier stages' files hand to ``stage`` (module docstring).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    stage : MissionStage
        The stage about to run.
    mission_dir : Path
        The mission folder (the earlier stages are complete in it).

    Returns
    -------
    Handoff
    """
    _, b, c = mission_section(cfg).route
    d = Path(mission_dir).resolve()
    learned = learned_model(cfg, d).model if stage.segment == "segment-3" else None
    if stage.command == "smooth":
        return Handoff(plan=stage_by_key(f"{stage.segment}/plan").mcap(d), estimate=learned)
    if stage.key == CALIBRATE_KEY:
        return Handoff(telemetry=stage_by_key("segment-1/track").mcap(d))
    if stage.key == ON_MANOEUVRE_KEY:  # fitted from the first calibration's scales (the config's if rejected)
        return Handoff(telemetry=stage_by_key(MANOEUVRE_KEY).mcap(d), rigid_body=calibration_stage_prior(cfg, d))
    if stage.command == "estimate":
        calibration = actuator_calibration(cfg, d)
        return Handoff(telemetry=stage_by_key("segment-2/track").mcap(d),
                       rigid_body=calibration.rigid_body if calibration is not None else None)
    if stage.command != "track":
        return Handoff(estimate=learned)
    if stage.key == MANOEUVRE_KEY:  # from where segment 1 ended, at B
        offset = _final_position(stage_by_key("segment-1/track").mcap(d)) - _waypoint(cfg, b)
        return Handoff(initial_offset_m=tuple(offset.tolist()))
    if stage.segment == "segment-1":
        return Handoff(reference=stage_by_key("segment-1/smooth").mcap(d))
    if stage.segment == "segment-2":
        before = MANOEUVRE_KEY if MANOEUVRE_KEY in {s.key for s in mission_stages(cfg)} else "segment-1/track"
        offset = _final_position(stage_by_key(before).mcap(d)) - _waypoint(cfg, b)
        return Handoff(reference=stage_by_key("segment-2/excite").mcap(d), initial_offset_m=tuple(offset.tolist()))
    offset = _final_position(stage_by_key("segment-2/track").mcap(d)) - _waypoint(cfg, c)
    return Handoff(reference=stage_by_key("segment-3/smooth").mcap(d), initial_offset_m=tuple(offset.tolist()),
                   estimate=learned)


def validate_mission(cfg: OacliConfig) -> None:
    """Derive every stage's config with placeholder hand-offs, so a bad override stops the mission before it runs.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.

    Raises
    ------
    ConfigError
        Naming the stage, the segment's overrides and the field.
    """
    placeholder = Path("placeholder.mcap")
    for stage in mission_stages(cfg):
        ref = placeholder if stage.command == "track" else None
        stage_config(cfg, stage, Handoff(reference=ref))


def _read_summary(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "summary.json").read_text())


def _clear_incomplete(folder: Path, mission_dir: Path) -> None:
    """Remove an incomplete stage folder (only ever inside the mission folder)."""
    folder = folder.resolve()
    if folder.exists():
        if Path(mission_dir).resolve() not in folder.parents:
            raise InputError(f"{folder}: not inside the mission folder {mission_dir}")
        shutil.rmtree(folder)


def start_mission(cfg: OacliConfig, *, out: Path | None, runs_root: Path) -> Path:
    """Create a new mission folder and write its ``config.yaml`` (first, atomically).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config (validated by :func:`validate_mission` first).
    out, runs_root : Path
        As for every stage (:func:`oacli.io.runfolder.create_run_dir`).

    Returns
    -------
    Path
        The folder ``runs_root/mission-<name>-<UTC stamp>`` or ``out``.
    """
    mission_dir = create_run_dir(f"mission-{cfg.name}", out=out, runs_root=runs_root)
    write_text_atomic(mission_dir / "config.yaml", dump_config(cfg))
    return mission_dir


def copy_stages_before(source_dir: Path, mission_dir: Path, cfg: OacliConfig, from_key: str) -> None:
    """Copy the complete stage folders that run before ``from_key`` from ``source_dir`` (``--from``).

    Parameters
    ----------
    source_dir : Path
        An earlier mission folder (not modified).
    mission_dir : Path
        The new mission folder.
    cfg : OacliConfig
        The mission config.
    from_key : str
        The first stage to rerun (``segment-3/track`` ...).

    Raises
    ------
    InputError
        A stage before ``from_key`` is not complete in ``source_dir``.
    """
    first = stage_by_key(from_key)
    for stage in mission_stages(cfg):
        if stage.key == first.key:
            return
        src = stage.folder(source_dir)
        if not is_complete(src):
            raise InputError(f"--from {from_key}: {src} is not complete; resume that mission first (--resume)")
        dst = stage.folder(mission_dir)
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(src, dst)


def run_mission(
    cfg: OacliConfig,
    mission_dir: Path,
    *,
    progress: ProgressFactory | None = None,
    announce: Callable[[str], None] | None = None,
    background: bool = False,
) -> MissionResult:
    """Run (or resume) every stage of a mission in ``mission_dir``, then write its outputs and ``summary.json``.

    Complete stage folders are kept; incomplete ones are removed and rerun.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    mission_dir : Path
        The mission folder (from :func:`start_mission`, or an interrupted one).
    progress : callable, optional
        Progress callback per stage key.
    announce : callable, optional
        Called with one line per stage (kept / running / its status).
    background : bool
        Run the stages the flight does not wait for (the calibrations, the sequential estimate, the baselines,
        ``mission.mcap``) in a second process beside it (:mod:`oacli.mission.background`): same files and numbers,
        less wall time on a machine with a free core. False: every stage in line, in order.

    Returns
    -------
    MissionResult

    Raises
    ------
    OacliError
        A stage of the mission proper failed (its folder and the mission's ``summary.json`` say why). A failing
        baseline is recorded in the comparison instead.

    Notes
    -----
    The stage MCAPs this run writes are remembered while it runs (:mod:`oacli.io.mcap_memo`): the hand-offs, the
    comparison rows, the recording and the plots read them back without walking the files again (same records).
    """
    with folder_lock(mission_dir, "mission"), mcap_memo.remembering():  # one process at a time (exit 2)
        return _run_mission(cfg, mission_dir, progress=progress, announce=announce, background=background)


def run_one_stage(cfg: OacliConfig, key: str, mission_dir: Path,
                  progress: Callable[[float], None] | None = None) -> tuple[dict[str, Any], OacliConfig | None]:
    """Run the stage ``key`` into its folder (an incomplete one is removed first), with its hand-off and config.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    key : str
        The stage's key.
    mission_dir : Path
        The mission folder (the stages it reads are complete in it).
    progress : callable, optional
        Progress callback.

    Returns
    -------
    summary : dict
        The stage's summary; for a failure the mission records (a baseline's or an estimate's: segment 3 then falls
        back to the prior, :func:`learned_model`), its entry (status ``failed``, ``error``, ``handled``).
    stage_cfg : OacliConfig or None
        The config it ran with; None for a recorded failure.

    Raises
    ------
    OacliError
        Any other stage's failure.
    """
    stage = stage_by_key(key)
    folder = stage.folder(mission_dir)
    _clear_incomplete(folder, mission_dir)
    folder.parent.mkdir(parents=True, exist_ok=True)
    try:
        handoff = handoff_for(cfg, stage, mission_dir)
        stage_cfg = stage_config(cfg, stage, handoff)
        result = run_stage(stage, stage_cfg, handoff, folder, progress)
    except OacliError as exc:
        if not (stage.name in BASELINE_STAGES or stage.command == "estimate"):
            raise
        return {"stage": stage.command, "status": FAILED, "error": "; ".join(exc.problems), "handled": True}, None
    return result.summary, stage_cfg


def _check_complete(key: str, summary: dict[str, Any], folder: Path) -> None:
    if summary.get("status") not in COMPLETE_STATUSES:
        raise OacliError(f"{key}: ended {summary.get('status')} (see {folder / 'summary.json'})")


def _run_mission(
    cfg: OacliConfig,
    mission_dir: Path,
    *,
    progress: ProgressFactory | None,
    announce: Callable[[str], None] | None,
    background: bool,
) -> MissionResult:
    wall = time.perf_counter()
    say = announce or (lambda _line: None)
    stages = mission_stages(cfg)
    number = {s.key: i for i, s in enumerate(stages, start=1)}
    own = [s.key for s in stages if s.name not in BASELINE_STAGES]
    results: dict[str, dict[str, Any]] = {}
    current: str | None = None
    in_background = background and any(s.key in BACKGROUND for s in stages)
    bg = BackgroundStages(cfg, mission_dir, run_one_stage) if in_background else None
    launched: list[str] = []  # handed to the background process, in order

    def record(outcome: Outcome) -> None:
        """A background stage's outcome, recorded as the chain records its own."""
        nonlocal current
        if outcome.key == MISSION_MCAP_JOB and outcome.kind == "done":
            return
        current = outcome.key
        if outcome.kind == "crash":
            raise RuntimeError(f"{outcome.key} (in the background process): {outcome.message}")
        if outcome.kind == "error":
            raise OacliError(outcome.message)
        tag = f"[{number[outcome.key]}/{len(stages)}] {outcome.key}"
        if outcome.kind == "handled":
            assert outcome.failure is not None
            results[outcome.key] = outcome.failure
            say(f"{tag}: failed: {outcome.failure['error']}")
        else:
            folder = stage_by_key(outcome.key).folder(mission_dir)
            results[outcome.key] = _read_summary(folder)
            say(f"{tag}: {results[outcome.key]['status']} ({results[outcome.key].get('wall_time_s', 0.0):.1f} s, "
                "beside the flight)")
            _check_complete(outcome.key, results[outcome.key], folder)
        current = None

    def launch(stage: MissionStage) -> None:
        assert bg is not None
        bg.submit([stage.key])
        launched.append(stage.key)
        say(f"[{number[stage.key]}/{len(stages)}] {stage.key}: running {stage.command} beside the flight")

    try:
        if bg is not None:
            bg.start()  # before any stage: forked while this process has one thread (mission.background)
        stopped: str | None = None
        stopped_at = len(stages)
        for i, stage in enumerate(stages, start=1):
            if stage.key in launched:
                continue
            current = stage.key
            folder = stage.folder(mission_dir)
            if is_complete(folder):
                results[stage.key] = _read_summary(folder)
                say(f"[{i}/{len(stages)}] {stage.key}: kept ({results[stage.key]['status']})")
            elif bg is not None and stage.key in BACKGROUND:
                launch(stage)  # estimates and baselines never stop a mission (stop_reason): nothing to check here
                continue
            else:
                if bg is not None:  # start what flies beside this stage, wait for what it reads
                    for later in stages[i:]:
                        if LAUNCH_BEFORE.get(later.key) == stage.key and not is_complete(later.folder(mission_dir)):
                            launch(later)
                    bg.wait_for({k for k in bg.pending() if stage.key not in BACKGROUND[k]}, record)
                    current = stage.key
                say(f"[{i}/{len(stages)}] {stage.key}: running {stage.command}")
                summary, stage_cfg = run_one_stage(cfg, stage.key, mission_dir,
                                                   progress(stage.key) if progress else None)
                results[stage.key] = summary
                if stage_cfg is None:
                    say(f"[{i}/{len(stages)}] {stage.key}: failed: {summary['error']}")
                    continue
                remember_config(folder / "config.yaml", stage_cfg)  # the outputs below need not parse it again
                say(f"[{i}/{len(stages)}] {stage.key}: {summary['status']} ({summary.get('wall_time_s', 0.0):.1f} s)")
                _check_complete(stage.key, summary, folder)
            stopped = stop_reason(stage.key, results[stage.key]) if stage.key in own else None
            stopped_at = number[stage.key]
            if stopped is not None:
                say(f"[{i}/{len(stages)}] {stopped}")
                break
        if bg is not None:
            bg.wait_all(record)
            if stopped is not None:  # what was launched beside a flight that stopped the mission did not fly
                after = {s.key for s in stages[stopped_at:]}
                for key in (k for k in launched if k in after):
                    results.pop(key, None)
                    _clear_incomplete(stage_by_key(key).folder(mission_dir), mission_dir)
        results = {s.key: results[s.key] for s in stages if s.key in results}
        current = None
        if stopped is not None:
            if bg is not None:
                bg.stop()
            summary = stopped_summary(cfg, stages, results, stopped)
            summary["wall_time_s"] = time.perf_counter() - wall
            write_summary(mission_dir, summary)
            return MissionResult(mission_dir, summary, results)
        summary = mission_summary(cfg, mission_dir, stages, results)
        say("writing mission.mcap (every stage on the mission clock, for Foxglove: docs/foxglove/mission.json)")
        if bg is not None:
            bg.submit([MISSION_MCAP_JOB], summary)
        else:
            write_mission_mcap(mission_dir, summary)
        say("writing mission.rrd" + (" and plots/" if cfg.outputs.mission_pngs else ""))
        from oacli.mission.recording import write_mission_recording  # rerun: imported after the worker's fork

        records = load_mission_records(mission_dir, summary)  # once for both (the stage MCAPs are cached)
        write_mission_recording(mission_dir / "mission.rrd", mission_dir, summary,
                                recording_name=f"{cfg.name}/mission", records=records)
        with held():  # matplotlib can swallow an interruption raised inside its drawing: raised after the PNGs
            plots = write_mission_plots(mission_dir, summary, records=records) if cfg.outputs.mission_pngs else {}
        if bg is not None:
            current = "mission outputs"
            bg.wait_all(record)
            bg.stop()  # before summary.json: once it is written, nothing is left to stop (a signal then keeps it)
        summary["files"]["rrd"] = "mission.rrd"
        summary["files"]["mcap"] = MISSION_MCAP
        summary["files"]["plots"] = {k: str(p.relative_to(mission_dir)) for k, p in plots.items()}
        summary["wall_time_s"] = time.perf_counter() - wall
        write_summary(mission_dir, summary)
        return MissionResult(mission_dir, summary, results)
    except BaseException as exc:
        if bg is not None:  # nothing writes after the failed summary; an unfinished stage stays incomplete
            bg.stop()
        # The worst of the stages that ran stays the mission's status; the failure is reported beside it.
        verdict = stage_verdict(results, own)
        interrupted = isinstance(exc, KeyboardInterrupt)
        reason = "; ".join(exc.problems) if isinstance(exc, OacliError) else f"{type(exc).__name__}: {exc}"
        where = current or "mission outputs"
        level = INTERRUPTED if interrupted else NO_SOLUTION if isinstance(exc, InfeasibleError) else FAILED
        verdict.add(level, "interrupted" if interrupted else "failed", f"{where}: {reason}")
        failed = verdict.apply({"stage": "mission", "name": cfg.name, "seed": cfg.seed, "error": reason,
                                "failed_stage": where,
                                "stages": {k: {"status": v.get("status")} for k, v in results.items()},
                                "resume": f"oacli mission --resume {mission_dir}"})
        write_summary(mission_dir, failed)
        if isinstance(exc, OacliError) and not isinstance(exc, MissionStageError):
            # The mission's config was valid (validate_mission ran first): not exit 2, the mission's status's code.
            raise MissionStageError([f"{where}: {p}" for p in exc.problems], failed["status"]) from exc
        raise
    finally:
        if bg is not None:
            bg.stop()


def stopped_summary(cfg: OacliConfig, stages: tuple[MissionStage, ...], results: dict[str, dict[str, Any]],
                    reason: str) -> dict[str, Any]:
    """The ``summary.json`` of a mission stopped after an ``unsafe`` (or ``no_solution``) stage.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    stages : tuple of MissionStage
        The stages the mission would have run.
    results : dict
        The summaries of the stages that ran, by key.
    reason : str
        Why it stopped (:func:`oacli.mission.verdict.stop_reason`).

    Returns
    -------
    dict
        Status the worst of the stages that ran, the reason ``stopped``, every stage's status (``not_run`` for the
        stages after the stop).
    """
    own = [s.key for s in stages if s.name not in BASELINE_STAGES]
    verdict = stage_verdict(results, own)
    summary: dict[str, Any] = {
        "stage": "mission", "name": cfg.name, "seed": cfg.seed, "route": list(mission_section(cfg).route),
        "stopped": reason,
        "stages": {s.key: ({"status": results[s.key].get("status"), "wall_time_s": results[s.key].get("wall_time_s"),
                            "folder": f"{s.segment}/{s.name}", "command": s.command} if s.key in results
                           else {"status": "not_run", "folder": f"{s.segment}/{s.name}", "command": s.command})
                   for s in stages},
        "files": {"config": "config.yaml", "summary": "summary.json"},
    }
    if "segment-2/estimate" in results:
        summary["estimate"] = _estimate_entry(results["segment-2/estimate"])
    return verdict.apply(summary)


def _estimate_entry(estimate: dict[str, Any]) -> dict[str, Any]:
    return {k: estimate.get(k) for k in ("method", "mass_kg", "inertia_kgm2", "std", "crb_std", "truth_theta",
                                         "error_pct", "error_over_std", "cov_reduction_pct", "status")}


def _segment_times(stages_done: dict[str, dict[str, Any]]) -> dict[str, tuple[float, float]]:
    t0 = 0.0
    out = {}
    for seg in SEGMENTS:
        duration = float(stages_done[f"{seg}/track"]["sim_time_s"])
        if seg == "segment-1" and MANOEUVRE_KEY in stages_done:  # flown at B before the grasp
            duration += float(stages_done[MANOEUVRE_KEY].get("sim_time_s") or 0.0)
        out[seg] = (t0, duration)
        t0 += duration
    return out


def mission_summary(cfg: OacliConfig, mission_dir: Path, stages: tuple[MissionStage, ...],
                    results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The mission's ``summary.json`` content (contract in ``docs/mission.md``).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    mission_dir : Path
        The mission folder.
    stages : tuple of MissionStage
        The stages run.
    results : dict
        Each stage's summary by key.

    Returns
    -------
    dict
    """
    mission = mission_section(cfg)
    a, b, c = mission.route
    times = _segment_times(results)
    ends = {"segment-1": (a, b), "segment-2": (b, c), "segment-3": (c, a)}
    # A baseline is a counterfactual flight: its status is reported in the comparison, not the mission's.
    verdict = stage_verdict(results, [s.key for s in stages if s.name not in BASELINE_STAGES])
    learned = learned_model(cfg, mission_dir)
    if learned.note is not None:
        verdict.add(DEGRADED, "estimate_fallback", learned.note)
    calibration = actuator_calibration(cfg, mission_dir)
    if calibration is not None and calibration.source == "config" and calibration.note is not None:
        verdict.add(DEGRADED, "calibration_fallback", calibration.note)
    elif calibration is not None and calibration.replaced and calibration.note is not None:
        verdict.add(DEGRADED, "calibration_inconsistent", calibration.note)
    lagging = plan_above_nominal(results.get("segment-3/smooth"), results.get("segment-3/track"))
    if lagging is not None:
        verdict.add(DEGRADED, "plan_above_nominal", lagging)
    estimate = results["segment-2/estimate"]
    comparison = {}
    for key in ("segment-3/track", *(f"segment-3/{n}" for n in BASELINE_STAGES)):
        if key in results:
            comparison[key] = comparison_row(key, results[key], mission_dir)
    final = comparison.get("segment-3/track", {})
    if final.get("arrival_time_s", 0.0) is None:
        verdict.add(FAILED, "not_arrived", f"segment-3/track: the robot never stayed within {ARRIVAL_TOLERANCE_M:g} m "
                    f"of {a} ({final.get('final_distance_m', float('nan')):.3g} m from it at the end)")
    summary: dict[str, Any] = {
        "stage": "mission",
        "name": cfg.name,
        "seed": cfg.seed,
        "route": list(mission.route),
        "segments": {seg: {"from": ends[seg][0], "to": ends[seg][1], "start_time_s": times[seg][0],
                           "duration_s": times[seg][1]} for seg in SEGMENTS},
        "grasp_time_s": times["segment-2"][0],
        "mission_time_s": sum(d for _, d in times.values()),
        "stages": {s.key: {"status": results[s.key].get("status"), "wall_time_s": results[s.key].get("wall_time_s"),
                           "folder": f"{s.segment}/{s.name}", "command": s.command} for s in stages},
        "estimate": _estimate_entry(estimate),
        "learned_model": learned.summary(),
        "calibration": None if calibration is None else calibration.summary(),
        "estimate_sequential": {k: results["segment-2/estimate-sequential"].get(k)
                                for k in ("mass_kg", "inertia_kgm2", "std", "error_pct", "status")},
        "comparison": comparison,
        "files": {"config": "config.yaml", "summary": "summary.json"},
    }
    return verdict.apply(summary)
