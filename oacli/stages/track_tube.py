"""The ``track`` stage with ``controller: tube``: the controller from the config, its records and its summary.

Split from :mod:`oacli.stages.track` so that the stage runner reads as one flow; everything here is specific to
robust tube MPC (Mayne, Seron & Raković 2005; Raković et al. 2005; [Doerr2021] Eqs. 15-28). The tube's
design from the config is :func:`oacli.stages.settings.tube_design_from_config`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import special, stats

from oacli.config import OacliConfig
from oacli.control.observer import RateObserver, TranslationObserver, observer_for
from oacli.control.rigid_terms import RigidCompensator
from oacli.control.tracking import StateEstimate, TrackingWeights
from oacli.control.tube_design import TubeDesign
from oacli.control.tube_monitor import TubeMonitor, half_widths
from oacli.control.tube_mpc import TerminalWeights, TubeHistory, TubeMPC
from oacli.geometry.collision import RobotBody
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.rerun.tube import log_disturbance_layers, log_tube_layers
from oacli.io.rerun.writer import StageRecording
from oacli.model.limits import MotionLimits
from oacli.model.robot_model import RobotModel
from oacli.stages.settings import robot_model, tube_design_from_config
from oacli.status import StatusReport
from oacli.types import Telemetry, Trajectory

LogEntry = tuple[float, str, str]


# ----------------------------------------------------------------------------------------------------------------
# Robust tube MPC (controller.type: tube)
# ----------------------------------------------------------------------------------------------------------------

#: A measured error counts as outside Z only beyond this fraction of Z's largest offset (rounding, solver tolerance).
TUBE_TOLERANCE_REL = 1e-6


def tube_controller_from_config(
    cfg: OacliConfig, reference: Trajectory, design: TubeDesign, weights: TrackingWeights, limits: MotionLimits,
    *, model: RobotModel | None = None, observer: TranslationObserver | None = None,
    rate_observer: RateObserver | None = None,
) -> TubeMPC:
    """The :class:`TubeMPC` of ``cfg`` around ``design`` (mass: the design's; inertia: ``model``'s, default
    :func:`~oacli.stages.settings.robot_model`); with an output-feedback design it acts on ``observer``'s estimate
    (a new one when omitted)."""
    model = robot_model(cfg) if model is None else model
    tube = cfg.controller.tube
    terminal = None
    if tube.terminal is not None:
        terminal = TerminalWeights(np.asarray(tube.terminal.position), np.asarray(tube.terminal.velocity))
    step = tube.prediction_step_s if tube.prediction_step_s is not None else cfg.controller.period_s
    if observer is None and design.output_feedback:
        observer = observer_for(design)
    if rate_observer is None:
        rate_observer = rate_observer_for(cfg, model)
    force_limit = np.array([ax.force_limit_N for ax in design.axes])
    return TubeMPC(
        reference, design, inertia_kgm2=model.inertia_kgm2, horizon=cfg.controller.horizon, prediction_step_s=step,
        weights=weights, limits=limits, terminal=terminal,
        max_consecutive_failures=cfg.controller.max_consecutive_failures, fast=tube.solver == "direct",
        observer=observer, initial_weight=tube.initial_weight, rate_observer=rate_observer,
        rigid=RigidCompensator.of_model(model, force_limit, limits.torque_Nm), **workspace_arguments(cfg),
    )


def rate_observer_for(cfg: OacliConfig, model: RobotModel) -> RateObserver | None:
    """The body-rate observer of ``controller.tube.observer.rate_gain`` (None when unset)."""
    gain = cfg.controller.tube.observer.rate_gain
    if gain is None:
        return None
    tensor = model.inertia_tensor_kgm2 if np.any(model.inertia_products_kgm2 != 0) else None
    return RateObserver(np.asarray(model.inertia_kgm2), gain, cfg.controller.period_s, tensor)


def workspace_arguments(cfg: OacliConfig) -> dict[str, Any]:
    """``scene`` and ``robot`` for the controllers when ``controller.position_constraints`` is on, else none.

    Parameters
    ----------
    cfg : OacliConfig

    Returns
    -------
    dict
        Keyword arguments for :class:`~oacli.control.tracking.TrackingMPC` and
        :class:`~oacli.control.tube_mpc.TubeMPC`.
    """
    if not cfg.controller.position_constraints:
        return {}
    return {"scene": cfg.scene(), "robot": RobotBody.sphere(robot_model(cfg).radius_m),
            "keep_in_margin_m": cfg.environment.keep_in_margin_m}


def state_estimate(cfg: OacliConfig) -> StateEstimate:
    """The standard MPC's state estimate and its rows' margin (``controller.estimate``, ``sensors``' σ).

    Parameters
    ----------
    cfg : OacliConfig

    Returns
    -------
    StateEstimate
    """
    est, s = cfg.controller.estimate, cfg.sensors
    return StateEstimate(s.position_std_m, s.velocity_std_mps,
                         est.accel_std_mps2 if est.observer else None, est.margin_sigmas, est.min_margin_m)


def standard_mpc_arguments(cfg: OacliConfig) -> dict[str, Any]:
    """:func:`workspace_arguments` and the :func:`state_estimate` for :class:`~oacli.control.tracking.TrackingMPC`.

    Parameters
    ----------
    cfg : OacliConfig

    Returns
    -------
    dict
    """
    return {**workspace_arguments(cfg), "estimate": state_estimate(cfg)}


#: Term budget of the invariant set when the tube is redesigned beyond W during a run (bounds its time).
REDESIGN_MAX_TERMS = 200
#: A redesign grows W to (1 + margin) × the largest measured |w| per axis and component.
REDESIGN_MARGIN = 0.5
#: Redesigns allowed in one run; a further violation latches the safe hold.
MAX_REDESIGNS = 3


def monitored_tube_controller(
    cfg: OacliConfig, reference: Trajectory, design: TubeDesign, weights: TrackingWeights, limits: MotionLimits,
    *, model: RobotModel | None = None,
) -> TubeMonitor:
    """The tube controller of ``cfg`` with the beyond-W check and response of ``controller.tube.beyond_w``.

    ``model`` (default :func:`~oacli.stages.settings.robot_model`) is the one ``design`` was made with
    (:func:`~oacli.stages.settings.tube_design_from_config`); a redesign beyond W uses it too.
    """
    model = robot_model(cfg) if model is None else model
    observer, rates = observer_for(design), rate_observer_for(cfg, model)  # one estimate across redesigns
    return TubeMonitor(
        lambda d: tube_controller_from_config(cfg, reference, d, weights, limits, model=model, observer=observer,
                                              rate_observer=rates),
        design,
        response=cfg.controller.tube.beyond_w, actuator_force_limit_N=np.asarray(model.force_limit_N),
        redesign=lambda extra: tube_design_from_config(cfg, extra_box=extra, max_terms=REDESIGN_MAX_TERMS,
                                                       model=model),
        margin=REDESIGN_MARGIN, max_redesigns=MAX_REDESIGNS, noise_allowance=noise_boxes(cfg)[0],
    )


def noise_boxes(cfg: OacliConfig) -> tuple[np.ndarray, np.ndarray]:
    """The sensor noise the tube checks tolerate (``controller.tube.monitor_noise_sigmas`` = k; ``sensors``' σ).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    w_box : ndarray, shape (3, 2)
        On the measured one-step disturbance ``w = x̃⁺ − A x̃ − B u`` ([Doerr2021] Eq. 15), which carries
        ``n⁺ − A n``: position ``k (2σ_p + dt σ_v)``, velocity ``2 k σ_v`` per axis.
    state_box : ndarray, shape (3, 2)
        On the measured state: ``[k σ_p, k σ_v]`` per axis.
    """
    k = cfg.controller.tube.monitor_noise_sigmas
    sp, sv, dt = cfg.sensors.position_std_m, cfg.sensors.velocity_std_mps, cfg.controller.period_s
    w_box = np.tile([k * (2 * sp + dt * sv), 2 * k * sv], (3, 1))
    return w_box, np.tile([k * sp, k * sv], (3, 1))


def _true_at_control(tel: Telemetry) -> np.ndarray:
    """True translational state ``[r, v]`` (K, 6) at the control instants (recorded by the simulator; else linear
    between plant samples, 16 ms apart)."""
    if tel.x_true_ctrl is not None:
        return np.asarray(tel.x_true_ctrl[:, 0:6])
    return np.column_stack([np.interp(tel.t_ctrl, tel.t_true, tel.x_true[:, j]) for j in range(6)])


def tube_exits(design: TubeDesign, states: np.ndarray, predicted: np.ndarray, tolerance: float,
               state_box: np.ndarray | None = None) -> int:
    """Steps whose state left the promised tube ``ẑ_k ⊕ Z`` (``ẑ_k ⊕ T`` with an observer; grown by ``state_box``
    for measurement noise).

    Parameters
    ----------
    design : TubeDesign
        Its lasso ``Z = {e: H e <= h}``.
    states : ndarray, shape (K, 6)
        ``[r, v]`` per control step.
    predicted : ndarray, shape (K, 6)
        ``ẑ_k`` (NaN where none).
    tolerance : float
        Slack below zero still counted inside.
    state_box : ndarray, shape (3, 2), optional
        ``[position, velocity]`` half-widths per axis added to Z (support ``|H| d``).

    Returns
    -------
    int
    """
    h_matrix, h_vector = design.promise.h_matrix, design.promise.h_vector
    grow = 0.0 if state_box is None else np.abs(h_matrix) @ np.concatenate([state_box[:, 0], state_box[:, 1]])
    ok_rows = np.all(np.isfinite(predicted), axis=1)
    errors = states[ok_rows] - predicted[ok_rows]
    slack = (h_vector + grow)[None, :] - errors @ h_matrix.T
    return int(np.sum(slack.min(axis=1) < -tolerance))


def describe_tube_design(design: TubeDesign) -> list[LogEntry]:
    out: list[LogEntry] = []
    for ax in design.axes:
        wp, wv = ax.disturbance.half_widths
        out.append((0.0, "info",
                    f"tube {ax.name}: W ±{wp:.3g} m, ±{wv:.3g} m/s per {design.dt_s:g} s; K = "
                    f"[{ax.gain[0, 0]:.4g}, {ax.gain[0, 1]:.4g}]; Z: s = {ax.rpi.s}, alpha = {ax.rpi.alpha:.4g}, "
                    f"{ax.reduction.facets_before} -> {ax.reduction.facets_after} facets (+{ax.reduction.growth:.1%});"
                    f" nominal force within ±{ax.force_bounds_N[1]:.4g} N, velocity ±{ax.velocity_bounds_mps[1]:.4g}"
                    " m/s"))
        if ax.disturbance.scale != 1.0:
            out.append((0.0, "warning",
                        f"tube {ax.name}: W scaled by {ax.disturbance.scale:.4g} (on_empty_tightening: scale_w): "
                        "the tube guarantee covers only the scaled disturbance set"))
    return out


def _axis_lists(values: np.ndarray) -> dict[str, list[float]]:
    """``(3, 2)`` half-widths as ``{w_position_m: [x, y, z], w_velocity_mps: [x, y, z]}``."""
    v = np.asarray(values, dtype=float)
    return {"w_position_m": [float(a) for a in v[:, 0]], "w_velocity_mps": [float(a) for a in v[:, 1]]}


def beyond_w_summary(monitor: TubeMonitor) -> dict[str, Any]:
    """The ``beyond_w`` entry of the summary: how often the realised disturbance left W, and the responses."""
    rec = monitor.disturbance_record()
    measured = np.isfinite(rec.margin)
    first = float(rec.t[np.argmax(rec.violated)]) if rec.violated.any() else None
    ratio = np.abs(rec.w) / np.where(rec.w_half_widths > 0, rec.w_half_widths, np.nan)
    worst = float(np.nanmax(ratio)) if measured.any() else None
    return {
        "policy": monitor.response,
        "checked_steps": int(measured.sum()),
        "violations": int(rec.violated.sum()),
        "first_violation_s": first,
        "max_over_w": worst,
        "measured_max": _axis_lists(np.nanmax(np.abs(rec.w), axis=0) if measured.any() else np.zeros((3, 2))),
        "redesigns": monitor.redesigns,
        "held": monitor.held,
        "responses": [{"t": e.t, "response": e.response, "reason": e.reason,
                       "redesign_time_s": e.redesign_time_s, "measured_max": _axis_lists(e.measured_max),
                       "w_before": _axis_lists(e.w_before),
                       "w_after": _axis_lists(e.w_after)} for e in monitor.events],
        "final_w": _axis_lists(half_widths(monitor.design)),
    }


def describe_beyond_w(monitor: TubeMonitor) -> list[LogEntry]:
    """Log lines of the beyond-W responses."""
    out: list[LogEntry] = []
    for e in monitor.events:
        after = ", ".join(f"{ax} ±{p:.3g} m ±{v:.3g} m/s" for ax, (p, v) in zip("xyz", e.w_after, strict=True))
        timing = "" if e.redesign_time_s is None else f" in {e.redesign_time_s:.3f} s"
        out.append((e.t, "warning", f"beyond W at t = {e.t:.2f} s: {e.response} ({e.reason}){timing}; W now {after}"))
    return out


def tube_summary(monitor: TubeMonitor, history: TubeHistory, tel: Telemetry, cfg: OacliConfig) -> dict[str, Any]:
    """Summary entries of a tube run: violations, beyond-W responses, RPI figures, tightened bounds.

    ``tube_violations`` counts control steps whose measured state left the tube promised at the previous step,
    ``x̃_k − ẑ_k ∉ Z`` with ``ẑ_k = A z_{k−1} + B v_{k−1}`` (beyond ``TUBE_TOLERANCE_REL`` of Z's size): the
    invariance guarantee, which can only fail when a disturbance left W. ``w_violations`` counts steps whose
    measured one-step disturbance left W (``beyond_w`` has the details and the responses).
    With ``controller.tube.monitor_noise_sigmas`` = k > 0 the measured state counts as outside only beyond
    ``Z ⊕ [kσ_p, kσ_v]`` (:func:`noise_boxes`). ``tube_violations_true`` counts the steps whose *true* state (known
    in simulation) left ``ẑ_k ⊕ Z`` exactly: the guarantee itself. ``tube.lasso_violations`` counts steps with
    ``x̃_k − z_k ∉ Z`` for the nominal state actually used (a
    constraint of the QP). ``solver_failures`` counts failed solves. The design figures are the initial design's;
    ``beyond_w.final_w`` is W after any redesign, ``tube.final_design`` its figures.
    """
    design = monitor.designs[0][1]
    tol = TUBE_TOLERANCE_REL * float(np.max(design.lasso.h_vector))
    tube_margin = history.tube_margin
    checked = np.isfinite(tube_margin)
    force_limit = np.array([ax.force_limit_N for ax in design.axes])
    over_u = np.abs(tel.u_command[:, 0:3]) > force_limit * (1 + TUBE_TOLERANCE_REL)
    details = design.summary()
    details.update({
        "tube_checked_steps": int(checked.sum()),
        "min_tube_margin": float(np.min(tube_margin[checked])) if checked.any() else None,
        "lasso_violations": int(np.sum(history.lasso_margin < -tol)),
        "force_limit_violations": int(np.any(over_u, axis=1).sum()),
        "force_limit_N": force_limit.tolist(),
        "prediction_step_s": cfg.controller.tube.prediction_step_s or cfg.controller.period_s,
        "solver_path": cfg.controller.tube.solver,
        "designs": len(monitor.designs),
    })
    if monitor.redesigns:
        final = monitor.design.summary()
        details["final_design"] = {k: final[k] for k in ("rpi", "w_position_m", "w_velocity_mps",
                                                         "tightened_force_N", "tightened_velocity_mps")}
    beyond = beyond_w_summary(monitor)
    designs = [d for _, d in monitor.designs]
    index = monitor.disturbance_record().design_index
    _, state_box = noise_boxes(cfg)
    measured = np.column_stack([tel.x_measured[:, 0:3], tel.x_measured[:, 3:6]])
    true = _true_at_control(tel)
    k_noise = cfg.controller.tube.monitor_noise_sigmas
    if design.output_feedback:  # the measured state is x + n: inside ẑ ⊕ T ⊕ N
        k_noise = cfg.controller.tube.observer.noise_sigmas
        state_box = np.tile([k_noise * cfg.sensors.position_std_m, k_noise * cfg.sensors.velocity_std_mps], (3, 1))
    exits_measured = (int(np.sum(tube_margin[checked] < -tol)) if k_noise == 0
                      else tube_exits_in_force(designs, index, measured, history.predicted_nominal, state_box))
    details["monitor_noise_sigmas"] = cfg.controller.tube.monitor_noise_sigmas
    details["designs_in_force"] = [int(np.sum(index == i)) for i in range(len(designs))]
    details.update(noise_events(cfg, measured, true, designs, index, history))
    return {
        "tube_violations": exits_measured,
        "tube_violations_true": tube_exits_in_force(designs, index, true, history.predicted_nominal),
        "w_violations": beyond["violations"],
        "rpi": {k: details["rpi"][k] for k in ("s", "alpha", "facets")},
        "tightened_force_N": details["tightened_force_N"],
        "tightened_velocity_mps": details["tightened_velocity_mps"],
        "solver_failures": int(history.solver_failed.sum()),
        "beyond_w": beyond,
        "tube": details,
    }


def tube_exits_in_force(designs: list[TubeDesign], index: np.ndarray, states: np.ndarray, predicted: np.ndarray,
                        state_box: np.ndarray | None = None) -> int:
    """:func:`tube_exits` with, at each step, the promise of the design in force (``index``: per step, into
    ``designs``; after a redesign beyond W the new tube is the promise).

    Parameters
    ----------
    designs : list of TubeDesign
    index : ndarray of int, shape (K,)
    states, predicted : ndarray, shape (K, 6)
    state_box : ndarray, shape (3, 2), optional

    Returns
    -------
    int
    """
    total = 0
    for i, design in enumerate(designs):
        rows = np.asarray(index) == i
        if rows.any():
            tol = TUBE_TOLERANCE_REL * float(np.max(design.promise.h_vector))
            total += tube_exits(design, states[rows], predicted[rows], tol, state_box)
    return total


def noise_events(cfg: OacliConfig, measured: np.ndarray, true: np.ndarray, designs: list[TubeDesign],
                 index: np.ndarray, history: TubeHistory) -> dict[str, Any]:
    """The sensor noise against the bound the promise assumes (``k`` σ: ``controller.tube.observer.noise_sigmas``
    with an observer, else ``monitor_noise_sigmas``), and the estimate against the error set S.

    ``noise_beyond_bound`` counts control steps with a translational noise component beyond ``k σ``;
    ``noise_beyond_expected`` is what the Gaussian tail predicts, ``K (1 − erf(k/√2)⁶)``, and
    ``noise_beyond_limit`` its Poisson 99.9 % quantile (more: the sensor is noisier than configured).
    ``error_set_exits`` counts steps whose estimation error ``x − x̂`` left S (output feedback only).
    """
    tube = cfg.controller.tube
    k = tube.observer.noise_sigmas if tube.observer.enabled else tube.monitor_noise_sigmas
    out: dict[str, Any] = {"noise_sigmas": k}
    if k > 0 and cfg.sensors.position_std_m > 0 and cfg.sensors.velocity_std_mps > 0:
        sigma = np.repeat([cfg.sensors.position_std_m, cfg.sensors.velocity_std_mps], 3)
        beyond = np.any(np.abs(measured - true) > k * sigma, axis=1)
        expected = len(beyond) * (1.0 - special.erf(k / np.sqrt(2.0)) ** 6)
        out.update({"noise_beyond_bound": int(beyond.sum()), "noise_beyond_expected": float(expected),
                    "noise_beyond_limit": int(stats.poisson.ppf(0.999, expected))})
    if designs[0].output_feedback:
        exits = 0
        for i, design in enumerate(designs):
            rows = np.asarray(index) == i
            for j, ax in enumerate(design.axes):
                if ax.output is not None and rows.any():
                    err = (true - history.estimate)[rows][:, [j, j + 3]]
                    s = ax.output.s
                    tol = TUBE_TOLERANCE_REL * float(np.max(s.b))
                    exits += int(np.sum(np.min(s.b[None, :] - err @ s.a.T, axis=1) < -tol))
        out["error_set_exits"] = exits
        out["rms_estimation_error_m"] = float(np.sqrt(np.mean(np.sum((true - history.estimate)[:, 0:3] ** 2,
                                                                     axis=1))))
    return out


def add_tube_reasons(report: StatusReport, summary: dict[str, Any]) -> None:
    """Findings of a tube run: the tube assumption (disturbance in W, state in the promised tube) broken."""
    beyond = summary["beyond_w"]
    if beyond["violations"]:
        responses = beyond["responses"]
        what = "; ".join(f"{r['response']} at t = {r['t']:.2f} s" for r in responses) or "no response"
        final = beyond["final_w"]
        new_w = ""
        if beyond["redesigns"]:
            new_w = (f", W now ±{max(final['w_position_m']):.3g} m, ±{max(final['w_velocity_mps']):.3g} m/s "
                     "(largest axis)")
        report.degraded("beyond_w", f"the realised disturbance left W on {beyond['violations']} of "
                                    f"{beyond['checked_steps']} steps (first at t = {beyond['first_violation_s']:.2f} "
                                    f"s, up to {beyond['max_over_w']:.3g} × W); response: {what}{new_w}")
    tube = summary["tube"]
    scales = tube.get("w_scale") or []
    if any(s < 1.0 for s in scales):
        shrunk = ", ".join(f"{axis} to {s:.3g}" for axis, s in zip("xyz", scales, strict=False) if s < 1.0)
        report.degraded("w_scaled", f"W was shrunk below what the model's uncertainty says ({shrunk} of it; "
                                    "controller.tube.disturbance.on_empty_tightening: scale_w): the tube guarantees "
                                    "the smaller W only")
    if tube.get("noise_beyond_bound", 0) > tube.get("noise_beyond_limit", np.inf):
        report.degraded("noise", f"the sensor noise exceeded {tube['noise_sigmas']:g} σ on {tube['noise_beyond_bound']}"
                                 f" steps, more than the Gaussian tail allows ({tube['noise_beyond_expected']:.2g} "
                                 "expected): the sensor is noisier than the tube's promise assumes")
    if summary["tube_violations"]:
        report.degraded("tube", f"the measured state left the promised tube on {summary['tube_violations']} steps")
    if summary.get("tube_violations_true"):
        report.degraded("tube_true", f"the true state left the promised tube on {summary['tube_violations_true']} "
                                     "steps")
    lasso = summary["tube"]["lasso_violations"]
    if lasso:
        report.degraded("lasso", f"the nominal state's lasso x - z in Z was violated on {lasso} steps")


def write_tube_topics(writer: StageMcapWriter, tel: Telemetry, monitor: TubeMonitor, history: TubeHistory) -> None:
    """Write the tube controller's topics (``/control/nominal``, ``/control/ancillary``, ``/state/nominal``,
    ``/tube/design``, ``/tube/disturbance``; ``docs/mcap.md``) to the track MCAP.

    Parameters
    ----------
    writer : StageMcapWriter
        The open writer.
    tel : Telemetry
        The run.
    monitor : TubeMonitor
        The tube controller after the run.
    history : TubeHistory
        What it did at each step.
    """
    k = len(tel.t_ctrl)
    zeros = np.zeros((k, 3))
    writer.write_wrenches(ms.TOPIC_CONTROL_NOMINAL, tel.t_ctrl, np.hstack([history.nominal_force, history.torque]))
    writer.write_wrenches(ms.TOPIC_CONTROL_ANCILLARY, tel.t_ctrl, np.hstack([history.ancillary_force, zeros]))
    nominal = tel.x_measured.copy()  # attitude columns: measured (attitude runs standard MPC, no tube)
    nominal[:, 0:6] = history.nominal_state
    writer.write_states(ms.TOPIC_STATE_NOMINAL, tel.t_ctrl, nominal,
                        np.hstack([history.nominal_force, history.torque]), name="nominal")
    for index, (t_design, design) in enumerate(monitor.designs):
        axes = []
        for ax in design.axes:
            axes.append({
                "name": ax.name, "z_normals": ax.z.a, "z_offsets": ax.z.b, "promise_normals": ax.promise.a,
                "promise_offsets": ax.promise.b, "w_vertices": ax.disturbance.w.vertices,
                "gain": ax.gain[0], "s": ax.rpi.s, "alpha": ax.rpi.alpha, "epsilon": ax.rpi.epsilon,
                "facets_before_reduction": ax.reduction.facets_before, "w_scale": ax.disturbance.scale,
                "force_bounds_N": ax.force_bounds_N, "velocity_bounds_mps": ax.velocity_bounds_mps,
                "force_limit_N": ax.force_limit_N, "velocity_limit_mps": ax.velocity_limit_mps,
            })
        writer.write_json(ms.TOPIC_TUBE_DESIGN, ms.TUBE_DESIGN, ms.TUBE_DESIGN_SCHEMA, t_design,
                          {"dt_s": design.dt_s, "design": index, "axes": axes})
    rec = monitor.disturbance_record()
    extent = np.array([d.position_extent() for _, d in monitor.designs])[rec.design_index]  # (K, 3, 2) [m]
    writer.write_tube_sections(history.t, history.nominal_state[:, 0:3], extent)
    # Plain Python values, converted once for the whole record (write_json would convert each step's arrays).
    w_pos, w_vel = rec.w[:, :, 0].tolist(), rec.w[:, :, 1].tolist()
    half_pos, half_vel = rec.w_half_widths[:, :, 0].tolist(), rec.w_half_widths[:, :, 1].tolist()
    margin, violated, design_index = rec.margin.tolist(), rec.violated.tolist(), rec.design_index.tolist()
    for i, t_i in enumerate(rec.t.tolist()):
        writer.write_json(ms.TOPIC_TUBE_DISTURBANCE, ms.TUBE_DISTURBANCE, ms.TUBE_DISTURBANCE_SCHEMA, t_i, {
            "w_position_m": w_pos[i], "w_velocity_mps": w_vel[i], "w_half_position_m": half_pos[i],
            "w_half_velocity_mps": half_vel[i], "margin": margin[i], "violation": bool(violated[i]),
            "design": int(design_index[i]),
        })


def tube_layers(monitor: TubeMonitor, history: TubeHistory) -> Callable[[StageRecording], None]:
    """The tube layers of the track recording (:mod:`oacli.io.rerun.tube`), as its ``extra`` callback.

    Parameters
    ----------
    monitor : TubeMonitor
        The tube controller after the run (its designs and the disturbance record).
    history : TubeHistory
        What it did at each step.

    Returns
    -------
    callable
        Logs the tube and the disturbance layers into a :class:`~oacli.io.rerun.writer.StageRecording`.
    """
    designs = [d for _, d in monitor.designs]
    record = monitor.disturbance_record()

    def extra(rec: StageRecording) -> None:
        log_tube_layers(rec, history, designs, record.design_index)
        log_disturbance_layers(rec, record)

    return extra
