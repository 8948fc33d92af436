"""The report's own figures, rendered to PNG bytes in memory (matplotlib, Agg; :mod:`oacli.io.plots.common`).

* :func:`tracking_bands` -- a mission's position error ‖r − r_ref‖ per segment, and for every tube MPC flight the
  band the tube allows: with the nominal z, the tube's box ``z ⊕ Z`` and its half-widths h (per axis, the larger
  side), ``‖z − r_ref‖ − ‖h‖ ≤ ‖r − r_ref‖ ≤ ‖z − r_ref‖ + ‖h‖`` (triangle inequality) whenever the true state is
  in its tube ([Doerr2021] Eqs. 15-28): the error leaving the band means the state left the tube.
* :func:`cell_intervals` -- a campaign's per-cell medians with their 95 % intervals, one panel per figure.
* :func:`cell_cdfs` -- a campaign's per-cell empirical CDFs of one figure.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg", force=True)

import numpy as np

from oacli.io.plots.common import decimate, legend_outside, save_png, subplots


def constrained(nrows: int, ncols: int, figsize: tuple[float, float], **kwargs: Any) -> tuple[Any, Any]:
    """A plain Agg figure with matplotlib's constrained layout (long tick labels get their room).

    Parameters
    ----------
    nrows, ncols : int
    figsize : tuple of float
        [in].

    Returns
    -------
    fig, axes
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def constrained_png(fig: Any, dpi: int = 100) -> bytes:
    """PNG bytes of a :func:`constrained` figure."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def png_bytes_of(fig: Any) -> bytes:
    """Render ``fig`` the way every oacli PNG is rendered (:func:`oacli.io.plots.common.save_png`) and return the
    bytes.

    Parameters
    ----------
    fig : Figure

    Returns
    -------
    bytes
    """
    with tempfile.TemporaryDirectory(prefix="oacli-report-") as tmp:
        path = save_png(fig, Path(tmp) / "figure.png")
        return path.read_bytes()


def tracking_bands(records: Any, mission_dir: Path) -> bytes:
    """Position error per segment with the tube bands (module docstring).

    Parameters
    ----------
    records : MissionRecords
        The mission's records (:func:`oacli.mission.records.load_mission_records`).
    mission_dir : Path
        The mission folder (the flights' references are read from their MCAPs, cached by the records' reader).

    Returns
    -------
    bytes
        PNG.
    """
    from oacli.mission.layout import SEGMENTS, stage_by_key
    from oacli.mission.plots import FLIGHT_COLORS
    from oacli.mission.records import read_telemetry_cached

    fig, axes = subplots(len(SEGMENTS), 1, figsize=(10, 8.5))
    for ax, seg in zip(axes, SEGMENTS, strict=True):
        flights = [f for f in records.flights.values() if f.key.startswith(seg + "/") and f.t_ctrl.size]
        for f in flights:
            color = FLIGHT_COLORS.get(f.key)
            rms = float(np.sqrt(np.mean(f.position_error_m**2)))
            ax.plot(*decimate(f.t_ctrl, f.position_error_m), color=color, lw=1.2,
                    label=f"{f.label} (RMS {1e3 * rms:.1f} mm)")
            if f.nominal_m is not None and f.tube_lower_m is not None and f.tube_upper_m is not None:
                tel = read_telemetry_cached(stage_by_key(f.key).mcap(mission_dir))
                ref = np.asarray(tel.x_reference[:, 0:3], dtype=float)
                n = min(len(ref), len(f.nominal_m))
                half = np.maximum(f.nominal_m[:n] - f.tube_lower_m[:n], f.tube_upper_m[:n] - f.nominal_m[:n])
                centre = np.linalg.norm(f.nominal_m[:n] - ref[:n], axis=1)
                reach = np.linalg.norm(half, axis=1)
                t = f.t_ctrl[:n]
                ax.fill_between(t, np.maximum(centre - reach, 0.0), centre + reach, color=color, alpha=0.15, lw=0,
                                label=f"{f.label}: tube band")
        info = records.segments.get(seg, {})
        ax.set_title(f"{seg}: {info.get('from', '?')} → {info.get('to', '?')}", loc="left", fontsize="medium")
        ax.set_ylabel("‖r − r_ref‖ [m]")
        ax.grid(True, alpha=0.3)
        if not flights:
            ax.text(0.5, 0.5, "no flight recorded", transform=ax.transAxes, ha="center", va="center")
        legend_outside(ax)
    axes[-1].set_xlabel("mission time [s]")
    fig.suptitle("Tracking error per segment; shaded: what the tube allows while the true state stays in it")
    return png_bytes_of(fig)


def cell_intervals(panels: list[dict[str, Any]]) -> bytes:
    """Per-cell medians with their 95 % intervals, one panel per figure (a forest plot).

    Parameters
    ----------
    panels : list of dict
        Each ``{"title": str, "unit": str, "flight": float or None, "rows": [(label, median, lo, hi, n), ...]}``;
        ``lo``/``hi`` None where the interval is not defined (too few runs).

    Returns
    -------
    bytes
        PNG.
    """
    n = max(1, len(panels))
    cols = min(3, n)
    nrows = (n + cols - 1) // cols
    height = max(2.0, 0.28 * max((len(p["rows"]) for p in panels), default=1) + 1.0)
    fig, axes = constrained(nrows, cols, figsize=(5.0 * cols, height * nrows), squeeze=False)
    flat = list(np.ravel(axes))
    for ax, panel in zip(flat, panels, strict=False):
        rows = panel["rows"]
        y = np.arange(len(rows))[::-1]
        for yi, (label, med, lo, hi, _n) in zip(y, rows, strict=True):
            if med is None:
                ax.text(0.02, yi, f"{label}: no data", fontsize=7, va="center", transform=ax.get_yaxis_transform())
                continue
            if lo is not None and hi is not None and np.isfinite(lo) and np.isfinite(hi):
                ax.plot([lo, hi], [yi, yi], color="tab:blue", lw=2.0)
            ax.plot(med, yi, "o", color="tab:blue", ms=4)
        if panel.get("flight") is not None:
            ax.axvline(panel["flight"], color="tab:red", ls="--", lw=1.0, label="flight")
            ax.legend(loc="lower right", fontsize=7)
        ax.set_yticks(y)
        ax.set_yticklabels([f"{r[0]} (n={r[4]})" for r in rows], fontsize=7)
        ax.set_ylim(-0.6, len(rows) - 0.4)
        ax.set_xlabel(panel["unit"])
        ax.set_title(panel["title"], loc="left", fontsize="small")
        ax.grid(True, axis="x", alpha=0.3)
    for ax in flat[len(panels):]:
        ax.set_visible(False)
    fig.suptitle("Per cell: median and distribution-free 95 % interval")
    return constrained_png(fig)


def cell_cdfs(title: str, unit: str, series: dict[str, np.ndarray]) -> bytes:
    """Empirical CDFs of one figure, one line per cell.

    Parameters
    ----------
    title, unit : str
    series : dict of str to ndarray
        Cell name -> its runs' values (non-finite ones dropped).

    Returns
    -------
    bytes
        PNG.
    """
    fig, ax = constrained(1, 1, figsize=(9, 3.6))
    for name, values in series.items():
        v = np.sort(np.asarray(values, dtype=float)[np.isfinite(values)])
        if v.size:
            ax.step(np.r_[v[0], v], np.r_[0.0, np.arange(1, v.size + 1) / v.size], where="post", lw=1.2,
                    label=f"{name} (n={v.size})")
    ax.set_ylim(0.0, 1.05)
    ax.set_xlabel(unit)
    ax.set_ylabel("fraction of runs ≤")
    ax.set_title(title, loc="left", fontsize="medium")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    return constrained_png(fig)


__all__ = ["cell_cdfs", "cell_intervals", "png_bytes_of", "tracking_bands"]
