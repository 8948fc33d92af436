"""RATTLE's terminal phase: the last replan drops the information term and plans to the goal at rest.

RATTLE trades information against goal-directed motion online, and the information weight shuts off "as the robot
reaches the goal position" ([ReSWARM2023] §4.4, text around Fig. 4: the decay "and eventual shut-off in the
information gain content as the robot reaches the goal"). The covariance-driven decay
(:func:`oacli.excitation.rattle.information_weights`) alone need not reach zero within the run, and a horizon that
ends with a soft terminal cost (weight 100 on ``x_N ⊖ x_goal``) does not end at rest: the flight-fault campaign's
segment 2 ended 1-4 cm from C, still moving, in every run. The terminal phase closes the run:

* the **terminal replan** is scheduled at ``t_term = T − hold − N Δt`` (``T`` the run's end, ``hold`` the time held
  at the goal, ``N Δt`` the horizon), or at the first replan when the run is shorter than that; regular replans
  before it stay on their period, none follows it;
* it rewards no information (γ = 0: the shut-off) and constrains every step from the arrival
  ``T − hold`` on to the goal at rest (position, velocity, attitude error and rate bounds of zero, with the
  planner's exact penalty, :func:`terminal_bounds`, :func:`terminal_violation`); after the plan's end the loop
  holds its last sample (:func:`oacli.trajectory.sample_states`).

At rest in closed loop is not at rest in the plan: the loop feeds noisy measurements back, so the true state
jitters about the goal. :func:`closed_loop_jitter_std` gives that jitter's standard deviation per quantity from the
LQR closed loop of the hover model and the sensor noise (the discrete Lyapunov equation); the excite stage's goal
check (:mod:`oacli.stages.rattle_goal`) allows a chosen number of those σ beyond the design tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from oacli.control.lqr import dlqr
from oacli.excitation.problem import LENGTH_UNIT_M
from oacli.model.double_integrator import hover_error_model
from oacli.model.limits import MotionLimits
from oacli.types import InertialParams

FREE_BOUND = 100.0
"""Terminal bound of a step before the arrival [m, m/s, rad, rad/s]: far beyond any state the planner reaches."""


def terminal_bounds(horizon: int, arrival_step: int | None) -> np.ndarray:
    """Per-step bounds on ``[|r − r_goal|, |v|, |e|, |ω|]`` (each per axis) of a plan, shape (N+1, 4).

    Parameters
    ----------
    horizon : int
        N steps.
    arrival_step : int or None
        The first step at the goal at rest (0 from step ``arrival_step`` on); None: no terminal phase.

    Returns
    -------
    ndarray, shape (N+1, 4)
        [m, m/s, rad, rad/s].
    """
    bounds = np.full((horizon + 1, 4), FREE_BOUND)
    if arrival_step is not None:
        bounds[max(int(arrival_step), 0):] = 0.0
    return bounds


def terminal_violation(bounds: np.ndarray, dr: np.ndarray, v: np.ndarray, e: np.ndarray, omega: np.ndarray,
                       limits: MotionLimits) -> float:
    """The terminal bounds' normalised violation of a rollout, as the planner's QP slacks measure it.

    Per step the largest excess over the bounds, in units of :data:`~oacli.excitation.problem.LENGTH_UNIT_M`
    (position), the velocity limit, 1 rad (attitude) and the rate limit; summed over the steps.

    Parameters
    ----------
    bounds : ndarray, shape (N+1, 4)
        :func:`terminal_bounds`.
    dr, v, e, omega : ndarray, shape (N+1, 3)
        Position relative to the goal [m], velocity [m/s], attitude error [rad] and body rate [rad/s].
    limits : MotionLimits

    Returns
    -------
    float
    """
    excess = np.stack([
        (np.abs(dr) - bounds[:, 0:1]) / LENGTH_UNIT_M,
        (np.abs(v) - bounds[:, 1:2]) / limits.velocity_mps,
        np.abs(e) - bounds[:, 2:3],
        (np.abs(omega) - bounds[:, 3:4]) / limits.angular_velocity_radps,
    ])
    return float(np.sum(np.maximum(np.max(excess, axis=(0, 2)), 0.0)))


@dataclass(frozen=True)
class TerminalPhase:
    """When the terminal replan happens and where it arrives (module docstring).

    Attributes
    ----------
    end_s : float
        Mission time at which the run ends [s].
    hold_s : float
        Time held at the goal before the end [s], ≥ 0.
    horizon_s : float
        The planner's horizon N Δt [s].
    """

    end_s: float
    hold_s: float
    horizon_s: float

    @property
    def arrival_s(self) -> float:
        """Mission time from which the plan is at the goal at rest [s]."""
        return self.end_s - self.hold_s

    @property
    def start_s(self) -> float:
        """The terminal replan's time [s]: its horizon ends at the arrival."""
        return self.arrival_s - self.horizon_s

    def is_terminal(self, t: float) -> bool:
        """Whether a replan at ``t`` is the terminal one.

        Parameters
        ----------
        t : float
            Mission time of the replan [s].

        Returns
        -------
        bool
        """
        return t >= self.start_s - 1e-9

    def next_replan(self, t: float, period_s: float) -> float:
        """The replan after a regular one: one period later, but not after the terminal replan.

        Parameters
        ----------
        t : float
            Mission time of the regular replan [s].
        period_s : float
            Replan period [s].

        Returns
        -------
        float
            Mission time of the next replan [s].
        """
        return min(t + period_s, self.start_s)

    def arrival_step(self, t: float, dt_s: float) -> int:
        """The first step of a plan at or after the arrival.

        Parameters
        ----------
        t : float
            Mission time of the plan's first sample [s].
        dt_s : float
            The plan's step [s].

        Returns
        -------
        int
            At least 1 (the first sample is the measured state).
        """
        return max(math.ceil((self.arrival_s - t) / dt_s - 1e-9), 1)


def closed_loop_jitter_std(params: InertialParams, dt_s: float, feedback_q: np.ndarray, feedback_r: np.ndarray,
                           noise_std: np.ndarray) -> np.ndarray:
    """Stationary standard deviation of the true state about a held goal under the LQR fed noisy measurements.

    The loop of :class:`oacli.excitation.rattle_loop.RattleController` at rest: the error ``e`` to the held goal
    follows the hover model ``e⁺ = A e + B u`` ([Doerr2021] Eqs. 33-36 linearised, exact discretisation) with
    ``u = K (e + n)``, ``n`` the measurement noise (white, per-axis σ). The stationary covariance solves
    ``P = (A + B K) P (A + B K)ᵀ + B K Σ_n Kᵀ Bᵀ`` (discrete Lyapunov equation).

    Parameters
    ----------
    params : InertialParams
        The model of the loop's gain (the estimate).
    dt_s : float
        Control period [s].
    feedback_q, feedback_r : ndarray, shape (12,), (6,)
        LQR weights on ``[r, v, φ, ω]`` and ``[f, τ]``.
    noise_std : ndarray, shape (12,)
        Measurement noise σ on ``[r, v, φ, ω]`` per axis [m, m/s, rad, rad/s].

    Returns
    -------
    ndarray, shape (12,)
        σ of the true error ``[r, v, φ, ω]`` at the control instants [m, m/s, rad, rad/s].
    """
    a, b = hover_error_model(params, dt_s)
    k, _ = dlqr(a, b, np.diag(feedback_q), np.diag(feedback_r))
    a_cl = a + b @ k
    bk = b @ k
    cov = scipy.linalg.solve_discrete_lyapunov(a_cl, bk @ np.diag(np.asarray(noise_std, dtype=float) ** 2) @ bk.T)
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))
