"""The ``mission`` section: the three-segment assembly mission ([Doerr2021] Fig. 1, Results; [ReSWARM2023] §4.7).

``route`` names the waypoints A (construction/assembly site), B (storage or 3D printer, where the payload is
grasped) and C (the safe area where the payload's inertia is learned). ``grasped`` is the plant after the grasp
(the truth of segments 2 and 3); ``prior`` is what the controller assumes about it before estimation, with its
standard deviations (the tube's W of segment 2 comes from them, [Doerr2021] Eq. 28). ``segments`` holds per-segment
overrides of any other section (deep-merged into the file's sections for that segment's stages and validated like
the file).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import (
    Name,
    NonNegativeReal,
    PositiveReal,
    PositiveVector4,
    PrincipalInertia,
    Section,
    StrictBool,
    StrictInt,
    none_to,
)

SEGMENT_NAMES = ("segment-1", "segment-2", "segment-3")


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``override`` merged in: mappings recursively, anything else replaced.

    Parameters
    ----------
    base, override : Mapping
        Plain config data.

    Returns
    -------
    dict
        A new mapping (the inputs are not modified: ``base`` is copied once, each replacing value of ``override``
        once).
    """
    return _merge_into(copy.deepcopy(dict(base)), override)


def _merge_into(out: dict[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Merge ``override`` into ``out`` (already a private copy) in place and return it."""
    for key, value in override.items():
        current = out.get(key)
        if isinstance(value, Mapping) and isinstance(current, Mapping):
            out[key] = _merge_into(current if isinstance(current, dict) else dict(current), value)
        else:
            out[key] = copy.deepcopy(value)
    return out


class GraspedPlantConfig(Section):
    """The simulated plant once the payload is grasped at B (the truth of segments 2 and 3)."""

    mass_kg: PositiveReal = Field(description="Mass of robot + payload [kg] ([Doerr2021] Table 1: 15 kg).")
    inertia_kgm2: PrincipalInertia = Field(description="Principal inertias of robot + payload [kg·m²].")


class PayloadPriorConfig(Section):
    """The controller's model of robot + payload before estimation: mean and variances (the unit of
    ``robot.variance``)."""

    mass_kg: PositiveReal = Field(description="Prior mass [kg].")
    inertia_kgm2: PrincipalInertia = Field(description="Prior principal inertias [kg·m²].")
    variance: PositiveVector4 = Field(
        description="Variances of θ = [m, Ixx, Iyy, Izz] [kg², (kg·m²)² ×3], > 0 (σ_m = sqrt(variance[0]) sizes "
        "segment 2's W, [Doerr2021] Eq. 28)."
    )


class CalibrationManoeuvreConfig(Section):
    """A rotation-rich flight of the known bare robot at B before the grasp, for the actuator calibration.

    Segment 1 barely rotates the robot, so its telemetry calibrates the torque scales κ_τ only to the prior's few
    per cent, and the payload's inertias are known no better than κ_τ (``τ = κ_τ ⊙ τ_cmd = J ω̇``: κ_τ and J enter
    as one product, docs/estimation.md). This manoeuvre (stage ``segment-1/calibrate-manoeuvre``, a ``track`` of a
    waypoint reference, :func:`oacli.reference.waypoint_reference`) swings the robot about each body axis in turn,
    ``+angle`` then ``-angle`` then back, while it translates ``±offset`` along the same axis, within the rate and
    torque limits; ``segment-1/calibrate`` then fits the force and torque scales on its telemetry with the robot's
    mass and inertias held ([ReSWARM2023] Eqs. 38-39).
    """

    angle_rad: Annotated[PositiveReal, Field(le=1.5)] = Field(
        default=0.25, description="Slew amplitude about each body axis [rad], in (0, 1.5].")
    offset_m: Annotated[NonNegativeReal, Field(le=0.3)] = Field(
        default=0.08, description="Translation amplitude along each body axis during its slews [m], in [0, 0.3].")
    angular_rate_radps: PositiveReal = Field(
        default=0.15, description="Peak angular rate of the slews [rad/s] (reference.angular_rate_radps; <= every "
        "robot angular velocity limit).")
    angular_acceleration_radps2: PositiveReal = Field(
        default=0.08, description="Peak angular acceleration of the slews [rad/s²] (the largest inertia × it must "
        "stay within every robot torque limit: 0.08 × 0.162 = 0.013 N·m < 0.0216 N·m on the ISS robot).")
    acceleration_mps2: PositiveReal = Field(
        default=0.02, description="Peak linear acceleration of the translations [m/s²] (mass × it within every "
        "robot force limit).")
    cruise_speed_mps: PositiveReal = Field(default=0.1, description="Peak translation speed [m/s].")
    hold_s: NonNegativeReal = Field(default=0.5, description="Hold at each pose of the manoeuvre [s].")
    repeats: Annotated[StrictInt, Field(ge=1, le=5)] = Field(
        default=1, description="The three axes' swings flown this many times, 1..5.")


SegmentName = Literal["segment-1", "segment-2", "segment-3"]
"""segment-1: A → B (plan, smooth, track); segment-2: B → C (excite, track, estimate); segment-3: C → A (plan,
smooth, track and the baselines)."""


class MissionConfig(Section):
    """``oacli mission``: route, payload, and per-segment settings ([Doerr2021] Fig. 1; [ReSWARM2023] Table 1)."""

    route: tuple[Name, Name, Name] = Field(
        default=("A", "B", "C"),
        description="Waypoint names A (assembly site), B (grasp: storage / 3D printer), C (safe area).",
    )
    excitation_method: Literal["offline", "rattle"] | None = Field(
        default=None, description="Segment 2: offline A-optimal design or RATTLE (default: excitation.method)."
    )
    grasped: GraspedPlantConfig = Field(description="The plant after the grasp at B.")
    prior: PayloadPriorConfig = Field(description="The controller's model after the grasp, before estimation.")
    w_sigmas: PositiveReal = Field(
        default=2.0, description="The tubes' W from this many σ of the model's mass: the prior's in segment 2, the "
        "estimate's in segment 3 ([Doerr2021] Eq. 28 uses 2).",
    )
    rate_margin_sigmas: NonNegativeReal = Field(
        default=0.0, description="Rates kept under inertia error: after the grasp, the controllers keep "
        "1 - 1/(1 + n σ_I/I) of the angular-rate limit free (controller.rate_margin) and the excitation's rate and "
        "torque shares shrink by I/(I + n σ_I), with this many σ of the model's inertias (the largest relative σ); "
        "0: no margin.",
    )
    settle_s: NonNegativeReal = Field(
        default=2.0, description="Tracking time after each reference's end (simulation.settle_time_s) [s]."
    )
    baselines: StrictBool = Field(
        default=True, description="Also fly segment 3 with standard and tube MPC on the prior ([Doerr2021] Fig. 3(d))."
    )
    unconstrained_baseline: StrictBool = Field(
        default=False, description="With baselines: also fly segment 3 with standard MPC on the prior WITHOUT "
        "workspace constraints (controller.position_constraints false, the paper's standard MPC), folder "
        "segment-3/baseline-mpc-unconstrained-prior.",
    )
    calibration: StrictBool = Field(
        default=False, description="Calibrate the actuators on segment 1's flight of the known robot first "
        "(segment-1/calibrate: the estimation section's force and torque scales with the robot's mass and inertias "
        "held, [ReSWARM2023] Eqs. 38-39) and hand its mean and σ to segment 2's estimates as their prior.",
    )
    calibration_manoeuvre: CalibrationManoeuvreConfig | None = Field(
        default=None, description="With calibration: fly a rotation-rich manoeuvre of the known robot at B before "
        "the grasp (segment-1/calibrate-manoeuvre) and calibrate on its telemetry instead of segment 1's, so the "
        "torque scales are identified too and handed to segment 2 (its held κ_τ ± σ, or its prior where it estimates "
        "them; mapping, {} takes the defaults); null: calibrate on segment 1's track (force scales only).",
    )
    segments: Annotated[dict[str, Any], none_to({})] = Field(
        default_factory=dict,
        description="Per-segment overrides of the other sections (segment-1, segment-2, segment-3), deep-merged; "
        "a stage key (segment-3/baseline-mpc-prior ...) overrides that stage alone, after its segment's.",
    )

    @field_validator("calibration_manoeuvre", mode="after")
    @classmethod
    def _manoeuvre_needs_calibration(cls, value: CalibrationManoeuvreConfig | None,
                                     info: ValidationInfo) -> CalibrationManoeuvreConfig | None:
        if value is not None and info.data.get("calibration") is False:
            raise PydanticCustomError("oacli_range", "needs mission.calibration: true (the manoeuvre is flown for "
                                      "segment-1/calibrate); set it null or calibration true")
        return value


__all__ = ["SEGMENT_NAMES", "CalibrationManoeuvreConfig", "GraspedPlantConfig", "MissionConfig", "PayloadPriorConfig",
           "SegmentName", "deep_merge"]
