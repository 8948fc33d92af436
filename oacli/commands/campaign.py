"""``oacli campaign``: Monte Carlo runs over dispersions and flight faults, on a process pool or Dask
(``docs/campaign.md``).

Forms::

    oacli campaign CONFIG [--executor local --workers 2] [--dry-run] [--out DIR]
    oacli campaign DIR --resume [--executor ...]
    oacli campaign rerun DIR K [--out DIR]
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from oacli.commands.common import OutOption, QuietOption, RunsDirOption, SetOption, json_text, run_guarded


def _rerun(args: list[str], out: Path | None, quiet: bool, json_out: bool) -> None:
    def action():
        from oacli.campaign.driver import rerun
        from oacli.errors import ConfigError

        if len(args) != 2:
            raise ConfigError("rerun: expected DIR K (a campaign folder and a run index)")
        try:
            k = int(args[1])
        except ValueError:
            raise ConfigError(f"rerun: K: {args[1]!r}: must be a run index (an integer >= 0)") from None
        return rerun(Path(args[0]), k, out)

    outcome = run_guarded(action)
    if json_out:
        typer.echo(json_text(outcome))
    elif not quiet:
        typer.echo(f"run {outcome['k']}: status {outcome['status']}, hash {outcome['hash']}")
        typer.echo(f"manifest hash {outcome['manifest_hash']}: " + ("same, bit for bit" if outcome["same"]
                                                                   else "DIFFERENT"))
    typer.echo(f"rerun folder: {outcome['out']}", err=True)
    if not outcome["same"]:
        raise typer.Exit(1)


def campaign(
    target: Annotated[str, typer.Argument(metavar="CONFIG|DIR|rerun", help="A campaign config (configs/campaign_"
                                          "*.yaml); a campaign folder with --resume; or 'rerun' DIR K.")],
    rest: Annotated[list[str] | None, typer.Argument(metavar="DIR K", help="With 'rerun': the campaign folder "
                                                     "and the run index.")] = None,
    executor: Annotated[str, typer.Option("--executor", metavar="serial|local|dask-local|dask://HOST:PORT",
                                          help="Where runs execute.")] = "local",
    workers: Annotated[int, typer.Option("--workers", help="Worker processes (local, dask-local).")] = 2,
    out: OutOption = None,
    runs_root: RunsDirOption = Path("runs"),
    sets: SetOption = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Write every run's config, then stop.")] = False,
    resume: Annotated[bool, typer.Option("--resume", help="DIR is a campaign folder: rerun its missing and failed "
                                         "runs in place.")] = False,
    quiet: QuietOption = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print the summary as JSON on stdout.")] = False,
) -> None:
    """Fly a job many times over dispersed conditions and flight faults; aggregate the statistics."""
    from oacli.errors import ConfigError

    if target == "rerun":
        _rerun(list(rest or []), out, quiet, json_out)
        return
    say = (lambda line: typer.echo(line, err=True)) if not quiet else None
    from oacli.commands.progress import CampaignProgress

    bar = CampaignProgress(not quiet, workers=workers)

    def action():
        from oacli.campaign.driver import load_campaign, prepare, run_campaign
        from oacli.campaign.executors import check_executor, make_executor
        from oacli.campaign.finalize import finalize
        from oacli.errors import InputError

        check_executor(executor, workers)
        if rest:
            raise ConfigError(f"unexpected arguments {rest} (only 'rerun' takes DIR K)")
        path = Path(target)
        if resume:
            if out is not None or sets:
                raise ConfigError("--resume: a resumed campaign keeps its folder and config (no --out, --set)")
            if not path.is_dir():
                raise InputError(f"{path}: --resume needs a campaign folder")
            folder = path
        else:
            if path.is_dir():
                raise InputError(f"{path}: a folder; give a campaign config, or add --resume")
            campaign_cfg = load_campaign(path, sets)
            folder = prepare(campaign_cfg, out=out, runs_root=runs_root)
            if say:
                say(f"wrote {campaign_cfg.config.runs} run configs to {folder / 'runs'}")
            if dry_run:
                return folder, None
        start = time.perf_counter()
        from oacli.campaign.driver import load_existing

        cfg = load_existing(folder).config
        handle = make_executor(executor, workers, memory_limit_mb=cfg.memory_limit_mb)
        try:
            run_campaign(folder, handle, announce=bar.line if say else None, progress=bar)
        finally:
            bar.close()
            handle.close()
        summary = finalize(folder, wall_time_s=time.perf_counter() - start, executor=handle.kind)
        if cfg.outputs.report:  # report.html from the finalised folder (oacli report; outputs.report: false skips)
            from oacli.commands.report import report_after_run
            report_after_run(folder, say)
        return folder, summary

    folder, summary = run_guarded(action)
    if summary is None:
        typer.echo(f"campaign folder: {folder} (dry run: run configs only)", err=quiet)
        return
    if json_out:
        typer.echo(json_text({**summary, "run_dir": str(folder)}))
    elif not quiet:
        from oacli.campaign.outputs import print_table

        print_table(summary)
    typer.echo(f"campaign folder: {folder}", err=True)
    if summary["missing"]:
        typer.echo(f"warning: {summary['missing']} runs unfinished; oacli campaign {folder} --resume", err=True)
        raise typer.Exit(1)
