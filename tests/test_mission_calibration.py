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
from oacli.mission.calibration import (
    CALIBRATE_KEY,
    CHI2_ACCEPT_MAX,
    CONSISTENCY_Z_MAX,
    KNOWN_PRODUCTS_STD,
    KNOWN_VARIANCE,
    MANOEUVRE_KEY,
    ON_MANOEUVRE_KEY,
    PRIOR_Z_MAX,
    actuator_calibration,
    assess_calibration,
    config_actuator_prior,
    handed_rigid_body,
    reconcile_flights,
)
from oacli.mission.calibration_linearity import Z_SATURATION
from oacli.mission.configs import Handoff, seed_index, stage_config, stage_seed
from oacli.mission.layout import MISSION_STAGES, stage_by_key
from oacli.mission.run import handoff_for, mission_stages, mission_summary
from oacli.model import quaternion as quat

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
    assert "; torque scale " in output   # the manoeuvre's: segment 2 holds them
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
    # Segment 2's batch and sequential estimates take the last calibration (the manoeuvre's, fitted from this one's
    # scales, when it is flown) as their prior, its torque scales as their held values: config and summary read back.
    assert cfg.mission.calibration_manoeuvre is not None   # the default mission flies it
    on_manoeuvre = stage_by_key(ON_MANOEUVRE_KEY).folder(run)
    last = json.loads((on_manoeuvre / "summary.json").read_text())["rigid_body"]
    chained = load_config(on_manoeuvre / "config.yaml").estimation.rigid_body   # fitted from this one's scales
    np.testing.assert_array_equal(chained.force_scale, kappa)
    np.testing.assert_array_equal(chained.force_scale_std, sigma)
    handed = {g: np.array([last["estimate"][f"{g}_{a}"] for a in AXES]) for g in ("force_scale", "torque_scale")}
    handed_std = {g: np.array([last["std"][f"{g}_{a}"] for a in AXES]) for g in ("force_scale", "torque_scale")}
    assert np.all(handed_std["torque_scale"] < 0.2 * 0.05)   # the slews calibrate κ_τ far below the 5 % prior
    for key in ("segment-2/estimate", "segment-2/estimate-sequential"):
        stage_cfg = load_config(run / key / "config.yaml")
        for group in ("force_scale", "torque_scale"):
            np.testing.assert_array_equal(getattr(stage_cfg.estimation.rigid_body, group), handed[group])
            np.testing.assert_array_equal(getattr(stage_cfg.estimation.rigid_body, f"{group}_std"), handed_std[group])
        stage_summary = json.loads((run / key / "summary.json").read_text())
        prior_std = stage_summary["rigid_body"]["prior_std"]
        np.testing.assert_allclose([prior_std[f"force_scale_{a}"] for a in AXES], handed_std["force_scale"],
                                   rtol=1e-12)
        # The held κ_τ's σ in the consider covariance is the calibrated one: physical² = statistical² + Σ_j (S_ij
        # σ_j)² (the held entries independent), and the inertias' σ is well under the 5 % κ_τ prior's ~4 %.
        consider = stage_summary["consider"]
        assert consider["held"] == [f"torque_scale_{a}" for a in AXES]
        for name in ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2"):
            spread = sum((consider["sensitivity"][name][f"torque_scale_{a}"] * sd) ** 2
                         for a, sd in zip(AXES, handed_std["torque_scale"], strict=True))
            assert consider["std_physical"][name] ** 2 == pytest.approx(consider["std_statistical"][name] ** 2
                                                                        + spread, rel=1e-6), name
        rb = stage_summary["rigid_body"]
        assert all(consider["std_physical"][n] < 0.015 * rb["estimate"][n] for n in ("Ixx_kgm2", "Iyy_kgm2",
                                                                                    "Izz_kgm2"))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["stages"][CALIBRATE_KEY]["status"] == cal["status"]
    entry = summary["calibration"]
    assert entry["source"] == "calibration" and entry["note"] is None and entry["stage"] == ON_MANOEUVRE_KEY
    np.testing.assert_array_equal(entry["force_scale"], handed["force_scale"])
    assert all(abs(z) <= 3 for z in entry["z_score"].values())


def test_calibration_off_keeps_todays_stages_seeds_and_configs():
    """mission.calibration: false runs the stages and draws the seeds of the mission before the calibration; with
    it, only segment 2's estimates change (their rigid_body prior)."""
    on = _cfg("mission.calibration_manoeuvre=null")
    off = _cfg("mission.calibration=false", "mission.calibration_manoeuvre=null")
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
    flown = load_config(run / "config.yaml")
    out = tmp_path / "m"
    shutil.copytree(run, out)
    path = out / CALIBRATE_KEY / "summary.json"
    data = json.loads(path.read_text())
    data.update(converged=False, iterations=30)
    path.write_text(json.dumps(data))
    # With the manoeuvre (the default): its own fit, from the config's prior, is handed on and the first one's
    # failure is named.
    chained = actuator_calibration(flown, out)
    assert chained.source == "calibration" and chained.stage == ON_MANOEUVRE_KEY
    assert f"{CALIBRATE_KEY} did not converge" in chained.note and "fitted from the config's prior" in chained.note
    # Without it, segment 2 falls back to the config's prior.
    cfg = flown.model_copy(update={"mission": flown.mission.model_copy(update={"calibration_manoeuvre": None})})
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
    # A χ² far above the accepted ratio is not handed on (up to CHI2_ACCEPT_MAX it is, σ inflated: below).
    data.update(converged=True, status="degraded", chi2_ratio=2.5, status_reasons=[
        {"level": "degraded", "kind": "fit_chi2", "message": "χ² 2.5 × its expected value"}])
    path.write_text(json.dumps(data))
    degraded = actuator_calibration(cfg, out)
    assert degraded.source == "config" and "ended degraded (fit_chi2; χ² 2.5" in degraded.note
    shutil.rmtree(out / CALIBRATE_KEY)   # the stage failed (handled): no folder at all
    assert "failed" in actuator_calibration(cfg, out).note


@pytest.mark.parametrize(("setting", "field"), [
    ("mission.calibration=maybe", "mission.calibration"),
    ("mission.calibration_manoeuvre={angle_rad: 2}", "mission.calibration_manoeuvre.angle_rad"),
    ("mission.calibration_manoeuvre={repeats: 0}", "mission.calibration_manoeuvre.repeats"),
    ("mission.calibration_manoeuvre=5", "mission.calibration_manoeuvre"),
    # beyond the robot's torque limit: the manoeuvre's reference is refused up front, naming the option
    ("mission.calibration_manoeuvre={angular_acceleration_radps2: 0.5}", "mission.calibration_manoeuvre"),
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
    data["mission"].update(calibration=False, calibration_manoeuvre=None)
    (source / "config.yaml").write_text(yaml.safe_dump(data))
    result = RUNNER.invoke(app, ["mission", str(source), "--from", CALIBRATE_KEY, "--out", str(tmp_path / "new")])
    assert result.exit_code == 2, result.output
    assert "--from: segment-1/calibrate is not a stage of this mission" in result.output
    assert not (tmp_path / "new" / "segment-1").exists()


def test_bad_manoeuvre_without_calibration_exits_2(tmp_path):
    result = RUNNER.invoke(app, ["mission", str(ROOT / "configs" / "mission_iss.yaml"), "--set",
                                 "mission.calibration=false", "--set", "mission.calibration_manoeuvre={}",
                                 "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert "mission.calibration_manoeuvre" in result.output and "needs mission.calibration: true" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()


def test_a_calibration_with_nothing_to_calibrate_exits_2_naming_the_way_out(tmp_path):
    """estimation.parameters without a scale group leaves the calibration nothing to fit: exit 2 before anything
    flies, naming the field and both settings that turn the calibration off (the default flies the manoeuvre,
    which needs the calibration); that way out gives a mission whose every stage has a valid config."""
    sets = "estimation.parameters=[mass, inertia, products, com]"
    result = RUNNER.invoke(app, ["mission", str(ROOT / "configs" / "mission_iss.yaml"), "--set", sets,
                                 "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert "needs force_scale or torque_scale in estimation.parameters" in result.output
    assert "set mission.calibration: false and mission.calibration_manoeuvre: null" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()
    cfg = _cfg(sets, "mission.calibration=false", "mission.calibration_manoeuvre=null")
    keys = [s.key for s in mission_stages(cfg)]
    assert CALIBRATE_KEY not in keys and MANOEUVRE_KEY not in keys
    for stage in mission_stages(cfg):
        stage_config(cfg, stage, Handoff(telemetry=Path("t.mcap") if stage.command == "estimate" else None,
                                         reference=Path("r.mcap") if stage.command == "track" else None))


MANOEUVRE_SETS = ("mission.calibration_manoeuvre={}",
                  "estimation.parameters=[mass, inertia, com, force_scale, torque_scale]")


def test_manoeuvre_stages_reference_and_calibration_configs():
    """The manoeuvre (segment-1/calibrate-manoeuvre) flies at B between segment 1 and the grasp: about each body axis
    +angle, -angle, back, within the rate and torque limits; segment-1/calibrate-on-manoeuvre fits its telemetry
    from the first calibration's scales with the known robot's m, I and products held. The other stages keep
    their seeds."""
    from oacli.stages.track import reference_from_config

    cfg = _cfg(*MANOEUVRE_SETS)
    man = cfg.mission.calibration_manoeuvre
    keys = [s.key for s in mission_stages(cfg)]
    i = keys.index("segment-1/track")
    assert keys[i + 1:i + 4] == [MANOEUVRE_KEY, CALIBRATE_KEY, ON_MANOEUVRE_KEY]
    assert keys[i + 4] == "segment-2/excite"
    plain = _cfg("estimation.parameters=[mass, inertia, com, force_scale, torque_scale]",
                 "mission.calibration_manoeuvre=null")
    assert [k for k in keys if k not in (MANOEUVRE_KEY, ON_MANOEUVRE_KEY)] == [s.key for s in mission_stages(plain)]
    seeds = {k: seed_index(stage_by_key(k)) for k in keys}
    assert len(set(seeds.values())) == len(seeds)
    assert all(seeds[s.key] == seed_index(s) for s in mission_stages(plain))

    stage_cfg = stage_config(cfg, stage_by_key(MANOEUVRE_KEY), Handoff(initial_offset_m=(0.01, -0.02, 0.0)))
    assert stage_cfg.controller.type == "mpc" and stage_cfg.truth.mass_kg == cfg.truth.mass_kg  # the bare robot
    assert stage_cfg.simulation.initial_offset_m == (0.01, -0.02, 0.0)   # where segment 1 ended
    ref = reference_from_config(stage_cfg)
    b = cfg.waypoints["B"]
    np.testing.assert_allclose(ref.x[0, 0:3], b.position, atol=1e-12)
    np.testing.assert_allclose(ref.x[-1, 0:3], b.position, atol=1e-12)
    assert quat.angle_between(ref.x[-1, 6:10], np.asarray(b.quaternion)) < 1e-9
    # Body-frame rotation from B's attitude: each axis reaches ±angle about itself alone, in x, y, z order.
    rot = np.array([quat.error_vector(np.asarray(b.quaternion), q) for q in ref.x[:, 6:10]])
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        moving = np.abs(rot[:, axis]) > 1e-6
        assert np.all(np.abs(rot[moving][:, others]) < 1e-6)
        np.testing.assert_allclose([rot[:, axis].max(), rot[:, axis].min()], [man.angle_rad, -man.angle_rad],
                                   atol=1e-6)
    assert np.abs(ref.x[:, 10:13]).max() <= man.angular_rate_radps + 1e-9
    assert np.all(np.abs(ref.u[:, 3:6]) < np.asarray(cfg.robot.torque_limit_Nm))   # feed-forward within limits
    assert np.abs(ref.u[:, 3:6]).max() > 0.3 * min(cfg.robot.torque_limit_Nm)       # and rotation-rich

    cal = stage_config(cfg, stage_by_key(ON_MANOEUVRE_KEY), Handoff(
        telemetry=Path("m.mcap"), rigid_body={"force_scale": [1.03, 0.97, 1.02], "force_scale_std": [0.003] * 3}))
    assert cal.estimation.method == "batch" and cal.estimation.prior.variance == KNOWN_VARIANCE
    assert cal.estimation.rigid_body.products_std_kgm2 == KNOWN_PRODUCTS_STD
    assert cal.estimation.rigid_body.force_scale == (1.03, 0.97, 1.02)
    assert Path(cal.inputs.estimate_telemetry).name == "m.mcap"
    assert "torque_scale" in cal.estimation.parameters
    first = stage_config(cfg, stage_by_key(CALIBRATE_KEY), Handoff(telemetry=Path("t.mcap"), rigid_body={
        "force_scale": [1.03, 0.97, 1.02], "force_scale_std": [0.003] * 3}))
    assert first.estimation.rigid_body == plain.estimation.rigid_body   # the first one: the config's prior


def test_the_manoeuvre_calibrates_the_torque_scales_segment_2_holds():
    """The default mission estimates no torque scale in segment 2, yet its manoeuvre calibration fits them (the
    slews inform κ_τ); segment 2 holds the calibrated κ_τ ± σ, which its consider covariance then carries
    (oacli.estimation.consider) instead of the config's 5 %. Segment 1's calibration fits segment 2's groups only."""
    cfg = _cfg()
    assert cfg.mission.calibration_manoeuvre is not None and "torque_scale" not in cfg.estimation.parameters
    on_manoeuvre = stage_config(cfg, stage_by_key(ON_MANOEUVRE_KEY), Handoff(telemetry=Path("m.mcap"))).estimation
    assert {"force_scale", "torque_scale"} <= set(on_manoeuvre.parameters)
    assert set(cfg.estimation.parameters) <= set(on_manoeuvre.parameters)
    first = stage_config(cfg, stage_by_key(CALIBRATE_KEY), Handoff(telemetry=Path("t.mcap"))).estimation
    assert first.parameters == cfg.estimation.parameters
    handed = handed_rigid_body(_summary(std=0.003))
    assert handed["torque_scale"] == [1.04, 0.96, 1.05]
    est = stage_config(cfg, stage_by_key("segment-2/estimate"), Handoff(telemetry=Path("t.mcap"),
                                                                         rigid_body=handed)).estimation
    assert "torque_scale" not in est.parameters
    assert est.rigid_body.torque_scale == (1.04, 0.96, 1.05) and est.rigid_body.torque_scale_std == (0.003,) * 3


def _summary(std=0.004, **changes):
    est = {f"{g}_{a}": v for g, vals in (("force_scale", (1.03, 0.97, 1.02)), ("torque_scale", (1.04, 0.96, 1.05)))
           for a, v in zip(AXES, vals, strict=True)}
    data = {"status": "ok", "status_reasons": [], "converged": True, "covariance_identified": True,
            "std": {"mass_kg": 1e-4}, "chi2_ratio": 1.02,
            "rigid_body": {"estimate": est, "std": dict.fromkeys(est, std)}}
    data.update(changes)
    return data


CONFIG_PRIOR = {"force_scale": [1.0] * 3, "force_scale_std": [0.05] * 3,
                "torque_scale": [1.0] * 3, "torque_scale_std": [0.05] * 3}


def test_acceptance_rule_inflates_a_moderate_chi2_and_rejects_a_contradicted_prior():
    ok = _summary()
    handed, problems, inflation = assess_calibration(ok, CONFIG_PRIOR)
    assert not problems and inflation == 1.0 and handed == handed_rigid_body(ok)
    # degraded by a χ² 1.44 × expected only (e.g. localisation jumps): handed on, σ × √1.44 = 1.2 (Birge ratio)
    reasons = [{"kind": "fit_chi2"}, {"kind": "rejected"}]
    handed, problems, inflation = assess_calibration(_summary(status="degraded", chi2_ratio=1.44,
                                                              status_reasons=reasons), CONFIG_PRIOR)
    assert not problems and inflation == pytest.approx(1.2)
    np.testing.assert_allclose(handed["torque_scale_std"], [0.0048] * 3)
    for bad in (_summary(status="degraded", chi2_ratio=CHI2_ACCEPT_MAX * 1.01, status_reasons=reasons),
                _summary(status="degraded", status_reasons=[{"kind": "gate_empty"}]),
                _summary(converged=False, iterations=30)):
        handed, problems, _ = assess_calibration(bad, CONFIG_PRIOR)
        assert handed == {} and problems
    # A saturating impeller: κ_y 0.658 (campaign run, truth 0.857) is 6.8 prior σ from 1: not handed on.
    sat = _summary()
    sat["rigid_body"]["estimate"]["force_scale_y"] = 0.658
    handed, problems, _ = assess_calibration(sat, CONFIG_PRIOR)
    assert handed == {} and "force_scale_y 0.6580 contradicts its prior" in problems[0]
    # Chained (the manoeuvre's fit from the first calibration): the shift posterior - prior has variance
    # σ_prior² - σ_post²; a shift of 4.5 of those σ is two flights that disagree, 3.5 is not.
    first = handed_rigid_body(_summary(std=0.003))
    post_std = 0.0029
    spread = np.sqrt(0.003**2 - post_std**2)
    for shift, rejected in ((4.5 * spread, True), (3.5 * spread, False)):
        second = _summary(std=post_std)
        second["rigid_body"]["estimate"]["torque_scale_z"] = 1.05 + shift
        handed, problems, _ = assess_calibration(second, first)
        assert bool(problems) is rejected and (handed == {}) is rejected
        if rejected:
            assert f"accepted up to {PRIOR_Z_MAX:g}" in problems[0] and "torque_scale_z" in problems[0]


def test_the_prior_test_uses_the_fits_own_sigma_not_the_consider_covariance():
    """A calibration whose consider covariance (docs/estimation.md: what the fit holds fixed) widens κ_y's σ to the
    prior's 5 %: the shift of κ_y 0.9686 (a payload-envelope run's) is judged against the fit's own σ, as the update
    formula assumes, so it is handed on (with the wide σ); before, σ_prior² − σ_post² ≈ 0 made it 63 σ and the
    calibration was refused as a saturating actuator. A saturating impeller's κ_y 0.658 is still refused."""
    wide = _summary()
    wide["rigid_body"]["estimate"]["force_scale_y"] = 0.9686
    wide["rigid_body"]["std"]["force_scale_y"] = 0.0508
    wide["consider"] = {"std_statistical": dict.fromkeys(wide["rigid_body"]["estimate"], 0.0017)}
    handed, problems, _ = assess_calibration(wide, CONFIG_PRIOR)
    assert not problems and handed["force_scale_std"][1] == pytest.approx(0.0508)
    wide["rigid_body"]["estimate"]["force_scale_y"] = 0.658
    handed, problems, _ = assess_calibration(wide, CONFIG_PRIOR)
    assert handed == {} and "force_scale_y 0.6580 contradicts its prior" in problems[0]


def test_two_flights_that_disagree_hand_on_the_manoeuvres_own_estimate():
    """Segment 1 (κ₁ ± σ₁) is the manoeuvre's prior; its own data say κ_d ± σ_d, the fit κ₂ the inverse-variance
    combination. Agreeing flights keep κ₂; on a disagreement (a saturating impeller biased segment 1's κ_x,
    campaign run 2: 0.9997 ± 0.0032 against the truth 1.0355) κ_d ± σ_d is recovered exactly and handed on."""
    first = {"force_scale": [0.9997, 0.97, 1.02], "force_scale_std": [0.0032, 0.004, 0.004]}

    def fit(kd, sd):  # the scalar Gaussian update the batch fit makes per axis
        post_var = 1.0 / (1.0 / first["force_scale_std"][0] ** 2 + 1.0 / sd**2)
        kappa = post_var * (first["force_scale"][0] / first["force_scale_std"][0] ** 2 + kd / sd**2)
        return {"force_scale": [kappa, 0.97, 1.02], "force_scale_std": [np.sqrt(post_var), 0.0039, 0.0039]}

    handed, replaced, problems = reconcile_flights(fit(1.0300, 0.009), first)   # z 3.2: disagree
    assert not problems and len(replaced) == 1 and replaced[0].startswith("force_scale_x")
    np.testing.assert_allclose([handed["force_scale"][0], handed["force_scale_std"][0]], [1.0300, 0.009], rtol=1e-9)
    assert handed["force_scale"][1:] == [0.97, 1.02]
    inflated = fit(1.0300, 0.009)   # as assess_calibration hands it: σ × 1.5 (a χ² of 2.25 × expected)
    inflated["force_scale_std"] = [1.5 * v for v in inflated["force_scale_std"]]
    handed, replaced, _ = reconcile_flights(inflated, first, inflation=1.5)   # σ_d inflated too
    np.testing.assert_allclose(handed["force_scale_std"][0], 1.5 * 0.009, rtol=1e-9)
    second = fit(1.0050, 0.009)   # z 0.55: agree, κ₂ kept
    handed, replaced, problems = reconcile_flights(second, first)
    assert handed == second and not replaced and not problems
    z = (1.0300 - 0.9997) / np.hypot(0.009, 0.0032)
    assert z > CONSISTENCY_Z_MAX > (1.0050 - 0.9997) / np.hypot(0.009, 0.0032)


def test_manoeuvre_calibration_is_handed_on_and_a_rejected_first_one_noted(mission_run, tmp_path):
    """With the manoeuvre, segment 2 takes segment-1/calibrate-on-manoeuvre's scales; when the first calibration
    was rejected the second (then fitted from the config's prior) is still handed on, with a note and no fallback."""
    run, _, _ = mission_run
    cfg = _cfg(*MANOEUVRE_SETS)
    out = tmp_path / "m"
    (out / "segment-1").mkdir(parents=True)
    shutil.copytree(run / CALIBRATE_KEY, out / CALIBRATE_KEY)
    shutil.copytree(run / CALIBRATE_KEY, out / ON_MANOEUVRE_KEY)
    second = json.loads((out / ON_MANOEUVRE_KEY / "summary.json").read_text())
    first = json.loads((out / CALIBRATE_KEY / "summary.json").read_text())
    cal = actuator_calibration(cfg, out)
    assert cal.source == "calibration" and cal.stage == ON_MANOEUVRE_KEY and cal.note is None
    assert cal.rigid_body == handed_rigid_body(second)
    assert cal.summary()["stage"] == ON_MANOEUVRE_KEY
    handoff = handoff_for(cfg, stage_by_key(ON_MANOEUVRE_KEY), out)   # fitted from the first's scales
    assert handoff.rigid_body == handed_rigid_body(first)
    assert handoff.telemetry.parent.name == "calibrate-manoeuvre"
    first.update(converged=False, iterations=30)
    (out / CALIBRATE_KEY / "summary.json").write_text(json.dumps(first))
    assert handoff_for(cfg, stage_by_key(ON_MANOEUVRE_KEY), out).rigid_body is None   # the config's prior
    cal = actuator_calibration(cfg, out)
    assert cal.source == "calibration" and "segment-1/calibrate did not converge" in cal.note
    shutil.rmtree(out / ON_MANOEUVRE_KEY)
    cal = actuator_calibration(cfg, out)
    assert cal.source == "config" and "segment-1/calibrate-on-manoeuvre failed" in cal.note


def _fly_manoeuvre(out: Path, *sets: str):
    """Fly the manoeuvre with known actuator scales and fit it as segment-1/calibrate-on-manoeuvre does."""
    from oacli.stages.estimate import run_estimate
    from oacli.stages.track import run_track

    cfg = _cfg(*MANOEUVRE_SETS, "truth.actuator_scale=[1.03, 0.97, 1.02, 1.04, 0.96, 1.05]", *sets)
    track = run_track(stage_config(cfg, stage_by_key(MANOEUVRE_KEY), Handoff()), out=out / "track", progress=None)
    assert track.summary["status"] == "ok"
    telemetry = out / "track" / "track.mcap"
    est = run_estimate(stage_config(cfg, stage_by_key(ON_MANOEUVRE_KEY), Handoff(telemetry=telemetry)),
                       telemetry=telemetry, out=out / "estimate", progress=None)
    return cfg, est.summary


def test_manoeuvre_recovers_the_force_and_torque_scales(tmp_path):
    """A simulated manoeuvre of the known robot (truth κ_F 1.03 / 0.97 / 1.02, κ_τ 1.04 / 0.96 / 1.05, never told
    the estimator) calibrates both within 3 of their σ, the torque scales to < 0.5 % (segment 1's flight: 3-4 %,
    docs/estimation.md), and is handed on."""
    cfg, summary = _fly_manoeuvre(tmp_path)
    assert summary["status"] == "ok" and summary["converged"]
    rb = summary["rigid_body"]
    for group, truth in (("force_scale", cfg.truth.actuator_scale[:3]), ("torque_scale", cfg.truth.actuator_scale[3:])):
        est = np.array([rb["estimate"][f"{group}_{a}"] for a in AXES])
        std = np.array([rb["std"][f"{group}_{a}"] for a in AXES])
        assert np.all(np.abs(est - truth) <= 3 * std), (group, est, std, truth)
        assert np.all(std < (0.005 if group == "torque_scale" else 0.015)), (group, std)
    handed, problems, inflation = assess_calibration(summary, config_actuator_prior(cfg))
    assert not problems and inflation == 1.0 and handed["torque_scale"] == [rb["estimate"][f"torque_scale_{a}"]
                                                                          for a in AXES]


@pytest.mark.slow
def test_a_saturating_torque_axis_is_not_handed_on(tmp_path):
    """The y torque delivers only 35 % of its limit (faults.actuator_saturation; the command is still recorded as
    applied): the fit's κ_τy contradicts the 5 % prior and the calibration is rejected (31 s on an idle core)."""
    cfg, summary = _fly_manoeuvre(tmp_path, "faults.actuator_saturation=[1, 1, 1, 1, 0.35, 1]")
    handed, problems, _ = assess_calibration(summary, config_actuator_prior(cfg))
    assert handed == {} and any("torque_scale_y" in p and "contradicts its prior" in p for p in problems), problems


def test_the_flights_clip_test_runs_on_the_flown_telemetry_and_passes_a_healthy_robot(mission_run, tmp_path):
    """The clip test (oacli.mission.calibration_linearity) reads segment 1's flown telemetry: a healthy robot is not
    refused (no axis below −Z_SATURATION) and the summary reports the scores."""
    run, cfg_path, _ = mission_run
    cfg = load_config(cfg_path)
    out = tmp_path / "m"
    (out / "segment-1").mkdir(parents=True)
    for key in (CALIBRATE_KEY, "segment-1/track", MANOEUVRE_KEY, ON_MANOEUVRE_KEY):
        shutil.copytree(run / key, out / key)
    cal = actuator_calibration(cfg, out)
    assert cal.source == "calibration" and cal.note is None and cal.stage == ON_MANOEUVRE_KEY
    z = cal.summary()["linearity_z"]
    assert z and all(v >= -Z_SATURATION for v in z.values()), z
    assert set(z) <= {"force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z"}


@pytest.mark.slow
def test_a_force_axis_saturating_in_both_flights_is_refused(mission_run, tmp_path):
    """World y delivers at most 75 % of its limit in the manoeuvre (faults.actuator_saturation): the flights' clip
    test finds force_y and the calibration falls back to the config's prior with the axis named (~35 s on an idle
    core)."""
    run, _, _ = mission_run
    flown = tmp_path / "flown"
    cfg, _ = _fly_manoeuvre(flown, "faults.actuator_saturation=[1, 0.75, 1, 1, 1, 1]")
    out = tmp_path / "m"
    (out / "segment-1").mkdir(parents=True)
    for key in (CALIBRATE_KEY, "segment-1/track"):
        shutil.copytree(run / key, out / key)
    shutil.copytree(flown / "track", out / MANOEUVRE_KEY)
    shutil.copytree(flown / "estimate", out / ON_MANOEUVRE_KEY)
    cal = actuator_calibration(cfg, out)
    assert cal.source == "config" and "saturating actuator" in cal.note and "force_y" in cal.note, cal.note
    assert cal.summary()["linearity_z"]["force_y"] < -Z_SATURATION
