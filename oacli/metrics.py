"""Tracking metrics of a closed-loop run (the numbers in ``summary.json``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from oacli.geometry import Scene
from oacli.geometry.depth import keep_in_depth, keep_out_depth
from oacli.model import quaternion as quat
from oacli.trajectory import sample_states
from oacli.types import Telemetry, Trajectory

# A limit counts as violated only beyond this relative margin (solver tolerances are ~1e-8).
_LIMIT_RTOL = 1e-6


@dataclass(frozen=True)
class TrackingErrors:
    """Errors of the true state against the reference, at the plant samples.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Time [s].
    position_m : ndarray, shape (M,)
        ‖r − r_ref‖ [m].
    attitude_rad : ndarray, shape (M,)
        Rotation angle between q and q_ref [rad].
    """

    t: np.ndarray
    position_m: np.ndarray
    attitude_rad: np.ndarray


def true_states_at(telemetry: Telemetry, times: np.ndarray) -> np.ndarray:
    """The true state at arbitrary ``times``, from the plant samples around each.

    A time on the plant grid takes that sample. Between two samples ``a < t < b`` the translation is the exact
    solution for a constant acceleration on ``[a, t]`` and another on ``[t, b]`` that reproduce both samples'
    positions and velocities: the simulator holds the world-frame force constant over a control period, so at a
    control instant (the only input switch between the two samples) the position and velocity are exact. The
    quaternion is slerped and the angular rate interpolated linearly (rotation has gyroscopic terms; over one
    plant period the difference is far below the errors plotted).

    Parameters
    ----------
    telemetry : Telemetry
        A simulated run (``t_true`` increasing).
    times : ndarray, shape (k,)
        Times [s], clipped to ``[t_true[0], t_true[-1]]``.

    Returns
    -------
    ndarray, shape (k, 13)
        States ``[r, v, q, omega]`` at ``times``.
    """
    t_true, x_true = telemetry.t_true, telemetry.x_true
    t = np.clip(np.asarray(times, dtype=float), t_true[0], t_true[-1])
    b = np.clip(np.searchsorted(t_true, t - 1e-9), 0, len(t_true) - 1)
    on_grid = np.abs(t_true[b] - t) <= 1e-9
    out = x_true[b].copy()
    k = np.flatnonzero(~on_grid)
    if k.size == 0:
        return out
    b = b[k]
    a = b - 1
    h1 = (t[k] - t_true[a])[:, None]
    h2 = (t_true[b] - t[k])[:, None]
    h = h1 + h2
    xa, xb = x_true[a], x_true[b]
    dv = xb[:, 3:6] - xa[:, 3:6]
    dr = xb[:, 0:3] - xa[:, 0:3] - xa[:, 3:6] * h
    # a1 h1 + a2 h2 = dv;  a1 (h1^2/2 + h1 h2) + a2 h2^2/2 = dr  (determinant -h1 h2 h / 2)
    det = -0.5 * h1 * h2 * h
    a1 = (dv * 0.5 * h2**2 - dr * h2) / det
    out[k, 0:3] = xa[:, 0:3] + xa[:, 3:6] * h1 + 0.5 * a1 * h1**2
    out[k, 3:6] = xa[:, 3:6] + a1 * h1
    s = (h1 / h)[:, 0]
    out[k, 6:10] = quat.slerp(xa[:, 6:10], xb[:, 6:10], s)  # row by row, vectorised
    out[k, 10:13] = xa[:, 10:13] + (xb[:, 10:13] - xa[:, 10:13]) * (h1 / h)
    return out


def tracking_errors(telemetry: Telemetry, reference: Trajectory, times: np.ndarray | None = None) -> TrackingErrors:
    """Position and attitude errors of the true state at ``times`` (the plant samples by default).

    Parameters
    ----------
    telemetry : Telemetry
        A simulated run.
    reference : Trajectory
    times : ndarray, shape (k,), optional
        Evaluation times [s]; the true state is taken at exactly these times (:func:`true_states_at`), so the
        true state and the reference are compared at equal times.

    Returns
    -------
    TrackingErrors
    """
    t = telemetry.t_true if times is None else np.asarray(times, dtype=float)
    x_true = telemetry.x_true if times is None else true_states_at(telemetry, t)
    x_ref = sample_states(reference, t)
    pos = np.linalg.norm(x_true[:, 0:3] - x_ref[:, 0:3], axis=1)
    att = quat.angle_between(x_ref[:, 6:10], x_true[:, 6:10])
    return TrackingErrors(t, pos, att)


#: Violation kinds of :func:`safety_report`, in report order, with the unit of their depth.
SAFETY_UNITS = {
    "keep_in": "m",
    "keep_out": "m",
    "velocity": "m/s",
    "angular_velocity": "rad/s",
    "input": "fraction of the limit",
}
#: A position counts as outside the free space only beyond this depth [m] (closed boxes, rounding).
_DEPTH_TOL_M = 1e-9


@dataclass(frozen=True)
class Violation:
    """Violations of one kind over a run.

    Attributes
    ----------
    count : int
        Violating samples (plant samples; control steps for ``input``).
    first_time_s : float or None
        Time of the first violating sample [s]; None when there is none.
    worst_depth : float
        Largest depth (0 when there is none), in ``unit``: distance outside the keep-in union or inside a
        keep-out zone [m], excess over a velocity limit [m/s, rad/s], excess over an input limit as a fraction
        of that limit.
    unit : str
    """

    count: int
    first_time_s: float | None
    worst_depth: float
    unit: str

    def as_dict(self) -> dict[str, Any]:
        """The entry of the ``safety`` block of ``summary.json``.

        Returns
        -------
        dict
            ``count``, ``first_time_s``, ``worst_depth`` and ``unit``.
        """
        return {"count": self.count, "first_time_s": self.first_time_s, "worst_depth": self.worst_depth,
                "unit": self.unit}


def _violation(kind: str, t: np.ndarray, depth: np.ndarray, bad: np.ndarray) -> Violation:
    """Summarise the samples flagged ``bad`` (their depth: NaN counts as infinitely deep)."""
    if not np.any(bad):
        return Violation(0, None, 0.0, SAFETY_UNITS[kind])
    worst = np.where(np.isnan(depth), np.inf, depth)[bad].max()
    return Violation(int(bad.sum()), float(t[np.argmax(bad)]), float(worst), SAFETY_UNITS[kind])


def _limit_violation(kind: str, t: np.ndarray, values: np.ndarray, limits: np.ndarray) -> Violation:
    """Per-axis limit: broken beyond a relative ``_LIMIT_RTOL`` (or not finite); depth ``max_i |v_i| − limit_i``."""
    v = np.asarray(values, dtype=float)
    lim = np.asarray(limits, dtype=float)
    finite = np.all(np.isfinite(v), axis=-1)
    bad = ~finite | np.any(np.abs(np.where(np.isfinite(v), v, 0.0)) > lim * (1 + _LIMIT_RTOL), axis=-1)
    depth = np.where(finite, np.max(np.abs(v) - lim, axis=-1), np.inf)
    return _violation(kind, t, depth, bad)


def safety_report(
    t_true: np.ndarray,
    x_true: np.ndarray,
    *,
    scene: Scene | None,
    velocity_limit_mps: np.ndarray,
    angular_velocity_limit_radps: np.ndarray,
    robot_radius_m: float = 0.0,
    keep_in_margin_m: float = 0.0,
    t_ctrl: np.ndarray | None = None,
    u_command: np.ndarray | None = None,
    input_limits: np.ndarray | None = None,
) -> dict[str, Violation]:
    """Count, first time and worst depth of every kind of violation, evaluated on the true states.

    Parameters
    ----------
    t_true : ndarray, shape (M,)
        Plant sample times [s] (the dense ``/state/true`` record).
    x_true : ndarray, shape (M, 13)
        True states.
    scene : Scene, optional
        Keep-in boxes and keep-out ellipsoids (safety factor applied); None skips both.
    velocity_limit_mps, angular_velocity_limit_radps : ndarray, shape (3,)
        Hard limits per world axis / body axis.
    robot_radius_m : float
        The robot's radius [m]: keep-out depth is the penetration of this ball into an ellipsoid
        (:func:`oacli.geometry.depth.keep_out_depth`).
    keep_in_margin_m : float
        Margin kept from the keep-in faces [m] (0: Astrobee's keep-in zones bound the robot's centre, as in the
        planners' collision checks; :func:`oacli.geometry.depth.keep_in_depth`).
    t_ctrl, u_command, input_limits : ndarray, optional
        Control times [s], commanded inputs (K, 6) and their limits (6,): the ``input`` kind counts control steps
        whose command exceeds an actuator limit (the actuators saturate it). Zero counts when omitted.

    Returns
    -------
    dict of str to Violation
        Keys ``keep_in``, ``keep_out``, ``velocity``, ``angular_velocity``, ``input``. A limit counts as broken
        beyond a relative ``1e-6`` of it, a position beyond ``1e-9`` m outside the free space; non-finite states
        count as violations of every kind with an infinite depth.
    """
    t = np.asarray(t_true, dtype=float)
    x = np.asarray(x_true, dtype=float)
    pos = x[:, 0:3]
    if scene is not None:
        keep_in = keep_in_depth(pos, scene, keep_in_margin_m)
        keep_out = keep_out_depth(pos, scene, robot_radius_m)
    else:
        keep_in = keep_out = np.where(np.all(np.isfinite(pos), axis=1), 0.0, np.inf)
    report = {
        "keep_in": _violation("keep_in", t, keep_in, ~(keep_in <= _DEPTH_TOL_M)),
        "keep_out": _violation("keep_out", t, keep_out, ~(keep_out <= _DEPTH_TOL_M)),
        "velocity": _limit_violation("velocity", t, x[:, 3:6], velocity_limit_mps),
        "angular_velocity": _limit_violation("angular_velocity", t, x[:, 10:13], angular_velocity_limit_radps),
        "input": Violation(0, None, 0.0, SAFETY_UNITS["input"]),
    }
    if u_command is not None and input_limits is not None and t_ctrl is not None:
        lim = np.asarray(input_limits, dtype=float)
        u = np.asarray(u_command, dtype=float)
        finite = np.all(np.isfinite(u), axis=-1)
        bad = ~finite | np.any(np.abs(np.where(np.isfinite(u), u, 0.0)) > lim * (1 + _LIMIT_RTOL) + 1e-12, axis=-1)
        rel = np.where(finite, np.max(np.abs(u) / lim - 1.0, axis=-1), np.inf)
        report["input"] = _violation("input", np.asarray(t_ctrl, dtype=float), rel, bad)
    return report


def safety_block(report: dict[str, Violation], *, samples: int, robot_radius_m: float,
                 keep_in_margin_m: float) -> dict[str, Any]:
    """The ``safety`` block of ``summary.json``: one entry per kind plus what was evaluated.

    Parameters
    ----------
    report : dict of str to Violation
        From :func:`safety_report`.
    samples : int
        Number of plant samples evaluated.
    robot_radius_m : float
        Robot radius used for the keep-out depths [m].
    keep_in_margin_m : float
        Margin kept from the keep-in walls [m].

    Returns
    -------
    dict
    """
    return {
        "evaluated_on": "/state/true (every plant sample); input: /control/command (every control step)",
        "samples": int(samples),
        "robot_radius_m": float(robot_radius_m),
        "keep_in_margin_m": float(keep_in_margin_m),
        **{kind: v.as_dict() for kind, v in report.items()},
    }


def constraint_violations(
    telemetry: Telemetry,
    *,
    input_limits: np.ndarray,
    velocity_limit_mps: np.ndarray,
    angular_velocity_limit_radps: np.ndarray,
    scene: Scene | None = None,
    robot_radius_m: float = 0.0,
) -> dict[str, int]:
    """Count violated constraints (the counts of :func:`safety_report`).

    Parameters
    ----------
    telemetry : Telemetry
    input_limits : ndarray, shape (6,)
        Force [N] and torque [N·m] limits.
    velocity_limit_mps, angular_velocity_limit_radps : ndarray, shape (3,)
    scene : Scene, optional
        Keep-in and keep-out zones (not checked without).
    robot_radius_m : float
        Radius of the robot's ball [m] for the keep-out check.

    Returns
    -------
    dict of str to int
        ``input`` (control steps whose *commanded* input exceeds a per-axis limit; the applied input is saturated
        anyway), ``velocity`` and ``angular_velocity`` (plant samples exceeding a per-axis limit), ``keep_in`` (plant
        samples whose position is in no keep-in box) and ``keep_out`` (plant samples where the robot's ball of
        ``robot_radius_m`` overlaps a keep-out ellipsoid, safety factor included).
    """
    report = safety_report(
        telemetry.t_true, telemetry.x_true, scene=scene, velocity_limit_mps=velocity_limit_mps,
        angular_velocity_limit_radps=angular_velocity_limit_radps, robot_radius_m=robot_radius_m,
        t_ctrl=telemetry.t_ctrl, u_command=telemetry.u_command, input_limits=input_limits,
    )
    return {kind: report[kind].count for kind in ("input", "velocity", "angular_velocity", "keep_in", "keep_out")}


def percentiles_ms(seconds: np.ndarray) -> dict[str, float]:
    """``{p50, p95, max}`` of durations given in seconds, in milliseconds (NaN entries ignored).

    Parameters
    ----------
    seconds : ndarray
        Durations [s].

    Returns
    -------
    dict of str to float
        ``p50``, ``p95``, ``max`` [ms] (NaN when there is no finite entry).
    """
    ms = 1e3 * np.asarray(seconds, dtype=float)
    ms = ms[np.isfinite(ms)]
    if ms.size == 0:
        return {"p50": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {
        "p50": float(np.percentile(ms, 50)),
        "p95": float(np.percentile(ms, 95)),
        "max": float(ms.max()),
    }


def rms(values: np.ndarray) -> float:
    """Root mean square.

    Parameters
    ----------
    values : ndarray

    Returns
    -------
    float
        NaN for an empty array.
    """
    v = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(v * v))) if v.size else float("nan")
