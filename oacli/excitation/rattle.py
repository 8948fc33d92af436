"""Online information-aware receding-horizon planning (RATTLE; [ReSWARM2023] §4.4 and §4.6).

Every replan (12 s as flown) the planner solves, from the current measured state and with the latest parameter
estimate ``θ̂`` and its standard deviations ``σ``, a horizon of N steps (40 × 0.3 s as flown)::

    minimise   Σ_{k=1}^{N-1} ‖x_k ⊖ x_goal‖²_Q + Σ_{k=0}^{N-1} ‖u_k‖²_R + ‖x_N ⊖ x_goal‖²_{Q_N}
               − Σ_i γ_i · ½ log(1 + F_ii σ_i²)
    subject to the RK4 dynamics ([Doerr2021] Eqs. 33-36) with θ̂, input, velocity and rate limits, keep-in boxes and
               keep-out ellipsoids,

where ``x ⊖ x_goal = [r − r_goal, v, e(q), ω]`` (``e`` the small-angle attitude error) and ``F`` is the Fisher
information of the horizon's measurements (:mod:`oacli.excitation.information`). ``½ log(1 + F_ii σ_i²)`` is the
information [nats] the horizon would add about parameter i alone given its current uncertainty: it is large while
σ_i is large and fades as the parameter is learned. The per-parameter weight follows the published decay rule
([ReSWARM2023] Fig. 4; [RATTLE2022]; values of [RattleCode] execute_asap config)::

    γ_i = γ0_i · exp(−β · floor_i / σ_i),   and γ_i = 0 once σ_i ≤ α · floor_i,

with α = 2.2, β = 5, floor = [0.03, 1e-4, 1e-4, 1e-4], γ0 = [50, 20, 20, 20] for [m, Ixx, Iyy, Izz]. A terminal
replan (``arrival_step``, :mod:`oacli.excitation.rattle_terminal`) sets γ = 0 and bounds every step from the arrival
on to the goal at rest (exact penalty).

The problem is non-convex (information is a convex function of the inputs, and it is *maximised*); it is solved by
a few sequential convex programming iterations in the spirit of ACADO's real-time iterations: each linearises the
dynamics (exact RK4 Jacobians) and the information term (exact adjoint gradient,
:mod:`oacli.excitation.fim_gradient`) along the current rollout, keeps the tracking cost quadratic (exact for the
translation), and solves a QP (cvxpy, Clarabel; built once, DPP) within a trust region; a step is kept only when it
lowers the true cost plus the exact penalty of the constraint violation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from oacli.excitation.convex import AttitudeErrorModel, RotationDynamics
from oacli.excitation.fim_gradient import fim_gradients
from oacli.excitation.information import (
    N_PARAMS,
    MeasurementModel,
    output_sensitivities,
    propagate_with_sensitivities,
)
from oacli.excitation.information_full import FullInformationTerm
from oacli.excitation.problem import (
    LENGTH_UNIT_M,
    attitude_errors,
    chord_margin_m,
    keep_in_violation,
    keep_out_violation,
    rest_to_rest_inputs,
)
from oacli.excitation.rattle_terminal import terminal_bounds, terminal_violation
from oacli.geometry import Scene
from oacli.geometry.halfspaces import keep_out_zone, point_halfspaces
from oacli.model.limits import MotionLimits
from oacli.solver import solve_clarabel
from oacli.types import Trajectory


@dataclass(frozen=True)
class InformationWeighting:
    """The per-parameter information weight and its decay with the estimate's standard deviation ([ReSWARM2023] §4.4).

    Attributes
    ----------
    gamma0 : ndarray, shape (4,)
        Initial weights γ0 for [m, Ixx, Iyy, Izz] (or for the chosen entries of the full θ,
        :func:`oacli.excitation.rattle_full.full_weighting`).
    floor : ndarray, shape (4,)
        Desired precision per parameter [kg, kg·m²] (likewise).
    alpha : float
        Shut-off: γ_i = 0 once σ_i ≤ α · floor_i.
    beta : float
        Decay constant.
    """

    gamma0: np.ndarray = field(default_factory=lambda: np.array([50.0, 20.0, 20.0, 20.0]))
    floor: np.ndarray = field(default_factory=lambda: np.array([0.03, 1e-4, 1e-4, 1e-4]))
    alpha: float = 2.2
    beta: float = 5.0

    def __post_init__(self) -> None:
        for name in ("gamma0", "floor"):
            value = np.array(getattr(self, name), dtype=float).reshape(-1)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if self.gamma0.size != self.floor.size:
            raise ValueError(f"gamma0 has {self.gamma0.size} entries, floor {self.floor.size}")

    def weights(self, std: np.ndarray) -> np.ndarray:
        """γ (4,) for the current standard deviations σ (4,).

        Parameters
        ----------
        std : ndarray, shape (4,)

        Returns
        -------
        ndarray, shape (4,)
        """
        return information_weights(std, self)


def information_weights(std: np.ndarray, weighting: InformationWeighting) -> np.ndarray:
    """RATTLE's decay rule ``γ_i = γ0_i exp(−β floor_i/σ_i)``, zero once ``σ_i ≤ α floor_i`` ([ReSWARM2023] §4.4).

    Parameters
    ----------
    std : ndarray, shape (4,)
        Standard deviations σ.
    weighting : InformationWeighting

    Returns
    -------
    ndarray, shape (4,)
        γ.
    """
    sigma = np.asarray(std, dtype=float)
    with np.errstate(divide="ignore", over="ignore"):
        gamma = weighting.gamma0 * np.exp(-weighting.beta * weighting.floor / np.maximum(sigma, 1e-300))
    return np.where(sigma <= weighting.alpha * weighting.floor, 0.0, gamma)


@dataclass(frozen=True)
class PlannerWeights:
    """Quadratic tracking weights of the planner (RATTLE: state [10, 10, 10, 5, 5, 5, 1×6], input 1, terminal 100).

    Attributes
    ----------
    position, velocity, attitude, angular_velocity : float
        Stage weights on ``r − r_goal`` [1/m²], ``v`` [s²/m²], attitude error [1/rad²], ``ω`` [s²/rad²].
    force, torque : float
        Input weights [1/N², 1/(N·m)²].
    terminal : float
        Weight on every component of the final error.
    """

    position: float = 10.0
    velocity: float = 5.0
    attitude: float = 1.0
    angular_velocity: float = 1.0
    force: float = 1.0
    torque: float = 1.0
    terminal: float = 100.0


@dataclass(frozen=True)
class ReplanResult:
    """One replan.

    Attributes
    ----------
    trajectory : Trajectory
        N+1 samples (mission time), ``u[k]`` held over step k, ``u[N] = 0``.
    cost : float
        True cost of the plan (tracking + input − information reward).
    information_reward : float
        ``Σ γ_i ½ log(1 + F_ii σ_i²)`` of the plan.
    information : ndarray, shape (4, 4)
        Fisher information of the plan's measurements.
    violation : float
        Normalised constraint violation of the plan (0 when every constraint holds).
    iterations : int
        SCP iterations run; ``accepted`` of them kept.
    accepted : int
    solve_time_s : float
        Wall time of the whole replan [s].
    status : str
        Last solver status.
    arrival_step : int or None
        The terminal phase's arrival step (None: not a terminal replan).
    """

    trajectory: Trajectory
    cost: float
    information_reward: float
    information: np.ndarray
    violation: float
    iterations: int
    accepted: int
    solve_time_s: float
    status: str
    arrival_step: int | None = None


class InformationAwarePlanner:
    """RATTLE's local planner: a few SCP iterations on the information-aware horizon problem (module docstring).

    Parameters
    ----------
    goal : ndarray, shape (13,)
        Goal state (at rest).
    horizon : int
        N steps.
    dt_s : float
        Step [s].
    limits : MotionLimits
    measurement : MeasurementModel
        The measurements the information term counts (one per step).
    scene : Scene
    weights : PlannerWeights
    iterations : int
        SCP iterations per replan.
    penalty : float
        Exact penalty on the normalised constraint violation.
    trust_region : float
        Initial trust region as a fraction of the input limits.
    dither : float
        Amplitude (fraction of the input limits) of the rest-to-rest excitation tried as a second starting point.
    clearance_m : float
        Extra distance kept from keep-in faces and keep-out surfaces [m].
    stop_speed_fraction : float
        The speed at the end of the horizon is bounded by this fraction of the velocity limit, and the last sample
        keeps the braking distance from that speed (at full force) from the walls and obstacles, so that the next
        plan can always stay in the workspace.
    information : FullInformationTerm, optional
        Reward the information of chosen entries of the full θ instead of [m, I]
        (:mod:`oacli.excitation.rattle_full`); ``std`` and ``gamma`` of :meth:`plan` then run over those entries.
    """

    def __init__(
        self,
        goal: np.ndarray,
        *,
        horizon: int = 40,
        dt_s: float = 0.3,
        limits: MotionLimits,
        measurement: MeasurementModel,
        scene: Scene | None = None,
        weights: PlannerWeights | None = None,
        iterations: int = 3,
        penalty: float = 1000.0,
        trust_region: float = 0.25,
        dither: float = 0.3,
        clearance_m: float = 0.0,
        stop_speed_fraction: float = 0.25,
        information: FullInformationTerm | None = None,
    ) -> None:
        self.goal = np.array(goal, dtype=float).reshape(13)
        self.information_term = information
        self._theta_full: np.ndarray | None = None
        self.n = int(horizon)
        self.dt = float(dt_s)
        self.limits = limits
        self.measurement = measurement
        self.scene = scene or Scene()
        self.weights = weights or PlannerWeights()
        self.iterations = int(iterations)
        self.penalty = float(penalty)
        self.trust_region = float(trust_region)
        self.dither = float(dither)
        self.clearance_m = float(clearance_m)
        self.stop_speed = float(stop_speed_fraction) * limits.velocity_mps
        self._built_for_mass: float | None = None
        self._terminal_bounds = terminal_bounds(self.n, None)

    # -- the QP -----------------------------------------------------------------------------------------------

    def _build(self, mass: float) -> None:
        n = self.n
        dt = self.dt
        lim = self.limits
        w = self.weights
        du = cp.Variable((n, 6), name="du")
        dr = cp.Variable((n + 1, 3), name="dr")
        dv = cp.Variable((n + 1, 3), name="dv")
        drot = cp.Variable((n + 1, 7), name="drot")
        self.du = du
        self.p_r = cp.Parameter((n + 1, 3), name="r_minus_goal")
        self.p_v = cp.Parameter((n + 1, 3), name="v_bar")
        self.p_w = cp.Parameter((n + 1, 3), name="w_bar")
        self.p_u = cp.Parameter((n, 6), name="u_bar")
        self.p_g = cp.Parameter((n, 6), name="information_gradient")
        self.p_delta = cp.Parameter(6, nonneg=True, name="trust_region")
        self.rotation = RotationDynamics(drot, du[:, 3:6])
        self.attitude = AttitudeErrorModel(drot[:, 0:4])
        cons = [dr[0] == 0, dv[0] == 0, *self.rotation.constraints]
        cons += [
            dr[1:] == dr[:-1] + dt * dv[:-1] + (dt**2 / (2.0 * mass)) * du[:, 0:3],
            dv[1:] == dv[:-1] + (dt / mass) * du[:, 0:3],
            cp.abs(self.p_u + du) <= np.tile(lim.input[None, :], (n, 1)),
            cp.abs(du) <= np.ones((n, 1)) @ cp.reshape(self.p_delta, (1, 6), order="C"),
        ]
        s_v = cp.Variable(n, nonneg=True)
        s_w = cp.Variable(n, nonneg=True)
        self.p_w_bound = cp.Parameter((n, 3), nonneg=True, name="rate_bound")
        cons += [
            cp.abs(self.p_v[1:] + dv[1:]) <= cp.reshape(1.0 + s_v, (n, 1), order="C") @ lim.velocity_mps[None, :],
            cp.abs(self.p_w[1:] + drot[1:, 4:7])
            <= self.p_w_bound + cp.reshape(s_w, (n, 1), order="C") @ lim.angular_velocity_radps[None, :],
        ]
        # Room to stop at the end of the horizon: the next plan must be able to stay in the workspace
        # (recursive feasibility of the receding horizon).
        s_stop = cp.Variable(nonneg=True)
        cons.append(cp.abs(self.p_v[n] + dv[n]) <= self.stop_speed * (1.0 + s_stop))
        slacks = [s_v, s_w, s_stop]
        # RATTLE's terminal phase (:mod:`oacli.excitation.rattle_terminal`): the steps at and after the arrival are
        # at the goal at rest (bounds per step [m, m/s, rad, rad/s]; :data:`FREE_BOUND` elsewhere), exact penalty.
        self.p_terminal = cp.Parameter((n + 1, 4), nonneg=True, name="terminal_bounds")
        s_t = cp.Variable(n + 1, nonneg=True)
        bound = [cp.reshape(self.p_terminal[:, j], (n + 1, 1), order="C") @ np.ones((1, 3)) for j in range(4)]
        unit = [LENGTH_UNIT_M * np.ones(3), lim.velocity_mps, np.ones(3), lim.angular_velocity_radps]
        col = cp.reshape(s_t, (n + 1, 1), order="C")
        for j, expr in enumerate((self.p_r + dr, self.p_v + dv, self.attitude.expr, self.p_w + drot[:, 4:7])):
            cons.append(cp.abs(expr) <= bound[j] + col @ unit[j][None, :])
        slacks.append(s_t)
        self.has_keep_in = bool(self.scene.keep_in)
        if self.has_keep_in:
            self.in_lo0, self.in_hi0, self.in_lo1, self.in_hi1 = (cp.Parameter((n, 3)) for _ in range(4))
            s_in = cp.Variable(n, nonneg=True)
            ls = cp.reshape(LENGTH_UNIT_M * s_in, (n, 1), order="C") @ np.ones((1, 3))
            cons += [dr[:-1] >= self.in_lo0 - ls, dr[:-1] <= self.in_hi0 + ls,
                     dr[1:] >= self.in_lo1 - ls, dr[1:] <= self.in_hi1 + ls]
            slacks.append(s_in)
        self.out_params = []
        for _ in self.scene.keep_out:
            n_hat, c0, c1 = cp.Parameter((n, 3)), cp.Parameter(n), cp.Parameter(n)
            s_out = cp.Variable(n, nonneg=True)
            cons += [cp.sum(cp.multiply(n_hat, dr[:-1]), axis=1) >= c0 - LENGTH_UNIT_M * s_out,
                     cp.sum(cp.multiply(n_hat, dr[1:]), axis=1) >= c1 - LENGTH_UNIT_M * s_out]
            self.out_params.append((n_hat, c0, c1))
            slacks.append(s_out)
        self.slacks = slacks

        r = self.p_r + dr
        v = self.p_v + dv
        om = self.p_w + drot[:, 4:7]
        e = self.attitude.expr
        stage = slice(1, n)
        tracking = (
            w.position * cp.sum_squares(r[stage]) + w.velocity * cp.sum_squares(v[stage])
            + w.attitude * cp.sum_squares(e[stage]) + w.angular_velocity * cp.sum_squares(om[stage])
        )
        terminal = w.terminal * (
            cp.sum_squares(r[n]) + cp.sum_squares(v[n]) + cp.sum_squares(e[n]) + cp.sum_squares(om[n])
        )
        effort = w.force * cp.sum_squares(self.p_u[:, 0:3] + du[:, 0:3]) + w.torque * cp.sum_squares(
            self.p_u[:, 3:6] + du[:, 3:6]
        )
        information = cp.sum(cp.multiply(self.p_g, du))
        penalty = self.penalty * sum(cp.sum(s) for s in slacks)
        self.problem = cp.Problem(cp.Minimize(tracking + terminal + effort - information + penalty), cons)
        self._built_for_mass = mass

    # -- true cost and violation --------------------------------------------------------------------------------

    def _margins(self, theta: np.ndarray) -> tuple[np.ndarray, float]:
        margin = chord_margin_m(self.limits.force_N, theta, self.dt) + self.clearance_m
        return margin, float(np.linalg.norm(margin - self.clearance_m)) + self.clearance_m

    def stop_distance(self, theta: np.ndarray) -> np.ndarray:
        """Per-axis braking distance [m] from the end-of-horizon speed bound at full force.

        Parameters
        ----------
        theta : ndarray, shape (4,)
            θ = [m, Ixx, Iyy, Izz] of the model planned with (the current estimate); the mass m [kg] brakes.

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.stop_speed**2 * theta[0] / (2.0 * self.limits.force_N)

    def _evaluate(self, x0, u, theta, std, gamma) -> dict:
        if self.information_term is None:
            x, s = propagate_with_sensitivities(x0, u, theta, self.dt)
            g_state, g_acc = output_sensitivities(x, u, s, theta, self.measurement)
            fim = np.einsum("kmi,kmj->ij", g_state, g_state) + np.einsum("kmi,kmj->ij", g_acc, g_acc)
        else:
            assert self._theta_full is not None
            full = self.information_term.information(x0, u, self._theta_full, self.dt, self.measurement)
            x, fim = full.x, full.fim
        reward = float(np.sum(gamma * 0.5 * np.log1p(np.diag(fim) * std**2)))
        w = self.weights
        err, jac = attitude_errors(self.goal[6:10], x[:, 6:10])
        dr = x[:, 0:3] - self.goal[0:3]
        stage = slice(1, self.n)
        tracking = (
            w.position * np.sum(dr[stage] ** 2) + w.velocity * np.sum(x[stage, 3:6] ** 2)
            + w.attitude * np.sum(err[stage] ** 2) + w.angular_velocity * np.sum(x[stage, 10:13] ** 2)
        )
        terminal = w.terminal * (np.sum(dr[-1] ** 2) + np.sum(x[-1, 3:6] ** 2) + np.sum(err[-1] ** 2)
                                 + np.sum(x[-1, 10:13] ** 2))
        effort = w.force * np.sum(u[:, 0:3] ** 2) + w.torque * np.sum(u[:, 3:6] ** 2)
        lim = self.limits
        margin, out_margin = self._margins(theta)
        stop = self.stop_distance(theta)
        viol = (
            np.sum(np.maximum(np.max(np.abs(x[1:, 3:6]) / lim.velocity_mps, axis=1) - 1.0, 0.0))
            + np.sum(np.maximum(np.max(np.abs(x[1:, 10:13]) / lim.angular_velocity_radps, axis=1) - 1.0, 0.0))
            + max(float(np.max(np.abs(x[-1, 3:6]) / self.stop_speed)) - 1.0, 0.0)
            + np.sum(keep_in_violation(self.scene, x[:, 0:3], margin, end_extra_m=stop)[0]) / LENGTH_UNIT_M
            + np.sum(keep_out_violation(self.scene, x[:, 0:3], out_margin, float(np.linalg.norm(stop))))
            / LENGTH_UNIT_M
        )
        viol += terminal_violation(self._terminal_bounds, dr, x[:, 3:6], err, x[:, 10:13], lim)
        cost = tracking + terminal + effort - reward
        return {"u": u, "x": x, "fim": 0.5 * (fim + fim.T), "reward": reward, "cost": float(cost),
                "violation": float(viol), "merit": float(cost + self.penalty * viol), "err": err, "jac": jac}

    def _set(self, ev: dict, theta, std, gamma, delta: float) -> None:
        x = ev["x"]
        self.p_r.value = x[:, 0:3] - self.goal[0:3]
        self.p_v.value = x[:, 3:6]
        self.p_w.value = x[:, 10:13]
        self.p_u.value = ev["u"]
        fim = ev["fim"]
        weight = np.diag(gamma * 0.5 * std**2 / (1.0 + np.diag(fim) * std**2))
        if self.information_term is None:
            lin = fim_gradients(x[0], ev["u"], theta, self.dt, self.measurement, weight[None])
            self.p_g.value = lin.gradients[0]
        else:  # the dynamics' Jacobians of the 4-parameter model, the information's gradient of the full one
            assert self._theta_full is not None
            lin = fim_gradients(x[0], ev["u"], theta, self.dt, self.measurement, np.zeros((1, N_PARAMS, N_PARAMS)))
            self.p_g.value = self.information_term.gradient(x[0], ev["u"], self._theta_full, self.dt,
                                                            self.measurement, weight)
        self.rotation.set(lin.a, lin.b)
        self.attitude.set(ev["err"], ev["jac"])
        self.p_delta.value = delta * self.limits.input
        self.p_terminal.value = self._terminal_bounds
        # The rates follow the linearised rotation only to first order: the model aims at 90 % of the limit (never
        # tighter than the current rate, so the slack at zero step is the true violation), leaving the rest for
        # the linearisation error of a step.
        w_max = self.limits.angular_velocity_radps[None, :]
        self.p_w_bound.value = np.minimum(w_max, np.maximum(0.9 * w_max, np.abs(x[1:, 10:13])))
        pos = x[:, 0:3]
        margin, out_margin = self._margins(theta)
        stop = self.stop_distance(theta)
        if self.has_keep_in:
            _, boxes = keep_in_violation(self.scene, pos, margin)
            lo = np.array([self.scene.keep_in[i].lower for i in boxes]) + margin
            hi = np.array([self.scene.keep_in[i].upper for i in boxes]) - margin
            self.in_lo0.value, self.in_hi0.value = lo - pos[:-1], hi - pos[:-1]
            lo[-1] += stop
            hi[-1] -= stop
            self.in_lo1.value, self.in_hi1.value = lo - pos[1:], hi - pos[1:]
        mid = 0.5 * (pos[:-1] + pos[1:])
        for (n_hat, c0, c1), ell in zip(self.out_params, self.scene.keep_out, strict=True):
            nh, beta, _ = point_halfspaces(keep_out_zone(ell), mid)
            n_hat.value = nh
            c0.value = beta + out_margin - np.einsum("ki,ki->k", nh, pos[:-1])
            bound1 = beta + out_margin - np.einsum("ki,ki->k", nh, pos[1:])
            bound1[-1] += float(np.linalg.norm(stop))
            c1.value = bound1

    # -- public -------------------------------------------------------------------------------------------------

    def plan(
        self,
        x0: np.ndarray,
        theta: np.ndarray,
        std: np.ndarray,
        gamma: np.ndarray,
        *,
        t0: float = 0.0,
        u_warm: np.ndarray | None = None,
        theta_full: np.ndarray | None = None,
        arrival_step: int | None = None,
    ) -> ReplanResult:
        """Plan N steps from ``x0`` with the model ``theta`` (the estimate), its std ``σ`` and weights ``γ``.

        Parameters
        ----------
        x0 : ndarray, shape (13,)
            Current (measured) state.
        theta, std, gamma : ndarray, shape (4,)
            Estimate, its standard deviations and the information weights (:func:`information_weights`).
        t0 : float
            Mission time of ``x0`` [s] (time stamps of the returned trajectory).
        u_warm : ndarray, shape (N, 6), optional
            Initial inputs (e.g. the previous plan shifted); zero (drift) by default.
        theta_full : ndarray, shape (16,), optional
            With an information term: the full θ its information is evaluated at (default: ``theta`` with the
            term's prior for the rest); ``std`` and ``gamma`` then have one entry per chosen entry.
        arrival_step : int, optional
            RATTLE's terminal phase (:mod:`oacli.excitation.rattle_terminal`): the plan reaches the goal at rest by
            this step and stays there (exact penalty), and rewards no information (γ = 0).

        Returns
        -------
        ReplanResult
        """
        wall = time.perf_counter()
        theta = np.asarray(theta, dtype=float)
        if self.information_term is not None:
            self._theta_full = (self.information_term.theta(theta) if theta_full is None
                                else np.asarray(theta_full, dtype=float).reshape(16))
        std = np.asarray(std, dtype=float)
        gamma = np.asarray(gamma, dtype=float)
        self._terminal_bounds = terminal_bounds(self.n, arrival_step)
        if arrival_step is not None:
            gamma = np.zeros_like(gamma)
        if self._built_for_mass is None or abs(self._built_for_mass - theta[0]) > 1e-12 * theta[0]:
            self._build(float(theta[0]))
        u = np.zeros((self.n, 6)) if u_warm is None else np.asarray(u_warm, dtype=float)
        current = self._evaluate(x0, np.clip(u, -self.limits.input, self.limits.input), theta, std, gamma)
        if np.any(gamma > 0):
            # The information of a parameter is quadratic in the inputs that excite it, so its gradient vanishes
            # where they are zero (a saddle: a robot at rest would never start to excite). A rest-to-rest dither
            # on every axis is tried as a second starting point; the better one (true merit) is kept.
            amp = self.dither * np.vstack([self.limits.force_N, self.limits.torque_Nm])
            dither = rest_to_rest_inputs(x0, x0, self.n, self.dt, theta, excitation=amp)
            other = self._evaluate(x0, np.clip(u + dither, -self.limits.input, self.limits.input), theta, std, gamma)
            if other["merit"] < current["merit"]:
                current = other
        delta = self.trust_region
        accepted = 0
        status = "not run"
        for _ in range(self.iterations):
            self._set(current, theta, std, gamma, delta)
            out = solve_clarabel(self.problem, quiet=True)
            status = out.status
            if not out.success or self.du.value is None:
                delta *= 0.5
                continue
            predicted = float(self.problem.value) - current["reward"]
            trial = np.clip(current["u"] + self.du.value, -self.limits.input, self.limits.input)
            candidate = self._evaluate(x0, trial, theta, std, gamma)
            predicted_decrease = current["merit"] - predicted
            actual = current["merit"] - candidate["merit"]
            if actual > 0 and predicted_decrease > 0 and actual >= 0.1 * predicted_decrease:
                current = candidate
                accepted += 1
                if actual >= 0.75 * predicted_decrease:
                    delta = min(2.0 * delta, 2.0)
            else:
                delta *= 0.5
        n = self.n
        t = t0 + self.dt * np.arange(n + 1)
        traj = Trajectory(t, current["x"], np.vstack([current["u"], np.zeros((1, 6))]), name="rattle_plan")
        return ReplanResult(
            trajectory=traj,
            cost=current["cost"],
            information_reward=current["reward"],
            information=current["fim"],
            violation=current["violation"],
            iterations=self.iterations,
            accepted=accepted,
            solve_time_s=time.perf_counter() - wall,
            status=status,
            arrival_step=arrival_step,
        )
