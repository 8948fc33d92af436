"""The ``rls`` method of the estimate stage: the flight's recursive least squares ([ReSWARM2023] §4.4.1, §6.2.1).

Builds the acceleration samples from the aligned records (:func:`oacli.estimation.rls.acceleration_samples`), fits
the per-axis force scale first when the config names a calibration mass ([ReSWARM2023] Eqs. 38-39), runs
:class:`oacli.estimation.rls.RlsEstimator` and returns what :func:`oacli.stages.estimate.run_estimation` reports.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from oacli.config.estimation import RlsConfig
from oacli.errors import InputError
from oacli.estimation.batch_model import FullModel
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.imu import ImuStream, gyro_noise_variance
from oacli.estimation.models import EstimatorSettings, Measurement
from oacli.estimation.rls import (
    RATTLE_TABLE_COV_REDUCTION_PCT,
    RATTLE_TABLE_ERROR_PCT,
    AccelerationSamples,
    RlsEstimator,
    acceleration_samples,
    calibrate_force_scale,
)
from oacli.estimation.rls_full import RLS_FULL_GROUPS, RlsFullEstimator
from oacli.types import InertialParams, ParameterEstimate


@dataclass(frozen=True)
class RlsRun:
    """One run of the flight's estimator, in the terms of the estimate stage.

    Attributes
    ----------
    final : ParameterEstimate
    history : list of ParameterEstimate
        After every sample.
    t : ndarray, shape (K,)
        Sample times [s] (record times).
    status : list of str
        Per sample: accepted, rejected (χ² gate) or infeasible (update not applied).
    d2 : ndarray, shape (K,)
        Normalised innovation squared per sample.
    gate_threshold : float
        χ² threshold with 6 degrees of freedom (``inf`` without gating).
    nis_ratio : float
        Mean ``d²/6`` over the samples (about 1 for a consistent estimator).
    nis_dof : int
        6 × the number of samples.
    summary : dict
        The method's own summary entries (force scale, calibration, infeasible updates).
    full : (ndarray (16,), ndarray (16, 16)) or None
        With ``rls.full_body``: the full rigid body's θ and covariance (entries not estimated: zero variance).
    """

    final: ParameterEstimate
    history: list[ParameterEstimate]
    t: np.ndarray
    status: list[str]
    d2: np.ndarray
    gate_threshold: float
    nis_ratio: float
    nis_dof: int
    summary: dict[str, Any]
    full: tuple[np.ndarray, np.ndarray] | None = None


def run_rls(records: list[Measurement], settings: EstimatorSettings, prior: ParameterEstimate,
            config: RlsConfig, imu: ImuStream | None = None, period_s: float | None = None,
            model: FullModel | None = None) -> RlsRun:
    """Run the flight's RLS over time-ordered records.

    Parameters
    ----------
    records : list of Measurement
        Time-ordered, aligned records (with accelerometer readings where the telemetry has an IMU).
    settings : EstimatorSettings
        Measurement noise (velocity, angular velocity and accelerometer std) and the gate probability.
    prior : ParameterEstimate
        ``θ₀``, ``P₀``.
    config : RlsConfig
        Force scale, optional calibration mass, process noise.
    imu : ImuStream, optional
        The telemetry's IMU: the angular acceleration is then the gyro's slope over each control period (else the
        measured rate's finite difference, biased in closed loop: the summary warns).
    period_s : float, optional
        Control period [s] (for the gyro's noise variance, fitted on the data).
    model : FullModel, optional
        With ``config.full_body``: the groups and the prior of the full rigid body
        (:class:`oacli.estimation.rls_full.RlsFullEstimator`; the force scale as calibrated here, the torque scale
        at the prior's mean).

    Returns
    -------
    RlsRun

    Raises
    ------
    InputError
        When the records give fewer than two usable control intervals or lack the noise figures needed.
    """
    noise = settings.measurement
    gyro_var = gyro_noise_variance(records, imu, period_s) if imu is not None and period_s is not None else None
    try:
        samples = acceleration_samples(records, noise.velocity_std_mps, noise.angular_velocity_std_radps,
                                       noise.linear_acceleration_std_mps2, imu=imu if gyro_var else None,
                                       gyro_noise_variance_rad2ps2=gyro_var)
    except ValueError as exc:
        raise InputError(f"estimation.method rls: {exc} (measurement_noise)") from None
    accel_from_imu = any(r.linear_acceleration_mps2 is not None for r in records)
    summary: dict[str, Any] = {"acceleration_samples": len(samples), "rls_sources": {
        "linear_acceleration": "accelerometer" if accel_from_imu else "velocity finite difference",
        "angular_acceleration": "gyro slope" if gyro_var else "rate finite difference"}}
    if not (accel_from_imu and gyro_var):
        summary["warnings"] = ["rls: accelerations from finite differences of localisation are biased in closed "
                               "loop (the controller reacts to the same noise); fly with the IMU "
                               "(sensors.imu.enabled, estimation.measurement_noise.linear_acceleration_std_mps2)"]
    scale = np.array(config.force_scale, dtype=float)
    if config.calibration_mass_kg is not None:
        try:
            fit = calibrate_force_scale(samples, InertialParams(config.calibration_mass_kg, prior.theta[1:4]))
        except ValueError as exc:
            raise InputError(f"estimation.rls.calibration_mass_kg: {exc}") from None
        scale = fit.scale
        summary["force_scale_calibration"] = {"mass_kg": float(config.calibration_mass_kg),
                                              "scale": [float(v) for v in fit.scale],
                                              "std": [float(v) for v in fit.std], "samples": fit.samples}
    summary["force_scale"] = [float(v) for v in scale]
    if config.full_body and model is not None:
        return _run_full(samples, settings, model, scale, summary)
    est = RlsEstimator(prior, force_scale=scale, gate_probability=settings.gate_probability,
                       process_variance=np.array(config.process_variance, dtype=float))
    final = est.run(samples)
    summary["infeasible_updates"] = int(est.infeasible)
    summary["flight_rattle_table"] = {"source": "[ReSWARM2023] §6.2, RATTLE table",
                                      "error_pct": list(RATTLE_TABLE_ERROR_PCT),
                                      "cov_reduction_pct": list(RATTLE_TABLE_COV_REDUCTION_PCT)}
    d2 = np.array([s.d2 for s in est.history])
    gate = settings.gate_probability
    return RlsRun(
        final=final, history=[s.estimate for s in est.history], t=samples.t, status=[s.status for s in est.history],
        d2=d2, gate_threshold=chi2_threshold(6, gate) if gate is not None else float("inf"),
        nis_ratio=float(np.mean(d2) / 6.0), nis_dof=6 * d2.size, summary=summary,
    )


def _run_full(samples: AccelerationSamples, settings: EstimatorSettings, model: FullModel, force_scale: np.ndarray,
              summary: dict[str, Any]) -> RlsRun:
    """:func:`run_rls` with the full rigid body's RLS (``rls.full_body``)."""
    groups = model.params.groups
    if set(groups) - set(RLS_FULL_GROUPS):
        raise InputError(f"estimation.parameters: the rls method estimates {', '.join(RLS_FULL_GROUPS)}, not "
                         f"{', '.join(sorted(set(groups) - set(RLS_FULL_GROUPS)))} (the force scale is calibrated: "
                         "rls.force_scale or rls.calibration_mass_kg)")
    mean = np.array(model.prior_mean, dtype=float)
    mean[10:13] = force_scale
    try:
        est = RlsFullEstimator(mean, model.prior_cov, groups, settings.gate_probability, t0=float(samples.t[0]))
    except ValueError as exc:
        raise InputError(f"estimation.rigid_body: {exc}") from None
    history: list[ParameterEstimate] = []
    status: list[str] = []
    for k in range(len(samples)):
        status.append(est.update(samples.t[k], samples.accel_mps2[k], samples.alpha_radps2[k], samples.force_N[k],
                                 samples.torque_Nm[k], samples.rate_radps[k], samples.accel_std_mps2[k],
                                 samples.alpha_std_radps2[k]))
        history.append(est.estimate.parameter_estimate())
    final = est.estimate
    cov = np.zeros((16, 16))
    cov[np.ix_(final.index, final.index)] = final.covariance
    summary["infeasible_updates"] = int(est.infeasible)
    summary["rls_full"] = {"groups": list(groups), "physical": final.physical,
                           "triangle_margin_kgm2": final.triangle_margin,
                           "theta": {n: float(final.theta[i]) for n, i in zip(final.names, final.index, strict=True)},
                           "std": {n: float(v) for n, v in zip(final.names, final.std, strict=True)}}
    if not final.physical:
        summary.setdefault("warnings", []).append("rls: the full rigid body's estimate is not physical")
    summary["flight_rattle_table"] = {"source": "[ReSWARM2023] §6.2, RATTLE table",
                                      "error_pct": list(RATTLE_TABLE_ERROR_PCT),
                                      "cov_reduction_pct": list(RATTLE_TABLE_COV_REDUCTION_PCT)}
    d2 = np.array([h[2] for h in est.history])
    gate = settings.gate_probability
    return RlsRun(
        final=final.parameter_estimate(), history=history, t=samples.t, status=status, d2=d2,
        gate_threshold=chi2_threshold(6, gate) if gate is not None else float("inf"),
        nis_ratio=float(np.mean(d2) / 6.0), nis_dof=6 * d2.size, summary=summary, full=(final.theta, cov),
    )
