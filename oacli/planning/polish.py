"""Trajectory polish: sequential convex programming that shortens the path of a smoothed trajectory.

LQR shortcutting (:mod:`oacli.planning.shortcut`) minimises the LQR cost ``J`` of the translational plan; at cruise
speed that cost prefers wide turns around the tips of elongated keep-out ellipsoids (a tip's curvature radius
``a²/b`` is far below ``v²/a_max``), so the geometric path stays a few per cent longer than the shortest
collision-free one. The polish takes the shortcut result and minimises its *path length* on the same double
integrator ([Doerr2021] Eq. 34) by sequential convex programming (SCP; Schulman et al. 2014, "Motion planning with
sequential convex optimization and convex collision checking"; Mao, Szmuk & Açıkmeşe 2016, "Successive
convexification of non-convex optimal control problems"), each subproblem a second-order cone program solved by
Clarabel. Near a tip the result slows down to turn tightly and makes up the time on the straights.

Grid
----
The polish re-plans the held force on a grid of pieces of ``step_s`` (the last one shorter when the duration is
not a multiple; every piece a multiple of the output step ``dt_s``), ``k = 0 .. N``, so the subproblem stays small
(its size grows with N; cvxpy's one-time canonicalisation of the reference formulation with N²). The result is
sampled back on ``dt_s`` exactly (:meth:`~oacli.planning.translational.TranslationalTrajectory.refined`).

Subproblem (built once per trajectory, re-solved with the data of each iteration)
--------------------------------------------------------------------------------
Assembled directly in Clarabel's conic form by :class:`~oacli.planning.polish_conic.PolishConic` (default), or as
the DPP cvxpy problem :class:`~oacli.planning.polish_subproblem.PolishSubproblem` (``backend='cvxpy'``, the
reference; the tests check that both have the same optimum). Rows implied by the trust region and the velocity
limits are left out of the direct form (same feasible set), and after the first iteration it solves with a working
set of the force/velocity rows and the cost cap, grown until the solution satisfies the rest (the same optimum;
:mod:`oacli.planning.polish_conic`).
::

    minimise    Σ_k ( ‖P1_k − P0_k‖ + ‖P2_k − P1_k‖ )  +  w_e Σ_k h_k ‖f_k‖²  +  λ Σ_k s_k
    subject to  r_{k+1} = r_k + h_k v_k + h_k²/(2m) f_k,   v_{k+1} = v_k + (h_k/m) f_k     (exact discretisation)
                x_0 = start,  x_N = goal,
                |f_k,i| <= (1 − ε) F_i,   |v_k,i| <= (1 − ε) V_i   (0 < k < N),
                lower_k − s_k <= P <= upper_k + s_k       for P in {P0_k, P1_k, P2_k}     (keep-in box),
                n_kjᵀ P >= b_kj − s_k                      for P in {P0_k, P1_k, P2_k}, every keep-out zone j,
                |r_k,i − r̄_k,i| <= Δ,   s_k >= 0,
                [optional]  J(x, f) <= J_max                                            (LQR cost cap).

``P0_k = r_k``, ``P1_k = r_k + (h_k/2) v_k`` and ``P2_k = r_{k+1}`` are the Bézier control points of the exact
quadratic position ``r(τ) = r_k + v_k τ + ½ (f_k/m) τ²`` on piece k (all affine in the variables). The curve lies
in their convex hull, so

* the length term is an upper bound of the exact arc length (a control polygon is never shorter than its curve);
* a half-space or box that holds the three control points holds the whole continuous piece (no tunnelling).

``s_k`` is a virtual buffer (Mao et al. 2016) with an exact ℓ1 penalty λ: it keeps every subproblem feasible when
the reference violates a constraint (only the first reference can: see below) and is zero whenever a solution
within the trust region satisfies them all.

Convexified keep-out zones
--------------------------
Zone j's set of forbidden centre positions is ``O_j = E_j ⊕ R`` (the keep-out ellipsoid, safety factor applied,
[Doerr2021] Eqs. 12-14, grown by the robot's bounding ellipsoid R, [ReSWARM2023] §4.2.2). For the reference r̄, the hull
of piece k's control points is mapped into the normalised coordinates ``w = L (p − c_j)`` of an ellipsoid containing
``O_j`` (``E_j`` itself for a point robot; the trace-minimal outer ellipsoid of the Minkowski sum otherwise), where
that ellipsoid is the unit ball. The hull's point ``w*`` of least norm (exact: vertices, edges and face of the
triangle) gives the direction ``m = w*/‖w*‖``; the world normal is ``n = Lᵀ m`` and the offset is the support
function of ``O_j`` plus a clearance μ::

    b_kj = nᵀ c_j + sqrt(nᵀ Σ_j n) + sqrt(nᵀ Σ_R n) + μ ‖n‖      (Σ_j = P_j⁻¹, Σ_R the robot's shape).

``O_j`` lies entirely on the other side, so a piece whose control points satisfy the constraint is collision-free
in continuous time: a solution with ``s = 0`` is *certified* collision-free. When the reference hull is at least μ
outside the outer ellipsoid, ``m`` separates it from the unit ball and the reference satisfies its own
linearisation; once a certified solution becomes the reference this holds at every later iteration, so each
subproblem's optimum is no worse than the reference (the inner-convex-approximation argument of Marks & Wright
1978) and the iteration descends monotonically. At a contact the half-space is the zone's tangent plane.

Iteration
---------
The first reference is the input projected onto the grid (least-squares fit of the knot states, then the exact
goal). Each subproblem solution is made exact: the forces get the least-norm correction that reaches the goal
exactly (:func:`terminal_correction`) and the states are re-propagated. It becomes the next reference (a certified
one doubles Δ up to its maximum; a certified one that fails an exact check halves it, as does a failed solve), and
it becomes the *result* only if, after cutting any trailing rest at the goal, it is within the force and velocity
limits, passes the EXACT continuous collision check (:class:`~oacli.geometry.collision.CollisionChecker`), fits
the cost cap and is shorter than the best so far by more than :data:`MIN_GAIN` (relative; exact arc length,
:meth:`~oacli.planning.translational.TranslationalTrajectory.path_length_m`, of the candidate sampled every ``dt_s``
as it would be returned). The result is therefore never longer than the input and never breaks the limits or
collision-freedom; its duration never exceeds the budget. The iteration stops when a certified step lowers the
subproblem objective by less than ``tolerance`` (relative), or when ``stall_iterations`` certified steps in a row
shorten the best by less than ``stall_gain`` (relative) each: the objective can keep creeping down through its
effort term while the returned length gains only micrometres (on S2, runs of ten and more certified steps each
shorten a 5.6 m path by 0.1-10 µm while a contact slides along a keep-out zone's edge).

Look-ahead
----------
Near a tip of a keep-out zone the half-space of a piece is the tangent plane at the point its reference touches;
a piece that must slide round the tip gets only as far as that plane lets it, and the next subproblem, linearised
there, a little further: on S2 runs of 10-30 certified steps each move the knots on in the same direction by a
ratio of 0.9-1.0 of the step before (cosine > 0.99). After a certified accepted step whose knot position change
has a cosine of at least ``prediction_min_cos`` with the step before, the next subproblem's half-spaces are
therefore taken at the reference moved on by ``prediction`` times the last step (its trust region, keep-in boxes
and everything else stay at the reference). Every such half-space is still a supporting half-space of ``O_j``
(the offset is the support function in *any* direction), so a certified solution stays collision-free in
continuous time; what is lost is only the descent argument (the reference need not satisfy half-spaces taken
ahead of it). A look-ahead step therefore counts only when it is certified, accepted and shortens the best by at
least ``stall_gain``; otherwise the next step linearises at its reference again (at the look-ahead's result when it
was accepted); a look-ahead step that did not pay counts for neither the stall nor the convergence test.
``prediction = 0`` never looks ahead. The iteration is a different one, so it can end in a different local optimum
of the non-convex problem: on the benchmark's S2 plans of seeds 0-59 (``benchmarks/bench_planners.py``) it solves
24 % fewer subproblems; the median path comes out 3e-5 shorter (relative; 37 of 60 shorter, by up to 2.4e-3) and
one longer (by 2.1e-6); on the ISS segments the subproblems change by -6 % and +4 %, and no path is longer.

Cost semantics
--------------
The polish minimises *length* (plus a small effort term), not the LQR cost ``J`` of
:mod:`oacli.planning.translational` that the planners and the shortcutting minimise; shortening the path at the same
duration takes more force, so ``J`` usually rises. Both are reported before and after. With ``cost_cap = J_max``
the subproblem also keeps ``J <= J_max`` (``J`` is a convex quadratic of the variables on a fixed grid) and a
candidate above it is never the result: the ``smooth`` stage passes the cost of *its* input, so shortcutting
followed by the polish never returns a trajectory costlier than the plan it was given.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import CollisionChecker
from oacli.geometry.halfspaces import keep_out_zones
from oacli.planning.translational import CostWeights, TranslationalTrajectory
from oacli.solver import SUCCESS_STATUSES

IMPROVED = "improved"
NOT_IMPROVED = "not_improved"
SKIPPED = "skipped"

ACCEPTED = "accepted"
NOT_SHORTER = "not_shorter"
COLLISION = "collision"
LIMITS = "limits"
COST = "cost"
SOLVER = "solver_failed"
STEP_OUTCOMES = (ACCEPTED, NOT_SHORTER, COLLISION, LIMITS, COST, SOLVER)

#: Largest buffer [m] for which a solution counts as certified (solver tolerance).
_CERTIFIED_M = 1e-7
#: Least relative shortening that counts (the closed-form arc length rounds at ~1e-8 in near-straight pieces).
MIN_GAIN = 1e-7


@dataclass(frozen=True)
class PolishIteration:
    """One SCP subproblem and the verdict on its solution.

    Attributes
    ----------
    index : int
    trust_radius_m : float
        Δ used [m].
    status : str
        cvxpy-style status of the subproblem.
    objective : float
        Subproblem optimum (length bound + effort + buffer penalty), NaN when the solve failed.
    buffer_m : float
        Largest virtual buffer s_k of the solution [m] (0: certified collision-free and inside the keep-in).
    length_m : float
        Exact arc length of the candidate [m] (NaN when the solve failed).
    duration_s : float
        Candidate duration after cutting the trailing rest [s].
    cost : float
        LQR cost ``J`` of the candidate.
    solve_time_s : float
        Wall time of the subproblem solve [s] (with ``backend='cvxpy'`` the first includes cvxpy's
        canonicalisation).
    outcome : str
        ``accepted`` (the new result) or why not (:data:`STEP_OUTCOMES`).
    predicted : bool
        The keep-out half-spaces were taken ahead of the reference (look-ahead step; module docstring).
    """

    index: int
    trust_radius_m: float
    status: str
    objective: float
    buffer_m: float
    length_m: float
    duration_s: float
    cost: float
    solve_time_s: float
    outcome: str
    predicted: bool = False


@dataclass(frozen=True)
class PolishResult:
    """Outcome of :func:`polish_trajectory`.

    Attributes
    ----------
    status : str
        ``improved``, ``not_improved`` or ``skipped`` (see ``reason``).
    trajectory : TranslationalTrajectory
        The polished trajectory sampled every ``dt_s`` (the input when nothing was accepted).
    length_before_m, length_after_m : float
        Exact arc lengths [m].
    duration_before_s, duration_after_s : float
    cost_before, cost_after : float
        LQR cost ``J`` (:mod:`oacli.planning.translational`) of the input and of the result.
    duration_budget_s : float
        Longest duration allowed [s].
    cost_cap : float or None
        ``J_max`` kept (None: no cap).
    pieces : int
        N, pieces of the polish grid (0 when skipped).
    iterations : tuple of PolishIteration
    reason : str
        Why the polish stopped: ``iterations`` (budget spent), ``converged`` (a certified step gained less than the
        tolerance), ``stalled`` (``stall_iterations`` certified steps in a row shortened the best by less than
        ``stall_gain``),
        ``trust_radius`` (Δ fell below its minimum), or why it was skipped.
    accepted_trajectories : tuple of (int, TranslationalTrajectory)
        Every accepted candidate with its iteration index (sampled every ``dt_s``), for replaying the polish.
    """

    status: str
    trajectory: TranslationalTrajectory
    length_before_m: float
    length_after_m: float
    duration_before_s: float
    duration_after_s: float
    cost_before: float
    cost_after: float
    duration_budget_s: float
    cost_cap: float | None
    pieces: int
    iterations: tuple[PolishIteration, ...]
    reason: str
    accepted_trajectories: tuple[tuple[int, TranslationalTrajectory], ...] = ()

    @property
    def accepted(self) -> int:
        """Accepted candidates (each one shorter than the previous result)."""
        return sum(it.outcome == ACCEPTED for it in self.iterations)


# The polish is split in four modules: polish_grid (time grid, projection, exact propagation), polish_geometry
# (half-spaces and bounds of the convexification), polish_subproblem (the convex subproblem) and this one (types
# and the SCP loop); their public names are re-exported here.
from oacli.planning.polish_conic import PolishConic  # noqa: E402
from oacli.planning.polish_geometry import (  # noqa: E402
    keep_in_bounds,
    keep_out_halfspaces,
    keep_out_halfspaces_of_zones,
    min_norm_on_triangles,
)
from oacli.planning.polish_grid import (  # noqa: E402
    exact_trajectory,
    polish_grid,
    project_onto_grid,
    terminal_correction,
    trim_rest,
    within_limits,
)
from oacli.planning.polish_settings import PolishSettings  # noqa: E402
from oacli.planning.polish_subproblem import PolishSubproblem, lqr_cost_expression  # noqa: E402

__all__ = [
    "ACCEPTED", "COLLISION", "COST", "IMPROVED", "LIMITS", "MIN_GAIN", "NOT_IMPROVED", "NOT_SHORTER", "SKIPPED",
    "SOLVER", "STEP_OUTCOMES", "PolishConic", "PolishIteration", "PolishResult", "PolishSettings", "PolishSubproblem",
    "exact_trajectory", "keep_in_bounds", "keep_out_halfspaces", "lqr_cost_expression", "min_norm_on_triangles",
    "polish_grid", "polish_trajectory", "project_onto_grid", "terminal_correction", "trim_rest", "within_limits",
]


def _cosine(a: np.ndarray, b: np.ndarray) -> float:
    """Cosine of the angle between two arrays taken as vectors (0 when one is zero)."""
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.sum(a * b)) / norm if norm > 0 else 0.0


def polish_trajectory(
    traj: TranslationalTrajectory,
    checker: CollisionChecker,
    goal: np.ndarray,
    force_limit_N: np.ndarray,
    velocity_limit_mps: np.ndarray,
    weights: CostWeights,
    *,
    dt_s: float,
    duration_budget_s: float | None = None,
    cost_cap: float | None = None,
    settings: PolishSettings | None = None,
) -> PolishResult:
    """Shorten the path of a collision-free, rest-to-rest trajectory by SCP (module docstring).

    Parameters
    ----------
    traj : TranslationalTrajectory
        Input (e.g. the LQR shortcut result): collision-free, within the limits, ending at ``goal``.
    checker : CollisionChecker
        Scene and robot body; every accepted candidate passes its exact continuous check.
    goal : ndarray, shape (6,)
        Goal state (the input's last state).
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
    weights : CostWeights
        Weights of the LQR cost ``J`` (reported, and capped with ``cost_cap``).
    dt_s : float
        Output step [s] (the planner's ``output_dt_s``); ``settings.step_s`` is rounded to a multiple of it.
    duration_budget_s : float, optional
        Longest duration of the result [s]; never less than the input's duration (the default).
    cost_cap : float, optional
        ``J_max``: keep ``J <= J_max`` (the polish is skipped when the input is above it).
    settings : PolishSettings, optional

    Returns
    -------
    PolishResult
    """
    s = settings if settings is not None else PolishSettings()
    goal = np.asarray(goal, dtype=float).reshape(6)
    force_limit_N = np.asarray(force_limit_N, dtype=float).reshape(3)
    velocity_limit_mps = np.asarray(velocity_limit_mps, dtype=float).reshape(3)
    length0, cost0, dur0 = traj.path_length_m(), traj.cost(weights, goal), traj.duration_s
    budget = max(dur0, duration_budget_s if duration_budget_s is not None else dur0)
    cap = None if cost_cap is None else float(cost_cap)
    iters: list[PolishIteration] = []
    accepted: list[tuple[int, TranslationalTrajectory]] = []

    def result(status: str, out: TranslationalTrajectory, reason: str, pieces: int = 0) -> PolishResult:
        return PolishResult(status, out, length0, out.path_length_m(), dur0, out.duration_s, cost0,
                            out.cost(weights, goal), budget, cap, pieces, tuple(iters), reason, tuple(accepted))

    if len(traj) < 2 or not np.array_equal(traj.x[-1], goal):
        return result(SKIPPED, traj, "the input does not end exactly at the goal")
    if cap is not None and cost0 > cap * (1 + 1e-9):
        return result(SKIPPED, traj, f"the input's cost {cost0:.6g} is above the cost cap {cap:.6g}")
    h = polish_grid(budget + 1e-9 * dt_s, s.step_s, dt_s)
    n = h.shape[0]
    if n < 2:
        return result(SKIPPED, traj, f"the input is shorter than two polish steps of {s.step_s:g} s")
    zones = keep_out_zones(checker.scene, checker.robot)
    builder = PolishConic if s.backend == "direct" else PolishSubproblem
    sub = builder(h, traj.model, traj.x[0], goal, force_limit_N, velocity_limit_mps, len(zones), s,
                  weights, with_cost_cap=cap is not None)
    if cap is not None:
        sub.set_cost_cap(cap)
    ref = project_onto_grid(traj, h, goal)
    best: TranslationalTrajectory | None = None
    best_len = length0
    radius = s.trust_radius_m
    last_objective = np.inf
    stalled = 0
    reason = "iterations"
    ahead: np.ndarray | None = None  # the last step (knot states), when the next linearisation looks ahead by it
    last_step: np.ndarray | None = None  # the last certified accepted step's knot position changes
    for i in range(s.iterations):
        if radius < s.min_trust_radius_m:
            reason = "trust_radius"
            break
        x = ref.x
        p0, p1, p2 = x[:-1, 0:3], x[:-1, 0:3] + 0.5 * h[:, None] * x[:-1, 3:6], x[1:, 0:3]
        predicted = ahead is not None
        xl = x if ahead is None else x + s.prediction * ahead  # where the half-spaces are taken
        planes = keep_out_halfspaces_of_zones(zones, xl[:-1, 0:3], xl[:-1, 0:3] + 0.5 * h[:, None] * xl[:-1, 3:6],
                                              xl[1:, 0:3], s.clearance_m)
        sub.set_reference(x[:, 0:3], radius, *keep_in_bounds(checker, p0, p1, p2),
                          [pl[0] for pl in planes], [pl[1] for pl in planes])
        if hasattr(sub, "set_working_hint"):
            sub.set_working_hint(x, ref.u, ref.cost(weights, goal) if cap is not None else 0.0)
        t0 = time.perf_counter()
        status = sub.solve()
        base = dict(index=i, trust_radius_m=radius, status=status, solve_time_s=time.perf_counter() - t0)
        if status not in SUCCESS_STATUSES or sub.f_value is None:
            iters.append(PolishIteration(**base, objective=np.nan, buffer_m=np.nan, length_m=np.nan,  # type: ignore[arg-type]
                                         duration_s=np.nan, cost=np.nan, outcome=SOLVER, predicted=predicted))
            radius *= 0.5
            ahead = last_step = None
            continue
        full = exact_trajectory(traj.x[0], sub.f_value, goal, h, traj.model)
        coarse = trim_rest(full, goal, s.rest_tolerance)
        cand = coarse.refined(dt_s)  # the output, judged as it would be returned
        buffer = float(np.max(sub.buffer_value))  # type: ignore[arg-type]
        certified = buffer <= _CERTIFIED_M
        length, cost = cand.path_length_m(), cand.cost(weights, goal)
        if not within_limits(cand, force_limit_N, velocity_limit_mps):
            outcome = LIMITS
        elif cap is not None and cost > cap * (1 + 1e-9):
            outcome = COST
        elif not checker.is_free(coarse.pieces()):  # the same curve as cand's, in fewer pieces
            outcome = COLLISION
        elif not length < best_len * (1.0 - MIN_GAIN):
            outcome = NOT_SHORTER
        else:
            outcome = ACCEPTED
        objective = float(sub.objective)
        iters.append(PolishIteration(**base, objective=objective, buffer_m=buffer, length_m=length,  # type: ignore[arg-type]
                                     duration_s=cand.duration_s, cost=cost, outcome=outcome, predicted=predicted))
        gained = certified and outcome == ACCEPTED and length < best_len * (1.0 - s.stall_gain)
        if outcome == ACCEPTED:
            best, best_len = cand, length
            accepted.append((i, cand))
        if predicted and not gained:
            # The look-ahead did not pay: back to the reference's own linearisation (from the new result if there
            # is one), whose step descends; such a step counts for neither the stall nor the convergence test.
            ahead = last_step = None
            if outcome == ACCEPTED:
                ref = full
            continue
        # A certified step that shortens the best by less than ``stall_gain`` (or not at all) counts as stalled.
        small = certified and outcome in (ACCEPTED, NOT_SHORTER) and not gained
        stalled = stalled + 1 if small else 0
        if s.stall_iterations > 0 and stalled >= s.stall_iterations:
            reason = "stalled"
            break
        if certified and outcome in (LIMITS, COST, COLLISION):
            radius *= 0.5  # a certified solution should pass: numerical trouble, take smaller steps
            continue
        # Look ahead after a certified accepted step in the direction of the one before (module docstring).
        step = full.x[:, 0:3] - x[:, 0:3]
        aligned = last_step is not None and _cosine(step, last_step) >= s.prediction_min_cos
        last_step = step if (certified and outcome == ACCEPTED) else None
        ahead = full.x - x if (aligned and last_step is not None and s.prediction > 0) else None
        ref = full  # descends once certified; before, it moves the reference towards the constraints
        if certified:
            radius = min(2.0 * radius, s.max_trust_radius_m)
            if last_objective - objective < s.tolerance * abs(objective):
                reason = "converged"
                break
            last_objective = objective
    if best is None:
        return result(NOT_IMPROVED, traj, reason, n)
    return result(IMPROVED, best, reason, n)
