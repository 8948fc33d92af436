"""The ``plan`` stage: a collision-free, dynamically feasible trajectory between two waypoints.

Inputs: the config (robot, scene, waypoints, ``planner`` section) and a segment ``A-B``. Everything is validated
before the run folder is created (unknown waypoints, a start or goal inside a keep-out zone or outside the keep-in
boxes: exit 2, no folder). Outputs in the run folder: ``config.yaml`` (resolved, with the segment and planner that
ran), ``plan.mcap``, ``plan.rrd`` and ``summary.json`` (last). Without a solution within the budget the MCAP and
the recording still hold the partial tree, ``summary.json`` says ``"status": "no_solution"`` and the command exits
with code 3. While the search runs, the tree's growth and the best cost are journaled to ``plan.mcap``'s temporary
(:mod:`oacli.stages.plan_journal`), so a killed run leaves a readable record; the complete file replaces it.

``plan.mcap`` topics (besides the contract of docs/mcap.md): ``/trajectory`` (oacli.TrajectorySample, the plan),
``/robot/pose``, ``/scene`` (scene and path), ``/plan/tree`` (oacli.PlanTreeNode, one record per node of the final
tree), ``/plan/rewires`` (oacli.PlanRewire), ``/plan/solutions`` (oacli.PlanSolution), ``/log``; metadata record
``oacli.plan`` (planner, segment, status, cost). Planner records carry ``t = 0`` (they are not on the trajectory's
time axis) and their own ``iteration`` and ``wall_time_s``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.errors import ConfigError, InfeasibleError
from oacli.geometry import Scene
from oacli.geometry.collision import CollisionChecker, RobotBody
from oacli.geometry.verify import dense_check
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.plots.plan import write_path_plots
from oacli.io.rerun.plan import write_plan_recording
from oacli.io.runfolder import StageResult
from oacli.phases import set_phase
from oacli.planning.full_state import full_state_trajectory, minimum_time_lower_bound_s, translational_part
from oacli.planning.kino_rrt import plan_kino_rrt
from oacli.planning.lqr_rrt_star import plan_lqr_rrt_star
from oacli.planning.problem import PlanningProblem
from oacli.planning.result import PlanResult
from oacli.planning.translational import TranslationalTrajectory
from oacli.planning.tree import EDGE_LQR, EDGE_PRIMITIVE
from oacli.stages.design_limits import design_limit_log, planner_design_limits
from oacli.stages.plan_journal import PlanJournal
from oacli.stages.settings import (
    cost_weights,
    kino_rrt_settings,
    lqr_rrt_star_settings,
    open_run,
    robot_body,
    robot_model,
)
from oacli.status import NO_SOLUTION, OK, StatusReport, add_output_trajectory_reasons, status_log
from oacli.types import Trajectory

LogEntry = tuple[float, str, str]

#: Stream keys of the per-stage random generators (``default_rng([seed, key])``).
PLAN_STREAM = 0x504C414E  # "PLAN"
SMOOTH_STREAM = 0x534D4F4F  # "SMOO"

@dataclass(frozen=True)
class Segment:
    """A planning query from the config: waypoint names, poses and the robot body used for collisions."""

    name: str
    start_name: str
    goal_name: str
    start: np.ndarray  # 13-state at rest
    goal: np.ndarray


def _fmt_point(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in p) + ")"


def resolve_segment(cfg: OacliConfig, segment: str | None) -> Segment:
    """The segment ``A-B`` to plan: from the option, else ``planner.segment``, else the reference's first two names.

    Raises
    ------
    ConfigError
        No segment given anywhere, unknown waypoint names, or an ambiguous split (names containing ``-``).
    """
    where = "--segment" if segment is not None else "planner.segment"
    text = segment if segment is not None else cfg.planner.segment
    if text is None:
        names = [w for w in cfg.reference.waypoints if isinstance(w, str)]
        if len(names) < 2:
            raise ConfigError(
                f"{where}: no segment to plan: give --segment A-B, planner.segment, or two waypoint names in "
                "reference.waypoints"
            )
        text, where = f"{names[0]}-{names[1]}", "reference.waypoints"
    defined = ", ".join(sorted(cfg.waypoints)) or "none"
    splits = [
        (text[:i], text[i + 1 :])
        for i, ch in enumerate(text)
        if ch == "-" and text[:i] in cfg.waypoints and text[i + 1 :] in cfg.waypoints
    ]
    if not splits:
        raise ConfigError(f"{where}: {text}: not two waypoint names joined by '-' (defined in waypoints: {defined})")
    if len(splits) > 1:
        raise ConfigError(f"{where}: {text}: ambiguous, it splits into waypoints {splits}")
    a, b = splits[0]
    if a == b:
        raise ConfigError(f"{where}: {text}: start and goal are the same waypoint")
    return Segment(text, a, b, cfg.waypoint(a).state(), cfg.waypoint(b).state())


def describe_body(body: RobotBody) -> str:
    if body.is_point:
        return "the robot (a point)"
    return f"the robot (bounding radius {body.bounding_radius_m:.3g} m)"


def check_endpoint(label: str, where: str, position: np.ndarray, checker: CollisionChecker, body: RobotBody) -> None:
    """Refuse a start or goal inside a keep-out zone or outside every keep-in box (ConfigError, exit 2)."""
    for kind, j in checker.point_violations(position):
        if kind == "keep_in":
            raise ConfigError(f"{where}: {label} {_fmt_point(position)} is outside every keep-in box "
                              "(environment.keep_in)")
        raise ConfigError(f"{where}: {label} {_fmt_point(position)}: {describe_body(body)} overlaps keep-out zone "
                          f"environment.keep_out.{j} (safety factor included)")


def build_problem(cfg: OacliConfig, seg: Segment) -> tuple[PlanningProblem, RobotBody]:
    """Validate the query and build the :class:`~oacli.planning.problem.PlanningProblem` (no files touched)."""
    scene = cfg.scene()
    if not scene.keep_in:
        raise ConfigError("environment.keep_in: planning samples positions in the keep-in boxes; give at least one")
    body = robot_body(cfg, seg.start[6:10], seg.goal[6:10])
    checker = CollisionChecker(scene, body)
    check_endpoint(f"start of segment {seg.name}", f"waypoints.{seg.start_name}", seg.start[0:3], checker, body)
    check_endpoint(f"goal of segment {seg.name}", f"waypoints.{seg.goal_name}", seg.goal[0:3], checker, body)
    robot = robot_model(cfg)
    limits = planner_design_limits(cfg).limits
    problem = PlanningProblem(
        start=seg.start[0:6], goal=seg.goal[0:6], model=robot,
        force_limit_N=limits.force_N, velocity_limit_mps=limits.velocity_mps,
        checker=checker, sample_lower=np.array([b.lower for b in scene.keep_in]),
        sample_upper=np.array([b.upper for b in scene.keep_in]),
        weights=cost_weights(cfg),
    )
    return problem, body


def to_output(cfg: OacliConfig, trans: TranslationalTrajectory, q_start: np.ndarray, q_goal: np.ndarray,
              name: str) -> Trajectory:
    """The 13-state output trajectory sampled every ``planner.output_dt_s`` with the attitude slerped within the
    design limits' angular rate and torque."""
    limits = planner_design_limits(cfg).limits
    return full_state_trajectory(
        trans.refined(cfg.planner.output_dt_s), q_start, q_goal,
        rate_limit_radps=limits.angular_velocity_radps,
        torque_limit_Nm=limits.torque_Nm, hold_dt_s=cfg.planner.output_dt_s, name=name,
        frame=cfg.environment.frame,
    )


def trajectory_metrics(cfg: OacliConfig, traj: Trajectory, checker: CollisionChecker, body: RobotBody,
                       goal6: np.ndarray) -> dict[str, Any]:
    """Summary numbers of an output trajectory; collisions re-checked exactly and densely (every 5 mm).

    ``within_limits``: within the design limits (:func:`~oacli.stages.design_limits.planner_design_limits`);
    ``within_robot_limits``: within the robot's own; ``min_time_lower_bound_s`` under the design limits.
    """
    robot = robot_model(cfg)
    design = planner_design_limits(cfg)
    lim = design.limits
    trans = translational_part(traj, robot)
    report = checker.check(trans.pieces())
    force = np.abs(traj.u[:, 0:3]).max(axis=0)
    torque = np.abs(traj.u[:, 3:6]).max(axis=0)
    vel = np.abs(traj.x[:, 3:6]).max(axis=0)
    omega = np.abs(traj.x[:, 10:13]).max(axis=0)

    def within(limits) -> bool:
        return bool(
            np.all(force <= limits.force_N * (1 + 1e-9)) and np.all(vel <= limits.velocity_mps * (1 + 1e-9))
            and np.all(torque <= limits.torque_Nm * (1 + 1e-9))
            and np.all(omega <= limits.angular_velocity_radps * (1 + 1e-9))
        )

    bound = minimum_time_lower_bound_s(traj.x[0, 0:3], traj.x[-1, 0:3], lim.force_N, lim.velocity_mps, robot)
    out: dict[str, Any] = {
        "cost": trans.cost(cost_weights(cfg), goal6),
        "path_length_m": trans.path_length_m(),
        "duration_s": traj.duration_s,
        "min_time_lower_bound_s": bound,
        "duration_ratio": traj.duration_s / bound if bound > 0 else float("nan"),
        "impulse_Ns": trans.impulse_Ns(),
        "max_force_N": float(force.max()),
        "max_force_per_axis_N": force,
        "max_velocity_mps": float(vel.max()),
        "max_torque_Nm": float(torque.max()),
        "max_angular_velocity_radps": float(omega.max()),
        "within_limits": within(lim),
        "within_robot_limits": within(design.robot),
        "collision_free": bool(report.free),
    }
    if not report.free:
        out["first_collision"] = {
            "t_s": float(trans.t[report.first_piece] + np.nan_to_num(report.time_in_piece_s)),
            "kind": report.kind, "zone": report.zone,
        }
    if np.allclose(body.sigma, body.sigma[0, 0] * np.eye(3)):  # sphere or point: the dense re-check applies
        dense = dense_check(trans.t, trans.x, trans.u, trans.model, checker.scene, body.bounding_radius_m)
        out["dense_check"] = {"ok": dense.ok, "samples": dense.samples, "max_spacing_m": dense.max_spacing_m,
                              "min_clearance_m": dense.min_clearance_m}
    return out


def _edge_name(kind: int) -> str:
    return {EDGE_LQR: "lqr", EDGE_PRIMITIVE: "primitive"}.get(int(kind), "root")


def write_plan_topics(writer: StageMcapWriter, scene: Scene, result: PlanResult, output: Trajectory | None,
                      summary: dict[str, Any], log: list[LogEntry]) -> None:
    """Write the plan's topics (module docstring) to its MCAP.

    Parameters
    ----------
    writer : StageMcapWriter
        The open writer.
    scene : Scene
        The workspace.
    result : PlanResult
        The planner's output (tree, rewires, solutions).
    output : Trajectory or None
        The plan (None without a solution).
    summary : dict
        The stage's summary (for the ``oacli.plan`` metadata).
    log : list of (float, str, str)
        The stage's log.
    """
    tree = result.tree
    in_path = np.zeros(len(tree), dtype=bool)
    in_path[list(result.path)] = True
    writer.write_metadata("oacli.plan", {k: summary[k] for k in ("planner", "segment", "status", "iterations",
                                                                   "nodes") if k in summary}
                          | {"cost": summary.get("cost")})
    paths = {"plan": output.x[:, 0:3]} if output is not None else {}
    writer.write_scene(scene, paths)
    writer.write_plan_tree(tree.edges, in_path)
    if output is not None:
        writer.write_trajectory("/trajectory", output)
        writer.write_poses(output.t, output.x)
        writer.write_robot_body(output.t, output.x)
    for i in range(len(tree)):
        writer.write_json(ms.TOPIC_PLAN_TREE, ms.PLAN_TREE_NODE, ms.PLAN_TREE_NODE_SCHEMA, 0.0, {
            "node": i, "parent": int(tree.parent[i]), "iteration": int(tree.iteration[i]),
            "wall_time_s": float(tree.wall_time_s[i]), "position": tree.states[i, 0:3],
            "velocity": tree.states[i, 3:6], "cost": float(tree.cost[i]), "edge": _edge_name(tree.kind[i]),
            "edge_steps": int(tree.steps[i]), "edge_duration_s": float(tree.duration_s[i]),
            "edge_force": tree.force[i], "in_path": bool(in_path[i]), "goal": i == tree.goal_node,
        })
    for ev in result.rewires:
        writer.write_json(ms.TOPIC_PLAN_REWIRES, ms.PLAN_REWIRE, ms.PLAN_REWIRE_SCHEMA, 0.0, {
            "iteration": ev.iteration, "node": ev.node, "old_parent": ev.old_parent,
            "new_parent": ev.new_parent, "old_steps": ev.old_steps, "new_steps": ev.new_steps,
            "old_cost": ev.old_cost, "new_cost": ev.new_cost, "descendants_updated": ev.descendants_updated,
        })
    for sol in result.solutions:
        writer.write_json(ms.TOPIC_PLAN_SOLUTIONS, ms.PLAN_SOLUTION, ms.PLAN_SOLUTION_SCHEMA, 0.0, {
            "iteration": sol.iteration, "wall_time_s": sol.wall_time_s, "cost": sol.cost, "nodes": sol.nodes,
        })
    for t, level, message in log:
        writer.write_log(t, level, message)


def run_plan(
    cfg: OacliConfig,
    *,
    segment: str | None = None,
    planner: str | None = None,
    out: Path | None = None,
    runs_root: Path = Path("runs"),
    progress: Callable[[float], None] | None = None,
) -> StageResult:
    """Run the ``plan`` stage and write its run folder (module docstring).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration (seed override applied).
    segment : str, optional
        ``A-B``; overrides ``planner.segment``.
    planner : str, optional
        ``lqr-rrt-star`` or ``kino-rrt``; overrides ``planner.type``.
    out, runs_root : Path
        Run folder (see :func:`oacli.io.runfolder.create_run_dir`).
    progress : callable, optional
        Called with the used fraction of the planning budget.

    Returns
    -------
    StageResult

    Raises
    ------
    ConfigError
        Bad segment, start or goal in collision, no keep-in box (before any file is written).
    InfeasibleError
        No solution within the budget (the run folder then holds the partial tree, status ``no_solution``).
    """
    wall_start = time.perf_counter()
    if planner is not None:
        if planner not in ("lqr-rrt-star", "kino-rrt"):
            raise ConfigError(f"--planner: {planner}: must be 'lqr-rrt-star' or 'kino-rrt'")
        cfg = cfg.model_copy(update={"planner": cfg.planner.model_copy(update={"type": planner})})
    seg = resolve_segment(cfg, segment)
    cfg = cfg.model_copy(update={"planner": cfg.planner.model_copy(update={"segment": seg.name})})
    problem, body = build_problem(cfg, seg)
    scene = problem.checker.scene
    kind = cfg.planner.type
    limits = planner_design_limits(cfg)

    log: list[LogEntry] = design_limit_log(limits)
    # The tree's growth goes to the MCAP while the search runs (oacli.stages.plan_journal); the journal is
    # deleted once the complete file is in place (StageJournal.replaced_by).
    with (open_run("plan", cfg, out=out, runs_root=runs_root, started=wall_start) as run,
          PlanJournal(run.open_mcap) as journal):
        rng = np.random.default_rng([cfg.seed, PLAN_STREAM])
        log.append((0.0, "info", f"{kind}: segment {seg.name} from {_fmt_point(seg.start[0:3])} to "
                                 f"{_fmt_point(seg.goal[0:3])}; {describe_body(body)}"))
        set_phase(progress, "LQR-RRT* search" if kind == "lqr-rrt-star" else "kinodynamic RRT search")
        if kind == "lqr-rrt-star":
            result = plan_lqr_rrt_star(problem, lqr_rrt_star_settings(cfg), rng, progress=progress,
                                       on_iteration=journal.on_iteration)
        else:
            result = plan_kino_rrt(problem, kino_rrt_settings(cfg), rng, progress=progress,
                                   on_iteration=journal.on_iteration)
        output = None
        summary: dict[str, Any] = {
            "stage": "plan",
            "status": "ok" if result.solved else "no_solution",
            "planner": kind,
            "segment": seg.name,
            "seed": cfg.seed,
            "iterations": result.iterations,
            "nodes": len(result.tree),
            "stop_reason": result.stop_reason,
            "time_to_first_solution_s": result.time_to_first_solution_s,
            "iterations_to_first_solution": result.iterations_to_first_solution,
            "planning_time_s": result.planning_time_s,
            "cost_first_solution": result.solutions[0].cost if result.solutions else float("nan"),
            "solution_improvements": max(len(result.solutions) - 1, 0),
            "rewires": len(result.rewires),
            "stats": result.stats,
            "design_limits": limits.summary(),
        }
        if result.solved:
            output = to_output(cfg, result.trajectory, seg.start[6:10], seg.goal[6:10], "plan")  # type: ignore[arg-type]
            summary |= trajectory_metrics(cfg, output, problem.checker, body, problem.goal)
            log.append((0.0, "info", f"solution after {result.iterations_to_first_solution} iterations "
                                     f"({result.time_to_first_solution_s:.3f} s), {len(result.tree)} nodes, "
                                     f"cost {summary['cost']:.6g}"))
            log.append((output.duration_s, "info", f"arrives at {seg.goal_name} after {output.duration_s:.1f} s"))
        else:
            summary |= {"cost": float("nan"), "collision_free": None, "duration_s": float("nan"),
                        "path_length_m": float("nan"), "max_force_N": float("nan")}
            log.append((0.0, "error", f"no solution within the budget ({result.iterations} iterations, "
                                      f"{result.planning_time_s:.1f} s, {len(result.tree)} nodes)"))
        report = StatusReport(OK if result.solved else NO_SOLUTION)
        if result.solved:
            add_output_trajectory_reasons(report, summary, "plan")
        report.apply(summary)
        log.extend(status_log(summary))
        with journal.replaced_by(run.open_mcap()) as writer:  # the journal stays until the complete file is in place
            write_plan_topics(writer, scene, result, output, summary, log)
        write_plan_recording(
            run.file("rrd", "plan.rrd"), scene=scene, start=seg.start[0:3], goal=seg.goal[0:3], result=result,
            trajectory=output, limits=limits.limits, log=log, recording_name=f"{cfg.name}/plan",
        )
        if cfg.outputs.plots:
            write_path_plots(run, summary, scene=scene, robot_radius_m=float(robot_model(cfg).radius_m),
                             paths={} if output is None else {"plan": output.x[:, 0:3]}, start_m=seg.start[0:3],
                             goal_m=seg.goal[0:3])
        stage = run.finish(summary)
    if not result.solved:
        raise InfeasibleError(
            f"no solution from {seg.start_name} to {seg.goal_name} within the budget ({result.iterations} "
            f"iterations, {result.planning_time_s:.1f} s, {len(result.tree)} nodes; stopped by "
            f"{result.stop_reason}); the partial tree is in {stage.run_dir}"
        )
    return stage
