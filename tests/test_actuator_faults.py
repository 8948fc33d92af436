"""The plant's unmodelled actuator scale error and centre-of-mass offset (oacli.sim.simulator), against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from oacli.config import config_from_dict
from oacli.errors import ConfigError
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.types import ControlStep, InertialParams, SolveInfo


class ConstantInput:
    """A controller that always commands the same wrench."""

    def __init__(self, u: np.ndarray) -> None:
        self.u = np.asarray(u, dtype=float)

    def step(self, t: float, y: np.ndarray) -> ControlStep:
        return ControlStep(self.u, SolveInfo("const", True), np.asarray(y))


def _run(u, **kw):
    x0 = np.zeros(13)
    x0[9] = 1.0
    truth = InertialParams(10.0, (0.15, 0.14, 0.16))
    return simulate(ConstantInput(u), x0, truth, duration_s=2.0, control_period_s=0.2, plant_period_s=0.016,
                    input_limits=np.array([1.0, 1.0, 1.0, 0.1, 0.1, 0.1]), sensors=SensorNoise(),
                    disturbance=Disturbance.none(), rng=np.random.default_rng(0), **kw)


def test_actuator_scale_scales_the_delivered_force_not_the_recorded_one():
    u = np.array([0.2, -0.1, 0.05, 0.0, 0.0, 0.0])
    scale = np.array([1.05, 0.97, 1.0, 1.0, 1.0, 1.0])
    tel = _run(u, actuator_scale=scale)
    t = tel.t_true[-1]
    expected = 0.5 * (scale[0:3] * u[0:3] / 10.0) * t**2       # x = ½ a t², a = s·F / m (identity attitude:
                                                                # the body axes are the world axes)
    np.testing.assert_allclose(tel.x_true[-1, 0:3], expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(tel.u_applied, np.tile(u, (len(tel.t_ctrl), 1)))   # what the log holds


def test_actuator_scale_is_per_body_axis():
    """Astrobee's impellers are body-fixed: yawed by 90° (body x = world y), a world-x force is scaled by the body
    y factor and a world-y force by the body x factor."""
    u = np.array([0.2, -0.1, 0.0, 0.0, 0.0, 0.0])
    scale = np.array([1.05, 0.97, 1.0, 1.0, 1.0, 1.0])
    x0 = np.zeros(13)
    x0[6:10] = [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]
    tel = simulate(ConstantInput(u), x0, InertialParams(10.0, (0.15, 0.14, 0.16)), duration_s=2.0, control_period_s=0.2,
                   plant_period_s=0.016, input_limits=np.array([1.0, 1.0, 1.0, 0.1, 0.1, 0.1]),
                   sensors=SensorNoise(), disturbance=Disturbance.none(), rng=np.random.default_rng(0),
                   actuator_scale=scale)
    t = tel.t_true[-1]
    expected = 0.5 * (np.array([0.97, 1.05, 1.0]) * u[0:3] / 10.0) * t**2
    np.testing.assert_allclose(tel.x_true[-1, 0:3], expected, rtol=1e-9, atol=1e-12)


def test_com_offset_torques_the_body_by_minus_r_cross_f():
    u = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    r = np.array([0.0, 0.004, 0.0])
    tel = _run(u, com_offset_m=r)
    # At identity attitude the torque is (-r) × F = -(0.004 ŷ × 0.3 x̂) = +0.0012 ẑ N·m; ω_z(t) ≈ τ_z t / Izz for
    # the small rotation of 2 s (the attitude change couples only at second order).
    tau_z = -np.cross(r, u[0:3])[2]
    assert tau_z == pytest.approx(0.0012)
    t = tel.t_true[-1]
    assert tel.x_true[-1, 12] == pytest.approx(tau_z * t / 0.16, rel=1e-3)
    assert abs(tel.x_true[-1, 10]) < 1e-6 and abs(tel.x_true[-1, 11]) < 1e-6
    no_offset = _run(u)
    assert np.all(no_offset.x_true[:, 10:13] == 0.0)


@pytest.mark.parametrize(("field", "value", "reason"), [
    ("actuator_scale", [1.0, 1.0, 2.0, 1.0, 1.0, 1.0], "must be <= 1.5"),
    ("actuator_scale", [1.0, 1.0, 1.0], "6"),
    ("com_offset_m", [0.1, 0.0, 0.0], "±0.05 m"),
])
def test_truth_actuator_fields_are_validated(field, value, reason):
    text = f"robot: {{mass_kg: 9.5, inertia_kgm2: [0.15, 0.14, 0.16], force_limit_N: [0.5, 0.5, 0.5], " \
           f"torque_limit_Nm: [0.05, 0.05, 0.05]}}\ntruth: {{{field}: {value}}}\n"
    with pytest.raises(ConfigError) as err:
        config_from_dict(yaml.safe_load(text), source="cfg")
    assert f"truth.{field}" in str(err.value) and reason in str(err.value)
