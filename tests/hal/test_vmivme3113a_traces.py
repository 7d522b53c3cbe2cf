"""Golden bus traces of the VMIVME-3113A driver, written by hand from docs/boards/vmivme-3113a.md
(register table and "Driver API" cycles), never captured from the driver.

Board at 0x8500 (A16). From the doc: ID +0x00 (0x1100); CSR +0x02 (FAIL_LED_OFF bit 14,
END_OF_SCAN bit 13 on read, TWOS_COMPLEMENT bit 12, SOFTWARE_RESET bit 9, MODE bits 8:6, 0 =
autoscanning); CH0..CH63 at +0x80 + 2·k; a 64-channel scan takes 64 × 10 µs.
"""

from __future__ import annotations

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.vmivme3113a import Vmivme3113aBoard
from hal.adc_dac import AdcTimeoutError, BoardIdError, Calibration
from hal.adc_dac.vmivme3113a import Vmi3113aStatus, Vmivme3113aDriver
from hal.adc_dac.vmivme3113a_format import Vmi3113aFormat, Vmi3113aRange, volts_from_code, volts_from_codes
from hal.vme import BusError
from tests.support.bus_trace import Answer, RecordingBus

BASE = 0x8500
PROBE = "R A16 0x8500 D16 0x1100"  # ID
RESET = "W A16 0x8502 D16 0x0200"  # CSR.SOFTWARE_RESET
AUTOSCAN = "W A16 0x8502 D16 0x4000"  # CSR: FAIL_LED_OFF, MODE 0 (autoscanning), offset binary
AUTOSCAN_TC = "W A16 0x8502 D16 0x5000"  # + TWOS_COMPLEMENT
NOT_YET = "R A16 0x8502 D16 0x4000"  # CSR read: no END_OF_SCAN
EOS = "R A16 0x8502 D16 0x6000"  # CSR read: END_OF_SCAN


def scripted(extra: dict[tuple[str, int], Answer] | None = None, *,
             csr: Answer = (0x4000, 0x6000)) -> RecordingBus:
    answers: dict[tuple[str, int], Answer] = {("A16", 0x8500): 0x1100, ("A16", 0x8502): csr}
    answers.update(extra or {})
    return RecordingBus(answers=answers)


def opened(extra: dict[tuple[str, int], Answer] | None = None, **kw) -> tuple[RecordingBus, Vmivme3113aDriver]:
    bus = scripted(extra)
    drv = Vmivme3113aDriver(bus, BASE, **kw)
    bus.clear()
    return bus, drv


# --- open: probe, reset, autoscanning, first scan ------------------------------------------------------

def test_opening_probes_resets_starts_autoscanning_and_waits_for_the_first_scan() -> None:
    bus = scripted()
    Vmivme3113aDriver(bus, BASE)
    assert bus.trace() == [PROBE, RESET, AUTOSCAN, NOT_YET, EOS]
    assert bus.delays == [pytest.approx(640e-6), pytest.approx(20e-6)]  # one scan, then one poll interval


def test_opening_in_twos_complement_sets_the_format_bit() -> None:
    bus = scripted(csr=0x7000)
    Vmivme3113aDriver(bus, BASE, data_format="twos_complement")
    assert bus.trace() == [PROBE, RESET, AUTOSCAN_TC, "R A16 0x8502 D16 0x7000"]


def test_a_board_with_another_id_is_refused_after_the_one_id_read() -> None:
    bus = RecordingBus(answers={("A16", 0x8500): 0xAD16})  # the reference ADC there
    with pytest.raises(BoardIdError, match="0x8500.*ID register reads 0xAD16, expected 0x1100"):
        Vmivme3113aDriver(bus, BASE)
    assert bus.trace() == ["R A16 0x8500 D16 0xAD16"]


def test_no_board_at_the_address_ends_the_probe_in_a_bus_error() -> None:
    bus = RecordingBus(answers={})
    with pytest.raises(BusError):
        Vmivme3113aDriver(bus, BASE)
    assert bus.trace() == []


def test_a_board_that_never_ends_a_scan_times_out_with_the_csr_in_the_error() -> None:
    bus = scripted(csr=0x4000)
    with pytest.raises(AdcTimeoutError, match="CSR=0x4000"):
        Vmivme3113aDriver(bus, BASE, timeout_s=100e-6)
    assert bus.trace()[:3] == [PROBE, RESET, AUTOSCAN]
    assert set(bus.trace()[3:]) == {NOT_YET}


def test_twos_complement_on_the_unipolar_range_is_refused_before_any_cycle() -> None:
    bus = scripted()
    with pytest.raises(ValueError, match="two's complement"):
        Vmivme3113aDriver(bus, BASE, input_range="unipolar_10v", data_format="twos_complement")
    assert bus.trace() == []


# --- reads --------------------------------------------------------------------------------------------

def test_scan_of_32_channels_is_32_data_reads_and_nothing_else() -> None:
    bus, drv = opened({("A16", 0x8580 + 2 * k): 0x0800 for k in range(64)})
    drv.scan(31)
    assert bus.trace() == [f"R A16 0x{0x8580 + 2 * k:X} D16 0x0800" for k in range(32)]
    assert bus.delays == []  # no start, no wait


def test_scan_converts_offset_binary_words_to_volts_by_the_docs_examples() -> None:
    # doc: ±10 V 0x0C00 → +5.0, 0x0600 → −2.5, 0x08B8 → +0.8984375, 0x0FFF → +9.9951171875
    words = {0x8580: 0x0C00, 0x8582: 0x0600, 0x8584: 0x08B8, 0x8586: 0x0FFF}
    _, drv = opened({("A16", a): w for a, w in words.items()})
    assert drv.scan(3).tolist() == [5.0, -2.5, 0.8984375, 9.9951171875]
    assert drv.scan_counts([3, 0]).tolist() == [0x0FFF, 0x0C00]
    assert drv.lsb_v == 0.0048828125


def test_scan_converts_twos_complement_words_on_the_5v_range() -> None:
    # doc: ±5 V two's complement 0x0400 → +2.5, 0xFE00 → −1.25, 0x0171 → +0.90087890625, 0xF800 → −5.0
    words = {0x8580: 0x0400, 0x8582: 0xFE00, 0x8584: 0x0171, 0x8586: 0xF800}
    bus = scripted({("A16", a): w for a, w in words.items()}, csr=0x7000)
    drv = Vmivme3113aDriver(bus, BASE, input_range="bipolar_5v", data_format="twos_complement")
    assert drv.scan(3).tolist() == [2.5, -1.25, 0.90087890625, -5.0]
    assert drv.lsb_v == 0.00244140625


def test_read_counts_is_one_read_of_the_channels_word() -> None:
    bus, drv = opened({("A16", 0x858A): 0x0971})
    assert drv.read_counts(5) == 0x971
    assert bus.trace() == ["R A16 0x858A D16 0x0971"]
    assert bus.delays == []


def test_a_read_is_sure_to_show_an_input_change_after_one_scan_and_one_conversion() -> None:
    _, drv = opened()
    assert drv.fresh_after_s == pytest.approx(65 * 10e-6)  # doc: 64 channels + 1 at 10 µs each


def test_calibration_is_applied_per_channel_in_scan_and_read_volts() -> None:
    cal = Calibration((0.1,) + (0.0,) * 63, (2.0,) + (1.0,) * 63)
    _, drv = opened({("A16", 0x8580): 0x0C00}, calibration=cal)
    assert drv.read_volts(0) == (5.0 - 0.1) / 2.0
    assert drv.scan(0).tolist() == [(5.0 - 0.1) / 2.0]


def test_status_is_one_csr_read_decoded() -> None:
    bus, drv = opened()
    s = drv.status()
    assert bus.trace() == [EOS]
    assert (s.end_of_scan, s.new_data_ready, s.fail_led_off, s.twos_complement, s.mode) == (True, False, True, False, 0)


@pytest.mark.parametrize("call", [lambda d: d.scan(64), lambda d: d.read_counts(-1), lambda d: d.scan(3, gain=2),
                                  lambda d: d.read_volts(0, gain=8), lambda d: d.scan([])])
def test_channels_outside_0_63_and_gains_other_than_1_are_refused_without_a_cycle(call) -> None:
    bus, drv = opened()
    with pytest.raises(ValueError):
        call(drv)
    assert bus.trace() == []


# --- through the emulator -------------------------------------------------------------------------------

def test_the_driver_reads_the_emulated_board_through_a_crate() -> None:
    c = Crate("t")
    c.install(Vmivme3113aBoard("adc0", wiring={0: "p0", 31: "p31"}), base=BASE, space="A16")
    c.signals.set_analog("p0", 5.0)
    c.signals.set_analog("p31", -2.5)
    bus = RecordingBus(c)
    drv = Vmivme3113aDriver(bus, BASE)
    assert bus.trace() == [PROBE, RESET, AUTOSCAN, "R A16 0x8502 D16 0xE000"]  # NEW_DATA_READY + END_OF_SCAN
    volts = drv.scan(31)
    assert volts[0] == 5.0 and volts[31] == -2.5
    assert np.all(volts[1:31] == 0.0)


def test_through_the_crate_a_read_shows_an_input_step_only_after_fresh_after_s() -> None:
    c = Crate("t")
    c.install(Vmivme3113aBoard("adc0", wiring={0: "p0"}), base=BASE, space="A16")
    drv = Vmivme3113aDriver(c, BASE)
    assert drv.read_counts(0) == 0x800  # 0 V
    c.signals.set_analog("p0", 5.0)
    assert drv.read_counts(0) == 0x800  # the same conversion: the board has not converted channel 0 again
    c.delay(drv.fresh_after_s)
    assert drv.read_counts(0) == 0xC00  # +5 V on ±10 V


@pytest.mark.parametrize(("csr", "decoded"), [
    # (new_data_ready, end_of_scan, fail_led_off, twos_complement), docs/boards/vmivme-3113a.md CSR bits 15..12
    (0x0000, (False, False, False, False)),
    (0x8000, (True, False, False, False)),
    (0x4000, (False, False, True, False)),
    (0x2000, (False, True, False, False)),
    (0x1000, (False, False, False, True)),
    (0x0FFF, (False, False, False, False)),
])
def test_each_csr_status_bit_decodes_alone(csr: int, decoded: tuple) -> None:
    s = Vmi3113aStatus.decode(csr)
    assert (s.new_data_ready, s.end_of_scan, s.fail_led_off, s.twos_complement) == decoded


# --- edges and texts ------------------------------------------------------------------------------------
def test_the_first_autoscan_wait_ends_at_its_deadline_and_names_itself() -> None:
    # times exact in binary: 64 conversions of 2**-22 s = 2**-16 s, polls every 2**-19 s, timeout 3 polls
    tc, tp = 2.0**-22, 2.0**-19
    bus = scripted(csr=0x4000)
    with pytest.raises(AdcTimeoutError) as ei:
        Vmivme3113aDriver(bus, BASE, conversion_time_s=tc, poll_interval_s=tp, timeout_s=3 * tp)
    assert bus.trace() == [PROBE, RESET, AUTOSCAN] + [NOT_YET] * 4
    assert ei.value.timeout_s == 64 * tc + 3 * tp
    assert str(ei.value).startswith("ADC VMIVME-3113A first autoscan did not finish within 21 µs (CSR=0x4000); ")


def test_the_default_timeout_of_the_first_scan_is_5_ms() -> None:
    with pytest.raises(AdcTimeoutError) as ei:
        Vmivme3113aDriver(scripted(csr=0x4000), BASE)
    assert ei.value.timeout_s == pytest.approx(64 * 10e-6 + 5e-3)


def test_refusals_name_the_board_and_the_limit() -> None:
    with pytest.raises(ValueError, match=r"^VMIVME-3113A: two's complement data on the unipolar 0\.\.10 V range means "
                                         r"nothing; use offset_binary$"):
        Vmivme3113aDriver(scripted(), BASE, input_range="unipolar_10v", data_format="twos_complement")
    with pytest.raises(BoardIdError, match=r"^no VMIVME-3113A at 0x8500: "):
        Vmivme3113aDriver(scripted({("A16", 0x8500): 0xAD16}), BASE)
    with pytest.raises(ValueError, match=r"^VMIVME-3113A calibration has 4 channels, the board has 64$"):
        Vmivme3113aDriver(scripted(), BASE, calibration=Calibration.identity(4))
    _, drv = opened({("A16", 0x8580 + 2 * ch): 0x0800 for ch in range(4)})  # CH0..CH3's data words
    with pytest.raises(ValueError, match=r"^VMIVME-3113A channel 64 is not 0\.\.63$"):
        drv.read_counts(64)
    with pytest.raises(ValueError, match=r"^scan needs at least one channel$"):
        drv.scan([])
    drv.scan_counts(3)  # the plan for 0..3 is kept ...
    with pytest.raises(ValueError, match=r"^VMIVME-3113A gain 2: the board has gain 1 only \(its range is set by "
                                         r"jumpers\)$"):
        drv.scan_counts(3, gain=2)  # ... and a gain other than 1 is still refused


def test_the_format_helpers_convert_arrays_and_refuse_what_they_do_not_know() -> None:
    # docs/boards/vmivme-3113a.md: 12-bit offset binary; ±10 V: LSB 20 V / 4096; 0..10 V: 10 V / 4096
    np.testing.assert_allclose(volts_from_codes(np.array([0, 0x800, 0xC00]), Vmi3113aRange.BIPOLAR_10V),
                               [-10.0, 0.0, 5.0])
    np.testing.assert_allclose(volts_from_codes([0, 0x800], Vmi3113aRange.UNIPOLAR_10V), [0.0, 5.0])
    with pytest.raises(ValueError, match=r"^VMIVME-3113A code 4096 is outside 0\.\.0xFFF$"):
        volts_from_code(0x1000, Vmi3113aRange.BIPOLAR_10V)
    with pytest.raises(ValueError, match=r"^unknown VMIVME-3113A data format 'gray'; expected offset_binary or "
                                         r"twos_complement$"):
        Vmi3113aFormat.parse("gray")
    with pytest.raises(ValueError, match=r"^unknown VMIVME-3113A input range 'x'; expected one of bipolar_10v, "
                                         r"bipolar_5v, unipolar_10v$"):
        Vmi3113aRange.parse("x")


def test_a_single_read_in_twos_complement_gives_the_offset_binary_code() -> None:
    # the doc: bit 11 inverted and copied into bits 15:12; 0x0000 is mid-scale, 0xF800 the bottom
    _, drv = opened({("A16", 0x8580): 0x0000, ("A16", 0x8582): 0xF800}, data_format="twos_complement")
    assert (drv.read_counts(0), drv.read_counts(1)) == (0x800, 0x000)
