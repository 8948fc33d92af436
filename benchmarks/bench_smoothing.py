"""Benchmark: where ``oacli smooth`` spends its time, and the polish's two subproblem paths side by side.

For each scene of :mod:`benchmarks.bench_planners` (S1, S2, ISS A-B, ISS C-A) and seed: the LQR-RRT* first
solution (not timed here), then the LQR shortcutting exactly as the stage runs it (its connector built inside the
timing), then the polish with the subproblem assembled directly for Clarabel (``backend='direct'``, the default,
with its working set of limit, trust-region and cost-cap rows), the same with every row in every solve
(``active_set=False``) and with the cvxpy/DPP reference (``backend='cvxpy'``), rotating which goes first. Prints
per scene the medians of the shortcut time, of the three polish times and their ratios, and the polished length
and duration (they solve the same subproblems: the lengths agree to ~1e-7).

Run from the repository root: ``taskset -c 1 python -m benchmarks.bench_smoothing [--seeds 3] [--scenes S1 S2]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.bench_planners import SCENE_NAMES, scene_config  # noqa: E402
from oacli.planning.lqr_rrt_star import plan_lqr_rrt_star  # noqa: E402
from oacli.planning.polish import polish_trajectory  # noqa: E402
from oacli.planning.shortcut import lqr_shortcut  # noqa: E402
from oacli.stages.design_limits import planner_design_limits  # noqa: E402
from oacli.stages.plan import PLAN_STREAM, SMOOTH_STREAM, build_problem, resolve_segment  # noqa: E402
from oacli.stages.settings import (  # noqa: E402
    cost_weights,
    lqr_rrt_star_settings,
    polish_settings,
    shortcut_connector,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--scenes", nargs="+", default=list(SCENE_NAMES), choices=SCENE_NAMES)
    args = parser.parse_args()
    print(f"{'scene':<8} {'seeds':>5} {'shortcut s':>10} {'polish direct s':>15} {'all rows s':>10} "
          f"{'polish cvxpy s':>14} {'all rows/direct':>15} {'cvxpy/direct':>12} {'length direct':>13} "
          f"{'length all rows':>15} {'length cvxpy':>12} {'duration':>8}")
    for name in args.scenes:
        cfg = scene_config(name)
        problem, _ = build_problem(cfg, resolve_segment(cfg, None))
        p = cfg.planner
        lim = planner_design_limits(cfg).limits
        times: dict[str, list[float]] = {"shortcut": [], "direct": [], "all_rows": [], "cvxpy": []}
        lengths: dict[str, list[float]] = {"direct": [], "all_rows": [], "cvxpy": []}
        durations: list[float] = []
        for seed in range(args.seeds):
            plan = plan_lqr_rrt_star(problem, lqr_rrt_star_settings(cfg), np.random.default_rng([seed, PLAN_STREAM]))
            if not plan.solved:
                continue
            t0 = time.perf_counter()
            sc = lqr_shortcut(plan.trajectory, shortcut_connector(cfg), problem.checker, problem.goal, lim.force_N,
                              lim.velocity_mps, np.random.default_rng([seed, SMOOTH_STREAM]), tries=p.shortcut.tries,
                              sample_dt_s=p.output_dt_s)
            times["shortcut"].append(time.perf_counter() - t0)
            variants = ("direct", "all_rows", "cvxpy")
            order = variants[seed % 3:] + variants[:seed % 3]
            for backend in order:
                settings = replace(polish_settings(cfg), backend="cvxpy" if backend == "cvxpy" else "direct",
                                   active_set=backend == "direct")
                t0 = time.perf_counter()
                res = polish_trajectory(sc.trajectory, problem.checker, problem.goal, lim.force_N, lim.velocity_mps,
                                        cost_weights(cfg), dt_s=p.output_dt_s,
                                        cost_cap=plan.cost if p.polish.keep_cost else None,
                                        settings=settings)
                times[backend].append(time.perf_counter() - t0)
                lengths[backend].append(res.length_after_m)
            durations.append(res.duration_after_s)
        med = {k: float(np.median(v)) for k, v in times.items()}
        print(f"{name:<8} {len(durations):>5} {med['shortcut']:>10.3f} {med['direct']:>15.3f} {med['all_rows']:>10.3f} "
              f"{med['cvxpy']:>14.3f} {med['all_rows'] / med['direct']:>15.2f} {med['cvxpy'] / med['direct']:>12.2f} "
              f"{np.median(lengths['direct']):>13.5f} {np.median(lengths['all_rows']):>15.5f} "
              f"{np.median(lengths['cvxpy']):>12.5f} {np.median(durations):>8.1f}")


if __name__ == "__main__":
    main()
