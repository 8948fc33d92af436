"""Benchmark: the offline tube design with the relative ε (the preset) vs the flight code's absolute ε, and what
the tighter lasso costs per controller step.

Both designs are for ``configs/iss_reswarm_tube.yaml`` (ReSWARM settings: 9.5 kg, 0.2 s, u_max 0.15 N, ancillary
Q = diag(5, 10), R = 2): the preset's own tube (``rpi_epsilon`` relative, ``F_∞ ⊆ Z ⊆ (1 + ε) F_∞``) and the
ReSWARM flight settings (absolute ε = 0.005, 5 % facet growth). For each: the design time (median over
``--repeats`` designs: ancillary gain, RPI set, facet reduction, tightening; then ``summary()`` once, which adds
the independent minimal box and the baseline design), Z's ratio to the minimal box, the lasso's facets and the
tightened bounds; then one closed loop with the preset's tube is recorded and both controllers (direct Clarabel
path, horizon of the preset) replay it interleaved step by step, so the lasso's extra rows are measured under the
same load.

Run: ``python benchmarks/bench_tube_design.py [--repeats 5] [--steps 150]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oacli.config import load_config
from oacli.control.tube_design import BASELINE_EPSILON, BASELINE_FACET_GROWTH
from oacli.stages.track import reference_from_config
from oacli.stages.track_tube import tube_controller_from_config

PRESET = Path(__file__).resolve().parents[1] / "configs" / "iss_reswarm_tube.yaml"


def limits_and_weights(cfg):
    from oacli.control.tracking import TrackingWeights
    from oacli.model.limits import MotionLimits

    robot, w = cfg.robot, cfg.controller.weights
    limits = MotionLimits(np.asarray(robot.force_limit_N), np.asarray(robot.torque_limit_Nm),
                            np.asarray(robot.velocity_limit_mps), np.asarray(robot.angular_velocity_limit_radps))
    weights = TrackingWeights(*(np.asarray(getattr(w, f)) for f in
                                ("position", "velocity", "attitude", "angular_velocity", "force", "torque")))
    return limits, weights


def design(cfg, mode: str, epsilon: float, growth: float):
    """The tube of ``cfg`` with the given ε settings (same W, K and limits as the stage builds)."""
    from oacli.control.disturbance import DisturbanceSpec
    from oacli.control.tube_design import AncillaryWeights, design_translation_tube

    tube, robot = cfg.controller.tube, cfg.robot.model()
    dist, anc = tube.disturbance, tube.ancillary
    spec = DisturbanceSpec(
        n_sigma=dist.mass_sigmas,
        force_N=np.asarray(dist.force_N), box_position_m=np.asarray(dist.position_m),
        box_velocity_mps=np.asarray(dist.velocity_mps), noise_position_m=np.asarray(dist.position_noise_m),
        noise_velocity_mps=np.asarray(dist.velocity_noise_mps),
    )
    force_limit = np.asarray(tube.force_limit_N if tube.force_limit_N is not None else robot.force_limit_N)
    return design_translation_tube(
        model=robot, dt_s=cfg.controller.period_s, force_limit_N=force_limit,
        velocity_limit_mps=np.asarray(robot.velocity_limit_mps),
        weights=AncillaryWeights(anc.position, anc.velocity, anc.force), spec=spec, epsilon=epsilon,
        epsilon_mode=mode, max_terms=tube.rpi_max_terms, facet_growth=growth,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="designs timed per setting")
    parser.add_argument("--steps", type=int, default=150, help="replayed controller steps")
    args = parser.parse_args()
    cfg = load_config(PRESET)
    tube = cfg.controller.tube
    settings = {
        f"{tube.rpi_epsilon_mode} eps={tube.rpi_epsilon:g}, growth {tube.lasso_facet_growth:g} (preset)":
            (tube.rpi_epsilon_mode, tube.rpi_epsilon, tube.lasso_facet_growth),
        f"absolute eps={BASELINE_EPSILON:g}, growth {BASELINE_FACET_GROWTH:g} (flight)":
            ("absolute", BASELINE_EPSILON, BASELINE_FACET_GROWTH),
    }
    designs = {}
    for label, (mode, eps, growth) in settings.items():
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            d = design(cfg, mode, eps, growth)
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        summary = d.summary()
        summary_s = time.perf_counter() - t0
        designs[label] = d
        ax, ratio, gain = d.axes[0], summary["z_to_minimal_box"], summary["tightening_gain"]
        print(f"{label}: design p50 {np.median(times):.3f} s (min {min(times):.3f}, max {max(times):.3f}), "
              f"summary {summary_s:.3f} s")
        print(f"  x axis: s = {ax.rpi.s}, {ax.reduction.facets_before} -> {ax.reduction.facets_after} facets; "
              f"Z / minimal box: position {ratio['position'][0]:.4f}, velocity {ratio['velocity'][0]:.4f} "
              f"(guaranteed <= {1 + ax.relative_bound:.4f}); tightened force ±{ax.force_bounds_N[1]:.5f} N, "
              f"velocity ±{ax.velocity_bounds_mps[1]:.5f} m/s (ideal ±{gain['ideal_force_N'][0][1]:.5f} N, "
              f"±{gain['ideal_velocity_mps'][0][1]:.5f} m/s)")

    from oacli.sim.sensors import Disturbance, SensorNoise
    from oacli.sim.simulator import simulate

    reference = reference_from_config(cfg)
    limits, weights = limits_and_weights(cfg)
    preset_design = next(iter(designs.values()))
    ctrl = tube_controller_from_config(cfg, reference, preset_design, weights, limits)
    dist = cfg.truth.disturbance
    tel = simulate(ctrl, reference.x[0], cfg.truth_params(), duration_s=reference.duration_s + 5.0,
                   control_period_s=cfg.controller.period_s, plant_period_s=cfg.simulation.plant_period_s,
                   input_limits=np.r_[limits.force_N, limits.torque_Nm], sensors=SensorNoise(),
                   disturbance=Disturbance(dist.bias, dist.random_bound), rng=np.random.default_rng(cfg.seed))
    t, x = tel.t_ctrl[: args.steps], tel.x_measured[: args.steps]
    ctrls = {label: tube_controller_from_config(cfg, reference, d, weights, limits) for label, d in designs.items()}
    step_ms: dict[str, list[float]] = {label: [] for label in ctrls}
    for tk, xk in zip(t, x, strict=True):
        for label, c in ctrls.items():
            step_ms[label].append(1e3 * c.step(float(tk), xk).info.step_time_s)
    print(f"controller step (direct path, N = {cfg.controller.horizon}, {len(t)} replayed steps, interleaved):")
    for label, c in ctrls.items():
        compiled = c.qp.compiled
        print(f"  {label}: {compiled.n_constraints} rows, step p50 {np.median(step_ms[label][1:]):.3f} ms")


if __name__ == "__main__":
    main()
