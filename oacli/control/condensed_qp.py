"""The condensed dense form of a compiled controller QP, solved by DAQP: a lower limit for the controller's step.

:class:`oacli.control.compiled_qp.CompiledQP` holds cvxpy's canonical form of a DPP problem,
``minimise ½xᵀPx + qᵀx  s.t.  A_eq x = b_eq,  A_in x ≤ b_in`` with ``q``, ``b`` (and the values of ``A``) affine in
the parameter vector θ. Condensing eliminates the equality rows (the prediction model, ``x_0 = x̂``): with ``Z`` an
orthonormal basis of the null space of the constant ``A_eq`` and ``x = A_eq⁺ b_eq + Z y``, the problem becomes the
dense QP

    minimise ½ yᵀ (ZᵀPZ) y + (Zᵀ(P x_p + q))ᵀ y   s.t.   (A_in Z) y ≤ b_in − A_in x_p,   x_p = A_eq⁺ b_eq,

the classical condensed MPC QP (inputs, the free initial nominal state and slacks as unknowns; Mayne, Seron &
Raković 2005 for the tube problem) when the equalities are the dynamics. ``ZᵀPZ``, ``A_eq⁺`` and, when ``A`` is
constant, ``A_in Z`` are computed once; each solve costs a few dense matrix-vector products and one DAQP call
(dual active-set, Arnström, Bemporad & Axehill 2022), which is why the benchmarks use it as the lower limit of a
controller step (``benchmarks/bench_tube_mpc.py``). The same problem as the cvxpy one: the tests compare the
solutions. DAQP (``pip install daqp``, the ``bench`` extra) is imported on first use; the controllers themselves
solve with Clarabel.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.linalg as sla

from oacli.control.compiled_qp import CompiledQP


class CondensedQP:
    """The condensed QP of a :class:`CompiledQP` (module docstring), solved with DAQP.

    Parameters
    ----------
    compiled : CompiledQP
        A compiled problem whose cones are one zero cone (equalities) followed by one nonnegative cone.
    ridge : float
        Added to the diagonal of the condensed Hessian (it is singular along slack variables).

    Raises
    ------
    ValueError
        When the cones are not of that form or the equalities depend on the parameters.
    """

    def __init__(self, compiled: CompiledQP, ridge: float = 1e-7) -> None:
        import daqp

        self._daqp = daqp
        self.compiled = compiled
        cones = compiled._cones
        kinds = [type(c).__name__ for c in cones]
        if kinds not in (["ZeroConeT", "NonnegativeConeT"], ["NonnegativeConeT"]):
            raise ValueError(f"condensing needs equality then inequality rows, got cones {kinds}")
        n_eq = int(cones[0].dim) if kinds[0] == "ZeroConeT" else 0
        a = compiled._a.toarray()
        self.n_eq = n_eq
        a_eq, self._a_in = a[:n_eq], a[n_eq:]
        if compiled._t_a is not None:
            theta_probe = np.random.default_rng(0).standard_normal(compiled._n_params + 1)
            theta_probe[compiled._const_col] = 1.0
            a_probe = compiled._a.copy()
            a_probe.data = compiled._t_a @ theta_probe
            if np.any(a_probe.toarray()[:n_eq] != a_eq):
                raise ValueError("the equality rows depend on the parameters: cannot condense once")
        p = compiled._p.toarray()
        p = np.triu(p) + np.triu(p, 1).T  # Clarabel holds the upper triangle
        self._p = p
        if n_eq:
            self._z = sla.null_space(a_eq)
            self._a_eq_pinv = np.linalg.pinv(a_eq)
        else:
            self._z = np.eye(a.shape[1])
            self._a_eq_pinv = np.zeros((a.shape[1], 0))
        self._h = self._z.T @ p @ self._z
        self._h = 0.5 * (self._h + self._h.T)
        # Slack variables (soft limits, exact ℓ1 penalty) carry no quadratic weight: a tiny ridge makes H positive
        # definite, as DAQP needs, and moves the solution by O(ridge · |y|) (the tests bound the difference).
        self._h += ridge * np.eye(self._h.shape[0])
        self._pz = p @ self._z
        self._a_in_z = self._a_in @ self._z
        self.n_unknowns = self._z.shape[1]
        self.n_rows = self._a_in.shape[0]
        self._x: np.ndarray | None = None

    def solve(self, values: dict[Any, Any] | None = None, **settings: Any) -> tuple[bool, int, float]:
        """Solve the condensed QP for the parameter values (as :meth:`CompiledQP.solve`).

        Parameters
        ----------
        values : dict, optional
            Parameter values by parameter id; parameters not in it use their ``.value``.
        **settings
            DAQP settings (e.g. ``iter_limit``).

        Returns
        -------
        success : bool
        iterations : int
        wall_s : float
            Wall time of the condensing and the DAQP call [s].
        """
        comp = self.compiled
        theta = comp.parameter_vector(values)
        start = time.perf_counter()
        q = comp._t_q @ theta
        b = comp._t_b @ theta
        b_eq, b_in = b[: self.n_eq], b[self.n_eq :]
        a_in_z = self._a_in_z
        a_in = self._a_in
        if comp._t_a is not None:
            a_now = comp._a.copy()
            a_now.data = comp._t_a @ theta
            a_in = a_now.toarray()[self.n_eq :]
            a_in_z = a_in @ self._z
        x_p = self._a_eq_pinv @ b_eq
        f = self._pz.T @ x_p + self._z.T @ q
        upper = b_in - a_in @ x_p
        lower = np.full_like(upper, -1e30)
        y, _fval, flag, info = self._daqp.solve(self._h, f, a_in_z, upper, lower, np.zeros(upper.size, np.int32),
                                                **settings)
        wall = time.perf_counter() - start
        ok = flag == 1
        self.exitflag = int(flag)
        self._x = x_p + self._z @ np.asarray(y) if ok else None
        return ok, int(info["iterations"]), wall

    def value(self, variable: Any) -> np.ndarray:
        """Value of a variable of the compiled problem in the last successful solve (its shape).

        Parameters
        ----------
        variable : cvxpy.Variable

        Returns
        -------
        ndarray
        """
        if self._x is None:
            raise RuntimeError("no solution: the last solve failed or none was run")
        col = self.compiled._var_cols[variable.id]
        return self._x[col : col + variable.size].reshape(variable.shape, order="F")
