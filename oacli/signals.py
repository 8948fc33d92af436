"""Termination signals handled like Ctrl-C: SIGTERM (what ``timeout``, systemd, docker and Dask send) and
SIGHUP raise :class:`Terminated`, a :class:`KeyboardInterrupt`, so every cleanup path that handles Ctrl-C runs
(temporary files removed, ``summary.json`` written with ``"status": "interrupted"``). The command then exits
with ``128 + signal number`` (143 for SIGTERM; 130 for Ctrl-C), as a shell reports a process killed by it.

Native code that calls back into Python (the foxglove MCAP writer writes every chunk through a Python file object)
turns an exception raised in the callback into its own error: a Ctrl-C arriving there would end the run as
``failed`` with "I/O error from writing" and break the writer. Within :func:`terminate_like_interrupt`, SIGINT,
SIGTERM and SIGHUP arriving inside a :class:`held` block are therefore held (:data:`PENDING`) and raised when the
block ends, or earlier by :func:`raise_pending` at a point where native code is not running (between two messages).

Once a run is recorded (its complete ``summary.json`` written) a signal never turns it into ``interrupted``
(:func:`oacli.io.runfolder.write_summary` keeps it, :func:`note_recorded`), and never kills the process silently:
the console script installs :func:`exit_on_signal` handlers outside the command's own block, which print one line
and exit with 130 / 143 (``interrupted (terminated by SIGTERM) after the run was recorded``).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType

#: Signals turned into :class:`Terminated` (SIGINT keeps Python's own KeyboardInterrupt).
HANDLED = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))

#: Exit code of a run stopped by Ctrl-C (128 + SIGINT).
INTERRUPT_EXIT_CODE = 128 + int(signal.SIGINT)


class Terminated(KeyboardInterrupt):
    """The process received a termination signal (SIGTERM, SIGHUP); handled wherever Ctrl-C is."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        super().__init__(f"terminated by {signal.Signals(self.signum).name}")


def exit_code_for(exc: BaseException) -> int:
    """``128 + signal number`` for an interruption: 143 for SIGTERM, 130 for Ctrl-C (KeyboardInterrupt)."""
    return 128 + exc.signum if isinstance(exc, Terminated) else INTERRUPT_EXIT_CODE


def describe_interruption(exc: BaseException) -> str:
    """``"terminated by SIGTERM"`` or ``"interrupted by the user (KeyboardInterrupt)"``."""
    if isinstance(exc, Terminated):
        return str(exc)
    return "interrupted by the user (KeyboardInterrupt)"


_raised: list[int] = []

#: Signal numbers received inside a :class:`held` block and not raised yet (a list: its truth is cheap to test).
PENDING: list[int] = []
_held = [0]  # depth of nested held blocks (main thread only)
_MAIN_THREAD = threading.main_thread().ident


def _interruption(signum: int) -> KeyboardInterrupt:
    return KeyboardInterrupt() if signum == int(signal.SIGINT) else Terminated(signum)


def raise_pending() -> None:
    """Raise the interruption held so far (if any), e.g. between two writes of a long :class:`held` block."""
    if PENDING:
        signum = PENDING[0]
        PENDING.clear()
        raise _interruption(signum)


class held:
    """Within the block, an interruption (SIGINT, SIGTERM, SIGHUP, as handled by :func:`terminate_like_interrupt`)
    is held and raised when the outermost block ends (module docstring). Cheap enough to wrap every call into a
    native writer."""

    __slots__ = ()

    def __enter__(self) -> None:
        if threading.get_ident() == _MAIN_THREAD:  # signal handlers run only in the main thread
            _held[0] += 1

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        if threading.get_ident() != _MAIN_THREAD:
            return
        _held[0] -= 1
        if _held[0] == 0 and PENDING:
            if exc is not None:  # already leaving by an error: that error goes on, the interruption is noted
                signum = PENDING[0]
                PENDING.clear()
                if not isinstance(exc, KeyboardInterrupt):
                    exc.add_note(f"({signal.Signals(signum).name} received while this error was raised)")
                return
            raise_pending()


_atomic = [0]  # depth of nested atomic blocks (main thread only)


class atomic(held):
    """A :class:`held` block without interruption points: everything in it completes (e.g. a journal record, its
    bookkeeping and its flush to disk), and the interruption is raised when the outermost held block ends."""

    __slots__ = ()

    def __enter__(self) -> None:
        if threading.get_ident() == _MAIN_THREAD:
            _atomic[0] += 1
        super().__enter__()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        if threading.get_ident() == _MAIN_THREAD:
            _atomic[0] -= 1
        super().__exit__(exc_type, exc, tb)


def interruption_point() -> None:
    """Raise the interruption held so far here (a point where native code is not running, e.g. between two
    messages of a long write), unless inside an :class:`atomic` block."""
    if PENDING and not _atomic[0]:
        raise_pending()


def interruption_message(exc: BaseException) -> str:
    """The CLI's line: ``"interrupted"`` (Ctrl-C) or ``"interrupted (terminated by SIGTERM)"``."""
    return f"interrupted ({exc})" if isinstance(exc, Terminated) else "interrupted"


#: Signals delivered inside the current :func:`terminate_like_interrupt` block (raised or held).
DELIVERED: list[int] = []


def delivered() -> int | None:
    """The first signal delivered inside the current :func:`terminate_like_interrupt` block, or None: when a command
    returns normally although one was, the interruption was swallowed on its way (raised inside a weakref callback
    or a ``__del__``, where Python only prints "Exception ignored"), and the command still ends 130/143."""
    return DELIVERED[0] if DELIVERED else None


def swallowed_message(signum: int) -> str:
    """The CLI's line for a swallowed interruption (:func:`delivered`) once the run is recorded."""
    return recorded_message(_interruption(signum)) or \
        f"{interruption_message(_interruption(signum))} after the run was recorded"


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    DELIVERED.append(signum)
    if _raised:  # a second signal while the first one's cleanup runs: let the cleanup finish
        return
    _raised.append(signum)
    if _held[0]:
        PENDING.append(signum)
        return
    raise Terminated(signum)


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    DELIVERED.append(signum)
    if _held[0]:
        if not PENDING:
            PENDING.append(signum)
        return
    raise KeyboardInterrupt


@contextlib.contextmanager
def terminate_like_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated`, and SIGINT (when Python's own handler is
    installed, i.e. not ignored) :class:`KeyboardInterrupt`, both held inside :class:`held` blocks; the previous
    handlers are restored after.

    Outside the main thread (where Python cannot install handlers) the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _raised.clear()
    PENDING.clear()
    RECORDED.clear()
    DELIVERED.clear()
    previous = {}
    for signum in HANDLED:
        previous[signum] = signal.signal(signum, _raise_terminated)
    if signal.getsignal(signal.SIGINT) in (signal.default_int_handler, _exit_on_signal):
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_interrupt)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


#: The complete ``summary.json`` kept although a signal came after it was written: ``[(path, status)]``.
RECORDED: list[tuple[Path, str]] = []


def note_recorded(path: Path, status: str) -> None:
    """Note that the complete ``summary.json`` at ``path`` (status ``status``) was kept although the run was then
    stopped by a signal (:func:`oacli.io.runfolder.write_summary`)."""
    RECORDED[:] = [(Path(path), str(status))]


def recorded_message(exc: BaseException) -> str | None:
    """The CLI's one line for an interruption that came after the run was recorded, else None."""
    if not RECORDED:
        return None
    path, status = RECORDED[0]
    return f"{interruption_message(exc)} after the run was recorded ({path}: status {status})"


def _exit_on_signal(signum: int, frame: FrameType | None) -> None:
    exc = _interruption(signum)
    line = recorded_message(exc) or interruption_message(exc)
    with contextlib.suppress(Exception):
        sys.stderr.write(f"error: {line}\n")
        sys.stderr.flush()
    raise SystemExit(exit_code_for(exc))


def exit_on_signal() -> None:
    """Install the console script's handlers: outside a command's :func:`terminate_like_interrupt` block (before it
    starts, and after it, e.g. while the results are printed once ``summary.json`` is written), SIGINT, SIGTERM and
    SIGHUP print one line and exit with ``128 + signal number`` instead of killing the process silently or printing
    a traceback. Main thread only; SIGINT only when Python's own handler is installed (not ignored)."""
    if threading.current_thread() is not threading.main_thread() or os.name != "posix":
        return
    for signum in HANDLED:
        signal.signal(signum, _exit_on_signal)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _exit_on_signal)
