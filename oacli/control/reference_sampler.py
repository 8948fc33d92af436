"""The controllers' reference sampler: :func:`oacli.trajectory.sample_states` with the per-segment work done once.

Every controller step samples the reference at ``t + k·T`` (k = 0..N). :func:`~oacli.trajectory.sample_states`
recomputes, for each sample, the segment's relative rotation ``δ = log(q_iᵀ ⊗ q_{i+1})`` and its state difference;
here they are computed once per reference segment at construction, and the slerp ``q_i ⊗ exp(s δ)`` (then
normalised) is written out per component instead of through the generic quaternion helpers (their
``np.cross``/``concatenate`` calls dominate on a handful of rows). The formulas and their order of operations are
those of :mod:`oacli.model.quaternion`, so the samples agree with ``sample_states`` to rounding (the tests check).
:func:`attitude_errors` and :func:`feedforward` do the same for the controllers' attitude chart
(:func:`oacli.model.quaternion.error_vector`) and feed-forward (:func:`oacli.trajectory.feedforward_inputs`).
"""

from __future__ import annotations

import numpy as np

from oacli.geometry.vectors import cross_rows
from oacli.model import quaternion as quat
from oacli.types import InertialParams, Trajectory


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
            self._inner_t = np.ascontiguousarray(self.t[1:-1])  # the knots strictly inside (segment search)
            self._dx = self.x[1:] - self.x[:-1]
            self._dt = self.t[1:] - self.t[:-1]
            q = self.x[:, 6:10]
            self._delta = quat.log(quat.multiply(quat.conjugate(q[:-1]), q[1:]))
            # One row per segment [t_i, dt_i, x_i (13), dx_i (13), δ_i (3)]: a step gathers its segments once.
            self._table = np.column_stack([self.t[:-1], self._dt, self.x[:-1], self._dx, self._delta])

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
        # clip(searchsorted(t, times, "right") − 1, 0, K − 2) in one call: the count of t_1..t_{K−2} ≤ time
        # (t is non-decreasing: before t_0 none, from t_{K−1} on all K − 2 of them; NaN sorts last either way).
        idx = np.searchsorted(self._inner_t, times, side="right")
        seg = self._table[idx]  # [t_i, dt_i, x_i, dx_i, δ_i] per sample
        s = (times - seg[:, 0]) / seg[:, 1]
        np.clip(s, 0.0, 1.0, out=s)
        s_col = s[:, None]
        x0 = seg[:, 2:15]
        np.add(x0, s_col * seg[:, 15:28], out=out)
        # exp(s δ) (quat.exp), then q0 ⊗ e (quat.multiply), then quat.normalize; the norms are
        # np.linalg.norm's own sqrt(add.reduce(v * v)) (the same operations without its wrapper).
        phi = s_col * seg[:, 28:31]
        angle = np.sqrt(np.add.reduce(phi * phi, axis=-1, keepdims=True))
        half = 0.5 * angle
        small = angle < 1e-6
        if np.logical_or.reduce(small, axis=None):  # small.any()
            safe = np.where(small, 1.0, angle)
            k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
        else:  # the same values as the np.where form when no angle is small
            k = np.sin(half) / angle
        ev = k * phi
        ew = np.cos(half)
        pv, pw = x0[:, 6:9], x0[:, 9:10]
        q = np.empty((times.size, 4))
        q[:, 0:3] = pw * ev + ew * pv + cross_rows(pv, ev)
        q[:, 3:4] = pw * ew - np.add.reduce(pv * ev, axis=-1, keepdims=True)
        q /= np.sqrt(np.add.reduce(q * q, axis=-1, keepdims=True))
        out[:, 6:10] = np.where(q[:, 3:4] < 0.0, -q, q)
        after = times > t[-1]
        out[after, 3:6] = 0.0
        out[after, 10:13] = 0.0
        return out


def attitude_errors(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """:func:`oacli.model.quaternion.error_vector` (``φ = log(q_refᵀ ⊗ q)``) with its helpers written out.

    Parameters
    ----------
    q_ref : ndarray, shape (4,) or (k, 4)
        Reference attitude(s).
    q : ndarray, shape (k, 4) or (4,)
        Attitude(s).

    Returns
    -------
    ndarray, shape (k, 3) or (3,)
        φ [rad].
    """
    p = np.asarray(q_ref, dtype=float)
    q = np.asarray(q, dtype=float)
    pv, pw = -p[..., :3], p[..., 3:4]  # the conjugate
    qv, qw = q[..., :3], q[..., 3:4]
    vec = pw * qv + qw * pv + cross_rows(pv, qv)  # shape (..., 3): the broadcast of p's and q's
    r = np.empty((*vec.shape[:-1], 4))
    r[..., :3] = vec
    r[..., 3:4] = pw * qw - np.add.reduce(pv * qv, axis=-1, keepdims=True)
    # log (normalise, w >= 0, 2 atan2(|v|, w) v/|v|); the norms are np.linalg.norm's sqrt(add.reduce(v * v)).
    r /= np.sqrt(np.add.reduce(r * r, axis=-1, keepdims=True))
    r = np.where(r[..., 3:4] < 0.0, -r, r)
    v, w = r[..., :3], r[..., 3:4]
    s = np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=True))
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-9
    if np.logical_or.reduce(small, axis=None):  # small.any()
        k = np.where(small, 2.0 / np.where(small, w, 1.0), angle / np.where(small, 1.0, s))
    else:  # the same values as the np.where form when no rotation is small
        k = angle / s
    return np.asarray(k * v)


def feedforward(x_ref: np.ndarray, dt: float, params: InertialParams,
                inertia_tensor_kgm2: np.ndarray | None = None) -> np.ndarray:
    """:func:`oacli.trajectory.feedforward_inputs` written out (the same operations and arguments), shape (N, 6).

    Parameters
    ----------
    x_ref : ndarray, shape (N+1, 13)
        Reference states.
    dt : float
        Sample period [s].
    params : InertialParams
        The controller's model θ (``RobotModel.params``): mass m [kg] and principal inertias I [kg·m²].
    inertia_tensor_kgm2 : ndarray, shape (3, 3), optional
        The full tensor ``J`` [kg·m²] (products of inertia) in place of ``diag(I)``: ``J ω̇ + ω × J ω``
        ([Doerr2021] Eq. 35b); None: the diagonal, the same operations as without the argument.

    Returns
    -------
    ndarray, shape (N, 6)
        ``m (v_{k+1} − v_k)/dt`` and ``I (ω_{k+1} − ω_k)/dt + ω_k × I ω_k``.
    """
    mass_kg, inertia_kgm2 = params.mass_kg, params.inertia_kgm2
    out = np.empty((x_ref.shape[0] - 1, 6))
    out[:, 0:3] = mass_kg * ((x_ref[1:, 3:6] - x_ref[:-1, 3:6]) / dt)
    w = x_ref[:-1, 10:13]
    if inertia_tensor_kgm2 is not None:
        j_t = np.asarray(inertia_tensor_kgm2, dtype=float).T  # rows: (J v)ᵀ = vᵀ Jᵀ
        out[:, 3:6] = ((x_ref[1:, 10:13] - x_ref[:-1, 10:13]) / dt) @ j_t + cross_rows(w, w @ j_t)
        return out
    out[:, 3:6] = inertia_kgm2 * ((x_ref[1:, 10:13] - x_ref[:-1, 10:13]) / dt) + cross_rows(w, inertia_kgm2 * w)
    return out
