"""Golden bus traces of the BIT3 driver, written by hand from docs/boards/bit3.md.

Each expected trace is the doc's register sequence ("Driver sequences") with the doc's offsets and
worked values: the CSR block at A16 0xC000 (STATUS +0x0, COMMAND +0x2, IRQ_CTRL +0x4,
DOORBELL_OUT +0x6, DOORBELL_IN +0x8, ERRORS +0xC, ID +0xE), the window at A24 0x400000. The
scripted bus answers reads as the doc says the card would; the forwarding bus runs the same driver
on a crate with the emulated card (its own reading of the doc).
"""

from __future__ import annotations

import pytest

from emulators.bit3 import Bit3Board, Bit3Link, Bit3RemotePort
from emulators.crate import Crate
from hal.bit3 import Bit3Driver, Bit3Error, LinkDownError, RemoteBusError
from hal.bit3.driver import Bit3WindowMemory
from hal.vme import BusError, BusErrorCause, Width
from hal.vme.types import resolve_am
from tests.support.bus_trace import Answer, RecordingBus

CSR, WIN = 0xC000, 0x400000
ID_READ = "R A16 0xC00E D16 0x0413"


def _scripted(**answers: Answer) -> tuple[RecordingBus, Bit3Driver]:
    """A driver on a scripted bus; ``answers`` by register name (CSR) or ``window_<offset>``."""
    offsets = {"STATUS": 0x0, "COMMAND": 0x2, "IRQ_CTRL": 0x4, "DOORBELL_IN": 0x8, "DOORBELL_COUNT": 0xA,
               "ERRORS": 0xC, "ID": 0xE}
    table: dict[tuple[str, int], Answer] = {}
    for name, answer in answers.items():
        if name.startswith("window_"):
            table[("A24", WIN + int(name.removeprefix("window_"), 16))] = answer
        else:
            table[("A16", CSR + offsets[name])] = answer
    bus = RecordingBus(answers=table)
    return bus, Bit3Driver(bus, CSR, WIN, window_size=0x1000)


def _berr(cause: BusErrorCause, address: int) -> Answer:
    def fail(_n: int) -> int:
        raise BusError(address, resolve_am("A24"), Width.D32, cause)

    return fail


# --- probe and status --------------------------------------------------------------------
def test_probe_reads_the_id_register_once() -> None:
    bus, drv = _scripted(ID=0x0413)
    assert drv.probe() == 0x0413
    assert bus.trace() == [ID_READ]


def test_probe_of_another_card_fails_after_the_same_single_read() -> None:
    bus, drv = _scripted(ID=0xAD16)
    with pytest.raises(Bit3Error, match="0xAD16"):
        drv.probe()
    assert bus.trace() == ["R A16 0xC00E D16 0xAD16"]


def test_status_reads_status_then_errors() -> None:
    bus, drv = _scripted(STATUS=0x0023, ERRORS=0x0002)
    st = drv.status()
    assert bus.trace() == ["R A16 0xC000 D16 0x0023", "R A16 0xC00C D16 0x0002"]
    assert (st.link_up, st.remote_power, st.doorbell, st.error_latched, st.errors) == (True, True, True, False, 2)


def test_status_decodes_each_sticky_bit() -> None:
    for raw, name in ((0x0004, "timeout"), (0x0008, "remote_berr"), (0x0010, "parity")):
        _bus, drv = _scripted(STATUS=raw, ERRORS=0)
        st = drv.status()
        assert [f for f in ("timeout", "remote_berr", "parity") if getattr(st, f)] == [name]
        assert st.error_latched and not st.link_up


def test_reset_link_writes_reset_and_window_enable_then_reads_status() -> None:
    bus, drv = _scripted(STATUS=0x0003, ERRORS=0x0000)
    assert drv.reset_link().usable
    assert bus.trace() == ["W A16 0xC002 D16 0x0003", "R A16 0xC000 D16 0x0003", "R A16 0xC00C D16 0x0000"]


# --- doorbells and the interrupt -----------------------------------------------------------
def test_ring_doorbell_writes_the_code_to_doorbell_out() -> None:
    bus, drv = _scripted()
    drv.ring_doorbell(0x1234)
    drv.ring_doorbell(0x10002)  # 16-bit code: the doc's register is D16
    assert bus.trace() == ["W A16 0xC006 D16 0x1234", "W A16 0xC006 D16 0x0002"]


def test_doorbell_interrupt_is_enabled_at_level_3_vector_0xb3_and_acknowledged_by_reading_doorbell_in() -> None:
    bus, drv = _scripted(DOORBELL_IN=0x0042)
    got: list[int] = []
    drv.on_doorbell(got.append)
    assert bus.trace() == ["W A16 0xC004 D16 0xB30B"]
    handler = bus.irq_handler(0xB3)
    assert handler is not None
    bus.clear()
    handler(0xB3)  # the CPU took the IRQ and the IACK returned vector 0xB3
    assert bus.trace() == ["R A16 0xC008 D16 0x0042"] and got == [0x42]


def test_doorbell_interrupt_at_level_5_vector_0xa7() -> None:
    bus, _ = _scripted()
    drv = Bit3Driver(bus, CSR, WIN, irq_level=5, irq_vector=0xA7)
    drv.on_doorbell(lambda code: None)
    assert bus.trace() == ["W A16 0xC004 D16 0xA70D"]


def test_disabling_the_doorbell_interrupt_writes_zero() -> None:
    bus, drv = _scripted()
    drv.on_doorbell(lambda code: None)
    bus.clear()
    drv.disable_doorbell_irq()
    assert bus.trace() == ["W A16 0xC004 D16 0x0000"]
    assert bus.irq_handler(0xB3) is None


def test_polled_doorbell_reads_doorbell_in_only_when_status_says_pending() -> None:
    bus, drv = _scripted(STATUS=[0x0023, 0x0003], ERRORS=0, DOORBELL_IN=0x0009)
    assert drv.read_doorbell() == 9
    assert drv.read_doorbell() is None
    assert bus.trace() == [
        "R A16 0xC000 D16 0x0023", "R A16 0xC00C D16 0x0000", "R A16 0xC008 D16 0x0009",
        "R A16 0xC000 D16 0x0003", "R A16 0xC00C D16 0x0000",
    ]


# --- buffer write and read through the window ---------------------------------------------------
def test_buffer_write_uses_d8_to_the_word_boundary_d32_blocks_then_d8() -> None:
    bus, drv = _scripted()
    drv.write_bytes(0x102, bytes(range(1, 10)))  # 9 bytes from 0x102: 2 + 4 + 3
    assert bus.trace() == [
        "W A24 0x400102 D8 0x01",
        "W A24 0x400103 D8 0x02",
        "W A24 0x400104 D32 0x03040506 BLT",
        "W A24 0x400108 D8 0x07",
        "W A24 0x400109 D8 0x08",
        "W A24 0x40010A D8 0x09",
    ]


def test_aligned_buffer_write_is_one_block_of_big_endian_words() -> None:
    bus, drv = _scripted()
    drv.memory(0x40).write(0x8, b"VSM1\x00\x00\x00\x01")
    assert bus.trace() == ["W A24 0x400048 D32 0x56534D31 BLT", "W A24 0x40004C D32 0x00000001 BLT"]


def test_buffer_read_assembles_big_endian_bytes_from_block_cycles() -> None:
    bus, drv = _scripted(window_10=0x11223344, window_14=0x55667788, window_18=0x99)
    assert drv.read_bytes(0x10, 9) == bytes([0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88, 0x99])
    assert bus.trace() == ["R A24 0x400010 D32 0x11223344 BLT", "R A24 0x400014 D32 0x55667788 BLT",
                           "R A24 0x400018 D8 0x99"]


def test_single_window_cycles_at_each_width() -> None:
    bus, drv = _scripted(window_20=0xCAFE)
    drv.write(0x24, 0xDEADBEEF, Width.D32)
    drv.write(0x28, 0xBEEF, Width.D16)
    assert drv.read(0x20, Width.D16) == 0xCAFE
    assert bus.trace() == ["W A24 0x400024 D32 0xDEADBEEF", "W A24 0x400028 D16 0xBEEF", "R A24 0x400020 D16 0xCAFE"]


# --- sticky errors -------------------------------------------------------------------------------
def test_window_berr_link_down_reads_status_and_errors_then_raises_link_down() -> None:
    bus, drv = _scripted(window_0=_berr(BusErrorCause.LINK_DOWN, WIN), STATUS=0x0004, ERRORS=0x0001)
    with pytest.raises(LinkDownError) as ei:
        drv.read(0)
    assert ei.value.status == 0x0004 and ei.value.bus_error is not None
    assert ei.value.bus_error.address == WIN
    # the failed window cycle ends in BERR (no data: not a trace line); then the diagnosis
    assert bus.trace() == ["R A16 0xC000 D16 0x0004", "R A16 0xC00C D16 0x0001"]


def test_window_berr_remote_raises_remote_bus_error() -> None:
    bus, drv = _scripted(window_8=_berr(BusErrorCause.REMOTE, WIN + 8), STATUS=0x000B, ERRORS=0x0001)
    with pytest.raises(RemoteBusError, match="remote bus error") as ei:
        drv.read(8)
    assert ei.value.status == 0x000B
    assert bus.trace() == ["R A16 0xC000 D16 0x000B", "R A16 0xC00C D16 0x0001"]


def test_power_cycled_remote_crate_needs_a_link_reset_on_the_emulated_card() -> None:
    """The same driver against the emulated card: every STATUS and ERRORS value is the doc's."""
    link = Bit3Link(0x1000)
    remote = Bit3RemotePort(link)
    remote.power_on()
    crate = Crate()
    crate.install(Bit3Board("bit3", link, window_base=WIN), base=CSR, space="A16")
    bus = RecordingBus(crate)
    drv = Bit3Driver(bus, CSR, WIN, window_size=0x1000)
    assert drv.probe() == 0x0413
    remote.power_off()
    with pytest.raises(LinkDownError, match="remote crate power is off"):
        drv.read(0)
    remote.power_on()
    with pytest.raises(LinkDownError, match="latched"):
        drv.read(0)
    assert drv.reset_link().usable
    remote.memory.write(0, b"\x00\x00\x01\x02")
    assert drv.read(0) == 0x0102
    assert bus.trace() == [
        ID_READ,
        "R A16 0xC000 D16 0x0004", "R A16 0xC00C D16 0x0001",  # timed out: remote off, timeout latched
        "R A16 0xC000 D16 0x0007", "R A16 0xC00C D16 0x0002",  # refused: latched (counted)
        "W A16 0xC002 D16 0x0003", "R A16 0xC000 D16 0x0003", "R A16 0xC00C D16 0x0000",
        "R A24 0x400000 D32 0x00000102",
    ]


def test_doorbell_irq_on_the_emulated_card_is_taken_and_acknowledged() -> None:
    link = Bit3Link(0x100)
    remote = Bit3RemotePort(link)
    remote.power_on()
    crate = Crate()
    card = Bit3Board("bit3", link, window_base=WIN)
    crate.install(card, base=CSR, space="A16")
    bus = RecordingBus(crate)
    drv = Bit3Driver(bus, CSR, WIN, window_size=0x100)
    got: list[int] = []
    drv.on_doorbell(got.append)
    remote.ring(0x0042)
    crate.delay(1e-6)  # the crate's CPU takes the interrupt
    assert got == [0x42] and not card.irq_pending
    assert bus.trace() == ["W A16 0xC004 D16 0xB30B", "R A16 0xC008 D16 0x0042"]


# --- limits, defaults and texts ------------------------------------------------------------------
def test_driver_refuses_an_a16_window_and_an_irq_level_or_vector_out_of_range() -> None:
    bus = RecordingBus(answers={})
    with pytest.raises(ValueError, match=r"^the BIT3 window must be in A24 or A32$"):
        Bit3Driver(bus, CSR, 0x8000, window_space="A16")
    for level, vector in ((1, 0x00), (7, 0xFF)):
        Bit3Driver(bus, CSR, WIN, irq_level=level, irq_vector=vector)
    for level, vector in ((0, 0xB3), (8, 0xB3), (3, -1), (3, 0x100)):
        with pytest.raises(ValueError, match=rf"^IRQ level {level} must be 1\.\.7 and vector {vector} 0\.\.255$"):
            Bit3Driver(bus, CSR, WIN, irq_level=level, irq_vector=vector)


def test_the_default_window_is_64_kib_and_accesses_beyond_it_are_refused_without_a_cycle() -> None:
    bus = RecordingBus(answers={("A24", WIN + 0xFFFF): 0x5A})
    drv = Bit3Driver(bus, CSR, WIN)
    assert drv.read(0xFFFF, Width.D8) == 0x5A
    with pytest.raises(ValueError, match=r"^window access 0x10000\.\.0x10001 outside the 0x10000-byte window$"):
        drv.read(0x10000, Width.D8)
    with pytest.raises(ValueError, match=r"^window access -0x1\.\.0x3 outside the 0x10000-byte window$"):
        drv.write(-1, 0)
    assert bus.trace() == ["R A24 0x40FFFF D8 0x5A"]


def test_block_transfers_check_count_times_width_against_the_window() -> None:
    bus, drv = _scripted()  # a 0x1000-byte window
    with pytest.raises(ValueError, match=r"^window access 0xff8\.\.0x1004 outside"):
        drv.read_block(0xFF8, 3)  # 3 D32 words: 12 bytes from 0xFF8
    drv.write_block(0xFFC, [1, 2], Width.D16)  # 4 bytes from 0xFFC: the last of the window
    assert bus.trace() == ["W A24 0x400FFC D16 0x0001 BLT", "W A24 0x400FFE D16 0x0002 BLT"]
    with pytest.raises(ValueError, match=r"^window access 0xffc\.\.0x1002 outside"):
        drv.write_block(0xFFC, [1, 2, 3], Width.D16)


def test_block_transfers_use_the_window_s_space_and_the_given_width() -> None:
    bus = RecordingBus(answers={("A32", 0x8000_0000): 0x1234, ("A32", 0x8000_0002): 0x5678})
    drv = Bit3Driver(bus, CSR, 0x8000_0000, window_space="A32")
    assert drv.read_block(0, 2, Width.D16) == [0x1234, 0x5678]
    drv.write_block(4, [0xAB], Width.D16)
    assert bus.trace() == ["R A32 0x80000000 D16 0x1234 BLT", "R A32 0x80000002 D16 0x5678 BLT",
                           "W A32 0x80000004 D16 0x00AB BLT"]


def test_ring_doorbell_sends_code_1_by_default() -> None:
    bus, drv = _scripted()
    drv.ring_doorbell()
    assert bus.trace() == ["W A16 0xC006 D16 0x0001"]


def test_a_second_on_doorbell_replaces_the_callback_on_the_same_handler() -> None:
    bus, drv = _scripted(DOORBELL_IN=0x0007)
    first: list[int] = []
    second: list[int] = []
    drv.on_doorbell(first.append)
    drv.on_doorbell(second.append)
    handler = bus.irq_handler(0xB3)
    assert handler is not None
    handler(0xB3)
    assert (first, second) == ([], [7])


def test_memory_views_default_to_the_rest_of_the_window() -> None:
    _bus, drv = _scripted()  # a 0x1000-byte window
    m = drv.memory(0x40)
    assert (m.base, m.size) == (0x40, 0xFC0)
    m = drv.memory(0x40, 0x10)
    assert (m.base, m.size) == (0x40, 0x10)
    m = Bit3WindowMemory(drv)
    assert (m.base, m.size) == (0, 0x1000)
    assert Bit3WindowMemory(drv, 0x100, 8).size == 8
    assert Bit3WindowMemory(drv, 0x100).size == 0xF00


def test_a_failed_window_cycle_is_explained_with_the_status_in_full() -> None:
    _bus, drv = _scripted(window_10=_berr(BusErrorCause.LINK_DOWN, WIN + 0x10), STATUS=0x0004, ERRORS=0x0001)
    with pytest.raises(LinkDownError) as ei:
        drv.read(0x10)
    assert str(ei.value) == (
        "BIT3 window +0x10: link down (the bus-bridge link is down or the remote crate is off; STATUS=0x0004 "
        "link_up=0 remote_power=0 timeout=1 remote_berr=0 parity=0); check cable and remote power, then reset_link()")
    _bus, drv = _scripted(window_8=_berr(BusErrorCause.REMOTE, WIN + 8), STATUS=0x001B, ERRORS=0x0001)
    with pytest.raises(RemoteBusError) as ei2:
        drv.read(8)
    assert str(ei2.value) == (
        "BIT3 window +0x8: remote bus error (the remote side of a bus bridge failed the cycle; STATUS=0x001B "
        "link_up=1 remote_power=1 timeout=0 remote_berr=1 parity=1); reset_link() clears the latched error")


def test_a_failed_window_cycle_with_status_unreadable_says_so() -> None:
    def berr_with_detail(_n: int) -> int:
        raise BusError(WIN + 4, resolve_am("A24"), Width.D32, BusErrorCause.NO_RESPONDER, detail="cable out")

    _bus, drv = _scripted(window_4=berr_with_detail)  # no STATUS answer: the diagnosis read fails too
    with pytest.raises(LinkDownError) as ei:
        drv.read(4)
    assert ei.value.status is None
    assert str(ei.value) == ("BIT3 window +0x4: link down (cable out; STATUS unreadable); "
                             "check cable and remote power, then reset_link()")
    with pytest.raises(LinkDownError, match=r"^BIT3 window \+0x4: link down"):
        drv.read_block(4, 1)


def test_a_failed_block_write_is_a_link_error_too() -> None:
    link = Bit3Link(0x1000)  # the remote crate never powered on
    crate = Crate()
    crate.install(Bit3Board("bit3", link, window_base=WIN), base=CSR, space="A16")
    drv = Bit3Driver(crate, CSR, WIN, window_size=0x1000)
    with pytest.raises(LinkDownError, match=r"^BIT3 window \+0x10: link down") as ei:
        drv.write_block(0x10, [1, 2])
    assert ei.value.bus_error is not None and ei.value.bus_error.address == WIN + 0x10
