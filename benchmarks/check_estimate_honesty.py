"""Check: is the estimate stage's reported σ honest? z-scores over seeds, batch and sequential, with and without a
torque-scale dispersion in the truth.

Segment 2 of a default mission run (``oacli mission configs/mission_iss.yaml --out RUN``) is flown again per seed,
without its MPC (too slow for 50 × 2 × 2 runs): the simulator plays segment 2's applied inputs back with a PD
correction on the *measured* state towards the run's true trajectory (so the inputs react to the sensor noise as
the MPC's do), the plant being the run's truth (grasped mass and inertias, CoM offset, actuator scales) with the
torque scales drawn ``1 + N(0, pct %)`` per axis (``--torque-dispersion-pct``; 0: the run's exact ones), the sensor
noise drawn from the seed. The records go straight to the estimate stage's own :func:`run_estimation` with the run's
``segment-2/estimate/config.yaml`` (prior, calibrated force scale, noise models, parameters) and one window.

Printed per parameter and case: the z-scores' standard deviation (honest σ: about 1; the issue asks ≤ 1.2), mean,
largest |z|, share within 2σ (≥ 90 %) and within 3σ, for

* ``physical``: ``(θ̂ − θ)/σ`` with the stage's reported σ (summary ``std``/``rigid_body``: the consider covariance,
  :mod:`oacli.estimation.consider`);
* ``statistical``: the same with the estimator's σ alone (the held groups taken as exact: the σ reported before);
* ``handed``: the inertias against the effective inertia ``J_i/κ_τ,i`` with the σ handed to segment 3;

and the statuses of the runs (the stage's findings: χ², NIS).

Run: ``nice -n 10 python benchmarks/check_estimate_honesty.py RUN --seeds 1-50 --method batch
--torque-dispersion-pct 0 1`` (~3 s a seed for the batch, ~6 s for the sequential filter, one core);
``--torque-scale-std 0.01 --products-std 1e-5`` gives the held groups priors that match the truth's spread (κ_τ
± 1 %, products 0): a calibration check of the consider covariance (the z spreads should then be about 1).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oacli.config import load_config
from oacli.estimation.batch_model import FullModel
from oacli.estimation.manifold import boxminus
from oacli.estimation.preprocessing import measurements_from_telemetry
from oacli.estimation.rigid_parameters import FULL_NAMES
from oacli.io.mcap_read import read_telemetry
from oacli.sim.sensors import Disturbance
from oacli.sim.simulator import simulate
from oacli.stages.estimate import _estimate_summary, run_estimation
from oacli.stages.estimate_rigid import batch_model, truth_full_from_config_yaml
from oacli.stages.settings import estimation_prior, estimator_settings, sensor_noise
from oacli.types import ControlStep, InertialParams, SolveInfo


class ReplayPD:
    """Segment 2's applied inputs, corrected by a PD law on the measured state towards the run's true states."""

    def __init__(self, u: np.ndarray, x_ref: np.ndarray, mass_kg: float, inertia: np.ndarray) -> None:
        self.u, self.x_ref, self.k = u, x_ref, 0
        self.gain = np.r_[0.05 * mass_kg * np.ones(3), 0.4 * mass_kg * np.ones(3),
                          0.1 * inertia, 0.5 * inertia]

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        k = min(self.k, len(self.u) - 1)
        e = boxminus(x_measured[None], self.x_ref[k][None])[0] * self.gain  # [dr, dv, dθ (body), dω]
        u = self.u[k] - np.r_[e[0:3] + e[3:6], e[6:9] + e[9:12]]
        self.k += 1
        return ControlStep(u=u, info=SolveInfo("replay-pd", True), x_reference=self.x_ref[k])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a default mission's run folder")
    parser.add_argument("--seeds", default="1-50", help="first-last seed")
    parser.add_argument("--method", default="batch", choices=["batch", "sequential"])
    parser.add_argument("--torque-dispersion-pct", type=float, nargs="+", default=[0.0, 1.0])
    parser.add_argument("--torque-scale-std", type=float, default=None,
                        help="the held torque scales' prior σ (default: the run's estimation.rigid_body)")
    parser.add_argument("--products-std", type=float, default=None,
                        help="the held products of inertia's prior σ [kg·m²] (default: the run's)")
    args = parser.parse_args()
    first, last = (int(v) for v in args.seeds.split("-"))
    cfg = load_config(args.run / "segment-2" / "estimate" / "config.yaml")
    config_yaml = (args.run / "segment-2" / "estimate" / "config.yaml").read_text()
    truth0 = truth_full_from_config_yaml(config_yaml)
    assert truth0 is not None, "the run's config has no truth"
    tel0 = read_telemetry(args.run / "segment-2" / "track" / "track.mcap")
    x_ref = tel0.x_true_ctrl if tel0.x_true_ctrl is not None else tel0.x_reference
    period = float(np.median(np.diff(tel0.t_ctrl)))
    plant = 1.0 / cfg.simulation.plant_rate_hz
    settings, prior = estimator_settings(cfg), estimation_prior(cfg)
    model = batch_model(cfg, prior)
    assert model is not None, "the run's estimate config estimates mass and inertia only (nothing held)"
    cov = model.prior_cov.copy()  # the held groups' prior σ replaced where asked (their means and the rest kept)
    for at, std in ((slice(13, 16), args.torque_scale_std), (slice(4, 7), args.products_std)):
        if std is not None:
            cov[at, at] = std**2 * np.eye(3)
    model = FullModel(model.params, model.prior_mean, cov)
    idx = model.params.index
    limits = np.r_[cfg.robot.force_limit_N, cfg.robot.torque_limit_Nm]
    for pct in args.torque_dispersion_pct:
        z: dict[str, dict[str, list[float]]] = {"physical": {}, "statistical": {}, "handed": {}}
        statuses: dict[str, int] = {}
        ratios: list[float] = []
        wall = time.perf_counter()
        for seed in range(first, last + 1):
            truth = truth0.copy()
            truth[13:16] = truth0[13:16] * (1.0 + pct / 100.0 * np.random.default_rng([seed, 7]).normal(size=3))
            tel = simulate(ReplayPD(tel0.u_applied, x_ref, truth[0], truth[1:4]), x_ref[0],
                           InertialParams(truth[0], truth[1:4]), duration_s=period * len(tel0.t_ctrl),
                           control_period_s=period, plant_period_s=plant, input_limits=limits,
                           sensors=sensor_noise(cfg), disturbance=Disturbance.none(),
                           rng=np.random.default_rng(seed), actuator_scale=truth[10:16], com_offset_m=truth[7:10])
            recs = measurements_from_telemetry(tel)
            run = run_estimation(recs, settings, prior, args.method, use_prior=cfg.estimation.use_prior,
                                 window_s=1e9, model=model)
            summary = _estimate_summary(run, prior, truth[:4], Path("simulated"))
            statuses[summary["status"]] = statuses.get(summary["status"], 0) + 1
            ratios.append(summary.get("chi2_ratio") or summary.get("nis_ratio") or float("nan"))
            assert run.full is not None
            theta, cov = run.full
            stat = (run.extras or {}).get("consider", {}).get("std_statistical", {})
            handed = run.final.std
            for i in idx:
                name = FULL_NAMES[i]
                err = theta[i] - truth[i]
                z["physical"].setdefault(name, []).append(err / np.sqrt(cov[i, i]))
                z["statistical"].setdefault(name, []).append(err / stat.get(name, np.sqrt(cov[i, i])))
                if 1 <= i <= 3:  # the effective inertia J_i / κ_τ,i against the σ handed on
                    z["handed"].setdefault(name, []).append((theta[i] - truth[i] / truth[12 + i]) / handed[i])
            worst = max(abs(v[-1]) for v in z["physical"].values())
            print(f"  seed {seed}: {summary['status']}, ratio {ratios[-1]:.3f}, max |z| {worst:.2f}", flush=True)
        n = last - first + 1
        print(f"\n{args.method}, torque-scale dispersion {pct:g} %: {n} seeds in {time.perf_counter() - wall:.0f} s, "
              f"statuses {statuses}, {'χ²' if args.method == 'batch' else 'NIS'} ratio "
              f"{np.nanmin(ratios):.3f}-{np.nanmax(ratios):.3f}")
        print(f"{'σ':<12} {'parameter':<16} {'std(z)':>7} {'mean(z)':>8} {'max|z|':>7} {'in 2σ':>6} {'in 3σ':>6}")
        for kind, per in z.items():
            for name, values in per.items():
                v = np.array(values)
                print(f"{kind:<12} {name:<16} {np.std(v, ddof=1):7.2f} {np.mean(v):8.2f} {np.max(np.abs(v)):7.2f} "
                      f"{100 * np.mean(np.abs(v) <= 2):5.0f}% {100 * np.mean(np.abs(v) <= 3):5.0f}%")
            allz = np.concatenate([np.array(v) for v in per.values()])
            print(f"{kind:<12} {'(all)':<16} {np.std(allz, ddof=1):7.2f} {np.mean(allz):8.2f} "
                  f"{np.max(np.abs(allz)):7.2f} {100 * np.mean(np.abs(allz) <= 2):5.0f}% "
                  f"{100 * np.mean(np.abs(allz) <= 3):5.0f}%")


if __name__ == "__main__":
    main()
