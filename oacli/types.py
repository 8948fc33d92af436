"""Shared data types of the algorithm core.

Every type is a frozen dataclass with fixed array shapes and SI units. Shapes are checked in
``__post_init__``; nothing is silently squeezed or broadcast.

State convention ([Doerr2021] Eq. 33): ``x = [r (3) m, v (3) m/s, q (4) [x, y, z, w] scalar last,
omega (3) rad/s]``, 13 entries. ``r`` and ``v`` are expressed in the world (ISS) frame, ``q`` rotates body
vectors into the world frame and ``omega`` is the body angular rate expressed in the body frame.

Input convention: ``u = [f (3) N, tau (3) N·m]``; the force ``f`` is expressed in the **world** frame (as in
[Doerr2021] Eq. 34b and in the RATTLE planner's model) and the torque ``tau`` in the **body** frame (Eq. 35b).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

STATE_DIM = 13
INPUT_DIM = 6
POS = slice(0, 3)
VEL = slice(3, 6)
QUAT = slice(6, 10)
OMEGA = slice(10, 13)
FORCE = slice(0, 3)
TORQUE = slice(3, 6)


def _as_array(name: str, value, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``value`` as a read-only float64 array, checking its shape (``None`` = any length)."""
    arr = np.array(value, dtype=float)
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)):
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class InertialParams:
    """Rigid-body inertial parameters ([Doerr2021] Eqs. 34-35).

    Attributes
    ----------
    mass_kg : float
        Mass m [kg], > 0.
    inertia_kgm2 : ndarray, shape (3,)
        Principal moments of inertia (Ixx, Iyy, Izz) [kg·m²] about the body axes through the CoM.
    """

    mass_kg: float
    inertia_kgm2: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "inertia_kgm2", _as_array("inertia_kgm2", self.inertia_kgm2, (3,)))
        object.__setattr__(self, "mass_kg", float(self.mass_kg))
        if not self.mass_kg > 0:
            raise ValueError(f"mass_kg must be > 0, got {self.mass_kg}")
        if np.any(self.inertia_kgm2 <= 0):
            raise ValueError(f"inertia_kgm2 must be > 0, got {self.inertia_kgm2}")


@dataclass(frozen=True)
class Trajectory:
    """A time-stamped state and input trajectory.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Strictly increasing time stamps [s].
    x : ndarray, shape (N, 13)
        States, see the module docstring for the layout.
    u : ndarray, shape (N, 6)
        Inputs [N, N·m] applied from ``t[k]`` to ``t[k+1]`` (zero-order hold); the last row is the input at the
        final time (held, usually zero).
    name : str
        Human-readable name (e.g. ``"reference"``).
    frame : str
        Name of the world frame the positions are expressed in.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    name: str = "trajectory"
    frame: str = "world"

    def __post_init__(self) -> None:
        t = _as_array("t", self.t, (None,))
        n = t.shape[0]
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "x", _as_array("x", self.x, (n, STATE_DIM)))
        object.__setattr__(self, "u", _as_array("u", self.u, (n, INPUT_DIM)))
        if n < 1:
            raise ValueError("a trajectory needs at least one sample")
        if np.any(np.diff(t) <= 0):
            raise ValueError("t must be strictly increasing")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample [s]."""
        return float(self.t[-1] - self.t[0])


@dataclass(frozen=True)
class SolveInfo:
    """Outcome of one optimisation (python-control's Result pattern).

    Attributes
    ----------
    status : str
        Solver status string as reported (``"optimal"``, ``"infeasible"``, ...).
    success : bool
        True when the solution was used.
    objective : float
        Optimal objective value (NaN when the solve failed).
    iterations : int
        Solver iterations (-1 when unknown).
    solve_time_s : float
        Wall time of the solver call [s].
    step_time_s : float
        Wall time of everything the controller did this step, solver included [s].
    """

    status: str
    success: bool
    objective: float = float("nan")
    iterations: int = -1
    solve_time_s: float = float("nan")
    step_time_s: float = float("nan")


@dataclass(frozen=True)
class ControlStep:
    """What a controller returns each update: the input it asks for, its solve record, its reference.

    Attributes
    ----------
    u : ndarray, shape (6,)
        Input ``[f N world frame, τ N·m body frame]`` to hold until the next update.
    info : SolveInfo
        The update's optimisation record.
    x_reference : ndarray, shape (13,)
        Reference state the controller aimed at this update.
    """

    u: np.ndarray
    info: SolveInfo
    x_reference: np.ndarray


class Controller(Protocol):
    """A sampled-data controller (what :func:`oacli.sim.simulator.simulate` runs in closed loop)."""

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """Input to apply from time ``t`` [s] given the measured state ``x_measured (13,)``.

        Parameters
        ----------
        t : float
            Mission time [s].
        x_measured : ndarray, shape (13,)
            Measured state.

        Returns
        -------
        ControlStep
        """
        ...


@dataclass(frozen=True)
class Telemetry:
    """What a closed-loop run recorded.

    Attributes
    ----------
    t_true : ndarray, shape (M,)
        Plant time stamps [s] (the truth integrator's rate, 62.5 Hz by default).
    x_true : ndarray, shape (M, 13)
        True state at ``t_true``.
    t_ctrl : ndarray, shape (K,)
        Controller update times [s].
    x_measured : ndarray, shape (K, 13)
        Measured state handed to the controller at ``t_ctrl``.
    x_reference : ndarray, shape (K, 13)
        Reference state at ``t_ctrl``.
    u_command : ndarray, shape (K, 6)
        Input the controller asked for [N, N·m].
    u_applied : ndarray, shape (K, 6)
        Input the actuators applied after saturation [N, N·m].
    solve_info : tuple of SolveInfo, length K
        Per-step solver record.
    disturbance : ndarray, shape (K, 6)
        Additive force/torque disturbance acting during each control period [N, N·m].
    x_true_ctrl : ndarray, shape (K, 13), optional
        True state at each control instant (what the sensors measured), when the simulator recorded it.
    """

    t_true: np.ndarray
    x_true: np.ndarray
    t_ctrl: np.ndarray
    x_measured: np.ndarray
    x_reference: np.ndarray
    u_command: np.ndarray
    u_applied: np.ndarray
    solve_info: tuple[SolveInfo, ...] = field(default_factory=tuple)
    disturbance: np.ndarray | None = None
    x_true_ctrl: np.ndarray | None = None

    def __post_init__(self) -> None:
        t_true = _as_array("t_true", self.t_true, (None,))
        m = t_true.shape[0]
        t_ctrl = _as_array("t_ctrl", self.t_ctrl, (None,))
        k = t_ctrl.shape[0]
        object.__setattr__(self, "t_true", t_true)
        object.__setattr__(self, "x_true", _as_array("x_true", self.x_true, (m, STATE_DIM)))
        object.__setattr__(self, "t_ctrl", t_ctrl)
        object.__setattr__(self, "x_measured", _as_array("x_measured", self.x_measured, (k, STATE_DIM)))
        object.__setattr__(self, "x_reference", _as_array("x_reference", self.x_reference, (k, STATE_DIM)))
        object.__setattr__(self, "u_command", _as_array("u_command", self.u_command, (k, INPUT_DIM)))
        object.__setattr__(self, "u_applied", _as_array("u_applied", self.u_applied, (k, INPUT_DIM)))
        dist = np.zeros((k, INPUT_DIM)) if self.disturbance is None else self.disturbance
        object.__setattr__(self, "disturbance", _as_array("disturbance", dist, (k, INPUT_DIM)))
        if self.x_true_ctrl is not None:
            object.__setattr__(self, "x_true_ctrl", _as_array("x_true_ctrl", self.x_true_ctrl, (k, STATE_DIM)))
        if len(self.solve_info) not in (0, k):
            raise ValueError(f"solve_info: expected {k} entries, got {len(self.solve_info)}")
        object.__setattr__(self, "solve_info", tuple(self.solve_info))


@dataclass(frozen=True)
class ParameterEstimate:
    """An estimate of the inertial parameters θ = [m kg, Ixx, Iyy, Izz kg·m²] ([Doerr2021] Eqs. 31-32).

    Attributes
    ----------
    t : float
        Time of the last measurement used [s].
    theta : ndarray, shape (4,)
        Estimate.
    covariance : ndarray, shape (4, 4)
        Estimate covariance (e.g. (AᵀA)⁻¹ of the batch problem, or the filter's P).
    method : str
        ``"batch"``, ``"sequential"``, ``"prior"`` ...
    samples_used, samples_rejected : int
        Measurements used, and rejected by outlier gating.
    """

    t: float
    theta: np.ndarray
    covariance: np.ndarray
    method: str
    samples_used: int = 0
    samples_rejected: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "theta", _as_array("theta", self.theta, (4,)))
        cov = _as_array("covariance", self.covariance, (4, 4))
        object.__setattr__(self, "covariance", cov)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations sqrt(diag P), shape (4,)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def inertial_params(self) -> InertialParams:
        """The estimate as :class:`InertialParams` (raises ValueError if it is not physical).

        Returns
        -------
        InertialParams
        """
        return InertialParams(self.theta[0], self.theta[1:4])
