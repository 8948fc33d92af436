"""The controllers' reference sampler: :func:`oacli.trajectory.sample_states` with the per-segment work done once.

Every controller step samples the reference at ``t + k·T`` (k = 0..N). :func:`~oacli.trajectory.sample_states`
recomputes, for each sample, the segment's relative rotation ``δ = log(q_iᵀ ⊗ q_{i+1})`` and its state difference;
here they are computed once per reference segment at construction, and the slerp ``q_i ⊗ exp(s δ)`` (then
normalised) is written out per component instead of through the generic quaternion helpers (their
``np.cross``/``concatenate`` calls dominate on a handful of rows). The formulas and their order of operations are
those of :mod:`oacli.model.quaternion`, so the samples agree with ``sample_states`` to rounding (the tests check).
"""

from __future__ import annotations

import numpy as np

from oacli.model import quaternion as quat
from oacli.types import Trajectory


class ReferenceSampler:
    """Samples of a reference at arbitrary times, as :func:`oacli.trajectory.sample_states` (see the module docstring).

    Parameters
    ----------
    reference : Trajectory
    """

    def __init__(self, reference: Trajectory) -> None:
        self.t = np.asarray(reference.t, dtype=float)
        self.x = np.asarray(reference.x, dtype=float)
        if self.t.size > 1:
            self._dx = self.x[1:] - self.x[:-1]
            self._dt = self.t[1:] - self.t[:-1]
            q = self.x[:, 6:10]
            self._delta = quat.log(quat.multiply(quat.conjugate(q[:-1]), q[1:]))

    def states(self, times: np.ndarray) -> np.ndarray:
        """States at ``times`` [s], shape (k, 13): linear in position, velocity and rate, slerp in attitude; the
        first state before the start, the final pose at rest after the end.

        Parameters
        ----------
        times : ndarray, shape (k,)

        Returns
        -------
        ndarray, shape (k, 13)
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        t = self.t
        out = np.empty((times.size, 13))
        if t.size == 1:
            out[:] = self.x[0]
            after = times > t[0]
            out[after, 3:6] = 0.0
            out[after, 10:13] = 0.0
            return out
        idx = np.clip(np.searchsorted(t, times, side="right") - 1, 0, t.size - 2)
        s = np.clip((times - t[idx]) / self._dt[idx], 0.0, 1.0)
        x0 = self.x[idx]
        out[:] = x0 + s[:, None] * self._dx[idx]
        # exp(s δ) (quat.exp), then q0 ⊗ e (quat.multiply), then quat.normalize.
        phi = s[:, None] * self._delta[idx]
        angle = np.linalg.norm(phi, axis=-1, keepdims=True)
        half = 0.5 * angle
        small = angle < 1e-6
        safe = np.where(small, 1.0, angle)
        k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
        ev = k * phi
        ew = np.cos(half)
        pv, pw = x0[:, 6:9], x0[:, 9:10]
        cross = np.empty_like(pv)
        cross[:, 0] = pv[:, 1] * ev[:, 2] - pv[:, 2] * ev[:, 1]
        cross[:, 1] = pv[:, 2] * ev[:, 0] - pv[:, 0] * ev[:, 2]
        cross[:, 2] = pv[:, 0] * ev[:, 1] - pv[:, 1] * ev[:, 0]
        q = np.empty((times.size, 4))
        q[:, 0:3] = pw * ev + ew * pv + cross
        q[:, 3:4] = pw * ew - np.sum(pv * ev, axis=-1, keepdims=True)
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        out[:, 6:10] = np.where(q[:, 3:4] < 0.0, -q, q)
        after = times > t[-1]
        out[after, 3:6] = 0.0
        out[after, 10:13] = 0.0
        return out
