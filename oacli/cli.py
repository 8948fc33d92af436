"""The ``oacli`` command line: thin wrappers that load a config, call one stage runner and report.

Exit codes: 0 success (status ``ok``, or ``degraded`` with a warning); 1 internal error; 2 bad input (config, file,
option); 3 infeasible problem (no plan within the budget, empty tightened sets, no feasible excitation); 4 the run
was ``unsafe`` (the true state left a keep-in zone, entered a keep-out zone or broke a velocity or angular-rate
limit; the run folder is complete); 130 interrupted. Every status other than ``ok`` prints one ``warning:`` line on
stderr naming what happened (:mod:`oacli.status`). Errors are printed on stderr as one line per problem, never as a
traceback (set ``OACLI_DEBUG=1`` to see one). Progress goes to stderr, the results table to stdout.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from oacli import __version__
from oacli.errors import ConfigError, OacliError

app = typer.Typer(
    name="oacli",
    help="Plan, control and learn the model of a free-flying space robot (Astrobee) during on-orbit assembly.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


# Options every stage command shares (``Annotated`` aliases: ``out: OutOption = None``).
ConfigArgument = Annotated[Path, typer.Argument(help="YAML configuration file (see configs/).")]
OutOption = Annotated[Path | None, typer.Option("--out", "-o", help="Run folder (must not exist or be empty).")]
RunsDirOption = Annotated[Path, typer.Option("--runs-dir", help="Parent of automatically named run folders.")]
SeedOption = Annotated[int | None, typer.Option("--seed", help="Override the config's seed.")]
QuietOption = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no results table.")]


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"oacli {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """oacli: plan | smooth | excite | track | estimate."""


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


def _fail(exc: BaseException) -> typer.Exit:
    """Print an error without a traceback and return the Exit to raise."""
    if isinstance(exc, OacliError):
        for line in exc.problems:
            typer.echo(f"error: {line}", err=True)
        return typer.Exit(exc.exit_code)
    if isinstance(exc, KeyboardInterrupt):
        typer.echo("error: interrupted", err=True)
        return typer.Exit(130)
    if os.environ.get("OACLI_DEBUG"):
        raise exc
    typer.echo(f"internal error: {type(exc).__name__}: {exc} (set OACLI_DEBUG=1 for a traceback)", err=True)
    return typer.Exit(1)


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_format_value(v)}" for k, v in value.items())
    return str(value)


def print_table(summary: dict[str, Any], keys: list[str]) -> None:
    """Print selected summary entries as an aligned two-column table on stdout."""
    width = max(len(k) for k in keys)
    for key in keys:
        if key in summary:
            typer.echo(f"{key:<{width}}  {_format_value(summary[key])}")


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
        return action()
    except (OacliError, KeyboardInterrupt, Exception) as exc:  # every error is mapped to an exit code
        raise _fail(exc) from None


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


def main() -> None:
    """Console-script entry point."""
    app()


# Each command lives in its own module under oacli.commands and registers itself on ``app``.
from oacli.commands import estimate as _estimate  # noqa: E402, F401
from oacli.commands import excite as _excite  # noqa: E402, F401
from oacli.commands import plan as _plan  # noqa: E402, F401
from oacli.commands import smooth as _smooth  # noqa: E402, F401
from oacli.commands import track as _track  # noqa: E402, F401

if __name__ == "__main__":
    main()
