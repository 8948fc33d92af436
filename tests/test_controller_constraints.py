"""Keep-in and keep-out inside the controllers: the shared convex pieces, the compiled path with
parameters in the constraint matrix, DPP, closed loops with a plant heavier than the model (standard MPC, soft
rows) and with disturbances in W (tube MPC, hard tightened rows), the standard MPC's safe hold, and the payload
chain ``oacli excite`` -> ``oacli track`` read back from the MCAP."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import cvxpy as cp
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.control.compiled_qp import CompiledQP
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.mpc import LinearMPC
from oacli.control.tracking import TrackingMPC, TrackingWeights, to_error_state
from oacli.control.tube_design import AncillaryWeights, design_translation_tube
from oacli.control.tube_mpc import TerminalWeights, TubeMPC
from oacli.control.workspace import PositionRows, WorkspaceRows, braking_lines, shifted_plan
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.geometry.collision import CollisionChecker, RobotBody
from oacli.geometry.halfspaces import best_piece, keep_in_pieces, keep_out_zone, point_halfspaces
from oacli.io.mcap_io import read_telemetry, read_trajectory
from oacli.model.double_integrator import hover_error_model
from oacli.model.limits import MotionLimits
from oacli.model.quaternion import to_rotation_matrix
from oacli.planning.polish import keep_out_halfspaces
from oacli.reference import waypoint_reference
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.stages.track_tube import workspace_arguments
from oacli.trajectory import feedforward_inputs, sample_states
from oacli.types import InertialParams, SolveInfo
from tests.conftest import REPO
from tests.model_helpers import mass_model

# [AstrobeeFSW] astrobee/config/worlds/iss.config: the bare robot
BARE = InertialParams(9.583788668, [0.153427995, 0.14271405, 0.162302759])
PAYLOAD = InertialParams(15.0, [0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1, Astrobee with the printed object
RADIUS = 0.25  # [AstrobeeFSW] astrobee/config/worlds/iss.config, collision radius
U_MAX = np.array([0.452, 0.216, 0.257, 0.0452, 0.0216, 0.0257])  # [ReSWARM2023] Table 2 (2000 RPM), torque ≈ 1/10
LIMITS = MotionLimits(U_MAX[:3], U_MAX[3:], np.full(3, 0.2), np.full(3, 0.1745))
WEIGHTS = TrackingWeights(*[np.full(3, v) for v in (10.0, 1.0, 10.0, 1.0, 1.0, 100.0)])
ISS = load_config(REPO / "configs" / "iss_reswarm.yaml").scene()
runner = CliRunner()


def body_inside(scene: Scene, positions: np.ndarray, radius: float) -> np.ndarray:
    """True where a sphere of ``radius`` centred at each position lies in the keep-in union: its centre is in a
    convex piece of the union (a box or a bridge between two boxes) shrunk by the radius."""
    lo, hi = keep_in_pieces(scene)
    p = np.asarray(positions, dtype=float)[:, None, :]
    return np.any(np.all((p >= lo + radius - 1e-12) & (p <= hi - radius + 1e-12), axis=2), axis=1)


def body_clear(scene: Scene, positions: np.ndarray, radius: float) -> np.ndarray:
    """True where the sphere touches no keep-out zone (exact ellipsoid test of the collision checker)."""
    checker = CollisionChecker(Scene(keep_out=scene.keep_out), RobotBody.sphere(radius))
    return checker.points_free(np.asarray(positions, dtype=float))


# -- the convex pieces -------------------------------------------------------------------------------------------


def test_bridges_of_the_jem_boxes_lie_in_the_union_and_join_the_shrunk_boxes(rng):
    lo, hi = keep_in_pieces(ISS)
    assert lo.shape == (5, 3)  # the three JEM boxes and the two bridges between touching boxes
    pts = lo[3:, None, :] + rng.uniform(0, 1, (2, 5000, 3)) * (hi[3:] - lo[3:])[:, None, :]
    assert np.all(ISS.in_keep_in(pts.reshape(-1, 3)))  # every point of a bridge is in one of the boxes
    # Along the flight from A to B the shrunk boxes leave a gap at y = -9.2365; the shrunk bridge has none.
    path = np.column_stack([np.full(50, 10.8), np.linspace(-9.6, -7.75, 50), np.linspace(4.8, 5.2, 50)])
    boxes_only = Scene(keep_in=ISS.keep_in)
    in_shrunk_box = np.any([b.contains(path, RADIUS) for b in boxes_only.keep_in], axis=0)
    assert not np.all(in_shrunk_box)
    assert np.all(body_inside(ISS, path, RADIUS))


def test_best_piece_holds_the_point_with_the_largest_margin_or_is_the_nearest():
    lo = np.array([[0.0, 0, 0], [0.5, 0, 0], [3.0, 0, 0]])
    hi = np.array([[1.0, 1, 1], [2.0, 1, 1], [4.0, 1, 1]])
    pts = np.array([[0.3, 0.5, 0.5], [0.9, 0.5, 0.5], [1.5, 0.5, 0.5], [2.6, 0.5, 0.5], [5.0, 0.5, 0.5]])
    # 0.9: in both of the first two boxes, margin 0.1 in box 0, 0.4 in box 1; 2.6 is outside all, nearest box 2.
    np.testing.assert_array_equal(best_piece(lo, hi, pts), [0, 1, 1, 2, 2])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_point_half_space_excludes_the_grown_zone_and_matches_the_polish(seed):
    """Every centre position in the half-space keeps the body out of the zone (exact check); the polish's
    half-space of a degenerate piece (three equal control points) is the same one (one implementation)."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal(4)
    rotation = to_rotation_matrix(q / np.linalg.norm(q))
    zone_e = Ellipsoid.from_semi_axes(rng.uniform(-1, 1, 3), rng.uniform(0.1, 0.8, 3), rotation)
    radius = float(rng.choice([0.0, 0.25]))
    body = RobotBody.sphere(radius)
    zone = keep_out_zone(zone_e, body)
    p = zone_e.center + rng.normal(0, 1.5, (1, 3))
    n, beta, margin = point_halfspaces(zone, p)
    n2, beta2, margin2 = keep_out_halfspaces(zone, p, p, p, 0.0)
    np.testing.assert_allclose(n, n2, atol=1e-12)
    np.testing.assert_allclose([beta, margin], [beta2, margin2], atol=1e-12)
    pts = rng.uniform(-4, 4, (3000, 3))
    pts = pts + np.clip(beta[0] - pts @ n[0], 0, None)[:, None] * n[0]  # projected into the half-space
    assert np.all(CollisionChecker(Scene(keep_out=(zone_e,)), body).points_free(pts))
    # Tight: the plane touches the grown zone at its support point along n.
    sz, nn = zone.sigma_zone, n[0]
    touch = zone_e.center + sz @ nn / np.sqrt(nn @ sz @ nn) + radius * nn
    assert nn @ touch == pytest.approx(beta[0], abs=1e-12)


@settings(max_examples=80, deadline=None)
@given(a=st.floats(0.002, 0.05), vbar=st.floats(0.02, 0.3), frac_d=st.floats(0, 1), frac_v=st.floats(0, 1))
def test_braking_rows_certify_the_stop_and_are_invariant_under_braking(a, vbar, frac_d, frac_v):
    """A state (distance d to the face, speed v towards it) that satisfies the rows stops within d when braking
    at the full deceleration ā, and stays inside the rows all the way (recursive feasibility)."""
    lines = braking_lines(np.array([a]), np.array([vbar]))

    def ok(d, v):
        return all(v <= ic[0] + sl[0] * d + 1e-12 for sl, ic in lines)

    d_star = vbar**2 / a
    d = frac_d * 2 * d_star
    v_max = min(vbar, min(ic[0] + sl[0] * d for sl, ic in lines))
    v = frac_v * v_max
    assert ok(d, v)
    assert v * v / (2 * a) <= d + 1e-12  # the stop point is inside
    tau = np.linspace(0, v / a, 200)
    assert all(ok(d - (v * s - 0.5 * a * s * s), v - a * s) for s in tau)


def test_shifted_plan_interpolates_and_holds_at_the_ends():
    plan = np.arange(18.0).reshape(6, 3)
    got = shifted_plan(2.0, 1.0, plan, np.array([1.0, 2.0, 2.5, 7.0, 9.0]))
    np.testing.assert_allclose(got, [plan[0], plan[0], 0.5 * (plan[0] + plan[1]), plan[5], plan[5]])


# -- the compiled path with parameters in the constraint matrix, DPP ---------------------------------------------


def test_compiled_path_updates_a_when_parameters_multiply_variables(rng):
    x = cp.Variable((5, 3))
    normal, offset, target = cp.Parameter((5, 3)), cp.Parameter(5), cp.Parameter((5, 3))
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x) - 2 * cp.sum(cp.multiply(target, x))),
                         [cp.sum(cp.multiply(normal, x), axis=1) >= offset, x <= 2.0])
    assert problem.is_dpp()
    compiled = CompiledQP(problem)
    for i in range(8):
        n = rng.normal(size=(5, 3))
        b = rng.normal(size=5)
        if i % 2:  # inactive rows: a zero normal (its entries stay in the pattern) and offset -1
            n[[1, 3]] = 0.0
            b[[1, 3]] = -1.0
        normal.value, offset.value, target.value = n, b, rng.normal(size=(5, 3))
        fast = compiled.solve()
        problem.solve(solver=cp.CLARABEL)
        assert fast.success and problem.status == "optimal"
        np.testing.assert_allclose(compiled.value(x), x.value, atol=1e-6)
        assert fast.objective == pytest.approx(problem.value, rel=1e-7, abs=1e-8)


def _random_rows(rng, k, zones, box=True):
    lower = rng.uniform(-1.5, -0.5, (k, 3)) if box else np.zeros((k, 0))
    upper = rng.uniform(0.5, 1.5, (k, 3)) if box else np.zeros((k, 0))
    normals = rng.normal(size=(zones, k, 3))
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    offsets = rng.uniform(-1.0, 0.2, (zones, k))
    normals[0, ::2] = 0.0  # some inactive rows
    offsets[0, ::2] = -1.0
    return PositionRows(lower, upper, normals, offsets)


def test_standard_mpc_with_rows_is_dpp_and_both_paths_agree(rng):
    a, b = hover_error_model(BARE, 0.2)
    kw = dict(keep_in=True, keep_out_zones=2, braking_mps2=LIMITS.force_N / BARE.mass_kg,
              braking_speed_mps=LIMITS.velocity_mps)
    x_max = LIMITS.error_state
    fast = LinearMPC(a, b, WEIGHTS.q_diag, WEIGHTS.r_diag, 10, LIMITS.input, x_max=x_max, **kw)
    slow = LinearMPC(a, b, WEIGHTS.q_diag, WEIGHTS.r_diag, 10, LIMITS.input, x_max=x_max, fast=False, **kw)
    assert fast.problem.is_dpp()
    slacks = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(6):
            x0 = np.r_[rng.uniform(-1, 1, 3), rng.uniform(-0.05, 0.05, 3), rng.uniform(-0.3, 0.3, 3), np.zeros(3)]
            x_ref = np.tile(rng.uniform(-0.5, 0.5, 12) * np.r_[[1] * 3, [0.1] * 9], (11, 1))
            rows = _random_rows(rng, 10, 2)
            f = fast.solve(x0, x_ref, np.zeros((10, 6)), rows)
            s = slow.solve(x0, x_ref, np.zeros((10, 6)), rows)
            assert f.info.success and s.info.success
            np.testing.assert_allclose(f.u, s.u, atol=1e-5)
            assert f.info.objective == pytest.approx(s.info.objective, rel=1e-6)
            assert f.position_slack_m == pytest.approx(s.position_slack_m, abs=1e-6)
            slacks.append(f.position_slack_m)
            if f.position_slack_m < 1e-7:  # met rows: the predicted positions satisfy them
                assert np.all(rows.violation_m(f.x[1:, 0:3]) <= 1e-6)
    assert max(slacks) > 0  # some random rows are not met by x0's motion: the soft path was exercised
    with pytest.raises(ValueError, match="workspace rows"):
        fast.solve(np.zeros(12), np.zeros((11, 12)), np.zeros((10, 6)))


def _jem_zone_scene() -> Scene:
    """The JEM with a keep-out sphere of 0.15 m radius 0.3 m beside the straight A -> B line."""
    return Scene(keep_in=ISS.keep_in, keep_out=(Ellipsoid.from_semi_axes([11.1, -8.7, 5.0], [0.15] * 3),),
                 frame="iss")


def _tube_design(mass=9.5, mass_std=0.1, force=0.002):
    spec = DisturbanceSpec(force_N=np.full(3, force))
    return design_translation_tube(model=mass_model(mass, mass_std), dt_s=0.2, force_limit_N=np.full(3, 0.15),
                                   velocity_limit_mps=np.full(3, 0.2), weights=AncillaryWeights(5.0, 10.0, 2.0),
                                   spec=spec, epsilon=0.005)


TUBE_WEIGHTS = TrackingWeights(*(np.full(3, w) for w in (50.0, 5.0, 10.0, 1.0, 0.1, 100.0)))


def _a_to_b(params, speed=0.05):
    return waypoint_reference(np.array([[10.8, -9.6, 4.8], [10.8, -7.75, 5.2]]),
                              np.array([[0.0, 0.0, -0.7071068, 0.7071068]] * 2), params, speed_mps=speed,
                              accel_mps2=0.01, rate_radps=0.0873, ang_accel_radps2=0.05, hold_s=2.0)


def _tube(reference, design, scene, fast=True):
    return TubeMPC(reference, design, inertia_kgm2=BARE.inertia_kgm2, horizon=5,
                   prediction_step_s=1.0, weights=TUBE_WEIGHTS, limits=LIMITS,
                   terminal=TerminalWeights(np.full(3, 100.0), np.full(3, 10.0)), fast=fast, scene=scene,
                   robot=RobotBody.sphere(RADIUS), keep_in_margin_m=RADIUS)


def test_tube_qp_with_rows_is_dpp_and_the_closed_loop_is_the_same_through_either_path():
    design = _tube_design()
    ref = _a_to_b(InertialParams(9.5, BARE.inertia_kgm2))
    runs = []
    for fast in (True, False):
        ctrl = _tube(ref, design, _jem_zone_scene(), fast=fast)
        assert ctrl.qp.problem.is_dpp()
        tel = simulate(ctrl, ref.x[0], InertialParams(9.5, BARE.inertia_kgm2), duration_s=8.0, control_period_s=0.2,
                       plant_period_s=1 / 62.5, input_limits=U_MAX, sensors=SensorNoise(),
                       disturbance=Disturbance(np.zeros(6), np.zeros(6)), rng=np.random.default_rng(0))
        runs.append((tel, ctrl))
    (tel_a, ctrl_a), (tel_b, _) = runs
    assert ctrl_a.qp.compiled._t_a is not None  # the keep-out normals are parameters of A
    assert all(i.success for i in tel_a.solve_info)
    np.testing.assert_allclose(tel_a.u_command, tel_b.u_command, atol=1e-7)
    np.testing.assert_allclose(tel_a.x_true, tel_b.x_true, atol=1e-8)


def test_without_a_scene_the_controllers_are_unchanged(rng):
    """scene=None builds exactly the problem without rows (same sizes, same solution as a plain LinearMPC)."""
    ref = _a_to_b(BARE, speed=0.1)
    plain = TrackingMPC(ref, BARE, dt_s=0.2, horizon=10, weights=WEIGHTS, limits=LIMITS)
    a, b = hover_error_model(BARE, 0.2)
    base = LinearMPC(a, b, WEIGHTS.q_diag, WEIGHTS.r_diag, 10, LIMITS.input, x_max=LIMITS.error_state)
    assert plain.workspace is None and plain.mpc.compiled.n_constraints == base.compiled.n_constraints
    x = ref.x[0].copy()
    x[0:3] += rng.normal(0, 0.05, 3)
    step = plain.step(3.0, x)
    xr = sample_states(ref, 3.0 + 0.2 * np.arange(11))
    sol = base.solve(to_error_state(x, xr[0, 0:3], xr[0, 6:10]), to_error_state(xr, xr[0, 0:3], xr[0, 6:10]),
                     feedforward_inputs(xr, 0.2, BARE))
    np.testing.assert_array_equal(step.u, sol.u[0])


# -- closed loops --------------------------------------------------------------------------------------------------

#: A 3 m bay with a keep-out sphere (0.2 m) whose centre is 0.3 m beside the reference line, which itself runs
#: 0.2 m below the ceiling: tracking the line exactly puts the 0.25 m robot into the zone and through the ceiling.
BAY = Scene(keep_in=(Box([0.0, -1.0, -1.0], [3.0, 1.0, 1.0]),),
            keep_out=(Ellipsoid.from_semi_axes([1.5, 0.3, 0.8], [0.2, 0.2, 0.2]),))


def _bay_reference():
    return waypoint_reference(np.array([[0.9, 0.0, 0.8], [2.1, 0.0, 0.8]]), np.array([[0.0, 0.0, 0.0, 1.0]] * 2),
                              BARE, speed_mps=0.08, accel_mps2=0.01, rate_radps=0.05, ang_accel_radps2=0.02,
                              hold_s=1.0)


def _fly_bay(scene, seed):
    ref = _bay_reference()
    ctrl = TrackingMPC(ref, BARE, dt_s=0.2, horizon=10, weights=WEIGHTS, limits=LIMITS, scene=scene,
                       robot=RobotBody.sphere(RADIUS), keep_in_margin_m=RADIUS, max_consecutive_failures=5)
    x0 = ref.x[0].copy()
    x0[2] -= 0.1  # start below the ceiling's margin (the reference start itself is too close to it)
    tel = simulate(ctrl, x0, PAYLOAD, duration_s=ref.duration_s + 4.0, control_period_s=0.2,
                   plant_period_s=1 / 62.5, input_limits=U_MAX,
                   sensors=SensorNoise(position_std_m=0.002, velocity_std_mps=0.0005),
                   disturbance=Disturbance(np.zeros(6), np.r_[np.full(3, 0.002), np.zeros(3)]),
                   rng=np.random.default_rng(seed))
    return ref, tel


def test_standard_mpc_keeps_a_heavier_plant_in_the_keep_in_and_out_of_the_keep_out():
    """Truth 15 kg (Table 1 inertias), model the bare 9.58 kg robot. Without rows the robot follows the reference
    into the keep-out zone and through the ceiling; with them the true state (every plant tick) stays clear."""
    _, tel = _fly_bay(None, seed=0)
    p = tel.x_true[:, 0:3]
    assert not np.all(body_inside(BAY, p, RADIUS)) and not np.all(body_clear(BAY, p, RADIUS))
    for seed in range(6):
        ref, tel = _fly_bay(BAY, seed)
        p = tel.x_true[:, 0:3]
        assert np.all(body_inside(BAY, p, RADIUS)), seed
        assert np.all(body_clear(BAY, p, RADIUS)), seed
        assert all(i.success for i in tel.solve_info)
        assert np.linalg.norm(p[-1] - ref.x[-1, 0:3]) < 0.3  # it still gets there (the goal is near the ceiling)


@pytest.mark.parametrize("seed", range(4))
def test_tube_mpc_keeps_the_true_state_in_the_tightened_sets_under_disturbances_in_w(seed):
    """Disturbances within W (truth mass in the 2σ interval, random force within the W force term): every plant
    tick of the true state has the body in the JEM and clear of a keep-out zone beside the A -> B path, the
    measured error stays in Z, and the nominal state used at each step satisfies its tightened rows."""
    rng = np.random.default_rng(seed)
    design = _tube_design()
    truth = InertialParams(9.5 + rng.uniform(-0.2, 0.2), BARE.inertia_kgm2)
    ref = _a_to_b(InertialParams(9.5, BARE.inertia_kgm2))
    scene = _jem_zone_scene()
    ctrl = _tube(ref, design, scene)
    tel = simulate(ctrl, ref.x[0], truth, duration_s=ref.duration_s + 3.0, control_period_s=0.2,
                   plant_period_s=1 / 62.5, input_limits=U_MAX, sensors=SensorNoise(),
                   disturbance=Disturbance(np.zeros(6), np.r_[np.full(3, 0.002), np.zeros(3)]), rng=rng)
    h = ctrl.history()
    assert set(h.mode) == {"mpc"}
    p = tel.x_true[:, 0:3]
    assert np.all(body_inside(scene, p, RADIUS)) and np.all(body_clear(scene, p, RADIUS))
    tol = 1e-7 * np.max(design.lasso.h_vector)
    assert np.all(h.tube_margin[1:] >= -tol)
    # The zone forced a detour: the unconstrained reference passes through the grown zone.
    assert not np.all(body_clear(scene, ref.x[:, 0:3], RADIUS))
    # Mechanism: the applied nominal z_0 is in the tightened keep-in box of its step (recomputed here).
    rows = ctrl.workspace.rows(sample_states(ref, h.t)[:, 0:3])
    z = h.nominal_state[:, 0:3]
    assert np.all((z >= rows.lower - 1e-7) & (z <= rows.upper + 1e-7))


# -- the standard MPC's safe hold ---------------------------------------------------------------------------------


def test_standard_mpc_latches_a_safe_hold_after_consecutive_failures(monkeypatch):
    ref = _a_to_b(BARE, speed=0.1)
    ctrl = TrackingMPC(ref, BARE, dt_s=0.2, horizon=10, weights=WEIGHTS, limits=LIMITS, scene=ISS,
                       robot=RobotBody.sphere(RADIUS), keep_in_margin_m=RADIUS, max_consecutive_failures=3)
    real, calls = ctrl.mpc.compiled.solve, {"n": 0}

    def solve(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 60:  # every solve after 12 s fails
            return SolveInfo("infeasible", False, float("nan"), -1, 0.0)
        return real(*args, **kwargs)

    monkeypatch.setattr(ctrl.mpc.compiled, "solve", solve)
    tel = simulate(ctrl, ref.x[0], BARE, duration_s=40.0, control_period_s=0.2, plant_period_s=1 / 62.5,
                   input_limits=U_MAX, sensors=SensorNoise(), disturbance=Disturbance.none(),
                   rng=np.random.default_rng(0))
    status = [i.status for i in tel.solve_info]
    assert all(i.success for i in tel.solve_info[:60])
    assert status[60:62] == ["fallback (infeasible)"] * 2 and status[62] == "hold (infeasible)"
    assert set(status[63:]) == {"hold (safe_hold)"} and not any(i.success for i in tel.solve_info[60:])
    assert calls["n"] == 63  # no solve once in the hold
    assert np.linalg.norm(tel.x_true[-1, 3:6]) < 1e-6  # braked to rest
    assert np.all(np.abs(tel.u_command) <= U_MAX + 1e-12)
    q_entry = tel.x_measured[62, 6:10]
    assert abs(abs(float(q_entry @ tel.x_true[-1, 6:10])) - 1.0) < 1e-6  # attitude held
    speed = np.linalg.norm(tel.x_true[:, 3:6], axis=1)
    t_hold = tel.t_ctrl[62]
    after = tel.t_true >= t_hold + 0.2
    assert np.all(np.diff(speed[after]) <= 1e-9)  # braking, never speeding up


# -- the payload chain through the CLI -----------------------------------------------------------------------------


def payload_config(tmp: Path, controller: str, *, keep_in=None, excitation=None, constraints=True,
                   keep_in_margin_m: float = 0.0) -> Path:
    """iss_reswarm.yaml with the 15 kg payload as the plant and the bare robot as the model; for the tube, W covers
    the payload by [Doerr2021] Eq. 28's one-step deviation ``f(u, m₀) − f(u, m_true)`` at the largest force per axis."""
    data = yaml.safe_load((REPO / "configs" / "iss_reswarm.yaml").read_text())
    data["truth"] = {"mass_kg": float(PAYLOAD.mass_kg), "inertia_kgm2": [float(v) for v in PAYLOAD.inertia_kgm2]}
    data["sensors"] = dict.fromkeys(("position_std_m", "velocity_std_mps", "attitude_std_rad",
                                     "angular_velocity_std_radps"), 0.0)  # the tube needs bounded noise
    if keep_in is not None:
        data["environment"]["keep_in"] = [{"corners": keep_in}]
    data["environment"]["keep_in_margin_m"] = keep_in_margin_m
    if excitation:
        data["excitation"].update(excitation)
    ctrl = data["controller"]
    ctrl["type"], ctrl["position_constraints"] = controller, constraints
    if controller == "tube":
        m0, dt = data["robot"]["mass_kg"], 1.0 / ctrl["rate_hz"]
        u = np.asarray(data["robot"]["force_limit_N"])
        dv = u * (1.0 / m0 - 1.0 / PAYLOAD.mass_kg) * np.array([[dt * dt / 2], [dt]])  # [position; velocity]
        ctrl.update(horizon=5, weights={"position": 50.0, "velocity": 5.0, "force": 0.1, "attitude": 10.0,
                                        "angular_velocity": 1.0, "torque": 100.0})
        ctrl["tube"] = {"prediction_step_s": 1.0, "terminal": {"position": 100.0, "velocity": 10.0},
                        "disturbance": {"position_m": (dv[0] * 1.001).tolist(),
                                        "velocity_mps": (dv[1] * 1.001).tolist()}}
    path = tmp / f"payload-{controller}-{constraints}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_cli(*args) -> None:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output


def true_positions(run: Path) -> tuple[np.ndarray, Scene]:
    tel = read_telemetry(run / "track.mcap")
    return tel.x_true[:, 0:3], load_config(run / "config.yaml").scene()


def test_payload_chain_with_the_tube_stays_in_the_keep_in_fast(tmp_path):
    """Shrunk chain: a 20 s excitation in a tight keep-in box (its reference passes within 0.1 m of the walls,
    closer than the robot's radius), tracked by the tube MPC with the 15 kg plant and
    environment.keep_in_margin_m = the robot's radius (the body must stay in the box), with and without the
    workspace rows; /state/true read back from the MCAP, the status checked against it."""
    box = [[10.4, -8.15, 3.9], [11.4, -7.35, 5.6]]
    excite_cfg = payload_config(tmp_path, "mpc", keep_in=box, excitation={"duration_s": 20.0, "steps": 40})
    run_cli("excite", excite_cfg, "--out", tmp_path / "excite", "--quiet")
    reference = read_trajectory(tmp_path / "excite" / "excite.mcap")
    scene = load_config(excite_cfg).scene()
    assert not np.all(body_inside(scene, reference.x[:, 0:3], RADIUS))  # tracking it exactly would hit a wall
    inside = {}
    for on in (True, False):
        cfg = payload_config(tmp_path, "tube", keep_in=box, constraints=on, keep_in_margin_m=RADIUS)
        out = tmp_path / f"track-{on}"
        result = runner.invoke(app, ["track", str(cfg), "--reference", str(tmp_path / "excite" / "excite.mcap"),
                                     "--out", str(out), "--quiet"])
        p, scene = true_positions(out)
        assert p.shape[0] > 1000  # every plant tick (62.5 Hz)
        inside[on] = bool(np.all(body_inside(scene, p, RADIUS)))
        status = json.loads((out / "summary.json").read_text())["status"]
        assert (result.exit_code, status) == ((0, "ok") if inside[on] else (4, "unsafe")), result.output
    assert inside == {True: True, False: False}  # with rows it stays in; the same tube without them does not


@pytest.mark.slow
def test_payload_chain_of_the_issue_stays_in_the_jem_with_the_tube_and_leaves_it_without_rows(tmp_path):
    """The issue's chain: oacli excite (60 s, the preset) then oacli track with the 15 kg plant and the bare-robot
    model, in the JEM, with environment.keep_in_margin_m = the robot's radius (its body must stay inside). Tube MPC
    with rows: the body stays in the keep-in at every plant tick; the same tube without rows leaves it (so the check
    can fail); standard MPC with rows stays inside too on this run. The status agrees with /state/true."""
    excite_cfg = payload_config(tmp_path, "mpc")
    run_cli("excite", excite_cfg, "--out", tmp_path / "excite", "--quiet")
    ref = tmp_path / "excite" / "excite.mcap"
    outcome = {}
    for controller, on in (("tube", True), ("tube", False), ("mpc", True)):
        out = tmp_path / f"track-{controller}-{on}"
        cfg = payload_config(tmp_path, controller, constraints=on, keep_in_margin_m=RADIUS)
        result = runner.invoke(app, ["track", str(cfg), "--reference", str(ref), "--out", str(out), "--quiet"])
        p, scene = true_positions(out)
        outcome[controller, on] = bool(np.all(body_inside(scene, p, RADIUS)))
        summary = json.loads((out / "summary.json").read_text())
        assert (summary["safety"]["keep_in"]["count"] == 0) == outcome[controller, on]
        assert result.exit_code == (4 if summary["status"] == "unsafe" else 0), result.output
    assert outcome == {("tube", True): True, ("tube", False): False, ("mpc", True): True}


def body_excursion_m(scene: Scene, positions: np.ndarray, radius: float) -> np.ndarray:
    """Per position, how far [m] the sphere's centre is from the nearest convex piece of the keep-in union shrunk by
    the radius (L∞; 0 inside one): an upper bound of how far the body reaches out of the union."""
    lo, hi = keep_in_pieces(scene)
    p = np.asarray(positions, dtype=float)[:, None, :]
    excess = np.max(np.maximum(lo + radius - p, p - hi + radius), axis=2)
    return np.maximum(excess.min(axis=1), 0.0)


def test_standard_mpc_with_rows_keeps_far_closer_to_the_corner_the_reference_cuts(tmp_path):
    """The reference of tests/test_cli_status.py: across a concave corner of the keep-in, 0.128 m outside it.
    Without rows the robot's centre follows it out of the JEM (unsafe, exit 4); with the default rows (soft, at the
    control instants: no guarantee) it stays within a centimetre of the keep-in, and the status says honestly
    whether it left (unsafe, exit 4) or not (ok)."""
    data = yaml.safe_load((REPO / "configs" / "iss_reswarm.yaml").read_text())
    q = [0.0, 0.0, -0.7071068, 0.7071068]
    data["waypoints"]["P"] = {"position": [12.25, -9.6, 4.8], "quaternion": q}
    data["waypoints"]["Q"] = {"position": [11.9, -8.6, 4.8], "quaternion": q}
    data["reference"]["waypoints"] = ["P", "Q"]
    excursion = {}
    for on in (True, False):
        data["controller"]["position_constraints"] = on
        cfg = tmp_path / f"corner-{on}.yaml"
        cfg.write_text(yaml.safe_dump(data, sort_keys=False))
        result = runner.invoke(app, ["track", str(cfg), "--out", str(tmp_path / f"run-{on}"), "--quiet"])
        summary = yaml.safe_load((tmp_path / f"run-{on}" / "summary.json").read_text())
        p, scene = true_positions(tmp_path / f"run-{on}")
        depth = body_excursion_m(scene, p, 0.0)
        left = bool(np.any(depth > 1e-9))
        assert summary["safety"]["keep_in"]["count"] == int(np.sum(depth > 1e-9))
        assert (result.exit_code, summary["status"]) == ((4, "unsafe") if left else (0, "ok"))
        excursion[on] = float(depth.max())
    assert excursion[True] < 0.01 and excursion[False] > 0.05


def test_position_constraints_switch_reaches_the_controllers():
    cfg = load_config(REPO / "configs" / "iss_reswarm_tube.yaml")
    args = workspace_arguments(cfg)
    assert cfg.controller.position_constraints is True
    assert [b.lower.tolist() for b in args["scene"].keep_in] == [b.lower.tolist() for b in cfg.scene().keep_in]
    assert args["robot"].bounding_radius_m == pytest.approx(cfg.robot.radius_m)
    off = cfg.model_copy(update={"controller": cfg.controller.model_copy(update={"position_constraints": False})})
    assert workspace_arguments(off) == {}
    assert args["keep_in_margin_m"] == cfg.environment.keep_in_margin_m == 0.0  # keep-in bounds the centre
    ws = WorkspaceRows(ISS, RobotBody.sphere(RADIUS), keep_in_margin_m=RADIUS)
    rows = ws.rows(np.array([[10.8, -9.6, 4.8]]))
    np.testing.assert_allclose(rows.upper - rows.lower, [[2.1355 - 0.5, 6.4833 + 2.4 - 0.5, 2.1349 - 0.5]], atol=1e-9)
