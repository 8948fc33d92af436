"""Benchmark: information of the offline excitation design vs the flown RATTLE files, and planner/design speed.

Information (issue 5 target: tr F⁻¹ of our design ≤ 0.5 × the best flown ``excitation_iss_*`` trajectory). The ISS
problem of the flown files: B (10.8, -7.75, 5.2) → C (10.8, -7.75, 4.3), 60 s, |F| ≤ 0.25 N, |τ| ≤ 0.025 N·m,
|ω| ≤ 0.175 rad/s, |v| ≤ 0.15 m/s, quaternion (0, 0, -0.7071, 0.7071) at both ends (configs/iss_reswarm.yaml,
which also keeps 0.1 m from the JEM walls). Everything is evaluated in this run with the same Fisher information
([Doerr2021] Eq. 29, measurements every 0.5 s as in the files) and the same noise model, RATTLE's sequential estimator
(rattle ``param_est``: R = diag(5e-6 ×3 velocity, 2.5e-4 ×3 angular velocity, 5e-6 ×3 linear acceleration), read as
variances since the filter forms S = H P Hᵀ + R), at θ = Astrobee with object ([Doerr2021] Table 1: 15 kg,
0.1464/0.1376/0.1604 kg·m²). The flown files' inputs (force world frame, torque body frame; SOURCE.md) are rolled out
on that model from their first sample.

Speed (targets: one replan of the information-aware planner at N = 40 ≤ 0.3 s — ACADO RTI SQP took 0.929 s,
[ReSWARM2023] Table 5 — and the offline design ≤ 30 s). The planner baseline measured in the same run is the same
planner with its cvxpy problem rebuilt at every replan.

Speed of the offline design on the default mission (issue 9 target: the ``segment-2/excite`` stage ≤ 2.5 s on one
core): the mission's segment-2 problem (configs/mission_iss.yaml, B → C, 120 steps) designed by the reference path
(``design_excitation(..., reference=True)``: generic rollouts and adjoint, ``problem.solve()`` per subproblem, every
step judged whole) and by the fast path (split translation/rotation rollouts and batched adjoint, compiled Clarabel
subproblem, force part of a failed step judged on its own), alternating per repeat, with the time ratio, both
criteria (tr F⁻¹), both designs' dense feasibility, and the whole stage (outputs included) on the fast path.

Run: ``python benchmarks/bench_excitation.py [--replans 10] [--repeats 3] [--only mission]`` from the repository
root (``taskset -c 1`` to pin one core). ``--compare-tree DIR`` (repeatable) times this checkout's design and stage
against another oacli checkout (e.g. ``git worktree add /tmp/base main``), each in fresh processes, alternating per
repeat, with both criteria. The information table needs the RATTLE data ([RattleData], docs/references.md) at
../shared/data (skipped with a message when absent).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from oacli.config import load_config
from oacli.excitation.design import design_excitation
from oacli.excitation.fim_gradient import criterion_value, scaling_matrix
from oacli.excitation.information import (
    PARAM_NAMES,
    cramer_rao_std,
    fisher_information,
    propagate_with_sensitivities,
)
from oacli.excitation.problem import collision_free
from oacli.excitation.rattle import InformationAwarePlanner, InformationWeighting
from oacli.io.reference_files import load_csv
from oacli.mission.configs import Handoff, stage_config
from oacli.mission.layout import stage_by_key
from oacli.stages.design_limits import motion_limits
from oacli.stages.excite import excitation_problem, run_excite
from oacli.stages.settings import scp_settings

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "rattle-iros-2022" / "info-trajectories"
THETA = np.array([15.0, 0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1, Astrobee with object
ACADO_REPLAN_S = 0.929  # [ReSWARM2023] Table 5, information-aware local planner, N = 40, ACADO RTI SQP


def _fmt(v: float) -> str:
    return "inf" if not np.isfinite(v) else f"{v:.4g}"


def information_table(cfg) -> None:
    problem = excitation_problem(cfg)
    assert np.allclose(problem.theta, THETA), "the preset's prior should be [Doerr2021] Table 1"
    t0 = time.perf_counter()
    design = design_excitation(problem, scp_settings(cfg))
    wall = time.perf_counter() - t0
    rel = scaling_matrix(THETA, "relative")
    rows = []
    design_u = design.trajectory.u[:-1]
    rows.append(("oacli design (SCP)", design.fim, np.sum(design_u**2), design.terminal_residual["position_m"]))
    if not DATA.exists():
        print(f"information table skipped: the flown RATTLE files are not at {DATA}")
    else:
        for path in sorted(DATA.glob("excitation_iss_*.csv"), key=lambda p: int(p.stem.rsplit("_", 1)[1])):
            ref = load_csv(path, sample_period_s=0.5)
            dt = float(ref.t[1] - ref.t[0])
            u = ref.u[:-1]
            fim = fisher_information(ref.x[0], u, THETA, dt, problem.measurement)
            x, _ = propagate_with_sensitivities(ref.x[0], u, THETA, dt)
            end = float(np.max(np.abs(x[-1, 0:3] - problem.goal[0:3])))
            rows.append((f"flown {path.name}", fim, np.sum(u**2), end))
    print(f"\nInformation: ISS B→C, 60 s, {problem.steps} measurements, θ = {THETA.tolist()}, RATTLE noise model")
    head = (f"{'trajectory':<28} {'tr F⁻¹':>10} {'tr F⁻¹ rel':>11} "
            + " ".join(f"{'σ_' + n.split('_')[0] + ' %':>9}" for n in PARAM_NAMES)
            + f" {'Σ u²':>8} {'end to C [m]':>12}")
    print(head)
    for name, fim, energy, end in rows:
        crb = cramer_rao_std(fim, THETA)
        pct = 100 * crb / THETA
        a_abs, a_rel = criterion_value(fim, "A", np.eye(4)), criterion_value(fim, "A", rel)
        print(f"{name:<28} {_fmt(a_abs):>10} {_fmt(a_rel):>11} " + " ".join(f"{_fmt(p):>9}" for p in pct)
              + f" {energy:>8.3f} {end:>12.3g}")
    flown = [criterion_value(f, "A", np.eye(4)) for name, f, _, _ in rows[1:]]
    if flown:
        best = min(flown)
        ours = criterion_value(design.fim, "A", np.eye(4))
        print(f"ratio design / best flown tr F⁻¹: {ours / best:.3f}  (target ≤ 0.5)")
    print(f"offline design: {len(design.iterations)} SCP iterations, wall time {wall:.2f} s (target ≤ 30 s); "
          f"stop: {design.stop_reason}; collision-free: {design.collision_free}")


def replan_speed(cfg, replans: int) -> None:
    exc = cfg.excitation
    rcfg = exc.rattle
    problem = excitation_problem(cfg)
    limits = motion_limits(cfg, rattle=True)
    weighting = InformationWeighting(np.array(rcfg.gamma0), np.array(rcfg.floor), rcfg.alpha, rcfg.beta)
    rng = np.random.default_rng(0)

    def make():
        return InformationAwarePlanner(problem.goal, horizon=rcfg.horizon, dt_s=rcfg.step_s, limits=limits,
                                       measurement=problem.measurement, scene=problem.scene,
                                       iterations=rcfg.iterations, penalty=rcfg.penalty, clearance_m=exc.clearance_m)

    # States along the way from B to C, uncertainty shrinking from the prior towards the floors.
    cases = []
    for i in range(replans):
        s = i / max(replans - 1, 1)
        x0 = problem.start.copy()
        x0[0:3] = (1 - s) * problem.start[0:3] + s * problem.goal[0:3] + rng.normal(0, 0.02, 3)
        x0[3:6] = rng.uniform(-0.03, 0.03, 3)
        x0[10:13] = rng.uniform(-0.05, 0.05, 3)
        std = np.sqrt(np.diag(exc.prior.covariance())) * 10.0 ** (-2.0 * s)
        cases.append((x0, std, weighting.weights(std)))
    planner = make()
    t0 = time.perf_counter()
    planner.plan(cases[0][0], THETA, cases[0][1], cases[0][2])
    first = time.perf_counter() - t0
    once = []
    for x0, std, gamma in cases:
        t0 = time.perf_counter()
        planner.plan(x0, THETA, std, gamma)
        once.append(time.perf_counter() - t0)
    rebuilt = []
    for x0, std, gamma in cases[: max(3, replans // 3)]:
        t0 = time.perf_counter()
        make().plan(x0, THETA, std, gamma)
        rebuilt.append(time.perf_counter() - t0)
    p50 = float(np.median(once))
    print(f"\nReplan of the information-aware planner, N = {rcfg.horizon} × {rcfg.step_s} s, {rcfg.iterations} SCP "
          f"iterations, {replans} replans")
    print(f"{'variant':<34} {'p50 [s]':>8} {'max [s]':>8} {'vs ACADO 0.929 s':>17}")
    print(f"{'built once (DPP), first call':<34} {first:>8.3f} {first:>8.3f} {ACADO_REPLAN_S / first:>16.2f}x")
    print(f"{'built once (DPP)':<34} {p50:>8.3f} {max(once):>8.3f} {ACADO_REPLAN_S / p50:>16.2f}x")
    print(f"{'rebuilt every replan (baseline)':<34} {np.median(rebuilt):>8.3f} {max(rebuilt):>8.3f} "
          f"{ACADO_REPLAN_S / np.median(rebuilt):>16.2f}x")
    print(f"built once vs rebuilt: {np.median(rebuilt) / p50:.2f}x faster; target p50 ≤ 0.3 s")


def _design_check(problem, design) -> str:
    """Dense feasibility of a design: keep-in/keep-out between samples, limits, end conditions."""
    traj = design.trajectory
    x, u = traj.x, traj.u[:-1]
    lim = problem.limits
    tol = 1 + 1e-9
    within = bool(np.all(np.abs(u) <= lim.input * tol) and np.all(np.abs(x[:, 3:6]) <= lim.velocity_mps * tol)
                  and np.all(np.abs(x[:, 10:13]) <= lim.angular_velocity_radps * tol))
    clear = collision_free(problem.scene, x, u, problem.dt, problem.theta, substeps=50)
    res = design.terminal_residual
    t = problem.terminal
    end = (res["position_m"] <= t.position_m * tol and res["velocity_mps"] <= t.velocity_mps * (1 + 1e-6)
           and res["attitude_rad"] <= t.attitude_rad * tol
           and res["angular_velocity_radps"] <= t.angular_velocity_radps * tol)
    return f"limits {'ok' if within else 'VIOLATED'}, dense keep-in/out {'ok' if clear else 'VIOLATED'}, " \
           f"end {'ok' if end else 'MISSED'}"


def mission_design_speed(mission_config: Path, repeats: int) -> None:
    """Reference vs fast design of the mission's segment-2 excitation, alternating per repeat (same process)."""
    cfg = stage_config(load_config(mission_config), stage_by_key("segment-2/excite"), Handoff())
    problem = excitation_problem(cfg)
    settings = scp_settings(cfg)
    print(f"\nOffline design, mission segment 2 ({mission_config.name}): {problem.steps} steps of {problem.dt} s, "
          f"criterion {problem.criterion} ({problem.scaling}), max {settings.max_iterations} SCP iterations, "
          f"tolerance {settings.tolerance}")
    print(f"{'repeat':<7} {'path':<10} {'wall [s]':>9} {'cpu [s]':>8} {'SCP it.':>8} {'accepted':>9} "
          f"{'tr F⁻¹':>14}  stop")
    rows: dict[str, list[tuple[float, float]]] = {"reference": [], "fast": []}
    designs = {}
    for r in range(repeats):
        order = ("reference", "fast") if r % 2 == 0 else ("fast", "reference")
        for path in order:
            t0, c0 = time.perf_counter(), time.process_time()
            d = design_excitation(problem, settings, rng=np.random.default_rng(cfg.seed), reference=path == "reference")
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            rows[path].append((wall, cpu))
            designs[path] = d
            print(f"{r + 1:<7} {path:<10} {wall:>9.2f} {cpu:>8.2f} {len(d.iterations):>8} {d.accepted_iterations:>9} "
                  f"{d.criterion_final:>14.10g}  {d.stop_reason}")
    ref_wall = float(np.median([w for w, _ in rows["reference"]]))
    fast_wall = float(np.median([w for w, _ in rows["fast"]]))
    ref_cpu = float(np.median([c for _, c in rows["reference"]]))
    fast_cpu = float(np.median([c for _, c in rows["fast"]]))
    j_ref, j_fast = designs["reference"].criterion_final, designs["fast"].criterion_final
    print(f"median wall: reference {ref_wall:.2f} s, fast {fast_wall:.2f} s -> {ref_wall / fast_wall:.1f}x "
          f"(cpu {ref_cpu:.2f} s vs {fast_cpu:.2f} s -> {ref_cpu / fast_cpu:.1f}x)")
    print(f"criterion tr F⁻¹: reference {j_ref:.10g}, fast {j_fast:.10g} (fast/reference − 1 = "
          f"{j_fast / j_ref - 1:+.2e}; SCP tolerance {settings.tolerance} of the merit ≈ "
          f"{settings.tolerance * designs['fast'].criterion_initial / j_ref:.1e} of tr F⁻¹)")
    for path, d in designs.items():
        print(f"{path:<10} {_design_check(problem, d)}")
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        run_excite(cfg, out=Path(tmp) / "excite")
        stage, stage_cpu = time.perf_counter() - t0, time.process_time() - c0
        design_s = json.loads((Path(tmp) / "excite" / "summary.json").read_text())["solve_time_s"]
    print(f"segment-2/excite stage on the fast path (design + MCAP, recording, plots): {stage:.2f} s wall, "
          f"{stage_cpu:.2f} s cpu, of which the design {design_s:.2f} s wall (target ≤ 2.5 s on an idle core)")


def _child_design(mission_config: Path) -> None:
    """One measured design and stage of the mission's segment-2 excitation in this process (``--child``): prints JSON.

    The stage runs once first (imports, first-call caches, as in a mission where earlier stages ran), then the
    design and the whole stage are measured fresh (the subproblem is built and canonicalised again each time).
    """
    cfg = stage_config(load_config(mission_config), stage_by_key("segment-2/excite"), Handoff())
    problem = excitation_problem(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        run_excite(cfg, out=Path(tmp) / "warm")
        t0, c0 = time.perf_counter(), time.process_time()
        d = design_excitation(problem, scp_settings(cfg), rng=np.random.default_rng(cfg.seed))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        t0, c0 = time.perf_counter(), time.process_time()
        run_excite(cfg, out=Path(tmp) / "excite")
        stage, stage_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(json.dumps({"wall": wall, "cpu": cpu, "stage_wall": stage, "stage_cpu": stage_cpu,
                      "criterion": d.criterion_final, "iterations": len(d.iterations),
                      "accepted": d.accepted_iterations, "stop": d.stop_reason}))


def compare_trees(trees: list[Path], mission_config: Path, repeats: int) -> None:
    """This checkout against other checkouts of oacli (e.g. main's), the same benchmark in fresh processes,
    alternating the order per repeat; the timings are of the mission's segment-2 design and its whole stage."""
    import subprocess
    import sys

    sides = [("this", REPO), *((str(t), t.resolve()) for t in trees)]
    rows: dict[str, list[dict]] = {name: [] for name, _ in sides}
    print(f"\nOffline design of the mission's segment 2, this checkout vs {', '.join(str(t) for t in trees)} "
          f"({repeats} repeats, alternating; fresh process each)")
    print(f"{'repeat':<7} {'tree':<28} {'design wall':>11} {'cpu':>6} {'stage wall':>10} {'cpu':>6} {'SCP it.':>7} "
          f"{'tr F⁻¹':>16}")
    for r in range(repeats):
        for name, tree in (sides if r % 2 == 0 else sides[::-1]):
            env = {**__import__("os").environ, "PYTHONPATH": str(tree)}
            out = subprocess.run([sys.executable, __file__, "--child", "--mission-config", str(mission_config)],
                                 env=env, cwd=tree, capture_output=True, text=True, check=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            rows[name].append(row)
            print(f"{r + 1:<7} {name[-28:]:<28} {row['wall']:>11.3f} {row['cpu']:>6.3f} {row['stage_wall']:>10.3f} "
                  f"{row['stage_cpu']:>6.3f} {row['iterations']:>7} {row['criterion']:>16.10g}")
    base = rows["this"]
    for name, _ in sides[1:]:
        other = rows[name]
        med = {k: (float(np.median([b[k] for b in base])), float(np.median([o[k] for o in other])))
               for k in ("wall", "cpu", "stage_wall", "stage_cpu")}
        j_this, j_other = base[-1]["criterion"], other[-1]["criterion"]
        (w, w_o), (c, c_o), (sw, sw_o), (sc, sc_o) = (med[k] for k in ("wall", "cpu", "stage_wall", "stage_cpu"))
        print(f"median vs {name}: design wall {w:.3f} s vs {w_o:.3f} s ({w_o / w:.2f}x), cpu {c:.3f} vs {c_o:.3f} s; "
              f"stage wall {sw:.3f} vs {sw_o:.3f} s ({sw_o / sw:.2f}x), cpu {sc:.3f} vs {sc_o:.3f} s")
        print(f"tr F⁻¹: this {j_this:.10g}, {name} {j_other:.10g} (this/other − 1 = {j_this / j_other - 1:+.2e})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replans", type=int, default=10, help="replans timed")
    parser.add_argument("--repeats", type=int, default=3, help="alternating reference/fast design repeats")
    parser.add_argument("--config", type=Path, default=REPO / "configs" / "iss_reswarm.yaml")
    parser.add_argument("--mission-config", type=Path, default=REPO / "configs" / "mission_iss.yaml")
    parser.add_argument("--only", choices=("table", "replan", "mission"), help="run one section only")
    parser.add_argument("--compare-tree", type=Path, action="append", default=[],
                        help="another oacli checkout (e.g. a worktree of main) to time against this one, fresh "
                             "processes alternating per repeat (with --only mission: instead of reference vs fast)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child_design(args.mission_config)
        return
    if args.compare_tree:
        compare_trees(args.compare_tree, args.mission_config, args.repeats)
        if args.only == "mission":
            return
    cfg = load_config(args.config)
    if args.only in (None, "mission"):
        mission_design_speed(args.mission_config, args.repeats)
    if args.only in (None, "table"):
        information_table(cfg)
    if args.only in (None, "replan"):
        replan_speed(cfg, args.replans)


if __name__ == "__main__":
    main()
