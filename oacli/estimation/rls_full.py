"""The flight's recursive least squares extended to the full rigid body: mass, inertia tensor with products and the
centre-of-mass offset ([ReSWARM2023] §3, §4.4.1, Eqs. 31-33, 40-42; :mod:`oacli.estimation.rls`).

**Model.** oacli's state position is the centre of mass's and the force acts at the geometric centre, ``c`` from
it (:mod:`oacli.sim.actuators`). The Newton-Euler equations in the body frame, with the calibrated force
``F' = κ_F ⊙ F_b`` and torque ``τ' = κ_τ ⊙ τ``, are ([ReSWARM2023] §3)::

    m a = F',        J α + ω × J ω = τ' − c × F'                                   (about the centre of mass)

With the reference point's acceleration ``a_o = a − α × c − ω × (ω × c)`` and the parallel-axis theorem
``I_o = J + m([c]×ᵀ[c]×)`` the same equations read ``m a_o + α × h + ω × (ω × h) = F'``,
``I_o α + ω × I_o ω + h × a_o = τ'`` with ``h = m c``: linear in ``π = [m, h, I_o]`` (Atkeson, An & Hollerbach
1986). Both are *equation-error* forms: the measured accelerations sit in the regressor, and the least-squares
estimate is biased towards zero by their noise (errors in variables; with differenced velocities the noise is
comparable to the signal). The flight's estimator avoided that by keeping the measured accelerations as the
measurement and regressing them in the inverse parameters (:mod:`oacli.estimation.rls`). This module does the same
for the full rigid body (output-error form)::

    z = [a, α] = h(ψ) + ν,    h = [F' ψ_m,  K (τ' − c × F' − ω × K⁻¹ ω)],    ψ = [1/m, K = J⁻¹ (6), c (3)]

Translation is linear in ``ψ_m = 1/m``; rotation is linear in ``K`` but for the small gyroscopic term and the
``K (c × F')`` product (``|c × F'|`` ≈ 1 mN·m against torques of 10 mN·m), both linearised at the current estimate,
as the 4-parameter filter linearises its gyroscopic term. With the products and the offset left out (held at zero)
``K = diag(1/Ixx, 1/Iyy, 1/Izz)`` and the filter *is* :class:`oacli.estimation.rls.RlsEstimator` (tested). The
update is the flight's (``K = P Hᵀ S⁻¹``, Joseph form), with its χ² gate on 6 degrees of freedom
([ReSWARM2023] Eqs. 40-42).

**Jacobian** (``E_e`` the symmetric basis matrix of ``K``'s entry ``e``, ``n = τ' − c × F' − ω × Jω``)::

    ∂a/∂ψ_m = F',   ∂α/∂K_e = E_e n + K (ω × (J E_e J ω)),   ∂α/∂c = K [F']×

**Reported θ and covariance.** ``m = 1/ψ_m``, ``J = K⁻¹``, ``c``; first order ``dm = −m² dψ_m``,
``dJ = −J dK J``. **Physical consistency**: an update that would leave the physical set (``m ≤ 0``, or ``J`` not
positive definite with strict triangle inequalities, :func:`oacli.estimation.rigid_parameters.is_physical_full`)
is not applied and is counted (``infeasible``); :attr:`RlsFullEstimate.physical` reports the final estimate's
state and :attr:`RlsFullEstimate.triangle_margin` the smallest slack of ``Σ_c = tr(J)/2 − J`` (Wensing et al.
2017: the pseudo-inertia is positive definite exactly when it is > 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from oacli.estimation.gating import chi2_threshold
from oacli.estimation.rigid_parameters import FULL_NAMES, N_FULL, inertia_tensor, is_physical_full
from oacli.estimation.rls import AccelerationSamples
from oacli.types import ParameterEstimate

__all__ = ["RLS_FULL_GROUPS", "RlsFullEstimate", "RlsFullEstimator", "full_acceleration_model"]

RLS_FULL_GROUPS = ("mass", "inertia", "products", "com")
"""Groups the full RLS can estimate (the scales are calibrated beforehand, [ReSWARM2023] Eqs. 38-39)."""
_PSI_OF_GROUP = {"mass": (0,), "inertia": (1, 2, 3), "products": (4, 5, 6), "com": (7, 8, 9)}
"""ψ = [1/m, K_xx, K_yy, K_zz, K_xy, K_xz, K_yz, c (3)]; the same positions as θ's first ten entries."""
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
_MEAS_DIM = 6


def _sym(v: np.ndarray) -> np.ndarray:
    """The symmetric 3×3 matrix of entries [xx, yy, zz, xy, xz, yz]."""
    out = np.empty((3, 3))
    for (a, b), value in zip(_PAIRS, v, strict=True):
        out[a, b] = out[b, a] = value
    return out


def _entries(mat: np.ndarray) -> np.ndarray:
    return np.array([mat[a, b] for a, b in _PAIRS])


def _basis() -> np.ndarray:
    out = np.zeros((6, 3, 3))
    for e, (a, b) in enumerate(_PAIRS):
        out[e, a, b] = out[e, b, a] = 1.0
    return out


_E = _basis()


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def full_acceleration_model(psi: np.ndarray, force_N: np.ndarray, torque_Nm: np.ndarray, rate_radps: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    """``h(ψ)`` (6) and ``∂h/∂ψ`` (6, 10) of the module docstring (body frame, calibrated force and torque).

    Parameters
    ----------
    psi : ndarray, shape (10,)
        ``[1/m 1/kg, K = J⁻¹ entries xx, yy, zz, xy, xz, yz 1/(kg·m²), c m]``.
    force_N, torque_Nm : ndarray, shape (3,)
        ``κ_F ⊙ F_b`` and ``κ_τ ⊙ τ`` [N, N·m].
    rate_radps : ndarray, shape (3,)
        ω [rad/s].

    Returns
    -------
    h : ndarray, shape (6,)
        [m/s², rad/s²].
    jac : ndarray, shape (6, 10)
    """
    k = _sym(psi[1:7])
    j = np.linalg.inv(k)
    c = psi[7:10]
    w = rate_radps
    n = torque_Nm - np.cross(c, force_N) - np.cross(w, j @ w)
    h = np.r_[force_N * psi[0], k @ n]
    jac = np.zeros((6, 10))
    jac[0:3, 0] = force_N
    jw = j @ w
    for e in range(6):
        jac[3:6, 1 + e] = _E[e] @ n + k @ np.cross(w, j @ (_E[e] @ jw))
    jac[3:6, 7:10] = k @ _skew(force_N)
    return h, jac


def _theta_of_psi(psi: np.ndarray) -> np.ndarray:
    """θ's first ten entries [m, J entries, c] of ψ."""
    j = np.linalg.inv(_sym(psi[1:7]))
    return np.r_[1.0 / psi[0], _entries(j), psi[7:10]]


def _theta_jacobian(psi: np.ndarray) -> np.ndarray:
    """``∂θ[:10]/∂ψ`` (10, 10): ``dm = −m² dψ_m``, ``dJ = −J dK J``, ``dc = dc``."""
    j = np.linalg.inv(_sym(psi[1:7]))
    out = np.zeros((10, 10))
    out[0, 0] = -1.0 / psi[0] ** 2
    for e in range(6):
        out[1:7, 1 + e] = _entries(-j @ _E[e] @ j)
    out[7:10, 7:10] = np.eye(3)
    return out


@dataclass(frozen=True)
class RlsFullEstimate:
    """The full RLS's estimate.

    Attributes
    ----------
    t : float
        Time of the last sample used [s].
    theta : ndarray, shape (16,)
        θ (:data:`oacli.estimation.rigid_parameters.FULL_NAMES`); the entries not estimated at the prior's.
    index : ndarray of int, shape (p,)
        θ indices of the estimated entries.
    covariance : ndarray, shape (p, p)
        Their covariance (first order from ψ's).
    samples_used, samples_rejected, infeasible : int
        Updates applied, refused by the χ² gate, refused for leaving the physical set.
    physical : bool
        ``m > 0`` and ``J`` positive definite with strict triangle inequalities.
    triangle_margin : float
        Smallest eigenvalue of ``Σ_c = tr(J)/2 · 1 − J`` [kg·m²] (> 0 when physical).
    """

    t: float
    theta: np.ndarray
    index: np.ndarray
    covariance: np.ndarray
    samples_used: int
    samples_rejected: int
    infeasible: int
    physical: bool
    triangle_margin: float

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the estimated entries (p,)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the estimated entries."""
        return tuple(FULL_NAMES[i] for i in self.index)

    def parameter_estimate(self) -> ParameterEstimate:
        """The ``[m, Ixx, Iyy, Izz]`` part as a :class:`oacli.types.ParameterEstimate` (method ``"rls"``).

        Returns
        -------
        ParameterEstimate
        """
        pos = [int(np.flatnonzero(self.index == i)[0]) for i in range(4)]
        return ParameterEstimate(self.t, self.theta[0:4], self.covariance[np.ix_(pos, pos)], "rls",
                                 self.samples_used, self.samples_rejected)


@dataclass
class RlsFullEstimator:
    """Recursive least squares on accelerations for ``[m, J (with products), c]`` (module docstring).

    Parameters
    ----------
    prior_theta : ndarray, shape (16,)
        Prior mean of θ (must be physical); its scales are the calibrated ``κ_F``, ``κ_τ`` used as known.
    prior_covariance : ndarray, shape (16, 16)
        Prior covariance of θ (only the estimated entries' block is used).
    groups : sequence of str
        Estimated groups of :data:`RLS_FULL_GROUPS`; mass and inertia are required.
    gate_probability : float or None
        χ² gate probability (0.99 in flight; None: no gate).
    t0 : float
        Time of the prior [s].
    """

    prior_theta: np.ndarray
    prior_covariance: np.ndarray
    groups: Sequence[str] = RLS_FULL_GROUPS
    gate_probability: float | None = 0.99
    t0: float = 0.0
    history: list[tuple[float, str, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        unknown = sorted(set(self.groups) - set(RLS_FULL_GROUPS))
        if unknown:
            raise ValueError(f"the full RLS estimates {list(RLS_FULL_GROUPS)}, not {unknown} (scales: calibrate)")
        if "mass" not in self.groups or "inertia" not in self.groups:
            raise ValueError("the full RLS needs mass and inertia among its groups")
        theta = np.array(self.prior_theta, dtype=float).reshape(N_FULL)
        if not is_physical_full(theta):
            raise ValueError("the prior θ is not physical")
        if "products" not in self.groups and np.any(theta[4:7] != 0):
            raise ValueError("products held fixed must be 0 (K = J⁻¹ is then diagonal); estimate them instead")
        self._theta_fixed = theta
        self._idx = np.array([i for g in RLS_FULL_GROUPS if g in self.groups for i in _PSI_OF_GROUP[g]], dtype=int)
        k = np.linalg.inv(inertia_tensor(theta))
        self._psi_all = np.r_[1.0 / theta[0], _entries(k), theta[7:10]]
        t_jac = _theta_jacobian(self._psi_all)[np.ix_(self._idx, self._idx)]
        t_inv = np.linalg.inv(t_jac)
        cov = np.array(self.prior_covariance, dtype=float).reshape(N_FULL, N_FULL)[np.ix_(self._idx, self._idx)]
        self._p = t_inv @ cov @ t_inv.T
        self._gate = (chi2_threshold(_MEAS_DIM, self.gate_probability) if self.gate_probability is not None
                      else float("inf"))
        self.samples_used = 0
        self.samples_rejected = 0
        self.infeasible = 0
        self._t = float(self.t0)

    def _theta_full(self, psi_all: np.ndarray) -> np.ndarray:
        out = self._theta_fixed.copy()
        out[0:10] = _theta_of_psi(psi_all)
        return out

    @property
    def estimate(self) -> RlsFullEstimate:
        """The current estimate."""
        theta = self._theta_full(self._psi_all)
        t_jac = _theta_jacobian(self._psi_all)[np.ix_(self._idx, self._idx)]
        cov = t_jac @ self._p @ t_jac.T
        j = inertia_tensor(theta)
        margin = float(np.linalg.eigvalsh(0.5 * np.trace(j) * np.eye(3) - j).min())
        return RlsFullEstimate(self._t, theta, self._idx.copy(), 0.5 * (cov + cov.T), self.samples_used,
                               self.samples_rejected, self.infeasible, is_physical_full(theta), margin)

    def update(self, t: float, accel_mps2: np.ndarray, alpha_radps2: np.ndarray, force_N: np.ndarray,
               torque_Nm: np.ndarray, rate_radps: np.ndarray, accel_std_mps2: float, alpha_std_radps2: float) -> str:
        """One update with ``z = [a, α]`` (body frame); returns ``"accepted"``, ``"rejected"`` or ``"infeasible"``.

        Parameters
        ----------
        t : float
            Sample time [s].
        accel_mps2, alpha_radps2 : ndarray, shape (3,)
            Measured accelerations of the centre of mass and of the attitude, body frame.
        force_N, torque_Nm : ndarray, shape (3,)
            Applied (commanded) force and torque, body frame; scaled here by the prior's κ_F, κ_τ.
        rate_radps : ndarray, shape (3,)
            Measured angular rate.
        accel_std_mps2, alpha_std_radps2 : float
            Noise std of each component.

        Returns
        -------
        str
        """
        kf, kt = self._theta_fixed[10:13], self._theta_fixed[13:16]
        h, jac_all = full_acceleration_model(self._psi_all, kf * np.asarray(force_N, dtype=float),
                                             kt * np.asarray(torque_Nm, dtype=float), np.asarray(rate_radps, float))
        jac = jac_all[:, self._idx]
        r = np.r_[np.full(3, accel_std_mps2**2), np.full(3, alpha_std_radps2**2)]
        nu = np.r_[accel_mps2, alpha_radps2] - h
        s = jac @ self._p @ jac.T + np.diag(r)
        chol = np.linalg.cholesky(0.5 * (s + s.T))
        w = np.linalg.solve(chol, nu)
        d2 = float(w @ w)
        if d2 > self._gate:
            self.samples_rejected += 1
            self.history.append((float(t), "rejected", d2))
            return "rejected"
        gain = np.linalg.solve(chol.T, np.linalg.solve(chol, jac @ self._p)).T
        psi = self._psi_all.copy()
        psi[self._idx] += gain @ nu
        ok = psi[0] > 0
        if ok:
            try:
                np.linalg.cholesky(_sym(psi[1:7]))
                ok = is_physical_full(self._theta_full(psi))
            except np.linalg.LinAlgError:
                ok = False
        if not ok:
            self.infeasible += 1
            self.history.append((float(t), "infeasible", d2))
            return "infeasible"
        ikh = np.eye(self._idx.size) - gain @ jac
        self._p = ikh @ self._p @ ikh.T + (gain * r) @ gain.T  # Joseph form
        self._psi_all = psi
        self._t = float(t)
        self.samples_used += 1
        self.history.append((float(t), "accepted", d2))
        return "accepted"

    def run(self, samples: AccelerationSamples) -> RlsFullEstimate:
        """Update with every sample in order.

        Parameters
        ----------
        samples : AccelerationSamples

        Returns
        -------
        RlsFullEstimate
        """
        for k in range(len(samples)):
            self.update(samples.t[k], samples.accel_mps2[k], samples.alpha_radps2[k], samples.force_N[k],
                        samples.torque_Nm[k], samples.rate_radps[k], samples.accel_std_mps2[k],
                        samples.alpha_std_radps2[k])
        return self.estimate
