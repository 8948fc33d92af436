"""The full rigid body in the controllers: the centre-of-mass moment's feed-forward and the inertia tensor.

Astrobee's thrust acts at the geometric centre, ``−c`` from the centre of mass (``c`` = centre-of-mass offset, body
frame), so a body force ``F_b`` also torques the body about its centre of mass by ``(−c) × F_b`` ([ReSWARM2023] §3:
the Newton-Euler equations about a point that is not the centre of mass; the simulator's plant,
:func:`oacli.sim.actuators.delivered_wrench`). The controllers plan the torque ``τ_des`` about the centre of mass and
the force ``F`` in the world frame ([Doerr2021] Eq. 34: ``u = [f (world), τ (body)]``); with a learned ``ĉ`` they
command

    τ_cmd = τ_des + ĉ × F_b,   F_b = R(q̃)ᵀ F                                         (feed-forward)

(``R(q̃)`` the measured attitude's body-to-world rotation), so the plant delivers
``τ_cmd + (−c) × F_b = τ_des + (ĉ − c) × F_b``: the moment cancels up to the estimate's error ``δc = ĉ − c``, whose
worst case enters W's attitude part (:func:`oacli.control.disturbance.attitude_disturbance`).

The compensation must fit in the actuator: ``|(ĉ × F_b)_i| = |(e_i × ĉ) · F_b| ≤ ‖e_i × ĉ‖ ‖F_b‖`` with ``‖F_b‖ =
‖F‖ ≤ ‖F_max‖`` for any attitude (``F`` in the world box ``|F_j| ≤ F_max,j``), i.e.
``sqrt(ĉ_j² + ĉ_k²) ‖F_max‖`` on body axis ``i`` (:func:`com_moment_bound_Nm`; the bound is reached at the box's
corner for a suitable attitude). The torque the MPC may plan is the limit less that bound
(:func:`planned_torque_limit_Nm`), so ``τ_cmd`` stays within the actuator limit; where the bound exceeds
:data:`MAX_COMPENSATION_SHARE` of an axis's limit, the tightening stops there (the MPC keeps half its authority) and
the commanded torque is clipped to the limit on the rare steps that would exceed it (counted,
:attr:`RigidCompensator.clipped_steps`).

The inertia tensor ``J`` (products of inertia) replaces ``diag(I)`` in the attitude model linearised about rest,
``ω̇ = J⁻¹ τ`` (:func:`oacli.model.double_integrator.hover_error_model`), and in the feed-forward
``τ = J ω̇_ref + ω × J ω`` ([Doerr2021] Eq. 35b; :func:`oacli.control.reference_sampler.feedforward`).

A model with neither (``c = 0`` and no products: the 4-parameter θ) gives no :class:`RigidCompensator` and the
controllers are exactly those of θ = [m, Ixx, Iyy, Izz].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model import quaternion as quat
from oacli.model.robot_model import RobotModel

MAX_COMPENSATION_SHARE = 0.5
"""Largest share of each axis's torque limit the compensation's worst case may take from the MPC."""


def com_moment_bound_Nm(offset_m: np.ndarray, force_limit_N: np.ndarray) -> np.ndarray:
    """Worst case per body axis of ``|(c × F_b)_i|`` over every attitude and world force ``|F_j| ≤ F_max,j``.

    ``(c × F_b)_i = (e_i × c) · F_b`` and ``‖F_b‖ = ‖F‖ ≤ ‖F_max‖``: ``sqrt(c_j² + c_k²) ‖F_max‖`` (j, k the other
    axes); with ``c`` anywhere in the box ``|c_j| ≤ offset_m[j]`` the same expression of the box's half-widths
    (its corner). Reached: for ``F_b`` along ``e_i × c`` with the norm of the box's corner.

    Parameters
    ----------
    offset_m : ndarray, shape (3,)
        ``|c|`` per body axis, or the half-widths of a box of offsets [m].
    force_limit_N : ndarray, shape (3,)
        The world force box's half-widths [N].

    Returns
    -------
    ndarray, shape (3,)
        The bound per body axis [N·m].
    """
    c2 = np.asarray(offset_m, dtype=float) ** 2
    others = np.array([c2[1] + c2[2], c2[0] + c2[2], c2[0] + c2[1]])
    return np.asarray(np.sqrt(others)) * float(np.linalg.norm(np.asarray(force_limit_N, dtype=float)))


def planned_torque_limit_Nm(torque_limit_Nm: np.ndarray, compensation_Nm: np.ndarray) -> np.ndarray:
    """The torque the MPC may plan: the limit less the compensation's worst case, at most
    :data:`MAX_COMPENSATION_SHARE` of it (module docstring).

    Parameters
    ----------
    torque_limit_Nm : ndarray, shape (3,)
        The actuator's torque limit per body axis [N·m].
    compensation_Nm : ndarray, shape (3,)
        :func:`com_moment_bound_Nm` of the compensated offset.

    Returns
    -------
    ndarray, shape (3,)
    """
    limit = np.asarray(torque_limit_Nm, dtype=float)
    return np.asarray(limit - np.minimum(np.asarray(compensation_Nm, dtype=float), MAX_COMPENSATION_SHARE * limit))


@dataclass
class RigidCompensator:
    """The learned centre of mass and inertia tensor as the controllers use them (module docstring).

    Attributes
    ----------
    inertia_tensor_kgm2 : ndarray, shape (3, 3)
        ``J`` [kg·m²] of the attitude model and the feed-forward.
    com_offset_m : ndarray, shape (3,)
        ``ĉ``, body frame [m].
    torque_limit_Nm : ndarray, shape (3,)
        The actuator's torque limit [N·m] ``τ_cmd`` is clipped to.
    planned_torque_limit_Nm : ndarray, shape (3,)
        The torque the MPC may plan (:func:`planned_torque_limit_Nm`).
    clipped_steps : int
        Steps on which ``τ_cmd`` had to be clipped to the limit (0 while the tightening covers the compensation).
    """

    inertia_tensor_kgm2: np.ndarray
    com_offset_m: np.ndarray
    torque_limit_Nm: np.ndarray
    planned_torque_limit_Nm: np.ndarray
    clipped_steps: int = 0

    @classmethod
    def of_model(cls, model: RobotModel, force_limit_N: np.ndarray,
                 torque_limit_Nm: np.ndarray | None = None) -> RigidCompensator | None:
        """The compensator of ``model``'s centre of mass and tensor; None when it has neither (θ of 4).

        Parameters
        ----------
        model : RobotModel
            The controller's model.
        force_limit_N : ndarray, shape (3,)
            The largest world force the controller commands per axis [N] (the compensation's worst case).
        torque_limit_Nm : ndarray, shape (3,), optional
            The torque limit (default the model's).

        Returns
        -------
        RigidCompensator or None
        """
        if not (np.any(model.com_offset_m != 0) or np.any(model.inertia_products_kgm2 != 0)):
            return None
        limit = model.torque_limit_Nm if torque_limit_Nm is None else np.asarray(torque_limit_Nm, dtype=float)
        bound = com_moment_bound_Nm(np.abs(model.com_offset_m), force_limit_N)
        return cls(model.inertia_tensor_kgm2, np.array(model.com_offset_m, dtype=float), np.array(limit),
                   planned_torque_limit_Nm(limit, bound))

    def command(self, u: np.ndarray, q: np.ndarray) -> np.ndarray:
        """``u`` with ``τ_cmd = τ_des + ĉ × R(q)ᵀ F``, clipped to the torque limit (a new array).

        Parameters
        ----------
        u : ndarray, shape (6,)
            ``[F (world) N, τ_des (body) N·m]``.
        q : ndarray, shape (4,)
            The measured attitude [x, y, z, w].

        Returns
        -------
        ndarray, shape (6,)
        """
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat.rotation_floats(*(float(v) for v in q))
        f0, f1, f2 = float(u[0]), float(u[1]), float(u[2])
        b0 = r00 * f0 + r10 * f1 + r20 * f2  # F_b = Rᵀ F
        b1 = r01 * f0 + r11 * f1 + r21 * f2
        b2 = r02 * f0 + r12 * f1 + r22 * f2
        c0, c1, c2 = (float(v) for v in self.com_offset_m)
        tau = u[3:6] + np.array([c1 * b2 - c2 * b1, c2 * b0 - c0 * b2, c0 * b1 - c1 * b0])
        clipped = np.clip(tau, -self.torque_limit_Nm, self.torque_limit_Nm)
        if np.any(clipped != tau):
            self.clipped_steps += 1
        out = np.array(u, dtype=float)
        out[3:6] = clipped
        return out


__all__ = ["MAX_COMPENSATION_SHARE", "RigidCompensator", "com_moment_bound_Nm", "planned_torque_limit_Nm"]
