"""Named faults of the emulators: a pulled board, the plant's sensor and amplifier faults, CAN frame
loss and delay, a dead plant node, a dead vision system."""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from emulators.adc import AdcBoard
from emulators.bit3 import Bit3Board
from emulators.can.bus import Endpoint, open_bus
from emulators.can.codec import CanCodec
from emulators.can.node import PLANT_IDS, PlantNode
from emulators.can.toy import ToyCommand, ToyPlant
from emulators.crate import Crate
from emulators.dac import DacBoard
from emulators.faults import UnknownFaultError
from emulators.pio import PioBoard
from emulators.plant import Plant, load_plant_params
from emulators.plant.plant import FAULT_INJECTED
from emulators.quadrature import QuadratureBoard
from emulators.vision import VisionSystem
from hal.vme import BusError, BusErrorCause, Width

T = 0.008


def test_a_removed_board_answers_nothing_until_it_is_back(crate: Crate) -> None:
    crate.write(0x1010, 0xBEEF, space="A16", width=Width.D16)
    board = crate.board("ram16")
    board.inject("removed")
    t0 = crate.clock.now_ns
    with pytest.raises(BusError) as e:
        crate.read(0x1010, space="A16", width=Width.D16)
    assert e.value.cause is BusErrorCause.NO_RESPONDER
    assert crate.clock.now_ns - t0 >= crate.bus_timeout_ns  # the bus timer ended the cycle
    board.clear_fault("removed")
    assert crate.read(0x1010, space="A16", width=Width.D16) == 0xBEEF


@pytest.mark.parametrize("board_type", [AdcBoard, DacBoard, PioBoard, QuadratureBoard, Bit3Board])
def test_every_board_type_can_be_removed_and_keeps_its_own_faults(board_type) -> None:
    faults = board_type.known_faults()
    assert "removed" in faults
    assert set(board_type.FAULTS) <= set(faults)


def _plant() -> Plant:
    return Plant(load_plant_params("jpl-arm"), seed=1)


def _drive(p: Plant, volts: float = 2.0):
    cmd = p.idle_command()
    cmd.amp_enable[:] = True
    cmd.amp_command_v[0] = volts
    return cmd


def test_a_frozen_pot_holds_the_wiper_where_it_was_while_the_joint_moves_on() -> None:
    p = _plant()
    cmd = _drive(p)
    for _ in range(5):
        p.step_period(cmd, T)
    held = float(p.pot.volts(p.joint_angle())[0])
    p.inject("pot_frozen", joint="j1")
    theta0 = p.joint_angle()[0]
    for _ in range(20):
        s = p.step_period(cmd, T)
        assert s.pot_v[0] == held  # noise-free: the wiper no longer slides on the element
    assert abs(p.joint_angle()[0] - theta0) > 0.01  # the joint did move
    assert s.pot_v[1] != p.pot.volts(p.joint_angle())[1]  # the other pots keep their noise


def test_open_wiper_and_stuck_tach_read_their_held_volts_and_heal_when_cleared() -> None:
    p = _plant()
    cmd = _drive(p)
    p.inject("pot_open", joint="j2")
    p.inject("tach_stuck", joint="j1", volts=-10.0)
    s = p.step_period(cmd, T)
    assert s.pot_v[1] == 10.0 and s.tach_v[0] == -10.0
    p.clear_fault()
    s = p.step_period(cmd, T)
    assert s.pot_v[1] != 10.0 and abs(s.tach_v[0]) < 1.0


def test_an_injected_amplifier_fault_survives_fault_resets_until_cleared() -> None:
    p = _plant()
    cmd = _drive(p)
    p.inject("amp_fault", joint="j1")
    s = p.step_period(cmd, T)
    assert s.amp_fault[0] and s.truth["amp_fault_cause"][0] & FAULT_INJECTED and not s.amp_fault[1]
    reset = cmd.copy()
    reset.fault_reset[0] = True
    p.step_period(reset, T)
    s = p.step_period(cmd, T)
    assert s.amp_fault[0] and abs(s.truth["current_a"][0]) < 0.05  # still tripped: no drive current
    p.clear_fault("amp_fault")
    p.step_period(reset, T)
    s = p.step_period(cmd, T)
    assert not s.amp_fault[0] and s.truth["current_a"][0] > 1.0


def test_plant_faults_need_a_joint_of_the_plant() -> None:
    p = _plant()
    with pytest.raises(ValueError, match="no joint named 'j9'"):
        p.inject("pot_frozen", joint="j9")
    with pytest.raises(ValueError, match="name the joint"):
        p.inject("tach_stuck")
    with pytest.raises(UnknownFaultError):
        p.inject("pot_melted", joint="j1")
    assert not p.active_faults


def _pair(chan: str) -> tuple[Endpoint, can.BusABC]:
    return Endpoint(open_bus("virtual", chan), {0x7FF}), open_bus("virtual", chan)


def _frames(n: int) -> list[can.Message]:
    return [can.Message(arbitration_id=0x100, data=k.to_bytes(2, "little"), is_extended_id=False)
            for k in range(n)]


def _received(ep: Endpoint, timeout: float = 0.05) -> list[int]:
    got = []
    while (m := ep.recv(timeout)) is not None:
        got.append(int.from_bytes(m.data, "little"))
    return got


def test_frame_loss_drops_the_seeded_share_of_received_frames() -> None:
    lost = []
    for _ in range(2):
        ep, peer = _pair("fault-loss")
        ep.inject("frame_loss", percent=25.0, direction="rx", seed=3)
        for m in _frames(400):
            peer.send(m)
        got = _received(ep)
        lost.append(sorted(set(range(400)) - set(got)))
        assert ep.lost == len(lost[-1])
        ep.close()
        peer.shutdown()
    assert lost[0] == lost[1]  # the same seed loses the same frames
    assert 60 <= len(lost[0]) <= 140


def test_frame_loss_on_send_never_reaches_the_bus() -> None:
    ep, peer = _pair("fault-loss-tx")
    ep.inject("frame_loss", percent=100.0, direction="tx")
    for m in _frames(5):
        ep.send(m)
    assert peer.recv(0.05) is None and ep.lost == 5
    ep.close()
    peer.shutdown()


def test_delayed_frames_arrive_late_and_are_overtaken_by_undelayed_ones() -> None:
    ep, peer = _pair("fault-delay")
    ep.inject("frame_delay", ms=30.0, percent=50.0, seed=1)
    t0 = time.monotonic()
    for m in _frames(20):
        peer.send(m)
    got = _received(ep, 0.1)
    assert sorted(got) == list(range(20))  # none lost
    assert got != sorted(got)  # the delayed ones come after frames sent later
    assert time.monotonic() - t0 >= 0.03
    ep.close()
    peer.shutdown()


def test_a_dead_plant_node_answers_nothing_and_sends_no_heartbeat() -> None:
    node_ep = Endpoint(open_bus("virtual", "fault-node"), PLANT_IDS)
    node = PlantNode(node_ep, lambda s: ToyPlant(2, seed=s), 2, command_type=ToyCommand)
    codec = CanCodec()
    node.handle(codec.frame("CONTROL", Command=1, NJoints=2, BootId=1))  # a session: the node obeys boot id 1
    sync = codec.frame("SYNC", Tick=0, PeriodS=T, DelayS=0.0, Seq=0, BootId=1)
    node.handle(sync)
    answered = node_ep.sent
    assert answered > 0  # alive: SYNC is answered
    node.inject("dead")
    node.handle(codec.frame("SYNC", Tick=1, PeriodS=T, DelayS=0.0, Seq=1, BootId=1))
    node.heartbeat(now=1e9)
    assert node_ep.sent == answered and node.counters.steps == 1
    node.close()


class _NoServer:
    def step(self, now: float):
        raise AssertionError("a dead vision system runs no protocol")


def test_a_dead_vision_system_does_nothing_when_stepped() -> None:
    vision = VisionSystem(_NoServer(), [1.0, 0.0, 0.3])  # type: ignore[arg-type]
    vision.inject("dead")
    vision.step(0.5)
    assert vision.stats.frames == 0
    np.testing.assert_array_equal(vision.target, [1.0, 0.0, 0.3])
