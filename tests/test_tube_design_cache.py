"""Second speed pass on the tube design: the batched Minkowski series, the LP-free 2-D boundedness test, the batched
minimal-RPI support sum and the in-process memo of axis designs, each checked against an independent reference."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

import oacli.control.tube_design as td
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.tube_design import AncillaryWeights, design_translation_tube
from oacli.sets import Polytope
from oacli.sets.hull import convex_hull_2d, minkowski_sum_linear_images, minkowski_sum_polygons
from oacli.sets.rpi import minimal_rpi_support
from tests.model_helpers import mass_model


def _support(points: np.ndarray, d: np.ndarray) -> np.ndarray:
    return np.max(points @ d.T, axis=0)


@pytest.mark.parametrize("seed", range(6))
def test_linear_images_sum_matches_term_by_term_merge_and_qhull(seed):
    """⊕ M_i P from one edge merge has the support function of the term-by-term merge (and of qhull on all pairwise
    vertex sums for three terms) in 200 random directions, with maps of both determinant signs."""
    rng = np.random.default_rng(seed)
    poly = convex_hull_2d(rng.normal(size=(9, 2)))
    maps = rng.normal(size=(3 if seed % 2 else 7, 2, 2))
    fast = minkowski_sum_linear_images(poly, maps)
    slow = convex_hull_2d(poly @ maps[0].T)
    for m in maps[1:]:
        slow = minkowski_sum_polygons(slow, convex_hull_2d(poly @ m.T))
    dirs = rng.normal(size=(200, 2))
    np.testing.assert_allclose(_support(fast, dirs), _support(slow, dirs), rtol=1e-12, atol=1e-12)
    if len(maps) == 3:
        a, b, c = (poly @ m.T for m in maps)
        pairs = (a[:, None, None, :] + b[None, :, None, :] + c[None, None, :, :]).reshape(-1, 2)
        hull = pairs[ConvexHull(pairs).vertices]
        np.testing.assert_allclose(_support(fast, dirs), _support(hull, dirs), rtol=1e-12, atol=1e-12)


def test_linear_images_sum_with_a_singular_map():
    """A rank-one map (segment image) takes the term-by-term path and still gives the exact sum."""
    poly = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    maps = np.array([np.eye(2), [[1.0, 0.0], [0.0, 0.0]]])
    pts = minkowski_sum_linear_images(poly, maps)
    assert _support(pts, np.array([[1.0, 0.0]]))[0] == pytest.approx(2.0)
    assert _support(pts, np.array([[0.0, 1.0]]))[0] == pytest.approx(1.0)


@pytest.mark.parametrize("seed", range(20))
def test_boundedness_without_lp_agrees_with_lps(seed):
    """The angular-gap test for 2-D polytopes agrees with HiGHS maximising ±e_i on random inequality systems
    (bounded ones from spanning normals, unbounded ones with all normals in a half-plane)."""
    rng = np.random.default_rng(100 + seed)
    k = int(rng.integers(3, 8))
    ang = rng.uniform(0, 2 * np.pi, k) if seed % 2 else rng.uniform(0, 0.9 * np.pi, k)
    a = np.column_stack([np.cos(ang), np.sin(ang)])
    b = rng.uniform(0.5, 2.0, k)
    lp_bounded = True
    for d in np.vstack([np.eye(2), -np.eye(2)]):
        res = linprog(-d, A_ub=a, b_ub=b, bounds=[(None, None)] * 2, method="highs")
        lp_bounded &= res.status != 3
    assert Polytope(a, b).is_bounded() == lp_bounded


def test_batched_minimal_rpi_support_equals_a_plain_sum():
    """The blocked sum equals a plain 3000-term Σ h_W((A_Kᵏ)ᵀ d) (ρ < 0.95: the rest is negligible)."""
    a_k = np.array([[0.95, 0.18], [-0.3, 0.8]])
    w = Polytope.symmetric_box([0.01, 0.02])
    d = np.random.default_rng(3).normal(size=(5, 2))
    total, power = np.zeros(5), np.eye(2)
    for _ in range(3000):
        total += w.support(d @ power)
        power = a_k @ power
    support, tail = minimal_rpi_support(a_k, w, d)
    np.testing.assert_allclose(support, total, rtol=1e-12)
    assert np.all(tail >= 0) and np.all(support + tail >= total * (1 - 1e-12))


def _design(force_n: float):
    spec = DisturbanceSpec(force_N=np.full(3, force_n))
    return design_translation_tube(model=mass_model(9.5, 0.1), dt_s=0.2, force_limit_N=np.full(3, 0.15),
                                   velocity_limit_mps=np.full(3, 0.2), weights=AncillaryWeights(5.0, 10.0, 2.0),
                                   spec=spec, epsilon=0.05)


def test_axis_designs_are_memoised_by_their_inputs():
    """The same inputs return the same AxisTube (no recomputation); other inputs a different design, equal to a
    fresh computation with the memo cleared."""
    first = _design(0.002)
    again = _design(0.002)
    assert all(a is b for a, b in zip(first.axes, again.axes, strict=True))
    other = _design(0.003)
    assert other.axes[0] is not first.axes[0]
    assert other.axes[0].disturbance.half_widths[1] > first.axes[0].disturbance.half_widths[1]
    td._AXIS_CACHE.clear()
    fresh = _design(0.003)
    assert fresh.axes[0] is not other.axes[0]
    np.testing.assert_array_equal(fresh.axes[0].z.b, other.axes[0].z.b)
    assert fresh.axes[0].force_bounds_N == other.axes[0].force_bounds_N
