"""The ``planner`` section: global planning (LQR-RRT*, kinodynamic RRT) and LQR shortcutting.

Every random choice of ``oacli plan`` and ``oacli smooth`` derives from the config's top-level ``seed`` (one
numpy generator per stage, seeded with ``[seed, stage]``), so the same config and seed give the same plan; only a
run that is cut by ``time_budget_s`` depends on the machine's speed.

Units: times s, lengths m, speeds m/s; the cost weights make the trajectory cost (see
:mod:`oacli.planning.translational`) ``J = ∫ [w_t + ½ fᵀRf + ½ (x - x_g)ᵀ Q (x - x_g)] dt`` dimensionless.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from oacli.config.fields import (
    Fraction,
    NonNegativeReal,
    NonNegativeVector3,
    PositiveReal,
    PositiveVector3,
    Real,
    Section,
    StrictBool,
    StrictInt,
    Weight3,
    none_to,
    raise_at,
)
from oacli.config.limits import LimitsOverride, ReferenceMarginConfig

PlannerType = Literal["lqr-rrt-star", "kino-rrt"]
"""Planner kinds: LQR-RRT* (Doerr et al. 2021) or kinodynamic RRT with motion primitives ([ReSWARM2023] §4.1.2)."""

#: Largest connection or shortcut horizon in planner steps (the LQR maps are precomputed for every horizon).
MAX_STEPS = 400

Probability = Annotated[Real, Field(ge=0, lt=1)]


def _broadcast3(value):
    """A single number is repeated on every axis (as for the controller weights)."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (value, value, value)
    return value


class PlannerWeights(Section):
    """Weights of the trajectory cost that every planner, the shortcutting and the summaries use."""

    position: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="q_r per axis [1/(m²·s)], >= 0: weight on the position error to the goal ([Doerr2021] Eq. 5); "
        "a single number is used on all three axes.",
    )
    velocity: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="q_v per axis [s/m²], >= 0: weight on the velocity error to the goal (at rest: on speed); "
        "a single number is used on all three axes.",
    )
    force: Weight3 = Field(default=(1.0, 1.0, 1.0), description="R per axis [1/(N²·s)], > 0 ([Doerr2021] Eq. 5).")
    time: PositiveReal = Field(default=0.1, description="w_t [1/s], > 0: the price of one second of flight.")

    @model_validator(mode="before")
    @classmethod
    def _broadcast(cls, data):
        if isinstance(data, dict):
            data = {k: _broadcast3(v) if k in ("position", "velocity") else v for k, v in data.items()}
        return data


class KinoRrtConfig(Section):
    """Kinodynamic RRT with motion primitives ([ReSWARM2023] §4.1.2-4.1.3, Eqs. 26-27)."""

    primitive_fraction: Fraction = Field(
        default=0.5, description="α of Eq. 27 [-], in (0, 1]: primitives apply ±α × the force limit per axis."
    )
    primitive_dt_s: PositiveReal = Field(
        default=2.0, description="Propagation time Δt of a primitive [s], > 0; a multiple of output_dt_s."
    )
    primitive_set: Literal["axes", "combinations"] = Field(
        default="axes",
        description="'axes': ±α F_i on one axis at a time plus zero, 7 actions (Eq. 27); 'combinations': every "
        "combination of {-α F_i, 0, +α F_i}, 27 actions.",
    )
    position_weight: PositiveReal = Field(default=1.0, description="w_r of the metric (Eq. 26) [1/m], > 0.")
    velocity_weight: PositiveReal = Field(default=5.0, description="w_v of the metric (Eq. 26) [s/m], > 0.")
    goal_bias: Probability = Field(default=0.1, description="Probability of sampling the goal [-], in [0, 1).")


class ShortcutConfig(Section):
    """LQR shortcutting ([Doerr2021] §"Trajectory Smoothing by LQR Shortcutting"; [ReSWARM2023] §4.3)."""

    tries: Annotated[StrictInt, Field(ge=0)] = Field(default=1000, description="Random shortcut tries [-], >= 0.")
    max_horizon_s: PositiveReal = Field(
        default=60.0, description="Longest shortcut connection [s], > 0 (a multiple of steer_dt_s)."
    )


class PolishConfig(Section):
    """Trajectory polish after LQR shortcutting: sequential convex programming that shortens the path
    (:mod:`oacli.planning.polish`)."""

    enabled: StrictBool = Field(default=True, description="Run the polish in oacli smooth after the shortcutting.")
    iterations: Annotated[StrictInt, Field(ge=1)] = Field(
        default=30, description="SCP subproblems (second-order cone programs) at most, >= 1."
    )
    step_s: PositiveReal = Field(
        default=0.5, description="Held-force step of the polish grid [s], > 0; a multiple of output_dt_s."
    )
    duration_factor: Annotated[Real, Field(ge=1)] | None = Field(
        default=None,
        description="Duration budget as a multiple of the minimum-time lower bound [-], >= 1: the polish may "
        "lengthen the trajectory up to max(input duration, factor × bound); default: keep the input's duration.",
    )
    effort_weight: NonNegativeReal = Field(
        default=0.01, description="Weight w_e of Σ h |f|² against the path length [m/(N²·s)], >= 0."
    )
    trust_radius_m: PositiveReal = Field(default=0.05, description="Initial trust radius on positions [m], > 0.")
    clearance_m: NonNegativeReal = Field(
        default=1e-4, description="Extra distance kept from every keep-out zone (robot included) [m], >= 0."
    )
    keep_cost: StrictBool = Field(
        default=True,
        description="Never return a trajectory whose LQR cost J exceeds the cost of the smooth stage's input "
        "(the polish minimises length, not J; the shortcutting alone never raises J).",
    )


class PlannerConfig(Section):
    """Global planning of a segment between two waypoints, and smoothing of the plan."""

    type: PlannerType = Field(default="lqr-rrt-star", description="'lqr-rrt-star' or 'kino-rrt'.")
    segment: str | None = Field(
        default=None,
        description="'A-B': plan from waypoint A to waypoint B (names from the top-level waypoints); default: "
        "the first two names of reference.waypoints.",
    )
    max_iterations: Annotated[StrictInt, Field(ge=1)] = Field(default=2000, description="Iteration budget, >= 1.")
    time_budget_s: PositiveReal = Field(default=30.0, description="Wall-time budget of the search [s], > 0.")
    anytime: StrictBool = Field(
        default=False,
        description="LQR-RRT*: false stops at the first solution (as flown in ReSWARM); true keeps improving "
        "until a budget is spent.",
    )
    goal_bias: Probability = Field(
        default=0.05, description="LQR-RRT*: probability of connecting the goal instead of sampling [-]."
    )
    goal_tolerance_m: PositiveReal = Field(
        default=0.5, description="Kino-RRT: distance to the goal from which the exact LQR goal link is tried [m]."
    )
    goal_tolerance_mps: PositiveReal = Field(
        default=0.1, description="Kino-RRT: speed below which the exact LQR goal link is tried [m/s]."
    )
    near_gamma: PositiveReal = Field(
        default=20.0, description="γ of the near radius γ (log n / n)^(1/6) ([Doerr2021] Eq. 11), in cost units, > 0."
    )
    max_near: Annotated[StrictInt, Field(ge=1)] = Field(default=30, description="Largest near set [-], >= 1.")
    steer_dt_s: PositiveReal = Field(default=0.5, description="Step of the held force in LQR connections [s].")
    steer_horizon_s: PositiveReal = Field(
        default=5.0, description="Horizon of the cost-to-go metric and longest steering connection [s]."
    )
    max_connection_s: PositiveReal = Field(
        default=15.0, description="Longest LQR connection in choose-parent, rewiring and goal links [s]."
    )
    output_dt_s: PositiveReal = Field(
        default=0.1, description="Sample step of the output trajectory [s]; steer_dt_s is a multiple of it."
    )
    robot_semi_axes_m: PositiveVector3 | None = Field(
        default=None,
        description="Semi-axes of the robot's bounding ellipsoid along its body axes [m] (default: a sphere of "
        "robot.radius_m). Oriented by the start attitude when the segment keeps the attitude, else replaced by "
        "the sphere of its largest semi-axis (the body turns along the path).",
    )
    weights: Annotated[PlannerWeights, none_to({})] = Field(
        default_factory=PlannerWeights, description="Cost weights ([Doerr2021] Eq. 5 plus a price on time)."
    )
    limits: Annotated[LimitsOverride, none_to({})] = Field(
        default_factory=LimitsOverride,
        description="Caps of plan and smooth below the robot's (omitted ones: the robot's), with the margin "
        "applied; a value above the robot's is refused or clipped (margin.on_excess).",
    )
    margin: Annotated[ReferenceMarginConfig, none_to({})] = Field(
        default_factory=ReferenceMarginConfig,
        description="Share of the robot's limits plan and smooth may use, with the mass margin of [Doerr2021] Eq. 28 "
        "(m_prior = robot.mass_kg, σ_m default: sqrt(estimation.prior.mass_variance_kg2)).",
    )
    kino: Annotated[KinoRrtConfig, none_to({})] = Field(
        default_factory=KinoRrtConfig, description="Kinodynamic RRT settings."
    )
    shortcut: Annotated[ShortcutConfig, none_to({})] = Field(
        default_factory=ShortcutConfig, description="LQR shortcutting settings (oacli smooth)."
    )
    polish: Annotated[PolishConfig, none_to({})] = Field(
        default_factory=PolishConfig, description="Path-length polish after the shortcutting (oacli smooth)."
    )

    @model_validator(mode="after")
    def _consistent_steps(self) -> PlannerConfig:
        problems: list[tuple[tuple[str | int, ...], Any, str]] = []

        def steps(value: float, unit: float) -> float:
            return value / unit

        def multiple(value: float, unit: float) -> bool:
            n = round(value / unit)
            return n >= 1 and abs(n * unit - value) <= 1e-9 * max(value, 1.0)

        if not multiple(self.steer_dt_s, self.output_dt_s):
            problems.append(
                (("steer_dt_s",), self.steer_dt_s, f"must be a multiple of output_dt_s ({self.output_dt_s:g} s)")
            )
        if not multiple(self.polish.step_s, self.output_dt_s):
            problems.append(
                (("polish", "step_s"), self.polish.step_s,
                 f"must be a multiple of output_dt_s ({self.output_dt_s:g} s)")
            )
        if not multiple(self.kino.primitive_dt_s, self.output_dt_s):
            problems.append(
                (("kino", "primitive_dt_s"), self.kino.primitive_dt_s,
                 f"must be a multiple of output_dt_s ({self.output_dt_s:g} s)")
            )
        for name, value in (("steer_horizon_s", self.steer_horizon_s), ("max_connection_s", self.max_connection_s)):
            if steps(value, self.steer_dt_s) < 2 - 1e-9:
                problems.append(((name,), value, f"must be >= 2 × steer_dt_s ({2 * self.steer_dt_s:g} s)"))
        if self.max_connection_s < self.steer_horizon_s:
            problems.append(
                (("max_connection_s",), self.max_connection_s,
                 f"must be >= steer_horizon_s ({self.steer_horizon_s:g} s)")
            )
        if steps(self.shortcut.max_horizon_s, self.steer_dt_s) < 2 - 1e-9:
            problems.append(
                (("shortcut", "max_horizon_s"), self.shortcut.max_horizon_s,
                 f"must be >= 2 × steer_dt_s ({2 * self.steer_dt_s:g} s)")
            )
        for loc, value in (
            (("max_connection_s",), self.max_connection_s),
            (("shortcut", "max_horizon_s"), self.shortcut.max_horizon_s),
        ):
            if steps(value, self.steer_dt_s) > MAX_STEPS:
                problems.append(
                    (loc, value, f"must be <= {MAX_STEPS} × steer_dt_s ({MAX_STEPS * self.steer_dt_s:g} s)")
                )
        if self.segment is not None and "-" not in self.segment:
            problems.append((("segment",), self.segment, "must look like 'A-B' (two waypoint names joined by '-')"))
        raise_at("PlannerConfig", problems)
        return self

    def steps(self, seconds: float) -> int:
        """``seconds`` in planner steps (rounded down, at least 2)."""
        return max(2, int(seconds / self.steer_dt_s + 1e-9))


__all__ = ["KinoRrtConfig", "PlannerConfig", "PlannerType", "PlannerWeights", "PolishConfig", "ShortcutConfig"]
