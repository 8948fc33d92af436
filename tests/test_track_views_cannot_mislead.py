"""The track stage's ``views.png`` cannot show a collision that did not happen.

Independent check, read from the drawn figure: each panel's basis comes from its axis labels, its keep-out shadow
from its ``Ellipse`` patch and the flown path from its line. The true shadow is the convex hull of the projected
points of a densely sampled ellipsoid surface (no formula of the plotting code); the drawn ellipse must equal it.
Whenever the sampled 3-D path stays outside the ellipsoid and a panel draws it crossing the shadow, another panel
must draw it clear of the shadow.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.patches import Ellipse
from matplotlib.path import Path as MplPath
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from oacli.geometry import Box, Scene
from oacli.geometry.shapes import Ellipsoid
from oacli.io.plots import track_views

AXIS = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def _axis_direction(label: str) -> np.ndarray:
    if label[0] in AXIS and label[1:].startswith(" ["):
        return AXIS[label[0]]
    match = re.match(r"along \(([^)]*)\)", label)
    assert match, label
    w = np.array([float(v) for v in match.group(1).split(",")])
    return w / np.linalg.norm(w)


def _boundary(patch: Ellipse) -> np.ndarray:
    """720 points on a drawn ellipse's boundary, from its centre, width, height and angle [deg]."""
    a = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    phi = np.radians(patch.get_angle())
    local = np.column_stack([0.5 * patch.get_width() * np.cos(a), 0.5 * patch.get_height() * np.sin(a)])
    rot = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    return np.asarray(patch.get_center()) + local @ rot.T


def _drawn_panels(monkeypatch, tmp_path, scene, path_m, robot_radius_m=0.0):
    """Draw views.png for ``path_m`` and return per projected panel: (basis (2, 3), solid shadows (list of (M, 2)
    boundary points), flown line (N, 2))."""
    captured = {}

    def capture(fig, path):
        panels = []
        for ax in fig.axes:
            if not ax.get_xlabel().endswith("[m]") or not ax.get_ylabel().endswith("[m]"):
                continue  # the clearance-over-time panel
            if ax.get_ylabel().startswith("clearance"):
                continue
            basis = np.vstack([_axis_direction(ax.get_xlabel()), _axis_direction(ax.get_ylabel())])
            shadows = [_boundary(p) for p in ax.patches if isinstance(p, Ellipse) and p.get_fill()]
            (flown,) = [np.asarray(line.get_xydata()) for line in ax.lines if line.get_label() == "flown (true)"]
            panels.append((basis, shadows, flown))
        captured["panels"] = panels
        return path

    monkeypatch.setattr(track_views, "save_png", capture)
    t = np.linspace(0.0, 30.0, len(path_m))
    x = np.zeros((len(path_m), 13))
    x[:, 0:3] = path_m
    x[:, 9] = 1.0
    drawn = track_views.plot_views(tmp_path / "views.png", scene, robot_radius_m, SimpleNamespace(x=x),
                                   SimpleNamespace(t_true=t, x_true=x))
    return captured["panels"], drawn


def _true_shadow(zone: Ellipsoid, basis: np.ndarray) -> np.ndarray:
    """Convex hull of the projected surface samples (4,000 points on the ellipsoid)."""
    rng = np.random.default_rng(0)
    s = rng.standard_normal((4000, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    chol = np.linalg.cholesky(np.linalg.inv(zone.shape))  # P⁻¹ = L Lᵀ: surface = c + L s, |s| = 1
    pts = (zone.center + s @ chol.T) @ basis.T
    return pts[ConvexHull(pts).vertices]


def _inside(polygon: np.ndarray, points: np.ndarray, shrink: float = 1.0) -> np.ndarray:
    """Which ``points``, moved towards the polygon's centre by the factor ``shrink``, lie inside ``polygon``."""
    centre = polygon.mean(axis=0)
    return MplPath(polygon).contains_points(centre + shrink * (points - centre))


def _check(monkeypatch, tmp_path, zone: Ellipsoid, path_m: np.ndarray) -> list[bool]:
    """Checks the drawn shadows and the property; returns per panel whether it draws the path crossing."""
    scene = Scene(keep_in=(Box(np.full(3, -50.0), np.full(3, 50.0)),), keep_out=(zone,))
    panels, _ = _drawn_panels(monkeypatch, tmp_path, scene, path_m)
    assert len(panels) >= 3
    crossing = []
    for basis, shadows, flown in panels:
        truth = _true_shadow(zone, basis)
        (drawn,) = shadows
        assert np.all(_inside(drawn, truth, 0.99)), "the drawn keep-out is smaller than its shadow"
        assert np.all(_inside(truth, drawn, 0.99)), "the drawn keep-out is larger than its shadow"
        oblique = not all(np.count_nonzero(row) == 1 for row in basis)  # its label's directions: 3 decimals
        np.testing.assert_allclose(flown, path_m @ basis.T, atol=5e-3 if oblique else 1e-12)
        crossing.append(bool(np.any(_inside(truth, flown))))
    clears_3d = not np.any(zone.contains(path_m))
    if clears_3d and any(crossing):
        assert not all(crossing), "the path clears the keep-out, but every view draws it crossing"
    return crossing


def test_segment_3_like_path_below_the_keep_out_is_drawn_clear_in_the_front_view(monkeypatch, tmp_path):
    zone = Ellipsoid.from_semi_axes(np.array([10.8, -8.7, 5.0]), np.array([0.25, 0.15, 0.25]))
    s = np.linspace(0.0, 1.0, 400)[:, None]
    path = np.array([10.8, -7.75, 4.3]) * (1 - s) + np.array([10.8, -9.6, 4.8]) * s
    path[:, 2] -= 0.15 * np.sin(np.pi * s[:, 0])  # sags below the keep-out
    crossing = _check(monkeypatch, tmp_path, zone, path)
    assert crossing[0] and not crossing[2]  # top view crosses, front view (y-z) clears


def test_a_diagonal_pass_crossing_every_axis_view_gets_a_clearance_view(monkeypatch, tmp_path):
    zone = Ellipsoid.from_semi_axes(np.zeros(3), np.full(3, 0.5))
    w = np.ones(3) / np.sqrt(3.0)
    offset = 0.55 * np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0)  # 0.05 m clear in 3-D; 0, 0.02, 0.02 m in x-y, x-z, y-z
    path = offset + np.linspace(-1.5, 1.5, 600)[:, None] * w
    crossing = _check(monkeypatch, tmp_path, zone, path)
    assert crossing[:3] == [True, True, True] and len(crossing) == 4 and not crossing[3]


@pytest.mark.parametrize("seed", range(12))
def test_random_passes_that_clear_in_3d_are_drawn_clear_somewhere(monkeypatch, tmp_path, seed):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    semi = rng.uniform(0.15, 0.5, 3)
    zone = Ellipsoid.from_semi_axes(rng.uniform(-1, 1, 3), semi, rot)
    w = rng.standard_normal(3)
    w /= np.linalg.norm(w)
    n = rng.standard_normal(3)
    n -= (n @ w) * w
    n /= np.linalg.norm(n)
    s = np.linspace(-1.5, 1.5, 500)[:, None]
    bend = 0.2 * rng.uniform(-1, 1) * (1.0 - (s / 1.5) ** 2)  # straight or gently curved
    path = zone.center + (semi.max() * rng.uniform(1.02, 1.3) + bend) * n + s * w
    _check(monkeypatch, tmp_path, zone, path)


def test_far_keep_out_is_left_out_and_clearance_panel_reads_the_distance(monkeypatch, tmp_path):
    near = Ellipsoid.from_semi_axes(np.zeros(3), np.full(3, 0.3))
    far = Ellipsoid.from_semi_axes(np.array([5.0, 5.0, 5.0]), np.full(3, 0.3))
    scene = Scene(keep_out=(near, far))
    path = np.column_stack([np.linspace(-1, 1, 201), np.full(201, 0.5), np.zeros(201)])
    panels, drawn = _drawn_panels(monkeypatch, tmp_path, scene, path, robot_radius_m=0.1)
    assert drawn.zones == [near] and len(panels) == 3  # the path clears in 3-D and in the top view: no 4th view
    # closest approach: the point (0, 0.5, 0), 0.2 m from the sphere's surface, minus the robot radius 0.1 m
    assert drawn.clearance_m is not None and drawn.clearance_m.min() == pytest.approx(0.1, abs=1e-9)
