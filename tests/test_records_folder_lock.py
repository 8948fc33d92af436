"""An advisory lock on a mission or campaign folder while it runs or resumes. A second resume exits 2
naming the holder (pid, host, start time); two concurrent ``oacli campaign DIR --resume`` fly each run exactly once.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from oacli.campaign import manifest
from oacli.cli import app
from oacli.io.folder_lock import HOLDER_FILE, FolderBusy, folder_lock
from tests.conftest import REPO, small_mission_config
from tests.test_campaign import tiny_campaign

runner = CliRunner()


def test_a_held_folder_refuses_a_second_holder_naming_the_first(tmp_path):
    with folder_lock(tmp_path, "campaign"):
        assert (tmp_path / HOLDER_FILE).is_file()
        with pytest.raises(FolderBusy) as busy, folder_lock(tmp_path, "campaign"):
            pass
        line = busy.value.problems[0]
        assert f"pid {os.getpid()} on host {socket.gethostname()} since 20" in line and "in use" in line
        assert busy.value.exit_code == 2
    assert not (tmp_path / HOLDER_FILE).exists()  # released: the next holder takes it
    with folder_lock(tmp_path, "campaign"):
        pass


def test_a_second_mission_resume_exits_2_naming_the_holder(tmp_path):
    from oacli.config import load_config
    from oacli.mission.run import start_mission

    cfg = load_config(small_mission_config(tmp_path))
    folder = start_mission(cfg, out=tmp_path / "mission", runs_root=tmp_path)
    with folder_lock(folder, "mission"):
        result = runner.invoke(app, ["mission", str(folder), "--resume", "-q"])
    assert result.exit_code == 2, result.output
    assert f"the mission is in use by pid {os.getpid()}" in result.output and "Traceback" not in result.output
    assert sorted(p.name for p in folder.iterdir()) == ["config.yaml"]  # nothing written by the refused resume


def test_two_concurrent_campaign_resumes_fly_each_run_once(tmp_path):
    path = tiny_campaign(tmp_path, runs=3)
    folder = tmp_path / "camp"
    done = runner.invoke(app, ["campaign", str(path), "--out", str(folder), "--dry-run", "-q"])
    assert done.exit_code == 0, done.output
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-m", "oacli", "campaign", str(folder), "--resume", "--executor", "serial", "-q"]
    procs = [subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    outcomes = [(p.wait(timeout=300), p.communicate()[1]) for p in procs]
    codes = sorted(code for code, _ in outcomes)
    assert codes in ([0, 0], [0, 2]), outcomes
    for code, err in outcomes:
        assert "Traceback" not in err
        if code == 2:
            assert "the campaign is in use by pid" in err and "on host" in err and "since" in err, err
    records = manifest.read(folder)
    flown = sorted(r["k"] for r in records if r["status"] in manifest.FINAL)
    assert flown == [0, 1, 2], records  # each run flown exactly once
    assert not (folder / HOLDER_FILE).exists()
