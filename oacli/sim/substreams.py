"""Named random sub-streams: one independent generator per simulated sensor, all from the run's seed.

The closed loop draws from ``numpy.random.default_rng(seed)``; a sensor added later must not shift those draws
(existing configs keep their numbers), nor must one sensor's draws depend on another's settings. Each sensor
therefore gets its own child of the root ``numpy.random.SeedSequence(seed)``, keyed by the CRC-32 of its name
(the spawn key ``SeedSequence.spawn`` would use, with a stable name instead of a position).
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["sensor_rng"]


def sensor_rng(seed: int, name: str) -> np.random.Generator:
    """The generator of the sub-stream ``name`` of ``seed``.

    Parameters
    ----------
    seed : int
        The run's seed (>= 0).
    name : str
        Sub-stream name, e.g. ``"imu"`` or ``"localisation"``.

    Returns
    -------
    numpy.random.Generator
        Independent of ``default_rng(seed)`` and of every other name's generator.
    """
    key = zlib.crc32(name.encode("utf-8"))
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(key,)))
