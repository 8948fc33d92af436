"""Translational trajectories of the double integrator under a zero-order-hold force, and their exact cost.

The planners work in the translational state ``x = [r (3) m, v (3) m/s]`` of [Doerr2021] Eq. 34: ``r̈ = f / m`` per
world axis with the force ``f`` held constant over each interval. A :class:`TranslationalTrajectory` is a sequence
of such intervals; between samples the position is the exact quadratic ``r(τ) = r_k + v_k τ + ½ (f_k/m) τ²``.

Cost
----
Every planner, the shortcutting and the summaries use one cost, Doerr's quadratic cost (Eq. 5) in continuous time
plus a price on time::

    J = ∫ [ w_t + ½ f(t)ᵀ R f(t) + ½ (x(t) - x_g)ᵀ Q (x(t) - x_g) ] dt,   Q = diag(q_r, q_v) per axis,

with ``x_g`` the goal of the plan (at rest). For a zero-order-hold force the integral over one interval of length
``h`` is exactly ``w_t h + Σ_axes ½ zᵀ W(h) z`` with ``z = [r_k - r_g, v_k, v_k - v_g, f_k]`` per axis and
``W(h)`` from :func:`interval_cost_matrix`. The cost is therefore additive over intervals and independent of how an
interval is subdivided: cutting a trajectory at any sample and splicing in another piece changes the cost by
exactly the difference of the two pieces' costs (what LQR shortcutting needs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import Pieces
from oacli.model.robot_model import RobotModel

#: Relative tolerance of the zero-order-hold consistency check of sampled trajectories.
ZOH_RTOL = 1e-7


@dataclass(frozen=True)
class CostWeights:
    """Weights of the trajectory cost (see the module docstring).

    Attributes
    ----------
    position : ndarray, shape (3,)
        ``q_r`` per axis [1/(m²·s)], >= 0, on the position error to the goal.
    velocity : ndarray, shape (3,)
        ``q_v`` per axis [s/m²], >= 0, on the velocity error to the goal (at rest: on the speed).
    force : ndarray, shape (3,)
        ``R`` per axis [1/(N²·s)], > 0.
    time : float
        ``w_t`` [1/s], > 0 (every connection then has a positive cost, which RRT*'s rewiring relies on).
    """

    position: np.ndarray
    velocity: np.ndarray
    force: np.ndarray
    time: float

    def __post_init__(self) -> None:
        for name in ("position", "velocity", "force"):
            arr = np.array(getattr(self, name), dtype=float).reshape(3)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "time", float(self.time))
        if np.any(self.position < 0) or np.any(self.velocity < 0):
            raise ValueError("position and velocity weights must be >= 0")
        if np.any(self.force <= 0):
            raise ValueError("force weights must be > 0")
        if not self.time > 0:
            raise ValueError("the time weight must be > 0")


def interval_cost_matrix(h: float, model: RobotModel, q_r: float, q_v: float, r_f: float) -> np.ndarray:
    """``W(h)`` of one axis with ``½ zᵀ W z = ∫₀ʰ [½ q_r (r(τ) - r_g)² + ½ q_v (v(τ) - v_g)² + ½ r_f f²] dτ``.

    ``z = [r₀ - r_g, v₀, v₀ - v_g, f]`` (start position error, start velocity, start velocity error, held force),
    ``v(τ) = v₀ + (f/m) τ``, ``r(τ) = r₀ + v₀ τ + ½ (f/m) τ²``; the entries are the exact polynomial integrals.

    Parameters
    ----------
    h : float
        Interval length [s].
    model : RobotModel
        The robot; its mass ``m = model.mass_kg`` [kg].
    q_r, q_v, r_f : float
        Position, velocity and force weights of the axis.

    Returns
    -------
    ndarray, shape (4, 4)
    """
    m = model.mass_kg
    w = np.zeros((4, 4))
    # position error e_r + v τ + ½ a τ², a = f/m: indices (0, 1, 3)
    pos = q_r * np.array(
        [
            [h, h**2 / 2.0, h**3 / (6.0 * m)],
            [h**2 / 2.0, h**3 / 3.0, h**4 / (8.0 * m)],
            [h**3 / (6.0 * m), h**4 / (8.0 * m), h**5 / (20.0 * m * m)],
        ]
    )
    w[np.ix_([0, 1, 3], [0, 1, 3])] += pos
    # velocity error e_v + a τ: indices (2, 3)
    vel = q_v * np.array([[h, h**2 / (2.0 * m)], [h**2 / (2.0 * m), h**3 / (3.0 * m * m)]])
    w[np.ix_([2, 3], [2, 3])] += vel
    w[3, 3] += r_f * h
    return w


def interval_costs(
    x: np.ndarray, u: np.ndarray, h: np.ndarray, model: RobotModel, weights: CostWeights, goal: np.ndarray
) -> np.ndarray:
    """Exact cost of each zero-order-hold interval, shape (n,).

    Parameters
    ----------
    x : ndarray, shape (n, 6)
        States at the start of each interval.
    u : ndarray, shape (n, 3)
        Held forces [N].
    h : ndarray, shape (n,)
        Interval lengths [s].
    model : RobotModel
        The robot (its mass [kg]).
    weights : CostWeights
    goal : ndarray, shape (6,)
        Goal state ``x_g``.

    Returns
    -------
    ndarray, shape (n,)
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    h = np.asarray(h, dtype=float)[:, None]
    a = u / model.mass_kg
    e_r = x[:, 0:3] - goal[0:3]
    v = x[:, 3:6]
    e_v = v - goal[3:6]
    q_r, q_v, r_f = weights.position, weights.velocity, weights.force
    pos = (
        e_r**2 * h
        + e_r * v * h**2
        + (v**2 + e_r * a) * h**3 / 3.0
        + v * a * h**4 / 4.0
        + a**2 * h**5 / 20.0
    )
    vel = e_v**2 * h + e_v * a * h**2 + a**2 * h**3 / 3.0
    return weights.time * h[:, 0] + 0.5 * np.sum(q_r * pos + q_v * vel + r_f * u**2 * h, axis=1)


def _arc_length(v0: np.ndarray, acc: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Exact length of ``∫₀ʰ |v0 + acc τ| dτ`` per row (closed form of the integral of sqrt(quadratic))."""
    a2 = np.sum(acc * acc, axis=1)
    speed0 = np.linalg.norm(v0, axis=1)
    out = speed0 * h
    curved = a2 > 1e-30
    if np.any(curved):
        a2c = a2[curved]
        sa = np.sqrt(a2c)
        b = np.sum(v0[curved] * acc[curved], axis=1) / a2c  # shift: |v0 + aτ|² = A[(τ + b)² + q]
        q = np.clip(np.sum(v0[curved] ** 2, axis=1) / a2c - b * b, 0.0, None)

        def prim(u: np.ndarray) -> np.ndarray:
            root = np.sqrt(u * u + q)
            with np.errstate(divide="ignore", invalid="ignore"):
                log_term = np.where(q > 1e-300, q * np.arcsinh(u / np.sqrt(np.where(q > 1e-300, q, 1.0))), 0.0)
            return 0.5 * (u * root + log_term)

        out[curved] = sa * (prim(h[curved] + b) - prim(b))
    return out


@dataclass(frozen=True)
class TranslationalTrajectory:
    """A double-integrator trajectory under a zero-order-hold force (see the module docstring).

    Attributes
    ----------
    t : ndarray, shape (n+1,)
        Strictly increasing sample times [s].
    x : ndarray, shape (n+1, 6)
        States ``[r (m), v (m/s)]`` at the samples.
    u : ndarray, shape (n, 3)
        World-frame force [N] held from ``t[k]`` to ``t[k+1]``.
    model : RobotModel
        The robot model the samples follow (its mass, :attr:`mass_kg`, is the double integrator's).
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    model: RobotModel

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float).reshape(-1)
        x = np.array(self.x, dtype=float).reshape(t.shape[0], 6)
        u = np.array(self.u, dtype=float).reshape(max(t.shape[0] - 1, 0), 3)
        if t.shape[0] < 1:
            raise ValueError("a trajectory needs at least one sample")
        if np.any(np.diff(t) <= 0):
            raise ValueError("t must be strictly increasing")
        for arr in (t, x, u):
            arr.setflags(write=False)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "u", u)
        if not isinstance(self.model, RobotModel):
            raise TypeError(f"model: expected a RobotModel, got {type(self.model).__name__}")

    @property
    def mass_kg(self) -> float:
        """Mass [kg] of the double integrator, ``model.mass_kg``."""
        return self.model.mass_kg

    # -- construction ----------------------------------------------------------------------------------------

    @classmethod
    def trusted(cls, t: np.ndarray, x: np.ndarray, u: np.ndarray, model: RobotModel) -> TranslationalTrajectory:
        """Wrap float arrays of the right shapes, ``t`` strictly increasing, without copying or checking them.

        For the planners' inner loops, whose arrays are built from already valid trajectories; the arrays are
        made read-only like the checked constructor's.

        Parameters
        ----------
        t : ndarray, shape (n+1,)
        x : ndarray, shape (n+1, 6)
        u : ndarray, shape (n, 3)
        model : RobotModel

        Returns
        -------
        TranslationalTrajectory
        """
        out = object.__new__(cls)
        for arr in (t, x, u):
            arr.setflags(write=False)
        object.__setattr__(out, "t", t)
        object.__setattr__(out, "x", x)
        object.__setattr__(out, "u", u)
        object.__setattr__(out, "model", model)
        return out

    @classmethod
    def from_forces(cls, x0: np.ndarray, forces: np.ndarray, h: np.ndarray, model: RobotModel, t0: float = 0.0):
        """Propagate the exact double integrator from ``x0`` under held ``forces (n, 3)`` for durations ``h``.

        Parameters
        ----------
        x0 : ndarray, shape (6,)
            Initial state ``[r, v]``.
        forces : ndarray, shape (n, 3)
            Held forces [N].
        h : ndarray, shape (n,)
            Interval lengths [s].
        model : RobotModel
            The robot (its mass [kg]).
        t0 : float, optional
            Time [s] of the first sample.

        Returns
        -------
        TranslationalTrajectory
        """
        forces = np.asarray(forces, dtype=float).reshape(-1, 3)
        h = np.broadcast_to(np.asarray(h, dtype=float), (forces.shape[0],))
        x = np.empty((forces.shape[0] + 1, 6))
        x[0] = x0
        acc = forces / model.mass_kg
        for k in range(forces.shape[0]):
            x[k + 1, 0:3] = x[k, 0:3] + x[k, 3:6] * h[k] + 0.5 * acc[k] * h[k] ** 2
            x[k + 1, 3:6] = x[k, 3:6] + acc[k] * h[k]
        return cls(t0 + np.concatenate([[0.0], np.cumsum(h)]), x, forces, model)

    @staticmethod
    def concatenate(parts: list[TranslationalTrajectory]) -> TranslationalTrajectory:
        """Join trajectories end to start (each part's time restarts where the previous ended).

        The first state of each later part replaces the last state of the previous one; they must agree.

        Parameters
        ----------
        parts : list of TranslationalTrajectory
            At least one part, all of the same model.

        Returns
        -------
        TranslationalTrajectory
        """
        if not parts:
            raise ValueError("nothing to concatenate")
        t = [parts[0].t - parts[0].t[0]]
        x = [parts[0].x]
        u = [parts[0].u]
        for part in parts[1:]:
            if not np.allclose(part.x[0], x[-1][-1], rtol=0.0, atol=1e-9):
                raise ValueError("consecutive parts do not meet")
            t.append(t[-1][-1] + part.t[1:] - part.t[0])
            x.append(part.x[1:])
            u.append(part.u)
        return TranslationalTrajectory(np.concatenate(t), np.vstack(x), np.vstack(u), parts[0].model)

    # -- queries ---------------------------------------------------------------------------------------------

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def h(self) -> np.ndarray:
        """Interval lengths [s], shape (n,)."""
        return np.diff(self.t)

    @property
    def duration_s(self) -> float:
        """Total duration [s]."""
        return float(self.t[-1] - self.t[0])

    def pieces(self) -> Pieces:
        """The constant-acceleration pieces for continuous collision checking.

        Returns
        -------
        Pieces
        """
        return Pieces(self.x[:-1, 0:3], self.x[:-1, 3:6], self.u / self.mass_kg, self.h)

    def interval_costs(self, weights: CostWeights, goal: np.ndarray) -> np.ndarray:
        """Exact cost of each interval (module docstring), shape (n,).

        Parameters
        ----------
        weights : CostWeights
        goal : ndarray, shape (6,)
            Goal state ``x_g``.

        Returns
        -------
        ndarray, shape (n,)
        """
        return interval_costs(self.x[:-1], self.u, self.h, self.model, weights, np.asarray(goal, dtype=float))

    def cost(self, weights: CostWeights, goal: np.ndarray) -> float:
        """Exact total cost ``J`` (module docstring).

        Parameters
        ----------
        weights : CostWeights
        goal : ndarray, shape (6,)
            Goal state ``x_g``.

        Returns
        -------
        float
        """
        return float(self.interval_costs(weights, goal).sum())

    def path_length_m(self) -> float:
        """Exact length of the path traced by the position [m].

        Returns
        -------
        float
        """
        return float(_arc_length(self.x[:-1, 3:6], self.u / self.mass_kg, self.h).sum())

    def impulse_Ns(self) -> float:
        """Total impulse ``∫ Σ_i |f_i| dt`` [N·s] (what the thrusters spend).

        Returns
        -------
        float
        """
        return float(np.sum(np.abs(self.u) * self.h[:, None]))

    def max_abs_force_N(self) -> np.ndarray:
        """Largest ``|f_i|`` per axis [N], shape (3,).

        Returns
        -------
        ndarray, shape (3,)
        """
        return np.abs(self.u).max(axis=0) if self.u.shape[0] else np.zeros(3)

    def max_abs_velocity_mps(self) -> np.ndarray:
        """Largest ``|v_i|`` per axis [m/s] (exact: velocity is linear between samples), shape (3,).

        Returns
        -------
        ndarray, shape (3,)
        """
        return np.abs(self.x[:, 3:6]).max(axis=0)

    def states_at(self, times: np.ndarray) -> np.ndarray:
        """Exact states at ``times`` [s] inside ``[t[0], t[-1]]``, shape (len(times), 6).

        Parameters
        ----------
        times : ndarray, shape (k,)
            Times [s].

        Returns
        -------
        ndarray, shape (k, 6)
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if len(self) == 1:
            return np.tile(self.x[0], (times.size, 1))
        k = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, len(self) - 2)
        tau = (times - self.t[k])[:, None]
        acc = self.u[k] / self.mass_kg
        out = np.empty((times.size, 6))
        out[:, 0:3] = self.x[k, 0:3] + self.x[k, 3:6] * tau + 0.5 * acc * tau * tau
        out[:, 3:6] = self.x[k, 3:6] + acc * tau
        return out

    def refined(self, dt_s: float) -> TranslationalTrajectory:
        """The same motion sampled every ``dt_s`` (each interval must be an integer multiple of ``dt_s``).

        Parameters
        ----------
        dt_s : float
            New sample period [s].

        Returns
        -------
        TranslationalTrajectory
            ``self`` when the samples are already ``dt_s`` apart.
        """
        h = self.h
        counts = np.rint(h / dt_s).astype(int)
        if np.any(counts < 1) or np.any(np.abs(counts * dt_s - h) > 1e-9 * np.maximum(h, 1.0)):
            raise ValueError(f"every interval must be a multiple of {dt_s} s")
        if np.all(counts == 1):
            return self
        if np.all(counts == counts[0]) and np.all(h == h[0]):
            return self._refined_uniform(int(counts[0]))
        piece = np.repeat(np.arange(h.shape[0]), counts)  # the interval of every new sample after the first
        sample_idx = np.concatenate([[0], np.cumsum(counts)])
        j = np.arange(1, piece.shape[0] + 1) - sample_idx[piece]  # 1 .. counts[k] within interval k
        t_all = np.empty(piece.shape[0] + 1)
        t_all[0] = self.t[0]
        t_all[1:] = self.t[piece] + h[piece] * j / counts[piece]
        t_all[sample_idx] = self.t  # interval ends exact
        x_all = self.states_at(t_all)
        x_all[sample_idx] = self.x  # keep the original samples bit-exact
        return TranslationalTrajectory(t_all, x_all, self.u[piece], self.model)

    def _refined_uniform(self, c: int) -> TranslationalTrajectory:
        """:meth:`refined` when every interval has the same length and splits into ``c`` samples."""
        n = len(self) - 1
        h = float(self.t[1] - self.t[0])
        tau = h * np.arange(c) / c  # offsets of the new samples in an interval, the start included
        acc = self.u / self.mass_kg  # (n, 3)
        r0, v0 = self.x[:-1, None, 0:3], self.x[:-1, None, 3:6]
        tt = tau[None, :, None]
        x_all = np.empty((n * c + 1, 6))
        body = x_all[:-1].reshape(n, c, 6)
        body[:, :, 0:3] = r0 + v0 * tt + 0.5 * acc[:, None, :] * tt * tt
        body[:, :, 3:6] = v0 + acc[:, None, :] * tt
        body[:, 0, :] = self.x[:-1]  # keep the original samples bit-exact
        x_all[-1] = self.x[-1]
        t_all = np.empty(n * c + 1)
        t_all[:-1] = (self.t[:-1, None] + tau[None, :]).reshape(-1)
        t_all[::c] = self.t
        return TranslationalTrajectory.trusted(t_all, x_all, np.repeat(self.u, c, axis=0), self.model)

    def zoh_residual(self) -> float:
        """Largest deviation [m or m/s] of the samples from the exact propagation of the held forces.

        Returns
        -------
        float
            0 for fewer than two samples.
        """
        if len(self) < 2:
            return 0.0
        h = self.h[:, None]
        acc = self.u / self.mass_kg
        r_pred = self.x[:-1, 0:3] + self.x[:-1, 3:6] * h + 0.5 * acc * h * h
        v_pred = self.x[:-1, 3:6] + acc * h
        return float(max(np.abs(r_pred - self.x[1:, 0:3]).max(), np.abs(v_pred - self.x[1:, 3:6]).max()))

    def is_zoh_consistent(self) -> bool:
        """True when the samples follow the held forces within :data:`ZOH_RTOL` of the motion's scale.

        Returns
        -------
        bool
        """
        scale = max(1.0, float(np.abs(self.x).max()))
        return self.zoh_residual() <= ZOH_RTOL * scale
