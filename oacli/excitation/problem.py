"""The excitation problem shared by the offline design and the online planner: limits, workspace linearisation,
rest-to-rest initial guesses and dense collision checks.

Workspace constraints are convexified per *segment* (the motion between two samples). Under a zero-order-hold
force the position between samples is the parabola ``p(τ) = p_k + v_k τ + ½ (f_k/m) τ²``, which stays within
``δ = ‖a‖ dt²/8`` of the chord ``p_k → p_{k+1}`` (``a = f/m``). Hence:

* keep-in box: both ends of the chord inside the box shrunk by ``δ`` (per axis) keeps the whole parabola inside;
* keep-out ellipsoid ``(p − c)ᵀP(p − c) ≥ 1`` ([Doerr2021] Eq. 12): the half-space ``n̂ᵀp ≥ β̂`` bounded by the
  supporting plane of the ellipsoid at the point of its surface along ``p̄ − c`` in the ellipsoid's metric
  (``n̂ ∝ P(p̄ − c)``, the gradient direction at ``p̄``; :func:`oacli.geometry.halfspaces.point_halfspaces`), with
  ``p̄`` the chord midpoint of the current iterate, lies in free space. Both chord ends ``≥ β̂ + δ`` put the chord
  in that half-space and the parabola within ``δ`` of it, so the *continuous* motion is collision-free, not only
  its samples.

The same functions measure the violation of a trajectory (for the SCP merit), with the linearisation taken at
that trajectory, so the convexified constraints at zero step reproduce it exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.errors import InfeasibleError
from oacli.geometry import Scene
from oacli.geometry.halfspaces import (
    KeepOutZone,
    best_box,
    keep_out_zone,
    metric_directions,
    supporting_halfspaces,
)
from oacli.geometry.verify import dense_positions
from oacli.model import quaternion as quat
from oacli.model.limits import MotionLimits

LENGTH_UNIT_M = 0.01
"""Slack unit of the geometric constraints [m] (1 cm of intrusion = one unit of violation)."""


@dataclass(frozen=True)
class TerminalTolerance:
    """How close to the goal, at rest, the trajectory must end (per axis)."""

    position_m: float = 0.01
    velocity_mps: float = 1e-3
    attitude_rad: float = 0.01
    angular_velocity_radps: float = 1e-3


def chord_margin_m(force_limit_n: np.ndarray, theta: np.ndarray, dt_s: float) -> np.ndarray:
    """Per-axis bound ``|a_i| dt²/8`` [m] on the distance between the parabola and its chord over one step.

    Parameters
    ----------
    force_limit_n : ndarray, shape (3,)
        Force limits [N].
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model the design is made for (``a_i = F_i / m``).
    dt_s : float
        Step [s].

    Returns
    -------
    ndarray, shape (3,)
    """
    return np.asarray(force_limit_n, dtype=float) / theta[0] * dt_s**2 / 8.0


def box_assignment(scene: Scene, p_start: np.ndarray, p_end: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """Index of the keep-in box best containing each segment ``p_start[k] → p_end[k]`` (largest worst margin).

    Parameters
    ----------
    scene : Scene
        Has at least one keep-in box (ValueError otherwise).
    p_start, p_end : ndarray, shape (N, 3)
        Segment ends [m].
    margin : ndarray, shape (3,)
        Inward margin of the boxes [m].

    Returns
    -------
    ndarray of int, shape (N,)
        All zeros when the scene has a single box.
    """
    return best_box(scene, p_start, p_end, margin=margin)


def keep_in_violation(
    scene: Scene,
    positions: np.ndarray,
    margin: np.ndarray,
    boxes: np.ndarray | None = None,
    end_extra_m: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Violation [m] of the keep-in constraint per segment, and the box used for each segment.

    ``positions (N+1, 3)``: segment k runs from sample k to k+1. With ``boxes`` omitted the best box per segment is
    used (:func:`box_assignment`), which makes the violation a function of the positions alone. ``end_extra_m``
    shrinks the box further for the very last sample (room to stop, used by the receding-horizon planner).

    Parameters
    ----------
    scene : Scene
    positions : ndarray, shape (N+1, 3)
        Sample positions [m].
    margin : ndarray, shape (3,)
        Inward margin of the boxes [m].
    boxes : ndarray of int, shape (N,), optional
        Box per segment.
    end_extra_m : float or ndarray, optional
        Extra margin [m] for the last sample.

    Returns
    -------
    violation : ndarray, shape (N,)
        [m], 0 where the segment is inside.
    boxes : ndarray of int, shape (N,)
    """
    if not scene.keep_in:
        n = positions.shape[0] - 1
        return np.zeros(n), np.zeros(n, dtype=int)
    p0, p1 = positions[:-1], positions[1:]
    if boxes is None:
        boxes = box_assignment(scene, p0, p1, margin)
    lo = np.array([scene.keep_in[i].lower for i in boxes]) + margin
    hi = np.array([scene.keep_in[i].upper for i in boxes]) - margin
    lo1, hi1 = lo.copy(), hi.copy()
    lo1[-1] += end_extra_m
    hi1[-1] -= end_extra_m
    excess = np.maximum.reduce([lo - p0, p0 - hi, lo1 - p1, p1 - hi1])
    return np.maximum(excess.max(axis=1), 0.0), boxes


def keep_in_sample_bounds(scene: Scene, positions: np.ndarray, margin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample keep-in bounds: the intersection of the (shrunk) boxes of the sample's two segments.

    Segment k runs from sample k to k+1 and must lie in its box (:func:`box_assignment`, shrunk by ``margin``);
    by convexity of a box that holds exactly when both its ends do, so the whole path is inside when every sample
    lies in the boxes of the segments it ends and starts, the intersection of two boxes (one box per axis
    interval). The offline design states the keep-in constraint this way: one pair of bounds per sample and axis
    instead of two per segment end (half the rows of its subproblem), the same set of paths.

    Parameters
    ----------
    scene : Scene
        Has at least one keep-in box.
    positions : ndarray, shape (N+1, 3)
        Sample positions [m] (the box of each segment is chosen at them).
    margin : ndarray, shape (3,)
        Inward margin of the boxes [m].

    Returns
    -------
    lower, upper : ndarray, shape (N+1, 3)
        [m]; ``lower > upper`` on an axis where the two boxes do not overlap.
    """
    boxes = box_assignment(scene, positions[:-1], positions[1:], margin)
    lo_seg = np.array([scene.keep_in[i].lower for i in boxes]) + margin
    hi_seg = np.array([scene.keep_in[i].upper for i in boxes]) - margin
    lower = np.vstack([lo_seg, lo_seg[-1:]])
    upper = np.vstack([hi_seg, hi_seg[-1:]])
    lower[1:] = np.maximum(lower[1:], lo_seg)
    upper[1:] = np.minimum(upper[1:], hi_seg)
    return lower, upper


def keep_in_sample_violation(scene: Scene, positions: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """Violation [m] of the keep-in constraint per sample against :func:`keep_in_sample_bounds` (largest axis).

    Zero for every sample exactly when :func:`keep_in_violation` is zero for every segment.

    Parameters
    ----------
    scene : Scene
    positions : ndarray, shape (N+1, 3)
        Sample positions [m].
    margin : ndarray, shape (3,)
        Inward margin of the boxes [m].

    Returns
    -------
    ndarray, shape (N+1,)
        [m], 0 where the sample is inside (all zeros without keep-in boxes).
    """
    if not scene.keep_in:
        return np.zeros(positions.shape[0])
    lower, upper = keep_in_sample_bounds(scene, positions, margin)
    return np.maximum(np.max(np.maximum(lower - positions, positions - upper), axis=1), 0.0)


def segment_halfspaces(zone: KeepOutZone, p0: np.ndarray, p1: np.ndarray,
                       lateral_inside: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Half-spaces ``n̂ᵀp ≥ β̂`` of a keep-out zone for the segments ``p0[k] → p1[k]``, taken at their midpoints.

    With ``lateral_inside``, a segment whose midpoint lies inside the zone is pushed out sideways: its metric
    direction loses its component along the segment (in the zone's normalised coordinates), and a segment through
    the centre takes the normalised axis most perpendicular to it. Along the path, the plain rule gives the samples
    of a straight run through the zone opposite normals on either side of the centre (forward and backward), a
    linearisation that no step satisfies and that has no lateral sensitivity to escape by (an SCP from an exactly
    symmetric start stalls there); the lateral rule gives them one consistent way around. Outside the zone both
    rules agree.

    Parameters
    ----------
    zone : KeepOutZone
    p0, p1 : ndarray, shape (K, 3)
        Segment ends [m].
    lateral_inside : bool, optional
        Apply the lateral rule to midpoints inside the zone.

    Returns
    -------
    normal : ndarray, shape (K, 3)
        Unit normals.
    offset : ndarray, shape (K,)
        β̂ [m].
    """
    mid = 0.5 * (p0 + p1)
    w = metric_directions(zone, mid)
    if lateral_inside:
        w_raw = (mid - zone.center) @ zone.metric.T  # the centre itself included (metric_directions: +x there)
        inside = np.sum(w_raw * w_raw, axis=1) < 1.0
        if inside.any():
            d = (p1[inside] - p0[inside]) @ zone.metric.T
            d_norm = np.linalg.norm(d, axis=1, keepdims=True)
            d_hat = np.divide(d, d_norm, out=np.zeros_like(d), where=d_norm > 0)
            wi = w_raw[inside]
            lateral = wi - np.sum(wi * d_hat, axis=1, keepdims=True) * d_hat
            flat = np.sum(lateral * lateral, axis=1) <= 1e-18 * np.maximum(np.sum(wi * wi, axis=1), 1e-30)
            if flat.any():  # through the centre: the normalised axis most perpendicular to the segment
                eye = np.eye(3)
                axis = eye[np.argmin(np.abs(d_hat[flat]), axis=1)]
                lateral[flat] = axis - np.sum(axis * d_hat[flat], axis=1, keepdims=True) * d_hat[flat]
            keep = np.sum(lateral * lateral, axis=1) > 0  # a zero-length segment keeps its plain direction
            w_in = w[inside]
            w_in[keep] = lateral[keep]
            w[inside] = w_in
    return supporting_halfspaces(zone, w)


def keep_out_violation(scene: Scene, positions: np.ndarray, margin_m: float, end_extra_m: float = 0.0,
                       lateral_inside: bool = False) -> np.ndarray:
    """Violation [m] per keep-out zone and segment: ``max(0, β̂ + δ − n̂ᵀp)`` over both chord ends.

    The half-space is taken at the chord midpoint (see the module docstring; ``lateral_inside``: see
    :func:`segment_halfspaces`); the very last sample needs ``end_extra_m`` more.

    Parameters
    ----------
    scene : Scene
    positions : ndarray, shape (N+1, 3)
        Sample positions [m].
    margin_m : float
        Clearance δ [m].
    end_extra_m : float, optional
    lateral_inside : bool, optional

    Returns
    -------
    ndarray, shape (E, N)
    """
    p0, p1 = positions[:-1], positions[1:]
    out = np.zeros((len(scene.keep_out), p0.shape[0]))
    extra = np.zeros(p0.shape[0])
    extra[-1] = end_extra_m
    for e, ell in enumerate(scene.keep_out):
        n_hat, beta = segment_halfspaces(keep_out_zone(ell), p0, p1, lateral_inside)
        gap0 = np.einsum("ki,ki->k", n_hat, p0) - beta - margin_m
        gap1 = np.einsum("ki,ki->k", n_hat, p1) - beta - margin_m - extra
        out[e] = np.maximum(-np.minimum(gap0, gap1), 0.0)
    return out


def collision_free(scene: Scene, x: np.ndarray, u: np.ndarray, dt_s: float, theta: np.ndarray,
                   substeps: int = 20) -> bool:
    """True when the continuous motion stays in a keep-in box and out of every keep-out zone (dense re-check).

    Parameters
    ----------
    scene : Scene
    x : ndarray, shape (N+1, 13)
        States.
    u : ndarray, shape (N, 6) or (N+1, 6)
        Inputs (a last row is unused).
    dt_s : float
        Step [s].
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model (the held acceleration is ``f / m``).
    substeps : int, optional
        Points per step (:func:`oacli.geometry.verify.dense_positions`).

    Returns
    -------
    bool
    """
    n = x.shape[0] - 1
    _, pts = dense_positions(dt_s * np.arange(n + 1), x, np.asarray(u[:n, 0:3], dtype=float) / theta[0],
                             substeps=substeps)
    return bool(np.all(scene.in_keep_in(pts)) and not np.any(scene.in_keep_out(pts)))


def left_multiplication_matrix(p: np.ndarray) -> np.ndarray:
    """``L(p)`` (4, 4) with ``p ⊗ q = L(p) q`` (Hamilton product, scalar last).

    Parameters
    ----------
    p : ndarray, shape (4,)
        Quaternion ``[x, y, z, w]``.

    Returns
    -------
    ndarray, shape (4, 4)
    """
    x, y, z, w = np.asarray(p, dtype=float)
    return np.array([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])


def attitude_errors(q_goal: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Small-angle attitude errors ``e = 2 vec(q_goal⁻¹ ⊗ q)`` (sign fixed so the scalar part is ≥ 0).

    Parameters
    ----------
    q_goal : ndarray, shape (4,)
    q : ndarray, shape (K, 4)

    Returns
    -------
    e : ndarray, shape (K, 3)
    jac : ndarray, shape (K, 3, 4)
        ``∂e/∂q``.
    """
    left = left_multiplication_matrix(quat.conjugate(q_goal))
    rel = np.asarray(q, dtype=float) @ left.T
    sign = np.where(rel[:, 3] >= 0, 1.0, -1.0)
    return 2.0 * sign[:, None] * rel[:, 0:3], 2.0 * sign[:, None, None] * left[None, 0:3, :]


def attitude_error(q_goal: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`attitude_errors` of one quaternion: ``e`` (3,) and ``∂e/∂q`` (3, 4).

    Parameters
    ----------
    q_goal, q : ndarray, shape (4,)

    Returns
    -------
    e : ndarray, shape (3,)
    jac : ndarray, shape (3, 4)
    """
    e, jac = attitude_errors(q_goal, np.asarray(q, dtype=float)[None, :])
    return e[0], jac[0]


def rest_to_rest_profile(n: int, shape: np.ndarray, displacement_coeff: float) -> np.ndarray:
    """Project ``shape (n,)`` so that ``Σ w = 0`` (rest to rest) and ``Σ w_k (n − k − ½) = displacement_coeff``.

    Parameters
    ----------
    n : int
        Number of steps.
    shape : ndarray, shape (n,)
        Profile to project.
    displacement_coeff : float
        Required ``Σ w_k (n − k − ½)``.

    Returns
    -------
    ndarray, shape (n,)
    """
    c = np.vstack([np.ones(n), n - np.arange(n) - 0.5])
    rhs = np.array([0.0, displacement_coeff])
    return shape - c.T @ np.linalg.solve(c @ c.T, c @ shape - rhs)


def minimum_time_s(distance: float, accel: float, speed: float) -> float:
    """Shortest rest-to-rest time [s] over ``distance`` with bounded acceleration and speed (bang-coast-bang).

    Parameters
    ----------
    distance : float
        [m] or [rad].
    accel : float
        Acceleration bound, > 0.
    speed : float
        Speed bound, > 0.

    Returns
    -------
    float
    """
    if distance <= 0:
        return 0.0
    if speed * speed / accel >= distance:
        return 2.0 * np.sqrt(distance / accel)
    return distance / speed + speed / accel


def check_reachable(
    start: np.ndarray, goal: np.ndarray, duration_s: float, theta: np.ndarray, limits: MotionLimits
) -> None:
    """Raise :class:`InfeasibleError` when the goal cannot be reached at rest within the duration.

    A necessary condition per axis: the bang-coast-bang minimum time of the translation along each world axis
    (force and velocity limits) and of the rotation angle about each body axis (torque and rate limits,
    gyroscopic coupling ignored) must not exceed the duration.

    Parameters
    ----------
    start, goal : ndarray, shape (13,)
    duration_s : float
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    limits : MotionLimits
    """
    d = np.abs(goal[0:3] - start[0:3])
    rot = np.abs(quat.error_vector(start[6:10], goal[6:10]))
    problems = []
    for i, axis in enumerate("xyz"):
        t_lin = minimum_time_s(d[i], limits.force_N[i] / theta[0], limits.velocity_mps[i])
        if t_lin > duration_s:
            problems.append(
                f"moving {d[i]:.3g} m along {axis} needs at least {t_lin:.3g} s with |f_{axis}| <= "
                f"{limits.force_N[i]:.3g} N and |v_{axis}| <= {limits.velocity_mps[i]:.3g} m/s (mass {theta[0]:.4g} "
                f"kg), more than the {duration_s:.3g} s allowed"
            )
        t_rot = minimum_time_s(rot[i], limits.torque_Nm[i] / theta[1 + i], limits.angular_velocity_radps[i])
        if t_rot > duration_s:
            problems.append(
                f"rotating {rot[i]:.3g} rad about body {axis} needs at least {t_rot:.3g} s with |tau_{axis}| <= "
                f"{limits.torque_Nm[i]:.3g} N·m and |w_{axis}| <= {limits.angular_velocity_radps[i]:.3g} rad/s, "
                f"more than the {duration_s:.3g} s allowed"
            )
    if problems:
        raise InfeasibleError(problems)


def rest_to_rest_inputs(
    start: np.ndarray,
    goal: np.ndarray,
    steps: int,
    dt_s: float,
    theta: np.ndarray,
    excitation: np.ndarray | None = None,
) -> np.ndarray:
    """Inputs (N, 6) that move the model from ``start`` to ``goal`` at rest, optionally with excitation added.

    Translation: the force profile ``f_k ∝ sin(2π(k + ½)/N)`` projected so that the discrete double integrator
    (exact under a zero-order hold) ends at the goal at rest. Rotation: the same profile about the fixed body axis
    of the rotation ``start → goal``, as angular acceleration ``α``, with torque ``I α + ω × I ω`` (so that ω stays
    on that axis). ``excitation (2, 3)`` adds amplitudes [force N, torque N·m] per axis of zero-net harmonics
    (``cos(2π h (k + ½)/N)``, h = 2, 3, 4 per axis, projected to leave both the end position and the end angle
    unchanged to first order).

    Parameters
    ----------
    start, goal : ndarray, shape (13,)
        At rest.
    steps : int
        N.
    dt_s : float
        Step [s].
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    excitation : ndarray, shape (2, 3), optional
        Harmonic amplitudes (none by default).

    Returns
    -------
    ndarray, shape (N, 6)
    """
    n = steps
    m = theta[0]
    inertia = theta[1:4]
    phase = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    base = np.sin(phase)
    coeff = float(np.sum(base * (n - np.arange(n) - 0.5)))
    u = np.zeros((n, 6))
    disp = goal[0:3] - start[0:3]
    u[:, 0:3] = np.outer(base, disp) * m / (dt_s**2 * coeff)
    angle = quat.error_vector(start[6:10], goal[6:10])  # body-frame rotation vector
    alpha = np.outer(base, angle) / (dt_s**2 * coeff)
    if excitation is not None:
        amp = np.asarray(excitation, dtype=float).reshape(2, 3)
        for i in range(3):
            prof = rest_to_rest_profile(n, np.cos((2 + i) * phase), 0.0)
            prof = prof / max(np.abs(prof).max(), 1e-12)
            u[:, i] += amp[0, i] * prof
            alpha[:, i] += amp[1, i] * prof / inertia[i]
    # Torque that produces α about the body axes, compensating the gyroscopic term along the way.
    w = np.vstack([np.zeros(3), np.cumsum(alpha * dt_s, axis=0)[:-1]])
    w_mid = w + 0.5 * alpha * dt_s
    u[:, 3:6] = inertia * alpha + np.cross(w_mid, inertia * w_mid)
    return u


def _triangle(phase: np.ndarray) -> np.ndarray:
    """Unit triangle wave of period 1: 0 → 1 (¼) → 0 (½) → −1 (¾) → 0."""
    f = np.mod(phase, 1.0)
    return np.where(f < 0.25, 4 * f, np.where(f < 0.75, 2 - 4 * f, 4 * f - 4))


def translation_excitation(
    start: np.ndarray,
    transfer_force: np.ndarray,
    dt_s: float,
    theta: np.ndarray,
    limits: MotionLimits,
    scene: Scene,
    margin_m: np.ndarray,
    max_cycles: int = 12,
) -> np.ndarray:
    """Out-and-back force patterns (N, 3) that keep the speed high, added to a rest-to-rest transfer.

    The mass information of velocity measurements grows with ``Σ_k v_k²`` (``∂v/∂m = −v/m``), so a good start
    for the design spends as long as possible near the speed limit. Per world axis, the velocity
    ``v(t) = clip(A · tri(c t/T), −V, V)`` (``c`` whole cycles, ramps at 80 % of the acceleration left by the
    transfer, plateaus at 90 % of the speed left by it) returns to rest and to its start; of the cycle counts and
    signs whose motion stays in the keep-in box of the start (shrunk by ``margin_m``) and within the limits, the one
    with the largest ``Σ v²`` is kept (none when nothing fits).

    Parameters
    ----------
    start : ndarray, shape (13,)
    transfer_force : ndarray, shape (N, 3)
        Forces [N] of the rest-to-rest transfer.
    dt_s : float
        Step [s].
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model the design is made for (its mass relates force and velocity).
    limits : MotionLimits
    scene : Scene
    margin_m : ndarray, shape (3,)
        Inward margin of the keep-in box [m].
    max_cycles : int, optional
        Largest number of cycles tried per axis.

    Returns
    -------
    ndarray, shape (N, 3)
        Forces [N] to add to the transfer (zero on axes where nothing fits).
    """
    n = transfer_force.shape[0]
    mass_kg = theta[0]
    duration = n * dt_s
    v_tr = np.vstack([np.zeros(3), np.cumsum(transfer_force * dt_s / mass_kg, axis=0)])
    p_tr = start[0:3] + np.vstack([np.zeros(3), np.cumsum(0.5 * dt_s * (v_tr[:-1] + v_tr[1:]), axis=0)])
    if scene.keep_in:
        inside = [b for b in scene.keep_in if np.all(b.contains(start[0:3]))] or list(scene.keep_in)
        box = max(inside, key=lambda b: float(np.min(np.minimum(start[0:3] - b.lower, b.upper - start[0:3]))))
        lo, hi = box.lower + margin_m, box.upper - margin_m
    else:
        lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
    t = dt_s * np.arange(n + 1)
    out = np.zeros((n, 3))
    for i in range(3):
        accel = (0.8 * limits.force_N[i] - np.max(np.abs(transfer_force[:, i]))) / mass_kg
        speed = 0.9 * limits.velocity_mps[i] - np.max(np.abs(v_tr[:, i]))
        if accel <= 0 or speed <= 0:
            continue
        best, best_score = None, -np.inf
        for cycles in range(1, max_cycles + 1):
            period = duration / cycles
            v = np.clip(accel * period / 4.0 * _triangle(t / period), -speed, speed)
            f = mass_kg * np.diff(v) / dt_s
            f = rest_to_rest_profile(n, f, 0.0)
            for sign in (1.0, -1.0):
                fs = sign * f
                vs = v_tr[:, i] + np.concatenate([[0.0], np.cumsum(fs * dt_s / mass_kg)])
                ps = p_tr[:, i] + np.concatenate([[0.0], np.cumsum(0.5 * dt_s * (vs[:-1] + vs[1:]) - 0.5 * dt_s
                                                                   * (v_tr[:-1, i] + v_tr[1:, i]))])
                if (np.any(ps < lo[i]) or np.any(ps > hi[i]) or np.max(np.abs(vs)) > 0.95 * limits.velocity_mps[i]
                        or np.max(np.abs(fs + transfer_force[:, i])) > 0.95 * limits.force_N[i]):
                    continue
                score = float(np.sum(vs**2))
                if score > best_score:
                    best, best_score = fs, score
        if best is not None:
            out[:, i] = best
    return out
