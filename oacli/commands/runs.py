"""``oacli runs list``: the run folders under a runs directory, newest first, with stage and status."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

runs_app = typer.Typer(help="List run folders.", no_args_is_help=True)


def describe_runs(runs_dir: Path) -> list[dict]:
    """One entry per run folder (a folder with ``summary.json`` or ``config.yaml``), newest name first.

    Parameters
    ----------
    runs_dir : Path
        Parent of the run folders.

    Returns
    -------
    list of dict
        ``name``, ``stage``, ``status``, ``path``.
    """
    out: list[dict[str, Any]] = []
    if not runs_dir.is_dir():
        return out
    for d in sorted((p for p in runs_dir.iterdir() if p.is_dir()), key=lambda p: p.name, reverse=True):
        summary_path = d / "summary.json"
        if not summary_path.exists() and not (d / "config.yaml").exists():
            continue
        try:
            summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
        except (OSError, ValueError):
            summary = {}
        out.append({"name": d.name, "stage": summary.get("stage", "mission" if (d / "mission.rrd").exists() else "?"),
                    "status": summary.get("status", "incomplete"), "path": str(d)})
    return out


@runs_app.command("list")
def runs_list(
    runs_dir: Annotated[Path, typer.Option("--runs-dir", help="Parent of the run folders.")] = Path("runs"),
    json_out: Annotated[bool, typer.Option("--json", help="JSON on stdout.")] = False,
) -> None:
    """List the run folders under --runs-dir (newest first): name, stage, status."""
    runs = describe_runs(runs_dir)
    if json_out:
        typer.echo(json.dumps(runs))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table("run", "stage", "status", box=None)
    for r in runs:
        table.add_row(r["name"], r["stage"], r["status"])
    Console(width=160).print(table)
