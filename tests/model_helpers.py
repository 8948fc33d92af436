"""A robot model for tests that need only a mass and its σ (the tube, W, the design limits)."""

from __future__ import annotations

import numpy as np

from oacli.model.robot_model import RobotModel

ASTROBEE_INERTIA_KGM2 = (0.153427995, 0.14271405, 0.162302759)
"""astrobee iss.config: diag(Ixx, Iyy, Izz) [kg·m²]."""


def mass_model(mass_kg: float, mass_std_kg: float = 0.0, *, force_limit_N: float = 0.452,
               velocity_limit_mps: float = 0.2) -> RobotModel:
    """A :class:`RobotModel` of ``mass_kg`` with σ_m = ``mass_std_kg`` (covariance ``diag(σ_m², 0, 0, 0)``)."""
    cov = np.zeros((4, 4))
    cov[0, 0] = mass_std_kg**2
    return RobotModel(mass_kg=mass_kg, inertia_kgm2=np.array(ASTROBEE_INERTIA_KGM2), covariance=cov,
                      force_limit_N=np.full(3, force_limit_N), torque_limit_Nm=np.full(3, 0.0452),
                      velocity_limit_mps=np.full(3, velocity_limit_mps),
                      angular_velocity_limit_radps=np.full(3, 0.1745))
