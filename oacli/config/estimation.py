"""The ``estimation`` section: inertial parameter estimation from a tracking run (``oacli estimate``).

Sources of the defaults: RATTLE's sequential estimator (``param_est/scripts/param_est_config.py`` in
[RattleCode] albee/rattle-iros-2022, "rattle" below) and the ReSWARM flight paper ([ReSWARM2023]). In rattle the
prior ``P`` and the measurement noise ``R`` are **covariances**: ``P = diag(vec_cov)`` and ``R = diag(vec_R)``
enter the EKF as ``S = H P Hᵀ + R``, so their diagonals are variances. Here variances are given as variances and
noise as standard deviations (``std = sqrt(variance)``).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import (
    NonNegativeVector4,
    PositiveReal,
    PositiveVector3,
    Real,
    Section,
    StrictInt,
    Vector3,
    none_to,
)
from oacli.config.prior import RATTLE_PRIOR_THETA, RATTLE_PRIOR_VARIANCE, PriorConfig

EstimationMethod = Literal["batch", "sequential", "rls"]
ParameterGroup = Literal["mass", "inertia", "products", "com", "force_scale", "torque_scale"]


class RigidBodyPriorConfig(Section):
    """Prior (and, for a group not estimated, the fixed value) of the full rigid body's other parameters.

    The groups of ``estimation.parameters`` beyond mass and inertia (:mod:`oacli.estimation.rigid_parameters`):
    products of inertia, centre-of-mass offset, per-body-axis force and torque scale ([ReSWARM2023] Eqs. 38-39).
    """

    products_kgm2: Vector3 = Field(
        default=(0.0, 0.0, 0.0), description="Inertia tensor entries Jxy, Jxz, Jyz [kg·m²] (prior mean).")
    products_std_kgm2: PositiveReal = Field(
        default=0.005, description="Prior standard deviation of each inertia tensor entry off the diagonal [kg·m²].")
    com_m: Vector3 = Field(
        default=(0.0, 0.0, 0.0), description="Centre of mass relative to the geometric centre, body frame [m] "
        "(prior mean; astrobee iss.config measured (0.0037, -0.0003, -0.0025) m).")
    com_std_m: PositiveReal = Field(default=0.01, description="Prior standard deviation of each CoM component [m].")
    force_scale: PositiveVector3 = Field(
        default=(1.0, 1.0, 1.0), description="Delivered ÷ commanded force per body axis (prior mean).")
    force_scale_std: PositiveReal | PositiveVector3 = Field(
        default=0.05, description="Prior standard deviation of each force scale, one for all axes or per body axis "
        "(few-percent thrust errors, [ReSWARM2023] §6.2.1; the mission's segment-1/calibrate sets it per axis).")
    torque_scale: PositiveVector3 = Field(
        default=(1.0, 1.0, 1.0), description="Delivered ÷ commanded torque per body axis (prior mean).")
    torque_scale_std: PositiveReal | PositiveVector3 = Field(
        default=0.05, description="Prior standard deviation of each torque scale, one for all axes or per body axis.")

    def mean(self) -> np.ndarray:
        """[products (3), CoM (3), force scale (3), torque scale (3)]."""
        return np.r_[self.products_kgm2, self.com_m, self.force_scale, self.torque_scale].astype(float)

    def std(self) -> np.ndarray:
        """Standard deviations in the order of :meth:`mean`."""
        return np.concatenate([np.broadcast_to(np.asarray(v, dtype=float), (3,)) for v in (
            self.products_std_kgm2, self.com_std_m, self.force_scale_std, self.torque_scale_std)])


class MeasurementNoiseConfig(Section):
    """Standard deviations of the measurements the estimators use; ``null`` leaves a quantity out."""

    position_std_m: PositiveReal | None = Field(
        default=0.01, description="Position noise std per axis [m] (ISS localisation, [ReSWARM2023] §5.4.2)."
    )
    velocity_std_mps: PositiveReal | None = Field(
        default=math.sqrt(5e-6), description="Velocity noise std per axis [m/s] (rattle R: variance 5e-6)."
    )
    attitude_std_rad: PositiveReal | None = Field(
        default=0.005, description="Attitude noise std per axis, body-frame rotation vector [rad]."
    )
    angular_velocity_std_radps: PositiveReal | None = Field(
        default=math.sqrt(2.5e-4), description="Angular velocity noise std per axis [rad/s] (rattle R: 2.5e-4)."
    )
    linear_acceleration_std_mps2: PositiveReal | None = Field(
        default=None,
        description="Linear acceleration noise std per axis [m/s²] (rattle R: variance 5e-6, i.e. 0.00224); "
        "used only when the telemetry records accelerations.",
    )


class ProcessNoiseConfig(Section):
    """Unmodelled wrench in the process model (white noise; see ``oacli.estimation.models.ProcessNoise``)."""

    force_std_N: PositiveReal = Field(
        default=1e-5,
        description="Std of an unmodelled force held over one control period [N], > 0; set it to the plant's "
        "disturbance level (small: the model is trusted).",
    )
    torque_std_Nm: PositiveReal = Field(
        default=1e-6, description="Std of an unmodelled torque held over one control period [N·m], > 0."
    )


class RlsConfig(Section):
    """The flight's recursive least squares on accelerations ([ReSWARM2023] §4.4.1, §6.2.1; method ``rls``)."""

    force_scale: PositiveVector3 = Field(
        default=(1.0, 1.0, 1.0),
        description="Per-body-axis force scale κ [-] calibrated on a run of the known robot ([ReSWARM2023] Eqs. "
        "38-39; `oacli estimate --calibrate-force-scale MASS_KG` fits it); the estimator uses κ ⊙ F.",
    )
    calibration_mass_kg: PositiveReal | None = Field(
        default=None,
        description="Fit κ on the estimated telemetry itself first, with this known mass [kg], as the flight did "
        "([ReSWARM2023] §6.2.1); null uses force_scale. Circular when the same run's mass is estimated: the mass "
        "estimate then reflects the calibration mass.",
    )
    process_variance: NonNegativeVector4 = Field(
        default=(0.0, 0.0, 0.0, 0.0),
        description="Random-walk variance added to P per sample [kg², (kg·m²)² ×3] (RATTLE's Q; 0: constant θ).",
    )
    full_body: bool = Field(
        default=False,
        description="Estimate the groups of estimation.parameters (mass, inertia, products, com; the scales are "
        "calibrated, not estimated) with the full rigid body's RLS (oacli.estimation.rls_full); false: [m, I] only "
        "(process_variance applies to this one only).",
    )


class EstimationConfig(Section):
    """Inertial parameter estimation ([Doerr2021] Eqs. 31-32; [ReSWARM2023] §4.4.1, §6.2.1)."""

    method: EstimationMethod = Field(
        default="batch", description="'batch' (maximum likelihood over the whole run), 'sequential' (EKF) or "
        "'rls' (the flight's recursive least squares on accelerations, [ReSWARM2023] §4.4.1).",
    )
    rls: Annotated[RlsConfig, none_to({})] = Field(
        default_factory=RlsConfig, description="Method 'rls': force scale calibration and process noise."
    )
    prior: Annotated[PriorConfig, none_to({})] = Field(
        default_factory=PriorConfig, description="Prior on θ (also the starting point of the batch solver)."
    )
    parameters: tuple[ParameterGroup, ...] = Field(
        default=("mass", "inertia"),
        description="Batch and sequential: which parameters are estimated, groups of mass, inertia (Ixx, Iyy, "
        "Izz), products (Jxy, Jxz, Jyz), com (centre-of-mass offset), force_scale, torque_scale (per body axis); "
        "must include mass and inertia. The others are held at rigid_body's means. The rls method estimates mass "
        "and inertia only (its force scale: rls.force_scale), with rls.full_body also products and com.",
    )
    rigid_body: Annotated[RigidBodyPriorConfig, none_to({})] = Field(
        default_factory=RigidBodyPriorConfig,
        description="Prior of the parameters beyond mass and inertia (their fixed values when not estimated).",
    )
    use_prior: bool = Field(
        default=True, description="Batch: include the prior in the likelihood (the sequential filter always does)."
    )
    measurement_noise: Annotated[MeasurementNoiseConfig, none_to({})] = Field(
        default_factory=MeasurementNoiseConfig, description="Measurement noise model."
    )
    process_noise: Annotated[ProcessNoiseConfig, none_to({})] = Field(
        default_factory=ProcessNoiseConfig, description="Process noise model."
    )
    gate_probability: Annotated[Real, Field(gt=0.0, lt=1.0)] | None = Field(
        default=0.99, description="χ² outlier gate level in (0, 1), null disables gating ([ReSWARM2023] §6.2.1: 0.99)."
    )
    max_iterations: Annotated[StrictInt, Field(ge=1, le=1000)] = Field(
        default=30, description="Batch: Gauss-Newton iterations per gating round, 1..1000."
    )
    max_gating_rounds: Annotated[StrictInt, Field(ge=1, le=100)] = Field(
        default=8, description="Batch: re-solves after outlier rejection, 1..100."
    )
    tolerance: PositiveReal = Field(
        default=1e-10, description="Batch: relative cost decrease (and step) at which iterations stop, > 0."
    )
    reorder_window: Annotated[StrictInt, Field(ge=0, le=10000)] = Field(
        default=8, description="Sequential: records held back to restore time-stamp order, >= 0."
    )
    substep_s: PositiveReal | None = Field(
        default=None,
        description="Integration step of the process model [s] (default: simulation.plant_rate_hz's period).",
    )
    max_relative_std: PositiveReal = Field(
        default=0.1,
        description="A parameter whose Cramér-Rao bound exceeds this fraction of its value is reported as "
        "unobservable and no estimate is written, > 0.",
    )
    window_s: PositiveReal = Field(
        default=10.0,
        description="Batch: also solve on growing windows every window_s seconds to record convergence [s], > 0.",
    )

    @field_validator("parameters")
    @classmethod
    def _parameter_groups(cls, groups: Any) -> Any:
        if len(set(groups)) != len(groups):
            raise PydanticCustomError("oacli_estimation", "a group is listed twice")
        if "mass" not in groups or "inertia" not in groups:
            raise PydanticCustomError("oacli_estimation", "must include mass and inertia")
        return groups

    @model_validator(mode="after")
    def _something_measured(self) -> EstimationConfig:
        noise = self.measurement_noise
        state = (noise.position_std_m, noise.velocity_std_mps, noise.attitude_std_rad, noise.angular_velocity_std_radps)
        if all(s is None for s in state):
            raise PydanticCustomError(
                "oacli_estimation", "measurement_noise: at least one of position, velocity, attitude or angular "
                "velocity must be measured"
            )
        return self

    def prior_theta(self, robot_theta: np.ndarray) -> np.ndarray:
        """θ₀ [kg, kg·m² ×3]: the configured mean, missing entries from the robot model ``robot_theta``."""
        return self.prior.theta(robot_theta)

    def prior_covariance(self) -> np.ndarray:
        """P₀ = diag(mass variance, inertia variances) [kg², (kg·m²)²]."""
        return self.prior.covariance()


__all__ = [
    "RATTLE_PRIOR_THETA",
    "RATTLE_PRIOR_VARIANCE",
    "EstimationConfig",
    "EstimationMethod",
    "MeasurementNoiseConfig",
    "ParameterGroup",
    "PriorConfig",
    "ProcessNoiseConfig",
    "RigidBodyPriorConfig",
    "RlsConfig",
]
