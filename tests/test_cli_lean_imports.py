"""``oacli --help`` and ``oacli report`` start lean (issue 34: writing the report costs ≤ 10 % of the mission; the
CLI's start-up was most of it): they do not import the solvers (cvxpy, clarabel), Rerun, scipy, the planners, the
controllers or the estimators. Each command runs in a fresh interpreter, whose ``sys.modules`` is read back after.

With the page's figures present (a mission that wrote its report) neither matplotlib nor the config models are
imported either; without them the report draws its tracking figure from the stage MCAPs (matplotlib, the configs)
and still needs no scipy (the tube bands' extents: :func:`oacli.mission.records.first_coordinate_range`).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from oacli.mission.records import first_coordinate_range
from oacli.sets import Polytope

ROOT = Path(__file__).resolve().parents[1]
NEVER = ("cvxpy", "clarabel", "osqp", "rerun", "scipy", "oacli.planning", "oacli.control", "oacli.estimation",
         "oacli.excitation", "oacli.sim", "oacli.stages", "oacli.campaign")
"""Packages neither ``oacli --help`` nor ``oacli report`` of a mission imports."""

SNIPPET = """
import json, runpy, sys
sys.argv = ["oacli", *json.loads(sys.argv[1])]
try:
    runpy.run_module("oacli", run_name="__main__")
except SystemExit as exc:
    code = exc.code
else:
    code = 0
print(json.dumps({"code": code, "modules": sorted(sys.modules)}), file=sys.stderr)
"""


def imported(args: list[str]) -> set[str]:
    """The modules a fresh ``oacli ARGS`` has imported when it exits (asserting it exits 0)."""
    proc = subprocess.run([sys.executable, "-c", SNIPPET, json.dumps(args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    result = json.loads(proc.stderr.strip().splitlines()[-1])
    assert result["code"] in (0, None), proc.stderr
    return set(result["modules"])


def heavy(modules: set[str], packages: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in packages))


def test_help_imports_no_solver_no_config_no_numpy():
    modules = imported(["--help"])
    assert heavy(modules, (*NEVER, "numpy", "matplotlib", "oacli.config", "oacli.mission", "oacli.report")) == []


def test_report_with_its_figures_in_the_folder_reads_only_files(mission_run, tmp_path):
    run = mission_run[0]
    assert (run / "plots" / "tracking_bands.png").is_file()  # left by the mission's own report
    modules = imported(["report", str(run), "--out", str(tmp_path / "r.html"), "-q"])
    assert (tmp_path / "r.html").stat().st_size > 100_000
    assert heavy(modules, (*NEVER, "matplotlib", "oacli.config", "oacli.mission.records", "oacli.sets")) == []


def test_report_drawing_its_tracking_figure_imports_no_solver_nor_scipy(mission_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(mission_run[0], run)
    (run / "plots" / "tracking_bands.png").unlink()
    modules = imported(["report", str(run), "--out", str(tmp_path / "r.html"), "-q"])
    assert "matplotlib" in modules and "oacli.mission.records" in modules  # it did draw
    assert heavy(modules, (*NEVER, "oacli.sets")) == []
    # the figure drawn is the one the mission's report drew (the same data, the same extents)
    assert (run / "plots" / "tracking_bands.png").read_bytes() == \
        (mission_run[0] / "plots" / "tracking_bands.png").read_bytes()


def test_report_of_a_run_without_plots_draws_every_figure_without_the_estimators(mission_run, tmp_path):
    """A campaign's run (``outputs.plots: none``): the report draws its three figures from the MCAPs, still without
    scipy or the estimators (the flight's error figures are a constant of the plots, equal to the estimator's)."""
    from oacli.estimation.rls import RATTLE_TABLE_ERROR_PCT
    from oacli.mission.plots import FLIGHT_ERROR_PCT
    from oacli.report.mission import FLIGHT_ERROR_PCT as REPORT_FLIGHT_ERROR_PCT

    assert FLIGHT_ERROR_PCT == RATTLE_TABLE_ERROR_PCT == REPORT_FLIGHT_ERROR_PCT == (0.39, 0.91, 1.35, 6.92)
    run = tmp_path / "run"
    shutil.copytree(mission_run[0], run)
    shutil.rmtree(run / "plots")
    modules = imported(["report", str(run), "--out", str(tmp_path / "r.html"), "-q"])
    assert "oacli.mission.plots" in modules and (tmp_path / "r.html").read_text().count("data:image/png") == 3
    assert heavy(modules, (*NEVER, "oacli.sets")) == []


def test_first_coordinate_range_is_the_polytope_support(rng):
    """Random bounded polygons (a random point set's hull, as inequalities with redundant and near-parallel rows)
    against :meth:`Polytope.support` (scipy's HalfspaceIntersection / linprog); unbounded and empty ones are
    handed to it."""
    for _ in range(60):
        pts = rng.normal(size=(rng.integers(3, 12), 2)) * rng.uniform(0.01, 3.0, size=2)
        hull = Polytope.from_vertices(pts)
        a = np.vstack([hull.a, hull.a[:2] * (1 + 1e-13)])
        b = np.r_[hull.b, hull.b[:2] * (1 + 1e-13) + 0.5]  # redundant rows
        low, high = first_coordinate_range(a, b)
        assert low == pytest.approx(pts[:, 0].min(), abs=1e-9) and high == pytest.approx(pts[:, 0].max(), abs=1e-9)
        ref = Polytope(a, b)
        assert low == pytest.approx(-ref.support(np.array([-1.0, 0.0])), abs=1e-9)
        assert high == pytest.approx(ref.support(np.array([1.0, 0.0])), abs=1e-9)
    half_plane = first_coordinate_range(np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), np.ones(3))
    assert half_plane == (-np.inf, 1.0)
    empty = first_coordinate_range(np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]),
                                   np.array([-1.0, -1.0, 1.0, 1.0]))  # x <= -1 and x >= 1
    assert empty == (np.inf, -np.inf)
