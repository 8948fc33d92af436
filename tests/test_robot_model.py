"""The robot model that flows through the stages (:mod:`oacli.model.robot_model`) and its config builders.

Closed-form references: the [Doerr2021] Eq. 28 interval ``θ_i ± n_σ σ_i`` against the tube's disturbance bound
and the design limits' ``m_upper``; the estimate round trip; every validation error names its field. The builders
(``robot_model``, ``truth_model``, the priors) are checked against the preset's YAML numbers, and every key the
model's σ used to be read from is refused with the one line naming its new place (issue 28).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from oacli.config import config_from_dict, dump_config, load_config
from oacli.config.prior import PriorConfig
from oacli.control.disturbance import mass_uncertainty_bound, step_gain
from oacli.errors import ConfigError
from oacli.model.limits import MotionLimits
from oacli.model.robot_model import RobotModel
from oacli.planning.translational import TranslationalTrajectory
from oacli.reference_limits import ReferenceMargin
from oacli.stages import design_limits, settings

REPO = Path(__file__).resolve().parents[1]
INERTIA = np.array([0.153427995, 0.14271405, 0.162302759])  # [AstrobeeFSW] iss.config


def model(**kw) -> RobotModel:
    args = dict(mass_kg=9.5, inertia_kgm2=INERTIA, covariance=np.diag([0.25, 1e-4, 2e-4, 3e-4]),
                force_limit_N=[0.849, 0.406, 0.486], torque_limit_Nm=[0.0849, 0.0406, 0.0486],
                velocity_limit_mps=[0.2] * 3, angular_velocity_limit_radps=[0.1745] * 3, radius_m=0.25)
    args.update(kw)
    return RobotModel(**args)


def test_theta_std_and_limits_are_the_fields_in_order():
    m = model()
    np.testing.assert_array_equal(m.theta, [9.5, *INERTIA])
    np.testing.assert_allclose(m.std, [0.5, 0.01, math.sqrt(2e-4), math.sqrt(3e-4)], rtol=1e-15)
    assert m.mass_std_kg == 0.5
    np.testing.assert_array_equal(m.input_limits, [0.849, 0.406, 0.486, 0.0849, 0.0406, 0.0486])
    np.testing.assert_array_equal(m.rate_limits, [0.2] * 3 + [0.1745] * 3)
    assert isinstance(m.limits, MotionLimits)
    np.testing.assert_array_equal(m.limits.input, m.input_limits)
    np.testing.assert_array_equal(m.limits.rate, m.rate_limits)
    assert m.params.mass_kg == 9.5 and np.array_equal(m.params.inertia_kgm2, INERTIA)


def test_arrays_are_read_only_and_copied():
    inertia = INERTIA.copy()
    m = model(inertia_kgm2=inertia)
    inertia[0] = 1.0  # the caller's array is not the model's
    assert m.inertia_kgm2[0] == INERTIA[0]
    for name in ("inertia_kgm2", "covariance", "force_limit_N", "torque_limit_Nm", "velocity_limit_mps",
                 "angular_velocity_limit_radps", "theta"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(m, name)[0] = 1.0


@pytest.mark.parametrize("sigma_kg, n_sigma", [(0.5, 2.0), (0.0, 2.0), (1.2, 3.0), (0.3, 0.0)])
def test_mass_bounds_are_doerr_eq_28(sigma_kg, n_sigma):
    m = model(covariance=np.diag([sigma_kg**2, 1e-4, 1e-4, 1e-4]))
    lower, upper = m.mass_bounds_kg(n_sigma)
    assert lower == pytest.approx(9.5 - n_sigma * sigma_kg, rel=1e-14)
    assert upper == pytest.approx(9.5 + n_sigma * sigma_kg, rel=1e-14)
    # the design limits' m_upper and the tube's W (the lighter mass moves further) use the same interval
    assert ReferenceMargin(m, n_sigma).mass_upper_kg == upper
    assert m.parameter_interval("mass_kg", n_sigma) == (lower, upper)
    u_max, dt = 0.15, 0.2
    w = mass_uncertainty_bound(m, u_max, dt, n_sigma)
    np.testing.assert_allclose(w, u_max * (1.0 / lower - 1.0 / 9.5) * step_gain(dt), rtol=1e-12, atol=1e-18)


def test_parameter_intervals_of_the_inertias_are_their_sigma_bounds():
    m = model()
    for i, name in enumerate(("Ixx", "Iyy", "Izz")):
        lower, upper = m.parameter_interval(name, 3.0)
        assert lower == pytest.approx(INERTIA[i] - 3.0 * m.std[i + 1], rel=1e-14)
        assert upper == pytest.approx(INERTIA[i] + 3.0 * m.std[i + 1], rel=1e-14)
        assert m.inertia_upper_kgm2(3.0)[i] == upper
    with pytest.raises(ValueError, match="unknown parameter"):
        m.parameter_interval("Ixy", 2.0)
    with pytest.raises(ValueError, match="n_sigma"):
        m.parameter_interval("Ixx", -1.0)


def test_mass_bounds_refuse_a_non_positive_lower_mass():
    m = model(covariance=np.diag([25.0, 1e-4, 1e-4, 1e-4]))  # σ = 5 kg: 9.5 − 2·5 < 0
    with pytest.raises(ValueError, match="not positive"):
        m.mass_bounds_kg(2.0)
    assert m.mass_bounds_kg(1.0) == (4.5, 14.5)
    with pytest.raises(ValueError, match="n_sigma"):
        m.mass_bounds_kg(-1.0)


def test_with_estimate_round_trip_keeps_limits_and_geometry():
    m = model()
    assert m.with_estimate(m.theta, m.covariance) == m
    theta = np.array([15.2, 0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1, a payload
    cov = np.array([[0.04, 1e-4, 0, 0], [1e-4, 1e-6, 0, 0], [0, 0, 1e-6, 0], [0, 0, 0, 1e-6]])
    e = m.with_estimate(theta, cov)
    np.testing.assert_array_equal(e.theta, theta)
    np.testing.assert_array_equal(e.covariance, cov)
    assert e.mass_bounds_kg(2.0) == pytest.approx((15.2 - 0.4, 15.2 + 0.4), rel=1e-14)
    np.testing.assert_array_equal(e.input_limits, m.input_limits)
    np.testing.assert_array_equal(e.rate_limits, m.rate_limits)
    assert e.radius_m == m.radius_m
    assert e.with_estimate(m.theta, m.covariance) == m  # and back
    assert e != m


@pytest.mark.parametrize("key", ["mass_std_kg", "inertia_std_kgm2"])
def test_the_mission_priors_old_sigma_keys_are_refused_naming_the_variance(key):
    data = yaml.safe_load((REPO / "configs" / "mission_iss.yaml").read_text())
    data["mission"]["prior"][key] = 1.0
    with pytest.raises(ConfigError) as err:
        config_from_dict(data, source="test.yaml")
    assert err.value.problems == [f"test.yaml: mission.prior.{key}: 1.0: no longer a key: give the model's variances "
                                  "as one list variance: [m kg², Ixx, Iyy, Izz (kg·m²)²] (the unit of robot.variance)"]


# -- no bare mass in a core signature (issue 28) ------------------------------------------------------------

NUMERICAL_KERNELS: set[str] = set()
"""Public core functions that still take the mass as a number: none (docs/architecture.md, "The robot model"). The
tube, W, the observer, the design limits, the planners' double-integrator kernels (``RobotModel``), the excitation's
translation kernels and the lost-input model (θ), the simulator's plant and IMU, the reference feed-forward and the
flight's force-scale calibration (``InertialParams``) take a model; a new bare mass fails the test below."""
CORE_EXCLUDED = ("io", "commands", "stages", "mission", "campaign")


def bare_mass_signatures() -> set[str]:
    """``file:function`` of every public function in the core with a parameter named like a mass that is not
    annotated as a ``RobotModel``."""
    import ast

    root = REPO / "oacli"
    found = set()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] in CORE_EXCLUDED or rel.name == "cli.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            if node.name.startswith("_") and node.name != "__init__":
                continue
            args = node.args.posonlyargs + node.args.args + node.args.kwonlyargs
            if any("mass" in a.arg and "RobotModel" not in (ast.unparse(a.annotation) if a.annotation else "")
                   for a in args):
                found.add(f"{rel.as_posix()}:{node.name}")
    return found


def test_no_new_core_signature_takes_a_bare_mass():
    found = bare_mass_signatures()
    new = found - NUMERICAL_KERNELS
    assert not new, f"a bare mass in a core signature (take the RobotModel): {sorted(new)}"
    # the entry points of the issue take the model
    for name in ("control/tube_design.py:design_translation_tube", "control/tube_design.py:design_axis",
                 "control/disturbance.py:mass_uncertainty_bound", "control/disturbance.py:force_disturbance_bound",
                 "control/observer.py:observer_spec", "config/tube.py:tube_problems",
                 "reference_limits.py:mass_upper_bound_kg"):
        assert name not in found
    assert len(found) == len(NUMERICAL_KERNELS)  # the list is exact: remove a kernel from it once it takes the model


def test_a_translational_trajectory_carries_the_model_not_a_mass():
    with pytest.raises(TypeError, match=r"^model: expected a RobotModel, got float"):
        TranslationalTrajectory(np.array([0.0, 1.0]), np.zeros((2, 6)), np.zeros((1, 3)), 9.5)
    m = model()
    traj = TranslationalTrajectory.from_forces(np.zeros(6), [[0.95, 0.0, 0.0]], 2.0, m)
    assert traj.model is m and traj.mass_kg == 9.5
    assert traj.x[-1, 3] == pytest.approx(0.95 * 2.0 / 9.5, rel=1e-15)  # v = f h / m ([Doerr2021] Eq. 34)
    assert traj.x[-1, 0] == pytest.approx(0.5 * 0.95 / 9.5 * 2.0**2, rel=1e-15)


@pytest.mark.parametrize("kw, field", [
    (dict(mass_kg=0.0), "mass_kg"),
    (dict(mass_kg=float("nan")), "mass_kg"),
    (dict(inertia_kgm2=[0.1, -0.1, 0.1]), "inertia_kgm2"),
    (dict(inertia_kgm2=[0.1, 0.1, 0.3]), "inertia_kgm2"),  # 0.1 + 0.1 < 0.3
    (dict(inertia_kgm2=[0.1, 0.1]), "inertia_kgm2"),
    (dict(covariance=np.diag([-0.1, 1e-4, 1e-4, 1e-4])), "covariance"),
    (dict(covariance=np.eye(4) + np.triu(np.full((4, 4), 0.1), 1)), "covariance"),  # not symmetric
    (dict(covariance=np.array([[1, 2, 0, 0], [2, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])), "covariance"),  # λ = −1
    (dict(covariance=np.eye(3)), "covariance"),
    (dict(force_limit_N=[0.1, 0.0, 0.1]), "force_limit_N"),
    (dict(torque_limit_Nm=[0.1, 0.1, np.inf]), "torque_limit_Nm"),
    (dict(velocity_limit_mps=[0.2, 0.2]), "velocity_limit_mps"),
    (dict(angular_velocity_limit_radps=[-0.1, 0.1, 0.1]), "angular_velocity_limit_radps"),
    (dict(radius_m=-0.1), "radius_m"),
])
def test_invalid_models_are_refused_naming_the_field(kw, field):
    with pytest.raises(ValueError, match=f"^{field}"):
        model(**kw)


def test_with_estimate_refuses_a_non_physical_estimate():
    with pytest.raises(ValueError, match=r"^inertia_kgm2: the triangle inequality"):
        model().with_estimate([9.5, 0.1, 0.1, 0.25], np.zeros((4, 4)))
    with pytest.raises(ValueError, match=r"^theta"):
        model().with_estimate([9.5, 0.1, 0.1], np.zeros((4, 4)))


def test_a_zero_covariance_is_a_model_known_exactly():
    m = model(covariance=np.zeros((4, 4)))
    assert m.mass_bounds_kg(2.0) == (9.5, 9.5)
    np.testing.assert_array_equal(m.std, np.zeros(4))


# -- the config's models ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def iss():
    return load_config(REPO / "configs" / "iss_reswarm.yaml")


def test_robot_and_truth_models_from_the_preset(iss):
    raw = yaml.safe_load((REPO / "configs" / "iss_reswarm.yaml").read_text())
    robot = raw["robot"]
    m = settings.robot_model(iss)
    np.testing.assert_array_equal(m.theta, [robot["mass_kg"], *robot["inertia_kgm2"]])
    np.testing.assert_array_equal(m.covariance, np.zeros((4, 4)))  # no robot.variance: the robot model known
    np.testing.assert_array_equal(m.force_limit_N, robot["force_limit_N"])
    assert m.radius_m == iss.robot.radius_m
    t = settings.truth_model(iss)
    truth = iss.truth_params()
    np.testing.assert_array_equal(t.theta, [truth.mass_kg, *truth.inertia_kgm2])
    np.testing.assert_array_equal(t.covariance, np.zeros((4, 4)))
    np.testing.assert_array_equal(t.input_limits, m.input_limits)
    # the planner's robot is known: no derating through the estimator's prior variance; the robot model's σ_m
    # (robot.variance) is the planner's and the tube's
    limits = design_limits.planner_design_limits(iss)
    assert limits.margin.mass_std_kg == 0.0 and limits.margin.mass_ratio == 1.0
    data = yaml.safe_load(dump_config(iss))
    data["robot"]["variance"] = [4.0, 0.0, 0.0, 0.0]
    given = config_from_dict(data, source="test.yaml")
    assert settings.robot_model(given).mass_std_kg == 2.0
    margin = design_limits.planner_design_limits(given).margin
    assert margin.mass_upper_kg == iss.robot.mass_kg + 2 * 2.0


def test_priors_apply_their_section_mean_over_the_robot(iss):
    raw = yaml.safe_load((REPO / "configs" / "iss_reswarm.yaml").read_text())
    exc, est = raw["excitation"]["prior"], raw["estimation"]["prior"]
    e = settings.excitation_prior_model(iss)
    np.testing.assert_array_equal(e.theta, [exc["mass_kg"], *exc["inertia_kgm2"]])
    np.testing.assert_array_equal(np.diag(e.covariance), exc["variance"])
    p = settings.estimation_prior(iss)
    np.testing.assert_array_equal(p.theta, [est["mass_kg"], *est["inertia_kgm2"]])
    np.testing.assert_array_equal(np.diag(p.covariance), est["variance"])


def test_one_prior_config_one_spelling():
    a = PriorConfig(variance=(15.0, 0.005, 0.004, 0.003))
    np.testing.assert_array_equal(a.covariance(), np.diag([15.0, 0.005, 0.004, 0.003]))
    assert a.model_dump()["variance"] == (15.0, 0.005, 0.004, 0.003)


@pytest.mark.parametrize("path, value, new_place", [
    (("controller", "tube", "disturbance", "mass_std_kg"), 0.1, "robot.variance"),
    (("planner", "margin", "mass_std_kg"), 0.1, "robot.variance[0]"),
    (("excitation", "margin", "mass_std_kg"), 0.1, "excitation.prior.variance[0]"),
    (("estimation", "prior", "mass_variance_kg2"), 1.0, "variance: [m kg²"),
    (("excitation", "prior", "inertia_variance_kg2m4"), [0.1, 0.1, 0.1], "variance: [m kg²"),
])
def test_old_keys_of_the_model_sigma_are_refused_naming_the_new_place(iss, path, value, new_place):
    data = yaml.safe_load(dump_config(iss))
    section = data
    for key in path[:-1]:
        section = section.setdefault(key, {})
    section[path[-1]] = value
    with pytest.raises(ConfigError) as err:
        config_from_dict(data, source="test.yaml")
    lines = err.value.problems
    assert len(lines) == 1, lines
    assert ".".join(path) in lines[0] and new_place in lines[0] and "no longer a key" in lines[0]


@pytest.mark.parametrize("preset", ["doerr2021", "iss_reswarm", "iss_reswarm_tube"])
def test_presets_survive_the_dump_with_one_prior_type(preset):
    cfg = load_config(REPO / "configs" / f"{preset}.yaml")
    assert type(cfg.excitation.prior) is type(cfg.estimation.prior) is PriorConfig
    again = config_from_dict(yaml.safe_load(dump_config(cfg)), source="again")
    assert again == cfg
    np.testing.assert_array_equal(again.excitation.prior.covariance(), cfg.excitation.prior.covariance())
