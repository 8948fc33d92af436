"""Steady-state observer of the translational state for output-feedback tube MPC ([Mayne2006]).

Each world axis is the exact double integrator ``[p, v]⁺ = A [p, v] + B f`` (model mass) measured directly,
``y = [p, v] + n`` (the localisation's position and velocity). The observer is the filter form of a steady-state
Kalman filter (Kalman 1960; Anderson & Moore 1979, §4.4): predict with the model and the applied force, correct
with the constant gain L,

    x̂⁻ = A x̂ + B f,    x̂ = x̂⁻ + L (y − x̂⁻),

with ``L = P (P + R)⁻¹``, P the stabilising solution of the filter Riccati equation for the process noise of a
white acceleration of standard deviation ``σ_a`` held over a step (``Q = σ_a² g gᵀ``, ``g = [dt²/2, dt]``) and the
sensor covariance ``R = diag(σ_p², σ_v²)``; or a given diagonal Luenberger gain. The error sets of the gain are
:func:`oacli.sets.error_set.output_feedback_sets`.
"""

from __future__ import annotations

import numpy as np

from oacli.control.lqr import solve_dare
from oacli.control.tube_design import ObserverSpec, TubeDesign
from oacli.model.double_integrator import double_integrator
from oacli.model.robot_model import RobotModel


def kalman_gain(a: np.ndarray, dt_s: float, accel_std_mps2: float, position_std_m: float,
                velocity_std_mps: float) -> np.ndarray:
    """Steady-state Kalman gain (filter form) of one axis measured in position and velocity.

    Parameters
    ----------
    a : ndarray, shape (2, 2)
        Model over one step.
    dt_s : float
        Step [s].
    accel_std_mps2 : float
        σ of the white process acceleration [m/s²], > 0.
    position_std_m, velocity_std_mps : float
        Sensor σ [m], [m/s], > 0.

    Returns
    -------
    ndarray, shape (2, 2)
        L, with ``(I − L) A`` Schur stable.
    """
    g = np.array([[0.5 * dt_s * dt_s], [dt_s]])
    q = accel_std_mps2**2 * (g @ g.T) + 1e-18 * np.eye(2)
    r = np.diag([position_std_m**2, velocity_std_mps**2])
    p = solve_dare(np.asarray(a, dtype=float).T, np.eye(2), q, r)  # a priori covariance (duality)
    return np.asarray(p @ np.linalg.inv(p + r))


class TranslationObserver:
    """The observer of the three translational axes (module docstring); state ``[r (3) m, v (3) m/s]``.

    Parameters
    ----------
    a, b : ndarray, shapes (2, 2), (2, 1)
        Per-axis model over one control step (model mass).
    gain : ndarray, shape (2, 2)
        L, the same on every axis.
    dt_s : float
        Control period [s]; a measurement after another interval re-initialises the estimate.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, gain: np.ndarray, dt_s: float) -> None:
        eye3 = np.eye(3)
        self.a6 = np.kron(np.asarray(a, dtype=float), eye3)
        self.b6 = np.kron(np.asarray(b, dtype=float), eye3)
        self.l6 = np.kron(np.asarray(gain, dtype=float), eye3)
        self.dt_s = float(dt_s)
        self._x: np.ndarray | None = None
        self._t: float | None = None
        self._force: np.ndarray | None = None

    @property
    def estimate(self) -> np.ndarray | None:
        """The current estimate (6,), None before the first measurement."""
        return None if self._x is None else self._x.copy()

    def applied(self, force_N: np.ndarray) -> None:
        """Record the world force applied from the last measurement to the next one.

        Parameters
        ----------
        force_N : ndarray, shape (3,)
            Applied force, world frame [N].
        """
        self._force = np.array(force_N, dtype=float)

    def update(self, t: float, y: np.ndarray) -> np.ndarray:
        """Predict with the force of :meth:`applied` since the last update, correct with ``y``; return ``x̂``.

        Parameters
        ----------
        t : float
            Measurement time [s].
        y : ndarray, shape (6,)
            Measured ``[r, v]`` (world frame).

        Returns
        -------
        ndarray, shape (6,)
            ``x̂``.
        """
        y = np.asarray(y, dtype=float)
        prev, t_prev, force_N = self._x, self._t, self._force
        if prev is None or t_prev is None or force_N is None or abs(t - t_prev - self.dt_s) > 1e-6 * self.dt_s:
            self._x = y.copy()  # initialise on the measurement: ε_0 = −n_0
        else:
            pred = self.a6 @ prev + self.b6 @ force_N
            self._x = pred + self.l6 @ (y - pred)
        self._t = float(t)
        return self._x.copy()


class RateObserver:
    """Steady-state observer of the body angular rate ("attitude the same way where the rates matter").

    Euler's equations predict the rate over one control period under the applied torque,
    ``ω̂⁻ = ω̂ + dt I⁻¹ (τ − ω̂ × I ω̂)``, and a constant gain corrects it with the measured rate,
    ``ω̂ = ω̂⁻ + l (ω̃ − ω̂⁻)``: the rate noise reaches the attitude MPC attenuated to about ``√(l / (2 − l))`` of
    its σ (white noise through the first-order filter). No set is claimed for attitude (it has no tube).

    Parameters
    ----------
    inertia_kgm2 : ndarray, shape (3,)
        Principal inertias of the model [kg·m²].
    gain : float
        l in (0, 1].
    dt_s : float
        Control period [s]; a measurement after another interval re-initialises the estimate.
    inertia_tensor_kgm2 : ndarray, shape (3, 3), optional
        The full tensor ``J`` [kg·m²] (products of inertia): ``ω̂⁻ = ω̂ + dt J⁻¹ (τ − ω̂ × J ω̂)``; None: ``diag(I)``.
    """

    def __init__(self, inertia_kgm2: np.ndarray, gain: float, dt_s: float,
                 inertia_tensor_kgm2: np.ndarray | None = None) -> None:
        self.inertia = np.asarray(inertia_kgm2, dtype=float).reshape(3)
        self.tensor = None if inertia_tensor_kgm2 is None else np.asarray(inertia_tensor_kgm2, float).reshape(3, 3)
        self.tensor_inv = None if self.tensor is None else np.linalg.inv(self.tensor)
        self.gain, self.dt_s = float(gain), float(dt_s)
        self._w: np.ndarray | None = None
        self._t: float | None = None
        self._torque: np.ndarray | None = None

    def applied(self, torque_Nm: np.ndarray) -> None:
        """Record the body torque applied until the next measurement.

        Parameters
        ----------
        torque_Nm : ndarray, shape (3,)
            Applied torque, body frame [N·m].
        """
        self._torque = np.array(torque_Nm, dtype=float)

    def update(self, t: float, omega_radps: np.ndarray) -> np.ndarray:
        """Predict with the recorded torque, correct with the measured rate; return ``ω̂`` [rad/s] (3,).

        Parameters
        ----------
        t : float
            Measurement time [s].
        omega_radps : ndarray, shape (3,)
            Measured body rate [rad/s].

        Returns
        -------
        ndarray, shape (3,)
        """
        y = np.asarray(omega_radps, dtype=float)
        w, t_prev, tau = self._w, self._t, self._torque
        if w is None or t_prev is None or tau is None or abs(t - t_prev - self.dt_s) > 1e-6 * self.dt_s:
            self._w = y.copy()
        else:
            if self.tensor is None or self.tensor_inv is None:
                pred = w + self.dt_s * (tau - np.cross(w, self.inertia * w)) / self.inertia
            else:
                pred = w + self.dt_s * (self.tensor_inv @ (tau - np.cross(w, self.tensor @ w)))
            self._w = pred + self.gain * (y - pred)
        self._t = float(t)
        return self._w.copy()


def observer_spec(*, model: RobotModel, dt_s: float, position_std_m: float, velocity_std_mps: float,
                  noise_sigmas: float, gain: tuple[float, float] | None, accel_std_mps2: float) -> ObserverSpec:
    """The observer of an output-feedback tube design: gain L and the noise bound ``noise_sigmas`` σ per axis.

    Parameters
    ----------
    model : RobotModel
        The controller's model (its mass m₀ [kg]: the double integrator the observer predicts with).
    dt_s : float
        Control period [s].
    position_std_m, velocity_std_mps : float
        Sensor σ [m], [m/s], > 0.
    noise_sigmas : float
        Noise bound of the error set in σ.
    gain : (float, float) or None
        Diagonal Luenberger gain; None: :func:`kalman_gain` with ``accel_std_mps2``.
    accel_std_mps2 : float
        Process acceleration σ of the Kalman gain [m/s²].

    Returns
    -------
    ObserverSpec
    """
    if not (position_std_m > 0 and velocity_std_mps > 0):
        raise ValueError("the observer needs sensors.position_std_m > 0 and sensors.velocity_std_mps > 0")
    a, _ = double_integrator(dt_s, 1.0 / model.mass_kg)
    ell = (np.diag([float(gain[0]), float(gain[1])]) if gain is not None
           else kalman_gain(a, dt_s, accel_std_mps2, position_std_m, velocity_std_mps))
    noise = np.tile([noise_sigmas * position_std_m, noise_sigmas * velocity_std_mps], (3, 1))
    return ObserverSpec(ell, noise)


def observer_for(design: TubeDesign) -> TranslationObserver | None:
    """The observer of an output-feedback design (its model and gain), None for state feedback.

    Parameters
    ----------
    design : TubeDesign

    Returns
    -------
    TranslationObserver or None
    """
    out = design.axes[0].output
    if out is None:
        return None
    ax = design.axes[0]
    return TranslationObserver(ax.a, ax.b, out.observer_gain, design.dt_s)
