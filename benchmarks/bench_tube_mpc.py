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

Second table — the cost of the workspace rows (issue 8; target: within 1.3× of the step without them): the preset
controller (direct path, N = 5) with ``controller.position_constraints`` on (keep-in boxes shrunk by the robot and
the tube, braking rows; :mod:`oacli.control.workspace`) against the same controller with it off (positions free,
the problem before issue 8), and with the JEM plus one keep-out ellipsoid beside the path (its half-space normals
are Parameters in the constraint matrix: the compiled path updates A's values every step). For each seed a closed
loop (the preset's random force drawn from that seed) records the measured states; the controllers replay them,
all stepped at every state in an order that rotates from step to step, so each sees the same inputs and the same
machine load. Medians over all steps of all seeds; the ratio is with / without.

Third table — the lower limit (issue 13 item 4): the same tube MPC problem condensed (equalities eliminated, a
dense QP in the inputs, the free initial nominal state and the slacks; :mod:`oacli.control.condensed_qp`) and
solved by DAQP (dual active-set, the fastest dense QP solver on PyPI for small MPC problems), against our full
controller step (compiled direct-Clarabel path), at N = 5 and N = 40. A first pass records each step's parameter
values; the timed pass replays the states, the controller step and the DAQP solve of the same instance alternating
which goes first. The limit is the wall time of the condensing (matrix-vector products) plus the DAQP call; the
last column is the largest difference of the first nominal force between the two. A second line gives the process
CPU times (less sensitive to other load on a shared machine than the wall times). Needs ``pip install daqp``
(the ``bench`` extra); skipped without it.

Run: ``python benchmarks/bench_tube_mpc.py [--steps 200] [--seeds 5] [--only-workspace | --only-limit]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oacli.config import load_config
from oacli.control.tracking import TrackingWeights
from oacli.control.tube_mpc import TerminalWeights
from oacli.geometry import Ellipsoid, Scene
from oacli.model.limits import MotionLimits
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.stages.settings import tube_design_from_config
from oacli.stages.track import reference_from_config
from oacli.stages.track_tube import tube_controller_from_config

PRESET = Path(__file__).resolve().parents[1] / "configs" / "iss_reswarm_tube.yaml"


def limits_and_weights(cfg):
    robot, w = cfg.robot, cfg.controller.weights
    limits = MotionLimits(np.asarray(robot.force_limit_N), np.asarray(robot.torque_limit_Nm),
                            np.asarray(robot.velocity_limit_mps), np.asarray(robot.angular_velocity_limit_radps))
    weights = TrackingWeights(*(np.asarray(getattr(w, f)) for f in
                                ("position", "velocity", "attitude", "angular_velocity", "force", "torque")))
    return limits, weights


def record_states(cfg, reference, design, limits, weights, seed=None):
    """(t, x_measured) of a closed loop at the config's horizon (random force drawn from ``seed``)."""
    ctrl = tube_controller_from_config(cfg, reference, design, weights, limits)
    dist = cfg.truth.disturbance
    rng = np.random.default_rng(cfg.seed if seed is None else seed)
    tel = simulate(ctrl, reference.x[0], cfg.truth_params(), duration_s=reference.duration_s + 5.0,
                   control_period_s=cfg.controller.period_s, plant_period_s=cfg.simulation.plant_period_s,
                   input_limits=np.r_[limits.force_N, limits.torque_Nm], sensors=SensorNoise(),
                   disturbance=Disturbance(dist.bias, dist.random_bound), rng=rng)
    return tel.t_ctrl, tel.x_measured


def with_controller(cfg, **update):
    """``cfg`` with ``controller`` fields replaced."""
    return cfg.model_copy(update={"controller": cfg.controller.model_copy(update=update)})


#: A keep-out ellipsoid beside the A -> B path of the preset (0.6 m from it in x): its rows are active.
SIDE_ZONE = Ellipsoid.from_semi_axes([11.4, -8.6, 5.0], [0.15, 0.15, 0.15])


def workspace_overhead(cfg, reference, design, limits, weights, seeds: int, steps: int) -> None:
    """Second table of the module docstring."""
    off = with_controller(cfg, position_constraints=False)
    on = with_controller(cfg, position_constraints=True)
    # The problem as it was before the issue "safe by construction": the flight ε (absolute 0.005, facet growth
    # 0.05: a smaller Z polytope, fewer lasso rows) and free positions.
    flight_tube = cfg.controller.tube.model_copy(update={"rpi_epsilon_mode": "absolute", "rpi_epsilon": 0.005,
                                                         "lasso_facet_growth": 0.05})
    before = with_controller(cfg, position_constraints=False, tube=flight_tube)
    variants = {"without (free positions)": (off, None), "with (JEM keep-in)": (on, None),
                "with (JEM + keep-out)": (on, SIDE_ZONE), "before (flight ε, free)": (before, None)}
    designs = {name: design for name in variants}
    designs["before (flight ε, free)"] = tube_design_from_config(before)
    step_ms = {name: [] for name in variants}
    solve_ms = {name: [] for name in variants}
    rows, fails = {}, dict.fromkeys(variants, 0)
    for seed in range(seeds):
        times, states = record_states(on, reference, design, limits, weights, seed=seed)
        times, states = times[:steps], states[:steps]
        ctrls = {}
        for name, (c, zone) in variants.items():
            ctrl = tube_controller_from_config(c, reference, designs[name], weights, limits)
            if zone is not None:  # same controller, scene with the extra zone
                scene = c.scene()
                scene = Scene(scene.keep_in, (*scene.keep_out, zone), scene.frame)
                ctrl = type(ctrl)(reference, design, inertia_kgm2=np.asarray(c.robot.inertia_kgm2),
                                  horizon=ctrl.horizon,
                                  prediction_step_s=ctrl.step_s, weights=weights, limits=limits,
                                  terminal=_terminal(c), max_consecutive_failures=ctrl.max_failures,
                                  scene=scene, robot=ctrl.workspace.robot)
            ctrls[name] = ctrl
            rows[name] = ctrl.qp.compiled.n_constraints
        names = list(ctrls)
        for j, (t, x) in enumerate(zip(times, states, strict=True)):
            order = names[j % len(names):] + names[: j % len(names)]  # rotate who goes first
            for name in order:
                out = ctrls[name].step(float(t), x)
                if j:  # the first step builds caches: left out
                    step_ms[name].append(1e3 * out.info.step_time_s)
                    solve_ms[name].append(1e3 * out.info.solve_time_s)
                fails[name] += not out.info.success
    base = np.median(step_ms["without (free positions)"])
    print(f"\nworkspace rows, N = {cfg.controller.horizon}, {seeds} seeds x {steps} steps (medians; ratio = step / "
          "step without)")
    print(f"{'controller':<26} {'rows':>5} {'step p50 [ms]':>14} {'solver p50 [ms]':>16} {'ratio':>6} "
          f"{'not solved':>11}")
    for name in variants:
        med = np.median(step_ms[name])
        print(f"{name:<26} {rows[name]:>5} {med:>14.3f} {np.median(solve_ms[name]):>16.3f} {med / base:>6.2f} "
              f"{fails[name]:>11}")
    before_ms = np.median(step_ms["before (flight ε, free)"])
    print(f"with (JEM keep-in) / before (flight ε, free): {np.median(step_ms['with (JEM keep-in)']) / before_ms:.2f} "
          "(the issue's target: <= 1.3)")


def _terminal(cfg):
    term = cfg.controller.tube.terminal
    return None if term is None else TerminalWeights(np.asarray(term.position), np.asarray(term.velocity))


def daqp_limit(cfg, reference, design, limits, weights, times, states) -> None:
    """Third table of the module docstring."""
    try:
        import daqp  # noqa: F401

        from oacli.control.condensed_qp import CondensedQP
    except ImportError:
        print("\nlower limit: skipped (pip install daqp)")
        return
    print(f"\nlower limit: condensed QP + DAQP vs our controller step, {len(times) - 1} steps (medians; alternating)")
    print(f"{'N':>3} {'unknowns':>9} {'rows':>5} {'our step [ms]':>14} {'our solver [ms]':>16} {'DAQP limit [ms]':>16} "
          f"{'step/limit':>11} {'DAQP iter':>10} {'max |dv0| [N]':>14}")
    for horizon in (5, 40):
        cfg_n = with_controller(cfg, horizon=horizon)
        recorder = tube_controller_from_config(cfg_n, reference, design, weights, limits)
        ctrl = tube_controller_from_config(cfg_n, reference, design, weights, limits)
        ids = {p.name(): p.id for p in ctrl.qp.problem.parameters()}  # the recorder's Parameters -> ctrl's
        names = {p.id: p.name() for p in recorder.qp.problem.parameters()}
        instances = []
        for t, x in zip(times, states, strict=True):
            recorder.step(float(t), x)
            instances.append({ids[names[k]]: np.array(v) for k, v in recorder.qp._values.items()})
        limit = CondensedQP(ctrl.qp.compiled)
        v = ctrl.qp._vars["translation"].v
        ours, solver, lim, iters, dv, ours_cpu, lim_cpu = [], [], [], [], [], [], []
        ctrl.step(float(times[0]), states[0])  # first step builds caches: left out
        for j in range(1, len(times)):
            order = (0, 1) if j % 2 else (1, 0)
            for who in order:
                cpu = time.process_time()
                if who == 0:
                    out = ctrl.step(float(times[j]), states[j])
                    ours_cpu.append(time.process_time() - cpu)
                else:
                    ok, it, wall = limit.solve(instances[j])
                    lim_cpu.append(time.process_time() - cpu)
            ours.append(out.info.step_time_s)
            solver.append(out.info.solve_time_s)
            lim.append(wall)
            iters.append(it)
            if ok and out.info.success and ctrl.qp.compiled._x is not None:
                dv.append(float(np.max(np.abs(limit.value(v)[0] - ctrl.qp.compiled.value(v)[0]))))
        step_ms, lim_ms = 1e3 * np.median(ours), 1e3 * np.median(lim)
        step_cpu, lim_cpu_ms = 1e3 * np.median(ours_cpu), 1e3 * np.median(lim_cpu)
        print(f"{horizon:>3} {limit.n_unknowns:>9} {limit.n_rows:>5} {step_ms:>14.3f} {1e3 * np.median(solver):>16.3f} "
              f"{lim_ms:>16.3f} {step_ms / lim_ms:>11.2f} {np.median(iters):>10.0f} {max(dv, default=np.nan):>14.1e}")
        print(f"{'':>3} process CPU time: our step {step_cpu:.3f} ms, DAQP limit {lim_cpu_ms:.3f} ms, "
              f"step/limit {step_cpu / lim_cpu_ms:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="replayed steps per horizon (and per seed)")
    parser.add_argument("--seeds", type=int, default=5, help="closed loops replayed for the workspace table")
    parser.add_argument("--only-workspace", action="store_true", help="print the workspace table only")
    parser.add_argument("--only-limit", action="store_true", help="print the DAQP lower-limit table only")
    args = parser.parse_args()
    cfg = load_config(PRESET)
    reference = reference_from_config(cfg)
    limits, weights = limits_and_weights(cfg)
    t0 = time.perf_counter()
    design = tube_design_from_config(cfg)
    design_s = time.perf_counter() - t0
    if args.only_workspace:
        workspace_overhead(cfg, reference, design, limits, weights, args.seeds, args.steps)
        return
    times, states = record_states(cfg, reference, design, limits, weights)
    times, states = times[: args.steps], states[: args.steps]
    if args.only_limit:
        daqp_limit(cfg, reference, design, limits, weights, times, states)
        return
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
    workspace_overhead(cfg, reference, design, limits, weights, args.seeds, args.steps)
    daqp_limit(cfg, reference, design, limits, weights, times, states)


if __name__ == "__main__":
    main()
