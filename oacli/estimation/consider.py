"""Schmidt "consider" covariance: the held parameters' prior uncertainty in the σ of the estimated ones.

The batch ([Doerr2021] Eqs. 31-32) and the sequential filter estimate a chosen part of the full rigid body
(``estimation.parameters``, :mod:`oacli.estimation.rigid_parameters`) and hold the other groups at their prior mean
``h₀``. Their covariance ``P = [(AᵀA)⁻¹]_θθ`` treats the held values as exact, but they are known only to their
prior ``P_h`` (``estimation.rigid_body``: products of inertia 0 ± 0.005 kg·m², torque scales 1 ± 5 %). Linearised
at the solution, with ``b(θ, h)`` the whitened residuals, ``A = ∂b/∂θ`` (states and estimated parameters) and
``B = ∂b/∂h``, the estimate moves with the held values as

    S = ∂θ̂/∂h = −(AᵀA)⁻¹ AᵀB,      cov(θ̂ − θ) = P + S P_h Sᵀ

(S. F. Schmidt's consider covariance, 1966; [Tapley2004] Ch. 6, "Consider covariance analysis"). For the linear
model ``y = Aθ + Bh + e`` with ``h ~ N(h₀, P_h)`` held at ``h₀`` this is exact (the tests check it against the
closed form and by Monte Carlo). Held products of inertia are mapped through φ (log-Cholesky), exactly at a held
mean of 0 (the default: ``dθ_held/dφ_est = 0`` there), to first order otherwise.

``S`` is computed without forming ``AᵀA``: the held entries are appended to φ as the last columns of the batch
problem's border (:class:`AugmentedModel`, the prior kept on the estimated entries only), and the block QR of
``A`` of :meth:`oacli.estimation.batch_problem.BatchProblem.last_covariance_qr` is run on ``[A, B]``. Its last
triangular block over ``[x_K, φ, h]``, ``[[R₁₁, R₁₂], [0, R₂₂]]``, gives ``S₁ = −R₁₁⁻¹R₁₂`` (the least-squares
solution for ``[x_K, φ]`` with ``h`` fixed, ``R₁₁ z = c − R₁₂ h``) and ``R₁₁⁻¹R₁₁⁻ᵀ = P`` (:func:`split_triangular`).
``R₂₂`` (what the data say about ``h``) is never needed, so held entries the data do not see at all are fine.

Two covariances are reported (docs/estimation.md, "Held groups: the consider covariance"):

* **physical**: every held group considered: the σ of the physical m, J, c, κ_F against the truth (summary
  ``std``, ``rigid_body``);
* **handed on** (``effective``): the inertias taken as the effective inertia ``J_i/κ_τ,i`` (:data:`ABSORBED`), what
  a controller commanding ``τ`` with κ_τ = 1 needs: ``ω̇ = J⁻¹(κ_τ ⊙ τ − ω × Jω)`` sees J and κ_τ mostly as
  ``J/κ_τ``, so the held κ_τ's uncertainty enters only through what the data identify of J itself (the gyroscopic
  term), :func:`effective_sensitivity`. The controllers (segment 3's model, W of [Doerr2021] Eq. 28) get this one.

The sequential filter's final estimate of a constant parameter equals the batch posterior for a linear-Gaussian
model, so its ``S`` is the batch problem's at the filter's estimates (:func:`consider_held`), added to the filter's
own ``P`` (a post-hoc Schmidt-Kalman filter: the held entries as consider states with zero gain).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla

from oacli.estimation.batch_model import FullModel
from oacli.estimation.batch_problem import BatchProblem, last_triangular_block
from oacli.estimation.manifold import TANGENT_DIM
from oacli.estimation.models import EstimatorSettings, Measurement
from oacli.estimation.rigid_parameters import (
    FULL_NAMES,
    GROUPS,
    phi_from_theta_full,
    theta_from_phi_full,
    theta_jacobian_full,
)
from oacli.types import ParameterEstimate

__all__ = ["ABSORBED", "AugmentedModel", "ConsiderCovariance", "batch_sensitivity", "consider_covariance",
           "consider_held", "effective_sensitivity", "held_index", "linear_sensitivity", "split_triangular"]

ABSORBED: dict[str, str] = {"torque_scale": "inertia"}
"""Held group → the estimated group whose value absorbs it in the model a controller flies: the diagonal inertia as
``J_i/κ_τ,i`` (the control law commands torque; ``J/κ_τ`` enters ``ω̇`` but for the gyroscopic term;
:func:`effective_sensitivity`). A held force scale is not absorbed: per body axis, it cannot be folded into one
scalar mass."""


def consider_covariance(cov: np.ndarray, sensitivity: np.ndarray, cov_held: np.ndarray) -> np.ndarray:
    """``P + S P_h Sᵀ`` (symmetrised): the covariance of an estimate whose held parameters have covariance ``P_h``.

    Parameters
    ----------
    cov : ndarray, shape (n, n)
        ``P``, the estimate's covariance with the held parameters exact.
    sensitivity : ndarray, shape (n, n_h)
        ``S = ∂θ̂/∂h``.
    cov_held : ndarray, shape (n_h, n_h)
        ``P_h``, the held parameters' prior covariance.

    Returns
    -------
    ndarray, shape (n, n)
    """
    s = np.asarray(sensitivity, dtype=float)
    out = np.asarray(cov, dtype=float) + s @ np.asarray(cov_held, dtype=float) @ s.T
    return 0.5 * (out + out.T)


def split_triangular(r: np.ndarray, n1: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``P₁ = R₁₁⁻¹R₁₁⁻ᵀ`` and ``S₁ = −R₁₁⁻¹R₁₂`` of an upper triangular ``R`` over ``[z₁ (n1), h]``.

    With ``A = QR`` the least-squares solution for ``z₁`` at a fixed ``h`` is ``R₁₁ z₁ = c₁ − R₁₂ h``: its covariance
    is ``P₁`` and its sensitivity to ``h`` is ``S₁`` (module docstring). None when ``R₁₁`` is singular (a negligible
    pivot: ``z₁`` not identified).

    Parameters
    ----------
    r : ndarray, shape (m, n1 + n_h), m >= n1
        Upper triangular (rows beyond ``n1`` may be missing or rank deficient).
    n1 : int
        Columns of ``z₁``.

    Returns
    -------
    tuple of ndarray (n1×n1, n1×n_h), or None
    """
    r = np.asarray(r, dtype=float)
    if r.shape[0] < n1:
        return None
    r11, r12 = r[:n1, :n1], r[:n1, n1:]
    piv = np.abs(np.diag(r11))
    if not np.all(np.isfinite(r[:n1])) or np.min(piv) <= 1e-14 * np.max(piv):
        return None
    r_inv = sla.solve_triangular(r11, np.eye(n1), check_finite=False)
    return r_inv @ r_inv.T, -(r_inv @ r12)


def linear_sensitivity(a_est: np.ndarray, a_held: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``P = (AᵀA)⁻¹`` and ``S = −(AᵀA)⁻¹AᵀB`` of whitened least squares ``min ‖A θ + B h − y‖²`` at fixed ``h``,
    from a QR factorisation of ``[A, B]`` (:func:`split_triangular`): the dense form of :func:`batch_sensitivity`.

    Parameters
    ----------
    a_est : ndarray, shape (m, n)
        ``A`` (whitened: unit noise).
    a_held : ndarray, shape (m, n_h)
        ``B``.

    Returns
    -------
    tuple of ndarray (n×n, n×n_h), or None when ``A`` has not full column rank
    """
    a = np.hstack([np.asarray(a_est, dtype=float), np.asarray(a_held, dtype=float)])
    return split_triangular(np.asarray(np.linalg.qr(a, mode="r")), np.shape(a_est)[1])


@dataclass(frozen=True)
class AugmentedModel(FullModel):
    """A :class:`FullModel` whose φ is ``[φ of the estimated entries, φ of the held entries held]``: the batch
    problem's border gets the held entries' columns ``B`` (the prior stays on the estimated entries, so the rows
    and the estimated columns are those of the problem solved).

    Attributes
    ----------
    held : ndarray of int
        θ/φ indices of the held entries appended (in θ order).
    """

    held: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def n(self) -> int:
        """Estimated plus held entries."""
        return self.params.n + int(self.held.size)

    @property
    def prior_index(self) -> np.ndarray:
        """The estimated entries (the prior's rows are the solved problem's)."""
        return self.params.index

    @property
    def differentiated(self) -> np.ndarray:
        """The estimated and the held entries (``B``'s columns need the held ones' sensitivities too)."""
        return np.union1d(super().differentiated, np.asarray(self.held, dtype=int)).astype(int)

    def phi_full(self, phi: np.ndarray) -> np.ndarray:
        """The 16-entry φ of ``[φ_est, φ_held]``.

        Parameters
        ----------
        phi : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (16,)
        """
        phi = np.asarray(phi, dtype=float)
        out = phi_from_theta_full(self.params.theta_fixed)
        out[self.params.index] = phi[:self.params.n]
        out[self.held] = phi[self.params.n:]
        return out

    def theta(self, phi: np.ndarray) -> np.ndarray:
        """θ (16) of ``[φ_est, φ_held]``.

        Parameters
        ----------
        phi : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (16,)
        """
        return theta_from_phi_full(self.phi_full(phi))

    def jacobian(self, phi: np.ndarray) -> np.ndarray:
        """``dθ/d[φ_est, φ_held]`` (16×n).

        Parameters
        ----------
        phi : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (16, n)
        """
        return theta_jacobian_full(self.phi_full(phi))[:, np.r_[self.params.index, self.held]]


def held_index(model: FullModel) -> np.ndarray:
    """θ indices of the entries ``model`` holds whose prior variance is positive (the ones to consider).

    Parameters
    ----------
    model : FullModel

    Returns
    -------
    ndarray of int
    """
    est = set(model.params.index.tolist())
    var = np.diag(model.prior_cov)
    return np.array([i for i in range(var.size) if i not in est and var[i] > 0], dtype=int)


def batch_sensitivity(problem: BatchProblem, states: np.ndarray, phi: np.ndarray, inliers: np.ndarray,
                      n_est: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``P`` and ``S`` of ``[δx_K, δφ_est]`` against ``δφ_held`` from the block QR of the augmented problem.

    Parameters
    ----------
    problem : BatchProblem
        Built with an :class:`AugmentedModel` (φ = ``[φ_est, φ_held]``).
    states : ndarray, shape (K, 13)
        The solution's states.
    phi : ndarray, shape (n_est + n_held,)
        ``[φ_est at the solution, φ_held at the held values]``.
    inliers : ndarray of bool, shape (K,)
        Records whose measurements were used.
    n_est : int
        Estimated entries.

    Returns
    -------
    tuple of ndarray ((12 + n_est)², (12 + n_est)×n_held), or None when not identified
    """
    if problem.k < 2:
        return None
    _, groups = problem.jacobian_groups(states, phi, inliers)
    r = last_triangular_block(groups, problem.k, problem.n_par, full_last=False)
    return None if r is None else split_triangular(r, TANGENT_DIM + n_est)


@dataclass(frozen=True)
class ConsiderCovariance:
    """The estimate's covariance with the held entries' prior uncertainty (module docstring).

    Attributes
    ----------
    theta : ndarray, shape (16,)
        θ̂ (held entries at their held values).
    statistical : ndarray, shape (16, 16)
        The estimator's own covariance (held entries exact: zero rows).
    physical : ndarray, shape (16, 16)
        ``statistical + T P_h Tᵀ`` with ``T = dθ̂/dθ_held`` over every held entry; the held entries' rows carry their
        prior.
    effective : ndarray, shape (16, 16)
        The same with the inertias taken as ``J_i/κ_τ,i`` (:func:`effective_sensitivity`; what is handed to the
        controllers).
    sensitivity : ndarray, shape (16, n_held)
        ``T = dθ̂/dθ_held`` [θ units per θ_held unit].
    held : ndarray of int
        θ indices of the held entries considered.
    absorbed : ndarray of int
        Those the effective inertia absorbs (:data:`ABSORBED`).
    """

    theta: np.ndarray
    statistical: np.ndarray
    physical: np.ndarray
    effective: np.ndarray
    sensitivity: np.ndarray
    held: np.ndarray
    absorbed: np.ndarray

    def summary(self, index: np.ndarray) -> dict[str, Any]:
        """The summary's ``consider`` section for the estimated entries ``index``.

        Parameters
        ----------
        index : ndarray of int
            θ indices of the estimated entries.

        Returns
        -------
        dict
        """
        def std(cov: np.ndarray) -> dict[str, float]:
            return {FULL_NAMES[i]: float(np.sqrt(max(cov[i, i], 0.0))) for i in index}

        return {
            "held": [FULL_NAMES[i] for i in self.held],
            "absorbed_in_handed": [FULL_NAMES[i] for i in self.absorbed],
            "std_statistical": std(self.statistical), "std_physical": std(self.physical),
            "std_handed": std(self.effective),
            "sensitivity": {FULL_NAMES[i]: {FULL_NAMES[h]: float(self.sensitivity[i, j])
                                            for j, h in enumerate(self.held)} for i in index},
        }


def consider_held(records: Sequence[Measurement], settings: EstimatorSettings, prior: ParameterEstimate | None,
                  model: FullModel, states: np.ndarray, inliers: np.ndarray, theta: np.ndarray,
                  covariance: np.ndarray) -> ConsiderCovariance | None:
    """The consider covariance of an estimate of ``model`` (batch or sequential) from the batch problem's
    sensitivity at it (module docstring).

    Parameters
    ----------
    records : sequence of Measurement
        The records estimated, in time order (one per row of ``states``).
    settings : EstimatorSettings
    prior : ParameterEstimate or None
        The prior the estimate used (None: the batch without it).
    model : FullModel
    states : ndarray, shape (K, 13)
        The estimate's states (batch: smoothed; sequential: filtered).
    inliers : ndarray of bool, shape (K,)
        Records whose measurements were used.
    theta : ndarray, shape (16,)
        θ̂.
    covariance : ndarray, shape (16, 16)
        The estimator's covariance of θ̂.

    Returns
    -------
    ConsiderCovariance or None
        None when nothing is held with a positive prior variance or the covariance is not finite (then the
        estimator's own covariance stands, exactly as before).
    """
    held = held_index(model)
    cov = np.asarray(covariance, dtype=float)
    if held.size == 0 or not np.all(np.isfinite(cov)) or len(records) < 2:
        return None
    est = model.params.index
    aug = AugmentedModel(model.params, model.prior_mean, model.prior_cov, held)
    theta_w = prior.theta if prior is not None else np.asarray(theta, dtype=float)[:4]
    problem = BatchProblem(records, settings, prior, theta_w, aug)
    phi_full = phi_from_theta_full(np.asarray(theta, dtype=float))
    phi = np.r_[phi_full[est], phi_from_theta_full(model.params.theta_fixed)[held]]
    x = np.asarray(states, dtype=float)
    used = np.asarray(inliers, dtype=bool) & problem.has_state
    if problem.has_gaps:  # the lost inputs' model corrected with the solution's residuals, as the batch does
        problem.set_lost_inputs(problem.measurement_noise(x, used), aug.theta4(phi))
    split = batch_sensitivity(problem, x, phi, used, est.size)
    if split is None:
        return None
    s_phi = split[1][TANGENT_DIM:]  # dφ̂_est/dφ_held
    jac = theta_jacobian_full(aug.phi_full(phi))
    t_phi = jac[:, est] @ s_phi + jac[:, held]  # dθ̂/dφ_held (the held θ move with their own φ)
    t_theta = t_phi @ np.linalg.inv(jac[np.ix_(held, held)])  # dθ̂/dθ_held (exact when dθ_held/dφ_est = 0)
    p_held = model.prior_cov[np.ix_(held, held)]
    absorbed_groups = {g for g, by in ABSORBED.items() if by in model.params.groups}
    absorbed = np.array([i for i in held if any(i in GROUPS[g] for g in absorbed_groups)], dtype=int)
    physical = consider_covariance(cov, t_theta, p_held)
    effective = consider_covariance(cov, effective_sensitivity(t_theta, held, absorbed, theta,
                                                               model.params.theta_fixed), p_held)
    return ConsiderCovariance(np.asarray(theta, dtype=float), cov, physical, effective, t_theta, held, absorbed)


def effective_sensitivity(sensitivity: np.ndarray, held: np.ndarray, absorbed: np.ndarray, theta: np.ndarray,
                          theta_fixed: np.ndarray) -> np.ndarray:
    """``dθ̂/dh`` of the estimate taken as the effective inertia ``J_a h₀,a/κ_τ,a`` (``J_a/κ_τ,a`` for ``h₀ = 1``).

    With the held torque scale ``h₀`` and the truth's ``κ``, ``θ̂ ≈ J + T (h₀ − κ)`` while the effective inertia a
    controller assuming ``h₀`` needs is ``J h₀/κ ≈ J + (J/h₀)(h₀ − κ)``: the error against it moves with
    ``T − J_a/h₀,a`` on the column of ``κ_τ,a`` and row of ``J_aa``. It vanishes when the data see only ``J/κ_τ``;
    the gyroscopic term ``ω × Jω`` (which does not scale with ``κ_τ``) identifies part of J itself and leaves the
    rest.

    Parameters
    ----------
    sensitivity : ndarray, shape (16, n_held)
        ``T = dθ̂/dθ_held``.
    held, absorbed : ndarray of int
        θ indices of the held entries (the columns) and of those absorbed (torque scales).
    theta : ndarray, shape (16,)
        θ̂.
    theta_fixed : ndarray, shape (16,)
        The held values ``h₀``.

    Returns
    -------
    ndarray, shape (16, n_held)
    """
    out = np.array(sensitivity, dtype=float)
    first = GROUPS["torque_scale"][0]
    for j, h in enumerate(np.asarray(held).tolist()):
        if h in set(np.asarray(absorbed).tolist()):
            axis = 1 + h - first  # J_aa's θ index
            out[axis, j] -= float(theta[axis]) / float(theta_fixed[h])
    return out
