"""Closed-loop simulator: truth plant, sampled controller, saturating actuators, noisy sensors.

The truth plant (its own inertial parameters, which may differ from the controller's model) is integrated
with RK4 on a fixed grid of ``plant_period_s`` (62.5 Hz on Astrobee). The controller runs every
``control_period_s`` and its input is held (zero-order hold) until the next update; when a controller instant
falls between two plant ticks the integration step is split there, so both rates are honoured exactly.
Actuators saturate each axis at its limit. Every random draw comes from the generator passed in.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from oacli.model.rigid_body import propagate, theta_of
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.types import Controller, InertialParams, SolveInfo, Telemetry

_TIME_TOL = 1e-9


def simulate(
    controller: Controller,
    x0: np.ndarray,
    truth: InertialParams,
    *,
    duration_s: float,
    control_period_s: float,
    plant_period_s: float,
    input_limits: np.ndarray,
    sensors: SensorNoise,
    disturbance: Disturbance,
    rng: np.random.Generator,
    progress: Callable[[float], None] | None = None,
) -> Telemetry:
    """Run the closed loop from ``x0`` for ``duration_s`` [s].

    Parameters
    ----------
    controller : Controller
    x0 : ndarray, shape (13,)
        Initial true state.
    truth : InertialParams
        Inertial parameters of the simulated plant.
    duration_s, control_period_s, plant_period_s : float
        Simulated time and the two periods [s].
    input_limits : ndarray, shape (6,)
        Per-axis actuator saturation [N, N·m].
    sensors : SensorNoise
    disturbance : Disturbance
    rng : numpy.random.Generator
        Source of every random draw (measurement noise, then disturbance, each control step).
    progress : callable, optional
        Called with the completed fraction in [0, 1] after each control step.

    Returns
    -------
    Telemetry
        True state on the plant grid (and at the final time), and per control step the measured state,
        reference, commanded and applied input, disturbance and solve record.
    """
    if duration_s <= 0 or control_period_s <= 0 or plant_period_s <= 0:
        raise ValueError("duration and periods must be > 0")
    theta = theta_of(truth)
    n_ctrl = int(np.floor(duration_s / control_period_s + _TIME_TOL))
    n_ctrl = max(n_ctrl, 1)
    t_end = n_ctrl * control_period_s
    x = np.array(x0, dtype=float)
    t_true = [0.0]
    x_true = [x.copy()]
    t_ctrl = np.arange(n_ctrl) * control_period_s
    rec_meas = np.empty((n_ctrl, 13))
    rec_ref = np.empty((n_ctrl, 13))
    rec_cmd = np.empty((n_ctrl, 6))
    rec_app = np.empty((n_ctrl, 6))
    rec_dist = np.empty((n_ctrl, 6))
    infos: list[SolveInfo] = []
    next_tick = 1
    for j in range(n_ctrl):
        t0 = t_ctrl[j]
        t1 = min(t0 + control_period_s, t_end)
        y = sensors.measure(x, rng)
        step = controller.step(float(t0), y)
        u_cmd = np.asarray(step.u, dtype=float)
        u_app = np.clip(u_cmd, -input_limits, input_limits)
        w = disturbance.sample(rng)
        rec_meas[j], rec_ref[j], rec_cmd[j], rec_app[j], rec_dist[j] = y, step.x_reference, u_cmd, u_app, w
        infos.append(step.info)
        u_total = u_app + w
        t = t0
        while t < t1 - _TIME_TOL:
            tick = next_tick * plant_period_s
            t_next = min(tick, t1)
            x = propagate(x, u_total, theta, t_next - t)
            t = t_next
            if abs(t - tick) <= _TIME_TOL:
                next_tick += 1
                t_true.append(tick)
                x_true.append(x.copy())
        if progress is not None:
            progress((j + 1) / n_ctrl)
    if t_end - t_true[-1] > _TIME_TOL:
        t_true.append(t_end)
        x_true.append(x.copy())
    return Telemetry(
        t_true=np.array(t_true),
        x_true=np.array(x_true),
        t_ctrl=t_ctrl,
        x_measured=rec_meas,
        x_reference=rec_ref,
        u_command=rec_cmd,
        u_applied=rec_app,
        solve_info=tuple(infos),
        disturbance=rec_dist,
    )
