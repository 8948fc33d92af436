"""Errors that end a command with a clear message instead of a traceback.

The CLI maps :class:`OacliError` subclasses to an exit code and prints ``str(error)`` (one line per problem)
on stderr. The algorithm core raises them for bad *input* (a start inside an obstacle, an empty tightened set);
programming errors stay ordinary exceptions.
"""

from __future__ import annotations


class OacliError(Exception):
    """Base class: a problem the user can fix. ``exit_code`` is the process exit code the CLI uses."""

    exit_code = 1

    def __init__(self, problems: str | list[str]):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


class ConfigError(OacliError):
    """The configuration file or a command-line value is malformed or non-physical (exit code 2)."""

    exit_code = 2


class InputError(OacliError):
    """An input file (reference, previous stage's MCAP) is missing, unreadable or inconsistent (exit code 2)."""

    exit_code = 2


class InfeasibleError(OacliError):
    """The problem as posed has no solution (unreachable goal, empty tightened set) (exit code 3)."""

    exit_code = 3
