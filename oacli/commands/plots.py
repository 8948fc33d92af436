"""``oacli plots RUN_DIR``: draw a finished run's PNGs afterwards from its MCAPs (:mod:`oacli.stages.replot`).

A stage folder gets the PNGs its stage draws with ``outputs.plots: all``; a mission folder gets every complete
stage folder's PNGs and the mission's ``plots/`` (``--stage`` picks some: a stage key such as
``segment-2/track``, or ``mission``). ``--out DIR`` writes them there instead (a mission's layout mirrored). One line
per PNG written goes to stdout (``--json``: one JSON object); summaries are not changed.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from oacli.commands.common import run_guarded

MISSION_PLOTS = "mission"


def _draw_mission(run_dir: Path, summary: dict, keys: list[str] | None, out: Path | None) -> dict[str, dict]:
    from oacli.errors import InputError
    from oacli.io.runfolder import is_complete
    from oacli.mission.layout import ALL_STAGES
    from oacli.mission.plots import write_mission_plots
    from oacli.stages.replot import draw_stage

    known = [s.key for s in ALL_STAGES] + [MISSION_PLOTS]
    for key in keys or ():
        if key not in known:
            raise InputError(f"--stage: {key}: not a mission stage; one of {', '.join(known)}")
    written: dict[str, dict] = {}
    for stage in ALL_STAGES:  # an optional stage the mission did not fly has no folder: skipped silently
        if keys and stage.key not in keys:
            continue
        folder = stage.folder(run_dir)
        if not is_complete(folder):
            if keys or folder.exists():
                typer.echo(f"warning: {stage.key}: skipped, the stage folder is not complete", err=True)
            continue
        target = None if out is None else out / stage.segment / stage.name
        written[stage.key] = {k: str(p) for k, p in draw_stage(folder, target).items()}
    if not keys or MISSION_PLOTS in keys:
        if not is_complete(run_dir):
            typer.echo(f"warning: mission plots skipped: the mission did not finish (status {summary.get('status')})",
                       err=True)
        elif missing := [s.key for s in ALL_STAGES if s.key in summary.get("stages", {})
                         and not is_complete(s.folder(run_dir))]:
            typer.echo(f"warning: mission plots skipped: stage folder {missing[0]} is not complete (emptied or "
                       f"damaged since the mission ran){f' (and {len(missing) - 1} more)' if len(missing) > 1 else ''}",
                       err=True)
        else:
            target = None if out is None else out / "plots"
            try:
                pngs = write_mission_plots(run_dir, summary, out_dir=target)
            except OSError as exc:  # a stage's file removed since: the user can fix it (rerun with --from)
                raise InputError(f"{run_dir}: cannot draw the mission plots: "
                                 f"{exc.filename or ''} {(exc.strerror or str(exc)).lower()}".replace("  ", " ")
                                 ) from None
            written[MISSION_PLOTS] = {k: str(p) for k, p in pngs.items()}
    return written


def plots(
    run_dir: Annotated[Path, typer.Argument(metavar="RUN_DIR", help="A stage's or a mission's run folder.")],
    stages: Annotated[
        list[str] | None,
        typer.Option("--stage", "-s", metavar="KEY", help="Mission folders: only this stage's PNGs (a key such as "
                     "segment-2/track) or 'mission' (the mission's plots/); repeatable. Default: all."),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", metavar="DIR", help="Write the PNGs here instead of into the run folder."),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print what was written as JSON on stdout.")] = False,
) -> None:
    """Draw a finished run's PNGs from its MCAPs (the figures the stage or mission draws with outputs.plots: all)."""

    def action() -> dict[str, dict]:
        from oacli.errors import InputError
        from oacli.stages.replot import draw_stage, read_summary

        if not run_dir.is_dir():
            raise InputError(f"{run_dir}: not a folder")
        summary = read_summary(run_dir)
        if summary["stage"] == "mission":
            return _draw_mission(run_dir, summary, stages, out)
        if stages:
            raise InputError("--stage: only for mission folders")
        return {str(summary["stage"]): {k: str(p) for k, p in draw_stage(run_dir, out).items()}}

    written = run_guarded(action)
    if json_out:
        typer.echo(json.dumps({"run_dir": str(run_dir), "written": written}, indent=2))
        return
    for key, pngs in written.items():
        for path in pngs.values():
            typer.echo(f"{key}: {path}")
