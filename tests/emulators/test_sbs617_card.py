"""The emulated SBS (Bit 3) Model 617, register by register, against docs/boards/sbs617.md.

Raw bus cycles (no driver) on a crate; every expected value is the doc's (its worked values,
its "Window cycles" order, its fault table). The last tests build the card from the crate-file
snippet the jpl-arm-vmic preset uses and run the vision-servo protocol over it against the
emulated vision computer.
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from emulators.bit3 import Bit3RemotePort
from emulators.crate import Crate
from emulators.crate_file import build_crate
from emulators.sbs617 import Sbs617Card
from emulators.vision import VisionParams, VisionSystem
from emulators.vision_protocol import EndReason as VisionEndReason
from emulators.vision_protocol import VisionServer, VisionState
from hal.bit3 import Sbs617Driver
from hal.bit3.protocol import EndReason, RobotState, VisionServoClient, format_layout
from hal.board_types import BOARD_TYPES
from hal.config import ConfigTable
from hal.kinematics import ArmModel
from hal.vme import BusError, BusErrorCause, Width

NODE, MAPS, WIN = 0x80000000, 0x80010000, 0x82000000
LOC_CMD1, LOC_INT_CTRL, LOC_STATUS, REMOTE = NODE + 0, NODE + 1, NODE + 2, NODE + 8
ENTRY0 = 0x00400E60  # the doc's worked entry: remote A24 0x400000, AM 0x39, remote RAM


def _crate() -> tuple[Crate, Sbs617Card, Bit3RemotePort]:
    crate = Crate("robot")
    card = Sbs617Card("link", map_base=MAPS, window_base=WIN, remote_base=0x400000)
    crate.install(card, base=NODE, space="A32")
    return crate, card, Bit3RemotePort(card.link)


def _rb(crate: Crate, address: int, width: Width = Width.D8) -> int:
    return crate.read(address, space="A32", width=width)


def _wb(crate: Crate, address: int, value: int, width: Width = Width.D8) -> None:
    crate.write(address, value, space="A32", width=width)


def _mapped() -> tuple[Crate, Sbs617Card, Bit3RemotePort]:
    crate, card, port = _crate()
    _wb(crate, MAPS, ENTRY0, Width.D32)
    return crate, card, port


# --- power-up and the local registers ------------------------------------------------------
def test_power_up_values() -> None:
    crate, _card, _port = _crate()
    assert [_rb(crate, NODE + o) for o in (0, 1, 2, 3)] == [0x00, 0x00, 0x00, 0x00]
    assert _rb(crate, REMOTE) == 0x90  # WAS_RESET and NOT_LOCKED (doc, Open points 5)
    assert _rb(crate, REMOTE) == 0x10  # the read cleared WAS_RESET
    assert _rb(crate, MAPS, Width.D32) == 0x00000001 and _rb(crate, MAPS + 0x7FFC, Width.D32) == 0x00000001


def test_no_connect_is_live_and_not_cleared_by_clr_error() -> None:
    crate, _card, port = _crate()
    port.power_off()
    assert _rb(crate, LOC_STATUS) == 0x01
    _wb(crate, LOC_CMD1, 0x80)
    assert _rb(crate, LOC_STATUS) == 0x01
    port.power_on()
    assert _rb(crate, LOC_STATUS) == 0x00


def test_loc_cmd1_one_shots_read_zero_and_snd_pt_reads_back() -> None:
    crate, _card, _port = _crate()
    _wb(crate, LOC_CMD1, 0xE0)
    assert _rb(crate, LOC_CMD1) == 0x20


def test_loc_int_ctrl_stores_6_5_and_2_0_and_bits_4_3_read_zero() -> None:
    crate, _card, _port = _crate()
    _wb(crate, LOC_INT_CTRL, 0xFF)
    assert _rb(crate, LOC_INT_CTRL) == 0x67


# --- bad accesses ----------------------------------------------------------------------------
@pytest.mark.parametrize(("address", "width", "write", "cause"), [
    (LOC_STATUS, Width.D16, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (NODE, Width.D32, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (LOC_STATUS, Width.D8, True, BusErrorCause.ACCESS),
    (NODE + 0x03, Width.D8, True, BusErrorCause.ACCESS),
    (NODE + 0x1F, Width.D8, True, BusErrorCause.ACCESS),
    (NODE + 0x05, Width.D8, False, BusErrorCause.NO_RESPONDER),
    (NODE + 0x17, Width.D8, False, BusErrorCause.NO_RESPONDER),
    (NODE + 0x19, Width.D8, False, BusErrorCause.NO_RESPONDER),
    (NODE + 0x1E, Width.D8, False, BusErrorCause.NO_RESPONDER),
    (MAPS, Width.D16, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (MAPS + 1, Width.D8, True, BusErrorCause.UNSUPPORTED_WIDTH),
])
def test_bad_accesses_end_in_berr(address: int, width: Width, write: bool, cause: BusErrorCause) -> None:
    crate, _card, _port = _crate()
    with pytest.raises(BusError) as e:
        if write:
            _wb(crate, address, 0, width)
        else:
            _rb(crate, address, width)
    assert e.value.cause is cause


# --- window cycles, in the doc's order ------------------------------------------------------
def test_window_worked_example() -> None:
    crate, card, _port = _mapped()
    card.link.mem[0x10:0x14] = bytes([0x11, 0x22, 0x33, 0x44])
    assert _rb(crate, WIN + 0x10, Width.D32) == 0x11223344
    assert _rb(crate, WIN + 0x12, Width.D16) == 0x3344
    assert _rb(crate, WIN + 0x13, Width.D8) == 0x44
    _wb(crate, WIN + 0x20, 0xCAFE, Width.D16)
    assert bytes(card.link.mem[0x20:0x22]) == bytes([0xCA, 0xFE])
    assert _rb(crate, LOC_STATUS) == 0x00


def test_an_invalid_entry_latches_rembus_and_reads_all_ones() -> None:
    crate, _card, _port = _crate()  # every entry invalid at power-up
    assert _rb(crate, WIN, Width.D16) == 0xFFFF
    assert _rb(crate, LOC_STATUS) == 0x40


def test_remote_power_off_times_out_after_32_us_and_reads_0x05() -> None:
    crate, card, port = _mapped()
    card.link.mem[0:4] = bytes([1, 2, 3, 4])
    port.power_off()
    t0 = crate.clock.now_ns
    assert _rb(crate, WIN, Width.D32) == 0xFFFFFFFF
    assert crate.clock.now_ns - t0 >= 32_000
    _wb(crate, WIN, 0, Width.D32)
    assert bytes(card.link.mem[0:4]) == bytes([1, 2, 3, 4])  # the write was lost
    assert _rb(crate, LOC_STATUS) == 0x05
    port.power_on()
    _wb(crate, LOC_CMD1, 0x80)
    assert _rb(crate, LOC_STATUS) == 0x00
    assert _rb(crate, WIN, Width.D32) == 0x01020304


def test_a_latched_error_does_not_stop_later_cycles() -> None:
    crate, card, _port = _mapped()
    card.link.mem[8] = 0x5A
    card.inject("remote_berr", start=0, end=4)
    assert _rb(crate, WIN, Width.D8) == 0xFF
    assert _rb(crate, WIN + 8, Width.D8) == 0x5A
    assert _rb(crate, LOC_STATUS) == 0x40


def test_link_down_fault_sets_no_connect_and_times_out() -> None:
    crate, _card, _port = _mapped()
    _card.inject("link_down")
    assert _rb(crate, WIN, Width.D32) == 0xFFFFFFFF
    assert _rb(crate, LOC_STATUS) == 0x05


def test_remote_timeout_fault_times_out_with_the_link_up() -> None:
    crate, card, _port = _mapped()
    card.inject("remote_timeout", start=0x100, end=0x200)
    assert _rb(crate, WIN + 0x80, Width.D8) == 0x00
    t0 = crate.clock.now_ns
    assert _rb(crate, WIN + 0x100, Width.D8) == 0xFF
    assert crate.clock.now_ns - t0 >= 32_000
    assert _rb(crate, LOC_STATUS) == 0x04


def test_parity_fault_counts_down() -> None:
    crate, _card, _port = _mapped()
    _card.inject("parity", count=2)
    assert [_rb(crate, WIN, Width.D8) for _ in range(3)] == [0xFF, 0xFF, 0x00]
    assert _rb(crate, LOC_STATUS) == 0x80
    assert _card.fault("parity") is None


def test_wrong_function_am_or_address_is_a_remote_bus_error() -> None:
    for entry in (0x00400E70,  # function 3: the remote card's dual-port RAM (not fitted)
                  0x00400E40,  # function 0: none
                  0x00400260,  # AM 0x09: A32, the memory is A24
                  0x00500E60):  # 0x500000: beyond the 4 KiB memory at 0x400000
        crate, _card, _port = _crate()
        _wb(crate, MAPS, entry, Width.D32)
        assert _rb(crate, WIN, Width.D8) == 0xFF, hex(entry)
        assert _rb(crate, LOC_STATUS) == 0x40, hex(entry)


def test_function_1_remote_bus_io_reaches_the_remote_memory_as_vmedrv_maps_it() -> None:
    crate, card, _port = _crate()
    _wb(crate, MAPS, 0x00400E50, Width.D32)  # vmedrv_config_table: A24 data AM, fcREMOTE_BUS_IO
    card.link.mem[4:6] = bytes([0xBE, 0xEF])
    assert _rb(crate, WIN + 4, Width.D16) == 0xBEEF
    assert _rb(crate, LOC_STATUS) == 0x00


def test_second_page_goes_through_entry_one() -> None:
    crate, card, _port = _crate()
    link = card.link
    _wb(crate, MAPS + 4, ENTRY0, Width.D32)  # page 1 of the window -> remote 0x400000
    link.mem[0x34] = 0x77
    assert _rb(crate, WIN + 0x1034, Width.D8) == 0x77


# --- remote registers and programmed interrupts ---------------------------------------------
def test_remote_register_with_the_link_down_times_out() -> None:
    crate, _card, port = _crate()
    port.power_off()
    assert _rb(crate, REMOTE) == 0xFF
    assert _rb(crate, LOC_STATUS) == 0x05


def test_snd_pr_rings_the_remote_side() -> None:
    crate, _card, port = _crate()
    got: list[int] = []
    port.on_doorbell(got.append)
    _wb(crate, REMOTE, 0x20)
    assert got == [0] and port.poll_doorbells()[0] == 0
    assert _rb(crate, LOC_STATUS) == 0x00


def test_remote_interrupt_sets_pr_and_pt_and_either_clear_removes_it() -> None:
    for clear_at, value in ((LOC_CMD1, 0x40), (REMOTE, 0x40)):  # NetBSD's and vmedrv's handlers
        crate, _card, port = _crate()
        _rb(crate, REMOTE)  # take WAS_RESET away
        port.ring(7)
        assert _rb(crate, LOC_STATUS) == 0x20
        assert _rb(crate, REMOTE) == 0x12  # NOT_LOCKED | PT_SET
        _wb(crate, clear_at, value)
        assert _rb(crate, LOC_STATUS) == 0x00


def test_interrupt_asserts_only_with_int_en_and_releases_on_clear() -> None:
    crate, card, port = _crate()
    seen: list[tuple[int, int]] = []

    def handler(vector: int) -> None:  # as a driver's: look, then clear the source (level-sensitive)
        seen.append((vector, _rb(crate, LOC_INT_CTRL)))
        _wb(crate, LOC_CMD1, 0x40)

    crate.register_irq_handler(0xB3, handler)
    port.ring()
    assert not card.irq_pending and _rb(crate, LOC_INT_CTRL) == 0x00 and seen == []
    _wb(crate, LOC_INT_CTRL, 0x40)  # a pending interrupt asserts as soon as it is enabled
    assert seen == [(0xB3, 0xC0)]  # vector from the crate file; INT_ACT read 1 in the handler
    assert not card.irq_pending and _rb(crate, LOC_INT_CTRL) == 0x40 and _rb(crate, LOC_STATUS) == 0x00


def test_error_interrupt_with_err_int_en() -> None:
    crate, card, _port = _crate()
    _wb(crate, LOC_INT_CTRL, 0x20)
    _rb(crate, WIN, Width.D8)  # invalid entry: REMBUS latched
    assert card.irq_pending
    _wb(crate, LOC_CMD1, 0x80)
    assert not card.irq_pending


def test_a_remote_interrupt_while_the_cable_is_out_is_lost() -> None:
    crate, card, port = _crate()
    card.inject("link_down")
    port.ring()
    card.clear_fault("link_down")
    assert _rb(crate, LOC_STATUS) == 0x00


# --- the crate file, the board table, the protocol ------------------------------------------
PRESET_SNIPPET = """
[[crate.board]]
type = "sbs617"
name = "vision-link"
space = "A32"
base = 0x80000000
map_base = 0x80010000
window_base = 0x82000000
remote_space = "A24"
remote_base = 0x400000
mem_size = 0x1000
irq_level = 3
irq_vector = 0xB3
"""


def _from_snippet() -> tuple[Crate, Sbs617Card, Sbs617Driver]:
    crate = build_crate(ConfigTable(tomllib.loads(PRESET_SNIPPET), "snippet"))
    card = crate.board("vision-link")
    assert isinstance(card, Sbs617Card)
    drv = BOARD_TYPES["sbs617"].load_driver()(crate, 0x80000000, 0x80010000, 0x82000000, remote_base=0x400000,
                                              remote_space="A24", mem_size=0x1000, irq_level=3, irq_vector=0xB3)
    return crate, card, drv


def test_the_preset_snippet_builds_the_card_and_the_table_probe_reads_it() -> None:
    crate, card, _drv = _from_snippet()
    assert {card.map_ram.base, card.window.base, card.map_ram.space.name} == {0x80010000, 0x82000000, "A32"}
    probe = BOARD_TYPES["sbs617"].load_probe()
    assert probe is not None
    reading = probe(crate, 0x80000000, card.space)
    assert reading.ok and "remote connected" in reading.detail
    Bit3RemotePort(card.link).power_off()
    assert "remote crate off" in probe(crate, 0x80000000, card.space).detail
    nothing = probe(crate, 0xC000, card.space)  # nothing there (as on a VME bus: the BARs are PCI's)
    assert not nothing.ok and "PCI card" in nothing.detail


def test_vision_servo_protocol_over_the_617_converges() -> None:
    crate, card, drv = _from_snippet()
    arm = ArmModel()
    remote = Bit3RemotePort(card.link)
    drv.setup()
    format_layout(drv.memory())
    robot = VisionServoClient(drv.memory(), ring=drv.ring_doorbell)
    drv.on_doorbell(robot.notify)
    server = VisionServer(remote.memory, ring=remote.ring)
    remote.on_doorbell(server.notify)
    theta = np.array([0.2, 0.5, -1.0, 0.0, 0.0, 0.0])
    target = arm.position(theta) + np.array([0.05, -0.04, 0.03])
    vision = VisionSystem(server, target, arm, VisionParams(rate_hz=50.0, latency_s=0.0, gain=0.5,
                                                            max_step_m=0.01, tolerance_m=0.002))
    robot.publish_joints(theta, 0.0)
    robot.request(crate.now())
    for k in range(1, 500):
        crate.advance_to(k * 8_000_000)
        t = crate.now()
        vision.step(t)
        cmd = robot.step(t)
        if cmd is not None:
            theta += arm.ee_delta_to_joint_delta(theta, cmd.dp)
        robot.publish_joints(theta, t)
        if robot.state is RobotState.IDLE and server.state is VisionState.IDLE:
            break
    assert server.end_reason is VisionEndReason.TARGET_REACHED
    assert robot.end_reason is EndReason.PEER_ENDED
    assert float(np.linalg.norm(arm.position(theta) - target)) < 0.004
    assert robot.doorbells > 0 and server.doorbells > 0


def test_remote_power_off_ends_the_task_with_link_error() -> None:
    crate, card, drv = _from_snippet()
    remote = Bit3RemotePort(card.link)
    drv.setup()
    format_layout(drv.memory())
    robot = VisionServoClient(drv.memory(), ring=drv.ring_doorbell)
    robot.request(crate.now())
    remote.power_off()
    robot.step(crate.now())
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.LINK_ERROR
    assert robot.link_errors >= 1
