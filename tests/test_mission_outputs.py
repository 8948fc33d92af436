"""The mission's recording (``mission.rrd``) and PNG plots, written by ``oacli mission`` on the shrunk default
mission (the session fixture ``mission_run`` of conftest.py), read back and checked against the stage MCAPs."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from oacli.io.mcap_io import read_stage, read_telemetry
from oacli.io.rerun.read import (
    read_blueprint_views,
    read_recording_component,
    read_recording_entities,
    read_recording_scalars,
)
from oacli.metrics import true_states_at
from oacli.mission.layout import BASELINES, stage_by_key
from oacli.mission.recording import APPLICATION_ID

PARAMS = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")


@pytest.fixture(scope="module")
def mission(mission_run) -> tuple[Path, dict]:
    mission_dir = mission_run[0]
    return mission_dir, json.loads((mission_dir / "summary.json").read_text())


def test_recording_is_one_mission_timeline(mission):
    mission_dir, summary = mission
    rrd = mission_dir / "mission.rrd"
    from rerun.chunk import RrdReader

    (store,) = RrdReader(rrd).recordings()
    assert store.application_id == APPLICATION_ID
    scalars = read_recording_scalars(rrd)  # on the mission_time timeline
    seg3 = summary["segments"]["segment-3"]
    seg3_end = seg3["start_time_s"] + seg3["duration_s"]
    t_max = max(t[-1] for t, _ in scalars.values())
    assert t_max >= seg3_end - 0.5
    # each flight's error series starts at its segment's offset and equals ‖r_true − r_ref‖ of its MCAP
    for key in ("segment-1/track", "segment-2/track", *BASELINES):
        t, err = scalars[f"metrics/position_error/{key}"]
        tel = read_telemetry(stage_by_key(key).mcap(mission_dir))
        offset = summary["segments"][key.split("/")[0]]["start_time_s"]
        np.testing.assert_allclose(t, tel.t_ctrl + offset, atol=1e-9)
        x_at = true_states_at(tel, tel.t_ctrl)  # the true state at the control instants themselves
        ref = read_stage(stage_by_key(key).mcap(mission_dir), topics=["/reference"]).trajectories["/reference"]
        np.testing.assert_allclose(err, np.linalg.norm(x_at[:, 0:3] - ref.x[:, 0:3], axis=1), atol=1e-12)
    # the grasp happens at grasp_time_s
    t_grasp, _ = read_recording_component(rrd, "world/grasp", "Points3D:positions")
    assert t_grasp is not None and t_grasp[0] == pytest.approx(summary["grasp_time_s"], abs=1e-9)
    t_log, texts = read_recording_component(rrd, "log", "TextLog:text")
    assert any("grasp" in str(m[0]) and abs(t - summary["grasp_time_s"]) < 1e-9 for t, m in zip(t_log, texts,
                                                                                                   strict=True))


def test_every_blueprint_view_shows_data(mission):
    mission_dir, _ = mission
    rrd = mission_dir / "mission.rrd"
    views = read_blueprint_views(rrd)
    entities = read_recording_entities(rrd)
    assert {v["class"] for v in views} >= {"3D", "TimeSeries", "TextLog"}
    assert len([v for v in views if v["class"] == "3D"]) == 2  # the mission, and segment 3's flights side by side
    for view in views:
        origin = view["origin"].strip("/")
        assert any(e == origin or e.startswith(origin + "/") for e in entities), view
    scalars = read_recording_scalars(rrd)
    for view in views:
        if view["class"] == "TimeSeries":
            origin = view["origin"].strip("/")
            assert any(k == origin or k.startswith(origin + "/") for k in scalars), view
    for key in (*BASELINES, "segment-1/track", "segment-2/track"):
        assert f"world/{key}/actual" in entities and f"world/{key}/robot" in entities
    for key in ("segment-2/track", "segment-3/track", "segment-3/baseline-tube-prior"):
        assert f"world/{key}/tube" in entities  # tube MPC flights
    assert "world/segment-3/baseline-mpc-prior/tube" not in entities  # standard MPC: no tube
    for seg in ("segment-1", "segment-3"):
        _, rows = read_recording_component(rrd, f"world/{seg}/plan/tree", "LineStrips3D:strips")
        nodes = read_stage(stage_by_key(f"{seg}/plan").mcap(mission_dir),
                           topics=["/plan/tree"]).json_records["/plan/tree"]
        assert len(rows[0]) == len(nodes) - 1  # one edge per node but the root
    # inputs against the limits of each flight's config
    _, force = scalars["metrics/force_N"]
    _, upper = scalars["metrics/force_N/limit_upper"]
    assert force.shape[1] == 3 and np.all(upper > 0) and np.all(np.abs(force) <= upper.max(axis=0) * (1 + 1e-6))


def test_estimate_bands_are_the_mcap_two_sigma(mission):
    mission_dir, summary = mission
    scalars = read_recording_scalars(mission_dir / "mission.rrd")
    offset = summary["segments"]["segment-2"]["start_time_s"]
    for key, method in (("segment-2/estimate-sequential", "sequential"), ("segment-2/estimate", "batch")):
        params = read_stage(stage_by_key(key).mcap(mission_dir),
                            topics=["/estimate/params"]).json_records["/estimate/params"]
        theta = np.array([[p["mass_kg"], *p["inertia_kgm2"]] for p in params])
        std = np.array([p["std"] for p in params], dtype=float)
        for i, name in enumerate(PARAMS):
            t, value = scalars[f"estimate/{name}/{method}"]
            _, upper = scalars[f"estimate/{name}/{method}/upper_2sigma"]
            _, lower = scalars[f"estimate/{name}/{method}/lower_2sigma"]
            np.testing.assert_allclose(t, np.array([p["t"] for p in params]) + offset, atol=1e-9)
            np.testing.assert_array_equal(value, theta[:, i])
            np.testing.assert_allclose(upper - value, 2 * std[:, i], rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(value - lower, 2 * std[:, i], rtol=1e-9, atol=1e-15)
            _, truth = scalars[f"estimate/{name}/truth"]
            np.testing.assert_array_equal(truth, summary["estimate"]["truth_theta"][i])


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", path
    assert data[-8:-4] == b"IEND", path  # complete file
    return struct.unpack(">II", data[16:24])


def _mission_pngs(mission_dir: Path) -> list[str]:
    """The PNGs in plots/ but the report's kept tracking figure (oacli.report.mission.BANDS_PNG, written with the
    mission's report.html)."""
    from oacli.report.mission import BANDS_PNG

    return [p.name for p in (mission_dir / "plots").iterdir() if p.name != Path(BANDS_PNG).name]


def test_plots_are_valid_pngs(mission):
    mission_dir, summary = mission
    files = {name: mission_dir / rel for name, rel in summary["files"]["plots"].items()}   # written by the runner
    assert set(files) == {"tracking_error", "estimate_convergence", "paths"}
    for name, path in files.items():
        assert path == mission_dir / "plots" / f"{name}.png"
        width, height = _png_size(path)
        assert 600 <= width <= 3000 and 400 <= height <= 3000, (name, width, height)
        assert path.stat().st_size > 20_000, name  # drawn, not blank
    assert sorted(_mission_pngs(mission_dir)) == sorted(f"{n}.png" for n in files)


def test_mission_plots_are_laid_out_within_the_figure_without_overlaps(mission, tmp_path, monkeypatch):
    """The fixed layout (oacli.io.plots.common.fixed_layout) leaves room for every title, label and legend."""
    import oacli.io.plots.common as plot_common
    import oacli.mission.plots as mission_plots
    from tests.test_stage_plots import layout_problems

    mission_dir, summary = mission
    problems: dict[str, list[str]] = {}
    real_save = mission_plots.save_png

    def check(fig, path):
        plot_common.lay_out(fig)  # as save_png lays it out
        fig.canvas.draw()
        problems[Path(path).name] = layout_problems(fig)
        return real_save(fig, path)

    monkeypatch.setattr(mission_plots, "save_png", check)
    written = mission_plots.write_mission_plots(mission_dir, summary, out_dir=tmp_path)
    assert sorted(p.name for p in written.values()) == sorted(problems) == sorted(_mission_pngs(mission_dir))
    assert {k: v for k, v in problems.items() if v} == {}


def test_cached_reads_follow_the_file(mission, tmp_path):
    """The mission's read cache returns the same object while a file is unchanged and reads it again when a stage
    rewrites it (--resume / --from): the files stay the source of truth."""
    import shutil

    from oacli.mission import records

    mission_dir, _ = mission
    path = tmp_path / "track.mcap"
    shutil.copyfile(stage_by_key("segment-1/track").mcap(mission_dir), path)
    first = records.read_telemetry_cached(path)
    assert records.read_telemetry_cached(path) is first
    np.testing.assert_array_equal(first.x_true, read_telemetry(path).x_true)
    shutil.copyfile(stage_by_key("segment-3/track").mcap(mission_dir), path)  # a rerun stage's new file
    second = records.read_telemetry_cached(path)
    assert second is not first
    np.testing.assert_array_equal(second.x_true, read_telemetry(path).x_true)
    stage = records.read_stage_cached(path, topics=["/reference"])
    assert records.read_stage_cached(path, topics=["/reference"]) is stage
    assert records.read_stage_cached(path, topics=["/log"]) is not stage  # per topic set
    records.CACHE = False
    try:
        assert records.read_telemetry_cached(path) is not records.read_telemetry_cached(path)
    finally:
        records.CACHE = True
