"""A SIGINT or SIGTERM at any moment of a mission's final write (``mission.rrd``, ``plots/``,
``summary.json``) leaves either the complete mission or an ``interrupted`` one whose stage folders are all still
complete, and ``oacli mission --resume`` then finishes it.

The shared mission of ``conftest.py`` (``mission_run``) is copied and its summary marked ``interrupted`` -- the
state a signal at the start of the final write leaves -- and each copy is resumed (only the final write runs again)
with a real signal sent to this process at an offset across that write, measured by a first resume. The default
suite sends 2 signals; the slow suite 20 of each kind.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

import oacli.mission.recording as mission_recording_module
from oacli.cli import app
from oacli.io.runfolder import is_complete
from oacli.mission.layout import MISSION_STAGES

# A signal raised inside a weakref callback (matplotlib) is printed as "Exception ignored" and reported by pytest;
# the command still ends 130/143 (oacli.signals.delivered), which the checks assert.
pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
runner = CliRunner()


def _interrupted_copy(source: Path, target: Path) -> Path:
    shutil.copytree(source, target, symlinks=True)
    summary = json.loads((target / "summary.json").read_text())
    (target / "summary.json").write_text(json.dumps({"stage": "mission", "status": "interrupted",
                                                     "error": "terminated by SIGTERM",
                                                     "stages": summary["stages"]}))
    for path in (target / "mission.rrd", target / "plots"):
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    return target


def _resume(folder: Path, monkeypatch: pytest.MonkeyPatch, signum: int | None, offset_s: float):
    """``oacli mission FOLDER --resume`` with ``signum`` sent ``offset_s`` after the final write begins."""
    started: list[float] = []
    timers: list[threading.Timer] = []
    original = mission_recording_module.write_mission_recording

    def recording_then_shoot(*args, **kwargs):
        started.append(time.perf_counter())
        if signum is not None:
            timers.append(threading.Timer(offset_s, os.kill, (os.getpid(), signum)))
            timers[-1].start()
        return original(*args, **kwargs)

    monkeypatch.setattr(mission_recording_module, "write_mission_recording", recording_then_shoot)
    previous = signal.signal(signal.SIGTERM, lambda *_: None)  # a SIGTERM after the command ends: harmless here
    result = None
    try:
        try:
            result = runner.invoke(app, ["mission", str(folder), "--resume", "-q"])
            for timer in timers:
                timer.cancel()
                timer.join()
        except KeyboardInterrupt:  # the SIGINT came after the command returned
            pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        monkeypatch.undo()
    return result, (time.perf_counter() - started[0]) if started else 0.0


def _check(folder: Path, result, signame: str) -> str:
    summary = json.loads((folder / "summary.json").read_text())
    for stage in MISSION_STAGES:  # the stages are never touched by the final write
        assert is_complete(stage.folder(folder)), stage.key
    assert not list(folder.glob(".*.partial")) and not list(folder.glob("plots/.*.partial"))
    if summary["status"] in ("ok", "degraded", "unsafe"):
        assert (folder / "mission.rrd").is_file()
        for name in summary["files"].get("plots", {}).values():
            assert (folder / name).is_file(), name
        if result is not None and result.exit_code not in (0, 4):
            assert result.exit_code in (130, 143) and "after the run was recorded" in result.output
        return "complete"
    assert summary["status"] == "interrupted", summary
    if result is not None:
        assert result.exit_code == (143 if signame == "SIGTERM" else 130), result.output
        assert "Traceback" not in result.output and "internal error" not in result.output
    assert "oacli mission --resume" in summary["resume"]
    return "interrupted"


@pytest.fixture(scope="module")
def final_write(mission_run, tmp_path_factory):
    """The shared mission, and how long its final write takes (a resume of an interrupted copy)."""
    folder = _interrupted_copy(mission_run[0], tmp_path_factory.mktemp("mission_final") / "base")
    mp = pytest.MonkeyPatch()
    result, duration_s = _resume(folder, mp, None, 0.0)
    assert result is not None and result.exit_code in (0, 4), result.output
    assert json.loads((folder / "summary.json").read_text())["status"] in ("ok", "degraded", "unsafe")
    return mission_run[0], duration_s


def _sweep(final_write, tmp_path, monkeypatch, signums, count) -> dict[str, int]:
    source, duration_s = final_write
    seen: dict[str, int] = {}
    last_interrupted = None
    for k in range(count):
        signum = signums[k % len(signums)]
        folder = _interrupted_copy(source, tmp_path / f"m-{k}")
        result, _ = _resume(folder, monkeypatch, signum, duration_s * (k + 0.5) / count)
        kind = _check(folder, result, signal.Signals(signum).name)
        seen[kind] = seen.get(kind, 0) + 1
        if kind == "interrupted":
            last_interrupted = folder
    if last_interrupted is not None:  # an interrupted final write is finished by a resume
        result, _ = _resume(last_interrupted, monkeypatch, None, 0.0)
        assert result is not None and result.exit_code in (0, 4), result.output
        assert _check(last_interrupted, result, "") == "complete"
    return seen


def test_a_signal_during_the_missions_final_write_leaves_it_resumable(final_write, tmp_path, monkeypatch):
    seen = _sweep(final_write, tmp_path, monkeypatch, (signal.SIGTERM, signal.SIGINT), 2)
    assert sum(seen.values()) == 2


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signals_at_20_offsets_across_the_missions_final_write(final_write, tmp_path, monkeypatch, signum):
    seen = _sweep(final_write, tmp_path, monkeypatch, (signum,), 20)
    assert sum(seen.values()) == 20 and seen.get("interrupted", 0) >= 1, seen
