"""Per-axis actuator and flight-mode limits of the free flyer: the one limits type of the core.

Force [N] per world axis, torque [N·m] per body axis, velocity [m/s] per world axis and angular rate [rad/s] per
body axis, each ``|·_i| <= limit_i`` ([Doerr2021] Eq. 26's input and state constraints; [ReSWARM2023] Table 2).
The tracking controllers, the tube design, the excitation design and the RATTLE planner all take this type; the
robot model (:class:`oacli.model.robot_model.RobotModel`) hands it out as ``limits``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LIMIT_FIELDS = ("force_N", "torque_Nm", "velocity_mps", "angular_velocity_radps")
"""The limited quantities, in the order of the constructor."""


@dataclass(frozen=True)
class MotionLimits:
    """Per-axis limits: force [N] (world frame), torque [N·m] (body frame), velocity [m/s], angular rate [rad/s].

    Each is stored as a read-only float array of shape (3,) with finite entries > 0 (a ``ValueError`` naming the
    field otherwise).

    Attributes
    ----------
    force_N, torque_Nm, velocity_mps, angular_velocity_radps : ndarray, shape (3,)
    """

    force_N: np.ndarray
    torque_Nm: np.ndarray
    velocity_mps: np.ndarray
    angular_velocity_radps: np.ndarray

    def __post_init__(self) -> None:
        for name in LIMIT_FIELDS:
            value = np.array(getattr(self, name), dtype=float)
            if value.size != 3:
                raise ValueError(f"{name} must be three finite numbers > 0, got shape {value.shape}")
            value = value.reshape(3)
            if np.any(~(value > 0)) or not np.all(np.isfinite(value)):
                raise ValueError(f"{name} must be three finite numbers > 0, got {value}")
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def get(self, quantity: str) -> np.ndarray:
        """The bound of one quantity (a name of :data:`LIMIT_FIELDS`).

        Parameters
        ----------
        quantity : str
            ``"force_N"``, ``"torque_Nm"``, ``"velocity_mps"`` or ``"angular_velocity_radps"``.

        Returns
        -------
        ndarray, shape (3,)
        """
        if quantity not in LIMIT_FIELDS:
            raise KeyError(quantity)
        value: np.ndarray = getattr(self, quantity)
        return value

    def as_dict(self) -> dict[str, list[float]]:
        """``{quantity: [x, y, z]}`` as plain floats.

        Returns
        -------
        dict of str to list of float
        """
        return {q: [float(v) for v in self.get(q)] for q in LIMIT_FIELDS}

    @property
    def input(self) -> np.ndarray:
        """Input bounds ``[f (3) N, τ (3) N·m]``, shape (6,)."""
        return np.concatenate([self.force_N, self.torque_Nm])

    @property
    def rate(self) -> np.ndarray:
        """Rate bounds ``[v (3) m/s, ω (3) rad/s]``, shape (6,)."""
        return np.concatenate([self.velocity_mps, self.angular_velocity_radps])

    @property
    def error_state(self) -> np.ndarray:
        """Limits on the 12-dimensional error state ``[r, v, φ, ω]`` (inf where none), shape (12,)."""
        inf = np.full(3, np.inf)
        return np.concatenate([inf, self.velocity_mps, inf, self.angular_velocity_radps])


__all__ = ["LIMIT_FIELDS", "MotionLimits"]
