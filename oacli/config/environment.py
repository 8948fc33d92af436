"""The workspace (``environment``: keep-in boxes, keep-out ellipsoids) and the poses in it (``waypoints``)."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import Discriminator, Field, Tag, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import (
    IDENTITY_QUATERNION,
    BoundedPositiveVector3,
    BoxCorners,
    Name,
    NonNegativeReal,
    Position3,
    Quaternion,
    Real,
    Section,
    SPDMatrix3,
    none_to,
    raise_at,
)
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.model import quaternion as quat


class Pose(Section):
    """A position [m] and attitude quaternion ``[x, y, z, w]`` in the world frame."""

    position: Position3 = Field(description="Position in the world frame [m].")
    quaternion: Quaternion = Field(
        default=IDENTITY_QUATERNION, description="Attitude [x, y, z, w], scalar last, body to world; unit norm."
    )

    def state(self) -> np.ndarray:
        """The 13-entry state ``[r, v=0, q, omega=0]`` at rest in this pose (see :mod:`oacli.types`)."""
        x = np.zeros(13)
        x[0:3] = self.position
        x[6:10] = self.quaternion
        return x


class KeepInBox(Section):
    """An axis-aligned keep-in box given by two opposite corners in any order (sorted per axis on load)."""

    corners: BoxCorners = Field(
        description="Two opposite corners [[x, y, z], [x, y, z]] [m]; stored sorted as (lower, upper)."
    )

    @property
    def lower(self) -> tuple[float, float, float]:
        """Lower corner [m]."""
        return self.corners[0]

    @property
    def upper(self) -> tuple[float, float, float]:
        """Upper corner [m]."""
        return self.corners[1]

    def box(self) -> Box:
        """The box as :class:`oacli.geometry.Box`."""
        return Box(self.lower, self.upper)  # type: ignore[arg-type]


class KeepOutEllipsoid(Section):
    """Ellipsoidal keep-out zone ([Doerr2021] Eq. 12): either ``semi_axes_m`` (+ ``quaternion``) or ``shape_matrix``."""

    center: Position3 = Field(description="Centroid [m].")
    semi_axes_m: BoundedPositiveVector3 | None = Field(
        default=None, description="Semi-axes along the body axes of ``quaternion`` [m], each > 0."
    )
    quaternion: Quaternion | None = Field(
        default=None,
        description="Orientation [x, y, z, w] of the semi-axes (only with semi_axes_m; default: axis-aligned).",
    )
    shape_matrix: SPDMatrix3 | None = Field(
        default=None,
        description="Symmetric positive definite 3x3 shape matrix P [1/m²], free space (p-c)ᵀP(p-c) >= 1.",
    )

    @model_validator(mode="after")
    def _one_description(self) -> KeepOutEllipsoid:
        if (self.semi_axes_m is None) == (self.shape_matrix is None):
            got = "both" if self.semi_axes_m is not None else "neither"
            raise PydanticCustomError(
                "oacli_ellipsoid", "give exactly one of semi_axes_m or shape_matrix (got {got})", {"got": got}
            )
        if self.shape_matrix is not None and self.quaternion is not None:
            raise_at(
                "KeepOutEllipsoid",
                [(("quaternion",), list(self.quaternion), "only allowed with semi_axes_m, not with shape_matrix")],
            )
        return self

    def ellipsoid(self) -> Ellipsoid:
        """The keep-out zone as :class:`oacli.geometry.Ellipsoid` (without the environment's safety factor)."""
        if self.shape_matrix is not None:
            return Ellipsoid(self.center, self.shape_matrix)  # type: ignore[arg-type]
        rotation = None if self.quaternion is None else quat.to_rotation_matrix(np.array(self.quaternion))
        return Ellipsoid.from_semi_axes(self.center, self.semi_axes_m, rotation)  # type: ignore[arg-type]


class EnvironmentConfig(Section):
    """The workspace: keep-in boxes (their union is allowed) minus keep-out ellipsoids."""

    frame: Name = Field(default="world", description="Name of the world frame positions are expressed in.")
    safety_factor: Annotated[Real, Field(ge=1)] = Field(
        default=1.0, description="Multiplies every keep-out semi-axis ([Doerr2021] Eq. 12), >= 1 [-]."
    )
    keep_in: Annotated[tuple[KeepInBox, ...], none_to(())] = Field(
        default=(), description="Keep-in boxes; empty means unbounded."
    )
    keep_out: Annotated[tuple[KeepOutEllipsoid, ...], none_to(())] = Field(
        default=(), description="Keep-out ellipsoids."
    )
    keep_in_margin_m: NonNegativeReal = Field(
        default=0.0,
        description="Distance the robot's centre keeps from the keep-in walls [m], >= 0. Keep-in boxes bound the "
        "robot's centre (as the planners' collision checks and Astrobee's keep-in files do); keep-out zones are "
        "grown by robot.radius_m. Used by the controllers' keep-in rows and the safety check of tracking runs.",
    )

    def scene(self) -> Scene:
        """The workspace as :class:`oacli.geometry.Scene`, keep-out zones inflated by ``safety_factor``."""
        return Scene(
            keep_in=tuple(b.box() for b in self.keep_in),
            keep_out=tuple(e.ellipsoid().inflated(self.safety_factor) for e in self.keep_out),
            frame=self.frame,
        )




def _waypoint_ref_tag(value: Any) -> str | None:
    if isinstance(value, str):
        return "<name>"
    if isinstance(value, dict | Pose):
        return "<pose>"
    return None


WaypointRef = Annotated[
    Annotated[str, Tag("<name>")] | Annotated[Pose, Tag("<pose>")],
    Discriminator(
        _waypoint_ref_tag,
        custom_error_type="oacli_waypoint_ref",
        custom_error_message="must be a waypoint name or a {position, quaternion} mapping",
    ),
]
"""A waypoint given by its name in ``waypoints:`` or inline as a pose. Tags in ``<>`` never reach messages."""


__all__ = [
    "EnvironmentConfig",
    "KeepInBox",
    "KeepOutEllipsoid",
    "Pose",
    "WaypointRef",
]
