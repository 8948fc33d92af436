"""``oacli plan``: a collision-free trajectory between two waypoints (LQR-RRT* or kinodynamic RRT)."""

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

PLAN_TABLE = [
    "status", "planner", "segment", "iterations", "nodes", "time_to_first_solution_s", "cost", "path_length_m",
    "duration_s", "duration_ratio", "max_force_N", "collision_free", "wall_time_s",
]


def plan(
    config: ConfigArgument,
    segment: Annotated[
        str | None, typer.Option("--segment", "-s", help="Waypoints 'A-B' to plan between (default: "
                                 "planner.segment, else the first two of reference.waypoints).")
    ] = None,
    planner: Annotated[
        str | None, typer.Option("--planner", "-p", help="'lqr-rrt-star' or 'kino-rrt' (default: planner.type).")
    ] = None,
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    seed: SeedOption = None,
    quiet: QuietOption = False,
    sets: SetOption = None,
    json_out: JsonOption = False,
    view: ViewOption = False,
) -> None:
    """Plan a segment; write plan.mcap (trajectory, tree, scene), plan.rrd and summary.json.

    Exit code 3 when no solution is found within the budget (the run folder then holds the partial tree).
    """

    def action():
        from oacli.stages.plan import run_plan

        cfg = load_config_with_seed(config, seed, sets)
        return run_plan(cfg, segment=segment, planner=planner, out=out, runs_root=runs_root,
                        progress=Progress("plan", not quiet))

    run_stage_command(action, PLAN_TABLE, quiet, json_out, view)
