"""Robust tube MPC: the QP (DPP, fast path = problem.solve()), W ([Doerr2021] Eq. 28), the design, the closed loop
under disturbances drawn from W (random and vertex sequences), the Mayne et al. 2005 example, fallback and hold."""

from __future__ import annotations

import warnings

import cvxpy as cp
import numpy as np
import pytest

from oacli.control.compiled_qp import CompiledQP
from oacli.control.disturbance import DisturbanceSpec, mass_uncertainty_bound
from oacli.control.lqr import dlqr, solve_dare
from oacli.control.mpc import LinearMPC
from oacli.control.tracking import TrackingWeights
from oacli.control.tube_design import AncillaryWeights, design_translation_tube
from oacli.control.tube_mpc import TerminalWeights, TubeMPC
from oacli.control.tube_qp import LinearConstraint, NominalQP, QPBlock
from oacli.errors import InfeasibleError
from oacli.model.double_integrator import double_integrator
from oacli.model.limits import MotionLimits
from oacli.reference import waypoint_reference
from oacli.sets import Polytope, minimal_rpi_outer, rpi_margins
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.types import InertialParams
from tests.model_helpers import mass_model

# ReSWARM tube MPC settings ([RattleCode] casadi_nmpc / z_poly_calc).
MASS = 9.5
INERTIA = [0.153427995, 0.14271405, 0.162302759]  # astrobee iss.config
DT = 0.2
U_TUBE = np.full(3, 0.15)
V_MAX = np.full(3, 0.2)
WEIGHTS = TrackingWeights(*(np.full(3, w) for w in (50.0, 5.0, 10.0, 1.0, 0.1, 100.0)))
LIMITS = MotionLimits(np.array([0.452, 0.216, 0.257]), np.array([0.0452, 0.0216, 0.0257]), V_MAX,
                        np.full(3, 0.1745))
TERMINAL = TerminalWeights(np.full(3, 100.0), np.full(3, 10.0))


def reswarm_design(mass_std=0.1, force=0.002, **kw):
    spec = DisturbanceSpec(force_N=np.full(3, force))
    return design_translation_tube(model=mass_model(MASS, mass_std), dt_s=DT, force_limit_N=U_TUBE,
                                   velocity_limit_mps=V_MAX,
                                   weights=AncillaryWeights(5.0, 10.0, 2.0), spec=spec, epsilon=0.005,
                                   epsilon_mode="absolute", facet_growth=0.05, **kw)  # rattle z_poly_calc


def two_block_qp(horizon, design, fast=True, **kw):
    from oacli.model.double_integrator import hover_error_model

    a, b = hover_error_model(InertialParams(MASS, INERTIA), 1.0)
    trans = QPBlock("translation", a[:6, :6], b[:6, :3], np.r_[WEIGHTS.position, WEIGHTS.velocity], WEIGHTS.force,
                    np.diag(np.r_[TERMINAL.position, TERMINAL.velocity]), state=design.tightened_state,
                    input=design.tightened_input, lasso=design.lasso)
    q_r = np.r_[WEIGHTS.attitude, WEIGHTS.angular_velocity]
    rot = QPBlock("attitude", a[6:, 6:], b[6:, 3:], q_r, WEIGHTS.torque,
                  solve_dare(a[6:, 6:], b[6:, 3:], np.diag(q_r), np.diag(WEIGHTS.torque)),
                  state=LinearConstraint.box(np.r_[np.full(3, np.inf), LIMITS.angular_velocity_radps]),
                  input=LinearConstraint.box(LIMITS.torque_Nm))
    return NominalQP([trans, rot], horizon, fast=fast, **kw)


def random_parameters(qp, rng, scale=1.0):
    n, out = qp.horizon, {}
    for name in ("translation", "attitude"):
        x = rng.normal(size=6) * np.r_[[0.2] * 3, [0.02] * 3] * scale
        ref = np.cumsum(rng.normal(size=(n + 1, 6)) * 0.01, axis=0)
        out[name] = (x, ref, rng.normal(size=(n, 3)) * 0.01)
        qp.set_parameters(name, *out[name])
    return out


@pytest.fixture(scope="module")
def design():
    return reswarm_design()


# -- the QP ------------------------------------------------------------------------------------------------------


def test_nominal_qp_is_dpp_and_resolving_raises_no_warning(design, rng):
    qp = two_block_qp(5, design)
    assert qp.problem.is_dpp()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a cvxpy warning (e.g. DPP lost, recompiling) fails the test
        for _ in range(3):
            random_parameters(qp, rng)
            assert qp.solve().info.success
            assert qp.solve(fast=False).info.success


@pytest.mark.parametrize("horizon", [1, 5, 20])
def test_fast_path_gives_the_problem_solve_solution(horizon, design, rng):
    qp = two_block_qp(horizon, design)
    for _ in range(6):
        random_parameters(qp, rng)
        fast, plain = qp.solve(), qp.solve(fast=False)
        assert fast.info.status == plain.info.status == "optimal"
        assert fast.info.objective == pytest.approx(plain.info.objective, rel=1e-9, abs=1e-12)
        for name in ("translation", "attitude"):
            np.testing.assert_allclose(fast.blocks[name].z, plain.blocks[name].z, atol=1e-9)
            np.testing.assert_allclose(fast.blocks[name].v, plain.blocks[name].v, atol=1e-9)


def test_solver_options_do_not_change_the_solution(design, rng):
    """Iterative refinement off (the default of both paths) vs Clarabel's own defaults: same optimum."""
    qp = two_block_qp(10, design)
    reference = two_block_qp(10, design, fast=False, clarabel_options={})
    for _ in range(5):
        random_parameters(qp, np.random.default_rng(_))
        random_parameters(reference, np.random.default_rng(_))
        a, b = qp.solve(), reference.solve()
        np.testing.assert_allclose(a.blocks["translation"].v, b.blocks["translation"].v, atol=1e-6)
        np.testing.assert_allclose(a.blocks["attitude"].v, b.blocks["attitude"].v, atol=1e-7)


def test_objective_includes_the_reference_constant(design, rng):
    """The QP drops Σ w r² (not DPP); NominalQP adds it back: its objective is the tracking cost of Eq. 27."""
    qp = two_block_qp(4, design)
    params = random_parameters(qp, rng)
    sol = qp.solve()
    cost = 0.0
    for blk in qp.blocks:
        bv, s = qp._vars[blk.name], sol.blocks[blk.name]
        _, x_ref, u_ref = params[blk.name]
        dz, dv = s.z - x_ref, s.v - u_ref
        cost += np.sum(blk.q_diag * dz[:-1] ** 2) + np.sum(blk.r_diag * dv**2) + dz[-1] @ blk.terminal @ dz[-1]
        cost += 0.0 if bv.slack is None else blk.soft_penalty * np.sum(qp.compiled.value(bv.slack))
    assert sol.info.objective == pytest.approx(cost, rel=1e-7)


def test_standard_block_is_the_existing_linear_mpc(rng):
    """A standard block alone solves the same problem as oacli.control.mpc.LinearMPC ([Doerr2021] Eq. 26)."""
    a, b = double_integrator(0.2, 1 / MASS)
    q, r = np.array([10.0, 1.0]), np.array([1.0])
    p = solve_dare(a, b, np.diag(q), np.diag(r))
    mpc = LinearMPC(a, b, q, r, 8, np.array([0.1]), x_max=np.array([np.inf, 0.05]), terminal=p)
    qp = NominalQP([QPBlock("axis", a, b, q, r, p, state=LinearConstraint.box(np.array([np.inf, 0.05])),
                            input=LinearConstraint.box(np.array([0.1])))], 8)
    for _ in range(5):
        x0 = rng.normal(size=2) * [0.5, 0.04]
        ref = np.zeros((9, 2))
        qp.set_parameters("axis", x0, ref, np.zeros((8, 1)))
        ours, theirs = qp.solve(), mpc.solve(x0, ref, np.zeros((8, 1)))
        np.testing.assert_allclose(ours.blocks["axis"].v, theirs.u, atol=1e-7)


def test_compiled_qp_refuses_a_parameter_in_the_quadratic_term():
    """A parameter in the constraint matrix is supported (tests/test_controller_constraints.py); in P it is not."""
    x, p = cp.Variable(2), cp.Parameter(nonneg=True, value=1.0)
    problem = cp.Problem(cp.Minimize(p * cp.sum_squares(x)), [x >= 1])
    assert problem.is_dpp()
    with pytest.raises(ValueError, match="quadratic term"):
        CompiledQP(problem)


# -- W and the design --------------------------------------------------------------------------------------------


def test_mass_bound_is_doerr_eq_28_and_covers_every_mass_in_the_interval():
    m0, sigma, u_max, dt = 9.5, 0.1, 0.15, 0.2
    w = mass_uncertainty_bound(mass_model(m0, sigma), u_max, dt)

    def f(u, m):  # the exact one-step double integrator from rest
        return np.array([0.5 * dt * dt, dt]) * u / m

    heavy, light = f(u_max, m0 + 2 * sigma), f(u_max, m0 - 2 * sigma)
    np.testing.assert_allclose(w, np.abs(f(u_max, m0) - np.maximum(heavy, light)))
    # Closed form: u_max (1/(m0 − 2σ) − 1/m0) [dt²/2, dt].
    np.testing.assert_allclose(w, u_max * (1 / (m0 - 2 * sigma) - 1 / m0) * np.array([0.02, 0.2]), rtol=1e-12)
    for m in np.linspace(m0 - 2 * sigma, m0 + 2 * sigma, 21):
        for u in np.linspace(-u_max, u_max, 11):
            assert np.all(np.abs(f(u, m) - f(u, m0)) <= w * (1 + 1e-12))


def test_design_figures_of_the_reswarm_settings(design):
    summary = design.summary()
    for ax in design.axes:
        assert np.all(rpi_margins(ax.a_closed, ax.z, ax.disturbance.w) >= 0)  # the set in use is RPI
        assert ax.z.contains(ax.rpi.z, tol=1e-15)  # and contains F(α, s), so F_∞
        assert ax.reduction.facets_after < ax.reduction.facets_before
        # tightening by support functions: Ū = [−u_max + h(−K), u_max − h(K)]
        assert ax.force_bounds_N[1] == pytest.approx(0.15 - ax.z.support(ax.gain[0]), rel=1e-12)
        assert ax.velocity_bounds_mps[1] == pytest.approx(0.2 - ax.z.support(np.array([0.0, 1.0])), rel=1e-12)
    assert summary["rpi"]["s"] == [design.axes[0].rpi.s] * 3
    assert all(0 < a < 1 for a in summary["rpi"]["alpha"])


def test_too_large_w_stops_with_w_and_the_actuator_margin():
    with pytest.raises(InfeasibleError, match=r"(?s)W per 0.2 s control step.*actuator margin -"):
        reswarm_design(mass_std=0.1, force=0.2)


def test_explicit_scale_policy_shrinks_w_and_reports_it():
    design = reswarm_design(mass_std=0.1, force=0.2, on_empty="scale_w", min_nominal_fraction=0.2)
    for ax in design.axes:
        assert 0 < ax.disturbance.scale < 1
        assert ax.force_bounds_N[1] >= 0.2 * 0.15 and ax.velocity_bounds_mps[1] >= 0.2 * 0.2
        assert np.all(rpi_margins(ax.a_closed, ax.z, ax.disturbance.w) >= 0)
    assert design.summary()["w_scale"] == [ax.disturbance.scale for ax in design.axes]


# -- closed loop under disturbances from W -------------------------------------------------------------------------


def tube_regulator(a, b, q, r, w, x_constraint: Polytope, u_max, horizon, epsilon):
    """A generic tube MPC regulator (one tube block) and its design pieces."""
    k, _ = dlqr(a, b, np.diag(q), np.diag(r))
    z = minimal_rpi_outer(a + b @ k, w, epsilon).z
    x_bar = x_constraint.pontryagin_difference(z)
    u_bar = Polytope.symmetric_box([u_max]).pontryagin_difference(z.linear_map(k))
    qp = NominalQP([QPBlock("x", a, b, q, r, solve_dare(a, b, np.diag(q), np.diag(r)),
                            state=LinearConstraint(x_bar.a, x_bar.b), input=LinearConstraint(u_bar.a, u_bar.b),
                            lasso=LinearConstraint(z.a, z.b))], horizon)
    return qp, k, z


def run_regulator(qp, k, z, a, b, x0, disturbances, x_constraint, u_max):
    """Closed loop x⁺ = A x + B u + w; asserts the guarantees at every step; returns the final state.

    Both examples are double integrators ``[p, v]`` with constraints on v only, so the QP is posed relative to
    the current position (as :class:`TubeMPC` does) and the regulation target −p is passed as the reference.
    """
    n = qp.horizon
    x = np.asarray(x0, dtype=float)
    tol = 1e-7 * float(np.max(z.b))
    z_pred = None
    for w in disturbances:
        if z_pred is not None:
            assert z.contains_points(x - z_pred, tol=tol)  # in the promised tube ẑ ⊕ Z
        shift = np.array([x[0], 0.0])
        qp.set_parameters("x", x - shift, np.tile(-shift, (n + 1, 1)), np.zeros((n, b.shape[1])))
        sol = qp.solve()
        assert sol.info.success
        z0, v0 = sol.blocks["x"].z[0] + shift, sol.blocks["x"].v[0]
        assert z.contains_points(x - z0, tol=tol)  # lasso
        u = v0 + k @ (x - z0)
        assert np.all(np.abs(u) <= u_max * (1 + 1e-6))  # input limit (within the solver tolerance)
        assert x_constraint.contains_points(x, tol=1e-6)  # state limit
        z_pred = a @ z0 + b @ v0
        x = a @ x + b @ u + w
    return x, z0


def disturbance_sequences(w: Polytope, steps, seeds):
    """Random sequences drawn uniformly from W's bounding box and kept in W, and vertex sequences."""
    v = w.vertices
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        lo, hi = v.min(axis=0), v.max(axis=0)
        uniform = [p for p in rng.uniform(lo, hi, (10 * steps, v.shape[1])) if w.contains_points(p)][:steps]
        yield "random", np.array(uniform)
        yield "vertex", v[rng.integers(0, len(v), steps)]  # worst case: a vertex of W every step
        yield "constant vertex", np.tile(v[seed % len(v)], (steps, 1))


def test_mayne_seron_rakovic_2005_example_keeps_every_guarantee():
    """[Mayne2005] (Mayne, Seron & Raković 2005), Section 4 example: x⁺ = [[1, 1], [0, 1]] x + [0.5, 1]ᵀ u + w,
    X = {x : x₂ ≤ 2}, U = {|u| ≤ 1}, W = {‖w‖_∞ ≤ 0.1}, Q = I, R = 0.01, N = 9, from x₀ = (−5, −2) (their Fig. 2).
    K is the LQR gain of (Q, R) and there is no terminal constraint set here (terminal cost only): the paper's
    figure gives no number to compare with, so this checks the properties it illustrates."""
    a, b = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[0.5], [1.0]])
    w = Polytope.symmetric_box([0.1, 0.1])
    x_con = Polytope(np.array([[0.0, 1.0]]), [2.0])
    qp, k, z = tube_regulator(a, b, np.ones(2), np.array([0.01]), w, x_con, 1.0, 9, 1e-3)
    for _kind, seq in disturbance_sequences(w, 25, 8):
        _, z_final = run_regulator(qp, k, z, a, b, [-5.0, -2.0], seq, x_con, 1.0)
        # The nominal state reaches the origin, so (lasso) the state ends in the tube Z around it.
        np.testing.assert_allclose(z_final, 0.0, atol=1e-4)  # (interior-point accuracy)


def test_astrobee_axis_regulator_under_disturbances_from_w(design):
    """One translational axis with the ReSWARM tube, regulated from 0.3 m away at the velocity limit's edge."""
    ax = design.axes[0]
    x_con = Polytope(np.array([[0.0, 1.0], [0.0, -1.0]]), [0.2, 0.2])
    z = ax.z
    k = ax.gain
    a, b = ax.a, ax.b
    qp = NominalQP([QPBlock("x", a, b, np.array([50.0, 5.0]), np.array([0.1]), np.diag([100.0, 10.0]),
                            state=LinearConstraint(np.array([[0.0, 1.0], [0.0, -1.0]]),
                                                   [ax.velocity_bounds_mps[1], -ax.velocity_bounds_mps[0]]),
                            input=LinearConstraint.box(np.array([ax.force_bounds_N[1]])),
                            lasso=LinearConstraint(z.a, z.b))], 10)
    for _kind, seq in disturbance_sequences(ax.disturbance.w, 60, 6):
        run_regulator(qp, k, z, a, b, [0.3, -0.19], seq, x_con, 0.15)


@pytest.mark.parametrize(("truth_mass", "force_bias", "force_random", "seed"), [
    (9.3, 0.002, 0.0, 0),  # lightest mass in 2σ, constant worst-case force (a vertex of W)
    (9.7, -0.002, 0.0, 1),  # heaviest mass, opposite vertex
    (9.583788668, 0.0, 0.002, 2),  # measured ISS mass, random force within the bound
    (9.3, 0.0, 0.002, 3),
])
def test_tube_mpc_closed_loop_stays_in_the_tube_and_within_limits(design, truth_mass, force_bias, force_random,
                                                                   seed):
    """The full controller (attitude included) on the rigid-body plant: every disturbance is inside W, so the
    measured state stays in ẑ ⊕ Z at every step and no limit is violated."""
    ref = waypoint_reference(np.array([[10.8, -9.6, 4.8], [11.1, -9.4, 4.7]]),
                             np.array([[0.0, 0.0, -0.7071068, 0.7071068], [0.0, 0.0, 0.0, 1.0]]),
                             InertialParams(MASS, INERTIA), speed_mps=0.05, accel_mps2=0.01, rate_radps=0.05,
                             ang_accel_radps2=0.02, hold_s=1.0)
    ctrl = TubeMPC(ref, design, inertia_kgm2=INERTIA, horizon=5, prediction_step_s=1.0, weights=WEIGHTS,
                   limits=LIMITS, terminal=TERMINAL)
    x0 = ref.x[0].copy()
    x0[0:3] += [0.01, -0.005, 0.003]  # start off the reference
    bias = np.r_[np.full(3, force_bias), np.zeros(3)]
    tel = simulate(ctrl, x0, InertialParams(truth_mass, INERTIA), duration_s=ref.duration_s + 2.0,
                   control_period_s=DT, plant_period_s=1 / 62.5, input_limits=np.r_[LIMITS.force_N, LIMITS.torque_Nm],
                   sensors=SensorNoise(), disturbance=Disturbance(bias, np.r_[np.full(3, force_random), np.zeros(3)]),
                   rng=np.random.default_rng(seed))
    h = ctrl.history()
    tol = 1e-7 * np.max(design.lasso.h_vector)
    assert h.mode == ("mpc",) * len(h.t)
    assert np.all(h.tube_margin[1:] >= -tol) and np.isnan(h.tube_margin[0])
    assert np.all(h.lasso_margin >= 0.0)  # exactly: the QP lasso is backed off by half the invariance margin
    np.testing.assert_allclose(tel.u_command[:, 0:3], h.nominal_force + h.ancillary_force, atol=1e-15)
    assert np.all(np.abs(tel.u_command[:, 0:3]) <= U_TUBE * (1 + 1e-6))
    assert np.all(np.abs(tel.x_true[:, 3:6]) <= V_MAX)
    assert np.all(np.abs(tel.x_true[:, 10:13]) <= LIMITS.angular_velocity_radps)
    assert np.linalg.norm(tel.x_true[-1, 0:3] - ref.x[-1, 0:3]) < 0.01


# -- failures ----------------------------------------------------------------------------------------------------


def failing_controller(design, fail_steps, max_failures=3):
    ref = waypoint_reference(np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0]]), np.array([[0.0, 0.0, 0.0, 1.0]] * 2),
                             InertialParams(MASS, INERTIA), speed_mps=0.05, accel_mps2=0.01, rate_radps=0.05,
                             ang_accel_radps2=0.02, hold_s=1.0)
    ctrl = TubeMPC(ref, design, inertia_kgm2=INERTIA, horizon=5, prediction_step_s=1.0, weights=WEIGHTS,
                   limits=LIMITS, terminal=TERMINAL, max_consecutive_failures=max_failures)
    real_solve, calls = ctrl.qp.solve, {"n": 0}

    def solve(**kw):
        sol = real_solve(**kw)
        step, calls["n"] = calls["n"], calls["n"] + 1
        if step in fail_steps:  # the solver reports failure: the solution must not be used
            return type(sol)({k: type(v)(v.z * np.nan, v.v * np.nan, np.nan) for k, v in sol.blocks.items()},
                             type(sol.info)("infeasible", False))
        return sol

    ctrl.qp.solve = solve
    return ref, ctrl


def run(ctrl, ref, seconds, truth_mass=9.583788668, seed=0):
    return simulate(ctrl, ref.x[0], InertialParams(truth_mass, INERTIA), duration_s=seconds, control_period_s=DT,
                    plant_period_s=1 / 62.5, input_limits=np.r_[LIMITS.force_N, LIMITS.torque_Nm],
                    sensors=SensorNoise(), disturbance=Disturbance(np.zeros(6), np.r_[np.full(3, 0.002), np.zeros(3)]),
                    rng=np.random.default_rng(seed))


def test_failed_solves_follow_the_shifted_plan_with_the_ancillary_law(design):
    ref, ctrl = failing_controller(design, fail_steps={20, 21, 40})
    tel = run(ctrl, ref, 12.0)
    h = ctrl.history()
    assert [i for i, m in enumerate(h.mode) if m != "mpc"] == [20, 21, 40]
    assert h.solver_failed.sum() == 3
    # The fallback nominal state is the prediction ẑ = A z + B v of the previous step, its input the plan's.
    for i in (20, 21, 40):
        np.testing.assert_allclose(h.nominal_state[i], h.predicted_nominal[i], atol=1e-12)
        assert not tel.solve_info[i].success and tel.solve_info[i].status.startswith("fallback")
    # The plan of step 19 (1 s steps) gives the nominal force of steps 20 and 21 (0.2 s and 0.4 s into it).
    np.testing.assert_allclose(h.nominal_force[20], h.nominal_force[21], atol=1e-15)
    tol = 1e-7 * np.max(design.lasso.h_vector)
    assert np.all(h.tube_margin[1:] >= -tol) and np.all(h.lasso_margin >= -tol)
    np.testing.assert_allclose(tel.u_command[:, 0:3], h.nominal_force + h.ancillary_force, atol=1e-15)


def test_consecutive_failures_end_in_a_safe_hold(design):
    ref, ctrl = failing_controller(design, fail_steps=set(range(15, 10_000)), max_failures=3)
    tel = run(ctrl, ref, 30.0)
    h = ctrl.history()
    modes = list(h.mode)
    assert modes[:15] == ["mpc"] * 15 and modes[15:17] == ["fallback"] * 2 and set(modes[17:]) == {"hold"}
    assert h.solver_failed.sum() == 3  # no solve is attempted once in the hold
    # The hold's nominal brakes to rest without overshoot, within the tightened force, and the tube holds.
    speeds = np.abs(h.nominal_state[17:, 3:6])
    assert np.all(np.diff(speeds, axis=0) <= 1e-15)
    np.testing.assert_allclose(h.nominal_state[-1, 3:6], 0.0, atol=1e-12)
    assert np.all(np.abs(h.nominal_force) <= np.array([ax.force_bounds_N[1] for ax in design.axes]) + 1e-15)
    tol = 1e-7 * np.max(design.lasso.h_vector)
    assert np.all(h.tube_margin[1:] >= -tol)
    assert np.all(np.abs(tel.u_command[:, 0:3]) <= U_TUBE * (1 + 1e-6))
    assert np.linalg.norm(tel.x_true[-1, 3:6]) < 0.003  # the robot is at rest up to the ±0.002 N disturbance


def test_closed_loop_is_the_same_through_either_solve_path(design):
    """The controller with the direct Clarabel path and with problem.solve() flies the same trajectory."""
    runs = []
    for fast in (True, False):
        ref, ctrl = failing_controller(design, fail_steps=set())
        ctrl.fast = fast
        runs.append((run(ctrl, ref, 6.0), ctrl.history()))
    (tel_a, h_a), (tel_b, h_b) = runs
    np.testing.assert_allclose(tel_a.u_command, tel_b.u_command, atol=1e-8)
    np.testing.assert_allclose(h_a.nominal_state, h_b.nominal_state, atol=1e-8)
    np.testing.assert_allclose(tel_a.x_true, tel_b.x_true, atol=1e-9)


def test_bounded_measurement_noise_is_covered_by_w_and_the_state_tightening():
    """With measurement noise |n| ≤ N, W gains N ⊕ (−A N) and X̄ = X ⊖ (Z ⊕ N): the measured error stays in the
    promised tube and the TRUE velocity within its limit, the input within U, for random and vertex noise."""
    from oacli.control.tube_design import design_axis

    noise = np.array([0.002, 0.0005])  # [m, m/s]
    spec = DisturbanceSpec(force_N=np.full(3, 0.002), noise_position_m=np.full(3, noise[0]),
                           noise_velocity_mps=np.full(3, noise[1]))
    common = {"model": mass_model(MASS, 0.1), "dt_s": DT, "force_limit_N": 0.15, "velocity_limit_mps": 0.2,
              "weights": AncillaryWeights(5.0, 10.0, 2.0), "epsilon": 0.005}
    ax = design_axis(0, spec=spec, **common)
    assert ax.feasible
    clean = design_axis(0, spec=DisturbanceSpec(force_N=np.full(3, 0.002)), **common)
    assert ax.velocity_bounds_mps[1] < clean.velocity_bounds_mps[1] - noise[1]  # noise tightens X beyond Z alone
    z, k, a, b = ax.z, ax.gain, ax.a, ax.b
    qp = NominalQP([QPBlock("x", a, b, np.array([50.0, 5.0]), np.array([0.1]), np.diag([100.0, 10.0]),
                            state=LinearConstraint(np.array([[0.0, 1.0], [0.0, -1.0]]),
                                                   [ax.velocity_bounds_mps[1], -ax.velocity_bounds_mps[0]]),
                            input=LinearConstraint.box(np.array([ax.force_bounds_N[1]])),
                            lasso=LinearConstraint(z.a, z.b))], 10)
    w_process = Polytope.symmetric_box(ax.disturbance.mass_term + ax.disturbance.force_term)
    tol = 1e-7 * float(np.max(z.b))
    for seed in range(6):
        rng = np.random.default_rng(seed)
        x, z_pred = np.array([0.4, -0.18]), None
        for step in range(50):
            n = noise * (rng.choice([-1.0, 1.0], 2) if seed % 2 else rng.uniform(-1, 1, 2))  # vertex or random
            x_meas = x + n
            if z_pred is not None:
                assert z.contains_points(x_meas - z_pred, tol=tol)
            shift = np.array([x_meas[0], 0.0])
            qp.set_parameters("x", x_meas - shift, np.tile(-shift, (11, 1)), np.zeros((10, 1)))
            sol = qp.solve()
            assert sol.info.success, step
            z0, v0 = sol.blocks["x"].z[0] + shift, sol.blocks["x"].v[0]
            u = v0 + k @ (x_meas - z0)
            assert abs(u[0]) <= 0.15 * (1 + 1e-6) and abs(x[1]) <= 0.2 * (1 + 1e-6)
            z_pred = a @ z0 + b @ v0
            w = w_process.vertices[rng.integers(0, 4)] if seed % 2 else rng.uniform(-1, 1, 2) * w_process.b[:2]
            x = a @ x + b @ u + w
