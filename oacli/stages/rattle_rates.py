"""RATTLE's angular rates within what the tracking controller keeps: the planner's and the rate governor's limit.

The tracking controllers constrain the body rate to ``(1 − controller.rate_margin)`` × the robot's limit
(:func:`oacli.stages.settings.controller_limits`): the margin is room for what the controller cannot see, an
inertia unlike its model's and the noise on the measured rate (σ 0.016 rad/s in the flight's sensors). RATTLE's
design limit was the robot's × ``excitation.margin.reference_angular_velocity_fraction`` (0.9) and its loop's rate
governor (:func:`oacli.excitation.rattle_loop.rate_governed_torque`) held the *measured* rate at the robot's limit:
the flown motion then reached 0.157-0.170 rad/s on the true state (limit 0.1745), and the track of it, whose
controller rides its 0.14 rad/s constraint on noisy rates, broke the limit in 4 of 50 study runs (README, RATTLE
table). RATTLE now plans within the controller's constraint (:func:`rattle_planner_limits`) and its governor holds
the measured rate there too (:func:`rattle_governor_limit`), so the margin the controller needs is left free in
the excitation itself.
"""

from __future__ import annotations

import numpy as np

from oacli.config import OacliConfig
from oacli.model.limits import MotionLimits
from oacli.stages.rattle_goal import loop_jitter_std
from oacli.stages.settings import controller_limits, excitation_prior_model, robot_model


def rattle_governor_limit(cfg: OacliConfig) -> np.ndarray:
    """The rate governor's limit [rad/s] (3,): the robot's × ``(1 − controller.rate_margin)``."""
    return np.asarray(controller_limits(cfg, robot_model(cfg)).angular_velocity_radps, dtype=float)


JITTER_SIGMAS = 2.0
"""The planner's rate cap leaves this many σ of the RATTLE loop's own rate jitter below the governor's limit."""


def rattle_planner_limits(cfg: OacliConfig, design: MotionLimits) -> MotionLimits:
    """The design limits with the angular rate capped at the governor's (:func:`rattle_governor_limit`) less
    :data:`JITTER_SIGMAS` σ of the loop's rate jitter under the sensor noise (:func:`oacli.stages.rattle_goal.
    loop_jitter_std` with the prior's θ): the flown motion, which the track stage follows, then stays within the
    tracking controller's constraint.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration (``controller.rate_margin``, ``robot``).
    design : MotionLimits
        RATTLE's design limits (:func:`oacli.stages.design_limits.excitation_design_limits`).

    Returns
    -------
    MotionLimits
    """
    jitter = loop_jitter_std(cfg, np.asarray(excitation_prior_model(cfg).theta, dtype=float))["angular_velocity_radps"]
    rate = np.minimum(design.angular_velocity_radps, rattle_governor_limit(cfg) - JITTER_SIGMAS * jitter)
    return MotionLimits(design.force_N, design.torque_Nm, design.velocity_mps, rate)
