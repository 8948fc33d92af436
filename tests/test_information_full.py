"""The full rigid body's Fisher information, scaled A-criterion and input gradient (excitation.information_full)."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.estimation.batch_model import FullModel, full_prior
from oacli.estimation.bounds_full import cramer_rao_bound_full
from oacli.estimation.manifold import boxminus
from oacli.estimation.rigid_dynamics import accelerations_full, propagate_full
from oacli.estimation.rigid_parameters import GROUPS, ParameterSet
from oacli.excitation import information as info4
from oacli.excitation import information_full as full
from oacli.excitation.fim_gradient import criterion_gradient

ALL = tuple(GROUPS)
THETA4 = np.array([9.58, 0.153, 0.143, 0.162])
EXTRA = np.r_[0.002, -0.001, 0.0015, 0.0037, -0.0003, -0.0025, 1.03, 0.97, 1.01, 0.98, 1.02, 1.0]
EXTRA_STD = np.r_[np.full(3, 0.005), np.full(3, 0.01), np.full(6, 0.05)]


def _inputs(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None]
    u = np.c_[0.1 * np.sin(0.3 * t + rng.uniform(0, 6, 3)), 0.01 * np.sin(0.5 * t + rng.uniform(0, 6, 3))]
    x0 = np.zeros(13)
    x0[6:10] = [0.1, -0.2, 0.3, 0.927]
    x0[6:10] /= np.linalg.norm(x0[6:10])
    x0[10:13] = [0.02, -0.01, 0.03]
    return x0, u


MODEL = info4.MeasurementModel(position_std_m=0.01, velocity_std_mps=2e-3, angular_velocity_std_radps=1.6e-2,
                               linear_acceleration_std_mps2=2e-3, angular_acceleration_std_radps2=0.05)


def test_four_entries_equal_todays_information() -> None:
    x0, u = _inputs(40)
    f_old = info4.fisher_information(x0, u, THETA4, 0.5, MODEL)
    new = full.fisher_information_full(x0, u, full.ideal_theta(THETA4), 0.5, MODEL)
    scale = np.sqrt(np.outer(np.diag(f_old), np.diag(f_old)))
    assert np.max(np.abs(new.fim - f_old) / scale) < 1e-12
    assert np.allclose(new.per_step.sum(axis=0), new.fim, rtol=1e-12, atol=0)
    # An attitude measurement differs by the quaternion's radial drift: the old recursion keeps the un-rescaled RK4
    # map's Jacobian, this one projects on the tangent every step (the derivative of the normalised map).
    att = info4.MeasurementModel(attitude_std_rad=0.01)
    f_old = info4.fisher_information(x0, u, THETA4, 0.5, att)
    f_new = full.fisher_information_full(x0, u, full.ideal_theta(THETA4), 0.5, att).fim
    assert np.max(np.abs(f_new - f_old)) < 1e-5 * np.max(np.abs(f_old))


def _rollout_outputs(x0: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float) -> np.ndarray:
    """States and accelerations of the rollout, no Jacobians (for finite differences)."""
    xs = [x0]
    acc = []
    for k in range(u.shape[0]):
        acc.append(accelerations_full(xs[-1][None], u[k][None], theta)[0][0])
        xs.append(propagate_full(xs[-1][None], u[k][None], theta, np.array([[dt]]), jacobians=False)[0][0])
    return np.array(xs), np.array(acc)


def test_full_information_matches_finite_differences() -> None:
    x0, u = _inputs(25)
    dt = 0.5
    theta = full.ideal_theta(THETA4, EXTRA)
    got = full.fisher_information_full(x0, u, theta, dt, MODEL, ALL)
    w_state = np.sqrt(MODEL.state_weights)
    w_acc = np.sqrt(MODEL.acceleration_weights)
    g_state = np.zeros((u.shape[0], 12, 16))
    g_acc = np.zeros((u.shape[0], 6, 16))
    for i in range(16):
        h = 1e-6 * max(abs(theta[i]), 1e-2)
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        xp, ap = _rollout_outputs(x0, u, tp, dt)
        xm, am = _rollout_outputs(x0, u, tm, dt)
        g_state[:, :, i] = boxminus(xp[1:], xm[1:]) / (2 * h) * w_state
        g_acc[:, :, i] = (ap - am) / (2 * h) * w_acc
    f_fd = np.einsum("kmi,kmj->ij", g_state, g_state) + np.einsum("kmi,kmj->ij", g_acc, g_acc)
    scale = np.sqrt(np.outer(np.diag(f_fd), np.diag(f_fd)))
    assert np.max(np.abs(got.fim - f_fd) / scale) < 1e-5
    # The full θ's information alone is singular (force scale × mass, torque scale × inertia): the CRB says so,
    # and the prior of the entries beyond mass and inertia makes it finite.
    assert np.all(np.isinf(full.cramer_rao_std_full(got.fim)))
    prior_std = np.r_[np.sqrt([15.0, 0.005, 0.005, 0.005]), EXTRA_STD]
    assert np.all(np.isfinite(full.cramer_rao_std_full(full.add_prior_information(got.fim, ALL, prior_std))))


def test_information_with_unknown_start_equals_bounds_full() -> None:
    x0, u = _inputs(30)
    dt = 0.5
    theta = full.ideal_theta(THETA4, EXTRA)
    groups = ("mass", "inertia", "products", "com")
    meas = info4.MeasurementModel(velocity_std_mps=2e-3, angular_velocity_std_radps=1.6e-2)
    f = full.information_unknown_start(x0, u, theta, dt, meas, groups)
    prior_std = np.r_[np.sqrt([15.0, 0.005, 0.005, 0.005]), EXTRA_STD]
    f = full.add_prior_information(f, groups, prior_std)
    xs = full.fisher_information_full(x0, u, theta, dt, meas, groups).x
    mean, cov = full_prior(THETA4, np.diag(prior_std[:4] ** 2), EXTRA, EXTRA_STD)
    model = FullModel(ParameterSet.build(groups, theta), mean, cov)
    t = dt * np.arange(u.shape[0] + 1)
    bound = cramer_rao_bound_full(t, xs, np.r_[u, np.zeros((1, 6))], theta, model, meas, dt)
    assert np.array_equal(bound.index, full.entry_index(groups))
    scale = np.sqrt(np.outer(np.diag(f), np.diag(f)))
    assert np.max(np.abs(bound.information - f) / scale) < 1e-9
    assert np.allclose(full.cramer_rao_std_full(f), bound.std, rtol=1e-8)


def test_a_criterion_is_unit_invariant_with_prior_scaling() -> None:
    x0, u = _inputs(30)
    theta = full.ideal_theta(THETA4, EXTRA)
    groups = ("mass", "inertia", "com")
    prior_std = np.r_[np.sqrt([15.0, 0.005, 0.005, 0.005]), EXTRA_STD]
    f = full.fisher_information_full(x0, u, theta, 0.5, MODEL, groups).fim
    # The CoM in millimetres and the inertia in g·m²: θ' = T θ, so F' = T⁻¹ F T⁻¹ and σ' = T σ.
    t = np.r_[1.0, 1e3, 1e3, 1e3, 1e3, 1e3, 1e3]
    f_units = f / np.outer(t, t)
    prior_units = prior_std.copy()
    prior_units[full.entry_index(groups)] *= t
    theta_units = theta.copy()
    theta_units[full.entry_index(groups)] *= t
    for scaling in ("prior", "nominal"):
        a = full.a_criterion_full(f, full.parameter_scale(theta, prior_std, groups, scaling))
        b = full.a_criterion_full(f_units, full.parameter_scale(theta_units, prior_units, groups, scaling))
        assert np.isfinite(a) and b == pytest.approx(a, rel=1e-9)
    a = full.a_criterion_full(f, full.parameter_scale(theta, prior_std, groups, "absolute"))
    b = full.a_criterion_full(f_units, full.parameter_scale(theta_units, prior_units, groups, "absolute"))
    assert b > 1e3 * a  # the unscaled trace is dominated by whichever unit is smallest
    # The prior-scaled criterion is the sum of the (CRB / prior σ)² ratios.
    crb = full.cramer_rao_std_full(f)
    assert a == pytest.approx(np.sum(crb**2), rel=1e-9)
    assert full.a_criterion_full(f, full.parameter_scale(theta, prior_std, groups)) == pytest.approx(
        np.sum((crb / prior_std[full.entry_index(groups)]) ** 2), rel=1e-9)


def test_criterion_gradient_matches_the_exact_adjoint() -> None:
    x0, u = _inputs(20)
    meas = info4.MeasurementModel(velocity_std_mps=2e-3, angular_velocity_std_radps=1.6e-2,
                                  linear_acceleration_std_mps2=2e-3)
    value_ref, grad_ref = criterion_gradient(x0, u, THETA4, 0.5, meas, "A", "relative")
    scale = full.parameter_scale(full.ideal_theta(THETA4), np.ones(16), ("mass", "inertia"), "nominal")
    value, grad = full.a_criterion_gradient_full(x0, u, full.ideal_theta(THETA4), 0.5, meas, scale,
                                                 input_scale=np.r_[np.full(3, 0.1), np.full(3, 0.01)])
    assert value == pytest.approx(value_ref, rel=1e-10)
    assert np.max(np.abs(grad - grad_ref)) < 1e-5 * np.max(np.abs(grad_ref))
