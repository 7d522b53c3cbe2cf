"""Every watchdog cause leads to a safe stop: amplifiers disabled, DAC outputs at 0 V, reason kept."""

from __future__ import annotations

import numpy as np
import pytest

from emulators.board import BoardAccessError
from hal.vme import BusErrorCause
from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def _started(seed: int = 0, n_ticks: int = 400):
    system = build_emulated_rig(None, seed=seed)
    loop = build_loop(system, n_ticks=n_ticks)
    loop.start()
    runner = LockstepRunner(system, loop)
    runner.run(40)  # moving by now (the demo move starts at t = 0)
    assert loop.fault is None
    return system, loop, runner


def _assert_safe(system, loop, cause: str) -> None:
    assert loop.fault is not None and loop.fault.cause == cause, loop.fault
    assert not loop.enabled
    signals = system.crate.signals
    for j in system.rig.joints:
        if "amp_enable" in j.wiring:
            assert signals.get_digital(j.net("amp_enable")) is False, j.name
        if "amp_command" in j.wiring:
            # 0 V commanded; the uncalibrated DAC's offset error (≤ 10 mV in the preset) remains
            assert signals.get_analog(j.net("amp_command")) == pytest.approx(0.0, abs=0.0125), j.name
    # the plant sees the amplifiers off: no more drive current after a few ticks
    truth = system.truth()
    assert np.all(np.abs(truth["current_a"][:6]) < 0.5)


def test_driver_error_stops_safely(monkeypatch) -> None:
    system, loop, runner = _started()
    adc = system.crate.board("adc0")

    def berr(offset, width):
        raise BoardAccessError(BusErrorCause.NO_RESPONDER, "board pulled from the crate")

    monkeypatch.setattr(adc, "bus_read", berr)
    runner.run(5)
    _assert_safe(system, loop, "driver_error")
    assert "bus error" in loop.fault.detail


def test_pot_at_rail_is_implausible() -> None:
    system, loop, runner = _started()
    system.crate.board("adc0").inject("stuck_channel", channel=0, code=0xFFF)  # open wiper → +10 V
    runner.run(5)
    _assert_safe(system, loop, "implausible_sensor")
    assert loop.fault.joint == "j1"


def test_stuck_pot_while_moving_is_stale() -> None:
    system, loop, runner = _started(n_ticks=600)
    loop.watchdog.cross_checks = False  # the encoder would see it first: the stale rule on its own
    loop.watchdog.following_error_rad[:] = 10.0  # let staleness, not following error, trip
    runner.run(60)  # j2 moving faster now
    code = system.io.adc["adc0"].read_counts(1)  # freeze the wiper where it is now
    system.crate.board("adc0").inject("stuck_channel", channel=1, code=code)
    runner.run(100)
    _assert_safe(system, loop, "stale_sensor")
    assert loop.fault.joint == "j2"


def test_amplifier_fault_line_stops() -> None:
    system, loop, runner = _started()
    system.crate.board("pio0").inject("line_stuck", line="PB2", level=True)
    runner.run(3)
    _assert_safe(system, loop, "amplifier_fault")
    assert loop.fault.joint == "j3"


def test_following_error_stops() -> None:
    system, loop, runner = _started()
    loop.watchdog.following_error_rad[:] = np.radians(0.01)
    runner.run(3)
    _assert_safe(system, loop, "following_error")


def test_live_commands_apply_at_tick_boundaries() -> None:
    _, loop, runner = _started()
    seen = []
    loop.submit(lambda lp: lp.law.set_gains(kp=150.0, joint=0), lambda r, e: seen.append((lp_tick(loop), e)))
    assert loop.law.gains.kp[0] == 100.0  # nothing happens before the next tick
    runner.run(2)
    assert loop.law.gains.kp[0] == 150.0 and seen and seen[0][1] is None


def lp_tick(loop) -> int:
    return loop.tick_count
