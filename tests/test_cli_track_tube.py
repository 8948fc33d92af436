"""End-to-end ``oacli track`` with ``controller: tube``: run the CLI, read the MCAP and the recording back, check."""

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
from oacli.io.rerun.read import (
    empty_blueprint_views,
    read_application_id,
    read_blueprint_timeline,
    read_blueprint_views,
    read_recording_component,
    read_recording_entities,
    read_recording_scalars,
)
from oacli.model.double_integrator import double_integrator
from oacli.sets import Polytope
from tests.conftest import MIT_ISS, REPO, require_shared
from tests.mcap_checks import check_json_records
from tests.plot_checks import PNGS

TUBE = REPO / "configs" / "iss_reswarm_tube.yaml"
runner = CliRunner()


def run_cli(*args: str):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def tube_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("tube") / "run"
    result = run_cli("track", TUBE, "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    return out


def design_record(run: Path) -> dict:
    (record,) = read_stage(run / "track.mcap", topics=["/tube/design"]).json_records["/tube/design"]
    return record


def test_summary_reports_the_tube(tube_run):
    expected = ["config.yaml", "summary.json", "track.mcap", "track.rrd", *PNGS["track"]]
    assert sorted(p.name for p in tube_run.iterdir()) == sorted(expected)
    s = json.loads((tube_run / "summary.json").read_text())
    assert s["status"] == "ok" and s["controller"] == "tube"
    assert s["tube_violations"] == 0 and s["constraint_violations"] == 0
    assert s["fallback_steps"] == 0 and s["solver_failures"] == 0 and s["safe_hold_steps"] == 0
    design = design_record(tube_run)
    assert s["rpi"] == {"s": [a["s"] for a in design["axes"]], "alpha": [a["alpha"] for a in design["axes"]],
                        "facets": [len(a["z_offsets"]) for a in design["axes"]]}
    assert s["tightened_force_N"] == [a["force_bounds_N"] for a in design["axes"]]
    assert s["tightened_velocity_mps"] == [a["velocity_bounds_mps"] for a in design["axes"]]
    for lo, hi in s["tightened_force_N"]:
        assert -0.15 < lo < 0 < hi < 0.15  # U ⊖ K Z strictly inside U = [−0.15, 0.15] N
    assert s["tube"]["lasso_violations"] == 0 and s["tube"]["force_limit_violations"] == 0
    assert load_config(tube_run / "config.yaml") == load_config(TUBE)


def test_json_records_follow_the_contract_schemas(tube_run):
    counts = check_json_records(tube_run / "track.mcap")
    steps = json.loads((tube_run / "summary.json").read_text())["control_steps"]
    assert counts["oacli.TubeDesign"] == 1 and counts["oacli.TubeDisturbance"] == steps
    assert counts["oacli.SolverStats"] == steps


def test_inputs_are_nominal_plus_ancillary_and_the_state_stays_in_the_tube(tube_run):
    """u = v + K (x − z) sample by sample; the realised one-step disturbance lies in W, and then x − z ∈ Z at
    every control step and x⁺ − (A z + B v) ∈ Z (the promised tube)."""
    rec = read_stage(tube_run / "track.mcap")
    tel = read_telemetry(tube_run / "track.mcap")
    for topic in ("/control/nominal", "/control/ancillary", "/state/nominal", "/control/command", "/tube/design"):
        assert topic in rec.topics, topic
    t_nom, nominal = rec.wrenches["/control/nominal"]
    t_anc, ancillary = rec.wrenches["/control/ancillary"]
    z_traj = rec.trajectories["/state/nominal"]
    np.testing.assert_array_equal(t_nom, tel.t_ctrl)
    np.testing.assert_array_equal(t_anc, tel.t_ctrl)
    np.testing.assert_array_equal(z_traj.t, tel.t_ctrl)
    z = z_traj.x[:, 0:6]
    v = nominal[:, 0:3]
    np.testing.assert_allclose(tel.u_command[:, 0:3], v + ancillary[:, 0:3], atol=1e-15)
    np.testing.assert_allclose(tel.u_command[:, 3:6], nominal[:, 3:6], atol=0)  # attitude: no ancillary part
    design = design_record(tube_run)
    cfg = load_config(TUBE)
    a, b = double_integrator(design["dt_s"], 1.0 / cfg.robot.mass_kg)
    sensors = cfg.sensors
    assert sensors.position_std_m == sensors.velocity_std_mps == 0.0  # so the measured state is the true state
    x_true_ctrl = tel.x_measured  # true state at the control instants (0.2 s is not a multiple of 1/62.5 s)
    both = np.isin(tel.t_true, tel.t_ctrl)  # where the plant grid hits a control instant, the two agree
    np.testing.assert_array_equal(tel.x_true[both][:, 0:6], tel.x_measured[np.isin(tel.t_ctrl, tel.t_true)][:, 0:6])
    for i, axis in enumerate(design["axes"]):
        cols = [i, i + 3]
        k = np.array(axis["gain"])
        zset = Polytope(np.array(axis["z_normals"]), np.array(axis["z_offsets"]))
        wset = Polytope.from_vertices(np.array(axis["w_vertices"]))
        e = tel.x_measured[:, cols] - z[:, cols]
        np.testing.assert_allclose(ancillary[:, i], e @ k, atol=1e-14)  # u_anc = K (x − z)
        assert np.all(zset.contains_points(e))  # x − z ∈ Z at every control step
        # The truth is within W: x_{k+1} − (A x_k + B u_k) ∈ W for every step (mass 9.58 kg in 9.5 ± 0.2 kg and
        # the ±0.002 N force of the preset) ...
        x_k = x_true_ctrl[:, cols]
        w_real = x_k[1:] - x_k[:-1] @ a.T - tel.u_applied[:-1, i : i + 1] @ b.T
        assert np.all(wset.contains_points(w_real, tol=1e-12))
        assert np.abs(w_real).max() > 0.3 * np.abs(wset.vertices).max()  # (and not trivially small)
        # ... so the state stays in the promised tube around the predicted nominal.
        z_next = z[:-1, cols] @ a.T + v[:-1, i : i + 1] @ b.T
        assert np.all(zset.contains_points(x_k[1:] - z_next, tol=1e-12))
        # Nominal inside the tightened sets.
        assert np.all(np.abs(v[:, i]) <= axis["force_bounds_N"][1] * (1 + 1e-9))
        assert np.all(np.abs(z[:, i + 3]) <= axis["velocity_bounds_mps"][1] * (1 + 1e-9))
    assert np.all(np.abs(tel.u_command[:, 0:3]) <= 0.15 * (1 + 1e-6))


def test_recording_shows_the_tube_and_the_split_inputs(tube_run):
    rrd = tube_run / "track.rrd"
    entities = read_recording_entities(rrd)
    for entity in ("world/tube", "world/nominal", "world/nominal/centre", "metrics/tube/force_nominal_N",
                   "metrics/tube/force_ancillary_N", "metrics/tube/nominal_velocity_mps", "metrics/tube/tube_margin",
                   "metrics/force_N", "world/robot"):
        assert entity in entities, entity
    rec = read_stage(tube_run / "track.mcap")
    _, nominal = rec.wrenches["/control/nominal"]
    _, ancillary = rec.wrenches["/control/ancillary"]
    scalars = read_recording_scalars(rrd)
    np.testing.assert_allclose(scalars["metrics/tube/force_nominal_N"][1], nominal[:, 0:3], atol=1e-12)
    np.testing.assert_allclose(scalars["metrics/tube/force_ancillary_N"][1], ancillary[:, 0:3], atol=1e-12)
    s = json.loads((tube_run / "summary.json").read_text())
    limit = scalars["metrics/tube/force_nominal_N/limit_upper"][1]
    np.testing.assert_allclose(limit[0], [hi for _, hi in s["tightened_force_N"]], rtol=1e-12)
    # The tube boxes: centred on the nominal positions, as wide as Z's projection on position.
    _, centers = read_recording_component(rrd, "world/tube", "Boxes3D:centers")
    _, half = read_recording_component(rrd, "world/tube", "Boxes3D:half_sizes")
    z = rec.trajectories["/state/nominal"].x[:, 0:3]
    np.testing.assert_allclose(centers[0], z, atol=1e-4)  # float32 in the recording
    design = design_record(tube_run)
    extent = [Polytope(np.array(a["z_normals"]), np.array(a["z_offsets"])).support(np.array([1.0, 0.0]))
              for a in design["axes"]]
    np.testing.assert_allclose(half[0][0], extent, rtol=1e-6)


def test_tracks_the_mit_iss_reference_with_zero_violations(tmp_path):
    """MIT-ISS reference (RATTLE release, 140 s at 0.2 s) with the ReSWARM tube settings (u_max 0.15 N).

    The reference steps its velocity by 0.0408 m/s within one 0.2 s sample (a 2 N impulse for 9.5 kg), beyond
    what 0.15 N can follow: the stated bound is RMS ≤ 2 cm, max ≤ 6 cm, with zero constraint and tube violations.
    """
    require_shared(MIT_ISS)
    out = tmp_path / "run"
    result = run_cli("track", TUBE, "--reference", MIT_ISS, "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    s = json.loads((out / "summary.json").read_text())
    assert s["constraint_violations"] == 0 and s["tube_violations"] == 0
    assert s["fallback_steps"] == 0 and s["solver_failures"] == 0
    assert s["tube"]["force_limit_violations"] == 0
    assert s["rms_position_error_m"] <= 0.02 and s["max_position_error_m"] <= 0.06
    assert s["final_position_error_m"] <= 0.01
    assert s["sim_time_s"] == pytest.approx(139.8 + 5.0, abs=0.2)


def write_variant(tmp_path: Path, edit) -> Path:
    data = yaml.safe_load(TUBE.read_text())
    edit(data)
    path = tmp_path / "variant.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_too_large_w_stops_with_exit_3_and_leaves_no_run_folder(tmp_path):
    cfg = write_variant(tmp_path, lambda d: d["controller"]["tube"]["disturbance"].update(force_N=[0.2] * 3))
    result = run_cli("track", cfg, "--runs-dir", tmp_path / "runs")
    assert result.exit_code == 3, result.output
    assert "Traceback" not in result.output
    assert "actuator margin" in result.stderr and "W per 0.2 s control step" in result.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


@pytest.mark.parametrize(("edit", "field"), [
    (lambda d: d["controller"]["tube"].update(prediction_step_s=0.3), "controller.tube.prediction_step_s"),
    (lambda d: d["controller"]["tube"].update(force_limit_N=[0.5, 0.15, 0.15]), "controller.tube.force_limit_N.0"),
    (lambda d: d["robot"].update(variance=[25.0, 0.0, 0.0, 0.0]), "controller.tube.disturbance.mass_sigmas"),
    (lambda d: d["controller"]["tube"].update(rpi_epsilon=-1.0), "controller.tube.rpi_epsilon"),
    (lambda d: d["controller"]["tube"].update(lasso=1), "controller.tube.lasso"),
])
def test_bad_tube_settings_name_the_field(tmp_path, edit, field):
    cfg = write_variant(tmp_path, edit)
    result = run_cli("track", cfg, "--runs-dir", tmp_path / "runs")
    assert result.exit_code == 2, result.output
    assert field in result.stderr, result.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def assert_recording_opens_right(rrd, stage):
    """Own application id (own layout when several recordings are open), no panel empty on the opening timeline."""
    assert read_application_id(rrd) == f"oacli-{stage}"
    assert read_blueprint_timeline(rrd) == "mission_time"
    assert read_blueprint_views(rrd), "no blueprint"
    assert empty_blueprint_views(rrd) == []


def test_tube_track_recording_opens_with_every_panel_filled(tube_run):
    assert_recording_opens_right(tube_run / "track.rrd", "track-tube")


def test_a_tube_with_w_shrunk_by_scale_w_ends_degraded_saying_so(tmp_path):
    # The W of test_too_large_w_... (no tube for it) flown with the explicit policy: W is shrunk per axis, so the
    # tube guarantees less than the model's uncertainty says; the run must not claim "ok" (status honesty).
    cfg = write_variant(tmp_path, lambda d: d["controller"]["tube"]["disturbance"].update(
        force_N=[0.2] * 3, on_empty_tightening="scale_w"))
    out = tmp_path / "run"
    result = run_cli("track", cfg, "--out", out, "--quiet")
    assert result.exit_code == 0, result.output  # degraded exits 0
    s = json.loads((out / "summary.json").read_text())
    scales = [a["w_scale"] for a in design_record(out)["axes"]]
    assert s["tube"]["w_scale"] == scales and all(0 < v < 1 for v in scales)
    assert s["status"] == "degraded"
    (reason,) = [r for r in s["status_reasons"] if r["kind"] == "w_scaled"]
    assert reason["level"] == "degraded" and "scale_w" in reason["message"]
    assert f"x to {scales[0]:.3g}" in reason["message"]
