"""Golden bus traces of the DAC driver: every operation's cycles, compared with a literal trace
written by hand from docs/boards/dac.md (register table and coding).

Board at 0x7000 (A16). From the doc: ID +0x00 (0xDA08), CSR +0x02 (UPDATE_ALL bit 0, SETTLING
bit 1, RESET bit 15), UPDATE +0x04 (bit n: channel n), DATA0..DATA7 +0x10..+0x1E, OUT0..OUT7
+0x20..+0x2E; codes offset binary, code = floor((V + 10 V) / 4.8828125 mV + ½).
"""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.dac import DacBoard
from hal.adc_dac import BoardIdError, DacDriver, DacRangeError
from hal.vme import BusError
from tests.support.bus_trace import Answer, RecordingBus

BASE = 0x7000
PROBE = "R A16 0x7000 D16 0xDA08"


def scripted(extra: dict[int, int] | None = None) -> RecordingBus:
    """A bus answering the ID, and ``extra``: A16 address → the value its reads answer."""
    answers: dict[tuple[str, int], Answer] = {("A16", 0x7000): 0xDA08}
    answers.update({("A16", address): v for address, v in (extra or {}).items()})
    return RecordingBus(answers=answers)


# --- probe and reset ----------------------------------------------------------------------------

def test_opening_the_driver_reads_the_id_and_writes_nothing() -> None:
    bus = scripted()
    DacDriver(bus, BASE)
    assert bus.trace() == [PROBE]


def test_a_board_with_another_id_is_refused() -> None:
    bus = RecordingBus(answers={("A16", 0x7000): 0xAD16})  # an ADC there
    with pytest.raises(BoardIdError, match="0x7000.*reads 0xAD16, expected 0xDA08"):
        DacDriver(bus, BASE)
    assert bus.trace() == ["R A16 0x7000 D16 0xAD16"]
    with pytest.raises(BusError):
        DacDriver(RecordingBus(answers={}), BASE)


def test_reset_writes_csr_reset() -> None:
    bus = scripted()
    DacDriver(bus, BASE).reset()
    assert bus.trace() == [PROBE, "W A16 0x7002 D16 0x8000"]


# --- writes and strobes ---------------------------------------------------------------------------

@pytest.mark.parametrize(("channel", "volts", "data"), [
    (0, 2.5, "W A16 0x7010 D16 0x0A00"),
    (1, 0.0, "W A16 0x7012 D16 0x0800"),
    (4, -10.0, "W A16 0x7018 D16 0x0000"),
    (6, 9.9951171875, "W A16 0x701C D16 0x0FFF"),
    (7, -3.3, "W A16 0x701E D16 0x055C"),
])
def test_write_volts_loads_the_holding_register_then_strobes_its_update_bit(channel: int, volts: float,
                                                                            data: str) -> None:
    bus = scripted()
    dac = DacDriver(bus, BASE)
    bus.clear()
    dac.write_volts(channel, volts)
    assert bus.trace() == [data, f"W A16 0x7004 D16 0x{1 << channel:04X}"]


def test_write_many_loads_every_channel_then_one_strobe() -> None:
    bus = scripted()
    dac = DacDriver(bus, BASE)
    bus.clear()
    result = dac.write_many({0: 1.0, 3: -2.0, 7: 9.5})
    assert result.codes == {0: 0x8CD, 3: 0x666, 7: 0xF9A}
    assert bus.trace() == ["W A16 0x7010 D16 0x08CD", "W A16 0x7016 D16 0x0666", "W A16 0x701E D16 0x0F9A",
                           "W A16 0x7004 D16 0x0089"]  # UPDATE: channels 0, 3 and 7 at once


def test_a_load_without_update_then_the_update_all_strobe() -> None:
    bus = scripted()
    dac = DacDriver(bus, BASE)
    bus.clear()
    assert not dac.write_volts(3, 4.0, update=False).updated
    dac.update()
    dac.update([1, 5])
    assert bus.trace() == ["W A16 0x7016 D16 0x0B33",  # DATA3: +4.0 V
                           "W A16 0x7002 D16 0x0001",  # CSR.UPDATE_ALL
                           "W A16 0x7004 D16 0x0022"]  # UPDATE: channels 1 and 5


def test_write_counts_writes_the_raw_code() -> None:
    bus = scripted()
    dac = DacDriver(bus, BASE)
    bus.clear()
    dac.write_counts(5, 0x123)
    dac.write_counts(2, 0xFFF, update=False)
    assert bus.trace() == ["W A16 0x701A D16 0x0123", "W A16 0x7004 D16 0x0020", "W A16 0x7014 D16 0x0FFF"]


def test_an_out_of_range_command_writes_nothing_and_clamping_writes_the_end_codes() -> None:
    bus = scripted()
    dac = DacDriver(bus, BASE)
    bus.clear()
    with pytest.raises(DacRangeError):
        dac.write_many({0: 1.0, 1: 10.0})  # +10.0 V is one code past 0xFFF
    assert bus.trace() == []
    dac.clamp = True
    dac.write_many({0: 12.0, 1: -11.0})
    assert bus.trace() == ["W A16 0x7010 D16 0x0FFF", "W A16 0x7012 D16 0x0000", "W A16 0x7004 D16 0x0003"]


# --- readback ------------------------------------------------------------------------------------

def test_readbacks_read_out_data_and_csr() -> None:
    bus = scripted({0x7024: 0x0A00, 0x7014: 0xF555, 0x7002: 0x0002})  # OUT2, DATA2, CSR
    dac = DacDriver(bus, BASE)
    bus.clear()
    assert dac.read_back_counts(2) == 0xA00
    assert dac.read_holding_counts(2) == 0x555  # bits 15:12 are not the code
    assert dac.settling
    assert bus.trace() == ["R A16 0x7024 D16 0x0A00", "R A16 0x7014 D16 0xF555", "R A16 0x7002 D16 0x0002"]


# --- through the emulator ------------------------------------------------------------------------

def test_a_simultaneous_update_through_the_emulator() -> None:
    crate = Crate("t")
    board = DacBoard("dac0", wiring={0: "o0", 3: "o3"})
    crate.install(board, base=BASE, space="A16")
    bus = RecordingBus(crate)
    dac = DacDriver(bus, BASE)
    dac.write_many({0: 1.0, 3: -2.0}, update=False)
    assert dac.read_back_counts(0) == 0x800  # holding loaded, output still 0 V
    dac.update([0, 3])
    crate.delay(12e-6)
    assert (crate.signals.get_analog("o0"), crate.signals.get_analog("o3")) == (1.0009765625, -2.001953125)
    assert bus.trace() == [PROBE, "W A16 0x7010 D16 0x08CD", "W A16 0x7016 D16 0x0666", "R A16 0x7020 D16 0x0800",
                           "W A16 0x7004 D16 0x0009"]
