"""The closed-loop simulation (``simulation``) and the measurement noise (``sensors``).

``sensors`` first gives the noise on the state handed to the controller (``/state/measured``). Its ``imu`` and
``localisation`` sub-sections add the measurements as flown ([ReSWARM2023] §5.4.2-§5.4.3, §6.2.1): an IMU at the
plant rate with bias, and localisation messages at their own rate with jumps, drops and delays. Both are off by
default, so a config without them gives the same numbers as before they existed.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import NonNegativeReal, Position3, PositiveReal, Real, Section, none_to

Probability = Annotated[Real, Field(ge=0, le=1)]


class ImuConfig(Section):
    """A simulated IMU at the plant rate (62.5 Hz on Astrobee): specific force and angular rate, body frame.

    Each reading is the true value plus a bias plus white noise. The bias starts at a draw of ``N(0, bias_std²)``
    per axis and then follows a random walk of intensity ``bias_random_walk`` (0: constant).
    """

    enabled: bool = Field(default=False, description="Simulate the IMU and write /imu (default off).")
    accelerometer_noise_std_mps2: NonNegativeReal = Field(
        default=0.0, description="White noise std of each specific-force reading per axis [m/s²], >= 0 (rattle R "
        "linear acceleration variance 5e-6: 0.00224).")
    gyro_noise_std_radps: NonNegativeReal = Field(
        default=0.0, description="White noise std of each angular-rate reading per axis [rad/s], >= 0.")
    accelerometer_bias_std_mps2: NonNegativeReal = Field(
        default=0.0, description="Std of the initial accelerometer bias per axis [m/s²], >= 0.")
    gyro_bias_std_radps: NonNegativeReal = Field(
        default=0.0, description="Std of the initial gyro bias per axis [rad/s], >= 0.")
    accelerometer_bias_random_walk: NonNegativeReal = Field(
        default=0.0, description="Accelerometer bias random walk [m/s²/√s], >= 0 (0: constant bias).")
    gyro_bias_random_walk: NonNegativeReal = Field(
        default=0.0, description="Gyro bias random walk [rad/s/√s], >= 0 (0: constant bias).")


class LocalisationConfig(Section):
    """Simulated localisation messages (the full measured state, as Astrobee's EKF publishes it) at their own rate.

    The noise is the parent ``sensors`` section's. Each message independently jumps (probability
    ``jump_probability``; position by a random direction times a magnitude uniform in ``jump_position_m``, attitude
    about a random axis by an angle uniform in ``jump_attitude_rad``), is dropped (``drop_probability``) or is
    delayed (``delay_probability``; delay exponential with mean ``delay_mean_s``): a delayed message is written when
    it arrives, after later ones, with its true stamp.
    """

    enabled: bool = Field(default=False, description="Simulate localisation and write /localisation (default off).")
    rate_hz: PositiveReal = Field(default=5.0, description="Localisation message rate [Hz], > 0.")
    jump_probability: Probability = Field(default=0.0, description="Probability that a message jumps, in [0, 1].")
    jump_position_m: tuple[NonNegativeReal, NonNegativeReal] = Field(
        default=(0.1, 0.3), description="Range [min, max] of the position jump [m] ([ReSWARM2023] Fig. 21).")
    jump_attitude_rad: tuple[NonNegativeReal, NonNegativeReal] = Field(
        default=(0.05, 0.2), description="Range [min, max] of the attitude jump [rad].")
    drop_probability: Probability = Field(default=0.0, description="Probability that a message is lost, in [0, 1].")
    delay_probability: Probability = Field(
        default=0.0, description="Probability that a message is delayed (arrives after later ones), in [0, 1].")
    delay_mean_s: NonNegativeReal = Field(default=0.5, description="Mean of the exponential delay [s], >= 0.")

    @model_validator(mode="after")
    def _ranges(self) -> LocalisationConfig:
        for name in ("jump_position_m", "jump_attitude_rad"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise PydanticCustomError("oacli_range", f"{name}: min {lo} > max {hi}")
        return self


class SensorsConfig(Section):
    """Standard deviations of zero-mean Gaussian measurement noise on the state handed to the controller, and the
    optional flight-like IMU and localisation streams."""

    position_std_m: NonNegativeReal = Field(default=0.0, description="Position noise std per axis [m], >= 0.")
    velocity_std_mps: NonNegativeReal = Field(default=0.0, description="Velocity noise std per axis [m/s], >= 0.")
    attitude_std_rad: NonNegativeReal = Field(
        default=0.0, description="Attitude noise std per axis (small rotation vector) [rad], >= 0."
    )
    angular_velocity_std_radps: NonNegativeReal = Field(
        default=0.0, description="Angular velocity noise std per axis [rad/s], >= 0."
    )
    imu: Annotated[ImuConfig, none_to({})] = Field(
        default_factory=ImuConfig, description="Simulated IMU at the plant rate (off by default).")
    localisation: Annotated[LocalisationConfig, none_to({})] = Field(
        default_factory=LocalisationConfig, description="Simulated localisation messages (off by default).")


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
    "ImuConfig",
    "LocalisationConfig",
    "SensorsConfig",
    "SimulationConfig",
]
