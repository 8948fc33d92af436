"""One helper solves every cvxpy problem of the core and records the outcome (oacli.solver.solve_clarabel)."""

from __future__ import annotations

import ast
import math
import warnings
from pathlib import Path

import cvxpy as cp
import numpy as np
import pytest

from oacli.control.mpc import LinearMPC
from oacli.model.double_integrator import hover_error_model
from oacli.solver import MAX_STATUS_CHARS, SUCCESS_STATUSES, solve_clarabel, solver_error_status
from oacli.types import InertialParams

ROOT = Path(__file__).resolve().parents[1] / "oacli"


def test_solved_qp_reports_the_closed_form_optimum():
    """min (x − 3)² + (y + 1)² s.t. x + y ≤ 1: the projection of (3, −1) onto the half-plane, (2.5, −1.5), value 0.5."""
    x = cp.Variable(2)
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x - np.array([3.0, -1.0]))), [cp.sum(x) <= 1.0])
    info = solve_clarabel(problem)
    assert info.status == "optimal" and info.success
    assert info.objective == pytest.approx(0.5, abs=1e-7)
    np.testing.assert_allclose(x.value, [2.5, -1.5], atol=1e-6)
    assert info.iterations >= 1 and 0.0 <= info.solve_time_s < 60.0 and math.isnan(info.step_time_s)


def test_infeasible_problem_is_a_failure_without_objective():
    x = cp.Variable()
    info = solve_clarabel(cp.Problem(cp.Minimize(x), [x >= 1.0, x <= 0.0]))
    assert info.status == "infeasible" and info.status not in SUCCESS_STATUSES
    assert not info.success and math.isnan(info.objective) and info.iterations == -1


def test_a_raising_solver_is_reported_in_one_format(monkeypatch):
    def broken(self, *args, **kwargs):
        raise cp.error.SolverError("Clarabel failed: " + "x" * 200 + "\nsecond line")

    monkeypatch.setattr(cp.Problem, "solve", broken)
    x = cp.Variable()
    info = solve_clarabel(cp.Problem(cp.Minimize(x), [x >= 0]))
    assert not info.success and math.isnan(info.objective) and info.iterations == -1
    assert info.status.startswith("solver_error: Clarabel failed: xxx")
    assert len(info.status) == MAX_STATUS_CHARS and "\n" not in info.status
    assert solver_error_status("Clarabel status Unknown") == "solver_error: Clarabel status Unknown"

    # The controllers' plain path reports it the same way.
    a, b = hover_error_model(InertialParams(9.58, (0.153, 0.143, 0.162)), 0.2)
    mpc = LinearMPC(a, b, np.ones(12), np.ones(6), 5, np.full(6, 0.5), fast=False)
    sol = mpc.solve(np.zeros(12), np.zeros((6, 12)), np.zeros((5, 6)))
    assert sol.info.status == info.status and not sol.info.success and np.all(np.isnan(sol.u))


def test_quiet_silences_cvxpy_user_warnings_only_when_asked(monkeypatch):
    real = cp.Problem.solve

    def warns(self, *args, **kwargs):
        warnings.warn("Solution may be inaccurate.", UserWarning, stacklevel=2)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(cp.Problem, "solve", warns)
    x = cp.Variable()
    problem = cp.Problem(cp.Minimize(cp.square(x - 2.0)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert solve_clarabel(problem, quiet=True).objective == pytest.approx(0.0, abs=1e-8)
        with pytest.raises(UserWarning, match="inaccurate"):
            solve_clarabel(problem)


def test_every_cvxpy_solve_of_the_package_goes_through_the_helper():
    """No module but oacli/solver.py calls ``<problem>.solve(solver=...)`` or catches cvxpy's SolverError."""
    offenders = []
    for path in sorted(ROOT.rglob("*.py")):
        if path == ROOT / "solver.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "solve"
                    and any(k.arg == "solver" for k in node.keywords)):
                offenders.append(f"{path.relative_to(ROOT.parent)}:{node.lineno} .solve(solver=...)")
            if isinstance(node, ast.Attribute) and node.attr == "SolverError":
                offenders.append(f"{path.relative_to(ROOT.parent)}:{node.lineno} SolverError")
    assert not offenders, offenders
