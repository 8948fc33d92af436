"""Closed-loop simulator: truth plant, sampled controller, saturating actuators, noisy sensors.

The truth plant (its own inertial parameters, which may differ from the controller's model) is integrated
with RK4 on a fixed grid of ``plant_period_s`` (62.5 Hz on Astrobee). The controller runs every
``control_period_s`` and its input is held (zero-order hold) until the next update; when a controller instant
falls between two plant ticks the integration step is split there, so both rates are honoured exactly.
Actuators saturate each axis at its limit. Two actuator effects of a real free-flyer may be switched on
(:mod:`oacli.sim.actuators`): a scale error between the applied and the delivered input per *body* axis (Astrobee's
impellers are body-fixed), and a centre-of-mass offset ``r`` from the geometric centre the thrust acts on, which
adds the torque ``-r × F_body``; both are recomputed at every plant step from the attitude at its start. The
disturbance's force is added in the world frame after them and does not torque the body. The recorded
``u_applied`` stays what the robot believes it applied (the saturated command), as a flight log would. Every
random draw comes from the generator passed in.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from oacli.model.rigid_body import theta_of
from oacli.sim.actuators import delivered_wrench, delivered_wrench_floats
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
        Delivered ÷ applied input per axis: force per body axis, torque per body axis (default: ones, perfect
        actuators).
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
    tensor_plant = None if inertia_tensor_kgm2 is None else TensorPlant(truth, inertia_tensor_kgm2)
    scale = np.ones(6) if actuator_scale is None else np.asarray(actuator_scale, dtype=float).reshape(6)
    offset = None if com_offset_m is None or not np.any(com_offset_m) else np.asarray(com_offset_m, float).reshape(3)
    n_ctrl = int(np.floor(duration_s / control_period_s + _TIME_TOL))
    n_ctrl = max(n_ctrl, 1)
    t_end = n_ctrl * control_period_s
    x = np.array(x0, dtype=float)
    state = [float(v) for v in x]  # the plant state as Python floats: the substep loop works on these
    t_true = [0.0]
    x_true = [tuple(state)]
    mass, inertia = float(theta[0]), (float(theta[1]), float(theta[2]), float(theta[3]))
    offset_r = None if offset is None else (float(offset[0]), float(offset[1]), float(offset[2]))
    body_scale = None if np.all(scale[0:3] == 1.0) else (float(scale[0]), float(scale[1]), float(scale[2]))
    body_scale_arr = None if body_scale is None else np.array(body_scale)
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
        x = np.array(state)
        rec_true[j] = x
        y = sensors.measure(x, rng)
        step = controller.step(float(t0), y)
        u_cmd = np.asarray(step.u, dtype=float)
        u_app = np.clip(u_cmd, -input_limits, input_limits)
        w = disturbance.sample(rng)
        rec_meas[j], rec_ref[j], rec_cmd[j], rec_app[j], rec_dist[j] = y, step.x_reference, u_cmd, u_app, w
        infos.append(step.info)
        u_del = u_app if delivered_limits is None else np.clip(u_app, -delivered_limits, delivered_limits)
        if body_scale is None and offset is None:
            u_total = [float(v) for v in scale * u_del + w]
            w_force = (0.0, 0.0, 0.0)
        else:  # the force is scaled per body axis at every plant step; the disturbance force added after
            u_total = [float(v) for v in np.r_[u_del[0:3], scale[3:6] * u_del[3:6] + w[3:6]]]
            w_force = (float(w[0]), float(w[1]), float(w[2]))
        # The plant steps of this control period: up to each plant tick, the last one cut at t1.
        steps: list[float] = []
        ticks: list[float | None] = []
        t = t0
        while t < t1 - _TIME_TOL:
            tick = next_tick * plant_period_s
            t_next = min(tick, t1)
            steps.append(t_next - t)
            t = t_next
            if abs(t - tick) <= _TIME_TOL:
                next_tick += 1
                ticks.append(tick)
            else:
                ticks.append(None)
        if tensor_plant is None:
            states = _propagate_steps(state, u_total, mass, inertia, offset_r, steps, body_scale, w_force)
        else:  # products of inertia: the numpy step of the full tensor (campaign dispersions)
            states = []
            for dt in steps:
                x_now, u_now = np.array(state), np.array(u_total)
                u_step = delivered_wrench(u_now, x_now[6:10], body_scale_arr, offset)
                u_step[0:3] += w_force
                state = [float(v) for v in tensor_plant.propagate(x_now, u_step, theta, dt)]
                states.append(tuple(state))
        if states:
            state = list(states[-1])
        for tick_s, sample in zip(ticks, states, strict=True):
            if tick_s is not None:
                t_true.append(tick_s)
                x_true.append(sample)
        if j == n_ctrl - 1 and t_end - t_true[-1] > _TIME_TOL:
            t_true.append(t_end)
            x_true.append(tuple(state))
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


def _propagate_steps(s: list[float], u: list[float], mass: float, inertia: tuple[float, float, float],
                     offset: tuple[float, float, float] | None, steps: list[float],
                     force_scale: tuple[float, float, float] | None = None,
                     w_force: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> list[tuple[float, ...]]:
    """The plant over consecutive steps ``steps`` [s] under the held input ``u``: the state after each step.

    Each step is :func:`oacli.model.rigid_body.propagate` (RK4 of [Doerr2021] Eqs. 34-35 with ``u`` held, then the
    quaternion renormalised with ``w >= 0``) with the delivered wrench (body-axis force scale ``force_scale`` and
    centre-of-mass torque, :func:`oacli.sim.actuators.delivered_wrench`, plus the world force ``w_force``) taken at
    the step's initial attitude, written out on Python floats: the same operations in the same order as the numpy
    version (bit-identical; ``tests/test_simulator.py`` checks), without its per-call array overhead. The
    translational stages need no position (the force is held), so only the velocities of the stages are formed.
    """
    px, py, pz, vx, vy, vz, qx, qy, qz, qw, wx, wy, wz = s
    ix, iy, iz = inertia
    f0, f1, f2, t0, t1, t2 = u
    ax, ay, az = f0 / mass, f1 / mass, f2 / mass
    tx, ty, tz = t0, t1, t2
    dyz, dzx, dxy = iz - iy, ix - iz, iy - ix
    out: list[tuple[float, ...]] = []
    varying = offset is not None or force_scale is not None
    for dt in steps:
        if varying:
            g0, g1, g2, tx, ty, tz = delivered_wrench_floats(f0, f1, f2, t0, t1, t2, qx, qy, qz, qw, force_scale,
                                                             offset)
            ax, ay, az = (g0 + w_force[0]) / mass, (g1 + w_force[1]) / mass, (g2 + w_force[2]) / mass
        h = 0.5 * dt
        # k1 at s
        a1 = 0.5 * (qw * wx - qz * wy + qy * wz)
        b1 = 0.5 * (qz * wx + qw * wy - qx * wz)
        c1 = 0.5 * (-qy * wx + qx * wy + qw * wz)
        d1 = 0.5 * (-qx * wx - qy * wy - qz * wz)
        e1 = (tx - dyz * wy * wz) / ix
        g1 = (ty - dzx * wz * wx) / iy
        k1 = (tz - dxy * wx * wy) / iz
        # k2 at s + h k1
        sx, sy, sz, sw = qx + h * a1, qy + h * b1, qz + h * c1, qw + h * d1
        ox, oy, oz = wx + h * e1, wy + h * g1, wz + h * k1
        a2 = 0.5 * (sw * ox - sz * oy + sy * oz)
        b2 = 0.5 * (sz * ox + sw * oy - sx * oz)
        c2 = 0.5 * (-sy * ox + sx * oy + sw * oz)
        d2 = 0.5 * (-sx * ox - sy * oy - sz * oz)
        e2 = (tx - dyz * oy * oz) / ix
        g2 = (ty - dzx * oz * ox) / iy
        k2 = (tz - dxy * ox * oy) / iz
        # k3 at s + h k2
        sx, sy, sz, sw = qx + h * a2, qy + h * b2, qz + h * c2, qw + h * d2
        ox, oy, oz = wx + h * e2, wy + h * g2, wz + h * k2
        a3 = 0.5 * (sw * ox - sz * oy + sy * oz)
        b3 = 0.5 * (sz * ox + sw * oy - sx * oz)
        c3 = 0.5 * (-sy * ox + sx * oy + sw * oz)
        d3 = 0.5 * (-sx * ox - sy * oy - sz * oz)
        e3 = (tx - dyz * oy * oz) / ix
        g3 = (ty - dzx * oz * ox) / iy
        k3 = (tz - dxy * ox * oy) / iz
        # k4 at s + dt k3
        sx, sy, sz, sw = qx + dt * a3, qy + dt * b3, qz + dt * c3, qw + dt * d3
        ox, oy, oz = wx + dt * e3, wy + dt * g3, wz + dt * k3
        a4 = 0.5 * (sw * ox - sz * oy + sy * oz)
        b4 = 0.5 * (sz * ox + sw * oy - sx * oz)
        c4 = 0.5 * (-sy * ox + sx * oy + sw * oz)
        d4 = 0.5 * (-sx * ox - sy * oy - sz * oz)
        e4 = (tx - dyz * oy * oz) / ix
        g4 = (ty - dzx * oz * ox) / iy
        k4 = (tz - dxy * ox * oy) / iz
        c = dt / 6.0
        # Translation: the position's stage derivatives are the stage velocities v, v + h a, v + h a, v + dt a.
        hx, hy, hz = vx + h * ax, vy + h * ay, vz + h * az
        px = px + c * (vx + 2.0 * hx + 2.0 * hx + (vx + dt * ax))
        py = py + c * (vy + 2.0 * hy + 2.0 * hy + (vy + dt * ay))
        pz = pz + c * (vz + 2.0 * hz + 2.0 * hz + (vz + dt * az))
        vx = vx + c * (ax + 2.0 * ax + 2.0 * ax + ax)
        vy = vy + c * (ay + 2.0 * ay + 2.0 * ay + ay)
        vz = vz + c * (az + 2.0 * az + 2.0 * az + az)
        qx = qx + c * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        qy = qy + c * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
        qz = qz + c * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
        qw = qw + c * (d1 + 2.0 * d2 + 2.0 * d3 + d4)
        wx = wx + c * (e1 + 2.0 * e2 + 2.0 * e3 + e4)
        wy = wy + c * (g1 + 2.0 * g2 + 2.0 * g3 + g4)
        wz = wz + c * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if qw / norm < 0.0:
            norm = -norm
        qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
        out.append((px, py, pz, vx, vy, vz, qx, qy, qz, qw, wx, wy, wz))
    return out
