"""Trajectory-tracking MPC for the full 6-DoF free-flyer (translation *and* attitude).

The papers assumed perfect attitude tracking (Doerr et al. 2021, Results); this controller tracks attitude
too, within the torque limits. Each step it expresses the measured state and the reference over the horizon
in a local error chart and solves the standard MPC of Doerr Eq. 26 on the exact hover discretisation
(:func:`oacli.model.double_integrator.hover_error_model`):

* position relative to the current reference position (a constant shift: translation is exactly linear),
  world-frame velocity (force is applied in the world frame);
* attitude as the body-frame rotation vector relative to the current reference attitude ``q_a``
  (``q = q_a ⊗ exp(φ)``), body angular rate.

Reference inputs over the horizon are the model-consistent feed-forward (:func:`feedforward_inputs`).
When a solve fails the controller falls back to the shifted previous plan, and once that is used up to the
LQR law of the same weights, clipped to the limits; each fallback is recorded in the step's SolveInfo.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from oacli.control.lqr import dlqr
from oacli.control.mpc import LinearMPC
from oacli.model import quaternion as quat
from oacli.model.double_integrator import hover_error_model
from oacli.sim.simulator import ControlStep
from oacli.trajectory import feedforward_inputs, sample_states
from oacli.types import InertialParams, SolveInfo, Trajectory


@dataclass(frozen=True)
class TrackingLimits:
    """Per-axis limits [N, N·m, m/s, rad/s], each shape (3,)."""

    force_N: np.ndarray
    torque_Nm: np.ndarray
    velocity_mps: np.ndarray
    angular_velocity_radps: np.ndarray

    @property
    def input(self) -> np.ndarray:
        """Input limits [f, τ] (6,)."""
        return np.concatenate([self.force_N, self.torque_Nm])

    @property
    def error_state(self) -> np.ndarray:
        """Limits on the 12-dimensional error state (inf where none)."""
        inf = np.full(3, np.inf)
        return np.concatenate([inf, self.velocity_mps, inf, self.angular_velocity_radps])


@dataclass(frozen=True)
class TrackingWeights:
    """Diagonal MPC weights per axis: state [r, v, φ, ω] and input [f, τ], each shape (3,)."""

    position: np.ndarray
    velocity: np.ndarray
    attitude: np.ndarray
    angular_velocity: np.ndarray
    force: np.ndarray
    torque: np.ndarray

    @property
    def q_diag(self) -> np.ndarray:
        """Stage state weight diagonal (12,)."""
        return np.concatenate([self.position, self.velocity, self.attitude, self.angular_velocity])

    @property
    def r_diag(self) -> np.ndarray:
        """Input weight diagonal (6,)."""
        return np.concatenate([self.force, self.torque])


def to_error_state(x: np.ndarray, origin_m: np.ndarray, q_anchor: np.ndarray) -> np.ndarray:
    """Map full states to the error chart ``[r − origin, v, φ, ω]``.

    Parameters
    ----------
    x : ndarray, shape (..., 13)
        Full states.
    origin_m : ndarray, shape (3,)
        Position origin [m].
    q_anchor : ndarray, shape (4,)
        Attitude the error φ is measured from.

    Returns
    -------
    ndarray, shape (..., 12)
    """
    x = np.asarray(x, dtype=float)
    phi = quat.error_vector(q_anchor, x[..., 6:10])
    return np.concatenate([x[..., 0:3] - origin_m, x[..., 3:6], phi, x[..., 10:13]], axis=-1)


class TrackingMPC:
    """Standard MPC tracking a reference trajectory (Doerr Eq. 26), attitude included.

    Parameters
    ----------
    reference : Trajectory
        The trajectory to follow.
    params : InertialParams
        The controller's model.
    dt_s : float
        Prediction step [s] (the control period by default).
    horizon : int
        Number of prediction steps N.
    weights : TrackingWeights
    limits : TrackingLimits
    """

    def __init__(
        self,
        reference: Trajectory,
        params: InertialParams,
        *,
        dt_s: float,
        horizon: int,
        weights: TrackingWeights,
        limits: TrackingLimits,
    ) -> None:
        self.reference = reference
        self.params = params
        self.dt_s = float(dt_s)
        self.horizon = int(horizon)
        self.limits = limits
        a, b = hover_error_model(params, self.dt_s)
        self.mpc = LinearMPC(
            a, b, weights.q_diag, weights.r_diag, self.horizon, limits.input, x_max=limits.error_state
        )
        self.lqr_gain, _ = dlqr(a, b, np.diag(weights.q_diag), np.diag(weights.r_diag))
        self._plan: np.ndarray | None = None
        self._plan_age = 0
        self._offsets = self.dt_s * np.arange(self.horizon + 1)

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """Solve once at time ``t`` [s] from the measured state; see :class:`oacli.sim.simulator.Controller`.

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state ``[r, v, q, ω]``.

        Returns
        -------
        ControlStep
            The input to hold until the next step, the solve record and the reference state at ``t``.
        """
        start = time.perf_counter()
        x_ref_full = sample_states(self.reference, t + self._offsets)
        u_ref = feedforward_inputs(x_ref_full, self.dt_s, self.params)
        origin = x_ref_full[0, 0:3]
        anchor = x_ref_full[0, 6:10]
        e0 = to_error_state(x_measured, origin, anchor)
        e_ref = to_error_state(x_ref_full, origin, anchor)
        sol = self.mpc.solve(e0, e_ref, u_ref)
        if sol.info.success:
            self._plan, self._plan_age = sol.u, 0
            u = sol.u[0]
            status, success = sol.info.status, True
        else:
            self._plan_age += 1
            if self._plan is not None and self._plan_age < self.horizon:
                u = self._plan[self._plan_age]
                status = f"fallback_shifted_plan ({sol.info.status})"
            else:
                u = u_ref[0] + self.lqr_gain @ (e0 - e_ref[0])
                status = f"fallback_lqr ({sol.info.status})"
            u = np.clip(u, -self.limits.input, self.limits.input)
            success = False
        info = SolveInfo(
            status=status,
            success=success,
            objective=sol.info.objective,
            iterations=sol.info.iterations,
            solve_time_s=sol.info.solve_time_s,
            step_time_s=time.perf_counter() - start,
        )
        return ControlStep(u=np.asarray(u, dtype=float), info=info, x_reference=x_ref_full[0])
