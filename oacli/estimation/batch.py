"""Batch maximum-likelihood estimation of states and inertial parameters ([Doerr2021] Eqs. 31-32).

Given records ``ỹ_k`` (measured state, applied input, optional accelerations) at times ``t_1 .. t_K``, the
estimator maximises Eq. 31, ``Π p(ỹ_k | x_k) Π p(x_k | x_{k-1}, u_{k-1}, θ)``, over every state and the parameters,
``ϑ = [x_1 .. x_K, θ]``. With Gaussian noise this is the nonlinear least-squares problem

    min_ϑ  Σ_k ‖ R^-½ (h(x_k) ⊟ ỹ_k) ‖²  +  Σ_k ‖ Q_k^-½ (x_{k+1} ⊟ f(x_k, u_k, θ)) ‖²  (+ ‖ P₀^-½ (θ − θ₀) ‖²)

solved by Gauss-Newton with Levenberg-Marquardt damping: each iteration linearises about ``ϑ̄`` and solves Eq. 32,
``min ‖b(ϑ̄) + A δϑ‖²``, then updates ``x̄ ⊞ δx`` (quaternion-aware, :mod:`oacli.estimation.manifold`) and θ.

Choices the paper leaves open, and what is done here:

* **Residuals on the manifold.** The attitude residuals are body-frame rotation vectors ``log(q̃⁻¹ ⊗ q)`` and
  ``log(f_q⁻¹ ⊗ q_{k+1})``; their Jacobians use the exact inverse SO(3) Jacobians, so the linearisation is exact to
  first order even far from the solution (checked against finite differences in the tests).
* **Process model.** ``f`` is the simulator's multi-rate RK4 integration with the input held over each control
  period (:mod:`oacli.estimation.propagation`), with its exact Jacobians ``A_k = ∂f/∂x``, ``C_k = ∂f/∂θ``.
* **Physical parameters.** θ is estimated through φ (:mod:`oacli.estimation.parametrization`), so every iterate has
  mass > 0 and inertias satisfying the triangle inequalities; the maximum-likelihood point is the same.
* **Sparsity.** Every residual touches one state, or two consecutive states, and φ, so ``AᵀA`` is block
  tridiagonal in the states (12×12 blocks) with a dense 4-column border in φ. It is accumulated directly in blocks
  (``A`` is never formed) and ``(AᵀA + λD) δϑ = −Aᵀb`` is solved by eliminating the states: a banded Cholesky
  factorisation of the state block and a 4×4 Schur complement on φ; the cost grows linearly with the telemetry.
  ``estimate_batch(..., reference=True)`` keeps the original path (``A`` assembled as a ``scipy.sparse`` matrix,
  ``AᵀA`` factorised by sparse LU, the general 13×17 RK4 Jacobians): the same iterations, to check against.
  Its covariance comes from the augmented system ``[[I, A], [Aᵀ, 0]]`` (sparse LU), not from ``AᵀA``: see below.
* **Covariance.** ``cov(θ̂) = [(AᵀA)⁻¹]_θθ`` at the solution (Doerr: "extracted from (AᵀA)⁻¹"), mapped from φ
  to θ through ``dθ/dφ``. It is computed from a block QR factorisation of ``A`` (a square-root information
  smoother, :meth:`BatchProblem.last_covariance_qr`), not from ``AᵀA``: with a nearly rigid process model
  ``cond(AᵀA)`` reaches 10¹³, so any solve of the normal equations is good to ~10⁻⁵ relative only (the
  original path's LU of ``AᵀA`` differed from a dense QR of ``A`` by 8.6e-6 on the 60 s ISS run), while the QR is
  good to ``cond(A)·ε`` (3.6e-10 there). The reference path therefore solves the augmented system
  ``[[I, A], [Aᵀ, 0]] [r; z] = [0; −e]`` (Björck 1996, §2.5.3) by sparse LU, which never forms ``AᵀA`` and is
  accurate to ``cond(A)·ε`` as well: the two covariances agree to 3.4e-10 on that run.
* **Outliers.** After convergence every record's normalised residual ``d²_k = ‖R^-½ (h(x̂_k) ⊟ ỹ_k)‖²`` is tested
  against the χ² gate ([ReSWARM2023] §6.2.1); records outside it are dropped and the problem is re-solved, until the
  inlier set no longer changes. The dynamics still tie the state of a dropped record to its neighbours.
* **Continuation.** With a nearly rigid model (small process noise) the process residuals have tiny standard
  deviations, and the second-order terms a large parameter step leaves in them (``u Δt/m`` is not linear in m)
  make full Gauss-Newton steps overshoot, so Levenberg-Marquardt would crawl. The problem is therefore solved
  first with the process noise inflated 1000×, 100× and 10× (each solution warm-starts the next, with a loose
  tolerance) and then with the configured noise; only the last stage's costs are in ``cost_history``. The
  continuation runs in the first gating round only: a later round starts at the previous round's solution, which
  dropping a few outliers moves by little, and converges in a few full steps from there (on the 60 s ISS run, with
  or without 5 % localisation jumps, it reaches the same θ̂ to 2e-12 relative as restarting the continuation every
  round, with 40 % fewer iterations).
* **Gauge.** State components that are not measured at all (e.g. position when only velocities are used) have
  unobservable offsets that do not affect θ; the first state's unmeasured components get a unit-weight tie to the
  first record so that ``AᵀA`` stays invertible.
* **Imperfect telemetry** (:mod:`oacli.estimation.alignment`). An input-only record (``state_measured=False``: the
  localisation message was lost) keeps its state variable and process residuals but has no measurement residual
  and is never an inlier. A record that ``starts_segment`` (the input over the interval before it is unknown) is
  never reached by holding an input over the gap (:func:`segment_link_weights`): the unknown wrench is predicted
  from its neighbours with the prediction's error (measured on the run, :func:`lost_input_prior`) as extra process
  noise over that interval; after the first solve the prediction is redone by regression on the neighbours' mean
  and their measurement residuals (:func:`noise_corrected_prediction`: the controller's reaction to measurement
  noise is most of the miss, and a prediction whose error correlates with it biased Ixx) and solved again, the
  directions weighted at that solve's θ̂. Where the records carry the accelerometer's mean over a lost period
  (:func:`oacli.estimation.imu.attach_accelerations`), the force is not predicted: the specific force *is*
  ``f/m``, so the translation across the gap takes the measured acceleration (:func:`lost_input_model`); where
  they carry the gyro's slope over it, the rotation takes the measured ``ω̇`` likewise ([Doerr2021] Eq. 35b). Without
  a prediction the force is profiled out (position continuity kept) and the rotational state after the gap is
  estimated afresh; a longer gap is cut (the segment's first state free, with its own gauge tie). Cutting every
  gap biases θ in closed loop (see :func:`segment_link_weights`).
* **Goodness of fit.** At the solution the cost ``‖b‖²`` of a correct model is χ²-distributed with
  ``m − n`` degrees of freedom (residuals minus unknowns); :attr:`BatchResult.chi2` and ``chi2_dof`` report both,
  so a fit far outside its expected range (a wrong input record, an unmodelled effect) is visible.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from oacli.estimation.batch_model import FullModel, LegacyModel
from oacli.estimation.batch_problem import BatchProblem, marginal_covariances
from oacli.estimation.gating import chi2_threshold
from oacli.estimation.levenberg_marquardt import LAMBDA_INIT, levenberg_marquardt
from oacli.estimation.models import EstimatorSettings, Measurement
from oacli.estimation.preprocessing import order_by_time
from oacli.estimation.propagation import (
    TIME_TOL_S,
    propagate_state_one,
    substep_schedule,
)
from oacli.types import ParameterEstimate

__all__ = ["UNIDENTIFIED_VARIANCE", "BatchResult", "covariance_at", "estimate_batch", "estimate_batch_windows",
           "extend_states"]

_LAMBDA_WARM = 1e-12
"""Initial damping of every Levenberg-Marquardt solve of :func:`estimate_batch` warm-started at the solution of fewer
records (a longer window of :func:`estimate_batch_windows`): Gauss-Newton steps are nearly exact there, and a
damping of 1e-6 · diag(AᵀA) slows the weakly determined directions of an ill-conditioned ``AᵀA`` (cond ~10¹³) by
one decade per iteration; LM raises it again after a rejected step. A cold start keeps :data:`LAMBDA_INIT` in
every round: on flight-like telemetry (large residuals) undamped Gauss-Newton converges only linearly after the
gating round, and the cost tolerance then stops it up to 7e-7 (relative, 3e-5 standard deviations) short of the
minimum in θ on the default mission's first 10 s window (windows warm-started from a converged solution: 7e-8 on
the second, 7e-10 at the last)."""
_CONTINUATION = (1000.0, 100.0, 10.0)
"""Process-noise inflation factors solved first, each warm-starting the next (see the module docstring)."""
_CONTINUATION_WARM = (10.0,)
"""The continuation of a warm-started solve (:func:`estimate_batch_windows`): the last stage only. Without it the
new records' open-loop states can lead the first gating round elsewhere (a window with localisation jumps and a
gap converged to a different inlier set than a cold solve); with the full continuation the warm start saves little
(16 instead of 21 iterations per window on the default mission, 10 with this one stage)."""
_CONTINUATION_TOLERANCE = 1e-6

UNIDENTIFIED_VARIANCE = 1e300
"""The variance reported for every parameter when ``AᵀA`` is singular at the solution (θ not identified by the
records that passed the gate): finite, so the estimate stays a valid Gaussian, but no σ (the estimate stage reports
none and ends ``degraded``)."""


@dataclass(frozen=True)
class BatchResult:
    """Outcome of :func:`estimate_batch`.

    Attributes
    ----------
    estimate : ParameterEstimate
        θ̂ and ``[(AᵀA)⁻¹]_θθ``; ``samples_used`` = inlier records, ``samples_rejected`` = gated records plus
        duplicated time stamps.
    t : ndarray, shape (K,)
        Record times [s] in time order (duplicates removed).
    states : ndarray, shape (K, 13)
        Estimated states ``x̂_k``.
    inliers : ndarray of bool, shape (K,)
        Records used in the final solve.
    d2 : ndarray, shape (K,)
        Normalised residual squared of every record against the final fit.
    gate_threshold : float
        χ² threshold used (``inf`` without gating); ``dof`` degrees of freedom per record.
    dof : int
    iterations : int
        Gauss-Newton iterations over all gating rounds.
    gating_rounds : int
    cost_history : tuple of float
        Cost ``‖b‖²`` after every accepted iteration (first entry: the initial guess), across rounds.
    converged : bool
        The last round met the tolerance within ``max_iterations``.
    duplicates : int
        Records dropped for a repeated time stamp.
    solve_time_s : float
        Wall time [s].
    phi : ndarray, shape (4,)
        The solution in the physical parametrisation (:mod:`oacli.estimation.parametrization`).
    last_covariance : ndarray, shape (16, 16)
        Covariance of ``[δx_K (12, tangent of the last state), δφ (4)]`` -- what a filter continuing from here
        needs (:class:`oacli.estimation.sequential.SequentialEstimator` bootstraps from it).
    chi2 : float
        Final cost ``‖b‖²`` (whitened residuals squared, configured process noise).
    chi2_dof : int
        Its expected value for a correct model: residuals minus unknowns (``m − n``).
    gate_emptied : bool
        No record passed the χ² gate in some round (the previous inlier set was kept).
    segments : int
        Records linked by the process model form this many segments (1 without gaps).
    theta_full : ndarray, shape (16,) or None
        The full model's θ (:mod:`oacli.estimation.rigid_parameters`; entries not estimated at their fixed
        values); None for θ = [m, Ixx, Iyy, Izz].
    covariance_full : ndarray, shape (16, 16) or None
        ``[(AᵀA)⁻¹]_θθ`` of the full θ (zero rows and columns for the entries not estimated).
    """

    estimate: ParameterEstimate
    t: np.ndarray
    states: np.ndarray
    inliers: np.ndarray
    d2: np.ndarray
    gate_threshold: float
    dof: int
    iterations: int
    gating_rounds: int
    cost_history: tuple[float, ...]
    converged: bool
    duplicates: int
    solve_time_s: float
    phi: np.ndarray
    last_covariance: np.ndarray
    chi2: float = float("nan")
    chi2_dof: int = 0
    gate_emptied: bool = False
    segments: int = 1
    theta_full: np.ndarray | None = None
    covariance_full: np.ndarray | None = None


def covariance_at(
    records: Sequence[Measurement], settings: EstimatorSettings, prior: ParameterEstimate | None,
    states: np.ndarray, phi: np.ndarray, weights_theta: np.ndarray, model: FullModel | None = None,
) -> np.ndarray:
    """The batch problem's parameter covariance ``[(AᵀA)⁻¹]_θθ`` at a given point, without iterating.

    The covariance of the maximum-likelihood problem ([Doerr2021] Eqs. 31-32: ``cov(θ̂)`` "extracted from
    ``(AᵀA)⁻¹``", module docstring) evaluated at ``(states, φ)``: what a solve converged there would report.
    The sequential filter uses it to skip bootstrap checks that cannot hand over yet.

    Parameters
    ----------
    records : sequence of Measurement
        Time-ordered records.
    settings : EstimatorSettings
    prior : ParameterEstimate or None
        Prior on θ (its information is added when given).
    states : ndarray, shape (K, 13)
        States of the records at the point.
    phi : ndarray, shape (4,)
        Parameters at the point in the solver's parametrisation (:mod:`oacli.estimation.parametrization`).
    weights_theta : ndarray, shape (4,)
        θ ``[m kg, Ixx, Iyy, Izz kg·m²]`` at which the lost inputs' model is weighted.
    model : FullModel, optional
        The full rigid body's chosen part (default θ = [m, Ixx, Iyy, Izz]).

    Returns
    -------
    ndarray, shape (4, 4) or (16, 16)
        Covariance of ``θ`` (``inf`` diagonal when ``AᵀA`` is singular).
    """
    problem = BatchProblem(records, settings, prior, weights_theta, model)
    cov, _ = marginal_covariances(problem, states, phi, problem.has_state.copy())
    return cov


def estimate_batch(
    records: Sequence[Measurement],
    settings: EstimatorSettings,
    prior: ParameterEstimate | None,
    *,
    initial_theta: np.ndarray | None = None,
    initial_states: np.ndarray | None = None,
    initial_phi: np.ndarray | None = None,
    continuation: bool = True,
    warm_start: bool = False,
    reference: bool = False,
    model: FullModel | None = None,
) -> BatchResult:
    """Batch maximum-likelihood estimate of the states and θ from a set of records ([Doerr2021] Eqs. 31-32).

    Parameters
    ----------
    records : sequence of Measurement
        In any order (sorted by time stamp here; repeated time stamps are dropped and counted). At least 2.
    settings : EstimatorSettings
        Noise models, integration grid, gate, iteration limits.
    prior : ParameterEstimate or None
        Gaussian prior ``N(θ₀, P₀)`` on θ (``None``: pure maximum likelihood). ``P₀`` is a covariance
        (variances on its diagonal).
    initial_theta : ndarray, shape (4,), optional
        Starting point (default: the prior mean); must be physical.
    initial_states : ndarray, shape (K, 13), optional
        Starting states for the time-ordered records (default: the measured states).
    initial_phi : ndarray, shape (4,), optional
        Starting point in the physical parametrisation (overrides ``initial_theta``; a previous solution's ``phi``,
        which may lie arbitrarily close to the physical boundary).
    continuation : bool
        Solve with inflated process noise first (see the module docstring); a warm start close to the solution
        may skip it.
    warm_start : bool
        The starting point is a previous solution (of fewer records): the continuation's last stage only
        (:data:`_CONTINUATION_WARM`), every Levenberg-Marquardt solve started with little damping
        (:data:`_LAMBDA_WARM`).
    reference : bool
        Use the original implementation (sparse ``A`` assembled, ``AᵀA`` factorised by LU, the general
        :func:`~oacli.estimation.propagation.propagate_intervals`) instead of the block normal equations with a
        Schur complement on φ; the same iterations, kept to check the fast path against (tests, benchmark).
    model : FullModel, optional
        Estimate a chosen part of the full rigid body (:mod:`oacli.estimation.batch_model`; ``initial_theta``
        then has 16 entries or 4, the rest from the model's fixed values); default θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    BatchResult
    """
    wall = time.perf_counter()
    ordered = order_by_time(records)
    recs = ordered.records
    if len(recs) < 2:
        raise ValueError(f"the batch estimator needs at least 2 records with distinct time stamps, got {len(recs)}")
    if initial_theta is None and initial_phi is None:
        if prior is None and model is None:
            raise ValueError("give a prior or an initial_theta")
        initial_theta = model.prior_mean if model is not None else prior.theta  # type: ignore[union-attr]
    pm: LegacyModel | FullModel = LegacyModel() if model is None else model
    phi = pm.phi(initial_theta) if initial_phi is None else np.array(initial_phi, dtype=float)  # type: ignore[arg-type]
    theta_w = prior.theta if prior is not None else pm.theta4(phi)
    problem = BatchProblem(recs, settings, prior, theta_w, model)
    x = problem.y.copy() if initial_states is None else np.array(initial_states, dtype=float)
    threshold = chi2_threshold(problem.dof, settings.gate_probability) if settings.gate_probability else np.inf
    inliers = problem.has_state.copy()
    if not np.any(inliers):
        raise ValueError("the batch estimator needs at least one record with a measured state")
    gate_emptied = False
    history: list[float] = []
    iterations = 0
    loose = EstimatorSettings(**{**settings.__dict__, "tolerance": max(settings.tolerance, _CONTINUATION_TOLERANCE)})
    rounds = 0
    converged = False
    lam0 = _LAMBDA_WARM if warm_start else LAMBDA_INIT
    for rounds in range(1, settings.max_gating_rounds + 1):
        # The continuation in the first round only: a later round starts from the previous round's solution, which
        # dropping a few outliers moves by little (the full Gauss-Newton steps do not overshoot from there).
        for factor in (_CONTINUATION_WARM if warm_start else _CONTINUATION) if continuation and rounds == 1 else ():
            problem.set_process_noise_scale(factor)
            x, phi, its, _ = levenberg_marquardt(problem, x, phi, inliers, loose, [], reference, lam0)
            iterations += its
        problem.set_process_noise_scale(1.0)
        x, phi, its, converged = levenberg_marquardt(problem, x, phi, inliers, settings, history, reference, lam0)
        iterations += its
        if rounds == 1 and problem.has_gaps:
            # The lost inputs' prediction corrected with this solve's measurement residuals (set_lost_inputs), and
            # solved again from here.
            problem.set_lost_inputs(problem.measurement_noise(x, inliers), pm.theta4(phi))
            x, phi, its, converged = levenberg_marquardt(problem, x, phi, inliers, settings, history, reference,
                                                          lam0)
            iterations += its
        d2 = problem.d2(x, phi)
        new_inliers = problem.has_state & (np.nan_to_num(d2, nan=np.inf) <= threshold)
        if not np.any(new_inliers):
            gate_emptied = True  # reported: the caller must not call this fit ok
            break  # nothing passes the gate: keep the last inlier set rather than an empty problem
        if np.array_equal(new_inliers, inliers):
            break
        inliers = new_inliers
    d2 = problem.d2(x, phi)
    cov_theta, cov_last = marginal_covariances(problem, x, phi, inliers, reference)
    cov = cov_theta[:4, :4]
    estimate = ParameterEstimate(
        t=float(problem.t[-1]),
        theta=pm.theta4(phi),
        covariance=cov if np.all(np.isfinite(cov)) else np.diag(np.full(4, UNIDENTIFIED_VARIANCE)),
        method="batch",
        samples_used=int(inliers.sum()),
        samples_rejected=int((~inliers & problem.has_state).sum()) + len(ordered.duplicates),
    )
    return BatchResult(
        estimate=estimate,
        t=problem.t,
        states=x,
        inliers=inliers,
        d2=d2,
        gate_threshold=float(threshold),
        dof=problem.dof,
        iterations=iterations,
        gating_rounds=rounds,
        cost_history=tuple(history),
        converged=converged,
        duplicates=len(ordered.duplicates),
        solve_time_s=time.perf_counter() - wall,
        phi=phi,
        last_covariance=cov_last,
        chi2=float(history[-1]) if history else float("nan"),
        chi2_dof=problem.residual_count(inliers) - problem.n_var,
        gate_emptied=gate_emptied,
        segments=int(problem.segment_starts.size),
        theta_full=None if model is None else model.theta(phi),
        covariance_full=None if model is None else cov_theta,
    )


def extend_states(
    states: np.ndarray, records: Sequence[Measurement], theta: np.ndarray, substep_s: float,
    model: FullModel | None = None,
) -> np.ndarray:
    """Warm start for a longer window.

    The solved ``states`` for the first records, then the process model propagated from the last of them with the
    records' inputs (consistent with the dynamics: the stiff process residuals start at zero).

    Parameters
    ----------
    states : ndarray, shape (n, 13)
        Solved states of the first n records.
    records : sequence of Measurement
        The records of the longer window (at least n), in time order.
    theta : ndarray, shape (4,) or (16,)
        θ = [m, Ixx, Iyy, Izz], or the full model's θ with ``model``.
    substep_s : float
        Integration substep [s].
    model : FullModel, optional
        The full rigid body's process model (default: θ = [m, Ixx, Iyy, Izz]).

    Returns
    -------
    ndarray, shape (len(records), 13)
    """
    out = np.array([r.x_measured for r in records])
    n = states.shape[0]
    out[:n] = states
    if n >= len(records):
        return out
    t = np.array([r.t for r in records])
    sched = substep_schedule(t[n - 1:-1], t[n:], substep_s)
    for i in range(n, len(records)):
        if records[i].starts_segment:
            continue  # the input before it is unknown: start from its measurement
        if model is None:
            out[i] = propagate_state_one(out[i - 1], records[i - 1].u_applied, theta, sched[i - n])
        else:
            out[i] = model.propagate(out[i - 1][None], records[i - 1].u_applied[None], theta, sched[i - n][None],
                                     jacobians=False)[0][0]
    return out


def estimate_batch_windows(
    records: Sequence[Measurement],
    settings: EstimatorSettings,
    prior: ParameterEstimate | None,
    window_ends_s: Sequence[float],
    *,
    progress: Callable[[float], None] | None = None,
    reference: bool = False,
    model: FullModel | None = None,
) -> list[BatchResult]:
    """Batch estimates on growing windows ``[t_first, t_end]`` (to show convergence over mission time).

    Each window is warm-started from the previous solution (states and θ, the new records' states propagated by
    :func:`extend_states`) with one continuation stage (:data:`_CONTINUATION_WARM`) and little initial damping
    (:data:`_LAMBDA_WARM`): on the default mission 10 iterations per window instead of 21 (two gating rounds
    each), θ̂ equal to a cold solve's to 7e-10 relative on the last window and 7e-8 on the second (the cost
    tolerance's accuracy: 6e-6 standard deviations). A window whose warm solve does not converge is solved again
    from the prior. Windows with fewer
    than two records are skipped. The last entry of ``window_ends_s`` should be the last record time to include
    all data. ``progress`` is called with the fraction of windows done.

    Parameters
    ----------
    records : sequence of Measurement
    settings : EstimatorSettings
    prior : ParameterEstimate or None
    window_ends_s : sequence of float
        End time [s] of each window, increasing.
    progress : callable, optional
    reference : bool
        Solve every window with the original implementation (see :func:`estimate_batch`).
    model : FullModel, optional
        Estimate a chosen part of the full rigid body (see :func:`estimate_batch`).

    Returns
    -------
    list of BatchResult
        One per window that was solved.
    """
    ordered = order_by_time(records).records
    t = np.array([r.t for r in ordered])
    results: list[BatchResult] = []
    theta = None if prior is None else prior.theta
    phi: np.ndarray | None = None
    states: np.ndarray | None = None
    for i, end in enumerate(window_ends_s):
        n = int(np.searchsorted(t, end + TIME_TOL_S, side="right"))
        if n >= 2:
            init = None if states is None else extend_states(states, ordered[:n], theta, settings.substep_s,  # type: ignore[arg-type]
                                                             model)
            result = estimate_batch(ordered[:n], settings, prior, initial_theta=theta, initial_states=init,
                                    initial_phi=phi, warm_start=init is not None,
                                    reference=reference, model=model)
            if init is not None and not result.converged:  # the warm start did not pay off: solve from the prior
                result = estimate_batch(ordered[:n], settings, prior, reference=reference, model=model)
            results.append(result)
            theta = result.estimate.theta if result.theta_full is None else result.theta_full
            phi, states = result.phi, result.states
        if progress is not None:
            progress((i + 1) / len(window_ends_s))
    return results
