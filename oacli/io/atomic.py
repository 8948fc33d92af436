"""Crash-safe file writing: write under an exclusive temporary name, flush and fsync, then rename into place.

Temporary files are created with :func:`tempfile.mkstemp` in the target folder (``O_CREAT | O_EXCL``, a random
name ``.<final name>.<random>.partial``, the permissions ``open`` would give): a name planted in advance (a symlink to a
file elsewhere) is never opened, and nothing deletes a name and then opens it again. The folder itself must
not be a symlink (:func:`check_real_folder`). Write errors become :class:`WriteError`, one line naming the
path and the cause (``no space left on device (ENOSPC)``).
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from oacli.errors import OacliError

#: Permission bits of finished files (``0666`` minus the process umask, as ``open`` would create them).
_UMASK = os.umask(0o022)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK


class WriteError(OacliError):
    """A file could not be written (disk full, permission, I/O error, a symlink in the way); exit code 1."""

    exit_code = 1


def describe_os_error(exc: BaseException, path: Path | str) -> str:
    """One line naming ``path`` and the cause, e.g. ``cannot write runs/x/track.mcap: no space left on device
    (ENOSPC)``."""
    while isinstance(exc, BaseException) and not isinstance(exc, OSError) and exc.__cause__ is not None:
        exc = exc.__cause__
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, str(exc.errno))
        reason = (exc.strerror or os.strerror(exc.errno)).lower()
        return f"cannot write {path}: {reason} ({name})"
    return f"cannot write {path}: {exc}"


def check_real_folder(folder: Path) -> None:
    """Refuse a folder that is a symlink (or not a folder): files of a run are written only inside it.

    Raises
    ------
    WriteError
        ``folder`` is a symlink or not a directory.
    """
    folder = Path(folder)
    try:
        st = os.lstat(folder)
    except OSError as exc:
        raise WriteError(describe_os_error(exc, folder)) from None
    if stat.S_ISLNK(st.st_mode):
        raise WriteError(f"cannot write into {folder}: it is a symlink (refused: a run folder must be a real folder)")
    if not stat.S_ISDIR(st.st_mode):
        raise WriteError(f"cannot write into {folder}: not a folder")


def fsync_path(path: Path) -> None:
    """fsync a file (or directory) so that its contents survive a crash (the last component is not followed)."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _mkstemp(final: Path) -> tuple[int, Path]:
    check_real_folder(final.parent)
    try:
        fd, name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent)
    except OSError as exc:
        raise WriteError(describe_os_error(exc, final)) from None
    os.fchmod(fd, FILE_MODE)
    return fd, Path(name)


def _commit(tmp: Path, final: Path) -> None:
    os.replace(tmp, final)
    fsync_path(final.parent)


@contextlib.contextmanager
def atomic_file(final: Path) -> Iterator[BinaryIO]:
    """Yield a binary file open on a fresh exclusive temporary file beside ``final``; on success flush, fsync
    and rename it onto ``final``.

    On an exception the temporary file is removed and ``final`` is not created (an existing ``final`` is left
    as it was). An ``OSError`` while writing or committing becomes :class:`WriteError` (one line, path and
    cause).
    """
    final = Path(final)
    fd, tmp = _mkstemp(final)
    try:
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        _commit(tmp, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise WriteError(describe_os_error(exc, final)) from exc
        raise


@contextlib.contextmanager
def atomic_path(final: Path) -> Iterator[Path]:
    """Yield the path of a fresh exclusive temporary file beside ``final``; on success fsync it and
    ``os.replace`` it onto ``final``.

    The temporary file exists (empty) when the block starts: write it by name (opening it truncates it). On an
    exception it is removed and ``final`` is never created, so a half-written file never carries the final
    name; a crash leaves a ``.partial`` leftover. Prefer :func:`atomic_file` when the writer takes a file object.
    """
    final = Path(final)
    fd, tmp = _mkstemp(final)
    os.close(fd)
    try:
        yield tmp
        fsync_path(tmp)
        _commit(tmp, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise WriteError(describe_os_error(exc, final)) from exc
        raise


def write_bytes_atomic(final: Path, data: bytes) -> None:
    """Write ``data`` to ``final`` atomically (exclusive temporary file, fsync, rename)."""
    with atomic_file(final) as handle:
        handle.write(data)


def write_text_atomic(final: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``final`` atomically."""
    write_bytes_atomic(final, text.encode("utf-8"))
