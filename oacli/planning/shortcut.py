"""Trajectory smoothing by LQR shortcutting ([Doerr2021] §"Trajectory Smoothing by LQR Shortcutting";
[ReSWARM2023] §4.3; after Hauser & Ng-Thow-Hing 2010).

Each try picks two random samples ``x_a`` (at ``t_a``) and ``x_b`` (at ``t_b``) of the current trajectory
``σ = [σ1, σ2, σ3]`` and computes the LQR interpolation between them: for every horizon, the exact LQR connection
from ``x_a`` to ``x_b`` (:class:`~oacli.planning.steering.LqrConnector`). The cheapest connection is spliced in
for ``σ2`` only if it

1. costs less than ``σ2`` (the cost of :mod:`oacli.planning.translational` is additive over samples, so the
   whole trajectory's cost drops by exactly the difference),
2. keeps every force ``|f_i| <= F_i`` and every velocity ``|v_i| <= V_i``, and
3. is collision-free in continuous time (:mod:`oacli.geometry.collision`).

(The ReSWARM flight code spliced shortcuts in without the collision check.) Every try is recorded with its
outcome, so the smoothing can be audited.

Speed (issue 13): tries are drawn in batches against the current trajectory and their connection costs for every
horizon computed in one vectorised call (most tries end there: no cheaper connection); the cheaper horizons of a
try are then taken in cost order: the first few horizons' forces and samples come from one batched product
(:meth:`~oacli.planning.steering.LqrConnector.batch`: their limit check), the remaining horizons' limits from one
limit check of them all, and the samples of the first ``max_collision_checks`` within the limits are tested at
once by :class:`~oacli.planning.sample_filter.SampleFilter` (a sample that certainly collides rejects its
connection); only the others get the exact continuous check. A try after an accepted one in the same
batch was drawn on the old trajectory: it is dropped unrecorded and drawn again, so every recorded try saw the
trajectory as it was at that try, and ``tries`` tries are recorded.

The result never costs more than the input, and stays within the limits and collision-free if the input was.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import CollisionChecker
from oacli.planning.sample_filter import SampleFilter
from oacli.planning.steering import LIMIT_RTOL, LqrConnector
from oacli.planning.translational import TranslationalTrajectory

ACCEPTED = "accepted"
NOT_LOWER_COST = "not_lower_cost"
INPUT_LIMIT = "input_limit"
VELOCITY_LIMIT = "velocity_limit"
COLLISION = "collision"
REJECTIONS = (NOT_LOWER_COST, INPUT_LIMIT, VELOCITY_LIMIT, COLLISION)

_IMPROVE_RTOL = 1e-12
#: Horizons of one try batched together (in cost order) for their limit and sample checks.
_CHUNK = 8


@dataclass(frozen=True)
class ShortcutAttempt:
    """One shortcut try.

    Attributes
    ----------
    index : int
        Try number (0-based).
    a, b : int
        Sample indices of the end points in the trajectory as it was at this try.
    t_a, t_b : float
        Their times [s].
    steps : int
        Horizon [steps] of the best connection considered (0 when none was lower-cost).
    old_cost, new_cost : float
        Cost of the replaced section and of the connection (NaN when none was considered).
    outcome : str
        ``accepted`` or a rejection reason (:data:`REJECTIONS`).
    """

    index: int
    a: int
    b: int
    t_a: float
    t_b: float
    steps: int
    old_cost: float
    new_cost: float
    outcome: str


@dataclass(frozen=True)
class ShortcutResult:
    """Outcome of :func:`lqr_shortcut`.

    Attributes
    ----------
    trajectory : TranslationalTrajectory
        The smoothed trajectory.
    cost_before, cost_after : float
        Costs of the input and of the result.
    attempts : tuple of ShortcutAttempt
        Every try, in order.
    sections : tuple of (int, TranslationalTrajectory)
        Every accepted shortcut: its try number and the spliced-in section.
    """

    trajectory: TranslationalTrajectory
    cost_before: float
    cost_after: float
    attempts: tuple[ShortcutAttempt, ...]
    sections: tuple[tuple[int, TranslationalTrajectory], ...] = ()

    @property
    def tried(self) -> int:
        """Number of tries."""
        return len(self.attempts)

    @property
    def accepted(self) -> int:
        """Number of shortcuts spliced in."""
        return sum(a.outcome == ACCEPTED for a in self.attempts)

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected tries by reason (every reason listed, zeros included)."""
        return {r: sum(a.outcome == r for a in self.attempts) for r in REJECTIONS}


def _cumulative_costs(traj: TranslationalTrajectory, weights, goal: np.ndarray) -> np.ndarray:
    """``[0, J_0, J_0 + J_1, ...]``: the cost of samples ``a..b`` is ``cum[b] - cum[a]``."""
    return np.concatenate([[0.0], np.cumsum(traj.interval_costs(weights, goal))])


def splice(
    traj: TranslationalTrajectory, a: int, b: int, section: TranslationalTrajectory
) -> TranslationalTrajectory:
    """Replace samples ``a..b`` of ``traj`` by ``section`` (which must start at ``x[a]`` and end at ``x[b]``).

    Parameters
    ----------
    traj : TranslationalTrajectory
    a, b : int
        Sample indices, ``a < b``.
    section : TranslationalTrajectory
        The replacement.

    Returns
    -------
    TranslationalTrajectory
        Later samples are shifted in time by the change of duration.
    """
    shift = traj.t[a] - section.t[0]
    t_sec = section.t + shift
    delay = t_sec[-1] - traj.t[b]
    t = np.concatenate([traj.t[: a + 1], t_sec[1:], traj.t[b + 1 :] + delay])
    x = np.concatenate([traj.x[: a + 1], section.x[1:], traj.x[b + 1 :]])
    u = np.concatenate([traj.u[:a], section.u, traj.u[b:]])
    if np.all(np.diff(t) > 0):  # always, unless rounding of the shift merged two samples
        return TranslationalTrajectory.trusted(t, x, u, traj.model)
    return TranslationalTrajectory(t, x, u, traj.model)


def lqr_shortcut(
    traj: TranslationalTrajectory,
    connector: LqrConnector,
    checker: CollisionChecker,
    goal: np.ndarray,
    force_limit_N: np.ndarray,
    velocity_limit_mps: np.ndarray,
    rng: np.random.Generator,
    *,
    tries: int,
    sample_dt_s: float | None = None,
    max_collision_checks: int = 3,
    batch_size: int = 16,
) -> ShortcutResult:
    """Smooth ``traj`` by ``tries`` random LQR shortcuts (module docstring).

    Parameters
    ----------
    traj : TranslationalTrajectory
        Input trajectory (zero-order-hold samples).
    connector : LqrConnector
        Exact LQR connections (its step is the shortcut's force step; its weights define the cost).
    checker : CollisionChecker
        Continuous collision checks.
    goal : ndarray, shape (6,)
        The plan's goal ``x_g`` (enters the cost's state term).
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
        Per-axis limits.
    rng : numpy.random.Generator
        Source of the random sample pairs.
    tries : int
        Number of shortcut tries.
    sample_dt_s : float, optional
        Sample spliced sections every ``sample_dt_s`` (must divide the connector's step); default: its step.
    max_collision_checks : int
        Connections (in cost order) checked for collisions per try.
    batch_size : int
        Tries drawn at once against the current trajectory, their connection costs computed together (the
        tries after an accepted one in the same batch are dropped and drawn again: every try sees the trajectory
        as it is at that try).

    Returns
    -------
    ShortcutResult
    """
    weights = connector.weights
    goal = np.asarray(goal, dtype=float)
    cost_before = traj.cost(weights, goal)
    attempts: list[ShortcutAttempt] = []
    sections: list[tuple[int, TranslationalTrajectory]] = []
    cum = _cumulative_costs(traj, weights, goal)  # changes only when a section is spliced in
    tries = int(tries)
    batch = max(1, int(batch_size))
    f_lim = np.asarray(force_limit_N, dtype=float) * (1.0 + LIMIT_RTOL)
    v_lim = np.asarray(velocity_limit_mps, dtype=float) * (1.0 + LIMIT_RTOL)
    sample_filter = SampleFilter(checker)
    while len(attempts) < tries:
        n = len(traj)
        if n < 3:
            i = len(attempts)
            attempts.append(ShortcutAttempt(i, 0, n - 1, 0.0, traj.duration_s, 0, 0.0, np.nan, NOT_LOWER_COST))
            continue
        # A batch of tries drawn against the current trajectory; their connection costs in one vectorised call.
        # Tries are recorded in order; once one is spliced in, the rest of the batch (drawn on the old
        # trajectory) is dropped unrecorded and a new batch is drawn.
        k = min(batch, tries - len(attempts))
        a_all = rng.integers(0, n - 2, size=k)
        span = n - 1 - a_all  # log-uniform section length: as many local as global tries
        u = rng.uniform(size=k)
        length = np.exp(np.log(2.0) + u * (np.log(span + 1.0) - np.log(2.0))).astype(int)
        b_all = a_all + np.minimum(span, np.maximum(2, length))
        old_all = cum[b_all] - cum[a_all]
        cost_all = connector.costs(traj.x[a_all], traj.x[b_all], goal)
        lower_all = cost_all < (old_all - _IMPROVE_RTOL * np.maximum(1.0, np.abs(old_all)))[:, None]
        any_lower = lower_all.any(axis=1).tolist()
        a_list, b_list, old_list = a_all.tolist(), b_all.tolist(), old_all.tolist()
        t_a_list, t_b_list = traj.t[a_all].tolist(), traj.t[b_all].tolist()
        for j in range(k):
            i = len(attempts)
            a, b, old = a_list[j], b_list[j], old_list[j]
            if not any_lower[j]:
                attempts.append(ShortcutAttempt(i, a, b, t_a_list[j], t_b_list[j], 0, old, np.nan, NOT_LOWER_COST))
                continue
            base = dict(index=i, a=a, b=b, t_a=t_a_list[j], t_b=t_b_list[j], old_cost=old)
            costs = cost_all[j]
            x_a, x_b = traj.x[a], traj.x[b]
            candidates = np.flatnonzero(lower_all[j])  # only the cheaper horizons matter
            # The cheaper horizons in cost order; the first ``max_collision_checks`` within the limits are
            # collision-checked in that order, a sample that certainly collides rejecting one at once.
            outcome, steps, checked = "", -1, 0
            order = candidates[np.argsort(costs[candidates], kind="stable")]
            # The limits of the horizons in cost order from their batched forces and samples, in chunks (8, then
            # doubling: most of a long list is beyond the limits) until ``max_collision_checks`` are within them;
            # the samples of those are tested by the sample filter.
            pos, chunk, force_ok_any = 0, _CHUNK, False
            passing: list[np.ndarray] = []
            sampled: list[np.ndarray] = []
            found = 0
            while found < max_collision_checks and pos < order.size:
                part = order[pos:pos + chunk]
                pos += part.size
                chunk *= 2
                u_c, x_c = connector.batch(x_a, x_b, goal, part)
                f_pass = np.all(np.abs(u_c) <= f_lim, axis=(1, 2))
                force_ok_any |= bool(f_pass.any())
                ok = np.flatnonzero(f_pass & np.all(np.abs(x_c[:, :, 3:6]) <= v_lim, axis=(1, 2)))
                ok = ok[: max_collision_checks - found]
                if ok.size:
                    passing.append(part[ok])
                    sampled.append(x_c[ok])
                    found += ok.size
            if found:
                if len(passing) == 1:
                    horizons, states = passing[0], sampled[0]
                else:  # one sample-filter call: the parts' samples zero-padded to the longest (masked by steps)
                    horizons = np.concatenate(passing)
                    states = np.zeros((found, max(x.shape[1] for x in sampled), 6))
                    row = 0
                    for x in sampled:
                        states[row:row + x.shape[0], : x.shape[1]] = x
                        row += x.shape[0]
                rejected = sample_filter.connections_colliding(states, horizons).tolist()
                for n_steps, reject in zip(horizons.tolist(), rejected, strict=True):
                    if checked == 0:
                        outcome, steps = COLLISION, n_steps
                    checked += 1
                    if reject:
                        continue
                    section = connector.trajectory(x_a, x_b, goal, n_steps)
                    if checker.is_free(section.pieces()):
                        if sample_dt_s is not None:
                            section = section.refined(sample_dt_s)
                        traj = splice(traj, a, b, section)
                        # The cost is additive over intervals and time-invariant: only the section's are new.
                        sec_cum = cum[a] + np.cumsum(section.interval_costs(weights, goal))
                        cum = np.concatenate([cum[: a + 1], sec_cum, cum[b + 1 :] + (sec_cum[-1] - cum[b])])
                        sections.append((i, section))
                        outcome, steps = ACCEPTED, n_steps
                        break
            if checked == 0:  # no cheaper connection within the limits: name the limit
                best = int(candidates[np.argmin(costs[candidates])])
                reason = INPUT_LIMIT if not force_ok_any else VELOCITY_LIMIT
                attempts.append(ShortcutAttempt(**base, steps=best, new_cost=float(costs[best]), outcome=reason))  # type: ignore[arg-type]
                continue
            attempts.append(ShortcutAttempt(**base, steps=steps, new_cost=float(costs[steps]), outcome=outcome))  # type: ignore[arg-type]
            if outcome == ACCEPTED:
                break  # the rest of the batch was drawn on the old trajectory
    return ShortcutResult(traj, cost_before, traj.cost(weights, goal), tuple(attempts), tuple(sections))
