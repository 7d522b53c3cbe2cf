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
from hal.pio import LineDirectionError, LineStuckError, PioBoardIdError, PioDriver, PwmRangeError, UnknownLineError
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


def test_set_pwm_zeroes_the_duty_before_the_direction_line_moves_and_writes_the_line_every_time() -> None:
    # one program whether the direction reverses or not (docs/boards/pio.md): duty (0 on a
    # reversal, else the new duty), the direction line and its read-back, then the duty
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
        "W A16 0x401C D16 0x007D", "W A16 0x4006 D8 0x02", "R A16 0x400A D8 0x02",  # same direction:
        "W A16 0x401C D16 0x007D",  # the new duty (125 ticks) at once, the line written high again
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # reversal: PA1 low
        "W A16 0x401C D16 0x007D",
        "W A16 0x401C D16 0x01F4", "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # −100 %: 500 ticks
        "W A16 0x401C D16 0x01F4",
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
    assert bus.trace() == ["W A16 0x401A D16 0x01F4",
                           "W A16 0x401C D16 0x007D", "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # PA1 low
                           "W A16 0x401C D16 0x007D", "W A16 0x4018 D16 0x0001"]
    assert crate.signals.get_analog("hb1.pwm") == 0.25 and crate.signals.get_digital("hb1.dir") is False


# --- bits other than 0, boundaries, state after reset and close, error texts ---------------------
def test_driver_refuses_an_irq_level_or_vector_the_board_cannot_hold() -> None:
    bus = _scripted()
    for level in (1, 7):
        PioDriver(bus, BASE, irq_level=level)
    for vector in (0x00, 0xFF):
        PioDriver(bus, BASE, vector=vector)
    for level in (0, 8):
        with pytest.raises(ValueError, match=rf"^irq_level {level} is not 1\.\.7$"):
            PioDriver(bus, BASE, irq_level=level)
    for vector in (-1, 0x100):
        with pytest.raises(ValueError, match=rf"^vector {vector} is not an 8-bit status/ID$"):
            PioDriver(bus, BASE, vector=vector)
    with pytest.raises(UnknownLineError, match=r"^wiring table entry 'x' = 'PD0': 'PD0' is not a PIO line; "
                                               r"expected PA0\.\.PA7, PB0\.\.PB7 or PC0\.\.PC7$"):
        PioDriver(bus, BASE, lines={"x": "PD0"})


def test_default_interrupt_word_is_vector_0x60_level_3() -> None:
    bus = _scripted()
    d = PioDriver(bus, BASE)
    bus.clear()
    d.on_change("PB1", lambda n, v: None)  # bit 1 of port B: IER_B 0x02 from a clean start
    assert bus.trace() == ["W A16 0x4013 D8 0x02", "W A16 0x400F D8 0x02", "W A16 0x4016 D16 0x6083"]


def test_on_change_of_lines_adds_their_bits_and_refuses_an_output() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["hb1.dir"])
    bus.clear()
    d.on_change("PB1", lambda n, v: None)
    d.on_change("PB4", lambda n, v: None)
    assert bus.trace()[3:5] == ["W A16 0x4013 D8 0x10", "W A16 0x400F D8 0x12"]  # PB1 kept, PB4 added
    with pytest.raises(LineDirectionError, match=r"^PIO line 'hb1\.dir' is an output; input-change interrupts "
                                                 r"watch inputs only$"):
        d.on_change("hb1.dir", lambda n, v: None)  # PA1, bit 1


def test_on_change_takes_a_port_by_letter_or_p_letter_and_a_wiring_name_first() -> None:
    bus = _scripted()
    d = PioDriver(bus, BASE, lines={"B": "PA3"})
    bus.clear()
    ports: list[tuple[str, int, int]] = []
    d.on_change("PC", lambda p, changed, levels: ports.append((p, changed, levels)))
    d.on_change(" pa ", lambda p, changed, levels: None)
    d.on_change("B", lambda n, v: None)  # the wiring table's line B is PA3, not port B
    assert bus.trace() == [
        "W A16 0x4014 D8 0xFF", "W A16 0x4010 D8 0xFF", "W A16 0x4016 D16 0x6083",  # port C
        "W A16 0x4012 D8 0xFF", "W A16 0x400E D8 0xFF", "W A16 0x4016 D16 0x6083",  # port A
        "W A16 0x4012 D8 0x08", "W A16 0x400E D8 0xFF", "W A16 0x4016 D16 0x6083",  # line B = PA3
    ]


def test_the_handler_serves_port_b_when_port_a_has_nothing_enabled_and_calls_only_changed_lines() -> None:
    bus = _scripted({0x4013: [0x08, 0x00], 0x400B: 0x0A}, wires=False)  # PB3 changed; pins PB1, PB3 high
    d = _driver(bus)
    seen: list[tuple[str, bool]] = []
    d.on_change("PB1", lambda n, v: seen.append((n, v)))
    d.on_change("PB3", lambda n, v: seen.append((n, v)))
    bus.clear()
    handler = bus.irq_handler(0x60)
    assert handler is not None
    handler(0x60)
    assert bus.trace() == ["R A16 0x4013 D8 0x08", "W A16 0x4013 D8 0x08", "R A16 0x400B D8 0x0A"]
    assert seen == [("PB3", True)]


def test_is_output_reads_each_bit_of_the_direction_shadow() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["hb1.dir", "PC7"])
    assert [d.is_output(n) for n in ("amp1.enable", "hb1.dir", "PA2", "PC6", "PC7")] == [
        False, True, False, False, True]


def test_configure_sets_several_initial_levels_of_one_port_and_refuses_one_for_an_input() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["PC1", "PC5"], initial={"PC1": True, "PC5": True})
    assert bus.trace() == ["W A16 0x4006 D8 0x00", "W A16 0x4002 D8 0x00", "W A16 0x4007 D8 0x00",
                           "W A16 0x4003 D8 0x00", "W A16 0x4008 D8 0x22", "W A16 0x4004 D8 0x22"]
    with pytest.raises(LineDirectionError, match=r"^initial level given for 'PC2', which is not in outputs$"):
        d.configure(outputs=["PC1"], initial={"PC2": True})


def test_set_line_on_an_input_names_its_pin_and_a_pin_stuck_high_is_reported_high() -> None:
    bus = _scripted({0x400A: 0x02}, wires=False)  # PA1's wire stays high
    d = _driver(bus)
    with pytest.raises(LineDirectionError, match=r"^PIO line 'amp1\.fault' \(PB0\) is an input; "
                                                 r"list it in configure\(outputs=\.\.\.\) to drive it$"):
        d.set_line("amp1.fault", True)
    d.configure(outputs=["hb1.dir"])
    with pytest.raises(LineStuckError) as ei:
        d.set_line("hb1.dir", False)
    assert ei.value.lines == {"hb1.dir": True}
    assert str(ei.value) == ("output line(s) do not follow their latch: hb1.dir (latch 0, pin 1); the line is stuck "
                             "or shorted — check the wiring and the load before re-enabling")


def test_verify_outputs_lists_each_stuck_output_by_name_or_pin_with_its_pin_level() -> None:
    bus = _scripted({0x400A: 0x02}, wires=False)  # PIN_A: PA1 high, PA2 low
    d = _driver(bus)
    d.configure(outputs=["hb1.dir", "PA2"], initial={"PA2": True})  # latch: PA1 low, PA2 high
    with pytest.raises(LineStuckError) as ei:
        d.verify_outputs()
    assert ei.value.lines == {"hb1.dir": True, "PA2": False}
    assert "hb1.dir (latch 0, pin 1), PA2 (latch 1, pin 0); " in str(ei.value)


def test_unknown_names_and_ports_are_refused_naming_what_is_known() -> None:
    bus = _scripted()
    d = _driver(bus)
    with pytest.raises(UnknownLineError, match=r"^unknown PIO line 'x': not in the wiring table \(known: amp1\.enable, "
                                               r"amp1\.fault, grip\.closed, hb1\.dir\) and not a pin PA0\.\.PC7$"):
        d.resolve("x")
    with pytest.raises(UnknownLineError, match=r"\(known: none\)"):
        PioDriver(bus, BASE).resolve("x")
    assert d.read_port(2) == 0x00
    for bad in (3, -1, "D"):
        with pytest.raises(UnknownLineError, match=rf"^unknown PIO port {bad!r}; expected A, B or C$"):
            d.read_port(bad)


def test_write_port_takes_a_byte_and_set_line_keeps_the_other_bits_it_wrote() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["amp1.enable"])
    d.write_port("A", 0xFF)
    bus.clear()
    d.set_line("amp1.enable", False, verify=False)
    assert bus.trace() == ["W A16 0x4006 D8 0xFE"]
    for bad in (-1, 0x100):
        with pytest.raises(ValueError, match=rf"^port value {bad} is not a byte$"):
            d.write_port("A", bad)


def test_after_reset_every_line_is_an_input_no_interrupt_is_enabled_and_the_period_is_0() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.configure(outputs=["amp1.enable", "PB0", "PC0"])
    d.on_change("PB3", lambda n, v: None)
    d.set_pwm_period(50e-6)
    d.reset()
    assert [d.is_output(n) for n in ("PA0", "PB0", "PC0")] == [False, False, False]
    with pytest.raises(PwmRangeError, match=r"^PWM period is 0 \(output held low\); pass period_s or call "
                                            r"set_pwm_period first$"):
        d.set_pwm(0.5)
    bus.clear()
    for line in ("PA1", "PB1", "PC1"):
        d.on_change(line, lambda n, v: None)
    assert [t for t in bus.trace() if t.startswith(("W A16 0x400E", "W A16 0x400F", "W A16 0x4010"))] == [
        "W A16 0x400E D8 0x02", "W A16 0x400F D8 0x02", "W A16 0x4010 D8 0x02"]
    assert bus.irq_handler(0x60) is not None


def test_after_close_a_new_watch_starts_from_no_enabled_bits_and_registers_the_handler_again() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.on_change("PB0", lambda n, v: None)
    d.close()
    assert bus.irq_handler(0x60) is None
    bus.clear()
    d.on_change("PB1", lambda n, v: None)
    assert bus.trace()[1] == "W A16 0x400F D8 0x02"
    assert bus.irq_handler(0x60) is not None


def test_pwm_limits_and_their_texts() -> None:
    bus = _scripted()
    d = _driver(bus)
    d.set_pwm(0.0, period_s=50e-6)  # no direction line: a zero duty is allowed, a negative one is not
    with pytest.raises(PwmRangeError, match=r"^negative duty -0\.5 needs a direction line \(none configured\)$"):
        d.set_pwm(-0.5)
    with pytest.raises(PwmRangeError, match=r"^PWM duty 1\.5 is outside \[-1, 1\]$"):
        d.set_pwm(1.5)
    with pytest.raises(LineDirectionError, match=r"^PWM direction line 'hb1\.dir' is an input; "
                                                 r"configure it as an output$"):
        d.set_pwm(0.5, direction_line="hb1.dir")  # PA1, bit 1, an input
    d.set_pwm_period(6.5535e-3)  # 65535 ticks, the top
    for bad in (6.5536e-3, float("inf"), float("nan")):
        with pytest.raises(PwmRangeError, match=r"^PWM period .* s is outside 2\.\.65535 ticks of 10 MHz "
                                                r"\(0\.2 µs \.\. 6\.5535 ms\)$"):
            d.set_pwm_period(bad)


def test_pwm_duty_of_a_running_timer_with_period_0_is_0() -> None:
    bus = _scripted({0x4018: 0x0001, 0x401A: 0x0000, 0x401C: 0x0010})
    d = _driver(bus)
    assert d.pwm_duty() == 0.0


def test_a_board_with_another_id_is_named_in_full() -> None:
    bus = _scripted({0x4000: 0xAD16})
    with pytest.raises(PioBoardIdError, match=r"^no parallel I/O board at 0x4000: ID register reads 0xAD16, "
                                              r"expected 0x5001; check the base address in the crate/rig file$"):
        _driver(bus).probe()


def test_the_handler_goes_on_past_a_port_with_nothing_pending() -> None:
    bus = _scripted({0x4012: 0x00, 0x4013: 0x02, 0x400B: 0x02}, wires=False)  # port A quiet, PB1 changed
    d = _driver(bus)
    seen: list[tuple[str, bool]] = []
    d.on_change("PA4", lambda n, v: seen.append((n, v)))
    d.on_change("PB1", lambda n, v: seen.append((n, v)))
    bus.clear()
    handler = bus.irq_handler(0x60)
    assert handler is not None
    handler(0x60)
    assert bus.trace() == ["R A16 0x4012 D8 0x00", "R A16 0x4013 D8 0x02", "W A16 0x4013 D8 0x02",
                           "R A16 0x400B D8 0x02"]
    assert seen == [("PB1", True)]
