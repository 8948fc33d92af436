"""Closed-loop simulator: truth plant, sampled controller, saturating actuators, noisy sensors.

The truth plant (its own inertial parameters, which may differ from the controller's model) is integrated
with RK4 on a fixed grid of ``plant_period_s`` (62.5 Hz on Astrobee). The controller runs every
``control_period_s`` and its input is held (zero-order hold) until the next update; when a controller instant
falls between two plant ticks the integration step is split there, so both rates are honoured exactly.
Actuators saturate each axis at its limit. Two unmodelled actuator effects of a real free-flyer may be switched on:
a per-axis scale error between the applied and the delivered input, and a centre-of-mass offset ``r`` from the
geometric centre the thrust acts on, which adds the torque ``-r × F_body`` (recomputed at every plant step from the
current attitude). The recorded ``u_applied`` stays what the robot believes it applied (the saturated command), as
a flight log would. Every random draw comes from the generator passed in.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from oacli.model import quaternion as quat
from oacli.model.rigid_body import propagate, theta_of
from oacli.sim.full_inertia import TensorPlant
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
    actuator_scale: np.ndarray | None = None,
    com_offset_m: np.ndarray | None = None,
    on_step: Callable[..., None] | None = None,
    inertia_tensor_kgm2: np.ndarray | None = None,
    delivered_limits: np.ndarray | None = None,
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
    actuator_scale : ndarray, shape (6,), optional
        Delivered ÷ applied input per axis (default: ones, perfect actuators).
    com_offset_m : ndarray, shape (3,), optional
        Centre of mass relative to the geometric centre, body frame [m] (default: zero).
    on_step : callable, optional
        Called after each control step ``j`` as ``on_step(j, t_true=..., x_true=..., t_ctrl=..., x_measured=...,
        x_reference=..., u_command=..., u_applied=..., disturbance=..., info=...)``: the plant samples produced
        during the step (``t_true`` shape (M,), ``x_true`` (M, 13); step 0 includes the initial state at t = 0 and
        the last step the final state at the end time) and the step's controller record (the same values as the
        returned :class:`Telemetry`), so a caller can write the run while it is produced. Arrays are copies.
    inertia_tensor_kgm2 : ndarray, shape (3, 3), optional
        Full inertia tensor of the plant (products of inertia, :class:`oacli.sim.full_inertia.TensorPlant`);
        default: ``diag(truth.inertia_kgm2)``.
    delivered_limits : ndarray, shape (6,), optional
        Actuator saturation fault: the plant receives the applied input clipped again at these bounds
        (``faults.actuator_saturation``; unmodelled, ``u_applied`` is unchanged). Default: no further clipping.

    Returns
    -------
    Telemetry
        True state on the plant grid (and at the final time), and per control step the measured state,
        reference, commanded and applied input, disturbance and solve record.
    """
    if duration_s <= 0 or control_period_s <= 0 or plant_period_s <= 0:
        raise ValueError("duration and periods must be > 0")
    theta = theta_of(truth)
    step_plant = propagate if inertia_tensor_kgm2 is None else TensorPlant(truth.mass_kg, inertia_tensor_kgm2).propagate
    scale = np.ones(6) if actuator_scale is None else np.asarray(actuator_scale, dtype=float).reshape(6)
    offset = None if com_offset_m is None or not np.any(com_offset_m) else np.asarray(com_offset_m, float).reshape(3)
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
    rec_true = np.empty((n_ctrl, 13))
    infos: list[SolveInfo] = []
    next_tick = 1
    reported = 0  # plant samples already handed to on_step
    for j in range(n_ctrl):
        t0 = t_ctrl[j]
        t1 = min(t0 + control_period_s, t_end)
        rec_true[j] = x
        y = sensors.measure(x, rng)
        step = controller.step(float(t0), y)
        u_cmd = np.asarray(step.u, dtype=float)
        u_app = np.clip(u_cmd, -input_limits, input_limits)
        w = disturbance.sample(rng)
        rec_meas[j], rec_ref[j], rec_cmd[j], rec_app[j], rec_dist[j] = y, step.x_reference, u_cmd, u_app, w
        infos.append(step.info)
        u_del = u_app if delivered_limits is None else np.clip(u_app, -delivered_limits, delivered_limits)
        u_total = scale * u_del + w
        t = t0
        while t < t1 - _TIME_TOL:
            tick = next_tick * plant_period_s
            t_next = min(tick, t1)
            u_step = u_total if offset is None else _with_offset_torque(u_total, x, offset)
            x = step_plant(x, u_step, theta, t_next - t)
            t = t_next
            if abs(t - tick) <= _TIME_TOL:
                next_tick += 1
                t_true.append(tick)
                x_true.append(x.copy())
        if j == n_ctrl - 1 and t_end - t_true[-1] > _TIME_TOL:
            t_true.append(t_end)
            x_true.append(x.copy())
        if on_step is not None:
            on_step(j, t_true=np.array(t_true[reported:]), x_true=np.array(x_true[reported:]).reshape(-1, 13),
                    t_ctrl=float(t0), x_measured=rec_meas[j].copy(), x_reference=rec_ref[j].copy(),
                    u_command=rec_cmd[j].copy(), u_applied=rec_app[j].copy(), disturbance=rec_dist[j].copy(),
                    info=step.info)
            reported = len(t_true)
        if progress is not None:
            progress((j + 1) / n_ctrl)
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
        x_true_ctrl=rec_true,
    )


def _with_offset_torque(u: np.ndarray, x: np.ndarray, com_offset_m: np.ndarray) -> np.ndarray:
    """``u`` plus the torque of its force about a centre of mass displaced by ``com_offset_m`` (body frame).

    The force acts at the geometric centre, at ``-r`` from the centre of mass, so it adds ``τ = (-r) × F_body``
    with ``F_body = Rᵀ F_world`` ([Doerr2021] Eq. 34 for the frames).
    """
    force_body = quat.to_rotation_matrix(x[6:10]).T @ u[0:3]
    out = np.array(u, dtype=float)
    out[3:6] += np.cross(-com_offset_m, force_body)
    return out
