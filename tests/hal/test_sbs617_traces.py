"""Golden bus traces of the SBS 617 driver, written by hand from docs/boards/sbs617.md.

The doc's example placement ("Driver sequences"): node registers at A32 0x80000000 (LOC_CMD1 +0x00,
LOC_INT_CTRL +0x01, LOC_STATUS +0x02, REM_CMD1_STATUS +0x08), mapping RAM at A32 0x80010000, the
window at A32 0x82000000, the remote memory at remote A24 0x400000. The scripted bus answers as
the doc says the card would; the forwarding bus runs the driver on a crate with the emulated card
(its own reading of the doc).
"""

from __future__ import annotations

import re

import pytest

from emulators.bit3 import Bit3RemotePort
from emulators.crate import Crate
from emulators.sbs617 import Sbs617Card
from hal.bit3 import Bit3Error, LinkDownError, RemoteBusError, Sbs617Driver, sbs617_regs
from hal.bit3.sbs617 import Sbs617WindowMemory, probe_sbs617
from hal.vme import AddressSpace, Width
from hal.vme.registers import Access, Field, Register
from tests.support.bus_trace import Answer, RecordingBus

NODE, MAPS, WIN = 0x80000000, 0x80010000, 0x82000000
LSR_OK = "R A32 0x80000002 D8 0x00"
CLEAR_ERRORS = "W A32 0x80000000 D8 0x80"


def _scripted(mem_size: int = 0x1000, **answers: Answer) -> tuple[RecordingBus, Sbs617Driver]:
    """A driver on a scripted bus; ``answers`` by register name or ``window_<hex offset>``."""
    offsets = {"LOC_CMD1": 0x0, "LOC_INT_CTRL": 0x1, "LOC_STATUS": 0x2, "REM_STATUS": 0x8}
    table: dict[tuple[str, int], Answer] = {}
    for name, answer in answers.items():
        if name.startswith("window_"):
            table[("A32", WIN + int(name.removeprefix("window_"), 16))] = answer
        else:
            table[("A32", NODE + offsets[name])] = answer
    bus = RecordingBus(answers=table)
    return bus, Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000, mem_size=mem_size)


# --- probe, reset, status ----------------------------------------------------------------
def test_probe_is_the_reset_sequence_of_chapter_5_2() -> None:
    bus, drv = _scripted(LOC_STATUS=[0x00, 0x00], REM_STATUS=0x90)
    assert drv.probe().usable
    assert bus.trace() == [LSR_OK, "R A32 0x80000008 D8 0x90", CLEAR_ERRORS, LSR_OK]


def test_probe_with_the_remote_crate_off_stops_after_one_read() -> None:
    bus, drv = _scripted(LOC_STATUS=0x01)
    with pytest.raises(LinkDownError, match="not connected"):
        drv.probe()
    assert bus.trace() == ["R A32 0x80000002 D8 0x01"]


def test_probe_fails_when_clearing_leaves_an_error_bit() -> None:
    bus, drv = _scripted(LOC_STATUS=[0x00, 0x40], REM_STATUS=0x10)
    with pytest.raises(Bit3Error, match="0x40"):
        drv.probe()
    assert bus.trace()[-1] == "R A32 0x80000002 D8 0x40"


def test_setup_maps_one_entry_per_4k_page_as_the_worked_entries() -> None:
    bus, drv = _scripted(mem_size=0x1800, LOC_STATUS=0x00, REM_STATUS=0x10)
    drv.setup()
    assert bus.trace()[4:] == ["W A32 0x80010000 D32 0x00400E60", "W A32 0x80010004 D32 0x00401E60"]


def test_setup_of_an_a32_remote_memory_uses_the_a32_data_am() -> None:
    bus = RecordingBus(answers={("A32", NODE + 2): 0x00, ("A32", NODE + 8): 0x10})
    drv = Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x08000000, remote_space="A32", mem_size=0x100)
    drv.setup()
    assert bus.trace()[-1] == "W A32 0x80010000 D32 0x08000260"


def test_status_decodes_each_loc_status_bit() -> None:
    for raw, name in ((0x80, "parity"), (0x40, "remote_berr"), (0x20, "doorbell"), (0x04, "timeout"),
                      (0x02, "lrc")):
        _bus, drv = _scripted(LOC_STATUS=raw)
        st = drv.status()
        assert [f for f in ("parity", "remote_berr", "doorbell", "timeout", "lrc") if getattr(st, f)] == [name]
        assert st.link_up
    _bus, drv = _scripted(LOC_STATUS=0x01)
    assert not drv.status().link_up and not drv.status().usable


# --- window transfers --------------------------------------------------------------------
def test_read_bytes_uses_d8_ends_d32_words_then_checks_loc_status() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00, window_3=0xAA, window_4=0x11223344, window_8=0x55, window_9=0x66)
    assert drv.read_bytes(3, 7) == bytes([0xAA, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66])
    assert bus.trace() == ["R A32 0x82000003 D8 0xAA", "R A32 0x82000004 D32 0x11223344",
                           "R A32 0x82000008 D8 0x55", "R A32 0x82000009 D8 0x66", LSR_OK]


def test_write_bytes_then_one_status_read() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00)
    drv.write_bytes(0x20, bytes([0xCA, 0xFE, 0xBA, 0xBE, 0x01]))
    assert bus.trace() == ["W A32 0x82000020 D32 0xCAFEBABE", "W A32 0x82000024 D8 0x01", LSR_OK]


def test_a_timed_out_read_clears_the_error_and_raises_link_down() -> None:
    bus, drv = _scripted(LOC_STATUS=0x05, window_0=0xFFFFFFFF)
    with pytest.raises(LinkDownError) as e:
        drv.read(0)
    assert e.value.status == 0x05
    assert bus.trace() == ["R A32 0x82000000 D32 0xFFFFFFFF", "R A32 0x80000002 D8 0x05", CLEAR_ERRORS]
    assert drv.errors == 1


def test_a_remote_bus_error_clears_and_raises_remote_bus_error() -> None:
    for raw in (0x40, 0x80, 0x02):
        bus, drv = _scripted(LOC_STATUS=raw)
        with pytest.raises(RemoteBusError):
            drv.write(4, 0x1234, Width.D16)
        assert bus.trace() == ["W A32 0x82000004 D16 0x1234", f"R A32 0x80000002 D8 0x{raw:02X}", CLEAR_ERRORS]


def test_no_connect_alone_raises_without_a_clear_write() -> None:
    bus, drv = _scripted(LOC_STATUS=0x01, window_0=0x00)
    with pytest.raises(LinkDownError):
        drv.read(0, Width.D8)
    assert bus.trace() == ["R A32 0x82000000 D8 0x00", "R A32 0x80000002 D8 0x01"]


# --- programmed interrupts ---------------------------------------------------------------
def test_ring_sends_pr_through_remote_command_1_then_checks() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00)
    drv.ring_doorbell(2)
    assert bus.trace() == ["W A32 0x80000008 D8 0x20", LSR_OK]


def test_ring_with_the_link_down_raises() -> None:
    bus, drv = _scripted(LOC_STATUS=0x05)
    with pytest.raises(LinkDownError):
        drv.ring_doorbell()
    assert bus.trace() == ["W A32 0x80000008 D8 0x20", "R A32 0x80000002 D8 0x05", CLEAR_ERRORS]


def test_doorbell_interrupt_on_handler_and_off() -> None:
    bus, drv = _scripted(LOC_STATUS=0x20)
    got: list[int] = []
    drv.on_doorbell(got.append)
    assert bus.trace() == ["W A32 0x80000001 D8 0x40"]
    bus.clear()
    handler = bus.irq_handler(0xB3)
    assert handler is not None
    handler(0xB3)
    assert bus.trace() == ["R A32 0x80000002 D8 0x20", "W A32 0x80000000 D8 0x40"]
    assert got == [0]
    bus.clear()
    drv.disable_doorbell_irq()
    assert bus.trace() == ["W A32 0x80000001 D8 0x00"]
    assert bus.irq_handler(0xB3) is None


def test_poll_doorbell_acknowledges_only_when_pr_is_set() -> None:
    bus, drv = _scripted(LOC_STATUS=[0x00, 0x20])
    assert drv.read_doorbell() is None
    assert drv.read_doorbell() == 0
    assert bus.trace() == [LSR_OK, "R A32 0x80000002 D8 0x20", "W A32 0x80000000 D8 0x40"]


# --- the same driver on the emulated card ------------------------------------------------
def _on_crate() -> tuple[RecordingBus, Sbs617Driver, Sbs617Card]:
    crate = Crate()
    card = Sbs617Card("vision-link", map_base=MAPS, window_base=WIN, remote_base=0x400000)
    crate.install(card, base=NODE, space="A32")
    bus = RecordingBus(crate)
    return bus, Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000, mem_size=0x1000), card


def test_setup_on_the_emulated_card_reads_was_reset_then_clears() -> None:
    bus, drv, _card = _on_crate()
    drv.setup()
    assert bus.trace() == [LSR_OK, "R A32 0x80000008 D8 0x90", CLEAR_ERRORS, LSR_OK,
                           "W A32 0x80010000 D32 0x00400E60"]


def test_worked_example_through_the_emulated_card() -> None:
    bus, drv, card = _on_crate()
    drv.setup()
    card.link.mem[0x10:0x14] = bytes([0x11, 0x22, 0x33, 0x44])
    bus.clear()
    assert drv.read(0x10) == 0x11223344
    assert drv.read(0x12, Width.D16) == 0x3344
    assert drv.read(0x13, Width.D8) == 0x44
    assert bus.trace() == ["R A32 0x82000010 D32 0x11223344", LSR_OK, "R A32 0x82000012 D16 0x3344", LSR_OK,
                           "R A32 0x82000013 D8 0x44", LSR_OK]


def test_remote_power_off_on_the_emulated_card_reads_all_ones_and_0x05() -> None:
    bus, drv, card = _on_crate()
    drv.setup()
    Bit3RemotePort(card.link).power_off()
    bus.clear()
    with pytest.raises(LinkDownError):
        drv.read(0x10)
    assert bus.trace() == ["R A32 0x82000010 D32 0xFFFFFFFF", "R A32 0x80000002 D8 0x05", CLEAR_ERRORS]


# --- the dry pass's probe, the register helper, edges ----------------------------------------------
@pytest.mark.parametrize(("lsr", "ctrl", "ok", "text"), [
    (0x00, 0x00, True, "LOC_STATUS 0x00 (remote connected), LOC_INT_CTRL 0x00; no ID register"),
    (0x01, 0x00, True, "LOC_STATUS 0x01 (remote crate off or cable out), LOC_INT_CTRL 0x00; no ID register"),
    (0xF6, 0xE7, True, "LOC_STATUS 0xF6 (remote connected), LOC_INT_CTRL 0xE7; no ID register"),  # every other bit
    (0x08, 0x00, False, "LOC_STATUS 0x08, LOC_INT_CTRL 0x00: bits the 617 reads as 0 are set"),  # LOC_STATUS bit 3
    (0x00, 0x10, False, "LOC_STATUS 0x00, LOC_INT_CTRL 0x10: bits the 617 reads as 0 are set"),  # LOC_INT_CTRL bit 4
    (0x00, 0x08, False, "LOC_STATUS 0x00, LOC_INT_CTRL 0x08: bits the 617 reads as 0 are set"),  # LOC_INT_CTRL bit 3
])
def test_the_dry_pass_probe_reads_the_bits_that_must_be_0(lsr: int, ctrl: int, ok: bool, text: str) -> None:
    bus = RecordingBus(answers={("A32", NODE + 2): lsr, ("A32", NODE + 1): ctrl})
    got = probe_sbs617(bus, NODE, AddressSpace.A32)
    assert (got.ok, got.detail) == (ok, text)
    assert bus.trace() == [f"R A32 0x80000002 D8 0x{lsr:02X}", f"R A32 0x80000001 D8 0x{ctrl:02X}"]


def test_the_dry_pass_probe_of_nothing_says_the_card_is_pci() -> None:
    got = probe_sbs617(RecordingBus(answers={}), NODE, AddressSpace.A32)
    assert got.ok is False
    assert got.detail.startswith("BusError: ") and got.detail.endswith(
        " (the SBS 617 is a PCI card: its registers are the host's PCI BARs, not VME addresses)")


def test_node_registers_are_single_bytes() -> None:
    f = Field("X", 1, 2)
    assert sbs617_regs._r("R", 0x05, Access.RO, f, reset=0x12, doc="d") == Register(
        "R", 0x05, Width.D8, Access.RO, fields=(f,), reset=0x12, doc="d")
    assert sbs617_regs._r("S", 0x06, Access.RW) == Register("S", 0x06, Width.D8, Access.RW)


def test_driver_refuses_irq_levels_vectors_and_sizes_out_of_range() -> None:
    bus = RecordingBus(answers={})
    kw = {"remote_base": 0x400000}
    for level, vector in ((1, 0x00), (7, 0xFF)):
        Sbs617Driver(bus, NODE, MAPS, WIN, irq_level=level, irq_vector=vector, **kw)
    for level, vector in ((0, 0xB3), (8, 0xB3), (3, -1), (3, 0x100)):
        with pytest.raises(ValueError, match=rf"^IRQ level {level} must be 1\.\.7 and vector {vector} 0\.\.255$"):
            Sbs617Driver(bus, NODE, MAPS, WIN, irq_level=level, irq_vector=vector, **kw)
    Sbs617Driver(bus, NODE, MAPS, WIN, mem_size=1, **kw)
    with pytest.raises(ValueError, match=r"^remote base 0x400000 must be 4 KiB aligned and 0 < mem_size <= 32 MiB$"):
        Sbs617Driver(bus, NODE, MAPS, WIN, mem_size=0, **kw)


def test_longer_transfers_step_four_bytes_a_word() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00, window_1=0x01, window_2=0x02, window_3=0x03, window_4=0x04050607,
                         window_8=0x08090A0B, window_C=0x0C)
    assert drv.read_bytes(1, 12) == bytes(range(1, 13))
    assert bus.trace() == ["R A32 0x82000001 D8 0x01", "R A32 0x82000002 D8 0x02", "R A32 0x82000003 D8 0x03",
                           "R A32 0x82000004 D32 0x04050607", "R A32 0x82000008 D32 0x08090A0B",
                           "R A32 0x8200000C D8 0x0C", LSR_OK]
    bus.clear()
    drv.write_bytes(1, bytes(range(1, 13)))
    assert bus.trace() == ["W A32 0x82000001 D8 0x01", "W A32 0x82000002 D8 0x02", "W A32 0x82000003 D8 0x03",
                           "W A32 0x82000004 D32 0x04050607", "W A32 0x82000008 D32 0x08090A0B",
                           "W A32 0x8200000C D8 0x0C", LSR_OK]


def test_ring_doorbell_default_and_an_interrupt_without_pr_only_reads() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00)
    drv.ring_doorbell()
    assert bus.trace() == ["W A32 0x80000008 D8 0x20", LSR_OK]
    got: list[int] = []
    drv.on_doorbell(got.append)
    bus.clear()
    handler = bus.irq_handler(0xB3)
    assert handler is not None
    handler(0xB3)  # LOC_STATUS 0x00: no PR interrupt pending
    assert bus.trace() == [LSR_OK] and got == []


def test_each_status_error_counts() -> None:
    _bus, drv = _scripted(LOC_STATUS=0x40)
    for _ in range(2):
        with pytest.raises(RemoteBusError):
            drv.write(0, 1, Width.D8)
    assert drv.errors == 2


def test_status_errors_are_explained_in_full_and_carry_the_status() -> None:
    _bus, drv = _scripted(LOC_STATUS=0x04, window_10=0)
    with pytest.raises(LinkDownError) as ei:
        drv.read(0x10)
    assert ei.value.status == 0x04
    assert str(ei.value) == ("SBS 617 read +0x10: link down (LOC_STATUS=0x04 no_connect=0 timeout=1 rembus=0 parity=0 "
                             "lrc=0); check the cable and the remote crate's power, then reset_link()")
    _bus, drv = _scripted(LOC_STATUS=0xC2)
    with pytest.raises(RemoteBusError) as ei2:
        drv.write_bytes(0x20, b"\x01\x02")
    assert ei2.value.status == 0xC2 and ei2.value.bus_error is None
    assert str(ei2.value) == ("SBS 617 write +0x20..+0x22: remote bus error (LOC_STATUS=0xC2 no_connect=0 timeout=0 "
                              "rembus=1 parity=1 lrc=1); the error is cleared")
    _bus, drv = _scripted(LOC_STATUS=0x40, window_8=0)
    with pytest.raises(RemoteBusError, match=r"^SBS 617 read \+0x8\.\.\+0xC: remote bus error"):
        drv.read_bytes(8, 4)
    _bus, drv = _scripted(LOC_STATUS=0x40)
    with pytest.raises(RemoteBusError, match=r"^SBS 617 write \+0x4: remote bus error"):
        drv.write(4, 0)
    _bus, drv = _scripted(LOC_STATUS=0x40)
    with pytest.raises(RemoteBusError, match=r"^SBS 617 ring: remote bus error"):
        drv.ring_doorbell()
    assert drv.status().errors == 1


def test_a_failed_host_cycle_names_the_operation() -> None:
    bus = RecordingBus(answers={})  # nothing answers a read: the host's bus fails, not the link
    drv = Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000)
    for call, what in ((lambda: drv.read(0x10), "read +0x10"), (lambda: drv.read_bytes(0x10, 4), "read +0x10")):
        with pytest.raises(LinkDownError, match=rf"^SBS 617 {re.escape(what)}: the host's bus failed \(") as ei:
            call()
        assert ei.value.bus_error is not None and ei.value.status is None


def test_probe_with_the_remote_off_says_so_in_full() -> None:
    _bus, drv = _scripted(LOC_STATUS=0x01)
    with pytest.raises(LinkDownError) as ei:
        drv.probe()
    assert ei.value.status == 0x01
    assert str(ei.value) == ("SBS 617 at 0x80000000: not connected (LOC_STATUS=0x01): the remote crate is off or "
                             "the cable is out")


def test_window_limits_of_the_default_4_kib_memory() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00, window_FFC=0x01020304)
    assert drv.read(0xFFC) == 0x01020304  # the last word of 0x1000 bytes
    for offset, width in ((0xFFD, Width.D32), (0x1000, Width.D8), (-1, Width.D8)):
        with pytest.raises(ValueError, match=r"outside the 0x1000-byte memory$"):
            drv.read(offset, width)
    with pytest.raises(ValueError, match=r"^window access 0xffe\.\.0x1002 outside the 0x1000-byte memory$"):
        drv.write_bytes(0xFFE, b"abcd")
    Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000, mem_size=32 << 20)  # the whole window
    with pytest.raises(ValueError, match=r"^remote base 0x400000 must be 4 KiB aligned"):
        Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000, mem_size=(32 << 20) + 1)
    with pytest.raises(ValueError, match=r"^the remote memory must be in A24 or A32, not A16$"):
        Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x4000, remote_space="A16")
    assert Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000).irq_level == 3


def test_an_interrupt_with_a_latched_error_clears_it() -> None:
    bus, drv = _scripted(LOC_STATUS=0x44)  # remote BERR and timeout latched, no PR
    drv.on_doorbell(lambda code: None)
    bus.clear()
    handler = bus.irq_handler(0xB3)
    assert handler is not None
    handler(0xB3)
    assert bus.trace() == ["R A32 0x80000002 D8 0x44", CLEAR_ERRORS]


def test_memory_views_default_to_the_rest_of_the_memory_and_go_through_the_window() -> None:
    bus, drv = _scripted(LOC_STATUS=0x00, window_44=0x11223344)  # 0x1000 bytes of remote memory
    assert (drv.memory().base, drv.memory().size) == (0, 0x1000)
    assert (drv.memory(0x40).base, drv.memory(0x40).size) == (0x40, 0xFC0)
    assert drv.memory(0x40, 0x10).size == 0x10
    assert (Sbs617WindowMemory(drv).base, Sbs617WindowMemory(drv).size) == (0, 0x1000)
    assert Sbs617WindowMemory(drv, 0x100).size == 0xF00
    view = drv.memory(0x40)
    assert view.read(4, 4) == bytes([0x11, 0x22, 0x33, 0x44])
    view.write(8, b"VSM1")
    assert bus.trace() == ["R A32 0x82000044 D32 0x11223344", LSR_OK, "W A32 0x82000048 D32 0x56534D31", LSR_OK]


def test_a_failed_host_write_names_the_operation() -> None:
    drv = Sbs617Driver(Crate(), NODE, MAPS, WIN, remote_base=0x400000)  # an empty crate: every cycle fails
    for call, what in ((lambda: drv.write(0x10, 1), "write +0x10"), (lambda: drv.write_bytes(0x10, b"abcd"),
                                                                     "write +0x10"), (drv.ring_doorbell, "ring")):
        with pytest.raises(LinkDownError, match=rf"^SBS 617 {re.escape(what)}: the host's bus failed \(") as ei:
            call()
        assert ei.value.bus_error is not None and ei.value.status is None


def test_defaults_4_kib_of_remote_memory_and_a_second_doorbell_callback_replaces_the_first() -> None:
    bus, _ = _scripted(LOC_STATUS=0x20)
    drv = Sbs617Driver(bus, NODE, MAPS, WIN, remote_base=0x400000)
    assert drv.window_size == 0x1000
    first: list[int] = []
    second: list[int] = []
    drv.on_doorbell(first.append)
    drv.on_doorbell(second.append)
    handler = bus.irq_handler(0xB3)
    assert handler is not None
    handler(0xB3)
    assert (first, second) == ([], [0])
