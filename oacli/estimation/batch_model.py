"""Which θ the batch problem estimates: the original [m, Ixx, Iyy, Izz] or a chosen part of the full rigid body.

:class:`BatchProblem <oacli.estimation.batch_problem.BatchProblem>` asks its model for θ of φ, ``dθ/dφ``, the
process model's propagation and the continuous accelerations with their Jacobians, and the prior's residual. The
original 4 parameters (:class:`LegacyModel`) keep :mod:`oacli.estimation.parametrization` and the structured
propagation of :mod:`oacli.estimation.propagation`; any other choice (:class:`FullModel`) uses the full rigid body of
:mod:`oacli.estimation.rigid_parameters` (log-Cholesky pseudo-inertia, Rucker & Wensing 2022 Eq. 9) and
:mod:`oacli.estimation.rigid_dynamics` (body-axis actuator scales, centre-of-mass torque, inertia products).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.estimation import parametrization as par
from oacli.estimation.propagation import (
    dynamics_batch,
    dynamics_jacobians_batch,
    propagate_intervals,
    propagate_intervals_structured,
)
from oacli.estimation.rigid_dynamics import accelerations_full, propagate_full, propagate_full_one
from oacli.estimation.rigid_parameters import N_FULL, ParameterSet

_ACCEL_ROWS = np.r_[3:6, 10:13]

__all__ = ["FullModel", "LegacyModel", "full_prior"]


class LegacyModel:
    """θ = [m, Ixx, Iyy, Izz] through φ = [log m, log A, log B, log C] (:mod:`oacli.estimation.parametrization`)."""

    n = par.N_PARAMS
    prior_index = np.arange(4)

    def theta(self, phi: np.ndarray) -> np.ndarray:
        """θ (4) of φ (4).

        Parameters
        ----------
        phi : ndarray, shape (n,)
            φ of the estimated entries.

        Returns
        -------
        ndarray, shape (4,)
        """
        return par.theta_from_phi(phi)

    def theta4(self, phi: np.ndarray) -> np.ndarray:
        """[m, Ixx, Iyy, Izz] of φ.

        Parameters
        ----------
        phi : ndarray, shape (n,)
            φ of the estimated entries.

        Returns
        -------
        ndarray, shape (4,)
        """
        return par.theta_from_phi(phi)

    def jacobian(self, phi: np.ndarray) -> np.ndarray:
        """``dθ/dφ`` (4×4).

        Parameters
        ----------
        phi : ndarray, shape (n,)
            φ of the estimated entries.

        Returns
        -------
        ndarray, shape (4, 4)
        """
        return par.theta_jacobian(phi)

    def phi(self, theta: np.ndarray) -> np.ndarray:
        """φ of θ (its first 4 entries).

        Parameters
        ----------
        theta : ndarray, shape (4,) or more

        Returns
        -------
        ndarray, shape (4,)
        """
        return par.phi_from_theta(np.asarray(theta, dtype=float)[:4])

    def propagate(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray, *,
                  jacobians: bool = True, reference: bool = False
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """End states, ``∂f/∂x`` and ``∂f/∂θ`` of the process model ([Doerr2021] Eqs. 34-35).

        Parameters
        ----------
        x : ndarray, shape (K, 13)
        u : ndarray, shape (K, 6)
        theta : ndarray
            θ of :meth:`theta`.
        durations : ndarray, shape (K, M)
            Sub-step durations [s].
        jacobians : bool
            False: the end states only.
        reference : bool
            The general RK4 path (4 parameters only).

        Returns
        -------
        x_next : ndarray, shape (K, 13)
        a : ndarray, shape (K, 13, 13) or None
        c : ndarray, shape (K, 13, len(theta)) or None
        """
        if reference:
            return propagate_intervals(x, u, theta, durations)
        return propagate_intervals_structured(x, u, theta, durations, jacobians=jacobians)

    def accelerations(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, jacobians: bool = True
                      ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """``[v̇, ω̇]`` and its Jacobians on x and θ ([Doerr2021] Eqs. 34-35).

        Parameters
        ----------
        x : ndarray, shape (K, 13)
        u : ndarray, shape (K, 6)
        theta : ndarray
            θ of :meth:`theta`.
        jacobians : bool
            Also the Jacobians.

        Returns
        -------
        acc : ndarray, shape (K, 6)
        d_x : ndarray, shape (K, 6, 13) or None
        d_theta : ndarray, shape (K, 6, len(theta)) or None
        """
        f = dynamics_batch(x, u, theta)[:, _ACCEL_ROWS]
        if not jacobians:
            return f, None, None
        jac = dynamics_jacobians_batch(x, u, theta)[:, _ACCEL_ROWS]
        return f, jac[:, :, 0:13], jac[:, :, 13:]


_INERTIA_ENTRIES = frozenset(range(1, 7))


def _reachable(index: np.ndarray) -> np.ndarray:
    """``index`` with every inertia entry added when it holds one (:attr:`FullModel.differentiated`)."""
    entries = {int(i) for i in index}
    if entries & _INERTIA_ENTRIES:
        entries |= _INERTIA_ENTRIES
    return np.array(sorted(entries), dtype=int)


@dataclass(frozen=True)
class FullModel:
    """A chosen part of the full rigid body (:class:`~oacli.estimation.rigid_parameters.ParameterSet`).

    Attributes
    ----------
    params : ParameterSet
    prior_mean : ndarray, shape (16,)
        Prior mean of θ (:func:`full_prior`).
    prior_cov : ndarray, shape (16, 16)
        Prior covariance of θ.
    """

    params: ParameterSet
    prior_mean: np.ndarray
    prior_cov: np.ndarray

    @property
    def n(self) -> int:
        """Estimated entries."""
        return self.params.n

    @property
    def prior_index(self) -> np.ndarray:
        """θ indices the prior's residual is on (the estimated ones)."""
        return self.params.index

    @property
    def differentiated(self) -> np.ndarray:
        """θ entries whose sensitivities :meth:`propagate` carries: every entry ``dθ/dφ`` can reach (the estimated
        ones, and all six inertia entries when any of them is estimated: the log-Cholesky map couples a held
        product with the estimated diagonal unless it is 0). ``∂x⁺/∂θ`` is zero in the other columns."""
        return _reachable(self.params.index)

    def theta(self, phi: np.ndarray) -> np.ndarray:
        """θ (16) of φ (n).

        Parameters
        ----------
        phi : ndarray, shape (n,)
            φ of the estimated entries.

        Returns
        -------
        ndarray, shape (16,)
        """
        return self.params.theta(phi)

    def theta4(self, phi: np.ndarray) -> np.ndarray:
        """[m, Ixx, Iyy, Izz] of φ.

        Parameters
        ----------
        phi : ndarray, shape (n,)
            φ of the estimated entries.

        Returns
        -------
        ndarray, shape (4,)
        """
        return self.theta(phi)[:4]

    def jacobian(self, phi: np.ndarray) -> np.ndarray:
        """``dθ/dφ`` (16×n).

        Parameters
        ----------
        phi : ndarray, shape (n,)
            φ of the estimated entries.

        Returns
        -------
        ndarray, shape (16, n)
        """
        return self.params.jacobian(phi)

    def phi(self, theta: np.ndarray) -> np.ndarray:
        """φ (n) of θ.

        Parameters
        ----------
        theta : ndarray, shape (16,) or (4,)
            θ; with 4 entries the rest from the fixed values.

        Returns
        -------
        ndarray, shape (n,)
        """
        theta = np.asarray(theta, dtype=float)
        if theta.size == 4:
            theta = np.r_[theta, self.params.theta_fixed[4:]]
        return self.params.phi_from_theta(theta)

    def propagate(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, durations: np.ndarray, *,
                  jacobians: bool = True, reference: bool = False
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """End states, ``∂f/∂x`` and ``∂f/∂θ`` of the full model (:func:`propagate_full`).

        Parameters
        ----------
        x : ndarray, shape (K, 13)
        u : ndarray, shape (K, 6)
        theta : ndarray
            θ of :meth:`theta`.
        durations : ndarray, shape (K, M)
            Sub-step durations [s].
        jacobians : bool
            False: the end states only.
        reference : bool
            The general RK4 path (4 parameters only).

        Returns
        -------
        x_next : ndarray, shape (K, 13)
        a : ndarray, shape (K, 13, 13) or None
        c : ndarray, shape (K, 13, len(theta)) or None
        """
        if np.shape(x)[0] == 1:  # a filter step or a warm start's record: the single-interval path (8× faster)
            x1, a1, c1 = propagate_full_one(x, u, theta, durations, jacobians=jacobians)
            return x1[None], None if a1 is None else a1[None], None if c1 is None else c1[None]
        # Only the sensitivities dθ/dφ can reach are carried (zero columns of c elsewhere).
        return propagate_full(x, u, theta, durations, jacobians=jacobians, columns=self.differentiated)

    def accelerations(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, jacobians: bool = True
                      ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """``[v̇, ω̇]`` and its Jacobians on x and θ (:func:`accelerations_full`).

        Parameters
        ----------
        x : ndarray, shape (K, 13)
        u : ndarray, shape (K, 6)
        theta : ndarray
            θ of :meth:`theta`.
        jacobians : bool
            Also the Jacobians.

        Returns
        -------
        acc : ndarray, shape (K, 6)
        d_x : ndarray, shape (K, 6, 13) or None
        d_theta : ndarray, shape (K, 6, len(theta)) or None
        """
        f, dx, dth = accelerations_full(x, u, theta)
        return (f, dx, dth) if jacobians else (f, None, None)


def full_prior(theta4: np.ndarray, cov4: np.ndarray, extra_mean: np.ndarray, extra_std: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """The prior ``N(θ₀, P₀)`` on the full θ (16): the 4-parameter prior's mean and covariance on [m, I], the other
    12 entries independent with means ``extra_mean`` and standard deviations ``extra_std``.

    Parameters
    ----------
    theta4 : ndarray, shape (4,)
    cov4 : ndarray, shape (4, 4)
    extra_mean, extra_std : ndarray, shape (12,)
        [products kg·m² (3), centre of mass m (3), force scale (3), torque scale (3)].

    Returns
    -------
    mean : ndarray, shape (16,)
    cov : ndarray, shape (16, 16)
    """
    mean = np.r_[np.asarray(theta4, dtype=float), np.asarray(extra_mean, dtype=float)]
    cov = np.zeros((N_FULL, N_FULL))
    cov[:4, :4] = cov4
    cov[4:, 4:] = np.diag(np.asarray(extra_std, dtype=float) ** 2)
    return mean, cov
