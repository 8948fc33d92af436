"""Benchmark: information of the offline excitation design vs the flown RATTLE files, and planner/design speed.

Information (issue 5 target: tr F⁻¹ of our design ≤ 0.5 × the best flown ``excitation_iss_*`` trajectory). The ISS
problem of the flown files: B (10.8, -7.75, 5.2) → C (10.8, -7.75, 4.3), 60 s, |F| ≤ 0.25 N, |τ| ≤ 0.025 N·m,
|ω| ≤ 0.175 rad/s, |v| ≤ 0.15 m/s, quaternion (0, 0, -0.7071, 0.7071) at both ends (configs/iss_reswarm.yaml,
which also keeps 0.1 m from the JEM walls). Everything is evaluated in this run with the same Fisher information
(Doerr Eq. 29, measurements every 0.5 s as in the files) and the same noise model, RATTLE's sequential estimator
(rattle ``param_est``: R = diag(5e-6 ×3 velocity, 2.5e-4 ×3 angular velocity, 5e-6 ×3 linear acceleration), read as
variances since the filter forms S = H P Hᵀ + R), at θ = Astrobee with object ([Doerr2021] Table 1: 15 kg,
0.1464/0.1376/0.1604 kg·m²). The flown files' inputs (force world frame, torque body frame; SOURCE.md) are rolled out
on that model from their first sample.

Speed (targets: one replan of the information-aware planner at N = 40 ≤ 0.3 s — ACADO RTI SQP took 0.929 s,
[ReSWARM2023] Table 5 — and the offline design ≤ 30 s). The planner baseline measured in the same run is the same
planner with its cvxpy problem rebuilt at every replan.

Run: ``python benchmarks/bench_excitation.py [--replans 10]`` from the repository root. The information table needs
the RATTLE data ([RattleData], docs/references.md) at ../shared/data (skipped with a message when absent).
"""

from __future__ import annotations

import argparse
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
from oacli.excitation.rattle import InformationAwarePlanner, InformationWeighting
from oacli.io.reference_files import load_csv
from oacli.stages.excite import excitation_problem
from oacli.stages.settings import motion_limits, scp_settings

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replans", type=int, default=10, help="replans timed")
    parser.add_argument("--config", type=Path, default=REPO / "configs" / "iss_reswarm.yaml")
    args = parser.parse_args()
    cfg = load_config(args.config)
    information_table(cfg)
    replan_speed(cfg, args.replans)


if __name__ == "__main__":
    main()
