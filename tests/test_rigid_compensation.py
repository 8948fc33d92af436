"""The learned centre of mass and inertia tensor in the controllers (issue 30, item 4): the feed-forward of the
centre-of-mass moment, the attitude model with products of inertia, W's attitude part and the 4-parameter case."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from oacli.control.disturbance import attitude_disturbance
from oacli.control.reference_sampler import feedforward
from oacli.control.rigid_terms import (
    MAX_COMPENSATION_SHARE,
    RigidCompensator,
    com_moment_bound_Nm,
    planned_torque_limit_Nm,
)
from oacli.control.tracking import TrackingMPC, TrackingWeights
from oacli.control.tube_mpc import TubeMPC
from oacli.mission.configs import model_section, with_rigid_estimate
from oacli.model import quaternion as quat
from oacli.model.double_integrator import hover_error_model
from oacli.model.limits import MotionLimits
from oacli.model.robot_model import RobotModel
from oacli.reference import waypoint_reference
from oacli.sim.actuators import delivered_wrench
from oacli.sim.full_inertia import TensorPlant
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.types import InertialParams
from tests.model_helpers import ASTROBEE_INERTIA_KGM2

MASS = 9.583788668
INERTIA = np.array(ASTROBEE_INERTIA_KGM2)
FORCE = np.array([0.452, 0.216, 0.257])
TORQUE = np.array([0.0452, 0.0216, 0.0257])
LIMITS = MotionLimits(FORCE, TORQUE, np.full(3, 0.2), np.full(3, 0.1745))
WEIGHTS = TrackingWeights(*(np.full(3, w) for w in (10.0, 1.0, 10.0, 1.0, 1.0, 100.0)))
COM = np.array([0.03, -0.03, 0.03])  # a payload's centre of mass 5 cm off the geometric centre
DT = 0.2


def model(com=(0.0, 0.0, 0.0), com_std=(0.0, 0.0, 0.0), products=(0.0, 0.0, 0.0), products_std=(0.0, 0.0, 0.0),
          inertia_std=0.0) -> RobotModel:
    cov = np.diag([0.0, *(np.full(3, inertia_std**2))])
    return RobotModel(MASS, INERTIA, cov, FORCE, TORQUE, np.full(3, 0.2), np.full(3, 0.1745), 0.25,
                      com_offset_m=com, com_std_m=com_std, inertia_products_kgm2=products,
                      products_std_kgm2=products_std)


def rotated_tensor() -> np.ndarray:
    """A tensor with products: Astrobee's principal moments turned by 0.3 rad about (1, 2, 3)."""
    r = quat.to_rotation_matrix(quat.exp(0.3 * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)))
    return np.asarray(r @ np.diag(INERTIA) @ r.T)


def translating_reference():
    """1 m along x with the attitude held: the force is large, the reference torque zero."""
    return waypoint_reference(np.array([[0.0, 0.0, 0.0], [1.0, 0.3, -0.2]]),
                              np.array([[0.0, 0.0, -0.7071068, 0.7071068]] * 2), InertialParams(MASS, INERTIA),
                              speed_mps=0.15, accel_mps2=0.03, rate_radps=0.05, ang_accel_radps2=0.02, hold_s=1.0)


def fly(controller, ref, com=COM, tensor=None):
    return simulate(controller, ref.x[0], InertialParams(MASS, INERTIA), duration_s=ref.duration_s + 2.0,
                    control_period_s=DT, plant_period_s=1 / 62.5, input_limits=np.r_[FORCE, TORQUE],
                    sensors=SensorNoise(), disturbance=Disturbance(np.zeros(6), np.zeros(6)),
                    rng=np.random.default_rng(0), com_offset_m=com, inertia_tensor_kgm2=tensor)


def attitude_rms(tel, ref) -> float:
    from oacli.trajectory import sample_states

    x_ref = sample_states(ref, tel.t_true)
    phi = quat.error_vector(x_ref[:, 6:10], tel.x_true[:, 6:10])
    return float(np.sqrt(np.mean(np.sum(phi**2, axis=1))))


# -- the feed-forward in closed loop ----------------------------------------------------------------------------


def test_the_feedforward_cancels_a_known_com_moment_in_closed_loop():
    """The plant's thrust acts 5 cm from the centre of mass (sim/actuators.py: τ += (−c) × F_b): the standard MPC
    that knows c commands τ + c × F_b and tracks attitude far better than the one that does not."""
    ref = translating_reference()
    plain = TrackingMPC(ref, InertialParams(MASS, INERTIA), dt_s=DT, horizon=10, weights=WEIGHTS, limits=LIMITS)
    comp = RigidCompensator.of_model(model(com=COM), FORCE)
    assert comp is not None
    learned = TrackingMPC(ref, InertialParams(MASS, INERTIA), dt_s=DT, horizon=10, weights=WEIGHTS, limits=LIMITS,
                          rigid=comp)
    without, with_ = attitude_rms(fly(plain, ref), ref), attitude_rms(tel := fly(learned, ref), ref)
    assert with_ < 0.1 * without, (with_, without)
    assert comp.clipped_steps == 0
    assert np.all(np.abs(tel.u_command[:, 3:6]) <= TORQUE * (1 + 1e-12))  # τ_cmd within the actuator
    # what the plant delivers about the CoM is the MPC's τ_des: the commanded minus ĉ × F_b, plus (−c) × F_b
    k = len(tel.t_ctrl) // 2
    u = tel.u_command[k]
    q = tel.x_true[np.searchsorted(tel.t_true, tel.t_ctrl[k]), 6:10]
    delivered = delivered_wrench(u, q, None, COM)
    f_b = quat.to_rotation_matrix(q).T @ u[0:3]
    np.testing.assert_allclose(delivered[3:6], u[3:6] - np.cross(COM, f_b), atol=1e-15)


def test_the_tube_mpc_compensates_too_and_keeps_its_tube():
    from oacli.control.disturbance import DisturbanceSpec
    from oacli.control.tube_design import AncillaryWeights, design_translation_tube
    from tests.model_helpers import mass_model

    design = design_translation_tube(model=mass_model(MASS, 0.1), dt_s=DT, force_limit_N=np.full(3, 0.15),
                                     velocity_limit_mps=np.full(3, 0.2), weights=AncillaryWeights(5.0, 10.0, 2.0),
                                     spec=DisturbanceSpec(force_N=np.full(3, 0.002)), epsilon=0.005,
                                     epsilon_mode="absolute", facet_growth=0.05)
    ref = waypoint_reference(np.array([[0.0, 0.0, 0.0], [0.4, 0.2, -0.1]]),
                             np.array([[0.0, 0.0, -0.7071068, 0.7071068]] * 2), InertialParams(MASS, INERTIA),
                             speed_mps=0.08, accel_mps2=0.01, rate_radps=0.05, ang_accel_radps2=0.02, hold_s=1.0)
    runs = {}
    for name, rigid in (("plain", None), ("learned", RigidCompensator.of_model(model(com=COM), np.full(3, 0.15)))):
        ctrl = TubeMPC(ref, design, inertia_kgm2=INERTIA, horizon=5, prediction_step_s=1.0, weights=WEIGHTS,
                       limits=LIMITS, rigid=rigid)
        tel = fly(ctrl, ref)
        runs[name] = (attitude_rms(tel, ref), ctrl.history(), tel)
    assert runs["learned"][0] < 0.2 * runs["plain"][0], (runs["learned"][0], runs["plain"][0])
    h, tel = runs["learned"][1], runs["learned"][2]
    assert h.mode == ("mpc",) * len(h.t)
    assert np.all(h.tube_margin[1:] >= -1e-7)
    assert np.all(np.abs(tel.u_command[:, 3:6]) <= TORQUE * (1 + 1e-12))


# -- the attitude model with products of inertia ----------------------------------------------------------------


def test_linearised_attitude_model_with_a_full_tensor_matches_finite_differences():
    """hover_error_model's attitude block with J equals the derivative of one RK4 step of the nonlinear rigid body
    with that tensor (oacli.sim.full_inertia) at rest, in the chart φ = log(q₀ᵀ q)."""
    j = rotated_tensor()
    plant = TensorPlant(InertialParams(MASS, INERTIA), j)
    a, b = hover_error_model(InertialParams(MASS, np.diag(j)), DT, j)
    q0 = quat.normalize(np.array([0.1, -0.2, 0.3, 0.9]))

    def step(phi0, w0, tau):
        x = np.zeros(13)
        x[6:10] = quat.multiply(q0, quat.exp(phi0))
        x[10:13] = w0
        out = plant.propagate(x, np.r_[np.zeros(3), tau], plant.theta, DT)
        return np.r_[quat.error_vector(q0, out[6:10]), out[10:13]]

    eps, z = 1e-6, np.zeros(3)
    fd_a, fd_b = np.zeros((6, 6)), np.zeros((6, 3))
    for i in range(3):
        e = eps * np.eye(3)[i]
        fd_a[:, i] = (step(e, z, z) - step(-e, z, z)) / (2 * eps)
        fd_a[:, 3 + i] = (step(z, e, z) - step(z, -e, z)) / (2 * eps)
        fd_b[:, i] = (step(z, z, e) - step(z, z, -e)) / (2 * eps)
    np.testing.assert_allclose(a[6:, 6:], fd_a, atol=1e-8)
    np.testing.assert_allclose(b[6:, 3:], fd_b, rtol=1e-6, atol=1e-9)
    assert np.max(np.abs(b[9:12, 3:] - DT * np.diag(1.0 / np.diag(j)))) > 0.01  # the products matter here


def test_feedforward_with_a_tensor_is_eulers_equation():
    """τ = J ω̇ + ω × J ω ([Doerr2021] Eq. 35b): the tensor plant's ω̇ under that torque is the reference's."""
    j = rotated_tensor()
    rng = np.random.default_rng(3)
    x_ref = np.zeros((6, 13))
    x_ref[:, 6:10] = [0.0, 0.0, 0.0, 1.0]
    x_ref[:, 10:13] = rng.normal(scale=0.05, size=(6, 3))
    u = feedforward(x_ref, DT, InertialParams(MASS, np.diag(j)), j)
    plant = TensorPlant(InertialParams(MASS, INERTIA), j)
    for k in range(5):
        wdot = plant.dynamics(x_ref[k], u[k])[10:13]
        np.testing.assert_allclose(wdot, (x_ref[k + 1, 10:13] - x_ref[k, 10:13]) / DT, atol=1e-12)


# -- W's attitude part --------------------------------------------------------------------------------------------


def test_attitude_w_contains_the_worst_case_com_moment_at_every_vertex():
    """|δc × R(q)ᵀ F| over the vertices of the δc box (n_σ σ_c), the world force box and attitudes (random and the
    worst one) never exceeds W's centre-of-mass term, and the worst attitude reaches it."""
    sigma_c = np.array([0.004, 0.001, 0.002])
    m = model(com=COM, com_std=sigma_c)
    w = attitude_disturbance(m, FORCE, TORQUE, LIMITS.angular_velocity_radps, DT, n_sigma=2.0)
    rng = np.random.default_rng(7)
    rotations = list(quat.to_rotation_matrix(quat.normalize(rng.normal(size=(200, 4)))))
    worst = np.zeros(3)
    for signs_c in itertools.product((-1, 1), repeat=3):
        dc = 2.0 * sigma_c * np.array(signs_c)
        for signs_f in itertools.product((-1, 1), repeat=3):
            f = FORCE * np.array(signs_f)
            for r in rotations:
                worst = np.maximum(worst, np.abs(np.cross(dc, r.T @ f)))
            for i in range(3):  # the attitude that turns F onto e_i × δc: the bound is reached
                target = np.cross(np.eye(3)[i], dc)
                r = _rotation_taking(f, target)
                worst[i] = max(worst[i], abs(np.cross(dc, r.T @ f)[i]))
    assert np.all(worst <= w.com_term_Nm * (1 + 1e-12))
    np.testing.assert_allclose(worst, w.com_term_Nm, rtol=1e-9)
    assert np.all(w.products_term_Nm == 0.0) and np.all(w.inertia_term_Nm == 0.0)  # no σ there
    np.testing.assert_allclose(w.step_box[:, 1], w.com_term_Nm / INERTIA * DT)


def _rotation_taking(f, target):
    """R with R ê = f̂ where ê = target/|target|, i.e. Rᵀ f ∥ target."""
    a, b = target / np.linalg.norm(target), f / np.linalg.norm(f)
    v, c = np.cross(a, b), float(a @ b)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def test_attitude_w_inertia_and_products_terms():
    """The inertia term is Eq. 28's mass term for rotation; products' σ add δJ α_max and the gyroscopic term, and
    the products' torque covers |δJ ω̇ + ω × δJ ω| at the box's vertices."""
    m = model(products_std=np.array([0.002, 0.001, 0.003]), inertia_std=0.01)
    w = attitude_disturbance(m, FORCE, TORQUE, LIMITS.angular_velocity_radps, DT, n_sigma=2.0)
    alpha = TORQUE / (INERTIA - 0.02)
    np.testing.assert_allclose(w.inertia_term_Nm, 0.02 * alpha)
    rng = np.random.default_rng(1)
    for signs in itertools.product((-1, 1), repeat=3):
        dp = 2.0 * m.products_std_kgm2 * np.array(signs)
        dj = np.array([[0, dp[0], dp[1]], [dp[0], 0, dp[2]], [dp[1], dp[2], 0]])
        for _ in range(20):
            wdot = alpha * rng.uniform(-1, 1, 3)
            omega = LIMITS.angular_velocity_radps * rng.uniform(-1, 1, 3)
            assert np.all(np.abs(dj @ wdot + np.cross(omega, dj @ omega)) <= w.products_term_Nm)
    with pytest.raises(ValueError, match="not positive"):
        attitude_disturbance(model(inertia_std=0.1), FORCE, TORQUE, LIMITS.angular_velocity_radps, DT, 2.0)


def test_the_compensation_fits_in_the_actuator():
    """The MPC's torque limit is the actuator's less the compensation's worst case (capped at half the limit)."""
    bound = com_moment_bound_Nm(COM, FORCE)
    np.testing.assert_allclose(bound, np.sqrt(2) * 0.03 * np.linalg.norm(FORCE))
    planned = planned_torque_limit_Nm(TORQUE, bound)
    np.testing.assert_allclose(planned, TORQUE - np.minimum(bound, MAX_COMPENSATION_SHARE * TORQUE))
    small = com_moment_bound_Nm(np.array([0.0037, -0.0003, -0.0025]), FORCE)  # astrobee iss.config's offset
    assert np.all(small < 0.2 * TORQUE)
    np.testing.assert_allclose(planned_torque_limit_Nm(TORQUE, small), TORQUE - small)


# -- the 4-parameter case -----------------------------------------------------------------------------------------


def test_the_four_parameter_model_gives_todays_controllers():
    """A model without centre of mass and products has no compensator (the controllers take the θ-of-4 path,
    bit for bit); and a compensator with c = 0 and a diagonal tensor commands what that path commands."""
    m4 = model()
    assert not m4.has_rigid_body and RigidCompensator.of_model(m4, FORCE) is None
    assert RigidCompensator.of_model(m4.with_estimate(np.r_[15.0, INERTIA], np.eye(4) * 1e-4), FORCE) is None
    a0, b0 = hover_error_model(InertialParams(MASS, INERTIA), DT)
    a1, b1 = hover_error_model(InertialParams(MASS, INERTIA), DT, np.diag(INERTIA))
    np.testing.assert_array_equal(a0, a1)
    np.testing.assert_allclose(b0, b1, rtol=1e-15)
    ref = translating_reference()
    trivial = RigidCompensator(np.diag(INERTIA), np.zeros(3), TORQUE, TORQUE)
    outs = []
    for rigid in (None, trivial):
        ctrl = TrackingMPC(ref, InertialParams(MASS, INERTIA), dt_s=DT, horizon=10, weights=WEIGHTS, limits=LIMITS,
                           rigid=rigid)
        outs.append(fly(ctrl, ref, com=None).u_command)
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-9)


# -- the robot model and its handoff ------------------------------------------------------------------------------


def test_the_model_carries_the_rigid_body_through_the_mission_handoff():
    from oacli.config.robot import RobotConfig

    rigid = {"estimate": {"com_x_m": 0.01, "com_y_m": -0.02, "com_z_m": 0.005, "Ixy_kgm2": 0.002},
             "std": {"com_x_m": 1e-4, "com_y_m": 2e-4, "com_z_m": 3e-4, "Ixy_kgm2": 5e-5}}
    m = with_rigid_estimate(model(), rigid)
    np.testing.assert_array_equal(m.com_offset_m, [0.01, -0.02, 0.005])
    np.testing.assert_array_equal(m.com_std_m, [1e-4, 2e-4, 3e-4])
    np.testing.assert_array_equal(m.inertia_products_kgm2, [0.002, 0.0, 0.0])  # Ixz, Iyz not estimated: kept
    np.testing.assert_array_equal(m.products_std_kgm2, [5e-5, 0.0, 0.0])
    assert m.inertia_tensor_kgm2[0, 1] == m.inertia_tensor_kgm2[1, 0] == 0.002
    back = RobotConfig(**model_section(m), force_limit_N=FORCE, torque_limit_Nm=TORQUE).model()
    for name in ("com_offset_m", "com_std_m", "inertia_products_kgm2", "products_std_kgm2"):
        np.testing.assert_allclose(getattr(back, name), getattr(m, name), rtol=1e-15)
    assert m.with_estimate(np.r_[15.0, INERTIA], np.zeros((4, 4))).com_offset_m[1] == -0.02  # kept by an estimate
    with pytest.raises(ValueError, match="inertia_products_kgm2"):
        model(products=np.array([0.2, 0.0, 0.0]))  # |Ixy| > sqrt(Ixx Iyy): not positive definite


def test_a_clipped_compensation_degrades_the_track():
    """A track whose CoM compensation was clipped on some steps names it (``com_clipped``, degraded); none: no
    finding."""
    from oacli.stages.track_rigid import com_clip_finding

    assert com_clip_finding({"com_compensation": None}) is None
    assert com_clip_finding({"com_compensation": {"clipped_steps": 0}}) is None
    message = com_clip_finding({"com_compensation": {"clipped_steps": 3}})
    assert message is not None and "on 3 steps" in message

