"""The ``controller.tube`` section: robust tube MPC settings (used when ``controller.type`` is ``tube``).

Defaults follow the ReSWARM flight settings ([RattleCode] ``casadi_nmpc``/``z_poly_calc``):
ancillary LQR Q = diag(5, 10), R = 2; W from the 2σ mass bounds ([Doerr2021] Eq. 28). The invariant set differs:
the flight code's absolute ε = 0.005 (``rpi_epsilon_mode: absolute``) almost doubles a tube of a few millimetres,
so the default ε is relative, ``F_∞ ⊆ Z ⊆ 1.05 F_∞`` for the set in use ([Rakovic2005]).
Imported by :mod:`oacli.config.models` (import ``oacli.config``, not this module, to load it).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import Field

from oacli.config.fields import (
    Fraction,
    NonNegativeReal,
    NonNegativeVector3,
    PositiveReal,
    PositiveVector3,
    Section,
    StrictBool,
    StrictInt,
    Weight3,
    none_to,
)
from oacli.model.robot_model import RobotModel


class TubeTerminalWeights(Section):
    """Diagonal terminal weight of the nominal translation MPC ([Doerr2021] Eq. 24, the matrix H)."""

    position: Weight3 = Field(default=(100.0, 100.0, 100.0), description="Terminal position weight [1/m²], > 0.")
    velocity: Weight3 = Field(default=(10.0, 10.0, 10.0), description="Terminal velocity weight [s²/m²], > 0.")


class AncillaryConfig(Section):
    """Discrete LQR weights of the ancillary law u = v + K (x − z), the same on every axis."""

    position: PositiveReal = Field(default=5.0, description="Q position weight [1/m²], > 0 (ReSWARM: 5).")
    velocity: PositiveReal = Field(default=10.0, description="Q velocity weight [s²/m²], > 0 (ReSWARM: 10).")
    force: PositiveReal = Field(default=2.0, description="R force weight [1/N²], > 0 (ReSWARM: 2).")


class TubeDisturbanceConfig(Section):
    """What the disturbance set W per control step is made of (summed per world axis)."""

    mass_sigmas: PositiveReal = Field(
        default=2.0,
        description="Mass interval half-width in σ (Eq. 28: 2): W gains the one-step deviation at the tube force "
        "limit between the model mass and mass ± mass_sigmas·σ_m ([Doerr2021] Eq. 28), σ_m = sqrt(robot.variance[0]) "
        "(the model's; 0: no mass term).",
    )
    force_N: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Bound of an external force per world axis [N], >= 0."
    )
    position_m: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Extra position disturbance per control step [m], >= 0."
    )
    velocity_mps: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Extra velocity disturbance per control step [m/s], >= 0."
    )
    position_noise_m: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Bound of the position measurement noise [m], >= 0."
    )
    velocity_noise_mps: NonNegativeVector3 = Field(
        default=(0.0, 0.0, 0.0), description="Bound of the velocity measurement noise [m/s], >= 0."
    )
    on_empty_tightening: Literal["error", "scale_w"] = Field(
        default="error",
        description="When W is too large for the limits: 'error' stops (exit 3); 'scale_w' shrinks W of that axis "
        "(the guarantee then covers the smaller W only; the factor is logged and reported).",
    )
    min_nominal_fraction: Annotated[PositiveReal, Field(lt=1)] = Field(
        default=0.1, description="With scale_w: fraction of each limit left to the nominal MPC, in (0, 1)."
    )


class ObserverConfig(Section):
    """Output-feedback tube MPC ([Mayne2006]): a steady-state observer in the loop and its estimation-error set."""

    enabled: StrictBool = Field(
        default=False,
        description="Act on an observer's estimate instead of the measured state; the tube then promises "
        "z ⊕ T for the true state under sensor noise bounded at noise_sigmas σ (oacli.sets.error_set).",
    )
    noise_sigmas: PositiveReal = Field(
        default=3.0,
        description="Sensor noise bound of the error set, in σ of the sensors section [-], > 0; a sample beyond it "
        "is counted (summary tube.noise_beyond_bound) against the number the Gaussian tail predicts.",
    )
    gain: Annotated[tuple[Fraction, Fraction] | None, none_to(None)] = Field(
        default=None,
        description="Diagonal Luenberger gain [position, velocity] in (0, 1] (filter form); default: the "
        "steady-state Kalman gain for accel_std_mps2 and the sensors' σ.",
    )
    accel_std_mps2: PositiveReal = Field(
        default=0.01, description="σ of the Kalman filter's white process acceleration [m/s²], > 0."
    )
    rate_gain: Annotated[Fraction | None, none_to(None)] = Field(
        default=None,
        description="Gain in (0, 1] of a body-rate observer (Euler's equations, oacli.control.observer.RateObserver)"
        " whose estimate the attitude MPC uses; none: the measured rate. No set is claimed for attitude.",
    )


class TubeConfig(Section):
    """Robust tube MPC: translation by tube MPC, attitude by standard MPC, one QP per step."""

    prediction_step_s: PositiveReal | None = Field(
        default=None,
        description="Step of the nominal MPC model [s]; an integer multiple of the control period (ReSWARM: "
        "1.0 s at a 0.2 s control period). Default: the control period.",
    )
    force_limit_N: PositiveVector3 | None = Field(
        default=None,
        description="Force limit U of the tube per world axis [N], <= robot.force_limit_N (ReSWARM: 0.15). "
        "Default: robot.force_limit_N.",
    )
    terminal: Annotated[TubeTerminalWeights | None, none_to(None)] = Field(
        default=None, description="Diagonal terminal weights; default: the discrete Riccati solution."
    )
    ancillary: Annotated[AncillaryConfig, none_to({})] = Field(
        default_factory=AncillaryConfig, description="Ancillary LQR weights."
    )
    disturbance: Annotated[TubeDisturbanceConfig, none_to({})] = Field(
        default_factory=TubeDisturbanceConfig, description="The disturbance set W."
    )
    rpi_epsilon: PositiveReal = Field(
        default=0.05,
        description="Accuracy ε of the invariant set Z > 0. rpi_epsilon_mode relative: Z (the lasso in use, after "
        "facet reduction) lies within (1 + ε) times the minimal invariant set F_∞, in every direction [-]; "
        "absolute: Raković et al. 2005's F(α, s) ⊆ F_∞ ⊕ ε·B_∞ [m, m/s] (ReSWARM flight code: 0.005).",
    )
    rpi_epsilon_mode: Literal["relative", "absolute"] = Field(
        default="relative",
        description="'relative' (default): ε scales F_∞; 'absolute': the paper's ∞-norm ball radius (reproduces "
        "published examples and the flight settings).",
    )
    rpi_max_terms: Annotated[StrictInt, Field(ge=1, le=2000)] = Field(
        default=1000,
        description="Refuse (never truncate) when the invariant set needs more terms than this, 1..2000 (2000 "
        "terms take about 2 s per axis).",
    )
    lasso_facet_growth: Annotated[NonNegativeReal, Field(le=1)] = Field(
        default=0.02,
        description="Relative growth of Z allowed to drop facets (verified invariant); 0 keeps every facet. With a "
        "relative ε it is the largest share of (1 + ε) the reduction gets (at most half, geometrically).",
    )
    beyond_w: Literal["redesign", "hold", "ignore"] = Field(
        default="redesign",
        description="When a realised one-step disturbance leaves W (measured every step, "
        "oacli.control.tube_monitor): 'redesign' the tube with the measured bound (x 1.5) and continue, or the "
        "safe hold when no tube exists for it; 'hold' the safe hold at once; 'ignore' log and count only. The "
        "run's status is 'degraded' either way.",
    )
    monitor_noise_sigmas: NonNegativeReal = Field(
        default=0.0,
        description="Sensor noise the beyond-W monitor and the tube check tolerate, in σ of the sensors section: "
        "a measured w (or measured state) counts as outside W (or the tube) only beyond this many σ of the noise "
        "it carries (0: none). The tube guarantee itself does not cover Gaussian noise; the true state's tube "
        "violations are reported apart (tube_violations_true).",
    )
    initial_weight: NonNegativeReal = Field(
        default=0.0,
        description="Cost w (x̂ − z_0)ᵀ Q (x̂ − z_0) on the free initial nominal state, Q the translation weights "
        "[-], >= 0; 0: the cost of Mayne et al. 2005 (the nominal may start anywhere in the lasso). Constraints, "
        "hence the guarantee, are unchanged.",
    )
    observer: Annotated[ObserverConfig, none_to({})] = Field(
        default_factory=ObserverConfig, description="Output feedback: observer and estimation-error set."
    )
    solver: Literal["direct", "cvxpy"] = Field(
        default="direct",
        description="'direct': cvxpy canonicalises once, Clarabel is called with updated data; 'cvxpy': "
        "problem.solve() every step (same problem, slower).",
    )


def tube_problems(tube: TubeConfig, *, period_s: float, model: RobotModel,
                  sensor_std: tuple[float, float] | None = None) -> list[tuple[tuple[str | int, ...], Any, str]]:
    """Cross-field problems of ``controller.tube`` as ``(loc, value, reason)`` (checked when type is ``tube``);
    ``model`` is the robot model (``robot.model()``: its mass interval and force limit), ``sensor_std``
    ``(sensors.position_std_m, sensors.velocity_std_mps)``."""
    problems: list[tuple[tuple[str | int, ...], Any, str]] = []
    base = ("controller", "tube")
    if tube.observer.enabled and sensor_std is not None and not (sensor_std[0] > 0 and sensor_std[1] > 0):
        problems.append(((*base, "observer", "enabled"), True,
                         "the observer's error set needs sensors.position_std_m > 0 and sensors.velocity_std_mps > 0"))
    if tube.prediction_step_s is not None:
        ratio = tube.prediction_step_s / period_s
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            problems.append((
                (*base, "prediction_step_s"), tube.prediction_step_s,
                f"must be an integer multiple of the control period 1/controller.rate_hz = {period_s:g} s",
            ))
    if tube.force_limit_N is not None:
        for i, (lim, robot) in enumerate(zip(tube.force_limit_N, model.force_limit_N, strict=True)):
            if lim > robot * (1 + 1e-12):
                problems.append(((*base, "force_limit_N", i), lim,
                                 f"must be <= robot.force_limit_N[{i}] = {robot:g} N (the actuator limit)"))
    dist = tube.disturbance
    if model.mass_std_kg == 0:
        for i, axis in enumerate("xyz"):
            if dist.force_N[i] == 0 and not (dist.position_m[i] > 0 and dist.velocity_mps[i] > 0):
                problems.append((
                    (*base, "disturbance"), None,
                    f"W has no width on the {axis} axis: set robot.variance[0] > 0, force_N > 0, or both "
                    "position_m and velocity_mps > 0 (the invariant-set algorithm needs the origin inside W)",
                ))
                break
    low = model.parameter_interval("mass_kg", dist.mass_sigmas)[0]
    if not (low > 0 and math.isfinite(low)):
        problems.append(((*base, "disturbance", "mass_sigmas"), dist.mass_sigmas,
                         f"robot.mass_kg - {dist.mass_sigmas:g} sigma (sigma = sqrt(robot.variance[0]) = "
                         f"{model.mass_std_kg:g} kg) = {low:g} kg must be > 0"))
    return problems
