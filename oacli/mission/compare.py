"""The [Doerr2021] Fig. 3(d) comparison: segment 3 flown three ways, measured the same way.

Per flight (a ``track`` folder): RMS / max position error, the overshoot past the goal along the approach direction,
the control effort ∫‖F‖ dt, the time any force axis is saturated, the arrival time (from which the robot stays
within :data:`ARRIVAL_TOLERANCE_M` of the goal), the duration flown, and the keep-in / keep-out / limit violations.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from oacli.mission.layout import FLIGHT_LABELS
from oacli.mission.records import load_config_cached, read_telemetry_cached

ARRIVAL_TOLERANCE_M = 0.02
"""Arrival: the true position stays within this distance of the reference's final position [m]."""

SATURATION_FRACTION = 0.999
"""A force axis counts as saturated at this fraction of its limit or above."""


def overshoot_m(t: np.ndarray, position: np.ndarray, goal: np.ndarray, approach: np.ndarray) -> float:
    """Largest excursion past the goal along the approach direction [m] (0 when the goal is never passed).

    Parameters
    ----------
    t : ndarray, shape (K,)
        Times [s] (unused except for shape checks).
    position : ndarray, shape (K, 3)
        True positions [m].
    goal : ndarray, shape (3,)
        The reference's final position [m].
    approach : ndarray, shape (3,)
        Direction of the final approach (:func:`approach_direction`; normalised here).

    Returns
    -------
    float
    """
    position = np.asarray(position, dtype=float).reshape(len(t), 3)
    norm = float(np.linalg.norm(approach))
    if norm == 0.0:
        return 0.0
    ahead = (position - np.asarray(goal, dtype=float)) @ (np.asarray(approach, dtype=float) / norm)
    return float(max(0.0, ahead.max()))


APPROACH_CHORD_M = 0.1
"""The approach direction is the chord from the last reference point this far from the goal to the goal [m]."""


def approach_direction(reference_m: np.ndarray, chord_m: float = APPROACH_CHORD_M) -> np.ndarray:
    """Direction of the final approach: from the last reference position at least ``chord_m`` from the goal to the
    goal (the reference's own overall direction when it never is that far).

    The reference's last velocity is not used: a smoothed plan can end with a small correction in another direction
    (its velocity at the last moving sample pointed back along the route in some segment-3 plans), and then every
    earlier sample of the flight projected as "past the goal" (overshoots of 0.66-1.42 m).

    Parameters
    ----------
    reference_m : ndarray, shape (K, 3)
        Reference positions [m]; the last is the goal.
    chord_m : float
        Chord length [m].

    Returns
    -------
    ndarray, shape (3,)
        Not normalised (zero for a reference that never moves).
    """
    ref = np.asarray(reference_m, dtype=float).reshape(-1, 3)
    goal = ref[-1]
    far = np.flatnonzero(np.linalg.norm(ref - goal, axis=1) >= chord_m)
    return goal - (ref[far[-1]] if far.size else ref[0])


def arrival_time_s(t: np.ndarray, position: np.ndarray, goal: np.ndarray, tolerance_m: float) -> float | None:
    """First time from which the position stays within ``tolerance_m`` of ``goal`` [s] (None if never).

    Parameters
    ----------
    t : ndarray, shape (K,)
        Times [s].
    position : ndarray, shape (K, 3)
        True positions [m].
    goal : ndarray, shape (3,)
        Goal [m].
    tolerance_m : float
        Radius [m].

    Returns
    -------
    float or None
    """
    outside = np.linalg.norm(np.asarray(position, dtype=float) - np.asarray(goal, dtype=float), axis=1) > tolerance_m
    if outside[-1]:
        return None
    if not outside.any():
        return float(t[0])
    return float(t[int(np.flatnonzero(outside)[-1]) + 1])


def effort_and_saturation(t_ctrl: np.ndarray, u_applied: np.ndarray, force_limit_N: np.ndarray,
                          period_s: float) -> tuple[float, float]:
    """Control effort ∫‖F‖ dt [N·s] and the time any force axis is saturated [s] (zero-order hold inputs).

    Parameters
    ----------
    t_ctrl : ndarray, shape (K,)
        Control instants [s].
    u_applied : ndarray, shape (K, 6)
        Applied inputs, held for ``period_s`` each.
    force_limit_N : ndarray, shape (3,)
        Actuator force limits [N].
    period_s : float
        Control period [s].

    Returns
    -------
    effort_Ns : float
    saturated_s : float
    """
    force = np.asarray(u_applied, dtype=float)[:, 0:3]
    effort = float(np.linalg.norm(force, axis=1).sum() * period_s)
    saturated = np.any(np.abs(force) >= SATURATION_FRACTION * np.asarray(force_limit_N), axis=1)
    return effort, float(saturated.sum() * period_s)


def comparison_row(key: str, summary: dict[str, Any], mission_dir: Path) -> dict[str, Any]:
    """One flight of segment 3, measured (module docstring).

    Parameters
    ----------
    key : str
        ``segment-3/track`` or a baseline key (:data:`oacli.mission.layout.FLIGHT_LABELS`).
    summary : dict
        The flight's stage summary (a failed baseline has only ``status`` and ``error``).
    mission_dir : Path
        The mission folder.

    Returns
    -------
    dict
    """
    row: dict[str, Any] = {"label": FLIGHT_LABELS.get(key, key), "status": summary.get("status")}
    if "rms_position_error_m" not in summary:
        row["error"] = summary.get("error")
        return row
    folder = Path(mission_dir) / key
    cfg = load_config_cached(folder / "config.yaml")
    tel = read_telemetry_cached(folder / "track.mcap")
    goal = tel.x_reference[-1, 0:3]
    approach = approach_direction(tel.x_reference[:, 0:3])
    effort, saturated = effort_and_saturation(tel.t_ctrl, tel.u_applied, np.asarray(cfg.robot.force_limit_N),
                                              cfg.controller.period_s)
    violations = summary.get("constraint_violations_by_kind", {})
    row.update({
        "controller": summary.get("controller"),
        "model_mass_kg": cfg.robot.mass_kg,
        "rms_position_error_m": summary["rms_position_error_m"],
        "max_position_error_m": summary["max_position_error_m"],
        "overshoot_m": overshoot_m(tel.t_true, tel.x_true[:, 0:3], goal, approach),
        "control_effort_Ns": effort,
        "time_saturated_s": saturated,
        "arrival_time_s": arrival_time_s(tel.t_true, tel.x_true[:, 0:3], goal, ARRIVAL_TOLERANCE_M),
        "final_distance_m": float(np.linalg.norm(tel.x_true[-1, 0:3] - goal)),
        "duration_s": float(tel.t_true[-1]),
        "keep_in_violations": int(violations.get("keep_in", 0)),
        "keep_out_violations": int(violations.get("keep_out", 0)),
        "limit_violations": int(sum(violations.get(k, 0) for k in ("input", "velocity", "angular_velocity"))),
    })
    return row
