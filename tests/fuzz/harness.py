"""What the fuzz harnesses share: the per-example time bound (a hang is reported with its harness
and input instead of hanging forever), the per-harness counts, and :func:`refused`, which a
harness calls when its target refused an input with its own typed error.

The settings of every ``@given`` test in ``tests/fuzz`` come from the profile in force (registered
in ``tests/fuzz/conftest.py``): harnesses set no ``max_examples`` of their own.
"""

from __future__ import annotations

import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hypothesis import event
from hypothesis.errors import HypothesisException, InvalidArgument

#: examples the test suite's short run gives each harness
SHORT_EXAMPLES = 40
#: per-example bound (s) in the suite: generous, a hang guard, not a speed check
SUITE_TIMEOUT_S = 60.0


class FuzzHang(BaseException):
    """An example ran past the per-example bound (a BaseException: no harness catches it)."""


@dataclass
class Counts:
    """One harness's figures over a run."""

    examples: int = 0
    escaped: int = 0  #: examples that raised an exception other than an assertion (a crash)
    failed: int = 0  #: examples whose property assertion failed
    hangs: int = 0
    refused: dict[str, int] = field(default_factory=dict)  #: typed refusals, by kind
    first_problem: str = ""  #: the first escape, failure or hang: what and on which input

    def as_dict(self) -> dict[str, Any]:
        return {"examples": self.examples, "escaped": self.escaped, "failed": self.failed, "hangs": self.hangs,
                "refused": dict(self.refused), "first_problem": self.first_problem}


COUNTS: dict[str, Counts] = {}
_current: list[str] = []  # the harness running now (one at a time: the main thread)
_started: list[float] = []  # when the running example started (monotonic), empty between examples
_input: list[str] = []  # the running example's input (repr), for a hang report


def refused(kind: str) -> None:
    """The target refused this input with its own typed error ``kind`` (counted, and a
    hypothesis event: ``--hypothesis-show-statistics`` lists them too)."""
    try:
        event(f"refused: {kind}")
    except InvalidArgument:  # not inside a hypothesis example (the framework's own tests)
        pass
    if _current:
        c = COUNTS[_current[0]]
        c.refused[kind] = c.refused.get(kind, 0) + 1


def _short_repr(args: tuple[Any, ...], kwargs: dict[str, Any], limit: int = 2000) -> str:
    text = ", ".join([*(repr(a) for a in args), *(f"{k}={v!r}" for k, v in kwargs.items())])
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} characters)"


def _on_alarm(signum: int, frame: Any) -> None:
    raise FuzzHang(f"example ran over the per-example bound in {_current[0] if _current else '?'}")


def bounded(name: str, inner: Callable[..., Any], timeout_s: float) -> Callable[..., Any]:
    """``inner`` (a hypothesis test's inner test) counted under ``name`` and bounded: SIGALRM after
    ``timeout_s`` raises :class:`FuzzHang` in the example (the main thread)."""
    counts = COUNTS.setdefault(name, Counts())

    @functools.wraps(inner)
    def run(*args: Any, **kwargs: Any) -> Any:
        counts.examples += 1
        _current[:] = [name]
        _input[:] = [_short_repr(args, kwargs)]
        _started[:] = [time.monotonic()]
        old = signal.signal(signal.SIGALRM, _on_alarm)
        signal.setitimer(signal.ITIMER_REAL, timeout_s)
        try:
            return inner(*args, **kwargs)
        except FuzzHang:
            counts.hangs += 1
            counts.first_problem = counts.first_problem or f"hang (> {timeout_s:g} s) on {_input[0]}"
            raise
        except AssertionError as e:
            counts.failed += 1
            counts.first_problem = counts.first_problem or f"AssertionError: {e} on {_input[0]}"
            raise
        except HypothesisException:  # assume(), ... : hypothesis's own control flow
            raise
        except Exception as e:
            counts.escaped += 1
            counts.first_problem = counts.first_problem or f"{type(e).__name__}: {e} on {_input[0]}"
            raise
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
            _started.clear()

    return run


class Watchdog:
    """The backstop when SIGALRM cannot interrupt an example (stuck in C code): a thread that,
    ``grace_s`` after the bound, prints the harness, its input and the counts so far, and ends the
    process with exit status 3."""

    def __init__(self, timeout_s: float, grace_s: float = 10.0,
                 report: Callable[[], None] | None = None) -> None:
        self.limit_s = timeout_s + grace_s
        self.report = report
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="fuzz-watchdog", daemon=True)

    def start(self) -> Watchdog:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def _watch(self) -> None:
        while not self._stop.wait(0.5):
            started = list(_started)
            if started and time.monotonic() - started[0] > self.limit_s:
                name = _current[0] if _current else "?"
                COUNTS.setdefault(name, Counts()).hangs += 1
                print(f"\nfuzz: HANG in {name}: an example ran over {self.limit_s:g} s and SIGALRM could not "
                      f"stop it; input: {_input[0] if _input else '?'}", file=sys.stderr, flush=True)
                if self.report is not None:
                    self.report()
                os._exit(3)
