"""RATTLE's terminal phase and rate margins (oacli.excitation.rattle_terminal, oacli.stages.rattle_goal,
oacli.stages.rattle_rates): the schedule, the closed loop's noise jitter against a simulation of the same loop, and
the mission's segment 2 flown with RATTLE ending at C at rest with its rates inside the controller's margin."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from oacli.config import config_from_dict
from oacli.config.overrides import apply_overrides
from oacli.control.lqr import dlqr
from oacli.errors import ConfigError
from oacli.excitation.rattle_terminal import FREE_BOUND, TerminalPhase, closed_loop_jitter_std, terminal_bounds
from oacli.mission.configs import Handoff, stage_config
from oacli.mission.layout import stage_by_key
from oacli.model.double_integrator import hover_error_model
from oacli.stages.excite import run_excite
from oacli.stages.rattle_goal import loop_jitter_std
from oacli.stages.rattle_rates import JITTER_SIGMAS, rattle_governor_limit
from oacli.stages.settings import excitation_prior_model
from oacli.types import InertialParams

ROOT = Path(__file__).resolve().parents[1]


def test_terminal_schedule_and_bounds():
    """T = 60 s, hold 4 s, horizon 40 × 0.3 s: regular replans every 12 s until the terminal one at 44 s, whose
    horizon ends at the arrival (56 s); it constrains its last steps to the goal at rest, the others are free."""
    phase = TerminalPhase(end_s=60.0, hold_s=4.0, horizon_s=12.0)
    assert (phase.arrival_s, phase.start_s) == (56.0, 44.0)
    assert [phase.next_replan(t, 12.0) for t in (0.0, 12.0, 24.0, 36.0)] == [12.0, 24.0, 36.0, 44.0]
    assert not phase.is_terminal(36.0) and phase.is_terminal(44.0) and phase.is_terminal(44.2)
    assert phase.arrival_step(44.0, 0.3) == 40 and phase.arrival_step(44.2, 0.3) == 40   # ceil(11.8 / 0.3)
    assert TerminalPhase(10.0, 4.0, 12.0).arrival_step(0.0, 0.3) == 20   # a run shorter than the horizon
    bounds = terminal_bounds(40, 38)
    assert bounds.shape == (41, 4) and np.all(bounds[38:] == 0.0) and np.all(bounds[:38] == FREE_BOUND)
    assert np.all(terminal_bounds(40, None) == FREE_BOUND)


def test_jitter_matches_a_simulation_of_the_noisy_loop():
    """The Lyapunov σ equals the sample σ of the same linear loop driven by white measurement noise (2 × 10⁵ steps,
    within 3 %)."""
    params = InertialParams(15.0, np.array([0.15, 0.14, 0.16]))
    q = np.repeat([10.0, 1.0, 10.0, 1.0], 3)
    r = np.repeat([1.0, 100.0], 3)
    noise = np.repeat([0.01, 0.0022, 0.005, 0.016], 3)
    sigma = closed_loop_jitter_std(params, 0.2, q, r, noise)
    a, b = hover_error_model(params, 0.2)
    k, _ = dlqr(a, b, np.diag(q), np.diag(r))
    rng = np.random.default_rng(0)
    n_steps = 200_000
    e = np.zeros(12)
    samples = np.empty((n_steps, 12))
    a_cl, bk = a + b @ k, b @ k
    draws = rng.standard_normal((n_steps, 12)) * noise
    for i in range(n_steps):
        e = a_cl @ e + bk @ draws[i]
        samples[i] = e
    np.testing.assert_allclose(samples[1000:].std(axis=0), sigma, rtol=0.03)
    assert 0.005 < sigma[9] < 0.012   # the rate jitter: several times the design tolerance of 1 mrad/s


def test_terminal_hold_must_fit_in_the_run():
    data = yaml.safe_load((ROOT / "configs" / "rattle_flight_rls.yaml").read_text())
    with pytest.raises(ConfigError, match="terminal_hold_s"):
        config_from_dict(apply_overrides(data, ["excitation.rattle.terminal_hold_s=40"]), source="test")


def test_mission_segment_2_with_rattle_ends_at_c_at_rest(tmp_path):
    """The flight-fault campaign's segment 2 (configs/campaign_reswarm_flight.yaml: RATTLE, the full rigid body):
    the terminal replan plans to C at rest, the flown run ends there within the design tolerance plus 4σ of the
    loop's noise jitter (status ok; before the terminal phase every such run ended 1-4 cm away, still moving), and
    it still gathers the information (A-criterion down by more than 50×); RATTLE's planned rates stay within the
    controller's rate margin less 2σ of its loop's rate jitter and the true rate within the robot's limit."""
    data = apply_overrides(yaml.safe_load((ROOT / "configs" / "mission_iss.yaml").read_text()), [
        "mission.excitation_method=rattle", "outputs.plots=false",
        "estimation.parameters=[mass, inertia, products, com, force_scale, torque_scale]"])
    mission = config_from_dict(data, source="test")
    cfg = stage_config(mission, stage_by_key("segment-2/excite"), Handoff())
    summary = run_excite(cfg, out=tmp_path / "excite").summary
    assert summary["status"] == "ok", summary.get("status_reasons")
    tol, res = summary["goal_tolerance"], summary["goal_residual"]
    assert all(res[k] <= tol[k] for k in ("position_m", "velocity_mps", "angular_velocity_radps")), (res, tol)
    assert summary["final_position_error_m"] < 0.02 and summary["final_speed_mps"] < 0.005
    plan = summary["plan_goal_residual"]
    assert plan["position_m"] < 1e-6 and plan["velocity_mps"] < 1e-6 and plan["angular_velocity_radps"] < 1e-4
    assert summary["terminal_replan_s"] == pytest.approx(cfg.excitation.rattle.duration_s - 4.0 - 12.0, abs=0.2)
    assert summary["criterion_final"] < summary["criterion_initial"] / 50
    governor = rattle_governor_limit(cfg)
    np.testing.assert_allclose(governor, 0.1745 * (1 - cfg.controller.rate_margin))
    jitter = loop_jitter_std(cfg, np.array(excitation_prior_model(cfg).theta))["angular_velocity_radps"]
    # the plans start from the measured (noisy) rate; beyond their first samples they keep the cap
    assert summary["max_plan_angular_velocity_radps"] <= float(np.max(governor)) - JITTER_SIGMAS * jitter + 0.02
    assert summary["max_angular_velocity_radps"] < 0.1745 and summary["safety"]["angular_velocity"]["count"] == 0
