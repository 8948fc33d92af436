"""References the robot can fly: design limits ([Doerr2021] Eq. 28 mass margin), section limits above the robot's,
the reference check of ``oacli track`` and RATTLE's rate governor."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from oacli.config import config_from_dict, load_config
from oacli.errors import ConfigError, InputError
from oacli.excitation.rattle_loop import rate_governed_torque
from oacli.model import rigid_body as rb
from oacli.reference_limits import (
    MotionLimits,
    ReferenceMargin,
    check_reference_limits,
    design_limits,
    limits_above_robot,
    required_inputs,
)
from oacli.stages.design_limits import excitation_design_limits, planner_design_limits
from oacli.stages.settings import robot_model
from oacli.stages.track import check_reference_for_plant
from oacli.trajectory import feedforward_inputs
from oacli.types import InertialParams, Trajectory
from tests.conftest import REPO
from tests.model_helpers import mass_model

ISS = REPO / "configs" / "iss_reswarm.yaml"
ROBOT = MotionLimits([0.452, 0.216, 0.257], [0.0452, 0.0216, 0.0257], [0.2] * 3, [0.1745] * 3)


def iss_dict() -> dict:
    return yaml.safe_load(ISS.read_text())


# ----------------------------------------------------------------------------------------------------------------
# Design limits
# ----------------------------------------------------------------------------------------------------------------


def test_mass_upper_bound_is_the_eq28_two_sigma_bound():
    assert ReferenceMargin(mass_model(15.0, math.sqrt(15.0)), 2.0).mass_upper_kg == pytest.approx(
        15.0 + 2.0 * 3.872983346207417)
    assert ReferenceMargin(mass_model(9.5), 2.0).mass_upper_kg == 9.5
    with pytest.raises(ValueError):
        ReferenceMargin(mass_model(9.5, 0.1), -1.0)


def test_a_plant_at_the_upper_mass_follows_the_design_with_the_feedback_share_left(rng):
    for _ in range(50):
        m_prior = rng.uniform(5.0, 30.0)
        margin = ReferenceMargin(mass_model(m_prior, rng.uniform(0.0, 5.0)), rng.uniform(1.0, 3.0),
                                 force_fraction=0.8)
        lim = design_limits(ROBOT, margin)
        # The design accelerates its model at up to a = f/m_prior; the heaviest plant of the margin needs
        # m_upper a, which must be the feedback-free share of the actuator, no more.
        needed = margin.mass_upper_kg * lim.limits.force_N / m_prior
        np.testing.assert_allclose(needed, 0.8 * ROBOT.force_N, rtol=1e-12)
        # Every lighter plant needs less.
        m = rng.uniform(0.5 * m_prior, margin.mass_upper_kg)
        assert np.all(m * lim.limits.force_N / m_prior <= 0.8 * ROBOT.force_N * (1 + 1e-12))


def test_design_limits_apply_the_shares_and_only_lower_with_caps():
    margin = ReferenceMargin(mass_model(10.0, 1.0), 2.0, force_fraction=0.8, torque_fraction=0.7, velocity_fraction=0.9,
                             angular_velocity_fraction=0.5)
    lim = design_limits(ROBOT, margin, {"force_N": [0.1, 1.0, 1.0], "angular_velocity_radps": None})
    np.testing.assert_allclose(lim.limits.force_N, [0.1, 0.216 * 10 / 12 * 0.8, 0.257 * 10 / 12 * 0.8])
    np.testing.assert_array_equal(lim.capped["force_N"], [True, False, False])
    np.testing.assert_allclose(lim.limits.torque_Nm, 0.7 * ROBOT.torque_Nm)
    np.testing.assert_allclose(lim.limits.velocity_mps, 0.9 * ROBOT.velocity_mps)
    np.testing.assert_allclose(lim.limits.angular_velocity_radps, 0.5 * ROBOT.angular_velocity_radps)
    summary = lim.summary()
    assert summary["mass_upper_kg"] == pytest.approx(12.0) and summary["mass_ratio"] == pytest.approx(10 / 12)


def test_limits_above_robot_names_each_axis():
    excess = limits_above_robot(ROBOT, {"force_N": [0.25, 0.25, 0.25], "angular_velocity_radps": [0.1745] * 3})
    assert [(e.quantity, e.axis, e.requested, e.robot) for e in excess] == [("force_N", 1, 0.25, 0.216)]


def test_iss_preset_excitation_limits_follow_the_excitation_prior():
    cfg = load_config(ISS)
    lim = excitation_design_limits(cfg)
    ratio = 15.0 / (15.0 + 2.0 * math.sqrt(15.0))  # excitation.prior: 15 kg, variance 15 kg²
    np.testing.assert_allclose(lim.limits.force_N, np.minimum([0.25, 0.216, 0.25], 0.8 * ratio * ROBOT.force_N))
    np.testing.assert_allclose(lim.limits.torque_Nm, np.minimum([0.025, 0.0216, 0.025], 0.8 * ROBOT.torque_Nm))
    np.testing.assert_allclose(lim.limits.angular_velocity_radps, 0.9 * 0.1745)
    assert np.all(lim.limits.force_N < ROBOT.force_N) and np.all(lim.limits.angular_velocity_radps < 0.1745)
    # RATTLE: its own caps (0.15 N, 0.015 N·m) over excitation.limits, still under the margin.
    rattle = excitation_design_limits(cfg, rattle=True)
    np.testing.assert_allclose(rattle.limits.force_N, np.minimum(0.15, 0.8 * ratio * ROBOT.force_N))
    np.testing.assert_allclose(rattle.limits.torque_Nm, np.minimum(0.015, 0.8 * ROBOT.torque_Nm))


def test_planner_limits_use_the_robot_model_and_its_own_std():
    """The robot is known unless robot.variance says otherwise: no derating through the estimator prior's default
    variance (15 kg²: a plan with no payload was 50 % slower); the model's σ_m derates by Eq. 28's bound, n_σ the
    planner's (planner.margin.mass_sigmas)."""
    data = iss_dict()
    cfg = config_from_dict(data)
    m = cfg.robot.mass_kg
    lim = planner_design_limits(cfg)
    np.testing.assert_allclose(lim.limits.force_N, ROBOT.force_N * 0.8)
    np.testing.assert_allclose(lim.limits.velocity_mps, 0.18)
    data["robot"]["variance"] = [15.0, 0.0, 0.0, 0.0]
    lim = planner_design_limits(config_from_dict(data))
    np.testing.assert_allclose(lim.limits.force_N, ROBOT.force_N * 0.8 * m / (m + 2.0 * math.sqrt(15.0)))
    # The planner choosing 0 σ (or a model known exactly) keeps only the feedback share.
    data["planner"]["margin"] = {"mass_sigmas": 0.0, "reference_force_fraction": 1.0}
    lim = planner_design_limits(config_from_dict(data))
    np.testing.assert_allclose(lim.limits.force_N, ROBOT.force_N)


def test_a_section_limit_above_the_robot_is_refused_naming_field_and_values():
    data = iss_dict()
    data["excitation"]["limits"]["force_N"] = [0.25, 0.25, 0.25]
    with pytest.raises(ConfigError) as err:
        excitation_design_limits(config_from_dict(data))
    assert len(err.value.problems) == 1
    text = err.value.problems[0]
    assert "excitation.limits.force_N.1" in text and "0.25" in text and "robot.force_limit_N.1 = 0.216 N" in text
    data = iss_dict()
    data["planner"]["limits"] = {"velocity_mps": [0.3, 0.1, 0.1]}
    with pytest.raises(ConfigError, match=r"planner\.limits\.velocity_mps\.0: 0\.3: .*robot\.velocity_limit_mps\.0"):
        planner_design_limits(config_from_dict(data))


def test_clip_lowers_to_the_robot_and_states_it():
    data = iss_dict()
    data["excitation"]["limits"]["force_N"] = [0.25, 0.25, 0.25]
    data["excitation"]["margin"] = {"on_excess": "clip", "reference_force_fraction": 1.0, "mass_sigmas": 0.0}
    lim = excitation_design_limits(config_from_dict(data))
    np.testing.assert_allclose(lim.limits.force_N, [0.25, 0.216, 0.25])
    assert len(lim.notes) == 1 and "excitation.limits.force_N.1 = 0.25 N" in lim.notes[0]
    assert "clipped to 0.216 N" in lim.notes[0]
    assert lim.summary()["notes"] == list(lim.notes)


# ----------------------------------------------------------------------------------------------------------------
# The reference check
# ----------------------------------------------------------------------------------------------------------------


def ramp_reference(accel: np.ndarray, alpha_z: float, dt: float = 0.5, n: int = 21) -> Trajectory:
    """Constant linear acceleration and a constant angular acceleration about body z, from rest."""
    t = dt * np.arange(n)
    x = np.zeros((n, 13))
    x[:, 0:3] = 0.5 * np.outer(t**2, accel)
    x[:, 3:6] = np.outer(t, accel)
    x[:, 6:10] = [0.0, 0.0, 0.0, 1.0]
    x[:, 12] = alpha_z * t
    return Trajectory(t, x, np.zeros((n, 6)))


def test_check_gives_worst_ratio_and_first_time_in_closed_form():
    plant = InertialParams(15.0, [0.15, 0.14, 0.16])
    ref = ramp_reference(np.array([0.0, 0.016, 0.0]), alpha_z=0.02)
    check = check_reference_limits(ref, plant, ROBOT)
    force = check.checks["force_N"]
    assert force.worst_ratio == pytest.approx(15.0 * 0.016 / 0.216, rel=1e-12)  # 1.11: above the y actuator
    assert force.exceeded and force.first_exceeded_t_s == 0.0 and force.first_axis == 1
    assert force.first_value == pytest.approx(0.24) and force.first_limit == 0.216
    torque = check.checks["torque_Nm"]  # ω about a principal axis: no gyroscopic torque, τ = I α
    assert torque.worst_ratio == pytest.approx(0.16 * 0.02 / 0.0257, rel=1e-9) and not torque.exceeded
    speed = check.checks["velocity_mps"]  # v = a t reaches 0.016 × 10 s = 0.16 m/s < 0.2
    assert speed.worst_ratio == pytest.approx(0.16 / 0.2) and speed.worst_t_s == 10.0 and not speed.exceeded
    rate = check.checks["angular_velocity_radps"]  # ω = 0.02 t: above 0.1745 rad/s after 8.725 s, first at 9 s
    assert rate.exceeded and rate.first_exceeded_t_s == pytest.approx(9.0) and rate.first_axis == 2
    assert rate.worst_ratio == pytest.approx(0.2 / 0.1745) and rate.worst_t_s == 10.0
    assert check.exceeded == ["force_N", "angular_velocity_radps"] and not check.ok
    msg = check.message()
    assert "force_N 0.24 N > 0.216 N (y) at t = 0.00 s" in msg and "angular_velocity_radps" in msg
    summary = check.summary()
    assert summary["force_N"]["first_axis"] == "y" and summary["exceeded"] == ["force_N", "angular_velocity_radps"]
    # The lighter robot model needs less: the same reference is within its force limit.
    light = check_reference_limits(ref, InertialParams(9.5, [0.15, 0.14, 0.16]), ROBOT)
    assert not light.checks["force_N"].exceeded


def test_check_adds_the_plant_disturbance():
    plant = InertialParams(10.0, [0.15, 0.14, 0.16])
    ref = ramp_reference(np.array([0.01, 0.0, 0.0]), alpha_z=0.0)
    bias = np.array([-0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    bound = np.array([0.0, 0.02, 0.0, 0.0, 0.0, 0.0])
    check = check_reference_limits(ref, plant, ROBOT, disturbance_bias=bias, disturbance_bound=bound)
    # A bias against the motion must be overcome too: |m a − b| = 0.1 + 0.05; the random part adds its bound.
    assert check.checks["force_N"].worst_ratio == pytest.approx(max(0.15 / 0.452, 0.02 / 0.216), rel=1e-12)


def test_required_inputs_are_the_feedforward_of_the_plant_also_on_an_uneven_grid(rng):
    plant = InertialParams(12.0, [0.15, 0.14, 0.16])
    u = np.zeros((30, 6))
    u[:, 0:3] = rng.uniform(-0.1, 0.1, (30, 3))
    u[:, 3:6] = rng.uniform(-0.005, 0.005, (30, 3))
    x = [np.r_[np.zeros(6), 0.0, 0.0, 0.0, 1.0, np.zeros(3)]]
    for k in range(30):
        x.append(rb.propagate(x[-1], u[k], np.r_[plant.mass_kg, plant.inertia_kgm2], 0.5))
    x = np.array(x)
    t = 0.5 * np.arange(31)
    uniform = required_inputs(Trajectory(t, x, np.zeros((31, 6))), plant)
    np.testing.assert_allclose(uniform, feedforward_inputs(x, 0.5, plant), rtol=1e-12)
    np.testing.assert_allclose(uniform[:, 0:3], u[:, 0:3], rtol=1e-9, atol=1e-12)  # exact for the force
    keep = np.r_[0:10, 10:31:2]  # 0.5 s steps, then 1 s steps
    uneven = required_inputs(Trajectory(t[keep], x[keep], np.zeros((keep.size, 6))), plant)
    np.testing.assert_allclose(uneven[:10], uniform[:10], rtol=1e-12)
    np.testing.assert_allclose(uneven[10:, 0:3], 0.5 * (u[10::2, 0:3] + u[11::2, 0:3]), rtol=1e-9, atol=1e-12)


def test_check_for_plant_warns_in_the_log_or_refuses_when_strict():
    data = iss_dict()
    data["truth"] = {"mass_kg": 30.0}
    cfg = config_from_dict(data)
    ref = ramp_reference(np.array([0.0, 0.01, 0.0]), alpha_z=0.0)
    log: list = []
    check = check_reference_for_plant(cfg, ref, log)
    assert check.exceeded == ["force_N"]  # 30 kg × 0.01 = 0.3 N > 0.216 N on y
    assert log == [(0.0, "warning", check.message())]
    with pytest.raises(InputError, match=r"force_N 0\.3 N > 0\.216 N \(y\) at t = 0\.00 s.*--strict"):
        check_reference_for_plant(cfg, ref, [], strict=True)
    assert robot_model(cfg).limits.force_N[1] == 0.216


# ----------------------------------------------------------------------------------------------------------------
# RATTLE's rate governor
# ----------------------------------------------------------------------------------------------------------------


def test_rate_governor_keeps_the_next_rate_within_the_limit(rng):
    inertia = np.array([0.153, 0.143, 0.162])
    theta = np.r_[9.6, inertia]
    limit, tau_max, dt = np.full(3, 0.1745), np.array([0.0452, 0.0216, 0.0257]), 0.2
    governed = 0
    for _ in range(200):
        w = rng.uniform(-0.17, 0.17, 3)
        tau = rng.uniform(-tau_max, tau_max)
        out = rate_governed_torque(tau, w, inertia, dt, limit, tau_max)
        assert np.all(np.abs(out) <= tau_max * (1 + 1e-12))
        # Unchanged whenever the requested torque keeps the predicted rate within the limit.
        gyro = np.cross(w, inertia * w)
        pred = w + dt * (tau - gyro) / inertia
        np.testing.assert_array_equal(out[np.abs(pred) <= limit], tau[np.abs(pred) <= limit])
        governed += int(np.any(out != tau))
        x = np.r_[np.zeros(6), 0.0, 0.0, 0.0, 1.0, w]
        x1 = rb.propagate(x, np.r_[np.zeros(3), out], theta, dt)
        assert np.all(np.abs(x1[10:13]) <= limit + 2e-4)  # first-order prediction: the gyroscopic term moves
    assert governed > 20
    # Already beyond the limit: full braking.
    out = rate_governed_torque(np.array([0.01, 0.0, 0.0]), np.array([0.3, 0.0, 0.0]), inertia, dt, limit, tau_max)
    assert out[0] == -tau_max[0]
