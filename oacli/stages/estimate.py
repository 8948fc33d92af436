"""Stage ``estimate``: inertial parameters from a tracking run ([Doerr2021] Eqs. 31-32; [ReSWARM2023] §4.4.1, §6.2.1).

Inputs: the config (its ``estimation`` section: method, prior, noise, gate; ``robot`` as the default prior mean;
``simulation.plant_rate_hz`` as the default integration grid) and a ``track.mcap`` (measured states and applied
inputs at the control rate; its attached config gives the truth when the run was simulated). Everything is read,
estimated and checked for identifiability **before** the run folder is created. Outputs: ``config.yaml`` (written
first), ``estimate.mcap``, ``estimate.rrd`` and ``summary.json`` (written last).

Telemetry is taken as flown, by time stamp (:mod:`oacli.estimation.alignment`): reordered, late, duplicated and
missing localisation messages and gaps in the input record are handled and counted (``telemetry_records`` in the
summary); a file cut mid-write is estimated from its intact records with the loss reported (``truncated``) and
status ``degraded``. The fit is checked, never trusted (:func:`estimate_findings`): the batch's χ² against its
expected value, convergence and the χ² gate; the sequential filter's normalised innovations, re-initialisations and
rejections. Each finding makes the run ``degraded`` with one sentence saying why.

Measurements as flown (``sensors.imu``/``sensors.localisation`` of the track run): when the file has
``/localisation``, its messages (by their stamps, in arrival order) are the measured states instead of
``/state/measured``; when ``estimation.measurement_noise.linear_acceleration_std_mps2`` is set, ``/imu`` must be
present and each measured record gets the accelerometer reading under its input, the bias estimated and removed
first (:mod:`oacli.estimation.imu`; summary ``imu``).

Telemetry that cannot identify θ (too short, or no torque so the inertias are invisible) ends with
:class:`oacli.errors.InfeasibleError` (exit code 3) naming the unobservable parameters and their Cramér-Rao bound
relative to their value; no estimate is written.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from oacli.config import OacliConfig
from oacli.config.estimation import RlsConfig
from oacli.errors import InfeasibleError, InputError
from oacli.estimation.alignment import AlignmentReport, align_records
from oacli.estimation.batch import UNIDENTIFIED_VARIANCE, BatchResult, estimate_batch_windows
from oacli.estimation.batch_model import FullModel
from oacli.estimation.bounds import CramerRaoBound, cramer_rao_bound, describe_unobservable, unobservable_parameters
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.imu import ImuStream, attach_accelerations, fit_accelerometer_bias
from oacli.estimation.lost_inputs import bridge_accelerations, bridge_angular_accelerations
from oacli.estimation.models import EstimatorSettings, Measurement
from oacli.estimation.sequential import SequentialEstimator
from oacli.excitation.information import PARAM_NAMES
from oacli.geometry.shapes import Scene
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.plots.estimate import write_estimate_plots
from oacli.io.rerun.estimate import EstimationRecords, write_estimate_recording
from oacli.io.runfolder import StageResult
from oacli.io.telemetry_streams import TelemetryStreams, read_telemetry_streams
from oacli.phases import set_phase
from oacli.stages.estimate_rigid import batch_model, consider_run, rigid_body_section
from oacli.stages.estimate_rls import run_rls
from oacli.stages.settings import estimation_prior, estimator_settings, open_run
from oacli.status import StatusReport, status_log
from oacli.types import ParameterEstimate

LogEntry = tuple[float, str, str]
_YAML_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml's safe loader when PyYAML has it (a track run's attached config: 6 ms instead of 45 ms in Python)."""

@dataclass(frozen=True)
class EstimationRun:
    """Everything one estimation produced (before any file is written).

    Attributes
    ----------
    method : str
    final : ParameterEstimate
    history : list of ParameterEstimate
        Estimates over mission time (batch: growing windows; sequential: after every record).
    t_records : ndarray, shape (K,)
    states : ndarray, shape (K, 13)
        Estimated states at the record times (batch: smoothed; sequential: filtered).
    inputs, measured : ndarray, shape (K, 6), (K, 13)
        Applied inputs and measured states of the records.
    status : list of str
        Per record: accepted, rejected, initialised or reinitialised.
    d2 : ndarray, shape (K,)
        Normalised residual (batch) or innovation (sequential) squared.
    dof : int
    gate_threshold : float
        χ² threshold (``inf`` without gating).
    bound : CramerRaoBound
        Along the estimated trajectory, over the records used.
    batch : BatchResult or None
    reinitialisations : int
        Sequential: robot-state re-initialisations.
    solve_time_s : float
    segments : int
        Segments linked by the process model (gaps in the input record split them).
    gaps_bridged : int
        Sequential: gaps in the input record the filter predicted across (one lost control record: the wrench
        predicted from its neighbours, its error as process noise), after the bootstrap.
    gaps_bridged_imu : int
        Sequential: of those, the gaps bridged with the IMU (``/imu`` kept: the accelerometer's lost force, the
        gyro's lost torque, or both; the summary's ``imu.gaps_bridged_gyro`` counts the gyro's).
    segment_restarts : int
        Sequential: gaps it could not bridge (the batch cuts them), where it re-initialised the robot state.
    extras : dict or None
        The method's own summary entries (``rls``: force scale and its calibration, infeasible updates).
    full : tuple of ndarray or None
        The full rigid body's θ (16) and covariance (16×16) when one was estimated.
    nis_ratio : float
        Sequential: mean normalised innovation squared of the filter's own updates over its expected value (its
        dimension); about 1 for a consistent filter, NaN when the filter made no update of its own.
    bootstrap_unidentified : bool
        Sequential: the batch bootstrap handed over without a usable covariance and the filter went on from the
        prior (:attr:`oacli.estimation.sequential.SequentialEstimator.bootstrap_unidentified`).
    nis_dof : int
        Sequential: the degrees of freedom of those innovations summed (the expected value of their summed NIS: a
        consistent filter's innovations are white, Bar-Shalom et al. 2001 §5.4, so the sum is χ² with this many).
    """

    method: str
    final: ParameterEstimate
    history: list[ParameterEstimate]
    t_records: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    measured: np.ndarray
    status: list[str]
    d2: np.ndarray
    dof: int
    gate_threshold: float
    bound: CramerRaoBound
    batch: BatchResult | None
    reinitialisations: int
    solve_time_s: float
    segments: int = 1
    nis_ratio: float = float("nan")
    nis_dof: int = 0
    bootstrap_unidentified: bool = False
    gaps_bridged: int = 0
    gaps_bridged_imu: int = 0
    segment_restarts: int = 0
    extras: dict[str, Any] | None = None
    full: tuple[np.ndarray, np.ndarray] | None = None


def truth_from_config_yaml(text: str | None) -> np.ndarray | None:
    """θ of the ``truth`` section of a run's resolved config (None when absent or not numeric)."""
    if not text:
        return None
    try:
        data = yaml.load(text, Loader=_YAML_SAFE_LOADER)
        truth = data["truth"]
        theta = np.array([float(truth["mass_kg"]), *(float(v) for v in truth["inertia_kgm2"])])
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        return None
    return theta if theta.shape == (4,) and np.all(np.isfinite(theta)) and np.all(theta > 0) else None


def run_estimation(
    records: list[Measurement], settings: EstimatorSettings, prior: ParameterEstimate, method: str, *,
    use_prior: bool = True, window_s: float = 10.0, progress: Callable[[float], None] | None = None,
    rls: RlsConfig | None = None, imu: ImuStream | None = None, period_s: float | None = None,
    model: FullModel | None = None,
) -> EstimationRun:
    """Run one estimator over time-ordered records and evaluate the Cramér-Rao bound along its estimate.

    Parameters
    ----------
    records : list of Measurement
        In time order (a track run's records are).
    settings : EstimatorSettings
    prior : ParameterEstimate
        ``N(θ₀, P₀)``: the sequential filter's initial state; the batch's starting point, and its prior when
        ``use_prior``.
    method : str
        ``"batch"``, ``"sequential"`` or ``"rls"``.
    use_prior : bool
        Batch only: include the prior in the likelihood.
    window_s : float
        Batch only: growing windows every ``window_s`` seconds (for the convergence record), then all records.
    progress : callable, optional
        Called with the completed fraction.
    rls : RlsConfig, optional
        Method ``rls``: force scale, calibration mass, process noise (default: :class:`RlsConfig`'s).
    imu : ImuStream, optional
        Method ``rls``: the telemetry's IMU (angular accelerations from the gyro).
    period_s : float, optional
        Method ``rls``: the control period [s].
    model : FullModel, optional
        Methods ``batch`` and ``sequential``: the part of the full rigid body estimated
        (:func:`oacli.stages.estimate_rigid.batch_model`; default θ = [m, Ixx, Iyy, Izz]).
    """
    start = time.perf_counter()
    t = np.array([r.t for r in records])
    by_t = {r.t: r for r in records}
    has_acc = bool(records) and all(np.any(np.isfinite(r.accelerations())) for r in records if r.state_measured)
    batch = None
    reinitialisations = 0
    segments = 1 + sum(r.starts_segment for r in records)
    nis_ratio = float("nan")
    nis_dof = 0
    bootstrap_unidentified = False
    gaps_bridged = gaps_bridged_imu = segment_restarts = 0
    extras: dict[str, Any] | None = None
    full = None
    if method == "batch":
        ends = [*np.arange(t[0] + window_s, t[-1] - 0.5 * window_s, window_s), t[-1]]
        set_phase(progress, f"batch window 1/{len(ends)}")

        def window_done(fraction: float) -> None:
            done = round(fraction * len(ends))
            if done < len(ends):
                set_phase(progress, f"batch window {done + 1}/{len(ends)}")
            if progress is not None:
                progress(fraction)

        results = estimate_batch_windows(records, settings, prior if use_prior else None, ends, progress=window_done,
                                         model=model)
        batch = results[-1]
        if batch.theta_full is not None and batch.covariance_full is not None:
            full = (batch.theta_full, batch.covariance_full)
        history = [r.estimate for r in results]
        final, states, d2, dof = batch.estimate, batch.states, batch.d2, batch.dof
        status = ["accepted" if ok else "rejected" if by_t[ti].state_measured else "predicted"
                  for ok, ti in zip(batch.inliers, batch.t, strict=True)]
        threshold = batch.gate_threshold
        used = batch.inliers
        t = batch.t
    elif method == "sequential":
        est = SequentialEstimator(settings, prior, intermediate_estimates=False, model=model)  # keeps the final one
        set_phase(progress, f"sequential EKF ({len(records)} records)")
        for i, rec in enumerate(records):
            est.update(rec)
            if progress is not None and (i % 25 == 0 or i == len(records) - 1):
                progress((i + 1) / len(records))
        final = est.flush()
        full = est.full_estimate() if model is not None else None
        steps = [s for s in est.history if s.status != "late"]
        history = [s.estimate for s in steps]
        states = np.array([s.state for s in steps])
        status = [s.status for s in steps]
        d2 = np.array([s.d2 for s in steps])
        dof = max((s.dof for s in steps), default=0)
        gate = settings.gate_probability
        threshold = chi2_threshold(dof, gate) if gate is not None and dof > 0 else float("inf")
        used = np.array([s.status in ("accepted", "initialised", "segment") for s in steps])
        t = np.array([s.t for s in steps])
        reinitialisations = est.reinitialisations
        bootstrap_unidentified = est.bootstrap_unidentified
        gaps_bridged, gaps_bridged_imu, segment_restarts = est.gaps_bridged, est.gaps_bridged_imu, est.segments
        own = [s for s in steps[est.bootstrap_records:] if s.status in ("accepted", "rejected") and s.dof > 0]
        if own:
            nis_ratio = float(np.mean([s.d2 / s.dof for s in own]))
            nis_dof = int(sum(s.dof for s in own))
        lost = ~np.all(np.isfinite(states), axis=1)  # input-only records after a gap: no state to report
        states[lost] = np.array([by_t[ti].x_measured for ti in t[lost]]).reshape(-1, 13)
    elif method == "rls":
        set_phase(progress, f"recursive least squares ({len(records)} records)")
        flight = run_rls(records, settings, prior, rls or RlsConfig(), imu, period_s, model)
        full = flight.full
        final, history, t, status, d2 = flight.final, flight.history, flight.t, flight.status, flight.d2
        states = np.array([by_t[ti].x_measured for ti in t]).reshape(-1, 13)  # no state estimate: as measured
        dof, threshold = 6, flight.gate_threshold
        used = np.array([s == "accepted" for s in status])
        nis_ratio, nis_dof, extras = flight.nis_ratio, flight.nis_dof, flight.summary
        if progress is not None:
            progress(1.0)
    else:
        raise ValueError(f"unknown method {method!r} (batch, sequential or rls)")
    if model is not None and full is not None and method != "rls":  # the held groups' prior (estimate_rigid)
        full, final, extras = consider_run(records, settings, prior if use_prior or method != "batch" else None,
                                           model, t, states, used, full, final, history)
    recs = [by_t[ti] for ti in t]
    u = np.array([r.u_applied for r in recs]).reshape(-1, 6)
    y = np.array([r.x_measured for r in recs]).reshape(-1, 13)
    starts = np.array([r.starts_segment for r in recs], dtype=bool)
    bridge_acc, bridge_var = bridge_accelerations(recs, settings.measurement)
    bound = cramer_rao_bound(t, states, u, final.theta, settings.measurement, settings.substep_s,
                             used=used, accelerations_measured=has_acc, segment_starts=starts,
                             bridge_acceleration=bridge_acc, bridge_acceleration_variance=bridge_var, measured=y,
                             gyro=bridge_angular_accelerations(recs))
    return EstimationRun(
        method=method, final=final, history=history, t_records=t, states=states, inputs=u,
        measured=y, status=status, d2=d2, dof=dof, gate_threshold=threshold, bound=bound, batch=batch,
        reinitialisations=reinitialisations, solve_time_s=time.perf_counter() - start, segments=segments,
        nis_ratio=nis_ratio, nis_dof=nis_dof, bootstrap_unidentified=bootstrap_unidentified,
        gaps_bridged=gaps_bridged, gaps_bridged_imu=gaps_bridged_imu,
        segment_restarts=segment_restarts, extras=extras, full=full,
    )


def _by_name(values: np.ndarray) -> dict[str, float]:
    return {name: float(v) for name, v in zip(PARAM_NAMES, values, strict=True)}


def _estimate_summary(
    run: EstimationRun, prior: ParameterEstimate, truth: np.ndarray | None, telemetry: Path,
    alignment: AlignmentReport | None = None, streams: TelemetryStreams | None = None,
) -> dict[str, Any]:
    final = run.final
    identified = bool(np.all(np.diag(final.covariance) < UNIDENTIFIED_VARIANCE))
    std = final.std if identified else np.full(final.theta.size, np.nan)  # no σ: null in summary.json
    summary: dict[str, Any] = {
        "stage": "estimate",
        "status": "ok",  # set by estimate_findings
        "method": run.method,
        "telemetry": str(telemetry),
        "mass_kg": float(final.theta[0]),
        "inertia_kgm2": [float(v) for v in final.theta[1:4]],
        "std": _by_name(std),
        "crb_std": _by_name(run.bound.std),
        "crb_std_known_initial_state": _by_name(run.bound.std_known_initial_state),
        "std_over_crb": _by_name(std / run.bound.std),
        "prior_theta": [float(v) for v in prior.theta],
        "prior_std": _by_name(prior.std),
        "cov_reduction_pct": _by_name(100.0 * (1.0 - std**2 / np.diag(prior.covariance))),
        "covariance_identified": identified,
        "samples_used": int(final.samples_used),
        "samples_rejected": int(final.samples_rejected),
        "samples_total": sum(s != "predicted" for s in run.status),
        "gate_threshold": run.gate_threshold if np.isfinite(run.gate_threshold) else None,
        "gate_dof": int(run.dof),
        "duration_s": float(run.t_records[-1] - run.t_records[0]),
        "solve_time_s": float(run.solve_time_s),
        "segments": int(run.segments),
    }
    if alignment is not None:
        summary["telemetry_records"] = alignment.as_dict()
    if streams is not None and streams.truncated:
        lost = streams.bytes_total - streams.bytes_read
        summary["truncated"] = {
            "bytes_read": int(streams.bytes_read), "bytes_total": int(streams.bytes_total), "bytes_lost": int(lost),
            "lost_pct": 100.0 * lost / max(streams.bytes_total, 1),
            "last_measurement_t_s": float(np.max(streams.t_measured)),
            "last_input_t_s": float(np.max(streams.t_applied)),
        }
    if truth is not None:
        summary["truth_theta"] = [float(v) for v in truth]
        summary["error_pct"] = _by_name(100.0 * np.abs(final.theta - truth) / truth)
        summary["error_over_std"] = _by_name(np.abs(final.theta - truth) / std)
    if run.batch is not None:
        summary["iterations"] = int(run.batch.iterations)
        summary["gating_rounds"] = int(run.batch.gating_rounds)
        summary["converged"] = bool(run.batch.converged)
        summary["cost_initial"] = float(run.batch.cost_history[0])
        summary["cost_final"] = float(run.batch.cost_history[-1])
        summary["windows"] = len(run.history)
        summary["chi2"] = float(run.batch.chi2)
        summary["chi2_expected"] = int(run.batch.chi2_dof)
        summary["chi2_ratio"] = float(run.batch.chi2 / run.batch.chi2_dof) if run.batch.chi2_dof > 0 else None
        summary["gate_emptied"] = bool(run.batch.gate_emptied)
    else:
        summary["state_reinitialisations"] = int(run.reinitialisations)
        summary["gaps_bridged"] = int(run.gaps_bridged)
        summary["gaps_bridged_imu"] = int(run.gaps_bridged_imu)
        summary["segment_restarts"] = int(run.segment_restarts)
        summary["nis_ratio"] = run.nis_ratio if np.isfinite(run.nis_ratio) else None
        summary["nis_expected"] = int(run.nis_dof)
        summary["bootstrap_unidentified"] = bool(run.bootstrap_unidentified)
    if run.extras:
        extras = dict(run.extras)
        if extras.get("warnings"):
            summary.setdefault("warnings", []).extend(extras["warnings"])
        extras.pop("warnings", None)
        summary.update(extras)
    notes = estimate_warnings(summary)
    if notes:
        summary.setdefault("warnings", []).extend(notes)
    estimate_findings(summary).apply(summary)
    return summary


CHI2_RATIO_LIMIT = 1.1
"""A batch fit whose cost exceeds this multiple of its expected value *and* its expected spread by
:data:`CHI2_SIGNIFICANCE` standard deviations is ``degraded``: the data do not fit the model (a wrong input record,
an unmodelled effect such as a thrust scale error or a centre-of-mass offset, noise levels set too low), so the
reported σ, which covers the modelled noise only, understates the error. At a ratio r a noise-like misfit
understates σ by √r (5 % at 1.1); a systematic one (a bias) by more: on the default flight-like mission the fit's
χ² is 1.19 times its expected value, 8 of its standard deviations above it, and Izz ends 5.3 reported σ from the
truth. The significance test keeps a short record (few degrees of freedom) from being flagged by chance."""
CHI2_SIGNIFICANCE = 5.0
"""Standard deviations ``√(2 dof)`` of a χ²-distributed cost by which the fit must miss its expected value ``dof``
to count (both ways: :func:`estimate_findings` degrades above, :func:`estimate_warnings` notes below)."""
CHI2_LOW_RATIO = 0.5
"""A batch fit whose cost is below this fraction of its expected value (and significantly so) is noted in
``warnings`` (the status is kept): the configured measurement or process noise is far above the telemetry's, so the
reported σ is conservative (e.g. noise-free simulated sensors against the estimator's noise model)."""
NIS_RATIO_LIMIT = 3.0
"""A sequential filter whose mean normalised innovation squared exceeds this multiple of its expected value
diverged (its covariance no longer describes its errors)."""
REJECTED_FRACTION_LIMIT = 0.2
"""More than this fraction of the records outside the χ² gate is ``degraded``: the gate no longer removes a few
outliers, it discards the data."""


def _chi2_spreads(ratio: float, dof: int) -> float:
    """How many standard deviations ``√(2 dof)`` a cost of ``ratio · dof`` lies from its expected value ``dof``
    (positive above it)."""
    return float((ratio - 1.0) * dof / np.sqrt(2.0 * dof))


def estimate_warnings(summary: dict[str, Any]) -> list[str]:
    """Notes on an estimate that do not change its status: a batch fit whose χ² is far *below* its expected value
    (:data:`CHI2_LOW_RATIO`), i.e. the noise model overstates the telemetry's noise and the reported σ is
    conservative."""
    ratio, dof = summary.get("chi2_ratio"), summary.get("chi2_expected") or 0
    if ratio is None or dof <= 0 or ratio >= CHI2_LOW_RATIO or -_chi2_spreads(ratio, dof) <= CHI2_SIGNIFICANCE:
        return []
    return [f"the batch fit's χ² is {ratio:.3g} times its expected value {dof}: the configured noise "
            "(estimation.measurement_noise, estimation.process_noise) is far above the telemetry's, so the reported "
            "σ is conservative (larger than the estimate's real error)"]


def estimate_findings(summary: dict[str, Any]) -> StatusReport:
    """Findings that make an estimate ``degraded`` (:mod:`oacli.status`), each with one sentence saying why.

    Batch: the last Levenberg-Marquardt round missed its tolerance, no record passed the χ² gate, or the fit's
    χ² is significantly above its expected value (:data:`CHI2_RATIO_LIMIT`, :data:`CHI2_SIGNIFICANCE`).
    Sequential: the batch bootstrap never identified θ, the filter lost the state and re-initialised, its
    normalised innovations are far above their expected value (:data:`NIS_RATIO_LIMIT`, diverged) or significantly
    above it (the batch's χ² rule on their sum: inconsistent). Both: no covariance (θ not identified), too many
    records rejected (:data:`REJECTED_FRACTION_LIMIT`), gaps in the input record (inputs unknown: predicted or cut,
    :mod:`oacli.estimation.alignment`), a truncated telemetry file.
    """
    report = StatusReport()
    if summary.get("covariance_identified") is False:
        report.degraded("no_covariance", "the estimate has no covariance: the information matrix is singular at the "
                                         "solution (θ not identified by the records used), so it reports no σ")
    if summary.get("converged") is False:
        report.degraded("not_converged", f"the batch estimate did not converge within {summary['iterations']} "
                                         "iterations (estimation.max_iterations)")
    if summary.get("gate_emptied"):
        report.degraded("gate_empty", "no record passed the χ² gate: the estimate uses records the gate rejected")
    ratio, dof = summary.get("chi2_ratio"), summary.get("chi2_expected") or 0
    if ratio is not None and dof > 0 and ratio > CHI2_RATIO_LIMIT and _chi2_spreads(ratio, dof) > CHI2_SIGNIFICANCE:
        report.degraded("fit_chi2", f"the batch fit's χ² is {ratio:.3g} times its expected value {dof} "
                                    f"({_chi2_spreads(ratio, dof):.1f} of its standard deviations above it): the "
                                    "telemetry does not fit the model (inputs, noise levels or unmodelled effects "
                                    "such as thrust errors or a centre-of-mass offset), and the reported σ covers "
                                    "the modelled noise only")
    if summary.get("bootstrap_unidentified"):
        report.degraded("not_identified", "the sequential filter's batch bootstrap could not identify θ from its "
                                          "records (no usable covariance: e.g. no record passed its χ² gate); the "
                                          "filter went on from the prior, so the estimate may be the prior itself")
    if summary.get("state_reinitialisations"):
        report.degraded("reinitialised", f"the sequential filter lost the state and re-initialised "
                                         f"{summary['state_reinitialisations']} times")
    nis, nis_dof = summary.get("nis_ratio"), summary.get("nis_expected") or 0
    if nis is not None and nis > NIS_RATIO_LIMIT:
        report.degraded("diverged", f"the sequential filter diverged: its innovations are {nis:.3g} times their "
                                    "expected size")
    elif (nis is not None and nis_dof > 0 and nis > CHI2_RATIO_LIMIT
          and _chi2_spreads(nis, nis_dof) > CHI2_SIGNIFICANCE):
        report.degraded("nis_inconsistent", f"the sequential filter's normalised innovations are {nis:.3g} times "
                                            f"their expected value ({_chi2_spreads(nis, nis_dof):.1f} standard "
                                            "deviations of their sum above it): the telemetry does not fit the "
                                            "model (inputs, noise levels or unmodelled effects such as thrust errors "
                                            "or a centre-of-mass offset), and the reported σ covers the modelled "
                                            "noise only")
    if summary.get("consider_skipped"):
        report.degraded("consider_skipped", summary["consider_skipped"])
    total = summary.get("samples_total") or 0
    if total and summary.get("samples_rejected", 0) > REJECTED_FRACTION_LIMIT * total:
        report.degraded("rejected", f"{summary['samples_rejected']} of {total} records were rejected by the χ² "
                                    "gate or arrived too late")
    gaps = (summary.get("telemetry_records") or {}).get("gaps", 0)
    if gaps:
        report.degraded("input_gaps", f"{gaps} gaps in the input record (controller records lost, no command log to "
                                      "bridge them): the inputs over them are unknown, measured by the "
                                      "accelerometer, predicted from their neighbours or cut; the estimate's σ "
                                      "includes it")
    cut = summary.get("truncated")
    if cut:
        report.degraded("truncated", f"the telemetry file was cut mid-write: its intact records end at byte "
                                     f"{cut['bytes_read']} of {cut['bytes_total']} and at t = "
                                     f"{cut['last_measurement_t_s']:.2f} s; everything logged later is lost, the "
                                     "estimate uses the intact part")
    return report


def run_estimate(
    cfg: OacliConfig,
    *,
    telemetry: Path,
    method: str | None = None,
    out: Path | None = None,
    runs_root: Path = Path("runs"),
    progress: Callable[[float], None] | None = None,
    allow_truncated: bool = True,
) -> StageResult:
    """Run the ``estimate`` stage and write its run folder.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration (its ``estimation`` section).
    telemetry : Path
        A ``track.mcap``.
    method : str, optional
        ``"batch"``, ``"sequential"`` or ``"rls"`` (default: ``cfg.estimation.method``).
    out : Path, optional
        Exact run folder (must not exist or be empty); otherwise ``runs_root/<name>-<UTC stamp>``.
    runs_root : Path
        Parent folder of automatically named runs.
    progress : callable, optional
        Called with the completed fraction of the estimation.
    allow_truncated : bool
        Estimate from the intact part of a cut telemetry file (status ``degraded``, the loss in ``truncated``);
        False refuses it (exit code 2).

    Returns
    -------
    StageResult

    Raises
    ------
    InputError
        Unreadable telemetry, or fewer than two control steps (exit code 2).
    InfeasibleError
        The telemetry does not identify every parameter (exit code 3); the message names them.
    """
    wall_start = time.perf_counter()
    telemetry = Path(telemetry)
    method = method or cfg.estimation.method
    if method not in ("batch", "sequential", "rls"):
        raise InputError(f"--method {method}: must be batch, sequential or rls")
    streams = read_telemetry_streams(telemetry)
    if streams.truncated and not allow_truncated:
        raise InputError(f"{telemetry}: the file is truncated (cut at byte {streams.bytes_read} of "
                         f"{streams.bytes_total}); --allow-truncated estimates from its intact part")
    truth = truth_from_config_yaml(streams.config_yaml)
    use_localisation = streams.t_localisation is not None and streams.t_localisation.size > 0
    t_meas, x_meas = ((streams.t_localisation, streams.x_localisation) if use_localisation
                      else (streams.t_measured, streams.x_measured))
    if t_meas is None or x_meas is None:  # read_telemetry_streams refuses a file without measurements
        raise InputError(f"{telemetry}: no measured states (/state/measured or /localisation)")
    records, alignment = align_records(
        t_meas, x_meas, streams.t_applied, streams.u_applied,
        reorder_window=cfg.estimation.reorder_window, t_command=streams.t_command, u_command=streams.u_command,
        input_limits=np.r_[cfg.robot.force_limit_N, cfg.robot.torque_limit_Nm],
    )
    records, imu_summary = _with_imu(cfg, records, streams, alignment.control_period_s, telemetry)
    measured = sum(r.state_measured for r in records)
    if measured < 2:
        raise InputError(f"{telemetry}: {measured} usable measurement(s); estimation needs at least 2")
    settings = estimator_settings(cfg)
    prior = estimation_prior(cfg)
    full_rls = method == "rls" and cfg.estimation.rls.full_body
    model = batch_model(cfg, prior) if method in ("batch", "sequential") or full_rls else None
    run = run_estimation(records, settings, prior, method, use_prior=cfg.estimation.use_prior,
                         window_s=cfg.estimation.window_s, progress=progress, rls=cfg.estimation.rls,
                         imu=_imu_stream(streams), period_s=alignment.control_period_s, model=model)
    limit = cfg.estimation.max_relative_std
    unobservable = unobservable_parameters(run.bound, run.final.theta, limit)
    if unobservable:
        raise InfeasibleError(
            f"{telemetry} ({run.t_records[-1] - run.t_records[0]:.1f} s, {len(records)} records): "
            + describe_unobservable(unobservable, limit)
            + "; no estimate written. Track an exciting reference (forces on every axis for the mass, torques on "
            "every axis for the inertias) for longer."
        )

    counts = ", ".join(f"{k} {v}" for k, v in alignment.as_dict().items() if k != "control_period_s")
    log: list[LogEntry] = [
        (0.0, "info", f"telemetry {telemetry}: {len(records)} records over {run.t_records[-1]:.1f} s"),
        (0.0, "info", f"telemetry by time stamp: {counts}"),
        (0.0, "info", f"method {method}, prior θ0 = {np.round(prior.theta, 6).tolist()}"),
    ]
    rejected_t = [t for t, s in zip(run.t_records, run.status, strict=True) if s in ("rejected", "reinitialised")]
    for t in rejected_t:
        log.append((float(t), "warning", "record rejected by the χ² gate"))
    final = run.final
    log.append((float(run.t_records[-1]), "info",
                f"θ = {np.round(final.theta, 6).tolist()} ± {np.round(final.std, 6).tolist()} "
                f"(Cramér-Rao {np.round(run.bound.std, 6).tolist()}), {final.samples_rejected} rejected"))
    summary = _estimate_summary(run, prior, truth, telemetry, alignment, streams)
    if method in ("batch", "sequential") or full_rls:
        log.append((float(run.t_records[-1]), "info", rigid_body_section(summary, run, model, settings, records,
                                                                         streams.config_yaml)))
    if use_localisation:
        summary["measurements_topic"] = ms.TOPIC_LOCALISATION
        log.insert(1, (0.0, "info", f"measured states from {ms.TOPIC_LOCALISATION} (by stamp)"))
    if imu_summary is not None:
        summary["imu"] = imu_summary
        log.insert(1, (0.0, "info", "accelerometer: bias " + str(np.round(imu_summary["bias_mps2"], 6).tolist())
                       + f" m/s² from {imu_summary['samples_fitted']} readings, "
                       f"{imu_summary['records_with_acceleration']} records with an acceleration, "
                       f"{imu_summary['gaps_bridged_gyro']} lost torques bridged by the gyro"))
    log.extend(status_log(summary, float(run.t_records[-1])))  # estimate findings are never unsafe

    with open_run("estimate", cfg, out=out, runs_root=runs_root, started=wall_start) as run_folder:
        with run_folder.open_mcap(method=run.method, telemetry=str(telemetry)) as writer:
            write_estimate_topics(writer, run, log, cfg.scene())
        per_record = EstimationRecords(
            run.t_records, run.d2, run.gate_threshold,
            np.array([s in ("rejected", "reinitialised") for s in run.status]), run.measured[:, 0:3],
            run.states[:, 0:3],
        )
        write_estimate_recording(
            run_folder.file("rrd", "estimate.rrd"), estimates=run.history, truth=truth, crb_std=run.bound.std,
            records=per_record, log=log, recording_name=f"{cfg.name}/estimate", frame=cfg.environment.frame,
        )
        if cfg.outputs.plots:
            write_estimate_plots(run_folder, summary, estimates=run.history, truth=truth, crb_std=run.bound.std,
                                 innovation=(run.t_records, run.d2, run.gate_threshold,
                                             np.array([s == "rejected" for s in run.status], dtype=bool)))
        return run_folder.finish(summary)


def _imu_stream(streams: TelemetryStreams) -> ImuStream | None:
    """The telemetry's ``/imu`` readings, or None."""
    if streams.t_imu is None or streams.imu is None or streams.t_imu.size == 0:
        return None
    return ImuStream(streams.t_imu, streams.imu[:, 0:3], streams.imu[:, 3:6])


def _with_imu(cfg: OacliConfig, records: list[Measurement], streams: TelemetryStreams, period_s: float,
              telemetry: Path) -> tuple[list[Measurement], dict[str, Any] | None]:
    """Records with the accelerometer's linear acceleration when the config measures it (module docstring)."""
    if cfg.estimation.measurement_noise.linear_acceleration_std_mps2 is None:
        return records, None
    field = "estimation.measurement_noise.linear_acceleration_std_mps2"
    if streams.t_imu is None or streams.imu is None or streams.t_imu.size == 0:
        raise InputError(f"{field}: set, but {telemetry} has no {ms.TOPIC_IMU} messages (track with "
                         "sensors.imu.enabled: true, or set it to null)")
    imu = ImuStream(streams.t_imu, streams.imu[:, 0:3], streams.imu[:, 3:6])
    t_inputs = np.unique(np.concatenate([streams.t_applied] + ([] if streams.t_command is None
                                                                else [streams.t_command])))
    fit = fit_accelerometer_bias(records, imu, t_inputs, period_s)
    if fit is None:
        raise InputError(f"{field}: {telemetry} has fewer than 4 {ms.TOPIC_IMU} readings under a known input")
    out, missing = attach_accelerations(records, imu, fit.bias_mps2, t_inputs, period_s)
    trailing = 0  # measurements after the last logged input (its control period over): no input, no reading
    while len(out) > 2 and out[-1].linear_acceleration_mps2 is None:
        missing -= out.pop().state_measured
        trailing += 1
    if missing:
        raise InputError(f"{field}: {missing} measured records of {telemetry} have no {ms.TOPIC_IMU} reading under "
                         "their input; the estimators need one for every record (set it to null to leave them out)")
    return out, {
        "bias_mps2": fit.bias_mps2.tolist(), "bias_std_mps2": fit.bias_std_mps2.tolist(),
        "inverse_mass_per_kg": fit.inverse_mass_per_kg, "samples_fitted": fit.samples,
        "residual_rms_mps2": fit.residual_rms_mps2,
        "records_with_acceleration": sum(r.linear_acceleration_mps2 is not None for r in out),
        "gaps_bridged_gyro": sum(r.angular_acceleration_var_rad2ps4 is not None for r in out),
        "trailing_records_dropped": trailing,
    }


def _params_record(estimate: ParameterEstimate, final: bool) -> dict[str, Any]:
    return {
        "method": estimate.method,
        "mass_kg": float(estimate.theta[0]),
        "inertia_kgm2": estimate.theta[1:4],
        "covariance": estimate.covariance,
        "std": estimate.std,
        "samples_used": int(estimate.samples_used),
        "samples_rejected": int(estimate.samples_rejected),
        "final": final,
    }


def write_estimate_topics(writer: StageMcapWriter, run: EstimationRun, log: list[LogEntry],
                          scene: Scene | None = None) -> None:
    """Write an estimation's topics (``docs/mcap.md``, stage ``estimate``) to its MCAP.

    Parameters
    ----------
    writer : StageMcapWriter
        The open writer.
    run : EstimationRun
        The estimation.
    log : list of (float, str, str)
        The stage's log.
    scene : Scene, optional
        The workspace, written on ``/scene`` with the paths ``measured`` and ``estimated`` and the robot body.
    """
    if scene is not None:
        writer.write_scene(scene, {"measured": run.measured[:, 0:3], "estimated": run.states[:, 0:3]},
                           t=float(run.t_records[0]))
    gate = run.gate_threshold if np.isfinite(run.gate_threshold) else None
    for i, est in enumerate(run.history):
        writer.write_json(ms.TOPIC_ESTIMATE_PARAMS, ms.PARAMETER_ESTIMATE, ms.PARAMETER_ESTIMATE_SCHEMA, est.t,
                          _params_record(est, final=i == len(run.history) - 1))
    for t, status, d2 in zip(run.t_records, run.status, run.d2, strict=True):
        writer.write_json(ms.TOPIC_ESTIMATE_SAMPLES, ms.ESTIMATION_SAMPLE, ms.ESTIMATION_SAMPLE_SCHEMA, float(t),
                          {"status": status, "d2": float(d2), "dof": int(run.dof), "gate": gate})
    if run.batch is not None:
        t_end = float(run.t_records[-1])
        for i, cost in enumerate(run.batch.cost_history):
            writer.write_json(ms.TOPIC_ESTIMATE_COST, ms.ESTIMATION_COST, ms.ESTIMATION_COST_SCHEMA, t_end,
                              {"iteration": i, "cost": float(cost)})
    writer.write_states(ms.TOPIC_STATE_ESTIMATED, run.t_records, run.states, run.inputs, name="estimated")
    writer.write_poses(run.t_records, run.states)
    writer.write_robot_body(run.t_records, run.states)
    for t, level, message in log:
        writer.write_log(t, level, message)
