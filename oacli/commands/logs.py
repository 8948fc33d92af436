"""``oacli logs verify FILE`` and ``oacli logs recover FILE OUT``: check an MCAP file, rescue a cut-off one.

Exit codes: ``verify`` 0 when the file is complete and every CRC matches, 3 when it is truncated or corrupt (one
line on stderr naming the problem and its byte offset); ``recover`` 0 when nothing was lost, 3 when data was lost
(the line says how many messages were saved). Both exit 2 when FILE is missing, not a regular file (a FIFO, a
device, a folder: refused without reading) or not an MCAP file, and ``recover`` when OUT exists (unless
``--force``). Both read with bounded memory (:mod:`oacli.io.mcap_recover`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from oacli.commands.common import run_guarded

logs_app = typer.Typer(help="Check and recover MCAP files.", no_args_is_help=True)

#: Exit code of a damaged file (verify) or of a recovery that lost data.
EXIT_DAMAGED = 3


@logs_app.command("verify")
def logs_verify(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="The .mcap file to check.")],
) -> None:
    """Check an MCAP file's structure and CRCs (chunks, attachments, data section, summary); exit 3 when it is
    truncated or corrupt, naming what is wrong and where."""
    from oacli.io.mcap_recover import describe, verify

    scan = run_guarded(lambda: verify(file))
    if scan.ok:
        typer.echo(describe(scan))
        return
    typer.echo(f"error: {describe(scan)}", err=True)
    if scan.messages:
        typer.echo(f"{scan.messages} messages in {scan.chunks} complete chunks before the problem; "
                   "`oacli logs recover` saves them", err=True)
    raise typer.Exit(EXIT_DAMAGED)


@logs_app.command("recover")
def logs_recover(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="The cut-off or damaged .mcap file.")],
    out: Annotated[Path, typer.Argument(metavar="OUT", help="The valid .mcap file to write (must not exist).")],
    force: Annotated[bool, typer.Option("--force", help="Replace OUT if it exists.")] = False,
) -> None:
    """Rescan FILE into a valid MCAP OUT with every complete message, schema, channel, metadata record and
    attachment; exit 3 when data was lost."""
    from oacli.io.mcap_recover import recover

    result = run_guarded(lambda: recover(file, out, force=force))
    scan = result.scan
    for problem in scan.problems:
        typer.echo(f"warning: {problem.message}", err=True)
    line = (f"{result.messages} messages saved to {out} ({scan.channels} channels, {scan.metadata} metadata "
            f"records, {scan.attachments} attachments)")
    if result.lost:
        if not scan.problems:
            typer.echo(f"warning: {file}: ended before its data end record", err=True)
        typer.echo(f"data lost: {line}", err=True)
        raise typer.Exit(EXIT_DAMAGED)
    typer.echo(line)
