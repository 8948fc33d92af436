"""The campaign driver: write every run's config first, then run them on an executor with failure isolation.

Folder layout (``docs/campaign.md``)::

    <campaign>/campaign.yaml        the resolved campaign config (+ oacli version)
    <campaign>/base.yaml            the resolved base config (``set`` merged)
    <campaign>/runs/run-KKKKK/spec.json   run k's spec: its config, seed and draws (written first, atomically)
    <campaign>/runs.json            index of the specs, written after the last spec (the preparation is complete)
    <campaign>/runs/run-KKKKK/attempt-N/  each attempt's files and result.json
    <campaign>/manifest.jsonl       append-only, one line per finished attempt (:mod:`oacli.campaign.manifest`)
    <campaign>/summary.json, plots/, campaign.rrd, campaign.mcap   the aggregates (:mod:`oacli.campaign.outputs`)

Failure isolation: a run whose simulation raises is ``failed`` (traceback kept; not retried). A worker death,
timeout or out-of-memory is retried up to ``max_retries`` times, then ``infra_failed``. When several runs were in
flight as a process pool broke, no one knows which killed it: they are rerun one at a time ("solo") without
being charged, and a run is charged only for a death while it ran alone (or for its own timeout or MemoryError).
The other runs are untouched.
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from oacli import __version__
from oacli.campaign import manifest
from oacli.campaign.cells import campaign_cells
from oacli.campaign.executors import ExecutorHandle
from oacli.campaign.jobs import STATUS_OOM, execute_run
from oacli.campaign.sampling import sample_run
from oacli.config import ConfigError, config_from_dict, dump_config, load_config, read_yaml_file
from oacli.config.campaign import CampaignConfig
from oacli.config.mission import deep_merge
from oacli.errors import InputError
from oacli.io.atomic import write_text_atomic
from oacli.io.folder_lock import folder_lock
from oacli.io.jsonsafe import to_json_safe
from oacli.io.runfolder import create_run_dir

POLL_S = 0.2


@dataclass(frozen=True)
class Campaign:
    """A loaded campaign: its config and the resolved base config as plain data."""

    config: CampaignConfig
    base: dict[str, Any]


def load_campaign(path: Path, sets: list[str] | None = None) -> Campaign:
    """Read a campaign file, its base config (``set`` and ``--set base.…`` merged) and validate both.

    Parameters
    ----------
    path : Path
        The campaign YAML.
    sets : list of str, optional
        ``--set`` overrides of the campaign (``runs=10``, ``dispersions.mass_pct=1``, ``set.seed=3`` ...).

    Returns
    -------
    Campaign

    Raises
    ------
    ConfigError
        One line per problem, naming the file and the field.
    """
    from pydantic import ValidationError

    from oacli.config import format_validation_errors
    from oacli.config.overrides import apply_overrides

    path = Path(path)
    data = read_yaml_file(path)  # bounded read, strict YAML 1.2 loader: as for every config file
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping (runs, base, dispersions, faults ...)")
    data = apply_overrides(data, sets)
    try:
        cfg = CampaignConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_errors(exc, str(path))) from None
    base_path = (path.parent / cfg.base) if not Path(cfg.base).is_absolute() else Path(cfg.base)
    base_cfg = load_config(base_path)
    base = yaml.safe_load(dump_config(base_cfg))
    if cfg.set:
        base = deep_merge(base, cfg.set)
    base_dir = str(base_path.resolve().parent)
    for key in ("reference",):  # relative files of the base resolve against its folder, wherever runs execute
        section = base.get(key) or {}
        if section.get("file") and not Path(section["file"]).is_absolute():
            section["file"] = str(Path(base_dir) / section["file"])
    checked = config_from_dict(base, source=f"{base_path} (with {path}: set)", base_dir=base_dir)
    if cfg.job == "mission" and checked.mission is None:
        raise ConfigError(f"{path}: job: mission needs a base config with a mission section ({base_path} has none)")
    if cfg.job != "mission" and checked.reference.source == "waypoints" and not checked.reference.waypoints:
        raise ConfigError(f"{path}: job: {cfg.job} needs a base config with a reference ({base_path} has none)")
    return Campaign(cfg, yaml.safe_load(dump_config(checked)))


def run_dir(campaign_dir: Path, k: int) -> Path:
    """Folder of run ``k``."""
    return Path(campaign_dir) / "runs" / f"run-{k:05d}"


def read_spec(campaign_dir: Path, k: int) -> dict[str, Any]:
    """Run ``k``'s spec as written before the campaign ran.

    Raises
    ------
    InputError
        No such run in the campaign.
    """
    path = run_dir(campaign_dir, k) / "spec.json"
    if not path.exists():
        raise InputError(f"{campaign_dir}: no run {k} (no {path})")
    return json.loads(path.read_text())


def prepare(campaign: Campaign, *, out: Path | None, runs_root: Path) -> Path:
    """Create the campaign folder and write every run's spec (each atomically), then ``runs.json``.

    Parameters
    ----------
    campaign : Campaign
    out, runs_root : Path
        As for every stage (:func:`oacli.io.runfolder.create_run_dir`; an existing folder is never overwritten).

    Returns
    -------
    Path
        The campaign folder.
    """
    cfg = campaign.config
    folder = create_run_dir(f"campaign-{cfg.name}", out=out, runs_root=runs_root)
    write_text_atomic(folder / "campaign.yaml", yaml.safe_dump(
        {"oacli_version": __version__, **cfg.model_dump(mode="json")}, sort_keys=False))
    write_text_atomic(folder / "base.yaml", yaml.safe_dump(campaign.base, sort_keys=False))
    write_specs(campaign, folder)
    return folder


def write_specs(campaign: Campaign, folder: Path) -> None:
    """Write the spec of every run that has none yet (validating its config), then ``runs.json``."""
    cfg = campaign.config
    index = {}
    first_of_cell = max(len(campaign_cells(cfg)), 1)
    for k in range(cfg.runs):
        rdir = run_dir(folder, k)
        spec = sample_run(cfg, campaign.base, k)
        spec["oacli_version"] = __version__
        path = rdir / "spec.json"
        if not path.exists():
            cell = f" (cell {spec['cell']})" if "cell" in spec else ""
            run_cfg = config_from_dict(spec["config"], source=f"run {k}{cell}")  # a dispersion or cell breaking it
            if cfg.job == "mission" and k < first_of_cell:  # each cell's stage configs derive (e.g. no tube observer
                from oacli.mission.run import validate_mission  # without sensor noise): stops here, not in every run

                try:
                    validate_mission(run_cfg)
                except ConfigError as exc:
                    raise ConfigError([f"run {k}{cell}: {line}" for line in exc.problems]) from None
            rdir.mkdir(parents=True, exist_ok=True)
            write_text_atomic(path, json.dumps(to_json_safe(spec), indent=1, allow_nan=False))
        index[k] = {"seed": spec["seed"], "faults": spec["draws"]["faults"],
                    **({"cell": spec["cell"]} if "cell" in spec else {})}
    write_text_atomic(folder / "runs.json", json.dumps({"runs": cfg.runs, "index": index}, indent=1))


def load_existing(folder: Path) -> Campaign:
    """The campaign of an existing folder (``--resume``, ``rerun``), from its own ``campaign.yaml``/``base.yaml``.

    Raises
    ------
    InputError
        Not a campaign folder.
    """
    folder = Path(folder)
    if not (folder / "campaign.yaml").exists() or not (folder / "base.yaml").exists():
        raise InputError(f"{folder}: not a campaign folder (no campaign.yaml / base.yaml)")
    data = yaml.safe_load((folder / "campaign.yaml").read_text())
    version = data.pop("oacli_version", None)
    if version != __version__:
        raise InputError(f"{folder}: written by oacli {version}, this is {__version__}: runs would not reproduce")
    return Campaign(CampaignConfig.model_validate(data), yaml.safe_load((folder / "base.yaml").read_text()))


@dataclass
class _InFlight:
    k: int
    started: float
    solo: bool


Announce = Callable[[str], None]


def run_campaign(folder: Path, handle: ExecutorHandle, *, announce: Announce | None = None,
                 progress: Callable[[int, int], None] | None = None) -> dict[int, dict]:
    """Run every run of ``folder`` without a final record in the manifest (all of them the first time; on
    ``--resume`` the missing and failed ones), appending each attempt's outcome to the manifest.

    Parameters
    ----------
    folder : Path
        A prepared campaign folder.
    handle : ExecutorHandle
        Where the runs execute.
    announce : callable, optional
        Called with one line per finished attempt.
    progress : callable, optional
        Called as ``progress(done, total)`` with the runs to do before any starts (``done = 0``) and after each run
        that ends (``oacli.commands.progress.CampaignProgress``).

    Returns
    -------
    dict of int to dict
        Each run's final manifest record.

    Raises
    ------
    oacli.io.folder_lock.FolderBusy
        Another oacli process runs or resumes this campaign (exit 2, naming it): the folder's advisory lock
        (:mod:`oacli.io.folder_lock`) is held while the runs fly, so two resumes never fly a run twice.
    """
    with folder_lock(Path(folder), "campaign"):
        return _run_campaign(Path(folder), handle, announce=announce, progress=progress)


def _run_campaign(folder: Path, handle: ExecutorHandle, *, announce: Announce | None = None,
                  progress: Callable[[int, int], None] | None = None) -> dict[int, dict]:
    campaign = load_existing(folder)
    cfg = campaign.config
    if not (folder / "runs.json").exists():
        write_specs(campaign, folder)  # the preparation was interrupted: finish it (existing specs are kept)
    say = announce or (lambda _line: None)
    done = manifest.final_states(manifest.read(folder))
    todo = deque(k for k in range(cfg.runs) if done.get(k, {}).get("status") not in manifest.COMPLETED)
    specs = {k: read_spec(folder, k) for k in todo}
    infra = {k: 0 for k in todo}
    solo_queue: deque[int] = deque()
    inflight: dict[Future, _InFlight] = {}
    total = len(todo)
    if progress is not None:
        progress(0, total)

    def finish(k: int, record: dict[str, Any]) -> None:
        record = {"k": k, "executor": handle.kind, "infra_attempts": infra[k], **record}
        manifest.append(folder, record)
        if record["status"] in manifest.FINAL:
            done[k] = record
            if progress is not None:
                progress(sum(1 for j in specs if j in done), total)
            say(f"run {k}: {record['status']}" + (f" ({record.get('error')})" if record.get("error") else "")
                + f" [{sum(1 for j in specs if j in done)}/{total}]")
        else:
            say(f"run {k}: retry after {record.get('error')}")

    def charge(k: int, reason: str) -> None:
        infra[k] += 1
        if infra[k] > cfg.max_retries:
            finish(k, {"status": manifest.INFRA_FAILED, "error": reason})
        else:
            finish(k, {"status": manifest.RETRY, "error": reason})
            todo.appendleft(k)

    def submit(k: int, solo: bool) -> None:
        fut = handle.executor.submit(execute_run, specs[k], str(folder))
        inflight[fut] = _InFlight(k, time.monotonic(), solo)

    try:
        while todo or solo_queue or inflight:
            while len(inflight) < handle.workers:
                if solo_queue and not inflight:
                    submit(solo_queue.popleft(), True)
                elif todo and not solo_queue and not any(f.solo for f in inflight.values()):
                    submit(todo.popleft(), False)
                else:
                    break
            finished, _ = wait(list(inflight), timeout=POLL_S, return_when=FIRST_COMPLETED)
            deaths: list[_InFlight] = []
            if handle.broken():  # every run in flight fails with the pool: collect them all
                finished, _ = wait(list(inflight))
            for fut in finished:
                item = inflight.pop(fut)
                try:
                    res = fut.result()
                except BaseException as exc:
                    if handle.is_worker_death(exc):
                        deaths.append(item)
                    else:
                        finish(item.k, {"status": manifest.FAILED, "error": f"{type(exc).__name__}: {exc}"})
                    continue
                if res["status"] == STATUS_OOM:
                    charge(item.k, f"out of memory: {res.get('error')}")
                else:
                    finish(item.k, {key: res.get(key) for key in ("status", "hash", "metrics", "error", "traceback",
                                                                  "attempt", "wall_time_s", "pid")})
            if len(deaths) == 1 and (deaths[0].solo or not inflight):
                charge(deaths[0].k, "worker died")
            else:
                solo_queue.extend(d.k for d in deaths)
            now = time.monotonic()
            late = [f for f, item in inflight.items() if now - item.started > cfg.timeout_s]
            for fut in late:
                item = inflight.pop(fut)
                fut.cancel()
                charge(item.k, f"timeout after {cfg.timeout_s:g} s")
            if late and handle.kind == "local":
                handle.kill_workers()  # the only way to stop a running task; the others in flight go solo
                wait(list(inflight))
                solo_queue.extend(item.k for item in inflight.values())
                inflight.clear()
                handle.rebuild()
            elif handle.broken():
                handle.rebuild()
    finally:
        for fut in inflight:
            fut.cancel()
    return done


def rerun(folder: Path, k: int, out: Path | None) -> dict[str, Any]:
    """Rerun run ``k`` of a campaign alone, in this process, into a new folder, and compare its hash.

    Parameters
    ----------
    folder : Path
        The campaign folder.
    k : int
        Run index.
    out : Path, optional
        Folder for the rerun (default ``<campaign>/reruns/run-KKKKK-<n>``; never an existing one).

    Returns
    -------
    dict
        ``k``, ``status``, ``hash``, ``manifest_hash`` (None if the run has no completed record), ``same``, ``out``.
    """
    from oacli.campaign.jobs import pin_threads, run_job

    load_existing(folder)
    spec = read_spec(folder, k)
    if out is None:
        parent = Path(folder) / "reruns"
        parent.mkdir(exist_ok=True)
        n = 0
        while (parent / f"run-{k:05d}-{n}").exists():
            n += 1
        out = parent / f"run-{k:05d}-{n}"
    out = create_run_dir("rerun", out=out)
    pin_threads()
    result = run_job(spec, out)
    final = manifest.final_states(manifest.read(folder)).get(k)
    recorded = final.get("hash") if final else None
    outcome = {"k": k, "status": result["metrics"].get("status"), "hash": result["hash"], "manifest_hash": recorded,
               "same": recorded == result["hash"], "out": str(out), "metrics": result["metrics"]}
    write_text_atomic(out / "rerun.json", json.dumps(to_json_safe(outcome), indent=1, allow_nan=False))
    return outcome


__all__ = ["Campaign", "load_campaign", "load_existing", "prepare", "read_spec", "rerun", "run_campaign"]
