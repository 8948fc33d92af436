"""Operations on :class:`oacli.types.Trajectory`: sampling at arbitrary times and model-consistent inputs."""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat
from oacli.types import InertialParams, Trajectory


def sample_states(traj: Trajectory, times: np.ndarray) -> np.ndarray:
    """States of ``traj`` at ``times`` [s], shape (len(times), 13).

    Position, velocity and angular velocity are interpolated linearly, attitude by slerp. Before the first
    sample the first state is returned; after the last sample the robot holds the final pose at rest
    (zero velocity and angular velocity), which is what a tracking controller should converge to.

    Parameters
    ----------
    traj : Trajectory
    times : ndarray, shape (k,)
        Times [s].

    Returns
    -------
    ndarray, shape (k, 13)
    """
    times = np.atleast_1d(np.asarray(times, dtype=float))
    t = traj.t
    out = np.empty((times.size, 13))
    if len(traj) == 1:
        out[:] = traj.x[0]
        after = times > t[0]
        out[after, 3:6] = 0.0
        out[after, 10:13] = 0.0
        return out
    idx = np.clip(np.searchsorted(t, times, side="right") - 1, 0, t.size - 2)
    s = np.clip((times - t[idx]) / (t[idx + 1] - t[idx]), 0.0, 1.0)
    x0, x1 = traj.x[idx], traj.x[idx + 1]
    lin = x0 + s[:, None] * (x1 - x0)
    out[:] = lin
    out[:, 6:10] = quat.slerp(x0[:, 6:10], x1[:, 6:10], s)
    after = times > t[-1]
    out[after, 3:6] = 0.0
    out[after, 10:13] = 0.0
    return out


def feedforward_inputs(x_ref: np.ndarray, dt: float, params: InertialParams) -> np.ndarray:
    """Inputs that make the model follow ``x_ref (N+1, 13)`` sampled every ``dt`` [s], shape (N, 6).

    Force ``f_k = m (v_{k+1} − v_k)/dt`` (exact for the discrete double integrator's velocity) and torque
    ``τ_k = I (ω_{k+1} − ω_k)/dt + ω_k × I ω_k`` ([Doerr2021] Eqs. 34b, 35b).

    Parameters
    ----------
    x_ref : ndarray, shape (N+1, 13)
        Reference states.
    dt : float
        Sample period [s].
    params : InertialParams
        The model.

    Returns
    -------
    ndarray, shape (N, 6)
    """
    inertia = params.inertia_kgm2
    dv = np.diff(x_ref[:, 3:6], axis=0) / dt
    dw = np.diff(x_ref[:, 10:13], axis=0) / dt
    w = x_ref[:-1, 10:13]
    torque = inertia * dw + np.cross(w, inertia * w)
    return np.hstack([params.mass_kg * dv, torque])


def sample_inputs(traj: Trajectory, times: np.ndarray) -> np.ndarray:
    """Inputs of ``traj`` at ``times`` [s] under its zero-order hold, shape (len(times), 6); zero after the end.

    Parameters
    ----------
    traj : Trajectory
    times : ndarray, shape (k,)
        Times [s].

    Returns
    -------
    ndarray, shape (k, 6)
    """
    times = np.atleast_1d(np.asarray(times, dtype=float))
    idx = np.clip(np.searchsorted(traj.t, times, side="right") - 1, 0, len(traj) - 1)
    out = traj.u[idx].copy()
    out[times > traj.t[-1]] = 0.0
    return out
