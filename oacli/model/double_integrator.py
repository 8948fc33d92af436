"""Exact discrete double integrator and the hover error model used by the MPC.

Translation ([Doerr2021] Eq. 34) is linear: per axis ``[p, v]`` with ``p̈ = f/m``. Its exact zero-order-hold
discretisation over ``dt`` is ``A = [[1, dt], [0, 1]]``, ``B = [[dt²/(2m)], [dt/m]]``.

Attitude linearised about rest (ω = 0) in a body-frame rotation-vector error chart ``φ`` (``q = q_a ⊗ exp(φ)``)
is again a double integrator per principal axis: ``φ̈ = τ / I_i`` (the gyroscopic term ω × Iω is second order
and vanishes in the linearisation at ω = 0); with products of inertia, ``φ̈ = J⁻¹ τ``. That is the exact
discretisation of [Doerr2021] Eq. 2 about hover.
"""

from __future__ import annotations

import numpy as np

from oacli.model.robot_model import RobotModel
from oacli.types import InertialParams

ERROR_STATE_DIM = 12  # [r (3), v (3), φ (3), ω (3)]


def double_integrator(dt: float, gain: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation of ``ẍ = gain·u`` for one axis.

    Parameters
    ----------
    dt : float
        Step [s].
    gain : float, optional
        Input gain (``1/m`` for a force input).

    Returns
    -------
    a : ndarray, shape (2, 2)
    b : ndarray, shape (2, 1)
    """
    a = np.array([[1.0, dt], [0.0, 1.0]])
    b = np.array([[0.5 * dt * dt * gain], [dt * gain]])
    return a, b


def translational_model(model: RobotModel, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discrete translational model, state ``[r (3), v (3)]``, input ``f (3)`` (world frame).

    Parameters
    ----------
    model : RobotModel
        The robot; its mass ``model.mass_kg`` [kg] ([Doerr2021] Eq. 34b).
    dt : float
        Step [s].

    Returns
    -------
    a : ndarray, shape (6, 6)
    b : ndarray, shape (6, 3)
    """
    return _translation(model.mass_kg, dt)


def _translation(mass_kg: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`translational_model` of the mass ``mass_kg`` [kg] (also :func:`hover_error_model`'s block)."""
    eye = np.eye(3)
    a = np.block([[eye, dt * eye], [np.zeros((3, 3)), eye]])
    b = np.vstack([0.5 * dt * dt / mass_kg * eye, dt / mass_kg * eye])
    return a, b


def hover_error_model(params: InertialParams, dt: float,
                      inertia_tensor_kgm2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of the free-flyer linearised about hover, error state ``[r, v, φ, ω]`` (12).

    With a full inertia tensor ``J`` (products of inertia) the attitude block is ``φ̈ = J⁻¹ τ``: [Doerr2021]
    Eq. 35b, ``ω̇ = J⁻¹ (τ − ω × J ω)``, linearised at ω = 0 (the gyroscopic term is second order in ω).

    Parameters
    ----------
    params : InertialParams
        Mass and principal inertias of the model.
    dt : float
        Step [s].
    inertia_tensor_kgm2 : ndarray, shape (3, 3), optional
        ``J`` [kg·m²] (symmetric positive definite) in place of ``diag(params.inertia_kgm2)``; None: the diagonal
        (the same arrays as without the argument).

    Returns
    -------
    A : ndarray, shape (12, 12)
    B : ndarray, shape (12, 6)
        Input ``[f (world) N, τ (body) N·m]``.
    """
    a = np.zeros((12, 12))
    b = np.zeros((12, 6))
    a_t, b_t = _translation(params.mass_kg, dt)
    a[:6, :6] = a_t
    b[:6, :3] = b_t
    eye = np.eye(3)
    if inertia_tensor_kgm2 is None:
        inv_i = np.diag(1.0 / params.inertia_kgm2)
    else:
        inv_i = np.linalg.inv(np.asarray(inertia_tensor_kgm2, dtype=float).reshape(3, 3))
    a[6:, 6:] = np.block([[eye, dt * eye], [np.zeros((3, 3)), eye]])
    b[6:9, 3:] = 0.5 * dt * dt * inv_i
    b[9:12, 3:] = dt * inv_i
    return a, b
