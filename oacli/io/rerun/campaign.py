"""The campaign's Rerun recording (``campaign.rrd``) and its layout.

Entities (a fixed contract; tests read them back), on the sequence timeline ``run`` (the run index; the layout opens
on it): ``campaign/<metric>`` (one ``Scalars`` sample per completed run, drawn as points: independent runs are not
joined by lines), ``campaign/status`` (each run's final status as a ``StateChange``), ``campaign/log`` (one line per
run: its status, and its error when it failed), and ``histograms/<metric>`` (static bar charts: runs per bin of each
metric). Application id ``oacli-campaign``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.io.rerun.layout import collapsed_side_panels
from oacli.io.rerun.writer import StageRecording, application_id

RUN_TIMELINE = "run"
STATUS = "campaign/status"
CAMPAIGN_LOG = "campaign/log"
HISTOGRAMS = "histograms"

#: Readable names of the metrics (``campaign/<key>``), with units; unknown keys are shown as they are.
METRIC_TITLES = {
    "rms_position_error_mm": "RMS position error [mm]",
    "max_position_error_mm": "Max position error [mm]",
    "violations": "Constraint violations [steps]",
    "tube_violations_true": "Tube violations, true state [steps]",
    "fallback_steps": "Fallback steps",
}
_POINT_COLOR = (90, 150, 255, 255)
_BAR_COLOR = (90, 150, 255, 255)
_LEVELS = {"ok": "INFO", "degraded": "WARN", "unsafe": "ERROR", "failed": "ERROR", "infra_failed": "ERROR"}


def metric_title(key: str) -> str:
    """A metric's readable title (``estimate_error_pct/mass`` → ``mass estimate error [%]``)."""
    if key.startswith("estimate_error_pct/"):
        return f"{key.split('/', 1)[1]} estimate error [%]"
    return METRIC_TITLES.get(key, key.replace("_", " "))


def histogram(values: np.ndarray, bins: int | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Runs per bin of the finite ``values``: (bin centres, counts, bin width); ``bins`` from the sample size by
    default.

    Parameters
    ----------
    values : ndarray
        One value per run.
    bins : int, optional
        Number of bins (default: ``clip(n // 2, 5, 40)``).

    Returns
    -------
    centres, counts : ndarray
    width : float
        Bin width (the bars' width: Rerun draws bars one abscissa unit wide otherwise).
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return np.empty(0), np.empty(0), 1.0
    n_bins = int(bins if bins is not None else min(40, max(5, v.size // 2)))
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    counts, edges = np.histogram(v, bins=n_bins, range=(lo, hi))
    return 0.5 * (edges[:-1] + edges[1:]), counts.astype(float), float(edges[1] - edges[0])


def campaign_blueprint(metrics: list[str], runs: tuple[int, int] | None = None) -> rrb.Blueprint:
    """Layout: per-run status and the run log on the left; one row per metric: its value per run (points) and its
    histogram (tracking metrics and estimation errors in two tabs when both are there).

    Parameters
    ----------
    metrics : list of str
        The metric keys logged (``campaign/<key>`` and ``histograms/<key>``).
    runs : (int, int), optional
        First and last run index: the run axes span them with half a run to spare (no point on the edge).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    if runs is None:
        span = rr.TimeRange(start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.infinite())
    else:
        span = rr.TimeRange(start=rr.TimeRangeBoundary.absolute(seq=int(runs[0]) - 1),
                            end=rr.TimeRangeBoundary.absolute(seq=int(runs[1]) + 1))
    whole = rrb.TimeAxis(view_range=span)

    def row(key: str) -> rrb.Horizontal:
        return rrb.Horizontal(
            rrb.TimeSeriesView(origin=f"campaign/{key}", name=f"{metric_title(key)} per run", axis_x=whole,
                               plot_legend=rrb.PlotLegend(visible=False)),
            rrb.BarChartView(origin=f"{HISTOGRAMS}/{key}", name=f"{metric_title(key)}: runs per bin",
                             plot_legend=rrb.PlotLegend(visible=False)),
        )

    tracking = [k for k in metrics if not k.startswith("estimate_error_pct/")]
    estimation = [k for k in metrics if k.startswith("estimate_error_pct/")]
    groups = [rrb.Vertical(*(row(k) for k in keys), name=name)
              for name, keys in (("Tracking", tracking), ("Estimation", estimation)) if keys]
    right = groups[0] if len(groups) == 1 else rrb.Tabs(*groups, active_tab=0)
    status = rrb.Vertical(
        rrb.StateTimelineView(origin=STATUS, name="Status per run (x: run)", time_view=whole),
        rrb.TextLogView(origin=CAMPAIGN_LOG, name="Runs: status, error"),
        row_shares=[1.0, 2.0],
        name="Runs",
    )
    return rrb.Blueprint(
        rrb.Horizontal(status, right, column_shares=[1.0, 2.4]),
        rrb.TimePanel(timeline=RUN_TIMELINE, state="collapsed"),
        *collapsed_side_panels(),
    )


def write_campaign_recording(path: Path, series: Mapping[str, tuple[np.ndarray, np.ndarray]],
                             runs: Mapping[int, tuple[str, str | None]], name: str) -> None:
    """Write ``campaign.rrd`` (entities in the module docstring) with :func:`campaign_blueprint`.

    Parameters
    ----------
    path : Path
        Output ``.rrd`` (written atomically).
    series : mapping of str to (ndarray, ndarray)
        Metric key to (run indices, one value per run).
    runs : mapping of int to (str, str or None)
        Every finished run's index to its status and error message (None when it did not fail).
    name : str
        Campaign name (the recording is named ``<name>/campaign``).
    """
    rec = StageRecording(application_id("campaign"), f"{name}/campaign")
    stream = rec.stream
    keys = sorted(series)
    for key in keys:
        ks, values = series[key]
        entity = f"campaign/{key}"
        stream.log(entity, rr.SeriesPoints(names=[metric_title(key)], colors=[_POINT_COLOR], marker_sizes=[4.0]),
                   static=True, strict=True)
        stream.send_columns(entity, indexes=[rr.TimeColumn(RUN_TIMELINE, sequence=np.asarray(ks, dtype=np.int64))],
                            columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)), strict=True)
        centres, counts, width = histogram(values)
        if counts.size:
            stream.log(f"{HISTOGRAMS}/{key}", rr.BarChart(counts, abscissa=centres, widths=np.full(counts.size, width),
                                                          color=_BAR_COLOR), static=True, strict=True)
    if runs:
        order = sorted(runs)
        index = [rr.TimeColumn(RUN_TIMELINE, sequence=np.array(order, dtype=np.int64))]
        stream.send_columns(STATUS, indexes=index, columns=rr.StateChange.columns(state=[runs[k][0] for k in order]),
                            strict=True)
        lines = [f"run {k}: {runs[k][0]}" + (f": {runs[k][1]}" if runs[k][1] else "") for k in order]
        stream.send_columns(CAMPAIGN_LOG, indexes=index,
                            columns=rr.TextLog.columns(text=lines, level=[_LEVELS.get(runs[k][0], "INFO")
                                                                           for k in order]), strict=True)
    shown = [k for k in keys if np.any(np.isfinite(np.asarray(series[k][1], dtype=float)))]
    indices = sorted(runs) or [int(k) for key in keys for k in series[key][0]]
    rec.save(Path(path), campaign_blueprint(shown, (min(indices), max(indices)) if indices else None))
