"""The nominal MPC of robust tube MPC as one cvxpy QP, built once (DPP) and re-solved every step.

The QP holds one or more decoupled linear subsystems ("blocks") over a common horizon N. A *tube block*
(Mayne, Seron & Raković 2005; [Doerr2021] Eq. 27) has a free initial nominal state ``z_0`` tied to the
measured state ``x`` by the lasso constraint ``x − z_0 ∈ Z`` and tightened hard constraints ``z_k ∈ X̄``
(k = 0..N) and ``v_k ∈ Ū``; a *standard block* ([Doerr2021] Eq. 26) starts at ``x`` and has soft state limits
(exact ℓ1 penalty, so a measured state outside them never makes the QP infeasible) and hard input limits.
Both minimise

    Σ_{k<N} ‖Q^½ (z_k − x_ref,k)‖² + ‖R^½ (v_k − u_ref,k)‖² + ‖L (z_N − x_ref,N)‖²,   P_N = L Lᵀ.

A block may also keep its predicted positions in the workspace (:class:`PositionRowsSpec`,
:mod:`oacli.control.workspace`): a keep-in box ``lower_k ≤ p_k ≤ upper_k`` and keep-out half-spaces
``n_jkᵀ p_k ≥ β_jk`` with Parameter bounds and normals, on ``z_0..z_N`` and HARD in a tube block (the caller
tightens them by Z, so that they hold for the true state; each half-space also holds at the next knot, so the
whole segment ``z_k → z_{k+1}`` is in it), on ``y_1..y_N`` and soft with an exact ℓ1 penalty in a standard block.

Optionally (tube block) *braking rows* at the terminal knot keep the point where braking at ā (per axis) from
``(p, v) = z_N`` stops, ``p + v|v|/(2ā)``, inside the terminal box: with ``d = upper − p``, it does exactly when
``v ≤ sqrt(2ā d)``, a convex set but a cone constraint; the rows are its piecewise-linear inner approximation for
half the braking acceleration, ``v ≤ min(s₀ d, v̄/3 + s₁ d)`` (:func:`braking_lines`: the chords of ``sqrt(ā d)``
through ``d = 0, d*/4, d*``, ``d* = v̄²/ā``, v̄ the velocity bound), and the mirror rows for the lower face. The
halved acceleration makes them invariant under braking at ā (on each chord the braking trajectory's slope ``ā/v``
is at least the chord's), so every plan ends in a state from which braking stays in the box: the previous plan
followed by braking is feasible at the next step (recursive feasibility of the keep-in rows, up to a change of the
box chosen for a step), and a safe hold that finishes the plan and then brakes stays in the keep-in. Linear rows at
one knot keep the QP small: second-order cones, or these rows at every knot, cost 1.5× the solve time.

Every constraint is a linear inequality ``H y ≤ h`` written without ``abs`` atoms (which would add hidden
variables), and the references enter the cost through ``sum_squares(c ⊙ (z − r))`` with constant ``c``, which
keeps the problem DPP (``quad_form(z − r, Q)`` with a Parameter ``r`` would not). Parameters enter only the
linear cost term, the right-hand sides and (keep-out normals) the constraint matrix's values, so
:class:`oacli.control.compiled_qp.CompiledQP` can solve it without re-canonicalising.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import clarabel
import cvxpy as cp
import numpy as np

from oacli.control.compiled_qp import CLARABEL_OPTIONS, CompiledQP
from oacli.control.workspace import PositionRows, braking_lines
from oacli.solver import solve_clarabel
from oacli.types import SolveInfo


@dataclass(frozen=True)
class LinearConstraint:
    """``H y ≤ h`` on a vector y (a state or an input)."""

    h_matrix: np.ndarray
    h_vector: np.ndarray

    def __post_init__(self) -> None:
        hm = np.array(self.h_matrix, dtype=float, ndmin=2)
        hv = np.array(self.h_vector, dtype=float).reshape(-1)
        if hm.shape[0] != hv.shape[0]:
            raise ValueError(f"H has {hm.shape[0]} rows but h has {hv.shape[0]} entries")
        object.__setattr__(self, "h_matrix", hm)
        object.__setattr__(self, "h_vector", hv)

    @classmethod
    def box(cls, bound: np.ndarray, lower: np.ndarray | None = None) -> LinearConstraint:
        """``lower ≤ y ≤ bound`` (``lower = −bound`` by default); infinite entries are left out.

        Parameters
        ----------
        bound : ndarray, shape (n,)
            Upper bounds (``inf`` for none).
        lower : ndarray, shape (n,), optional
            Lower bounds (``-inf`` for none).

        Returns
        -------
        LinearConstraint
        """
        upper = np.asarray(bound, dtype=float).reshape(-1)
        low = -upper if lower is None else np.asarray(lower, dtype=float).reshape(-1)
        eye = np.eye(upper.size)
        up, lo = np.isfinite(upper), np.isfinite(low)
        return cls(np.vstack([eye[up], -eye[lo]]), np.concatenate([upper[up], -low[lo]]))

    @property
    def rows(self) -> int:
        """Number of inequalities."""
        return int(self.h_vector.size)


@dataclass(frozen=True)
class PositionRowsSpec:
    """Workspace rows on a block's predicted positions (their values are set per solve, :meth:`NominalQP.set_rows`).

    Attributes
    ----------
    keep_in : bool
        Keep-in box rows.
    keep_out_zones : int
        Keep-out half-space rows per step (J).
    position_index : int
        First position component of the block's state (three components).
    velocity_index : int
        First velocity component (for the braking rows).
    braking_mps2 : ndarray, shape (3,), optional
        ā per axis [m/s²]: add braking rows at the terminal knot (module docstring; tube block only).
    braking_speed_mps : ndarray, shape (3,), optional
        v̄ per axis [m/s], the velocity bound of the block's states (required with ``braking_mps2``).
    penalty : float
        Exact ℓ1 penalty of the soft rows of a standard block [1/m].
    """

    keep_in: bool = True
    keep_out_zones: int = 0
    position_index: int = 0
    velocity_index: int = 3
    braking_mps2: np.ndarray | None = None
    braking_speed_mps: np.ndarray | None = None
    penalty: float = 1e5


@dataclass(frozen=True)
class QPBlock:
    """One linear subsystem ``y_{k+1} = A y_k + B u_k`` of the nominal QP.

    Attributes
    ----------
    name : str
    a, b : ndarray, shapes (n, n), (n, m)
    q_diag, r_diag : ndarray, shapes (n,), (m,)
        Stage weights (≥ 0 and > 0).
    terminal : ndarray, shape (n, n)
        Terminal weight P_N (symmetric positive semidefinite).
    state : LinearConstraint, optional
        Tube block: the tightened X̄, hard on z_0..z_N. Standard block: soft limits on y_1..y_N.
    input : LinearConstraint, optional
        Hard input constraint (tube block: Ū).
    lasso : LinearConstraint, optional
        ``Z`` as ``H e ≤ h``; given ⇒ tube block with the constraint ``x − z_0 ∈ Z``; omitted ⇒ ``y_0 = x``.
    soft_penalty : float
        ℓ1 weight of the soft state-limit slack (standard block).
    positions : PositionRowsSpec, optional
        Workspace rows on the predicted positions.
    initial_weight : ndarray, shape (n, n), optional
        Tube block: cost ``(z_0 − x)ᵀ P₀ (z_0 − x)`` on the free initial nominal state (symmetric PSD; none: the
        cost of [Mayne2005], which leaves ``z_0`` anywhere in the lasso).
    """

    name: str
    a: np.ndarray
    b: np.ndarray
    q_diag: np.ndarray
    r_diag: np.ndarray
    terminal: np.ndarray
    state: LinearConstraint | None = None
    input: LinearConstraint | None = None
    lasso: LinearConstraint | None = None
    soft_penalty: float = 1e4
    positions: PositionRowsSpec | None = None
    initial_weight: np.ndarray | None = None

    @property
    def n(self) -> int:
        """State dimension."""
        return int(np.shape(self.a)[0])

    @property
    def m(self) -> int:
        """Input dimension."""
        return int(np.shape(self.b)[1])


@dataclass
class _BlockVars:
    x: cp.Parameter
    x_ref: cp.Parameter
    u_ref: cp.Parameter
    z: cp.Variable
    z_n: cp.Variable
    v: cp.Variable
    slack: cp.Variable | None = None
    box_lower: cp.Parameter | None = None
    box_upper: cp.Parameter | None = None
    out_normals: tuple[cp.Parameter, ...] = ()
    out_offsets: tuple[cp.Parameter, ...] = ()
    position_slack: cp.Variable | None = None


@dataclass(frozen=True)
class BlockSolution:
    """Solution of one block: nominal states ``z (N+1, n)`` and inputs ``v (N, m)`` (NaN when failed)."""

    z: np.ndarray
    v: np.ndarray
    max_slack: float
    position_slack_m: float = 0.0


@dataclass(frozen=True)
class _Gathers:
    """Where a block's solution lies in the compiled problem's ``x``: index arrays (z: (N+1, n); v transposed:
    (m, N), so that ``x[v_t].T`` is column-major like cvxpy's value) and the slacks' slices (only their maximum is
    read, so their shapes do not matter)."""

    z: np.ndarray
    v_t: np.ndarray
    slack: slice | None
    position_slack: slice | None


def _gathers(compiled: CompiledQP, bv: _BlockVars) -> _Gathers:
    """The :class:`_Gathers` of block variables ``bv`` in ``compiled`` (columns: cvxpy's, column-major)."""
    cols = compiled._var_cols

    def index(var: cp.Variable) -> np.ndarray:
        return np.asarray(cols[var.id] + np.arange(var.size).reshape(var.shape, order="F"))

    def span(var: cp.Variable | None) -> slice | None:
        return None if var is None else slice(cols[var.id], cols[var.id] + var.size)

    z = np.vstack([index(bv.z), index(bv.z_n)[None, :]])
    return _Gathers(z, np.ascontiguousarray(index(bv.v).T), span(bv.slack), span(bv.position_slack))


@dataclass(frozen=True)
class QPSolution:
    """One solve of :class:`NominalQP`: per-block solutions (by name) and the solve record."""

    blocks: dict[str, BlockSolution]
    info: SolveInfo


class NominalQP:
    """The nominal MPC QP of one or more blocks, built once, solved by the fast path or ``problem.solve()``.

    Parameters
    ----------
    blocks : sequence of QPBlock
    horizon : int
        N ≥ 1.
    fast : bool
        Compile the direct Clarabel path (:class:`CompiledQP`) and use it by default.
    clarabel_options : dict, optional
        Clarabel settings used by both paths (default :data:`CLARABEL_OPTIONS`).
    """

    def __init__(
        self,
        blocks: list[QPBlock] | tuple[QPBlock, ...],
        horizon: int,
        *,
        fast: bool = True,
        clarabel_options: dict[str, Any] | None = None,
    ) -> None:
        if horizon < 1:
            raise ValueError("horizon must be >= 1")
        self.blocks = tuple(blocks)
        self.horizon = n_steps = int(horizon)
        names = [blk.name for blk in self.blocks]
        if len(set(names)) != len(names):
            raise ValueError(f"block names must be unique, got {names}")
        cost = 0
        constraints = []
        self._vars: dict[str, _BlockVars] = {}
        self._weights: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._values: dict[int, np.ndarray] = {}
        for blk in self.blocks:
            n, m = blk.n, blk.m
            # States k = 0..N-1 and the terminal state are separate variables so that every quadratic term
            # is on a variable itself: cvxpy then puts the weights straight into P (a quadratic term on a
            # slice or an affine residual costs one auxiliary variable and equality row per entry).
            bv = _BlockVars(
                x=cp.Parameter(n, name=f"{blk.name}_x"),
                x_ref=cp.Parameter((n_steps + 1, n), name=f"{blk.name}_x_ref"),
                u_ref=cp.Parameter((n_steps, m), name=f"{blk.name}_u_ref"),
                z=cp.Variable((n_steps, n), name=f"{blk.name}_z"),
                z_n=cp.Variable(n, name=f"{blk.name}_z_terminal"),
                v=cp.Variable((n_steps, m), name=f"{blk.name}_v"),
            )
            a, b = np.asarray(blk.a, dtype=float), np.asarray(blk.b, dtype=float)
            q_w = np.tile(np.asarray(blk.q_diag, dtype=float), (n_steps, 1))
            r_w = np.tile(np.asarray(blk.r_diag, dtype=float), (n_steps, 1))
            p_n = np.asarray(blk.terminal, dtype=float)
            p_n = 0.5 * (p_n + p_n.T)
            # ‖c ⊙ (z − r)‖² = Σ w z² − 2 Σ (w ⊙ r) z + const: the references enter only the linear term q.
            # The constant Σ w r² is not DPP (a product of parameters); NominalQP adds it to the objective.
            cost = cost + (
                cp.sum(cp.multiply(q_w, cp.square(bv.z)))
                - 2 * cp.sum(cp.multiply(cp.multiply(q_w, bv.x_ref[:n_steps]), bv.z))
                + cp.sum(cp.multiply(r_w, cp.square(bv.v)))
                - 2 * cp.sum(cp.multiply(cp.multiply(r_w, bv.u_ref), bv.v))
                + cp.quad_form(bv.z_n, p_n, assume_PSD=True)
                - 2 * (bv.x_ref[n_steps] @ p_n) @ bv.z_n
            )
            self._weights[blk.name] = (q_w, r_w, p_n)
            if n_steps > 1:
                constraints.append(bv.z[1:] == bv.z[:-1] @ a.T + bv.v[:-1] @ b.T)
            constraints.append(bv.z_n == a @ bv.z[n_steps - 1] + b @ bv.v[n_steps - 1])
            if blk.input is not None:
                hu = blk.input
                constraints.append(bv.v @ hu.h_matrix.T <= np.tile(hu.h_vector, (n_steps, 1)))
            if blk.lasso is not None:
                hz = blk.lasso
                # x − z_0 ∈ Z  ⇔  H z_0 ≥ H x − h
                constraints.append(hz.h_matrix @ bv.z[0] >= hz.h_matrix @ bv.x - hz.h_vector)
                if blk.initial_weight is not None:  # (z_0 − x)ᵀ P₀ (z_0 − x) without its constant xᵀ P₀ x
                    p0 = np.asarray(blk.initial_weight, dtype=float)
                    p0 = 0.5 * (p0 + p0.T)
                    cost = cost + cp.quad_form(bv.z[0], p0, assume_PSD=True) - 2 * (bv.x @ p0) @ bv.z[0]
                if blk.state is not None:
                    hx = blk.state
                    constraints += [
                        bv.z @ hx.h_matrix.T <= np.tile(hx.h_vector, (n_steps, 1)),
                        hx.h_matrix @ bv.z_n <= hx.h_vector,
                    ]
            else:
                constraints.append(bv.z[0] == bv.x)
                if blk.state is not None and blk.state.rows:
                    hx = blk.state
                    bv.slack = cp.Variable((n_steps, hx.rows), name=f"{blk.name}_slack")
                    constraints += [bv.slack >= 0, hx.h_matrix @ bv.z_n <= hx.h_vector + bv.slack[n_steps - 1]]
                    if n_steps > 1:
                        constraints.append(
                            bv.z[1:] @ hx.h_matrix.T <= np.tile(hx.h_vector, (n_steps - 1, 1)) + bv.slack[:-1]
                        )
                    cost = cost + blk.soft_penalty * cp.sum(bv.slack)
            if blk.positions is not None:
                constraints, cost = self._position_rows(blk, blk.positions, bv, constraints, cost)
            self._vars[blk.name] = bv
        self.problem = cp.Problem(cp.Minimize(cost), constraints)
        self.clarabel_options = dict(CLARABEL_OPTIONS if clarabel_options is None else clarabel_options)
        settings = clarabel.DefaultSettings()
        for key, value in self.clarabel_options.items():
            setattr(settings, key, value)
        self.compiled = CompiledQP(self.problem, settings) if fast else None
        self._n_parameters = len(self.problem.parameters())
        # The fast path keeps θ and writes each value into its slice (CompiledQP.parameter_views) as it is set.
        self._theta: np.ndarray | None = None
        self._views: dict[int, np.ndarray] = {}
        self._gathers: dict[str, _Gathers] = {}
        if self.compiled is not None:
            self._theta = self.compiled.parameter_vector(missing_as_zero=True)
            self._views = self.compiled.parameter_views(self._theta)
            self._gathers = {name: _gathers(self.compiled, bv) for name, bv in self._vars.items()}

    def _position_rows(self, blk: QPBlock, spec: PositionRowsSpec, bv: _BlockVars, constraints: list[Any],
                       cost: Any) -> Any:
        """Add the workspace rows ``spec`` of ``blk`` (module docstring): hard on z_0..z_N for a tube block, soft
        on y_1..y_N for a standard one."""
        n_steps = self.horizon
        i, iv = spec.position_index, spec.velocity_index
        hard = blk.lasso is not None
        states = cp.vstack([bv.z, bv.z_n[None, :]]) if hard else cp.vstack([bv.z[1:], bv.z_n[None, :]])
        k = n_steps + 1 if hard else n_steps
        pos = states[:, i : i + 3]
        sigma: float | cp.Expression = 0.0
        if not hard:
            bv.position_slack = cp.Variable(k, name=f"{blk.name}_position_slack")
            sigma = bv.position_slack[:, None]
            constraints.append(bv.position_slack >= 0)
            cost = cost + spec.penalty * cp.sum(bv.position_slack)
        if spec.keep_in:
            bv.box_lower = cp.Parameter((k, 3), name=f"{blk.name}_box_lower")
            bv.box_upper = cp.Parameter((k, 3), name=f"{blk.name}_box_upper")
            constraints += [pos >= bv.box_lower - sigma, pos <= bv.box_upper + sigma]
            if hard and spec.braking_mps2 is not None:  # at the terminal knot (module docstring)
                if spec.braking_speed_mps is None:
                    raise ValueError(f"{blk.name}: braking rows need braking_speed_mps")
                vel, p_n = bv.z_n[iv : iv + 3], bv.z_n[i : i + 3]
                for slope, intercept in braking_lines(spec.braking_mps2, spec.braking_speed_mps):
                    constraints += [vel <= intercept + cp.multiply(slope, bv.box_upper[k - 1] - p_n),
                                    -vel <= intercept + cp.multiply(slope, p_n - bv.box_lower[k - 1])]
        normals, offsets = [], []
        for j in range(spec.keep_out_zones):
            normals.append(cp.Parameter((k, 3), name=f"{blk.name}_out_normal_{j}"))
            offsets.append(cp.Parameter(k, name=f"{blk.name}_out_offset_{j}"))
            slack = 0.0 if hard else bv.position_slack
            constraints.append(cp.sum(cp.multiply(normals[j], pos), axis=1) >= offsets[j] - slack)
            if hard:  # both ends of each nominal segment in the segment's first half-space
                constraints.append(cp.sum(cp.multiply(normals[j][:-1], pos[1:]), axis=1) >= offsets[j][:-1])
        bv.out_normals, bv.out_offsets = tuple(normals), tuple(offsets)
        return constraints, cost

    def rows_steps(self, name: str) -> int:
        """Number of predicted positions block ``name``'s workspace rows apply to.

        Parameters
        ----------
        name : str
            Block name.

        Returns
        -------
        int
            N + 1 for a tube block (z_0..z_N), N for a standard block (y_1..y_N).
        """
        blk = next(b for b in self.blocks if b.name == name)
        return self.horizon + 1 if blk.lasso is not None else self.horizon

    def set_rows(self, name: str, rows: PositionRows) -> None:
        """Set block ``name``'s workspace rows.

        Parameters
        ----------
        name : str
            Block name (its :class:`PositionRowsSpec` fixes the rows it has).
        rows : PositionRows
            Rows in the block's coordinates, for the steps of :meth:`rows_steps`.

        Raises
        ------
        ValueError
            When a shape differs from the block's Parameters or a value is not finite.
        """
        bv = self._vars[name]
        pairs: list[tuple[cp.Parameter, np.ndarray]] = []
        if bv.box_lower is not None and bv.box_upper is not None:
            pairs += [(bv.box_lower, rows.lower), (bv.box_upper, rows.upper)]
        if len(bv.out_normals) != rows.normals.shape[0]:
            raise ValueError(f"{name}: {len(bv.out_normals)} keep-out zones expected, got {rows.normals.shape[0]}")
        if bv.out_normals:
            pairs += list(zip(bv.out_normals, rows.normals, strict=True))
            pairs += list(zip(bv.out_offsets, rows.offsets, strict=True))
        self._set(pairs)

    def set_parameters(self, name: str, x: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> None:
        """Set block ``name``'s measured state ``x (n,)``, references ``x_ref (N+1, n)`` and ``u_ref (N, m)``.

        The shapes are checked here, the values handed to the solve path (written into θ for the fast path;
        cvxpy's Parameters receive them only for the ``problem.solve()`` path, where their own validation runs) and
        checked to be finite when solving (:meth:`solve` raises ValueError naming the parameter).

        Parameters
        ----------
        name : str
            Block name.
        x : ndarray, shape (n,)
            Measured state of the block.
        x_ref : ndarray, shape (N+1, n)
            Reference states.
        u_ref : ndarray, shape (N, m)
            Reference inputs.
        """
        bv = self._vars[name]
        self._set(((bv.x, x), (bv.x_ref, x_ref), (bv.u_ref, u_ref)))

    def _set(self, pairs: Any) -> None:
        """Store ``(parameter, value)`` pairs (shape checked) for both solve paths and write them into θ."""
        views, values = self._views, self._values
        for param, value in pairs:
            arr = np.asarray(value, dtype=float)
            if arr.shape != param.shape:
                raise ValueError(f"{param.name()}: expected finite values of shape {param.shape}, got {arr.shape}")
            values[param.id] = arr
            view = views.get(param.id)
            if view is not None:
                view[...] = arr

    def _check_finite(self) -> None:
        """Raise ValueError naming the first parameter whose value is not finite."""
        for param in self.problem.parameters():
            arr = self._values.get(param.id)
            if arr is not None and not np.isfinite(arr).all():
                raise ValueError(f"{param.name()}: expected finite values of shape {param.shape}, got {arr.shape}")

    def _reference_constant(self) -> float:
        """``Σ w r²`` over every block: the part of the tracking cost that does not depend on the variables."""
        total = 0.0
        for name, bv in self._vars.items():
            q_w, r_w, p_n = self._weights[name]
            x_ref, u_ref = self._values[bv.x_ref.id], self._values[bv.u_ref.id]
            # np.sum's own reduction (np.add.reduce over every axis) without its wrapper: the same sums.
            total += float(np.add.reduce(q_w * x_ref[:-1] ** 2, axis=None) + np.add.reduce(r_w * u_ref**2, axis=None)
                           + x_ref[-1] @ p_n @ x_ref[-1])
        return total

    def solve(self, *, fast: bool | None = None) -> QPSolution:
        """Solve with the current parameters.

        Parameters
        ----------
        fast : bool, optional
            True: the direct Clarabel path (the default when compiled); False: ``problem.solve(solver=CLARABEL)``.

        Returns
        -------
        QPSolution
            Per-block solutions (NaN when the solve failed) and the solve record.
        """
        use_fast = self.compiled is not None if fast is None else fast
        compiled = self.compiled
        if use_fast and compiled is None:
            raise ValueError("the fast path was not compiled (fast=False at construction)")
        start = time.perf_counter()
        value: Callable[[cp.Variable], np.ndarray] | None
        theta = self._theta
        if use_fast and compiled is not None and theta is not None:  # theta is set whenever compiled is
            if len(self._values) < self._n_parameters:  # some set on the cvxpy Parameters only (or missing: raises)
                theta = compiled.parameter_vector(self._values)
            if not np.logical_and.reduce(np.isfinite(theta)):
                self._check_finite()
            out = compiled.solve_vector(theta)
            value = compiled.value if out.success else None
        else:
            self._check_finite()
            for param in self.problem.parameters():
                param.value = self._values[param.id]
            out = solve_clarabel(self.problem, **self.clarabel_options)  # solve_time_s: wall of solve()
            value = (lambda var: np.asarray(var.value)) if out.success else None
        status, objective, iterations, solve_time = out.status, out.objective, out.iterations, out.solve_time_s
        wall = time.perf_counter() - start
        if value is not None:
            objective += self._reference_constant()
        blocks = {}
        x_sol = compiled.solution if use_fast and compiled is not None else None
        for name, bv in self._vars.items():
            if value is None:
                nan_z = np.full((self.horizon + 1, bv.z_n.size), np.nan)
                blocks[name] = BlockSolution(nan_z, np.full(bv.v.shape, np.nan), np.nan)
            elif x_sol is not None:  # the same values and layouts as the branch below, gathered from x at once
                g = self._gathers[name]
                slack = 0.0 if g.slack is None else float(np.maximum.reduce(x_sol[g.slack], axis=None, initial=0.0))
                pos_slack = 0.0 if g.position_slack is None else float(np.maximum.reduce(
                    x_sol[g.position_slack], axis=None, initial=0.0))
                blocks[name] = BlockSolution(x_sol[g.z], x_sol[g.v_t].T, slack, pos_slack)  # initial 0: >= 0
            else:
                slack = 0.0 if bv.slack is None else float(np.max(value(bv.slack), initial=0.0))
                pos_slack = 0.0 if bv.position_slack is None else float(np.max(value(bv.position_slack),
                                                                                initial=0.0))
                z = np.vstack([value(bv.z), value(bv.z_n)[None, :]])
                blocks[name] = BlockSolution(z, np.array(value(bv.v)), max(slack, 0.0), max(pos_slack, 0.0))
        info = SolveInfo(status, value is not None, objective, iterations, solve_time, wall)
        return QPSolution(blocks, info)

