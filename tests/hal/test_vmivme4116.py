"""VMIC VMIVME-4116: the doc (docs/boards/vmivme4116.md) as the spec of both the driver's map and
the emulator's own; coding, update modes, the P3 connection, settling, bad accesses, the reset
state and the driver's zero-output path (the safe stop's "DAC at 0 V"), faults, and the crate
entry the jpl-arm-vmic preset needs.

Expected codes and volts are literals from the doc's coding and worked examples, never the
library's conversion functions (the driver's bus cycles: test_vmivme4116_traces.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from emulators.adc import AdcBoard
from emulators.board_types import BUILTIN_BOARD_TYPES as EMULATOR_TYPES
from emulators.crate import Crate
from emulators.crate_file import load_crate
from emulators.vmivme4116 import VmiVme4116Board, vmivme4116_factory
from hal.adc_dac import (
    VMI4116_REGMAP,
    AdcDriver,
    Calibration,
    DacRangeError,
    VmiVme4116Driver,
    probe_vmivme4116,
)
from hal.adc_dac.vmivme4116 import vmi4116_code_to_volts, vmi4116_volts_to_code
from hal.board_types import BOARD_TYPES
from hal.vme import BusError, BusErrorCause, Width
from tests.support.board_spec import doc_registers, doc_rows, map_differences

BASE = 0x7000
LSB_V = 20.0 / 65536  # 305.17578125 µV (the doc), the tolerance of the end-to-end checks
# The doc's register offsets, written out: CHANn at 2·n, CSR at 0x10; CSR bits 14 LED_OFF,
# 9 START_CONVERT, 8 AO_P3.
CSR = 0x10


def make(**kw) -> tuple[Crate, VmiVme4116Board]:
    c = Crate("t")
    board = VmiVme4116Board("dac0", wiring={ch: f"out{ch}" for ch in range(8)}, **kw)
    c.install(board, base=BASE, space="A16", slot=4)
    return c, board


def nets(c: Crate) -> list[float]:
    return [c.signals.get_analog(f"out{ch}", default=99.0) for ch in range(8)]


def settle(c: Crate) -> None:
    c.delay(20e-6)  # two settling times


def _num(text: str) -> float:
    return float(text.replace("−", "-"))


def _examples() -> list[tuple[float, int, int, float]]:
    """The doc's worked examples: (volts, offset-binary code, two's complement code, output V)."""
    return [(_num(r["volts"]), int(r["code"], 16), int(r["two's complement"], 16), _num(r["output v"]))
            for r in doc_rows("vmivme4116", "volts", "code", "two's complement", "output V")]


# --- the doc is the spec: the driver and the emulator, each checked against it ---------------------

def test_the_driver_register_map_is_the_docs_register_table() -> None:
    assert map_differences(VMI4116_REGMAP, doc_registers("vmivme4116"), who="driver") == []


def test_the_emulator_register_map_is_the_docs_register_table() -> None:
    assert map_differences(VmiVme4116Board.REGMAP, doc_registers("vmivme4116"), who="emulator") == []


def test_the_docs_register_table_states_the_sources_layout() -> None:
    """The doc table itself against the sources' struct (chan[8]; csr) and CSR bits, as literals."""
    regs = doc_registers("vmivme4116")
    assert {n: r.offset for n, r in regs.items()} == {**{f"CHAN{n}": 2 * n for n in range(8)}, "CSR": 0x10}
    assert regs["CSR"].fields == {"LED_OFF": (14, 1), "AOTESTBS": (13, 1), "AINTESTBS": (12, 1), "TESTBUS": (11, 1),
                                  "START_CONVERT": (9, 1), "AO_P3": (8, 1)}


def test_the_driver_converts_the_docs_worked_examples() -> None:
    examples = _examples()
    assert len(examples) == 9
    for v, code, code_2c, out in examples:
        assert vmi4116_volts_to_code(v) == (code, False), v
        assert vmi4116_volts_to_code(v, "twos_complement") == (code_2c, False), v
        assert vmi4116_code_to_volts(code) == out and vmi4116_code_to_volts(code_2c, "twos_complement") == out
    assert vmi4116_volts_to_code(10.0) == (0xFFFF, True)  # the doc: +10.0 V is one code past 0xFFFF
    assert vmi4116_volts_to_code(-10.1) == (0x0000, True)


@pytest.mark.parametrize("coding", ["offset_binary", "twos_complement"])
def test_the_emulator_outputs_the_docs_worked_examples(coding: str) -> None:
    """Each example's code written to CHAN5 (+0x0A) and strobed with CSR 0x4300 (LED_OFF,
    START_CONVERT, AO_P3): the output pin settles at the example's volts."""
    c = Crate("doc")
    board = VmiVme4116Board("dac0", wiring={5: "out5"}, coding=coding)
    c.install(board, base=BASE, space="A16")
    for _, code, code_2c, out in _examples():
        c.write(BASE + 0x0A, code if coding == "offset_binary" else code_2c)
        c.write(BASE + CSR, 0x4300)
        c.delay(12e-6)
        assert c.signals.get_analog("out5") == out and board.output_volts(5) == out, hex(code)


# --- registers and bad accesses ---------------------------------------------------------------------

def test_csr_reads_back_its_control_bits_and_start_convert_reads_zero() -> None:
    c, _ = make()
    assert c.read(BASE + CSR) == 0x0000  # power-up: fail LED on, outputs disconnected
    c.write(BASE + CSR, 0xFFFF)
    assert c.read(BASE + CSR) == 0x7900  # bits 14, 13, 12, 11, 8; START_CONVERT and unnamed bits read 0


def test_a_channel_register_read_answers_but_never_returns_the_code() -> None:
    c, _ = make()
    c.write(BASE + 0x04, 0x1234)
    assert c.read(BASE + 0x04) == 0xFFFF  # the doc: undefined data, the emulator's 0xFFFF


@pytest.mark.parametrize(("offset", "width", "write", "cause"), [
    (0x12, Width.D16, False, BusErrorCause.NO_RESPONDER),  # unused[7]: 0x12..0x1F
    (0x1E, Width.D16, True, BusErrorCause.NO_RESPONDER),
    (0x10, Width.D8, False, BusErrorCause.UNSUPPORTED_WIDTH),  # D16 only
    (0x03, Width.D8, True, BusErrorCause.UNSUPPORTED_WIDTH),
    (0x00, Width.D32, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (0x10, Width.D32, True, BusErrorCause.UNSUPPORTED_WIDTH),
])
def test_bad_accesses_end_in_the_docs_bus_errors(offset: int, width: Width, write: bool,
                                                  cause: BusErrorCause) -> None:
    c, _ = make()
    with pytest.raises(BusError) as ei:
        if write:
            c.write(BASE + offset, 0, space="A16", width=width)
        else:
            c.read(BASE + offset, space="A16", width=width)
    assert ei.value.cause is cause


# --- reset state ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("coding", "zero_code"), [("offset_binary", 0x8000), ("twos_complement", 0x0000)])
def test_powers_up_at_zero_volts_disconnected_with_the_fail_led_on(coding: str, zero_code: int) -> None:
    c, board = make(coding=coding)
    assert nets(c) == [0.0] * 8
    assert not board.connected and board.fail_led_on
    assert board.converter == [zero_code] * 8 and board.holding == [zero_code] * 8
    assert [board.converter_volts(ch) for ch in range(8)] == [0.0] * 8
    assert c.read(BASE + CSR) == 0x0000


def test_a_sysreset_while_running_returns_every_output_to_zero_volts_and_disconnects() -> None:
    c, board = make()
    dac = VmiVme4116Driver(c, BASE)
    dac.write_many({ch: 1.0 + ch for ch in range(8)})
    settle(c)
    assert nets(c)[7] == pytest.approx(8.0, abs=LSB_V)
    board.reset()
    assert nets(c) == [0.0] * 8 and not board.connected
    assert board.converter == [0x8000] * 8 and c.read(BASE + CSR) == 0x0000


# --- the driver: bring-up, zero path, update modes ------------------------------------------------------

def test_opening_the_driver_zeroes_then_connects_so_the_amplifiers_never_see_a_stale_code() -> None:
    """Latches left at +7 V by an earlier user, outputs disconnected: opening the driver must
    not put 7 V on any amplifier, not even for an instant."""
    c, board = make()
    for ch in range(8):
        c.write(BASE + 2 * ch, 0xD999)  # +7.0 V
    c.write(BASE + CSR, 0x0200)  # START_CONVERT alone: the converters hold +7 V, P3 still off
    settle(c)
    assert nets(c) == [0.0] * 8 and board.converter_volts(0) == pytest.approx(7.0, abs=LSB_V)
    seen: list[float] = []
    for ch in range(8):
        c.signals.subscribe(f"out{ch}", lambda net, v, seen=seen: seen.append(v))
    dac = VmiVme4116Driver(c, BASE)
    # at the instant of connection the converters have settled from +7 V to within ½ LSB of 0 V
    assert board.connected and all(abs(board.output_volts(ch)) <= LSB_V / 2 for ch in range(8))
    settle(c)
    assert board.connected and not board.fail_led_on
    assert board.converter == [0x8000] * 8 and nets(c) == [0.0] * 8
    assert all(v == 0.0 for v in seen)
    assert [dac.read_back_counts(ch) for ch in range(8)] == [0x8000] * 8


@pytest.mark.parametrize("update", ["synchronized", "immediate"])
def test_zero_drives_every_output_to_zero_volts(update: str) -> None:
    c, board = make(update=update)
    dac = VmiVme4116Driver(c, BASE, synchronized=update == "synchronized")
    dac.write_many({0: 9.0, 1: -9.0, 2: 2.5, 3: -2.5, 4: 1.0, 5: -1.0, 6: 5.0, 7: -5.0})
    settle(c)
    assert nets(c)[0] == pytest.approx(9.0, abs=LSB_V) and nets(c)[7] == pytest.approx(-5.0, abs=LSB_V)
    dac.zero()
    settle(c)
    assert nets(c) == [0.0] * 8  # the plant's side: every amplifier command net
    assert board.converter == [0x8000] * 8 and board.connected  # the board's own state
    assert [dac.read_back_counts(ch) for ch in range(8)] == [0x8000] * 8


def test_the_servos_stop_write_reaches_zero_volts_through_a_calibration() -> None:
    """The servo's stop writes 0.0 V to every channel with write_many (calibration applied):
    each output then sits at its calibrated 0 V code and the net reads 0 V within ½ LSB."""
    offsets = [0.004, -0.003, 0.002, 0.005, -0.004, 0.003, -0.008, 0.01]
    c, board = make(offset_v=offsets)
    dac = VmiVme4116Driver(c, BASE, calibration=Calibration(offset_v=tuple(offsets), gain=(1.0,) * 8))
    dac.write_many({ch: 3.0 for ch in range(8)})
    dac.write_many({ch: 0.0 for ch in range(8)})
    settle(c)
    for ch in range(8):
        assert abs(nets(c)[ch]) <= LSB_V / 2 + 1e-12, ch
        assert dac.read_back_counts(ch) == dac.code_for(ch, 0.0)[0] == board.converter[ch]


def test_synchronized_update_changes_nothing_until_the_strobe_then_every_channel_at_once() -> None:
    c, board = make()
    dac = VmiVme4116Driver(c, BASE)
    dac.write_many({0: 2.5, 3: -2.0}, update=False)
    settle(c)
    assert nets(c)[0] == 0.0 and nets(c)[3] == 0.0 and dac.read_back_counts(0) == 0x8000
    dac.update()
    c.delay(11e-6)
    assert nets(c)[0] == 2.5 and nets(c)[3] == -2.0001220703125
    assert board.converter[0] == 0xA000 and board.converter[3] == 0x6666


def test_immediate_update_reaches_the_output_on_the_write() -> None:
    c, board = make(update="immediate")
    dac = VmiVme4116Driver(c, BASE, synchronized=False)
    dac.write_volts(2, 5.0, update=False)
    c.delay(11e-6)
    assert nets(c)[2] == 5.0 and board.converter[2] == 0xC000 and dac.read_back_counts(2) == 0xC000
    c.write(BASE + CSR, 0x4300)  # START_CONVERT does nothing in immediate mode
    assert board.updates == 9  # the open's eight channel writes, then this one


def test_output_settles_first_order_and_the_net_sees_the_final_value_after_settling() -> None:
    c, board = make()
    dac = VmiVme4116Driver(c, BASE)
    dac.write_volts(1, 10.0 - LSB_V)  # full scale from 0 V
    c.delay(5e-6)
    mid = board.output_volts(1)
    assert 9.0 < mid < 10.0 - LSB_V and nets(c)[1] == 0.0
    c.delay(5e-6)
    assert abs(board.output_volts(1) - (10.0 - LSB_V)) <= LSB_V / 2  # within ½ LSB at the settling time
    assert nets(c)[1] == 10.0 - LSB_V


def test_disconnect_takes_the_outputs_off_p3() -> None:
    c, board = make()
    dac = VmiVme4116Driver(c, BASE)
    dac.write_volts(0, 4.0)
    settle(c)
    dac.disconnect()
    assert nets(c)[0] == 0.0 and not board.connected and board.fail_led_on
    assert board.converter[0] == 0xB333  # the converter still holds its code


def test_out_of_range_raises_a_typed_error_and_writes_nothing() -> None:
    c, board = make()
    dac = VmiVme4116Driver(c, BASE)
    with pytest.raises(DacRangeError, match=r"channel 1: \+10.00000 V is outside the output range -10.00000"):
        dac.write_many({0: 1.0, 1: 10.0})
    assert board.holding == [0x8000] * 8
    dac.clamp = True
    result = dac.write_many({0: 12.0, 1: -11.0})
    assert result.clamped == (0, 1) and result.codes == {0: 0xFFFF, 1: 0x0000} and dac.clamp_events == 2


def test_a_board_that_stops_answering_cannot_be_read_back() -> None:
    c, board = make()
    dac = VmiVme4116Driver(c, BASE)
    board.inject("removed")
    with pytest.raises(BusError):
        dac.read_back_counts(0)


def test_probe_reads_the_csr_and_a_missing_board_is_refused() -> None:
    c, _ = make()
    assert probe_vmivme4116(c, BASE).detail == "no ID register (VMIVME-4116); CSR 0x0000"
    assert not probe_vmivme4116(c, 0x7100).ok
    with pytest.raises(BusError):
        VmiVme4116Driver(c, 0x7100)


def test_both_board_type_tables_name_the_4116_as_a_dac() -> None:
    bt = BOARD_TYPES["vmivme-4116"]
    assert (bt.role, bt.vendor, bt.model, bt.document) == ("dac", "VMIC", "VMIVME-4116", "docs/boards/vmivme4116.md")
    assert bt.load_driver() is VmiVme4116Driver and bt.channels() == 8
    assert bt.load_probe() is probe_vmivme4116 and bt.id_register() is None  # no ID register
    assert EMULATOR_TYPES["vmivme-4116"] is vmivme4116_factory


# --- fault ------------------------------------------------------------------------------------------

def test_dead_channel_fault_is_seen_through_an_adc_loopback() -> None:
    c = Crate("loop")
    board = VmiVme4116Board("dac0", wiring={0: "loop0"})
    c.install(board, base=BASE, space="A16")
    c.install(AdcBoard("adc0", wiring={0: "loop0"}), base=0x6000, space="A16")
    dac, adc = VmiVme4116Driver(c, BASE), AdcDriver(c, 0x6000)
    dac.write_volts(0, 3.0)
    settle(c)
    assert adc.read_volts(0) == pytest.approx(3.0, abs=0.01)
    board.inject("dead_channel", channel=0, volts=-9.0)
    assert adc.read_volts(0) == pytest.approx(-9.0, abs=0.01)
    assert dac.read_back_counts(0) == 0x8000 + round(3.0 / LSB_V)  # the driver cannot see it
    board.clear_fault("dead_channel")
    assert adc.read_volts(0) == pytest.approx(3.0, abs=0.01)


# --- the crate entry of the jpl-arm-vmic preset ------------------------------------------------------------

PRESET_SNIPPET = """
[crate]
[[crate.board]]
type = "vmivme-4116"
name = "dac0"                    # amplifier commands (0..5); 6, 7 loop back to adc1
slot = 4
space = "A16"
base = 0x7000                    # a 32-byte boundary
update = "synchronized"          # the board's update jumper: all joints' commands in one instant
coding = "offset_binary"
offset_v = [0.004, -0.003, 0.002, 0.005, -0.004, 0.003, -0.008, 0.01]
gain_error = [0.001, -0.002, 0.0015, 0.0, -0.001, 0.002, 0.003, -0.002]
[crate.board.wiring]             # what vmehil adds from [joint.wiring] amp_command = "dac0:N"
0 = "j1.amp_command"
5 = "j6.amp_command"
6 = "loop.dac0.6"
"""


def test_the_preset_snippet_builds_a_crate_the_driver_runs(tmp_path: Path) -> None:
    p = tmp_path / "rig.toml"
    p.write_text(PRESET_SNIPPET)
    c = load_crate(p)
    desc = c.describe()[0]
    assert (desc["type"], desc["vendor"], desc["model"], desc["document"]) == (
        "vmivme-4116", "VMIC", "VMIVME-4116", "docs/boards/vmivme4116.md")
    assert Path(__file__).resolve().parents[2].joinpath(desc["document"]).is_file()
    dac = VmiVme4116Driver(c, 0x7000, clamp=True)
    dac.write_many({0: 2.0, 5: -2.0})
    settle(c)
    assert c.signals.get_analog("j1.amp_command") == pytest.approx(2.0 * 1.001 + 0.004, abs=LSB_V)
    assert c.signals.get_analog("j6.amp_command") == pytest.approx(-2.0 * 1.002 + 0.003, abs=LSB_V)
    dac.zero()
    settle(c)
    assert c.signals.get_analog("j1.amp_command") == 0.004  # the board's own offset at the 0 V code
