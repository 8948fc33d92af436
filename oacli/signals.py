"""Termination signals handled like Ctrl-C: SIGTERM (what ``timeout``, systemd, docker and Dask send) and
SIGHUP raise :class:`Terminated`, a :class:`KeyboardInterrupt`, so every cleanup path that handles Ctrl-C runs
(temporary files removed, ``summary.json`` written with ``"status": "interrupted"``). The command then exits
with ``128 + signal number`` (143 for SIGTERM; 130 for Ctrl-C), as a shell reports a process killed by it.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
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


def interruption_message(exc: BaseException) -> str:
    """The CLI's line: ``"interrupted"`` (Ctrl-C) or ``"interrupted (terminated by SIGTERM)"``."""
    return f"interrupted ({exc})" if isinstance(exc, Terminated) else "interrupted"


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    if _raised:  # a second signal while the first one's cleanup runs: let the cleanup finish
        return
    _raised.append(signum)
    raise Terminated(signum)


@contextlib.contextmanager
def terminate_like_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated`; the previous handlers are restored after.

    Outside the main thread (where Python cannot install handlers) the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _raised.clear()
    previous = {}
    for signum in HANDLED:
        previous[signum] = signal.signal(signum, _raise_terminated)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
