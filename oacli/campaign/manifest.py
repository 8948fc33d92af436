"""The campaign's append-only ``manifest.jsonl``: one JSON line per finished attempt, written by the driver alone.

Each line is written with one ``write`` and fsynced, so a killed driver loses at most the line being written; a
cut last line is ignored when reading (and the next append starts on a new line). A run's state is its last line
with a final status: ``ok``, ``degraded``, ``unsafe`` (the job ran; its own status), ``failed`` (the simulation
raised; not retried) or ``infra_failed`` (the worker died, timed out or ran out of memory more often than the
retries allow). Lines with status ``retry`` record an infrastructure failure that was retried.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from oacli.io.jsonsafe import to_json_safe

MANIFEST = "manifest.jsonl"
COMPLETED = ("ok", "degraded", "unsafe")
"""The job ran to its end (its own status)."""
FAILED = "failed"
INFRA_FAILED = "infra_failed"
RETRY = "retry"
FINAL = (*COMPLETED, FAILED, INFRA_FAILED)


def append(campaign_dir: Path, record: dict[str, Any]) -> None:
    """Append ``record`` as one line and fsync.

    Parameters
    ----------
    campaign_dir : Path
        The campaign folder.
    record : dict
        Plain data (NaN becomes null).
    """
    path = Path(campaign_dir) / MANIFEST
    line = json.dumps(to_json_safe(record), sort_keys=True, allow_nan=False) + "\n"
    with open(path, "a+b") as fh:
        fh.seek(0, os.SEEK_END)
        if fh.tell() > 0:
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) != b"\n":  # a line cut by a killed driver: start a new one
                line = "\n" + line
        fh.write(line.encode())
        fh.flush()
        os.fsync(fh.fileno())


def read(campaign_dir: Path) -> list[dict[str, Any]]:
    """Every complete line of the manifest, in order (a cut or garbled line is skipped).

    Parameters
    ----------
    campaign_dir : Path

    Returns
    -------
    list of dict
    """
    path = Path(campaign_dir) / MANIFEST
    if not path.exists():
        return []
    out = []
    for raw in path.read_bytes().splitlines():
        try:
            rec = json.loads(raw)
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        if isinstance(rec, dict) and isinstance(rec.get("k"), int):
            out.append(rec)
    return out


def final_states(records: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    """Each run's last record with a final status.

    Parameters
    ----------
    records : list of dict
        :func:`read`'s lines.

    Returns
    -------
    dict of int to dict
    """
    out: dict[int, dict[str, Any]] = {}
    for rec in records:
        if rec.get("status") in FINAL:
            out[rec["k"]] = rec
    return out


__all__ = ["COMPLETED", "FAILED", "FINAL", "INFRA_FAILED", "MANIFEST", "RETRY", "append", "final_states", "read"]
