"""The ``track`` stage: follow a reference with MPC in closed loop and record everything.

Inputs: the config (robot model, truth plant, sensors, controller, scene) and a reference (from the config's
waypoints or file, or a file / previous stage's MCAP given on the command line). Outputs in the run folder:
``config.yaml`` (resolved, written first), ``track.mcap``, ``track.rrd`` and ``summary.json`` (written last).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oacli import __version__
from oacli.config import OacliConfig, dump_config
from oacli.control.tracking import TrackingLimits, TrackingMPC, TrackingWeights
from oacli.control.tube_monitor import TubeMonitor
from oacli.control.tube_mpc import TubeHistory
from oacli.errors import InputError
from oacli.geometry import Scene
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.reference_files import load_reference
from oacli.io.rerun_io import write_track_recording
from oacli.io.rerun_tube import tube_track_blueprint
from oacli.io.runfolder import git_commit, open_stage_run
from oacli.metrics import percentiles_ms, rms, tracking_errors
from oacli.reference import waypoint_reference
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.stages.design_limits import check_reference_for_plant
from oacli.stages.track_status import assess_track, controller_counts, status_log, track_safety
from oacli.stages.track_tube import (
    add_tube_reasons,
    describe_beyond_w,
    describe_tube_design,
    monitored_tube_controller,
    tube_design_from_config,
    tube_layers,
    tube_summary,
    workspace_arguments,
    write_tube_topics,
)
from oacli.status import StatusReport
from oacli.trajectory import sample_inputs
from oacli.types import Telemetry, Trajectory

LogEntry = tuple[float, str, str]


@dataclass(frozen=True)
class StageResult:
    """What a stage produced: its run folder, its summary and the files it wrote."""

    run_dir: Path
    summary: dict[str, Any]
    files: dict[str, Path]


def reference_from_config(cfg: OacliConfig) -> Trajectory:
    """The reference the config asks for: through its waypoints, or from its file."""
    ref = cfg.reference
    frame = cfg.environment.frame
    if ref.source == "file":
        if ref.file is None:  # the config validation requires a file for source: file
            raise InputError("reference.file: missing: required when reference.source is 'file'")
        return load_reference(Path(ref.file), sample_period_s=ref.sample_period_s, frame=frame)
    poses = cfg.reference_poses()
    return waypoint_reference(
        np.array([p.position for p in poses]),
        np.array([p.quaternion for p in poses]),
        cfg.robot_params(),
        speed_mps=ref.cruise_speed_mps,
        accel_mps2=ref.acceleration_mps2,
        rate_radps=ref.angular_rate_radps,
        ang_accel_radps2=ref.angular_acceleration_radps2,
        hold_s=ref.hold_s,
        frame=frame,
    )


def _describe_point(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in p) + ")"


def check_reference_in_workspace(reference: Trajectory, scene: Scene, log: list[LogEntry]) -> None:
    """Refuse a reference that starts or ends inside a keep-out zone or outside every keep-in box.

    A path that crosses a keep-out zone in between is logged as a warning (tracking it is allowed, e.g. to
    study a bad plan), and counted in the summary's constraint violations if the robot follows it.
    """
    for label, p in (("start", reference.x[0, 0:3]), ("end", reference.x[-1, 0:3])):
        for i, e in enumerate(scene.keep_out):
            if e.contains(p):
                raise InputError(
                    f"reference {label} {_describe_point(p)} is inside keep-out zone environment.keep_out.{i}"
                )
        if not scene.in_keep_in(p):
            raise InputError(
                f"reference {label} {_describe_point(p)} is outside every keep-in box (environment.keep_in)"
            )
    inside = scene.in_keep_out(reference.x[:, 0:3]) | ~scene.in_keep_in(reference.x[:, 0:3])
    if np.any(inside):
        k = int(np.argmax(inside))
        log.append((0.0, "warning", f"reference leaves the free space at t = {reference.t[k]:.2f} s"))


def _track_summary(
    cfg: OacliConfig, reference: Trajectory, tel: Telemetry, limits: TrackingLimits
) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    errors = tracking_errors(tel, reference)
    ctrl_errors = tracking_errors(tel, reference, tel.t_ctrl)
    safety = track_safety(cfg, tel, limits)
    violations = {kind: safety[kind]["count"] for kind in ("input", "velocity", "angular_velocity", "keep_in",
                                                          "keep_out")}
    summary = {
        "stage": "track",
        "status": "ok",  # set by assess_track once every entry is in
        "controller": cfg.controller.type,
        "reference": reference.name,
        "seed": cfg.seed,
        "rms_position_error_m": rms(errors.position_m),
        "max_position_error_m": float(errors.position_m.max()),
        "final_position_error_m": float(errors.position_m[-1]),
        "rms_attitude_error_rad": rms(errors.attitude_rad),
        "max_attitude_error_rad": float(errors.attitude_rad.max()),
        "final_attitude_error_rad": float(errors.attitude_rad[-1]),
        "constraint_violations": int(sum(violations.values())),
        "constraint_violations_by_kind": violations,
        "safety": safety,
        **controller_counts(tel),
        "control_steps": len(tel.t_ctrl),
        "solve_time_ms": percentiles_ms(np.array([i.solve_time_s for i in tel.solve_info])),
        "step_time_ms": percentiles_ms(np.array([i.step_time_s for i in tel.solve_info])),
        "sim_time_s": float(tel.t_true[-1]),
    }
    return summary, ctrl_errors.position_m, ctrl_errors.attitude_rad


def run_track(
    cfg: OacliConfig,
    *,
    reference: Trajectory | None = None,
    out: Path | None = None,
    runs_root: Path = Path("runs"),
    progress: Callable[[float], None] | None = None,
    strict_reference: bool = False,
) -> StageResult:
    """Run the ``track`` stage and write its run folder.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration (seed overrides already applied).
    reference : Trajectory, optional
        The reference to follow; built from ``cfg.reference`` when omitted.
    out : Path, optional
        Exact run folder (must not exist or be empty); otherwise ``runs_root/<name>-<UTC stamp>``.
    runs_root : Path
        Parent folder of automatically named runs.
    progress : callable, optional
        Called with the completed fraction of the simulation.
    strict_reference : bool
        Refuse (InputError) a reference the plant cannot follow within the robot's limits instead of warning
        (:func:`oacli.stages.design_limits.check_reference_for_plant`).

    Returns
    -------
    StageResult
    """
    wall_start = time.perf_counter()
    log: list[LogEntry] = []
    if reference is None:
        reference = reference_from_config(cfg)
    scene = cfg.scene()
    check_reference_in_workspace(reference, scene, log)
    reference_check = check_reference_for_plant(cfg, reference, log, strict=strict_reference)
    log.append((0.0, "info", f"reference {reference.name}: {len(reference)} samples, {reference.duration_s:.1f} s"))

    robot = cfg.robot
    limits = TrackingLimits(
        force_N=np.asarray(robot.force_limit_N),
        torque_Nm=np.asarray(robot.torque_limit_Nm),
        velocity_mps=np.asarray(robot.velocity_limit_mps),
        angular_velocity_radps=np.asarray(robot.angular_velocity_limit_radps),
    )
    weights_cfg = cfg.controller.weights
    weights = TrackingWeights(*(np.asarray(getattr(weights_cfg, f)) for f in
                                ("position", "velocity", "attitude", "angular_velocity", "force", "torque")))
    design = tube_design_from_config(cfg) if cfg.controller.type == "tube" else None
    controller: TrackingMPC | TubeMonitor
    if design is None:
        controller = TrackingMPC(
            reference, cfg.robot_params(), dt_s=cfg.controller.period_s, horizon=cfg.controller.horizon,
            weights=weights, limits=limits, max_consecutive_failures=cfg.controller.max_consecutive_failures,
            **workspace_arguments(cfg),
        )
    else:
        controller = monitored_tube_controller(cfg, reference, design, weights, limits)
        log.extend(describe_tube_design(design))
    x0 = reference.x[0].copy()
    x0[0:3] += np.asarray(cfg.simulation.initial_offset_m)
    sensors = SensorNoise(**cfg.sensors.model_dump())
    dist_cfg = cfg.truth.disturbance
    disturbance = Disturbance(dist_cfg.bias, dist_cfg.random_bound)

    config_yaml = dump_config(cfg)
    with open_stage_run("track", cfg.name, config_yaml, out=out, runs_root=runs_root, started=wall_start) as run:
        rng = np.random.default_rng(cfg.seed)
        tel = simulate(
            controller, x0, cfg.truth_params(),
            duration_s=reference.duration_s + cfg.simulation.settle_time_s,
            control_period_s=cfg.controller.period_s,
            plant_period_s=cfg.simulation.plant_period_s,
            input_limits=limits.input,
            sensors=sensors, disturbance=disturbance, rng=rng, progress=progress,
        )
        summary, pos_err_ctrl, att_err_ctrl = _track_summary(cfg, reference, tel, limits)
        summary["reference_check"] = reference_check.summary()
        monitor = controller if isinstance(controller, TubeMonitor) else None
        history = monitor.history() if monitor is not None else None
        findings = StatusReport()
        if monitor is not None and history is not None:
            summary.update(tube_summary(monitor, history, tel, cfg))
            add_tube_reasons(findings, summary)
            log.extend(describe_beyond_w(monitor))
            log.append((float(tel.t_true[-1]), "info" if summary["tube_violations"] == 0 else "warning",
                        f"tube: {summary['tube_violations']} steps outside the promised tube, "
                        f"{summary['w_violations']} beyond W, {summary['fallback_steps']} fallback steps, "
                        f"{summary['safe_hold_steps']} in safe hold"))
        assess_track(summary, findings).apply(summary)
        for t, info in zip(tel.t_ctrl, tel.solve_info, strict=True):
            if not info.success:
                log.append((float(t), "warning", f"controller step failed: {info.status}"))
        log.append((float(tel.t_true[-1]), "info",
                    f"done: rms position error {summary['rms_position_error_m']:.4f} m, "
                    f"{summary['solver_failures']} solver failures, "
                    f"{summary['constraint_violations']} constraint violations; status {summary['status']}"))
        log.extend(status_log(summary, float(tel.t_true[-1])))
        _write_track_mcap(run.file("mcap", "track.mcap"), cfg, config_yaml, reference, tel, scene, log, monitor,
                          history)
        write_track_recording(
            run.file("rrd", "track.rrd"), scene=scene, t_ref=reference.t, x_ref=reference.x,
            t_true=tel.t_true, x_true=tel.x_true,
            t_ctrl=tel.t_ctrl, u_command=tel.u_command, u_applied=tel.u_applied,
            position_error_m=pos_err_ctrl, attitude_error_rad=att_err_ctrl,
            solve_time_ms=1e3 * np.array([i.solve_time_s for i in tel.solve_info]),
            force_limit_N=limits.force_N, torque_limit_Nm=limits.torque_Nm, log=log,
            recording_name=f"{cfg.name}/track",
            extra=None if monitor is None or history is None else tube_layers(monitor, history),
            blueprint=None if design is None else tube_track_blueprint(),
        )
        run.finish(summary)
    return StageResult(run.run_dir, summary, run.files)


def _write_track_mcap(
    path: Path, cfg: OacliConfig, config_yaml: str, reference: Trajectory, tel: Telemetry, scene: Scene,
    log: list[LogEntry], monitor: TubeMonitor | None = None, history: TubeHistory | None = None,
) -> None:
    metadata = {"stage": "track", "seed": cfg.seed, "git_commit": git_commit(), "version": __version__,
                "config_name": cfg.name}
    u_true = tel.u_applied[np.clip(np.searchsorted(tel.t_ctrl, tel.t_true, side="right") - 1, 0, None)]
    with StageMcapWriter(path, stage="track", config_yaml=config_yaml, metadata=metadata,
                         frame=cfg.environment.frame) as writer:
        writer.write_scene(scene, {"reference": reference.x[:, 0:3], "actual": tel.x_true[:, 0:3]})
        writer.write_states("/reference", tel.t_ctrl, tel.x_reference, sample_inputs(reference, tel.t_ctrl))
        writer.write_states("/state/true", tel.t_true, tel.x_true, u_true)
        writer.write_states("/state/measured", tel.t_ctrl, tel.x_measured, tel.u_command)
        writer.write_wrenches("/control/command", tel.t_ctrl, tel.u_command)
        writer.write_wrenches("/control/applied", tel.t_ctrl, tel.u_applied)
        if tel.disturbance is not None:  # always set once the Telemetry is built (zeros when none)
            writer.write_wrenches("/disturbance", tel.t_ctrl, tel.disturbance)
        writer.write_solver_stats(tel.t_ctrl, tel.solve_info)
        if monitor is not None and history is not None:
            write_tube_topics(writer, tel, monitor, history)
        writer.write_poses(tel.t_true, tel.x_true)
        for t, level, message in log:
            writer.write_log(t, level, message)
