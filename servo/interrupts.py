"""Signals as exceptions, so that every way out of a run passes through the safe stop.

SIGINT already arrives as :class:`KeyboardInterrupt`. :func:`stop_signals_raise` makes SIGTERM
(and SIGHUP) raise :class:`Terminated` in the main thread for the duration of a run; the
runners (:mod:`servo.runner`) catch both, safe-stop the rig in the same tick and end the run
with the fault cause ``interrupted``. SIGKILL cannot be caught: that is what the amplifier-side
enable watchdog is for (docs/faults.md).

A safe stop must not be cut short by a second signal (Ctrl-C pressed twice, a burst of SIGTERMs):
:class:`SignalsDeferred` is its critical section. Inside it SIGINT, SIGTERM and SIGHUP are held
(recorded, not raised); the code that owns the section decides what to do with them when the stop
is done (:class:`servo.loop.ServoLoop` records them and raises the first).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any, ClassVar


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
            if signal.getsignal(s) is _raise:  # a handler set inside the block (a program that
                signal.signal(s, h)             # ends ignoring further signals) stays


#: what a signal becomes in the main thread: the exceptions a stop defers or records
INTERRUPTS = (KeyboardInterrupt, Terminated)

#: the signals a critical section holds back
DEFERRED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def interrupt_for(signum: int) -> BaseException:
    """The exception a signal raises outside a critical section."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


class SignalsDeferred:
    """A signal-safe critical section: between :meth:`begin` and :meth:`end` (or as a ``with``
    block) SIGINT, SIGTERM and SIGHUP arriving in this process are appended to ``held`` as the
    exception they would have raised (:func:`interrupt_for`) instead of raising it.

    Sections nest and may overlap (one can begin before another ends: a stop hands over to the
    writing of its report): one handler per signal is installed while any section is open and
    appends to the newest open section's list; the handlers found at the first begin are put
    back when the last section ends. Outside the main thread (where Python runs no signal
    handlers) a section holds nothing and changes nothing."""

    _open: ClassVar[list[SignalsDeferred]] = []  #: the open sections, oldest first
    _saved: ClassVar[dict[int, Any]] = {}  #: the handlers found when the first one began

    def __init__(self, held: list[BaseException] | None = None) -> None:
        self.held: list[BaseException] = [] if held is None else held
        self._active = False

    @staticmethod
    def _hold(signum: int, frame: FrameType | None) -> None:
        if not SignalsDeferred._open:  # the last section ended while its handlers were being put back
            raise interrupt_for(signum)
        SignalsDeferred._open[-1].held.append(interrupt_for(signum))

    def begin(self) -> SignalsDeferred:
        if self._active or threading.current_thread() is not threading.main_thread():
            return self
        cls = SignalsDeferred
        first = not cls._open
        # registered before the handlers go in: a signal after its handler is installed always
        # finds a section to be held by (before, one arriving while the handlers were being
        # installed raised from the middle of the installation and left a handler with no section)
        cls._open.append(self)
        self._active = True
        if first:
            try:
                for s in DEFERRED_SIGNALS:
                    cls._saved[s] = signal.signal(s, cls._hold)
            except BaseException:  # a signal through a handler not yet replaced: no section after all
                self.end()
                raise
        return self

    def end(self) -> None:
        if not self._active:
            return
        cls = SignalsDeferred
        self._active = False
        cls._open.remove(self)
        if not cls._open:
            saved, cls._saved = cls._saved, {}
            for s, h in saved.items():
                # None: the handler found was not installed from Python (it cannot be put back
                # from Python either); the default is the nearest ("TypeError: signal handler
                # must be …" came from passing None, seen once under a burst of signals)
                signal.signal(s, h if h is not None else signal.SIG_DFL)

    def __enter__(self) -> list[BaseException]:
        self.begin()
        return self.held

    def __exit__(self, *exc: object) -> None:
        self.end()
