"""Benchmark: one MPC step at N = 5, 20, 40 — built once vs a naive problem rebuilt every step.

Three paths solve the same tracking MPC (Doerr Eq. 26, 12-state hover error model of Astrobee, Clarabel) from
the same sequence of initial states: the default compiled path (canonicalised once, Clarabel called directly
with updated data), the same DPP problem through ``problem.solve()``, and a naive formulation that rebuilds
the cvxpy problem every step, as a straight transcription of the equations would. Figures are medians over
the steps measured in this run, so the ratios are meaningful on a shared, noisy machine.

Run: ``python benchmarks/bench_mpc_step.py [--steps 40]``
"""

from __future__ import annotations

import argparse
import time

import cvxpy as cp
import numpy as np

from oacli.control.mpc import LinearMPC
from oacli.model.double_integrator import hover_error_model
from oacli.types import InertialParams

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="steps measured per horizon")
    args = parser.parse_args()
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


if __name__ == "__main__":
    main()
