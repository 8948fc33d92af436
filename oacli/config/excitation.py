"""The ``excitation`` section: information-rich trajectory design ([Doerr2021] Eq. 30) and RATTLE.

Everything has a default except the start and the goal (needed by ``oacli excite`` only, checked there). Numbers
with a published source say so in their description; see ``configs/`` for commented presets.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BeforeValidator, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.environment import WaypointRef
from oacli.config.fields import (
    Fraction,
    PositiveReal,
    PositiveVector4,
    Real,
    Section,
    StrictBool,
    StrictInt,
    none_to,
    sequence_of,
)
from oacli.config.limits import LimitsOverride, ReferenceMarginConfig
from oacli.config.prior import PriorConfig

MAX_EXCITATION_STEPS = 2000
"""Largest accepted number of design steps."""

RATTLE_VELOCITY_STD = math.sqrt(5e-6)
"""rattle ``param_est/scripts/param_est_config.py``: R_6DOF velocity entries 0.5e-5, read as variances (the filter
adds R to H P Hᵀ, ``S = H P Hᵀ + R``), so the standard deviation is sqrt(5e-6) = 2.236e-3 m/s."""
RATTLE_ANGULAR_VELOCITY_STD = math.sqrt(2.5e-4)
"""rattle ``param_est``: R_6DOF angular velocity entries 0.25e-3 (variances) -> 1.581e-2 rad/s."""
RATTLE_ACCELERATION_STD = math.sqrt(5e-6)
"""rattle ``param_est``: R_6DOF linear acceleration entries 0.5e-5 (variances) -> 2.236e-3 m/s²."""

NonNegativeVector4 = Annotated[
    tuple[
        Annotated[Real, Field(ge=0)], Annotated[Real, Field(ge=0)], Annotated[Real, Field(ge=0)],
        Annotated[Real, Field(ge=0)],
    ],
    BeforeValidator(sequence_of(4)),
]


class MeasurementNoiseConfig(Section):
    """What the estimator measures, with per-axis noise standard deviations (``null`` = not measured).

    The defaults are RATTLE's sequential estimator (rattle ``param_est``): velocity, angular velocity and linear
    acceleration, with R = diag(5e-6 ×3, 2.5e-4 ×3, 5e-6 ×3) read as variances.
    """

    position_std_m: PositiveReal | None = Field(default=None, description="Position noise std [m].")
    velocity_std_mps: PositiveReal | None = Field(
        default=RATTLE_VELOCITY_STD, description="Velocity noise std [m/s] (rattle: sqrt(5e-6))."
    )
    attitude_std_rad: PositiveReal | None = Field(default=None, description="Attitude noise std [rad].")
    angular_velocity_std_radps: PositiveReal | None = Field(
        default=RATTLE_ANGULAR_VELOCITY_STD, description="Angular velocity noise std [rad/s] (rattle: sqrt(2.5e-4))."
    )
    linear_acceleration_std_mps2: PositiveReal | None = Field(
        default=RATTLE_ACCELERATION_STD, description="Linear acceleration noise std [m/s²] (rattle: sqrt(5e-6))."
    )
    angular_acceleration_std_radps2: PositiveReal | None = Field(
        default=None, description="Angular acceleration noise std [rad/s²]."
    )

    @model_validator(mode="after")
    def _something_measured(self) -> MeasurementNoiseConfig:
        if all(getattr(self, name) is None for name in type(self).model_fields):
            raise PydanticCustomError("oacli_measurement", "at least one quantity must be measured (all are null)")
        return self


class TerminalToleranceConfig(Section):
    """How close to the goal, at rest, the design must end (largest per-axis error)."""

    position_m: PositiveReal = Field(default=0.01, description="Position tolerance [m].")
    velocity_mps: PositiveReal = Field(default=1e-3, description="Velocity tolerance [m/s].")
    attitude_rad: PositiveReal = Field(default=0.01, description="Attitude tolerance [rad].")
    angular_velocity_radps: PositiveReal = Field(default=1e-3, description="Angular velocity tolerance [rad/s].")


class ScpConfig(Section):
    """Sequential convex programming of the offline design."""

    max_iterations: Annotated[StrictInt, Field(ge=1, le=1000)] = Field(
        default=60, description="Convex subproblems solved at most, 1..1000 (the ISS mission's design converges "
        "in 20-35; with the prior equal to the payload in 43-48: 40 stopped every such design short, 0.03 % above "
        "its optimum, 'degraded')."
    )
    trust_region_initial: PositiveReal = Field(
        default=0.5, description="Initial trust region, fraction of the input limits [-], > 0."
    )
    trust_region_min: PositiveReal = Field(default=1e-3, description="Stop below this trust region [-], > 0.")
    trust_region_max: PositiveReal = Field(default=2.0, description="Largest trust region [-], > 0.")
    penalty: PositiveReal = Field(
        default=10.0, description="Exact-penalty weight on the normalised constraint violation [-], > 0."
    )
    tolerance: PositiveReal = Field(
        default=1e-4, description="Stop when the predicted merit decrease, or the decrease a full step achieved, "
        "is below this (merit starts at 1)."
    )
    starts: Annotated[StrictInt, Field(ge=1, le=50)] = Field(
        default=1,
        description="Starts: the deterministic initial guess plus random ones (from the seed); the best after "
        "screening_iterations continues, 1..50.",
    )
    screening_iterations: Annotated[StrictInt, Field(ge=1, le=100)] = Field(
        default=5, description="Iterations each start gets before the best one is chosen, 1..100."
    )

    @model_validator(mode="after")
    def _ordered(self) -> ScpConfig:
        if not self.trust_region_min <= self.trust_region_initial <= self.trust_region_max:
            raise PydanticCustomError(
                "oacli_trust_region",
                "need trust_region_min <= trust_region_initial <= trust_region_max (got {a}, {b}, {c})",
                {"a": self.trust_region_min, "b": self.trust_region_initial, "c": self.trust_region_max},
            )
        return self


class RattleWeightsConfig(Section):
    """Planner tracking weights (rattle: state [10, 10, 10, 5, 5, 5, 1×6], input 1, terminal 100)."""

    position: PositiveReal = Field(default=10.0, description="Position error weight [1/m²].")
    velocity: PositiveReal = Field(default=5.0, description="Velocity weight [s²/m²].")
    attitude: PositiveReal = Field(default=1.0, description="Attitude error weight [1/rad²].")
    angular_velocity: PositiveReal = Field(default=1.0, description="Angular velocity weight [s²/rad²].")
    force: PositiveReal = Field(default=1.0, description="Force weight [1/N²].")
    torque: PositiveReal = Field(default=1.0, description="Torque weight [1/(N·m)²].")
    terminal: PositiveReal = Field(default=100.0, description="Final-error weight [-].")


class RattleConfig(Section):
    """The online information-aware planner in closed loop (RATTLE, [ReSWARM2023] §4.4, §4.6)."""

    horizon: Annotated[StrictInt, Field(ge=2, le=500)] = Field(
        default=40, description="Planning horizon N [steps] (rattle: 40)."
    )
    step_s: PositiveReal = Field(default=0.3, description="Planning step [s] (rattle: 0.3 s).")
    replan_period_s: PositiveReal = Field(default=12.0, description="Time between replans [s] (flown: 12 s).")
    duration_s: PositiveReal = Field(default=60.0, description="Closed-loop run time [s].")
    estimator: Literal["sequential", "oracle"] = Field(
        default="sequential",
        description="Estimator in the loop: 'sequential' (the error-state EKF of oacli.estimation, configured by "
        "the estimation section) or 'oracle' (Cramér-Rao covariance around the true parameters: an upper bound "
        "on what any estimator can deliver, for studies of the planner alone).",
    )
    iterations: Annotated[StrictInt, Field(ge=1, le=100)] = Field(
        default=3, description="SCP iterations per replan (ACADO RTI ran up to 5 SQP iterations)."
    )
    penalty: PositiveReal = Field(default=1000.0, description="Exact penalty on the normalised violation [-].")
    stop_speed_fraction: Fraction = Field(
        default=0.25,
        description="End-of-horizon speed bound as a fraction of the velocity limit; the last planned sample keeps "
        "the braking distance from walls and obstacles (recursive feasibility), in (0, 1].",
    )
    terminal_hold_s: Annotated[Real, Field(ge=0)] | None = Field(
        default=4.0,
        description="RATTLE's terminal phase (oacli.excitation.rattle_terminal): the last replan drops the "
        "information term and plans to the goal at rest, arriving this long [s] before the run ends (>= 0, below "
        "duration_s); null: every replan informs and the run may end away from the goal.",
    )
    goal_noise_sigmas: PositiveReal = Field(
        default=4.0,
        description="The run ends at the goal at rest when its true state is within excitation.terminal_tolerance "
        "plus this many σ of the closed loop's jitter under the sensor noise (Lyapunov equation of the LQR loop) [-].",
    )
    weights: Annotated[RattleWeightsConfig, none_to({})] = Field(
        default_factory=RattleWeightsConfig, description="Quadratic tracking weights of the planner."
    )
    gamma0: NonNegativeVector4 = Field(
        default=(50.0, 20.0, 20.0, 20.0), description="Initial information weights γ0 for [m, Ixx, Iyy, Izz]."
    )
    floor: PositiveVector4 = Field(
        default=(0.03, 1e-4, 1e-4, 1e-4), description="Desired precision per parameter [kg, kg·m²]."
    )
    alpha: PositiveReal = Field(default=2.2, description="Shut-off: γ_i = 0 once σ_i <= alpha · floor_i.")
    beta: PositiveReal = Field(default=5.0, description="Decay: γ_i = γ0_i exp(-beta floor_i / σ_i).")
    limits: Annotated[LimitsOverride, none_to({})] = Field(
        default_factory=LimitsOverride,
        description="Planner limits (rattle planner: 0.15 N, 0.015 N·m); omitted ones: excitation.limits, then robot; "
        "capped by excitation.margin like the offline design's.",
    )

    @model_validator(mode="after")
    def _hold_within_run(self) -> RattleConfig:
        if self.terminal_hold_s is not None and self.terminal_hold_s >= self.duration_s:
            raise PydanticCustomError(
                "oacli_terminal_hold", "terminal_hold_s ({h}) must be below duration_s ({d})",
                {"h": self.terminal_hold_s, "d": self.duration_s},
            )
        return self


ParameterGroup = Literal["mass", "inertia", "products", "com", "force_scale", "torque_scale"]


class InformationConfig(Section):
    """Which entries of the full rigid body's θ the excitation informs, and how the A-criterion is scaled.

    The default, mass and inertia, is the 4-parameter design of [Doerr2021] Eq. 30 and RATTLE's information term,
    unchanged. More groups (:mod:`oacli.excitation.information_full`): the offline SCP minimises their scaled
    A-criterion (:mod:`oacli.excitation.design_full`; ``criterion`` must be A, ``parameter_scaling`` is not used)
    and RATTLE's information term counts them (weights below, their σ from the sequential filter's full estimate,
    else their prior σ); the summary reports their Cramér-Rao bound along the trajectory. The γ0 and floors of the
    groups beyond mass and inertia have no published source: they are chosen like RATTLE's (γ0 = 20, floor of the
    order of a good estimate).
    """

    parameters: tuple[ParameterGroup, ...] = Field(
        default=("mass", "inertia"),
        description="Informed groups: mass, inertia, products, com, force_scale, torque_scale; must include mass and "
        "inertia (the default keeps the 4-parameter design).",
    )
    scaling: Literal["prior", "nominal", "absolute"] = Field(
        default="prior",
        description="A-criterion of the full θ on D F D: 'prior' D = prior σ (unit free: Σ CRB²/σ²), 'nominal' "
        "D = |θ| (prior σ where θ = 0), 'absolute' D = 1 (unit dependent).",
    )
    products_gamma0: Annotated[Real, Field(ge=0)] = Field(default=20.0, description="RATTLE γ0 of each product.")
    products_floor_kgm2: PositiveReal = Field(default=1e-4, description="RATTLE floor of each product [kg·m²].")
    com_gamma0: Annotated[Real, Field(ge=0)] = Field(default=20.0, description="RATTLE γ0 of each CoM component.")
    com_floor_m: PositiveReal = Field(default=5e-4, description="RATTLE floor of each CoM component [m].")
    scale_gamma0: Annotated[Real, Field(ge=0)] = Field(default=20.0, description="RATTLE γ0 of each scale factor.")
    scale_floor: PositiveReal = Field(default=2e-3, description="RATTLE floor of each scale factor [-].")

    @field_validator("parameters")
    @classmethod
    def _groups(cls, groups: tuple[str, ...]) -> tuple[str, ...]:
        if len(set(groups)) != len(groups):
            raise PydanticCustomError("oacli_information", "a group is listed twice")
        if "mass" not in groups or "inertia" not in groups:
            raise PydanticCustomError("oacli_information", "must include mass and inertia")
        return groups

    @property
    def is_legacy(self) -> bool:
        """Mass and inertia only: the 4-parameter design."""
        return set(self.parameters) == {"mass", "inertia"}


class ExcitationConfig(Section):
    """Information-rich excitation from ``start`` to ``goal`` ([Doerr2021] Eq. 30) and online RATTLE planning."""

    method: Literal["offline", "rattle"] = Field(
        default="offline", description="'offline': SCP design (Eq. 30); 'rattle': online planner in closed loop."
    )
    start: WaypointRef | None = Field(default=None, description="Start pose (waypoint name or inline), at rest.")
    goal: WaypointRef | None = Field(default=None, description="Goal pose (waypoint name or inline), at rest.")
    duration_s: PositiveReal = Field(default=60.0, description="Duration of the offline design [s].")
    steps: Annotated[StrictInt, Field(ge=2, le=MAX_EXCITATION_STEPS)] = Field(
        default=120,
        description=f"Design steps N (dt = duration/N; one measurement per step), 2..{MAX_EXCITATION_STEPS}.",
    )
    criterion: Literal["A", "D", "E"] = Field(
        default="A", description="A: tr F⁻¹ (Eq. 30), D: -log det F, E: -λ_min F."
    )
    parameter_scaling: Literal["absolute", "relative"] = Field(
        default="absolute", description="Criterion on θ as is (Eq. 30) or on θ relative to the prior."
    )
    use_prior_information: StrictBool = Field(
        default=False, description="Add the prior's information (inverse variance) to the design's FIM."
    )
    clearance_m: Annotated[Real, Field(ge=0)] = Field(
        default=0.0, description="Extra distance kept from keep-in faces and keep-out surfaces [m], >= 0."
    )
    limits: Annotated[LimitsOverride, none_to({})] = Field(
        default_factory=LimitsOverride,
        description="Caps of the design below the robot's (omitted ones: the robot's); each with the margin applied "
        "(see margin); a value above the robot's is refused or clipped (margin.on_excess).",
    )
    margin: Annotated[ReferenceMarginConfig, none_to({})] = Field(
        default_factory=ReferenceMarginConfig,
        description="Share of the robot's limits the design (offline and RATTLE) may use, with the mass margin of "
        "[Doerr2021] Eq. 28 (σ_m default: sqrt(excitation.prior.variance[0])).",
    )
    measurement: Annotated[MeasurementNoiseConfig, none_to({})] = Field(
        default_factory=MeasurementNoiseConfig, description="The FIM's measurement model."
    )
    terminal_tolerance: Annotated[TerminalToleranceConfig, none_to({})] = Field(
        default_factory=TerminalToleranceConfig, description="How close to the goal, at rest, the design must end."
    )
    scp: Annotated[ScpConfig, none_to({})] = Field(
        default_factory=ScpConfig, description="Sequential convex programming settings of the offline design."
    )
    prior: Annotated[PriorConfig, none_to({})] = Field(
        default_factory=PriorConfig, description="Prior estimate of θ (the design's model) and its variance."
    )
    rattle: Annotated[RattleConfig, none_to({})] = Field(
        default_factory=RattleConfig, description="Online information-aware planner (method 'rattle')."
    )
    information: Annotated[InformationConfig, none_to({})] = Field(
        default_factory=InformationConfig,
        description="Which entries of the full rigid body the excitation informs (default: mass and inertia).",
    )


__all__ = [
    "ExcitationConfig",
    "InformationConfig",
    "LimitsOverride",
    "MeasurementNoiseConfig",
    "PriorConfig",
    "RattleConfig",
    "RattleWeightsConfig",
    "ReferenceMarginConfig",
    "ScpConfig",
    "TerminalToleranceConfig",
]
