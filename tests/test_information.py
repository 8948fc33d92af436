"""Parameter sensitivities and Fisher information ([Doerr2021] Eqs. 29-30) against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.excitation.information import (
    MeasurementModel,
    a_optimality,
    cramer_rao_std,
    fisher_information,
    information_per_step,
    propagate_with_sensitivities,
    unidentifiable_parameters,
)
from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb

THETA = np.array([15.0, 0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1, Astrobee with object
FULL = MeasurementModel(0.01, 0.002, 0.005, 0.001, 0.003, 0.01)


def excitation(rng, n=40):
    u = np.zeros((n, 6))
    u[:, 0:3] = rng.uniform(-0.2, 0.2, (n, 3))
    u[:, 3:6] = rng.uniform(-0.02, 0.02, (n, 3))
    x0 = np.zeros(13)
    x0[6:10] = quat.normalize(rng.standard_normal(4))
    x0[10:13] = rng.uniform(-0.05, 0.05, 3)
    return x0, u


def measurements(x0, u, theta, dt, q_nominal):
    """Noise-free measurement vector as a function of θ (attitude as error about the nominal attitude)."""
    x = [x0]
    for k in range(u.shape[0]):
        x.append(rb.propagate(x[-1], u[k], theta, dt))
    x = np.array(x)
    y = []
    for k in range(1, u.shape[0] + 1):
        y.append(np.r_[x[k, 0:6], quat.error_vector(q_nominal[k], x[k, 6:10]), x[k, 10:13]])
    acc = [rb.dynamics(x[k], u[k], theta)[np.r_[3:6, 10:13]] for k in range(u.shape[0])]
    return np.concatenate(y), np.concatenate(acc)


def test_sensitivities_match_finite_differences(rng):
    x0, u = excitation(rng)
    dt = 0.3
    _x, s = propagate_with_sensitivities(x0, u, THETA, dt)
    eps = 1e-6 * THETA
    for i in range(4):
        xp, _ = propagate_with_sensitivities(x0, u, THETA + eps[i] * np.eye(4)[i], dt)
        xm, _ = propagate_with_sensitivities(x0, u, THETA - eps[i] * np.eye(4)[i], dt)
        fd = (xp - xm) / (2 * eps[i])
        np.testing.assert_allclose(s[:, :, i], fd, rtol=1e-5, atol=1e-7 * np.abs(fd).max())


def test_fisher_information_matches_finite_differences(rng):
    x0, u = excitation(rng)
    dt = 0.3
    x, _ = propagate_with_sensitivities(x0, u, THETA, dt)
    fim = fisher_information(x0, u, THETA, dt, FULL)
    cols_y, cols_a = [], []
    for i in range(4):
        step = 1e-6 * THETA[i] * np.eye(4)[i]
        yp, ap = measurements(x0, u, THETA + step, dt, x[:, 6:10])
        ym, am = measurements(x0, u, THETA - step, dt, x[:, 6:10])
        cols_y.append((yp - ym) / (2 * step[i]))
        cols_a.append((ap - am) / (2 * step[i]))
    jy, ja = np.column_stack(cols_y), np.column_stack(cols_a)
    n = u.shape[0]
    w_y = np.tile(np.r_[[0.01**-2] * 3, [0.002**-2] * 3, [0.005**-2] * 3, [0.001**-2] * 3], n)
    w_a = np.tile(np.r_[[0.003**-2] * 3, [0.01**-2] * 3], n)
    expected = jy.T @ (w_y[:, None] * jy) + ja.T @ (w_a[:, None] * ja)
    np.testing.assert_allclose(fim, expected, rtol=2e-5)
    np.testing.assert_allclose(information_per_step(x0, u, THETA, 0.3, FULL).sum(0), fim, rtol=1e-12)


def test_no_torque_means_no_inertia_information(rng):
    """Like the flown excitation files 9 and 10 (SOURCE.md): force only, so the inertias are unidentifiable."""
    x0, u = excitation(rng)
    x0[10:13] = 0.0
    u[:, 3:6] = 0.0
    fim = fisher_information(x0, u, THETA, 0.3, FULL)
    assert unidentifiable_parameters(fim, THETA) == ["Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2"]
    crb = cramer_rao_std(fim, THETA)
    assert np.isfinite(crb[0]) and np.all(np.isinf(crb[1:]))
    assert a_optimality(fim) == np.inf


def test_mass_bound_closed_form_for_a_velocity_measured_push():
    """Constant force f along x for N steps, velocity measured with std σ: ∂v_k/∂m = −f k dt / m², so
    F_mm = Σ_k (f k dt / m²)² / σ² and the Cramér-Rao bound is its inverse square root."""
    m, f, dt, n, sigma = 15.0, 0.2, 0.5, 30, 0.002
    u = np.zeros((n, 6))
    u[:, 0] = f
    x0 = np.zeros(13)
    x0[9] = 1.0
    fim = fisher_information(x0, u, THETA, dt, MeasurementModel(velocity_std_mps=sigma))
    k = np.arange(1, n + 1)
    expected = np.sum((f * k * dt / m**2) ** 2) / sigma**2
    assert fim[0, 0] == pytest.approx(expected, rel=1e-12)
    np.testing.assert_allclose(fim[1:, :], 0.0, atol=1e-20)


def test_fisher_information_is_right_through_a_half_turn():
    """A spin of more than π about z takes the propagated quaternion through w = 0 (where a w >= 0 convention would
    flip its sign): the information must still match finite differences of the (sign-free) measurements."""
    n, dt = 40, 0.5
    x0 = np.zeros(13)
    x0[6:10] = [0.0, 0.0, -0.7071068, 0.7071068]
    x0[10:13] = [0.01, -0.02, 0.25]  # 0.25 rad/s for 20 s: 5 rad
    rng = np.random.default_rng(4)
    u = np.zeros((n, 6))
    u[:, 0:3] = rng.uniform(-0.2, 0.2, (n, 3))
    u[:, 3:6] = rng.uniform(-0.01, 0.01, (n, 3))
    x, _ = propagate_with_sensitivities(x0, u, THETA, dt)
    assert np.any(x[:, 9] < 0) and np.any(x[:, 9] > 0)  # w did change sign along the trajectory
    model = MeasurementModel(attitude_std_rad=0.005, angular_velocity_std_radps=0.001)
    fim = fisher_information(x0, u, THETA, dt, model)
    cols = []
    for i in range(4):
        step = 1e-6 * THETA[i] * np.eye(4)[i]
        yp, _ = measurements(x0, u, THETA + step, dt, x[:, 6:10])
        ym, _ = measurements(x0, u, THETA - step, dt, x[:, 6:10])
        cols.append((yp - ym) / (2 * step[i]))
    jac = np.column_stack(cols).reshape(n, 12, 4)[:, 6:12].reshape(-1, 4)
    w = np.tile(np.r_[[0.005**-2] * 3, [0.001**-2] * 3], n)
    np.testing.assert_allclose(fim, jac.T @ (w[:, None] * jac), rtol=2e-5)
