"""Cramér-Rao bounds of the inertial parameters along an estimated trajectory ([Doerr2021] Eq. 29).

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

**Gaps in the input record** (lost controller records, :mod:`oacli.estimation.alignment`). Where the batch estimator
bridges a gap, the wrench held over it is unknown; the bound carries it as a nuisance parameter ``w = [f/m, τ]`` (6
per gap) that moves the state after the gap along the estimator's directions, with the prior the estimator gives it
(its neighbours' regression, or the accelerometer's mean for ``f/m`` and the gyro's slope for ``τ``:
:func:`oacli.estimation.lost_inputs.lost_input_model`)
-- a hybrid bound (``w`` random, θ and the initial state fixed) that the batch's covariance estimates; ``w`` without a
prior (``lost_inputs="nuisance"``) and every gap cut (``"cut"``, the bound this module gave before) are available for
comparison. On the benchmark's gapped ISS runs (10 % of the controller records lost, ``benchmarks/bench_estimation.py``)
the mass bound is 0.88 % with the prior, 1.9 % without it and 2.0 % with every gap cut, against 0.154 % clean; even
an oracle that knew the controller and the true states (only the lost record's own measurement noise unpredictable,
~36 mN per axis) would be bounded at 0.87-0.97 % on three seeds, so the median error of an efficient estimator
(0.674 σ) cannot reach the flight figure of 0.39 % without another measurement of the lost force (the command log,
or the accelerometer: 0.52 %).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from oacli.estimation.lost_inputs import (
    GyroBridge,
    lost_input_model,
    unknown_force_directions,
    unknown_torque_directions,
)
from oacli.estimation.manifold import TANGENT_DIM, boxminus, lift_matrix, project_matrix
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
    lost_inputs: str = "prior",
    bridge_acceleration: np.ndarray | None = None,
    bridge_acceleration_variance: np.ndarray | None = None,
    measured: np.ndarray | None = None,
    gyro: GyroBridge | None = None,
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
        Records after a gap in the inputs (:mod:`oacli.estimation.alignment`): the input over the interval before
        them is unknown. What the bound assumes there is ``lost_inputs``.
    lost_inputs : {"prior", "nuisance", "cut"}
        A gap the batch estimator bridges (one lost control instant between known inputs,
        :func:`oacli.estimation.lost_inputs.lost_input_model`) carries the unknown wrench as a nuisance parameter
        ``w = [f/m, τ]`` (6 per gap) that moves the state after the gap along the estimator's directions
        (:func:`~oacli.estimation.lost_inputs.unknown_force_directions`, exact, and
        :func:`~oacli.estimation.lost_inputs.unknown_torque_directions`, first order). ``"prior"`` (default): ``w``
        has the Gaussian prior the estimator uses (the neighbours' prediction with its error variance measured on
        the run; ``f/m`` from the accelerometer where ``bridge_acceleration`` has it) -- the bound of that model
        (a hybrid bound: ``w`` random, θ and the initial states fixed), which the batch's covariance estimates.
        ``"nuisance"``: ``w`` unknown with no prior (a bound for any estimator that does not use the neighbours'
        prediction). ``"cut"``: every gap cuts the run; each segment's initial state is unknown and the
        information of the segments adds up (gaps the estimator does not bridge are cut in every mode).
    bridge_acceleration : ndarray, shape (K, 3), optional
        Mean accelerometer ``f/m`` over each record's interval with an unknown input (NaN where none).
    bridge_acceleration_variance : ndarray, shape (K,), optional
        Its variance per axis [m²/s⁴].
    measured : ndarray, shape (K, 13), optional
        The measured states: the residuals ``ỹ ⊟ x̂`` of the ``used`` records give the lost wrench's prior the
        variance of the estimator's noise-corrected prediction
        (:func:`oacli.estimation.lost_inputs.noise_corrected_prediction`), as the batch estimator's last solve uses it.
    gyro : GyroBridge, optional
        The gyro's ``ω̇`` over the lost intervals (:func:`oacli.estimation.lost_inputs.bridge_angular_accelerations`):
        where it has one, ``τ`` has the prior ``J² σ_ᾱ²`` ([Doerr2021] Eq. 35b, :func:`lost_input_model`).

    Returns
    -------
    CramerRaoBound
    """
    if lost_inputs not in ("prior", "nuisance", "cut"):
        raise ValueError(f"lost_inputs: {lost_inputs!r} (prior, nuisance or cut)")
    t = np.asarray(t, dtype=float)
    states = np.asarray(states, dtype=float)
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float).reshape(-1, 6)
    k = t.shape[0]
    used = np.ones(k, dtype=bool) if used is None else np.asarray(used, dtype=bool)
    starts_mask = np.zeros(k, dtype=bool)
    if segment_starts is not None:
        starts_mask |= np.asarray(segment_starts, dtype=bool)
    starts_mask[0] = True
    bridges: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # interval -> (directions 12x6, prior information 6)
    if k > 1 and np.any(starts_mask[1:]) and lost_inputs != "cut":
        links = ~starts_mask[1:]
        noise = None
        if measured is not None:
            noise = np.full((k, TANGENT_DIM), np.nan)
            noise[used] = boxminus(np.asarray(measured, dtype=float)[used], states[used])
        u, bridged, variance, _ = lost_input_model(
            t, u, links, np.asarray(theta, dtype=float)[:4], bridge_acceleration=bridge_acceleration,
            bridge_acceleration_variance=bridge_acceleration_variance, noise=noise, gyro=gyro)
        dt = np.diff(t)
        for i in np.flatnonzero(bridged):
            d = np.concatenate([unknown_force_directions(dt[i:i + 1])[0],
                                unknown_torque_directions(dt[i:i + 1], theta[1:4])[0]], axis=1)
            info = 1.0 / variance[i] if lost_inputs == "prior" else np.zeros(6)
            bridges[int(i)] = (d, info)
            starts_mask[i + 1] = False
    starts = np.flatnonzero(starts_mask)
    pieces = [
        _segment_information(t[a:b], states[a:b], u[a:b], theta, model, substep_s, used[a:b], accelerations_measured,
                             {int(i - a): v for i, v in bridges.items() if a <= i < b - 1})
        for a, b in zip(starts, [*starts[1:], k], strict=True) if np.any(used[a:b])
    ]
    f_eff: np.ndarray = np.sum([p[0] for p in pieces], axis=0)
    f_tt: np.ndarray = np.sum([p[1] for p in pieces], axis=0)
    return CramerRaoBound(std=cramer_rao_std(f_eff, theta), std_known_initial_state=cramer_rao_std(f_tt, theta),
                          information=f_eff, information_known_initial_state=f_tt)


def _eliminate(info: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Schur complement of ``info`` on the ``keep`` indices (the others eliminated as nuisance parameters)."""
    drop = np.setdiff1d(np.arange(info.shape[0]), keep)
    f_kk = info[np.ix_(keep, keep)]
    if drop.size == 0:
        return 0.5 * (f_kk + f_kk.T)
    f_kd = info[np.ix_(keep, drop)]
    f_dd = info[np.ix_(drop, drop)]
    try:
        out = f_kk - f_kd @ np.linalg.solve(f_dd, f_kd.T)
    except np.linalg.LinAlgError:  # a nuisance direction the data do not see at all
        out = f_kk - f_kd @ np.linalg.lstsq(f_dd, f_kd.T, rcond=None)[0]
    return 0.5 * (out + out.T)


def _segment_information(
    t: np.ndarray, states: np.ndarray, u: np.ndarray, theta: np.ndarray, model: MeasurementModel, substep_s: float,
    used: np.ndarray, accelerations_measured: bool, bridges: dict[int, tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray]:
    """Information on θ of one segment linked by the process model: with its initial state unknown (``F_eff``) and
    known (``F_θθ``); the nuisance wrenches of ``bridges`` (interval -> directions, prior information) are
    eliminated in both."""
    k = t.shape[0]
    state_rows, accel_rows = measured_rows(model)
    w_state = np.sqrt(model.state_weights[state_rows])
    if not accelerations_measured:
        accel_rows = accel_rows[:0]
    w_accel = np.sqrt(model.acceleration_weights[accel_rows])
    order = sorted(bridges)
    col = {i: TANGENT_DIM + N_PARAMS + 6 * g for g, i in enumerate(order)}
    n = TANGENT_DIM + N_PARAMS + 6 * len(order)
    # Sensitivities in the tangent chart of each state (so the quaternion's sign convention cannot matter):
    # S_k = ∂(x_k ⊟ x̂_k)/∂[δx_0, θ, w] (12, n), S_0 = [I | 0], S_{k+1} = P(x⁺) A_k L(x̂_k) S_k + [0 | P(x⁺) C_k | D_k]
    # with x⁺ = f(x̂_k) (D_k on the columns of interval k's nuisance wrench); there the measurement Jacobian
    # H L = I (information.py's H for a unit quaternion).
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
            sens[i + 1, :, TANGENT_DIM:TANGENT_DIM + N_PARAMS] += c_t[i]
            if i in col:
                sens[i + 1, :, col[i]:col[i] + 6] += bridges[i][0]
    info = np.zeros((n, n))
    for i in np.flatnonzero(used):  # type: ignore[assignment]
        g = sens[i][state_rows] * w_state[:, None]
        info += g.T @ g
    if accel_rows.size:
        jac = dynamics_jacobians_batch(states, u, theta)[:, _ACCEL_ROWS]
        lifts = lift_matrix(states)
        for i in np.flatnonzero(used):  # type: ignore[assignment]
            g = jac[i, :, 0:13] @ lifts[i] @ sens[i]
            g[:, TANGENT_DIM:TANGENT_DIM + N_PARAMS] += jac[i, :, 13:]
            g = g[accel_rows] * w_accel[:, None]
            info += g.T @ g
    for i in order:  # the nuisance wrenches' prior (zero information: unknown)
        c0 = col[i]
        info[c0:c0 + 6, c0:c0 + 6] += np.diag(bridges[i][1])
    # Gauge: unmeasured components of x_0 (offsets that do not affect θ) get unit information.
    for row in np.setdiff1d(np.arange(TANGENT_DIM), state_rows):
        info[row, row] += 1.0
    theta_cols = np.arange(TANGENT_DIM, TANGENT_DIM + N_PARAMS)
    f_eff = _eliminate(info, theta_cols)
    known = np.r_[theta_cols, TANGENT_DIM + N_PARAMS + np.arange(6 * len(order))]
    f_tt = _eliminate(info[np.ix_(known, known)], np.arange(N_PARAMS))
    return f_eff, f_tt


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
