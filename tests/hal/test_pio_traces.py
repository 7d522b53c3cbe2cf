"""Golden bus traces of the parallel I/O driver (hal.pio.PioDriver), written by hand from
docs/boards/pio.md: the register table (offsets from the base, D8 port registers, D16 control
words), the driver's cycle table ("The driver") and the PWM worked values.

The board sits at 0x4000 in A16, so e.g. DATA_A (0x06) is ``0x4006`` and PWM_DUTY (0x1C) is
``0x401C``. Most tests run the driver alone on a scripted bus; two forward to an emulated crate
with the PIO board installed (the interrupt path and the PWM net).
"""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.pio import PioBoard
from hal.pio import LineStuckError, PioBoardIdError, PioDriver, PwmRangeError
from hal.vme.types import AddressModifier, Width
from tests.support.bus_trace import Answer, RecordingBus

BASE = 0x4000
WIRING = {"amp1.enable": "PA0", "hb1.dir": "PA1", "amp1.fault": "PB0", "grip.closed": "PC7"}

#: the driver's constructor adopts the board's state: DDR_A..C, DATA_A..C, PWM_PERIOD (doc)
ADOPT = [
    "R A16 0x4002 D8 0x00", "R A16 0x4003 D8 0x00", "R A16 0x4004 D8 0x00",
    "R A16 0x4006 D8 0x00", "R A16 0x4007 D8 0x00", "R A16 0x4008 D8 0x00",
    "R A16 0x401A D16 0x0000",
]


class _WiredBus(RecordingBus):
    """A scripted bus that also remembers the last value written to each address (kept across
    :meth:`clear`), so a PIN_x answer can follow its DATA_x latch like a healthy wire."""

    def __init__(self, answers: dict[tuple[str, int], Answer]) -> None:
        super().__init__(answers=answers)
        self.written: dict[int, int] = {}

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        super()._write(am, address, width, value)
        self.written[address] = value


def _scripted(answers: dict[int, Answer] | None = None, *, wires: bool = True) -> _WiredBus:
    """A scripted bus answering the board's registers with 0 (the power-up state) unless
    ``answers`` (address → answer) says otherwise; PIN_x follow DATA_x writes when ``wires``."""
    box: list[_WiredBus] = []
    script: dict[int, Answer] = {a: 0 for a in (0x4002, 0x4003, 0x4004, 0x4006, 0x4007, 0x4008, 0x400E, 0x400F,
                                                 0x4010, 0x4012, 0x4013, 0x4014, 0x4016, 0x4018, 0x401A, 0x401C)}
    script[0x4000] = 0x5001
    if wires:  # PIN_A/B/C (0x0A..0x0C) follow DATA_A/B/C (0x06..0x08)
        def follows(data: int) -> Answer:
            return lambda _n: box[0].written.get(data, 0)

        for pin, data in ((0x400A, 0x4006), (0x400B, 0x4007), (0x400C, 0x4008)):
            script[pin] = follows(data)
    script.update(answers or {})
    bus = _WiredBus({("A16", a): v for a, v in script.items()})
    box.append(bus)
    return bus


def _driver(bus: _WiredBus, *, vector: int = 0x60, irq_level: int = 3,
            pwm_direction_line: str | None = None) -> PioDriver:
    d = PioDriver(bus, BASE, lines=WIRING, vector=vector, irq_level=irq_level, pwm_direction_line=pwm_direction_line)
    bus.clear()
    return d


# --- construction, probe, reset ------------------------------------------------------------
def test_constructor_adopts_the_boards_directions_latches_and_period_by_reads_only() -> None:
    bus = _scripted({0x4002: 0x03, 0x4006: 0x05, 0x401A: 0x01F4})
    d = PioDriver(bus, BASE, lines=WIRING)
    assert bus.trace() == [
        "R A16 0x4002 D8 0x03", "R A16 0x4003 D8 0x00", "R A16 0x4004 D8 0x00",
        "R A16 0x4006 D8 0x05", "R A16 0x4007 D8 0x00", "R A16 0x4008 D8 0x00",
        "R A16 0x401A D16 0x01F4",
    ]
    bus.clear()
    # the adopted latch is DATA_A & DDR_A = 0x01 (bit 2 read 1 but PA2 is an input): PA1 high → 0x03
    d.set_line("hb1.dir", True, verify=False)
    assert bus.trace() == ["W A16 0x4006 D8 0x03"]


def test_probe_reads_the_id_register() -> None:
    bus = _scripted()
    d = _driver(bus)
    assert d.probe() == 0x5001
    assert bus.trace() == ["R A16 0x4000 D16 0x5001"]


def test_probe_refuses_a_board_with_another_id() -> None:
    bus = _scripted({0x4000: 0xDA08})  # a DAC board's ID at the PIO's base
    d = _driver(bus)
    with pytest.raises(PioBoardIdError, match=r"0xDA08.*0x5001"):
        d.probe()
    assert bus.trace() == ["R A16 0x4000 D16 0xDA08"]


def test_reset_stops_the_pwm_and_interrupt_then_drives_latches_low_before_making_inputs() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.reset()
    assert bus.trace() == [
        "W A16 0x4018 D16 0x0000",  # PWM_CTL: stop
        "W A16 0x401C D16 0x0000",  # PWM_DUTY
        "W A16 0x401A D16 0x0000",  # PWM_PERIOD
        "W A16 0x4016 D16 0x0000",  # INT_CTL: interrupt off, level 0
        "W A16 0x400E D8 0x00", "W A16 0x400F D8 0x00", "W A16 0x4010 D8 0x00",  # IER_A..C
        "W A16 0x4012 D8 0xFF", "W A16 0x4013 D8 0xFF", "W A16 0x4014 D8 0xFF",  # ICS_A..C: clear all
        "W A16 0x4006 D8 0x00", "W A16 0x4007 D8 0x00", "W A16 0x4008 D8 0x00",  # DATA_A..C: latches low
        "W A16 0x4002 D8 0x00", "W A16 0x4003 D8 0x00", "W A16 0x4004 D8 0x00",  # DDR_A..C: all inputs
    ]


# --- lines -----------------------------------------------------------------------------------
def test_configure_loads_each_ports_latch_before_its_direction() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["amp1.enable", "hb1.dir", "PC3"], initial={"hb1.dir": True, "PC3": True})
    assert bus.trace() == [
        "W A16 0x4006 D8 0x02", "W A16 0x4002 D8 0x03",  # port A: latch PA1 high, then PA0, PA1 outputs
        "W A16 0x4007 D8 0x00", "W A16 0x4003 D8 0x00",  # port B: all inputs
        "W A16 0x4008 D8 0x08", "W A16 0x4004 D8 0x08",  # port C: PC3
    ]


def test_set_line_writes_the_whole_latch_from_the_drivers_copy_then_reads_the_pin() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["amp1.enable", "hb1.dir"], initial={"hb1.dir": True})
    bus.clear()
    d.set_line("amp1.enable", True)
    d.set_line("hb1.dir", False)
    d.set_line("amp1.enable", False, verify=False)
    assert bus.trace() == [
        "W A16 0x4006 D8 0x03", "R A16 0x400A D8 0x03",  # PA0 high, PA1 stays high; PIN_A read back
        "W A16 0x4006 D8 0x01", "R A16 0x400A D8 0x01",
        "W A16 0x4006 D8 0x00",  # no verify: the write alone
    ]


def test_set_line_raises_when_the_pin_does_not_follow_the_latch() -> None:
    bus = _scripted({0x400A: 0x00}, wires=False)  # PA0's wire stays low
    d = _driver(bus)
    d.configure(outputs=["amp1.enable"])
    bus.clear()
    with pytest.raises(LineStuckError, match=r"amp1\.enable \(latch 1, pin 0\)"):
        d.set_line("amp1.enable", True)
    assert bus.trace() == ["W A16 0x4006 D8 0x01", "R A16 0x400A D8 0x00"]


def test_get_line_read_port_read_pins_and_write_port() -> None:
    bus = _scripted({0x4007: 0x01, 0x400C: 0x80}, wires=False)
    d = _driver(bus)
    assert d.get_line("amp1.fault") is True
    assert d.read_port("B") == 0x01
    assert d.read_pins("PC") == 0x80
    d.write_port("C", 0x5A)
    assert bus.trace() == ["R A16 0x4007 D8 0x01", "R A16 0x4007 D8 0x01", "R A16 0x400C D8 0x80",
                           "W A16 0x4008 D8 0x5A"]


def test_verify_outputs_reads_the_pins_of_the_ports_with_outputs_only() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["amp1.enable", "PC2"], initial={"PC2": True})
    bus.clear()
    d.verify_outputs()
    assert bus.trace() == ["R A16 0x400A D8 0x00", "R A16 0x400C D8 0x04"]


# --- input-change interrupt -------------------------------------------------------------------
def test_on_change_clears_stale_status_then_enables_the_line_then_the_interrupt() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.on_change("amp1.fault", lambda n, v: None)
    d.on_change("grip.closed", lambda n, v: None)
    assert bus.trace() == [
        "W A16 0x4013 D8 0x01", "W A16 0x400F D8 0x01", "W A16 0x4016 D16 0x6083",  # vector 0x60, ien, level 3
        "W A16 0x4014 D8 0x80", "W A16 0x4010 D8 0x80", "W A16 0x4016 D16 0x6083",
    ]


def test_interrupt_control_word_carries_the_drivers_vector_and_level() -> None:
    bus = _scripted()
    d = _driver(bus, vector=0x61, irq_level=4)
    d.on_change("B", lambda p, changed, levels: None)  # a whole port: every input bit of port B
    d.close()
    assert bus.trace() == [
        "W A16 0x4013 D8 0xFF", "W A16 0x400F D8 0xFF", "W A16 0x4016 D16 0x6184",
        "W A16 0x4016 D16 0x6104",  # close: ien 0, vector and level kept
        "W A16 0x400E D8 0x00", "W A16 0x400F D8 0x00", "W A16 0x4010 D8 0x00",
    ]


def test_interrupt_handler_reads_status_clears_exactly_those_bits_and_reads_the_pins() -> None:
    bus = _scripted({0x4013: [0x03, 0x00], 0x400B: 0x01}, wires=False)  # PB0 and PB1 changed
    d = _driver(bus)
    seen: list[tuple[str, bool]] = []
    d.on_change("amp1.fault", lambda n, v: seen.append((n, v)))
    bus.clear()
    handler = bus.irq_handler(0x60)
    assert handler is not None
    handler(0x60)
    handler(0x60)  # nothing pending any more: the status read alone
    assert bus.trace() == [
        "R A16 0x4013 D8 0x03", "W A16 0x4013 D8 0x01", "R A16 0x400B D8 0x01",  # only the enabled PB0
        "R A16 0x4013 D8 0x00",
    ]
    assert seen == [("amp1.fault", True)]


def test_interrupt_path_on_the_emulated_board() -> None:
    crate = Crate("pio-trace")
    crate.install(PioBoard("pio0", lines={"PB0": "amp1.fault"}), base=BASE, space="A16", slot=4)
    bus = RecordingBus(crate)
    d = PioDriver(bus, BASE, lines=WIRING, vector=0x61, irq_level=4)
    seen: list[tuple[str, bool]] = []
    d.on_change("amp1.fault", lambda n, v: seen.append((n, v)))
    bus.clear()
    crate.signals.set_digital("amp1.fault", True)  # the amplifier trips: PB0 rises
    bus.delay(0)  # the crate takes the interrupt at the next cycle or delay
    assert bus.trace() == ["R A16 0x4013 D8 0x01", "W A16 0x4013 D8 0x01", "R A16 0x400B D8 0x01"]
    assert seen == [("amp1.fault", True)]


# --- PWM ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(("period_s", "duty", "period_word", "duty_word"), [
    (50e-6, 0.4, "0x01F4", "0x00C8"),
    (100e-6, 0.123, "0x03E8", "0x007B"),
    (0.2e-6, 0.5, "0x0002", "0x0001"),
    (6.5535e-3, 1.0, "0xFFFF", "0xFFFF"),
])
def test_set_pwm_writes_period_and_duty_ticks_of_the_docs_worked_values(period_s, duty, period_word,
                                                                          duty_word) -> None:
    bus = _scripted()
    d = _driver(bus)  # no direction line: positive duties only
    d.set_pwm(duty, period_s=period_s)
    assert bus.trace() == [f"W A16 0x401A D16 {period_word}", f"W A16 0x401C D16 {duty_word}"]


def test_set_pwm_zeroes_the_duty_before_the_direction_line_moves() -> None:
    bus = _scripted()
    d = _driver(bus, pwm_direction_line="hb1.dir")
    d.configure(outputs=["hb1.dir"])
    bus.clear()
    d.set_pwm(0.4, period_s=50e-6)
    d.set_pwm(0.25)
    d.set_pwm(-0.25)
    d.set_pwm(-1.0)
    d.set_pwm(0.0)
    assert bus.trace() == [
        "W A16 0x401A D16 0x01F4",
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0x02", "R A16 0x400A D8 0x02",  # forward: PA1 high
        "W A16 0x401C D16 0x00C8",  # 200 ticks = 40 %
        "W A16 0x401C D16 0x007D",  # same direction: the duty alone (125 ticks)
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # reversal: PA1 low
        "W A16 0x401C D16 0x007D",
        "W A16 0x401C D16 0x01F4",  # −100 %: 500 ticks
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0x02", "R A16 0x400A D8 0x02",  # zero counts as forward
        "W A16 0x401C D16 0x0000",
    ]


def test_pwm_period_outside_the_timer_makes_no_cycle() -> None:
    bus = _scripted()
    d = _driver(bus)
    for bad in (0.1e-6, 6.6e-3):
        with pytest.raises(PwmRangeError):
            d.set_pwm_period(bad)
    assert bus.trace() == []


def test_pwm_enable_and_the_duty_read_back() -> None:
    bus = _scripted({0x4018: [0x0001, 0x0001, 0x0000], 0x401A: 0x01F4, 0x401C: 0x00C8})
    d = _driver(bus)
    d.pwm_enable(True)
    assert d.pwm_duty() == 0.4
    d.pwm_enable(False)
    assert d.pwm_duty() == 0.4  # the script still answers enabled for the second read
    assert d.pwm_duty() == 0.0
    assert bus.trace() == [
        "W A16 0x4018 D16 0x0001",
        "R A16 0x4018 D16 0x0001", "R A16 0x401A D16 0x01F4", "R A16 0x401C D16 0x00C8",
        "W A16 0x4018 D16 0x0000",
        "R A16 0x4018 D16 0x0001", "R A16 0x401A D16 0x01F4", "R A16 0x401C D16 0x00C8",
        "R A16 0x4018 D16 0x0000",  # stopped: no period or duty read
    ]


def test_pwm_on_the_emulated_board_publishes_the_duty_fraction() -> None:
    crate = Crate("pio-trace")
    crate.install(PioBoard("pio0", lines={"PA1": "hb1.dir"}, pwm_net="hb1.pwm"), base=BASE, space="A16", slot=4)
    bus = RecordingBus(crate)
    d = PioDriver(bus, BASE, lines=WIRING, pwm_direction_line="hb1.dir")
    d.configure(outputs=["hb1.dir"])
    bus.clear()
    d.set_pwm(-0.25, period_s=50e-6)
    d.pwm_enable(True)
    assert bus.trace() == ["W A16 0x401A D16 0x01F4", "W A16 0x401C D16 0x007D", "W A16 0x4018 D16 0x0001"]
    assert crate.signals.get_analog("hb1.pwm") == 0.25 and crate.signals.get_digital("hb1.dir") is False
