"""Run folders: ``runs/<name>-<UTC timestamp>/`` holding the resolved config, one MCAP + one Rerun recording
per stage, and ``summary.json``.

A run folder is *complete* when its ``summary.json`` exists with ``"status": "ok"``; ``summary.json`` is written
last, atomically. A run that fails after its folder was created gets a ``summary.json`` with
``"status": "failed"`` and the error, so it never looks complete. Existing folders are never overwritten.
"""

from __future__ import annotations

import datetime as _dt
import json
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import oacli
from oacli.errors import InputError
from oacli.io.atomic import write_text_atomic
from oacli.io.jsonsafe import to_json_safe


def utc_stamp(now: _dt.datetime | None = None) -> str:
    """UTC time stamp for folder names, e.g. ``20261122T011530Z``."""
    now = now or _dt.datetime.now(_dt.UTC)
    return now.strftime("%Y%m%dT%H%M%SZ")


def create_run_dir(name: str, *, out: Path | None = None, runs_root: Path = Path("runs")) -> Path:
    """Create and return a new, empty run folder.

    Parameters
    ----------
    name : str
        Run name prefix (from the config).
    out : Path, optional
        Exact folder to use. It must not exist, or be an empty folder.
    runs_root : Path
        Parent of automatically named folders ``<name>-<UTC stamp>`` (a ``-2``, ``-3`` … suffix is added when
        two runs start in the same second).

    Raises
    ------
    InputError
        When ``out`` exists and is not an empty folder (runs are never overwritten).
    """
    if out is not None:
        out = Path(out)
        if out.exists():
            if not out.is_dir() or any(out.iterdir()):
                raise InputError(f"--out {out}: already exists and is not empty; runs are never overwritten")
            return out
        out.mkdir(parents=True)
        return out
    runs_root = Path(runs_root)
    runs_root.mkdir(parents=True, exist_ok=True)
    base = f"{name}-{utc_stamp()}"
    for i in range(1, 1000):
        candidate = runs_root / (base if i == 1 else f"{base}-{i}")
        try:
            candidate.mkdir()
        except FileExistsError:
            continue
        return candidate
    raise InputError(f"{runs_root}: could not create a new run folder for {base}")


def git_commit() -> str:
    """Commit hash of the oacli checkout, or ``"unknown"`` when not installed from a git checkout."""
    src = Path(oacli.__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    commit = out.stdout.strip()
    if out.returncode != 0 or not commit:
        return "unknown"
    dirty = subprocess.run(
        ["git", "-C", str(src), "status", "--porcelain", "--untracked-files=no"],
        capture_output=True, text=True, timeout=5, check=False,
    )
    return commit + ("-dirty" if dirty.returncode == 0 and dirty.stdout.strip() else "")


def write_summary(run_dir: Path, summary: Mapping[str, Any], filename: str = "summary.json") -> Path:
    """Write ``summary`` as strict JSON (NaN → null), atomically; returns the path."""
    path = Path(run_dir) / filename
    write_text_atomic(path, json.dumps(to_json_safe(summary), indent=2, allow_nan=False) + "\n")
    return path
