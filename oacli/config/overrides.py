"""``--set KEY=VALUE`` overrides applied to plain config data (the stage commands, ``oacli mission`` and the campaign
files share them)."""

from __future__ import annotations

from typing import Any

from oacli.errors import ConfigError


def apply_overrides(data: dict[str, Any], sets: list[str] | None) -> dict[str, Any]:
    """Apply ``--set KEY=VALUE`` overrides (dotted paths, YAML values) to plain config data.

    Parameters
    ----------
    data : dict
        The configuration as plain data (changed in place and returned).
    sets : list of str, optional
        ``section.field=value`` items; the value is read as YAML (``15``, ``[1, 2, 3]``, ``tube``).

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        An item without ``=`` or an empty path, or a path through a value that is not a section.
    """
    from oacli.config import parse_yaml_value  # the package imports this module's users; import late

    for item in sets or ():
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise ConfigError(f"--set {item}: expected KEY=VALUE with a dotted key, e.g. robot.mass_kg=15")
        # The loader of config files: YAML 1.2 scalars (``1:30`` stays text, ``1e3`` is a number), size caps.
        value = parse_yaml_value(text, f"--set {key}") if text.strip() else None
        node = data
        parts = key.split(".")
        for depth, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"--set {key}: {'.'.join(parts[:depth + 1])} is a value, not a section")
            node = child
        node[parts[-1]] = value
    return data
