"""The mission's actuator calibration ([ReSWARM2023] Eqs. 38-39): segment-1/calibrate fits the force scale on the
known robot's flight and hands its mean and σ to segment 2's estimates as their prior.

The default-suite tests read the shrunk default mission of ``conftest.mission_run`` (``mission.calibration: true``
in configs/mission_iss.yaml) back, or derive stage configs without flying (a copied folder with one summary
changed, as in test_mission_status.py).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import config_from_dict, load_config
from oacli.config.overrides import apply_overrides
from oacli.io.mcap_read import read_stage
from oacli.mission.calibration import CALIBRATE_KEY, KNOWN_VARIANCE, actuator_calibration
from oacli.mission.configs import Handoff, seed_index, stage_config, stage_seed
from oacli.mission.layout import MISSION_STAGES, stage_by_key
from oacli.mission.run import handoff_for, mission_stages, mission_summary

ROOT = Path(__file__).resolve().parents[1]
RUNNER = CliRunner()
AXES = ("x", "y", "z")


def _cfg(*sets: str):
    data = apply_overrides(yaml.safe_load((ROOT / "configs" / "mission_iss.yaml").read_text()), list(sets))
    return config_from_dict(data, source="test")


def test_calibration_stage_fits_the_force_scale_and_segment_2_takes_it_as_prior(mission_run):
    run, cfg_path, output = mission_run
    cfg = load_config(cfg_path)
    assert cfg.mission.calibration
    assert "actuator calibration (segment 1, [ReSWARM2023] Eqs. 38-39): force scale" in output
    folder = stage_by_key(CALIBRATE_KEY).folder(run)
    cal = json.loads((folder / "summary.json").read_text())
    assert cal["stage"] == "estimate" and cal["status"] == "ok" and cal["converged"]
    assert read_stage(folder / "estimate.mcap").metadata["oacli"]["stage"] == "estimate"
    # It estimated segment 1's telemetry, the known robot held at robot: with a negligible variance.
    cal_cfg = load_config(folder / "config.yaml")
    assert Path(cal_cfg.inputs.estimate_telemetry) == (run / "segment-1/track/track.mcap").resolve()
    assert cal_cfg.estimation.method == "batch"
    assert cal_cfg.estimation.prior.mass_kg == cfg.robot.mass_kg
    assert cal_cfg.estimation.prior.variance == KNOWN_VARIANCE
    # Its force scale is within 3σ of the simulated thrusters' (truth.actuator_scale, never told the estimator).
    rb = cal["rigid_body"]
    kappa = np.array([rb["estimate"][f"force_scale_{a}"] for a in AXES])
    sigma = np.array([rb["std"][f"force_scale_{a}"] for a in AXES])
    truth = np.array(cfg.truth.actuator_scale[:3])
    assert np.all(np.abs(kappa - truth) <= 3 * sigma), (kappa, sigma, truth)
    assert np.all(sigma < 0.5 * cfg.estimation.rigid_body.force_scale_std)  # well below the config prior σ
    # Segment 2's batch and sequential estimates take it as their prior: config and summary read back.
    for key in ("segment-2/estimate", "segment-2/estimate-sequential"):
        stage_cfg = load_config(run / key / "config.yaml")
        np.testing.assert_array_equal(stage_cfg.estimation.rigid_body.force_scale, kappa)
        np.testing.assert_array_equal(stage_cfg.estimation.rigid_body.force_scale_std, sigma)
        prior_std = json.loads((run / key / "summary.json").read_text())["rigid_body"]["prior_std"]
        np.testing.assert_allclose([prior_std[f"force_scale_{a}"] for a in AXES], sigma, rtol=1e-12)
    summary = json.loads((run / "summary.json").read_text())
    assert summary["stages"][CALIBRATE_KEY]["status"] == cal["status"]
    entry = summary["calibration"]
    assert entry["source"] == "calibration" and entry["note"] is None
    np.testing.assert_array_equal(entry["force_scale"], kappa)
    assert all(abs(z) <= 3 for z in entry["z_score"].values())


def test_calibration_off_keeps_todays_stages_seeds_and_configs():
    """mission.calibration: false runs the stages and draws the seeds of the mission before the calibration; with
    it, only segment 2's estimates change (their rigid_body prior)."""
    on, off = _cfg(), _cfg("mission.calibration=false")
    assert CALIBRATE_KEY in [s.key for s in mission_stages(on)]
    before = [s for s in MISSION_STAGES if s.key != CALIBRATE_KEY]
    assert mission_stages(off) == tuple(before)
    assert [seed_index(s) for s in before] == list(range(len(before)))   # the seeds the stages had before
    handed = Handoff(telemetry=Path("t.mcap"), rigid_body={"force_scale": [1.03, 0.97, 1.02],
                                                           "force_scale_std": [0.003, 0.004, 0.005]})
    for stage in before:
        ref = Path("r.mcap") if stage.command == "track" else None
        plain = Handoff(reference=ref, telemetry=Path("t.mcap") if stage.command == "estimate" else None)
        a = stage_config(off, stage, plain).model_dump(mode="json")
        b = stage_config(on, stage, handed if stage.command == "estimate" else plain).model_dump(mode="json")
        assert a["seed"] == stage_seed(off.seed, MISSION_STAGES.index(stage) if stage.segment == "segment-1"
                                       else MISSION_STAGES.index(stage) - 1)
        if stage.command == "estimate":
            assert a["estimation"]["rigid_body"]["force_scale_std"] == 0.05
            assert b["estimation"]["rigid_body"]["force_scale"] == [1.03, 0.97, 1.02]
            a["estimation"].pop("rigid_body")
            b["estimation"].pop("rigid_body")
        assert a == b, stage.key


def test_an_unconverged_calibration_falls_back_to_the_config_prior(mission_run, tmp_path):
    run, _, _ = mission_run
    cfg = load_config(run / "config.yaml")
    out = tmp_path / "m"
    shutil.copytree(run, out)
    path = out / CALIBRATE_KEY / "summary.json"
    data = json.loads(path.read_text())
    data.update(converged=False, iterations=30)
    path.write_text(json.dumps(data))
    fallback = actuator_calibration(cfg, out)
    assert fallback.source == "config" and not fallback.rigid_body and "did not converge" in fallback.note
    handoff = handoff_for(cfg, stage_by_key("segment-2/estimate"), out)
    assert handoff.rigid_body == {}
    est = stage_config(cfg, stage_by_key("segment-2/estimate"), handoff).estimation
    assert est.rigid_body.force_scale_std == cfg.estimation.rigid_body.force_scale_std
    stages = mission_stages(cfg)
    results = {s.key: json.loads((s.folder(out) / "summary.json").read_text()) for s in stages}
    summary = mission_summary(cfg, out, stages, results)
    assert summary["status"] == "degraded"
    assert "calibration_fallback" in [r["kind"] for r in summary["status_reasons"]]
    assert summary["calibration"]["source"] == "config"
    # Converged but degraded (the actuator model does not fit segment 1, e.g. a saturating impeller): its small σ
    # would make segment 2's mass confidently wrong, so it is not handed on either.
    data.update(converged=True, status="degraded", status_reasons=[
        {"level": "degraded", "kind": "fit_chi2", "message": "χ² 1.42 × its expected value"}])
    path.write_text(json.dumps(data))
    degraded = actuator_calibration(cfg, out)
    assert degraded.source == "config" and "ended degraded (fit_chi2)" in degraded.note
    shutil.rmtree(out / CALIBRATE_KEY)   # the stage failed (handled): no folder at all
    assert "failed" in actuator_calibration(cfg, out).note


@pytest.mark.parametrize(("setting", "field"), [
    ("mission.calibration=maybe", "mission.calibration"),
    ("estimation.parameters=[mass, inertia, com]", "mission.calibration"),
    ("estimation.rigid_body.force_scale_std=[0.01, -0.01, 0.01]", "estimation.rigid_body.force_scale_std"),
])
def test_bad_calibration_settings_exit_2_naming_the_field(setting, field, tmp_path):
    result = RUNNER.invoke(app, ["mission", str(ROOT / "configs" / "mission_iss.yaml"), "--set", setting,
                                 "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert field in result.output and "Traceback" not in result.output
    assert not (tmp_path / "run" / "summary.json").exists()


def test_rigid_body_scale_std_per_axis_or_one_for_all():
    """``force_scale_std`` / ``torque_scale_std`` take one σ for the three body axes or one per axis (the
    calibration's), in the order of :meth:`RigidBodyPriorConfig.mean`."""
    from oacli.config.estimation import RigidBodyPriorConfig

    one = RigidBodyPriorConfig().std()
    np.testing.assert_array_equal(one, np.repeat([0.005, 0.01, 0.05, 0.05], 3))
    per_axis = RigidBodyPriorConfig(force_scale_std=(0.003, 0.004, 0.005), torque_scale_std=(0.03, 0.02, 0.01)).std()
    np.testing.assert_array_equal(per_axis[6:], [0.003, 0.004, 0.005, 0.03, 0.02, 0.01])
    np.testing.assert_array_equal(per_axis[:6], one[:6])


def test_from_a_stage_the_mission_does_not_run_exits_2(mission_run, tmp_path):
    """``--from segment-1/calibrate`` on a mission without the calibration: exit 2 naming the option, nothing
    copied or run (before: every stage was copied and the mission ran none of them again)."""
    run, _, _ = mission_run
    source = tmp_path / "source"
    source.mkdir()
    data = yaml.safe_load((run / "config.yaml").read_text())
    data["mission"]["calibration"] = False
    (source / "config.yaml").write_text(yaml.safe_dump(data))
    result = RUNNER.invoke(app, ["mission", str(source), "--from", CALIBRATE_KEY, "--out", str(tmp_path / "new")])
    assert result.exit_code == 2, result.output
    assert "--from: segment-1/calibrate is not a stage of this mission" in result.output
    assert not (tmp_path / "new" / "segment-1").exists()
