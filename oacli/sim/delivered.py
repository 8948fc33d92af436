"""What the actuators delivered during a simulated run, and the true state at any time from it.

The simulator ([`oacli.sim.simulator`]) records the applied input per control step, the disturbance and the true
state on the plant grid. The flight-like sensors need the wrench actually acting on the robot (``scale · u + w``,
[Doerr2021] Eqs. 33-35 with the unmodelled actuator scale and disturbance) and the true state at their own stamps,
which need not lie on the plant grid: :meth:`DeliveredInput.states_at` integrates from the last plant sample
through the control switches, as the simulator did.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model.rigid_body import propagate, theta_of
from oacli.sim.simulator import _with_offset_torque
from oacli.types import InertialParams, Telemetry

__all__ = ["DeliveredInput"]

_TIME_TOL = 1e-9


@dataclass(frozen=True)
class DeliveredInput:
    """The wrench acting on the plant per control step (zero-order hold).

    Attributes
    ----------
    t_ctrl : ndarray, shape (K,)
        Control instants [s].
    wrench : ndarray, shape (K, 6)
        Delivered force (world frame) [N] and torque (body frame, before the centre-of-mass offset) [N·m].
    com_offset_m : ndarray, shape (3,) or None
        Centre-of-mass offset of the plant, body frame [m].
    """

    t_ctrl: np.ndarray
    wrench: np.ndarray
    com_offset_m: np.ndarray | None = None

    @classmethod
    def from_telemetry(cls, tel: Telemetry, actuator_scale: np.ndarray | None = None,
                       com_offset_m: np.ndarray | None = None) -> DeliveredInput:
        """``scale · u_applied + disturbance`` of a run.

        Parameters
        ----------
        tel : Telemetry
        actuator_scale : ndarray, shape (6,), optional
            Delivered ÷ applied per axis (default ones).
        com_offset_m : ndarray, shape (3,), optional

        Returns
        -------
        DeliveredInput
        """
        scale = np.ones(6) if actuator_scale is None else np.asarray(actuator_scale, dtype=float).reshape(6)
        dist = np.zeros_like(tel.u_applied) if tel.disturbance is None else tel.disturbance
        offset = None if com_offset_m is None or not np.any(com_offset_m) else np.asarray(com_offset_m, float)
        return cls(np.asarray(tel.t_ctrl, float), scale * tel.u_applied + dist, offset)

    def step_index(self, t: np.ndarray) -> np.ndarray:
        """Index of the control step active at each time ``t`` (the last instant ``<= t``).

        Parameters
        ----------
        t : ndarray, shape (N,)

        Returns
        -------
        ndarray of int, shape (N,)
        """
        idx = np.searchsorted(self.t_ctrl, np.asarray(t, float) + _TIME_TOL, side="right") - 1
        return np.clip(idx, 0, len(self.t_ctrl) - 1)

    def force_world(self, t: np.ndarray) -> np.ndarray:
        """Delivered force at each time ``t`` (world frame) [N], shape (N, 3).

        Parameters
        ----------
        t : ndarray, shape (N,)

        Returns
        -------
        ndarray, shape (N, 3)
        """
        return self.wrench[self.step_index(t), 0:3]

    def states_at(self, t: np.ndarray, t_true: np.ndarray, x_true: np.ndarray, truth: InertialParams) -> np.ndarray:
        """True states at times ``t``: from the last plant sample, integrated through the control switches.

        Parameters
        ----------
        t : ndarray, shape (N,)
            Query times in ``[t_true[0], t_true[-1]]`` [s].
        t_true, x_true : ndarray, shape (M,), (M, 13)
            The run's true states on the plant grid.
        truth : InertialParams
            The plant's inertial parameters.

        Returns
        -------
        ndarray, shape (N, 13)
        """
        theta = theta_of(truth)
        out = np.empty((len(t), 13))
        base = np.clip(np.searchsorted(t_true, np.asarray(t, float) + _TIME_TOL, side="right") - 1, 0, None)
        for n, (s, i) in enumerate(zip(np.asarray(t, float), base, strict=True)):
            x, tc = np.array(x_true[i], float), float(t_true[i])
            while s - tc > _TIME_TOL:
                j = int(self.step_index(np.array([tc]))[0])
                t_switch = self.t_ctrl[j + 1] if j + 1 < len(self.t_ctrl) else np.inf
                t_next = min(s, t_switch) if t_switch > tc + _TIME_TOL else s
                u = self.wrench[j]
                if self.com_offset_m is not None:
                    u = _with_offset_torque(u, x, self.com_offset_m)
                x = propagate(x, u, theta, t_next - tc)
                tc = t_next
            out[n] = x
        return out
