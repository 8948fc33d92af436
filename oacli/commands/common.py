"""What every ``oacli`` command shares: the common options, the progress bar, config loading with ``--seed``,
the mapping of errors to one-line messages and exit codes, and the results table.

The commands (one module each in :mod:`oacli.commands`) import from here; :mod:`oacli.cli` registers them on the
Typer app.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from oacli.commands.progress import Progress
from oacli.errors import ConfigError, OacliError
from oacli.signals import (
    delivered,
    exit_code_for,
    interruption_message,
    recorded_message,
    swallowed_message,
    terminate_like_interrupt,
)

__all__ = ["Progress"]  # re-exported: the commands import it from here

# Nothing heavy is imported at module level (oacli.config and its pydantic models, numpy, rich): `oacli --help` and
# `oacli report` import every command module; a command imports what it needs when it runs.

# Options every stage command shares (``Annotated`` aliases: ``out: OutOption = None``). Metavars name what a
# value is (CONFIG, DIR, FILE, INT); flags show none (:func:`hide_flag_types`).
ConfigArgument = Annotated[Path, typer.Argument(metavar="CONFIG", help="YAML configuration file (see configs/).")]
OutOption = Annotated[
    Path | None, typer.Option("--out", "-o", metavar="DIR", help="Run folder (must not exist or be empty).")
]
RunsDirOption = Annotated[
    Path, typer.Option("--runs-dir", metavar="DIR", help="Parent of automatically named run folders "
                       "<config name>-<stage>-<UTC stamp>.")
]
SeedOption = Annotated[int | None, typer.Option("--seed", metavar="INT", help="Override the config's seed.")]
QuietOption = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no results table.")]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", metavar="KEY=VALUE", help="Override a config value by its dotted path, e.g. "
                 "--set robot.mass_kg=15 (YAML value; repeatable; validated like the file's values)."),
]
ViewOption = Annotated[bool, typer.Option("--view", help="Open the recording in the Rerun viewer (127.0.0.1).")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print the results (summary.json) as strict JSON on stdout "
                                          "(NaN and infinities as null).")]


def choice_metavar(choices: Sequence[str]) -> str:
    """The metavar of an option taking one of ``choices``: ``[a|b|c]`` (shown by ``--help``)."""
    return "[" + "|".join(choices) + "]"


def complete_choices(choices: Sequence[str]) -> Callable[[str], list[str]]:
    """A shell-completion callback offering the ``choices`` that start with what was typed."""

    def complete(incomplete: str) -> list[str]:
        return [c for c in choices if c.startswith(incomplete)]

    return complete


def check_choice(option: str, value: str | None, choices: Sequence[str]) -> None:
    """Refuse a value outside ``choices`` with one line naming the option (exit 2); ``None`` passes."""
    if value is not None and value not in choices:
        raise ConfigError(f"{option} {value}: must be one of " + ", ".join(choices))


def hide_flag_types() -> None:
    """Show no type for flags in ``--help`` (typer prints ``--quiet <bool>``, as if the flag took a value).

    Applies to every flag of the app, typer's own ``--help`` and ``--install-completion`` included, by wrapping
    ``TyperOption.display_type_rich``; a no-op when a typer release no longer has that method.
    """
    from typer.core import TyperOption

    original = getattr(TyperOption, "display_type_rich", None)
    if original is None or getattr(original, "_oacli_flags_hidden", False):
        return

    def display_type_rich(self, ctx):
        if self.is_flag and self.metavar is None:
            return None
        return original(self, ctx)

    display_type_rich._oacli_flags_hidden = True  # type: ignore[attr-defined]
    TyperOption.display_type_rich = display_type_rich  # type: ignore[method-assign]


def json_text(data: Any) -> str:
    """``data`` as strict JSON (RFC 8259): numpy values as plain numbers, NaN and ±inf as ``null`` (as in
    summary.json, :func:`oacli.io.jsonsafe.to_json_safe`), paths and other objects as strings."""
    import json

    from oacli.io.jsonsafe import to_json_safe

    return json.dumps(to_json_safe(data), allow_nan=False, default=str)


def fail(exc: BaseException) -> typer.Exit:
    """Print an error without a traceback and return the Exit to raise."""
    if isinstance(exc, OacliError):
        for line in exc.problems:
            typer.echo(f"error: {line}", err=True)
        return typer.Exit(exc.exit_code)
    if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, or SIGTERM/SIGHUP (oacli.signals): exit 130 / 143
        typer.echo(f"error: {recorded_message(exc) or interruption_message(exc)}", err=True)
        for note in getattr(exc, "__notes__", ()):  # e.g. what could not be kept or written while stopping
            typer.echo(f"warning: {note.strip('()')}", err=True)
        if os.environ.get("OACLI_DEBUG"):
            import traceback

            traceback.print_exception(exc)
        return typer.Exit(exit_code_for(exc))
    if os.environ.get("OACLI_DEBUG"):
        raise exc
    typer.echo(f"internal error: {type(exc).__name__}: {exc} (set OACLI_DEBUG=1 for a traceback)", err=True)
    return typer.Exit(1)


def format_value(value: Any) -> str:
    """A summary value for the results table: floats to 4 significant digits, vectors in brackets."""
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return ", ".join(f"{k} {format_value(v)}" for k, v in value.items())
    return str(value)


def print_table(summary: dict[str, Any], keys: list[str]) -> None:
    """Print selected summary entries as a two-column rich table on stdout (plain text when not a terminal)."""
    from rich.console import Console
    from rich.table import Table

    table = Table(show_header=False, box=None, pad_edge=False)
    table.add_column("key", style="bold")
    table.add_column("value", overflow="fold")
    for key in keys:
        if key in summary:
            table.add_row(key, format_value(summary[key]))
    Console(soft_wrap=False, width=max(120, 40)).print(table)


def load_config_with_seed(config: Path, seed: int | None, sets: list[str] | None = None):
    """Load a config file and apply ``--set`` overrides and a ``--seed`` override (validated like the file's values;
    an error names the field)."""
    import os

    from oacli.config import config_from_dict, load_config
    from oacli.config.overrides import apply_overrides

    cfg = load_config(config)
    if sets:
        data = apply_overrides(cfg.model_dump(mode="json"), sets)
        cfg = config_from_dict(data, source=f"{config} (--set)", base_dir=os.path.dirname(os.path.abspath(config)))
    if seed is not None:
        if seed < 0:
            raise ConfigError(f"--seed: {seed}: must be >= 0")
        cfg = cfg.model_copy(update={"seed": seed})
    return cfg


def run_guarded(action: Callable[[], Any]) -> Any:
    """Run a command's action, mapping every error to a clear message and an exit code (no traceback)."""
    try:
        with terminate_like_interrupt():
            result = action()
            swallowed = delivered()  # an interruption lost on its way (oacli.signals.delivered): still 130/143
    except (OacliError, KeyboardInterrupt, Exception) as exc:  # every error is mapped to an exit code
        raise fail(exc) from None
    if swallowed is not None:
        typer.echo(f"error: {swallowed_message(swallowed)}", err=True)
        raise typer.Exit(128 + swallowed)
    return result


def run_stage_command(action: Callable[[], Any], table: list[str], quiet: bool, json_out: bool = False,
                      view: bool = False) -> None:
    """Run a stage command's action (errors mapped by :func:`run_guarded`), then print its results table on
    stdout (unless ``quiet``) and the run folder (on stderr when quiet, so stdout stays empty).

    A status other than ``ok`` prints one ``warning:`` line on stderr (even when quiet) and exits with its code
    (:data:`oacli.status.EXIT_CODES`: ``degraded`` 0, ``unsafe`` 4). With ``json_out`` stdout holds only the
    summary as JSON (plus ``run_dir``). With ``view`` the stage's ``.rrd`` opens in the Rerun viewer.
    """
    from oacli.status import exit_code, warning_line

    result = run_guarded(action)
    warning = warning_line(result.summary)
    if warning is not None:
        typer.echo(warning, err=True)
    if json_out:
        typer.echo(json_text({**result.summary, "run_dir": str(result.run_dir)}))
    elif not quiet:
        print_table(result.summary, table)
    typer.echo(f"run folder: {result.run_dir}", err=quiet or json_out)
    if view:
        from oacli.commands.view import open_in_viewer

        open_in_viewer(result.run_dir)
    code = exit_code(result.summary.get("status", "ok"))
    if code:
        raise typer.Exit(code)
