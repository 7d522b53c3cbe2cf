"""Golden bus traces of the ADC driver: every operation's cycles, compared with a literal trace
written by hand from docs/boards/adc.md (register table, CSR bits, gain table, conversion).

Board at 0x6000 (A16). From the doc: ID +0x00 (0xAD16), CSR +0x02 (D8: +0x02 configuration byte,
+0x03 action/status byte; START bit 0, SCAN bit 1, BUSY bit 2, DONE bit 3, EARLY bit 4, OVERRUN
bit 5, IRQ_PEND bit 7, IRQ_EN bit 8, IRQ_LEVEL bits 11:9, RANGE bit 12, RESET bit 15), CHAN +0x04
(GAIN bits 5:4, CHANNEL bits 3:0), DATA +0x06, VECTOR +0x08, SCAN_LAST +0x0A, SCAN_GAIN0/1
+0x0C/+0x0E (2 bits a channel), BUF0..BUF15 +0x20..+0x3E; gain codes 0..3 = ×1, ×2, ×4, ×8.

Most tests run the driver alone on a scripted bus (the status byte answering BUSY, then DONE);
the interrupt path and one conversion also run through a crate with the emulator installed.
"""

from __future__ import annotations

import pytest

from emulators.adc import AdcBoard
from emulators.crate import Crate
from hal.adc_dac import AdcDriver, AdcError, AdcRange, AdcTimeoutError, BoardIdError
from hal.vme import BusError
from tests.support.bus_trace import Answer, RecordingBus

BASE = 0x6000
PROBE = "R A16 0x6000 D16 0xAD16"  # ID
RESET = "W A16 0x6002 D16 0x8000"  # CSR.RESET
BIPOLAR = "W A16 0x6002 D16 0x0000"  # CSR: RANGE 0 (±10 V), no interrupt
UNIPOLAR = "W A16 0x6002 D16 0x1000"  # CSR: RANGE 1 (0..10 V)
START = "W A16 0x6003 D8 0x01"  # CSR low byte: START
SCAN = "W A16 0x6003 D8 0x02"  # CSR low byte: SCAN
BUSY = "R A16 0x6003 D8 0x04"  # status byte: BUSY
DONE = "R A16 0x6003 D8 0x08"  # status byte: DONE

RANGE_WORD = {AdcRange.BIPOLAR_10V: BIPOLAR, AdcRange.UNIPOLAR_10V: UNIPOLAR}


def scripted(extra: dict[tuple[str, int], Answer] | None = None, *,
             status: Answer = (0x04, 0x04, 0x08)) -> RecordingBus:
    """A bus answering the ID and, at the status byte, BUSY twice then DONE (by default)."""
    answers: dict[tuple[str, int], Answer] = {("A16", 0x6000): 0xAD16, ("A16", 0x6003): status}
    answers.update(extra or {})
    return RecordingBus(answers=answers)


# --- probe and reset ----------------------------------------------------------------------------

@pytest.mark.parametrize(("rng", "config"), [("bipolar", BIPOLAR), ("unipolar", UNIPOLAR)])
def test_opening_the_driver_probes_the_id_resets_the_board_and_programs_the_range(rng: str, config: str) -> None:
    bus = scripted()
    AdcDriver(bus, BASE, range=rng)
    assert bus.trace() == [PROBE, RESET, config]


def test_a_board_with_another_id_is_refused_after_the_one_id_read() -> None:
    bus = RecordingBus(answers={("A16", 0x6000): 0xDA08})  # a DAC there
    with pytest.raises(BoardIdError, match="0x6000.*reads 0xDA08, expected 0xAD16"):
        AdcDriver(bus, BASE)
    assert bus.trace() == ["R A16 0x6000 D16 0xDA08"]


def test_no_board_at_the_address_ends_the_probe_in_a_bus_error() -> None:
    bus = RecordingBus(answers={})
    with pytest.raises(BusError):
        AdcDriver(bus, BASE)
    assert bus.trace() == []


# --- single conversion at each gain and range -----------------------------------------------------

# channel 3, DATA answering channel 3 and code 0xC00: ±10 V/gain → +FS/2; 0..10 V/gain → ¾·FS
@pytest.mark.parametrize(("rng", "gain", "chan", "volts"), [
    (AdcRange.BIPOLAR_10V, 1, "0x0003", 5.0),
    (AdcRange.BIPOLAR_10V, 2, "0x0013", 2.5),
    (AdcRange.BIPOLAR_10V, 4, "0x0023", 1.25),
    (AdcRange.BIPOLAR_10V, 8, "0x0033", 0.625),
    (AdcRange.UNIPOLAR_10V, 1, "0x0003", 7.5),
    (AdcRange.UNIPOLAR_10V, 2, "0x0013", 3.75),
    (AdcRange.UNIPOLAR_10V, 4, "0x0023", 1.875),
    (AdcRange.UNIPOLAR_10V, 8, "0x0033", 0.9375),
])
def test_a_single_conversion_writes_chan_starts_polls_until_done_and_reads_data(
        rng: AdcRange, gain: int, chan: str, volts: float) -> None:
    bus = scripted({("A16", 0x6006): 0x3C00})
    adc = AdcDriver(bus, BASE, range=rng)
    assert adc.read_volts(3, gain) == volts
    assert bus.trace() == [
        PROBE, RESET, RANGE_WORD[rng],
        f"W A16 0x6004 D16 {chan}",  # CHAN: gain code, channel 3
        START,
        BUSY, BUSY, DONE,
        "R A16 0x6006 D16 0x3C00",  # DATA: channel 3, code 0xC00
    ]
    assert bus.delays == [15e-6, 2e-6, 2e-6]  # the conversion time, then the poll interval


def test_read_counts_returns_the_code_of_data_and_refuses_another_channels_word() -> None:
    bus = scripted({("A16", 0x6006): (0xF971, 0x2971)})
    adc = AdcDriver(bus, BASE)
    bus.clear()
    assert adc.read_counts(15, 2) == 0x971
    assert bus.trace() == ["W A16 0x6004 D16 0x001F", START, BUSY, BUSY, DONE, "R A16 0x6006 D16 0xF971"]
    with pytest.raises(AdcError, match="channel 2, expected 15"):
        adc.read_counts(15, 2)


def test_a_conversion_that_never_finishes_times_out_after_reading_the_csr() -> None:
    # the wait: 15 µs, then polls every 2 µs until 15 + 5 µs have passed (polls at 15, 17, 19, 21 µs)
    bus = scripted({("A16", 0x6002): 0x0004}, status=0x04)
    adc = AdcDriver(bus, BASE, timeout_s=5e-6)
    bus.clear()
    with pytest.raises(AdcTimeoutError, match="CSR=0x0004"):
        adc.read_counts(0)
    assert bus.trace() == ["W A16 0x6004 D16 0x0000", START, BUSY, BUSY, BUSY, BUSY, "R A16 0x6002 D16 0x0004"]


def test_a_single_conversion_through_the_emulator() -> None:
    crate = Crate("t")
    crate.install(AdcBoard("adc0", wiring={7: "in7"}), base=BASE, space="A16")
    crate.signals.set_analog("in7", 0.9)
    bus = RecordingBus(crate)
    adc = AdcDriver(bus, BASE)
    assert adc.read_counts(7, 2) == 0x971  # +0.9 V at gain 2 on ±10 V (the doc's example)
    assert bus.trace() == [PROBE, RESET, BIPOLAR, "W A16 0x6004 D16 0x0017", START,
                           DONE,  # 15 µs of conversion have passed: done at the first poll
                           "R A16 0x6006 D16 0x7971"]


# --- scan at each gain and range -------------------------------------------------------------------

# BUF0..BUF3 answer codes 0xC00, 0x800, 0x400, 0xFFF (channel tags 0..3)
BUFS = {("A16", 0x6020): 0x0C00, ("A16", 0x6022): 0x1800, ("A16", 0x6024): 0x2400, ("A16", 0x6026): 0x3FFF}


@pytest.mark.parametrize(("rng", "gain", "gains_word", "volts"), [
    (AdcRange.BIPOLAR_10V, 1, "0x0000", [5.0, 0.0, -5.0, 9.9951171875]),
    (AdcRange.BIPOLAR_10V, 2, "0x5555", [2.5, 0.0, -2.5, 4.99755859375]),
    (AdcRange.BIPOLAR_10V, 4, "0xAAAA", [1.25, 0.0, -1.25, 2.498779296875]),
    (AdcRange.BIPOLAR_10V, 8, "0xFFFF", [0.625, 0.0, -0.625, 1.2493896484375]),
    (AdcRange.UNIPOLAR_10V, 1, "0x0000", [7.5, 5.0, 2.5, 9.99755859375]),
    (AdcRange.UNIPOLAR_10V, 2, "0x5555", [3.75, 2.5, 1.25, 4.998779296875]),
    (AdcRange.UNIPOLAR_10V, 4, "0xAAAA", [1.875, 1.25, 0.625, 2.4993896484375]),
    (AdcRange.UNIPOLAR_10V, 8, "0xFFFF", [0.9375, 0.625, 0.3125, 1.24969482421875]),
])
def test_a_scan_programs_the_sequencer_starts_polls_and_reads_the_buffer(
        rng: AdcRange, gain: int, gains_word: str, volts: list[float]) -> None:
    bus = scripted(BUFS, status=(0x04, 0x08))
    adc = AdcDriver(bus, BASE, range=rng)
    bus.clear()
    assert list(adc.scan(3, gain)) == volts
    assert bus.trace() == [
        "W A16 0x600A D16 0x0003",  # SCAN_LAST: channels 0..3
        f"W A16 0x600C D16 {gains_word}",  # SCAN_GAIN0: the gain code in each channel's 2 bits
        f"W A16 0x600E D16 {gains_word}",  # SCAN_GAIN1
        SCAN,
        BUSY, DONE,
        "R A16 0x6020 D16 0x0C00", "R A16 0x6022 D16 0x1800", "R A16 0x6024 D16 0x2400", "R A16 0x6026 D16 0x3FFF",
    ]
    assert bus.delays == [60e-6, 2e-6]  # four conversion times, then one poll interval


def test_a_repeated_scan_does_not_rewrite_the_sequencer() -> None:
    bus = scripted(BUFS, status=0x08)
    adc = AdcDriver(bus, BASE)
    adc.scan_counts(3)
    bus.clear()
    assert list(adc.scan_counts(3)) == [0xC00, 0x800, 0x400, 0xFFF]
    assert bus.trace() == [SCAN, DONE, "R A16 0x6020 D16 0x0C00", "R A16 0x6022 D16 0x1800",
                           "R A16 0x6024 D16 0x2400", "R A16 0x6026 D16 0x3FFF"]


def test_a_scan_of_a_channel_list_with_per_channel_gains() -> None:
    bus = scripted({("A16", 0x6020 + 2 * k): k << 12 | 0x100 * k for k in range(13)}, status=0x08)
    adc = AdcDriver(bus, BASE)
    bus.clear()
    assert list(adc.scan_counts([5, 0], gain={0: 8})) == [0x500, 0x000]
    assert bus.trace()[:4] == ["W A16 0x600A D16 0x0005",  # the board scans 0..5
                               "W A16 0x600C D16 0x0003",  # channel 0 (bits 1:0) at gain 8 (code 3)
                               "W A16 0x600E D16 0x0000", SCAN]
    assert bus.trace()[5:] == [f"R A16 0x{0x6020 + 2 * k:X} D16 0x{k:X}{k:X}00" for k in range(6)]
    bus.clear()
    adc.scan_counts([12], gain={12: 4})
    assert bus.trace()[:4] == ["W A16 0x600A D16 0x000C",
                               "W A16 0x600C D16 0x0000",
                               "W A16 0x600E D16 0x0200",  # channel 12 (bits 9:8 of SCAN_GAIN1) at gain 4 (code 2)
                               SCAN]


# --- interrupts ------------------------------------------------------------------------------------

def test_enabling_interrupts_programs_vector_level_and_enable() -> None:
    bus = scripted()
    adc = AdcDriver(bus, BASE, range="unipolar")
    bus.clear()
    adc.enable_interrupts(level=3, vector=0x60)
    assert bus.trace() == ["W A16 0x6002 D16 0x1000",  # interrupts off first (the range kept)
                           "W A16 0x6008 D16 0x0060",  # VECTOR
                           "W A16 0x6002 D16 0x1700"]  # RANGE, IRQ_LEVEL 3, IRQ_EN
    bus.clear()
    adc.set_range("bipolar")
    adc.disable_interrupts()
    assert bus.trace() == ["W A16 0x6002 D16 0x0700", "W A16 0x6002 D16 0x0000"]


def test_an_interrupt_driven_conversion_through_the_emulator() -> None:
    crate = Crate("t")
    crate.install(AdcBoard("adc0", wiring={9: "in9"}), base=BASE, space="A16")
    crate.signals.set_analog("in9", -4.5)
    bus = RecordingBus(crate)
    adc = AdcDriver(bus, BASE)
    adc.enable_interrupts(level=3, vector=0x60)
    bus.clear()
    assert adc.read_counts(9) == 0x466  # −4.5 V: 5.5 V / 4.8828125 mV = 1126.4 → 1126
    assert bus.trace() == [
        "W A16 0x6004 D16 0x0009", START,
        # the conversion ends: IRQ3, IACK answers 0x60, the driver's handler:
        "R A16 0x6002 D16 0x0788",  # CSR: IRQ_LEVEL 3, IRQ_EN, IRQ_PEND, DONE
        "W A16 0x6003 D8 0x80",  # release the RORA request: IRQ_PEND written 1
        "R A16 0x6006 D16 0x9466",  # DATA: channel 9, code 0x466
    ]
    assert adc.interrupts_taken == 1


# --- status and flags ------------------------------------------------------------------------------

def test_status_reads_the_csr_and_clear_flags_writes_one_to_early_and_overrun() -> None:
    bus = scripted({("A16", 0x6002): 0x1B3C})
    adc = AdcDriver(bus, BASE)
    bus.clear()
    s = adc.status()
    assert (s.busy, s.done, s.early_read, s.overrun, s.irq_pending, s.irq_enabled, s.irq_level, s.range) == (
        True, True, True, True, False, True, 5, AdcRange.UNIPOLAR_10V)
    adc.clear_flags()
    assert bus.trace() == ["R A16 0x6002 D16 0x1B3C", "W A16 0x6003 D8 0x30"]


def test_start_conversion_and_read_data_are_the_raw_steps() -> None:
    bus = scripted({("A16", 0x6006): 0x2ABC})
    adc = AdcDriver(bus, BASE)
    bus.clear()
    adc.start_conversion(2, gain=8)
    assert adc.read_data() == (2, 0xABC)
    assert bus.trace() == ["W A16 0x6004 D16 0x0032", START, "R A16 0x6006 D16 0x2ABC"]
    bus.clear()
    with pytest.raises(ValueError, match="channel 16"):
        adc.start_conversion(16)
    with pytest.raises(ValueError, match="gain"):
        adc.start_conversion(1, gain=3)
    assert bus.trace() == []


# --- status bits one at a time, waits and their limits -------------------------------------------

@pytest.mark.parametrize(("csr", "decoded"), [
    # (busy, done, early_read, overrun, irq_pending, irq_enabled, irq_level, unipolar)
    (0x0000, (False, False, False, False, False, False, 0, False)),
    (0x0004, (True, False, False, False, False, False, 0, False)),  # bit 2 BUSY
    (0x0008, (False, True, False, False, False, False, 0, False)),  # bit 3 DONE
    (0x0010, (False, False, True, False, False, False, 0, False)),  # bit 4 EARLY
    (0x0020, (False, False, False, True, False, False, 0, False)),  # bit 5 OVERRUN
    (0x0080, (False, False, False, False, True, False, 0, False)),  # bit 7 IRQ_PEND
    (0x0100, (False, False, False, False, False, True, 0, False)),  # bit 8 IRQ_EN
    (0x0E00, (False, False, False, False, False, False, 7, False)),  # bits 11:9 IRQ_LEVEL
    (0x1000, (False, False, False, False, False, False, 0, True)),  # bit 12 RANGE
    (0x8043, (False, False, False, False, False, False, 0, False)),  # RESET, bit 6, SCAN, START: none of these
])
def test_status_decodes_each_csr_bit_alone(csr: int, decoded: tuple) -> None:
    bus = scripted({("A16", 0x6002): csr})
    s = AdcDriver(bus, BASE).status()
    assert (s.busy, s.done, s.early_read, s.overrun, s.irq_pending, s.irq_enabled, s.irq_level,
            s.range is AdcRange.UNIPOLAR_10V) == decoded


@pytest.mark.parametrize("status", [0x00, 0x0C])
def test_the_wait_needs_done_and_not_busy(status: int) -> None:
    # idle without DONE (nothing converted yet), or DONE with BUSY (a new conversion running):
    # neither ends the wait, which times out after 15 + 5 µs (polls at 15, 17, 19, 21 µs)
    bus = scripted({("A16", 0x6002): status}, status=status)
    adc = AdcDriver(bus, BASE, timeout_s=5e-6)
    bus.clear()
    with pytest.raises(AdcTimeoutError):
        adc.read_counts(0)
    assert bus.trace()[2:] == [f"R A16 0x6003 D8 0x{status:02X}"] * 4 + [f"R A16 0x6002 D16 0x{status:04X}"]


def test_the_wait_ends_at_its_deadline_and_says_how_long_it_waited() -> None:
    # times exact in binary: conversion 2**-16 s, polls every 2**-19 s, timeout 3 polls; the
    # deadline is the fourth poll's time, so the fourth poll is the last
    tc, tp = 2.0**-16, 2.0**-19
    bus = scripted({("A16", 0x6002): 0x0004}, status=0x04)
    adc = AdcDriver(bus, BASE, conversion_time_s=tc, poll_interval_s=tp, timeout_s=3 * tp)
    bus.clear()
    with pytest.raises(AdcTimeoutError) as ei:
        adc.read_counts(4)
    assert bus.trace()[2:] == [BUSY] * 4 + ["R A16 0x6002 D16 0x0004"]
    assert ei.value.timeout_s == tc + 3 * tp and ei.value.csr == 0x0004
    assert str(ei.value) == ("ADC conversion of channel 4 did not finish within 21 µs (CSR=0x0004); "  # 20.98 µs
                             "check the board's clock/conversion time, the IRQ level and vector, or raise timeout_s")


def test_a_scan_that_never_finishes_names_the_scan_and_the_default_timeout() -> None:
    bus = scripted({("A16", 0x6002): 0x0004}, status=0x04)
    adc = AdcDriver(bus, BASE)  # 15 µs a conversion, 1 ms of timeout by default
    with pytest.raises(AdcTimeoutError) as ei:
        adc.scan(3)
    assert ei.value.timeout_s == pytest.approx(4 * 15e-6 + 1e-3)
    assert str(ei.value).startswith("ADC scan of channels 0..3 did not finish within 1060 µs (CSR=0x0004); ")


def test_an_interrupt_driven_wait_ends_at_its_deadline_too() -> None:
    tc, tp = 2.0**-16, 2.0**-19  # as above: exact in binary, the deadline on the fourth check
    bus = scripted({("A16", 0x6002): 0x0704})  # no interrupt ever comes
    adc = AdcDriver(bus, BASE, conversion_time_s=tc, poll_interval_s=tp, timeout_s=3 * tp)
    adc.enable_interrupts(level=3, vector=0x60)
    bus.delays.clear()
    with pytest.raises(AdcTimeoutError) as ei:
        adc.read_counts(0)
    assert bus.delays == [tc, tp, tp, tp]
    assert ei.value.timeout_s == tc + 3 * tp
    assert str(ei.value).startswith("ADC conversion of channel 0 (interrupt-driven) did not finish within 21 µs "
                                    "(CSR=0x0704); ")


def test_timeout_text_is_in_whole_microseconds() -> None:
    assert "within 1500000 µs (CSR=0x0000)" in str(AdcTimeoutError("scan", 1.5, 0))


def test_channel_and_scan_list_refusals_name_the_range() -> None:
    adc = AdcDriver(scripted(), BASE)
    with pytest.raises(ValueError, match=r"^ADC channel 16 is not 0\.\.15$"):
        adc.read_counts(16)
    with pytest.raises(ValueError, match=r"^scan needs at least one channel$"):
        adc.scan([])


def test_interrupt_levels_1_to_7_are_accepted_and_others_refused() -> None:
    bus = scripted()
    adc = AdcDriver(bus, BASE)
    for level in (0, 8):
        with pytest.raises(ValueError, match=rf"^IRQ level {level} is not 1\.\.7$"):
            adc.enable_interrupts(level=level, vector=0x60)
    bus.clear()
    adc.enable_interrupts(level=1, vector=0x60)
    adc.enable_interrupts(level=7, vector=0x61)
    assert bus.trace()[2] == "W A16 0x6002 D16 0x0300"  # IRQ_LEVEL 1, IRQ_EN
    assert bus.trace()[5] == "W A16 0x6002 D16 0x0F00"  # IRQ_LEVEL 7, IRQ_EN


def test_the_wrong_board_is_named_in_the_id_error_in_full() -> None:
    bus = RecordingBus(answers={("A16", 0x6000): 0x5001})  # a PIO there
    with pytest.raises(BoardIdError, match=r"^no ADC at 0x6000: ID register reads 0x5001, expected 0xAD16; "
                                           r"check the base address in the crate/rig file$"):
        AdcDriver(bus, BASE)
