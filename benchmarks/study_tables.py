"""The study presets' tables for README (issue 34), from a campaign folder's manifest (complete or not).

Per cell, the median of each figure with its distribution-free 95 % interval and n (``oacli.campaign.aggregate``,
the same numbers as ``summary.json`` ``cells`` of a finished campaign), and the paired comparisons the verdicts use
(flights of one mission; the two controllers of one Experiment Set 3 replicate): how many pairs go which way, with
the two-sided sign test's p-value (ties dropped).

Run: ``python benchmarks/study_tables.py runs/study-fig3d`` (or ``runs/study-rattle``, ``runs/study-expset3``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from scipy.stats import binomtest

from oacli.campaign import manifest
from oacli.campaign.aggregate import FLIGHT_NAMES, run_figures
from oacli.campaign.cells import campaign_cells
from oacli.campaign.driver import load_existing
from oacli.campaign.intervals import median_interval, proportion_interval
from oacli.campaign.study_metrics import THETA_KEYS


def _m(stat: dict[str, Any], scale: float = 1.0, digits: int = 1) -> str:
    if stat.get("median") is None:
        return "–"
    med = stat["median"] * scale
    if stat.get("low") is None:
        return f"{med:.{digits}f} (n = {stat['n']}, no interval)"
    lo, hi = stat["low"] * scale, stat["high"] * scale
    fmt = lambda v: "∞" if math.isinf(v) else f"{v:.{digits}f}"  # noqa: E731
    return f"{fmt(med)} [{fmt(lo)}, {fmt(hi)}]"


def _p(flags: list[bool]) -> str:
    s = proportion_interval(sum(flags), len(flags))
    if not s["n"]:
        return "–"
    return f"{s['count']}/{s['n']} [{100 * s['low']:.0f}, {100 * s['high']:.0f} %]"


def _sign(diffs: list[float]) -> str:
    pos = sum(d > 0 for d in diffs)
    neg = sum(d < 0 for d in diffs)
    p = binomtest(pos, pos + neg).pvalue if pos + neg else float("nan")
    return f"{pos} > / {neg} < / {len(diffs) - pos - neg} = (p = {p:.2g})"


def load(folder: Path) -> tuple[Any, dict[str, list[tuple[int, dict[str, Any], str]]]]:
    """The campaign and, per cell, its completed runs ``(replicate, figures, status)`` in run order."""
    campaign = load_existing(folder)
    final = manifest.final_states(manifest.read(folder))
    index = json.loads((folder / "runs.json").read_text())["index"]
    ncells = max(len(campaign_cells(campaign.config)), 1)
    runs: dict[str, list[tuple[int, dict[str, Any], str]]] = {}
    for k, rec in sorted(final.items()):
        if rec["status"] not in manifest.COMPLETED or not rec.get("metrics"):
            continue
        cell = index[str(k)].get("cell", "all")
        figs = run_figures(rec["metrics"])
        figs["_metrics"] = rec["metrics"]
        figs["_dir"] = folder / rec["attempt"]
        runs.setdefault(cell, []).append((k // ncells, figs, rec["status"]))
    return campaign, runs


def stat(rows: list[tuple[int, dict[str, Any], str]], key: str) -> dict[str, Any]:
    return median_interval([f.get(key) for _, f, _ in rows])


def remeasure_overshoot(runs: dict[str, list[tuple[int, dict[str, Any], str]]]) -> int:
    """Each flight's overshoot again from its track.mcap along the final approach
    (:func:`oacli.mission.compare.approach_direction`; the campaign's rows were measured along the reference's last
    velocity by the code it ran). Returns how many changed by more than 1 mm."""
    from oacli.io.mcap_read import read_telemetry
    from oacli.mission.compare import approach_direction, overshoot_m

    changed = 0
    for rows in runs.values():
        for _, f, _ in rows:
            for key in f["_metrics"].get("comparison") or {}:
                name = FLIGHT_NAMES.get(key, key)
                if f.get(f"{name}.overshoot_m") is None:
                    continue
                tel = read_telemetry(f["_dir"] / "mission" / key / "track.mcap")
                new = overshoot_m(tel.t_true, tel.x_true[:, 0:3], tel.x_reference[-1, 0:3],
                                  approach_direction(tel.x_reference[:, 0:3]))
                changed += abs(new - f[f"{name}.overshoot_m"]) > 1e-3
                f[f"{name}.overshoot_m"] = new
    return changed


def fig3d(runs: dict[str, list[tuple[int, dict[str, Any], str]]]) -> None:
    te, mp, mu, tp = "seg3_tube_estimate", "seg3_mpc_prior", "seg3_mpc_prior_unconstrained", "seg3_tube_prior"
    print(f"overshoot re-measured along the final approach from the MCAPs: {remeasure_overshoot(runs)} flights "
          "changed by more than 1 mm")
    print("| cell | runs · reached segment 3 |"
          " overshoot [mm]: tube/estimate · std MPC/prior · std MPC/prior, no workspace · tube/prior |"
          " std MPC/prior saturated: runs, median time [s] | tube/estimate saturated runs |")
    print("|---|---|---|---|---|")
    for cell, rows in runs.items():
        sat = [f[f"{mp}.time_saturated_s"] > 0 for _, f, _ in rows if f.get(f"{mp}.time_saturated_s") is not None]
        sat_te = [f[f"{te}.time_saturated_s"] > 0 for _, f, _ in rows if f.get(f"{te}.time_saturated_s") is not None]
        over = " · ".join(_m(stat(rows, f"{x}.overshoot_m"), 1e3) for x in (te, mp, mu, tp))
        seg3 = sum(1 for _, f, _ in rows if f["_metrics"].get("comparison"))
        sat_s = _m(stat(rows, f"{mp}.time_saturated_s"), 1, 2)
        print(f"| {cell} | {len(rows)} · {seg3} | {over} | {_p(sat)}, {sat_s} | {_p(sat_te)} |")
    print()
    print("| cell | std MPC/prior, no workspace: keep-out entered · clearance [mm] | std MPC/prior (workspace rows):"
          " entered · clearance [mm] | tube/estimate: entered · clearance [mm] | tube/prior entered |")
    print("|---|---|---|---|---|")
    for cell, rows in runs.items():
        ent = {x: [bool((f.get(f"{x}.violations") is not None) and
                        int((f["_metrics"]["comparison"].get(_key(x)) or {}).get("keep_out_violations") or 0) > 0)
                   for _, f, _ in rows if f.get(f"{x}.violations") is not None] for x in (te, mp, mu, tp)}
        print(f"| {cell} | {_p(ent[mu])} · {_m(stat(rows, f'{mu}.keep_out_clearance_m'), 1e3, 2)} | "
              f"{_p(ent[mp])} · {_m(stat(rows, f'{mp}.keep_out_clearance_m'), 1e3, 2)} | "
              f"{_p(ent[te])} · {_m(stat(rows, f'{te}.keep_out_clearance_m'), 1e3, 2)} | {_p(ent[tp])} |")
    print()
    print("| cell | arrival (2 cm) [s]: tube/estimate · tube/prior | tube/prior later than tube/estimate (paired)"
          " | RMS [mm]: tube/estimate · std MPC/prior · tube/prior | std MPC/prior overshoots more than"
          " tube/estimate (paired) |")
    print("|---|---|---|---|---|")
    for cell, rows in runs.items():
        later = [f[f"{tp}.arrival_time_s"] - f[f"{te}.arrival_time_s"] for _, f, _ in rows
                 if f.get(f"{tp}.arrival_time_s") is not None and f.get(f"{te}.arrival_time_s") is not None
                 and not (math.isinf(f[f"{tp}.arrival_time_s"]) and math.isinf(f[f"{te}.arrival_time_s"]))]
        more = [f[f"{mp}.overshoot_m"] - f[f"{te}.overshoot_m"] for _, f, _ in rows
                if f.get(f"{mp}.overshoot_m") is not None and f.get(f"{te}.overshoot_m") is not None]
        arrive = " · ".join(_m(stat(rows, f"{x}.arrival_time_s"), 1, 2) for x in (te, tp))
        rms = " · ".join(_m(stat(rows, f"{x}.rms_position_error_m"), 1e3) for x in (te, mp, tp))
        print(f"| {cell} | {arrive} | {_sign(later)} | {rms} | {_sign(more)} |")
    statuses: dict[str, int] = {}
    for rows in runs.values():
        for _, _, s in rows:
            statuses[s] = statuses.get(s, 0) + 1
    print(f"\nmission statuses: {statuses}")


def _key(name: str) -> str:
    return next(k for k, v in FLIGHT_NAMES.items() if v == name)


def rattle(runs: dict[str, list[tuple[int, dict[str, Any], str]]]) -> None:
    flight_err, flight_red = (0.39, 0.91, 1.35, 6.92), (99, 68, 49, 25)
    for cell, rows in runs.items():
        print(f"cell {cell}: n = {len(rows)}")
        print("| parameter | RLS error [%] | flight error | RLS covariance reduction [%] | flight reduction |"
              " error ÷ reported σ | error ÷ Cramér-Rao σ |")
        print("|---|---|---|---|---|---|---|")
        own = [json.loads((f["_dir"] / "estimate" / "summary.json").read_text()).get("error_over_std") or {}
               for _, f, _ in rows]
        for i, p in enumerate(("mass", "Ixx", "Iyy", "Izz")):
            crb = median_interval([abs(f["_metrics"]["estimate"]["error_over_crb"][i]) for _, f, _ in rows
                                   if f["_metrics"].get("estimate")])
            sig = median_interval([o.get(THETA_KEYS[i]) for o in own])
            print(f"| {p} | {_m(stat(rows, f'rls.abs_error_pct.{p}'), 1, 2)} | {flight_err[i]} | "
                  f"{_m(stat(rows, f'rls.cov_reduction_pct.{p}'), 1, 3)} | {flight_red[i]} | {_m(sig, 1, 2)} | "
                  f"{_m(crb, 1, 2)} |")
        statuses: dict[str, int] = {}
        for _, _, s in rows:
            statuses[s] = statuses.get(s, 0) + 1
        print(f"statuses: {statuses}")


def expset3(runs: dict[str, list[tuple[int, dict[str, Any], str]]]) -> None:
    keys = (("hold_rms_m", 1e3, "mm"), ("hold_max_m", 1e3, "mm"), ("lag_s", 1, "s"),
            ("lag_residual_rms_m", 1e3, "mm"), ("rms_position_error_m", 1e3, "mm"))
    tube, std = runs.get("controller=tube", []), runs.get("controller=standard", [])
    by_rep = {r: f for r, f, _ in std}
    print(f"| figure | tube MPC (n = {len(tube)}) | standard MPC (n = {len(std)}) | paired tube − standard |")
    print("|---|---|---|---|")
    for key, scale, unit in keys:
        diffs = [f[key] - by_rep[r][key] for r, f, _ in tube
                 if r in by_rep and f.get(key) is not None and by_rep[r].get(key) is not None]
        med = median_interval(diffs)
        print(f"| {key} [{unit}] | {_m(stat(tube, key), scale, 2)} | {_m(stat(std, key), scale, 2)} | "
              f"{_sign(diffs)}, median {_m(med, scale, 2)} |")
    # Sluggishness at the goal: from the reference's stop, the time until the robot stays within 1 cm / 2 cm of it
    for tol in (0.01, 0.02):
        settle = {name: {r: settle_s(f["_dir"] / "track" / "track.mcap", tol) for r, f, _ in rows}
                  for name, rows in (("tube", tube), ("standard", std))}
        diffs = [settle["tube"][r] - settle["standard"][r] for r in settle["tube"] if r in settle["standard"]
                 and not (math.isinf(settle["tube"][r]) and math.isinf(settle["standard"][r]))]
        print(f"| settle_{100 * tol:.0f}cm_s [s] | {_m(median_interval(list(settle['tube'].values())), 1, 2)} | "
              f"{_m(median_interval(list(settle['standard'].values())), 1, 2)} | {_sign(diffs)}, median "
              f"{_m(median_interval(diffs), 1, 2)} |")
    for name, rows in (("tube", tube), ("standard", std)):
        statuses: dict[str, int] = {}
        for _, _, s in rows:
            statuses[s] = statuses.get(s, 0) + 1
        print(f"{name} statuses: {statuses}")


def settle_s(track_mcap: Path, tolerance_m: float) -> float:
    """Time from the reference's stop until the true position stays within ``tolerance_m`` of its end [s]
    (``inf``: never; 0: already there when it stopped)."""
    import numpy as np

    from oacli.io.mcap_read import read_telemetry
    from oacli.mission.compare import arrival_time_s

    tel = read_telemetry(track_mcap)
    ref = np.asarray(tel.x_reference, dtype=float)
    moving = np.flatnonzero(np.linalg.norm(ref[:, 3:6], axis=1) > 1e-6)
    t_stop = float(tel.t_ctrl[moving[-1] + 1]) if moving.size and moving[-1] + 1 < len(tel.t_ctrl) else 0.0
    arrival = arrival_time_s(tel.t_true, tel.x_true[:, 0:3], ref[-1, 0:3], tolerance_m)
    return math.inf if arrival is None else max(0.0, arrival - t_stop)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    folder = parser.parse_args().folder
    campaign, runs = load(folder)
    print(f"{campaign.config.name}: {sum(len(v) for v in runs.values())} completed runs of {campaign.config.runs}")
    {"study-fig3d": fig3d, "study-rattle": rattle, "study-expset3": expset3}[campaign.config.name](runs)


if __name__ == "__main__":
    main()
