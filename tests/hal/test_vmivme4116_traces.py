"""Golden bus traces of the VMIVME-4116 driver: every operation's cycles, compared with a literal
trace written by hand from docs/boards/vmivme4116.md (register table and coding).

Board at 0x7000 (A16). From the doc: CHAN0..CHAN7 at +0x00..+0x0E (write-only), CSR at +0x10
(LED_OFF bit 14, START_CONVERT bit 9, AO_P3 bit 8); codes 16-bit offset binary,
code = floor((V + 10 V) / 305.17578125 µV + ½), or two's complement (bit 15 inverted).
"""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.vmivme4116 import VmiVme4116Board
from hal.adc_dac import Calibration, DacRangeError, VmiVme4116Driver, probe_vmivme4116
from hal.adc_dac.vmivme4116 import Vmi4116RangeError, vmi4116_code_to_volts, vmi4116_volts_to_code
from tests.support.bus_trace import RecordingBus

BASE = 0x7000
ZEROES = [f"W A16 0x{0x7000 + 2 * n:04X} D16 0x8000" for n in range(8)]  # CHAN0..CHAN7 ← 0 V
OPEN = ["R A16 0x7010 D16 0x0000", *ZEROES,
        "W A16 0x7010 D16 0x0200",  # CSR: START_CONVERT, outputs still off P3
        "W A16 0x7010 D16 0x4100"]  # CSR: LED_OFF | AO_P3, after the settling time
STROBE = "W A16 0x7010 D16 0x4300"  # CSR: LED_OFF | START_CONVERT | AO_P3


def opened(**kw) -> tuple[RecordingBus, VmiVme4116Driver]:
    bus = RecordingBus(answers={("A16", 0x7010): 0x0000})  # a CSR at power-up
    dac = VmiVme4116Driver(bus, BASE, **kw)
    return bus, dac


# --- probe, open and the zero path --------------------------------------------------------------------

def test_probe_reads_the_csr_and_writes_nothing() -> None:
    bus = RecordingBus(answers={("A16", 0x7010): 0x4100})
    reading = probe_vmivme4116(bus, BASE)
    assert reading.ok and reading.detail == "no ID register (VMIVME-4116); CSR 0x4100"
    assert (reading.id_expected, reading.id_read) == (None, None)
    assert bus.trace() == ["R A16 0x7010 D16 0x4100"]
    nothing = RecordingBus(answers={})
    refused = probe_vmivme4116(nothing, BASE)
    assert refused.ok is False and refused.detail.startswith("BusError: bus error on D16 read at A16 0x7010")
    assert nothing.trace() == []  # the refused read is no completed cycle


def test_opening_zeroes_and_strobes_off_p3_waits_the_settling_time_then_connects() -> None:
    bus, _ = opened()
    assert bus.trace() == OPEN
    assert bus.delays == [10e-6]  # between the strobe and the connection


def test_zero_writes_the_zero_volt_code_to_every_channel_then_one_strobe() -> None:
    bus, dac = opened()
    bus.clear()
    dac.zero()
    dac.reset()
    assert bus.trace() == [*ZEROES, STROBE, *ZEROES, STROBE]


def test_twos_complement_coding_writes_zero_volts_as_0x0000() -> None:
    bus, dac = opened(coding="twos_complement")
    assert bus.trace()[1:9] == [f"W A16 0x{0x7000 + 2 * n:04X} D16 0x0000" for n in range(8)]
    bus.clear()
    dac.write_volts(0, 2.5)
    dac.write_volts(1, -10.0)
    assert bus.trace() == ["W A16 0x7000 D16 0x2000", STROBE, "W A16 0x7002 D16 0x8000", STROBE]


def test_disconnect_writes_the_power_up_csr() -> None:
    bus, dac = opened()
    bus.clear()
    dac.disconnect()
    assert bus.trace() == ["W A16 0x7010 D16 0x0000"]


# --- writes and strobes ------------------------------------------------------------------------------

@pytest.mark.parametrize(("channel", "volts", "data"), [
    (0, 2.5, "W A16 0x7000 D16 0xA000"),
    (1, 0.0, "W A16 0x7002 D16 0x8000"),
    (4, -10.0, "W A16 0x7008 D16 0x0000"),
    (6, 9.99969482421875, "W A16 0x700C D16 0xFFFF"),
    (7, -3.3, "W A16 0x700E D16 0x55C3"),
])
def test_write_volts_loads_the_channel_then_strobes(channel: int, volts: float, data: str) -> None:
    bus, dac = opened()
    bus.clear()
    dac.write_volts(channel, volts)
    assert bus.trace() == [data, STROBE]


def test_write_many_loads_every_channel_then_one_strobe() -> None:
    bus, dac = opened()
    bus.clear()
    result = dac.write_many({0: 1.0, 3: -2.0, 7: 9.5})
    assert result.codes == {0: 0x8CCD, 3: 0x6666, 7: 0xF99A}
    assert bus.trace() == ["W A16 0x7000 D16 0x8CCD", "W A16 0x7006 D16 0x6666", "W A16 0x700E D16 0xF99A",
                           STROBE]


def test_a_load_without_update_then_the_strobe() -> None:
    bus, dac = opened()
    bus.clear()
    assert not dac.write_volts(3, 4.0, update=False).updated
    dac.update()
    dac.update([1, 5])  # no per-channel strobe: the same CSR write
    assert bus.trace() == ["W A16 0x7006 D16 0xB333", STROBE, STROBE]


def test_write_counts_writes_the_raw_code() -> None:
    bus, dac = opened()
    bus.clear()
    dac.write_counts(5, 0x1234)
    dac.write_counts(2, 0xFFFF, update=False)
    assert bus.trace() == ["W A16 0x700A D16 0x1234", STROBE, "W A16 0x7004 D16 0xFFFF"]


def test_an_out_of_range_command_writes_nothing_and_clamping_writes_the_end_codes() -> None:
    bus, dac = opened()
    bus.clear()
    with pytest.raises(DacRangeError):
        dac.write_many({0: 1.0, 1: 10.0})  # +10.0 V is one code past 0xFFFF
    assert bus.trace() == []
    dac.clamp = True
    dac.write_many({0: 12.0, 1: -11.0})
    assert bus.trace() == ["W A16 0x7000 D16 0xFFFF", "W A16 0x7002 D16 0x0000", STROBE]


# --- readback ------------------------------------------------------------------------------------

def test_read_back_reads_the_csr_and_returns_the_last_updated_code() -> None:
    bus, dac = opened()
    dac.write_volts(2, 2.5, update=False)
    bus.clear()
    assert dac.read_back_counts(2) == 0x8000  # loaded, not yet updated
    dac.update()
    assert dac.read_back_counts(2) == 0xA000
    assert dac.read_csr() == 0x0000
    assert bus.trace() == ["R A16 0x7010 D16 0x0000", STROBE, "R A16 0x7010 D16 0x0000", "R A16 0x7010 D16 0x0000"]


# --- through the emulator ------------------------------------------------------------------------

def test_a_synchronized_update_through_the_emulator() -> None:
    crate = Crate("t")
    crate.install(VmiVme4116Board("dac0", wiring={0: "o0", 3: "o3"}), base=BASE, space="A16")
    bus = RecordingBus(crate)
    dac = VmiVme4116Driver(bus, BASE)
    dac.write_many({0: 1.0, 3: -2.0})
    crate.delay(12e-6)
    assert (crate.signals.get_analog("o0"), crate.signals.get_analog("o3")) == (1.00006103515625, -2.0001220703125)
    assert bus.trace() == [*OPEN, "W A16 0x7000 D16 0x8CCD", "W A16 0x7006 D16 0x6666", STROBE]


# --- edges and texts ------------------------------------------------------------------------------------
def test_conversions_default_to_offset_binary_and_refuse_nan_and_17_bit_codes() -> None:
    assert vmi4116_volts_to_code(0.0) == (0x8000, False)  # offset binary by default
    assert vmi4116_code_to_volts(0x0000) == -10.0
    with pytest.raises(ValueError, match=r"^DAC command is NaN$"):
        vmi4116_volts_to_code(float("nan"))
    with pytest.raises(ValueError, match=r"^DAC code 65536 is outside 0\.\.0xFFFF$"):
        vmi4116_code_to_volts(0x10000)


def test_driver_refusals_name_the_limit() -> None:
    with pytest.raises(ValueError, match=r"^VMIVME-4116 coding 'gray': expected one of offset_binary, "
                                         r"twos_complement$"):
        opened(coding="gray")
    with pytest.raises(ValueError, match=r"^VMIVME-4116 calibration has 4 channels, the board has 8$"):
        opened(calibration=Calibration.identity(4))
    bus, dac = opened()
    for bad in (-1, 8):
        with pytest.raises(ValueError, match=rf"^DAC channel {bad} is not 0\.\.7$"):
            dac.write_counts(bad, 0)
    bus.clear()
    dac.write_counts(7, 0x0000, update=False)  # both ends of the 16 bits are codes
    dac.write_counts(7, 0xFFFF, update=False)
    assert bus.trace() == ["W A16 0x700E D16 0x0000", "W A16 0x700E D16 0xFFFF"]
    for bad in (-1, 0x10000):
        with pytest.raises(ValueError, match=rf"^DAC code {bad} is outside 0\.\.0xFFFF$"):
            dac.write_counts(0, bad)


def test_clamp_events_add_up_and_the_result_says_whether_it_strobed() -> None:
    _, dac = opened(clamp=True)
    assert dac.clamp is True
    dac.write_many({0: 11.0})
    res = dac.write_many({0: 11.0, 1: -11.0}, update=False)
    assert dac.clamp_events == 3 and res.clamped == (0, 1) and res.updated is False
    assert dac.write_many({}).updated is False and dac.write_many({2: 1.0}).updated is True


def test_the_range_error_names_the_channel_and_the_calibrated_command() -> None:
    e = Vmi4116RangeError(3, 9.9, 10.2)
    assert e.channel == 3
    assert str(e) == ("VMIVME-4116 channel 3: +9.90000 V (calibrated command +10.20000 V) is outside the output range "
                      "-10.00000..+9.99969 V; limit the command upstream or open the driver with clamp=True")
    assert str(Vmi4116RangeError(1, 12.0, 12.0)).startswith("VMIVME-4116 channel 1: +12.00000 V is outside")
