"""The robot model that flows through the stages: inertial parameters, their uncertainty, limits and geometry.

One object carries what the planner, the tube design, the MPCs, the excitation design, the estimator and the
simulator need to know about the robot ([Doerr2021] Fig. 1: the model is planned with, controlled with, excited,
estimated and handed to the next segment):

* ``θ = [m, Ixx, Iyy, Izz]`` [kg, kg·m² ×3] of the free-flyer dynamics ([Doerr2021] Eqs. 33-36), principal axes;
* the covariance of θ (4 × 4; zeros: known exactly): a prior before estimation, the estimator's covariance after
  ([Doerr2021] Eqs. 31-32; [ReSWARM2023] §4.4.1);
* the actuator and flight-mode limits (:class:`oacli.model.limits.MotionLimits`; [ReSWARM2023] Table 2);
* the collision radius;
* the full rigid body beyond θ ([Doerr2021] text before Eq. 29; [ReSWARM2023] §3): the centre-of-mass offset ``c``
  from the geometric centre the thrust acts on (body frame) and the products of inertia ``[Ixy, Ixz, Iyz]`` of the
  tensor ``J`` (body frame), each with its σ (zeros: the principal-axes, centred robot, known exactly, as before
  the full rigid body was estimated). The controllers compensate ``c``'s moment and use ``J``
  (:mod:`oacli.control.rigid_terms`); W's attitude part takes their σ (:mod:`oacli.control.disturbance`).

Every σ-bound is derived from ``covariance`` by one function, :meth:`RobotModel.parameter_interval`
(``[θ_i − n_σ σ_i, θ_i + n_σ σ_i]``, [Doerr2021] Eq. 28), each consumer choosing only its own ``n_σ``: the tube's
W (:meth:`RobotModel.mass_bounds_kg`, :mod:`oacli.control.disturbance`), the design limits' heaviest plant
(:mod:`oacli.reference_limits`), the mission's reference and rate margins. The tube design, W, the observer, the
design limits, the tube's config checks and the planners take the model, not a bare mass (docs/architecture.md,
"The robot model"). The estimator hands its result to the next segment through :meth:`RobotModel.with_estimate`
(same limits and geometry, new θ and covariance).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from oacli.model.limits import MotionLimits
from oacli.types import InertialParams

N_THETA = 4
"""Length of θ = [m, Ixx, Iyy, Izz]."""

PARAMETER_NAMES = ("mass_kg", "Ixx", "Iyy", "Izz")
"""The names of θ's entries, in order (:meth:`RobotModel.parameter_interval`)."""

INERTIA_TRIANGLE_RTOL = 1e-12
"""Relative tolerance of the triangle inequalities ``Ixx + Iyy >= Izz`` (as the config's)."""

COVARIANCE_RTOL = 1e-9
"""Relative tolerance (to the largest entry) of the covariance's symmetry and smallest eigenvalue."""

_VECTORS = ("force_limit_N", "torque_limit_Nm", "velocity_limit_mps", "angular_velocity_limit_radps")
_RIGID = ("com_offset_m", "com_std_m", "inertia_products_kgm2", "products_std_kgm2")
_FIELDS = ("mass_kg", "inertia_kgm2", "covariance", *_VECTORS, "radius_m", *_RIGID)
_PRODUCT_INDEX = ((0, 1), (0, 2), (1, 2))
"""The tensor entries of ``inertia_products_kgm2`` = [Ixy, Ixz, Iyz]."""


def inertia_tensor(inertia_kgm2: np.ndarray, products_kgm2: np.ndarray) -> np.ndarray:
    """The symmetric tensor ``J`` [kg·m²] of the diagonal ``(Ixx, Iyy, Izz)`` and the products ``(Ixy, Ixz, Iyz)``.

    Parameters
    ----------
    inertia_kgm2 : ndarray, shape (3,)
    products_kgm2 : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (3, 3)
    """
    j = np.diag(np.asarray(inertia_kgm2, dtype=float))
    for value, (a, b) in zip(np.asarray(products_kgm2, dtype=float), _PRODUCT_INDEX, strict=True):
        j[a, b] = j[b, a] = value
    return j


def _zeros3() -> np.ndarray:
    return np.zeros(3)


def _read_only(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a read-only float array of ``shape`` with finite entries (ValueError naming ``name``)."""
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    arr.setflags(write=False)
    return arr


def check_covariance(name: str, covariance: np.ndarray) -> None:
    """Refuse a matrix that is not a covariance: not symmetric or not positive semidefinite.

    Parameters
    ----------
    name : str
        Field name for the message.
    covariance : ndarray, shape (n, n)

    Raises
    ------
    ValueError
        Naming ``name`` and the reason (largest asymmetry or smallest eigenvalue).
    """
    scale = max(1.0, float(np.max(np.abs(covariance)))) if covariance.size else 1.0
    asym = float(np.max(np.abs(covariance - covariance.T))) if covariance.size else 0.0
    if asym > COVARIANCE_RTOL * scale:
        raise ValueError(f"{name}: not symmetric (largest |C - Cᵀ| = {asym:.3g})")
    low = float(np.min(np.linalg.eigvalsh(0.5 * (covariance + covariance.T))))
    if low < -COVARIANCE_RTOL * scale:
        raise ValueError(f"{name}: not positive semidefinite (smallest eigenvalue {low:.3g})")


@dataclass(frozen=True, eq=False)
class RobotModel:
    """What the stages know about the robot: θ, its covariance, the limits and the collision radius.

    Immutable; every array is stored read-only as float64. Build it from the config with
    :func:`oacli.stages.settings.robot_model` (the controller's prior) or ``truth_model`` (the simulated plant).

    Attributes
    ----------
    mass_kg : float
        Mass m [kg], > 0 ([Doerr2021] Eq. 34b).
    inertia_kgm2 : ndarray, shape (3,)
        Principal moments (Ixx, Iyy, Izz) [kg·m²] about the body axes through the centre of mass, > 0, each sum of
        two >= the third ([Doerr2021] Eq. 35b).
    covariance : ndarray, shape (4, 4)
        Covariance of θ = [m, Ixx, Iyy, Izz] [kg², kg²·m², (kg·m²)²]; symmetric positive semidefinite; zeros: θ known
        exactly.
    force_limit_N : ndarray, shape (3,)
        Force bound per world axis [N], > 0.
    torque_limit_Nm : ndarray, shape (3,)
        Torque bound per body axis [N·m], > 0.
    velocity_limit_mps : ndarray, shape (3,)
        Velocity bound per world axis [m/s], > 0.
    angular_velocity_limit_radps : ndarray, shape (3,)
        Angular-rate bound per body axis [rad/s], > 0.
    radius_m : float
        Collision radius [m], >= 0.
    com_offset_m : ndarray, shape (3,)
        Centre of mass relative to the geometric centre, body frame [m] (default zeros).
    com_std_m : ndarray, shape (3,)
        Its σ per body axis [m], >= 0 (default zeros: known).
    inertia_products_kgm2 : ndarray, shape (3,)
        Products of inertia ``[Ixy, Ixz, Iyz]`` [kg·m²] of the tensor ``J`` whose diagonal is ``inertia_kgm2``
        (default zeros: principal axes); ``J`` must be positive definite with principal moments satisfying the
        triangle inequalities.
    products_std_kgm2 : ndarray, shape (3,)
        Their σ [kg·m²], >= 0 (default zeros).

    Raises
    ------
    ValueError
        On construction, naming the field: a non-positive mass or inertia, a triangle inequality broken, a
        covariance that is not 4 × 4 symmetric positive semidefinite, a limit not finite and > 0, a negative radius.
    """

    mass_kg: float
    inertia_kgm2: np.ndarray
    covariance: np.ndarray
    force_limit_N: np.ndarray
    torque_limit_Nm: np.ndarray
    velocity_limit_mps: np.ndarray
    angular_velocity_limit_radps: np.ndarray
    radius_m: float = 0.0
    com_offset_m: np.ndarray = field(default_factory=_zeros3)
    com_std_m: np.ndarray = field(default_factory=_zeros3)
    inertia_products_kgm2: np.ndarray = field(default_factory=_zeros3)
    products_std_kgm2: np.ndarray = field(default_factory=_zeros3)

    def __post_init__(self) -> None:
        mass = float(self.mass_kg)
        if not (mass > 0 and np.isfinite(mass)):
            raise ValueError(f"mass_kg: must be a finite number > 0, got {mass:g}")
        object.__setattr__(self, "mass_kg", mass)
        inertia = _read_only("inertia_kgm2", self.inertia_kgm2, (3,))
        if np.any(~(inertia > 0)):
            raise ValueError(f"inertia_kgm2: each principal moment must be > 0, got {inertia.tolist()}")
        tol = INERTIA_TRIANGLE_RTOL * float(np.max(inertia))
        names = ("Ixx", "Iyy", "Izz")
        for k in range(3):
            i, j = (m for m in range(3) if m != k)
            if inertia[i] + inertia[j] < inertia[k] - tol:
                raise ValueError(f"inertia_kgm2: the triangle inequality {names[i]} + {names[j]} >= {names[k]} "
                                 f"fails ({inertia[i]:g} + {inertia[j]:g} < {inertia[k]:g})")
        object.__setattr__(self, "inertia_kgm2", inertia)
        cov = _read_only("covariance", self.covariance, (N_THETA, N_THETA))
        check_covariance("covariance", cov)
        object.__setattr__(self, "covariance", cov)
        for name in _VECTORS:
            value = _read_only(name, getattr(self, name), (3,))
            if np.any(~(value > 0)):
                raise ValueError(f"{name}: each entry must be > 0, got {value.tolist()}")
            object.__setattr__(self, name, value)
        radius = float(self.radius_m)
        if not (radius >= 0 and np.isfinite(radius)):
            raise ValueError(f"radius_m: must be a finite number >= 0, got {radius:g}")
        object.__setattr__(self, "radius_m", radius)
        for name in _RIGID:
            value = _read_only(name, getattr(self, name), (3,))
            if name.endswith("_std_m") or name.endswith("_std_kgm2"):
                if np.any(value < 0):
                    raise ValueError(f"{name}: each entry must be >= 0, got {value.tolist()}")
            object.__setattr__(self, name, value)
        if np.any(self.inertia_products_kgm2 != 0):
            principal = np.linalg.eigvalsh(self.inertia_tensor_kgm2)
            if not principal[0] > 0:
                raise ValueError(f"inertia_products_kgm2: the tensor is not positive definite (smallest principal "
                                 f"moment {principal[0]:.3g} kg·m²)")
            if principal[0] + principal[1] < principal[2] * (1.0 - INERTIA_TRIANGLE_RTOL):
                raise ValueError("inertia_products_kgm2: the principal moments break the triangle inequality "
                                 f"({principal.tolist()})")

    def __eq__(self, other: object) -> bool:
        """Equal when every field is (arrays element by element)."""
        if not isinstance(other, RobotModel):
            return NotImplemented
        return all(np.array_equal(getattr(self, f), getattr(other, f)) for f in _FIELDS)

    __hash__ = None  # type: ignore[assignment]  # holds arrays: not hashable

    # -- inertial parameters ------------------------------------------------------------------------------------

    @property
    def theta(self) -> np.ndarray:
        """θ = [m, Ixx, Iyy, Izz] [kg, kg·m² ×3], shape (4,) ([Doerr2021] Eqs. 33-36)."""
        out = np.concatenate([[self.mass_kg], self.inertia_kgm2])
        out.setflags(write=False)
        return out

    @property
    def params(self) -> InertialParams:
        """Mass and principal inertias as :class:`oacli.types.InertialParams`."""
        return InertialParams(self.mass_kg, self.inertia_kgm2)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of θ, ``sqrt(diag(covariance))``, shape (4,)."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    @property
    def mass_std_kg(self) -> float:
        """σ_m = ``sqrt(covariance[0, 0])`` [kg]."""
        return float(self.std[0])

    def parameter_interval(self, name: str, n_sigma: float) -> tuple[float, float]:
        """The ``n_σ`` interval ``[θ_i − n_σ σ_i, θ_i + n_σ σ_i]`` of one parameter ([Doerr2021] Eq. 28).

        The one function every consumer derives a σ-bound from (the tube's W, the design limits' heaviest plant,
        the reference's and the rate margins): each chooses only its own ``n_sigma``; σ_i is
        ``sqrt(covariance[i, i])``.

        Parameters
        ----------
        name : str
            ``"mass_kg"`` or ``"Ixx"``, ``"Iyy"``, ``"Izz"`` (:data:`PARAMETER_NAMES`).
        n_sigma : float
            Half-width in standard deviations, finite and >= 0.

        Returns
        -------
        lower, upper : float
            ``θ_i ∓ n_σ σ_i`` [kg or kg·m²] (the lower bound may be <= 0: a consumer that divides by it checks).

        Raises
        ------
        ValueError
            An unknown name or a negative or non-finite ``n_sigma``.
        """
        if name not in PARAMETER_NAMES:
            raise ValueError(f"unknown parameter {name!r} (one of {', '.join(PARAMETER_NAMES)})")
        if not (n_sigma >= 0 and np.isfinite(n_sigma)):
            raise ValueError(f"n_sigma: must be a finite number >= 0, got {n_sigma}")
        i = PARAMETER_NAMES.index(name)
        half = float(n_sigma) * float(self.std[i])
        value = float(self.theta[i])
        return value - half, value + half

    def mass_bounds_kg(self, n_sigma: float = 2.0) -> tuple[float, float]:
        """The mass interval ``[m − n_σ σ_m, m + n_σ σ_m]`` of the robust tube ([Doerr2021] Eq. 28).

        :meth:`parameter_interval` of the mass, refusing a lower bound that is not positive (Eq. 28 divides by it).

        Parameters
        ----------
        n_sigma : float
            Half-width in standard deviations, >= 0 (Eq. 28: 2).

        Returns
        -------
        lower_kg, upper_kg : float
            The lightest and heaviest plausible mass [kg].

        Raises
        ------
        ValueError
            ``n_sigma`` negative, or the lower bound not positive.
        """
        lower, upper = self.parameter_interval("mass_kg", n_sigma)
        if not lower > 0:
            raise ValueError(f"mass_kg - {n_sigma:g} sigma = {lower:g} kg is not positive")
        return lower, upper

    def inertia_upper_kgm2(self, n_sigma: float) -> np.ndarray:
        """Upper ends ``I + n_σ σ_I`` of the three principal inertias' intervals [kg·m²], shape (3,).

        Parameters
        ----------
        n_sigma : float
            Half-width in standard deviations, >= 0.

        Returns
        -------
        ndarray, shape (3,)
        """
        return np.array([self.parameter_interval(n, n_sigma)[1] for n in PARAMETER_NAMES[1:]])

    # -- the full rigid body ------------------------------------------------------------------------------------

    @property
    def inertia_tensor_kgm2(self) -> np.ndarray:
        """``J`` [kg·m²], shape (3, 3): ``diag(inertia_kgm2)`` with the products off the diagonal."""
        return inertia_tensor(self.inertia_kgm2, self.inertia_products_kgm2)

    @property
    def has_rigid_body(self) -> bool:
        """True when the model carries a centre-of-mass offset or products of inertia (a mean or a σ ≠ 0)."""
        return any(bool(np.any(getattr(self, name) != 0)) for name in _RIGID)

    def with_rigid_body(self, com_offset_m: np.ndarray, com_std_m: np.ndarray, inertia_products_kgm2: np.ndarray,
                        products_std_kgm2: np.ndarray) -> RobotModel:
        """The model with the centre-of-mass offset, the products of inertia and their σ replaced.

        Parameters
        ----------
        com_offset_m, com_std_m : ndarray, shape (3,)
            ``c`` and σ_c, body frame [m].
        inertia_products_kgm2, products_std_kgm2 : ndarray, shape (3,)
            ``[Ixy, Ixz, Iyz]`` and their σ [kg·m²].

        Returns
        -------
        RobotModel

        Raises
        ------
        ValueError
            As on construction (a tensor that is not positive definite, a negative σ).
        """
        return replace(self, com_offset_m=com_offset_m, com_std_m=com_std_m,
                       inertia_products_kgm2=inertia_products_kgm2, products_std_kgm2=products_std_kgm2)

    # -- limits -------------------------------------------------------------------------------------------------

    @property
    def limits(self) -> MotionLimits:
        """The actuator and flight-mode limits as :class:`~oacli.model.limits.MotionLimits`."""
        return MotionLimits(self.force_limit_N, self.torque_limit_Nm, self.velocity_limit_mps,
                            self.angular_velocity_limit_radps)

    @property
    def input_limits(self) -> np.ndarray:
        """Input bounds ``[f (3) N, τ (3) N·m]``, shape (6,); ``|u_i| <= input_limits[i]``."""
        return np.concatenate([self.force_limit_N, self.torque_limit_Nm])

    @property
    def rate_limits(self) -> np.ndarray:
        """Rate bounds ``[v (3) m/s, ω (3) rad/s]``, shape (6,)."""
        return np.concatenate([self.velocity_limit_mps, self.angular_velocity_limit_radps])

    # -- updates ------------------------------------------------------------------------------------------------

    def with_estimate(self, theta: np.ndarray, covariance: np.ndarray) -> RobotModel:
        """The model after estimation: θ and its covariance replaced, limits, geometry and the rigid body's
        centre of mass and products kept (:meth:`with_rigid_body` replaces those).

        What the estimator hands to the next segment ([Doerr2021] Eqs. 31-32: the estimate and the covariance
        from ``(AᵀA)⁻¹``; the next tube's W from its Eq. 28 bounds).

        Parameters
        ----------
        theta : ndarray, shape (4,)
            [m kg, Ixx, Iyy, Izz kg·m²].
        covariance : ndarray, shape (4, 4)
            Its covariance.

        Returns
        -------
        RobotModel

        Raises
        ------
        ValueError
            A non-physical θ or an invalid covariance (as on construction).
        """
        t = _read_only("theta", theta, (N_THETA,))
        return replace(self, mass_kg=float(t[0]), inertia_kgm2=t[1:4], covariance=covariance)


__all__ = ["COVARIANCE_RTOL", "N_THETA", "PARAMETER_NAMES", "RobotModel", "check_covariance", "inertia_tensor"]
