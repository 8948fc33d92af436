"""Run folders: ``runs/<name>-<stage>-<UTC timestamp>/`` holding the resolved config, one MCAP + one Rerun recording
per stage, and ``summary.json``; the skeleton every stage runs in (:func:`open_stage_run`, :class:`StageRun`,
:class:`StageResult`).

``summary.json`` is written last, atomically. A run folder is *complete* when its ``summary.json`` exists with a
status of :data:`oacli.status.COMPLETE_STATUSES` — ``ok``, ``degraded``, ``unsafe`` or ``no_solution``: the stage
ran to its end and wrote every file it lists under ``files``; the status then says how the run went (see
:mod:`oacli.status`; ``degraded`` and ``unsafe`` runs are complete records of a run that went wrong, kept for
review). A run stopped after its folder was created gets a ``summary.json`` with ``"status": "interrupted"``
(Ctrl-C) or ``"status": "failed"`` and the error, so it never looks complete (:func:`is_complete`). Existing folders
are never overwritten.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import subprocess
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import oacli
from oacli.errors import InputError, OacliError
from oacli.io.atomic import write_text_atomic
from oacli.io.jsonsafe import to_json_safe
from oacli.io.mcap_write import StageMcapWriter
from oacli.signals import describe_interruption, note_recorded
from oacli.status import COMPLETE_STATUSES, FAILED, INTERRUPTED


def utc_stamp(now: _dt.datetime | None = None) -> str:
    """UTC time stamp for folder names, e.g. ``20261122T011530Z``."""
    now = now or _dt.datetime.now(_dt.UTC)
    return now.strftime("%Y%m%dT%H%M%SZ")


def create_run_dir(name: str, *, out: Path | None = None, runs_root: Path = Path("runs")) -> Path:
    """Create and return a new, empty run folder.

    Parameters
    ----------
    name : str
        Run name prefix (from the config).
    out : Path, optional
        Exact folder to use. It must not exist, or be an empty folder.
    runs_root : Path
        Parent of automatically named folders ``<name>-<UTC stamp>`` (a ``-2``, ``-3`` … suffix is added when
        two runs start in the same second).

    Raises
    ------
    InputError
        When ``out`` exists and is not an empty folder (runs are never overwritten).
    """
    if out is not None:
        out = Path(out)
        if out.is_symlink():
            raise InputError(f"--out {out}: is a symlink{'' if out.exists() else ' (dangling)'}; "
                             "give the path of a new folder (run folders are never written through symlinks)")
        if out.exists():
            if not out.is_dir():
                raise InputError(f"--out {out}: exists and is not a folder; runs are never overwritten")
            if any(out.iterdir()):
                raise InputError(f"--out {out}: already exists and is not empty; runs are never overwritten")
            return out
        _mkdir(out, "--out", parents=True)
        return out
    runs_root = Path(runs_root)
    if runs_root.exists() and not runs_root.is_dir():
        raise InputError(f"--runs-dir {runs_root}: exists and is not a folder")
    _mkdir(runs_root, "--runs-dir", parents=True, exist_ok=True)
    base = f"{name}-{utc_stamp()}"
    for i in range(1, 1000):
        candidate = runs_root / (base if i == 1 else f"{base}-{i}")
        try:
            candidate.mkdir()
        except FileExistsError:
            continue
        return candidate
    raise InputError(f"{runs_root}: could not create a new run folder for {base}")


def _mkdir(path: Path, option: str, **kwargs: bool) -> None:
    """``path.mkdir(**kwargs)``, an ``OSError`` becoming one line naming the option, the path and the reason."""
    try:
        path.mkdir(**kwargs)
    except OSError as exc:
        reason = "a component of the path is a file" if isinstance(exc, (FileExistsError, NotADirectoryError)) \
            else (exc.strerror or str(exc)).lower()
        raise InputError(f"{option} {path}: cannot create the folder: {reason}") from None


def git_commit() -> str:
    """Commit hash of the oacli checkout, or ``"unknown"`` when not installed from a git checkout."""
    src = Path(oacli.__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    commit = out.stdout.strip()
    if out.returncode != 0 or not commit:
        return "unknown"
    dirty = subprocess.run(
        ["git", "-C", str(src), "status", "--porcelain", "--untracked-files=no"],
        capture_output=True, text=True, timeout=5, check=False,
    )
    return commit + ("-dirty" if dirty.returncode == 0 and dirty.stdout.strip() else "")


#: ``summary.json`` files this process wrote with a complete status (resolved path -> status): a signal arriving
#: after one is written never turns it into ``interrupted`` or ``failed`` (:func:`write_summary`).
_RECORDED: dict[Path, str] = {}


def write_summary(run_dir: Path, summary: Mapping[str, Any], filename: str = "summary.json") -> Path:
    """Write ``summary`` as strict JSON (NaN → null), atomically; returns the path.

    A summary with a complete status (:data:`oacli.status.COMPLETE_STATUSES`) is final: should this process then
    try to replace it by an ``interrupted`` or ``failed`` one (a signal arriving after the run was recorded, while
    the stage or mission returns), the complete one is kept and :func:`oacli.signals.note_recorded` says so (the
    CLI's line: ``interrupted after the run was recorded``).
    """
    path = Path(run_dir) / filename
    key = path.absolute()
    status = summary.get("status")
    if status not in COMPLETE_STATUSES and key in _RECORDED and path.is_file():
        note_recorded(path, _RECORDED[key])
        return path
    write_text_atomic(path, json.dumps(to_json_safe(summary), indent=2, allow_nan=False) + "\n")
    if status in COMPLETE_STATUSES:
        _RECORDED[key] = str(status)
    else:
        _RECORDED.pop(key, None)
    return path


@dataclass(frozen=True)
class StageResult:
    """What a stage produced: its run folder, its summary and the files it wrote.

    Attributes
    ----------
    run_dir : Path
        The run folder.
    summary : dict
        The content of ``summary.json``.
    files : dict of str to Path
        Files written, by role (``config``, ``mcap``, ``rrd``, ``summary``).
    """

    run_dir: Path
    summary: dict[str, Any]
    files: dict[str, Path]


def run_metadata(stage: str, *, seed: object, config_name: str, **extra: object) -> dict[str, object]:
    """The entries every stage puts in its MCAP's ``oacli`` metadata record (``docs/mcap.md``).

    Parameters
    ----------
    stage : str
        Stage name.
    seed : object
        The config's seed.
    config_name : str
        The config's ``name``.
    **extra : object
        Stage-specific entries (``method``, ``telemetry`` ...).

    Returns
    -------
    dict
        ``stage``, ``seed``, ``git_commit`` (:func:`git_commit`), ``version``, ``config_name`` and ``extra``.
    """
    return {"stage": stage, "seed": seed, "git_commit": git_commit(), "version": oacli.__version__,
            "config_name": config_name, **extra}


class StageRun:
    """A stage's run folder between its creation and its ``summary.json`` (see :func:`open_stage_run`).

    Attributes
    ----------
    stage : str
        Stage name (``track``, ``plan`` ...).
    run_dir : Path
        The folder.
    files : dict of str to Path
        Files written so far, by role (``config``, ``mcap``, ``rrd`` ...); listed in the summary.
    config_yaml : str
        The resolved config (attached to the MCAP).
    seed : object
        The config's seed (MCAP metadata).
    config_name : str
        The config's ``name`` (MCAP metadata).
    frame : str
        The world frame's name (MCAP metadata, ``frame_id`` of poses).
    """

    def __init__(self, stage: str, run_dir: Path, started: float | None = None, *, config_yaml: str = "",
                 seed: object = "unknown", config_name: str = "", frame: str = "world") -> None:
        self.stage = stage
        self.run_dir = run_dir
        self.files: dict[str, Path] = {}
        #: What each record holds, by role, when the stage is stopped (``complete`` or ``journal``): the
        #: interrupted summary's ``records`` (e.g. ``{"mcap": "journal"}``: track.mcap is the journal kept).
        self.records: dict[str, str] = {}
        self.config_yaml = config_yaml
        self.seed = seed
        self.config_name = config_name
        self.frame = frame
        self._start = time.perf_counter() if started is None else started

    def file(self, role: str, name: str) -> Path:
        """Register and return the path of an output file, e.g. ``run.file("mcap", "track.mcap")``.

        Parameters
        ----------
        role : str
            Key in the summary's ``files``.
        name : str
            File name in the run folder.

        Returns
        -------
        Path
        """
        path = self.run_dir / name
        self.files[role] = path
        return path

    def open_mcap(self, **metadata: object) -> StageMcapWriter:
        """The writer of the stage's MCAP ``<stage>.mcap`` (registered as ``mcap``); use it in a ``with`` block.

        Parameters
        ----------
        **metadata : object
            Stage-specific entries of the ``oacli`` metadata record, after those of :func:`run_metadata`.

        Returns
        -------
        StageMcapWriter
            With the resolved config attached, the run metadata and the world frame; time-ordered (messages of
            all topics merged by time when the ``with`` block ends, so a cut file holds every topic up to about
            the same time).
        """
        path = self.file("mcap", f"{self.stage}.mcap")
        info = run_metadata(self.stage, seed=self.seed, config_name=self.config_name, **metadata)
        return StageMcapWriter(path, stage=self.stage, config_yaml=self.config_yaml, metadata=info, frame=self.frame,
                               time_ordered=True)

    def finish(self, summary: dict[str, Any]) -> StageResult:
        """Add ``wall_time_s``, ``run_dir`` and ``files`` to ``summary`` and write it (last, atomically).

        Parameters
        ----------
        summary : dict
            The stage's summary (its ``status`` set).

        Returns
        -------
        StageResult
            The run folder, the summary and the files (``summary.json`` included).
        """
        summary["wall_time_s"] = time.perf_counter() - self._start
        summary["run_dir"] = str(self.run_dir)
        summary["files"] = {k: p.name for k, p in self.files.items()}
        self.files["summary"] = write_summary(self.run_dir, summary)
        return StageResult(self.run_dir, summary, self.files)


@contextlib.contextmanager
def open_stage_run(
    stage: str,
    name: str,
    config_yaml: str,
    *,
    seed: object = "unknown",
    frame: str = "world",
    out: Path | None = None,
    runs_root: Path = Path("runs"),
    started: float | None = None,
) -> Iterator[StageRun]:
    """Create a run folder, write the resolved ``config.yaml`` first, and yield a :class:`StageRun`.

    If the block raises, ``summary.json`` records ``"status": "interrupted"`` (KeyboardInterrupt) or
    ``"status": "failed"`` and the error before the exception propagates, so such a run never looks complete.

    Parameters
    ----------
    stage : str
        Stage name.
    name : str
        The config's ``name``: the MCAP's ``config_name``; an automatically named folder is
        ``<name>-<stage>-<UTC stamp>`` (e.g. ``iss-reswarm-track-20261201T101500Z``).
    config_yaml : str
        The resolved config.
    seed : object
        The config's seed (MCAP metadata).
    frame : str
        The world frame's name (MCAP metadata).
    out, runs_root : Path
        The folder (see :func:`create_run_dir`).
    started : float, optional
        A ``time.perf_counter()`` value: when the stage began, for ``wall_time_s`` (default: the folder's creation).

    Yields
    ------
    StageRun
    """
    run_dir = create_run_dir(f"{name}-{stage}", out=out, runs_root=runs_root)
    run = StageRun(stage, run_dir, started, config_yaml=config_yaml, seed=seed, config_name=name, frame=frame)
    write_text_atomic(run.file("config", "config.yaml"), config_yaml)
    try:
        yield run
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):
            status, reason = INTERRUPTED, describe_interruption(exc)
        else:
            status, reason = FAILED, f"{type(exc).__name__}: {exc}"
        try:
            files = {k: p.name for k, p in run.files.items() if p.exists()}
            interrupted = {"stage": stage, "status": status, "error": reason,
                           "wall_time_s": time.perf_counter() - run._start, "files": files}
            records = {k: v for k, v in run.records.items() if k in files or v.startswith("journal")}
            if records:
                interrupted["records"] = records
            write_summary(run.run_dir, interrupted)
        except (OSError, OacliError) as err:  # e.g. the disk is full: report the first error, not this one
            exc.add_note(f"(the {status} summary.json could not be written either: {err})")
        raise


#: Largest ``summary.json`` read [bytes] (a stage writes a few KiB).
MAX_SUMMARY_BYTES = 16 * 1024 * 1024


def read_summary_file(path: Path) -> dict[str, Any]:
    """A ``summary.json`` as a mapping; anything else (a FIFO, a device, a folder, binary data, invalid JSON, more than
    :data:`MAX_SUMMARY_BYTES`, not a mapping) is an :class:`InputError` naming the file (exit 2), read without
    blocking.

    Parameters
    ----------
    path : Path
        The file.

    Returns
    -------
    dict
    """
    import os

    from oacli.io.regular_files import open_regular

    fd = open_regular(path, "a summary.json file")
    try:
        with os.fdopen(fd, "rb") as f:
            data = f.read(MAX_SUMMARY_BYTES + 1)
    except OSError as exc:
        raise InputError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if len(data) > MAX_SUMMARY_BYTES:
        raise InputError(f"{path}: larger than {MAX_SUMMARY_BYTES} bytes; not a summary.json oacli wrote")
    try:
        summary = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{path}: not a JSON summary ({type(exc).__name__}: {str(exc)[:120]})") from None
    if not isinstance(summary, dict):
        raise InputError(f"{path}: not a JSON summary (the top level is not a mapping)")
    return summary


def is_complete(run_dir: Path) -> bool:
    """True when ``run_dir/summary.json`` exists, parses and has a complete status (module docstring)."""
    path = Path(run_dir) / "summary.json"
    try:
        status = json.loads(path.read_text()).get("status")
    except (OSError, ValueError, AttributeError):
        return False
    return status in COMPLETE_STATUSES
