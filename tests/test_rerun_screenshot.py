"""The recordings as a reviewer sees them in the real Rerun viewer (issues 12 and 33), rendered headless.

Each test opens recordings in one headless viewer (``rerun --headless``), driven through ``rerun viewer-mcp``
(:mod:`tests.rerun_viewer`): for every recording it puts that recording on screen, reads the views the viewer lays
out for it (its blueprint state), checks that each one has data on the timeline the viewer shows, and saves a
screenshot (set ``OACLI_SCREENSHOTS=<folder>`` to keep them). Pairs of one stage's two kinds (standard vs tube MPC
tracks, offline vs RATTLE excitations) are opened in one viewer: each must keep its own layout.

Headless rendering needs a GPU or a software renderer: on Linux a Vulkan loader and driver, e.g. Debian's
``mesa-vulkan-drivers`` (lavapipe) with ``WGPU_BACKEND=vulkan``. Without one the module is skipped with the reason.
"""

from __future__ import annotations

import ctypes.util
import glob
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from oacli.cli import app
from oacli.io.rerun.read import (
    read_application_id,
    read_blueprint_views,
    read_entities_shown_on,
    read_recording_scalars,
)
from tests.rerun_viewer import RERUN, HeadlessViewer, Shown, ViewerError
from tests.test_cli_excite import small_iss
from tests.test_stage_plots import stage_runs  # noqa: F401 -- the tiny runs of every stage (fixture)

REPO = Path(__file__).resolve().parents[1]
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")


def vulkan_missing() -> str | None:
    """Why the headless viewer cannot render here (None when a Vulkan loader and a driver are present)."""
    if not RERUN.exists() and shutil.which("rerun") is None:
        return "the bundled rerun viewer binary (rerun-sdk) is not installed"
    if ctypes.util.find_library("vulkan") is None:
        return ("no Vulkan loader (libvulkan.so.1): the Rerun viewer's headless mode needs a GPU or a software "
                "renderer; install Debian's mesa-vulkan-drivers and run with WGPU_BACKEND=vulkan")
    drivers = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if not drivers and not any(glob.glob(f"{d}/*.json") for d in ICD_DIRS):
        return ("a Vulkan loader but no Vulkan driver (no ICD in " + ", ".join(ICD_DIRS) + "): install Debian's "
                "mesa-vulkan-drivers (lavapipe, a software renderer) and run with WGPU_BACKEND=vulkan")
    return None


pytestmark = pytest.mark.skipif(vulkan_missing() is not None, reason=str(vulkan_missing()))

#: Panels (view origins) a recording kind must show, beyond "every view of its stored blueprint".
TUBE_PANELS = {"metrics/tube/force_nominal_N", "metrics/tube/force_ancillary_N", "metrics/tube/tube_margin",
               "metrics/tube/disturbance_position_m", "metrics/tube/disturbance_velocity_mps",
               "metrics/tube/nominal_velocity_mps", "metrics/tube/w_violation"}
TRACK_PANELS = {"world", "log", "metrics/position_error_m", "metrics/force_N", "metrics/torque_Nm"}
EXPECTED: dict[str, set[str]] = {
    "oacli-track-mpc": TRACK_PANELS,
    "oacli-track-tube": TRACK_PANELS | TUBE_PANELS,
    "oacli-excite-offline": {"world", "charts/criterion", "metrics/information", "metrics/force_N"},
    "oacli-excite-rattle": {"world", "metrics/gamma", "metrics/information", "metrics/force_N"},
    "oacli-plan": {"world", "charts/solution_cost", "metrics/force_N", "metrics/velocity_mps"},
    "oacli-estimate": {"world", "log", "metrics/innovation_d2"},
    "oacli-smooth": {"world", "charts/cost", "charts/polish_length_m", "metrics/force_N"},
    "oacli-campaign": {"campaign/status", "campaign/log", "campaign/rms_position_error_mm",
                       "histograms/rms_position_error_mm"},
    "oacli-mission": {"world", "metrics/position_error", "estimate/mass_kg", "metrics/force_fraction"},
}
#: Panels a kind must not show (the other kind's).
ABSENT: dict[str, set[str]] = {"oacli-track-mpc": TUBE_PANELS, "oacli-excite-offline": {"metrics/gamma"},
                               "oacli-excite-rattle": {"charts/criterion"}}


def run_cli(*args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result


@pytest.fixture(scope="module")
def kinds(stage_runs, tmp_path_factory) -> dict[str, Path]:  # noqa: F811
    """One recording of every kind: the shared stage runs plus a tube-MPC track and a RATTLE excitation."""
    tmp = tmp_path_factory.mktemp("kinds")
    run_cli("track", REPO / "configs" / "iss_reswarm_tube.yaml", "--out", tmp / "tube", "--quiet")
    rattle = small_iss(tmp / "rattle.yaml", rattle={"duration_s": 24.0, "replan_period_s": 12.0,
                                                    "limits": {"force_N": [0.15] * 3, "torque_Nm": [0.015] * 3}})
    run_cli("excite", rattle, "--method", "rattle", "--out", tmp / "rattle", "--quiet")
    return {"track-mpc": stage_runs["track"] / "track.rrd", "track-tube": tmp / "tube" / "track.rrd",
            "excite-offline": stage_runs["excite"] / "excite.rrd", "excite-rattle": tmp / "rattle" / "excite.rrd",
            "plan": stage_runs["plan"] / "plan.rrd", "smooth": stage_runs["smooth"] / "smooth.rrd",
            "estimate": stage_runs["estimate"] / "estimate.rrd"}


def views_without_data(rrd: Path, shown: Shown) -> list[str]:
    """The views on screen with nothing to draw on the viewer's timeline: no entity at or below their origin has
    static data or rows on it (time series views: no ``Scalars`` on it)."""
    assert shown.timeline, "the viewer shows no timeline"
    entities = read_entities_shown_on(rrd, shown.timeline)
    scalars = set(read_recording_scalars(rrd, timeline=shown.timeline))
    empty = []
    for view in shown.views:
        origin = str(view["origin"]).strip("/")
        pool = scalars if view["class"] == "TimeSeries" else entities
        if not any(origin == "" or e == origin or e.startswith(origin + "/") for e in pool):
            empty.append(f"{view['name']} ({origin})")
    return empty


def check_screenshot(png: Path) -> None:
    import matplotlib.image as mpimg

    pixels = np.asarray(mpimg.imread(png), dtype=float)
    assert pixels.shape[0] >= 800 and pixels.shape[1] >= 1280, pixels.shape
    assert pixels.std() > 0.01, f"{png}: a uniform image (nothing drawn)"
    keep = os.environ.get("OACLI_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(png, Path(keep) / png.name)


def orange(r: np.ndarray, g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pixels of the flown / planned path's orange (255, 170, 40)."""
    return (np.abs(r - 255) < 40) & (np.abs(g - 170) < 40) & (np.abs(b - 40) < 40)


def cyan_or_blue(r: np.ndarray, g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pixels of the tube's nominal path (cyan, dimmed by the tube drawn over it) or the reference (blue)."""
    return (g - r > 40) & (b - r > 40)


#: Pixels of the path each kind's 3-D view is framed on.
PATH_PIXELS = {"oacli-track-mpc": orange, "oacli-track-tube": cyan_or_blue, "oacli-smooth": orange,
               "oacli-plan": orange}


def drawn_extent(png: Path, which) -> float:
    """How much of an image the pixels ``which(r, g, b)`` span: the larger of their width and height spans, as a
    fraction of the image's."""
    import matplotlib.image as mpimg

    pixels = np.asarray(mpimg.imread(png), dtype=float)[..., :3] * 255.0
    ys, xs = np.nonzero(which(pixels[..., 0], pixels[..., 1], pixels[..., 2]))
    if xs.size == 0:
        return 0.0
    return max(np.ptp(xs) / pixels.shape[1], np.ptp(ys) / pixels.shape[0])


def open_together(rrds: dict[str, Path], workdir: Path) -> dict[str, Shown]:
    """Open ``rrds`` (label → file) in one headless viewer, in that order; what each shows, screenshots taken.

    The 3-D view of a kind in :data:`PATH_PIXELS` must open framed on the path: it spans at least a fifth of the
    view (framed on the whole ISS module, a track's path spanned 3-4 %)."""
    by_app = {read_application_id(p): (label, p) for label, p in rrds.items()}
    assert len(by_app) == len(rrds), f"two recordings share an application id: {sorted(by_app)}"
    out: dict[str, Shown] = {}
    no_adapter = "the Vulkan driver offers no adapter to wgpu (install mesa-vulkan-drivers, WGPU_BACKEND=vulkan)"
    try:
        viewer = HeadlessViewer(list(rrds.values()), workdir)
    except ViewerError as exc:
        if "No graphics adapter was found" in str(exc):
            pytest.skip(no_adapter)
        raise
    with viewer:
        try:
            state = viewer.wait_loaded(len(rrds))
        except ViewerError as exc:
            if "No graphics adapter was found" in str(exc):
                pytest.skip(no_adapter)
            raise
        for recording in state["recordings"]:
            shown = viewer.show(recording, state)
            label, rrd = by_app[shown.application_id]
            png = viewer.screenshot(workdir / f"{label}.png")
            out[label] = shown
            check_screenshot(png)
            stored = {str(v["origin"]).strip("/") for v in read_blueprint_views(rrd)}
            assert shown.origins() == stored, (label, shown.origins() ^ stored)
            assert EXPECTED[shown.application_id] <= shown.origins(), (label, EXPECTED[shown.application_id]
                                                                       - shown.origins())
            assert not ABSENT.get(shown.application_id, set()) & shown.origins(), label
            assert views_without_data(rrd, shown) == [], label
            if shown.application_id in PATH_PIXELS:
                (world,) = [v for v in shown.views if v["class"] == "3D"]
                view_png = viewer.screenshot(workdir / f"{label}_3d.png", view_id=world["view_id"])
                extent = drawn_extent(view_png, PATH_PIXELS[shown.application_id])
                assert extent > 0.2, f"{label}: the path spans {extent:.1%} of the 3-D view"
    assert set(out) == set(rrds)
    return out


def test_mpc_then_tube_tracks_keep_their_layouts_in_one_viewer(kinds, tmp_path):
    shown = open_together({"track-mpc": kinds["track-mpc"], "track-tube": kinds["track-tube"]}, tmp_path)
    assert len(shown["track-tube"].views) > len(shown["track-mpc"].views)
    for label in ("track-mpc", "track-tube"):
        assert any(n.startswith("World (iss frame)") for n in shown[label].names())


def test_offline_then_rattle_excitations_keep_their_layouts_in_one_viewer(kinds, tmp_path):
    open_together({"excite-offline": kinds["excite-offline"], "excite-rattle": kinds["excite-rattle"]}, tmp_path)


def test_plan_smooth_estimate_and_campaign_open_with_every_panel_showing_data(kinds, tmp_path):
    from tests.test_campaign import run_with, tiny_campaign

    campaign = tiny_campaign(tmp_path, runs=3)
    run_with(campaign, tmp_path / "campaign", "serial", workers=1, outputs=True)
    shown = open_together({"plan": kinds["plan"], "smooth": kinds["smooth"], "estimate": kinds["estimate"],
                           "campaign": tmp_path / "campaign" / "campaign.rrd"}, tmp_path)
    assert shown["campaign"].timeline == "run" and shown["plan"].timeline == "mission_time"


def test_mission_opens_with_every_panel_showing_data(mission_run, tmp_path):
    shown = open_together({"mission": mission_run[0] / "mission.rrd"}, tmp_path)
    assert any(n.startswith("World (iss frame)") for n in shown["mission"].names())
