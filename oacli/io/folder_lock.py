"""An advisory lock on a mission or campaign folder while it runs or resumes: a second ``oacli mission --resume`` or
``oacli campaign --resume`` of the same folder exits 2 naming the holder instead of flying the same runs twice.

The lock is an ``flock`` (``fcntl``) on a descriptor of the folder itself, taken without waiting
(``LOCK_EX | LOCK_NB``); the kernel releases it when the holder exits, however it ends (a SIGKILL included), so a
stale lock never blocks a resume. Who holds it is written to ``<folder>/.oacli.lock`` (one JSON line: ``pid``,
``host``, ``started_utc``, ``command``) while it is held, and the file is removed on release (a killed holder leaves
it behind: it is then out of date and harmless, overwritten by the next holder). The lock is advisory: it binds oacli
processes, not other programs, and it does not hold across machines on network file systems that do not forward
``flock``.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from oacli.errors import InputError, OacliError

#: The holder's description, inside the locked folder.
HOLDER_FILE = ".oacli.lock"


class FolderBusy(InputError):
    """Another oacli process holds the folder's lock (exit code 2)."""


HOLDER_WAIT_S = 2.0
"""How long a process that finds the lock taken waits for the holder's description [s]."""


def _holder(folder: Path, wait_s: float = HOLDER_WAIT_S) -> str:
    """``pid 123 on host h since 2026-12-05T14:00:00Z (oacli campaign --resume)``, or what is known.

    The holder writes its description just after it takes the lock: a process that finds the lock taken waits up
    to ``wait_s`` for it before saying it is not written yet.
    """
    deadline = time.monotonic() + wait_s
    while True:
        try:
            with open(folder / HOLDER_FILE, encoding="utf-8") as f:
                info = json.loads(f.read(4096))
            return (f"pid {int(info['pid'])} on host {info['host']} since {info['started_utc']}"
                    + (f" ({info['command']})" if info.get("command") else ""))
        except (OSError, ValueError, KeyError, TypeError):
            if time.monotonic() >= deadline:
                return "another oacli process (its pid, host and start time are not written yet)"
            time.sleep(0.05)


@contextlib.contextmanager
def folder_lock(folder: Path, what: str) -> Iterator[None]:
    """Hold the advisory lock of ``folder`` for the block (module docstring).

    Parameters
    ----------
    folder : Path
        The mission or campaign folder (exists).
    what : str
        What runs in it, for the message (``"mission"``, ``"campaign"``).

    Raises
    ------
    FolderBusy
        Another process holds the lock: one line naming the folder and the holder (pid, host, start time).
    """
    folder = Path(folder)
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputError(f"{folder}: cannot open the {what} folder ({exc.strerror or exc})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise FolderBusy(f"{folder}: the {what} is in use by {_holder(folder)}; wait for it to end or stop "
                                 "it (a folder is run or resumed by one oacli process at a time)") from None
            raise InputError(f"{folder}: cannot lock the {what} folder ({exc.strerror or exc})") from None
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "started_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
                "command": " ".join(["oacli", *sys.argv[1:]])[:300]}
        with contextlib.suppress(OSError, OacliError):  # the lock holds without its description
            from oacli.io.atomic import write_text_atomic

            write_text_atomic(folder / HOLDER_FILE, json.dumps(info) + "\n")
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                (folder / HOLDER_FILE).unlink()
    finally:
        os.close(fd)  # releases the lock
