"""Flight faults the truth plant and the flight software may suffer (``faults``), and the full inertia tensor.

[ReSWARM2023] §5.4 and §6.2.1 list what went wrong in flight: localisation jumps, dropped, delayed and out-of-order
measurements (``sensors.localisation``), impeller thrust that differs per axis (``truth.actuator_scale``), and
actuators that cannot deliver what is commanded. This section adds the two that have no home elsewhere:

- ``actuator_saturation``: per axis, the fraction of the robot's input limit the actuators can still deliver
  (1: healthy). The flight software does not know: the command is clipped at the robot's limits as always and
  recorded as applied; the plant receives it clipped again at ``fraction × limit``.
- ``controller_stall``: from ``start_s`` for ``duration_s`` the command bus stalls and the actuators hold the last
  command sent before the stall (:class:`oacli.sim.stall.StalledController`).

Both are off by default, so a config without them gives the same numbers as before they existed.

:data:`InertiaTensor` is the type of ``truth.inertia_tensor_kgm2``: a 3×3 tensor with products of inertia, checked
symmetric, positive definite and satisfying the triangle inequalities of its principal moments.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import AfterValidator, BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import NonNegativeReal, Real, Section, Vector3, none_to, sequence_of

SYMMETRY_RTOL = 1e-9
"""Largest ``|J - Jᵀ|`` relative to ``max |J|`` accepted as symmetric."""


def check_inertia_tensor(rows: tuple[tuple[float, float, float], ...]) -> tuple[tuple[float, float, float], ...]:
    """Validate a full inertia tensor ([Doerr2021] Eq. 35b with products of inertia).

    Parameters
    ----------
    rows : tuple of three 3-tuples
        ``J`` [kg·m²] about the centre of mass, body frame.

    Returns
    -------
    tuple
        ``rows`` unchanged.

    Raises
    ------
    PydanticCustomError
        Not symmetric, not positive definite, or its principal moments break ``I1 + I2 >= I3`` (any order).
    """
    j = np.asarray(rows, dtype=float)
    scale = float(np.max(np.abs(j)))
    if scale <= 0.0 or np.max(np.abs(j - j.T)) > SYMMETRY_RTOL * scale:
        raise PydanticCustomError("oacli_matrix", "must be symmetric (J = Jᵀ) and non-zero")
    moments = np.linalg.eigvalsh(0.5 * (j + j.T))
    if moments[0] <= 0.0:
        raise PydanticCustomError("oacli_matrix", "must be positive definite (smallest principal moment {m} kg·m²)",
                                  {"m": f"{moments[0]:.3g}"})
    if moments[0] + moments[1] < moments[2] * (1.0 - 1e-12):
        raise PydanticCustomError("oacli_inertia", "principal moments {m} break the triangle inequality I1 + I2 >= I3 "
                                  "(no rigid body has them)", {"m": str(np.round(moments, 6).tolist())})
    return rows


InertiaTensor = Annotated[tuple[Vector3, Vector3, Vector3], BeforeValidator(sequence_of(3)),
                          AfterValidator(check_inertia_tensor)]

SaturationFraction = Annotated[Real, Field(gt=0, le=1)]


class StallConfig(Section):
    """A stalled controller: the actuators hold the last command from ``start_s`` for ``duration_s``."""

    start_s: NonNegativeReal = Field(default=0.0, description="Stage time at which the stall starts [s], >= 0.")
    duration_s: NonNegativeReal = Field(default=0.0, description="Length of the stall [s], >= 0 (0: no stall).")


class FaultsConfig(Section):
    """Actuator saturation and controller stall faults ([ReSWARM2023] §5.4, §6.2.1); off by default."""

    actuator_saturation: Annotated[
        tuple[SaturationFraction, SaturationFraction, SaturationFraction, SaturationFraction, SaturationFraction,
              SaturationFraction], BeforeValidator(sequence_of(6, broadcast=True))] = Field(
        default=(1.0, 1.0, 1.0, 1.0, 1.0, 1.0),
        description="Per axis [force x, y, z, torque x, y, z], the fraction of the robot's input limit the "
                    "actuators deliver, in (0, 1]; 1 = healthy. Unmodelled: the command is recorded as applied.")
    controller_stall: Annotated[StallConfig, none_to({})] = Field(
        default_factory=StallConfig, description="The actuators hold the last command for a while (off: duration 0).")

    @model_validator(mode="after")
    def _finite(self) -> FaultsConfig:
        if self.controller_stall.start_s > 1e6 or self.controller_stall.duration_s > 1e6:
            raise PydanticCustomError("oacli_range", "controller_stall: times above 1e6 s")
        return self

    def delivered_fraction(self) -> np.ndarray | None:
        """The saturation fractions as an array, or None when every axis is healthy."""
        frac = np.asarray(self.actuator_saturation, dtype=float)
        return None if np.all(frac == 1.0) else frac


__all__ = ["FaultsConfig", "InertiaTensor", "StallConfig", "check_inertia_tensor"]
