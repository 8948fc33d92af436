"""RATTLE's information term for chosen entries of the full rigid body ([ReSWARM2023] §4.4 generalised).

The planner of :mod:`oacli.excitation.rattle` rewards ``Σ_i γ_i · ½ log(1 + F_ii σ_i²)`` over θ = [m, Ixx, Iyy, Izz].
With :class:`oacli.excitation.information_full.FullInformationTerm` the sum runs over the chosen entries of the full θ
(:mod:`oacli.estimation.rigid_parameters`; ``excitation.information.parameters``): ``F`` is the full model's
Fisher information along the horizon (:func:`oacli.excitation.information_full.fisher_information_full`), its input
gradient the batched central differences of :func:`oacli.excitation.information_full.functional_gradient`, the
weights γ follow RATTLE's decay rule per entry (:func:`oacli.excitation.rattle.information_weights`) and the σ of
an entry is the sequential filter's (its full estimate) where it estimates the entry, else the entry's prior σ
(:func:`entry_estimate`). Each term ``½ log(1 + F_ii σ_i²)`` is in nats whatever the unit of the entry, so the
information term needs no further scaling.
"""

from __future__ import annotations

import numpy as np

from oacli.estimation.rigid_parameters import GROUPS, N_FULL
from oacli.excitation.information_full import FullInformationTerm, entry_index
from oacli.excitation.rattle import InformationWeighting

__all__ = ["FullInformationTerm", "entry_estimate", "full_weighting"]


def full_weighting(base: InformationWeighting, groups: tuple[str, ...], gamma0: dict[str, float],
                   floor: dict[str, float]) -> InformationWeighting:
    """RATTLE's weighting over the chosen entries: mass and inertia from ``base``, the other groups' γ0 and floor
    per group (one value for each entry of the group).

    Parameters
    ----------
    base : InformationWeighting
        The 4-parameter weighting (γ0, floor, α, β).
    groups : tuple of str
    gamma0, floor : dict of str to float
        Per group beyond mass and inertia [unit of the entries for the floor].

    Returns
    -------
    InformationWeighting
    """
    g0 = [base.gamma0[i] if i < 4 else 0.0 for i in entry_index(groups)]
    fl = [base.floor[i] if i < 4 else 0.0 for i in entry_index(groups)]
    for pos, i in enumerate(entry_index(groups)):
        if i >= 4:
            group = next(g for g, members in GROUPS.items() if i in members)
            g0[pos], fl[pos] = gamma0[group], floor[group]
    return InformationWeighting(np.array(g0), np.array(fl), base.alpha, base.beta)


def entry_estimate(estimate_theta: np.ndarray, estimate_std: np.ndarray, term: FullInformationTerm,
                   full: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """θ (16) and the σ of the chosen entries for a replan.

    Parameters
    ----------
    estimate_theta, estimate_std : ndarray, shape (4,)
        The estimator's ``[m, I]`` and their σ.
    term : FullInformationTerm
    full : (ndarray (16,), ndarray (16, 16)), optional
        The estimator's full estimate and covariance (:meth:`oacli.estimation.sequential.SequentialEstimator.
        full_estimate`); an entry with zero variance there is not estimated, its σ is its prior's (a 4-parameter
        filter's (4,) estimate adds nothing).

    Returns
    -------
    theta : ndarray, shape (16,)
    std : ndarray, shape (p,)
    """
    idx = term.index
    theta = term.theta(estimate_theta)
    std = np.asarray(term.prior_std, dtype=float).reshape(N_FULL).copy()
    std[0:4] = estimate_std
    if full is not None and np.asarray(full[0]).size == N_FULL:  # a 4-parameter filter's is (4,): nothing more
        theta_f, cov_f = (np.asarray(a, dtype=float) for a in full)
        var = np.diag(cov_f)
        estimated = var > 0
        estimated[0:4] = False
        theta[4:] = theta_f[4:]
        std[estimated] = np.sqrt(var[estimated])
    return theta, std[idx]
