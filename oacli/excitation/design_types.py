"""What the offline excitation design (:mod:`oacli.excitation.design`) takes and returns.

:class:`ExcitationProblem` states the design problem ([Doerr2021] Eq. 30: start and goal at rest, duration,
steps, the parameters it is designed for, the measurement model, limits, scene, criterion), :class:`ScpSettings`
the sequential convex programming settings, :class:`ScpIterate` one SCP iteration and :class:`ExcitationDesign`
the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from oacli.excitation.fim_gradient import Criterion, Scaling
from oacli.excitation.information import N_PARAMS, MeasurementModel
from oacli.excitation.information_full import FullScaling, entry_index, parameter_scale
from oacli.excitation.problem import TerminalTolerance
from oacli.geometry import Scene
from oacli.model.limits import MotionLimits
from oacli.types import Trajectory


@dataclass(frozen=True)
class FullDesignSpec:
    """The entries an offline design informs.

    Attributes
    ----------
    groups : tuple of str
        Groups of :data:`oacli.estimation.rigid_parameters.GROUPS`.
    theta : ndarray, shape (16,)
        θ the design is made for (:func:`oacli.excitation.information_full.ideal_theta`).
    prior_std : ndarray, shape (16,)
        Prior σ of every entry (scaling, and the prior information of the entries beyond mass and inertia).
    scaling : {"prior", "nominal", "absolute"}
    """

    groups: tuple[str, ...]
    theta: np.ndarray
    prior_std: np.ndarray
    scaling: FullScaling = "prior"

    @property
    def index(self) -> np.ndarray:
        """θ indices of the entries."""
        return entry_index(self.groups)

    @property
    def scale(self) -> np.ndarray:
        """``d`` of ``D = diag(d)`` (:func:`oacli.excitation.information_full.parameter_scale`)."""
        return parameter_scale(self.theta, self.prior_std, self.groups, self.scaling)


@dataclass(frozen=True)
class ExcitationProblem:
    """An offline excitation design problem.

    Attributes
    ----------
    start, goal : ndarray, shape (13,)
        Start and goal states (at rest: zero velocity and angular velocity).
    duration_s : float
        Duration T [s].
    steps : int
        Number of steps N (``dt = T/N``); one measurement per step.
    theta : ndarray, shape (4,)
        Parameters the design is made for [m kg, Ixx, Iyy, Izz kg·m²] (the prior estimate).
    measurement : MeasurementModel
        Measured quantities and noise (the FIM's R).
    limits : MotionLimits
    scene : Scene
        Keep-in boxes and keep-out ellipsoids (safety factor applied).
    criterion : {"A", "D", "E"}
    scaling : {"absolute", "relative"}
        Criterion on θ as is (Eq. 30) or on θ relative to the design value.
    prior_information : ndarray, shape (4, 4), optional
        Information added to the measurements' (inverse prior covariance); none by default (Eq. 30).
    clearance_m : float
        Extra distance kept from keep-in faces and keep-out surfaces [m].
    terminal : TerminalTolerance
    information : FullDesignSpec, optional
        Design for these entries of the full θ (:mod:`oacli.excitation.design_full`; A-criterion only) instead of
        [m, Ixx, Iyy, Izz].
    """

    start: np.ndarray
    goal: np.ndarray
    duration_s: float
    steps: int
    theta: np.ndarray
    measurement: MeasurementModel
    limits: MotionLimits
    scene: Scene = field(default_factory=Scene)
    criterion: Criterion = "A"
    scaling: Scaling = "absolute"
    prior_information: np.ndarray | None = None
    clearance_m: float = 0.0
    terminal: TerminalTolerance = field(default_factory=TerminalTolerance)
    information: FullDesignSpec | None = None

    def __post_init__(self) -> None:
        for name in ("start", "goal"):
            value = np.array(getattr(self, name), dtype=float).reshape(13)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        theta = np.array(self.theta, dtype=float).reshape(N_PARAMS)
        theta.setflags(write=False)
        object.__setattr__(self, "theta", theta)
        if self.steps < 2 or self.duration_s <= 0:
            raise ValueError("need at least 2 steps and a positive duration")
        if self.criterion not in ("A", "D", "E"):
            raise ValueError(f"unknown criterion {self.criterion!r}")

    @property
    def dt(self) -> float:
        """Step [s]."""
        return self.duration_s / self.steps

    @property
    def prior(self) -> np.ndarray:
        """Prior information (4, 4) (zeros when none)."""
        if self.prior_information is None:
            return np.zeros((N_PARAMS, N_PARAMS))
        return np.asarray(self.prior_information, dtype=float)


@dataclass(frozen=True)
class ScpSettings:
    """Sequential convex programming settings.

    Attributes
    ----------
    max_iterations : int
        Subproblems solved at most.
    trust_region_initial, trust_region_min, trust_region_max : float
        Trust region Δ as a fraction of the per-axis input limit.
    penalty : float
        Exact-penalty weight μ on the normalised constraint violation.
    accept_ratio, good_ratio : float
        A step is accepted when actual/predicted merit decrease ≥ accept_ratio; Δ grows above good_ratio.
    shrink, grow : float
        Trust-region factors.
    tolerance : float
        Stop when the predicted merit decrease is below this (the merit starts at 1).
    starts : int
        Number of starts (the deterministic initial guess plus random ones); each runs ``screening_iterations``
        and the best continues up to ``max_iterations``.
    screening_iterations : int
        Iterations every start gets before the best is chosen.
    split_steps : bool
        When a step fails the merit test, try its force part alone (translation and rotation are decoupled, see
        :mod:`oacli.excitation.design`); fast path only. Fewer subproblems (13 instead of 40 on the ISS mission's
        segment 2), at a final criterion that may differ within the tolerance.
    """

    max_iterations: int = 30
    trust_region_initial: float = 0.5
    trust_region_min: float = 1e-3
    trust_region_max: float = 2.0
    penalty: float = 10.0
    accept_ratio: float = 0.1
    good_ratio: float = 0.75
    shrink: float = 0.5
    grow: float = 2.0
    tolerance: float = 1e-4
    starts: int = 1
    screening_iterations: int = 5
    split_steps: bool = True


@dataclass(frozen=True)
class ScpIterate:
    """One SCP iteration: the candidate step and what became of it.

    ``criterion`` and ``merit`` are those of the accepted iterate *after* the iteration (the current design);
    ``candidate_*`` those of the trial point; ``predicted_merit`` the subproblem's model value there.
    """

    iteration: int
    criterion: float
    merit: float
    violation: float
    candidate_criterion: float
    candidate_merit: float
    predicted_merit: float
    ratio: float
    trust_region_force: float
    trust_region_torque: float
    accepted: bool
    status: str
    solve_time_s: float


@dataclass(frozen=True)
class ExcitationDesign:
    """Result of :func:`design_excitation`.

    Attributes
    ----------
    trajectory : Trajectory
        N+1 samples every dt; ``u[k]`` held from ``t[k]`` to ``t[k+1]``, ``u[N] = 0``.
    fim : ndarray, shape (4, 4)
        Fisher information of the design (measurements only, no prior).
    criterion_initial, criterion_final : float
        Criterion (of F plus the prior information) of the initial guess and of the design.
    iterations : tuple of ScpIterate
    solve_time_s : float
        Wall time of the whole design [s].
    stop_reason : str
    terminal_residual : dict
        ``position_m``, ``velocity_mps``, ``attitude_rad``, ``angular_velocity_radps``: largest per-axis error at
        the end.
    violations : dict
        Normalised constraint violations of the design (0 when every constraint holds).
    collision_free : bool
        Dense re-check of the continuous motion against the scene.
    crb_std : ndarray, shape (4,)
        Cramér-Rao bound ``sqrt(diag F⁻¹)`` (measurements only).
    information_over_time : ndarray, shape (N+1, 4, 4)
        Cumulative Fisher information of the measurements up to each sample.
    initial : Trajectory
        The initial guess.
    """

    trajectory: Trajectory
    fim: np.ndarray
    criterion_initial: float
    criterion_final: float
    iterations: tuple[ScpIterate, ...]
    solve_time_s: float
    stop_reason: str
    terminal_residual: dict[str, float]
    violations: dict[str, float]
    collision_free: bool
    crb_std: np.ndarray
    information_over_time: np.ndarray
    initial: Trajectory

    @property
    def accepted_iterations(self) -> int:
        """Number of accepted steps."""
        return sum(it.accepted for it in self.iterations)


__all__ = ["ExcitationDesign", "ExcitationProblem", "FullDesignSpec", "ScpIterate", "ScpSettings"]
