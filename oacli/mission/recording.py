"""The mission's Rerun recording: every segment on one ``mission_time`` timeline, one blueprint.

Each stage's MCAP has its own time (0 at the stage's start); :func:`oacli.mission.records.load_mission_records`
shifts it by its segment's ``start_time_s``. Application id ``oacli-mission``: the viewer keeps the mission's
layout apart from the stage recordings' (blueprints are stored per application id).

Entities (a fixed contract; tests read them back). ``<flight>`` is a track folder's key (``segment-1/track``,
``segment-2/track``, ``segment-3/track``, ``segment-3/baseline-mpc-prior``, ``segment-3/baseline-tube-prior`` and,
when the mission flew it (``mission.unconstrained_baseline``), ``segment-3/baseline-mpc-unconstrained-prior``):

* ``world/keep_in``, ``world/keep_out`` (static scene), ``world/waypoints`` (A, B, C; static);
* ``world/<segment>/plan/tree`` and ``world/<segment>/plan/path`` (the planner's tree and plan),
  ``world/<segment>/smooth/path``, ``world/segment-2/excite/path`` (the excitation reference), each logged at its
  segment's start;
* ``world/<flight>/actual`` (the true path flown, ``/state/true``) at the flight's start, ``world/<flight>/robot``
  (the body moving over ``mission_time``; cleared when a segment-1/2 flight ends), and for tube MPC flights
  ``world/<flight>/nominal`` (nominal path z) and ``world/<flight>/tube`` (box hull of ``z ⊕ Z`` per control
  step);
* ``world/grasp`` (where the payload is grasped, at ``grasp_time_s``);
* ``metrics/position_error/<flight>`` -- ‖r − r_ref‖ [m] of every flight;
* ``metrics/force_N`` and ``metrics/torque_Nm`` -- applied input per axis of the main flight (segments 1, 2 and
  segment-3's tube MPC with estimate), with ``limit_upper``/``limit_lower`` children (the limit of each flight);
* ``metrics/force_fraction/<flight>`` -- max over axes of |f_i| / f_limit_i of every segment-3 flight, with
  ``metrics/force_fraction/limit`` (1: saturated);
* ``estimate/<param>/<method>`` (``method`` = ``sequential`` or ``batch``) with children ``upper_2sigma`` /
  ``lower_2sigma`` (estimate ± 2 std of the estimate MCAP), and ``estimate/<param>/truth`` (when known), for
  ``param`` in ``mass_kg``, ``Ixx_kgm2``, ``Iyy_kgm2``, ``Izz_kgm2``;
* ``log`` -- mission events (segment starts, the grasp) and every stage's log, prefixed with the stage key.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from oacli.io.rerun.layout import collapsed_side_panels, framed_eye, world_title
from oacli.io.rerun.writer import (
    AXIS_NAMES,
    LIMIT_LOWER,
    LIMIT_UPPER,
    LOG,
    TIMELINE,
    WORLD,
    StageRecording,
    time_column,
    time_series_view,
)
from oacli.mission.layout import BASELINES, FLIGHT_LABELS, SEGMENTS
from oacli.mission.records import PARAMETERS, Flight, MissionRecords, load_mission_records

APPLICATION_ID = "oacli-mission"
WAYPOINTS = "world/waypoints"
GRASP = "world/grasp"
POSITION_ERROR = "metrics/position_error"
FORCE = "metrics/force_N"
TORQUE = "metrics/torque_Nm"
FORCE_FRACTION = "metrics/force_fraction"
ESTIMATE = "estimate"

#: The flight whose inputs are plotted against the limits, per segment.
MAIN_FLIGHTS = ("segment-1/track", "segment-2/track", "segment-3/track")

#: Colours of the flights ([Doerr2021] Fig. 3(d): green, cyan, magenta for segment 3).
FLIGHT_COLORS: dict[str, tuple[int, int, int, int]] = {
    "segment-1/track": (255, 170, 40, 255),
    "segment-2/track": (200, 110, 30, 255),
    "segment-3/track": (40, 180, 60, 255),
    "segment-3/baseline-mpc-prior": (30, 200, 230, 255),
    "segment-3/baseline-tube-prior": (220, 50, 220, 255),
    "segment-3/baseline-mpc-unconstrained-prior": (188, 189, 34, 255),
}
#: The segment-3 flights' colours by name, for the 3-D tab's title (the unconstrained one only when flown).
SEGMENT3_COLOR_NAMES = {"segment-3/track": "green", "segment-3/baseline-mpc-prior": "cyan",
                        "segment-3/baseline-tube-prior": "magenta",
                        "segment-3/baseline-mpc-unconstrained-prior": "olive"}
_PATH_COLORS = {"plan": (150, 150, 255, 255), "smooth": (60, 110, 230, 255), "excite": (120, 60, 200, 255)}
_TREE_COLOR = (160, 160, 160, 110)
_WAYPOINT_COLOR = (250, 250, 250, 255)
_GRASP_COLOR = (255, 215, 0, 255)
_METHOD_COLORS = {"sequential": (40, 120, 230, 255), "batch": (230, 120, 30, 255)}
_TRUTH_COLOR = (40, 170, 60, 255)
_ROBOT_EDGE_M = 0.30


def _method(key: str) -> str:
    return "sequential" if key.endswith("-sequential") else "batch"


def mission_blueprint(records: MissionRecords | None = None) -> rrb.Blueprint:
    """The mission's layout.

    Left: a 3D view of the whole mission (tab 1) and one of the three segment-3 flights side by side (tab 2), above
    the text log, their cameras framed on the waypoints and paths (not on the whole workspace). Middle: position
    error of every flight [m], force and torque of the main flight against the limits, and force / limit of the
    segment-3 flights. Right: the four parameters converging with ± 2σ and
    the truth, zoomed on segment 2.

    Parameters
    ----------
    records : MissionRecords, optional
        When given, the estimate views open on segment 2's time range.

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    frame = "world" if records is None else records.scene.frame
    everything, segment3 = _focus(records)
    world = rrb.Spatial3DView(origin=WORLD, name=world_title(frame, "plans, references, flown paths, tubes"),
                              eye_controls=None if everything is None else framed_eye(everything))
    seg3 = rrb.Spatial3DView(
        eye_controls=None if segment3 is None else framed_eye(segment3),
        origin=WORLD,
        contents=["$origin/keep_in", "$origin/keep_out", f"$origin/{WAYPOINTS.split('/', 1)[1]}",
                  "$origin/segment-3/**", "- $origin/segment-3/plan/**"],
        name="Segment 3: " + ", ".join(f"{label} ({SEGMENT3_COLOR_NAMES[key]})" for key, label in FLIGHT_LABELS.items()
                                       if key in BASELINES or (records is not None and key in records.flights)),
    )
    scene = rrb.Vertical(rrb.Tabs(world, seg3, active_tab=0), rrb.TextLogView(origin=LOG, name="Log"),
                         row_shares=[3.0, 1.0], name="Scene")
    note = ": x red, y green, z blue; thin = ± limit"
    metrics = rrb.Vertical(
        time_series_view(POSITION_ERROR, "Position error [m], every flight"),
        time_series_view(FORCE, "Force applied [N], main flight" + note, legend=False),
        time_series_view(TORQUE, "Torque applied [N·m], main flight" + note, legend=False),
        time_series_view(FORCE_FRACTION, "Segment 3: max |force| / limit (1 = saturated)"),
        name="Tracking",
    )
    axis = None
    if records is not None and "segment-2" in records.segments:
        start = float(records.segments["segment-2"]["start_time_s"])
        end = start + float(records.segments["segment-2"].get("duration_s", 0.0))
        if end > start:
            pad = 0.05 * (end - start)
            axis = rrb.TimeAxis(view_range=rr.TimeRange(start=rr.TimeRangeBoundary.absolute(seconds=start - pad),
                                                        end=rr.TimeRangeBoundary.absolute(seconds=end + pad)))
    estimates = []
    for param, unit in PARAMETERS:
        view = time_series_view(f"{ESTIMATE}/{param}",
                                f"{param.split('_')[0]} [{unit}]: sequential blue, batch orange, ± 2σ, truth green")
        if axis is not None:
            view = rrb.TimeSeriesView(origin=f"{ESTIMATE}/{param}", name=view.name, axis_x=axis)
        estimates.append(view)
    return rrb.Blueprint(
        rrb.Horizontal(scene, metrics, rrb.Vertical(*estimates, name="Estimates"), column_shares=[1.3, 1.0, 1.0]),
        rrb.TimePanel(timeline=TIMELINE, expanded=True),
        *collapsed_side_panels(),
        collapse_panels=False,
    )


def _focus(records: MissionRecords | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Points [m] the 3-D views frame: waypoints and every path and flight; segment 3's flights alone."""
    if records is None:
        return None, None
    pts = [np.asarray(p, dtype=float).reshape(1, 3) for p in records.waypoints_m.values()]
    pts += [path.positions_m for key, path in records.paths.items() if path.kind != "plan"]
    pts += [f.x_true[:, 0:3] for f in records.flights.values()]
    seg3 = [f.x_true[:, 0:3] for key, f in records.flights.items() if key.startswith("segment-3/")]
    return (np.concatenate(pts) if pts else None), (np.concatenate(seg3) if seg3 else None)


def _at(rec: StageRecording, t: float, entity: str, archetype: Any) -> None:
    """Log one row at mission time ``t`` [s]."""
    stream = rec.stream
    stream.set_time(TIMELINE, duration=np.timedelta64(int(np.rint(float(t) * 1e9)), "ns"))
    try:
        stream.log(entity, archetype, strict=True)
    finally:
        stream.reset_time()


def _log_plans(rec: StageRecording, records: MissionRecords) -> None:
    for key, path in records.paths.items():
        base = f"{WORLD}/{key}"
        rec.log_path(f"{base}/path", path.positions_m, color=_PATH_COLORS.get(path.kind, (200, 200, 200, 255)),
                     radius_m=0.008 if path.kind != "plan" else 0.005, static=False, t=path.offset_s)
        if path.tree_starts_m is not None and path.tree_ends_m is not None:
            rec.log_segments(f"{base}/tree", path.tree_starts_m, path.tree_ends_m, color=_TREE_COLOR,
                             static=False, t=path.offset_s)


def _log_flight(rec: StageRecording, flight: Flight, *, clear_after: bool) -> None:
    base = f"{WORLD}/{flight.key}"
    color = FLIGHT_COLORS.get(flight.key, (255, 170, 40, 255))
    rec.log_path(f"{base}/actual", flight.x_true[:, 0:3], color=color, radius_m=0.006, static=False,
                 t=flight.offset_s)
    robot = f"{base}/robot"
    q = flight.x_true[:, 6:10]
    q = q / np.linalg.norm(q, axis=1)[:, None]
    rec.stream.send_columns(robot, indexes=[time_column(flight.t_true)],
                            columns=rr.Transform3D.columns(translation=flight.x_true[:, 0:3], quaternion=q),
                            strict=True)
    half = 0.5 * _ROBOT_EDGE_M
    body_color = np.array([*color[:3], 120], dtype=np.uint8)
    _at(rec, float(flight.t_true[0]), robot,
        rr.Boxes3D(half_sizes=[[half, half, half]], colors=[body_color],
                   fill_mode=rr.components.FillMode.TransparentFillMajorWireframe,
                   labels=[flight.label], show_labels=False))
    if clear_after:
        _at(rec, float(flight.t_true[-1]) + 1e-3, robot, rr.Clear(recursive=False))
    if flight.nominal_m is not None and flight.tube_lower_m is not None and flight.tube_upper_m is not None:
        rec.log_path(f"{base}/nominal", flight.nominal_m, color=(*color[:3], 200), radius_m=0.003, static=False,
                     t=flight.offset_s)
        lower, upper = flight.tube_lower_m, flight.tube_upper_m
        _at(rec, flight.offset_s, f"{base}/tube",
            rr.Boxes3D(centers=0.5 * (lower + upper), half_sizes=0.5 * (upper - lower), colors=[(*color[:3], 60)],
                       fill_mode=rr.components.FillMode.MajorWireframe))


def _step_limits(rec: StageRecording, entity: str, flights: Sequence[Flight], limits: Sequence[np.ndarray],
                 faded: np.ndarray) -> None:
    """± limits per axis as series stepping from flight to flight (two samples per flight)."""
    t = np.concatenate([[f.t_ctrl[0], f.t_ctrl[-1]] for f in flights])
    lim = np.concatenate([np.tile(v, (2, 1)) for v in limits])
    for child, sign, label in ((LIMIT_UPPER, 1.0, "+"), (LIMIT_LOWER, -1.0, "−")):
        path = f"{entity}/{child}"
        rec.stream.log(path, rr.SeriesLines(names=[f"{label}{a} limit" for a in AXIS_NAMES], colors=faded,
                                            widths=[0.75] * 3), static=True, strict=True)
        rec.stream.send_columns(path, indexes=[time_column(t)], columns=rr.Scalars.columns(scalars=sign * lim),
                                strict=True)


def _log_inputs(rec: StageRecording, records: MissionRecords) -> None:
    main = [records.flights[k] for k in MAIN_FLIGHTS if k in records.flights and records.flights[k].t_ctrl.size]
    if main:
        t = np.concatenate([f.t_ctrl for f in main])
        u = np.concatenate([f.u_applied for f in main])
        faded = np.array([[230, 60, 60, 150], [60, 180, 75, 150], [60, 110, 230, 150]], dtype=np.uint8)
        rec.log_series(FORCE, t, u[:, 0:3], AXIS_NAMES)
        _step_limits(rec, FORCE, main, [f.force_limit_N for f in main], faded)
        rec.log_series(TORQUE, t, u[:, 3:6], AXIS_NAMES)
        _step_limits(rec, TORQUE, main, [f.torque_limit_Nm for f in main], faded)
    seg3 = [records.flights[k] for k in FLIGHT_LABELS if k in records.flights and records.flights[k].t_ctrl.size]
    for f in seg3:
        frac = np.max(np.abs(f.u_applied[:, 0:3]) / f.force_limit_N, axis=1)
        rec.log_series(f"{FORCE_FRACTION}/{f.key}", f.t_ctrl, frac, [FLIGHT_LABELS[f.key]],
                       colors=[FLIGHT_COLORS[f.key]])
    if seg3:
        span = np.array([min(f.t_ctrl[0] for f in seg3), max(f.t_ctrl[-1] for f in seg3)])
        rec.log_series(f"{FORCE_FRACTION}/limit", span, np.ones(2), ["limit"], colors=[(150, 150, 150, 200)],
                       width=1.0)


def _log_estimates(rec: StageRecording, records: MissionRecords) -> None:
    for key, est in records.estimates.items():
        method = _method(key)
        color = _METHOD_COLORS[method]
        band = (*color[:3], 110)
        for i, (param, _) in enumerate(PARAMETERS):
            entity = f"{ESTIMATE}/{param}/{method}"
            rec.log_series(entity, est.t, est.theta[:, i], [method], colors=[color], width=2.0)
            rec.log_series(f"{entity}/upper_2sigma", est.t, est.theta[:, i] + 2 * est.std[:, i], [f"{method} +2σ"],
                           colors=[band], width=1.0)
            rec.log_series(f"{entity}/lower_2sigma", est.t, est.theta[:, i] - 2 * est.std[:, i], [f"{method} −2σ"],
                           colors=[band], width=1.0)
    if records.truth_theta is not None and records.estimates:
        start = min(float(e.t[0]) for e in records.estimates.values())
        span = np.array([min(start, records.grasp_time_s), max(records.end_time_s, start)])
        for i, (param, _) in enumerate(PARAMETERS):
            rec.log_series(f"{ESTIMATE}/{param}/truth", span, np.full(2, records.truth_theta[i]), ["truth"],
                           colors=[_TRUTH_COLOR], width=1.0)


def _log_events(rec: StageRecording, records: MissionRecords) -> None:
    if records.waypoints_m:
        names = list(records.waypoints_m)
        rec.log_points(WAYPOINTS, np.array([records.waypoints_m[n] for n in names]), color=_WAYPOINT_COLOR,
                       radius_m=0.04, labels=names)
    events: list[tuple[float, str, str]] = []
    for seg in SEGMENTS:
        info = records.segments.get(seg)
        if info is not None:
            events.append((float(info["start_time_s"]), "INFO",
                           f"{seg} starts: {info.get('from')} -> {info.get('to')} "
                           f"({float(info.get('duration_s', 0.0)):.1f} s)"))
    t_grasp = records.grasp_time_s
    events.append((t_grasp, "WARN", "grasp at B: payload picked up, the plant's mass and inertia change"))
    seg2 = records.flights.get("segment-2/track")
    where = (seg2.x_true[0, 0:3] if seg2 is not None else records.waypoints_m.get("B"))
    if where is not None:
        _at(rec, t_grasp, GRASP, rr.Points3D([where], radii=[0.08], colors=[_GRASP_COLOR], labels=["grasp"],
                                            show_labels=True))
    rec.log_entries(sorted(events + list(records.log), key=lambda e: e[0]))


def write_mission_recording(path: Path, mission_dir: Path, summary: dict[str, Any], *, recording_name: str,
                            records: MissionRecords | None = None) -> None:
    """Write ``mission.rrd``: the whole mission on the ``mission_time`` timeline (module docstring) with
    :func:`mission_blueprint`.

    Parameters
    ----------
    path : Path
        Output ``.rrd`` (written atomically; its folder must exist).
    mission_dir : Path
        The mission folder (:mod:`oacli.mission.layout`); the stage MCAPs are read from it.
    summary : dict
        The mission summary (segments' ``start_time_s`` and ``duration_s``, ``grasp_time_s``, ``estimate``).
    recording_name : str
        Recording name shown in the viewer.
    records : MissionRecords, optional
        The records of ``mission_dir`` already read (:func:`load_mission_records`; read here otherwise).

    Raises
    ------
    oacli.errors.InputError
        A stage MCAP is unreadable.
    FileNotFoundError
        No stage folder holds a config.
    """
    if records is None:
        records = load_mission_records(Path(mission_dir), summary)
    rec = StageRecording(APPLICATION_ID, recording_name)
    rec.log_scene(records.scene)
    _log_events(rec, records)
    _log_plans(rec, records)
    for key, flight in records.flights.items():
        _log_flight(rec, flight, clear_after=key in ("segment-1/track", "segment-2/track"))
        if flight.t_ctrl.size:
            rec.log_series(f"{POSITION_ERROR}/{key}", flight.t_ctrl, flight.position_error_m, [flight.label],
                           colors=[FLIGHT_COLORS.get(key, (255, 170, 40, 255))])
    _log_inputs(rec, records)
    _log_estimates(rec, records)
    rec.save(Path(path), mission_blueprint(records))
