"""The reference trajectory the controller tracks (``reference``)."""

from __future__ import annotations

import os
from typing import Annotated, Literal

from pydantic import Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

from oacli.config.environment import WaypointRef
from oacli.config.fields import NonNegativeReal, PositiveReal, Section, none_to


class ReferenceConfig(Section):
    """The reference trajectory the controller tracks."""

    source: Literal["waypoints", "file"] = Field(
        default="waypoints", description="'waypoints': through ``waypoints`` at cruise speed; 'file': from ``file``."
    )
    waypoints: Annotated[tuple[WaypointRef, ...], none_to(())] = Field(
        default=(), description="Waypoint names (from the top-level ``waypoints``) or inline poses, in order."
    )
    cruise_speed_mps: PositiveReal = Field(
        default=0.1, description="Speed between waypoints [m/s], > 0 and <= every robot velocity limit."
    )
    acceleration_mps2: PositiveReal = Field(
        default=0.0175,
        description="Peak linear acceleration between waypoints [m/s²], > 0; mass × acceleration must stay "
        "within every robot force limit (default: Astrobee nominal flight mode).",
    )
    angular_rate_radps: PositiveReal = Field(
        default=0.0873,
        description="Peak angular rate between waypoints [rad/s], > 0 and <= every robot angular velocity limit "
        "(default: half the Astrobee nominal 0.1745 rad/s).",
    )
    angular_acceleration_radps2: PositiveReal = Field(
        default=0.05,
        description="Peak angular acceleration between waypoints [rad/s²], > 0; the largest inertia × angular "
        "acceleration must stay within every robot torque limit.",
    )
    hold_s: NonNegativeReal = Field(default=2.0, description="Hold time at each waypoint [s], >= 0.")
    file: str | None = Field(
        default=None,
        description="DAT folder or CSV file with a reference (source 'file'); relative paths are resolved "
        "against the config file's folder and stored absolute. Existence is checked by the stage.",
    )
    sample_period_s: PositiveReal = Field(
        default=0.5, description="Sample period of 19-row CSV files that carry no time column [s], > 0."
    )

    @field_validator("file", mode="after")
    @classmethod
    def _absolute_file(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value is None:
            return None
        if not value.strip():
            raise PydanticCustomError("oacli_path", "must not be empty")
        base = (info.context or {}).get("base_dir") or os.getcwd()
        return os.path.abspath(os.path.join(base, os.path.expanduser(value)))


__all__ = [
    "ReferenceConfig",
]
