"""The full rigid body's parameters θ and a parametrisation φ that is physical by construction.

θ (16 entries, body frame of the robot): mass ``m`` [kg]; the inertia tensor about the centre of mass, diagonal
``Ixx, Iyy, Izz`` and off-diagonal entries ``Ixy, Ixz, Iyz`` of the symmetric matrix ``J`` [kg·m²]; the centre of mass
relative to the geometric centre ``c`` [m]; the force scale ``κ_F`` and torque scale ``κ_τ`` per body axis
(delivered ÷ commanded, :mod:`oacli.sim.actuators`). [Doerr2021]'s parameter set includes the centre of mass and the
principal axes (text before Eq. 29); [ReSWARM2023] Eqs. 38-39 calibrate the force scale.

Physical consistency is the positive-definite pseudo-inertia ``P = [[Σ_o, h], [hᵀ, m]]`` (Wensing, Kim & Slotine
2017, Eq. 12), ``Σ_o = ∫ p pᵀ dm`` the second moment about the geometric centre and ``h = m c``. Rucker & Wensing
(2022, "Smooth parameterization of rigid-body inertia", Eq. 9) write ``P = U Uᵀ`` with ``U`` upper triangular and
an exponentiated diagonal (log-Cholesky). Its last column is ``e^α [t; 1]`` with ``t = c`` and ``m = e^{2α}``, and
its upper 3×3 block gives ``Σ_c = Σ_o − m c cᵀ``, the second moment about the centre of mass: ``P ≻ 0`` exactly when
``m > 0`` and ``Σ_c ≻ 0``. Here, equivalently, with ``Σ_c = L Lᵀ`` (``L`` lower triangular):

    φ = [log m, ℓ_x, ℓ_y, ℓ_z, L_yx, L_zx, L_zy, c_x, c_y, c_z, κ_F (3), κ_τ (3)],   L_ii = exp(ℓ_i / 2)
    J = tr(Σ_c) 1 − Σ_c                                                                (Wensing 2017, Eq. 7)

Every real φ gives ``m > 0`` and a positive-definite ``J`` whose principal moments satisfy the triangle
inequalities. With the products fixed at zero (``L`` diagonal) ``ℓ = [log A, log B, log C]`` of
:mod:`oacli.estimation.parametrization`, so the reduced set ``[mass, inertia]`` *is* the 4-parameter φ. The scale
factors are estimated as they are (a prior keeps them near 1; their physical set is not at stake).

Which entries are estimated is chosen by groups (``estimation.parameters``); the others stay at the prior's mean.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

N_FULL = 16
GROUPS: dict[str, tuple[int, ...]] = {
    "mass": (0,),
    "inertia": (1, 2, 3),
    "products": (4, 5, 6),
    "com": (7, 8, 9),
    "force_scale": (10, 11, 12),
    "torque_scale": (13, 14, 15),
}
"""θ (and φ) indices of each parameter group."""
FULL_NAMES = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2", "Ixy_kgm2", "Ixz_kgm2", "Iyz_kgm2", "com_x_m",
              "com_y_m", "com_z_m", "force_scale_x", "force_scale_y", "force_scale_z", "torque_scale_x",
              "torque_scale_y", "torque_scale_z")
LEGACY_GROUPS = ("mass", "inertia")
"""θ = [m, Ixx, Iyy, Izz]: the estimators' original 4 parameters."""

_OFF = ((1, 0), (2, 0), (2, 1))  # L's strictly lower entries in φ[4:7]
_J_OFF = ((0, 1), (0, 2), (1, 2))  # J's off-diagonal entries in θ[4:7]


def inertia_tensor(theta: np.ndarray) -> np.ndarray:
    """``J`` (3×3) of θ's inertia entries [kg·m²].

    Parameters
    ----------
    theta : ndarray, shape (16,)

    Returns
    -------
    ndarray, shape (3, 3)
    """
    t = np.asarray(theta, dtype=float)
    j = np.diag(t[1:4])
    for (a, b), v in zip(_J_OFF, t[4:7], strict=True):
        j[a, b] = j[b, a] = v
    return j


def _lower(phi: np.ndarray) -> np.ndarray:
    low = np.diag(np.exp(0.5 * np.asarray(phi[1:4], dtype=float)))
    for (a, b), v in zip(_OFF, phi[4:7], strict=True):
        low[a, b] = v
    return low


def theta_from_phi_full(phi: np.ndarray) -> np.ndarray:
    """θ (16) of φ (16); always physical (module docstring, Rucker & Wensing 2022 Eq. 9).

    Parameters
    ----------
    phi : ndarray, shape (16,)

    Returns
    -------
    ndarray, shape (16,)
    """
    phi = np.asarray(phi, dtype=float)
    low = _lower(phi)
    sigma = low @ low.T
    j = np.trace(sigma) * np.eye(3) - sigma
    out = np.empty(N_FULL)
    out[0] = np.exp(phi[0])
    out[1:4] = np.diag(j)
    out[4:7] = [j[a, b] for a, b in _J_OFF]
    out[7:16] = phi[7:16]
    return out


def phi_from_theta_full(theta: np.ndarray) -> np.ndarray:
    """φ (16) of a physical θ (raises ``ValueError`` when ``m <= 0`` or ``Σ_c = ½ tr(J) 1 − J`` is not positive
    definite, i.e. ``J`` breaks a strict triangle inequality).

    Parameters
    ----------
    theta : ndarray, shape (16,)

    Returns
    -------
    ndarray, shape (16,)
    """
    theta = np.asarray(theta, dtype=float)
    j = inertia_tensor(theta)
    sigma = 0.5 * np.trace(j) * np.eye(3) - j
    if not theta[0] > 0:
        raise ValueError(f"mass {theta[0]} is not > 0")
    try:
        low = np.linalg.cholesky(sigma)
    except np.linalg.LinAlgError:
        raise ValueError(f"the inertia tensor {j.tolist()} is not physical (Σ = tr(J)/2 − J is not positive "
                         "definite: a triangle inequality fails)") from None
    out = np.empty(N_FULL)
    out[0] = np.log(theta[0])
    out[1:4] = 2.0 * np.log(np.diag(low))
    out[4:7] = [low[a, b] for a, b in _OFF]
    out[7:16] = theta[7:16]
    return out


def theta_jacobian_full(phi: np.ndarray) -> np.ndarray:
    """``dθ/dφ`` (16×16) at φ, exact.

    Parameters
    ----------
    phi : ndarray, shape (16,)

    Returns
    -------
    ndarray, shape (16, 16)
    """
    phi = np.asarray(phi, dtype=float)
    low = _lower(phi)
    jac = np.zeros((N_FULL, N_FULL))
    jac[0, 0] = np.exp(phi[0])
    # dL/dφ_i for the 6 inertia coordinates, then dΣ = dL Lᵀ + L dLᵀ, dJ = tr(dΣ) 1 − dΣ.
    entries = [(a, a) for a in range(3)] + list(_OFF)
    for col, (a, b) in enumerate(entries):
        d_low = np.zeros((3, 3))
        d_low[a, b] = 0.5 * low[a, a] if a == b else 1.0
        d_sigma = d_low @ low.T + low @ d_low.T
        d_j = np.trace(d_sigma) * np.eye(3) - d_sigma
        jac[1:4, 1 + col] = np.diag(d_j)
        jac[4:7, 1 + col] = [d_j[p, q] for p, q in _J_OFF]
    jac[7:16, 7:16] = np.eye(9)
    return jac


@dataclass(frozen=True)
class ParameterSet:
    """Which entries of θ are estimated; the others are held at ``theta_fixed``.

    Attributes
    ----------
    groups : tuple of str
        Estimated groups (keys of :data:`GROUPS`), in θ order.
    theta_fixed : ndarray, shape (16,)
        θ for the entries not estimated (and the starting point of the others) [SI units].
    """

    groups: tuple[str, ...]
    theta_fixed: np.ndarray

    @classmethod
    def build(cls, groups: Sequence[str], theta_fixed: np.ndarray) -> ParameterSet:
        """A set from group names (any order; unknown names raise ``ValueError``).

        Parameters
        ----------
        groups : sequence of str
        theta_fixed : ndarray, shape (16,)

        Returns
        -------
        ParameterSet
        """
        unknown = sorted(set(groups) - set(GROUPS))
        if unknown:
            raise ValueError(f"unknown parameter group(s) {unknown}: choose from {list(GROUPS)}")
        if "products" in groups and "inertia" not in groups:
            raise ValueError("'products' needs 'inertia' (the inertia tensor is estimated as a whole)")
        ordered = tuple(g for g in GROUPS if g in groups)
        return cls(ordered, np.array(theta_fixed, dtype=float).reshape(N_FULL))

    @property
    def index(self) -> np.ndarray:
        """θ/φ indices of the estimated entries, in θ order."""
        return np.array([i for g in self.groups for i in GROUPS[g]], dtype=int)

    @property
    def n(self) -> int:
        """Number of estimated entries."""
        return int(self.index.size)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the estimated entries (:data:`FULL_NAMES`)."""
        return tuple(FULL_NAMES[i] for i in self.index)

    @property
    def is_legacy(self) -> bool:
        """The original θ = [m, Ixx, Iyy, Izz] with the rest of the model ideal (zero CoM offset, unit scales,
        no products)."""
        ideal = np.r_[np.zeros(6), np.ones(6)]
        return self.groups == LEGACY_GROUPS and bool(np.all(self.theta_fixed[4:16] == ideal))

    def phi_full(self, phi: np.ndarray) -> np.ndarray:
        """The 16-entry φ with the estimated entries ``phi`` inserted into the fixed ones.

        Parameters
        ----------
        phi : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (16,)
        """
        out = phi_from_theta_full(self.theta_fixed)
        out[self.index] = np.asarray(phi, dtype=float)
        return out

    def phi_from_theta(self, theta_full: np.ndarray) -> np.ndarray:
        """φ of the estimated entries of a physical θ (the others are ignored).

        Parameters
        ----------
        theta_full : ndarray, shape (16,)

        Returns
        -------
        ndarray, shape (n,)
        """
        return phi_from_theta_full(theta_full)[self.index]

    def theta(self, phi: np.ndarray) -> np.ndarray:
        """θ (16) of φ.

        Parameters
        ----------
        phi : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (16,)
        """
        return theta_from_phi_full(self.phi_full(phi))

    def jacobian(self, phi: np.ndarray) -> np.ndarray:
        """``dθ/dφ`` at φ.

        Parameters
        ----------
        phi : ndarray, shape (n,)

        Returns
        -------
        ndarray, shape (16, n)
        """
        return theta_jacobian_full(self.phi_full(phi))[:, self.index]


def is_physical_full(theta: np.ndarray) -> bool:
    """True when θ (16) has ``m > 0`` and a positive-definite ``Σ_c`` (Wensing 2017: ``P ≻ 0``).

    Parameters
    ----------
    theta : ndarray, shape (16,)

    Returns
    -------
    bool
    """
    try:
        phi_from_theta_full(theta)
    except ValueError:
        return False
    return bool(np.all(np.isfinite(theta)))


__all__ = ["FULL_NAMES", "GROUPS", "LEGACY_GROUPS", "N_FULL", "ParameterSet", "inertia_tensor", "is_physical_full",
           "phi_from_theta_full", "theta_from_phi_full", "theta_jacobian_full"]
