"""Each stage's PNG plots (issue 12 item 2): written into the run folder, listed in summary.json, valid PNGs of a
sensible size; the track error plot draws exactly the series behind the summary's RMS / max; a failing figure
becomes a summary warning and never loses the run."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import oacli.io.plots.track as track_plots
from oacli.cli import app
from oacli.io.plots.common import guarded_plots, plt
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

    def capture(fig, path):
        captured[Path(path).name] = [(ln.get_label(), np.asarray(ln.get_xdata(), dtype=float),
                                      np.asarray(ln.get_ydata(), dtype=float))
                                     for ax in fig.axes for ln in ax.get_lines()]
        return real_save(fig, path)

    payload = payload_config(tmp / "payload.yaml")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(track_plots, "save_png", capture)
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
            "excite": tmp / "excite", "captured": captured}  # type: ignore[dict-item]


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
