"""The plant node's sessions: once it acknowledged a controller's RESET, CONTROL, SYNC and CMD
frames of other controllers (boot ids) are refused and counted, never obeyed; another
controller's RESET is accepted when the session is over (END, or its owner silent for the
node's controller timeout).

The node is driven frame by frame (``handle``) with a fake clock: no thread, no race with the
wall clock. A second bus on the same ``virtual`` channel reads what the node sends.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from emulators.can.bus import Endpoint, open_bus
from emulators.can.codec import CanCodec
from emulators.can.dbc import CONTROL_END, CONTROL_RESET
from emulators.can.node import PLANT_IDS, PlantNode
from emulators.can.toy import ToyCommand, ToyPlant

N = 3
PERIOD, DELAY = 0.008, 0.001
CODEC = CanCodec()
A, B = 0x1207, 0x3409  # two controllers' boot ids (different low bytes)
_chan = itertools.count()


class Clock:
    def __init__(self) -> None:
        self.t = 50.0

    def __call__(self) -> float:
        return self.t


class Bench:
    """A lockstep node with a fake clock, and the frames it sends."""

    def __init__(self, *, free_running: bool = False) -> None:
        chan = f"node-session-{next(_chan)}"
        self.clock = Clock()
        self.node = PlantNode(Endpoint(open_bus("virtual", chan), PLANT_IDS), lambda s: ToyPlant(N, seed=s), N,
                              free_running=free_running, command_type=ToyCommand, period_s=PERIOD,
                              delay_s=DELAY, clock=self.clock)
        self.bus = open_bus("virtual", chan)
        self.tick = {A: 0, B: 0}

    def close(self) -> None:
        self.node.close()
        self.bus.shutdown()

    def reset(self, boot: int, seed: int = 5) -> None:
        self.node.handle(CODEC.frame("CONTROL", Command=CONTROL_RESET, Seed=seed, NJoints=N, BootId=boot))

    def end(self, boot: int) -> None:
        self.node.handle(CODEC.frame("CONTROL", Command=CONTROL_END, NJoints=N, BootId=boot))

    def send_tick(self, boot: int, *, volts: float = 0.3, enable: bool = True) -> None:
        """CMD frames and SYNC of ``boot``'s next tick, one period after the last."""
        self.clock.t += PERIOD
        raw = {"AmpCommand": np.full(N, round(volts / 2e-6)), "PwmDuty": np.zeros(N, np.int64),
               "AmpEnable": np.full(N, int(enable)), "FaultReset": np.zeros(N, np.int64),
               "PwmDirection": np.ones(N, np.int64), "Brake": np.zeros(N, np.int64),
               "Watchdog": np.asarray(self.tick[boot] % 2)}
        for m in CODEC.command_frames(raw, self.tick[boot], boot):
            self.node.handle(m)
        self.node.handle(CODEC.sync_frame(raw, self.tick[boot], PERIOD, DELAY, boot))
        self.tick[boot] += 1

    def frames(self) -> dict[str, list]:
        out: dict[str, list] = {}
        while (m := self.bus.recv(0.0)) is not None:
            f = CODEC.try_decode(m)
            if f is not None:
                out.setdefault(f.kind, []).append(f)
        return out

    def acks(self, frames: dict[str, list]) -> list[tuple[int, int]]:
        """(acknowledged boot id, session number) of every ResetAck sent."""
        return [(int(f.raw["Tick"]), int(f.raw["Session"])) for f in frames.get("PLANT_STATUS", [])
                if f.raw["ResetAck"]]


@pytest.fixture
def bench():
    b = Bench()
    yield b
    b.close()


def test_the_acknowledgement_names_the_controller_and_its_session(bench):
    bench.reset(A)
    f = bench.frames()
    assert bench.acks(f) == [(A, 1)]
    session = f["PLANT_SESSION"][-1].raw
    assert (session["Owner"], session["Session"], session["Active"], session["Open"]) == (A, 1, 1, 0)
    bench.send_tick(A)
    answers = [s for s in bench.frames()["PLANT_STATUS"] if not s.raw["ResetAck"]]
    assert [int(s.raw["Session"]) for s in answers] == [1]


def test_a_second_controller_cannot_take_over_a_running_session(bench):
    bench.reset(A, seed=5)
    for _ in range(5):
        bench.send_tick(A, volts=0.3)
    steps, plant = bench.node.counters.steps, bench.node.plant
    cmd_before = {k: v.copy() for k, v in bench.node.cmd_raw.items()}
    bench.frames()
    bench.reset(B, seed=99)  # refused: A is alive
    f = bench.frames()
    assert bench.acks(f) == []
    assert bench.node.plant is plant and bench.node.seed == 5
    s = f["PLANT_SESSION"][-1].raw  # sent at once, so B learns why
    assert (s["Owner"], s["Active"], s["RefusedBoot"], s["Refused"]) == (A, 1, B, 1)
    bench.send_tick(B, volts=-5.0, enable=False)  # B's CMD and SYNC: neither taken nor stepped
    assert bench.node.counters.steps == steps
    assert all(np.array_equal(bench.node.cmd_raw[k], v) for k, v in cmd_before.items())
    bench.end(B)  # nor may B end A's session
    assert bench.node.session_owner == A
    assert bench.node.counters.refused == 1 + N + 1 + 1 and bench.node.counters.refused_resets == 1
    bench.send_tick(A)  # A goes on undisturbed
    assert bench.node.counters.steps == steps + 1 and bench.node.counters.missing_cmd == 0


def test_another_controllers_sync_does_not_hold_the_command_timeout_off():
    b = Bench()
    b.node.command_timeout_s = 0.2
    try:
        b.reset(A)
        b.send_tick(A)
        for _ in range(40):  # 0.32 s of B's ticks, A silent
            b.send_tick(B)
        assert b.node.command_timed_out or b.node.check_command_timeout()
    finally:
        b.close()


def test_a_restarted_controller_reconnects_once_the_old_one_is_silent(bench):
    bench.reset(A)
    bench.send_tick(A)
    bench.frames()
    bench.clock.t += 0.4  # A silent for 0.4 s: inside the node's 0.5 s controller timeout
    bench.reset(B, seed=8)
    assert bench.acks(bench.frames()) == [] and bench.node.session_owner == A
    bench.clock.t += 0.2  # 0.6 s: A's session is over
    assert bench.node.session_open()
    bench.reset(B, seed=8)
    assert bench.acks(bench.frames()) == [(B, 2)]
    assert bench.node.session_owner == B and bench.node.seed == 8
    steps = bench.node.counters.steps
    bench.send_tick(A)  # A, back from the dead, is now the stranger
    assert bench.node.counters.steps == steps
    bench.send_tick(B)
    assert bench.node.counters.steps == steps + 1


def test_a_heartbeat_keeps_the_session_alive(bench):
    bench.reset(A)
    for counter in range(10):  # 1 s of heartbeats only (a run between moves)
        bench.clock.t += 0.1
        bench.node.handle(CODEC.frame("HEARTBEAT_CONTROLLER", State=2, BootId=A, Counter=counter))
    bench.reset(B)
    assert bench.node.session_owner == A


def test_end_frees_the_node_at_once_and_idles_the_amplifiers(bench):
    bench.reset(A)
    bench.send_tick(A, enable=True)
    assert bench.node.cmd_raw["AmpEnable"].all()
    bench.end(A)
    assert bench.node.session_owner is None and not bench.node.cmd_raw["AmpEnable"].any()
    assert bench.node.cmd_raw["AmpCommand"].tolist() == [0] * N
    bench.frames()
    bench.reset(B)
    assert bench.acks(bench.frames()) == [(B, 2)]


def test_a_resent_reset_is_acknowledged_again_without_rebuilding_the_plant(bench):
    bench.reset(A, seed=5)
    plant = bench.node.plant
    bench.reset(A, seed=5)  # the link resent it before it saw the acknowledgement
    assert bench.acks(bench.frames()) == [(A, 1), (A, 1)]
    assert bench.node.plant is plant and bench.node.counters.duplicate_resets == 1
    bench.send_tick(A)
    bench.reset(A, seed=5)  # after commands: a real reset of the same controller
    assert bench.node.plant is not plant and bench.acks(bench.frames()) == [(A, 2)]


def test_without_a_session_nothing_but_a_reset_is_obeyed(bench):
    bench.send_tick(A)
    bench.node.handle(CODEC.frame("CONTROL", Command=0, NJoints=N, BootId=A))
    assert bench.node.counters.steps == 0 and bench.node.counters.refused == N + 2
    assert not bench.node.cmd_raw["AmpEnable"].any()


def test_session_numbers_run_1_to_15_and_wrap(bench):
    numbers = []
    for k in range(17):
        bench.reset(A + k)
        numbers += [s for _, s in bench.acks(bench.frames())]
        bench.end(A + k)
    assert numbers == [*range(1, 16), 1, 2]
