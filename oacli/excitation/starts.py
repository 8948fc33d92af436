"""Starts of the offline excitation design's SCP (:mod:`oacli.excitation.design`).

Information is a convex function of the inputs and the design *maximises* it, so the SCP ends in a local optimum
that depends on its start. :func:`initial_guess` is the deterministic start (long stretches near the speed limit,
every rotation axis excited); :func:`perturbed_guess` draws further ones for the multi-start.
"""

from __future__ import annotations

import numpy as np

from oacli.excitation.design_types import ExcitationProblem
from oacli.excitation.problem import chord_margin_m, rest_to_rest_inputs, rest_to_rest_profile, translation_excitation
from oacli.excitation.split_information import rollout


def initial_guess(problem: ExcitationProblem, excitation_fraction: float = 0.3) -> np.ndarray:
    """A rest-to-rest input sequence (N, 6) that already excites every parameter (so that F is non-singular).

    Forces: the transfer plus out-and-back patterns near the speed limit (:func:`translation_excitation`).
    Torques: the rotation plus zero-net harmonics at ``excitation_fraction`` of the limits, halved until the
    rollout keeps inputs, velocities and rates within 90 % of their limits.

    Parameters
    ----------
    problem : ExcitationProblem
    excitation_fraction : float, optional
        Start amplitude of the harmonics, as a fraction of the limits.

    Returns
    -------
    ndarray, shape (N, 6)
    """
    p = problem
    lim = p.limits
    frac = excitation_fraction
    u = rest_to_rest_inputs(p.start, p.goal, p.steps, p.dt, p.theta)
    margin = chord_margin_m(lim.force_N, p.theta, p.dt) + p.clearance_m
    pattern = translation_excitation(p.start, u[:, 0:3], p.dt, p.theta, lim, p.scene, margin)
    for _ in range(12):
        amp = frac * np.vstack([np.where(np.any(pattern != 0, axis=0), 0.0, lim.force_N), lim.torque_Nm])
        u = rest_to_rest_inputs(p.start, p.goal, p.steps, p.dt, p.theta, excitation=amp)
        u[:, 0:3] += pattern
        x = rollout(p.start, u, p.theta, p.dt).x  # the split rollout: same states to rounding
        ok = (
            np.all(np.abs(u) <= 0.9 * lim.input)
            and np.all(np.abs(x[:, 3:6]) <= 0.9 * lim.velocity_mps)
            and np.all(np.abs(x[:, 10:13]) <= 0.9 * lim.angular_velocity_radps)
        )
        if ok:
            return u
        frac *= 0.5
    return np.clip(u, -lim.input, lim.input)


def perturbed_guess(problem: ExcitationProblem, rng: np.random.Generator) -> np.ndarray:
    """Another start for the SCP: the rest-to-rest transfer plus random zero-net harmonics on every channel.

    Each channel gets ``cos(2π h (k + ½)/N + φ)`` with a random harmonic h ∈ {1, ..., 4} and phase φ, projected so
    that the end state is unchanged to first order, at half the limit (halved until within 90 % of every limit).

    Parameters
    ----------
    problem : ExcitationProblem
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (N, 6)
    """
    p = problem
    n = p.steps
    lim = p.limits
    phase = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    shapes = np.empty((n, 6))
    for c in range(6):
        prof = rest_to_rest_profile(n, np.cos(rng.integers(1, 5) * phase + rng.uniform(0.0, 2.0 * np.pi)), 0.0)
        shapes[:, c] = prof / max(np.abs(prof).max(), 1e-12)
    base = rest_to_rest_inputs(p.start, p.goal, n, p.dt, p.theta)
    frac = 0.5
    u = base
    for _ in range(12):
        u = base.copy()
        u[:, 0:3] += frac * lim.force_N * shapes[:, 0:3]
        u[:, 3:6] += frac * lim.torque_Nm * shapes[:, 3:6]
        x = rollout(p.start, u, p.theta, p.dt).x  # the split rollout: same states to rounding
        if (np.all(np.abs(u) <= 0.9 * lim.input) and np.all(np.abs(x[:, 3:6]) <= 0.9 * lim.velocity_mps)
                and np.all(np.abs(x[:, 10:13]) <= 0.9 * lim.angular_velocity_radps)):
            break
        frac *= 0.5
    return np.clip(u, -lim.input, lim.input)


__all__ = ["initial_guess", "perturbed_guess"]
