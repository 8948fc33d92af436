"""``--view``: open a run's Rerun recording in the bundled Rerun viewer, bound to 127.0.0.1 only."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def viewer_command(rrd: Path) -> list[str]:
    """The command line that opens ``rrd`` in the bundled Rerun viewer, its servers bound to 127.0.0.1.

    Parameters
    ----------
    rrd : Path
        The recording.

    Returns
    -------
    list of str
    """
    return [sys.executable, "-m", "rerun", str(rrd), "--bind", "127.0.0.1"]


def open_in_viewer(run_dir: Path) -> subprocess.Popen | None:
    """Spawn the viewer on the run folder's ``.rrd`` (detached; oacli does not wait for it).

    Parameters
    ----------
    run_dir : Path
        A run folder holding one ``<stage>.rrd`` (or ``mission.rrd``).

    Returns
    -------
    subprocess.Popen or None
        The viewer process; None (with a message on stderr) when the folder holds no recording.
    """
    rrds = sorted(Path(run_dir).glob("*.rrd"))
    if not rrds:
        sys.stderr.write(f"warning: --view: no .rrd in {run_dir}\n")
        return None
    return subprocess.Popen(viewer_command(rrds[0]), start_new_session=True, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
