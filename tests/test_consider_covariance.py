"""The Schmidt consider covariance of the held parameter groups (oacli.estimation.consider).

Closed form: for ``y = Aθ + Bh + e`` with ``h ~ N(h₀, P_h)`` held at ``h₀``, the least-squares estimate's error has
covariance ``P + S P_h Sᵀ`` with ``P = (AᵀA)⁻¹``, ``S = −(AᵀA)⁻¹AᵀB`` ([Tapley2004] Ch. 6): exactly, and
by Monte Carlo. The batch problem's block-QR sensitivity equals the dense one and the re-solved nonlinear
estimator's finite difference; hostile inputs (a held entry confounded with an estimated one, one the data do not
see, rank-deficient data, nothing held, an unidentified covariance) behave as the closed form says.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from estimation_helpers import (
    CONTROL_PERIOD_S,
    PLANT_PERIOD_S,
    SENSORS,
    Playback,
    exciting_inputs,
    initial_state,
    records,
    settings,
)

from oacli.estimation.batch import estimate_batch
from oacli.estimation.batch_model import FullModel, full_prior
from oacli.estimation.batch_problem import BatchProblem
from oacli.estimation.consider import (
    AugmentedModel,
    batch_sensitivity,
    consider_covariance,
    consider_held,
    held_index,
    linear_sensitivity,
)
from oacli.estimation.manifold import TANGENT_DIM
from oacli.estimation.rigid_parameters import GROUPS, ParameterSet, inertia_tensor, phi_from_theta_full
from oacli.sim.sensors import Disturbance
from oacli.sim.simulator import simulate
from oacli.stages.estimate_rigid import apply_physical_std, consider_run
from oacli.types import InertialParams, ParameterEstimate

TRUTH = np.array([15.0, 0.1464, 0.1376, 0.1604, 0.0, 0.0, 0.0, 0.0037, -0.0003, -0.0025,
                  1.03, 0.97, 1.02, 1.0, 1.0, 1.0])
PRIOR = ParameterEstimate(0.0, [14.0, 0.15, 0.15, 0.15], np.diag([1.0, 4e-4, 4e-4, 4e-4]), "prior")
EXTRA_STD = np.r_[np.full(3, 0.005), np.full(3, 0.01), np.full(6, 0.05)]
HELD_DEFAULT = ("mass", "inertia", "com", "force_scale")  # the default mission's set: products, torque scale held


def _model(groups=HELD_DEFAULT, fixed_shift: np.ndarray | None = None) -> FullModel:
    mean, cov = full_prior(PRIOR.theta, PRIOR.covariance, np.r_[np.zeros(6), np.ones(6)], EXTRA_STD)
    fixed = mean if fixed_shift is None else mean + fixed_shift
    return FullModel(ParameterSet.build(groups, fixed), fixed, cov)


def _linear_case(seed: int = 0):
    rng = np.random.default_rng(seed)
    m, n, n_h = 40, 3, 2
    a = rng.normal(size=(m, n))
    b = rng.normal(size=(m, n_h)) + 0.8 * a[:, :n_h]  # held columns correlated with the estimated ones
    root = rng.normal(size=(n_h, n_h))
    return a, b, root @ root.T + 0.1 * np.eye(n_h)


def test_linear_gaussian_closed_form_and_monte_carlo():
    """P and S from the QR of [A, B] equal (AᵀA)⁻¹ and −(AᵀA)⁻¹AᵀB; over 20000 draws of h ~ N(h₀, P_h) and the
    noise, the estimate's error covariance is P + S P_h Sᵀ (each variance within 5 %, the whitened errors' mean
    square within 3 % of n), while P alone understates it."""
    a, b, p_h = _linear_case()
    p, s = linear_sensitivity(a, b)
    info_inv = np.linalg.inv(a.T @ a)
    np.testing.assert_allclose(p, info_inv, rtol=1e-10)
    np.testing.assert_allclose(s, -info_inv @ a.T @ b, rtol=1e-10, atol=1e-13)
    expected = consider_covariance(p, s, p_h)
    np.testing.assert_allclose(expected, info_inv + info_inv @ a.T @ b @ p_h @ b.T @ a @ info_inv, rtol=1e-10)
    rng = np.random.default_rng(1)
    theta, h0 = np.array([1.0, -2.0, 0.5]), np.array([0.3, -0.1])
    draws = 20000
    h = h0 + rng.normal(size=(draws, 2)) @ np.linalg.cholesky(p_h).T
    y = theta @ a.T + h @ b.T + rng.normal(size=(draws, a.shape[0]))
    est = np.linalg.lstsq(a, (y - h0 @ b.T).T, rcond=None)[0].T  # h held at h₀
    err = est - theta
    np.testing.assert_allclose(np.cov(err.T), expected, rtol=0.05, atol=0.05 * np.sqrt(np.outer(*2 * [np.diag(
        expected)])).max())
    np.testing.assert_allclose(np.diag(np.cov(err.T)) / np.diag(expected), 1.0, atol=0.05)
    white = np.linalg.solve(np.linalg.cholesky(expected), err.T)
    assert abs(np.mean(np.sum(white**2, axis=0)) / a.shape[1] - 1.0) < 0.03
    assert np.all(np.diag(np.cov(err.T)) > 1.5 * np.diag(p))  # the estimator's own P is far too small here


def test_hostile_linear_cases():
    """A held column equal to an estimated one: S = −e_i, the variance grows by P_h exactly; a held column the
    data do not see (zeros): S = 0 and the covariance is P exactly; rank-deficient A: no covariance (None)."""
    a, _, _ = _linear_case(2)
    p, s = linear_sensitivity(a, a[:, [1]])
    np.testing.assert_allclose(s[:, 0], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(consider_covariance(p, s, [[0.3]])[1, 1], p[1, 1] + 0.3, rtol=1e-12)
    p0, s0 = linear_sensitivity(a, np.zeros((a.shape[0], 2)))
    assert np.all(s0 == 0.0)
    np.testing.assert_array_equal(consider_covariance(p0, s0, np.eye(2)), p0)
    assert linear_sensitivity(np.c_[a[:, :2], a[:, 0]], a[:, [1]]) is None


@pytest.fixture(scope="module")
def solved():
    """25 s of exciting open-loop data of a plant with a CoM offset and force scale errors, the default mission's
    set [mass, inertia, com, force_scale] solved (products and torque scales held at 0 and 1)."""
    n = 125
    tel = simulate(Playback(exciting_inputs(n, 7)), initial_state(), InertialParams(TRUTH[0], TRUTH[1:4]),
                   duration_s=n * CONTROL_PERIOD_S, control_period_s=CONTROL_PERIOD_S,
                   plant_period_s=PLANT_PERIOD_S, input_limits=np.full(6, 10.0), sensors=SENSORS,
                   disturbance=Disturbance.none(), rng=np.random.default_rng(4), actuator_scale=TRUTH[10:16],
                   com_offset_m=TRUTH[7:10], inertia_tensor_kgm2=inertia_tensor(TRUTH))
    recs = records(tel)
    model = _model()
    return recs, model, estimate_batch(recs, settings(), PRIOR, model=model)


def test_batch_sensitivity_equals_the_dense_jacobians(solved):
    """The block QR of the augmented problem gives the solved problem's own covariance of [x_K, φ] and the
    sensitivity −(AᵀA)⁻¹AᵀB of the dense Jacobian (BatchProblem.evaluate, sparse path, held columns appended);
    P₁ also equals the dense one."""
    recs, model, res = solved
    held = held_index(model)
    assert [g for g in GROUPS if set(GROUPS[g]) <= set(held.tolist())] == ["products", "torque_scale"]
    aug = AugmentedModel(model.params, model.prior_mean, model.prior_cov, held)
    problem = BatchProblem(recs, settings(), PRIOR, PRIOR.theta, aug)
    phi = np.r_[res.phi, phi_from_theta_full(model.params.theta_fixed)[held]]
    p1, s1 = batch_sensitivity(problem, res.states, phi, res.inliers, model.n)
    np.testing.assert_allclose(p1, res.last_covariance, rtol=1e-7, atol=1e-14)
    k = 40  # the dense check on the first 40 records (any point: the identity is algebraic)
    problem = BatchProblem(recs[:k], settings(), PRIOR, PRIOR.theta, aug)
    p1, s1 = batch_sensitivity(problem, res.states[:k], phi, res.inliers[:k], model.n)
    _, a_mat = problem.evaluate(res.states[:k], phi, res.inliers[:k], jacobian=True)
    dense = a_mat.toarray()
    n_x = TANGENT_DIM * problem.k
    a_est, b_held = dense[:, :n_x + model.n], dense[:, n_x + model.n:]
    p_dense, s_dense = linear_sensitivity(a_est, b_held)
    np.testing.assert_allclose(s1, s_dense[n_x - TANGENT_DIM:], rtol=1e-6, atol=1e-9 * np.abs(s_dense).max())
    last = slice(n_x - TANGENT_DIM, None)
    np.testing.assert_allclose(p1, p_dense[last, last], rtol=1e-6, atol=1e-9 * np.abs(p1).max())


def test_sensitivity_equals_the_re_solved_estimators_difference(solved):
    """θ̂ re-solved with a held torque scale (product of inertia) moved by 0.01 (0.0005 kg·m²) moves by the
    sensitivity's column: to first order, within 0.1 of the estimate's σ everywhere and within 5 % where the
    predicted move is a σ or more (the entries the held value biases most: a few σ here); the physical covariance
    adds T P_h Tᵀ to the estimator's, the handed one takes the inertias as J/κ_τ (T − J on the torque scales'
    columns), and the held entries' rows carry their prior."""
    recs, model, res = solved
    con = consider_held(recs, settings(), PRIOR, model, res.states, res.inliers, res.theta_full, res.covariance_full)
    assert con is not None
    held = con.held.tolist()
    est = model.params.index
    sd = np.sqrt(np.diag(res.covariance_full))[est]
    for h, step in ((13, 0.01), (4, 0.0005)):  # torque scale x, product Jxy
        again = estimate_batch(recs, settings(), PRIOR, model=_model(fixed_shift=step * np.eye(16)[h]),
                               initial_phi=res.phi)
        moved = (again.theta_full - res.theta_full)[est] / sd
        want = con.sensitivity[est, held.index(h)] * step / sd
        assert np.abs(want).max() > 1.5  # a held value a fifth or a tenth of its prior σ off biases θ̂ by σs
        np.testing.assert_allclose(moved, want, atol=0.1)
        big = np.abs(want) >= 1.0
        np.testing.assert_allclose(moved[big], want[big], rtol=0.05)
    p_h = model.prior_cov[np.ix_(con.held, con.held)]
    np.testing.assert_allclose(con.physical, consider_covariance(res.covariance_full, con.sensitivity, p_h),
                               rtol=1e-12)
    np.testing.assert_allclose(np.diag(con.physical)[con.held], np.diag(p_h), rtol=1e-9)
    assert con.absorbed.tolist() == list(GROUPS["torque_scale"])
    t_eff = con.sensitivity.copy()  # the effective inertia J_a/κ_a moves by J_a per unit κ_a (held at 1)
    for axis in range(3):
        t_eff[1 + axis, held.index(13 + axis)] -= res.theta_full[1 + axis]
    np.testing.assert_allclose(con.effective, consider_covariance(res.covariance_full, t_eff, p_h), rtol=1e-12)
    assert np.all(np.linalg.eigvalsh(con.effective - con.statistical) > -1e-12)
    assert con.effective[0, 0] == pytest.approx(con.physical[0, 0], rel=1e-12)  # the mass absorbs nothing


def test_stage_reports_physical_and_hands_the_effective(solved):
    """consider_run: the last history entry becomes the handed estimate (effective covariance); the summary's std,
    error_over_std, std_over_crb and cov_reduction_pct of m and I become the physical ones."""
    recs, model, res = solved
    history = [PRIOR, res.estimate]
    full, final, extras = consider_run(recs, settings(), PRIOR, model, res.t, res.states, res.inliers,
                                       (res.theta_full, res.covariance_full), res.estimate, history)
    assert history[-1] is final and extras is not None
    con = extras["consider"]
    assert con["absorbed_in_handed"] == ["torque_scale_x", "torque_scale_y", "torque_scale_z"]
    np.testing.assert_allclose(final.std, [con["std_handed"][k] for k in ("mass_kg", "Ixx_kgm2", "Iyy_kgm2",
                                                                          "Izz_kgm2")], rtol=1e-12)
    np.testing.assert_array_equal(final.theta, res.estimate.theta)
    names = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")
    summary = {"consider": con, "crb_std": dict.fromkeys(names, 1.0), "prior_std": dict.fromkeys(names, 1.0),
               "truth_theta": TRUTH[:4].tolist(), "std": {}}
    apply_physical_std(summary, full)
    phys = np.sqrt(np.diag(full[1])[:4])
    np.testing.assert_allclose([summary["std"][k] for k in names], phys, rtol=1e-12)
    np.testing.assert_allclose([summary["error_over_std"][k] for k in names],
                               np.abs(res.theta_full[:4] - TRUTH[:4]) / phys, rtol=1e-12)
    assert np.all(final.std >= res.estimate.std) and phys[0] == pytest.approx(final.std[0], rel=1e-9)


def test_nothing_held_or_unidentified_keeps_the_estimators_covariance(solved):
    """Every group estimated (nothing held), or a covariance that is not finite: no consider covariance (None),
    so the estimate stage reports the estimator's own covariance, exactly as before."""
    recs, _, res = solved
    everything = _model(("mass", "inertia", "products", "com", "force_scale", "torque_scale"))
    assert held_index(everything).size == 0
    assert consider_held(recs, settings(), PRIOR, everything, res.states, res.inliers, res.theta_full,
                         np.eye(16)) is None
    model = _model()
    bad = res.covariance_full.copy()
    bad[0, 0] = np.inf
    assert consider_held(recs, settings(), PRIOR, model, res.states, res.inliers, res.theta_full, bad) is None
    history = [res.estimate]
    full, final, extras = consider_run(recs, settings(), PRIOR, model, res.t, res.states, res.inliers,
                                       (res.theta_full, bad), res.estimate, history)
    assert extras is None and final is res.estimate and full[1] is bad and history == [res.estimate]


def test_a_gap_in_the_input_record_is_bridged_as_the_batch_does(solved):
    """Records with a gap in the input record (a record that starts a segment: the lost wrench predicted from its
    neighbours, oacli.estimation.lost_inputs): the consider covariance is still formed, finite and at least the
    estimator's, and one lost control period of 125 changes the sensitivities by a few per cent only."""
    recs, model, res = solved
    gapped = list(recs)
    gapped[60] = dataclasses.replace(gapped[60], starts_segment=True)
    args = (settings(), PRIOR, model, res.states, res.inliers, res.theta_full, res.covariance_full)
    whole, cut = consider_held(recs, *args), consider_held(gapped, *args)
    assert whole is not None and cut is not None
    assert np.all(np.isfinite(cut.physical)) and np.all(np.linalg.eigvalsh(cut.physical - cut.statistical) > -1e-12)
    est = model.params.index
    np.testing.assert_allclose(cut.sensitivity[est], whole.sensitivity[est], rtol=0.1,
                               atol=0.05 * np.abs(whole.sensitivity[est]).max())


def test_an_estimate_on_the_lamina_boundary_keeps_its_covariance_and_says_so(solved):
    """A filter's θ̂ whose inertias meet a triangle inequality with equality (an envelope run: 0.0754 + 0.4765 =
    0.5520 kg·m²) has no log-Cholesky φ to differentiate at: consider_run keeps the estimator's covariance, names
    the reason (``consider_skipped``, a finding: the stage is degraded) and never raises (it failed the whole mission
    before)."""
    recs, model, res = solved
    theta = res.theta_full.copy()
    theta[1:4] = [0.07544099056109987, 0.4765270351085512, 0.07544099056109987 + 0.4765270351085512]
    history = [res.estimate]
    with pytest.raises(ValueError, match="not physical"):
        phi_from_theta_full(theta)
    full, final, extras = consider_run(recs, settings(), PRIOR, model, res.t, res.states, res.inliers,
                                       (theta, res.covariance_full), res.estimate, history)
    assert final is res.estimate and full[1] is res.covariance_full and history == [res.estimate]
    assert extras is not None and "consider covariance could not be formed" in extras["consider_skipped"]
    from oacli.stages.estimate import estimate_findings  # the stage then says degraded, with that reason

    report = estimate_findings({"status": "ok", **extras})
    assert report.status == "degraded" and [r.kind for r in report.reasons] == ["consider_skipped"]
    assert estimate_findings({"status": "ok"}).status == "ok"
