"""Gauss-Newton with Levenberg-Marquardt damping for the batch problem ([Doerr2021] Eq. 32).

Each iteration linearises ``b(ϑ)`` about ``ϑ̄`` and solves ``(AᵀA + λD) δϑ = −Aᵀb`` (block normal equations by
default, the sparse reference path on request); a step that lowers the cost is taken and λ decreased, else λ is
raised. See :mod:`oacli.estimation.batch` for the continuation and the tolerances.
"""

from __future__ import annotations

import numpy as np

from oacli.estimation.batch_normal import NormalEquations, ReferenceSystem
from oacli.estimation.batch_problem import BatchProblem
from oacli.estimation.manifold import (
    TANGENT_DIM,
    boxplus,
)
from oacli.estimation.models import EstimatorSettings

LAMBDA_INIT = 1e-6
LAMBDA_MAX = 1e12


def linearise(
    problem: BatchProblem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, reference: bool
) -> tuple[np.ndarray, NormalEquations | ReferenceSystem]:
    """Residuals and the normal equations at (x, φ): block form (default) or the sparse reference path.

    The linearisation ``b(ϑ̄) + A δϑ`` of [Doerr2021] Eq. 32 about the current iterate.

    Parameters
    ----------
    problem : BatchProblem
        The batch problem (data, noise models, prior).
    x : ndarray, shape (K, 13)
        States [r m, v m/s, q (x, y, z, w), ω rad/s].
    phi : ndarray, shape (4,)
        φ = [log m, log A, log B, log C] (:mod:`oacli.estimation.parametrization`).
    inliers : ndarray of bool, shape (K,)
        Records whose measurement (and acceleration) rows are used.
    reference : bool
        Assemble the sparse ``A`` and factorise ``AᵀA`` by LU (:class:`ReferenceSystem`) instead of the block
        normal equations (:class:`NormalEquations`).

    Returns
    -------
    b : ndarray, shape (N,)
        Whitened residuals (dimensionless).
    system : NormalEquations or ReferenceSystem
        The normal equations ``AᵀA δϑ = −Aᵀb`` at (x, φ).
    """
    if reference:
        b, a_mat = problem.evaluate(x, phi, inliers, jacobian=True)
        return b, ReferenceSystem(b, a_mat)  # type: ignore[arg-type]
    b, normal = problem.normal_equations(x, phi, inliers)
    return b, normal  # type: ignore[return-value]


EARLY_STOP_STEP = 1e-6
"""Largest step entry (m, m/s, rad, rad/s of the states' tangents; log-parameters of φ) :func:`levenberg_marquardt`
may leave untaken when the linearised cost predicts a decrease below the tolerance."""


def levenberg_marquardt(
    problem: BatchProblem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, settings: EstimatorSettings,
    history: list[float], reference: bool = False, lambda_init: float = LAMBDA_INIT,
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Minimise ‖b‖² from (x, φ) starting with damping ``lambda_init``; returns the solution, the iterations done
    and whether it converged.

    Gauss-Newton steps of [Doerr2021] Eq. 32 on the maximum-likelihood problem Eq. 31, damped as
    ``(AᵀA + λ D) δϑ = −Aᵀb`` with ``D`` the diagonal of ``AᵀA`` (floored at 1e-12 of its largest entry); the states
    are updated on the manifold (``x ⊞ δx``), φ additively. λ is divided by 10 after a step that does not raise the
    cost and multiplied by 10 after one that does, up to ``LAMBDA_MAX``.

    Parameters
    ----------
    problem : BatchProblem
        The batch problem (data, noise models, prior).
    x : ndarray, shape (K, 13)
        Initial states [r m, v m/s, q (x, y, z, w), ω rad/s].
    phi : ndarray, shape (4,)
        Initial φ = [log m, log A, log B, log C].
    inliers : ndarray of bool, shape (K,)
        Records whose measurement (and acceleration) rows are used.
    settings : EstimatorSettings
        ``max_iterations`` and ``tolerance`` (on the relative cost decrease and on the largest step entry).
    history : list of float
        Appended with the cost ‖b‖² at the start and after every accepted step (mutated in place).
    reference : bool, default False
        Use the sparse reference path (:func:`linearise`).
    lambda_init : float, default LAMBDA_INIT
        Initial damping λ (dimensionless, relative to ``D``).

    Returns
    -------
    x : ndarray, shape (K, 13)
        Final states.
    phi : ndarray, shape (4,)
        Final φ.
    iterations : int
        Iterations done.
    converged : bool
        True when the relative cost decrease (achieved, or predicted by the linearised problem for a next step
        below :data:`EARLY_STOP_STEP`, which is then not taken) or the step fell below ``settings.tolerance``, or
        no damping up to
        ``LAMBDA_MAX`` lowers the cost (a minimum within rounding); False after ``max_iterations`` or when the
        damped system stays singular.
    """
    b, system = linearise(problem, x, phi, inliers, reference)
    cost = float(b @ b)
    history.append(cost)
    lam = lambda_init
    k = problem.k
    for it in range(1, settings.max_iterations + 1):
        h_diag = system.diagonal()
        diag = np.maximum(h_diag, 1e-12 * max(h_diag.max(), 1.0))
        retried = False
        while True:
            step = system.solve(lam * diag)
            if step is None:
                lam *= 10.0
                if lam > LAMBDA_MAX:
                    return x, phi, it, False
                continue
            if not retried and float(np.max(np.abs(step))) < EARLY_STOP_STEP:
                # Converged before a negligible step: the linearised cost predicts a relative decrease below the
                # tolerance (the test below, on the step the model predicts, without propagating to it). Not for a
                # larger step (a flat direction, e.g. a filter's bootstrap on a few records): that one is taken.
                if system.predicted_decrease(step) < settings.tolerance * max(cost, 1e-300):
                    return x, phi, it, True
            x_new = boxplus(x, step[: TANGENT_DIM * k].reshape(k, TANGENT_DIM))
            phi_new = phi + step[TANGENT_DIM * k:]
            # The first trial of an iteration is linearised at once (it is nearly always taken); after a rejection
            # the cost comes first, from the end states only, and the Jacobians only for a step that is taken.
            cheap = retried and not reference
            try:
                with np.errstate(all="ignore"):  # a wild trial step may overflow; it is then rejected below
                    if cheap:
                        b_new = problem.jacobian_groups(x_new, phi_new, inliers, jacobian=False)[0]
                    else:
                        b_new, system_new = linearise(problem, x_new, phi_new, inliers, reference)
                    cost_new = float(b_new @ b_new)
            except np.linalg.LinAlgError:  # a wild trial step made a matrix of the model singular (the full rigid
                cost_new = float("inf")    # body's inertia tensor): rejected like an overflow, more damping
            if np.isfinite(cost_new) and cost_new <= cost:
                if cheap:
                    b_new, system_new = linearise(problem, x_new, phi_new, inliers, reference)
                    cost_new = float(b_new @ b_new)
                break
            retried = True
            lam *= 10.0
            if lam > LAMBDA_MAX:
                return x, phi, it, True  # no descent left: at a minimum within rounding
        decrease = (cost - cost_new) / max(cost, 1e-300)
        step_size = float(np.max(np.abs(step)))
        x, phi, b, system, cost = x_new, phi_new, b_new, system_new, cost_new
        history.append(cost)
        lam = max(lam / 10.0, 1e-15)
        if decrease < settings.tolerance or step_size < settings.tolerance:
            return x, phi, it, True
    return x, phi, settings.max_iterations, False
