"""Is the actuator linear over the commands the calibration flights used? A test for a saturating impeller.

The calibration ([ReSWARM2023] Eqs. 38-39; :mod:`oacli.mission.calibration`) fits one scale per axis,
``delivered = κ ⊙ commanded``. An impeller that saturates below the robot's limit (``faults.actuator_saturation``:
it delivers at most a fraction of the limit, [ReSWARM2023] §6.2.1 "input saturation") breaks that model for the large
commands only: the fit averages the clipped response into κ, which comes out a few per cent low with a σ that knows
nothing of it (a flight-fault campaign run: κ_x 0.999 ± 0.003 for a true 1.036, z −11.9, handed on). The χ² does not
see it (that run's sensor noise was dispersed below the modelled), nor does the prior check (3.6 % is inside the 5 %
prior), nor the comparison of the two flights (both clipped).

This module asks the telemetry of the known robot's flights whether the response is clipped above some level. For a
level ``s`` (a fraction of the robot's limit, scanned over :data:`LEVELS`) and an axis, the commanded excess beyond
it, ``e = sign(u) max(|u| − s L, 0)``, is a regressor the linear model does not have; a saturation at ``s`` makes its
coefficient δ ≈ −1 (the excess is not delivered), a linear actuator δ = 0.

* **Force, world axis j** (the fault clips the applied world force per axis): the measured positions and velocities
  of every flight, all three world axes at once, are regressed on their initial values, the double (position) and
  single (velocity) integrals of ``R_ji κ_i (Rᵀ f)_i / m`` (the body-axis scales κ shared by the flights and axes,
  ``R`` the measured attitude, ``m`` the known mass, zero-order hold; [Doerr2021] Eq. 33) and those of ``e / m`` on
  axis j (κ ≈ 1 there: the test needs the sign, not the few per cent).
* **Torque, body axis b**: the measured rates on their initial values and the integrals of ``κ_b τ_b / I_b``, of the
  gyroscopic term, of the centre-of-mass torque ``(c × F_body)_b / I_b`` (c unknown, three regressors) and of
  ``e / I_b`` ([Doerr2021] Eq. 35b).

Rows are weighted by the sensors' σ and fitted by least squares with a robust gate (residuals beyond
:data:`GATE_SIGMAS` robust σ dropped, then refitted: localisation jumps); ``z = δ / σ_δ`` (σ from the residuals'
own scatter). The smallest z over the levels is the axis's finding, and ``z < −`` :data:`Z_SATURATION` refuses the
calibration. A level that fewer than :data:`MIN_SAMPLES` commands exceed is not tested (no information, and a clip
that few commands reach does not bias κ much).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from oacli.model import quaternion as quat
from oacli.types import Telemetry

GATE_SIGMAS = 4.0
"""Residuals beyond this many robust σ (1.4826 × the median absolute deviation) are dropped before the refit."""

Z_SATURATION = 4.0
"""A clip ``z = δ/σ_δ`` below ``−Z_SATURATION`` at some level refuses the calibration (one-sided: a saturation
delivers less, never more)."""

LEVELS = tuple(np.round(np.arange(0.5, 0.96, 0.05), 2))
"""Saturation levels tested, as fractions of the robot's limit per axis."""

MIN_SAMPLES = 5
"""A level that fewer commands exceed is not tested."""

NOISE_FLOORS = (1e-3, 5e-4, 1e-3)
"""Smallest σ of position [m], velocity [m/s] and rate [rad/s] the rows are weighted with: the regression's own
approximations (the attitude held over a control step, κ ≈ 1 in the excess term) stay below them."""

AXES = ("force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z")
"""Forces in the world frame (as applied), torques in the body frame."""


@dataclass(frozen=True)
class AxisLinearity:
    """The strongest clip found on one actuator axis.

    Attributes
    ----------
    axis : str
        One of :data:`AXES`.
    z : float
        The smallest ``δ / σ_δ`` over the tested levels (nan: no level tested).
    level : float
        The level of that z, fraction of the robot's limit (nan: none).
    peak_fraction : float
        The largest command over the flights as a fraction of the robot's limit.
    """

    axis: str
    z: float
    level: float
    peak_fraction: float

    @property
    def saturating(self) -> bool:
        """The response is clipped significantly (``z < −Z_SATURATION``)."""
        return bool(np.isfinite(self.z) and self.z < -Z_SATURATION)

    def describe(self) -> str:
        """One plain sentence."""
        return (f"{self.axis} is delivered less than commanded above {self.level:.2f} of its limit (clip z "
                f"{self.z:.1f} < −{Z_SATURATION:g}; commands up to {self.peak_fraction:.2f} of it)")


@dataclass(frozen=True)
class _Flight:
    t: np.ndarray
    dt: np.ndarray
    x: np.ndarray
    u: np.ndarray
    rot: np.ndarray
    f_body: np.ndarray


def _flight(tel: Telemetry) -> _Flight:
    t = np.asarray(tel.t_ctrl, dtype=float)
    x = np.array(tel.x_measured, dtype=float)[: t.size]
    u = np.asarray(tel.u_applied, dtype=float)[: t.size]
    q = quat.normalize(x[:, 6:10])
    # A localisation jump corrupts one record's attitude: where a record is far from both neighbours that agree,
    # take the previous one (the attitude enters every later integral through R).
    for k in range(1, len(q) - 1):
        a, b, c = q[k - 1], q[k], q[k + 1]
        if abs(a @ c) > np.cos(0.02) and abs(a @ b) < np.cos(0.02) and abs(b @ c) < np.cos(0.02):
            q[k] = a
    rot = quat.to_rotation_matrix(q)
    return _Flight(t, np.append(np.diff(t), 0.0), x, u, rot, np.einsum("kji,kj->ki", rot, u[:, 0:3]))


def _integrals(acc: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and position at the control instants from rest under piecewise-constant ``acc`` held ``dt``."""
    v = np.concatenate([[0.0], np.cumsum(acc[:-1] * dt[:-1])])
    p = np.concatenate([[0.0], np.cumsum(v[:-1] * dt[:-1] + 0.5 * acc[:-1] * dt[:-1] ** 2)])
    return v, p


def _robust_z(a: np.ndarray, y: np.ndarray) -> float:
    """``x[-1] / σ`` of the least-squares fit ``y ≈ a x`` after :data:`GATE_SIGMAS` gating."""
    keep = np.isfinite(y) & np.all(np.isfinite(a), axis=1)
    x = np.zeros(a.shape[1])
    for _ in range(5):
        x, *_ = np.linalg.lstsq(a[keep], y[keep], rcond=None)
        r = y - a @ x
        sigma = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        new = np.isfinite(r) & (np.abs(r) <= GATE_SIGMAS * max(sigma, 1e-15))
        if np.array_equal(new, keep):
            break
        keep = new
    r = (y - a @ x)[keep]
    dof = int(keep.sum()) - a.shape[1]
    if dof < 1:
        return float("nan")
    # The rows are weighted by the sensors' σ: a scatter below 1 is not believed (ideal sensors, floors below).
    cov = max(float(r @ r) / dof, 1.0) * np.linalg.pinv(a[keep].T @ a[keep])
    std = float(np.sqrt(max(cov[-1, -1], 0.0)))
    return float(x[-1] / std) if std > 0 else float("nan")


def _force_system(flights: Sequence[_Flight], mass: float, pos_std: float, vel_std: float) -> tuple[list, np.ndarray]:
    """Rows (positions and velocities, three world axes, every flight) on the initial states and the shared κ."""
    blocks, ys = [], []
    n_init = 6 * len(flights)
    for fi, fl in enumerate(flights):
        k = fl.t.size
        for j in range(3):
            vel_cols, pos_cols = np.zeros((k, n_init + 3)), np.zeros((k, n_init + 3))
            pos_cols[:, 6 * fi + 2 * j] = 1.0
            pos_cols[:, 6 * fi + 2 * j + 1] = fl.t - fl.t[0]
            vel_cols[:, 6 * fi + 2 * j + 1] = 1.0
            for i in range(3):
                v, p = _integrals(fl.rot[:, j, i] * fl.f_body[:, i] / mass, fl.dt)
                vel_cols[:, n_init + i], pos_cols[:, n_init + i] = v, p
            blocks.append((fi, j, "p", pos_cols / pos_std))
            blocks.append((fi, j, "v", vel_cols / vel_std))
            ys += [fl.x[:, j] / pos_std, fl.x[:, 3 + j] / vel_std]
    return blocks, np.concatenate(ys)


def actuator_linearity(tels: Sequence[Telemetry], mass_kg: float, inertia_kgm2: np.ndarray,
                       input_limits: np.ndarray, noise_std: Sequence[float]) -> list[AxisLinearity]:
    """The strongest clip on each actuator axis over the known robot's flights (module docstring).

    Parameters
    ----------
    tels : sequence of Telemetry
        The flights (``t_ctrl``, ``x_measured``, ``u_applied``: world force [N], body torque [N·m]).
    mass_kg : float
        The known robot's mass [kg].
    inertia_kgm2 : ndarray, shape (3,)
        Its principal inertias [kg·m²].
    input_limits : ndarray, shape (6,)
        The robot's force [N] and torque [N·m] limits.
    noise_std : sequence of float
        Measurement σ of position [m], velocity [m/s] and angular velocity [rad/s] (row weights; at least
        :data:`NOISE_FLOORS`).

    Returns
    -------
    list of AxisLinearity
        One per :data:`AXES`.
    """
    flights = [_flight(t) for t in tels if np.asarray(t.t_ctrl).size > 10]
    lim = np.asarray(input_limits, dtype=float)
    inertia = np.asarray(inertia_kgm2, dtype=float)
    pos_std, vel_std, rate_std = (max(float(v), f) for v, f in zip(noise_std, NOISE_FLOORS, strict=True))
    blocks, y = _force_system(flights, mass_kg, pos_std, vel_std)
    base = np.vstack([b[3] for b in blocks])
    out: list[AxisLinearity] = []
    for axis, name in enumerate(AXES):
        peak = max(float(np.max(np.abs(fl.u[:, axis]))) for fl in flights) / lim[axis]
        best, best_level = float("nan"), float("nan")
        for level in LEVELS:
            excess = [np.sign(fl.u[:, axis]) * np.maximum(np.abs(fl.u[:, axis]) - level * lim[axis], 0.0)
                      for fl in flights]
            if sum(int(np.count_nonzero(e)) for e in excess) < MIN_SAMPLES:
                continue
            if axis < 3:
                col = []
                for fi, j, kind, _ in blocks:
                    v, p = _integrals(excess[fi] / mass_kg, flights[fi].dt)
                    col.append(np.zeros(v.size) if j != axis else (p / pos_std if kind == "p" else v / vel_std))
                z = _robust_z(np.column_stack([base, np.concatenate(col)]), y)
            else:
                z = _robust_z(*_torque_system(flights, axis - 3, inertia, excess, rate_std))
            if np.isfinite(z) and not z >= best:
                best, best_level = z, float(level)
        out.append(AxisLinearity(name, best, best_level, peak))
    return out


def _torque_system(flights: Sequence[_Flight], b: int, inertia: np.ndarray, excess: Sequence[np.ndarray],
                   rate_std: float) -> tuple[np.ndarray, np.ndarray]:
    """Rate rows of body axis b (every flight) on the initial rate, κ_b, the CoM torque, gyroscopic term, excess."""
    n = len(flights)
    rows, ys = [], []
    for fi, fl in enumerate(flights):
        k = fl.t.size
        omega = fl.x[:, 10:13]
        gyro = -np.cross(omega, inertia * omega)[:, b] / inertia[b]
        cols = np.zeros((k, n + 6))
        cols[:, fi] = 1.0
        cols[:, n] = _integrals(fl.u[:, 3 + b] / inertia[b], fl.dt)[0]
        cols[:, n + 1] = _integrals(gyro, fl.dt)[0]
        for i in range(3):  # (e_i × F_body)_b, zero for i = b
            cols[:, n + 2 + i] = _integrals(np.cross(np.eye(3)[i][None, :], fl.f_body)[:, b] / inertia[b], fl.dt)[0]
        cols[:, n + 5] = _integrals(excess[fi] / inertia[b], fl.dt)[0]
        rows.append(cols / rate_std)
        ys.append(omega[:, b] / rate_std)
    a = np.vstack(rows)
    used = np.any(a != 0.0, axis=0)
    used[-1] = True
    return a[:, used], np.concatenate(ys)
