"""The standard MPC's margin for the state-estimate error (issue 29): the workspace rows keep the TRUE position
clear at k σ of the error of the position predicted from the estimate (oacli.control.tracking,
oacli.control.workspace). Checked against the Gaussian quantile, a Monte-Carlo run of the filter, and the
config's wiring."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from oacli.config import load_config
from oacli.control.observer import TranslationObserver
from oacli.control.tracking import StateEstimate, estimate_observer, predicted_position_std
from oacli.control.workspace import WorkspaceRows
from oacli.geometry import Ellipsoid, Scene
from oacli.geometry.collision import RobotBody
from oacli.model.double_integrator import double_integrator
from oacli.stages.track_tube import standard_mpc_arguments, workspace_arguments
from oacli.types import InertialParams
from tests.conftest import REPO

SIGMA = np.array([0.004, 0.002, 0.003])  # per-axis σ of the error [m]
K = 3.0
SCENE = Scene(keep_out=(Ellipsoid.from_semi_axes((1.0, 0.0, 0.0), (0.3, 0.2, 0.25)),))


def test_rows_keep_the_true_position_clear_at_k_sigma():
    plain = WorkspaceRows(SCENE, RobotBody.sphere(0.1))
    tight = WorkspaceRows(SCENE, RobotBody.sphere(0.1), error_std_m=SIGMA, error_sigmas=K)
    lin = np.array([[0.4, 0.1, 0.05], [0.6, -0.3, 0.2], [1.0, 0.0, -0.6]])
    a, b = plain.rows(lin), tight.rows(lin)
    np.testing.assert_allclose(a.normals, b.normals)
    n = a.normals[0]
    sigma_n = np.sqrt((n**2) @ SIGMA**2)  # σ of nᵀe for independent axes
    np.testing.assert_allclose(b.offsets[0] - a.offsets[0], K * sigma_n, rtol=1e-12)
    # Monte Carlo: a position ON the tightened row, the true one p - e (e ~ N(0, diag σ²)): it violates the
    # plain row with the one-sided Gaussian tail probability of K σ.
    rng = np.random.default_rng(29)
    e = rng.normal(size=(400_000, 3)) * SIGMA
    inside = (b.offsets[0][:, None] - n @ e.T) < a.offsets[0][:, None]  # nᵀ(p − e) < β_plain
    np.testing.assert_allclose(inside.mean(axis=1), stats.norm.sf(K), atol=3e-4)
    with pytest.raises(ValueError, match="error σ"):
        WorkspaceRows(SCENE, error_std_m=-SIGMA, error_sigmas=K)


def test_the_margin_floor_holds_with_an_exact_state_and_yields_to_k_sigma():
    """max(k σ_i, floor) per axis: with σ = 0 every row moves out by exactly the floor (unit normals); where k σ_i
    exceeds it, the k σ margin stands (the flight's sensors: 3 × 2.17 mm > 2 mm)."""
    lin = np.array([[0.4, 0.1, 0.05], [0.6, -0.3, 0.2], [1.0, 0.0, -0.6]])
    plain = WorkspaceRows(SCENE, RobotBody.sphere(0.1)).rows(lin)
    floor = WorkspaceRows(SCENE, RobotBody.sphere(0.1), min_error_margin_m=0.002).rows(lin)
    np.testing.assert_allclose(floor.offsets[0] - plain.offsets[0], 0.002, rtol=1e-12)
    both = WorkspaceRows(SCENE, RobotBody.sphere(0.1), error_std_m=SIGMA, error_sigmas=K, min_error_margin_m=0.007)
    n = plain.normals[0]
    per_axis = np.maximum(K * SIGMA, 0.007)  # x: 12 mm stands, y and z: the 7 mm floor
    np.testing.assert_allclose(both.rows(lin).offsets[0] - plain.offsets[0], np.sqrt((n**2) @ per_axis**2),
                               rtol=1e-12)
    with pytest.raises(ValueError, match="margin floor"):
        WorkspaceRows(SCENE, min_error_margin_m=-0.001)


def test_keep_in_boxes_shrink_by_k_sigma_per_axis():
    from oacli.geometry import Box

    scene = Scene(keep_in=(Box((0.0, 0.0, 0.0), (2.0, 1.0, 1.5)),))
    p = np.array([[1.0, 0.5, 0.7], [1.1, 0.5, 0.7]])
    a = WorkspaceRows(scene).rows(p)
    b = WorkspaceRows(scene, error_std_m=SIGMA, error_sigmas=K).rows(p)
    np.testing.assert_allclose(b.lower - a.lower, np.tile(K * SIGMA, (2, 1)))
    np.testing.assert_allclose(a.upper - b.upper, np.tile(K * SIGMA, (2, 1)))


@pytest.mark.parametrize("filtered", [False, True])
def test_predicted_position_std_is_the_monte_carlo_error_of_the_next_position(filtered):
    # The flight's sensors (mission_iss.yaml), 5 Hz, a 9.58 kg model; the plant is the model with a white
    # acceleration of the filter's assumed σ, driven by a known force.
    dt, mass, sp, sv, sa = 0.2, 9.583788668, 0.01, 0.00223606797749979, 0.01
    est = StateEstimate(sp, sv, sa if filtered else None, K)
    a, b = double_integrator(dt, 1.0 / mass)
    obs = estimate_observer(est, InertialParams(mass, np.array([0.153, 0.143, 0.162])), dt)
    assert isinstance(obs, TranslationObserver) == filtered
    rng = np.random.default_rng(7)
    x = np.zeros((2, 3))  # [p; v] per axis (columns)
    errors = []
    g = np.array([0.5 * dt * dt, dt])
    for k in range(6000):
        y = x + rng.normal(size=(2, 3)) * np.array([[sp], [sv]])
        force = 0.05 * np.sin(0.05 * k) * np.ones(3)
        if obs is None:
            xh = y
        else:
            xh6 = obs.update(k * dt, np.concatenate([y[0], y[1]]))
            xh = xh6.reshape(2, 3)
            obs.applied(force)
        pred = a @ xh + b @ force[None, :]  # the controller's prediction of the next position
        x = a @ x + b @ force[None, :] + np.outer(g, rng.normal(size=3) * sa)
        if k > 50:
            errors.append(pred[0] - x[0])
    measured = float(np.std(np.concatenate(errors)))
    assert measured == pytest.approx(predicted_position_std(est, dt), rel=0.05)
    if filtered:  # the filter's prediction is 4-5 times better than the raw measurement's
        assert predicted_position_std(est, dt) < 0.3 * sp


def test_the_config_reaches_the_standard_mpc_only():
    cfg = load_config(REPO / "configs" / "mission_iss.yaml")
    args = standard_mpc_arguments(cfg)
    est = args.pop("estimate")
    assert args.keys() == workspace_arguments(cfg).keys()  # the tube MPC gets no estimate (it has its own)
    assert est == StateEstimate(cfg.sensors.position_std_m, cfg.sensors.velocity_std_mps,
                                cfg.controller.estimate.accel_std_mps2, cfg.controller.estimate.margin_sigmas,
                                cfg.controller.estimate.min_margin_m)
    assert est.filtered and cfg.controller.estimate.margin_sigmas == 3.0
    quiet = cfg.model_copy(update={"sensors": cfg.sensors.model_copy(update={"position_std_m": 0.0,
                                                                           "velocity_std_mps": 0.0})})
    est0 = standard_mpc_arguments(quiet)["estimate"]
    assert not est0.filtered and predicted_position_std(est0, 0.2) == 0.0  # no noise, no margin
