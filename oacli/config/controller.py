"""The tracking controller (``controller``): standard MPC, or robust tube MPC with the settings of
:mod:`oacli.config.tube`."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from oacli.config.fields import (
    NonNegativeReal,
    PositiveReal,
    Section,
    StrictBool,
    StrictInt,
    Weight3,
    none_to,
    read_only,
)
from oacli.config.tube import TubeConfig

MAX_HORIZON = 500
"""Largest accepted MPC horizon [steps]."""


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
        return read_only(self.position + self.velocity + self.attitude + self.angular_velocity)

    def input_weights(self) -> np.ndarray:
        """Diagonal of R for ``[force (3), torque (3)]``, shape (6,), read-only."""
        return read_only(self.force + self.torque)


ControllerType = Literal["mpc", "tube"]
"""Controller kinds: ``"mpc"`` (standard MPC) and ``"tube"`` (robust tube MPC, settings in ``controller.tube``)."""


class EstimateConfig(Section):
    """The standard MPC's state estimate (``controller.estimate``): the measured state or a steady-state Kalman
    filter's estimate, and the margin of the workspace rows for its error (oacli.control.tracking)."""

    observer: StrictBool = Field(
        default=True,
        description="Act on a steady-state Kalman filter's estimate of position and velocity (the tube's "
        "observer, oacli.control.observer; Astrobee's controller acts on its EKF's) instead of the raw "
        "measurement; used when sensors.position_std_m and velocity_std_mps are both > 0 (else the measurement).",
    )
    accel_std_mps2: PositiveReal = Field(
        default=0.01, description="σ of the filter's white process acceleration [m/s²], > 0 (model error).",
    )
    margin_sigmas: NonNegativeReal = Field(
        default=3.0,
        description="The workspace rows keep the TRUE position clear at this many σ of the error of the next "
        "position predicted from the estimate (sensors' σ, or the filter's covariance), >= 0; 0: the rows bound "
        "the estimate only.",
    )
    min_margin_m: NonNegativeReal = Field(
        default=0.002,
        description="Floor of that margin per axis [m], >= 0, kept with exact sensors too: with none, the soft "
        "rows, their linearisation and the motion between control instants let the true position graze a "
        "keep-out zone by ~0.01 mm (1 of 8 ideal-sensor seeds of configs/mission_iss.yaml's segment 1).",
    )


class ControllerConfig(Section):
    """The tracking controller."""

    type: ControllerType = Field(
        default="mpc", description="Controller kind: 'mpc' (standard MPC) or 'tube' (robust tube MPC)."
    )
    rate_hz: PositiveReal = Field(default=5.0, description="Control update rate [Hz], > 0.")
    horizon: Annotated[StrictInt, Field(ge=1, le=MAX_HORIZON)] = Field(
        default=10, description=f"Prediction horizon [steps of 1/rate_hz s], 1..{MAX_HORIZON}."
    )
    weights: Annotated[ControllerWeights, none_to({})] = Field(
        default_factory=ControllerWeights, description="Diagonal cost weights."
    )
    max_consecutive_failures: Annotated[StrictInt, Field(ge=1)] = Field(
        default=5,
        description="Consecutive failed solves tolerated [-], >= 1; then a latched safe hold (brake to rest, hold "
        "the attitude; see oacli.control.tracking and oacli.control.tube_mpc).",
    )
    position_constraints: StrictBool = Field(
        default=True,
        description="Keep the predicted positions in the keep-in boxes (shrunk by environment.keep_in_margin_m) "
        "and out of the "
        "keep-out zones (grown by it): soft rows in the standard MPC, hard rows tightened by the tube in the tube "
        "MPC (oacli.control.workspace). false: positions are free.",
    )
    estimate: Annotated[EstimateConfig, none_to({})] = Field(
        default_factory=EstimateConfig,
        description="The standard MPC's state estimate and the margin its workspace rows keep for its error.",
    )
    tube: Annotated[TubeConfig, none_to({})] = Field(
        default_factory=TubeConfig, description="Robust tube MPC settings (used when type is 'tube')."
    )
    rate_margin: Annotated[NonNegativeReal, Field(lt=0.9)] = Field(
        default=0.0,
        description="Share of robot.angular_velocity_limit_radps the controller keeps free, in [0, 0.9): its "
        "attitude MPC constrains the predicted rate to (1 - rate_margin) x the limit, so a plant whose inertia "
        "differs from the model's overshoots into the margin, not past the limit (the safety check still uses the "
        "limit itself). The mission sets it from the model's inertia σ (mission.rate_margin_sigmas).",
    )

    @property
    def period_s(self) -> float:
        """Control period [s]."""
        return 1.0 / self.rate_hz


__all__ = [
    "MAX_HORIZON",
    "ControllerConfig",
    "ControllerType",
    "ControllerWeights",
    "EstimateConfig",
]
