"""The campaign file (``oacli campaign``): a base config, dispersions, flight fault models, runs and a seed.

A campaign flies one job (``mission``, ``track`` or ``closed-loop``) ``runs`` times. Run ``k`` takes the base
config (``base``, a path relative to the campaign file, deep-merged with ``set``), draws its dispersions and
faults from named sub-streams of ``numpy.random.SeedSequence(seed, spawn_key=(k, ...))``
(:mod:`oacli.campaign.sampling`) and writes them into its own config. Dispersions are relative to the base values
(1σ of a normal, in percent or SI units); each fault model strikes a run with its ``probability`` and then sets the
matching config section ([ReSWARM2023] §5.4, §6.2.1: localisation jumps, dropped, delayed and out-of-order
measurements, per-axis actuator scale errors and saturation, a stalled controller).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import (
    Name,
    NonNegativeReal,
    NonNegativeVector3,
    PositiveReal,
    Real,
    Section,
    StrictInt,
    none_to,
    sequence_of,
)
from oacli.config.outputs import CampaignOutputsConfig

Probability = Annotated[Real, Field(ge=0, le=1)]
Range = tuple[NonNegativeReal, NonNegativeReal]
MAX_RUNS = 100_000
"""Most runs one campaign may ask for (the manifest and plots stay readable)."""

JobKind = Literal["mission", "track", "closed-loop", "excite-estimate"]
"""``mission``: ``oacli mission`` per run (the flight's setting); ``track``: the ``track`` stage with its files;
``excite-estimate``: ``excite``, ``track`` of the excitation, ``estimate`` (a RATTLE flight and its estimator);
``closed-loop``: the tracking controller and the truth plant only, no files (cheap: statistics of the controller
alone, and the tests)."""

InjectKind = Literal["raise", "exit", "oom", "hang"]


def _check_range(name: str, value: tuple[float, float]) -> None:
    if value[0] > value[1]:
        raise PydanticCustomError("oacli_range", f"{name}: min {value[0]} > max {value[1]}")


def _broadcast6(value: Any) -> Any:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (value,) * 6
    return sequence_of(6)(value)


class DispersionsConfig(Section):
    """1σ of the dispersions, relative to the base config's values (0: not dispersed). Every draw is normal, or,
    with ``distribution: uniform``, uniform over ± the value (an envelope: docs/mission.md)."""

    distribution: Literal["normal", "uniform"] = Field(
        default="normal", description="normal: each value is 1σ of a normal draw; uniform: the half-width of a "
        "uniform draw (principal_axes_rad: the largest rotation angle, about a uniformly drawn axis; inertias "
        "breaking a triangle inequality are drawn again).")

    mass_pct: NonNegativeReal = Field(
        default=0.0, description="Plant mass (robot + payload after the grasp) [% of the base value].")
    inertia_pct: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Principal inertias Ixx, Iyy, Izz [% of the base values].")
    principal_axes_rad: NonNegativeReal = Field(
        default=0.0, description="Misalignment of the payload's principal axes (rotation vector per axis) [rad]: "
        "gives the plant a full inertia tensor R diag(I) Rᵀ with products of inertia (truth.inertia_tensor_kgm2).")
    com_offset_m: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Centre-of-mass offset added to the base's, body frame [m].")
    sensor_noise_pct: NonNegativeReal = Field(
        default=0.0, description="Common scale factor of every sensors.*_std (log-normal, 1σ in %).")
    initial_position_m: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Initial position offset per axis [m] (simulation.initial_offset_m).")
    actuator_scale_pct: Annotated[tuple[NonNegativeReal, ...], BeforeValidator(_broadcast6)] = Field(
        default=(0.0,) * 6, description="Per-axis actuator scale error [% of 1] (truth.actuator_scale, clipped "
        "to [0.5, 1.5]); one number for every axis.")


class FaultModel(Section):
    """A flight fault: each run suffers it with ``probability``."""

    probability: Probability = Field(default=0.0, description="Fraction of the runs with this fault, in [0, 1].")


class LocalisationJumps(FaultModel):
    """Localisation jumps ([ReSWARM2023] §5.4.2, Fig. 21): sensors.localisation.jump_* ."""

    rate: Probability = Field(default=0.02, description="Probability that a localisation message jumps.")
    position_m: Range = Field(default=(0.1, 0.3), description="Range of the position jump [m].")
    attitude_rad: Range = Field(default=(0.05, 0.2), description="Range of the attitude jump [rad].")


class DroppedMeasurements(FaultModel):
    """Lost localisation messages: sensors.localisation.drop_probability."""

    rate: Probability = Field(default=0.05, description="Probability that a localisation message is lost.")


class DelayedMeasurements(FaultModel):
    """Delayed, hence out-of-order, localisation messages: sensors.localisation.delay_*."""

    rate: Probability = Field(default=0.05, description="Probability that a message is delayed.")
    mean_delay_s: NonNegativeReal = Field(default=0.5, description="Mean of the exponential delay [s].")


class ActuatorScaleErrors(FaultModel):
    """Per-axis thrust scale errors on top of the dispersion ([ReSWARM2023] §5.3: impeller thrust varies)."""

    std_pct: NonNegativeReal = Field(default=5.0, description="1σ of the extra per-axis scale error [%].")


class ActuatorSaturation(FaultModel):
    """One actuator axis (drawn uniformly) delivers only a fraction of its limit (faults.actuator_saturation)."""

    fraction: Range = Field(default=(0.3, 0.8), description="Range of the delivered fraction of the limit.")

    @model_validator(mode="after")
    def _fraction(self) -> ActuatorSaturation:
        if not 0.0 < self.fraction[0] <= self.fraction[1] <= 1.0:
            raise PydanticCustomError("oacli_range", "fraction: must satisfy 0 < min <= max <= 1")
        return self


class ControllerStall(FaultModel):
    """The command bus stalls and the actuators hold the last command (faults.controller_stall)."""

    start_s: Range = Field(default=(2.0, 20.0), description="Range of the stall's start, stage time [s].")
    duration_s: Range = Field(default=(0.5, 3.0), description="Range of the stall's length [s].")


class CampaignFaults(Section):
    """The flight fault models ([ReSWARM2023] §5.4, §6.2.1); each strikes a run with its probability."""

    localisation_jumps: Annotated[LocalisationJumps, none_to({})] = Field(default_factory=LocalisationJumps)
    dropped_measurements: Annotated[DroppedMeasurements, none_to({})] = Field(default_factory=DroppedMeasurements)
    delayed_measurements: Annotated[DelayedMeasurements, none_to({})] = Field(default_factory=DelayedMeasurements)
    actuator_scale_errors: Annotated[ActuatorScaleErrors, none_to({})] = Field(default_factory=ActuatorScaleErrors)
    actuator_saturation: Annotated[ActuatorSaturation, none_to({})] = Field(default_factory=ActuatorSaturation)
    controller_stall: Annotated[ControllerStall, none_to({})] = Field(default_factory=ControllerStall)

    @model_validator(mode="after")
    def _ranges(self) -> CampaignFaults:
        _check_range("localisation_jumps.position_m", self.localisation_jumps.position_m)
        _check_range("localisation_jumps.attitude_rad", self.localisation_jumps.attitude_rad)
        _check_range("controller_stall.start_s", self.controller_stall.start_s)
        _check_range("controller_stall.duration_s", self.controller_stall.duration_s)
        return self


class FlightFigures(Section):
    """The flight's estimation errors to compare against ([ReSWARM2023] RATTLE table)."""

    mass_pct: NonNegativeReal = Field(default=0.39, description="Flight mass error [%].")
    inertia_pct: NonNegativeVector3 = Field(default=(0.91, 1.35, 6.92), description="Flight Ixx, Iyy, Izz errors [%].")


CellLevels = dict[Annotated[str, Field(min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_.%+-]+$")],
                  Annotated[dict[str, Any], none_to({})]]
"""A factor's levels: level name -> overrides of the base config (nested, or dotted keys ``mission.prior.mass_kg``)."""


class CampaignConfig(Section):
    """``oacli campaign``: Monte Carlo runs of one job over dispersed conditions and flight faults."""

    name: Name = Field(default="campaign", description="Campaign name (folder prefix), [A-Za-z0-9_.-]+.")
    seed: Annotated[StrictInt, Field(ge=0)] = Field(default=0, description="Campaign seed, >= 0.")
    runs: Annotated[StrictInt, Field(ge=1, le=MAX_RUNS)] = Field(description=f"Number of runs, 1..{MAX_RUNS}.")
    job: JobKind = Field(default="mission",
                         description="What each run flies: mission | track | closed-loop | excite-estimate.")
    base: str = Field(description="Base config file (a mission config for job 'mission'), relative to this file.")
    set: Annotated[dict[str, Any], none_to({})] = Field(
        default_factory=dict, description="Overrides deep-merged into the base config before any dispersion.")
    dispersions: Annotated[DispersionsConfig, none_to({})] = Field(default_factory=DispersionsConfig)
    faults: Annotated[CampaignFaults, none_to({})] = Field(default_factory=CampaignFaults)
    timeout_s: PositiveReal = Field(
        default=3600.0, description="Wall time of one run before it counts as an infrastructure failure [s].")
    memory_limit_mb: Annotated[StrictInt, Field(ge=0)] = Field(
        default=0, description="Address-space limit of a local worker process [MiB] (0: none); a run that "
        "exceeds it is an out-of-memory infrastructure failure.")
    max_retries: Annotated[StrictInt, Field(ge=0, le=10)] = Field(
        default=2, description="Retries of a run after a worker death, timeout or out-of-memory.")
    flight: Annotated[FlightFigures, none_to({})] = Field(default_factory=FlightFigures)
    grid: Annotated[dict[Name, CellLevels], none_to({})] = Field(
        default_factory=dict, description="Study cells: factor -> level -> overrides of the base config. The cells "
        "are the product of the levels (in file order); run k flies cell k mod (number of cells), so 'runs' is the "
        "total and a study needs runs = seeds per cell x cells. Runs of one replicate (k div cells) share their draws "
        "and seed (a paired design). Summary: per cell, medians with distribution-free 95 % intervals.")
    outputs: Annotated[CampaignOutputsConfig, none_to({})] = Field(default_factory=CampaignOutputsConfig)
    inject: Annotated[dict[Annotated[int, Field(ge=0)], InjectKind], none_to({})] = Field(
        default_factory=dict, description="Testing aid: break run k on purpose (raise | exit | oom | hang) to check "
        "failure isolation; 'exit', 'oom' and 'hang' strike every attempt.")

    @model_validator(mode="after")
    def _grid(self) -> CampaignConfig:
        for factor, levels in self.grid.items():
            if not levels:
                raise PydanticCustomError("oacli_grid", f"grid.{factor}: needs at least one level")
        return self


__all__ = ["CampaignConfig", "CampaignFaults", "DispersionsConfig", "JobKind"]
