"""Trajectory-tracking MPC for the full 6-DoF free-flyer (translation *and* attitude).

The papers assumed perfect attitude tracking (Doerr et al. 2021, Results); this controller tracks attitude
too, within the torque limits. Each step it expresses the measured state and the reference over the horizon
in a local error chart and solves the standard MPC of [Doerr2021] Eq. 26 on the exact hover discretisation
(:func:`oacli.model.double_integrator.hover_error_model`):

* position relative to the current reference position (a constant shift: translation is exactly linear),
  world-frame velocity (force is applied in the world frame);
* attitude as the body-frame rotation vector relative to the current reference attitude ``q_a``
  (``q = q_a ⊗ exp(φ)``), body angular rate.

Reference inputs over the horizon are the model-consistent feed-forward (:func:`oacli.trajectory.feedforward_inputs`).

Workspace (optional, given a scene): the predicted positions of steps 1..N stay in the keep-in box of the
reference and outside the keep-out zones grown by the robot's body (:mod:`oacli.control.workspace`, half-spaces
linearised at the previous plan when there is one), and the point where each predicted state would stop, braking
at half the model's deceleration (force limit / model mass), stays in the box too — so a plant up to twice as
heavy as the model has room to stop. The rows are soft with an exact ℓ1 penalty (:class:`LinearMPC`):
a measured state outside a row never makes the QP infeasible.

State estimate (optional, :class:`StateEstimate`): the controller plans from the measured state, or, with an
observer, from a steady-state Kalman filter's estimate of position and velocity
(:class:`oacli.control.observer.TranslationObserver`, fed the commanded force). Either way the true position at the
next step is the one predicted from the estimate minus the prediction's error, zero-mean with per-axis σ
``sqrt(σ_p² + dt² σ_v²)`` from a raw measurement (position and velocity errors) or ``sqrt(P⁻_pp)``, the filter's
a-priori position variance (:func:`predicted_position_std`); the workspace rows keep it clear at ``k`` σ
(:class:`~oacli.control.workspace.WorkspaceRows`), so the *true* state keeps out of the zones the independent
safety check measures. Beyond that there is no robustness margin here (model error, disturbances: use the tube MPC
for a guarantee). The rows hold at the prediction instants, with no extra margin for the motion between them: a
plan certified collision-free in continuous time (``oacli smooth``) is then followed as closely as without rows.

Failures: when a solve fails the controller follows the shifted previous plan, and once that is used up the LQR
law of the same weights, clipped to the limits. After ``max_consecutive_failures`` failed solves in a row it
latches a *safe hold*: it stops solving, brakes the measured velocity to rest as fast as the force limits allow
(``f = clip(−m v / dt, ±f_max)``) and holds the attitude it had on entry with the attitude LQR (clipped). The
step's SolveInfo.status starts with the mode: the solver's status for a fresh solve, ``"fallback (…)"``,
``"lqr (…)"`` or ``"hold (…)"`` otherwise (with ``success`` False).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from oacli.control.lqr import dlqr, solve_dare
from oacli.control.mpc import POSITION_PENALTY, LinearMPC
from oacli.control.observer import TranslationObserver, kalman_gain
from oacli.control.reference_sampler import ReferenceSampler, attitude_errors, feedforward
from oacli.control.rigid_terms import RigidCompensator
from oacli.control.workspace import WorkspaceRows, shifted_plan
from oacli.geometry.collision import RobotBody
from oacli.geometry.shapes import Scene
from oacli.model import quaternion as quat
from oacli.model.double_integrator import double_integrator, hover_error_model
from oacli.model.limits import MotionLimits
from oacli.types import ControlStep, InertialParams, SolveInfo, Trajectory


@dataclass(frozen=True)
class TrackingWeights:
    """Diagonal MPC weights per axis: state [r, v, φ, ω] and input [f, τ], each shape (3,)."""

    position: np.ndarray
    velocity: np.ndarray
    attitude: np.ndarray
    angular_velocity: np.ndarray
    force: np.ndarray
    torque: np.ndarray

    @property
    def q_diag(self) -> np.ndarray:
        """Stage state weight diagonal (12,)."""
        return np.concatenate([self.position, self.velocity, self.attitude, self.angular_velocity])

    @property
    def r_diag(self) -> np.ndarray:
        """Input weight diagonal (6,)."""
        return np.concatenate([self.force, self.torque])


@dataclass(frozen=True)
class StateEstimate:
    """What the standard MPC acts on and the margin its workspace rows keep for its error (module docstring).

    Attributes
    ----------
    position_std_m, velocity_std_mps : float
        The sensors' σ per axis [m], [m/s] (>= 0).
    observer_accel_std_mps2 : float or None
        σ of the Kalman filter's white process acceleration [m/s²]; None: act on the measurement (also when a
        sensor σ is 0: there is nothing to filter).
    sigmas : float
        k: the rows keep the true position clear at k σ of the prediction's error.
    min_margin_m : float
        Floor [m] of that margin per axis (kept with an exact state too).
    """

    position_std_m: float
    velocity_std_mps: float
    observer_accel_std_mps2: float | None = None
    sigmas: float = 3.0
    min_margin_m: float = 0.0

    @property
    def filtered(self) -> bool:
        """True when the controller acts on the observer's estimate."""
        return self.observer_accel_std_mps2 is not None and self.position_std_m > 0 and self.velocity_std_mps > 0


def predicted_position_std(estimate: StateEstimate, dt_s: float) -> float:
    """σ [m] per axis of the error of the position predicted one step ahead from the state estimate.

    From a raw measurement the prediction ``p̂ + dt v̂ + …`` is off by ``e_p + dt e_v``: σ =
    ``sqrt(σ_p² + dt² σ_v²)``. From the steady-state Kalman filter it is the a-priori covariance ``P⁻`` of the
    filter Riccati equation (:func:`oacli.control.observer.kalman_gain`; Anderson & Moore 1979, §4.4): σ =
    ``sqrt(P⁻_pp)``.

    Parameters
    ----------
    estimate : StateEstimate
    dt_s : float
        Control period [s].

    Returns
    -------
    float

    Notes
    -----
    Independent of the mass: the filter's ``A`` is the double integrator's, and the input (known) adds no error.
    """
    if not estimate.filtered:
        return float(np.hypot(estimate.position_std_m, dt_s * estimate.velocity_std_mps))
    assert estimate.observer_accel_std_mps2 is not None  # filtered
    a, _ = double_integrator(dt_s)
    g = np.array([[0.5 * dt_s * dt_s], [dt_s]])
    q = estimate.observer_accel_std_mps2**2 * (g @ g.T) + 1e-18 * np.eye(2)
    r = np.diag([estimate.position_std_m**2, estimate.velocity_std_mps**2])
    p_prior = solve_dare(np.asarray(a).T, np.eye(2), q, r)
    return float(np.sqrt(p_prior[0, 0]))


def estimate_observer(
    estimate: StateEstimate | None, params: InertialParams, dt_s: float
) -> TranslationObserver | None:
    """The translational observer of ``estimate`` (None when the controller acts on the measurement).

    Parameters
    ----------
    estimate : StateEstimate or None
    params : InertialParams
        The controller's model (its mass [kg] scales the force input).
    dt_s : float
        Control period [s].

    Returns
    -------
    TranslationObserver or None
    """
    if estimate is None or not estimate.filtered:
        return None
    assert estimate.observer_accel_std_mps2 is not None  # filtered
    a, b = double_integrator(dt_s, 1.0 / params.mass_kg)
    gain = kalman_gain(a, dt_s, estimate.observer_accel_std_mps2, estimate.position_std_m, estimate.velocity_std_mps)
    return TranslationObserver(a, b, gain, dt_s)


def to_error_state(x: np.ndarray, origin_m: np.ndarray, q_anchor: np.ndarray) -> np.ndarray:
    """Map full states to the error chart ``[r − origin, v, φ, ω]``.

    Parameters
    ----------
    x : ndarray, shape (..., 13)
        Full states.
    origin_m : ndarray, shape (3,)
        Position origin [m].
    q_anchor : ndarray, shape (4,)
        Attitude the error φ is measured from.

    Returns
    -------
    ndarray, shape (..., 12)
    """
    x = np.asarray(x, dtype=float)
    phi = attitude_errors(q_anchor, x[..., 6:10])
    return np.concatenate([x[..., 0:3] - origin_m, x[..., 3:6], phi, x[..., 10:13]], axis=-1)


class TrackingMPC:
    """Standard MPC tracking a reference trajectory ([Doerr2021] Eq. 26), attitude included.

    Parameters
    ----------
    reference : Trajectory
        The trajectory to follow.
    params : InertialParams
        The controller's model.
    dt_s : float
        Prediction step [s] (the control period by default).
    horizon : int
        Number of prediction steps N.
    weights : TrackingWeights
    limits : MotionLimits
    scene : Scene, optional
        Keep the predicted positions in its free space (soft rows, module docstring); None: positions are free
        (the controller is then exactly the one without workspace rows).
    robot : RobotBody, optional
        The robot's bounding body the keep-out zones grow by (a point if omitted).
    keep_in_margin_m : float
        Distance the robot's centre keeps from the keep-in walls [m] (keep-in boxes bound the centre).
    max_consecutive_failures : int, optional
        Failed solves in a row before the latched safe hold; None: never hold.
    position_penalty : float
        Exact ℓ1 penalty on the position rows' slack [1/m].
    estimate : StateEstimate, optional
        The measured state or an observer's estimate, and the rows' margin for its error (module docstring);
        None: the measured state, no margin.
    rigid : RigidCompensator, optional
        The learned centre of mass and inertia tensor (:mod:`oacli.control.rigid_terms`): the attitude model and
        feed-forward with ``J``, the planned torque limited to ``rigid.planned_torque_limit_Nm`` and the
        commanded torque ``τ + ĉ × R(q̃)ᵀ F``; None: θ = [m, Ixx, Iyy, Izz] alone (the controller as before).
    """

    def __init__(
        self,
        reference: Trajectory,
        params: InertialParams,
        *,
        dt_s: float,
        horizon: int,
        weights: TrackingWeights,
        limits: MotionLimits,
        scene: Scene | None = None,
        robot: RobotBody | None = None,
        keep_in_margin_m: float = 0.0,
        max_consecutive_failures: int | None = None,
        position_penalty: float = POSITION_PENALTY,
        estimate: StateEstimate | None = None,
        rigid: RigidCompensator | None = None,
    ) -> None:
        if max_consecutive_failures is not None and max_consecutive_failures < 1:
            raise ValueError("max_consecutive_failures must be >= 1")
        self.reference = reference
        self._sampler = ReferenceSampler(reference)
        self.params = params
        self.dt_s = float(dt_s)
        self.horizon = int(horizon)
        self.rigid = rigid
        self._tensor = None if rigid is None else rigid.inertia_tensor_kgm2
        if rigid is not None:  # the torque the MPC plans leaves room for the compensation
            limits = MotionLimits(limits.force_N, rigid.planned_torque_limit_Nm, limits.velocity_mps,
                                  limits.angular_velocity_radps)
        self.limits = limits
        self.max_failures = max_consecutive_failures
        self.workspace: WorkspaceRows | None = None
        if scene is not None and (scene.keep_in or scene.keep_out):
            horizon_s = self.horizon * self.dt_s
            self.workspace = WorkspaceRows(
                scene, robot, keep_in_margin_m=keep_in_margin_m,
                activation_m=1.0 + float(np.max(limits.velocity_mps)) * horizon_s,
                error_std_m=None if estimate is None else np.full(
                    3, predicted_position_std(estimate, self.dt_s)),
                error_sigmas=0.0 if estimate is None else estimate.sigmas,
                min_error_margin_m=0.0 if estimate is None else estimate.min_margin_m,
            )
        self.observer = estimate_observer(estimate, params, self.dt_s)
        ws = self.workspace
        a, b = hover_error_model(params, self.dt_s, self._tensor)
        self.mpc = LinearMPC(
            a, b, weights.q_diag, weights.r_diag, self.horizon, limits.input, x_max=limits.error_state,
            keep_in=ws is not None and ws.has_keep_in, keep_out_zones=0 if ws is None else ws.n_zones,
            position_penalty=position_penalty,
            braking_mps2=limits.force_N / params.mass_kg if ws is not None and ws.has_keep_in else None,
            braking_speed_mps=limits.velocity_mps,
        )
        self.lqr_gain, _ = dlqr(a, b, np.diag(weights.q_diag), np.diag(weights.r_diag))
        self._k_att, _ = dlqr(a[6:, 6:], b[6:, 3:], np.diag(weights.q_diag[6:]), np.diag(weights.r_diag[3:]))
        self._plan: np.ndarray | None = None
        self._plan_age = 0
        self._plan_positions: tuple[float, np.ndarray] | None = None  # (time, world positions (N+1, 3))
        self._failures = 0
        self._hold_q: np.ndarray | None = None
        self._offsets = self.dt_s * np.arange(self.horizon + 1)

    def _hold_input(self, x: np.ndarray, q_hold: np.ndarray) -> np.ndarray:
        """Safe hold: brake the measured velocity as fast as the force limits allow, hold the attitude ``q_hold``."""
        force = np.clip(-self.params.mass_kg * x[3:6] / self.dt_s, -self.limits.force_N, self.limits.force_N)
        phi = quat.error_vector(q_hold, x[6:10])
        torque = np.clip(self._k_att @ np.concatenate([phi, x[10:13]]), -self.limits.torque_Nm,
                         self.limits.torque_Nm)
        return np.concatenate([force, torque])

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """Solve once at time ``t`` [s] from the measured state; see :class:`oacli.types.Controller`.

        With an observer the position and velocity are its estimate (updated with this measurement and the
        force of the previous step), the attitude and rate the measured ones.

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state ``[r, v, q, ω]``.

        Returns
        -------
        ControlStep
            The input to hold until the next step, the solve record and the reference state at ``t``.
        """
        x = np.asarray(x_measured, dtype=float)
        if self.observer is None:
            out = self._step(t, x)
        else:
            x = x.copy()
            x[0:6] = self.observer.update(t, x[0:6])
            out = self._step(t, x)
            self.observer.applied(out.u[0:3])
        if self.rigid is not None:  # τ_cmd = τ_des + ĉ × R(q̃)ᵀ F (oacli.control.rigid_terms)
            out = replace(out, u=self.rigid.command(out.u, x[6:10]))
        return out

    def _step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """One step from the state the controller acts on (measured or estimated); see :meth:`step`.

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state ``[r, v, q, ω]``.

        Returns
        -------
        ControlStep
            The input to hold until the next step, the solve record and the reference state at ``t``.
        """
        start = time.perf_counter()
        x = np.asarray(x_measured, dtype=float)
        x_ref_full = self._sampler.states(t + self._offsets)
        if self._hold_q is not None:
            info = SolveInfo("hold (safe_hold)", False, solve_time_s=0.0, step_time_s=time.perf_counter() - start)
            return ControlStep(u=self._hold_input(x, self._hold_q), info=info, x_reference=x_ref_full[0])
        u_ref = feedforward(x_ref_full, self.dt_s, self.params, self._tensor)
        origin = x_ref_full[0, 0:3]
        anchor = x_ref_full[0, 6:10]
        # The measured state and the references in one call (row by row the same values).
        errors = to_error_state(np.vstack([x_ref_full, x]), origin, anchor)
        e0, e_ref = errors[-1], errors[:-1]
        rows = None
        if self.workspace is not None:
            lin = None
            if self._plan_positions is not None:
                plan_t, plan_p = self._plan_positions
                lin = shifted_plan(plan_t, self.dt_s, plan_p, t + self._offsets)
            rows = self.workspace.rows(x_ref_full[:, 0:3], lin).steps(slice(1, None)).shifted(origin)
        sol = self.mpc.solve(e0, e_ref, u_ref, rows)
        if sol.info.success:
            self._plan, self._plan_age, self._failures = sol.u, 0, 0
            self._plan_positions = (t, sol.x[:, 0:3] + origin)
            u = sol.u[0]
            status, success = sol.info.status, True
        else:
            self._plan_age += 1
            self._failures += 1
            success = False
            if self.max_failures is not None and self._failures >= self.max_failures:
                self._hold_q = np.array(x[6:10])
                u = self._hold_input(x, self._hold_q)
                status = f"hold ({sol.info.status})"
            elif self._plan is not None and self._plan_age < self.horizon:
                u = self._plan[self._plan_age]
                status = f"fallback ({sol.info.status})"
            else:
                u = u_ref[0] + self.lqr_gain @ (e0 - e_ref[0])
                status = f"lqr ({sol.info.status})"
            u = np.clip(u, -self.limits.input, self.limits.input)
        info = SolveInfo(
            status=status,
            success=success,
            objective=sol.info.objective,
            iterations=sol.info.iterations,
            solve_time_s=sol.info.solve_time_s,
            step_time_s=time.perf_counter() - start,
        )
        return ControlStep(u=np.asarray(u, dtype=float), info=info, x_reference=x_ref_full[0])
