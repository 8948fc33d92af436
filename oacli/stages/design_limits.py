"""The design limits of ``plan``, ``smooth`` and ``excite``: the robot's limits, derated by the model's mass
uncertainty and each section's shares and caps (:mod:`oacli.reference_limits`).

Design limits
-------------
Which model (the ``m_prior`` and σ_m of ``m_upper = m_prior + n_σ σ_m``, [Doerr2021] Eq. 28,
:mod:`oacli.reference_limits`): a :class:`~oacli.model.robot_model.RobotModel`, σ_m from its covariance:

* ``excite``: the design's model, ``excitation.prior`` (mass default ``robot.mass_kg``, σ_m =
  ``sqrt(excitation.prior.variance[0])``);
* ``plan`` and ``smooth``: the robot model (``robot:``, σ_m = ``sqrt(robot.variance[0])``, 0 unless given; the
  mission writes each segment's model there: the prior's, then the estimate's), the same model the tube's W uses.

Each section chooses only its n_σ, ``<section>.margin.mass_sigmas`` (0: no mass derating). Section caps above
the robot's limits are refused (:class:`~oacli.errors.ConfigError`, exit 2) or, with ``margin.on_excess: clip``,
clipped with a note that the stage writes to its log and summary.
"""

from __future__ import annotations

import numpy as np

from oacli.config import OacliConfig
from oacli.config.limits import LimitsOverride, ReferenceMarginConfig
from oacli.errors import ConfigError
from oacli.model.limits import MotionLimits
from oacli.model.robot_model import RobotModel
from oacli.reference_limits import (
    QUANTITIES,
    UNITS,
    DesignLimits,
    ReferenceMargin,
    design_limits,
    limits_above_robot,
)
from oacli.stages.settings import excitation_prior_model, robot_model

ROBOT_FIELDS = {"force_N": "force_limit_N", "torque_Nm": "torque_limit_Nm", "velocity_mps": "velocity_limit_mps",
                "angular_velocity_radps": "angular_velocity_limit_radps"}
"""The ``robot`` field of each limited quantity."""


def resolve_design_limits(
    model: RobotModel,
    margin: ReferenceMarginConfig,
    caps: list[tuple[str, LimitsOverride]],
    *,
    margin_path: str,
) -> DesignLimits:
    """Design limits from the designer's model, a margin section and section caps (later caps win per quantity).

    Parameters
    ----------
    model : RobotModel
        The designer's model: the robot's limits, ``m_prior`` and σ_m (from its covariance).
    margin : ReferenceMarginConfig
    caps : list of (str, LimitsOverride)
        Config path of each cap section (``"excitation.limits"``) and its values, in override order.
    margin_path : str
        Config path of the margin section (for messages).

    Returns
    -------
    DesignLimits
        The limits a designer must respect, the robot's, and a note per clipped cap.

    Raises
    ------
    ConfigError
        A cap above the robot's limit with ``on_excess: error``: one line per axis, naming the field, both values.
    """
    robot_limits = model.limits
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
    ref_margin = ReferenceMargin(
        model=model, mass_sigmas=margin.mass_sigmas,
        force_fraction=margin.reference_force_fraction, torque_fraction=margin.reference_torque_fraction,
        velocity_fraction=margin.reference_velocity_fraction,
        angular_velocity_fraction=margin.reference_angular_velocity_fraction,
    )
    return design_limits(robot_limits, ref_margin, caps_clipped, tuple(notes))


def excitation_design_limits(cfg: OacliConfig, *, rattle: bool = False) -> DesignLimits:
    """Design limits of ``oacli excite`` (module docstring).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    rattle : bool
        RATTLE (``excitation.rattle.limits`` over ``excitation.limits``) instead of the offline design
        (``excitation.limits``); both with ``excitation.margin``.

    Returns
    -------
    DesignLimits
    """
    exc = cfg.excitation
    caps = [("excitation.limits", exc.limits)]
    if rattle:
        caps.append(("excitation.rattle.limits", exc.rattle.limits))
    return resolve_design_limits(excitation_prior_model(cfg), exc.margin, caps, margin_path="excitation.margin")


def planner_design_limits(cfg: OacliConfig) -> DesignLimits:
    """Design limits of ``oacli plan`` and ``oacli smooth``: ``planner.limits`` with ``planner.margin``.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    DesignLimits
    """
    p = cfg.planner
    return resolve_design_limits(robot_model(cfg), p.margin, [("planner.limits", p.limits)],
                                 margin_path="planner.margin")


def design_limit_log(limits: DesignLimits) -> list[tuple[float, str, str]]:
    """The log lines a stage writes about its design limits.

    Parameters
    ----------
    limits : DesignLimits

    Returns
    -------
    list of (float, str, str)
        ``(0, "info", the limits)`` and a warning per clipped section cap.
    """
    return [(0.0, "info", limits.describe()), *((0.0, "warning", note) for note in limits.notes)]


def to_motion_limits(limits: DesignLimits) -> MotionLimits:
    """The design limits as the excitation core's limits.

    Parameters
    ----------
    limits : DesignLimits

    Returns
    -------
    MotionLimits
    """
    lim = limits.limits
    return MotionLimits(lim.force_N, lim.torque_Nm, lim.velocity_mps, lim.angular_velocity_radps)


def motion_limits(cfg: OacliConfig, *, rattle: bool = False) -> MotionLimits:
    """The limits the offline design (or, with ``rattle``, the RATTLE planner) must respect.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    rattle : bool
        The RATTLE planner's (see :func:`excitation_design_limits`).

    Returns
    -------
    MotionLimits
    """
    return to_motion_limits(excitation_design_limits(cfg, rattle=rattle))


