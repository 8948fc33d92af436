"""Output-feedback tube MPC ([Mayne2006]): the observer, its estimation-error set S and the true-state tube T.

The sets are checked against simulation: a Monte Carlo of the observer with Gaussian noise truncated at the
configured bound (and worst-case bang-bang noise) never leaves S, and the true deviation of the closed loop
``ξ⁺ = A_K ξ − B K ε + w`` never leaves T; the invariance margins and ``R ⊕ S ⊆ T`` are checked by the set code.
"""

from __future__ import annotations

import numpy as np
import pytest

from oacli.control.disturbance import DisturbanceSpec
from oacli.control.observer import TranslationObserver, kalman_gain, observer_spec
from oacli.control.tube_design import AncillaryWeights, design_translation_tube
from oacli.model.double_integrator import double_integrator
from oacli.sets import rpi_margins
from tests.model_helpers import mass_model

DT, MASS = 0.2, 15.5
SIGMA = np.array([0.01, 0.00223606797749979])  # the flight's position and velocity noise (mission_iss.yaml)


def _axis(k_sigma: float = 3.0, gain: tuple[float, float] = (0.5, 0.3)):
    a, b = double_integrator(DT, 1.0 / MASS)
    spec = observer_spec(model=mass_model(MASS, 0.05), dt_s=DT, position_std_m=SIGMA[0], velocity_std_mps=SIGMA[1],
                         noise_sigmas=k_sigma, gain=gain, accel_std_mps2=0.01)
    design = design_translation_tube(
        model=mass_model(MASS, 0.05), dt_s=DT, force_limit_N=np.full(3, 0.15), velocity_limit_mps=np.full(3, 0.2),
        weights=AncillaryWeights(), spec=DisturbanceSpec(force_N=np.full(3, 0.005)),
        epsilon=0.05, observer=spec)
    return a, b, design


def test_kalman_gain_matches_scipy_riccati():
    """The steady-state gain from our doubling Riccati solver equals the one from scipy's Schur solver."""
    from scipy.linalg import solve_discrete_are

    a, _ = double_integrator(DT, 1.0 / MASS)
    ell = kalman_gain(a, DT, 0.01, *SIGMA)
    g = np.array([[0.5 * DT * DT], [DT]])
    q, r = 1e-4 * g @ g.T + 1e-18 * np.eye(2), np.diag(SIGMA**2)
    p = solve_discrete_are(a.T, np.eye(2), q, r)
    np.testing.assert_allclose(ell, p @ np.linalg.inv(p + r), rtol=1e-7)
    assert np.max(np.abs(np.linalg.eigvals((np.eye(2) - ell) @ a))) < 1.0


def test_sets_are_invariant_and_nested():
    _, _, design = _axis()
    for ax in design.axes:
        out = ax.output
        assert out is not None
        assert rpi_margins(out.a_error, out.s, out.w_error).min() >= 0.0
        assert rpi_margins(ax.a_closed, out.t, out.w_true).min() >= 0.0
        assert out.t.contains(out.lasso.minkowski_sum(out.s), tol=1e-12)
        assert out.s.contains(out.noise)  # ε_0 = −n_0 of an observer started on a measurement lies in S
    summary = design.summary()["output_feedback"]
    # T ⊇ S and the tightened bounds come from T (velocity) and K R (force).
    assert summary["true_tube_position_m"][0] > summary["error_set_position_m"][0] >= 0.03
    ax = design.axes[0]
    t_vel = ax.output.t.support(np.array([0.0, 1.0]))
    assert ax.velocity_bounds_mps[1] == pytest.approx(0.2 - t_vel, rel=1e-9)
    k = ax.gain[0]
    assert ax.force_bounds_N[1] == pytest.approx(0.15 - max(ax.output.lasso.support(k),
                                                            ax.output.lasso.support(-k)), rel=1e-9)


def _truncated_normal(rng: np.random.Generator, size: tuple[int, ...], k: float) -> np.ndarray:
    out = rng.standard_normal(size)
    bad = np.abs(out) > k
    while bad.any():
        out[bad] = rng.standard_normal(int(bad.sum()))
        bad = np.abs(out) > k
    return out


@pytest.mark.parametrize("noise", ["gaussian", "worst"])
def test_error_set_and_true_tube_cover_a_monte_carlo_of_the_observer(noise):
    """200 runs × 300 steps of the closed loop with the observer of the design; noise within 3σ (Gaussian truncated
    at the bound, or bang-bang at the bound: the adversarial case), disturbance uniform in W. The estimation
    error stays in S and the true deviation from the nominal in T at every step; the realised extent reaches a
    fair share of the bound (the sets are not vacuous)."""
    a, b, design = _axis()
    ax = design.axes[0]
    out = ax.output
    k_sigma = 3.0
    rng = np.random.default_rng(7)
    runs, steps = 200, 300
    w_half = ax.disturbance.half_widths
    obs = TranslationObserver(a, b, out.observer_gain, DT)
    ell, a_err = out.observer_gain, out.a_error
    bk = b @ ax.gain
    xi = np.zeros((runs, 2))  # true deviation x − z (nominal held at the origin)
    y0 = SIGMA * (_truncated_normal(rng, (runs, 2), k_sigma) if noise == "gaussian"
                  else k_sigma * rng.choice([-1.0, 1.0], (runs, 2)))
    eps = -y0  # observer started on the first measurement
    worst_s = worst_t = -np.inf
    reach = np.zeros(2)
    for _ in range(steps):
        if noise == "gaussian":
            n = SIGMA * _truncated_normal(rng, (runs, 2), k_sigma)
        else:
            n = SIGMA * k_sigma * rng.choice([-1.0, 1.0], (runs, 2))
        w = w_half * rng.uniform(-1.0, 1.0, (runs, 2))
        xi = xi @ ax.a_closed.T - eps @ bk.T + w  # u = K (x̂ − z) = K (ξ − ε)
        eps = eps @ a_err.T + w @ (np.eye(2) - ell).T - n @ ell.T
        worst_s = max(worst_s, float(np.max(eps @ out.s.a.T - out.s.b)))
        worst_t = max(worst_t, float(np.max(xi @ out.t.a.T - out.t.b)))
        reach = np.maximum(reach, np.max(np.abs(eps), axis=0))
    assert worst_s <= 1e-12
    assert worst_t <= 1e-12
    s_ext = np.array([out.s.support(np.array([1.0, 0.0])), out.s.support(np.array([0.0, 1.0]))])
    assert np.all(reach > (0.3 if noise == "gaussian" else 0.6) * s_ext)
    # The observer class runs the same recursion.
    x_true = np.array([0.3, -0.05])
    obs.applied(np.zeros(3))
    y = np.concatenate([np.full(3, x_true[0]), np.full(3, x_true[1])])
    first = obs.update(0.0, y + 0.01)
    obs.applied(np.zeros(3))
    x_next = a @ x_true
    second = obs.update(DT, np.concatenate([np.full(3, x_next[0]), np.full(3, x_next[1])]))
    pred = a @ first[[0, 3]]
    np.testing.assert_allclose(second[[0, 3]], pred + ell @ (x_next - pred), rtol=1e-12)


def test_exits_are_counted_against_the_tube_in_force():
    """After a redesign beyond W the promise is the new design's tube: an error
    outside the first tube but inside the second counts only on the steps the first one was in force."""
    from oacli.stages.track_tube import tube_exits_in_force

    def sf_design(force_n: float):
        return design_translation_tube(
            model=mass_model(MASS), dt_s=DT, force_limit_N=np.full(3, 0.15), velocity_limit_mps=np.full(3, 0.2),
            weights=AncillaryWeights(), spec=DisturbanceSpec(force_N=np.full(3, force_n)), epsilon=0.05)

    small, large = sf_design(0.002), sf_design(0.02)
    p_small = small.axes[0].promise.support(np.array([1.0, 0.0]))
    p_large = large.axes[0].promise.support(np.array([1.0, 0.0]))
    assert p_large > 2 * p_small
    k = 10
    predicted = np.zeros((k, 6))
    states = np.zeros((k, 6))
    states[:, 0] = 0.5 * (p_small + p_large)  # outside the small tube, inside the large one
    index = np.array([0] * 4 + [1] * 6)
    assert tube_exits_in_force([small, large], index, states, predicted) == 4
    assert tube_exits_in_force([small, large], np.zeros(k, dtype=int), states, predicted) == k
    # A measured state gets the noise box on top: 0 exits once the box covers the excess.
    box = np.tile([p_large, 0.0], (3, 1))
    assert tube_exits_in_force([small, large], index, states, predicted, box) == 0


def test_rate_observer_follows_euler_and_attenuates_noise():
    """The body-rate observer predicts with Euler's equations (a torque-free spin about a principal axis stays
    put; a torque changes the rate by τ dt / I) and passes white rate noise at about √(l/(2 − l)) of its σ."""
    from oacli.control.observer import RateObserver

    inertia = np.array([0.15, 0.14, 0.16])
    obs = RateObserver(inertia, 0.3, DT)
    w0 = np.array([0.0, 0.0, 0.1])
    obs.update(0.0, w0)
    obs.applied(np.array([0.01, 0.0, 0.0]))
    pred = w0 + DT * (np.array([0.01, 0.0, 0.0]) - np.cross(w0, inertia * w0)) / inertia
    np.testing.assert_allclose(obs.update(DT, pred), pred, rtol=1e-12)
    rng = np.random.default_rng(3)
    obs = RateObserver(inertia, 0.3, DT)
    sigma, est = 0.0158, []
    for j in range(4000):
        obs.applied(np.zeros(3))
        est.append(obs.update(j * DT, sigma * rng.standard_normal(3)))
    ratio = np.std(np.array(est)[100:]) / sigma
    assert ratio == pytest.approx(np.sqrt(0.3 / 1.7), rel=0.08)


def test_observer_without_sensor_noise_is_refused_naming_the_field():
    from pathlib import Path

    from oacli.config import config_from_dict, load_config
    from oacli.errors import ConfigError

    data = load_config(Path(__file__).resolve().parents[1] / "configs" / "iss_reswarm_tube.yaml").model_dump(
        mode="json")
    data["controller"]["tube"]["observer"] = {"enabled": True}
    data["sensors"] = {"position_std_m": 0.0, "velocity_std_mps": 0.002}
    with pytest.raises(ConfigError, match=r"controller\.tube\.observer\.enabled.*sensors\.position_std_m > 0"):
        config_from_dict(data, source="test")
    data["sensors"]["position_std_m"] = 0.01
    assert config_from_dict(data, source="test").controller.tube.observer.enabled
