"""End-to-end ``oacli track`` → ``oacli estimate``: run the CLI, read the MCAPs and the recording back, check values."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.io.mcap_io import read_stage, read_telemetry
from oacli.io.rerun.estimate import D2, PARAM_ENTITIES
from oacli.io.rerun.read import (
    empty_blueprint_views,
    read_application_id,
    read_blueprint_timeline,
    read_blueprint_views,
    read_recording_entities,
    read_recording_scalars,
)
from tests.conftest import INFO_TRAJECTORIES, REPO, require_shared
from tests.mcap_checks import check_json_records
from tests.plot_checks import PNGS

ISS = REPO / "configs" / "iss_reswarm.yaml"
TRUTH = [15.0, 0.1464, 0.1376, 0.1604]  # [Doerr2021] Table 1: Astrobee with the 3D-printed object
NAMES = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")
runner = CliRunner()


def run_cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def payload_config(path: Path, **changes) -> Path:
    """The ISS preset with the payload as the plant, the robot model as prior mean, a waypoint reference that
    rotates the robot about its three axes (no shared data needed), and a short run."""
    data = yaml.safe_load(ISS.read_text())
    data["name"] = "payload"
    data["seed"] = 3
    data["truth"] = {"mass_kg": TRUTH[0], "inertia_kgm2": TRUTH[1:]}
    data["waypoints"].update({
        "R1": {"position": [10.9, -7.6, 5.0], "quaternion": [0.339005, -0.339005, -0.620545, 0.620545]},
        "R2": {"position": [10.7, -7.8, 4.8], "quaternion": [0.59501, 0.0, -0.382051, 0.707107]},
    })
    data["reference"].update({"waypoints": ["B", "R1", "R2"], "cruise_speed_mps": 0.05, "acceleration_mps2": 0.01,
                              "angular_rate_radps": 0.15, "angular_acceleration_radps2": 0.1, "hold_s": 0.5})
    data["simulation"]["settle_time_s"] = 1.0
    data["estimation"]["prior"] = {"variance": [15.0, 0.005, 0.005, 0.005]}
    data["estimation"]["window_s"] = 15.0
    for key, value in changes.items():
        section, field = key.split("__")
        data[section][field] = value
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def track_run(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("estimate")
    cfg = payload_config(root / "payload.yaml")
    result = run_cli("track", cfg, "--out", root / "track", "--quiet")
    assert result.exit_code == 0, result.output
    return cfg, root / "track" / "track.mcap"


@pytest.fixture(scope="module")
def batch_run(track_run, tmp_path_factory) -> Path:
    cfg, telemetry = track_run
    out = tmp_path_factory.mktemp("batch") / "run"
    result = run_cli("estimate", cfg, "--telemetry", telemetry, "--out", out)
    assert result.exit_code == 0, result.output
    assert "mass_kg" in result.stdout and "crb_std" in result.stdout
    return out


def test_batch_run_folder_summary_and_accuracy_against_the_cramer_rao_bound(batch_run):
    assert sorted(p.name for p in batch_run.iterdir()) == sorted(["config.yaml", "estimate.mcap", "estimate.rrd",
                                                                "summary.json", *PNGS["estimate"]])
    s = json.loads((batch_run / "summary.json").read_text())
    assert s["stage"] == "estimate" and s["status"] == "ok" and s["method"] == "batch"
    theta = np.array([s["mass_kg"], *s["inertia_kgm2"]])
    std = np.array([s["std"][n] for n in NAMES])
    crb = np.array([s["crb_std"][n] for n in NAMES])
    err = np.array([s["error_pct"][n] for n in NAMES])
    # The truth comes from the telemetry's attached config; every error within 4 Cramér-Rao bounds.
    np.testing.assert_allclose(err, 100 * np.abs(theta - TRUTH) / TRUTH, rtol=1e-12)
    assert np.all(np.abs(theta - TRUTH) < 4 * crb), (theta, crb)
    # The batch covariance (AᵀA)⁻¹ is the bound of a nearly rigid model (initial state unknown).
    np.testing.assert_allclose(std, crb, rtol=0.1)
    assert all(s["crb_std_known_initial_state"][n] < s["crb_std"][n] for n in NAMES)
    # Covariance reduction against the prior variances (15 kg², 0.005 (kg·m²)²).
    prior_var = np.array([15.0, 0.005, 0.005, 0.005])
    np.testing.assert_allclose([s["cov_reduction_pct"][n] for n in NAMES], 100 * (1 - std**2 / prior_var), rtol=1e-9)
    assert s["samples_used"] + s["samples_rejected"] == s["samples_total"]
    assert s["samples_rejected"] <= 0.03 * s["samples_total"]  # the 0.99 gate on clean data
    assert s["converged"] and s["cost_final"] < s["cost_initial"]


def test_estimate_mcap_reads_back_and_matches_the_summary(batch_run, track_run):
    s = json.loads((batch_run / "summary.json").read_text())
    record = read_stage(batch_run / "estimate.mcap")
    assert record.metadata["oacli"]["stage"] == "estimate"
    assert record.metadata["oacli"]["method"] == "batch"
    assert yaml.safe_load(record.attachments["config.yaml"]) == yaml.safe_load((batch_run / "config.yaml").read_text())
    params = record.json_records["/estimate/params"]
    assert len(params) == s["windows"] >= 2
    final = params[-1]
    assert final["final"] and not any(p["final"] for p in params[:-1])
    assert final["mass_kg"] == s["mass_kg"] and final["inertia_kgm2"] == s["inertia_kgm2"]
    assert final["samples_used"] == s["samples_used"] and final["samples_rejected"] == s["samples_rejected"]
    cov = np.array(final["covariance"])
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [s["std"][n] for n in NAMES], rtol=1e-12)
    assert np.all(np.diff([p["t"] for p in params]) > 0)
    # One sample record per telemetry record, rejections consistent with the summary.
    samples = record.json_records["/estimate/samples"]
    tel = read_telemetry(track_run[1])
    assert len(samples) == len(tel.t_ctrl)
    assert sum(r["status"] == "rejected" for r in samples) == s["samples_rejected"]
    assert all(r["d2"] > r["gate"] for r in samples if r["status"] == "rejected")
    assert all(r["d2"] <= r["gate"] for r in samples if r["status"] == "accepted")
    # The estimated states follow the true ones closely.
    est = record.trajectories["/state/estimated"]
    idx = np.searchsorted(tel.t_true, est.t[::2] - 1e-9)
    assert np.max(np.abs(est.x[::2, 0:3] - tel.x_true[idx, 0:3])) < 0.01


def test_estimate_records_follow_the_contract_schemas(batch_run):
    counts = check_json_records(batch_run / "estimate.mcap")
    summary = json.loads((batch_run / "summary.json").read_text())
    assert counts["oacli.ParameterEstimate"] == summary["windows"]
    assert counts["oacli.EstimationSample"] == summary["samples_total"]
    assert counts["oacli.EstimationCost"] >= 1


def test_recording_shows_the_estimates_with_bands_truth_and_gate(batch_run):
    s = json.loads((batch_run / "summary.json").read_text())
    entities = read_recording_entities(batch_run / "estimate.rrd")
    for entity in PARAM_ENTITIES:
        for child in ("", "/upper_2sigma", "/lower_2sigma", "/truth"):
            assert entity + child in entities
    scalars = read_recording_scalars(batch_run / "estimate.rrd")
    _, mass = scalars["estimate/mass_kg"]
    _, upper = scalars["estimate/mass_kg/upper_2sigma"]
    assert mass[-1] == pytest.approx(s["mass_kg"], rel=1e-12)
    assert upper[-1] == pytest.approx(s["mass_kg"] + 2 * s["std"]["mass_kg"], rel=1e-12)
    _, truth = scalars["estimate/Izz_kgm2/truth"]
    np.testing.assert_allclose(truth, TRUTH[3])
    _, d2 = scalars[D2]
    assert len(d2) == s["samples_total"]
    if s["samples_rejected"]:
        _, rejected = scalars[f"{D2}/rejected"]
        assert len(rejected) == s["samples_rejected"]
    views = {v["origin"] for v in read_blueprint_views(batch_run / "estimate.rrd")}
    assert set(PARAM_ENTITIES) <= views


def test_sequential_estimate_agrees_with_the_batch(track_run, batch_run, tmp_path):
    cfg, telemetry = track_run
    result = run_cli("estimate", cfg, "--telemetry", telemetry, "--method", "sequential", "--out", tmp_path / "seq",
                     "--quiet")
    assert result.exit_code == 0, result.output
    seq = json.loads((tmp_path / "seq" / "summary.json").read_text())
    batch = json.loads((batch_run / "summary.json").read_text())
    assert seq["method"] == "sequential"
    params = read_stage(tmp_path / "seq" / "estimate.mcap").json_records["/estimate/params"]
    assert params[-1]["method"] == "sequential" and params[-1]["final"]
    for i, name in enumerate(NAMES):
        value = seq["mass_kg"] if i == 0 else seq["inertia_kgm2"][i - 1]
        ref = batch["mass_kg"] if i == 0 else batch["inertia_kgm2"][i - 1]
        assert abs(value - ref) < batch["std"][name], name
        assert abs(value - TRUTH[i]) < 4 * seq["crb_std"][name], name


@pytest.mark.shared_data
def test_flown_excitation_trajectory_tracked_with_the_payload_then_estimated(tmp_path):
    """RATTLE's flown ISS excitation (B → C, 60 s) tracked by the robot carrying the payload, then estimated."""
    reference = require_shared(INFO_TRAJECTORIES / "excitation_iss_11.csv")
    cfg = payload_config(tmp_path / "payload.yaml", estimation__window_s=100.0)
    result = run_cli("track", cfg, "--reference", reference, "--out", tmp_path / "track", "--quiet")
    assert result.exit_code == 0, result.output
    result = run_cli("estimate", cfg, "--telemetry", tmp_path / "track" / "track.mcap", "--out", tmp_path / "est",
                     "--quiet")
    assert result.exit_code == 0, result.output
    s = json.loads((tmp_path / "est" / "summary.json").read_text())
    for i, name in enumerate(NAMES):
        value = s["mass_kg"] if i == 0 else s["inertia_kgm2"][i - 1]
        assert abs(value - TRUTH[i]) < 4 * s["crb_std"][name], name
    # [ReSWARM2023] flight errors were 0.39 / 0.91 / 1.35 / 6.92 %; the simulated bound is far tighter.
    assert max(s["error_pct"].values()) < 0.9
    assert s["duration_s"] == pytest.approx(60.8, abs=0.3)  # 60 s reference + 1 s settling, 0.2 s steps


def test_no_torque_means_unobservable_inertias_exit_3_and_no_run_folder(tmp_path):
    cfg = payload_config(tmp_path / "still.yaml", reference__waypoints=["B", "C"],
                         sensors__attitude_std_rad=0.0, sensors__angular_velocity_std_radps=0.0,
                         sensors__position_std_m=0.0, sensors__velocity_std_mps=0.0)
    assert run_cli("track", cfg, "--out", tmp_path / "track", "--quiet").exit_code == 0
    tel = read_telemetry(tmp_path / "track" / "track.mcap")
    assert np.all(np.abs(tel.u_applied[:, 3:6]) < 1e-12)  # a pure translation: no torque (to rounding)
    result = run_cli("estimate", cfg, "--telemetry", tmp_path / "track" / "track.mcap", "--runs-dir",
                     tmp_path / "runs", "--quiet")
    assert result.exit_code == 3, result.output
    assert "Traceback" not in result.output
    for name in ("Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2"):
        assert name in result.stderr
    assert "mass_kg" not in result.stderr.split("unobservable")[1].split(";")[0]
    assert [line[:7] for line in result.stderr.splitlines()] == ["error: "]  # one line
    assert not (tmp_path / "runs").exists()


def test_bad_inputs_exit_2_with_one_clear_line(track_run, batch_run, tmp_path):
    cfg, telemetry = track_run
    missing = run_cli("estimate", cfg, "--telemetry", tmp_path / "nope.mcap", "--runs-dir", tmp_path / "runs")
    assert missing.exit_code == 2 and "nope.mcap" in missing.stderr
    method = run_cli("estimate", cfg, "--telemetry", telemetry, "--method", "kalman", "--runs-dir", tmp_path / "runs")
    assert method.exit_code == 2 and "--method kalman" in method.stderr
    # An MCAP that is not a tracking run (the estimate's own) names the missing topic.
    wrong = run_cli("estimate", cfg, "--telemetry", batch_run / "estimate.mcap", "--runs-dir", tmp_path / "runs")
    assert wrong.exit_code == 2 and "/state/measured" in wrong.stderr
    for result in (missing, method, wrong):
        assert "Traceback" not in result.output
        assert all(line.startswith("error: ") for line in result.stderr.splitlines() if line.strip())
    assert not (tmp_path / "runs").exists()


def assert_recording_opens_right(rrd, stage):
    """Own application id (own layout when several recordings are open), no panel empty on the opening timeline."""
    assert read_application_id(rrd) == f"oacli-{stage}"
    assert read_blueprint_timeline(rrd) == "mission_time"
    assert read_blueprint_views(rrd), "no blueprint"
    assert empty_blueprint_views(rrd) == []


def test_estimate_recording_opens_with_every_panel_filled(batch_run):
    assert_recording_opens_right(batch_run / "estimate.rrd", "estimate")


def test_scene_with_the_robot_body_in_the_estimate_and_track_mcaps(batch_run, track_run):
    from tests.mcap_checks import robot_body_samples, scene_updates

    cfg = load_config(track_run[0])
    for path, paths in ((batch_run / "estimate.mcap", {"path/measured", "path/estimated"}),
                        (track_run[1], {"path/reference", "path/actual"})):
        (t0, workspace), *_ = scene_updates(path)
        ids = {e.id for e in workspace.entities}
        assert ids == {f"keep_in/{i}" for i in range(len(cfg.scene().keep_in))} | {
            f"keep_out/{i}" for i in range(len(cfg.scene().keep_out))} | paths
        # the body is posed at the robot's pose (/robot/pose) at the same times, at most 10 Hz
        times, positions, quats, edges = robot_body_samples(path)
        record = read_stage(path)
        states = record.trajectories["/state/estimated" if path.name == "estimate.mcap" else "/state/true"]
        ns = np.rint(states.t * 1e9).astype(np.int64)
        idx = np.searchsorted(ns, times)
        assert np.array_equal(ns[idx], times) and t0 <= times[0]
        np.testing.assert_array_equal(positions, states.x[idx, 0:3])
        np.testing.assert_array_equal(quats, states.x[idx, 6:10])
        assert edges == [0.30] * len(times) and len(times) >= 10
        assert np.all(np.diff(times[:-1]) >= 0.1e9 - 20e6)  # ≤ 10 Hz up to one plant sample
        assert times[-1] == ns[-1]


def test_full_rigid_body_parameters_through_the_cli(track_run, tmp_path):
    """`--set estimation.parameters=[...]`: the summary's rigid_body lists every estimated entry with σ, truth and
    z-score (this plant has no CoM offset: found within 3σ of zero), the log names them; a set without the mass
    is refused with exit 2 and one line naming the field, before any run folder."""
    cfg, telemetry = track_run
    out = tmp_path / "full"
    result = run_cli("estimate", cfg, "--telemetry", telemetry, "--out", out, "--quiet",
                     "--set", "estimation.parameters=[mass,inertia,com]")
    assert result.exit_code in (0, 4), result.output
    s = json.loads((out / "summary.json").read_text())
    rb = s["rigid_body"]
    assert rb["parameters"] == ["mass", "inertia", "com"]
    assert set(rb["estimate"]) == {*NAMES, "com_x_m", "com_y_m", "com_z_m"}
    assert rb["truth"]["com_x_m"] == 0.0 and all(abs(rb["z_score"][n]) < 3 for n in ("com_x_m", "com_y_m", "com_z_m"))
    assert rb["estimate"]["mass_kg"] == pytest.approx(s["mass_kg"], rel=1e-12)
    assert rb["std"]["mass_kg"] == pytest.approx(s["std"]["mass_kg"], rel=1e-12)
    assert rb["prior_std"]["com_x_m"] == pytest.approx(0.01)
    bad = run_cli("estimate", cfg, "--telemetry", telemetry, "--runs-dir", tmp_path / "runs",
                  "--set", "estimation.parameters=[mass,com]")
    assert bad.exit_code == 2 and "parameters" in bad.stderr and "Traceback" not in bad.output
    assert not (tmp_path / "runs").exists()
