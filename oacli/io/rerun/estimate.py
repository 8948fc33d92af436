"""The ``estimate`` stage's Rerun recording: parameter estimates converging with their 2σ bands.

Entities (a fixed contract; tests read them back):

* ``estimate/<param>`` -- the estimate of ``mass_kg``, ``Ixx_kgm2``, ``Iyy_kgm2``, ``Izz_kgm2`` over mission time,
  with children ``upper_2sigma`` / ``lower_2sigma`` (estimate ± 2 standard deviations), ``truth`` (constant, when
  the truth is known) and ``crb_2sigma_upper`` / ``crb_2sigma_lower`` (final estimate ± 2 Cramér-Rao bounds);
* ``metrics/innovation_d2`` -- the normalised residual (innovation) squared of every record, with the χ² gate
  under ``metrics/innovation_d2/gate`` and the rejected records as points under ``metrics/innovation_d2/rejected``;
* ``world/measured`` (measured positions), ``world/rejected`` (positions of the rejected records, red),
  ``world/estimated`` (estimated path);
* ``log`` -- the stage's text log.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.io.rerun.layout import collapsed_side_panels, world_title, world_view
from oacli.io.rerun.writer import (
    LOG,
    TIMELINE,
    WORLD,
    LogEntry,
    StageRecording,
    application_id,
    time_column,
    time_series_view,
)
from oacli.types import ParameterEstimate

PARAM_ENTITIES = ("estimate/mass_kg", "estimate/Ixx_kgm2", "estimate/Iyy_kgm2", "estimate/Izz_kgm2")
PARAM_TITLES = ("Mass [kg]", "Ixx [kg·m²]", "Iyy [kg·m²]", "Izz [kg·m²]")
D2 = "metrics/innovation_d2"
MEASURED = "world/measured"
REJECTED = "world/rejected"
ESTIMATED = "world/estimated"

_ESTIMATE_COLOR = (40, 120, 230, 255)
_BAND_COLOR = (40, 120, 230, 110)
_TRUTH_COLOR = (40, 170, 60, 255)
_CRB_COLOR = (150, 150, 150, 150)
_REJECTED_COLOR = (230, 40, 40, 255)
_GATE_COLOR = (235, 165, 30, 255)  # amber: distinct from the rejected points' red


@dataclass(frozen=True)
class EstimationRecords:
    """What the estimator did with each telemetry record, for the recording.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Record times [s].
    d2 : ndarray, shape (K,)
        Normalised residual/innovation squared per record (NaN where not computed).
    gate_threshold : float
        χ² gate (``inf``: no gate drawn).
    rejected : ndarray of bool, shape (K,)
        Records rejected by the gate (or late).
    measured_positions, estimated_positions : ndarray, shape (K, 3)
        Positions [m].
    """

    t: np.ndarray
    d2: np.ndarray
    gate_threshold: float
    rejected: np.ndarray
    measured_positions: np.ndarray
    estimated_positions: np.ndarray


def estimate_blueprint(*, frame: str = "world", focus: np.ndarray | None = None) -> rrb.Blueprint:
    """Default layout: the four parameters (estimate, 2σ band, truth) in a grid, d² with the gate, 3D, log.

    Parameters
    ----------
    frame : str
        Name of the world frame (the 3-D view's title).
    focus : ndarray, shape (N, 3), optional
        Points [m] the 3-D view frames (measured and estimated positions).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    params = rrb.Grid(
        *(time_series_view(entity, f"{title}: ± 2σ, truth, ± 2 CRB", legend=False)
          for entity, title in zip(PARAM_ENTITIES, PARAM_TITLES, strict=True)),
        name="Parameters",
    )
    right = rrb.Vertical(
        time_series_view(D2, "Normalised innovation² (χ² gate amber, rejected red)"),
        world_view(WORLD, world_title(frame, "measured (rejected red), estimated path"), focus),
        rrb.TextLogView(origin=LOG, name="Log"),
        row_shares=[1.0, 1.5, 0.7],
    )
    return rrb.Blueprint(rrb.Horizontal(params, right, column_shares=[1.6, 1.0]),
                         rrb.TimePanel(timeline=TIMELINE, state="collapsed"), *collapsed_side_panels())


def _constant(rec: StageRecording, entity: str, t_span: np.ndarray, value: float, name: str, color) -> None:
    rec.log_series(entity, t_span, np.full(2, value), [name], colors=[color], width=1.0)


def write_estimate_recording(
    path: Path,
    *,
    estimates: Sequence[ParameterEstimate],
    truth: np.ndarray | None,
    crb_std: np.ndarray,
    records: EstimationRecords,
    log: Sequence[LogEntry] = (),
    recording_name: str = "estimate",
    frame: str = "world",
) -> None:
    """Write the ``estimate`` stage's recording (see the module docstring) with :func:`estimate_blueprint`.

    Parameters
    ----------
    path : Path
        Output ``.rrd`` (written atomically).
    estimates : sequence of ParameterEstimate
        The estimates over mission time (their θ and standard deviations [kg, kg·m²] are drawn).
    truth : ndarray, shape (4,), optional
        True θ when known.
    crb_std : ndarray, shape (4,)
        Cramér-Rao bound of the final estimate (drawn as ± 2 bounds around it; ``inf`` is not drawn).
    records : EstimationRecords
        Per telemetry record: d², the gate, rejection and positions.
    log : sequence of (t, level, message)
        The stage's text log.
    recording_name : str
        Recording name shown in the viewer.
    frame : str
        Name of the world frame the positions are in (the 3-D view's title).
    """
    t_est = np.array([e.t for e in estimates], dtype=float)
    theta = np.array([e.theta for e in estimates], dtype=float).reshape(-1, 4)
    std = np.array([e.std for e in estimates], dtype=float).reshape(-1, 4)
    t_records = np.asarray(records.t, dtype=float)
    d2 = records.d2
    rejected = np.asarray(records.rejected, dtype=bool)
    rec = StageRecording(application_id("estimate"), recording_name)
    span = np.array([min(t_est.min(), t_records.min()), max(t_est.max(), t_records.max())])
    for i, entity in enumerate(PARAM_ENTITIES):
        name = entity.rsplit("/", 1)[-1]
        rec.log_series(entity, t_est, theta[:, i], [name], colors=[_ESTIMATE_COLOR], width=2.0)
        rec.log_series(f"{entity}/upper_2sigma", t_est, theta[:, i] + 2 * std[:, i], ["+2σ"], colors=[_BAND_COLOR],
                       width=1.0)
        rec.log_series(f"{entity}/lower_2sigma", t_est, theta[:, i] - 2 * std[:, i], ["−2σ"], colors=[_BAND_COLOR],
                       width=1.0)
        if truth is not None:
            _constant(rec, f"{entity}/truth", span, float(truth[i]), "truth", _TRUTH_COLOR)
        if np.isfinite(crb_std[i]):
            _constant(rec, f"{entity}/crb_2sigma_upper", span, float(theta[-1, i] + 2 * crb_std[i]), "+2 CRB",
                      _CRB_COLOR)
            _constant(rec, f"{entity}/crb_2sigma_lower", span, float(theta[-1, i] - 2 * crb_std[i]), "−2 CRB",
                      _CRB_COLOR)
    finite = np.isfinite(d2)
    if np.any(finite):
        rec.log_series(D2, t_records[finite], d2[finite], ["d²"], colors=[_ESTIMATE_COLOR], width=1.0)
        if np.isfinite(records.gate_threshold):
            _constant(rec, f"{D2}/gate", span, float(records.gate_threshold), "χ² gate", _GATE_COLOR)
        bad = rejected & finite
        if np.any(bad):
            rec.stream.log(f"{D2}/rejected", rr.SeriesPoints(colors=[_REJECTED_COLOR], names=["rejected"],
                                                              marker_sizes=[4.0]), static=True)
            rec.stream.send_columns(f"{D2}/rejected", indexes=[time_column(t_records[bad])],
                                    columns=rr.Scalars.columns(scalars=d2[bad]), strict=True)
    measured = records.measured_positions
    rec.log_points(MEASURED, measured[~rejected], color=(120, 120, 120, 255), radius_m=0.005)
    if np.any(rejected):
        rec.log_points(REJECTED, measured[rejected], color=_REJECTED_COLOR, radius_m=0.02)
    rec.log_path(ESTIMATED, records.estimated_positions, color=_ESTIMATE_COLOR)
    rec.log_entries(log)
    focus = np.concatenate([np.asarray(measured, dtype=float).reshape(-1, 3),
                            np.asarray(records.estimated_positions, dtype=float).reshape(-1, 3)])
    rec.save(Path(path), estimate_blueprint(frame=frame, focus=focus))
