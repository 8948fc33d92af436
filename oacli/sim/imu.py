"""Simulated IMU: specific force and angular rate in the body frame, with bias and white noise.

Astrobee's IMU runs at the flight software's 62.5 Hz ([ReSWARM2023] §5.4.3; astrobee hw/pmc_actuator.config); the RATTLE
estimator used its linear acceleration with the variance 5e-6 (m/s²)² (rattle ``param_est`` R). In orbit the
station and the robot fall together, so the accelerometer reads the specific force of the wrench acting on the
robot, ``a = Rᵀ f / m`` (body frame; ``f`` the delivered force in the world frame, [Doerr2021] Eq. 34), and the
gyro the body rate ``ω``. Each reading adds a bias and white noise::

    ã_i = Rᵀ(q_i) f_i / m + b_a(t_i) + n_a,i        ω̃_i = ω_i + b_g(t_i) + n_g,i

with ``b(0) ~ N(0, σ_b²)`` per axis and ``b(t_{i+1}) = b(t_i) + σ_rw √Δt · N(0, 1)`` (random walk; constant when
``σ_rw = 0``). Every draw is made whatever the settings (fixed shapes), so changing one level never shifts
another draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model import quaternion as quat
from oacli.types import InertialParams

__all__ = ["ImuModel", "ImuSamples", "simulate_imu"]


@dataclass(frozen=True)
class ImuModel:
    """Noise and bias levels of the IMU (see the module docstring).

    Attributes
    ----------
    accelerometer_noise_std_mps2, gyro_noise_std_radps : float
        White noise std per reading and axis [m/s², rad/s].
    accelerometer_bias_std_mps2, gyro_bias_std_radps : float
        Std of the initial bias per axis [m/s², rad/s].
    accelerometer_bias_random_walk, gyro_bias_random_walk : float
        Random-walk intensity of the bias [m/s²/√s, rad/s/√s] (0: constant).
    """

    accelerometer_noise_std_mps2: float = 0.0
    gyro_noise_std_radps: float = 0.0
    accelerometer_bias_std_mps2: float = 0.0
    gyro_bias_std_radps: float = 0.0
    accelerometer_bias_random_walk: float = 0.0
    gyro_bias_random_walk: float = 0.0


@dataclass(frozen=True)
class ImuSamples:
    """IMU readings and the biases behind them (the biases are simulation truth, not part of a flight log).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Stamps [s].
    specific_force_mps2 : ndarray, shape (N, 3)
        Accelerometer readings, body frame [m/s²].
    angular_rate_radps : ndarray, shape (N, 3)
        Gyro readings, body frame [rad/s].
    accelerometer_bias_mps2, gyro_bias_radps : ndarray, shape (N, 3)
        The biases at each reading.
    """

    t: np.ndarray
    specific_force_mps2: np.ndarray
    angular_rate_radps: np.ndarray
    accelerometer_bias_mps2: np.ndarray
    gyro_bias_radps: np.ndarray


def _bias(b0: np.ndarray, walk: np.ndarray, std_rw: float, dt: np.ndarray) -> np.ndarray:
    steps = std_rw * np.sqrt(dt)[:, None] * walk[1:]
    return b0[None, :] + np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def simulate_imu(
    t: np.ndarray, x_true: np.ndarray, force_world_N: np.ndarray, plant: InertialParams, model: ImuModel,
    rng: np.random.Generator,
) -> ImuSamples:
    """IMU readings at ``t`` from the true states and the delivered force (module docstring).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Stamps [s], increasing.
    x_true : ndarray, shape (N, 13)
        True states at ``t``.
    force_world_N : ndarray, shape (N, 3)
        Force acting on the robot at ``t`` (world frame) [N].
    plant : InertialParams
        The true plant (its mass [kg] turns the force into the specific force).
    model : ImuModel
    rng : numpy.random.Generator
        Draws, in order: initial biases (accelerometer, gyro; 3 each), random-walk normals (N × 3 each), white
        noise (N × 3 each).

    Returns
    -------
    ImuSamples
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x_true, dtype=float).reshape(-1, 13)
    n = t.shape[0]
    b0 = rng.standard_normal((2, 3))
    walk = rng.standard_normal((2, n, 3))
    noise = rng.standard_normal((2, n, 3))
    dt = np.diff(t)
    b_acc = _bias(model.accelerometer_bias_std_mps2 * b0[0], walk[0], model.accelerometer_bias_random_walk, dt)
    b_gyr = _bias(model.gyro_bias_std_radps * b0[1], walk[1], model.gyro_bias_random_walk, dt)
    rot = quat.to_rotation_matrix(x[:, 6:10])
    a_body = np.einsum("nji,nj->ni", rot, np.asarray(force_world_N, float).reshape(n, 3)) / plant.mass_kg
    acc = a_body + b_acc + model.accelerometer_noise_std_mps2 * noise[0]
    gyr = x[:, 10:13] + b_gyr + model.gyro_noise_std_radps * noise[1]
    return ImuSamples(t, acc, gyr, b_acc, b_gyr)
