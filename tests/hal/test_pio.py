"""Parallel I/O board: registers, directions, nets, change interrupt, PWM, faults, driver."""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.crate_file import build_crate
from emulators.pio import PioBoard
from hal.config import ConfigError, ConfigTable
from hal.pio import (
    PIO_REGS,
    LineDirectionError,
    LineStuckError,
    PioDriver,
    PwmRangeError,
    UnknownLineError,
    pio_regs,
)
from hal.vme import AddressSpace, BusError, BusErrorCause, Width
from hal.vme.registers import RegisterMap
from tests.support.board_spec import doc_registers, map_differences
from vmehil.commands.crate import probe_all

BASE = 0x4000
WIRING = {
    "amp1.enable": "PA0",
    "hb1.dir": "PA1",
    "hb1.brake": "PA2",
    "amp1.fault": "PB0",
    "grip.open": "PB1",
    "grip.closed": "PC7",
}
NETS = {"PA0": "amp1.en", "PA1": "hb1.dir", "PA2": "hb1.brake", "PB0": "amp1.fault", "PB1": "grip.open",
        "PC7": "grip.closed"}


@pytest.fixture
def rig() -> tuple[Crate, PioBoard, PioDriver]:
    c = Crate("pio-test")
    b = PioBoard("pio0", lines=NETS, pwm_net="hb1.pwm")
    c.install(b, base=BASE, space="A16", slot=4)
    d = PioDriver(c, BASE, lines=WIRING, pwm_direction_line="hb1.dir", vector=0x61, irq_level=4)
    return c, b, d


#: offset and width of each register, from docs/boards/pio.md (not from either map under test)
_D8, _D16 = Width.D8, Width.D16
REGS = {
    "ID": (0x00, _D16), "DDR_A": (0x02, _D8), "DDR_B": (0x03, _D8), "DDR_C": (0x04, _D8),
    "DATA_A": (0x06, _D8), "DATA_B": (0x07, _D8), "DATA_C": (0x08, _D8),
    "PIN_A": (0x0A, _D8), "PIN_B": (0x0B, _D8), "PIN_C": (0x0C, _D8),
    "IER_A": (0x0E, _D8), "IER_B": (0x0F, _D8), "IER_C": (0x10, _D8),
    "ICS_A": (0x12, _D8), "ICS_B": (0x13, _D8), "ICS_C": (0x14, _D8),
    "INT_CTL": (0x16, _D16), "PWM_CTL": (0x18, _D16), "PWM_PERIOD": (0x1A, _D16), "PWM_DUTY": (0x1C, _D16),
    "PWM_COUNT": (0x1E, _D16),
}


def _r(c: Crate, reg: str) -> int:
    offset, width = REGS[reg]
    return c.read(BASE + offset, space="A16", width=width)


def _w(c: Crate, reg: str, value: int) -> None:
    offset, width = REGS[reg]
    c.write(BASE + offset, value, space="A16", width=width)


# --- registers ---------------------------------------------------------------------------
def test_id_is_the_first_readable_register_and_the_crate_probe_reads_it(rig) -> None:
    c, _, _ = rig
    assert _r(c, "ID") == 0x5001
    (probe,) = probe_all(c)
    assert probe["ok"] and probe["value"] == "0x5001" and probe["width"] == "D16"
    with pytest.raises(BusError) as ei:
        _w(c, "ID", 0)
    assert ei.value.cause is BusErrorCause.ACCESS


def test_port_registers_are_d8_and_pin_registers_read_only(rig) -> None:
    c, _, _ = rig
    with pytest.raises(BusError) as ei:
        c.read(BASE + 0x02, space="A16", width=Width.D16)  # DDR_A
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH
    with pytest.raises(BusError) as ei:
        _w(c, "PIN_B", 0xFF)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        c.read(BASE + 0x05, space="A16", width=Width.D8)  # hole between DDR_C and DATA_A
    assert ei.value.cause is BusErrorCause.NO_RESPONDER


def test_power_up_state_all_inputs_pwm_off(rig) -> None:
    c, _, _ = rig
    for p in "ABC":
        assert _r(c, f"DDR_{p}") == 0 and _r(c, f"IER_{p}") == 0 and _r(c, f"ICS_{p}") == 0
    assert _r(c, "PWM_CTL") == 0 and c.signals.get_analog("hb1.pwm", -1.0) == 0.0
    assert "amp1.en" not in c.signals.digital  # nothing driven


def test_outputs_drive_nets_inputs_read_nets_and_data_mixes_latch_and_pins(rig) -> None:
    c, _, _ = rig
    _w(c, "DATA_A", 0b101)
    _w(c, "DDR_A", 0b011)  # PA0, PA1 outputs; PA2 input
    assert c.signals.get_digital("amp1.en") is True and c.signals.get_digital("hb1.dir") is False
    assert "hb1.brake" not in c.signals.digital  # an input does not drive its net
    c.signals.set_digital("hb1.brake", False)
    assert _r(c, "DATA_A") == 0b001  # latch for outputs, pin (0) for the input although latch bit 2 = 1
    assert _r(c, "PIN_A") == 0b001
    c.signals.set_digital("hb1.brake", True)
    assert _r(c, "DATA_A") == 0b101 and _r(c, "PIN_A") == 0b101
    c.signals.set_digital("amp1.fault", True)
    assert _r(c, "DATA_B") == 0b01 and _r(c, "PIN_B") == 0b01
    assert _r(c, "DATA_C") == 0  # unwired inputs float low


def test_stale_latch_drives_when_a_line_becomes_output_like_the_68230(rig) -> None:
    c, _, _ = rig
    _w(c, "DATA_A", 0x01)  # written while PA0 is an input: stored in the latch
    assert "amp1.en" not in c.signals.digital
    _w(c, "DDR_A", 0x01)
    assert c.signals.get_digital("amp1.en") is True  # the stale latch appears on the wire


def test_driver_configure_never_drives_a_stale_latch(rig) -> None:
    c, _, d = rig
    _w(c, "DATA_A", 0xFF)  # somebody left the latch high
    seen: list[bool] = []
    c.signals.subscribe("amp1.en", lambda n, v: seen.append(v))
    d.configure(outputs=["amp1.enable", "hb1.dir"], initial={"hb1.dir": True})
    assert seen == [False]
    assert c.signals.get_digital("hb1.dir") is True
    assert d.is_output("amp1.enable") and not d.is_output("amp1.fault")
    assert _r(c, "DDR_A") == 0b011 and _r(c, "DDR_B") == 0 and _r(c, "DDR_C") == 0


def test_driver_named_lines_and_ports(rig) -> None:
    c, _, d = rig
    d.configure(outputs=["amp1.enable", "hb1.brake"])
    d.set_line("amp1.enable", True)
    assert c.signals.get_digital("amp1.en") and d.get_line("amp1.enable")
    d.set_line("PA2", True)  # pin names work too
    assert c.signals.get_digital("hb1.brake")
    c.signals.set_digital("grip.closed", True)
    assert d.get_line("grip.closed") and not d.get_line("grip.open")
    assert d.read_port("C") == 0x80 and d.read_pins("PC") == 0x80
    d.write_port("A", 0x00)
    assert not c.signals.get_digital("amp1.en") and d.read_port(0) == 0


def test_driver_typed_errors(rig) -> None:
    _, _, d = rig
    d.configure(outputs=["amp1.enable"])
    with pytest.raises(UnknownLineError, match=r"amp9\.enable.*known: amp1\.enable"):
        d.set_line("amp9.enable", True)
    with pytest.raises(UnknownLineError):
        d.get_line("PD0")
    with pytest.raises(LineDirectionError, match="is an input"):
        d.set_line("amp1.fault", True)
    with pytest.raises(LineDirectionError, match="output"):
        d.on_change("amp1.enable", lambda n, v: None)
    with pytest.raises(UnknownLineError):
        PioDriver(d.bus, BASE, lines={"x": "PZ9"})
    with pytest.raises(UnknownLineError):
        d.read_port("D")
    with pytest.raises(LineDirectionError):
        d.configure(outputs=["amp1.enable"], initial={"hb1.dir": True})


# --- input-change interrupt --------------------------------------------------------------
def test_change_interrupt_calls_the_line_callback_through_its_vector(rig) -> None:
    c, b, d = rig
    d.configure(outputs=["amp1.enable"])
    seen: list[tuple[str, bool]] = []
    d.on_change("amp1.fault", lambda name, level: seen.append((name, level)))
    assert c.irq_handler(0x61) is not None
    assert _r(c, "INT_CTL") == 0x6100 | 0x80 | 4
    c.signals.set_digital("amp1.fault", True)  # the amplifier trips
    c.delay(0)  # interrupts are taken at the next bus cycle or delay
    assert seen == [("amp1.fault", True)]
    assert c.counter_snapshot()["iack.IRQ4"] == 1
    assert not b.irq_pending and _r(c, "ICS_B") == 0
    c.signals.set_digital("amp1.fault", False)
    c.delay(0)
    assert seen[-1] == ("amp1.fault", False)


def test_change_status_is_w1c_and_the_request_is_held_until_cleared(rig) -> None:
    c, b, _ = rig
    _w(c, "IER_B", 0x03)
    _w(c, "INT_CTL", 0x7000 | 0x80 | 2)
    c.irq.ipl = 7  # mask the CPU to look at the board
    c.signals.set_digital("amp1.fault", True)
    c.signals.set_digital("grip.open", True)
    assert _r(c, "ICS_B") == 0x03 and b.irq_pending
    _w(c, "ICS_B", 0x01)  # clear one bit: the other still requests
    assert _r(c, "ICS_B") == 0x02 and b.irq_pending
    _w(c, "ICS_B", 0x02)
    assert _r(c, "ICS_B") == 0 and not b.irq_pending


def test_disabled_lines_latch_status_but_do_not_interrupt(rig) -> None:
    c, b, _ = rig
    _w(c, "INT_CTL", 0x7000 | 0x80 | 2)
    c.signals.set_digital("grip.closed", True)
    assert _r(c, "ICS_C") == 0x80 and not b.irq_pending
    c.irq.ipl = 7
    _w(c, "IER_C", 0x80)  # enabling with a stale status bit interrupts at once (real boards do)
    assert b.irq_pending


def test_driver_clears_stale_status_before_enabling(rig) -> None:
    c, _, d = rig
    c.signals.set_digital("grip.closed", True)  # stale change before anyone listens
    seen: list[tuple[str, bool]] = []
    d.on_change("grip.closed", lambda n, v: seen.append((n, v)))
    c.delay(0)
    assert seen == []
    c.signals.set_digital("grip.closed", False)
    c.delay(0)
    assert seen == [("grip.closed", False)]


def test_port_callback_gets_changed_mask_and_levels(rig) -> None:
    c, _, d = rig
    seen: list[tuple[str, int, int]] = []
    d.on_change("B", lambda port, changed, levels: seen.append((port, changed, levels)))
    c.irq.ipl = 7
    c.signals.set_digital("amp1.fault", True)
    c.signals.set_digital("grip.open", True)
    c.irq.ipl = 0
    c.delay(0)
    assert seen == [("B", 0x03, 0x03)]
    d.close()
    c.signals.set_digital("amp1.fault", False)
    c.delay(0)
    assert len(seen) == 1 and c.irq_handler(0x61) is None


def test_output_and_direction_changes_are_not_input_changes(rig) -> None:
    c, _, _ = rig
    c.signals.set_digital("amp1.en", True)  # net high while PA0 is an input
    _w(c, "ICS_A", 0xFF)
    _w(c, "DDR_A", 0x01)  # now an output driving 0
    _w(c, "DATA_A", 0x01)
    _w(c, "DATA_A", 0x00)
    assert _r(c, "ICS_A") == 0


# --- PWM ---------------------------------------------------------------------------------
def test_pwm_registers_publish_the_duty_fraction(rig) -> None:
    c, b, _ = rig
    _w(c, "PWM_PERIOD", 500)  # 50 µs: 20 kHz
    _w(c, "PWM_DUTY", 125)
    assert c.signals.get_analog("hb1.pwm") == 0.0  # not enabled
    _w(c, "PWM_CTL", 1)
    assert c.signals.get_analog("hb1.pwm") == pytest.approx(0.25)
    _w(c, "PWM_DUTY", 600)  # duty >= period: 100 %
    assert c.signals.get_analog("hb1.pwm") == 1.0
    _w(c, "PWM_PERIOD", 0)  # period 0 holds the output low
    assert c.signals.get_analog("hb1.pwm") == 0.0
    assert b.duty_fraction() == 0.0


def test_pwm_counter_runs_on_the_10mhz_clock(rig) -> None:
    c, _, _ = rig
    _w(c, "PWM_PERIOD", 1000)
    _w(c, "PWM_CTL", 1)
    for delay in (0.0, 30e-6, 77.7e-6, 1e-3):
        c.delay(delay)
        v = _r(c, "PWM_COUNT")  # the board answers at the end of the cycle
        assert v == (c.clock.now_ns // 100) % 1000
    _w(c, "PWM_CTL", 0)
    assert _r(c, "PWM_COUNT") == 0


def test_set_pwm_sign_sets_direction_and_magnitude_sets_duty(rig) -> None:
    c, _, d = rig
    d.configure(outputs=["hb1.dir", "hb1.brake"])
    d.set_pwm(0.4, period_s=50e-6)
    d.pwm_enable(True)
    assert _r(c, "PWM_PERIOD") == 500 and _r(c, "PWM_DUTY") == 200
    assert c.signals.get_digital("hb1.dir") is True and c.signals.get_analog("hb1.pwm") == pytest.approx(0.4)
    d.set_pwm(-1.0)
    assert c.signals.get_digital("hb1.dir") is False and c.signals.get_analog("hb1.pwm") == 1.0
    assert d.pwm_duty() == 1.0
    d.pwm_enable(False)
    assert c.signals.get_analog("hb1.pwm") == 0.0 and d.pwm_duty() == 0.0


def test_reversal_zeroes_duty_before_the_direction_line_moves(rig) -> None:
    c, _, d = rig
    d.configure(outputs=["hb1.dir"])
    d.set_pwm(0.8, period_s=50e-6)
    d.pwm_enable(True)
    log: list[tuple[str, object]] = []
    c.signals.subscribe("hb1.pwm", lambda n, v: log.append((n, v)))
    c.signals.subscribe("hb1.dir", lambda n, v: log.append((n, v)))
    d.set_pwm(-0.5)
    assert log == [("hb1.pwm", 0.0), ("hb1.dir", False), ("hb1.pwm", 0.5)]


def test_pwm_range_errors(rig) -> None:
    _, _, d = rig
    d.configure(outputs=["hb1.dir"])
    with pytest.raises(PwmRangeError, match="period is 0"):
        d.set_pwm(0.5)
    for bad in (1.01, -2.0, float("nan")):
        with pytest.raises(PwmRangeError):
            d.set_pwm(bad, period_s=50e-6)
    with pytest.raises(PwmRangeError, match="6.5535 ms"):
        d.set_pwm_period(10e-3)
    d2 = PioDriver(d.bus, BASE, lines=WIRING)
    d2.set_pwm_period(50e-6)
    with pytest.raises(PwmRangeError, match="direction line"):
        d2.set_pwm(-0.5)
    with pytest.raises(LineDirectionError):
        d2.set_pwm(0.5, direction_line="amp1.fault")


# --- faults ------------------------------------------------------------------------------
def test_stuck_output_is_invisible_in_data_but_seen_by_the_driver(rig) -> None:
    c, b, d = rig
    d.configure(outputs=["amp1.enable"])
    b.inject("line_stuck", line="PA0", level=False)
    with pytest.raises(LineStuckError, match=r"amp1\.enable"):
        d.set_line("amp1.enable", True)
    assert c.signals.get_digital("amp1.en") is False  # the wire stays low
    assert d.get_line("amp1.enable") is True  # DATA_A reads the latch: looks fine
    with pytest.raises(LineStuckError) as ei:
        d.verify_outputs()
    assert ei.value.lines == {"amp1.enable": False}
    b.clear_fault("line_stuck")
    assert c.signals.get_digital("amp1.en") is True
    d.verify_outputs()


def test_stuck_input_reads_the_stuck_level_and_its_onset_is_a_change(rig) -> None:
    c, b, d = rig
    seen: list[tuple[str, bool]] = []
    d.on_change("amp1.fault", lambda n, v: seen.append((n, v)))
    b.inject("line_stuck", line="PB0", level=True)
    c.delay(0)
    assert seen == [("amp1.fault", True)] and d.get_line("amp1.fault")
    c.signals.set_digital("amp1.fault", False)  # the net moves, the stuck pin does not
    c.delay(0)
    assert d.get_line("amp1.fault") and len(seen) == 1
    with pytest.raises(ValueError, match="not a PIO line"):
        b.inject("line_stuck", line="PQ1", level=True)


# --- crate file --------------------------------------------------------------------------
def test_crate_file_builds_a_wired_pio_board() -> None:
    cfg = ConfigTable({"crate": {"name": "r", "board": [{
        "type": "pio", "name": "pio0", "space": "A16", "base": 0x4000,
        "lines": {"PA0": "amp1.en", "pb0": "amp1.fault"}, "pwm_net": "hb1.pwm"}]}}, "<test>")
    c = build_crate(cfg)
    b = c.board("pio0")
    assert isinstance(b, PioBoard) and b.describe()["lines"] == {"PA0": "amp1.en", "PB0": "amp1.fault"}
    d = PioDriver(c, 0x4000, lines={"en": "PA0"})
    d.configure(outputs=["en"])
    d.set_line("en", True)
    assert c.signals.get_digital("amp1.en")
    bad = ConfigTable({"crate": {"board": [{"type": "pio", "name": "p", "space": "A16", "base": 0x4000,
                                            "lines": {"PD0": "x"}}]}}, "<test>")
    with pytest.raises(ConfigError, match="PD0"):
        build_crate(bad)


# --- the doc is the spec: both maps checked against its table ------------------------------
def test_doc_register_table_states_every_register_of_the_board() -> None:
    doc = doc_registers("pio")
    assert {name: (r.offset, r.width) for name, r in doc.items()} == {
        name: (offset, width.name) for name, (offset, width) in REGS.items()}
    assert doc["ID"].reset == 0x5001 and doc["ICS_B"].access == "RW1C" and doc["PIN_C"].reset is None
    assert doc["INT_CTL"].fields == {"vector": (8, 8), "ien": (7, 1), "level": (0, 3)}


def test_driver_register_map_matches_the_doc() -> None:
    assert map_differences(PIO_REGS, doc_registers("pio"), who="hal.pio") == []


def test_pin_names_are_p_port_and_bit_0_to_7() -> None:
    assert [pio_regs.parse_line(p) for p in ("PA0", " pb3 ", "PC7")] == [(0, 0), (1, 3), (2, 7)]
    for bad in ("PAX", "PA8", "PD0", "PA", "PA00", "QA0"):
        with pytest.raises(ValueError, match=rf"^{bad!r} is not a PIO line; expected PA0\.\.PA7, PB0\.\.PB7 "
                                             r"or PC0\.\.PC7$"):
            pio_regs.parse_line(bad)


def test_port_register_builder_gives_the_doc_s_fifteen_port_registers() -> None:
    # PIO_REGS is built at import, before any test; calling the builder here checks what it
    # makes as it runs now (a mutation tester's changes to it take effect only so)
    doc = {n: r for n, r in doc_registers("pio").items() if n.split("_")[0] in ("DDR", "DATA", "PIN", "IER", "ICS")}
    built = pio_regs._port_regs()
    assert len(built) == len(doc) == 15
    ports = RegisterMap("pio ports", 0x20, AddressSpace.A16, tuple(built))
    assert map_differences(ports, doc, who="hal.pio._port_regs") == []


def test_emulator_register_map_matches_the_doc() -> None:
    assert map_differences(PioBoard.REGMAP, doc_registers("pio"), who="emulators.pio") == []


def test_bad_accesses_end_in_berr_as_the_doc_lists(rig) -> None:
    c, _, _ = rig
    cases = [  # (read or write, offset, width, cause) from the doc's "What a bad access does"
        ("r", 0x05, Width.D8, BusErrorCause.NO_RESPONDER), ("r", 0x09, Width.D8, BusErrorCause.NO_RESPONDER),
        ("r", 0x0D, Width.D8, BusErrorCause.NO_RESPONDER), ("r", 0x11, Width.D8, BusErrorCause.NO_RESPONDER),
        ("r", 0x15, Width.D8, BusErrorCause.NO_RESPONDER),
        ("r", 0x00, Width.D8, BusErrorCause.UNSUPPORTED_WIDTH), ("r", 0x01, Width.D8, BusErrorCause.UNSUPPORTED_WIDTH),
        ("r", 0x06, Width.D16, BusErrorCause.UNSUPPORTED_WIDTH), ("r", 0x18, Width.D8, BusErrorCause.UNSUPPORTED_WIDTH),
        ("w", 0x18, Width.D32, BusErrorCause.UNSUPPORTED_WIDTH),
        ("w", 0x0A, Width.D8, BusErrorCause.ACCESS), ("w", 0x1E, Width.D16, BusErrorCause.ACCESS),
    ]
    for op, offset, width, cause in cases:
        with pytest.raises(BusError) as ei:
            if op == "r":
                c.read(BASE + offset, space="A16", width=width)
            else:
                c.write(BASE + offset, 0, space="A16", width=width)
        assert ei.value.cause is cause, (op, hex(offset), width)
    assert _r(c, "PWM_PERIOD") == 0  # the refused write changed nothing


def test_unused_control_bits_are_ignored_on_write_and_read_zero(rig) -> None:
    c, b, _ = rig
    _w(c, "INT_CTL", 0x6178)  # vector 0x61, bits 6:3 set, ien 0, level 0
    assert _r(c, "INT_CTL") == 0x6100 and not b.irq_pending
    _w(c, "PWM_CTL", 0xFFFE)  # every bit but enable
    assert _r(c, "PWM_CTL") == 0


def test_probe_reads_the_id_of_the_emulated_board(rig) -> None:
    _, _, d = rig
    assert d.probe() == 0x5001


def test_reset_returns_the_board_to_its_power_up_state(rig) -> None:
    c, b, d = rig
    d.configure(outputs=["amp1.enable", "hb1.dir"], initial={"amp1.enable": True})
    d.on_change("amp1.fault", lambda n, v: None)
    d.set_pwm(0.5, period_s=50e-6)
    d.pwm_enable(True)
    d.reset()
    for reg in REGS:
        if reg not in ("ID", "PWM_COUNT") and not reg.startswith("PIN_"):
            assert _r(c, reg) == 0, reg
    assert c.signals.get_digital("amp1.en") is False and c.signals.get_analog("hb1.pwm") == 0.0
    assert c.irq_handler(0x61) is None and not b.irq_pending
