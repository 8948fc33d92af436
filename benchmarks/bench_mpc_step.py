"""Benchmark: one MPC step at N = 5, 20, 40 — built once vs a naive problem rebuilt every step.

Three paths solve the same tracking MPC ([Doerr2021] Eq. 26, 12-state hover error model of Astrobee, Clarabel) from
the same sequence of initial states: the default compiled path (canonicalised once, Clarabel called directly
with updated data), the same DPP problem through ``problem.solve()``, and a naive formulation that rebuilds
the cvxpy problem every step, as a straight transcription of the equations would. Figures are medians over
the steps measured in this run, so the ratios are meaningful on a shared, noisy machine.

Second table — the cost of the workspace rows (issue 8) in the tracking MPC ``oacli track`` runs
(:class:`oacli.control.tracking.TrackingMPC`, compiled path): each preset's controller with
``controller.position_constraints`` on (keep-in box, braking and keep-out rows, soft) against the same controller
with it off (positions free, the problem before issue 8). A closed loop of the preset (rows on) records the
measured states; both controllers replay them, alternating which goes first, for ``--seeds`` seeds of the sensor
noise. Medians over all steps; the ratio is with / without. The last column is the largest sum of a step's
Lagrange multipliers of the position rows (``problem.solve()`` duals, steps whose rows are met), the figure the
exact-penalty weight ``oacli.control.mpc.POSITION_PENALTY`` (1e5) must exceed.

Run: ``python benchmarks/bench_mpc_step.py [--steps 40] [--seeds 3] [--only-workspace]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cvxpy as cp
import numpy as np

from oacli.config import load_config
from oacli.control.mpc import POSITION_PENALTY, LinearMPC
from oacli.control.tracking import TrackingMPC, TrackingWeights
from oacli.model.double_integrator import hover_error_model
from oacli.model.limits import MotionLimits
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.stages.track import reference_from_config
from oacli.stages.track_tube import workspace_arguments
from oacli.types import InertialParams

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

PARAMS = InertialParams(9.583788668, [0.153427995, 0.14271405, 0.162302759])
Q = np.array([10.0] * 3 + [1.0] * 3 + [10.0] * 3 + [1.0] * 3)
R = np.array([1.0] * 3 + [100.0] * 3)
U_MAX = np.array([0.452, 0.216, 0.257, 0.0452, 0.0216, 0.0257])
X_MAX = np.r_[[np.inf] * 3, [0.2] * 3, [np.inf] * 3, [0.1745] * 3]


def naive_step(a, b, p_terminal, horizon, x0, x_ref, u_ref):
    """The MPC written directly, rebuilt and canonicalised every call."""
    x = cp.Variable((horizon + 1, 12))
    u = cp.Variable((horizon, 6))
    cost = 0
    cons = [x[0] == x0]
    for k in range(horizon):
        cost += cp.quad_form(x[k] - x_ref[k], np.diag(Q)) + cp.quad_form(u[k] - u_ref[k], np.diag(R))
        cons += [x[k + 1] == a @ x[k] + b @ u[k], cp.abs(u[k]) <= U_MAX, cp.abs(x[k + 1, 3:6]) <= 0.2,
                 cp.abs(x[k + 1, 9:12]) <= 0.1745]
    cost += cp.quad_form(x[horizon] - x_ref[horizon], p_terminal)
    prob = cp.Problem(cp.Minimize(cost), cons)
    prob.solve(solver=cp.CLARABEL)
    return u.value[0]


def tracking_controller(cfg, reference, rows: bool) -> TrackingMPC:
    """The preset's standard MPC, with or without the workspace rows."""
    robot, w = cfg.robot, cfg.controller.weights
    limits = MotionLimits(np.asarray(robot.force_limit_N), np.asarray(robot.torque_limit_Nm),
                            np.asarray(robot.velocity_limit_mps), np.asarray(robot.angular_velocity_limit_radps))
    weights = TrackingWeights(*(np.asarray(getattr(w, f)) for f in
                                ("position", "velocity", "attitude", "angular_velocity", "force", "torque")))
    return TrackingMPC(reference, cfg.robot_params(), dt_s=cfg.controller.period_s, horizon=cfg.controller.horizon,
                       weights=weights, limits=limits, **(workspace_arguments(cfg) if rows else {}))


def closed_loop(cfg, reference, seed: int):
    ctrl = tracking_controller(cfg, reference, rows=True)
    dist = cfg.truth.disturbance
    tel = simulate(ctrl, reference.x[0], cfg.truth_params(), duration_s=reference.duration_s + 5.0,
                   control_period_s=cfg.controller.period_s, plant_period_s=cfg.simulation.plant_period_s,
                   input_limits=ctrl.limits.input, sensors=SensorNoise(**cfg.sensors.model_dump()),
                   disturbance=Disturbance(dist.bias, dist.random_bound), rng=np.random.default_rng(seed))
    return tel.t_ctrl, tel.x_measured


def largest_multiplier_sum(cfg, reference, times, states) -> float:
    """Largest Σ of a step's position-row multipliers over the replayed steps (``problem.solve()`` duals)."""
    ctrl = tracking_controller(cfg, reference, rows=True)
    ctrl.mpc.compiled = None  # problem.solve(): the duals are read from the cvxpy constraints
    slack = ctrl.mpc._pos_slack
    (nonneg,) = [c for c in ctrl.mpc.problem.constraints if [v.id for v in c.variables()] == [slack.id]]
    worst = 0.0
    for t, x in zip(times, states, strict=True):
        ctrl.step(float(t), x)
        if slack.value is not None and np.max(slack.value) < 1e-7:
            # Stationarity in σ_k: ρ_p = Σ_k λ + μ_k, μ the multiplier of σ ≥ 0.
            worst = max(worst, POSITION_PENALTY - float(np.min(nonneg.dual_value)))
    return worst


def workspace_overhead(steps: int, seeds: int) -> None:
    """Second table of the module docstring."""
    print(f"\ntracking MPC with / without workspace rows, {seeds} seeds x <= {steps} steps (medians)")
    print(f"{'preset':<16} {'N':>3} {'rows off':>9} {'rows on':>8} {'step off [ms]':>14} {'step on [ms]':>13} "
          f"{'ratio':>6} {'solver ratio':>13} {'max Σλ':>8}")
    for name in ("doerr2021", "iss_reswarm"):
        cfg = load_config(CONFIGS / f"{name}.yaml")
        reference = reference_from_config(cfg)
        step = {True: [], False: []}
        solve = {True: [], False: []}
        sizes = {}
        multipliers = 0.0
        for seed in range(seeds):
            times, states = closed_loop(cfg, reference, seed)
            times, states = times[:steps], states[:steps]
            ctrls = {on: tracking_controller(cfg, reference, on) for on in (False, True)}
            sizes = {on: c.mpc.compiled.n_constraints for on, c in ctrls.items()}
            for j, (t, x) in enumerate(zip(times, states, strict=True)):
                for on in ((False, True) if j % 2 else (True, False)):
                    out = ctrls[on].step(float(t), x)
                    if j:
                        step[on].append(out.info.step_time_s)
                        solve[on].append(out.info.solve_time_s)
            if seed == 0:
                multipliers = largest_multiplier_sum(cfg, reference, times, states)
        off, on = (1e3 * np.median(step[k]) for k in (False, True))
        solver_ratio = np.median(solve[True]) / np.median(solve[False])
        print(f"{name:<16} {cfg.controller.horizon:>3} {sizes[False]:>9} {sizes[True]:>8} {off:>14.2f} {on:>13.2f} "
              f"{on / off:>6.2f} {solver_ratio:>13.2f} {multipliers:>8.3g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="steps measured per horizon")
    parser.add_argument("--seeds", type=int, default=3, help="closed loops replayed for the workspace table")
    parser.add_argument("--only-workspace", action="store_true", help="print the workspace table only")
    args = parser.parse_args()
    if args.only_workspace:
        workspace_overhead(max(args.steps, 200), args.seeds)
        return
    rng = np.random.default_rng(0)
    a, b = hover_error_model(PARAMS, 0.2)
    print(f"{'N':>4} {'compiled p50 [ms]':>18} {'solve() p50 [ms]':>17} {'rebuilt p50 [ms]':>17}"
          f" {'rebuilt/compiled':>17} {'first solve [s]':>16} {'max |Δu|':>9}")
    for horizon in (5, 20, 40):
        x_ref = np.zeros((horizon + 1, 12))
        u_ref = np.zeros((horizon, 6))
        states = [rng.uniform(-1, 1, 12) * np.r_[[0.5] * 3, [0.05] * 3, [0.2] * 3, [0.02] * 3]
                  for _ in range(args.steps)]
        t0 = time.perf_counter()
        mpc = LinearMPC(a, b, Q, R, horizon, U_MAX, x_max=X_MAX)
        first = mpc.solve(states[0], x_ref, u_ref)
        first_s = time.perf_counter() - t0
        plain = LinearMPC(a, b, Q, R, horizon, U_MAX, x_max=X_MAX, fast=False)
        fast, mid, slow, diff = [], [], [], []
        for x0 in states:
            t = time.perf_counter()
            sol = mpc.solve(x0, x_ref, u_ref)
            fast.append(time.perf_counter() - t)
            t = time.perf_counter()
            plain.solve(x0, x_ref, u_ref)
            mid.append(time.perf_counter() - t)
            t = time.perf_counter()
            u_naive = naive_step(a, b, mpc.terminal, horizon, x0, x_ref, u_ref)
            slow.append(time.perf_counter() - t)
            diff.append(np.max(np.abs(sol.u[0] - u_naive)))
        assert first.info.success
        f, m, s = (1e3 * np.median(v) for v in (fast, mid, slow))
        print(f"{horizon:>4} {f:>18.2f} {m:>17.2f} {s:>17.2f} {s / f:>17.1f} {first_s:>16.3f} {max(diff):>9.1e}")
    workspace_overhead(max(args.steps, 200), args.seeds)


if __name__ == "__main__":
    main()
