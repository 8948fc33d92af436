"""The condensed dense form of a compiled controller QP, solved by DAQP: a lower limit for the controller's step.

:class:`oacli.control.compiled_qp.CompiledQP` holds cvxpy's canonical form of a DPP problem,
``minimise ½xᵀPx + qᵀx  s.t.  A_eq x = b_eq,  A_in x ≤ b_in`` with ``q``, ``b`` (and the values of ``A``) affine in
the parameter vector θ. Condensing eliminates the equality rows (the prediction model, ``x_0 = x̂``): with ``Z`` an
orthonormal basis of the null space of the constant ``A_eq`` and ``x = A_eq⁺ b_eq + Z y``, the problem becomes the
dense QP

    minimise ½ yᵀ (ZᵀPZ) y + (Zᵀ(P x_p + q))ᵀ y   s.t.   (A_in Z) y ≤ b_in − A_in x_p,   x_p = A_eq⁺ b_eq,

the classical condensed MPC QP (inputs, the free initial nominal state and slacks as unknowns; Mayne, Seron &
Raković 2005 for the tube problem) when the equalities are the dynamics. Everything that does not depend on θ is
done once, at construction, which is the fastest honest setup of the peer (``benchmarks/bench_tube_mpc.py`` uses it
as the lower limit of a controller step):

* the condensing: ``ZᵀPZ``, ``A_in Z`` and, when ``A`` is constant, the linear maps ``θ ↦ f = Zᵀ(P x_p + q)`` and
  ``θ ↦ b_in − A_in x_p`` as one dense matrix (one matrix-vector product per solve);
* DAQP's own set-up (dual active-set, Arnström, Bemporad & Axehill 2022): its Python ``daqp.Model`` factorises
  ``H`` and forms its constraint data once (``daqp.solve`` repeats both at every call, 2.5× the solve at N = 5);
  each solve updates ``f`` and the bounds only (and ``A`` when a parameter enters it);
* a hot start (``warm_start=True``, default): DAQP starts from the working set of the previous solve, as an
  active-set MPC does from step to step (Arnström et al. 2022); the optimum is the same (the tests compare),
  only the iterations differ. ``warm_start=False`` starts every solve from the empty working set.

The same problem as the cvxpy one: the tests compare the solutions. DAQP (``pip install daqp``, the ``bench``
extra) is imported on first use; the controllers themselves solve with Clarabel.
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
    warm_start : bool
        Start each solve from the previous solve's working set (True) or from the empty one (False).

    Raises
    ------
    ValueError
        When the cones are not of that form or the equalities depend on the parameters.
    """

    def __init__(self, compiled: CompiledQP, ridge: float = 1e-7, *, warm_start: bool = True) -> None:
        import daqp

        self._daqp = daqp
        self.compiled = compiled
        self.warm_start = bool(warm_start)
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
        if n_eq:
            self._z = sla.null_space(a_eq)
            a_eq_pinv = np.linalg.pinv(a_eq)
        else:
            self._z = np.eye(a.shape[1])
            a_eq_pinv = np.zeros((a.shape[1], 0))
        h = self._z.T @ p @ self._z
        h = 0.5 * (h + h.T)
        # Slack variables (soft limits, exact ℓ1 penalty) carry no quadratic weight: a tiny ridge makes H positive
        # definite, as DAQP needs, and moves the solution by O(ridge · |y|) (the tests bound the difference).
        self._h = h + ridge * np.eye(h.shape[0])
        t_q, t_b = compiled._t_q.toarray(), compiled._t_b.toarray()
        # θ ↦ x_p = A_eq⁺ b_eq, f = Zᵀ(P x_p + q) and (A constant) b_in − A_in x_p: linear maps, formed once.
        self._x_p_map = a_eq_pinv @ t_b[:n_eq]
        self._f_map = self._z.T @ (p @ self._x_p_map + t_q)
        self._b_in_map = t_b[n_eq:]
        self._a_in_z = self._a_in @ self._z
        self.n_unknowns = self._z.shape[1]
        self.n_rows = self._a_in.shape[0]
        self._data_map: np.ndarray | None = None  # [f; b_in − A_in x_p] as one map when A is constant
        if compiled._t_a is None:
            self._data_map = np.vstack([self._f_map, self._b_in_map - self._a_in @ self._x_p_map])
        self._lower = np.full(self.n_rows, -1e30)
        self._sense = np.zeros(self.n_rows, np.int32)
        self._model: Any = None  # daqp.Model, set up at the first solve (its factorisation of H: once)
        self._theta: np.ndarray | None = None
        self._y: np.ndarray | None = None
        self.exitflag = 0

    def _data(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``f``, the upper bounds and (when a parameter enters A) ``A_in Z`` for θ."""
        if self._data_map is not None:
            g = self._data_map @ theta
            return g[: self.n_unknowns], g[self.n_unknowns :], None
        comp = self.compiled
        a_now = comp._a.copy()
        a_now.data = comp._t_a @ theta
        a_in = a_now.toarray()[self.n_eq :]
        upper = self._b_in_map @ theta - a_in @ (self._x_p_map @ theta)
        return self._f_map @ theta, upper, a_in @ self._z

    def solve(self, values: dict[Any, Any] | None = None, **settings: Any) -> tuple[bool, int, float]:
        """Solve the condensed QP for the parameter values (as :meth:`CompiledQP.solve`).

        Parameters
        ----------
        values : dict, optional
            Parameter values by parameter id; parameters not in it use their ``.value``.
        **settings
            DAQP settings (e.g. ``iter_limit``), applied from this solve on.

        Returns
        -------
        success : bool
        iterations : int
        wall_s : float
            Wall time of the condensing (the data update) and the DAQP solve [s]; the set-up of the first solve
            (DAQP's factorisation) is not included.
        """
        theta = self.compiled.parameter_vector(values)
        if self._model is None:
            f, upper, a_in_z = self._data(theta)
            self._model = self._daqp.Model()
            flag = self._model.setup(self._h, f, self._a_in_z if a_in_z is None else a_in_z, upper, self._lower,
                                     self._sense)
            flag = flag[0] if isinstance(flag, tuple) else flag
            if flag < 0:
                raise RuntimeError(f"DAQP set-up failed (exit flag {flag})")
        if settings:
            self._model.settings = settings
        start = time.perf_counter()
        f, upper, a_in_z = self._data(theta)
        update: dict[str, np.ndarray] = {"f": f, "bupper": upper}
        if a_in_z is not None:
            update["A"] = a_in_z
        if not self.warm_start:
            update["sense"] = self._sense  # the empty working set
        self._model.update(**update)
        y, _fval, flag, info = self._model.solve()
        wall = time.perf_counter() - start
        ok = flag == 1
        self.exitflag = int(flag)
        self._theta, self._y = (theta, np.array(y)) if ok else (None, None)
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
        if self._theta is None or self._y is None:
            raise RuntimeError("no solution: the last solve failed or none was run")
        x = self._x_p_map @ self._theta + self._z @ self._y
        col = self.compiled._var_cols[variable.id]
        return np.asarray(x[col : col + variable.size].reshape(variable.shape, order="F"))
