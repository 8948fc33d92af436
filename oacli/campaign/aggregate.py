"""The campaign's statistics over its runs' final manifest records (``summary.json``; ``docs/campaign.md``).

Success means the job ran to its end without an ``unsafe`` status (``ok`` or ``degraded``). Tracking errors are
percentiles over the completed runs. Estimation errors (``job: mission``) are percentiles of the absolute percent
errors next to the flight figures ([ReSWARM2023] RATTLE table: mass 0.39 %, inertias 0.91 / 1.35 / 6.92 %) and of the
errors in units of the Cramér-Rao bound's σ ([Doerr2021] Eq. 32): an efficient, unbiased estimator has RMS 1 there.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.campaign import manifest
from oacli.config.campaign import CampaignConfig

PERCENTILES = (5, 50, 95)
PARAMS = ("mass", "Ixx", "Iyy", "Izz")
STATUSES = (*manifest.COMPLETED, manifest.FAILED, manifest.INFRA_FAILED)


def _pct(values: list[float]) -> dict[str, float | None]:
    arr = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    if arr.size == 0:
        return {**{f"p{p}": None for p in PERCENTILES}, "max": None, "n": 0}
    return {**{f"p{p}": float(np.percentile(arr, p)) for p in PERCENTILES}, "max": float(arr.max()),
            "n": int(arr.size)}


def _estimation(metrics: list[dict[str, Any]], cfg: CampaignConfig) -> dict[str, Any] | None:
    est = [m["estimate"] for m in metrics if m.get("estimate")]
    if not est:
        return None
    err = np.abs(np.array([e["error_pct"] for e in est], dtype=float))
    crb = np.array([e["error_over_crb"] for e in est], dtype=float)
    flight = np.array([cfg.flight.mass_pct, *cfg.flight.inertia_pct])
    out: dict[str, Any] = {"runs": len(est), "abs_error_pct": {}, "error_over_crb": {}, "flight_pct": {},
                           "within_flight_fraction": {}, "agreement": {}}
    for i, name in enumerate(PARAMS):
        col = err[:, i]
        out["abs_error_pct"][name] = _pct(col.tolist())
        finite = crb[:, i][np.isfinite(crb[:, i])]
        out["error_over_crb"][name] = {**_pct(np.abs(finite).tolist()),
                                       "rms": float(np.sqrt(np.mean(finite**2))) if finite.size else None}
        out["flight_pct"][name] = float(flight[i])
        out["within_flight_fraction"][name] = float(np.mean(col <= flight[i]))
        median = float(np.median(col))
        # The flight figure is one flight's error: "agrees" when it lies within the simulated 5-95 % band.
        lo, hi = np.percentile(col, 5), np.percentile(col, 95)
        if flight[i] < lo:
            verdict = "simulation worse than flight"
        elif flight[i] > hi:
            verdict = "simulation better than flight"
        else:
            verdict = "agrees"
        out["agreement"][name] = {"median_abs_error_pct": median, "p5": float(lo), "p95": float(hi),
                                  "flight_pct": float(flight[i]), "verdict": verdict}
    return out


def summarize(cfg: CampaignConfig, final: dict[int, dict[str, Any]], runs_index: dict[str, Any]) -> dict[str, Any]:
    """The campaign statistics.

    Parameters
    ----------
    cfg : CampaignConfig
        The campaign.
    final : dict of int to dict
        Each run's final manifest record.
    runs_index : dict
        ``runs.json``'s ``index`` (faults per run).

    Returns
    -------
    dict
    """
    counts = dict.fromkeys(STATUSES, 0)
    for rec in final.values():
        counts[rec["status"]] = counts.get(rec["status"], 0) + 1  # a mission may end no_solution too
    missing = cfg.runs - len(final)
    completed = [rec for rec in final.values() if rec["status"] in manifest.COMPLETED]
    metrics = [rec["metrics"] for rec in completed if rec.get("metrics")]
    success = counts["ok"] + counts["degraded"]
    viol = {kind: int(sum(m["violations"][kind] for m in metrics)) for kind in ("keep_in", "keep_out", "limits")}
    runs_with = {kind: int(sum(1 for m in metrics if m["violations"][kind] > 0)) for kind in viol}
    faults: dict[str, dict[str, Any]] = {}
    for k_str, entry in runs_index.items():
        k = int(k_str)
        for name in entry.get("faults", ()):
            f = faults.setdefault(name, {"runs": 0, "success": 0})
            f["runs"] += 1
            if final.get(k, {}).get("status") in ("ok", "degraded"):
                f["success"] += 1
    for f in faults.values():
        f["success_rate"] = f["success"] / f["runs"] if f["runs"] else None
    return {
        "stage": "campaign",
        "name": cfg.name,
        "seed": cfg.seed,
        "job": cfg.job,
        "runs": cfg.runs,
        "finished": len(final),
        "missing": missing,
        "status_counts": counts,
        "success_rate": success / cfg.runs,
        "unsafe": counts["unsafe"],
        "degraded": counts["degraded"],
        "failed": counts["failed"],
        "infra_failed": counts["infra_failed"],
        "violations": viol,
        "runs_with_violations": runs_with,
        "tube_violations": int(sum(m.get("tube_violations", 0) for m in metrics)),
        "tube_violations_true": int(sum(m.get("tube_violations_true", 0) for m in metrics)),
        "runs_with_tube_violations": int(sum(1 for m in metrics if m.get("tube_violations_true", 0) > 0)),
        "fallback_steps": int(sum(m.get("fallback_steps", 0) for m in metrics)),
        "runs_with_fallbacks": int(sum(1 for m in metrics if m.get("fallback_steps", 0) > 0)),
        "tracking": {"rms_position_error_m": _pct([m.get("rms_position_error_m") for m in metrics]),
                     "max_position_error_m": _pct([m.get("max_position_error_m") for m in metrics])},
        "estimation": _estimation(metrics, cfg),
        "faults": faults,
        "hashes": {str(k): final[k].get("hash") for k in sorted(final)},
    }


__all__ = ["PARAMS", "summarize"]
