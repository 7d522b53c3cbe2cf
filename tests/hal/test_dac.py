"""DAC board: the doc (docs/boards/dac.md) as the spec of both the driver's map and the emulator's
own; registers, double buffering, simultaneous update, settling, range errors and clamping,
calibration, the dead-channel fault and a DAC→ADC loopback through a signals net.

Expected codes and volts are literals from the doc's coding and worked examples, never the
library's conversion functions (the driver's bus cycles: test_dac_traces.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.adc import AdcBoard
from emulators.crate import Crate
from emulators.crate_file import load_crate
from emulators.dac import DacBoard
from hal.adc_dac import (
    DAC_BOARD_ID,
    DAC_REGMAP,
    AdcDriver,
    BoardIdError,
    Calibration,
    DacDriver,
    DacRangeError,
)
from hal.adc_dac.conversions import (
    CODE_MAX,
    CODE_MID,
    DAC_V_MAX,
    DAC_V_MIN,
    dac_code_to_volts,
    dac_volts_to_code,
)
from hal.vme import BusError, BusErrorCause, Width
from tests.support.board_spec import doc_registers, doc_rows, map_differences

BASE = 0x7000
ADC_BASE = 0x6000
DAC_LSB_V = 20.0 / 4096  # 4.8828125 mV (docs/boards/dac.md), the tolerance of the end-to-end checks


def make(**kw) -> tuple[Crate, DacBoard, DacDriver]:
    c = Crate("t")
    board = DacBoard("dac0", wiring={ch: f"out{ch}" for ch in range(8)}, **kw)
    c.install(board, base=BASE, space="A16", slot=6)
    return c, board, DacDriver(c, BASE)


def rd(c: Crate, reg: str) -> int:
    return c.read(BASE + DAC_REGMAP[reg].offset, space="A16", width=Width.D16)


def wr(c: Crate, reg: str, value: int) -> None:
    c.write(BASE + DAC_REGMAP[reg].offset, value, space="A16", width=Width.D16)


def settle(c: Crate) -> None:
    c.delay(50e-6)


# --- codec ------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(v=st.floats(DAC_V_MIN, DAC_V_MAX))
def test_dac_volts_code_volts_round_trip_within_one_lsb(v: float) -> None:
    code, clipped = dac_volts_to_code(v)
    assert not clipped
    assert abs(dac_code_to_volts(code) - v) <= DAC_LSB_V / 2 + 1e-12


@settings(max_examples=200, deadline=None)
@given(code=st.integers(0, CODE_MAX))
def test_dac_code_volts_code_is_identity(code: int) -> None:
    assert dac_volts_to_code(dac_code_to_volts(code)) == (code, False)


def test_dac_offset_binary_scaling() -> None:
    assert dac_volts_to_code(0.0) == (0x800, False)
    assert dac_volts_to_code(-10.0) == (0, False)
    assert dac_volts_to_code(9.9951171875) == (0xFFF, False)
    assert dac_volts_to_code(10.0) == (0xFFF, True)  # +10 V itself is not representable
    assert dac_volts_to_code(-10.01) == (0, True)


# --- the doc is the spec: the driver and the emulator, each checked against it ---------------

def _examples() -> list[tuple[float, int, float]]:
    """The doc's worked examples: (volts, code, output volts)."""
    return [(float(r["volts"].replace("−", "-")), int(r["code"], 16), float(r["output v"].replace("−", "-")))
            for r in doc_rows("dac", "volts", "code", "output V")]


def test_the_driver_register_map_is_the_docs_register_table() -> None:
    assert map_differences(DAC_REGMAP, doc_registers("dac"), who="driver") == []


def test_the_emulator_register_map_is_the_docs_register_table() -> None:
    assert map_differences(DacBoard.REGMAP, doc_registers("dac"), who="emulator") == []


def test_the_driver_converts_the_docs_worked_examples() -> None:
    examples = _examples()
    assert len(examples) == 9
    for v, code, out in examples:
        assert dac_volts_to_code(v) == (code, False), v
        assert dac_code_to_volts(code) == out, code
    assert dac_volts_to_code(10.0) == (0xFFF, True)  # the doc: +10.0 V is out of range


def test_the_emulator_outputs_the_docs_worked_examples() -> None:
    """Each example's code written to DATA5 and strobed with UPDATE bit 5 (the doc's offsets and
    bit): the output pin settles at the example's volts."""
    regs = doc_registers("dac")
    c = Crate("doc")
    board = DacBoard("dac0", wiring={5: "out5"}, settling_time_ns=10_000)
    c.install(board, base=BASE, space="A16")
    for _, code, out in _examples():
        c.write(BASE + regs["DATA5"].offset, code)
        c.write(BASE + regs["UPDATE"].offset, 1 << regs["UPDATE"].fields["CH5"][0])
        c.delay(12e-6)
        assert c.signals.get_analog("out5") == out and board.output_volts(5) == out, code
        assert c.read(BASE + regs["OUT5"].offset) == code


# --- registers --------------------------------------------------------------------------

def test_id_register_and_probe() -> None:
    c, _, _ = make()
    assert rd(c, "ID") == DAC_BOARD_ID
    with pytest.raises(BusError) as ei:
        wr(c, "ID", 1)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BoardIdError, match="expected 0xDA08"):
        DacDriver(_adc_crate(), ADC_BASE)


def _adc_crate() -> Crate:
    c = Crate()
    c.install(AdcBoard("adc"), base=ADC_BASE, space="A16")
    return c


def test_powers_up_at_zero_volts() -> None:
    c, board, dac = make()
    for ch in range(8):
        assert rd(c, f"DATA{ch}") == CODE_MID and dac.read_back_counts(ch) == CODE_MID
        assert c.signals.get_analog(f"out{ch}", default=99.0) == 0.0
        assert board.output_volts(ch) == 0.0


def test_update_register_is_write_only_and_data_keeps_12_bits() -> None:
    c, _, dac = make()
    with pytest.raises(BusError) as ei:
        rd(c, "UPDATE")
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        wr(c, "OUT0", 0)
    assert ei.value.cause is BusErrorCause.ACCESS
    wr(c, "DATA3", 0xFABC)
    assert rd(c, "DATA3") == 0xABC
    assert dac.read_holding_counts(3) == 0xABC


@pytest.mark.parametrize(("offset", "width", "write", "cause"), [
    (0x06, Width.D16, False, BusErrorCause.NO_RESPONDER),  # 0x06-0x0F not decoded
    (0x0E, Width.D16, True, BusErrorCause.NO_RESPONDER),
    (0x11, Width.D8, True, BusErrorCause.UNSUPPORTED_WIDTH),  # D8 only on ID, CSR and UPDATE
    (0x20, Width.D8, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (0x10, Width.D32, True, BusErrorCause.UNSUPPORTED_WIDTH),  # no D32 anywhere
    (0x00, Width.D16, True, BusErrorCause.ACCESS),  # ID is read-only
])
def test_bad_accesses_end_in_the_docs_bus_errors(offset: int, width: Width, write: bool,
                                                  cause: BusErrorCause) -> None:
    c, _, _ = make()
    with pytest.raises(BusError) as ei:
        if write:
            c.write(BASE + offset, 0, space="A16", width=width)
        else:
            c.read(BASE + offset, space="A16", width=width)
    assert ei.value.cause is cause


def test_a_d8_strobe_of_update_bits_7_0_updates_and_of_bits_15_8_does_nothing() -> None:
    c, _, dac = make()
    dac.write_counts(2, 0xA00, update=False)
    c.write(BASE + 0x04, 0xFF, space="A16", width=Width.D8)  # +0x04 holds bits 15:8: no channel
    assert dac.read_back_counts(2) == 0x800
    c.write(BASE + 0x05, 0x04, space="A16", width=Width.D8)  # bit 2: channel 2
    assert dac.read_back_counts(2) == 0xA00


def test_csr_strobes_read_zero() -> None:
    c, _, _ = make()
    wr(c, "CSR", 0x0001)
    assert rd(c, "CSR") & 0x0001 == 0


# --- double buffering -------------------------------------------------------------------------

def test_holding_register_does_not_change_the_output_until_the_strobe() -> None:
    c, board, dac = make()
    res = dac.write_volts(2, 5.0, update=False)
    assert not res.updated
    settle(c)
    assert dac.read_holding_counts(2) == 0xC00  # +5.0 V
    assert dac.read_back_counts(2) == CODE_MID
    assert c.signals.get_analog("out2") == 0.0 and board.output_volts(2) == 0.0
    dac.update([2])
    assert dac.read_back_counts(2) == 0xC00
    settle(c)
    assert c.signals.get_analog("out2") == pytest.approx(5.0, abs=DAC_LSB_V / 2)


def test_write_many_updates_several_channels_with_one_strobe() -> None:
    c, _, dac = make()
    seen: dict[str, int] = {}
    for ch in range(8):
        c.signals.subscribe(f"out{ch}", lambda net, v: seen.setdefault(net, c.clock.now_ns))
    writes0 = c.counter_snapshot().get("write.A16.D16", 0)
    dac.write_many({0: 1.0, 3: -2.0, 7: 9.5})
    assert c.counter_snapshot()["write.A16.D16"] - writes0 == 4  # 3 holding writes + 1 strobe
    settle(c)
    assert set(seen) == {"out0", "out3", "out7"}
    assert len(set(seen.values())) == 1  # all three outputs changed in the same instant
    assert c.signals.get_analog("out3") == pytest.approx(-2.0, abs=DAC_LSB_V / 2)


def test_update_all_strobe() -> None:
    c, _, dac = make()
    for ch in range(8):
        dac.write_volts(ch, ch - 4.0, update=False)
    dac.update()  # CSR.UPDATE_ALL
    settle(c)
    assert [round(c.signals.get_analog(f"out{ch}"), 2) for ch in range(8)] == [ch - 4.0 for ch in range(8)]


def test_output_settles_first_order_and_the_net_sees_the_final_value_after_settling() -> None:
    c, board, dac = make(settling_time_ns=10_000)
    dac.write_volts(1, 8.0)
    t0 = c.clock.now_ns  # the strobe takes effect at the end of its bus cycle
    assert dac.settling
    mid = board.output_volts(1, t0 + 2_000)
    assert 0.0 < mid < 8.0
    assert board.output_volts(1, t0 + 1_000) < mid < board.output_volts(1, t0 + 4_000)
    assert c.signals.get_analog("out1") == 0.0  # not yet
    c.delay(9e-6)
    assert c.signals.get_analog("out1") == 0.0
    assert 7.9 < board.output_volts(1) < 8.0
    c.delay(2e-6)
    assert c.signals.get_analog("out1") == pytest.approx(8.0, abs=DAC_LSB_V / 2)
    assert abs(board.output_volts(1, t0 + 9_999) - board.output_volts(1)) < DAC_LSB_V / 2  # ½ LSB at settling time
    assert not dac.settling


def test_a_newer_strobe_supersedes_a_settling_one() -> None:
    c, _, dac = make(settling_time_ns=10_000)
    dac.write_volts(0, 5.0)
    c.delay(3e-6)
    dac.write_volts(0, -5.0)
    c.delay(8e-6)  # the first strobe's settling time has passed: the net must not show +5 V
    assert c.signals.get_analog("out0") == 0.0
    c.delay(5e-6)
    assert c.signals.get_analog("out0") == pytest.approx(-5.0, abs=DAC_LSB_V / 2)


def test_driver_reset_returns_outputs_to_zero() -> None:
    c, _, dac = make()
    dac.write_many({0: 3.0, 1: -3.0})
    settle(c)
    dac.reset()
    assert c.signals.get_analog("out0") == 0.0 and dac.read_back_counts(1) == CODE_MID


# --- range errors and clamping -------------------------------------------------------------------

@pytest.mark.parametrize("volts", [10.0, -10.01, 12.0, -50.0])
def test_out_of_range_raises_a_typed_error_and_writes_nothing(volts: float) -> None:
    c, _, dac = make()
    writes0 = c.counter_snapshot().get("write.A16.D16", 0)
    with pytest.raises(DacRangeError, match=r"outside the output range.*clamp=True") as ei:
        dac.write_many({0: 1.0, 5: volts})
    assert ei.value.channel == 5 and ei.value.volts == volts
    assert c.counter_snapshot().get("write.A16.D16", 0) == writes0
    with pytest.raises(ValueError, match="NaN"):
        dac.write_volts(0, float("nan"))
    with pytest.raises(ValueError, match="channel 8"):
        dac.write_volts(8, 0.0)


def test_clamp_mode_clamps_and_reports() -> None:
    c = Crate()
    c.install(DacBoard("d", wiring={0: "a", 1: "b"}), base=BASE, space="A16")
    dac = DacDriver(c, BASE, clamp=True)
    res = dac.write_many({0: 12.0, 1: -11.0})
    assert res.clamped == (0, 1) and res.codes == {0: CODE_MAX, 1: 0}
    assert dac.clamp_events == 2
    res = dac.write_volts(0, 1.0)
    assert res.clamped == () and dac.clamp_events == 2
    settle(c)
    assert c.signals.get_analog("b") == pytest.approx(-10.0)


# --- calibration --------------------------------------------------------------------------------

def test_calibration_compensates_offset_and_gain_errors() -> None:
    offs = [0.0, 0.04, 0, 0, 0, 0, 0, 0]
    gerr = [0.0, -0.015, 0, 0, 0, 0, 0, 0]
    c, _, dac = make(offset_v=offs, gain_error=gerr)
    dac.write_volts(1, 6.0)
    settle(c)
    assert c.signals.get_analog("out1") == pytest.approx(6.0 * 0.985 + 0.04, abs=DAC_LSB_V)
    dac.calibration = Calibration(tuple(offs), tuple(1 + g for g in gerr))
    dac.write_volts(1, 6.0)
    settle(c)
    assert c.signals.get_analog("out1") == pytest.approx(6.0, abs=DAC_LSB_V)
    # the range check applies to the calibrated command: 9.9 V needs > full scale on this channel
    with pytest.raises(DacRangeError, match="calibrated command"):
        dac.write_volts(1, 9.9)


# --- fault ------------------------------------------------------------------------------------

def test_dead_channel_fault_is_seen_through_the_loopback() -> None:
    c, board, dac, adc = _loopback()
    dac.write_volts(0, 4.0)
    settle(c)
    board.inject("dead_channel", channel=0)
    assert abs(adc.read_volts(0)) < 2 * DAC_LSB_V  # the driver sees 0 V where it wrote 4 V
    assert dac.read_back_counts(0) == 0xB33  # registers still say 4 V (14 V / 4.8828125 mV = 2867.2)
    dac.write_volts(0, -4.0)
    settle(c)
    assert abs(adc.read_volts(0)) < 2 * DAC_LSB_V
    board.inject("dead_channel", channel=0, volts=-9.0)
    assert adc.read_volts(0) == pytest.approx(-9.0, abs=2 * DAC_LSB_V)
    board.clear_fault("dead_channel")
    assert adc.read_volts(0) == pytest.approx(-4.0, abs=2 * DAC_LSB_V)


# --- loopback ---------------------------------------------------------------------------------------

def _loopback() -> tuple[Crate, DacBoard, DacDriver, AdcDriver]:
    c = Crate("loop")
    c.install(AdcBoard("adc0", wiring={0: "loop0"}, noise_rms_v=1e-3, seed=11), base=ADC_BASE, space="A16")
    board = DacBoard("dac0", wiring={0: "loop0"})
    c.install(board, base=BASE, space="A16")
    return c, board, DacDriver(c, BASE), AdcDriver(c, ADC_BASE)


@pytest.mark.parametrize("volts", [-9.5, -3.3, 0.0, 0.7, 5.0, 9.9])
def test_dac_to_adc_loopback_reads_back_the_written_voltage(volts: float) -> None:
    c, _, dac, adc = _loopback()
    dac.write_volts(0, volts)
    settle(c)
    got = sum(adc.read_volts(0) for _ in range(8)) / 8
    assert got == pytest.approx(volts, abs=1.5 * DAC_LSB_V)


# --- crate file ---------------------------------------------------------------------------------------

def test_crate_file_builds_a_wired_dac(tmp_path: Path) -> None:
    p = tmp_path / "c.toml"
    p.write_text(
        """
[crate]
[[crate.board]]
type = "dac"
name = "dac0"
space = "A16"
base = 0x7000
settling_time_us = 5
gain_error = [0, 0, 0.01, 0, 0, 0, 0, 0]
[crate.board.wiring]
2 = "amp1.cmd"
"""
    )
    c = load_crate(p)
    dac = DacDriver(c, 0x7000)
    dac.write_volts(2, 5.0)
    c.delay(6e-6)
    assert c.signals.get_analog("amp1.cmd") == pytest.approx(5.05, abs=DAC_LSB_V)
    assert c.describe()[0]["type"] == "dac"


# --- the driver's API edges and texts ------------------------------------------------------------

def test_wrong_board_at_the_address_is_named_in_the_id_error() -> None:
    with pytest.raises(BoardIdError, match=r"^no DAC at 0x6000: ID register reads 0xAD16, expected 0xDA08; "
                                           r"check the base address in the crate/rig file$"):
        DacDriver(_adc_crate(), ADC_BASE)
    c, _, dac = make()
    assert dac.bus is c
    with pytest.raises(ValueError, match=r"^DAC calibration has 4 channels, the board has 8$"):
        DacDriver(c, BASE, calibration=Calibration.identity(4))


def test_channel_and_raw_code_ranges() -> None:
    *_, dac = make()
    for bad in (-1, 8):
        with pytest.raises(ValueError, match=rf"^DAC channel {bad} is not 0\.\.7$"):
            dac.write_counts(bad, 0x800)
    dac.write_counts(7, 0x000)  # both ends of the 12 bits are codes
    assert dac.read_holding_counts(7) == 0x000
    dac.write_counts(7, 0xFFF, update=False)
    assert dac.read_holding_counts(7) == 0xFFF
    for bad in (-1, 0x1000):
        with pytest.raises(ValueError, match=rf"^DAC code {bad} is outside 0\.\.0xFFF$"):
            dac.write_counts(0, bad)


def test_write_result_says_whether_an_update_strobe_was_written() -> None:
    *_, dac = make()
    assert dac.write_many({0: 1.0}).updated is True
    assert dac.write_many({0: 1.0}, update=False).updated is False
    assert dac.write_many({}).updated is False  # nothing loaded: no strobe


def test_range_error_names_the_command_and_the_calibrated_command() -> None:
    e = DacRangeError(3, 12.0, 12.0)
    assert (e.channel, e.volts, e.command_v) == (3, 12.0, 12.0)
    assert str(e) == ("DAC channel 3: +12.0000 V is outside the output range -10.0000..+9.9951 V; "
                      "limit the command upstream or open the driver with clamp=True")
    e = DacRangeError(1, 9.9, 10.02)
    assert e.command_v == 10.02
    assert str(e) == ("DAC channel 1: +9.9000 V (calibrated command +10.0200 V) is outside the output range "
                      "-10.0000..+9.9951 V; limit the command upstream or open the driver with clamp=True")
