"""Trajectory polish, part 4: the SCP subproblem assembled directly in Clarabel's conic form (the fast path).

The same second-order cone program as :class:`~oacli.planning.polish_subproblem.PolishSubproblem` (the module
docstring of :mod:`oacli.planning.polish`; that cvxpy/DPP formulation stays the reference, and the tests check
that both give the same optimum). cvxpy's one-time canonicalisation of that problem grows with N² and costs
seconds for a 30 s trajectory, longer than all the subproblem solves together; here the data are written down
directly: ``minimise ½ xᵀ P x + qᵀ x  s.t.  A x + s = b, s ∈ K`` with the variables stacked as
``x = [r (N+1)×3, v (N+1)×3, f N×3, s N, t¹ N, t² N]`` (row-major per knot), ``K`` = zero cone (start, goal and
the exact dynamics), non-negative cone (force, velocity, trust-region, buffer, keep-in and keep-out rows),
second-order cones ``‖P1_k − P0_k‖ <= t¹_k``, ``‖P2_k − P1_k‖ <= t²_k`` and, with a cost cap, one cone for
``½ ‖G z‖² <= J_max − w_t Σ h``, written as ``‖[2 G z; α − 1]‖ <= α + 1`` with ``α = 2 (J_max − w_t Σ h)``.
``G`` per piece and axis is the factor ``W(h) = Gᵀ G`` of :func:`~oacli.planning.translational.
interval_cost_matrix` (as :func:`~oacli.planning.polish_subproblem.lqr_cost_expression`).

The constant structure (dynamics, limits, cones, objective) is built once per grid; each :meth:`solve` writes the
rows that depend on the reference (keep-in bounds, keep-out half-spaces, trust region) and calls Clarabel.

Working set (active-set style, exact)
-------------------------------------
Most force, velocity and trust-region rows and the cost cap's cone are slack at the optimum, and they make up
half of the rows (the cone of the cap is dense over the knots). The first SCP subproblem is solved with all of
them; each later one first with a *working set*: the rows whose bound its reference (:meth:`set_working_hint`;
the previous solution, corrected) comes within :data:`NEAR_FRACTION` of, and the trust-region rows of the knots
the last step moved by :data:`NEAR_TRUST_FRACTION` of Δ. The solution is then checked against every left-out
row; the violated ones (and those it comes within :data:`WIDE_FRACTION` of) join the set and the problem is
solved again, until the solution satisfies them all (at the latest when the set is complete). The
relaxed problem's optimum satisfying every left-out constraint is the optimum of the full problem (a relaxation
whose optimum is feasible for the original is optimal for it), so the result is the full subproblem's: only the
time changes. (The keep-in and keep-out rows left out as implied by the trust region stay implied: the accepted
solution satisfies every trust-region row.)
"""

from __future__ import annotations

import clarabel
import numpy as np
import scipy.sparse as sp

from oacli.model.robot_model import RobotModel
from oacli.planning.polish_settings import PolishSettings
from oacli.planning.translational import CostWeights, interval_cost_matrix
from oacli.solver import CLARABEL_STATUS, solver_error_status

#: A row is left out only when the reachable set satisfies it with at least this margin [m].
_IMPLIED_M = 1e-6
#: A limit row (or the cost cap) joins the working set when a reference or solution uses this fraction of its bound.
NEAR_FRACTION = 0.1
#: ... and, after a solution broke a left-out row, every row that solution used this fraction of.
WIDE_FRACTION = 0.5
#: A knot's trust-region rows join the working set when the last step moved it this fraction of the radius Δ (and
#: when a solution moves it beyond :data:`WIDE_FRACTION` of Δ after breaking one).
NEAR_TRUST_FRACTION = 0.25
#: A left-out row counts as violated beyond this [N, m/s; relative for the cost cap] (far below the margin ε F).
_VIOLATION_TOL = 1e-9


class _Rows:
    """COO triplets of a block of constraint rows."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        self.count = 0

    def add(self, cols: list[np.ndarray], vals: list[np.ndarray | float], b: np.ndarray) -> None:
        """Add ``len(b)`` rows ``Σ_j vals[j][r] x[cols[j][r]]`` (each entry list of length len(b))."""
        b = np.asarray(b, dtype=float)
        idx = self.count + np.arange(b.size)
        for c, v in zip(cols, vals, strict=True):
            self.rows.append(idx)
            self.cols.append(np.asarray(c, dtype=np.int64).ravel())
            self.vals.append(np.broadcast_to(np.asarray(v, dtype=float), b.shape).ravel())
        self.b.append(b.ravel())
        self.count += b.size

    def matrix(self, n: int) -> tuple[sp.coo_matrix, np.ndarray]:
        if not self.count:
            return sp.coo_matrix((0, n)), np.zeros(0)
        a = sp.coo_matrix((np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
                          shape=(self.count, n))
        return a, np.concatenate(self.b)


class PolishConic:
    """The polish subproblem assembled directly for Clarabel (module docstring); same inputs as
    :class:`~oacli.planning.polish_subproblem.PolishSubproblem`.

    Set before each :meth:`solve`: ``r_ref`` (N+1, 3), ``radius``, ``box_lower``/``box_upper`` (N, 3),
    ``normals[j]`` (N, 3), ``offsets[j]`` (N,) and ``cost_cap`` (when built with one). After a successful solve,
    ``f_value`` (N, 3), ``buffer_value`` (N,) and ``objective`` hold the solution.
    """

    def __init__(self, h: np.ndarray, model: RobotModel, start: np.ndarray, goal: np.ndarray,
                 force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray, n_zones: int, settings: PolishSettings,
                 weights: CostWeights, with_cost_cap: bool = False) -> None:
        h = np.asarray(h, dtype=float)
        n, m = h.shape[0], model.mass_kg
        self.h, self.n = h, n
        self.n_zones = int(n_zones)
        self.r_ref: np.ndarray | None = None
        self.radius: float | None = None
        self.box_lower: np.ndarray | None = None
        self.box_upper: np.ndarray | None = None
        self.normals: list[np.ndarray | None] = [None] * self.n_zones
        self.offsets: list[np.ndarray | None] = [None] * self.n_zones
        self.cost_cap: float | None = None
        self.with_cost_cap = bool(with_cost_cap)
        self.f_value: np.ndarray | None = None
        self.buffer_value: np.ndarray | None = None
        self.objective = float("nan")
        # Variable layout.
        k_idx = np.arange(n + 1)
        self._r = (3 * k_idx[:, None] + np.arange(3)).astype(np.int64)  # (N+1, 3)
        self._v = self._r + 3 * (n + 1)
        self._f = (6 * (n + 1) + 3 * np.arange(n)[:, None] + np.arange(3)).astype(np.int64)  # (N, 3)
        self._s = 6 * (n + 1) + 3 * n + np.arange(n)
        self._t1 = self._s + n
        self._t2 = self._t1 + n
        self.n_var = int(self._t2[-1] + 1)
        hc = np.repeat(h[:, None], 3, axis=1)
        # Objective: Σ t¹ + Σ t² + λ Σ s + w_e Σ h ‖f‖² (½ xᵀ P x with P = 2 w_e h on the forces).
        self._q = np.zeros(self.n_var)
        self._q[self._t1] = 1.0
        self._q[self._t2] = 1.0
        self._q[self._s] = settings.buffer_penalty
        p_diag = np.zeros(self.n_var)
        p_diag[self._f.ravel()] = 2.0 * settings.effort_weight * hc.ravel()
        self._p = sp.csc_matrix(sp.diags(p_diag))
        # Equalities: start, goal, exact dynamics.
        eq = _Rows()
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        eq.add([self._r[0]], [1.0], start[0:3])
        eq.add([self._v[0]], [1.0], start[3:6])
        eq.add([self._r[n]], [1.0], goal[0:3])
        eq.add([self._v[n]], [1.0], goal[3:6])
        eq.add([self._r[1:], self._r[:-1], self._v[:-1], self._f], [1.0, -1.0, -hc, -0.5 * hc * hc / m],
               np.zeros((n, 3)))
        eq.add([self._v[1:], self._v[:-1], self._f], [1.0, -1.0, -hc / m], np.zeros((n, 3)))
        self._eq = eq.matrix(self.n_var)
        # Limit rows (A x <= b, one entry each): sign * x[col] <= bound, force then velocity; a working subset
        # of them enters each solve (module docstring). Buffer rows s >= 0 are always in.
        eps = settings.limit_margin
        f_lim = np.tile((1.0 - eps) * np.asarray(force_limit_N, dtype=float), (n, 1)).ravel()
        cols, signs, bounds = [self._f.ravel()] * 2, [np.ones(3 * n), -np.ones(3 * n)], [f_lim, f_lim]
        if n > 1:
            v_lim = np.tile((1.0 - eps) * np.asarray(velocity_limit_mps, dtype=float), (n - 1, 1)).ravel()
            cols += [self._v[1:n].ravel()] * 2
            signs += [np.ones(3 * (n - 1)), -np.ones(3 * (n - 1))]
            bounds += [v_lim, v_lim]
        self._lim_col = np.concatenate(cols).astype(np.int64)
        self._lim_sign = np.concatenate(signs)
        self._lim_bound = np.concatenate(bounds)
        self._lim_work = np.zeros(self._lim_col.shape[0], dtype=bool)
        self._cap_work = False
        self._hinted = False
        self._tr_work = np.zeros((n + 1, 3), dtype=bool)  # trust-region rows (both signs) in the working set
        self._r_prev: np.ndarray | None = None
        self.active_set = bool(settings.active_set)
        self.rounds = 0  # solves of the last :meth:`solve` (working-set rounds)
        buf = _Rows()
        buf.add([self._s], [-1.0], np.zeros(n))
        self._buffer_rows = buf.matrix(self.n_var)
        self._v_bound = np.maximum((1.0 - eps) * np.asarray(velocity_limit_mps, dtype=float), np.abs(start[3:6]))
        self._half_h3 = 0.5 * hc  # (N, 3): P1's coefficient of v_k
        self._half_h_v = 0.5 * self.h[:, None] * self._v_bound  # (N, 3): P1's reach beyond Δ
        # Control points per piece and axis (the variable rows): P0 = r_k, P1 = r_k + h/2 v_k, P2 = r_{k+1}.
        # Second-order cones of the length terms: s = b − A x = (t, d), d = P1 − P0 or P2 − P1.
        soc = _Rows()
        cone_rows = np.empty((2, n, 4), dtype=np.int64)
        for which, (t_col, cols, vals) in enumerate((
            (self._t1, [self._v[:-1]], [0.5 * hc]),
            (self._t2, [self._r[1:], self._r[:-1], self._v[:-1]], [np.ones((n, 3)), -np.ones((n, 3)), -0.5 * hc]),
        )):
            # Interleave per piece: [t_k, d_k,x, d_k,y, d_k,z].
            cone_rows[which] = soc.count + 4 * np.arange(n)[:, None] + np.arange(4)
            for c, v in zip(cols, vals, strict=True):
                soc.rows.append((cone_rows[which][:, 1:]).ravel())
                soc.cols.append(np.asarray(c, dtype=np.int64).ravel())
                soc.vals.append(-np.asarray(v, dtype=float).ravel())
            soc.rows.append(cone_rows[which][:, 0])
            soc.cols.append(t_col)
            soc.vals.append(-np.ones(n))
            soc.b.append(np.zeros(4 * n))
            soc.count += 4 * n
        self._soc = soc.matrix(self.n_var)
        self._n_soc = 2 * n
        self._cap = self._cap_rows(h, model, weights, goal) if self.with_cost_cap else None
        self._cap_gz = None if self._cap is None else (self._cap[0].tocsr()[1:-1], self._cap[1][1:-1])
        self._time_cost = weights.time * float(h.sum())
        # Clarabel without iterative refinement of its KKT solves: half the time per interior-point iteration on
        # these problems, same iterations and optimum (to ~1e-10 on S2); a solve that does not end ``Solved`` is
        # repeated with the refinement (Clarabel's default).
        self._settings_refined = clarabel.DefaultSettings()
        self._settings_refined.verbose = False
        self._settings = clarabel.DefaultSettings()
        self._settings.verbose = False
        self._settings.iterative_refinement_enable = False

    def set_reference(self, r_ref: np.ndarray, radius: float, box_lower: np.ndarray, box_upper: np.ndarray,
                      normals: list[np.ndarray], offsets: list[np.ndarray]) -> None:
        """Set the data of one SCP iteration (trust-region centre and radius, keep-in bounds, half-spaces).

        Parameters
        ----------
        r_ref : ndarray, shape (N+1, 3)
            Trust-region centre: the reference's knot positions [m].
        radius : float
            Trust radius Δ [m].
        box_lower, box_upper : ndarray, shape (N, 3)
            Keep-in box of each piece [m].
        normals : list of ndarray, shape (N, 3)
            Per keep-out zone, the half-space normals of the pieces.
        offsets : list of ndarray, shape (N,)
            Per keep-out zone, the half-space offsets.
        """
        self.r_ref, self.radius = np.asarray(r_ref, dtype=float), float(radius)
        self.box_lower, self.box_upper = np.asarray(box_lower, dtype=float), np.asarray(box_upper, dtype=float)
        self.normals = [np.asarray(v, dtype=float) for v in normals]
        self.offsets = [np.asarray(v, dtype=float) for v in offsets]

    def set_cost_cap(self, cap: float) -> None:
        """Set ``J_max`` (built with ``with_cost_cap``).

        Parameters
        ----------
        cap : float
            The LQR cost cap ``J_max``.
        """
        self.cost_cap = float(cap)

    def _cap_rows(self, h: np.ndarray, model: RobotModel, weights: CostWeights,
                  goal: np.ndarray) -> tuple[sp.coo_matrix, np.ndarray]:
        """Rows ``2 G z`` of the cost cap's cone: A = −2 G M, b = −2 G c with ``z = M x − c`` per piece and axis."""
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        b: list[np.ndarray] = []
        count = 1  # row 0 of the cone is the constant α + 1
        for step in np.unique(h):
            idx = np.flatnonzero(h == step)
            for i in range(3):
                w = interval_cost_matrix(float(step), model, weights.position[i], weights.velocity[i], weights.force[i])
                lam, vec = np.linalg.eigh(0.5 * (w + w.T))
                keep = lam > 1e-14 * max(float(lam.max()), 1e-300)
                g = np.sqrt(lam[keep])[:, None] * vec[:, keep].T  # (q, 4) on z = [r − r_g, v, v − v_g, f]
                z_cols = [self._r[idx, i], self._v[idx, i], self._v[idx, i], self._f[idx, i]]
                c = np.array([goal[i], 0.0, goal[3 + i], 0.0])
                for row_g in g:
                    r_idx = count + np.arange(idx.shape[0])
                    for coef, zc in zip(row_g, z_cols, strict=True):
                        rows.append(r_idx)
                        cols.append(zc)
                        vals.append(np.full(idx.shape[0], -2.0 * coef))
                    b.append(np.full(idx.shape[0], -2.0 * float(row_g @ c)))
                    count += idx.shape[0]
        a = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(count + 1, self.n_var))
        return a, np.concatenate([[0.0], *b, [0.0]])

    def _variable_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Trust region, keep-in and keep-out rows for the current reference (A x <= b) as COO triplets
        ``(rows, cols, vals, b)``, every block vectorised (rows in the order: trust region +, −; keep-in per control
        point P0, P1, P2 and sign +, −; keep-out per zone and control point, pieces ascending)."""
        n = self.n
        r_ref = np.asarray(self.r_ref, dtype=float)
        rad = float(self.radius)  # type: ignore[arg-type]
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        bs: list[np.ndarray] = []
        count = 0
        trust = self._tr_work if self.active_set else np.ones_like(self._tr_work)
        tr_cols = self._r[trust]
        if tr_cols.size:
            t = tr_cols.size
            r_t = r_ref[trust]
            rows.append(np.arange(2 * t))
            cols.append(np.concatenate([tr_cols, tr_cols]))
            vals.append(np.concatenate([np.ones(t), -np.ones(t)]))
            bs += [r_t + rad, rad - r_t]
            count = 2 * t
        lo, hi = np.asarray(self.box_lower, dtype=float), np.asarray(self.box_upper, dtype=float)
        # Rows implied by the trust region and the velocity limits are left out (the feasible set, hence the
        # optimum, is the same; Clarabel's KKT system gets smaller): every control point stays in the interval
        # r̄ ± Δ (P0, P2) or r̄ ± (Δ + h/2 V̄) (P1) around the reference, V̄ = max(velocity limit, |start velocity|).
        reach1 = rad + self._half_h_v
        centre = (r_ref[:-1], r_ref[:-1], r_ref[1:])
        reach = (rad, reach1, rad)
        # Keep-in: per control point and sign, ±P − s <= ±bound unless the reachable interval satisfies it.
        keep_in = np.stack([m for c_p, d_p in zip(centre, reach, strict=True)
                            for m in (c_p + d_p > hi - _IMPLIED_M, -(c_p - d_p) > -lo - _IMPLIED_M)])  # (6, N, 3)
        combo, k, i = np.nonzero(keep_in)
        if combo.size:
            m_in = combo.size
            sign = np.where(combo % 2 == 0, 1.0, -1.0)
            point = combo // 2
            r_row = count + np.arange(m_in)
            mid = np.flatnonzero(point == 1)
            rows += [r_row, r_row[mid], r_row]
            cols += [self._r[k + (point == 2), i], self._v[k[mid], i[mid]], self._s[k]]
            vals += [sign, sign[mid] * self._half_h3[k[mid], i[mid]], -np.ones(m_in)]
            bs.append(np.where(sign > 0, hi[k, i], -lo[k, i]))
            count += m_in
        if self.normals:
            # Keep-out: −nᵀP − s <= −b, kept unless min over the reachable interval of nᵀP is at least b.
            nrm = np.stack([np.asarray(v, dtype=float) for v in self.normals])  # (J, N, 3)
            off = np.stack([np.asarray(v, dtype=float) for v in self.offsets])  # (J, N)
            abs_n = np.abs(nrm)
            least = np.stack([np.einsum("jki,ki->jk", nrm, c_p)
                              - np.einsum("jki,ki->jk", abs_n, np.broadcast_to(d_p, (n, 3)))
                              for c_p, d_p in zip(centre, reach, strict=True)], axis=1)  # (J, 3, N)
            zone, point, k = np.nonzero(least < off[:, None, :] + _IMPLIED_M)
            if zone.size:
                m_out = zone.size
                r_row = count + np.arange(m_out)
                n_sel = -nrm[zone, k]  # (M, 3)
                r_cols = self._r[k + (point == 2)]  # (M, 3)
                mid = np.flatnonzero(point == 1)
                rows += [np.repeat(r_row, 3), np.repeat(r_row[mid], 3), r_row]
                cols += [r_cols.ravel(), self._v[k[mid]].ravel(), self._s[k]]
                vals += [n_sel.ravel(), (n_sel[mid] * self._half_h3[k[mid]]).ravel(), -np.ones(m_out)]
                bs.append(-off[zone, k])
                count += m_out
        if not rows:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)
        return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), np.concatenate([b.ravel() for b in bs])

    def set_working_hint(self, x_ref: np.ndarray, f_ref: np.ndarray, cost_ref: float) -> None:
        """Start the working set of the next :meth:`solve`: every row at the first call, then the limit rows the
        reference comes near and the cost cap when its cost does (module docstring). Only the time of
        :meth:`solve` depends on it, never the optimum.

        Parameters
        ----------
        x_ref : ndarray, shape (N+1, 6)
            Reference knot states.
        f_ref : ndarray, shape (N, 3)
            Reference held forces [N].
        cost_ref : float
            Reference LQR cost ``J``.
        """
        r_prev, self._r_prev = self._r_prev, np.asarray(x_ref, dtype=float)[:, 0:3].copy()
        if not self._hinted:  # the first subproblem: every row (its solution jumps far from the input)
            self._hinted = True
            self._lim_work[:] = True
            self._tr_work[:] = True
            self._cap_work = True
            return
        self._lim_work[:] = False
        self._cap_work = False
        # Trust-region rows where the last step moved the knot a good part of the radius.
        self._tr_work[:] = np.abs(self._r_prev - r_prev) >= NEAR_TRUST_FRACTION * float(self.radius)  # type: ignore[arg-type]
        values = np.zeros(self.n_var)
        values[self._f.ravel()] = np.asarray(f_ref, dtype=float).ravel()
        values[self._v.ravel()] = np.asarray(x_ref, dtype=float)[:, 3:6].ravel()
        self._add_near(values)
        if self.cost_cap is not None and cost_ref >= (1.0 - NEAR_FRACTION) * self.cost_cap:
            self._cap_work = True

    def _add_near(self, x: np.ndarray, fraction: float = NEAR_FRACTION) -> bool:
        """Add the left-out limit rows that ``x`` violates or comes within ``fraction`` of their bound to; True when
        one of them is violated (then also those within :data:`WIDE_FRACTION`, as the next solution moves on)."""
        value = self._lim_sign * x[self._lim_col]
        out = ~self._lim_work
        violated = bool(np.any(out & (value > self._lim_bound + _VIOLATION_TOL)))
        frac = max(fraction, WIDE_FRACTION) if violated else fraction
        self._lim_work |= out & (value >= (1.0 - frac) * self._lim_bound)
        return violated

    def _add_trust(self, x: np.ndarray) -> bool:
        """Add the left-out trust-region rows ``x`` breaks (and, then, those it uses WIDE_FRACTION of); True when
        one is broken."""
        step = np.abs(x[self._r] - np.asarray(self.r_ref, dtype=float))
        rad = float(self.radius)  # type: ignore[arg-type]
        violated = bool(np.any(~self._tr_work & (step > rad + _VIOLATION_TOL)))
        if violated:
            self._tr_work |= step >= (1.0 - WIDE_FRACTION) * rad
        return violated

    def _cap_violated(self, x: np.ndarray) -> bool:
        """Whether ``x`` breaks the left-out cost cap (``½ ‖G z‖² <= J_max − w_t Σ h``)."""
        a_gz, b_gz = self._cap_gz  # type: ignore[misc]
        y = b_gz - a_gz @ x  # 2 G z
        room = float(self.cost_cap) - self._time_cost  # type: ignore[arg-type]
        return float(y @ y) / 8.0 > room + _VIOLATION_TOL * max(1.0, abs(float(self.cost_cap)))  # type: ignore[arg-type]

    def _assemble(self) -> tuple[sp.csc_matrix, np.ndarray, list]:
        """The conic data with the current working set: the blocks' COO triplets stacked, one conversion to CSC."""
        work = self._lim_work if self.active_set else np.ones_like(self._lim_work)
        k = int(work.sum())
        r_v, c_v, d_v, b_v = self._variable_rows()
        n_v = b_v.shape[0]
        eq, buf, soc = self._eq[0], self._buffer_rows[0], self._soc[0]
        n_eq, n_buf = eq.shape[0], buf.shape[0]
        base = n_eq + k + n_buf + n_v  # first row of the cones
        rows = [eq.row, n_eq + np.arange(k), (n_eq + k) + buf.row, (n_eq + k + n_buf) + r_v, base + soc.row]
        cols = [eq.col, self._lim_col[work], buf.col, c_v, soc.col]
        vals = [eq.data, self._lim_sign[work], buf.data, d_v, soc.data]
        rhs = [self._eq[1], self._lim_bound[work], self._buffer_rows[1], b_v, self._soc[1]]
        cones = [clarabel.ZeroConeT(n_eq), clarabel.NonnegativeConeT(k + n_buf + n_v)]
        cones += [clarabel.SecondOrderConeT(4)] * self._n_soc
        n_rows = base + soc.shape[0]
        if self._cap is not None and (self._cap_work or not self.active_set):
            a_cap, b_cap = self._cap
            alpha = 2.0 * (float(self.cost_cap) - self._time_cost)  # type: ignore[arg-type]
            b_cap = b_cap.copy()
            b_cap[0], b_cap[-1] = alpha + 1.0, alpha - 1.0
            rows.append(n_rows + a_cap.row)
            cols.append(a_cap.col)
            vals.append(a_cap.data)
            rhs.append(b_cap)
            cones.append(clarabel.SecondOrderConeT(a_cap.shape[0]))
            n_rows += a_cap.shape[0]
        a = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n_rows, self.n_var))
        return a, np.concatenate(rhs), cones

    def _complete(self) -> bool:
        return (bool(self._lim_work.all()) and bool(self._tr_work.all())
                and (self._cap is None or self._cap_work))

    def solve(self) -> str:
        """Assemble the reference-dependent rows and solve with Clarabel, growing the working set until the solution
        satisfies every left-out row (module docstring); ``rounds`` counts the solves.

        Returns
        -------
        str
            cvxpy-style status (``optimal``, ``optimal_inaccurate``, ``infeasible`` ...), or
            ``solver_error: ...``.
        """
        self.f_value = self.buffer_value = None
        self.objective = float("nan")
        self.rounds = 0
        while True:
            a, b, cones = self._assemble()
            self.rounds += 1
            try:
                sol = clarabel.DefaultSolver(self._p, self._q, a, b, cones, self._settings).solve()
                if str(sol.status) != "Solved":
                    sol = clarabel.DefaultSolver(self._p, self._q, a, b, cones, self._settings_refined).solve()
            except Exception as exc:
                return solver_error_status(exc)
            status = CLARABEL_STATUS.get(str(sol.status)) or solver_error_status(f"Clarabel status {sol.status}")
            complete = not self.active_set or self._complete()
            if status not in ("optimal", "optimal_inaccurate"):
                if complete:
                    return status
                self._lim_work[:] = True  # decide on the full problem
                self._tr_work[:] = True
                self._cap_work = True
                continue
            x = np.asarray(sol.x)
            if not complete:
                violated = self._add_near(x)
                violated |= self._add_trust(x)
                if self._cap is not None and not self._cap_work and self._cap_violated(x):
                    self._cap_work = violated = True
                if violated:
                    continue
            self.f_value = x[self._f]
            self.buffer_value = np.maximum(x[self._s], 0.0)
            self.objective = float(sol.obj_val)
            return status
