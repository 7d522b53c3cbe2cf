"""Shared test support for the console tests: a ServoLoop over a small simulated JointIO (a rigid
double integrator per joint), and helpers that drive ticks and collect console replies.

No tests here; the console tests import it as ``tests.support.console``.
"""

from __future__ import annotations

import math
import time

import numpy as np

from servo.control.normalize import normalizing_chain
from servo.control.objects import build_controller
from servo.io import Measurement
from servo.loop import ServoLoop, WatchdogConfig
from servo.trajectory import JointLimits, PlanContext, Sequencer


class SimIO:
    """Stand-in for servo.io.JointIO: joints of inertia ``inertia`` kg·m² integrated exactly over
    each period with the commanded torque held (ZOH); measured position = true position."""

    def __init__(self, n: int = 2, period_s: float = 0.008, inertia: float = 1.0) -> None:
        self.n = n
        self.period_s = period_s
        self.inertia = inertia
        self.theta = np.zeros(n)
        self.omega = np.zeros(n)
        self.enabled = False
        self.read_error: Exception | None = None
        self.fault = np.zeros(n, bool)

    def read(self) -> Measurement:
        if self.read_error is not None:
            raise self.read_error
        nan = np.full(self.n, np.nan)
        return Measurement(theta_pot=self.theta.copy(), theta_enc=self.theta.copy(), omega_tach=self.omega.copy(),
                           omega_enc=self.omega.copy(), current=np.zeros(self.n), pot_v=nan,
                           fault=self.fault.copy(), theta=self.theta.copy(), omega=self.omega.copy())

    def write_torque(self, torque: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        tau = np.asarray(torque, float) if self.enabled else np.zeros(self.n)
        a = tau / self.inertia
        T = self.period_s
        self.theta = self.theta + self.omega * T + 0.5 * a * T * T
        self.omega = self.omega + a * T
        return tau.copy()

    def enable(self, on: bool = True) -> None:
        self.enabled = on

    def clear_faults(self) -> None:
        self.fault[:] = False

    def safe_stop(self) -> list[str]:
        self.enabled = False
        return []


def make_loop(n: int = 2, names: list[str] | None = None, inertia: float = 1.0) -> ServoLoop:
    """A started ServoLoop (paper gains, pid only) over :class:`SimIO`."""
    io = SimIO(n, inertia=inertia)
    chain = normalizing_chain([inertia] * n, [1.0] * n, [1.0] * n, [1.0] * n)
    ctrl = build_controller({"objects": ["pid"]}, chain, io.period_s)
    ctx = PlanContext(JointLimits.make(n, math.radians(30.0)))
    seq = Sequencer([], np.zeros(n), ctx)
    wd = WatchdogConfig(following_error_rad=np.full(n, math.radians(10.0)))
    loop = ServoLoop(io, ctrl, seq, wd, names=names or [f"j{i + 1}" for i in range(n)])
    loop.plan_context = ctx  # type: ignore[attr-defined]
    loop.start()
    return loop


def tick(loop: ServoLoop, console=None, n: int = 1) -> None:
    """Run ``n`` ticks, calling the console's per-tick hook after each (what a runner does)."""
    for _ in range(n):
        loop.tick()
        if console is not None:
            console.on_tick(loop)


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
        self.send((line + "\r\n").encode())
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
