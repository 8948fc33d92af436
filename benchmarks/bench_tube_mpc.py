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
controller step (compiled direct-Clarabel path), at N = 5 and N = 40. The limit is DAQP at its fastest honest
set-up: the condensing maps formed once (one matrix-vector product per solve), ``daqp.Model`` set up once (its
factorisation of H), and a hot start from the previous step's working set, as an active-set MPC runs. Two more
lines give DAQP without the hot start (cached set-up, empty working set) and DAQP as this table measured it before
(``daqp.solve`` per call, which sets up and factorises every call). A first pass records each step's parameter
values; the timed pass replays the states, stepping the controller and solving the same instance with each of the
three DAQP set-ups, the four in an order that rotates from step to step. The limit's time is the wall time of the
data update (condensing) and the DAQP solve; DAQP's set-up and the first instance are left out, as our first step
is. The last column is the largest difference of the first nominal force between the limit and our solution. A
second line gives the process CPU times (less sensitive to other load on a shared machine than the wall times).
Needs ``pip install daqp`` (the ``bench`` extra); skipped without it.

``--against SRC`` times our step (N = 5 and 40, the same replay) on another source tree (e.g. a worktree of main)
and on this one, each run in its own subprocess with ``PYTHONPATH`` set, alternating for ``--repeats`` repeats, and
prints both sides' medians of the wall and process CPU times and their ratio.

Run: ``python benchmarks/bench_tube_mpc.py [--steps 200] [--seeds 5] [--only-workspace | --only-limit]
[--against SRC [--repeats 5]]``
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
        import daqp

        from oacli.control.condensed_qp import CondensedQP
    except ImportError:
        print("\nlower limit: skipped (pip install daqp)")
        return
    print(f"\nlower limit: condensed QP + DAQP vs our controller step, {len(times) - 1} steps (medians; the four "
          "alternate in a rotating order)")
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
        hot = CondensedQP(ctrl.qp.compiled)  # the limit: hot start from the previous step's working set
        cold = CondensedQP(ctrl.qp.compiled, warm_start=False)
        v = ctrl.qp._vars["translation"].v
        wall = {k: [] for k in ("ours", "solver", "hot", "cold", "per_call")}
        cpu = {k: [] for k in ("ours", "hot", "cold", "per_call")}
        iters = {k: [] for k in ("hot", "cold", "per_call")}
        dv = []
        ctrl.step(float(times[0]), states[0])  # first step builds caches: left out
        for limit in (hot, cold):  # DAQP's set-up (factorisation, once) on the first instance: left out too
            limit.solve(instances[0])

        def per_call(values, qp=hot):
            """DAQP as the table had it before: ``daqp.solve`` (set-up and factorisation at every call)."""
            theta = qp.compiled.parameter_vector(values)
            start = time.perf_counter()
            f, upper, a_in_z = qp._data(theta)
            _y, _f, flag, info = daqp.solve(qp._h, f, qp._a_in_z if a_in_z is None else a_in_z, upper, qp._lower,
                                            qp._sense)
            return flag == 1, int(info["iterations"]), time.perf_counter() - start

        contenders = ("ours", "hot", "cold", "per_call")
        solved = False
        for j in range(1, len(times)):
            k = j % len(contenders)
            for who in contenders[k:] + contenders[:k]:  # rotate who goes first
                start_cpu = time.process_time()
                if who == "ours":
                    out = ctrl.step(float(times[j]), states[j])
                    cpu[who].append(time.process_time() - start_cpu)
                    wall["ours"].append(out.info.step_time_s)
                    wall["solver"].append(out.info.solve_time_s)
                    continue
                ok, it, w = per_call(instances[j]) if who == "per_call" else (hot if who == "hot" else
                                                                               cold).solve(instances[j])
                cpu[who].append(time.process_time() - start_cpu)
                wall[who].append(w)
                iters[who].append(it)
                solved = ok if who == "hot" else solved
            if solved and out.info.success and ctrl.qp.compiled.solution is not None:  # this step's solutions
                dv.append(float(np.max(np.abs(hot.value(v)[0] - ctrl.qp.compiled.value(v)[0]))))
        ms = {k: 1e3 * np.median(val) for k, val in wall.items()}
        ms_cpu = {k: 1e3 * np.median(val) for k, val in cpu.items()}
        print(f"{horizon:>3} {hot.n_unknowns:>9} {hot.n_rows:>5} {ms['ours']:>14.3f} {ms['solver']:>16.3f} "
              f"{ms['hot']:>16.3f} {ms['ours'] / ms['hot']:>11.2f} {np.median(iters['hot']):>10.0f} "
              f"{max(dv, default=np.nan):>14.1e}")
        print(f"{'':>3} process CPU time: our step {ms_cpu['ours']:.3f} ms, DAQP limit {ms_cpu['hot']:.3f} ms, "
              f"step/limit {ms_cpu['ours'] / ms_cpu['hot']:.2f}")
        for key, text in (("cold", "DAQP without the hot start (cached set-up, empty working set)"),
                          ("per_call", "DAQP as measured before (daqp.solve: set-up and factorisation every call)")):
            print(f"{'':>3} {text}: {ms[key]:.3f} ms (CPU {ms_cpu[key]:.3f} ms), {np.median(iters[key]):.0f} iter, "
                  f"our step / it {ms['ours'] / ms[key]:.2f} (CPU {ms_cpu['ours'] / ms_cpu[key]:.2f})")


def step_times(cfg, reference, design, limits, weights, times, states, horizons=(5, 40)) -> dict[str, list[float]]:
    """Median wall and process CPU time [s] of our controller step per horizon, replaying ``states``."""
    out = {}
    for horizon in horizons:
        ctrl = tube_controller_from_config(with_controller(cfg, horizon=horizon), reference, design, weights, limits)
        ctrl.step(float(times[0]), states[0])  # first step builds caches: left out
        wall, cpu = [], []
        for t, x in zip(times[1:], states[1:], strict=True):
            start = time.process_time()
            wall.append(ctrl.step(float(t), x).info.step_time_s)
            cpu.append(time.process_time() - start)
        out[str(horizon)] = [float(np.median(wall)), float(np.median(cpu))]
    return out


def against(other: Path, repeats: int, steps: int) -> None:
    """Our step on the tree ``other`` (e.g. a worktree of main) and on this file's tree, alternating per repeat
    (one subprocess each, the same recorded states), so the machine's load weighs on both alike."""
    import json
    import os
    import subprocess
    import sys

    sides: dict[str, list[dict[str, list[float]]]] = {"other": [], "this": []}
    root = Path(__file__).resolve().parents[1]
    for rep in range(repeats):
        for side, src in (("other", other), ("this", root)):
            env = {**os.environ, "PYTHONPATH": str(src)}
            text = subprocess.run([sys.executable, __file__, "--steps", str(steps), "--step-json"], env=env,
                                  check=True, capture_output=True, text=True).stdout
            sides[side].append(json.loads(text.strip().splitlines()[-1]))
            print(f"repeat {rep + 1} {side:<5} " + "  ".join(
                f"N={n}: step {1e3 * w:.3f} ms (CPU {1e3 * c:.3f} ms)" for n, (w, c) in sides[side][-1].items()),
                flush=True)
    print(f"medians over {repeats} alternating repeats: other = {other}, this = {root}")
    for n in sides["this"][0]:
        o = np.median(np.array([run[n] for run in sides["other"]]), axis=0)
        t = np.median(np.array([run[n] for run in sides["this"]]), axis=0)
        print(f"  N = {n:>2}: step other {1e3 * o[0]:.3f} ms -> this {1e3 * t[0]:.3f} ms ({t[0] / o[0]:.3f}); "
              f"CPU other {1e3 * o[1]:.3f} ms -> this {1e3 * t[1]:.3f} ms ({t[1] / o[1]:.3f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="replayed steps per horizon (and per seed)")
    parser.add_argument("--seeds", type=int, default=5, help="closed loops replayed for the workspace table")
    parser.add_argument("--only-workspace", action="store_true", help="print the workspace table only")
    parser.add_argument("--only-limit", action="store_true", help="print the DAQP lower-limit table only")
    parser.add_argument("--against", type=Path, help="another source tree: our step there and here, alternating")
    parser.add_argument("--repeats", type=int, default=5, help="alternating repeats of --against")
    parser.add_argument("--step-json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.against is not None:
        against(args.against, args.repeats, args.steps)
        return
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
    if args.step_json:
        import json

        print(json.dumps(step_times(cfg, reference, design, limits, weights, times, states)))
        return
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
