"""The ``oacli`` command line: thin wrappers that load a config, call one stage runner and report.

Exit codes: 0 success (status ``ok``, or ``degraded`` with a warning); 1 internal error; 2 bad input (config, file,
option); 3 infeasible problem (no plan within the budget, empty tightened sets, no feasible excitation); 4 the run
was ``unsafe`` (the true state left a keep-in zone, entered a keep-out zone or broke a velocity or angular-rate
limit; the run folder is complete); 130 interrupted. Every status other than ``ok`` prints one ``warning:`` line on
stderr naming what happened (:mod:`oacli.status`). Errors are printed on stderr as one line per problem, never as a
traceback (set ``OACLI_DEBUG=1`` to see one). Progress goes to stderr, the results table to stdout.
"""

from __future__ import annotations

from typing import Annotated

import typer

from oacli import __version__
from oacli.commands.campaign import campaign
from oacli.commands.common import hide_flag_types
from oacli.commands.config_show import config_app
from oacli.commands.estimate import estimate
from oacli.commands.excite import excite
from oacli.commands.info import info
from oacli.commands.logs import logs_app
from oacli.commands.mission import mission
from oacli.commands.plan import plan
from oacli.commands.plots import plots
from oacli.commands.report import report
from oacli.commands.runs import runs_app
from oacli.commands.smooth import smooth
from oacli.commands.track import track

hide_flag_types()  # no '<bool>' after flags in --help


def plain_help_metavars() -> None:
    """``--help`` in the usual Unix style (issue 33): a required argument is ``CONFIG`` in the usage line, not
    ``{CONFIG}``; arguments show their metavar and no ``<path>`` / ``<str>`` tag beside it; an option without a
    metavar shows its type in capitals (``INT``, ``TEXT``, ``PATH``) instead of ``<int>``, ``<str>``.

    Wraps typer's ``TyperArgument._usage_display_name`` / ``display_type_rich`` and ``TyperOption.display_type_rich``
    (typer 0.2x); a no-op for what a typer release no longer has.
    """
    from typer.core import TyperArgument, TyperOption

    usage = getattr(TyperArgument, "_usage_display_name", None)
    if usage is not None and not getattr(usage, "_oacli_plain", False):
        def usage_display_name(self):  # type: ignore[no-untyped-def]
            name = usage(self)
            if self.required and name.startswith("{"):
                name = name[1:].replace("}", "", 1)
            return name

        usage_display_name._oacli_plain = True  # type: ignore[attr-defined]
        TyperArgument._usage_display_name = usage_display_name  # type: ignore[method-assign]
    if hasattr(TyperArgument, "display_type_rich"):
        TyperArgument.display_type_rich = lambda self, ctx: None  # type: ignore[method-assign]
    option_type = getattr(TyperOption, "display_type_rich", None)
    if option_type is not None and not getattr(option_type, "_oacli_plain", False):
        def display_type_rich(self, ctx):  # type: ignore[no-untyped-def]
            text = option_type(self, ctx)
            if isinstance(text, str) and text.startswith("<") and ">" in text:
                label, rest = text[1:].split(">", 1)
                return {"str": "TEXT"}.get(label, label.upper()) + rest
            return text

        display_type_rich._oacli_plain = True  # type: ignore[attr-defined]
        TyperOption.display_type_rich = display_type_rich  # type: ignore[method-assign]


plain_help_metavars()

app = typer.Typer(
    name="oacli",
    help="Plan, control and learn the model of a free-flying space robot (Astrobee) during on-orbit assembly.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
)

# Each command lives in its own module under oacli.commands (shared options and helpers in oacli.commands.common);
# registered here, in this order (the order of `oacli --help`).
app.command("campaign")(campaign)
app.command("estimate")(estimate)
app.command("excite")(excite)
app.command("mission")(mission)
app.command("plan")(plan)
app.command("smooth")(smooth)
app.command("track")(track)
app.command("plots")(plots)
app.command("report")(report)
app.command("info")(info)
app.add_typer(runs_app, name="runs")
app.add_typer(config_app, name="config")
app.add_typer(logs_app, name="logs")


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
    """oacli: mission | plan | smooth | excite | track | estimate."""


def main() -> None:
    """Console-script entry point (a signal outside a command's own handling prints one line and exits 130/143:
    :func:`oacli.signals.exit_on_signal`)."""
    from oacli.signals import exit_on_signal

    exit_on_signal()
    app()


if __name__ == "__main__":
    main()
