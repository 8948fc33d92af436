"""Headless screenshot check (issue 12 item 4): open each stage's ``.rrd`` in the bundled Rerun viewer without a
window and save a PNG of what a user sees on open.

rerun-sdk 0.41's ``rerun`` binary has ``--headless`` (an offscreen egui_kittest harness) and ``--screenshot-to``
(save a screenshot of the whole window and quit). Headless rendering still needs a GPU or a software renderer: on
Linux a Vulkan loader and driver, e.g. Debian's ``mesa-vulkan-drivers`` (lavapipe) with ``WGPU_BACKEND=vulkan``.
Without one the module is skipped at once with the reason.
"""

from __future__ import annotations

import ctypes.util
import glob
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.test_stage_plots import png_size, stage_runs  # noqa: F401 -- the tiny runs of every stage (fixture)

RERUN = Path(sys.executable).with_name("rerun")
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
TIMEOUT_S = 120.0


def vulkan_missing() -> str | None:
    """Why the headless viewer cannot render here (None when a Vulkan loader and a driver are present)."""
    if not RERUN.exists() and shutil.which("rerun") is None:
        return "the bundled rerun viewer binary (rerun-sdk) is not installed"
    if ctypes.util.find_library("vulkan") is None:
        return ("no Vulkan loader (libvulkan.so.1): the Rerun viewer's headless mode (rerun FILE.rrd --headless "
                "--screenshot-to PNG) needs a GPU or a software renderer; install Debian's mesa-vulkan-drivers "
                "and run with WGPU_BACKEND=vulkan")
    drivers = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if not drivers and not any(glob.glob(f"{d}/*.json") for d in ICD_DIRS):
        return ("a Vulkan loader but no Vulkan driver (no ICD in " + ", ".join(ICD_DIRS) + "): install Debian's "
                "mesa-vulkan-drivers (lavapipe, a software renderer) and run with WGPU_BACKEND=vulkan")
    return None


pytestmark = pytest.mark.skipif(vulkan_missing() is not None, reason=str(vulkan_missing()))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def screenshot(rrd: Path, png: Path) -> subprocess.CompletedProcess[str]:
    """``rerun RRD --headless --screenshot-to PNG`` bound to 127.0.0.1, in its own process group (the launcher can
    leave a viewer child: the whole group is ended on a timeout)."""
    cmd = [str(RERUN if RERUN.exists() else shutil.which("rerun")), str(rrd), "--headless", "--screenshot-to",
           str(png), "--window-size", "1280x800", "--bind", "127.0.0.1", "--port", str(free_port())]
    env = {**os.environ, "WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan")}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"rerun --headless --screenshot-to did not finish within {TIMEOUT_S:.0f} s:\n{out[-2000:]}")
    return subprocess.CompletedProcess(cmd, proc.returncode, out, "")


@pytest.mark.parametrize("stage", ["track", "plan", "smooth", "excite", "estimate"])
def test_each_recording_renders_headless_to_a_png(stage_runs, stage, tmp_path):  # noqa: F811
    rrd = stage_runs[stage] / f"{stage}.rrd"
    png = tmp_path / f"{stage}_viewer.png"
    result = screenshot(rrd, png)
    if "No graphics adapter was found" in result.stdout:
        pytest.skip("the Vulkan driver offers no adapter to wgpu (install mesa-vulkan-drivers, WGPU_BACKEND=vulkan)")
    assert result.returncode == 0 and png.exists(), result.stdout[-3000:]
    width, height = png_size(png)
    assert width >= 640 and height >= 400, (width, height)
    import matplotlib.image as mpimg

    pixels = np.asarray(mpimg.imread(png), dtype=float)
    assert pixels.std() > 0.01, "the screenshot is a uniform image (nothing drawn)"
