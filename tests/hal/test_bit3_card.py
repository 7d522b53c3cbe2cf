"""BIT3 card emulation and driver: registers, window, BusError on link down, doorbells."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from emulators.bit3 import Bit3Board, Bit3Link, Bit3RemotePort
from emulators.crate import Crate
from emulators.crate_file import build_crate
from hal.bit3 import BIT3_CSR, CARD_ID, Bit3Driver, LinkDownError, RemoteBusError
from hal.config import ConfigTable
from hal.vme import BusError, BusErrorCause, Width
from tests.support import REPO
from tests.support.board_spec import doc_registers, map_differences

CSR, WIN = 0xC000, 0x400000


def _rig(space: str = "A24", size: int = 0x1000, powered: bool = True):
    link = Bit3Link(size)
    link.remote_power = powered
    crate = Crate("local")
    card = Bit3Board("bit3", link, window_base=WIN if space == "A24" else 0x90000000, window_space=space)
    crate.install(card, base=CSR, space="A16")
    drv = Bit3Driver(crate, CSR, card.window_base, window_space=space, window_size=size)
    return crate, card, drv, Bit3RemotePort(link)


def test_card_decodes_csr_in_a16_and_window_in_a24() -> None:
    crate, _card, drv, _ = _rig()
    assert drv.probe() == CARD_ID
    names = {row["name"]: row for row in crate.describe()}
    assert names["bit3"]["space"] == "A16"
    assert names["bit3.window"]["space"] == "A24" and names["bit3.window"]["base"] == "0x400000"
    st0 = drv.status()
    assert st0.link_up and st0.remote_power and not st0.error_latched


@pytest.mark.parametrize("space", ["A24", "A32"])
def test_window_maps_remote_memory_big_endian(space: str) -> None:
    _, _, drv, remote = _rig(space)
    drv.write(0x10, 0x11223344, Width.D32)
    assert remote.memory.read(0x10, 4) == b"\x11\x22\x33\x44"
    remote.memory.write(0x20, b"\xca\xfe\xba\xbe")
    assert drv.read(0x20, Width.D16) == 0xCAFE
    assert drv.read(0x22, Width.D16) == 0xBABE
    assert drv.read(0x23, Width.D8) == 0xBE


@given(offset=st.integers(0, 0x200), data=st.binary(min_size=0, max_size=64))
def test_byte_transfers_round_trip_at_any_alignment(offset: int, data: bytes) -> None:
    _, _, drv, remote = _rig()
    drv.write_bytes(offset, data)
    assert remote.memory.read(offset, len(data)) == data
    assert drv.read_bytes(offset, len(data)) == data


def test_block_transfers_use_block_cycles() -> None:
    crate, _, drv, remote = _rig()
    drv.write_block(0x100, [1, 2, 3, 0xFFFFFFFF])
    assert drv.read_block(0x100, 4) == [1, 2, 3, 0xFFFFFFFF]
    assert remote.memory.read(0x10C, 4) == b"\xff\xff\xff\xff"
    assert crate.counter_snapshot()["write.A24.D32"] == 4


def test_remote_power_off_ends_window_cycles_in_link_down_and_latches_timeout() -> None:
    crate, _card, drv, remote = _rig()
    remote.power_off()
    st0 = drv.status()
    assert not st0.link_up and not st0.remote_power
    with pytest.raises(BusError) as ei:
        crate.read(WIN, space="A24", width=Width.D16)
    assert ei.value.cause is BusErrorCause.LINK_DOWN
    assert drv.status().timeout and drv.status().errors == 1
    with pytest.raises(LinkDownError, match="remote crate power is off"):
        drv.read(0)
    remote.power_on()
    # The error stays latched: the card refuses remote cycles until the link is reset.
    with pytest.raises(LinkDownError, match="latched"):
        drv.write(0, 5)
    st1 = drv.reset_link()
    assert st1.usable and st1.errors == 0
    drv.write(0, 5)
    assert drv.read(0) == 5


def test_unplugged_cable_is_link_down_even_with_remote_power() -> None:
    _, card, drv, _ = _rig()
    card.inject("link_down")
    st0 = drv.status()
    assert st0.remote_power and not st0.link_up
    with pytest.raises(LinkDownError, match="cable disconnected") as ei:
        drv.read_bytes(0, 8)
    assert ei.value.bus_error is not None and ei.value.bus_error.cause is BusErrorCause.LINK_DOWN
    card.clear_fault("link_down")
    assert drv.reset_link().usable


def test_remote_bus_error_and_parity_raise_remote_cause() -> None:
    _crate, card, drv, _ = _rig()
    card.inject("remote_berr", start=0x80, end=0x100)
    drv.write(0x40, 1)  # outside the failing range
    with pytest.raises(RemoteBusError) as ei:
        drv.read(0x80)
    assert ei.value.bus_error.cause is BusErrorCause.REMOTE
    assert drv.status().remote_berr
    card.clear_fault("remote_berr")
    drv.reset_link()
    card.inject("parity", count=1)
    with pytest.raises(RemoteBusError, match="parity"):
        drv.read(0)
    assert drv.status().parity
    assert drv.reset_link().usable
    assert drv.read(0x40) == 1


def test_status_sticky_bits_are_write_one_to_clear_and_live_bits_read_only() -> None:
    _crate, _card, drv, remote = _rig()
    remote.power_off()
    with pytest.raises(LinkDownError):
        drv.read(0)
    remote.power_on()
    timeout = BIT3_CSR["STATUS"].field("timeout").mask
    drv.csr.write("STATUS", 0xFFFF & ~timeout)  # every bit but timeout: live bits ignore writes
    assert drv.status().timeout and drv.status().link_up
    drv.csr.write("STATUS", timeout)
    assert drv.status().usable


def test_csr_register_access_rules() -> None:
    crate, _, _drv, _ = _rig()
    with pytest.raises(BusError) as ei:
        crate.read(CSR + BIT3_CSR["DOORBELL_OUT"].offset, space="A16", width=Width.D16)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        crate.write(CSR + BIT3_CSR["ID"].offset, 1, space="A16", width=Width.D16)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        crate.read(CSR, space="A16", width=Width.D32)
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH


def test_window_disabled_does_not_answer() -> None:
    _crate, _, drv, _ = _rig()
    drv.csr.write("COMMAND", 0)
    with pytest.raises(LinkDownError):
        drv.read(0)
    drv.reset_link()
    assert drv.read(0) == 0


def test_local_doorbell_reaches_the_remote_side_with_its_code() -> None:
    _, _, drv, remote = _rig()
    got: list[int] = []
    remote.on_doorbell(got.append)
    drv.ring_doorbell(0x1234)
    drv.ring_doorbell(7)
    assert got == [0x1234, 7]
    assert remote.poll_doorbells() == (0, 7)  # already delivered by callback


def test_doorbell_to_a_dead_remote_is_a_link_error() -> None:
    crate, _, drv, remote = _rig()
    remote.power_off()
    with pytest.raises(LinkDownError):
        drv.ring_doorbell(1)
    assert crate.read(CSR, space="A16", width=Width.D16) == 0x0004  # timeout latched
    assert crate.read(CSR + 0x0C, space="A16", width=Width.D16) == 1  # and counted in ERRORS


def test_remote_doorbell_raises_the_local_irq_with_the_programmed_vector() -> None:
    crate, card, drv, remote = _rig()
    drv.irq_level, drv.irq_vector = 5, 0xA7
    got: list[int] = []
    drv.on_doorbell(got.append)
    remote.ring(0x0042)
    crate.delay(1e-6)
    assert got == [0x42]
    assert crate.counter_snapshot()["iack.IRQ5"] == 1
    assert not card.irq_pending and not drv.status().doorbell
    remote.ring(0x0043)
    remote.ring(0x0044)  # coalesces with the previous one before the CPU takes the IRQ
    crate.delay(1e-6)
    assert got == [0x42, 0x44]
    assert drv.csr.read("DOORBELL_COUNT") == 3


def test_remote_doorbell_polled_when_irq_disabled() -> None:
    _crate, card, drv, remote = _rig()
    remote.ring(9)
    assert not card.irq_pending
    assert drv.read_doorbell() == 9
    assert drv.read_doorbell() is None


def test_cross_process_style_polling_picks_up_doorbells_on_the_clock() -> None:
    # A card attached to a link whose remote side is elsewhere sees doorbells only by polling.
    link = Bit3Link(0x100)
    link.remote_power = True
    crate = Crate()
    card = Bit3Board("b", Bit3Link(buffer=link._buf, init=False), window_base=WIN, poll_period_s=50e-6)
    crate.install(card, base=CSR, space="A16")
    drv = Bit3Driver(crate, CSR, WIN, window_size=0x100)
    got: list[int] = []
    drv.on_doorbell(got.append)
    link.ring_local(0x77)  # rung through another Bit3Link object: no callback to this card
    assert got == []
    crate.delay(100e-6)
    assert got == [0x77]


def test_shared_memory_link_is_seen_by_an_attached_view_and_unlinked_by_its_creator() -> None:
    link = Bit3Link.create_shared(0x100)
    name = link.shm_name
    try:
        other = Bit3Link.attach_shared(name)
        other.remote_power = True
        other.mem[0:4] = b"ABCD"
        assert link.remote_power and bytes(link.mem[0:4]) == b"ABCD"
        other.close()
    finally:
        link.close()
    from multiprocessing import shared_memory

    with pytest.raises(FileNotFoundError):
        shared_memory.SharedMemory(name=name)


def test_crate_file_builds_a_bit3_card_with_its_window() -> None:
    cfg = ConfigTable({"crate": {"name": "c", "board": [
        {"type": "bit3", "name": "vis", "space": "A16", "base": 0xC000,
         "window_space": "A32", "window_base": 0x90000000, "window_size": 0x2000},
    ]}}, "<test>")
    crate = build_crate(cfg)
    drv = Bit3Driver(crate, 0xC000, 0x90000000, window_space="A32", window_size=0x2000)
    drv.probe()
    drv.write(0x1FFC, 0xDEADBEEF)
    assert drv.read(0x1FFC) == 0xDEADBEEF
    with pytest.raises(ValueError):
        drv.read(0x2000)


# --- the doc is the spec: each map against it, never against each other ------------------------
def test_driver_register_map_matches_the_card_doc() -> None:
    assert map_differences(BIT3_CSR, doc_registers("bit3"), who="hal.bit3.regs") == []


def test_emulator_register_map_matches_the_card_doc() -> None:
    assert map_differences(Bit3Board.REGMAP, doc_registers("bit3"), who="emulators.bit3") == []


def test_emulator_declares_its_own_register_map() -> None:
    assert Bit3Board.REGMAP is not BIT3_CSR


def test_card_doc_states_the_id_and_the_command_reset_value() -> None:
    doc = doc_registers("bit3")
    assert (doc["ID"].offset, doc["ID"].reset) == (0x0E, 0x0413)
    assert doc["COMMAND"].reset == 0x0002 and doc["COMMAND"].fields == {"window_enable": (1, 1), "reset": (0, 1)}
    assert "Generated by" not in (REPO / "docs" / "boards" / "bit3.md").read_text()


# --- literal values from docs/boards/bit3.md ---------------------------------------------------
def test_status_reads_the_live_bits_after_reset() -> None:
    crate, _card, _drv, remote = _rig()
    assert crate.read(CSR, space="A16", width=Width.D16) == 0x0003  # link up, remote powered
    remote.power_off()
    assert crate.read(CSR, space="A16", width=Width.D16) == 0x0000


def test_status_after_a_timeout_with_the_cable_pulled_reads_0x0006() -> None:
    crate, card, _drv, _ = _rig()
    card.inject("link_down")
    with pytest.raises(BusError):
        crate.read(WIN, space="A24", width=Width.D32)
    assert crate.read(CSR, space="A16", width=Width.D16) == 0x0006
    assert crate.read(CSR + 0x0C, space="A16", width=Width.D16) == 1  # ERRORS


def test_cycles_refused_while_an_error_is_latched_count_in_errors() -> None:
    crate, card, _drv, _ = _rig()
    card.inject("parity", count=1)
    for _ in range(3):  # the parity error, then two refusals (the error stays latched)
        with pytest.raises(BusError) as ei:
            crate.read(WIN, space="A24", width=Width.D32)
    assert ei.value.cause is BusErrorCause.LINK_DOWN and "latched" in ei.value.detail
    assert crate.read(CSR, space="A16", width=Width.D16) == 0x0013  # parity + live bits
    assert crate.read(CSR + 0x0C, space="A16", width=Width.D16) == 3
    crate.write(CSR + 0x02, 0x0003, space="A16", width=Width.D16)  # reset, window stays enabled
    assert crate.read(CSR + 0x0C, space="A16", width=Width.D16) == 0
    assert crate.read(CSR + 0x02, space="A16", width=Width.D16) == 0x0002  # reset reads 0


def test_command_reset_alone_also_disables_the_window() -> None:
    crate, _card, _drv, _ = _rig()
    crate.write(CSR + 0x02, 0x0001, space="A16", width=Width.D16)
    with pytest.raises(BusError) as ei:
        crate.read(WIN, space="A24", width=Width.D32)
    assert ei.value.cause is BusErrorCause.NO_RESPONDER
    assert crate.read(CSR + 0x0C, space="A16", width=Width.D16) == 0  # not the card answering


def test_pending_doorbell_interrupts_as_soon_as_irq_ctrl_enables_it() -> None:
    crate, card, _drv, remote = _rig()
    remote.ring(0x0042)
    assert crate.read(CSR, space="A16", width=Width.D16) == 0x0023
    assert not card.irq_pending
    crate.write(CSR + 0x04, 0xA70D, space="A16", width=Width.D16)  # level 5, enabled, vector 0xA7
    assert card.irq_pending and card.iack(5) == 0xA7
    assert card.irq_pending  # RORA: the IACK does not release it
    assert crate.read(CSR + 0x08, space="A16", width=Width.D16) == 0x0042
    assert not card.irq_pending and crate.read(CSR, space="A16", width=Width.D16) == 0x0003


def test_writing_one_to_status_doorbell_releases_the_interrupt() -> None:
    crate, card, _drv, remote = _rig()
    crate.write(CSR + 0x04, 0xB30B, space="A16", width=Width.D16)
    remote.ring(7)
    assert card.irq_pending
    crate.write(CSR, 0x0020, space="A16", width=Width.D16)
    assert not card.irq_pending and crate.read(CSR, space="A16", width=Width.D16) == 0x0003
    assert crate.read(CSR + 0x0A, space="A16", width=Width.D16) == 1  # DOORBELL_COUNT


def test_window_bytes_are_big_endian_as_the_doc_example() -> None:
    crate, _card, _drv, remote = _rig()
    remote.memory.write(0x10, bytes([0x11, 0x22, 0x33, 0x44]))
    assert crate.read(WIN + 0x10, space="A24", width=Width.D32) == 0x11223344
    assert crate.read(WIN + 0x12, space="A24", width=Width.D16) == 0x3344
    assert crate.read(WIN + 0x13, space="A24", width=Width.D8) == 0x44
    crate.write(WIN + 0x20, 0xCAFE, space="A24", width=Width.D16)
    assert remote.memory.read(0x20, 2) == bytes([0xCA, 0xFE])


def test_creator_close_unlinks_even_while_views_are_still_exported() -> None:
    from multiprocessing import shared_memory

    from hal.shm import BufferMemory

    link = Bit3Link.create_shared(0x100)
    name = link.shm_name
    view = BufferMemory(link.mem)
    with pytest.raises(BufferError, match="still in use"):
        link.close()
    with pytest.raises(FileNotFoundError):
        shared_memory.SharedMemory(name=name)
    view.release()
    link.close()  # now the mapping closes too
