"""Limit overrides and reference margins shared by the ``planner`` and ``excitation`` sections.

A designed reference (plan, smoothed plan, excitation) must be one the robot can fly. Its design limits are the
robot's (``robot:``), scaled by the margins of :class:`ReferenceMarginConfig` (the force also by the mass margin
``m_prior / m_upper`` of [Doerr2021] Eq. 28) and capped further by a section's own ``limits``; see
:mod:`oacli.reference_limits`. A section limit above the robot's is refused, or, with ``on_excess: clip``, clipped
to the robot's with a warning. Imported by :mod:`oacli.config.models` through the section modules.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from oacli.config.fields import Fraction, NonNegativeReal, PositiveVector3, Section


class LimitsOverride(Section):
    """Per-axis limits that cap a design further (each omitted one keeps the robot's); never above the robot's."""

    force_N: PositiveVector3 | None = Field(default=None, description="Force bound per world axis [N].")
    torque_Nm: PositiveVector3 | None = Field(default=None, description="Torque bound per body axis [N·m].")
    velocity_mps: PositiveVector3 | None = Field(default=None, description="Velocity bound per world axis [m/s].")
    angular_velocity_radps: PositiveVector3 | None = Field(
        default=None, description="Angular velocity bound per body axis [rad/s]."
    )


class ReferenceMarginConfig(Section):
    """How much of the robot's limits a designed reference may use (:mod:`oacli.reference_limits`).

    Force: ``robot.force_limit_N · m_prior / m_upper · reference_force_fraction`` with
    ``m_upper = m_prior + mass_sigmas · σ_m`` ([Doerr2021] Eq. 28: the 2σ mass bound), so that a plant as heavy as
    ``m_upper`` still follows the reference's accelerations with ``1 − reference_force_fraction`` of the actuator
    left to the feedback. Torque, velocity and angular rate: the robot's limit times their fraction.
    """

    mass_sigmas: NonNegativeReal = Field(
        default=2.0,
        description="n_σ of m_upper = m_prior + n_σ·σ_m ([Doerr2021] Eq. 28: 2), >= 0; σ_m is the designer's "
        "model's (excitation: sqrt(excitation.prior.variance[0]); planner: sqrt(robot.variance[0])); 0: no mass "
        "derating.",
    )
    reference_force_fraction: Fraction = Field(
        default=0.8,
        description="Share of the mass-margined force limit the reference may use, in (0, 1]; the rest is kept "
        "for the feedback.",
    )
    reference_torque_fraction: Fraction = Field(
        default=0.8, description="Share of robot.torque_limit_Nm the reference may use, in (0, 1]."
    )
    reference_velocity_fraction: Fraction = Field(
        default=0.9,
        description="Share of robot.velocity_limit_mps the reference may use, in (0, 1] (room for tracking "
        "overshoot).",
    )
    reference_angular_velocity_fraction: Fraction = Field(
        default=0.9,
        description="Share of robot.angular_velocity_limit_radps the reference may use, in (0, 1] (room for "
        "tracking overshoot).",
    )
    on_excess: Literal["error", "clip"] = Field(
        default="error",
        description="A section limit above the robot's: 'error' refuses the config (exit 2), 'clip' lowers it to "
        "the robot's and says so (log and summary).",
    )


__all__ = ["LimitsOverride", "ReferenceMarginConfig"]
