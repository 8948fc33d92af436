"""Disturbance sets W of the translational tube MPC, per world axis and control step.

Translation is exactly linear in the world frame (force in the world frame, [Doerr2021] Eq. 34), so the
model error of one axis over one control step ``dt`` is additive on ``[position, velocity]``:

* mass uncertainty ([Doerr2021] Eq. 28): with the mass estimate ``m₀`` and standard deviation ``σ``, the largest
  one-step deviation at the largest input ``u_max`` is
  ``w_max = |f(u_max, m₀) − max(f(u_max, m₀+2σ), f(u_max, m₀−2σ))|``, ``f`` the exact discrete double
  integrator from rest, ``f(u, m) = [dt²/(2m), dt/m] u``; the lighter mass moves further, so
  ``w_max = u_max (1/(m₀ − 2σ) − 1/m₀) [dt²/2, dt]``;
* an external force bound ``d`` (world frame): ``d [dt²/2, dt] / (m₀ − 2σ)`` (the lightest plausible mass);
* a given box ``[position, velocity]`` per step;
* measurement noise bounded by the box N: the controller sees ``x̃ = x + n``, and its error ``ẽ = x̃ − z`` obeys
  ``ẽ⁺ = A_K ẽ + w + n⁺ − A n`` (A the open-loop model), so W gains ``N ⊕ (−A N)``.

``W = scale · (box(mass + force + given) ⊕ N ⊕ (−A N))``; ``scale < 1`` only by an explicit policy.

W's attitude part (:func:`attitude_disturbance`, [Doerr2021] Eq. 28 generalised to the full rigid body's estimated
parameters): per body axis, the torque the model leaves unexplained from ``n_σ`` σ of the principal inertias, the
products of inertia and the centre of mass (the residual moment ``δc × F`` of the compensated offset,
:mod:`oacli.control.rigid_terms`). The centre of mass does not enter the translation (the force accelerates the
centre of mass by ``F/m`` wherever it acts). Attitude has no tube (:mod:`oacli.control.tube_mpc`): this part is
reported with each tracking run (``attitude_w``), sized for a tube on attitude, and bounds what the attitude MPC's
feedback must reject.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from oacli.control.rigid_terms import com_moment_bound_Nm
from oacli.model.robot_model import RobotModel
from oacli.sets import Polytope


def step_gain(dt_s: float) -> np.ndarray:
    """``[dt²/2, dt]``: position and velocity change per unit acceleration held over one step.

    Parameters
    ----------
    dt_s : float
        Step [s].

    Returns
    -------
    ndarray, shape (2,)
    """
    return np.array([0.5 * dt_s * dt_s, dt_s])


def mass_uncertainty_bound(model: RobotModel, force_max_N: float, dt_s: float, n_sigma: float = 2.0) -> np.ndarray:
    """[Doerr2021] Eq. 28: one-step bound ``[position m, velocity m/s]`` from the model's mass uncertainty.

    The mass interval is ``model.mass_bounds_kg(n_sigma)`` (σ_m from ``model.covariance``).

    Parameters
    ----------
    model : RobotModel
        The controller's model: mass m₀ [kg] and its covariance.
    force_max_N : float
        Largest force magnitude the controller applies on this axis [N].
    dt_s : float
        Control step [s].
    n_sigma : float
        Width of the mass interval in σ (2 in Eq. 28).

    Returns
    -------
    ndarray, shape (2,)
        Half-widths ``[position m, velocity m/s]`` of the one-step disturbance.

    Raises
    ------
    ValueError
        When ``m₀ − n_sigma σ ≤ 0``.
    """
    low, high = model.mass_bounds_kg(n_sigma)
    f0 = force_max_N / model.mass_kg * step_gain(dt_s)
    f_low = force_max_N / low * step_gain(dt_s)
    f_high = force_max_N / high * step_gain(dt_s)
    return np.abs(f0 - np.maximum(f_low, f_high))


def force_disturbance_bound(force_N: float, model: RobotModel, dt_s: float, n_sigma: float = 2.0) -> np.ndarray:
    """One-step bound ``[position m, velocity m/s]`` of a force ``|d| ≤ force_N`` held over ``dt_s`` on the
    lightest plausible mass ``m₀ − n_σ σ_m`` of ``model`` (:meth:`RobotModel.mass_bounds_kg`).

    Parameters
    ----------
    force_N : float
        Bound of the disturbance force [N].
    model : RobotModel
        The controller's model.
    dt_s : float
        Step [s].
    n_sigma : float
        Width of the mass interval in σ.

    Returns
    -------
    ndarray, shape (2,)
        Half-widths ``[position m, velocity m/s]``.
    """
    return force_N / model.mass_bounds_kg(n_sigma)[0] * step_gain(dt_s)


def _zeros3() -> np.ndarray:
    return np.zeros(3)


@dataclass(frozen=True)
class DisturbanceSpec:
    """What W is made of besides the model, per world axis (each array shape (3,)).

    The mass m₀ and its σ are the controller's model's (:class:`~oacli.model.robot_model.RobotModel`, passed to
    :meth:`axis`); the spec holds only the consumer's choices.

    Attributes
    ----------
    n_sigma : float
        Mass interval half-width in σ ([Doerr2021] Eq. 28: 2).
    force_N : ndarray
        External force bound per axis [N].
    box_position_m, box_velocity_mps : ndarray
        Extra per-step box half-widths [m], [m/s].
    noise_position_m, noise_velocity_mps : ndarray
        Measurement noise bounds [m], [m/s].
    """

    n_sigma: float = 2.0
    force_N: np.ndarray = field(default_factory=_zeros3)
    box_position_m: np.ndarray = field(default_factory=_zeros3)
    box_velocity_mps: np.ndarray = field(default_factory=_zeros3)
    noise_position_m: np.ndarray = field(default_factory=_zeros3)
    noise_velocity_mps: np.ndarray = field(default_factory=_zeros3)

    def noise_box(self, axis: int) -> np.ndarray:
        """Measurement noise half-widths ``[position, velocity]`` of one axis.

        Parameters
        ----------
        axis : int
            World axis 0, 1 or 2.

        Returns
        -------
        ndarray, shape (2,)
        """
        return np.array([self.noise_position_m[axis], self.noise_velocity_mps[axis]], dtype=float)

    def axis(self, model: RobotModel, axis: int, force_max_N: float, dt_s: float,
             scale: float = 1.0) -> AxisDisturbance:
        """W of world axis ``axis`` (0, 1, 2) for ``model``, inputs ``|u| ≤ force_max_N`` and control step ``dt_s``.

        Parameters
        ----------
        model : RobotModel
            The controller's model: m₀ and σ_m (0: no mass term) of [Doerr2021] Eq. 28.
        axis : int
            World axis 0, 1 or 2.
        force_max_N : float
            Largest force magnitude the controller applies on this axis [N].
        dt_s : float
            Control step [s].
        scale : float, optional
            Factor applied to the whole W (1: none).

        Returns
        -------
        AxisDisturbance
            W and its parts.
        """
        mass_term = (
            mass_uncertainty_bound(model, force_max_N, dt_s, self.n_sigma)
            if model.mass_std_kg > 0
            else np.zeros(2)
        )
        force_term = force_disturbance_bound(float(self.force_N[axis]), model, dt_s, self.n_sigma)
        box_term = np.array([self.box_position_m[axis], self.box_velocity_mps[axis]], dtype=float)
        noise = self.noise_box(axis)
        half = mass_term + force_term + box_term
        w = Polytope.symmetric_box(half)
        if np.any(noise > 0):
            a = np.array([[1.0, dt_s], [0.0, 1.0]])
            n_box = Polytope.symmetric_box(noise)
            w = w.minkowski_sum(n_box).minkowski_sum(n_box.linear_map(-a))
        if scale != 1.0:
            w = w.scaled(scale)
        return AxisDisturbance(w, mass_term, force_term, box_term, noise, float(scale))


@dataclass(frozen=True)
class AxisDisturbance:
    """W of one axis per control step, and its parts (each ``[position m, velocity m/s]`` half-widths).

    Attributes
    ----------
    w : Polytope
        The disturbance set (2-D).
    mass_term, force_term, box_term : ndarray, shape (2,)
    noise_bound : ndarray, shape (2,)
        Measurement noise half-widths (enter W as ``N ⊕ (−A N)``).
    scale : float
        Factor applied to the whole set (1 unless an explicit W-shrinking policy chose less).
    """

    w: Polytope
    mass_term: np.ndarray
    force_term: np.ndarray
    box_term: np.ndarray
    noise_bound: np.ndarray
    scale: float

    @property
    def half_widths(self) -> np.ndarray:
        """Largest |w| per component ``[position m, velocity m/s]`` (support along ±e)."""
        return np.maximum(self.w.support(np.eye(2)), self.w.support(-np.eye(2)))


@dataclass(frozen=True)
class AttitudeDisturbance:
    """W's attitude part ([Doerr2021] Eq. 28 generalised to the full rigid body): the torque about the centre of mass
    the model leaves unexplained, per body axis, and its one-step ``[φ rad, ω rad/s]`` half-widths.

    Attributes
    ----------
    inertia_term_Nm : ndarray, shape (3,)
        The principal inertias' ``n_σ`` interval at the largest planned angular acceleration: ``n_σ σ_I,i α_max,i``
        with ``α_max,i = τ_max,i / (I_i − n_σ σ_I,i)`` (Eq. 28's mass term for the rotation).
    products_term_Nm : ndarray, shape (3,)
        The products' ``n_σ`` box: ``Σ_{j≠i} n_σ σ_ij α_max,j + ‖ω_max‖² ‖δJ‖_F`` (``δJ ω̇`` and the gyroscopic
        ``ω × δJ ω``).
    com_term_Nm : ndarray, shape (3,)
        The residual centre-of-mass moment ``|δc × F_b|`` over ``|δc_j| ≤ n_σ σ_c,j``, every attitude and world force
        in the box (:func:`oacli.control.rigid_terms.com_moment_bound_Nm`; a vertex of the δc box).
    step_box : ndarray, shape (3, 2)
        Per body axis, ``[φ, ω]`` half-widths of one control step: the total torque on the lightest plausible
        inertia, ``(Σ terms) / (I_i − n_σ σ_I,i) [dt²/2, dt]`` (the exact double integrator, as the translation's).
    """

    inertia_term_Nm: np.ndarray
    products_term_Nm: np.ndarray
    com_term_Nm: np.ndarray
    step_box: np.ndarray

    @property
    def torque_Nm(self) -> np.ndarray:
        """The total torque half-width per body axis [N·m], shape (3,)."""
        return np.asarray(self.inertia_term_Nm + self.products_term_Nm + self.com_term_Nm)

    def summary(self) -> dict[str, list[float]]:
        """The terms as plain lists (a stage summary's ``attitude_w`` entry).

        Returns
        -------
        dict
            ``torque_Nm`` and its three terms [N·m], ``step_attitude_rad`` and ``step_rate_radps`` per body axis.
        """
        return {"torque_Nm": [float(v) for v in self.torque_Nm],
                "inertia_term_Nm": [float(v) for v in self.inertia_term_Nm],
                "products_term_Nm": [float(v) for v in self.products_term_Nm],
                "com_term_Nm": [float(v) for v in self.com_term_Nm],
                "step_attitude_rad": [float(v) for v in self.step_box[:, 0]],
                "step_rate_radps": [float(v) for v in self.step_box[:, 1]]}


def attitude_disturbance(model: RobotModel, force_limit_N: np.ndarray, torque_limit_Nm: np.ndarray,
                         rate_limit_radps: np.ndarray, dt_s: float, n_sigma: float = 2.0) -> AttitudeDisturbance:
    """W's attitude part of ``model`` (:class:`AttitudeDisturbance`; [Doerr2021] Eq. 28 with ``n_σ`` of every
    estimated parameter's σ: inertias, products of inertia, centre of mass).

    Parameters
    ----------
    model : RobotModel
        The controller's model: principal inertias with σ (covariance), products and centre of mass with σ.
    force_limit_N : ndarray, shape (3,)
        The largest world force the controller commands per axis [N].
    torque_limit_Nm : ndarray, shape (3,)
        The largest torque the controller commands per body axis [N·m].
    rate_limit_radps : ndarray, shape (3,)
        The body-rate bound [rad/s] (the gyroscopic term's ω).
    dt_s : float
        Control step [s].
    n_sigma : float
        Half-width of every interval in σ.

    Returns
    -------
    AttitudeDisturbance

    Raises
    ------
    ValueError
        An inertia's lower bound ``I − n_σ σ`` not positive.
    """
    inertia, sigma_i = model.inertia_kgm2, n_sigma * model.std[1:4]
    low = inertia - sigma_i
    if np.any(~(low > 0)):
        raise ValueError(f"inertia_kgm2 - {n_sigma:g} sigma = {low.tolist()} kg·m² is not positive")
    alpha = np.asarray(torque_limit_Nm, dtype=float) / low  # the largest angular acceleration of a plausible plant
    inertia_term = sigma_i * alpha
    d_products = n_sigma * model.products_std_kgm2  # [Ixy, Ixz, Iyz]
    d_j = np.array([[0.0, d_products[0], d_products[1]], [d_products[0], 0.0, d_products[2]],
                    [d_products[1], d_products[2], 0.0]])
    gyro = float(np.sum(np.asarray(rate_limit_radps, dtype=float) ** 2)) * float(np.linalg.norm(d_j))
    products_term = d_j @ alpha + gyro  # both 0 without products' σ
    com_term = com_moment_bound_Nm(n_sigma * model.com_std_m, force_limit_N)
    total = inertia_term + products_term + com_term
    box = (total / low)[:, None] * step_gain(dt_s)[None, :]
    return AttitudeDisturbance(inertia_term, products_term, com_term, box)
