"""The ``track`` stage's honest status: the safety block of the true state and the findings that set ``status``.

Split from :mod:`oacli.stages.track` so that the runner reads as one flow. The safety block is evaluated densely on
``/state/true`` (every plant sample) by :func:`oacli.metrics.safety_report`; the findings follow
:mod:`oacli.status`: the true state outside the keep-in, inside a keep-out (robot radius included) or beyond a
velocity or angular-rate limit makes the run ``unsafe``; failed solves, fallback or safe-hold steps, a command
beyond an actuator limit and, with the tube controller, a disturbance beyond W or a state outside the promised tube
make it ``degraded``.
"""

from __future__ import annotations

from typing import Any

from oacli.config import OacliConfig
from oacli.metrics import safety_block, safety_report
from oacli.model.limits import MotionLimits
from oacli.stages.settings import robot_model
from oacli.status import SAFE_HOLD_MODE, StatusReport, add_safety_reasons, controller_mode_counts, mode_word
from oacli.types import Telemetry


def track_safety(cfg: OacliConfig, tel: Telemetry, limits: MotionLimits) -> dict[str, Any]:
    """The ``safety`` block of a tracking run: every kind of violation of the true state (see the module)."""
    report = safety_report(
        tel.t_true, tel.x_true, scene=cfg.scene(), velocity_limit_mps=limits.velocity_mps,
        angular_velocity_limit_radps=limits.angular_velocity_radps, robot_radius_m=robot_model(cfg).radius_m,
        keep_in_margin_m=cfg.environment.keep_in_margin_m, t_ctrl=tel.t_ctrl, u_command=tel.u_command,
        input_limits=limits.input,
    )
    return safety_block(report, samples=len(tel.t_true), robot_radius_m=robot_model(cfg).radius_m,
                        keep_in_margin_m=cfg.environment.keep_in_margin_m)


def controller_counts(tel: Telemetry) -> dict[str, int]:
    """``solver_failures`` (steps whose solve failed; safe-hold steps attempt none), ``fallback_steps`` and
    ``safe_hold_steps`` from the mode word of each step's status (:func:`oacli.status.controller_mode_counts`)."""
    statuses = [info.status for info in tel.solve_info]
    failures = sum(not info.success and mode_word(info.status) != SAFE_HOLD_MODE for info in tel.solve_info)
    return {"solver_failures": int(failures), **controller_mode_counts(statuses)}


def assess_track(summary: dict[str, Any], extra: StatusReport | None = None) -> StatusReport:
    """The findings of a tracking run from its summary (``safety``, ``solver_failures``, ``fallback_steps``,
    ``safe_hold_steps``, ``control_steps``); ``extra`` carries controller-specific findings (tube)."""
    report = extra if extra is not None else StatusReport()
    add_safety_reasons(report, summary["safety"])
    steps = summary["control_steps"]
    if summary["solver_failures"]:
        report.degraded("solver", f"{summary['solver_failures']} of {steps} controller solves failed")
    fallback, hold = summary["fallback_steps"], summary["safe_hold_steps"]
    parts = []
    if fallback - hold:
        parts.append(f"{fallback - hold} steps were driven by a fallback (shifted plan or LQR)")
    if hold:
        parts.append(f"{hold} steps by the safe hold")
    if parts:
        report.degraded("fallback", ", ".join(parts))
    # Unsafe findings first: the warning line leads with what matters most.
    report.reasons.sort(key=lambda r: r.level != "unsafe")
    return report
