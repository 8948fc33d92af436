"""Write a campaign's aggregates from its manifest: ``summary.json``, ``plots/``, ``campaign.rrd``, ``campaign.mcap``.

Everything here is derived from ``manifest.jsonl`` and ``runs.json`` and may be rewritten (after ``--resume``);
``summary.json`` is written last.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from oacli.campaign import manifest
from oacli.campaign.aggregate import summarize
from oacli.campaign.driver import load_existing
from oacli.campaign.outputs import write_mcap, write_plots, write_recording
from oacli.io.atomic import write_text_atomic
from oacli.io.folder_lock import folder_lock
from oacli.io.jsonsafe import to_json_safe


def finalize(folder: Path, *, wall_time_s: float | None = None, executor: str | None = None) -> dict[str, Any]:
    """Aggregate the campaign in ``folder`` and write its outputs.

    Parameters
    ----------
    folder : Path
        The campaign folder.
    wall_time_s : float, optional
        The driver's wall time, recorded.
    executor : str, optional
        The executor used, recorded.

    Returns
    -------
    dict
        The summary.

    Raises
    ------
    oacli.io.folder_lock.FolderBusy
        Another oacli process runs or finalizes this campaign (exit 2).
    """
    start = time.perf_counter()
    folder = Path(folder)
    with folder_lock(folder, "campaign"):  # one process writes the outputs (a second exits 2, naming it)
        return _finalize(folder, start, wall_time_s, executor)


def _finalize(folder: Path, start: float, wall_time_s: float | None, executor: str | None) -> dict[str, Any]:
    campaign = load_existing(folder)
    final = manifest.final_states(manifest.read(folder))
    index = json.loads((folder / "runs.json").read_text())["index"]
    summary = summarize(campaign.config, final, index)
    summary["status"] = "complete" if summary["missing"] == 0 else "incomplete"
    summary["files"] = {"manifest": manifest.MANIFEST, "config": "campaign.yaml", "base": "base.yaml",
                        "plots": write_plots(folder, final, summary)}
    write_recording(folder / "campaign.rrd", final, campaign.config.name)
    write_mcap(folder / "campaign.mcap", final, summary, (folder / "campaign.yaml").read_text())
    summary["files"].update(rrd="campaign.rrd", mcap="campaign.mcap")
    summary["executor"] = executor
    summary["wall_time_s"] = wall_time_s
    summary["outputs_wall_time_s"] = time.perf_counter() - start
    write_text_atomic(folder / "summary.json", json.dumps(to_json_safe(summary), indent=1, allow_nan=False))
    return summary


__all__ = ["finalize"]
