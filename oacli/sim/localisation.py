"""Simulated localisation messages as flown: own rate, noise, jumps, lost and late messages.

Astrobee's localisation ([ReSWARM2023] §5.4.2-§5.4.3, §6.2.1) occasionally jumped when visual features were lost,
dropped messages, and delivered some late, so the log holds them out of time order with their true stamps. A
message here is the full measured state (pose, velocity, angular rate), as Astrobee's EKF publishes it, with the
noise of :class:`oacli.sim.sensors.SensorNoise`. Independently per message (the first one is always clean and on
time: a filter initialises from it):

* it **jumps** with probability ``jump_probability``: the position moves by a random direction times a magnitude
  uniform in ``jump_position_m``, the attitude rotates about a random body axis by an angle uniform in
  ``jump_attitude_rad`` (as :func:`oacli.sim.faults.inject_localisation_jumps`);
* it is **dropped** with probability ``drop_probability``;
* it is **delayed** with probability ``delay_probability`` by an exponential delay of mean ``delay_mean_s``; the
  messages are returned in arrival order (a delayed one after those stamped later but arriving earlier).

Every draw is made whatever the settings (fixed shapes), so changing one probability never shifts another draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.model import quaternion as quat
from oacli.sim.sensors import SensorNoise

__all__ = ["LocalisationMessages", "LocalisationModel", "localisation_stamps", "simulate_localisation"]


@dataclass(frozen=True)
class LocalisationModel:
    """Rate, noise and faults of the localisation (module docstring).

    Attributes
    ----------
    rate_hz : float
    noise : SensorNoise
    jump_probability, drop_probability, delay_probability : float
        Per-message probabilities in [0, 1].
    jump_position_m, jump_attitude_rad : (float, float)
        Ranges of the jump magnitudes [m], [rad].
    delay_mean_s : float
        Mean of the exponential delay [s].
    """

    rate_hz: float
    noise: SensorNoise
    jump_probability: float = 0.0
    drop_probability: float = 0.0
    delay_probability: float = 0.0
    jump_position_m: tuple[float, float] = (0.1, 0.3)
    jump_attitude_rad: tuple[float, float] = (0.05, 0.2)
    delay_mean_s: float = 0.5


@dataclass(frozen=True)
class LocalisationMessages:
    """The messages that reached the log, in arrival order, and what happened to all of them.

    Attributes
    ----------
    stamp_s : ndarray, shape (M,)
        True stamps of the delivered messages, in arrival order [s].
    arrival_s : ndarray, shape (M,)
        Arrival (log) times, non-decreasing [s].
    x : ndarray, shape (M, 13)
        Measured states.
    generated : int
        Messages produced before any loss.
    jumped_s, dropped_s, delayed_s : ndarray
        Stamps of the jumped (delivered or not), dropped and delayed messages [s].
    """

    stamp_s: np.ndarray
    arrival_s: np.ndarray
    x: np.ndarray
    generated: int
    jumped_s: np.ndarray
    dropped_s: np.ndarray
    delayed_s: np.ndarray

    def counts(self) -> dict[str, int]:
        """Counts for a summary.

        Returns
        -------
        dict
        """
        out_of_order = int(np.sum(self.stamp_s[1:] < np.maximum.accumulate(self.stamp_s)[:-1]))
        return {"generated": int(self.generated), "delivered": int(self.stamp_s.size),
                "jumped": int(self.jumped_s.size), "dropped": int(self.dropped_s.size),
                "delayed": int(self.delayed_s.size), "out_of_order": out_of_order}


def localisation_stamps(duration_s: float, rate_hz: float) -> np.ndarray:
    """Stamps ``k / rate_hz`` for ``k = 0 .. floor(duration_s · rate_hz)`` [s].

    Parameters
    ----------
    duration_s, rate_hz : float

    Returns
    -------
    ndarray
    """
    return np.arange(int(np.floor(duration_s * rate_hz + 1e-9)) + 1) / rate_hz


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def simulate_localisation(
    stamps: np.ndarray, x_true: np.ndarray, model: LocalisationModel, rng: np.random.Generator
) -> LocalisationMessages:
    """Localisation messages from the true states at their stamps (module docstring).

    Parameters
    ----------
    stamps : ndarray, shape (K,)
        Message stamps [s], increasing.
    x_true : ndarray, shape (K, 13)
        True states at the stamps.
    model : LocalisationModel
    rng : numpy.random.Generator
        Draws, in order: noise (K × 12), jump (K uniforms, K × 3 and K × 3 directions, K × 2 magnitudes), drop
        (K uniforms), delay (K uniforms, K exponentials).

    Returns
    -------
    LocalisationMessages
    """
    stamps = np.asarray(stamps, dtype=float)
    x_true = np.asarray(x_true, dtype=float).reshape(-1, 13)
    k = stamps.shape[0]
    noise = rng.standard_normal((k, 12))
    u_jump, dir_p = rng.random(k), rng.standard_normal((k, 3))
    dir_a, mag = rng.standard_normal((k, 3)), rng.random((k, 2))
    u_drop = rng.random(k)
    u_delay, delay = rng.random(k), rng.standard_exponential(k)
    n = model.noise
    x = x_true.copy()
    x[:, 0:3] += n.position_std_m * noise[:, 0:3]
    x[:, 3:6] += n.velocity_std_mps * noise[:, 3:6]
    x[:, 6:10] = quat.normalize(quat.multiply(x_true[:, 6:10], quat.exp(n.attitude_std_rad * noise[:, 6:9])))
    x[:, 10:13] += n.angular_velocity_std_radps * noise[:, 9:12]
    later = np.arange(k) > 0
    jump = later & (u_jump < model.jump_probability)
    p_lo, p_hi = model.jump_position_m
    a_lo, a_hi = model.jump_attitude_rad
    dp = _unit(dir_p) * (p_lo + (p_hi - p_lo) * mag[:, 0:1])
    dphi = _unit(dir_a) * (a_lo + (a_hi - a_lo) * mag[:, 1:2])
    x[jump, 0:3] += dp[jump]
    x[jump, 6:10] = quat.normalize(quat.multiply(x[jump, 6:10], quat.exp(dphi[jump])))
    drop = later & (u_drop < model.drop_probability)
    delayed = later & ~drop & (u_delay < model.delay_probability)
    arrival = stamps + np.where(delayed, model.delay_mean_s * delay, 0.0)
    keep = np.flatnonzero(~drop)
    order = keep[np.argsort(arrival[keep], kind="stable")]
    return LocalisationMessages(
        stamp_s=stamps[order], arrival_s=arrival[order], x=x[order], generated=k, jumped_s=stamps[jump],
        dropped_s=stamps[drop], delayed_s=stamps[delayed],
    )
