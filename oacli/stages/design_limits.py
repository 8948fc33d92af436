"""From the config to the design limits of ``plan``, ``smooth`` and ``excite`` (:mod:`oacli.reference_limits`).

Which prior mass and which σ_m (the "prior mass uncertainty" of ``m_upper = m_prior + n_σ σ_m``, Doerr 2021
Eq. 28):

* ``excite``: the design's model is ``excitation.prior`` (mass default ``robot.mass_kg``), so ``m_prior`` is that
  mass and σ_m the square root of its variance ``excitation.prior.variance[0]``;
* ``plan`` and ``smooth``: the model is ``robot.mass_kg``; σ_m is the prior standard deviation of the mass the
  estimator starts from, ``sqrt(estimation.prior.mass_variance_kg2)`` (its mean defaults to the robot's).

``<section>.margin.mass_std_kg`` overrides σ_m (0 for a model known exactly); ``controller.tube.disturbance.
mass_std_kg`` is not used: it is the spread of the estimate the tube's disturbance set W is sized for, not a
prior. Section caps above the robot's limits are refused (:class:`~oacli.errors.ConfigError`, exit 2) or, with
``margin.on_excess: clip``, clipped with a note that the stage writes to its log and summary.
"""

from __future__ import annotations

import math

import numpy as np

from oacli.config import OacliConfig
from oacli.config.limits import LimitsOverride, ReferenceMarginConfig
from oacli.config.models import RobotConfig
from oacli.errors import ConfigError, InputError
from oacli.reference_limits import (
    QUANTITIES,
    UNITS,
    DesignLimits,
    LimitSet,
    ReferenceLimitCheck,
    ReferenceMargin,
    check_reference_limits,
    design_limits,
    limits_above_robot,
)
from oacli.types import Trajectory

ROBOT_FIELDS = {"force_N": "force_limit_N", "torque_Nm": "torque_limit_Nm", "velocity_mps": "velocity_limit_mps",
                "angular_velocity_radps": "angular_velocity_limit_radps"}
"""The ``robot`` field of each limited quantity."""


def robot_limit_set(robot: RobotConfig) -> LimitSet:
    """The robot's actuator and flight-mode limits as a :class:`~oacli.reference_limits.LimitSet`."""
    return LimitSet(**{q: np.asarray(getattr(robot, ROBOT_FIELDS[q]), dtype=float) for q in QUANTITIES})


def resolve_design_limits(
    robot: RobotConfig,
    margin: ReferenceMarginConfig,
    caps: list[tuple[str, LimitsOverride]],
    *,
    mass_prior_kg: float,
    default_mass_std_kg: float,
    margin_path: str,
) -> DesignLimits:
    """Design limits from the robot, a margin section and section caps (later caps win per quantity).

    Parameters
    ----------
    robot : RobotConfig
    margin : ReferenceMarginConfig
    caps : list of (str, LimitsOverride)
        Config path of each cap section (``"excitation.limits"``) and its values, in override order.
    mass_prior_kg : float
        Mass of the designer's model [kg].
    default_mass_std_kg : float
        σ_m used when ``margin.mass_std_kg`` is not given [kg].
    margin_path : str
        Config path of the margin section (for messages).

    Raises
    ------
    ConfigError
        A cap above the robot's limit with ``on_excess: error``: one line per axis, naming the field, both values.
    """
    robot_limits = robot_limit_set(robot)
    effective: dict[str, tuple[str, np.ndarray]] = {}
    for path, section in caps:
        for quantity in QUANTITIES:
            value = getattr(section, quantity)
            if value is not None:
                effective[quantity] = (path, np.asarray(value, dtype=float))
    excess = limits_above_robot(robot_limits, {q: v for q, (_, v) in effective.items()})
    notes = []
    if excess:
        lines = []
        for e in excess:
            unit = UNITS[e.quantity]
            where = f"{effective[e.quantity][0]}.{e.quantity}.{e.axis}"
            robot_field = f"robot.{ROBOT_FIELDS[e.quantity]}.{e.axis}"
            if margin.on_excess == "error":
                lines.append(f"{where}: {e.requested:g}: above the robot's limit {robot_field} = {e.robot:g} {unit}; "
                             f"lower or omit it, or set {margin_path}.on_excess: clip")
            else:
                notes.append(f"{where} = {e.requested:g} {unit} is above the robot's limit {robot_field} = "
                             f"{e.robot:g} {unit}: clipped to {e.robot:g} {unit} ({margin_path}.on_excess: clip)")
        if lines:
            raise ConfigError(lines)
    caps_clipped = {q: np.minimum(v, robot_limits.get(q)) for q, (_, v) in effective.items()}
    std = default_mass_std_kg if margin.mass_std_kg is None else margin.mass_std_kg
    ref_margin = ReferenceMargin(
        mass_prior_kg=mass_prior_kg, mass_std_kg=std, mass_sigmas=margin.mass_sigmas,
        force_fraction=margin.reference_force_fraction, torque_fraction=margin.reference_torque_fraction,
        velocity_fraction=margin.reference_velocity_fraction,
        angular_velocity_fraction=margin.reference_angular_velocity_fraction,
    )
    return design_limits(robot_limits, ref_margin, caps_clipped, tuple(notes))


def excitation_design_limits(cfg: OacliConfig, *, rattle: bool = False) -> DesignLimits:
    """Design limits of ``oacli excite``: offline (``excitation.limits``) or RATTLE (``excitation.rattle.limits``
    over ``excitation.limits``), with ``excitation.margin`` (module docstring)."""
    exc = cfg.excitation
    caps = [("excitation.limits", exc.limits)]
    if rattle:
        caps.append(("excitation.rattle.limits", exc.rattle.limits))
    mass = exc.prior.mass_kg if exc.prior.mass_kg is not None else cfg.robot.mass_kg
    return resolve_design_limits(cfg.robot, exc.margin, caps, mass_prior_kg=mass,
                                 default_mass_std_kg=math.sqrt(exc.prior.variance[0]),
                                 margin_path="excitation.margin")


def planner_design_limits(cfg: OacliConfig) -> DesignLimits:
    """Design limits of ``oacli plan`` and ``oacli smooth``: ``planner.limits`` with ``planner.margin``
    (module docstring)."""
    p = cfg.planner
    return resolve_design_limits(cfg.robot, p.margin, [("planner.limits", p.limits)], mass_prior_kg=cfg.robot.mass_kg,
                                 default_mass_std_kg=math.sqrt(cfg.estimation.prior.mass_variance_kg2),
                                 margin_path="planner.margin")


def check_reference_for_plant(cfg: OacliConfig, reference: Trajectory, log: list[tuple[float, str, str]], *,
                              strict: bool = False) -> ReferenceLimitCheck:
    """Check a reference against the simulated plant ``truth`` (mass, inertia, disturbance) and ``robot``'s limits.

    A reference beyond a limit adds a warning to ``log`` (at the first time a limit is exceeded), or, with
    ``strict``, is refused.

    Raises
    ------
    InputError
        With ``strict``, when the plant cannot follow the reference within the limits (naming the quantity, the
        time and both values).
    """
    dist = cfg.truth.disturbance
    check = check_reference_limits(reference, cfg.truth_params(), robot_limit_set(cfg.robot),
                                   disturbance_bias=np.asarray(dist.bias),
                                   disturbance_bound=np.asarray(dist.random_bound))
    if not check.ok:
        if strict:
            raise InputError(f"{check.message()} (robot limits, truth plant); refused by --strict")
        first = min(t for q in check.exceeded if (t := check.checks[q].first_exceeded_t_s) is not None)
        log.append((float(first), "warning", check.message()))
    return check


__all__ = ["ROBOT_FIELDS", "check_reference_for_plant", "excitation_design_limits", "planner_design_limits",
           "resolve_design_limits", "robot_limit_set"]
