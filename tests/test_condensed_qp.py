"""The condensed QP solved by DAQP (the benchmarks' lower limit) is the controllers' problem: the
same first input as the compiled Clarabel path on one tube MPC instance and one tracking MPC instance with a
keep-out half-space (a Parameter in the constraint matrix)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("daqp", reason="daqp is not installed (pip install daqp, the bench extra)")

from test_tube_mpc import LIMITS, WEIGHTS, random_parameters, reswarm_design, two_block_qp

from oacli.control.condensed_qp import CondensedQP
from oacli.control.mpc import LinearMPC
from oacli.control.workspace import PositionRows
from oacli.model.double_integrator import hover_error_model
from oacli.types import InertialParams


def test_condensed_tube_qp_gives_the_controllers_first_input(rng):
    qp = two_block_qp(5, reswarm_design())
    random_parameters(qp, rng)
    sol = qp.solve()
    assert sol.info.success
    limit = CondensedQP(qp.compiled)
    assert limit.n_unknowns < qp.compiled.n_variables  # the dynamics are eliminated
    ok, iterations, _ = limit.solve(qp._values)
    assert ok and iterations > 0
    for name in ("translation", "attitude"):
        v = qp._vars[name].v
        # Clarabel stops at its 1e-8 gap/residual tolerances; the first input agrees far inside the tube's margins.
        np.testing.assert_allclose(limit.value(v)[0], sol.blocks[name].v[0], atol=1e-6)
        z = qp._vars[name].z
        np.testing.assert_allclose(limit.value(z)[0], sol.blocks[name].z[0], atol=1e-5)


def test_condensed_tracking_qp_with_a_keep_out_row_gives_the_same_first_input(rng):
    n_steps = 10
    a, b = hover_error_model(InertialParams(9.5, np.array([0.153, 0.143, 0.162])), 0.2)
    mpc = LinearMPC(a, b, WEIGHTS.q_diag, WEIGHTS.r_diag, n_steps, LIMITS.input, x_max=LIMITS.error_state,
                    keep_in=True, keep_out_zones=1)
    x0 = np.r_[0.05, 0.0, 0.0, 0.01, 0.0, 0.0, 0.02, 0.0, -0.01, 0.0, 0.0, 0.0]
    x_ref = np.zeros((n_steps + 1, 12))
    x_ref[:, 0] = np.linspace(0.0, 0.3, n_steps + 1)
    x_ref[:, 1] = -0.05  # the reference runs below the half-space y >= -0.01: the row is active
    normal = np.tile([0.0, 1.0, 0.0], (n_steps, 1))
    offsets = np.full((1, n_steps), -0.01)
    rows = PositionRows(np.full((n_steps, 3), -1.0), np.full((n_steps, 3), 1.0), normal[None], offsets)
    sol = mpc.solve(x0, x_ref, np.zeros((n_steps, 6)), rows)
    assert sol.info.success and sol.position_slack_m < 1e-9
    assert mpc.compiled._t_a is not None  # the normal is a Parameter in A
    limit = CondensedQP(mpc.compiled)
    ok, _, _ = limit.solve(mpc.last_values)
    assert ok
    np.testing.assert_allclose(limit.value(mpc._u)[0], sol.u[0], atol=1e-6)
    assert sol.x[-1, 1] == pytest.approx(-0.01, abs=1e-6)  # active
    assert limit.value(mpc._z_n)[1] >= -0.01 - 1e-7  # the keep-out row holds in the condensed solution


def _previous_condensed_data(limit: CondensedQP, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f and the upper bounds as the condensing computed them before it was formed once (per-solve products)."""
    comp = limit.compiled
    b = comp._t_b @ theta
    x_p = np.linalg.pinv(comp._a.toarray()[: limit.n_eq]) @ b[: limit.n_eq]
    p = comp._p.toarray()
    p = np.triu(p) + np.triu(p, 1).T
    return (p @ limit._z).T @ x_p + limit._z.T @ (comp._t_q @ theta), b[limit.n_eq :] - limit._a_in @ x_p


def test_hot_started_cached_daqp_is_the_per_call_solution(rng):
    """The limit's fastest honest set-up (condensing formed once, DAQP's Model set up once, hot start from the
    previous working set) solves the same QPs as daqp.solve per call from the empty working set: the same optimum
    over a sequence of nearby instances (as a controller's steps), with far fewer iterations."""
    import daqp

    qp = two_block_qp(5, reswarm_design())
    hot, cold = CondensedQP(qp.compiled), CondensedQP(qp.compiled, warm_start=False)
    base = random_parameters(qp, rng, scale=0.5)
    iterations = {"hot": [], "cold": [], "per_call": []}
    for k in range(12):
        for name, (x, ref, u_ref) in base.items():  # a slowly moving instance
            qp.set_parameters(name, x * (1 + 0.02 * k), ref + 0.001 * k, u_ref)
        theta = qp.compiled.parameter_vector(qp._values)
        f, upper, _ = hot._data(theta)
        f_prev, upper_prev = _previous_condensed_data(hot, theta)
        np.testing.assert_allclose(f, f_prev, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(upper, upper_prev, rtol=1e-9, atol=1e-12)
        y, _, flag, info = daqp.solve(hot._h, f, hot._a_in_z, upper, hot._lower, hot._sense)
        assert flag == 1
        iterations["per_call"].append(info["iterations"])
        for key, limit in (("hot", hot), ("cold", cold)):
            ok, it, _ = limit.solve(qp._values)
            assert ok
            iterations[key].append(it)
            np.testing.assert_allclose(limit._y, y, atol=1e-9)
    # From the empty working set the cached model takes the per-call path (up to rounding in its factors).
    assert np.median(iterations["cold"]) == pytest.approx(np.median(iterations["per_call"]), rel=0.1)
    assert sum(iterations["hot"][1:]) < sum(iterations["cold"][1:]) / 3
