"""Benchmark: oacli's planners against OMPL on the scenes S1 (sphere) and S2 (slalom), in the same run.

Same scenes (``benchmarks/scenes/*.yaml``), same double integrator (m = 9.6 kg, |F_i| <= 0.5 N, |v_i| <= 0.2 m/s),
same point validity function (``CollisionChecker.points_free``), N seeds each:

* **oacli LQR-RRT\\* + LQR shortcutting**: first solution (as flown in ReSWARM), then the configured shortcut
  tries; exactly what ``oacli plan`` and ``oacli smooth`` run.
* **oacli LQR-RRT\\* anytime + shortcutting**: the same, but improving for the geometric RRT*'s time budget
  before smoothing (``planner.anytime: true``), for the path-quality comparison.
* **... + polish**: both of the above followed by the path-length polish (:mod:`oacli.planning.polish`, sequential
  convex programming), exactly as ``oacli smooth`` runs it with the scene's ``planner.polish`` settings (cost cap:
  the plan's LQR cost).
* **oacli kino-RRT**: motion primitives (ReSWARM Eqs. 26-27) with the exact LQR goal link.
* **OMPL control RRT** (``ompl.control.RRT``): the same double integrator, validity checked at its propagation
  steps (its own design); reaching the goal within a distance of 0.1 in the 6-D state space.
* **OMPL RRT\\* + simplifyMax** (geometric, 3-D): the baseline for the geometric path length, with OMPL's motion
  validator at 0.1 % of the extent (its default 1 % lets simplified segments cut into the ellipsoids).

Metrics: success rate; time to first solution (median, p90) [s]; duration, impulse ∫Σ|f_i|dt and LQR cost (the
cost of :mod:`oacli.planning.translational`) of the (smoothed) trajectory; duration against the minimum-time lower
bound (per-axis bang-coast-bang, obstacles ignored); path length; and the rate of trajectories that pass an
independent dense re-check every 5 mm (:func:`oacli.geometry.verify.dense_check`); the wall time of the smoothing
(shortcutting, plus the polish where it runs). Ratios compare medians measured in this run, so they are
meaningful on a shared, noisy machine.

Run from the repository root: ``python -m benchmarks.bench_planners [--seeds 20] [--scenes S1 S2] [--ompl-budget 10]
[--json out.json]``
(needs ``pip install -e '.[bench]'`` for OMPL; without it only oacli's side runs).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from oacli.config import load_config
from oacli.geometry.verify import dense_check
from oacli.planning.full_state import minimum_time_lower_bound_s
from oacli.planning.kino_rrt import plan_kino_rrt
from oacli.planning.lqr_rrt_star import plan_lqr_rrt_star
from oacli.planning.shortcut import lqr_shortcut
from oacli.planning.steering import LqrConnector
from oacli.planning.translational import TranslationalTrajectory
from oacli.stages.plan import PLAN_STREAM, SMOOTH_STREAM, build_problem, resolve_segment
from oacli.stages.settings import kino_rrt_settings, lqr_rrt_star_settings
from oacli.stages.smooth import run_polish

SCENES = {"S1": Path(__file__).parent / "scenes" / "s1_sphere.yaml",
          "S2": Path(__file__).parent / "scenes" / "s2_slalom.yaml"}

try:
    from benchmarks.ompl_peers import ompl_control_rrt, ompl_rrt_star_length, seed_ompl
except ImportError as exc:  # ompl is in the bench extra only
    OMPL_ERROR: str | None = f"{type(exc).__name__}: {exc}"
else:
    OMPL_ERROR = None


def _median(values) -> float:
    v = np.array([x for x in values if np.isfinite(x)], dtype=float)
    return float(np.median(v)) if v.size else float("nan")


def _p90(values) -> float:
    v = np.array([x for x in values if np.isfinite(x)], dtype=float)
    return float(np.percentile(v, 90)) if v.size else float("nan")


def _dense_ok(traj: TranslationalTrajectory, scene) -> bool:
    return dense_check(traj.t, traj.x, traj.u, traj.mass_kg, scene, 0.0).ok


def _polyline_dense_ok(points: np.ndarray, scene) -> bool:
    """Dense re-check of a straight-segment path (unit-time segments, zero force)."""
    seg = np.diff(points, axis=0)
    x = np.hstack([points, np.vstack([seg, np.zeros((1, 3))])])
    return dense_check(np.arange(len(points), dtype=float), x, np.zeros((len(seg), 3)), 1.0, scene, 0.0).ok


def _traj_metrics(traj: TranslationalTrajectory, problem, bound: float) -> dict[str, float]:
    return {
        "duration_s": traj.duration_s,
        "duration_ratio": traj.duration_s / bound,
        "impulse_Ns": traj.impulse_Ns(),
        "cost": traj.cost(problem.weights, problem.goal),
        "length_m": traj.path_length_m(),
    }


def run_scene(name: str, seeds: int, ompl_budget: float, rrtstar_budget: float) -> dict[str, list[dict]]:
    cfg = load_config(SCENES[name])
    problem, _ = build_problem(cfg, resolve_segment(cfg, None))
    scene = problem.checker.scene
    bound = minimum_time_lower_bound_s(problem.start, problem.goal, problem.force_limit_N,
                                       problem.velocity_limit_mps, problem.mass_kg)
    p = cfg.planner
    first = lqr_rrt_star_settings(cfg)
    anytime = replace(first, anytime=True, time_budget_s=rrtstar_budget, max_iterations=10**9)
    conn = LqrConnector(problem.mass_kg, p.steer_dt_s, problem.weights, p.steps(p.shortcut.max_horizon_s))
    labels = {"oacli LQR-RRT* + shortcut": first, "oacli LQR-RRT* anytime + shortcut": anytime}
    rows: dict[str, list[dict]] = {}
    for label in labels:
        rows[label] = []
        rows[label + " + polish"] = []
    rows["oacli kino-RRT"] = []
    for seed in range(seeds):
        for label, settings in labels.items():
            t0 = time.perf_counter()
            result = plan_lqr_rrt_star(problem, settings, np.random.default_rng([seed, PLAN_STREAM]))
            row: dict = {"seed": seed, "solved": result.solved, "ttfs_s": result.time_to_first_solution_s}
            prow: dict = dict(row)
            if result.solved:
                t1 = time.perf_counter()
                smooth = lqr_shortcut(result.trajectory, conn, problem.checker, problem.goal, problem.force_limit_N,
                                      problem.velocity_limit_mps, np.random.default_rng([seed, SMOOTH_STREAM]),
                                      tries=p.shortcut.tries, sample_dt_s=p.output_dt_s)
                t2 = time.perf_counter()
                row |= _traj_metrics(smooth.trajectory, problem, bound)
                row["raw_duration_s"] = result.trajectory.duration_s
                raw_ok = _dense_ok(result.trajectory, scene)
                row["dense_ok"] = raw_ok and _dense_ok(smooth.trajectory, scene)
                row["smooth_s"] = t2 - t1
                row["wall_s"] = t2 - t0
                polish = run_polish(cfg, smooth.trajectory, problem.checker, problem.goal,
                                    result.cost if p.polish.keep_cost else None)
                t3 = time.perf_counter()
                prow |= _traj_metrics(polish.trajectory, problem, bound)
                prow["dense_ok"] = raw_ok and _dense_ok(polish.trajectory, scene)
                prow["exact_ok"] = bool(problem.checker.is_free(polish.trajectory.pieces()))
                prow["smooth_s"] = t3 - t1
                prow["wall_s"] = t3 - t0
                prow["polish_status"] = polish.status
                prow["polish_iterations"] = len(polish.iterations)
                prow["length_before_polish_m"] = polish.length_before_m
            rows[label].append(row)
            rows[label + " + polish"].append(prow)
        kino = plan_kino_rrt(problem, kino_rrt_settings(cfg), np.random.default_rng([seed, PLAN_STREAM]))
        krow: dict = {"seed": seed, "solved": kino.solved, "ttfs_s": kino.time_to_first_solution_s}
        if kino.solved:
            krow |= _traj_metrics(kino.trajectory, problem, bound)
            krow["dense_ok"] = _dense_ok(kino.trajectory, scene)
        rows["oacli kino-RRT"].append(krow)
    if OMPL_ERROR is not None:
        return rows
    rows["OMPL control RRT"] = []
    rows["OMPL RRT* + simplifyMax"] = []
    lower, upper = problem.sample_lower[0], problem.sample_upper[0]

    def valid(pos: np.ndarray) -> bool:
        return bool(problem.checker.points_free(pos))

    for seed in range(seeds):
        ok, wall, path = ompl_control_rrt(problem.start, problem.goal, lower, upper, problem.mass_kg,
                                          problem.force_limit_N, problem.velocity_limit_mps, valid,
                                          time_budget_s=ompl_budget)
        row = {"seed": seed, "solved": ok, "ttfs_s": wall if ok else float("nan")}
        if ok:
            traj = TranslationalTrajectory(path.t, path.x, path.u, problem.mass_kg)
            row |= _traj_metrics(traj, problem, bound)
            row["dense_ok"] = _dense_ok(traj, scene)
        rows["OMPL control RRT"].append(row)
        ok, length, pts = ompl_rrt_star_length(problem.start[0:3], problem.goal[0:3], lower, upper, valid,
                                               time_budget_s=rrtstar_budget)
        row = {"seed": seed, "solved": ok, "ttfs_s": float("nan"), "length_m": length}
        if ok:
            row["dense_ok"] = _polyline_dense_ok(pts, scene)
        rows["OMPL RRT* + simplifyMax"].append(row)
    return rows


def summarise(rows: list[dict]) -> dict[str, float]:
    solved = [r for r in rows if r["solved"]]
    out = {
        "success": len(solved) / len(rows),
        "ttfs_p50_s": _median(r["ttfs_s"] for r in rows),
        "ttfs_p90_s": _p90(r["ttfs_s"] for r in rows),
        "dense_free": (sum(bool(r.get("dense_ok")) for r in solved) / len(solved)) if solved else float("nan"),
        "dense_free_count": f"{sum(bool(r.get('dense_ok')) for r in solved)}/{len(solved)}",
    }
    for key in ("duration_s", "duration_ratio", "impulse_Ns", "cost", "length_m", "smooth_s"):
        out[key] = _median(r.get(key, float("nan")) for r in solved)
    return out


def print_table(scene: str, bound: float, summaries: dict[str, dict[str, float]]) -> None:
    print(f"\n{scene}: minimum-time lower bound {bound:.2f} s")
    head = (f"{'planner':<44} {'success':>7} {'TTFS p50':>9} {'TTFS p90':>9} {'duration':>9} {'/bound':>7}"
            f" {'impulse':>8} {'LQR cost':>9} {'length':>8} {'dense-free':>10} {'smooth s':>9}")
    print(head)
    print("-" * len(head))
    for name, s in summaries.items():
        print(f"{name:<44} {s['success']:>7.0%} {s['ttfs_p50_s']:>9.3f} {s['ttfs_p90_s']:>9.3f} "
              f"{s['duration_s']:>9.1f} {s['duration_ratio']:>7.2f} {s['impulse_Ns']:>8.2f} {s['cost']:>9.3f} "
              f"{s['length_m']:>8.4f} {s['dense_free_count']:>10} {s['smooth_s']:>9.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="runs per planner and scene")
    parser.add_argument("--scenes", nargs="+", default=["S1", "S2"], choices=sorted(SCENES))
    parser.add_argument("--ompl-budget", type=float, default=10.0, help="OMPL control RRT time budget [s]")
    parser.add_argument("--rrtstar-budget", type=float, default=2.0, help="OMPL geometric RRT* time budget [s]")
    parser.add_argument("--json", type=Path, help="also write every row and summary as JSON")
    args = parser.parse_args()
    if OMPL_ERROR is not None:
        print(f"OMPL not available ({OMPL_ERROR}); install the bench extra. Running oacli's side only.",
              file=sys.stderr)
    else:
        seed_ompl(12345)
    report = {}
    for scene in args.scenes:
        rows = run_scene(scene, args.seeds, args.ompl_budget, args.rrtstar_budget)
        summaries = {name: summarise(r) for name, r in rows.items()}
        cfg = load_config(SCENES[scene])
        problem, _ = build_problem(cfg, resolve_segment(cfg, None))
        bound = minimum_time_lower_bound_s(problem.start, problem.goal, problem.force_limit_N,
                                           problem.velocity_limit_mps, problem.mass_kg)
        print_table(scene, bound, summaries)
        ours = summaries["oacli LQR-RRT* + shortcut"]
        best = summaries["oacli LQR-RRT* anytime + shortcut"]
        ours_p = summaries["oacli LQR-RRT* + shortcut + polish"]
        best_p = summaries["oacli LQR-RRT* anytime + shortcut + polish"]
        if "OMPL control RRT" in summaries:
            peer, geo = summaries["OMPL control RRT"], summaries["OMPL RRT* + simplifyMax"]
            print(f"  TTFS p50 oacli / OMPL control RRT: {ours['ttfs_p50_s'] / peer['ttfs_p50_s']:.3f}")
            print(f"  smoothed duration / bound: oacli {ours['duration_ratio']:.2f} "
                  f"(anytime {best['duration_ratio']:.2f}), OMPL control RRT {peer['duration_ratio']:.2f}")
            print(f"  path length / OMPL RRT* + simplifyMax: oacli first solution + shortcut "
                  f"{ours['length_m'] / geo['length_m']:.4f}, anytime + shortcut "
                  f"{best['length_m'] / geo['length_m']:.4f}")
            print(f"  path length / OMPL RRT* + simplifyMax with the polish: first solution + shortcut + polish "
                  f"{ours_p['length_m'] / geo['length_m']:.4f}, anytime + shortcut + polish "
                  f"{best_p['length_m'] / geo['length_m']:.4f}")
        print(f"  smoothed duration / bound with the polish: {ours_p['duration_ratio']:.2f} "
              f"(anytime {best_p['duration_ratio']:.2f})")
        report[scene] = {"lower_bound_s": bound, "summaries": summaries, "rows": rows}
    if args.json:
        args.json.write_text(json.dumps(report, indent=2, default=float))


if __name__ == "__main__":
    main()
