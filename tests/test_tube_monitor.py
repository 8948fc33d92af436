"""Beyond W: the monitor measures the realised one-step disturbance, detects when it leaves W and responds
(redesign with the measured bound, safe hold, or log only), on the rigid-body plant in closed loop."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.control.disturbance import DisturbanceSpec
from oacli.control.tube_design import AncillaryWeights, design_translation_tube
from oacli.control.tube_monitor import TubeMonitor, extra_box_for, half_widths
from oacli.control.tube_mpc import TubeMPC
from oacli.errors import InfeasibleError
from oacli.model.double_integrator import double_integrator
from oacli.reference import waypoint_reference
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.types import InertialParams
from tests.model_helpers import mass_model
from tests.test_tube_mpc import DT, INERTIA, LIMITS, MASS, TERMINAL, U_TUBE, V_MAX, WEIGHTS, reswarm_design

TRUTH_MASS = 9.583788668
ACTUATOR = LIMITS.force_N


def redesign_fn(mass_std=0.1, force=0.002):
    def redesign(extra):
        spec = DisturbanceSpec(force_N=np.full(3, force), box_position_m=extra[:, 0],
                               box_velocity_mps=extra[:, 1])
        return design_translation_tube(model=mass_model(MASS, mass_std), dt_s=DT, force_limit_N=U_TUBE,
                                       velocity_limit_mps=V_MAX,
                                       weights=AncillaryWeights(5.0, 10.0, 2.0), spec=spec, epsilon=0.005,
                                       max_terms=200)
    return redesign


@pytest.fixture(scope="module")
def design():
    return reswarm_design()


@pytest.fixture(scope="module")
def reference():
    return waypoint_reference(np.array([[0.0, 0.0, 0.0], [0.4, 0.1, 0.0]]), np.array([[0.0, 0.0, 0.0, 1.0]] * 2),
                              InertialParams(MASS, INERTIA), speed_mps=0.05, accel_mps2=0.01, rate_radps=0.05,
                              ang_accel_radps2=0.02, hold_s=1.0)


def monitor(design, reference, response="redesign", **kw):
    def factory(d):
        return TubeMPC(reference, d, inertia_kgm2=INERTIA, horizon=5, prediction_step_s=1.0,
                       weights=WEIGHTS, limits=LIMITS, terminal=TERMINAL)
    return TubeMonitor(factory, design, response=response, actuator_force_limit_N=ACTUATOR,
                       redesign=redesign_fn() if response == "redesign" else None, **kw)


def fly(ctrl, reference, force_bias, seconds=12.0, random=0.0, seed=0):
    bias = np.r_[np.asarray(force_bias, dtype=float) * np.ones(3), np.zeros(3)]
    return simulate(ctrl, reference.x[0], InertialParams(TRUTH_MASS, INERTIA), duration_s=seconds,
                    control_period_s=DT, plant_period_s=1 / 62.5, input_limits=np.r_[LIMITS.force_N, LIMITS.torque_Nm],
                    sensors=SensorNoise(), disturbance=Disturbance(bias, np.r_[np.full(3, random), np.zeros(3)]),
                    rng=np.random.default_rng(seed))


def w_vertex_force(design) -> float:
    """The constant force (on the true mass) whose one-step velocity change is W's velocity half-width."""
    return float(half_widths(design)[0, 1] * TRUTH_MASS / DT)


def measured_w(tel, design):
    """Independent: x_k − (A x_{k−1} + B u_{k−1}) per axis from the telemetry (model mass, applied force)."""
    a, b = double_integrator(DT, 1.0 / MASS)
    out = np.full((len(tel.t_ctrl), 3, 2), np.nan)
    for i in range(3):
        x = tel.x_measured[:, [i, i + 3]]
        out[1:, i] = x[1:] - x[:-1] @ a.T - tel.u_applied[:-1, i : i + 1] @ b.T
    return out


def test_disturbances_inside_w_are_measured_and_never_flagged(design, reference):
    ctrl = monitor(design, reference)
    tel = fly(ctrl, reference, 0.0, random=0.002, seed=4)
    rec = ctrl.disturbance_record()
    np.testing.assert_array_equal(rec.t, tel.t_ctrl)
    np.testing.assert_allclose(rec.w, measured_w(tel, design), atol=1e-15, equal_nan=True)
    assert np.isnan(rec.margin[0]) and np.all(rec.margin[1:] >= 0.0)
    assert not rec.violated.any() and ctrl.events == [] and ctrl.redesigns == 0
    assert np.abs(rec.w[1:]).max(axis=0).min() > 0.0
    np.testing.assert_allclose(rec.w_half_widths, np.broadcast_to(half_widths(design), rec.w.shape))
    # Without a response the monitor is transparent: the same inputs as the bare TubeMPC.
    bare = monitor(design, reference).controllers[0]
    tel_bare = fly(bare, reference, 0.0, random=0.002, seed=4)
    np.testing.assert_array_equal(tel.u_command, tel_bare.u_command)


def test_a_constant_disturbance_at_twice_w_is_redesigned_for_and_then_kept_in_the_new_tube(design, reference):
    force = 2.0 * w_vertex_force(design)
    ctrl = monitor(design, reference)
    tel = fly(ctrl, reference, force)
    rec = ctrl.disturbance_record()
    (event,) = ctrl.events
    assert event.response == "redesign" and event.t == pytest.approx(DT) and ctrl.redesigns == 1
    assert event.redesign_time_s > 0
    # The first measured step is beyond W (about twice its velocity half-width), and flagged.
    assert rec.violated[1] and np.abs(rec.w[1, :, 1]).max() / half_widths(design)[0, 1] == pytest.approx(2.0, rel=0.05)
    # The new W contains the old one and 1.5 × the measured bound; later steps stay inside it.
    new = ctrl.design
    np.testing.assert_array_less(half_widths(design) - 1e-15, half_widths(new))
    assert np.all(half_widths(new) >= 1.5 * event.measured_max * (1 - 1e-9))
    assert not rec.violated[2:].any()
    np.testing.assert_array_equal(rec.design_index, [0] + [1] * (len(rec.t) - 1))
    # ... so the merged history keeps the state in the promised tube of the new design.
    h = ctrl.history()
    assert len(h.t) == len(tel.t_ctrl) and h.mode == ("mpc",) * len(h.t)
    tol = 1e-7 * np.max(new.lasso.h_vector)
    assert np.all(h.tube_margin[3:] >= -tol)
    np.testing.assert_allclose(tel.u_command[:, 0:3], h.nominal_force + h.ancillary_force, atol=1e-15)


def test_extra_box_grows_w_exactly_to_the_measured_bound(design):
    measured = 3.0 * half_widths(design)
    extra = extra_box_for(design, measured, 0.5)
    new = redesign_fn()(extra)
    np.testing.assert_allclose(half_widths(new), 4.5 * half_widths(design), rtol=1e-9)
    np.testing.assert_array_equal(extra_box_for(design, 0.1 * half_widths(design), 0.5), 0.0)


def test_hold_policy_latches_the_safe_hold(design, reference):
    ctrl = monitor(design, reference, response="hold")
    tel = fly(ctrl, reference, 2.0 * w_vertex_force(design))
    (event,) = ctrl.events
    assert event.response == "hold" and ctrl.held and ctrl.redesigns == 0
    modes = ctrl.history().mode
    k = int(np.searchsorted(tel.t_ctrl, event.t))
    assert set(modes[k:]) == {"hold"} and set(modes[:k]) == {"mpc"}
    assert all(info.status.startswith("hold") for info in tel.solve_info[k:])


def test_ignore_policy_counts_and_logs_only(design, reference):
    ctrl = monitor(design, reference, response="ignore")
    fly(ctrl, reference, 2.0 * w_vertex_force(design))
    rec = ctrl.disturbance_record()
    assert rec.violated.sum() > 10
    (event,) = ctrl.events
    assert event.response == "ignore" and not ctrl.held and ctrl.redesigns == 0
    assert set(ctrl.history().mode) == {"mpc"}


def test_a_disturbance_no_tube_can_cover_ends_in_the_safe_hold(design, reference):
    """30 × W needs more ancillary force than the actuators have: the redesign is infeasible, the hold latches
    and the robot is held near where it was (never flown off)."""
    force = 30.0 * w_vertex_force(design)
    with pytest.raises(InfeasibleError):
        redesign_fn()(extra_box_for(design, 30.0 * half_widths(design), 0.5))
    ctrl = monitor(design, reference)
    tel = fly(ctrl, reference, force, seconds=20.0)
    (event,) = ctrl.events
    assert event.response == "hold" and event.reason.startswith("redesign infeasible")
    assert ctrl.held and ctrl.redesigns == 0
    assert np.linalg.norm(tel.x_true[-1, 0:3] - reference.x[0, 0:3]) < 0.3


def test_too_many_redesigns_end_in_the_safe_hold(design, reference):
    ctrl = monitor(design, reference, max_redesigns=0)
    fly(ctrl, reference, 2.0 * w_vertex_force(design), seconds=2.0)
    (event,) = ctrl.events
    assert event.response == "hold" and "after 0 redesigns" in event.reason


def test_bad_monitor_settings_are_refused(design, reference):
    with pytest.raises(ValueError, match="response"):
        monitor(design, reference, response="panic")
    with pytest.raises(ValueError, match="redesign function"):
        TubeMonitor(lambda d: None, design, response="redesign", actuator_force_limit_N=ACTUATOR)
