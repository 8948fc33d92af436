"""CLI conveniences: --set, --json, info, runs list, config show, --view wiring."""

from __future__ import annotations

import json

import yaml
from typer.testing import CliRunner

from oacli.cli import app
from oacli.commands.view import viewer_command
from oacli.io.mcap_io import read_stage
from tests.conftest import REPO

DOERR = REPO / "configs" / "doerr2021.yaml"


def run_cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_set_json_info_and_runs_list(tmp_path):
    out = tmp_path / "runs" / "t"
    result = run_cli("track", DOERR, "--set", "simulation.settle_time_s=1", "--seed", "2", "--json", "--out", out)
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)
    summary = json.loads((out / "summary.json").read_text())
    assert printed["run_dir"] == str(out)
    assert printed["max_position_error_m"] == summary["max_position_error_m"]
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg["simulation"]["settle_time_s"] == 1.0 and cfg["seed"] == 2
    info = json.loads(run_cli("info", out, "--json").stdout)
    assert info["status"] == summary["status"] and "track.mcap" in info["files"]
    counts = read_stage(out / "track.mcap").message_counts
    assert {c["topic"]: c["messages"] for c in info["mcap"]["channels"]} == counts
    assert info["mcap"]["duration_s"] > 0
    runs = json.loads(run_cli("runs", "list", "--runs-dir", tmp_path / "runs", "--json").stdout)
    assert [(r["name"], r["stage"], r["status"]) for r in runs] == [("t", "track", summary["status"])]


def test_set_is_validated_like_file_values():
    result = run_cli("config", "show", DOERR, "--set", "robot.mass_kg=-3")
    assert result.exit_code == 2
    assert "robot.mass_kg" in result.output and "must be > 0" in result.output
    result = run_cli("config", "show", DOERR, "--set", "robot.mass_kg")
    assert result.exit_code == 2 and "KEY=VALUE" in result.output
    shown = yaml.safe_load(run_cli("config", "show", DOERR, "--set", "robot.mass_kg=15").stdout)
    assert shown["robot"]["mass_kg"] == 15.0 and "controller" in shown  # defaults filled in
    # --set values are read like file values, YAML 1.2: no sexagesimal 1:30 = 90, and 1e1 is a number
    result = run_cli("config", "show", DOERR, "--set", "seed=1:30")
    assert result.exit_code == 2 and "seed: '1:30': must be an integer" in result.output
    shown = yaml.safe_load(run_cli("config", "show", DOERR, "--set", "robot.mass_kg=1e1").stdout)
    assert shown["robot"]["mass_kg"] == 10.0


def test_info_refuses_a_missing_path(tmp_path):
    result = run_cli("info", tmp_path / "nope")
    assert result.exit_code == 2 and "not found" in result.output


def test_view_binds_the_viewer_to_localhost(tmp_path):
    cmd = viewer_command(tmp_path / "track.rrd")
    assert cmd[-2:] == ["--bind", "127.0.0.1"] and str(tmp_path / "track.rrd") in cmd
