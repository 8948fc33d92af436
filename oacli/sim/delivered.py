"""What the actuators delivered during a simulated run, and the true state at any time from it.

The simulator ([`oacli.sim.simulator`]) records the applied input per control step, the disturbance and the true
state on the plant grid. The flight-like sensors need the wrench actually acting on the robot (the force scaled per
body axis and the centre-of-mass torque of :mod:`oacli.sim.actuators`, plus the disturbance; [Doerr2021]
Eqs. 33-35) and the true state at their own stamps,
which need not lie on the plant grid: :meth:`DeliveredInput.states_at` integrates from the last plant sample
through the control switches, as the simulator did.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model.rigid_body import propagate, theta_of
from oacli.sim.actuators import delivered_wrench
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
        Applied force (world frame, before the body-axis scale) [N] and delivered torque (body frame, scaled, with
        the disturbance, before the centre-of-mass torque) [N·m].
    com_offset_m : ndarray, shape (3,) or None
        Centre-of-mass offset of the plant, body frame [m].
    force_scale : ndarray, shape (3,) or None
        Force scale per body axis (None: ones).
    force_disturbance : ndarray, shape (K, 3) or None
        World-frame disturbance force per control step [N] (None: zero).
    """

    t_ctrl: np.ndarray
    wrench: np.ndarray
    com_offset_m: np.ndarray | None = None
    force_scale: np.ndarray | None = None
    force_disturbance: np.ndarray | None = None

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
        if offset is None and np.all(scale[0:3] == 1.0):
            return cls(np.asarray(tel.t_ctrl, float), scale * tel.u_applied + dist, None)
        wrench = np.concatenate([tel.u_applied[:, 0:3], scale[3:6] * tel.u_applied[:, 3:6] + dist[:, 3:6]], axis=1)
        kf = None if np.all(scale[0:3] == 1.0) else scale[0:3].copy()
        return cls(np.asarray(tel.t_ctrl, float), wrench, offset, kf, np.array(dist[:, 0:3], dtype=float))

    def _acting(self, j: int, x: np.ndarray) -> np.ndarray:
        """The wrench acting in control step ``j`` at state ``x`` (:func:`oacli.sim.actuators.delivered_wrench`)."""
        u = delivered_wrench(self.wrench[j], x[6:10], self.force_scale, self.com_offset_m)
        if self.force_disturbance is not None:
            u[0:3] += self.force_disturbance[j]
        return u

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

    def force_world(self, t: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """Delivered force at each time ``t`` (world frame) [N], shape (N, 3).

        Parameters
        ----------
        t : ndarray, shape (N,)
        x : ndarray, shape (N, 13), optional
            True states at ``t``: needed when the force is scaled per body axis (its world direction then depends
            on the attitude).

        Returns
        -------
        ndarray, shape (N, 3)
        """
        idx = self.step_index(t)
        if self.force_scale is None and self.force_disturbance is None:
            return self.wrench[idx, 0:3]
        if self.force_scale is not None and x is None:
            raise ValueError("the force is scaled per body axis: give the states at t")
        out = np.empty((len(idx), 3))
        for n, j in enumerate(idx):
            out[n] = self._acting(int(j), np.asarray(x[n]) if x is not None else np.r_[np.zeros(9), 1.0, 0, 0, 0])[0:3]
        return out

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
                u = self.wrench[j] if self.force_disturbance is None else self._acting(j, x)
                x = propagate(x, u, theta, t_next - tc)
                tc = t_next
            out[n] = x
        return out
