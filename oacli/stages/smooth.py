"""The ``smooth`` stage: LQR shortcutting of a plan read back from its MCAP, then the path-length polish.

Inputs: the config (robot, scene, ``planner.weights``, ``planner.shortcut``, ``planner.polish``) and a previous
stage's MCAP with a
``/trajectory`` topic (``plan.mcap`` or an earlier ``smooth.mcap``). The input is refused (exit 2, no run folder)
when it is unreadable, in another frame, does not follow the double integrator of ``robot.mass_kg`` under its
held forces, does not end at rest, exceeds the force or velocity limits, or collides (a smoother must not launder
a colliding plan). Outputs: ``config.yaml``, ``smooth.mcap``, ``smooth.rrd``, ``summary.json``.

``smooth.mcap`` topics: ``/trajectory`` (the smoothed trajectory), ``/trajectory/input`` (the input as read),
``/trajectory/shortcut`` (after the shortcutting, before the polish; only when the polish ran), ``/robot/pose``,
``/scene`` (paths ``before``, ``shortcut`` when the polish ran, and ``after``), ``/smooth/shortcuts``
(oacli.ShortcutAttempt, one record per try, ``t = 0``), ``/smooth/polish`` (oacli.PolishIteration, one record per
SCP subproblem, ``t = 0``), ``/log``; metadata ``oacli.smooth`` (input file, costs, lengths).

Costs in ``summary.json``: ``cost_before`` is the input's LQR cost ``J``, ``cost_after_shortcut`` the cost after
the shortcutting (never higher), ``cost_after`` the output's. The polish minimises path length, not ``J``; with
``planner.polish.keep_cost`` (default) it never returns a trajectory costlier than the input, so
``cost_after <= cost_before`` still holds. ``polish`` holds its own before/after length, duration and cost.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.errors import InputError
from oacli.geometry import Scene
from oacli.geometry.collision import CollisionChecker
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter, read_stage, read_trajectory
from oacli.io.plots.plan import write_path_plots
from oacli.io.rerun.smooth import PolishSteps, ShortcutSteps, write_smooth_recording
from oacli.io.runfolder import StageResult
from oacli.phases import set_phase
from oacli.planning.full_state import minimum_time_lower_bound_s, translational_part
from oacli.planning.polish import SOLVER, STEP_OUTCOMES, PolishResult, polish_trajectory
from oacli.planning.shortcut import ACCEPTED, ShortcutResult, lqr_shortcut
from oacli.planning.translational import TranslationalTrajectory
from oacli.stages.design_limits import design_limit_log, planner_design_limits
from oacli.stages.plan import SMOOTH_STREAM, describe_body, to_output, trajectory_metrics
from oacli.stages.settings import cost_weights, open_run, polish_settings, robot_body, robot_model, shortcut_connector
from oacli.status import StatusReport, add_output_trajectory_reasons, status_log
from oacli.types import Trajectory

LogEntry = tuple[float, str, str]

def load_plan(cfg: OacliConfig, path: Path) -> Trajectory:
    """Read the input trajectory and check it against the config (see the module docstring)."""
    path = Path(path)
    record = read_stage(path, topics=["/trajectory"])
    if record.truncated:
        raise InputError(f"{path}: the file is truncated (its writer did not finish); rerun the stage that made it")
    traj = read_trajectory(path)
    if traj.frame != cfg.environment.frame:
        raise InputError(f"{path}: /trajectory is in frame {traj.frame!r}, the config's environment.frame is "
                         f"{cfg.environment.frame!r}")
    if len(traj) < 2:
        raise InputError(f"{path}: /trajectory has {len(traj)} sample; a plan needs at least two")
    return traj


def check_input(cfg: OacliConfig, path: Path, traj: Trajectory, checker: CollisionChecker) -> None:
    """Refuse an input the smoother cannot start from (InputError, exit 2).

    Its forces and velocities must be within the design limits (:func:`planner_design_limits`): the smoother only
    ever replaces sections, so an input beyond them would leave an output beyond them.
    """
    robot = robot_model(cfg)
    limits = planner_design_limits(cfg).limits
    trans = translational_part(traj, robot)
    if not trans.is_zoh_consistent():
        raise InputError(
            f"{path}: /trajectory does not follow the double integrator of robot.mass_kg = {robot.mass_kg:g} kg "
            f"under its held forces (largest deviation {trans.zoh_residual():.3g}); was it planned with another mass?"
        )
    if np.any(np.abs(trans.x[-1, 3:6]) > 1e-9):
        raise InputError(f"{path}: /trajectory does not end at rest (final velocity {trans.x[-1, 3:6]} m/s)")
    force = trans.max_abs_force_N()
    if np.any(force > limits.force_N * (1 + 1e-9)):
        raise InputError(f"{path}: /trajectory exceeds the design force limit {limits.force_N} N (robot.force_limit_N "
                         f"with planner.margin; largest |f| per axis {force} N): plan it with this config")
    vel = trans.max_abs_velocity_mps()
    if np.any(vel > limits.velocity_mps * (1 + 1e-9)):
        raise InputError(f"{path}: /trajectory exceeds the design velocity limit {limits.velocity_mps} m/s "
                         f"(robot.velocity_limit_mps with planner.margin; largest |v| per axis {vel} m/s): plan it "
                         "with this config")
    report = checker.check(trans.pieces())
    if not report.free:
        t_hit = float(trans.t[report.first_piece] + np.nan_to_num(report.time_in_piece_s))
        what = ("leaves the keep-in boxes" if report.kind == "keep_in"
                else f"enters keep-out zone environment.keep_out.{report.zone}")
        raise InputError(f"{path}: /trajectory {what} at t = {t_hit:.2f} s ({describe_body(checker.robot)}); "
                         "a colliding plan cannot be smoothed")


def write_smooth_topics(writer: StageMcapWriter, scene: Scene, source: Path, traj_in: Trajectory,
                        traj_shortcut: Trajectory, traj_out: Trajectory, result: ShortcutResult,
                        polish: PolishResult | None, summary: dict[str, Any], log: list[LogEntry]) -> None:
    """Write the smoothing's topics (module docstring) to its MCAP.

    Parameters
    ----------
    writer : StageMcapWriter
        The open writer.
    scene : Scene
        The workspace.
    source : Path
        The input MCAP (for the ``oacli.smooth`` metadata).
    traj_in, traj_shortcut, traj_out : Trajectory
        The input, the shortcut result (before the polish) and the output.
    result : ShortcutResult
        The shortcutting's record.
    polish : PolishResult or None
        The polish's record (None when it did not run).
    summary : dict
        The stage's summary (for the metadata).
    log : list of (float, str, str)
        The stage's log.
    """
    writer.write_metadata("oacli.smooth", {
        "input": str(source), "cost_before": summary["cost_before"],
        "cost_after_shortcut": result.cost_after, "cost_after": summary["cost_after"],
        "accepted": result.accepted, "tried": result.tried,
        "path_length_before_m": summary["path_length_before_m"],
        "path_length_after_m": summary["path_length_after_m"],
        "polish": "off" if polish is None else polish.status,
    })
    paths = {"before": traj_in.x[:, 0:3]}
    if polish is not None:
        paths["shortcut"] = traj_shortcut.x[:, 0:3]
    paths["after"] = traj_out.x[:, 0:3]
    writer.write_scene(scene, paths)
    writer.write_trajectory("/trajectory", traj_out)
    writer.write_trajectory("/trajectory/input", traj_in)
    if polish is not None:
        writer.write_trajectory("/trajectory/shortcut", traj_shortcut)
    writer.write_poses(traj_out.t, traj_out.x)
    writer.write_robot_body(traj_out.t, traj_out.x)
    for a in result.attempts:
        writer.write_json(ms.TOPIC_SMOOTH_SHORTCUTS, ms.SHORTCUT_ATTEMPT, ms.SHORTCUT_ATTEMPT_SCHEMA, 0.0, {
            "try": a.index, "a": a.a, "b": a.b, "t_a": a.t_a, "t_b": a.t_b, "steps": a.steps,
            "old_cost": a.old_cost, "new_cost": a.new_cost, "outcome": a.outcome,
        })
    for it in polish.iterations if polish is not None else ():
        writer.write_json(ms.TOPIC_SMOOTH_POLISH, ms.POLISH_ITERATION, ms.POLISH_ITERATION_SCHEMA, 0.0, {
            "iteration": it.index, "trust_radius_m": it.trust_radius_m, "status": it.status,
            "objective": it.objective, "buffer_m": it.buffer_m, "length_m": it.length_m,
            "duration_s": it.duration_s, "cost": it.cost, "solve_time_s": it.solve_time_s,
            "outcome": it.outcome, "predicted": it.predicted,
        })
    for t, level, message in log:
        writer.write_log(t, level, message)


def _cost_per_try(result: ShortcutResult) -> np.ndarray:
    costs = [result.cost_before]
    for a in result.attempts:
        costs.append(costs[-1] - (a.old_cost - a.new_cost) if a.outcome == ACCEPTED else costs[-1])
    return np.array(costs)


def run_polish(cfg: OacliConfig, trans: TranslationalTrajectory, checker: CollisionChecker, goal: np.ndarray,
               cost_cap: float | None) -> PolishResult:
    """Polish a shortcut result as configured in ``planner.polish`` (duration budget from ``duration_factor``),
    within the design limits."""
    robot, p = robot_model(cfg), cfg.planner.polish
    limits = planner_design_limits(cfg).limits
    budget = None
    if p.duration_factor is not None:
        bound = minimum_time_lower_bound_s(trans.x[0], goal, limits.force_N, limits.velocity_mps, robot)
        budget = p.duration_factor * bound
    return polish_trajectory(trans, checker, goal, limits.force_N, limits.velocity_mps, cost_weights(cfg),
                             dt_s=cfg.planner.output_dt_s,
                             duration_budget_s=budget, cost_cap=cost_cap, settings=polish_settings(cfg))


def polish_summary(polish: PolishResult, wall_time_s: float) -> dict[str, Any]:
    """The ``polish`` entry of summary.json (before = after the shortcutting)."""
    return {
        "enabled": True, "status": polish.status, "reason": polish.reason,
        "iterations": len(polish.iterations), "accepted": polish.accepted, "pieces": polish.pieces,
        "length_before_m": polish.length_before_m, "length_after_m": polish.length_after_m,
        "duration_before_s": polish.duration_before_s, "duration_after_s": polish.duration_after_s,
        "duration_budget_s": polish.duration_budget_s,
        "cost_before": polish.cost_before, "cost_after": polish.cost_after, "cost_cap": polish.cost_cap,
        "outcomes": {k: sum(it.outcome == k for it in polish.iterations) for k in STEP_OUTCOMES},
        "wall_time_s": wall_time_s,
    }


def smooth_findings(summary: dict[str, Any], polish: PolishResult | None) -> StatusReport:
    """The smoothed trajectory colliding or beyond a limit is ``unsafe``; a polish whose every SCP subproblem
    failed in the solver is ``degraded`` (the shortcut result is returned) (:mod:`oacli.status`)."""
    report = StatusReport()
    add_output_trajectory_reasons(report, summary, "smoothed trajectory")
    if polish is not None and polish.iterations and all(it.outcome == SOLVER for it in polish.iterations):
        report.degraded("polish", f"the polish failed: every one of its {len(polish.iterations)} subproblems failed "
                                  f"in the solver (last status {polish.iterations[-1].status}); the shortcut result "
                                  "is returned")
    return report


def run_smooth(
    cfg: OacliConfig,
    *,
    input_path: Path,
    out: Path | None = None,
    runs_root: Path = Path("runs"),
    progress: Callable[[float], None] | None = None,
) -> StageResult:
    """Run the ``smooth`` stage on ``input_path`` and write its run folder (module docstring).

    Raises
    ------
    InputError
        Unreadable or unsuitable input (before any file is written).
    """
    wall_start = time.perf_counter()
    input_path = Path(input_path).resolve()
    traj_in = load_plan(cfg, input_path)
    robot = robot_model(cfg)
    q_start, q_goal = traj_in.x[0, 6:10], traj_in.x[-1, 6:10]
    body = robot_body(cfg, q_start, q_goal)
    checker = CollisionChecker(cfg.scene(), body)
    check_input(cfg, input_path, traj_in, checker)
    trans = translational_part(traj_in, robot)
    goal = trans.x[-1].copy()
    p = cfg.planner
    connector = shortcut_connector(cfg)
    limits = planner_design_limits(cfg)
    lim = limits.limits

    log: list[LogEntry] = [(0.0, "info", f"smoothing {input_path} ({traj_in.duration_s:.1f} s) with "
                                         f"{p.shortcut.tries} LQR shortcut tries"
                                         + (", then the path-length polish" if p.polish.enabled else "")),
                           *design_limit_log(limits)]
    with open_run("smooth", cfg, out=out, runs_root=runs_root, started=wall_start) as run:
        rng = np.random.default_rng([cfg.seed, SMOOTH_STREAM])
        set_phase(progress, f"LQR shortcuts ({p.shortcut.tries} tries)")
        result = lqr_shortcut(
            trans, connector, checker, goal, lim.force_N, lim.velocity_mps,
            rng, tries=p.shortcut.tries, sample_dt_s=p.output_dt_s,
        )
        if progress is not None:
            progress(0.5 if p.polish.enabled else 1.0)
        polish: PolishResult | None = None
        final = result.trajectory
        if p.polish.enabled:
            t_polish = time.perf_counter()
            set_phase(progress, "path-length polish")
            polish = run_polish(cfg, result.trajectory, checker, goal,
                                result.cost_before if p.polish.keep_cost else None)
            polish_wall = time.perf_counter() - t_polish
            final = polish.trajectory
            if progress is not None:
                progress(1.0)
        traj_shortcut = to_output(cfg, result.trajectory, q_start, q_goal, "smooth")
        traj_out = to_output(cfg, final, q_start, q_goal, "smooth") if polish is not None else traj_shortcut
        before = trajectory_metrics(cfg, traj_in, checker, body, goal)
        after = trajectory_metrics(cfg, traj_out, checker, body, goal)
        summary: dict[str, Any] = {
            "stage": "smooth",
            "status": "ok",
            "input": str(input_path),
            "seed": cfg.seed,
            "cost_before": result.cost_before,
            "cost_after_shortcut": result.cost_after,
            "cost_after": after["cost"],
            "duration_before_s": traj_in.duration_s,
            "duration_after_shortcut_s": traj_shortcut.duration_s,
            "duration_after_s": traj_out.duration_s,
            "path_length_before_m": before["path_length_m"],
            "path_length_after_shortcut_m": result.trajectory.path_length_m(),
            "path_length_after_m": after["path_length_m"],
            "impulse_before_Ns": before["impulse_Ns"],
            "impulse_after_Ns": after["impulse_Ns"],
            "shortcuts_tried": result.tried,
            "shortcuts_accepted": result.accepted,
            "shortcuts_rejected": result.rejected,
            "polish": {"enabled": False} if polish is None else polish_summary(polish, polish_wall),
            "design_limits": limits.summary(),
            **{k: after[k] for k in after if k not in ("path_length_m", "impulse_Ns", "cost")},
        }
        summary["cost"] = after["cost"]
        smooth_findings(summary, polish).apply(summary)
        log.append((traj_out.duration_s, "info",
                    f"shortcutting: cost {result.cost_before:.6g} -> {result.cost_after:.6g}, duration "
                    f"{traj_in.duration_s:.1f} s -> {traj_shortcut.duration_s:.1f} s, {result.accepted}/{result.tried} "
                    "shortcuts accepted"))
        if polish is not None:
            log.append((traj_out.duration_s, "info",
                        f"polish ({polish.status}, {polish.reason}): path length {polish.length_before_m:.4f} m -> "
                        f"{polish.length_after_m:.4f} m, cost {polish.cost_before:.6g} -> {polish.cost_after:.6g}, "
                        f"{polish.accepted}/{len(polish.iterations)} SCP steps accepted"))
        log.extend(status_log(summary, traj_out.duration_s))
        with run.open_mcap() as writer:
            write_smooth_topics(writer, checker.scene, input_path, traj_in, traj_shortcut, traj_out, result, polish,
                                summary, log)
        shortcut_steps = ShortcutSteps([(i, sec.x[:, 0:3]) for i, sec in result.sections], _cost_per_try(result))
        polish_steps = None if polish is None else PolishSteps(
            traj_shortcut.x[:, 0:3], [(i, c.x[:, 0:3]) for i, c in polish.accepted_trajectories],
            np.array([it.length_m for it in polish.iterations]))
        write_smooth_recording(
            run.file("rrd", "smooth.rrd"), scene=checker.scene, before=traj_in, after=traj_out,
            shortcuts=shortcut_steps, polish=polish_steps, limits=lim, log=log, recording_name=f"{cfg.name}/smooth",
        )
        if cfg.outputs.plots:
            write_path_plots(run, summary, scene=checker.scene, robot_radius_m=float(robot_model(cfg).radius_m),
                             paths={"plan (input)": traj_in.x[:, 0:3], "smoothed": traj_out.x[:, 0:3]},
                             start_m=traj_in.x[0, 0:3], goal_m=goal[0:3])
        return run.finish(summary)

