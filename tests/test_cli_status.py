"""Honest run status end to end: ``oacli track`` runs that go wrong say so (summary.json, one warning line on
stderr, exit code), with the MCAP and the recording read back and checked against independent computations."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import oacli.stages.track as track_stage
from oacli.cli import app
from oacli.config import load_config
from oacli.control.tube_monitor import half_widths
from oacli.io.mcap_io import read_stage, read_telemetry
from oacli.io.rerun.read import read_recording_scalars
from oacli.model.double_integrator import double_integrator
from oacli.stages.settings import tube_design_from_config
from tests.conftest import REPO

ISS = REPO / "configs" / "iss_reswarm.yaml"
TUBE = REPO / "configs" / "iss_reswarm_tube.yaml"
runner = CliRunner()


def run_cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def variant(tmp_path: Path, base: Path, edit, name: str = "variant.yaml") -> Path:
    data = yaml.safe_load(base.read_text())
    edit(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def warnings_of(result) -> list[str]:
    return [ln for ln in result.stderr.splitlines() if ln.startswith("warning:")]


def w_vertex_force_N(cfg_path: Path) -> float:
    """Constant force (on the true mass) whose velocity change over one control period is W's half-width."""
    cfg = load_config(cfg_path)
    design = tube_design_from_config(cfg)
    return float(half_widths(design)[:, 1].max() * cfg.truth_params().mass_kg / cfg.controller.period_s)


def with_bias(force_N: float):
    def edit(d):
        d["truth"]["disturbance"] = {"force_bias_N": [force_N] * 3}
    return edit


# ------------------------------------------------------------------------------------------------------------
# Tube MPC beyond W
# ------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def twice_w_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("twice_w")
    cfg = variant(tmp, TUBE, with_bias(2.0 * w_vertex_force_N(TUBE)))
    out = tmp / "run"
    result = run_cli("track", cfg, "--out", out, "--quiet")
    return cfg, out, result


def test_twice_w_ends_degraded_with_one_warning_and_the_response_recorded(twice_w_run):
    _, out, result = twice_w_run
    assert result.exit_code == 0, result.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "degraded"
    (line,) = warnings_of(result)
    assert line.startswith("warning: track status degraded: the realised disturbance left W")
    assert "redesign at t = 0.20 s" in line
    beyond = s["beyond_w"]
    assert beyond["policy"] == "redesign" and beyond["violations"] >= 1 and beyond["redesigns"] == 1
    assert beyond["max_over_w"] == pytest.approx(2.0, rel=0.05)
    (response,) = beyond["responses"]
    assert response["response"] == "redesign" and response["t"] == pytest.approx(0.2)
    assert response["redesign_time_s"] > 0
    # The new W covers 1.5 × the bound measured up to the redesign, and (no noise: W is a box) every later w.
    for key in ("w_position_m", "w_velocity_mps"):
        final = np.array(beyond["final_w"][key])
        assert np.all(final >= 1.5 * np.array(response["measured_max"][key]) * (1 - 1e-9))
        assert np.all(final >= np.array(beyond["measured_max"][key]))
    assert s["tube_violations"] == 0 and s["safety"]["keep_in"]["count"] == 0
    # W exceeded 2x before the redesign: the true state may leave the promised tube then (reported apart)
    kinds = {r["kind"] for r in s["status_reasons"]}
    assert "beyond_w" in kinds and kinds <= {"beyond_w", "tube_true"}
    assert ("tube_true" in kinds) == (s["tube_violations_true"] > 0)


def test_twice_w_records_the_measured_disturbance_in_the_mcap_and_the_recording(twice_w_run):
    cfg_path, out, _ = twice_w_run
    s = json.loads((out / "summary.json").read_text())
    rec = read_stage(out / "track.mcap", topics=["/tube/disturbance", "/tube/design", "/log"])
    tel = read_telemetry(out / "track.mcap")
    records = rec.json_records["/tube/disturbance"]
    assert [r["t"] for r in records] == pytest.approx(tel.t_ctrl.tolist())
    assert sum(r["violation"] for r in records) == s["w_violations"] == s["beyond_w"]["violations"]
    designs = rec.json_records["/tube/design"]
    assert [d["design"] for d in designs] == [0, 1] and designs[1]["t"] == pytest.approx(0.2)
    # Independent: w_k = x_k − (A x_{k−1} + B u_{k−1}) from the measured states and applied forces (no noise here).
    cfg = load_config(cfg_path)
    a, b = double_integrator(cfg.controller.period_s, 1.0 / cfg.robot.mass_kg)
    w_pos = np.array([r["w_position_m"] if r["w_position_m"][0] is not None else [np.nan] * 3 for r in records])
    w_vel = np.array([r["w_velocity_mps"] if r["w_velocity_mps"][0] is not None else [np.nan] * 3 for r in records])
    for i in range(3):
        x = tel.x_measured[:, [i, i + 3]]
        w = x[1:] - x[:-1] @ a.T - tel.u_applied[:-1, i : i + 1] @ b.T
        np.testing.assert_allclose(w_pos[1:, i], w[:, 0], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(w_vel[1:, i], w[:, 1], rtol=1e-9, atol=1e-15)
    half_v = np.array([r["w_half_velocity_mps"] for r in records])
    outside = np.any(np.abs(w_vel[1:]) > half_v[1:] * (1 + 1e-6), axis=1)
    np.testing.assert_array_equal(outside, [r["violation"] for r in records[1:]])
    # The recording plots the same series against W's half-widths in use.
    scalars = read_recording_scalars(out / "track.rrd")
    t_rr, v_rr = scalars["metrics/tube/disturbance_velocity_mps"]
    np.testing.assert_allclose(t_rr, tel.t_ctrl, atol=1e-9)
    np.testing.assert_allclose(v_rr[1:], w_vel[1:], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(scalars["metrics/tube/disturbance_velocity_mps/limit_upper"][1], half_v, rtol=1e-12)
    log = [m for _, level, m in rec.log if level == "warning" and "beyond W" in m]
    assert len(log) == 1 and "redesign" in log[0]


def test_thirty_times_w_never_drifts_silently(tmp_path):
    cfg = variant(tmp_path, TUBE, with_bias(30.0 * w_vertex_force_N(TUBE)))
    out = tmp_path / "run"
    result = run_cli("track", cfg, "--out", out, "--quiet")
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] in ("degraded", "unsafe")
    assert result.exit_code == (4 if s["status"] == "unsafe" else 0), result.output
    assert len(warnings_of(result)) == 1
    if s["status"] == "degraded":  # held, not flown off
        assert s["safe_hold_steps"] > 0 and s["beyond_w"]["held"]
        assert s["beyond_w"]["responses"][0]["response"] == "hold"
        assert s["safety"]["keep_in"]["count"] == 0


# ------------------------------------------------------------------------------------------------------------
# Failing solvers, non-physical disturbances, leaving the keep-in, interrupts
# ------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("base", [ISS, TUBE], ids=["mpc", "tube"])
def test_a_solver_that_always_fails_ends_degraded(tmp_path, base):
    cfg = variant(tmp_path, base, lambda d: d["controller"]["weights"].update(position=1.0e300))
    out = tmp_path / "run"
    result = run_cli("track", cfg, "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "degraded"
    assert s["solver_failures"] >= 1 and s["fallback_steps"] >= s["control_steps"] - 1
    (line,) = warnings_of(result)
    assert "controller solves failed" in line
    stats = read_stage(out / "track.mcap", topics=["/solver/stats"]).json_records["/solver/stats"]
    assert sum(not r["success"] for r in stats) >= s["control_steps"] - 1


def test_a_non_physical_disturbance_is_refused_or_ends_unsafe(tmp_path):
    cfg = variant(tmp_path, ISS, lambda d: d.setdefault("truth", {}).update(
        disturbance={"force_random_N": [1.0e30] * 3}))
    out = tmp_path / "run"
    result = run_cli("track", cfg, "--out", out, "--quiet")
    assert "Traceback" not in result.output
    if result.exit_code == 2:
        assert "truth.disturbance.force_random_N" in result.stderr
        return
    assert result.exit_code == 4, result.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "unsafe" and s["safety"]["keep_in"]["count"] > 0
    assert s["safety"]["keep_in"]["worst_depth"] > 1e20
    # The reference check warns first (the disturbance bound alone exceeds the actuators), then the status line.
    assert warnings_of(result)[-1].startswith("warning: track status unsafe: the true state left the keep-in")


def corner_cut(d):
    """A reference from the JEM's wide box into the narrower one that cuts the corner outside the keep-in, tracked
    without the controller's position rows (with them the robot stays inside: tests/test_controller_constraints.py)."""
    d["controller"]["position_constraints"] = False
    q = [0.0, 0.0, -0.7071068, 0.7071068]
    d["waypoints"]["P"] = {"position": [12.25, -9.6, 4.8], "quaternion": q}
    d["waypoints"]["Q"] = {"position": [11.9, -8.6, 4.8], "quaternion": q}
    d["reference"]["waypoints"] = ["P", "Q"]


def test_standard_mpc_leaving_the_keep_in_is_unsafe_with_exit_4(tmp_path):
    cfg_path = variant(tmp_path, ISS, corner_cut)
    out = tmp_path / "run"
    result = run_cli("track", cfg_path, "--out", out)
    assert result.exit_code == 4, result.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "unsafe"
    (line,) = warnings_of(result)
    assert line.startswith("warning: track status unsafe: the true state left the keep-in on ")
    assert "status" in result.stdout and "unsafe" in result.stdout  # the results table still prints
    # Independent: distance of every /state/true sample to the nearest keep-in box, one box at a time.
    tel = read_telemetry(out / "track.mcap")
    boxes = load_config(cfg_path).scene().keep_in
    depth = np.full(len(tel.t_true), np.inf)
    for box in boxes:
        gap = np.maximum(np.maximum(box.lower - tel.x_true[:, 0:3], tel.x_true[:, 0:3] - box.upper), 0.0)
        depth = np.minimum(depth, np.linalg.norm(gap, axis=1))
    bad = depth > 1e-9
    keep_in = s["safety"]["keep_in"]
    assert keep_in["count"] == int(bad.sum()) > 0
    assert keep_in["first_time_s"] == pytest.approx(float(tel.t_true[np.argmax(bad)]), abs=1e-12)
    assert keep_in["worst_depth"] == pytest.approx(float(depth.max()), rel=1e-12)
    assert 0.05 < keep_in["worst_depth"] < 0.14  # the reference itself cuts at most 0.128 m outside
    assert s["constraint_violations_by_kind"]["keep_in"] == keep_in["count"]
    assert s["safety"]["samples"] == len(tel.t_true)


def test_an_interrupted_run_says_interrupted(tmp_path, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(track_stage, "simulate", interrupted)
    out = tmp_path / "run"
    result = run_cli("track", ISS, "--out", out, "--quiet")
    assert result.exit_code == 130
    assert result.stderr.strip().splitlines() == ["error: interrupted"]
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["stage"] == "track"


def test_an_unknown_beyond_w_response_names_the_field(tmp_path):
    cfg = variant(tmp_path, TUBE, lambda d: d["controller"]["tube"].update(beyond_w="panic"))
    result = run_cli("track", cfg, "--runs-dir", tmp_path / "runs")
    assert result.exit_code == 2, result.output
    assert "controller.tube.beyond_w" in result.stderr and "Traceback" not in result.output
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
