"""Tracking metrics of a closed-loop run (the numbers in ``summary.json``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry import Scene
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


def tracking_errors(telemetry: Telemetry, reference: Trajectory, times: np.ndarray | None = None) -> TrackingErrors:
    """Position and attitude errors of the true state at ``times`` (the plant samples by default).

    Parameters
    ----------
    telemetry : Telemetry
        A simulated run.
    reference : Trajectory
    times : ndarray, shape (k,), optional
        Evaluation times [s]; the true state is taken at the first plant sample at or after each.

    Returns
    -------
    TrackingErrors
    """
    t = telemetry.t_true if times is None else np.asarray(times, dtype=float)
    x_true = telemetry.x_true
    if times is not None:
        idx = np.clip(np.searchsorted(telemetry.t_true, t - 1e-9), 0, len(telemetry.t_true) - 1)
        x_true = telemetry.x_true[idx]
    x_ref = sample_states(reference, t)
    pos = np.linalg.norm(x_true[:, 0:3] - x_ref[:, 0:3], axis=1)
    att = quat.angle_between(x_ref[:, 6:10], x_true[:, 6:10])
    return TrackingErrors(t, pos, att)


def constraint_violations(
    telemetry: Telemetry,
    *,
    input_limits: np.ndarray,
    velocity_limit_mps: np.ndarray,
    angular_velocity_limit_radps: np.ndarray,
    scene: Scene | None = None,
) -> dict[str, int]:
    """Count violated constraints.

    Parameters
    ----------
    telemetry : Telemetry
    input_limits : ndarray, shape (6,)
        Force [N] and torque [N·m] limits.
    velocity_limit_mps, angular_velocity_limit_radps : ndarray, shape (3,)
    scene : Scene, optional
        Keep-in and keep-out zones (not checked without).

    Returns
    -------
    dict of str to int
        ``input`` (control steps whose *commanded* input exceeds a per-axis limit; the applied input is saturated
        anyway), ``velocity`` and ``angular_velocity`` (plant samples exceeding a per-axis limit), ``keep_in`` (plant
        samples whose position is in no keep-in box) and ``keep_out`` (plant samples inside a keep-out ellipsoid,
        safety factor included).
    """
    x = telemetry.x_true
    over_u = np.abs(telemetry.u_command) > input_limits * (1 + _LIMIT_RTOL) + 1e-12
    over_v = np.abs(x[:, 3:6]) > velocity_limit_mps * (1 + _LIMIT_RTOL)
    over_w = np.abs(x[:, 10:13]) > angular_velocity_limit_radps * (1 + _LIMIT_RTOL)
    counts = {
        "input": int(np.any(over_u, axis=1).sum()),
        "velocity": int(np.any(over_v, axis=1).sum()),
        "angular_velocity": int(np.any(over_w, axis=1).sum()),
        "keep_in": 0,
        "keep_out": 0,
    }
    if scene is not None:
        counts["keep_in"] = int((~scene.in_keep_in(x[:, 0:3])).sum())
        counts["keep_out"] = int(scene.in_keep_out(x[:, 0:3]).sum())
    return counts


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
