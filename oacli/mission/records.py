"""A finished mission's records on one ``mission_time`` axis, read back from its stage folders.

The mission recording (:mod:`oacli.mission.recording`) and the mission plots (:mod:`oacli.mission.plots`) show the
same data; this module reads it once from the stage MCAPs (the record of truth, :mod:`oacli.io.mcap_read`) and
shifts every stage's own time (0 at the start of the stage) by its segment's ``start_time_s`` from the mission
summary (the mission contract: segment-1 from 0, segment-2 from segment-1's end, the three segment-3 flights all
from segment-3's start; plans, smoothed paths, the excitation reference and the estimates at their segment's start).
Stages whose MCAP is missing (a failed or interrupted mission) are left out.

The mission reads the same stage MCAPs and configs several times (hand-offs, comparison rows, the recording, the
plots): :func:`read_telemetry_cached`, :func:`read_stage_cached` and :func:`load_config_cached` read each file once
per process and return the same
object while the file's modification time and size are unchanged (the files stay the source of truth: a stage
rerun by ``--resume`` or ``--from`` writes a new file, which is read again). Callers must not modify what they get.
A ``track.mcap`` is read once for both its telemetry and what the mission records show (:func:`stage_record`), and
the config a stage just ran with is remembered (:func:`remember_config`) instead of parsed back from its file.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from oacli.config import OacliConfig, dump_config, load_config
from oacli.geometry import Scene
from oacli.io import mcap_schema as ms
from oacli.io.mcap_read import TELEMETRY_TOPICS, StageRecord, read_stage, telemetry_from_record
from oacli.metrics import tracking_errors
from oacli.mission.layout import ALL_STAGES, MISSION_STAGES, RECORDED_STAGES, SEGMENTS, stage_by_key
from oacli.mission.layout import FLIGHT_LABELS as SEGMENT3_LABELS
from oacli.types import Telemetry

#: Cache the stage files read (module docstring); ``benchmarks/bench_outputs.py`` switches it off for the old path.
CACHE = True
#: Most files kept read (a mission has 12 stage MCAPs).
CACHE_SIZE = 32
_CACHE: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
_T = TypeVar("_T")


def clear_cache() -> None:
    """Forget every file read (:func:`read_telemetry_cached`, :func:`read_stage_cached`,
    :func:`load_config_cached`)."""
    _CACHE.clear()


def _key(kind: str, path: Path, extra: tuple[Any, ...]) -> tuple[Any, ...]:
    path = Path(path)
    stat = path.stat()
    return (kind, str(path.resolve()), stat.st_mtime_ns, stat.st_size, extra)


def _store(key: tuple[Any, ...], value: Any) -> None:
    _CACHE[key] = value
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)


def _cached(kind: str, path: Path, extra: tuple[Any, ...], read: Callable[[], _T]) -> _T:
    """``read()`` once per (file, modification time, size, ``extra``) while :data:`CACHE` is on."""
    if not CACHE:
        return read()
    key = _key(kind, path, extra)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]  # type: ignore[no-any-return]
    value = read()
    _store(key, value)
    return value


def remember_config(path: Path, cfg: OacliConfig) -> bool:
    """Let :func:`load_config_cached` of ``path`` return ``cfg`` (the config a stage just ran with, kept in memory)
    when the file holds exactly ``dump_config(cfg)``: :func:`~oacli.config.load_config` reads that text back into
    an equal model (paths in it are absolute). Otherwise nothing is remembered and the file is read when asked.

    Parameters
    ----------
    path : Path
        A stage folder's ``config.yaml``.
    cfg : OacliConfig
        The config the stage ran with.

    Returns
    -------
    bool
        Whether ``cfg`` was remembered.
    """
    if not CACHE:
        return False
    try:
        key = _key("config", path, ())
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return False
    if text != dump_config(cfg):
        return False
    _store(key, cfg)
    return True


def load_config_cached(path: Path) -> OacliConfig:
    """:func:`oacli.config.load_config` of a stage folder's ``config.yaml``, parsed once while the file is unchanged
    (shared: do not modify it).

    Parameters
    ----------
    path : Path
        A ``config.yaml``.

    Returns
    -------
    OacliConfig
    """
    return _cached("config", path, (), lambda: load_config(path))


def read_telemetry_cached(path: Path) -> Telemetry:
    """:func:`oacli.io.mcap_read.read_telemetry` of ``path``, read once while the file is unchanged (shared: do not
    modify it).

    Parameters
    ----------
    path : Path
        A ``track.mcap``.

    Returns
    -------
    Telemetry
    """
    return _cached("telemetry", path, (), lambda: telemetry_from_record(read_stage_cached(path, _TRACK_TOPICS)))


def read_stage_cached(path: Path, topics: Sequence[str] | None = None) -> StageRecord:
    """:func:`oacli.io.mcap_read.read_stage` of ``path`` (only ``topics`` when given), read once while the file is
    unchanged (shared: do not modify it).

    Parameters
    ----------
    path : Path
        A stage MCAP.
    topics : sequence of str, optional
        The topics to read (all by default).

    Returns
    -------
    StageRecord
    """
    key = None if topics is None else tuple(topics)
    return _cached("stage", path, (key,), lambda: read_stage(path) if topics is None else read_stage(path,
                                                                                                    topics=topics))


#: The parameters θ = [m, Ixx, Iyy, Izz] ([Doerr2021] Eq. 29) with their units.
PARAMETERS: tuple[tuple[str, str], ...] = (
    ("mass_kg", "kg"), ("Ixx_kgm2", "kg·m²"), ("Iyy_kgm2", "kg·m²"), ("Izz_kgm2", "kg·m²"))

#: The flights a mission may fly, in the order they are flown (segment-3's baselines last, the optional
#: unconstrained standard MPC of ``mission.unconstrained_baseline`` after them; a flight not flown is not read).
FLIGHTS: tuple[str, ...] = ("segment-1/track", "segment-2/track", *SEGMENT3_LABELS)

#: Flight labels for legends: segments 1 and 2 by their controller, segment 3 as in
#: :data:`oacli.mission.layout.FLIGHT_LABELS`.
FLIGHT_LABELS: dict[str, str] = {
    "segment-1/track": "segment 1, standard MPC",
    "segment-2/track": "segment 2, tube MPC, prior",
    **{key: f"segment 3, {label}" for key, label in SEGMENT3_LABELS.items()},
}


@dataclass(frozen=True)
class Flight:
    """One closed-loop flight (a ``track`` folder) on mission time.

    Attributes
    ----------
    key : str
        Stage key, e.g. ``segment-3/baseline-mpc-prior``.
    label : str
        Legend label.
    offset_s : float
        Its segment's start time [s] (added to the stage's own times).
    t_true, x_true : ndarray, shapes (N,), (N, 13)
        True states (``/state/true``) at mission times [s].
    t_ctrl : ndarray, shape (K,)
        Controller times [s] on mission time.
    position_error_m : ndarray, shape (K,)
        ‖r_true − r_ref‖ at the controller times [m].
    u_applied : ndarray, shape (K, 6)
        Applied force [N, world] and torque [N·m, body].
    force_limit_N, torque_limit_Nm : ndarray, shape (3,)
        The flight's actuator limits (its config's ``robot``).
    tube_lower_m, tube_upper_m : ndarray, shape (K, 3), or None
        Box hull of the tube ``z ⊕ Z`` at each controller time (tube MPC only) [m].
    nominal_m : ndarray, shape (K, 3), or None
        Nominal positions z (tube MPC only) [m].
    """

    key: str
    label: str
    offset_s: float
    t_true: np.ndarray
    x_true: np.ndarray
    t_ctrl: np.ndarray
    position_error_m: np.ndarray
    u_applied: np.ndarray
    force_limit_N: np.ndarray
    torque_limit_Nm: np.ndarray
    tube_lower_m: np.ndarray | None = None
    tube_upper_m: np.ndarray | None = None
    nominal_m: np.ndarray | None = None


@dataclass(frozen=True)
class PlannedPath:
    """A planned, smoothed or excitation reference path shown at its segment's start.

    Attributes
    ----------
    key : str
        Stage key (``segment-1/plan``, ``segment-1/smooth``, ``segment-2/excite`` ...).
    kind : str
        ``plan``, ``smooth`` or ``excite``.
    offset_s : float
        Its segment's start time [s].
    t : ndarray, shape (N,)
        Times on mission time [s].
    positions_m : ndarray, shape (N, 3)
    tree_starts_m, tree_ends_m : ndarray, shape (M, 3), or None
        The planner's tree edges parent → node (``plan`` only).
    """

    key: str
    kind: str
    offset_s: float
    t: np.ndarray
    positions_m: np.ndarray
    tree_starts_m: np.ndarray | None = None
    tree_ends_m: np.ndarray | None = None


@dataclass(frozen=True)
class EstimateSeries:
    """An estimate of θ over mission time (``/estimate/params`` of one estimate folder).

    Attributes
    ----------
    key : str
        Stage key (``segment-2/estimate`` or ``segment-2/estimate-sequential``).
    method : str
        ``batch`` or ``sequential``.
    t : ndarray, shape (K,)
        Time of the last record used, on mission time [s].
    theta : ndarray, shape (K, 4)
        [m kg, Ixx, Iyy, Izz kg·m²].
    std : ndarray, shape (K, 4)
        Standard deviations (the MCAP's ``std``), same units.
    """

    key: str
    method: str
    t: np.ndarray
    theta: np.ndarray
    std: np.ndarray


@dataclass(frozen=True)
class MissionRecords:
    """Everything the mission recording and plots show.

    Attributes
    ----------
    scene : Scene
        Keep-in boxes and keep-out ellipsoids (safety factor applied).
    robot_radius_m : float
        Collision radius [m].
    waypoints_m : dict[str, ndarray]
        ``A``, ``B``, ``C`` (those the segments name) -> position [m].
    segments : dict[str, dict]
        The summary's segments (``from``, ``to``, ``start_time_s``, ``duration_s``).
    grasp_time_s : float
        Mission time of the grasp at B [s].
    end_time_s : float
        Last mission time of any flight [s].
    flights : dict[str, Flight]
        By stage key, in :data:`FLIGHTS` order.
    paths : dict[str, PlannedPath]
        Plans, smoothed paths and the excitation reference by stage key.
    estimates : dict[str, EstimateSeries]
        By stage key.
    truth_theta : ndarray, shape (4,), or None
        True θ of the plant after the grasp, when known.
    log : list of (float, str, str)
        Every stage's text log on mission time, the message prefixed with the stage key.
    """

    scene: Scene
    robot_radius_m: float
    waypoints_m: dict[str, np.ndarray]
    segments: dict[str, dict[str, Any]]
    grasp_time_s: float
    end_time_s: float
    flights: dict[str, Flight] = field(default_factory=dict)
    paths: dict[str, PlannedPath] = field(default_factory=dict)
    estimates: dict[str, EstimateSeries] = field(default_factory=dict)
    truth_theta: np.ndarray | None = None
    log: list[tuple[float, str, str]] = field(default_factory=list)


#: The topics read of a ``track.mcap``: the telemetry and what the mission records show (one walk of the file).
_TRACK_TOPICS: tuple[str, ...] = (*TELEMETRY_TOPICS, ms.TOPIC_STATE_NOMINAL, ms.TOPIC_TUBE_DESIGN,
                                  ms.TOPIC_TUBE_DISTURBANCE, ms.TOPIC_LOG)

#: The topics :func:`load_mission_records` reads of each stage's MCAP, by command (one read per file: the log too).
_TOPICS: dict[str, tuple[str, ...]] = {
    "track": _TRACK_TOPICS,
    "plan": (ms.TOPIC_TRAJECTORY, ms.TOPIC_PLAN_TREE, ms.TOPIC_LOG),
    "smooth": (ms.TOPIC_TRAJECTORY, ms.TOPIC_PLAN_TREE, ms.TOPIC_LOG),
    "excite": (ms.TOPIC_TRAJECTORY, ms.TOPIC_PLAN_TREE, ms.TOPIC_LOG),
    "estimate": (ms.TOPIC_ESTIMATE_PARAMS, ms.TOPIC_LOG),
}


def stage_record(path: Path, command: str) -> StageRecord:
    """The topics of :data:`_TOPICS` of a stage's MCAP by its ``command`` (cached: the hand-offs, the comparison and
    the mission records share one read of each file).

    Parameters
    ----------
    path : Path
        A stage MCAP.
    command : str
        The stage's command (``track``, ``plan``, ``smooth``, ``excite``, ``estimate``).

    Returns
    -------
    StageRecord
    """
    return read_stage_cached(path, topics=_TOPICS.get(command, (ms.TOPIC_LOG,)))


def segment_offset(summary: dict[str, Any], segment: str) -> float:
    """``summary["segments"][segment]["start_time_s"]`` [s] (0 when the summary lacks it)."""
    return float(summary.get("segments", {}).get(segment, {}).get("start_time_s", 0.0))


def _stage_config(mission_dir: Path) -> OacliConfig:
    """The config of the first stage folder that has one (ordinary stage configs; the mission's own config
    holds the ``mission:`` section the stage configs are made from)."""
    for stage in MISSION_STAGES:
        path = stage.folder(mission_dir) / "config.yaml"
        if path.is_file():
            return load_config_cached(path)
    raise FileNotFoundError(f"{mission_dir}: no stage folder with a config.yaml")


def first_coordinate_range(normals: Any, offsets: Any) -> tuple[float, float]:
    """``[min, max]`` of the first coordinate over the polygon ``{z ∈ R² : A z ≤ b}`` (a tube axis's Z).

    For a bounded, non-empty polygon (its normals leave no angular gap of π or more) the extremes lie at vertices,
    found here as the feasible intersections of pairs of edges (numpy only: the report draws the tube bands
    without importing scipy); otherwise :meth:`oacli.sets.Polytope.support` decides (±inf, or -inf for an empty
    set), as it did for every polygon before.

    Parameters
    ----------
    normals : array_like, shape (m, 2)
        ``A``.
    offsets : array_like, shape (m,)
        ``b``.

    Returns
    -------
    tuple of float
        ``(min z₀, max z₀)`` [the units of z₀, m for the position axis].
    """
    a = np.asarray(normals, dtype=float).reshape(-1, 2)
    b = np.asarray(offsets, dtype=float).reshape(-1)
    if len(a) >= 3 and np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
        angles = np.sort(np.arctan2(a[:, 1], a[:, 0]))
        gaps = np.diff(np.r_[angles, angles[0] + 2.0 * np.pi])
        if gaps.max() < np.pi - 1e-9:  # bounded
            i, j = np.triu_indices(len(a), 1)
            det = a[i, 0] * a[j, 1] - a[i, 1] * a[j, 0]
            keep = np.abs(det) > 1e-12 * np.linalg.norm(a[i], axis=1) * np.linalg.norm(a[j], axis=1)
            i, j, det = i[keep], j[keep], det[keep]
            x = (b[i] * a[j, 1] - b[j] * a[i, 1]) / det
            y = (a[i, 0] * b[j] - a[j, 0] * b[i]) / det
            tol = 1e-9 * max(1.0, float(np.abs(b).max()))
            inside = np.all(np.outer(x, a[:, 0]) + np.outer(y, a[:, 1]) <= b + tol, axis=1)
            if inside.any():
                return float(x[inside].min()), float(x[inside].max())
    from oacli.sets import Polytope  # scipy: only for an unbounded, empty or malformed set

    zset = Polytope(a, b)
    return -float(zset.support(np.array([-1.0, 0.0]))), float(zset.support(np.array([1.0, 0.0])))


def _tube(record: StageRecord, t_ctrl_stage: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Box hull of ``z ⊕ Z`` per controller step from ``/state/nominal``, ``/tube/design`` and the design index of
    ``/tube/disturbance`` (the initial design where unknown)."""
    designs = record.json_records.get(ms.TOPIC_TUBE_DESIGN, ())
    nominal = record.trajectories.get(ms.TOPIC_STATE_NOMINAL)
    if not designs or nominal is None:
        return None
    extents = []  # per design: (3, 2) = [-min, max] of Z's projection on position
    for design in sorted(designs, key=lambda d: int(d.get("design", 0))):
        ext = []
        for ax in design["axes"]:
            low, high = first_coordinate_range(ax["z_normals"], ax["z_offsets"])
            ext.append([-low, high])
        extents.append(ext)
    ext_arr = np.asarray(extents, dtype=float)
    index = np.zeros(len(t_ctrl_stage), dtype=int)
    dist = record.json_records.get(ms.TOPIC_TUBE_DISTURBANCE, ())
    if len(dist) == len(t_ctrl_stage):
        index = np.clip([int(d.get("design", 0)) for d in dist], 0, len(extents) - 1)
    z = nominal.x[: len(t_ctrl_stage), 0:3]
    per_step = ext_arr[index[: len(z)]]
    return z - per_step[:, :, 0], z + per_step[:, :, 1], z


def _flight(mission_dir: Path, key: str, offset: float) -> Flight | None:
    stage = stage_by_key(key)
    path = stage.mcap(mission_dir)
    if not path.is_file():
        return None
    tel = read_telemetry_cached(path)
    record = stage_record(path, "track")
    errors = tracking_errors(tel, record.trajectories[ms.TOPIC_REFERENCE], times=tel.t_ctrl)
    cfg = load_config_cached(stage.folder(mission_dir) / "config.yaml")
    tube = _tube(record, tel.t_ctrl)
    return Flight(
        key=key, label=FLIGHT_LABELS[key], offset_s=offset,
        t_true=tel.t_true + offset, x_true=tel.x_true, t_ctrl=tel.t_ctrl + offset,
        position_error_m=errors.position_m, u_applied=tel.u_applied,
        force_limit_N=np.asarray(cfg.robot.force_limit_N, dtype=float),
        torque_limit_Nm=np.asarray(cfg.robot.torque_limit_Nm, dtype=float),
        tube_lower_m=None if tube is None else tube[0], tube_upper_m=None if tube is None else tube[1],
        nominal_m=None if tube is None else tube[2],
    )


def _path(mission_dir: Path, key: str, offset: float) -> PlannedPath | None:
    stage = stage_by_key(key)
    path = stage.mcap(mission_dir)
    if not path.is_file():
        return None
    record = stage_record(path, stage.command)
    traj = record.trajectories.get(ms.TOPIC_TRAJECTORY)
    if traj is None:
        return None
    starts = ends = None
    nodes = record.json_records.get(ms.TOPIC_PLAN_TREE, ())
    if nodes:
        pos = {int(n["node"]): np.asarray(n["position"], dtype=float) for n in nodes}
        edges = [(pos[int(n["parent"])], pos[int(n["node"])]) for n in nodes if int(n["parent"]) in pos]
        if edges:
            starts = np.array([a for a, _ in edges])
            ends = np.array([b for _, b in edges])
    return PlannedPath(key=key, kind=stage.command, offset_s=offset, t=traj.t + offset,
                       positions_m=traj.x[:, 0:3], tree_starts_m=starts, tree_ends_m=ends)


def _estimate(mission_dir: Path, key: str, offset: float) -> EstimateSeries | None:
    path = stage_by_key(key).mcap(mission_dir)
    if not path.is_file():
        return None
    params = stage_record(path, "estimate").json_records.get(ms.TOPIC_ESTIMATE_PARAMS, ())
    if not params:
        return None
    t = np.array([float(p["t"]) for p in params]) + offset
    theta = np.array([[float(p["mass_kg"]), *map(float, p["inertia_kgm2"])] for p in params])
    std = np.array([[np.nan if s is None else float(s) for s in p["std"]] for p in params])
    return EstimateSeries(key=key, method=str(params[0].get("method", "")), t=t, theta=theta, std=std)


def load_mission_records(mission_dir: Path, summary: dict[str, Any]) -> MissionRecords:
    """Read a mission folder's stage MCAPs onto mission time.

    Parameters
    ----------
    mission_dir : Path
        The mission run folder (:mod:`oacli.mission.layout`).
    summary : dict
        The mission summary (its ``segments`` give the offsets, ``grasp_time_s`` the grasp, ``estimate`` the truth).

    Returns
    -------
    MissionRecords

    Raises
    ------
    FileNotFoundError
        No stage folder holds a config.
    oacli.errors.InputError
        A stage MCAP is unreadable.
    """
    mission_dir = Path(mission_dir)
    cfg = _stage_config(mission_dir)
    segments = dict(summary.get("segments", {}))
    names = {str(seg.get(end)) for seg in segments.values() for end in ("from", "to")} or {"A", "B", "C"}
    waypoints = {n: np.asarray(cfg.waypoints[n].position, dtype=float) for n in sorted(names) if n in cfg.waypoints}
    flights = {}
    for key in FLIGHTS:
        flight = _flight(mission_dir, key, segment_offset(summary, key.split("/")[0]))
        if flight is not None:
            flights[key] = flight
    paths = {}
    for stage in ALL_STAGES:
        if stage.command in ("plan", "smooth", "excite"):
            p = _path(mission_dir, stage.key, segment_offset(summary, stage.segment))
            if p is not None:
                paths[stage.key] = p
    estimates = {}
    for key in ("segment-2/estimate-sequential", "segment-2/estimate"):
        e = _estimate(mission_dir, key, segment_offset(summary, "segment-2"))
        if e is not None:
            estimates[key] = e
    truth = (summary.get("estimate") or {}).get("truth_theta")
    log: list[tuple[float, str, str]] = []
    for stage in RECORDED_STAGES:  # the unconstrained baseline's log too, when flown
        path = stage.mcap(mission_dir)
        if path.is_file():
            offset = segment_offset(summary, stage.segment)
            log.extend((t + offset, level, f"[{stage.key}] {msg}")
                       for t, level, msg in stage_record(path, stage.command).log)
    log.sort(key=lambda e: e[0])
    ends = [float(f.t_true[-1]) for f in flights.values() if f.t_true.size]
    ends += [segment_offset(summary, s) + float(segments[s].get("duration_s", 0.0)) for s in SEGMENTS
             if s in segments]
    return MissionRecords(
        scene=cfg.scene(), robot_radius_m=float(cfg.robot.radius_m), waypoints_m=waypoints, segments=segments,
        grasp_time_s=float(summary.get("grasp_time_s", segment_offset(summary, "segment-2"))),
        end_time_s=max(ends, default=0.0), flights=flights, paths=paths, estimates=estimates,
        truth_theta=None if truth is None else np.asarray(truth, dtype=float), log=log,
    )
