"""The study presets' per-run figures (``configs/study_*.yaml``), computed from a run's files.

* [Doerr2021] Fig. 3(d): for each of segment 3's flights, the mission's comparison row (RMS error, overshoot, time
  saturated, arrival, violations) and the closest approach of the robot's body to a keep-out zone
  (:func:`keep_out_clearance_m`; negative: inside).
* [ReSWARM2023] RATTLE table: the batch and the sequential estimates' percent errors and covariance reductions.
* [ReSWARM2023] Experiment Set 3: the lag of the flown path behind the reference (:func:`tracking_lag`) and the
  position error while the reference holds still (:func:`hold_error`), what a disturbance alone drives.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from oacli.geometry.verify import point_ellipsoid_distance

COMPARISON_KEYS = ("rms_position_error_m", "max_position_error_m", "overshoot_m", "control_effort_Ns",
                   "time_saturated_s", "arrival_time_s", "keep_in_violations", "keep_out_violations",
                   "limit_violations")
"""The fields of a mission comparison row (:func:`oacli.mission.compare.comparison_row`) a campaign keeps."""

MAX_LAG_S = 5.0
"""Largest lag searched [s]."""

SETTLE_AFTER_STOP_S = 2.0
"""A holding reference counts as holding only this long after it stopped [s] (the approach transient is lag)."""


def keep_out_clearance_m(positions_m: np.ndarray, scene: Any, robot_radius_m: float) -> float | None:
    """Closest approach of the robot's ball to any keep-out ellipsoid [m]: min over samples and zones of the
    signed surface distance minus the radius (negative: the body entered the zone). None without keep-out zones.

    Parameters
    ----------
    positions_m : ndarray, shape (N, 3)
        True positions [m].
    scene : Scene
        Keep-out ellipsoids (safety factor applied).
    robot_radius_m : float
        Robot radius [m].

    Returns
    -------
    float or None
    """
    p = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if not scene.keep_out or not len(p):
        return None
    best = np.inf
    for e in scene.keep_out:
        semi, rot = e.principal_axes()
        best = min(best, float(np.min(point_ellipsoid_distance(p, e.center, semi, rot))))
    return best - float(robot_radius_m)


def tracking_lag(t_true: np.ndarray, r_true: np.ndarray, t_ref: np.ndarray, r_ref: np.ndarray,
                 max_lag_s: float = MAX_LAG_S) -> tuple[float, float]:
    """The delay τ ≥ 0 by which the flown path best matches the reference delayed, and the RMS left at τ.

    τ minimises RMS‖r(t) − r_ref(t − τ)‖ over the samples where ``t − τ`` lies within the reference's times, on a
    grid of the plant's sample period from 0 to ``max_lag_s``: a sluggish controller trails its reference by τ; the
    residual RMS is what the lag does not explain (disturbances, overshoot).

    Parameters
    ----------
    t_true, r_true : ndarray, shapes (N,), (N, 3)
        True positions and their times [s, m].
    t_ref, r_ref : ndarray, shapes (K,), (K, 3)
        Reference positions and their times [s, m].
    max_lag_s : float
        Largest lag searched [s].

    Returns
    -------
    lag_s : float
    residual_rms_m : float
    """
    t_true = np.asarray(t_true, dtype=float)
    r_true = np.asarray(r_true, dtype=float).reshape(-1, 3)
    t_ref = np.asarray(t_ref, dtype=float)
    r_ref = np.asarray(r_ref, dtype=float).reshape(-1, 3)
    step = float(np.median(np.diff(t_true))) if t_true.size > 1 else 0.016
    best = (0.0, np.inf)
    for tau in np.arange(0.0, max_lag_s + 0.5 * step, step):
        keep = (t_true - tau >= t_ref[0]) & (t_true - tau <= t_ref[-1])
        if keep.sum() < 2:
            break
        shifted = np.column_stack([np.interp(t_true[keep] - tau, t_ref, r_ref[:, i]) for i in range(3)])
        rms = float(np.sqrt(np.mean(np.sum((r_true[keep] - shifted) ** 2, axis=1))))
        if rms < best[1]:
            best = (float(tau), rms)
    return best


def hold_error(t_ctrl: np.ndarray, r_true: np.ndarray, x_reference: np.ndarray,
               settle_s: float = SETTLE_AFTER_STOP_S) -> tuple[float | None, float | None]:
    """RMS and max position error [m] while the reference holds still (at least ``settle_s`` after it stopped):
    the error a disturbance drives with nothing to follow ([ReSWARM2023] §6.3, disturbance rejection).

    Parameters
    ----------
    t_ctrl : ndarray, shape (K,)
        Control times [s].
    r_true : ndarray, shape (K, 3)
        True positions at ``t_ctrl`` [m].
    x_reference : ndarray, shape (K, 13)
        Reference states at ``t_ctrl``.
    settle_s : float
        Time after the reference stops before a sample counts [s].

    Returns
    -------
    rms_m, max_m : float or None
        None when the reference never holds that long.
    """
    t = np.asarray(t_ctrl, dtype=float)
    ref = np.asarray(x_reference, dtype=float)
    still = np.linalg.norm(ref[:, 3:6], axis=1) < 1e-6
    since = np.full(t.shape, -np.inf)
    start = None
    for i, s in enumerate(still):
        start = (t[i] if start is None else start) if s else None
        if start is not None:
            since[i] = t[i] - start
    hold = since >= settle_s
    if not hold.any():
        return None, None
    err = np.linalg.norm(np.asarray(r_true, dtype=float)[hold] - ref[hold, 0:3], axis=1)
    return float(np.sqrt(np.mean(err**2))), float(err.max())


def response_metrics(tel: Any) -> dict[str, Any]:
    """Experiment Set 3's figures of one tracking run: ``lag_s``, ``lag_residual_rms_m``, ``hold_rms_m``,
    ``hold_max_m``.

    Parameters
    ----------
    tel : Telemetry
        The run's telemetry.

    Returns
    -------
    dict
    """
    lag, residual = tracking_lag(tel.t_true, tel.x_true[:, 0:3], tel.t_ctrl, tel.x_reference[:, 0:3])
    r_ctrl = (tel.x_true_ctrl[:, 0:3] if tel.x_true_ctrl is not None
              else np.column_stack([np.interp(tel.t_ctrl, tel.t_true, tel.x_true[:, i]) for i in range(3)]))
    hold_rms, hold_max = hold_error(tel.t_ctrl, r_ctrl, tel.x_reference)
    return {"lag_s": lag, "lag_residual_rms_m": residual, "hold_rms_m": hold_rms, "hold_max_m": hold_max}


def comparison_metrics(folder: Path, summary: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Segment 3's flights of a mission folder: the comparison row's figures and the keep-out clearance.

    Parameters
    ----------
    folder : Path
        A complete mission folder.
    summary : dict
        Its ``summary.json``.

    Returns
    -------
    dict
        Stage key -> ``status``, :data:`COMPARISON_KEYS`, ``keep_out_clearance_m``.
    """
    from oacli.config import load_config
    from oacli.io.mcap_read import read_telemetry

    out: dict[str, dict[str, Any]] = {}
    for key, row in (summary.get("comparison") or {}).items():
        entry: dict[str, Any] = {"status": row.get("status"), **{k: row.get(k) for k in COMPARISON_KEYS}}
        stage_dir = Path(folder) / key
        if (stage_dir / "track.mcap").is_file() and "rms_position_error_m" in row:
            cfg = load_config(stage_dir / "config.yaml")
            tel = read_telemetry(stage_dir / "track.mcap")
            entry["keep_out_clearance_m"] = keep_out_clearance_m(tel.x_true[:, 0:3], cfg.scene(),
                                                                 cfg.robot.radius_m)
        out[key] = entry
    return out


def sequential_estimate(folder: Path) -> dict[str, Any] | None:
    """The sequential estimate's percent errors and covariance reductions (its stage summary), if it ran.

    Parameters
    ----------
    folder : Path
        A mission folder.

    Returns
    -------
    dict or None
        ``error_pct`` and ``cov_reduction_pct`` as lists (mass, Ixx, Iyy, Izz), ``status``.
    """
    path = Path(folder) / "segment-2" / "estimate-sequential" / "summary.json"
    if not path.is_file():
        return None
    s = json.loads(path.read_text())
    return {"error_pct": as_theta_list(s.get("error_pct")),
            "cov_reduction_pct": as_theta_list(s.get("cov_reduction_pct")), "status": s.get("status")}


THETA_KEYS = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")


def as_theta_list(value: Any) -> list[float | None] | None:
    """A per-parameter entry (a dict by :data:`THETA_KEYS` or a list of 4) as a list [mass, Ixx, Iyy, Izz]."""
    if value is None:
        return None
    if isinstance(value, dict):
        return [None if value.get(k) is None else float(value[k]) for k in THETA_KEYS]
    return [None if v is None else float(v) for v in value]


__all__ = ["comparison_metrics", "hold_error", "keep_out_clearance_m", "response_metrics", "sequential_estimate",
           "tracking_lag"]
