"""The campaign's outputs: PNG histograms and CDFs, the per-run metrics in a Rerun recording and an MCAP, a table.

``campaign.rrd`` holds one sample per completed run on the sequence timeline ``run`` (run index) under
``campaign/<metric>``, each run's status and histograms (:mod:`oacli.io.rerun.campaign`); ``campaign.mcap`` holds
one ``/campaign/run`` JSON record per finished run (``t`` = run index [s], a placeholder time) and the
``/campaign/summary`` record. Both are derived from ``manifest.jsonl``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from oacli.campaign.aggregate import PARAMS

RUN_TIMELINE = "run"
RUN_SCHEMA = {"type": "object", "properties": {"k": {"type": "integer"}, "status": {"type": "string"},
                                               "hash": {"type": ["string", "null"]}, "metrics": {"type": "object"}}}
SUMMARY_SCHEMA = {"type": "object", "properties": {"success_rate": {"type": "number"}}}


def _series(final: dict[int, dict[str, Any]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per-run scalar series of the completed runs: (run indices, values)."""
    out: dict[str, list[tuple[int, float]]] = {}
    for k in sorted(final):
        m = final[k].get("metrics") or {}
        if not m:
            continue
        values = {"rms_position_error_mm": 1e3 * (m.get("rms_position_error_m") or np.nan),
                  "max_position_error_mm": 1e3 * (m.get("max_position_error_m") or np.nan),
                  "violations": float(sum(m.get("violations", {}).values())),
                  "tube_violations_true": float(m.get("tube_violations_true", 0)),
                  "fallback_steps": float(m.get("fallback_steps", 0))}
        est = m.get("estimate")
        if est:
            for name, e in zip(PARAMS, est["error_pct"], strict=True):
                values[f"estimate_error_pct/{name}"] = float(e)
        for key, v in values.items():
            out.setdefault(key, []).append((k, v))
    return {key: (np.array([p[0] for p in pts]), np.array([p[1] for p in pts], dtype=float))
            for key, pts in out.items()}


def _cdf(ax: Any, values: np.ndarray, **kwargs: Any) -> None:
    """Empirical CDF of ``values`` as a step line from 0 (visible with a single run too)."""
    xs = np.sort(values)
    ax.step(np.r_[xs[0], xs], np.r_[0.0, np.arange(1, xs.size + 1) / xs.size], where="post", **kwargs)
    ax.set_ylim(0.0, 1.05)


def write_plots(folder: Path, final: dict[int, dict[str, Any]], summary: dict[str, Any]) -> dict[str, str]:
    """Histogram and CDF of the tracking error, CDFs of the estimation errors with the flight figures, statuses.

    Parameters
    ----------
    folder : Path
        The campaign folder (``plots/`` is created).
    final : dict of int to dict
        Final manifest records.
    summary : dict
        :func:`oacli.campaign.aggregate.summarize`'s result.

    Returns
    -------
    dict of str to str
        Plot name to path relative to ``folder``.
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    from oacli.io.plots.common import save_png

    plots = folder / "plots"
    plots.mkdir(exist_ok=True)
    series = _series(final)
    written: dict[str, str] = {}
    fig, ax = plt.subplots(figsize=(6, 3.5))
    names = list(summary["status_counts"])
    ax.bar(names, [summary["status_counts"][n] for n in names], color="#5a8ff0")
    ax.set_ylabel("runs")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_title(f"{summary['name']}: run status ({summary['runs']} runs)")
    save_png(fig, plots / "status.png")
    written["status"] = "plots/status.png"
    v = series["rms_position_error_mm"][1] if "rms_position_error_mm" in series else np.empty(0)
    v = v[np.isfinite(v)]
    if v.size:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5))
        a1.hist(v, bins=max(5, min(40, v.size // 2)), color="#5a8ff0")
        a1.set_xlabel("RMS position error [mm]")
        a1.set_ylabel("runs")
        a1.set_title("tracking error: histogram")
        _cdf(a2, v)
        a2.set_xlabel("RMS position error [mm]")
        a2.set_ylabel("fraction of runs ≤")
        a2.set_title("tracking error: CDF")
        a2.grid(alpha=0.3)
        save_png(fig, plots / "tracking_error.png")
        written["tracking_error"] = "plots/tracking_error.png"
    est = summary.get("estimation")
    if est:
        fig, axes = plt.subplots(1, 4, figsize=(14, 3.5))
        for ax, name in zip(axes, PARAMS, strict=True):
            v = np.abs(series[f"estimate_error_pct/{name}"][1])
            _cdf(ax, v, label="simulated runs")
            ax.axvline(est["flight_pct"][name], color="#d04040", ls="--", label="flight (ReSWARM)")
            ax.set_xlabel(f"|{name} error| [%]")
            ax.set_title(f"{name}: {est['agreement'][name]['verdict']}")
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("fraction of runs ≤")
        axes[0].legend(loc="lower right", fontsize=8)
        save_png(fig, plots / "estimation_error.png")
        written["estimation_error"] = "plots/estimation_error.png"
    return written


def write_recording(path: Path, final: dict[int, dict[str, Any]], name: str) -> None:
    """The per-run metrics, statuses and histograms as a Rerun recording with its layout
    (:mod:`oacli.io.rerun.campaign`).

    Parameters
    ----------
    path : Path
        ``campaign.rrd``.
    final : dict of int to dict
        Final manifest records.
    name : str
        Recording name.
    """
    from oacli.io.rerun.campaign import write_campaign_recording

    runs = {k: (str(rec["status"]), rec.get("error")) for k, rec in final.items()}
    write_campaign_recording(path, _series(final), runs, name)


def write_mcap(path: Path, final: dict[int, dict[str, Any]], summary: dict[str, Any], config_yaml: str) -> None:
    """One ``/campaign/run`` record per finished run and the ``/campaign/summary`` record (module docstring).

    Parameters
    ----------
    path : Path
        ``campaign.mcap``.
    final : dict of int to dict
        Final manifest records.
    summary : dict
        The statistics.
    config_yaml : str
        The campaign config, attached.
    """
    from oacli.io.mcap_io import StageMcapWriter

    with StageMcapWriter(path, stage="campaign", config_yaml=config_yaml,
                         metadata={"seed": summary["seed"]}, overwrite=True) as writer:
        for k in sorted(final):
            rec = final[k]
            writer.write_json("/campaign/run", "oacli.CampaignRun", RUN_SCHEMA, float(k),
                              {"k": k, "status": rec["status"], "hash": rec.get("hash"),
                               "metrics": rec.get("metrics") or {}, "error": rec.get("error")})
        writer.write_json("/campaign/summary", "oacli.CampaignSummary", SUMMARY_SCHEMA, float(max(final, default=0)),
                          {k: v for k, v in summary.items() if k != "hashes"})


def _fmt(v: Any, scale: float = 1.0, unit: str = "") -> str:
    return "—" if v is None else f"{v * scale:.3g}{unit}"


def table_rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """The printed table's rows (label, value).

    Parameters
    ----------
    summary : dict

    Returns
    -------
    list of (str, str)
    """
    c = summary["status_counts"]
    t = summary["tracking"]["rms_position_error_m"]
    rows = [
        ("runs", f"{summary['runs']} ({summary['finished']} finished)"),
        ("success rate (success: the run ended ok or degraded, i.e. finished without a safety breach)",
         f"{100 * summary['success_rate']:.1f} % ({c['ok']} ok + {c['degraded']} degraded of {summary['runs']} runs)"),
        ("ok / degraded / unsafe", f"{c['ok']} / {c['degraded']} / {c['unsafe']}"),
        ("failed / infra_failed", f"{c['failed']} / {c['infra_failed']}"),
        ("keep-in / keep-out / limit violations",
         " / ".join(str(summary["violations"][k]) for k in ("keep_in", "keep_out", "limits"))),
        ("tube violations (true state)", str(summary["tube_violations_true"])),
        ("fallback steps", str(summary["fallback_steps"])),
        ("RMS position error p5 / p50 / p95",
         f"{_fmt(t['p5'], 1e3)} / {_fmt(t['p50'], 1e3)} / {_fmt(t['p95'], 1e3)} mm"),
    ]
    est = summary.get("estimation")
    if est:
        for name in PARAMS:
            a = est["agreement"][name]
            crb = est["error_over_crb"][name]
            rows.append((f"|{name} error| p50 / p95 (flight)",
                         f"{a['median_abs_error_pct']:.3g} / {a['p95']:.3g} % ({a['flight_pct']} %): {a['verdict']}; "
                         f"RMS error/σ_CRB {_fmt(crb['rms'])}"))
    for name, f in summary["faults"].items():
        rows.append((f"fault {name}", f"{f['runs']} runs, success (ok or degraded) "
                                      f"{_fmt(f['success_rate'], 100, ' %')}"))
    return rows


def print_table(summary: dict[str, Any]) -> None:
    """Print the statistics as a rich table on stdout."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"campaign {summary['name']} ({summary['job']}, seed {summary['seed']})")
    table.add_column("figure")
    table.add_column("value")
    for label, value in table_rows(summary):
        table.add_row(label, value)
    Console(width=160).print(table)


__all__ = ["print_table", "table_rows", "write_mcap", "write_plots", "write_recording"]
