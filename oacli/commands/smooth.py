"""``oacli smooth``: LQR shortcutting of a plan read back from its MCAP, then the path-length polish."""

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

SMOOTH_TABLE = [
    "status", "cost_before", "cost_after_shortcut", "cost_after", "duration_before_s", "duration_after_s",
    "duration_ratio", "path_length_before_m", "path_length_after_shortcut_m", "path_length_after_m",
    "shortcuts_tried", "shortcuts_accepted", "shortcuts_rejected", "collision_free", "wall_time_s",
]


def smooth(
    config: ConfigArgument,
    input_path: Annotated[
        Path | None, typer.Option("--input", "-i", metavar="FILE",
                                  help="MCAP with a /trajectory to smooth (plan.mcap or smooth.mcap); default: the "
                                  "config's inputs.smooth_input (recorded by a run).")
    ] = None,
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    seed: SeedOption = None,
    quiet: QuietOption = False,
    sets: SetOption = None,
    json_out: JsonOption = False,
    view: ViewOption = False,
) -> None:
    """Smooth a plan by LQR shortcutting, then shorten its path (planner.polish); write smooth.mcap, smooth.rrd
    and summary.json."""

    def action():
        from oacli.config.inputs import with_input
        from oacli.stages.smooth import run_smooth

        cfg, path = with_input(load_config_with_seed(config, seed, sets), "smooth_input", input_path, "--input")
        return run_smooth(cfg, input_path=path, out=out, runs_root=runs_root,
                          progress=Progress("smooth", not quiet))

    run_stage_command(action, SMOOTH_TABLE, quiet, json_out, view)
