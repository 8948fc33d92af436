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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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
