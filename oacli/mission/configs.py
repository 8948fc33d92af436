"""Each mission stage's config, derived from the mission config and what the earlier stages produced.

A stage's config is the mission file's sections (without ``mission``), deep-merged with the segment's overrides
(``mission.segments``), then set by the mission: the route's waypoints, the plant (the bare robot in segment 1,
``mission.grasped`` after the grasp at B), the controller's model (the robot model, then ``mission.prior``, then
the estimate: the model handoff of [Doerr2021] Fig. 1), the controller type and the tube's W ([Doerr2021] Eq. 28
from ``w_sigmas`` σ of the model's mass), the reference file, the initial offset from where the previous segment
ended, and a seed of its own. Each config is validated like a file; its ``config.yaml`` in the stage's folder
reruns that stage alone (``oacli <stage> <folder>/config.yaml``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig, config_from_dict
from oacli.config.mission import MissionConfig, deep_merge
from oacli.errors import ConfigError, InfeasibleError
from oacli.mission.calibration import (
    CALIBRATE_KEY,
    MANOEUVRE_KEY,
    ON_MANOEUVRE_KEY,
    calibration_prior_section,
    manoeuvre_section,
)
from oacli.mission.layout import ALL_STAGES, MissionStage, stage_by_key
from oacli.model.robot_model import RobotModel
from oacli.stages.settings import robot_model, tube_design_from_config


@dataclass(frozen=True)
class Handoff:
    """What the earlier stages hand to a stage.

    Attributes
    ----------
    reference : Path or None
        The trajectory to track (a smooth or excite MCAP), for ``track`` stages.
    plan : Path or None
        The plan to smooth, for ``smooth`` stages.
    telemetry : Path or None
        The tracking run to estimate from, for ``estimate`` stages.
    initial_offset_m : tuple of float
        Where the previous segment's true state ended, minus this segment's start [m].
    estimate : RobotModel or None
        The learned model (segment 3): mass, inertias and their covariance, and the centre of mass and products of
        inertia with their σ when segment 2 estimated them.
    rigid_body : dict or None
        Segment 2's estimates: the actuator calibration's ``estimation.rigid_body`` entries
        (:mod:`oacli.mission.calibration`); None: the config's.
    """

    reference: Path | None = None
    plan: Path | None = None
    telemetry: Path | None = None
    initial_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimate: RobotModel | None = None
    rigid_body: dict[str, Any] | None = None


def stage_seed(seed: int, index: int) -> int:
    """The seed of the mission's ``index``-th stage: an independent stream per stage ([numpy] SeedSequence).

    Parameters
    ----------
    seed : int
        The mission's seed.
    index : int
        The stage's position in :data:`oacli.mission.layout.ALL_STAGES`.

    Returns
    -------
    int
        A seed in [0, 2³¹).
    """
    state = np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(1, dtype=np.uint32)
    return int(state[0] % (2**31))


CALIBRATION_SEED_INDEX = 1000
"""The spawn key of ``segment-1/calibrate``'s seed: apart from the other stages', which keep their index without it
(:func:`seed_index`), so ``mission.calibration: false`` draws the numbers of the mission before the calibration."""


def seed_index(stage: MissionStage) -> int:
    """The spawn key of ``stage``'s seed (:func:`stage_seed`): its index among the mission's stages without the
    calibration, :data:`CALIBRATION_SEED_INDEX` for the calibration.

    Parameters
    ----------
    stage : MissionStage

    Returns
    -------
    int
    """
    if stage.key == CALIBRATE_KEY:
        return CALIBRATION_SEED_INDEX
    return [s.key for s in ALL_STAGES if s.key != CALIBRATE_KEY].index(stage.key)


def mission_section(cfg: OacliConfig) -> MissionConfig:
    """The config's ``mission`` section.

    Parameters
    ----------
    cfg : OacliConfig
        A mission config.

    Returns
    -------
    MissionConfig

    Raises
    ------
    ConfigError
        The config has no ``mission`` section.
    """
    if cfg.mission is None:
        raise ConfigError("mission: missing: oacli mission needs a mission section (route, grasped, prior); "
                          "see configs/mission_iss.yaml")
    return cfg.mission


def prior_model(cfg: OacliConfig) -> RobotModel:
    """The controller's model of robot + payload after the grasp, before estimation (``mission.prior``).

    Parameters
    ----------
    cfg : OacliConfig
        A mission config.

    Returns
    -------
    RobotModel
    """
    prior = mission_section(cfg).prior
    return robot_model(cfg).with_estimate(
        np.array([prior.mass_kg, *prior.inertia_kgm2]), np.diag(np.array(prior.variance, dtype=float)))


RIGID_ENTRIES = (("com_x_m", "com_y_m", "com_z_m"), ("Ixy_kgm2", "Ixz_kgm2", "Iyz_kgm2"))
"""The estimate summary's ``rigid_body`` entries the learned model carries beyond θ: the centre of mass and the
products of inertia (:data:`oacli.estimation.rigid_parameters.FULL_NAMES`)."""


def with_rigid_estimate(model: RobotModel, rigid: dict[str, Any]) -> RobotModel:
    """``model`` with the centre of mass and the products of inertia the batch estimated, and their σ.

    Reads the estimate summary's ``rigid_body`` section (``estimate`` and ``std`` by name, as the estimate stage
    writes it); an entry not estimated stays at the model's value and σ (zeros for the prior: the centred,
    principal-axes robot, as before the full rigid body was estimated).

    Parameters
    ----------
    model : RobotModel
        The learned model (θ and its covariance set).
    rigid : dict
        The summary's ``rigid_body`` section.

    Returns
    -------
    RobotModel

    Raises
    ------
    ValueError
        The estimated tensor is not physical (the learned model then falls back to the prior).
    """
    estimate, std = rigid.get("estimate") or {}, rigid.get("std") or {}
    parts = []
    for names, mean0, std0 in ((RIGID_ENTRIES[0], model.com_offset_m, model.com_std_m),
                               (RIGID_ENTRIES[1], model.inertia_products_kgm2, model.products_std_kgm2)):
        mean, sigma = np.array(mean0, dtype=float), np.array(std0, dtype=float)
        for i, name in enumerate(names):
            if name in estimate and name in std:
                mean[i], sigma[i] = float(estimate[name]), float(std[name])
        parts.extend([mean, sigma])
    return model.with_rigid_body(*parts)


REFERENCE_SHARE = 0.8
"""Share of the smallest force (torque) limit the reference section's acceleration (angular acceleration) may ask
of the heaviest plausible plant (the rest for the feedback, as ``reference_force_fraction``)."""


def model_section(model: RobotModel) -> dict[str, Any]:
    """``model`` (mean *and* the diagonal of its covariance) as a stage config's ``robot:`` entries.

    Parameters
    ----------
    model : RobotModel

    Returns
    -------
    dict
        ``{"mass_kg", "inertia_kgm2", "variance", "com_offset_m", "com_variance_m2", "inertia_products_kgm2",
        "products_variance"}``: ``robot_model`` of the stage's config gives back θ, ``diag(covariance)``, the
        centre of mass, the products and their σ (σ² written, its square root read back: to rounding).
    """
    theta = model.theta

    def floats(values: np.ndarray) -> list[float]:
        return [float(v) for v in values]

    return {"mass_kg": float(theta[0]), "inertia_kgm2": floats(theta[1:4]),
            "variance": floats(np.diag(model.covariance)),
            "com_offset_m": floats(model.com_offset_m), "com_variance_m2": floats(model.com_std_m**2),
            "inertia_products_kgm2": floats(model.inertia_products_kgm2),
            "products_variance": floats(model.products_std_kgm2**2)}


def _model_sections(model: RobotModel, w_sigmas: float) -> dict[str, Any]:
    """The config entries that make ``model`` (mean *and* covariance) the controller's and the planner's model.

    The stage's ``robot:`` is the model (:func:`model_section`): the tube's W takes ``w_sigmas`` σ of its mass
    ([Doerr2021] Eq. 28) and the planner's design limits ``planner.margin.mass_sigmas`` σ, both σ_m the model's.
    """
    return {
        "robot": model_section(model),
        "controller": {"tube": {"disturbance": {"mass_sigmas": float(w_sigmas)}}},
    }


def reference_within_model(reference: dict[str, Any], robot: dict[str, Any], model: RobotModel,
                           n_sigma: float) -> dict[str, Any]:
    """The reference section's accelerations lowered so the heaviest plausible plant follows them.

    ``acceleration_mps2 ≤ φ · min F / m_upper`` and ``angular_acceleration_radps2 ≤ φ · min τ / max I_upper`` with
    ``m_upper = m + n_σ σ_m``, ``I_upper = I + n_σ σ_I`` ([Doerr2021] Eq. 28's bound; φ = :data:`REFERENCE_SHARE`):
    the section then holds for whatever model a segment is handed (a heavy payload no longer makes a valid mission
    config invalid in segment 3). Never raised above the file's values.

    Parameters
    ----------
    reference : dict
        The stage's ``reference`` section (plain data).
    robot : dict
        Its ``robot`` section (the limits).
    model : RobotModel
        The segment's model.
    n_sigma : float
        n_σ of the bounds.

    Returns
    -------
    dict
        ``{"acceleration_mps2": …, "angular_acceleration_radps2": …}``.
    """
    m_upper = model.parameter_interval("mass_kg", n_sigma)[1]
    i_upper = float(np.max(model.inertia_upper_kgm2(n_sigma)))
    acc = REFERENCE_SHARE * min(robot["force_limit_N"]) / m_upper
    ang = REFERENCE_SHARE * min(robot["torque_limit_Nm"]) / i_upper
    return {"acceleration_mps2": min(float(reference["acceleration_mps2"]), acc),
            "angular_acceleration_radps2": min(float(reference["angular_acceleration_radps2"]), ang)}


def _prior_sections(prior: RobotModel) -> dict[str, Any]:
    section = {k: v for k, v in model_section(prior).items() if k in ("mass_kg", "inertia_kgm2", "variance")}
    return {"excitation": {"prior": dict(section)}, "estimation": {"prior": dict(section)}}


MAX_RATE_MARGIN = 0.8
"""Most of the angular-rate limit the controllers keep free (``controller.rate_margin`` must stay below 0.9)."""


def inertia_margin_sections(model: RobotModel, n_sigma: float, data: dict[str, Any]) -> dict[str, Any]:
    """Margins for a plant whose inertias lie anywhere in the model's ``n_sigma`` range (``rate_margin_sigmas``).

    With ``k = 1 / (1 + n σ_I / I)`` (the largest relative σ of the three principal inertias), i.e. ``I / I_upper``:

    * ``controller.rate_margin = 1 − k``: the attitude MPC constrains the predicted rate to ``k`` × the limit, the
      room an under-modelled inertia's overshoot takes;
    * ``excitation.margin``: the rate share × ``k`` (the reference stays inside the controllers' constraint) and the
      torque share × ``k`` (a plant with ``I_upper`` needs ``I_upper / I`` times the model's torque for the same
      angular acceleration: [Doerr2021] Eq. 35b, as Eq. 28 does for the mass and the force).

    Parameters
    ----------
    model : RobotModel
        The controllers' model (mean and covariance).
    n_sigma : float
        n_σ; 0: no margin (an empty dict).
    data : dict
        The stage's config data (the excitation shares it lowers).

    Returns
    -------
    dict
        Sections to deep-merge.
    """
    if n_sigma <= 0:
        return {}
    rel = float(np.max(n_sigma * model.std[1:4] / model.inertia_kgm2))
    margin = min(1.0 - 1.0 / (1.0 + rel), MAX_RATE_MARGIN)
    keep = 1.0 - margin
    share = data["excitation"]["margin"]
    return {"controller": {"rate_margin": margin},
            "excitation": {"margin": {
                "reference_angular_velocity_fraction": share["reference_angular_velocity_fraction"] * keep,
                "reference_torque_fraction": share["reference_torque_fraction"] * keep}}}


def _connection_s(data: dict[str, Any], model: RobotModel, n_sigma: float) -> float:
    """Segment 3's longest LQR-RRT* connection [s]: the file's ``planner.max_connection_s`` (tuned for the
    ``robot:`` of the file) × ``sqrt(m_upper / m_robot)``, never shorter. A rest-to-rest move of length d at
    acceleration a takes ``2 sqrt(d / a)``, and a heavier model at the same force accelerates ``m_robot / m_upper``
    times slower: without it, a 25 kg payload's plan found no connection within the iteration budget."""
    base, dt = float(data["planner"]["max_connection_s"]), float(data["planner"]["steer_dt_s"])
    m_upper = model.parameter_interval("mass_kg", n_sigma)[1]
    scaled = base * max(1.0, float(np.sqrt(m_upper / float(data["robot"]["mass_kg"]))))
    return max(base, dt * float(np.ceil(scaled / dt - 1e-9)))  # a whole number of steering steps


def tube_nominal_force_N(cfg: OacliConfig) -> np.ndarray | None:
    """The tightened nominal input bound ``Ū = U ⊖ K Z`` (``U ⊖ K R`` with the observer) per world axis [N] of the
    tube ``cfg`` is flown with (:func:`oacli.stages.settings.tube_design_from_config`, its robot model); the
    smaller of ``−Ū_lower`` and ``Ū_upper`` (the nominal MPC's constraint, [Doerr2021] Eq. 27).

    Parameters
    ----------
    cfg : OacliConfig
        A tube-MPC stage's config.

    Returns
    -------
    ndarray, shape (3,), or None
        None when no tube can be designed (the track stage then reports why).
    """
    try:
        design = tube_design_from_config(cfg)
    except InfeasibleError:
        return None
    return np.array([min(-ax.force_bounds_N[0], ax.force_bounds_N[1]) for ax in design.axes])


NOMINAL_FLOOR_SHARE = 0.5
"""The plan's force cap follows the tube's tightened bound Ū down to this share of :data:`REFERENCE_SHARE` × the tube
force, not below: a heavy payload's output-feedback tube leaves Ū ≈ 0.02 N of 0.15 N (K R grows with the mass), and
the planner found no path from C to A at that force within its budget (2 of 16 runs of the payload-envelope
campaign); the nominal MPC then lags the part of the plan above Ū, as it did before the plan followed Ū."""


def _tube_force_cap(data: dict[str, Any], nominal_N: np.ndarray | None = None) -> list[float]:
    """Segment 3's planner force cap: :data:`REFERENCE_SHARE` of the tube's force limit
    ``controller.tube.force_limit_N``, never above the tightened nominal bound ``nominal_N`` of the tube the plan is
    flown with (:func:`tube_nominal_force_N`: the nominal MPC cannot ask more) unless that falls below
    :data:`NOMINAL_FLOOR_SHARE` of the share, the file's own
    ``planner.limits.force_N`` or the robot's limit.

    The tube MPC flies the plan, and segment 3 starts where segment 2's true state ended (up to 0.58 m from C for a
    25 kg payload on the 14.5 kg prior): a plan asking the whole nominal force leaves none to catch up, and such a
    flight overshot A by 0.24 m and never arrived; with 80 % it arrives.
    """
    tube = data["controller"]["tube"].get("force_limit_N") or data["robot"]["force_limit_N"]
    own = data["planner"].get("limits", {}).get("force_N") or data["robot"]["force_limit_N"]
    nominal = [np.inf] * 3 if nominal_N is None else [float(v) for v in nominal_N]
    return [float(min(REFERENCE_SHARE * t, max(n, NOMINAL_FLOOR_SHARE * REFERENCE_SHARE * t), o, r))
            for t, n, o, r in zip(tube, nominal, own, data["robot"]["force_limit_N"], strict=True)]


def stage_config(cfg: OacliConfig, stage: MissionStage, handoff: Handoff, *, source: str = "mission") -> OacliConfig:
    """The config of one mission stage (module docstring).

    Parameters
    ----------
    cfg : OacliConfig
        The mission config.
    stage : MissionStage
        The stage.
    handoff : Handoff
        What the earlier stages produced (placeholders are fine to validate up front).
    source : str
        Name used in validation messages.

    Returns
    -------
    OacliConfig

    Raises
    ------
    ConfigError
        The segment's overrides make an invalid config (the message names the segment and the field).
    """
    mission = mission_section(cfg)
    a, b, c = mission.route
    unknown = sorted(k for k in mission.segments if "/" in k and k not in {s.key for s in ALL_STAGES})
    if unknown:
        raise ConfigError(f"mission.segments.{unknown[0]}: unknown stage (allowed: "
                          + ", ".join(s.key for s in ALL_STAGES) + ")")
    data = cfg.model_dump(mode="json")  # what dump_config writes, without the YAML text round trip
    data.pop("mission", None)
    data = deep_merge(data, mission.segments.get(stage.segment) or {})
    data = deep_merge(data, mission.segments.get(stage.key) or {})  # one stage's own (e.g. a baseline), after
    index = seed_index(stage)
    prior = prior_model(cfg)
    grasped = {"mass_kg": mission.grasped.mass_kg, "inertia_kgm2": list(mission.grasped.inertia_kgm2)}
    sets: dict[str, Any] = {
        "name": f"{cfg.name}-{stage.segment}-{stage.name}"[:64],
        "seed": stage_seed(cfg.seed, index),
        "simulation": {"settle_time_s": mission.settle_s, "initial_offset_m": list(handoff.initial_offset_m)},
    }
    if stage.segment == "segment-1" and stage.key != MANOEUVRE_KEY:  # the mission's own start offset (a campaign
        sets["simulation"]["initial_offset_m"] = list(cfg.simulation.initial_offset_m)  # disperses it); later: handed
    if stage.segment == "segment-1":
        sets["planner"] = {"segment": f"{a}-{b}"}
        sets["controller"] = {"type": "mpc"}
    else:
        sets["truth"] = grasped
        sets = deep_merge(sets, _prior_sections(prior))
    model: RobotModel | None = None  # the controller's model after the grasp (None: the robot's, segment 1)
    if stage.segment == "segment-2":
        model = prior
        sets = deep_merge(sets, _model_sections(prior, mission.w_sigmas))
        sets = deep_merge(sets, {"controller": {"type": "tube"}, "excitation": {"start": b, "goal": c}})
        if mission.excitation_method is not None:
            sets["excitation"]["method"] = mission.excitation_method
    if stage.segment == "segment-3":
        sets["planner"] = {"segment": f"{c}-{a}"}
        learned = handoff.estimate if handoff.estimate is not None else prior
        model = prior if stage.name.endswith("-prior") else learned
        sets = deep_merge(sets, _model_sections(model, mission.w_sigmas))
        sets["controller"]["type"] = "mpc" if stage.name.startswith("baseline-mpc-") else "tube"
        if stage.name == "baseline-mpc-unconstrained-prior":  # the paper's standard MPC: no workspace constraints
            sets["controller"]["position_constraints"] = False
    if model is not None:
        sets["reference"] = reference_within_model(data["reference"], data["robot"], model, mission.w_sigmas)
        sets = deep_merge(sets, inertia_margin_sections(model, mission.rate_margin_sigmas, data))
    if stage.segment == "segment-3":
        assert model is not None
        nominal = None
        if stage.command in ("plan", "smooth"):  # the plan within the nominal bounds of the tube that flies it
            track = stage_config(cfg, stage_by_key("segment-3/track"), Handoff(estimate=handoff.estimate),
                                 source=source)
            nominal = tube_nominal_force_N(track)
        sets = deep_merge(sets, {"planner": {"limits": {"force_N": _tube_force_cap(data, nominal)},
                                             "max_connection_s": _connection_s(data, model, mission.w_sigmas)}})
    if stage.key == MANOEUVRE_KEY:  # the known robot's calibration manoeuvre at B: a waypoint reference
        sets = deep_merge(sets, manoeuvre_section(cfg))
    elif stage.command == "track" and handoff.reference is not None:
        sets = deep_merge(sets, {"reference": {"source": "file", "file": str(handoff.reference)}})
    # The stage's input file and method in its config, as its command records them: the folder's config.yaml alone
    # reruns it (``oacli smooth RUN/segment-1/smooth/config.yaml``, ``oacli estimate .../estimate/config.yaml``).
    if stage.command == "smooth" and handoff.plan is not None:
        sets["inputs"] = {"smooth_input": str(handoff.plan)}
    if stage.command == "estimate":
        if handoff.telemetry is not None:
            sets["inputs"] = {"estimate_telemetry": str(handoff.telemetry)}
        method = "sequential" if stage.name == "estimate-sequential" else "batch"
        sets = deep_merge(sets, {"estimation": {"method": method}})  # merged: the section holds the prior
        if stage.key in (CALIBRATE_KEY, ON_MANOEUVRE_KEY):  # the known robot: its θ held, the actuators fitted
            sets = deep_merge(sets, calibration_prior_section(cfg, manoeuvre=stage.key == ON_MANOEUVRE_KEY))
        if stage.key != CALIBRATE_KEY and handoff.rigid_body:
            sets = deep_merge(sets, {"estimation": {"rigid_body": dict(handoff.rigid_body)}})
    data = deep_merge(data, sets)
    try:
        return config_from_dict(data, source=f"{source} ({stage.key})")
    except ConfigError as exc:
        if stage.key == MANOEUVRE_KEY:
            raise ConfigError([f"mission.calibration_manoeuvre: {line} (the manoeuvre's reference, {stage.key})"
                               for line in exc.problems]) from None
        raise ConfigError([f"{line} (from mission.segments.{stage.segment} and the mission's settings)"
                           for line in exc.problems]) from None
