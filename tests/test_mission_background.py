"""The stages a mission runs beside the flight (:mod:`oacli.mission.background`) change its wall time only.

The shared mission (``conftest.mission_run``, through the CLI: on a machine with two cores its calibration,
sequential estimate, baselines and ``mission.mcap`` run in the background process) is compared with the same mission
run with ``--in-line``: every stage's summary and the mission's summary equal (timings and paths aside), every
stage MCAP holds the same messages, and ``mission.mcap`` the same messages on the same topics.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

from oacli.cli import app
from oacli.mission.background import BACKGROUND, LAUNCH_BEFORE, BackgroundStages, Outcome, background_workers_default
from oacli.mission.layout import ALL_STAGES, MISSION_STAGES
from tests.test_mission import stable


def _messages(path: Path) -> list[tuple[str, int, object]]:
    """Every message but the log's, JSON ones without their timings and run folder (:func:`stable`)."""
    out: list[tuple[str, int, object]] = []
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.topic.endswith("/log"):
                continue
            data: object = bytes(message.data)
            if channel.message_encoding == "json":
                data = stable(json.loads(message.data), str(path.parents[2]))
            out.append((channel.topic, message.log_time, data))
    return out


@pytest.fixture(scope="module")
def in_line(mission_run, tmp_path_factory):
    _, cfg, _ = mission_run
    out = tmp_path_factory.mktemp("in-line") / "run"
    result = CliRunner().invoke(app, ["mission", str(cfg), "--out", str(out), "--in-line"])
    assert result.exit_code == 0, result.output
    return out, result.output


def test_the_shared_mission_ran_stages_beside_the_flight(mission_run):
    if background_workers_default() == 0:
        pytest.skip("one usable core: oacli mission runs every stage in line here")
    _, _, output = mission_run
    assert "segment-2/estimate-sequential: running estimate beside the flight" in output
    assert "segment-3/baseline-tube-prior: running track beside the flight" in output


def test_in_line_and_beside_the_flight_give_the_same_mission(mission_run, in_line):
    run, _, _ = mission_run
    out, output = in_line
    assert "beside the flight" not in output
    for stage in MISSION_STAGES:
        if not stage.folder(run).exists():
            assert not stage.folder(out).exists(), stage.key
            continue
        a = json.loads((stage.folder(out) / "summary.json").read_text())
        b = json.loads((stage.folder(run) / "summary.json").read_text())
        assert stable(a, str(out)) == stable(b, str(run)), stage.key
        if stage.command in ("track", "estimate"):  # the flown and estimated records, message by message
            assert _messages(stage.mcap(out)) == _messages(stage.mcap(run)), stage.key
    a = json.loads((out / "summary.json").read_text())
    b = json.loads((run / "summary.json").read_text())
    assert stable(a, str(out)) == stable(b, str(run))
    assert a["status"] == b["status"] == "ok"
    topics_a = {t for t, _, _ in _messages(out / "mission.mcap")}
    topics_b = {t for t, _, _ in _messages(run / "mission.mcap")}
    assert topics_a == topics_b and "/segment-2/estimate-sequential/estimate/params" in topics_a


def test_the_mission_forks_its_worker_before_rerun_starts_threads(tmp_path):
    """``oacli mission`` imports rerun (whose runtime starts threads) only after its worker is forked, so the
    worker shares the imported modules instead of importing everything again (checked in a fresh process)."""
    import subprocess
    import sys

    code = ("import os, sys\n"
            "from oacli.commands.mission import mission\n"
            "from oacli.mission.run import run_mission\n"
            "from oacli.mission.background import _fork_safe\n"
            "print(_fork_safe(), 'rerun' in sys.modules)\n"
            "import rerun\n"
            "print(_fork_safe())\n")
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**__import__("os").environ, "PYTHONPATH": str(root)}, cwd=root)
    assert out.stdout.split() == ["True", "False", "False"], out.stdout + out.stderr


def test_background_stages_feed_nothing_the_stages_run_meanwhile_read(mission_run, tmp_path):
    """The table's promise, checked on the shared mission: with a background stage's folder gone, every stage the
    table lets run meanwhile gets the same hand-off and the same config (``handoff_for`` and ``stage_config`` are
    where the chain reads earlier stages)."""
    import dataclasses
    import shutil

    from oacli.config import dump_config, load_config
    from oacli.mission.configs import stage_config
    from oacli.mission.layout import stage_by_key
    from oacli.mission.run import handoff_for, mission_stages

    run, cfg_path, _ = mission_run
    cfg = load_config(cfg_path)
    keys = {s.key for s in mission_stages(cfg)}
    checked = 0
    for key, meanwhile in BACKGROUND.items():
        assert key in {s.key for s in ALL_STAGES}
        if key not in keys:
            continue
        without = tmp_path / key.replace("/", "_")
        shutil.copytree(run, without)
        shutil.rmtree(stage_by_key(key).folder(without))
        for other in sorted(meanwhile & keys):
            stage = stage_by_key(other)
            want, got = handoff_for(cfg, stage, run), handoff_for(cfg, stage, without)
            as_text = [str(dataclasses.asdict(h)).replace(str(d.resolve()), "<RUN>")
                       for h, d in ((want, run), (got, without))]
            assert as_text[0] == as_text[1], (key, other)
            configs = [dump_config(stage_config(cfg, stage, h)).replace(str(d.resolve()), "<RUN>")
                       for h, d in ((want, run), (got, without))]
            assert configs[0] == configs[1], (key, other)
            checked += 1
    assert checked >= 7
    assert set(LAUNCH_BEFORE) <= set(BACKGROUND)
    # A stage launched before a flight of the chain may run while that flight runs (it does not read it).
    assert all(target in BACKGROUND[key] for key, target in LAUNCH_BEFORE.items())


def test_a_crash_in_the_background_is_reported_with_its_stage(tmp_path):
    """A job whose stage raises reports it (kind ``crash``, the traceback), and the worker goes on to the next."""
    from oacli.config import load_config
    from oacli.mission.run import run_one_stage

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "mission_iss.yaml")
    bg = BackgroundStages(cfg, tmp_path / "nothing-here", run_one_stage)
    seen: list[Outcome] = []
    try:
        bg.submit(["segment-2/estimate-sequential"])   # no segment-2/track in the folder: the stage fails
        bg.wait_all(seen.append)
    finally:
        bg.stop()
    assert bg.start_method in ("fork", "spawn")
    assert len(seen) == 1 and seen[0].key == "segment-2/estimate-sequential"
    assert seen[0].kind in ("handled", "error", "crash")
    text = seen[0].message or (seen[0].failure or {}).get("error", "")
    assert "track" in text or "mcap" in text.lower(), text


def test_baselines_launched_beside_a_flight_that_ends_unsafe_are_removed(mission_run, tmp_path, monkeypatch):
    """segment-3/track ends unsafe (its real run, its summary then marked unsafe) while the baselines fly beside
    it: the mission stops there, and the baselines, which in line would never have flown, leave no folder and are
    ``not_run`` in its summary."""
    from oacli.config import load_config
    from oacli.mission import run as run_module
    from oacli.mission.run import run_mission
    from tests.test_mission_status import _copy_until

    run, cfg_path, _ = mission_run
    out = _copy_until(run, tmp_path / "m", "segment-3/smooth")
    real = run_module.run_stage

    def unsafe_segment_3(stage, stage_cfg, handoff, folder, progress):
        result = real(stage, stage_cfg, handoff, folder, progress)
        if stage.key == "segment-3/track":
            result.summary["status"] = "unsafe"
            result.summary["status_reasons"] = [{"level": "unsafe", "kind": "angular_velocity",
                                                 "message": "marked unsafe by the test"}]
            (folder / "summary.json").write_text(json.dumps(result.summary))
        return result

    monkeypatch.setattr(run_module, "run_stage", unsafe_segment_3)
    result = run_mission(load_config(out / "config.yaml"), out, background=True)
    summary = result.summary
    assert summary["status"] == "unsafe" and "segment-3/track" in summary["stopped"]
    for key in ("segment-3/baseline-mpc-prior", "segment-3/baseline-tube-prior"):
        assert summary["stages"][key]["status"] == "not_run", key
        assert not (out / key).exists(), key
    assert summary["stages"]["segment-2/estimate-sequential"]["status"] == "ok"   # kept, before the stop
    assert cfg_path.exists()
