"""The closed-loop simulation (``simulation``) and the measurement noise (``sensors``)."""

from __future__ import annotations

from pydantic import Field

from oacli.config.fields import NonNegativeReal, Position3, PositiveReal, Section


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
    initial_offset_m: Position3 = Field(
        default=(0.0, 0.0, 0.0), description="Offset of the initial true position from the reference start [m]."
    )

    @property
    def plant_period_s(self) -> float:
        """Plant integration step [s]."""
        return 1.0 / self.plant_rate_hz


__all__ = [
    "SensorsConfig",
    "SimulationConfig",
]
