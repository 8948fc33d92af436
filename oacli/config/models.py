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

Adding a section (``planner``, ``excitation``, ``estimation``) means adding a :class:`Section` subclass and a field
on :class:`OacliConfig`; adding a controller type means widening :data:`ControllerType` (or turning
``controller`` into a discriminated union on ``type``).
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Callable
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Strict,
    StringConstraints,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from oacli.geometry import Box, Ellipsoid, Scene
from oacli.model import quaternion as quat
from oacli.types import InertialParams

QUATERNION_NORM_TOLERANCE = 1e-3
"""Quaternions with ``|‖q‖ - 1| <= QUATERNION_NORM_TOLERANCE`` are normalised; others are rejected."""

INERTIA_TRIANGLE_RTOL = 1e-12
"""Relative tolerance of the triangle inequalities ``Ixx + Iyy >= Izz`` (and permutations)."""

MAX_HORIZON = 500
"""Largest accepted MPC horizon [steps]."""

NAME_PATTERN = r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$"
"""Run, frame and waypoint names: letters, digits, ``_``, ``.`` and ``-``, not starting with ``.`` or ``-``."""


# --------------------------------------------------------------------------------------------------------------
# Field types
# --------------------------------------------------------------------------------------------------------------


def _real(value: Any) -> float:
    """Accept a finite real number (int or float, not bool, not text) and return it as a float."""
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            raise PydanticCustomError("oacli_number", "must be a number") from None
        raise PydanticCustomError(
            "oacli_number",
            "must be a number, not text (YAML reads exponents without a decimal point, such as 1e3, as text: "
            "write 1.0e3)",
        )
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise PydanticCustomError("oacli_number", "must be a number")
    try:
        out = float(value)
    except (OverflowError, ValueError, TypeError):
        raise PydanticCustomError("oacli_finite", "must be a finite number") from None
    if not math.isfinite(out):
        raise PydanticCustomError("oacli_finite", "must be finite (not NaN or infinity)")
    return out


def _sequence(n: int, broadcast: bool = False) -> Callable[[Any], Any]:
    """Before-validator: the value must be a list of exactly ``n`` items.

    With ``broadcast`` a single positive number is also accepted and repeated ``n`` times (used for weights).
    """

    def check(value: Any) -> Any:
        if broadcast and isinstance(value, numbers.Real) and not isinstance(value, bool):
            scalar = _real(value)
            if scalar <= 0:
                raise PydanticCustomError("oacli_positive", "must be > 0")
            return (scalar,) * n
        if isinstance(value, np.ndarray):
            value = list(value)
        if not isinstance(value, list | tuple):
            what = f"a number or a list of {n} numbers" if broadcast else f"a list of {n} items"
            raise PydanticCustomError("oacli_sequence", "must be {what}", {"what": what})
        if len(value) != n:
            raise PydanticCustomError(
                "oacli_length", "must have exactly {n} elements, got {got}", {"n": n, "got": len(value)}
            )
        return tuple(value)

    return check


def _quaternion_normalised(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Normalise a quaternion whose norm is within tolerance of 1; reject any other."""
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise PydanticCustomError(
            "oacli_quaternion",
            "quaternion norm {norm} is not 1 (tolerance {tol})",
            {"norm": f"{norm:.6g}", "tol": QUATERNION_NORM_TOLERANCE},
        )
    if abs(norm - 1.0) <= 8 * np.finfo(float).eps:  # already unit: keep the exact values (dump round-trips)
        return q
    return tuple(c / norm for c in q)  # type: ignore[return-value]


def _principal_inertias(inertia: tuple[float, float, float]) -> tuple[float, float, float]:
    """Check the triangle inequalities of principal moments of inertia (each sum of two >= the third)."""
    names = ("Ixx", "Iyy", "Izz")
    tol = INERTIA_TRIANGLE_RTOL * max(inertia)
    for k in range(3):
        i, j = [m for m in range(3) if m != k]
        if inertia[i] + inertia[j] < inertia[k] - tol:
            raise PydanticCustomError(
                "oacli_inertia",
                "principal inertias violate the triangle inequality {a} + {b} >= {c} ({lhs} < {rhs})",
                {
                    "a": names[i],
                    "b": names[j],
                    "c": names[k],
                    "lhs": f"{inertia[i] + inertia[j]:.6g}",
                    "rhs": f"{inertia[k]:.6g}",
                },
            )
    return inertia


def _spd_matrix(rows: tuple[tuple[float, float, float], ...]) -> tuple[tuple[float, float, float], ...]:
    """Check that a 3x3 matrix is symmetric positive definite (same tolerances as :class:`Ellipsoid`)."""
    m = np.array(rows, dtype=float)
    if not np.allclose(m, m.T, rtol=1e-10, atol=1e-12):
        raise PydanticCustomError(
            "oacli_matrix",
            "must be symmetric (largest |P - Pᵀ| entry {asym})",
            {"asym": f"{np.max(np.abs(m - m.T)):.3g}"},
        )
    smallest = float(np.linalg.eigvalsh(m).min())
    if smallest <= 0:
        raise PydanticCustomError(
            "oacli_matrix", "must be positive definite (smallest eigenvalue {eig})", {"eig": f"{smallest:.6g}"}
        )
    return rows


def _sorted_corners(corners: tuple[tuple[float, float, float], ...]) -> tuple[tuple[float, float, float], ...]:
    """Sort two box corners per axis into (lower, upper); reject a zero width on any axis."""
    a, b = corners
    lower = tuple(min(x, y) for x, y in zip(a, b, strict=True))
    upper = tuple(max(x, y) for x, y in zip(a, b, strict=True))
    for axis, lo, hi in zip("xyz", lower, upper, strict=True):
        if hi <= lo:
            raise PydanticCustomError(
                "oacli_box", "box has zero width along {axis} (both corners at {value})", {"axis": axis, "value": lo}
            )
    return (lower, upper)  # type: ignore[return-value]


def _none_to(empty: Any) -> BeforeValidator:
    """Treat an empty YAML value (``key:`` with nothing after it) as ``empty`` (a section's defaults or no items)."""
    return BeforeValidator(lambda value: empty if value is None else value)


Real = Annotated[float, BeforeValidator(_real)]
"""A finite real number."""
PositiveReal = Annotated[Real, Field(gt=0)]
NonNegativeReal = Annotated[Real, Field(ge=0)]
StrictInt = Annotated[int, Strict()]

Vector3 = Annotated[tuple[Real, Real, Real], BeforeValidator(_sequence(3))]
"""Three finite real numbers."""
PositiveVector3 = Annotated[tuple[PositiveReal, PositiveReal, PositiveReal], BeforeValidator(_sequence(3))]
NonNegativeVector3 = Annotated[tuple[NonNegativeReal, NonNegativeReal, NonNegativeReal], BeforeValidator(_sequence(3))]
Weight3 = Annotated[tuple[PositiveReal, PositiveReal, PositiveReal], BeforeValidator(_sequence(3, broadcast=True))]
"""Three positive weights; a single number is repeated on every axis."""
Quaternion = Annotated[
    tuple[Real, Real, Real, Real], BeforeValidator(_sequence(4)), AfterValidator(_quaternion_normalised)
]
"""Unit quaternion ``[x, y, z, w]`` (scalar last)."""
PrincipalInertia = Annotated[PositiveVector3, AfterValidator(_principal_inertias)]
SPDMatrix3 = Annotated[tuple[Vector3, Vector3, Vector3], BeforeValidator(_sequence(3)), AfterValidator(_spd_matrix)]
BoxCorners = Annotated[tuple[Vector3, Vector3], BeforeValidator(_sequence(2)), AfterValidator(_sorted_corners)]
Name = Annotated[str, Strict(), StringConstraints(pattern=NAME_PATTERN, max_length=64)]

IDENTITY_QUATERNION = (0.0, 0.0, 0.0, 1.0)


def _raise_at(title: str, problems: list[tuple[tuple[str | int, ...], Any, str]]) -> None:
    """Raise one ValidationError carrying several ``(loc, value, reason)`` problems (used by cross-field checks)."""
    if problems:
        raise ValidationError.from_exception_data(
            title,
            [
                InitErrorDetails(type=PydanticCustomError("oacli_cross_field", reason), loc=loc, input=value)
                for loc, value, reason in problems
            ],
        )


def _ro(values: Any) -> np.ndarray:
    arr = np.array(values, dtype=float)
    arr.setflags(write=False)
    return arr


# --------------------------------------------------------------------------------------------------------------
# Sections
# --------------------------------------------------------------------------------------------------------------


class Section(BaseModel):
    """Base of every config section: frozen, unknown keys rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class RobotConfig(Section):
    """The robot model the planner, controller and estimator use (Doerr et al. 2021, Eqs. 33-36)."""

    mass_kg: PositiveReal = Field(description="Mass m [kg], > 0.")
    inertia_kgm2: PrincipalInertia = Field(
        description="Principal moments of inertia (Ixx, Iyy, Izz) [kg·m²] about the body axes through the CoM; "
        "each > 0 and each sum of two >= the third."
    )
    force_limit_N: PositiveVector3 = Field(description="Force bound per world axis, |f_i| <= limit [N].")
    torque_limit_Nm: PositiveVector3 = Field(description="Torque bound per body axis, |tau_i| <= limit [N·m].")
    velocity_limit_mps: PositiveVector3 = Field(
        default=(0.2, 0.2, 0.2),
        description="Velocity bound per world axis [m/s] (default: Astrobee nominal flight mode).",
    )
    angular_velocity_limit_radps: PositiveVector3 = Field(
        default=(0.1745, 0.1745, 0.1745),
        description="Angular velocity bound per body axis [rad/s] (default: Astrobee nominal flight mode).",
    )
    radius_m: NonNegativeReal = Field(default=0.25, description="Collision radius of the robot [m], >= 0.")

    def inertial_params(self) -> InertialParams:
        """Mass and principal inertias as :class:`oacli.types.InertialParams`."""
        return InertialParams(self.mass_kg, self.inertia_kgm2)  # type: ignore[arg-type]

    @property
    def input_limits(self) -> np.ndarray:
        """Input bounds ``[force (3) N, torque (3) N·m]``, shape (6,), read-only; ``|u_i| <= input_limits[i]``."""
        return _ro(self.force_limit_N + self.torque_limit_Nm)

    @property
    def velocity_limits(self) -> np.ndarray:
        """``[velocity (3) m/s, angular velocity (3) rad/s]`` bounds, shape (6,), read-only."""
        return _ro(self.velocity_limit_mps + self.angular_velocity_limit_radps)


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
        return _ro(self.force_bias_N + self.torque_bias_Nm)

    @property
    def random_bound(self) -> np.ndarray:
        """Half-width of the uniform random part ``[force (3) N, torque (3) N·m]``, shape (6,), read-only."""
        return _ro(self.force_random_N + self.torque_random_Nm)

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
    disturbance: Annotated[DisturbanceConfig, _none_to({})] = Field(
        default_factory=DisturbanceConfig, description="Additive disturbance acting on the plant."
    )

    def inertial_params(self) -> InertialParams:
        """True mass and principal inertias (only valid once filled, i.e. on a validated :class:`OacliConfig`)."""
        if self.mass_kg is None or self.inertia_kgm2 is None:
            raise ValueError("truth inertial parameters are not set; use OacliConfig.truth_params()")
        return InertialParams(self.mass_kg, self.inertia_kgm2)  # type: ignore[arg-type]


class Pose(Section):
    """A position [m] and attitude quaternion ``[x, y, z, w]`` in the world frame."""

    position: Vector3 = Field(description="Position in the world frame [m].")
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
    """Ellipsoidal keep-out zone (Doerr Eq. 12): either ``semi_axes_m`` (+ ``quaternion``) or ``shape_matrix``."""

    center: Vector3 = Field(description="Centroid [m].")
    semi_axes_m: PositiveVector3 | None = Field(
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
            _raise_at(
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
        default=1.0, description="Multiplies every keep-out semi-axis (Doerr Eq. 12), >= 1 [-]."
    )
    keep_in: Annotated[tuple[KeepInBox, ...], _none_to(())] = Field(
        default=(), description="Keep-in boxes; empty means unbounded."
    )
    keep_out: Annotated[tuple[KeepOutEllipsoid, ...], _none_to(())] = Field(
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


class SensorsConfig(Section):
    """Standard deviations of zero-mean Gaussian measurement noise on the state handed to the controller."""

    position_std_m: NonNegativeReal = Field(default=0.0, description="Position noise std per axis [m], >= 0.")
    velocity_std_mps: NonNegativeReal = Field(default=0.0, description="Velocity noise std per axis [m/s], >= 0.")
    attitude_std_rad: NonNegativeReal = Field(
        default=0.0, description="Attitude noise std per axis (small rotation vector) [rad], >= 0."
    )
    angular_velocity_std_radps: NonNegativeReal = Field(
        default=0.0, description="Angular velocity noise std per axis [rad/s], >= 0."
    )


class SimulationConfig(Section):
    """The closed-loop simulation."""

    plant_rate_hz: PositiveReal = Field(
        default=62.5, description="Integration rate of the true plant [Hz], > 0 (Astrobee control rate)."
    )
    settle_time_s: NonNegativeReal = Field(
        default=5.0, description="Extra simulated time after the reference ends [s], >= 0."
    )
    initial_offset_m: Vector3 = Field(
        default=(0.0, 0.0, 0.0), description="Offset of the initial true position from the reference start [m]."
    )

    @property
    def plant_period_s(self) -> float:
        """Plant integration step [s]."""
        return 1.0 / self.plant_rate_hz


class ControllerWeights(Section):
    """Diagonal MPC weights, one per axis; a single number is used on all three axes."""

    position: Weight3 = Field(default=(10.0, 10.0, 10.0), description="Position error weight [1/m²], > 0.")
    velocity: Weight3 = Field(default=(1.0, 1.0, 1.0), description="Velocity error weight [s²/m²], > 0.")
    attitude: Weight3 = Field(default=(10.0, 10.0, 10.0), description="Attitude error weight [1/rad²], > 0.")
    angular_velocity: Weight3 = Field(
        default=(1.0, 1.0, 1.0), description="Angular velocity error weight [s²/rad²], > 0."
    )
    force: Weight3 = Field(default=(1.0, 1.0, 1.0), description="Force weight [1/N²], > 0.")
    torque: Weight3 = Field(default=(100.0, 100.0, 100.0), description="Torque weight [1/(N·m)²], > 0.")

    def state_weights(self) -> np.ndarray:
        """Diagonal of Q for the 12-entry error ``[position, velocity, attitude, angular velocity]``, read-only."""
        return _ro(self.position + self.velocity + self.attitude + self.angular_velocity)

    def input_weights(self) -> np.ndarray:
        """Diagonal of R for ``[force (3), torque (3)]``, shape (6,), read-only."""
        return _ro(self.force + self.torque)


ControllerType = Literal["mpc", "tube"]
"""Controller kinds: ``"mpc"`` (standard MPC) and ``"tube"`` (robust tube MPC, settings in ``controller.tube``)."""

# The tube section lives in its own module, which builds on the types above (import order matters).
from oacli.config.tube import TubeConfig, tube_problems  # noqa: E402


class ControllerConfig(Section):
    """The tracking controller."""

    type: ControllerType = Field(
        default="mpc", description="Controller kind: 'mpc' (standard MPC) or 'tube' (robust tube MPC)."
    )
    rate_hz: PositiveReal = Field(default=5.0, description="Control update rate [Hz], > 0.")
    horizon: Annotated[StrictInt, Field(ge=1, le=MAX_HORIZON)] = Field(
        default=10, description=f"Prediction horizon [steps of 1/rate_hz s], 1..{MAX_HORIZON}."
    )
    weights: Annotated[ControllerWeights, _none_to({})] = Field(
        default_factory=ControllerWeights, description="Diagonal cost weights."
    )
    max_consecutive_failures: Annotated[StrictInt, Field(ge=1)] = Field(
        default=5,
        description="Consecutive failed solves tolerated [-], >= 1; then a latched safe hold (brake to rest, hold "
        "the attitude; see oacli.control.tracking and oacli.control.tube_mpc).",
    )
    position_constraints: Annotated[bool, Strict()] = Field(
        default=True,
        description="Keep the predicted positions in the keep-in boxes (shrunk by environment.keep_in_margin_m) "
        "and out of the "
        "keep-out zones (grown by it): soft rows in the standard MPC, hard rows tightened by the tube in the tube "
        "MPC (oacli.control.workspace). false: positions are free.",
    )
    tube: Annotated[TubeConfig, _none_to({})] = Field(
        default_factory=TubeConfig, description="Robust tube MPC settings (used when type is 'tube')."
    )

    @property
    def period_s(self) -> float:
        """Control period [s]."""
        return 1.0 / self.rate_hz


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


class ReferenceConfig(Section):
    """The reference trajectory the controller tracks."""

    source: Literal["waypoints", "file"] = Field(
        default="waypoints", description="'waypoints': through ``waypoints`` at cruise speed; 'file': from ``file``."
    )
    waypoints: Annotated[tuple[WaypointRef, ...], _none_to(())] = Field(
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


# --------------------------------------------------------------------------------------------------------------
# The whole file
# --------------------------------------------------------------------------------------------------------------

from oacli.config.estimation import EstimationConfig  # noqa: E402  (section module; imports the types above)
from oacli.config.excitation import ExcitationConfig  # noqa: E402  (needs Section and the types above)
from oacli.config.planner import PlannerConfig  # noqa: E402  (the planner section builds on the types above)


class OacliConfig(Section):
    """A complete, validated oacli configuration. Only ``robot`` is required; everything else has defaults."""

    name: Name = Field(default="oacli", description="Run name prefix, [A-Za-z0-9_.-]+.")
    seed: Annotated[StrictInt, Field(ge=0)] = Field(
        default=0, description="Seed every random choice derives from, >= 0."
    )
    robot: RobotConfig = Field(description="The model used by planner, controller and estimator.")
    truth: Annotated[TruthConfig, _none_to({})] = Field(
        default_factory=TruthConfig, description="The simulated plant (defaults to the robot model)."
    )
    environment: Annotated[EnvironmentConfig, _none_to({})] = Field(
        default_factory=EnvironmentConfig, description="Keep-in boxes and keep-out ellipsoids."
    )
    waypoints: Annotated[dict[Name, Pose], _none_to({})] = Field(
        default_factory=dict, description="Named poses, referred to by name elsewhere."
    )
    sensors: Annotated[SensorsConfig, _none_to({})] = Field(
        default_factory=SensorsConfig, description="Measurement noise."
    )
    simulation: Annotated[SimulationConfig, _none_to({})] = Field(
        default_factory=SimulationConfig, description="Closed-loop simulation settings."
    )
    controller: Annotated[ControllerConfig, _none_to({})] = Field(
        default_factory=ControllerConfig, description="Tracking controller settings."
    )
    reference: Annotated[ReferenceConfig, _none_to({})] = Field(
        default_factory=ReferenceConfig, description="Reference trajectory settings."
    )
    excitation: Annotated[ExcitationConfig, _none_to({})] = Field(
        default_factory=ExcitationConfig, description="Excitation design and online information-aware planning."
    )
    planner: Annotated[PlannerConfig, _none_to({})] = Field(
        default_factory=PlannerConfig, description="Global planning (oacli plan) and smoothing (oacli smooth)."
    )
    estimation: Annotated[EstimationConfig, _none_to({})] = Field(
        default_factory=EstimationConfig, description="Inertial parameter estimation (oacli estimate)."
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
                robot_mass_kg=self.robot.mass_kg,
                robot_force_limit_N=self.robot.force_limit_N,
            )
        if self.controller.rate_hz > self.simulation.plant_rate_hz:
            problems.append(
                (
                    ("controller", "rate_hz"),
                    self.controller.rate_hz,
                    f"must be <= simulation.plant_rate_hz ({self.simulation.plant_rate_hz:g} Hz)",
                )
            )
        _raise_at("OacliConfig", problems)
        return self

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
