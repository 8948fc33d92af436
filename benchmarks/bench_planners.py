"""Benchmark: oacli's planners against OMPL side by side, on S1, S2 and the ISS mission's segments, in one run.

Scenes: S1 (sphere) and S2 (slalom) of ``benchmarks/scenes/*.yaml`` (point robot, m = 9.6 kg, |F_i| <= 0.5 N,
|v_i| <= 0.2 m/s), and the two planned segments of the default mission ``configs/mission_iss.yaml`` exactly as the
mission configures them (:func:`oacli.mission.configs.stage_config`): ``ISS A-B`` (segment 1, the bare robot) and
``ISS C-A`` (segment 3; the learned model stood in for by the grasped truth with a 0.05 kg std), three JEM keep-in
boxes, one keep-out ellipsoid, a sphere robot of 0.25 m, the design limits (``planner.margin``).

Per seed the two sides alternate (oacli first on even seeds, OMPL first on odd ones), so a load change on a shared
machine hits both; ratios compare medians of this run. Pin it to one core: ``taskset -c 1``. On a heavily shared
machine wall times still swing with the load between seeds, so the time to a flyable trajectory is also reported in
CPU time of this process (``time.process_time``: oacli's plan + smooth, OMPL control RRT's whole call).

* **oacli LQR-RRT\\* + shortcut** and **+ shortcut + polish**: the first solution (as flown in ReSWARM), then
  exactly what ``oacli smooth`` runs (LQR shortcutting with the scene's ``planner.shortcut``, its connector built
  as the stage builds it, then the path-length polish with ``planner.polish``; cost cap: the plan's cost).
* **oacli LQR-RRT\\* anytime + shortcut + polish** (``--anytime``): improving for ``--rrtstar-budget`` first.
* **oacli kino-RRT**: motion primitives ([ReSWARM2023] Eqs. 26-27) with the exact LQR goal link (flyable as planned).
* **OMPL control RRT** (``ompl.control.RRT``): the same double integrator and limits, the scalar validity check of
  :class:`benchmarks.ompl_peers.ScalarValidity` (the same geometry: all keep-in boxes, keep-outs grown by the
  robot) at its propagation steps. Its first solution is its flyable trajectory.
* **OMPL RRT\\* + simplifyMax** (geometric, 3-D, ``--rrtstar-budget``), then the stop-and-go time parametrisation
  within the same limits (:func:`benchmarks.ompl_peers.stop_and_go`).

Columns: success rate; time to first solution (p50, p90) [s]; **time to a flyable trajectory** (p50, p90) [s]
(oacli: plan + smooth; OMPL control RRT: its first solution; OMPL RRT*: its budget + simplifyMax + the time
parametrisation); duration [s] and duration ÷ the minimum-time lower bound (per-axis bang-coast-bang, obstacles
ignored); path length [m]; the share of trajectories that pass the independent dense re-check every 5 mm
(:func:`oacli.geometry.verify.dense_check`, robot radius included); and the goal condition each side meets
(oacli: exactly the goal, at rest; OMPL control RRT: within 0.1 of the goal state in the 6-D Euclidean state
distance, not at rest; OMPL RRT*: the goal position, at rest after the parametrisation).

Run from the repository root: ``taskset -c 1 python -m benchmarks.bench_planners [--seeds 10]
[--scenes S1 S2 "ISS A-B" "ISS C-A"] [--ompl-budget 10] [--rrtstar-budget 2] [--anytime] [--json out.json]``
(OMPL needs ``pip install -e '.[bench]'``; without it only oacli's side runs).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.ompl_peers import (  # noqa: E402
    OMPL_IMPORT_ERROR,
    ScalarValidity,
    keep_in_bounds,
    ompl_control_rrt,
    ompl_rrt_star_path,
    seed_ompl,
    stop_and_go,
)
from oacli.config import OacliConfig, load_config  # noqa: E402
from oacli.geometry.verify import dense_check  # noqa: E402
from oacli.planning.full_state import minimum_time_lower_bound_s  # noqa: E402
from oacli.planning.kino_rrt import plan_kino_rrt  # noqa: E402
from oacli.planning.lqr_rrt_star import plan_lqr_rrt_star  # noqa: E402
from oacli.planning.problem import PlanningProblem  # noqa: E402
from oacli.planning.shortcut import lqr_shortcut  # noqa: E402
from oacli.planning.translational import TranslationalTrajectory  # noqa: E402
from oacli.stages.plan import PLAN_STREAM, SMOOTH_STREAM, build_problem, resolve_segment  # noqa: E402
from oacli.stages.settings import kino_rrt_settings, lqr_rrt_star_settings, shortcut_connector  # noqa: E402
from oacli.stages.smooth import run_polish  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE_FILES = {"S1": ROOT / "benchmarks" / "scenes" / "s1_sphere.yaml",
               "S2": ROOT / "benchmarks" / "scenes" / "s2_slalom.yaml"}
ISS_SEGMENTS = {"ISS A-B": "segment-1/plan", "ISS C-A": "segment-3/plan"}
SCENE_NAMES = (*SCENE_FILES, *ISS_SEGMENTS)

GOAL_OACLI = "exact, at rest"
GOAL_OMPL_CONTROL = "|x - x_g| <= 0.1 (6-D), not at rest"
GOAL_OMPL_GEOMETRIC = "goal position, at rest (stop-and-go)"

OACLI_SC = "oacli LQR-RRT* + shortcut"
OACLI_SMOOTH = "oacli LQR-RRT* + shortcut + polish"
OACLI_ANYTIME = "oacli LQR-RRT* anytime + shortcut + polish"
OACLI_KINO = "oacli kino-RRT"
OMPL_CONTROL = "OMPL control RRT"
OMPL_GEOMETRIC = "OMPL RRT* + simplifyMax + stop-and-go"


def scene_config(name: str) -> OacliConfig:
    """The config of a benchmark scene (module docstring)."""
    if name in SCENE_FILES:
        return load_config(SCENE_FILES[name])
    from oacli.mission.configs import Handoff, mission_section, prior_model, stage_config
    from oacli.mission.layout import MISSION_STAGES

    cfg = load_config(ROOT / "configs" / "mission_iss.yaml")
    stage = next(s for s in MISSION_STAGES if s.key == ISS_SEGMENTS[name])
    grasped = mission_section(cfg).grasped
    learned = prior_model(cfg).with_estimate(np.array([grasped.mass_kg, *grasped.inertia_kgm2]),
                                             np.diag([0.05, 1e-3, 1e-3, 1e-3]) ** 2)
    return stage_config(cfg, stage, Handoff(estimate=learned))


@dataclass
class Scene:
    """One benchmark scene: its config, planning problem, lower bound and the OMPL peers' inputs."""

    name: str
    cfg: OacliConfig
    problem: PlanningProblem
    bound_s: float
    radius_m: float
    lower: np.ndarray
    upper: np.ndarray
    valid: Callable[[float, float, float], bool]

    @classmethod
    def build(cls, name: str) -> Scene:
        cfg = scene_config(name)
        problem, body = build_problem(cfg, resolve_segment(cfg, None))
        bound = minimum_time_lower_bound_s(problem.start, problem.goal, problem.force_limit_N,
                                           problem.velocity_limit_mps, problem.model)
        lower, upper = keep_in_bounds(problem.checker)
        return cls(name, cfg, problem, bound, body.bounding_radius_m, lower, upper, ScalarValidity(problem.checker))


def _median(values) -> float:
    v = np.array([x for x in values if np.isfinite(x)], dtype=float)
    return float(np.median(v)) if v.size else float("nan")


def _median_counting_failures(rows: list[dict], key: str, dense: bool = False) -> float:
    """Median of ``key`` over *every* seed, an unsolved one counting as never reaching it (+inf): the time by which
    half of the runs have a flyable trajectory. The solved-only median drops a peer's failures (which spent the
    whole budget), so it flatters the planner that fails more often; both are printed. ``dense``: a solution that
    fails the dense re-check (it clips a keep-out between its states) counts as unsolved too."""
    v = np.array([r.get(key, np.nan) if r["solved"] and (r.get("dense_ok") or not dense) else np.inf
                  for r in rows], dtype=float)
    v = v[~np.isnan(v)]
    return float(np.median(v)) if v.size else float("nan")


def _p90(values) -> float:
    v = np.array([x for x in values if np.isfinite(x)], dtype=float)
    return float(np.percentile(v, 90)) if v.size else float("nan")


def _dense_ok(traj: TranslationalTrajectory, sc: Scene) -> bool:
    return dense_check(traj.t, traj.x, traj.u, traj.model, sc.problem.checker.scene, sc.radius_m).ok


def _metrics(traj: TranslationalTrajectory, sc: Scene) -> dict[str, float]:
    return {
        "duration_s": traj.duration_s,
        "duration_ratio": traj.duration_s / sc.bound_s,
        "impulse_Ns": traj.impulse_Ns(),
        "length_m": traj.path_length_m(),
        "goal_error": float(np.linalg.norm(traj.x[-1] - sc.problem.goal)),
        "dense_ok": _dense_ok(traj, sc),
    }


def run_oacli(sc: Scene, seed: int, anytime: float | None) -> dict[str, dict]:
    """LQR-RRT* (first solution or anytime) + shortcut + polish as ``oacli plan`` / ``oacli smooth`` run them."""
    cfg, problem = sc.cfg, sc.problem
    p = cfg.planner
    settings = lqr_rrt_star_settings(cfg)
    if anytime is not None:
        settings = replace(settings, anytime=True, time_budget_s=anytime, max_iterations=10**9)
    c0, t0 = time.process_time(), time.perf_counter()
    result = plan_lqr_rrt_star(problem, settings, np.random.default_rng([seed, PLAN_STREAM]))
    t_plan, c_plan = time.perf_counter() - t0, time.process_time() - c0
    row: dict = {"seed": seed, "solved": result.solved, "ttfs_s": result.time_to_first_solution_s,
                 "plan_s": t_plan, "goal": GOAL_OACLI}
    if not result.solved:
        return {"shortcut": row, "smooth": dict(row)}
    raw_ok = _dense_ok(result.trajectory, sc)
    c1, t1 = time.process_time(), time.perf_counter()
    sc_res = lqr_shortcut(result.trajectory, shortcut_connector(cfg), problem.checker, problem.goal,
                          problem.force_limit_N, problem.velocity_limit_mps,
                          np.random.default_rng([seed, SMOOTH_STREAM]), tries=p.shortcut.tries,
                          sample_dt_s=p.output_dt_s)
    t2, c2 = time.perf_counter(), time.process_time()
    polish = run_polish(cfg, sc_res.trajectory, problem.checker, problem.goal,
                        result.cost if p.polish.keep_cost else None)
    t3, c3 = time.perf_counter(), time.process_time()
    short = dict(row) | _metrics(sc_res.trajectory, sc)
    short |= {"dense_ok": raw_ok and short["dense_ok"], "smooth_s": t2 - t1, "flyable_s": t_plan + t2 - t1,
              "flyable_cpu_s": c_plan + c2 - c1}
    smooth = dict(row) | _metrics(polish.trajectory, sc)
    smooth |= {"dense_ok": raw_ok and smooth["dense_ok"], "smooth_s": t3 - t1, "flyable_s": t_plan + t3 - t1,
               "flyable_cpu_s": c_plan + c3 - c1,
               "shortcut_s": t2 - t1, "polish_s": t3 - t2, "polish_status": polish.status,
               "polish_iterations": len(polish.iterations), "raw_duration_s": result.trajectory.duration_s,
               "exact_ok": bool(problem.checker.is_free(polish.trajectory.pieces()))}
    return {"shortcut": short, "smooth": smooth}


def run_kino(sc: Scene, seed: int) -> dict:
    t0 = time.perf_counter()
    kino = plan_kino_rrt(sc.problem, kino_rrt_settings(sc.cfg), np.random.default_rng([seed, PLAN_STREAM]))
    wall = time.perf_counter() - t0
    row: dict = {"seed": seed, "solved": kino.solved, "ttfs_s": kino.time_to_first_solution_s, "goal": GOAL_OACLI}
    if kino.solved:
        row |= _metrics(kino.trajectory, sc) | {"flyable_s": wall}
    return row


def run_ompl_control(sc: Scene, seed: int, budget_s: float) -> dict:
    pr = sc.problem
    c0 = time.process_time()
    ok, wall, path = ompl_control_rrt(pr.start, pr.goal, sc.lower, sc.upper, pr.model.mass_kg, pr.force_limit_N,
                                      pr.velocity_limit_mps, sc.valid, time_budget_s=budget_s)
    cpu = time.process_time() - c0  # the whole call: the solve plus OMPL's setup and the path read-out
    row: dict = {"seed": seed, "solved": ok, "ttfs_s": wall if ok else float("nan"), "goal": GOAL_OMPL_CONTROL,
                 "ttfs_cpu_s": cpu if ok else float("nan")}
    if ok and path is not None:
        traj = TranslationalTrajectory(path.t, path.x, path.u, pr.model)
        row |= _metrics(traj, sc) | {"flyable_s": wall, "flyable_cpu_s": cpu}
    return row


def run_ompl_geometric(sc: Scene, seed: int, budget_s: float) -> dict:
    pr = sc.problem
    ok, wall, length, pts = ompl_rrt_star_path(pr.start[0:3], pr.goal[0:3], sc.lower, sc.upper, sc.valid,
                                               time_budget_s=budget_s)
    row: dict = {"seed": seed, "solved": ok, "ttfs_s": float("nan"), "goal": GOAL_OMPL_GEOMETRIC}
    if ok and pts is not None:
        t0 = time.perf_counter()
        t, x, u = stop_and_go(pts, pr.model.mass_kg, pr.force_limit_N, pr.velocity_limit_mps)
        traj = TranslationalTrajectory(t, x, u, pr.model)
        row |= _metrics(traj, sc) | {"flyable_s": wall + time.perf_counter() - t0, "polyline_length_m": length}
    return row


def run_scene(sc: Scene, seeds: int, ompl_budget: float, rrtstar_budget: float, anytime: bool) -> dict[str, list]:
    """Every planner on every seed, oacli and OMPL alternating which goes first."""
    rows: dict[str, list[dict]] = {OACLI_SC: [], OACLI_SMOOTH: [], OACLI_KINO: []}
    if anytime:
        rows[OACLI_ANYTIME] = []
    if OMPL_IMPORT_ERROR is None:
        rows[OMPL_CONTROL] = []
        rows[OMPL_GEOMETRIC] = []

    def oacli_side(seed: int) -> None:
        out = run_oacli(sc, seed, None)
        rows[OACLI_SC].append(out["shortcut"])
        rows[OACLI_SMOOTH].append(out["smooth"])
        if anytime:
            rows[OACLI_ANYTIME].append(run_oacli(sc, seed, rrtstar_budget)["smooth"])
        rows[OACLI_KINO].append(run_kino(sc, seed))

    def ompl_side(seed: int) -> None:
        if OMPL_IMPORT_ERROR is not None:
            return
        rows[OMPL_CONTROL].append(run_ompl_control(sc, seed, ompl_budget))
        rows[OMPL_GEOMETRIC].append(run_ompl_geometric(sc, seed, rrtstar_budget))

    for seed in range(seeds):
        sides = (oacli_side, ompl_side) if seed % 2 == 0 else (ompl_side, oacli_side)
        for side in sides:
            side(seed)
    return rows


def summarise(rows: list[dict]) -> dict:
    solved = [r for r in rows if r["solved"]]
    out: dict = {
        "success": len(solved) / len(rows),
        "ttfs_p50_s": _median(r["ttfs_s"] for r in rows),
        "ttfs_p90_s": _p90(r["ttfs_s"] for r in rows),
        "flyable_p50_s": _median(r.get("flyable_s", np.nan) for r in solved),
        "flyable_p90_s": _p90(r.get("flyable_s", np.nan) for r in solved),
        "dense_free": (sum(bool(r.get("dense_ok")) for r in solved) / len(solved)) if solved else float("nan"),
        "dense_free_count": f"{sum(bool(r.get('dense_ok')) for r in solved)}/{len(solved)}",
        "goal": rows[0]["goal"] if rows else "",
    }
    out["flyable_p50_all_s"] = _median_counting_failures(rows, "flyable_s")
    out["flyable_cpu_p50_all_s"] = _median_counting_failures(rows, "flyable_cpu_s")
    out["flyable_cpu_p50_dense_s"] = _median_counting_failures(rows, "flyable_cpu_s", dense=True)
    for key in ("duration_s", "duration_ratio", "impulse_Ns", "length_m", "smooth_s", "shortcut_s", "polish_s",
                "goal_error", "flyable_cpu_s"):
        out[key] = _median(r.get(key, np.nan) for r in solved)
    return out


def _paired_ratio(a: list[dict], b: list[dict], key_a: str, key_b: str) -> float:
    """Median over seeds solved by both of ``a[key_a] / b[key_b]`` (the same seed ran back to back)."""
    ratios = [ra[key_a] / rb[key_b] for ra, rb in zip(a, b, strict=True)
              if ra["solved"] and rb["solved"] and rb[key_b] > 0]
    return float(np.median(ratios)) if ratios else float("nan")


def print_table(sc: Scene, summaries: dict[str, dict]) -> None:
    print(f"\n{sc.name}: minimum-time lower bound {sc.bound_s:.2f} s")
    head = (f"{'planner':<42} {'success':>7} {'TTFS p50':>9} {'p90':>7} {'flyable p50':>11} {'p90':>7} "
            f"{'duration':>8} {'/bound':>6} {'length':>7} {'dense-free':>10}  goal condition")
    print(head)
    print("-" * len(head))
    for name, s in summaries.items():
        print(f"{name:<42} {s['success']:>7.0%} {s['ttfs_p50_s']:>9.3f} {s['ttfs_p90_s']:>7.3f} "
              f"{s['flyable_p50_s']:>11.3f} {s['flyable_p90_s']:>7.3f} {s['duration_s']:>8.1f} "
              f"{s['duration_ratio']:>6.2f} {s['length_m']:>7.4f} {s['dense_free_count']:>10}  {s['goal']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10, help="runs per planner and scene")
    parser.add_argument("--scenes", nargs="+", default=list(SCENE_NAMES), choices=SCENE_NAMES)
    parser.add_argument("--ompl-budget", type=float, default=10.0, help="OMPL control RRT time budget [s]")
    parser.add_argument("--rrtstar-budget", type=float, default=2.0,
                        help="OMPL geometric RRT* (and oacli anytime) time budget [s]")
    parser.add_argument("--anytime", action="store_true", help="also run oacli's anytime LQR-RRT*")
    parser.add_argument("--json", type=Path, help="also write every row and summary as JSON")
    args = parser.parse_args()
    if OMPL_IMPORT_ERROR is not None:
        print(f"OMPL not available ({OMPL_IMPORT_ERROR}); install the bench extra. Running oacli's side only.",
              file=sys.stderr)
    else:
        seed_ompl(12345)
    report = {}
    for name in args.scenes:
        sc = Scene.build(name)
        rows = run_scene(sc, args.seeds, args.ompl_budget, args.rrtstar_budget, args.anytime)
        summaries = {k: summarise(r) for k, r in rows.items()}
        print_table(sc, summaries)
        ours = summaries[OACLI_SMOOTH]
        print(f"  oacli smooth: shortcut p50 {ours['shortcut_s']:.3f} s + polish p50 {ours['polish_s']:.3f} s")
        if OMPL_CONTROL in summaries:
            peer = summaries[OMPL_CONTROL]
            print(f"  time to flyable p50, oacli plan + smooth / OMPL control RRT first solution: "
                  f"{ours['flyable_p50_s'] / peer['ttfs_p50_s']:.3f} (same-seed pairs: "
                  f"{_paired_ratio(rows[OACLI_SMOOTH], rows[OMPL_CONTROL], 'flyable_s', 'ttfs_s'):.3f})")
            print(f"  CPU time to flyable p50 (time.process_time, robust to a loaded machine): oacli "
                  f"{ours['flyable_cpu_s']:.3f} s, OMPL control RRT {peer['flyable_cpu_s']:.3f} s, ratio "
                  f"{ours['flyable_cpu_s'] / peer['flyable_cpu_s']:.3f} (same-seed pairs: "
                  f"{_paired_ratio(rows[OACLI_SMOOTH], rows[OMPL_CONTROL], 'flyable_cpu_s', 'flyable_cpu_s'):.3f})")
            print(f"  the same medians over every seed, an unsolved one counting as +inf (OMPL control RRT solved "
                  f"{peer['success']:.0%}, oacli {ours['success']:.0%}): wall ratio "
                  f"{ours['flyable_p50_all_s'] / peer['flyable_p50_all_s']:.3f}, CPU ratio "
                  f"{ours['flyable_cpu_p50_all_s'] / peer['flyable_cpu_p50_all_s']:.3f}; and with a solution that "
                  f"fails the dense re-check counted as unsolved (OMPL dense-free {peer['dense_free_count']}): CPU "
                  f"ratio {ours['flyable_cpu_p50_dense_s'] / peer['flyable_cpu_p50_dense_s']:.3f}")
            print(f"  TTFS p50 oacli / OMPL control RRT: {summaries[OACLI_SC]['ttfs_p50_s'] / peer['ttfs_p50_s']:.3f}")
            geo = summaries[OMPL_GEOMETRIC]
            print(f"  duration / bound: oacli {ours['duration_ratio']:.2f}, OMPL control RRT "
                  f"{peer['duration_ratio']:.2f}, OMPL RRT* stop-and-go {geo['duration_ratio']:.2f}")
            print(f"  path length / OMPL RRT* + simplifyMax: oacli + shortcut "
                  f"{summaries[OACLI_SC]['length_m'] / geo['length_m']:.4f}, + polish "
                  f"{ours['length_m'] / geo['length_m']:.4f}")
        report[name] = {"lower_bound_s": sc.bound_s, "summaries": summaries, "rows": rows}
    if args.json:
        args.json.write_text(json.dumps(report, indent=2, default=float))


if __name__ == "__main__":
    main()
