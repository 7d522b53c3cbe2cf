"""Golden bus traces of the VMIVME-2536 driver (hal.pio.Vmi2536Driver), written by hand from
docs/boards/vmivme2536.md: the register table (BID 0x00 and CSR 0x02 D16, INPUT 0x04 and OUTPUT
0x08 D32) and the driver's cycle table ("The driver").

The board sits at 0xFF00 in A16 (the EPICS support's default), so CSR is ``0xFF02``, INPUT
``0xFF04`` and OUTPUT ``0xFF08``. Most tests run the driver on a scripted bus; the last ones
forward to an emulated crate with the board installed and read the nets.
"""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.pio import PioBoard
from emulators.vmivme2536 import Vmi2536Board
from hal.board_types import BOARD_TYPES
from hal.pio import LineDirectionError, LineStuckError, UnknownLineError, Vmi2536BoardIdError, Vmi2536Driver
from hal.vme import AddressSpace
from hal.vme.types import AddressModifier, Width
from tests.support.bus_trace import Answer, RecordingBus

BASE = 0xFF00
WIRING = {"j1.amp_enable": "OUT0", "j2.amp_enable": "OUT1", "watchdog": "OUT16", "j1.amp_fault": "IN0",
          "j2.amp_fault": "IN5"}
ADOPT = ["R A16 0xFF08 D32 0x00000000"]  #: the constructor adopts the latch (doc)


class _LatchBus(RecordingBus):
    """A scripted bus whose OUTPUT reads back what was last written there (a healthy latch)."""

    def __init__(self, answers: dict[tuple[str, int], Answer]) -> None:
        super().__init__(answers=answers)
        self.latch = 0

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        super()._write(am, address, width, value)
        if address == BASE + 0x08:
            self.latch = value


def _scripted(answers: dict[int, Answer] | None = None, *, latch: bool = True) -> _LatchBus:
    box: list[_LatchBus] = []
    script: dict[int, Answer] = {BASE: 0x2536, BASE + 0x02: 0x0000, BASE + 0x04: 0x0000_0000}
    script[BASE + 0x08] = (lambda _n: box[0].latch) if latch else 0
    script.update(answers or {})
    bus = _LatchBus({("A16", a): v for a, v in script.items()})
    box.append(bus)
    return bus


def _driver(bus: _LatchBus, **kw) -> Vmi2536Driver:
    d = Vmi2536Driver(bus, BASE, lines=WIRING, **kw)
    bus.clear()
    return d


def test_the_constructor_only_reads_the_output_latch() -> None:
    bus = _scripted({BASE + 0x08: 0x0001_0002})
    d = Vmi2536Driver(bus, BASE, lines=WIRING)
    assert bus.trace() == ["R A16 0xFF08 D32 0x00010002"]
    # it adopted the latch: the next write keeps OUT1 and OUT16 as they were
    bus.clear()
    d.set_line("j1.amp_enable", True, verify=False)
    assert bus.trace() == ["W A16 0xFF08 D32 0x00010003"]


def test_probe_reads_bid_once() -> None:
    bus = _scripted()
    assert _driver(bus).probe() == 0x2536
    assert bus.trace() == ["R A16 0xFF00 D16 0x2536"]


def test_probe_with_a_stated_board_id_refuses_another_naming_both() -> None:
    bus = _scripted({BASE: 0x5001})
    with pytest.raises(Vmi2536BoardIdError, match=r"BID 0x2536 at 0xFF00: BID reads 0x5001"):
        _driver(bus, board_id=0x2536).probe()
    assert bus.trace() == ["R A16 0xFF00 D16 0x5001"]


def test_reset_clears_the_latch_then_deactivates() -> None:
    bus = _scripted()
    _driver(bus).reset()
    assert bus.trace() == ["W A16 0xFF08 D32 0x00000000", "W A16 0xFF02 D16 0x0000"]


def test_configure_loads_the_latch_before_activating_outputs_and_inputs() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["j1.amp_enable", "j2.amp_enable", "watchdog"], initial={"j2.amp_enable": True,
                                                                                  "watchdog": True})
    # OUT1 and OUT16 high: 0x00010002; then LED off | outputs on | inputs on = 0xE000
    assert bus.trace() == ["W A16 0xFF08 D32 0x00010002", "W A16 0xFF02 D16 0xE000"]


def test_configure_refuses_an_input_as_an_output_before_any_cycle() -> None:
    bus = _scripted()
    with pytest.raises(LineDirectionError, match="j1.amp_fault"):
        _driver(bus).configure(outputs=["j1.amp_fault"])
    with pytest.raises(LineDirectionError, match="not in outputs"):
        _driver(bus).configure(outputs=["j1.amp_enable"], initial={"j2.amp_enable": True})
    assert bus.trace() == []


def test_set_line_writes_the_whole_latch_from_the_copy_then_reads_it_back() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.set_line("watchdog", True)
    d.set_line("OUT31", True)
    d.set_line("watchdog", False)
    assert bus.trace() == [
        "W A16 0xFF08 D32 0x00010000", "R A16 0xFF08 D32 0x00010000",
        "W A16 0xFF08 D32 0x80010000", "R A16 0xFF08 D32 0x80010000",
        "W A16 0xFF08 D32 0x80000000", "R A16 0xFF08 D32 0x80000000",
    ]


def test_set_line_without_verify_is_one_write() -> None:
    bus = _scripted()
    _driver(bus).set_line("j2.amp_enable", True, verify=False)
    assert bus.trace() == ["W A16 0xFF08 D32 0x00000002"]


def test_a_latch_that_does_not_read_back_raises_line_stuck() -> None:
    bus = _scripted(latch=False)  # OUTPUT always reads 0
    with pytest.raises(LineStuckError, match=r"j1.amp_enable \(latch 1, pin 0\)"):
        _driver(bus).set_line("j1.amp_enable", True)
    assert bus.trace() == ["W A16 0xFF08 D32 0x00000001", "R A16 0xFF08 D32 0x00000000"]


def test_a_looped_back_output_is_verified_on_its_input() -> None:
    bus = _scripted({BASE + 0x04: 0x0000_0000})  # IN20 stays low: the wire did not follow
    d = _driver(bus, loopback={"j1.amp_enable": "IN20"})
    with pytest.raises(LineStuckError, match="j1.amp_enable"):
        d.set_line("j1.amp_enable", True)
    assert bus.trace() == ["W A16 0xFF08 D32 0x00000001", "R A16 0xFF08 D32 0x00000001",
                           "R A16 0xFF04 D32 0x00000000"]


def test_the_loopback_read_waits_settle_s_first() -> None:
    bus = _scripted({BASE + 0x04: 0x0010_0000})  # IN20 high
    d = _driver(bus, loopback={"OUT0": "IN20"}, settle_s=50e-6)
    d.set_line("j1.amp_enable", True)
    assert bus.delays == [50e-6]
    assert bus.trace()[-1] == "R A16 0xFF04 D32 0x00100000"


def test_get_line_reads_input_for_an_input_and_output_for_an_output() -> None:
    bus = _scripted({BASE + 0x04: 0x0000_0020})  # IN5 high
    d = _driver(bus)
    assert d.get_line("j2.amp_fault") is True
    assert d.get_line("j1.amp_fault") is False
    assert d.get_line("j1.amp_enable") is False
    assert bus.trace() == ["R A16 0xFF04 D32 0x00000020", "R A16 0xFF04 D32 0x00000020",
                           "R A16 0xFF08 D32 0x00000000"]


def test_ports_are_in_0_and_out_1() -> None:
    bus = _scripted({BASE + 0x04: 0x1234_5678})
    d = _driver(bus)
    assert d.resolve("j2.amp_fault") == (0, 5) and d.resolve("watchdog") == (1, 16)
    assert d.read_port(0) == 0x1234_5678 and d.read_port("in") == 0x1234_5678
    assert d.read_pins("OUT") == 0
    assert bus.trace() == ["R A16 0xFF04 D32 0x12345678", "R A16 0xFF04 D32 0x12345678",
                           "R A16 0xFF08 D32 0x00000000"]


def test_read_pins_of_the_outputs_takes_looped_back_bits_from_their_inputs() -> None:
    bus = _scripted({BASE + 0x04: 0x0001_0000})  # IN16 high, the loopback of OUT0
    d = _driver(bus, loopback={"OUT0": "IN16", "OUT1": "IN17"})
    d.write_port("OUT", 0x0000_0002)  # latch: OUT1 high, OUT0 low
    assert d.read_pins("OUT") == 0x0000_0001  # the wires: OUT0 high (stuck), OUT1 low
    assert bus.trace() == ["W A16 0xFF08 D32 0x00000002", "R A16 0xFF08 D32 0x00000002",
                           "R A16 0xFF04 D32 0x00010000"]


def test_verify_outputs_reads_the_latch_then_the_loopback_inputs() -> None:
    bus = _scripted({BASE + 0x04: 0x0001_0000})
    d = _driver(bus, loopback={"OUT0": "IN16", "OUT1": "IN17"})
    d.write_port("OUT", 0x0000_0003)
    bus.clear()
    with pytest.raises(LineStuckError) as ei:
        d.verify_outputs()
    assert ei.value.lines == {"j2.amp_enable": False}
    assert bus.trace() == ["R A16 0xFF08 D32 0x00000003", "R A16 0xFF04 D32 0x00010000"]


def test_errors_before_any_cycle() -> None:
    bus = _scripted()
    d = _driver(bus)
    with pytest.raises(LineDirectionError):
        d.set_line("j1.amp_fault", True)
    with pytest.raises(LineDirectionError):
        d.write_port("IN", 1)
    with pytest.raises(UnknownLineError):
        d.resolve("OUT32")
    with pytest.raises(UnknownLineError):
        d.resolve("PA0")
    with pytest.raises(UnknownLineError):
        Vmi2536Driver(bus, BASE, lines={"x": "IN32"})
    with pytest.raises(LineDirectionError):
        Vmi2536Driver(bus, BASE, loopback={"IN0": "OUT0"})
    d.close()
    assert bus.trace() == []


# --- on the emulated board ------------------------------------------------------------------
def _crate() -> tuple[Crate, RecordingBus]:
    c = Crate("t")
    c.install(Vmi2536Board("dio0", lines={"OUT0": "j1.en", "OUT16": "wd", "IN0": "j1.fault"}), base=BASE,
              space="A16", slot=5)
    return c, RecordingBus(c)


def test_on_the_board_configure_then_set_line_drives_the_net_with_the_docs_cycles() -> None:
    c, bus = _crate()
    d = Vmi2536Driver(bus, BASE, lines={"j1.en": "OUT0", "wd": "OUT16"})
    d.configure(outputs=["j1.en", "wd"])
    d.set_line("j1.en", True)
    assert bus.trace() == [*ADOPT, "W A16 0xFF08 D32 0x00000000", "W A16 0xFF02 D16 0xE000",
                           "W A16 0xFF08 D32 0x00000001", "R A16 0xFF08 D32 0x00000001"]
    assert c.signals.get_digital("j1.en") is True and c.signals.get_digital("wd") is False


def test_on_the_board_reset_drops_every_output() -> None:
    c, bus = _crate()
    d = Vmi2536Driver(bus, BASE)
    d.configure(outputs=["OUT0", "OUT16"], initial={"OUT0": True, "OUT16": True})
    assert c.signals.get_digital("j1.en") and c.signals.get_digital("wd")
    d.reset()
    assert not c.signals.get_digital("j1.en") and not c.signals.get_digital("wd")
    c.signals.set_digital("j1.fault", True)
    assert d.get_line("IN0") is False  # inputs off after reset: INPUT reads 0


# --- the dry pass's probe (hal.board_types "vmivme-2536"): reads only ------------------------
def test_the_dry_pass_probe_reads_every_register_at_its_width_and_writes_nothing() -> None:
    bus = _scripted({BASE + 0x02: 0xE000, BASE + 0x04: 0x0000_0009, BASE + 0x08: 0x0001_0000})
    probe = BOARD_TYPES["vmivme-2536"].load_probe()
    assert probe is not None
    reading = probe(bus, BASE, AddressSpace.A16)
    assert bus.trace() == ["R A16 0xFF00 D16 0x2536", "R A16 0xFF02 D16 0xE000", "R A16 0xFF04 D32 0x00000009",
                           "R A16 0xFF08 D32 0x00010000"]
    assert reading.ok and reading.id_read == 0x2536 and reading.id_expected is None
    assert "BID not published" in reading.detail


def test_the_dry_pass_probe_refuses_an_empty_slot_and_the_reference_pio() -> None:
    probe = BOARD_TYPES["vmivme-2536"].load_probe()
    assert probe is not None
    empty = Crate("empty")
    assert not probe(empty, BASE, AddressSpace.A16).ok
    c = Crate("pio")
    c.install(PioBoard("pio0"), base=BASE, space="A16", slot=5)
    reading = probe(c, BASE, AddressSpace.A16)  # ID 0x5001 answers at D16; DDR_A (0x02) is D8 only
    assert not reading.ok and "CSR: BusError" in reading.detail and reading.id_read == 0x5001


def test_read_pins_replaces_only_each_looped_back_bit_at_its_place() -> None:
    bus = _scripted({BASE + 0x04: 0x0010_0000})  # IN20 high, the loopback of OUT5
    d = _driver(bus, loopback={"OUT5": "IN20"})
    d.write_port("OUT", 0x0000_0040)  # latch: OUT6 high (not looped back), OUT5 low
    assert d.read_pins("OUT") == 0x0000_0060  # OUT5's wire is high; OUT6 is the latch's


def test_verify_outputs_lists_each_latch_bit_that_reads_back_wrong_with_its_level() -> None:
    bus = _scripted({BASE + 0x08: 0x0000_000A}, latch=False)  # OUTPUT reads OUT1 and OUT3 high
    d = _driver(bus)
    d.write_port("OUT", 0x0000_0022)  # the driver's copy: OUT1 and OUT5 high
    with pytest.raises(LineStuckError) as ei:
        d.verify_outputs()
    assert ei.value.lines == {"OUT3": True, "OUT5": False}  # stuck high, stuck low


# --- edges and texts ------------------------------------------------------------------------------------
def test_the_dry_pass_probe_reports_each_register_at_its_width() -> None:
    bus = _scripted({BASE + 0x02: 0xE000, BASE + 0x04: 0x0000_0009, BASE + 0x08: 0x0001_0000})
    probe = BOARD_TYPES["vmivme-2536"].load_probe()
    assert probe is not None
    reading = probe(bus, BASE, AddressSpace.A16)
    assert reading.ok is True
    assert reading.detail == ("BID 0x2536; CSR 0xE000; INPUT 0x00000009; OUTPUT 0x00010000 "
                              "(BID not published: not compared)")
    empty = probe(RecordingBus(answers={("A16", BASE): 0x2536}), BASE, AddressSpace.A16)
    assert empty.ok is False and empty.id_read == 0x2536
    assert empty.detail.startswith("BID 0x2536; CSR: BusError: ")


def test_board_id_settle_time_and_loopback_refusals() -> None:
    bus = _scripted()
    for bid in (0x0000, 0xFFFF):
        Vmi2536Driver(bus, BASE, board_id=bid)
    for bid in (-1, 0x10000):
        with pytest.raises(ValueError, match=rf"^board_id {bid} is not a 16-bit BID value$"):
            Vmi2536Driver(bus, BASE, board_id=bid)
    with pytest.raises(ValueError, match=r"^settle_s -1e-06 is not a time ≥ 0$"):
        Vmi2536Driver(bus, BASE, settle_s=-1e-6)
    for out, inp in (("IN0", "IN1"), ("OUT0", "OUT1")):
        with pytest.raises(LineDirectionError, match=rf"^loopback '{out}' → '{inp}': an output is looped back into "
                                                     r"an input$"):
            Vmi2536Driver(bus, BASE, loopback={out: inp})
    with pytest.raises(UnknownLineError, match=r"^wiring table entry 'x' = 'OUT32': 'OUT32' is not a VMIVME-2536 line; "
                                               r"expected IN0\.\.IN31 or OUT0\.\.OUT31$"):
        Vmi2536Driver(bus, BASE, lines={"x": "OUT32"})


def test_without_settle_time_a_loopback_read_does_not_wait() -> None:
    bus = _scripted({BASE + 0x04: 0x0010_0000})
    d = _driver(bus, loopback={"OUT0": "IN20"})
    d.set_line("j1.amp_enable", True)
    assert bus.delays == []


def test_ports_names_and_values_refused_with_their_texts() -> None:
    bus = _scripted({BASE + 0x04: 0x1234_5678})
    d = _driver(bus)
    assert d.read_port("OUT") == 0 and d.read_pins("IN") == 0x1234_5678
    for bad in (2, -1, "X"):
        with pytest.raises(UnknownLineError, match=rf"^unknown VMIVME-2536 port {bad!r}; expected IN or OUT$"):
            d.read_port(bad)
    with pytest.raises(UnknownLineError, match=r"^unknown VMIVME-2536 line 'x': not in the wiring table \(known: "
                                               r"j1\.amp_enable, j1\.amp_fault, j2\.amp_enable, j2\.amp_fault, "
                                               r"watchdog\) and not a pin IN0\.\.IN31 or OUT0\.\.OUT31$"):
        d.resolve("x")
    with pytest.raises(UnknownLineError, match=r"\(known: none\)"):
        Vmi2536Driver(bus, BASE).resolve("x")
    with pytest.raises(LineDirectionError, match=r"^VMIVME-2536 line 'j1\.amp_fault' \(IN0\) is an input$"):
        d.set_line("j1.amp_fault", True)
    with pytest.raises(LineDirectionError, match=r"^the VMIVME-2536 inputs cannot be written$"):
        d.write_port("IN", 1)
    d.write_port("OUT", 0x0000_0000)
    d.write_port("OUT", 0xFFFF_FFFF)
    with pytest.raises(ValueError, match=r"^port value 4294967296 is not 32 bits$"):
        d.write_port("OUT", 0x1_0000_0000)
    with pytest.raises(ValueError, match=r"^port value -1 is not 32 bits$"):
        d.write_port("OUT", -1)
    for pin in ("OUT07", "IN00"):
        with pytest.raises(UnknownLineError):
            d.resolve(pin)
    assert d.resolve("OUT7") == (1, 7) and d.resolve("IN0") == (0, 0)


def test_after_reset_the_next_line_write_starts_from_an_all_low_latch() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.write_port("OUT", 0x0000_00F0)
    d.reset()
    bus.clear()
    d.set_line("j2.amp_enable", True, verify=False)  # OUT1
    assert bus.trace() == ["W A16 0xFF08 D32 0x00000002"]


def test_stuck_lines_report_the_level_they_read() -> None:
    bus = _scripted({BASE + 0x08: 0x0000_0001}, latch=False)  # OUT0 reads high whatever is written
    d = _driver(bus)
    with pytest.raises(LineStuckError) as ei:
        d.set_line("j1.amp_enable", False)
    assert ei.value.lines == {"j1.amp_enable": True}
    bus = _scripted({BASE + 0x04: 0x0001_0000})  # IN16 high: the loopback of OUT1
    d = _driver(bus, loopback={"OUT1": "IN16"})
    with pytest.raises(LineStuckError) as ei:
        d.verify_outputs()
    assert ei.value.lines == {"j2.amp_enable": True}


def test_is_output_is_the_port_of_the_line() -> None:
    d = _driver(_scripted())
    assert [d.is_output(n) for n in ("j1.amp_enable", "watchdog", "j1.amp_fault", "IN31")] == [True, True, False, False]


def test_the_dry_pass_probe_reads_in_the_space_it_is_given() -> None:
    bus = RecordingBus(answers={("A24", 0x80FF00 + o): v for o, v in ((0, 0x2536), (2, 0), (4, 0), (8, 0))})
    probe = BOARD_TYPES["vmivme-2536"].load_probe()
    assert probe is not None
    assert probe(bus, 0x80FF00, AddressSpace.A24).ok is True
    assert bus.trace()[0] == "R A24 0x80FF00 D16 0x2536"


def test_the_dry_pass_probe_of_an_empty_slot_has_read_no_id() -> None:
    probe = BOARD_TYPES["vmivme-2536"].load_probe()
    assert probe is not None
    reading = probe(RecordingBus(answers={}), BASE, AddressSpace.A16)
    assert reading.ok is False and reading.id_read is None and reading.detail.startswith("BID: BusError: ")
