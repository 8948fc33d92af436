"""IMU readings into estimator records: accelerometer bias removed, specific force rotated into the world frame.

The estimators' acceleration measurement is ``f/m`` in the world frame at a record's stamp, just after its input
took effect (:class:`oacli.estimation.models.Measurement`, [Doerr2021] Eq. 34). An accelerometer reads the
specific force in the body frame plus a bias ``b`` (:mod:`oacli.sim.imu`)::

    ã_i = Rᵀ(q_i) f_i / m + b + n_i

**Bias: estimated, not augmented.** Left in, a bias of 1e-3 m/s² against the 1e-2 m/s² of an excitation's
accelerations biases the mass by percents; RATTLE's filter ([ReSWARM2023] §4.4.1) took the accelerations from
Astrobee's EKF, which estimates the IMU biases itself. Here the bias is estimated before the fit, jointly with
``1/m``, by linear least squares over **every** reading at the plant rate whose input is known (the model above is
linear in ``(1/m, b)`` given the applied input and the measured attitude)::

    min Σ_i ‖ã_i − c · Rᵀ(q_i) u_f,i − b‖²,    c ≈ 1/m

and subtracted from the reading used at each record. The records use one reading in about 12 (62.5 Hz against a
5 Hz controller), so the bias estimate's own error, ``σ_a / √N`` per axis (3e-5 m/s² for N = 5000 readings at
σ_a = 2.2e-3 m/s², the RATTLE level), is about ``1/√12`` of one record's noise averaged over the same records and
is left out of the Cramér-Rao bound; ``bias_std_mps2`` in the summary reports it. A random-walk bias is not
constant: what drifts over the run (``σ_rw √T``) stays in the residuals, bounded by the summary's
``residual_rms_mps2``. The gyro is not used: the localisation's angular rate (Astrobee's EKF output, its gyro
bias already removed) is the rate measurement.

**Lost controller records.** The IMU is a stream of its own: a lost controller record (measurement, input and
command of one control step) leaves its readings in the log. Over the lost control period the accelerometer
measures the unknown force as ``f/m``; :func:`attach_accelerations` gives the lost instant's input-only record the
mean of those readings and their number, and the batch estimator bridges the gap with it
(:func:`oacli.estimation.batch.lost_input_model`): on the benchmark's gapped ISS runs the mass bound drops from
0.88 % (force predicted from the neighbouring inputs) to 0.52 %.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from oacli.estimation.models import Measurement
from oacli.model import quaternion as quat

__all__ = ["AccelerometerFit", "ImuStream", "attach_accelerations", "fit_accelerometer_bias"]


@dataclass(frozen=True)
class ImuStream:
    """IMU readings as logged.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Stamps [s].
    specific_force_mps2, angular_rate_radps : ndarray, shape (N, 3)
        Body-frame readings [m/s², rad/s].
    """

    t: np.ndarray
    specific_force_mps2: np.ndarray
    angular_rate_radps: np.ndarray


@dataclass(frozen=True)
class AccelerometerFit:
    """The joint least-squares fit of ``(1/m, b)`` (module docstring).

    Attributes
    ----------
    bias_mps2 : ndarray, shape (3,)
    bias_std_mps2 : ndarray, shape (3,)
        Standard deviation of the bias estimate from the residual spread.
    inverse_mass_per_kg : float
    samples : int
        Readings with a known input used in the fit.
    residual_rms_mps2 : float
    """

    bias_mps2: np.ndarray
    bias_std_mps2: np.ndarray
    inverse_mass_per_kg: float
    samples: int
    residual_rms_mps2: float


def _interval_of(records: list[Measurement], t: np.ndarray, t_inputs: np.ndarray, period_s: float) -> np.ndarray:
    """Index of the record whose input acts at each ``t`` (-1 when unknown): the input logged last before ``t``
    must be the one logged last before the record, and still held (less than a control period old)."""
    tol = 1e-9
    t_rec = np.array([r.t for r in records])
    t_inputs = np.sort(np.asarray(t_inputs, float))
    idx = np.searchsorted(t_rec, t + tol, side="right") - 1
    k_t = np.searchsorted(t_inputs, t + tol, side="right") - 1
    k_rec = np.searchsorted(t_inputs, t_rec[np.maximum(idx, 0)] + tol, side="right") - 1
    held = (k_t >= 0) & (t - t_inputs[np.maximum(k_t, 0)] < period_s - tol)
    return np.where((idx >= 0) & (k_rec >= 0) & (k_rec == k_t) & held, idx, -1)


def _attitude_at(records: list[Measurement], idx: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Measured attitude of record ``idx`` carried to ``t`` with its measured rate (a few ms: first order)."""
    x = np.array([records[j].x_measured for j in idx]).reshape(-1, 13)
    dt = t - np.array([records[j].t for j in idx])
    return quat.normalize(quat.multiply(x[:, 6:10], quat.exp(x[:, 10:13] * dt[:, None])))


def fit_accelerometer_bias(
    records: list[Measurement], imu: ImuStream, t_inputs: np.ndarray, period_s: float
) -> AccelerometerFit | None:
    """Least-squares ``(1/m, b)`` over the readings whose input is known (module docstring).

    Parameters
    ----------
    records : list of Measurement
        Aligned records (strictly increasing stamps).
    imu : ImuStream
    t_inputs : ndarray
        Stamps of the logged inputs (applied or commanded) [s].
    period_s : float
        Control period [s] (how long an input is known to hold).

    Returns
    -------
    AccelerometerFit or None
        None with fewer than 4 usable readings.
    """
    t = np.asarray(imu.t, float)
    idx = _interval_of(records, t, t_inputs, period_s)
    use = idx >= 0
    if np.count_nonzero(use) < 4:
        return None
    q = _attitude_at(records, idx[use], t[use])
    f_world = np.array([records[j].u_applied[0:3] for j in idx[use]])
    f_body = np.einsum("nji,nj->ni", quat.to_rotation_matrix(q), f_world)
    a = np.asarray(imu.specific_force_mps2, float)[use]
    n = a.shape[0]
    design = np.zeros((3 * n, 4))
    design[:, 0] = f_body.ravel()
    for axis in range(3):
        design[axis::3, 1 + axis] = 1.0
    sol, *_ = np.linalg.lstsq(design, a.ravel(), rcond=None)
    res = a.ravel() - design @ sol
    dof = max(3 * n - 4, 1)
    sigma2 = float(res @ res) / dof
    cov = sigma2 * np.linalg.inv(design.T @ design)
    return AccelerometerFit(bias_mps2=sol[1:4], bias_std_mps2=np.sqrt(np.diag(cov)[1:4]),
                            inverse_mass_per_kg=float(sol[0]), samples=n,
                            residual_rms_mps2=float(np.sqrt(np.mean(res**2))))


def _gap_bridge(records: list[Measurement], j: int, imu: ImuStream, bias_mps2: np.ndarray, period_s: float
                ) -> tuple[np.ndarray, int] | None:
    """Mean world-frame specific force (bias removed) over the interval after input-only record ``j`` whose input is
    unknown, and the number of readings; the attitude at each reading is interpolated (slerp) between the measured
    records around the gap. None without a reading or a measured record on each side."""
    t0, t1 = records[j].t, records[j + 1].t
    if t1 - t0 > 1.5 * period_s + 1e-9:
        return None  # several inputs lost: the interval is cut, not bridged (alignment, batch)
    tol = 1e-9
    t = np.asarray(imu.t, float)
    inside = np.flatnonzero((t >= t0 - tol) & (t < t1 - tol))
    before = next((i for i in range(j, -1, -1) if records[i].state_measured), None)
    after = next((i for i in range(j + 1, len(records)) if records[i].state_measured), None)
    if inside.size == 0 or before is None or after is None:
        return None
    a, b = records[before], records[after]
    s = np.clip((t[inside] - a.t) / (b.t - a.t), 0.0, 1.0)
    q = np.atleast_2d(quat.slerp(a.x_measured[6:10], b.x_measured[6:10], s))
    f_body = np.asarray(imu.specific_force_mps2, float)[inside] - bias_mps2
    f_world = np.einsum("nij,nj->ni", quat.to_rotation_matrix(q), f_body)
    return f_world.mean(axis=0), int(inside.size)


def attach_accelerations(
    records: list[Measurement], imu: ImuStream, bias_mps2: np.ndarray, t_inputs: np.ndarray, period_s: float
) -> tuple[list[Measurement], int]:
    """Give each measured record the first reading at or after its stamp under the same input, bias removed and
    rotated into the world frame by the record's measured attitude.

    An input-only record whose own input is unknown (a lost control record: the next record starts a segment,
    :mod:`oacli.estimation.alignment`) gets instead the **mean of every reading over its interval** (one control
    period; attitudes interpolated between the measured records around the gap) and their number
    (``Measurement.acceleration_readings``): the accelerometer measures the lost force as ``f/m``, so the batch
    estimator bridges the gap with it instead of predicting the force from the neighbouring inputs
    (:func:`oacli.estimation.batch.lost_input_model`). The IMU is a separate stream: losing a controller record
    does not lose its readings.

    Parameters
    ----------
    records : list of Measurement
    imu : ImuStream
    bias_mps2 : ndarray, shape (3,)
        Accelerometer bias to subtract (body frame).
    t_inputs : ndarray
        Stamps of the logged inputs (applied or commanded) [s].
    period_s : float
        Control period [s].

    Returns
    -------
    records : list of Measurement
        Copies with ``linear_acceleration_mps2`` set where a reading exists (and the gap bridges).
    missing : int
        Measured records left without a reading.
    """
    t = np.asarray(imu.t, float)
    idx = _interval_of(records, t, t_inputs, period_s)
    first: dict[int, int] = {}
    for i, j in enumerate(idx):
        if j >= 0 and j not in first:
            first[int(j)] = i
    out: list[Measurement] = []
    missing = 0
    for j, rec in enumerate(records):
        found = first.get(j)
        if not rec.state_measured and j + 1 < len(records) and records[j + 1].starts_segment:
            bridge = _gap_bridge(records, j, imu, np.asarray(bias_mps2, float), period_s)
            if bridge is not None:
                out.append(replace(rec, linear_acceleration_mps2=bridge[0], acceleration_readings=bridge[1]))
                continue
        if found is None:
            missing += rec.state_measured
            out.append(rec)
            continue
        i = found
        q = _attitude_at(records, np.array([j]), t[i:i + 1])[0]
        a_world = quat.to_rotation_matrix(q) @ (np.asarray(imu.specific_force_mps2[i], float) - bias_mps2)
        out.append(replace(rec, linear_acceleration_mps2=a_world))
    return out, missing
