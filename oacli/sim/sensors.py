"""Measurement and disturbance models of the simulated plant."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model import quaternion as quat


@dataclass(frozen=True)
class SensorNoise:
    """Zero-mean Gaussian noise on the state estimate handed to the controller.

    Attributes
    ----------
    position_std_m, velocity_std_mps, attitude_std_rad, angular_velocity_std_radps : float
        Per-axis standard deviations; the attitude noise is a body-frame rotation vector.
    """

    position_std_m: float = 0.0
    velocity_std_mps: float = 0.0
    attitude_std_rad: float = 0.0
    angular_velocity_std_radps: float = 0.0

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy copy of the true state ``x (13,)``; draws 12 normals from ``rng`` every call.

        Parameters
        ----------
        x : ndarray, shape (13,)
            True state.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (13,)
        """
        n = rng.standard_normal(12)
        y = x.copy()
        y[0:3] += self.position_std_m * n[0:3]
        y[3:6] += self.velocity_std_mps * n[3:6]
        y[6:10] = quat.normalize(_multiply(x[6:10], quat.exp(self.attitude_std_rad * n[6:9])))
        y[10:13] += self.angular_velocity_std_radps * n[9:12]
        return y


def _multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` of two single quaternions ``[x, y, z, w]`` on Python floats: the same
    operations in the same order as :func:`oacli.model.quaternion.multiply` (bit-identical), without the
    per-call array overhead of its broadcasting form."""
    px, py, pz, pw = (float(c) for c in p)
    qx, qy, qz, qw = (float(c) for c in q)
    return np.array([
        (pw * qx + qw * px) + (py * qz - pz * qy),
        (pw * qy + qw * py) + (pz * qx - px * qz),
        (pw * qz + qw * pz) + (px * qy - py * qx),
        pw * qw - ((px * qx + py * qy) + pz * qz),
    ])


@dataclass(frozen=True)
class Disturbance:
    """Additive force (world frame) and torque (body frame) disturbance, held over each control period.

    Attributes
    ----------
    bias : ndarray, shape (6,)
        Constant part [N, N·m].
    random_bound : ndarray, shape (6,)
        Half-width of a uniform random part redrawn each control period [N, N·m] (≥ 0).
    """

    bias: np.ndarray
    random_bound: np.ndarray

    @classmethod
    def none(cls) -> Disturbance:
        """No disturbance.

        Returns
        -------
        Disturbance
        """
        return cls(np.zeros(6), np.zeros(6))

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """One disturbance value (6,); draws 6 uniforms from ``rng`` every call.

        Parameters
        ----------
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (6,)
            Force [N] and torque [N·m].
        """
        return self.bias + self.random_bound * rng.uniform(-1.0, 1.0, 6)
