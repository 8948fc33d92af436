"""The mission's status is honest: the worst of its stages, a stop on an ``unsafe`` stage, a later
failure beside it (never exit 2 for a valid config), a failed estimate not handed on, segment 3 derived from the
learned model and its covariance.

The default-suite tests reuse the shrunk default mission of ``conftest.mission_run`` (real stage outcomes): its
folder is copied and resumed with one stage's outcome changed, so no stage flies again. The three probes of the
issue fly whole missions (``slow``).
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
from oacli.mission.configs import NOMINAL_FLOOR_SHARE, REFERENCE_SHARE, Handoff, prior_model, stage_config
from oacli.mission.layout import MISSION_STAGES, stage_by_key
from oacli.mission.run import learned_model
from oacli.mission.verdict import MissionStageError, plan_above_nominal, stage_verdict
from oacli.model.robot_model import RobotModel
from oacli.stages.design_limits import planner_design_limits
from oacli.stages.settings import robot_model, tube_design_from_config
from oacli.status import EXIT_CODES

ROOT = Path(__file__).resolve().parents[1]
RUNNER = CliRunner()


def _copy_until(run: Path, dst: Path, last_key: str) -> Path:
    """A copy of the mission folder holding only the stages up to ``last_key`` (no mission summary)."""
    shutil.copytree(run, dst)
    keys = [s.key for s in MISSION_STAGES]
    for stage in MISSION_STAGES[keys.index(last_key) + 1:]:
        shutil.rmtree(stage.folder(dst), ignore_errors=True)
    for name in ("summary.json", "mission.rrd"):
        (dst / name).unlink(missing_ok=True)
    shutil.rmtree(dst / "plots", ignore_errors=True)
    return dst


def _edit_summary(folder: Path, **changes) -> None:
    path = folder / "summary.json"
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))


def test_an_unsafe_stage_stops_the_mission_with_exit_4(mission_run, tmp_path):
    """segment-2/track unsafe (its real summary with the true rate over the limit): nothing after it runs, the
    mission is unsafe (exit 4) and names the stage and the stop."""
    run, _, _ = mission_run
    out = _copy_until(run, tmp_path / "m", "segment-2/track")
    reason = {"level": "unsafe", "kind": "angular_velocity",
              "message": "the angular-rate limit was exceeded on 393 plant samples"}
    _edit_summary(out / "segment-2" / "track", status="unsafe", status_reasons=[reason])
    result = RUNNER.invoke(app, ["mission", str(out), "--resume", "--quiet"])
    assert result.exit_code == 4, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "unsafe"
    assert summary["status_reasons"][0]["kind"] == "angular_velocity"
    assert "segment-2/track" in summary["stopped"]
    assert summary["stages"]["segment-2/estimate"]["status"] == "not_run"
    assert not (out / "segment-2" / "estimate").exists() and not (out / "segment-3" / "plan").exists()


def test_a_failing_stage_is_failed_exit_1_not_2_and_keeps_the_earlier_findings(mission_run, tmp_path):
    """The estimate's MCAP segment 3 reads its model from is gone: the mission fails at segment-3/plan with exit 1
    (its config was valid; the stage's InputError would say 2), and its summary keeps the earlier stages'
    findings beside the error."""
    run, _, _ = mission_run
    out = _copy_until(run, tmp_path / "m", "segment-2/estimate")
    (out / "segment-2" / "estimate" / "estimate.mcap").unlink()
    result = RUNNER.invoke(app, ["mission", str(out), "--resume", "--quiet"])
    assert result.exit_code == 1, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["failed_stage"] == "segment-3/plan"
    kinds = [r["kind"] for r in summary["status_reasons"]]
    assert kinds[0] == "failed"
    earlier = json.loads((run / "segment-2" / "track" / "summary.json").read_text())
    for r in earlier.get("status_reasons") or []:  # the track's own findings are still there, beside the failure
        assert any(r["message"] in m["message"] for m in summary["status_reasons"])


def test_unsafe_wins_over_a_later_failure():
    """An unsafe stage then an error: the mission is unsafe (exit 4) with the failure reported beside it."""
    results = {"segment-1/track": {"status": "ok"},
               "segment-2/track": {"status": "unsafe", "status_reasons": [
                   {"level": "unsafe", "kind": "velocity", "message": "v over"}]},
               "segment-3/plan": {"status": "degraded", "status_reasons": [
                   {"level": "degraded", "kind": "x", "message": "y"}]}}
    verdict = stage_verdict(results, list(results))
    verdict.add("failed", "failed", "segment-3/smooth: boom")
    summary = verdict.apply({})
    assert summary["status"] == "unsafe"
    assert [r["level"] for r in summary["status_reasons"]] == ["unsafe", "failed", "degraded"]
    assert MissionStageError("x", summary["status"]).exit_code == EXIT_CODES["unsafe"] == 4
    assert MissionStageError("x", "failed").exit_code == 1


def test_a_batch_estimate_that_failed_is_not_handed_on(mission_run, tmp_path):
    """Not converged, no covariance: segment 3 gets the prior (mean and covariance), with a plain message."""
    run, _, _ = mission_run
    cfg = load_config(run / "config.yaml")
    good = learned_model(cfg, run)
    assert good.source == "estimate" and good.note is None
    assert good.model.mass_std_kg < prior_model(cfg).mass_std_kg  # the estimate's own covariance, not the prior's
    # issue 30: the learned centre of mass and its σ reach segment 3's controllers (the prior's is zero)
    if "com" in cfg.estimation.parameters:
        np.testing.assert_allclose(good.model.com_offset_m, cfg.truth.com_offset_m, atol=1e-3)
        assert np.all(good.model.com_std_m > 0) and not np.any(prior_model(cfg).com_offset_m)
        flown = stage_config(cfg, stage_by_key("segment-3/track"), Handoff(reference=Path("r.mcap"),
                                                                           estimate=good.model))
        np.testing.assert_array_equal(robot_model(flown).com_offset_m, good.model.com_offset_m)
    out = _copy_until(run, tmp_path / "m", "segment-2/estimate")
    _edit_summary(out / "segment-2" / "estimate", converged=False, iterations=212, covariance_identified=False,
                  std={"mass_kg": None, "Ixx_kgm2": None, "Iyy_kgm2": None, "Izz_kgm2": None})
    bad = learned_model(cfg, out)
    assert bad.source == "prior" and bad.model == prior_model(cfg)
    assert "did not converge" in bad.note and "no covariance" in bad.note
    assert "e+" not in bad.note and "inf" not in bad.note  # no sentinel numbers
    # No estimate at all (the stage refused: θ unobservable from the telemetry): the prior too, and the mission
    # counts the handled failure as degraded, not failed.
    none = learned_model(cfg, _copy_until(run, tmp_path / "n", "segment-2/estimate-sequential"))
    assert none.source == "prior" and "failed" in none.note
    handled = {"stage": "estimate", "status": "failed", "error": "unobservable", "handled": True}
    assert stage_verdict({"segment-2/estimate": handled}, ["segment-2/estimate"]).status == "degraded"
    stage_cfg = stage_config(cfg, stage_by_key("segment-3/track"), Handoff(reference=Path("r.mcap"),
                                                                           estimate=bad.model))
    assert robot_model(stage_cfg) == prior_model(cfg)  # mean and covariance (diagonal) of the prior


def _cfg(*sets: str):
    data = apply_overrides(yaml.safe_load((ROOT / "configs" / "mission_iss.yaml").read_text()), list(sets))
    return config_from_dict(data, source="test")


def test_segment_3_is_derived_from_the_learned_model_and_its_covariance():
    """Probe 1 of the issue (a 25 kg payload): segment 3's derived configs are valid (before: exit 2 at
    segment-3/plan, 25 kg × 0.01 m/s² > 0.216 N) and carry the learned σ, not the prior's nor a default's."""
    cfg = _cfg("mission.grasped.mass_kg=25")
    prior = prior_model(cfg)
    learned = prior.with_estimate(np.array([25.0, 0.157, 0.145, 0.162]), np.diag([0.043, 8e-4, 8e-4, 7e-4]) ** 2)
    plan = stage_config(cfg, stage_by_key("segment-3/plan"), Handoff(estimate=learned))
    assert plan.robot.mass_kg == 25.0
    assert robot_model(plan).mass_std_kg == pytest.approx(0.043)  # the plan's σ_m: the learned model's
    assert planner_design_limits(plan).margin.mass_std_kg == pytest.approx(0.043)
    m_upper = 25.0 + 2 * 0.043
    assert plan.reference.acceleration_mps2 * m_upper <= 0.8 * min(plan.robot.force_limit_N) + 1e-12
    tube_force = np.array(cfg.controller.tube.force_limit_N or cfg.robot.force_limit_N)  # null: the robot's
    np.testing.assert_array_less(np.array(plan.planner.limits.force_N), 0.8 * tube_force + 1e-12)  # 80 % of it
    # the steering horizon grows with the model's mass (same force, slower): 15 s × sqrt(25.09 / 9.58) → 24.5 s
    assert plan.planner.max_connection_s == pytest.approx(24.5)
    track = stage_config(cfg, stage_by_key("segment-3/track"), Handoff(reference=Path("r.mcap"), estimate=learned))
    assert robot_model(track) == learned  # W's σ_m and the plan's: one model, the learned covariance
    # the plan's force cap within the tightened nominal bounds Ū of the tube that flies it (issue 28)
    design = tube_design_from_config(track)
    for i, ax in enumerate(design.axes):
        assert plan.planner.limits.force_N[i] <= min(-ax.force_bounds_N[0], ax.force_bounds_N[1]) + 1e-12
        assert planner_design_limits(plan).limits.force_N[i] <= ax.force_bounds_N[1] + 1e-12
    # Probe 2 (3× the inertias): the reference's angular acceleration fits the heaviest plausible inertia.
    big = prior.with_estimate(np.array([15.5, 0.46, 0.43, 0.49]), np.diag([0.05, 0.002, 0.002, 0.002]) ** 2)
    plan = stage_config(_cfg("mission.grasped.inertia_kgm2=[0.46,0.43,0.49]"), stage_by_key("segment-3/plan"),
                        Handoff(estimate=big))
    assert plan.reference.angular_acceleration_radps2 * (0.49 + 2 * 0.002) <= 0.8 * 0.0216 + 1e-12


def test_a_plan_above_the_tubes_nominal_bound_is_reported():
    """Where the plan's force floor binds (a light payload on a vague model: Ū ≈ 0.02 N, K R grows with σ_m), the
    plan may ask more than the tube's nominal MPC can command; the mission reports it (``plan_above_nominal``),
    and it stays silent where the cap follows Ū (the default mission's case)."""
    cfg = load_config(ROOT / "configs" / "mission_unknown_payload.yaml")
    vague = prior_model(cfg).with_estimate(np.array([10.0, 0.3, 0.3, 0.3]), np.diag([3.0, 3e-3, 3e-3, 3e-3]) ** 2)
    plan = stage_config(cfg, stage_by_key("segment-3/plan"), Handoff(estimate=vague))
    track = stage_config(cfg, stage_by_key("segment-3/track"), Handoff(reference=Path("r.mcap"), estimate=vague))
    bounds = [list(ax.force_bounds_N) for ax in tube_design_from_config(track).axes]
    u_bar = np.array([min(-lo, hi) for lo, hi in bounds])
    tube_force = np.array(cfg.controller.tube.force_limit_N or cfg.robot.force_limit_N)
    floor = NOMINAL_FLOOR_SHARE * REFERENCE_SHARE * tube_force
    assert np.all(u_bar < floor)  # the floor binds: the cap is the floor, above Ū
    np.testing.assert_allclose(plan.planner.limits.force_N, floor)
    asked = {"max_force_per_axis_N": list(plan.planner.limits.force_N)}
    message = plan_above_nominal(asked, {"tightened_force_N": bounds})
    assert message is not None and all(f"{a} " in message for a in "xyz")
    below = {"max_force_per_axis_N": list(0.99 * u_bar)}
    assert plan_above_nominal(below, {"tightened_force_N": bounds}) is None
    assert plan_above_nominal(asked, {"status": "ok"}) is None  # a standard-MPC flight has no Ū


def test_rate_margin_from_the_models_inertia_sigma():
    """mission.rate_margin_sigmas: the controllers keep 1 − I/I_upper of the rate limit, the excitation's rate and
    torque shares shrink by I/I_upper (the prior's in segment 2); 0 leaves both as configured."""
    cfg = _cfg("mission.rate_margin_sigmas=2")
    stage = stage_config(cfg, stage_by_key("segment-2/excite"), Handoff())
    i, s = np.array(cfg.mission.prior.inertia_kgm2), np.sqrt(np.array(cfg.mission.prior.variance[1:]))
    keep = 1.0 / (1.0 + float(np.max(2 * s / i)))
    assert stage.controller.rate_margin == pytest.approx(1 - keep)
    assert stage.excitation.margin.reference_angular_velocity_fraction == pytest.approx(0.9 * keep)
    assert stage.excitation.margin.reference_torque_fraction == pytest.approx(0.8 * keep)
    plain = stage_config(_cfg("mission.rate_margin_sigmas=0"), stage_by_key("segment-2/excite"), Handoff())
    assert plain.controller.rate_margin == 0.0
    assert plain.excitation.margin.reference_angular_velocity_fraction == pytest.approx(0.9)


def test_a_known_robot_is_not_derated_by_a_default_prior_variance():
    """`oacli plan` on the bare robot: the force design limit is the reference share of the robot's, not 44 %."""
    from oacli.stages.design_limits import planner_design_limits

    cfg = load_config(ROOT / "configs" / "iss_reswarm.yaml")
    lim = planner_design_limits(cfg)
    np.testing.assert_allclose(lim.limits.force_N, 0.8 * np.asarray(cfg.robot.force_limit_N))
    assert isinstance(prior_model(_cfg()), RobotModel)


PROBES = [
    ("mass-25kg", ["mission.grasped.mass_kg=25"]),
    ("inertia-3x", ["mission.grasped.inertia_kgm2=[0.46,0.43,0.49]"]),
    ("com-offset", ["truth.com_offset_m=[0.05,-0.05,0.05]"]),
]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "sets"), PROBES, ids=[p[0] for p in PROBES])
def test_the_issues_probes_complete_or_stop_safely(name, sets, tmp_path):
    """Each probe of the payload-envelope review on the flight-like mission: it completes, or stops at an unsafe
    stage; its status is the worst of its stages, its exit code that status's, never 2; an unsafe stage is the last
    one run."""
    args = ["mission", str(ROOT / "configs" / "mission_iss.yaml"), "--out", str(tmp_path / "run"), "--quiet"]
    for s in sets:
        args += ["--set", s]
    result = RUNNER.invoke(app, args)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert result.exit_code == EXIT_CODES[summary["status"]] != 2, result.output
    statuses = [v["status"] for v in summary["stages"].values()]
    if "unsafe" in statuses:
        assert summary["status"] == "unsafe" and summary.get("stopped")
        assert all(s == "not_run" for s in statuses[statuses.index("unsafe") + 1:])
    else:
        assert summary["status"] in ("ok", "degraded", "failed")
        assert "error" not in summary  # completed: every stage ran
        row = summary["comparison"]["segment-3/track"]
        arrived = row["arrival_time_s"] is not None
        assert arrived == (summary["status"] != "failed")
        assert (not arrived) == any(r["kind"] == "not_arrived" for r in summary["status_reasons"])


def test_the_envelope_campaign_samples_the_envelope_uniformly(tmp_path):
    """configs/campaign_payload_envelope.yaml: ≥ 100 runs, each a valid mission config whose grasped payload lies
    in the envelope of docs/mission.md (10-30 kg, 0.5-4× the bare inertias, physical, CoM within 5 cm per axis of
    the measured offset, axes turned by at most 0.3 rad), spread over all of it, with the flight's sensor noise."""
    from scipy.spatial.transform import Rotation

    from oacli.campaign.driver import load_campaign, prepare

    campaign = load_campaign(ROOT / "configs" / "campaign_payload_envelope.yaml", [])
    assert campaign.config.runs >= 100 and campaign.config.dispersions.distribution == "uniform"
    n = 80
    campaign = load_campaign(ROOT / "configs" / "campaign_payload_envelope.yaml", [f"runs={n}"])
    folder = prepare(campaign, out=tmp_path / "dry", runs_root=tmp_path)
    bare = np.array([0.153427995, 0.14271405, 0.162302759])
    base = yaml.safe_load((ROOT / "configs" / "mission_iss.yaml").read_text())
    com0 = np.array(base["truth"]["com_offset_m"])
    masses, scales, angles = [], [], []
    for k in range(n):
        spec = json.loads((folder / "runs" / f"run-{k:05d}" / "spec.json").read_text())
        data = spec["config"]
        cfg = config_from_dict(data, source=f"run {k}")  # valid
        masses.append(cfg.mission.grasped.mass_kg)
        tensor = np.array(spec["draws"]["inertia_tensor_kgm2"])
        principal, axes = np.linalg.eigh(tensor)
        assert 2 * principal.max() <= principal.sum() + 1e-12  # a physical body
        scales.append(np.sort(principal) / np.sort(bare))
        # the rotation that diagonalises the tensor, its smallest angle over the axes' orderings and signs
        best = np.inf
        for perm in ([0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]):
            for signs in np.array(np.meshgrid([1, -1], [1, -1], [1, -1])).T.reshape(-1, 3):
                r = axes[:, perm] * signs
                if np.linalg.det(r) > 0:
                    best = min(best, np.linalg.norm(Rotation.from_matrix(r).as_rotvec()))
        angles.append(best)
        assert np.all(np.abs(np.array(cfg.truth.com_offset_m) - com0) <= 0.05 + 1e-12)
        assert cfg.sensors.angular_velocity_std_radps == base["sensors"]["angular_velocity_std_radps"]
    masses = np.array(masses)
    assert masses.min() >= 10.0 - 1e-9 and masses.max() <= 30.0 + 1e-9
    assert masses.min() < 12.0 and masses.max() > 28.0  # spread over the range (P(miss) < 1e-3 if uniform)
    ratio = np.array([np.asarray(s) for s in scales])
    assert ratio.min() > 0.5 * 0.9 and ratio.max() < 4.0 * 1.1 and ratio.max() > 3.0 and ratio.min() < 0.8
    assert max(angles) <= 0.3 + 1e-6 and max(angles) > 0.2
