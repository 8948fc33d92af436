"""Whether RATTLE's closed-loop run ends at the goal at rest: the excite stage's goal check of the ``rattle`` method.

An offline design is a plan: it ends at the goal within ``excitation.terminal_tolerance`` (1 cm, 1 mm/s, 1 mrad/s by
default). RATTLE's run is a flight: the LQR feeds noisy measurements back, so its true state jitters about the held
goal by σ of the order of mm, mm/s and mrad/s (:func:`oacli.excitation.rattle_terminal.closed_loop_jitter_std`;
the flight-like sensors, rate noise 0.016 rad/s, give a rate jitter of ~8 mrad/s, eight times the design tolerance).
The run's true final state is held to the design tolerance plus ``excitation.rattle.goal_noise_sigmas`` of that
jitter (per axis); its last plan (the terminal replan, :mod:`oacli.excitation.rattle_terminal`) to the design
tolerance itself. Both figures go to ``summary.json`` (``goal_tolerance``, ``plan_goal_residual``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.excitation.problem import attitude_errors
from oacli.excitation.rattle_loop import RattleRun
from oacli.excitation.rattle_terminal import closed_loop_jitter_std
from oacli.stages.settings import sensor_noise, terminal_tolerance
from oacli.status import StatusReport
from oacli.types import InertialParams

KEYS = ("position_m", "velocity_mps", "angular_velocity_radps")
"""The goal residuals checked (largest per-axis error)."""


def loop_jitter_std(cfg: OacliConfig, theta: np.ndarray) -> dict[str, float]:
    """σ of the RATTLE loop's jitter about a held state (largest axis): ``position_m``, ``velocity_mps``,
    ``angular_velocity_radps`` (:func:`oacli.excitation.rattle_terminal.closed_loop_jitter_std` with the config's
    ``controller`` weights and period and ``sensors`` noise, the gain's model ``theta`` = [m, Ixx, Iyy, Izz])."""
    s = sensor_noise(cfg)
    noise = np.repeat([s.position_std_m, s.velocity_std_mps, s.attitude_std_rad, s.angular_velocity_std_radps], 3)
    cw = cfg.controller.weights
    jitter = closed_loop_jitter_std(InertialParams(float(theta[0]), np.asarray(theta[1:4], dtype=float)),
                                    cfg.controller.period_s, cw.state_weights(), cw.input_weights(), noise)
    return {"position_m": float(np.max(jitter[0:3])), "velocity_mps": float(np.max(jitter[3:6])),
            "angular_velocity_radps": float(np.max(jitter[9:12]))}


def goal_tolerance(cfg: OacliConfig, theta: np.ndarray) -> dict[str, Any]:
    """The tolerance of the run's true final state: design tolerance + n σ of the closed loop's jitter.

    Parameters
    ----------
    cfg : OacliConfig
        The excite stage's config (``controller`` weights and period, ``sensors``, ``excitation``).
    theta : ndarray, shape (4,)
        ``[m, Ixx, Iyy, Izz]`` of the loop's last gain (the estimate at the last replan) [kg, kg·m²].

    Returns
    -------
    dict
        ``position_m``, ``velocity_mps``, ``angular_velocity_radps`` (the tolerances), ``noise_sigmas`` and
        ``jitter_std`` (σ per quantity, largest axis).
    """
    sigma = loop_jitter_std(cfg, theta)
    tol = terminal_tolerance(cfg)
    n = cfg.excitation.rattle.goal_noise_sigmas
    design = {"position_m": tol.position_m, "velocity_mps": tol.velocity_mps,
              "angular_velocity_radps": tol.angular_velocity_radps}
    out: dict[str, Any] = {key: design[key] + n * sigma[key] for key in KEYS}
    out["noise_sigmas"] = n
    out["jitter_std"] = sigma
    return out


def plan_goal_residual(run: RattleRun, goal: np.ndarray) -> dict[str, float]:
    """The last plan's final sample from the goal at rest (largest per-axis error) [m, m/s, rad, rad/s]."""
    x = run.replans[-1].plan.trajectory.x[-1]
    err, _ = attitude_errors(goal[6:10], x[None, 6:10])
    return {"position_m": float(np.max(np.abs(x[0:3] - goal[0:3]))), "velocity_mps": float(np.max(np.abs(x[3:6]))),
            "attitude_rad": float(np.max(np.abs(err))),
            "angular_velocity_radps": float(np.max(np.abs(x[10:13])))}


def goal_reasons(report: StatusReport, summary: dict[str, Any], cfg: OacliConfig) -> None:
    """``degraded`` when the run's true final state is beyond ``goal_tolerance`` or, with the terminal phase, the
    last plan ends beyond the design tolerance (``summary`` holds ``goal_residual``, ``goal_tolerance`` and
    ``plan_goal_residual``)."""
    residual, tol = summary["goal_residual"], summary["goal_tolerance"]
    over = [f"{key} {residual[key]:.3g} > {tol[key]:.3g}" for key in KEYS if residual[key] > tol[key] * 1.001]
    if over:
        report.degraded("goal", "the run ends away from the goal at rest (" + ", ".join(over) + "; "
                        "excitation.terminal_tolerance + excitation.rattle.goal_noise_sigmas × the loop's jitter σ)")
    if cfg.excitation.rattle.terminal_hold_s is None:
        return
    design = terminal_tolerance(cfg)
    plan = summary["plan_goal_residual"]
    bounds = {"position_m": design.position_m, "velocity_mps": design.velocity_mps,
              "attitude_rad": design.attitude_rad, "angular_velocity_radps": design.angular_velocity_radps}
    missed = [f"{key} {plan[key]:.3g} > {b:.3g}" for key, b in bounds.items() if plan[key] > b * 1.001]
    if missed:
        report.degraded("terminal_plan", "the terminal replan does not end at the goal at rest ("
                        + ", ".join(missed) + "; excitation.terminal_tolerance)")
