"""``oacli config show CONFIG``: the resolved configuration (every default filled in, ``--set`` applied)."""

from __future__ import annotations

import typer

from oacli.commands.common import ConfigArgument, SetOption, load_config_with_seed, run_guarded

config_app = typer.Typer(help="Inspect configurations.", no_args_is_help=True)


@config_app.command("show")
def config_show(config: ConfigArgument, sets: SetOption = None) -> None:
    """Print CONFIG resolved: validated, every default filled in, --set overrides applied (YAML on stdout)."""
    from oacli.config import dump_config

    cfg = run_guarded(lambda: load_config_with_seed(config, None, sets))
    typer.echo(dump_config(cfg), nl=False)
