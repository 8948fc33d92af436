"""oacli campaign, heavier cases (slow): a hanging run times out, the track and mission jobs end to end (the Dask
LocalCluster hash check runs in the default suite: tests/test_campaign.py)."""

from __future__ import annotations

import json

import pytest
import yaml
from conftest import small_mission_config
from test_campaign import run_with, tiny_campaign
from typer.testing import CliRunner

from oacli.campaign import manifest
from oacli.cli import app

pytestmark = pytest.mark.slow


def test_hanging_run_times_out_and_is_retried_then_infra_failed(tmp_path):
    path = tiny_campaign(tmp_path, runs=2, inject={1: "hang"})
    data = yaml.safe_load(path.read_text())
    data.update(timeout_s=30.0, max_retries=1)
    path.write_text(yaml.safe_dump(data))
    run_with(path, tmp_path / "out", "local", workers=2)
    records = manifest.read(tmp_path / "out")
    assert [r["status"] for r in records if r["k"] == 1] == ["retry", "infra_failed"]
    assert all("timeout after 30 s" in r["error"] for r in records if r["k"] == 1)
    final = manifest.final_states(records)
    assert final[0]["status"] in manifest.COMPLETED and final[0]["infra_attempts"] == 0


def test_track_job_writes_stage_folders_and_reruns_bit_for_bit(tmp_path):
    path = tiny_campaign(tmp_path, runs=2)
    data = yaml.safe_load(path.read_text())
    data["job"] = "track"
    path.write_text(yaml.safe_dump(data))
    result = CliRunner().invoke(app, ["campaign", str(path), "--out", str(tmp_path / "c"), "--executor", "local",
                                      "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["finished"] == 2
    for k in range(2):
        attempt = tmp_path / "c" / manifest.final_states(manifest.read(tmp_path / "c"))[k]["attempt"]
        assert (attempt / "track" / "track.mcap").exists() and (attempt / "track" / "summary.json").exists()
    rerun = CliRunner().invoke(app, ["campaign", "rerun", str(tmp_path / "c"), "1", "--json"])
    assert rerun.exit_code == 0, rerun.output
    assert json.loads(rerun.stdout)["hash"] == summary["hashes"]["1"]


def test_mission_job_reports_estimation_against_flight_and_crb(tmp_path):
    base = small_mission_config(tmp_path)
    campaign = {"name": "mini", "seed": 2, "runs": 2, "job": "mission", "base": base.name,
                "set": {"mission": {"baselines": False}},
                "dispersions": {"mass_pct": 1.0, "inertia_pct": [2.0, 2.0, 2.0], "principal_axes_rad": 0.03},
                "faults": {"localisation_jumps": {"probability": 1.0}, "actuator_scale_errors": {"probability": 1.0}}}
    path = tmp_path / "mini.yaml"
    path.write_text(yaml.safe_dump(campaign))
    summary = run_with(path, tmp_path / "c", "local", workers=2, outputs=True)
    assert summary["finished"] == 2
    est = summary["estimation"]
    assert est["runs"] == sum(summary["status_counts"][s] for s in manifest.COMPLETED)
    final = manifest.final_states(manifest.read(tmp_path / "c"))
    for rec in final.values():
        spec = json.loads((tmp_path / "c" / "runs" / f"run-{rec['k']:05d}" / "spec.json").read_text())
        err = rec["metrics"]["estimate"]["error_pct"]
        # The estimate's truth is the dispersed grasped plant (the diagonal of its tensor).
        mission_dir = tmp_path / "c" / rec["attempt"] / "mission"
        estimate = json.loads((mission_dir / "summary.json").read_text())["estimate"]
        assert estimate["truth_theta"] == pytest.approx([spec["draws"]["mass_kg"], *spec["draws"]["inertia_kgm2"]])
        assert err[0] == pytest.approx(100 * (estimate["mass_kg"] / estimate["truth_theta"][0] - 1))
    assert set(est["agreement"]) == {"mass", "Ixx", "Iyy", "Izz"}
    assert (tmp_path / "c" / "plots" / "estimation_error.png").exists()
