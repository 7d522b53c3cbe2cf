"""Driving a console from a test: helpers that run ticks until a condition holds, collect the
console's reply lines and talk to it the way a script does. The loop under the console is
:func:`tests.support.fakes.make_loop` or the emulated rig.

No tests here; the console tests import it as ``tests.support.console``.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

from servo.loop import ServoLoop
from tests.support.fakes import tick


def until(pred, loop: ServoLoop, console=None, max_ticks: int = 400, pause_s: float = 0.002, step=None) -> int:
    """Tick until ``pred()`` (checked after each tick, with a short pause so the reader thread can
    run); returns the number of ticks; fails the test after ``max_ticks``. ``step()`` replaces the
    plain tick (e.g. a runner's tick, which calls the console's hook itself)."""
    for k in range(max_ticks):
        if pred():
            return k
        if step is not None:
            step()
        else:
            tick(loop, console)
        time.sleep(pause_s)
    raise AssertionError(f"condition not met within {max_ticks} ticks")


class LineReader:
    """Collects CRLF lines from a read(n) -> bytes function; ``reply()`` returns one whole reply
    (the lines up to and including an OK/ERR line), skipping EVT lines into ``events``."""

    def __init__(self, read) -> None:
        self.read = read
        self.buf = b""
        self.events: list[str] = []

    def lines(self) -> list[str]:
        data = self.read(4096)
        if data:
            self.buf += data
        out = []
        while b"\n" in self.buf:
            line, self.buf = self.buf.split(b"\n", 1)
            text = line.decode("utf-8", "replace").strip("\r")
            if text:
                out.append(text)
        return out


class Driver:
    """Talks to a console the way a script does: ``ask(line)`` sends one line, runs ticks until the
    whole reply arrived and returns its lines (EVT lines go to ``events``)."""

    def __init__(self, loop: ServoLoop, console, send, poll, step=None) -> None:
        self.step = step
        self.loop = loop
        self.console = console
        self.send = send
        self.poll = poll
        self.events: list[str] = []
        self._pending: list[str] = []

    def _take_reply(self) -> list[str] | None:
        for i, line in enumerate(self._pending):
            if line.startswith(("OK", "ERR")):
                reply, self._pending = self._pending[: i + 1], self._pending[i + 1:]
                return reply
        return None

    def _collect(self) -> None:
        for line in self.poll():
            if line.startswith("EVT"):
                self.events.append(line)
            else:
                self._pending.append(line)

    def reply(self, max_ticks: int = 400) -> list[str]:
        got: list[list[str]] = []

        def ready() -> bool:
            self._collect()
            r = self._take_reply()
            if r is not None:
                got.append(r)
            return bool(got)

        until(ready, self.loop, self.console, max_ticks, step=self.step)
        return got[0]

    def ask(self, line: str, max_ticks: int = 400) -> list[str]:
        wait = getattr(self.console, "wait_taken", None)
        before = self.console.lines_taken() if wait is not None else 0
        self.send((line + "\r\n").encode())
        # the ticks count from when the console has the line: how long its reader and preparer
        # threads wait for a core (a loaded machine) must not decide which tick the command lands
        # on, nor use up max_ticks (the wait's bound is against a hang only)
        if wait is not None:
            assert wait(before + 1, timeout_s=60.0), f"the console did not take {line!r} within 60 s"
        return self.reply(max_ticks)

    def wait_event(self, prefix: str, max_ticks: int = 2000) -> str:
        found: list[str] = []

        def seen() -> bool:
            self._collect()
            for e in self.events:
                if e.startswith(prefix):
                    found.append(e)
                    self.events.remove(e)
                    return True
            return False

        until(seen, self.loop, self.console, max_ticks, pause_s=0.0005, step=self.step)
        return found[0]


def tap_poll(console):
    """Lines the console sends, via its tap (for loop://, where the port loops back to itself)."""
    lines: list[str] = []
    console.taps.append(lines.append)

    def poll() -> list[str]:
        out = lines[:]
        del lines[: len(out)]
        return out

    return poll


def wait_for_link(path: Path, proc: subprocess.Popen, timeout_s: float = 120.0) -> None:
    """Wait until the console's pty link ``path`` exists (a vmehil subprocess creates it); fail
    at once if ``proc`` exits first. The bound is against a hang only."""
    deadline = time.monotonic() + timeout_s
    while not path.is_symlink():
        if proc.poll() is not None:
            raise AssertionError(f"vmehil exited early: {proc.stderr.read() if proc.stderr else ''}")
        if time.monotonic() > deadline:
            raise AssertionError("the console pty did not appear")
        time.sleep(0.05)
