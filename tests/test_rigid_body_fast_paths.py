"""The unrolled copies of [Doerr2021] Eqs. 35-36 that have no pinning test of their own, pinned to the reference
:func:`oacli.model.rigid_body.dynamics` (Eq. 35), :func:`oacli.model.rigid_body.dynamics_jacobians` and
:func:`oacli.model.quaternion.xi_matrix` (Eq. 36) on random states, torques and inertias (docs/equations.md names
each fast path and its test; the others: tests/test_simulator.py, tests/test_batch_fast_path.py,
tests/test_batch_estimation.py, tests/test_sequential_estimation.py, tests/test_excitation_fast.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from oacli.estimation.manifold import xi_stack
from oacli.estimation.rotation_features import rate_map_blocks, rotation_rates, rotational_rate
from oacli.excitation.split_information import _gyro, _wdot, _xi
from oacli.model import rigid_body as rb
from oacli.model.quaternion import xi_matrix


def _samples(seed: int, k: int = 40):
    rng = np.random.default_rng(seed)
    x = np.zeros((k, 13))
    q = rng.normal(size=(k, 4))
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x[:, 10:13] = rng.normal(scale=0.3, size=(k, 3))
    u = rng.normal(scale=0.05, size=(k, 6))
    inertia = rng.uniform(0.1, 0.5, size=3)
    inertia[2] = min(inertia[2], inertia[0] + inertia[1])  # a physical body (triangle inequality)
    theta = np.array([9.5, *inertia])
    return x, u, theta


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotation_feature_rates_and_jacobians_equal_the_reference(seed):
    x, u, theta = _samples(seed)
    z = x[:, 6:13]
    want = np.array([rb.dynamics(x[k], u[k], theta)[6:13] for k in range(len(x))])
    np.testing.assert_allclose(rotation_rates(z, u[:, 3:6], theta[1:4]), want, rtol=1e-13, atol=1e-15)
    rates, jac = rotational_rate(z, u[:, 3:6], theta[1:4], rate_map_blocks(tuple(theta[1:4])))
    np.testing.assert_allclose(rates, want, rtol=1e-13, atol=1e-15)
    for k in range(len(x)):
        fx, _, ft = rb.dynamics_jacobians(x[k], u[k], theta)
        np.testing.assert_allclose(jac[k, :, :7], fx[6:13, 6:13], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(jac[k, :, 7:10], ft[6:13, 1:4], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("seed", [0, 1])
def test_split_information_euler_and_xi_equal_the_reference(seed):
    x, u, theta = _samples(seed)
    xr = x[:, 6:13]
    want = np.array([rb.dynamics(x[k], u[k], theta)[10:13] for k in range(len(x))])
    np.testing.assert_allclose(_wdot(xr, u[:, 3:6], theta[1:4]), want, rtol=1e-14, atol=1e-16)
    xi_ref = np.array([xi_matrix(q) for q in x[:, 6:10]])
    np.testing.assert_array_equal(_xi(x[:, 6:10]), xi_ref)
    np.testing.assert_array_equal(xi_stack(x[:, 6:10]), xi_ref)
    for k in range(len(x)):
        fx, _, _ = rb.dynamics_jacobians(x[k], u[k], theta)
        np.testing.assert_allclose(_gyro(x[k, 10:13], theta[1:4]), fx[10:13, 10:13], rtol=1e-13, atol=1e-16)


@pytest.mark.parametrize("columns", [[0, 1, 2, 3, 7, 8, 9, 10, 11, 12], [0, 1, 2, 3], [1, 2, 3, 4, 5, 6, 13, 14, 15],
                                     [7, 8, 9]])
def test_full_propagation_on_the_estimated_columns_equals_all_columns(columns):
    """``propagate_full(columns=…)`` (what the batch's full model carries: the estimated entries only) gives the
    same end states and ``∂x⁺/∂x``, the same ``∂x⁺/∂θ`` on those columns and zero on the others; the all-column
    result is itself pinned to finite differences in tests/test_rigid_body_estimation.py."""
    from oacli.estimation.propagation import substep_schedule
    from oacli.estimation.rigid_dynamics import propagate_full, propagate_full_one

    x, u, _ = _samples(3, k=25)
    theta = np.array([15.5, 0.15, 0.14, 0.16, 0.004, -0.003, 0.002, 0.01, -0.02, 0.015,
                      1.02, 0.97, 1.01, 0.98, 1.03, 0.99])
    t = np.arange(26) * 0.2
    durations = substep_schedule(t[:-1], t[1:], 0.016)
    cols = np.array(columns)
    x_all, a_all, c_all = propagate_full(x, u, theta, durations)
    x_sub, a_sub, c_sub = propagate_full(x, u, theta, durations, columns=cols)
    assert np.array_equal(x_sub, x_all) and np.array_equal(a_sub, a_all)
    np.testing.assert_allclose(c_sub[:, :, cols], c_all[:, :, cols], rtol=1e-12, atol=1e-15)
    assert not np.any(np.delete(c_sub, cols, axis=2))
    one = propagate_full_one(x[4], u[4], theta, durations[4], jacobians=False)   # the warm start's float path
    np.testing.assert_allclose(one[0], x_all[4], rtol=1e-12, atol=1e-14)
    assert one[1] is None and one[2] is None


@pytest.mark.parametrize("products", [(0.0, 0.0, 0.0), (0.012, -0.008, 0.005)])
def test_full_model_propagation_carries_every_column_its_jacobian_reaches(products):
    """The batch's full model carries only the θ columns dθ/dφ can reach (:attr:`FullModel.differentiated`), so
    ``c @ dθ/dφ`` equals the all-column product, also with held products of inertia away from 0 (the log-Cholesky
    map then couples them with the estimated diagonal)."""
    from oacli.estimation.batch_model import FullModel
    from oacli.estimation.propagation import substep_schedule
    from oacli.estimation.rigid_dynamics import propagate_full
    from oacli.estimation.rigid_parameters import ParameterSet

    x, u, _ = _samples(5, k=15)
    theta = np.array([15.5, 0.15, 0.14, 0.16, *products, 0.01, -0.02, 0.015, 1.02, 0.97, 1.01, 0.98, 1.03, 0.99])
    model = FullModel(ParameterSet.build(("mass", "inertia", "com", "force_scale"), theta), theta,
                      np.diag(np.full(16, 1e-2)))
    assert set(model.params.index.tolist()) < set(model.differentiated.tolist())
    phi = model.phi(theta)
    jac = model.jacobian(phi)
    t = np.arange(16) * 0.2
    durations = substep_schedule(t[:-1], t[1:], 0.016)
    _, _, c_model = model.propagate(x, u, theta, durations)
    _, _, c_all = propagate_full(x, u, theta, durations)
    np.testing.assert_allclose(c_model @ jac, c_all @ jac, rtol=1e-10, atol=1e-13)
