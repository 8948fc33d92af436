"""End-to-end ``oacli plan`` → ``oacli smooth`` (→ ``oacli track``): run the CLI, read the MCAPs and recordings
back and check their values; bad inputs end with exit 2 (no run folder), no solution with exit 3."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.geometry.verify import dense_check
from oacli.io.mcap_io import read_stage, read_trajectory
from oacli.io.rerun.read import (
    empty_blueprint_views,
    read_application_id,
    read_blueprint_timeline,
    read_blueprint_views,
    read_recording_component,
    read_recording_entities,
    read_recording_scalars,
)
from oacli.planning.full_state import translational_part
from oacli.planning.translational import CostWeights
from tests.mcap_checks import check_json_records
from tests.plan_checks import S1, S1_SHORTEST_M
from tests.plot_checks import PNGS

runner = CliRunner()


def run_cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def small_config(tmp: Path, **planner) -> Path:
    """S1 with small budgets (and the planner overrides given)."""
    data = yaml.safe_load(S1.read_text())
    data["planner"].update({"max_iterations": 300, "shortcut": {"tries": 150}}, **planner)
    path = tmp / "s1_small.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def assert_clean_failure(result, runs: Path, code: int = 2, must_name: str | None = None) -> None:
    assert result.exit_code == code, (result.exit_code, result.output)
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip() and not ln.startswith(("plan:", "smooth:"))]
    assert lines and all(ln.startswith("error: ") for ln in lines), result.stderr
    if must_name is not None:
        assert must_name in result.stderr, result.stderr
    assert not runs.exists() or not any(runs.iterdir()), "a run folder was left behind"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("plan_smooth")
    cfg = small_config(tmp)
    plan_dir, smooth_dir = tmp / "plan", tmp / "smooth"
    result = run_cli("plan", cfg, "--out", plan_dir, "--quiet", "--seed", "4")
    assert result.exit_code == 0, result.output
    result = run_cli("smooth", cfg, "--input", plan_dir / "plan.mcap", "--out", smooth_dir, "--quiet")
    assert result.exit_code == 0, result.output
    return {"config": cfg, "plan": plan_dir, "smooth": smooth_dir, "tmp": tmp}


def test_plan_run_folder_summary_and_mcap_agree(runs):
    plan_dir = runs["plan"]
    assert sorted(p.name for p in plan_dir.iterdir()) == sorted(["config.yaml", "plan.mcap", "plan.rrd", "summary.json",
                                                                 *PNGS["plan"]])
    summary = json.loads((plan_dir / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["planner"] == "lqr-rrt-star" and summary["segment"] == "S-G"
    for key in ("iterations", "nodes", "time_to_first_solution_s", "cost", "path_length_m", "duration_s",
                "max_force_N", "collision_free"):
        assert summary[key] is not None, key
    assert summary["collision_free"] is True and summary["dense_check"]["ok"] is True
    cfg = load_config(plan_dir / "config.yaml")
    assert cfg.seed == 4 and cfg.planner.segment == "S-G"

    record = read_stage(plan_dir / "plan.mcap")
    for topic in ("/trajectory", "/robot/pose", "/scene", "/plan/tree", "/plan/solutions", "/log"):
        assert topic in record.topics, topic
    assert record.metadata["oacli"]["stage"] == "plan"
    assert record.metadata["oacli.plan"]["segment"] == "S-G"
    traj = read_trajectory(plan_dir / "plan.mcap")
    assert traj.duration_s == pytest.approx(summary["duration_s"])
    trans = translational_part(traj, cfg.robot.model())
    w = cfg.planner.weights
    goal = np.concatenate([cfg.waypoints["G"].position, np.zeros(3)])
    assert trans.cost(CostWeights(w.position, w.velocity, w.force, w.time), goal) == pytest.approx(summary["cost"])
    assert trans.path_length_m() == pytest.approx(summary["path_length_m"])
    assert trans.path_length_m() >= S1_SHORTEST_M
    assert np.abs(traj.u[:, 0:3]).max() == pytest.approx(summary["max_force_N"])
    assert np.all(np.abs(traj.u[:, 0:3]) <= 0.5 + 1e-9) and np.all(np.abs(traj.x[:, 3:6]) <= 0.2 + 1e-9)
    np.testing.assert_array_equal(traj.x[0, 0:3], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(traj.x[-1, 0:6], goal)
    dense = dense_check(trans.t, trans.x, trans.u, trans.model, cfg.scene(), 0.0)
    assert dense.ok and dense.max_spacing_m <= 0.005 + 1e-9

    nodes = record.json_records["/plan/tree"]
    assert len(nodes) == summary["nodes"]
    by_id = {n["node"]: n for n in nodes}
    goal_nodes = [n for n in nodes if n["goal"]]
    assert len(goal_nodes) == 1
    chain, node = [], goal_nodes[0]
    while node["parent"] >= 0:
        chain.append(node["node"])
        node = by_id[node["parent"]]
    assert node["node"] == 0
    assert sorted([*chain, 0]) == sorted(n["node"] for n in nodes if n["in_path"])
    np.testing.assert_allclose(goal_nodes[0]["position"], goal[0:3])
    assert goal_nodes[0]["cost"] == pytest.approx(summary["cost"], rel=1e-9)
    solutions = record.json_records["/plan/solutions"]
    assert solutions[0]["iteration"] == summary["iterations_to_first_solution"]


def test_plan_and_smooth_records_follow_the_contract_schemas(runs):
    plan = check_json_records(runs["plan"] / "plan.mcap")
    summary = json.loads((runs["plan"] / "summary.json").read_text())
    assert plan["oacli.PlanTreeNode"] == summary["nodes"] and plan["oacli.PlanRewire"] == summary["rewires"]
    assert plan["oacli.PlanSolution"] == summary["solution_improvements"] + 1
    smooth = check_json_records(runs["smooth"] / "smooth.mcap")
    summary = json.loads((runs["smooth"] / "summary.json").read_text())
    assert smooth["oacli.ShortcutAttempt"] == summary["shortcuts_tried"]
    assert smooth["oacli.PolishIteration"] == summary["polish"]["iterations"]


def test_plan_recording_holds_the_tree_path_and_motion(runs):
    rrd = runs["plan"] / "plan.rrd"
    entities = read_recording_entities(rrd)
    for entity in ("world/keep_in", "world/keep_out", "world/plan/tree", "world/plan/growth", "world/plan/path",
                   "world/plan/start", "world/plan/goal", "world/robot", "metrics/force_N", "metrics/velocity_mps",
                   "metrics/solution_cost", "log"):
        assert entity in entities, entity
    summary = json.loads((runs["plan"] / "summary.json").read_text())
    _, rows = read_recording_component(rrd, "world/plan/tree", "LineStrips3D:strips")
    assert len(rows[-1]) == summary["nodes"] - 1  # one curve per edge
    traj = read_trajectory(runs["plan"] / "plan.mcap")
    t_force, force = read_recording_scalars(rrd)["metrics/force_N"]
    np.testing.assert_allclose(t_force, traj.t, atol=1e-9)
    np.testing.assert_allclose(force, traj.u[:, 0:3], atol=1e-12)
    times, growth = read_recording_component(rrd, "world/plan/growth", "LineStrips3D:strips", timeline="iteration")
    assert times is not None and len(growth) >= 1


def test_smooth_reads_the_plan_back_and_never_raises_the_cost(runs):
    smooth_dir, plan_dir = runs["smooth"], runs["plan"]
    summary = json.loads((smooth_dir / "summary.json").read_text())
    plan_summary = json.loads((plan_dir / "summary.json").read_text())
    assert summary["status"] == "ok"
    assert summary["cost_before"] == pytest.approx(plan_summary["cost"], rel=1e-9)
    assert summary["cost_after"] <= summary["cost_before"]
    assert summary["duration_before_s"] == pytest.approx(plan_summary["duration_s"])
    assert summary["shortcuts_tried"] == 150
    assert summary["shortcuts_accepted"] + sum(summary["shortcuts_rejected"].values()) == 150
    assert summary["collision_free"] is True and summary["dense_check"]["ok"] is True

    record = read_stage(smooth_dir / "smooth.mcap")
    assert record.metadata["oacli"]["stage"] == "smooth"
    shortcuts = record.json_records["/smooth/shortcuts"]
    assert len(shortcuts) == 150
    outcomes = [s["outcome"] for s in shortcuts]
    assert outcomes.count("accepted") == summary["shortcuts_accepted"]
    for reason, count in summary["shortcuts_rejected"].items():
        assert outcomes.count(reason) == count
    before = read_trajectory(plan_dir / "plan.mcap")
    np.testing.assert_array_equal(record.trajectories["/trajectory/input"].x, before.x)
    after = record.trajectories["/trajectory"]
    assert after.duration_s == pytest.approx(summary["duration_after_s"])
    np.testing.assert_array_equal(after.x[0, 0:6], before.x[0, 0:6])
    np.testing.assert_array_equal(after.x[-1, 0:6], before.x[-1, 0:6])
    cfg = load_config(runs["config"])
    trans = translational_part(after, cfg.robot.model())
    assert dense_check(trans.t, trans.x, trans.u, trans.model, cfg.scene(), 0.0).ok
    assert trans.path_length_m() >= S1_SHORTEST_M

    rrd = smooth_dir / "smooth.rrd"
    for entity in ("world/smooth/before", "world/smooth/after", "world/robot", "metrics/cost"):
        assert entity in read_recording_entities(rrd)
    _, costs = read_recording_component(rrd, "metrics/cost", "Scalars:scalars", timeline="shortcut")
    costs = np.concatenate(costs)
    assert len(costs) == 151 and np.all(np.diff(costs) <= 1e-12)
    assert costs[-1] == pytest.approx(summary["cost_after_shortcut"], rel=1e-9)  # the polish follows


def test_track_follows_the_smoothed_plan(runs):
    out = runs["tmp"] / "track"
    result = run_cli("track", runs["config"], "--reference", runs["smooth"] / "smooth.mcap", "--out", out, "--quiet")
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["rms_position_error_m"] < 0.005  # the plan is dynamically consistent with the model
    assert summary["constraint_violations"] == 0


def test_kino_rrt_from_the_command_line(tmp_path):
    cfg = small_config(tmp_path, max_iterations=4000)
    out = tmp_path / "kino"
    result = run_cli("plan", cfg, "--planner", "kino-rrt", "--out", out, "--quiet", "--seed", "1")
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner"] == "kino-rrt" and summary["collision_free"] is True
    edges = {n["edge"] for n in read_stage(out / "plan.mcap").json_records["/plan/tree"]}
    assert edges == {"root", "primitive", "lqr"}  # primitives and the exact LQR goal link


def test_same_seed_gives_the_same_plan(tmp_path):
    cfg = small_config(tmp_path)
    for name in ("a", "b"):
        assert run_cli("plan", cfg, "--out", tmp_path / name, "--quiet", "--seed", "9").exit_code == 0
    a, b = (read_trajectory(tmp_path / n / "plan.mcap") for n in ("a", "b"))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.u, b.u)


# ------------------------------------------------------------------------------------------------------------
# Bad input: exit 2 without a run folder; no solution: exit 3 with a partial, clearly marked run folder
# ------------------------------------------------------------------------------------------------------------


def _with(tmp: Path, edit) -> Path:
    data = yaml.safe_load(S1.read_text())
    edit(data)
    path = tmp / "edited.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_start_inside_a_keep_out_zone_is_refused(tmp_path):
    cfg = _with(tmp_path, lambda d: d["waypoints"]["S"].update(position=[0.9, 0.0, 0.0]))
    result = run_cli("plan", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="environment.keep_out.0")
    assert "waypoints.S" in result.stderr


def test_goal_outside_the_keep_in_box_is_refused(tmp_path):
    cfg = _with(tmp_path, lambda d: d["waypoints"]["G"].update(position=[3.5, 0.0, 0.0]))
    result = run_cli("plan", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="keep-in")


def test_unknown_segment_and_planner_are_refused(tmp_path):
    result = run_cli("plan", S1, "--segment", "S-X", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="--segment")
    result = run_cli("plan", S1, "--planner", "rrt-connect", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="--planner")


def test_no_solution_exits_3_and_keeps_the_partial_tree(tmp_path):
    # A wall across the whole box: the goal cannot be reached.
    cfg = _with(tmp_path, lambda d: (d["environment"]["keep_out"].append(
        {"center": [1.6, 0.0, 0.0], "semi_axes_m": [0.05, 3.0, 3.0]}), d["planner"].update(max_iterations=40)))
    out = tmp_path / "run"
    result = run_cli("plan", cfg, "--out", out, "--quiet")
    assert result.exit_code == 3, result.output
    assert "no solution" in result.stderr and str(out) in result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "no_solution" and summary["nodes"] >= 2
    record = read_stage(out / "plan.mcap")
    assert "/trajectory" not in record.topics
    assert len(record.json_records["/plan/tree"]) == summary["nodes"]
    assert "world/plan/growth" in read_recording_entities(out / "plan.rrd")


def test_smooth_refuses_a_plan_that_collides_in_its_config(runs, tmp_path):
    # The same plan, but the config now has an obstacle on its path.
    traj = read_trajectory(runs["plan"] / "plan.mcap")
    mid = traj.x[len(traj) // 2, 0:3]
    cfg = _with(tmp_path, lambda d: d["environment"]["keep_out"].append(
        {"center": [float(v) for v in mid], "semi_axes_m": [0.05, 0.05, 0.05]}))
    result = run_cli("smooth", cfg, "--input", runs["plan"] / "plan.mcap", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="environment.keep_out.1")


def test_smooth_refuses_a_missing_input_and_another_mass(runs, tmp_path):
    result = run_cli("smooth", runs["config"], "--input", tmp_path / "nope.mcap", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="nope.mcap")
    cfg = _with(tmp_path, lambda d: d["robot"].update(mass_kg=15.0))
    result = run_cli("smooth", cfg, "--input", runs["plan"] / "plan.mcap", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="robot.mass_kg")


def assert_recording_opens_right(rrd, stage):
    """Own application id (own layout when several recordings are open), no panel empty on the opening timeline."""
    assert read_application_id(rrd) == f"oacli-{stage}"
    assert read_blueprint_timeline(rrd) == "mission_time"
    assert read_blueprint_views(rrd), "no blueprint"
    assert empty_blueprint_views(rrd) == []


def test_plan_and_smooth_recordings_open_with_every_panel_filled(runs):
    assert_recording_opens_right(runs["plan"] / "plan.rrd", "plan")
    assert_recording_opens_right(runs["smooth"] / "smooth.rrd", "smooth")
    # the per-iteration figures are static line charts (shown on mission_time) beside the iteration-timeline series:
    # the chart's line is the series, x the iteration, y framed on the costs' range (not bars from 0)
    rrd = runs["plan"] / "plan.rrd"
    views = {v["origin"].strip("/"): v["class"] for v in read_blueprint_views(rrd)}
    assert views["charts/solution_cost"] == "2D"
    its, costs = read_recording_scalars(rrd, timeline="iteration")["metrics/solution_cost"]
    _, (strips,) = read_recording_component(rrd, "charts/solution_cost/line", "LineStrips2D:strips")
    (line,) = strips
    if costs.size > 1:
        np.testing.assert_allclose(line[:, 0], 3.0 * (its - its[0]) / (its[-1] - its[0]), atol=1e-5)
        np.testing.assert_allclose(-line[:, 1], (costs - costs.min()) / np.ptp(costs), atol=1e-5)
