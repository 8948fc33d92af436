"""Benchmark: one robust tube MPC controller step at N = 5, 20, 40 — direct Clarabel path vs ``problem.solve()``.

The controller is exactly what ``oacli track configs/iss_reswarm_tube.yaml`` runs (ReSWARM settings: nominal steps
of 1 s, 5 Hz control, u_max 0.15 N; tube on translation, standard MPC on attitude, one QP), with the horizon
overridden. A closed loop at N = 5 records the measured states; for every N two controllers (direct path and
``problem.solve()``, same cvxpy problem and Clarabel settings) replay that sequence, interleaved step by step, so
both see the same inputs and the same machine load. A "step" is everything ``TubeMPC.step`` does: reference
sampling, feed-forward, chart, the QP, fallback logic, the ancillary law and the record.

Figures: medians over the replayed steps [ms]; "first" is the wall time from building the controller (cvxpy
problem, canonicalisation, Clarabel set-up) to the end of its first step [s]; "design" is the offline tube design
(ancillary gain, RPI set, facet reduction, tightening) [s], once. Reference ([ReSWARM2023] Table 5): the flight tube
MPC step took 8.49 ms with qpOASES at N = 5 on a laptop.

Run: ``python benchmarks/bench_tube_mpc.py [--steps 200]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oacli.config import load_config
from oacli.control.tracking import TrackingLimits, TrackingWeights
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.stages.settings import tube_design_from_config
from oacli.stages.track import reference_from_config
from oacli.stages.track_tube import tube_controller_from_config

PRESET = Path(__file__).resolve().parents[1] / "configs" / "iss_reswarm_tube.yaml"


def limits_and_weights(cfg):
    robot, w = cfg.robot, cfg.controller.weights
    limits = TrackingLimits(np.asarray(robot.force_limit_N), np.asarray(robot.torque_limit_Nm),
                            np.asarray(robot.velocity_limit_mps), np.asarray(robot.angular_velocity_limit_radps))
    weights = TrackingWeights(*(np.asarray(getattr(w, f)) for f in
                                ("position", "velocity", "attitude", "angular_velocity", "force", "torque")))
    return limits, weights


def record_states(cfg, reference, design, limits, weights):
    """(t, x_measured) of a closed loop at the preset's horizon."""
    ctrl = tube_controller_from_config(cfg, reference, design, weights, limits)
    dist = cfg.truth.disturbance
    tel = simulate(ctrl, reference.x[0], cfg.truth_params(), duration_s=reference.duration_s + 5.0,
                   control_period_s=cfg.controller.period_s, plant_period_s=cfg.simulation.plant_period_s,
                   input_limits=np.r_[limits.force_N, limits.torque_Nm], sensors=SensorNoise(),
                   disturbance=Disturbance(dist.bias, dist.random_bound), rng=np.random.default_rng(cfg.seed))
    return tel.t_ctrl, tel.x_measured


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="replayed steps per horizon")
    args = parser.parse_args()
    cfg = load_config(PRESET)
    reference = reference_from_config(cfg)
    limits, weights = limits_and_weights(cfg)
    t0 = time.perf_counter()
    design = tube_design_from_config(cfg)
    design_s = time.perf_counter() - t0
    times, states = record_states(cfg, reference, design, limits, weights)
    times, states = times[: args.steps], states[: args.steps]
    print(f"tube design (3 axes: K, RPI s={design.axes[0].rpi.s}, {design.axes[0].reduction.facets_before} -> "
          f"{design.axes[0].reduction.facets_after} facets, tightening): {design_s:.3f} s; {len(times)} steps")
    header = (f"{'N':>3} {'vars':>5} {'rows':>5} {'direct p50 [ms]':>16} {'solver p50':>11} {'solve() p50 [ms]':>17}"
              f" {'ratio':>6} {'first direct [s]':>17} {'first solve() [s]':>18} {'max |du|':>9}")
    print(header)
    for horizon in (5, 20, 40):
        cfg_n = cfg.model_copy(update={"controller": cfg.controller.model_copy(update={"horizon": horizon})})
        ctrls, first = {}, {}
        for path in ("direct", "cvxpy"):
            tube = cfg_n.controller.tube.model_copy(update={"solver": path})
            cfg_p = cfg_n.model_copy(update={"controller": cfg_n.controller.model_copy(update={"tube": tube})})
            start = time.perf_counter()
            ctrls[path] = tube_controller_from_config(cfg_p, reference, design, weights, limits)
            ctrls[path].step(float(times[0]), states[0])
            first[path] = time.perf_counter() - start
        fast, slow, solver, du = [], [], [], []
        for t, x in zip(times[1:], states[1:], strict=True):
            a = ctrls["direct"].step(float(t), x)
            b = ctrls["cvxpy"].step(float(t), x)
            fast.append(a.info.step_time_s)
            solver.append(a.info.solve_time_s)
            slow.append(b.info.step_time_s)
            du.append(float(np.max(np.abs(a.u - b.u))))
        compiled = ctrls["direct"].qp.compiled
        f, s = 1e3 * np.median(fast), 1e3 * np.median(slow)
        print(f"{horizon:>3} {compiled.n_variables:>5} {compiled.n_constraints:>5} {f:>16.3f} "
              f"{1e3 * np.median(solver):>11.3f} {s:>17.3f} {s / f:>6.2f} {first['direct']:>17.3f} "
              f"{first['cvxpy']:>18.3f} {max(du):>9.1e}")


if __name__ == "__main__":
    main()
