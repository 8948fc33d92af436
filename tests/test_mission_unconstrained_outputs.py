"""A mission with ``mission.unconstrained_baseline`` (the study presets' Fig. 3(d) missions) shows its fourth
segment-3 flight, the standard MPC without workspace constraints, wherever the other two baselines appear: in
``mission.mcap`` (and the shipped Foxglove layout), ``mission.rrd``, the mission's tracking-error plot, and
``report.html`` (its table and its
tracking figure); each read back from the files.

Cheap: the shrunk default mission of ``conftest.mission_run`` is copied with the option switched on in its
``config.yaml`` and resumed, so only the new flight flies (its seed is its own: ``oacli.mission.layout.ALL_STAGES``),
then the mission's outputs are written again.
"""

from __future__ import annotations

import base64
import io
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from typer.testing import CliRunner

from oacli.cli import app
from oacli.io.mcap_io import read_stage, read_telemetry
from oacli.io.rerun.read import read_blueprint_views, read_recording_entities, read_recording_scalars
from oacli.metrics import true_states_at
from oacli.mission.layout import BASELINES, FLIGHT_LABELS, UNCONSTRAINED_BASELINE, stage_by_key
from oacli.report.build import fmt

KEY = UNCONSTRAINED_BASELINE
OLIVE = np.array([188, 189, 34])  # matplotlib's tab:olive, the flight's colour in the PNGs


@pytest.fixture(scope="module")
def unconstrained(mission_run, tmp_path_factory) -> tuple[Path, Path]:
    """(the shared mission, its copy resumed with the unconstrained baseline)."""
    source = mission_run[0]
    run = tmp_path_factory.mktemp("unconstrained") / "run"
    shutil.copytree(source, run)
    data = yaml.safe_load((run / "config.yaml").read_text())
    assert data["mission"]["baselines"] and not data["mission"].get("unconstrained_baseline")
    data["mission"]["unconstrained_baseline"] = True
    (run / "config.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    for name in ("summary.json", "mission.rrd", "mission.mcap", "report.html"):
        (run / name).unlink(missing_ok=True)
    shutil.rmtree(run / "plots")
    result = CliRunner().invoke(app, ["mission", str(run), "--resume", "--quiet"])
    assert result.exit_code == 0, result.output
    return source, run


def _olive_pixels(png: bytes) -> int:
    """Pixels within a small distance of tab:olive (anti-aliased line centres keep the colour)."""
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    return int((np.abs(rgb - OLIVE).max(axis=2) <= 12).sum())


def test_the_flight_flew_and_is_in_the_summary(unconstrained):
    source, run = unconstrained
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] in ("ok", "degraded")
    assert summary["stages"][KEY]["status"] in ("ok", "degraded", "unsafe")
    row = summary["comparison"][KEY]
    assert row["label"] == FLIGHT_LABELS[KEY] and row["rms_position_error_m"] > 0
    stage_cfg = yaml.safe_load((stage_by_key(KEY).folder(run) / "config.yaml").read_text())
    assert stage_cfg["controller"]["position_constraints"] is False  # the paper's standard MPC
    # the other flights were not flown again
    for key in BASELINES:
        assert (stage_by_key(key).mcap(run).read_bytes() == stage_by_key(key).mcap(source).read_bytes()), key


def test_mission_mcap_holds_the_flight_on_the_mission_clock(unconstrained):
    _, run = unconstrained
    summary = json.loads((run / "summary.json").read_text())
    start_ns = round(summary["segments"]["segment-3"]["start_time_s"] * 1e9)
    stage_times: dict[str, list[int]] = {}
    with stage_by_key(KEY).mcap(run).open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.topic != "/log":
                stage_times.setdefault(channel.topic, []).append(message.log_time)
    mission_times: dict[str, list[int]] = {}
    with (run / "mission.mcap").open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        info = next(m.metadata for m in reader.iter_metadata() if m.name == "oacli")
        for _, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic.startswith(f"/{KEY}/"):
                assert channel.metadata["stage"] == KEY
                mission_times.setdefault(channel.topic[len(KEY) + 1:], []).append(message.log_time)
    assert "/state/true" in stage_times and "/control/applied" in stage_times
    assert set(mission_times) == set(stage_times)
    for topic, times in stage_times.items():  # every message, shifted by segment 3's start
        assert sorted(mission_times[topic]) == sorted(t + start_ns for t in times), topic
    offsets = json.loads(info["offsets_s"])
    assert offsets[KEY] == offsets["segment-3/baseline-mpc-prior"] == summary["segments"]["segment-3"]["start_time_s"]


def test_the_shipped_foxglove_layout_shows_the_flight(unconstrained):
    """docs/foxglove/mission.json names the flight's scene, pose, position and force; all of them, and every other
    name of the layout, are in this mission's ``mission.mcap``."""
    from tests.test_foxglove_layouts import DOCS, _first_messages, check_layout

    _, run = unconstrained
    layout = json.loads((DOCS / "mission.json").read_text())
    text = json.dumps(layout)
    for name in (f"/{KEY}/scene", f"/{KEY}/robot/pose", f"/{KEY}/state/true.position[0]",
                 f"/{KEY}/control/applied.force[2]"):
        assert f'"{name}"' in text, name
    check_layout("mission", layout, _first_messages(run / "mission.mcap"))


def test_mission_rrd_shows_the_flight_beside_the_baselines(unconstrained):
    source, run = unconstrained
    summary = json.loads((run / "summary.json").read_text())
    rrd = run / "mission.rrd"
    scalars = read_recording_scalars(rrd)
    t, err = scalars[f"metrics/position_error/{KEY}"]
    tel = read_telemetry(stage_by_key(KEY).mcap(run))
    ref = read_stage(stage_by_key(KEY).mcap(run), topics=["/reference"]).trajectories["/reference"]
    np.testing.assert_allclose(t, tel.t_ctrl + summary["segments"]["segment-3"]["start_time_s"], atol=1e-9)
    np.testing.assert_allclose(err, np.linalg.norm(true_states_at(tel, tel.t_ctrl)[:, 0:3] - ref.x[:, 0:3], axis=1),
                               atol=1e-12)
    _, frac = scalars[f"metrics/force_fraction/{KEY}"]
    limit = np.asarray(yaml.safe_load((stage_by_key(KEY).folder(run) / "config.yaml").read_text())["robot"]
                       ["force_limit_N"])
    np.testing.assert_allclose(frac, np.max(np.abs(tel.u_applied[:, 0:3]) / limit, axis=1), rtol=1e-6)
    entities = read_recording_entities(rrd)
    assert {f"world/{KEY}/actual", f"world/{KEY}/robot"} <= entities
    assert f"world/{KEY}/tube" not in entities  # standard MPC: no tube
    names = [v["name"] or "" for v in read_blueprint_views(rrd) if v["class"] == "3D"]
    assert any(f"{FLIGHT_LABELS[KEY]} (olive)" in n for n in names), names
    # the default mission's recording does not name a flight it did not fly
    assert f"metrics/position_error/{KEY}" not in read_recording_scalars(source / "mission.rrd")
    assert not any("(olive)" in (v["name"] or "") for v in read_blueprint_views(source / "mission.rrd"))


def test_plots_and_report_show_the_flight(unconstrained):
    source, run = unconstrained
    summary = json.loads((run / "summary.json").read_text())
    # the tracking-error plot: the olive line of the new flight (none in the default mission's)
    rel = summary["files"]["plots"]["tracking_error"]
    assert _olive_pixels((run / rel).read_bytes()) > 200
    assert _olive_pixels((source / rel).read_bytes()) == 0
    # the report: the comparison table's fourth row with its figures, and the olive line in its tracking figure
    text = (run / "report.html").read_text()
    assert "Segment 3 flown 4 ways" in text
    row = summary["comparison"][KEY]
    table = text[text.index('id="comparison-table"'):]
    table = table[:table.index("</table>")]
    assert FLIGHT_LABELS[KEY] in table
    assert f"<td>{fmt(1e3 * row['rms_position_error_m'])}</td><td>{fmt(1e3 * row['max_position_error_m'])}</td>" \
           f"<td>{fmt(1e3 * row['overshoot_m'])}</td>" in table
    pngs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    tracking = base64.b64decode(pngs[0])  # the tube-band figure comes first
    assert _olive_pixels(tracking) > 200
    assert _olive_pixels(base64.b64decode(re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"',
                                                   (source / "report.html").read_text())[0])) == 0
