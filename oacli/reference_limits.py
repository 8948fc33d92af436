"""Limits a reference must respect: the design limits of every designer, and the check of a given reference.

Design limits (plan, smooth, excite). A reference is designed with a model mass ``m_prior``, but the plant may be
heavier. Following the reference's acceleration ``a = f / m_prior`` takes ``m a = f · m / m_prior`` on a plant of
mass ``m``; over the prior's ``n_σ`` bound ``m_upper = m_prior + n_σ σ_m`` (the 2σ mass bound of Doerr et al.
2021, Eq. 28) that stays within the actuator limit ``F`` when ``|f| ≤ F · m_prior / m_upper``. Of that, only the
share ``φ_f`` (``reference_force_fraction``) is given to the reference; the rest is left to the feedback, which
must also reject disturbances and tracking errors. Torque, velocity and angular rate keep a share ``φ`` of the
robot's limit (tracking overshoot; the inertia prior is not margined: see :class:`ReferenceMargin`). A designer's
own caps (``planner.limits``, ``excitation.limits``) may only lower these further.

Reference check (track). Before a reference is tracked, :func:`check_reference_limits` computes what following it
asks of the simulated plant: the force ``m_truth (v_{k+1} − v_k)/Δt`` and torque ``I_truth Δω/Δt + ω × I_truth ω``
of :func:`oacli.trajectory.feedforward_inputs` ([Doerr2021] Eqs. 34b, 35b) plus the plant's disturbance, against the
actuator limits, and the reference's velocity and angular rate against the robot's limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from oacli.model.limits import LIMIT_FIELDS, MotionLimits
from oacli.model.robot_model import RobotModel
from oacli.trajectory import feedforward_inputs
from oacli.types import InertialParams, Trajectory

QUANTITIES = LIMIT_FIELDS
"""The limited quantities, in the order of :class:`~oacli.model.limits.MotionLimits`' fields."""

UNITS = {"force_N": "N", "torque_Nm": "N·m", "velocity_mps": "m/s", "angular_velocity_radps": "rad/s"}
AXES = "xyz"
LIMIT_RTOL = 1e-9
"""A value counts as above its limit when ``|value| > limit · (1 + LIMIT_RTOL)``."""


@dataclass(frozen=True)
class ReferenceMargin:
    """The margins of a design: the mass uncertainty (Eq. 28) and the shares of the robot's limits.

    Attributes
    ----------
    model : RobotModel
        The designer's model: ``m_prior`` and, from its covariance, σ_m.
    mass_sigmas : float
        n_σ of ``m_upper = m_prior + n_σ σ_m`` (>= 0; 0: the design is not derated for the mass).
    force_fraction, torque_fraction, velocity_fraction, angular_velocity_fraction : float
        Shares in (0, 1] of the (mass-margined) force limit and of the torque, velocity and angular-rate limits.

    Notes
    -----
    The inertia prior is deliberately not margined like the mass: RATTLE's prior (σ_I = 0.071 kg·m² for
    I ≈ 0.15 kg·m²) would halve the torque and with it the information on the inertias; an inertia error is left
    to the torque share kept for the feedback, and ``oacli track`` checks the torque the true plant needs.
    """

    model: RobotModel
    mass_sigmas: float = 2.0
    force_fraction: float = 1.0
    torque_fraction: float = 1.0
    velocity_fraction: float = 1.0
    angular_velocity_fraction: float = 1.0

    def __post_init__(self) -> None:
        self.model.parameter_interval("mass_kg", self.mass_sigmas)  # validates n_σ
        for name in ("force_fraction", "torque_fraction", "velocity_fraction", "angular_velocity_fraction"):
            value = getattr(self, name)
            if not 0 < value <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {value}")

    @property
    def mass_prior_kg(self) -> float:
        """``m_prior``: the model's mass [kg]."""
        return self.model.mass_kg

    @property
    def mass_std_kg(self) -> float:
        """σ_m of the model's mass [kg] (``sqrt(covariance[0, 0])``)."""
        return self.model.mass_std_kg

    @property
    def mass_upper_kg(self) -> float:
        """``m_upper = m_prior + n_σ σ_m`` [kg] (Eq. 28: :meth:`RobotModel.parameter_interval`)."""
        return self.model.parameter_interval("mass_kg", self.mass_sigmas)[1]

    @property
    def mass_ratio(self) -> float:
        """``m_prior / m_upper`` (≤ 1): the share of the actuator a heavier plant leaves for the same acceleration."""
        return self.mass_prior_kg / self.mass_upper_kg

    def scale(self, quantity: str) -> float:
        """Factor applied to the robot's limit of ``quantity``."""
        if quantity == "force_N":
            return self.mass_ratio * self.force_fraction
        return {"torque_Nm": self.torque_fraction, "velocity_mps": self.velocity_fraction,
                "angular_velocity_radps": self.angular_velocity_fraction}[quantity]


@dataclass(frozen=True)
class LimitExcess:
    """A requested cap above the robot's limit: quantity, axis index, requested value and the robot's value."""

    quantity: str
    axis: int
    requested: float
    robot: float


def limits_above_robot(robot: MotionLimits, caps: dict[str, Any]) -> list[LimitExcess]:
    """Every axis where a requested cap (``{quantity: (3,) or None}``) is above the robot's limit."""
    out = []
    for quantity in QUANTITIES:
        cap = caps.get(quantity)
        if cap is None:
            continue
        cap = np.asarray(cap, dtype=float).reshape(3)
        lim = robot.get(quantity)
        for i in range(3):
            if cap[i] > lim[i] * (1 + LIMIT_RTOL):
                out.append(LimitExcess(quantity, i, float(cap[i]), float(lim[i])))
    return out


@dataclass(frozen=True)
class DesignLimits:
    """The limits a designer must respect, and where they come from (:func:`design_limits`).

    Attributes
    ----------
    limits : MotionLimits
        What the design may use.
    robot : MotionLimits
        The robot's actuator and flight-mode limits.
    margin : ReferenceMargin
    capped : dict
        ``{quantity: (3,) bool}``: axes where a section's cap, not the margined robot limit, binds.
    notes : tuple of str
        Clipped caps and other remarks, one line each (for the log and the summary).
    """

    limits: MotionLimits
    robot: MotionLimits
    margin: ReferenceMargin
    capped: dict[str, np.ndarray] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def summary(self) -> dict[str, Any]:
        """The ``design_limits`` entry of a stage's summary.json."""
        m = self.margin
        return {
            **self.limits.as_dict(),
            "robot": self.robot.as_dict(),
            "mass_prior_kg": m.mass_prior_kg,
            "mass_std_kg": m.mass_std_kg,
            "mass_sigmas": m.mass_sigmas,
            "mass_upper_kg": m.mass_upper_kg,
            "mass_ratio": m.mass_ratio,
            "fractions": {"force": m.force_fraction, "torque": m.torque_fraction, "velocity": m.velocity_fraction,
                          "angular_velocity": m.angular_velocity_fraction},
            "capped_by_section": {q: [bool(c) for c in self.capped.get(q, np.zeros(3, dtype=bool))]
                                  for q in QUANTITIES},
            "notes": list(self.notes),
        }

    def describe(self) -> str:
        """One line for the log: the design limits and the mass margin."""
        lim, m = self.limits, self.margin
        vec = lambda a: "[" + ", ".join(f"{v:.4g}" for v in a) + "]"  # noqa: E731
        return (f"design limits: force {vec(lim.force_N)} N (robot × {m.mass_prior_kg:.4g}/{m.mass_upper_kg:.4g} kg "
                f"× {m.force_fraction:g}), torque {vec(lim.torque_Nm)} N·m, velocity {vec(lim.velocity_mps)} m/s, "
                f"angular rate {vec(lim.angular_velocity_radps)} rad/s")


def design_limits(robot: MotionLimits, margin: ReferenceMargin, caps: dict[str, Any] | None = None,
                  notes: tuple[str, ...] = ()) -> DesignLimits:
    """The limits a reference designer must respect (module docstring; [Doerr2021] Eq. 28).

    ``force = robot.force_N · m_prior/m_upper · φ_f``, ``torque = robot.torque_Nm · φ_τ``,
    ``velocity = robot.velocity_mps · φ_v``, ``angular rate = robot.angular_velocity_radps · φ_ω``, each then
    lowered to a section's cap where one is given.

    Parameters
    ----------
    robot : MotionLimits
        The robot's limits.
    margin : ReferenceMargin
    caps : dict, optional
        ``{quantity: (3,) or None}``: a section's own limits. Caps above the robot's must have been refused or
        clipped by the caller (:func:`limits_above_robot`); here they are only ever used to lower a limit.
    notes : tuple of str
        Carried into :attr:`DesignLimits.notes`.

    Returns
    -------
    DesignLimits
    """
    caps = caps or {}
    values, capped = {}, {}
    for quantity in QUANTITIES:
        margined = robot.get(quantity) * margin.scale(quantity)
        cap = caps.get(quantity)
        if cap is None:
            values[quantity], capped[quantity] = margined, np.zeros(3, dtype=bool)
        else:
            cap = np.asarray(cap, dtype=float).reshape(3)
            values[quantity], capped[quantity] = np.minimum(margined, cap), cap < margined
    return DesignLimits(MotionLimits(**values), robot, margin, capped, tuple(notes))


# ----------------------------------------------------------------------------------------------------------------
# The check of a reference against the plant that will fly it
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class QuantityCheck:
    """How close a reference comes to one limit.

    Attributes
    ----------
    quantity : str
        One of :data:`QUANTITIES`.
    worst_ratio : float
        Largest ``|value| / limit`` over time and axes (0 when there is nothing to check).
    worst_t_s : float
        When it happens [s] (start of the step for force and torque).
    worst_axis : int
    worst_value, worst_limit : float
        ``|value|`` and the limit there.
    first_exceeded_t_s : float or None
        First time the limit is exceeded on any axis [s], None if never.
    first_axis : int or None
    first_value, first_limit : float or None
    """

    quantity: str
    worst_ratio: float
    worst_t_s: float
    worst_axis: int
    worst_value: float
    worst_limit: float
    first_exceeded_t_s: float | None = None
    first_axis: int | None = None
    first_value: float | None = None
    first_limit: float | None = None

    @property
    def exceeded(self) -> bool:
        """True when the limit is exceeded somewhere."""
        return self.first_exceeded_t_s is not None

    def describe(self) -> str:
        """``force_N 0.251 N > 0.216 N (y) at t = 3.50 s, worst 1.16× the limit at t = 12.00 s``."""
        unit = UNITS[self.quantity]
        if self.first_exceeded_t_s is None or self.first_axis is None:
            return f"{self.quantity} within its limit (worst {self.worst_ratio:.3g}× at t = {self.worst_t_s:.2f} s)"
        return (f"{self.quantity} {self.first_value:.5g} {unit} > {self.first_limit:.5g} {unit} "
                f"({AXES[self.first_axis]}) at t = {self.first_exceeded_t_s:.2f} s, worst {self.worst_ratio:.4g}× "
                f"the limit ({self.worst_value:.5g} {unit} on {AXES[self.worst_axis]}) at t = {self.worst_t_s:.2f} s")

    def summary(self) -> dict[str, Any]:
        """The entry of one quantity in ``reference_check``."""
        return {
            "worst_ratio": self.worst_ratio, "worst_t_s": self.worst_t_s, "worst_axis": AXES[self.worst_axis],
            "worst_value": self.worst_value, "limit": self.worst_limit, "exceeded": self.exceeded,
            "first_exceeded_t_s": self.first_exceeded_t_s,
            "first_axis": None if self.first_axis is None else AXES[self.first_axis],
            "first_value": self.first_value, "first_limit": self.first_limit,
        }


@dataclass(frozen=True)
class ReferenceLimitCheck:
    """Result of :func:`check_reference_limits`: one :class:`QuantityCheck` per quantity and the plant used."""

    checks: dict[str, QuantityCheck]
    plant: InertialParams

    @property
    def exceeded(self) -> list[str]:
        """The quantities whose limit the reference exceeds."""
        return [q for q in QUANTITIES if self.checks[q].exceeded]

    @property
    def ok(self) -> bool:
        """True when the plant can follow the reference within every limit."""
        return not self.exceeded

    def message(self) -> str:
        """One line naming every exceeded quantity with its time and values ('' when within the limits)."""
        if self.ok:
            return ""
        parts = "; ".join(self.checks[q].describe() for q in self.exceeded)
        return (f"the reference asks more than the plant (mass {self.plant.mass_kg:.4g} kg) can give: {parts}")

    def summary(self) -> dict[str, Any]:
        """The ``reference_check`` entry of summary.json."""
        return {
            "ok": self.ok,
            "exceeded": self.exceeded,
            "message": self.message(),
            "plant": {"mass_kg": float(self.plant.mass_kg),
                      "inertia_kgm2": [float(v) for v in self.plant.inertia_kgm2]},
            **{q: self.checks[q].summary() for q in QUANTITIES},
        }


def _quantity_check(quantity: str, t: np.ndarray, values: np.ndarray, limit: np.ndarray) -> QuantityCheck:
    if values.shape[0] == 0:
        return QuantityCheck(quantity, 0.0, float(t[0]) if t.size else 0.0, 0, 0.0, float(limit[0]))
    ratio = np.abs(values) / limit
    k, i = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    worst = (float(ratio[k, i]), float(t[k]), int(i), float(abs(values[k, i])), float(limit[i]))
    over = np.abs(values) > limit * (1 + LIMIT_RTOL)
    if not np.any(over):
        return QuantityCheck(quantity, *worst)
    k1 = int(np.argmax(np.any(over, axis=1)))
    i1 = int(np.argmax(ratio[k1] * over[k1]))
    return QuantityCheck(quantity, *worst, first_exceeded_t_s=float(t[k1]), first_axis=i1,
                         first_value=float(abs(values[k1, i1])), first_limit=float(limit[i1]))


def required_inputs(reference: Trajectory, plant: InertialParams) -> np.ndarray:
    """The force (world) and torque (body) that make ``plant`` follow the reference, shape (N−1, 6).

    :func:`oacli.trajectory.feedforward_inputs` of the reference's samples with the plant's mass and inertia
    (interval by interval when the sampling is not uniform).
    """
    t, x = reference.t, reference.x
    if t.size < 2:
        return np.zeros((0, 6))
    dt = np.diff(t)
    if np.allclose(dt, dt[0], rtol=1e-9, atol=0.0):
        return feedforward_inputs(x, float(dt[0]), plant)
    return np.vstack([feedforward_inputs(x[k:k + 2], float(dt[k]), plant) for k in range(dt.size)])


def check_reference_limits(
    reference: Trajectory,
    plant: InertialParams,
    limits: MotionLimits,
    disturbance_bias: np.ndarray | None = None,
    disturbance_bound: np.ndarray | None = None,
) -> ReferenceLimitCheck:
    """Can ``plant`` follow ``reference`` within ``limits``? (module docstring)

    Parameters
    ----------
    reference : Trajectory
    plant : InertialParams
        The plant that will fly it (the config's ``truth``).
    limits : MotionLimits
        Actuator limits (force per world axis, torque per body axis) and the speed and rate limits.
    disturbance_bias, disturbance_bound : ndarray, shape (6,), optional
        The plant's additive disturbance ``[f, τ]`` (constant part and bound of the random part): the actuator
        must supply ``u_ff − bias`` and up to ``bound`` more, so the check uses ``|u_ff − bias| + bound``.

    Returns
    -------
    ReferenceLimitCheck
        Worst ratio per quantity and the first time each limit is exceeded.
    """
    u = required_inputs(reference, plant)
    if disturbance_bias is not None:
        u = u - np.asarray(disturbance_bias, dtype=float).reshape(1, 6)
    u = np.abs(u)
    if disturbance_bound is not None:
        u = u + np.abs(np.asarray(disturbance_bound, dtype=float)).reshape(1, 6)
    t_steps = reference.t[:-1]
    checks = {
        "force_N": _quantity_check("force_N", t_steps, u[:, 0:3], limits.force_N),
        "torque_Nm": _quantity_check("torque_Nm", t_steps, u[:, 3:6], limits.torque_Nm),
        "velocity_mps": _quantity_check("velocity_mps", reference.t, reference.x[:, 3:6], limits.velocity_mps),
        "angular_velocity_radps": _quantity_check("angular_velocity_radps", reference.t, reference.x[:, 10:13],
                                                  limits.angular_velocity_radps),
    }
    return ReferenceLimitCheck(checks, plant)


__all__ = [
    "AXES",
    "LIMIT_RTOL",
    "QUANTITIES",
    "DesignLimits",
    "LimitExcess",
    "MotionLimits",
    "QuantityCheck",
    "ReferenceLimitCheck",
    "ReferenceMargin",
    "check_reference_limits",
    "design_limits",
    "limits_above_robot",
    "required_inputs",
]
