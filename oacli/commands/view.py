"""``--view``: open a run's Rerun recording in the bundled Rerun viewer, bound to 127.0.0.1 only.

The run is complete before the viewer starts; a viewer that cannot open (no display, or it exits at once) is
reported on stderr with the command to open the recording later, and the command exits with code 1.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import typer

#: How long the viewer is watched after its start: one that dies within it (no display, no GPU) is reported [s].
STARTUP_WATCH_S = 2.0


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


def no_display_reason(env: dict[str, str] | None = None, platform: str = sys.platform) -> str | None:
    """Why a viewer window cannot open here (None when it can): on Linux, neither ``DISPLAY`` nor
    ``WAYLAND_DISPLAY`` is set.

    Parameters
    ----------
    env : dict, optional
        Environment (``os.environ`` by default).
    platform : str
        ``sys.platform``.

    Returns
    -------
    str or None
    """
    env = dict(os.environ) if env is None else env
    if platform.startswith("linux") and not (env.get("DISPLAY") or env.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    return None


def _fail(rrd: Path, reason: str) -> None:
    later = " ".join(viewer_command(rrd)[2:])
    sys.stderr.write(f"error: --view: the Rerun viewer cannot open: {reason}. The run is complete; open its "
                     f"recording on a machine with a display: {later}\n")
    raise typer.Exit(code=1)


def open_in_viewer(run_dir: Path) -> subprocess.Popen | None:
    """Spawn the viewer on the run folder's ``.rrd`` (detached; oacli does not wait for it once it runs).

    Parameters
    ----------
    run_dir : Path
        A run folder holding one ``<stage>.rrd`` (or ``mission.rrd``).

    Returns
    -------
    subprocess.Popen or None
        The viewer process; None (with a message on stderr) when the folder holds no recording.

    Raises
    ------
    typer.Exit
        Code 1, after a message on stderr, when the viewer cannot open a window (no display) or exits within
        :data:`STARTUP_WATCH_S` with an error.
    """
    rrds = sorted(Path(run_dir).glob("*.rrd"))
    if not rrds:
        sys.stderr.write(f"warning: --view: no .rrd in {run_dir}\n")
        return None
    reason = no_display_reason()
    if reason is not None:
        _fail(rrds[0], reason)
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(viewer_command(rrds[0]), start_new_session=True, stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=log)
        deadline = time.monotonic() + STARTUP_WATCH_S
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
        if proc.poll() not in (None, 0):
            log.seek(0)
            tail = log.read().decode(errors="replace").strip().splitlines()[-1:] or ["(no output)"]
            _fail(rrds[0], f"the viewer exited with code {proc.returncode}: {tail[0][:300]}")
    return proc
