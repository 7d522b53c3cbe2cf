"""The enable watchdog through the whole in-process rig, on simulated time: the drivers toggle
the ``[rig.watchdog]`` line once per tick while enabled; a hung controller (ticks stop, the
plant's time goes on) loses its amplifiers after ``timeout_s``; a safe stop leaves the line low
and trips nothing; ``resume`` re-arms. Plus the rig-file checks of the line."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import tomli_w

from emulators.plant.amplifier import WATCHDOG_EXPIRED
from emulators.presets import resolve_rig
from hal.config import ConfigError, load_toml
from servo.rig import WATCHDOG_NET, load_rig
from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def _started(rig=None, ticks: int = 40):
    system = build_emulated_rig(rig, seed=0)
    loop = build_loop(system, n_ticks=2000)
    loop.start()
    runner = LockstepRunner(system, loop)
    runner.run(ticks)  # the demo move is under way: every amplifier enabled
    assert loop.fault is None
    return system, loop, runner


def _hung_periods(system, loop, n: int) -> dict[str, np.ndarray]:
    """The controller hangs: no ticks, no writes — but the rig's time goes on, period by period."""
    k0 = loop.tick_count
    for i in range(n):
        k = k0 + i
        system.advance_to(k * system.period_ns + round(system.computation_delay_s * 1e9))
        system.exchange(k)
        system.sense(k)
    loop.tick_count = k0 + n  # the clock went on while the loop hung
    return system.truth()


def test_the_drivers_toggle_the_line_once_per_tick_while_enabled() -> None:
    system, _, runner = _started(ticks=1)
    signals = system.crate.signals
    levels = []
    for _ in range(20):
        runner.run(1)
        levels.append(signals.get_digital(WATCHDOG_NET))
    assert levels == [levels[0], not levels[0]] * 10
    assert system.io.watchdog_running
    assert system.plant.watchdog.armed and system.plant.watchdog.trips == 0


def test_a_hung_controller_loses_its_amplifiers_after_the_timeout() -> None:
    system, loop, _ = _started()
    timeout_s = system.rig.watchdog.timeout_s
    before = int(timeout_s / system.period_s)  # whole periods that end before the pump runs out
    truth = _hung_periods(system, loop, before - 1)
    assert truth["amp_enabled"].all()  # still on: the last edge is less than timeout_s ago
    truth = _hung_periods(system, loop, 2)
    assert not truth["amp_enabled"].any()
    assert (truth["amp_watchdog_cause"] == WATCHDOG_EXPIRED).all()
    truth = _hung_periods(system, loop, 2)
    assert np.all(truth["current_a"] == 0.0)  # every output stage open, current decayed
    assert not system.harness.last.amp_fault.any()  # not a fault: the fault lines stay low


def test_resume_after_a_trip_re_arms_the_amplifiers() -> None:
    system, loop, runner = _started()
    _hung_periods(system, loop, 20)
    loop.safe_stop("stale_sensor", "the loop noticed it had hung")  # what a recovering loop does
    runner.run(1)  # the plant sees the lines once per period: the enables must be low for one
    assert not system.truth()["amp_enabled"].any()
    loop.resume()
    runner.run(3)
    truth = system.truth()
    assert truth["amp_enabled"].all() and not truth["amp_watchdog_tripped"].any()


def test_a_live_resume_long_after_a_stop_re_arms_with_one_edge_in_its_tick() -> None:
    """The resume runs inside a tick (a live command) that then writes torque: one edge in that
    tick, not two that would cancel and leave the rising enables facing a dead pump."""
    system, loop, runner = _started()
    loop.safe_stop("following_error", "test")
    runner.run(50)  # 0.4 s: the pump is long dead
    signals = system.crate.signals
    before = signals.get_digital(WATCHDOG_NET)
    loop.submit(lambda lp: lp.resume())
    runner.run(1)
    assert loop.enabled and signals.get_digital(WATCHDOG_NET) is not before
    runner.run(2)
    truth = system.truth()
    assert truth["amp_enabled"].all() and system.plant.watchdog.trips == 0


def test_a_safe_stop_leaves_the_line_low_and_trips_nothing() -> None:
    system, loop, runner = _started()
    loop.safe_stop("following_error", "test")
    assert loop.stop_incomplete == []
    assert system.crate.signals.get_digital(WATCHDOG_NET) is False
    assert not system.io.watchdog_running
    runner.run(50)  # 0.4 s: the pump has long run out
    assert system.plant.watchdog.trips == 0
    assert not system.truth()["amp_watchdog_tripped"].any()


def _rig_with_watchdog(tmp_path, watchdog: dict | None):
    data = copy.deepcopy(load_toml(resolve_rig("jpl-arm")).data)
    if watchdog is None:
        del data["rig"]["watchdog"]
    else:
        data["rig"]["watchdog"] = watchdog
    path = tmp_path / "rig.toml"
    path.write_bytes(tomli_w.dumps(data).encode())
    return path


def test_a_rig_without_watchdog_wiring_runs_without_one(tmp_path) -> None:
    system, loop, _ = _started(_rig_with_watchdog(tmp_path, None))
    assert system.rig.watchdog is None and not system.io.watchdog_running
    assert WATCHDOG_NET not in system.crate.signals.digital
    _hung_periods(system, loop, 20)
    assert system.truth()["amp_enabled"].all()  # nothing watches the controller


@pytest.mark.parametrize("watchdog, complaint", [
    ({"line": "pio0:PC7", "timeout_s": 0.05}, "already carries hand.amp_enable"),
    ({"line": "adc0:3", "timeout_s": 0.05}, "PIO line"),
    ({"line": "pio0:PWM", "timeout_s": 0.05}, "PIO line"),
    ({"line": "pio0:PB7", "timeout_s": 0.008}, "more than one servo period"),
    ({"line": "pio0:PB7"}, "timeout_s"),
    ({"line": "pio0:PB7", "timeout_s": 0.05, "period_s": 1}, "period_s"),
])
def test_the_rig_file_refuses_a_watchdog_line_that_cannot_work(tmp_path, watchdog, complaint) -> None:
    with pytest.raises(ConfigError, match=complaint):
        load_rig(_rig_with_watchdog(tmp_path, watchdog))


def test_the_presets_wire_their_watchdog_to_a_free_pio_line() -> None:
    for name in ("jpl-arm", "melmalec-16"):
        rig = load_rig(resolve_rig(name))
        assert rig.watchdog is not None and rig.watchdog.timeout_s > rig.period_s, name
        assert rig.watchdog.line not in {p for j in rig.joints for p in j.wiring.values()}, name
