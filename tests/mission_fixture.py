"""A small real mission folder, built by running the stage commands into the layout of :mod:`oacli.mission.layout`.

Used by the tests of the mission's recording and plots before (and independently of) ``oacli mission``: every stage
sub-folder is what that stage command writes, on a shrunk ``configs/doerr2021.yaml`` (short planner budget, few
excitation steps, short holds); the mission ``summary.json`` is written by hand following the contract
(``/work/notes/mission_contract.md``, :mod:`oacli.mission.run`).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import yaml
from typer.testing import CliRunner

from oacli.io.mcap_io import read_trajectory
from oacli.mission.layout import BASELINES, stage_by_key

REPO = Path(__file__).resolve().parents[1]
DOERR = REPO / "configs" / "doerr2021.yaml"

#: Plant with the printed object ([Doerr2021] Table 1), flown in segments 2 and 3.
TRUTH_WITH_OBJECT = {"mass_kg": 15.0, "inertia_kgm2": [0.1464, 0.1376, 0.1604]}

_TUBE = {
    "prediction_step_s": 1.0,
    "terminal": {"position": 100.0, "velocity": 10.0},
    "ancillary": {"position": 5.0, "velocity": 10.0, "force": 2.0},
    "rpi_epsilon": 0.05,
    "disturbance": {"mass_std_kg": 0.5, "mass_sigmas": 2.0, "force_N": [0.002, 0.002, 0.002],
                    "on_empty_tightening": "scale_w"},
    "solver": "direct",
}


def _shrunk(base: dict[str, Any]) -> dict[str, Any]:
    cfg = copy.deepcopy(base)
    cfg["name"] = "mission-fixture"
    cfg["simulation"]["settle_time_s"] = 1.0
    cfg["reference"]["hold_s"] = 0.5
    cfg["planner"].update({"time_budget_s": 2.0, "max_iterations": 300})
    cfg["planner"]["shortcut"]["tries"] = 30
    cfg["planner"]["polish"]["enabled"] = False
    cfg["excitation"].update({"duration_s": 20.0, "steps": 12})
    # C of the preset lies within the robot radius of the truss (keep-out 3): C -> A could not start there.
    cfg["waypoints"]["C"]["position"] = [0.2, -0.8, 0.0]
    return cfg


def _configs(root: Path) -> dict[str, Path]:
    """Write the stage configs of the fixture: standard MPC with the bare robot (segment 1), tube MPC with the
    object's prior (segment 2 and the tube baselines), standard MPC with the prior (baseline-mpc-prior)."""
    base = _shrunk(yaml.safe_load(DOERR.read_text()))
    prior = copy.deepcopy(base)
    prior["truth"] = copy.deepcopy(TRUTH_WITH_OBJECT)
    prior["robot"]["mass_kg"] = 13.0  # the prior: a guess of the loaded robot, 2 kg off
    tube = copy.deepcopy(prior)
    tube["controller"]["type"] = "tube"
    tube["controller"]["horizon"] = 5
    tube["controller"]["tube"] = copy.deepcopy(_TUBE)
    estimate_tube = copy.deepcopy(tube)
    estimate_tube["robot"].update(copy.deepcopy(TRUTH_WITH_OBJECT))  # stands in for the learned model
    estimate_tube["controller"]["tube"]["disturbance"]["mass_std_kg"] = 0.1
    paths = {}
    for name, cfg in (("segment-1", base), ("prior-mpc", prior), ("prior-tube", tube),
                      ("estimate-tube", estimate_tube)):
        paths[name] = root / f"{name}.yaml"
        paths[name].write_text(yaml.safe_dump(cfg, sort_keys=False))
    return paths


def _run(runner: CliRunner, *args: Any) -> None:
    from oacli.cli import app

    result = runner.invoke(app, [str(a) for a in args])
    if result.exit_code != 0:
        raise RuntimeError(f"oacli {' '.join(map(str, args))} failed ({result.exit_code}):\n{result.output}")


def build_mission_folder(mission_dir: Path, config_dir: Path) -> dict[str, Any]:
    """Run the stages of a mission into ``mission_dir`` and write its ``summary.json``.

    Parameters
    ----------
    mission_dir : Path
        The mission folder to create (must not exist).
    config_dir : Path
        Where the stage configs are written (outside the mission folder).

    Returns
    -------
    dict
        The mission summary written to ``mission_dir/summary.json``.
    """
    runner = CliRunner()
    config_dir.mkdir(parents=True, exist_ok=True)
    cfg = _configs(config_dir)
    m = Path(mission_dir)

    def folder(key: str) -> Path:
        return stage_by_key(key).folder(m)

    def mcap(key: str) -> Path:
        return stage_by_key(key).mcap(m)

    _run(runner, "plan", cfg["segment-1"], "--segment", "A-B", "--out", folder("segment-1/plan"), "-q")
    _run(runner, "smooth", cfg["segment-1"], "--input", mcap("segment-1/plan"), "--out", folder("segment-1/smooth"),
         "-q")
    _run(runner, "track", cfg["segment-1"], "--reference", mcap("segment-1/smooth"), "--out",
         folder("segment-1/track"), "-q")
    _run(runner, "excite", cfg["prior-tube"], "--out", folder("segment-2/excite"), "-q")
    _run(runner, "track", cfg["prior-tube"], "--reference", mcap("segment-2/excite"), "--out",
         folder("segment-2/track"), "-q")
    for key, method in (("segment-2/estimate-sequential", "sequential"), ("segment-2/estimate", "batch")):
        _run(runner, "estimate", cfg["prior-tube"], "--telemetry", mcap("segment-2/track"), "--method", method,
             "--out", folder(key), "-q")
    _run(runner, "plan", cfg["estimate-tube"], "--segment", "C-A", "--out", folder("segment-3/plan"), "-q")
    _run(runner, "smooth", cfg["estimate-tube"], "--input", mcap("segment-3/plan"), "--out",
         folder("segment-3/smooth"), "-q")
    for key, name in (("segment-3/track", "estimate-tube"), ("segment-3/baseline-mpc-prior", "prior-mpc"),
                      ("segment-3/baseline-tube-prior", "prior-tube")):
        _run(runner, "track", cfg[name], "--reference", mcap("segment-3/smooth"), "--out", folder(key), "-q")

    summary = _summary(m)
    (m / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def _summary(m: Path) -> dict[str, Any]:
    """The mission summary of the contract, from the stage folders' summaries."""

    def stage_summary(key: str) -> dict[str, Any]:
        return json.loads((stage_by_key(key).folder(m) / "summary.json").read_text())

    durations = {}
    for seg in ("segment-1", "segment-2", "segment-3"):
        t = read_trajectory(stage_by_key(f"{seg}/track").mcap(m), "/state/true").t
        durations[seg] = float(t[-1] - t[0])
    starts = {"segment-1": 0.0, "segment-2": durations["segment-1"]}
    starts["segment-3"] = starts["segment-2"] + durations["segment-2"]
    legs = {"segment-1": ("A", "B"), "segment-2": ("B", "C"), "segment-3": ("C", "A")}
    est = stage_summary("segment-2/estimate")
    comparison = {}
    for key, label in BASELINES.items():
        s = stage_summary(key)
        comparison[key] = {"label": label, "status": s.get("status"),
                           **{k: v for k, v in s.items() if k.endswith(("_error_m", "_rad"))}}
    return {
        "stage": "mission", "status": "ok", "name": "mission-fixture", "seed": 0,
        "segments": {seg: {"from": a, "to": b, "start_time_s": starts[seg], "duration_s": durations[seg]}
                     for seg, (a, b) in legs.items()},
        "grasp_time_s": starts["segment-2"],
        "stages": {key: {"status": stage_summary(key).get("status"), "wall_time_s": None, "folder": key}
                   for key in (s.key for s in _stages())},
        "comparison": comparison,
        "estimate": {k: est.get(k) for k in ("mass_kg", "inertia_kgm2", "std", "truth_theta", "error_pct")},
        "files": {"config": "config.yaml", "rrd": "mission.rrd", "plots": [], "summary": "summary.json"},
    }


def _stages():
    from oacli.mission.layout import MISSION_STAGES

    return MISSION_STAGES
