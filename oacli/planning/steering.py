"""Exact LQR connections of the double integrator: LQR steering, the cost-to-go metric and LQR interpolation.

A *connection* from ``x_a`` to ``x_b`` in N steps of ``dt`` is the zero-order-hold force sequence that minimises the
exact continuous cost of :mod:`oacli.planning.translational` ([Doerr2021] Eq. 5 in continuous time, with ``Q`` on the
error to the plan's goal ``x_g``) subject to the exact discrete dynamics (:func:`oacli.model.double_integrator.
translational_model`) and the *terminal constraint* ``x_N = x_b``. It is Doerr's finite-horizon LQR problem
(Eqs. 5-9) with an infinite terminal weight: where Perez et al.'s infinite-horizon steering only approaches
``x_b``, this one lands on it exactly, so a rewired node keeps its state and the edges below it stay valid.

Per axis the problem is a quadratic programme in ``U ∈ R^N`` with two equality constraints, and its data depend
on the end points only through ``y = [r_a, v_a, r_b, v_b, r_g, v_g]``. Its KKT system is solved once per N,
giving linear maps ``U = G_N y`` and ``x_k = X_{N,k} y`` and the optimal cost ``J_N = yᵀ M_N y + w_t N dt`` for
every pair of end points (the cost-to-go of Eq. 8: for fixed ``x_b`` it is ``½ x_aᵀ S x_a + x_aᵀ s + c``).

The metric of LQR-RRT* (Eq. 10) is ``J_N`` at a fixed horizon without its constant time term. As a function of
the tree node ``x_a`` (fixed sample ``x_b``) it is ``(x_a - m)ᵀ M_aa (x_a - m) + c(x_b)``, so with
``M_aa = Lᵀ L`` the nearest node is the Euclidean nearest neighbour of ``L m`` among the transformed nodes
``L x_a`` (:class:`LqrMetric`); the reverse direction (nodes as targets, for rewiring) uses ``M_bb`` the same way.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np

from oacli.model.double_integrator import double_integrator
from oacli.model.robot_model import RobotModel
from oacli.planning.translational import CostWeights, TranslationalTrajectory, interval_cost_matrix

#: A connection needs at least two steps (one step cannot reach an arbitrary position and velocity).
MIN_STEPS = 2
#: Limits are accepted up to this relative excess (rounding of the linear maps).
LIMIT_RTOL = 1e-9


#: The connector maps built so far by ``(n_max, dt, mass, per-axis weights)``, the 8 last used (oldest first).
_MAPS: collections.OrderedDict[tuple, tuple] = collections.OrderedDict()


def _connector_maps(n_max: int, dt: float, model: RobotModel, per_axis: tuple[tuple[float, float, float], ...]):
    """The stacked per-axis maps of :class:`LqrConnector` (read-only): they depend only on these numbers (of the
    model, its mass), so they are built once per process (plan and smooth, a benchmark's seeds share them)."""
    if (key := (n_max, dt, model.mass_kg, per_axis)) in _MAPS:
        _MAPS.move_to_end(key)
        return _MAPS[key]
    computed: dict[tuple[float, float, float], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for w_axis in per_axis:  # axes with equal weights share their maps
        if w_axis not in computed:
            computed[w_axis] = axis_maps(n_max, dt, model, *w_axis)
    maps = [computed[w_axis] for w_axis in per_axis]
    g = np.stack([m[0] for m in maps])  # (3, N+1, N, 6)
    x = np.stack([m[1] for m in maps])  # (3, N+1, N+1, 2, 6)
    m = np.stack([m[2] for m in maps])  # (3, N+1, 6, 6)
    v = np.ascontiguousarray(x[:, :, :, 1, :])  # velocity maps (3, N+1, N+1, 6)
    for arr in (g, x, m, v):
        arr.setflags(write=False)
    _MAPS[key] = out = (g, x, m, v, g[:, :, 0, :].tolist())
    while len(_MAPS) > 8:
        _MAPS.popitem(last=False)
    return out


def axis_maps(n_max: int, dt: float, model: RobotModel, q_r: float, q_v: float, r_f: float):
    """Per-axis maps of every N-step connection, ``MIN_STEPS <= N <= n_max``, by one Riccati recursion.

    The end points and the goal are carried as constant states, ``ξ = [r, v, r_g, v_g, r_b, v_b]``, so the
    stage cost ``½ [ξ; u]ᵀ Ŵ [ξ; u]`` (exact interval integrals of
    :func:`~oacli.planning.translational.interval_cost_matrix` over ``z = [r - r_g, v, v - v_g, u]``) is a pure
    quadratic form, and the terminal constraint ``x_N = x_b`` enters through a multiplier ν as the terminal value
    ``νᵀ (x_N - x_b)``. The value with ``j`` steps to go is ``½ ζᵀ P⁽ʲ⁾ ζ`` with ``ζ = [ξ; ν]``: the Riccati step of
    [Doerr2021] Eq. 9 (for the augmented system, no affine terms) gives ``P⁽ʲ⁺¹⁾`` and the gain ``u = K⁽ʲ⁾ ζ``. The
    system is time-invariant, so ``P⁽ᴺ⁾`` is the value of the N-step problem for every N at once; maximising over
    ν (the ν-block of ``P⁽ᴺ⁾`` is negative definite for N >= 2) gives the optimal cost and ``ν*``, and rolling
    the gains forward gives the forces and states as linear maps of ``y = [r_a, v_a, r_b, v_b, r_g, v_g]``.

    Parameters
    ----------
    n_max : int
        Longest horizon [steps].
    dt : float
        Step [s] of the held force.
    model : RobotModel
        The robot; its mass ``model.mass_kg`` [kg] is the double integrator's.
    q_r, q_v, r_f : float
        Position, velocity and force weights of this axis (:class:`~oacli.planning.translational.CostWeights`).

    Returns
    -------
    g : ndarray, shape (n_max + 1, n_max, 6)
        ``U = g[N, :N] @ y`` (rows beyond N are zero).
    states : ndarray, shape (n_max + 1, n_max + 1, 2, 6)
        ``x_k = states[N, k] @ y`` for ``k <= N``.
    cost : ndarray, shape (n_max + 1, 6, 6)
        ``J_N = yᵀ cost[N] y`` (without the time term).
    """
    a, b = double_integrator(dt, 1.0 / model.mass_kg)
    w = interval_cost_matrix(dt, model, q_r, q_v, r_f)
    # z = t_z @ [ξ; u], ξ = [r, v, r_g, v_g, r_b, v_b]
    t_z = np.zeros((4, 7))
    t_z[0, [0, 2]] = [1.0, -1.0]
    t_z[1, 1] = 1.0
    t_z[2, [1, 3]] = [1.0, -1.0]
    t_z[3, 6] = 1.0
    w_hat = t_z.T @ w @ t_z
    phi = np.eye(8)
    phi[0:2, 0:2] = a
    gam = np.zeros((8, 1))
    gam[0:2, 0] = b[:, 0]
    sel = np.zeros((7, 8))  # [ξ; u] from [ζ; u]
    sel[0:6, 0:6] = np.eye(6)
    w_zz = sel[0:6].T @ w_hat[0:6, 0:6] @ sel[0:6]
    w_uz = w_hat[6:7, 0:6] @ sel[0:6]
    w_uu = w_hat[6:7, 6:7]
    p = np.zeros((n_max + 1, 8, 8))
    p[0, 0:2, 6:8] = np.eye(2)
    p[0, 4:6, 6:8] = -np.eye(2)
    p[0] += p[0].T.copy()
    gains = np.zeros((n_max + 1, 1, 8))
    for j in range(n_max):
        q_zz = w_zz + phi.T @ p[j] @ phi
        q_uu = w_uu + gam.T @ p[j] @ gam
        q_uz = w_uz + gam.T @ p[j] @ phi
        gains[j + 1] = -q_uz / q_uu[0, 0]  # gain with j + 1 steps to go
        nxt = q_zz + q_uz.T @ gains[j + 1]
        p[j + 1] = 0.5 * (nxt + nxt.T)
    # From ξ ordering [r, v, r_g, v_g, r_b, v_b] to y ordering [r_a, v_a, r_b, v_b, r_g, v_g].
    perm = np.zeros((6, 6))
    perm[[0, 1, 4, 5, 2, 3], np.arange(6)] = 1.0  # ξ = perm @ y
    g = np.zeros((n_max + 1, n_max, 6))
    states = np.zeros((n_max + 1, n_max + 1, 2, 6))
    cost = np.zeros((n_max + 1, 6, 6))
    # Every horizon N at once: ν* and the cost from P⁽ᴺ⁾, then the gains rolled forward for all N > k together.
    ns = np.arange(MIN_STEPS, n_max + 1)
    pn = p[ns]
    p_vv, p_vx = pn[:, 6:8, 6:8], pn[:, 6:8, 0:6]
    nu = -np.linalg.solve(p_vv, p_vx)  # ν* = nu @ ξ0, per N
    c_x = pn[:, 0:6, 0:6] + np.swapaxes(p_vx, 1, 2) @ nu
    cost[ns] = 0.5 * perm.T @ (0.5 * (c_x + np.swapaxes(c_x, 1, 2))) @ perm
    zeta = np.concatenate([np.broadcast_to(np.eye(6), (ns.shape[0], 6, 6)), nu], axis=1) @ perm  # ζ_0 maps of y
    for k in range(n_max):
        first = max(0, k + 1 - MIN_STEPS)  # horizons N > k still running at step k
        idx = ns[first:]
        z = zeta[first:]
        states[idx, k] = z[:, 0:2]
        u = gains[idx - k] @ z
        g[idx, k] = u[:, 0]
        zeta[first:] = phi @ z + gam @ u
    states[ns, ns] = perm[4:6]  # x_N = x_b exactly
    return g, states, cost


@dataclass(frozen=True)
class ValueFunction:
    """Quadratic cost-to-go ``V(x_a) = ½ x_aᵀ S x_a + x_aᵀ s + c`` of an N-step connection ([Doerr2021] Eq. 8).

    Attributes
    ----------
    S : ndarray, shape (6, 6)
    s : ndarray, shape (6,)
    c : float
    """

    S: np.ndarray
    s: np.ndarray
    c: float

    def __call__(self, x_a: np.ndarray) -> np.ndarray:
        """``V`` at states of shape (..., 6)."""
        x = np.asarray(x_a, dtype=float)
        return 0.5 * np.einsum("...i,ij,...j->...", x, self.S, x) + x @ self.s + self.c


class LqrConnector:
    """Exact N-step LQR connections for ``MIN_STEPS <= N <= max_steps`` (module docstring).

    Parameters
    ----------
    model : RobotModel
        The robot; its mass ``model.mass_kg`` is the double integrator's [kg].
    dt_s : float
        Step [s] of the zero-order-hold force.
    weights : CostWeights
        Cost weights.
    max_steps : int
        Longest connection [steps].
    """

    def __init__(self, model: RobotModel, dt_s: float, weights: CostWeights, max_steps: int) -> None:
        if max_steps < MIN_STEPS:
            raise ValueError(f"max_steps must be >= {MIN_STEPS}, got {max_steps}")
        self.model = model
        self.dt_s = float(dt_s)
        self.weights = weights
        self.max_steps = int(max_steps)
        n_max = self.max_steps
        per_axis = [(float(weights.position[i]), float(weights.velocity[i]), float(weights.force[i])) for i in range(3)]
        self._g, self._x, self._m, self._v, self._first_gain = _connector_maps(
            n_max, self.dt_s, model, tuple(per_axis))
        self._g_flat = self._g.reshape(3, -1, 6)
        self._m_flat = self._m.reshape(3, -1, 6)
        self._v_flat = self._v.reshape(3, -1, 6)
        self._time_cost = weights.time * self.dt_s * np.arange(n_max + 1)
        self._time_cost_min = self._time_cost.copy()  # + inf below MIN_STEPS
        self._time_cost_min[:MIN_STEPS] = np.inf
        self._m_vec = np.ascontiguousarray(self._m.transpose(1, 0, 2, 3).reshape(n_max + 1, -1).T)  # (3·36, N+1)

    # -- vectorised over candidate pairs and horizons ----------------------------------------------------------

    @staticmethod
    def _y(x_a: np.ndarray, x_b: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Per-axis end-point vectors ``y (K, 3, 6)`` = ``[r_a, v_a, r_b, v_b, r_g, v_g]`` per axis."""
        x_a = np.asarray(x_a, dtype=float)
        x_b = np.asarray(x_b, dtype=float)
        if x_a.ndim == 1 and x_b.ndim == 1 and x_a.size == 6 and x_b.size == 6:  # one pair: one concatenation
            stacked = np.concatenate([x_a, x_b, np.asarray(goal, dtype=float).reshape(6)])
            return np.ascontiguousarray(stacked.reshape(1, 6, 3).transpose(0, 2, 1))
        x_a = x_a.reshape(-1, 2, 3)
        x_b = x_b.reshape(-1, 2, 3)
        y = np.empty((max(x_a.shape[0], x_b.shape[0]), 3, 6))
        y[:, :, 0:2] = x_a.transpose(0, 2, 1)
        y[:, :, 2:4] = x_b.transpose(0, 2, 1)
        y[:, :, 4:6] = np.asarray(goal, dtype=float).reshape(2, 3).T
        return y

    def costs(self, x_a: np.ndarray, x_b: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Optimal connection cost for every horizon, shape (K, max_steps + 1); ``inf`` for N < MIN_STEPS.

        Parameters
        ----------
        x_a, x_b : ndarray, shape (6,) or (K, 6)
            Start and end states ``[r, v]`` (broadcast against each other).
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).

        Returns
        -------
        ndarray, shape (K, max_steps + 1)
            Cost per pair and horizon, time term included.
        """
        y = self._y(x_a, x_b, goal)
        # J_N = Σ_axes yᵀ M_N y = (y ⊗ y) · vec(M_N): every pair and horizon in one matrix product.
        yy = (y[:, :, :, None] * y[:, :, None, :]).reshape(y.shape[0], -1)
        j = yy @ self._m_vec
        j += self._time_cost_min
        return j

    def within_limits(
        self, x_a: np.ndarray, x_b: np.ndarray, goal: np.ndarray, force_limit_N: np.ndarray,
        velocity_limit_mps: np.ndarray, steps: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Which connections keep every ``|f_i| <= F_i`` and every sampled ``|v_i| <= V_i``.

        Velocity is linear between samples under a held force, so the sampled check is exact.

        Parameters
        ----------
        x_a, x_b : ndarray, shape (6,) or (K, 6)
            Start and end states ``[r, v]`` (broadcast against each other).
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).
        force_limit_N, velocity_limit_mps : ndarray, shape (3,)
            Limits ``F`` and ``V`` per axis.
        steps : ndarray of int, optional
            Horizons to test (all by default).

        Returns
        -------
        force_ok, velocity_ok : ndarray of bool, shape (K, len(steps))
            False for horizons below ``MIN_STEPS``.
        """
        y = self._y(x_a, x_b, goal)
        if y.shape[0] == 1:  # one pair: every horizon in two batched products beats gathering a subset
            f_lim = np.asarray(force_limit_N, dtype=float).reshape(3, 1) * (1.0 + LIMIT_RTOL)
            v_lim = np.asarray(velocity_limit_mps, dtype=float).reshape(3, 1) * (1.0 + LIMIT_RTOL)
            n_all = self.max_steps + 1
            if steps is None:
                lo, hi = 0, n_all - 1
            else:
                steps = np.asarray(steps, dtype=int)
                if steps.size == 0:
                    return np.zeros((1, 0), dtype=bool), np.zeros((1, 0), dtype=bool)
                lo, hi = int(steps.min()), int(steps.max())
            n_rng = hi - lo + 1
            rows_g, rows_v = self.max_steps, n_all  # rows per horizon of the force and velocity maps
            f_all = np.ones(n_rng, dtype=bool)
            v_all = np.ones(n_rng, dtype=bool)
            for i in range(3):  # matrix-vector products (BLAS) on the horizons lo..hi only
                g = self._g_flat[i, lo * rows_g:(hi + 1) * rows_g]
                v = self._v_flat[i, lo * rows_v:(hi + 1) * rows_v]
                f_all &= np.abs(g @ y[0, i]).reshape(n_rng, -1).max(axis=1) <= f_lim[i, 0]
                v_all &= np.abs(v @ y[0, i]).reshape(n_rng, -1).max(axis=1) <= v_lim[i, 0]
            f_all[: max(0, MIN_STEPS - lo)] = False
            v_all[: max(0, MIN_STEPS - lo)] = False
            if steps is not None:
                f_all, v_all = f_all[steps - lo], v_all[steps - lo]
            return f_all[None, :], v_all[None, :]
        if steps is None:
            g, v = self._g_flat, self._v_flat
            n_steps = self.max_steps + 1
            too_short = np.arange(n_steps) < MIN_STEPS
        else:
            steps = np.asarray(steps, dtype=int)
            n_steps = steps.shape[0]
            g = self._g[:, steps].reshape(3, -1, 6)
            v = self._v[:, steps].reshape(3, -1, 6)
            too_short = steps < MIN_STEPS
        k = y.shape[0]
        f_lim = np.asarray(force_limit_N, dtype=float) * (1.0 + LIMIT_RTOL)
        v_lim = np.asarray(velocity_limit_mps, dtype=float) * (1.0 + LIMIT_RTOL)
        force_ok = np.ones((k, n_steps), dtype=bool)
        velocity_ok = np.ones((k, n_steps), dtype=bool)
        for i in range(3):
            yi = y[:, i, :].T  # (6, K)
            u = np.abs(g[i] @ yi).reshape(n_steps, -1, k).max(axis=1)  # (steps, K)
            vel = np.abs(v[i] @ yi).reshape(n_steps, -1, k).max(axis=1)
            force_ok &= (u <= f_lim[i]).T
            velocity_ok &= (vel <= v_lim[i]).T
        force_ok[:, too_short] = False
        velocity_ok[:, too_short] = False
        return force_ok, velocity_ok

    def batch(
        self, x_a: np.ndarray, x_b: np.ndarray, goal: np.ndarray, steps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Forces and sampled states of C connections at once, each with its own end points and horizon.

        The same linear maps as :meth:`trajectory` (``U = G_N y``, ``x_k = X_{N,k} y``) gathered for every
        connection and applied in one product, so the limit and sample-point checks of a whole candidate list
        (choose-parent, goal links, shortcut horizons) cost one call instead of one trajectory each.

        Parameters
        ----------
        x_a, x_b : ndarray, shape (6,) or (C, 6)
            Start and end states ``[r, v]`` (broadcast against each other).
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).
        steps : ndarray of int, shape (C,)
            Horizon ``N_c`` of each connection, ``MIN_STEPS <= N_c <= max_steps``.

        Returns
        -------
        forces : ndarray, shape (C, S, 3)
            Held forces [N], ``S = max(steps)``; zero beyond a connection's horizon.
        states : ndarray, shape (C, S + 1, 6)
            Sampled states ``[r, v]`` every ``dt``, the end points exact; zero beyond a connection's horizon.
        """
        steps = np.asarray(steps, dtype=np.int64).reshape(-1)
        c = steps.shape[0]
        s = int(steps.max()) if c else 0
        if c and (s > self.max_steps or int(steps.min()) < MIN_STEPS):
            raise ValueError(f"steps must be in [{MIN_STEPS}, {self.max_steps}]")
        y = self._y(x_a, x_b, goal)
        if y.shape[0] == 1:  # one pair of end points for every horizon: per axis one matrix-vector product
            y0 = y[0][:, :, None]  # (3, 6, 1)
            u = (self._g[:, steps, :s].reshape(3, -1, 6) @ y0).reshape(3, c, s).transpose(1, 2, 0)
            xs = ((self._x[:, steps, : s + 1].reshape(3, -1, 6) @ y0).reshape(3, c, s + 1, 2)
                  .transpose(1, 2, 3, 0).reshape(c, s + 1, 6))
        else:
            u = np.einsum("icsj,cij->csi", self._g[:, steps, :s], y)
            xs = np.einsum("icskj,cij->cski", self._x[:, steps, : s + 1], y).reshape(c, s + 1, 6)
        xs[:, 0] = np.asarray(x_a, dtype=float).reshape(-1, 6)
        xs[np.arange(c), steps] = np.asarray(x_b, dtype=float).reshape(-1, 6)
        return u, xs

    # -- one connection -------------------------------------------------------------------------------------

    def forces(self, x_a: np.ndarray, x_b: np.ndarray, goal: np.ndarray, steps: int) -> np.ndarray:
        """Optimal held forces of the ``steps``-step connection, shape (steps, 3) [N].

        Parameters
        ----------
        x_a, x_b : ndarray, shape (6,)
            Start and end states ``[r, v]``.
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).
        steps : int
            Horizon N [steps], ``MIN_STEPS <= N <= max_steps``.

        Returns
        -------
        ndarray, shape (steps, 3)
            Held forces [N].
        """
        self._check_steps(steps)
        y = self._y(x_a, x_b, goal)[0]
        return np.einsum("ija,ia->ji", self._g[:, steps, :steps], y)

    def trajectory(
        self, x_a: np.ndarray, x_b: np.ndarray, goal: np.ndarray, steps: int, t0: float = 0.0
    ) -> TranslationalTrajectory:
        """The ``steps``-step connection as a trajectory sampled every ``dt`` (end points exact).

        Parameters
        ----------
        x_a, x_b : ndarray, shape (6,)
            Start and end states ``[r, v]``.
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).
        steps : int
            Horizon N [steps], ``MIN_STEPS <= N <= max_steps``.
        t0 : float, optional
            Time [s] of the first sample.

        Returns
        -------
        TranslationalTrajectory
        """
        self._check_steps(steps)
        y = self._y(x_a, x_b, goal)[0]
        u = (self._g[:, steps, :steps] @ y[:, :, None])[:, :, 0].T  # (steps, 3)
        states = (self._x[:, steps, : steps + 1].reshape(3, -1, 6) @ y[:, :, None]).reshape(3, steps + 1, 2)
        x = np.empty((steps + 1, 6))
        x[:, 0:3] = states[:, :, 0].T
        x[:, 3:6] = states[:, :, 1].T
        x[0] = np.asarray(x_a, dtype=float).reshape(6)
        x[-1] = np.asarray(x_b, dtype=float).reshape(6)
        t = t0 + self.dt_s * np.arange(steps + 1)
        return TranslationalTrajectory.trusted(t, x, np.ascontiguousarray(u), self.model)

    def saturated_rollout(
        self, x_a: np.ndarray, x_target: np.ndarray, goal: np.ndarray, steps: int, force_limit_N: np.ndarray,
        velocity_limit_mps: np.ndarray,
    ) -> TranslationalTrajectory:
        """LQR steering within the limits: a shrinking-horizon LQR rollout towards ``x_target``.

        At step k the force is the first force of the optimal ``(steps - k)``-step connection from the current
        state to ``x_target`` (the last step matches the target velocity), clipped to ``|f_i| <= F_i`` and to the
        range that keeps ``|v_i| <= V_i`` at the next sample. The rollout reaches ``x_target`` when no limit is
        active and otherwise ends where the saturated motion gets to: a state reachable within the limits.

        Parameters
        ----------
        x_a : ndarray, shape (6,)
            Start state.
        x_target : ndarray, shape (6,)
            State to steer to.
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).
        steps : int
            Number of steps of the rollout.
        force_limit_N, velocity_limit_mps : ndarray, shape (3,)
            Limits per axis.

        Returns
        -------
        TranslationalTrajectory
            ``steps`` intervals of ``dt_s`` from ``x_a``.
        """
        xs, us = self._saturated(x_a, x_target, goal, steps, force_limit_N, velocity_limit_mps)
        return TranslationalTrajectory(self.dt_s * np.arange(steps + 1), xs, us, self.model)

    def saturated_end(
        self, x_a: np.ndarray, x_target: np.ndarray, goal: np.ndarray, steps: int, force_limit_N: np.ndarray,
        velocity_limit_mps: np.ndarray,
    ) -> np.ndarray:
        """The last state of :meth:`saturated_rollout` (the same arithmetic), without building the trajectory.

        Parameters
        ----------
        x_a : ndarray, shape (6,)
            Start state.
        x_target : ndarray, shape (6,)
            State to steer to.
        goal : ndarray, shape (6,)
            Goal state of the plan (the cost's ``x_g``).
        steps : int
            Number of steps of the rollout.
        force_limit_N, velocity_limit_mps : ndarray, shape (3,)
            Limits per axis.

        Returns
        -------
        ndarray, shape (6,)
            The rollout's end state.
        """
        xs, _ = self._saturated(x_a, x_target, goal, steps, force_limit_N, velocity_limit_mps)
        return xs[-1].copy()

    def _saturated(self, x_a, x_target, goal, steps, force_limit_N, velocity_limit_mps):
        self._check_steps(steps)
        m, dt = self.model.mass_kg, self.dt_s
        # Scalar arithmetic per axis: a handful of flops per step, far below numpy's per-call overhead.
        f_lim = [float(f) for f in np.asarray(force_limit_N, dtype=float).reshape(3)]
        v_lim = [float(v) for v in np.asarray(velocity_limit_mps, dtype=float).reshape(3)]
        x = [float(v) for v in np.asarray(x_a, dtype=float).reshape(6)]
        target = [float(v) for v in np.asarray(x_target, dtype=float).reshape(6)]
        goal = [float(v) for v in np.asarray(goal, dtype=float).reshape(6)]
        g0 = self._first_gain
        xs = np.empty((steps + 1, 6))
        us = np.empty((steps, 3))
        for i in range(3):  # the axes are independent: one scalar loop per axis over the steps
            r, v = x[i], x[3 + i]
            t_r, t_v, g_r, g_v = target[i], target[3 + i], goal[i], goal[3 + i]
            f_i, v_i, gains = f_lim[i], v_lim[i], g0[i]
            col_r, col_v, col_u = [r], [v], []
            for left in range(steps, 0, -1):
                if left >= MIN_STEPS:
                    g = gains[left]
                    ui = g[0] * r + g[1] * v + g[2] * t_r + g[3] * t_v + g[4] * g_r + g[5] * g_v
                else:
                    ui = m * (t_v - v) / dt
                lo = m * (-v_i - v) / dt
                if lo < -f_i:
                    lo = -f_i
                hi = m * (v_i - v) / dt
                if hi > f_i:
                    hi = f_i
                if hi < lo:
                    hi = lo
                if ui < lo:
                    ui = lo
                if ui > hi:
                    ui = hi
                acc = ui / m
                r = r + v * dt + 0.5 * acc * dt * dt
                v = v + acc * dt
                col_r.append(r)
                col_v.append(v)
                col_u.append(ui)
            xs[:, i] = col_r
            xs[:, 3 + i] = col_v
            us[:, i] = col_u
        return xs, us

    def value_function(self, steps: int, x_b: np.ndarray, goal: np.ndarray) -> ValueFunction:
        """Cost-to-go ``V(x_a)`` of reaching ``x_b`` in ``steps`` steps, in the form of [Doerr2021] Eq. 8.

        Parameters
        ----------
        steps : int
            Horizon N [steps].
        x_b : ndarray, shape (6,)
            End state.
        goal : ndarray, shape (6,)
            Goal state of the plan.

        Returns
        -------
        ValueFunction
            ``S``, ``s``, ``c`` of ``V(x_a)`` (time term not included).
        """
        self._check_steps(steps)
        x_b = np.asarray(x_b, dtype=float).reshape(6)
        goal = np.asarray(goal, dtype=float).reshape(6)
        s_mat = np.zeros((6, 6))
        s_vec = np.zeros(6)
        c = self._time_cost[steps]
        for i in range(3):
            m = self._m[i, steps]
            rest = np.array([x_b[i], x_b[3 + i], goal[i], goal[3 + i]])
            idx = [i, 3 + i]
            s_mat[np.ix_(idx, idx)] = 2.0 * m[0:2, 0:2]
            s_vec[idx] = 2.0 * m[0:2, 2:6] @ rest
            c += rest @ m[2:6, 2:6] @ rest
        return ValueFunction(s_mat, s_vec, float(c))

    def metric(self, steps: int) -> LqrMetric:
        """The cost-to-go metric at a fixed horizon (see :class:`LqrMetric`).

        Parameters
        ----------
        steps : int
            Horizon N [steps].

        Returns
        -------
        LqrMetric
        """
        self._check_steps(steps)
        return LqrMetric(self._m[:, steps], steps)

    def _check_steps(self, steps: int) -> None:
        if not MIN_STEPS <= steps <= self.max_steps:
            raise ValueError(f"steps must be in [{MIN_STEPS}, {self.max_steps}], got {steps}")


class LqrMetric:
    """The LQR cost-to-go at a fixed horizon as a Euclidean distance in transformed coordinates (Eqs. 10-11).

    ``J(x_a → x_b) = |L_a x_a - L_a m_a(x_b)|² + c_a(x_b)`` (forward: nodes as sources) and
    ``J(x_a → x_b) = |L_b x_b - L_b m_b(x_a)|² + c_b(x_a)`` (backward: nodes as targets), without the constant
    time term. ``L_a``, ``L_b`` are per-axis Cholesky factors of the 2x2 blocks ``M_aa``, ``M_bb`` of the cost.

    Parameters
    ----------
    cost : ndarray, shape (3, 6, 6)
        Per-axis cost matrices ``M`` over ``y = [r_a, v_a, r_b, v_b, r_g, v_g]``.
    steps : int
        The horizon they belong to.
    """

    def __init__(self, cost: np.ndarray, steps: int) -> None:
        self.steps = int(steps)
        self._fwd = self._side(cost, [0, 1], [2, 3, 4, 5])
        self._bwd = self._side(cost, [2, 3], [0, 1, 4, 5])

    @staticmethod
    def _side(cost: np.ndarray, own: list[int], rest: list[int]):
        chol = np.empty((3, 2, 2))
        shift = np.empty((3, 2, 4))
        const = np.empty((3, 4, 4))
        for i in range(3):
            m_oo = cost[i][np.ix_(own, own)]
            m_or = cost[i][np.ix_(own, rest)]
            m_rr = cost[i][np.ix_(rest, rest)]
            chol[i] = np.linalg.cholesky(m_oo).T  # upper: m_oo = Lᵀ L
            sol = np.linalg.solve(m_oo, m_or)
            shift[i] = -sol  # m = shift @ rest
            const[i] = m_rr - m_or.T @ sol
        return chol, shift, const

    @staticmethod
    def _axes(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.stack([x[..., 0:3], x[..., 3:6]], axis=-1)  # (..., 3 axes, 2)

    @staticmethod
    def _flat(z: np.ndarray) -> np.ndarray:
        return z.reshape(*z.shape[:-2], 6)

    def _coords(self, side, x: np.ndarray) -> np.ndarray:
        chol = side[0]
        return self._flat(np.einsum("iab,...ib->...ia", chol, self._axes(x)))

    def _query(self, side, other: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, float]:
        chol, shift, const = side
        o = self._axes(other)
        g = self._axes(goal)
        rest = np.concatenate([o, g], axis=-1)  # (3, 4)
        m = np.einsum("iab,ib->ia", shift, rest)
        c = float(np.einsum("ia,iab,ib->", rest, const, rest))
        return self._flat(np.einsum("iab,ib->ia", chol, m)), c

    def source_coords(self, x: np.ndarray) -> np.ndarray:
        """Transformed coordinates of states used as connection *sources*, shape (..., 6).

        Parameters
        ----------
        x : ndarray, shape (..., 6)
            States ``[r, v]``.

        Returns
        -------
        ndarray, shape (..., 6)
        """
        return self._coords(self._fwd, x)

    def target_coords(self, x: np.ndarray) -> np.ndarray:
        """Transformed coordinates of states used as connection *targets*, shape (..., 6).

        Parameters
        ----------
        x : ndarray, shape (..., 6)
            States ``[r, v]``.

        Returns
        -------
        ndarray, shape (..., 6)
        """
        return self._coords(self._bwd, x)

    def query_to(self, x_b: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, float]:
        """``(z, c)``: ``J(x_a → x_b) = |source_coords(x_a) - z|² + c`` for every source ``x_a``.

        Parameters
        ----------
        x_b : ndarray, shape (6,)
            The target.
        goal : ndarray, shape (6,)
            Goal state of the plan.

        Returns
        -------
        z : ndarray, shape (6,)
            Centre in the transformed coordinates.
        c : float
            Constant cost offset.
        """
        return self._query(self._fwd, x_b, goal)

    def query_from(self, x_a: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, float]:
        """``(z, c)``: ``J(x_a → x_b) = |target_coords(x_b) - z|² + c`` for every target ``x_b``.

        Parameters
        ----------
        x_a : ndarray, shape (6,)
            The source.
        goal : ndarray, shape (6,)
            Goal state of the plan.

        Returns
        -------
        z : ndarray, shape (6,)
            Centre in the transformed coordinates.
        c : float
            Constant cost offset.
        """
        return self._query(self._bwd, x_a, goal)
