"""Signals as exceptions, so that every way out of a run passes through the safe stop.

SIGINT already arrives as :class:`KeyboardInterrupt`. :func:`stop_signals_raise` makes SIGTERM
(and SIGHUP) raise :class:`Terminated` in the main thread for the duration of a run; the
runners (:mod:`servo.runner`) catch both, safe-stop the rig in the same tick and end the run
with the fault cause ``interrupted``. SIGKILL cannot be caught: that is what the amplifier-side
enable watchdog is for (docs/faults.md).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


class Terminated(BaseException):
    """The process was asked to terminate (SIGTERM, SIGHUP). A BaseException, like
    KeyboardInterrupt, so that ``except Exception`` in tools does not swallow it."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


#: exit statuses of a run ended by a signal (128 + the signal number, as shells report them)
EXIT_SIGINT = 128 + signal.SIGINT
EXIT_SIGTERM = 128 + signal.SIGTERM


def interrupt_name(exc: BaseException) -> str:
    """``"SIGINT"`` for a KeyboardInterrupt, the signal's name for :class:`Terminated`."""
    return str(exc) if isinstance(exc, Terminated) else "SIGINT"


def interrupt_exit_status(exc: BaseException) -> int:
    return 128 + exc.signum if isinstance(exc, Terminated) else EXIT_SIGINT


@contextmanager
def stop_signals_raise(signals: tuple[int, ...] = (signal.SIGTERM, signal.SIGHUP)) -> Iterator[None]:
    """Within the block, ``signals`` raise :class:`Terminated` in the main thread. Outside the
    main thread (where handlers cannot be installed) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum: int, frame: FrameType | None) -> None:
        raise Terminated(signum)

    old = {s: signal.signal(s, _raise) for s in signals}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
