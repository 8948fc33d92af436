"""LQR: DARE by doubling against scipy, and the affine time-varying Riccati recursion ([Doerr2021] Eqs. 8-9)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from oacli.control.lqr import dlqr, solve_dare, tv_riccati
from oacli.errors import InfeasibleError
from oacli.model.double_integrator import hover_error_model
from oacli.types import InertialParams

PARAMS = InertialParams(9.583788668, [0.153427995, 0.14271405, 0.162302759])  # Astrobee on ISS, [AstrobeeFSW]


def random_system(rng, n=4, m=2):
    a = rng.standard_normal((n, n)) * 0.6
    b = rng.standard_normal((n, m))
    l_q = rng.standard_normal((n, n))
    q = l_q @ l_q.T + 0.1 * np.eye(n)
    l_r = rng.standard_normal((m, m))
    r = l_r @ l_r.T + 0.5 * np.eye(m)
    return a, b, q, r


def test_dare_matches_scipy_on_the_free_flyer():
    a, b = hover_error_model(PARAMS, 0.2)
    q = np.diag([10.0] * 3 + [1.0] * 3 + [10.0] * 3 + [1.0] * 3)
    r = np.diag([1.0] * 3 + [100.0] * 3)
    p = solve_dare(a, b, q, r)
    expected = scipy.linalg.solve_discrete_are(a, b, q, r)
    np.testing.assert_allclose(p, expected, rtol=1e-9, atol=1e-9)
    k, _p2 = dlqr(a, b, q, r)
    np.testing.assert_allclose(k, -np.linalg.solve(r + b.T @ expected @ b, b.T @ expected @ a), rtol=1e-8, atol=1e-10)
    assert np.max(np.abs(np.linalg.eigvals(a + b @ k))) < 1.0


@pytest.mark.parametrize("seed", range(8))
def test_dare_matches_scipy_on_random_systems_with_cross_terms(seed):
    rng = np.random.default_rng(seed)
    a, b, q, r = random_system(rng)
    s = 0.05 * rng.standard_normal((4, 2))
    np.testing.assert_allclose(solve_dare(a, b, q, r), scipy.linalg.solve_discrete_are(a, b, q, r), rtol=1e-8)
    np.testing.assert_allclose(
        solve_dare(a, b, q, r, s), scipy.linalg.solve_discrete_are(a, b, q, r, s=s), rtol=1e-8, atol=1e-9
    )


def test_unstabilisable_system_is_refused():
    a = np.diag([1.2, 0.5])
    b = np.array([[0.0], [1.0]])  # the unstable mode is not actuated
    with pytest.raises(InfeasibleError):
        dlqr(a, b, np.eye(2), np.eye(1))


def test_long_horizon_riccati_converges_to_the_dare():
    a, b = hover_error_model(PARAMS, 0.2)
    q = np.diag([10.0] * 3 + [1.0] * 3 + [10.0] * 3 + [1.0] * 3)
    r = np.diag([1.0] * 3 + [100.0] * 3)
    n_steps = 400
    sol = tv_riccati(np.repeat(a[None], n_steps, 0), np.repeat(b[None], n_steps, 0),
                     np.repeat(q[None], n_steps, 0), np.repeat(r[None], n_steps, 0), q)
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    np.testing.assert_allclose(sol.S[0], p, rtol=1e-8, atol=1e-9)
    k, _ = dlqr(a, b, q, r)
    np.testing.assert_allclose(sol.K[0], k, rtol=1e-7, atol=1e-10)


@pytest.mark.parametrize("seed", range(5))
def test_affine_riccati_equals_the_direct_qp_solution(seed):
    """Eqs. 8-9 with drift g_k, cross P_k and linear q_k, r_k against the KKT solution of the stacked QP."""
    rng = np.random.default_rng(100 + seed)
    n, m, n_steps = 3, 2, 6
    a = rng.standard_normal((n_steps, n, n)) * 0.7
    b = rng.standard_normal((n_steps, n, m))
    g = rng.standard_normal((n_steps, n)) * 0.3
    q = np.empty((n_steps, n, n))
    r = np.empty((n_steps, m, m))
    p = np.empty((n_steps, n, m))
    for i in range(n_steps):
        l_blk = rng.standard_normal((n + m, n + m))
        blk = l_blk @ l_blk.T + 0.2 * np.eye(n + m)  # [[Q, P], [Pᵀ, R]] positive definite
        q[i], p[i], r[i] = blk[:n, :n], blk[:n, n:], blk[n:, n:]
    q_lin = rng.standard_normal((n_steps, n))
    r_lin = rng.standard_normal((n_steps, m))
    l_f = rng.standard_normal((n, n))
    q_final = l_f @ l_f.T + np.eye(n)
    q_final_lin = rng.standard_normal(n)
    c_final = 0.7
    x0 = rng.standard_normal(n)
    sol = tv_riccati(a, b, q, r, q_final, g=g, p=p, q_lin=q_lin, r_lin=r_lin, q_final_lin=q_final_lin,
                     c_final=c_final)

    # Direct solution: variables z = [x_1..x_N, u_0..u_{N-1}], x_0 fixed; equality-constrained QP via KKT.
    nx, nu = n * n_steps, m * n_steps
    h = np.zeros((nx + nu, nx + nu))
    f = np.zeros(nx + nu)
    const = 0.0

    def xi(k):  # index of x_k in z (k >= 1)
        return slice((k - 1) * n, k * n)

    def ui(k):
        return slice(nx + k * m, nx + (k + 1) * m)

    for k in range(n_steps):
        h[ui(k), ui(k)] += r[k]
        f[ui(k)] += r_lin[k]
        if k == 0:
            const += 0.5 * x0 @ q[0] @ x0 + q_lin[0] @ x0
            f[ui(0)] += p[0].T @ x0
        else:
            h[xi(k), xi(k)] += q[k]
            f[xi(k)] += q_lin[k]
            h[xi(k), ui(k)] += p[k]
            h[ui(k), xi(k)] += p[k].T
    h[xi(n_steps), xi(n_steps)] += q_final
    f[xi(n_steps)] += q_final_lin
    const += c_final
    e = np.zeros((nx, nx + nu))
    d = np.zeros(nx)
    for k in range(n_steps):
        e[xi(k + 1), xi(k + 1)] = np.eye(n)
        e[xi(k + 1), ui(k)] = -b[k]
        if k == 0:
            d[xi(1)] = a[0] @ x0 + g[0]
        else:
            e[xi(k + 1), xi(k)] = -a[k]
            d[xi(k + 1)] = g[k]
    kkt = np.block([[h, e.T], [e, np.zeros((nx, nx))]])
    z = np.linalg.solve(kkt, np.r_[-f, d])[: nx + nu]
    cost = 0.5 * z @ h @ z + f @ z + const

    xs, us = sol.rollout(a, b, g, x0)
    np.testing.assert_allclose(us.ravel(), z[nx:], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(xs[1:].ravel(), z[:nx], rtol=1e-8, atol=1e-10)
    assert sol.value(0, x0) == pytest.approx(cost, rel=1e-9, abs=1e-10)
