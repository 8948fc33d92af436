"""What Astrobee's body-fixed actuators deliver: per-body-axis force and torque scale, and the centre-of-mass torque.

Astrobee's impellers and nozzles are fixed to the body, so a thrust scale error (impeller speed, nozzle wear:
[ReSWARM2023] §5.3; calibrated per body axis in flight, §6.2.1 Eqs. 38-39) scales the force *in the body frame*. The
force acts at the geometric centre, at ``−r`` from the centre of mass (``r`` = centre-of-mass offset, body frame),
so it also torques the body about its centre of mass ([ReSWARM2023] §3, the Newton-Euler equations about a point
that is not the centre of mass):

    F_b = κ_F ⊙ (Rᵀ F_cmd),   F_world = R F_b,   τ = κ_τ ⊙ τ_cmd + (−r) × F_b

with ``R`` the body-to-world rotation of the attitude ([Doerr2021] Eq. 33-34 for the frames). The state's position
is the centre of mass's, so the translation is ``v̇ = F_world / m`` ([Doerr2021] Eq. 34) and the rotation
``ω̇ = J⁻¹(τ − ω × Jω)`` (Eq. 35b) about the centre of mass. The estimators' model of the same wrench, with its
derivatives, is :mod:`oacli.estimation.rigid_dynamics`.
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat

__all__ = ["delivered_wrench", "delivered_wrench_floats"]


def delivered_wrench(u: np.ndarray, q: np.ndarray, force_scale: np.ndarray | None,
                     com_offset_m: np.ndarray | None) -> np.ndarray:
    """The wrench acting on the body for the commanded ``u`` at attitude ``q`` (numpy reference).

    ``u``'s torque is taken as already scaled by ``κ_τ`` (a constant over the control period); the force is scaled
    per body axis by ``force_scale`` and its torque about the centre of mass added (module docstring).

    Parameters
    ----------
    u : ndarray, shape (6,)
        Commanded force (world frame) [N] and torque (body frame, already scaled) [N·m].
    q : ndarray, shape (4,)
        Attitude [x, y, z, w] (normalised here, sign w >= 0 as the simulator's steps).
    force_scale : ndarray, shape (3,) or None
        κ_F per body axis (None: ones).
    com_offset_m : ndarray, shape (3,) or None
        Centre of mass relative to the geometric centre, body frame [m] (None: zero).

    Returns
    -------
    ndarray, shape (6,)
        Delivered force (world frame) [N] and torque about the centre of mass (body frame) [N·m].
    """
    out = np.array(u, dtype=float)
    if force_scale is None and com_offset_m is None:
        return out
    q = np.asarray(q, dtype=float)
    qn = q / np.linalg.norm(q)
    if qn[3] < 0.0:
        qn = -qn
    rot = quat.to_rotation_matrix(qn)
    force_body = rot.T @ out[0:3]
    if force_scale is not None:
        force_body = np.asarray(force_scale, dtype=float) * force_body
        out[0:3] = rot @ force_body
    if com_offset_m is not None:
        out[3:6] += np.cross(-np.asarray(com_offset_m, dtype=float), force_body)
    return out


def delivered_wrench_floats(f0: float, f1: float, f2: float, t0: float, t1: float, t2: float, qx: float, qy: float,
                            qz: float, qw: float, kf: tuple[float, float, float] | None,
                            r: tuple[float, float, float] | None) -> tuple[float, float, float, float, float, float]:
    """:func:`delivered_wrench` on Python floats (the simulator's plant steps): the same operations, written out.

    Parameters
    ----------
    f0, f1, f2, t0, t1, t2 : float
        Commanded force (world) [N] and scaled torque (body) [N·m].
    qx, qy, qz, qw : float
        Attitude.
    kf : tuple of 3 float or None
        κ_F per body axis.
    r : tuple of 3 float or None
        Centre-of-mass offset, body frame [m].

    Returns
    -------
    tuple of 6 float
        Delivered world force [N] and torque about the centre of mass [N·m].
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat.rotation_floats(qx, qy, qz, qw)
    b0 = r00 * f0 + r10 * f1 + r20 * f2
    b1 = r01 * f0 + r11 * f1 + r21 * f2
    b2 = r02 * f0 + r12 * f1 + r22 * f2
    if kf is not None:
        b0, b1, b2 = kf[0] * b0, kf[1] * b1, kf[2] * b2
        f0 = r00 * b0 + r01 * b1 + r02 * b2
        f1 = r10 * b0 + r11 * b1 + r12 * b2
        f2 = r20 * b0 + r21 * b1 + r22 * b2
    if r is not None:
        a0, a1, a2 = -r[0], -r[1], -r[2]
        t0, t1, t2 = t0 + (a1 * b2 - a2 * b1), t1 + (a2 * b0 - a0 * b2), t2 + (a0 * b1 - a1 * b0)
    return f0, f1, f2, t0, t1, t2
