"""The input files of the stages that read a previous stage's output, so a run folder's ``config.yaml`` reruns
its stage exactly (``oacli smooth RUN/config.yaml``, ``oacli estimate RUN/config.yaml``).

The commands record what ``--input`` / ``--telemetry`` named (absolute) in the resolved config they write; given
again on the command line, the option overrides the config. ``track``'s ``--reference`` is recorded the same
way in ``reference.file`` (``reference.source: file``).
"""

from __future__ import annotations

import os

from pydantic import Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import Section


class InputsConfig(Section):
    """Files a stage reads (recorded by the commands; relative paths resolve against the config's folder)."""

    smooth_input: str | None = Field(
        default=None, description="The MCAP whose /trajectory `oacli smooth` smooths (its --input)."
    )
    estimate_telemetry: str | None = Field(
        default=None, description="The track.mcap `oacli estimate` estimates from (its --telemetry)."
    )

    @field_validator("smooth_input", "estimate_telemetry", mode="after")
    @classmethod
    def _absolute(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value is None:
            return None
        if not value.strip():
            raise PydanticCustomError("oacli_path", "must not be empty")
        base = (info.context or {}).get("base_dir") or os.getcwd()
        return os.path.abspath(os.path.join(base, os.path.expanduser(value)))


def with_input(cfg, field: str, path: os.PathLike[str] | str | None, option: str):
    """``cfg`` with ``inputs.<field>`` set to ``path`` (absolute) when given; the path to use, or an error.

    Parameters
    ----------
    cfg : OacliConfig
        The loaded config.
    field : str
        ``smooth_input`` or ``estimate_telemetry``.
    path : path-like or None
        What the command-line option named (None: take the config's).
    option : str
        The option's name, for the message.

    Returns
    -------
    tuple of (OacliConfig, pathlib.Path)

    Raises
    ------
    ConfigError
        Neither the option nor the config names the file.
    """
    from pathlib import Path

    from oacli.errors import ConfigError

    if path is None:
        recorded = getattr(cfg.inputs, field)
        if recorded is None:
            raise ConfigError(f"{option}: missing (and the config's inputs.{field} is not set)")
        return cfg, Path(recorded)
    absolute = os.path.abspath(os.fspath(path))
    cfg = cfg.model_copy(update={"inputs": cfg.inputs.model_copy(update={field: absolute})})
    return cfg, Path(absolute)


__all__ = ["InputsConfig", "with_input"]
