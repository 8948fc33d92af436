"""Stage MCAP files this process has just written, remembered so that reading one back skips the file's walk
(opt-in: :func:`remembering`, which the mission turns on around its stages; issue 9).

A mission hands each stage's files to the next stages and then reads them all again for its summary, recording
and plots. While :func:`remembering` is active, :class:`oacli.io.mcap_write.StageMcapWriter` keeps the payload of
every JSON and ``foxglove.Log`` message exactly as it handed it to the MCAP writer (in file order), and its metadata
records and attachments; when the file is complete it is stored here under its path, modification time and size.
:func:`oacli.io.mcap_read.read_stage` of that unchanged file then decodes those payloads with the same code that
decodes the file's (so the record is the same, value for value), takes the topics, schemas, channel metadata and
message counts from the file's own summary section, and falls back to reading the whole file when the summary
and what was remembered disagree in any count or name. The MCAP is still written and stays the record of truth: a
file changed on disk (another modification time or size) is read from disk.

The remembered files live in a :class:`contextvars.ContextVar`, not in module globals: each thread (a new thread
starts with an empty context) and each ``contextvars.copy_context()`` run sees only the files of its own
:func:`remembering` block, so two missions run in threads of one process (a campaign on Dask's threads) never see
each other's files, and a block that ends forgets exactly its own.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Most files remembered (a mission writes 12 stage MCAPs).
MAX_FILES = 32
#: :func:`remembering` keeps files only while this is on (``benchmarks/bench_mission_overhead.py`` turns it off for
#: the old path).
ENABLED = True

_Registry = OrderedDict[tuple[str, int, int], "Written"]
#: The files of the innermost active :func:`remembering` block of this context (None outside any).
_FILES: contextvars.ContextVar[_Registry | None] = contextvars.ContextVar("oacli_mcap_memo_files", default=None)


@dataclass
class Written:
    """What a writer wrote into one file (see the module docstring).

    Attributes
    ----------
    messages : dict of str to list of (int, bytes)
        Per topic, ``(log_time [ns], payload)`` of every JSON message and every ``foxglove.Log`` message (its
        protobuf encoding), in the order written.
    metadata : dict of str to dict of str to str
        Metadata records by name.
    attachments : dict of str to bytes
        Attachments by name.
    """

    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)


def active() -> bool:
    """Whether files written now are remembered."""
    return _FILES.get() is not None and ENABLED


@contextlib.contextmanager
def remembering() -> Iterator[None]:
    """Within the block, remember every stage MCAP written in this context (module docstring); forget them when
    the outermost block of this context ends (a nested block shares the outer block's files)."""
    outer = _FILES.get()
    token = _FILES.set(OrderedDict() if outer is None else outer)
    try:
        yield
    finally:
        _FILES.reset(token)


def _key(path: Path) -> tuple[str, int, int] | None:
    try:
        stat = Path(path).stat()
        return str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size
    except OSError:
        return None


def store(path: Path, written: Written) -> None:
    """Remember what was written into the complete file ``path`` (no-op unless :func:`active`).

    Parameters
    ----------
    path : Path
        The file, just completed.
    written : Written
        What its writer wrote.
    """
    files = _FILES.get()
    if files is None or not ENABLED:
        return
    key = _key(path)
    if key is None:
        return
    files[key] = written
    while len(files) > MAX_FILES:
        files.popitem(last=False)


def recall(path: Path) -> Written | None:
    """What was written into ``path`` when it is remembered and unchanged on disk (else None).

    Parameters
    ----------
    path : Path
        A stage MCAP.

    Returns
    -------
    Written or None
    """
    files = _FILES.get()
    if not files:
        return None
    key = _key(path)
    return None if key is None else files.get(key)


def summary_of(path: Path) -> Any | None:
    """The summary section of a complete MCAP file (``mcap.summary.Summary``), or None when it has none or it
    cannot be read."""
    from mcap.reader import make_reader

    try:
        with Path(path).open("rb") as f:
            return make_reader(f).get_summary()
    except Exception:  # any failure: the caller reads the whole file instead
        return None


__all__ = ["MAX_FILES", "Written", "active", "recall", "remembering", "store", "summary_of"]
