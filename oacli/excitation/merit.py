"""The merit of the offline excitation design's SCP (:mod:`oacli.excitation.design`): criterion and constraint
violations of a rollout of the nonlinear model.

The merit of an input sequence ``u`` is ``φ = J/J_ref + μ·V`` ([Doerr2021] Eq. 30 for the criterion ``J``
of the Fisher information, Eq. 29): ``J_ref`` the criterion of the first start, ``μ`` the exact-penalty weight and
``V`` the normalised constraint violation of the rollout (velocity and angular-rate limits, keep-in boxes and
keep-out zones between samples, see :mod:`oacli.excitation.problem`, and the terminal tolerance), measured as the
subproblem's slacks measure it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.errors import InfeasibleError
from oacli.excitation import split_information
from oacli.excitation.design_types import ExcitationProblem
from oacli.excitation.fim_gradient import criterion_value, scaling_matrix
from oacli.excitation.information import N_PARAMS, output_sensitivities, propagate_with_sensitivities
from oacli.excitation.problem import (
    LENGTH_UNIT_M,
    attitude_error,
    chord_margin_m,
    keep_in_sample_violation,
    keep_out_violation,
)


@dataclass(frozen=True)
class Evaluation:
    """A rollout of the nonlinear model and everything the merit needs.

    Attributes
    ----------
    u : ndarray, shape (N, 6)
        Inputs.
    x : ndarray, shape (N+1, 13)
        Their rollout from the problem's start.
    fim : ndarray, shape (4, 4)
        Fisher information of the rollout's measurements plus the prior information.
    criterion : float
        Design criterion of ``fim`` ([Doerr2021] Eq. 30).
    criterion_normalised : float
        ``criterion`` relative to the reference (:meth:`ScpMerit.normalise`).
    violations : dict
        Normalised violation per constraint kind (0 when it holds).
    merit : float
        ``criterion_normalised + μ Σ violations``.
    rollout : SplitRollout or None
        The split rollout with its Jacobians (fast path, :mod:`oacli.excitation.split_information`), reused for
        the FIM gradients; None on the reference path.
    """

    u: np.ndarray
    x: np.ndarray
    fim: np.ndarray
    criterion: float
    criterion_normalised: float
    violations: dict[str, float]
    merit: float
    rollout: split_information.SplitRollout | None = None

    @property
    def violation(self) -> float:
        """Total normalised violation."""
        return float(sum(self.violations.values()))


class ScpMerit:
    """The SCP merit ``J/J_ref + μ V`` of input sequences (see the module docstring).

    The first :meth:`evaluate` fixes the reference ``J_ref``, so that every later rollout (and every start of a
    multi-start) is judged on the same scale.

    Parameters
    ----------
    problem : ExcitationProblem
    penalty : float
        Exact-penalty weight μ on the normalised violation.
    fast : bool, optional
        Roll out with :mod:`oacli.excitation.split_information` (translation/rotation split, time batched; the
        same numbers to rounding) instead of the generic reference functions of
        :mod:`oacli.excitation.information`.
    """

    def __init__(self, problem: ExcitationProblem, penalty: float, fast: bool = True) -> None:
        self.p = problem
        self.fast = fast
        self.penalty = penalty
        self.d = scaling_matrix(problem.theta, problem.scaling)
        self.margin = chord_margin_m(problem.limits.force_N, problem.theta, problem.dt) + problem.clearance_m
        self.keep_out_margin = float(np.linalg.norm(self.margin - problem.clearance_m)) + problem.clearance_m
        self.reference: float | None = None

    def normalise(self, crit: float) -> float:
        """The criterion relative to the reference: ``J/J_ref`` (A), ``(J − J_ref)/4`` (D), ``J/|J_ref|`` (E).

        Parameters
        ----------
        crit : float
            Criterion value.

        Returns
        -------
        float
        """
        ref = self.reference
        assert ref is not None
        if self.p.criterion == "A":
            return crit / ref
        if self.p.criterion == "D":
            return (crit - ref) / N_PARAMS
        return crit / abs(ref)

    def fim(self, x: np.ndarray, s: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Fisher information (4, 4) of the measurements along a rollout ([Doerr2021] Eq. 29), symmetrised.

        Parameters
        ----------
        x : ndarray, shape (N+1, 13)
            Rollout states.
        s : ndarray
            Their parameter sensitivities (:func:`oacli.excitation.information.propagate_with_sensitivities`).
        u : ndarray, shape (N, 6)
            Inputs.

        Returns
        -------
        ndarray, shape (4, 4)
        """
        g_state, g_acc = output_sensitivities(x, u, s, self.p.theta, self.p.measurement)
        fim = np.einsum("kmi,kmj->ij", g_state, g_state) + np.einsum("kmi,kmj->ij", g_acc, g_acc)
        return 0.5 * (fim + fim.T)

    def violations(self, x: np.ndarray) -> dict[str, float]:
        """Normalised constraint violations of a rollout, per kind (0 when the constraint holds).

        Parameters
        ----------
        x : ndarray, shape (N+1, 13)
            Rollout states.

        Returns
        -------
        dict
            ``velocity``, ``angular_velocity`` (relative excess summed over the samples), ``keep_in``,
            ``keep_out`` (in units of ``LENGTH_UNIT_M``), ``terminal_position``, ``terminal_velocity``,
            ``terminal_attitude``, ``terminal_angular_velocity`` (relative excess over the tolerance).
        """
        p = self.p
        lim = p.limits
        tol = p.terminal
        out = {
            "velocity": float(np.sum(np.maximum(np.max(np.abs(x[1:, 3:6]) / lim.velocity_mps, axis=1) - 1.0, 0.0))),
            "angular_velocity": float(
                np.sum(np.maximum(np.max(np.abs(x[1:, 10:13]) / lim.angular_velocity_radps, axis=1) - 1.0, 0.0))
            ),
            "keep_in": float(np.sum(keep_in_sample_violation(p.scene, x[:, 0:3], self.margin)) / LENGTH_UNIT_M),
            "keep_out": float(np.sum(keep_out_violation(p.scene, x[:, 0:3], self.keep_out_margin,
                                                                lateral_inside=True)) / LENGTH_UNIT_M),
        }
        res = terminal_residual(x[-1], p.goal)
        out["terminal_position"] = max(res["position_m"] / tol.position_m - 1.0, 0.0)
        out["terminal_velocity"] = max(res["velocity_mps"] / tol.velocity_mps - 1.0, 0.0)
        out["terminal_attitude"] = max(res["attitude_rad"] / tol.attitude_rad - 1.0, 0.0)
        out["terminal_angular_velocity"] = max(res["angular_velocity_radps"] / tol.angular_velocity_radps - 1.0, 0.0)
        return out

    def evaluate(self, u: np.ndarray) -> Evaluation:
        """Roll out ``u`` on the nonlinear model and measure its criterion, violations and merit.

        Parameters
        ----------
        u : ndarray, shape (N, 6)
            Inputs.

        Returns
        -------
        Evaluation

        Raises
        ------
        InfeasibleError
            When the first evaluation (the reference) carries no information on some parameter.
        """
        ro = None
        if self.fast:
            ro = split_information.rollout(self.p.start, u, self.p.theta, self.p.dt)
            x = ro.x
            fim = split_information.fisher_information(ro, u, self.p.theta, self.p.measurement) + self.p.prior
        else:
            x, s = propagate_with_sensitivities(self.p.start, u, self.p.theta, self.p.dt)
            fim = self.fim(x, s, u) + self.p.prior
        crit = criterion_value(fim, self.p.criterion, self.d)
        if self.reference is None:
            if not np.isfinite(crit):
                raise InfeasibleError(
                    "the initial excitation carries no information on some parameters (singular Fisher information)"
                )
            self.reference = crit
        crit_n = self.normalise(crit) if np.isfinite(crit) else np.inf
        viol = self.violations(x)
        merit = crit_n + self.penalty * sum(viol.values())
        return Evaluation(u, x, fim, crit, crit_n, viol, merit, ro)


def terminal_residual(x_end: np.ndarray, goal: np.ndarray) -> dict[str, float]:
    """Largest per-axis error of the final state against the goal at rest.

    Parameters
    ----------
    x_end : ndarray, shape (13,)
    goal : ndarray, shape (13,)

    Returns
    -------
    dict
        ``position_m``, ``velocity_mps``, ``attitude_rad``, ``angular_velocity_radps``.
    """
    err, _ = attitude_error(goal[6:10], x_end[6:10])
    return {
        "position_m": float(np.max(np.abs(x_end[0:3] - goal[0:3]))),
        "velocity_mps": float(np.max(np.abs(x_end[3:6] - goal[3:6]))),
        "attitude_rad": float(np.max(np.abs(err))),
        "angular_velocity_radps": float(np.max(np.abs(x_end[10:13] - goal[10:13]))),
    }


__all__ = ["Evaluation", "ScpMerit", "terminal_residual"]
