"""Offline information-optimal excitation (Doerr et al. 2021, Eq. 30) by sequential convex programming.

Problem. Over N steps of ``dt`` from a start pose at rest to a goal pose at rest, find inputs ``u`` that minimise a
criterion of the Fisher information ``F(u)`` (Eq. 29; A: ``tr F⁻¹``, D: ``−log det F``, E: ``−λ_min F``, on
absolute or relative parameters) subject to the RK4 dynamics (Eqs. 33-36), per-axis force, torque, velocity and
angular-rate limits, the keep-in boxes and the keep-out ellipsoids (Eq. 12), and the terminal state within a
tolerance. The paper's version ignored obstacles and needed a "safe area"; this one respects them (also between
samples, see :mod:`oacli.excitation.problem`).

Sequential convex programming. Iterates are always *rollouts* of the nonlinear model (so the dynamics hold
exactly); around the current one a convex subproblem in the step ``δu`` is solved with cvxpy/Clarabel:

* dynamics linearised exactly: translation is an exact LTI double integrator (force in the world frame), the
  rotational block uses the exact RK4 Jacobians ``A_k, B_k`` (:func:`oacli.model.rigid_body.rk4_step_jacobians`);
* the FIM linearised, ``F(u + δu) ≈ F(u) + Σ_ab E_ab ⟨∂F_ab/∂u, δu⟩`` with exact adjoint gradients
  (:mod:`oacli.excitation.fim_gradient`), and the *exact convex* criterion of that affine matrix (tr_inv by a
  Schur complement, log_det, λ_min by an LMI) — a model that keeps the criterion's curvature in F;
* keep-in boxes and keep-out tangent half-spaces per segment; velocity, rate and terminal constraints linearised;
* every constraint but the input bounds is softened by a non-negative slack with an exact ℓ1 penalty μ, so the
  subproblem is always feasible (feasibility restoration when the linearised problem is not);
* a trust region ``|δu_i| ≤ Δ·u_max,i``.

A step is accepted only when the merit ``φ = J/J_ref + μ·V`` (``V`` the normalised constraint violation of the
*nonlinear* rollout, measured as the slacks measure it) decreases and the ratio of actual to predicted decrease is
at least ``accept_ratio``; Δ grows after good steps and shrinks after poor or rejected ones (separately for force and
torque: translation is exactly linear, rotation is where the model errs). Every iterate, accepted or not, is
recorded with its criterion, merit, violation and trust regions.

Two details keep the iteration efficient on long horizons, where the final attitude is a strongly nonlinear
function of the torques:

* constraints the model predicts only to first order (final attitude and rate, rate limits) are aimed at a
  tightened bound that is never tighter than the current value, so the slacks at zero step still equal the true
  violation while a step's linearisation error stays inside the true bound;
* a trial point that misses the final attitude gets a second-order correction (:func:`restore_rotation_endpoint`,
  Gauss-Newton on the final attitude and rate with the torques), and the better of the two is judged by the merit
  (the classical remedy for the Maratos effect of exact-penalty SQP).

Information is a convex function of the inputs and it is *maximised*, so the result is a local optimum that depends
on the start. The default start (:func:`initial_guess`) already spends long stretches near the speed limit (the mass
information of velocity measurements grows with ``Σ v²``) and excites every rotation axis; optional extra starts
(``ScpSettings.starts``) are screened for a few iterations and the best continues.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from oacli.errors import InfeasibleError
from oacli.excitation.convex import RotationDynamics
from oacli.excitation.fim_gradient import (
    Criterion,
    Scaling,
    criterion_value,
    fim_gradients,
    scaling_matrix,
    symmetric_basis,
)
from oacli.excitation.information import (
    N_PARAMS,
    MeasurementModel,
    cramer_rao_std,
    output_sensitivities,
    propagate_with_sensitivities,
)
from oacli.excitation.problem import (
    LENGTH_UNIT_M,
    MotionLimits,
    TerminalTolerance,
    attitude_error,
    check_reachable,
    chord_margin_m,
    collision_free,
    keep_in_violation,
    keep_out_violation,
    rest_to_rest_inputs,
    rest_to_rest_profile,
    translation_excitation,
)
from oacli.geometry import Scene
from oacli.geometry.halfspaces import keep_out_zone, point_halfspaces
from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb
from oacli.types import Trajectory

_OK = {cp.OPTIMAL, cp.OPTIMAL_INACCURATE}
_BASIS = symmetric_basis()
_PAIRS = [(a, b) for a in range(N_PARAMS) for b in range(a, N_PARAMS)]


@dataclass(frozen=True)
class ExcitationProblem:
    """An offline excitation design problem.

    Attributes
    ----------
    start, goal : ndarray, shape (13,)
        Start and goal states (at rest: zero velocity and angular velocity).
    duration_s : float
        Duration T [s].
    steps : int
        Number of steps N (``dt = T/N``); one measurement per step.
    theta : ndarray, shape (4,)
        Parameters the design is made for [m kg, Ixx, Iyy, Izz kg·m²] (the prior estimate).
    measurement : MeasurementModel
        Measured quantities and noise (the FIM's R).
    limits : MotionLimits
    scene : Scene
        Keep-in boxes and keep-out ellipsoids (safety factor applied).
    criterion : {"A", "D", "E"}
    scaling : {"absolute", "relative"}
        Criterion on θ as is (Eq. 30) or on θ relative to the design value.
    prior_information : ndarray, shape (4, 4), optional
        Information added to the measurements' (inverse prior covariance); none by default (Eq. 30).
    clearance_m : float
        Extra distance kept from keep-in faces and keep-out surfaces [m].
    terminal : TerminalTolerance
    """

    start: np.ndarray
    goal: np.ndarray
    duration_s: float
    steps: int
    theta: np.ndarray
    measurement: MeasurementModel
    limits: MotionLimits
    scene: Scene = field(default_factory=Scene)
    criterion: Criterion = "A"
    scaling: Scaling = "absolute"
    prior_information: np.ndarray | None = None
    clearance_m: float = 0.0
    terminal: TerminalTolerance = field(default_factory=TerminalTolerance)

    def __post_init__(self) -> None:
        for name in ("start", "goal"):
            value = np.array(getattr(self, name), dtype=float).reshape(13)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        theta = np.array(self.theta, dtype=float).reshape(N_PARAMS)
        theta.setflags(write=False)
        object.__setattr__(self, "theta", theta)
        if self.steps < 2 or self.duration_s <= 0:
            raise ValueError("need at least 2 steps and a positive duration")
        if self.criterion not in ("A", "D", "E"):
            raise ValueError(f"unknown criterion {self.criterion!r}")

    @property
    def dt(self) -> float:
        """Step [s]."""
        return self.duration_s / self.steps

    @property
    def prior(self) -> np.ndarray:
        """Prior information (4, 4) (zeros when none)."""
        if self.prior_information is None:
            return np.zeros((N_PARAMS, N_PARAMS))
        return np.asarray(self.prior_information, dtype=float)


@dataclass(frozen=True)
class ScpSettings:
    """Sequential convex programming settings.

    Attributes
    ----------
    max_iterations : int
        Subproblems solved at most.
    trust_region_initial, trust_region_min, trust_region_max : float
        Trust region Δ as a fraction of the per-axis input limit.
    penalty : float
        Exact-penalty weight μ on the normalised constraint violation.
    accept_ratio, good_ratio : float
        A step is accepted when actual/predicted merit decrease ≥ accept_ratio; Δ grows above good_ratio.
    shrink, grow : float
        Trust-region factors.
    tolerance : float
        Stop when the predicted merit decrease is below this (the merit starts at 1).
    starts : int
        Number of starts (the deterministic initial guess plus random ones); each runs ``screening_iterations``
        and the best continues up to ``max_iterations``.
    screening_iterations : int
        Iterations every start gets before the best is chosen.
    """

    max_iterations: int = 30
    trust_region_initial: float = 0.5
    trust_region_min: float = 1e-3
    trust_region_max: float = 2.0
    penalty: float = 10.0
    accept_ratio: float = 0.1
    good_ratio: float = 0.75
    shrink: float = 0.5
    grow: float = 2.0
    tolerance: float = 1e-4
    starts: int = 1
    screening_iterations: int = 5


@dataclass(frozen=True)
class ScpIterate:
    """One SCP iteration: the candidate step and what became of it.

    ``criterion`` and ``merit`` are those of the accepted iterate *after* the iteration (the current design);
    ``candidate_*`` those of the trial point; ``predicted_merit`` the subproblem's model value there.
    """

    iteration: int
    criterion: float
    merit: float
    violation: float
    candidate_criterion: float
    candidate_merit: float
    predicted_merit: float
    ratio: float
    trust_region_force: float
    trust_region_torque: float
    accepted: bool
    status: str
    solve_time_s: float


@dataclass(frozen=True)
class Evaluation:
    """A rollout of the nonlinear model and everything the merit needs."""

    u: np.ndarray
    x: np.ndarray
    fim: np.ndarray
    criterion: float
    criterion_normalised: float
    violations: dict[str, float]
    merit: float

    @property
    def violation(self) -> float:
        """Total normalised violation."""
        return float(sum(self.violations.values()))


@dataclass(frozen=True)
class ExcitationDesign:
    """Result of :func:`design_excitation`.

    Attributes
    ----------
    trajectory : Trajectory
        N+1 samples every dt; ``u[k]`` held from ``t[k]`` to ``t[k+1]``, ``u[N] = 0``.
    fim : ndarray, shape (4, 4)
        Fisher information of the design (measurements only, no prior).
    criterion_initial, criterion_final : float
        Criterion (of F plus the prior information) of the initial guess and of the design.
    iterations : tuple of ScpIterate
    solve_time_s : float
        Wall time of the whole design [s].
    stop_reason : str
    terminal_residual : dict
        ``position_m``, ``velocity_mps``, ``attitude_rad``, ``angular_velocity_radps``: largest per-axis error at
        the end.
    violations : dict
        Normalised constraint violations of the design (0 when every constraint holds).
    collision_free : bool
        Dense re-check of the continuous motion against the scene.
    crb_std : ndarray, shape (4,)
        Cramér-Rao bound ``sqrt(diag F⁻¹)`` (measurements only).
    information_over_time : ndarray, shape (N+1, 4, 4)
        Cumulative Fisher information of the measurements up to each sample.
    initial : Trajectory
        The initial guess.
    """

    trajectory: Trajectory
    fim: np.ndarray
    criterion_initial: float
    criterion_final: float
    iterations: tuple[ScpIterate, ...]
    solve_time_s: float
    stop_reason: str
    terminal_residual: dict[str, float]
    violations: dict[str, float]
    collision_free: bool
    crb_std: np.ndarray
    information_over_time: np.ndarray
    initial: Trajectory

    @property
    def accepted_iterations(self) -> int:
        """Number of accepted steps."""
        return sum(it.accepted for it in self.iterations)


# ----------------------------------------------------------------------------------------------------------------
# Merit: criterion and constraint violations of a rollout
# ----------------------------------------------------------------------------------------------------------------


class _Merit:
    """The SCP merit ``J/J_ref + μ V`` of input sequences (see the module docstring)."""

    def __init__(self, problem: ExcitationProblem, penalty: float) -> None:
        self.p = problem
        self.penalty = penalty
        self.d = scaling_matrix(problem.theta, problem.scaling)
        self.margin = chord_margin_m(problem.limits.force_N, problem.theta[0], problem.dt) + problem.clearance_m
        self.keep_out_margin = float(np.linalg.norm(self.margin - problem.clearance_m)) + problem.clearance_m
        self.reference: float | None = None

    def normalise(self, crit: float) -> float:
        ref = self.reference
        assert ref is not None
        if self.p.criterion == "A":
            return crit / ref
        if self.p.criterion == "D":
            return (crit - ref) / N_PARAMS
        return crit / abs(ref)

    def fim(self, x: np.ndarray, s: np.ndarray, u: np.ndarray) -> np.ndarray:
        g_state, g_acc = output_sensitivities(x, u, s, self.p.theta, self.p.measurement)
        fim = np.einsum("kmi,kmj->ij", g_state, g_state) + np.einsum("kmi,kmj->ij", g_acc, g_acc)
        return 0.5 * (fim + fim.T)

    def violations(self, x: np.ndarray) -> dict[str, float]:
        p = self.p
        lim = p.limits
        tol = p.terminal
        out = {
            "velocity": float(np.sum(np.maximum(np.max(np.abs(x[1:, 3:6]) / lim.velocity_mps, axis=1) - 1.0, 0.0))),
            "angular_velocity": float(
                np.sum(np.maximum(np.max(np.abs(x[1:, 10:13]) / lim.angular_velocity_radps, axis=1) - 1.0, 0.0))
            ),
            "keep_in": float(np.sum(keep_in_violation(p.scene, x[:, 0:3], self.margin)[0]) / LENGTH_UNIT_M),
            "keep_out": float(np.sum(keep_out_violation(p.scene, x[:, 0:3], self.keep_out_margin)) / LENGTH_UNIT_M),
        }
        res = terminal_residual(x[-1], p.goal)
        out["terminal_position"] = max(res["position_m"] / tol.position_m - 1.0, 0.0)
        out["terminal_velocity"] = max(res["velocity_mps"] / tol.velocity_mps - 1.0, 0.0)
        out["terminal_attitude"] = max(res["attitude_rad"] / tol.attitude_rad - 1.0, 0.0)
        out["terminal_angular_velocity"] = max(res["angular_velocity_radps"] / tol.angular_velocity_radps - 1.0, 0.0)
        return out

    def evaluate(self, u: np.ndarray) -> Evaluation:
        x, s = propagate_with_sensitivities(self.p.start, u, self.p.theta, self.p.dt)
        fim = self.fim(x, s, u) + self.p.prior
        crit = criterion_value(fim, self.p.criterion, self.d)
        if self.reference is None:
            if not np.isfinite(crit):
                raise InfeasibleError(
                    "the initial excitation carries no information on some parameters (singular Fisher information)"
                )
            self.reference = crit
        crit_n = self.normalise(crit) if np.isfinite(crit) else np.inf
        viol = self.violations(x)
        merit = crit_n + self.penalty * sum(viol.values())
        return Evaluation(u, x, fim, crit, crit_n, viol, merit)


def terminal_residual(x_end: np.ndarray, goal: np.ndarray) -> dict[str, float]:
    """Largest per-axis error of the final state against the goal at rest.

    Parameters
    ----------
    x_end : ndarray, shape (13,)
    goal : ndarray, shape (13,)

    Returns
    -------
    dict
        ``position_m``, ``velocity_mps``, ``attitude_rad``, ``angular_velocity_radps``.
    """
    err, _ = attitude_error(goal[6:10], x_end[6:10])
    return {
        "position_m": float(np.max(np.abs(x_end[0:3] - goal[0:3]))),
        "velocity_mps": float(np.max(np.abs(x_end[3:6] - goal[3:6]))),
        "attitude_rad": float(np.max(np.abs(err))),
        "angular_velocity_radps": float(np.max(np.abs(x_end[10:13] - goal[10:13]))),
    }


# ----------------------------------------------------------------------------------------------------------------
# The convex subproblem (built once, DPP)
# ----------------------------------------------------------------------------------------------------------------


class _Subproblem:
    """The convexified design problem around an iterate; cvxpy problem built once with Parameters."""

    def __init__(
        self, problem: ExcitationProblem, merit: _Merit, penalty: float, linearisation_margin: float = 0.5,
        rate_margin_fraction: float = 0.05,
    ) -> None:
        p = problem
        self.linearisation_margin = linearisation_margin
        self.rate_margin_fraction = rate_margin_fraction
        n = p.steps
        dt = p.dt
        m = p.theta[0]
        lim = p.limits
        self.p = p
        self.n = n
        u_max = lim.input
        self.du = cp.Variable((n, 6), name="du")
        dr = cp.Variable((n + 1, 3), name="dr")
        dv = cp.Variable((n + 1, 3), name="dv")
        drot = cp.Variable((n + 1, 7), name="drot")  # [δq (4), δω (3)]
        du = self.du

        self.u_bar = cp.Parameter((n, 6), name="u_bar")
        self.v_bar = cp.Parameter((n + 1, 3), name="v_bar")
        self.w_bar = cp.Parameter((n + 1, 3), name="w_bar")
        self.delta = cp.Parameter(6, nonneg=True, name="trust_region")  # per channel [N, N·m]

        self.rotation = RotationDynamics(drot, du[:, 3:6])
        cons = [dr[0] == 0, dv[0] == 0, *self.rotation.constraints]
        cons += [
            dr[1:] == dr[:-1] + dt * dv[:-1] + (dt**2 / (2.0 * m)) * du[:, 0:3],
            dv[1:] == dv[:-1] + (dt / m) * du[:, 0:3],
        ]
        u_row = u_max[None, :]
        cons += [
            cp.abs(self.u_bar + du) <= np.tile(u_row, (n, 1)),
            cp.abs(du) <= np.ones((n, 1)) @ cp.reshape(self.delta, (1, 6), order="C"),
        ]

        slacks = []
        s_v = cp.Variable(n, nonneg=True, name="s_velocity")
        s_w = cp.Variable(n, nonneg=True, name="s_rate")
        self.w_bound = cp.Parameter((n, 3), nonneg=True, name="rate_bound")
        cons += [
            cp.abs(self.v_bar[1:] + dv[1:]) <= cp.reshape(1.0 + s_v, (n, 1), order="C") @ lim.velocity_mps[None, :],
            cp.abs(self.w_bar[1:] + drot[1:, 4:7])
            <= self.w_bound + cp.reshape(s_w, (n, 1), order="C") @ lim.angular_velocity_radps[None, :],
        ]
        slacks += [s_v, s_w]

        self.has_keep_in = bool(p.scene.keep_in)
        if self.has_keep_in:
            # Bounds on dr relative to the iterate: lower/upper for the start and the end sample of each segment.
            self.in_lo0 = cp.Parameter((n, 3), name="in_lo0")
            self.in_hi0 = cp.Parameter((n, 3), name="in_hi0")
            self.in_lo1 = cp.Parameter((n, 3), name="in_lo1")
            self.in_hi1 = cp.Parameter((n, 3), name="in_hi1")
            s_in = cp.Variable(n, nonneg=True, name="s_keep_in")
            ls = cp.reshape(LENGTH_UNIT_M * s_in, (n, 1), order="C") @ np.ones((1, 3))
            cons += [
                dr[:-1] >= self.in_lo0 - ls, dr[:-1] <= self.in_hi0 + ls,
                dr[1:] >= self.in_lo1 - ls, dr[1:] <= self.in_hi1 + ls,
            ]
            slacks.append(s_in)
        self.out_n: list[cp.Parameter] = []
        self.out_c0: list[cp.Parameter] = []
        self.out_c1: list[cp.Parameter] = []
        for e in range(len(p.scene.keep_out)):
            n_hat = cp.Parameter((n, 3), name=f"out_n{e}")
            c0 = cp.Parameter(n, name=f"out_c0_{e}")
            c1 = cp.Parameter(n, name=f"out_c1_{e}")
            s_out = cp.Variable(n, nonneg=True, name=f"s_keep_out{e}")
            cons += [
                cp.sum(cp.multiply(n_hat, dr[:-1]), axis=1) >= c0 - LENGTH_UNIT_M * s_out,
                cp.sum(cp.multiply(n_hat, dr[1:]), axis=1) >= c1 - LENGTH_UNIT_M * s_out,
            ]
            self.out_n.append(n_hat)
            self.out_c0.append(c0)
            self.out_c1.append(c1)
            slacks.append(s_out)

        tol = p.terminal
        self.r_end = cp.Parameter(3, name="r_end_minus_goal")
        self.att_err = cp.Parameter(3, name="attitude_error_end")
        self.att_jac = cp.Parameter((3, 4), name="attitude_error_jacobian")
        self.att_bound = cp.Parameter(3, nonneg=True, name="attitude_bound")
        self.w_end_bound = cp.Parameter(3, nonneg=True, name="rate_end_bound")
        s_t = cp.Variable(4, nonneg=True, name="s_terminal")
        cons += [
            cp.abs(self.r_end + dr[n]) <= tol.position_m * (1.0 + s_t[0]),
            cp.abs(self.v_bar[n] + dv[n]) <= tol.velocity_mps * (1.0 + s_t[1]),
            cp.abs(self.att_err + self.att_jac @ drot[n, 0:4]) <= self.att_bound + tol.attitude_rad * s_t[2],
            cp.abs(self.w_bar[n] + drot[n, 4:7]) <= self.w_end_bound + tol.angular_velocity_radps * s_t[3],
        ]
        slacks.append(s_t)
        self.slacks = slacks

        # Affine model of the (scaled) FIM: F̃(δu) = F̃0 + reshape(Gm vec δu).
        self.f0 = cp.Parameter((N_PARAMS, N_PARAMS), name="fim0")
        self.gm = cp.Parameter((N_PARAMS * N_PARAMS, 6 * n), name="fim_gradient")
        fim_var = cp.Variable((N_PARAMS, N_PARAMS), symmetric=True, name="fim")
        cons.append(
            fim_var == self.f0 + cp.reshape(self.gm @ cp.vec(du, order="C"), (N_PARAMS, N_PARAMS), order="C")
        )
        self.crit_param = cp.Parameter((N_PARAMS, N_PARAMS), name="criterion_weight")
        if p.criterion == "A":
            z = cp.Variable((2 * N_PARAMS, 2 * N_PARAMS), PSD=True, name="schur")
            cons += [z[:N_PARAMS, :N_PARAMS] == fim_var, z[:N_PARAMS, N_PARAMS:] == self.crit_param]
            crit_expr = cp.trace(z[N_PARAMS:, N_PARAMS:])
        elif p.criterion == "D":
            crit_expr = -cp.log_det(fim_var) / N_PARAMS
        else:
            t_min = cp.Variable(name="lambda_min")
            z = cp.Variable((N_PARAMS, N_PARAMS), PSD=True, name="lmi")
            cons.append(z == fim_var - t_min * self.crit_param)
            crit_expr = -t_min
        penalty_expr = sum(cp.sum(s) for s in slacks)
        self.problem = cp.Problem(cp.Minimize(crit_expr + penalty * penalty_expr), cons)
        self.merit = merit

    def set_iterate(self, ev: Evaluation, lin, delta_force: float, delta_torque: float) -> None:
        p = self.p
        n = self.n
        x = ev.x
        self.u_bar.value = ev.u
        self.v_bar.value = x[:, 3:6]
        self.w_bar.value = x[:, 10:13]
        self.rotation.set(lin.a, lin.b)
        self.delta.value = np.concatenate([delta_force * p.limits.force_N, delta_torque * p.limits.torque_Nm])
        pos = x[:, 0:3]
        margin = self.merit.margin
        if self.has_keep_in:
            _, boxes = keep_in_violation(p.scene, pos, margin)
            lo = np.array([p.scene.keep_in[i].lower for i in boxes]) + margin
            hi = np.array([p.scene.keep_in[i].upper for i in boxes]) - margin
            self.in_lo0.value = lo - pos[:-1]
            self.in_hi0.value = hi - pos[:-1]
            self.in_lo1.value = lo - pos[1:]
            self.in_hi1.value = hi - pos[1:]
        mid = 0.5 * (pos[:-1] + pos[1:])
        for e, ell in enumerate(p.scene.keep_out):
            n_hat, beta, _ = point_halfspaces(keep_out_zone(ell), mid)
            bound = beta + self.merit.keep_out_margin
            self.out_n[e].value = n_hat
            self.out_c0[e].value = bound - np.einsum("ki,ki->k", n_hat, pos[:-1])
            self.out_c1[e].value = bound - np.einsum("ki,ki->k", n_hat, pos[1:])
        self.r_end.value = pos[n] - p.goal[0:3]
        err, jac = attitude_error(p.goal[6:10], x[n, 6:10])
        self.att_err.value = err
        self.att_jac.value = jac
        # Constraints the linear model predicts only to first order (rotation) are aimed at a tightened bound
        # (κ × the true one) but never tighter than the current value, so the slacks at zero step still equal the
        # true violations: linearisation errors of a step then stay inside the true bound (no Maratos effect).
        kappa = self.linearisation_margin
        tol = p.terminal
        self.att_bound.value = np.minimum(tol.attitude_rad, np.maximum(kappa * tol.attitude_rad, np.abs(err)))
        w_end = np.abs(x[n, 10:13])
        self.w_end_bound.value = np.minimum(
            tol.angular_velocity_radps, np.maximum(kappa * tol.angular_velocity_radps, w_end)
        )
        w_max = p.limits.angular_velocity_radps[None, :]
        rate_kappa = 1.0 - (1.0 - kappa) * self.rate_margin_fraction
        self.w_bound.value = np.minimum(w_max, np.maximum(rate_kappa * w_max, np.abs(x[1:, 10:13])))

        # Scaled FIM model: F̃ = Dθ F Dθ / c with c = tr(Dθ F Dθ)/4 (O(1) numbers for the conic solver).
        d_theta = np.abs(p.theta)
        f_rel = d_theta[:, None] * ev.fim * d_theta[None, :]
        c = float(np.trace(f_rel)) / N_PARAMS
        self.f0.value = f_rel / c
        gm = np.zeros((N_PARAMS * N_PARAMS, 6 * n))
        for idx, (a, b) in enumerate(_PAIRS):
            row = lin.gradients[idx].reshape(-1) * d_theta[a] * d_theta[b] / c
            gm[a * N_PARAMS + b] = row
            gm[b * N_PARAMS + a] = row
        self.gm.value = gm
        # Criterion on F_s = D_s F D_s = c T F̃ T with T = D_s Dθ⁻¹ (see the module docstring of fim_gradient).
        t_diag = np.diag(self.merit.d) / d_theta
        ref = self.merit.reference
        assert ref is not None
        if p.criterion == "A":
            self.crit_param.value = np.diag(1.0 / t_diag) / np.sqrt(c * ref)
        elif p.criterion == "E":
            self.crit_param.value = np.diag(1.0 / t_diag**2) * abs(ref) / c
        else:
            self.crit_param.value = np.eye(N_PARAMS)

    def solve(self) -> tuple[str, np.ndarray | None, float]:
        """Solve; returns (status, δu or None, total slack)."""
        try:
            with warnings.catch_warnings():
                # An inaccurate solve is reported in the status (and judged by the merit test), not as a warning.
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=cp.CLARABEL)
            status = str(self.problem.status)
        except cp.SolverError as exc:
            return f"solver_error: {exc}", None, float("nan")
        if status not in _OK or self.du.value is None:
            return status, None, float("nan")
        slack = float(sum(np.sum(np.maximum(s.value, 0.0)) for s in self.slacks))  # type: ignore[arg-type]
        return status, np.array(self.du.value), slack


# ----------------------------------------------------------------------------------------------------------------
# The SCP loop
# ----------------------------------------------------------------------------------------------------------------


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
    margin = chord_margin_m(lim.force_N, p.theta[0], p.dt) + p.clearance_m
    pattern = translation_excitation(p.start, u[:, 0:3], p.dt, p.theta[0], lim, p.scene, margin)
    for _ in range(12):
        amp = frac * np.vstack([np.where(np.any(pattern != 0, axis=0), 0.0, lim.force_N), lim.torque_Nm])
        u = rest_to_rest_inputs(p.start, p.goal, p.steps, p.dt, p.theta, excitation=amp)
        u[:, 0:3] += pattern
        x, _ = propagate_with_sensitivities(p.start, u, p.theta, p.dt)
        ok = (
            np.all(np.abs(u) <= 0.9 * lim.input)
            and np.all(np.abs(x[:, 3:6]) <= 0.9 * lim.velocity_mps)
            and np.all(np.abs(x[:, 10:13]) <= 0.9 * lim.angular_velocity_radps)
        )
        if ok:
            return u
        frac *= 0.5
    return np.clip(u, -lim.input, lim.input)


class _ScpRun:
    """One SCP run from one start, advanced an iteration at a time (see the module docstring)."""

    def __init__(self, problem: ExcitationProblem, settings: ScpSettings, merit: _Merit, sub: _Subproblem,
                 start: Evaluation) -> None:
        self.p = problem
        self.s = settings
        self.merit = merit
        self.sub = sub
        self.first = start
        self.current = start
        # Separate trust regions for force and torque: translation is exactly linear in the force, while the
        # rotation (and so the final attitude and the rates) is where the linear model errs.
        self.d_force = self.d_torque = settings.trust_region_initial
        self.history: list[ScpIterate] = []
        self.lin = None
        self.stop: str | None = None

    def step(self) -> None:
        p, settings, merit, sub = self.p, self.s, self.merit, self.sub
        it = len(self.history) + 1
        current = self.current
        if self.lin is None:
            self.lin = fim_gradients(p.start, current.u, p.theta, p.dt, p.measurement, _BASIS)  # type: ignore[assignment]
        lin = self.lin
        sub.set_iterate(current, lin, self.d_force, self.d_torque)
        t0 = time.perf_counter()
        status, du, slack = sub.solve()
        solve_time = time.perf_counter() - t0
        if du is None:
            self.d_force *= settings.shrink
            self.d_torque *= settings.shrink
            self.history.append(
                ScpIterate(it, current.criterion, current.merit, current.violation, float("nan"), float("nan"),
                           float("nan"), float("nan"), self.d_force, self.d_torque, False, status, solve_time)
            )
            if max(self.d_force, self.d_torque) < settings.trust_region_min:
                self.stop = f"subproblem failed ({status})"
            return
        dfim = _fim_step(lin.gradients, du)  # type: ignore[attr-defined]
        crit_model = criterion_value(current.fim + dfim, p.criterion, merit.d)
        predicted = merit.normalise(crit_model) + settings.penalty * slack if np.isfinite(crit_model) else np.inf
        predicted_decrease = current.merit - predicted
        trial = np.clip(current.u + du, -p.limits.input, p.limits.input)
        candidate = merit.evaluate(trial)
        if candidate.violations["terminal_attitude"] > 0 or candidate.violations["terminal_angular_velocity"] > 0:
            corrected = merit.evaluate(restore_rotation_endpoint(p, trial))
            if corrected.merit < candidate.merit:
                candidate = corrected
        actual = current.merit - candidate.merit
        ratio = actual / predicted_decrease if predicted_decrease > 0 else float("nan")
        accepted = bool(actual > 0 and predicted_decrease > 0 and ratio >= settings.accept_ratio)
        rotation_blamed = False
        if accepted:
            self.current = current = candidate
            self.lin = None
            if ratio >= settings.good_ratio:
                self.d_force = min(self.d_force * settings.grow, settings.trust_region_max)
                self.d_torque = min(self.d_torque * settings.grow, settings.trust_region_max)
        else:
            rotation_blamed = _rotational_violation(candidate) > _rotational_violation(current)
            self.d_torque *= settings.shrink
            if not rotation_blamed or self.d_torque < settings.trust_region_min:
                self.d_force *= settings.shrink
        self.history.append(
            ScpIterate(it, current.criterion, current.merit, current.violation, candidate.criterion,
                       candidate.merit, predicted, ratio, self.d_force, self.d_torque, accepted, status, solve_time)
        )
        if not (predicted_decrease > settings.tolerance) and not rotation_blamed:
            self.stop = "converged (predicted decrease below tolerance)"
        elif max(self.d_force, self.d_torque) < settings.trust_region_min:
            self.stop = "trust region below its minimum"


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
        x, _ = propagate_with_sensitivities(p.start, u, p.theta, p.dt)
        if (np.all(np.abs(u) <= 0.9 * lim.input) and np.all(np.abs(x[:, 3:6]) <= 0.9 * lim.velocity_mps)
                and np.all(np.abs(x[:, 10:13]) <= 0.9 * lim.angular_velocity_radps)):
            break
        frac *= 0.5
    return np.clip(u, -lim.input, lim.input)


def design_excitation(
    problem: ExcitationProblem,
    settings: ScpSettings | None = None,
    u_init: np.ndarray | None = None,
    progress: Callable[[float], None] | None = None,
    rng: np.random.Generator | None = None,
) -> ExcitationDesign:
    """Design an information-optimal excitation trajectory (Doerr Eq. 30) by SCP; see the module docstring.

    Parameters
    ----------
    problem : ExcitationProblem
    settings : ScpSettings, optional
    u_init : ndarray, shape (N, 6), optional
        Initial inputs (default: :func:`initial_guess`).
    progress : callable, optional
        Called with the fraction of the iteration budget used after each iteration (and 1.0 at the end).
    rng : numpy.random.Generator, optional
        Source of the extra starts (:func:`perturbed_guess`); a fixed seed by default.

    Returns
    -------
    ExcitationDesign

    Raises
    ------
    InfeasibleError
        When the goal cannot be reached at rest within the duration under the limits, or the initial guess
        carries no information on some parameter.
    """
    settings = settings or ScpSettings()
    wall = time.perf_counter()
    p = problem
    check_reachable(p.start, p.goal, p.duration_s, p.theta, p.limits)
    merit = _Merit(p, settings.penalty)
    if u_init is None:
        u0 = initial_guess(p)
    else:
        u0 = np.clip(np.asarray(u_init, dtype=float), -p.limits.input, p.limits.input)
    sub = _Subproblem(p, merit, settings.penalty)
    # The first start fixes the merit's normalisation, so that all starts are compared on the same merit.
    runs = [_ScpRun(p, settings, merit, sub, merit.evaluate(u0))]
    rng = np.random.default_rng(0) if rng is None else rng
    for _ in range(settings.starts - 1):
        runs.append(_ScpRun(p, settings, merit, sub, merit.evaluate(perturbed_guess(p, rng))))
    budget = settings.max_iterations
    used = 0
    if len(runs) > 1:
        # Multi-start: information is a convex function of the inputs and it is *maximised*, so the SCP ends in a
        # local optimum that depends on the start. Every start gets a few iterations; the best continues.
        for run in runs:
            for _ in range(settings.screening_iterations):
                if run.stop is not None:
                    break
                run.step()
                used += 1
                if progress is not None:
                    progress(min(used / (budget + settings.starts * settings.screening_iterations), 1.0))
    best = min(runs, key=lambda r: r.current.merit)
    while best.stop is None and len(best.history) < budget:
        best.step()
        used += 1
        if progress is not None:
            progress(min(used / (budget + settings.starts * settings.screening_iterations), 1.0))
    if best.stop is None:
        best.stop = "iteration limit"
    current, first, history, stop = best.current, best.first, best.history, best.stop
    if len(runs) > 1:
        stop += f" (best of {len(runs)} starts: start {runs.index(best) + 1})"

    if progress is not None:
        progress(1.0)
    x = current.x
    n = p.steps
    t = p.dt * np.arange(n + 1)
    u_full = np.vstack([current.u, np.zeros((1, 6))])
    traj = Trajectory(t, x, u_full, name="excitation")
    x_init = first.x
    initial = Trajectory(t, x_init, np.vstack([first.u, np.zeros((1, 6))]), name="initial_guess")
    fim_meas = current.fim - p.prior
    return ExcitationDesign(
        trajectory=traj,
        fim=fim_meas,
        criterion_initial=first.criterion,
        criterion_final=current.criterion,
        iterations=tuple(history),
        solve_time_s=time.perf_counter() - wall,
        stop_reason=stop,
        terminal_residual=terminal_residual(x[-1], p.goal),
        violations=current.violations,
        collision_free=collision_free(p.scene, x, current.u, p.dt, p.theta[0]),
        crb_std=cramer_rao_std(fim_meas, p.theta),
        information_over_time=cumulative_information(x, current.u, p.theta, p.dt, p.measurement),
        initial=initial,
    )


def restore_rotation_endpoint(
    problem: ExcitationProblem, u: np.ndarray, iterations: int = 3, target_fraction: float = 0.1
) -> np.ndarray:
    """Second-order correction of a trial step: Gauss-Newton on the final attitude and rate, torques only.

    The translational motion is exactly linear in the force, but the final attitude is a strongly nonlinear
    function of the torques over a long horizon, so a trial step that is good for the criterion often misses the
    terminal attitude by more than its tolerance (the Maratos effect of exact-penalty SQP). Each iteration solves
    ``r(u) + J δτ = 0`` for ``r = [e_N, ω_N − ω_goal]`` (6) with the exact RK4 Jacobians along the trial rollout, in
    the least-norm sense weighted by the torque headroom ``(τ_max − |τ|)²`` (saturated steps barely move), then
    clips to the torque limits.

    Parameters
    ----------
    problem : ExcitationProblem
    u : ndarray, shape (N, 6)
        Trial inputs.
    iterations : int, optional
        Gauss-Newton iterations.
    target_fraction : float, optional
        Stop once the residual is below this fraction of the terminal tolerance.

    Returns
    -------
    ndarray, shape (N, 6)
        Inputs with corrected torques.
    """
    p = problem
    u = np.array(u, dtype=float)
    n = p.steps
    tau_max = p.limits.torque_Nm
    tol = p.terminal
    for _ in range(iterations):
        x = np.empty((n + 1, 13))
        x[0] = p.start
        a_rot = np.empty((n, 7, 7))
        b_rot = np.empty((n, 7, 3))
        for k in range(n):
            x_next, a, b, _ = rb.rk4_step_jacobians(x[k], u[k], p.theta, p.dt)
            x_next[6:10] = quat.normalize(x_next[6:10])
            x[k + 1] = x_next
            a_rot[k] = a[6:13, 6:13]
            b_rot[k] = b[6:13, 3:6]
        err, jac = attitude_error(p.goal[6:10], x[n, 6:10])
        rate = x[n, 10:13] - p.goal[10:13]
        if (np.max(np.abs(err)) <= target_fraction * tol.attitude_rad
                and np.max(np.abs(rate)) <= target_fraction * tol.angular_velocity_radps):
            break
        m = np.zeros((6, 7))
        m[0:3, 0:4] = jac
        m[3:6, 4:7] = np.eye(3)
        jt = np.empty((n, 6, 3))
        for k in range(n - 1, -1, -1):
            jt[k] = m @ b_rot[k]
            m = m @ a_rot[k]
        j_flat = jt.transpose(1, 0, 2).reshape(6, 3 * n)
        weight = ((tau_max - np.abs(u[:, 3:6])) ** 2 + (0.01 * tau_max) ** 2).reshape(-1)
        residual = np.concatenate([err, rate])
        step = -weight * (j_flat.T @ np.linalg.solve((j_flat * weight) @ j_flat.T, residual))
        u[:, 3:6] = np.clip(u[:, 3:6] + step.reshape(n, 3), -tau_max, tau_max)
    return u


def _rotational_violation(ev: Evaluation) -> float:
    v = ev.violations
    return v["angular_velocity"] + v["terminal_attitude"] + v["terminal_angular_velocity"]


def _fim_step(gradients: np.ndarray, du: np.ndarray) -> np.ndarray:
    """First-order change of F for a step δu, from the gradients of its 10 distinct entries."""
    vals = np.einsum("pki,ki->p", gradients, du)
    out = np.zeros((N_PARAMS, N_PARAMS))
    for idx, (a, b) in enumerate(_PAIRS):
        out[a, b] = out[b, a] = vals[idx]
    return out


def cumulative_information(
    x: np.ndarray, u: np.ndarray, theta: np.ndarray, dt: float, model: MeasurementModel
) -> np.ndarray:
    """Fisher information of the measurements up to each sample, shape (N+1, 4, 4) (zero at t = 0).

    Parameters
    ----------
    x : ndarray, shape (N+1, 13)
        Rollout states (``x[0]`` is the start).
    u : ndarray, shape (N, 6)
    theta : ndarray, shape (4,)
        θ = [m, Ixx, Iyy, Izz] of the model.
    dt : float
    model : MeasurementModel

    Returns
    -------
    ndarray, shape (N+1, 4, 4)
    """
    _, s = propagate_with_sensitivities(x[0], u, theta, dt)
    g_state, g_acc = output_sensitivities(x, u, s, theta, model)
    per_step = np.einsum("kmi,kmj->kij", g_state, g_state) + np.einsum("kmi,kmj->kij", g_acc, g_acc)
    out = np.zeros((u.shape[0] + 1, N_PARAMS, N_PARAMS))
    out[1:] = np.cumsum(per_step, axis=0)
    return out
