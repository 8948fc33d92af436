"""Minimal RPI outer approximation (Raković, Kerrigan, Kouramas & Mayne 2005, Algorithm 1) and facet reduction."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from oacli.control.lqr import dlqr
from oacli.errors import InfeasibleError
from oacli.model.double_integrator import double_integrator
from oacli.sets import Polytope, RPITermsError, minimal_rpi_outer, minimal_rpi_support, reduce_facets, rpi_margins

# [Rakovic2005], example of their Eq. (15): x⁺ = [[1, 1], [0, 1]] x + [1, 1]ᵀ u + w, u = −[1.17, 1.03] x,
# W = {w : ‖w‖_∞ ≤ 1}.
RKKM_A_K = np.array([[1.0, 1.0], [0.0, 1.0]]) - np.array([[1.0], [1.0]]) @ np.array([[1.17, 1.03]])
RKKM_W = Polytope.symmetric_box([1.0, 1.0])


def infinite_sum_support(a_k, w, d, terms=3000):
    """h_{F_∞}(d) = Σ_{i≥0} h_W((A_Kⁱ)ᵀ d), summed until the terms vanish (A_K Schur stable)."""
    total, power = np.zeros(len(d)), np.eye(a_k.shape[0])
    for _ in range(terms):
        total += w.support(d @ power)
        power = a_k @ power
    return total


def test_rakovic_2005_example_reaches_the_published_alpha_and_s():
    """The example's figure shows F(α, s) with α = 1.9·10⁻⁵ and s = 10.

    We could not read the paper itself here: the pair (1.9·10⁻⁵, 10) is the label of pytope's reproduction of that
    figure (github.com/heirung/pytope, docs/Rakovic_2005.svg), which we take as the published values. Algorithm 1
    returns s = 10 for any ε in [α°(10) M(10) / (1 − α°(10)), α°(9) M(9) / (1 − α°(9))) ≈ [5.0e-5, 1.66e-4).
    """
    for eps in (6e-5, 1e-4, 1.6e-4):
        r = minimal_rpi_outer(RKKM_A_K, RKKM_W, eps)
        assert r.s == 10
        assert f"{r.alpha:.1e}" == "1.9e-05"  # the published value, two significant digits
        assert r.epsilon_achieved <= eps
    # α°(s) independently: for the unit box W, h_W(c) = ‖c‖₁, so α°(s) = max_i ‖(A_Kˢ)ᵀ f_i‖₁ = ‖A_Kˢ‖_∞.
    assert minimal_rpi_outer(RKKM_A_K, RKKM_W, 1e-4).alpha == pytest.approx(
        np.linalg.norm(np.linalg.matrix_power(RKKM_A_K, 10), np.inf), rel=1e-12
    )


def test_rakovic_2005_example_is_an_outer_epsilon_approximation(rng):
    """F_∞ ⊆ F(α, s) ⊆ F_∞ ⊕ B_∞(ε) (RKKM05 Theorem 2), checked through support functions."""
    eps = 1e-3
    r = minimal_rpi_outer(RKKM_A_K, RKKM_W, eps)
    d = rng.standard_normal((200, 2))
    h_inf = infinite_sum_support(RKKM_A_K, RKKM_W, d)
    h = r.z.support(d)
    assert np.all(h >= h_inf - 1e-12)
    assert np.all(h <= h_inf + eps * np.abs(d).sum(axis=1) + 1e-12)


def axis_systems():
    """Per-axis Astrobee translation at 0.2 s with the ReSWARM ancillary gain, and the RKKM05 example."""
    a, b = double_integrator(0.2, 1 / 9.5)
    k, _ = dlqr(a, b, np.diag([5.0, 10.0]), np.array([[2.0]]))  # [RattleCode] z_poly_calc: Q = diag(5, 10), R = 2
    return [
        (RKKM_A_K, RKKM_W, 1e-4),
        (a + b @ k, Polytope.symmetric_box([6.8e-6, 6.8e-5]), 0.005),
        (a + b @ k, Polytope.from_vertices([[1e-4, 1e-3], [-1e-4, 2e-4], [-1e-4, -1e-3], [1e-4, -2e-4]]), 1e-4),
    ]


@pytest.mark.parametrize("case", range(3))
def test_robust_invariance_facet_by_facet(case):
    """h_Z(A_Kᵀ a) + h_W(a) ≤ h_Z(a) for every facet a of Z (so A_K Z ⊕ W ⊆ Z)."""
    a_k, w, eps = axis_systems()[case]
    z = minimal_rpi_outer(a_k, w, eps).z
    scale = float(np.max(z.b))
    for a_i, b_i in zip(z.a, z.b, strict=True):
        assert z.support(a_k.T @ a_i) + w.support(a_i) <= b_i + 1e-12 * scale
    # and pointwise on the vertices: A_K v + w stays in Z for every vertex pair
    pts = (z.vertices @ a_k.T)[:, None, :] + w.vertices[None, :, :]
    assert np.all(z.contains_points(pts.reshape(-1, 2), tol=1e-12 * scale))


def test_n_dimensional_path_agrees_with_the_per_axis_sets():
    """A block-diagonal 4-D system (two copies of the RKKM05 example) through the general n-D (Qhull) path gives
    the product of the 2-D sets: the same s and α, and support values that add over the blocks."""
    a4 = np.zeros((4, 4))
    a4[:2, :2] = a4[2:, 2:] = RKKM_A_K
    w4 = Polytope.symmetric_box([1.0, 1.0, 1.0, 1.0])
    r4 = minimal_rpi_outer(a4, w4, 1e-2)
    r2 = minimal_rpi_outer(RKKM_A_K, RKKM_W, 1e-2)
    assert (r4.s, r4.alpha) == (r2.s, pytest.approx(r2.alpha))
    d = np.random.default_rng(3).standard_normal((50, 4))
    np.testing.assert_allclose(r4.z.support(d), r2.z.support(d[:, :2]) + r2.z.support(d[:, 2:]), rtol=1e-9)
    assert np.all(rpi_margins(a4, r4.z, w4) >= -1e-12)


def test_three_dimensional_system_is_robustly_invariant(rng):
    """The general n-D path (Qhull) on a coupled 3-D system with a non-box W."""
    while True:
        a = rng.standard_normal((3, 3))
        a *= 0.5 / np.max(np.abs(np.linalg.eigvals(a)))
        if np.linalg.cond(a) < 20:
            break
    w = Polytope.from_vertices(np.vstack([np.eye(3), -np.eye(3)]) * [0.5, 0.3, 0.8])  # an octahedron
    r = minimal_rpi_outer(a, w, 0.05)
    assert r.epsilon_achieved <= 0.05
    assert np.all(rpi_margins(a, r.z, w) >= -1e-12 * np.max(r.z.b))


def test_refuses_an_unstable_closed_loop():
    with pytest.raises(InfeasibleError, match="not Schur stable"):
        minimal_rpi_outer(np.array([[1.0, 0.2], [0.0, 1.0]]), RKKM_W, 0.01)


def test_never_truncates_the_series_silently():
    with pytest.raises(InfeasibleError, match="not truncated"):
        minimal_rpi_outer(RKKM_A_K, RKKM_W, 1e-9, max_terms=5)


def test_refuses_a_disturbance_set_without_the_origin_inside():
    with pytest.raises(InfeasibleError, match="origin in its interior"):
        minimal_rpi_outer(RKKM_A_K, Polytope.box([0.1, -1.0], [1.0, 1.0]), 0.01)


@settings(max_examples=25, deadline=None)
@given(
    st.floats(0.5, 50.0), st.floats(0.5, 50.0), st.floats(0.1, 20.0),
    st.floats(1e-6, 1e-3), st.floats(0.5, 20.0), st.floats(0.01, 0.3),
)
def test_facet_reduction_stays_invariant_outer_and_within_the_growth(q_pos, q_vel, r, w_pos, w_ratio, growth):
    a, b = double_integrator(0.2, 1 / 9.5)
    k, _ = dlqr(a, b, np.diag([q_pos, q_vel]), np.array([[r]]))
    a_k = a + b @ k
    w = Polytope.symmetric_box([w_pos, w_pos * w_ratio])
    z = minimal_rpi_outer(a_k, w, 0.5 * w_pos * w_ratio).z
    red = reduce_facets(a_k, z, w, growth)
    assert red.facets_after <= red.facets_before
    assert red.z.contains(z, tol=1e-12 * np.max(z.b))  # still an outer approximation of F_∞
    assert np.all(rpi_margins(a_k, red.z, w) >= 0.0)  # still RPI
    d = np.vstack([z.a, np.eye(2), -np.eye(2)])
    assert np.all(red.z.support(d) <= (1 + growth) * z.support(d) * (1 + 1e-9))


def test_facet_reduction_makes_the_reswarm_lasso_small():
    a_k, w, eps = axis_systems()[1]
    z = minimal_rpi_outer(a_k, w, eps)
    red = reduce_facets(a_k, z.z, w, 0.05)
    assert z.facets > 150  # F(α, s) of the flight settings: hundreds of facets
    assert red.facets_after <= 30
    assert red.growth <= 0.05 and red.min_margin >= 0.0


# -- relative ε: F_∞ ⊆ F(α, s) ⊆ (1 + ε) F_∞ ---------------------------------------------------------------------


def lp_support(p: Polytope, d: np.ndarray) -> float:
    """h_P(d) by scipy's HiGHS LP on the inequalities only (independent of the stored vertices)."""
    res = linprog(-d, A_ub=p.a, b_ub=p.b, bounds=[(None, None)] * p.dim, method="highs")
    assert res.status == 0
    return -res.fun


def unit_directions(rng, n, k):
    d = rng.standard_normal((k, n))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_minimal_rpi_support_is_the_geometric_series_for_a_diagonal_system(rng):
    """A_K = diag(λ₁, λ₂), W = box(w): h_{F_∞}(d) = Σ_j |d_j| w_j / (1 − |λ_j|) in closed form."""
    lam, half = np.array([0.9, -0.6]), np.array([0.3, 2.0])
    d = unit_directions(rng, 2, 50)
    h, tail = minimal_rpi_support(np.diag(lam), Polytope.symmetric_box(half), d)
    exact = np.abs(d) @ (half / (1 - np.abs(lam)))
    np.testing.assert_allclose(h, exact, rtol=1e-12)
    assert np.all(h <= exact * (1 + 1e-14)) and np.all(h + tail >= exact * (1 - 1e-14))  # a true bracket
    assert np.all(tail <= 1e-12 * h)


def test_minimal_rpi_support_brackets_the_direct_sum(rng):
    """Non-normal A_K (the RKKM05 example): the bracket [sum, sum + tail] holds a 5000-term direct sum."""
    d = unit_directions(rng, 2, 40)
    h, tail = minimal_rpi_support(RKKM_A_K, RKKM_W, d)
    direct = infinite_sum_support(RKKM_A_K, RKKM_W, d, terms=5000)
    assert np.all(h <= direct * (1 + 1e-13)) and np.all(direct <= (h + tail) * (1 + 1e-13))


@pytest.mark.parametrize("eps", [0.01, 0.05, 0.3])
def test_relative_epsilon_on_the_rakovic_example(eps, rng):
    """RKKM05's example with the relative rule: α ≤ ε/(1 + ε) at the smallest such s (for the unit box W,
    α°(s) = ‖A_Kˢ‖_∞ independently), F_∞ ⊆ F(α, s) ⊆ (1 + ε) F_∞ along 400 directions, and F(α, s) is RPI by LP."""
    r = minimal_rpi_outer(RKKM_A_K, RKKM_W, eps, mode="relative")
    alpha_of = [np.linalg.norm(np.linalg.matrix_power(RKKM_A_K, s), np.inf) for s in range(r.s + 1)]
    assert r.alpha == pytest.approx(alpha_of[r.s], rel=1e-12) and r.alpha <= eps / (1 + eps)
    assert all(a > eps / (1 + eps) for a in alpha_of[1:r.s])  # s is the first one
    assert r.mode == "relative" and r.epsilon_achieved == pytest.approx(r.alpha / (1 - r.alpha))
    assert r.epsilon_achieved <= eps
    d = unit_directions(rng, 2, 400)
    h_inf, _ = minimal_rpi_support(RKKM_A_K, RKKM_W, d)
    h = r.z.support(d)
    assert np.all(h >= h_inf * (1 - 1e-12))
    assert np.all(h <= (1 + eps) * h_inf * (1 + 1e-12))
    assert np.max(h / h_inf) > 1 + 0.2 * eps  # the rule is not vacuous: the bound is approached
    for a_i, b_i in zip(r.z.a, r.z.b, strict=True):  # A_K F ⊕ W ⊆ F with LP support values
        assert lp_support(r.z, RKKM_A_K.T @ a_i) + RKKM_W.support(a_i) <= b_i + 1e-9 * np.max(r.z.b)


def test_absolute_mode_is_the_default_and_reproduces_the_published_example():
    """mode="absolute" is Algorithm 1 as published: the same set as the default call, s = 10, α = 1.9e-5."""
    r, default = minimal_rpi_outer(RKKM_A_K, RKKM_W, 1e-4, mode="absolute"), minimal_rpi_outer(RKKM_A_K, RKKM_W, 1e-4)
    assert (r.s, f"{r.alpha:.1e}", r.mode) == (10, "1.9e-05", "absolute")
    assert (default.s, default.alpha, default.mode) == (r.s, r.alpha, "absolute")
    np.testing.assert_array_equal(r.z.b, default.z.b)
    assert r.epsilon_achieved == r.absolute_accuracy <= 1e-4


def test_relative_rule_refuses_beyond_max_terms_and_says_how_many():
    eps = 1e-6
    needed = next(s for s in range(1, 1000)
                  if np.linalg.norm(np.linalg.matrix_power(RKKM_A_K, s), np.inf) <= eps / (1 + eps))
    with pytest.raises(RPITermsError, match=rf"needs s = {needed} terms.*not truncated") as info:
        minimal_rpi_outer(RKKM_A_K, RKKM_W, eps, mode="relative", max_terms=needed - 1)
    assert info.value.needed == needed and info.value.max_terms == needed - 1
    assert isinstance(info.value, InfeasibleError)
    assert minimal_rpi_outer(RKKM_A_K, RKKM_W, eps, mode="relative", max_terms=needed).s == needed


def test_rejects_a_bad_mode_or_epsilon():
    with pytest.raises(ValueError, match="mode"):
        minimal_rpi_outer(RKKM_A_K, RKKM_W, 0.1, mode="percent")
    with pytest.raises(ValueError, match="epsilon"):
        minimal_rpi_outer(RKKM_A_K, RKKM_W, float("inf"), mode="relative")


def test_relative_rule_on_a_coupled_three_dimensional_system(rng):
    """The general n-D (Qhull) path with the relative rule: the inclusions hold along 300 directions."""
    while True:
        a = rng.standard_normal((3, 3))
        a *= 0.6 / np.max(np.abs(np.linalg.eigvals(a)))
        if np.linalg.cond(a) < 20:
            break
    w = Polytope.symmetric_box([0.5, 0.3, 0.8])
    r = minimal_rpi_outer(a, w, 0.05, mode="relative")
    d = unit_directions(rng, 3, 300)
    h_inf, _ = minimal_rpi_support(a, w, d)
    h = r.z.support(d)
    assert np.all(h >= h_inf * (1 - 1e-12)) and np.all(h <= 1.05 * h_inf * (1 + 1e-12))
    assert np.all(rpi_margins(a, r.z, w) >= -1e-12 * np.max(r.z.b))


@settings(max_examples=30, deadline=None)
@given(
    st.floats(0.2, 0.97), st.floats(-np.pi, np.pi), st.floats(-3.0, 3.0), st.floats(0.01, 2.0),
    st.floats(0.1, 10.0), st.floats(0.005, 0.5), st.integers(0, 2**31 - 1),
)
def test_relative_rule_property_random_stable_system(radius, angle, shear, w1, w_ratio, eps, seed):
    """Random Schur-stable 2×2 A_K (eigenvalues radius·e^{±iθ} or real, sheared by a random similarity) and a
    random box W: F_∞ ⊆ F(α, s) ⊆ (1 + ε) F_∞ along 200 directions (F_∞ from the independent series) and
    A_K F ⊕ W ⊆ F facet by facet."""
    rng = np.random.default_rng(seed)
    if abs(angle) < 0.3:  # real eigenvalues of both signs
        core = np.diag([radius, -radius * rng.uniform(0.1, 1.0)])
    else:
        core = radius * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    t = np.array([[1.0, shear], [0.0, 1.0]]) @ np.diag(rng.uniform(0.5, 2.0, 2))
    a_k = t @ core @ np.linalg.inv(t)
    w = Polytope.symmetric_box([w1, w1 * w_ratio])
    r = minimal_rpi_outer(a_k, w, eps, mode="relative", max_terms=2000)
    d = unit_directions(rng, 2, 200)
    h_inf, _ = minimal_rpi_support(a_k, w, d)
    h = r.z.support(d)
    assert np.all(h >= h_inf * (1 - 1e-11))
    assert np.all(h <= (1 + eps) * h_inf * (1 + 1e-11))
    assert np.all(rpi_margins(a_k, r.z, w) >= -1e-11 * np.max(r.z.b))
