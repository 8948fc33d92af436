"""From a translational plan to a full oacli :class:`~oacli.types.Trajectory` (13-state, 6 inputs) and back.

The planners plan the translational state only ([Doerr2021] Eq. 34; [ReSWARM2023] §4.1.3). The attitude is interpolated
from the start to the goal attitude along the whole plan with a rest-to-rest minimum-jerk time scaling of the slerp,
``q(t) = q₀ ⊗ exp(s(t/T) φ)`` with ``φ = log(q₀⁻¹ q₁)`` and ``s(τ) = 10τ³ - 15τ⁴ + 6τ⁵``, so that the body rate
``ω = ṡ φ`` (body frame) and the torque ``τ = I ω̇ + ω × I ω`` ([Doerr2021] Eq. 35b) are consistent with the rigid-body
model. If the translation is too short for the rotation within the angular-rate and torque limits, the robot
holds the goal position at rest until the rotation ends. The output is what ``oacli track --reference`` follows.
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat
from oacli.model.robot_model import RobotModel
from oacli.planning.translational import TranslationalTrajectory
from oacli.types import InertialParams, Trajectory

_PEAK_RATE = 1.875  # max ds/dτ of the minimum-jerk profile
_PEAK_ACCEL = 10.0 / np.sqrt(3.0)  # max |d²s/dτ²|


def rotation_duration_s(angle_rad: float, params: InertialParams, rate_limit_radps: np.ndarray,
                        torque_limit_Nm: np.ndarray) -> float:
    """Shortest minimum-jerk rest-to-rest rotation [s] through ``angle_rad`` within the rate and torque limits.

    Uses the smallest rate limit and the smallest ``τ_max,i / I_max`` (the rotation axis is arbitrary), ignoring
    the gyroscopic term (zero at rest, second order in ω).

    Parameters
    ----------
    angle_rad : float
        Rotation angle [rad].
    params : InertialParams
        Inertia of the robot.
    rate_limit_radps : ndarray, shape (3,)
        Angular velocity limits [rad/s].
    torque_limit_Nm : ndarray, shape (3,)
        Torque limits [N·m].

    Returns
    -------
    float
        Duration [s]; 0 for no rotation.
    """
    if angle_rad <= 0.0:
        return 0.0
    rate = float(np.min(rate_limit_radps))
    accel = float(np.min(torque_limit_Nm)) / float(np.max(params.inertia_kgm2))
    return max(_PEAK_RATE * angle_rad / rate, np.sqrt(_PEAK_ACCEL * angle_rad / accel))


def hold_until(trans: TranslationalTrajectory, end_s: float, dt_s: float) -> TranslationalTrajectory:
    """Extend a trajectory that ends at rest by holding its final position (zero force) until ``end_s``.

    Parameters
    ----------
    trans : TranslationalTrajectory
        Ends at rest.
    end_s : float
        Time [s] to hold until.
    dt_s : float
        Sample period [s] of the added samples (the last one may overshoot ``end_s`` by less than ``dt_s``).

    Returns
    -------
    TranslationalTrajectory
        ``trans`` itself when it already lasts until ``end_s``.
    """
    extra = end_s - trans.t[-1]
    if extra <= 1e-12:
        return trans
    if np.any(np.abs(trans.x[-1, 3:6]) > 1e-12):
        raise ValueError("only a trajectory that ends at rest can be held")
    n = int(np.ceil(extra / dt_s - 1e-9))
    t = trans.t[-1] + dt_s * np.arange(1, n + 1)
    x = np.tile(trans.x[-1], (n, 1))
    return TranslationalTrajectory(
        np.concatenate([trans.t, t]), np.vstack([trans.x, x]), np.vstack([trans.u, np.zeros((n, 3))]), trans.model
    )


def full_state_trajectory(
    trans: TranslationalTrajectory,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    *,
    rate_limit_radps: np.ndarray,
    torque_limit_Nm: np.ndarray,
    hold_dt_s: float,
    name: str = "plan",
    frame: str = "world",
) -> Trajectory:
    """The 13-state trajectory of a translational plan with the attitude slerped from ``q_start`` to ``q_goal``.

    Parameters
    ----------
    trans : TranslationalTrajectory
        Translational plan starting at t = 0 (and ending at rest if a hold may be needed); its robot model's
        principal inertias ``trans.model.inertia_kgm2`` size the rotation and its torques.
    q_start, q_goal : ndarray, shape (4,)
        Attitudes ``[x, y, z, w]`` at the start and the goal.
    rate_limit_radps, torque_limit_Nm : ndarray, shape (3,)
        Body rate and torque limits the rotation must respect.
    hold_dt_s : float
        Sample step of an appended hold [s].
    name, frame : str
        Trajectory name and world frame.

    Returns
    -------
    Trajectory
        ``x = [r, v, q, ω]``; ``u = [f (world), τ (body)]`` with the last row zero (rest at the goal).
    """
    q0 = quat.normalize(np.asarray(q_start, dtype=float))
    q1 = quat.normalize(np.asarray(q_goal, dtype=float))
    phi = quat.error_vector(q0, q1)
    angle = float(np.linalg.norm(phi))
    params = trans.model.params
    t_rot = rotation_duration_s(angle, params, rate_limit_radps, torque_limit_Nm)
    if t_rot > trans.duration_s:
        trans = hold_until(trans, t_rot, hold_dt_s)
    big_t = trans.duration_s
    t = trans.t - trans.t[0]
    n = t.shape[0]
    x = np.zeros((n, 13))
    x[:, 0:6] = trans.x
    u = np.zeros((n, 6))
    u[:-1, 0:3] = trans.u
    if angle == 0.0 or big_t == 0.0:
        x[:, 6:10] = q0
        return Trajectory(t, x, u, name=name, frame=frame)
    tau = t / big_t
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / big_t
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / big_t**2
    x[:, 6:10] = quat.normalize(quat.multiply(q0, quat.exp(s[:, None] * phi)))
    omega = ds[:, None] * phi
    x[:, 10:13] = omega
    inertia = params.inertia_kgm2
    torque = inertia * (dds[:, None] * phi) + np.cross(omega, inertia * omega)
    u[:-1, 3:6] = torque[:-1]
    return Trajectory(t, x, u, name=name, frame=frame)


def translational_part(traj: Trajectory, model: RobotModel) -> TranslationalTrajectory:
    """The translational plan inside a 13-state trajectory (position, velocity, held force).

    Parameters
    ----------
    traj : Trajectory
        A 13-state trajectory.
    model : RobotModel
        The robot the trajectory is planned for (its mass [kg] relates the held force to the motion).

    Returns
    -------
    TranslationalTrajectory
    """
    return TranslationalTrajectory(traj.t, traj.x[:, 0:6], traj.u[:-1, 0:3], model)


def minimum_time_lower_bound_s(
    start: np.ndarray, goal: np.ndarray, force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray, model: RobotModel
) -> float:
    """A lower bound [s] on the duration of any rest-to-rest motion from ``start`` to ``goal`` (positions).

    Each axis must cover its displacement ``d_i`` with ``|v_i| <= V_i`` and ``|a_i| <= F_i / m``; the fastest
    such 1-D motion is bang-coast-bang, ``d/V + V/a`` when ``d >= V²/a`` and ``2 sqrt(d/a)`` otherwise. Obstacles
    can only lengthen it, so the maximum over the axes bounds every collision-free plan from below.

    Parameters
    ----------
    start, goal : ndarray, shape (>= 3,)
        Start and goal states (positions first).
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
        Limits per axis.
    model : RobotModel
        The robot (``a_i = F_i / model.mass_kg``; the limits are given apart: they may be design limits).

    Returns
    -------
    float
    """
    d = np.abs(np.asarray(goal, dtype=float)[0:3] - np.asarray(start, dtype=float)[0:3])
    v = np.asarray(velocity_limit_mps, dtype=float)
    a = np.asarray(force_limit_N, dtype=float) / model.mass_kg
    coast = d >= v * v / a
    t = np.where(coast, d / v + v / a, 2.0 * np.sqrt(d / a))
    return float(t.max())
