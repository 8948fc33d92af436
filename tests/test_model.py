"""Free-flyer model: quaternions, dynamics, exact discretisation and Jacobians ([Doerr2021] Eqs. 2, 33-36)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from scipy.spatial.transform import Rotation

from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb
from oacli.model.double_integrator import double_integrator, hover_error_model, translational_model
from oacli.types import InertialParams
from tests.conftest import random_state
from tests.model_helpers import mass_model

THETA = np.array([9.0877, 0.1454, 0.1366, 0.1594])  # [Doerr2021] Table 1, Astrobee


def central_difference(fun, x0: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for e in np.eye(x0.size):
        cols.append((fun(x0 + eps * e) - fun(x0 - eps * e)) / (2 * eps))
    return np.column_stack(cols)


class TestQuaternion:
    def test_product_and_matrix_match_scipy(self, rng):
        for _ in range(20):
            p, q = quat.normalize(rng.standard_normal(4)), quat.normalize(rng.standard_normal(4))
            expected = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_matrix()
            np.testing.assert_allclose(quat.to_rotation_matrix(quat.multiply(p, q)), expected, atol=1e-12)
            np.testing.assert_allclose(quat.to_rotation_matrix(p), Rotation.from_quat(p).as_matrix(), atol=1e-12)
            raw = 3.0 * rng.standard_normal(4)   # unnormalised, either sign of w: the per-step float form
            np.testing.assert_allclose(np.reshape(quat.rotation_floats(*raw), (3, 3)),
                                       Rotation.from_quat(raw).as_matrix(), atol=1e-12)

    def test_exp_log_and_matrix_round_trip(self, rng):
        for _ in range(20):
            phi = rng.uniform(-1, 1, 3) * rng.uniform(0, np.pi) / np.sqrt(3)
            q = quat.exp(phi)
            np.testing.assert_allclose(quat.log(q), phi, atol=1e-12)
            np.testing.assert_allclose(q, Rotation.from_rotvec(phi).as_quat(canonical=True), atol=1e-12)
            back = quat.from_rotation_matrix(quat.to_rotation_matrix(q))
            np.testing.assert_allclose(back, quat.normalize(q), atol=1e-12)
        np.testing.assert_allclose(quat.log(quat.exp(np.array([1e-9, 0, 0]))), [1e-9, 0, 0], rtol=1e-9)

    def test_slerp_halves_the_angle(self, rng):
        q0, q1 = quat.normalize(rng.standard_normal(4)), quat.normalize(rng.standard_normal(4))
        mid = quat.slerp(q0, q1, 0.5)
        total = quat.angle_between(q0, q1)
        assert quat.angle_between(q0, mid) == pytest.approx(total / 2, abs=1e-12)
        np.testing.assert_allclose(quat.normalize(quat.slerp(q0, q1, 1.0)), quat.normalize(q1), atol=1e-12)

    def test_xi_matches_hamilton_body_rate(self, rng):
        q = quat.normalize(rng.standard_normal(4))
        w = rng.standard_normal(3)
        np.testing.assert_allclose(quat.xi_matrix(q) @ w, quat.multiply(q, np.r_[w, 0.0]), atol=1e-14)
        np.testing.assert_allclose(quat.omega_matrix(w) @ q, quat.xi_matrix(q) @ w, atol=1e-14)


class TestDynamics:
    def test_continuous_jacobians_match_finite_differences(self, rng):
        for _ in range(5):
            x, u = random_state(rng), rng.uniform(-0.5, 0.5, 6)
            fx, fu, ft = rb.dynamics_jacobians(x, u, THETA)
            np.testing.assert_allclose(fx, central_difference(lambda z: rb.dynamics(z, u, THETA), x), atol=1e-8)
            np.testing.assert_allclose(fu, central_difference(lambda z: rb.dynamics(x, z, THETA), u), atol=1e-8)
            np.testing.assert_allclose(ft, central_difference(lambda z: rb.dynamics(x, u, z), THETA), atol=1e-7)

    @pytest.mark.parametrize("dt", [0.016, 0.2, 1.0])
    def test_discrete_jacobians_match_finite_differences(self, rng, dt):
        for _ in range(3):
            x, u = random_state(rng), rng.uniform(-0.5, 0.5, 6)
            x_next, a, b, c = rb.rk4_step_jacobians(x, u, THETA, dt)
            np.testing.assert_array_equal(x_next, rb.rk4_step(x, u, THETA, dt))
            np.testing.assert_allclose(a, central_difference(lambda z: rb.rk4_step(z, u, THETA, dt), x), atol=1e-7)
            np.testing.assert_allclose(b, central_difference(lambda z: rb.rk4_step(x, z, THETA, dt), u), atol=1e-7)
            np.testing.assert_allclose(c, central_difference(lambda z: rb.rk4_step(x, u, z, dt), THETA), atol=1e-7)

    def test_torque_free_rotation_conserves_momentum_and_energy(self):
        # Asymmetric body spinning about all three axes: ω precesses, but R I ω and ½ωᵀIω are invariant.
        x = np.zeros(13)
        x[6:10] = quat.normalize(np.array([0.1, -0.3, 0.2, 0.9]))
        x[10:13] = [0.3, -0.5, 0.4]
        h0 = rb.angular_momentum_world(x, THETA)
        e0 = rb.rotational_energy(x, THETA)
        w0 = x[10:13].copy()
        for _ in range(int(60 / 0.016)):
            x = rb.propagate(x, np.zeros(6), THETA, 0.016)
        np.testing.assert_allclose(rb.angular_momentum_world(x, THETA), h0, rtol=1e-7, atol=1e-10)
        assert rb.rotational_energy(x, THETA) == pytest.approx(e0, rel=1e-7)
        assert np.linalg.norm(x[10:13] - w0) > 0.05  # the body rates did change (not a trivial spin)

    def test_rk4_is_exact_for_translation(self):
        # Constant force: position is quadratic in time, which RK4 integrates exactly.
        x = np.zeros(13)
        x[9] = 1.0
        x[3:6] = [0.1, -0.2, 0.05]
        f = np.array([0.3, -0.1, 0.2])
        dt = 0.7
        x1 = rb.rk4_step(x, np.r_[f, 0, 0, 0], THETA, dt)
        np.testing.assert_allclose(x1[0:3], x[3:6] * dt + 0.5 * f / THETA[0] * dt**2, atol=1e-15)
        np.testing.assert_allclose(x1[3:6], x[3:6] + f / THETA[0] * dt, atol=1e-15)


class TestDiscreteModels:
    def test_double_integrator_matches_zoh_discretisation(self):
        dt, m = 0.2, 9.6
        a_c = np.array([[0.0, 1.0], [0.0, 0.0]])
        b_c = np.array([[0.0], [1.0 / m]])
        a_d, b_d, *_ = scipy.signal.cont2discrete((a_c, b_c, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
        a, b = double_integrator(dt, 1.0 / m)
        np.testing.assert_allclose(a, a_d, atol=1e-15)
        np.testing.assert_allclose(b, b_d, atol=1e-15)
        a6, b6 = translational_model(mass_model(m), dt)
        big = scipy.linalg.expm(np.block([[np.kron(a_c, np.eye(3)), np.kron(b_c, np.eye(3))], [np.zeros((3, 9))]]) * dt)
        np.testing.assert_allclose(a6, big[:6, :6], atol=1e-14)
        np.testing.assert_allclose(b6, big[:6, 6:], atol=1e-14)

    def test_hover_error_model_is_the_rk4_linearisation_at_rest(self):
        params = InertialParams(9.0877, [0.1454, 0.1366, 0.1594])
        dt = 0.2
        x_bar = np.zeros(13)
        x_bar[9] = 1.0
        a13, b13, g = rb.linearize_discrete(x_bar, np.zeros(6), params, dt)
        np.testing.assert_allclose(g, 0.0, atol=1e-15)
        a12, b12 = hover_error_model(params, dt)
        # Chart: δq_vec = φ/2 at the identity, so φ rows are 2 × the quaternion-vector rows.
        keep = [0, 1, 2, 3, 4, 5, 6, 7, 8, 10, 11, 12]
        scale = np.ones(12)
        scale[6:9] = 2.0
        a_chart = scale[:, None] * a13[np.ix_(keep, keep)] / scale[None, :]
        b_chart = scale[:, None] * b13[keep]
        np.testing.assert_allclose(a_chart, a12, atol=1e-14)
        np.testing.assert_allclose(b_chart, b12, atol=1e-14)
