"""The planning problem in the translational state space and how to sample it.

The global planners plan the translational state ``x = [r, v]`` ([Doerr2021] Eq. 34) of the robot's centre, as Doerr
et al. and [ReSWARM2023] §4.1.3 do: attitude is interpolated afterwards (:mod:`oacli.planning.full_state`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from oacli.geometry.collision import CollisionChecker
from oacli.model.robot_model import RobotModel
from oacli.planning.translational import CostWeights


@dataclass(frozen=True)
class PlanningProblem:
    """Start, goal, limits, workspace and cost of one planning query.

    Attributes
    ----------
    start, goal : ndarray, shape (6,)
        ``[r (m), v (m/s)]``; the goal is usually at rest.
    model : RobotModel
        The robot model planned with (its mass, ``model.mass_kg``, is the double integrator's; the limits below
        are the planner's design limits, not necessarily the model's own).
    force_limit_N : ndarray, shape (3,)
        ``|f_i| <= F_i`` per world axis [N].
    velocity_limit_mps : ndarray, shape (3,)
        ``|v_i| <= V_i`` per world axis [m/s].
    checker : CollisionChecker
        Continuous collision checks of the robot body against the workspace.
    sample_lower, sample_upper : ndarray, shape (B, 3)
        Boxes positions are sampled from (the keep-in boxes), chosen with probability proportional to volume.
    weights : CostWeights
        The trajectory cost (:mod:`oacli.planning.translational`).
    """

    start: np.ndarray
    goal: np.ndarray
    model: RobotModel
    force_limit_N: np.ndarray
    velocity_limit_mps: np.ndarray
    checker: CollisionChecker
    sample_lower: np.ndarray
    sample_upper: np.ndarray
    weights: CostWeights
    #: Cumulative volume fractions of the sampling boxes (set in ``__post_init__``; picks a box by one draw).
    _box_cdf: np.ndarray = field(init=False, repr=False, compare=False)
    #: Per sampling box, the low corner and extent of the sampled state ``[r, v]`` (set in ``__post_init__``).
    _sample_low: np.ndarray = field(init=False, repr=False, compare=False)
    _sample_span: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name, shape in (("start", (6,)), ("goal", (6,)), ("force_limit_N", (3,)), ("velocity_limit_mps", (3,))):
            arr = np.array(getattr(self, name), dtype=float).reshape(shape)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        lo = np.array(self.sample_lower, dtype=float).reshape(-1, 3)
        hi = np.array(self.sample_upper, dtype=float).reshape(-1, 3)
        if lo.shape[0] == 0 or lo.shape != hi.shape or np.any(hi <= lo):
            raise ValueError("sampling needs at least one box with upper > lower on every axis")
        object.__setattr__(self, "sample_lower", lo)
        object.__setattr__(self, "sample_upper", hi)
        volumes = np.prod(hi - lo, axis=1)
        cdf = np.cumsum(volumes / volumes.sum())
        object.__setattr__(self, "_box_cdf", cdf / cdf[-1])
        v_lo = -np.asarray(self.velocity_limit_mps, dtype=float)
        v_span = np.asarray(self.velocity_limit_mps, dtype=float) - v_lo
        object.__setattr__(self, "_sample_low", np.hstack([lo, np.tile(v_lo, (lo.shape[0], 1))]))
        object.__setattr__(self, "_sample_span", np.hstack([hi - lo, np.tile(v_span, (lo.shape[0], 1))]))
        if np.any(self.force_limit_N <= 0) or np.any(self.velocity_limit_mps <= 0):
            raise ValueError("force and velocity limits must be > 0")

    def sample_state(self, rng: np.random.Generator) -> np.ndarray:
        """A state uniformly distributed over the sampling boxes × the velocity box (Doerr: random sampling).

        Parameters
        ----------
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (6,)
        """
        cdf = self._box_cdf
        # rng.choice(len(cdf), p=volumes / volumes.sum()) without its per-call checks: one uniform draw
        # looked up in the cumulative distribution, as Generator.choice does.
        b = 0 if cdf.shape[0] == 1 else int(cdf.searchsorted(rng.random(), side="right"))
        # rng.uniform(low, high) for the position box, then for the velocity box, is low + (high - low) U with
        # U = rng.random() drawn element by element: the same six numbers from one draw of six.
        low, span = self._sample_low[b], self._sample_span[b]
        return low + span * rng.random(6)

    def sample_free_state(self, rng: np.random.Generator, attempts: int = 100) -> np.ndarray | None:
        """A sampled state whose position is collision-free (None after ``attempts`` rejections).

        Parameters
        ----------
        rng : numpy.random.Generator
        attempts : int, optional
            Samples to try.

        Returns
        -------
        ndarray, shape (6,) or None
        """
        for _ in range(attempts):
            x = self.sample_state(rng)
            if self.checker.points_free(x[0:3]):
                return x
        return None
