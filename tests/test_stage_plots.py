"""Each stage's PNG plots: written into the run folder, listed in summary.json, valid PNGs of a
sensible size; the track error plot draws exactly the series behind the summary's RMS / max; a failing figure
becomes a summary warning and never loses the run."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from typer.testing import CliRunner

import oacli.io.plots.common as plot_common
import oacli.io.plots.estimate as estimate_plots
import oacli.io.plots.excite as excite_plots
import oacli.io.plots.plan as plan_plots
import oacli.io.plots.track as track_plots
import oacli.io.plots.track_views as track_views
from oacli.cli import app
from oacli.io.plots.common import decimate, guarded_plots
from tests.plot_checks import PNGS
from tests.test_cli_estimate import payload_config
from tests.test_cli_excite import small_iss
from tests.test_cli_plan_smooth import small_config

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
runner = CliRunner()


def run_cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from the IHDR chunk (a valid PNG starts with the signature and IHDR)."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE, path
    assert data[12:16] == b"IHDR", path
    assert data[-8:-4] == b"IEND", path
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


@pytest.fixture(scope="module")
def stage_runs(tmp_path_factory) -> dict[str, Path]:
    """Tiny runs of every stage through the CLI; the track error figure's lines are captured before saving."""
    tmp = tmp_path_factory.mktemp("plots")
    captured: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    real_save = track_plots.save_png

    layouts: dict[str, list[str]] = {}

    def capture(fig, path):
        captured[Path(path).name] = [(ln.get_label(), np.asarray(ln.get_xdata(), dtype=float),
                                      np.asarray(ln.get_ydata(), dtype=float))
                                     for ax in fig.axes for ln in ax.get_lines()]
        return check_layout(fig, path)

    def check_layout(fig, path):
        plot_common.lay_out(fig)  # as save_png does, in its order (it closes the figure: measure first)
        fig.canvas.draw()
        layouts[f"{Path(path).parent.name}/{Path(path).name}"] = layout_problems(fig)
        return real_save(fig, path)

    payload = payload_config(tmp / "payload.yaml")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(track_plots, "save_png", capture)
        for module in (estimate_plots, excite_plots, plan_plots, track_views):
            mp.setattr(module, "save_png", check_layout)
        mp.setattr(plot_common, "save_png", check_layout)  # plot_inputs
        result = run_cli("track", payload, "--out", tmp / "track", "--quiet")
        assert result.exit_code == 0, result.output
        result = run_cli("estimate", payload, "--telemetry", tmp / "track" / "track.mcap", "--method", "batch",
                         "--out", tmp / "estimate", "--quiet")
        assert result.exit_code == 0, result.output
        s1 = small_config(tmp, max_iterations=150, shortcut={"tries": 30})
        result = run_cli("plan", s1, "--out", tmp / "plan", "--quiet", "--seed", "4")
        assert result.exit_code == 0, result.output
        result = run_cli("smooth", s1, "--input", tmp / "plan" / "plan.mcap", "--out", tmp / "smooth", "--quiet")
        assert result.exit_code == 0, result.output
        excite = small_iss(tmp / "excite.yaml", steps=20, duration_s=20.0, scp={"max_iterations": 4})
        result = run_cli("excite", excite, "--out", tmp / "excite", "--quiet")
        assert result.exit_code == 0, result.output
    return {"track": tmp / "track", "estimate": tmp / "estimate", "plan": tmp / "plan", "smooth": tmp / "smooth",
            "excite": tmp / "excite", "captured": captured, "layouts": layouts}  # type: ignore[dict-item]


def layout_problems(fig) -> list[str]:
    """What a drawn figure's fixed layout got wrong: a title, label, tick label or legend cut by the figure's edge,
    or two axes' decorations (tick labels, titles, outside legends) overlapping."""
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    problems = []
    boxes = []
    for i, ax in enumerate(fig.axes):
        box = ax.get_tightbbox(renderer)  # the axes with its tick labels, labels, title and legend
        boxes.append(box)
        if box.x0 < -1 or box.y0 < -1 or box.x1 > width + 1 or box.y1 > height + 1:
            problems.append(f"axes {i} {ax.get_title(loc='left')!r} cut: {box.bounds} in {width}x{height}")
    for leg in fig.legends:
        box = leg.get_window_extent(renderer)
        if box.y0 < -1 or box.x0 < -1 or box.x1 > width + 1:
            problems.append(f"figure legend cut: {box.bounds}")
        boxes.append(box)
    if fig._suptitle is not None:
        boxes.append(fig._suptitle.get_window_extent(renderer))
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            dx = min(a.x1, b.x1) - max(a.x0, b.x0)
            dy = min(a.y1, b.y1) - max(a.y0, b.y0)
            if dx > 2 and dy > 2:
                problems.append(f"boxes {i} and {j} overlap by {dx:.0f} x {dy:.0f} px")
    return problems


def test_every_stage_png_is_laid_out_within_the_figure_without_overlaps(stage_runs):
    layouts = stage_runs["layouts"]
    assert len(layouts) == sum(len(v) for v in PNGS.values())
    assert {k: v for k, v in layouts.items() if v} == {}


def test_decimate_keeps_the_extremes_and_short_series():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 100.0, 50_001)
    y = np.cumsum(rng.normal(size=t.size))
    y[12_345] = 1e3  # a one-sample spike
    y[40_000] = np.nan  # a gap
    x_d, y_d = decimate(t, y, 3000)
    assert len(x_d) <= 3200 and x_d[0] == t[0] and x_d[-1] == t[-1]
    assert np.all(np.diff(x_d) > 0)  # a subsequence of the samples, in order
    assert np.nanmax(y_d) == 1e3 and np.nanmin(y_d) == np.nanmin(y) and np.isnan(y_d).sum() == 1
    # every kept sample is a sample of the curve
    np.testing.assert_array_equal(y_d, y[np.searchsorted(t, x_d)])
    # each bin's extremes are kept: the decimated curve's envelope over any window equals the original's
    for lo, hi in ((10.0, 20.0), (55.5, 70.25)):
        inside, inside_d = (t >= lo) & (t <= hi), (x_d >= lo) & (x_d <= hi)
        assert np.nanmax(y_d[inside_d]) <= np.nanmax(y[inside])
        assert np.nanmax(y_d[inside_d]) >= np.nanmax(y[(t >= lo + 0.2) & (t <= hi - 0.2)])
    # paths (x-y): the extremes of both coordinates are kept
    p = rng.normal(size=(20_000, 2)).cumsum(axis=0)
    px, py = decimate(p[:, 0], p[:, 1], 2000)
    assert px.max() == p[:, 0].max() and px.min() == p[:, 0].min() and py.max() == p[:, 1].max()
    # a short series, and the old path, are drawn as they are
    x_s, y_s = decimate(t[:100], y[:100], 3000)
    assert x_s is not None and len(x_s) == 100 and np.array_equal(y_s, y[:100])
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plot_common, "LEGACY", True)
        assert len(decimate(t, y, 3000)[0]) == t.size


@pytest.mark.parametrize("stage", sorted(PNGS))
def test_each_stage_writes_its_pngs_and_lists_them(stage_runs, stage):
    run = stage_runs[stage]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["stage"] == stage and "warnings" not in summary, summary.get("warnings")
    listed = {k: v for k, v in summary["files"].items() if k.startswith("png_")}
    assert listed == {f"png_{Path(n).stem}": n for n in PNGS[stage]}
    assert not list(run.glob(".*.partial")), "a temporary file was left behind"
    for name in PNGS[stage]:
        path = run / name
        width, height = png_size(path)
        assert 500 <= width <= 3000 and 400 <= height <= 3000, (name, width, height)
        assert path.stat().st_size > 10_000, name  # drawn, not blank


def test_track_error_plot_draws_the_summary_series(stage_runs):
    summary = json.loads((stage_runs["track"] / "summary.json").read_text())
    lines = stage_runs["captured"]["tracking_error.png"]
    dense = [(x, y) for label, x, y in lines if label.startswith("plant samples")]
    assert len(dense) == 1
    t, err = dense[0]
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms == pytest.approx(summary["rms_position_error_m"], rel=1e-12)
    assert float(err.max()) == pytest.approx(summary["max_position_error_m"], rel=1e-12)
    assert float(err[-1]) == pytest.approx(summary["final_position_error_m"], rel=1e-12)
    assert t[-1] == pytest.approx(summary["sim_time_s"], rel=1e-12)
    # The control-instant dots lie on the dense curve's range and are at the control period's instants.
    ctrl = [(x, y) for label, x, y in lines if label == "control instants"]
    assert len(ctrl) == 1 and len(ctrl[0][0]) == summary["control_steps"]
    assert np.all(ctrl[0][1] <= err.max() * (1 + 1e-9))


class _FakeRun:
    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.files: dict[str, Path] = {}

    def file(self, role: str, name: str) -> Path:
        self.files[role] = self.run_dir / name
        return self.files[role]


def test_a_failing_figure_becomes_a_warning_and_the_others_are_written(tmp_path):
    def good(path: Path) -> None:
        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1])
        track_plots.save_png(fig, path)

    def bad(path: Path) -> None:
        raise ValueError("no data to draw")

    run, summary = _FakeRun(tmp_path), {"status": "degraded"}
    guarded_plots(run, summary, {"broken": bad, "fine": good})
    assert summary["status"] == "degraded"
    assert summary["warnings"] == ["plot broken.png not written: ValueError: no data to draw"]
    assert set(run.files) == {"png_fine"} and png_size(tmp_path / "fine.png")[0] > 0
    assert not (tmp_path / "broken.png").exists()


def test_outputs_plots_false_writes_no_png_and_keeps_the_rest(tmp_path):
    """``outputs.plots: false`` (campaigns, benchmarks): no PNG and none listed; MCAP, .rrd and summary still
    written, and the summary's numbers are those of the same run with the PNGs."""
    doerr = Path(__file__).resolve().parents[1] / "configs" / "doerr2021.yaml"
    common = ("--set", "simulation.settle_time_s=1", "--quiet")
    result = run_cli("track", doerr, *common, "--set", "outputs.plots=false", "--out", tmp_path / "bare")
    assert result.exit_code == 0, result.output
    result = run_cli("track", doerr, *common, "--out", tmp_path / "full")
    assert result.exit_code == 0, result.output
    bare = json.loads((tmp_path / "bare" / "summary.json").read_text())
    full = json.loads((tmp_path / "full" / "summary.json").read_text())
    assert not list((tmp_path / "bare").glob("*.png"))
    assert not [k for k in bare["files"] if k.startswith("png_")]
    assert {"mcap", "rrd"} <= set(bare["files"]) and (tmp_path / "bare" / "track.mcap").stat().st_size > 0
    assert list((tmp_path / "full").glob("*.png"))
    assert bare["rms_position_error_m"] == full["rms_position_error_m"]


def _pixels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _figure_pairs(rng: np.random.Generator):
    """Two different data sets per reusable figure kind: (draw function, args A, args B); A and B differ in what a
    leftover from A would show in B (log against linear scale, aspect, titles, legends, colour cycle, limits)."""
    from oacli.geometry.shapes import Box, Ellipsoid, Scene
    from oacli.types import ParameterEstimate

    t = np.linspace(0.0, 30.0, 151)
    u_a, u_b = rng.normal(scale=0.1, size=(151, 6)), rng.normal(scale=0.02, size=(151, 6))
    lim = np.array([0.4, 0.2, 0.25]), np.array([0.04, 0.02, 0.025])
    info_log = np.einsum("k,ij->kij", np.logspace(-2, 4, 151), np.eye(4))
    info_lin = np.einsum("k,ij->kij", np.linspace(1.0, 2.0, 151), np.eye(4))
    scene = Scene(keep_in=(Box(np.array([-1.0, -1.0, -1.0]), np.array([2.0, 1.5, 1.0])),),
                  keep_out=(Ellipsoid(np.array([0.5, 0.2, 0.0]), np.diag([16.0, 25.0, 9.0])),))
    path_a = {"plan": np.column_stack([np.linspace(-0.5, 1.5, 40), np.linspace(-0.5, 1.0, 40), np.zeros(40)]),
              "other": np.column_stack([np.linspace(-0.8, 1.2, 40), np.zeros(40), np.linspace(0, 0.5, 40)])}
    path_b = {"extra": np.column_stack([np.linspace(0.0, 0.4, 9), np.linspace(0.0, 0.1, 9), np.zeros(9)])}
    cov = np.diag([0.01, 1e-6, 1e-6, 1e-6])
    est_a = [ParameterEstimate(float(k), np.array([10.0 + 0.1 * k, 0.15, 0.16, 0.17]), cov / (k + 1), "batch")
             for k in range(30)]
    est_b = [ParameterEstimate(float(k), np.array([12.0, 0.2, 0.21, 0.22]), cov, "batch") for k in range(5)]
    truth = np.array([10.0, 0.15, 0.16, 0.17])
    return [
        (plot_common.plot_inputs, (t, u_a, *lim, "A"), (t, u_b, *lim, "B title", "design limit", (2 * lim[0], lim[1]))),
        (excite_plots.plot_information, (t, info_log, "A"), (t, info_lin, "B")),
        (excite_plots.plot_information, (t, info_lin, "A"), (t, info_log, "B")),
        (plan_plots.plot_view, ((0, 1), "A view", scene, 0.2, path_a, np.zeros(3), np.ones(3)),
         ((0, 2), "B view", None, 0.0, path_b, np.zeros(3), np.full(3, 0.4))),
        (estimate_plots.plot_convergence, (est_a, truth, np.full(4, 1e-3)), (est_b, None, None)),
    ]


def test_a_figure_drawn_on_a_reused_template_is_pixel_identical_to_a_fresh_one(tmp_path):
    """subplots() hands out a blanked template of the same shape (common.REUSE): nothing of the previous figure
    (lines, patches, legends, titles, log scale, equal aspect, limits, colour cycle) may survive into the next."""
    rng = np.random.default_rng(11)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plot_common, "_TEMPLATES", {})
        for k, (draw, args_a, args_b) in enumerate(_figure_pairs(rng)):
            mp.setattr(plot_common, "REUSE", False)
            draw(tmp_path / f"fresh{k}.png", *args_b)
            mp.setattr(plot_common, "REUSE", True)
            plot_common._TEMPLATES.clear()
            draw(tmp_path / f"a{k}.png", *args_a)
            assert sum(len(v) for v in plot_common._TEMPLATES.values()) == 1  # A's figure went back to the pool
            draw(tmp_path / f"reused{k}.png", *args_b)
            fresh, reused = _pixels(tmp_path / f"fresh{k}.png"), _pixels(tmp_path / f"reused{k}.png")
            assert fresh.shape == reused.shape, draw.__name__
            differ = np.any(fresh != reused, axis=-1)
            assert not differ.any(), f"{draw.__name__} #{k}: {int(differ.sum())} pixels differ"
