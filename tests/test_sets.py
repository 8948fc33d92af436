"""Polytopes: support functions, linear maps, Minkowski sums, Pontryagin differences, containment."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

from oacli.sets import Polytope
from oacli.sets.hull import convex_hull_2d, hull_normals


def random_directions(rng, n, k=64):
    d = rng.standard_normal((k, n))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def lp_support(p: Polytope, d: np.ndarray) -> float:
    """Independent support value: scipy's HiGHS LP on the inequalities."""
    res = linprog(-d, A_ub=p.a, b_ub=p.b, bounds=[(None, None)] * p.dim, method="highs")
    assert res.status == 0
    return -res.fun


def test_box_support_is_the_closed_form(rng):
    lo, hi = np.array([-1.0, 0.5, -3.0]), np.array([2.0, 0.7, -1.0])
    box = Polytope.box(lo, hi)
    for d in random_directions(rng, 3):
        assert box.support(d) == pytest.approx(np.sum(np.where(d > 0, d * hi, d * lo)), abs=1e-12)
    assert box.n_facets == 6 and box.vertices.shape == (8, 3)


@pytest.mark.parametrize("n", [2, 3])
def test_enumerated_vertices_give_the_lp_support(n, rng):
    pts = rng.standard_normal((30, n))
    p = Polytope.from_vertices(pts)
    h_only = Polytope(p.a, p.b)  # forget the vertices: enumerate them from the inequalities
    for d in random_directions(rng, n, 20):
        assert h_only.support(d) == pytest.approx(lp_support(p, d), abs=1e-9)
        assert p.support(d) == pytest.approx(np.max(pts @ d), abs=1e-12)  # hull of the points


def test_2d_hull_matches_qhull_and_drops_only_interior_points(rng):
    pts = np.vstack([rng.uniform(-1, 1, (200, 2)), [[2, 0], [0, 2], [-2, 0], [0, -2], [1, 1]]])
    hull = convex_hull_2d(pts)
    qh = ConvexHull(pts)
    assert {tuple(p) for p in hull} == {tuple(p) for p in pts[qh.vertices]}
    # Counter-clockwise order: positive signed area.
    x, y = hull[:, 0], hull[:, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) == pytest.approx(qh.volume)


def test_degenerate_point_sets_are_described_exactly():
    seg = Polytope.from_vertices([[0.0, 0.0], [1.0, 2.0], [0.5, 1.0]])
    assert seg.contains_points(np.array([0.25, 0.5]), tol=1e-12)
    assert not seg.contains_points(np.array([0.25, 0.6]), tol=1e-9)
    assert seg.support(np.array([1.0, 2.0])) == pytest.approx(5.0)
    point = Polytope.from_vertices([[1.0, -1.0]])
    assert point.support(np.array([0.3, 0.4])) == pytest.approx(-0.1)
    with pytest.raises(ValueError, match="full-dimensional"):
        hull_normals(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]))


def test_linear_map_support_is_support_along_the_transposed_direction(rng):
    p = Polytope.from_vertices(rng.standard_normal((12, 2)))
    for m in (rng.standard_normal((2, 2)), rng.standard_normal((1, 2)), np.array([[1.0, 2.0], [2.0, 4.0]])):
        image = p.linear_map(m)
        for d in random_directions(rng, m.shape[0], 10):
            assert image.support(d) == pytest.approx(p.support(m.T @ d), abs=1e-10)


def test_minkowski_sum_support_is_the_sum_of_supports(rng):
    for n in (2, 3):
        p = Polytope.from_vertices(rng.standard_normal((10, n)))
        q = Polytope.from_vertices(rng.standard_normal((7, n)))
        s = p.minkowski_sum(q)
        for d in random_directions(rng, n, 30):
            assert s.support(d) == pytest.approx(p.support(d) + q.support(d), abs=1e-10)
        assert s.contains(p.translated(q.vertices[0]), tol=1e-10)


def test_pontryagin_difference_of_boxes_is_the_closed_form():
    p = Polytope.box([-3.0, -1.0], [2.0, 4.0])
    q = Polytope.box([-0.5, -0.2], [0.25, 0.3])
    diff = p.pontryagin_difference(q)
    expected = Polytope.box([-2.5, -0.8], [1.75, 3.7])
    for d in np.vstack([np.eye(2), -np.eye(2), [[1, 1], [1, -2]]]):
        assert diff.support(d) == pytest.approx(expected.support(d), abs=1e-12)


def test_pontryagin_difference_can_be_empty():
    p = Polytope.symmetric_box([1.0, 1.0])
    assert p.pontryagin_difference(Polytope.symmetric_box([1.5, 0.1])).is_empty()
    assert not p.pontryagin_difference(Polytope.symmetric_box([0.5, 0.1])).is_empty()


def test_support_of_an_unbounded_polytope_uses_a_linear_program():
    velocity_band = Polytope(np.array([[0.0, 1.0], [0.0, -1.0]]), [0.2, 0.2])  # positions free
    assert not velocity_band.is_bounded()
    assert velocity_band.support(np.array([0.0, 1.0])) == pytest.approx(0.2)
    assert velocity_band.support(np.array([1.0, 0.0])) == np.inf
    tight = velocity_band.pontryagin_difference(Polytope.symmetric_box([5.0, 0.05]))
    assert tight.b == pytest.approx([0.15, 0.15])


def test_an_lp_without_verdict_is_retried_with_highs_other_methods(monkeypatch):
    """HiGHS's default can end a degenerate LP with model status Unknown (a hypothesis case in
    test_pontryagin_difference_is_the_largest_such_set): the polytope's LPs retry with its other methods instead of
    raising; only when every method fails is it an error."""
    import scipy.optimize

    import oacli.sets.polytope as polytope

    calls: list[str] = []

    def flaky(c, A_ub, b_ub, bounds, method):  # scipy's argument names
        calls.append(method)
        if method == "highs":
            return scipy.optimize.OptimizeResult(status=4, message="model_status is Unknown")
        return linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method=method)

    monkeypatch.setattr(polytope, "linprog", flaky)
    box = Polytope(np.vstack([np.eye(3), -np.eye(3)]), [1.0, 2.0, 3.0, 1.0, 2.0, 3.0])
    centre, radius = box.chebyshev_ball()
    assert radius == pytest.approx(1.0) and abs(centre[0]) < 1e-9   # the largest ball in the box touches x = ±1
    assert calls == ["highs", "highs-ipm"]
    band = Polytope(np.array([[0.0, 1.0], [0.0, -1.0]]), [0.2, 0.2])
    assert band.support(np.array([0.0, 1.0])) == pytest.approx(0.2)
    monkeypatch.setattr(polytope, "linprog", lambda *a, **k: scipy.optimize.OptimizeResult(status=4, message="no"))
    with pytest.raises(RuntimeError, match="Chebyshev-ball LP failed"):
        Polytope(np.vstack([np.eye(2), -np.eye(2)]), [1.0] * 4).chebyshev_ball()


def test_containment_margin_is_the_smallest_offset_slack():
    p = Polytope.symmetric_box([1.0, 2.0])
    assert p.containment_margin(Polytope.symmetric_box([0.5, 1.0])) == pytest.approx(0.5)
    assert p.containment_margin(Polytope.symmetric_box([1.25, 1.0])) == pytest.approx(-0.25)
    assert p.contains(Polytope.symmetric_box([1.0, 2.0]))
    assert not p.contains(Polytope.symmetric_box([1.0 + 1e-9, 2.0]))


@st.composite
def polytope_pairs(draw):
    """A random full-dimensional polytope P (hull of points) and a smaller random polytope Q near the origin."""
    n = draw(st.sampled_from([2, 3]))
    seed = draw(st.integers(0, 2**32 - 1))
    k = draw(st.integers(n + 2, 14))
    rng = np.random.default_rng(seed)
    p = Polytope.from_vertices(rng.uniform(-1, 1, (k, n)) * rng.uniform(0.5, 3, n))
    scale = draw(st.floats(0.01, 0.6))
    q = Polytope.from_vertices(scale * rng.uniform(-1, 1, (draw(st.integers(n + 1, 8)), n)))
    return p, q


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(polytope_pairs())
def test_pontryagin_then_minkowski_stays_inside(pair):
    """(P ⊖ Q) ⊕ Q ⊆ P for any polytopes P, Q (whenever P ⊖ Q is non-empty)."""
    p, q = pair
    diff = p.pontryagin_difference(q)
    if diff.is_empty():
        return
    tol = 1e-9 * max(1.0, float(np.max(np.abs(p.b))))
    back = diff.minkowski_sum(q)
    assert p.containment_margin(back) >= -tol
    # And pointwise: every vertex of P ⊖ Q plus every vertex of Q is in P.
    pts = (diff.vertices[:, None, :] + q.vertices[None, :, :]).reshape(-1, p.dim)
    assert np.all(p.contains_points(pts, tol=tol))


@settings(max_examples=40, deadline=None)
@given(polytope_pairs())
def test_pontryagin_difference_is_the_largest_such_set(pair):
    """P ⊖ Q ⊕ Q ⊆ P is tight: each facet of P ⊖ Q touches P after adding Q (support equality)."""
    p, q = pair
    diff = p.pontryagin_difference(q)
    if diff.is_empty():
        return
    back = diff.minkowski_sum(q)
    # Along P's normals whose tightened inequality is not redundant, (P ⊖ Q) ⊕ Q reaches P's offset.
    active = np.abs(diff.support(diff.a) - diff.b) <= 1e-9 * max(1.0, np.max(np.abs(diff.b)))
    np.testing.assert_allclose(back.support(p.a[active]), p.b[active], atol=1e-8)
