"""The robot model (``robot``) and the simulated plant (``truth``, with its ``disturbance``)."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import BeforeValidator, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.faults import InertiaTensor
from oacli.config.fields import (
    NonNegativeReal,
    NonNegativeVector3,
    NonNegativeVector4,
    PositiveReal,
    PrincipalInertia,
    Real,
    Section,
    Vector3,
    none_to,
    read_only,
    sequence_of,
)
from oacli.model.robot_model import RobotModel
from oacli.types import InertialParams

ActuatorScale = Annotated[Real, Field(ge=0.5, le=1.5)]

MAX_LIMIT = 1e6
"""Largest accepted force [N], torque [N·m], speed [m/s] or rate [rad/s] bound: beyond it the QP solvers read a bound
as infinite (Clarabel and OSQP at about 1e20; 1e6 is eight orders above Astrobee's)."""

_Limit = Annotated[Real, Field(gt=0, le=MAX_LIMIT)]
LimitVector3 = Annotated[tuple[_Limit, _Limit, _Limit], BeforeValidator(sequence_of(3))]


class RobotConfig(Section):
    """The robot model the planner, controller and tube use ([Doerr2021] Eqs. 33-36): θ, its variances, limits.

    The stage's one model block: :meth:`model` is the :class:`~oacli.model.robot_model.RobotModel` every core entry
    point takes (the tube's W and the planner's design limits derive their σ from its ``variance``).
    """

    mass_kg: PositiveReal = Field(description="Mass m [kg], > 0.")
    inertia_kgm2: PrincipalInertia = Field(
        description="Principal moments of inertia (Ixx, Iyy, Izz) [kg·m²] about the body axes through the CoM; "
        "each > 0 and each sum of two >= the third."
    )
    force_limit_N: LimitVector3 = Field(description="Force bound per world axis, |f_i| <= limit [N].")
    torque_limit_Nm: LimitVector3 = Field(description="Torque bound per body axis, |tau_i| <= limit [N·m].")
    velocity_limit_mps: LimitVector3 = Field(
        default=(0.2, 0.2, 0.2),
        description="Velocity bound per world axis [m/s] (default: Astrobee nominal flight mode).",
    )
    angular_velocity_limit_radps: LimitVector3 = Field(
        default=(0.1745, 0.1745, 0.1745),
        description="Angular velocity bound per body axis [rad/s] (default: Astrobee nominal flight mode).",
    )
    radius_m: NonNegativeReal = Field(default=0.25, description="Collision radius of the robot [m], >= 0.")
    variance: NonNegativeVector4 = Field(
        default=(0.0, 0.0, 0.0, 0.0),
        description="Variances of θ = [m, Ixx, Iyy, Izz] [kg², (kg·m²)² ×3], >= 0 (the diagonal of the model's "
        "covariance; 0: known exactly). The tube's W and the planner's design limits take σ_m = sqrt(variance[0]) "
        "([Doerr2021] Eq. 28); the mission writes each segment's model here (the prior's, then the estimate's).",
    )
    com_offset_m: Vector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="The model's centre of mass relative to the geometric centre the thrust acts on, body frame [m] "
        "(default 0; the mission writes segment 2's estimate here for segment 3). The controllers compensate its "
        "moment c × F (docs/control.md, \"The full rigid body\").",
    )
    com_variance_m2: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="Variances of com_offset_m per body axis [m²], >= 0 (W's attitude part takes their σ).",
    )
    inertia_products_kgm2: Vector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="The model's products of inertia [Ixy, Ixz, Iyz] [kg·m²] (default 0: principal axes); with "
        "inertia_kgm2 the tensor the attitude controllers use (positive definite).",
    )
    products_variance: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="Variances of inertia_products_kgm2 [(kg·m²)²], >= 0.",
    )

    def model(self) -> RobotModel:
        """This section as the :class:`~oacli.model.robot_model.RobotModel` (covariance ``diag(variance)``; centre
        of mass and products with σ = sqrt of their variances)."""
        return RobotModel(
            mass_kg=self.mass_kg, inertia_kgm2=np.asarray(self.inertia_kgm2),
            covariance=np.diag(np.asarray(self.variance, dtype=float)), force_limit_N=np.asarray(self.force_limit_N),
            torque_limit_Nm=np.asarray(self.torque_limit_Nm), velocity_limit_mps=np.asarray(self.velocity_limit_mps),
            angular_velocity_limit_radps=np.asarray(self.angular_velocity_limit_radps), radius_m=self.radius_m,
            com_offset_m=np.asarray(self.com_offset_m, dtype=float),
            com_std_m=np.sqrt(np.asarray(self.com_variance_m2, dtype=float)),
            inertia_products_kgm2=np.asarray(self.inertia_products_kgm2, dtype=float),
            products_std_kgm2=np.sqrt(np.asarray(self.products_variance, dtype=float)),
        )

    def inertial_params(self) -> InertialParams:
        """Mass and principal inertias as :class:`oacli.types.InertialParams`."""
        return InertialParams(self.mass_kg, self.inertia_kgm2)  # type: ignore[arg-type]

    @property
    def input_limits(self) -> np.ndarray:
        """Input bounds ``[force (3) N, torque (3) N·m]``, shape (6,), read-only; ``|u_i| <= input_limits[i]``."""
        return read_only(self.force_limit_N + self.torque_limit_Nm)


class DisturbanceConfig(Section):
    """Additive force/torque disturbance on the simulated plant: ``bias + uniform(-random, +random)`` per axis."""

    force_bias_N: Vector3 = Field(default=(0.0, 0.0, 0.0), description="Constant force, world frame [N].")
    force_random_N: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="Bound of the uniform random force per world axis [N], >= 0; redrawn each control period.",
    )
    torque_bias_Nm: Vector3 = Field(default=(0.0, 0.0, 0.0), description="Constant torque, body frame [N·m].")
    torque_random_Nm: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="Bound of the uniform random torque per body axis [N·m], >= 0; redrawn each control period.",
    )

    @property
    def bias(self) -> np.ndarray:
        """Constant part ``[force (3) N, torque (3) N·m]``, shape (6,), read-only."""
        return read_only(self.force_bias_N + self.torque_bias_Nm)

    @property
    def random_bound(self) -> np.ndarray:
        """Half-width of the uniform random part ``[force (3) N, torque (3) N·m]``, shape (6,), read-only."""
        return read_only(self.force_random_N + self.torque_random_Nm)

    @property
    def is_zero(self) -> bool:
        """True when the disturbance is identically zero."""
        return not (np.any(self.bias) or np.any(self.random_bound))


class TruthConfig(Section):
    """The simulated plant. Missing inertial values are filled from ``robot`` when the config is validated."""

    mass_kg: PositiveReal | None = Field(default=None, description="True mass [kg], > 0 (default: robot's).")
    inertia_kgm2: PrincipalInertia | None = Field(
        default=None, description="True principal inertias (Ixx, Iyy, Izz) [kg·m²] (default: robot's)."
    )
    disturbance: Annotated[DisturbanceConfig, none_to({})] = Field(
        default_factory=DisturbanceConfig, description="Additive disturbance acting on the plant."
    )
    actuator_scale: Annotated[tuple[ActuatorScale, ActuatorScale, ActuatorScale, ActuatorScale, ActuatorScale,
                                    ActuatorScale], BeforeValidator(sequence_of(6))] = Field(
        default=(1.0, 1.0, 1.0, 1.0, 1.0, 1.0),
        description="Per-axis factor between the applied and the delivered input [force x, y, z (body), torque "
                    "x, y, z (body)], in [0.5, 1.5]; 1 = perfect actuators. Unmodelled: controllers and estimators "
                    "see the commanded (saturated) input ([ReSWARM2023] §5.3: impeller thrust varies).",
    )
    inertia_tensor_kgm2: InertiaTensor | None = Field(
        default=None,
        description="Full inertia tensor with products of inertia [kg·m²] (3×3, symmetric positive definite, "
                    "principal moments satisfying the triangle inequality); its diagonal is inertia_kgm2 (filled "
                    "from it when that is unset). Unmodelled: controllers and estimators use principal inertias.")
    com_offset_m: Vector3 = Field(
        default=(0.0, 0.0, 0.0),
        description="Centre of mass relative to the geometric centre the thrust acts on, body frame [m], each "
                    "|value| <= 0.05. Unmodelled: the force then also torques the body by -r × F (astrobee "
                    "iss.config measured (0.0037, -0.0003, -0.0025) m).",
    )

    @field_validator("com_offset_m")
    @classmethod
    def _small_offset(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        if max(abs(v) for v in value) > 0.05:
            raise ValueError("each component must be within ±0.05 m (a centre of mass outside the 30 cm body "
                             "is not a small offset)")
        return value

    @model_validator(mode="after")
    def _tensor_diagonal(self) -> TruthConfig:
        if self.inertia_tensor_kgm2 is None:
            return self
        diag = tuple(float(self.inertia_tensor_kgm2[i][i]) for i in range(3))
        if self.inertia_kgm2 is None:
            object.__setattr__(self, "inertia_kgm2", diag)
        elif any(abs(a - b) > 1e-9 * max(abs(b), 1e-12) for a, b in zip(self.inertia_kgm2, diag, strict=True)):
            raise PydanticCustomError("oacli_inertia", "inertia_kgm2 {a} must equal the diagonal of "
                                      "inertia_tensor_kgm2 {b}",
                                      {"a": str(list(self.inertia_kgm2)), "b": str(list(diag))})
        return self

    def inertial_params(self) -> InertialParams:
        """True mass and principal inertias (only valid once filled, i.e. on a validated :class:`OacliConfig`)."""
        if self.mass_kg is None or self.inertia_kgm2 is None:
            raise ValueError("truth inertial parameters are not set; use OacliConfig.truth_params()")
        return InertialParams(self.mass_kg, self.inertia_kgm2)  # type: ignore[arg-type]


__all__ = [
    "DisturbanceConfig",
    "RobotConfig",
    "TruthConfig",
]
