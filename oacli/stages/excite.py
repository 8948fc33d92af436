"""The ``excite`` stage: an information-rich trajectory from the config's start to its goal.

Two methods (``excitation.method`` or ``--method``):

* ``offline``: the A/D/E-optimal design of Doerr et al. 2021 (Eq. 30) by sequential convex programming
  (:mod:`oacli.excitation.design`). Each SCP iteration is journaled to the MCAP as it is produced
  (:mod:`oacli.stages.excite_journal`); the run folder is created by the first iteration, so a problem found
  infeasible before the SCP starts (exit 3) leaves no folder behind, and a design that fails its final check
  (exit 3) leaves the journal as ``excite.mcap`` next to a ``failed`` summary.
* ``rattle``: RATTLE's online information-aware planner in closed loop with the simulated plant (the config's
  ``truth``) and the sequential estimator of :mod:`oacli.estimation` (``excitation.rattle.estimator:
  sequential``, configured by the ``estimation`` section), or the Cramér-Rao oracle
  (:class:`oacli.excitation.oracle.CramerRaoOracle`, ``oracle``), named so in every output. Each control step is
  journaled to the MCAP as it is produced (:class:`oacli.stages.excite_journal.RattleJournal`).

Ctrl-C or a termination signal (SIGTERM, SIGHUP) keeps the journal of either method as ``excite.mcap`` (valid, the
computation so far) next to an ``interrupted`` ``summary.json`` (exit 130 / 143).

Both design within the limits of :func:`oacli.stages.design_limits.excitation_design_limits`: the robot's with
``excitation.margin`` (the force also × m_prior/m_upper, [Doerr2021] Eq. 28), capped by ``excitation.limits`` (RATTLE:
``excitation.rattle.limits`` over them); a cap above the robot's is refused (exit 2) or clipped with a warning. In
RATTLE's closed loop the feedback may use the actuator's full limits; RATTLE plans its rates and a rate governor
keeps the measured body rate within the tracking controller's (``controller.rate_margin``,
:mod:`oacli.stages.rattle_rates`). ``summary.json`` records the limits used (``design_limits``).

Outputs in the run folder: ``config.yaml`` (first), ``excite.mcap`` (``/trajectory`` as ``oacli.TrajectorySample``
at the design's sample period, the criterion per SCP iteration, the information over time, the scene),
``excite.rrd`` and ``summary.json`` (last).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.config.models import Pose
from oacli.errors import ConfigError, InfeasibleError, InputError
from oacli.estimation.online import OnlineSequentialEstimator
from oacli.estimation.sequential import SequentialEstimator
from oacli.excitation.design import ExcitationDesign, ExcitationProblem, design_excitation
from oacli.excitation.design_types import FullDesignSpec
from oacli.excitation.fim_gradient import criterion_value, scaling_matrix
from oacli.excitation.information import PARAM_NAMES, MeasurementModel, cramer_rao_std
from oacli.excitation.information_full import ideal_theta, information_summary
from oacli.excitation.oracle import CramerRaoOracle
from oacli.excitation.rattle import InformationAwarePlanner
from oacli.excitation.rattle_loop import RattleRun, run_rattle
from oacli.geometry import Scene
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.plots.excite import gathered_information, write_excite_plots
from oacli.io.rerun.excite import InformationSeries, RattleSteps, ScpSteps, write_excite_recording
from oacli.io.runfolder import StageResult, StageRun
from oacli.metrics import percentiles_ms, safety_block, safety_report
from oacli.phases import set_phase
from oacli.reference_limits import DesignLimits
from oacli.stages.design_limits import design_limit_log, excitation_design_limits, to_motion_limits
from oacli.stages.estimate_rigid import batch_model
from oacli.stages.excite_journal import ExciteJournal, RattleJournal
from oacli.stages.rattle_goal import goal_reasons, goal_tolerance, plan_goal_residual
from oacli.stages.rattle_rates import rattle_governor_limit, rattle_planner_limits
from oacli.stages.settings import (
    estimator_settings,
    excitation_prior_model,
    excitation_prior_std_full,
    full_information_term,
    information_weighting,
    measurement_model,
    open_run,
    plant_disturbance,
    rattle_planner_weights,
    robot_model,
    scp_settings,
    sensor_noise,
    terminal_tolerance,
    truth_model,
)
from oacli.status import StatusReport, add_safety_reasons, status_log
from oacli.trajectory import sample_states
from oacli.types import ParameterEstimate, Trajectory

LogEntry = tuple[float, str, str]

# ----------------------------------------------------------------------------------------------------------------
# Config -> problem
# ----------------------------------------------------------------------------------------------------------------


def _resolve_pose(cfg: OacliConfig, ref: str | Pose | None, field: str) -> Pose:
    if ref is None:
        raise ConfigError(f"excitation.{field}: <missing>: required by `oacli excite` (a waypoint name or a pose)")
    if isinstance(ref, str):
        if ref not in cfg.waypoints:
            defined = ", ".join(sorted(cfg.waypoints)) or "none"
            raise ConfigError(
                f"excitation.{field}: {ref!r}: unknown waypoint name (defined in waypoints: {defined})"
            )
        return cfg.waypoints[ref]
    return ref


def _describe(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in p) + ")"


def check_pose_in_workspace(label: str, position: np.ndarray, scene: Scene) -> None:
    """Refuse a start or goal inside a keep-out zone or outside every keep-in box (InputError naming both)."""
    for i, ellipsoid in enumerate(scene.keep_out):
        if ellipsoid.contains(position):
            raise InputError(
                f"excitation.{label} {_describe(position)} is inside keep-out zone environment.keep_out.{i}"
            )
    if not scene.in_keep_in(position):
        raise InputError(f"excitation.{label} {_describe(position)} is outside every keep-in box (environment.keep_in)")


def excitation_problem(cfg: OacliConfig, limits: DesignLimits | None = None) -> ExcitationProblem:
    """The offline design problem the config describes (start and goal checked against the workspace), within
    ``limits`` (default: :func:`~oacli.stages.design_limits.excitation_design_limits`)."""
    exc = cfg.excitation
    if limits is None:
        limits = excitation_design_limits(cfg)
    start = _resolve_pose(cfg, exc.start, "start").state()
    goal = _resolve_pose(cfg, exc.goal, "goal").state()
    scene = cfg.scene()
    check_pose_in_workspace("start", start[0:3], scene)
    check_pose_in_workspace("goal", goal[0:3], scene)
    prior_model = excitation_prior_model(cfg)
    theta = np.array(prior_model.theta)
    prior_info = np.linalg.inv(prior_model.covariance) if exc.use_prior_information else None
    spec = None
    if not exc.information.is_legacy and exc.method == "offline":
        if exc.criterion != "A":
            raise ConfigError(f"excitation.information.parameters: the full rigid body's design has the A-criterion "
                              f"only (excitation.criterion is {exc.criterion})")
        spec = FullDesignSpec(tuple(exc.information.parameters), ideal_theta(theta, cfg.estimation.rigid_body.mean()),
                              excitation_prior_std_full(cfg), exc.information.scaling)
    return ExcitationProblem(
        start=start,
        goal=goal,
        duration_s=exc.duration_s,
        steps=exc.steps,
        theta=theta,
        measurement=measurement_model(cfg),
        limits=to_motion_limits(limits),
        scene=scene,
        criterion=exc.criterion,
        scaling=exc.parameter_scaling,
        prior_information=prior_info,
        clearance_m=exc.clearance_m,
        terminal=terminal_tolerance(cfg),
        information=spec,
    )


def _information_full_block(cfg: OacliConfig, x0: np.ndarray, u: np.ndarray, theta4: np.ndarray, dt: float,
                            measurement: MeasurementModel) -> dict[str, Any] | None:
    """The scaled A-criterion and CRB of ``excitation.information.parameters`` along a trajectory (None for the
    default, mass and inertia: the summary's criterion and crb_std already say it)."""
    info = cfg.excitation.information
    if info.is_legacy:
        return None
    theta = ideal_theta(theta4, cfg.estimation.rigid_body.mean())
    block = information_summary(x0, u, theta, dt, measurement, tuple(info.parameters),
                                excitation_prior_std_full(cfg), info.scaling)
    block["designed_for"] = ("the informed entries (RATTLE's information term)" if cfg.excitation.method == "rattle"
                             else "the informed entries (the SCP's criterion: criterion_initial/final)")
    return block


def _named(values: np.ndarray) -> dict[str, float]:
    return {name: float(v) for name, v in zip(PARAM_NAMES, values, strict=True)}


def within_design_limits(x: np.ndarray, u: np.ndarray, limits: DesignLimits) -> bool:
    """Every input, velocity and angular rate of a design within the design limits (relative tolerance 1e-9)."""
    lim = limits.limits
    tol = 1 + 1e-9
    return bool(np.all(np.abs(u[:, 0:3]) <= lim.force_N * tol) and np.all(np.abs(u[:, 3:6]) <= lim.torque_Nm * tol)
                and np.all(np.abs(x[:, 3:6]) <= lim.velocity_mps * tol)
                and np.all(np.abs(x[:, 10:13]) <= lim.angular_velocity_radps * tol))


def check_design(design: ExcitationDesign, problem: ExcitationProblem) -> None:
    """Raise InfeasibleError when the design breaks the workspace, a limit or misses the goal."""
    problems = []
    if not design.collision_free:
        problems.append("the design leaves the keep-in boxes or enters a keep-out zone (dense re-check)")
    x = design.trajectory.x
    lim = problem.limits
    over_v = float(np.max(np.abs(x[:, 3:6]) / lim.velocity_mps))
    over_w = float(np.max(np.abs(x[:, 10:13]) / lim.angular_velocity_radps))
    if over_v > 1.001 or over_w > 1.001:
        problems.append(
            f"the design exceeds the velocity or angular-velocity limit (peak {over_v:.4g} and {over_w:.4g} × limit)"
        )
    tol = problem.terminal
    res = design.terminal_residual
    for key, bound in (("position_m", tol.position_m), ("velocity_mps", tol.velocity_mps),
                       ("attitude_rad", tol.attitude_rad), ("angular_velocity_radps", tol.angular_velocity_radps)):
        if res[key] > bound * 1.001:
            problems.append(
                f"the design ends {res[key]:.3g} ({key}) from the goal at rest, more than the tolerance {bound:.3g} "
                f"(excitation.terminal_tolerance); more iterations (excitation.scp.max_iterations) may help"
            )
    if problems:
        raise InfeasibleError([f"no feasible excitation found: {p}" for p in problems])


# ----------------------------------------------------------------------------------------------------------------
# The stage
# ----------------------------------------------------------------------------------------------------------------


def run_excite(
    cfg: OacliConfig,
    *,
    method: str | None = None,
    out: Path | None = None,
    runs_root: Path = Path("runs"),
    progress: Callable[[float], None] | None = None,
) -> StageResult:
    """Run the ``excite`` stage and write its run folder.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration (seed overrides applied).
    method : {"offline", "rattle"}, optional
        Overrides ``excitation.method``.
    out, runs_root, progress
        As for :func:`oacli.stages.track.run_track`.

    Returns
    -------
    StageResult
    """
    method = method or cfg.excitation.method
    if method not in ("offline", "rattle"):
        raise ConfigError(f"--method: {method!r}: must be 'offline' or 'rattle'")
    # recorded in the run's config.yaml, so `oacli excite RUN/config.yaml` reruns the same method
    cfg = cfg.model_copy(update={"excitation": cfg.excitation.model_copy(update={"method": method})})
    if method == "offline":
        return _run_offline(cfg, out=out, runs_root=runs_root, progress=progress)
    return _run_rattle(cfg, out=out, runs_root=runs_root, progress=progress)


def _information_records(writer: StageMcapWriter, t: np.ndarray, info: np.ndarray, theta: np.ndarray) -> np.ndarray:
    crb = np.array([cramer_rao_std(f, theta) if np.any(f) else np.full(4, np.inf) for f in info])
    for tk, fk, ck in zip(t, info, crb, strict=True):
        writer.write_json(ms.TOPIC_EXCITATION_INFORMATION, ms.INFORMATION, ms.INFORMATION_SCHEMA, float(tk),
                          {"parameters": list(PARAM_NAMES), "information": fk, "crb_std": ck})
    return crb


def _run_offline(cfg: OacliConfig, *, out: Path | None, runs_root: Path,
                 progress: Callable[[float], None] | None) -> StageResult:
    wall = time.perf_counter()
    limits = excitation_design_limits(cfg)
    problem = excitation_problem(cfg, limits)
    with contextlib.ExitStack() as folder:
        runs: list[StageRun] = []

        def stage_run() -> StageRun:  # the run folder, created by the journal's first record (or at the end)
            if not runs:
                runs.append(folder.enter_context(open_run("excite", cfg, out=out, runs_root=runs_root, started=wall)))
            return runs[0]

        # Each SCP iteration goes to the MCAP as it is produced (oacli.stages.excite_journal); the complete file
        # replaces the journal at the end. A design that fails its final check leaves the journal as excite.mcap.
        with ExciteJournal(lambda: stage_run().open_mcap(method="offline")) as journal:
            design = design_excitation(problem, scp_settings(cfg), progress=progress,
                                       rng=np.random.default_rng(cfg.seed), on_iteration=journal.on_iteration)
            try:
                check_design(design, problem)
            except InfeasibleError:
                journal.commit()
                raise
            # The journal stays the record until the complete file is in place (StageJournal.replaced_by).
            return _offline_outputs(cfg, problem, limits, design, stage_run(), journal)


def _offline_outputs(cfg: OacliConfig, problem: ExcitationProblem, limits: DesignLimits, design: ExcitationDesign,
                     run: StageRun, journal: ExciteJournal | None = None) -> StageResult:
    """Summary, MCAP, recording and plots of an offline design in its run folder (the MCAP replaces ``journal``)."""
    log: list[LogEntry] = [
        (0.0, "info", f"excitation design: {problem.steps} steps of {problem.dt:.4g} s, criterion {problem.criterion} "
                      f"({problem.scaling}), {len(design.iterations)} SCP iterations ({design.accepted_iterations} "
                      f"accepted), stop: {design.stop_reason}"),
        (0.0, "info", f"criterion {design.criterion_initial:.6g} -> {design.criterion_final:.6g}"),
        *design_limit_log(limits),
    ]
    traj = design.trajectory
    x, u = traj.x, traj.u
    summary = {
        "stage": "excite",
        "status": "ok",
        "method": "offline",
        "criterion": problem.criterion,
        "parameter_scaling": problem.scaling,
        "seed": cfg.seed,
        "criterion_initial": design.criterion_initial,
        "criterion_final": design.criterion_final,
        "criterion_ratio": design.criterion_final / design.criterion_initial if problem.criterion == "A" else None,
        "iterations": len(design.iterations),
        "accepted_iterations": design.accepted_iterations,
        "stop_reason": design.stop_reason,
        "solve_time_s": design.solve_time_s,
        "max_force_N": float(np.max(np.abs(u[:, 0:3]))),
        "max_torque_Nm": float(np.max(np.abs(u[:, 3:6]))),
        "max_speed_mps": float(np.max(np.abs(x[:, 3:6]))),
        "max_angular_velocity_radps": float(np.max(np.abs(x[:, 10:13]))),
        "design_limits": limits.summary(),
        "within_design_limits": within_design_limits(x, u, limits),
        "collision_free": bool(design.collision_free),
        "crb_std": _named(design.crb_std),
        "crb_std_pct": _named(100.0 * design.crb_std / problem.theta),
        "goal_residual": design.terminal_residual,
        "theta_design": _named(problem.theta),
        "duration_s": problem.duration_s,
        "steps": problem.steps,
        "dt_s": problem.dt,
    }
    block = _information_full_block(cfg, problem.start, u[:problem.steps], problem.theta, problem.dt,
                                    problem.measurement)
    if block is not None:
        summary["information_full"] = block
    offline_findings(summary, problem).apply(summary)
    log.extend(status_log(summary))
    mcap = run.open_mcap(method="offline")
    with mcap if journal is None else journal.replaced_by(mcap) as writer:
        crb = write_offline_topics(writer, problem, design, log, cfg.environment.frame)
    scp = ScpSteps(np.array([it.criterion for it in design.iterations]),
                   np.array([it.candidate_criterion for it in design.iterations]), design.initial.x[:, 0:3])
    write_excite_recording(
        run.file("rrd", "excite.rrd"), scene=problem.scene, trajectory=traj,
        information=InformationSeries(problem.theta, design.information_over_time, crb), limits=problem.limits,
        scp=scp, log=log, recording_name=f"{cfg.name}/excite",
    )
    if cfg.outputs.plots:
        write_excite_plots(run, summary, t_info_s=traj.t, information=design.information_over_time,
                           t_input_s=traj.t, u=traj.u, force_limit_N=problem.limits.force_N,
                           torque_limit_Nm=problem.limits.torque_Nm)
    return run.finish(summary)


def write_offline_topics(writer: StageMcapWriter, problem: ExcitationProblem, design: ExcitationDesign,
                         log: list[LogEntry], frame: str) -> np.ndarray:
    """Write the offline design's topics (module docstring) to its MCAP.

    Parameters
    ----------
    writer : StageMcapWriter
        The open writer.
    problem : ExcitationProblem
        The design problem.
    design : ExcitationDesign
        Its solution and the SCP's record.
    log : list of (float, str, str)
        The stage's log.
    frame : str
        The world frame's name.

    Returns
    -------
    ndarray, shape (N, 4)
        The Cramér-Rao standard deviation at each sample of the design (``inf`` where unidentifiable).
    """
    traj = design.trajectory
    x, u = traj.x, traj.u
    writer.write_scene(problem.scene, {"excitation": x[:, 0:3], "initial_guess": design.initial.x[:, 0:3]})
    writer.write_trajectory("/trajectory", Trajectory(traj.t, x, u, name="excitation", frame=frame))
    writer.write_poses(traj.t, x)
    writer.write_robot_body(traj.t, x)
    for it in design.iterations:
        writer.write_json(ms.TOPIC_EXCITATION_ITERATIONS, ms.SCP_ITERATION, ms.SCP_ITERATION_SCHEMA, 0.0, {
            "iteration": it.iteration, "criterion": it.criterion, "merit": it.merit,
            "violation": it.violation, "candidate_criterion": it.candidate_criterion,
            "candidate_merit": it.candidate_merit, "predicted_merit": it.predicted_merit,
            "ratio": it.ratio, "trust_region_force": it.trust_region_force,
            "trust_region_torque": it.trust_region_torque, "accepted": it.accepted, "status": it.status,
            "solve_time_ms": 1e3 * it.solve_time_s,
        })
    crb = _information_records(writer, traj.t, design.information_over_time, problem.theta)
    for t, level, message in log:
        writer.write_log(t, level, message)
    return crb


def _run_rattle(cfg: OacliConfig, *, out: Path | None, runs_root: Path,
                progress: Callable[[float], None] | None) -> StageResult:
    wall = time.perf_counter()
    exc = cfg.excitation
    rcfg = exc.rattle
    if not exc.information.is_legacy:  # an informed entry's σ must fall in the loop, else its weight never decays
        missing = sorted(set(exc.information.parameters) - set(cfg.estimation.parameters))
        if rcfg.estimator == "oracle" or missing:
            raise ConfigError("excitation.information.parameters: RATTLE informs only entries its filter estimates ("
                              + ("the oracle knows mass and inertia only" if rcfg.estimator == "oracle"
                                 else f"{', '.join(missing)} not in estimation.parameters") + ")")
    design_lim = excitation_design_limits(cfg, rattle=True)
    problem = excitation_problem(cfg, design_lim)  # start, goal, workspace checks, measurement model
    limits = rattle_planner_limits(cfg, to_motion_limits(design_lim))  # within the controller's rate margin
    actuator = robot_model(cfg).input_limits  # the plant's actuators: the feedback may use what the plan leaves
    planner = InformationAwarePlanner(
        problem.goal, horizon=rcfg.horizon, dt_s=rcfg.step_s, limits=limits, measurement=problem.measurement,
        scene=problem.scene, weights=rattle_planner_weights(cfg),
        iterations=rcfg.iterations, penalty=rcfg.penalty, clearance_m=exc.clearance_m,
        stop_speed_fraction=rcfg.stop_speed_fraction, information=full_information_term(cfg, limits.input),
    )
    weighting = information_weighting(cfg)
    prior_model, plant = excitation_prior_model(cfg), truth_model(cfg)
    prior_cov = np.array(prior_model.covariance)
    truth = plant.params
    theta_true = np.array(plant.theta)
    if rcfg.estimator == "oracle":
        estimator: CramerRaoOracle | OnlineSequentialEstimator = CramerRaoOracle(
            theta_true, prior_cov, problem.measurement, problem.start
        )
    else:
        prior = ParameterEstimate(0.0, prior_model.theta, prior_cov, "prior")
        # With the full θ informed, the filter estimates estimation.parameters' full rigid body, so that the σ of
        # the informed entries it estimates fall (and their weights decay) as the run goes.
        full_model = None if exc.information.is_legacy else batch_model(cfg, prior)
        estimator = OnlineSequentialEstimator(SequentialEstimator(estimator_settings(cfg), prior, model=full_model))
    cw = cfg.controller.weights

    with (open_run("excite", cfg, out=out, runs_root=runs_root, started=wall) as stage_run,
          RattleJournal(lambda: stage_run.open_mcap(method="rattle")) as journal):
        set_phase(progress, "RATTLE closed loop")
        # Each control step goes to the MCAP as it is produced (oacli.stages.excite_journal); the complete file
        # replaces the journal at the end (an interrupted run keeps it as excite.mcap).
        run = run_rattle(
            planner, estimator, weighting, problem.start, truth,
            duration_s=rcfg.duration_s, replan_period_s=rcfg.replan_period_s,
            control_period_s=cfg.controller.period_s, plant_period_s=cfg.simulation.plant_period_s,
            input_limits=actuator, feedback_q=cw.state_weights(), feedback_r=cw.input_weights(),
            sensors=sensor_noise(cfg), disturbance=plant_disturbance(cfg),
            rng=np.random.default_rng(cfg.seed), progress=progress,
            rate_limit_radps=rattle_governor_limit(cfg),
            actuator_scale=np.asarray(cfg.truth.actuator_scale), com_offset_m=np.asarray(cfg.truth.com_offset_m),
            on_step=journal.on_step, terminal_hold_s=rcfg.terminal_hold_s,
        )
        journal.flush()
        summary, traj, log = _rattle_summary(cfg, problem, design_lim, run, prior_cov, theta_true)
        # the journal stays the record until the complete file is in place (StageJournal.replaced_by)
        _write_rattle_outputs(stage_run, cfg, problem, run, traj, log, prior_cov, theta_true, journal)
        t_info, info = gathered_information(run.estimates, prior_cov)
        robot_lim = robot_model(cfg).limits
        if cfg.outputs.plots:
            write_excite_plots(stage_run, summary, t_info_s=t_info, information=info,
                               t_input_s=run.telemetry.t_ctrl, u=run.telemetry.u_applied,
                               force_limit_N=limits.force_N, torque_limit_Nm=limits.torque_Nm,
                               actuator=(robot_lim.force_N, robot_lim.torque_Nm))
        return stage_run.finish(summary)


def _flown_trajectory(run: RattleRun, frame: str) -> Trajectory:
    """The true states at the control instants with the inputs applied from each (plus the final state)."""
    tel = run.telemetry
    truth = Trajectory(tel.t_true, tel.x_true, np.zeros((len(tel.t_true), 6)))
    t = np.append(tel.t_ctrl, tel.t_true[-1])
    x = sample_states(truth, t)
    u = np.vstack([tel.u_applied, np.zeros((1, 6))])
    return Trajectory(t, x, u, name="rattle_flown", frame=frame)


def _flown_crb(tel, theta_true: np.ndarray, prior_cov: np.ndarray, measurement: MeasurementModel) -> np.ndarray:
    """Cramér-Rao bound (with the prior) of the measurements the loop took, excitation measurement model."""
    oracle = CramerRaoOracle(theta_true, prior_cov, measurement, tel.x_measured[0])
    for k in range(1, len(tel.t_ctrl)):
        oracle.update(float(tel.t_ctrl[k]), tel.x_measured[k], tel.u_applied[k - 1])
    return oracle.estimate.std


def _rattle_summary(cfg, problem, design_lim: DesignLimits, run: RattleRun, prior_cov, theta_true):
    exc = cfg.excitation
    d = scaling_matrix(theta_true, exc.parameter_scaling)
    prior_info = np.linalg.inv(prior_cov)
    final = run.final_estimate
    posterior_info = np.linalg.inv(final.covariance)
    tel = run.telemetry
    traj = _flown_trajectory(run, cfg.environment.frame)
    scene = problem.scene
    inside = scene.in_keep_in(tel.x_true[:, 0:3]) & ~scene.in_keep_out(tel.x_true[:, 0:3])
    goal = problem.goal
    solve = np.array([r.plan.solve_time_s for r in run.replans])
    log: list[LogEntry] = [(r.t, "info", f"replan: std {np.array2string(r.std, precision=4)}, gamma "
                            f"{np.array2string(r.gamma, precision=3)}, {r.plan.accepted}/{r.plan.iterations} steps "
                            f"kept, {1e3 * r.plan.solve_time_s:.0f} ms") for r in run.replans]
    what = ("Cramér-Rao covariance around the true parameters; not a real estimator" if final.method == "oracle-crb"
            else "error-state EKF with χ² gating")
    crb = final.std if final.method == "oracle-crb" else _flown_crb(tel, theta_true, prior_cov, problem.measurement)
    log.insert(0, (0.0, "info", f"RATTLE closed loop, estimator: {final.method} ({what})"))
    log[1:1] = design_limit_log(design_lim)
    robot = robot_model(cfg)
    peak_rate = float(np.max(np.abs(tel.x_true[:, 10:13])))
    peak_speed = float(np.max(np.abs(tel.x_true[:, 3:6])))
    within_robot = bool(np.all(np.abs(tel.x_true[:, 10:13]) <= np.asarray(robot.angular_velocity_limit_radps)
                               * (1 + 1e-9))
                        and np.all(np.abs(tel.x_true[:, 3:6]) <= np.asarray(robot.velocity_limit_mps) * (1 + 1e-9)))
    if not within_robot:
        log.append((float(tel.t_true[-1]), "warning", f"the flown motion exceeds the robot's velocity or angular "
                                                      f"rate limit (peak {peak_speed:.4g} m/s, {peak_rate:.4g} rad/s)"))
    summary = {
        "stage": "excite",
        "status": "ok",
        "method": "rattle",
        "estimator": final.method,
        "criterion": exc.criterion,
        "parameter_scaling": exc.parameter_scaling,
        "seed": cfg.seed,
        "criterion_initial": criterion_value(prior_info, exc.criterion, d),
        "criterion_final": criterion_value(posterior_info, exc.criterion, d),
        "iterations": len(run.replans),
        "replans": len(run.replans),
        "solve_time_s": float(solve.sum()),
        "replan_time_ms": percentiles_ms(solve),
        "max_force_N": float(np.max(np.abs(tel.u_applied[:, 0:3]))),
        "max_torque_Nm": float(np.max(np.abs(tel.u_applied[:, 3:6]))),
        "max_speed_mps": peak_speed,
        "max_angular_velocity_radps": peak_rate,
        "max_plan_angular_velocity_radps": float(max(np.max(np.abs(r.plan.trajectory.x[:, 10:13]))
                                                     for r in run.replans)),
        "within_robot_limits": within_robot,
        "rate_governed_steps": run.governed_steps,
        "rate_governor_limit_radps": rattle_governor_limit(cfg).tolist(),  # and the planner's cap (rattle_rates)
        "design_limits": design_lim.summary(),
        "collision_free": bool(np.all(inside)),
        "crb_std": _named(crb),
        "crb_std_pct": _named(100.0 * crb / theta_true),
        "estimate": {
            "theta": _named(final.theta),
            "std": _named(final.std),
            "error_pct": _named(100.0 * (final.theta - theta_true) / theta_true),
            "samples_used": final.samples_used,
            "samples_rejected": final.samples_rejected,
        },
        "prior_std": _named(np.sqrt(np.diag(prior_cov))),
        "gamma_final": _named(run.replans[-1].gamma),
        "goal_residual": {
            "position_m": float(np.max(np.abs(tel.x_true[-1, 0:3] - goal[0:3]))),
            "velocity_mps": float(np.max(np.abs(tel.x_true[-1, 3:6]))),
            "angular_velocity_radps": float(np.max(np.abs(tel.x_true[-1, 10:13]))),
        },
        "goal_tolerance": goal_tolerance(cfg, run.replans[-1].theta),
        "plan_goal_residual": plan_goal_residual(run, goal),
        "terminal_replan_s": next((r.t for r in run.replans if r.plan.arrival_step is not None), None),
        "final_position_error_m": float(np.linalg.norm(tel.x_true[-1, 0:3] - goal[0:3])),
        "final_speed_mps": float(np.linalg.norm(tel.x_true[-1, 3:6])),
        "duration_s": float(tel.t_true[-1]),
        "dt_s": cfg.controller.period_s,
        "force_limit_N": design_lim.limits.force_N,
        "torque_limit_Nm": design_lim.limits.torque_Nm,
    }
    robot = robot_model(cfg)
    report = safety_report(
        tel.t_true, tel.x_true, scene=scene, velocity_limit_mps=np.asarray(robot.velocity_limit_mps),
        angular_velocity_limit_radps=np.asarray(robot.angular_velocity_limit_radps), robot_radius_m=robot.radius_m,
        keep_in_margin_m=cfg.environment.keep_in_margin_m,
        t_ctrl=tel.t_ctrl, u_command=tel.u_command, input_limits=robot.input_limits,
    )
    summary["safety"] = safety_block(report, samples=len(tel.t_true), robot_radius_m=robot.radius_m,
                                     keep_in_margin_m=cfg.environment.keep_in_margin_m)
    block = _information_full_block(cfg, traj.x[0], traj.u[:-1], theta_true, cfg.controller.period_s,
                                    problem.measurement)
    if block is not None:
        last = run.replans[-1]
        if last.std_entries is not None and last.gamma_entries is not None:
            names = list(block["crb_std"])
            block["std_final"] = dict(zip(names, map(float, last.std_entries), strict=True))
            block["gamma_final"] = dict(zip(names, map(float, last.gamma_entries), strict=True))
        summary["information_full"] = block
    rattle_findings(summary, cfg, run).apply(summary)
    log.extend(status_log(summary, float(tel.t_true[-1])))
    return summary, traj, log


# ----------------------------------------------------------------------------------------------------------------
# Status (oacli.status)
# ----------------------------------------------------------------------------------------------------------------


def _goal_reasons(report: StatusReport, residual: dict[str, float], problem: ExcitationProblem) -> None:
    tol = problem.terminal
    over = [f"{key} {residual[key]:.3g} > {bound:.3g}"
            for key, bound in (("position_m", tol.position_m), ("velocity_mps", tol.velocity_mps),
                               ("angular_velocity_radps", tol.angular_velocity_radps))
            if key in residual and residual[key] > bound * 1.001]
    if over:
        report.degraded("goal", "the run ends away from the goal at rest (" + ", ".join(over)
                        + "; excitation.terminal_tolerance)")


def offline_findings(summary: dict[str, Any], problem: ExcitationProblem) -> StatusReport:
    """An offline design that stopped before the SCP converged, or that misses the goal, is ``degraded``."""
    report = StatusReport()
    stop = summary["stop_reason"]
    if not stop.startswith("converged"):
        report.degraded("scp", f"the SCP did not converge (stop: {stop}, {summary['iterations']} iterations); the "
                               "design is feasible but not shown optimal (excitation.scp.max_iterations)")
    _goal_reasons(report, summary["goal_residual"], problem)
    return report


def rattle_findings(summary: dict[str, Any], cfg: OacliConfig, run: RattleRun) -> StatusReport:
    """The RATTLE loop's findings: the true state's safety block (robot limits: unsafe; a command beyond the
    robot's actuators: degraded), replans without a solution and a final state away from the goal at rest, or a
    terminal plan that misses it (degraded, :func:`oacli.stages.rattle_goal.goal_reasons`)."""
    report = StatusReport()
    add_safety_reasons(report, summary["safety"])
    failed = [r for r in run.replans if r.plan.status not in ("optimal", "optimal_inaccurate")]
    if failed:
        report.degraded("replan", f"{len(failed)} of {len(run.replans)} replans ended without a solution (last "
                                  f"status {failed[-1].plan.status}); the previous plan was kept")
    goal_reasons(report, summary, cfg)
    return report


def _write_rattle_outputs(stage_run: StageRun, cfg: OacliConfig, problem: ExcitationProblem, run: RattleRun,
                          traj: Trajectory, log: list[LogEntry], prior_cov: np.ndarray, theta_true: np.ndarray,
                          journal: RattleJournal | None = None) -> None:
    tel = run.telemetry
    est_t = np.array([0.0] + [e.t for e in run.estimates])
    prior_info = np.linalg.inv(prior_cov)
    info = np.array([np.zeros((4, 4))] + [np.linalg.inv(e.covariance) - prior_info for e in run.estimates])
    info = 0.5 * (info + np.transpose(info, (0, 2, 1)))
    # The flown trajectory's samples are the control instants (plus the end): information at the same instants.
    idx = np.clip(np.searchsorted(est_t, traj.t + 1e-9) - 1, 0, len(est_t) - 1)
    info_traj = info[idx]
    mcap = stage_run.open_mcap(method="rattle")
    with mcap if journal is None else journal.replaced_by(mcap) as writer:
        plans = {f"plan_{i}": r.plan.trajectory.x[:, 0:3] for i, r in enumerate(run.replans)}
        writer.write_scene(problem.scene, {"flown": tel.x_true[:, 0:3], **plans})
        writer.write_trajectory("/trajectory", traj)
        writer.write_states("/state/true", tel.t_true, tel.x_true)
        writer.write_poses(tel.t_true, tel.x_true)
        writer.write_robot_body(tel.t_true, tel.x_true)
        for r in run.replans:
            writer.write_json(ms.TOPIC_EXCITATION_REPLANS, ms.REPLAN, ms.REPLAN_SCHEMA, r.t, {
                "theta": r.theta, "std": r.std, "gamma": r.gamma, "cost": r.plan.cost,
                "information_reward": r.plan.information_reward, "accepted_iterations": r.plan.accepted,
                "solve_time_ms": 1e3 * r.plan.solve_time_s, "status": r.plan.status,
                "estimator": run.final_estimate.method,
            })
        _information_records(writer, traj.t, info_traj, theta_true)
        for t, level, message in log:
            writer.write_log(t, level, message)
    # The recording shows the posterior std (prior included) over time, as the planner saw it.
    post_std = np.array([np.sqrt(np.diag(np.linalg.inv(prior_info + f))) for f in info_traj])
    rattle = RattleSteps([(r.t, r.plan.trajectory.x[:, 0:3]) for r in run.replans],
                         np.array([r.t for r in run.replans]), np.array([r.gamma for r in run.replans]))
    write_excite_recording(
        stage_run.file("rrd", "excite.rrd"), scene=problem.scene, trajectory=traj,
        information=InformationSeries(theta_true, info_traj, post_std), limits=robot_model(cfg).limits,
        rattle=rattle, log=log, recording_name=f"{cfg.name}/excite",
    )
