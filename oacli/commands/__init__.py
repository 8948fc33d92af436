"""CLI commands, one module each; shared options and helpers in :mod:`oacli.commands.common`.

:mod:`oacli.cli` registers the commands on its Typer app.
"""
