"""The mission's PNG plots (matplotlib, Agg backend: no display needed).

``mission_dir/plots/``:

* ``tracking_error.png`` -- position error ‖r − r_ref‖ [m] over mission time, one panel per segment; segment 3
  with the three flights of :data:`oacli.mission.layout.BASELINES` ([Doerr2021] Fig. 3(d)) and, when flown, the
  unconstrained standard MPC (``mission.unconstrained_baseline``, olive: red is the keep-out zones);
* ``estimate_convergence.png`` -- mass and the three principal inertias over mission time with ± 2σ bands and the
  truth (dashed), and the estimate's error and 2σ relative to the truth on a log scale against the ReSWARM flight
  figures (mass 0.39 %, inertias 0.91 / 1.35 / 6.92 %);
* ``paths.png`` -- the paths in the two projections that show them (:func:`view_axes`; the ISS mission: y-z along
  the module, and x-y), side by side and zoomed on the paths: keep-in boxes, keep-out ellipsoids (projected;
  dashed: grown by the robot radius), plan, smoothed path or excitation reference and the flown path of each
  segment, A, B and C.

Each file is rendered to memory and written atomically (:func:`oacli.io.atomic.atomic_path`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg", force=True)

import numpy as np

from oacli.io.plots.common import (
    AXES,
    decimate,
    draw_scene,
    legend_outside,
    log_scale,
    save_png,
    spans_decades,
    subplots,
)
from oacli.mission.layout import FLIGHT_LABELS, SEGMENTS
from oacli.mission.records import PARAMETERS, MissionRecords, load_mission_records

#: Relative estimation errors of the ReSWARM flight experiments [%] (issue 9; [ReSWARM2023] §6.3.1, the RATTLE
#: table): mass, Ixx, Iyy, Izz. The same figures as :data:`oacli.estimation.rls.RATTLE_TABLE_ERROR_PCT` (a test holds
#: them equal), written here so that drawing a mission's figures (``oacli report`` of a campaign run) does not import
#: the estimators and scipy with them.
FLIGHT_ERROR_PCT = (0.39, 0.91, 1.35, 6.92)

#: Matplotlib colours of the flights (segment 3 as [Doerr2021] Fig. 3(d): green, cyan, magenta).
FLIGHT_COLORS: dict[str, str] = {
    "segment-1/track": "tab:orange",
    "segment-2/track": "tab:brown",
    "segment-3/track": "tab:green",
    "segment-3/baseline-mpc-prior": "tab:cyan",
    "segment-3/baseline-tube-prior": "m",
    "segment-3/baseline-mpc-unconstrained-prior": "tab:olive",
}
_SEGMENT_COLORS = {"segment-1": "tab:orange", "segment-2": "tab:brown", "segment-3": "tab:green"}
_METHOD_COLORS = {"sequential": "tab:blue", "batch": "tab:orange"}


def plot_tracking_error(records: MissionRecords, path: Path) -> Path:
    """Position error per segment, segment 3 with its baselines (see the module docstring).

    Parameters
    ----------
    records : MissionRecords
        The mission's records.
    path : Path
        Output PNG.

    Returns
    -------
    Path
        ``path``.
    """
    fig, axes = subplots(len(SEGMENTS), 1, figsize=(10, 8.5))
    flown = [f.position_error_m for f in records.flights.values() if f.t_ctrl.size]
    errors = np.concatenate(flown) if flown else np.zeros(0)
    log = spans_decades(errors)  # one scale for every panel: a log panel beside a linear one misleads
    y_lim = error_axis_limits(errors, log)
    for ax, seg in zip(axes, SEGMENTS, strict=True):
        flights = [f for f in records.flights.values() if f.key.startswith(seg + "/") and f.t_ctrl.size]
        for f in flights:
            rms = float(np.sqrt(np.mean(f.position_error_m**2)))
            label = FLIGHT_LABELS.get(f.key, f.label) + f" (RMS {1e3 * rms:.1f} mm)"
            ax.plot(*decimate(f.t_ctrl, f.position_error_m), color=FLIGHT_COLORS.get(f.key), lw=1.3, label=label)
        info = records.segments.get(seg, {})
        ax.set_title(f"{seg}: {info.get('from', '?')} → {info.get('to', '?')}", loc="left", fontsize="medium")
        ax.set_ylabel("position error [m]" + (", log" if log else ""))
        ax.grid(True, alpha=0.3, which="both")
        if log:
            log_scale(ax)
        if y_lim is not None:
            ax.set_ylim(*y_lim)
        if not flights:
            ax.text(0.5, 0.5, "no flight recorded", transform=ax.transAxes, ha="center", va="center")
        legend_outside(ax)
    axes[-1].set_xlabel("mission time [s]")
    fig.suptitle("Tracking error ‖r − r_ref‖ per segment (segment 3: [Doerr2021] Fig. 3(d) baselines)")
    return save_png(fig, path)


#: Lowest decade shown below the largest error on a log error axis (a momentary zero crossing would stretch it).
LOG_DECADES_SHOWN = 3.0


def error_axis_limits(errors_m: np.ndarray, log: bool) -> tuple[float, float] | None:
    """The y range shared by the error panels [m]: ``[0, 1.05 max]`` linear; on a log axis from the smallest
    positive error (at most :data:`LOG_DECADES_SHOWN` decades below the largest) to 1.5 × the largest."""
    e = np.asarray(errors_m, dtype=float)
    e = e[np.isfinite(e)]
    if not e.size or e.max() <= 0:
        return None
    top = float(e.max())
    if not log:
        return 0.0, 1.05 * top
    low = max(float(e[e > 0].min()), top * 10.0**-LOG_DECADES_SHOWN)
    return low / 1.5, 1.5 * top


def _relative_pct(values: np.ndarray, truth: float) -> np.ndarray:
    return 100.0 * np.abs(values) / abs(truth) if truth != 0 else np.full_like(values, np.nan)


def plot_estimate_convergence(records: MissionRecords, path: Path) -> Path:
    """The four parameters converging (left) and their error and 2σ relative to the truth (right, log scale).

    Parameters
    ----------
    records : MissionRecords
        The mission's records.
    path : Path
        Output PNG.

    Returns
    -------
    Path
        ``path``.
    """
    truth = records.truth_theta
    fig, axes = subplots(4, 2, figsize=(12, 11), sharex=True)
    for i, (param, unit) in enumerate(PARAMETERS):
        ax, ax_rel = axes[i, 0], axes[i, 1]
        shown: list[np.ndarray] = []
        for key, est in records.estimates.items():
            method = "sequential" if key.endswith("-sequential") else "batch"
            color = _METHOD_COLORS[method]
            value, two_sigma = est.theta[:, i], 2.0 * est.std[:, i]
            ax.plot(est.t, value, color=color, lw=1.5, marker="o" if len(est.t) < 20 else None, ms=3,
                    label=f"{method} estimate")
            ax.fill_between(est.t, value - two_sigma, value + two_sigma, color=color, alpha=0.2, lw=0,
                            label=f"{method} ± 2σ")
            # y range: the converged half of each series (the first records' prior-sized bands would hide it)
            half = len(value) // 2
            shown += [value[half:] - two_sigma[half:], value[half:] + two_sigma[half:]]
            if truth is not None:
                ax_rel.plot(est.t, _relative_pct(value - truth[i], truth[i]), color=color, lw=1.5,
                            label=f"{method} |error|")
                ax_rel.plot(est.t, _relative_pct(two_sigma, truth[i]), color=color, lw=1.0, ls=":",
                            label=f"{method} 2σ")
            else:
                ax_rel.plot(est.t, 100.0 * two_sigma / np.abs(value), color=color, lw=1.0, ls=":",
                            label=f"{method} 2σ / estimate")
        if truth is not None:
            ax.axhline(truth[i], color="k", ls="--", lw=1.0, label="truth")
            shown.append(np.array([truth[i]]))
        flight = " / ".join(f"{v:g}" for v in FLIGHT_ERROR_PCT)
        ax_rel.axhline(FLIGHT_ERROR_PCT[i], color="tab:red", ls="--", lw=1.0,
                       label=f"flight error (ReSWARM):\n{flight} %, top to bottom")
        if shown:
            lo, hi = float(np.nanmin(np.concatenate(shown))), float(np.nanmax(np.concatenate(shown)))
            pad = 0.1 * (hi - lo) if hi > lo else 0.05 * max(abs(hi), 1e-9)
            ax.set_ylim(lo - pad, hi + pad)
        name = param.split("_")[0]
        ax.set_ylabel(f"{name} [{unit}]")
        ax_rel.set_ylabel(f"{name}: % of truth")
        log_scale(ax_rel)
        for a in (ax, ax_rel):
            a.grid(True, alpha=0.3, which="both")
            a.axvline(records.grasp_time_s, color="0.5", lw=0.8)
        if i == 0:  # one legend per column: the rows draw the same series
            legend_outside(ax_rel)
            legend_outside(ax)
            ax.set_title("estimate ± 2σ (y range: converged half; grey line: grasp)", loc="left",
                         fontsize="medium")
            ax_rel.set_title("error and 2σ relative to the truth (log)", loc="left", fontsize="medium")
    # x range set, not autoscaled: an axvline's data limits go through the view it is drawn into, whose last bits
    # differ on a reused figure (common.REUSE)
    t_all = np.concatenate([[records.grasp_time_s], *(e.t for e in records.estimates.values())])
    t_lo, t_hi = float(np.min(t_all)), float(np.max(t_all))
    pad = 0.05 * (t_hi - t_lo) if t_hi > t_lo else 1.0
    axes[0, 0].set_xlim(t_lo - pad, t_hi + pad)  # shared by every panel
    for a in axes[-1]:
        a.set_xlabel("mission time [s]")
    fig.suptitle("Inertial parameter estimates after the grasp (segment 2); flight figures: mass 0.39 %, "
                 "inertias 0.91 / 1.35 / 6.92 %")
    return save_png(fig, path)


#: Room around the paths in the path views [m] (the robot's radius and some).
VIEW_MARGIN_M = 0.35


def view_axes(points_m: np.ndarray) -> tuple[tuple[int, int], tuple[int, int]]:
    """The two projections that show a mission's paths: the plane of the two world axes along which the points
    spread most, then the plane of the most spread axis and the remaining one (each pair in x, y, z order).

    The ISS mission's route A -> B -> C -> A runs along the JEM's y and up and down in z (x stays within a few
    decimetres, where segment 1 swerves around the keep-out): y-z, then x-y.

    Parameters
    ----------
    points_m : ndarray, shape (N, 3)
        Every path's positions [m].

    Returns
    -------
    tuple of (int, int)
        World axes of the main view and of the second view.
    """
    pts = np.asarray(points_m, dtype=float).reshape(-1, 3)
    spread = np.ptp(pts, axis=0) if len(pts) else np.zeros(3)
    order = [int(i) for i in np.argsort(-spread, kind="stable")]
    main = tuple(sorted(order[:2]))
    second = tuple(sorted((order[0], order[2])))
    return main, second  # type: ignore[return-value]


#: Waypoints nearer each other than this fraction of a view's span are marked once, with their names joined
#: ("B, C"): their labels would be printed on top of each other.
LABEL_MERGE_FRACTION = 0.06


def waypoint_labels(waypoints_m: dict[str, np.ndarray], axes: tuple[int, int],
                    merge_m: float) -> list[tuple[list[str], tuple[float, float]]]:
    """The waypoint marks of one view: waypoints whose projections lie within ``merge_m`` [m] of a group's first
    one join that group (names in order, drawn at the first one's position).

    Parameters
    ----------
    waypoints_m : dict of str to ndarray, shape (3,)
    axes : tuple of int
        World axes of the view.
    merge_m : float
        Merge distance in the view [m].

    Returns
    -------
    list of (names, (x, y))
    """
    i, j = axes
    groups: list[tuple[list[str], tuple[float, float]]] = []
    for name, pos in waypoints_m.items():
        x, y = float(pos[i]), float(pos[j])
        for names, (gx, gy) in groups:
            if np.hypot(x - gx, y - gy) < merge_m:
                names.append(name)
                break
        else:
            groups.append(([name], (x, y)))
    return groups


def _path_view(ax: Any, records: MissionRecords, axes: tuple[int, int], lower: np.ndarray, upper: np.ndarray,
               title: str) -> None:
    """One projection of the scene, the paths and the waypoints, limited to the paths' box ``lower``-``upper``."""
    i, j = axes
    draw_scene(ax, records.scene, records.robot_radius_m, axes)
    styles = {"plan": (":", 1.0, "plan"), "smooth": ("--", 1.2, "smoothed"), "excite": ("--", 1.2, "excitation ref.")}
    for key, p in records.paths.items():
        seg = key.split("/")[0]
        ls, lw, what = styles.get(p.kind, (":", 1.0, p.kind))
        ax.plot(*decimate(p.positions_m[:, i], p.positions_m[:, j]), ls=ls, lw=lw,
                color=_SEGMENT_COLORS.get(seg, "0.4"), alpha=0.8, label=f"{seg} {what}")
    for key, f in records.flights.items():
        label = (f"{key.split('/')[0]} flown" if key not in FLIGHT_LABELS
                 else f"segment 3 flown: {FLIGHT_LABELS[key]}")
        width = {"segment-3/track": 3.0, "segment-3/baseline-mpc-prior": 2.0}.get(key, 1.2)  # overlaid: widest under
        ax.plot(*decimate(f.x_true[:, i], f.x_true[:, j]), lw=width, color=FLIGHT_COLORS.get(key), label=label)
    span = float(max(upper[i] - lower[i], upper[j] - lower[j]))
    for names, (x, y) in waypoint_labels(records.waypoints_m, axes, LABEL_MERGE_FRACTION * span):
        ax.plot(x, y, "k^", ms=9, zorder=5)
        ax.annotate(", ".join(names), (x, y), xytext=(6, 6), textcoords="offset points", fontsize=13,
                    fontweight="bold", zorder=6)
    # the view: the paths' box (the keep-in boxes reach far beyond), widened to equal scales by the aspect
    ax.dataLim.set_points(np.array([[lower[i], lower[j]], [upper[i], upper[j]]], dtype=float))
    ax.margins(0.0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{AXES[i]} [m]")
    ax.set_ylabel(f"{AXES[j]} [m]")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, loc="left", fontsize="medium")


def plot_paths(records: MissionRecords, path: Path) -> Path:
    """The paths of every segment in the two projections that show them (:func:`view_axes`), side by side, zoomed
    on the paths: keep-in boxes, keep-out ellipsoids (projected; dashed: grown by the robot radius), plans,
    smoothed paths, the excitation reference and the flown paths; A, B, C marked.

    Parameters
    ----------
    records : MissionRecords
        The mission's records.
    path : Path
        Output PNG.

    Returns
    -------
    Path
        ``path``.
    """
    points = [p.positions_m for p in records.paths.values()] + [f.x_true[:, 0:3] for f in records.flights.values()]
    points += [np.asarray(list(records.waypoints_m.values()), dtype=float).reshape(-1, 3)]
    pts = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 3) for p in points])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):  # nothing flown nor planned: the scene
        pts = np.array([b.lower for b in records.scene.keep_in] + [b.upper for b in records.scene.keep_in]
                       ).reshape(-1, 3) if records.scene.keep_in else np.zeros((1, 3))
    lower, upper = pts.min(axis=0) - VIEW_MARGIN_M, pts.max(axis=0) + VIEW_MARGIN_M
    main, second = view_axes(pts)
    fig, (ax_main, ax_second) = subplots(1, 2, figsize=(15, 7))
    name = {(0, 1): "top", (0, 2): "side", (1, 2): "side"}
    for ax, axes in ((ax_main, main), (ax_second, second)):
        _path_view(ax, records, axes, lower, upper,
                   f"{name[axes]} view ({AXES[axes[0]]}-{AXES[axes[1]]})")
    legend_outside(ax_second)
    fig.suptitle("Plans and flown paths of every segment, zoomed on the paths (keep-in: green, keep-out: red); "
                 "A, B, C marked")
    return save_png(fig, path)


def write_mission_plots(mission_dir: Path, summary: dict[str, Any], *, records: MissionRecords | None = None,
                        out_dir: Path | None = None) -> dict[str, Path]:
    """Write the mission's PNG plots into ``mission_dir/plots/`` (module docstring).

    Parameters
    ----------
    mission_dir : Path
        The mission folder (:mod:`oacli.mission.layout`); the stage MCAPs are read from it.
    summary : dict
        The mission summary (segments' ``start_time_s``, ``grasp_time_s``, ``estimate.truth_theta``).
    records : MissionRecords, optional
        The records of ``mission_dir`` already read (:func:`load_mission_records`; read here otherwise).
    out_dir : Path, optional
        Where the PNGs go (default ``mission_dir/plots``).

    Returns
    -------
    dict[str, Path]
        ``tracking_error``, ``estimate_convergence``, ``paths`` -> the PNG written.

    Raises
    ------
    oacli.errors.InputError
        A stage MCAP is unreadable.
    FileNotFoundError
        No stage folder holds a config.
    """
    mission_dir = Path(mission_dir)
    if records is None:
        records = load_mission_records(mission_dir, summary)
    out = mission_dir / "plots" if out_dir is None else Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return {
        "tracking_error": plot_tracking_error(records, out / "tracking_error.png"),
        "estimate_convergence": plot_estimate_convergence(records, out / "estimate_convergence.png"),
        "paths": plot_paths(records, out / "paths.png"),
    }
