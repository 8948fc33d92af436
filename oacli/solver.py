"""Solve a cvxpy problem with Clarabel and record the outcome as :class:`oacli.types.SolveInfo`.

Every cvxpy solve of the core goes through :func:`solve_clarabel`: the controllers' plain path
(:mod:`oacli.control.mpc`, :mod:`oacli.control.tube_qp`; their compiled fast path,
:mod:`oacli.control.compiled_qp`, reports the same record), the subproblems of the excitation design
(:mod:`oacli.excitation.subproblem`), of the RATTLE planner (:mod:`oacli.excitation.rattle`) and of the smoothing
polish (:mod:`oacli.planning.polish`). A solver that raises is reported, not raised: the status then reads
``solver_error: <reason>`` (:func:`solver_error_status`) and ``success`` is False; a status in
:data:`SUCCESS_STATUSES` means the solution may be used.
"""

from __future__ import annotations

import contextlib
import time
import warnings
from typing import Any

import cvxpy as cp

from oacli.types import SolveInfo

SUCCESS_STATUSES = frozenset({"optimal", "optimal_inaccurate"})
"""cvxpy statuses whose solution is used (an inaccurate solve is judged by its caller, not discarded)."""

MAX_STATUS_CHARS = 120
"""Longest status string: a solver's error message is cut to its first line and to this many characters."""


def solver_error_status(reason: object) -> str:
    """The status of a solve that did not finish: ``solver_error: <first line of reason>``, at most 120 characters.

    Parameters
    ----------
    reason : object
        The exception the solver raised, or a text saying what went wrong.

    Returns
    -------
    str
    """
    return f"solver_error: {reason}".splitlines()[0][:MAX_STATUS_CHARS]


def solve_clarabel(problem: cp.Problem, *, quiet: bool = False, **solve_options: Any) -> SolveInfo:
    """``problem.solve(solver=CLARABEL, **solve_options)``, timed, with its outcome as a :class:`SolveInfo`.

    Parameters
    ----------
    problem : cvxpy.Problem
    quiet : bool, optional
        Silence cvxpy's ``UserWarning`` (e.g. "solution may be inaccurate"): the status reports it.
    **solve_options
        Passed to ``problem.solve`` (Clarabel settings, ``canon_backend``, ...).

    Returns
    -------
    SolveInfo
        ``status`` cvxpy's status (or :func:`solver_error_status` when the solver raised); ``success`` when it is
        in :data:`SUCCESS_STATUSES`; then ``objective`` (the problem's value) and ``iterations`` (Clarabel's, -1
        when unknown), NaN and -1 otherwise; ``solve_time_s`` the wall time of the call [s]; ``step_time_s`` NaN
        (the caller's to fill).
    """
    start = time.perf_counter()
    try:
        with warnings.catch_warnings() if quiet else contextlib.nullcontext():
            if quiet:
                warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=cp.CLARABEL, **solve_options)
        status = str(problem.status)
    except cp.error.SolverError as exc:
        status = solver_error_status(exc)
    solve_time = time.perf_counter() - start
    success = status in SUCCESS_STATUSES
    stats = problem.solver_stats if success else None
    iterations = int(stats.num_iters) if stats is not None and stats.num_iters is not None else -1
    objective = float(problem.value) if success else float("nan")  # type: ignore[arg-type]
    return SolveInfo(status, success, objective, iterations, solve_time)




#: Clarabel's status strings -> cvxpy's status names (as cvxpy maps them), for the paths that call Clarabel
#: directly (:mod:`oacli.control.compiled_qp`, :mod:`oacli.planning.polish_conic`).
CLARABEL_STATUS = {
    "Solved": "optimal",
    "AlmostSolved": "optimal_inaccurate",
    "PrimalInfeasible": "infeasible",
    "AlmostPrimalInfeasible": "infeasible_inaccurate",
    "DualInfeasible": "unbounded",
    "AlmostDualInfeasible": "unbounded_inaccurate",
    "MaxIterations": "user_limit",
    "MaxTime": "user_limit",
}

__all__ = ["CLARABEL_STATUS", "MAX_STATUS_CHARS", "SUCCESS_STATUSES", "solve_clarabel", "solver_error_status"]
