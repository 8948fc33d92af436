"""The estimate stage's full rigid body: the batch model a config chooses and the summary of its parameters.

``estimation.parameters`` chooses which parts of θ the batch estimates (:mod:`oacli.estimation.rigid_parameters`);
``estimation.rigid_body`` gives the prior of the parts beyond mass and inertia (and the fixed values of those not
estimated). The summary's ``rigid_body`` section lists every estimated entry with its σ (``[(AᵀA)⁻¹]_θθ`` at the
solution, [Doerr2021] Eq. 32) and, for a simulated run, its truth and z-score ``(θ̂ − θ)/σ``.

Held groups (``estimation.parameters`` leaves them out) are known only to their prior: :func:`consider_run` adds
their uncertainty to the batch's and the sequential filter's covariance (:mod:`oacli.estimation.consider`, Schmidt's
consider covariance). The summary's ``std`` and ``rigid_body`` report the physical σ (every held group considered);
the final ``/estimate/params`` record, which segment 3 flies with, carries the covariance handed on (the torque
scales left out: the estimate is the effective inertia ``J/κ_τ`` the controllers need); the summary's ``consider``
section lists both and the sensitivities.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from oacli.config import OacliConfig
from oacli.estimation.batch_model import FullModel, full_prior
from oacli.estimation.bounds_full import FullBound, cramer_rao_bound_full
from oacli.estimation.consider import consider_held
from oacli.estimation.models import EstimatorSettings, Measurement
from oacli.estimation.rigid_parameters import FULL_NAMES, ParameterSet
from oacli.types import ParameterEstimate

__all__ = ["apply_full_bound", "apply_physical_std", "batch_model", "consider_run", "full_bound", "rigid_body_line",
           "rigid_body_section", "rigid_body_summary", "truth_full_from_config_yaml"]

_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def batch_model(cfg: OacliConfig, prior: ParameterEstimate) -> FullModel | None:
    """The batch's choice of θ: None for the original [m, Ixx, Iyy, Izz] with the rest ideal, else a
    :class:`FullModel` with the prior ``N(θ₀, P₀)`` of :func:`oacli.estimation.batch_model.full_prior`.

    Parameters
    ----------
    cfg : OacliConfig
    prior : ParameterEstimate
        The prior on [m, Ixx, Iyy, Izz].

    Returns
    -------
    FullModel or None
    """
    est = cfg.estimation
    mean, cov = full_prior(prior.theta, prior.covariance, est.rigid_body.mean(), est.rigid_body.std())
    params = ParameterSet.build(est.parameters, mean)
    if params.is_legacy:
        return None
    return FullModel(params, mean, cov)


def consider_run(records: list[Measurement], settings: EstimatorSettings, prior: ParameterEstimate | None,
                 model: FullModel, t: np.ndarray, states: np.ndarray, used: np.ndarray,
                 full: tuple[np.ndarray, np.ndarray], final: ParameterEstimate, history: list[ParameterEstimate]
                 ) -> tuple[tuple[np.ndarray, np.ndarray], ParameterEstimate, dict[str, Any] | None]:
    """The held groups' prior uncertainty in an estimate (:func:`oacli.estimation.consider.consider_held`).

    Parameters
    ----------
    records : list of Measurement
        The aligned records (by time stamp).
    settings : EstimatorSettings
    prior : ParameterEstimate or None
        The prior the estimator used (None: the batch without it).
    model : FullModel
    t : ndarray, shape (K,)
        The estimate's record times [s].
    states : ndarray, shape (K, 13)
        Its states.
    used : ndarray of bool, shape (K,)
        Records whose measurements it used.
    full : tuple of ndarray
        θ̂ (16) and the estimator's covariance (16×16).
    final : ParameterEstimate
        The final estimate of [m, Ixx, Iyy, Izz].
    history : list of ParameterEstimate
        The estimates over time; the last one (the final) is replaced in place.

    Returns
    -------
    full : tuple of ndarray
        θ̂ and the physical covariance (every held group considered).
    final : ParameterEstimate
        With the covariance handed on (``effective``).
    extras : dict or None
        ``{"consider": ...}`` for the summary; None (and ``full``, ``final`` unchanged) when nothing is held with a
        prior σ > 0 or the covariance is not finite; ``{"consider_skipped": reason}`` (``full``, ``final``
        unchanged) when θ̂ has no parametrisation to differentiate at (a non-physical or boundary inertia).
    """
    by_t = {r.t: r for r in records}
    try:
        con = consider_held([by_t[ti] for ti in t], settings, prior, model, states, used, *full)
    except (ValueError, np.linalg.LinAlgError) as exc:  # e.g. θ̂ on the lamina boundary (no φ there)
        reason = f"the consider covariance could not be formed ({exc}): σ without the held groups' prior"
        return full, final, {"consider_skipped": reason}  # a finding (estimate_findings): degraded
    if con is None:
        return full, final, None
    handed = ParameterEstimate(final.t, final.theta, con.effective[:4, :4], final.method, final.samples_used,
                               final.samples_rejected)
    if history:
        history[-1] = handed
    return (con.theta, con.physical), handed, {"consider": con.summary(model.params.index)}


def apply_physical_std(summary: dict[str, Any], full: tuple[np.ndarray, np.ndarray] | None) -> None:
    """With a consider covariance (summary ``consider``), the summary's ``std``, ``error_over_std``,
    ``std_over_crb`` and ``cov_reduction_pct`` of mass and inertia use the physical σ (``full``'s), not the one
    handed on.

    Parameters
    ----------
    summary : dict
        The estimate's summary, updated in place.
    full : tuple of ndarray or None
        θ̂ (16) and its physical covariance.
    """
    if full is None or "consider" not in summary:
        return
    std = np.sqrt(np.clip(np.diag(full[1])[:4], 0.0, None))
    names = FULL_NAMES[:4]
    summary["std"] = {n: float(v) for n, v in zip(names, std, strict=True)}
    summary["std_over_crb"] = {n: float(v / summary["crb_std"][n]) for n, v in zip(names, std, strict=True)}
    summary["cov_reduction_pct"] = {n: float(100.0 * (1.0 - (v / summary["prior_std"][n]) ** 2))
                                    for n, v in zip(names, std, strict=True)}
    if "truth_theta" in summary:
        err = np.abs(np.asarray(full[0][:4]) - np.asarray(summary["truth_theta"], dtype=float))
        summary["error_over_std"] = {n: float(e / v) for n, e, v in zip(names, err, std, strict=True)}


def truth_full_from_config_yaml(text: str | None) -> np.ndarray | None:
    """θ (16) of the ``truth`` section of a run's resolved config: mass, inertia (tensor entries where given),
    centre-of-mass offset and actuator scales (None when absent or not numeric).

    Parameters
    ----------
    text : str or None
        The run's attached config YAML.

    Returns
    -------
    ndarray, shape (16,) or None
    """
    if not text:
        return None
    try:
        truth = yaml.load(text, Loader=_LOADER)["truth"]
        theta = np.zeros(16)
        theta[0] = float(truth["mass_kg"])
        theta[1:4] = [float(v) for v in truth["inertia_kgm2"]]
        tensor = truth.get("inertia_tensor_kgm2")
        if tensor is not None:
            j = np.array(tensor, dtype=float).reshape(3, 3)
            theta[1:7] = [j[0, 0], j[1, 1], j[2, 2], j[0, 1], j[0, 2], j[1, 2]]
        theta[7:10] = [float(v) for v in truth.get("com_offset_m") or (0.0, 0.0, 0.0)]
        theta[10:16] = [float(v) for v in truth.get("actuator_scale") or (1.0,) * 6]
    except (KeyError, TypeError, ValueError, yaml.YAMLError):
        return None
    return theta if np.all(np.isfinite(theta)) else None


def rigid_body_summary(final: ParameterEstimate, full: tuple[np.ndarray, np.ndarray] | None,
                       model: FullModel | None, truth: np.ndarray | None) -> dict[str, Any]:
    """The ``rigid_body`` section of the summary: every estimated entry's estimate, σ, prior σ, and with a truth
    its error and z-score.

    Parameters
    ----------
    final : ParameterEstimate
        The final estimate of [m, Ixx, Iyy, Izz].
    full : tuple of ndarray or None
        The full θ (16) and its covariance (16×16) when a :class:`FullModel` was estimated.
    model : FullModel or None
        The model (None: θ = [m, Ixx, Iyy, Izz]).
    truth : ndarray, shape (16,) or None

    Returns
    -------
    dict
    """
    if model is None or full is None:
        idx = np.arange(4)
        theta = np.r_[final.theta, np.zeros(6), np.ones(6)]
        cov = np.zeros((16, 16))
        cov[:4, :4] = final.covariance
        prior_std = np.full(16, np.nan)
        groups: tuple[str, ...] = ("mass", "inertia")
    else:
        idx = model.params.index
        theta, cov = full
        prior_std = np.sqrt(np.diag(model.prior_cov))
        groups = model.params.groups
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    out: dict[str, Any] = {"parameters": list(groups), "estimate": {}, "std": {}, "prior_std": {}}
    for i in idx:
        name = FULL_NAMES[i]
        out["estimate"][name] = float(theta[i])
        out["std"][name] = float(std[i])
        if np.isfinite(prior_std[i]):
            out["prior_std"][name] = float(prior_std[i])
    if truth is not None:
        err = theta - truth
        out["truth"] = {FULL_NAMES[i]: float(truth[i]) for i in idx}
        out["z_score"] = {FULL_NAMES[i]: float(err[i] / std[i]) if std[i] > 0 else None for i in idx}
        unmodelled = [FULL_NAMES[i] for i in range(16) if i not in set(idx.tolist())
                      and abs(float(truth[i]) - float(theta[i])) > 1e-12]
        out["held_but_not_true"] = unmodelled
    return out


def rigid_body_line(section: dict[str, Any]) -> str:
    """One log line of the ``rigid_body`` section: the entries beyond mass and inertia, ``name = value ± σ`` (and
    the largest |z| with a truth).

    Parameters
    ----------
    section : dict
        :func:`rigid_body_summary`'s output.

    Returns
    -------
    str
    """
    parts = [f"{name} = {value:.6g} ± {section['std'][name]:.2g}" for name, value in section["estimate"].items()
             if name not in FULL_NAMES[:4]]
    line = "rigid body: " + (", ".join(parts) or "mass and inertia only")
    z = [abs(v) for v in (section.get("z_score") or {}).values() if v is not None]
    return line + (f"; largest |z| {max(z):.2f}" if z else "")


def full_bound(t: np.ndarray, states: np.ndarray, status: list[str], full: tuple[np.ndarray, np.ndarray] | None,
               model: FullModel | None, settings: EstimatorSettings, records: list[Measurement]) -> FullBound | None:
    """The full model's Cramér-Rao bound along the estimate (:func:`cramer_rao_bound_full`), or None without one.

    Parameters
    ----------
    t : ndarray, shape (K,)
        The estimate's record times [s].
    states : ndarray, shape (K, 13)
        Its estimated states.
    status : list of str
        Each record's status (``accepted``, ``initialised`` and ``segment`` count).
    full : tuple of ndarray or None
        θ̂ (16) and its covariance.
    model : FullModel or None
    settings : EstimatorSettings
    records : list of Measurement
        The aligned records (their inputs, gaps and accelerations).

    Returns
    -------
    FullBound or None
    """
    if model is None or full is None:
        return None
    by_t = {r.t: r for r in records}
    recs = [by_t[ti] for ti in t]
    has_acc = all(np.any(np.isfinite(r.accelerations())) for r in recs if r.state_measured)
    return cramer_rao_bound_full(
        t, states, np.array([r.u_applied for r in recs]).reshape(-1, 6), full[0], model, settings.measurement,
        settings.substep_s, used=np.array([s in ("accepted", "initialised", "segment") for s in status]),
        accelerations_measured=has_acc, segment_starts=np.array([r.starts_segment for r in recs], dtype=bool))


def apply_full_bound(summary: dict[str, Any], bound: FullBound | None) -> None:
    """With the full model, the summary's ``crb_std`` and ``std_over_crb`` of mass and inertia are the full model's
    bound (``crb_model`` says so), and ``rigid_body`` gets ``crb_std`` and ``error_over_crb`` of every entry.

    Parameters
    ----------
    summary : dict
        The estimate's summary (with ``rigid_body``), updated in place.
    bound : FullBound or None
        None: nothing changes (the 4-parameter bound stays).
    """
    if bound is None:
        return
    rb = summary["rigid_body"]
    crb = {FULL_NAMES[i]: float(v) for i, v in zip(bound.index, bound.std, strict=True)}
    rb["crb_std"] = crb
    if "truth" in rb:
        rb["error_over_crb"] = {name: (rb["estimate"][name] - rb["truth"][name]) / crb[name] if crb[name] > 0
                                else None for name in crb}
    summary["crb_std"] = {name: crb[name] for name in FULL_NAMES[:4]}
    summary["std_over_crb"] = {name: summary["std"][name] / crb[name] for name in FULL_NAMES[:4]}
    summary["crb_model"] = ("full rigid body " + str(rb["parameters"]) + ", the prior of the entries beyond mass and "
                            "inertia included (oacli.estimation.bounds_full)")


def rigid_body_section(summary: dict[str, Any], run: Any, model: FullModel | None, settings: EstimatorSettings,
                       records: list[Measurement], config_yaml: str | None) -> str:
    """Add the ``rigid_body`` section (and the full model's bound, :func:`apply_full_bound`) to an estimate's
    summary; return its log line (:func:`rigid_body_line`).

    Parameters
    ----------
    summary : dict
        The estimate's summary, updated in place.
    run : oacli.stages.estimate.EstimationRun
        The estimation (final estimate, full θ and covariance, records' times, states and statuses).
    model : FullModel or None
    settings : EstimatorSettings
    records : list of Measurement
    config_yaml : str or None
        The telemetry's attached config (its ``truth``).

    Returns
    -------
    str
    """
    summary["rigid_body"] = rigid_body_summary(run.final, run.full, model, truth_full_from_config_yaml(config_yaml))
    apply_physical_std(summary, run.full)
    apply_full_bound(summary, full_bound(run.t_records, run.states, run.status, run.full, model, settings, records))
    return rigid_body_line(summary["rigid_body"])
