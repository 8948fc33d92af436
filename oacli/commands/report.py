"""``oacli report RUN_DIR|CAMPAIGN_DIR``: write the folder's ``report.html`` (``docs/report.md``).

Also the hook ``oacli mission`` and ``oacli campaign`` call after their run (:func:`report_after_run`): a report that
cannot be written costs the run nothing but one ``warning:`` line (the run's own files are complete before it).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

from oacli.commands.common import QuietOption, run_guarded


def report_after_run(folder: Path, say: Callable[[str], None] | None) -> None:
    """Write ``folder/report.html`` after a mission or campaign; on any error print one warning line instead.

    Parameters
    ----------
    folder : Path
        The finished run's folder (its ``summary.json`` written).
    say : callable or None
        Where the "report: ..." line goes (None: nowhere); warnings always go to stderr.
    """
    from oacli.errors import OacliError
    from oacli.report.build import write_report

    try:
        result = write_report(folder)
    except (OacliError, Exception) as exc:  # the run is complete; the report is a derived file
        reason = "; ".join(exc.problems) if isinstance(exc, OacliError) else f"{type(exc).__name__}: {exc}"
        typer.echo(f"warning: report.html not written: {reason} (oacli report {folder} retries)", err=True)
        return
    if say is not None:
        say(f"report: {result.path} ({result.size_bytes / 1e6:.2f} MB, {result.wall_time_s:.2f} s)")


def report(
    target: Annotated[Path, typer.Argument(metavar="RUN_DIR|CAMPAIGN_DIR",
                                           help="A finished mission, stage or campaign folder.")],
    out: Annotated[Path | None, typer.Option("--out", "-o", metavar="FILE",
                                             help="Write here instead of RUN_DIR/report.html.")] = None,
    quiet: QuietOption = False,
) -> None:
    """Write report.html: one self-contained offline page with the status and its reasons, the segments or cells,
    the figures and the config, read from the folder's files (nothing is run again)."""

    def action():
        from oacli.report.build import write_report

        return write_report(target, out)

    result = run_guarded(action)
    if not quiet:
        typer.echo(f"{result.kind} report: {result.figures} figures, {result.size_bytes / 1e6:.2f} MB, "
                   f"written in {result.wall_time_s:.2f} s")
    typer.echo(f"report: {result.path}", err=quiet)
