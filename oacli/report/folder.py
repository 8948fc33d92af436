"""What kind of folder a report is asked for, and whether it holds what a report needs.

A *campaign* folder has ``campaign.yaml`` and ``runs.json``; any other run folder has ``summary.json`` whose
``stage`` is ``mission`` (a mission) or a stage's name. Bad input ends with one line (:class:`oacli.errors.InputError`,
exit 2): not a folder, not a run folder, no ``summary.json`` (an unfinished run), a ``summary.json`` that is not a
JSON object. A cut MCAP or PNG is refused when it is read (:mod:`oacli.report.mission`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from oacli.errors import InputError

Kind = Literal["mission", "campaign", "stage"]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_summary(folder: Path) -> dict[str, Any]:
    """``folder/summary.json`` as a dict.

    Raises
    ------
    InputError
        Missing, unreadable or not a JSON object.
    """
    path = Path(folder) / "summary.json"
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{folder}: no summary.json: the run has not finished (resume it first)") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not readable as JSON ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: not a JSON object")
    return data


def folder_kind(folder: Path) -> Kind:
    """``mission``, ``campaign`` or ``stage`` (module docstring).

    Parameters
    ----------
    folder : Path

    Returns
    -------
    str

    Raises
    ------
    InputError
        Not a folder, or not a run or campaign folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder (give a run folder or a campaign folder)")
    if (folder / "campaign.yaml").is_file() and (folder / "runs.json").is_file():
        return "campaign"
    if not (folder / "summary.json").is_file() and not (folder / "config.yaml").is_file():
        raise InputError(f"{folder}: not a run folder (no summary.json, no config.yaml)")
    summary = read_summary(folder)
    return "mission" if summary.get("stage") == "mission" else "stage"


def read_png(path: Path) -> bytes:
    """A PNG's bytes, checked to be a whole PNG (signature and the closing IEND chunk).

    Raises
    ------
    InputError
        Missing, not a PNG, or cut.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: not readable ({exc.strerror or type(exc).__name__})") from None
    if not data.startswith(PNG_SIGNATURE) or b"IEND" not in data[-16:]:
        raise InputError(f"{path}: not a whole PNG (cut or another format)")
    return data


__all__ = ["Kind", "folder_kind", "read_png", "read_summary"]
