"""Run statuses, violation depths and the safety block: closed forms, brute force and independent computations."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import minimize

import oacli
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.geometry.depth import keep_in_depth, keep_out_depth
from oacli.geometry.verify import point_ellipsoid_distance
from oacli.io.mcap_io import read_stage
from oacli.io.runfolder import is_complete, open_stage_run
from oacli.metrics import safety_block, safety_report
from oacli.status import (
    EXIT_CODES,
    StatusReport,
    add_output_trajectory_reasons,
    add_safety_reasons,
    controller_mode_counts,
    exit_code,
    mode_word,
    warning_line,
)
from tests.test_collision import random_rotation

# ------------------------------------------------------------------------------------------------------------
# Statuses
# ------------------------------------------------------------------------------------------------------------


def test_precedence_is_unsafe_over_degraded_over_ok():
    report = StatusReport()
    assert report.status == "ok"
    report.degraded("solver", "3 of 10 controller solves failed")
    assert report.status == "degraded"
    report.unsafe("keep_in", "left the keep-in")
    report.degraded("tube", "left the tube")
    assert report.status == "unsafe"
    summary = report.apply({"stage": "track"})
    assert summary["status"] == "unsafe"
    assert [r["level"] for r in summary["status_reasons"]] == ["unsafe", "degraded", "degraded"]
    # A terminal status is kept whatever the findings.
    no_solution = StatusReport("no_solution")
    no_solution.unsafe("x", "y")
    assert no_solution.status == "no_solution"
    with pytest.raises(ValueError, match="unknown status"):
        StatusReport("fine")


def test_exit_codes_and_the_one_warning_line():
    assert [exit_code(s) for s in ("ok", "degraded", "unsafe", "no_solution", "failed", "interrupted")] == \
        [0, 0, 4, 3, 1, 130]
    assert set(EXIT_CODES) == {"ok", "degraded", "unsafe", "no_solution", "failed", "interrupted"}
    assert warning_line({"stage": "track", "status": "ok", "status_reasons": []}) is None
    report = StatusReport()
    report.degraded("solver", "3 of 10 controller solves failed")
    report.degraded("fallback", "3 steps were driven by a fallback")
    line = warning_line(report.apply({"stage": "track"}))
    assert line == ("warning: track status degraded: 3 of 10 controller solves failed; 3 steps were driven by a "
                    "fallback")
    assert "\n" not in line
    assert warning_line({"stage": "plan", "status": "interrupted", "error": "interrupted by the user"}) == \
        "warning: plan status interrupted: interrupted by the user"


def test_controller_modes_are_counted_from_the_status_words():
    statuses = ["optimal", "fallback_shifted_plan (infeasible)", "fallback (solver_error)", "lqr (infeasible)",
                "hold (safe_hold)", "hold (infeasible)", "Optimal", "solver_error"]
    assert [mode_word(s) for s in statuses[:5]] == ["optimal", "fallback", "fallback", "lqr", "hold"]
    assert controller_mode_counts(statuses) == {"fallback_steps": 5, "safe_hold_steps": 2}
    assert controller_mode_counts([]) == {"fallback_steps": 0, "safe_hold_steps": 0}


def test_output_trajectory_findings():
    report = StatusReport()
    add_output_trajectory_reasons(report, {"collision_free": True, "within_limits": True,
                                           "dense_check": {"ok": True}}, "plan")
    assert report.status == "ok"
    add_output_trajectory_reasons(report, {"collision_free": False, "first_collision": {"t_s": 2.5, "kind": "keep_in"},
                                           "within_limits": False}, "plan")
    assert report.status == "unsafe"
    assert "t = 2.50 s (keep_in)" in report.reasons[0].message and report.reasons[1].kind == "limits"


# ------------------------------------------------------------------------------------------------------------
# Depths
# ------------------------------------------------------------------------------------------------------------


def surface_distance(p, center, axes, rot):
    """Independent distance from p to an ellipsoid's surface: SLSQP on min |x − q|² s.t. Σ (x_i/a_i)² = 1, from the
    radial projection and the six vertices (no closed form, no Eberly)."""
    q = rot.T @ (p - center)
    cons = {"type": "eq", "fun": lambda x: np.sum((x / axes) ** 2) - 1.0, "jac": lambda x: 2 * x / axes**2}
    radial = q / np.sqrt(np.sum((q / axes) ** 2)) if np.any(q) else axes * np.eye(3)[0]
    starts = [radial, *(s * a * e for a, e in zip(axes, np.eye(3), strict=True) for s in (1.0, -1.0))]
    best = min((minimize(lambda x: np.sum((x - q) ** 2), x0, jac=lambda x: 2 * (x - q), constraints=[cons],
                         method="SLSQP", options={"ftol": 1e-16, "maxiter": 500}) for x0 in starts),
               key=lambda r: r.fun)
    assert abs(np.sum((best.x / axes) ** 2) - 1.0) < 1e-9
    return float(np.linalg.norm(best.x - q))


def test_signed_distance_to_an_ellipsoid_inside_and_outside_against_an_optimiser():
    rng = np.random.default_rng(7)
    rot, axes, center = random_rotation(rng), np.array([0.3, 0.7, 1.1]), rng.normal(size=3)
    pts = center + (rng.normal(size=(12, 3)) * 0.5) @ rot.T  # many inside
    pts = np.vstack([pts, center, center + rot[:, 2] * 0.5])  # the centre and a point on the long axis (degenerate)
    sd = point_ellipsoid_distance(pts, center, axes, rot)
    ell = Ellipsoid.from_semi_axes(center, axes, rot)
    assert np.sum(sd < 0) >= 4
    for p, d in zip(pts, sd, strict=True):
        assert (d < 0) == bool(ell.contains(p))
        assert abs(d) == pytest.approx(surface_distance(p, center, axes, rot), abs=1e-7)
    # The centre is as deep as the shortest semi-axis.
    assert sd[-2] == pytest.approx(-0.3, abs=1e-9)


def test_keep_out_depth_of_a_ball_robot_in_a_sphere_is_closed_form():
    scene = Scene(keep_out=(Ellipsoid.from_semi_axes([1.0, 2.0, 3.0], [0.5, 0.5, 0.5]),))
    d = np.array([0.0, 0.2, 0.5, 0.6, 0.75, 0.8, 2.0])
    pts = np.array([1.0, 2.0, 3.0]) + d[:, None] * np.array([0.6, 0.0, 0.8])
    depth = keep_out_depth(pts, scene, robot_radius_m=0.25)
    np.testing.assert_allclose(depth, np.maximum(0.75 - d, 0.0), atol=1e-12)
    assert np.all(keep_out_depth(pts, Scene(), 0.25) == 0.0)
    assert keep_out_depth(np.array([[np.nan, 0.0, 0.0]]), scene, 0.25)[0] == np.inf


L_SHAPE = Scene(keep_in=(Box([0.0, 0.0, 0.0], [2.0, 1.0, 1.0]), Box([0.0, 1.0, 0.0], [1.0, 3.0, 1.0])))


def test_keep_in_depth_outside_is_the_distance_to_the_union():
    pts = np.array([[1.0, 0.5, 0.5], [2.3, 0.5, 0.5], [1.5, 1.5, 0.5], [2.3, 1.4, 1.2], [-0.1, 3.2, 0.5]])
    expected = np.array([0.0, 0.3, 0.5, np.sqrt(0.3**2 + 0.4**2 + 0.2**2), np.sqrt(0.01 + 0.04)])
    np.testing.assert_allclose(keep_in_depth(pts, L_SHAPE), expected, atol=1e-12)
    # With a 0.1 m margin: outside points 0.1 m deeper; (1, 0.5, 0.5) is 0.5 m from the complement, still 0.
    np.testing.assert_allclose(keep_in_depth(pts, L_SHAPE, 0.1), np.where(expected > 0, expected + 0.1, 0.0),
                               atol=1e-12)
    assert np.all(keep_in_depth(pts, Scene()) == 0.0)


def test_keep_in_depth_with_a_margin_erodes_the_union_not_each_box():
    # Two boxes side by side form [0, 2] x [0, 1] x [0, 1]: at their shared face the union has room, so a ball of
    # 0.3 m at (1, 0.5, 0.5) is inside (eroding each box alone would flag it 0.3 m deep).
    two = Scene(keep_in=(Box([0, 0, 0], [1, 1, 1]), Box([1, 0, 0], [2, 1, 1])))
    pts = np.array([[1.0, 0.5, 0.5], [1.0, 0.5, 0.1], [1.9, 0.5, 0.5], [2.2, 0.5, 0.5]])
    np.testing.assert_allclose(keep_in_depth(pts, two, 0.3), [0.0, 0.2, 0.2, 0.5], atol=1e-12)


def test_keep_in_depth_with_a_margin_against_brute_force():
    """max(0, r − d(p, ∁U)) inside and r + d(p, U) outside, against distances to a 1 cm grid of points outside
    (inside) the union, near the inner corner of an L where the erosion is not a box."""
    rng = np.random.default_rng(3)
    h = 0.01
    axes = [np.arange(0.3, 1.7 + h / 2, h), np.arange(0.3, 1.7 + h / 2, h), np.arange(-0.35, 1.35 + h / 2, h)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside_grid = L_SHAPE.in_keep_in(grid)
    outside, inside = grid[~inside_grid], grid[inside_grid]
    pts = np.column_stack([rng.uniform(0.65, 1.35, 15), rng.uniform(0.65, 1.35, 15), rng.uniform(0.0, 1.0, 15)])
    r = 0.3
    depth = keep_in_depth(pts, L_SHAPE, r)
    for p, d in zip(pts, depth, strict=True):
        if L_SHAPE.in_keep_in(p):
            expected = max(r - np.sqrt(np.min(np.sum((outside - p) ** 2, axis=1))), 0.0)
        else:
            expected = r + np.sqrt(np.min(np.sum((inside - p) ** 2, axis=1)))
        assert d == pytest.approx(expected, abs=h * np.sqrt(3) + 1e-12)
    assert np.any(depth > 0.05) and np.any(depth == 0)


# ------------------------------------------------------------------------------------------------------------
# The safety block
# ------------------------------------------------------------------------------------------------------------


def test_safety_report_counts_first_times_and_depths():
    t = np.arange(0.0, 10.0, 0.5)
    x = np.zeros((t.size, 13))
    x[:, 9] = 1.0
    x[:, 0] = 0.25 * t - 0.5  # leaves [0, 2] at t = 10 s ... starts outside until t = 2 s
    x[:, 1] = 0.5
    x[:, 2] = 0.5
    x[:, 4] = np.where(t >= 3.0, 0.25, 0.1)  # beyond 0.2 m/s from t = 3 s
    x[12, 11] = 0.3  # one angular-rate excursion at t = 6 s
    u = np.zeros((5, 6))
    u[3, 1] = 0.3  # commanded beyond the 0.2 N limit at t = 6 s (control period 2 s)
    scene = Scene(keep_in=(Box([0, 0, 0], [2, 1, 1]),),
                  keep_out=(Ellipsoid.from_semi_axes([1.0, 0.5, 0.5], [0.1, 0.1, 0.1]),))
    rep = safety_report(t, x, scene=scene, velocity_limit_mps=np.full(3, 0.2),
                        angular_velocity_limit_radps=np.full(3, 0.2), robot_radius_m=0.05,
                        t_ctrl=np.arange(5) * 2.0, u_command=u, input_limits=np.r_[np.full(3, 0.2), np.full(3, 0.1)])
    # keep-in: x < 0 for t < 2 s (4 samples, first at 0 s, 0.5 m deep at t = 0)
    assert (rep["keep_in"].count, rep["keep_in"].first_time_s, rep["keep_in"].worst_depth) == (4, 0.0, 0.5)
    # keep-out: |x - 1| < 0.15 for x in (0.85, 1.15): t in (5.4, 6.6) -> samples 5.5, 6.0, 6.5; depth 0.15 at 6.0
    assert (rep["keep_out"].count, rep["keep_out"].first_time_s) == (3, 5.5)
    assert rep["keep_out"].worst_depth == pytest.approx(0.15, abs=1e-9)
    assert (rep["velocity"].count, rep["velocity"].first_time_s) == (14, 3.0)
    assert rep["velocity"].worst_depth == pytest.approx(0.05, abs=1e-12)
    assert (rep["angular_velocity"].count, rep["angular_velocity"].first_time_s) == (1, 6.0)
    assert rep["angular_velocity"].worst_depth == pytest.approx(0.1, abs=1e-12)
    assert (rep["input"].count, rep["input"].first_time_s) == (1, 6.0)
    assert rep["input"].worst_depth == pytest.approx(0.5, abs=1e-12)  # 0.3 N against 0.2 N: 50 % over
    block = safety_block(rep, samples=t.size, robot_radius_m=0.05, keep_in_margin_m=0.0)
    json.dumps(block, allow_nan=False)
    report = StatusReport()
    add_safety_reasons(report, block)
    assert report.status == "unsafe"
    assert [r.kind for r in report.reasons] == ["keep_in", "keep_out", "velocity", "angular_velocity", "input"]
    assert [r.level for r in report.reasons][-1] == "degraded"
    assert "4 plant samples (first at t = 0.00 s, up to 0.5 m outside)" in report.reasons[0].message


def test_exactly_at_a_limit_is_no_violation_and_non_finite_is():
    t = np.array([0.0, 1.0, 2.0])
    x = np.zeros((3, 13))
    x[:, 9] = 1.0
    x[:, 3] = 0.2
    x[:, 10] = -0.1745
    rep = safety_report(t, x, scene=None, velocity_limit_mps=np.full(3, 0.2),
                        angular_velocity_limit_radps=np.full(3, 0.1745))
    assert all(v.count == 0 and v.first_time_s is None for v in rep.values())
    x[2, 0] = np.nan
    x[1, 4] = np.inf
    rep = safety_report(t, x, scene=Scene(keep_in=(Box([-1, -1, -1], [1, 1, 1]),)),
                        velocity_limit_mps=np.full(3, 0.2), angular_velocity_limit_radps=np.full(3, 0.1745))
    assert (rep["keep_in"].count, rep["keep_in"].first_time_s, rep["keep_in"].worst_depth) == (1, 2.0, np.inf)
    assert (rep["velocity"].count, rep["velocity"].worst_depth) == (1, np.inf)


# ------------------------------------------------------------------------------------------------------------
# Run folders
# ------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("exc", "status"), [(KeyboardInterrupt(), "interrupted"), (RuntimeError("boom"), "failed")])
def test_a_stopped_run_says_so_and_is_not_complete(tmp_path, exc, status):
    out = tmp_path / "run"
    with pytest.raises(type(exc)), open_stage_run("track", "x", "name: x\n", out=out) as run:
        run.file("mcap", "track.mcap").write_text("partial")
        raise exc
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == status and summary["stage"] == "track"
    assert summary["files"] == {"config": "config.yaml", "mcap": "track.mcap"}
    assert not is_complete(out)
    assert warning_line(summary).startswith(f"warning: track status {status}: ")


@pytest.mark.parametrize(("status", "complete"), [("ok", True), ("degraded", True), ("unsafe", True),
                                                   ("no_solution", True), ("failed", False), ("interrupted", False)])
def test_complete_run_folders(tmp_path, status, complete):
    with open_stage_run("track", "x", "name: x\n", out=tmp_path / "run") as run:
        run.finish({"stage": "track", "status": status})
    assert is_complete(tmp_path / "run") is complete
    assert not is_complete(tmp_path / "missing")


def test_stage_run_opens_its_mcap_with_the_run_metadata_and_returns_its_result(tmp_path):
    """One place builds the MCAP's ``oacli`` metadata: the run's seed, name and frame, the stage's extras."""
    config_yaml = "name: probe\nseed: 17\n"
    with open_stage_run("estimate", "probe", config_yaml, seed=17, frame="iss", out=tmp_path / "run") as run:
        with run.open_mcap(method="batch", telemetry="in/track.mcap") as writer:
            writer.write_log(0.0, "info", "hello")
        result = run.finish({"stage": "estimate", "status": "ok"})
    assert result.run_dir == tmp_path / "run" and result.summary["status"] == "ok"
    assert {k: p.name for k, p in result.files.items()} == {"config": "config.yaml", "mcap": "estimate.mcap",
                                                           "summary": "summary.json"}
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["files"] == {
        "config": "config.yaml", "mcap": "estimate.mcap"}
    record = read_stage(result.files["mcap"])
    meta = record.metadata["oacli"]
    assert {k: meta[k] for k in ("stage", "seed", "config_name", "frame", "method", "telemetry")} == {
        "stage": "estimate", "seed": "17", "config_name": "probe", "frame": "iss", "method": "batch",
        "telemetry": "in/track.mcap"}
    assert meta["version"] == oacli.__version__ and meta["git_commit"]
    assert record.attachments["config.yaml"].decode() == config_yaml
