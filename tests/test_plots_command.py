"""``outputs.plots`` (all | mission | none) and ``oacli plots RUN_DIR``: the mission draws only its own PNGs by
default, and every stage's PNGs can be drawn afterwards from the run folder's MCAPs, equal pixel for pixel to those
the stage draws at run time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import config_from_dict, dump_config, load_config
from oacli.config.outputs import PlotSet
from oacli.errors import ConfigError
from oacli.mission.layout import MISSION_STAGES
from oacli.mission.plots import view_axes
from oacli.mission.run import mission_stages
from tests.plot_checks import PNGS
from tests.test_stage_plots import png_size, stage_runs  # noqa: F401 -- the tiny runs of every stage (fixture)

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def _pixels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _plots(value):
    data = load_config(ROOT / "configs" / "doerr2021.yaml").model_dump(mode="json")
    data["outputs"] = {"plots": value}
    return config_from_dict(data, source="test").outputs


@pytest.mark.parametrize(("value", "expected", "stage", "mission"), [
    (True, PlotSet.ALL, True, True), (False, PlotSet.NONE, False, False), ("all", PlotSet.ALL, True, True),
    ("mission", PlotSet.MISSION, False, True), ("none", PlotSet.NONE, False, False),
    ("false", PlotSet.NONE, False, False), ("Mission", PlotSet.MISSION, False, True),
])
def test_outputs_plots_values(value, expected, stage, mission):
    outputs = _plots(value)
    assert outputs.plots is expected
    assert outputs.stage_pngs is stage and bool(outputs.plots) is stage  # a stage's `if cfg.outputs.plots:`
    assert outputs.mission_pngs is mission


def test_outputs_plots_refuses_other_values_and_round_trips():
    for bad in ("some", 3, None):
        with pytest.raises(ConfigError) as info:
            _plots(bad)
        assert "outputs.plots" in str(info.value) and "all, mission, none" in str(info.value)
    cfg = load_config(ROOT / "configs" / "mission_iss.yaml")
    assert cfg.outputs.plots is PlotSet.MISSION  # the mission presets: the mission's PNGs only
    assert "  plots: mission" in dump_config(cfg).splitlines()
    assert load_config(ROOT / "configs" / "iss_reswarm.yaml").outputs.plots is PlotSet.ALL  # stages: their own


def test_view_axes_pick_the_planes_the_paths_spread_in():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(200, 3)) * np.array([0.2, 2.0, 0.8])  # the ISS route: along y, up and down in z
    assert view_axes(pts) == ((1, 2), (0, 1))
    pts = rng.normal(size=(200, 3)) * np.array([3.0, 1.0, 0.1])  # a flat route in x-y
    assert view_axes(pts) == ((0, 1), (0, 2))


@pytest.mark.parametrize("stage", sorted(PNGS))
def test_plots_command_redraws_a_stage_folder_pixel_for_pixel(stage_runs, stage, tmp_path):  # noqa: F811
    run = stage_runs[stage]
    result = runner.invoke(app, ["plots", str(run), "--out", str(tmp_path), "--json"])
    assert result.exit_code == 0, result.output
    written = json.loads(result.output)["written"][stage]
    assert sorted(Path(p).name for p in written.values()) == sorted(PNGS[stage])
    for name in PNGS[stage]:
        redrawn, original = tmp_path / name, run / name
        png_size(redrawn)  # a complete, valid PNG
        a, b = _pixels(redrawn), _pixels(original)
        assert a.shape == b.shape, name
        assert not np.any(a != b), f"{stage}/{name}: {int(np.any(a != b, axis=-1).sum())} pixels differ"


def test_plots_command_refuses_what_is_not_a_run_folder(tmp_path, stage_runs):  # noqa: F811
    result = runner.invoke(app, ["plots", str(tmp_path)])
    assert result.exit_code == 2 and "no summary.json" in result.output
    result = runner.invoke(app, ["plots", str(stage_runs["track"]), "--stage", "segment-1/track"])
    assert result.exit_code == 2 and "--stage: only for mission folders" in result.output


def test_mission_draws_only_its_own_pngs_and_plots_draws_the_rest(mission_run, tmp_path):
    mission_dir = mission_run[0]
    summary = json.loads((mission_dir / "summary.json").read_text())
    assert set(summary["files"]["plots"]) == {"tracking_error", "estimate_convergence", "paths"}
    stages = mission_stages(load_config(mission_dir / "config.yaml"))   # with the default's calibration manoeuvre
    assert len(stages) == len(MISSION_STAGES) + 2
    for stage in stages:  # outputs.plots: mission -> no stage PNG, none listed; the data is all there
        folder = stage.folder(mission_dir)
        stage_summary = json.loads((folder / "summary.json").read_text())
        assert not list(folder.glob("*.png")), stage.key
        assert not [k for k in stage_summary["files"] if k.startswith("png_")], stage.key
        assert (folder / f"{stage.command}.mcap").is_file()
    result = runner.invoke(app, ["plots", str(mission_dir), "--out", str(tmp_path), "--json"])
    assert result.exit_code == 0, result.output
    written = json.loads(result.output)["written"]
    for stage in stages:
        names = sorted(Path(p).name for p in written[stage.key].values())
        assert names == sorted(PNGS[stage.command]), stage.key
        for name in names:
            width, height = png_size(tmp_path / stage.segment / stage.name / name)
            assert width >= 500 and height >= 400
    stage_pngs = sum(len(PNGS[stage.command]) for stage in stages)
    assert stage_pngs == 36  # 6 track-kind stages x 3, 4 plan/smooth x 2, excite 2, 4 estimates x 2 (calibrations)
    assert sum(len(v) for v in written.values()) == stage_pngs + 3  # and 3 of the mission
    for name in ("tracking_error", "estimate_convergence", "paths"):  # the mission's: as the runner drew them
        a, b = _pixels(tmp_path / "plots" / f"{name}.png"), _pixels(mission_dir / "plots" / f"{name}.png")
        assert a.shape == b.shape and not np.any(a != b), name
    result = runner.invoke(app, ["plots", str(mission_dir), "--stage", "segment-9/track"])
    assert result.exit_code == 2 and "not a mission stage" in result.output
