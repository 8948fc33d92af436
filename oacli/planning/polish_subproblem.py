"""Trajectory polish, part 3: the convex subproblem of one SCP iteration (see :mod:`oacli.planning.polish`)."""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from oacli.model.robot_model import RobotModel
from oacli.planning.polish_settings import PolishSettings
from oacli.planning.translational import CostWeights, interval_cost_matrix
from oacli.solver import solve_clarabel


class PolishSubproblem:
    """The SCP subproblem of the module docstring as one DPP cvxpy problem, built once per grid.

    Parameters (``cp.Parameter``, set before each :meth:`solve`): ``r_ref`` (N+1, 3) trust-region centre [m],
    ``radius`` Δ [m], ``box_lower``/``box_upper`` (N, 3) keep-in box of each piece [m], ``normals[j]`` (N, 3) and
    ``offsets[j]`` (N,) the half-spaces of keep-out zone j, and ``cost_cap`` (when built with one).

    Parameters
    ----------
    h : ndarray, shape (N,)
        Piece lengths [s].
    model : RobotModel
        The robot (its mass [kg] is the double integrator's).
    start, goal : ndarray, shape (6,)
        Fixed first and last states.
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
    n_zones : int
        Keep-out zones.
    settings : PolishSettings
    weights : CostWeights
        Weights of ``J`` (for the cost cap).
    with_cost_cap : bool
        Add the constraint ``J <= cost_cap``.
    """

    def __init__(self, h: np.ndarray, model: RobotModel, start: np.ndarray, goal: np.ndarray,
                 force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray, n_zones: int, settings: PolishSettings,
                 weights: CostWeights, with_cost_cap: bool = False) -> None:
        h = np.asarray(h, dtype=float)
        n, m = h.shape[0], model.mass_kg
        hc = h[:, None]
        self.h = h
        self.r = cp.Variable((n + 1, 3), name="r")
        self.v = cp.Variable((n + 1, 3), name="v")
        self.f = cp.Variable((n, 3), name="f")
        self.buffer = cp.Variable(n, nonneg=True, name="buffer")
        r, v, f = self.r, self.v, self.f
        s = cp.reshape(self.buffer, (n, 1), order="F")
        self.r_ref = cp.Parameter((n + 1, 3), name="r_ref")
        self.radius = cp.Parameter(nonneg=True, name="trust_radius")
        self.box_lower = cp.Parameter((n, 3), name="box_lower")
        self.box_upper = cp.Parameter((n, 3), name="box_upper")
        self.normals = [cp.Parameter((n, 3), name=f"normal_{j}") for j in range(n_zones)]
        self.offsets = [cp.Parameter(n, name=f"offset_{j}") for j in range(n_zones)]
        eps = settings.limit_margin
        p0, p1, p2 = r[:-1], r[:-1] + cp.multiply(0.5 * hc, v[:-1]), r[1:]
        cons = [
            r[0] == start[0:3], v[0] == start[3:6], r[n] == goal[0:3], v[n] == goal[3:6],
            r[1:] == r[:-1] + cp.multiply(hc, v[:-1]) + cp.multiply(0.5 * hc * hc / m, f),
            v[1:] == v[:-1] + cp.multiply(hc / m, f),
            cp.abs(f) <= np.tile((1.0 - eps) * force_limit_N, (n, 1)),
            cp.abs(r - self.r_ref) <= self.radius,
        ]
        if n > 1:
            cons.append(cp.abs(v[1:n]) <= np.tile((1.0 - eps) * velocity_limit_mps, (n - 1, 1)))
        for p in (p0, p1, p2):
            cons += [p >= self.box_lower - s, p <= self.box_upper + s]
            for nrm, off in zip(self.normals, self.offsets, strict=True):
                cons.append(cp.sum(cp.multiply(nrm, p), axis=1) >= off - self.buffer)
        length = cp.sum(cp.norm(p1 - p0, 2, axis=1)) + cp.sum(cp.norm(p2 - p1, 2, axis=1))
        effort = cp.sum(cp.multiply(h, cp.sum(cp.square(f), axis=1)))
        objective = length + settings.effort_weight * effort + settings.buffer_penalty * cp.sum(self.buffer)
        self.cost_cap = None
        if with_cost_cap:
            self.cost_cap = cp.Parameter(name="cost_cap")
            cons.append(lqr_cost_expression(r, v, f, h, model, weights, goal) <= self.cost_cap)
        self.problem = cp.Problem(cp.Minimize(objective), cons)

    def set_reference(self, r_ref: np.ndarray, radius: float, box_lower: np.ndarray, box_upper: np.ndarray,
                      normals: list[np.ndarray], offsets: list[np.ndarray]) -> None:
        """Set the Parameters of one SCP iteration (trust-region centre and radius, keep-in bounds, half-spaces).

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
        self.r_ref.value, self.radius.value = r_ref, radius
        self.box_lower.value, self.box_upper.value = box_lower, box_upper
        for j, (nrm, off) in enumerate(zip(normals, offsets, strict=True)):
            self.normals[j].value = nrm
            self.offsets[j].value = off

    def set_cost_cap(self, cap: float) -> None:
        """Set ``J_max`` (built with ``with_cost_cap``).

        Parameters
        ----------
        cap : float
            The LQR cost cap ``J_max``.
        """
        assert self.cost_cap is not None
        self.cost_cap.value = cap

    @property
    def f_value(self) -> np.ndarray | None:
        """Forces (N, 3) of the last solve."""
        return None if self.f.value is None else np.asarray(self.f.value)

    @property
    def buffer_value(self) -> np.ndarray | None:
        """Buffers (N,) of the last solve."""
        return None if self.buffer.value is None else np.asarray(self.buffer.value)

    @property
    def objective(self) -> float:
        """Optimum of the last solve."""
        return float(self.problem.value)  # type: ignore[arg-type]

    def solve(self) -> str:
        """Solve with Clarabel (:func:`oacli.solver.solve_clarabel`; an inaccurate solve is reported by its status,
        not a warning).

        Returns
        -------
        str
            cvxpy's status, or ``solver_error: ...`` when Clarabel raised.
        """
        return solve_clarabel(self.problem, quiet=True, canon_backend="COO").status


def lqr_cost_expression(r, v, f, h: np.ndarray, model: RobotModel, weights: CostWeights, goal: np.ndarray):
    """``J`` of :mod:`oacli.planning.translational` as a convex cvxpy expression on pieces of lengths ``h``.

    Each piece contributes ``w_t h_k + Σ_axes ½ zᵀ W(h_k) z`` with ``z = [r_k − r_g, v_k, v_k − v_g, f_k]``
    (:func:`~oacli.planning.translational.interval_cost_matrix`), written as ``½ ‖G z‖²`` with ``W = Gᵀ G``.

    Parameters
    ----------
    r, v : cvxpy.Expression, shape (n + 1, 3)
        Positions and velocities at the knots.
    f : cvxpy.Expression, shape (n, 3)
        Held forces.
    h : ndarray, shape (n,)
        Piece lengths [s].
    model : RobotModel
        The robot (its mass [kg]).
    weights : CostWeights
    goal : ndarray, shape (6,)

    Returns
    -------
    cvxpy.Expression
        Scalar, convex.
    """
    h = np.asarray(h, dtype=float)
    total = weights.time * float(h.sum())
    for step in np.unique(h):
        idx = np.flatnonzero(h == step)
        for i in range(3):
            w = interval_cost_matrix(float(step), model, weights.position[i], weights.velocity[i], weights.force[i])
            lam, vec = np.linalg.eigh(0.5 * (w + w.T))
            keep = lam > 1e-14 * max(float(lam.max()), 1e-300)
            g = np.sqrt(lam[keep])[:, None] * vec[:, keep].T
            z = cp.vstack([r[idx, i] - goal[i], v[idx, i], v[idx, i] - goal[3 + i], f[idx, i]])  # (4, K)
            total = total + 0.5 * cp.sum_squares(g @ z)
    return total
