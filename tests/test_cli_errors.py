"""Bad input ends with one clear line per problem, exit code 2, no traceback and no run folder."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from oacli.cli import app
from tests.conftest import REPO

ISS = REPO / "configs" / "iss_reswarm.yaml"
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def preset() -> dict:
    return yaml.safe_load(ISS.read_text())


def write_config(path: Path, data) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False) if not isinstance(data, str) else data)
    return path


def assert_clean_failure(result, runs: Path, *, code: int = 2, must_name: str | None = None) -> None:
    assert result.exit_code == code, (result.exit_code, result.output)
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert lines and all(ln.startswith("error: ") for ln in lines), result.stderr
    if must_name is not None:
        assert must_name in result.stderr, result.stderr
    assert not runs.exists() or not any(runs.iterdir()), "a run folder was left behind"


def test_negative_mass_names_the_field(tmp_path):
    data = preset()
    data["robot"]["mass_kg"] = -1.0
    cfg = write_config(tmp_path / "bad.yaml", data)
    result = invoke("track", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="robot.mass_kg")
    assert str(cfg) in result.stderr


def test_malformed_yaml_names_the_line(tmp_path):
    cfg = write_config(tmp_path / "bad.yaml", "name: x\nrobot: [1, 2\n")
    result = invoke("track", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="line")


def test_missing_config_file(tmp_path):
    result = invoke("track", tmp_path / "nope.yaml", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="nope.yaml")


def test_start_inside_a_keep_out_zone_is_refused(tmp_path):
    data = preset()
    data["environment"]["keep_out"] = [{"center": [10.8, -9.6, 4.8], "semi_axes_m": [0.2, 0.2, 0.2]}]
    cfg = write_config(tmp_path / "obstacle.yaml", data)
    result = invoke("track", cfg, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="environment.keep_out.0")


def test_missing_reference_file(tmp_path):
    result = invoke("track", ISS, "--reference", tmp_path / "missing.csv", "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="missing.csv")


def test_existing_out_folder_is_never_overwritten(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    result = invoke("track", ISS, "--out", out)
    assert result.exit_code == 2
    assert "never overwritten" in result.stderr
    assert (out / "keep.txt").read_text() == "precious"
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


def test_a_failure_mid_run_leaves_a_failed_summary_not_a_complete_run(tmp_path, monkeypatch):
    import oacli.stages.track as track_stage

    def explode(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(track_stage, "write_track_recording", explode)
    out = tmp_path / "run"
    result = invoke("track", ISS, "--out", out, "--quiet")
    assert result.exit_code == 1
    assert "disk on fire" in result.stderr and "Traceback" not in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "disk on fire" in summary["error"]
    assert not (out / "track.rrd").exists()
    assert not any(p.name.endswith(".partial") for p in out.iterdir())


_CORRUPTIONS = [
    (("robot", "mass_kg"), st.sampled_from([0, -9.6, "heavy", float("nan"), None])),
    (("robot", "inertia_kgm2"), st.sampled_from([[0.1, 0.1, 0.5], [0.1, -0.1, 0.1], [0.1, 0.1], "x"])),
    (("robot", "force_limit_N"), st.sampled_from([[0.4, 0.0, 0.4], [0.4, 0.4, float("inf")], [1, 2, 3, 4]])),
    (("controller", "rate_hz"), st.sampled_from([0, -5.0, "fast"])),
    (("controller", "horizon"), st.sampled_from([0, -1, 2.5, "ten"])),
    (("simulation", "plant_rate_hz"), st.sampled_from([0, -62.5])),
    (("sensors", "position_std_m"), st.sampled_from([-0.01, "noisy"])),
    (("waypoints", "A", "quaternion"), st.sampled_from([[0, 0, 0, 2.0], [0, 0, 0, 0], [0, 0, 1]])),
    (("seed",), st.sampled_from([-1, 1.5, "abc"])),
]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    which=st.integers(0, len(_CORRUPTIONS) - 1),
    data=st.data(),
    unknown_key=st.booleans(),
)
def test_generated_malformed_configs_fail_cleanly(tmp_path, which, data, unknown_key):
    """Property: any corrupted preset → exit 2, each stderr line names the file, no traceback, no run folder."""
    cfg = preset()
    path, strategy = _CORRUPTIONS[which]
    if unknown_key:
        node = cfg
        for key in path[:-1]:
            node = node[key]
        node["bogus_key"] = 1
        field = ".".join((*path[:-1], "bogus_key")) if len(path) > 1 else "bogus_key"
    else:
        node = cfg
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = data.draw(strategy)
        field = ".".join(path)
    runs = tmp_path / f"runs-{which}-{unknown_key}"
    config_file = write_config(tmp_path / "corrupt.yaml", cfg)
    result = invoke("track", config_file, "--runs-dir", runs)
    assert_clean_failure(result, runs, must_name=field)
    assert all(str(config_file) in ln for ln in result.stderr.splitlines() if ln.strip())


@pytest.mark.parametrize("seed", ["-3"])
def test_negative_seed_option(tmp_path, seed):
    result = invoke("track", ISS, "--seed", seed, "--runs-dir", tmp_path / "runs")
    assert_clean_failure(result, tmp_path / "runs", must_name="--seed")
