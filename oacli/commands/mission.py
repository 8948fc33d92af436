"""``oacli mission``: the three-segment assembly mission in one command (``docs/mission.md``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from oacli.commands.common import (
    JsonOption,
    OutOption,
    Progress,
    QuietOption,
    RunsDirOption,
    SeedOption,
    SetOption,
    ViewOption,
    format_value,
    json_text,
    load_config_with_seed,
    run_guarded,
)

COMPARISON_COLUMNS = [
    ("status", "status"), ("rms_position_error_m", "RMS err m"), ("max_position_error_m", "max err m"),
    ("overshoot_m", "overshoot m"), ("control_effort_Ns", "effort N·s"), ("time_saturated_s", "saturated s"),
    ("arrival_time_s", "arrival s"), ("keep_in_violations", "keep-in"), ("keep_out_violations", "keep-out"),
    ("limit_violations", "limits"),
]


def print_mission_tables(summary: dict[str, Any]) -> None:
    """The stages (status, wall time), the estimate and the segment-3 comparison, as aligned text on stdout.

    Parameters
    ----------
    summary : dict
        The mission's summary.
    """
    robot_time = summary.get("mission_time_s")
    flown = "" if robot_time is None else f", {robot_time:.1f} s of robot time"
    typer.echo(f"mission {summary['name']}: status {summary['status']}{flown} in "
               f"{summary.get('wall_time_s', 0.0):.1f} s")
    if summary.get("stopped"):
        typer.echo(f"stopped: {summary['stopped']}")
    width = max(len(k) for k in summary["stages"])
    for key, entry in summary["stages"].items():
        wall = entry.get("wall_time_s")
        typer.echo(f"  {key:<{width}}  {entry['status']:<10} {'' if wall is None else f'{wall:7.1f} s'}")
    cal = summary.get("calibration") or {}
    if cal.get("source") == "calibration":
        scales = "; ".join(
            f"{group.replace('_', ' ')} " + " / ".join(f"{k:.4f} ± {s:.4f}" for k, s in zip(
                cal[group], cal[f"{group}_std"], strict=True))
            for group in ("force_scale", "torque_scale") if group in cal)
        typer.echo(f"actuator calibration (segment 1, [ReSWARM2023] Eqs. 38-39): {scales}, segment 2's prior")
    elif cal.get("note"):
        typer.echo(f"actuator calibration: {cal['note']}")
    est = summary.get("estimate") or {}
    if est.get("error_pct"):
        typer.echo("estimate (batch) error %: " + format_value(est["error_pct"])
                   + "   (flight, [ReSWARM2023]: mass 0.39, inertias 0.91 / 1.35 / 6.92)")
    rows = summary.get("comparison", {})
    if rows:
        typer.echo("segment 3 ([Doerr2021] Fig. 3(d)):")
        label_w = max(len(r["label"]) for r in rows.values())
        typer.echo(f"  {'':<{label_w}}  " + "  ".join(f"{h:>11}" for _, h in COMPARISON_COLUMNS))
        for row in rows.values():
            cells = []
            for key, _ in COMPARISON_COLUMNS:
                value = row.get(key)
                cells.append(f"{'-' if value is None else format_value(value)[:11]:>11}")
            typer.echo(f"  {row['label']:<{label_w}}  " + "  ".join(cells))


def complete_stage(incomplete: str) -> list[str]:
    """Shell completion of ``--from``: the mission's stage keys (``segment-3/track``, ...) starting with what was
    typed."""
    from oacli.mission.layout import ALL_STAGES

    return [s.key for s in ALL_STAGES if s.key.startswith(incomplete)]


#: Width of the mission's final warning lines (wrapped, one finding a line).
WARNING_WIDTH = 110


def warning_lines(summary: dict[str, Any]) -> list[str]:
    """The mission's final warning on stderr: a headline naming the status and how many findings, then one wrapped
    line per finding (``- <stage key>: <what happened>``) instead of one line joining them all; [] for ``ok``.

    Parameters
    ----------
    summary : dict
        The mission's summary (``status``, ``status_reasons``).

    Returns
    -------
    list of str
    """
    import textwrap

    from oacli.status import warning_line

    status = summary.get("status", "ok")
    reasons = [r.get("message", "") if isinstance(r, dict) else str(r) for r in summary.get("status_reasons", ())]
    if status == "ok":
        return []
    if not reasons:
        line = warning_line(summary)
        return [] if line is None else [line]
    lines = [f"warning: mission status {status}: {len(reasons)} finding{'s' if len(reasons) != 1 else ''} "
             "(each stage's summary.json has the details):"]
    for text in reasons:
        lines += textwrap.wrap(text, WARNING_WIDTH, initial_indent="  - ", subsequent_indent="    ",
                               break_on_hyphens=False) or ["  -"]
    return lines


def mission(
    target: Annotated[
        Path, typer.Argument(metavar="TARGET", help="A mission config (YAML with a mission section, see "
                             "configs/mission_*.yaml), or a mission folder with --resume or --from.")
    ],
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    seed: SeedOption = None,
    quiet: QuietOption = False,
    sets: SetOption = None,
    json_out: JsonOption = False,
    view: ViewOption = False,
    resume: Annotated[
        bool, typer.Option("--resume", help="TARGET is an interrupted mission folder: keep its complete stages, "
                           "rerun the rest in place.")
    ] = False,
    from_stage: Annotated[
        str | None, typer.Option("--from", metavar="STAGE", autocompletion=complete_stage,
                                 help="TARGET is a mission folder: rerun from this "
                                 "stage (e.g. segment-3/track) into a new folder, copying the earlier stages' folders.")
    ] = None,
    in_line: Annotated[
        bool, typer.Option("--in-line", help="Run every stage in line on one core. By default, on a machine with "
                           "two or more cores, the stages the flight does not wait for (the calibrations, the "
                           "sequential estimate, the segment-3 baselines, mission.mcap) run beside it in a second "
                           "process: the same files and numbers, less wall time.")
    ] = False,
) -> None:
    """Fly the assembly mission A → B → C → A: plan, smooth, track (segment 1); excite, tube MPC, estimate
    (segment 2); plan, smooth, tube MPC with the learned model and the two baselines (segment 3)."""
    from oacli.status import exit_code

    def action():
        from oacli.config import load_config
        from oacli.errors import ConfigError, InputError
        from oacli.io.runfolder import is_complete
        from oacli.mission.layout import stage_by_key
        from oacli.mission.run import copy_stages_before, run_mission, start_mission, validate_mission

        if resume and from_stage is not None:
            raise ConfigError("--resume and --from: give one of them")
        if resume or from_stage is not None:
            if not (target.is_dir() and (target / "config.yaml").is_file()):
                raise InputError(f"{target}: not a mission folder (no config.yaml)")
            if seed is not None:
                raise ConfigError("--seed: a resumed or rerun mission keeps its folder's seed")
            cfg = load_config(target / "config.yaml")
        else:
            if target.is_dir():
                raise InputError(f"{target}: a folder; give a config file, or add --resume / --from STAGE")
            cfg = load_config_with_seed(target, seed, sets)
        validate_mission(cfg)
        if resume:
            if out is not None:
                raise ConfigError("--out: a resumed mission continues in its own folder")
            if is_complete(target):
                raise InputError(f"{target}: the mission is complete; use --from STAGE to rerun part of it")
            mission_dir = target
        else:
            if from_stage is not None:
                try:
                    stage_by_key(from_stage)
                except KeyError as exc:
                    raise ConfigError(f"--from: {exc.args[0]}") from None
                from oacli.mission.run import mission_stages
                if from_stage.strip("/") not in [s.key for s in mission_stages(cfg)]:
                    raise ConfigError(f"--from: {from_stage} is not a stage of this mission (an optional stage it "
                                      "does not run: mission.calibration, mission.baselines)")
            mission_dir = start_mission(cfg, out=out, runs_root=runs_root)
            if from_stage is not None:
                copy_stages_before(target, mission_dir, cfg, from_stage)
        say = (lambda line: typer.echo(line, err=True)) if not (quiet or json_out) else None
        from oacli.mission.background import background_workers_default

        result = run_mission(cfg, mission_dir, progress=lambda key: Progress(f"  {key}", not quiet), announce=say,
                             background=not in_line and background_workers_default() > 0)
        if cfg.outputs.report:  # report.html from the finished folder (oacli report; outputs.report: false skips)
            from oacli.commands.report import report_after_run
            from oacli.signals import note_recorded

            try:
                report_after_run(result.run_dir, say)
            except KeyboardInterrupt:  # the mission is recorded (summary.json): say so, exit 130/143
                note_recorded(result.run_dir / "summary.json", str(result.summary.get("status")))
                raise
        return result

    result = run_guarded(action)
    for line in warning_lines(result.summary):
        typer.echo(line, err=True)
    if json_out:
        typer.echo(json_text({**result.summary, "run_dir": str(result.run_dir)}))
    elif not quiet:
        print_mission_tables(result.summary)
    typer.echo(f"run folder: {result.run_dir}", err=quiet or json_out)
    if view:
        from oacli.commands.view import open_in_viewer

        open_in_viewer(result.run_dir)
    code = exit_code(result.summary.get("status", "ok"))
    if code:
        raise typer.Exit(code)
