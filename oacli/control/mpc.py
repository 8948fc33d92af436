"""Standard linear MPC ([Doerr2021] Eq. 26) as a cvxpy problem built once and re-solved.

The problem is parametrised (DPP) by the initial state and the reference over the horizon, so cvxpy
canonicalises it once; each step only updates the parameter values. By default the step then calls Clarabel
directly with the updated data (:class:`oacli.control.compiled_qp.CompiledQP`); ``fast=False`` goes through
``problem.solve()`` instead (same problem, same solution, more overhead).

    minimise   Σ_{k<N} ‖Q^½ (x_k − x_k,ref)‖² + ‖R^½ (u_k − u_k,ref)‖² + ‖L (x_N − x_N,ref)‖² + ρ Σ s
    subject to x_0 = x̂,  x_{k+1} = A x_k + B u_k,
               |u_k| ≤ u_max                      (hard, per axis),
               |x_k,i| ≤ x_max,i + s_k,i, s ≥ 0   (soft state limits, exact ℓ1 penalty ρ),

with ``P = L Lᵀ`` the terminal weight (by default the discrete Riccati solution, so that with no active
constraint the MPC law equals the infinite-horizon LQR law). State limits are soft so that a measured state
slightly outside them (noise, a disturbance) never makes the problem infeasible; the slack is reported.

The cvxpy problem is written so that canonicalisation adds no auxiliary variable (as
:class:`oacli.control.tube_qp.NominalQP`): the terminal state is its own variable, the references enter only the
linear cost term (``‖c ⊙ (x − r)‖² = Σ w x² − 2 Σ (w ⊙ r) x + Σ w r²``, the constant added back to the reported
objective) and the absolute values are pairs of linear rows. The same problem as the textbook form above with half
the variables (262 instead of 574 for the mission's N = 10 tracking MPC with workspace rows); Clarabel runs with
:data:`oacli.control.compiled_qp.CLARABEL_OPTIONS`.

Optionally the predicted positions ``p_k = x_k[i:i+3]`` (k = 1..N) are kept in the workspace
(:mod:`oacli.control.workspace`): a keep-in box ``lower_k ≤ p_k ≤ upper_k``, braking rows that keep the point
where each predicted state would stop (braking at half the given deceleration) in that box
(:func:`oacli.control.workspace.braking_lines`), and keep-out half-spaces ``n_jkᵀ p_k ≥ β_jk``, all Parameters (the
normals multiply the variables: the compiled path updates A's values), soft with one slack ``σ_k ≥ 0`` per step
shared by the step's rows and the exact ℓ1 penalty ``ρ_p Σ σ_k``: when the rows can be met, the solution meets
them (ρ_p above the sum of the step's Lagrange multipliers of the hard problem, :data:`POSITION_PENALTY`); when
they cannot (the measured state already outside, a plant that brakes less than the model), the QP stays feasible
and the slack is reported.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import clarabel
import cvxpy as cp
import numpy as np

from oacli.control.compiled_qp import CLARABEL_OPTIONS, CompiledQP
from oacli.control.lqr import solve_dare
from oacli.control.workspace import PositionRows, braking_lines
from oacli.solver import solve_clarabel
from oacli.types import SolveInfo

#: Default exact-penalty weight of the position slack [1/m]. Exact when above the sum of the Lagrange multipliers
#: of a step's rows in the problem with hard rows; the largest sum seen in closed loop (``problem.solve()`` duals,
#: steps whose hard rows are feasible) was 76.7 (payload chain: 15 kg plant, 9.58 kg model, excitation reference)
#: and 3.8 (configs/doerr2021.yaml, keep-out zones): 1e5 leaves three orders of magnitude for other weights.
#: ``python benchmarks/bench_mpc_step.py`` prints the figure for doerr2021.
POSITION_PENALTY = 1e5


@dataclass(frozen=True)
class MPCSolution:
    """One MPC solve.

    Attributes
    ----------
    u : ndarray, shape (N, m)
        Planned inputs (NaN when the solve failed).
    x : ndarray, shape (N+1, n)
        Predicted states (NaN when the solve failed).
    max_slack : float
        Largest state-limit slack used (0 when every state limit holds).
    info : SolveInfo
    position_slack_m : float
        Largest position-row slack used [m] (0 when every workspace row holds or there are none).
    """

    u: np.ndarray
    x: np.ndarray
    max_slack: float
    info: SolveInfo
    position_slack_m: float = 0.0


class LinearMPC:
    """Linear MPC on an LTI model ``x_{k+1} = A x_k + B u_k`` ([Doerr2021] Eq. 26).

    Parameters
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n, m)
    q_diag : ndarray, shape (n,)
        Diagonal of the stage state weight Q (> 0 or 0).
    r_diag : ndarray, shape (m,)
        Diagonal of the input weight R (> 0).
    horizon : int
        N, number of steps.
    u_max : ndarray, shape (m,)
        Symmetric per-axis input limits.
    x_max : ndarray, shape (n,), optional
        Symmetric per-component state limits (``inf`` for none); soft constraints.
    terminal : ndarray, shape (n, n), optional
        Terminal weight P; the DARE solution of (A, B, Q, R) by default.
    soft_penalty : float
        ℓ1 penalty ρ on state-limit slack (exact penalty: large compared with the cost's sensitivity).
    fast : bool
        Solve through the compiled direct-Clarabel path (default) rather than ``problem.solve()``.
    keep_in : bool
        Add keep-in box rows on the predicted positions (Parameters ``box_lower``, ``box_upper``, shape (N, 3)).
    keep_out_zones : int
        Number J of keep-out half-space rows per step (Parameters ``out_normals[j]`` (N, 3), ``out_offsets[j]``
        (N,)).
    position_index : int
        Index of the first position component in the state.
    position_penalty : float
        ρ_p, the exact ℓ1 penalty on the position slack [1/m].
    braking_mps2, braking_speed_mps : ndarray, shape (3,), optional
        ā and v̄ per axis: braking rows keep the stop point of every predicted state in its keep-in box
        (:func:`~oacli.control.workspace.braking_lines`; soft, same slack as the step's other rows). The velocity
        components follow the positions (``position_index + 3``).
    """

    def __init__(
        self,
        a: np.ndarray,
        b: np.ndarray,
        q_diag: np.ndarray,
        r_diag: np.ndarray,
        horizon: int,
        u_max: np.ndarray,
        x_max: np.ndarray | None = None,
        terminal: np.ndarray | None = None,
        soft_penalty: float = 1e4,
        fast: bool = True,
        *,
        keep_in: bool = False,
        keep_out_zones: int = 0,
        position_index: int = 0,
        position_penalty: float = POSITION_PENALTY,
        braking_mps2: np.ndarray | None = None,
        braking_speed_mps: np.ndarray | None = None,
    ) -> None:
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        n, m = b.shape
        if horizon < 1:
            raise ValueError("horizon must be >= 1")
        self.a, self.b, self.horizon = a, b, int(horizon)
        self.q_diag = np.asarray(q_diag, dtype=float)
        self.r_diag = np.asarray(r_diag, dtype=float)
        self.u_max = np.asarray(u_max, dtype=float)
        self.x_max = np.full(n, np.inf) if x_max is None else np.asarray(x_max, dtype=float)
        if terminal is None:
            terminal = solve_dare(a, b, np.diag(self.q_diag), np.diag(self.r_diag))
        self.terminal = np.asarray(terminal, dtype=float)
        n_steps = self.horizon

        self.x0 = cp.Parameter(n, name="x0")
        self.x_ref = cp.Parameter((n_steps + 1, n), name="x_ref")
        self.u_ref = cp.Parameter((n_steps, m), name="u_ref")
        # States 0..N-1 and the terminal state are separate variables and the references enter only the linear
        # term (‖c ⊙ (x − r)‖² = Σ w x² − 2 Σ (w ⊙ r) x + Σ w r²): cvxpy then puts the weights straight into P and
        # adds no auxiliary variable (a quadratic term on a slice or an affine residual, or an abs atom, costs one
        # per entry). The constant Σ w r² is added back to the reported objective.
        self._z = cp.Variable((n_steps, n), name="x")
        self._z_n = cp.Variable(n, name="x_terminal")
        self._u = cp.Variable((n_steps, m), name="u")

        chol = np.linalg.cholesky(self.terminal + 1e-12 * np.eye(n))
        p_n = chol @ chol.T
        p_n = 0.5 * (p_n + p_n.T)
        q_w = np.tile(self.q_diag, (n_steps, 1))
        r_w = np.tile(self.r_diag, (n_steps, 1))
        self._weights = (q_w, r_w, p_n)
        cost = (
            cp.sum(cp.multiply(q_w, cp.square(self._z)))
            - 2 * cp.sum(cp.multiply(cp.multiply(q_w, self.x_ref[:n_steps]), self._z))
            + cp.sum(cp.multiply(r_w, cp.square(self._u)))
            - 2 * cp.sum(cp.multiply(cp.multiply(r_w, self.u_ref), self._u))
            + cp.quad_form(self._z_n, p_n, assume_PSD=True)
            - 2 * (self.x_ref[n_steps] @ p_n) @ self._z_n
        )
        u_bound = np.tile(self.u_max, (n_steps, 1))
        constraints = [
            self._z[0] == self.x0,
            self._z_n == a @ self._z[n_steps - 1] + b @ self._u[n_steps - 1],
            self._u <= u_bound,
            -self._u <= u_bound,
        ]
        if n_steps > 1:
            constraints.insert(1, self._z[1:] == self._z[:-1] @ a.T + self._u[:-1] @ b.T)
        # Predicted states 1..N.
        future = cp.vstack([self._z[1:], self._z_n[None, :]]) if n_steps > 1 else self._z_n[None, :]
        self._limited = np.flatnonzero(np.isfinite(self.x_max))
        self._slack = None
        if self._limited.size:
            # A plain variable with an explicit sign constraint: cvxpy replaces variables that carry attributes
            # (nonneg=True) by new ones, which the compiled path could then not read back.
            self._slack = cp.Variable((n_steps, self._limited.size), name="slack")
            bound = np.tile(self.x_max[self._limited], (n_steps, 1))
            limited = future[:, self._limited]
            constraints += [limited <= bound + self._slack, -limited <= bound + self._slack, self._slack >= 0]
            cost = cost + soft_penalty * cp.sum(self._slack)
        self.box_lower = self.box_upper = None
        self.out_normals: list[cp.Parameter] = []
        self.out_offsets: list[cp.Parameter] = []
        self._pos_slack = None
        if keep_in or keep_out_zones:
            pos = future[:, position_index : position_index + 3]
            self._pos_slack = cp.Variable(n_steps, name="position_slack")
            sigma = self._pos_slack[:, None]
            constraints.append(self._pos_slack >= 0)
            if keep_in:
                self.box_lower = cp.Parameter((n_steps, 3), name="box_lower")
                self.box_upper = cp.Parameter((n_steps, 3), name="box_upper")
                constraints += [pos >= self.box_lower - sigma, pos <= self.box_upper + sigma]
                if braking_mps2 is not None:
                    if braking_speed_mps is None:
                        raise ValueError("braking rows need braking_speed_mps")
                    v_n = future[:, position_index + 3 : position_index + 6]
                    for slope, icpt in braking_lines(braking_mps2, braking_speed_mps):
                        sl, ic = np.tile(slope, (n_steps, 1)), np.tile(icpt, (n_steps, 1))
                        constraints += [v_n <= ic + cp.multiply(sl, self.box_upper - pos) + sigma,
                                        -v_n <= ic + cp.multiply(sl, pos - self.box_lower) + sigma]
            for j in range(keep_out_zones):
                normal = cp.Parameter((n_steps, 3), name=f"out_normal_{j}")
                offset = cp.Parameter(n_steps, name=f"out_offset_{j}")
                constraints.append(cp.sum(cp.multiply(normal, pos), axis=1) >= offset - self._pos_slack)
                self.out_normals.append(normal)
                self.out_offsets.append(offset)
            cost = cost + position_penalty * cp.sum(self._pos_slack)
        self.problem = cp.Problem(cp.Minimize(cost), constraints)
        self.clarabel_options = dict(CLARABEL_OPTIONS)
        settings = clarabel.DefaultSettings()
        for key, value in self.clarabel_options.items():
            setattr(settings, key, value)
        self.compiled = CompiledQP(self.problem, settings) if fast else None
        #: Parameter values of the last solve, by parameter id (what :meth:`CompiledQP.solve` took).
        self.last_values: dict[int, np.ndarray] = {}

    @property
    def has_position_rows(self) -> bool:
        """True when the problem has workspace rows on the predicted positions."""
        return self._pos_slack is not None

    def solve(
        self, x0: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray, rows: PositionRows | None = None
    ) -> MPCSolution:
        """Solve for initial state ``x0 (n,)``, reference states ``x_ref (N+1, n)`` and inputs ``u_ref (N, m)``.

        Parameters
        ----------
        x0 : ndarray, shape (n,)
            Initial state.
        x_ref : ndarray, shape (N+1, n)
            Reference states.
        u_ref : ndarray, shape (N, m)
            Reference inputs.
        rows : PositionRows, optional
            Workspace rows of steps 1..N in the state's coordinates; required when the problem has them.

        Returns
        -------
        MPCSolution
            Inputs, predicted states, slacks and the solve record (NaN arrays when the solve failed).
        """
        values = {self.x0.id: np.asarray(x0, dtype=float), self.x_ref.id: np.asarray(x_ref, dtype=float),
                  self.u_ref.id: np.asarray(u_ref, dtype=float)}
        if self.has_position_rows:
            if rows is None:
                raise ValueError("this MPC constrains positions: pass the workspace rows")
            if self.box_lower is not None and self.box_upper is not None:
                values[self.box_lower.id], values[self.box_upper.id] = rows.lower, rows.upper
            for j, (normal, offset) in enumerate(zip(self.out_normals, self.out_offsets, strict=True)):
                values[normal.id], values[offset.id] = rows.normals[j], rows.offsets[j]
        self.last_values = values
        start = time.perf_counter()
        value: Callable[[cp.Variable], np.ndarray] | None
        if self.compiled is not None:
            out = self.compiled.solve(values)
            value = self.compiled.value if out.success else None
        else:
            for param in self.problem.parameters():
                param.value = values[param.id]  # cvxpy validates shapes and values here
            out = solve_clarabel(self.problem, **self.clarabel_options)
            value = (lambda v: np.asarray(v.value)) if out.success and self._u.value is not None else None
        status, objective, iterations, solve_time = out.status, out.objective, out.iterations, out.solve_time_s
        wall = time.perf_counter() - start
        if value is not None:
            q_w, r_w, p_n = self._weights
            xr, ur = values[self.x_ref.id], values[self.u_ref.id]
            objective = objective + float(np.sum(q_w * xr[:-1] ** 2) + np.sum(r_w * ur**2) + xr[-1] @ p_n @ xr[-1])
            u, x = np.array(value(self._u)), np.vstack([value(self._z), value(self._z_n)[None, :]])
            slack = 0.0 if self._slack is None else float(np.max(value(self._slack), initial=0.0))
            pos_slack = 0.0 if self._pos_slack is None else float(np.max(value(self._pos_slack), initial=0.0))
            info = SolveInfo(status, True, float(objective), int(iterations), float(solve_time), wall)
            return MPCSolution(u, x, slack, info, max(pos_slack, 0.0))
        nan_u = np.full(self._u.shape, np.nan)
        nan_x = np.full((self.horizon + 1, self._z_n.size), np.nan)
        return MPCSolution(nan_u, nan_x, float("nan"), SolveInfo(status, False, float("nan"), -1, wall, wall))
