"""Cramér-Rao bounds of the inertial parameters along an estimated trajectory (Doerr Eq. 29).

The Fisher information of θ is built with the measurement model and the sensitivity conventions of
:mod:`oacli.excitation.information` (``F = Σ_k G_kᵀ R⁻¹ G_k``, ``G_k = H_k S_k``), with two differences that make the
bound the right yardstick for the estimators of this package:

* the sensitivities ``S_k = ∂x_k/∂[x_0, θ]`` follow the estimators' exact multi-rate process model
  (:mod:`oacli.estimation.propagation`), linearised about the *estimated* states ``x̂_k`` and θ̂, and are carried
  in the tangent chart of each state, so that the sign convention of the quaternions (the simulator keeps
  ``w >= 0`` and flips ``q`` when ``w`` crosses zero) cannot enter;
* the initial state is unknown to the estimators, so it enters as a nuisance parameter: the bound on θ is the
  Schur complement ``F_θθ − F_θx F_xx⁻¹ F_xθ`` of the joint information of ``[δx_0, θ]``. The bound of
  :func:`oacli.excitation.information.fisher_information`, which assumes ``x_0`` known, is reported beside it
  (``std_known_initial_state``); it is lower, and no estimator that must find ``x_0`` can reach it.

Both bounds assume the dynamics exact (no process noise), i.e. the output-error model of the simulator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from oacli.estimation.manifold import TANGENT_DIM, lift_matrix, project_matrix
from oacli.estimation.models import MeasurementModel, measured_rows
from oacli.estimation.propagation import dynamics_jacobians_batch, propagate_intervals_structured, substep_schedule
from oacli.excitation.information import PARAM_NAMES, cramer_rao_std, unidentifiable_parameters

__all__ = ["CramerRaoBound", "cramer_rao_bound", "unobservable_parameters"]

_ACCEL_ROWS = np.r_[3:6, 10:13]
N_PARAMS = 4


@dataclass(frozen=True)
class CramerRaoBound:
    """Cramér-Rao bounds of θ = [m, Ixx, Iyy, Izz] from one data set.

    Attributes
    ----------
    std : ndarray, shape (4,)
        ``sqrt(diag F_eff⁻¹)`` with the initial state unknown (``inf`` where unidentifiable).
    std_known_initial_state : ndarray, shape (4,)
        ``sqrt(diag F_θθ⁻¹)`` with the initial state known (information.py's bound).
    information : ndarray, shape (4, 4)
        ``F_eff``, the information on θ left after estimating the initial state.
    information_known_initial_state : ndarray, shape (4, 4)
        ``F_θθ``.
    """

    std: np.ndarray
    std_known_initial_state: np.ndarray
    information: np.ndarray
    information_known_initial_state: np.ndarray


def cramer_rao_bound(
    t: np.ndarray,
    states: np.ndarray,
    u: np.ndarray,
    theta: np.ndarray,
    model: MeasurementModel,
    substep_s: float,
    *,
    used: np.ndarray | None = None,
    accelerations_measured: bool = False,
    segment_starts: np.ndarray | None = None,
) -> CramerRaoBound:
    """Cramér-Rao bounds of θ from measuring ``states`` at times ``t`` (see the module docstring).

    Parameters
    ----------
    t : ndarray, shape (K,)
        Record times [s], strictly increasing.
    states : ndarray, shape (K, 13)
        Estimated states ``x̂_k`` (linearisation points).
    u : ndarray, shape (K, 6)
        Inputs held from ``t_k`` to ``t_{k+1}``.
    theta : ndarray, shape (4,)
        θ̂ [kg, kg·m²].
    model : MeasurementModel
        Measured quantities and noise (as used by the estimator).
    substep_s : float
        Integration grid [s].
    used : ndarray of bool, shape (K,), optional
        Records that count (e.g. the inliers of the χ² gate); default all.
    accelerations_measured : bool
        Count the model's acceleration measurements (only when the records carry them).
    segment_starts : ndarray of bool, shape (K,), optional
        Records after a gap in the inputs (:mod:`oacli.estimation.alignment`): the process model does not link
        them to the previous record, so each segment has its own unknown initial state. The information about θ
        of the segments adds up (each segment's initial state eliminated separately).

    Returns
    -------
    CramerRaoBound
    """
    t = np.asarray(t, dtype=float)
    states = np.asarray(states, dtype=float)
    theta = np.asarray(theta, dtype=float)
    k = t.shape[0]
    used = np.ones(k, dtype=bool) if used is None else np.asarray(used, dtype=bool)
    starts = np.flatnonzero(np.asarray(segment_starts, dtype=bool)) if segment_starts is not None else np.zeros(0)
    starts = np.union1d(starts, [0]).astype(int)
    if starts.size > 1:
        bounds = [
            cramer_rao_bound(t[a:b], states[a:b], np.asarray(u)[a:b], theta, model, substep_s, used=used[a:b],
                             accelerations_measured=accelerations_measured)
            for a, b in zip(starts, [*starts[1:], k], strict=True) if np.any(used[a:b])
        ]
        f_eff: np.ndarray = np.sum([bd.information for bd in bounds], axis=0)
        f_tt: np.ndarray = np.sum([bd.information_known_initial_state for bd in bounds], axis=0)
        return CramerRaoBound(std=cramer_rao_std(f_eff, theta), std_known_initial_state=cramer_rao_std(f_tt, theta),
                              information=f_eff, information_known_initial_state=f_tt)
    state_rows, accel_rows = measured_rows(model)
    w_state = np.sqrt(model.state_weights[state_rows])
    if not accelerations_measured:
        accel_rows = accel_rows[:0]
    w_accel = np.sqrt(model.acceleration_weights[accel_rows])
    n = TANGENT_DIM + N_PARAMS
    # Sensitivities in the tangent chart of each state (so the quaternion's sign convention cannot matter):
    # S_k = ∂(x_k ⊟ x̂_k)/∂[δx_0, θ] (12, 16), S_0 = [I | 0], S_{k+1} = P(x⁺) A_k L(x̂_k) S_k + [0 | P(x⁺) C_k] with
    # x⁺ = f(x̂_k); there the measurement Jacobian H L = I (information.py's H for a unit quaternion).
    sens = np.zeros((k, TANGENT_DIM, n))
    sens[0, :, 0:TANGENT_DIM] = np.eye(TANGENT_DIM)
    if k > 1:
        durations = substep_schedule(t[:-1], t[1:], substep_s)
        x_next, a, c = propagate_intervals_structured(states[:-1], u[:-1], theta, durations)
        proj = project_matrix(x_next)
        a_t = proj @ a @ lift_matrix(states[:-1])
        c_t = proj @ c
        for i in range(k - 1):
            sens[i + 1] = a_t[i] @ sens[i]
            sens[i + 1, :, TANGENT_DIM:] += c_t[i]
    info = np.zeros((n, n))
    for i in np.flatnonzero(used):  # type: ignore[assignment]
        g = sens[i][state_rows] * w_state[:, None]
        info += g.T @ g
    if accel_rows.size:
        jac = dynamics_jacobians_batch(states, u, theta)[:, _ACCEL_ROWS]
        lifts = lift_matrix(states)
        for i in np.flatnonzero(used):  # type: ignore[assignment]
            g = jac[i, :, 0:13] @ lifts[i] @ sens[i]
            g[:, TANGENT_DIM:] += jac[i, :, 13:]
            g = g[accel_rows] * w_accel[:, None]
            info += g.T @ g
    # Gauge: unmeasured components of x_0 (offsets that do not affect θ) get unit information.
    for row in np.setdiff1d(np.arange(TANGENT_DIM), state_rows):
        info[row, row] += 1.0
    f_xx = info[:TANGENT_DIM, :TANGENT_DIM]
    f_xt = info[:TANGENT_DIM, TANGENT_DIM:]
    f_tt = info[TANGENT_DIM:, TANGENT_DIM:]
    f_eff = f_tt - f_xt.T @ np.linalg.solve(f_xx, f_xt)
    f_eff = 0.5 * (f_eff + f_eff.T)
    return CramerRaoBound(
        std=cramer_rao_std(f_eff, theta),
        std_known_initial_state=cramer_rao_std(f_tt, theta),
        information=f_eff,
        information_known_initial_state=f_tt,
    )


def unobservable_parameters(
    bound: CramerRaoBound, theta: np.ndarray, max_relative_std: float
) -> list[tuple[str, float]]:
    """Parameters the data cannot determine.

    A parameter is listed when it is unidentifiable (null space of the information) or when its bound exceeds
    ``max_relative_std`` of its value.

    Parameters
    ----------
    bound : CramerRaoBound
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz].
        The values the relative bounds refer to.
    max_relative_std : float
        Largest acceptable relative standard deviation.

    Returns
    -------
    list of (str, float)
        ``(name, relative Cramér-Rao std)`` per listed parameter.
    """
    theta = np.asarray(theta, dtype=float)
    rel = bound.std / np.abs(theta)
    null = set(unidentifiable_parameters(bound.information, theta))
    out: list[tuple[str, float]] = []
    for i, name in enumerate(PARAM_NAMES):
        if name in null or not np.isfinite(rel[i]) or rel[i] > max_relative_std:
            out.append((name, float(rel[i])))
    return out


def describe_unobservable(items: Sequence[tuple[str, float]], max_relative_std: float) -> str:
    """One line naming the unobservable parameters and their relative bounds.

    Parameters
    ----------
    items : sequence of (str, float)
        As from :func:`unobservable_parameters`.
    max_relative_std : float

    Returns
    -------
    str
    """
    parts = [f"{name} (Cramér-Rao bound {'∞' if not np.isfinite(r) else f'{100 * r:.3g} %'})" for name, r in items]
    return (
        f"unobservable from this telemetry: {', '.join(parts)}; the limit is {100 * max_relative_std:g} % of the "
        "value"
    )
