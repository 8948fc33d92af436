"""RATTLE's information term over chosen entries of the full rigid body (oacli.excitation.rattle_full)."""

from __future__ import annotations

import numpy as np
import pytest

from oacli.excitation.information_full import FullInformationTerm, fisher_information_full, ideal_theta
from oacli.excitation.rattle import InformationAwarePlanner, InformationWeighting
from oacli.excitation.rattle_full import entry_estimate, full_weighting
from tests.test_rattle import JEM, P0, PLANNER_LIMITS, RATTLE_MODEL, TRUTH, B, C, state

EXTRA = np.r_[np.zeros(6), np.ones(6)]
PRIOR_STD = np.r_[np.sqrt(np.diag(P0)), np.full(3, 0.005), np.full(3, 0.01), np.full(6, 0.05)]


def _planner(term: FullInformationTerm | None) -> InformationAwarePlanner:
    return InformationAwarePlanner(state(C), horizon=40, dt_s=0.3, limits=PLANNER_LIMITS, measurement=RATTLE_MODEL,
                                   scene=JEM, iterations=3, information=term)


def _reward(fim: np.ndarray, std: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    return gamma * 0.5 * np.log1p(np.diag(fim) * std**2)


def test_weights_and_entry_estimates() -> None:
    groups = ("mass", "inertia", "com", "force_scale")
    w = full_weighting(InformationWeighting(), groups, {"com": 20.0, "force_scale": 10.0},
                       {"com": 5e-4, "force_scale": 2e-3})
    np.testing.assert_array_equal(w.gamma0, [50, 20, 20, 20, 20, 20, 20, 10, 10, 10])
    np.testing.assert_array_equal(w.floor, [0.03, 1e-4, 1e-4, 1e-4, 5e-4, 5e-4, 5e-4, 2e-3, 2e-3, 2e-3])
    term = FullInformationTerm(groups, EXTRA, PRIOR_STD, PLANNER_LIMITS.input)
    theta, std = entry_estimate(TRUTH, np.full(4, 0.1), term)
    np.testing.assert_array_equal(std, np.r_[np.full(4, 0.1), np.full(3, 0.01), np.full(3, 0.05)])
    assert np.array_equal(theta, ideal_theta(TRUTH, EXTRA))
    # A filter's full estimate: its σ where it estimates the entry (variance > 0), the prior's elsewhere.
    cov = np.diag(np.r_[np.full(4, 1e-2), np.zeros(3), np.full(3, 4e-6), np.zeros(6)])
    full_theta = ideal_theta(TRUTH, np.r_[np.zeros(3), 0.004, 0.0, -0.002, np.ones(6)])
    theta, std = entry_estimate(TRUTH, np.full(4, 0.1), term, (full_theta, cov))
    np.testing.assert_allclose(std, np.r_[np.full(4, 0.1), np.full(3, 2e-3), np.full(3, 0.05)])
    assert theta[7] == 0.004
    _, std4 = entry_estimate(TRUTH, np.full(4, 0.1), term, (TRUTH, np.eye(4)))  # a 4-parameter filter
    np.testing.assert_array_equal(std4, np.r_[np.full(4, 0.1), np.full(3, 0.01), np.full(3, 0.05)])
    with pytest.raises(ValueError, match="mass and inertia"):
        FullInformationTerm(("mass", "com"), EXTRA, PRIOR_STD, PLANNER_LIMITS.input)


def test_planner_with_the_full_term() -> None:
    sigma = np.sqrt(np.diag(P0))
    gamma = InformationWeighting().weights(sigma)
    legacy = _planner(None).plan(state(B), TRUTH, sigma, gamma)
    # Mass and inertia through the full model's information and its difference gradient: the same plan.
    same = _planner(FullInformationTerm(("mass", "inertia"), EXTRA, PRIOR_STD, PLANNER_LIMITS.input)).plan(
        state(B), TRUTH, sigma, gamma)
    assert np.max(np.abs(same.trajectory.u - legacy.trajectory.u)) < 1e-6 * np.max(PLANNER_LIMITS.input)
    assert same.information_reward == pytest.approx(legacy.information_reward, rel=1e-8)
    # With the CoM informed, the plan gathers more CoM information (by its own measure) than the 4-entry plan.
    groups = ("mass", "inertia", "com")
    w = full_weighting(InformationWeighting(), groups, {"com": 20.0}, {"com": 5e-4})
    std = np.r_[sigma, PRIOR_STD[7:10]]
    g = w.weights(std)
    assert np.all(g[4:] > 0)
    com_plan = _planner(FullInformationTerm(groups, EXTRA, PRIOR_STD, PLANNER_LIMITS.input)).plan(
        state(B), TRUTH, std, g)
    assert np.all(np.abs(com_plan.trajectory.u) <= PLANNER_LIMITS.input * (1 + 1e-9))
    assert np.all(JEM.in_keep_in(com_plan.trajectory.x[:, 0:3]))
    f_legacy = fisher_information_full(state(B), legacy.trajectory.u[:-1], ideal_theta(TRUTH, EXTRA), 0.3,
                                       RATTLE_MODEL, groups).fim
    assert com_plan.information.shape == (7, 7)
    assert _reward(com_plan.information, std, g)[4:].sum() > _reward(f_legacy, std, g)[4:].sum()
    assert com_plan.information_reward == pytest.approx(_reward(com_plan.information, std, g).sum(), rel=1e-12)


@pytest.mark.slow
def test_closed_loop_with_the_full_term_keeps_the_entries_weights() -> None:
    from oacli.excitation.oracle import CramerRaoOracle
    from oacli.excitation.rattle_loop import run_rattle
    from oacli.sim.sensors import Disturbance, SensorNoise
    from oacli.types import InertialParams

    groups = ("mass", "inertia", "com")
    term = FullInformationTerm(groups, EXTRA, PRIOR_STD, PLANNER_LIMITS.input)
    weighting = full_weighting(InformationWeighting(), groups, {"com": 20.0}, {"com": 5e-4})
    run = run_rattle(
        _planner(term), CramerRaoOracle(TRUTH, P0, RATTLE_MODEL, state(B)), weighting, state(B),
        InertialParams(TRUTH[0], TRUTH[1:]), duration_s=24.0, replan_period_s=12.0, control_period_s=0.2,
        plant_period_s=1 / 62.5, input_limits=PLANNER_LIMITS.input,
        feedback_q=np.r_[[10.0] * 3, [1.0] * 3, [10.0] * 3, [1.0] * 3], feedback_r=np.r_[[1.0] * 3, [100.0] * 3],
        sensors=SensorNoise(), disturbance=Disturbance.none(), rng=np.random.default_rng(0),
    )
    assert len(run.replans) == 2
    for r in run.replans:
        assert r.std_entries is not None and r.gamma_entries is not None and r.std_entries.size == 7
        np.testing.assert_array_equal(r.gamma, r.gamma_entries[:4])
        np.testing.assert_array_equal(r.std, r.std_entries[:4])
        np.testing.assert_array_equal(r.std_entries[4:], PRIOR_STD[7:10])  # the oracle knows no CoM: its prior σ
        assert np.all(r.gamma_entries[4:] > 0) and r.plan.information.shape == (7, 7)
    # The oracle's σ of mass and inertia fall, so their weights decay; the CoM's (prior σ) stay.
    assert np.all(run.replans[1].gamma_entries[:4] <= run.replans[0].gamma_entries[:4])
    np.testing.assert_array_equal(run.replans[1].gamma_entries[4:], run.replans[0].gamma_entries[4:])
