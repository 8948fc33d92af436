"""The ``track`` stage with ``controller: tube``: the tube design from the config, its records and its summary.

Split from :mod:`oacli.stages.track` so that the stage runner reads as one flow; everything here is specific to
robust tube MPC (Mayne, Seron & Raković 2005; Raković et al. 2005; Doerr et al. 2021 Eqs. 15-28).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.tracking import TrackingLimits, TrackingWeights
from oacli.control.tube_design import AncillaryWeights, TubeDesign, design_translation_tube
from oacli.control.tube_monitor import TubeMonitor, half_widths
from oacli.control.tube_mpc import TerminalWeights, TubeHistory, TubeMPC
from oacli.geometry.collision import RobotBody
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.rerun_tube import log_disturbance_layers, log_tube_layers
from oacli.status import StatusReport
from oacli.types import Telemetry, Trajectory

LogEntry = tuple[float, str, str]


# ----------------------------------------------------------------------------------------------------------------
# Robust tube MPC (controller.type: tube)
# ----------------------------------------------------------------------------------------------------------------

#: A measured error counts as outside Z only beyond this fraction of Z's largest offset (rounding, solver tolerance).
TUBE_TOLERANCE_REL = 1e-6

TUBE_DESIGN_SCHEMA = {
    "title": "oacli.TubeDesign",
    "description": "Robust tube MPC design per world axis x, y, z (Mayne et al. 2005; Raković et al. 2005); one "
    "record per design, at the time it took over.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "mission time [s]"},
        "dt_s": {"type": "number", "description": "control period, the step of W and of the ancillary law [s]"},
        "design": {"type": "integer", "description": "0: the initial design; 1, 2 ...: redesigns beyond W, in use "
                   "from t"},
        "axes": {
            "type": "array",
            "description": "per axis: Z as {e = [position m, velocity m/s] : H e <= h}, W's vertices, gain K "
            "(u = v + K e), RPI figures and tightened bounds",
        },
    },
    "required": ["t", "dt_s", "axes"],
}


def tube_design_from_config(cfg: OacliConfig, *, extra_box: np.ndarray | None = None,
                            max_terms: int | None = None) -> TubeDesign:
    """The translational tube of ``cfg.controller.tube`` (raises InfeasibleError with W and the margin).

    ``extra_box (3, 2)`` adds ``[position m, velocity m/s]`` half-widths per axis to W's box (a redesign beyond W,
    :mod:`oacli.control.tube_monitor`; then an empty tightening always refuses); ``max_terms`` caps the
    invariant-set terms below ``rpi_max_terms``.
    """
    tube = cfg.controller.tube
    robot = cfg.robot
    dist = tube.disturbance
    force_limit = np.asarray(tube.force_limit_N if tube.force_limit_N is not None else robot.force_limit_N)
    spec = DisturbanceSpec(
        mass_kg=robot.mass_kg, mass_std_kg=dist.mass_std_kg, n_sigma=dist.mass_sigmas,
        force_N=np.asarray(dist.force_N), box_position_m=np.asarray(dist.position_m),
        box_velocity_mps=np.asarray(dist.velocity_mps), noise_position_m=np.asarray(dist.position_noise_m),
        noise_velocity_mps=np.asarray(dist.velocity_noise_mps),
    )
    on_empty = dist.on_empty_tightening
    if extra_box is not None:
        extra = np.asarray(extra_box, dtype=float).reshape(3, 2)
        spec = replace(spec, box_position_m=spec.box_position_m + extra[:, 0],
                       box_velocity_mps=spec.box_velocity_mps + extra[:, 1])
        on_empty = "error"
    anc = tube.ancillary
    return design_translation_tube(
        mass_kg=robot.mass_kg, dt_s=cfg.controller.period_s, force_limit_N=force_limit,
        velocity_limit_mps=np.asarray(robot.velocity_limit_mps),
        weights=AncillaryWeights(anc.position, anc.velocity, anc.force), spec=spec, epsilon=tube.rpi_epsilon,
        epsilon_mode=tube.rpi_epsilon_mode,
        max_terms=tube.rpi_max_terms if max_terms is None else min(max_terms, tube.rpi_max_terms),
        facet_growth=tube.lasso_facet_growth, on_empty=on_empty, min_nominal_fraction=dist.min_nominal_fraction,
    )


def tube_controller_from_config(
    cfg: OacliConfig, reference: Trajectory, design: TubeDesign, weights: TrackingWeights, limits: TrackingLimits
) -> TubeMPC:
    """The :class:`TubeMPC` of ``cfg`` around ``design``."""
    tube = cfg.controller.tube
    terminal = None
    if tube.terminal is not None:
        terminal = TerminalWeights(np.asarray(tube.terminal.position), np.asarray(tube.terminal.velocity))
    step = tube.prediction_step_s if tube.prediction_step_s is not None else cfg.controller.period_s
    return TubeMPC(
        reference, cfg.robot_params(), design, horizon=cfg.controller.horizon, prediction_step_s=step,
        weights=weights, limits=limits, terminal=terminal,
        max_consecutive_failures=cfg.controller.max_consecutive_failures, fast=tube.solver == "direct",
        **workspace_arguments(cfg),
    )


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
    return {"scene": cfg.scene(), "robot": RobotBody.sphere(cfg.robot.radius_m),
            "keep_in_margin_m": cfg.environment.keep_in_margin_m}


#: Term budget of the invariant set when the tube is redesigned beyond W during a run (bounds its time).
REDESIGN_MAX_TERMS = 200
#: A redesign grows W to (1 + margin) × the largest measured |w| per axis and component.
REDESIGN_MARGIN = 0.5
#: Redesigns allowed in one run; a further violation latches the safe hold.
MAX_REDESIGNS = 3


def monitored_tube_controller(
    cfg: OacliConfig, reference: Trajectory, design: TubeDesign, weights: TrackingWeights, limits: TrackingLimits
) -> TubeMonitor:
    """The tube controller of ``cfg`` with the beyond-W check and response of ``controller.tube.beyond_w``."""
    return TubeMonitor(
        lambda d: tube_controller_from_config(cfg, reference, d, weights, limits), design,
        response=cfg.controller.tube.beyond_w, actuator_force_limit_N=np.asarray(cfg.robot.force_limit_N),
        redesign=lambda extra: tube_design_from_config(cfg, extra_box=extra, max_terms=REDESIGN_MAX_TERMS),
        margin=REDESIGN_MARGIN, max_redesigns=MAX_REDESIGNS,
    )


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
    ``tube.lasso_violations`` counts steps with ``x̃_k − z_k ∉ Z`` for the nominal state actually used (a
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
    return {
        "tube_violations": int(np.sum(tube_margin[checked] < -tol)),
        "w_violations": beyond["violations"],
        "rpi": {k: details["rpi"][k] for k in ("s", "alpha", "facets")},
        "tightened_force_N": details["tightened_force_N"],
        "tightened_velocity_mps": details["tightened_velocity_mps"],
        "solver_failures": int(history.solver_failed.sum()),
        "beyond_w": beyond,
        "tube": details,
    }


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
    if summary["tube_violations"]:
        report.degraded("tube", f"the measured state left the promised tube on {summary['tube_violations']} steps")
    lasso = summary["tube"]["lasso_violations"]
    if lasso:
        report.degraded("lasso", f"the nominal state's lasso x - z in Z was violated on {lasso} steps")


DISTURBANCE_SCHEMA = {
    "title": "oacli.TubeDisturbance",
    "description": "Realised one-step disturbance w_k = x_k − (A x_{k−1} + B u_{k−1}) of the translational error "
    "model per world axis, against the design's W (oacli.control.tube_monitor).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "control step time [s]"},
        "w_position_m": {"type": "array", "description": "measured w, position component, x y z [m] (null at the "
                         "first step)"},
        "w_velocity_mps": {"type": "array", "description": "measured w, velocity component, x y z [m/s]"},
        "w_half_position_m": {"type": "array", "description": "W's half-width in position, x y z [m]"},
        "w_half_velocity_mps": {"type": "array", "description": "W's half-width in velocity, x y z [m/s]"},
        "margin": {"type": ["number", "null"], "description": "min over axes and facets of b − a·w (>= 0 in W)"},
        "violation": {"type": "boolean", "description": "w left W on some axis"},
        "design": {"type": "integer", "description": "index of the tube design driving the step (0: initial)"},
    },
    "required": ["t", "w_position_m", "w_velocity_mps", "w_half_position_m", "w_half_velocity_mps", "violation"],
}


def write_tube_topics(writer: StageMcapWriter, tel: Telemetry, monitor: TubeMonitor, history: TubeHistory) -> None:
    k = len(tel.t_ctrl)
    zeros = np.zeros((k, 3))
    writer.write_wrenches("/control/nominal", tel.t_ctrl, np.hstack([history.nominal_force, history.torque]))
    writer.write_wrenches("/control/ancillary", tel.t_ctrl, np.hstack([history.ancillary_force, zeros]))
    nominal = tel.x_measured.copy()  # attitude columns: measured (attitude runs standard MPC, no tube)
    nominal[:, 0:6] = history.nominal_state
    writer.write_states("/state/nominal", tel.t_ctrl, nominal,
                        np.hstack([history.nominal_force, history.torque]), name="nominal")
    for index, (t_design, design) in enumerate(monitor.designs):
        axes = []
        for ax in design.axes:
            axes.append({
                "name": ax.name, "z_normals": ax.z.a, "z_offsets": ax.z.b, "w_vertices": ax.disturbance.w.vertices,
                "gain": ax.gain[0], "s": ax.rpi.s, "alpha": ax.rpi.alpha, "epsilon": ax.rpi.epsilon,
                "facets_before_reduction": ax.reduction.facets_before, "w_scale": ax.disturbance.scale,
                "force_bounds_N": ax.force_bounds_N, "velocity_bounds_mps": ax.velocity_bounds_mps,
                "force_limit_N": ax.force_limit_N, "velocity_limit_mps": ax.velocity_limit_mps,
            })
        writer.write_json("/tube/design", "oacli.TubeDesign", TUBE_DESIGN_SCHEMA, t_design,
                          {"dt_s": design.dt_s, "design": index, "axes": axes})
    rec = monitor.disturbance_record()
    for i in range(len(rec.t)):
        writer.write_json("/tube/disturbance", "oacli.TubeDisturbance", DISTURBANCE_SCHEMA, float(rec.t[i]), {
            "w_position_m": rec.w[i, :, 0], "w_velocity_mps": rec.w[i, :, 1],
            "w_half_position_m": rec.w_half_widths[i, :, 0], "w_half_velocity_mps": rec.w_half_widths[i, :, 1],
            "margin": rec.margin[i], "violation": bool(rec.violated[i]), "design": int(rec.design_index[i]),
        })


def tube_layers(monitor: TubeMonitor, history: TubeHistory):
    rec = monitor.disturbance_record()
    designs = [d for _, d in monitor.designs]
    index = rec.design_index

    def per_step(fn) -> np.ndarray:
        values = np.array([fn(d) for d in designs])
        return values[index]

    def extra(rec_stream) -> None:
        first = designs[0]
        log_tube_layers(
            rec_stream, t_ctrl=history.t, nominal_state=history.nominal_state, nominal_force=history.nominal_force,
            ancillary_force=history.ancillary_force, tube_margin=history.tube_margin,
            z_position_extent=per_step(lambda d: d.position_extent()),
            tightened_force_N=np.array([ax.force_bounds_N[1] for ax in first.axes]),
            ancillary_force_max_N=np.array([ax.ancillary_force_N for ax in first.axes]),
            tightened_velocity_mps=np.array([ax.velocity_bounds_mps[1] for ax in first.axes]),
        )
        log_disturbance_layers(rec_stream, t_ctrl=rec.t, w=rec.w, w_half_widths=rec.w_half_widths,
                               violated=rec.violated)

    return extra
