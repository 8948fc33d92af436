"""The sequential filter across a gap in the input record (:class:`oacli.estimation.sequential.SequentialEstimator`).

One lost control instant is bridged as the batch links it (:func:`~oacli.estimation.lost_inputs.lost_input_prior`,
:func:`~oacli.estimation.lost_inputs.segment_link_weights`): the input predicted from its neighbours, its error as
process noise, or the force and torque measured by the IMU where it survived ([Doerr2021] Eq. 35b for the gyro).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.estimation.lost_inputs import (
    BRIDGE_FACTOR,
    lost_input_prior,
    unknown_force_directions,
    unknown_torque_directions,
)
from oacli.estimation.models import Measurement
from oacli.estimation.propagation import TIME_TOL_S

__all__ = ["bridge_gap"]


def bridge_gap(est: Any, rec: Measurement) -> bool:
    """Prepare the prediction across a gap in the input record ending at ``rec`` (``rec.starts_segment``), as the
    batch links it (:func:`~oacli.estimation.lost_inputs.lost_input_prior`,
    :func:`~oacli.estimation.lost_inputs.segment_link_weights`); False when it cannot be bridged.

    One lost control instant: the previous record is the lost instant's input-only record (reached through a
    known input), and the unknown interval is as long as the one before it and at most ``BRIDGE_FACTOR``
    typical record spacings. Its input is predicted as the mean of the known inputs on either side,
    ``(u_{k-1} + u_{k+1}) / 2``, and the prediction's error variance, measured on the records so far (every
    triple of consecutive known inputs, as the batch measures it on the whole run), enters as process noise
    ``D Σ_u Dᵀ`` over the interval (``D``: the force and torque directions of the end state). Anything else
    (several lost instants, uneven stamps, fewer triples than the batch needs) is a gap the filter does not
    bridge: it re-initialises the robot state there (``segments``). Online the input after the gap must be
    taken as known (the batch also checks the interval after it).

    Parameters
    ----------
    est : oacli.estimation.sequential.SequentialEstimator
        The filter (its input history, θ̂ and noise models; its gap state is set here).
    rec : Measurement
        The record after the gap.

    Returns
    -------
    bool
        The gap is bridged (the next prediction crosses it).
    """
    t = np.array(est._inputs_t)
    k1 = t.size - 1  # rec
    k = k1 - 1  # the lost instant
    if k < 1 or est._inputs_start[k] or rec.t != t[k1]:
        return False
    dt_gap, dt_prev = t[k1] - t[k], t[k] - t[k - 1]
    if abs(dt_gap - dt_prev) > TIME_TOL_S + 1e-6 * abs(dt_gap):
        return False
    starts = np.array(est._inputs_start, dtype=bool)
    links = ~starts[1:]
    dt = np.diff(t)
    if dt_gap > BRIDGE_FACTOR * float(np.median(dt[links])) + TIME_TOL_S:
        return False
    u = np.array(est._inputs_u)
    _, _, variance = lost_input_prior(t, u, links)
    if not np.all(np.isfinite(variance)):
        return False
    theta = est.prior.theta
    est._u_last = 0.5 * (u[k - 1] + u[k1])
    d_force = unknown_force_directions(np.array([dt_gap]))[0]
    sigma_a = est.settings.measurement.linear_acceleration_std_mps2
    if est._lost_acc is not None and sigma_a is not None and np.isfinite(sigma_a) and sigma_a > 0:
        # The accelerometer measured the lost force as f/m (lost_input_model): no prediction, no mass.
        acc, readings = est._lost_acc
        variance = np.concatenate([np.full(3, float(sigma_a) ** 2 / max(readings, 1)), variance[3:6]])
        est._u_last[0:3] = 0.0
        est._gap_acc = (acc, float(dt_gap))
        est.gaps_bridged_imu += 1
    else:
        d_force = d_force / theta[0]
    d_torque = unknown_torque_directions(np.array([dt_gap]), theta[1:4])[0]
    if est._lost_gyro is not None:
        est.gaps_bridged_imu += est._gap_acc is None  # counted once per gap, either sensor
        # The gyro measured the lost torque's ω̇ (lost_input_model): J⁻¹τ = ω̇ + J⁻¹(ω × Jω) with the model's
        # torque 0 (its gyroscopic term stays), at the current θ̂; its variance directly on [½T², T].
        alpha, alpha_var, rate = est._lost_gyro
        inertia = est._model.theta4(est._phi)[1:4]
        est._gap_gyro = (alpha + np.cross(rate, rate * inertia) / inertia, rate, float(dt_gap))
        est._u_last[3:6] = 0.0
        variance = np.concatenate([variance[0:3], np.full(3, alpha_var)])
        d_torque = d_torque * theta[1:4]  # per unit ω̇
        est.gaps_bridged_gyro += 1
    d = np.concatenate([d_force, d_torque], axis=1)
    est._gap_q = (d * variance) @ d.T
    est.gaps_bridged += 1
    return True
