"""The plant node's amplifier side: the enable-watchdog line carried in SYNC, the wall-clock
command timeout, and the amplifier state in HEARTBEAT_PLANT / PLANT_STATUS.

The node is driven frame by frame (``handle``, ``step``) with a fake clock: no thread, no race
with the wall clock. A second bus on the same ``virtual`` channel reads what the node sends.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from emulators.can.bus import Endpoint, open_bus
from emulators.can.codec import CanCodec
from emulators.can.node import PLANT_IDS, PlantNode, node_spec
from emulators.plant import Plant, PlantCommand
from emulators.plant.amplifier import WATCHDOG_COMMAND_TIMEOUT, WATCHDOG_EXPIRED

SPEC = node_spec("jpl-arm")
N = SPEC.n_joints
PERIOD, DELAY = SPEC.period_s, SPEC.delay_s
CODEC = CanCodec()
_chan = itertools.count()
BOOT = 7  # the controller boot id of the session these tests play


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Controller:
    """Plays the controller's side of the protocol into a node, and reads the node's frames."""

    def __init__(self, *, command_timeout_s: float | None = 0.2, free_running: bool = False) -> None:
        chan = f"node-watchdog-{next(_chan)}"
        self.clock = Clock()
        self.node = PlantNode(Endpoint(open_bus("virtual", chan), PLANT_IDS),
                              lambda s: Plant.from_config(SPEC.table, seed=s), N, free_running=free_running,
                              period_s=PERIOD, delay_s=DELAY, command_timeout_s=command_timeout_s,
                              names=SPEC.names, clock=self.clock)
        self.bus = open_bus("virtual", chan)
        self.cmd = PlantCommand.idle(N)
        self.cmd.amp_command_v[:] = 0.2
        self.tick = 0
        self.node.handle(CODEC.frame("CONTROL", Command=1, Seed=3, NJoints=N, BootId=BOOT))

    def close(self) -> None:
        self.node.close()
        self.bus.shutdown()

    def send(self, *, enable: bool = True, toggle: bool = True, step: bool = True) -> None:
        """One tick, one period after the last: CMD frames and SYNC (lockstep: the node steps on it)."""
        self.clock.t += PERIOD
        self.cmd.amp_enable[:] = enable
        if toggle:
            self.cmd.watchdog_line = not self.cmd.watchdog_line
        raw = CODEC.command_raw(self.cmd)
        for m in CODEC.command_frames(raw, self.tick, BOOT):
            self.node.handle(m)
        self.node.handle(CODEC.sync_frame(raw, self.tick, PERIOD, DELAY, BOOT))
        if step and self.node.free_running:
            self.node.step(self.tick, PERIOD, DELAY)
        self.tick += 1

    def frames(self) -> dict[str, list]:
        """Everything the node sent since the last call, by kind."""
        out: dict[str, list] = {}
        while (m := self.bus.recv(0.0)) is not None:
            f = CODEC.try_decode(m)
            if f is not None:
                out.setdefault(f.kind, []).append(f)
        return out


@pytest.fixture
def ctl():
    c = Controller()
    yield c
    c.close()


def test_the_command_timeout_latches_every_enabled_amplifier_and_says_so_at_once(ctl):
    for _ in range(10):
        ctl.send()
    assert ctl.node.amplifiers().enabled.all()
    assert ctl.frames()["PLANT_STATUS"][-1].raw["WatchdogTripped"] == 0
    ctl.clock.t += 0.199  # inside the timeout: not yet
    assert not ctl.node.check_command_timeout()
    ctl.clock.t += 0.011
    assert ctl.node.check_command_timeout()
    amps = ctl.node.amplifiers()
    assert not amps.enabled.any() and (amps.cause == WATCHDOG_COMMAND_TIMEOUT).all() and amps.command_timeout
    hb = ctl.frames()["HEARTBEAT_PLANT"][-1].raw  # sent at once, not at the next 100 ms
    assert (hb["AmpsEnabled"], hb["WatchdogTripped"], hb["OffCause"], hb["CommandTimeout"]) == (
        0, N, WATCHDOG_COMMAND_TIMEOUT, 1)
    assert ctl.node.counters.command_timeouts == 1 and ctl.node.counters.watchdog_trips == N
    assert ctl.node.last_silence_s == pytest.approx(0.21)
    assert "0/7 enabled; 7 latched off (command_timeout)" in amps.describe(SPEC.names)
    assert not ctl.node.check_command_timeout()  # once per silence


def test_after_a_command_timeout_the_amplifiers_stay_off_until_their_enable_rises(ctl):
    ctl.send()
    ctl.clock.t += 1.0
    ctl.node.check_command_timeout()
    for _ in range(5):  # the controller is back, enables still high: still latched
        ctl.send()
    assert not ctl.node.command_timed_out and not ctl.node.amplifiers().enabled.any()
    frames = ctl.frames()
    assert [f.raw["CurrentA"] for f in frames["TRUTH"][-N:]] == [0.0] * N  # what the node publishes
    assert frames["PLANT_STATUS"][-1].raw["WatchdogTripped"] == 1
    ctl.send(enable=False)
    ctl.send(enable=True)
    assert ctl.node.amplifiers().enabled.all()


def test_syncs_hold_the_command_timeout_off_and_a_heartbeat_alone_does_not(ctl):
    for _ in range(100):  # 0.8 s of ticks, each well inside the timeout
        ctl.send()
        assert not ctl.node.check_command_timeout()
    for counter in range(5):  # a hung loop whose heartbeat still runs
        ctl.clock.t += 0.1
        ctl.node.handle(CODEC.frame("HEARTBEAT_CONTROLLER", State=2, BootId=BOOT, Counter=counter))
    assert ctl.node.check_command_timeout()


def test_without_a_command_timeout_the_node_never_holds_the_amplifiers_off():
    c = Controller(command_timeout_s=None)
    try:
        c.send()
        c.clock.t += 60.0
        assert not c.node.check_command_timeout()
        assert c.node.amplifiers().enabled.all()
    finally:
        c.close()


def test_a_node_reset_clears_the_command_timeout_and_the_latches(ctl):
    ctl.send()
    ctl.clock.t += 1.0
    ctl.node.check_command_timeout()
    ctl.node.handle(CODEC.frame("CONTROL", Command=1, Seed=3, NJoints=N, BootId=8))
    amps = ctl.node.amplifiers()
    assert not amps.command_timeout and not amps.tripped.any()


def test_free_running_the_line_stopping_trips_the_watchdog_and_toggles_two_to_a_step_still_count():
    c = Controller(free_running=True)
    try:
        for _ in range(30):  # two ticks' SYNCs between two node steps: two toggles, one step
            c.send(step=False)
            c.send()
        assert c.node.amplifiers().enabled.all()  # an edge in every step: no trip
        for _ in range(5):  # the controller dies; the node steps on (its own clock)
            c.node.step(c.tick, PERIOD, DELAY)
            c.tick += 1
        assert c.node.amplifiers().enabled.all()  # 40 ms of plant time: inside the 50 ms
        for _ in range(3):
            c.node.step(c.tick, PERIOD, DELAY)
            c.tick += 1
        amps = c.node.amplifiers()
        assert not amps.enabled.any() and (amps.cause == WATCHDOG_EXPIRED).all()
        hb = c.frames()["HEARTBEAT_PLANT"][-1].raw
        assert (hb["AmpsEnabled"], hb["OffCause"], hb["CommandTimeout"]) == (0, WATCHDOG_EXPIRED, 0)
    finally:
        c.close()


def test_the_lockstep_node_feeds_the_plant_the_received_level():
    c = Controller()
    try:
        levels = []
        for k in range(6):
            c.send(toggle=k % 3 != 2)
            levels.append(bool(c.node.plant._prev_cmd.watchdog_line))
        assert levels == [True, False, False, True, False, False]
        assert np.array_equal(c.node.plant.amplifier_enabled(), np.ones(N, bool))
    finally:
        c.close()


@pytest.mark.parametrize(("period", "delay"), [(10.0, 0.0), (0.004, 0.0), (PERIOD, 2 * PERIOD), (PERIOD, -1e-3),
                                               (float("nan"), 0.0)])
def test_a_sync_asking_for_another_period_or_an_impossible_delay_is_refused_not_stepped(period, delay) -> None:
    """One frame asking for a 10 s period used to keep the node integrating for 20 s."""
    ctl = Controller(command_timeout_s=None)
    try:
        ctl.send()
        steps = ctl.node.counters.steps
        raw = CODEC.command_raw(ctl.cmd)
        ctl.node.handle(CODEC.sync_frame(raw, ctl.tick, period, delay, BOOT))
        assert ctl.node.counters.steps == steps and ctl.node.counters.bad_sync == 1
        ctl.send()  # a proper SYNC is served as before
        assert ctl.node.counters.steps == steps + 1
    finally:
        ctl.close()


def test_a_clean_end_disarms_the_command_timeout():
    # after every clean run the node still reported "7 latched off (command_timeout)": the timeout
    # fired 0.2 s after END
    c = Controller()
    try:
        for _ in range(5):
            c.send()
        c.node.handle(CODEC.frame("CONTROL", Command=2, Seed=0, NJoints=N, BootId=BOOT))  # END
        c.clock.t += 5.0
        assert not c.node.check_command_timeout()
        assert not c.node.amplifiers().tripped.any() and c.node.counters.command_timeouts == 0
    finally:
        c.close()


def test_the_automatic_command_timeout_follows_the_period_and_the_measured_lateness():
    c = Controller(command_timeout_s="auto")
    try:
        for _ in range(5):
            c.send()
        assert c.node.effective_command_timeout_s() == pytest.approx(25 * PERIOD)  # 0.2 s at 125 Hz
        c.clock.t += 0.15 - PERIOD  # one tick 0.15 s late (a loaded machine)...
        c.send()
        assert c.node.effective_command_timeout_s() == pytest.approx(3 * 0.15)  # ...widens it to 0.45 s
        c.clock.t += 0.3
        assert not c.node.check_command_timeout()  # 0.3 s of silence: within 0.45 s
        c.clock.t += 0.2
        assert c.node.check_command_timeout() and not c.node.amplifiers().enabled.any()
        c.clock.t += 100.0  # never beyond 1 s, however late a tick once came
        c.send()
        c.clock.t += 30.0 - PERIOD
        c.send()
        assert c.node.effective_command_timeout_s() == 1.0
    finally:
        c.close()
