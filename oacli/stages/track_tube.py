"""The ``track`` stage with ``controller: tube``: the tube design from the config, its records and its summary.

Split from :mod:`oacli.stages.track` so that the stage runner reads as one flow; everything here is specific to
robust tube MPC (Mayne, Seron & Raković 2005; Raković et al. 2005; Doerr et al. 2021 Eqs. 15-28).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.tracking import TrackingLimits, TrackingWeights
from oacli.control.tube_design import AncillaryWeights, TubeDesign, design_translation_tube
from oacli.control.tube_mpc import TerminalWeights, TubeHistory, TubeMPC
from oacli.geometry.collision import RobotBody
from oacli.io.mcap_io import StageMcapWriter
from oacli.io.rerun_tube import log_tube_layers
from oacli.types import Telemetry, Trajectory

LogEntry = tuple[float, str, str]


# ----------------------------------------------------------------------------------------------------------------
# Robust tube MPC (controller.type: tube)
# ----------------------------------------------------------------------------------------------------------------

#: A measured error counts as outside Z only beyond this fraction of Z's largest offset (rounding, solver tolerance).
TUBE_TOLERANCE_REL = 1e-6

TUBE_DESIGN_SCHEMA = {
    "title": "oacli.TubeDesign",
    "description": "Robust tube MPC design per world axis x, y, z (Mayne et al. 2005; Raković et al. 2005).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "mission time [s]"},
        "dt_s": {"type": "number", "description": "control period, the step of W and of the ancillary law [s]"},
        "axes": {
            "type": "array",
            "description": "per axis: Z as {e = [position m, velocity m/s] : H e <= h}, W's vertices, gain K "
            "(u = v + K e), RPI figures and tightened bounds",
        },
    },
    "required": ["t", "dt_s", "axes"],
}


def tube_design_from_config(cfg: OacliConfig) -> TubeDesign:
    """The translational tube of ``cfg.controller.tube`` (raises InfeasibleError with W and the margin)."""
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
    anc = tube.ancillary
    return design_translation_tube(
        mass_kg=robot.mass_kg, dt_s=cfg.controller.period_s, force_limit_N=force_limit,
        velocity_limit_mps=np.asarray(robot.velocity_limit_mps),
        weights=AncillaryWeights(anc.position, anc.velocity, anc.force), spec=spec, epsilon=tube.rpi_epsilon,
        max_terms=tube.rpi_max_terms, facet_growth=tube.lasso_facet_growth, on_empty=dist.on_empty_tightening,
        min_nominal_fraction=dist.min_nominal_fraction,
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
    """``scene`` and ``robot`` for the controllers when ``controller.position_constraints`` is on, else none."""
    if not cfg.controller.position_constraints:
        return {}
    return {"scene": cfg.scene(), "robot": RobotBody.sphere(cfg.robot.radius_m)}


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


def tube_summary(design: TubeDesign, history: TubeHistory, tel: Telemetry, cfg: OacliConfig) -> dict[str, Any]:
    """Summary entries of a tube run: violations, fallbacks, RPI figures, tightened bounds.

    ``tube_violations`` counts control steps whose measured state left the tube promised at the previous step,
    ``x̃_k − ẑ_k ∉ Z`` with ``ẑ_k = A z_{k−1} + B v_{k−1}`` (beyond ``TUBE_TOLERANCE_REL`` of Z's size): the
    invariance guarantee, which can only fail when a disturbance left W. ``tube.lasso_violations`` counts steps
    with ``x̃_k − z_k ∉ Z`` for the nominal state actually used (a constraint of the QP). ``fallback_steps``
    counts steps not driven by a fresh solve (shifted plan or safe hold), ``solver_failures`` failed solves.
    """
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
    })
    return {
        "tube_violations": int(np.sum(tube_margin[checked] < -tol)),
        "rpi": {k: details["rpi"][k] for k in ("s", "alpha", "facets")},
        "tightened_force_N": details["tightened_force_N"],
        "tightened_velocity_mps": details["tightened_velocity_mps"],
        "solver_failures": int(history.solver_failed.sum()),
        "fallback_steps": history.count("fallback") + history.count("hold"),
        "safe_hold_steps": history.count("hold"),
        "tube": details,
    }


def write_tube_topics(writer: StageMcapWriter, tel: Telemetry, design: TubeDesign, history: TubeHistory) -> None:
    k = len(tel.t_ctrl)
    zeros = np.zeros((k, 3))
    writer.write_wrenches("/control/nominal", tel.t_ctrl, np.hstack([history.nominal_force, history.torque]))
    writer.write_wrenches("/control/ancillary", tel.t_ctrl, np.hstack([history.ancillary_force, zeros]))
    nominal = tel.x_measured.copy()  # attitude columns: measured (attitude runs standard MPC, no tube)
    nominal[:, 0:6] = history.nominal_state
    writer.write_states("/state/nominal", tel.t_ctrl, nominal,
                        np.hstack([history.nominal_force, history.torque]), name="nominal")
    axes = []
    for ax in design.axes:
        axes.append({
            "name": ax.name, "z_normals": ax.z.a, "z_offsets": ax.z.b, "w_vertices": ax.disturbance.w.vertices,
            "gain": ax.gain[0], "s": ax.rpi.s, "alpha": ax.rpi.alpha, "epsilon": ax.rpi.epsilon,
            "facets_before_reduction": ax.reduction.facets_before, "w_scale": ax.disturbance.scale,
            "force_bounds_N": ax.force_bounds_N, "velocity_bounds_mps": ax.velocity_bounds_mps,
            "force_limit_N": ax.force_limit_N, "velocity_limit_mps": ax.velocity_limit_mps,
        })
    writer.write_json("/tube/design", "oacli.TubeDesign", TUBE_DESIGN_SCHEMA, 0.0, {"dt_s": design.dt_s, "axes": axes})


def tube_layers(design: TubeDesign, history: TubeHistory):
    def extra(rec) -> None:
        log_tube_layers(
            rec, t_ctrl=history.t, nominal_state=history.nominal_state, nominal_force=history.nominal_force,
            ancillary_force=history.ancillary_force, tube_margin=history.tube_margin,
            z_position_extent=design.position_extent(),
            tightened_force_N=np.array([ax.force_bounds_N[1] for ax in design.axes]),
            ancillary_force_max_N=np.array([ax.ancillary_force_N for ax in design.axes]),
            tightened_velocity_mps=np.array([ax.velocity_bounds_mps[1] for ax in design.axes]),
        )

    return extra
