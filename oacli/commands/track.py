"""``oacli track``: closed-loop tracking of a reference with MPC or robust tube MPC (``controller.type``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from oacli.commands.common import (
    ConfigArgument,
    JsonOption,
    OutOption,
    Progress,
    QuietOption,
    RunsDirOption,
    SeedOption,
    SetOption,
    ViewOption,
    load_config_with_seed,
    run_stage_command,
)

TRACK_TABLE = [
    "status", "rms_position_error_m", "max_position_error_m", "final_position_error_m", "rms_attitude_error_rad",
    "constraint_violations", "constraint_violations_by_kind", "solver_failures", "fallback_steps",
    "safe_hold_steps", "tube_violations", "w_violations", "rpi", "solve_time_ms", "step_time_ms", "sim_time_s",
    "wall_time_s",
]


def track(
    config: ConfigArgument,
    reference: Annotated[
        Path | None,
        typer.Option("--reference", "-r", help="Reference to follow: a previous stage's MCAP (its /trajectory), "
                     "a RATTLE results_*_0.dat folder, or a CSV. Overrides the config's reference."),
    ] = None,
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    seed: SeedOption = None,
    quiet: QuietOption = False,
    sets: SetOption = None,
    json_out: JsonOption = False,
    view: ViewOption = False,
    strict: Annotated[
        bool,
        typer.Option("--strict", help="Refuse (exit 2) a reference the simulated plant (truth) cannot follow within "
                     "the robot's force, torque, velocity and angular-rate limits; without it: a warning."),
    ] = False,
) -> None:
    """Track a reference with MPC or robust tube MPC (controller.type) in closed-loop simulation; write
    track.mcap, track.rrd and summary.json."""

    def action():
        from oacli.io.reference_files import load_reference
        from oacli.stages.track import run_track

        cfg = load_config_with_seed(config, seed, sets)
        ref = None
        if reference is not None:
            ref_path = reference.resolve()
            ref = load_reference(ref_path, sample_period_s=cfg.reference.sample_period_s,
                                 frame=cfg.environment.frame)
            new_ref = cfg.reference.model_copy(update={"source": "file", "file": str(ref_path)})
            cfg = cfg.model_copy(update={"reference": new_ref})
        result = run_track(cfg, reference=ref, out=out, runs_root=runs_root, progress=Progress("track", not quiet),
                           strict_reference=strict)
        check = result.summary.get("reference_check", {})
        if check and not check["ok"]:
            typer.echo(f"warning: {check['message']} (tracked anyway; --strict refuses it)", err=True)
        return result

    run_stage_command(action, TRACK_TABLE, quiet, json_out, view)
