"""An independent, dense re-check of a trajectory against the workspace (a second opinion on the exact checks).

It shares no algorithm with :mod:`oacli.geometry.collision`: the trajectory is sampled so that consecutive
positions are at most ``spacing_m`` apart (5 mm by default), every position is evaluated from the zero-order-hold
model ``r(τ) = r_k + v_k τ + ½ (f_k/m) τ²`` directly, and each sample is tested

* against each keep-out ellipsoid by its Euclidean distance, computed by Eberly's method (the closest point of an
  ellipsoid with semi-axes ``a`` to ``y`` is ``x_i = a_i² y_i / (t + a_i²)`` where ``t`` is the root of
  ``Σ (a_i y_i / (t + a_i²))² = 1``, found by bisection; inside, the same gives the penetration depth), which
  must be at least the robot's radius; and
* against the keep-in boxes (the centre must lie in one of them).

Sampling can still miss an excursion shorter than the spacing; it is a cross-check, not a proof.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry.shapes import Scene
from oacli.model.robot_model import RobotModel

_BISECTIONS = 200


def point_ellipsoid_distance(points: np.ndarray, center: np.ndarray, semi_axes_m: np.ndarray,
                             rotation: np.ndarray) -> np.ndarray:
    """Signed Euclidean distance [m] from points (..., 3) to an ellipsoid's surface: > 0 outside, < 0 inside.

    Eberly's method ("Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid", 2013): in the
    principal frame, with the point folded into the first octant ``y >= 0``, the closest surface point is
    ``x_i = a_i² y_i / (t + a_i²)`` where ``t`` is the unique root in ``(−a_min², ∞)`` of
    ``F(t) = Σ (a_i y_i / (t + a_i²))² − 1`` (``t > 0`` outside, ``t < 0`` inside). The root is bisected in
    ``s = t + a_min² > 0``, so the denominators ``s + (a_i² − a_min²)`` carry no cancellation near the pole.
    A coordinate that is zero along the shortest axis (the degenerate case, e.g. the centre) is raised to
    ``1e-12 · a_max``: the distance is 1-Lipschitz in the point, so the result moves by at most ``√3 · 1e-12 a_max``.

    Parameters
    ----------
    points : ndarray, shape (..., 3)
    center : ndarray, shape (3,)
    semi_axes_m : ndarray, shape (3,)
    rotation : ndarray, shape (3, 3)
        Columns are the principal axes in the world frame.

    Returns
    -------
    ndarray, shape (...,)
        The distance to the surface for points outside, minus the distance to the surface (the penetration
        depth) for points inside.
    """
    a = np.asarray(semi_axes_m, dtype=float)
    y = np.abs(np.einsum("ji,...j->...i", rotation, np.asarray(points, dtype=float) - center))
    inside = np.sum((y / a) ** 2, axis=-1) < 1.0
    y = np.maximum(y, 1e-12 * np.max(a))
    a2 = a * a
    a2_min = float(np.min(a2))
    offset = a2 - a2_min  # t + a_i² = s + offset_i
    lo = np.zeros(y.shape[:-1])
    hi = a2_min + np.max(a) * np.linalg.norm(y, axis=-1)  # F <= 0 there: t + a_i² >= a_max |y| >= a_i |y|
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        f = np.sum((a * y / (mid[..., None] + offset)) ** 2, axis=-1) - 1.0
        lo = np.where(f > 0.0, mid, lo)
        hi = np.where(f > 0.0, hi, mid)
    s = 0.5 * (lo + hi)
    closest = a2 * y / (s[..., None] + offset)
    dist = np.linalg.norm(y - closest, axis=-1)
    return np.where(inside, -dist, dist)


@dataclass(frozen=True)
class DenseCheck:
    """Result of :func:`dense_check`.

    Attributes
    ----------
    ok : bool
        True when every sample is inside the keep-in union and at least ``robot_radius_m`` from every keep-out.
    samples : int
        Number of positions checked.
    max_spacing_m : float
        Largest distance between consecutive samples [m].
    min_clearance_m : float
        Smallest (distance to a keep-out surface − robot radius) [m] (inf without keep-outs).
    first_violation_s : float
        Time of the first violating sample [s] (NaN when ok).
    keep_in_violations, keep_out_violations : int
        Violating samples by kind.
    """

    ok: bool
    samples: int
    max_spacing_m: float
    min_clearance_m: float
    first_violation_s: float
    keep_in_violations: int
    keep_out_violations: int


def dense_positions(t: np.ndarray, x: np.ndarray, acceleration: np.ndarray,
                    spacing_m: float = 0.005, substeps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Times and positions of a zero-order-hold trajectory sampled at most ``spacing_m`` apart.

    Between samples the force is held, so the position is the exact parabola ``p_k + v_k τ + ½ a_k τ²`` with
    ``a_k = f_k/m`` ([Doerr2021] Eq. 34 with a world-frame force; the caller divides by its model's mass, as
    :func:`dense_check` does); each step is cut into equal parts, ending at the step's end.

    Parameters
    ----------
    t : ndarray, shape (n+1,)
    x : ndarray, shape (n+1, >= 6)
        States; ``x[:, 0:3]`` position [m], ``x[:, 3:6]`` velocity [m/s].
    acceleration : ndarray, shape (n, 3)
        Held world-frame acceleration ``f/m`` [m/s²].
    spacing_m : float
        Largest distance between consecutive points [m] (bounded per step by the step's top speed).
    substeps : int, optional
        A fixed number of points per step instead of the spacing.

    Returns
    -------
    times : ndarray, shape (k,)
        Sample times [s], starting at ``t[0]``.
    positions : ndarray, shape (k, 3)
        Positions [m] at those times.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    acceleration = np.asarray(acceleration, dtype=float)
    times = [t[:1]]
    pos = [x[:1, 0:3]]
    for k in range(t.shape[0] - 1):
        h = t[k + 1] - t[k]
        v, acc = x[k, 3:6], acceleration[k]
        top_speed = np.linalg.norm(v) + np.linalg.norm(acc) * h  # bounds the speed over the whole interval
        m = substeps if substeps is not None else max(1, int(np.ceil(top_speed * h / spacing_m)))
        tau = h * np.arange(1, m + 1) / m
        times.append(t[k] + tau)
        pos.append(x[k, 0:3] + np.outer(tau, v) + 0.5 * np.outer(tau * tau, acc))
    return np.concatenate(times), np.vstack(pos)


def dense_check(
    t: np.ndarray, x: np.ndarray, force: np.ndarray, model: RobotModel, scene: Scene, robot_radius_m: float,
    spacing_m: float = 0.005,
) -> DenseCheck:
    """Re-check a zero-order-hold trajectory every ``spacing_m`` against ``scene`` (module docstring).

    Parameters
    ----------
    t, x, spacing_m
        The trajectory and sampling, as in :func:`dense_positions`.
    force : ndarray, shape (n, 3)
        Held world-frame force [N].
    model : RobotModel
        The robot the trajectory is planned for (the held acceleration is ``force / model.mass_kg``).
    scene : Scene
        Keep-in boxes and keep-out ellipsoids.
    robot_radius_m : float
        The robot's radius [m] (its centre must stay this far from every keep-out zone).

    Returns
    -------
    DenseCheck
    """
    times, pts = dense_positions(t, x, np.asarray(force, dtype=float) / model.mass_kg, spacing_m)
    spacing = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).max()) if len(pts) > 1 else 0.0
    bad_in = ~scene.in_keep_in(pts)
    clearance = np.full(len(pts), np.inf)
    for e in scene.keep_out:
        semi, rot = e.principal_axes()
        clearance = np.minimum(clearance, point_ellipsoid_distance(pts, e.center, semi, rot) - robot_radius_m)
    bad_out = clearance < -1e-9
    bad = bad_in | bad_out
    first = float(times[np.argmax(bad)]) if np.any(bad) else float("nan")
    return DenseCheck(
        ok=not bool(np.any(bad)),
        samples=len(pts),
        max_spacing_m=spacing,
        min_clearance_m=float(clearance.min()) if len(pts) else float("inf"),
        first_violation_s=first,
        keep_in_violations=int(bad_in.sum()),
        keep_out_violations=int(bad_out.sum()),
    )
