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
``residual_rms_mps2``. At the measured records the gyro is not used: the localisation's angular rate (Astrobee's
EKF output, its gyro bias already removed) is the rate measurement.

**Lost controller records.** The IMU is a stream of its own: a lost controller record (measurement, input and
command of one control step) leaves its readings in the log. Over the lost control period the accelerometer
measures the unknown force as ``f/m``; :func:`attach_accelerations` gives the lost instant's input-only record the
mean of those readings and their number, and the batch estimator bridges the gap with it
(:func:`oacli.estimation.lost_inputs.lost_input_model`): on the benchmark's gapped ISS runs the mass bound drops from
0.88 % (force predicted from the neighbouring inputs) to 0.52 %.

**The gyro bridges a lost torque.** The lost torque ``τ`` is constant over its control period (zero-order hold), so
by [Doerr2021] Eq. 35b, ``J ω̇ = τ − ω × J ω``, the body rate is a straight line over the period to within the
change of the gyroscopic term (``~ω̇ ω ΔJ/J``: a few µrad/s over 0.2 s on the ISS runs), and so is it over every
other period: the rate is a continuous piecewise-linear function with its knots at the control instants. It is
fitted by least squares to the gyro's readings over the lost period and the neighbouring period on each side
(:func:`_gyro_window`; each period's slope free, so the neighbours' torques need no model and no ``J``), and the
lost period's mean ``ω̇`` is the difference of the fitted rates at its ends over ``T``, with the variance
``σ_g² cᵀ(XᵀX)⁻¹c`` of that contrast (``X`` the fit's hat-function design). A constant gyro bias cancels in it, so
it needs no estimate. The neighbours pin the rates at the lost period's ends: the variance is 0.45 times that of a
line fitted to the lost period's readings alone (``σ_g² / Σ(t_i − t̄)²``, this bridge before): on the benchmark's
gapped ISS runs (80 seeds) the median inertia bounds drop from 0.44 / 0.46 / 0.52 % to 0.39 / 0.40 / 0.45 % (the
bridges' noise was about half of their variance, seed 31); a neighbouring period that another lost
period's fit could also use is left out, so no reading enters two bridges and their errors stay independent (the
estimators and the bound take them so). ``σ_g²`` is not configured: it is the pooled variance of the residuals of
a line fit over every control period of the run (:func:`gyro_noise_variance`). The lost record gets that mean
``ω̇`` (``angular_acceleration_radps2``), its variance (``angular_acceleration_var_rad2ps4``) and the fitted rate at
its stamp in ``x_measured[10:13]`` (the point where the estimators evaluate the gyroscopic term); the estimators
integrate the measured ``ω̇`` across the gap instead of the torque
(:func:`oacli.estimation.lost_inputs.lost_input_model`).
Like the accelerometer's ``f/m``, it carries no inertia: the interval's rotation needs neither the torque nor ``J``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from oacli.estimation.models import Measurement
from oacli.model import quaternion as quat

__all__ = ["AccelerometerFit", "ImuStream", "attach_accelerations", "fit_accelerometer_bias", "gyro_noise_variance",
           "gyro_slopes"]


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


def _line_sums(s: np.ndarray, w: np.ndarray, group: np.ndarray, groups: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per group: readings ``n``, ``S_ss = Σ(s − s̄)²``, slope ``S_sw / S_ss`` (3), line value at ``s = 0`` (3)
    and residual sum of squares (3) of the least-squares line ``w ≈ a + b s``."""
    n = np.bincount(group, minlength=groups).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        s_mean = np.bincount(group, s, minlength=groups) / n
        w_mean = np.stack([np.bincount(group, w[:, i], minlength=groups) for i in range(3)], axis=1) / n[:, None]
        ds = s - s_mean[group]
        dw = w - w_mean[group]
        s_ss = np.bincount(group, ds * ds, minlength=groups)
        s_sw = np.stack([np.bincount(group, ds * dw[:, i], minlength=groups) for i in range(3)], axis=1)
        s_ww = np.stack([np.bincount(group, dw[:, i] ** 2, minlength=groups) for i in range(3)], axis=1)
        slope = s_sw / s_ss[:, None]
        at_zero = w_mean - slope * s_mean[:, None]
        rss = s_ww - slope * s_sw
    return n, s_ss, slope, at_zero, rss


def gyro_noise_variance(records: list[Measurement], imu: ImuStream, period_s: float) -> float | None:
    """The gyro's white-noise variance per axis [rad²/s²], from the data: the pooled residual variance of a line
    fitted to its readings over every control period between consecutive records (module docstring; the torque is
    held over each, [Doerr2021] Eq. 35b makes the rate a line to within the gyroscopic term's change).

    Parameters
    ----------
    records : list of Measurement
        Aligned records (strictly increasing stamps), measured or input-only.
    imu : ImuStream
    period_s : float
        Control period [s]: longer intervals (several lost instants) are left out.

    Returns
    -------
    float or None
        None with fewer than 10 degrees of freedom.
    """
    t_rec = np.array([r.t for r in records])
    t = np.asarray(imu.t, float)
    if t_rec.size < 2 or t.size < 3:
        return None
    k = np.searchsorted(t_rec, t + 1e-9, side="right") - 1
    ok = (k >= 0) & (k < t_rec.size - 1)
    k, t = k[ok], t[ok]
    w = np.asarray(imu.angular_rate_radps, float)[ok]
    short = np.diff(t_rec) <= 1.5 * period_s + 1e-9
    keep = short[k]
    k, t, w = k[keep], t[keep], w[keep]
    if k.size < 3:
        return None
    n, _, _, _, rss = _line_sums(t - t_rec[k], w, k, t_rec.size - 1)
    fit = n >= 3
    dof = 3.0 * float(np.sum(n[fit] - 2.0))
    if dof < 10:
        return None
    return float(np.sum(rss[fit])) / dof


def gyro_slopes(t_records: np.ndarray, imu: ImuStream) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gyro's least-squares rate slope ``ω̇`` over each interval between consecutive records ([Doerr2021]
    Eq. 35b: with the torque held the rate is a line to within the gyroscopic term's change); a constant gyro bias
    cancels in the slope.

    Parameters
    ----------
    t_records : ndarray, shape (K,)
        Strictly increasing record stamps [s].
    imu : ImuStream

    Returns
    -------
    slope : ndarray, shape (K - 1, 3)
        ``ω̇`` per interval [rad/s²] (NaN with fewer than 3 readings).
    s_ss : ndarray, shape (K - 1,)
        ``Σ(t − t̄)²`` of the interval's reading stamps [s²]: the slope's variance is the gyro's noise variance
        over it.
    count : ndarray, shape (K - 1,)
        Readings per interval.
    """
    t_rec = np.asarray(t_records, float)
    t = np.asarray(imu.t, float)
    groups = max(t_rec.size - 1, 0)
    k = np.searchsorted(t_rec, t + 1e-9, side="right") - 1
    ok = (k >= 0) & (k < groups)
    n, s_ss, slope, _, _ = _line_sums(t[ok] - t_rec[k[ok]], np.asarray(imu.angular_rate_radps, float)[ok], k[ok],
                                      groups)
    few = n < 3
    slope[few] = np.nan
    return slope, np.where(few, np.nan, s_ss), n


def _gyro_window(records: list[Measurement], j: int, lost: set[int], period_s: float) -> list[int]:
    """Record indices whose stamps are the knots of the rate fit around the lost interval ``[t_j, t_{j+1}]``: the
    interval itself and, on each side, the neighbouring control period when it is one period long (its torque held:
    a straight rate) and no other lost interval's fit reaches into it (so that no reading serves two bridges and
    their errors stay independent)."""
    short = 1.5 * period_s + 1e-9
    knots = [j, j + 1]
    if j >= 1 and records[j].t - records[j - 1].t <= short and not ({j - 1, j - 2} & lost):
        knots.insert(0, j - 1)
    if j + 2 < len(records) and records[j + 2].t - records[j + 1].t <= short and not ({j + 1, j + 2} & lost):
        knots.append(j + 2)
    return knots


def _gyro_bridge(records: list[Measurement], j: int, imu: ImuStream, variance: float, period_s: float,
                 lost: set[int] | None = None) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The gyro's mean ``ω̇`` (body frame) over the lost interval after input-only record ``j``, its variance per
    axis and the fitted rate at ``t_j`` (module docstring); None with fewer than 3 readings or a longer gap.

    The rate is fitted as a continuous piecewise-linear function of time with its knots at the record stamps
    (:func:`_gyro_window`: the lost interval and the neighbouring periods): each period's torque is held, so the rate
    is a line over it, and it is continuous at the switches ([Doerr2021] Eq. 35b). The lost interval's ``ω̇`` is the
    difference of the knot values at its ends over ``T``; the neighbours' readings fix those ends better than the
    interval's own (a variance ~0.45 times the single-interval line's with both neighbours), without any model of
    their torques (each period's slope is free)."""
    t0, t1 = records[j].t, records[j + 1].t
    if t1 - t0 > 1.5 * period_s + 1e-9:
        return None
    tol = 1e-9
    knots = _gyro_window(records, j, set() if lost is None else lost, period_s)
    t_knot = np.array([records[i].t for i in knots])
    t = np.asarray(imu.t, float)
    # Readings at an outer knot borrowed from a neighbour are left out (that stamp may end another bridge's fit).
    lo = t_knot[0] + (tol if knots[0] < j else -tol)
    hi = t_knot[-1] - (tol if knots[-1] > j + 1 else -tol)
    inside = np.flatnonzero((t >= lo) & (t <= hi))
    in_gap = np.count_nonzero((t[inside] >= t0 - tol) & (t[inside] <= t1 + tol))
    if in_gap < 3:
        return None
    design = np.stack([np.interp(t[inside], t_knot, np.eye(t_knot.size)[i]) for i in range(t_knot.size)], axis=1)
    gram = design.T @ design
    try:
        values = np.linalg.solve(gram, design.T @ np.asarray(imu.angular_rate_radps, float)[inside])
        cov = np.linalg.inv(gram)
    except np.linalg.LinAlgError:
        return None
    a, b = knots.index(j), knots.index(j + 1)
    contrast = np.zeros(t_knot.size)
    contrast[a], contrast[b] = -1.0 / (t1 - t0), 1.0 / (t1 - t0)
    return contrast @ values, float(variance) * float(contrast @ cov @ contrast), values[a]


def attach_accelerations(
    records: list[Measurement], imu: ImuStream, bias_mps2: np.ndarray, t_inputs: np.ndarray, period_s: float,
    *, gyro: bool = True,
) -> tuple[list[Measurement], int]:
    """Give each measured record the first reading at or after its stamp under the same input, bias removed and
    rotated into the world frame by the record's measured attitude.

    An input-only record whose own input is unknown (a lost control record: the next record starts a segment,
    :mod:`oacli.estimation.alignment`) gets instead the **mean of every reading over its interval** (one control
    period; attitudes interpolated between the measured records around the gap) and their number
    (``Measurement.acceleration_readings``): the accelerometer measures the lost force as ``f/m``, so the batch
    estimator bridges the gap with it instead of predicting the force from the neighbouring inputs
    (:func:`oacli.estimation.lost_inputs.lost_input_model`). The IMU is a separate stream: losing a controller record
    does not lose its readings. With ``gyro``, the same record also gets the gyro's mean ``ω̇`` over the interval
    (a continuous piecewise-linear fit of its readings over it and its neighbouring periods), its variance and the
    rate at its stamp: the gyro bridges the lost torque (module
    docstring, [Doerr2021] Eq. 35b).

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
    gyro : bool
        Bridge the lost torques with the gyro too (its noise measured on the run, :func:`gyro_noise_variance`).

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
    lost = [j for j, rec in enumerate(records)
            if not rec.state_measured and j + 1 < len(records) and records[j + 1].starts_segment]
    gyro_var = gyro_noise_variance(records, imu, period_s) if lost and gyro else None
    lost_set = set(lost)
    for j, rec in enumerate(records):
        found = first.get(j)
        if lost and j == lost[0]:
            lost.pop(0)
            bridge = _gap_bridge(records, j, imu, np.asarray(bias_mps2, float), period_s)
            turn = None if gyro_var is None else _gyro_bridge(records, j, imu, max(gyro_var, 1e-16), period_s,
                                                              lost_set)
            changes: dict = {}
            if bridge is not None:
                changes.update(linear_acceleration_mps2=bridge[0], acceleration_readings=bridge[1])
            if turn is not None:
                x_seed = np.array(rec.x_measured, dtype=float)
                x_seed[10:13] = turn[2]
                changes.update(angular_acceleration_radps2=turn[0], angular_acceleration_var_rad2ps4=turn[1],
                               x_measured=x_seed)
            if changes:
                out.append(replace(rec, **changes))
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
