"""Opening input files that must be regular files, without blocking, and reading them in place.

A FIFO opened for reading waits for a writer, ``/dev/zero`` never ends and a folder cannot be read: every input oacli
reads (MCAP files, ``summary.json``, reference tables) is opened with :func:`open_regular`, which refuses them with
one line (an :class:`~oacli.errors.InputError`, exit 2). :class:`ViewReader` reads a mapped file
(:class:`mmap.mmap`) as a stream without copying it.
"""

from __future__ import annotations

import io
import os
import stat
from pathlib import Path
from typing import Any

from oacli.errors import InputError


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def open_regular(path: Path, what: str = "an MCAP file") -> int:
    """A read-only descriptor of ``path`` (symlinks followed), refusing anything but a regular file without
    blocking: a FIFO, a device (``/dev/zero``), a socket or a folder is an :class:`InputError` naming it (exit 2).

    The file is opened with ``O_NONBLOCK`` (opening a FIFO for reading would wait for a writer) and checked with
    ``fstat`` on the descriptor (no race between the check and the open); the flag is then cleared.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise InputError(f"{path}: is {_kind(mode)}, not {what}; give a regular file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


class ViewReader(io.BufferedIOBase):
    """A seekable binary stream over a bytes-like object (an :class:`mmap.mmap`) without copying it (``io.BytesIO``
    copies anything but ``bytes``); not a ``RawIOBase``, which the ``mcap`` reader would wrap in a read-ahead
    buffer (its position then runs ahead of the records)."""

    def __init__(self, data: Any) -> None:
        super().__init__()
        self._data = data
        self._size = len(data)
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def read(self, size: int | None = -1) -> bytes:
        start = self._pos
        stop = self._size if size is None or size < 0 else min(self._size, start + size)
        self._pos = max(start, stop)
        return bytes(self._data[start:stop])

    def readinto(self, buffer: Any) -> int:
        chunk = self.read(len(buffer))
        buffer[: len(chunk)] = chunk
        return len(chunk)

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self._size}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def tell(self) -> int:
        return self._pos


def stream_of(data: Any) -> Any:
    """A binary stream over ``data``: ``io.BytesIO`` for bytes (no copy), `ViewReader` otherwise."""
    return io.BytesIO(data) if isinstance(data, bytes) else ViewReader(data)


__all__ = ["ViewReader", "open_regular", "stream_of"]
