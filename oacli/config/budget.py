"""The resource estimate of a run, checked against a documented budget before anything runs (``docs/records.md``).

:mod:`oacli.config.sizes` caps the number of simulation steps a duration and a rate imply; this module estimates
what a run then costs and refuses a config whose estimate exceeds the budget, with exit 2 and one line per field
that asks for it:

* **memory of the largest problem** [MiB]: the tracking MPC's condensed QP grows with the square of
  ``controller.horizon`` N. Measured with ``/usr/bin/time`` on ``configs/iss_reswarm.yaml`` (peak resident set of
  ``oacli track``): 263 MiB at N = 10, 648 MiB at N = 200, 1887 MiB at N = 400, i.e. about
  :data:`BASE_MEMORY_MB` + :data:`MPC_MB_PER_HORIZON_SQ` × N² (N = 500: about 2.9 GiB);
* **steps**: control steps (simulated time × ``controller.rate_hz``) and plant steps per control step
  (``simulation.plant_rate_hz`` / ``controller.rate_hz``: a rate of 1e-300 Hz would ask for 1e302 plant steps
  between two control updates); the excitation's simulated time (``excitation.duration_s``,
  ``excitation.rattle.duration_s``) at the plant rate, as for the tracked run;
* **file sizes** [MiB]: the stage's MCAP and Rerun recording, about :data:`OUTPUT_BYTES_PER_PLANT_STEP` bytes per
  plant step (measured: 1.30 MB for the 2775 plant steps of ``configs/iss_reswarm.yaml``).

The budget defaults to :data:`DEFAULT_MEMORY_BUDGET_MB` MiB of memory and :data:`DEFAULT_DISK_BUDGET_MB` MiB of
output per stage; the environment variables ``OACLI_MEMORY_BUDGET_MB`` and ``OACLI_DISK_BUDGET_MB`` override it
(a positive number of MiB) for a machine with more (or less) room.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

from oacli.errors import ConfigError

DEFAULT_MEMORY_BUDGET_MB = 2048.0
"""Memory a run may use by default [MiB] (override: ``OACLI_MEMORY_BUDGET_MB``)."""

DEFAULT_DISK_BUDGET_MB = 2048.0
"""Output one stage may write by default [MiB] (override: ``OACLI_DISK_BUDGET_MB``)."""

BASE_MEMORY_MB = 270.0
"""Resident memory of a small ``oacli track`` [MiB] (interpreter, numpy, solvers, recordings)."""

MPC_MB_PER_HORIZON_SQ = 0.0105
"""Memory of the condensed tracking QP per squared horizon step [MiB / step²] (measured, module docstring)."""

MAX_PLANT_STEPS_PER_CONTROL = 100_000
"""Most plant steps between two control updates (``simulation.plant_rate_hz / controller.rate_hz``)."""

OUTPUT_BYTES_PER_PLANT_STEP = 500.0
"""MCAP + Rerun bytes a tracked run writes per plant step [bytes] (measured, module docstring)."""

Problem = tuple[tuple[str | int, ...], Any, str]


@dataclass(frozen=True)
class Budget:
    """What a run may use: memory [MiB] and output of one stage [MiB]."""

    memory_mb: float = DEFAULT_MEMORY_BUDGET_MB
    disk_mb: float = DEFAULT_DISK_BUDGET_MB


def _env_mb(name: str, default: float) -> float:
    text = os.environ.get(name)
    if text is None or not text.strip():
        return default
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"{name}={text!r}: must be a positive number of MiB") from None
    if not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{name}={text!r}: must be a positive number of MiB")
    return value


def budget_from_env() -> Budget:
    """The budget: the defaults, overridden by ``OACLI_MEMORY_BUDGET_MB`` / ``OACLI_DISK_BUDGET_MB``.

    Raises
    ------
    ConfigError
        A variable that is not a positive number.
    """
    return Budget(_env_mb("OACLI_MEMORY_BUDGET_MB", DEFAULT_MEMORY_BUDGET_MB),
                  _env_mb("OACLI_DISK_BUDGET_MB", DEFAULT_DISK_BUDGET_MB))


@dataclass(frozen=True)
class Estimate:
    """A run's estimated cost (module docstring).

    Attributes
    ----------
    memory_mb : float
        Peak memory [MiB] (the tracking MPC's QP).
    control_steps : float
        Control updates of the tracked run.
    plant_steps_per_control : float
        Plant steps between two control updates.
    output_mb : float
        MCAP + Rerun recording of the tracked run [MiB].
    """

    memory_mb: float
    control_steps: float
    plant_steps_per_control: float
    output_mb: float


def estimate(cfg: Any, duration_s: float) -> Estimate:
    """The cost of tracking for ``duration_s`` [s] (reference + settle time) with ``cfg``'s controller and plant.

    Parameters
    ----------
    cfg : OacliConfig
        The config.
    duration_s : float
        Simulated time [s].

    Returns
    -------
    Estimate
    """
    horizon = float(cfg.controller.horizon)
    rate = float(cfg.controller.rate_hz)
    plant_rate = float(cfg.simulation.plant_rate_hz)
    return Estimate(
        memory_mb=BASE_MEMORY_MB + MPC_MB_PER_HORIZON_SQ * horizon**2,
        control_steps=duration_s * rate,
        plant_steps_per_control=plant_rate / rate if rate > 0 else math.inf,
        output_mb=duration_s * plant_rate * OUTPUT_BYTES_PER_PLANT_STEP / 2**20,
    )


def budget_problems(cfg: Any, duration_s: float, duration_field: tuple[str, ...]) -> list[Problem]:
    """The fields of ``cfg`` whose run would exceed the budget (module docstring), one problem each.

    Parameters
    ----------
    cfg : OacliConfig
        The config.
    duration_s : float
        The tracked run's simulated time [s] (reference + settle time; the settle time alone for a file reference).
    duration_field : tuple of str
        The field that sets most of ``duration_s`` (named when the output would be too large).

    Returns
    -------
    list of (loc, value, reason)
    """
    budget = budget_from_env()
    problems: list[Problem] = []
    est = estimate(cfg, duration_s)
    override = "(budget: oacli.config.budget; override with {var})"
    if est.memory_mb > budget.memory_mb:
        problems.append((("controller", "horizon"), cfg.controller.horizon,
                         f"the tracking MPC would need about {est.memory_mb:.0f} MiB, more than the "
                         f"{budget.memory_mb:.0f} MiB budget "
                         + override.format(var="OACLI_MEMORY_BUDGET_MB")))
    if est.plant_steps_per_control > MAX_PLANT_STEPS_PER_CONTROL:
        problems.append((("controller", "rate_hz"), cfg.controller.rate_hz,
                         f"a control period of {1.0 / cfg.controller.rate_hz:.3g} s is "
                         f"{est.plant_steps_per_control:.3g} plant steps of 1/simulation.plant_rate_hz, more than "
                         f"the {MAX_PLANT_STEPS_PER_CONTROL} allowed (oacli.config.budget)"))
    if est.output_mb > budget.disk_mb:
        problems.append((duration_field, _value(cfg, duration_field),
                         f"the run would write about {est.output_mb:.0f} MiB of recordings ({duration_s:.4g} s at "
                         f"{cfg.simulation.plant_rate_hz:g} Hz), more than the {budget.disk_mb:.0f} MiB budget "
                         + override.format(var="OACLI_DISK_BUDGET_MB")))
    return problems


def excitation_problems(cfg: Any, max_steps: int, steps_message: Any) -> list[Problem]:
    """The excitation's simulated times (``excitation.duration_s``, ``excitation.rattle.duration_s``) against the
    step cap and the disk budget, at the plant rate (the excitation is flown like a tracked run)."""
    exc = getattr(cfg, "excitation", None)
    if exc is None:
        return []
    budget = budget_from_env()
    rate = float(cfg.simulation.plant_rate_hz)
    problems: list[Problem] = []
    candidates: list[tuple[tuple[str, ...], float]] = [(("excitation", "duration_s"), float(exc.duration_s))]
    rattle = getattr(exc, "rattle", None)
    if rattle is not None:
        candidates.append((("excitation", "rattle", "duration_s"), float(rattle.duration_s)))
    for loc, duration in candidates:
        if duration * rate > max_steps:
            problems.append((loc, duration, steps_message(duration, rate)))
        elif duration * rate * OUTPUT_BYTES_PER_PLANT_STEP / 2**20 > budget.disk_mb:
            mb = duration * rate * OUTPUT_BYTES_PER_PLANT_STEP / 2**20
            problems.append((loc, duration, f"the excitation would write about {mb:.0f} MiB of recordings, more "
                                            f"than the {budget.disk_mb:.0f} MiB budget (oacli.config.budget; "
                                            "override with OACLI_DISK_BUDGET_MB)"))
    return problems


def _value(cfg: Any, loc: tuple[str, ...]) -> Any:
    value = cfg
    for part in loc:
        value = getattr(value, part, None)
    return value
