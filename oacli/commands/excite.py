"""``oacli excite``: an information-rich excitation trajectory (offline design or RATTLE in closed loop)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from oacli.commands.common import (
    JsonOption,
    OutOption,
    Progress,
    QuietOption,
    RunsDirOption,
    SeedOption,
    SetOption,
    ViewOption,
    check_choice,
    choice_metavar,
    complete_choices,
    load_config_with_seed,
    run_stage_command,
)

#: ``excitation.method``'s values (:class:`oacli.config.excitation.ExcitationConfig`).
METHODS = ("offline", "rattle")

EXCITE_TABLE = [
    "status", "method", "criterion", "criterion_initial", "criterion_final", "iterations", "solve_time_s",
    "max_force_N", "max_torque_Nm", "collision_free", "crb_std", "goal_residual", "wall_time_s",
]


def excite(
    config: Annotated[
        Path, typer.Argument(metavar="CONFIG", help="YAML config file with an excitation section (see configs/).")
    ],
    method: Annotated[
        str | None,
        typer.Option("--method", "-m", metavar=choice_metavar(METHODS), autocompletion=complete_choices(METHODS),
                     help="offline (SCP design, [Doerr2021] Eq. 30) or rattle (online "
                     "information-aware planner in closed loop). Overrides excitation.method."),
    ] = None,
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    seed: SeedOption = None,
    quiet: QuietOption = False,
    sets: SetOption = None,
    json_out: JsonOption = False,
    view: ViewOption = False,
) -> None:
    """Design an information-rich trajectory from excitation.start to excitation.goal; write excite.mcap,
    excite.rrd and summary.json."""

    def action():
        from oacli.stages.excite import run_excite

        check_choice("--method", method, METHODS)
        cfg = load_config_with_seed(config, seed, sets)
        return run_excite(cfg, method=method, out=out, runs_root=runs_root, progress=Progress("excite", not quiet))

    run_stage_command(action, EXCITE_TABLE, quiet, json_out, view)
