"""oacli campaign: reproducible runs across executors, failure isolation, resume after a killed driver."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from oacli.campaign import manifest
from oacli.campaign.driver import load_campaign, prepare, run_campaign
from oacli.campaign.executors import make_executor
from oacli.campaign.finalize import finalize
from oacli.cli import app

ROOT = Path(__file__).resolve().parents[1]
RUNS = 3


def tiny_campaign(folder: Path, *, runs: int = RUNS, inject: dict[int, str] | None = None,
                  name: str = "tiny") -> Path:
    """A campaign of the closed-loop job on a 0.15 m hop (about 1-2 s a run), with every dispersion and two faults
    that strike about half the runs."""
    base = yaml.safe_load((ROOT / "configs" / "doerr2021.yaml").read_text())
    base["name"] = "tiny-base"
    base["waypoints"]["D"] = {"position": [-0.05, 0.0, 0.0], "quaternion": [0.0, 0.0, 0.0, 1.0]}
    base["reference"] = {"source": "waypoints", "waypoints": ["A", "D"], "hold_s": 0.0}
    base["simulation"]["settle_time_s"] = 0.5
    base["sensors"] = {"position_std_m": 0.001, "velocity_std_mps": 0.0005, "attitude_std_rad": 0.002,
                       "angular_velocity_std_radps": 0.0005}
    (folder / "base.yaml").write_text(yaml.safe_dump(base))
    campaign = {
        "name": name, "seed": 11, "runs": runs, "job": "closed-loop", "base": "base.yaml",
        "dispersions": {"mass_pct": 3.0, "inertia_pct": [2.0, 2.0, 2.0], "principal_axes_rad": 0.05,
                        "com_offset_m": [0.002, 0.002, 0.002], "sensor_noise_pct": 20.0,
                        "initial_position_m": [0.005, 0.005, 0.005], "actuator_scale_pct": 2.0},
        "faults": {"controller_stall": {"probability": 0.5, "start_s": [1.0, 2.0], "duration_s": [0.5, 1.0]},
                   "actuator_saturation": {"probability": 0.5, "fraction": [0.5, 0.9]}},
        "inject": inject or {},
    }
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(campaign))
    return path


def run_with(path: Path, out: Path, executor: str, workers: int = 2, *, outputs: bool = False) -> dict:
    """Run a campaign; its summary (with plots and recordings when ``outputs``), else only the manifest's hashes."""
    campaign = load_campaign(path)
    folder = prepare(campaign, out=out, runs_root=out.parent)
    handle = make_executor(executor, workers)
    try:
        run_campaign(folder, handle)
    finally:
        handle.close()
    if outputs:
        return finalize(folder, executor=handle.kind)
    return {"hashes": {str(k): r.get("hash") for k, r in sorted(manifest.final_states(manifest.read(folder)).items())}}


@pytest.fixture(scope="module")
def serial_campaign(tmp_path_factory):
    folder = tmp_path_factory.mktemp("campaign")
    path = tiny_campaign(folder)
    return path, run_with(path, folder / "serial", "serial", outputs=True), folder / "serial"


def test_serial_campaign_outputs(serial_campaign):
    _, summary, folder = serial_campaign
    assert summary["finished"] == RUNS and summary["missing"] == 0
    assert sum(summary["status_counts"].values()) == RUNS
    assert summary["success_rate"] == pytest.approx(
        (summary["status_counts"]["ok"] + summary["status_counts"]["degraded"]) / RUNS)
    hashes = summary["hashes"]
    assert len(set(hashes.values())) == RUNS  # dispersed runs differ
    assert all(h is not None and len(h) == 64 for h in hashes.values())
    # The manifest holds exactly one final line per run, each with its hash.
    final = manifest.final_states(manifest.read(folder))
    assert {k: r["hash"] for k, r in final.items()} == {int(k): h for k, h in hashes.items()}
    # Every run's spec was written before any run, with the draws the config carries.
    for k in range(RUNS):
        spec = json.loads((folder / "runs" / f"run-{k:05d}" / "spec.json").read_text())
        assert spec["config"]["truth"]["mass_kg"] == spec["draws"]["mass_kg"]
        stalls = spec["config"]["faults"]["controller_stall"]
        stalls = stalls if stalls["duration_s"] > 0 else None
        assert ("controller_stall" in spec["draws"]["faults"]) == (stalls is not None)
        metrics = final[k]["metrics"]
        if stalls is not None:  # the stalled controller held its command for the drawn window (5 Hz steps)
            steps = metrics["stalled_steps"]
            assert abs(steps - 5 * stalls["duration_s"]) <= 1.0
        else:
            assert metrics["stalled_steps"] == 0
    # Plots, recording and MCAP exist and the MCAP holds one record per run.
    for name in ("status", "tracking_error"):
        assert (folder / summary["files"]["plots"][name]).stat().st_size > 1000
    from mcap.reader import make_reader

    with open(folder / "campaign.mcap", "rb") as fh:
        runs = [json.loads(m.data) for _, ch, m in make_reader(fh).iter_messages() if ch.topic == "/campaign/run"]
    assert sorted(r["k"] for r in runs) == list(range(RUNS))
    assert {str(r["k"]): r["hash"] for r in runs} == hashes
    tracking = summary["tracking"]["rms_position_error_m"]
    values = sorted(final[k]["metrics"]["rms_position_error_m"] for k in final)
    assert tracking["max"] == pytest.approx(values[-1]) and tracking["n"] == RUNS


def test_hashes_equal_local_and_rerun(serial_campaign, tmp_path):
    """Per-run result hashes are equal across serial and process-pool execution and a lone rerun (Dask
    LocalCluster: tests/test_campaign_jobs.py, slow)."""
    path, serial, serial_folder = serial_campaign
    local = run_with(path, tmp_path / "local", "local", workers=2)
    assert local["hashes"] == serial["hashes"]
    result = CliRunner().invoke(app, ["campaign", "rerun", str(serial_folder), "2", "--json"])
    assert result.exit_code == 0, result.output
    outcome = json.loads(result.stdout)
    assert outcome["same"] and outcome["hash"] == serial["hashes"]["2"]


def test_injected_failures_end_with_exact_statuses(serial_campaign, tmp_path):
    """A raising run is 'failed' (traceback, one attempt); a dying or out-of-memory run is retried twice, then
    'infra_failed'; the healthy run is untouched (same hash as the serial campaign)."""
    _, serial, _ = serial_campaign
    folder = tmp_path / "cfg"
    folder.mkdir()
    path = tiny_campaign(folder, runs=4, inject={1: "raise", 2: "exit", 3: "oom"})
    run_with(path, tmp_path / "local", "local", workers=2)
    final = manifest.final_states(manifest.read(tmp_path / "local"))
    assert {k: r["status"] for k, r in final.items() if k != 0} == {1: "failed", 2: "infra_failed",
                                                                    3: "infra_failed"}
    assert final[0]["status"] in manifest.COMPLETED and final[0]["hash"] == serial["hashes"]["0"]
    assert "injected failure" in final[1]["traceback"] and final[1]["infra_attempts"] == 0
    assert final[2]["infra_attempts"] == 3 and final[2]["error"] == "worker died"
    assert final[3]["infra_attempts"] == 3 and "out of memory" in final[3]["error"]
    records = manifest.read(tmp_path / "local")
    assert [r["status"] for r in records if r["k"] == 1] == ["failed"]  # not retried
    assert [r["status"] for r in records if r["k"] == 2] == ["retry", "retry", "infra_failed"]
    assert [r["status"] for r in records if r["k"] == 0] == [final[0]["status"]]


def test_killed_driver_resumed_equals_uninterrupted(serial_campaign, tmp_path):
    """SIGKILL the driver once a run is in the manifest; --resume finishes with the uninterrupted hashes."""
    path, serial, _ = serial_campaign
    out = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "oacli", "campaign", str(path), "--out", str(out),
                             "--executor", "serial", "-q"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not manifest.read(out) and proc.poll() is None:
            time.sleep(0.05)
        assert proc.poll() is None, "the campaign ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not (out / "summary.json").exists()
    assert 1 <= len(manifest.final_states(manifest.read(out))) < RUNS
    result = CliRunner().invoke(app, ["campaign", str(out), "--resume", "--executor", "serial", "--json"])
    assert result.exit_code == 0, result.output
    resumed = json.loads(result.stdout)
    assert resumed["hashes"] == serial["hashes"]
    # An existing campaign folder is never overwritten.
    again = CliRunner().invoke(app, ["campaign", str(path), "--out", str(out)])
    assert again.exit_code == 2 and "never overwritten" in again.output


def test_dry_run_writes_configs_only(tmp_path):
    path = tiny_campaign(tmp_path, runs=2)
    result = CliRunner().invoke(app, ["campaign", str(path), "--out", str(tmp_path / "dry"), "--dry-run", "-q"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "dry" / "runs").iterdir()) == ["run-00000", "run-00001"]
    assert not (tmp_path / "dry" / "manifest.jsonl").exists()
    assert json.loads((tmp_path / "dry" / "runs.json").read_text())["runs"] == 2


def test_bad_campaign_config_names_the_field(tmp_path):
    path = tiny_campaign(tmp_path)
    data = yaml.safe_load(path.read_text())
    data["faults"]["controller_stall"]["probability"] = 1.5
    path.write_text(yaml.safe_dump(data))
    result = CliRunner().invoke(app, ["campaign", str(path), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2
    assert "faults.controller_stall.probability" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x").exists()


def test_flight_preset_writes_valid_mission_configs(tmp_path):
    """The flight preset's runs are valid mission configs: the tensor reaches segments 2 and 3 only, with the
    grasped plant's diagonal."""
    campaign = load_campaign(ROOT / "configs" / "campaign_reswarm_flight.yaml", ["runs=3"])
    assert campaign.config.job == "mission" and campaign.base["mission"]["excitation_method"] == "rattle"
    folder = prepare(campaign, out=tmp_path / "dry", runs_root=tmp_path)
    for k in range(3):
        spec = json.loads((folder / "runs" / f"run-{k:05d}" / "spec.json").read_text())
        mission = spec["config"]["mission"]
        assert mission["grasped"]["mass_kg"] == spec["draws"]["mass_kg"]
        for seg in ("segment-2", "segment-3"):
            truth = mission["segments"][seg]["truth"]
            assert truth["inertia_kgm2"] == mission["grasped"]["inertia_kgm2"] == spec["draws"]["inertia_kgm2"]
        assert "truth" not in (mission["segments"].get("segment-1") or {})
        assert "actuator_scale_errors" in spec["draws"]["faults"]  # probability 1 in the preset


def test_hashes_equal_on_dask_local_cluster(tmp_path):
    """Per-run result hashes on a Dask LocalCluster (bound to 127.0.0.1) equal the serial ones."""
    path = tiny_campaign(tmp_path)
    serial = run_with(path, tmp_path / "serial", "serial")
    dask = run_with(path, tmp_path / "dask", "dask-local", workers=2)
    assert dask["hashes"] == serial["hashes"] and len(set(serial["hashes"].values())) == 3
