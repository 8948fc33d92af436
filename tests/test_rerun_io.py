"""Rerun recordings: write a synthetic track recording, read it back with ``rerun.chunk.RrdReader``, compare values.

Recordings are not byte-reproducible, so every check compares decoded values. Positions, sizes and quaternions are
stored as float32 by Rerun (rtol ~1e-7 relative, i.e. ~1e-6 m at ISS coordinates of ~10 m); scalars as float64;
times as integer nanoseconds.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation

from oacli.errors import InputError
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.io.rerun import writer as rerun_writer
from oacli.io.rerun.read import (
    read_blueprint_views,
    read_recording_component,
    read_recording_entities,
    read_recording_scalars,
)
from oacli.io.rerun.track import track_blueprint, write_track_recording
from oacli.io.rerun.writer import StageRecording
from oacli.metrics import TrackingErrors
from oacli.model.limits import MotionLimits
from oacli.types import SolveInfo, Telemetry, Trajectory

F32 = {"rtol": 2e-7, "atol": 2e-6}  # float32 storage of positions (|r| ~ 11 m)
T_ATOL = 1e-9  # times are stored in integer nanoseconds

CONTRACT = {
    "world/keep_in",
    "world/keep_out",
    "world/reference",
    "world/actual",
    "world/robot",
    "metrics/position_error_m",
    "metrics/attitude_error_rad",
    "metrics/force_N",
    "metrics/torque_Nm",
    "metrics/solve_time_ms",
    "log",
}


def _synthetic(duration_s: float = 20.0, true_hz: float = 62.5, ctrl_hz: float = 5.0, seed: int = 0) -> dict:
    """A synthetic track run: known sinusoidal errors, known (saturated) forces, 1 box + 2 ellipsoids."""
    rng = np.random.default_rng(seed)
    m = round(duration_s * true_hz) + 1
    k = round(duration_s * ctrl_hz) + 1
    t_true = np.linspace(0.0, duration_s, m)
    t_ctrl = np.linspace(0.0, duration_s, k)
    x_true = np.zeros((m, 13))
    x_true[:, 0] = 10.8 + 0.02 * t_true
    x_true[:, 1] = -9.6 + 0.3 * np.sin(0.1 * t_true)
    x_true[:, 2] = 4.9 + 0.1 * np.cos(0.2 * t_true)
    x_true[:, 6:10] = Rotation.from_rotvec(np.outer(0.05 * t_true, [0.2, 0.3, 0.93])).as_quat()
    t_ref = t_true[::5]
    x_ref = x_true[::5].copy()
    x_ref[:, 2] += 0.01
    force_limit = np.array([0.85, 0.41, 0.41])
    torque_limit = np.array([0.1, 0.08, 0.06])
    u_command = np.column_stack(
        [
            1.2 * np.sin(0.7 * t_ctrl),
            0.3 * np.cos(0.5 * t_ctrl),
            -0.6 * np.sin(0.3 * t_ctrl),
            0.05 * np.sin(t_ctrl),
            0.12 * np.cos(t_ctrl),
            0.01 * t_ctrl / duration_s,
        ]
    )
    limits = np.concatenate([force_limit, torque_limit])
    u_applied = np.clip(u_command, -limits, limits)
    rot = Rotation.from_euler("xyz", [0.4, -0.3, 1.1]).as_matrix()
    scene = Scene(
        keep_in=(Box([9.5, -10.5, 4.0], [11.8, -8.5, 5.6]),),
        keep_out=(
            Ellipsoid.from_semi_axes([10.9, -9.2, 4.6], [0.25, 0.4, 0.15], rot),
            Ellipsoid.from_semi_axes([11.3, -9.9, 5.2], [0.2, 0.2, 0.3]),
        ),
    )
    return {
        "scene": scene,
        "t_ref": t_ref,
        "x_ref": x_ref,
        "t_true": t_true,
        "x_true": x_true,
        "t_ctrl": t_ctrl,
        "u_command": u_command,
        "u_applied": u_applied,
        "position_error_m": 0.02 + 0.01 * np.sin(0.9 * t_ctrl),
        "attitude_error_rad": 0.05 * np.abs(np.cos(0.4 * t_ctrl)),
        "solve_time_s": 1e-3 * (3.0 + rng.random(k)),
        "force_limit_N": force_limit,
        "torque_limit_Nm": torque_limit,
        "log": [(0.0, "INFO", "track started"), (7.5, "WARNING", "force saturated"), (duration_s, "INFO", "done")],
    }


def _kwargs(run: dict) -> dict:
    """The synthetic run as the arguments of ``write_track_recording`` (reference, telemetry, errors, limits)."""
    t_true, x_true, t_ctrl = run["t_true"], run["x_true"], run["t_ctrl"]
    at_ctrl = x_true[np.clip(np.searchsorted(t_true, t_ctrl), 0, len(t_true) - 1)]
    telemetry = Telemetry(
        t_true, x_true, t_ctrl, x_measured=at_ctrl, x_reference=at_ctrl, u_command=run["u_command"],
        u_applied=run["u_applied"], solve_info=tuple(SolveInfo("optimal", True, solve_time_s=s)
                                                     for s in run["solve_time_s"]),
    )
    return {
        "scene": run["scene"],
        "reference": Trajectory(run["t_ref"], run["x_ref"], np.zeros((len(run["t_ref"]), 6)), name="reference"),
        "telemetry": telemetry,
        "errors": TrackingErrors(t_ctrl, run["position_error_m"], run["attitude_error_rad"]),
        "limits": MotionLimits(run["force_limit_N"], run["torque_limit_Nm"], [0.2] * 3, [0.17] * 3),
        "log": run["log"],
    }


@pytest.fixture(scope="module")
def run() -> dict:
    return _synthetic()


@pytest.fixture(scope="module")
def track_rrd(tmp_path_factory, run) -> Path:
    path = tmp_path_factory.mktemp("rrd") / "track.rrd"
    write_track_recording(path, **_kwargs(run))
    return path


# ---------------------------------------------------------------------------------------------------------------
# The track recording
# ---------------------------------------------------------------------------------------------------------------


def test_track_entities_exist(track_rrd):
    entities = read_recording_entities(track_rrd)
    assert entities >= CONTRACT, CONTRACT - entities
    for child in ("limit_upper", "limit_lower", "command"):
        assert f"metrics/force_N/{child}" in entities
        assert f"metrics/torque_Nm/{child}" in entities


def test_track_one_recording_with_name_and_mission_time_only(track_rrd):
    reader = RrdReader(track_rrd)
    (store,) = reader.recordings()
    assert store.application_id == "oacli-track-mpc"
    _, names = read_recording_component(track_rrd, "__properties", "RecordingInfo:name")
    assert names[-1].tolist() == ["track"]
    # No wall-clock timelines: log_time and log_tick are switched off.
    timelines = {name for ch in reader.stream() for name in ch.timeline_names}
    assert timelines == {"mission_time"}


def test_track_scalar_series_round_trip(track_rrd, run):
    s = read_recording_scalars(track_rrd)
    t = run["t_ctrl"]
    expected = {
        "metrics/position_error_m": run["position_error_m"],
        "metrics/attitude_error_rad": run["attitude_error_rad"],
        "metrics/solve_time_ms": 1e3 * run["solve_time_s"],
        "metrics/force_N": run["u_applied"][:, 0:3],
        "metrics/torque_Nm": run["u_applied"][:, 3:6],
        "metrics/force_N/command": run["u_command"][:, 0:3],
        "metrics/torque_Nm/command": run["u_command"][:, 3:6],
    }
    for entity, values in expected.items():
        times, got = s[entity]
        np.testing.assert_allclose(times, t, rtol=0, atol=T_ATOL, err_msg=entity)
        assert got.shape == values.shape, entity
        np.testing.assert_allclose(got, values, rtol=1e-15, atol=0, err_msg=entity)  # float64 end to end


def test_track_force_plotted_against_limits(track_rrd, run):
    s = read_recording_scalars(track_rrd)
    t0, t1 = run["t_ctrl"][0], run["t_ctrl"][-1]
    for entity, lim in (("metrics/force_N", run["force_limit_N"]), ("metrics/torque_Nm", run["torque_limit_Nm"])):
        for child, sign in (("limit_upper", 1.0), ("limit_lower", -1.0)):
            times, values = s[f"{entity}/{child}"]
            np.testing.assert_allclose(times, [t0, t1], atol=T_ATOL)
            np.testing.assert_allclose(values, np.tile(sign * lim, (2, 1)))
        # The applied wrench respects the limits, the command exceeds them somewhere (the data is saturated).
        _, applied = s[entity]
        _, command = s[f"{entity}/command"]
        assert np.all(np.abs(applied) <= lim + 1e-12)
        assert np.any(np.abs(command) > lim)


def test_track_series_are_named(track_rrd):
    for entity in ("metrics/force_N", "metrics/torque_Nm"):
        times, rows = read_recording_component(track_rrd, entity, "SeriesLines:names")
        assert times is None  # static styling
        assert rows[-1].tolist() == ["x", "y", "z"]
        _, colors = read_recording_component(track_rrd, entity, "SeriesLines:colors")
        assert len(set(colors[-1].tolist())) == 3
    _, rows = read_recording_component(track_rrd, "metrics/force_N/limit_upper", "SeriesLines:names")
    assert rows[-1].tolist() == ["+x limit", "+y limit", "+z limit"]


def test_track_keep_out_ellipsoids(track_rrd, run):
    ellipsoids = run["scene"].keep_out
    times, half_sizes = read_recording_component(track_rrd, "world/keep_out", "Ellipsoids3D:half_sizes")
    assert times is None
    _, centers = read_recording_component(track_rrd, "world/keep_out", "Ellipsoids3D:centers")
    _, quats = read_recording_component(track_rrd, "world/keep_out", "Ellipsoids3D:quaternions")
    assert half_sizes[-1].shape == (2, 3)
    for i, e in enumerate(ellipsoids):
        semi_axes, _ = e.principal_axes()
        np.testing.assert_allclose(half_sizes[-1][i], semi_axes, rtol=1e-6)
        np.testing.assert_allclose(np.sort(half_sizes[-1][i]), np.sort(1.0 / np.sqrt(np.linalg.eigvalsh(e.shape))))
        np.testing.assert_allclose(centers[-1][i], e.center, **F32)
        # The drawn ellipsoid R diag(a)… reproduces the keep-out shape matrix P = R diag(1/a²) Rᵀ.
        r = Rotation.from_quat(quats[-1][i].astype(float)).as_matrix()
        p = r @ np.diag(1.0 / half_sizes[-1][i].astype(float) ** 2) @ r.T
        np.testing.assert_allclose(p, e.shape, rtol=1e-5, atol=1e-5 * np.abs(e.shape).max())


def test_track_keep_in_box(track_rrd, run):
    (box,) = run["scene"].keep_in
    _, centers = read_recording_component(track_rrd, "world/keep_in", "Boxes3D:centers")
    _, half_sizes = read_recording_component(track_rrd, "world/keep_in", "Boxes3D:half_sizes")
    np.testing.assert_allclose(centers[-1][0], box.center, **F32)
    np.testing.assert_allclose(half_sizes[-1][0], 0.5 * box.size, **F32)


def test_track_robot_pose_over_time(track_rrd, run):
    t_true, x_true = run["t_true"], run["x_true"]
    times, translations = read_recording_component(track_rrd, "world/robot", "Transform3D:translation")
    _, quaternions = read_recording_component(track_rrd, "world/robot", "Transform3D:quaternion")
    np.testing.assert_allclose(times, t_true, atol=T_ATOL)
    for i in (0, 1, len(t_true) // 3, len(t_true) // 2, len(t_true) - 1):
        np.testing.assert_allclose(translations[i][0], x_true[i, 0:3], **F32)
        q = quaternions[i][0].astype(float)
        assert abs(abs(q @ x_true[i, 6:10]) - 1.0) < 1e-6  # same rotation (q and -q are equal)
    # The Astrobee body: a 30 cm cube drawn in the body frame, logged once.
    times, half = read_recording_component(track_rrd, "world/robot", "Boxes3D:half_sizes")
    assert times is None
    np.testing.assert_allclose(half[-1], [[0.15, 0.15, 0.15]], rtol=1e-6)


def test_track_paths(track_rrd, run):
    for entity, positions in (("world/actual", run["x_true"][:, 0:3]), ("world/reference", run["x_ref"][:, 0:3])):
        times, strips = read_recording_component(track_rrd, entity, "LineStrips3D:strips")
        assert times is None
        (strip,) = strips[-1]  # one strip: a list of points
        np.testing.assert_allclose(np.asarray(strip.tolist(), dtype=float), positions, **F32)


def test_track_text_log(track_rrd, run):
    times, texts = read_recording_component(track_rrd, "log", "TextLog:text")
    _, levels = read_recording_component(track_rrd, "log", "TextLog:level")
    np.testing.assert_allclose(times, [t for t, _, _ in run["log"]], atol=T_ATOL)
    assert [r.tolist() for r in texts] == [[m] for _, _, m in run["log"]]
    assert [r.tolist() for r in levels] == [["INFO"], ["WARN"], ["INFO"]]  # WARNING is Rerun's WARN


def test_track_blueprint_is_stored(track_rrd):
    reader = RrdReader(track_rrd)
    (blueprint,) = reader.blueprints()
    assert blueprint.application_id == "oacli-track-mpc"
    views = read_blueprint_views(track_rrd)
    by_origin = {v["origin"]: v["class"] for v in views}
    assert by_origin["world"] == "3D"
    assert by_origin["log"] == "TextLog"
    for origin in (
        "metrics/position_error_m",
        "metrics/attitude_error_rad",
        "metrics/force_N",
        "metrics/torque_Nm",
        "metrics/solve_time_ms",
    ):
        assert by_origin[origin] == "TimeSeries", origin
    names = " ".join(str(v["name"]) for v in views)
    for unit in ("[m]", "[rad]", "[N]", "[N·m]", "[ms]"):
        assert unit in names


def test_track_blueprint_builds():
    bp = track_blueprint()
    assert bp.root_container is not None


def test_track_140s_run_writes_fast(tmp_path):
    """A 140 s run: 62.5 Hz truth (8751 samples) and 5 Hz control (701 steps) must write in well under 2 s."""
    run = _synthetic(duration_s=140.0)
    assert run["x_true"].shape == (8751, 13) and run["t_ctrl"].shape == (701,)
    path = tmp_path / "track.rrd"
    kwargs = _kwargs(run)
    start = time.perf_counter()
    write_track_recording(path, **kwargs)
    elapsed = time.perf_counter() - start
    assert elapsed < 2.0, f"writing took {elapsed:.2f} s"
    s = read_recording_scalars(path)
    assert s["metrics/force_N"][1].shape == (701, 3)
    times, _ = read_recording_component(path, "world/robot", "Transform3D:translation")
    assert times.shape == (8751,)


# ---------------------------------------------------------------------------------------------------------------
# Atomic writing and failures
# ---------------------------------------------------------------------------------------------------------------


def test_failure_mid_write_leaves_no_final_file(tmp_path, run, monkeypatch):
    original = rr.RecordingStream.disconnect

    def disconnect_then_fail(self):
        original(self)  # the temporary file is now complete ...
        raise OSError("disk full")  # ... but something fails before the rename

    monkeypatch.setattr(rr.RecordingStream, "disconnect", disconnect_then_fail)
    path = tmp_path / "track.rrd"
    with pytest.raises(OSError, match="disk full"):
        write_track_recording(path, **_kwargs(run))
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []  # the temporary file is gone too


def test_failed_save_keeps_previous_file(tmp_path, run, monkeypatch):
    path = tmp_path / "track.rrd"
    write_track_recording(path, **_kwargs(run))
    before = read_recording_scalars(path)["metrics/position_error_m"][1]

    def fail(*args, **kwargs):
        raise RuntimeError("truncated")

    monkeypatch.setattr(rerun_writer, "_check_complete", fail)
    changed = dict(run, position_error_m=run["position_error_m"] + 1.0)
    with pytest.raises(RuntimeError, match="truncated"):
        write_track_recording(path, **_kwargs(changed))
    np.testing.assert_array_equal(read_recording_scalars(path)["metrics/position_error_m"][1], before)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["track.rrd"]


def test_bad_shapes_raise_before_writing(tmp_path, run):
    path = tmp_path / "track.rrd"
    with pytest.raises(ValueError, match="position_error_m"):
        write_track_recording(path, **_kwargs(dict(run, position_error_m=run["position_error_m"][:-1])))
    with pytest.raises(ValueError, match="torque_limit_Nm"):
        write_track_recording(path, **dict(_kwargs(run), limits=SimpleNamespace(force_N=np.ones(3),
                                                                                  torque_Nm=np.ones(2))))
    x_true = run["x_true"].copy()
    x_true[5, 6:10] = 0.0  # a zero quaternion cannot be drawn
    with pytest.raises(ValueError, match="world/robot"):
        write_track_recording(path, **_kwargs(dict(run, x_true=x_true)))
    assert list(tmp_path.iterdir()) == []


def test_truncated_recording_is_an_input_error(tmp_path, track_rrd):
    data = track_rrd.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="cannot read"):
        read_recording_scalars(cut)
    with pytest.raises(InputError, match="does not exist"):
        read_recording_entities(tmp_path / "missing.rrd")


# ---------------------------------------------------------------------------------------------------------------
# StageRecording as a building block
# ---------------------------------------------------------------------------------------------------------------


def test_save_is_final(tmp_path):
    rec = StageRecording(recording_name="plan")
    rec.log_text(0.0, "info", "hello")
    rec.save(tmp_path / "a.rrd")
    with pytest.raises(RuntimeError, match="already saved"):
        rec.log_text(1.0, "info", "too late")
    with pytest.raises(RuntimeError, match="already saved"):
        rec.save(tmp_path / "b.rrd")
    assert not (tmp_path / "b.rrd").exists()
    times, texts = read_recording_component(tmp_path / "a.rrd", "log", "TextLog:text")
    assert texts[0].tolist() == ["hello"] and times.tolist() == [0.0]


def _os_threads() -> int:
    """Number of OS threads of this process (Rerun's are native: ``threading`` does not see them)."""
    return len(os.listdir(f"/proc/{os.getpid()}/task"))


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc to count the process's OS threads")
def test_saved_recordings_leave_no_threads_behind(tmp_path):
    """Saving joins the stream's threads: 20 recordings in one process (a campaign worker flies hundreds) end
    with the threads they started with (before the fix, +2 per recording: 40 here)."""
    warm = StageRecording(recording_name="warm-up")
    warm.log_text(0.0, "info", "x")
    warm.save(tmp_path / "warm.rrd")
    del warm
    before = _os_threads()
    for k in range(20):
        rec = StageRecording(recording_name=f"r{k}")
        rec.log_series("metrics/a", np.linspace(0.0, 1.0, 5), np.arange(5.0))
        rec.save(tmp_path / f"r{k}.rrd")
        del rec
    assert _os_threads() <= before + 2
    _, values = read_recording_scalars(tmp_path / "r19.rrd")["metrics/a"]
    np.testing.assert_array_equal(values.ravel(), np.arange(5.0))


def test_saved_recordings_with_a_blueprint_leave_no_threads_behind(tmp_path):
    """The default layout goes in through a blueprint stream of its own: saving joins that stream's threads too
    (before the fix, +2 per recording with ``rr.send_blueprint``: a campaign worker held 860 threads after 50
    missions), and the file still carries the layout as its application's default."""
    layout = rrb.Blueprint(rrb.TimeSeriesView(origin="metrics", name="metrics"))
    warm = StageRecording(recording_name="warm-up")
    warm.log_text(0.0, "info", "x")
    warm.save(tmp_path / "warm.rrd", layout)
    del warm
    before = _os_threads()
    for k in range(10):
        rec = StageRecording(recording_name=f"r{k}")
        rec.log_series("metrics/a", np.linspace(0.0, 1.0, 5), np.arange(5.0))
        rec.save(tmp_path / f"r{k}.rrd", layout)
        del rec
    assert _os_threads() <= before + 2
    # the same layout as Rerun's own rr.send_blueprint writes
    reference = rr.RecordingStream("oacli", recording_id="reference")
    sink = rr.binary_stream(recording=reference)
    rr.send_blueprint(layout, make_active=False, make_default=True, recording=reference)
    reference.flush()
    (tmp_path / "reference.rrd").write_bytes(sink.read(flush=True) or b"")
    views = read_blueprint_views(tmp_path / "r9.rrd")
    assert views == read_blueprint_views(tmp_path / "reference.rrd")
    assert [v["origin"] for v in views] == ["metrics"]
    _, values = read_recording_scalars(tmp_path / "r9.rrd")["metrics/a"]
    np.testing.assert_array_equal(values.ravel(), np.arange(5.0))


def test_two_recordings_are_independent(tmp_path):
    """Each StageRecording has its own stream: nothing leaks between files (or into the global recording)."""
    a = StageRecording(recording_name="a")
    b = StageRecording(recording_name="b")
    t = np.linspace(0.0, 1.0, 11)
    a.log_series("metrics/a", t, t**2)
    b.log_series("metrics/b", t, np.column_stack([t, -t]), names=["up", "down"])
    a.log_path("world/plan/path", np.array([[0.0, 0, 0], [1, 1, 1], [2, 0, 1]]))
    b.save(tmp_path / "b.rrd")
    a.save(tmp_path / "a.rrd")
    assert read_recording_entities(tmp_path / "a.rrd") == {"metrics/a", "world/plan/path"}
    assert read_recording_entities(tmp_path / "b.rrd") == {"metrics/b"}
    ta, va = read_recording_scalars(tmp_path / "a.rrd")["metrics/a"]
    np.testing.assert_allclose(ta, t, atol=T_ATOL)
    np.testing.assert_allclose(va, t**2)
    _, vb = read_recording_scalars(tmp_path / "b.rrd")["metrics/b"]
    np.testing.assert_allclose(vb, np.column_stack([t, -t]))
    _, names = read_recording_component(tmp_path / "b.rrd", "metrics/b", "SeriesLines:names")
    assert names[-1].tolist() == ["up", "down"]
    assert RrdReader(tmp_path / "a.rrd").blueprints() == []  # no blueprint given, none stored
    assert rr.get_global_data_recording() is None


def test_times_round_to_nanoseconds(tmp_path):
    """Rerun truncates float seconds to ns; oacli rounds, so 0.7 s stays 0.7 s."""
    rec = StageRecording()
    t = np.array([0.1, 0.3, 0.7, 1.1, 2.9, 139.984])
    rec.log_series("metrics/v", t, np.arange(6.0))
    rec.save(tmp_path / "r.rrd")
    times, values = read_recording_scalars(tmp_path / "r.rrd")["metrics/v"]
    np.testing.assert_array_equal(np.rint(times * 1e9).astype(np.int64), np.rint(t * 1e9).astype(np.int64))
    np.testing.assert_array_equal(values, np.arange(6.0))


def test_log_series_checks_shapes():
    rec = StageRecording()
    t = np.arange(4.0)
    with pytest.raises(ValueError, match="2 names"):
        rec.log_series("m", t, np.zeros((4, 3)), names=["a", "b"])
    with pytest.raises(ValueError, match="expected values"):
        rec.log_series("m", t, np.zeros(5))
    with pytest.raises(ValueError, match="limits"):
        rec.log_series("m", t, np.zeros((4, 3)), limits=np.ones(2))
    with pytest.raises(ValueError, match="finite"):
        rec.log_series("m", np.array([0.0, np.nan, 2, 3]), np.zeros(4))


def test_segments_points_and_timed_paths(tmp_path):
    rec = StageRecording(recording_name="plan")
    rec.log_scene(Scene())  # empty scene: both entities exist, with no shapes
    starts = np.array([[0.0, 0, 0], [1, 0, 0]])
    ends = np.array([[1.0, 0, 0], [1, 1, 0]])
    rec.log_segments("world/plan/tree", starts, ends)
    rec.log_points("world/plan/samples", ends, labels=["a", "b"])
    rec.log_path("world/plan/mpc", starts, static=False, t=2.5)
    with pytest.raises(ValueError, match="needs a time"):
        rec.log_path("world/plan/mpc", starts, static=False)
    rec.save(tmp_path / "plan.rrd")
    path = tmp_path / "plan.rrd"
    _, strips = read_recording_component(path, "world/plan/tree", "LineStrips3D:strips")
    np.testing.assert_allclose(np.array(strips[-1].tolist(), dtype=float), np.stack([starts, ends], axis=1))
    _, pts = read_recording_component(path, "world/plan/samples", "Points3D:positions")
    np.testing.assert_allclose(pts[-1], ends)
    times, _ = read_recording_component(path, "world/plan/mpc", "LineStrips3D:strips")
    np.testing.assert_allclose(times, [2.5], atol=T_ATOL)
    _, half = read_recording_component(path, "world/keep_out", "Ellipsoids3D:half_sizes")
    assert half[-1].shape == (0, 3)
