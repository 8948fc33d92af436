"""The campaign's statistics over its runs' final manifest records (``summary.json``; ``docs/campaign.md``).

Success means the job ran to its end without an ``unsafe`` status (``ok`` or ``degraded``). Tracking errors are
percentiles over the completed runs. Estimation errors (``job: mission``) are percentiles of the absolute percent
errors next to the flight figures ([ReSWARM2023] RATTLE table: mass 0.39 %, inertias 0.91 / 1.35 / 6.92 %) and of the
errors in units of the Cramér-Rao bound's σ ([Doerr2021] Eq. 32): an efficient, unbiased estimator has RMS 1 there.

``cells`` holds, per study cell (:mod:`oacli.campaign.cells`; one cell ``all`` without a grid), every per-run figure
of :func:`run_figures` as a median with its distribution-free 95 % interval and every yes/no figure of
:func:`run_events` as a fraction with its Clopper-Pearson interval (:mod:`oacli.campaign.intervals`), over the cell's
completed runs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.campaign import manifest
from oacli.campaign.cells import campaign_cells
from oacli.campaign.intervals import median_interval, proportion_interval
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


FLIGHT_NAMES = {"segment-3/track": "seg3_tube_estimate", "segment-3/baseline-mpc-prior": "seg3_mpc_prior",
                "segment-3/baseline-tube-prior": "seg3_tube_prior",
                "segment-3/baseline-mpc-unconstrained-prior": "seg3_mpc_prior_unconstrained"}
"""Short names of segment 3's flights ([Doerr2021] Fig. 3(d)) in the per-run figures; other stage keys (a mission
with another baseline) keep their key."""

FLIGHT_FIELDS = ("rms_position_error_m", "max_position_error_m", "overshoot_m", "time_saturated_s", "arrival_time_s",
                 "control_effort_Ns", "keep_out_clearance_m")
RESPONSE_FIELDS = ("lag_s", "lag_residual_rms_m", "hold_rms_m", "hold_max_m")


def _flight_name(key: str) -> str:
    return FLIGHT_NAMES.get(key, key.replace("/", "_"))


def run_figures(m: dict[str, Any]) -> dict[str, float | None]:
    """One run's scalar figures, flat (the per-cell statistics' inputs).

    Keys: ``rms_position_error_m``, ``max_position_error_m`` (a mission: segment 3's tube flight); per segment-3
    flight ``<flight>.<field>`` for :data:`FLIGHT_FIELDS` and ``<flight>.violations`` (keep-in + keep-out + limit),
    a flight that never arrives counting as ``inf``; per estimator (``batch``, ``sequential``) and parameter
    ``<estimator>.abs_error_pct.<p>`` (``rls`` for the flight's estimator) and
    ``<estimator>.cov_reduction_pct.<p>``; a track's :data:`RESPONSE_FIELDS`.

    Parameters
    ----------
    m : dict
        The run's manifest metrics.

    Returns
    -------
    dict
    """
    out: dict[str, float | None] = {"rms_position_error_m": m.get("rms_position_error_m"),
                                    "max_position_error_m": m.get("max_position_error_m")}
    for key, row in (m.get("comparison") or {}).items():
        name = _flight_name(key)
        if row.get("rms_position_error_m") is None:
            continue  # a failed flight: counted by its status, not in the figures
        for field in FLIGHT_FIELDS:
            value = row.get(field)
            out[f"{name}.{field}"] = float("inf") if field == "arrival_time_s" and value is None else value
        out[f"{name}.violations"] = float(sum(int(row.get(k) or 0) for k in
                                              ("keep_in_violations", "keep_out_violations", "limit_violations")))
    for label, est in (("batch", m.get("estimate")), ("sequential", m.get("estimate_sequential"))):
        if not est:
            continue
        label = "rls" if est.get("method") == "rls" else label  # job excite-estimate with the flight's RLS
        for i, p in enumerate(PARAMS):
            err = (est.get("error_pct") or [None] * 4)[i]
            out[f"{label}.abs_error_pct.{p}"] = None if err is None else abs(float(err))
            red = (est.get("cov_reduction_pct") or [None] * 4)[i]
            out[f"{label}.cov_reduction_pct.{p}"] = None if red is None else float(red)
    for field in RESPONSE_FIELDS:
        if field in m:
            out[field] = m[field]
    return out


def run_events(status: str, m: dict[str, Any]) -> dict[str, bool]:
    """One run's yes/no figures: ``unsafe``, ``any_violation``, per segment-3 flight ``<flight>.keep_out_entered``
    (its body entered a keep-out zone), ``<flight>.never_arrived`` and ``<flight>.saturated``.

    Parameters
    ----------
    status : str
        The run's final status.
    m : dict
        Its manifest metrics.

    Returns
    -------
    dict
    """
    out = {"unsafe": status == "unsafe",
           "any_violation": any(int(v) > 0 for v in (m.get("violations") or {}).values())}
    for key, row in (m.get("comparison") or {}).items():
        if row.get("rms_position_error_m") is None:
            continue
        name = _flight_name(key)
        out[f"{name}.keep_out_entered"] = int(row.get("keep_out_violations") or 0) > 0
        out[f"{name}.never_arrived"] = row.get("arrival_time_s") is None
        out[f"{name}.saturated"] = float(row.get("time_saturated_s") or 0.0) > 0.0
    return out


def cell_statistics(cfg: CampaignConfig, final: dict[int, dict[str, Any]],
                    runs_index: dict[str, Any]) -> list[dict[str, Any]]:
    """Per cell: its levels, runs, and every figure's median / fraction with a 95 % interval (module docstring).

    Parameters
    ----------
    cfg : CampaignConfig
    final : dict of int to dict
        Final manifest records.
    runs_index : dict
        ``runs.json``'s index (each run's ``cell`` with a grid).

    Returns
    -------
    list of dict
        In cell order: ``name``, ``levels``, ``runs`` (planned), ``completed``, ``figures`` (name ->
        :func:`oacli.campaign.intervals.median_interval`), ``events`` (name ->
        :func:`oacli.campaign.intervals.proportion_interval`).
    """
    cells = campaign_cells(cfg)
    names = [c.name for c in cells] or ["all"]
    levels = {c.name: c.levels for c in cells}
    planned = dict.fromkeys(names, 0)
    for entry in runs_index.values():
        cell = entry.get("cell", "all") if cells else "all"
        if cell in planned:
            planned[cell] += 1
    figures: dict[str, dict[str, list[float | None]]] = {n: {} for n in names}
    events: dict[str, dict[str, list[bool]]] = {n: {} for n in names}
    for k, rec in sorted(final.items()):
        if rec["status"] not in manifest.COMPLETED or not rec.get("metrics"):
            continue
        cell = (runs_index.get(str(k)) or {}).get("cell", "all") if cells else "all"
        if cell not in figures:
            continue
        for key, value in run_figures(rec["metrics"]).items():
            figures[cell].setdefault(key, []).append(value)
        for key, flag in run_events(rec["status"], rec["metrics"]).items():
            events[cell].setdefault(key, []).append(bool(flag))
    out = []
    for n in names:
        completed = max((len(v) for v in events[n].values()), default=0)
        out.append({
            "name": n, "levels": levels.get(n, {}), "runs": planned[n], "completed": completed,
            "figures": {key: median_interval(vals) for key, vals in figures[n].items()
                        if any(v is not None for v in vals)},
            "events": {key: proportion_interval(sum(flags), len(flags)) for key, flags in events[n].items()},
        })
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
        "cells": cell_statistics(cfg, final, runs_index),
        "hashes": {str(k): final[k].get("hash") for k in sorted(final)},
    }


__all__ = ["FLIGHT_NAMES", "PARAMS", "cell_statistics", "run_events", "run_figures", "summarize"]
