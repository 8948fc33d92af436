"""Field types of the configuration models, and the base of every section.

Every number is a finite float (``Real``; text and booleans are refused with a reason), vectors are tuples of a
fixed length, quaternions ``[x, y, z, w]`` are unit (normalised silently within ``QUATERNION_NORM_TOLERANCE``),
principal inertias satisfy the triangle inequalities, shape matrices are symmetric positive definite. The section
modules (:mod:`oacli.config.robot`, ``environment``, ``simulation``, ``controller``, ``reference``, ``tube``,
``limits``, ``planner``, ``excitation``, ``estimation``) build on these; :mod:`oacli.config.models` assembles the
whole file.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from typing import Annotated, Any

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StringConstraints,
    ValidationError,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

QUATERNION_NORM_TOLERANCE = 1e-3
"""Quaternions with ``|‖q‖ - 1| <= QUATERNION_NORM_TOLERANCE`` are normalised; others are rejected."""

INERTIA_TRIANGLE_RTOL = 1e-12
"""Relative tolerance of the triangle inequalities ``Ixx + Iyy >= Izz`` (and permutations)."""

MAX_COORDINATE_M = 1.0e4
"""Largest magnitude of a coordinate in the world frame [m] (the ISS is about 100 m long): a position of 1e30
would overflow the geometry and ask grids and plots for absurd sizes."""

NAME_PATTERN = r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$"
"""Run, frame and waypoint names: letters, digits, ``_``, ``.`` and ``-``, not starting with ``.`` or ``-``."""


def _real(value: Any) -> float:
    """Accept a finite real number (int or float, not bool, not text) and return it as a float."""
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            raise PydanticCustomError("oacli_number", "must be a number") from None
        raise PydanticCustomError(
            "oacli_number",
            "must be a number, not text (remove the quotes)",
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


def sequence_of(n: int, broadcast: bool = False) -> Callable[[Any], Any]:
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


def _bounded_position(p: tuple[float, float, float]) -> tuple[float, float, float]:
    """Refuse coordinates beyond ±:data:`MAX_COORDINATE_M`."""
    worst = max(abs(c) for c in p)
    if worst > MAX_COORDINATE_M:
        raise PydanticCustomError(
            "oacli_workspace",
            "coordinate {value} m is beyond the workspace bound of ±{bound} m",
            {"value": f"{worst:.3g}", "bound": f"{MAX_COORDINATE_M:g}"},
        )
    return p


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


def none_to(empty: Any) -> BeforeValidator:
    """Treat an empty YAML value (``key:`` with nothing after it) as ``empty`` (a section's defaults or no items)."""
    return BeforeValidator(lambda value: empty if value is None else value)


Real = Annotated[float, BeforeValidator(_real)]
"""A finite real number."""
PositiveReal = Annotated[Real, Field(gt=0)]
NonNegativeReal = Annotated[Real, Field(ge=0)]
StrictInt = Annotated[int, Strict()]
StrictBool = Annotated[bool, Strict()]
Fraction = Annotated[Real, Field(gt=0, le=1)]
"""A fraction in (0, 1]."""

Vector3 = Annotated[tuple[Real, Real, Real], BeforeValidator(sequence_of(3))]
"""Three finite real numbers."""
Position3 = Annotated[Vector3, AfterValidator(_bounded_position)]
"""A position or displacement in the world frame [m], each coordinate within ±:data:`MAX_COORDINATE_M`."""
BoundedPositiveVector3 = Annotated[
    tuple[PositiveReal, PositiveReal, PositiveReal], BeforeValidator(sequence_of(3)), AfterValidator(_bounded_position)
]
"""Three positive lengths [m] (semi-axes, sizes), each at most :data:`MAX_COORDINATE_M`."""
PositiveVector3 = Annotated[tuple[PositiveReal, PositiveReal, PositiveReal], BeforeValidator(sequence_of(3))]
PositiveVector4 = Annotated[
    tuple[PositiveReal, PositiveReal, PositiveReal, PositiveReal], BeforeValidator(sequence_of(4))
]
"""Four positive numbers, one per parameter θ = [m, Ixx, Iyy, Izz]."""
NonNegativeVector4 = Annotated[
    tuple[NonNegativeReal, NonNegativeReal, NonNegativeReal, NonNegativeReal], BeforeValidator(sequence_of(4))
]
"""Four non-negative numbers, one per parameter θ = [m, Ixx, Iyy, Izz]."""
NonNegativeVector3 = Annotated[
    tuple[NonNegativeReal, NonNegativeReal, NonNegativeReal], BeforeValidator(sequence_of(3))
]
Weight3 = Annotated[tuple[PositiveReal, PositiveReal, PositiveReal], BeforeValidator(sequence_of(3, broadcast=True))]
"""Three positive weights; a single number is repeated on every axis."""
Quaternion = Annotated[
    tuple[Real, Real, Real, Real], BeforeValidator(sequence_of(4)), AfterValidator(_quaternion_normalised)
]
"""Unit quaternion ``[x, y, z, w]`` (scalar last)."""
PrincipalInertia = Annotated[PositiveVector3, AfterValidator(_principal_inertias)]
SPDMatrix3 = Annotated[tuple[Vector3, Vector3, Vector3], BeforeValidator(sequence_of(3)), AfterValidator(_spd_matrix)]
BoxCorners = Annotated[tuple[Position3, Position3], BeforeValidator(sequence_of(2)), AfterValidator(_sorted_corners)]
Name = Annotated[str, Strict(), StringConstraints(pattern=NAME_PATTERN, max_length=64)]

IDENTITY_QUATERNION = (0.0, 0.0, 0.0, 1.0)


def raise_at(title: str, problems: list[tuple[tuple[str | int, ...], Any, str]]) -> None:
    """Raise one ValidationError carrying several ``(loc, value, reason)`` problems (used by cross-field checks)."""
    if problems:
        raise ValidationError.from_exception_data(
            title,
            [
                InitErrorDetails(type=PydanticCustomError("oacli_cross_field", reason), loc=loc, input=value)
                for loc, value, reason in problems
            ],
        )


def read_only(values: Any) -> np.ndarray:
    """``values`` as a read-only float array."""
    arr = np.array(values, dtype=float)
    arr.setflags(write=False)
    return arr


class Section(BaseModel):
    """Base of every config section: frozen, unknown keys rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)


__all__ = [
    "IDENTITY_QUATERNION",
    "INERTIA_TRIANGLE_RTOL",
    "MAX_COORDINATE_M",
    "NAME_PATTERN",
    "QUATERNION_NORM_TOLERANCE",
    "BoundedPositiveVector3",
    "BoxCorners",
    "Fraction",
    "Name",
    "NonNegativeReal",
    "NonNegativeVector3",
    "Position3",
    "PositiveReal",
    "PositiveVector3",
    "PositiveVector4",
    "PrincipalInertia",
    "Quaternion",
    "Real",
    "SPDMatrix3",
    "Section",
    "StrictBool",
    "StrictInt",
    "Vector3",
    "Weight3",
    "none_to",
    "raise_at",
    "read_only",
    "sequence_of",
]
