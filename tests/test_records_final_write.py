"""A SIGINT or SIGTERM at any moment around track's final write leaves either the complete files or
the journal (kept as ``track.mcap``, or its ``.partial`` that ``oacli logs recover`` reads) holding the whole
simulation, and the ``interrupted`` summary says which (``records``); a signal once ``summary.json`` is written
never rewrites it nor kills the process silently.

The sweep sends real signals (``os.kill`` from a timer thread) to this process while ``oacli track`` runs in it
(Typer's runner), at offsets spread over the time between the end of the simulation and the end of the command,
measured by a first run. The default suite sends 6; the slow suite 24 of each signal (48 in all). The signals after
``summary.json`` are sent to a child process (the console script's own handlers): one case in the default suite,
four in the slow one.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from typer.testing import CliRunner

import oacli.stages.track as track_stage
from oacli.cli import app
from tests.conftest import REPO

# A signal raised inside a weakref callback (matplotlib) is printed as "Exception ignored" and reported by pytest;
# the command still ends 130/143 (oacli.signals.delivered), which the checks assert.
pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
ISS = REPO / "configs" / "iss_reswarm.yaml"
runner = CliRunner()


def _fast_config(folder: Path) -> Path:
    data = yaml.safe_load(ISS.read_text())
    data["simulation"]["settle_time_s"] = 1.0
    data["outputs"] = {**(data.get("outputs") or {}), "plots": "all"}
    path = folder / "fast_track.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _messages(path: Path) -> tuple[list[tuple[str, int, bytes]], bool]:
    """(topic, log time, data) of every message, CRCs checked, and whether the file has its summary section."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        rows = [(ch.topic, m.log_time, m.data) for _, ch, m in reader.iter_messages()]
        return rows, reader.get_summary() is not None


def _last_true_ns(rows: list[tuple[str, int, bytes]]) -> int:
    return max(t for topic, t, _ in rows if topic == "/state/true")


class _Shooter:
    """Send ``signum`` to this process ``offset_s`` after the simulation ends (when the summary is computed)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, signum: int | None, offset_s: float) -> None:
        self.started = 0.0
        self.timer: threading.Timer | None = None
        original = track_stage._track_summary

        def summary_then_shoot(*args, **kwargs):
            self.started = time.perf_counter()
            if signum is not None:
                self.timer = threading.Timer(offset_s, os.kill, (os.getpid(), signum))
                self.timer.start()
            return original(*args, **kwargs)

        monkeypatch.setattr(track_stage, "_track_summary", summary_then_shoot)


def _run(monkeypatch, cfg: Path, out: Path, signum: int | None, offset_s: float):
    shooter = _Shooter(monkeypatch, signum, offset_s)
    previous = signal.signal(signal.SIGTERM, lambda *_: None)  # a SIGTERM after the command ends: harmless here
    late = False
    try:
        try:
            result = runner.invoke(app, ["track", str(cfg), "--out", str(out), "--quiet"])
            if shooter.timer is not None:
                shooter.timer.cancel()
                shooter.timer.join()
        except KeyboardInterrupt:  # the SIGINT came after the command returned
            late = True
            result = None
    finally:
        signal.signal(signal.SIGTERM, previous)
    return result, time.perf_counter() - shooter.started, late


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """One uninterrupted run: its files, its last /state/true time and how long the command runs after the
    simulation (the window the sweep covers)."""
    folder = tmp_path_factory.mktemp("final_write")
    cfg = _fast_config(folder)
    mp = pytest.MonkeyPatch()
    try:
        result, after_s, _ = _run(mp, cfg, folder / "base", None, 0.0)
    finally:
        mp.undo()
    assert result.exit_code == 0, result.output
    rows, _ = _messages(folder / "base" / "track.mcap")
    return cfg, folder / "base", _last_true_ns(rows), after_s


def _check(out: Path, base: Path, last_true_ns: int, result, tmp_path: Path, signame: str) -> str:
    """Assert the folder holds the complete files or the journal with the whole simulation; returns which."""
    summary = json.loads((out / "summary.json").read_text())
    names = sorted(p.name for p in out.iterdir())
    if summary["status"] == "ok":  # the signal came after the run was recorded: nothing is lost, nothing rewritten
        assert names == sorted(p.name for p in base.iterdir())
        rows, complete = _messages(out / "track.mcap")
        assert complete and _last_true_ns(rows) == last_true_ns
        if result is not None and result.exit_code != 0:
            assert result.exit_code in (130, 143) and "after the run was recorded" in result.output
        return "recorded"
    assert summary["status"] == "interrupted" and result is not None
    assert result.exit_code == (143 if signame == "SIGTERM" else 130), result.output
    assert "Traceback" not in result.output
    kind = summary["records"]["mcap"]
    partials = [n for n in names if n.endswith(".partial")]
    if kind == "journal-partial":  # the journal could not be closed: its chunks stay, recover reads them
        assert len(partials) == 1 and summary["files"]["journal"] == partials[0]
        fixed = tmp_path / "fixed.mcap"
        done = runner.invoke(app, ["logs", "recover", str(out / partials[0]), str(fixed)])
        assert done.exit_code in (0, 3), done.output
        rows, _ = _messages(fixed)
    else:
        assert not partials, names
        assert summary["files"]["mcap"] == "track.mcap"
        rows, complete = _messages(out / "track.mcap")
        assert complete
        logs = [data for topic, _, data in rows if topic == "/log"]
        kept = any(b"journal of the simulation so far is kept" in log for log in logs)
        assert kept == (kind == "journal"), kind
        if kind == "complete":  # the final file: the scene and the summary-derived log are in it
            assert any(topic == "/scene" for topic, _, _ in rows) or any(b"done: rms" in log for log in logs)
    # Either way the data up to the signal, i.e. the whole simulation (it had ended), are there.
    assert _last_true_ns(rows) == last_true_ns
    return kind


def _sweep(monkeypatch, baseline, tmp_path, signums, count):
    cfg, base, last_true_ns, after_s = baseline
    seen: dict[str, int] = {}
    for k in range(count):
        signum = signums[k % len(signums)]
        offset = after_s * (k + 0.5) / count
        out = tmp_path / f"run-{k}"
        result, _, _late = _run(monkeypatch, cfg, out, signum, offset)
        monkeypatch.undo()
        kind = _check(out, base, last_true_ns, result, tmp_path, signal.Signals(signum).name)
        seen[kind] = seen.get(kind, 0) + 1
    return seen


def test_a_signal_around_the_final_write_leaves_the_complete_file_or_the_journal(monkeypatch, baseline, tmp_path):
    seen = _sweep(monkeypatch, baseline, tmp_path, (signal.SIGTERM, signal.SIGINT), 6)
    assert sum(seen.values()) == 6


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signals_at_24_offsets_across_the_final_write(monkeypatch, baseline, tmp_path, signum):
    seen = _sweep(monkeypatch, baseline, tmp_path, (signum,), 24)
    assert sum(seen.values()) == 24
    assert seen.get("journal", 0) + seen.get("journal-partial", 0) >= 1 and seen.get("complete", 0) >= 1, seen


# -- item 2: a signal once summary.json is written --------------------------------------------------------------

_SLOW_AFTER = textwrap.dedent("""
    import sys, time
    import oacli.io.runfolder as runfolder
    import oacli.commands.common as common
    where = sys.argv.pop(1)
    if where == "summary":
        original = runfolder.write_summary
        def write_summary(*args, **kwargs):
            path = original(*args, **kwargs)
            if '"status": "ok"' in path.read_text():
                time.sleep(3.0)
            return path
        runfolder.write_summary = write_summary
    else:
        original_table = common.print_table
        def print_table(*args, **kwargs):
            time.sleep(3.0)
            return original_table(*args, **kwargs)
        common.print_table = print_table
    from oacli.cli import main
    sys.argv[0] = "oacli"
    main()
""")


@pytest.mark.parametrize(("where", "signum"), [
    ("summary", signal.SIGTERM), pytest.param("table", signal.SIGINT, marks=pytest.mark.slow),
    pytest.param("summary", signal.SIGINT, marks=pytest.mark.slow),
    pytest.param("table", signal.SIGTERM, marks=pytest.mark.slow),
], ids=["summary-SIGTERM", "table-SIGINT", "summary-SIGINT", "table-SIGTERM"])
def test_a_signal_after_summary_json_keeps_it_and_exits_with_one_line(tmp_path, where, signum, baseline):
    cfg = baseline[0]
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    quiet = ["--quiet"] if where == "summary" else []  # the results table is printed only without --quiet
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_AFTER, where, "track", str(cfg), "--out", str(out), *quiet],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    summary = out / "summary.json"
    while not (summary.exists() and '"ok"' in summary.read_text()):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.01)
    time.sleep(0.3)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signum, err  # never killed by the signal (a negative code), never 1
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "interrupted" in lines[0], err
    assert "Traceback" not in err
    if where == "summary":
        assert "after the run was recorded" in lines[0]
    assert json.loads(summary.read_text())["status"] == "ok"  # the record stands
    rows, complete = _messages(out / "track.mcap")
    assert complete and _last_true_ns(rows) == baseline[2]
