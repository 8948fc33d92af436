"""What every ``oacli`` command shares: the common options, the progress bar, config loading with ``--seed``,
the mapping of errors to one-line messages and exit codes, and the results table.

The commands (one module each in :mod:`oacli.commands`) import from here; :mod:`oacli.cli` registers them on the
Typer app.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from oacli.errors import ConfigError, OacliError
from oacli.signals import exit_code_for, interruption_message, terminate_like_interrupt

# Options every stage command shares (``Annotated`` aliases: ``out: OutOption = None``).
ConfigArgument = Annotated[Path, typer.Argument(help="YAML configuration file (see configs/).")]
OutOption = Annotated[Path | None, typer.Option("--out", "-o", help="Run folder (must not exist or be empty).")]
RunsDirOption = Annotated[Path, typer.Option("--runs-dir", help="Parent of automatically named run folders.")]
SeedOption = Annotated[int | None, typer.Option("--seed", help="Override the config's seed.")]
QuietOption = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no results table.")]


class Progress:
    """A minimal progress bar on stderr: redrawn in place on a terminal, a line every 25 % otherwise."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label = label
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.start = time.perf_counter()
        self._last_step = -1

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        if self.tty:
            step = int(fraction * 100)
            if step == self._last_step:
                return
            self._last_step = step
            bar = "#" * (step // 4) + "-" * (25 - step // 4)
            elapsed = time.perf_counter() - self.start
            sys.stderr.write(f"\r{self.label} [{bar}] {step:3d}% {elapsed:6.1f} s")
            if fraction >= 1.0:
                sys.stderr.write("\n")
            sys.stderr.flush()
        else:
            step = int(fraction * 4)
            if step != self._last_step:
                self._last_step = step
                sys.stderr.write(f"{self.label}: {25 * step}% ({time.perf_counter() - self.start:.1f} s)\n")
                sys.stderr.flush()


def fail(exc: BaseException) -> typer.Exit:
    """Print an error without a traceback and return the Exit to raise."""
    if isinstance(exc, OacliError):
        for line in exc.problems:
            typer.echo(f"error: {line}", err=True)
        return typer.Exit(exc.exit_code)
    if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, or SIGTERM/SIGHUP (oacli.signals): exit 130 / 143
        typer.echo(f"error: {interruption_message(exc)}", err=True)
        return typer.Exit(exit_code_for(exc))
    if os.environ.get("OACLI_DEBUG"):
        raise exc
    typer.echo(f"internal error: {type(exc).__name__}: {exc} (set OACLI_DEBUG=1 for a traceback)", err=True)
    return typer.Exit(1)


def format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {format_value(v)}" for k, v in value.items())
    return str(value)


def print_table(summary: dict[str, Any], keys: list[str]) -> None:
    """Print selected summary entries as an aligned two-column table on stdout."""
    width = max(len(k) for k in keys)
    for key in keys:
        if key in summary:
            typer.echo(f"{key:<{width}}  {format_value(summary[key])}")


def load_config_with_seed(config: Path, seed: int | None):
    """Load a config file and apply a ``--seed`` override (validated like the config's own seed)."""
    from oacli.config import load_config

    cfg = load_config(config)
    if seed is not None:
        if seed < 0:
            raise ConfigError(f"--seed: {seed}: must be >= 0")
        cfg = cfg.model_copy(update={"seed": seed})
    return cfg


def run_guarded(action: Callable[[], Any]) -> Any:
    """Run a command's action, mapping every error to a clear message and an exit code (no traceback)."""
    try:
        with terminate_like_interrupt():
            return action()
    except (OacliError, KeyboardInterrupt, Exception) as exc:  # every error is mapped to an exit code
        raise fail(exc) from None


def run_stage_command(action: Callable[[], Any], table: list[str], quiet: bool) -> None:
    """Run a stage command's action (errors mapped by :func:`run_guarded`), then print its results table on
    stdout (unless ``quiet``) and the run folder (on stderr when quiet, so stdout stays empty).

    A status other than ``ok`` prints one ``warning:`` line on stderr (even when quiet) and exits with its code
    (:data:`oacli.status.EXIT_CODES`: ``degraded`` 0, ``unsafe`` 4).
    """
    from oacli.status import exit_code, warning_line

    result = run_guarded(action)
    warning = warning_line(result.summary)
    if warning is not None:
        typer.echo(warning, err=True)
    if not quiet:
        print_table(result.summary, table)
    typer.echo(f"run folder: {result.run_dir}", err=quiet)
    code = exit_code(result.summary.get("status", "ok"))
    if code:
        raise typer.Exit(code)
