"""``oacli estimate``: inertial parameters from a tracking run (batch maximum likelihood, sequential EKF, or the
flight's recursive least squares)."""

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

#: ``estimation.method``'s values (:data:`oacli.config.estimation.EstimationMethod`).
METHODS = ("batch", "sequential", "rls")

ESTIMATE_TABLE = [
    "status", "method", "mass_kg", "inertia_kgm2", "std", "crb_std", "error_pct", "cov_reduction_pct",
    "samples_used", "samples_rejected", "segments", "chi2_ratio", "nis_ratio", "solve_time_s",
]


def estimate(
    config: Annotated[
        Path, typer.Argument(metavar="CONFIG", help="YAML configuration file (its estimation section; see configs/).")
    ],
    telemetry: Annotated[
        Path | None, typer.Option("--telemetry", "-t", metavar="FILE",
                                  help="A tracking run's track.mcap (measured states, applied inputs); default: the "
                                  "config's inputs.estimate_telemetry (recorded by a run).")
    ] = None,
    method: Annotated[
        str | None,
        typer.Option("--method", "-m", metavar=choice_metavar(METHODS), autocompletion=complete_choices(METHODS),
                     help="batch (maximum likelihood over the run), sequential (EKF) or rls (the flight's "
                     "recursive least squares on accelerations); default: the config's estimation.method."),
    ] = None,
    allow_truncated: Annotated[
        bool,
        typer.Option("--allow-truncated/--refuse-truncated",
                     help="Estimate from the intact part of a cut telemetry file (status degraded, the loss "
                     "reported; default) or refuse it (exit 2)."),
    ] = True,
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    seed: SeedOption = None,
    quiet: QuietOption = False,
    sets: SetOption = None,
    json_out: JsonOption = False,
    view: ViewOption = False,
) -> None:
    """Estimate mass and principal inertias from TRACK.mcap; write estimate.mcap, estimate.rrd, summary.json.

    Telemetry is aligned by time stamp: reordered, late, duplicated and missing messages and gaps in the input
    record are handled and counted in summary.json (telemetry_records). Exit code 3 when the telemetry cannot
    identify every parameter (the message names them), 2 for bad input.
    """

    def action():
        from oacli.stages.estimate import run_estimate

        check_choice("--method", method, METHODS)
        from oacli.config.inputs import with_input

        cfg, path = with_input(load_config_with_seed(config, seed, sets), "estimate_telemetry", telemetry,
                               "--telemetry")
        if method is not None:  # recorded in the run's config.yaml, which then reruns the same method
            cfg = cfg.model_copy(update={"estimation": cfg.estimation.model_copy(update={"method": method})})
        return run_estimate(cfg, telemetry=path, method=method, out=out, runs_root=runs_root,
                            progress=Progress("estimate", not quiet), allow_truncated=allow_truncated)

    run_stage_command(action, ESTIMATE_TABLE, quiet, json_out, view)
