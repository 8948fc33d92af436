"""The track stage's record of the full rigid body in the controllers: the centre-of-mass compensation and W's
attitude part ([Doerr2021] Eq. 28 generalised; :mod:`oacli.control.rigid_terms`, :mod:`oacli.control.disturbance`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.control.disturbance import attitude_disturbance
from oacli.control.rigid_terms import RigidCompensator
from oacli.control.tracking import TrackingMPC
from oacli.control.tube_design import TubeDesign
from oacli.control.tube_monitor import TubeMonitor
from oacli.model.limits import MotionLimits
from oacli.model.robot_model import RobotModel

__all__ = ["com_clip_finding", "controller_force_limit_N", "rigid_body_entries"]


def controller_force_limit_N(limits: MotionLimits, design: TubeDesign | None) -> np.ndarray:
    """The largest world force the controller commands per axis [N]: the tube's U, else the MPC's limit."""
    if design is None:
        return np.asarray(limits.force_N, dtype=float)
    return np.array([ax.force_limit_N for ax in design.axes])


def _compensators(controller: TrackingMPC | TubeMonitor) -> list[RigidCompensator]:
    if isinstance(controller, TubeMonitor):
        return [c.rigid for c in controller.controllers if c.rigid is not None]
    return [] if controller.rigid is None else [controller.rigid]


def rigid_body_entries(cfg: OacliConfig, model: RobotModel, controller: TrackingMPC | TubeMonitor,
                       limits: MotionLimits, design: TubeDesign | None) -> dict[str, Any]:
    """The summary's ``attitude_w`` (W's attitude part of ``model`` at ``controller.tube.disturbance.mass_sigmas``
    σ, None when an inertia's interval reaches 0) and ``com_compensation`` (the compensated offset, the torque the
    MPC may plan and the steps whose commanded torque had to be clipped; None without a compensator).

    Parameters
    ----------
    cfg : OacliConfig
    model : RobotModel
        The controller's model.
    controller : TrackingMPC or TubeMonitor
        The controller after the run.
    limits : MotionLimits
        The controller's limits.
    design : TubeDesign or None
        The tube's design (None: the standard MPC).

    Returns
    -------
    dict
    """
    force = controller_force_limit_N(limits, design)
    try:
        w = attitude_disturbance(model, force, limits.torque_Nm, limits.angular_velocity_radps,
                                 cfg.controller.period_s, cfg.controller.tube.disturbance.mass_sigmas).summary()
    except ValueError:
        w = None
    comps = _compensators(controller)
    comp = None if not comps else {
        "com_offset_m": [float(v) for v in comps[0].com_offset_m],
        "products_kgm2": [float(v) for v in model.inertia_products_kgm2],
        "planned_torque_limit_Nm": [float(v) for v in comps[0].planned_torque_limit_Nm],
        "clipped_steps": int(sum(c.clipped_steps for c in comps)),
    }
    return {"attitude_w": w, "com_compensation": comp}


def com_clip_finding(summary: dict[str, Any]) -> str | None:
    """Why a track whose centre-of-mass compensation was clipped to the torque limit is ``degraded`` (None: it
    never was): on those steps the plant received less than the moment the compensation cancels
    (:mod:`oacli.control.rigid_terms`).

    Parameters
    ----------
    summary : dict
        The track's summary (its ``com_compensation`` entry).

    Returns
    -------
    str or None
    """
    clipped = int((summary.get("com_compensation") or {}).get("clipped_steps", 0))
    if not clipped:
        return None
    return (f"the centre-of-mass compensation was clipped to the torque limit on {clipped} steps (its worst case "
            "exceeds half the limit: docs/control.md), so the CoM moment was not fully cancelled there")
