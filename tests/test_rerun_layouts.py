"""Layouts that cannot mislead: convergence charts framed on their values, 3-D cameras framed on the
path, view titles that follow the world frame, the campaign's layout, and ``--view`` failing loudly.

Values are read back from the written ``.rrd`` files (:mod:`oacli.io.rerun.read`); the cameras are checked by
geometry (every framed point inside the field of view).
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest
import rerun as rr
from typer.testing import CliRunner

from oacli.cli import app
from oacli.io.rerun.campaign import HISTOGRAMS, RUN_TIMELINE, STATUS, histogram, write_campaign_recording
from oacli.io.rerun.chart import HEIGHT, WIDTH, log_line_chart
from oacli.io.rerun.layout import EYE_UP, framed_eye
from oacli.io.rerun.read import (
    read_blueprint_timeline,
    read_blueprint_views,
    read_recording_component,
    read_recording_entities,
    read_recording_scalars,
)
from oacli.io.rerun.track import write_track_recording
from oacli.io.rerun.writer import StageRecording
from tests.test_cli_plan_smooth import small_config
from tests.test_rerun_io import _kwargs, _synthetic


def _bar_values(path, entity: str) -> np.ndarray:
    """The values of a static ``BarChart`` (a tensor: read its buffer)."""
    from rerun.chunk import RrdReader

    for ch in RrdReader(path).stream().filter(content=f"/{entity}", components="BarChart:values"):
        batch = ch.to_record_batch()
        if "BarChart:values" in batch.schema.names:
            (row,) = batch.column("BarChart:values").to_pylist()
            return np.asarray(row[0]["buffer"], dtype=float)
    raise KeyError(entity)


def _vec(batch) -> np.ndarray:
    return np.asarray(batch.as_arrow_array().to_pylist(), dtype=float).reshape(3)


@pytest.mark.parametrize("seed", range(5))
def test_camera_frames_every_point_in_a_60_degree_view(seed):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(50, 3)) * rng.uniform(0.05, 3.0, size=3) + rng.uniform(-10, 10, size=3)
    eye = framed_eye(pts)
    position, target = _vec(eye.position), _vec(eye.look_target)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    np.testing.assert_allclose(target, 0.5 * (lo + hi), atol=1e-9)
    axis = (target - position) / np.linalg.norm(target - position)
    rays = pts - position
    angles = np.degrees(np.arccos(np.clip(rays @ axis / np.linalg.norm(rays, axis=1), -1, 1)))
    assert angles.max() < 30.0  # inside the field of view
    # ... and the path fills it: the bounding sphere spans 1/1.25 of the half-angle's sine (not a dot in the JEM)
    radius = max(0.5 * np.linalg.norm(hi - lo), 0.35)
    assert radius / np.linalg.norm(target - position) == pytest.approx(np.sin(np.radians(30)) / 1.25)
    assert _vec(eye.eye_up) @ np.array(EYE_UP) == pytest.approx(1.0)
    assert position[2] < target[2]  # looking down on the path: above is -z in the z-down world frames


def test_track_view_title_follows_the_world_frame(tmp_path):
    run = _synthetic(duration_s=4.0)
    kwargs = _kwargs(run)
    kwargs["scene"] = dataclasses.replace(kwargs["scene"], frame="assembly_bay")
    for controller in ("mpc",):
        path = tmp_path / f"{controller}.rrd"
        write_track_recording(path, **kwargs, controller=controller)
        (world,) = [v for v in read_blueprint_views(path) if v["class"] == "3D"]
        assert str(world["name"]).startswith("World (assembly_bay frame)"), world
        assert "ISS" not in str(world["name"]) and "iss" not in str(world["name"])


def _chart(tmp_path, x, y):
    rec = StageRecording("oacli-test", "chart")
    log_line_chart(rec.stream, "charts/c", np.asarray(x), np.asarray(y), color=(255, 0, 0), x_name="it",
                   y_name="cost")
    path = tmp_path / "chart.rrd"
    rec.save(path)
    _, (strips,) = read_recording_component(path, "charts/c/line", "LineStrips2D:strips")
    _, (labels,) = read_recording_component(path, "charts/c/ticks", "Points2D:labels")
    return strips[0], list(labels)


def test_line_chart_is_the_series_framed_on_its_range(tmp_path):
    x = np.array([3, 10, 40, 90, 150, 151])
    y = np.array([4.71, 3.9, np.nan, 3.0, 2.95, 2.93])
    line, labels = _chart(tmp_path, x, y)
    keep = np.isfinite(y)
    np.testing.assert_allclose(line[:, 0], WIDTH * (x[keep] - 3) / 148, atol=1e-6)
    # y framed on [2.93, 4.71] (not from 0): the 4.71 -> 2.93 fall spans the chart's height; y points down in 2-D
    np.testing.assert_allclose(-line[:, 1], HEIGHT * (y[keep] - 2.93) / (4.71 - 2.93), atol=1e-6)
    assert labels == ["cost 4.71", "cost 2.93", "it 3", "it 151"]


def test_line_chart_of_one_value_has_one_tick_per_axis(tmp_path):
    line, labels = _chart(tmp_path, [2], [3.949])
    assert line.shape == (1, 2) and labels == ["cost 3.949", "it 2"]


def test_campaign_recording_shows_points_per_run_status_and_histograms(tmp_path):
    rng = np.random.default_rng(1)
    ks = np.array([0, 1, 2, 4, 5, 6, 7])
    rms = rng.uniform(1.0, 5.0, ks.size)
    series = {"rms_position_error_mm": (ks, rms), "violations": (ks, np.zeros(ks.size)),
              "estimate_error_pct/mass": (ks, rng.normal(size=ks.size))}
    runs = {int(k): ("ok" if k % 2 else "degraded", None) for k in ks}
    runs[3] = ("failed", "solver crashed")
    path = tmp_path / "campaign.rrd"
    write_campaign_recording(path, series, runs, "tiny")

    assert read_blueprint_timeline(path) == RUN_TIMELINE
    scalars = read_recording_scalars(path, timeline=RUN_TIMELINE)
    for key, (k, v) in series.items():
        np.testing.assert_array_equal(scalars[f"campaign/{key}"][0], k)
        np.testing.assert_allclose(scalars[f"campaign/{key}"][1], v)
        # drawn as points (independent runs are not joined by lines)
        read_recording_component(path, f"campaign/{key}", "SeriesPoints:marker_sizes")
        with pytest.raises(KeyError):
            read_recording_component(path, f"campaign/{key}", "SeriesLines:widths")
        counts = _bar_values(path, f"{HISTOGRAMS}/{key}")
        np.testing.assert_array_equal(counts, histogram(v)[1])
        assert np.sum(counts) == ks.size
    t, states = read_recording_component(path, STATUS, "StateChange:state", timeline=RUN_TIMELINE)
    assert list(t) == sorted(runs) and [s[0] for s in states] == [runs[k][0] for k in sorted(runs)]
    # every logged entity is in a panel, and the panels have readable names
    views = read_blueprint_views(path)
    origins = [str(v["origin"]).strip("/") for v in views]
    for entity in read_recording_entities(path):
        if entity.startswith("__") or entity == "":
            continue
        assert any(entity == o or entity.startswith(o + "/") for o in origins), entity
    names = {str(v["name"]) for v in views}
    assert {"RMS position error [mm] per run", "mass estimate error [%]: runs per bin"} <= names


def test_histogram_counts_every_finite_value():
    values = np.array([1.0, 2.0, 2.0, np.nan, 7.0, np.inf])
    centres, counts, width = histogram(values, bins=3)
    assert counts.sum() == 4 and centres.shape == (3,) and width == pytest.approx(2.0)
    np.testing.assert_allclose(np.diff(centres), width)
    assert histogram(np.full(4, 2.5))[1].sum() == 4  # one value: a bin around it


@pytest.fixture(scope="module")
def s1(tmp_path_factory):
    return small_config(tmp_path_factory.mktemp("s1"), max_iterations=100, shortcut={"tries": 10})


def test_view_without_a_display_says_so_and_exits_1(s1, tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    result = CliRunner().invoke(app, ["plan", str(s1), "--out", str(tmp_path / "run"), "--quiet", "--view"])
    assert result.exit_code == 1, result.output
    assert "no display" in result.stderr and "plan.rrd" in result.stderr
    assert (tmp_path / "run" / "summary.json").is_file()  # the run itself is complete


def test_view_reports_a_viewer_that_dies_at_once(s1, tmp_path, monkeypatch):
    import oacli.commands.view as view

    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(view, "viewer_command", lambda rrd: [sys.executable, "-c",
                                                             "import sys; sys.stderr.write('cannot open display');"
                                                             " sys.exit(3)"])
    result = CliRunner().invoke(app, ["plan", str(s1), "--out", str(tmp_path / "run"), "--quiet", "--view"])
    assert result.exit_code == 1, result.output
    assert "exited with code 3: cannot open display" in result.stderr


def test_view_of_a_live_viewer_returns_it(tmp_path, monkeypatch):
    import oacli.commands.view as view

    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(view, "STARTUP_WATCH_S", 0.3)
    monkeypatch.setattr(view, "viewer_command", lambda rrd: [sys.executable, "-c", "import time; time.sleep(5)"])
    (tmp_path / "x.rrd").write_bytes(b"")
    proc = view.open_in_viewer(tmp_path)
    try:
        assert proc is not None and proc.poll() is None
    finally:
        proc.kill()
        proc.wait()


def test_rerun_sdk_still_has_the_state_timeline_view():
    import rerun.blueprint as rrb

    assert hasattr(rrb, "StateTimelineView") and hasattr(rr, "StateChange")
