"""Offline information-optimal excitation ([Doerr2021] Eq. 30) by sequential convex programming.

Problem. Over N steps of ``dt`` from a start pose at rest to a goal pose at rest, find inputs ``u`` that minimise a
criterion of the Fisher information ``F(u)`` (Eq. 29; A: ``tr F⁻¹``, D: ``−log det F``, E: ``−λ_min F``, on
absolute or relative parameters) subject to the RK4 dynamics (Eqs. 33-36), per-axis force, torque, velocity and
angular-rate limits, the keep-in boxes and the keep-out ellipsoids (Eq. 12), and the terminal state within a
tolerance. The paper's version ignored obstacles and needed a "safe area"; this one respects them (also between
samples, see :mod:`oacli.excitation.problem`).

Sequential convex programming. Iterates are always *rollouts* of the nonlinear model (so the dynamics hold
exactly); around the current one a convex subproblem in the step ``δu`` is solved with cvxpy/Clarabel:

* dynamics linearised exactly: translation is an exact LTI double integrator (force in the world frame), the
  rotational block uses the exact RK4 Jacobians ``A_k, B_k`` (:func:`oacli.model.rigid_body.rk4_step_jacobians`);
* the FIM linearised, ``F(u + δu) ≈ F(u) + Σ_ab E_ab ⟨∂F_ab/∂u, δu⟩`` with exact adjoint gradients
  (:mod:`oacli.excitation.fim_gradient`), and the *exact convex* criterion of that affine matrix (tr_inv by a
  Schur complement, log_det, λ_min by an LMI) — a model that keeps the criterion's curvature in F;
* keep-in boxes per sample (the intersection of the boxes of its two segments,
  :func:`oacli.excitation.problem.keep_in_sample_bounds`) and keep-out tangent half-spaces per segment (pushed
  sideways for segments inside a zone, :func:`oacli.excitation.problem.segment_halfspaces`); velocity, rate and
  terminal constraints linearised;
* every constraint but the input bounds is softened by a non-negative slack with an exact ℓ1 penalty μ, so the
  subproblem is always feasible (feasibility restoration when the linearised problem is not);
* a trust region ``|δu_i| ≤ Δ·u_max,i``.

A step is accepted only when the merit ``φ = J/J_ref + μ·V`` (``V`` the normalised constraint violation of the
*nonlinear* rollout, measured as the slacks measure it) decreases and the ratio of actual to predicted decrease is
at least ``accept_ratio``; Δ grows after good steps and shrinks after poor or rejected ones (separately for force and
torque: translation is exactly linear, rotation is where the model errs). Every iterate, accepted or not, is
recorded with its criterion, merit, violation and trust regions.

Two details keep the iteration efficient on long horizons, where the final attitude is a strongly nonlinear
function of the torques:

* constraints the model predicts only to first order (final attitude and rate, rate limits) are aimed at a
  tightened bound that is never tighter than the current value, so the slacks at zero step still equal the true
  violation while a step's linearisation error stays inside the true bound;
* a trial point that misses the final attitude gets a second-order correction (:func:`restore_rotation_endpoint`,
  Gauss-Newton on the final attitude and rate with the torques), and the better of the two is judged by the merit
  (the classical remedy for the Maratos effect of exact-penalty SQP).

Fast path (default) and reference path (``reference=True``). Translation (``[r, v]``, force, mass) and rotation
(``[q, ω]``, torque, inertias) are decoupled in the dynamics, in every constraint and in the Fisher information
(``F_mI ≡ 0``). The fast path uses that twice: rollouts, information and adjoint gradients come from
:mod:`oacli.excitation.split_information` (closed-form translation, batched rotational Jacobians; the same numbers
as the generic functions to rounding), and when a step fails the merit test its force part is tried alone
against the model of the force part (``ScpSettings.split_steps``; no extra subproblem) — on long horizons the
whole step fails almost always for its rotation, while the translation, which carries most of the information,
is modelled exactly. The subproblem is the same cvxpy problem, canonicalised once and re-solved through
:class:`oacli.control.compiled_qp.CompiledQP` with the parameter values passed directly. The decoupling also shapes
the subproblem (both paths): the FIM model has 7 gradient rows (F_mm in the forces, the six F_II entries in the
torques) instead of 16 dense ones, and input bounds and trust region are one box per input entry. The reference
path keeps the generic functions, ``problem.solve()`` per subproblem and whole steps only;
``benchmarks/bench_excitation.py`` times both.

Information is a convex function of the inputs and it is *maximised*, so the result is a local optimum that depends
on the start. The default start (:func:`initial_guess`) already spends long stretches near the speed limit (the mass
information of velocity measurements grows with ``Σ v²``) and excites every rotation axis; optional extra starts
(``ScpSettings.starts``) are screened for a few iterations and the best continues.

Where the pieces are: the problem, settings and result types in :mod:`oacli.excitation.design_types`, the merit
in :mod:`oacli.excitation.merit`, the convex subproblem in :mod:`oacli.excitation.subproblem`, the starts in
:mod:`oacli.excitation.starts`; this module runs the SCP loop (:func:`design_excitation`) and re-exports the types.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from oacli.excitation import split_information
from oacli.excitation.design_full import FullConvexSubproblem, FullScpMerit, full_linearisation, symmetric_pairs
from oacli.excitation.design_types import ExcitationDesign, ExcitationProblem, ScpIterate, ScpSettings
from oacli.excitation.fim_gradient import SYMMETRIC_PAIRS, criterion_value, fim_gradients, symmetric_basis
from oacli.excitation.information import (
    N_PARAMS,
    MeasurementModel,
    cramer_rao_std,
    information_per_step,
)
from oacli.excitation.merit import Evaluation, ScpMerit, terminal_residual
from oacli.excitation.problem import attitude_error, check_reachable, collision_free
from oacli.excitation.starts import initial_guess, perturbed_guess
from oacli.excitation.subproblem import ConvexSubproblem
from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb
from oacli.phases import set_phase
from oacli.types import Trajectory

_BASIS = symmetric_basis()


class _ScpRun:
    """One SCP run from one start, advanced an iteration at a time (see the module docstring)."""

    def __init__(self, problem: ExcitationProblem, settings: ScpSettings, merit: ScpMerit, sub: ConvexSubproblem,
                 start: Evaluation) -> None:
        self.full = problem.information is not None
        self.p = problem
        self.s = settings
        self.merit = merit
        self.sub = sub
        self.first = start
        self.current = start
        # Separate trust regions for force and torque: translation is exactly linear in the force, while the
        # rotation (and so the final attitude and the rates) is where the linear model errs.
        self.d_force = self.d_torque = settings.trust_region_initial
        self.history: list[ScpIterate] = []
        self.lin = None
        self.stop: str | None = None

    def step(self) -> None:
        p, settings, merit, sub = self.p, self.s, self.merit, self.sub
        it = len(self.history) + 1
        current = self.current
        if self.lin is None:
            if self.full:  # the full θ (oacli.excitation.design_full): difference gradients of its FIM
                assert p.information is not None
                self.lin = full_linearisation(p, p.information, current)  # type: ignore[assignment]
            elif current.rollout is not None:  # fast path: the iterate's split rollout, batched adjoint
                self.lin = split_information.fim_gradients(  # type: ignore[assignment]
                    p.start, current.u, p.theta, p.dt, p.measurement, _BASIS, ro=current.rollout)
            else:
                self.lin = fim_gradients(p.start, current.u, p.theta, p.dt, p.measurement, _BASIS)  # type: ignore[assignment]
        lin = self.lin
        sub.set_iterate(current, lin, self.d_force, self.d_torque)
        t0 = time.perf_counter()
        status, du, slack = sub.solve()
        solve_time = time.perf_counter() - t0
        if du is None:
            self.d_force *= settings.shrink
            self.d_torque *= settings.shrink
            self.history.append(
                ScpIterate(it, current.criterion, current.merit, current.violation, float("nan"), float("nan"),
                           float("nan"), float("nan"), self.d_force, self.d_torque, False, status, solve_time)
            )
            if max(self.d_force, self.d_torque) < settings.trust_region_min:
                self.stop = f"subproblem failed ({status})"
            return
        dfim = _fim_step(lin.gradients, du)  # type: ignore[attr-defined]
        crit_model = criterion_value(current.fim + dfim, p.criterion, merit.d)
        predicted = merit.normalise(crit_model) + settings.penalty * slack if np.isfinite(crit_model) else np.inf
        predicted_decrease = current.merit - predicted
        trial = np.clip(current.u + du, -p.limits.input, p.limits.input)
        candidate = merit.evaluate(trial)
        if candidate.violations["terminal_attitude"] > 0 or candidate.violations["terminal_angular_velocity"] > 0:
            corrected = merit.evaluate(restore_rotation_endpoint(p, trial, fast=merit.fast))
            if corrected.merit < candidate.merit:
                candidate = corrected
        actual = current.merit - candidate.merit
        ratio = actual / predicted_decrease if predicted_decrease > 0 else float("nan")
        accepted = bool(actual > 0 and predicted_decrease > 0 and ratio >= settings.accept_ratio)
        rotation_blamed = False
        partial = False
        if not accepted and merit.fast and settings.split_steps and np.any(du[:, 0:3]):
            # Force-only step. Translation ([r, v], force, mass) and rotation ([q, ω], torque, inertias) are
            # decoupled in the dynamics, the constraints and the Fisher information (F_mI ≡ 0), so the force part
            # of a step is judged on its own when the whole step fails (almost always for its rotation): same
            # merit test, against the model of the force part (its FIM change, its translational slacks, the
            # rotational violation unchanged). This is a second trial point of the same subproblem, no new solve.
            dfim_f = _fim_step(lin.gradients[:, :, 0:3], du[:, 0:3])  # type: ignore[attr-defined]
            crit_f = criterion_value(current.fim + dfim_f, p.criterion, merit.d)
            pred_f = (merit.normalise(crit_f) + settings.penalty * (sub.translation_slack
                                                                     + _rotational_violation(current))
                      if np.isfinite(crit_f) else np.inf)
            trial_f = current.u.copy()
            trial_f[:, 0:3] = trial[:, 0:3]
            cand_f = merit.evaluate(trial_f)
            dec_f = current.merit - pred_f
            ratio_f = (current.merit - cand_f.merit) / dec_f if dec_f > 0 else float("nan")
            if current.merit - cand_f.merit > 0 and dec_f > 0 and ratio_f >= settings.accept_ratio:
                partial = True
                rotation_blamed = True
                self.current = current = cand_f
                self.lin = None
                self.d_torque *= settings.shrink
                if ratio_f >= settings.good_ratio:
                    self.d_force = min(self.d_force * settings.grow, settings.trust_region_max)
                candidate, predicted, ratio, accepted = cand_f, pred_f, ratio_f, True
                status += " (force part)"
        if partial:
            pass  # trust regions already updated: force kept or grown, torque shrunk
        elif accepted:
            self.current = current = candidate
            self.lin = None
            if ratio >= settings.good_ratio:
                self.d_force = min(self.d_force * settings.grow, settings.trust_region_max)
                self.d_torque = min(self.d_torque * settings.grow, settings.trust_region_max)
        else:
            rotation_blamed = _rotational_violation(candidate) > _rotational_violation(current)
            self.d_torque *= settings.shrink
            if not rotation_blamed or self.d_torque < settings.trust_region_min:
                self.d_force *= settings.shrink
        self.history.append(
            ScpIterate(it, current.criterion, current.merit, current.violation, candidate.criterion,
                       candidate.merit, predicted, ratio, self.d_force, self.d_torque, accepted, status, solve_time)
        )
        if not (predicted_decrease > settings.tolerance) and not rotation_blamed:
            self.stop = "converged (predicted decrease below tolerance)"
        elif accepted and not partial and actual < settings.tolerance:
            # A full step taken that lowered the merit by less than the tolerance: the model's predicted decrease is
            # not realised (the rotation's nonlinearity), and the force-only steps between such steps gain nothing
            # either: on the default mission's design, 15 more iterations after this lowered the criterion 0.01 %.
            self.stop = "converged (a full step lowered the merit by less than the tolerance)"
        elif max(self.d_force, self.d_torque) < settings.trust_region_min:
            self.stop = "trust region below its minimum"


def design_excitation(
    problem: ExcitationProblem,
    settings: ScpSettings | None = None,
    u_init: np.ndarray | None = None,
    progress: Callable[[float], None] | None = None,
    rng: np.random.Generator | None = None,
    on_iteration: Callable[..., None] | None = None,
    reference: bool = False,
) -> ExcitationDesign:
    """Design an information-optimal excitation trajectory ([Doerr2021] Eq. 30) by SCP; see the module docstring.

    The default (fast) path and the reference path run the same SCP on the same subproblem; the fast one rolls out
    and differentiates with :mod:`oacli.excitation.split_information` (same numbers to rounding) and solves the
    subproblem through the compiled direct-Clarabel path (:class:`oacli.control.compiled_qp.CompiledQP`).

    Parameters
    ----------
    problem : ExcitationProblem
    settings : ScpSettings, optional
    u_init : ndarray, shape (N, 6), optional
        Initial inputs (default: :func:`initial_guess`).
    progress : callable, optional
        Called with the fraction of the iteration budget used after each iteration (and 1.0 at the end).
    rng : numpy.random.Generator, optional
        Source of the extra starts (:func:`perturbed_guess`); a fixed seed by default.
    on_iteration : callable, optional
        Called after each SCP iteration as ``on_iteration(start=k, iterate=ScpIterate, x=(N+1, 13), u=(N, 6))``
        with the start's index and its current (accepted) design, e.g. to record the run as it goes.
    reference : bool, optional
        Run the reference path (generic rollouts and adjoint of :mod:`oacli.excitation.information` and
        :mod:`oacli.excitation.fim_gradient`, ``problem.solve()`` per subproblem), kept to check the fast one.

    Returns
    -------
    ExcitationDesign

    Raises
    ------
    InfeasibleError
        When the goal cannot be reached at rest within the duration under the limits, or the initial guess
        carries no information on some parameter.
    """
    settings = settings or ScpSettings()
    wall = time.perf_counter()
    p = problem
    check_reachable(p.start, p.goal, p.duration_s, p.theta, p.limits)
    if u_init is None:
        u0 = initial_guess(p)
    else:
        u0 = np.clip(np.asarray(u_init, dtype=float), -p.limits.input, p.limits.input)
    merit: ScpMerit
    if p.information is None:
        merit = ScpMerit(p, settings.penalty, fast=not reference)
        sub = ConvexSubproblem(p, merit, settings.penalty, compiled=not reference)
    else:  # the full θ's entries (oacli.excitation.design_full; the fast path only)
        merit = FullScpMerit(p, settings.penalty, p.information)
        sub = FullConvexSubproblem(p, merit, settings.penalty, compiled=True)
    # The first start fixes the merit's normalisation, so that all starts are compared on the same merit.
    runs = [_ScpRun(p, settings, merit, sub, merit.evaluate(u0))]
    rng = np.random.default_rng(0) if rng is None else rng
    for _ in range(settings.starts - 1):
        runs.append(_ScpRun(p, settings, merit, sub, merit.evaluate(perturbed_guess(p, rng))))
    budget = settings.max_iterations
    used = 0
    if len(runs) > 1:
        # Multi-start: information is a convex function of the inputs and it is *maximised*, so the SCP ends in a
        # local optimum that depends on the start. Every start gets a few iterations; the best continues.
        for k, run in enumerate(runs):
            set_phase(progress, f"screening start {k + 1}/{len(runs)}")
            for _ in range(settings.screening_iterations):
                if run.stop is not None:
                    break
                run.step()
                used += 1
                if on_iteration is not None:
                    on_iteration(start=k, iterate=run.history[-1], x=run.current.x, u=run.current.u)
                if progress is not None:
                    progress(min(used / (budget + settings.starts * settings.screening_iterations), 1.0))
    best = min(runs, key=lambda r: r.current.merit)
    while best.stop is None and len(best.history) < budget:
        set_phase(progress, f"SCP iteration {len(best.history) + 1}/{budget}")
        best.step()
        used += 1
        if on_iteration is not None:
            on_iteration(start=runs.index(best), iterate=best.history[-1], x=best.current.x, u=best.current.u)
        if progress is not None:
            progress(min(used / (budget + settings.starts * settings.screening_iterations), 1.0))
    if best.stop is None:
        best.stop = "iteration limit"
    current, first, history, stop = best.current, best.first, best.history, best.stop
    if len(runs) > 1:
        stop += f" (best of {len(runs)} starts: start {runs.index(best) + 1})"

    if progress is not None:
        progress(1.0)
    x = current.x
    n = p.steps
    t = p.dt * np.arange(n + 1)
    u_full = np.vstack([current.u, np.zeros((1, 6))])
    traj = Trajectory(t, x, u_full, name="excitation")
    x_init = first.x
    initial = Trajectory(t, x_init, np.vstack([first.u, np.zeros((1, 6))]), name="initial_guess")
    if p.information is None:
        fim_meas = current.fim - p.prior
    else:  # the outputs stay the 4 entries' (the criterion is the full θ's)
        assert current.rollout is not None
        fim_meas = split_information.fisher_information(current.rollout, current.u, p.theta, p.measurement)
    return ExcitationDesign(
        trajectory=traj,
        fim=fim_meas,
        criterion_initial=first.criterion,
        criterion_final=current.criterion,
        iterations=tuple(history),
        solve_time_s=time.perf_counter() - wall,
        stop_reason=stop,
        terminal_residual=terminal_residual(x[-1], p.goal),
        violations=current.violations,
        collision_free=collision_free(p.scene, x, current.u, p.dt, p.theta),
        crb_std=cramer_rao_std(fim_meas, p.theta),
        information_over_time=cumulative_information(x, current.u, p.theta, p.dt, p.measurement,
                                                     rollout=current.rollout),
        initial=initial,
    )


def restore_rotation_endpoint(
    problem: ExcitationProblem, u: np.ndarray, iterations: int = 3, target_fraction: float = 0.1, fast: bool = False
) -> np.ndarray:
    """Second-order correction of a trial step: Gauss-Newton on the final attitude and rate, torques only.

    The translational motion is exactly linear in the force, but the final attitude is a strongly nonlinear
    function of the torques over a long horizon, so a trial step that is good for the criterion often misses the
    terminal attitude by more than its tolerance (the Maratos effect of exact-penalty SQP). Each iteration solves
    ``r(u) + J δτ = 0`` for ``r = [e_N, ω_N − ω_goal]`` (6) with the exact RK4 Jacobians along the trial rollout, in
    the least-norm sense weighted by the torque headroom ``(τ_max − |τ|)²`` (saturated steps barely move), then
    clips to the torque limits.

    Parameters
    ----------
    problem : ExcitationProblem
    u : ndarray, shape (N, 6)
        Trial inputs.
    iterations : int, optional
        Gauss-Newton iterations.
    target_fraction : float, optional
        Stop once the residual is below this fraction of the terminal tolerance.
    fast : bool, optional
        Roll out with :func:`oacli.excitation.split_information.rollout` (same Jacobians to rounding).

    Returns
    -------
    ndarray, shape (N, 6)
        Inputs with corrected torques.
    """
    p = problem
    u = np.array(u, dtype=float)
    n = p.steps
    tau_max = p.limits.torque_Nm
    tol = p.terminal
    for _ in range(iterations):
        if fast:
            ro = split_information.rollout(p.start, u, p.theta, p.dt)
            x, a_rot, b_rot = ro.x, ro.a_rot, ro.b_rot
        else:
            x = np.empty((n + 1, 13))
            x[0] = p.start
            a_rot = np.empty((n, 7, 7))
            b_rot = np.empty((n, 7, 3))
            for k in range(n):
                x_next, a, b, _ = rb.rk4_step_jacobians(x[k], u[k], p.theta, p.dt)
                x_next[6:10] = quat.normalize(x_next[6:10])
                x[k + 1] = x_next
                a_rot[k] = a[6:13, 6:13]
                b_rot[k] = b[6:13, 3:6]
        err, jac = attitude_error(p.goal[6:10], x[n, 6:10])
        rate = x[n, 10:13] - p.goal[10:13]
        if (np.max(np.abs(err)) <= target_fraction * tol.attitude_rad
                and np.max(np.abs(rate)) <= target_fraction * tol.angular_velocity_radps):
            break
        m = np.zeros((6, 7))
        m[0:3, 0:4] = jac
        m[3:6, 4:7] = np.eye(3)
        jt = np.empty((n, 6, 3))
        for k in range(n - 1, -1, -1):
            jt[k] = m @ b_rot[k]
            m = m @ a_rot[k]
        j_flat = jt.transpose(1, 0, 2).reshape(6, 3 * n)
        weight = ((tau_max - np.abs(u[:, 3:6])) ** 2 + (0.01 * tau_max) ** 2).reshape(-1)
        residual = np.concatenate([err, rate])
        step = -weight * (j_flat.T @ np.linalg.solve((j_flat * weight) @ j_flat.T, residual))
        u[:, 3:6] = np.clip(u[:, 3:6] + step.reshape(n, 3), -tau_max, tau_max)
    return u


def _rotational_violation(ev: Evaluation) -> float:
    v = ev.violations
    return v["angular_velocity"] + v["terminal_attitude"] + v["terminal_angular_velocity"]


def _fim_step(gradients: np.ndarray, du: np.ndarray) -> np.ndarray:
    """First-order change of F for a step δu, from the gradients of its distinct entries (10 for the 4 entries,
    ``p(p+1)/2`` in the order of :func:`oacli.excitation.design_full.symmetric_pairs` for p)."""
    vals = np.einsum("pki,ki->p", gradients, du)
    if gradients.shape[0] == len(SYMMETRIC_PAIRS):
        pairs, size = SYMMETRIC_PAIRS, N_PARAMS
    else:
        size = int((np.sqrt(8 * gradients.shape[0] + 1) - 1) // 2)
        pairs = symmetric_pairs(size)
    out = np.zeros((size, size))
    for idx, (a, b) in enumerate(pairs):
        out[a, b] = out[b, a] = vals[idx]
    return out


def cumulative_information(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
    rollout: split_information.SplitRollout | None = None,
) -> np.ndarray:
    """Fisher information of the measurements up to each sample, shape (N+1, 4, 4) (zero at t = 0).

    Parameters
    ----------
    x : ndarray, shape (N+1, 13)
        Rollout states of ``u`` (only the start ``x[0]`` is read: the rollout is recomputed).
    u : ndarray, shape (N, 6)
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    dt : float
    model : MeasurementModel
    rollout : SplitRollout, optional
        The split rollout of ``u`` (:func:`oacli.excitation.split_information.rollout`), when at hand.

    Returns
    -------
    ndarray, shape (N+1, 4, 4)
    """
    out = np.zeros((u.shape[0] + 1, N_PARAMS, N_PARAMS))
    if rollout is not None:
        out[1:] = np.cumsum(split_information.information_per_step(rollout, u, theta, model), axis=0)
    else:
        out[1:] = np.cumsum(information_per_step(x[0], u, theta, dt, model), axis=0)
    return out


__all__ = [
    "ExcitationDesign",
    "ExcitationProblem",
    "ScpIterate",
    "ScpSettings",
    "cumulative_information",
    "design_excitation",
    "initial_guess",
    "perturbed_guess",
    "restore_rotation_endpoint",
    "terminal_residual",
]
