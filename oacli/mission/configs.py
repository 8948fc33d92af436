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
from oacli.errors import ConfigError
from oacli.mission.layout import MISSION_STAGES, MissionStage
from oacli.model.robot_model import RobotModel
from oacli.stages.settings import robot_model


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
        The learned model (segment 3): mass, inertias and their covariance.
    """

    reference: Path | None = None
    plan: Path | None = None
    telemetry: Path | None = None
    initial_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimate: RobotModel | None = None


def stage_seed(seed: int, index: int) -> int:
    """The seed of the mission's ``index``-th stage: an independent stream per stage ([numpy] SeedSequence).

    Parameters
    ----------
    seed : int
        The mission's seed.
    index : int
        The stage's position in :data:`oacli.mission.layout.MISSION_STAGES`.

    Returns
    -------
    int
        A seed in [0, 2³¹).
    """
    state = np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(1, dtype=np.uint32)
    return int(state[0] % (2**31))


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
    variance = np.array([prior.mass_std_kg, *prior.inertia_std_kgm2]) ** 2
    return robot_model(cfg).with_estimate(
        np.array([prior.mass_kg, *prior.inertia_kgm2]), np.diag(variance))


def _model_sections(model: RobotModel, w_sigmas: float) -> dict[str, Any]:
    """The config entries that make ``model`` the controller's model, with its σ in the estimator prior and W."""
    theta = model.theta
    std = model.std
    return {
        "robot": {"mass_kg": float(theta[0]), "inertia_kgm2": [float(v) for v in theta[1:4]]},
        "controller": {"tube": {"disturbance": {"mass_std_kg": float(std[0]), "mass_sigmas": float(w_sigmas)}}},
    }


def _prior_sections(prior: RobotModel) -> dict[str, Any]:
    theta, var = prior.theta, np.diag(prior.covariance)
    section = {"mass_kg": float(theta[0]), "inertia_kgm2": [float(v) for v in theta[1:4]],
               "mass_variance_kg2": float(var[0]), "inertia_variance_kg2m4": [float(v) for v in var[1:4]]}
    return {"excitation": {"prior": dict(section)}, "estimation": {"prior": dict(section)}}


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
    unknown = sorted(k for k in mission.segments if "/" in k and k not in {s.key for s in MISSION_STAGES})
    if unknown:
        raise ConfigError(f"mission.segments.{unknown[0]}: unknown stage (allowed: "
                          + ", ".join(s.key for s in MISSION_STAGES) + ")")
    data = cfg.model_dump(mode="json")  # what dump_config writes, without the YAML text round trip
    data.pop("mission", None)
    data = deep_merge(data, mission.segments.get(stage.segment) or {})
    data = deep_merge(data, mission.segments.get(stage.key) or {})  # one stage's own (e.g. a baseline), after
    index = next(i for i, s in enumerate(MISSION_STAGES) if s.key == stage.key)
    prior = prior_model(cfg)
    grasped = {"mass_kg": mission.grasped.mass_kg, "inertia_kgm2": list(mission.grasped.inertia_kgm2)}
    sets: dict[str, Any] = {
        "name": f"{cfg.name}-{stage.segment}-{stage.name}"[:64],
        "seed": stage_seed(cfg.seed, index),
        "simulation": {"settle_time_s": mission.settle_s, "initial_offset_m": list(handoff.initial_offset_m)},
    }
    if stage.segment == "segment-1":  # the mission's own start offset (a campaign disperses it); later ones hand off
        sets["simulation"]["initial_offset_m"] = list(cfg.simulation.initial_offset_m)
    if stage.segment == "segment-1":
        sets["planner"] = {"segment": f"{a}-{b}"}
        sets["controller"] = {"type": "mpc"}
    else:
        sets["truth"] = grasped
        sets = deep_merge(sets, _prior_sections(prior))
    if stage.segment == "segment-2":
        sets = deep_merge(sets, _model_sections(prior, mission.w_sigmas))
        sets = deep_merge(sets, {"controller": {"type": "tube"}, "excitation": {"start": b, "goal": c}})
        if mission.excitation_method is not None:
            sets["excitation"]["method"] = mission.excitation_method
    if stage.segment == "segment-3":
        sets["planner"] = {"segment": f"{c}-{a}"}
        learned = handoff.estimate if handoff.estimate is not None else prior
        model = prior if stage.name.endswith("-prior") else learned
        sets = deep_merge(sets, _model_sections(model, mission.w_sigmas))
        sets["controller"]["type"] = "mpc" if stage.name == "baseline-mpc-prior" else "tube"
    if stage.command == "track" and handoff.reference is not None:
        sets["reference"] = {"source": "file", "file": str(handoff.reference)}
    # The stage's input file and method in its config, as its command records them: the folder's config.yaml alone
    # reruns it (``oacli smooth RUN/segment-1/smooth/config.yaml``, ``oacli estimate .../estimate/config.yaml``).
    if stage.command == "smooth" and handoff.plan is not None:
        sets["inputs"] = {"smooth_input": str(handoff.plan)}
    if stage.command == "estimate":
        if handoff.telemetry is not None:
            sets["inputs"] = {"estimate_telemetry": str(handoff.telemetry)}
        method = "sequential" if stage.name == "estimate-sequential" else "batch"
        sets = deep_merge(sets, {"estimation": {"method": method}})  # merged: the section holds the prior
    data = deep_merge(data, sets)
    try:
        return config_from_dict(data, source=f"{source} ({stage.key})")
    except ConfigError as exc:
        raise ConfigError([f"{line} (from mission.segments.{stage.segment} and the mission's settings)"
                           for line in exc.problems]) from None
