"""The flight-fault campaign against issue 30's "Done when" (configs/campaign_reswarm_flight.yaml), from a campaign
folder (complete or not): per parameter the median |error| of the batch estimate against the ReSWARM flight's
([ReSWARM2023] RATTLE table: mass 0.39 %, inertias 0.91 / 1.35 / 6.92 %), the spread (standard deviation) and RMS of
the signed error ÷ the Cramér-Rao bound, the CoM error median, and the actuator calibrations (handed on, fallbacks,
σ inflated, κ z-scores against the simulated truth).

Run: ``python benchmarks/check_reswarm_campaign.py /work/studies/reswarm50``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

NAMES = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")
FLIGHT_PCT = (0.39, 0.91, 1.35, 6.92)


def _mission_dirs(campaign: Path) -> list[Path]:
    out = []
    for run in sorted((campaign / "runs").glob("run-*")):
        attempts = sorted(run.glob("attempt-*/mission/summary.json"), key=lambda p: int(p.parts[-3].split("-")[1]))
        if attempts:
            out.append(attempts[-1].parent)
    return out


def _row(mission: Path) -> dict[str, Any] | None:
    summary = json.loads((mission / "summary.json").read_text())
    est = summary.get("estimate") or {}
    if not est.get("error_pct") or not est.get("crb_std"):
        return None
    truth = np.asarray(est["truth_theta"], dtype=float)
    value = np.r_[est["mass_kg"], est["inertia_kgm2"]]
    crb = np.array([est["crb_std"][n] for n in NAMES])
    row: dict[str, Any] = {"status": summary.get("status"), "error_pct": [est["error_pct"][n] for n in NAMES],
                           "error_over_crb": ((value - truth) / crb).tolist()}
    rb = json.loads((mission / "segment-2" / "estimate" / "summary.json").read_text()).get("rigid_body") or {}
    com = [k for k in ("com_x_m", "com_y_m", "com_z_m") if k in (rb.get("estimate") or {})]
    if len(com) == 3:
        row["com_error_mm"] = 1e3 * float(np.linalg.norm([rb["estimate"][k] - rb["truth"][k] for k in com]))
    cal = summary.get("calibration") or {}
    row["calibration"] = {"source": cal.get("source"), "stage": cal.get("stage"), "note": cal.get("note"),
                          "inflation": cal.get("sigma_inflation", 1.0), "z": cal.get("z_score") or {}}
    row["reasons"] = sorted({str(r.get("kind")) for r in summary.get("status_reasons") or ()})
    return row


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("campaign", type=Path)
    args = parser.parse_args()
    rows = [r for m in _mission_dirs(args.campaign) if (r := _row(m)) is not None]
    print(f"{len(rows)} runs with a batch estimate")
    err = np.array([r["error_pct"] for r in rows])
    ratio = np.array([r["error_over_crb"] for r in rows])
    print(f"{'':10s} {'median |err| %':>15s} {'flight %':>9s} {'p95 %':>7s} {'err/CRB spread':>15s} {'RMS':>6s}")
    for i, name in enumerate(NAMES):
        print(f"{name:10s} {np.median(err[:, i]):15.3f} {FLIGHT_PCT[i]:9.2f} {np.percentile(err[:, i], 95):7.3f} "
              f"{np.std(ratio[:, i], ddof=1):15.2f} {np.sqrt(np.mean(ratio[:, i] ** 2)):6.2f}")
    com = [r["com_error_mm"] for r in rows if "com_error_mm" in r]
    if com:
        print(f"CoM error median {np.median(com):.3f} mm, max {np.max(com):.3f} mm ({len(com)} runs)")
    sources: dict[str, int] = {}
    for r in rows:
        key = f"{r['calibration']['source']} ({r['calibration']['stage'] or 'segment-1/calibrate'})"
        sources[key] = sources.get(key, 0) + 1
    print("calibration handed on:", sources)
    print("calibration_fallback:", sum("calibration_fallback" in r["reasons"] for r in rows),
          "| σ inflated:", sum(r["calibration"]["inflation"] != 1.0 for r in rows),
          "| with a note:", sum(r["calibration"]["note"] is not None for r in rows))
    z = np.array([v for r in rows for v in r["calibration"]["z"].values()])
    if z.size:
        print(f"calibration κ z-scores: |z| median {np.median(np.abs(z)):.2f}, within 3σ {np.mean(np.abs(z) <= 3):.1%}"
              f", max {np.max(np.abs(z)):.2f} ({z.size})")
    status: dict[str, int] = {}
    for r in rows:
        status[r["status"]] = status.get(r["status"], 0) + 1
    print("mission status:", status)
    for r in rows:
        if r["calibration"]["note"]:
            print("  note:", r["calibration"]["note"][:300])


if __name__ == "__main__":
    main()
