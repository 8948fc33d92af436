"""Robust tube MPC tracking a reference: tube MPC on translation, standard MPC on attitude, one QP per step.

Translation (Mayne, Seron & Raković 2005; [Doerr2021] Eqs. 15-27): the nominal MPC chooses a free initial
nominal state ``z_0`` with ``x̃ − z_0 ∈ Z`` (x̃ the measured state) and a nominal plan under the tightened
constraints of :class:`oacli.control.tube_design.TubeDesign`; the applied force is
``u = v_0 + K (x̃ − z_0)`` ([Doerr2021] Eqs. 18-19). The nominal model may step slower than the controller (ReSWARM:
1 s steps at 5 Hz); the nominal state then evolves between control instants with the exact double integrator
under the held nominal input, so the tube guarantee holds at every control instant: if the disturbance of each
control step lies in W, ``x̃_{k+1} − ẑ_{k+1} ∈ Z`` with ``ẑ_{k+1} = A z_0 + B v_0`` (Z is robust positively
invariant), and then ``u ∈ U`` and the true velocity stays within its limit.

Output feedback ([Mayne2006]; ``observer``): the controller acts on the estimate ``x̂`` of
:class:`oacli.control.observer.TranslationObserver` instead of ``x̃``; the design's lasso is then
``R = T ⊖ S`` and its promise for the true state ``ẑ ⊕ T`` (:mod:`oacli.sets.error_set`), which holds while every
noise sample is within the design's bound. An optional cost ``initial_weight`` on ``x̂ − z_0`` keeps the nominal on
the estimate (it changes no constraint). With a :class:`~oacli.control.observer.RateObserver` the attitude MPC
uses the estimated body rate.

Attitude: the papers assumed it perfectly tracked (Doerr 2021, Results) and tubed translation only; here it is
tracked by the standard MPC of [Doerr2021] Eq. 26 in the body-frame rotation-vector chart of
:mod:`oacli.control.tracking`, within the torque limits, in the same QP (one solver call per step). A linear tube
on rotation would need W to bound the gyroscopic and chart linearisation errors, which grow with the rate; we
claim no guarantee there that we cannot prove.

Workspace (optional, given a scene): the nominal positions ``z_0..z_N`` stay, HARD, in the keep-in box of the
reference and outside the keep-out zones grown by the robot's body (:mod:`oacli.control.workspace`, half-spaces
linearised at the previous nominal plan when there is one), tightened so that the guarantee covers the true
state: the true position is ``z + ẽ − n`` with ``ẽ ∈ Z`` and ``|n| ≤`` the noise bound, so each row is tightened
by Z's position extent (:meth:`TubeDesign.position_extent`) plus the noise bound (per face of the box; the support
``Σ_i |n_i| ext_i`` for a half-space), by the parabola's distance from its chord between two nominal knots
(``ū T²/(8m)``, so the fallback's shifted plan stays inside) and by half the farthest the robot can travel in one
control period (``½‖v_max dt + ½ (u_max/m) dt²‖``, so the motion *between* control instants stays inside too).
With the braking rows (``braking=True``, default) the point where the nominal would stop, braking at ``ū/m``
from the plan's terminal knot, stays in the box too (linear rows invariant under braking,
:mod:`oacli.control.tube_qp`): a plan can always be continued by braking (the rows stay feasible from step to
step, up to a change of the box chosen for a step) and the safe hold, which finishes the plan and then brakes the
nominal at ū, keeps the keep-in.
Hence, while the disturbance of every control step lies in W and the QP solves (or the shifted plan is followed),
the true robot body stays in the keep-in boxes and out of the keep-out zones. When the tightened rows cannot be
met (e.g. a reference too close to a wall), the QP is infeasible and the failure handling below applies.

Failures: when a solve fails, the step follows the shifted previous nominal plan (``z = ẑ``, ``v`` = the plan's
input for this time) with the ancillary law, which keeps every guarantee; after ``max_consecutive_failures``
failures in a row, or when the plan is used up, the controller enters a latched *safe hold*: the nominal brakes
to rest with the largest tightened input (``v = clip(−m v_z / dt, Ū)``, so ``|v_z|`` never grows) and stays
there, the ancillary law keeps the robot in ``z ⊕ Z``, and attitude is held by an LQR on the attitude at entry
(clipped to the torque limits). With workspace rows the hold first finishes the last plan (nominal input from the
plan, as in the fallback) and brakes from its end, the state the braking rows certify; it brakes at once when
there is no plan left.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from oacli.control.lqr import dlqr, solve_dare
from oacli.control.observer import RateObserver, TranslationObserver
from oacli.control.reference_sampler import ReferenceSampler, attitude_errors, feedforward
from oacli.control.rigid_terms import RigidCompensator
from oacli.control.tracking import TrackingWeights
from oacli.control.tube_design import TubeDesign
from oacli.control.tube_qp import LinearConstraint, NominalQP, PositionRowsSpec, QPBlock
from oacli.control.workspace import WorkspaceRows, shifted_plan
from oacli.geometry.collision import RobotBody
from oacli.geometry.shapes import Scene
from oacli.model import quaternion as quat
from oacli.model.double_integrator import hover_error_model
from oacli.model.limits import MotionLimits
from oacli.types import ControlStep, InertialParams, SolveInfo, Trajectory

MODES = ("mpc", "fallback", "hold")


@dataclass(frozen=True)
class TubeHistory:
    """What the tube controller did at each of its K steps (arrays over steps).

    Attributes
    ----------
    t : ndarray, shape (K,)
        Step times [s].
    mode : tuple of str
        ``"mpc"`` (solved), ``"fallback"`` (shifted previous plan) or ``"hold"`` (safe hold).
    nominal_state : ndarray, shape (K, 6)
        Nominal translational state ``z = [r (world) m, v m/s]`` used at the step.
    nominal_force, ancillary_force : ndarray, shape (K, 3)
        ``v`` and ``K (x̃ − z)`` [N]; the commanded force is their sum.
    torque : ndarray, shape (K, 3)
        The attitude MPC's torque τ_des [N·m] (standard MPC, no tube); the commanded torque adds the
        centre-of-mass compensation with a :class:`~oacli.control.rigid_terms.RigidCompensator`.
    predicted_nominal : ndarray, shape (K, 6)
        ``ẑ_k = A z_{k−1} + B v_{k−1}`` (NaN at the first step).
    tube_margin : ndarray, shape (K,)
        ``min_i (h_i − H_i (x̃_k − ẑ_k))``: ≥ 0 when the measured state is in the promised tube ``ẑ_k ⊕ Z``.
    lasso_margin : ndarray, shape (K,)
        The same for ``x̃_k − z_k`` (the constraint of the QP; ≥ 0 up to solver tolerance).
    solver_failed : ndarray of bool, shape (K,)
        A solve was attempted at the step and failed.
    estimate : ndarray, shape (K, 6)
        The translational state the controller used: the observer's estimate ``x̂`` (output feedback), else the
        measured state.
    """

    t: np.ndarray
    mode: tuple[str, ...]
    nominal_state: np.ndarray
    nominal_force: np.ndarray
    ancillary_force: np.ndarray
    torque: np.ndarray
    predicted_nominal: np.ndarray
    tube_margin: np.ndarray
    lasso_margin: np.ndarray
    solver_failed: np.ndarray
    estimate: np.ndarray

    def count(self, mode: str) -> int:
        """Number of steps in ``mode``.

        Parameters
        ----------
        mode : str
            A mode name as recorded in ``mode``.

        Returns
        -------
        int
        """
        return sum(m == mode for m in self.mode)


@dataclass(frozen=True)
class TerminalWeights:
    """Diagonal terminal weight of the nominal translation MPC (position, velocity per axis, shape (3,))."""

    position: np.ndarray
    velocity: np.ndarray


class TubeMPC:
    """Robust tube MPC on translation plus standard MPC on attitude (see the module docstring).

    Parameters
    ----------
    reference : Trajectory
    design : TubeDesign
        Ancillary gain, Z and tightened constraints at the control period; its ``mass_kg`` is the controller's
        model mass (the one the tube was designed for, taken once).
    inertia_kgm2 : ndarray, shape (3,)
        The controller's principal inertias [kg·m²] (e.g. ``RobotModel.inertia_kgm2``).
    horizon : int
        N, prediction steps.
    prediction_step_s : float
        Nominal model step [s], an integer multiple of ``design.dt_s``.
    weights : TrackingWeights
        Stage weights (translation and attitude).
    limits : MotionLimits
        Torque and angular-velocity limits for attitude (translation uses the design's tightened sets).
    terminal : TerminalWeights, optional
        Translation terminal weight; the discrete Riccati solution when omitted.
    max_consecutive_failures : int
        Failed solves in a row before the safe hold.
    fast : bool
        Solve through the direct Clarabel path (True) or ``problem.solve()`` (False).
    scene : Scene, optional
        Keep the robot in its free space (hard, tightened rows; module docstring); None: positions are free (the
        controller is then exactly the one without workspace rows).
    robot : RobotBody, optional
        The robot's bounding body the keep-out zones grow by (a point if omitted).
    keep_in_margin_m : float
        Distance the robot's centre keeps from the keep-in walls [m] (keep-in boxes bound the centre).
    braking : bool
        Keep the nominal's braking points in the keep-in box too (module docstring).
    observer : TranslationObserver, optional
        Output feedback ([Mayne2006]): the controller acts on the observer's estimate (the design then has the
        error set; :mod:`oacli.sets.error_set`); shared by the successive controllers of a redesign.
    rigid : RigidCompensator, optional
        The learned centre of mass and inertia tensor (:mod:`oacli.control.rigid_terms`): the attitude model and
        feed-forward with ``J``, the attitude QP's torque bound ``rigid.planned_torque_limit_Nm`` and the commanded
        torque ``τ + ĉ × R(q̃)ᵀ F`` (F = v + K(x̂ − z), the whole commanded force); None: the controller of
        θ = [m, Ixx, Iyy, Izz] alone.
    """

    def __init__(
        self,
        reference: Trajectory,
        design: TubeDesign,
        *,
        inertia_kgm2: np.ndarray,
        horizon: int,
        prediction_step_s: float,
        weights: TrackingWeights,
        limits: MotionLimits,
        terminal: TerminalWeights | None = None,
        max_consecutive_failures: int = 5,
        fast: bool = True,
        scene: Scene | None = None,
        robot: RobotBody | None = None,
        keep_in_margin_m: float = 0.0,
        braking: bool = True,
        observer: TranslationObserver | None = None,
        initial_weight: float = 0.0,
        rate_observer: RateObserver | None = None,
        rigid: RigidCompensator | None = None,
    ) -> None:
        params = InertialParams(design.model.mass_kg, inertia_kgm2)
        self.rigid = rigid
        tensor = self._tensor = None if rigid is None else rigid.inertia_tensor_kgm2
        if rigid is not None:  # the torque the attitude MPC plans leaves room for the compensation
            limits = MotionLimits(limits.force_N, rigid.planned_torque_limit_Nm, limits.velocity_mps,
                                  limits.angular_velocity_radps)
        ratio = prediction_step_s / design.dt_s
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError("prediction_step_s must be an integer multiple of the control period")
        self.reference, self.params, self.design = reference, params, design
        self.observer, self.rate_observer = observer, rate_observer
        self._sampler = ReferenceSampler(reference)
        self.horizon, self.step_s, self.dt_s = int(horizon), float(prediction_step_s), design.dt_s
        self.limits, self.max_failures = limits, int(max_consecutive_failures)
        a12, b12 = hover_error_model(params, self.step_s, tensor)
        a_t, b_t = a12[:6, :6], b12[:6, :3]
        a_r, b_r = a12[6:, 6:], b12[6:, 3:]
        q_t = np.concatenate([weights.position, weights.velocity])
        q_r = np.concatenate([weights.attitude, weights.angular_velocity])
        p_t = (
            solve_dare(a_t, b_t, np.diag(q_t), np.diag(weights.force))
            if terminal is None
            else np.diag(np.concatenate([terminal.position, terminal.velocity]))
        )
        self.workspace = None
        spec = None
        if scene is not None and (scene.keep_in or scene.keep_out):
            self.workspace = self._workspace_rows(scene, robot, keep_in_margin_m)
            u_bar = np.array([min(-lo, hi) for lo, hi in (ax.force_bounds_N for ax in design.axes)])
            v_bar = np.array([max(-lo, hi) for lo, hi in (ax.velocity_bounds_mps for ax in design.axes)])
            spec = PositionRowsSpec(
                keep_in=self.workspace.has_keep_in, keep_out_zones=self.workspace.n_zones,
                braking_mps2=u_bar / params.mass_kg if braking else None, braking_speed_mps=v_bar,
            )
        trans = QPBlock(
            "translation", a_t, b_t, q_t, weights.force, p_t,
            state=design.tightened_state, input=design.tightened_input, lasso=design.lasso_for_solver,
            positions=spec, initial_weight=initial_weight * np.diag(q_t) if initial_weight > 0 else None,
        )
        rot = QPBlock(
            "attitude", a_r, b_r, q_r, weights.torque, solve_dare(a_r, b_r, np.diag(q_r), np.diag(weights.torque)),
            state=LinearConstraint.box(np.r_[np.full(3, np.inf), limits.angular_velocity_radps]),
            input=LinearConstraint.box(limits.torque_Nm),
        )
        self.qp = NominalQP([trans, rot], self.horizon, fast=fast)
        self.fast = fast
        # Exact per-control-step models for the nominal evolution and the attitude hold.
        a_c, b_c = hover_error_model(params, self.dt_s, tensor)
        self._a_c, self._b_c = a_c[:6, :6], b_c[:6, :3]
        self._k_att, _ = dlqr(a_c[6:, 6:], b_c[6:, 3:], np.diag(q_r), np.diag(weights.torque))
        self._gain = design.gain
        lo = np.array([ax.force_bounds_N[0] for ax in design.axes])
        hi = np.array([ax.force_bounds_N[1] for ax in design.axes])
        self._v_bounds = (lo, hi)
        self._offsets = self.step_s * np.arange(self.horizon + 1)
        self._plan_t: float | None = None
        self._plan_positions: np.ndarray | None = None  # nominal positions of the last plan, world (N+1, 3)
        self._plan_v: np.ndarray | None = None
        self._plan_tau: np.ndarray | None = None
        self._z_pred: np.ndarray | None = None
        self._failures = 0
        self._hold_q: np.ndarray | None = None
        self._rec: dict[str, list[Any]] = {k: [] for k in (
            "t", "mode", "z", "v", "anc", "tau", "z_pred", "tube", "lasso", "failed", "xhat")}

    # -- helpers -----------------------------------------------------------------------------------------------

    def _workspace_rows(self, scene: Scene, robot: RobotBody | None, keep_in_margin_m: float) -> WorkspaceRows:
        """The workspace rows tightened for the true state (module docstring)."""
        design, m = self.design, self.params.mass_kg
        noise = np.array([ax.disturbance.noise_bound[0] for ax in design.axes])
        u_bar = np.array([max(-lo, hi) for lo, hi in (ax.force_bounds_N for ax in design.axes)])
        chord = u_bar / m * self.step_s**2 / 8.0
        extent = design.position_extent() + (noise + chord)[:, None]
        u_max = np.array([ax.force_limit_N for ax in design.axes])
        v_max = np.array([ax.velocity_limit_mps for ax in design.axes])
        travel = v_max * self.dt_s + 0.5 * u_max / m * self.dt_s**2
        return WorkspaceRows(scene, robot, keep_in_margin_m=keep_in_margin_m, extent_m=extent,
                             clearance_m=0.5 * float(np.linalg.norm(travel)),
                             activation_m=1.0 + float(np.max(v_max)) * self.horizon * self.step_s)

    def _plan_input(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Nominal force and torque of the stored plan at time ``t``; None when there is none or it is used up."""
        if self._plan_t is None or self._plan_v is None or self._plan_tau is None:  # set together
            return None
        j = int(np.floor((t - self._plan_t) / self.step_s + 1e-9))
        if j >= self.horizon:
            return None
        return self._plan_v[j], self._plan_tau[j]

    def _hold_torque(self, x: np.ndarray) -> np.ndarray:
        q_hold = x[6:10] if self._hold_q is None else self._hold_q  # called in the hold, where it is set
        phi = quat.error_vector(q_hold, x[6:10])
        tau = self._k_att @ np.concatenate([phi, x[10:13]])
        return np.asarray(np.clip(tau, -self.limits.torque_Nm, self.limits.torque_Nm))

    def _brake(self, z: np.ndarray) -> np.ndarray:
        """Nominal input of the safe hold: stop the nominal velocity as fast as Ū allows (never overshoots)."""
        v = -self.params.mass_kg * z[3:6] / self.dt_s
        return np.clip(v, *self._v_bounds)

    def enter_safe_hold(self, q_hold: np.ndarray) -> None:
        """Latch the safe hold from the next step on (e.g. when W no longer holds, :mod:`oacli.control.tube_monitor`).

        Parameters
        ----------
        q_hold : ndarray, shape (4,)
            Attitude to hold, scalar-last quaternion.
        """
        if self._hold_q is None:
            self._hold_q = np.array(q_hold, dtype=float)

    # -- the controller step -----------------------------------------------------------------------------------

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """One control step at time ``t`` [s]; see :class:`oacli.types.Controller`.

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
        if self.rate_observer is not None:
            x = x.copy()
            x[10:13] = self.rate_observer.update(t, x[10:13])
        x_ref_full = self._sampler.states(t + self._offsets)
        # The translational state [r (world), v] the controller acts on: measured, or the observer's estimate.
        x_t = x[0:6] if self.observer is None else self.observer.update(t, x[0:6])
        z_pred = self._z_pred  # world coordinates
        tube_margin = np.nan if z_pred is None else self.design.error_margin(x_t - z_pred)
        info: SolveInfo
        attempted = self._hold_q is None
        if attempted:
            u_ref = feedforward(x_ref_full, self.step_s, self.params, self._tensor)
            anchor = x_ref_full[0, 6:10]
            # Translation is exactly linear: the QP works relative to the measured position (small numbers,
            # so the solver's absolute tolerances are small against Z).
            origin = np.zeros(6)
            origin[0:3] = x[0:3]
            ref_t = x_ref_full[:, 0:6] - origin
            # The reference attitudes and the measured one in one call (row by row the same values).
            n_ref = x_ref_full.shape[0]
            quats = np.empty((n_ref + 1, 4))
            quats[:n_ref] = x_ref_full[:, 6:10]
            quats[n_ref] = x[6:10]
            phi = attitude_errors(anchor, quats)
            ref_r = np.empty((n_ref, 6))
            ref_r[:, 0:3] = phi[:-1]
            ref_r[:, 3:6] = x_ref_full[:, 10:13]
            x_r = np.empty(6)
            x_r[0:3] = phi[-1]
            x_r[3:6] = x[10:13]
            self.qp.set_parameters("translation", x_t - origin, ref_t, u_ref[:, 0:3])
            self.qp.set_parameters("attitude", x_r, ref_r, u_ref[:, 3:6])
            if self.workspace is not None:
                lin = None
                if self._plan_positions is not None and self._plan_t is not None:
                    lin = shifted_plan(self._plan_t, self.step_s, self._plan_positions, t + self._offsets)
                rows = self.workspace.rows(x_ref_full[:, 0:3], lin)
                self.qp.set_rows("translation", rows.shifted(origin[0:3]))
            sol = self.qp.solve(fast=self.fast)
            info = sol.info
            if info.success:
                self._failures = 0
                tr, at = sol.blocks["translation"], sol.blocks["attitude"]
                self._plan_t, self._plan_v, self._plan_tau = t, tr.v, at.v
                self._plan_positions = tr.z[:, 0:3] + origin[0:3]
                mode, z, v, tau = "mpc", tr.z[0] + origin, tr.v[0], at.v[0]
            else:
                self._failures += 1
                planned = self._plan_input(t)
                if planned is None or z_pred is None or self._failures >= self.max_failures:
                    self._hold_q = np.array(x[6:10])
                else:
                    mode, z = "fallback", z_pred
                    v, tau = planned[0], np.clip(planned[1], -self.limits.torque_Nm, self.limits.torque_Nm)
        else:
            info = SolveInfo("safe_hold", False, solve_time_s=0.0)
        if self._hold_q is not None:
            mode = "hold"
            z = z_pred if z_pred is not None else x_t
            planned = self._plan_input(t) if self.workspace is not None and z_pred is not None else None
            v = self._brake(z) if planned is None else planned[0]  # with rows: finish the certified plan first
            tau = self._hold_torque(x)
        anc = self._gain @ (x_t - z)
        u = np.empty(6)
        np.add(v, anc, out=u[0:3])
        u[3:6] = tau
        self._z_pred = self._a_c @ z + self._b_c @ v
        if self.observer is not None:
            self.observer.applied(u[0:3])
        if self.rate_observer is not None:
            self.rate_observer.applied(u[3:6])  # τ_des: the torque about the CoM once ĉ's moment is cancelled
        if self.rigid is not None:  # τ_cmd = τ_des + ĉ × R(q̃)ᵀ F (oacli.control.rigid_terms)
            u = self.rigid.command(u, x[6:10])
        status = info.status if mode == "mpc" else f"{mode} ({info.status})"
        step_info = SolveInfo(status, mode == "mpc", info.objective, info.iterations, info.solve_time_s,
                              time.perf_counter() - start)
        rec = self._rec
        z_pred_rec = np.full(6, np.nan) if z_pred is None else z_pred
        for key, value in (("t", t), ("mode", mode), ("z", z), ("v", v), ("anc", anc), ("tau", tau),
                           ("z_pred", z_pred_rec), ("tube", tube_margin),
                           ("lasso", self.design.error_margin(x_t - z)),
                           ("failed", attempted and not info.success), ("xhat", x_t)):
            rec[key].append(value)
        return ControlStep(u=u, info=step_info, x_reference=x_ref_full[0])

    def history(self) -> TubeHistory:
        """Everything recorded so far.

        Returns
        -------
        TubeHistory
        """
        rec = self._rec
        k = len(rec["t"])

        def arr(key: str, width: int) -> np.ndarray:
            return np.array(rec[key], dtype=float).reshape(k, width)

        return TubeHistory(
            t=np.array(rec["t"], dtype=float),
            mode=tuple(rec["mode"]),
            nominal_state=arr("z", 6),
            nominal_force=arr("v", 3),
            ancillary_force=arr("anc", 3),
            torque=arr("tau", 3),
            predicted_nominal=arr("z_pred", 6),
            tube_margin=np.array(rec["tube"], dtype=float),
            lasso_margin=np.array(rec["lasso"], dtype=float),
            solver_failed=np.array(rec["failed"], dtype=bool),
            estimate=arr("xhat", 6),
        )

