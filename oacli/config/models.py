"""Strict, frozen pydantic models of an oacli configuration file.

Every section is a frozen pydantic v2 model that forbids unknown keys. Numbers are stored as Python floats and
vectors as tuples of floats, so a model is immutable and dumps to plain YAML. All lengths are in metres, times in
seconds, forces in newtons and torques in newton-metres; quaternions are ``[x, y, z, w]`` (scalar last, Doerr et
al. 2021, Eq. 33) and rotate body vectors into the world frame.

Validation rejects non-physical values with a reason per field: non-finite numbers, wrong vector lengths,
non-positive masses and limits, principal inertias that violate the triangle inequalities, shape matrices that are
not symmetric positive definite, quaternions whose norm is not 1 (within ``QUATERNION_NORM_TOLERANCE`` they are
normalised silently), and cross-field inconsistencies (unknown waypoint names, a cruise speed above the velocity
limit, a file reference without a file).

This module holds the whole file (:class:`OacliConfig`, with the cross-field checks) and re-exports the sections;
each section lives in its own module (:mod:`oacli.config.robot`, ``environment``, ``simulation``, ``controller``,
``tube``, ``reference``, ``planner``, ``excitation``, ``estimation``, ``limits``), all built on the field types
and the :class:`~oacli.config.fields.Section` base of :mod:`oacli.config.fields`. Adding a section means adding a
module with a ``Section`` subclass and a field on :class:`OacliConfig`; adding a controller type means widening
:data:`~oacli.config.controller.ControllerType` (or turning ``controller`` into a discriminated union on ``type``).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError
from pydantic_core.core_schema import ErrorType

from oacli.config.controller import MAX_HORIZON, ControllerConfig, ControllerType, ControllerWeights
from oacli.config.environment import EnvironmentConfig, KeepInBox, KeepOutEllipsoid, Pose
from oacli.config.estimation import EstimationConfig
from oacli.config.excitation import ExcitationConfig
from oacli.config.faults import FaultsConfig
from oacli.config.fields import (
    IDENTITY_QUATERNION,
    INERTIA_TRIANGLE_RTOL,
    NAME_PATTERN,
    QUATERNION_NORM_TOLERANCE,
    Name,
    Section,
    StrictInt,
    none_to,
    raise_at,
)
from oacli.config.inputs import InputsConfig
from oacli.config.mission import SEGMENT_NAMES, MissionConfig, deep_merge
from oacli.config.outputs import OutputsConfig
from oacli.config.planner import PlannerConfig
from oacli.config.reference import ReferenceConfig
from oacli.config.robot import DisturbanceConfig, RobotConfig, TruthConfig
from oacli.config.simulation import SensorsConfig, SimulationConfig
from oacli.config.sizes import size_problems
from oacli.config.tube import tube_problems
from oacli.geometry import Scene
from oacli.types import InertialParams

_CORE_ERROR_TYPES = frozenset(ErrorType.__args__)  # type: ignore[attr-defined]


class OacliConfig(Section):
    """A complete, validated oacli configuration. Only ``robot`` is required; everything else has defaults."""

    name: Name = Field(default="oacli", description="Run name prefix, [A-Za-z0-9_.-]+.")
    seed: Annotated[StrictInt, Field(ge=0)] = Field(
        default=0, description="Seed every random choice derives from, >= 0."
    )
    robot: RobotConfig = Field(description="The model used by planner, controller and estimator.")
    truth: Annotated[TruthConfig, none_to({})] = Field(
        default_factory=TruthConfig, description="The simulated plant (defaults to the robot model)."
    )
    environment: Annotated[EnvironmentConfig, none_to({})] = Field(
        default_factory=EnvironmentConfig, description="Keep-in boxes and keep-out ellipsoids."
    )
    waypoints: Annotated[dict[Name, Pose], none_to({})] = Field(
        default_factory=dict, description="Named poses, referred to by name elsewhere."
    )
    sensors: Annotated[SensorsConfig, none_to({})] = Field(
        default_factory=SensorsConfig, description="Measurement noise."
    )
    simulation: Annotated[SimulationConfig, none_to({})] = Field(
        default_factory=SimulationConfig, description="Closed-loop simulation settings."
    )
    faults: Annotated[FaultsConfig, none_to({})] = Field(
        default_factory=FaultsConfig, description="Actuator saturation and controller stall faults (off by default)."
    )
    controller: Annotated[ControllerConfig, none_to({})] = Field(
        default_factory=ControllerConfig, description="Tracking controller settings."
    )
    reference: Annotated[ReferenceConfig, none_to({})] = Field(
        default_factory=ReferenceConfig, description="Reference trajectory settings."
    )
    excitation: Annotated[ExcitationConfig, none_to({})] = Field(
        default_factory=ExcitationConfig, description="Excitation design and online information-aware planning."
    )
    planner: Annotated[PlannerConfig, none_to({})] = Field(
        default_factory=PlannerConfig, description="Global planning (oacli plan) and smoothing (oacli smooth)."
    )
    estimation: Annotated[EstimationConfig, none_to({})] = Field(
        default_factory=EstimationConfig, description="Inertial parameter estimation (oacli estimate)."
    )
    inputs: Annotated[InputsConfig, none_to({})] = Field(
        default_factory=InputsConfig, description="Files smooth and estimate read (recorded by the commands)."
    )
    outputs: Annotated[OutputsConfig, none_to({})] = Field(
        default_factory=OutputsConfig, description="Optional outputs: the PNG figures."
    )
    mission: MissionConfig | None = Field(
        default=None, description="The three-segment assembly mission (oacli mission); other commands ignore it."
    )

    @model_validator(mode="after")
    def _resolve_and_cross_check(self) -> OacliConfig:
        # Fill the plant from the robot model so the resolved config states what was simulated.
        if self.truth.mass_kg is None or self.truth.inertia_kgm2 is None:
            filled = self.truth.model_copy(
                update={
                    "mass_kg": self.truth.mass_kg if self.truth.mass_kg is not None else self.robot.mass_kg,
                    "inertia_kgm2": self.truth.inertia_kgm2
                    if self.truth.inertia_kgm2 is not None
                    else self.robot.inertia_kgm2,
                }
            )
            object.__setattr__(self, "truth", filled)

        problems: list[tuple[tuple[str | int, ...], Any, str]] = []
        ref = self.reference
        defined = ", ".join(sorted(self.waypoints)) or "none"
        for i, item in enumerate(ref.waypoints):
            if isinstance(item, str) and item not in self.waypoints:
                problems.append(
                    (("reference", "waypoints", i), item, f"unknown waypoint name (defined in waypoints: {defined})")
                )
        if self.mission is not None:
            for i, name in enumerate(self.mission.route):
                if name not in self.waypoints:
                    problems.append((("mission", "route", i), name,
                                     f"unknown waypoint name (defined in waypoints: {defined})"))
        if ref.source == "file" and ref.file is None:
            problems.append((("reference", "file"), None, "required when reference.source is 'file'"))
        vmin = min(self.robot.velocity_limit_mps)
        if ref.source == "waypoints" and ref.cruise_speed_mps > vmin:
            problems.append(
                (
                    ("reference", "cruise_speed_mps"),
                    ref.cruise_speed_mps,
                    f"must be <= the smallest robot.velocity_limit_mps ({vmin:g} m/s)",
                )
            )
        if ref.source == "waypoints":
            wmin = min(self.robot.angular_velocity_limit_radps)
            if ref.angular_rate_radps > wmin:
                problems.append(
                    (
                        ("reference", "angular_rate_radps"),
                        ref.angular_rate_radps,
                        f"must be <= the smallest robot.angular_velocity_limit_radps ({wmin:g} rad/s)",
                    )
                )
            fmin = min(self.robot.force_limit_N)
            if ref.acceleration_mps2 * self.robot.mass_kg > fmin:
                problems.append(
                    (
                        ("reference", "acceleration_mps2"),
                        ref.acceleration_mps2,
                        f"needs robot.mass_kg × acceleration = {ref.acceleration_mps2 * self.robot.mass_kg:.4g} N, "
                        f"more than the smallest robot.force_limit_N ({fmin:g} N)",
                    )
                )
            tmin = min(self.robot.torque_limit_Nm)
            imax = max(self.robot.inertia_kgm2)
            if ref.angular_acceleration_radps2 * imax > tmin:
                problems.append(
                    (
                        ("reference", "angular_acceleration_radps2"),
                        ref.angular_acceleration_radps2,
                        f"needs the largest robot.inertia_kgm2 × angular acceleration = "
                        f"{ref.angular_acceleration_radps2 * imax:.4g} N·m, more than the smallest "
                        f"robot.torque_limit_Nm ({tmin:g} N·m)",
                    )
                )
        if self.controller.type == "tube":
            problems += tube_problems(
                self.controller.tube,
                period_s=self.controller.period_s,
                model=self.robot.model(),
                sensor_std=(self.sensors.position_std_m, self.sensors.velocity_std_mps),
            )
        if self.controller.rate_hz > self.simulation.plant_rate_hz:
            problems.append(
                (
                    ("controller", "rate_hz"),
                    self.controller.rate_hz,
                    f"must be <= simulation.plant_rate_hz ({self.simulation.plant_rate_hz:g} Hz)",
                )
            )
        if not problems:
            problems += size_problems(self)  # steps = duration × rate, against a cap (oacli.config.sizes)
        raise_at("OacliConfig", problems)
        self._check_segment_overrides()
        return self

    def _check_segment_overrides(self) -> None:
        """Validate each ``mission.segments`` override merged into the file's sections, at the override's path."""
        if self.mission is None or not self.mission.segments:
            return
        base = self.model_dump(mode="json", exclude={"mission"})
        details: list[InitErrorDetails] = []
        for segment, overrides in self.mission.segments.items():
            loc0 = ("mission", "segments", segment)
            if segment.split("/", 1)[0] not in SEGMENT_NAMES:  # a segment, or one stage of it (segment-3/track)
                details.append(InitErrorDetails(type=PydanticCustomError(
                    "oacli_segment", "unknown segment (allowed: " + ", ".join(SEGMENT_NAMES) + ", or one of their "
                    "stages, e.g. segment-3/baseline-mpc-prior)"), loc=loc0, input=overrides))
                continue
            if overrides is None:
                continue
            if not isinstance(overrides, dict):
                details.append(InitErrorDetails(type=PydanticCustomError(
                    "oacli_segment", "must be a mapping of config sections"), loc=loc0, input=overrides))
                continue
            try:
                OacliConfig.model_validate(deep_merge(base, overrides))
            except ValidationError as exc:
                for err in exc.errors():
                    loc = ("mission", "segments", segment, *err["loc"])
                    if err["type"] in _CORE_ERROR_TYPES:
                        details.append(InitErrorDetails(type=err["type"], loc=loc, input=err["input"],
                                                        ctx=err.get("ctx", {})))
                    else:
                        details.append(InitErrorDetails(type=PydanticCustomError(err["type"], err["msg"]), loc=loc,
                                                        input=err["input"]))
        if details:
            raise ValidationError.from_exception_data("OacliConfig", details)

    def truth_params(self) -> InertialParams:
        """Inertial parameters of the simulated plant (the robot's unless ``truth`` overrides them)."""
        return self.truth.inertial_params()

    def robot_params(self) -> InertialParams:
        """Inertial parameters of the robot model (same as ``robot.inertial_params()``)."""
        return self.robot.inertial_params()

    def scene(self) -> Scene:
        """The workspace with the safety factor applied (same as ``environment.scene()``)."""
        return self.environment.scene()

    def waypoint(self, name: str) -> Pose:
        """The named waypoint; ``KeyError`` if it is not defined."""
        return self.waypoints[name]

    def reference_poses(self) -> tuple[Pose, ...]:
        """``reference.waypoints`` with names resolved to poses, in order."""
        return tuple(self.waypoints[w] if isinstance(w, str) else w for w in self.reference.waypoints)


__all__ = [
    "IDENTITY_QUATERNION",
    "INERTIA_TRIANGLE_RTOL",
    "MAX_HORIZON",
    "NAME_PATTERN",
    "QUATERNION_NORM_TOLERANCE",
    "ControllerConfig",
    "ControllerType",
    "ControllerWeights",
    "DisturbanceConfig",
    "EnvironmentConfig",
    "KeepInBox",
    "KeepOutEllipsoid",
    "OacliConfig",
    "Pose",
    "ReferenceConfig",
    "RobotConfig",
    "Section",
    "SensorsConfig",
    "SimulationConfig",
    "TruthConfig",
]
