"""Segment 1 of a mission over many seeds: does the standard MPC keep the TRUE state clear under sensor noise?

A cheaper equivalent of ``oacli campaign configs/campaign_tube_noise.yaml`` for segment 1 only (issue 29): run k
(k = 0..N-1) takes the campaign's config seed :func:`oacli.campaign.sampling.run_seed` ``(campaign seed, k)`` and
flies the mission's segment-1 stages (plan, smooth, track with the standard MPC) exactly as ``oacli mission``
derives them (:func:`oacli.mission.configs.stage_config`, :func:`oacli.mission.run.handoff_for`). Per run it prints
the track's status, the true state's keep-out and keep-in violation counts and worst depth (oacli's safety block),
the smallest true clearance between the robot's body and the keep-out zones (this script's own arithmetic: exact
distance to each ellipsoid minus the robot radius) and the RMS tracking error; then the totals.

Run: ``python benchmarks/check_segment1_noise.py [--config configs/mission_iss.yaml] [--seed 1] [--runs 56]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from oacli.campaign.sampling import run_seed
from oacli.config import load_config
from oacli.io.mcap_read import read_telemetry
from oacli.mission.run import handoff_for, mission_stages, stage_config
from oacli.mission.stage_call import run_stage

REPO = Path(__file__).resolve().parents[1]


def _ellipsoid_distance(p: np.ndarray, center: np.ndarray, axes: np.ndarray) -> float:
    """Exact distance [m] from ``p`` to an axis-aligned ellipsoid (0 inside), by the Lagrange multiplier's root."""
    y = np.abs(p - center)
    if np.sum((y / axes) ** 2) <= 1.0:
        return 0.0
    # x_i = a_i² y_i / (a_i² + λ), λ ≥ 0 the root of Σ (x_i / a_i)² = 1: decreasing in λ.

    def gap(lam: float) -> float:
        return float(np.sum((axes * y / (axes**2 + lam)) ** 2) - 1.0)

    res = minimize_scalar(lambda lam: gap(lam) ** 2, bounds=(0.0, float(np.linalg.norm(y) * axes.max() * 4)),
                          method="bounded", options={"xatol": 1e-14})
    x = axes**2 * y / (axes**2 + res.x)
    return float(np.linalg.norm(y - x))


def clearance_m(x_true: np.ndarray, cfg_path: Path) -> float:
    """Smallest distance [m] between the robot's body and any (axis-aligned) keep-out zone over the flight."""
    cfg = load_config(cfg_path)
    env, radius = cfg.environment, cfg.robot.radius_m
    best = np.inf
    p = x_true[:, 0:3]
    for zone in env.keep_out:
        if zone.shape_matrix is not None or (zone.quaternion and tuple(zone.quaternion) != (0.0, 0.0, 0.0, 1.0)):
            raise SystemExit("only axis-aligned keep-out ellipsoids are measured here")
        c, a = np.asarray(zone.center), np.asarray(zone.semi_axes_m) * env.safety_factor
        scaled = np.sqrt(np.sum(((p - c) / a) ** 2, axis=1))
        for i in np.argsort(scaled)[:40]:  # the nearest samples in the ellipsoid's metric
            best = min(best, _ellipsoid_distance(p[i], c, a) - radius)
    return float(best)


def fly_segment_1(config: Path, seed: int, folder: Path) -> dict[str, object]:
    """Plan, smooth and track segment 1 of ``config`` with ``seed`` into ``folder``; the track's figures."""
    cfg = load_config(config).model_copy(update={"seed": seed})
    for stage in mission_stages(cfg):
        if stage.segment != "segment-1":
            continue
        handoff = handoff_for(cfg, stage, folder)
        out = stage.folder(folder)
        out.parent.mkdir(parents=True, exist_ok=True)
        run_stage(stage, stage_config(cfg, stage, handoff), handoff, out, None)
    track = folder / "segment-1" / "track"
    summary = json.loads((track / "summary.json").read_text())
    tel = read_telemetry(track / "track.mcap")
    safety = summary["safety"]
    return {"status": summary["status"], "keep_out": safety["keep_out"]["count"],
            "keep_out_depth_m": safety["keep_out"]["worst_depth"], "keep_in": safety["keep_in"]["count"],
            "clearance_m": clearance_m(tel.x_true, track / "config.yaml"),
            "rms_position_error_m": summary["rms_position_error_m"],
            "final_position_error_m": summary["final_position_error_m"], "wall_s": summary["wall_time_s"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=REPO / "configs" / "mission_iss.yaml")
    parser.add_argument("--seed", type=int, default=1, help="campaign seed (configs/campaign_tube_noise.yaml: 1)")
    parser.add_argument("--runs", type=int, default=56)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override of the mission config (e.g. controller.estimate_margin_sigmas=0)")
    args = parser.parse_args()
    config = args.config
    if args.set:
        import yaml

        from oacli.config.overrides import apply_overrides

        data = apply_overrides(yaml.safe_load(config.read_text()), args.set)
        tmp_cfg = Path(tempfile.mkdtemp()) / config.name
        tmp_cfg.write_text(yaml.safe_dump(data))
        config = tmp_cfg
    rows = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.runs):
            seed = run_seed(args.seed, k)
            row = fly_segment_1(config, seed, Path(tmp) / f"run-{k:03d}")
            rows.append(row)
            print(f"run {k:3d} seed {seed:10d}: {row['status']:8s} keep-out {row['keep_out']:3d} "
                  f"(depth {1e3 * float(row['keep_out_depth_m']):.2f} mm), keep-in {row['keep_in']}, "
                  f"clearance {1e3 * float(row['clearance_m']):7.2f} mm, "
                  f"RMS {1e3 * float(row['rms_position_error_m']):.2f} mm", flush=True)
    graze = [r for r in rows if r["keep_out"] or r["keep_in"]]
    clear = [float(r["clearance_m"]) for r in rows]
    rms = [float(r["rms_position_error_m"]) for r in rows]
    print(f"{len(rows)} seeds: {len(graze)} with the true state in a keep-out or out of the keep-in; "
          f"statuses {sorted({str(r['status']) for r in rows})}; smallest clearance {1e3 * min(clear):.2f} mm "
          f"(median {1e3 * statistics.median(clear):.2f} mm); RMS tracking error median "
          f"{1e3 * statistics.median(rms):.2f} mm, max {1e3 * max(rms):.2f} mm; "
          f"{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
