"""oacli report on campaigns: a small real one written by `oacli campaign` (study cells), and a 50-run one built from
synthetic run records through the real preparation, manifest, aggregation and outputs, both opened in a real
headless Chromium (status, per-cell intervals, every figure rendered, one row per run with its rerun command and
recording, 0 network requests, ≤ 5 MB). The per-cell intervals are checked against the order statistics.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from chromium_cdp import PAGE_FACTS, chromium_or_skip, open_page
from scipy.stats import binom
from typer.testing import CliRunner

from oacli.campaign import manifest
from oacli.campaign.driver import load_campaign, prepare
from oacli.campaign.finalize import finalize
from oacli.campaign.intervals import median_interval, proportion_interval
from oacli.cli import app
from oacli.report.build import write_report

ROOT = Path(__file__).resolve().parents[1]
MAX_BYTES = 5_000_000
RUNS = 50


def test_median_interval_is_the_order_statistics_interval():
    # Conover's table: n = 25 -> ranks 8 and 18; n = 50 -> 18 and 33; below 6 runs no 95 % interval exists
    x = np.arange(1.0, 26.0)
    got = median_interval(x[::-1])
    assert (got["low"], got["high"], got["median"]) == (8.0, 18.0, 13.0)
    assert got["coverage"] == pytest.approx(1 - 2 * binom.cdf(7, 25, 0.5)) and got["coverage"] >= 0.95
    assert 1 - 2 * binom.cdf(8, 25, 0.5) < 0.95  # the next narrower interval would not do
    got = median_interval(np.arange(1.0, 51.0))
    assert (got["low"], got["high"]) == (18.0, 33.0)
    assert median_interval([3.0, 1.0, 2.0, None, 5.0, 4.0])["low"] is None  # n = 5
    assert median_interval([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])["low"] == 1.0  # n = 6: the extremes, 96.9 %
    never = median_interval([1.0, 2.0, math.inf, math.inf, math.inf, math.inf, math.inf])
    assert never["median"] == math.inf and never["low"] == 1.0  # runs that never arrive rank last


def test_median_interval_covers_at_its_level():
    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(2000):  # a skewed distribution with a known median: exp(1) has median ln 2
        got = median_interval(rng.exponential(size=30))
        hits += got["low"] <= math.log(2) <= got["high"]
    assert hits / 2000 >= got["coverage"] - 0.015  # exact coverage 95.7 % at n = 30, within sampling error


def test_proportion_interval_is_clopper_pearson():
    got = proportion_interval(0, 50)
    assert got["low"] == 0.0 and got["high"] == pytest.approx(1 - 0.025 ** (1 / 50))
    got = proportion_interval(50, 50)
    assert got["high"] == 1.0 and got["low"] == pytest.approx(0.025 ** (1 / 50))


# -- a small real campaign with two study cells -------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_campaign(tmp_path_factory):
    from test_campaign import tiny_campaign

    folder = tmp_path_factory.mktemp("report-campaign")
    path = tiny_campaign(folder, runs=4, name="tiny-cells")
    data = yaml.safe_load(path.read_text())
    data["faults"] = {}
    data["grid"] = {"noise": {"low": {"sensors.position_std_m": 0.0005}, "high": {"sensors.position_std_m": 0.004}}}
    path.write_text(yaml.safe_dump(data, sort_keys=False))  # the cells in file order
    result = CliRunner().invoke(app, ["campaign", str(path), "--executor", "serial", "--out",
                                      str(folder / "run")])
    assert result.exit_code == 0, result.output
    return folder / "run", result.output


def test_campaign_writes_its_report_with_cells(small_campaign):
    folder, output = small_campaign
    summary = json.loads((folder / "summary.json").read_text())
    assert [c["name"] for c in summary["cells"]] == ["noise=low", "noise=high"]
    assert [c["runs"] for c in summary["cells"]] == [2, 2]
    # run k flies cell k mod 2, replicate k div 2: the two cells of a replicate share their draws (paired)
    specs = [json.loads((folder / "runs" / f"run-{k:05d}" / "spec.json").read_text()) for k in range(4)]
    assert [s["cell"] for s in specs] == ["noise=low", "noise=high"] * 2
    assert specs[0]["seed"] == specs[1]["seed"] != specs[2]["seed"] == specs[3]["seed"]
    assert specs[0]["draws"]["mass_kg"] == specs[1]["draws"]["mass_kg"]
    assert [s["config"]["sensors"]["position_std_m"] / s["draws"]["sensor_noise_factor"] for s in specs] == \
        pytest.approx([0.0005, 0.004] * 2)
    final = manifest.final_states(manifest.read(folder))
    for cell in summary["cells"]:
        ks = [k for k in final if specs[k]["cell"] == cell["name"]]
        lag = [final[k]["metrics"]["lag_s"] for k in ks]
        assert cell["figures"]["lag_s"]["median"] == pytest.approx(float(np.median(lag)))
        assert cell["figures"]["lag_s"]["low"] is None  # two runs give no 95 % interval, and say so
    page = folder / "report.html"
    assert page.is_file() and "report: " in output
    text = page.read_text()
    assert len(text.encode()) <= MAX_BYTES
    for k in range(4):
        assert f"oacli campaign rerun {folder} {k}" in text


def test_bad_campaign_input_is_one_line_and_exit_2(small_campaign, tmp_path):
    folder, _ = small_campaign
    import shutil

    copy = tmp_path / "unfinished"
    shutil.copytree(folder, copy, ignore=shutil.ignore_patterns("runs", "*.rrd", "*.mcap", "report.html"))
    (copy / "summary.json").unlink()
    result = CliRunner().invoke(app, ["report", str(copy)])
    assert result.exit_code == 2
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "no summary.json" in lines[0] and "--resume" in lines[0]


def test_bad_cell_override_names_the_cell(tmp_path):
    from test_campaign import tiny_campaign

    path = tiny_campaign(tmp_path, runs=2, name="bad-cell")
    data = yaml.safe_load(path.read_text())
    data["grid"] = {"noise": {"low": {}, "typo": {"sensors.position_sd_m": 0.1}}}
    path.write_text(yaml.safe_dump(data))
    result = CliRunner().invoke(app, ["campaign", str(path), "--dry-run", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "cell noise=typo" in result.stderr and "position_sd_m" in result.stderr


def test_small_campaign_report_in_headless_chromium(small_campaign):
    chromium = chromium_or_skip()
    folder, _ = small_campaign
    page = open_page(chromium, folder / "report.html", PAGE_FACTS)
    facts = page.value
    assert page.network_requests == []
    assert facts["status"].startswith("status: complete")
    assert facts["run_rows"] == 1 + 4
    assert facts["images"] and all(i["complete"] and i["w"] > 200 and i["h"] > 100 for i in facts["images"])


# -- a 50-run campaign from synthetic run records -------------------------------------------------------------------


def _synthetic_metrics(rng: np.random.Generator, heavy: bool) -> dict:
    """Plausible manifest metrics of one mission run (segment 3's flights, estimates), drawn."""
    rows = {}
    for key, scale in (("segment-3/track", 30.0), ("segment-3/baseline-mpc-prior", 10.0),
                       ("segment-3/baseline-tube-prior", 35.0)):
        s = scale * (2.0 if heavy else 1.0)
        arrival = None if rng.random() < 0.1 else float(27 + rng.exponential(0.5))
        rows[key] = {"status": "ok", "rms_position_error_m": 1e-3 * s * rng.lognormal(0, 0.2),
                     "max_position_error_m": 2e-3 * s, "overshoot_m": 1e-3 * s * rng.random(),
                     "control_effort_Ns": 4.5, "time_saturated_s": float(rng.exponential(0.5)),
                     "arrival_time_s": arrival, "keep_in_violations": 0,
                     "keep_out_violations": int(rng.random() < 0.05), "limit_violations": 0,
                     "keep_out_clearance_m": float(0.2 + 0.05 * rng.standard_normal())}
    err = rng.normal(0, [0.3, 0.8, 1.2, 4.0])
    return {"status": "ok", "violations": {"keep_in": 0, "keep_out": 0, "limits": 0},
            "tube_violations": 0, "tube_violations_true": int(rng.integers(0, 50)), "fallback_steps": 0,
            "solver_failures": 0, "rms_position_error_m": rows["segment-3/track"]["rms_position_error_m"],
            "max_position_error_m": 0.06, "final_position_error_m": 0.01,
            "estimate": {"error_pct": err.tolist(), "error_over_crb": (err / 0.2).tolist(),
                         "cov_reduction_pct": [99.9, 99.8, 99.8, 99.8], "status": "degraded"},
            "estimate_sequential": {"error_pct": (1.1 * err).tolist(), "cov_reduction_pct": [99.0, 90.0, 80.0, 70.0],
                                    "status": "degraded"},
            "comparison": rows}


@pytest.fixture(scope="module")
def big_campaign(tmp_path_factory):
    """A 50-run mission campaign with two cells: the real folder and specs (prepare), synthetic run records (the
    missions are not flown), a placeholder mission.rrd per run, then the real finalize and report."""
    folder = tmp_path_factory.mktemp("report-big")
    path = folder / "big.yaml"
    path.write_text(yaml.safe_dump({
        "name": "big", "seed": 5, "runs": RUNS, "job": "mission", "base": str(ROOT / "configs" / "mission_iss.yaml"),
        "set": {"outputs": {"plots": "none", "report": False}},
        "grid": {"prior": {"light": {"mission.prior.mass_kg": 14.5}, "heavy": {"mission.prior.mass_kg": 12.0}}}},
        sort_keys=False))
    out = prepare(load_campaign(path), out=folder / "run", runs_root=folder)
    rng = np.random.default_rng(7)
    index = json.loads((out / "runs.json").read_text())["index"]
    for k in range(RUNS):
        attempt = out / "runs" / f"run-{k:05d}" / "attempt-0"
        (attempt / "mission").mkdir(parents=True)
        (attempt / "mission" / "mission.rrd").write_bytes(b"placeholder")
        metrics = _synthetic_metrics(rng, index[str(k)]["cell"] == "prior=heavy")
        manifest.append(out, {"k": k, "status": "ok", "hash": f"{k:064x}", "metrics": metrics,
                              "attempt": str(attempt.relative_to(out)), "wall_time_s": 1.0, "infra_attempts": 0,
                              "executor": "synthetic"})
    summary = finalize(out)
    result = write_report(out)
    return out, summary, result


def test_50_run_report_intervals_and_rows(big_campaign):
    folder, summary, result = big_campaign
    assert result.size_bytes <= MAX_BYTES and result.kind == "campaign"
    final = manifest.final_states(manifest.read(folder))
    index = json.loads((folder / "runs.json").read_text())["index"]
    for cell in summary["cells"]:
        ks = sorted(k for k in final if index[str(k)]["cell"] == cell["name"])
        assert len(ks) == 25 and cell["completed"] == 25
        rms = np.sort([final[k]["metrics"]["comparison"]["segment-3/baseline-mpc-prior"]["rms_position_error_m"]
                       for k in ks])
        got = cell["figures"]["seg3_mpc_prior.rms_position_error_m"]
        assert got["median"] == pytest.approx(rms[12]) and (got["low"], got["high"]) == (rms[7], rms[17])
        mass = np.sort([abs(final[k]["metrics"]["estimate_sequential"]["error_pct"][0]) for k in ks])
        assert cell["figures"]["sequential.abs_error_pct.mass"]["median"] == pytest.approx(mass[12])
        never = sum(final[k]["metrics"]["comparison"]["segment-3/track"]["arrival_time_s"] is None for k in ks)
        assert cell["events"]["seg3_tube_estimate.never_arrived"]["count"] == never
    text = result.path.read_text()
    for k in range(RUNS):
        assert f"oacli campaign rerun {folder} {k}</code>" in text
        assert str((folder / "runs" / f"run-{k:05d}" / "attempt-0" / "mission" / "mission.rrd").resolve()) in text


def test_50_run_report_in_headless_chromium(big_campaign, tmp_path):
    chromium = chromium_or_skip()
    result = big_campaign[2]
    page = open_page(chromium, result.path, PAGE_FACTS)
    facts = page.value
    assert page.network_requests == []
    assert facts["status"].startswith("status: complete")
    assert facts["run_rows"] == 1 + RUNS
    assert facts["cell_rows"] > 2 * 10
    ids = {i["alt"] for i in facts["images"]}
    assert {"status", "tracking error", "estimation error", "Per-cell medians with 95 % intervals"} <= ids
    assert any(a.startswith("CDF per cell") for a in ids)
    for img in facts["images"]:
        assert img["complete"] and img["w"] > 300 and img["h"] > 200 and img["shown_w"] > 300, img
    (tmp_path / "campaign_report.png").write_bytes(page.screenshot_png)
    assert page.screenshot_png[:8] == b"\x89PNG\r\n\x1a\n"


# -- the study presets --------------------------------------------------------------------------------------------


def test_study_presets_load_with_their_cells():
    from oacli.campaign.cells import campaign_cells

    fig3d = load_campaign(ROOT / "configs" / "study_fig3d.yaml")
    cells = campaign_cells(fig3d.config)
    assert len(cells) == 8 and fig3d.config.runs == 50 * len(cells)
    assert fig3d.base["mission"]["unconstrained_baseline"] is True  # the paper's standard MPC in every mission
    grasped = fig3d.base["mission"]["grasped"]["mass_kg"]
    payload = 15.0 - 9.0877  # [Doerr2021] Table 1: Astrobee with the object, Astrobee alone
    for cell in cells:
        pct = int(cell.levels["prior_error"].removesuffix("pct"))
        prior = cell.overrides["mission"]["prior"]
        assert grasped - prior["mass_kg"] == pytest.approx(pct / 100 * payload, abs=1e-5)
        assert 2 * prior["variance"][0] ** 0.5 >= grasped - prior["mass_kg"] - 1e-6  # 2σ covers the error (Eq. 28)
    rattle = load_campaign(ROOT / "configs" / "study_rattle.yaml")
    assert campaign_cells(rattle.config) == () and rattle.config.runs >= 50
    assert rattle.base["excitation"]["method"] == "rattle" and rattle.base["estimation"]["method"] == "rls"
    assert rattle.base["truth"]["mass_kg"] == rattle.base["robot"]["mass_kg"]  # the bare robot
    assert rattle.base["excitation"]["prior"]["variance"][0] == pytest.approx(15.0)  # [RattleCode] P0
    assert rattle.base["estimation"]["prior"]["variance"][0] == pytest.approx(15.0)
    expset3 = load_campaign(ROOT / "configs" / "study_expset3.yaml")
    cells = campaign_cells(expset3.config)
    assert [c.overrides["controller"]["type"] for c in cells] == ["tube", "mpc"]
    assert expset3.config.runs == 50 * len(cells)
    assert expset3.base["robot"]["mass_kg"] == expset3.base["truth"]["mass_kg"]  # the correct model
