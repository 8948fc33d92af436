"""The ``track`` stage: follow a reference with MPC in closed loop and record everything.

Inputs: the config (robot model, truth plant, sensors, controller, scene) and a reference (from the config's
waypoints or file, or a file / previous stage's MCAP given on the command line). Outputs in the run folder:
``config.yaml`` (resolved, written first), ``track.mcap``, ``track.rrd`` and ``summary.json`` (written last).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.config.sizes import check_simulation_length
from oacli.control.rigid_terms import RigidCompensator
from oacli.control.tracking import TrackingMPC
from oacli.control.tube_monitor import TubeMonitor
from oacli.control.tube_mpc import TubeHistory
from oacli.errors import InputError
from oacli.geometry import Scene
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.plots.track import write_track_plots
from oacli.io.reference_files import load_reference
from oacli.io.rerun.track import write_track_recording
from oacli.io.rerun.tube import tube_track_blueprint
from oacli.io.runfolder import StageResult
from oacli.metrics import TrackingErrors, percentiles_ms, rms, tracking_errors
from oacli.model.limits import MotionLimits
from oacli.phases import set_phase
from oacli.reference import waypoint_reference
from oacli.reference_limits import ReferenceLimitCheck, check_reference_limits
from oacli.signals import held
from oacli.sim.simulator import simulate
from oacli.sim.stall import with_stall
from oacli.stages.faults import fault_arguments
from oacli.stages.flown_sensors import FlownSensors, flown_sensors, write_flown_sensor_topics
from oacli.stages.settings import (
    controller_limits,
    open_run,
    plant_disturbance,
    robot_model,
    sensor_noise,
    tracking_weights,
    truth_model,
    tube_design_from_config,
)
from oacli.stages.track_journal import TrackJournal
from oacli.stages.track_rigid import com_clip_finding, controller_force_limit_N, rigid_body_entries
from oacli.stages.track_status import assess_track, controller_counts, track_safety
from oacli.stages.track_tube import (
    add_tube_reasons,
    describe_beyond_w,
    describe_tube_design,
    monitored_tube_controller,
    standard_mpc_arguments,
    tube_layers,
    tube_summary,
    write_tube_topics,
)
from oacli.status import StatusReport, status_log
from oacli.trajectory import sample_inputs
from oacli.types import Telemetry, Trajectory

LogEntry = tuple[float, str, str]


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


def check_reference_fits(cfg: OacliConfig, reference: Trajectory) -> None:
    """Refuse a reference in another frame than ``environment.frame`` (as ``smooth`` does), or one so long that
    simulating it would take more than :data:`oacli.config.sizes.MAX_SIMULATION_STEPS` plant steps."""
    if reference.frame != cfg.environment.frame:
        raise InputError(f"reference {reference.name}: in frame {reference.frame!r}, the config's "
                         f"environment.frame is {cfg.environment.frame!r}")
    problem = check_simulation_length(reference.duration_s + cfg.simulation.settle_time_s,
                                      cfg.simulation.plant_rate_hz, f"reference {reference.name}")
    if problem is not None:
        raise InputError(f"{problem} (with simulation.settle_time_s)")


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


def check_reference_for_plant(cfg: OacliConfig, reference: Trajectory, log: list[LogEntry], *,
                              strict: bool = False) -> ReferenceLimitCheck:
    """Check a reference against the simulated plant ``truth`` (mass, inertia, disturbance) and ``robot``'s limits.

    A reference beyond a limit adds a warning to ``log`` (at the first time a limit is exceeded), or, with
    ``strict``, is refused.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    reference : Trajectory
        The reference to follow.
    log : list of (float, str, str)
        The stage's log (a warning is appended).
    strict : bool
        Refuse instead of warning.

    Returns
    -------
    ReferenceLimitCheck
        The inputs and rates the plant needs, per quantity, against the robot's limits.

    Raises
    ------
    InputError
        With ``strict``, when the plant cannot follow the reference within the limits (naming the quantity, the
        time and both values).
    """
    check = check_reference_limits(reference, cfg.truth_params(), robot_model(cfg).limits,
                                   disturbance_bias=np.asarray(cfg.truth.disturbance.bias),
                                   disturbance_bound=np.asarray(cfg.truth.disturbance.random_bound))
    if not check.ok:
        if strict:
            raise InputError(f"{check.message()} (robot limits, truth plant); refused by --strict")
        first = min(t for q in check.exceeded if (t := check.checks[q].first_exceeded_t_s) is not None)
        log.append((float(first), "warning", check.message()))
    return check


def _track_summary(
    cfg: OacliConfig, reference: Trajectory, tel: Telemetry, limits: MotionLimits
) -> tuple[dict[str, Any], TrackingErrors]:
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
    return summary, ctrl_errors


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
        (:func:`check_reference_for_plant`).

    Returns
    -------
    StageResult
    """
    wall_start = time.perf_counter()
    log: list[LogEntry] = []
    if reference is None:
        reference = reference_from_config(cfg)
    scene = cfg.scene()
    check_reference_fits(cfg, reference)
    check_reference_in_workspace(reference, scene, log)
    reference_check = check_reference_for_plant(cfg, reference, log, strict=strict_reference)
    log.append((0.0, "info", f"reference {reference.name}: {len(reference)} samples, {reference.duration_s:.1f} s"))

    model, plant = robot_model(cfg), truth_model(cfg)
    limits = model.limits  # the plant's saturation and the safety check
    ctrl_limits = controller_limits(cfg, model)  # the controllers': the rate margin (controller.rate_margin)
    weights = tracking_weights(cfg)
    design = tube_design_from_config(cfg, model=model) if cfg.controller.type == "tube" else None
    controller: TrackingMPC | TubeMonitor
    if design is None:
        controller = TrackingMPC(
            reference, model.params, dt_s=cfg.controller.period_s, horizon=cfg.controller.horizon,
            weights=weights, limits=ctrl_limits, max_consecutive_failures=cfg.controller.max_consecutive_failures,
            rigid=RigidCompensator.of_model(model, controller_force_limit_N(ctrl_limits, None), ctrl_limits.torque_Nm),
            **standard_mpc_arguments(cfg),
        )
    else:
        controller = monitored_tube_controller(cfg, reference, design, weights, ctrl_limits, model=model)
        log.extend(describe_tube_design(design))
    x0 = reference.x[0].copy()
    x0[0:3] += np.asarray(cfg.simulation.initial_offset_m)
    sensors, disturbance = sensor_noise(cfg), plant_disturbance(cfg)

    with open_run("track", cfg, out=out, runs_root=runs_root, started=wall_start) as run:
        # The per-step topics go to the MCAP while the simulation runs (a killed run leaves a readable file);
        # the complete file is written at the end and then replaces the journal (oacli.stages.track_journal).
        with TrackJournal(run.open_mcap(), reference, run=run) as journal:
            rng = np.random.default_rng(cfg.seed)
            set_phase(progress, "closed-loop simulation")
            tel = simulate(
                with_stall(controller, cfg.faults.controller_stall.start_s, cfg.faults.controller_stall.duration_s),
                x0, plant.params,
                duration_s=reference.duration_s + cfg.simulation.settle_time_s,
                control_period_s=cfg.controller.period_s,
                plant_period_s=cfg.simulation.plant_period_s,
                input_limits=limits.input,
                sensors=sensors, disturbance=disturbance, rng=rng, progress=progress,
                actuator_scale=np.asarray(cfg.truth.actuator_scale), com_offset_m=np.asarray(cfg.truth.com_offset_m),
                on_step=journal.on_step, **fault_arguments(cfg, limits.input),
            )
            journal.flush(final=True)
            summary, ctrl_errors = _track_summary(cfg, reference, tel, limits)
            flown = flown_sensors(cfg, tel)
            if flown is not None:
                summary["sensors"] = flown.summary()
            summary["reference_check"] = reference_check.summary()
            summary.update(rigid_body_entries(cfg, model, controller, ctrl_limits, design))
            findings = StatusReport()
            clipped = com_clip_finding(summary)
            if clipped is not None:
                findings.degraded("com_clipped", clipped)
                log.append((float(tel.t_true[-1]), "warning", clipped))
            monitor = controller if isinstance(controller, TubeMonitor) else None
            history = monitor.history() if monitor is not None else None
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
            # The journal stays the record until the complete file is in place (TrackJournal.replaced_by): a
            # signal at any moment leaves one or the other, and the interrupted summary says which.
            with journal.replaced_by(run.open_mcap()) as writer:
                writer.reuse_encoded(journal.encoded)  # the rows the journal wrote are encoded once
                write_track_topics(writer, reference, tel, scene, log, monitor, history, flown)
            write_track_recording(
                run.file("rrd", "track.rrd"), scene=scene, reference=reference, telemetry=tel, errors=ctrl_errors,
                limits=limits, log=log, recording_name=f"{cfg.name}/track",
                extra=None if monitor is None or history is None else tube_layers(monitor, history),
                blueprint=None if design is None else tube_track_blueprint, controller=cfg.controller.type,
            )
            if cfg.outputs.plots:  # held: matplotlib turns an interruption inside its drawing into an error
                with held():  # (a lost signal, a missing PNG); it is raised once the figures are written
                    write_track_plots(run, summary, telemetry=tel, reference=reference, limits=limits, scene=scene,
                                      robot_radius_m=float(robot_model(cfg).radius_m))
            return run.finish(summary)


def write_track_topics(
    writer: StageMcapWriter, reference: Trajectory, tel: Telemetry, scene: Scene, log: list[LogEntry],
    monitor: TubeMonitor | None = None, history: TubeHistory | None = None, flown: FlownSensors | None = None,
) -> None:
    """Write a tracking run's topics to its MCAP (``docs/mcap.md``; the tube's with a tube controller).

    Parameters
    ----------
    writer : StageMcapWriter
        The open writer.
    reference : Trajectory
        The reference followed.
    tel : Telemetry
        The run.
    scene : Scene
        The workspace.
    log : list of (float, str, str)
        The stage's log.
    monitor : TubeMonitor, optional
        The tube controller (with ``history``).
    history : TubeHistory, optional
        What the tube controller did at each step.
    flown : FlownSensors, optional
        The flight-like IMU and localisation streams (``/imu``, ``/localisation``).
    """
    u_true = tel.u_applied[np.clip(np.searchsorted(tel.t_ctrl, tel.t_true, side="right") - 1, 0, None)]
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
    if flown is not None:
        write_flown_sensor_topics(writer, flown)
    writer.write_poses(tel.t_true, tel.x_true)
    writer.write_robot_body(tel.t_true, tel.x_true)
    for t, level, message in log:
        writer.write_log(t, level, message)
