"""Placeholder RobotModel (the robotmodel branch replaces this file)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class RobotModel:
    """Mass, inertias and their covariance ([Doerr2021] Eq. 28), with the actuator limits and geometry."""

    mass_kg: float
    inertia_kgm2: np.ndarray
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((4, 4)))
    force_limit_N: np.ndarray = field(default_factory=lambda: np.ones(3))
    torque_limit_Nm: np.ndarray = field(default_factory=lambda: np.ones(3))
    velocity_limit_mps: np.ndarray = field(default_factory=lambda: np.ones(3))
    angular_velocity_limit_radps: np.ndarray = field(default_factory=lambda: np.ones(3))
    radius_m: float = 0.0

    @property
    def theta(self) -> np.ndarray:
        """θ = [m, Ixx, Iyy, Izz]."""
        return np.array([self.mass_kg, *np.asarray(self.inertia_kgm2)])

    @property
    def std(self) -> np.ndarray:
        """1σ of θ."""
        return np.sqrt(np.diag(self.covariance))

    def with_estimate(self, theta: np.ndarray, covariance: np.ndarray) -> RobotModel:
        """This model with θ and its covariance replaced."""
        theta = np.asarray(theta, dtype=float)
        return replace(self, mass_kg=float(theta[0]), inertia_kgm2=theta[1:4].copy(),
                       covariance=np.asarray(covariance, dtype=float).copy())
