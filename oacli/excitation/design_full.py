"""The offline excitation design ([Doerr2021] Eq. 30) for chosen entries of the full rigid body.

The SCP of :mod:`oacli.excitation.design` with three pieces replaced, everything else (rollouts for the constraints,
the linearised dynamics, the slacks, the trust regions, the merit test) as it is:

* **the merit's criterion** (:class:`FullScpMerit`): the scaled A-criterion ``tr (D F D)⁻¹`` of the chosen entries
  (:func:`oacli.excitation.information_full.a_criterion_full`, ``D`` of
  :func:`oacli.excitation.information_full.parameter_scale`: the prior σ by default, so unit free), with ``F`` the full
  model's information plus the prior of the entries beyond mass and inertia
  (:func:`oacli.excitation.information_full.add_prior_information`: without it the scales make ``F`` singular) and
  the problem's prior information on mass and inertia when it has one;
* **the FIM model of the subproblem** (:class:`FullConvexSubproblem`): ``F̃(δu) = F̃0 + Σ_ab E_ab ⟨∇F̃_ab, δu⟩`` over
  all ``p(p+1)/2`` entries and both input channels (the centre of mass couples the force into the rotation, so the
  4-entry structure ``F_mI ≡ 0`` does not hold), and the exact convex A-criterion of it by the Schur complement;
* **the FIM gradients** (:func:`full_linearisation`): the batched central differences of
  :func:`oacli.excitation.information_full.functional_gradient`, one batch for all entries.

Only the A-criterion is offered (the D- and E-criteria would need no scaling, but are not wired). The design's
``fim``, ``crb_std`` and ``information_over_time`` stay the 4 entries' (what the outputs of the excite stage are
about); :class:`oacli.excitation.design_types.FullDesignSpec` keeps the chosen entries and the criterion is theirs.
"""

from __future__ import annotations

from dataclasses import replace

import cvxpy as cp
import numpy as np

from oacli.errors import InfeasibleError
from oacli.excitation import split_information
from oacli.excitation.design_types import ExcitationProblem, FullDesignSpec
from oacli.excitation.fim_gradient import FimGradient
from oacli.excitation.information_full import (
    a_criterion_full,
    add_prior_information,
    fisher_information_full,
    functional_gradient,
)
from oacli.excitation.merit import Evaluation, ScpMerit
from oacli.excitation.subproblem import ConvexSubproblem

__all__ = ["FullConvexSubproblem", "FullDesignSpec", "FullScpMerit", "full_linearisation", "symmetric_pairs"]


def symmetric_pairs(p: int) -> tuple[tuple[int, int], ...]:
    """``(a, b)``, ``a ≤ b``, of a symmetric p×p matrix, row by row (the order of
    :data:`oacli.excitation.fim_gradient.SYMMETRIC_PAIRS` for p = 4).

    Parameters
    ----------
    p : int

    Returns
    -------
    tuple of (int, int)
    """
    return tuple((a, b) for a in range(p) for b in range(a, p))


class FullScpMerit(ScpMerit):
    """:class:`oacli.excitation.merit.ScpMerit` with the full θ's criterion (module docstring).

    Parameters
    ----------
    problem : ExcitationProblem
        Its ``criterion`` must be ``"A"``.
    penalty : float
    spec : FullDesignSpec
    """

    def __init__(self, problem: ExcitationProblem, penalty: float, spec: FullDesignSpec) -> None:
        if problem.criterion != "A":
            raise ValueError("the full θ's design has the A-criterion only")
        super().__init__(problem, penalty, fast=True)
        self.spec = spec
        self.d = np.diag(spec.scale)
        p = spec.index.size
        prior = add_prior_information(np.zeros((p, p)), spec.groups, spec.prior_std)
        prior[0:4, 0:4] += problem.prior
        self.prior = prior
        """Prior information (p, p) added to the measurements'."""

    def evaluate(self, u: np.ndarray) -> Evaluation:
        """Roll out ``u`` and measure the full criterion, violations and merit.

        Parameters
        ----------
        u : ndarray, shape (N, 6)

        Returns
        -------
        Evaluation
            ``fim`` is the chosen entries' (p, p), prior included.
        """
        p = self.p
        ro = split_information.rollout(p.start, u, p.theta, p.dt)
        fim = fisher_information_full(p.start, u, self.spec.theta, p.dt, p.measurement, self.spec.groups).fim
        fim = fim + self.prior
        crit = a_criterion_full(fim, self.spec.scale)
        if self.reference is None:
            if not np.isfinite(crit):
                raise InfeasibleError("the initial excitation carries no information on some parameters of the full "
                                      "rigid body (singular Fisher information)")
            self.reference = crit
        crit_n = self.normalise(crit) if np.isfinite(crit) else np.inf
        viol = self.violations(ro.x)
        return Evaluation(u, ro.x, fim, crit, crit_n, viol, crit_n + self.penalty * sum(viol.values()), ro)


def full_linearisation(problem: ExcitationProblem, spec: FullDesignSpec, ev: Evaluation) -> FimGradient:
    """The rotation's step Jacobians of the iterate (split rollout) with the gradients of the chosen entries' FIM
    entries ``(a, b)`` of :func:`symmetric_pairs` (Q, N, 6), by :func:`functional_gradient`.

    Parameters
    ----------
    problem : ExcitationProblem
    spec : FullDesignSpec
    ev : Evaluation
        The iterate (with its split rollout).

    Returns
    -------
    FimGradient
    """
    p = spec.index.size
    zero = np.zeros((1, 4, 4))
    lin = split_information.fim_gradients(problem.start, ev.u, problem.theta, problem.dt, problem.measurement, zero,
                                          ro=ev.rollout)
    basis = np.zeros((p * (p + 1) // 2, p, p))
    for q, (a, b) in enumerate(symmetric_pairs(p)):
        basis[q, a, b] = basis[q, b, a] = 1.0 if a == b else 0.5
    _, grads = functional_gradient(problem.start, ev.u, spec.theta, problem.dt, problem.measurement, basis,
                                   spec.groups, problem.limits.input)
    return replace(lin, gradients=grads)


class FullConvexSubproblem(ConvexSubproblem):
    """:class:`oacli.excitation.subproblem.ConvexSubproblem` with the FIM model of the chosen entries (module
    docstring); the same constraints, slacks and trust region.

    Parameters
    ----------
    problem : ExcitationProblem
    merit : FullScpMerit
    penalty : float
    compiled : bool, optional
    """

    def __init__(self, problem: ExcitationProblem, merit: FullScpMerit, penalty: float, compiled: bool = True
                 ) -> None:
        self._p_entries = merit.spec.index.size
        super().__init__(problem, merit, penalty, compiled=compiled)

    def _information_model(self, du: cp.Variable, cons: list[cp.Constraint], n: int) -> cp.Expression:
        p = self._p_entries
        pairs = symmetric_pairs(p)
        scatter = np.zeros((p * p, len(pairs)))
        for col, (a, b) in enumerate(pairs):
            scatter[a * p + b, col] = scatter[b * p + a, col] = 1.0
        self.f0 = cp.Parameter((p, p), name="fim0")
        self.g_full = cp.Parameter((len(pairs), 6 * n), name="fim_gradient")
        dfim = cp.Variable(len(pairs), name="fim_change")
        cons.append(dfim == self.g_full @ cp.vec(du, order="C"))
        fim_var = cp.Variable((p, p), symmetric=True, name="fim")
        cons.append(fim_var == self.f0 + cp.reshape(scatter @ dfim, (p, p), order="C"))
        self.crit_param = cp.Parameter((p, p), name="criterion_weight")
        z = cp.Variable((2 * p, 2 * p), PSD=True, name="schur")
        cons += [z[:p, :p] == fim_var, z[:p, p:] == self.crit_param]
        return cp.trace(z[p:, p:])

    def _set_information(self, ev: Evaluation, lin, put) -> None:
        # F̃ = D F D / c, c = tr(D F D)/p; the objective tr(F̃⁻¹)/(c J_ref) = J/J_ref through C = 1/sqrt(c J_ref).
        p = self._p_entries
        d = np.diag(self.merit.d)
        f_s = d[:, None] * ev.fim * d[None, :]
        c = float(np.trace(f_s)) / p
        put(self.f0, f_s / c)
        rows = np.array([d[a] * d[b] / c for a, b in symmetric_pairs(p)])
        put(self.g_full, lin.gradients.reshape(len(rows), -1) * rows[:, None])
        ref = self.merit.reference
        assert ref is not None
        put(self.crit_param, np.eye(p) / np.sqrt(c * ref))
