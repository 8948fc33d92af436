"""What the CLI prints reads as text: ``--help`` in Unix style, ``--from`` completes stage names,
``oacli info`` prints status findings as lines and points a cut file at ``oacli logs``, and the mission's final
warning is a headline plus one wrapped line per finding."""

from __future__ import annotations

import json
import re

import click
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from oacli.cli import app
from oacli.commands.mission import WARNING_WIDTH, warning_lines
from oacli.io.mcap_write import StageMcapWriter
from oacli.mission.layout import ALL_STAGES

runner = CliRunner()


def _commands(group, path: tuple[str, ...] = ()):
    yield path, group
    if hasattr(group, "commands"):  # a group (typer's own click)
        for name, sub in group.commands.items():
            yield from _commands(sub, (*path, name))


ROOT = typer.main.get_command(app)
ALL_COMMANDS = [path for path, _ in _commands(ROOT)]


@pytest.mark.parametrize("path", ALL_COMMANDS, ids=lambda p: " ".join(p) or "oacli")
def test_help_is_unix_style_without_braces_or_type_tags(path):
    result = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "200", "TERM": "dumb"})
    assert result.exit_code == 0, result.output
    usage = next(line for line in result.output.splitlines() if "Usage:" in line)
    assert "{" not in usage and "}" not in usage, usage
    assert not re.search(r"<(str|int|float|path|bool|list\[[a-z]+\])>", result.output), result.output


def test_required_arguments_are_plain_names_in_the_usage_line():
    result = runner.invoke(app, ["plan", "--help"], env={"COLUMNS": "200", "TERM": "dumb"})
    assert re.search(r"Usage: .* plan \[OPTIONS\] CONFIG\s*$", result.output, re.M), result.output
    result = runner.invoke(app, ["campaign", "--help"], env={"COLUMNS": "200", "TERM": "dumb"})
    assert "CONFIG|DIR|rerun [DIR K]..." in result.output and "--workers" in result.output
    assert re.search(r"--workers\s+INT\b", result.output), result.output


def test_from_completes_the_mission_stage_names():
    mission = ROOT.commands["mission"]
    (option,) = [p for p in mission.params if "--from" in getattr(p, "opts", ())]
    ctx = click.Context(mission)
    offered = [item.value for item in option.shell_complete(ctx, "segment-3/b")]
    assert offered == ["segment-3/baseline-mpc-prior", "segment-3/baseline-tube-prior",
                       "segment-3/baseline-mpc-unconstrained-prior"]  # the optional one too (a study's missions)
    every = [item.value for item in option.shell_complete(ctx, "")]
    assert every == [s.key for s in ALL_STAGES]


def _small_mcap(path):
    x = np.zeros((400, 13))
    x[:, 0] = np.linspace(0.0, 1.0, 400)
    x[:, 9] = 1.0
    with StageMcapWriter(path, stage="track", config_yaml="a: 1\n", time_ordered=True) as w:
        w.write_states("/state/true", np.arange(400) * 0.016, x)
    return path


def test_info_prints_findings_as_lines_and_sends_a_cut_file_to_logs(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    reasons = [{"level": "degraded", "kind": "tube_true", "message": "the true state left the promised tube on 3 "
                "steps"}, {"level": "degraded", "kind": "solver", "message": "1 of 163 controller solves failed"}]
    (run / "summary.json").write_text(json.dumps({"stage": "track", "status": "degraded",
                                                  "status_reasons": reasons}))
    _small_mcap(run / "track.mcap")
    result = runner.invoke(app, ["info", str(run)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert "  - degraded: the true state left the promised tube on 3 steps [tube_true]" in lines
    assert "  - degraded: 1 of 163 controller solves failed [solver]" in lines
    assert "{" not in result.stdout and "'level'" not in result.stdout
    full = (run / "track.mcap").read_bytes()
    (run / "track.mcap").write_bytes(full[: len(full) // 2])  # cut: no summary section, no footer
    result = runner.invoke(app, ["info", str(run / "track.mcap")])
    assert result.exit_code != 0
    (line,) = result.stderr.strip().splitlines()
    assert f"oacli logs verify {run / 'track.mcap'}" in line and f"oacli logs recover {run / 'track.mcap'}" in line
    assert "opcode" not in line and "exceeds" not in line
    (tmp_path / "notes.mcap").write_text("not an mcap")
    result = runner.invoke(app, ["info", str(tmp_path / "notes.mcap")])
    assert result.stderr.strip() == f"error: {tmp_path / 'notes.mcap'}: not an MCAP file"


def test_mission_warning_is_a_headline_and_one_wrapped_line_per_finding():
    reasons = [{"level": "degraded", "kind": "tube_true", "message": f"segment-{k}/track: " + "the true state left "
                "the promised tube on many steps, " * (k + 1) + "end"} for k in range(1, 5)]
    lines = warning_lines({"status": "degraded", "status_reasons": reasons})
    assert lines[0] == "warning: mission status degraded: 4 findings (each stage's summary.json has the details):"
    assert all(len(line) <= WARNING_WIDTH for line in lines)
    starts = [i for i, line in enumerate(lines) if line.startswith("  - ")]
    assert len(starts) == 4 and starts[0] == 1
    for k, (a, b) in enumerate(zip(starts, [*starts[1:], len(lines)], strict=True)):
        text = " ".join(line.strip() for line in lines[a:b])[2:]
        assert text == reasons[k]["message"]  # nothing lost in the wrapping
    assert warning_lines({"status": "ok", "status_reasons": []}) == []
