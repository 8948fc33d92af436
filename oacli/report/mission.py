"""The content of a mission's report, read from its folder (``summary.json``, the stage MCAPs, ``plots/``).

Figures: the tracking error per segment with the tube bands (:func:`oacli.report.figures.tracking_bands`, drawn from
the MCAPs once and kept in ``plots/tracking_bands.png`` when the mission has a ``plots/`` folder), the estimates
converging with ± 2σ and the paths (``plots/estimate_convergence.png`` and ``plots/paths.png`` when the mission drew
them, otherwise drawn here from the MCAPs by the mission's own plot functions). The stage MCAPs are read only for a
figure not found in ``plots/``. A mission that did not end complete gets its status, error and config, no figures.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

from oacli.errors import InputError
from oacli.io.atomic import write_bytes_atomic
from oacli.report.folder import read_png
from oacli.status import COMPLETE_STATUSES

PARAMS = (("mass", "kg"), ("Ixx", "kg·m²"), ("Iyy", "kg·m²"), ("Izz", "kg·m²"))
THETA_KEYS = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")
FLIGHT_ERROR_PCT = (0.39, 0.91, 1.35, 6.92)
"""[ReSWARM2023] RATTLE table: % error per parameter."""
FLIGHT_COV_REDUCTION_PCT = (99.0, 68.0, 49.0, 25.0)
"""[ReSWARM2023] RATTLE table: % covariance reduction per parameter."""


def _theta(value: Any) -> list[Any]:
    if isinstance(value, dict):
        return [value.get(k) for k in THETA_KEYS]
    if isinstance(value, list | tuple):
        return list(value)
    return [None] * 4


def _stage_summary(folder: Path, rel: str) -> dict[str, Any]:
    path = folder / rel / "summary.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def segment_rows(folder: Path, summary: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per segment: route, mission times, its stages' statuses, its main flight's errors.

    Parameters
    ----------
    folder : Path
        The mission folder.
    summary : dict
        Its ``summary.json``.

    Returns
    -------
    list of dict
    """
    rows = []
    stages = summary.get("stages") or {}
    for seg, info in (summary.get("segments") or {}).items():
        mine = {k: v for k, v in stages.items() if k.startswith(seg + "/")}
        track = _stage_summary(folder, f"{seg}/track")
        rows.append({
            "segment": seg, "route": f"{info.get('from', '?')} → {info.get('to', '?')}",
            "start_s": info.get("start_time_s"), "duration_s": info.get("duration_s"),
            "stages": [{"key": k.split("/", 1)[1], "status": v.get("status"), "wall_s": v.get("wall_time_s")}
                       for k, v in mine.items()],
            "controller": track.get("controller"),
            "rms_mm": None if track.get("rms_position_error_m") is None else 1e3 * track["rms_position_error_m"],
            "max_mm": None if track.get("max_position_error_m") is None else 1e3 * track["max_position_error_m"],
            "status": track.get("status"),
        })
    return rows


def estimate_rows(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """Per parameter: the batch estimate, ± σ, truth, error, covariance reduction, the sequential estimate's error,
    beside the flight's figures ([ReSWARM2023] RATTLE table).

    Parameters
    ----------
    summary : dict
        The mission's ``summary.json``.

    Returns
    -------
    list of dict
    """
    est = summary.get("estimate") or {}
    seq = summary.get("estimate_sequential") or {}
    if not est.get("mass_kg"):
        return []
    value = [est.get("mass_kg"), *(est.get("inertia_kgm2") or [None] * 3)]
    std, truth = _theta(est.get("std")), _theta(est.get("truth_theta"))
    err, red = _theta(est.get("error_pct")), _theta(est.get("cov_reduction_pct"))
    seq_err = _theta(seq.get("error_pct"))
    return [{"param": name, "unit": unit, "value": value[i], "std": std[i], "truth": truth[i], "error_pct": err[i],
             "cov_reduction_pct": red[i], "sequential_error_pct": seq_err[i], "flight_error_pct": FLIGHT_ERROR_PCT[i],
             "flight_cov_reduction_pct": FLIGHT_COV_REDUCTION_PCT[i]} for i, (name, unit) in enumerate(PARAMS)]


def comparison_rows(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """Segment 3's flights ([Doerr2021] Fig. 3(d)) as the mission measured them (``summary.json``).

    Parameters
    ----------
    summary : dict

    Returns
    -------
    list of dict
    """
    out = []
    for key, row in (summary.get("comparison") or {}).items():
        out.append({"key": key, **row})
    return out


BANDS_PNG = "plots/tracking_bands.png"
"""Where the report keeps its tracking-error figure in a mission folder whose ``plots/`` the mission drew: a later
``oacli report`` of the same (finished, unchanging) folder inlines it instead of reading every stage MCAP and
drawing it again."""


class _Records:
    """The mission's records, read on first use only (a report whose figures are all in ``plots/`` reads none)."""

    def __init__(self, folder: Path, summary: dict[str, Any]) -> None:
        self.folder, self.summary = folder, summary
        self._records: Any = None

    def get(self) -> Any:
        if self._records is None:
            from oacli.mission.records import load_mission_records

            try:
                self._records = load_mission_records(self.folder, self.summary)
            except FileNotFoundError as exc:
                raise InputError(f"{self.folder}: {exc}") from None
        return self._records


def _drawn(folder: Path, summary: dict[str, Any], name: str, draw: str, records: _Records) -> tuple[bytes, str]:
    rel = ((summary.get("files") or {}).get("plots") or {}).get(name)
    if rel and (folder / rel).is_file():
        return read_png(folder / rel), rel
    from oacli.mission import plots  # matplotlib: only when a figure is drawn here

    with tempfile.TemporaryDirectory(prefix="oacli-report-") as tmp:
        path = getattr(plots, draw)(records.get(), Path(tmp) / f"{name}.png")
        return path.read_bytes(), "drawn from the stage MCAPs"


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The bytes an MCAP file starts and ends with (the MCAP specification, "Magic")."""


def check_stage_mcaps(folder: Path, summary: dict[str, Any]) -> None:
    """Refuse a mission whose stage MCAPs are not whole (each must end with :data:`MCAP_MAGIC`), without reading them.

    Raises
    ------
    InputError
        Naming the first cut or missing file.
    """
    from oacli.mission.layout import stage_by_key

    for key, entry in (summary.get("stages") or {}).items():
        if (entry or {}).get("status") not in COMPLETE_STATUSES:
            continue  # not run, or failed: no file to check
        try:
            path = stage_by_key(key).mcap(folder)
        except KeyError:
            continue
        try:
            with path.open("rb") as fh:
                head = fh.read(len(MCAP_MAGIC))
                fh.seek(-len(MCAP_MAGIC), 2)
                tail = fh.read()
        except OSError as exc:
            raise InputError(f"{path}: not readable ({exc.strerror or type(exc).__name__})") from None
        if head != MCAP_MAGIC or tail != MCAP_MAGIC:
            raise InputError(f"{path}: not a whole MCAP file (cut or another format)")


def _bands(folder: Path, records: _Records) -> tuple[bytes, str]:
    """The tracking-error figure: :data:`BANDS_PNG` when an earlier report left it, else drawn (and left there when
    the mission has a ``plots/`` folder)."""
    cached = folder / BANDS_PNG
    if cached.is_file():
        check_stage_mcaps(folder, records.summary)  # not read for the figure: still refuse a cut one
        return read_png(cached), "drawn from the track MCAPs"  # by an earlier report: the same figure
    from oacli.report.figures import tracking_bands

    png = tracking_bands(records.get(), folder)
    if cached.parent.is_dir():
        try:
            write_bytes_atomic(cached, png)
        except OSError:
            pass  # a read-only folder: the page still gets the figure
    return png, "drawn from the track MCAPs"


def mission_figures(folder: Path, summary: dict[str, Any]) -> list[dict[str, Any]]:
    """The mission's figures (module docstring), each ``{"id", "title", "caption", "png", "source"}``.

    The stage MCAPs are read only for a figure that is not in ``plots/`` yet.

    Parameters
    ----------
    folder : Path
    summary : dict

    Returns
    -------
    list of dict

    Raises
    ------
    InputError
        A stage MCAP or PNG is unreadable or cut.
    """
    records = _Records(folder, summary)
    png, source = _bands(folder, records)
    figures = [{"id": "tracking", "title": "Tracking error per segment",
                "caption": "‖r − r_ref‖ of every flight; segment 3 with the [Doerr2021] Fig. 3(d) baselines. Shaded: "
                "the range the tube allows around its nominal while the true state stays in the tube (tube MPC "
                "flights); the line leaving its band is the state leaving the tube.",
                "png": png, "source": source}]
    png, source = _drawn(folder, summary, "estimate_convergence", "plot_estimate_convergence", records)
    figures.append({"id": "estimates", "title": "Estimates converging (± 2σ)",
                    "caption": "Mass and principal inertias after the grasp with ± 2σ bands and the truth (dashed); "
                    "right: error and 2σ relative to the truth against the flight's figures.",
                    "png": png, "source": source})
    png, source = _drawn(folder, summary, "paths", "plot_paths", records)
    figures.append({"id": "paths", "title": "Paths", "caption": "Plans, smoothed paths, the excitation reference and "
                    "the flown paths of every segment among the keep-in boxes and keep-out zones.",
                    "png": png, "source": source})
    return figures


def mission_context(folder: Path, summary: dict[str, Any]) -> dict[str, Any]:
    """Everything the mission page shows.

    Parameters
    ----------
    folder : Path
    summary : dict

    Returns
    -------
    dict
    """
    complete = summary.get("status") in COMPLETE_STATUSES
    config = folder / "config.yaml"
    rrd = folder / "mission.rrd"
    return {
        "kind": "mission",
        "title": f"mission {summary.get('name', folder.name)}",
        "summary": summary,
        "complete": complete,
        "segments": segment_rows(folder, summary) if complete else [],
        "estimate": estimate_rows(summary) if complete else [],
        "comparison": comparison_rows(summary) if complete else [],
        "figures": mission_figures(folder, summary) if complete else [],
        "config_text": config.read_text() if config.is_file() else None,
        "files": {"recording": str(rrd.resolve()) if rrd.is_file() else None, "folder": str(folder.resolve())},
        "commands": {"view": f"rerun {rrd.resolve()}" if rrd.is_file() else None,
                     "resume": None if complete else f"oacli mission {folder} --resume"},
    }


__all__ = ["comparison_rows", "estimate_rows", "mission_context", "mission_figures", "segment_rows"]
