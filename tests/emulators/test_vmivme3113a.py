"""The VMIVME-3113A emulator against docs/boards/vmivme-3113a.md, through raw bus cycles only (no
driver): the registers' offsets, bits and reset values are the doc's, written here as literals.

Board at 0x8500 (A16). From the doc: ID +0x00 = 0x1100; CSR +0x02 (NEW_DATA_READY 15 / GAIN_DELAY,
FAIL_LED_OFF 14, END_OF_SCAN 13 / START_CONVERT, TWOS_COMPLEMENT 12, SOFTWARE_RESET 9, MODE 8:6);
CFR +0x04; ICR +0x0A (FLAG 7, FLAG_AUTO_CLEAR 6, INTERRUPT_ENABLE 4, INTR_AUTO_CLEAR 3, LEVEL 2:0);
IVR +0x12 (reset 0x0F); TM0..TM2 +0x20..+0x24; TMC +0x26 (write-only); CH0..CH63 at +0x80 + 2·k.
One conversion every 10 µs; a 64-channel scan 640 µs.
"""

from __future__ import annotations

import pytest

from emulators.board_factory import BuildContext
from emulators.crate import Crate
from emulators.signals import Signals
from emulators.vmivme3113a import Vmivme3113aBoard, vmivme3113a_factory
from hal.config import ConfigError, ConfigTable
from hal.vme import BusError, BusErrorCause, Width

BASE = 0x8500
CSR, CFR, ICR, IVR = BASE + 0x02, BASE + 0x04, BASE + 0x0A, BASE + 0x12


def ch(k: int) -> int:
    return BASE + 0x80 + 2 * k


def make(**kw) -> tuple[Crate, Vmivme3113aBoard]:
    c = Crate("t")
    board = Vmivme3113aBoard("adc0", wiring={0: "in0", 5: "in5", 63: "in63"}, **kw)
    c.install(board, base=BASE, space="A16")
    return c, board


def rd(c: Crate, address: int) -> int:
    return c.read(address, space="A16", width=Width.D16)


def wr(c: Crate, address: int, value: int) -> None:
    c.write(address, value, space="A16", width=Width.D16)


# --- identification, reset state, bad accesses ----------------------------------------------------

def test_id_reads_0x1100_and_registers_hold_their_reset_values() -> None:
    c, _ = make()
    assert rd(c, BASE) == 0x1100
    assert rd(c, CSR) == 0x0000  # autoscanning, LED on, offset binary; nothing ended at t = 0
    assert rd(c, CFR) == 0x0000
    assert rd(c, ICR) == 0x0000
    assert rd(c, IVR) == 0x000F
    assert [rd(c, BASE + o) for o in (0x20, 0x22, 0x24)] == [0, 0, 0]
    assert rd(c, ch(0)) == 0x0000 and rd(c, ch(63)) == 0x0000


@pytest.mark.parametrize(("offset", "width", "write", "cause"), [
    (0x06, Width.D16, False, BusErrorCause.NO_RESPONDER),   # 0x06-0x09 not decoded
    (0x0C, Width.D16, True, BusErrorCause.NO_RESPONDER),    # 0x0C-0x11
    (0x14, Width.D16, False, BusErrorCause.NO_RESPONDER),   # 0x14-0x1F
    (0x28, Width.D16, False, BusErrorCause.NO_RESPONDER),   # 0x28-0x7F
    (0x7E, Width.D16, False, BusErrorCause.NO_RESPONDER),
    (0x02, Width.D8, False, BusErrorCause.UNSUPPORTED_WIDTH),  # D16 only
    (0x81, Width.D8, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (0x80, Width.D32, False, BusErrorCause.UNSUPPORTED_WIDTH),
    (0x00, Width.D16, True, BusErrorCause.ACCESS),  # ID read-only
    (0x80, Width.D16, True, BusErrorCause.ACCESS),  # CH0 read-only
    (0xFE, Width.D16, True, BusErrorCause.ACCESS),  # CH63
    (0x26, Width.D16, False, BusErrorCause.ACCESS),  # TMC write-only
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


def test_interrupt_registers_keep_their_low_byte_and_csr_reads_back_its_control_bits() -> None:
    c, _ = make()
    wr(c, ICR, 0xFF13)
    wr(c, IVR, 0x1260)
    wr(c, CFR, 0xBEEF)
    assert (rd(c, ICR), rd(c, IVR), rd(c, CFR)) == (0x0013, 0x0060, 0xBEEF)
    wr(c, CSR, 0x5C3F)  # LED off, two's c., ext start, timer start, MODE 0, bits 5:0 set
    assert rd(c, CSR) & ~0xA000 == 0x5C00  # status bits aside; bits 5:0 read 0
    wr(c, BASE + 0x26, 0x0036)  # TMC takes a control word


# --- autoscanning: timing, ages, status -------------------------------------------------------------

def test_autoscan_stores_channel_k_at_the_end_of_its_conversion_slot() -> None:
    c, _ = make()
    c.signals.set_analog("in5", 5.0)
    c.advance_to(59_000)
    assert rd(c, ch(5)) == 0x0000  # read at 59.3 µs: channel 5 converts during 50..60 µs
    c.advance_to(60_000)
    assert rd(c, ch(5)) == 0x0C00  # +5 V on ±10 V, offset binary


def test_a_read_returns_the_latest_ended_conversion_until_the_next_one_of_that_channel() -> None:
    c, _ = make()
    c.signals.set_analog("in0", 5.0)
    c.advance_to(20_000)
    assert rd(c, ch(0)) == 0x0C00  # conversion 0 (0..10 µs)
    c.signals.set_analog("in0", -2.5)
    c.advance_to(600_000)
    assert rd(c, ch(0)) == 0x0C00  # next conversion of channel 0 is 640..650 µs
    c.advance_to(650_000)
    assert rd(c, ch(0)) == 0x0600


def test_end_of_scan_and_new_data_ready_report_since_the_last_csr_read() -> None:
    c, _ = make()
    c.advance_to(5_000)
    assert rd(c, CSR) == 0x0000  # nothing ended yet
    c.advance_to(15_000)
    assert rd(c, CSR) == 0x8000  # conversion 0 ended: NEW_DATA_READY
    assert rd(c, CSR) == 0x0000  # the read cleared it
    c.advance_to(640_000)
    assert rd(c, CSR) == 0xA000  # the first scan of 64 ended: + END_OF_SCAN
    assert rd(c, CSR) == 0x0000


def test_software_reset_restores_the_registers_zeroes_the_data_and_restarts_the_scan() -> None:
    c, _ = make()
    c.signals.set_analog("in0", 5.0)
    wr(c, IVR, 0x60)
    wr(c, CSR, 0x5000)
    c.advance_to(700_000)
    assert rd(c, ch(0)) == 0x0400  # two's complement of 0xC00
    wr(c, CSR, 0x0200)  # SOFTWARE_RESET (alone, as the EPICS init writes it)
    assert rd(c, IVR) == 0x000F
    assert rd(c, CSR) == 0x0000
    assert rd(c, ch(0)) == 0x0000  # data zeroed, the restarted scan has not reached channel 0's end
    c.delay(10e-6)
    assert rd(c, ch(0)) == 0x0C00  # offset binary again


def test_two_complement_codes_are_sign_extended_and_stored_in_the_format_of_their_conversion() -> None:
    c, _ = make()
    c.signals.set_analog("in5", -2.5)
    wr(c, CSR, 0x1000)
    c.advance_to(100_000)
    assert rd(c, ch(5)) == 0xFE00  # 0x600 with bit 11 inverted, sign-extended
    wr(c, CSR, 0x0000)
    assert rd(c, ch(5)) == 0xFE00  # the stored code keeps its format
    c.advance_to(700_000)
    assert rd(c, ch(5)) == 0x0600


@pytest.mark.parametrize(("rng", "volts", "word"), [
    ("bipolar_10v", 0.9, 0x08B8),
    ("bipolar_5v", 0.9, 0x0971),
    ("unipolar_10v", 0.9, 0x0171),
    ("unipolar_10v", -2.0, 0x0000),  # saturates at the rail, never wraps
    ("bipolar_5v", 10.0, 0x0FFF),
])
def test_the_jumpered_range_sets_the_quantizer(rng: str, volts: float, word: int) -> None:
    c, _ = make(input_range=rng)
    c.signals.set_analog("in0", volts)
    c.delay(20e-6)
    assert rd(c, ch(0)) == word


def test_unwired_channels_read_zero_volts() -> None:
    c, _ = make()
    c.delay(700e-6)
    assert rd(c, ch(30)) == 0x0800


# --- scanning modes and the interrupt ---------------------------------------------------------------

def test_scanning_poll_waits_for_start_convert_scans_once_and_holds_the_codes() -> None:
    c, _ = make()
    c.signals.set_analog("in5", 5.0)
    wr(c, CSR, 0x40C0)  # FAIL_LED_OFF, MODE 3 (scanning poll)
    rd(c, CSR)
    c.delay(1e-3)
    assert rd(c, CSR) == 0x40C0  # idle: nothing converts
    wr(c, CSR, 0x60C0)  # + START_CONVERT
    c.delay(639e-6)
    assert rd(c, CSR) & 0x2000 == 0
    c.delay(2e-6)
    assert rd(c, CSR) & 0x2000  # END_OF_SCAN after 64 × 10 µs
    c.signals.set_analog("in5", -2.5)
    c.delay(1e-3)
    assert rd(c, ch(5)) == 0x0C00  # the scan's code, not the net's value now


def test_start_convert_while_a_scan_runs_is_ignored() -> None:
    c, _ = make()
    wr(c, CSR, 0x40C0)
    wr(c, CSR, 0x60C0)
    c.delay(300e-6)
    wr(c, CSR, 0x60C0)  # ignored: the first scan still ends at 640 µs
    c.delay(345e-6)
    assert rd(c, CSR) & 0x2000


def test_scanning_interrupt_requests_at_end_of_scan_and_iack_releases_it() -> None:
    c, board = make()
    seen: list[int] = []
    c.register_irq_handler(0x60, seen.append)
    wr(c, IVR, 0x60)
    wr(c, ICR, 0x0013)  # INTERRUPT_ENABLE, LEVEL 3
    wr(c, CSR, 0x4100)  # MODE 4
    wr(c, CSR, 0x6100)  # START_CONVERT
    c.delay(600e-6)
    assert seen == []
    c.delay(50e-6)
    assert seen == [0x60]
    assert not board.irq_pending  # released by the IACK (ROAK)
    assert rd(c, CSR) == 0xE100
    assert rd(c, ICR) == 0x0013  # INTR_AUTO_CLEAR off: stays enabled


def test_intr_auto_clear_and_flag_auto_clear_clear_their_bits_at_iack() -> None:
    c, _ = make()
    seen: list[int] = []
    c.register_irq_handler(0x61, seen.append)
    wr(c, IVR, 0x61)
    wr(c, ICR, 0x00DA)  # FLAG, FLAG_AUTO_CLEAR, INTERRUPT_ENABLE, INTR_AUTO_CLEAR, LEVEL 2
    wr(c, CSR, 0x4100)
    wr(c, CSR, 0x6100)
    c.delay(700e-6)
    assert seen == [0x61]
    assert rd(c, ICR) == 0x004A  # FLAG and INTERRUPT_ENABLE cleared; FLAG_AUTO_CLEAR, INTR_AUTO_CLEAR, LEVEL 2 stay
    wr(c, CSR, 0x6100)
    c.delay(700e-6)
    assert seen == [0x61]  # no second interrupt: disabled by the first IACK


def test_autoscanning_and_scanning_poll_request_no_interrupt() -> None:
    c, board = make()
    seen: list[int] = []
    c.register_irq_handler(0x60, seen.append)
    wr(c, IVR, 0x60)
    wr(c, ICR, 0x0013)
    c.delay(2e-3)  # three autoscans
    wr(c, CSR, 0x40C0)
    wr(c, CSR, 0x60C0)
    c.delay(1e-3)
    assert seen == [] and not board.irq_pending


def test_random_modes_stop_the_sequencer_and_the_words_hold() -> None:
    c, _ = make()
    c.signals.set_analog("in5", 5.0)
    c.delay(700e-6)
    wr(c, CSR, 0x4040)  # MODE 1 (random poll): not modelled, the sequencer stops
    c.signals.set_analog("in5", -2.5)
    rd(c, CSR)
    c.delay(2e-3)
    assert rd(c, CSR) == 0x4040
    assert rd(c, ch(5)) == 0x0C00


# --- front end and faults ----------------------------------------------------------------------------

def test_stuck_channel_fault_and_noise_burst_on_listed_channels_only() -> None:
    c, board = make()
    c.signals.set_analog("in0", 1.0)
    c.signals.set_analog("in5", 1.0)
    board.inject("stuck_channel", channel=0, code=0x123)
    board.inject("noise_burst", rms_v=0.05, channels=[5])
    words0, words5 = set(), set()
    for _ in range(20):
        c.delay(640e-6)
        words0.add(rd(c, ch(0)))
        words5.add(rd(c, ch(5)))
    assert words0 == {0x123}
    assert len(words5) > 5  # 50 mV rms ≈ 10 LSB: the codes spread
    board.clear_fault()
    c.delay(640e-6)
    assert rd(c, ch(5)) == 0x08CD  # 1.0 V: floor(11 / 0.0048828125 + ½) = 2253 = 0x8CD


def test_noise_is_seeded_by_the_crate_seed() -> None:
    def codes(seed: int) -> list[int]:
        c = Crate("s")
        c.install(Vmivme3113aBoard("adc0", wiring={0: "in0"}, noise_rms_v=0.01, seed=seed), base=BASE, space="A16")
        c.signals.set_analog("in0", 1.0)
        out = []
        for _ in range(10):
            c.delay(640e-6)
            out.append(rd(c, ch(0)))
        return out

    assert codes(3) == codes(3)
    assert codes(3) != codes(4)


# --- crate file --------------------------------------------------------------------------------------

def test_the_factory_builds_the_board_from_its_crate_table() -> None:
    cfg = ConfigTable({"input_range": "bipolar_5v", "conversion_time_us": 20, "noise_rms_v": 0.0,
                       "offset_v": [0.0, 0.0, 0.0, 0.01] + [0.0] * 60, "wiring": {"3": "pot"}}, "test", "crate.board")
    board = vmivme3113a_factory("adc0", cfg, BuildContext(Signals(), seed=1))
    assert board.conversion_time_ns == 20_000 and board.input_range == "bipolar_5v"
    assert board.describe()["model"] == "VMIVME-3113A"
    c = Crate("f")
    c.install(board, base=BASE, space="A16")
    c.signals.set_analog("pot", 2.49)
    c.delay(100e-6)
    assert rd(c, ch(3)) == 0x0C00  # 2.49 + 0.01 = 2.5 V on ±5 V


@pytest.mark.parametrize(("data", "key"), [
    ({"wiring": {"64": "x"}}, "wiring.64"),
    ({"input_range": "bipolar_2v"}, "input_range"),
    ({"offset_v": [0.0] * 16}, "offset_v"),
    ({"conversion_time_us": 0}, "conversion_time_us"),
])
def test_bad_crate_entries_name_the_key(data: dict, key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        vmivme3113a_factory("adc0", ConfigTable(data, "test", "crate.board"), BuildContext(Signals()))
