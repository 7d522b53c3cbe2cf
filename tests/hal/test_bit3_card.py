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
    _, _, drv, remote = _rig()
    remote.power_off()
    with pytest.raises(LinkDownError):
        drv.ring_doorbell(1)


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


def test_docs_register_table_matches_the_register_map() -> None:
    doc = (REPO / "docs" / "bit3.md").read_text()
    assert BIT3_CSR.markdown_table() in doc


def test_creator_close_unlinks_even_while_views_are_still_exported() -> None:
    from multiprocessing import shared_memory

    from hal.bit3 import BufferMemory

    link = Bit3Link.create_shared(0x100)
    name = link.shm_name
    view = BufferMemory(link.mem)
    with pytest.raises(BufferError, match="still in use"):
        link.close()
    with pytest.raises(FileNotFoundError):
        shared_memory.SharedMemory(name=name)
    view.release()
    link.close()  # now the mapping closes too
