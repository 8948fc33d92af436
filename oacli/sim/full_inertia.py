"""The truth plant with a full inertia tensor: products of inertia the controllers' diagonal model does not know.

[Doerr2021] Eq. 35b, ``ω̇ = J⁻¹ (τ − ω × J ω)``, with the full symmetric positive-definite tensor ``J`` instead of
``diag(Ixx, Iyy, Izz)``; everything else is :func:`oacli.model.rigid_body.dynamics`. Integrated with the same
classical RK4 step and quaternion renormalisation as :func:`oacli.model.rigid_body.propagate`, so a diagonal ``J``
gives the same states to rounding.
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat
from oacli.model.rigid_body import dynamics
from oacli.types import InertialParams


class TensorPlant:
    """RK4 step of the rigid body with a full inertia tensor.

    Parameters
    ----------
    plant : InertialParams
        The true plant (its mass [kg]; its principal inertias are replaced by the tensor's diagonal).
    inertia_tensor_kgm2 : array_like, shape (3, 3)
        ``J`` about the centre of mass, body frame [kg·m²] (symmetric positive definite).
    """

    def __init__(self, plant: InertialParams, inertia_tensor_kgm2: np.ndarray) -> None:
        self.inertia = np.array(inertia_tensor_kgm2, dtype=float).reshape(3, 3)
        self.inertia_inv = np.linalg.inv(self.inertia)
        self.theta = np.array([plant.mass_kg, *np.diag(self.inertia)])

    def dynamics(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``ẋ`` with ``ω̇ = J⁻¹ (τ − ω × J ω)`` ([Doerr2021] Eq. 35b).

        Parameters
        ----------
        x : ndarray, shape (13,)
        u : ndarray, shape (6,)

        Returns
        -------
        ndarray, shape (13,)
        """
        out = dynamics(x, u, self.theta)
        w = x[10:13]
        out[10:13] = self.inertia_inv @ (u[3:6] - np.cross(w, self.inertia @ w))
        return out

    def propagate(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float) -> np.ndarray:
        """One RK4 step of length ``dt`` [s] and quaternion renormalisation (``theta`` is ignored: same signature as
        :func:`oacli.model.rigid_body.propagate`).

        Parameters
        ----------
        x : ndarray, shape (13,)
        u : ndarray, shape (6,)
        theta : ndarray
            Unused.
        dt : float

        Returns
        -------
        ndarray, shape (13,)
        """
        k1 = self.dynamics(x, u)
        k2 = self.dynamics(x + 0.5 * dt * k1, u)
        k3 = self.dynamics(x + 0.5 * dt * k2, u)
        k4 = self.dynamics(x + dt * k3, u)
        out = x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out[6:10] = quat.normalize(out[6:10])
        return np.asarray(out)


__all__ = ["TensorPlant"]
