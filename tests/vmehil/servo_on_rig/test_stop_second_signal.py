"""A safe stop is a signal-safe critical section: an interrupt raised inside it (here at the
first "enable low" write of each stop attempt — the runner's stop, ``armed()``'s except,
``armed()``'s finally) is held, the write made again, the stop completed and the interruption
recorded in ``final_stop``. Each test reads the emulated boards' nets, not a flag."""

from __future__ import annotations

import os
import signal

import pytest

from servo.interrupts import SignalsDeferred, Terminated
from servo.runner import LockstepRunner
from tests.support.boards import assert_boards_safe, driving
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

FAIL_AT = 100  # the demo move is under way: every amplifier enabled, DACs at a few volts


def _interrupt_stops(system, monkeypatch, times: int) -> list[int]:
    """From now on, the first amplifier-enable write to low of each of the next ``times`` calls
    of the drivers' safe stop raises KeyboardInterrupt before it reaches the board. Returns the
    list of stop attempts seen (its length: how many stops ran)."""
    io = system.io
    attempts: list[int] = []
    pending = {"armed": False}
    enables = {j.net("amp_enable") for j in system.rig.joints if "amp_enable" in j.wiring}
    real_stop = io.safe_stop

    def counting_stop(*a, **k):
        attempts.append(len(attempts))
        pending["armed"] = len(attempts) <= times
        return real_stop(*a, **k)

    monkeypatch.setattr(io, "safe_stop", counting_stop)
    for drv in io.pio.values():
        real_set = drv.set_line

        def set_line(name, level, *, verify=True, _real=real_set):
            if name in enables and not level and pending["armed"]:
                pending["armed"] = False
                raise KeyboardInterrupt
            return _real(name, level, verify=verify)

        monkeypatch.setattr(drv, "set_line", set_line)
    return attempts


@pytest.mark.parametrize("times", [1, 2, 3])
def test_interrupts_inside_each_stop_attempt_leave_the_rig_safe_and_recorded(times, monkeypatch) -> None:
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=400)
    runner = LockstepRunner(system, loop)

    def interrupt_at(lp) -> None:
        if lp.tick_count == FAIL_AT:
            assert driving(system)
            raise KeyboardInterrupt

    runner.after_tick.append(interrupt_at)
    attempts = _interrupt_stops(system, monkeypatch, times)
    with pytest.raises(KeyboardInterrupt), loop.armed():
        runner.run(300)
        if runner.ended_by is not None:
            raise runner.ended_by  # as `vmehil run` ends: with the signal's exit status
    assert len(attempts) == 3  # the runner's stop, armed()'s except, armed()'s finally
    assert_boards_safe(system)
    assert not driving(system)
    stop = loop.final_stop
    assert stop is not None and stop["reason"] == "interrupted" and stop["verified"] is True
    # the interrupt that ended the ticks, and one held inside each of the first `times` stops
    assert [i["during"] for i in stop["interruptions"]] == ["run"] + ["stop"] * times
    assert all(i["signal"] == "SIGINT" for i in stop["interruptions"])
    assert loop.fault is not None and loop.fault.cause == "interrupted"


def test_an_interrupt_in_the_final_stop_of_a_run_that_ended_is_raised_after_it(monkeypatch) -> None:
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=50)
    runner = LockstepRunner(system, loop)
    _interrupt_stops(system, monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt), loop.armed():
        runner.run(50)
    # no exchange follows a run's final stop: the boards' nets, not yet the plant, show it
    signals = system.crate.signals
    for j in system.rig.joints:
        assert signals.get_digital(j.net("amp_enable")) is False, j.name
        assert signals.get_analog(j.net("amp_command")) == pytest.approx(0.0, abs=0.0125), j.name
    assert loop.final_stop is not None and loop.final_stop["reason"] == "end"
    assert loop.final_stop["interruptions"] == [{"signal": "SIGINT", "tick": 50, "during": "stop"}]


def test_a_critical_section_holds_real_signals_until_it_ends() -> None:
    held: list[BaseException] = []
    with SignalsDeferred(held):
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGTERM)
        # the handlers run at the next bytecode boundary: here, inside the section
        for _ in range(1000):
            if len(held) == 2:
                break
    assert [type(e) for e in held] == [KeyboardInterrupt, Terminated]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # put back
