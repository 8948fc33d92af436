"""The mission's actuator calibration: segment 1's flight of the known robot calibrates the thrusters first.

The flight calibrated the per-axis force scale on its own data before estimating the payload ([ReSWARM2023] Eqs.
38-39, §6.2.1): ``v̇ = R κ_F ⊙ (Rᵀ F) / m`` hides a common factor of κ_F and m, so a payload's mass is known no
better than κ_F (and its inertias no better than the torque scale κ_τ). Segment 1 flies the bare robot, whose mass
and inertias are known (``robot:``): the stage ``segment-1/calibrate`` (an ordinary ``estimate`` of segment 1's
telemetry, :func:`calibration_prior_section`) holds them with a negligible variance and estimates the estimation
section's other groups. Its force and torque scales (mean and σ per body axis) become the ``estimation.rigid_body``
prior of segment 2's estimates (:func:`actuator_calibration`): the payload changes mass, inertia and CoM, not the
impellers.

Segment 1 barely rotates the robot, so it calibrates κ_τ only to a few per cent. With
``mission.calibration_manoeuvre`` the known robot also flies a rotation-rich manoeuvre at B before the grasp
(``segment-1/calibrate-manoeuvre``: a waypoint reference, :func:`manoeuvre_poses`) and ``segment-1/calibrate-on-
manoeuvre`` fits its telemetry from segment 1's scales (products of inertia held too), which are then handed on.

Acceptance (:func:`assess_calibration`, :func:`reconcile_flights`): a calibration that failed, did not converge, or
ended ``degraded`` for anything but a moderately high χ² (σ then inflated by √χ²), or whose scale contradicts the
prior it was fitted from, is not handed on: segment 2 keeps the config's prior and the mission says so
(``degraded``, ``calibration_fallback``). Where the two flights disagree on a scale (e.g. a saturating impeller
clipped segment 1's large commands; the manoeuvre's reference asks for about half of each limit at most), the
manoeuvre's own estimate of it is handed on (``degraded``, ``calibration_inconsistent``). A saturating impeller that
clips both flights passes all of these (the fit averages the clipped response into κ, a few per cent low, with a χ²
near 1 and a shift inside the prior): the flights' telemetry is therefore also asked whether any axis's response is
clipped above some fraction of its limit (:func:`flights_linearity`, :mod:`oacli.mission.calibration_linearity`),
and a clipped axis refuses the calibration (``calibration_fallback``, the axis and level named).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.errors import ConfigError
from oacli.io.mcap_read import read_telemetry
from oacli.io.runfolder import is_complete
from oacli.mission.calibration_linearity import AxisLinearity, actuator_linearity
from oacli.mission.layout import stage_by_key
from oacli.status import OK

__all__ = [
    "CALIBRATE_KEY",
    "CALIBRATION_FLIGHTS",
    "CHI2_ACCEPT_MAX",
    "CONSISTENCY_Z_MAX",
    "HANDED_GROUPS",
    "KNOWN_VARIANCE",
    "MANOEUVRE_KEY",
    "ON_MANOEUVRE_KEY",
    "PRIOR_Z_MAX",
    "TOLERATED_KINDS",
    "ActuatorCalibration",
    "actuator_calibration",
    "assess_calibration",
    "calibration_prior_section",
    "calibration_stage_prior",
    "config_actuator_prior",
    "estimate_failures",
    "flights_linearity",
    "handed_rigid_body",
    "manoeuvre_poses",
    "manoeuvre_section",
    "reconcile_flights",
]

CALIBRATE_KEY = "segment-1/calibrate"
"""The calibration stage's key (:data:`oacli.mission.layout.MISSION_STAGES`)."""

MANOEUVRE_KEY = "segment-1/calibrate-manoeuvre"
"""The optional calibration manoeuvre's key (:data:`oacli.mission.layout.OPTIONAL_STAGES`)."""

HANDED_GROUPS = ("force_scale", "torque_scale")
"""The groups the calibration hands to segment 2 (the actuators'; the payload changes the rest)."""

KNOWN_VARIANCE = (1e-8, 1e-10, 1e-10, 1e-10)
"""Variance of the known robot's [m, Ixx, Iyy, Izz] in the calibration [kg², (kg·m²)² ×3]: σ 0.1 g and
1e-5 kg·m² (0.001 % and 0.007 %), the mass and inertias held while the scales are fitted."""

KNOWN_PRODUCTS_STD = 1e-5
"""σ of the known robot's products of inertia [kg·m²] (held at 0, its principal axes) in a calibration on the
manoeuvre (``mission.calibration_manoeuvre``)."""

ON_MANOEUVRE_KEY = "segment-1/calibrate-on-manoeuvre"
"""The second calibration (``mission.calibration_manoeuvre``): the manoeuvre's telemetry fitted from the first's
scales (:data:`oacli.mission.layout.OPTIONAL_STAGES`)."""

TOLERATED_KINDS = ("fit_chi2", "rejected", "input_gaps")
"""``degraded`` findings of a calibration that still leave its scales usable (:func:`assess_calibration`)."""

CHI2_ACCEPT_MAX = 2.0
"""Largest χ² ratio (χ² ÷ its expected value) of a ``degraded`` calibration that is handed on (σ inflated)."""

PRIOR_Z_MAX = 4.0
"""Largest |z| of a calibrated scale against the prior it was fitted from (:func:`assess_calibration`)."""

CONSISTENCY_Z_MAX = 3.0
"""Largest |z| between the two calibration flights of the known robot on one scale (:func:`reconcile_flights`)."""

_AXES = ("x", "y", "z")


def manoeuvre_poses(cfg: OacliConfig) -> list[dict[str, list[float]]]:
    """The calibration manoeuvre's poses (``mission.calibration_manoeuvre``), from B and back to B.

    For each body axis ``e`` in turn (x, y, z; ``repeats`` times): to ``B + offset R e`` turned by ``+angle`` about
    ``e`` (body frame), to ``B - offset R e`` turned by ``-angle``, and back to B: three rest-to-rest legs per axis
    that slew the robot about that axis (torque about it alone, [Doerr2021] Eq. 1b) while it translates along it.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config (with ``mission.calibration_manoeuvre`` set).

    Returns
    -------
    list of dict
        Inline waypoints ``{"position": [3] m, "quaternion": [x, y, z, w]}`` (``reference.waypoints``).
    """
    from oacli.model import quaternion as quat

    assert cfg.mission is not None and cfg.mission.calibration_manoeuvre is not None
    man = cfg.mission.calibration_manoeuvre
    b = cfg.waypoints[cfg.mission.route[1]]
    p_b, q_b = np.asarray(b.position, dtype=float), quat.normalize(np.asarray(b.quaternion, dtype=float))
    rot = quat.to_rotation_matrix(q_b)

    def pose(p: np.ndarray, q: np.ndarray) -> dict[str, list[float]]:
        return {"position": [float(v) for v in p], "quaternion": [float(v) for v in quat.normalize(q)]}

    poses = [pose(p_b, q_b)]
    for _ in range(man.repeats):
        for axis in np.eye(3):
            for sign in (1.0, -1.0):
                poses.append(pose(p_b + sign * man.offset_m * rot @ axis,
                                  quat.multiply(q_b, quat.exp(sign * man.angle_rad * axis))))
            poses.append(pose(p_b, q_b))
    return poses


def manoeuvre_section(cfg: OacliConfig) -> dict[str, Any]:
    """The calibration manoeuvre's ``reference`` section (the waypoint reference of :func:`manoeuvre_poses` with
    ``mission.calibration_manoeuvre``'s limits), to deep-merge into the stage's config.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.

    Returns
    -------
    dict
    """
    assert cfg.mission is not None and cfg.mission.calibration_manoeuvre is not None
    man = cfg.mission.calibration_manoeuvre
    return {"reference": {"source": "waypoints", "file": None, "waypoints": manoeuvre_poses(cfg),
                          "cruise_speed_mps": man.cruise_speed_mps, "acceleration_mps2": man.acceleration_mps2,
                          "angular_rate_radps": man.angular_rate_radps,
                          "angular_acceleration_radps2": man.angular_acceleration_radps2, "hold_s": man.hold_s}}


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


def calibration_prior_section(cfg: OacliConfig, *, manoeuvre: bool = False) -> dict[str, Any]:
    """The calibration stage's ``estimation`` settings: batch, the known robot's θ with :data:`KNOWN_VARIANCE`.

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    manoeuvre : bool
        For :data:`ON_MANOEUVRE_KEY`: the known robot's products of inertia are held too (at 0,
        :data:`KNOWN_PRODUCTS_STD`), and every group of :data:`HANDED_GROUPS` is estimated (the slews inform the
        torque scales even where segment 2 holds them).

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
        off = "mission.calibration: false" + ("" if cfg.mission is None or cfg.mission.calibration_manoeuvre is None
                                              else " and mission.calibration_manoeuvre: null")
        raise ConfigError("mission.calibration: true needs force_scale or torque_scale in estimation.parameters "
                          f"(it has {', '.join(cfg.estimation.parameters)}); set {off}")
    robot = cfg.robot
    section: dict[str, Any] = {"estimation": {"method": "batch", "prior": {
        "mass_kg": float(robot.mass_kg), "inertia_kgm2": [float(v) for v in robot.inertia_kgm2],
        "variance": list(KNOWN_VARIANCE)}}}
    if manoeuvre:  # the known robot's principal axes too: its slews would otherwise trade products of inertia for κ_τ.
        section["estimation"]["rigid_body"] = {"products_kgm2": [0.0, 0.0, 0.0],
                                               "products_std_kgm2": KNOWN_PRODUCTS_STD}
        # The slews determine the torque scales whatever segment 2 estimates: a segment 2 that holds them gets the
        # calibrated κ_τ ± σ as its held value, so its consider covariance carries σ, not the config's 5 %.
        section["estimation"]["parameters"] = list(dict.fromkeys([*cfg.estimation.parameters, *HANDED_GROUPS]))
    return section


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
    stage : str
        The stage whose estimate is handed on.
    inflation : float
        The factor its σ was inflated by (:func:`assess_calibration`; 1: none).
    replaced : tuple of str
        The scales on which the two flights disagreed, handed on from the manoeuvre alone
        (:func:`reconcile_flights`).
    linearity : dict of str to float
        The clip test's smallest z per actuator axis over the calibration flights
        (:mod:`oacli.mission.calibration_linearity`; a saturating actuator refuses the calibration).
    """

    source: str
    rigid_body: dict[str, Any] = field(default_factory=dict)
    note: str | None = None
    truth: dict[str, float] = field(default_factory=dict)
    stage: str = CALIBRATE_KEY
    inflation: float = 1.0
    replaced: tuple[str, ...] = ()
    linearity: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The ``calibration`` entry of the mission's summary (with the z-scores where the truth is known)."""
        out: dict[str, Any] = {"source": self.source, **self.rigid_body, "note": self.note}
        if self.linearity:
            out["linearity_z"] = dict(self.linearity)
        if self.stage != CALIBRATE_KEY or self.inflation != 1.0:
            out.update(stage=self.stage, sigma_inflation=self.inflation, replaced=list(self.replaced))
        z = {}
        for group in HANDED_GROUPS:
            for i, a in enumerate(_AXES):
                name = f"{group}_{a}"
                if group in self.rigid_body and name in self.truth:
                    z[name] = (self.rigid_body[group][i] - self.truth[name]) / self.rigid_body[f"{group}_std"][i]
        if z:
            out["z_score"] = z
        return out


def config_actuator_prior(cfg: OacliConfig) -> dict[str, Any]:
    """The config's actuator prior (``estimation.rigid_body``) as per-axis means and σ, like
    :func:`handed_rigid_body`'s."""
    rb = cfg.estimation.rigid_body
    out: dict[str, Any] = {}
    for group in HANDED_GROUPS:
        std = getattr(rb, f"{group}_std")
        out[group] = [float(v) for v in getattr(rb, group)]
        out[f"{group}_std"] = [float(v) for v in np.broadcast_to(np.asarray(std, dtype=float), (3,))]
    return out


def assess_calibration(summary: dict[str, Any], prior: dict[str, Any]) -> tuple[dict[str, Any], list[str], float]:
    """Whether a calibration stage's estimate may be handed on, and what (the acceptance rule).

    1. It must have converged with a finite covariance (:func:`estimate_failures`).
    2. ``ok``, or ``degraded`` only for findings that leave the scales usable (:data:`TOLERATED_KINDS`: a χ² above
       its expected value, records rejected by the gate, input gaps) with a χ² ratio up to
       :data:`CHI2_ACCEPT_MAX`. The handed σ is then inflated by √(χ² ratio) (the Birge ratio: the residuals are
       larger than the noise model says, so the σ from that model is too small by about that factor).
    3. Every handed scale must agree with the prior it was fitted from: in a linear-Gaussian update the shift of
       the mean, posterior - prior, has variance σ_prior² - σ_post², so ``|z| = |κ - κ_prior| /
       √(σ_prior² - σ_post²)`` (``σ_post`` the fit's own, before the consider covariance) above
       :data:`PRIOR_Z_MAX` means the telemetry contradicts the prior. With the
       config's 5 % prior that is a scale 20 % off (a saturating impeller: the commands are recorded as applied
       while the plant receives less, [ReSWARM2023] §6.2.1). Two calibration flights are compared by
       :func:`reconcile_flights`.

    Parameters
    ----------
    summary : dict
        The calibration stage's ``summary.json`` (empty: the stage failed).
    prior : dict
        The prior it was fitted from, as :func:`handed_rigid_body` returns.

    Returns
    -------
    handed : dict
        The ``estimation.rigid_body`` entries (empty when rejected).
    problems : list of str
        Why it is rejected (empty: accepted).
    inflation : float
        The factor applied to its σ (1: none).
    """
    if not summary:
        return {}, ["failed (no estimate from its telemetry)"], 1.0
    problems = estimate_failures(summary)
    if problems:
        return {}, problems, 1.0
    inflation = 1.0
    if summary.get("status") != OK:
        kinds = list(dict.fromkeys(str(r.get("kind")) for r in summary.get("status_reasons") or ()))
        ratio = float(summary.get("chi2_ratio") or 1.0)
        if not kinds or set(kinds) - set(TOLERATED_KINDS) or not ratio <= CHI2_ACCEPT_MAX:
            return {}, [f"ended {summary.get('status')} ({', '.join(kinds) or 'see its summary.json'}; χ² "
                        f"{ratio:.3g} × expected, accepted up to {CHI2_ACCEPT_MAX:g} × with "
                        f"{'/'.join(TOLERATED_KINDS)} only): the actuator model does not explain the telemetry, so "
                        "its σ is not to be trusted"], 1.0
        inflation = float(np.sqrt(max(ratio, 1.0)))
    handed = handed_rigid_body(summary)
    if not handed:
        return {}, ["estimated no force or torque scale"], 1.0
    # The update's own σ (the fit's, before the consider covariance widens it by what it holds fixed: that one is
    # not a posterior of this prior and may exceed it, docs/estimation.md).
    statistical = (summary.get("consider") or {}).get("std_statistical") or {}
    for group in HANDED_GROUPS:
        if group not in handed:
            continue
        handed[f"{group}_std"] = [inflation * v for v in handed[f"{group}_std"]]
        if group not in prior:
            continue
        for i, a in enumerate(_AXES):
            shift = handed[group][i] - prior[group][i]
            post = float(statistical.get(f"{group}_{a}", handed[f"{group}_std"][i] / inflation))
            var = prior[f"{group}_std"][i] ** 2 - post ** 2
            z = shift / np.sqrt(max(var, 1e-4 * prior[f"{group}_std"][i] ** 2))
            if abs(z) > PRIOR_Z_MAX:
                problems.append(f"{group}_{a} {handed[group][i]:.4f} contradicts its prior {prior[group][i]:.4f} ± "
                                f"{prior[f'{group}_std'][i]:.3g} (z {z:.1f}, accepted up to {PRIOR_Z_MAX:g}: e.g. a "
                                "saturating actuator)")
    return ({}, problems, 1.0) if problems else (handed, [], inflation)


def reconcile_flights(second: dict[str, Any], first: dict[str, Any],
                      inflation: float = 1.0) -> tuple[dict[str, Any], list[str], list[str]]:
    """Check the manoeuvre's calibration (fitted from the first one's scales) against segment 1's, per scale.

    The manoeuvre's fit ``κ₂ ± σ₂`` started from segment 1's ``κ₁ ± σ₁``; per axis (scalar Gaussian update, the
    cross-correlations neglected) the manoeuvre's own data say ``κ_d ± σ_d`` with ``1/σ_d² = 1/σ₂² - 1/σ₁²`` and
    ``κ_d = σ_d² (κ₂/σ₂² - κ₁/σ₁²)``, and the two flights agree when ``|κ_d - κ₁| / √(σ_d² + σ₁²)`` (= ``|κ₂ - κ₁|
    / √(σ₁² - σ₂²)``) is at most :data:`CONSISTENCY_Z_MAX`. Where they do not, a fault struck one flight: a
    saturating actuator clips the large commands only ([ReSWARM2023] §6.2.1; ``faults.actuator_saturation`` delivers
    at least 60 % of a limit in the flight-fault campaign), and the manoeuvre's reference asks for less than about
    half of every limit (the defaults of ``mission.calibration_manoeuvre``; the MPC's feedback adds to it) while
    segment 1's plan may use most of it, so the manoeuvre's own ``κ_d ± σ_d`` is handed on for that scale.

    Parameters
    ----------
    second : dict
        The manoeuvre's handed scales (:func:`assess_calibration`), σ already multiplied by ``inflation``.
    first : dict
        Segment 1's handed scales (its prior).
    inflation : float
        The factor ``second``'s σ carries (removed for the update arithmetic, applied to σ_d).

    Returns
    -------
    handed : dict
        ``second`` with the disagreeing scales replaced (empty when a replacement is impossible).
    replaced : list of str
        One sentence per replaced scale.
    problems : list of str
        Why nothing can be handed on (empty: it can).
    """
    out = {k: list(v) for k, v in second.items()}
    replaced: list[str] = []
    for group in HANDED_GROUPS:
        if group not in second or group not in first:
            continue
        for i, a in enumerate(_AXES):
            k1, s1 = first[group][i], first[f"{group}_std"][i]
            k2, s2 = second[group][i], second[f"{group}_std"][i] / inflation
            var = s1**2 - s2**2
            z = (k2 - k1) / np.sqrt(max(var, 1e-4 * s1**2))
            if abs(z) <= CONSISTENCY_Z_MAX:
                continue
            info = 1.0 / s2**2 - 1.0 / s1**2
            if info <= 0.0:
                return {}, replaced, [f"{group}_{a}: the two flights disagree (z {z:.1f}) and the manoeuvre alone does "
                                      "not determine it"]
            kd, sd = (k2 / s2**2 - k1 / s1**2) / info, 1.0 / np.sqrt(info)
            out[group][i], out[f"{group}_std"][i] = float(kd), float(inflation * sd)
            replaced.append(f"{group}_{a}: segment 1 says {k1:.4f} ± {s1:.2g}, the manoeuvre {kd:.4f} ± {sd:.2g} "
                            f"(z {z:.1f} > {CONSISTENCY_Z_MAX:g}: e.g. a saturating actuator); the manoeuvre's is "
                            "handed on")
    return out, replaced, []


def _stage_summary(mission_dir: Path, key: str) -> dict[str, Any]:
    folder = stage_by_key(key).folder(Path(mission_dir))
    return json.loads((folder / "summary.json").read_text()) if is_complete(folder) else {}


def calibration_stage_prior(cfg: OacliConfig, mission_dir: Path) -> dict[str, Any] | None:
    """The ``estimation.rigid_body`` prior of :data:`ON_MANOEUVRE_KEY`: :data:`CALIBRATE_KEY`'s handed scales when
    they pass :func:`assess_calibration`, else None (the config's)."""
    handed, problems, _ = assess_calibration(_stage_summary(mission_dir, CALIBRATE_KEY), config_actuator_prior(cfg))
    return None if problems else handed


def actuator_calibration(cfg: OacliConfig, mission_dir: Path) -> ActuatorCalibration | None:
    """The actuator prior segment 2's estimates take (None: ``mission.calibration`` is off).

    Without the manoeuvre: :data:`CALIBRATE_KEY`'s estimate if it passes :func:`assess_calibration` against the
    config's prior. With it (``mission.calibration_manoeuvre``): :data:`ON_MANOEUVRE_KEY`'s, fitted from the
    first calibration's scales (or the config's when that one was rejected), assessed against the config's prior
    and, scale by scale, against the first one (:func:`reconcile_flights`).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    mission_dir : Path
        The mission folder (the calibration stages have run in it).

    Returns
    -------
    ActuatorCalibration or None
    """
    if cfg.mission is None or not cfg.mission.calibration:
        return None
    config_prior = config_actuator_prior(cfg)
    first = _stage_summary(mission_dir, CALIBRATE_KEY)
    handed, problems, inflation = assess_calibration(first, config_prior)
    key, summary = CALIBRATE_KEY, first
    notes = [f"{CALIBRATE_KEY} {' and '.join(problems)}"] if problems else []
    replaced: list[str] = []
    if cfg.mission.calibration_manoeuvre is not None:
        first_handed = None if problems else handed
        key, summary = ON_MANOEUVRE_KEY, _stage_summary(mission_dir, ON_MANOEUVRE_KEY)
        handed, problems, inflation = assess_calibration(summary, config_prior)  # plausible at all?
        if not problems and first_handed is not None:  # and the two flights agree
            handed, replaced, problems = reconcile_flights(handed, first_handed, inflation)
        if problems:
            notes.append(f"{ON_MANOEUVRE_KEY} {' and '.join(problems)}")
    linearity = flights_linearity(cfg, mission_dir)
    clipped = [a.describe() for a in linearity if a.saturating]
    if clipped:  # the scales fitted a clipped response: a saturating impeller, not to be handed on
        found = (f"the known robot's flights ({', '.join(CALIBRATION_FLIGHTS)}) show a saturating actuator: "
                 + "; ".join(clipped))
        problems = [*problems, found]
        notes.append(found)
    if problems:
        return ActuatorCalibration("config", note=(
            f"the actuator calibration: {'; '.join(notes)}: segment 2's estimates keep the config's actuator prior "
            "(estimation.rigid_body)"), linearity=_linearity_z(linearity))
    truth = {k: float(v) for k, v in ((summary.get("rigid_body") or {}).get("truth") or {}).items()}
    note = None
    if notes:  # the manoeuvre's fit from the config's prior: handed on, the first one's rejection noted
        note = f"the actuator calibration: {'; '.join(notes)}: {key} is handed on, fitted from the config's prior"
    if replaced:
        note = f"the actuator calibration's two flights disagree: {'; '.join(replaced)}"
    return ActuatorCalibration("calibration", handed, note=note, truth=truth, stage=key, inflation=inflation,
                               replaced=tuple(replaced), linearity=_linearity_z(linearity))


CALIBRATION_FLIGHTS = ("segment-1/track", MANOEUVRE_KEY)
"""The known robot's flights whose telemetry the calibrations fit (the manoeuvre's when it is flown)."""

_LINEARITY_CACHE: dict[tuple[str, ...], list[AxisLinearity]] = {}


def flights_linearity(cfg: OacliConfig, mission_dir: Path) -> list[AxisLinearity]:
    """The clip test of :mod:`oacli.mission.calibration_linearity` over the calibration flights' telemetry
    (:data:`CALIBRATION_FLIGHTS` that ran; empty when none did)."""
    paths = [stage_by_key(key).mcap(Path(mission_dir)) for key in CALIBRATION_FLIGHTS
             if is_complete(stage_by_key(key).folder(Path(mission_dir)))]
    if not paths:
        return []
    cache_key = tuple(f"{p}:{p.stat().st_mtime_ns}" for p in paths)
    if cache_key not in _LINEARITY_CACHE:
        s, robot = cfg.sensors, cfg.robot
        _LINEARITY_CACHE[cache_key] = actuator_linearity(
            [read_telemetry(p) for p in paths], float(robot.mass_kg), np.asarray(robot.inertia_kgm2, dtype=float),
            np.concatenate([robot.force_limit_N, robot.torque_limit_Nm]),
            (s.position_std_m, s.velocity_std_mps, s.angular_velocity_std_radps))
    return _LINEARITY_CACHE[cache_key]


def _linearity_z(linearity: list[AxisLinearity]) -> dict[str, float]:
    return {a.axis: round(a.z, 2) for a in linearity if np.isfinite(a.z)}
