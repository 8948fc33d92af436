"""The simulator arguments of the config's flight faults and full inertia tensor (:mod:`oacli.config.faults`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.config import OacliConfig


def fault_arguments(cfg: OacliConfig, input_limits: np.ndarray) -> dict[str, Any]:
    """Keyword arguments of :func:`oacli.sim.simulator.simulate` for ``truth.inertia_tensor_kgm2`` and
    ``faults.actuator_saturation`` (the stall wraps the controller: :func:`oacli.sim.stall.with_stall`).

    Parameters
    ----------
    cfg : OacliConfig
        The stage's config.
    input_limits : ndarray, shape (6,)
        The robot's input limits [N, N·m].

    Returns
    -------
    dict
        ``inertia_tensor_kgm2`` (3×3 or None) and ``delivered_limits`` (6 or None).
    """
    tensor = cfg.truth.inertia_tensor_kgm2
    fraction = cfg.faults.delivered_fraction()
    return {
        "inertia_tensor_kgm2": None if tensor is None else np.asarray(tensor, dtype=float),
        "delivered_limits": None if fraction is None else fraction * np.asarray(input_limits, dtype=float),
    }


__all__ = ["fault_arguments"]
