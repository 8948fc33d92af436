"""Independent check of a payload-envelope campaign (issue 29): every flown track MCAP against the limits.

For each run folder of a finished ``oacli campaign`` (``runs/run-*/attempt-N/mission``, the last attempt), reads
the mission's own flights' track MCAPs and checks the *true* state at every plant sample and
the applied input at every control step, with its own arithmetic (not oacli's metrics): the robot's centre inside
the keep-in boxes (the union, shrunk by ``environment.keep_in_margin_m``), the body (radius ``robot.radius_m``)
outside every keep-out ellipsoid (exact distance by minimisation where the grown-ellipsoid test flags a sample),
``|v_i| ≤ velocity limit``, ``|ω_i| ≤ angular-rate limit``, ``|F_i| ≤ force limit``. Then it prints, per mission
status, the runs, their violations, the runs arriving at A within 2 cm, the reasons of the others, the batch mass
error, the exit codes and the runs whose segment 3 flew the prior (the estimate not handed on).

Run: ``python benchmarks/check_envelope_campaign.py CAMPAIGN_FOLDER``
"""

from __future__ import annotations

import argparse
import json
import statistics
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from oacli.config import load_config
from oacli.io.mcap_read import read_telemetry
from oacli.status import EXIT_CODES

RTOL = 1e-9
TRACKS = ("segment-1/track", "segment-2/track", "segment-3/track")


def _distance_to_ellipsoid(p: np.ndarray, center: np.ndarray, shape: np.ndarray) -> float:
    """Euclidean distance from ``p`` to the ellipsoid ``(x − c)ᵀ S (x − c) ≤ 1`` (0 inside)."""
    d = p - center
    if d @ shape @ d <= 1.0:
        return 0.0
    vals, vecs = np.linalg.eigh(shape)
    scale = 1.0 / np.sqrt(vals)

    def on_surface(u: np.ndarray) -> np.ndarray:
        return center + vecs @ (scale * u / np.linalg.norm(u))

    best = np.inf
    for start in (vecs.T @ d / scale, *np.eye(3), *-np.eye(3)):
        res = minimize(lambda u: float(np.sum((on_surface(u) - p) ** 2)), start + 1e-9, method="Nelder-Mead",
                       options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 4000})
        best = min(best, float(np.sqrt(res.fun)))
    return best


def check_track(mcap: Path, cfg_path: Path) -> dict[str, int]:
    """Violation counts of one flight: keep_in, keep_out, velocity, angular_velocity, force."""
    cfg = load_config(cfg_path)
    tel = read_telemetry(mcap)
    x, u = tel.x_true, tel.u_applied
    r = cfg.robot
    out = {"velocity": int(np.sum(np.any(np.abs(x[:, 3:6]) > np.asarray(r.velocity_limit_mps) * (1 + RTOL), 1))),
           "angular_velocity": int(np.sum(np.any(np.abs(x[:, 10:13]) > np.asarray(r.angular_velocity_limit_radps)
                                                 * (1 + RTOL), 1))),
           "force": int(np.sum(np.any(np.abs(u[:, 0:3]) > np.asarray(r.force_limit_N) * (1 + RTOL), 1)))}
    env = cfg.environment
    p = x[:, 0:3]
    if env.keep_in:
        margin = getattr(env, "keep_in_margin_m", 0.0) or 0.0
        inside = np.zeros(len(p), dtype=bool)
        for box in env.keep_in:
            c = np.asarray(box.corners, dtype=float)
            lo, hi = c.min(axis=0) + margin, c.max(axis=0) - margin
            inside |= np.all((p >= lo - 1e-9) & (p <= hi + 1e-9), axis=1)
        out["keep_in"] = int(np.sum(~inside))
    else:
        out["keep_in"] = 0
    hits = 0
    for zone in env.keep_out:
        center = np.asarray(zone.center)
        if zone.shape_matrix is not None:
            shape = np.asarray(zone.shape_matrix) / env.safety_factor**2
        else:
            rot = Rotation.from_quat(zone.quaternion or (0.0, 0.0, 0.0, 1.0)).as_matrix()
            axes = np.asarray(zone.semi_axes_m) * env.safety_factor
            shape = rot @ np.diag(1.0 / axes**2) @ rot.T
        vals, vecs = np.linalg.eigh(shape)
        grown = vecs @ np.diag(1.0 / (1.0 / np.sqrt(vals) + r.radius_m) ** 2) @ vecs.T
        d = p - center
        near = np.einsum("ij,jk,ik->i", d, grown, d) <= 1.0
        hits += sum(_distance_to_ellipsoid(q, center, shape) < r.radius_m - 1e-6 for q in p[near])
    out["keep_out"] = int(hits)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("campaign", type=Path)
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    for run in sorted((args.campaign / "runs").glob("run-*")):
        attempts = sorted(run.glob("attempt-*/mission"), key=lambda p: int(p.parent.name.split("-")[1]))
        mission = attempts[-1] if attempts else run / "mission"
        summary_path = mission / "summary.json"
        row: dict[str, Any] = {"run": run.name}
        if not summary_path.exists():
            row["status"] = "no summary"
            rows.append(row)
            continue
        summary = json.loads(summary_path.read_text())
        row["status"] = summary["status"]
        row["reasons"] = sorted({r["kind"] for r in summary.get("status_reasons") or []})
        row["violations"] = {}
        for key in TRACKS:
            folder = mission / key
            if (folder / "track.mcap").exists() and (folder / "summary.json").exists():
                row["violations"][key] = check_track(folder / "track.mcap", folder / "config.yaml")
        comp = (summary.get("comparison") or {}).get("segment-3/track") or {}
        row["arrived"] = comp.get("arrival_time_s") is not None
        row["final_distance_m"] = comp.get("final_distance_m")
        est = summary.get("estimate") or {}
        row["mass_error_pct"] = (est.get("error_pct") or {}).get("mass_kg")
        inertia = est.get("inertia_kgm2")
        if inertia:  # how far the estimate is from the lamina boundary (a sum of two = the third)
            i = np.asarray(inertia, dtype=float)
            row["triangle_slack"] = float(np.min(i.sum() - 2 * i) / i.max())
        learned = summary.get("learned_model") or {}
        row["learned_source"] = learned.get("source")
        row["learned_note"] = learned.get("note")
        row["exit_code"] = EXIT_CODES.get(summary["status"], 1)
        rows.append(row)
    n = len(rows)
    print(f"{n} runs; statuses: {dict(Counter(r['status'] for r in rows))}")
    bad = [(r["run"], r["status"], k, v) for r in rows for k, v in (r.get("violations") or {}).items()
           if any(v.values())]
    safe_bad = [b for b in bad if b[1] != "unsafe"]
    print(f"flights with a violation (true state / applied force): {len(bad)}; in runs not 'unsafe': {len(safe_bad)}")
    for b in bad:
        print("   ", *b)
    arrived = sum(bool(r.get("arrived")) for r in rows)
    print(f"arrived at A within 2 cm: {arrived}/{n} ({100 * arrived / max(n, 1):.0f} %)")
    for r in rows:
        if not r.get("arrived"):
            print(f"    {r['run']}: {r['status']}, reasons {r.get('reasons')}, "
                  f"final distance {r.get('final_distance_m')}")
    errs = [r["mass_error_pct"] for r in rows if r.get("mass_error_pct") is not None]
    if errs:
        print(f"batch mass error: median {statistics.median(errs):.3g} %, max {max(errs):.3g} % ({len(errs)} runs)")
    print(f"mission exit codes (from the status): {dict(Counter(r.get('exit_code') for r in rows))}")
    fallbacks = [r for r in rows if r.get("learned_source") == "prior"]
    print(f"segment 3 flew the prior (the batch estimate not handed on): {len(fallbacks)}/{n}")
    for r in fallbacks:
        print(f"    {r['run']}: triangle slack of the estimate {r.get('triangle_slack', float('nan')):.2g} "
              f"(min(sum of two - third) / max); {r.get('learned_note')}")
    manifest = args.campaign / "manifest.jsonl"
    if manifest.exists():
        lines = [json.loads(line) for line in manifest.read_text().splitlines() if line.strip()]
        print(f"manifest statuses: {dict(Counter(r.get('status') for r in lines))}")
        for r in lines:
            if r.get("error"):
                print(f"    run {r.get('k')}: {r['error'][:200]}")

if __name__ == "__main__":
    main()
