"""Fisher information, A-optimal criterion and Cramér-Rao bound of the full rigid body's chosen entries along an
excitation ([Doerr2021] Eqs. 29-30 generalised to the full θ of :mod:`oacli.estimation.rigid_parameters`).

θ has 16 entries (mass, the inertia tensor's diagonal and products, the centre-of-mass offset, per-axis force and
torque scales); a design informs a chosen subset ``θ_S`` (groups of :data:`oacli.estimation.rigid_parameters.GROUPS`,
``excitation.information.parameters``). The response to the inputs ``u`` (each held for ``dt``) from a known
initial state is the full process model of the estimators (:func:`oacli.estimation.rigid_dynamics.propagate_full`,
one RK4 step per ``dt``, the wrench held, exact Jacobians ``A_k = ∂x_{k+1}/∂x_k`` and ``C_k = ∂x_{k+1}/∂θ``). On
the 12-entry tangent ``[δr, δv, δφ, δω]`` (body-frame attitude error, :mod:`oacli.estimation.manifold`) the
sensitivities follow::

    S_0 = 0,    S_{k+1} = P(x_{k+1}) (A_k L(x_k) S_k + C_k[:, S])

(``L`` the lift, ``P`` the projection), and the measurements of :class:`oacli.excitation.information.MeasurementModel`
give ``F = Σ_k G_kᵀ R⁻¹ G_k`` (Eq. 29): states at ``k = 1..N`` (``G_k = S_k``), accelerations ``[v̇, ω̇]`` at
``k = 0..N−1`` (``G_k = ∂a/∂x L(x_k) S_k + ∂a/∂θ_S``). With ``θ_S = [m, Ixx, Iyy, Izz]`` and the other entries ideal
(no CoM offset, no products, unit scales) the model is that of :mod:`oacli.excitation.information` and ``F`` equals
its :func:`~oacli.excitation.information.fisher_information` to rounding (tested).

**Scaling.** θ mixes kilograms, kg·m², metres and dimensionless scales, so ``tr F⁻¹`` adds variances of different
units: a change of unit of one entry (m → mm for the CoM) reweights the criterion arbitrarily. The A-criterion is
therefore evaluated on the scaled information ``F_s = D F D`` with ``D = diag(d)`` (:func:`parameter_scale`):

* ``"prior"`` (default): ``d_i = σ_prior,i``, so ``tr F_s⁻¹ = Σ_i CRB_i² / σ_prior,i²``, the sum of the
  variance ratios (posterior-to-prior, data alone): dimensionless, and invariant to the units of every entry
  (a unit change scales ``θ_i``, ``σ_prior,i`` and ``F_ii^-½`` alike; tested);
* ``"nominal"``: ``d_i = |θ_i|`` where that is not zero, else the prior σ (the CoM and the products are nominally
  zero: relative errors are undefined there);
* ``"absolute"``: ``d = 1``, [Doerr2021] Eq. 30 as printed (unit dependent; kept for the 4-entry design).

**Input gradient.** The SCP and RATTLE linearise a linear functional ``⟨M, F⟩`` in the inputs.
:func:`functional_gradient` computes ``∂⟨M, F⟩/∂u`` by central differences of the rollout, all ``2·6·N``
perturbed rollouts propagated together as one batch of the vectorised model (one pass of ``N`` batched steps);
the truncation error is ``O(h²)`` with a relative step ``h = 1e-5`` of each input's scale (tested against the exact
adjoint of :mod:`oacli.excitation.fim_gradient` in the 4-entry case). A perturbation of step k changes nothing
before it, so those rows are propagated from step k on only (half the work).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from oacli.estimation.manifold import TANGENT_DIM, lift_matrix, project_matrix
from oacli.estimation.rigid_dynamics import accelerations_full, propagate_full
from oacli.estimation.rigid_parameters import FULL_NAMES, GROUPS, LEGACY_GROUPS, N_FULL
from oacli.excitation.information import MeasurementModel

__all__ = [
    "FullInformation",
    "FullInformationTerm",
    "FullScaling",
    "a_criterion_full",
    "a_criterion_gradient_full",
    "add_prior_information",
    "cramer_rao_std_full",
    "entry_index",
    "fisher_information_full",
    "functional_gradient",
    "ideal_theta",
    "information_per_step_full",
    "information_summary",
    "information_unknown_start",
    "parameter_scale",
]

FullScaling = Literal["prior", "nominal", "absolute"]


def entry_index(groups: Sequence[str]) -> np.ndarray:
    """θ indices (in θ order) of the chosen groups of :data:`oacli.estimation.rigid_parameters.GROUPS`.

    Parameters
    ----------
    groups : sequence of str
        Group names; unknown names raise ``ValueError``.

    Returns
    -------
    ndarray of int, shape (p,)
    """
    unknown = sorted(set(groups) - set(GROUPS))
    if unknown:
        raise ValueError(f"unknown parameter group(s) {unknown}: choose from {list(GROUPS)}")
    if not groups:
        raise ValueError("choose at least one parameter group")
    return np.array([i for g in GROUPS if g in groups for i in GROUPS[g]], dtype=int)


def ideal_theta(theta4: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
    """θ (16) from ``[m, Ixx, Iyy, Izz]`` and the 12 other entries (default: ideal, i.e. no products, no CoM
    offset, unit scales).

    Parameters
    ----------
    theta4 : ndarray, shape (4,)
        [kg, kg·m² ×3].
    extra : ndarray, shape (12,), optional
        [products (3) kg·m², CoM (3) m, force scale (3), torque scale (3)].

    Returns
    -------
    ndarray, shape (16,)
    """
    ext = np.r_[np.zeros(6), np.ones(6)] if extra is None else np.asarray(extra, dtype=float).reshape(12)
    return np.r_[np.asarray(theta4, dtype=float).reshape(4), ext]


@dataclass(frozen=True)
class FullInformation:
    """The Fisher information of the chosen entries along one input sequence.

    Attributes
    ----------
    index : ndarray of int, shape (p,)
        θ indices of the entries.
    names : tuple of str
        Their names (:data:`oacli.estimation.rigid_parameters.FULL_NAMES`).
    fim : ndarray, shape (p, p)
        ``F`` ([Doerr2021] Eq. 29) [1/unit_i unit_j].
    per_step : ndarray, shape (N, p, p)
        The information of each step's measurements (states after step k, accelerations at step k); sums to ``fim``.
    x : ndarray, shape (N+1, 13)
        The rollout's states.
    """

    index: np.ndarray
    names: tuple[str, ...]
    fim: np.ndarray
    per_step: np.ndarray
    x: np.ndarray


def _rollouts(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
              idx: np.ndarray, per_step: bool, x0_unknown: bool = False, rows_per_step: int = 0
              ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """F (B, p, p) of B input sequences ``u`` (B, N, 6) from one ``x0``; optionally per step, and the states of
    the first sequence. ``x0_unknown``: the information of ``[δx_0 (12), θ_S]`` (B = 1), the state measured at
    k = 0 too. ``rows_per_step`` > 0: rows ``1 + r k .. r (k + 1)`` differ from row 0 only from step k on (input
    perturbations of step k), so before it they are row 0's and are not propagated (causality: half the work)."""
    b, n = u.shape[0], u.shape[1]
    nx = TANGENT_DIM if x0_unknown else 0
    p = nx + idx.size
    x = np.repeat(np.asarray(x0, dtype=float)[None], b, axis=0)
    s = np.zeros((b, TANGENT_DIM, p))
    if nx:
        s[:, :, 0:nx] = np.eye(nx)
    fim = np.zeros((b, p, p))
    steps = np.zeros((n, p, p)) if per_step else None
    xs = np.empty((n + 1, 13))
    xs[0] = x[0]
    w_state = np.sqrt(model.state_weights)
    w_acc = np.sqrt(model.acceleration_weights)
    if x0_unknown:
        g0 = s * w_state[None, :, None]
        fim += np.einsum("bmi,bmj->bij", g0, g0)
    for k in range(n):
        act = b if rows_per_step <= 0 else min(b, 1 + rows_per_step * (k + 1))
        xa, sa, uk = x[:act], s[:act], u[:act, k]
        lift = lift_matrix(xa)
        info = np.zeros((act, p, p))
        if np.any(w_acc):
            _, jx, jth = accelerations_full(xa, uk, theta)
            g = (jx @ lift) @ sa
            g[:, :, nx:] += jth[:, :, idx]
            g *= w_acc[None, :, None]
            info += np.einsum("bmi,bmj->bij", g, g)
        x_next, a, c = propagate_full(xa, uk, theta, np.full((act, 1), float(dt)))
        assert a is not None and c is not None
        proj = project_matrix(x_next)
        s_next = proj @ (a @ (lift @ sa))
        s_next[:, :, nx:] += proj @ c[:, :, idx]
        g = s_next * w_state[None, :, None]
        info += np.einsum("bmi,bmj->bij", g, g)
        x[:act], s[:act] = x_next, s_next
        fim[:act] += info
        if act < b:  # the rows perturbed later are still row 0
            x[act:], s[act:] = x_next[0], s_next[0]
            fim[act:] += info[0]
        if steps is not None:
            steps[k] = info[0]
        xs[k + 1] = x[0]
    return fim, steps, xs


def _checked(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, groups: Sequence[str]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    x0 = np.asarray(x0, dtype=float).reshape(13)
    u = np.asarray(u, dtype=float).reshape(-1, 6)
    theta = np.asarray(theta, dtype=float).reshape(N_FULL)
    return x0, u, theta, entry_index(groups)


def fisher_information_full(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
                            groups: Sequence[str] = LEGACY_GROUPS) -> FullInformation:
    """``F`` of the chosen entries from measuring the response to ``u`` from ``x0`` (module docstring; Eq. 29).

    Parameters
    ----------
    x0 : ndarray, shape (13,)
        Known initial state.
    u : ndarray, shape (N, 6)
        Inputs [N world frame, N·m body frame], each held for ``dt``.
    theta : ndarray, shape (16,)
        θ at which the information is evaluated (:func:`ideal_theta` builds one from the 4 entries).
    dt : float
        Step [s]; one measurement per step.
    model : MeasurementModel
        What is measured, with which noise.
    groups : sequence of str
        The informed groups (default: mass and inertia).

    Returns
    -------
    FullInformation
    """
    x0, u, theta, idx = _checked(x0, u, theta, groups)
    fim, steps, xs = _rollouts(x0, u[None], theta, dt, model, idx, per_step=True)
    assert steps is not None
    f = 0.5 * (fim[0] + fim[0].T)
    return FullInformation(idx, tuple(FULL_NAMES[i] for i in idx), f, steps, xs)


def information_unknown_start(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float,
                               model: MeasurementModel, groups: Sequence[str] = LEGACY_GROUPS) -> np.ndarray:
    """``F`` of the chosen entries when the initial state is a nuisance parameter: the information of
    ``[δx_0, θ_S]`` with the state also measured at ``k = 0``, ``δx_0`` eliminated (Schur complement), as
    :func:`oacli.estimation.bounds_full.cramer_rao_bound_full` does for one segment.

    Parameters
    ----------
    x0, u, theta, dt, model, groups
        As :func:`fisher_information_full`; ``x0`` is the linearisation point of the initial state.

    Returns
    -------
    ndarray, shape (p, p)
    """
    x0, u, theta, idx = _checked(x0, u, theta, groups)
    fim, _, _ = _rollouts(x0, u[None], theta, dt, model, idx, per_step=False, x0_unknown=True)
    info = fim[0]
    unmeasured = np.flatnonzero(model.state_weights == 0)
    info[unmeasured, unmeasured] += 1.0  # gauge of unmeasured initial states, as bounds_full
    nx = TANGENT_DIM
    f_eff = info[nx:, nx:] - info[nx:, :nx] @ np.linalg.solve(info[:nx, :nx], info[:nx, nx:])
    return 0.5 * (f_eff + f_eff.T)


def add_prior_information(fim: np.ndarray, groups: Sequence[str], prior_std: np.ndarray) -> np.ndarray:
    """``F + diag(1/σ²)`` on the chosen entries *other than* mass and inertia.

    The data cannot separate a common factor of the force scale and the mass, nor (but for the gyroscopic term)
    of the torque scale and the inertia: with the scales informed, ``F`` alone is singular. As in
    :mod:`oacli.estimation.bounds_full`, the prior of the centre of mass, products and scales (what is known of
    the robot before the run) is added, mass and inertia are left to the data.

    Parameters
    ----------
    fim : ndarray, shape (p, p)
    groups : sequence of str
    prior_std : ndarray, shape (16,)
        Prior standard deviation of every θ entry.

    Returns
    -------
    ndarray, shape (p, p)
    """
    idx = entry_index(groups)
    sigma = np.asarray(prior_std, dtype=float).reshape(N_FULL)[idx]
    beyond = idx >= 4
    out = np.array(fim, dtype=float)
    out[beyond, beyond] += 1.0 / sigma[beyond] ** 2
    return out


def information_per_step_full(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float,
                              model: MeasurementModel, groups: Sequence[str] = LEGACY_GROUPS) -> np.ndarray:
    """Each step's information (N, p, p); the sum is :func:`fisher_information_full`'s ``fim``.

    Parameters
    ----------
    x0, u, theta, dt, model, groups
        As :func:`fisher_information_full`.

    Returns
    -------
    ndarray, shape (N, p, p)
    """
    return fisher_information_full(x0, u, theta, dt, model, groups).per_step


def parameter_scale(theta: np.ndarray, prior_std: np.ndarray, groups: Sequence[str],
                    scaling: FullScaling = "prior") -> np.ndarray:
    """``d`` of ``D = diag(d)`` for the chosen entries (module docstring, **Scaling**).

    Parameters
    ----------
    theta : ndarray, shape (16,)
        Nominal θ.
    prior_std : ndarray, shape (16,)
        Prior standard deviation of every θ entry [unit of the entry], > 0 for the chosen ones.
    groups : sequence of str
    scaling : {"prior", "nominal", "absolute"}

    Returns
    -------
    ndarray, shape (p,)
        [unit of each entry].
    """
    idx = entry_index(groups)
    sigma = np.asarray(prior_std, dtype=float).reshape(N_FULL)[idx]
    if scaling == "absolute":
        return np.ones(idx.size)
    if not np.all(sigma > 0):
        raise ValueError("the prior standard deviations of the chosen entries must be > 0")
    if scaling == "prior":
        return sigma
    if scaling == "nominal":
        nominal = np.abs(np.asarray(theta, dtype=float).reshape(N_FULL)[idx])
        return np.where(nominal > 0, nominal, sigma)
    raise ValueError(f"unknown parameter scaling {scaling!r}")


def a_criterion_full(fim: np.ndarray, scale: np.ndarray) -> float:
    """``tr (D F D)⁻¹`` with ``D = diag(scale)`` ([Doerr2021] Eq. 30 on scaled entries); ``inf`` when singular.

    Parameters
    ----------
    fim : ndarray, shape (p, p)
    scale : ndarray, shape (p,)
        :func:`parameter_scale`.

    Returns
    -------
    float
        Dimensionless for the ``"prior"`` and ``"nominal"`` scalings.
    """
    d = np.asarray(scale, dtype=float)
    fs = d[:, None] * (0.5 * (fim + fim.T)) * d[None, :]
    try:
        chol = np.linalg.cholesky(fs)
    except np.linalg.LinAlgError:
        return float("inf")
    inv_chol = np.linalg.solve(chol, np.eye(d.size))
    return float(np.sum(inv_chol * inv_chol))


def cramer_rao_std_full(fim: np.ndarray) -> np.ndarray:
    """``sqrt(diag F⁻¹)`` (p,) [unit of each entry]; ``inf`` everywhere when F is singular.

    Parameters
    ----------
    fim : ndarray, shape (p, p)

    Returns
    -------
    ndarray, shape (p,)
    """
    f = 0.5 * (fim + fim.T)
    try:
        np.linalg.cholesky(f)
    except np.linalg.LinAlgError:
        return np.full(f.shape[0], np.inf)
    return np.sqrt(np.diag(np.linalg.inv(f)))


def functional_gradient(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
                        weights: np.ndarray, groups: Sequence[str] = LEGACY_GROUPS,
                        input_scale: np.ndarray | None = None, rel_step: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """``F`` and ``∂⟨M_q, F⟩/∂u`` (Q, N, 6) for the weight matrices ``M_q`` (module docstring, central differences).

    Parameters
    ----------
    x0, u, theta, dt, model, groups
        As :func:`fisher_information_full`.
    weights : ndarray, shape (Q, p, p)
        Symmetric weight matrices.
    input_scale : ndarray, shape (6,), optional
        Scale of each input channel [N, N·m] (the input limits); default ``max|u|`` per channel, else 1.
    rel_step : float
        Difference step as a fraction of ``input_scale``.

    Returns
    -------
    fim : ndarray, shape (p, p)
    gradients : ndarray, shape (Q, N, 6)
    """
    x0, u, theta, idx = _checked(x0, u, theta, groups)
    n = u.shape[0]
    w = np.asarray(weights, dtype=float).reshape(-1, idx.size, idx.size)
    if input_scale is None:
        peak = np.max(np.abs(u), axis=0)
        input_scale = np.where(peak > 0, peak, 1.0)
    h = rel_step * np.asarray(input_scale, dtype=float).reshape(6)
    batch = np.repeat(u[None], 1 + 2 * 6 * n, axis=0)
    for k in range(n):
        for j in range(6):
            col = 1 + 2 * (6 * k + j)
            batch[col, k, j] += h[j]
            batch[col + 1, k, j] -= h[j]
    fim, _, _ = _rollouts(x0, batch, theta, dt, model, idx, per_step=False, rows_per_step=12)
    values = np.einsum("qij,bij->qb", w, fim)
    diff = (values[:, 1::2] - values[:, 2::2]).reshape(w.shape[0], n, 6) / (2.0 * h[None, None, :])
    f = fim[0]
    return 0.5 * (f + f.T), diff


def a_criterion_gradient_full(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
                              scale: np.ndarray, groups: Sequence[str] = LEGACY_GROUPS,
                              input_scale: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The scaled A-criterion ``J = tr (D F D)⁻¹`` and ``∂J/∂u`` (N, 6).

    ``∂J/∂F = −D (D F D)⁻² D``, contracted with ``∂F/∂u`` (:func:`functional_gradient`).

    Parameters
    ----------
    x0, u, theta, dt, model, groups
        As :func:`fisher_information_full`.
    scale : ndarray, shape (p,)
        :func:`parameter_scale`.
    input_scale : ndarray, shape (6,), optional
        As :func:`functional_gradient`.

    Returns
    -------
    value : float
    gradient : ndarray, shape (N, 6)
        ``nan`` when F is singular.
    """
    info = fisher_information_full(x0, u, theta, dt, model, groups)
    d = np.asarray(scale, dtype=float)
    value = a_criterion_full(info.fim, d)
    if not np.isfinite(value):
        return value, np.full(np.asarray(u).reshape(-1, 6).shape, np.nan)
    fs_inv = np.linalg.inv(d[:, None] * info.fim * d[None, :])
    m = -(d[:, None] * (fs_inv @ fs_inv) * d[None, :])
    _, grad = functional_gradient(x0, u, theta, dt, model, 0.5 * (m + m.T)[None], groups, input_scale)
    return value, grad[0]


def information_summary(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel,
                        groups: Sequence[str], prior_std: np.ndarray, scaling: FullScaling = "prior"
                        ) -> dict[str, object]:
    """What a trajectory tells about the chosen entries: the scaled A-criterion and the Cramér-Rao bound, the
    information of the data plus the prior of the entries beyond mass and inertia (:func:`add_prior_information`).

    Parameters
    ----------
    x0, u, theta, dt, model, groups
        As :func:`fisher_information_full`.
    prior_std : ndarray, shape (16,)
        Prior σ of every θ entry.
    scaling : {"prior", "nominal", "absolute"}

    Returns
    -------
    dict
        ``parameters``, ``scaling``, ``a_criterion`` (``tr (D F D)⁻¹``; None when singular), ``crb_std`` and
        ``prior_std`` by entry name, ``crb_over_prior`` (σ_CRB / σ_prior by name).
    """
    info = fisher_information_full(x0, u, theta, dt, model, groups)
    fim = add_prior_information(info.fim, groups, prior_std)
    d = parameter_scale(theta, prior_std, groups, scaling)
    crit = a_criterion_full(fim, d)
    crb = cramer_rao_std_full(fim)
    sigma = np.asarray(prior_std, dtype=float).reshape(N_FULL)[info.index]
    return {
        "parameters": list(groups),
        "scaling": scaling,
        "a_criterion": crit if np.isfinite(crit) else None,
        "crb_std": {n: float(v) for n, v in zip(info.names, crb, strict=True)},
        "prior_std": {n: float(v) for n, v in zip(info.names, sigma, strict=True)},
        "crb_over_prior": {n: float(v) for n, v in zip(info.names, crb / sigma, strict=True)},
    }


@dataclass(frozen=True)
class FullInformationTerm:
    """The chosen entries and what is known of the others.

    Attributes
    ----------
    groups : tuple of str
        Informed groups (must include mass and inertia).
    theta_extra : ndarray, shape (12,)
        Prior mean of [products kg·m², CoM m, force scale, torque scale] (the model where nothing better is known).
    prior_std : ndarray, shape (16,)
        Prior standard deviation of every θ entry.
    input_scale : ndarray, shape (6,)
        Difference step scale per input channel [N, N·m] (the planner's input limits).
    """

    groups: tuple[str, ...]
    theta_extra: np.ndarray
    prior_std: np.ndarray
    input_scale: np.ndarray

    def __post_init__(self) -> None:
        if "mass" not in self.groups or "inertia" not in self.groups:
            raise ValueError("the information term needs mass and inertia among its groups")
        entry_index(self.groups)  # unknown names raise

    @property
    def index(self) -> np.ndarray:
        """θ indices of the entries."""
        return entry_index(self.groups)

    def theta(self, theta4: np.ndarray) -> np.ndarray:
        """θ (16) with ``[m, I]`` from the estimate and the rest from the prior.

        Parameters
        ----------
        theta4 : ndarray, shape (4,)

        Returns
        -------
        ndarray, shape (16,)
        """
        return ideal_theta(theta4, self.theta_extra)

    def information(self, x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float,
                    measurement: MeasurementModel) -> FullInformation:
        """The horizon's information of the entries (:func:`fisher_information_full`).

        Parameters
        ----------
        x0 : ndarray, shape (13,)
        u : ndarray, shape (N, 6)
        theta : ndarray, shape (16,)
        dt : float
        measurement : MeasurementModel

        Returns
        -------
        FullInformation
        """
        return fisher_information_full(x0, u, theta, dt, measurement, self.groups)

    def gradient(self, x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, measurement: MeasurementModel,
                 weight: np.ndarray) -> np.ndarray:
        """``∂⟨M, F⟩/∂u`` (N, 6) for one weight matrix ``M`` (p, p) (:func:`functional_gradient`).

        Parameters
        ----------
        x0, u, theta, dt, measurement
            As :meth:`information`.
        weight : ndarray, shape (p, p)

        Returns
        -------
        ndarray, shape (N, 6)
        """
        return functional_gradient(x0, u, theta, dt, measurement, weight[None], self.groups, self.input_scale)[1][0]
