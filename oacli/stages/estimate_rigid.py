"""The estimate stage's full rigid body: the batch model a config chooses and the summary of its parameters.

``estimation.parameters`` chooses which parts of θ the batch estimates (:mod:`oacli.estimation.rigid_parameters`);
``estimation.rigid_body`` gives the prior of the parts beyond mass and inertia (and the fixed values of those not
estimated). The summary's ``rigid_body`` section lists every estimated entry with its σ (``[(AᵀA)⁻¹]_θθ`` at the
solution, [Doerr2021] Eq. 32) and, for a simulated run, its truth and z-score ``(θ̂ − θ)/σ``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from oacli.config import OacliConfig
from oacli.estimation.batch_model import FullModel, full_prior
from oacli.estimation.rigid_parameters import FULL_NAMES, ParameterSet
from oacli.types import ParameterEstimate

__all__ = ["batch_model", "rigid_body_line", "rigid_body_summary", "truth_full_from_config_yaml"]

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
    line = "rigid body: " + ", ".join(parts)
    z = [abs(v) for v in (section.get("z_score") or {}).values() if v is not None]
    return line + (f"; largest |z| {max(z):.2f}" if z else "")
