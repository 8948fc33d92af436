"""The content of a campaign's report, read from its folder (``summary.json``, ``manifest.jsonl``, ``runs.json``,
``plots/``, the runs' attempt folders).

Shown: the status counts and the printed table's figures, per cell every figure's median with its distribution-free
95 % interval and every yes/no figure's fraction with its Clopper-Pearson interval (``summary.json`` ``cells``,
:mod:`oacli.campaign.aggregate`), the CDFs (``plots/`` and, with several cells, per cell), and one row per run with
the command that reruns it and the path of its recording.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from oacli.campaign import manifest
from oacli.campaign.aggregate import run_figures
from oacli.campaign.outputs import table_rows
from oacli.errors import InputError
from oacli.report.folder import read_png, read_summary

HEADLINE = ("seg3_tube_estimate.rms_position_error_m", "seg3_mpc_prior.rms_position_error_m",
            "seg3_tube_prior.rms_position_error_m", "seg3_mpc_prior.overshoot_m", "seg3_mpc_prior.time_saturated_s",
            "seg3_tube_prior.arrival_time_s", "seg3_mpc_prior.keep_out_clearance_m",
            "seg3_mpc_prior_unconstrained.keep_out_clearance_m",
            "sequential.abs_error_pct.mass", "sequential.abs_error_pct.Izz", "sequential.cov_reduction_pct.mass",
            "batch.abs_error_pct.mass", "batch.abs_error_pct.Izz", "hold_rms_m", "lag_s", "hold_max_m",
            "rms_position_error_m")
"""The figures drawn in the per-cell interval plot, in this order, those present (at most :data:`MAX_PANELS`)."""
MAX_PANELS = 9
FLIGHT_PCT = {"mass": 0.39, "Ixx": 0.91, "Iyy": 1.35, "Izz": 6.92}
FLIGHT_COV_PCT = {"mass": 99.0, "Ixx": 68.0, "Iyy": 49.0, "Izz": 25.0}


def unit_of(key: str) -> tuple[str, float]:
    """Display unit and scale of a figure by its name's suffix (``_m`` shown in mm)."""
    if key.endswith("_m"):
        return "mm", 1e3
    if key.endswith("_Ns"):
        return "N·s", 1.0
    if key.endswith("_s"):
        return "s", 1.0
    if ".abs_error_pct." in key or ".cov_reduction_pct." in key or key.endswith("_pct"):
        return "%", 1.0
    return "", 1.0


def flight_figure(key: str) -> float | None:
    """The [ReSWARM2023] RATTLE table's figure for an estimation key, else None."""
    param = key.rsplit(".", 1)[-1]
    if ".abs_error_pct." in key:
        return FLIGHT_PCT.get(param)
    if ".cov_reduction_pct." in key:
        return FLIGHT_COV_PCT.get(param)
    return None


def _scaled(value: float | None, scale: float) -> float | None:
    if value is None:
        return None
    return value * scale if math.isfinite(value) else value


def interval_rows(cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per figure, one row per cell: median and 95 % interval in display units.

    Parameters
    ----------
    cells : list of dict
        ``summary.json`` ``cells``.

    Returns
    -------
    list of dict
        ``key``, ``unit``, ``flight``, ``headline``, ``cells``: [``name``, ``median``, ``low``, ``high``, ``n``].
    """
    keys: list[str] = []
    for c in cells:
        keys += [k for k in c["figures"] if k not in keys]
    out = []
    for key in keys:
        unit, scale = unit_of(key)
        rows = []
        for c in cells:
            f = c["figures"].get(key)
            if f is None:
                continue
            rows.append({"name": c["name"], "median": _scaled(f["median"], scale), "low": _scaled(f["low"], scale),
                         "high": _scaled(f["high"], scale), "n": f["n"]})
        out.append({"key": key, "unit": unit, "flight": flight_figure(key), "headline": key in HEADLINE,
                    "cells": rows})
    out.sort(key=lambda r: (not r["headline"], HEADLINE.index(r["key"]) if r["headline"] else 0))
    return out


def event_rows(cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per yes/no figure, one row per cell: the fraction of runs and its 95 % interval."""
    keys: list[str] = []
    for c in cells:
        keys += [k for k in c["events"] if k not in keys]
    return [{"key": key, "cells": [{"name": c["name"], **c["events"][key]} for c in cells if key in c["events"]]}
            for key in keys]


def run_rows(folder: Path, final: dict[int, dict[str, Any]], index: dict[str, Any], job: str) -> list[dict[str, Any]]:
    """One row per run: status, cell, headline error, hash, the rerun command, the recording's path.

    Parameters
    ----------
    folder : Path
        The campaign folder.
    final : dict of int to dict
        Final manifest records.
    index : dict
        ``runs.json`` ``index``.
    job : str
        The campaign's job (where the recording lies in an attempt folder).

    Returns
    -------
    list of dict
    """
    recording = {"mission": "mission/mission.rrd", "track": "track/track.rrd"}.get(job)
    rows = []
    for k_str in sorted(index, key=int):
        k = int(k_str)
        rec = final.get(k)
        entry = index[k_str]
        rrd = None
        if rec and rec.get("attempt") and recording:
            path = folder / rec["attempt"] / recording
            rrd = str(path.resolve()) if path.is_file() else None
        metrics = (rec or {}).get("metrics") or {}
        rms = metrics.get("rms_position_error_m")
        rows.append({"k": k, "cell": entry.get("cell", ""), "status": (rec or {}).get("status", "not run"),
                     "faults": ", ".join(entry.get("faults") or ()), "rms_mm": None if rms is None else 1e3 * rms,
                     "hash": ((rec or {}).get("hash") or "")[:12], "error": (rec or {}).get("error"),
                     "rerun": f"oacli campaign rerun {folder} {k}", "recording": rrd})
    return rows


def campaign_figures(folder: Path, summary: dict[str, Any], final: dict[int, dict[str, Any]],
                     index: dict[str, Any]) -> list[dict[str, Any]]:
    """The campaign's figures: ``plots/`` (status counts, tracking error histogram and CDF, estimation-error CDFs),
    the per-cell intervals and, with several cells, per-cell CDFs.

    Parameters
    ----------
    folder : Path
    summary : dict
    final : dict of int to dict
    index : dict

    Returns
    -------
    list of dict
    """
    from oacli.report.figures import cell_cdfs, cell_intervals

    captions = {"status": "Final status of every run.",
                "tracking_error": "RMS position error of the runs (a mission: segment 3's tube flight): histogram "
                "and empirical CDF.",
                "estimation_error": "Empirical CDFs of the batch estimate's |error| per parameter, the flight's "
                "figure dashed ([ReSWARM2023] RATTLE table)."}
    figures = []
    for name, rel in ((summary.get("files") or {}).get("plots") or {}).items():
        figures.append({"id": f"plot-{name}", "title": name.replace("_", " "), "caption": captions.get(name, ""),
                        "png": read_png(folder / rel), "source": rel})
    cells = summary.get("cells") or []
    rows = [r for r in interval_rows(cells) if r["headline"]][:MAX_PANELS]
    if rows and cells:
        panels = [{"title": r["key"], "unit": r["unit"], "flight": r["flight"],
                   "rows": [(c["name"], c["median"], c["low"], c["high"], c["n"]) for c in r["cells"]]} for r in rows]
        figures.append({"id": "cell-intervals", "title": "Per-cell medians with 95 % intervals",
                        "caption": "Median of each figure per cell and its distribution-free 95 % interval (order "
                        "statistics; none below 6 runs); red dashed: the flight's figure.",
                        "png": cell_intervals(panels), "source": "drawn from summary.json (cells)"})
    if len(cells) > 1 and rows:
        key = rows[0]["key"]
        unit, scale = unit_of(key)
        series: dict[str, list[float]] = {c["name"]: [] for c in cells}
        for k, rec in final.items():
            if rec.get("status") in manifest.COMPLETED and rec.get("metrics"):
                value = run_figures(rec["metrics"]).get(key)
                cell = (index.get(str(k)) or {}).get("cell")
                if value is not None and cell in series:
                    series[cell].append(scale * float(value))
        figures.append({"id": "cell-cdfs", "title": f"CDF per cell: {key}",
                        "caption": "Empirical CDF of the first headline figure, one line per cell.",
                        "png": cell_cdfs(key, unit, {n: np.asarray(v) for n, v in series.items()}),
                        "source": "drawn from manifest.jsonl"})
    return figures


def campaign_context(folder: Path) -> dict[str, Any]:
    """Everything the campaign page shows.

    Parameters
    ----------
    folder : Path
        A campaign folder.

    Returns
    -------
    dict

    Raises
    ------
    InputError
        No ``summary.json`` (not finalised), an unreadable ``runs.json``, or a cut PNG.
    """
    if not (folder / "summary.json").is_file():
        raise InputError(f"{folder}: no summary.json: the campaign has not finished "
                         f"(oacli campaign {folder} --resume)")
    summary = read_summary(folder)
    try:
        index = json.loads((folder / "runs.json").read_text())["index"]
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError(f"{folder / 'runs.json'}: not a campaign run index") from None
    final = manifest.final_states(manifest.read(folder))
    cells = summary.get("cells") or []
    return {
        "kind": "campaign",
        "title": f"campaign {summary.get('name', folder.name)}",
        "summary": summary,
        "complete": summary.get("status") == "complete",
        "table": table_rows(summary) if "status_counts" in summary else [],
        "cells": cells,
        "intervals": interval_rows(cells),
        "events": event_rows(cells),
        "runs": run_rows(folder, final, index, str(summary.get("job"))),
        "figures": campaign_figures(folder, summary, final, index),
        "config_text": (folder / "campaign.yaml").read_text() if (folder / "campaign.yaml").is_file() else None,
        "base_text": (folder / "base.yaml").read_text() if (folder / "base.yaml").is_file() else None,
        "files": {"folder": str(folder.resolve()),
                  "recording": str((folder / "campaign.rrd").resolve()) if (folder / "campaign.rrd").is_file()
                  else None},
        "commands": {"resume": None if summary.get("status") == "complete" else f"oacli campaign {folder} --resume"},
    }


__all__ = ["campaign_context", "campaign_figures", "event_rows", "interval_rows", "run_rows"]
