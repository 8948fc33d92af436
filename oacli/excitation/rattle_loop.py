"""RATTLE in closed loop: information-aware replanning, a sequential estimator and the simulated plant.

:class:`RattleController` implements the simulator's ``Controller`` protocol (:mod:`oacli.sim.simulator`). At each
control step it first feeds the estimator the new measurement (with the input held since the previous one); every
``replan_period_s`` it reads the estimate, sets the information weights by the decay rule
(:func:`oacli.excitation.rattle.information_weights`) and replans from the measured state with the estimate as the
model (warm-started with the previous plan shifted). Between replans it follows the plan: the planned input plus
an LQR correction of the error to the planned state (gain from the exact hover discretisation with the current
estimate, :func:`oacli.model.double_integrator.hover_error_model`), clipped to the limits. With a terminal phase
(:class:`oacli.excitation.rattle_terminal.TerminalPhase`) the last replan comes when its horizon ends ``hold`` before
the run's end; it informs nothing and plans to the goal at rest, which the loop then holds.

The plan keeps its angular rate within the planner's (margined) limit, but the feedback that corrects attitude
errors can push the rate past the robot's limit. With ``rate_limit_radps`` a rate governor bounds each body
torque so that the rate predicted at the end of the control period with the current estimate,
``ω_i + Δt (τ_i − (ω × I ω)_i) / I_i``, stays within the limit (:func:`rate_governed_torque`); under a held torque
the rate moves monotonically over the period (up to the gyroscopic term), so the end bounds the whole period.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from oacli.control.lqr import dlqr
from oacli.control.tracking import to_error_state
from oacli.excitation.oracle import OnlineEstimator
from oacli.excitation.rattle import InformationAwarePlanner, InformationWeighting, ReplanResult
from oacli.excitation.rattle_full import entry_estimate
from oacli.excitation.rattle_terminal import TerminalPhase
from oacli.model.double_integrator import hover_error_model
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.trajectory import sample_inputs, sample_states
from oacli.types import ControlStep, InertialParams, ParameterEstimate, SolveInfo, Telemetry, Trajectory


@dataclass(frozen=True)
class ReplanRecord:
    """One replan of the closed loop.

    Attributes
    ----------
    t : float
        Mission time [s].
    theta, std, gamma : ndarray, shape (4,)
        Estimate used as the model, its standard deviations, and the information weights set from them.
    plan : ReplanResult
    std_entries, gamma_entries : ndarray, shape (p,), optional
        With the planner's full information term (:mod:`oacli.excitation.rattle_full`): σ and γ of every informed
        entry of the full θ (mass and inertia first, as ``std`` and ``gamma``).
    """

    t: float
    theta: np.ndarray
    std: np.ndarray
    gamma: np.ndarray
    plan: ReplanResult
    std_entries: np.ndarray | None = None
    gamma_entries: np.ndarray | None = None


class RattleController:
    """Replanning information-aware controller (see the module docstring).

    Parameters
    ----------
    planner : InformationAwarePlanner
    estimator : OnlineEstimator
    weighting : InformationWeighting
    replan_period_s : float
        Time between replans [s] (12 s as flown).
    control_period_s : float
        Period of :meth:`step` [s] (for the feedback gain).
    feedback_q, feedback_r : ndarray, shape (12,), (6,)
        LQR weights on the error ``[r, v, φ, ω]`` and on ``[f, τ]``.
    input_limits : ndarray, shape (6,)
        Actuator limits the input is clipped to (the plan keeps its own, lower, design limits).
    rate_limit_radps : ndarray, shape (3,), optional
        Body-rate limit of the rate governor (:func:`rate_governed_torque`); none by default.
    terminal : TerminalPhase, optional
        RATTLE's terminal phase (:mod:`oacli.excitation.rattle_terminal`): a last replan with no information term
        that arrives at the goal at rest before the run ends; none by default (every replan informs).
    """

    def __init__(
        self,
        planner: InformationAwarePlanner,
        estimator: OnlineEstimator,
        weighting: InformationWeighting,
        *,
        replan_period_s: float,
        control_period_s: float,
        feedback_q: np.ndarray,
        feedback_r: np.ndarray,
        input_limits: np.ndarray,
        rate_limit_radps: np.ndarray | None = None,
        terminal: TerminalPhase | None = None,
    ) -> None:
        self.planner = planner
        self.terminal = terminal
        self.estimator = estimator
        self.weighting = weighting
        self.replan_period_s = float(replan_period_s)
        self.control_period_s = float(control_period_s)
        self.q = np.diag(feedback_q)
        self.r = np.diag(feedback_r)
        self.input_limits = np.asarray(input_limits, dtype=float)
        self.rate_limit = None if rate_limit_radps is None else np.asarray(rate_limit_radps, dtype=float)
        self.governed_steps = 0
        self.replans: list[ReplanRecord] = []
        self.estimates: list[ParameterEstimate] = []
        self._plan: Trajectory | None = None
        self._next_replan = 0.0
        self._u_prev: np.ndarray | None = None
        self._gain: np.ndarray | None = None

    def _replan(self, t: float, x: np.ndarray) -> None:
        est = self.estimator.estimate
        std = est.std
        term = self.planner.information_term
        theta_full = std_entries = None
        if term is not None:  # σ of the chosen entries: the filter's full estimate where it has one, else the prior
            filt = getattr(self.estimator, "filter", None)
            full = filt.full_estimate() if filt is not None and hasattr(filt, "full_estimate") else None
            theta_full, std_entries = entry_estimate(est.theta, std, term, full)
            gamma_entries = self.weighting.weights(std_entries)
            gamma = gamma_entries[0:4]
        else:
            gamma = self.weighting.weights(std)
        arrival = None
        if self.terminal is not None and self.terminal.is_terminal(t):  # the shut-off: no information, to rest
            arrival = self.terminal.arrival_step(t, self.planner.dt)
            gamma = np.zeros_like(gamma)
            if term is not None:
                gamma_entries = np.zeros_like(gamma_entries)
        warm = None
        if self._plan is not None:
            times = t + self.planner.dt * np.arange(self.planner.n)
            warm = sample_inputs(self._plan, times)
        if term is None:
            plan = self.planner.plan(x, est.theta, std, gamma, t0=t, u_warm=warm, arrival_step=arrival)
        else:
            assert std_entries is not None
            plan = self.planner.plan(x, est.theta, std_entries, gamma_entries, t0=t, u_warm=warm,
                                     theta_full=theta_full, arrival_step=arrival)
        self._plan = plan.trajectory
        params = InertialParams(est.theta[0], est.theta[1:4])
        a, b = hover_error_model(params, self.control_period_s)
        self._gain, _ = dlqr(a, b, self.q, self.r)
        if term is None:
            self.replans.append(ReplanRecord(t, est.theta.copy(), std.copy(), gamma, plan))
        else:
            self.replans.append(ReplanRecord(t, est.theta.copy(), std.copy(), gamma, plan, std_entries,
                                             gamma_entries))
        self._next_replan = t + self.replan_period_s
        if self.terminal is not None:  # none after the terminal replan; the terminal one not after its time
            self._next_replan = (np.inf if arrival is not None
                                 else self.terminal.next_replan(t, self.replan_period_s))

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """Input for ``[t, t + control period)`` (simulator ``Controller`` protocol).

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state.

        Returns
        -------
        ControlStep
        """
        start = time.perf_counter()
        if self._u_prev is not None:
            self.estimates.append(self.estimator.update(t, x_measured, self._u_prev))
        solve_time = float("nan")
        if t >= self._next_replan - 1e-9:
            self._replan(t, x_measured)
            solve_time = self.replans[-1].plan.solve_time_s
        assert self._plan is not None and self._gain is not None
        x_ref = sample_states(self._plan, np.array([t]))[0]
        u_ff = sample_inputs(self._plan, np.array([t]))[0]
        err = to_error_state(x_measured, x_ref[0:3], x_ref[6:10])
        err[3:6] -= x_ref[3:6]
        err[9:12] -= x_ref[10:13]
        u = np.clip(u_ff + self._gain @ err, -self.input_limits, self.input_limits)
        if self.rate_limit is not None:
            theta = self.replans[-1].theta
            tau = rate_governed_torque(u[3:6], x_measured[10:13], theta[1:4], self.control_period_s,
                                       self.rate_limit, self.input_limits[3:6])
            self.governed_steps += int(np.any(tau != u[3:6]))
            u[3:6] = tau
        self._u_prev = u
        info = SolveInfo("optimal", True, solve_time_s=solve_time, step_time_s=time.perf_counter() - start)
        return ControlStep(u, info, x_ref)


def rate_governed_torque(
    torque_Nm: np.ndarray,
    omega_radps: np.ndarray,
    inertia_kgm2: np.ndarray,
    dt_s: float,
    rate_limit_radps: np.ndarray,
    torque_limit_Nm: np.ndarray,
) -> np.ndarray:
    """The torque nearest to ``torque_Nm`` (per body axis) whose predicted rate after ``dt_s`` is within the limit.

    Euler's equation ([Doerr2021] Eq. 35b) over one held step predicts ``ω_i⁺ = ω_i + Δt (τ_i − g_i) / I_i`` with the
    gyroscopic term ``g = ω × I ω``; ``|ω_i⁺| ≤ ω_max,i`` is the interval
    ``τ_i ∈ [g_i + I_i (−ω_max,i − ω_i)/Δt, g_i + I_i (ω_max,i − ω_i)/Δt]``. The torque is clipped to that interval
    intersected with the actuator limits; when the two do not meet (the rate is already too high to be brought
    back in one step) the actuator limit nearest to the interval is used (full braking).

    Parameters
    ----------
    torque_Nm : ndarray, shape (3,)
        Torque asked for [N·m], body frame.
    omega_radps : ndarray, shape (3,)
        Current body rate [rad/s].
    inertia_kgm2 : ndarray, shape (3,)
        Principal inertias [kg·m²].
    dt_s : float
        Hold time of the torque [s].
    rate_limit_radps, torque_limit_Nm : ndarray, shape (3,)
        Per-axis rate [rad/s] and actuator torque [N·m] limits.

    Returns
    -------
    ndarray, shape (3,)
    """
    tau = np.asarray(torque_Nm, dtype=float)
    w = np.asarray(omega_radps, dtype=float)
    inertia = np.asarray(inertia_kgm2, dtype=float)
    gyro = np.cross(w, inertia * w)
    w_max = np.asarray(rate_limit_radps, dtype=float)
    t_max = np.asarray(torque_limit_Nm, dtype=float)
    lo = gyro + inertia * (-w_max - w) / dt_s
    hi = gyro + inertia * (w_max - w) / dt_s
    lo_c, hi_c = np.maximum(lo, -t_max), np.minimum(hi, t_max)
    out = np.clip(tau, lo_c, hi_c)
    empty = lo_c > hi_c
    out[empty] = np.where(lo[empty] > t_max[empty], t_max[empty], -t_max[empty])
    return out


@dataclass(frozen=True)
class RattleRun:
    """A closed-loop RATTLE run.

    Attributes
    ----------
    telemetry : Telemetry
    replans : tuple of ReplanRecord
    estimates : tuple of ParameterEstimate
        The estimator's output after each measurement.
    governed_steps : int
        Control steps whose torque the rate governor changed.
    """

    telemetry: Telemetry
    replans: tuple[ReplanRecord, ...]
    estimates: tuple[ParameterEstimate, ...]
    governed_steps: int = 0

    @property
    def final_estimate(self) -> ParameterEstimate:
        """The last estimate."""
        return self.estimates[-1]


def run_rattle(
    planner: InformationAwarePlanner,
    estimator: OnlineEstimator,
    weighting: InformationWeighting,
    x0: np.ndarray,
    truth: InertialParams,
    *,
    duration_s: float,
    replan_period_s: float,
    control_period_s: float,
    plant_period_s: float,
    input_limits: np.ndarray,
    feedback_q: np.ndarray,
    feedback_r: np.ndarray,
    sensors: SensorNoise,
    disturbance: Disturbance,
    rng: np.random.Generator,
    progress: Callable[[float], None] | None = None,
    rate_limit_radps: np.ndarray | None = None,
    actuator_scale: np.ndarray | None = None,
    com_offset_m: np.ndarray | None = None,
    on_step: Callable[..., None] | None = None,
    terminal_hold_s: float | None = None,
) -> RattleRun:
    """Simulate RATTLE in closed loop from ``x0`` for ``duration_s`` (see :class:`RattleController`).

    ``input_limits`` are the actuator's (the feedback may use what the plan leaves of them); ``rate_limit_radps``
    turns the rate governor on.

    Parameters
    ----------
    planner, estimator, weighting
        As in :class:`RattleController`.
    x0 : ndarray, shape (13,)
        Initial state.
    truth : InertialParams
        The simulated plant.
    duration_s : float
    replan_period_s, control_period_s : float
        As in :class:`RattleController`.
    plant_period_s : float
        Integration step of the plant [s].
    input_limits : ndarray, shape (6,)
    feedback_q, feedback_r : ndarray
        As in :class:`RattleController`.
    sensors : SensorNoise
    disturbance : Disturbance
    rng : numpy.random.Generator
    progress : callable, optional
        Called with the fraction done.
    rate_limit_radps : ndarray, shape (3,), optional
        Body-rate limit of the rate governor [rad/s]; no governor when omitted.
    actuator_scale, com_offset_m : ndarray, optional
        The plant's unmodelled actuator scale error and centre-of-mass offset (:func:`oacli.sim.simulator.simulate`).
    on_step : callable, optional
        Called after each control step with what the step produced (passed to :func:`oacli.sim.simulator.simulate`,
        whose docstring lists the arguments; ``x_reference`` is the plan's state at the step), e.g. to journal
        the loop as it runs.
    terminal_hold_s : float, optional
        Turns RATTLE's terminal phase on (:class:`oacli.excitation.rattle_terminal.TerminalPhase`): the plan
        arrives at the goal at rest this long [s] before the run ends (at ``duration_s``); off when omitted.

    Returns
    -------
    RattleRun
        Telemetry, replans and estimates.
    """
    controller = RattleController(
        planner, estimator, weighting, replan_period_s=replan_period_s, control_period_s=control_period_s,
        feedback_q=feedback_q, feedback_r=feedback_r, input_limits=input_limits, rate_limit_radps=rate_limit_radps,
        terminal=None if terminal_hold_s is None else TerminalPhase(duration_s, terminal_hold_s,
                                                                    planner.n * planner.dt),
    )
    tel = simulate(
        controller, x0, truth, duration_s=duration_s, control_period_s=control_period_s,
        plant_period_s=plant_period_s, input_limits=input_limits, sensors=sensors, disturbance=disturbance,
        rng=rng, progress=progress, actuator_scale=actuator_scale, com_offset_m=com_offset_m, on_step=on_step,
    )
    return RattleRun(tel, tuple(controller.replans), tuple(controller.estimates), controller.governed_steps)
