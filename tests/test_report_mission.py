"""oacli report on a mission: the page `oacli mission` writes, opened in a real headless Chromium (status, segment
table, every figure rendered, 0 network requests, a screenshot), its figures equal to the folder's files, and bad
input refused with one line (exit 2).

The mission is the session's shared one (``mission_run`` of conftest.py); the browser tests skip, with the reason,
where no Chromium is installed (``.ci/run`` installs it on a Debian CI machine).
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import shutil
import struct

import pytest
from chromium_cdp import PAGE_FACTS, chromium_or_skip, open_page
from markupsafe import escape
from typer.testing import CliRunner

from oacli.cli import app
from oacli.report.build import fmt

MAX_BYTES = 5_000_000


def png_size(data: bytes) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def embedded_pngs(text: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)]


@pytest.fixture(scope="module")
def mission(mission_run):
    run_dir, _, output = mission_run
    return run_dir, json.loads((run_dir / "summary.json").read_text()), output


def test_mission_writes_a_self_contained_report(mission):
    run_dir, summary, output = mission
    page = run_dir / "report.html"
    assert page.is_file(), output
    text = page.read_text()
    assert len(text.encode()) <= MAX_BYTES
    # written by the mission, with its time on the progress stream
    line = next(ln for ln in output.splitlines() if ln.startswith("report: "))
    assert str(page) in line and re.search(r"\(\d+\.\d\d MB, \d+\.\d\d s\)", line)
    # offline: nothing but inline data; no script at all
    assert not re.search(r'(src|href)="(?!data:)', text), "a resource outside the file"
    assert "<script" not in text and "http://" not in text and "https://" not in text
    # the figures: the tube-band figure drawn from the MCAPs, the others the mission's own PNGs byte for byte
    pngs = embedded_pngs(text)
    assert len(pngs) == 3
    for name in ("estimate_convergence", "paths"):
        assert (run_dir / summary["files"]["plots"][name]).read_bytes() in pngs
    w, h = png_size(pngs[0])
    assert w > 500 and h > 500
    # status, reasons, the segments and the comparison as summary.json has them
    assert f">{summary['status']}<" in text
    for reason in summary.get("status_reasons", []):
        assert str(escape(reason["message"])) in text
    for seg, info in summary["segments"].items():
        track = json.loads((run_dir / seg / "track" / "summary.json").read_text())
        assert f"<td>{fmt(1e3 * track['rms_position_error_m'])}</td>" in text, seg
        assert f"<td>{fmt(info['duration_s'])}</td>" in text
    for row in summary["comparison"].values():
        assert f"<td>{fmt(1e3 * row['overshoot_m'])}</td>" in text
    assert str(escape((run_dir / "config.yaml").read_text())) in text


def test_report_command_reads_the_folder_and_changes_nothing_else(mission, tmp_path):
    run_dir, _, _ = mission
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in run_dir.rglob("*")
              if p.is_file() and p.name != "report.html"}
    out = tmp_path / "again.html"
    result = CliRunner().invoke(app, ["report", str(run_dir), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "mission report: 3 figures" in result.output
    after = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in run_dir.rglob("*")
             if p.is_file() and p.name != "report.html"}
    assert after == before  # nothing was run again, nothing rewritten
    # the same page but for the time it was written
    strip = lambda t: re.sub(r"written \S+Z", "", t)  # noqa: E731
    assert strip(out.read_text()) == strip((run_dir / "report.html").read_text())


def _one_error_line(result) -> str:
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    return lines[0]


def test_bad_input_is_one_line_and_exit_2(mission, tmp_path):
    run_dir, _, _ = mission
    runner = CliRunner()
    assert "not a folder" in _one_error_line(runner.invoke(app, ["report", str(tmp_path / "nothing")]))
    (tmp_path / "empty").mkdir()
    assert "not a run folder" in _one_error_line(runner.invoke(app, ["report", str(tmp_path / "empty")]))
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    shutil.copy(run_dir / "config.yaml", unfinished / "config.yaml")
    assert "no summary.json" in _one_error_line(runner.invoke(app, ["report", str(unfinished)]))
    (unfinished / "summary.json").write_text("{\"status\": ")
    assert "not readable as JSON" in _one_error_line(runner.invoke(app, ["report", str(unfinished)]))
    # a copy whose segment-3 track MCAP is cut in half
    cut = tmp_path / "cut"
    shutil.copytree(run_dir, cut, ignore=shutil.ignore_patterns("*.rrd", "report.html"))
    mcap = cut / "segment-3" / "track" / "track.mcap"
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    line = _one_error_line(runner.invoke(app, ["report", str(cut)]))
    assert "track.mcap" in line
    assert not (cut / "report.html").exists()
    # and one whose PNG is cut
    cut_png = tmp_path / "cut-png"
    shutil.copytree(run_dir, cut_png, ignore=shutil.ignore_patterns("*.rrd", "report.html"))
    png = cut_png / "plots" / "paths.png"
    png.write_bytes(png.read_bytes()[:1000])
    assert "paths.png" in _one_error_line(runner.invoke(app, ["report", str(cut_png)]))


def test_mission_report_in_headless_chromium(mission, tmp_path):
    chromium = chromium_or_skip()
    run_dir, summary, _ = mission
    page = open_page(chromium, run_dir / "report.html", PAGE_FACTS)
    facts = page.value
    assert page.requests and page.requests[0].startswith("file://")
    assert page.network_requests == []  # 0 network requests: everything is inline
    assert facts["scripts"] == 0
    assert facts["status"].startswith(f"status: {summary['status']}")
    assert facts["segment_rows"] == 1 + len(summary["segments"])
    assert facts["comparison_rows"] == 1 + len(summary["comparison"])
    assert facts["estimate_rows"] == 5
    assert len(facts["images"]) == 3
    for img in facts["images"]:  # every figure decoded and laid out
        assert img["complete"] and img["w"] > 500 and img["h"] > 300 and img["shown_w"] > 300, img
    w, h = png_size(page.screenshot_png)
    assert w >= 1000 and h > 3000  # the whole page, figures included
    (tmp_path / "mission_report.png").write_bytes(page.screenshot_png)


def test_the_request_check_can_fail(tmp_path):
    """The same check sees a page that fetches an image (the control: 0 requests above is a measurement)."""
    chromium = chromium_or_skip()
    probe = tmp_path / "probe.html"
    probe.write_text('<!DOCTYPE html><html><body><p id="status-line">x</p>'
                     '<img src="http://127.0.0.1:9/x.png"></body></html>')
    page = open_page(chromium, probe, PAGE_FACTS)
    assert page.network_requests == ["http://127.0.0.1:9/x.png"]


def test_an_unfinished_mission_gets_its_status_error_and_resume_command(mission, tmp_path):
    run_dir, _, _ = mission
    failed = tmp_path / "failed"
    failed.mkdir()
    shutil.copy(run_dir / "config.yaml", failed / "config.yaml")
    (failed / "summary.json").write_text(json.dumps({
        "stage": "mission", "status": "interrupted", "error": "KeyboardInterrupt: <stopped>",
        "stages": {"segment-1/plan": {"status": "ok"}}, "resume": f"oacli mission --resume {failed}"}))
    result = CliRunner().invoke(app, ["report", str(failed)])
    assert result.exit_code == 0, result.output
    text = (failed / "report.html").read_text()
    assert ">interrupted<" in text and "KeyboardInterrupt: &lt;stopped&gt;" in text  # escaped
    assert f"oacli mission {failed} --resume" in text and "<img" not in text


def test_without_plots_the_report_draws_the_same_figures_from_the_mcaps(mission, tmp_path):
    run_dir, summary, _ = mission
    bare = tmp_path / "bare"
    shutil.copytree(run_dir, bare, ignore=shutil.ignore_patterns("*.rrd", "report.html", "plots"))
    result = CliRunner().invoke(app, ["report", str(bare)])
    assert result.exit_code == 0, result.output
    text = (bare / "report.html").read_text()
    pngs = embedded_pngs(text)
    assert text.count("drawn from the stage MCAPs") == 2
    for name in ("estimate_convergence", "paths"):  # the mission's own plot functions, byte for byte
        assert (run_dir / summary["files"]["plots"][name]).read_bytes() in pngs, name
    # The mission's page left its tracking figure in plots/ (a later `oacli report` inlines it, reading no MCAP):
    # the same bytes as drawn afresh here from the MCAPs; without a plots/ folder nothing is left behind.
    assert (run_dir / "plots" / "tracking_bands.png").read_bytes() == pngs[0]
    assert not (bare / "plots").exists()
