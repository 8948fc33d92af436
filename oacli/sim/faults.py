"""Localisation faults: jumps of the measured pose ([ReSWARM2023] §5.4.2, §6.2.1, Fig. 21).

In flight Astrobee's localisation occasionally jumped when visual features were lost; the estimators must reject
such records (χ² gating). :func:`inject_localisation_jumps` replaces a fraction of measured states by jumped ones:
the position moves by a random direction times a magnitude drawn uniformly in ``position_jump_m`` and the attitude
rotates about a random axis by an angle drawn uniformly in ``attitude_jump_rad`` (body frame).
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def inject_localisation_jumps(
    x_measured: np.ndarray,
    fraction: float,
    rng: np.random.Generator,
    *,
    position_jump_m: tuple[float, float] = (0.1, 0.3),
    attitude_jump_rad: tuple[float, float] = (0.05, 0.2),
    skip_first: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Replace ``round(fraction · K)`` measured states by localisation jumps.

    Parameters
    ----------
    x_measured : ndarray, shape (K, 13)
        Measured states (not modified).
    fraction : float
        Fraction of records to corrupt, in [0, 1].
    rng : numpy.random.Generator
        Source of every random draw.
    position_jump_m, attitude_jump_rad : (float, float)
        Ranges of the jump magnitudes [m], [rad].
    skip_first : int
        Leave the first records clean (a filter initialises from its first record).

    Returns
    -------
    x_jumped : ndarray, shape (K, 13)
        Copy with the jumps.
    indices : ndarray of int
        Sorted indices of the corrupted records.
    """
    x = np.array(x_measured, dtype=float)
    if not 0.0 <= fraction <= 1.0:
        raise ValueError("fraction must be in [0, 1]")
    candidates = np.arange(skip_first, x.shape[0])
    n = min(round(fraction * x.shape[0]), candidates.size)
    idx = np.sort(rng.choice(candidates, size=n, replace=False))
    dp = _unit_vectors(rng, n) * rng.uniform(*position_jump_m, (n, 1))
    dphi = _unit_vectors(rng, n) * rng.uniform(*attitude_jump_rad, (n, 1))
    x[idx, 0:3] += dp
    x[idx, 6:10] = quat.normalize(quat.multiply(x[idx, 6:10], quat.exp(dphi)))
    return x, idx
