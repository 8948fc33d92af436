"""Closed-loop simulator: exact multi-rate integration, saturation, seeded noise and disturbance."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.types import ControlStep, InertialParams, SolveInfo

TRUTH = InertialParams(15.0, [0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1, Astrobee with object
LIMITS = np.array([0.5, 0.5, 0.5, 0.05, 0.05, 0.05])


class PiecewiseForce:
    """Commands a force that changes every control step: f_j = base · (j + 1), no torque."""

    def __init__(self, base):
        self.base = np.asarray(base, dtype=float)
        self.calls: list[tuple[float, np.ndarray]] = []

    def step(self, t, x_measured):
        j = len(self.calls)
        self.calls.append((t, x_measured.copy()))
        return ControlStep(np.r_[self.base * (j + 1), 0.0, 0.0, 0.0], SolveInfo("open_loop", True), x_measured)


def at_rest():
    x = np.zeros(13)
    x[9] = 1.0
    return x


def closed_form_position(base, t_ctrl, period, mass, t):
    """Position at time t under the piecewise-constant force base·(j+1) on [t_j, t_j + period)."""
    p = np.zeros(3)
    v = np.zeros(3)
    for j, tj in enumerate(t_ctrl):
        dt = min(max(t - tj, 0.0), period)
        a = base * (j + 1) / mass
        p = p + v * dt + 0.5 * a * dt * dt
        v = v + a * dt
    return p


def test_multirate_integration_is_exact_for_translation():
    """62.5 Hz plant and 5 Hz controller: 0.2 s is 12.5 plant steps, so steps are split at the control instants."""
    base = np.array([0.01, -0.02, 0.005])
    ctrl = PiecewiseForce(base)
    tel = simulate(ctrl, at_rest(), TRUTH, duration_s=3.0, control_period_s=0.2, plant_period_s=0.016,
                   input_limits=LIMITS, sensors=SensorNoise(), disturbance=Disturbance.none(),
                   rng=np.random.default_rng(0))
    np.testing.assert_allclose(tel.t_ctrl, 0.2 * np.arange(15))
    # 3.0 s is 187.5 plant ticks: every interval is 16 ms but the last, cut at the final time.
    np.testing.assert_allclose(np.diff(tel.t_true)[:-1], 0.016, atol=1e-12)
    assert np.diff(tel.t_true)[-1] == pytest.approx(0.008)
    assert tel.t_true[-1] == pytest.approx(3.0)
    for k in (0, 13, 25, 100, len(tel.t_true) - 1):
        expected = closed_form_position(base, tel.t_ctrl, 0.2, TRUTH.mass_kg, tel.t_true[k])
        np.testing.assert_allclose(tel.x_true[k, 0:3], expected, atol=1e-13)
    # Controller instants see the true state at exactly that time (noise-free sensor).
    for t, y in ctrl.calls[1:4]:
        np.testing.assert_allclose(y[0:3], closed_form_position(base, tel.t_ctrl, 0.2, TRUTH.mass_kg, t), atol=1e-13)


def test_actuators_saturate_per_axis():
    ctrl = PiecewiseForce([0.3, -0.01, 0.0])  # axis x exceeds 0.5 N from the second step on
    tel = simulate(ctrl, at_rest(), TRUTH, duration_s=1.0, control_period_s=0.2, plant_period_s=0.016,
                   input_limits=LIMITS, sensors=SensorNoise(), disturbance=Disturbance.none(),
                   rng=np.random.default_rng(0))
    np.testing.assert_allclose(tel.u_command[:, 0], 0.3 * np.arange(1, 6))
    np.testing.assert_allclose(tel.u_applied[:, 0], np.minimum(0.3 * np.arange(1, 6), 0.5))
    np.testing.assert_allclose(tel.u_applied[:, 1], tel.u_command[:, 1])


def _noisy_run(seed):
    ctrl = PiecewiseForce([0.0, 0.0, 0.0])
    return simulate(ctrl, at_rest(), TRUTH, duration_s=40.0, control_period_s=0.2, plant_period_s=0.016,
                    input_limits=LIMITS, sensors=SensorNoise(0.01, 0.002, 0.005, 0.001),
                    disturbance=Disturbance(np.zeros(6), np.r_[0.01, 0.01, 0.01, 0.0, 0.0, 0.0]),
                    rng=np.random.default_rng(seed))


def test_same_seed_same_numbers_and_noise_has_the_configured_spread():
    a, b, c = _noisy_run(7), _noisy_run(7), _noisy_run(8)
    np.testing.assert_array_equal(a.x_measured, b.x_measured)
    np.testing.assert_array_equal(a.x_true, b.x_true)
    assert not np.allclose(a.x_measured, c.x_measured)
    # The measurement error of position has the configured standard deviation (200 × 3 samples: ±10 %).
    idx = np.searchsorted(a.t_true, a.t_ctrl)
    err = a.x_measured[:, 0:3] - a.x_true[idx, 0:3]
    assert np.std(err) == pytest.approx(0.01, rel=0.1)
    # The disturbance stays in its bound and is applied.
    assert np.all(np.abs(a.disturbance[:, :3]) <= 0.01)
    assert np.std(a.disturbance[:, :3]) == pytest.approx(0.01 / np.sqrt(3), rel=0.15)
    assert np.linalg.norm(a.x_true[-1, 3:6]) > 0.0


def test_on_step_hands_over_every_sample_once_and_changes_nothing():
    """``on_step`` (used by ``track`` to write its MCAP while it runs) sees every plant sample exactly once, in
    order, and every control step's record; the run is the same with or without it (seeded noise included)."""
    steps: list[dict] = []
    with_hook = simulate(PiecewiseForce([0.01, 0.0, 0.0]), at_rest(), TRUTH, duration_s=3.0, control_period_s=0.2,
                         plant_period_s=0.016, input_limits=LIMITS, sensors=SensorNoise(0.01, 0.002, 0.005, 0.001),
                         disturbance=Disturbance(np.zeros(6), np.full(6, 0.001)), rng=np.random.default_rng(3),
                         on_step=lambda j, **rec: steps.append({"j": j, **rec}))
    without = simulate(PiecewiseForce([0.01, 0.0, 0.0]), at_rest(), TRUTH, duration_s=3.0, control_period_s=0.2,
                       plant_period_s=0.016, input_limits=LIMITS, sensors=SensorNoise(0.01, 0.002, 0.005, 0.001),
                       disturbance=Disturbance(np.zeros(6), np.full(6, 0.001)), rng=np.random.default_rng(3))
    np.testing.assert_array_equal(with_hook.x_true, without.x_true)
    np.testing.assert_array_equal(with_hook.x_measured, without.x_measured)
    assert [s["j"] for s in steps] == list(range(len(without.t_ctrl)))
    np.testing.assert_array_equal(np.concatenate([s["t_true"] for s in steps]), without.t_true)
    np.testing.assert_array_equal(np.vstack([s["x_true"] for s in steps]), without.x_true)
    for key, field in (("x_measured", "x_measured"), ("u_applied", "u_applied"), ("u_command", "u_command"),
                       ("disturbance", "disturbance"), ("x_reference", "x_reference")):
        np.testing.assert_array_equal(np.array([s[key] for s in steps]), getattr(without, field))
    assert [s["t_ctrl"] for s in steps] == without.t_ctrl.tolist()
    # Each step's samples lie in (t_j, t_j + period] (step 0 also holds t = 0).
    for s in steps[1:]:
        assert np.all(s["t_true"] > s["t_ctrl"]) and np.all(s["t_true"] <= s["t_ctrl"] + 0.2 + 1e-12)


class TorqueAndForce:
    """Commands a force and a torque that change every control step (spins the body up, so attitude moves)."""

    def __init__(self):
        self.j = 0

    def step(self, t, x_measured):
        self.j += 1
        u = np.r_[0.01 * np.sin(self.j), -0.02 * np.cos(0.5 * self.j), 0.005, 0.004, -0.003 * self.j / 10, 0.002]
        return ControlStep(u, SolveInfo("open_loop", True), x_measured)


@pytest.mark.parametrize(("com_offset", "force_scale"), [(None, None), ((0.004, -0.001, -0.0025), None),
                                                         ((0.004, -0.001, -0.0025), (1.03, 0.97, 1.02))])
def test_plant_steps_equal_the_numpy_rk4_bit_for_bit(com_offset, force_scale):
    """The simulator's written-out plant steps (``_propagate_steps``) are :func:`oacli.model.rigid_body.propagate`
    (RK4, then the quaternion renormalised with w >= 0) with the delivered wrench (body-axis force scale and
    centre-of-mass torque, :func:`oacli.sim.actuators.delivered_wrench`) taken at each step's start: bit for bit
    against the numpy version, on a spinning body and uneven steps."""
    from oacli.model.rigid_body import propagate, theta_of
    from oacli.sim.actuators import delivered_wrench
    from oacli.sim.simulator import _propagate_steps

    rng = np.random.default_rng(5)
    theta = theta_of(TRUTH)
    for _ in range(5):
        x = np.r_[rng.normal(size=3), 0.05 * rng.normal(size=3), rng.normal(size=4), 0.2 * rng.normal(size=3)]
        x[6:10] /= np.linalg.norm(x[6:10])
        u = np.r_[0.2 * rng.normal(size=3), 0.02 * rng.normal(size=3)]
        steps = [0.016, 0.008, 0.016, 0.0123, 0.016]
        got = _propagate_steps([float(v) for v in x], [float(v) for v in u], TRUTH.mass_kg,
                               tuple(float(v) for v in TRUTH.inertia_kgm2), com_offset, steps, force_scale)
        for dt, sample in zip(steps, got, strict=True):
            u_step = delivered_wrench(u, x[6:10], None if force_scale is None else np.array(force_scale),
                                      None if com_offset is None else np.array(com_offset))
            x = propagate(x, u_step, theta, dt)
            np.testing.assert_array_equal(np.array(sample), x)


def test_plant_matches_an_accurate_integration_of_the_rigid_body():
    """Closed loop with a spinning body and 12.5 plant steps per control period (steps split at the control
    instants): the true state at every control instant is within 1e-9 of ``solve_ivp`` (DOP853, tight tolerances)
    of [Doerr2021] Eqs. 34-35 under the same held inputs."""
    from scipy.integrate import solve_ivp

    from oacli.model.rigid_body import dynamics, theta_of

    x0 = at_rest()
    x0[3:6] = [0.05, -0.02, 0.01]
    x0[6:10] = np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9])
    x0[10:13] = [0.05, -0.1, 0.08]
    tel = simulate(TorqueAndForce(), x0, TRUTH, duration_s=2.0, control_period_s=0.2, plant_period_s=0.016,
                   input_limits=LIMITS, sensors=SensorNoise(), disturbance=Disturbance.none(),
                   rng=np.random.default_rng(0))
    theta = theta_of(TRUTH)
    y = x0.copy()
    for j, t0 in enumerate(tel.t_ctrl):
        np.testing.assert_allclose(tel.x_true_ctrl[j], y, rtol=0, atol=1e-9)
        sol = solve_ivp(lambda _t, s, j=j: dynamics(s, tel.u_applied[j], theta), (t0, t0 + 0.2), y,
                        rtol=1e-12, atol=1e-14, method="DOP853")
        y = sol.y[:, -1]
    np.testing.assert_allclose(tel.x_true[-1], y, rtol=0, atol=1e-9)
