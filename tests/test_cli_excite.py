"""End-to-end ``oacli excite``: run the CLI, read the MCAP and the Rerun recording back, then track the design."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.excitation.information import MeasurementModel, cramer_rao_std, fisher_information
from oacli.excitation.rattle import InformationWeighting
from oacli.geometry.verify import dense_positions
from oacli.io.mcap_io import read_stage, read_telemetry, read_trajectory
from oacli.io.rerun.read import (
    empty_blueprint_views,
    read_application_id,
    read_blueprint_timeline,
    read_blueprint_views,
    read_recording_entities,
    read_recording_scalars,
)
from oacli.trajectory import sample_states
from tests.conftest import REPO
from tests.mcap_checks import check_json_records
from tests.plot_checks import PNGS
from tests.test_cli_errors import assert_clean_failure

ISS = REPO / "configs" / "iss_reswarm.yaml"
PAYLOAD = {"mass_kg": 15.0, "inertia_kgm2": [0.1464, 0.1376, 0.1604]}  # [Doerr2021] Table 1, Astrobee with object
runner = CliRunner()


def run_cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def small_iss(path: Path, **excitation) -> Path:
    """The ISS preset's B→C excitation, shortened (40 steps of 1 s), with the payload as the simulated truth and
    the impellers at 2500 RPM ([ReSWARM2023] Table 2) so that the tracker has force to spare."""
    data = yaml.safe_load(ISS.read_text())
    data["truth"] = dict(PAYLOAD)
    data["robot"]["force_limit_N"] = [0.680, 0.332, 0.394]
    data["robot"]["torque_limit_Nm"] = [0.068, 0.0332, 0.0394]
    data["robot"]["angular_velocity_limit_radps"] = [0.5236, 0.5236, 0.5236]  # astrobee "difficult" flight mode
    data["excitation"].update({"steps": 40, "duration_s": 40.0, "scp": {"max_iterations": 15}})
    for key, value in excitation.items():
        data["excitation"][key] = value
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def config(tmp_path_factory) -> Path:
    return small_iss(tmp_path_factory.mktemp("cfg") / "small.yaml")


@pytest.fixture(scope="module")
def excite_run(config, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("excite") / "run"
    result = run_cli("excite", config, "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    return out


def test_run_folder_and_summary(excite_run, config):
    assert sorted(p.name for p in excite_run.iterdir()) == sorted(["config.yaml", "excite.mcap", "excite.rrd",
                                                                   "summary.json", *PNGS["excite"]])
    summary = json.loads((excite_run / "summary.json").read_text())
    for key in ("criterion_initial", "criterion_final", "iterations", "solve_time_s", "max_force_N", "max_torque_Nm",
                "collision_free", "crb_std", "goal_residual"):
        assert key in summary, key
    assert summary["stage"] == "excite" and summary["method"] == "offline"
    # The status follows the SCP's stop: converged → ok; the 15-iteration cap kept for the test → an honest
    # "degraded" (reason scp), still exit 0.
    if summary["stop_reason"].startswith("converged"):
        assert summary["status"] == "ok" and summary["status_reasons"] == []
    else:
        assert summary["stop_reason"] == "iteration limit"
        assert summary["status"] == "degraded" and [r["kind"] for r in summary["status_reasons"]] == ["scp"]
    assert summary["criterion_final"] < summary["criterion_initial"]
    assert summary["collision_free"] is True
    assert summary["max_force_N"] <= 0.25 + 1e-9 and summary["max_torque_Nm"] <= 0.025 + 1e-9
    assert load_config(excite_run / "config.yaml") == load_config(config)


def test_mcap_reads_back_and_agrees_with_the_summary(excite_run, config):
    cfg = load_config(config)
    summary = json.loads((excite_run / "summary.json").read_text())
    record = read_stage(excite_run / "excite.mcap", validate_crcs=True)
    assert record.topics["/trajectory"] == "oacli.TrajectorySample"
    for topic in ("/excitation/iterations", "/excitation/information", "/scene", "/robot/pose", "/log"):
        assert topic in record.topics, topic
    assert record.metadata["oacli"]["stage"] == "excite"
    traj = read_trajectory(excite_run / "excite.mcap")
    # At the design's sample period, from B at rest to C within the tolerance reported.
    np.testing.assert_allclose(np.diff(traj.t), 1.0, atol=1e-9)
    assert len(traj) == 41
    np.testing.assert_allclose(traj.x[0, 0:3], cfg.waypoints["B"].position)
    np.testing.assert_allclose(traj.x[0, 3:6], 0.0)
    residual = np.max(np.abs(traj.x[-1, 0:3] - np.asarray(cfg.waypoints["C"].position)))
    assert residual == pytest.approx(summary["goal_residual"]["position_m"], abs=1e-12)
    assert residual <= cfg.excitation.terminal_tolerance.position_m * (1 + 1e-6)
    assert np.max(np.abs(traj.u[:, 0:3])) == pytest.approx(summary["max_force_N"], abs=1e-12)
    # Collision-free between the samples too (the parabola under the held force), with the clearance kept.
    _, pts = dense_positions(traj.t, traj.x, traj.u[:-1, 0:3] / 15.0, substeps=50)
    assert np.all(cfg.scene().in_keep_in(pts, margin_m=cfg.excitation.clearance_m - 1e-6))
    # The criterion per iteration; the last one is the design's.
    iterations = record.json_records["/excitation/iterations"]
    assert len(iterations) == summary["iterations"]
    assert [r["iteration"] for r in iterations] == list(range(1, len(iterations) + 1))
    assert iterations[-1]["criterion"] == pytest.approx(summary["criterion_final"], rel=1e-12)
    # Information over time: recomputing the FIM from the trajectory read back gives the last record and the bound.
    info = record.json_records["/excitation/information"]
    assert len(info) == len(traj)
    theta = np.array([15.0, 0.1464, 0.1376, 0.1604])
    model = MeasurementModel(**cfg.excitation.measurement.model_dump())
    fim = fisher_information(traj.x[0], traj.u[:-1], theta, 1.0, model)
    np.testing.assert_allclose(np.array(info[-1]["information"]), fim, rtol=1e-9)
    np.testing.assert_allclose(info[-1]["crb_std"], cramer_rao_std(fim, theta), rtol=1e-9)
    np.testing.assert_allclose(list(summary["crb_std"].values()), cramer_rao_std(fim, theta), rtol=1e-9)
    assert np.trace(np.linalg.inv(fim)) == pytest.approx(summary["criterion_final"], rel=1e-9)


def test_excite_records_follow_the_contract_schemas(excite_run):
    counts = check_json_records(excite_run / "excite.mcap")
    summary = json.loads((excite_run / "summary.json").read_text())
    assert counts["oacli.ScpIteration"] == summary["iterations"]
    assert counts["oacli.Information"] == counts["oacli.TrajectorySample"] == summary["steps"] + 1


def test_recording_reads_back_with_the_logged_values(excite_run):
    rrd = excite_run / "excite.rrd"
    entities = read_recording_entities(rrd)
    for entity in ("world/keep_in", "world/keep_out", "world/excitation", "world/initial_guess", "world/robot",
                   "metrics/criterion", "metrics/information", "metrics/crb_std_log10_pct", "metrics/force_N",
                   "metrics/torque_Nm", "log"):
        assert entity in entities, entity
    traj = read_trajectory(excite_run / "excite.mcap")
    scalars = read_recording_scalars(rrd)
    t_force, force = scalars["metrics/force_N"]
    np.testing.assert_allclose(t_force, traj.t, atol=1e-9)
    np.testing.assert_allclose(force, traj.u[:, 0:3], atol=1e-12)
    _, information = scalars["metrics/information"]
    last = read_stage(excite_run / "excite.mcap").json_records["/excitation/information"][-1]
    theta = np.array([15.0, 0.1464, 0.1376, 0.1604])
    np.testing.assert_allclose(information[-1], np.diag(np.array(last["information"])) * theta**2, rtol=1e-12)
    per_iteration = read_recording_scalars(rrd, timeline="scp_iteration")
    iterations, criterion = per_iteration["metrics/criterion"]
    records = read_stage(excite_run / "excite.mcap").json_records["/excitation/iterations"]
    np.testing.assert_array_equal(iterations, np.arange(1, len(records) + 1))
    np.testing.assert_allclose(criterion, [r["criterion"] for r in records], rtol=1e-12)


def test_excite_then_track_with_the_payload(excite_run, config, tmp_path):
    """The design is trackable: the MPC (model: bare Astrobee, 9.58 kg, with its keep-in/keep-out rows) follows it
    with the 15 kg payload (keep-in boxes bound the robot's centre, as in the design's own collision checks)."""
    out = tmp_path / "track"
    result = run_cli("track", config, "--reference", excite_run / "excite.mcap", "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    design = read_trajectory(excite_run / "excite.mcap")
    tel = read_telemetry(out / "track.mcap")
    # The tracker's reference is the design, sampled at the controller times.
    np.testing.assert_allclose(tel.x_reference[:, 0:3], sample_states(design, tel.t_ctrl)[:, 0:3], atol=1e-9)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["constraint_violations"] == 0
    assert summary["solver_failures"] == 0
    assert summary["rms_position_error_m"] <= 0.06  # 36 % mass error in the controller's model
    assert summary["max_position_error_m"] <= 0.10
    assert summary["final_position_error_m"] <= 0.02
    idx = np.searchsorted(tel.t_true, tel.t_ctrl - 1e-9)
    err = np.linalg.norm(tel.x_true[idx, 0:3] - tel.x_reference[:, 0:3], axis=1)
    assert np.sqrt(np.mean(err**2)) <= 0.06

    # ... and the whole segment-2 chain closes: estimate θ from the tracking run's MCAP (excite → track → estimate).
    est_out = tmp_path / "estimate"
    result = run_cli("estimate", config, "--telemetry", out / "track.mcap", "--out", est_out, "--quiet")
    assert result.exit_code == 0, result.output
    est = json.loads((est_out / "summary.json").read_text())
    assert est["status"] == "ok" and est["method"] == "batch"
    theta = np.array([est["mass_kg"], *est["inertia_kgm2"]])
    truth = np.array([PAYLOAD["mass_kg"], *PAYLOAD["inertia_kgm2"]])
    names = ["mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2"]
    np.testing.assert_allclose([est["error_pct"][n] for n in names], 100.0 * np.abs(theta - truth) / truth,
                               rtol=1e-9, atol=1e-12)
    # Within 4 Cramér-Rao bounds of the truth, and far better known than before (RATTLE's P0).
    assert np.all(np.abs(theta - truth) <= 4.0 * np.array([est["crb_std"][n] for n in names]))
    assert all(est["cov_reduction_pct"][n] > 90.0 for n in names)


def test_rattle_method_replans_and_records_the_weights(tmp_path):
    cfg_path = small_iss(tmp_path / "rattle.yaml", rattle={"duration_s": 24.0, "replan_period_s": 12.0,
                                                           "limits": {"force_N": [0.15] * 3, "torque_Nm": [0.015] * 3}})
    out = tmp_path / "run"
    result = run_cli("excite", cfg_path, "--method", "rattle", "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "rattle" and summary["estimator"] == "sequential"
    assert {n for k, n in summary["files"].items() if k.startswith("png_")} == set(PNGS["excite"])
    assert summary["replans"] == 2 and summary["collision_free"] is True
    # The real sequential estimator (error-state EKF) ran in the loop: its estimate is consistent with its own
    # covariance and far better known than the prior (RATTLE's P0).
    est, prior_std = summary["estimate"], summary["prior_std"]
    truth = load_config(cfg_path).truth_params()
    theta_true = {"mass_kg": truth.mass_kg, "Ixx_kgm2": truth.inertia_kgm2[0], "Iyy_kgm2": truth.inertia_kgm2[1],
                  "Izz_kgm2": truth.inertia_kgm2[2]}
    for name, value in theta_true.items():
        assert abs(est["theta"][name] - value) <= 4.0 * est["std"][name] + 1e-12, name
        assert est["std"][name] < 0.2 * prior_std[name], name
    assert est["samples_used"] > 100
    assert summary["criterion_final"] < summary["criterion_initial"]
    record = read_stage(out / "excite.mcap")
    replans = record.json_records["/excitation/replans"]
    # RATTLE's terminal phase (excitation.rattle.terminal_hold_s 4 s): the replan whose 12 s horizon ends 4 s before
    # the end (24 - 4 - 12 = 8 s) is the last; it drops the information term (γ = 0) and plans to the goal at rest.
    assert [r["t"] for r in replans] == [0.0, 8.0] and summary["terminal_replan_s"] == 8.0
    rule = InformationWeighting()
    np.testing.assert_allclose(replans[0]["gamma"], rule.weights(np.array(replans[0]["std"])), rtol=1e-12)
    assert np.all(np.array(replans[0]["gamma"]) > 0) and np.all(np.array(replans[1]["gamma"]) == 0.0)
    assert summary["plan_goal_residual"]["position_m"] < 1e-6 and summary["status"] == "ok"
    assert_recording_opens_right(out / "excite.rrd", "excite-rattle")
    assert "metrics/gamma" in {v["origin"].strip("/") for v in read_blueprint_views(out / "excite.rrd")}
    traj = read_trajectory(out / "excite.mcap")
    np.testing.assert_allclose(np.diff(traj.t[:-1]), 0.2, atol=1e-9)  # the controller period (5 Hz)
    # The plans keep to the planner's caps (0.15 N) under the margin; the feedback around them may use the rest of
    # the actuator (the flown inputs), never more.
    assert np.all(np.array(summary["design_limits"]["force_N"]) <= 0.15 + 1e-12)
    robot = load_config(cfg_path).robot
    assert np.all(np.abs(traj.u[:, 0:6]) <= robot.input_limits * (1 + 1e-12))
    assert summary["within_robot_limits"] is True
    counts = check_json_records(out / "excite.mcap")
    assert counts["oacli.Replan"] == 2 and counts["oacli.Information"] == len(traj)
    t_gamma, gamma = read_recording_scalars(out / "excite.rrd")["metrics/gamma"]
    np.testing.assert_allclose(t_gamma, [0.0, 8.0], atol=1e-9)
    np.testing.assert_allclose(gamma, [r["gamma"] for r in replans], rtol=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# Bad input: one clear message, exit 2 (3 when infeasible), no run folder
# ----------------------------------------------------------------------------------------------------------------


def test_start_inside_a_keep_out_zone_is_refused(tmp_path):
    data = yaml.safe_load(ISS.read_text())
    data["environment"]["keep_out"] = [{"center": [10.8, -7.75, 5.2], "semi_axes_m": [0.2, 0.2, 0.2]}]
    cfg = tmp_path / "obstacle.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    result = run_cli("excite", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", code=2, must_name="environment.keep_out.0")
    assert "excitation.start" in result.stderr


def test_infeasible_limits_exit_3_without_a_run_folder(tmp_path):
    cfg = small_iss(tmp_path / "tiny.yaml", limits={"force_N": [0.005, 0.005, 0.005]})
    result = run_cli("excite", cfg, "--runs-dir", tmp_path / "runs")
    # 0.9 m along z with 0.005 N on 15 kg needs 2 sqrt(0.9 / 3.33e-4) = 104 s > 40 s.
    assert_clean_failure(result, tmp_path / "runs", code=3, must_name="along z")


def test_unknown_goal_and_missing_start_name_the_field(tmp_path):
    cfg = small_iss(tmp_path / "bad.yaml", goal="Z")
    result = run_cli("excite", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", code=2, must_name="excitation.goal")
    cfg = small_iss(tmp_path / "bad2.yaml", start=None)
    result = run_cli("excite", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", code=2, must_name="excitation.start")


def test_unknown_method_is_refused(tmp_path):
    result = run_cli("excite", ISS, "--method", "magic", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", code=2, must_name="--method")


def assert_recording_opens_right(rrd, stage):
    """Own application id (own layout when several recordings are open), no panel empty on the opening timeline."""
    assert read_application_id(rrd) == f"oacli-{stage}"
    assert read_blueprint_timeline(rrd) == "mission_time"
    assert read_blueprint_views(rrd), "no blueprint"
    assert empty_blueprint_views(rrd) == []


def test_excite_recording_opens_with_every_panel_filled(excite_run):
    rrd = excite_run / "excite.rrd"
    assert_recording_opens_right(rrd, "excite-offline")
    views = {v["origin"].strip("/") for v in read_blueprint_views(rrd)}
    assert {"charts/criterion", "metrics/velocity_mps", "metrics/crb_std_log10_pct"} <= views
    # log10 of the Cramer-Rao std in % of theta, from the summary's final values
    _, log_pct = read_recording_scalars(rrd)["metrics/crb_std_log10_pct"]
    summary = json.loads((excite_run / "summary.json").read_text())
    np.testing.assert_allclose(10 ** log_pct[-1], list(summary["crb_std_pct"].values()), rtol=1e-6)
