"""Solve a parametrised cvxpy QP by calling Clarabel directly with updated data (the fast path).

cvxpy canonicalises a DPP problem into ``minimise ½xᵀPx + qᵀx + d  s.t.  A x + s = b, s ∈ K`` with
``(q, d)`` and ``(A, b)`` affine in the parameter vector θ: ``problem.get_problem_data(CLARABEL)`` builds that
parametrised cone program once (cvxpy's ``ParamConeProg``, stored in the data under ``"param_prob"``, already in
Clarabel's cone order) and every ``problem.solve()`` re-applies it, formats the data, builds a new Clarabel
solver and inverts the solution through the reduction chain. When the parameters enter only ``q``, ``d`` and
``b`` (P and A constant, checked here), all of that reduces to two sparse matrix-vector products
``q = T_q θ``, ``b = T_b θ``, ``DefaultSolver.update(q=q, b=b)`` and ``solve()`` on one solver object, and the
variables are slices of Clarabel's ``x`` (cvxpy's ``var_id_to_col``, column-major). The problem stays
formulated in cvxpy; the tests check that both paths give the same solution.

Parameters may also multiply variables in the constraints (``nᵀ p ≥ β`` with a Parameter normal n, as the
controllers' keep-out half-spaces): the DPP tensor then maps θ to the *values* of A as well. Its sparsity pattern
is every entry that some θ can make non-zero (the structural entries of the tensor, kept even when their current
value is 0), fixed at construction; each solve computes the values ``T_A θ`` in that pattern's column-major order
(Clarabel's CSC order) and passes them to ``update(A=...)``, which keeps the KKT system's symbolic structure.
P must stay constant.
"""

from __future__ import annotations

import time
from typing import Any

import clarabel
import cvxpy as cp
import numpy as np
import scipy.sparse as sp
from cvxpy import settings as cps
from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import dims_to_solver_cones
from cvxpy.reductions.solvers.conic_solvers.conic_solver import ConicSolver

from oacli.solver import CLARABEL_STATUS, SUCCESS_STATUSES, solver_error_status
from oacli.types import SolveInfo

#: Clarabel settings of the controllers' QPs (both solve paths): the defaults except iterative refinement of the
#: KKT solves, which costs more than half the solve time on these small, well-scaled QPs; the interior-point method
#: still stops only when Clarabel's residual and gap tolerances (1e-8) are met (tests compare with the defaults).
CLARABEL_OPTIONS: dict[str, Any] = {"iterative_refinement_enable": False}


class CompiledQP:
    """A DPP cvxpy problem canonicalised once and re-solved with Clarabel directly.

    Parameters
    ----------
    problem : cvxpy.Problem
        DPP problem whose parameters appear only in the linear objective term, the objective constant, the
        constraint right-hand sides (the usual MPC: initial state and references) and the constraint matrix
        (linear in the parameters, e.g. half-space normals).
    settings : clarabel.DefaultSettings, optional
        Solver settings; Clarabel's defaults (as ``problem.solve(solver=CLARABEL)`` uses) when omitted.

    Raises
    ------
    ValueError
        When the problem is not DPP or a parameter enters P.
    """

    def __init__(self, problem: cp.Problem, settings: clarabel.DefaultSettings | None = None) -> None:
        if not problem.is_dpp():
            raise ValueError("the problem is not DPP: it cannot be canonicalised once")
        self.problem = problem
        data, _chain, _inverse = problem.get_problem_data(cp.CLARABEL)
        prog = data[cps.PARAM_PROB]
        n = prog.x.size
        # The tensor has (n + 1)·m rows (the column-major entries of A, then b), one column per parameter entry
        # plus the constant: work on its stored entries (COO) rather than slicing a matrix of n·m rows.
        tensor = sp.coo_array(prog.A)
        n_cols = tensor.shape[1]
        m = tensor.shape[0] // (n + 1)
        if prog.P is not None and sp.csc_array(prog.P)[:, :-1].nnz:
            raise ValueError("a parameter enters the quadratic term: use problem.solve()")
        rows, cols, vals = tensor.coords[0].astype(np.int64), tensor.coords[1].astype(np.int64), tensor.data
        in_a = rows < m * n
        ra, ca, va = rows[in_a], cols[in_a], vals[in_a]
        self._t_a: sp.csr_array | None = None
        if np.any((ca < n_cols - 1) & (va != 0)):
            # Structural entries of A (rows of the tensor = column-major positions in A), sorted = CSC order.
            # Clarabel's form A x + s = b holds −A of cvxpy's A x + b ∈ K.
            flat = np.unique(ra)
            self._t_a = sp.csr_array((-va, (np.searchsorted(flat, ra), ca)), shape=(flat.size, n_cols))
            counts = np.bincount(flat // m, minlength=n)
            self._a_structure = (flat % m, np.concatenate([[0], np.cumsum(counts)]))
            self._a_param_cols = np.unique(ca[(ca < n_cols - 1) & (va != 0)])
        else:
            # Clarabel's form A x + s = b: the data already hold A negated by ConicSolver.apply.
            self._a = sp.csc_matrix(data[cps.A])
        self._p = sp.csc_matrix(sp.triu(data[cps.P])) if cps.P in data else sp.csc_matrix((n, n))
        self._t_b = sp.csr_array((vals[~in_a], (rows[~in_a] - m * n, cols[~in_a])), shape=(m, n_cols))
        t_q = sp.csr_array(prog.q)
        self._t_q, self._t_d = sp.csr_array(t_q[:n, :]), t_q[[n], :].toarray().ravel()
        self._cones = dims_to_solver_cones(data[ConicSolver.DIMS])
        self._n_params = prog.total_param_size
        self._param_slices = []
        known = {p.id: p for p in problem.parameters()}
        for pid, col in prog.param_id_to_col.items():
            if pid == -1 or pid not in known:
                if pid in prog.id_to_param and pid not in known:
                    raise ValueError("cvxpy replaced a parameter (attributes): use plain cp.Parameter objects")
                continue
            self._param_slices.append((known[pid], col, prog.param_id_to_size[pid], pid))
        self._const_col = prog.param_id_to_col[-1] if -1 in prog.param_id_to_col else self._n_params
        self._var_cols = {v.id: prog.var_id_to_col[v.id] for v in problem.variables() if v.id in prog.var_id_to_col}
        self.n_variables, self.n_constraints = n, m
        self._settings = settings or clarabel.DefaultSettings()
        self._settings.verbose = False
        theta = self.parameter_vector(missing_as_zero=True)  # structure only: q and b are set at every solve
        if self._t_a is not None:
            # Clarabel equilibrates A once, here: unset parameters entering A count as 1 (a row of zeros would
            # get an extreme scaling), then A's values are updated at every solve.
            theta_a = theta.copy()
            unset = self._a_param_cols[theta_a[self._a_param_cols] == 0.0]
            theta_a[unset] = 1.0
            self._a = sp.csc_matrix((self._t_a @ theta_a, *self._a_structure), shape=(m, n))
        self._settings.input_sparse_dropzeros = False  # the pattern must survive values that are 0
        self._solver = clarabel.DefaultSolver(
            self._p, self._t_q @ theta, self._a, self._t_b @ theta, self._cones, self._settings
        )
        if not self._solver.is_data_update_allowed():
            raise ValueError("Clarabel does not allow data updates with these settings (presolve/chordal)")
        # T_q, T_b (and T_A) stacked: one sparse product per solve (each row's sum is the same as in its own
        # matrix: CSR rows are kept with their entries in order).
        parts = [self._t_q, self._t_b] + ([] if self._t_a is None else [self._t_a])
        self._t_all = sp.csr_array(sp.vstack(parts, format="csr"))
        self._split = (n, n + m)
        self._x: np.ndarray | None = None
        self._a_last: np.ndarray | None = None  # A's values at the last update (None: the set-up values)

    def parameter_vector(self, values: dict[Any, Any] | None = None, *, missing_as_zero: bool = False) -> np.ndarray:
        """θ: parameter values, column-major, with the constant 1 at its column (cvxpy's layout).

        ``values`` maps a parameter's id to its value (shape of the parameter); parameters not in it use their
        ``.value``. Passing values directly skips cvxpy's per-assignment validation (the caller checks shapes).

        Parameters
        ----------
        values : dict, optional
            Parameter values by parameter id.
        missing_as_zero : bool, optional
            Leave parameters without a value at zero instead of raising.

        Returns
        -------
        ndarray, shape (n_params + 1,)
        """
        theta = np.zeros(self._n_params + 1)
        for param, col, size, pid in self._param_slices:
            value = values[pid] if values is not None and pid in values else param.value
            if value is None:
                if missing_as_zero:
                    continue
                raise ValueError(f"parameter {param.name()} has no value")
            try:  # column-major, through a Fortran-ordered view of θ's slice (no intermediate copy)
                theta[col : col + size].reshape(param.shape, order="F")[...] = value
            except ValueError:  # another shape of the same size
                theta[col : col + size] = np.asarray(value, dtype=float).ravel(order="F")
        theta[self._const_col] = 1.0
        return theta

    def parameter_views(self, theta: np.ndarray) -> dict[int, np.ndarray]:
        """Views of ``theta``'s slices in each parameter's shape (column-major), by parameter id.

        Writing a parameter's value into its view sets θ exactly as :meth:`parameter_vector` does (the same
        Fortran-ordered view of the slice), so a caller can keep one θ and update it in place.

        Parameters
        ----------
        theta : ndarray, shape (n_params + 1,)
            A parameter vector (e.g. ``parameter_vector(missing_as_zero=True)``), written through the views.

        Returns
        -------
        dict
            Parameter id -> view of ``theta`` in the parameter's shape.
        """
        # A contiguous 1-D slice reshapes to any shape, in either order, as a view of θ.
        return {pid: theta[col : col + size].reshape(param.shape, order="F")
                for param, col, size, pid in self._param_slices}

    def solve(self, values: dict[Any, Any] | None = None) -> SolveInfo:
        """Solve with the parameters' values; variables are then read with :meth:`value`.

        Parameters
        ----------
        values : dict, optional
            Parameter values by parameter id; parameters not in it use their ``.value``.

        Returns
        -------
        SolveInfo
            cvxpy-style status (``"optimal"``, ``"infeasible"``, ...; :func:`oacli.solver.solver_error_status` for
            a Clarabel status cvxpy does not know), success, the objective of the cvxpy problem (NaN unless solved),
            Clarabel's iterations and the wall time of the data update and the solve [s] (Clarabel's own
            ``solve_time`` reads higher than the wall time around the call, so it is not used); ``step_time_s`` NaN.
        """
        return self.solve_vector(self.parameter_vector(values))

    def solve_vector(self, theta: np.ndarray) -> SolveInfo:
        """:meth:`solve` with the parameter vector θ given (:meth:`parameter_vector`'s layout, constant included).

        Parameters
        ----------
        theta : ndarray, shape (n_params + 1,)
            Parameter values, column-major, with the constant 1 at its column.

        Returns
        -------
        SolveInfo
            As :meth:`solve`.
        """
        start = time.perf_counter()
        # The data go to Clarabel as lists: its binding reads a list of floats about twice as fast as an array
        # (the same values).
        stacked = self._t_all @ theta
        n_q, n_qb = self._split
        q, b = stacked[:n_q].tolist(), stacked[n_q:n_qb].tolist()
        if self._t_a is None:
            self._solver.update(q=q, b=b)
        else:
            a_values = stacked[n_qb:]
            if self._a_last is not None and np.array_equal(a_values, self._a_last):
                # A unchanged (e.g. keep-out rows inactive from step to step): Clarabel keeps its scaled copy.
                self._solver.update(q=q, b=b)
            else:
                self._solver.update(q=q, b=b, A=a_values.tolist())
                self._a_last = a_values
        sol = self._solver.solve()
        wall = time.perf_counter() - start
        status = CLARABEL_STATUS.get(str(sol.status)) or solver_error_status(f"Clarabel status {sol.status}")
        self._x = np.asarray(sol.x) if status in SUCCESS_STATUSES else None
        objective = float(sol.obj_val + self._t_d @ theta) if self._x is not None else float("nan")
        return SolveInfo(status, self._x is not None, objective, int(sol.iterations), wall)

    @property
    def solution(self) -> np.ndarray | None:
        """Clarabel's ``x`` of the last successful solve (cvxpy's variable columns), None after a failure or before
        any solve."""
        return self._x

    def value(self, variable: cp.Variable) -> np.ndarray:
        """Value of ``variable`` in the last successful solve (shape of the variable).

        Parameters
        ----------
        variable : cvxpy.Variable
            A variable of the compiled problem.

        Returns
        -------
        ndarray
            Its value, in the variable's shape.
        """
        if self._x is None:
            raise RuntimeError("no solution: the last solve failed or none was run")
        col = self._var_cols[variable.id]
        return self._x[col : col + variable.size].reshape(variable.shape, order="F")
