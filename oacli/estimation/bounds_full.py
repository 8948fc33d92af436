"""Cramér-Rao bound of the full rigid body's estimated parameters along an estimated trajectory ([Doerr2021] Eq. 29).

:func:`oacli.estimation.bounds.cramer_rao_bound` for a chosen part of the full rigid body
(:class:`oacli.estimation.batch_model.FullModel`): the Fisher information ``F = Σ_k G_kᵀ R⁻¹ G_k`` of
``[δx_0, θ_est]`` with the sensitivities ``S_k = ∂x_k/∂[x_0, θ]`` of the full process model
(:func:`oacli.estimation.rigid_dynamics.propagate_full`), linearised about the estimated states and θ̂, the initial
state of each segment eliminated as a nuisance parameter (Schur complement).

The data cannot separate a common factor of the force scale and the mass, nor (but for the gyroscopic term) of the
torque scale and the inertia (docs/estimation.md): without a prior the information is singular. The bound is
therefore a hybrid one: the prior information of the entries *other than* mass and inertia (centre of mass,
products, scales: what is known about the robot before the run) is added; mass and inertia are bounded by the data
alone. Every gap in the input record cuts the run (a segment's initial state is unknown), a conservative choice
where the estimators bridge a lost control record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.estimation.batch_model import FullModel
from oacli.estimation.manifold import TANGENT_DIM, lift_matrix, project_matrix
from oacli.estimation.models import MeasurementModel, measured_rows
from oacli.estimation.propagation import substep_schedule

__all__ = ["FullBound", "cramer_rao_bound_full"]


@dataclass(frozen=True)
class FullBound:
    """Cramér-Rao bound of the estimated entries of the full θ.

    Attributes
    ----------
    index : ndarray of int, shape (n,)
        θ indices of the estimated entries (:data:`oacli.estimation.rigid_parameters.FULL_NAMES`).
    std : ndarray, shape (n,)
        ``sqrt(diag F_eff⁻¹)`` (``inf`` where unidentifiable) [SI units of each entry].
    information : ndarray, shape (n, n)
        ``F_eff``: the information on θ_est left after the initial states, prior on the entries beyond m and I.
    """

    index: np.ndarray
    std: np.ndarray
    information: np.ndarray


def cramer_rao_bound_full(
    t: np.ndarray, states: np.ndarray, u: np.ndarray, theta: np.ndarray, model: FullModel,
    measurement: MeasurementModel, substep_s: float, *, used: np.ndarray | None = None,
    accelerations_measured: bool = False, segment_starts: np.ndarray | None = None,
) -> FullBound:
    """The bound of the module docstring.

    Parameters
    ----------
    t : ndarray, shape (K,)
        Record times [s], strictly increasing.
    states : ndarray, shape (K, 13)
        Estimated states (linearisation points).
    u : ndarray, shape (K, 6)
        Commanded inputs held from ``t_k`` to ``t_{k+1}``.
    theta : ndarray, shape (16,)
        θ̂ of the full rigid body.
    model : FullModel
        The estimated entries and their prior.
    measurement : MeasurementModel
        Measured quantities and noise (as the estimator uses them).
    substep_s : float
        Integration grid [s].
    used : ndarray of bool, shape (K,), optional
        Records that count (the χ² gate's inliers); default all.
    accelerations_measured : bool
        Count the model's acceleration measurements.
    segment_starts : ndarray of bool, shape (K,), optional
        Records after a gap in the inputs: the run is cut there.

    Returns
    -------
    FullBound
    """
    t = np.asarray(t, dtype=float)
    states = np.asarray(states, dtype=float)
    u = np.asarray(u, dtype=float).reshape(-1, 6)
    theta = np.asarray(theta, dtype=float)
    k = t.size
    idx = model.params.index
    n = idx.size
    used = np.ones(k, dtype=bool) if used is None else np.asarray(used, dtype=bool)
    starts_mask = np.zeros(k, dtype=bool)
    if segment_starts is not None:
        starts_mask |= np.asarray(segment_starts, dtype=bool)
    starts_mask[0] = True
    starts = np.flatnonzero(starts_mask)
    state_rows, accel_rows = measured_rows(measurement)
    w_state = np.sqrt(measurement.state_weights[state_rows])
    if not accelerations_measured:
        accel_rows = accel_rows[:0]
    w_accel = np.sqrt(measurement.acceleration_weights[accel_rows])
    f_eff = np.zeros((n, n))
    for a, b in zip(starts, [*starts[1:], k], strict=True):
        if not np.any(used[a:b]):
            continue
        m = b - a
        sens = np.zeros((m, TANGENT_DIM, TANGENT_DIM + n))
        sens[0, :, 0:TANGENT_DIM] = np.eye(TANGENT_DIM)
        if m > 1:
            durations = substep_schedule(t[a:b - 1], t[a + 1:b], substep_s)
            x_next, a_mat, c_mat = model.propagate(states[a:b - 1], u[a:b - 1], theta, durations)
            assert a_mat is not None and c_mat is not None
            proj = project_matrix(x_next)
            a_t = proj @ a_mat @ lift_matrix(states[a:b - 1])
            c_t = proj @ c_mat[:, :, idx]
            for i in range(m - 1):
                sens[i + 1] = a_t[i] @ sens[i]
                sens[i + 1, :, TANGENT_DIM:] += c_t[i]
        info = np.zeros((TANGENT_DIM + n, TANGENT_DIM + n))
        for r in np.flatnonzero(used[a:b]):
            g = sens[r][state_rows] * w_state[:, None]
            info += g.T @ g
        if accel_rows.size:
            _, jx, jth = model.accelerations(states[a:b], u[a:b], theta)
            assert jx is not None and jth is not None
            lifts = lift_matrix(states[a:b])
            for r in np.flatnonzero(used[a:b]):
                g = jx[r] @ lifts[r] @ sens[r]
                g[:, TANGENT_DIM:] += jth[r][:, idx]
                g = g[accel_rows] * w_accel[:, None]
                info += g.T @ g
        for row in np.setdiff1d(np.arange(TANGENT_DIM), state_rows):  # gauge, as bounds.py
            info[row, row] += 1.0
        f_xx, f_xt, f_tt = info[:TANGENT_DIM, :TANGENT_DIM], info[:TANGENT_DIM, TANGENT_DIM:], info[TANGENT_DIM:,
                                                                                                     TANGENT_DIM:]
        try:
            f_eff += f_tt - f_xt.T @ np.linalg.solve(f_xx, f_xt)
        except np.linalg.LinAlgError:
            f_eff += f_tt - f_xt.T @ np.linalg.lstsq(f_xx, f_xt, rcond=None)[0]
    beyond = idx >= 4  # the prior of the entries other than mass and inertia
    prior_var = np.diag(model.prior_cov)[idx]
    f_eff[beyond, beyond] += 1.0 / prior_var[beyond]
    f_eff = 0.5 * (f_eff + f_eff.T)
    try:
        cov = np.linalg.inv(f_eff)
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        if not np.all(np.isfinite(std)) or np.any(np.diag(cov) <= 0):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        std = np.full(n, np.inf)
    return FullBound(index=idx, std=std, information=f_eff)
