"""Progress that is never silent nor absurd, and a campaign's "success" said where it is printed.
"""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from oacli.campaign.outputs import table_rows
from oacli.cli import app
from oacli.commands import progress as progress_module
from oacli.commands.progress import CampaignProgress, Progress
from tests.test_campaign import tiny_campaign


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_pipe_progress_prints_no_zero_percent_line(monkeypatch, capsys):
    clock = Clock()
    monkeypatch.setattr(progress_module.time, "perf_counter", clock)
    bar = Progress("track", True)
    bar.tty = False
    clock.now += 0.05
    bar(0.0)
    bar(0.002)  # a first tiny step: its ETA would be 25 s for a 0.05 s start
    assert capsys.readouterr().err == ""
    clock.now += 0.95  # 1 s in, 25 % done: 3 s left
    bar(0.25)
    clock.now += 3.0
    bar(1.0)
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["track: 25% (1.0 s, ETA 3 s)", "track: 100% (4.0 s)"]


def test_campaign_bar_shows_runs_and_eta_from_the_start(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(progress_module.time, "perf_counter", clock)
    bar = CampaignProgress(True, workers=2)
    bar.tty = True  # the rich bar, as on a terminal
    clock.now += 50.0  # preparing the run configs: not a run's time
    bar(0, 4)
    fields = bar._bar.tasks[0].fields
    assert fields == {"runs": "0/4 runs", "eta": "estimating…"}  # shown before any run ends
    clock.now += 30.0
    bar(1, 4)  # one run in 30 s, three left: 90 s
    task = bar._bar.tasks[0]
    assert task.fields == {"runs": "1/4 runs", "eta": "0:01:30"} and task.completed == 1 and task.total == 4
    bar(4, 4)
    assert bar._bar is None  # closed at the end


def test_campaign_pipe_lines_carry_elapsed_and_eta(monkeypatch, capsys):
    clock = Clock()
    monkeypatch.setattr(progress_module.time, "perf_counter", clock)
    bar = CampaignProgress(True, workers=1)
    bar.tty = False
    bar(0, 2)
    clock.now += 10.0
    bar(1, 2)
    bar.line("run 0: degraded [1/2]")
    clock.now += 10.0
    bar(2, 2)
    bar.line("run 1: ok [2/2]")
    assert capsys.readouterr().err.splitlines() == [
        "campaign: 2 runs, 1 at a time", "run 0: degraded [1/2] (10 s, ETA 10 s)", "run 1: ok [2/2] (20 s)"]


def test_success_rate_says_what_success_means():
    summary = {"runs": 4, "finished": 4, "success_rate": 1.0, "faults": {},
               "status_counts": {"ok": 0, "degraded": 4, "unsafe": 0, "failed": 0, "infra_failed": 0},
               "violations": {"keep_in": 0, "keep_out": 0, "limits": 0}, "tube_violations_true": 0,
               "fallback_steps": 0, "tracking": {"rms_position_error_m": {"p5": None, "p50": None, "p95": None}}}
    rows = dict(table_rows(summary))
    (label,) = [k for k in rows if k.startswith("success rate")]
    assert "ok or degraded" in label and "safety breach" in label
    assert rows[label] == "100.0 % (0 ok + 4 degraded of 4 runs)"


@pytest.mark.slow  # two closed-loop runs and the campaign's outputs: about 12 s
def test_campaign_cli_announces_the_runs_first_and_defines_success(tmp_path):
    path = tiny_campaign(tmp_path, runs=2)
    result = CliRunner().invoke(app, ["campaign", str(path), "--executor", "serial", "--out", str(tmp_path / "c")])
    assert result.exit_code == 0, result.output
    err = result.stderr
    assert err.index("campaign: 2 runs, ") < err.index("run 0: ")
    first_run = re.search(r"run \d: \w+ \[1/2\] \((\d+) s, ETA (\d+) s\)", err)
    assert first_run, err
    counts = re.search(r"success rate \(success: the run ended ok or degraded.*?(\d+) ok \+ (\d+) degraded of 2 "
                       r"runs", result.stdout, re.S)
    assert counts, result.stdout
    statuses = re.findall(r"run \d: (\w+) \[", err)
    assert int(counts.group(1)) == statuses.count("ok") and int(counts.group(2)) == statuses.count("degraded")
