"""Every way out of a run ends safe: an exception from any part of a tick, SIGINT and SIGTERM
safe-stop the rig in the same tick. Each test reads the emulated boards' nets (enable lines,
DAC outputs, PWM), not a flag."""

from __future__ import annotations

import os
import signal

import pytest

from emulators.board import BoardAccessError
from hal.vme import BusErrorCause
from servo.interrupts import Terminated, stop_signals_raise
from servo.runner import LockstepRunner, RealtimeRunner
from tests.support.boards import assert_boards_safe, driving
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

FAIL_AT = 100  # the demo move is under way: every amplifier enabled, DACs at a few volts


def _rig(realtime_clock=None):
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=400)
    loop.start()
    if realtime_clock is None:
        runner = LockstepRunner(system, loop)
    else:
        runner = RealtimeRunner(system, loop, clock=realtime_clock[0], sleep=realtime_clock[1])
    return system, loop, runner


def _raise_at(k: int, exc: BaseException):
    def hook(loop) -> None:
        if loop.tick_count == k:
            raise exc
    return hook


@pytest.mark.parametrize("source", ["trajectory", "control_object", "plant", "after_tick_hook"])
def test_an_exception_in_any_part_of_a_tick_safe_stops_in_that_tick(source, monkeypatch) -> None:
    system, loop, runner = _rig()
    runner.run(FAIL_AT - 1)
    assert driving(system) and loop.fault is None
    boom = RuntimeError(f"injected failure in the {source}")
    if source == "trajectory":
        monkeypatch.setattr(loop.sequencer, "sample", lambda t: (_ for _ in ()).throw(boom))
    elif source == "control_object":
        monkeypatch.setattr(loop.controller, "update", lambda ctx: (_ for _ in ()).throw(boom))
    elif source == "plant":
        monkeypatch.setattr(system.link, "exchange", lambda *a: (_ for _ in ()).throw(boom))
    else:
        runner.after_tick.append(_raise_at(FAIL_AT, boom))
    done = runner.run(300)
    assert done < 300 and runner.ended_by is boom
    assert loop.fault is not None and loop.fault.cause == "exception"
    assert "RuntimeError: injected failure" in loop.fault.detail
    assert loop.fault.tick in (FAIL_AT - 1, FAIL_AT)  # the tick that failed
    assert loop.stop_incomplete == []
    if source == "plant":
        # the plant itself failed: its state is unknown, but every board output is safe
        signals = system.crate.signals
        assert not any(signals.get_digital(j.net("amp_enable")) for j in system.rig.joints if "amp_enable" in j.wiring)
    else:
        assert_boards_safe(system)


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt(), Terminated(signal.SIGTERM)], ids=["SIGINT", "SIGTERM"])
def test_an_interrupt_safe_stops_with_cause_interrupted(interrupt) -> None:
    system, loop, runner = _rig()
    runner.after_tick.append(_raise_at(FAIL_AT, interrupt))
    runner.run(300)
    assert loop.fault is not None and loop.fault.cause == "interrupted"
    assert ("SIGTERM" if isinstance(interrupt, Terminated) else "SIGINT") in loop.fault.detail
    assert_boards_safe(system)


def test_a_real_sigterm_becomes_a_safe_stop() -> None:
    system, loop, runner = _rig()

    def kill_self(lp) -> None:
        if lp.tick_count == FAIL_AT:
            os.kill(os.getpid(), signal.SIGTERM)

    runner.after_tick.append(kill_self)
    with stop_signals_raise():
        runner.run(300)
    assert isinstance(runner.ended_by, Terminated)
    assert loop.fault is not None and loop.fault.cause == "interrupted" and "SIGTERM" in loop.fault.detail
    assert_boards_safe(system)


def test_a_stop_that_cannot_be_confirmed_is_reported_as_incomplete(monkeypatch) -> None:
    """A PIO board pulled from the crate: the enables cannot be driven nor read back."""
    system, loop, runner = _rig()
    runner.run(FAIL_AT)
    pio = system.crate.board("pio0")

    def berr(*a, **k):
        raise BoardAccessError(BusErrorCause.NO_RESPONDER, "board pulled from the crate")

    monkeypatch.setattr(pio, "bus_read", berr)
    monkeypatch.setattr(pio, "bus_write", berr)
    runner.run(5)
    assert loop.fault is not None
    lines = [p for p in loop.stop_incomplete if "enable" in p]
    assert lines and all("cannot be read back" in p or "bus error" in p.lower() for p in lines)


def test_realtime_loop_that_falls_behind_stops_with_cause_overrun() -> None:
    """The clock is injected: from tick 50 on every tick takes 3 periods."""
    fake = {"t": 0.0}
    clock = lambda: fake["t"]  # noqa: E731
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=400)
    loop.start()
    runner = RealtimeRunner(system, loop, clock=clock, sleep=lambda s: fake.__setitem__("t", fake["t"] + s),
                            spin_s=0.0)
    period = system.rig.period_s

    def slow(lp) -> None:
        if lp.tick_count >= 50:
            fake["t"] += 3 * period

    runner.after_tick.append(slow)
    done = runner.run(400)
    assert loop.fault is not None and loop.fault.cause == "overrun", loop.fault
    assert 50 < done < 60  # 5 periods behind after three slow ticks
    assert_boards_safe(system)


def test_realtime_overrun_warn_policy_runs_on() -> None:
    fake = {"t": 0.0}
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=100)
    loop.start()
    runner = RealtimeRunner(system, loop, clock=lambda: fake["t"], spin_s=0.0, overrun="warn",
                            sleep=lambda s: fake.__setitem__("t", fake["t"] + s))
    runner.after_tick.append(lambda lp: fake.__setitem__("t", fake["t"] + 3 * system.rig.period_s))
    assert runner.run(100) == 100
    assert loop.fault is None and runner.late_ticks > 0
