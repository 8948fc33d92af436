"""Crash-safe file writing: write under an exclusive temporary name, flush and fsync, then rename into place, so
that the final name is never a half-written file and never a symlink.

Every name is resolved relative to a descriptor of the target folder, opened once without following a symlink
(``O_DIRECTORY | O_NOFOLLOW``): a folder swapped for a symlink later does not redirect the writes. The temporary
file ``.<final name>.<random>.partial`` is created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` (a name planted in advance,
e.g. a symlink to a file elsewhere, is never opened; nothing deletes a name and then opens it again), with the
permissions ``open`` would give. Before the rename the temporary name must still be the file created (same device
and inode, not a symlink), and after it the final name is checked again: a name that turned out a symlink or
another file is removed and the write refused (:class:`WriteError`) — the way rosbag2 and the MCAP writers treat
their outputs. Write errors become :class:`WriteError`, one line naming the path and the cause (``no space left on
device (ENOSPC)``).
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from oacli.errors import OacliError

#: Permission bits of finished files (``0666`` minus the process umask, as ``open`` would create them).
_UMASK = os.umask(0o022)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
_DIRECTORY = getattr(os, "O_DIRECTORY", 0)


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


def open_folder(folder: Path) -> int:
    """A descriptor of ``folder`` opened without following a symlink (``O_DIRECTORY | O_NOFOLLOW``).

    Raises
    ------
    WriteError
        ``folder`` is a symlink, not a folder, or cannot be opened.
    """
    check_real_folder(folder)
    try:
        return os.open(folder, os.O_RDONLY | _DIRECTORY | _NOFOLLOW | _CLOEXEC)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENOTDIR):
            raise WriteError(f"cannot write into {folder}: it is a symlink or not a folder (refused)") from None
        raise WriteError(describe_os_error(exc, folder)) from None


def fsync_path(path: Path) -> None:
    """fsync a file (or directory) so that its contents survive a crash (the last component is not followed)."""
    fd = os.open(path, os.O_RDONLY | _NOFOLLOW)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class _Temporary:
    """An exclusive temporary file beside ``final``, renamed onto it by :meth:`commit` (module docstring)."""

    def __init__(self, final: Path) -> None:
        self.final = Path(final)
        self.dir_fd = open_folder(self.final.parent)
        try:
            self.fd, self.name = self._create()
            st = os.fstat(self.fd)
            self.identity = (st.st_dev, st.st_ino)
        except BaseException:
            os.close(self.dir_fd)
            raise
        #: Leave the temporary file in place on an error (a journal that ``oacli logs recover`` can read).
        self.keep_on_error = False

    @property
    def path(self) -> Path:
        """The temporary file's path."""
        return self.final.parent / self.name

    def _create(self) -> tuple[int, str]:
        flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC
        for _ in range(100):
            name = f".{self.final.name}.{secrets.token_hex(6)}.partial"
            try:
                fd = os.open(name, flags, 0o600, dir_fd=self.dir_fd)
            except FileExistsError:
                continue
            except OSError as exc:
                raise WriteError(describe_os_error(exc, self.final)) from None
            os.fchmod(fd, FILE_MODE)
            return fd, name
        raise WriteError(f"cannot write {self.final}: no free temporary name")

    def _same_file(self, name: str) -> bool:
        try:
            st = os.lstat(name, dir_fd=self.dir_fd)
        except OSError:
            return False
        return stat.S_ISREG(st.st_mode) and (st.st_dev, st.st_ino) == self.identity

    def commit(self) -> None:
        """fsync the file, rename it onto the final name (relative to the folder's descriptor), check that the final
        name is the file written (a symlink or another file is removed and refused), and fsync the folder."""
        os.fsync(self.fd)
        if not self._same_file(self.name):
            raise WriteError(f"cannot write {self.final}: its temporary file {self.name} was replaced (by a symlink "
                             "or another file) before the rename; refused, the final name is not created")
        os.replace(self.name, self.final.name, src_dir_fd=self.dir_fd, dst_dir_fd=self.dir_fd)
        if not self._same_file(self.final.name):
            with contextlib.suppress(OSError):
                if not self._same_file(self.final.name):
                    os.unlink(self.final.name, dir_fd=self.dir_fd)
            raise WriteError(f"cannot write {self.final}: the final name turned out a symlink or another file "
                             "after the rename; removed and refused")
        os.fsync(self.dir_fd)

    def remove(self) -> None:
        """Delete the temporary file (if it is still the one created)."""
        with contextlib.suppress(OSError):
            if self._same_file(self.name):
                os.unlink(self.name, dir_fd=self.dir_fd)

    def close(self) -> None:
        """Close the descriptors (file and folder)."""
        for fd in (self.fd, self.dir_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.fd = self.dir_fd = -1


class atomic_file:
    """Context manager yielding a binary file open on a fresh exclusive temporary file beside ``final``; on success
    flush, fsync and rename it onto ``final`` (never a symlink: module docstring).

    On an exception the temporary file is removed (unless :attr:`keep_on_error` was set: it then stays, e.g. a
    journal ``oacli logs recover`` reads) and ``final`` is not created (an existing ``final`` is left as it was).
    An ``OSError`` while writing or committing becomes :class:`WriteError` (one line, path and cause).
    """

    def __init__(self, final: Path) -> None:
        self.final = Path(final)
        self.keep_on_error = False
        self._tmp: _Temporary | None = None
        self._handle: BinaryIO | None = None

    @property
    def temporary(self) -> Path | None:
        """The temporary file's path while the block runs."""
        return None if self._tmp is None else self._tmp.path

    def __enter__(self) -> BinaryIO:
        self._tmp = _Temporary(self.final)
        self._handle = os.fdopen(os.dup(self._tmp.fd), "w+b")
        return self._handle

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        tmp, handle = self._tmp, self._handle
        if tmp is None or handle is None:
            return
        self._tmp = self._handle = None
        try:
            if exc is None:
                try:
                    handle.flush()
                    handle.close()
                    tmp.commit()
                except BaseException as err:
                    tmp.remove()
                    if isinstance(err, OSError):
                        raise WriteError(describe_os_error(err, self.final)) from err
                    raise
                return
            with contextlib.suppress(OSError):
                handle.close()
            if not self.keep_on_error:
                tmp.remove()
            if isinstance(exc, OSError):
                raise WriteError(describe_os_error(exc, self.final)) from exc
        finally:
            tmp.close()


@contextlib.contextmanager
def atomic_path(final: Path) -> Iterator[Path]:
    """Yield the path of a fresh exclusive temporary file beside ``final``; on success fsync it and rename it onto
    ``final`` (never a symlink: module docstring).

    The temporary file exists (empty) when the block starts: write it by name (opening it truncates it). On an
    exception it is removed and ``final`` is never created, so a half-written file never carries the final
    name; a crash leaves a ``.partial`` leftover. Prefer :func:`atomic_file` when the writer takes a file object.
    """
    final = Path(final)
    tmp = _Temporary(final)
    try:
        yield tmp.path
        tmp.commit()
    except BaseException as exc:
        tmp.remove()
        if isinstance(exc, OSError):
            raise WriteError(describe_os_error(exc, final)) from exc
        raise
    finally:
        tmp.close()


def write_bytes_atomic(final: Path, data: bytes) -> None:
    """Write ``data`` to ``final`` atomically (exclusive temporary file, fsync, rename, never a symlink)."""
    with atomic_file(final) as handle:
        handle.write(data)


def write_text_atomic(final: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``final`` atomically."""
    write_bytes_atomic(final, text.encode("utf-8"))
