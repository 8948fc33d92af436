"""Choices and clean metavars in --help, strict --json, stage names in run folders, and
named phases in the progress output."""

from __future__ import annotations

import json
import re
from typing import get_args

import pytest
from typer.testing import CliRunner

from oacli.cli import app
from oacli.commands import estimate as estimate_cmd
from oacli.commands import excite as excite_cmd
from oacli.commands import plan as plan_cmd
from oacli.commands.common import complete_choices, json_text
from oacli.config.estimation import EstimationMethod
from oacli.config.excitation import ExcitationConfig
from oacli.config.planner import PlannerType
from oacli.excitation.design import design_excitation
from oacli.excitation.design_types import ScpSettings
from tests.conftest import REPO

DOERR = REPO / "configs" / "doerr2021.yaml"
COMMANDS = (["plan"], ["smooth"], ["track"], ["excite"], ["estimate"], ["mission"], ["plots"], ["info"],
            ["runs", "list"], ["config", "show"], [])


def run_cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "200", "TERM": "dumb"})


def test_choices_are_the_config_values():
    assert plan_cmd.PLANNERS == get_args(PlannerType)
    assert estimate_cmd.METHODS == get_args(EstimationMethod)
    assert excite_cmd.METHODS == get_args(ExcitationConfig.model_fields["method"].annotation)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c) or "oacli")
def test_help_names_values_not_python_types(command):
    result = run_cli(*command, "--help")
    assert result.exit_code == 0, result.output
    assert not re.search(r"<(bool|str|int|float)>", result.output), result.output
    expected = {"plan": "[lqr-rrt-star|kino-rrt]", "excite": "[offline|rattle]", "estimate": "[batch|sequential|rls]"}
    if command and command[0] in expected:
        assert expected[command[0]] in result.output


def test_choices_complete_in_the_shell():
    assert complete_choices(plan_cmd.PLANNERS)("k") == ["kino-rrt"]
    assert complete_choices(estimate_cmd.METHODS)("") == ["batch", "sequential", "rls"]


@pytest.mark.parametrize("args,option", [(("plan", DOERR, "--planner", "rrt"), "--planner rrt"),
                                         (("excite", DOERR, "--method", "magic"), "--method magic")])
def test_a_value_outside_the_choices_is_one_line(tmp_path, args, option):
    result = run_cli(*args, "--runs-dir", tmp_path / "runs")
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [result.stderr.strip()]
    assert result.stderr.startswith(f"error: {option}: must be one of ")
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_json_text_is_strict():
    import numpy as np

    text = json_text({"a": float("nan"), "b": [np.float64(1.5), float("inf")], "c": np.arange(2), "p": REPO})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict constant {c}")) == {
        "a": None, "b": [1.5, None], "c": [0, 1], "p": str(REPO)}


def test_track_run_folder_named_by_stage_strict_json_and_phases(tmp_path):
    runs = tmp_path / "runs"
    result = run_cli("track", DOERR, "--set", "simulation.settle_time_s=1", "--runs-dir", runs, "--json")
    assert result.exit_code == 0, result.output
    (run_dir,) = runs.iterdir()
    assert re.fullmatch(r"doerr2021-track-\d{8}T\d{6}Z", run_dir.name), run_dir.name
    printed = json.loads(result.stdout, parse_constant=lambda c: pytest.fail(f"non-strict constant {c}"))
    assert printed["run_dir"] == str(run_dir)
    assert printed == {**json.loads((run_dir / "summary.json").read_text()), "run_dir": str(run_dir)}
    # progress (stderr, not a terminal: a line every 25 %) names the phase
    assert re.search(r"^track: closed-loop simulation: 100% ", result.stderr, re.M), result.stderr


def test_scp_iterations_are_named_phases():
    from tests.test_excitation_design import problem

    class Recorder:
        def __init__(self):
            self.phases, self.fractions = [], []

        def __call__(self, fraction):
            self.fractions.append((self.phases[-1] if self.phases else None, fraction))

        def phase(self, name):
            self.phases.append(name)

    rec = Recorder()
    design = design_excitation(problem(n=20), ScpSettings(max_iterations=4, starts=2, screening_iterations=1),
                               progress=rec)
    assert rec.phases[:2] == ["screening start 1/2", "screening start 2/2"]
    scp = rec.phases[2:]
    assert scp == [f"SCP iteration {k}/4" for k in range(2, 2 + len(scp))]  # the best start continues from 1
    assert len(design.iterations) >= 1 and rec.fractions[-1] == (rec.phases[-1], 1.0)
