"""Tube design with a relative ε: Z against the minimal box of F_∞ on the ReSWARM preset, the split
of the bound between F(α, s) and the facet reduction, the summary's figures, the flight settings' figures, and the
config fields (Raković, Kerrigan, Kouramas & Mayne 2005; Mayne, Seron & Raković 2005; [Doerr2021] Eq. 28)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.tube_design import (
    BASELINE_EPSILON,
    BASELINE_FACET_GROWTH,
    AncillaryWeights,
    design_axis,
    design_translation_tube,
    reduction_growth,
    split_relative_epsilon,
)
from oacli.errors import ConfigError, InfeasibleError
from oacli.sets import Polytope
from oacli.stages.settings import tube_design_from_config
from tests.conftest import REPO
from tests.model_helpers import mass_model

PRESET = REPO / "configs" / "iss_reswarm_tube.yaml"
E4 = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])  # ±position, ±velocity
MASS, DT = 9.5, 0.2
WEIGHTS = AncillaryWeights(5.0, 10.0, 2.0)  # ReSWARM ancillary LQR ([RattleCode] z_poly_calc)


def direct_f_inf_support(a_k, w, d, terms=4000):
    """h_{F_∞}(d) = Σ_k h_W((A_Kᵏ)ᵀ d), a plain 4000-term sum (ρ(A_K) ≈ 0.94 here: the rest is < 1e-100)."""
    d = np.atleast_2d(d)
    total, power = np.zeros(len(d)), np.eye(2)
    for _ in range(terms):
        total += w.support(d @ power)
        power = a_k @ power
    return total


def lp_support(p: Polytope, d: np.ndarray) -> float:
    """h_P(d) by HiGHS on the inequalities only."""
    res = linprog(-d, A_ub=p.a, b_ub=p.b, bounds=[(None, None)] * p.dim, method="highs")
    assert res.status == 0
    return -res.fun


def design(epsilon, mode="relative", growth=0.02, spec=None, **kw):
    spec = spec or DisturbanceSpec(force_N=np.full(3, 0.002))
    model = kw.pop("model", mass_model(MASS, 0.1))
    return design_translation_tube(model=model, dt_s=DT, force_limit_N=np.full(3, 0.15),
                                   velocity_limit_mps=np.full(3, 0.2), weights=WEIGHTS, spec=spec, epsilon=epsilon,
                                   epsilon_mode=mode, facet_growth=growth, **kw)


@pytest.fixture(scope="module")
def preset_design():
    return tube_design_from_config(load_config(PRESET))


# -- the ReSWARM preset ------------------------------------------------------------------------------------------


def test_preset_z_is_within_five_percent_of_the_minimal_box(preset_design, rng):
    """Z in use (after facet reduction) against the box hull of F_∞ from an independent direct sum: ≥ 1 (Z ⊇ F_∞),
    ≤ 1.05 in position and velocity on every axis, and Z ⊆ 1.05 F_∞ along 300 random directions too."""
    assert load_config(PRESET).controller.tube.rpi_epsilon == 0.05
    d = rng.standard_normal((300, 2))
    for ax in preset_design.axes:
        a_k, w = ax.a_closed, ax.disturbance.w
        box = direct_f_inf_support(a_k, w, E4)
        ratio = ax.z.support(E4) / box
        assert np.all(ratio >= 1 - 1e-12) and np.all(ratio <= 1.05), ratio
        assert ax.ratio_to_minimal_box == pytest.approx((ratio[:2].max(), ratio[2:].max()), rel=1e-10)
        assert ax.minimal_support["position"] == pytest.approx(box[0], rel=1e-12)
        assert ax.relative_bound <= 0.05
        assert np.all(ax.z.support(d) <= (1 + ax.relative_bound) * direct_f_inf_support(a_k, w, d) * (1 + 1e-12))
        for a_i, b_i in zip(ax.z.a, ax.z.b, strict=True):  # RPI, with LP support values: A_K Z ⊕ W ⊆ Z
            assert lp_support(ax.z, a_k.T @ a_i) + w.support(a_i) <= b_i
        assert ax.reduction.min_margin > 0  # room for the solver back-off of the lasso


def test_preset_tightened_bounds_and_what_they_gained(preset_design):
    """Ū = U ⊖ K Z and X̄ = X ⊖ Z from Z's support; both wider than with the flight settings' Z, and within the
    ideal Z = F_∞ (independent sums): the summary says so, and is plain JSON."""
    s = preset_design.summary()
    json.dumps(s, allow_nan=False)
    gain = s["tightening_gain"]
    assert gain["baseline"] == {"epsilon_mode": "absolute", "epsilon": BASELINE_EPSILON,
                                "facet_growth": BASELINE_FACET_GROWTH}
    for i, ax in enumerate(preset_design.axes):
        k = ax.gain[0]
        assert ax.force_bounds_N[1] == pytest.approx(0.15 - ax.z.support(k), rel=1e-12)
        assert ax.velocity_bounds_mps[1] == pytest.approx(0.2 - ax.z.support(np.array([0.0, 1.0])), rel=1e-12)
        ideal_force = 0.15 - direct_f_inf_support(ax.a_closed, ax.disturbance.w, k)[0]
        ideal_vel = 0.2 - direct_f_inf_support(ax.a_closed, ax.disturbance.w, np.array([0.0, 1.0]))[0]
        assert gain["ideal_force_N"][i][1] == pytest.approx(ideal_force, rel=1e-12)
        assert gain["ideal_velocity_mps"][i][1] == pytest.approx(ideal_vel, rel=1e-12)
        base = design(BASELINE_EPSILON, "absolute", BASELINE_FACET_GROWTH).axes[i]
        assert gain["baseline_force_N"][i] == list(base.force_bounds_N)
        assert gain["baseline_velocity_mps"][i] == list(base.velocity_bounds_mps)
        assert gain["force_gain_N"][i] == pytest.approx(ax.force_bounds_N[1] - base.force_bounds_N[1], rel=1e-12)
        assert gain["force_gain_N"][i] > 0.005 and gain["velocity_gain_mps"][i] > 0.001  # Z half as wide
        assert 0 <= gain["force_to_ideal_N"][i] <= 0.05 * (0.15 - ideal_force)  # K F_∞ ⊆ K Z ⊆ 1.05 K F_∞
        assert 0 <= gain["velocity_to_ideal_mps"][i] <= 0.05 * (0.2 - ideal_vel)
    assert s["rpi"]["epsilon"] == 0.05 and s["rpi"]["epsilon_mode"] == "relative"
    assert s["z_to_minimal_box"]["position"] == [ax.ratio_to_minimal_box[0] for ax in preset_design.axes]
    assert s["minimal_box_velocity_mps"] == [ax.minimal_support["velocity"] for ax in preset_design.axes]
    assert all(b <= 0.05 for b in s["rpi"]["relative_bound"])


def test_flight_settings_reproduce_the_figures_of_the_issue():
    """Absolute ε = 0.005 (rattle z_poly_calc) on the same W: F(α, s) is 1.93× the minimal box in position and
    1.90× in velocity, and the reduced Z (5 % growth) is larger still."""
    for ax in design(0.005, "absolute", 0.05).axes:
        box = direct_f_inf_support(ax.a_closed, ax.disturbance.w, E4)
        f = ax.rpi.z.support(E4) / box
        assert (f"{f[0]:.2f}", f"{f[2]:.2f}") == ("1.93", "1.90")
        assert ax.ratio_to_minimal_box[0] > f[0]
        assert ax.relative_bound == pytest.approx((1 / (1 - ax.rpi.alpha)) * (1 + ax.reduction.growth) - 1)


# -- the split of the relative bound -----------------------------------------------------------------------------


@pytest.mark.parametrize(("eps", "growth"), [(0.05, 0.02), (0.05, 0.5), (0.005, 0.02), (0.3, 0.0), (1.0, 0.1)])
def test_split_of_the_relative_bound(eps, growth):
    """(1 + ε_F)(1 + g) = 1 + ε with g ≤ facet_growth and g ≤ √(1 + ε) − 1; after F(α, s) (α ≤ ε_F/(1 + ε_F)) the
    reduction's growth is at least g and keeps (1 − α)⁻¹(1 + g') ≤ 1 + ε."""
    eps_f, g = split_relative_epsilon(eps, growth)
    assert (1 + eps_f) * (1 + g) == pytest.approx(1 + eps, rel=1e-14)
    assert 0 <= g <= min(growth, np.sqrt(1 + eps) - 1) + 1e-15 and eps_f > 0
    for alpha in np.linspace(0, eps_f / (1 + eps_f), 7):
        g_final = reduction_growth(eps, growth, alpha)
        assert g - 1e-14 <= g_final <= growth
        assert (1 + g_final) / (1 - alpha) <= (1 + eps) * (1 + 1e-14)


@settings(max_examples=8, deadline=None)
@given(st.floats(0.0, 0.3), st.floats(0.0005, 0.02), st.floats(0.02, 0.3), st.floats(0.0, 0.05),
       st.one_of(st.just(0.0), st.floats(1e-5, 0.002)))
def test_relative_design_property(mass_std, force, eps, growth, noise_v):
    """Random W (mass, force and velocity-noise terms): Z ⊇ F(α, s) ⊇ F_∞, Z ⊆ (1 + ε) F_∞ along the axes and
    K, Z is RPI, and the tightened bounds are within ε of the ideal ones (Z = F_∞), never beyond."""
    spec = DisturbanceSpec(force_N=np.full(3, force), noise_velocity_mps=np.full(3, noise_v))
    common = {"model": mass_model(MASS, mass_std), "dt_s": DT, "force_limit_N": 0.15, "velocity_limit_mps": 0.2,
              "weights": WEIGHTS, "spec": spec}
    ax = design_axis(1, epsilon=eps, epsilon_mode="relative", facet_growth=growth, **common)
    a_k, w = ax.a_closed, ax.disturbance.w
    dirs = np.vstack([E4, ax.gain, -ax.gain])
    h_inf = direct_f_inf_support(a_k, w, dirs)
    h = ax.z.support(dirs)
    assert np.all(h >= h_inf * (1 - 1e-12)) and np.all(h <= (1 + eps) * h_inf * (1 + 1e-12))
    assert ax.relative_bound <= eps * (1 + 1e-12)
    assert ax.z.contains(ax.rpi.z, tol=1e-12 * np.max(ax.z.b))
    assert ax.reduction.min_margin >= -1e-12 * np.max(ax.z.b)  # growth 0 keeps F(α, s): RPI up to rounding
    if not ax.feasible:  # W too large for the limits (a refusal of design_translation_tube): no bounds to compare
        return
    (_, u_ideal), (_, v_ideal) = ax.ideal_bounds()  # Z ⊇ F_∞: never wider than the ideal bounds, and close
    assert u_ideal - eps * (0.15 - u_ideal) * (1 + 1e-12) <= ax.force_bounds_N[1] <= u_ideal + 1e-15
    assert v_ideal == pytest.approx(0.2 - h_inf[2] - noise_v, rel=1e-12)
    assert v_ideal - eps * h_inf[2] * (1 + 1e-12) <= ax.velocity_bounds_mps[1] <= v_ideal + 1e-15


def test_design_names_the_term_limit_and_the_terms_needed():
    needed = design(0.05).axes[0].rpi.s
    with pytest.raises(InfeasibleError, match=rf"controller\.tube\.rpi_max_terms.*needs {needed} terms"):
        design(0.05, max_terms=needed - 1)
    assert design(0.05, max_terms=needed).axes[0].rpi.s == needed


# -- closed loop with the tight tube -----------------------------------------------------------------------------


@pytest.mark.parametrize(("eps", "truth_mass", "force_bias"), [
    (0.05, 9.3, 0.002),  # the preset's ε; lightest mass in 2σ and a constant worst-case force: a vertex of W
    (0.05, 9.7, -0.002),  # heaviest mass, the opposite vertex
    (0.01, 9.3, 0.002),  # a tighter tube (about 100 facets, smaller invariance margins)
])
def test_tight_tube_holds_under_disturbances_at_the_vertices_of_w(eps, truth_mass, force_bias):
    """TubeMPC with the relative-ε tube on the rigid-body plant, disturbance at W's vertices: the measured state
    stays in ẑ ⊕ Z at every step (the tube is tight but still invariant; the QP's lasso back-off absorbs the
    solver tolerance), and the force stays within U."""
    from oacli.control.tracking import TrackingWeights
    from oacli.control.tube_mpc import TerminalWeights, TubeMPC
    from oacli.model.limits import MotionLimits
    from oacli.reference import waypoint_reference
    from oacli.sim.sensors import Disturbance, SensorNoise
    from oacli.sim.simulator import simulate
    from oacli.types import InertialParams

    inertia = [0.153427995, 0.14271405, 0.162302759]  # astrobee iss.config
    limits = MotionLimits(np.array([0.452, 0.216, 0.257]), np.array([0.0452, 0.0216, 0.0257]), np.full(3, 0.2),
                            np.full(3, 0.1745))
    weights = TrackingWeights(*(np.full(3, v) for v in (50.0, 5.0, 10.0, 1.0, 0.1, 100.0)))  # rattle tube MPC
    tube = design(eps)
    ref = waypoint_reference(np.array([[10.8, -9.6, 4.8], [11.1, -9.4, 4.7]]),
                             np.array([[0.0, 0.0, -0.7071068, 0.7071068], [0.0, 0.0, 0.0, 1.0]]),
                             InertialParams(MASS, inertia), speed_mps=0.05, accel_mps2=0.01, rate_radps=0.05,
                             ang_accel_radps2=0.02, hold_s=1.0)
    ctrl = TubeMPC(ref, tube, inertia_kgm2=inertia, horizon=5, prediction_step_s=1.0, weights=weights,
                   limits=limits, terminal=TerminalWeights(np.full(3, 100.0), np.full(3, 10.0)))
    x0 = ref.x[0].copy()
    x0[0:3] += [0.01, -0.005, 0.003]
    tel = simulate(ctrl, x0, InertialParams(truth_mass, inertia), duration_s=ref.duration_s + 2.0,
                   control_period_s=DT, plant_period_s=1 / 62.5, input_limits=np.r_[limits.force_N, limits.torque_Nm],
                   sensors=SensorNoise(), disturbance=Disturbance(np.r_[np.full(3, force_bias), np.zeros(3)],
                                                                  np.zeros(6)), rng=np.random.default_rng(0))
    h = ctrl.history()
    assert h.mode == ("mpc",) * len(h.t)
    assert np.all(h.tube_margin[1:] >= -1e-7 * np.max(tube.lasso.h_vector))
    assert np.all(h.lasso_margin >= 0.0)
    assert np.all(np.abs(tel.u_command[:, 0:3]) <= 0.15 * (1 + 1e-6))
    assert np.linalg.norm(tel.x_true[-1, 0:3] - ref.x[-1, 0:3]) < 0.01


# -- config ------------------------------------------------------------------------------------------------------

runner = CliRunner()


def variant(tmp_path, **tube):
    data = yaml.safe_load(PRESET.read_text())
    data["controller"]["tube"].update(tube)
    path = tmp_path / "variant.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_config_epsilon_mode_defaults_to_relative_and_accepts_absolute(tmp_path):
    data = yaml.safe_load(PRESET.read_text())
    for key in ("rpi_epsilon", "rpi_epsilon_mode", "lasso_facet_growth"):
        del data["controller"]["tube"][key]
    path = tmp_path / "defaults.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    tube = load_config(path).controller.tube
    assert (tube.rpi_epsilon_mode, tube.rpi_epsilon, tube.lasso_facet_growth) == ("relative", 0.05, 0.02)
    assert load_config(variant(tmp_path, rpi_epsilon_mode="absolute", rpi_epsilon=0.005)).controller.tube \
        .rpi_epsilon_mode == "absolute"


def test_the_stage_designs_with_the_configured_epsilon_mode(tmp_path):
    """rpi_epsilon_mode: absolute reaches the design: the flight settings' s = 53 (not the relative rule's)."""
    cfg = load_config(variant(tmp_path, rpi_epsilon_mode="absolute", rpi_epsilon=0.005, lasso_facet_growth=0.05))
    ax = tube_design_from_config(cfg).axes[0]
    assert (ax.epsilon_mode, ax.rpi.mode) == ("absolute", "absolute")
    assert ax.rpi.s == design(0.005, "absolute", 0.05).axes[0].rpi.s


@pytest.mark.parametrize(("tube", "field"), [
    ({"rpi_epsilon_mode": "percent"}, "controller.tube.rpi_epsilon_mode"),
    ({"rpi_max_terms": 5000}, "controller.tube.rpi_max_terms"),
    ({"rpi_max_terms": 0}, "controller.tube.rpi_max_terms"),
])
def test_bad_epsilon_settings_name_the_field(tmp_path, tube, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_config(variant(tmp_path, **tube))


def test_track_refuses_when_the_set_needs_more_terms_than_allowed(tmp_path):
    """Exit 3, one message naming controller.tube.rpi_max_terms and the terms needed, no run folder."""
    needed = tube_design_from_config(load_config(PRESET)).axes[0].rpi.s
    result = runner.invoke(app, ["track", str(variant(tmp_path, rpi_max_terms=needed - 1)),
                                 "--runs-dir", str(tmp_path / "runs")])
    assert result.exit_code == 3, result.output
    assert "Traceback" not in result.output
    assert "controller.tube.rpi_max_terms" in result.stderr and f"needs {needed} terms" in result.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
