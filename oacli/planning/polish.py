"""Trajectory polish: sequential convex programming that shortens the path of a smoothed trajectory.

LQR shortcutting (:mod:`oacli.planning.shortcut`) minimises the LQR cost ``J`` of the translational plan; at cruise
speed that cost prefers wide turns around the tips of elongated keep-out ellipsoids (a tip's curvature radius
``a²/b`` is far below ``v²/a_max``), so the geometric path stays a few per cent longer than the shortest
collision-free one. The polish takes the shortcut result and minimises its *path length* on the same double
integrator (Doerr Eq. 34) by sequential convex programming (SCP; Schulman et al. 2014, "Motion planning with
sequential convex optimization and convex collision checking"; Mao, Szmuk & Açıkmeşe 2016, "Successive
convexification of non-convex optimal control problems"), each subproblem a second-order cone program solved by
Clarabel. Near a tip the result slows down to turn tightly and makes up the time on the straights.

Grid
----
The polish re-plans the held force on a grid of pieces of ``step_s`` (the last one shorter when the duration is
not a multiple; every piece a multiple of the output step ``dt_s``), ``k = 0 .. N``, so the subproblem stays small
(its size, and cvxpy's one-time canonicalisation, grow with N and with N² respectively). The result is sampled back
on ``dt_s`` exactly (:meth:`~oacli.planning.translational.TranslationalTrajectory.refined`).

Subproblem (one cvxpy problem, built once per trajectory and re-solved with new Parameter values)
----------------------------------------------------------------------------------------------------
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
Doerr Eqs. 12-14, grown by the robot's bounding ellipsoid R, ReSWARM §4.2.2). For the reference r̄, the hull of
piece k's control points is mapped into the normalised coordinates ``w = L (p − c_j)`` of an ellipsoid containing
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
collision-freedom; its duration never exceeds the budget.

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

import cvxpy as cp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from oacli.geometry.collision import CollisionChecker
from oacli.geometry.halfspaces import KeepOutZone, keep_out_zones, supporting_halfspaces
from oacli.planning.translational import CostWeights, TranslationalTrajectory, interval_cost_matrix
from oacli.solver import SUCCESS_STATUSES, solve_clarabel

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

#: Stand-in for an unbounded keep-in coordinate [m] (a scene without keep-in boxes).
_FAR_M = 1e6
#: Largest buffer [m] for which a solution counts as certified (solver tolerance).
_CERTIFIED_M = 1e-7
#: Least relative shortening that counts (the closed-form arc length rounds at ~1e-8 in near-straight pieces).
MIN_GAIN = 1e-7


@dataclass(frozen=True)
class PolishSettings:
    """Settings of :func:`polish_trajectory`.

    Attributes
    ----------
    iterations : int
        SCP subproblems solved at most.
    step_s : float
        Piece length of the polish grid [s] (a multiple of the output step).
    effort_weight : float
        ``w_e`` [m/(N²·s)], >= 0: weight of ``Σ h ‖f‖²`` against the length [m] (regularises the forces).
    buffer_penalty : float
        λ [-], > 0: exact penalty on the virtual buffers (metres of length per metre of violation).
    trust_radius_m : float
        Initial trust radius Δ [m] (per axis, on the knot positions).
    min_trust_radius_m, max_trust_radius_m : float
        The polish stops when Δ falls below the minimum; Δ never grows beyond the maximum [m].
    clearance_m : float
        μ [m], >= 0: extra distance kept from every keep-out zone (covers the exact re-propagation).
    limit_margin : float
        ε [-]: the subproblem keeps ``|f_i| <= (1 − ε) F_i`` and ``|v_i| <= (1 − ε) V_i``.
    tolerance : float
        Stop when a certified step lowers the subproblem objective by less than this fraction.
    rest_tolerance : float
        A trailing piece within this distance [m] and speed [m/s] of the goal at rest counts as arrived.
    """

    iterations: int = 30
    step_s: float = 0.5
    effort_weight: float = 0.01
    buffer_penalty: float = 1e3
    trust_radius_m: float = 0.05
    min_trust_radius_m: float = 1e-4
    max_trust_radius_m: float = 0.4
    clearance_m: float = 1e-4
    limit_margin: float = 1e-6
    tolerance: float = 1e-5
    rest_tolerance: float = 1e-7


@dataclass(frozen=True)
class PolishIteration:
    """One SCP subproblem and the verdict on its solution.

    Attributes
    ----------
    index : int
    trust_radius_m : float
        Δ used [m].
    status : str
        cvxpy status of the subproblem.
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
        Wall time of the subproblem solve [s] (the first includes cvxpy's canonicalisation).
    outcome : str
        ``accepted`` (the new result) or why not (:data:`STEP_OUTCOMES`).
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
        tolerance), ``trust_radius`` (Δ fell below its minimum), or why it was skipped.
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


# ------------------------------------------------------------------------------------------------------------
# Grid, projection and exact propagation
# ------------------------------------------------------------------------------------------------------------


def polish_grid(duration_s: float, step_s: float, dt_s: float) -> np.ndarray:
    """Piece lengths [s] covering ``duration_s``: pieces of ``step_s``, the last one shorter if need be.

    ``duration_s`` and ``step_s`` are rounded to multiples of ``dt_s`` (the duration down); every piece is then a
    multiple of ``dt_s``.

    Parameters
    ----------
    duration_s : float
        Duration to cover [s].
    step_s : float
        Piece length [s].
    dt_s : float
        Output sample period [s].

    Returns
    -------
    ndarray, shape (N,)
    """
    total = int(np.floor(duration_s / dt_s + 1e-9))
    per = max(1, round(step_s / dt_s))
    if total < 1:
        raise ValueError(f"duration {duration_s} s is shorter than the output step {dt_s} s")
    counts = [per] * (total // per) + ([total % per] if total % per else [])
    return np.array(counts, dtype=float) * dt_s


def _final_state_map(h: np.ndarray, mass_kg: float) -> np.ndarray:
    """Per axis, the effect ``Γ`` (2, N) of each held force on the final ``[r, v]`` (steps ``h``)."""
    after = np.concatenate([np.cumsum(h[::-1])[::-1][1:], [0.0]])  # time left after each piece
    return np.stack([(h / mass_kg) * (0.5 * h + after), h / mass_kg])


def terminal_correction(x0: np.ndarray, forces: np.ndarray, goal: np.ndarray, h: np.ndarray,
                        mass_kg: float) -> np.ndarray:
    """Least-norm change of the held forces (N, 3) after which the propagated final state is ``goal``.

    Per axis the final state is affine in the forces, ``x_N = Φ x_0 + Γ f`` with the columns
    ``Γ_k = (h_k/m) [h_k/2 + Σ_{j>k} h_j, 1]``; the correction is ``Γᵀ (Γ Γᵀ)⁻¹ (x_g − x_N)`` (N >= 2).

    Parameters
    ----------
    x0 : ndarray, shape (6,)
        Start state.
    forces : ndarray, shape (N, 3)
        Held forces [N].
    goal : ndarray, shape (6,)
        Required final state.
    h : ndarray, shape (N,)
        Piece lengths [s].
    mass_kg : float

    Returns
    -------
    ndarray, shape (N, 3)
        The corrected forces.
    """
    h = np.broadcast_to(np.asarray(h, dtype=float), (forces.shape[0],))
    gamma = _final_state_map(h, mass_kg)
    final = TranslationalTrajectory.from_forces(x0, forces, h, mass_kg).x[-1]
    err = np.asarray(goal, dtype=float) - final
    lam = np.linalg.solve(gamma @ gamma.T, np.stack([err[0:3], err[3:6]]))  # (2, 3)
    return forces + gamma.T @ lam


def exact_trajectory(x0: np.ndarray, forces: np.ndarray, goal: np.ndarray, h: np.ndarray,
                     mass_kg: float) -> TranslationalTrajectory:
    """The motion of held ``forces`` from ``x0`` corrected to end exactly at ``goal`` (last sample pinned).

    Parameters
    ----------
    x0, forces, goal, h, mass_kg
        As in :func:`terminal_correction`.

    Returns
    -------
    TranslationalTrajectory
    """
    forces = terminal_correction(x0, np.asarray(forces, dtype=float), goal, h, mass_kg)
    traj = TranslationalTrajectory.from_forces(x0, forces, h, mass_kg)
    x = traj.x.copy()
    x[-1] = goal  # equal up to rounding after the correction
    return TranslationalTrajectory(traj.t, x, traj.u, mass_kg)


def trim_rest(traj: TranslationalTrajectory, goal: np.ndarray, tolerance: float) -> TranslationalTrajectory:
    """Cut the trailing pieces that already rest at ``goal``, keeping at least two pieces; exact again.

    A piece rests when its states are within ``tolerance`` of the goal and its force changes the speed by at most
    ``tolerance`` over the piece.

    Parameters
    ----------
    traj : TranslationalTrajectory
    goal : ndarray, shape (6,)
    tolerance : float
        [m, m/s].

    Returns
    -------
    TranslationalTrajectory
        ``traj`` itself when nothing is cut.
    """
    h = traj.h
    near = np.all(np.abs(traj.x - goal) <= tolerance, axis=1)
    still = np.append(np.all(np.abs(traj.u) * h[:, None] / traj.mass_kg <= tolerance, axis=1), True)
    resting = np.flip(np.cumprod(np.flip(near & still))).astype(bool)  # this sample and every later one rest
    k = max(int(np.argmax(resting)) if resting.any() else len(h), 2)
    if k >= len(h):
        return traj
    return exact_trajectory(traj.x[0], traj.u[:k], goal, h[:k], traj.mass_kg)


def project_onto_grid(traj: TranslationalTrajectory, h: np.ndarray, goal: np.ndarray) -> TranslationalTrajectory:
    """The input as a trajectory on the polish grid: held forces fitted by least squares to its states at the
    knots, then corrected to reach ``goal`` exactly (:func:`exact_trajectory`).

    Minimises ``Σ_k ‖r_k − r̂_k‖² + (h̄)² ‖v_k − v̂_k‖²`` (h̄ the mean piece length, so both terms are lengths) over
    the forces, subject to the exact discretisation from the input's first state: an equality-constrained least
    squares problem, solved as one sparse KKT system (all three axes at once). Knots beyond the input's end take
    its final state (the goal at rest).

    Parameters
    ----------
    traj : TranslationalTrajectory
        The input.
    h : ndarray, shape (n,)
        Piece lengths [s] of the grid.
    goal : ndarray, shape (6,)

    Returns
    -------
    TranslationalTrajectory
    """
    h = np.asarray(h, dtype=float)
    n, m = h.shape[0], traj.mass_kg
    t_knots = np.concatenate([[0.0], np.cumsum(h)]) + traj.t[0]
    target = traj.states_at(np.minimum(t_knots, traj.t[-1]))[1:]  # (n, 6): knots 1..n
    w_v = float(np.mean(h)) ** 2
    # Unknowns per axis z = [r_1..r_n, v_1..v_n, f_0..f_{n-1}]; constraints: the dynamics of pieces 0..n-1.
    eye = sp.identity(n, format="csr")
    shift = sp.diags(np.ones(n - 1), -1, shape=(n, n), format="csr")  # picks x_{k-1} for row k
    dyn = sp.bmat([
        [eye - shift, -sp.diags(h) @ shift, sp.diags(-0.5 * h * h / m)],
        [None, eye - shift, sp.diags(-h / m)],
    ], format="csr")
    hess = sp.diags(np.concatenate([np.ones(n), np.full(n, w_v), np.full(n, 1e-12)]))
    kkt = sp.bmat([[hess, dyn.T], [dyn, None]], format="csc")
    x0 = traj.x[0]
    rhs_dyn = np.zeros((2 * n, 3))
    rhs_dyn[0] = x0[0:3] + h[0] * x0[3:6]  # piece 0 starts from the known first state
    rhs_dyn[n] = x0[3:6]
    rhs = np.vstack([target[:, 0:3], w_v * target[:, 3:6], np.zeros((n, 3)), rhs_dyn])
    sol = spla.spsolve(kkt, rhs)
    forces = np.asarray(sol).reshape(-1, 3)[2 * n:3 * n]
    return exact_trajectory(x0, forces, goal, h, m)


def within_limits(traj: TranslationalTrajectory, force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray) -> bool:
    """Every held force and every velocity within its per-axis limit (relative tolerance 1e-9, as the stages).

    Parameters
    ----------
    traj : TranslationalTrajectory
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)

    Returns
    -------
    bool
    """
    return bool(np.all(traj.max_abs_force_N() <= force_limit_N * (1 + 1e-9))
                and np.all(traj.max_abs_velocity_mps() <= velocity_limit_mps * (1 + 1e-9)))


# ------------------------------------------------------------------------------------------------------------
# Geometry of the convexification
# ------------------------------------------------------------------------------------------------------------


def _closest_on_segments(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Point of least norm on each segment ``a[i] → b[i]``, shape (K, 3)."""
    d = b - a
    dd = np.einsum("ki,ki->k", d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dd > 1e-300, -np.einsum("ki,ki->k", a, d) / dd, 0.0)
    t = np.clip(np.nan_to_num(t), 0.0, 1.0)
    return a + t[:, None] * d


def min_norm_on_triangles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Point of least Euclidean norm in each triangle ``conv{a, b, c}`` (degenerate triangles allowed), (K, 3).

    Exact: the minimum lies on an edge or, if the origin projects inside the triangle's plane region, at that
    projection; every candidate is in the triangle, and the least-norm one is returned.

    Parameters
    ----------
    a, b, c : ndarray, shape (K, 3)
        Corners.

    Returns
    -------
    ndarray, shape (K, 3)
    """
    cands = [_closest_on_segments(a, b), _closest_on_segments(b, c), _closest_on_segments(a, c)]
    nrm = np.cross(b - a, c - a)
    n2 = np.einsum("ki,ki->k", nrm, nrm)
    scale = np.maximum.reduce([np.einsum("ki,ki->k", e, e) for e in (b - a, c - a, c - b)]) + 1e-300
    face = n2 > 1e-12 * scale * scale
    if np.any(face):
        af, bf, cf, nf = a[face], b[face], c[face], nrm[face]
        p = nf * (np.einsum("ki,ki->k", af, nf) / n2[face])[:, None]
        # Barycentric signs: p inside iff it is on the inner side of the three edges.
        s1 = np.einsum("ki,ki->k", np.cross(bf - af, p - af), nf)
        s2 = np.einsum("ki,ki->k", np.cross(cf - bf, p - bf), nf)
        s3 = np.einsum("ki,ki->k", np.cross(af - cf, p - cf), nf)
        inside = (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
        proj = np.full_like(a, np.inf)
        idx = np.flatnonzero(face)[inside]
        proj[idx] = p[inside]
        cands.append(proj)
    stack = np.stack(cands, axis=1)  # (K, C, 3)
    norms = np.linalg.norm(stack, axis=2)
    return stack[np.arange(a.shape[0]), np.argmin(norms, axis=1)]


def keep_out_halfspaces(
    zone: KeepOutZone, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, clearance_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Half-spaces ``nᵀ p >= b`` (unit n) that keep pieces with control points ``p0, p1, p2`` (K, 3) out of a zone.

    Parameters
    ----------
    zone : KeepOutZone
    p0, p1, p2 : ndarray, shape (K, 3)
        Control points [m] of the K pieces (start, mid-piece control point, end).
    clearance_m : float
        Extra clearance [m].

    Returns
    -------
    normal : ndarray, shape (K, 3)
    offset : ndarray, shape (K,)
        ``b``: the support of the zone (robot included) in direction n plus the clearance (module docstring).
    margin : ndarray, shape (K,)
        ``min_P nᵀ P − b`` over the three control points [m]: >= 0 where these pieces satisfy their half-space.
    """
    lmat, c = zone.metric, zone.center
    w = [(p - c) @ lmat.T for p in (p0, p1, p2)]
    w_star = min_norm_on_triangles(*w)
    norm = np.linalg.norm(w_star, axis=1)
    # The hull contains the centre (no direction): point from the centre to the hull's mean instead.
    m = np.where(norm[:, None] > 1e-12, w_star, (w[0] + w[1] + w[2]) / 3.0)
    m = np.where(np.linalg.norm(m, axis=1)[:, None] > 1e-12, m, np.array([1.0, 0.0, 0.0]))
    n, offset = supporting_halfspaces(zone, m, clearance_m)
    current = np.minimum.reduce([np.einsum("ki,ki->k", n, p) for p in (p0, p1, p2)])
    return n, offset, current - offset


def keep_in_bounds(checker: CollisionChecker, p0: np.ndarray, p1: np.ndarray,
                   p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per piece, the keep-in box its control points must stay in.

    The first box holding all three of them, else the box holding most of them (the buffer then absorbs the
    difference); without keep-in boxes, bounds far outside any scene.

    Parameters
    ----------
    checker : CollisionChecker
    p0, p1, p2 : ndarray, shape (K, 3)
        Control points [m] of the K pieces (start, mid-piece control point, end).

    Returns
    -------
    lower, upper : ndarray, shape (K, 3)
    """
    boxes = checker.scene.keep_in
    k = p0.shape[0]
    if not boxes:
        return np.full((k, 3), -_FAR_M), np.full((k, 3), _FAR_M)
    lo = np.array([b.lower for b in boxes])
    hi = np.array([b.upper for b in boxes])
    count = sum(np.all((p[:, None, :] >= lo) & (p[:, None, :] <= hi), axis=2).astype(int) for p in (p0, p1, p2))
    chosen = np.argmax(count, axis=1)  # first box with the most control points inside
    return lo[chosen], hi[chosen]


# ------------------------------------------------------------------------------------------------------------
# The subproblem
# ------------------------------------------------------------------------------------------------------------


class PolishSubproblem:
    """The SCP subproblem of the module docstring as one DPP cvxpy problem, built once per grid.

    Parameters (``cp.Parameter``, set before each :meth:`solve`): ``r_ref`` (N+1, 3) trust-region centre [m],
    ``radius`` Δ [m], ``box_lower``/``box_upper`` (N, 3) keep-in box of each piece [m], ``normals[j]`` (N, 3) and
    ``offsets[j]`` (N,) the half-spaces of keep-out zone j, and ``cost_cap`` (when built with one).

    Parameters
    ----------
    h : ndarray, shape (N,)
        Piece lengths [s].
    mass_kg : float
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

    def __init__(self, h: np.ndarray, mass_kg: float, start: np.ndarray, goal: np.ndarray,
                 force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray, n_zones: int, settings: PolishSettings,
                 weights: CostWeights, with_cost_cap: bool = False) -> None:
        h = np.asarray(h, dtype=float)
        n, m = h.shape[0], float(mass_kg)
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
            cons.append(lqr_cost_expression(r, v, f, h, m, weights, goal) <= self.cost_cap)
        self.problem = cp.Problem(cp.Minimize(objective), cons)

    def solve(self) -> str:
        """Solve with Clarabel (:func:`oacli.solver.solve_clarabel`; an inaccurate solve is reported by its status,
        not a warning).

        Returns
        -------
        str
            cvxpy's status, or ``solver_error: ...`` when Clarabel raised.
        """
        return solve_clarabel(self.problem, quiet=True, canon_backend="COO").status


def lqr_cost_expression(r, v, f, h: np.ndarray, mass_kg: float, weights: CostWeights, goal: np.ndarray):
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
    mass_kg : float
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
            w = interval_cost_matrix(float(step), mass_kg, weights.position[i], weights.velocity[i], weights.force[i])
            lam, vec = np.linalg.eigh(0.5 * (w + w.T))
            keep = lam > 1e-14 * max(float(lam.max()), 1e-300)
            g = np.sqrt(lam[keep])[:, None] * vec[:, keep].T
            z = cp.vstack([r[idx, i] - goal[i], v[idx, i], v[idx, i] - goal[3 + i], f[idx, i]])  # (4, K)
            total = total + 0.5 * cp.sum_squares(g @ z)
    return total


# ------------------------------------------------------------------------------------------------------------
# The polish
# ------------------------------------------------------------------------------------------------------------


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
    sub = PolishSubproblem(h, traj.mass_kg, traj.x[0], goal, force_limit_N, velocity_limit_mps, len(zones), s,
                           weights, with_cost_cap=cap is not None)
    if sub.cost_cap is not None:
        sub.cost_cap.value = cap
    ref = project_onto_grid(traj, h, goal)
    best: TranslationalTrajectory | None = None
    best_len = length0
    radius = s.trust_radius_m
    last_objective = np.inf
    reason = "iterations"
    for i in range(s.iterations):
        if radius < s.min_trust_radius_m:
            reason = "trust_radius"
            break
        x = ref.x
        p0, p1, p2 = x[:-1, 0:3], x[:-1, 0:3] + 0.5 * h[:, None] * x[:-1, 3:6], x[1:, 0:3]
        for j, zone in enumerate(zones):
            nrm, off, _ = keep_out_halfspaces(zone, p0, p1, p2, s.clearance_m)
            sub.normals[j].value = nrm
            sub.offsets[j].value = off
        sub.box_lower.value, sub.box_upper.value = keep_in_bounds(checker, p0, p1, p2)
        sub.r_ref.value = x[:, 0:3]
        sub.radius.value = radius
        t0 = time.perf_counter()
        status = sub.solve()
        base = dict(index=i, trust_radius_m=radius, status=status, solve_time_s=time.perf_counter() - t0)
        if status not in SUCCESS_STATUSES or sub.f.value is None:
            iters.append(PolishIteration(**base, objective=np.nan, buffer_m=np.nan, length_m=np.nan,  # type: ignore[arg-type]
                                         duration_s=np.nan, cost=np.nan, outcome=SOLVER))
            radius *= 0.5
            continue
        full = exact_trajectory(traj.x[0], sub.f.value, goal, h, traj.mass_kg)
        coarse = trim_rest(full, goal, s.rest_tolerance)
        cand = coarse.refined(dt_s)  # the output, judged as it would be returned
        buffer = float(np.max(sub.buffer.value))  # type: ignore[arg-type]
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
        objective = float(sub.problem.value)
        iters.append(PolishIteration(**base, objective=objective, buffer_m=buffer, length_m=length,  # type: ignore[arg-type]
                                     duration_s=cand.duration_s, cost=cost, outcome=outcome))
        if outcome == ACCEPTED:
            best, best_len = cand, length
            accepted.append((i, cand))
        if certified and outcome in (LIMITS, COST, COLLISION):
            radius *= 0.5  # a certified solution should pass: numerical trouble, take smaller steps
            continue
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
