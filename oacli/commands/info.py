"""``oacli info PATH``: describe a run folder or an MCAP file, like ``ros2 bag info``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from oacli.commands.common import json_text
from oacli.errors import InputError


def mcap_info(path: Path) -> dict[str, Any]:
    """Channels, message counts, time span and metadata names of an MCAP file (from its summary section).

    Parameters
    ----------
    path : Path
        The ``.mcap``.

    Returns
    -------
    dict
        ``file``, ``bytes``, ``start_s``, ``end_s``, ``duration_s`` (log times), ``messages`` and ``channels``
        (``topic``, ``schema``, ``encoding``, ``messages`` each).

    Raises
    ------
    InputError
        Not a readable MCAP file.
    """
    from mcap.reader import make_reader

    from oacli.io.regular_files import open_regular

    fd = open_regular(path)  # a FIFO, a device or a folder: exit 2 without blocking
    try:
        with open(fd, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # the mcap reader raises several types on a bad file
        summary = None
    if summary is None or summary.statistics is None:
        raise InputError(_unreadable(path))
    stats = summary.statistics
    schemas = {sid: s.name for sid, s in summary.schemas.items()}
    channels = [
        {"topic": ch.topic, "schema": schemas.get(ch.schema_id, ""), "encoding": ch.message_encoding,
         "messages": int(stats.channel_message_counts.get(cid, 0))}
        for cid, ch in sorted(summary.channels.items(), key=lambda kv: kv[1].topic)
    ]
    start, end = stats.message_start_time * 1e-9, stats.message_end_time * 1e-9
    return {"file": str(path), "bytes": path.stat().st_size, "start_s": start, "end_s": end,
            "duration_s": end - start, "messages": int(stats.message_count), "channels": channels}


#: The first bytes of every MCAP file.
_MCAP_MAGIC = b"\x89MCAP0\r\n"


def _unreadable(path: Path) -> str:
    """One line for an MCAP file ``info`` cannot summarise: a cut or damaged one points at ``oacli logs``."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(_MCAP_MAGIC))
    except OSError as exc:
        return f"{path}: cannot read it ({exc.strerror or exc})"
    if head != _MCAP_MAGIC:
        return f"{path}: not an MCAP file"
    return (f"{path}: an MCAP file without a readable summary (cut short or damaged): check it with "
            f"'oacli logs verify {path}'; save its complete chunks with 'oacli logs recover {path} OUT.mcap'")


def format_reason(reason: Any) -> str:
    """A status finding of ``summary.json`` (``{level, kind, message}``) as ``level: message [kind]``."""
    if isinstance(reason, dict):
        text = f"{reason.get('level', '?')}: {reason.get('message', '')}"
        return text + (f" [{reason['kind']}]" if reason.get("kind") else "")
    return str(reason)


def path_info(path: Path) -> dict[str, Any]:
    """:func:`mcap_info` of a file, or for a run folder its status, files and its MCAP's info.

    Parameters
    ----------
    path : Path
        A run folder or an ``.mcap``.

    Returns
    -------
    dict

    Raises
    ------
    InputError
        A missing path, or neither a folder nor an MCAP file.
    """
    if not path.exists():
        raise InputError(f"{path}: not found")
    if not path.is_dir():
        return mcap_info(path)
    from oacli.io.runfolder import read_summary_file

    summary_path = path / "summary.json"
    summary = read_summary_file(summary_path) if summary_path.exists() or summary_path.is_symlink() else {}
    mcaps = sorted(path.glob("*.mcap"))
    return {"run": str(path), "stage": summary.get("stage"), "status": summary.get("status", "incomplete"),
            "status_reasons": summary.get("status_reasons", []),
            "files": sorted(p.name for p in path.iterdir()),
            "mcap": mcap_info(mcaps[0]) if mcaps else None}


def info(
    path: Annotated[Path, typer.Argument(metavar="PATH", help="A run folder or an MCAP file.")],
    json_out: Annotated[bool, typer.Option("--json", help="Strict JSON on stdout (NaN, inf as null).")] = False,
) -> None:
    """Describe a run folder or an MCAP file: status, channels, message counts, duration."""
    from oacli.commands.common import run_guarded

    data = run_guarded(lambda: path_info(path))
    if json_out:
        typer.echo(json_text(data))
        return
    if "run" in data:
        typer.echo(f"run:       {data['run']}\nstage:     {data['stage']}\nstatus:    {data['status']}")
        for reason in data["status_reasons"]:
            typer.echo(f"  - {format_reason(reason)}")
        typer.echo(f"files:     {', '.join(data['files'])}")
        data = data["mcap"]
        if data is None:
            return
    typer.echo(f"file:      {data['file']} ({data['bytes']} bytes)")
    typer.echo(f"duration:  {data['duration_s']:.3f} s  ({data['start_s']:.3f} .. {data['end_s']:.3f})")
    typer.echo(f"messages:  {data['messages']}")
    width = max((len(c["topic"]) for c in data["channels"]), default=5)
    typer.echo("channels:")
    for c in data["channels"]:
        typer.echo(f"  {c['topic']:<{width}}  {c['messages']:>7} msgs  {c['schema']} ({c['encoding']})")
