"""The mission's actuator calibration: segment 1's flight of the known robot calibrates the thrusters first.

The flight calibrated the per-axis force scale on its own data before estimating the payload ([ReSWARM2023] Eqs.
38-39, §6.2.1): ``v̇ = R κ_F ⊙ (Rᵀ F) / m`` hides a common factor of κ_F and m, so a payload's mass is known no
better than κ_F. Segment 1 flies the bare robot, whose mass and inertias are known (``robot:``): the stage
``segment-1/calibrate`` (an ordinary ``estimate`` of segment 1's telemetry, :func:`calibration_prior_section`)
holds them with a negligible variance and estimates the estimation section's other groups. Its force and torque
scales (mean and σ per body axis) become the ``estimation.rigid_body`` prior of segment 2's estimates
(:func:`actuator_calibration`): the payload changes mass, inertia and CoM, not the impellers. A calibration that
failed, did not converge or ended other than ``ok`` (e.g. ``degraded``: its χ² says the actuator model does not
explain the telemetry, as with a saturating impeller, so its small σ would make segment 2's mass confidently
wrong) is not handed on: segment 2 keeps the config's prior and the mission says so (``degraded``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.errors import ConfigError
from oacli.io.runfolder import is_complete
from oacli.mission.layout import stage_by_key
from oacli.status import OK

__all__ = ["CALIBRATE_KEY", "HANDED_GROUPS", "KNOWN_VARIANCE", "ActuatorCalibration", "actuator_calibration",
           "calibration_prior_section", "estimate_failures", "handed_rigid_body"]

CALIBRATE_KEY = "segment-1/calibrate"
"""The calibration stage's key (:data:`oacli.mission.layout.MISSION_STAGES`)."""

HANDED_GROUPS = ("force_scale", "torque_scale")
"""The groups the calibration hands to segment 2 (the actuators'; the payload changes the rest)."""

KNOWN_VARIANCE = (1e-8, 1e-10, 1e-10, 1e-10)
"""Variance of the known robot's [m, Ixx, Iyy, Izz] in the calibration [kg², (kg·m²)² ×3]: σ 0.1 g and
1e-5 kg·m² (0.001 % and 0.007 %), the mass and inertias held while the scales are fitted."""

_AXES = ("x", "y", "z")


def estimate_failures(estimate: dict[str, Any]) -> list[str]:
    """Why an estimate's summary must not be handed on (empty: it may).

    Parameters
    ----------
    estimate : dict
        An estimate stage's ``summary.json``.

    Returns
    -------
    list of str
        ``did not converge``, ``has no covariance (θ not identified)``: plain words, no sentinel numbers.
    """
    out = []
    if estimate.get("converged") is False:
        out.append(f"did not converge (within {estimate.get('iterations', '?')} iterations)")
    if estimate.get("covariance_identified") is False:
        out.append("has no covariance (θ not identified by the telemetry)")
    std = estimate.get("std") or {}
    if any(v is None or not np.isfinite(v) for v in std.values()):
        if not out:
            out.append("has no finite standard deviation")
    return out


def calibration_prior_section(cfg: OacliConfig) -> dict[str, Any]:
    """The calibration stage's ``estimation`` settings: batch, the known robot's θ with :data:`KNOWN_VARIANCE`.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.

    Returns
    -------
    dict
        To deep-merge into the stage's config.

    Raises
    ------
    ConfigError
        ``estimation.parameters`` has none of :data:`HANDED_GROUPS` (nothing to calibrate).
    """
    if not set(HANDED_GROUPS) & set(cfg.estimation.parameters):
        raise ConfigError("mission.calibration: true needs force_scale or torque_scale in estimation.parameters "
                          f"(it has {', '.join(cfg.estimation.parameters)}); set mission.calibration: false")
    robot = cfg.robot
    return {"estimation": {"method": "batch", "prior": {
        "mass_kg": float(robot.mass_kg), "inertia_kgm2": [float(v) for v in robot.inertia_kgm2],
        "variance": list(KNOWN_VARIANCE)}}}


def handed_rigid_body(summary: dict[str, Any]) -> dict[str, Any]:
    """The ``estimation.rigid_body`` entries a calibration summary hands on: each estimated group of
    :data:`HANDED_GROUPS` as its mean and per-axis σ (the marginal σ of the batch's covariance, [Doerr2021] Eq. 32).

    Parameters
    ----------
    summary : dict
        The calibration stage's ``summary.json`` (its ``rigid_body`` section).

    Returns
    -------
    dict
        E.g. ``{"force_scale": [..3], "force_scale_std": [..3]}``; empty when none was estimated.
    """
    rb = summary.get("rigid_body") or {}
    est, std = rb.get("estimate") or {}, rb.get("std") or {}
    out: dict[str, Any] = {}
    for group in HANDED_GROUPS:
        names = [f"{group}_{a}" for a in _AXES]
        if all(n in est and n in std for n in names):
            out[group] = [float(est[n]) for n in names]
            out[f"{group}_std"] = [float(std[n]) for n in names]
    return out


@dataclass(frozen=True)
class ActuatorCalibration:
    """What segment 2's estimates are handed: the calibration's actuator prior, or none (the config's).

    Attributes
    ----------
    source : str
        ``calibration`` (segment-1/calibrate's estimate) or ``config`` (the fallback: ``estimation.rigid_body``).
    rigid_body : dict
        The ``estimation.rigid_body`` entries to set (empty with the fallback).
    note : str or None
        Why the calibration was not handed on (None when it was).
    truth : dict
        The calibration's truth of the handed entries (a simulated run), by name.
    """

    source: str
    rigid_body: dict[str, Any] = field(default_factory=dict)
    note: str | None = None
    truth: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The ``calibration`` entry of the mission's summary (with the z-scores where the truth is known)."""
        out: dict[str, Any] = {"source": self.source, **self.rigid_body, "note": self.note}
        z = {}
        for group in HANDED_GROUPS:
            for i, a in enumerate(_AXES):
                name = f"{group}_{a}"
                if group in self.rigid_body and name in self.truth:
                    z[name] = (self.rigid_body[group][i] - self.truth[name]) / self.rigid_body[f"{group}_std"][i]
        if z:
            out["z_score"] = z
        return out


def actuator_calibration(cfg: OacliConfig, mission_dir: Path) -> ActuatorCalibration | None:
    """The actuator prior segment 2's estimates take (None: ``mission.calibration`` is off).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    mission_dir : Path
        The mission folder (``segment-1/calibrate`` has run in it).

    Returns
    -------
    ActuatorCalibration or None
    """
    if cfg.mission is None or not cfg.mission.calibration:
        return None
    folder = stage_by_key(CALIBRATE_KEY).folder(Path(mission_dir))
    summary: dict[str, Any] = {}
    if is_complete(folder):
        summary = json.loads((folder / "summary.json").read_text())
        problems = estimate_failures(summary)
        if summary.get("status") != OK and not problems:  # a fit the model does not explain: σ not to be trusted
            kinds = ", ".join(dict.fromkeys(str(r.get("kind")) for r in summary.get("status_reasons") or ()))
            problems = [f"ended {summary.get('status')} ({kinds or 'see its summary.json'}): the actuator model "
                        "does not explain segment 1's telemetry, so its σ is not to be trusted"]
    else:  # the stage refused (e.g. a scale unobservable from the telemetry)
        problems = ["failed (no estimate from segment 1's telemetry)"]
    handed = handed_rigid_body(summary) if not problems else {}
    if not problems and not handed:
        problems = ["estimated no force or torque scale"]
    if problems:
        return ActuatorCalibration("config", note=(
            f"the actuator calibration ({CALIBRATE_KEY}) {' and '.join(problems)}: segment 2's estimates keep the "
            "config's actuator prior (estimation.rigid_body)"))
    truth = {k: float(v) for k, v in ((summary.get("rigid_body") or {}).get("truth") or {}).items()}
    return ActuatorCalibration("calibration", handed, truth=truth)
