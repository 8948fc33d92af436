"""Reference trajectories through waypoints with a minimum-jerk time scaling.

Each leg moves in a straight line from one waypoint to the next while the attitude slerps, both driven by
the same minimum-jerk time scaling ``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵`` (τ = t/T), whose peak rate is ``1.875/T`` and
peak acceleration ``5.7735/T²``. The leg duration T is the smallest that keeps the speed, acceleration,
angular rate and angular acceleration within the given limits. The inputs are the ones the model needs to
follow the reference exactly (f = m a in the world frame, τ = I α + ω × I ω in the body frame).
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat
from oacli.types import InertialParams, Trajectory

_PEAK_RATE = 1.875  # max of ds/dτ for the minimum-jerk profile
_PEAK_ACCEL = 10.0 / np.sqrt(3.0)  # max of d²s/dτ²


def _min_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s, ds/dτ, d²s/dτ² of the minimum-jerk profile on τ ∈ [0, 1]."""
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


def leg_duration(
    distance_m: float, angle_rad: float, speed: float, accel: float, rate: float, ang_accel: float
) -> float:
    """Shortest minimum-jerk leg duration [s] within the speed/acceleration and angular limits.

    Parameters
    ----------
    distance_m : float
        Translation [m].
    angle_rad : float
        Rotation [rad].
    speed, accel : float
        Speed [m/s] and acceleration [m/s²] limits.
    rate, ang_accel : float
        Angular rate [rad/s] and angular acceleration [rad/s²] limits.

    Returns
    -------
    float
        At least 1 ms.
    """
    return max(
        _PEAK_RATE * distance_m / speed,
        np.sqrt(_PEAK_ACCEL * distance_m / accel),
        _PEAK_RATE * angle_rad / rate,
        np.sqrt(_PEAK_ACCEL * angle_rad / ang_accel),
        1e-3,
    )


def waypoint_reference(
    positions: np.ndarray,
    quaternions: np.ndarray,
    params: InertialParams,
    *,
    speed_mps: float,
    accel_mps2: float,
    rate_radps: float,
    ang_accel_radps2: float,
    hold_s: float = 0.0,
    sample_period_s: float = 0.1,
    name: str = "reference",
    frame: str = "world",
) -> Trajectory:
    """Rest-to-rest reference through ``positions (K, 3)`` [m] with attitudes ``quaternions (K, 4)``.

    The robot holds each waypoint for ``hold_s`` [s] (including the first and the last).

    Parameters
    ----------
    positions : ndarray, shape (K, 3)
        Waypoints [m].
    quaternions : ndarray, shape (K, 4)
        Attitudes at the waypoints.
    params : InertialParams
        For the feedforward inputs.
    speed_mps, accel_mps2, rate_radps, ang_accel_radps2 : float
        Limits of each leg (:func:`leg_duration`).
    hold_s : float, optional
        Hold at each waypoint [s].
    sample_period_s : float, optional
        Sample period [s].
    name, frame : str, optional
        Trajectory name and coordinate frame.

    Returns
    -------
    Trajectory
    """
    positions = np.asarray(positions, dtype=float)
    quaternions = quat.normalize(np.asarray(quaternions, dtype=float))
    if positions.shape[0] < 1 or positions.shape != (quaternions.shape[0], 3):
        raise ValueError("positions (K, 3) and quaternions (K, 4) must have the same K >= 1")
    t_now = 0.0
    ts, xs, us = [], [], []

    def hold(p: np.ndarray, q: np.ndarray, duration: float) -> None:
        nonlocal t_now
        n = max(round(duration / sample_period_s), 1)
        t = t_now + sample_period_s * np.arange(n)
        x = np.zeros((n, 13))
        x[:, 0:3] = p
        x[:, 6:10] = q
        ts.append(t)
        xs.append(x)
        us.append(np.zeros((n, 6)))
        t_now += n * sample_period_s

    hold(positions[0], quaternions[0], hold_s)
    inertia = params.inertia_kgm2
    for i in range(positions.shape[0] - 1):
        p0, p1 = positions[i], positions[i + 1]
        q0, q1 = quaternions[i], quaternions[i + 1]
        delta = quat.error_vector(q0, q1)  # body-frame rotation vector of the leg
        dist = float(np.linalg.norm(p1 - p0))
        angle = float(np.linalg.norm(delta))
        big_t = leg_duration(dist, angle, speed_mps, accel_mps2, rate_radps, ang_accel_radps2)
        n = max(int(np.ceil(big_t / sample_period_s)), 1)
        big_t = n * sample_period_s
        tau = np.arange(n) / n
        s, ds, dds = _min_jerk(tau)
        ds, dds = ds / big_t, dds / big_t**2
        x = np.zeros((n, 13))
        x[:, 0:3] = p0 + s[:, None] * (p1 - p0)
        x[:, 3:6] = ds[:, None] * (p1 - p0)
        x[:, 6:10] = quat.normalize(quat.multiply(q0, quat.exp(s[:, None] * delta)))
        x[:, 10:13] = ds[:, None] * delta
        w = x[:, 10:13]
        u = np.zeros((n, 6))
        u[:, 0:3] = params.mass_kg * dds[:, None] * (p1 - p0)
        u[:, 3:6] = inertia * (dds[:, None] * delta) + np.cross(w, inertia * w)
        ts.append(t_now + sample_period_s * np.arange(n))
        xs.append(x)
        us.append(u)
        t_now += big_t
        hold(p1, q1, hold_s)
    # Final sample at rest at the last waypoint.
    x_end = np.zeros((1, 13))
    x_end[0, 0:3] = positions[-1]
    x_end[0, 6:10] = quaternions[-1]
    ts.append(np.array([t_now]))
    xs.append(x_end)
    us.append(np.zeros((1, 6)))
    return Trajectory(np.concatenate(ts), np.vstack(xs), np.vstack(us), name=name, frame=frame)
