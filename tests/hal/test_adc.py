"""ADC board: the doc (docs/boards/adc.md) as the spec of both the driver's map and the emulator's
own; register behaviour, conversion timing, flags, interrupts, scan, front end, faults,
calibration — the driver (hal.adc_dac.adc) against the emulator (emulators.adc) in a crate.

Expected codes and volts are literals from the doc's formula and worked examples (by hand), never
the library's conversion functions (the driver's bus cycles: test_adc_traces.py)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.adc import AdcBoard
from emulators.crate import Crate
from emulators.crate_file import load_crate
from emulators.faults import UnknownFaultError
from emulators.ram import RamBoard
from hal.adc_dac import (
    ADC_BOARD_ID,
    ADC_REGMAP,
    AdcDriver,
    AdcRange,
    AdcTimeoutError,
    BoardIdError,
    Calibration,
    CalibrationError,
)
from hal.adc_dac.conversions import (
    ADC_GAINS,
    CODE_MAX,
    CODE_MID,
    adc_code_to_volts,
    adc_codes_to_volts,
    adc_lsb,
    adc_span,
    adc_volts_to_code,
    dac_code_to_volts,
    dac_volts_to_code,
    gain_code,
    gain_from_code,
)
from hal.config import ConfigError
from hal.vme import BusError, BusErrorCause, Width
from tests.support.board_spec import doc_registers, doc_rows, map_differences

BASE = 0x6000
LSB = 20.0 / 4096  # ±10 V at gain 1: 4.8828125 mV (docs/boards/adc.md)
CSR = ADC_REGMAP["CSR"]
BIT = {f.name: f.mask for f in CSR.fields}


def make(noise: float = 0.0, seed: int = 1, **kw) -> tuple[Crate, AdcBoard, AdcDriver]:
    c = Crate("t")
    wiring = {ch: f"in{ch}" for ch in range(16)}
    board = AdcBoard("adc0", wiring=wiring, noise_rms_v=noise, seed=seed, **kw)
    c.install(board, base=BASE, space="A16", slot=5)
    return c, board, AdcDriver(c, BASE)


def rd(c: Crate, reg: str) -> int:
    return c.read(BASE + ADC_REGMAP[reg].offset, space="A16", width=Width.D16)


def wr(c: Crate, reg: str, value: int) -> None:
    c.write(BASE + ADC_REGMAP[reg].offset, value, space="A16", width=Width.D16)


def start(c: Crate) -> None:
    c.write(BASE + 3, BIT["START"], space="A16", width=Width.D8)


# --- conversions (shared codec) -----------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(rng=st.sampled_from(list(AdcRange)), gain=st.sampled_from(ADC_GAINS), frac=st.floats(0.0, 1.0))
def test_adc_volts_code_volts_round_trip_within_one_lsb(rng: AdcRange, gain: int, frac: float) -> None:
    v0, v1 = adc_span(rng, gain)
    v = v0 + frac * (v1 - v0)
    code = adc_volts_to_code(v, rng, gain)
    assert 0 <= code <= CODE_MAX
    assert abs(adc_code_to_volts(code, rng, gain) - v) <= 0.5 * adc_lsb(rng, gain) + 1e-12
    assert adc_codes_to_volts([code], rng, gain)[0] == pytest.approx(adc_code_to_volts(code, rng, gain))


@settings(max_examples=200, deadline=None)
@given(rng=st.sampled_from(list(AdcRange)), gain=st.sampled_from(ADC_GAINS), code=st.integers(0, CODE_MAX))
def test_adc_code_volts_code_is_identity(rng: AdcRange, gain: int, code: int) -> None:
    assert adc_volts_to_code(adc_code_to_volts(code, rng, gain), rng, gain) == code


@settings(max_examples=300, deadline=None)
@given(rng=st.sampled_from(list(AdcRange)), gain=st.sampled_from(ADC_GAINS),
       volts=st.floats(-30.0, 30.0, allow_nan=False))
def test_adc_volts_to_code_is_the_docs_formula(rng: AdcRange, gain: int, volts: float) -> None:
    # docs/boards/adc.md: FS = 10 V/gain; ±10 V: V0 = -FS, LSB = 2·FS/4096; 0..10 V: V0 = 0, LSB = FS/4096
    fs = 10.0 / gain
    v0, lsb = (-fs, 2 * fs / 4096) if rng is AdcRange.BIPOLAR_10V else (0.0, fs / 4096)
    expected = min(max(math.floor((volts - v0) / lsb + 0.5), 0), 0xFFF)
    assert adc_volts_to_code(volts, rng, gain) == expected


def test_adc_volts_to_code_refuses_a_gain_outside_the_table() -> None:
    with pytest.raises(ValueError, match="gain"):
        adc_volts_to_code(1.0, AdcRange.BIPOLAR_10V, 3)


def test_adc_scaling_and_clipping_rules() -> None:
    b = AdcRange.BIPOLAR_10V
    u = AdcRange.UNIPOLAR_10V
    assert adc_volts_to_code(0.0, b) == 0x800  # offset binary
    assert adc_volts_to_code(-10.0, b) == 0
    assert adc_volts_to_code(10.0, b) == 0xFFF  # +FS is one LSB beyond the last code: saturates
    assert adc_volts_to_code(25.0, b) == 0xFFF and adc_volts_to_code(-25.0, b) == 0
    assert adc_volts_to_code(1.25, b, 8) == 0xFFF  # ±1.25 V at gain 8
    assert adc_volts_to_code(-0.5, u) == 0 and adc_volts_to_code(5.0, u) == 2048
    assert adc_lsb(b, 1) == pytest.approx(20 / 4096) and adc_lsb(u, 4) == pytest.approx(2.5 / 4096)
    with pytest.raises(ValueError, match="gain"):
        adc_lsb(b, 3)
    with pytest.raises(ValueError, match="NaN"):
        adc_volts_to_code(float("nan"), b)


# --- the doc is the spec: the driver and the emulator, each checked against it -------------

_RANGES = {"±10 V": AdcRange.BIPOLAR_10V, "0..10 V": AdcRange.UNIPOLAR_10V}


def _volts(cell: str) -> float:
    return float(cell.replace("−", "-"))


def _examples() -> list[tuple[AdcRange, int, float, int, float]]:
    """The doc's worked examples: (range, gain, input volts, code, code centre volts)."""
    rows = doc_rows("adc", "range", "gain", "input V", "code", "code centre V")
    return [(_RANGES[r["range"]], int(r["gain"]), _volts(r["input v"]), int(r["code"], 16), _volts(r["code centre v"]))
            for r in rows]


def _doc_gain_codes() -> dict[int, int]:
    """The doc's gain table: gain → gain code."""
    return {int(r["gain"]): int(r["gain code"]) for r in doc_rows("adc", "gain code", "gain")}


def test_conversions_default_to_gain_1_and_refuse_nan_and_codes_beyond_12_bits() -> None:
    # docs/boards/adc.md: ±10 V at gain 1, LSB 20 V / 4096; 0..10 V, LSB 10 V / 4096
    assert adc_code_to_volts(0xC00, AdcRange.BIPOLAR_10V) == 5.0
    assert adc_lsb(AdcRange.BIPOLAR_10V) == 20.0 / 4096
    assert adc_span(AdcRange.BIPOLAR_10V) == (-10.0, 10.0 - 20.0 / 4096)
    assert adc_span(AdcRange.UNIPOLAR_10V) == (0.0, 10.0 - 10.0 / 4096)
    with pytest.raises(ValueError, match=r"^ADC input is NaN$"):
        adc_volts_to_code(math.nan, AdcRange.BIPOLAR_10V)
    with pytest.raises(ValueError, match=r"^ADC code 4096 is outside 0\.\.0xFFF$"):
        adc_code_to_volts(0x1000, AdcRange.BIPOLAR_10V)
    with pytest.raises(ValueError, match=r"^DAC command is NaN$"):
        dac_volts_to_code(math.nan)
    with pytest.raises(ValueError, match=r"^DAC code -1 is outside 0\.\.0xFFF$"):
        dac_code_to_volts(-1)


def test_range_names_and_the_array_conversion_at_gain_1_by_default() -> None:
    for text in ("bipolar", " Unipolar ", "BIPOLAR_10V", "unipolar_10v"):
        assert AdcRange.parse(text) is (AdcRange.UNIPOLAR_10V if "uni" in text.lower() else AdcRange.BIPOLAR_10V)
    assert AdcRange.parse(AdcRange.UNIPOLAR_10V) is AdcRange.UNIPOLAR_10V
    with pytest.raises(ValueError, match=r"^unknown ADC range 'tripolar'; expected 'bipolar' \(±10 V\) "
                                         r"or 'unipolar' \(0\.\.10 V\)$"):
        AdcRange.parse("tripolar")
    # 0x000, 0x800, 0xC00 at gain 1: −10, 0, +5 V bipolar; 0, 5, 7.5 V unipolar (docs/boards/adc.md)
    np.testing.assert_allclose(adc_codes_to_volts([0, 0x800, 0xC00], AdcRange.BIPOLAR_10V), [-10.0, 0.0, 5.0])
    np.testing.assert_allclose(adc_codes_to_volts([0, 0x800, 0xC00], AdcRange.UNIPOLAR_10V), [0.0, 5.0, 7.5])


def test_the_driver_register_map_is_the_docs_register_table() -> None:
    assert map_differences(ADC_REGMAP, doc_registers("adc"), who="driver") == []


def test_the_emulator_register_map_is_the_docs_register_table() -> None:
    assert map_differences(AdcBoard.REGMAP, doc_registers("adc"), who="emulator") == []


def test_the_driver_gain_codes_are_the_docs_gain_table() -> None:
    table = _doc_gain_codes()
    assert table == {1: 0, 2: 1, 4: 2, 8: 3}  # the doc's table itself, as written
    assert {g: gain_code(g) for g in table} == table
    assert {c: gain_from_code(c) for c in table.values()} == {c: g for g, c in table.items()}


def test_the_driver_converts_the_docs_worked_examples() -> None:
    examples = _examples()
    assert len(examples) == 34  # both ranges, every gain
    for rng, gain, v, code, centre in examples:
        assert adc_volts_to_code(v, rng, gain) == code, (rng, gain, v)
        assert adc_code_to_volts(code, rng, gain) == centre, (rng, gain, code)


def test_the_emulator_converts_the_docs_worked_examples() -> None:
    """The emulator driven through the doc's own bit positions (CSR.RANGE, CSR.START, CHAN's
    fields, DATA) and gain table: each worked example's input converts to its code."""
    regs = doc_registers("adc")
    csr, chan, data = regs["CSR"], regs["CHAN"], regs["DATA"]
    gain_codes = _doc_gain_codes()
    c = Crate("doc")
    c.install(AdcBoard("adc0", wiring={5: "in5"}), base=BASE, space="A16")
    for rng, gain, v, code, _ in _examples():
        c.signals.set_analog("in5", v)
        range_bit = 1 << csr.fields["RANGE"][0] if rng is AdcRange.UNIPOLAR_10V else 0
        c.write(BASE + csr.offset, range_bit, space="A16", width=Width.D16)
        c.write(BASE + chan.offset, gain_codes[gain] << chan.fields["GAIN"][0] | 5 << chan.fields["CHANNEL"][0])
        c.write(BASE + csr.offset, range_bit | 1 << csr.fields["START"][0])
        c.delay(20e-6)
        assert c.read(BASE + data.offset) == 5 << 12 | code, (rng, gain, v)


def test_a_d8_write_of_the_configuration_byte_leaves_the_flags_and_starts_nothing() -> None:
    # docs/boards/adc.md: +0x02 is the configuration byte; it neither starts anything nor clears a flag
    c, board, _ = make()
    start(c)
    start(c)  # while busy: OVERRUN
    c.read(BASE + 0x06, space="A16", width=Width.D16)  # DATA while busy: EARLY
    c.delay(20e-6)
    assert rd(c, "CSR") == 0x0038  # OVERRUN, EARLY, DONE
    c.write(BASE + 0x02, 0x10, space="A16", width=Width.D8)  # RANGE = 1 (0..10 V)
    assert rd(c, "CSR") == 0x1038 and board.conversions == 1
    c.write(BASE + 0x03, 0x30, space="A16", width=Width.D8)  # clear both flags; RANGE stays
    assert rd(c, "CSR") == 0x1008


# --- registers ----------------------------------------------------------------------------

def test_id_register_is_read_only_and_identifies_the_board() -> None:
    c, _, _ = make()
    assert rd(c, "ID") == ADC_BOARD_ID
    assert c.read(BASE, space="A16", width=Width.D8) == ADC_BOARD_ID >> 8
    assert c.read(BASE + 1, space="A16", width=Width.D8) == ADC_BOARD_ID & 0xFF
    with pytest.raises(BusError) as ei:
        wr(c, "ID", 0)
    assert ei.value.cause is BusErrorCause.ACCESS


def test_driver_refuses_a_board_that_is_not_this_adc() -> None:
    c = Crate()
    c.install(RamBoard("ram", 0x100), base=0x1000, space="A16")
    with pytest.raises(BoardIdError, match="0x1000.*expected 0xAD16"):
        AdcDriver(c, 0x1000)


def test_data_and_buffer_are_read_only_holes_are_bus_errors() -> None:
    c, _, _ = make()
    for reg in ("DATA", "BUF0", "BUF15"):
        with pytest.raises(BusError) as ei:
            wr(c, reg, 1)
        assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        c.read(BASE + 0x10, space="A16", width=Width.D16)  # hole between SCAN_GAIN1 and BUF0
    assert ei.value.cause is BusErrorCause.NO_RESPONDER
    with pytest.raises(BusError) as ei:
        c.read(BASE + 0x04, space="A16", width=Width.D32)  # CHAN+DATA as one D32
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH


@pytest.mark.parametrize(("offset", "width", "write", "cause"), [
    (0x12, Width.D16, False, BusErrorCause.NO_RESPONDER),  # 0x10-0x1F not decoded
    (0x1E, Width.D16, True, BusErrorCause.NO_RESPONDER),
    (0x04, Width.D8, True, BusErrorCause.UNSUPPORTED_WIDTH),  # D8 only on ID and CSR
    (0x07, Width.D8, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (0x20, Width.D32, False, BusErrorCause.UNSUPPORTED_WIDTH),  # no D32 anywhere
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


def test_configuration_registers_read_back_masked() -> None:
    c, _, _ = make()
    assert rd(c, "VECTOR") == 0x0F and rd(c, "SCAN_LAST") == 15  # reset values
    wr(c, "CHAN", 0xFFFF)
    assert rd(c, "CHAN") == 0x3F  # 4-bit channel, 2-bit gain
    wr(c, "VECTOR", 0x1A5)
    assert rd(c, "VECTOR") == 0xA5
    wr(c, "SCAN_LAST", 0x37)
    assert rd(c, "SCAN_LAST") == 0x7
    wr(c, "SCAN_GAIN0", 0xBEEF)
    wr(c, "SCAN_GAIN1", 0x1234)
    assert (rd(c, "SCAN_GAIN0"), rd(c, "SCAN_GAIN1")) == (0xBEEF, 0x1234)


def test_csr_config_bits_are_read_write_strobes_read_zero() -> None:
    c, _, _ = make()
    wr(c, "CSR", CSR.pack(IRQ_LEVEL=5, RANGE=1))
    assert CSR.unpack(rd(c, "CSR"))["IRQ_LEVEL"] == 5
    assert CSR.unpack(rd(c, "CSR"))["RANGE"] == 1
    start(c)
    st_ = CSR.unpack(rd(c, "CSR"))
    assert st_["START"] == 0 and st_["BUSY"] == 1
    assert st_["IRQ_LEVEL"] == 5  # a D8 write of the action byte leaves the configuration byte alone


def test_software_reset_restores_power_up_state_and_aborts_a_conversion() -> None:
    c, board, _ = make()
    wr(c, "VECTOR", 0x44)
    start(c)
    wr(c, "CSR", CSR.pack(RESET=1))
    c.delay(50e-6)
    assert rd(c, "VECTOR") == 0x0F
    st_ = CSR.unpack(rd(c, "CSR"))
    assert st_["BUSY"] == 0 and st_["DONE"] == 0
    assert board.conversions == 0


# --- timing, flags ------------------------------------------------------------------------

def test_conversion_takes_the_board_conversion_time() -> None:
    c, _, _ = make(conversion_time_ns=15_000)
    start(c)
    t0 = c.clock.now_ns
    done_at = None
    while done_at is None:
        csr = c.read(BASE + 3, space="A16", width=Width.D8)
        if csr & BIT["DONE"]:
            done_at = c.clock.now_ns
        else:
            assert csr & BIT["BUSY"]
    assert 15_000 <= done_at - t0 + 300 <= 15_000 + 600  # finished within one poll cycle of 15 µs


def test_early_read_returns_stale_value_and_sets_flag() -> None:
    c, _, adc = make()
    c.signals.set_analog("in2", 1.0)
    first = adc.read_counts(2)
    c.signals.set_analog("in2", -3.0)
    adc.start_conversion(2)
    ch, stale = adc.read_data()  # too early
    assert (ch, stale) == (2, first)
    s = adc.status()
    assert s.early_read and s.busy and not s.overrun
    c.delay(20e-6)
    assert adc.read_data()[1] == 0x59A  # −3.0 V: 7 V / 4.8828125 mV = 1433.6 → 1434
    assert adc.status().early_read  # sticky until cleared
    adc.clear_flags()
    assert not adc.status().early_read


def test_early_read_of_scan_buffer_sets_flag() -> None:
    c, _, adc = make()
    c.write(BASE + 3, BIT["SCAN"], space="A16", width=Width.D8)
    rd(c, "BUF3")
    assert adc.status().early_read


def test_start_while_busy_sets_overrun_and_is_ignored() -> None:
    c, _, adc = make()
    c.signals.set_analog("in1", 2.0)
    c.signals.set_analog("in7", -2.0)
    adc.start_conversion(1)
    adc.start_conversion(7)  # CHAN now says 7, but the board is busy: ignored
    assert adc.status().overrun
    c.delay(40e-6)
    ch, code = adc.read_data()
    assert ch == 1 and code == 0x99A  # +2.0 V: 12 V / 4.8828125 mV = 2457.6 → 2458
    adc.clear_flags()
    assert not adc.status().overrun


def test_sample_and_hold_at_conversion_start() -> None:
    c, _, adc = make()
    c.signals.set_analog("in4", 1.0)
    adc.start_conversion(4)
    c.delay(5e-6)
    c.signals.set_analog("in4", 9.0)  # changes mid-conversion: not seen
    c.delay(20e-6)
    assert adc.read_data()[1] == 0x8CD  # +1.0 V: 2252.8 → 2253, not +9.0 V


def test_scan_samples_each_channel_at_its_own_conversion_start() -> None:
    c, _, _ = make()
    for ch in (0, 1):
        c.signals.set_analog(f"in{ch}", 1.0)
    t = c.clock.now_ns

    def step() -> None:
        for ch in (0, 1):
            c.signals.set_analog(f"in{ch}", 5.0)

    # channel 0 starts at the SCAN write; channel 1 one conversion (15 µs) later
    c.clock.schedule(t + 8_000, step)
    c.write(BASE + 3, BIT["SCAN"], space="A16", width=Width.D8)
    c.delay(400e-6)
    b0 = rd(c, "BUF0") & 0xFFF
    b1 = rd(c, "BUF1") & 0xFFF
    assert b0 == 0x8CD  # +1.0 V
    assert b1 == 0xC00  # +5.0 V


@pytest.mark.parametrize("steps_us", [[400.0], [7.0] * 60, [15.0] * 30, [22.0, 1.0, 90.0, 300.0],
                                      [44.999, 0.001, 400.0]])
def test_a_scan_samples_each_channel_at_its_own_start_however_the_time_is_advanced(steps_us: list[float]) -> None:
    # conversions whose end is the clock's next event run without the event queue
    # (SimClock.free_until); net changes queued at, between and at the very instant of
    # conversion starts must be seen by exactly the conversions that start at or after them,
    # whatever steps the time is advanced in
    c, board, _ = make()
    wr(c, "SCAN_LAST", 15)

    def set_all(v: float) -> Callable[[], None]:
        def apply() -> None:
            for ch in range(16):
                c.signals.set_analog(f"in{ch}", v)
        return apply

    c.write(BASE + 3, BIT["SCAN"], space="A16", width=Width.D8)
    t0 = c.clock.now_ns  # conversion k starts at t0 + k·15 µs (0 V on every input now)
    # (conversion index, ns after its start, volts): at a start (queued before the end event
    # that starts it: seen by it), mid-conversion (seen by the next), a nanosecond before a start
    changes = ((3, 0, 1.0), (4, 0, 2.0), (4, 7_000, 7.5), (9, 0, 3.0), (12, 14_999, 4.0))
    for k, dt_ns, v in changes:
        c.clock.schedule(t0 + k * 15_000 + dt_ns, set_all(v))
    # ±10 V, gain 1: code = floor((V + 10 V) / 4.8828125 mV + ½)
    code_of = {0.0: 0x800, 1.0: 0x8CD, 2.0: 0x99A, 7.5: 0xE00, 3.0: 0xA66, 4.0: 0xB33}
    expected = []
    for k in range(16):
        seen = [v for kk, d, v in changes if t0 + kk * 15_000 + d <= t0 + k * 15_000]
        expected.append(code_of[seen[-1] if seen else 0.0])
    for step in steps_us:
        c.delay(step * 1e-6)
    codes = [rd(c, f"BUF{k}") & 0xFFF for k in range(16)]
    assert codes == expected
    assert board.conversions == 16 and not rd(c, "CSR") & BIT["BUSY"]


def test_a_scan_is_busy_until_its_last_conversion_ends() -> None:
    c, board, _ = make()
    wr(c, "SCAN_LAST", 15)
    c.write(BASE + 3, BIT["SCAN"], space="A16", width=Width.D8)
    t0 = c.clock.now_ns
    c.clock.advance_to(t0 + 16 * 15_000 - 1)  # the CSR read through its hook: no bus cycle, no time
    assert c.clock.now_ns == t0 + 16 * 15_000 - 1
    assert board.read_CSR() & BIT["BUSY"] and board.conversions == 15
    c.clock.advance_to(t0 + 16 * 15_000)
    assert not board.read_CSR() & BIT["BUSY"] and board.read_CSR() & BIT["DONE"] and board.conversions == 16


def test_polled_read_times_out_with_a_typed_error() -> None:
    c = Crate()
    c.install(AdcBoard("slow", conversion_time_ns=5_000_000), base=BASE, space="A16")
    adc = AdcDriver(c, BASE, timeout_s=1e-3)
    with pytest.raises(AdcTimeoutError, match="did not finish") as ei:
        adc.read_counts(0)
    assert ei.value.csr & BIT["BUSY"]


# --- ranges, gains, front end --------------------------------------------------------------

@pytest.mark.parametrize(("gain", "code", "volts"), [(1, 0x8B8, 0.8984375), (2, 0x971, 0.90087890625),
                                                    (4, 0xAE1, 0.899658203125), (8, 0xDC3, 0.9002685546875)])
def test_gain_divides_the_input_range(gain: int, code: int, volts: float) -> None:
    # +0.9 V on ±10 V / gain: the doc's worked examples
    c, _, adc = make()
    c.signals.set_analog("in3", 0.9)
    assert adc.read_counts(3, gain) == code
    assert adc.read_volts(3, gain) == volts


def test_unipolar_range_and_clipping_at_the_rails() -> None:
    c, _, adc = make()
    adc.set_range("unipolar")
    assert adc.status().range is AdcRange.UNIPOLAR_10V
    c.signals.set_analog("in0", 7.5)
    c.signals.set_analog("in1", -2.0)
    c.signals.set_analog("in2", 14.0)
    assert adc.read_counts(0) == 3072
    assert adc.read_counts(1) == 0
    assert adc.read_counts(2) == CODE_MAX
    adc.set_range(AdcRange.BIPOLAR_10V)
    assert adc.read_counts(1) == 0x666  # −2.0 V: 8 V / 4.8828125 mV = 1638.4 → 1638
    assert adc.read_counts(2, gain=2) == CODE_MAX


def test_the_driver_names_the_volts_of_one_code_of_its_range() -> None:
    # docs/boards/adc.md gain table, gain 1: ±10 V 4.8828125 mV, 0..10 V 2.44140625 mV
    _, _, adc = make()
    assert adc.lsb_v == 0.0048828125
    adc.set_range("unipolar")
    assert adc.lsb_v == 0.00244140625


def test_unwired_channel_reads_zero_volts() -> None:
    c = Crate()
    c.install(AdcBoard("a", wiring={0: "x"}), base=BASE, space="A16")
    adc = AdcDriver(c, BASE)
    c.signals.set_analog("x", 3.0)
    assert adc.read_counts(5) == CODE_MID


def test_noiseless_quantization_error_is_within_half_lsb() -> None:
    c, _, adc = make()
    for v in np.linspace(-9.99, 9.99, 97):
        c.signals.set_analog("in6", float(v))
        assert abs(adc.read_volts(6) - v) <= LSB / 2 + 1e-12


def test_noise_and_quantization_statistics_of_a_seeded_run() -> None:
    noise = 2e-3
    c, _, adc = make(noise=noise, seed=42)
    c.signals.set_analog("in5", 1.234)
    v = np.array([adc.read_volts(5) for _ in range(2000)])
    assert abs(v.mean() - 1.234) < 0.3e-3
    expected_std = np.hypot(noise, LSB / np.sqrt(12))  # Gaussian noise + quantization
    assert 0.9 * expected_std < v.std() < 1.1 * expected_std
    # bit-for-bit deterministic for a seed, different for another seed
    c2, _, adc2 = make(noise=noise, seed=42)
    c2.signals.set_analog("in5", 1.234)
    first = [round((x + 10.0) / (20.0 / 4096)) for x in v[:50]]  # the codes whose centres run 1 read
    assert [adc2.read_counts(5) for _ in range(50)] == first
    c3, _, adc3 = make(noise=noise, seed=43)
    c3.signals.set_analog("in5", 1.234)
    assert [adc3.read_counts(5) for _ in range(50)] != [adc2.read_counts(5) for _ in range(50)]


def test_offset_and_gain_errors_and_calibration_that_removes_them() -> None:
    offs = [0.0] * 16
    gerr = [0.0] * 16
    offs[2], gerr[2] = 0.050, 0.02
    c, _, adc = make(offset_v=offs, gain_error=gerr)
    c.signals.set_analog("in2", 4.0)
    raw = adc.read_volts(2)
    assert raw == pytest.approx(4.0 * 1.02 + 0.05, abs=LSB)
    cal = Calibration(tuple(offs), tuple(1 + g for g in gerr))
    adc.calibration = cal
    assert adc.read_volts(2) == pytest.approx(4.0, abs=LSB)
    assert adc.scan([2])[0] == pytest.approx(4.0, abs=LSB)
    assert adc.read_counts(2) == 0xB4E  # raw is raw: 4.13 V → 14.13 V / 4.8828125 mV = 2893.8 → 2894


def test_extra_noise_source_is_evaluated_at_each_conversion() -> None:
    c, board, adc = make(seed=3)
    calls: list[int] = []

    def hbridge_noise() -> float:
        calls.append(c.clock.now_ns)
        return 0.02

    board.add_noise_source(hbridge_noise)
    c.signals.set_analog("in0", 0.5)
    v = np.array([adc.read_volts(0) for _ in range(300)])
    assert len(calls) == 300 and len(set(calls)) == 300
    assert 0.017 < v.std() < 0.023


# --- interrupts -------------------------------------------------------------------------------

def test_interrupt_driven_conversion() -> None:
    c, board, adc = make()
    adc.enable_interrupts(level=3, vector=0x60)
    c.signals.set_analog("in9", -4.5)
    code = adc.read_counts(9)
    assert code == 0x466  # −4.5 V: 5.5 V / 4.8828125 mV = 1126.4 → 1126
    assert adc.interrupts_taken == 1
    assert c.counter_snapshot()["iack.IRQ3"] == 1
    assert not board.irq_pending and not adc.status().irq_pending  # the handler released the RORA request
    assert rd(c, "VECTOR") == 0x60
    adc.scan(4)
    assert adc.interrupts_taken == 2
    adc.disable_interrupts()
    assert c.irq_handler(0x60) is None
    adc.read_counts(9)
    assert adc.interrupts_taken == 2


def test_rora_request_stays_until_the_host_clears_it() -> None:
    c, board, _ = make()
    calls: list[int] = []
    c.register_irq_handler(0x61, calls.append)  # a handler that forgets to clear the board
    wr(c, "VECTOR", 0x61)
    wr(c, "CSR", CSR.pack(IRQ_EN=1, IRQ_LEVEL=2))
    start(c)
    c.delay(20e-6)
    assert len(calls) == c.irq.storm_limit and c.counter_snapshot()["irq.storms"] >= 1
    assert board.irq_pending
    c.write(BASE + 3, BIT["IRQ_PEND"], space="A16", width=Width.D8)
    assert not board.irq_pending


def test_interrupt_wait_times_out_when_the_vector_is_wrong() -> None:
    c, _, adc = make()
    adc.enable_interrupts(level=4, vector=0x70)
    wr(c, "VECTOR", 0x71)  # the board now answers IACK with a vector nobody handles
    with pytest.raises(AdcTimeoutError, match="interrupt-driven"):
        adc.read_counts(0)
    assert 0x71 in c.irq.unhandled


def test_irq_level_zero_means_no_interrupt() -> None:
    c, board, _ = make()
    wr(c, "CSR", CSR.pack(IRQ_EN=1, IRQ_LEVEL=0))
    start(c)
    c.delay(20e-6)
    assert not board.irq_pending and c.irq.unhandled == []


# --- scan ---------------------------------------------------------------------------------------

def test_scan_with_block_read_matches_single_conversions() -> None:
    c, _, adc = make()
    volts = np.linspace(-8, 8, 16)
    for ch, v in enumerate(volts):
        c.signals.set_analog(f"in{ch}", float(v))
    before = c.counter_snapshot().get("read.A16.D16", 0)
    t0 = c.now()
    got = adc.scan(15)
    elapsed = c.now() - t0
    reads = c.counter_snapshot()["read.A16.D16"] - before
    assert got == pytest.approx(volts, abs=LSB / 2)
    assert 16 * 15e-6 <= elapsed < 16 * 15e-6 + 40e-6  # 16 conversions back to back + bus cycles
    assert reads == 16  # the block read of BUF0..BUF15
    for ch in range(16):
        word = rd(c, f"BUF{ch}")
        assert word >> 12 == ch  # channel tag
    singles = [adc.read_counts(ch) for ch in range(16)]
    assert list(adc.scan_counts(15)) == singles


def test_a_repeated_scan_follows_a_new_calibration_and_a_new_range() -> None:
    c, _, adc = make()
    c.signals.set_analog("in0", 2.0)
    assert adc.scan(0)[0] == pytest.approx(2.0, abs=LSB / 2)
    adc.calibration = Calibration((0.5,) + (0.0,) * 15, (1.0,) * 16)  # the same scan, a new calibration
    assert adc.scan(0)[0] == pytest.approx(1.5, abs=LSB / 2)
    adc.set_range("unipolar")  # the same scan and calibration, a new range: code 819 is 2.0 V (not −6 V)
    assert adc.scan(0)[0] == pytest.approx(1.5, abs=LSB / 4)


def test_scan_of_a_channel_list_with_per_channel_gains() -> None:
    c, _, adc = make()
    c.signals.set_analog("in0", 0.3)
    c.signals.set_analog("in5", 6.0)
    got = adc.scan([5, 0], gain={0: 8})
    assert got[0] == pytest.approx(6.0, abs=LSB / 2)
    assert got[1] == pytest.approx(0.3, abs=LSB / 8 / 2)  # ±1.25 V at gain 8
    assert rd(c, "SCAN_LAST") == 5
    assert rd(c, "SCAN_GAIN0") & 0x3 == 3  # channel 0 at gain 8
    c.signals.set_analog("in12", 2.0)  # clips at gain 8 (±1.25 V), not at gain 4 (±2.5 V)
    assert adc.scan_counts([12], gain={12: 4})[0] == 0xE66  # 4.5 V / 1.220703125 mV = 3686.4 → 3686
    assert rd(c, "SCAN_GAIN1") == 2 << 8  # channel 12 at gain code 2
    assert adc.scan_counts([12], gain={12: 8})[0] == CODE_MAX
    with pytest.raises(ValueError, match="channel 16"):
        adc.scan([16])
    with pytest.raises(ValueError, match="gain"):
        adc.scan(3, gain=3)


def test_scan_registers_are_written_only_when_the_configuration_changes() -> None:
    c, _, adc = make()
    adc.scan(2)
    w = c.counter_snapshot()["write.A16.D16"]
    adc.scan(2)
    assert c.counter_snapshot()["write.A16.D16"] == w  # repeated tick scans: start + wait + block read only


# --- faults ---------------------------------------------------------------------------------------

def test_stuck_channel_fault_is_seen_by_the_driver() -> None:
    c, board, adc = make()
    c.signals.set_analog("in3", 2.0)
    board.inject("stuck_channel", channel=3, code=0x123)
    assert adc.read_counts(3) == 0x123
    assert adc.scan(3)[3] == -8.5791015625  # −10 V + 0x123 · 4.8828125 mV
    assert adc.read_counts(2) == CODE_MID  # other channels unaffected
    board.clear_fault("stuck_channel")
    assert adc.read_counts(3) == 0x99A  # +2.0 V


def test_noise_burst_fault_on_listed_channels_only() -> None:
    _, board, adc = make(seed=9)
    board.inject("noise_burst", rms_v=0.05, channels=[1])
    quiet = np.array([adc.scan(1) for _ in range(200)])
    assert quiet[:, 0].std() == 0.0
    assert 0.04 < quiet[:, 1].std() < 0.06
    board.clear_fault()
    assert np.array([adc.read_volts(1) for _ in range(20)]).std() == 0.0
    with pytest.raises(UnknownFaultError, match="stuck_channel"):
        board.inject("melted")


# --- calibration dataclass -------------------------------------------------------------------------

def test_calibration_dict_round_trip_and_errors() -> None:
    cal = Calibration.from_dict({"offset_v": [0.01] * 16, "gain": [1.001] * 16}, channels=16)
    assert Calibration.from_dict(cal.to_dict()) == cal
    assert cal.correct(0, cal.apply(0, 3.0)) == pytest.approx(3.0)
    assert Calibration.from_dict({"gain": [1.0] * 8}).offset_v == (0.0,) * 8
    with pytest.raises(CalibrationError, match="expected 16"):
        Calibration.from_dict({"gain": [1.0] * 8}, channels=16)
    with pytest.raises(CalibrationError, match="gain .* must be"):
        Calibration.from_dict({"gain": [0.0] * 4})
    with pytest.raises(CalibrationError, match="unknown keys"):
        Calibration.from_dict({"ofset_v": [0.0]})
    with pytest.raises(CalibrationError, match="list of numbers"):
        Calibration.from_dict({"offset_v": "0.1"})
    c, _, _ = make()
    with pytest.raises(ValueError, match="16"):
        AdcDriver(c, BASE, calibration=Calibration.identity(8))


# --- crate files -------------------------------------------------------------------------------------

CRATE = """
[crate]
name = "t"
[[crate.board]]
type = "adc"
name = "adc0"
space = "A16"
base = 0x6000
noise_rms_v = 0.0
conversion_time_us = 10
offset_v = [0.1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
[crate.board.wiring]
0 = "pot1"
3 = "pot2"
"""


def test_crate_file_builds_a_wired_adc(tmp_path: Path) -> None:
    p = tmp_path / "c.toml"
    p.write_text(CRATE)
    c = load_crate(p, seed=5)
    board = c.board("adc0")
    assert isinstance(board, AdcBoard) and board.conversion_time_ns == 10_000
    adc = AdcDriver(c, 0x6000, conversion_time_s=10e-6)
    c.signals.set_analog("pot1", 1.0)
    c.signals.set_analog("pot2", -1.0)
    assert adc.read_volts(0) == pytest.approx(1.1, abs=LSB)
    assert adc.read_volts(3) == pytest.approx(-1.0, abs=LSB)
    from vmehil.commands.crate import probe_all

    assert probe_all(c)[0]["value"] == f"0x{ADC_BOARD_ID:X}"


@pytest.mark.parametrize(
    "mutation,key",
    [
        (lambda s: s.replace('3 = "pot2"', '16 = "pot2"'), "wiring.16"),
        (lambda s: s.replace("offset_v = [0.1, 0,", "offset_v = [0,"), "offset_v"),
        (lambda s: s.replace("conversion_time_us = 10", "conversion_time_us = 0"), "conversion_time_us"),
    ],
)
def test_bad_adc_crate_entries_name_the_key(tmp_path: Path, mutation, key: str) -> None:
    p = tmp_path / "c.toml"
    p.write_text(mutation(CRATE))
    with pytest.raises(ConfigError, match=key):
        load_crate(p)
